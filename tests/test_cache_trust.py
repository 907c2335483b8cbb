"""The cache runs no code another user could have written: the directory must be the user's
alone (else it is not used), an entry must be the user's own regular file, and its payload is
unpickled only after the HMAC under the user's secret ``<cache>/.key`` matches.

Every attack below plants a payload whose unpickling creates a marker file; each test asserts
that the marker is absent *and* that the outcome says why. Real files throughout; the tests run
as root, so ``chown`` to uid 65534 stands in for another user."""

import hashlib
import json
import logging
import os
import pickle
import re
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from qifreport.cache import CACHE_FORMAT, NominalOptions, entry_path, load_entry, part_state
from qifreport.cache_trust import (
    KEY_BYTES,
    KEY_FILE,
    CorruptEntry,
    UntrustedCache,
    cache_secret,
    check_cache_dir,
    entry_mac,
)
from qifreport.metrology.inspection import InspectionInputs, InspectionParams, inspect
from qifreport.simulate.shapes import thin_shell

EXE = Path(sys.executable).parent / "qifreport"
OPTS = NominalOptions(tolerance=0.5)
OTHER_UID = 65534  # nobody: "another user"

pytestmark = pytest.mark.skipif(
    os.geteuid() != 0, reason="simulating another user's files needs chown (root)"
)


class Plant:
    """Unpickling this opens ``marker`` for writing: a payload that runs code."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def evil(marker: Path) -> bytes:
    return pickle.dumps(Plant(marker))


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A small shell nominal (551 vertices) prepared into a cache directory that
    :func:`part_state` creates itself (under a permissive umask)."""
    part = tmp_path_factory.mktemp("part")
    V, F = thin_shell(spacing=6.0)
    nominal = part / "small.ply"
    trimesh.Trimesh(V, F, process=False).export(nominal)
    cache = tmp_path_factory.mktemp("home") / "deep" / "cache"
    old = os.umask(0o022)
    try:
        state, outcome = part_state(nominal, OPTS, InspectionParams(), cache)
    finally:
        os.umask(old)
    assert outcome.status == "built", outcome
    return nominal, cache, state, outcome


def split(entry: Path) -> tuple[dict, bytes]:
    head, _, payload = entry.read_bytes().partition(b"\n")
    return json.loads(head), payload


def write(entry: Path, header: dict, payload: bytes) -> None:
    entry.write_bytes(json.dumps(header, sort_keys=True).encode() + b"\n" + payload)


def copy_cache(small, tmp_path) -> tuple[Path, Path]:
    """A copy of the built cache (modes kept) and its entry."""
    _, cache, _, outcome = small
    d = tmp_path / "cache"
    shutil.copytree(cache, d)
    return d, d / outcome.path.name


def test_the_payload_would_run_code(tmp_path):
    """The attack is live: a plain unpickling of the payload creates the marker."""
    marker = tmp_path / "control"
    pickle.loads(evil(marker)).close()
    assert marker.exists()


def test_new_cache_is_private_and_entries_authenticated(small):
    nominal, cache, state, outcome = small
    st = os.stat(cache)
    assert stat.S_IMODE(st.st_mode) == 0o700 and st.st_uid == os.geteuid()
    key = cache / KEY_FILE
    kst = os.lstat(key)
    assert stat.S_ISREG(kst.st_mode) and stat.S_IMODE(kst.st_mode) == 0o600
    assert kst.st_size == KEY_BYTES == 32
    assert not stat.S_IMODE(os.stat(outcome.path).st_mode) & 0o077
    header, payload = split(outcome.path)
    assert header["format"] == CACHE_FORMAT == 25
    assert header["key"] == state.key
    assert header["hmac"] == entry_mac(key.read_bytes(), header, payload)
    # the secret is the user's: another secret gives another HMAC
    assert header["hmac"] != entry_mac(b"\0" * 32, header, payload)
    again, second = part_state(nominal, OPTS, InspectionParams(), cache)
    assert second.status == "hit" and again.key == state.key
    assert key.read_bytes() == cache_secret(cache)  # the key is reused, never rewritten


def test_new_cache_is_private_under_any_umask(tmp_path):
    old = os.umask(0o277)  # would make the directory 0500 and the key 0400
    try:
        secret = cache_secret(tmp_path / "c")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "c").st_mode) == 0o700
    assert stat.S_IMODE(os.stat(tmp_path / "c" / KEY_FILE).st_mode) == 0o600
    assert len(secret) == KEY_BYTES
    assert sorted(os.listdir(tmp_path / "c")) == [KEY_FILE]  # no temporary file left


@pytest.mark.parametrize("attack", ["swap", "forged-mac", "no-mac", "other-entry"])
def test_crafted_entry_never_runs(small, tmp_path, caplog, attack):
    """A header copied from a genuine entry with the payload swapped (length and SHA-256
    fixed up, as anyone can) fails the HMAC: never unpickled, rebuilt and replaced."""
    nominal, _, state, _ = small
    d, entry = copy_cache(small, tmp_path)
    marker = tmp_path / "marker"
    header, _ = split(entry)
    payload = evil(marker)
    if attack == "other-entry":  # a genuine header of another part's entry, in this place
        other, _ = part_state(nominal, NominalOptions(tolerance=0.4), InspectionParams(), d)
        header, _ = split(entry_path(d, nominal, other.key))
        header["key"] = state.key
    header["payload_bytes"] = len(payload)
    header["payload_sha256"] = hashlib.sha256(payload).hexdigest()
    if attack == "forged-mac":  # the attacker's own secret
        header["hmac"] = entry_mac(os.urandom(32), header, payload)
    elif attack == "no-mac":
        del header["hmac"]
    write(entry, header, payload)
    with pytest.raises(CorruptEntry, match="HMAC"):
        load_entry(entry, state.key, cache_secret(d))
    assert not marker.exists()
    with caplog.at_level(logging.WARNING, logger="qifreport.cache"):
        again, outcome = part_state(nominal, OPTS, InspectionParams(), d)
    assert not marker.exists()
    assert outcome.status == "rebuilt" and "HMAC" in outcome.reason, outcome
    assert any(str(entry) in r.getMessage() for r in caplog.records)
    np.testing.assert_array_equal(again.prepared.V, state.prepared.V)
    # replaced by a genuine entry: the next use loads it
    _, third = part_state(nominal, OPTS, InspectionParams(), d)
    assert third.status == "hit"
    assert not marker.exists()


def genuine_evil(entry: Path, secret: bytes, marker: Path) -> None:
    """Turn ``entry`` into one that passes every content check (the HMAC is computed with the
    real secret, as if it had leaked) but whose payload runs code."""
    header, _ = split(entry)
    payload = evil(marker)
    header["payload_bytes"] = len(payload)
    header["payload_sha256"] = hashlib.sha256(payload).hexdigest()
    header["hmac"] = entry_mac(secret, header, payload)
    write(entry, header, payload)


def test_control_a_valid_mac_is_all_that_content_checks_ask(small, tmp_path):
    """Control for the ownership tests: the same crafted entry, the user's own, 0600, *is*
    unpickled (the marker appears) -- so in the tests below it is ownership, mode or the link
    that stops it."""
    _, _, state, _ = small
    d, entry = copy_cache(small, tmp_path)
    marker = tmp_path / "control"
    genuine_evil(entry, cache_secret(d), marker)
    with pytest.raises(CorruptEntry, match="not this part's state"):
        load_entry(entry, state.key, cache_secret(d))
    assert marker.exists()


@pytest.mark.parametrize("how", ["other-owner", "group-writable", "symlink"])
def test_entry_not_the_users_own_is_refused(small, tmp_path, how):
    nominal, _, state, _ = small
    d, entry = copy_cache(small, tmp_path)
    marker = tmp_path / "marker"
    secret = cache_secret(d)
    if how == "symlink":  # a link in the cache to a crafted file elsewhere
        target = tmp_path / "elsewhere.qprep"
        shutil.copy(entry, target)
        genuine_evil(target, secret, marker)
        planted = target.read_bytes()
        entry.unlink()
        entry.symlink_to(target)
        expect = "symbolic link"
    else:
        genuine_evil(entry, secret, marker)
        if how == "other-owner":
            os.chown(entry, OTHER_UID, OTHER_UID)
            expect = f"owned by uid {OTHER_UID}"
        else:
            os.chmod(entry, 0o620)
            expect = "writable by group or others"
    with pytest.raises(CorruptEntry, match=expect):
        load_entry(entry, state.key, secret)
    assert not marker.exists()
    again, outcome = part_state(nominal, OPTS, InspectionParams(), d)
    assert not marker.exists()
    assert outcome.status == "rebuilt" and expect in outcome.reason, outcome
    np.testing.assert_array_equal(again.prepared.V, state.prepared.V)
    st = os.lstat(entry)  # replaced by the user's own regular file
    assert stat.S_ISREG(st.st_mode) and st.st_uid == os.geteuid()
    assert not stat.S_IMODE(st.st_mode) & 0o077
    if how == "symlink":
        assert target.read_bytes() == planted  # the link's target untouched


UNTRUSTED = {
    "dir-mode-0777": "is writable by group or others (mode 0777)",
    "dir-group-writable": "is writable by group or others (mode 0770)",
    "dir-other-owner": f"is owned by uid {OTHER_UID}",
    "key-other-owner": f"is owned by uid {OTHER_UID}",
    "key-mode-0644": "has mode 0644, not 0600",
    "key-short": "is 16 bytes, not 32",
    "key-symlink": "is a symbolic link",
}


@pytest.mark.parametrize("how", list(UNTRUSTED))
def test_untrusted_directory_is_not_used(small, tmp_path, caplog, how):
    """Neither read (the planted entry would run: its HMAC is right) nor written (nothing
    changes in the directory, which is not chmod-ed); one warning; the state is built."""
    nominal, _, state, _ = small
    d, entry = copy_cache(small, tmp_path)
    marker = tmp_path / "marker"
    key = d / KEY_FILE
    genuine_evil(entry, key.read_bytes(), marker)
    if how == "dir-mode-0777":
        os.chmod(d, 0o777)
    elif how == "dir-group-writable":
        os.chmod(d, 0o770)
    elif how == "dir-other-owner":
        os.chown(d, OTHER_UID, OTHER_UID)
    elif how == "key-other-owner":
        os.chown(key, OTHER_UID, OTHER_UID)
    elif how == "key-mode-0644":
        os.chmod(key, 0o644)
    elif how == "key-short":
        key.write_bytes(key.read_bytes()[:16])
    else:
        real = tmp_path / "real.key"
        shutil.copy2(key, real)
        key.unlink()
        key.symlink_to(real)
    before = {p.name: (os.lstat(p).st_mtime_ns, p.read_bytes()) for p in d.iterdir()}
    mode = os.stat(d).st_mode
    with pytest.raises(UntrustedCache, match=re.escape(UNTRUSTED[how])):
        cache_secret(d)
    with caplog.at_level(logging.WARNING, logger="qifreport.cache"):
        got, outcome = part_state(nominal, OPTS, InspectionParams(), d)
    assert not marker.exists()
    assert outcome.status == "refused" and outcome.path is None, outcome
    assert UNTRUSTED[how] in outcome.reason and "cache not used" in outcome.describe()
    warnings = [
        r.getMessage()
        for r in caplog.records
        if r.name == "qifreport.cache" and r.levelno == logging.WARNING
    ]
    assert len(warnings) == 1 and str(d) in warnings[0] and UNTRUSTED[how] in warnings[0]
    after = {p.name: (os.lstat(p).st_mtime_ns, p.read_bytes()) for p in d.iterdir()}
    assert after == before and os.stat(d).st_mode == mode  # nothing written, not chmod-ed
    np.testing.assert_array_equal(got.prepared.V, state.prepared.V)
    assert got.key == state.key


def test_a_file_in_place_of_the_directory_is_refused(small, tmp_path):
    nominal = small[0]
    d = tmp_path / "notadir"
    d.write_text("x")
    with pytest.raises(UntrustedCache, match="not a directory"):
        check_cache_dir(d)
    _, outcome = part_state(nominal, OPTS, InspectionParams(), d)
    assert outcome.status == "refused" and d.read_text() == "x"


def test_inspection_through_a_refused_directory_equals_a_fresh_one(small, tmp_path):
    nominal = small[0]
    d = tmp_path / "shared"
    d.mkdir()
    os.chmod(d, 0o777)
    params = InspectionParams(tolerance=0.5)
    state, outcome = part_state(nominal, OPTS, params, d)
    assert outcome.status == "refused"
    P, _ = thin_shell(spacing=3.0)
    part, zones = state.part, state.drawing.zones
    a = inspect(part.V, part.F, P, params, InspectionInputs(zones=zones, prepared=state.prepared))
    b = inspect(part.V, part.F, P, params, InspectionInputs(zones=zones))
    assert a.verdict == b.verdict
    np.testing.assert_allclose(a.deviation, b.deviation, atol=1e-9, equal_nan=True)
    assert os.listdir(d) == []


def test_cli_inspection_with_a_shared_cache_directory(small, tmp_path):
    """The command runs as with ``--no-cache``, with one warning naming the directory."""
    nominal = small[0]
    P, _ = thin_shell(spacing=3.0)
    scan = tmp_path / "scan.ply"
    trimesh.PointCloud(P).export(scan)
    d = tmp_path / "shared"
    d.mkdir()
    os.chmod(d, 0o777)
    runs = {}
    for name, flag in (("refused", ["--cache", d]), ("off", ["--no-cache"])):
        out = tmp_path / name
        runs[name] = subprocess.run(
            [EXE, nominal, scan, "--tolerance", "0.5", *flag, "--out", out, "--quiet", "--no-pdf"],
            capture_output=True,
            text=True,
        )
        assert (out / "small.qif").is_file(), runs[name].stderr
    refused, off = runs["refused"], runs["off"]
    assert refused.returncode == off.returncode
    lines = [ln for ln in refused.stderr.splitlines() if "cache" in ln]
    assert len(lines) == 1 and str(d) in lines[0] and "writable by group or others" in lines[0]
    assert "cache" not in off.stderr
    assert os.listdir(d) == []
