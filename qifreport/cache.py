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

Trust (:mod:`qifreport.cache_trust`): nothing is unpickled that anyone but the current user
could have written, and only after its header and an HMAC under the user's secret check out.

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
from qifreport.registration.restraint.fixture_load import LoadModel
from qifreport.registration.restraint.restrained import RestraintBasis

from .atomic_io import sha256
from .cache_prune import SUFFIX, prune, size_limit, touch
from .cache_trust import (
    CorruptEntry,
    UntrustedCache,
    cache_secret,
    entry_mac,
    open_entry,
)
from .nominal import load_nominal
from .options import NominalOptions
from .restraint import (
    build_load_model,
    build_restraint,
    restraint_with_drawing_material,
    with_drawing_material,
    with_limits,
)

__all__ = [
    "CACHE_FORMAT",
    "CacheOutcome",
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

#: version of the entry layout, part of every key: an entry written by another layout of
#: :class:`PartState` (or of anything it holds) is never read; bump it when that changes
CACHE_FORMAT = 25


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
    fixture_load : the part's elastic model for the virtual fixture's load
        (:func:`qifreport.restraint.build_load_model`), or why there is none (a sentence);
        None when no virtual fixture is to be bounded (rigid only, held at clamps).
    """

    part: Part
    drawing: Drawing
    prepared: PreparedPart
    nominal_sha256: str
    key: str
    build_seconds: float = 0.0
    restraint: RestraintBasis | None = None
    fixture_load: LoadModel | str | None = None


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
        "fixture_load": None if options.fixture_load is None else options.fixture_load.key(),
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
    its elastic models are built and it is prepared (:func:`part_state`).
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
        solid_mesh=options.restraint is not None or _loads(options),
        solid_mesh_for_material=options.fixture_load is not None,
    )
    if on_nominal is not None:  # the mesh is known: what needs only it starts (or stops) now
        on_nominal(part)
    restraint = fixture_load = None
    solid = None if part.solid_mesh is None else (part.solid_mesh.X, part.solid_mesh.T)
    if options.restraint is not None:
        held = restraint_with_drawing_material(options.restraint, drawing.material)
        restraint = build_restraint(part.V, part.F, held, solid=solid)
    if options.fixture_load is not None:
        spec = with_drawing_material(options.fixture_load, drawing.material)
        fixture_load = (
            spec
            if isinstance(spec, str)
            else build_load_model(part.V, part.F, spec, solid=solid, step=part.face_id is not None)
        )
    part.solid_mesh = None  # in the models now: not kept in the cache entry
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
        fixture_load=fixture_load,
    )


def _loads(options: NominalOptions) -> bool:
    """Whether the virtual fixture's load is to be measured on a model of the part's
    solid (a material is stated)."""
    return options.fixture_load is not None and options.fixture_load.material is not None


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
    line, payload = open_entry(path)
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

    def built(status: str, reason: str = "", path: Path | None = None, secret: bytes = b""):
        # without an entry to write, only what one inspection needs
        state = build_state(
            nominal,
            options,
            params,
            digest,
            key,
            complete=path is not None,
            lazy_basis=lazy_basis,
            on_nominal=on_nominal,
        )
        if path is not None:
            try:
                save_entry(path, state, material, secret)
                prune(path.parent, size_limit(), keep=path)
            except OSError as exc:  # a read-only cache must not stop an inspection
                log.warning("could not write the cache entry %s: %s", path, exc)
        return state, CacheOutcome(
            status,
            path,
            time.perf_counter() - t0,
            state.build_seconds,
            reason=reason,
            timings=dict(state.prepared.timings),
        )

    if cache_dir is None:
        return built("off")
    try:
        secret = cache_secret(cache_dir)
    except UntrustedCache as exc:  # never read nor write a directory others could write
        log.warning("%s: the part is prepared without the cache", exc)
        return built("refused", str(exc))
    path = entry_path(cache_dir, nominal, key)
    reason = ""
    exists = os.path.lexists(path)  # a symbolic link (even a dangling one) is refused
    if exists and not rebuild:
        try:
            return _cache_hit(path, key, secret, options, on_nominal, t0)
        except CorruptEntry as exc:
            reason = str(exc)
            log.warning("cache entry %s refused (%s): rebuilding it", path, reason)
    elif rebuild and exists:
        reason = "rebuild asked for"
    return built("rebuilt" if reason else "built", reason, path, secret)


def _cache_hit(
    path: Path,
    key: str,
    secret: bytes,
    options: NominalOptions,
    on_nominal: Callable[[Part], None] | None,
    t0: float,
) -> tuple[PartState, CacheOutcome]:
    """The state in the entry ``path`` (:func:`load_entry`; :class:`CorruptEntry` when it is
    refused), with the options' clamp force limits, and how it was obtained (``t0``: when
    :func:`part_state` started, :func:`time.perf_counter`)."""
    state = load_entry(path, key, secret)
    touch(path)  # its last use: the size bound evicts the entries used longest ago
    if state.restraint is not None and options.restraint is not None:
        with_limits(state.restraint, options.restraint)
    log.info("part state loaded from %s", path)
    outcome = CacheOutcome("hit", path, time.perf_counter() - t0, state.build_seconds)
    if on_nominal is not None:
        on_nominal(state.part)
    return state, outcome


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
