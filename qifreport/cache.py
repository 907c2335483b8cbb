"""The per-part cache: a nominal's prepared state, built once, loaded by every later scan.

``qifreport prepare PART.step`` (and, implicitly, the first inspection of a part) reads the
nominal, tessellates it, lays its tolerance zones and computes everything an inspection needs
from the nominal alone (:func:`qifreport.metrology.prepared.prepare_part`: operators, unscored
bands, bending basis, pose-search model). The result is one file in the cache directory::

    <cache>/<part stem>-<key[:20]>.qprep

Its name carries the **key**: the SHA-256 of a JSON document (the *key material*) holding
the SHA-256 of the nominal file, every parameter that changes the state (tolerance,
tessellation, bending energy, crease and rim bands, number of modes), the cache format
version and the versions of qifreport, numpy and scipy. A different part, parameter or
software version is a different entry; nothing is ever looked up by file name alone.

File layout: one line of JSON (the header: format, key, key material, SHA-256 and length of
the payload, build time, HMAC) followed by the payload, a pickle of :class:`PartState`.
Entries are written to a temporary file and renamed into place, so a reader never sees half an
entry and concurrent builders of one part are harmless (the last rename wins; both are
identical).

Trust. Unpickling runs code, so nothing is unpickled that anyone but the current user
(``os.geteuid()``) could have written (POSIX ownership and modes):

* the **directory** must be owned by the user and writable by nobody else (no group/other
  write bit). A directory this module creates is made mode 0700 (``chmod`` after ``mkdir``,
  whatever the umask); an existing directory is never changed. A directory that fails the
  check (or cannot be created) is not used at all -- neither read nor written: one warning,
  the inspection goes on without the cache (:class:`CacheOutcome` status ``"refused"``);
* the directory holds the user's **secret**, ``<cache>/.key``: 32 random bytes, written to a
  private temporary file and hard-linked into place (exclusive: an existing key is never
  overwritten), mode 0600. A key file that is a symbolic link, not a regular file, not owned
  by the user, not mode 0600 or not 32 bytes refuses the directory as above;
* an **entry** is read only when it is a regular file (opened with ``O_NOFOLLOW``: never a
  symbolic link) owned by the user and writable by nobody else, checked on the open file;
* then its header must parse, name this format, carry the key :func:`part_state`
  **recomputes from the inputs** (the header's key is only compared, never trusted), the
  payload's length and SHA-256, and an HMAC-SHA256, under the secret, of the canonical header
  (all of it but the HMAC) and the payload, compared with :func:`hmac.compare_digest`. Only
  then is the payload unpickled. A header copied from another entry with a swapped payload
  fails the HMAC.

An entry that fails any check is logged and never used; the state is rebuilt and the entry
replaced by a fresh one (the directory is the user's, so replacing it is the user's to do).
Running as another user (root included) against someone's cache directory therefore runs
without the cache.
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import json
import logging
import os
import pickle
import secrets
import stat
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import scipy

from qifreport import __version__
from qifreport.metrology.model import Drawing, Part
from qifreport.metrology.params import InspectionParams
from qifreport.metrology.prepared import PreparedPart, part_settings, prepare_part
from qifreport.registration.deformable.methods import method_spec
from qifreport.registration.restraint.restrained import RestraintBasis

from .nominal import load_nominal
from .options import NominalOptions
from .restraint import build_restraint, with_limits

__all__ = [
    "CACHE_FORMAT",
    "CacheOutcome",
    "CorruptEntry",
    "KEY_BYTES",
    "KEY_FILE",
    "NominalOptions",
    "PartState",
    "UntrustedCache",
    "cache_key",
    "cache_secret",
    "check_cache_dir",
    "default_cache_dir",
    "entry_mac",
    "entry_path",
    "key_material",
    "load_entry",
    "part_state",
    "save_entry",
    "sha256",
]

log = logging.getLogger(__name__)

#: version of the entry layout, part of every key: an entry written by another layout of
#: :class:`PartState` (or of anything it holds) is never read; bump it when that changes
CACHE_FORMAT = 17
SUFFIX = ".qprep"
#: the per-user secret's file name inside the cache directory, and its length in bytes
KEY_FILE = ".key"
KEY_BYTES = 32
_MAX_HEADER = 1 << 20


def sha256(path: Path) -> str:
    """Hex SHA-256 digest of a file."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def default_cache_dir() -> Path:
    """``$QIFREPORT_CACHE``, else the user cache directory (``~/.cache/qifreport``)."""
    env = os.environ.get("QIFREPORT_CACHE")
    if env:
        return Path(env)
    import platformdirs

    return Path(platformdirs.user_cache_dir("qifreport", appauthor=False))


@dataclass
class PartState:
    """A nominal read and prepared: all an inspection of one more scan needs from the part.

    Attributes
    ----------
    part : the nominal's mesh, faces and provenance (:class:`qifreport.metrology.model.Part`).
    drawing : its zones, characteristics and datums (:class:`qifreport.metrology.model.Drawing`).
    prepared : the scan-independent state (:class:`qifreport.metrology.prepared.PreparedPart`).
    nominal_sha256 : digest of the nominal file.  key : the cache key.
    build_seconds : what reading and preparing took when the entry was built.
    restraint : the part's restraint basis (:func:`qifreport.restraint.build_restraint`)
        when the options hold it at clamps; None otherwise.
    """

    part: Part
    drawing: Drawing
    prepared: PreparedPart
    nominal_sha256: str
    key: str
    build_seconds: float = 0.0
    restraint: RestraintBasis | None = None


@dataclass
class CacheOutcome:
    """How :func:`part_state` obtained the state.

    Attributes
    ----------
    status : ``"hit"`` (loaded), ``"built"`` (no entry), ``"rebuilt"`` (an entry was
        refused: see ``reason``), ``"refused"`` (the cache directory is not trusted, see
        ``reason``: neither read nor written) or ``"off"`` (no cache directory).
    path : the entry file (None when off or refused).
    reason : why an entry, or the directory, was refused.
    seconds : time to obtain the state (load, or read + prepare).
    build_seconds : the entry's original build time.
    """

    status: str
    path: Path | None
    seconds: float
    build_seconds: float
    reason: str = ""
    timings: dict = field(default_factory=dict)

    def describe(self) -> str:
        if self.status == "hit":
            return (
                f"part state loaded from cache in {self.seconds:.2f} s (building it took "
                f"{self.build_seconds:.1f} s): {self.path}"
            )
        if self.status == "off":
            return f"part state prepared in {self.seconds:.1f} s (no cache)"
        if self.status == "refused":
            return f"part state prepared in {self.seconds:.1f} s (cache not used: {self.reason})"
        why = f" (cache entry refused: {self.reason})" if self.reason else ""
        return f"part state prepared in {self.seconds:.1f} s{why}, cached: {self.path}"


class CorruptEntry(Exception):
    """A cache entry that cannot be trusted (the message says why)."""


class UntrustedCache(Exception):
    """A cache directory (or its key file) the current user cannot trust (the message names
    it and says why): the cache is not used."""


def _writable_by_others(mode: int) -> bool:
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


def key_material(nominal_sha256: str, options: NominalOptions, params: InspectionParams) -> dict:
    """Everything the prepared state depends on, as a JSON-able dict.

    Parameters
    ----------
    nominal_sha256 : digest of the nominal file.  options : how it is read.
    params : :class:`qifreport.metrology.params.InspectionParams`.
    """
    return {
        "format": CACHE_FORMAT,
        "software": __version__,
        "numpy": ".".join(np.__version__.split(".")[:2]),
        "scipy": ".".join(scipy.__version__.split(".")[:2]),
        "nominal_sha256": nominal_sha256,
        "nominal": {
            "tolerance": options.tolerance,
            "max_edge": options.max_edge,
            "deflection": options.deflection,
            "accept_tolerance_as_read": options.accept_tolerance_as_read,
            "mesher": options.mesher,
            "solid": options.solid,
        },
        "part": part_settings(params),
        "restraint": None if options.restraint is None else options.restraint.key(),
    }


def cache_key(material: dict) -> str:
    """SHA-256 of the canonical JSON of the key material."""
    text = json.dumps(material, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def entry_path(cache_dir: Path, nominal: Path, key: str) -> Path:
    """``<cache>/<stem>-<key[:20]>.qprep``."""
    stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in nominal.stem)[:40]
    return Path(cache_dir) / f"{stem}-{key[:20]}{SUFFIX}"


def build_state(
    nominal: Path,
    options: NominalOptions,
    params: InspectionParams,
    nominal_sha256: str,
    key: str = "",
    complete: bool = True,
    lazy_basis: bool = False,
    on_nominal: Callable[[Part], None] | None = None,
) -> PartState:
    """Read the nominal and prepare it.

    ``complete``: everything any inspection of the part may need (a cache entry serves
    them all); otherwise only what an inspection with ``params`` needs up front (the bending
    basis for GB-CICP; the pose search builds its model itself if the scan needs it).
    ``lazy_basis``: leave out the bending basis, the costliest part (an inspection that
    judges the free state first needs it only when the free state does not conform; it is
    then built by the fixture, and a cache entry's stored by :func:`store_basis`), with or
    without ``complete``. ``on_nominal``: called with the part once it is read, before
    it is prepared (:func:`part_state`).
    """
    t0 = time.perf_counter()
    part, drawing = load_nominal(
        nominal,
        options.tolerance,
        options.max_edge,
        options.deflection,
        accept_tolerance_as_read=options.accept_tolerance_as_read,
        mesher=options.mesher,
        solid=options.solid,
        solid_mesh=options.restraint is not None,
    )
    restraint = None
    if options.restraint is not None:
        solid = None if part.solid_mesh is None else (part.solid_mesh.X, part.solid_mesh.T)
        restraint = build_restraint(part.V, part.F, options.restraint, solid=solid)
        part.solid_mesh = None  # in the basis now: not kept in the cache entry
    if on_nominal is not None:
        on_nominal(part)
    if complete:
        prepared = prepare_part(part.V, part.F, params, basis=not lazy_basis)
    else:
        basis = (
            method_spec(params.method).uses_bending_basis
            and not params.rigid_only
            and params.gbcicp.solver == "modal"
            and not lazy_basis
        )
        prepared = prepare_part(part.V, part.F, params, basis=basis, model=False)
    return PartState(
        part=part,
        drawing=drawing,
        prepared=prepared,
        nominal_sha256=nominal_sha256,
        key=key,
        build_seconds=time.perf_counter() - t0,
        restraint=restraint,
    )


def save_entry(path: Path, state: PartState, material: dict, secret: bytes) -> None:
    """Write ``state`` to ``path`` atomically (temporary file in the same directory, mode 0600,
    renamed), authenticated with ``secret``.

    Parameters
    ----------
    path : the entry file (:func:`entry_path`), in a directory :func:`cache_secret` accepted.
    state : the state.  material : its key material (:func:`key_material`).
    secret : the user's key (:func:`cache_secret`).
    """
    payload = pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
    header = {
        "format": CACHE_FORMAT,
        "key": state.key,
        "material": material,
        "payload_sha256": hashlib.sha256(payload).hexdigest(),
        "payload_bytes": len(payload),
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "build_seconds": state.build_seconds,
    }
    header["hmac"] = entry_mac(secret, header, payload)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=SUFFIX, dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(json.dumps(header, sort_keys=True).encode("utf-8") + b"\n")
            fh.write(payload)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _open_entry(path: Path) -> tuple[bytes, bytes]:
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


def load_entry(path: Path, key: str, secret: bytes) -> PartState:
    """Read, check and verify one entry; :class:`CorruptEntry` (with the reason) unless trusted.

    The payload is unpickled only after every check of the module docstring passed: the file
    is the user's regular file, the header names this format and ``key``, the payload has the
    recorded length and SHA-256, and the HMAC under ``secret`` matches.

    Parameters
    ----------
    path : the entry file.  key : the key recomputed from the inputs (:func:`cache_key`).
    secret : the user's key (:func:`cache_secret`).
    """
    line, payload = _open_entry(path)
    try:
        header = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CorruptEntry("header is not JSON") from exc
    if not isinstance(header, dict) or header.get("format") != CACHE_FORMAT:
        raise CorruptEntry(
            f"format {header.get('format') if isinstance(header, dict) else '?'}"
            f", expected {CACHE_FORMAT}"
        )
    if header.get("key") != key:
        raise CorruptEntry("key differs (stale entry)")
    if len(payload) != header.get("payload_bytes"):
        raise CorruptEntry(
            f"payload is {len(payload)} bytes, header says "
            f"{header.get('payload_bytes')} (truncated?)"
        )
    if hashlib.sha256(payload).hexdigest() != header.get("payload_sha256"):
        raise CorruptEntry("payload SHA-256 mismatch (corrupted)")
    recorded = header.get("hmac")
    if not isinstance(recorded, str) or not hmac.compare_digest(
        entry_mac(secret, header, payload).encode("ascii"), recorded.encode("utf-8")
    ):
        raise CorruptEntry("refused: HMAC mismatch (not written with this cache's key)")
    try:
        state = pickle.loads(payload)
    except Exception as exc:  # an authenticated payload that does not unpickle: another build
        raise CorruptEntry(f"payload does not load: {type(exc).__name__}: {exc}") from exc
    if not isinstance(state, PartState) or state.key != key:
        raise CorruptEntry("payload is not this part's state")
    return state


def part_state(
    nominal: Path,
    options: NominalOptions,
    params: InspectionParams,
    cache_dir: Path | None,
    *,
    rebuild: bool = False,
    lazy_basis: bool = False,
    on_nominal: Callable[[Part], None] | None = None,
) -> tuple[PartState, CacheOutcome]:
    """The prepared state of ``nominal``: loaded from ``cache_dir`` when a trusted entry
    exists, else built (and stored there).

    Parameters
    ----------
    nominal : the nominal file (STEP or mesh).  options : how it is read.
    params : :class:`qifreport.metrology.params.InspectionParams` of the inspections to come.
    cache_dir : cache directory, None to neither read nor write one. A directory that fails
        :func:`cache_secret` is not used either (one warning; status ``"refused"``).
    rebuild : ignore an existing entry and build a fresh one.
    lazy_basis : a built state leaves out the bending basis (:func:`build_state`): the
        fixture builds it if the free state does not conform, beside the free state's
        judgement; with a cache the caller stores it then (:func:`store_basis`).
    on_nominal : called once with the part (:class:`qifreport.metrology.model.Part`) as soon
        as it is known: when a state is built, after reading it and before preparing it (the
        costly part), so that work needing only the mesh can start beside the preparation
        (the command line's scan measures); on a cache hit, once the entry is loaded.

    Raises
    ------
    qifreport.errors.InputError
        The nominal cannot be read (as :func:`qifreport.nominal.load_nominal`).
    """
    t0 = time.perf_counter()
    digest = sha256(nominal)
    material = key_material(digest, options, params)
    key = cache_key(material)

    def for_one_inspection() -> PartState:  # without a cache: only what it needs
        return build_state(
            nominal,
            options,
            params,
            digest,
            key,
            complete=False,
            lazy_basis=lazy_basis,
            on_nominal=on_nominal,
        )

    if cache_dir is None:
        state = for_one_inspection()
        return state, CacheOutcome(
            "off",
            None,
            time.perf_counter() - t0,
            state.build_seconds,
            timings=dict(state.prepared.timings),
        )
    try:
        secret = cache_secret(cache_dir)
    except UntrustedCache as exc:  # never read nor write a directory others could write
        log.warning("%s: the part is prepared without the cache", exc)
        state = for_one_inspection()
        return state, CacheOutcome(
            "refused",
            None,
            time.perf_counter() - t0,
            state.build_seconds,
            reason=str(exc),
            timings=dict(state.prepared.timings),
        )
    path = entry_path(cache_dir, nominal, key)
    reason = ""
    exists = os.path.lexists(path)  # a symbolic link (even a dangling one) is refused
    if exists and not rebuild:
        try:
            state = load_entry(path, key, secret)
            if state.restraint is not None and options.restraint is not None:
                with_limits(state.restraint, options.restraint)
            log.info("part state loaded from %s", path)
            outcome = CacheOutcome("hit", path, time.perf_counter() - t0, state.build_seconds)
            if on_nominal is not None:
                on_nominal(state.part)
            return state, outcome
        except CorruptEntry as exc:
            reason = str(exc)
            log.warning("cache entry %s refused (%s): rebuilding it", path, reason)
    elif rebuild and exists:
        reason = "rebuild asked for"
    state = build_state(
        nominal, options, params, digest, key, lazy_basis=lazy_basis, on_nominal=on_nominal
    )
    try:
        save_entry(path, state, material, secret)
    except OSError as exc:  # a read-only cache must not stop an inspection
        log.warning("could not write the cache entry %s: %s", path, exc)
    status = "rebuilt" if reason else "built"
    return state, CacheOutcome(
        status,
        path,
        time.perf_counter() - t0,
        state.build_seconds,
        reason=reason,
        timings=dict(state.prepared.timings),
    )


def store_basis(
    state: PartState,
    outcome: CacheOutcome,
    basis,
    options: NominalOptions,
    params: InspectionParams,
    cache_dir: Path | None,
) -> bool:
    """Complete a cache entry built without its bending basis with the ``basis`` an
    inspection's virtual fixture built
    (:class:`qifreport.registration.deformable.bending_basis.BendingBasis`
    of this part's mesh and settings). True when the entry was rewritten; a cache that
    cannot be written is left as it is (logged)."""
    if (
        basis is None
        or outcome.path is None
        or cache_dir is None
        or state.prepared.basis is not None
        or len(basis.Phi) != len(state.part.V)
        or basis.energy != state.prepared.energy
    ):
        return False
    state.prepared.basis = basis
    try:
        save_entry(
            outcome.path,
            state,
            key_material(state.nominal_sha256, options, params),
            cache_secret(cache_dir),
        )
    except (OSError, UntrustedCache) as exc:
        log.warning("could not complete the cache entry %s: %s", outcome.path, exc)
        return False
    log.info("bending basis stored in %s", outcome.path)
    return True
