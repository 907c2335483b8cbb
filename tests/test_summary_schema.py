"""The versioned JSON Schema of the ``--json`` summary: it is a valid draft 2020-12 schema,
every summary the CLI writes conforms to it, and it catches real mistakes."""

from __future__ import annotations

import copy
import io
import json
import math
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from qifreport.summary import (
    SUMMARY_SCHEMA_VERSION,
    summary_schema,
    summary_schema_path,
    validate_summary,
)
from tests.conftest import ROOT, assert_valid_summary

SAMPLES = ROOT / "samples"


def _no_nan(token: str):
    raise ValueError(f"non-standard JSON number {token}")


def _cli_json(argv: list[str], out: Path, stem: str) -> tuple[int, dict]:
    """Run ``qifreport ARGV --json --quiet --out OUT`` in-process; the exit code and the JSON
    it wrote, parsed strictly (a NaN/Infinity token is an error, not a float)."""
    from qifreport.cli import main

    with redirect_stdout(io.StringIO()), pytest.raises(SystemExit) as exc:
        main([*argv, "--json", "--quiet", "--out", str(out)])
    text = (out / f"{stem}.json").read_text()
    return exc.value.code, json.loads(text, parse_constant=_no_nan)


@pytest.fixture(scope="module")
def mesh_doc(tmp_path_factory):
    code, doc = _cli_json(
        [str(SAMPLES / "shell_nominal.ply"), str(SAMPLES / "shell_scan.ply"), "--tolerance", "0.5"],
        tmp_path_factory.mktemp("mesh"),
        "shell_nominal",
    )
    assert code == 0
    return doc


@pytest.fixture(scope="module")
def rigid_doc(tmp_path_factory):
    """--rigid-only: no GB-CICP result, unresolved GB-CICP defaults (nulls)."""
    code, doc = _cli_json(
        [
            str(SAMPLES / "shell_nominal.ply"),
            str(SAMPLES / "shell_scan.ply"),
            "--tolerance",
            "0.5",
            "--rigid-only",
        ],
        tmp_path_factory.mktemp("rigid"),
        "shell_nominal",
    )
    assert code in (0, 1)
    return doc


@pytest.fixture(scope="module")
def step_doc(tmp_path_factory):
    """The STEP panel: PMI zones, not-evaluated items, a failing part with regions."""
    code, doc = _cli_json(
        [str(SAMPLES / "panel.step"), str(SAMPLES / "panel_scan_defect.ply")],
        tmp_path_factory.mktemp("step"),
        "panel",
    )
    assert code in (0, 1)
    return doc


# --------------------------------------------------------------------------- the schema itself


def test_schema_is_a_valid_draft_2020_12_schema():
    from jsonschema import Draft202012Validator

    schema = summary_schema()
    Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["$id"] == "https://qifreport.org/schemas/summary-1.schema.json"
    assert schema["properties"]["schema"]["const"] == SUMMARY_SCHEMA_VERSION
    assert "schema" in schema["required"] and "qif" not in schema["required"]


def test_schema_file_is_the_canonical_one_at_the_repo_root():
    assert summary_schema_path() == ROOT / "schemas" / "summary-1.schema.json"
    summary_schema()["title"] = "changed"  # a copy: the cached schema is not touched
    assert summary_schema()["title"] != "changed"


_CONDITIONAL = {"allOf", "anyOf", "if", "then", "else"}


def _descriptions_missing(node, path="#") -> list[str]:
    """Properties of the schema without a description (every key must say its unit)."""
    out = []
    if isinstance(node, dict):
        for name, sub in node.get("properties", {}).items():
            if isinstance(sub, dict) and "description" not in sub and "const" not in sub:
                out.append(f"{path}/{name}")
        for key, sub in node.items():
            if key not in _CONDITIONAL:  # if/then only narrow properties described elsewhere
                out += _descriptions_missing(sub, f"{path}/{key}")
    elif isinstance(node, list):
        for i, sub in enumerate(node):
            out += _descriptions_missing(sub, f"{path}/{i}")
    return out


def test_every_property_is_described():
    assert _descriptions_missing(summary_schema()) == []


# ---------------------------------------------------------------------- real CLI outputs


@pytest.mark.slow
@pytest.mark.parametrize("which", ["mesh_doc", "rigid_doc", "step_doc"])
def test_cli_outputs_validate(which, request):
    doc = request.getfixturevalue(which)
    assert doc["schema"] == SUMMARY_SCHEMA_VERSION
    assert_valid_summary(doc)


@pytest.mark.slow
def test_outputs_cover_the_variants(mesh_doc, rigid_doc, step_doc):
    """The three runs exercise the optional shapes: null GB-CICP, STEP nominal, regions."""
    assert mesh_doc["nominal"]["format"] == "mesh" and mesh_doc["verdict"] == "PASS"
    assert rigid_doc["registration"]["gbcicp"] is None
    assert rigid_doc["parameters"]["gbcicp"]["band_limit"] is None
    assert step_doc["nominal"]["format"] == "step" and step_doc["characteristics"]
    assert step_doc["verdict"] == "FAIL" and step_doc["acceptance"]["regions"]
    assert {z["source"] for z in step_doc["tolerances"]} == {"pmi"}


@pytest.mark.slow
@pytest.mark.parametrize(
    "qif",
    [
        {
            "path": "out/panel.qif",
            "valid": True,
            "validated_with": ["xmlschema"],
            "message": "valid",
        },
        {
            "path": "out/panel.qif",
            "valid": None,
            "validated_with": [],
            "message": "not validated: QIF schemas not found",
        },
    ],
)
def test_optional_qif_block_validates(mesh_doc, qif):
    assert_valid_summary({**mesh_doc, "qif": qif})


# ------------------------------------------------------------------ the schema catches mistakes


def _set(doc: dict, path: str, value) -> None:
    *head, last = path.strip("/").split("/")
    node = doc
    for k in head:
        node = node[int(k)] if isinstance(node, list) else node[k]
    if value is _DELETE:
        del node[last]
    elif isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value


_DELETE = object()

#: (mutation path, new value, error location expected in the report)
MISTAKES = {
    "missing verdict": ("/verdict", _DELETE, "/: 'verdict' is a required property"),
    "verdict OK": ("/verdict", "OK", "/verdict: 'OK' is not one of"),
    "zone verdict lowercase": ("/tolerances/0/verdict", "pass", "/tolerances/0/verdict:"),
    "negative region area": (
        "/acceptance/regions/0/area",
        -12.5,
        "/acceptance/regions/0/area: -12.5 is less than the minimum",
    ),
    "negative scored area": ("/coverage/scored_area_mm2", -1.0, "/coverage/scored_area_mm2:"),
    "string for a number": (
        "/vertex_deviation/rms",
        "0.21",
        "/vertex_deviation/rms: '0.21' is not of type",
    ),
    "percent for a fraction": (
        "/acceptance/in_tolerance_fraction",
        95.4,
        "/acceptance/in_tolerance_fraction: 95.4 is greater than",
    ),
    "NaN leaking": ("/coverage/coverage", math.nan, "/coverage/coverage: nan is not a JSON number"),
    "unknown top-level key": ("/extra", 1, "Additional properties are not allowed ('extra'"),
    "unknown zone key": ("/tolerances/0/center_mm", 0.0, "/tolerances/0: Additional properties"),
    "wrong schema version": ("/schema", "qifreport-summary/2", "/schema: 'qifreport-summary/1'"),
    "missing schema version": ("/schema", _DELETE, "/: 'schema' is a required property"),
    "bad sha256": ("/inputs/scan/sha256", "abc", "/inputs/scan/sha256:"),
    "bad region sign": ("/acceptance/regions/0/sign", 0, "/acceptance/regions/0/sign:"),
    "unknown zone source": ("/tolerances/0/source", "cli", "/tolerances/0/source:"),
    "float count": ("/mesh/vertices", 36056.5, "/mesh/vertices: 36056.5 is not of type"),
    "step nominal without tessellation": (
        "/nominal/tessellation",
        _DELETE,
        "/nominal: 'tessellation' is a required property",
    ),
    "PASS with failing zones": (
        "/verdict",
        "PASS",
        "/decided_by: <array of 2> is expected to be empty",
    ),
    "empty stats with numbers": ("/vertex_deviation/n", 0, "/vertex_deviation/rms:"),
    "bad qif block": (
        "/qif",
        {"path": "x.qif", "valid": "yes", "validated_with": [], "message": ""},
        "/qif/valid: 'yes' is not of type",
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(MISTAKES))
def test_schema_catches_mistakes(step_doc, name):
    path, value, expect = MISTAKES[name]
    assert validate_summary(step_doc) == []
    doc = copy.deepcopy(step_doc)
    _set(doc, path, value)
    errors = validate_summary(doc)
    assert any(e.startswith(expect) or expect in e for e in errors), (name, errors)


@pytest.mark.slow
def test_consistency_rules(mesh_doc):
    """Verdict and acceptance must agree: a FAIL needs a reason, a passed surface none."""
    doc = copy.deepcopy(mesh_doc)
    doc["verdict"] = "FAIL"
    errors = validate_summary(doc)
    assert "/decided_by: [] should be non-empty" in errors, errors
    doc = copy.deepcopy(mesh_doc)
    doc["acceptance"]["reasons"] = ["made up"]
    assert any(e.startswith("/acceptance/reasons:") for e in validate_summary(doc))
    doc = copy.deepcopy(mesh_doc)
    doc["tolerances"][0]["faces"] = [0, 1]  # the general zone has no face list
    assert any(e.startswith("/tolerances/0/faces:") for e in validate_summary(doc))
