"""Normals of a scan's points: local PCA, and one consistent side per sheet of the scan.

:func:`pca_normals` estimates each point's normal from its ``k`` nearest neighbours (the sign
arbitrary); :func:`orient_normals_consistent` signs them consistently along each connected
sheet of the scan (a minimum spanning tree over pairs on one smooth skin, Hoppe et al. 1992)
and outward where the scan shows a thin wall's other skin behind a point
(:func:`wall_sides`); :func:`one_skin_normals` refits them on one skin at a length of the
part first, as the inspection measures the seated scan's.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "SIDE_KNOWN",
    "STACKED",
    "TANGENT_EDGE",
    "TANGENT_PARALLEL",
    "WALL_AGREEMENT",
    "WALL_CONE",
    "WALL_MIN_POINTS",
    "WALL_PARALLEL",
    "WALL_PROBES",
    "WALL_SAMPLE",
    "orient_normals_consistent",
    "one_skin_normals",
    "pca_normals",
    "refined_normals",
    "wall_sides",
]


def pca_normals(P: np.ndarray, k: int = 12, tree: cKDTree | None = None) -> np.ndarray:
    """Unit normals (m, 3) of the scan from the PCA of each point's ``k`` nearest neighbours.

    The sign is arbitrary (a one-sided scan has no inside); use ``|n . n_scan|``.
    """
    tree = tree or cKDTree(P)
    k = min(k, len(P))
    _, idx = tree.query(P, k=k, workers=-1)
    return _pca_of(P, idx)


def _pca_of(P: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """The normals of :func:`pca_normals` from the neighbourhoods ``idx`` (m, k), each
    point's ``k`` nearest points of ``P`` (m, 3) as ``cKDTree.query`` orders them."""
    N = np.empty((len(P), 3))
    # in blocks of points: each point's neighbourhood is its own, and a (m, k, 3) copy of
    # 400k points' neighbourhoods would hold 115 MB twice over
    for s in range(0, len(P), _PCA_BLOCK):
        Q = np.take(P, idx[s : s + _PCA_BLOCK], axis=0)  # (np.take: registration.arrays)
        Q -= Q.mean(axis=1, keepdims=True)
        _, vecs = np.linalg.eigh(np.matmul(Q.transpose(0, 2, 1), Q))
        N[s : s + _PCA_BLOCK] = vecs[:, :, 0]
    return N


#: most neighbours :func:`refined_normals` fits a tangent plane to; the slab of one skin, a
#: share of its radius; the fewest neighbours it fits, and the least spread across the
#: second tangent direction, as a share of the first (scan lines: points along a line leave
#: the normal undetermined about the line)
REFINE_MAX_NEIGHBOURS = 48
REFINE_SLAB = 0.25
REFINE_MIN_POINTS = 5
REFINE_MIN_SPREAD = 0.05


def refined_normals(
    P: np.ndarray,
    Ns: np.ndarray,
    prior: np.ndarray,
    radius: float,
    tree: cKDTree | None = None,
) -> np.ndarray:
    """Scan normals (m, 3) refitted on the points of one skin within ``radius`` mm.

    :func:`pca_normals` takes each point's ``k`` nearest neighbours: their reach follows
    the scan's density, and on a sparse scan of a thin wall (or one along scan lines) they
    mix the wall's two skins or lie along one line, and the normal turns by tens of
    degrees. Here each point's tangent plane is fitted to its neighbours within a fixed
    ``radius`` (at most :data:`REFINE_MAX_NEIGHBOURS`, at least the nearest
    :data:`REFINE_MIN_POINTS`) that lie in the slab of half-width :data:`REFINE_SLAB` x
    ``radius`` about the point across ``prior``, its approximate normal (the nominal's
    surface normal there, the scan seated rigidly on it): a wall's other skin, farther
    than the slab, never enters. The normal is the prior where fewer than
    :data:`REFINE_MIN_POINTS` neighbours are in the slab or they lie along one line
    (second tangent spread under :data:`REFINE_MIN_SPREAD` of the first).

    Each normal keeps the side of ``Ns`` (the consistently signed scan normals) where the
    two agree within 60 degrees, else the prior's.

    Parameters
    ----------
    P : (m, 3) scan points, mm.  Ns : (m, 3) their unit normals, signed.
    prior : (m, 3) unit approximate normals (e.g. of the nominal's closest triangles).
    radius : the neighbourhood, mm, stated from the part (not from the scan's spacing).
    tree : ``cKDTree(P)``.
    """
    return _refined(P, Ns, prior, radius, tree or cKDTree(P))[0]


def _refined(
    P: np.ndarray, Ns: np.ndarray, prior: np.ndarray, radius: float, tree: cKDTree, n: int = 0
) -> tuple:
    """:func:`refined_normals`, and each point's ``n`` nearest points from its neighbour
    query (:func:`_leading`; ``n`` 0: none).

    Returns
    -------
    normals : (m, 3) as :func:`refined_normals`.
    near : ``[nb, spacing, again]`` of :func:`_leading` for all points, or None.
    """
    m = len(P)
    k = min(REFINE_MAX_NEIGHBOURS, m)
    out = np.asarray(prior, dtype=np.float64).copy()
    held = None
    if 2 <= n and min(n + 1, m) <= k:
        held = [np.empty((m, n), dtype=np.intp), np.empty(m), np.empty(m, dtype=bool)]
    lead = max(n + 1, REFINE_MIN_POINTS)
    for s in range(0, m, _PCA_BLOCK):
        X0, N0 = P[s : s + _PCA_BLOCK], out[s : s + _PCA_BLOCK]
        dist, idx = _nearest_within(tree, X0, k, lead, radius)
        if held is not None:
            for kept, part in zip(held, _leading(dist, idx, n, m), strict=True):
                kept[s : s + _PCA_BLOCK] = part
        D = np.take(P, idx, axis=0) - X0[:, None, :]  # (np.take: registration.arrays)
        near = (dist <= radius) | (np.arange(k) < REFINE_MIN_POINTS)
        w = near & (np.abs(np.einsum("mki,mi->mk", D, N0)) <= REFINE_SLAB * radius)
        cnt = w.sum(axis=1)
        W = w.astype(np.float64)
        D -= (np.einsum("mki,mk->mi", D, W) / np.maximum(cnt, 1)[:, None])[:, None, :]
        D *= W[..., None]
        # the weighted scatter, one (3, k) @ (k, 3) product per point (batched BLAS)
        vals, vecs = np.linalg.eigh(np.matmul(D.transpose(0, 2, 1), D))
        ok = (cnt >= REFINE_MIN_POINTS) & (vals[:, 1] > REFINE_MIN_SPREAD * vals[:, 2])
        N0[ok] = vecs[ok, :, 0]
    same = np.einsum("ij,ij->i", out, Ns)
    side = np.where(np.abs(same) >= 0.5, same, np.einsum("ij,ij->i", out, prior))
    out[side < 0] *= -1.0
    return out, held


def _nearest_within(
    tree: cKDTree, X: np.ndarray, k: int, lead: int, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """``tree.query(X, k)`` where it matters to the refit: each row's first ``lead``
    neighbours, and beyond them those within ``radius`` mm; the rest of a row's ``k``
    columns hold distance inf (index 0).

    On a scan denser than the radius needs, a search of ``k`` unbounded neighbours costs
    three times as much for columns the refit weighs 0. So the search is bounded by the
    radius, in the order a sample of the rows says is cheaper: when most rows hold
    ``lead`` points within it, the ``k`` nearest within the radius first, then the
    ``lead`` nearest of the rows short of them; else the ``lead`` nearest first, then
    the ``k`` within the radius of the rows whose ``lead``-th lies within it. Either
    order gives the same arrays.

    Parameters
    ----------
    tree : ``cKDTree`` of the points.  X : (a, 3) query points, mm.  k : columns.
    lead : columns always searched (clipped to ``k``).  radius : mm.

    Returns
    -------
    dist : (a, k) float, ascending per row.  idx : (a, k) intp.
    """
    a, lead = len(X), min(lead, k)
    sample = tree.query(X[:: max(1, a // 512)], k=lead, distance_upper_bound=radius)[0]
    if np.mean(np.isfinite(np.reshape(sample, (-1, lead))[:, -1])) >= 0.5:
        d, i = tree.query(X, k=k, distance_upper_bound=radius, workers=-1)
        dist, idx = np.reshape(d, (a, k)), np.reshape(i, (a, k))
        rows, then, bound = np.flatnonzero(~np.isfinite(dist[:, lead - 1])), lead, np.inf
    else:
        dist, idx = np.full((a, k), np.inf), np.zeros((a, k), dtype=np.intp)
        d, i = tree.query(X, k=lead, workers=-1)
        dist[:, :lead], idx[:, :lead] = np.reshape(d, (a, lead)), np.reshape(i, (a, lead))
        rows, then, bound = np.flatnonzero(dist[:, lead - 1] <= radius), k, radius
    if len(rows):
        d, i = tree.query(X[rows], k=then, distance_upper_bound=bound, workers=-1)
        dist[rows, :then] = np.reshape(d, (-1, then))
        idx[rows, :then] = np.reshape(i, (-1, then))
    idx[~np.isfinite(dist)] = 0
    return dist, idx


#: points per block of :func:`pca_normals`, neighbour pairs per block of
#: :func:`orient_normals_consistent`
_PCA_BLOCK = 32_768
_PAIR_BLOCK = 1 << 20


#: a neighbour the side is carried to lies within asin(0.2) = 11.5 deg of both points'
#: tangent planes, their normals within acos(0.95) = 18 deg of each other: the same skin
#: (a looser graph carried the side across a thin wall's rim and sharp bends: on a 1.2 mm
#: steel bracket scanned from both sides half the points faced inwards)
TANGENT_EDGE = 0.2
TANGENT_PARALLEL = 0.95
#: a wall's other skin is looked for along each normal at these distances, mm (walls of
#: sheet metal and moulded plastic, 0.3-4.5 mm), within this share of the distance (or 0.75
#: of the point spacing there) of the probe, its normal within acos(0.9) of the point's
WALL_PROBES = (0.3, 0.45, 0.7, 1.0, 1.5, 2.2, 3.2, 4.5)
WALL_CONE = 0.4
WALL_PARALLEL = 0.9
#: a sheet's side is the scan's own when this many of its (sampled) points, and this
#: share of them, see a wall behind them and this share of those agree on the side (a
#: few points that see another object of the scan decide nothing for a whole sheet)
WALL_MIN_POINTS = 10
WALL_MIN_SHARE = 0.05
WALL_AGREEMENT = 0.9
#: points looked from (every m // WALL_SAMPLE-th), each voting for its sheet
WALL_SAMPLE = 30_000
#: a neighbour lies across a wall (stacked) when its offset along either normal exceeds
#: this share of its distance (acos(0.7) = 46 deg of the normal), beside a point else
STACKED = 0.7
#: the sheet label of points whose side the scan itself decided (see
#: :func:`orient_normals_consistent`): no vote against a nominal changes it
SIDE_KNOWN = -1


def wall_sides(
    P: np.ndarray,
    Ns: np.ndarray,
    at: np.ndarray | None = None,
    tree: cKDTree | None = None,
) -> np.ndarray:
    """(a,) +1 where another skin of the scan lies behind a point along its normal (a thin
    wall's: the normal points outwards), -1 where it lies in front, 0 where neither or both.

    The nearest scan point to ``P + a n`` for each probe distance ``a``
    (:data:`WALL_PROBES`, mm) counts if it lies within :data:`WALL_CONE` ``a`` of the
    probe (or 0.75 x the point's spacing, when larger), stacked along the normal and with
    a parallel normal: the first such distance on each side is where the other skin is.

    Parameters
    ----------
    P : (m, 3) scan points, mm.  Ns : (m, 3) their unit normals.
    at : (a,) indices of the points looked from (default: all).  tree : ``cKDTree(P)``.
    """
    tree = tree or cKDTree(P)
    at = np.arange(len(P)) if at is None else np.asarray(at)
    return _wall_sides(P, Ns, at, tree, tree.query(P[at], k=2, workers=-1)[0][:, 1])


def _wall_sides(
    P: np.ndarray, Ns: np.ndarray, at: np.ndarray, tree: cKDTree, spacing: np.ndarray
) -> np.ndarray:
    """:func:`wall_sides` from the points ``at`` (a,), given ``spacing`` (a,), the distance
    of each to its second nearest point of ``P`` (``tree.query(P[at], k=2)``)."""
    X0, N0 = P[at], Ns[at]
    reach = 0.75 * spacing
    hit = np.full((2, len(at)), np.inf)
    for side, sgn in enumerate((1.0, -1.0)):
        for a in WALL_PROBES:
            idx = np.flatnonzero(np.isinf(hit[side]))
            if not len(idx):
                break
            cone = np.maximum(WALL_CONE * a, reach[idx])
            # a bounded search (most probes of a single skin find nothing near): the same
            # nearest point wherever one lies within the cone, index len(P) where none does
            dist, j = tree.query(
                X0[idx] + sgn * a * N0[idx], distance_upper_bound=float(cone.max()), workers=-1
            )
            found = dist < cone
            idx, j, dist = idx[found], j[found], dist[found]
            d = P[j] - X0[idx]
            ok = np.abs(np.einsum("ij,ij->i", N0[idx], Ns[j])) > WALL_PARALLEL
            ok &= np.abs(np.einsum("ij,ij->i", d, N0[idx])) > STACKED * np.linalg.norm(d, axis=1)
            hit[side, idx[ok]] = a
    front, behind = hit
    out = np.zeros(len(at), dtype=np.int8)
    out[behind < front] = 1
    out[front < behind] = -1
    return out


def _leading(dist: np.ndarray, idx: np.ndarray, n: int, m: int) -> list | None:
    """The ``n`` nearest points of each of a points, from ``(dist, idx)`` (a, K), their
    ``tree.query`` for K of the m points (``n`` <= K), as a query for ``n`` gives them:
    the same where the first ``n + 1`` distances of a row all differ (the ``n`` nearest,
    and their order, then are the only ones), or where K = m; the other rows (equal
    distances, which the search may order otherwise) are to be queried again.

    Returns
    -------
    ``[nb, spacing, again]``: nb (a, n) the first ``n`` columns of ``idx``; spacing (a,)
    the distance to the second nearest point (``n`` >= 2); again (a,) bool, the rows to
    query again. None when K < min(``n`` + 1, m) (the ``n``-th's successor unknown).
    """
    if n < 2 or idx.shape[1] < min(n + 1, m):
        return None
    d = dist[:, : n + 1]
    return [idx[:, :n].copy(), dist[:, 1].copy(), np.any(d[:, 1:] == d[:, :-1], axis=1)]


def _tangent_graph(
    P: np.ndarray, Ns: np.ndarray, k: int, tree: cKDTree, held: list | None = None
) -> tuple:
    """The graph along which :func:`orient_normals_consistent` propagates the sign of the
    unsigned normals ``Ns`` (m, 3) of the scan ``P`` (m, 3) mm, from its ``k``-NN pairs
    (``held``: a list holding nb (m, k + 1), each point's ``k + 1`` nearest points as
    ``tree.query`` gives them, emptied here; default: queried here).

    Returns
    -------
    G : (m, m) symmetric sparse CSR, the pairs on one smooth skin (:data:`TANGENT_EDGE`,
        :data:`TANGENT_PARALLEL`) weighted ``1 - |n_i . n_j|`` (+1e-6).
    pi, pj : (e,) the pairs side by side: not across a wall, nor a sharp crease.
    """
    from scipy.sparse import coo_matrix

    m = len(P)
    # (the arrays of every pair, 35 MB each for 400k points, are dropped once used: on a
    # large scan this runs beside the part's preparation, and the two peaks add up)
    nb = tree.query(P, k=k + 1, workers=-1)[1] if held is None else held.pop()
    i = np.repeat(np.arange(m), k)
    j = nb[:, 1:].ravel()
    del nb
    L, off, par = (np.empty(len(i)) for _ in range(3))
    # the pairs in blocks (their (E, 3) offsets and normals, 105 MB each for 400k points, are
    # not all held at once); rows gathered by np.take (qifreport.registration.arrays)
    for s in range(0, len(i), _PAIR_BLOCK):
        b = slice(s, s + _PAIR_BLOCK)
        Ni, Nj = np.take(Ns, i[b], axis=0), np.take(Ns, j[b], axis=0)
        d = np.take(P, j[b], axis=0) - np.take(P, i[b], axis=0)
        L[b] = np.maximum(np.linalg.norm(d, axis=1), 1e-12)
        off[b] = np.maximum(
            np.abs(np.einsum("ij,ij->i", d, Ni)), np.abs(np.einsum("ij,ij->i", d, Nj))
        )
        par[b] = np.abs(np.einsum("ij,ij->i", Ni, Nj))
    keep = (off < TANGENT_EDGE * L) & (par > TANGENT_PARALLEL)
    beside = (off < STACKED * L) & (par > 0.7)  # not across a wall, nor a sharp crease
    pi, pj = i[beside], j[beside]
    i, j = i[keep], j[keep]
    w = 1.0 - par[keep] + 1e-6
    del L, off, par, keep, beside
    G = coo_matrix((w, (i, j)), shape=(m, m)).tocsr()
    del i, j, w
    return G.maximum(G.T), pi, pj


def _spanning_tree(G):
    """The minimum spanning forest of the symmetric sparse graph ``G`` (m, m), each edge
    once (upper triangular, sparse)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import minimum_spanning_tree

    # each edge once (the upper triangle): Kruskal sorts half as many weights and meets
    # every edge in the same order, so the tree is the same
    return minimum_spanning_tree(sp.triu(G, format="csr"))


def _tree_parents(T, m: int) -> tuple[int, np.ndarray, np.ndarray]:
    """The components of the spanning forest ``T`` (m, m, sparse, each edge once) and a
    breadth-first tree of each.

    Returns
    -------
    n_comp : number of connected components (sheets).
    labels : (m,) component of each point.
    pred : (m,) parent of each point (the roots, each component's first point, their own).
    """
    import scipy.sparse as sp
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    T = T.maximum(T.T)
    n_comp, labels = connected_components(T, directed=False)
    # parent of every point in a breadth-first tree of its component (roots: themselves),
    # one search from a hub joined to each component's first point
    roots = np.unique(labels, return_index=True)[1]
    hub = coo_matrix((np.ones(len(roots)), (np.full(len(roots), m), roots)), shape=(m + 1, m + 1))
    T = (sp.block_diag((T, sp.csr_matrix((1, 1)))) + hub).tocsr()
    _, pred = breadth_first_order(T, m, directed=False)
    pred = pred[:m].copy()
    pred[roots] = roots
    return n_comp, labels, pred


def _path_signs(Ns: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """The sign (m,) that turns each normal of ``Ns`` (m, 3) to its tree root's side: the
    product of the edge signs along its path to the root (``pred`` (m,) the parents),
    by pointer doubling, log2(depth) vectorised steps."""
    flip = np.where(np.einsum("ij,ij->i", Ns, Ns[pred]) < 0, -1.0, 1.0)
    up = pred.copy()
    while np.any(up != up[up]):
        flip *= flip[up]
        up = up[up]
    flip *= flip[up]  # the roots' own sign, +1
    return flip


def _outward_sheets(
    P: np.ndarray,
    out: np.ndarray,
    labels: np.ndarray,
    n_comp: int,
    tree: cKDTree,
    spacing: np.ndarray | None = None,
) -> np.ndarray:
    """Turn outward, in place, the sheets of the consistently signed normals ``out`` (m, 3)
    whose points see the wall's other skin (:func:`wall_sides` on a sample: its points
    vote for their sheets, ``labels`` (m,)). ``spacing`` (m,): each point's distance to
    its second nearest point (default: queried here). Returns (n_comp,) bool, the sheets
    whose side the vote decided."""
    m = len(P)
    probe = np.arange(0, m, max(1, m // WALL_SAMPLE))
    sides = np.zeros(m, dtype=np.int8)
    if spacing is None:
        sides[probe] = wall_sides(P, out, probe, tree)
    else:
        sides[probe] = _wall_sides(P, out, probe, tree, spacing[probe])
    pos = np.bincount(labels, weights=sides > 0, minlength=n_comp)
    neg = np.bincount(labels, weights=sides < 0, minlength=n_comp)
    seen = pos + neg
    probed = np.bincount(labels[probe], minlength=n_comp)
    known = (seen >= np.maximum(WALL_MIN_POINTS, WALL_MIN_SHARE * probed)) & (
        np.maximum(pos, neg) >= WALL_AGREEMENT * seen
    )
    inward = known & (neg > pos)
    out[inward[labels]] *= -1.0
    return known


def orient_normals_consistent(
    P: np.ndarray, Ns: np.ndarray, k: int = 10, tree: cKDTree | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Give unsigned normals (m, 3) one consistent side per connected sheet of the scan,
    and the outward side where the scan shows it.

    The sign is propagated along a minimum spanning tree of the k-NN graph weighted by
    ``1 - |n_i . n_j|`` (Hoppe et al. 1992), over the pairs that lie on one smooth skin
    (:data:`TANGENT_EDGE`, :data:`TANGENT_PARALLEL`): each point takes the side of its
    parent. Where a sheet's points see another skin behind them (:func:`wall_sides`: a
    thin wall scanned from both sides) its side is outward, away from that skin, and its
    label is :data:`SIDE_KNOWN`. The side of every other sheet is arbitrary: the caller
    chooses it (e.g. by a vote against a posed nominal,
    :func:`qifreport.registration.deformable.result.orient_scan_normals`): on a wall deflected by
    more than half its thickness the nearest nominal skin is the other one, so the scan's
    own evidence comes first.

    Returns
    -------
    normals : (m, 3) unit normals, consistently signed within each sheet.
    labels : (m,) int sheet label of each point (>= 0), or :data:`SIDE_KNOWN`.
    """
    return _orient(P, Ns, k, tree or cKDTree(P))


def _orient(P: np.ndarray, Ns: np.ndarray, k: int, tree: cKDTree, near: list | None = None):
    """:func:`orient_normals_consistent`; ``near``: ``[nb, spacing, again]`` of
    :func:`_leading` for ``k + 1`` neighbours (``k`` as bounded here), emptied here, or
    None (queried here)."""
    m = len(P)
    k = min(k, m - 1)
    spacing = None
    if near is None or near[0].shape[1] != k + 1:
        G, pi, pj = _tangent_graph(P, Ns, k, tree)
    else:
        nb, spacing, again = near
        near.clear()
        again = np.flatnonzero(again)
        if len(again):
            nb[again] = tree.query(P[again], k=k + 1, workers=-1)[1].reshape(len(again), k + 1)
        G, pi, pj = _tangent_graph(P, Ns, k, tree, [nb])
        del nb, again
    T = _spanning_tree(G)
    del G
    n_comp, labels, pred = _tree_parents(T, m)
    del T
    out = Ns * _path_signs(Ns, pred)[:, None]
    known = _outward_sheets(P, out, labels, n_comp, tree, spacing)
    del spacing
    # the scraps between them (points at creases and rims, whose PCA normals no tangent
    # pair joins) take their known neighbours' side, not across a wall; once (a second
    # round, from scraps to scraps, turned more of the bracket's points inwards than right)
    ask = ~known[labels[pi]] & known[labels[pj]]
    agree = np.sign(np.einsum("ij,ij->i", out[pi[ask]], out[pj[ask]]))
    votes = np.bincount(labels[pi[ask]], weights=agree, minlength=n_comp)
    out[(votes < 0)[labels]] *= -1.0
    known |= votes != 0
    labels = np.where(known[labels], SIDE_KNOWN, labels)
    return out, labels


def one_skin_normals(
    P: np.ndarray,
    Ns: np.ndarray,
    prior: np.ndarray,
    radius: float,
    k: int = 10,
    tree: cKDTree | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Scan normals (m, 3) refitted on one skin within ``radius`` mm
    (:func:`refined_normals`), then signed consistently per sheet along them
    (:func:`orient_normals_consistent`), and each point's sheet label.

    The sheets are propagated over the refitted normals, not over the ``k``-nearest ones
    ``Ns`` came from: where the ``k`` nearest neighbours reach beyond a thin wall's
    thickness (a sparser scan of the same wall) their normals mix its two skins and turn by
    tens of degrees, few neighbour pairs then pass the same-skin test, and the scan falls
    apart into thousands of one-point sheets, each sided by its nearest nominal vertex,
    which on a wall deflected by more than half its thickness lies on the other skin.
    Refitted at a length of the part, the normals, and so the sheets, do not depend on the
    scan's density.

    Parameters
    ----------
    P : (m, 3) scan points, mm.  Ns : (m, 3) their unit normals, signed (the refit's first
    guess of each side).  prior : (m, 3) unit approximate normals (the nominal's, the scan
    seated on it).  radius : the refit's neighbourhood, mm, a length of the part.
    k : neighbours of the propagation graph.  tree : ``cKDTree(P)``.
    """
    tree = tree or cKDTree(P)
    Nr, near = _refined(P, Ns, prior, radius, tree, min(k, len(P) - 1) + 1)
    return _orient(P, Nr, k, tree, near)
