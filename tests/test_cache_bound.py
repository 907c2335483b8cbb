"""The per-part cache is bounded: each new entry evicts the entries used longest ago beyond
``$QIFREPORT_CACHE_MAX_MB``; ``qifreport cache`` lists and prunes it by hand."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from qifreport.cache_prune import cache_entries, prune
from tests.conftest import ROOT

EXE = Path(sys.executable).with_name("qifreport")


def _entry(d: Path, name: str, mb: float, age_s: float) -> Path:
    """A stand-in entry of ``mb`` MB last used ``age_s`` seconds ago."""
    p = d / f"{name}-0123456789abcdef0123.qprep"
    header = json.dumps({"created": "2026-01-01T00:00:00+00:00"}).encode() + b"\n"
    p.write_bytes(header + b"\0" * int(mb * 1e6))
    t = time.time() - age_s
    os.utime(p, (t, t))
    return p


def test_the_least_recently_used_go_first_and_the_new_one_stays(tmp_path):
    old = _entry(tmp_path, "old", 3, 3000)
    mid = _entry(tmp_path, "mid", 3, 2000)
    new = _entry(tmp_path, "new", 3, 5000)  # just written, yet its time is oldest
    assert [e.part for e in cache_entries(tmp_path)] == ["mid", "old", "new"]
    gone = prune(tmp_path, 6.5e6, keep=new)
    assert [e.part for e in gone] == ["old"]
    assert new.exists() and mid.exists() and not old.exists()
    assert prune(tmp_path, 10e6) == []  # within the bound: nothing goes


def test_an_inspection_keeps_the_cache_within_its_bound(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir(mode=0o700)
    stale = _entry(cache, "stale", 20, 86400)
    env = {**os.environ, "QIFREPORT_CACHE_MAX_MB": "30"}
    r = subprocess.run(
        [str(EXE), "prepare", ROOT / "samples" / "shell_nominal.ply", "--tolerance", "0.5"]
        + ["--cache", str(cache)],
        capture_output=True,
        text=True,
        env=env,
    )
    assert r.returncode == 0, r.stderr
    left = cache_entries(cache)
    assert not stale.exists() and [e.part for e in left] == ["shell_nominal"]
    assert sum(e.size for e in left) <= 30e6
    listed = subprocess.run(
        [str(EXE), "cache", "--cache", str(cache)], capture_output=True, text=True, env=env
    )
    assert (
        listed.returncode == 0 and "1 entry" in listed.stdout and "shell_nominal" in listed.stdout
    )
    emptied = subprocess.run(
        [str(EXE), "cache", "--cache", str(cache), "--prune", "--max-size", "0"],
        capture_output=True,
        text=True,
    )
    assert emptied.returncode == 0 and "removed 1 entry" in emptied.stdout
    assert cache_entries(cache) == []
