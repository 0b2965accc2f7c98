"""Bad input through the real command line (docs/running.md).

Every bad case must end with a non-zero exit and a few plain lines on stderr naming the file,
the key (and line, where known) and the problem; no traceback; the output folder, which holds
the result of an earlier good run, must be left exactly as it was, with no staging folder
beside it. Expressions are parsed, never executed: a malicious one must leave no trace.

The CLI calls (a fresh interpreter each, ~1.5 s of imports) run concurrently in one
module-scoped fixture; the parametrized tests then check each outcome.
"""

from __future__ import annotations

import os
import shutil
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from conftest import run_cli

# One worker takes the whole module (make test runs --dist loadgroup):
# its module fixture runs some fifty command lines (34 s), once, not once in each worker.
pytestmark = pytest.mark.xdist_group("bad_input")

# The impacting bar (cases/impacting_bar.yaml) on a tiny mesh for a few steps.
GOOD = """\
name: bad
mesh:
  shape: bar
  dim: 1
  length: 1.0
  cells: 10
material:
  E: 1.0
  rho: 1.0
  nu: 0.0
  area: 1.0
initial:
  velocity: [-1.0]
contacts:
  - name: wall
    type: obstacle
    nodes: left
    normal: [-1.0]
    gap: 0.1
    restitution: 0.0
solver:
  method: newmark
  dt: 0.01
  t_end: 0.05
output:
  every: 1
  probes:
    left: [0.0]
"""

BUILTIN_MESH = "  shape: bar\n  dim: 1\n  length: 1.0\n  cells: 10\n"
MATERIAL = "material:\n  E: 1.0\n  rho: 1.0\n  nu: 0.0\n  area: 1.0\n"
WALL = ("  - name: wall\n    type: obstacle\n    nodes: left\n    normal: [-1.0]\n"
        "    gap: 0.1\n    restitution: 0.0\n")
PAIR_MESH = (BUILTIN_MESH, "  file: pair.msh\n")


def pair(groups):
    """Edit: the wall contact replaced by a pair contact between two node groups of pair.msh."""
    return (WALL, f"  - name: joint\n    type: pair\n    nodes: [{groups}]\n    normal: [1.0]\n")


def before_output(text):
    """Edit: `text` inserted as top-level keys before `output:`."""
    return ("output:\n", f"{text}\noutput:\n")


PAYLOAD = "__import__('os').system('touch SENTINEL')"


@dataclass
class Bad:
    """One bad input.

    edits: (old, new) replacements of GOOD (each `old` occurs exactly once);
    key: the dotted key the message must name, or None (YAML syntax errors);
    at: a text whose first line in the edited case is the line the message must give,
        or None where no line is known (a --set option);
    says: fragments the message must contain;
    args: extra command-line arguments; fresh: no earlier result in OUT (it must stay absent);
    runtime: the case is valid but fails during the time loop (a "run failed" message).
    """

    id: str
    edits: tuple
    key: str | None
    at: str | None
    says: tuple
    args: tuple = ()
    fresh: bool = False
    runtime: bool = False
    never: tuple = ()   # fragments the message must not contain (advice that does not fit the cause)


BAD = [
    # YAML syntax
    Bad("yaml-syntax", (("  E: 1.0\n", "  E: 1.0: 2\n"),), None, "E: 1.0: 2", ("invalid YAML",)),
    # unknown keys, with the closest valid key
    Bad("unknown-key", (("    restitution: 0.0", "    restitutoin: 0.0"),), "contacts[0].restitutoin",
        "restitutoin", ("unknown key", "did you mean 'restitution'?")),
    Bad("unknown-top-key", (("output:\n", "outptu:\n"),), "outptu", "outptu", ("did you mean 'output'?",)),
    # wrong types
    Bad("type-E", (("  E: 1.0", "  E: stiff"),), "material.E", "E: stiff", ("expected a number", "'stiff'")),
    Bad("type-cells", (("cells: 10", "cells: 2.5"),), "mesh.cells", "cells: 2.5", ("expected an integer",)),
    Bad("type-normal", (("normal: [-1.0]", "normal: -1.0"),), "contacts[0].normal", "normal: -1.0",
        ("expected a list",)),
    # non-positive material and solver numbers
    Bad("E-negative", (("  E: 1.0", "  E: -70e9"),), "material.E", "E: -70e9", ("must be > 0",)),
    Bad("rho-zero", (("  rho: 1.0", "  rho: 0.0"),), "material.rho", "rho: 0.0", ("must be > 0",)),
    Bad("area-negative", (("  area: 1.0", "  area: -1.0"),), "material.area", "area: -1.0", ("must be > 0",)),
    Bad("dt-zero", (("  dt: 0.01", "  dt: 0"),), "solver.dt", "dt: 0", ("must be > 0",)),
    Bad("t_end-negative", (("  t_end: 0.05", "  t_end: -4"),), "solver.t_end", "t_end: -4", ("must be > 0",)),
    Bad("dt-above-t_end", (("  dt: 0.01", "  dt: 0.1"),), "solver.dt", "dt: 0.1", ("must be <= t_end",)),
    # nu outside [0, 0.5), restitution outside [0, 1]
    Bad("nu-half", (("  nu: 0.0", "  nu: 0.5"),), "material.nu", "nu: 0.5", ("must be in [0, 0.5)",)),
    Bad("nu-negative", (("  nu: 0.0", "  nu: -0.1"),), "material.nu", "nu: -0.1", ("must be in [0, 0.5)",)),
    Bad("restitution-above-1", (("restitution: 0.0", "restitution: 1.5"),), "contacts[0].restitution",
        "restitution: 1.5", ("must be in [0, 1]",)),
    Bad("restitution-negative", (("restitution: 0.0", "restitution: -0.1"),), "contacts[0].restitution",
        "restitution: -0.1", ("must be in [0, 1]",)),
    # an elastic stop's stiffness must be positive; coupling is one of two words
    Bad("stiffness-zero", (("restitution: 0.0", "restitution: 0.0\n    stiffness: 0"),), "contacts[0].stiffness",
        "stiffness: 0", ("must be > 0",)),
    Bad("coupling-unknown", (("restitution: 0.0", "restitution: 0.0\n    coupling: average"),),
        "contacts[0].coupling", "coupling: average", ("each", "mean")),
    # a --set override: the message points to the option
    Bad("set-E-negative", (), "material.E", None, ("must be > 0", "--set material.E=-1"),
        args=("--set", "material.E=-1")),
    # node groups and bodies that do not exist: the message lists those that do
    Bad("contact-group", (("nodes: left", "nodes: middle"),), "contacts[0].nodes", "nodes: middle",
        ("no node group 'middle'", "left, right")),
    Bad("support-group", (before_output("supports: [{nodes: clamp, fix: [x]}]"),), "supports[0].nodes",
        "supports:", ("no node group 'clamp'", "left, right")),
    Bad("load-group", (before_output("loads: [{nodes: tip, force: [1.0]}]"),), "loads[0].nodes", "loads:",
        ("no node group 'tip'", "left, right")),
    Bad("material-body", ((MATERIAL, "materials:\n  rod: {E: 1.0, rho: 1.0}\n"),), "materials.rod", "rod:",
        ("no body 'rod'", "bodies: bar")),
    Bad("initial-body", (("velocity: [-1.0]", "velocity: [{body: rod, value: [-1.0]}]"),),
        "initial.velocity[0]", "velocity:", ("no body 'rod'", "bodies: bar")),
    Bad("load-body", (before_output("loads:\n  - {body: rod, acceleration: [-9.81]}"),), "loads[0].body",
        "- {body: rod", ("no body 'rod'", "bodies: bar")),
    Bad("gmsh-group", (PAIR_MESH, pair("a_right, b_middle")), "contacts[0].nodes", "nodes: [a_right",
        ("no node group 'b_middle'", "a_right, b_left, b_left_extra")),
    Bad("gmsh-body", (PAIR_MESH, (MATERIAL, "materials:\n  bar_a: {E: 1.0, rho: 1.0}\n"
                                            "  bar_c: {E: 1.0, rho: 1.0}\n")),
        "materials.bar_c", "bar_c:", ("no body 'bar_c'", "bodies: bar_a, bar_b")),
    # parameters: reserved names, unknown names in expressions, a --set parameter nothing uses
    Bad("param-reserved", (before_output("parameters: {t: 1.0}"),), "parameters.t", "parameters:",
        ("'t' is reserved",)),
    Bad("param-not-a-number", (before_output("parameters: {F0: strong}"),), "parameters.F0", "parameters:",
        ("expected a number", "'strong'")),
    Bad("param-unknown-name", (before_output('parameters: {F0: 1.0}\nloads: [{nodes: right, force: ["G0*t"]}]'),),
        "loads[0].force[0]", "loads:", ("'G0' is not an allowed name", "F0")),
    Bad("param-set-unused", (), "parameters.freq", None, ("no expression of the case uses parameter 'freq'",
                                                         "--set parameters.freq=1"),
        args=("--set", "parameters.freq=1")),
    # a missing mesh file
    Bad("mesh-missing", ((BUILTIN_MESH, "  file: meshes/missing.msh\n"),), "mesh.file", "file:",
        ("mesh file not found", "missing.msh")),
    # normals of the wrong dimension or zero length (one component = x, valid in any dimension)
    Bad("normal-2-in-1d", (("normal: [-1.0]", "normal: [-1.0, 0.0]"),), "contacts[0].normal", "normal:",
        ("2 components", "the mesh is 1D (give 1 component)")),
    Bad("normal-3-in-2d", (("dim: 1", "dim: 2"), ("normal: [-1.0]", "normal: [-1.0, 0.0, 0.0]")),
        "contacts[0].normal", "normal:", ("3 components", "the mesh is 2D (give 1 or 2 components)")),
    Bad("normal-zero", (("normal: [-1.0]", "normal: [0.0]"),), "contacts[0].normal", "normal:",
        ("nonzero length",)),
    # pair groups that do not match up (1 node against 2)
    Bad("pair-mismatch", (PAIR_MESH, pair("a_right, b_left_extra")), "contacts[0].nodes", "nodes: [a_right",
        ("do not match up", "1 node)", "2 nodes")),
    # expressions that are not plain arithmetic (the payload would touch SENTINEL if executed)
    Bad("expr-velocity", (("velocity: [-1.0]", f'velocity: ["{PAYLOAD}"]'),), "initial.velocity[0]",
        "velocity:", ("not allowed",)),
    Bad("expr-force", (before_output(f'loads: [{{nodes: right, force: ["{PAYLOAD}"]}}]'),),
        "loads[0].force[0]", "loads:", ("not allowed",)),
    Bad("expr-set", (), "initial.velocity[0]", None, ("not allowed",),
        args=("--set", f'initial.velocity=["{PAYLOAD}"]')),
    Bad("expr-attribute", (("velocity: [-1.0]", 'velocity: ["x.__class__"]'),), "initial.velocity[0]",
        "velocity:", ("attribute access is not allowed",)),
    Bad("initial-not-finite", (("velocity: [-1.0]", 'velocity: ["-1/x"]'),), "initial.velocity[0]",
        "velocity:", ("'-1/x' is not finite",)),
    # an initial state that already violates a constraint: the left end 0.2 beyond a gap of 0.1
    Bad("initial-penetration", (("  velocity: [-1.0]\n", "  velocity: [-1.0]\n  displacement: [-0.2]\n"),),
        "contacts[0]", "- name: wall", ("violates contact 'wall'",)),
    # errors found after the mesh is built, into an OUT that does not exist yet: it is not created
    Bad("fresh-contact-group", (("nodes: left", "nodes: middle"),), "contacts[0].nodes", "nodes: middle",
        ("no node group 'middle'",), fresh=True),
    # numbers whose squares (or the model's products of them) leave the floats (issue 16): refused on their key
    # before anything is built, with no advice that belongs to another cause
    Bad("E-huge", (), "material.E", None, ("must be within 1e-100 and 1e+100", "got 1e+308", "--set material.E=1e308"),
        args=("--set", "material.E=1e308")),
    Bad("area-huge", (("  area: 1.0", "  area: 1e308"),), "material.area", "area: 1e308", ("must be within",)),
    Bad("area-subnormal", (), "material.area", None, ("got 1e-320",), args=("--set", "material.area=1e-320")),
    Bad("beta-huge", (), "damping.beta", None, ("got 1e+308",), args=("--set", "damping.beta=1e308")),
    Bad("length-subnormal", (), "mesh.length", None, ("got 1e-320",), args=("--set", "mesh.length=1e-320")),
    Bad("rho-subnormal", (), "material.rho", None, ("got 1e-320",),
        args=("--set", "material.rho=1e-320", "--set", "solver.method=central_difference"), never=("explicit",)),
    # a declared exact solution the case does not fit (B1's clamped bar on B2's free one)
    Bad("reference-unfit", (("name: bad\n", "name: bad\nreference: b1\n"),), "reference", "reference: b1",
        ("b1: needs one support holding x at the other end (right)",)),
    # a valid case whose solution blows up during the time loop (after the staging folder exists)
    Bad("run-fails", (before_output('loads: [{nodes: right, force: ["exp(1e5*t)"]}]'),), None, None,
        ("the run failed", "no longer finite", "left as it was"), runtime=True),
]
EXPRESSION_CASES = [bad.id for bad in BAD if bad.id.startswith("expr-")]


def edited(edits) -> str:
    text = GOOD
    for old, new in edits:
        assert text.count(old) == 1, f"{old!r} must occur once in the case"
        text = text.replace(old, new)
    return text


def write_pair_mesh(path: Path) -> None:
    """Two 1D bars [0, 1] and [1.1, 2.1]: bodies bar_a, bar_b; node groups a_right, b_left
    (one node each) and b_left_extra (two nodes, so it cannot pair with a_right)."""
    import gmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.model.add("two_bars")
        geo = gmsh.model.geo
        p = [geo.addPoint(x, 0.0, 0.0, 0.25) for x in (0.0, 1.0, 1.1, 2.1)]
        a, b = geo.addLine(p[0], p[1]), geo.addLine(p[2], p[3])
        geo.synchronize()
        for dim, tags, name in ((1, [a], "bar_a"), (1, [b], "bar_b"), (0, [p[1]], "a_right"),
                                (0, [p[2]], "b_left"), (0, [p[2], p[3]], "b_left_extra")):
            gmsh.model.setPhysicalName(dim, gmsh.model.addPhysicalGroup(dim, tags), name)
        gmsh.model.mesh.generate(1)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def snapshot(folder: Path) -> dict | None:
    """Every file below `folder` with its bytes (None when the folder does not exist)."""
    if not folder.exists():
        return None
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@dataclass
class Outcome:
    case: Path
    out: Path
    before: dict | None
    proc: object


@pytest.fixture(scope="module")
def previous(tmp_path_factory):
    """The result of a good run (the earlier result every bad run must leave alone)."""
    root = tmp_path_factory.mktemp("bad_input")
    good = root / "good.yaml"
    good.write_text(GOOD)
    proc = run_cli("run", str(good), "-o", "previous", "-q", cwd=root)
    assert proc.returncode == 0, proc.stderr
    return root / "previous"


@pytest.fixture(scope="module")
def outcomes(previous):
    """Run every bad case (concurrently) into an OUT holding an earlier good result."""
    root = previous.parent
    write_pair_mesh(root / "pair.msh")

    jobs = {}
    for bad in BAD:
        folder = root / bad.id
        folder.mkdir()
        case = folder / "bad.yaml"
        case.write_text(edited(bad.edits))
        shutil.copy(root / "pair.msh", folder / "pair.msh")
        out = folder / "out"
        if not bad.fresh:
            shutil.copytree(previous, out)
        jobs[bad.id] = (bad, case, out, snapshot(out))

    def launch(job):
        bad, case, out, before = job
        proc = run_cli("run", case.name, "-o", out.name, *bad.args, cwd=case.parent)
        return bad.id, Outcome(case, out, before, proc)

    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 1)) as pool:
        return dict(pool.map(launch, jobs.values()))


def test_good_run_leaves_only_its_output_folder(previous):
    assert {"history.csv", "summary.json", "case.resolved.yaml", "results.pvd"} <= set(snapshot(previous))
    assert [p.name for p in previous.parent.iterdir() if p.name.startswith(".previous.")] == []


@pytest.mark.parametrize("bad", BAD, ids=[bad.id for bad in BAD])
def test_bad_input_is_reported(outcomes, bad):
    result = outcomes[bad.id]
    err = result.proc.stderr
    assert result.proc.returncode not in (0, None), err
    assert "Traceback" not in err, err
    assert len(err.strip().splitlines()) < 5, err
    if bad.runtime:
        assert err.startswith("fem-impact: the run failed: "), err
    else:
        assert err.startswith("fem-impact: error: "), err
        assert result.case.name in err, err
    if bad.at is not None:
        lines = result.case.read_text().splitlines()
        line = next(n for n, text in enumerate(lines, 1) if bad.at in text)
        assert f"{result.case.name}:{line}: " in err, err
    if bad.key is not None:
        assert f": {bad.key}: " in err, err
    for fragment in bad.says:
        assert fragment in err, err
    for fragment in bad.never:
        assert fragment not in err, err


@pytest.mark.parametrize("bad", BAD, ids=[bad.id for bad in BAD])
def test_output_folder_left_as_it_was(outcomes, bad):
    result = outcomes[bad.id]
    assert result.proc.returncode != 0
    assert snapshot(result.out) == result.before
    if bad.fresh:
        assert not result.out.exists()
    else:
        assert {"history.csv", "summary.json", "case.resolved.yaml"} <= set(result.before)
    leftovers = [p.name for p in result.out.parent.iterdir() if p.name.startswith(".out.")]
    assert leftovers == []


def test_expression_is_never_executed(outcomes, tmp_path):
    for name in EXPRESSION_CASES:
        result = outcomes[name]
        assert result.proc.returncode != 0, name
        assert "not allowed" in result.proc.stderr, result.proc.stderr
    assert not list(result.case.parent.parent.rglob("SENTINEL"))
    # The payload does leave a trace when Python runs it, so its absence above means something.
    cwd = os.getcwd()
    try:
        os.chdir(tmp_path)
        eval(PAYLOAD)  # noqa: S307 - deliberately, in a scratch folder
    finally:
        os.chdir(cwd)
    assert (tmp_path / "SENTINEL").exists()
