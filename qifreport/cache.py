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
the payload, build time) followed by the payload, a pickle of :class:`PartState`. An entry is
trusted only when the header parses, its format and key match the ones asked for, and the
payload's length and SHA-256 match the header; anything else (truncated, bit-flipped, written
by another version, unreadable) is logged, rebuilt and replaced -- never used. Entries are
written to a temporary file and renamed into place, so a reader never sees half an entry and
concurrent builders of one part are harmless (the last rename wins; both are identical).

The payload is a pickle: load entries only from a cache directory you trust as much as the
installation itself (the default is the user's own cache directory).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import pickle
import tempfile
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import scipy

from qifreport import __version__
from qifreport.metrology.params import InspectionParams
from qifreport.metrology.prepared import PreparedPart, part_settings, prepare_part

from .nominal import Nominal, load_nominal
from .options import NominalOptions

__all__ = [
    "CACHE_FORMAT",
    "CacheOutcome",
    "CorruptEntry",
    "NominalOptions",
    "PartState",
    "cache_key",
    "default_cache_dir",
    "entry_path",
    "key_material",
    "load_entry",
    "part_state",
    "save_entry",
    "sha256",
]

log = logging.getLogger(__name__)

#: version of the entry layout; bump it whenever :class:`PartState` or anything it holds
#: changes shape
#: 2: module paths under the one import root qifreport.* (pickles name them)
CACHE_FORMAT = 2
SUFFIX = ".qprep"


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
    nominal : mesh, face ids, zones and provenance (:class:`qifreport.nominal.Nominal`).
    prepared : the scan-independent state (:class:`qifreport.metrology.prepared.PreparedPart`).
    nominal_sha256 : digest of the nominal file.  key : the cache key.
    build_seconds : what reading and preparing took when the entry was built.
    """

    nominal: Nominal
    prepared: PreparedPart
    nominal_sha256: str
    key: str
    build_seconds: float = 0.0


@dataclass
class CacheOutcome:
    """How :func:`part_state` obtained the state.

    Attributes
    ----------
    status : ``"hit"`` (loaded), ``"built"`` (no entry), ``"rebuilt"`` (an entry was
        refused: see ``reason``) or ``"off"`` (no cache directory).
    path : the entry file (None when off).  reason : why an entry was refused.
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
        why = f" (cache entry refused: {self.reason})" if self.reason else ""
        return f"part state prepared in {self.seconds:.1f} s{why}, cached: {self.path}"


class CorruptEntry(Exception):
    """A cache entry that cannot be trusted (the message says why)."""


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
        },
        "part": part_settings(params),
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
) -> PartState:
    """Read the nominal and prepare it.

    ``complete``: everything any inspection of the part may need (a cache entry serves
    them all); otherwise only what an inspection with ``params`` needs up front (the bending
    basis for GB-CICP; the pose search builds its model itself if the scan needs it).
    """
    t0 = time.perf_counter()
    nom = load_nominal(nominal, options.tolerance, options.max_edge, options.deflection)
    if complete:
        prepared = prepare_part(nom.V, nom.F, params)
    else:
        basis = (
            params.method == "gbcicp" and not params.rigid_only and params.gbcicp.solver == "modal"
        )
        prepared = prepare_part(nom.V, nom.F, params, basis=basis, model=False)
    return PartState(
        nominal=nom,
        prepared=prepared,
        nominal_sha256=nominal_sha256,
        key=key,
        build_seconds=time.perf_counter() - t0,
    )


def save_entry(path: Path, state: PartState, material: dict) -> None:
    """Write ``state`` to ``path`` atomically (temporary file in the same directory, renamed)."""
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
    path.parent.mkdir(parents=True, exist_ok=True)
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


def load_entry(path: Path, key: str) -> PartState:
    """Read and verify one entry; :class:`CorruptEntry` (with the reason) unless trusted."""
    try:
        with open(path, "rb") as fh:
            line = fh.readline(1 << 20)
            payload = fh.read()
    except OSError as exc:
        raise CorruptEntry(f"unreadable: {exc}") from exc
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
    try:
        state = pickle.loads(payload)
    except Exception as exc:  # a verified payload that does not unpickle: another build
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
) -> tuple[PartState, CacheOutcome]:
    """The prepared state of ``nominal``: loaded from ``cache_dir`` when a trusted entry
    exists, else built (and stored there).

    Parameters
    ----------
    nominal : the nominal file (STEP or mesh).  options : how it is read.
    params : :class:`qifreport.metrology.params.InspectionParams` of the inspections to come.
    cache_dir : cache directory, None to neither read nor write one.
    rebuild : ignore an existing entry and build a fresh one.

    Raises
    ------
    qifreport.errors.InputError
        The nominal cannot be read (as :func:`qifreport.nominal.load_nominal`).
    """
    t0 = time.perf_counter()
    digest = sha256(nominal)
    material = key_material(digest, options, params)
    key = cache_key(material)
    if cache_dir is None:  # one inspection: build only what it needs
        state = build_state(nominal, options, params, digest, key, complete=False)
        return state, CacheOutcome(
            "off",
            None,
            time.perf_counter() - t0,
            state.build_seconds,
            timings=dict(state.prepared.timings),
        )
    path = entry_path(cache_dir, nominal, key)
    reason = ""
    if path.exists() and not rebuild:
        try:
            state = load_entry(path, key)
            log.info("part state loaded from %s", path)
            return state, CacheOutcome("hit", path, time.perf_counter() - t0, state.build_seconds)
        except CorruptEntry as exc:
            reason = str(exc)
            log.warning("cache entry %s refused (%s): rebuilding it", path, reason)
    elif rebuild and path.exists():
        reason = "rebuild asked for"
    state = build_state(nominal, options, params, digest, key)
    try:
        save_entry(path, state, material)
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
