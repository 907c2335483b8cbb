"""The two registries: the characteristic kinds (qifreport/kinds.py) and the deformable
methods (registration/deformable/methods.py).

* Outside the registries no code compares a registered kind's or method's name as a string:
  the layers ask the registry (a kind's family, datum rule, QIF rules; a method's
  capabilities).
* A new kind is one registration: sphericity, registered here only, is measured through the
  product's dispatch on a scanned sphere, written as a QIF ``Sphericity`` characteristic and
  carried by the batch statistics, no other module edited; and it is gone afterwards.
"""

from __future__ import annotations

import ast
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from qifreport.kinds import (
    KINDS,
    CharacteristicKind,
    QifRules,
    kind_for_qif_type,
    lookup_kind,
    register_kind,
    registered,
)
from qifreport.metrology.gdt.characteristic_types import (
    CharacteristicResult,
    CharacteristicSpec,
    zone_uncertainty,
)
from qifreport.metrology.gdt.characteristics import measure_characteristics
from qifreport.metrology.gdt.form import least_squares_sphere
from qifreport.metrology.gdt.measured_surface import MeasuredSurface
from qifreport.registration.deformable.methods import METHODS, method_label, method_spec

ROOT = Path(__file__).resolve().parents[1]
#: the folders of the product's code, and the registries themselves (where the names live)
SCANNED = ("step", "registration", "metrology", "qif", "qifreport")
REGISTRIES = {"qifreport/kinds.py", "registration/deformable/methods.py"}


# ------------------------------------------------------------------ no name compared as text


def _strings(node: ast.AST) -> list[str]:
    """The string constants a comparison's side is: one, or a tuple/list/set of them."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return [e.value for e in node.elts if isinstance(e, ast.Constant)]
    return []


def _compared_names(source: str, names: set[str]) -> list[tuple[int, str]]:
    """(line, name) of each ``==``, ``!=``, ``in``, ``not in`` comparison one of whose sides
    is (or lists) a string constant in ``names``."""
    out = []
    ops = (ast.Eq, ast.NotEq, ast.In, ast.NotIn)
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Compare) or not any(isinstance(o, ops) for o in node.ops):
            continue
        for side in (node.left, *node.comparators):
            out += [(node.lineno, s) for s in _strings(side) if s in names]
    return out


def test_the_scan_finds_a_compared_name():
    """The scan itself: each form of comparison is caught, other strings are not."""
    code = (
        "a = kind == 'flatness'\n"
        "b = m != 'gbcicp'\n"
        "c = k in ('x', 'position')\n"
        "d = k not in {'roundness'}\n"
        "e = 'area' in basis\n"
        "f = {'position': 1}\n"
    )
    names = {"flatness", "gbcicp", "position", "roundness"}
    assert _compared_names(code, names) == [
        (1, "flatness"),
        (2, "gbcicp"),
        (3, "position"),
        (4, "roundness"),
    ]


def test_no_kind_or_method_name_is_compared_as_a_string():
    names = set(KINDS) | set(METHODS)
    offenders = []
    for folder in SCANNED:
        for f in sorted((ROOT / folder).rglob("*.py")):
            rel = f.relative_to(ROOT).as_posix()
            if rel in REGISTRIES or "__pycache__" in rel:
                continue
            offenders += [
                f"{rel}:{line} compares {name!r}"
                for line, name in _compared_names(f.read_text(), names)
            ]
    assert not offenders, "ask the registry instead:\n" + "\n".join(offenders)


# ------------------------------------------------------------------------------- the methods


def test_every_method_is_implemented_and_labelled():
    for name, spec in METHODS.items():
        assert spec.name == name and method_spec(name) is spec
        assert method_label(name) == spec.label
        assert spec.qif_algorithm.startswith(spec.label + ":")
        assert spec.module.startswith("qifreport.registration.")
        params = spec.params_type()
        assert params.__dataclass_fields__  # a parameter dataclass
    # the product's method has every capability the inspection asks of GB-CICP
    gb = method_spec("gbcicp")
    assert gb.flags_defects and gb.uses_bending_basis and gb.moves_along_normals_only
    assert gb.params_field == "gbcicp" and gb.band_limited
    assert [m.name for m in METHODS.values() if m.driven_by_clamps] == ["rbffem"]
    # another program's fit: no capability, its name as its label
    other = method_spec("tps")
    assert other.label == "TPS" and not (other.flags_defects or other.uses_bending_basis)


# --------------------------------------------------------------------------- a toy new kind

#: the sphere: diameter 10 mm about the origin
RADIUS = 5.0
#: the sphericity tolerance and the form put on the sphere: a bump of this height
TOLERANCE, BUMP = 0.05, 0.02


def sphericity(spec, S, sample, feat, frame, sizes, surf, faces):
    """Sphericity of a sphere's points: the peak-to-valley of their distances from the
    least-squares sphere's centre (a kind's per-feature measurement, signature of
    :mod:`qifreport.metrology.gdt.geometric`)."""
    if feat.kind != "sphere":
        raise ValueError("sphericity of a feature that is not a sphere")
    c, r = least_squares_sphere(S)
    d = np.linalg.norm(S - c, axis=1) - r
    return float(np.ptp(d)), float(np.ptp(d)), zone_uncertainty(d, sample.U), "least squares", 0.0


SPHERICITY = CharacteristicKind(
    "sphericity",
    family="form",
    datums="never",
    measure=f"{__name__}:sphericity",
    qif_type="Sphericity",
    qif=QifRules(),
)


def _sphere_surface(dev_of) -> MeasuredSurface:
    """A 10 mm sphere's mesh (one B-rep face) measured with each vertex at ``dev_of(n)``
    along its outward normal ``n`` (k, 3) -> (k,) mm; every vertex's U 2 um."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    V, F = np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64)
    N = V / np.linalg.norm(V, axis=1, keepdims=True)
    e = np.empty(0)
    return MeasuredSurface(
        V,
        F,
        np.zeros(len(F), dtype=np.int64),
        N[F],
        dev_of(N),
        np.full(len(V), 0.002),
        np.empty((0, 3)),
        e.astype(np.int64),
        e,
        e,
    )


def _bumped(N: np.ndarray) -> np.ndarray:
    """0.03 mm oversize, moved 0.05 mm along x, and a 0.02 mm bump about +z (30 deg wide):
    its form is the bump alone."""
    angle = np.arccos(np.clip(N[:, 2], -1.0, 1.0))
    return 0.03 + 0.05 * N[:, 0] + BUMP * np.exp(-((angle / np.radians(15.0)) ** 2))


def _spec() -> CharacteristicSpec:
    return CharacteristicSpec(
        key="G1",
        kind="sphericity",
        name="ball",
        step_id=7,
        faces=np.array([0]),
        tolerance=TOLERANCE,
    )


def test_a_kind_registered_alone_is_measured_written_and_summarised(tmp_path):
    assert lookup_kind("sphericity") is None
    with registered(SPHERICITY):
        # measured through the product's dispatch (metrology/gdt/characteristics.py)
        surf = _sphere_surface(_bumped)
        assert surf.nominal([0]).kind == "sphere"
        (res,), frames = measure_characteristics([_spec()], {}, surf, "iso14253")
        assert frames == []
        assert res.status == "PASS", res.reason
        # the bump's height, not the size or the offset (about the nominal centre and radius
        # the points spread 0.12 mm; twice the largest residual would be about 0.026 mm)
        assert res.value == pytest.approx(BUMP, abs=0.002), res.reading
        assert res.reading.startswith("least squares; ") and res.n_points == len(surf.V)
        # an oversize sphere has none
        oversize = _sphere_surface(lambda N: np.full(len(N), 0.03))
        (perfect,), _ = measure_characteristics([_spec()], {}, oversize, "iso14253")
        assert perfect.value < 1e-6
        # written as a QIF Sphericity characteristic and carried by the batch statistics
        assert kind_for_qif_type("Sphericity") is SPHERICITY
        summary = _summarised(tmp_path, res)
        assert summary.kind == "Sphericity" and summary.tolerance == TOLERANCE
        assert summary.count == 3 and summary.cp is None and summary.cpk is not None
    # and gone: neither measured nor a QIF type any more
    assert lookup_kind("sphericity") is None and kind_for_qif_type("Sphericity") is None
    (after,), _ = measure_characteristics([_spec()], {}, _sphere_surface(_bumped), "iso14253")
    assert after.status == "NOT_MEASURED" and "not measured by qifreport" in after.reason


def _summarised(tmp_path: Path, res: CharacteristicResult):
    """Three results documents holding ``res``'s characteristic (values about its value),
    written by the product's builders, read back and summarised."""
    from lxml import etree

    from qifreport.qif.feature_characteristics import qif_type
    from qifreport.qif.reader import read_results
    from qifreport.qif.statistics import build_statistics, summarize
    from tests.round_trip import one_characteristic_document

    assert qif_type(res.spec) == "Sphericity"
    paths = []
    for k, value in enumerate((res.value, res.value + 0.004, res.value - 0.003)):
        c = CharacteristicResult(res.spec, value=value, uncertainty=0.002, status="PASS")
        path = tmp_path / f"scan_{k}.qif"
        path.write_bytes(one_characteristic_document(c))
        paths.append(path)
    results = [read_results(p) for p in paths]
    created = datetime(2026, 3, 1, tzinfo=timezone.utc)
    doc = etree.tostring(build_statistics(results, part_name="ball", created=created))
    assert b"SphericityCharacteristicStats" in doc
    (summary,) = summarize(results)
    return summary


def test_a_kind_is_registered_once():
    with registered(SPHERICITY):
        with pytest.raises(ValueError, match="already registered"):
            register_kind(SPHERICITY)
        with pytest.raises(ValueError, match="QIF type"):
            register_kind(CharacteristicKind("ball_form", family="form", qif_type="Sphericity"))
    assert "sphericity" not in KINDS
    with pytest.raises(ValueError, match="family"):
        CharacteristicKind("x", family="shape")
