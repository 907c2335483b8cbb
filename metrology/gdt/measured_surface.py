"""The part's measured surface as its features are judged on it: per B-rep face, in the
nominal frame, with the virtual fixture's displacement taken out.

Two samplings of one surface:

* the **scan points** themselves, carried back through the fixture's displacement at their
  closest point, with the B-rep face each lies on: a feature's form, size, orientation and
  location are read on them (a smoothed field would average a defect narrower than its
  smoothing away, and bias a small radius), those that judge the surface (outside the
  unscored bands along creases and rims, where a point may lie on the neighbouring face,
  and nearest one of the feature's own measured vertices, not at its rim) when enough do,
  else all on the feature (a face narrower than the band), their heights
  over the feature's nominal surface through an areal Gaussian filter of a cut-off stated
  in mm (:func:`filtered`);
* the **vertices** of the nominal mesh moved along their outward normal by their measured
  deviation (each a robust local fit of the scan points around it: a filtered surface, the
  one the profile zones are judged on, with its expanded uncertainty ``U``): a feature's
  reading on a surface a virtual fixture displaced (carried back through its displacement a
  point also slides along the surface) or where no scan points are kept (the free state of
  a held judgement), and its areal coverage (the share of its own vertices measured).

A face set's own vertices are those whose every triangle belongs to the set (a vertex on
an edge to another face is that face's too, and its deviation mixes both); its nominal
geometry is read from the triangles' corners with the B-rep's exact normals.

Lengths mm; ``V`` (n, 3), ``F`` (f, 3), ``P`` (m, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from qifreport.metrology.gdt.datums import DatumFeature, nominal_feature
from qifreport.registration.arrays import LabelIndex, unique_sorted
from qifreport.registration.mesh import bounding_diagonal

__all__ = ["FeatureSample", "MeasuredSurface"]

#: fewest measured vertices for a feature to be judged on its vertices (where it has no
#: scan points), and fewest judging scan points for it to be read on those alone (else on
#: all its points)
MIN_VERTICES = 12
#: a scan point is its labelled feature's when its distance from the feature's nominal
#: surface and its deviation from the part's agree within this, mm: the nominal feature's
#: fit to the mesh corners and the fixture's carry-back stay well inside it, a neighbouring
#: face's point near a crease does not (:func:`_own_points`)
OWN_SURFACE_MM = 0.01
#: cut-off of the areal Gaussian filter a feature's points are read through, mm: the
#: smallest of ISO 16610's usual cut-off series (0.8, 2.5, 8 mm), so that a defect 2 mm
#: wide (sigma 1 mm) keeps 98 % of its depth (:func:`filtered`)
CUTOFF_MM = 0.8
#: the nearest points the filter averages over (at 8 points/mm^2 they reach 1.1 mm, where
#: the weight is 3 % of the centre's)
FILTER_NEIGHBOURS = 32


@dataclass
class FeatureSample:
    """One feature's measured surface.

    Attributes
    ----------
    S : (k, 3) measured positions in the nominal frame, mm.
    U : (k,) their expanded uncertainty (k = 2), mm.
    source : ``'vertices'`` or ``'scan points'``.
    coverage : share of the feature's own vertices measured (None: it has none).
    nominal : the feature's nominal plane or cylinder (None: another surface).
    """

    S: np.ndarray
    U: np.ndarray
    source: str
    coverage: float | None
    nominal: DatumFeature | None


@dataclass
class MeasuredSurface:
    """The compliance-removed measured surface of a B-rep part (module docstring).

    Attributes
    ----------
    V, F : nominal mesh, mm.  face_id : (f,) B-rep face of each triangle (mesh face ids).
    corner_normals : (f, 3, 3) the B-rep's outward unit normals at each triangle's corners.
    dev : (n,) measured deviation of each vertex along its normal, mm (NaN: not scored).
    U : (n,) its expanded uncertainty, mm.
    P : (m, 3) scan points carried back into the nominal frame, mm.
    P_face : (m,) the mesh face each point lies on (-1: none).
    P_dev : (m,) each point's signed deviation, mm.  P_U : (m,) its expanded uncertainty.
    P_ok : (m,) bool, the points that judge the surface (outside the crease and rim bands);
        None: all.
    P_vertex : (m,) the nominal vertex nearest each point's closest point (-1: none); a
        feature is read on the points whose vertex is one of its own measured ones (its
        rim left out as its vertices' reading left it out); None: no such restriction.
    read_on_points : features are read on the scan points (the free state, a rigid
        restraint); False: on the vertices where enough are measured (a virtual fixture's
        surface: its displacement carries a point back along the surface too, by up to
        1.8 mm on the sample panel, past its face's rim).
    diagonal : the part's size, the diagonal of the box around ``V``, mm (derived): the
        bound of a physically plausible reading
        (:func:`~qifreport.metrology.gdt.characteristic_types.implausible`).
    """

    V: np.ndarray
    F: np.ndarray
    face_id: np.ndarray
    corner_normals: np.ndarray
    dev: np.ndarray
    U: np.ndarray
    P: np.ndarray
    P_face: np.ndarray
    P_dev: np.ndarray
    P_U: np.ndarray
    P_ok: np.ndarray | None = None
    P_vertex: np.ndarray | None = None
    read_on_points: bool = True

    def __post_init__(self) -> None:
        n = len(self.V)
        self.diagonal = bounding_diagonal(self.V)
        self._valence = np.bincount(self.F.ravel(), minlength=n)
        # the corners' normals summed per vertex, corner 0 of every triangle first, then 1
        # and 2 (each vertex's sum in that order)
        corner = self.F.T.ravel()
        Nc = np.asarray(self.corner_normals, dtype=np.float64).transpose(1, 0, 2).reshape(-1, 3)
        N = np.stack([np.bincount(corner, Nc[:, j], minlength=n) for j in range(3)], axis=1)
        self.N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)
        self._nominal: dict[tuple[int, ...], DatumFeature | None] = {}
        self._samples: dict[tuple, FeatureSample] = {}
        self._triangles = LabelIndex(self.face_id)
        self._points = LabelIndex(self.P_face)

    def triangles_on(self, faces) -> np.ndarray:
        """(k,) the ids, ascending, of the triangles on ``faces`` (mesh face ids)."""
        return self._triangles.of(faces)

    def points_on(self, faces) -> np.ndarray:
        """(m,) bool, the scan points labelled with one of ``faces``."""
        return self._points.mask(faces)

    def own_vertices(self, faces) -> np.ndarray:
        """Vertex ids whose every triangle lies on ``faces`` (mesh face ids)."""
        tri = self._triangles.of(faces)
        inside = np.bincount(self.F[tri].ravel(), minlength=len(self.V))
        return np.flatnonzero((inside > 0) & (inside == self._valence))

    def nominal(self, faces, label: str = "") -> DatumFeature | None:
        """The nominal plane or cylinder of ``faces`` (None: neither, or no triangle)."""
        key = tuple(sorted(int(f) for f in faces))
        if key not in self._nominal:
            tri = self._triangles.of(key)
            feat = None
            if len(tri):
                X = self.V[self.F[tri]].reshape(-1, 3)
                Nc = self.corner_normals[tri].reshape(-1, 3)
                # a cone's apex has no normal (the B-rep's is NaN there: a drill point)
                ok = np.isfinite(Nc).all(axis=1) & (np.linalg.norm(Nc, axis=1) > 0.5)
                X, Nc = X[ok], Nc[ok]
                try:
                    feat = nominal_feature(label, X, Nc)
                except ValueError:
                    feat = None
            self._nominal[key] = feat
        return self._nominal[key]

    def features(self, faces) -> list[np.ndarray]:
        """``faces`` split into single features: coplanar planes together, coaxial
        cylinders of one radius together (a hole split into two half faces), any other face
        alone; a pattern of holes or bosses gives one feature per member. File order of
        the first face of each."""
        tol = max(1e-4 * max(self.diagonal, 1.0), 1e-3)
        groups: list[tuple[list[int], DatumFeature | None]] = []
        for f in faces:
            g = self.nominal([int(f)])
            for members, h in groups:
                if g is not None and h is not None and _same_feature(g, h, tol):
                    members.append(int(f))
                    break
            else:
                groups.append(([int(f)], g))
        return [np.array(m, dtype=np.int64) for m, _ in groups]

    def sample(self, faces, label: str = "") -> FeatureSample:
        """The measured surface of ``faces``: their own vertices when enough were scored
        (:data:`MIN_VERTICES`), else the scan points on them (kept: asked again, the same
        object)."""
        key = (tuple(sorted(int(f) for f in faces)), label)
        if key not in self._samples:
            self._samples[key] = self._sample(faces, label)
        return self._samples[key]

    def _sample(self, faces, label: str) -> FeatureSample:
        own = self.own_vertices(faces)
        ok = own[np.isfinite(self.dev[own])]
        nominal = self.nominal(faces, label)
        coverage = len(ok) / len(own) if len(own) else None
        on = self._points.mask(faces)
        if not self.read_on_points and len(ok) >= MIN_VERTICES:
            S = self.V[ok] + self.dev[ok, None] * self.N[ok]
            return FeatureSample(S, self.U[ok], "vertices", coverage, nominal)
        if nominal is not None and on.any():
            on[on] = _own_points(self.P[on], self.P_dev[on], nominal)
        if on.any():
            judging = on if self.P_ok is None else on & self.P_ok
            if self.P_vertex is not None:  # as the feature's own vertices: not at its rim
                at = np.flatnonzero(judging)
                judging[at] = np.isin(self.P_vertex[at], ok)
            if judging.sum() >= MIN_VERTICES:
                on = judging
            S = self.P[on] if nominal is None else filtered(self.P[on], nominal)
            return FeatureSample(S, self.P_U[on], "scan points", coverage, nominal)
        if len(ok) >= MIN_VERTICES:
            S = self.V[ok] + self.dev[ok, None] * self.N[ok]
            return FeatureSample(S, self.U[ok], "vertices", coverage, nominal)
        return FeatureSample(self.P[on], self.P_U[on], "scan points", coverage, nominal)

    def vertex_deviation_near(
        self, faces, position: np.ndarray, radius: float, k: int
    ) -> np.ndarray:
        """Deviations of the ``k`` measured vertices of ``faces`` (any of their triangles)
        nearest ``position``, those within ``radius`` mm of it."""
        v = unique_sorted(self.F[self._triangles.of(faces)])
        v = v[np.isfinite(self.dev[v])]
        d = np.linalg.norm(self.V[v] - np.asarray(position, dtype=np.float64), axis=1)
        near = np.argsort(d)[:k]
        return self.dev[v[near]][d[near] <= radius]

    def point_deviation_near(self, faces, position: np.ndarray, radius: float) -> np.ndarray:
        """Deviations (k,) of the scan points on ``faces`` within ``radius`` mm of
        ``position`` (nominal frame)."""
        on = self._points.of(faces)
        d = np.linalg.norm(self.P[on] - np.asarray(position, dtype=np.float64), axis=1)
        return self.P_dev[on][d <= radius]


def nominal_distance(P: np.ndarray, feat: DatumFeature) -> np.ndarray:
    """(m,) signed distance, mm, of points ``P`` (m, 3) from a nominal feature's surface,
    positive outside the material: a plane's (along its outward normal), a cylinder's or
    sphere's (radial), a cone's (across its surface)."""
    X = np.asarray(P, dtype=np.float64) - feat.origin
    if feat.kind == "plane":
        return X @ feat.direction
    if feat.kind == "sphere":
        d = np.linalg.norm(X, axis=1) - feat.radius
    else:
        z = X @ feat.direction
        rho = np.linalg.norm(X - np.outer(z, feat.direction), axis=1)
        if feat.kind == "cone":
            d = rho * np.cos(feat.half_angle) - z * np.sin(feat.half_angle)
        else:
            d = rho - feat.radius
    return -d if feat.internal else d


def nominal_normal(P: np.ndarray, feat: DatumFeature) -> np.ndarray:
    """(m, 3) outward unit normal of a nominal feature's surface under points ``P`` (m, 3):
    the gradient of :func:`nominal_distance`."""
    X = np.asarray(P, dtype=np.float64) - feat.origin
    if feat.kind == "plane":
        return np.broadcast_to(feat.direction, X.shape).copy()
    if feat.kind == "sphere":
        n = X
    else:
        z = X @ feat.direction
        n = X - np.outer(z, feat.direction)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        if feat.kind == "cone":
            n = np.cos(feat.half_angle) * n - np.sin(feat.half_angle) * feat.direction
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return -n if feat.internal else n


def filtered(P: np.ndarray, feat: DatumFeature, cutoff: float = CUTOFF_MM) -> np.ndarray:
    """The feature's points (m, 3) with their heights over its nominal surface passed
    through an areal Gaussian filter of cut-off ``cutoff`` mm (ISO 16610-61: the weight
    ``exp(-pi (r / (alpha cutoff))^2)``, ``alpha = sqrt(ln 2 / pi)``, half the amplitude
    of a ``cutoff`` wavelength kept), each moved along the nominal normal to its filtered
    height: the scanner's noise widens a zone read on the extremes of thousands of points
    less (about 8 sigma raw), a defect wider than the cut-off is kept (sigma 1 mm at 98 %,
    a 0.5 mm bump of sigma 3 mm whole). Over the points' :data:`FILTER_NEIGHBOURS` nearest within
    the kernel's reach; a point with none keeps its height."""
    from scipy.spatial import cKDTree

    P = np.asarray(P, dtype=np.float64)
    if len(P) < 2:
        return P.copy()
    h = nominal_distance(P, feat)
    a = np.sqrt(np.log(2.0) / np.pi) * cutoff
    k = min(FILTER_NEIGHBOURS, len(P))
    d, j = cKDTree(P).query(P, k=k, distance_upper_bound=1.5 * a)
    w = np.where(np.isfinite(d), np.exp(-np.pi * (d / a) ** 2), 0.0)
    hj = np.where(j < len(P), h[np.minimum(j, len(P) - 1)], 0.0)
    hf = np.einsum("ij,ij->i", w, hj) / w.sum(axis=1)
    return P + (hf - h)[:, None] * nominal_normal(P, feat)


def _own_points(P: np.ndarray, dev: np.ndarray, feat: DatumFeature) -> np.ndarray:
    """(m,) bool: the points (labelled on the feature's faces, deviations ``dev`` from the
    part's surface) that read on the feature's own surface the deviation they were given,
    within :data:`OWN_SURFACE_MM`. At a crease the closest chord may be the feature's while
    the point lies on the neighbouring face (within the chord's sag of the edge: a boss's
    wall read 0.13 mm above the plane it stands on); its deviation is the neighbour's, and
    on the feature it would be a phantom one."""
    return np.abs(nominal_distance(P, feat) - dev) <= OWN_SURFACE_MM


def _same_feature(g: DatumFeature, h: DatumFeature, tol: float) -> bool:
    """Two faces' geometries are one feature: coplanar planes (same side), or coaxial
    cylinders of one radius on the same side of the material (``tol`` mm)."""
    if g.kind != h.kind:
        return False
    if g.kind == "plane":
        return bool(
            g.direction @ h.direction > 1 - 1e-6 and abs((h.origin - g.origin) @ g.direction) < tol
        )
    if g.kind == "sphere":
        return bool(
            np.linalg.norm(g.origin - h.origin) < tol
            and abs(g.radius - h.radius) < tol
            and g.internal == h.internal
        )
    if g.kind == "cone":
        return bool(
            g.direction @ h.direction > 1 - 1e-6
            and np.linalg.norm(g.origin - h.origin) < tol
            and abs(g.half_angle - h.half_angle) < 1e-4
            and g.internal == h.internal
        )
    if abs(g.direction @ h.direction) < 1 - 1e-6 or g.internal != h.internal:
        return False
    d = h.origin - g.origin
    across = d - (d @ g.direction) * g.direction
    return bool(np.linalg.norm(across) < tol and abs(g.radius - h.radius) < tol)
