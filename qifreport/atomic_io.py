"""Atomic output files: write beside the target, then rename (no partial file on failure)."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = [
    "atomic_write",
    "atomic_write_many",
]


def atomic_write(path: str | Path, write: Callable[[Path], object]) -> None:
    """Write through ``write(tmp_path)`` into a temp file beside ``path``, then rename.

    A failure leaves no partial ``path`` behind (and an existing ``path`` untouched). The
    file gets the permissions of an ordinary new file (``0666 & ~umask``), not mkstemp's 0600.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_many(items: list[tuple[str | Path, Callable[[Path], object]]]) -> None:
    """Write several files all-or-nothing: every ``write(tmp)`` runs (in order) into a temp
    file beside its target; only when all succeeded are they renamed into place.

    A failure in any writer leaves none of the targets created or changed.
    """
    staged: list[tuple[Path, Path]] = []
    try:
        for path, write in items:
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
            os.close(fd)
            staged.append((path, Path(tmp)))
            write(Path(tmp))
        umask = os.umask(0)
        os.umask(umask)
        for _path, tmp in staged:
            os.chmod(tmp, 0o666 & ~umask)
    except BaseException:
        for _path, tmp in staged:
            tmp.unlink(missing_ok=True)
        raise
    for path, tmp in staged:
        os.replace(tmp, path)
