"""STEP reading through OCP and tessellation with face ids, on the real NIST exports."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import NIST, shared_file


@pytest.fixture(scope="module")
def ctc01():
    from qifreport.step.reader import read_step

    return read_step(shared_file("step/nist/" + NIST[0]), pmi=False)


@pytest.mark.parametrize("name", NIST)
def test_every_face_maps_to_its_step_entity(name):
    """Each B-rep face is traced back to an ADVANCED_FACE record of the file text."""
    import re

    from qifreport.step.reader import read_step

    path = shared_file("step/nist/" + name)
    part = read_step(path, pmi=False)
    assert part.n_solids >= 1
    assert np.all(part.face_step_ids >= 0), "some faces lost their STEP entity id"
    assert len(set(part.face_step_ids.tolist())) == len(part.faces)
    text = path.read_text(encoding="latin-1")
    faces_in_text = {int(m) for m in re.findall(r"#(\d+)\s*=\s*ADVANCED_FACE\s*\(", text)}
    assert set(part.face_step_ids.tolist()) <= faces_in_text


def test_tessellation_carries_face_ids_and_is_welded(ctc01):
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    from qifreport.registration.mesh import boundary_vertices
    from qifreport.step.tessellate import tessellate

    m = tessellate(ctc01.shape, ctc01.faces)
    assert m.face_id.shape == (len(m.F),)
    assert set(np.unique(m.face_id)) == set(range(len(ctc01.faces)))
    # the per-face triangulations are welded into one closed surface (CTC 01 is a solid)
    assert int(np.sum(boundary_vertices(m.F, len(m.V)))) == 0
    # vertices on face boundaries know every face around them
    vf = m.vertex_faces()
    assert sum(len(f) >= 2 for f in vf) > 0.2 * len(vf) or sum(len(f) >= 2 for f in vf) > 500
    # the mesh area matches the exact B-rep area within the chord error
    props = GProp_GProps()
    BRepGProp.SurfaceProperties_s(ctc01.shape, props)
    area_mesh = (
        0.5
        * np.linalg.norm(
            np.cross(m.V[m.F[:, 1]] - m.V[m.F[:, 0]], m.V[m.F[:, 2]] - m.V[m.F[:, 0]]), axis=1
        ).sum()
    )
    assert abs(area_mesh - props.Mass()) / props.Mass() < 5e-3
    # per-face areas too: face 0's triangles vs its exact area
    for k in (0, len(ctc01.faces) // 2):
        p = GProp_GProps()
        BRepGProp.SurfaceProperties_s(ctc01.faces[k], p)
        sel = m.F[m.face_id == k]
        a = (
            0.5
            * np.linalg.norm(
                np.cross(m.V[sel[:, 1]] - m.V[sel[:, 0]], m.V[sel[:, 2]] - m.V[sel[:, 0]]), axis=1
            ).sum()
        )
        assert abs(a - p.Mass()) / p.Mass() < 2e-2


def test_max_edge_bounds_edges_and_keeps_vertices_on_the_surface(ctc01):
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
    from OCP.BRepExtrema import BRepExtrema_DistShapeShape
    from OCP.gp import gp_Pnt

    from qifreport.registration.mesh import edges
    from qifreport.step.tessellate import tessellate

    m = tessellate(ctc01.shape, ctc01.faces, max_edge=8.0)
    E = edges(m.F)
    L = np.linalg.norm(m.V[E[:, 0]] - m.V[E[:, 1]], axis=1)
    assert L.max() <= 8.0 + 1e-9
    # sampled vertices lie within the deflection of their own B-rep face
    rng = np.random.default_rng(0)
    for t in rng.choice(len(m.F), 40, replace=False):
        v = m.V[m.F[t, 0]]
        d = BRepExtrema_DistShapeShape(
            BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, v))).Vertex(), ctc01.faces[m.face_id[t]]
        )
        assert d.Value() <= m.deflection * 1.01 + 1e-6


def test_inch_file_is_converted_to_mm():
    """FTC 06 is an inch file: OCP's geometry comes back in mm (12 in = 304.8 mm)."""
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import tessellate

    part = read_step(shared_file("step/nist/nist_ftc_06_asme1_ap242-e1.stp"), pmi=False)
    m = tessellate(part.shape, part.faces)
    ext = np.ptp(m.V, axis=0)
    assert abs(ext.max() - 304.8) < 0.5


def test_not_a_step_file_is_an_input_error(tmp_path):
    from qifreport.errors import InputError
    from qifreport.step.reader import read_step

    bad = tmp_path / "x.step"
    bad.write_text("solid nothing\nendsolid\n")
    with pytest.raises(InputError, match="not a STEP"):
        read_step(bad)
    trunc = tmp_path / "t.step"
    trunc.write_text(
        "ISO-10303-21;\nHEADER;\nENDSEC;\nDATA;\n#1=CARTESIAN_POINT('',(0.,0.,0.));\n"
        "ENDSEC;\nEND-ISO-10303-21;\n"
    )
    with pytest.raises(InputError, match="no (transferable )?shape|no surface"):
        read_step(trunc)
