"""A small B-rep geometry kernel: the faces that carry, bound or share the axis of geometry.

AP242 files often associate datum targets, axes, thread cylinders or dimension origins with
geometry that is not a face: isolated CARTESIAN_POINTs, TRIMMED_CURVEs, COMPOSITE_CURVEs,
GEOMETRIC_CURVE_SETs, EDGE_CURVEs. :class:`FaceLocator` samples such items (lines, conics,
B-splines, polylines, placements), reads the analytic surfaces (plane, cylinder, cone, sphere,
torus) and sampled boundaries of the B-rep's faces, and finds the faces carrying the samples, the
faces an edge bounds, or the rotational faces coaxial with a circle or an axis line.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from .instance_graph import refs_of, unwrap_typed
from .p21 import Entity, Enum, Ref, Typed
from .units import MeasureReader

log = logging.getLogger(__name__)

__all__ = ["FACE_TYPES", "FaceLocator"]

#: topological faces accepted as targets of a face association (with AP242's triangulated
#: faces, the faces of a tessellated part)
FACE_TYPES = frozenset(
    {
        "ADVANCED_FACE",
        "FACE_SURFACE",
        "FACE",
        "ORIENTED_FACE",
        "SUBFACE",
        "CONNECTED_FACE_SUB_SET",
        "TRIANGULATED_FACE",
        "COMPLEX_TRIANGULATED_FACE",
    }
)

_ROTATIONAL = ("cylinder", "cone", "sphere", "torus")
_ANGLE_STEP = math.radians(10.0)  # arc sampling step
_SPLINE_SAMPLES = 24
_LINE_SAMPLES = 9  # so that a line target whose ends touch face boundaries has inner samples


@dataclass
class _Piece:
    """Sample points of one geometric item, with its axis when it is a circle or a line."""

    points: np.ndarray  # (k, 3)
    circle: tuple[np.ndarray, np.ndarray, float] | None = None  # centre, normal, radius
    line: tuple[np.ndarray, np.ndarray] | None = None  # point, unit direction


@dataclass
class _Surface:
    """An analytic face surface in the shape's length unit."""

    face: int
    kind: str  # 'plane', 'cylinder', 'cone', 'sphere', 'torus' or 'other'
    origin: np.ndarray
    z: np.ndarray
    x: np.ndarray
    radius: float = 0.0
    minor: float = 0.0
    semi_angle: float = 0.0
    same_sense: bool = True

    @property
    def y(self) -> np.ndarray:
        return np.cross(self.z, self.x)

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Distance of points ``p`` (k, 3) to the (untrimmed) surface."""
        d = p - self.origin
        h = d @ self.z
        if self.kind == "plane":
            return np.abs(h)
        rho = np.linalg.norm(d - np.outer(h, self.z), axis=1)
        if self.kind == "cylinder":
            return np.abs(rho - self.radius)
        if self.kind == "cone":
            t = math.tan(self.semi_angle)
            return np.abs(rho - self.radius - h * t) * math.cos(self.semi_angle)
        if self.kind == "sphere":
            return np.abs(np.linalg.norm(d, axis=1) - self.radius)
        if self.kind == "torus":
            return np.abs(np.hypot(rho - self.radius, h) - self.minor)
        return np.full(len(p), np.inf)

    def uv(self, p: np.ndarray) -> np.ndarray:
        """Surface coordinates (u periodic in radians for rotational surfaces)."""
        d = p - self.origin
        a, b, h = d @ self.x, d @ self.y, d @ self.z
        if self.kind == "plane":
            return np.column_stack([a, b])
        u = np.arctan2(b, a)
        if self.kind == "sphere":
            r = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
            return np.column_stack([u, np.arcsin(np.clip(h / r, -1.0, 1.0))])
        return np.column_stack([u, h])

    def radius_at(self, h: float) -> float:
        if self.kind == "cone":
            return self.radius + h * math.tan(self.semi_angle)
        return self.radius


def _crossings(uv: np.ndarray, segments: list[np.ndarray], periodic: bool) -> np.ndarray:
    """Even-odd count of boundary crossings of the rays from ``uv`` towards +v."""
    count = np.zeros(len(uv), dtype=int)
    for seg in segments:
        if len(seg) < 2:
            continue
        u1, v1 = seg[:-1, 0], seg[:-1, 1]
        u2, v2 = seg[1:, 0], seg[1:, 1]
        du = u2 - u1
        if periodic:
            du = (du + math.pi) % (2.0 * math.pi) - math.pi
        lo_u = np.where(du >= 0, u1, u1 + du)  # start of the span in increasing u
        span = np.abs(du)
        keep = span > 1e-15
        lo_u, span = lo_u[keep], span[keep]
        lo_v = np.where(du >= 0, v1, v2)[keep]
        hi_v = np.where(du >= 0, v2, v1)[keep]
        for i, (pu, pv) in enumerate(uv):
            a = pu - lo_u
            if periodic:
                a = a % (2.0 * math.pi)
            inside = (a >= 0) & (a < span)
            if not inside.any():
                continue
            t = a[inside] / span[inside]
            v = lo_v[inside] + t * (hi_v[inside] - lo_v[inside])
            count[i] += int(np.count_nonzero(v > pv))
    return count % 2 == 1


def _segment_distance(p: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` (k, 3) to a 3D polyline (m, 3)."""
    if len(polyline) == 1:
        return np.linalg.norm(p - polyline[0], axis=1)
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    L2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    t = np.clip(np.einsum("kij,ij->ki", p[:, None, :] - a[None], ab) / L2, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2).min(axis=1)


class FaceLocator:
    """Locates the faces carrying (or coaxial with) points and curves of supplemental geometry.

    AP242 files often associate datum targets, axes, thread cylinders or dimension origins
    with geometry that is not a face: isolated CARTESIAN_POINTs, TRIMMED_CURVEs,
    COMPOSITE_CURVEs, GEOMETRIC_CURVE_SETs, EDGE_CURVEs. This class maps them to faces:

    * an EDGE_CURVE to the faces it bounds (for a circular edge only the coaxial rotational
      faces, i.e. the hole or boss rather than the surrounding plane);
    * any other item is sampled; a face *carries* a sample when the sample lies on its
      surface within ``tol`` and inside its boundary (even-odd ray test in surface
      coordinates, or within ``tol`` of the boundary);
    * a circle or line that no face carries is matched to the rotational faces (cylinder,
      cone, sphere, torus) whose axis it shares: a circle centred on the axis, a line on it.

    Coordinates are those of the shape representation (file length unit); supplemental
    geometry is assumed to share the coordinate system of the B-rep (true for single parts).
    """

    def __init__(self, reader: MeasureReader) -> None:
        self.r = reader
        self.m = reader.m
        self.angle_rad = math.radians(reader.context_angle.scale or 180.0 / math.pi)
        self._surfaces: dict[int, _Surface | None] = {}
        self._boundary: dict[int, list[np.ndarray]] = {}
        self._edge_samples: dict[int, np.ndarray] = {}
        self._all_faces: list[int] | None = None
        pts = [self.point(v.params[1]) for v in self.m.by_type("VERTEX_POINT")]
        pts = [p for p in pts if p is not None]
        diag = float(np.ptp(np.array(pts), axis=0).max()) * math.sqrt(3) if pts else 1.0
        #: on-surface / on-axis tolerance, in the file's length unit
        self.tol = max(diag * 1e-5, 1e-9)
        self.diag = diag

    # ---- primitives ---------------------------------------------------------------------
    def point(self, ref: object) -> np.ndarray | None:
        """Coordinates of a CARTESIAN_POINT or VERTEX_POINT, ``None`` for anything else."""
        ent = self.r.get(ref)
        if ent is None:
            return None
        if ent.has("CARTESIAN_POINT"):
            coords = ent.part("CARTESIAN_POINT")[1]
            vals = [float(c) for c in coords] + [0.0] * (3 - len(coords))
            return np.array(vals[:3])
        if ent.has("VERTEX_POINT"):
            return self.point(ent.part("VERTEX_POINT")[1])
        return None

    def direction(self, ref: object, default: tuple = (0.0, 0.0, 1.0)) -> np.ndarray:
        """Unit vector of a DIRECTION or VECTOR, ``default`` when missing or null."""
        ent = self.r.get(ref)
        if ent is not None and ent.has("VECTOR"):
            return self.direction(ent.part("VECTOR")[1], default)
        if ent is not None and ent.has("DIRECTION"):
            vals = [float(c) for c in ent.part("DIRECTION")[1]] + [0.0] * 3
            v = np.array(vals[:3])
        else:
            v = np.array(default, dtype=float)
        n = np.linalg.norm(v)
        return v / n if n > 0 else np.array(default, dtype=float)

    def placement(self, ref: object) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Origin, z and x axes of an AXIS2_PLACEMENT_3D (x made orthogonal to z)."""
        ent = self.r.get(ref)
        if ent is None or not (ent.has("AXIS2_PLACEMENT_3D") or ent.has("AXIS2_PLACEMENT_2D")):
            return None
        p = ent.params
        origin = self.point(p[1])
        if origin is None:
            return None
        z = self.direction(p[2]) if len(p) >= 4 else np.array([0.0, 0.0, 1.0])
        x = self.direction(p[-1], (1.0, 0.0, 0.0)) if len(p) >= 3 else np.array([1.0, 0, 0])
        x = x - (x @ z) * z
        if np.linalg.norm(x) < 1e-9:
            x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
        return origin, z, x / np.linalg.norm(x)

    # ---- curves -------------------------------------------------------------------------
    def _conic(self, ent: Entity) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        p = ent.params
        pl = self.placement(p[1])
        if pl is None:
            raise ValueError(f"#{ent.id}: no placement")
        a = float(p[2])
        b = float(p[3]) if ent.has("ELLIPSE") and len(p) >= 4 else a
        return pl[0], pl[1], pl[2], a, b

    def _conic_points(self, conic: tuple, t0: float, t1: float) -> np.ndarray:
        c, z, x, a, b = conic
        y = np.cross(z, x)
        n = max(2, int(math.ceil(abs(t1 - t0) / _ANGLE_STEP)) + 1)
        t = np.linspace(t0, t1, n)
        return c + np.outer(a * np.cos(t), x) + np.outer(b * np.sin(t), y)

    def _conic_param(self, conic: tuple, q: np.ndarray) -> float:
        c, z, x, a, b = conic
        d = q - c
        return math.atan2((d @ np.cross(z, x)) / b, (d @ x) / a)

    def _spline(self, ent: Entity, n: int = _SPLINE_SAMPLES) -> np.ndarray:
        """Sample a (rational) B_SPLINE_CURVE_WITH_KNOTS over its whole parameter range.

        A simple instance's parameters are its name, degree, points, form, closed, self-
        intersecting, then the multiplicities and knots; a complex one's B_SPLINE_CURVE part
        holds degree, points, form, closed and self-intersecting (its name is in its
        REPRESENTATION_ITEM part), the knots in the B_SPLINE_CURVE_WITH_KNOTS part and the
        weights in a RATIONAL_B_SPLINE_CURVE part (I-DEAS writes circles so)."""
        if ent.parts is None:
            base = ent.params
            degree, pts = int(base[1]), base[2]
            mults, knots = base[6], base[7]
            weights = None
        else:
            base = ent.part("B_SPLINE_CURVE")
            degree, pts = int(base[0]), base[1]
            kp = ent.part("B_SPLINE_CURVE_WITH_KNOTS")
            mults, knots = kp[0], kp[1]
            wp = ent.part("RATIONAL_B_SPLINE_CURVE")
            weights = np.array([float(w) for w in wp[0]]) if wp else None
        ctrl = np.array([self.point(r) for r in refs_of(pts)], dtype=float)
        kv = np.repeat(np.array([float(k) for k in knots]), [int(m) for m in mults])
        if weights is not None and len(weights) == len(ctrl):
            ctrl = np.column_stack([ctrl * weights[:, None], weights])
        t = np.linspace(kv[degree], kv[len(kv) - degree - 1], n)
        out = np.array([_de_boor(degree, kv, ctrl, ti) for ti in t])
        if out.shape[1] == 4:
            out = out[:, :3] / out[:, 3:4]
        return out

    def curve(self, ref: object, trims: tuple[object, object] | None = None, sense: bool = True,
              ends: tuple[np.ndarray, np.ndarray] | None = None) -> _Piece | None:  # fmt: skip
        """Sample a curve, optionally trimmed by parameters or points (TRIMMED_CURVE)."""
        ent = self.r.get(ref)
        if ent is None:
            return None
        if ent.has("LINE"):
            p = ent.params
            q = self.point(p[1])
            vec = self.r.get(p[2])
            d = self.direction(p[2])
            mag = float(vec.params[2]) if vec is not None and vec.has("VECTOR") else 1.0
            if ends is not None:
                a, b = ends
            elif trims is not None:
                t0, t1 = (self._trim_param(tr, lambda x: float((x - q) @ d) / mag) for tr in trims)
                a, b = q + t0 * mag * d, q + t1 * mag * d
            else:
                a, b = q, q + mag * d
            pts = a + np.outer(np.linspace(0.0, 1.0, _LINE_SAMPLES), b - a)
            return _Piece(pts, line=(q, d))
        if ent.has("CIRCLE") or ent.has("ELLIPSE"):
            conic = self._conic(ent)
            if ends is not None:
                t0, t1 = (self._conic_param(conic, e) for e in ends)
                same = np.linalg.norm(ends[0] - ends[1]) < self.tol
            elif trims is not None:
                t0, t1 = (
                    self._trim_param(tr, lambda x: self._conic_param(conic, x), angle=True)
                    for tr in trims
                )
                same = False
            else:
                t0, t1, same = 0.0, 2.0 * math.pi, False
            if not sense:
                t0, t1 = t1, t0
            if same:
                t1 = t0 + 2.0 * math.pi
            else:
                while t1 <= t0 + 1e-12:
                    t1 += 2.0 * math.pi
                while t1 - t0 > 2.0 * math.pi + 1e-9:
                    t1 -= 2.0 * math.pi
            circle = (conic[0], conic[1], conic[3]) if conic[3] == conic[4] else None
            return _Piece(self._conic_points(conic, t0, t1), circle=circle)
        if ent.has("TRIMMED_CURVE"):
            p = ent.params
            return self.curve(
                p[1], (p[2], p[3]), bool(p[4].value) if isinstance(p[4], Enum) else True
            )
        if ent.has("B_SPLINE_CURVE_WITH_KNOTS"):
            try:
                pts = self._spline(ent)
            except (TypeError, ValueError, IndexError, AttributeError):
                # a spline written otherwise than the standard says: not located
                log.debug(
                    "B-spline curve #%s not sampled: parameters not as AP242 writes them", ref
                )
                return None
            if ends is not None:
                i0 = int(np.argmin(np.linalg.norm(pts - ends[0], axis=1)))
                i1 = int(np.argmin(np.linalg.norm(pts - ends[1], axis=1)))
                if i0 != i1:
                    lo, hi = sorted((i0, i1))
                    pts = pts[lo : hi + 1]
            return _Piece(pts)
        if ent.has("SURFACE_CURVE") or ent.has("SEAM_CURVE") or ent.has("INTERSECTION_CURVE"):
            return self.curve(ent.params[1], trims, sense, ends)
        if ent.has("POLYLINE"):
            pts = [self.point(r) for r in refs_of(ent.params[1])]
            return _Piece(np.array([q for q in pts if q is not None]))
        return None

    def _trim_param(self, trim: object, project, angle: bool = False) -> float:
        """A trimming select: PARAMETER_VALUE (preferred) or a CARTESIAN_POINT."""
        items = trim if isinstance(trim, tuple) and not isinstance(trim, Typed) else (trim,)
        for it in items:
            if isinstance(it, Typed) and it.type == "PARAMETER_VALUE":
                v = float(unwrap_typed(it)[0])
                return v * self.angle_rad if angle else v
        for it in items:
            q = self.point(it)
            if q is not None:
                return project(q)
        raise ValueError("no trimming value")

    def pieces(self, ref: Ref) -> list[_Piece]:
        """Sample an identified item (point, curve, curve set, placement)."""
        ent = self.r.get(ref)
        if ent is None:
            return []
        if ent.has("CARTESIAN_POINT") or ent.has("VERTEX_POINT"):
            q = self.point(ref)
            return [_Piece(q[None, :])] if q is not None else []
        if ent.has("AXIS2_PLACEMENT_3D"):
            pl = self.placement(ref)
            return [_Piece(pl[0][None, :])] if pl else []
        if ent.has("GEOMETRIC_CURVE_SET") or ent.has("GEOMETRIC_SET"):
            out = []
            for r in refs_of(ent.params[1]):
                out.extend(self.pieces(r))
            return out
        if ent.has("COMPOSITE_CURVE"):
            out = []
            for seg in refs_of(ent.params[1]):
                s = self.r.get(seg)
                if s is not None and len(s.params) >= 3:
                    out.extend(self.pieces(s.params[2]))
            return _merge_circles(out)
        if ent.has("EDGE_CURVE"):
            p = ent.params
            a, b = self.point(p[1]), self.point(p[2])
            ends = (a, b) if a is not None and b is not None else None
            piece = self.curve(p[3], sense=bool(p[4].value), ends=ends)
            return [piece] if piece is not None else []
        try:
            piece = self.curve(ref)
        except (ValueError, IndexError, TypeError) as exc:
            log.debug("geometry #%d not sampled: %s", ref.id, exc)
            return []
        return [piece] if piece is not None else []

    # ---- faces --------------------------------------------------------------------------
    def surface(self, face: int) -> _Surface | None:
        """The analytic surface of an ADVANCED_FACE (cached), ``None`` if not analytic."""
        if face in self._surfaces:
            return self._surfaces[face]
        s = None
        ent = self.r.get(Ref(face))
        try:
            if ent is not None and ent.has("ADVANCED_FACE"):
                p = ent.params
                s = self._make_surface(
                    face, p[2], bool(p[3].value) if isinstance(p[3], Enum) else True
                )
        except (ValueError, IndexError, TypeError) as exc:
            log.debug("face #%d surface not understood: %s", face, exc)
        self._surfaces[face] = s
        return s

    def _make_surface(self, face: int, ref: object, same_sense: bool) -> _Surface | None:
        ent = self.r.get(ref)
        if ent is None:
            return None
        kinds = {
            "PLANE": "plane", "CYLINDRICAL_SURFACE": "cylinder", "CONICAL_SURFACE": "cone",
            "SPHERICAL_SURFACE": "sphere", "TOROIDAL_SURFACE": "torus",
        }  # fmt: skip
        kind = next((k for t, k in kinds.items() if ent.has(t)), None)
        if kind is None:
            return None
        p = ent.params
        pl = self.placement(p[1])
        if pl is None:
            return None
        s = _Surface(face, kind, pl[0], pl[1], pl[2], same_sense=same_sense)
        if kind in ("cylinder", "cone", "sphere", "torus"):
            s.radius = float(p[2])
        if kind == "cone":
            s.semi_angle = float(p[3]) * self.angle_rad
        if kind == "torus":
            s.minor = float(p[3])
        return s

    def boundary(self, face: int) -> list[np.ndarray]:
        """Sampled 3D boundary polylines of a face (one per edge or vertex loop)."""
        if face in self._boundary:
            return self._boundary[face]
        out: list[np.ndarray] = []
        ent = self.r.get(Ref(face))
        for bound in refs_of(ent.params[1] if ent is not None else ()):
            b = self.r.get(bound)
            loop = self.r.get(b.params[1]) if b is not None and len(b.params) >= 2 else None
            if loop is None:
                continue
            if loop.has("VERTEX_LOOP"):
                q = self.point(loop.params[1])
                if q is not None:
                    out.append(q[None, :])
                continue
            for oe in refs_of(loop.params[1] if loop.has("EDGE_LOOP") else ()):
                o = self.r.get(oe)
                if o is None or len(o.params) < 4:
                    continue
                edge = o.params[3]
                if edge.id not in self._edge_samples:
                    pieces = self.pieces(edge)
                    self._edge_samples[edge.id] = pieces[0].points if pieces else np.empty((0, 3))
                pts = self._edge_samples[edge.id]
                if len(pts):
                    out.append(pts)
        self._boundary[face] = out
        return out

    def all_faces(self) -> list[int]:
        """Ids of every ADVANCED_FACE of the model."""
        if self._all_faces is None:
            self._all_faces = [e.id for e in self.m.by_type("ADVANCED_FACE")]
        return self._all_faces

    def carried_by(self, pts: np.ndarray) -> tuple[set[int], set[int]]:
        """Faces carrying the points: ``(strictly inside, on the boundary)``."""
        inside: set[int] = set()
        edge: set[int] = set()
        for face in self.all_faces():
            s = self.surface(face)
            if s is None:
                continue
            on = s.distance(pts) <= self.tol
            if not on.any():
                continue
            q = pts[on]
            bnd = self.boundary(face)
            if not bnd:
                continue
            near = np.zeros(len(q), dtype=bool)
            for poly in bnd:
                near |= _segment_distance(q, poly) <= self.tol
            if near.any():
                edge.add(face)
            rest = q[~near]
            if len(rest) and s.kind != "torus":
                segs = [s.uv(poly) for poly in bnd]
                if _crossings(s.uv(rest), segs, periodic=s.kind != "plane").any():
                    inside.add(face)
            elif len(rest):  # torus: no ray test; accept when inside the boundary's box
                lo = np.min([poly.min(axis=0) for poly in bnd], axis=0) - self.tol
                hi = np.max([poly.max(axis=0) for poly in bnd], axis=0) + self.tol
                if ((rest >= lo) & (rest <= hi)).all(axis=1).any():
                    inside.add(face)
        return inside, edge

    def coaxial(self, piece: _Piece) -> set[int]:
        """Rotational faces sharing the axis of a circle (or lying around an axis line)."""
        if piece.circle is not None:
            c, n, rc = piece.circle
            axis_pt, axis_dir, samples = c, n, c[None, :]
        elif piece.line is not None:
            axis_pt, axis_dir = piece.line
            samples, rc = piece.points, None
        else:
            return set()
        best: dict[int, float] = {}
        for face in self.all_faces():
            s = self.surface(face)
            if s is None or s.kind not in _ROTATIONAL:
                continue
            if np.linalg.norm(np.cross(s.z, axis_dir)) > 1e-4:
                continue
            off = axis_pt - s.origin
            if np.linalg.norm(off - (off @ s.z) * s.z) > max(self.tol, 1e-6 * self.diag) * 10:
                continue
            bnd = self.boundary(face)
            if not bnd:
                continue
            h = np.concatenate([(poly - s.origin) @ s.z for poly in bnd])
            hs = (samples - s.origin) @ s.z
            lo, hi = h.min() - 10 * self.tol, h.max() + 10 * self.tol
            if rc is not None:  # a circle: its plane must cut the face
                if not (lo <= hs[0] <= hi):
                    continue
                best[face] = abs(s.radius_at(float(hs[0])) - rc)
            else:  # an axis line: must overlap the face's axial extent substantially
                overlap = min(hi, hs.max()) - max(lo, hs.min())
                if overlap <= 0.5 * min(hi - lo, hs.max() - hs.min()):
                    continue
                best[face] = s.radius if s.kind != "sphere" else 0.0
        if not best:
            return set()
        closest = min(best.values())
        return {f for f, d in best.items() if d <= closest + 10 * self.tol}

    def edge_faces(self, edge: int) -> set[int]:
        """Faces bounded by an edge; for a circular edge only its coaxial rotational faces."""
        faces: set[int] = set()
        for oe in self.r.referrers_with(edge, ("ORIENTED_EDGE",)):
            for loop in self.r.referrers_with(oe.id, ("EDGE_LOOP",)):
                for bound in self.r.referrers_with(loop.id, ("FACE_BOUND", "FACE_OUTER_BOUND")):
                    for face in self.m.referrers(bound.id):
                        if FACE_TYPES.intersection(self.r.types(face)):
                            faces.add(face)
        pieces = self.pieces(Ref(edge))
        if faces and pieces and pieces[0].circle is not None:
            c, n, _ = pieces[0].circle
            rot = set()
            for f in faces:
                s = self.surface(f)
                if s is not None and s.kind in _ROTATIONAL:
                    off = c - s.origin
                    if (
                        np.linalg.norm(np.cross(s.z, n)) < 1e-4
                        and np.linalg.norm(off - (off @ s.z) * s.z) <= 10 * self.tol
                    ):
                        rot.add(f)
            if rot:
                return rot
        return faces

    def locate(self, ref: Ref) -> tuple[set[int], str]:
        """Faces for a non-face item and how they were found (``''`` when none)."""
        types = self.r.types(ref)
        if "EDGE_CURVE" in types:
            faces = self.edge_faces(ref.id)
            return faces, "bounded by the edge" if faces else ""
        try:
            pieces = self.pieces(ref)
        except (ValueError, IndexError, TypeError) as exc:
            log.debug("geometry #%d not sampled: %s", ref.id, exc)
            return set(), ""
        pieces = [pc for pc in pieces if len(pc.points)]
        carried = []
        for piece in pieces:
            inside, edge = self.carried_by(piece.points)
            carried.append(inside or edge)
        if pieces and all(carried):
            return set().union(*carried), "carrying the geometry"
        # some piece floats (an axis, a thread or a centre line): the item describes a
        # feature by its axis, so the coaxial rotational faces are meant
        coaxial: set[int] = set()
        for piece in pieces:
            coaxial |= self.coaxial(piece)
        if coaxial:
            return coaxial, "coaxial with the geometry"
        found = set().union(*carried) if carried else set()
        return found, "carrying part of the geometry" if found else ""


def _merge_circles(pieces: list[_Piece]) -> list[_Piece]:
    """Arcs of one circle (a COMPOSITE_CURVE of half circles) become one piece."""
    if len(pieces) < 2 or any(p.circle is None for p in pieces):
        return pieces
    c0, n0, r0 = pieces[0].circle
    for p in pieces[1:]:
        c, n, r = p.circle
        if np.linalg.norm(c - c0) > 1e-9 * max(1.0, r0) or abs(abs(n @ n0) - 1) > 1e-9 or r != r0:
            return pieces
    return [_Piece(np.concatenate([p.points for p in pieces]), circle=pieces[0].circle)]


def _de_boor(degree: int, knots: np.ndarray, ctrl: np.ndarray, t: float) -> np.ndarray:
    """Point of a B-spline at ``t`` (de Boor); ``ctrl`` may be homogeneous."""
    n = len(ctrl)
    k = int(np.searchsorted(knots, t, side="right") - 1)
    k = min(max(k, degree), n - 1)
    d = [ctrl[j + k - degree].copy() for j in range(degree + 1)]
    for r in range(1, degree + 1):
        for j in range(degree, r - 1, -1):
            i = j + k - degree
            denom = knots[i + degree + 1 - r] - knots[i]
            alpha = 0.0 if denom == 0 else (t - knots[i]) / denom
            d[j] = (1.0 - alpha) * d[j - 1] + alpha * d[j]
    return d[degree]
