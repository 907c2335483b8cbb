"""Independent QIF consumers for tests: software we did not write reads our QIF files.

Two readers of the official QIF 3.0 schemas (``../shared/qif/xsd``), see ``../shared/README.md``
("Known traps"):

* **PyXB** (``pyxb-x`` on PyPI): ``pyxbgen`` generates a Python binding from the XSDs, which
  parses a document into typed objects. It checks content order, required elements,
  enumerations, facets (patterns, lengths, ranges) and the lexical form of decimals, dateTime
  and lists, but not key/keyref/unique.
* **Xerces-C** (``DOMCount`` from Debian ``libxerces-c-samples``): a full XSD 1.0 validator
  including identity constraints (key/keyref), run with ``-v=always -n -s -f``; exit 4 on error.

Both need the schemas with the xmldsig import resolved locally (no network):
:func:`local_xsd_copy` makes such a copy. A missing tool fails the test under CI (``CI=true``)
and skips it elsewhere, with the reason.

Typical use (the session fixtures ``qif_xsd`` and ``pyxb_qif`` are in ``tests/conftest.py``)::

    assert_read_by_independent_consumers(path, pyxb_qif, qif_xsd)
"""

from __future__ import annotations

import hashlib
import importlib.util
import itertools
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from types import ModuleType
from typing import NamedTuple

import pytest

from tests.conftest import shared_file

QIF_NS = "http://qifstandards.org/xsd/qif3"
XSI_NS = "http://www.w3.org/2001/XMLSchema-instance"
#: the remote location QIFDocument.xsd imports the W3C XML-signature schema from
DSIG_REMOTE = "http://www.w3.org/TR/2002/REC-xmldsig-core-20020212/xmldsig-core-schema.xsd"
#: where the local xmldsig copy goes, relative to the XSD root (QIFDocument.xsd's own comment
#: names this path as the local alternative to the remote import)
DSIG_LOCAL = "QIFLibrary/xmldsig-core-schema.xsd"
DOMCOUNT_ARGS = ("-v=always", "-n", "-s", "-f")
#: DOMCount's exit status when the document has errors
DOMCOUNT_ERROR_EXIT = 4

_module_ids = itertools.count()
#: the PyXB binding loaded in this process and a digest of the XSDs it came from: PyXB
#: registers namespaces process-wide, so a second binding of the same namespaces cannot load
_binding: tuple[str, ModuleType] | None = None


# ---------------------------------------------------------------------------------- helpers


def fail_or_skip(msg: str):
    """Fail the test under CI (env ``CI == "true"``), skip it elsewhere; never returns."""
    if os.environ.get("CI") == "true":
        pytest.fail(msg)
    pytest.skip(msg)


def poppler_tool(name: str) -> str:
    """Path of a poppler-utils command (``pdftoppm``, ``pdftotext``, ``pdfinfo``,
    ``pdffonts``); fails under CI and skips elsewhere when it is missing."""
    import shutil

    exe = shutil.which(name)
    if exe is None:
        fail_or_skip(f"{name} not found: install Debian package poppler-utils (`make system-deps`)")
    return exe


def shared_xsd_dir() -> Path:
    """The official QIF 3.0 XSD root in ../shared (``QIFApplications/``, ``QIFLibrary/``).

    Fails under CI and skips elsewhere when it is missing (``tests.conftest.shared_file``).
    """
    return shared_file("qif/xsd/QIFApplications/QIFDocument.xsd").parents[1]


def shared_xsd_available() -> bool:
    """True when the official XSDs are in ../shared (no skip, no failure)."""
    from tests.conftest import SHARED

    return (SHARED / "qif/xsd/QIFApplications/QIFDocument.xsd").is_file()


def _xmlschema_dsig() -> Path:
    """The W3C xmldsig schema bundled with the ``xmlschema`` package (a project dependency)."""
    import xmlschema

    p = Path(xmlschema.__file__).parent / "schemas" / "DSIG" / "xmldsig-core-schema.xsd"
    if not p.is_file():
        fail_or_skip(f"xmlschema's bundled xmldsig schema not found: {p}")
    return p


def domcount_command() -> str:
    """Path of Xerces-C ``DOMCount``; fails under CI, skips elsewhere if it is not installed."""
    exe = shutil.which("DOMCount")
    if exe is None:
        fail_or_skip(
            "DOMCount (Xerces-C) not found: install Debian package libxerces-c-samples "
            "(`make system-deps`)"
        )
    return exe


def pyxbgen_command() -> str:
    """Path of ``pyxbgen`` (beside this interpreter, else on PATH); fails under CI, skips
    elsewhere if ``pyxb-x`` is not installed."""
    here = Path(sys.executable).parent / "pyxbgen"
    exe = str(here) if here.is_file() else shutil.which("pyxbgen")
    if exe is None or importlib.util.find_spec("pyxb") is None:
        fail_or_skip("pyxbgen not found: install pyxb-x (`pip install -e '.[dev]'`)")
    return exe


# ------------------------------------------------------------------------------- XSD copy


def local_xsd_copy(dest: Path, src: Path | None = None) -> Path:
    """Copy the official QIF XSDs into ``dest`` with the xmldsig import resolved locally.

    ``src`` is the XSD root (default: ``../shared/qif/xsd``). In the copy only:
    xmlschema's bundled ``xmldsig-core-schema.xsd`` is put at ``QIFLibrary/`` (any DOCTYPE
    removed; the bundled file has it commented out) and the remote xmldsig ``schemaLocation``
    in ``QIFApplications/QIFDocument.xsd`` is rewritten to ``../QIFLibrary/...``. No other
    byte changes. Returns the copy's ``QIFApplications/QIFDocument.xsd``.
    """
    src = Path(src) if src is not None else shared_xsd_dir()
    dest = Path(dest)
    shutil.copytree(src, dest, dirs_exist_ok=True)
    dsig = _xmlschema_dsig().read_text(encoding="utf-8")
    # a live DOCTYPE (with internal subset) makes some tools fetch the remote DTD or choke
    dsig = re.sub(r"<!DOCTYPE\s[^\[>]*(\[.*?\]\s*)?>", "", dsig, count=1, flags=re.S)
    (dest / DSIG_LOCAL).write_text(dsig, encoding="utf-8")
    root = dest / "QIFApplications" / "QIFDocument.xsd"
    text = root.read_bytes()
    old = f'schemaLocation="{DSIG_REMOTE}"'.encode()
    if text.count(old) != 1:
        raise AssertionError(f"{root}: expected exactly one remote xmldsig import ({DSIG_REMOTE})")
    root.write_bytes(text.replace(old, f'schemaLocation="../{DSIG_LOCAL}"'.encode()))
    return root


# ------------------------------------------------------------------------------------ PyXB


def pyxb_binding(workdir: Path, xsd: Path | None = None) -> ModuleType:
    """Generate the PyXB binding of QIFDocument.xsd into ``workdir`` and import it.

    Runs ``pyxbgen --schema-location=<xsd> --module=QIFDocument`` (about 12 s; it also writes
    ``_ds.py`` for the xmldsig namespace) and imports the result from its file under a unique
    module name (about 8 s: 26 MB of generated source). ``xsd`` defaults to a fresh
    :func:`local_xsd_copy` in ``workdir/xsd``. Use it through the session fixture
    ``pyxb_qif`` (tests/conftest.py). A binding of the same schemas at the same location
    already in ``workdir`` is imported without generating it again.

    PyXB registers namespace bindings process-wide, so only one binding can be loaded per
    process: a later call with the same schemas returns the loaded module (nothing is
    generated); with different schemas it raises ``RuntimeError``.
    """
    global _binding
    exe = pyxbgen_command()
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    if xsd is None:
        xsd = local_xsd_copy(workdir / "xsd")
    xsd = Path(xsd).resolve()
    digest = _xsd_digest(xsd.parents[1])
    if _binding is not None:
        if _binding[0] != digest:
            raise RuntimeError(
                f"a PyXB binding of other schemas is already loaded ({_binding[1].__file__})"
            )
        return _binding[1]
    gen = workdir / "pyxb_gen"
    gen.mkdir(exist_ok=True)
    # a binding of these very schemas, at this location, generated before (by another
    # process sharing ``workdir``) is imported as it is
    made = gen / "schemas.sha256"
    stamp = f"{digest} {xsd}"
    if not (made.is_file() and made.read_text() == stamp):
        r = subprocess.run(
            [exe, f"--schema-location={xsd}", "--module=QIFDocument"],
            cwd=gen,
            capture_output=True,
            text=True,
        )
        if r.returncode != 0 or not (gen / "QIFDocument.py").is_file():
            raise RuntimeError(f"pyxbgen failed (exit {r.returncode}):\n{r.stdout}\n{r.stderr}")
        made.write_text(stamp)
    uid = f"qif_pyxb_{os.getpid()}_{next(_module_ids)}"
    # QIFDocument.py does `import _ds`: load it under a unique name and alias it while the
    # main module executes, so that nothing named `_ds` stays in sys.modules afterwards.
    ds = _import_file(f"{uid}_ds", gen / "_ds.py") if (gen / "_ds.py").is_file() else None
    saved = sys.modules.get("_ds")
    try:
        if ds is not None:
            sys.modules["_ds"] = ds
        module = _import_file(uid, gen / "QIFDocument.py")
    finally:
        if saved is not None:
            sys.modules["_ds"] = saved
        else:
            sys.modules.pop("_ds", None)
    _binding = (digest, module)
    return module


def _xsd_digest(root: Path) -> str:
    """SHA-256 over the relative paths and contents of the ``*.xsd`` files under ``root``."""
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.xsd")):
        h.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


def _import_file(name: str, path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(name, None)
        raise
    return module


def pyxb_read(module: ModuleType, path: Path) -> object:
    """Parse a QIF document with the PyXB binding; returns the root binding object
    (a ``QIFDocumentType`` for a QIF document).

    Invalid content raises PyXB's own exception (``pyxb.ValidationError`` subclasses such as
    ``UnrecognizedContentError``, ``SimpleFacetValueError``, ``SimpleTypeValueError``) with
    its message; dates Python's ``datetime`` cannot hold (hour 24, years outside 1..9999)
    raise ``ValueError``.
    """
    return module.CreateFromDocument(Path(path).read_bytes())


# --------------------------------------------------------------------------------- Xerces


class XercesResult(NamedTuple):
    """Outcome of :func:`xerces_validate`."""

    returncode: int  #: DOMCount's exit status: 0 valid, 4 errors
    output: str  #: stdout+stderr (temporary copy's path replaced by the document's)
    errors: list[str]  #: one ``"line L, char C: message"`` per error / fatal error
    warnings: list[str]  #: likewise for warnings (e.g. a schema file that cannot be opened)

    @property
    def ok(self) -> bool:
        """Valid: exit 0, no error and no warning."""
        return self.returncode == 0 and not self.errors and not self.warnings


_DIAG = re.compile(
    r"^(Fatal Error|Error|Warning) at file (.*?), line (\d+), char (\d+)\s*\n\s*Message: (.*)$",
    re.M,
)
# the root start tag: skip the XML declaration, PIs, comments and a DOCTYPE
_PROLOG_ITEM = re.compile(rb"\s*(<\?.*?\?>|<!--.*?-->|<!DOCTYPE\s(?:[^\[>]|\[.*?\])*>)", re.S)
_NAME = rb"[^\s=/>\"']+"
_VALUE = rb"(?:\"[^\"]*\"|'[^']*')"
_ATTR = re.compile(rb"(\s+)(" + _NAME + rb")(\s*=\s*)(" + _VALUE + rb")")
_START_TAG = re.compile(
    rb"<(" + _NAME + rb")((?:\s+" + _NAME + rb"\s*=\s*" + _VALUE + rb")*)\s*/?>"
)


def with_schema_location(data: bytes, xsd: Path) -> bytes:
    """``data`` (a UTF-8/ASCII QIF document) with the root's ``xsi:schemaLocation`` set to
    ``<QIF namespace> <xsd as file URI>``, added (with an ``xsi`` declaration if needed) when
    absent. Nothing else in the bytes changes."""
    bom = b"\xef\xbb\xbf" if data.startswith(b"\xef\xbb\xbf") else b""
    body = data[len(bom) :]
    if body.startswith((b"\xff\xfe", b"\xfe\xff")) or body[:4] in (b"<\0?\0", b"\0<\0?"):
        raise ValueError("UTF-16 documents are not supported here")
    pos = 0
    while m := _PROLOG_ITEM.match(body, pos):
        pos = m.end()
    while body[pos : pos + 1].isspace():
        pos += 1
    tag = _START_TAG.match(body, pos)
    if tag is None:
        raise ValueError("no root start tag found")
    attrs = list(_ATTR.finditer(tag.group(2)))
    xsi_prefixes = [
        a.group(2)[len(b"xmlns:") :]
        for a in attrs
        if a.group(2).startswith(b"xmlns:") and a.group(4)[1:-1] == XSI_NS.encode()
    ]
    value = f"{QIF_NS} {Path(xsd).resolve().as_uri()}".encode()
    existing = [a for a in attrs for p in xsi_prefixes if a.group(2) == p + b":schemaLocation"]
    start = tag.start(2)
    if existing:
        a = existing[0]
        q = a.group(4)[:1]
        s, e = start + a.start(4), start + a.end(4)
        new = body[:s] + q + value + q + body[e:]
    else:
        prefix = xsi_prefixes[0] if xsi_prefixes else b"xsi"
        if not xsi_prefixes:
            used = {a.group(2) for a in attrs}
            while b"xmlns:" + prefix in used:
                prefix += b"_"
        add = b"" if xsi_prefixes else b" xmlns:" + prefix + b'="' + XSI_NS.encode() + b'"'
        add += b" " + prefix + b':schemaLocation="' + value + b'"'
        new = body[: tag.end(2)] + add + body[tag.end(2) :]
    return bom + new


def xerces_validate(path: Path, xsd: Path) -> XercesResult:
    """Validate ``path`` with Xerces-C: ``DOMCount -v=always -n -s -f`` on a temporary copy
    whose ``xsi:schemaLocation`` points to ``xsd`` (e.g. from :func:`local_xsd_copy`), the
    only change. Returns ``XercesResult(returncode, output, errors, warnings)``, a tuple:
    ``rc, out, errors, warnings = xerces_validate(...)``.
    """
    exe = domcount_command()
    path, xsd = Path(path), Path(xsd)
    if not xsd.is_file():
        raise FileNotFoundError(xsd)
    with tempfile.TemporaryDirectory(prefix="qif-xerces-") as tmp:
        copy = Path(tmp) / path.name
        copy.write_bytes(with_schema_location(path.read_bytes(), xsd))
        r = subprocess.run(
            [exe, *DOMCOUNT_ARGS, str(copy)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
        )
        out = r.stdout.replace(str(copy), str(path))
    errors, warnings = [], []
    for kind, _file, line, char, msg in _DIAG.findall(out):
        (warnings if kind == "Warning" else errors).append(f"line {line}, char {char}: {msg}")
    if r.returncode != 0 and not errors:  # an exception DOMCount reports in another form
        errors.append(out.strip() or f"DOMCount exit {r.returncode}")
    return XercesResult(r.returncode, out, errors, warnings)


# ------------------------------------------------------------------------------ assertion


def assert_read_by_independent_consumers(path: Path, binding: ModuleType, xsd: Path) -> None:
    """Assert that both independent consumers accept the QIF document ``path``: the PyXB
    ``binding`` (:func:`pyxb_binding`) parses it into a ``QIFDocumentType`` without exception,
    and Xerces-C validates it against ``xsd`` (:func:`local_xsd_copy`) with exit 0 and no
    error or warning."""
    try:
        root = pyxb_read(binding, path)
    except Exception as e:  # report PyXB's message in the assertion
        details = e.details() if hasattr(e, "details") else str(e)
        raise AssertionError(f"PyXB rejects {path}: {type(e).__name__}: {details}") from e
    assert isinstance(root, binding.QIFDocumentType), (
        f"PyXB read {path} as {type(root).__name__}, not QIFDocumentType"
    )
    res = xerces_validate(path, xsd)
    assert res.ok, f"Xerces-C rejects {path} (exit {res.returncode}):\n" + "\n".join(
        res.errors + res.warnings
    )
