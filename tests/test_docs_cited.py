"""Every document the repository cites is in the repository (issue 17).

The tracked text files (code, tests, cases, examples, README, docs, Makefile, pyproject) are
scanned for the documents they name: Markdown files (by name, with or without a path),
files under ``docs/``, the targets of Markdown links and pictures, and paths that climb out
with ``../``. Each must be a tracked file (or folder) of the repository: a path is taken from
the citing file's folder or from the repository's root (a ``../`` path also from a top-level
folder, as a case file's ``mesh.file`` is), a bare name must be the name of some tracked file.
A section cited as ``s. N`` (or ``section N``, ``B2``) right after a document's path must be a
heading of that document (``## N. ...``, ``### N.M ...``, a heading naming B2). What ``make docs``
writes (``docs/_build/``, ``docs/_generated/``: the site and the generated case reference, not tracked)
may be cited. This file is not scanned: its examples are not citations.
"""

from __future__ import annotations

import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
THIS = Path(__file__).resolve().relative_to(ROOT).as_posix()
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".cfg", ".txt", ".sh"}
TEXT_NAMES = {"Makefile"}
SKIP_DIRS = {".git", ".venv", "results", "__pycache__", ".pytest_cache", ".hypothesis"}

URL = re.compile(r"[a-z][a-z0-9+.-]*://\S+", re.IGNORECASE)
DOCUMENT = re.compile(r"(?<![\w./-])((?:\.\.?/)*(?:[\w-]+/)*[\w-]+\.md)\b")
DOCS_PATH = re.compile(r"(?<![\w./-])(docs/[\w./-]*\w)")
CLIMB = re.compile(r"(?<![\w./-])((?:\.\./)+[\w./-]*\w/?)")
LINK = re.compile(r"\]\(([^)\s]+)\)")
# What follows a document's name when a section of it is cited (across a line break, a comment's #).
SECTION = re.compile(r"`?[,;:]?\s*(?:#\s*)?(?:s\.|sections?\b)\s*(\d+(?:\.\d+)*)|`?[,;:]?\s+(B\d+)[a-z]?\b")
HEADING = re.compile(r"^#{1,6}\s+(.*\S)\s*$", re.MULTILINE)
BUILT = ("docs/_build", "docs/_generated")   # written by `make docs` (gitignored)


@dataclass(frozen=True)
class Reference:
    file: str        # the citing file, relative to the root
    line: int
    target: str      # as written
    section: str | None = None


def repository_files(root: Path) -> list[str]:
    """The tracked files (``git ls-files``); outside a git checkout, the files under ``root``."""
    try:
        out = subprocess.run(["git", "-C", str(root), "ls-files", "-z"], capture_output=True, check=True).stdout
        files = [f for f in out.decode().split("\0") if f]
        if files:
            return [f for f in files if (root / f).is_file()]
    except (OSError, subprocess.CalledProcessError):
        pass
    found = []
    for folder, dirs, names in os.walk(root):
        dirs[:] = [d for d in dirs if d not in SKIP_DIRS]
        found += [str((Path(folder) / n).relative_to(root)) for n in names]
    return found


def is_text(path: str) -> bool:
    p = Path(path)
    return p.suffix in TEXT_SUFFIXES or p.name in TEXT_NAMES or p.parts[0] == ".ci"


def references(root: Path, files: list[str]) -> list[Reference]:
    """Every document reference of the text files, with the section it cites (if any)."""
    refs = []
    for name in filter(is_text, files):
        text = URL.sub(lambda m: " " * len(m.group()), (root / name).read_text(errors="replace"))
        found: dict[tuple[int, str], str | None] = {}
        patterns = [DOCUMENT, DOCS_PATH, CLIMB] + ([LINK] if name.endswith(".md") else [])
        for pattern in patterns:
            for m in pattern.finditer(text):
                target = m.group(1)
                if pattern is LINK:
                    target = target.split("#")[0]
                    if not target or target.startswith(("mailto:", "/")):
                        continue
                section = None
                if target.endswith(".md"):
                    after = SECTION.match(text, m.end())
                    if after:
                        section = after.group(1) or after.group(2)
                key = (m.start(1), target)
                if found.get(key) is None:
                    found[key] = section
        for (start, target), section in sorted(found.items()):
            refs.append(Reference(name, text.count("\n", 0, start) + 1, target, section))
    return refs


def resolve(root: Path, files: list[str], ref: Reference) -> str | None:
    """The tracked file (or folder, ending in /) a reference names, relative to the root; None if none."""
    tracked = set(files)
    folders = {str(Path(f).parent) + "/" for f in files} | {
        "/".join(Path(f).parts[:k]) + "/" for f in files for k in range(1, len(Path(f).parts))}
    target = ref.target
    if "/" not in target:
        matches = sorted(f for f in tracked if Path(f).name == target)
        return matches[0] if matches else None
    here = Path(ref.file).parent
    bases = [here, Path(".")]
    if target.startswith("../"):
        bases += sorted({Path(Path(f).parts[0]) for f in files if len(Path(f).parts) > 1})
    for base in bases:
        path = os.path.normpath(base / target)
        if path.startswith(".."):
            continue   # outside the repository
        if path in tracked:
            return path
        if path + "/" in folders:
            return path + "/"
    return None


def headings(root: Path, path: str) -> list[str]:
    return HEADING.findall((root / path).read_text())


def has_section(titles: list[str], section: str) -> bool:
    if section.startswith("B"):
        return any(re.search(rf"\b{section}\b", t) for t in titles)
    return any(re.match(rf"{re.escape(section)}\.?\s", t) for t in titles)


def is_built(ref: Reference) -> bool:
    """Whether a reference names what the site's build writes (from the root or the citing file's folder)."""
    paths = {os.path.normpath(ref.target), os.path.normpath(Path(ref.file).parent / ref.target)}
    return any(p == b or p.startswith(b + "/") for p in paths for b in BUILT)


def problems(root: Path, files: list[str]) -> list[str]:
    """One line per reference to a document that is not in the repository, or to a section it lacks."""
    out = []
    for ref in references(root, files):
        where = f"{ref.file}:{ref.line}: {ref.target!r}"
        if is_built(ref):
            continue
        path = resolve(root, files, ref)
        if path is None:
            out.append(f"{where} is not in the repository")
        elif ref.section and not has_section(headings(root, path), ref.section):
            out.append(f"{where} has no section {ref.section}")
    return out


def cited_files() -> list[str]:
    return [f for f in repository_files(ROOT) if f != THIS]


def test_every_cited_document_is_in_the_repository():
    found = problems(ROOT, cited_files())
    assert not found, "documents cited but not in the repository:\n" + "\n".join(found)


def test_the_code_cites_the_theory_by_section():
    """The check sees the citations it is for: the integrators cite docs/theory.md by section."""
    refs = references(ROOT, cited_files())
    cited = {(r.file, r.section) for r in refs if r.target == "docs/theory.md" and r.section}
    assert {f for f, _ in cited} >= {"fem_impact/integrators/newmark.py", "fem_impact/integrators/moreau_jean.py",
                                     "fem_impact/fem/reduced.py"}
    assert any(r.target == "docs/benchmarks.md" and r.section for r in refs)


def test_the_check_is_not_fooled(tmp_path):
    """A small tree with one good and one bad reference of each kind: exactly the bad ones are found."""
    doc, missing = "theory.md", "METHOD.md"
    files = {
        "docs/" + doc: "# Theory\n\n## 1. Notation\n\n### 1.2 Units\n\n## B2: a bar\n",
        "docs/bar.png": "",
        "meshes/two_bars.msh": "",
        "README.md": (f"See [the theory](docs/{doc}), ![a bar](docs/bar.png), [gone](docs/gone.md),\n"
                      f"the site in docs/_build/html, [built](docs/_generated/keys.md) and [gone](docs/_built/x.md),\n"
                      f"![lost](docs/lost.png) and `../shared/peers/`; a case file's `../meshes/two_bars.msh`.\n"),
        "fem_impact/a.py": (f'"""The step (docs/{doc} s. 1.2; docs/{doc}\n# section 1).\n'
                            f'Wrong: docs/{doc} s. 3, docs/{doc} B3, {missing}, docs/{doc} B2."""\n'),
        "cases/c.yaml": f"# B2 ({missing} B2), docs/{doc} B2, see {doc} s. 1, not `docs/{doc}` s. 7\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    found = problems(tmp_path, sorted(files))
    assert sorted(found) == sorted([
        "README.md:1: 'docs/gone.md' is not in the repository",
        "README.md:2: 'docs/_built/x.md' is not in the repository",
        "README.md:3: 'docs/lost.png' is not in the repository",
        "README.md:3: '../shared/peers/' is not in the repository",
        f"fem_impact/a.py:3: 'docs/{doc}' has no section 3",
        f"fem_impact/a.py:3: 'docs/{doc}' has no section B3",
        f"fem_impact/a.py:3: '{missing}' is not in the repository",
        f"cases/c.yaml:1: '{missing}' is not in the repository",
        f"cases/c.yaml:1: 'docs/{doc}' has no section 7",
    ])
