"""Mesh quality of the two B-rep meshers: BRepMesh + long-edge bisection
(:func:`qifreport.step.tessellate.tessellate`, today's default) against gmsh
(:func:`qifreport.step.gmsh_mesh.gmsh_tessellate`), on ``samples/panel.step`` and every
NIST file in ``../shared/step/nist``.

Each (file, mesher) runs in a fresh child process (cold: imports, STEP read and the first
tessellation), then tessellates again in that process (warm; BRepMesh's stored triangulation
is cleaned first so it really meshes again). Per row:

* ``tri``: triangles; ``amin p1 / p50``: percentiles of each triangle's smallest angle
  (degrees); ``<5deg``: share of triangles with an angle under 5 degrees;
* ``dup``, ``nm``, ``open``: duplicate triangles, non-manifold edges, open boundary edges;
  ``pcs``: edge-connected pieces / the B-rep's own pieces (faces joined by shared edges);
* ``chord``: largest distance of sampled triangle centroids (up to 16 per face) to *their*
  B-rep face (OCP BRepExtrema; the per-face id is used, so it also checks the id map), in
  units of the deflection;
* ``fit rms / max``: distance of 20,000 points on the exact B-rep surfaces (area-uniform on
  a fine BRepMesh of a copy of the shape, each projected onto its face's exact surface) to the
  mesh (libigl point-mesh distance), mm, and the max in units of the deflection (``defl``,
  mm: 1e-3 of the diagonal, the chord height both meshers are asked to stay within);
* ``read``, ``tess``, ``warm``, ``prep``: seconds (STEP read; tessellation cold and warm;
  :func:`qifreport.metrology.prepared.prepare_part` with default parameters, with
  ``--prepare``); ``MiB``: the child's peak resident memory (``VmHWM``) after the cold
  tessellation, and of the warm one (the high-water mark reset through
  ``/proc/self/clear_refs`` before it).

A file that fails is a row saying why.

    python bench/mesh_quality.py [--prepare] [--timeout 900] [--json out.json] [files...]
    python bench/mesh_quality.py --table out.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
MESHERS = ("brepmesh", "gmsh")
N_FIT = 20_000


def _hwm_mib() -> float:
    for ln in Path("/proc/self/status").read_text().splitlines():
        if ln.startswith("VmHWM:"):
            return int(ln.split()[1]) / 1024.0
    return float("nan")


def _reset_hwm() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _mesh(part, mesher: str, max_edge: float):
    if mesher == "gmsh":
        from qifreport.step.gmsh_mesh import gmsh_tessellate

        return gmsh_tessellate(part.shape, part.faces, max_edge=max_edge)
    from qifreport.step.tessellate import tessellate

    return tessellate(part.shape, part.faces, max_edge=max_edge)


def _chord(part, mesh, per_face: int = 16) -> float:
    """Largest distance (mm) of sampled centroids of face k's triangles to OCP face k."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
    from OCP.BRepExtrema import BRepExtrema_DistShapeShape
    from OCP.gp import gp_Pnt

    cen = mesh.V[mesh.F].mean(axis=1)
    order = np.argsort(mesh.face_id, kind="stable")
    starts = np.searchsorted(mesh.face_id[order], np.arange(len(part.faces) + 1))
    worst = 0.0
    for k, face in enumerate(part.faces):
        tri = order[starts[k] : starts[k + 1]]
        if len(tri) == 0:
            continue
        pick = tri[np.linspace(0, len(tri) - 1, min(per_face, len(tri))).astype(np.int64)]
        for t in pick:
            v = BRepBuilderAPI_MakeVertex(gp_Pnt(*cen[t])).Vertex()
            d = BRepExtrema_DistShapeShape(v, face)
            if d.IsDone():
                worst = max(worst, d.Value())
    return worst


def _brep_points(shape, deflection: float, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) points on the exact B-rep surfaces, area-uniform, mm (independent of both
    meshers: a fine BRepMesh of a *copy* is only the area measure, each point is projected
    onto its face's exact surface)."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Copy
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.gp import gp_Pnt
    from OCP.ShapeAnalysis import ShapeAnalysis_Surface
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS
    from OCP.TopTools import TopTools_IndexedMapOfShape

    cp = BRepBuilderAPI_Copy(shape, True, False).Shape()
    BRepMesh_IncrementalMesh(cp, deflection / 5.0, False, 0.2, True)
    fmap = TopTools_IndexedMapOfShape()
    TopExp.MapShapes_s(cp, TopAbs_FACE, fmap)
    tris, owner = [], []
    for i in range(1, fmap.Size() + 1):
        face = TopoDS.Face_s(fmap.FindKey(i))
        loc = TopLoc_Location()
        tri = BRep_Tool.Triangulation_s(face, loc)
        if tri is None:
            continue
        trsf = loc.Transformation()
        P = np.array(
            [
                (lambda p: (p.X(), p.Y(), p.Z()))(tri.Node(j + 1).Transformed(trsf))
                for j in range(tri.NbNodes())
            ]
        )
        T = np.array([tri.Triangle(j + 1).Get() for j in range(tri.NbTriangles())]) - 1
        tris.append(P[T])
        owner.append(np.full(len(T), i))
    X = np.concatenate(tris)
    own = np.concatenate(owner)
    area = 0.5 * np.linalg.norm(np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(X), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    w = np.c_[1 - s, s * (1 - r2), s * r2]
    pts = np.einsum("ij,ijk->ik", w, X[pick])
    out = np.empty_like(pts)
    cache: dict[int, ShapeAnalysis_Surface] = {}
    for j, (p, fi) in enumerate(zip(pts, own[pick], strict=True)):
        sas = cache.get(int(fi))
        if sas is None:
            sas = cache[int(fi)] = ShapeAnalysis_Surface(
                BRep_Tool.Surface_s(TopoDS.Face_s(fmap.FindKey(int(fi))))
            )
        uv = sas.ValueOfUV(gp_Pnt(*p), 1e-7)
        q = sas.Value(uv)
        out[j] = (q.X(), q.Y(), q.Z())
    return out


def child(path: str, mesher: str, do_prepare: bool) -> dict:
    """One cold (file, mesher) measurement in this (fresh) process."""
    import igl

    t0 = time.perf_counter()
    from OCP.BRepTools import BRepTools

    from qifreport.step.gmsh_mesh import brep_pieces, mesh_stats
    from qifreport.step.reader import read_step
    from qifreport.step.tessellate import shape_diagonal

    t_import = time.perf_counter() - t0
    t0 = time.perf_counter()
    part = read_step(path, pmi=False)
    t_read = time.perf_counter() - t0
    diag = shape_diagonal(part.shape)
    max_edge = diag / 60.0
    t0 = time.perf_counter()
    mesh = _mesh(part, mesher, max_edge)
    t_tess = time.perf_counter() - t0
    mib_cold = _hwm_mib()
    row = {
        "faces": len(part.faces),
        "solids": part.n_solids,
        "import_s": t_import,
        "read_s": t_read,
        "tess_s": t_tess,
        "mib_cold": mib_cold,
        "vertices": len(mesh.V),
        "deflection": mesh.deflection,
        **mesh_stats(mesh.V, mesh.F),
    }
    row["brep_pieces"], row["brep_free_edges"] = brep_pieces(part.shape, part.faces)
    row["faces_meshed"] = int(len(np.unique(mesh.face_id)))
    row["chord_mm"] = _chord(part, mesh)
    pts = _brep_points(part.shape, mesh.deflection, N_FIT)
    d2, _, _ = igl.point_mesh_squared_distance(pts, mesh.V, mesh.F)
    d = np.sqrt(np.asarray(d2))
    row["fit_rms"] = float(np.sqrt(np.mean(d * d)))
    row["fit_max"] = float(d.max())
    if do_prepare:
        from qifreport.metrology.params import InspectionParams
        from qifreport.metrology.prepared import prepare_part

        t0 = time.perf_counter()
        try:
            prepare_part(mesh.V, mesh.F, InspectionParams())
            row["prep_s"] = time.perf_counter() - t0
        except Exception as exc:  # a row of figures even when the preparation fails
            row["prep_error"] = f"{type(exc).__name__}: {exc}"[:120]
    # warm: the same process meshes again (BRepMesh's stored triangulation removed first)
    BRepTools.Clean_s(part.shape)
    row["hwm_reset"] = _reset_hwm()
    t0 = time.perf_counter()
    _mesh(part, mesher, max_edge)
    row["warm_s"] = time.perf_counter() - t0
    row["mib_warm"] = _hwm_mib()
    return row


def _files(args) -> list[Path]:
    if args.files:
        return [Path(f) for f in args.files]
    return [ROOT / "samples" / "panel.step", *sorted((SHARED / "step" / "nist").glob("*.stp"))]


def _fmt(r: dict) -> str:
    if "error" in r:
        return f"{r['file']:<26} {r['mesher']:<8} FAILED: {r['error']}"
    prep = f"{r['prep_s']:6.1f}" if "prep_s" in r else "  FAIL" if "prep_error" in r else "     -"
    return (
        f"{r['file']:<26} {r['mesher']:<8} {r['triangles']:>8} {r['min_angle_p1']:6.2f} "
        f"{r['min_angle_p50']:6.2f} {100 * r['share_under_5deg']:6.2f} "
        f"{r['duplicate_triangles']:>6} {r['non_manifold_edges']:>6} {r['boundary_edges']:>5} "
        f"{r['pieces']:>3}/{r['brep_pieces']:<2} {r['deflection']:6.3f} "
        f"{r['chord_mm'] / r['deflection']:5.2f} {r['fit_rms']:7.4f} {r['fit_max']:7.4f} "
        f"{r['fit_max'] / r['deflection']:5.2f} {r['read_s']:5.2f} {r['tess_s']:6.2f} "
        f"{r['warm_s']:6.2f} {prep} {r['mib_cold']:6.0f} {r['mib_warm']:6.0f}"
    ) + (f"  prepare: {r['prep_error']}" if "prep_error" in r else "")


HEADER = (
    f"{'file':<26} {'mesher':<8} {'tri':>8} {'amin':>6} {'amin':>6} {'<5deg':>6} "
    f"{'dup':>6} {'nm':>6} {'open':>5} {'pcs':>6} {'defl':>6} {'chord':>5} {'fit':>7} "
    f"{'fit':>7} {'fit':>5} "
    f"{'read':>5} {'tess':>6} {'warm':>6} {'prep':>6} {'MiB':>6} {'MiB':>6}\n"
    f"{'':<26} {'':<8} {'':>8} {'p1':>6} {'p50':>6} {'%':>6} {'':>6} {'':>6} {'':>5} "
    f"{'mesh/B':>6} {'mm':>6} {'/defl':>5} {'rms mm':>7} {'max mm':>7} {'/defl':>5} "
    f"{'s':>5} {'cold s':>6} "
    f"{'s':>6} {'s':>6} {'cold':>6} {'warm':>6}"
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="*")
    ap.add_argument("--prepare", action="store_true", help="also time prepare_part")
    ap.add_argument("--timeout", type=float, default=900.0, help="per child, seconds")
    ap.add_argument("--json", type=Path, help="write the rows here")
    ap.add_argument("--meshers", default=",".join(MESHERS))
    ap.add_argument("--table", type=Path, help="print the table of an earlier --json and stop")
    ap.add_argument("--child", nargs=3, metavar=("FILE", "MESHER", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        path, mesher, out = args.child
        Path(out).write_text(json.dumps(child(path, mesher, args.prepare)))
        return 0
    if args.table:
        print(HEADER)
        for r in json.loads(args.table.read_text()):
            print(_fmt(r))
        return 0
    print(f"# mesh_quality {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC", flush=True)
    print(HEADER, flush=True)
    rows = []
    for path in _files(args):
        for mesher in args.meshers.split(","):
            r = {"file": path.name[:26], "mesher": mesher}
            with tempfile.NamedTemporaryFile(suffix=".json") as tmp:
                cmd = [sys.executable, __file__, "--child", str(path), mesher, tmp.name]
                if args.prepare:
                    cmd.append("--prepare")
                t0 = time.perf_counter()
                try:
                    p = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
                    if p.returncode != 0:
                        last = (p.stderr.strip().splitlines() or ["no message"])[-1]
                        r["error"] = f"exit {p.returncode}: {last[:160]}"
                    else:
                        r.update(json.loads(Path(tmp.name).read_text()))
                except subprocess.TimeoutExpired:
                    r["error"] = f"timed out after {args.timeout:.0f} s"
                r["wall_s"] = time.perf_counter() - t0
            rows.append(r)
            print(_fmt(r), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))
    bad = [r for r in rows if "error" in r]
    if bad:
        print(f"# {len(bad)} row(s) failed", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
