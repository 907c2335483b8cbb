"""The solids of a STEP part: what they are, and whether they overlap.

A file may hold several solids: an assembly of parts, a multi-body part, or (a common
export mistake) the same body several times, or one body inside another. An inspection is
of one part: :func:`solid_infos` lists the solids (index, name, faces, volume, box) for the
user to pick one (``--solid``), and :func:`overlapping_pairs` finds the solids that share
volume (nested or overlapping), which are never one part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SolidInfo", "overlapping_pairs", "pick_solid", "solid_infos", "solid_shape"]


@dataclass
class SolidInfo:
    """One solid of a part.

    Attributes
    ----------
    index : 0-based, the order of ``TopExp.MapShapes(shape, TopAbs_SOLID)``.
    name : its name in the file ('' when it has none).
    faces : number of its B-rep faces.  volume : mm^3 (NaN: OCCT cannot measure it, as for
        a tessellated solid, whose triangulated faces have no surface).
    lo, hi : (3,) its axis-aligned bounding box, mm.
    """

    index: int
    name: str
    faces: int
    volume: float
    lo: np.ndarray
    hi: np.ndarray

    def describe(self) -> str:
        """``0 "bracket" (120 faces, 35,200 mm^3)``."""
        name = f' "{self.name}"' if self.name else ""
        vol = f"{self.volume:,.0f} mm^3" if np.isfinite(self.volume) else "volume not measured"
        return f"{self.index}{name} ({self.faces} faces, {vol})"

    def to_dict(self) -> dict:
        return {
            "index": self.index,
            "name": self.name,
            "faces": self.faces,
            "volume_mm3": float(self.volume) if np.isfinite(self.volume) else None,
            "box_min_mm": [float(x) for x in self.lo],
            "box_max_mm": [float(x) for x in self.hi],
        }


def _solids(shape) -> list:
    from OCP.TopAbs import TopAbs_SOLID
    from OCP.TopExp import TopExp
    from OCP.TopTools import TopTools_IndexedMapOfShape

    smap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(shape, TopAbs_SOLID, smap)
    return [smap.FindKey(i) for i in range(1, smap.Size() + 1)]


def solid_shape(shape, index: int):
    """The ``index``-th solid of ``shape`` (0-based, :class:`SolidInfo`'s order)."""
    solids = _solids(shape)
    if not 0 <= index < len(solids):
        raise IndexError(f"solid {index} of {len(solids)}")
    return solids[index]


def solid_infos(shape, names: list[str] | None = None) -> list[SolidInfo]:
    """The solids of ``shape`` (``TopoDS_Shape``, mm), named by ``names`` (one per solid)."""
    from OCP.Bnd import Bnd_Box
    from OCP.BRepBndLib import BRepBndLib
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp
    from OCP.TopTools import TopTools_IndexedMapOfShape

    out = []
    for i, s in enumerate(_solids(shape)):
        props = GProp_GProps()
        try:
            BRepGProp.VolumeProperties_s(s, props)
            volume = abs(float(props.Mass()))
        except Exception:  # OCCT's Standard_Failure: faces without a surface (tessellated)
            volume = float("nan")
        box = Bnd_Box()
        BRepBndLib.Add_s(s, box)
        x0, y0, z0, x1, y1, z1 = box.Get()
        fmap = TopTools_IndexedMapOfShape()
        TopExp.MapShapes_s(s, TopAbs_FACE, fmap)
        out.append(
            SolidInfo(
                index=i,
                name=(names[i] if names and i < len(names) else "") or "",
                faces=fmap.Size(),
                volume=volume,
                lo=np.array([x0, y0, z0]),
                hi=np.array([x1, y1, z1]),
            )
        )
    return out


def overlapping_pairs(
    shape, infos: list[SolidInfo], rel: float = 1e-4
) -> list[tuple[int, int, float]]:
    """Pairs of solids that share volume: ``(i, j, common mm^3)`` with the common volume
    above ``rel`` of the smaller solid's (a solid inside another, the same body twice, or
    two bodies that interpenetrate). Only pairs whose boxes meet are intersected (OCCT's
    Boolean common)."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Common
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    solids = _solids(shape)
    out = []
    for a in range(len(infos)):
        for b in range(a + 1, len(infos)):
            A, B = infos[a], infos[b]
            if np.any(A.hi < B.lo) or np.any(B.hi < A.lo):
                continue
            if not (np.isfinite(A.volume) and np.isfinite(B.volume)):
                continue  # no volume to share (a tessellated solid)
            common = BRepAlgoAPI_Common(solids[a], solids[b])
            if not common.IsDone():
                continue
            props = GProp_GProps()
            BRepGProp.VolumeProperties_s(common.Shape(), props)
            v = abs(float(props.Mass()))
            if v > rel * min(A.volume, B.volume):
                out.append((a, b, v))
    return out


def pick_solid(infos: list[SolidInfo], selector: str) -> int:
    """The index of the solid ``selector`` names: its 0-based index, or its name (exact,
    then case-insensitive; a name shared by several solids is ambiguous).
    ``KeyError`` with the reason when it names none or several."""
    s = selector.strip()
    if s.isdigit():
        i = int(s)
        if i < len(infos):
            return i
        raise KeyError(f"no solid {i}: the file has {len(infos)} (0 to {len(infos) - 1})")
    for match in (lambda n: n == s, lambda n: n.lower() == s.lower()):
        hits = [x.index for x in infos if x.name and match(x.name)]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            raise KeyError(f"{len(hits)} solids are named {s!r}: pick one by index {hits}")
    raise KeyError(f"no solid named {s!r}")
