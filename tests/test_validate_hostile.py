"""``qifreport validate`` on hostile files: bounded time and memory, exit 2 or findings.

Every case runs the real console script as a subprocess under an address-space limit
(``RLIMIT_AS`` 2 GiB) and a 60 s timeout, and checks: exit 1 or 2, no traceback, at most two
lines on stderr, done in time; a secret string planted where a hostile file points is never
in the output. The files named on the command line are refused before anything parses them
(a device, a FIFO, a directory, a socket, over 100 MiB, a DOCTYPE: XXE, billion laughs);
the documents a file links to (``ExternalQIFReferences``) are followed by the DMSC checks
only inside the file's own folder tree, as regular files within the size limit, and a refused
one is a ``CheckDocuments`` finding ("linked document refused: WHY").

The linked-document cases run with ``--no-strict``: xmlschema does not follow links, and its
schema load (5-40 s on a busy machine) would only eat the time limit. The one in-process test
is the DMSC time limit (:data:`qifreport.qif.dmsc.DMSC_TIMEOUT_S`), which no file can
trigger quickly.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.conftest import shared_file

EXE = Path(sys.executable).parent / "qifreport"
#: the address-space limit of every run
LIMIT_AS = 2 << 30
#: seconds a run may take
TIMEOUT = 60.0
#: stderr lines a run may print
MAX_STDERR_LINES = 2
SECRET = "QIFREPORT-SECRET-5e1f0c7a"
RESULTS = "qif/samples/community/Exploded_Results1.QIF"
PLAN = "qif/samples/community/Exploded_Plan.QIF"
LINK = "./Exploded_Plan.QIF"  # the URI of RESULTS


@dataclass
class Run:
    """A finished ``qifreport validate`` run."""

    rc: int
    stdout: str
    stderr: str
    elapsed: float
    peak_mib: float

    @property
    def output(self) -> str:
        return self.stdout + self.stderr


_LAUNCH = (
    "import os, resource, sys; n = int(sys.argv[1]); "
    "resource.setrlimit(resource.RLIMIT_AS, (n, n)); os.execv(sys.argv[2], sys.argv[2:])"
)


def _vm_hwm_kib(pid: int) -> int:
    """``VmHWM`` of a running process, KiB (0 once it has exited)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _drain(stream, sink: list[str]) -> None:
    sink.append(stream.read())


def run_validate(*args: object) -> Run:
    """``qifreport validate ARGS`` under RLIMIT_AS and the timeout (killed and failed after it).

    The child's own peak resident memory is its ``VmHWM``, polled while it runs.
    """
    t0 = time.monotonic()
    # a small launcher sets the limit and execs the command: no preexec_fn, so the child is
    # spawned without a copy of this (possibly large) process, whose resident size Linux
    # would otherwise carry into the child's ru_maxrss
    proc = subprocess.Popen(
        [sys.executable, "-c", _LAUNCH, str(LIMIT_AS), str(EXE), "validate", *map(str, args)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    out: list[str] = []
    err: list[str] = []
    readers = [
        threading.Thread(target=_drain, args=(proc.stdout, out), daemon=True),
        threading.Thread(target=_drain, args=(proc.stderr, err), daemon=True),
    ]
    for r in readers:
        r.start()
    peak_kib = 0
    while True:
        peak_kib = max(peak_kib, _vm_hwm_kib(proc.pid))
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        if time.monotonic() - t0 > TIMEOUT:
            proc.kill()
            os.wait4(proc.pid, 0)
            proc.returncode = -9
            pytest.fail(f"qifreport validate {args} still running after {TIMEOUT:g} s (killed)")
        time.sleep(0.02)
    elapsed = time.monotonic() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    for r in readers:
        r.join(10)
    proc.stdout.close()
    proc.stderr.close()
    # the child's own high-water mark (VmHWM, read while it runs): ru_maxrss would carry the
    # resident size of this, possibly large, test process across fork and exec
    run = Run(proc.returncode, "".join(out), "".join(err), elapsed, peak_kib / 1024)
    print(f"{' '.join(map(str, args))}: exit {run.rc}, {elapsed:.2f} s, {run.peak_mib:.0f} MiB")
    return run


def assert_safe(run: Run, rcs: tuple[int, ...] = (1, 2)) -> None:
    """Exit in ``rcs``, no traceback, a few stderr lines at most, in time, no secret."""
    assert run.rc in rcs, run
    assert "Traceback" not in run.output, run.stderr
    assert len(run.stderr.splitlines()) <= MAX_STDERR_LINES, run.stderr
    assert run.elapsed < TIMEOUT
    assert SECRET not in run.output


def _results_with_link(uri: str) -> str:
    """The community results file with its one external reference pointing at ``uri``."""
    text = shared_file(RESULTS).read_text(encoding="utf-8")
    assert text.count(f"<URI>{LINK}</URI>") == 1
    return text.replace(f"<URI>{LINK}</URI>", f"<URI>{uri}</URI>")


def _with_doctype(doctype: str, entity_ref: str = "") -> str:
    """The community results file with ``doctype`` after its XML declaration (and an entity
    reference in its QPId, where the DMSC checks would print a linked document's)."""
    text = shared_file(RESULTS).read_text(encoding="utf-8")
    decl, rest = text.split("\n", 1)
    assert decl.startswith("<?xml")
    return f"{decl}\n{doctype}\n" + rest.replace("<QPId>", f"<QPId>{entity_ref}", 1)


# --------------------------------------------------------------------------------------------
# the file named on the command line


def test_dev_zero_is_refused():
    run = run_validate("/dev/zero")
    assert_safe(run, (2,))
    assert run.stderr == (
        "qifreport: error: /dev/zero: not a regular file (a character device); not checked\n"
    )
    assert run.stdout == ""


def test_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.QIF"
    os.mkfifo(fifo)  # nobody ever writes: opening it for reading would block
    run = run_validate(fifo)
    assert_safe(run, (2,))
    assert run.stderr == f"qifreport: error: {fifo}: not a regular file (a FIFO); not checked\n"


def test_directory_and_socket_are_refused(tmp_path):
    short = Path(tempfile.mkdtemp(prefix="qv"))  # a socket path is limited to ~100 bytes
    sock_path = short / "s.QIF"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.bind(str(sock_path))
        run = run_validate(tmp_path, sock_path)
    sock_path.unlink()
    short.rmdir()
    assert_safe(run, (2,))
    assert run.stderr.splitlines() == [
        f"qifreport: error: {tmp_path}: not a regular file (a directory); not checked",
        f"qifreport: error: {sock_path}: not a regular file (a socket); not checked",
    ]


def test_200_mb_file_is_refused_unread(tmp_path):
    big = tmp_path / "big.QIF"
    head = shared_file(RESULTS).read_bytes().split(b"<QPId>")[0]
    with big.open("wb") as f:
        f.write(head + b"<!--")
        f.truncate(200 * 1000 * 1000)  # then zeros (sparse: no 200 MB written to disk)
    run = run_validate(big)
    assert_safe(run, (2,))
    assert run.stderr == (
        f"qifreport: error: {big}: larger than 100 MiB (200000000 bytes); not checked\n"
    )
    assert run.peak_mib < 400  # nothing of it was read


XXE = {
    # a general external entity used in the document (the classic XXE)
    "general": ('<!DOCTYPE QIFDocument [<!ENTITY x SYSTEM "{secret}">]>', "&x;"),
    # a parameter entity expanded inside the internal subset
    "parameter": ('<!DOCTYPE QIFDocument [<!ENTITY % p SYSTEM "{secret}"> %p;]>', ""),
    # an external DTD, and an entity it would declare
    "external-dtd": ('<!DOCTYPE QIFDocument SYSTEM "{secret}">', "&x;"),
    # the DOCTYPE after a prolog comment of over 1 MiB (refused on the parsed document)
    "after-long-comment": (
        "<!--" + " " * (1 << 21) + '-->\n<!DOCTYPE QIFDocument [<!ENTITY x SYSTEM "{secret}">]>',
        "&x;",
    ),
}


@pytest.mark.parametrize("case", list(XXE))
def test_xxe_is_refused_and_nothing_leaks(tmp_path, case):
    secret = tmp_path / "secret.txt"
    secret.write_text(SECRET)
    doctype, ref = XXE[case]
    p = tmp_path / "xxe.QIF"
    p.write_text(_with_doctype(doctype.format(secret=secret.as_uri()), ref), encoding="utf-8")
    run = run_validate(p)
    assert_safe(run, (2,))
    assert run.stderr.startswith(
        f"qifreport: error: {p}: DTD/entity declarations are not allowed in a QIF document"
    )


def test_xxe_in_utf16_is_refused(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text(SECRET)
    text = _with_doctype(f'<!DOCTYPE QIFDocument [<!ENTITY x SYSTEM "{secret.as_uri()}">]>', "&x;")
    text = text.replace('encoding="UTF-8"', 'encoding="UTF-16"', 1)
    assert 'encoding="UTF-16"' in text
    p = tmp_path / "xxe16.QIF"
    p.write_bytes(text.encode("utf-16"))
    run = run_validate(p)
    assert_safe(run, (2,))
    assert "DTD/entity declarations are not allowed in a QIF document" in run.stderr


def test_billion_laughs_is_refused(tmp_path):
    ents = ['<!ENTITY lol0 "lol">'] + [
        f'<!ENTITY lol{i} "{f"&lol{i - 1};" * 10}">' for i in range(1, 10)
    ]
    p = tmp_path / "lol.QIF"
    p.write_text(_with_doctype(f"<!DOCTYPE QIFDocument [{''.join(ents)}]>", "&lol9;"))
    run = run_validate(p)
    assert_safe(run, (2,))
    assert "DTD/entity declarations are not allowed in a QIF document" in run.stderr
    assert run.elapsed < 30 and run.peak_mib < 600


def test_good_file_still_valid_under_the_limits():
    """The control: the limits do not stop a good file (its link inside its folder)."""
    path = shared_file(RESULTS)
    run = run_validate(path, "--no-strict")
    assert_safe(run, (0,))
    assert run.stdout.splitlines()[0] == f"{path}: valid"
    assert "refused" not in run.output


# --------------------------------------------------------------------------------------------
# the documents a checked file links to (DMSC document())


@pytest.fixture
def folder(tmp_path) -> Path:
    """``tmp_path/docs`` with the linked plan; beside it (outside) ``outside.QIF``, a plan
    whose QPId is the secret (the checks would print it: "QPIdExt(...)")."""
    docs = tmp_path / "docs"
    docs.mkdir()
    plan = shared_file(PLAN).read_text(encoding="utf-8")
    (docs / "Exploded_Plan.QIF").write_text(plan, encoding="utf-8")
    head, rest = plan.split("<QPId>", 1)
    (tmp_path / "outside.QIF").write_text(f"{head}<QPId>{SECRET}{rest}", encoding="utf-8")
    (tmp_path / "secret.txt").write_text(SECRET)
    return docs


def _linked_case(folder: Path, name: str) -> tuple[str, str]:
    """Make the linked-document case ``name`` in ``folder``: (URI, the reason expected)."""
    outside = folder.parent / "outside.QIF"
    if name == "dev-zero":
        return "/dev/zero", "refused: /dev/zero: outside the folder of the checked document"
    if name == "file-url-dev-zero":
        return "file:///dev/zero", "(= /dev/zero): outside the folder of the checked document"
    if name == "dot-dot":
        return "../outside.QIF", f"(= {outside}): outside the folder of the checked document"
    if name == "absolute":
        return str(outside), "outside the folder of the checked document"
    if name == "symlink-out":
        (folder / "link.QIF").symlink_to(outside)
        return "./link.QIF", f"(= {outside}): outside the folder of the checked document"
    if name == "symlink-dev-zero":
        (folder / "zero.QIF").symlink_to("/dev/zero")
        return "./zero.QIF", "(= /dev/zero): outside the folder of the checked document"
    if name == "fifo":
        os.mkfifo(folder / "pipe.QIF")
        return "./pipe.QIF", "not a regular file (a FIFO)"
    if name == "directory":
        (folder / "sub").mkdir()
        return "./sub", "not a regular file (a directory)"
    if name == "too-large":
        with (folder / "huge.QIF").open("wb") as f:
            f.truncate(150 * 1000 * 1000)
        return "./huge.QIF", "larger than 100 MiB (150000000 bytes)"
    if name == "xxe":
        secret = (folder.parent / "secret.txt").as_uri()
        plan = shared_file(PLAN).read_text(encoding="utf-8")
        decl, rest = plan.split("\n", 1)
        doctype = f'<!DOCTYPE QIFDocument [<!ENTITY x SYSTEM "{secret}">]>'
        (folder / "xxe.QIF").write_text(
            f"{decl}\n{doctype}\n" + rest.replace("<QPId>", "<QPId>&x;", 1), encoding="utf-8"
        )
        return "./xxe.QIF", "DTD/entity declarations are not allowed in a QIF document"
    if name == "not-xml":
        (folder / "junk.QIF").write_bytes(b"\x00\x01 not XML " * 100)
        return "./junk.QIF", "not well-formed XML"
    raise AssertionError(name)


LINKED = [
    "dev-zero",
    "file-url-dev-zero",
    "dot-dot",
    "absolute",
    "symlink-out",
    "symlink-dev-zero",
    "fifo",
    "directory",
    "too-large",
    "xxe",
    "not-xml",
]


@pytest.mark.parametrize("name", LINKED)
def test_linked_document_refused(folder, name):
    uri, why = _linked_case(folder, name)
    p = folder / "results.QIF"
    p.write_text(_results_with_link(uri), encoding="utf-8")
    text = p.read_text(encoding="utf-8")
    uri_line = text[: text.index(f"<URI>{uri}</URI>")].count("\n") + 1
    run = run_validate(p, "--no-strict")
    assert_safe(run, (1,))
    lines = run.stdout.splitlines()
    assert lines[0] == f"{p}: INVALID"
    assert "CheckDocuments 1 error" in lines[2]
    refused = [ln for ln in lines if "[dmsc/CheckDocuments/linked-document-refused]" in ln]
    assert len(refused) == 1, lines
    assert refused[0].startswith(
        f"{p}:{uri_line}: [dmsc/CheckDocuments/linked-document-refused] linked document "
        f"refused: {uri}"
    )
    assert why in refused[0]
    # the checks go on and report the link as they report a missing document
    assert any(
        ln.endswith(
            f"[dmsc/CheckFormat/external-document] The external document was not found URI = {uri}."
        )
        for ln in lines
    ), lines


def test_refused_link_of_a_linked_document(folder):
    """A link in a linked document is refused too (a warning about that document)."""
    (folder / "middle.QIF").write_text(_results_with_link("/dev/zero"), encoding="utf-8")
    p = folder / "results.QIF"
    p.write_text(_results_with_link("./middle.QIF"), encoding="utf-8")
    run = run_validate(p, "--no-strict")
    assert_safe(run)
    assert (
        f"{p}: [dmsc/CheckDocuments/CheckDocuments:linked-document-refused] warning: in a linked "
        "document: linked document refused: /dev/zero: outside the folder of the checked "
        f"document ({folder})" in run.stdout.splitlines()
    )


# --------------------------------------------------------------------------------------------
# the DMSC time limit (in process: no file reaches it quickly)


def test_dmsc_time_limit():
    from qifreport.qif import dmsc
    from qifreport.qif.xsd import checks_dir, parse_document

    path = shared_file("qif/samples/community/SheetMetal_QIF_Results_6_samples.QIF")
    tree = parse_document(path)
    cd = checks_dir()
    assert dmsc.DMSC_TIMEOUT_S >= 60
    t0 = time.monotonic()
    findings = dmsc.dmsc_findings(tree, path.resolve(), cd, timeout=0.002)
    assert time.monotonic() - t0 < 5
    assert [(f.category, f.rule, f.severity) for f in findings] == [
        ("CheckFormat", "timeout", "error")
    ]
    assert "did not finish within 0.002 s" in findings[0].message
    # the abandoned run ends at its next callback; the next run compiles its own checks
    later = dmsc.dmsc_findings(tree, path.resolve(), cd)
    assert later and all(f.rule != "timeout" for f in later)
    deadline = time.monotonic() + 30
    while any(t.name == "qifreport-dmsc" for t in threading.enumerate()):
        assert time.monotonic() < deadline, "the abandoned DMSC run did not end"
        time.sleep(0.05)
