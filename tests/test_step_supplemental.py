"""Supplemental faces: B-rep faces in no solid (issue 20: real CAD nominals).

NIST CTC 04 carries a free disk (face #17460, the face of profile pmi #18835) lying on the
solid's plane with no shared edges; meshed with the solid it doubled the surface, every
scan point went to the solid's face and the tolerance scored 0 % of a perfect scan. Now the
free face is left out of the mesh and its tolerance is judged on the solid's triangles
beneath it. Real OCP on the real file; the zone logic on arrays.
"""

from __future__ import annotations

import numpy as np
import pytest

from qifreport.metrology.acceptance.bands import lay_bands, zone_vertex_areas
from qifreport.metrology.deviation.hygiene import mesh_hygiene
from qifreport.nominal import seat_faces
from qifreport.step.reader import read_step
from qifreport.step.supplemental import face_solids
from tests.conftest import shared_file

CTC04 = "step/nist/nist_ctc_04_asme1_ap242-e1.stp"


@pytest.fixture(scope="module")
def ctc04(nist_nominal):
    return read_step(shared_file(CTC04)), nist_nominal(CTC04.removeprefix("step/nist/"))


def test_free_faces_are_found_from_the_brep():
    """The faces in no solid, by STEP id: CTC 01 has none, CTC 04 the disk, CTC 02 two."""
    found = {}
    for name in ("ctc_01_asme1_ap242-e1", "ctc_02_asme1_ap242-e2", "ctc_04_asme1_ap242-e1"):
        part = read_step(shared_file(f"step/nist/nist_{name}.stp"))
        free = face_solids(part.shape, part.faces) < 0
        found[name[:6]] = sorted(int(part.face_step_ids[i]) for i in np.flatnonzero(free))
    assert found == {"ctc_01": [], "ctc_02": [3148, 3149], "ctc_04": [17460]}


def test_the_disk_leaves_the_mesh_and_its_tolerance_takes_its_footprint(ctc04):
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    step_part, (part, drawing) = ctc04
    disk = step_part.face_index()[17460]
    props = GProp_GProps()
    BRepGProp.SurfaceProperties_s(step_part.faces[disk], props)
    brep_area = props.Mass()  # 962.1 mm^2
    assert not np.any(part.face_id == disk)
    # the disk was the mesh's only open boundary and its second piece
    h = mesh_hygiene(part.V, part.F)
    assert h.boundary_edges == 0 and h.components == 1, h.describe()
    (sup,) = part.info["supplemental_faces"]
    assert sup["step_id"] == 17460 and len(sup["on_faces"]) == 1
    zone = next(z for z in drawing.zones if z.step_id == 18835)
    assert list(zone.faces) == [disk] and zone.triangles is not None
    bands = lay_bands(part.F, len(part.V), part.face_id, drawing.zones)
    k = next(i for i, z in enumerate(bands.zones) if z.step_id == 18835)
    area = zone_vertex_areas(part.V, part.F, bands.tri_masks[k]).sum()
    # the footprint is the solid's triangles whose centroids lie on the disk: the disk's
    # area to within the triangles along its rim (measured 949 of 962 mm^2)
    assert abs(area - brep_area) < 0.03 * brep_area, (area, brep_area)
    # beneath it, the solid's face keeps its own triangles (and so its own tolerances)
    assert np.all(np.isin(part.face_id[bands.tri_masks[k]], sup["on_faces"]))


def test_a_tolerance_on_a_face_off_the_solid_is_listed_not_dropped():
    """Arrays: a unit square (face 0, the solid), a free square on it (face 1) and one
    5 mm above it (face 2); a zone on each free face."""
    from qifreport.metrology.acceptance.bands import ToleranceZone

    sq = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], float)
    grid = np.array([[x, y, 0.0] for y in np.linspace(0, 10, 11) for x in np.linspace(0, 10, 11)])
    Fs = []
    for j in range(10):
        for i in range(10):
            a = j * 11 + i
            Fs += [[a, a + 1, a + 12], [a, a + 12, a + 11]]
    on = sq * [0.3, 0.3, 1] + [2, 2, 0]  # a 3 x 3 mm patch lying on the solid
    off = sq + [0, 0, 5]
    V = np.vstack([grid, on, off])
    n = len(grid)
    F = np.array(
        Fs + [[n, n + 1, n + 2], [n, n + 2, n + 3], [n + 4, n + 5, n + 6], [n + 4, n + 6, n + 7]]
    )
    face_id = np.array([0] * len(Fs) + [1, 1, 2, 2])
    free = np.array([False, True, True])

    def zone(face, key):
        return ToleranceZone(
            key, key, "surface_profile", 0.2, -0.1, 0.1, np.array([face]), "pmi", step_id=100 + face
        )

    V2, F2, fid2, zones, skipped, sup = seat_faces(
        V,
        F,
        face_id,
        np.where(free, -1, 0),
        None,
        [zone(1, "T1"), zone(2, "T2")],
        [],
        np.array([10, 11, 12]),
        1e-6,
    )
    assert len(F2) == len(Fs) and set(fid2) == {0} and len(V2) == len(grid)
    (t1,) = zones
    assert t1.key == "T1" and 4 <= len(t1.triangles) <= 24  # the 3 x 3 mm patch's cells
    (t2,) = skipped
    assert t2.step_id == 102 and "#12" in t2.reason and "off the part's solid" in t2.reason
    assert [s["footprint_area_mm2"] > 0 for s in sup] == [True, False]
    # the same faces, the square above now a face of a second solid, and solid 0 picked:
    # its tolerance is on the other solid, listed as such; its triangles leave the mesh
    V2, F2, fid2, zones, skipped, sup = seat_faces(
        V,
        F,
        face_id,
        np.array([0, -1, 1]),
        0,
        [zone(1, "T1"), zone(2, "T2")],
        [],
        np.array([10, 11, 12]),
        1e-6,
    )
    assert len(F2) == len(Fs) and [z.key for z in zones] == ["T1"]
    (t2,) = skipped
    assert "on solid 1, not on the solid inspected (0)" in t2.reason
    assert len(sup) == 1 and sup[0]["footprint_area_mm2"] > 0


def test_a_complex_rational_b_spline_circle_is_sampled_on_its_circle():
    """I-DEAS writes a circle as a complex instance (BOUNDED_CURVE, B_SPLINE_CURVE,
    B_SPLINE_CURVE_WITH_KNOTS, RATIONAL_B_SPLINE_CURVE, ...): its B_SPLINE_CURVE part has no
    name, so its degree is the first parameter (read as the second, ``int()`` of the point
    list stopped ``pmi`` with a TypeError). A curve that cannot be read is not located."""
    from qifreport.step.brep_geometry import FaceLocator
    from qifreport.step.p21 import P21Model, Ref
    from qifreport.step.units import MeasureReader

    pts = [(1.5, 0.5), (2.366025403784449, 0.5), (1.933012701892205, 1.25), (1.5, 2.0)]
    pts += [(1.066987298107795, 1.25), (0.633974596215551, 0.5), (1.5, 0.5)]
    body = "".join(
        f"#{10 + i}=CARTESIAN_POINT('',({x!r},{y!r},0.0));" for i, (x, y) in enumerate(pts)
    )
    refs = ",".join(f"#{10 + i}" for i in range(len(pts)))
    body += (
        f"#30=(BOUNDED_CURVE()B_SPLINE_CURVE(2,({refs}),.CIRCULAR_ARC.,.T.,.U.)"
        "B_SPLINE_CURVE_WITH_KNOTS((3,2,2,3),(0.0,0.33333333333333,0.66666666666667,1.0),"
        ".UNSPECIFIED.)CURVE()GEOMETRIC_REPRESENTATION_ITEM()"
        "RATIONAL_B_SPLINE_CURVE((1.0,0.5,1.0,0.5,1.0,0.5,1.0))REPRESENTATION_ITEM('E13'));"
        "#31=VERTEX_POINT('',#10);#32=VERTEX_POINT('',#13);"
        # the same curve written with a wrong parameter count: not located, no exception
        f"#33=(BOUNDED_CURVE()B_SPLINE_CURVE(({refs}))B_SPLINE_CURVE_WITH_KNOTS((3,2,2,3))"
        "CURVE()REPRESENTATION_ITEM('bad'));"
    )
    locator = FaceLocator(MeasureReader(P21Model.from_text(f"DATA;{body}ENDSEC;")))
    piece = locator.curve(Ref(30))
    r = np.linalg.norm(piece.points[:, :2] - [1.5, 1.0], axis=1)
    assert (
        len(piece.points) > 20
        and np.allclose(r, 0.5, atol=1e-9)
        and np.allclose(piece.points[:, 2], 0)
    )
    assert locator.curve(Ref(33)) is None
