"""The documentation site (docs/, Sphinx with MyST) builds with warnings as errors, its case-file reference
is generated from the schemas and covers every key, and the README stays a short front page."""

from __future__ import annotations

import importlib.util
import re
import shlex
import subprocess
import sys
import types
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def generator():
    """docs/_ext/case_reference.py, the Sphinx extension that writes the case-file reference."""
    spec = importlib.util.spec_from_file_location("case_reference", ROOT / "docs" / "_ext" / "case_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_readme_is_a_short_front_page():
    lines = README.read_text().splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines: the rest belongs in docs/"
    text = README.read_text()
    for command in ("make run", "make test", "make docs"):
        assert command in text
    for picture in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):
        assert (ROOT / picture).is_file(), picture


def test_the_readme_presents_the_default_method():
    """The README's introduction (before its first section) names the method a case without one gets."""
    from fem_impact.integrators.parameters import DEFAULT_METHOD, SCHEMAS

    intro = README.read_text().split("\n## ")[0]
    assert f"solver.method: {DEFAULT_METHOD}" in intro
    title = (SCHEMAS[DEFAULT_METHOD].__doc__ or "").split(":", 1)[1].split("time stepping")[0].strip()
    assert title and title in intro and "default" in intro.lower()


def test_the_makefile_builds_the_site_with_warnings_as_errors():
    recipe = [line for line in (ROOT / "Makefile").read_text().splitlines() if "-m sphinx" in line]
    assert len(recipe) == 1 and {"-W", "--keep-going", "-n"} <= set(recipe[0].split())
    packages = (ROOT / "Makefile").read_text()
    assert "python3-sphinx" in packages and "python3-myst-parser" in packages


def test_the_reference_has_every_solver_key_and_every_law_key():
    from fem_impact.integrators.parameters import SCHEMAS
    from fem_impact.nonsmooth.laws import LAWS

    text = generator().reference_markdown()
    for name, schema in SCHEMAS.items():
        method, _, scheme = name.partition("/")
        section = text.split(f"### `method: {method}`" + (f", `scheme: {scheme}`" if scheme else ""))[1]
        section = section.split("\n### ")[0]
        for key, info in schema.model_fields.items():
            row = next(line for line in section.splitlines() if line.startswith(f"| `{key}` |"))
            unit = (info.json_schema_extra or {}).get("unit", "") if isinstance(info.json_schema_extra, dict) else ""
            cells = [c.strip() for c in row.strip().strip("|").split(" | ")]
            assert cells[4] == unit and cells[5] == " ".join((info.description or "").split()).replace("|", "\\|"), row
    assert "| `dt` | float | required | > 0 | s | time step |" in text
    assert "| `theta` | float | 0.5 | >= 0.5, <= 1 |" in text
    for name, law in LAWS.items():
        section = text.split(f"### `law: {name}`")[1].split("\n### ")[0]
        for key in law.keys.model_fields:
            assert f"| `{key}` |" in section, (name, key)


class _Point(BaseModel):
    """A probe point."""

    at: list[float] = Field(min_length=1, max_length=3, description="its coordinates", json_schema_extra={"unit": "m"})


class _Output(BaseModel):
    """What a run writes."""

    every: int = Field(20, ge=1, description="steps between frames")
    format: Literal["vtu", "xdmf"] = Field("vtu", description="the fields' format")
    probes: dict[str, _Point] = Field(default_factory=dict, description="named points")
    limit: float | None = Field(None, alias="max", gt=0, description="a bound", json_schema_extra={"unit": "s"})


def test_the_generator_walks_any_section_model(monkeypatch):
    """With ``fem_impact.config.schema.SECTIONS`` (section name -> pydantic model), every section and the
    models its keys hold get a table: type, default, range from the constraints, unit, meaning."""
    module = types.ModuleType("fem_impact.config.schema")
    module.SECTIONS = {"output": _Output}
    monkeypatch.setitem(sys.modules, "fem_impact.config.schema", module)
    text = generator().sections_markdown()
    assert "### `output`" in text and "What a run writes." in text
    assert "| `every` | int | 20 | >= 1 |  | steps between frames |" in text
    assert "| `format` | one of: `vtu`, `xdmf` | `vtu` |" in text
    assert "| `probes` | mapping of str to _Point (below) | {} |" in text
    assert "| `max` | float or null | none | > 0 | s | a bound |" in text
    assert "#### _Point" in text and "| `at` | list of float | required | at least 1 item, at most 3 items | m |" in text


def test_without_the_section_schemas_the_reference_points_to_the_case_files_page(monkeypatch):
    monkeypatch.setitem(sys.modules, "fem_impact.config.schema", None)   # (an import of it raises ImportError)
    assert "{doc}`/case_files`" in generator().sections_markdown()


def test_the_site_builds_with_warnings_as_errors(tmp_path):
    """The Makefile's sphinx-build command, into a temporary folder: every page in a toctree, every
    cross-reference and autodoc target resolved, the case reference generated."""
    recipe = next(line for line in (ROOT / "Makefile").read_text().splitlines() if "-m sphinx" in line)
    args = shlex.split(recipe.split("-m sphinx", 1)[1])
    options = args[:args.index("docs")]                       # (then the source and the Makefile's build folder)
    out = subprocess.run([sys.executable, "-m", "sphinx", *options, "docs", str(tmp_path / "html")], cwd=ROOT,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    reference = re.sub(r"<[^>]+>", "", (tmp_path / "html" / "case_reference.html").read_text())
    assert "method: moreau_jean" in reference and "law: elastic_stop" in reference
    assert (tmp_path / "html" / "tutorials" / "vibrodrive.html").is_file()


def test_the_law_example_of_the_python_api_page_runs_and_books_its_loss():
    """The page's damped stop, as written there, registers and runs a case, its loss in its own column."""
    import re as _re

    import fem_impact
    from fem_impact.config.case import load_case
    from fem_impact.nonsmooth import laws

    page = (ROOT / "docs" / "python_api.md").read_text()
    code = next(block for block in _re.findall(r"```python\n(.*?)```", page, _re.S) if "class DampedStop" in block)
    contact = _re.search(r"# contacts: (\[.*\])", code, _re.S).group(1)
    try:
        exec(compile(code, "docs/python_api.md", "exec"), {})
        case = load_case(ROOT / "cases" / "impacting_bar.yaml",
                         ["contacts=" + " ".join(contact.replace("#", "").split()), "solver.method=moreau_jean",
                          "mesh.cells=20", "solver.dt=0.01", "solver.t_end=0.5"])
        summary = fem_impact.run(case).summary
    finally:
        laws.LAWS.pop("damped_stop", None)
    assert summary["stop_damping_loss"] > 0
    assert summary["max_energy_error_relative"] <= 1e-10
