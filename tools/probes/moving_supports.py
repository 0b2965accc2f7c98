"""Class ``moving-supports``: contacts and structures next to supports with a prescribed motion
(``supports[].displacement``), 1D/2D/3D, every method, the reduced model with and without its static
correction, components held still and driven, motions that start at 0 or not.

Each probe judges an exact answer where there is one, or a refusal in one line naming the key:

- a rod at rest against a wall, pushed at either end at v (E = rho = L = 1): the wall force
  2 rho c A v on [L/c, 3L/c], the pushed end's reaction rho c A v on [0, 2L/c], the pushed end at
  v t (the staircase of tests/test_prescribed_motion.py);
- a free rod pushed at v towards a wall d away from its other end: that end stays until L/c, then
  moves at 2v, so it first touches the wall at L/c + d/(2v);
- a table whose base is driven (a step from t = 0, or a smooth ramp from 0), damped: at rest, its
  top has moved with the base (a rigid translation), and the base takes no force;
- a block pushed along a frictionless floor under gravity: at rest, it has moved with its pushed end,
  and the floor carries its weight;
- what cannot be done correctly is refused (status 2, naming the key): the reduced model without
  its static correction, a contact on a driven dof, a dof held still by one support and moved by
  another, two motions of one dof; a motion that blows up stops the run in one line (status 3).
"""

from __future__ import annotations

import csv

import numpy as np
import yaml

from . import CASES, ok, probe, wrong

V = 0.01       # pushing speed (c = 1)
CELLS = 50
A = 1e-3       # base motion of the table

# method name -> solver keys (the reduced model with its static correction, unless said)
METHODS = {
    "moreau_jean": {"method": "moreau_jean"},
    "newmark": {"method": "newmark"},
    "central_difference": {"method": "central_difference"},
    "modal": {"method": "modal", "modes": 20},
    "modal-newmark": {"method": "modal", "scheme": "newmark", "modes": 20},
}
# how close a staircase plateau must come (the discrete front's ripple; the reduced model's truncation)
PLATEAU = {"moreau_jean": 0.02, "newmark": 0.02, "central_difference": 0.02, "modal": 0.05, "modal-newmark": 0.05}


# -- the cases ------------------------------------------------------------------------------------

def _bar(dim: int, cells: int = CELLS, height: float = 0.1, width: float = 0.1) -> dict:
    mesh = {"shape": "bar", "dim": dim, "length": 1.0, "cells": cells}
    if dim >= 2:
        mesh["height"] = height
    if dim == 3:
        mesh["width"] = width
    return mesh


def _section(dim: int) -> float:
    """The rod's cross-section (m^2 in 3D; thickness x height in 2D; area in 1D)."""
    return {1: 1.0, 2: 0.1 * 10.0, 3: 0.1 * 0.1}[dim]


def _material(dim: int, nu: float = 0.0) -> dict:
    material = {"E": 1.0, "rho": 1.0, "nu": nu}
    if dim < 3:
        material["area"] = 1.0 if dim == 1 else 10.0
    return material


def _point(dim: int, x: float) -> list:
    """A point at ``x`` on the rod's axis."""
    return [x] + [0.05] * (dim - 1)


def _rod(dim: int, end: str, method: str, gap: float, t_end: float) -> dict:
    """A rod pushed at ``end`` at speed V (towards the other end), a wall ``gap`` beyond the other end."""
    sign, wall = (1.0, "right") if end == "left" else (-1.0, "left")
    solver = {**METHODS[method], "dt": 0.5 / CELLS, "t_end": t_end}
    if dim == 3 and method == "central_difference":
        solver["dt"] = 0.2 / CELLS   # (the 3D mesh's stable limit)
    if dim == 3 and method.startswith("modal"):
        solver["modes"] = 40         # (the 3D rod's bending modes come first: the axial ones need more)
    return {"name": "pushed", "parameters": {"v": sign * V},
            "mesh": _bar(dim), "material": _material(dim),
            "supports": [{"nodes": end, "fix": ["x"], "displacement": ["v*t"]}],
            "contacts": [{"name": "wall", "type": "obstacle", "nodes": wall, "normal": [sign] + [0.0] * (dim - 1),
                          "gap": gap, "coupling": "mean"}],
            "solver": solver,
            "output": {"vtk": False, "probes": {"base": _point(dim, 0.0 if end == "left" else 1.0),
                                                "tip": _point(dim, 1.0 if end == "left" else 0.0)}}}


def _table(dim: int, method: str, motion: str) -> dict:
    """A block on a base driven up by ``motion`` (the other components held still), damped to rest."""
    fix = list("xyz"[:dim])
    displacement = ["0"] * dim
    displacement[1] = motion
    solver = {**METHODS[method], "dt": 0.02, "t_end": 12.0}
    if method.startswith("modal"):
        solver["modes"] = 10
    if method == "central_difference":
        solver["dt"] = 0.005
    return {"name": "table", "parameters": {"A": A}, "mesh": _bar(dim, 10, 0.2, 0.2),
            "material": {"E": 1.0, "rho": 1.0, "nu": 0.3, **({"area": 1.0} if dim == 2 else {})},
            "damping": {"alpha": 4.0},
            "supports": [{"nodes": "bottom", "fix": fix, "displacement": displacement}],
            "solver": solver, "output": {"vtk": False, "probes": {"top": [0.5, 0.2, 0.1][:dim]}}}


# -- running and reading --------------------------------------------------------------------------

def _run(ctx, data: dict, *options, mpi: int = 0):
    """Write the case, run it; (completed, output folder)."""
    case = ctx.folder / f"{data['name']}.yaml"
    case.write_text(yaml.safe_dump(data, sort_keys=False))
    out = ctx.folder / "out"
    return ctx.run("run", case, "-q", "-o", out, *options, mpi=mpi), out


def _history(out) -> dict[str, np.ndarray]:
    with open(out / "history.csv", newline="") as f:
        rows = list(csv.reader(f))
    values = np.array(rows[1:], dtype=float)
    return {name: values[:, k] for k, name in enumerate(rows[0])}


def _solved(ctx, data: dict, *options, mpi: int = 0):
    """The run's history, or the verdict of a run that did not end cleanly."""
    r, out = _run(ctx, data, *options, mpi=mpi)
    bad = ctx.succeeded(r)
    return (None, bad) if bad else (_history(out), None)


def _refused(ctx, data: dict, *needles, options=()):
    r, out = _run(ctx, data, *options)
    verdict = ctx.refused(r, *needles)
    if verdict.kind == "ok" and out.exists():
        return wrong(f"refused, yet {out} was written")
    return verdict


def _plateau(h, column, start, end):
    t = h["t"]
    return float(np.median(h[column][(t > start + 0.2) & (t < end - 0.1)]))


def _close(what: str, got: float, want: float, rel: float, problems: list, absolute: float = 0.0) -> None:
    if not abs(got - want) <= rel * abs(want) + absolute:
        problems.append(f"{what} {got:.6g}, exact {want:.6g} (tolerance {rel:g})")


def _judged(problems: list, detail: str = ""):
    return wrong("; ".join(problems)) if problems else ok(detail)


# -- a rod pushed against a wall: the staircase ---------------------------------------------------

def _staircase(dim: int, end: str, method: str, mpi: int = 0):
    def body(ctx):
        h, bad = _solved(ctx, _rod(dim, end, method, gap=0.0, t_end=3.5), mpi=mpi)
        if bad:
            return bad
        sign, area, rel, problems = (1.0 if end == "left" else -1.0), _section(dim), PLATEAU[method], []
        _close("wall force on [1, 3]", _plateau(h, "wall.force", 1.0, 3.0), 2 * V * area, rel, problems)
        _close("wall force on [0, 1]", _plateau(h, "wall.force", 0.0, 1.0), 0.0, 0.0, problems, 1e-6 * V * area)
        reaction = f"{end}.reaction"
        _close("pushed end's reaction on [0, 2]", sign * _plateau(h, reaction, 0.0, 2.0), V * area, rel, problems)
        _close("pushed end's displacement at t_end", h["base.ux"][-1], sign * V * h["t"][-1], 1e-9, problems)
        if h["wall.gap"].min() < -1e-9 * V:
            problems.append(f"the wall is crossed by {-h['wall.gap'].min():.3g}")
        return _judged(problems, f"wall {_plateau(h, 'wall.force', 1.0, 3.0) / (2 * V * area):.4f} x exact")
    return body


for _dim in (1, 2, 3):
    for _end in ("left", "right"):
        for _method in METHODS:
            probe("moving-supports", f"{_dim}D rod pushed at its {_end} end against a wall, {_method}")(
                _staircase(_dim, _end, _method))
for _end in ("left", "right"):
    probe("moving-supports", f"1D rod pushed at its {_end} end against a wall, moreau_jean, 2 MPI ranks")(
        _staircase(1, _end, "moreau_jean", mpi=2))


# -- a free rod driven into a wall: the first touch ----------------------------------------------

def _first_touch(end: str, method: str):
    gap = V   # touched at L/c + d/(2v) = 1.5

    def body(ctx):
        h, bad = _solved(ctx, _rod(1, end, method, gap=gap, t_end=2.0))
        if bad:
            return bad
        problems = []
        touching = np.flatnonzero(h["wall.force"] > 0.0)
        if not touching.size:
            return wrong("the rod never reaches the wall")
        first = h["t"][touching[0]]
        _close("first touch", first, 1.0 + gap / (2 * V), 0.0, problems, 0.05)
        sign = 1.0 if end == "left" else -1.0
        k = int(np.argmin(abs(h["t"] - 1.25)))
        _close("free end's displacement at t = 1.25", sign * h["tip.ux"][k], 2 * V * 0.25, 0.05, problems)
        if h["wall.gap"].min() < -1e-9 * V:
            problems.append(f"the wall is crossed by {-h['wall.gap'].min():.3g}")
        return _judged(problems, f"first touch at {first:.3f} (exact 1.5)")
    return body


for _end in ("left", "right"):
    for _method in METHODS:
        probe("moving-supports", f"free 1D rod driven at its {_end} end into a wall, {_method}")(
            _first_touch(_end, _method))


# -- a table on a driven base: the static displacement -------------------------------------------

MOTIONS = {"a step from t = 0": "A", "a ramp from 0": "A*(1 - cos(pi*min(t, 4)/4))/2"}


def _table_at_rest(dim: int, method: str, motion: str, mpi: int = 0):
    def body(ctx):
        h, bad = _solved(ctx, _table(dim, method, MOTIONS[motion]), mpi=mpi)
        if bad:
            return bad
        problems = []
        _close("top's displacement at rest", h["top.uy"][-1], A, 1e-6, problems)
        _close("top's sideways displacement", h["top.ux"][-1], 0.0, 0.0, problems, 1e-6 * A)
        _close("base's reaction at rest", h["bottom.reaction_y"][-1], 0.0, 0.0, problems, 1e-6 * A)
        return _judged(problems, f"top/base {h['top.uy'][-1] / A:.9f}")
    return body


for _dim in (2, 3):
    for _motion in MOTIONS:
        for _method in METHODS:
            probe("moving-supports", f"{_dim}D table on a base driven by {_motion}, {_method}")(
                _table_at_rest(_dim, _method, _motion))
probe("moving-supports", "2D table on a base driven by a ramp from 0, moreau_jean, 2 MPI ranks")(
    _table_at_rest(2, "moreau_jean", "a ramp from 0", mpi=2))


@probe("moving-supports", "2D block pushed along a frictionless floor under gravity, every method in turn")
def _floor(ctx):
    """The floor's contact rows sit on the pushed end's corner, on the component the support leaves free."""
    problems = []
    for method in METHODS:
        solver = {**METHODS[method], "dt": 0.005 if method == "central_difference" else 0.02, "t_end": 14.0}
        if method.startswith("modal"):
            solver["modes"] = 10
        data = {"name": f"slide_{method.replace('-', '_')}", "parameters": {"A": 0.05, "g": 0.01},
                "mesh": _bar(2, 10, 0.2), "material": {"E": 1.0, "rho": 1.0, "nu": 0.0, "area": 1.0},
                "damping": {"alpha": 3.0}, "loads": [{"body": "all", "acceleration": [0.0, "-g"]}],
                "supports": [{"nodes": "left", "fix": ["x"], "displacement": ["A*(1 - cos(pi*min(t, 4)/4))/2"]}],
                "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0],
                              "gap": 0.0}],
                "solver": solver, "output": {"vtk": False, "probes": {"tip": [1.0, 0.0]}}}
        h, bad = _solved(ctx, data)
        if bad:
            return bad
        # (at rest the block has moved with its pushed end: exact up to the mesh's O(h^2) under gravity)
        _close(f"{method}: tip's displacement at rest", h["tip.ux"][-1], 0.05, 1e-3, problems)
        _close(f"{method}: floor's force at rest (the weight)", h["floor.force"][-1], 0.2 * 0.01, 1e-4, problems)
    return _judged(problems)


# -- refusals -------------------------------------------------------------------------------------

for _dim in (1, 2, 3):
    for _scheme in ("moreau_jean", "newmark"):
        def _truncated(ctx, dim=_dim, scheme=_scheme):
            data = _rod(dim, "left", "modal", gap=0.0, t_end=1.0)
            data["solver"].update(scheme=scheme, static_correction=False)
            return _refused(ctx, data, "solver.static_correction", "supports[0]")
        probe("moving-supports", f"{_dim}D rod, modal ({_scheme}) without static correction: refused")(_truncated)


@probe("moving-supports", "2D table, modal without static correction: refused")
def _table_truncated(ctx):
    data = _table(2, "modal", MOTIONS["a ramp from 0"])
    data["solver"]["static_correction"] = False
    return _refused(ctx, data, "solver.static_correction")


@probe("moving-supports", "base_excited_beam.yaml --set solver.static_correction=false (modal): refused")
def _beam_truncated(ctx):
    out = ctx.folder / "out"
    r = ctx.run("run", CASES / "base_excited_beam.yaml", "-q", "-o", out, "--set", "solver.method=modal",
                "--set", "solver.modes=3", "--set", "solver.static_correction=false")
    verdict = ctx.refused(r, "solver.static_correction", "base_excited_beam.yaml")
    return wrong(f"refused, yet {out} was written") if verdict.kind == "ok" and out.exists() else verdict


@probe("moving-supports", "2D table, modal without static correction, a base that holds still ('0'): runs")
def _truncated_still(ctx):
    data = _table(2, "modal", "0")
    data["solver"]["static_correction"] = False
    h, bad = _solved(ctx, data)
    if bad:
        return bad
    return ok() if np.all(h["top.uy"] == 0.0) else wrong(f"the still table moved: {abs(h['top.uy']).max():.3g}")


for _dim in (1, 2):
    def _on_driven(ctx, dim=_dim):
        data = _rod(dim, "left", "moreau_jean", gap=0.1, t_end=0.1)
        data["contacts"] = [{"name": "stop", "type": "obstacle", "nodes": "left", "normal": [-1.0] + [0.0] * (dim - 1),
                             "gap": 0.1}]
        return _refused(ctx, data, "contacts[0].nodes", "prescribes")
    probe("moving-supports", f"{_dim}D contact on the driven end, along the driven component: refused")(_on_driven)


@probe("moving-supports", "2D contact on the driven end, along the driven component, right end driven: refused")
def _on_driven_right(ctx):
    data = _rod(2, "right", "moreau_jean", gap=0.1, t_end=0.1)
    data["contacts"] = [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [1.0, 0.0], "gap": 0.1}]
    return _refused(ctx, data, "contacts[0].nodes", "prescribes")


def _held_and_driven(dim: int, still_group: str):
    def body(ctx):
        data = _rod(dim, "left", "moreau_jean", gap=0.0, t_end=0.1)
        data["supports"] = [{"nodes": still_group, "fix": list("xyz"[:dim])}, data["supports"][0]]
        return _refused(ctx, data, "supports[1].displacement", still_group)
    return body


probe("moving-supports", "2D corner held still by 'bottom' and driven by 'left': refused")(_held_and_driven(2, "bottom"))
probe("moving-supports", "3D edge held still by 'back' and driven by 'left': refused")(_held_and_driven(3, "back"))


@probe("moving-supports", "2D axisymmetric: the axis driven radially: refused")
def _axis_driven(ctx):
    data = _table(2, "moreau_jean", "A")
    data["mesh"]["hypothesis"] = "axisymmetric"
    data["material"].pop("area")
    data["supports"] = [{"nodes": "left", "fix": ["x"], "displacement": ["A*t"]}]
    return _refused(ctx, data, "supports[0].displacement", "axis")


@probe("moving-supports", "2D corner held still by 'bottom' in x, 'left' driving y only: runs, exact")
def _agreeing(ctx):
    data = _table(2, "moreau_jean", "A")
    data["supports"] = [{"nodes": "bottom", "fix": ["x"]},
                        {"nodes": "left", "fix": ["y", "x"], "displacement": ["0.5*t", "0"]}]
    data["solver"].update(t_end=0.2)
    data["output"]["probes"] = {"corner": [0.0, 0.0]}
    h, bad = _solved(ctx, data)
    if bad:
        return bad
    problems = []
    _close("corner's uy", h["corner.uy"][-1], 0.5 * h["t"][-1], 1e-12, problems)
    _close("corner's ux", h["corner.ux"][-1], 0.0, 0.0, problems)
    return _judged(problems)


@probe("moving-supports", "2D table, a side stop along x on nodes whose x the base holds at '0': runs, open at rest")
def _side_stop(ctx):
    data = _table(2, "moreau_jean", "A")
    data["contacts"] = [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [1.0, 0.0], "gap": 1e-4,
                         "coupling": "mean"}]
    h, bad = _solved(ctx, data)
    if bad:
        return bad
    problems = []
    _close("top's displacement at rest", h["top.uy"][-1], A, 1e-6, problems)
    _close("stop's gap at rest", h["stop.gap"][-1], 1e-4, 1e-6, problems)
    return _judged(problems)


@probe("moving-supports", "2D table, a side stop along y on nodes the base drives in y: refused")
def _side_stop_driven(ctx):
    data = _table(2, "moreau_jean", "A")
    data["contacts"] = [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [0.0, 1.0], "gap": 1e-4,
                         "coupling": "mean"}]
    return _refused(ctx, data, "contacts[0].nodes", "prescribes")


@probe("moving-supports", "two supports moving one dof: refused")
def _two_motions(ctx):
    data = _rod(2, "left", "moreau_jean", gap=0.0, t_end=0.1)
    data["supports"].append({"nodes": "left_bottom", "fix": ["x"], "displacement": ["2*v*t"]})
    return _refused(ctx, data, "supports", "same dof")


@probe("moving-supports", "a motion in x (not t alone): refused")
def _not_in_t(ctx):
    data = _rod(1, "left", "moreau_jean", gap=0.0, t_end=0.1)
    data["supports"][0]["displacement"] = ["x*t"]
    return _refused(ctx, data, "supports[0].displacement")


@probe("moving-supports", "a motion that blows up: one line, status 3")
def _blows_up(ctx):
    data = _rod(1, "right", "newmark", gap=0.0, t_end=0.1)
    data["supports"][0]["displacement"] = ["1/(0.05 - t)"]
    r, _ = _run(ctx, data)
    return ctx.refused(r, "no longer finite", "1/(0.05 - t)", status=3)


@probe("moving-supports", "fix: all in 2D with one expression: refused")
def _all_short(ctx):
    data = _table(2, "moreau_jean", "A")
    data["supports"] = [{"nodes": "bottom", "fix": "all", "displacement": ["A"]}]
    return _refused(ctx, data, "supports[0].displacement")

