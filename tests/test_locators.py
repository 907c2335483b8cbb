"""A locator on a narrow face read from its patch (metrology.locators): the free state moved
the face across half its own width; the neighbouring faces place the patch."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from qifreport.metrology.restraint.locators import patch_offset
from qifreport.registration.mesh import face_normals
from qifreport.registration.normals import pca_normals

WALL = 1.8  # mm: a panel's end face


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


@pytest.mark.parametrize(
    ("t", "angle"),
    [((0.15, 0.0, 0.9), 0.0), ((-0.3, 0.05, -0.8), 0.01), ((0.0, 0.0, 0.0), -0.015)],
)
def test_the_patch_reads_a_narrow_face_moved_across_its_width(t, angle):
    box = trimesh.creation.box(extents=(40.0, 30.0, WALL))
    V, F = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=1.5)
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    Nt = face_normals(V, F)
    c = np.array([20.0, 0.0, 0.0])  # the locator, on the end face x = +20, along x
    n0 = np.array([1.0, 0.0, 0.0])
    R, t = _rot_y(angle), np.asarray(t)
    moved = trimesh.Trimesh(V @ R.T + t, F, process=False)
    rng = np.random.default_rng(0)
    P, tri = trimesh.sample.sample_surface(moved, 60_000, seed=1)
    P = P + rng.normal(0.0, 0.01, (len(P), 1)) * moved.face_normals[tri]
    Ns = pca_normals(P, 12)
    Ns *= np.sign(np.einsum("ij,ij->i", Ns, moved.face_normals[tri]))[:, None]
    truth = float((R @ c + t - c) @ n0)
    got = patch_offset(V, F, Nt, P, Ns, c, n0, radius=15.0, gate=3.0)
    assert got == pytest.approx(truth, abs=0.02), (got, truth)


def test_an_unseen_patch_is_not_read():
    box = trimesh.creation.box(extents=(40.0, 30.0, WALL))
    V, F = np.asarray(box.vertices, float), np.asarray(box.faces, np.int64)
    P = np.array([[-20.0, 0.0, 0.0]] * 5) + np.arange(5)[:, None] * 0.1  # far side only
    Ns = np.tile([-1.0, 0.0, 0.0], (5, 1))
    got = patch_offset(
        V, F, face_normals(V, F), P, Ns, np.array([20.0, 0, 0]), [1, 0, 0], 15.0, 3.0
    )
    assert np.isnan(got)
