"""The shape of the code, checked: short functions in the inspection core, kinds and methods
named only in their registries, text that stays true (no timings or issue numbers in code
comments and docstrings, a README that is a user's document).

Each check reads the sources as text or syntax trees; each fails on the first offender it
finds and names it (file, line, what).
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the library and the job runner: no function longer than this many lines
FUNCTION_LIMIT = 80
CORE = ["step", "metrology", "registration", "qif", "qifreport/pipeline.py"]
#: every folder of Python sources the project ships or runs
SOURCES = ["step", "registration", "metrology", "qif", "qifreport", "bench", "samples"]
README_LIMIT = 300


def _py_files(entries: list[str]) -> list[Path]:
    out: list[Path] = []
    for e in entries:
        p = ROOT / e
        out.extend([p] if p.is_file() else sorted(p.rglob("*.py")))
    return out


def function_lengths(files: list[Path]) -> list[tuple[int, str]]:
    """(lines, "file:line name") of every function and method in ``files``, longest first."""
    rows = []
    for f in files:
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                rows.append((n, f"{f.relative_to(ROOT)}:{node.lineno} {node.name}"))
    return sorted(rows, reverse=True)


def test_function_lengths_are_measured_right():
    """The counter counts a function's lines from ``def`` to its last line."""
    src = "def f():\n" + "    x = 1\n" * 120 + "\n\ndef g():\n    return 2\n"
    tmp = ROOT / "tests" / "_probe_shape.py"
    try:
        tmp.write_text(src)
        rows = function_lengths([tmp])
    finally:
        tmp.unlink()
    assert [r[0] for r in rows] == [121, 2]


def test_no_long_function_in_the_core():
    """No function of the library or the job runner over FUNCTION_LIMIT lines; the longest
    are listed in the failure."""
    rows = function_lengths(_py_files(CORE))
    over = [r for r in rows if r[0] > FUNCTION_LIMIT]
    assert not over, "over the limit:\n" + "\n".join(f"{n:5d} {w}" for n, w in over)


def comments(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every ``#`` comment in a Python file."""
    toks = tokenize.generate_tokens(io.StringIO(path.read_text()).readline)
    return [(t.start[0], t.string) for t in toks if t.type == tokenize.COMMENT]


def docstrings(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every line of the module's, its classes' and its functions' docstrings."""
    rows = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                first = node.body[0].lineno
                rows.extend((first + i, line) for i, line in enumerate(doc.splitlines()))
    return rows


#: an issue or stop number of this project: "issue 23", "issues 12/14", "stop 7", "(#41)",
#: "fixed in #41"; a bare "#16292" is a STEP entity id (data), not an issue
ISSUE = re.compile(
    r"\b(issues?|stops?)\s+#?\d+|\(#\d+\)|\b(fixed in|see|fixes|closes|PR)\s+#\d+", re.IGNORECASE
)
#: the one allowance: citations of OpenCASCADE's public tracker ("OCCT issues #1368, #384")
OCCT_CITATION = re.compile(r"\bOCCT issues? #\d+(,\s*#\d+)*")
#: a duration: "0.14 s", "1.3 CPU-s", "28 ms", "2.5 seconds", "69 s"
TIMING = re.compile(
    r"\b\d+(\.\d+)?\s*(ms|µs|us|CPU-s|seconds?|s)\b(?!\s*(\^|\*\*|-1|/))", re.IGNORECASE
)
#: a duration that is configured, not measured, is spared when the words right before it
#: name it a period or a limit ("every 20 ms", "a timeout of 120 s", "time limit of 300 s")
CONFIGURED = re.compile(r"\b(every|after|timeout( of)?|time limit( of)?|interval( of)?)\s*$", re.I)
#: ``s`` the symbol of a formula is spared: a divisor ``/ (3 s)`` or the end of an inline
#: literal (``|d| < 4.685 s``)
FORMULA_BEFORE = re.compile(r"/\s*\($")


def names_an_issue(text: str) -> bool:
    """Whether ``text`` names an issue or stop number (OCCT's tracker cited aside)."""
    return bool(ISSUE.search(OCCT_CITATION.sub("", text)))


def measured_timings(text: str) -> list[str]:
    """The durations in ``text`` that read as measurements (configured ones and formula
    symbols spared, see :data:`CONFIGURED` and :data:`FORMULA_BEFORE`)."""
    found = []
    for m in TIMING.finditer(text):
        before, after = text[: m.start()], text[m.end() :]
        if CONFIGURED.search(before) or after.startswith("``"):
            continue
        if FORMULA_BEFORE.search(before) and after.startswith(")"):
            continue
        found.append(m.group(0))
    return found


def test_the_text_patterns_catch_what_they_should():
    for bad in ("# see issue 23", "# fixed in #41", "issues 12/14 moved it", "(#41)", "stop 7"):
        assert names_an_issue(bad), bad
    for fine in (
        "# the 3 issues of the seam",
        "OCCT issues #1368,",
        "OCCT issues #1368, #384, #1138)",
        "as NIST FTC 07 #16292 and FTC 10 #18552 encode it",
        "``(pmi #1234)``",
        "#5 = NAME(a, b);",
    ):
        assert not names_an_issue(fine), fine
    for bad in (
        "# 0.14 s on 400k points",
        "# 28 ms with METIS",
        "# 1.3 CPU-s",
        "took 2.5 seconds",
        "the rigid stage 5.7 -> 2.1 s",
        "without importing matplotlib (0.1-0.2 s)",
        "(0.14 s)",
    ):
        assert measured_timings(bad), bad
    for fine in (
        "# sigma 3 mm, 5 passes",
        "re-checked every 20 ms (SIGALRM)",
        "a timeout of 120 s",
        "the time limit of 300 s",
        "Cpk = (USL - mean) / (3 s)",
        "``(1 - (d / (4.685 s))^2)^2`` for ``|d| < 4.685 s``",
        "1/s",
    ):
        assert not measured_timings(fine), fine


def test_no_timings_or_issue_numbers_in_code_comments():
    """Benchmarks print timings and commit messages keep history: a comment or a docstring
    (module, class, function) says neither."""
    bad = []
    for f in _py_files(SOURCES):
        for line, text in comments(f) + docstrings(f):
            if names_an_issue(text) or measured_timings(text):
                bad.append(f"{f.relative_to(ROOT)}:{line} {text.strip()}")
    assert not bad, "\n".join(bad[:40])


def test_readme_is_a_users_document():
    """README: at most README_LIMIT lines, with install, quick start, commands, outputs and
    exit codes; the method, figures and design are in docs/, which names the paper."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= README_LIMIT, len(text.splitlines())
    low = text.lower()
    for must in ("install", "quick start", "exit code", "docs/"):
        assert must in low, must
    docs = ROOT / "docs"
    assert docs.is_dir() and list(docs.glob("*.md"))
    method = "\n".join(p.read_text() for p in docs.glob("*.md"))
    assert "Automatic Inspection of Flexible Parts Using Virtual Fixturing" in method
    for rel in re.findall(r"\]\(([^)#:]+\.md)", text):
        assert (ROOT / rel).is_file(), f"README links a missing {rel}"
