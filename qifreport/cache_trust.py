"""Whether the per-part cache (:mod:`qifreport.cache`) may be trusted: its directory, the
user's secret in it, and an entry's file and HMAC.

Unpickling runs code, so nothing is unpickled that anyone but the current user
(``os.geteuid()``) could have written (POSIX ownership and modes):

* the **directory** must be owned by the user and writable by nobody else (no group/other
  write bit). A directory this module creates is made mode 0700 (``chmod`` after ``mkdir``,
  whatever the umask); an existing directory is never changed. A directory that fails the
  check (or cannot be created) is not used at all -- neither read nor written: one warning,
  the inspection goes on without the cache (:class:`qifreport.cache.CacheOutcome` status
  ``"refused"``);
* the directory holds the user's **secret**, ``<cache>/.key``: 32 random bytes, written to a
  private temporary file and hard-linked into place (exclusive: an existing key is never
  overwritten), mode 0600. A key file that is a symbolic link, not a regular file, not owned
  by the user, not mode 0600 or not 32 bytes refuses the directory as above;
* an **entry** is read only when it is a regular file (opened with ``O_NOFOLLOW``: never a
  symbolic link) owned by the user and writable by nobody else, checked on the open file;
* then its header must parse, name this format, carry the key :func:`qifreport.cache.part_state`
  **recomputes from the inputs** (the header's key is only compared, never trusted), the
  payload's length and SHA-256, and an HMAC-SHA256, under the secret, of the canonical header
  (all of it but the HMAC) and the payload, compared with :func:`hmac.compare_digest`. Only
  then is the payload unpickled. A header copied from another entry with a swapped payload
  fails the HMAC.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import json
import logging
import os
import secrets
import stat
import tempfile
from pathlib import Path

__all__ = [
    "KEY_BYTES",
    "KEY_FILE",
    "CorruptEntry",
    "UntrustedCache",
    "cache_secret",
    "check_cache_dir",
    "entry_mac",
    "open_entry",
]

log = logging.getLogger("qifreport.cache")

#: the per-user secret's file name inside the cache directory, and its length in bytes
KEY_FILE = ".key"
KEY_BYTES = 32
#: longest header line read from an entry, bytes
_MAX_HEADER = 1 << 20


class CorruptEntry(Exception):
    """A cache entry that cannot be trusted (the message says why)."""


class UntrustedCache(Exception):
    """A cache directory (or its key file) the current user cannot trust (the message names
    it and says why): the cache is not used."""


def _writable_by_others(mode: int) -> bool:
    """Whether ``mode`` lets the group or others write."""
    return bool(mode & (stat.S_IWGRP | stat.S_IWOTH))


def _owner_problem(st: os.stat_result) -> str:
    """Why a file or directory with status ``st`` is not the current user's alone ("" if it
    is)."""
    uid = os.geteuid()
    if st.st_uid != uid:
        return f"owned by uid {st.st_uid}, not by this user (uid {uid})"
    if _writable_by_others(st.st_mode):
        return f"writable by group or others (mode {stat.S_IMODE(st.st_mode):04o})"
    return ""


def check_cache_dir(cache_dir: Path, *, create: bool = True) -> None:
    """Check that ``cache_dir`` is the current user's alone; create it (mode 0700) if missing.

    Parameters
    ----------
    cache_dir : the cache directory.
    create : create a missing directory (its parents with the default mode, itself 0700).

    Raises
    ------
    UntrustedCache
        It cannot be created, is not a directory, is not owned by the current user or is
        writable by group or others. An existing directory is never modified.
    """
    cache_dir = Path(cache_dir)
    if create and not os.path.lexists(cache_dir):
        try:
            cache_dir.parent.mkdir(parents=True, exist_ok=True)
            os.mkdir(cache_dir, 0o700)
        except FileExistsError:
            pass  # created meanwhile (by another process): checked below like any other
        except OSError as exc:
            raise UntrustedCache(f"cache directory {cache_dir} cannot be created: {exc}") from exc
        else:
            os.chmod(cache_dir, 0o700)  # ours, just made: 0700 whatever the umask
            log.info("created the cache directory %s (mode 0700)", cache_dir)
    try:
        st = os.stat(cache_dir)
    except OSError as exc:
        raise UntrustedCache(f"cache directory {cache_dir} is unusable: {exc}") from exc
    if not stat.S_ISDIR(st.st_mode):
        raise UntrustedCache(f"cache directory {cache_dir} is not a directory")
    problem = _owner_problem(st)
    if problem:
        raise UntrustedCache(f"cache directory {cache_dir} is {problem}")


def _read_secret(path: Path) -> bytes | None:
    """The secret in ``path``, None if there is no such file; :class:`UntrustedCache` unless it
    is a regular file of the user's, mode 0600, :data:`KEY_BYTES` long."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    except OSError as exc:  # ELOOP: a symbolic link
        what = "a symbolic link" if os.path.islink(path) else f"unreadable ({exc})"
        raise UntrustedCache(f"cache key file {path} is {what}") from exc
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UntrustedCache(f"cache key file {path} is not a regular file")
        uid = os.geteuid()
        if st.st_uid != uid:
            raise UntrustedCache(
                f"cache key file {path} is owned by uid {st.st_uid}, not by this user (uid {uid})"
            )
        if stat.S_IMODE(st.st_mode) != 0o600:
            raise UntrustedCache(
                f"cache key file {path} has mode {stat.S_IMODE(st.st_mode):04o}, not 0600"
            )
        data = os.read(fd, KEY_BYTES + 1)
    finally:
        os.close(fd)
    if len(data) != KEY_BYTES:
        raise UntrustedCache(f"cache key file {path} is {len(data)} bytes, not {KEY_BYTES}")
    return data


def cache_secret(cache_dir: Path) -> bytes:
    """The current user's secret for ``cache_dir``, created on first use.

    The directory is checked (and created) by :func:`check_cache_dir`. A missing key is made
    from :func:`secrets.token_bytes` in a private temporary file (mode 0600) and hard-linked to
    ``<cache>/.key``: exclusive (an existing key, e.g. one another process made meanwhile,
    is never replaced) and atomic (no reader sees a partial key).

    Parameters
    ----------
    cache_dir : the cache directory.

    Returns
    -------
    bytes
        :data:`KEY_BYTES` bytes.

    Raises
    ------
    UntrustedCache
        The directory fails :func:`check_cache_dir`, or the key file is a symbolic link, not
        a regular file, not owned by the current user, not mode 0600 or not
        :data:`KEY_BYTES` long, or it cannot be created.
    """
    cache_dir = Path(cache_dir)
    check_cache_dir(cache_dir)
    path = cache_dir / KEY_FILE
    key = _read_secret(path)
    if key is not None:
        return key
    try:
        fd, tmp = tempfile.mkstemp(prefix=".tmp-key-", dir=cache_dir)
        try:
            os.fchmod(fd, 0o600)
            with os.fdopen(fd, "wb") as fh:
                fh.write(secrets.token_bytes(KEY_BYTES))
                fh.flush()
                os.fsync(fh.fileno())
            with contextlib.suppress(FileExistsError):  # another process was first: use its key
                os.link(tmp, path)
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    except OSError as exc:
        raise UntrustedCache(f"cache key file {path} cannot be created: {exc}") from exc
    key = _read_secret(path)
    if key is None:
        raise UntrustedCache(f"cache key file {path} vanished while it was created")
    log.info("created the cache key %s", path)
    return key


def _canonical(header: dict) -> bytes:
    return json.dumps(header, sort_keys=True, separators=(",", ":")).encode("utf-8")


def entry_mac(secret: bytes, header: dict, payload: bytes) -> str:
    """HMAC-SHA256 (hex) of an entry under ``secret``: the canonical JSON of ``header`` (every
    field but ``"hmac"``), a newline and the payload.

    Parameters
    ----------
    secret : the user's key (:func:`cache_secret`).  header : the entry's header.
    payload : the pickled state.
    """
    mac = hmac.new(secret, digestmod=hashlib.sha256)
    mac.update(_canonical({k: v for k, v in header.items() if k != "hmac"}))
    mac.update(b"\n")
    mac.update(payload)
    return mac.hexdigest()


def open_entry(path: Path) -> tuple[bytes, bytes]:
    """The header line and payload of ``path``, read only if it is a regular file (not a
    symbolic link) of the current user's, writable by nobody else; else :class:`CorruptEntry`.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        if os.path.islink(path):
            raise CorruptEntry("refused: a symbolic link") from exc
        raise CorruptEntry(f"unreadable: {exc}") from exc
    try:
        st = os.fstat(fd)  # the file opened, not whatever the name points at now
        if not stat.S_ISREG(st.st_mode):
            raise CorruptEntry("refused: not a regular file")
        problem = _owner_problem(st)
        if problem:
            raise CorruptEntry(f"refused: {problem}")
        with os.fdopen(fd, "rb") as fh:
            fd = -1
            return fh.readline(_MAX_HEADER), fh.read()
    except OSError as exc:
        raise CorruptEntry(f"unreadable: {exc}") from exc
    finally:
        if fd >= 0:
            os.close(fd)
