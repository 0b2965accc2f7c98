"""Sphinx configuration of fem-impact's documentation site (``make docs`` builds it into docs/_build)."""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))          # the package of this checkout, not an installed one
sys.path.insert(0, str(HERE / "_ext"))

project = "fem-impact"
author = "the fem-impact authors"
try:
    from fem_impact import __version__ as release
except ImportError:   # (the site still builds its pages; autodoc then warns, and -W fails the build)
    release = "unknown"
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "case_reference",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "_generated", "tutorials/*.py", "Thumbs.db", ".DS_Store"]
myst_enable_extensions = ["colon_fence", "dollarmath"]
myst_heading_anchors = 3

html_theme = "alabaster"
html_title = "fem-impact"
html_theme_options = {"description": "impacts on finite-element structures", "fixed_sidebar": True}

autodoc_member_order = "bysource"
autodoc_typehints = "description"

nitpicky = True
# Names in signatures and docstrings that are not documented on this site (the standard library, numpy,
# pydantic, PETSc, mpi4py): no intersphinx here (the build works offline), so they are not links.
nitpick_ignore_regex = [
    ("py:class", r"(numpy|np|pathlib|pydantic|petsc4py|mpi4py|collections\.abc|typing|os)\..*"),
    ("py:class", r"(Path|ndarray|BaseModel|MPI\.Comm|Comm|Mapping|Iterable|Sequence|Callable|Any|LawKeys)"),
    ("py:class", r"fem_impact\..*"),
    ("py:obj", r"fem_impact\..*"),
    ("py:mod", r"fem_impact\..*"),          # modules named in docstrings: the site documents the public API only
    # numpydoc's words for types in the docstrings' parameter lists
    ("py:class", r"(path-like|optional|iterable|callable|mapping|mpi4py communicator|.* to .*|.* of .*)"),
    # Docstrings name internal functions and methods; those stay plain text. A reference to the public API
    # (fem_impact.run, load_case, Case, Result, the errors) must resolve. (Napoleon also reads a paragraph
    # that follows a docstring's "Raises" section as exception names: lowercase words, ignored here.)
    ("py:(func|meth|attr|data|exc)",
     r"(?!fem_impact\.(run|load_case|Case|Result|CaseError|SimulationError|FemImpactError)\b).*"),
]


def _readme(app, env, node, contnode):
    """docs/theory.md links the repository's README (``../README.md``), which is not a page of the site:
    the link goes to the site's front page, which the README points to."""
    target = node.get("reftarget", "")
    if target.endswith("README.md"):
        from sphinx.util.nodes import make_refnode
        return make_refnode(app.builder, node.get("refdoc", ""), root_doc, "", contnode)
    return None


def setup(app):
    app.connect("missing-reference", _readme)
