"""Class ``small-defects``: the small things a user meets around a run, each with its variants.

- ``--set KEY=null`` takes out a key that a refusal asks to remove (null is "not given", as everywhere
  in a case file), and the axisymmetric model's refusal of ``area`` says so;
- a YAML alias inside its own anchor (from ``--set`` or a file) is one line naming the key;
- ``fem-impact animate`` renders a run written as XDMF (``output.format: xdmf``) as it does a VTK one;
- damaged XDMF results (a truncated ``results.h5``, a cut index, a missing data set) are one line
  naming the file, from ``animate`` (status 2) and from ``Result.fields()`` (a SimulationError);
- two physical groups of one name in a Gmsh file are refused naming the file and the name;
- ``fem-impact modes`` gives an axisymmetric model's effective mass along its axis only;
- the mesh scripts of ``meshes/`` take their main dimensions as options, build a mesh that
  fem-impact runs, and refuse values that do not fit in one line (status 2, no file).
"""

from __future__ import annotations

import csv

import yaml

from . import CASES, ROOT, ok, probe, wrong

BAR = CASES / "impacting_bar.yaml"
AXI = CASES / "vibroconverter_axi.yaml"
SHORT = ("--set", "solver.t_end=0.02", "--set", "solver.dt=0.01", "--set", "mesh.cells=10")


def _write(ctx, name: str, data: dict):
    path = ctx.folder / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _refused_then_null_runs(ctx, case, bad: list, null: str, needle: str, *more):
    """``bad`` --set options are refused naming ``needle``; with ``--set NULL=null`` added, the run goes."""
    sets = [x for option in bad for x in ("--set", option)]
    out = ctx.folder / "out"
    r = ctx.run("run", case, "-q", "-o", out, *sets, *more)
    verdict = ctx.refused(r, needle)
    if verdict.kind != "ok":
        return verdict
    r = ctx.run("run", case, "-q", "-o", out, *sets, *more, "--set", f"{null}=null")
    return ctx.succeeded(r) or ok(f"null took {null} out")


# -- --set KEY=null: the key a refusal asks to remove ----------------------------------------------

AXI_BAR = {"name": "disk", "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.2, "cells": 4,
                                    "hypothesis": "axisymmetric"},
           "material": {"E": 1.0, "rho": 1.0, "nu": 0.3, "area": 2.0},
           "solver": {"dt": 0.01, "t_end": 0.02}, "output": {"vtk": False}}


@probe("small-defects", "axisymmetric model with material.area: refused, the advice named, --set ...=null runs")
def _axi_area(ctx):
    case = _write(ctx, "disk.yaml", AXI_BAR)
    r = ctx.run("run", case, "-q", "-o", ctx.folder / "out")
    verdict = ctx.refused(r, "material.area", "--set material.area=null")
    if verdict.kind != "ok":
        return verdict
    return ctx.succeeded(ctx.run("run", case, "-q", "-o", ctx.folder / "out", "--set", "material.area=null")) or ok()


@probe("small-defects", "axisymmetric model with materials.BODY.area: refused, --set materials.bar.area=null runs")
def _axi_materials_area(ctx):
    data = {**AXI_BAR, "materials": {"bar": AXI_BAR["material"]}}
    del data["material"]
    case = _write(ctx, "disk.yaml", data)
    r = ctx.run("run", case, "-q", "-o", ctx.folder / "out")
    verdict = ctx.refused(r, "materials.bar.area", "--set materials.bar.area=null")
    if verdict.kind != "ok":
        return verdict
    return ctx.succeeded(ctx.run("run", case, "-q", "-o", ctx.folder / "out", "--set",
                                 "materials.bar.area=null")) or ok()


@probe("small-defects", "impacting_bar.yaml made axisymmetric by --set: area refused, then taken out by null")
def _axi_by_set(ctx):
    return _refused_then_null_runs(ctx, BAR, ["mesh.dim=2", "mesh.height=0.1", "mesh.hypothesis=axisymmetric",
                                              "mesh.axis=x"], "material.area", "material.area", *SHORT)


NULL_KEYS = [   # (--set options refused with "remove it", the key null takes out)
    (["mesh.height=0.1"], "mesh.height"),
    (["mesh.hypothesis=plane_strain"], "mesh.hypothesis"),
    (["mesh.dim=2", "mesh.axis=x"], "mesh.axis"),
    (["solver.method=modal", "solver.modes=3", "solver.tolerance=0.1"], "solver.tolerance"),
    (["contacts.0.stiffness=1e6", "contacts.0.restitution=0.5"], "contacts.0.restitution"),
    (["solver.theta=0.5"], "solver.theta"),
]

for _bad, _key in NULL_KEYS:
    def _null(ctx, bad=_bad, key=_key):
        needle = key.replace(".0.", "[0].")
        return _refused_then_null_runs(ctx, BAR, bad, key, needle, *SHORT)
    probe("small-defects", f"--set {' '.join(_bad)}: refused, then --set {_key}=null runs")(_null)


# -- YAML aliases inside their own anchors --------------------------------------------------------

ALIASES = [("material.E=&a [*a]", "material.E"), ("material=&m {E: *m}", "material"),
           ("contacts.0=&c {name: *c}", "contacts"), ("initial.velocity=[&v [1, *v]]", "initial.velocity"),
           ("parameters.a.b.c.d.e.f.g=" + "[" * 60 + "1" + "]" * 60, "parameters")]

for _option, _needle in ALIASES:
    def _alias(ctx, option=_option, needle=_needle):
        out = ctx.folder / "out"
        verdict = ctx.refused(ctx.run("run", BAR, "-q", "-o", out, "--set", option), needle)
        return wrong(f"refused, yet {out} was written") if verdict.kind == "ok" and out.exists() else verdict
    probe("small-defects", f"--set {_option[:40]}: one line naming the key")(_alias)


@probe("small-defects", "a case file with an alias inside its own anchor: one line naming the key and line")
def _alias_in_file(ctx):
    text = BAR.read_text().replace("initial:\n  velocity: [-1.0]", "initial:\n  velocity: &a [*a]")
    if text == BAR.read_text():
        return wrong("the probe's case edit did not apply (impacting_bar.yaml changed?)")
    case = ctx.folder / "looped.yaml"
    case.write_text(text)
    return ctx.refused(ctx.run("run", case, "-q", "-o", ctx.folder / "out"), "looped.yaml:", "initial.velocity")


# -- XDMF results: animate, and damaged files ----------------------------------------------------

def _xdmf_run(ctx, dim: int):
    """A short run written as XDMF (shared by the probes), copied into the probe's folder."""
    def build(work):
        r = ctx.run("run", BAR, "-q", "-o", work / "run", "--set", f"mesh.dim={dim}", "--set", "mesh.cells=20",
                    "--set", "solver.dt=0.02", "--set", "solver.t_end=0.2", "--set", "output.every=2",
                    "--set", "output.format=xdmf")
        if r.status != 0:
            raise RuntimeError(f"the XDMF run failed: {r.tail()}")
    return ctx.shared(f"xdmf{dim}d", build) / "run"


for _dim in (1, 2):
    def _animate_xdmf(ctx, dim=_dim):
        run = _xdmf_run(ctx, dim)
        gif = ctx.folder / "x.gif"
        r = ctx.run("animate", run, "-o", gif, "--size", "160x96")
        bad = ctx.succeeded(r)
        if bad:
            return bad
        if "(6 frames" not in r.stdout or not gif.is_file():
            return wrong(f"expected 6 frames in {gif}: {r.stdout.strip()}")
        r = ctx.run("animate", run, "--frame", "2", "-o", ctx.folder / "f.png", "--size", "160x96")
        return ctx.succeeded(r) or ok(r.stdout.strip())
    probe("small-defects", f"animate a {_dim}D run written as XDMF: a GIF and a PNG")(_animate_xdmf)


def _truncate(path, keep: float = 0.5):
    path.write_bytes(path.read_bytes()[: int(path.stat().st_size * keep)])


def _rename_last_dataset(path):
    text = path.read_text()
    last = text.rindex("results.h5:/Function/u/")
    path.write_text(text[:last] + text[last:].replace("/Function/u/", "/Function/w/", 1))


DAMAGES = {
    "results.h5 truncated to half": lambda run: _truncate(run / "results.h5"),
    "results.h5 emptied": lambda run: _truncate(run / "results.h5", 0.0),
    "results.h5 removed": lambda run: (run / "results.h5").unlink(),
    "results.xdmf cut in half": lambda run: _truncate(run / "results.xdmf"),
    "results.xdmf garbage": lambda run: (run / "results.xdmf").write_text("not xml at all <"),
    "the last frame's data set renamed": lambda run: _rename_last_dataset(run / "results.xdmf"),
}

FIELDS_SCRIPT = """
import sys
import fem_impact as fi
try:
    fields = fi.Result.load(sys.argv[1]).fields()
except fi.SimulationError as err:
    print(f"fem-impact: error: {err}", file=sys.stderr)
    sys.exit(2)
print(len(fields.t), "frames")
"""

for _name, _damage in DAMAGES.items():
    def _animate_damaged(ctx, damage=_damage):
        run = _xdmf_run(ctx, 2)
        damage(run)
        r = ctx.run("animate", run, "-o", ctx.folder / "x.gif")
        verdict = ctx.refused(r, "results.xdmf", max_lines=1)
        if verdict.kind == "ok" and (ctx.folder / "x.gif").exists():
            return wrong("refused, yet the GIF was written")
        return verdict

    def _fields_damaged(ctx, damage=_damage):
        run = _xdmf_run(ctx, 2)
        damage(run)
        script = ctx.folder / "fields.py"
        script.write_text(FIELDS_SCRIPT)
        return ctx.refused(ctx.run(script, run, python=True), "results.xdmf", max_lines=1)

    probe("small-defects", f"animate on XDMF results, {_name}: one line")(_animate_damaged)
    probe("small-defects", f"Result.load(...).fields(), {_name}: a SimulationError naming the file")(_fields_damaged)


@probe("small-defects", "animate on a run without fields (output.vtk: false): one line naming both series")
def _animate_nothing(ctx):
    run = ctx.folder / "run"
    bad = ctx.succeeded(ctx.run("run", BAR, "-q", "-o", run, *SHORT, "--set", "output.vtk=false"))
    if bad:
        return bad
    return ctx.refused(ctx.run("animate", run), "results.pvd", "results.xdmf", max_lines=1)


# -- Gmsh files with two physical groups of one name ------------------------------------------------

GMSH_SCRIPT = """
import sys
import gmsh
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
a, b = gmsh.model.occ.addRectangle(0, 0, 0, 1, 0.5), gmsh.model.occ.addRectangle(1, 0, 0, 1, 0.5)
gmsh.model.occ.fragment([(2, a)], [(2, b)])
gmsh.model.occ.synchronize()
for dim, tags, name in ((2, [a], "bar_a"), (2, [b], "bar_b"), (0, [1], "corner")):
    gmsh.model.setPhysicalName(dim, gmsh.model.addPhysicalGroup(dim, tags), name)
for name, x in (("left", 0.0), ("right", 2.0)):
    ends = gmsh.model.getEntitiesInBoundingBox(x - 1e-6, -1e-6, -1e-6, x + 1e-6, 0.5 + 1e-6, 1e-6, 1)
    gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, [t for _, t in ends]), name)
gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
gmsh.model.mesh.generate(2)
gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
gmsh.write(sys.argv[1])
gmsh.finalize()
"""

TWINS = [({"bar_b": "bar_a"}, "bar_a", True), ({"right": "left"}, "left", True),
         ({"corner": "left"}, "left", True), ({"corner": "right", "right": "corner"}, None, False),
         ({"corner": "bar_a"}, None, False)]


def _twins(renames: dict, name: str | None, refused: bool):
    def body(ctx):
        def build(work):
            script = work / "two_bodies.py"
            script.write_text(GMSH_SCRIPT)
            r = ctx.run(script, work / "good.msh", python=True)
            if r.status != 0:
                raise RuntimeError(f"gmsh failed: {r.tail()}")
        good = (ctx.shared("two_bodies", build) / "good.msh").read_text()
        head, _, rest = good.partition("$PhysicalNames")
        names, _, tail = rest.partition("$EndPhysicalNames")
        swapped = {old: f"@{k}@" for k, old in enumerate(renames)}
        for old, marker in swapped.items():
            names = names.replace(f'"{old}"', f'"{marker}"')
        for old, marker in swapped.items():
            names = names.replace(f'"{marker}"', f'"{renames[old]}"')
        mesh = ctx.folder / "bars.msh"
        mesh.write_text(f"{head}$PhysicalNames{names}$EndPhysicalNames{tail}")
        case = _write(ctx, "case.yaml", {"name": "twins", "mesh": {"file": "bars.msh"},
                                         "material": {"E": 1.0, "rho": 1.0, "area": 1.0},
                                         "supports": [{"nodes": "left", "fix": "all"}],
                                         "solver": {"dt": 0.1, "t_end": 0.2}, "output": {"vtk": False}})
        r = ctx.run("run", case, "-q", "-o", ctx.folder / "out")
        if refused:
            return ctx.refused(r, "bars.msh", f"'{name}'", "mesh.file")
        return ctx.succeeded(r) or ok()
    return body


for _renames, _name, _refused in TWINS:
    _what = ", ".join(f"{a} -> {b}" for a, b in _renames.items())
    probe("small-defects", f"Gmsh file with groups renamed {_what}: "
                           f"{'refused naming the file and the name' if _refused else 'runs'}")(
        _twins(_renames, _name, _refused))


# -- modes of an axisymmetric model ------------------------------------------------------------------

def _modes_columns(ctx, case, *args):
    out = ctx.folder / "modes"
    r = ctx.run("modes", case, "-o", out, *args)
    bad = ctx.succeeded(r)
    if bad:
        return None, None, bad
    with open(out / "modes.csv", newline="") as f:
        return next(csv.reader(f)), r.stdout, None


for _axis, _radial in (("y", "x"), ("x", "y")):
    def _axi_modes(ctx, axis=_axis, radial=_radial):
        data = {**AXI_BAR, "mesh": {**AXI_BAR["mesh"], "axis": axis}}
        data["material"] = {k: v for k, v in AXI_BAR["material"].items() if k != "area"}
        columns, table, bad = _modes_columns(ctx, _write(ctx, "disk.yaml", data), "-n", "4")
        if bad:
            return bad
        if f"mass_{radial}_percent" in columns or f"mass_{axis}_percent" not in columns:
            return wrong(f"modes.csv columns {columns}: the axis is {axis}, the radius {radial}")
        if f"mass {radial} [%]" in table:
            return wrong("the table prints a radial effective mass")
        return ok()
    probe("small-defects", f"modes of an axisymmetric model about {_axis}: effective mass along {_axis} only")(
        _axi_modes)


@probe("small-defects", "modes of vibroconverter_axi.yaml --at tip --direction y (the radius): no Gamma")
def _axi_modes_at(ctx):
    columns, table, bad = _modes_columns(ctx, AXI, "-n", "2", "--at", "tip", "--direction", "y")
    if bad:
        return bad
    if any(c.startswith("participation") for c in columns) or "mass_y_percent" in columns:
        return wrong(f"modes.csv columns {columns}")
    return ok() if "no Gamma" in table else wrong("the table does not say why Gamma is left out")


@probe("small-defects", "modes of a plane model: effective masses along x and y")
def _plane_modes(ctx):
    data = {**AXI_BAR, "mesh": {k: v for k, v in AXI_BAR["mesh"].items() if k != "hypothesis"}}
    columns, _, bad = _modes_columns(ctx, _write(ctx, "plate.yaml", data), "-n", "3")
    if bad:
        return bad
    return ok() if {"mass_x_percent", "mass_y_percent"} <= set(columns) else wrong(f"columns {columns}")


# -- mesh scripts with their dimensions as options --------------------------------------------------

SCRIPT_RUNS = [   # (script, options, case, --set options for the case)
    ("vibroconverter_axi.py", ["--length", "0.08", "--r-large", "0.012", "--r-small", "0.004", "--h", "2e-3"], AXI,
     ["output.probes={tip: [0.08, 0.0]}", "solver.t_end=1e-6"]),
    ("vibroconverter_axi.py", ["--split", "0.4", "--h", "2.5e-3"], AXI,
     ["output.probes={tip: [0.1, 0.0]}", "solver.t_end=1e-6"]),
    ("vibromotor.py", ["--slider-length", "0.04", "--driver-height", "0.015", "--h", "2.5e-3"],
     CASES / "vibromotor.yaml", ["solver.t_end=5e-5", "output.vtk=false"]),
    ("vibromotor.py", ["--driver-width", "0.012", "--slider-thickness", "0.006", "-h", "2e-3"],
     CASES / "vibromotor.yaml", ["solver.t_end=5e-5", "output.vtk=false"]),
    ("vibroconverter.py", ["--length", "0.12", "--split", "0.5", "--h", "4e-3"], CASES / "vibroconverter_free.yaml",
     ["solver.t_end=1e-6", "output.probes={tip: [0.12]}"]),
    ("two_bars.py", ["--length", "0.5", "--gap", "0.05", "--cells", "20"], CASES / "two_bars.yaml",
     ["solver.t_end=0.01", "output.vtk=false", "output.probes={a_right: [0.5], b_left: [0.55]}"]),
]

for _script, _options, _case, _sets in SCRIPT_RUNS:
    def _script_runs(ctx, script=_script, options=_options, case=_case, sets=_sets):
        mesh = ctx.folder / "m.msh"
        r = ctx.run(ROOT / "meshes" / script, *options, "-o", mesh, python=True)
        bad = ctx.succeeded(r)
        if bad:
            return bad
        if not mesh.is_file():
            return wrong(f"{script} said {r.stdout.strip()!r} but wrote no {mesh}")
        r = ctx.run("run", case, "-q", "-o", ctx.folder / "out", "--set", f"mesh.file={mesh}",
                    *(x for s in sets for x in ("--set", s)))
        return ctx.succeeded(r) or ok()
    probe("small-defects", f"meshes/{_script} {' '.join(_options)}: fem-impact runs the mesh")(_script_runs)

SCRIPT_ERRORS = [
    ("vibroconverter_axi.py", ["--length", "-0.1"], "--length"),
    ("vibroconverter_axi.py", ["--r-small", "0.02"], "small radius"),
    ("vibroconverter_axi.py", ["--split", "1.2"], "split"),
    ("vibroconverter_axi.py", ["--h", "nan"], "--h"),
    ("vibroconverter_axi.py", ["--h", "0.03"], "h = 0.03"),
    ("vibroconverter_axi.py", ["--r-large", "big"], "--r-large"),
    ("vibromotor.py", ["--slider-length", "0.005"], "slider"),
    ("vibromotor.py", ["-h", "0"], "-h/--h"),
    ("vibromotor.py", ["--driver-height", "inf"], "--driver-height"),
    ("two_bars.py", ["--cells", "0"], "cells"),
    ("two_bars.py", ["--gap", "-1"], "--gap"),
    ("vibroconverter.py", ["--split", "0"], "--split"),
    ("vibrodrive.py", ["--alpha", "70"], "alpha"),
    ("vibrodrive.py", ["--refine", "0.5"], "refine"),
]

for _script, _options, _needle in SCRIPT_ERRORS:
    def _script_refuses(ctx, script=_script, options=_options, needle=_needle):
        r = ctx.run(ROOT / "meshes" / script, *options, "-o", ctx.folder / "m.msh", python=True)
        verdict = ctx.refused(r, needle, f"{script}: error:", max_lines=1)
        if verdict.kind == "ok" and (ctx.folder / "m.msh").exists():
            return wrong("refused, yet the mesh was written")
        return verdict
    probe("small-defects", f"meshes/{_script} {' '.join(_options)}: refused naming it")(_script_refuses)


@probe("small-defects", "meshes/vibroconverter_axi.py -o horn.vtk: refused (Gmsh picks the format by extension)")
def _script_bad_output(ctx):
    r = ctx.run(ROOT / "meshes" / "vibroconverter_axi.py", "-o", ctx.folder / "horn.vtk", python=True)
    return ctx.refused(r, "-o/--output", ".msh", max_lines=1)


@probe("small-defects", "meshes/*.py --help: every script lists its dimensions with units and defaults")
def _script_help(ctx):
    wanted = {"vibroconverter_axi.py": ("--length", "--r-large", "--r-small", "--split", "in m", "default"),
              "vibromotor.py": ("--driver-width", "--driver-height", "--slider-length", "--slider-thickness", "in m"),
              "vibroconverter.py": ("--length", "--split", "in m"), "two_bars.py": ("--length", "--gap", "--cells"),
              "vibrodrive.py": ("--length", "--width", "--alpha", "in m"),
              "hammer_rod.py": ("--length", "--side", "--hammer", "--gap", "--cells", "default 0.2 m"),
              "block_on_slab.py": ("--cell", "default 0.01 m")}
    problems = []
    for script, needles in wanted.items():
        r = ctx.run(ROOT / "meshes" / script, "--help", python=True)
        bad = ctx.succeeded(r)
        if bad:
            return bad
        text = " ".join(r.stdout.split())
        problems += [f"{script} --help does not mention {n}" for n in needles if n not in text]
    return wrong("; ".join(problems)) if problems else ok()


# -- tractions: a force per unit area on a node group's boundary faces -------------------------------------

TRACTION_BAR = {"name": "pulled", "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.1, "cells": 10},
                "material": {"E": 100.0, "rho": 1.0, "nu": 0.3, "area": 0.5},
                "loads": [{"nodes": "right", "traction": ["3*t", 2.0]}],
                "solver": {"dt": 0.01, "t_end": 0.5}, "output": {"vtk": False}}


@probe("small-defects", "a traction on a 2D bar's end: its momentum the traction's impulse times the end's area")
def _traction_impulse(ctx):
    case = _write(ctx, "pulled.yaml", TRACTION_BAR)
    r = ctx.run("run", case, "-q", "-o", ctx.folder / "out")
    bad = ctx.succeeded(r)
    if bad:
        return bad
    with open(ctx.folder / "out" / "history.csv", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    t, px, py = (float(rows[-1][k]) for k in ("t", "bar.px", "bar.py"))
    area = 0.1 * 0.5
    want = (1.5 * t * t * area, 2.0 * t * area)   # (the trapezoidal rule is exact on a linear load)
    if abs(px - want[0]) > 1e-9 * want[0] or abs(py - want[1]) > 1e-9 * want[1]:
        return wrong(f"momentum ({px:.10g}, {py:.10g}), the traction's impulse ({want[0]:.10g}, {want[1]:.10g})")
    return ok()


for _name, _load, _needles in (
        ("with a force on the same load", {"nodes": "right", "traction": [1.0], "force": [1.0]},
         ("loads[0].traction", "not both")),
        ("on a group the mesh lacks", {"nodes": "rim", "traction": [1.0]}, ("loads[0].nodes", "rim")),
        ("with an acceleration", {"nodes": "right", "traction": [1.0], "acceleration": [1.0]},
         ("loads[0].acceleration",)),
        ("not a number", {"nodes": "right", "traction": ["fast"]}, ("loads[0].traction",)),
):
    def _refusal(ctx, load=_load, needles=_needles):
        case = _write(ctx, "pulled.yaml", {**TRACTION_BAR, "loads": [load]})
        out = ctx.folder / "out"
        verdict = ctx.refused(ctx.run("run", case, "-q", "-o", out), *needles)
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    probe("small-defects", f"a traction {_name}: refused naming the key")(_refusal)
