"""Generate the demo inputs in samples/ (deterministic; re-run to regenerate).

Mesh nominal (the fallback input, with ``--tolerance``):

* ``shell_nominal.ply``: the 170 x 110 mm doubly curved thin shell (8,436 vertices).
* ``shell_scan.ply``: a simulated free-state scan of it: analytic compliance at 2 % of the
  diagonal (~4 mm), 3 views, 0.02 mm range noise, clamp dropout. Conforming at +/-0.5 mm.
* ``shell_scan_defect.ply``: the same with a 1.0 mm / sigma 7 mm Gaussian bump: fails the
  region criterion at +/-0.5 mm.

STEP nominal with semantic PMI (the product's main input):

* ``panel.step``: the 160 x 100 mm cover of :mod:`make_step_sample` (AP242, datums A|B|C,
  surface profile 1.0 mm on every face, 0.5 mm on the crown's outer skin, flatness 0.2 mm
  on the flanges).
* ``panel_scan.ply``: its free state, made by the part's own elasticity
  (:func:`panel_target_warp`: a truth model held at the datum targets its drawing's
  restraint note names, A2 and A3 lifted 1 mm: a flange twist), seen by 3 views from above
  and 3 from below (the part turned over: the 1.0 mm profile applies to every face, so both
  skins must be measured), 0.02 mm noise. Out of tolerance free, conforming held as the
  drawing says (at those targets, within its 20 N per target; the drawing states ABS).
* ``panel_scan_defect.ply``: the same with a 0.45 mm / sigma 6 mm bump on the crown: out of
  the 0.5 mm skin profile (T2, +/-0.25) over about 100 mm^2, inside the 1.0 mm one (T1).
* ``panel_scan_warped.ply``: a free state made by the part's own elasticity
  (:mod:`qifreport.simulate.physical`): the panel held at the clamps of
  ``panel_clamps.csv`` (hand-written) with A2 lifted 1.2 mm and A4 pressed 0.8 mm (a
  twist), on a truth model that is not the product's (tetrahedra at 1/60 of the diagonal
  against 1/40, Poisson's ratio 0.40 against ABS's 0.35; its pads the 5 mm the clamps
  have, as ``--pad-radius`` tells the product), scanned as the others. Restrained at
  those clamps it conforms (held within 6 um rms of nominal).

The demo scans were once made by an analytic field applied vertically, not a shape the
part's elasticity makes (holding it needed about 212 N on the product's model); it remains
:func:`panel_scan_set`'s default for a case without a ``warp``. They were then made by
forces on the targets and a press on the crown: a shape the drawing's restraint (the
targets) does not take back, so the part judged as its drawing says failed.

Usage: ``python samples/make_samples.py [OUTDIR]``
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

from qifreport.registration.mesh import vertex_normals
from qifreport.simulate.cases import make_case
from qifreport.simulate.defects import gaussian_bump
from qifreport.simulate.deform import analytic_deformation
from qifreport.simulate.scanner import ScanSpec, turntable_views, virtual_scan
from qifreport.simulate.shapes import thin_shell

SEED = 1
#: tessellation edge for the simulation (mm); the scan does not depend on the inspection mesh
PANEL_EDGE = 2.5
#: defect centre on the crown (mm, nominal frame)
PANEL_DEFECT_AT = (25.0, 10.0, 9.3)


def panel_scan_set(
    step_path: Path, cases: list[dict], deflection: float | None = None
) -> list[np.ndarray]:
    """Simulated free-state scans of the STEP panel, one per case (float32, mm).

    Each case is a dict with ``warp`` (the free state's displacement, a function of points
    mm, :func:`panel_target_warp`; None: the analytic field of ``amplitude``, a fraction
    of the diagonal, default 0.015, and ``field_seed``, None: the default coefficients,
    applied vertically), ``scan_seed`` (noise and dropout,
    default :data:`SEED`), ``defect`` (None or ``(a, sigma)`` mm, on the crown at
    :data:`PANEL_DEFECT_AT` shifted by ``defect_shift`` mm in x), ``pose`` (None or a
    ``(R, t)`` applied to the points: a scan delivered in the scanner's frame) and
    ``both_sides`` (default True: views from above and below; False: from above only, the
    underside unmeasured). ``deflection``: the chord tolerance of the surface scanned, mm
    (None: the tessellator's default, whose chords on the crown lie up to about 0.1 mm
    inside its arc; the demo scans use 0.01 mm, so that their surface is the part's).
    """
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import tessellate

    part = read_step(step_path, pmi=False)
    m = tessellate(part.shape, part.faces, max_edge=PANEL_EDGE, deflection=deflection)
    V, F = m.V, m.F
    diag = float(np.linalg.norm(np.ptp(V, axis=0)))
    skin = np.unique(m.F[m.face_id == _skin_face(m)])
    out = []
    for c in cases:
        if c.get("warp") is not None:
            d = c["warp"](V)
        else:
            d = analytic_deformation(
                V,
                F,
                c.get("amplitude", 0.015) * diag,
                seed=c.get("field_seed"),
                direction=(0.0, 0.0, 1.0),
            )
        Vs = V + d
        if c.get("defect") is not None:
            at = np.array(PANEL_DEFECT_AT) + np.array([c.get("defect_shift", 0.0), 0.0, 0.0])
            dv = int(skin[np.argmin(np.linalg.norm(V[skin] - at, axis=1))])
            N = vertex_normals(Vs, F)
            Vs = Vs + gaussian_bump(Vs, N, Vs[dv], *c["defect"])
        views = turntable_views(both_sides=c.get("both_sides", True))
        spec = ScanSpec(directions=views, noise=0.02, seed=c.get("scan_seed", SEED))
        P = virtual_scan(Vs, F, spec).P
        if c.get("pose") is not None:
            R, t = c["pose"]
            P = P @ np.asarray(R).T + np.asarray(t)
        out.append(P.astype(np.float32))
    return out


#: the warped sample's clamp lifts (mm along the normal) and its truth model's settings
PANEL_LIFTS = {"A2": 1.2, "A4": -0.8}
TRUTH_EDGE_SHARE = 1.0 / 60.0
TRUTH_NU = 0.40
TRUTH_PAD = 5.0

#: the demo scans' free state: the panel held at the datum targets its drawing's restraint
#: note names (A1-A4 along the normal, B1 and C1-C2 along their axes) with A2 and A3 lifted
#: (a twist of the flanges, as a part warps after moulding), on the truth model
PANEL_TARGET_LIFTS = {"A2": 1.0, "A3": 1.0}
#: that free state's figures (:func:`panel_target_warp`, on the truth model): its strain
#: energy, mJ, and the equivalent force, N: twice it over the field's largest normal
#: correction at the inspection nominal's vertices, rigid motion removed
PANEL_WARP_ENERGY = 0.332
PANEL_WARP_FORCE = 1.02
#: the force each of the targets A1-A4 takes in that hold, N (the truth's pad reactions)
PANEL_TARGET_FORCE = 0.331


def truth_model(step_path: Path):
    """The panel's truth elastic model (tetrahedra at :data:`TRUTH_EDGE_SHARE` of the
    diagonal, Poisson's ratio :data:`TRUTH_NU`, ABS's modulus: not the product's model)."""
    from qifreport.registration.restraint.elastic import Material, elastic_model
    from qifreport.step.gmsh_mesh import gmsh_solid_mesh
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import shape_diagonal

    part = read_step(step_path, pmi=False)
    tets = gmsh_solid_mesh(part.shape, TRUTH_EDGE_SHARE * shape_diagonal(part.shape))
    return elastic_model(tets.X, tets.T, Material("truth", 2300.0, TRUTH_NU, 1.05e-9))


def _held_solution(step_path: Path, model, clamps: list, lifts: dict[str, float]):
    """The truth ``model`` held at ``clamps`` with ``lifts`` (mm along each one's first
    direction; :func:`qifreport.simulate.physical.held_free_solution`), on 5 mm pads."""
    from qifreport.metrology.deviation.closest import closest_points
    from qifreport.registration.mesh import face_normals
    from qifreport.restraint import boundary_normals
    from qifreport.simulate.physical import held_free_solution
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import tessellate

    part = read_step(step_path, pmi=False)
    m = tessellate(part.shape, part.faces, max_edge=PANEL_EDGE, deflection=0.01)
    _, tri, _ = closest_points(m.V, m.F, np.array([c.position for c in clamps]))
    sn = boundary_normals(model.X, model.T)
    return held_free_solution(
        model,
        clamps,
        face_normals(m.V, m.F)[tri],
        lifts,
        pad_radius=TRUTH_PAD,
        surface=np.linalg.norm(sn, axis=1) > 0,
        surface_normals=sn,
    )


def panel_target_warp(
    step_path: Path, lifts: dict[str, float] | None = None
) -> tuple[callable, dict]:
    """The demo panel's free state: the truth model (:func:`truth_model`) held at the datum
    targets of its drawing (``--clamps pmi``'s clamps) with ``lifts`` (default
    :data:`PANEL_TARGET_LIFTS`). Returns the displacement field (a function of points, mm)
    and its strain energy (``energy_mJ``)."""
    from qifreport.restraint import clamps_from_pmi

    model = truth_model(step_path)
    sol = _held_solution(
        step_path, model, list(clamps_from_pmi(step_path)), lifts or PANEL_TARGET_LIFTS
    )
    info = {"energy_mJ": float(sol.energy), "pad_forces_N": np.abs(sol.pad_forces).tolist()}

    def field(points: np.ndarray) -> np.ndarray:
        return model.displacement_at(sol, points)

    return field, info


def panel_warped_scan(step_path: Path, clamps_path: Path) -> np.ndarray:
    """The panel's elastic free state (module docstring), scanned (float32, mm)."""
    from qifreport.registration.restraint.clamps import parse_clamps
    from qifreport.registration.restraint.elastic import Material, elastic_model
    from qifreport.step.gmsh_mesh import gmsh_solid_mesh
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import tessellate

    part = read_step(step_path, pmi=False)
    # a fine chord (10 um): the scan must not carry the tessellation's own error
    m = tessellate(part.shape, part.faces, max_edge=PANEL_EDGE, deflection=0.01)
    V, F = m.V, m.F
    diag = float(np.linalg.norm(np.ptp(V, axis=0)))
    tets = gmsh_solid_mesh(part.shape, TRUTH_EDGE_SHARE * diag)
    model = elastic_model(tets.X, tets.T, Material("truth", 2300.0, TRUTH_NU, 1.05e-9))
    clamps = parse_clamps(clamps_path.read_text(encoding="utf-8"))
    sol = _held_solution(step_path, model, clamps, PANEL_LIFTS)
    Vs = V + model.displacement_at(sol, V)
    spec = ScanSpec(directions=turntable_views(both_sides=True), noise=0.02, seed=SEED)
    return virtual_scan(Vs, F, spec).P.astype(np.float32)


def panel_scans(step_path: Path, out: Path) -> None:
    names = ("panel_scan.ply", "panel_scan_defect.ply")
    warp, info = panel_target_warp(step_path)
    print(f"panel free state: {info['energy_mJ']:.3g} mJ of strain energy")
    scans = panel_scan_set(
        step_path, [{"warp": warp}, {"warp": warp, "defect": (0.45, 6.0)}], deflection=0.01
    )
    for name, P in zip(names, scans, strict=True):
        trimesh.PointCloud(P).export(out / name)
        print(f"{name}: {len(P)} points")


def _skin_face(m) -> int:
    """The crown's outer skin: the face with the largest upward-facing area."""
    from qifreport.registration.mesh import face_normals

    n = face_normals(m.V, m.F)
    a = 0.5 * np.linalg.norm(
        np.cross(m.V[m.F[:, 1]] - m.V[m.F[:, 0]], m.V[m.F[:, 2]] - m.V[m.F[:, 0]]), axis=1
    )
    up = np.bincount(m.face_id, weights=a * (n[:, 2] > 0.5), minlength=m.n_faces)
    return int(np.argmax(up))


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    V, F = thin_shell()
    trimesh.Trimesh(V, F, process=False).export(out / "shell_nominal.ply")
    for name, defect in (("shell_scan.ply", None), ("shell_scan_defect.ply", (1.0, 7.0))):
        case = make_case(V, F, generator="analytic", amplitude=0.02, defect=defect, seed=SEED)
        P = case.P.astype(np.float32)  # scanners deliver single precision
        trimesh.PointCloud(P).export(out / name)
        print(f"{name}: {len(P)} points")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from make_step_sample import build_sample

    build_sample(out / "panel.step")
    panel_scans(out / "panel.step", out)
    P = panel_warped_scan(out / "panel.step", Path(__file__).resolve().parent / "panel_clamps.csv")
    trimesh.PointCloud(P).export(out / "panel_scan_warped.ply")
    print(f"panel_scan_warped.ply: {len(P)} points")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent)
