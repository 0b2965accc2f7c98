"""Docstrings and comments of the package say what and why: no issue numbers, no measured figures.

Measurements, benchmarks and history belong in the documentation pages (docs/performance.md,
docs/verification.md) and in commit messages, where they carry their date and the command that
reproduces them; in the code they go stale silently.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "fem_impact"

FORBIDDEN = {
    "an issue number": r"\bissues?\s*#?\s*\d+|(?<![\w&/])#\d{2,}\b",
    "a measured figure": r"\bmeasured\b[^.\n]{0,60}\d",
    "a timing": r"\b\d+(?:\.\d+)?\s*(?:ms|us|µs)\b(?:\s*(?:a|per)\s+step)?",
    "a speed ratio": r"\b\d+(?:\.\d+)?\s*(?:times|x)\s+(?:faster|slower|quicker)\b",
    "a benchmark's plate": r"\b\d[\d ]*-row plate\b|\b(?:1681|6561)[- ]rows?\b",
}


def texts(path: Path):
    """(line, text) of every comment and docstring of a module."""
    source = path.read_text()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            yield token.start[0], token.string
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield node.body[0].lineno, doc


def offences(path: Path, root: Path = PACKAGE.parent) -> list[str]:
    found = []
    for line, text in texts(path):
        for what, pattern in FORBIDDEN.items():
            for match in re.finditer(pattern, text, re.I):
                found.append(f"{path.relative_to(root)}:{line}: {what}: {match.group(0)!r}")
    return found


@pytest.mark.parametrize("sample, caught", [
    ("# see issue 19", True), ("# (#123)", True), ('"""measured 0.10 on B2a"""', True),
    ("# 9.32 ms a step", True), ("# 5 times faster", True), ("# the 1681-row plate", True),
    ("# the errors measured against the exact solution", False), ("# 42.0 s, 12 min", False),
    ('"""a step of 1e-3 s"""', False),
])
def test_the_check_catches_what_it_names_and_leaves_the_rest(tmp_path, sample, caught):
    module = tmp_path / "module.py"
    module.write_text(f"{sample}\n")
    assert bool(offences(module, tmp_path)) is caught


def test_no_docstring_or_comment_names_an_issue_or_quotes_a_figure():
    found = [offence for path in sorted(PACKAGE.rglob("*.py")) for offence in offences(path)]
    assert not found, "\n".join(found)
