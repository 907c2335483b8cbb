"""Atomic output files: write beside the target, then rename (no partial file on failure)."""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import tempfile
from collections.abc import Callable, Collection
from pathlib import Path

from .errors import raise_if_interrupted

__all__ = [
    "sha256",
    "atomic_write",
    "atomic_write_many",
    "output_lock",
    "remove_stale_temps",
    "temp_name_pattern",
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


def atomic_write_many(
    items: list[tuple[str | Path, Callable[[Path], object]]],
    *,
    executor=None,
    beside: Collection[str | Path] = (),
) -> None:
    """Write several files all-or-nothing: every ``write(tmp)`` runs (in order) into a temp
    file beside its target; only when all succeeded are they renamed into place.

    A failure in any writer leaves none of the targets created or changed.

    ``executor`` (``submit(fn, *args)`` returning a future with ``result()`` and
    ``cancel()``, e.g. :class:`qifreport.forked.ForkExecutor`) runs the writers of the
    targets in ``beside`` while the others run here: writers that only read their inputs
    (a report), not state the others share.
    """
    staged: list[tuple[Path, Path]] = []
    pending: list = []
    later = {Path(p) for p in beside} if executor is not None else set()
    try:
        raise_if_interrupted()
        for path, _write in items:
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
            os.close(fd)
            staged.append((path, Path(tmp)))
        for (path, tmp), (_path, write) in zip(staged, items, strict=True):
            if path in later:
                pending.append(executor.submit(write, tmp))
        for (path, tmp), (_path, write) in zip(staged, items, strict=True):
            if path not in later:
                write(tmp)
        for future in pending:
            future.result()
        umask = os.umask(0)
        os.umask(umask)
        for _path, tmp in staged:
            os.chmod(tmp, 0o666 & ~umask)
        raise_if_interrupted()
    except BaseException:
        for future in pending:
            future.cancel()
        for _path, tmp in staged:
            tmp.unlink(missing_ok=True)
        raise
    # the renames are not interrupted by a signal half-way (all published, or none)
    with _signals_held():
        for path, tmp in staged:
            os.replace(tmp, path)


#: signals held while a set of files is renamed into place
_HELD = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP) if hasattr(signal, "SIGHUP") else ()


@contextlib.contextmanager
def _signals_held():
    if not _HELD or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def temp_name_pattern(path: str | Path) -> str:
    """The glob of the temporary files :func:`atomic_write` makes for ``path`` (its folder's
    ``.<name>.*.tmp``)."""
    return f".{Path(path).name}.*.tmp"


def remove_stale_temps(paths: list[Path]) -> list[Path]:
    """Remove the temporary files a killed run left for ``paths`` (our naming only: see
    :func:`temp_name_pattern`); call it only while no other writer of ``paths`` can run (under
    :func:`output_lock`). Returns the files removed."""
    removed = []
    for path in paths:
        path = Path(path)
        if not path.parent.is_dir():
            continue
        for tmp in path.parent.glob(temp_name_pattern(path)):
            if tmp.is_file() and not tmp.is_symlink():
                tmp.unlink(missing_ok=True)
                removed.append(tmp)
    return removed


@contextlib.contextmanager
def output_lock(folder: str | Path):
    """An exclusive lock on an output folder for the duration of a run: ``flock`` on the
    folder itself, so no lock file is left behind. A folder that does not exist yet is made
    first (and removed again, with the parents made for it, if the run leaves it empty), so
    two runs into two new folders of one parent do not contend. A second run into the same
    folder gets ``BlockingIOError`` instead of overwriting the first one's files."""
    import fcntl

    target = Path(folder).absolute()
    made = []
    p = target
    while not p.exists() and p != p.parent:
        made.append(p)
        p = p.parent
    target.mkdir(parents=True, exist_ok=True)
    fd = os.open(target, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        yield
    finally:
        os.close(fd)
        for d in made:  # deepest first; a folder the run wrote into is not empty
            try:
                d.rmdir()
            except OSError:
                break


def sha256(path: Path) -> str:
    """Hex SHA-256 digest of a file."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
