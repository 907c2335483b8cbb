"""The per-part cache's housekeeping: what it holds, and a size bound kept by evicting the
entries used longest ago.

Every entry (``<cache>/<stem>-<key>.qprep``, :mod:`qifreport.cache`) is a prepared part: a
few MB for a small part, hundreds for a large one with its bending basis. An entry's
modification time is its last use (an inspection that loads it touches it); after each
entry written the cache is cut to :func:`size_limit` (``$QIFREPORT_CACHE_MAX_MB``, default
:data:`DEFAULT_MAX_MB`) by removing the least recently used entries, never the one just
written. ``qifreport cache --list`` and ``--prune`` do the same by hand.

Public API
----------
:class:`CacheEntry`, :func:`cache_entries`, :func:`prune`, :func:`size_limit`, :func:`touch`
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

__all__ = [
    "DEFAULT_MAX_MB",
    "ENV_MAX_MB",
    "SUFFIX",
    "CacheEntry",
    "cache_entries",
    "prune",
    "size_limit",
    "touch",
]

log = logging.getLogger(__name__)

#: the cache's default size bound, MB (a morning of large parts once filled 1 GB)
DEFAULT_MAX_MB = 2048.0
ENV_MAX_MB = "QIFREPORT_CACHE_MAX_MB"
#: an entry's file name ends so (:data:`qifreport.cache.SUFFIX`)
SUFFIX = ".qprep"


@dataclass(frozen=True)
class CacheEntry:
    """One entry: its ``path``, ``size`` (bytes), ``last_used`` (UTC), ``created`` (as its
    header says, '' when unreadable) and the nominal's ``part`` name (the file's stem)."""

    path: Path
    size: int
    last_used: datetime
    created: str
    part: str


def size_limit() -> float:
    """The cache's bound, bytes: ``$QIFREPORT_CACHE_MAX_MB`` (MB) or :data:`DEFAULT_MAX_MB`
    (a value that is not a number >= 0 is ignored, with a warning)."""
    text = os.environ.get(ENV_MAX_MB)
    mb = DEFAULT_MAX_MB
    if text:
        try:
            mb = float(text)
            if not mb >= 0:
                raise ValueError(text)
        except ValueError:
            log.warning("%s=%r is not a size in MB: %g MB used", ENV_MAX_MB, text, DEFAULT_MAX_MB)
            mb = DEFAULT_MAX_MB
    return mb * 1e6


def _created(path: Path) -> str:
    """The entry header's creation time ('' when the header cannot be read)."""
    try:
        with open(path, "rb") as fh:
            return str(json.loads(fh.readline(1 << 16)).get("created", ""))
    except (OSError, ValueError, AttributeError):
        return ""


def cache_entries(cache_dir: Path) -> list[CacheEntry]:
    """The entries of ``cache_dir``, most recently used first (none: an empty list)."""
    out = []
    for p in Path(cache_dir).glob(f"*{SUFFIX}"):
        if p.name.startswith(".") or p.is_symlink() or not p.is_file():
            continue
        st = p.stat()
        out.append(
            CacheEntry(
                path=p,
                size=st.st_size,
                last_used=datetime.fromtimestamp(st.st_mtime, timezone.utc),
                created=_created(p),
                part=p.name[: -len(SUFFIX)].rsplit("-", 1)[0],
            )
        )
    return sorted(out, key=lambda e: e.last_used, reverse=True)


def prune(cache_dir: Path, max_bytes: float, keep: Path | None = None) -> list[CacheEntry]:
    """Remove the least recently used entries of ``cache_dir`` until the rest hold at most
    ``max_bytes``, never ``keep`` (the entry just written); returns the entries removed."""
    entries = cache_entries(cache_dir)
    total = sum(e.size for e in entries)
    removed = []
    for e in reversed(entries):  # least recently used first
        if total <= max_bytes:
            break
        if keep is not None and e.path == Path(keep):
            continue
        with contextlib.suppress(FileNotFoundError):
            e.path.unlink()
            removed.append(e)
            total -= e.size
            log.info(
                "cache: removed %s (%.1f MB, last used %s)", e.path.name, e.size / 1e6, e.last_used
            )
    return removed


def touch(path: Path) -> None:
    """Mark an entry as used now (its modification time; a read-only cache is left alone)."""
    with contextlib.suppress(OSError):
        os.utime(path)
