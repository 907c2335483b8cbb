"""The per-part cache: keyed by content and settings, verified on load, rebuilt when corrupt,
and an inspection from a cached state equal to one prepared afresh."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qifreport.cache import NominalOptions, cache_key, key_material, load_entry, part_state, sha256
from qifreport.cache_trust import CorruptEntry, cache_secret
from qifreport.metrology.inspection import InspectionInputs, InspectionParams, inspect
from qifreport.metrology.prepared import prepare_part
from qifreport.registration.pointcloud import read_scan

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "samples"
EXE = Path(sys.executable).parent / "qifreport"
OPTS = NominalOptions(tolerance=0.5)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The shell nominal prepared into a fresh cache directory (built, then loaded)."""
    d = tmp_path_factory.mktemp("cache")
    nominal = tmp_path_factory.mktemp("part") / "shell.ply"
    shutil.copy(SAMPLES / "shell_nominal.ply", nominal)
    state, first = part_state(nominal, OPTS, InspectionParams(), d)
    return nominal, d, state, first


def test_first_use_builds_then_loads_the_same_state(built):
    nominal, d, state, first = built
    assert first.status == "built" and first.path.is_file()
    assert first.path.parent == d and first.path.name.startswith("shell-")
    again, second = part_state(nominal, OPTS, InspectionParams(), d)
    assert second.status == "hit" and second.path == first.path
    p, q = state.prepared, again.prepared
    np.testing.assert_array_equal(p.V, q.V)
    np.testing.assert_array_equal(p.basis.Phi, q.basis.Phi)
    assert (p.ops.Q != q.ops.Q).nnz == 0
    np.testing.assert_array_equal(p.near_rim, q.near_rim)
    np.testing.assert_array_equal(p.model.fields, q.model.fields)
    assert again.drawing.zones[0].half_width == 0.5
    # every part of the expensive state is there: 100 modes, the pose-search model
    assert p.basis.Phi.shape == (len(p.V), 100) and p.model is not None


def test_key_covers_content_settings_and_versions(built, tmp_path):
    nominal, _, state, _ = built
    base = key_material(sha256(nominal), OPTS, InspectionParams())
    assert cache_key(base) == state.key
    variants = [
        key_material("0" * 64, OPTS, InspectionParams()),
        key_material(sha256(nominal), NominalOptions(tolerance=0.4), InspectionParams()),
        key_material(sha256(nominal), NominalOptions(0.5, max_edge=2.0), InspectionParams()),
        key_material(sha256(nominal), OPTS, InspectionParams(energy="laplacian")),
        key_material(sha256(nominal), OPTS, InspectionParams(edge_band=0.0)),
        key_material(sha256(nominal), OPTS, InspectionParams(boundary_band=3.0)),
    ]
    keys = {cache_key(m) for m in variants}
    assert len(keys) == len(variants) and state.key not in keys
    for field in ("format", "software", "numpy", "scipy"):
        assert field in base
    # the same content under another name is the same entry's key
    other = tmp_path / "renamed.ply"
    shutil.copy(nominal, other)
    assert cache_key(key_material(sha256(other), OPTS, InspectionParams())) == state.key


def test_the_nominal_is_handed_over_before_the_part_is_prepared(built, tmp_path, monkeypatch):
    """``part_state`` gives the nominal to ``on_nominal`` once: before the costly preparation
    when it builds the state (without a cache and into one), and once on a cache hit (the
    command line starts the scan's normals there, beside the preparation)."""
    import qifreport.cache as cache

    nominal = built[0]
    events = []
    real = cache.prepare_part

    def preparing(*args, **kwargs):
        events.append("prepare")
        return real(*args, **kwargs)

    def seen(part):
        events.append(("nominal", len(part.V)))

    monkeypatch.setattr(cache, "prepare_part", preparing)
    n = len(built[2].part.V)
    part_state(nominal, OPTS, InspectionParams(), None, on_nominal=seen)
    assert events == [("nominal", n), "prepare"]
    for expected in ([("nominal", n), "prepare"], [("nominal", n)]):  # built, then a hit
        events.clear()
        _, outcome = part_state(nominal, OPTS, InspectionParams(), tmp_path, on_nominal=seen)
        assert events == expected, outcome.status


@pytest.mark.parametrize("damage", ["flip", "truncate", "header", "foreign"])
def test_damaged_entry_is_refused_and_rebuilt(built, tmp_path, damage):
    nominal, d, state, first = built
    cache = tmp_path / "c"
    shutil.copytree(d, cache)
    entry = cache / first.path.name
    data = bytearray(entry.read_bytes())
    if damage == "flip":
        data[-1000] ^= 0x40  # one bit deep in the payload
    elif damage == "truncate":
        del data[len(data) // 2 :]
    elif damage == "header":
        data[:10] = b"garbage!!!"
    else:  # a well-formed entry of another key in this entry's place
        head, _, payload = bytes(data).partition(b"\n")
        h = json.loads(head)
        h["key"] = "f" * 64
        data = bytearray(json.dumps(h).encode() + b"\n" + payload)
    entry.write_bytes(bytes(data))
    with pytest.raises(CorruptEntry):
        load_entry(entry, state.key, cache_secret(cache))
    if damage != "flip":
        return  # rebuilding is the same path for every damage: once is enough (8 s)
    again, outcome = part_state(nominal, OPTS, InspectionParams(), cache)
    assert outcome.status == "rebuilt", outcome
    assert outcome.reason
    np.testing.assert_array_equal(again.prepared.V, state.prepared.V)
    assert load_entry(entry, state.key, cache_secret(cache)).key == state.key  # replaced
    assert not list(cache.glob(".tmp-*"))  # no temporary file left behind


def test_cached_inspection_equals_a_fresh_one(built):
    nominal, d, state, _ = built
    P = read_scan(SAMPLES / "shell_scan_defect.ply").points
    params = InspectionParams(tolerance=0.5)
    cached, _ = part_state(nominal, OPTS, params, d)
    part, zones = cached.part, cached.drawing.zones
    a = inspect(part.V, part.F, P, params, InspectionInputs(zones=zones, prepared=cached.prepared))
    b = inspect(part.V, part.F, P, params, InspectionInputs(zones=zones))
    assert a.verdict == b.verdict == "FAIL"  # the 1 mm bump is found either way
    np.testing.assert_allclose(a.deviation, b.deviation, atol=1e-9, equal_nan=True)
    assert a.acceptance.largest_region_area == pytest.approx(b.acceptance.largest_region_area)


def test_prepared_state_refuses_other_settings(built):
    _, _, state, _ = built
    part = state.part
    P = read_scan(SAMPLES / "shell_scan.ply").points
    reuse = InspectionInputs(prepared=state.prepared)
    with pytest.raises(ValueError, match="other settings"):
        inspect(part.V, part.F, P, InspectionParams(edge_band=0.0), reuse)
    with pytest.raises(ValueError, match="another nominal"):
        inspect(part.V + 1.0, part.F, P, InspectionParams(), reuse)


def test_prepare_part_without_basis_or_model():
    from qifreport.simulate.shapes import thin_shell

    V, F = thin_shell()
    p = prepare_part(V, F, InspectionParams(), basis=False, model=False)
    assert p.basis is None and p.model is None and p.energy == "hessian"  # an open sheet


def test_prepare_command_then_inspection_hits_the_cache(tmp_path):
    cache = tmp_path / "cache"
    r = subprocess.run(
        [
            str(EXE),
            "prepare",
            SAMPLES / "shell_nominal.ply",
            "--tolerance",
            "0.5",
            "--cache",
            cache,
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert "prepared in" in r.stdout and "basis" in r.stdout
    assert len(list(cache.glob("shell_nominal-*.qprep"))) == 1
    r = subprocess.run(
        [
            str(EXE),
            "prepare",
            SAMPLES / "shell_nominal.ply",
            "--tolerance",
            "0.5",
            "--cache",
            cache,
        ],
        capture_output=True,
        text=True,
    )
    assert "loaded from cache" in r.stdout, r.stdout
    r = subprocess.run(
        [
            str(EXE),
            SAMPLES / "shell_nominal.ply",
            SAMPLES / "shell_scan.ply",
            "--tolerance",
            "0.5",
            "--cache",
            cache,
            "--out",
            tmp_path,
            "--quiet",
            "-v",
            "--no-pdf",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "loaded from" in r.stderr
    # another tolerance is another entry
    r = subprocess.run(
        [
            str(EXE),
            "prepare",
            SAMPLES / "shell_nominal.ply",
            "--tolerance",
            "0.3",
            "--cache",
            cache,
        ],
        capture_output=True,
        text=True,
    )
    assert "prepared in" in r.stdout
    assert len(list(cache.glob("shell_nominal-*.qprep"))) == 2


def test_prepare_command_bad_nominal(tmp_path):
    bad = tmp_path / "part.step"
    bad.write_text("ISO-10303-21;\nthis is not a STEP file\n")
    r = subprocess.run(
        [str(EXE), "prepare", bad, "--cache", tmp_path / "c"], capture_output=True, text=True
    )
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "part.step" in r.stderr
    assert not list(tmp_path.rglob("*.qprep"))  # nothing cached for an unreadable part


def test_without_cache_only_what_the_inspection_needs(built):
    """``--no-cache``: one inspection builds no bending basis for a baseline method and no
    pose-search model up front (the pose search builds it if the scan needs it)."""
    nominal = built[0]
    state, outcome = part_state(nominal, OPTS, InspectionParams(method="nicp"), None)
    assert outcome.status == "off" and outcome.path is None
    assert state.prepared.basis is None and state.prepared.model is None
    assert state.prepared.ops.Q.shape == (len(state.part.V),) * 2


def test_without_cache_the_basis_waits_for_a_fixture(built):
    """``--no-cache`` as the command runs it (the free state first): the bending basis is left
    to the virtual fixture, which builds it only if the free state does not conform (beside
    its judgement, on a second CPU); a caller that asks for it up front gets the same modes
    as a cache entry holds."""
    nominal, _, cached, _ = built
    lazy, outcome = part_state(nominal, OPTS, InspectionParams(), None, lazy_basis=True)
    assert outcome.status == "off" and lazy.prepared.basis is None
    assert "basis" not in outcome.timings
    eager, _ = part_state(nominal, OPTS, InspectionParams(), None)
    np.testing.assert_array_equal(eager.prepared.basis.Phi, cached.prepared.basis.Phi)
