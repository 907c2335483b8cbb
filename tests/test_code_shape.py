"""The shape of the code, checked: short functions in the inspection core, kinds and methods
named only in their registries, text that stays true (no timings or issue numbers in code
comments, a README that is a user's document).

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
FUNCTION_LIMIT = 100
CORE = ["metrology", "registration", "qif", "qifreport/pipeline.py"]
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


#: an issue or stop number: "issue 23", "issues 12/14", "(#41)", "stop 7"
ISSUE = re.compile(r"\b(issues?|stops?)\s+#?\d+|#\d+\b", re.IGNORECASE)
#: a measured duration: "0.14 s", "1.3 CPU-s", "28 ms", "2.5 seconds", "69 s"
TIMING = re.compile(
    r"\b\d+(\.\d+)?\s*(ms|µs|us|CPU-s|seconds?|s)\b(?!\s*(\^|\*\*|-1|/))", re.IGNORECASE
)


def test_the_text_patterns_catch_what_they_should():
    assert ISSUE.search("# see issue 23") and ISSUE.search("# fixed in #41")
    assert not ISSUE.search("# the 3 issues of the seam")
    assert TIMING.search("# 0.14 s on 400k points") and TIMING.search("# 28 ms with METIS")
    assert TIMING.search("# 1.3 CPU-s") and not TIMING.search("# sigma 3 mm, 5 passes")


def test_no_timings_or_issue_numbers_in_code_comments():
    """Benchmarks print timings and commit messages keep history: a comment says neither."""
    bad = []
    for f in _py_files(SOURCES):
        for line, text in comments(f):
            if ISSUE.search(text) or TIMING.search(text):
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
