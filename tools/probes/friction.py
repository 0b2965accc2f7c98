"""Class ``friction``: friction and the energy watch through the command line, judged by physics.

Every run must end without a traceback; one that runs must keep the guarantees of the default method
(E <= E0 + W_ext within the round-off the run reports, every loss >= 0, the friction loss never
decreasing, the balance closed), and where an exact answer exists, give it: a half or quarter model on
symmetry planes moves as the full model, a block launched at v0 slides v0^2 / (2 mu g) and stops.
A method that cannot take friction refuses it in one line (status 2) naming the key to change.

Variants: supports that hold a tangent (symmetry planes in 2D and 3D, an axisymmetric axis, obstacles
and pairs, an oblique floor); a steel block with mu 0.5 over many steps dt (W from the solves,
symmetric to their round-off only); a steel disk on a ``point:`` floor; mu 0 and > 0; every method;
the false energy alarm of a stiff block moving far (resting and launched, flying, several dt and
theta); blow-ups and overflows named by what is true of the method.
"""

from __future__ import annotations

import json

import numpy as np
import yaml

from . import CASES, Verdict, ok, probe, wrong

G = 9.81
BLOCK = CASES / "sliding_block.yaml"


# -- running and reading ---------------------------------------------------------------------
def _write(ctx, data: dict, name: str = "case.yaml"):
    path = ctx.folder / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _history(out) -> dict:
    with open(out / "history.csv") as f:
        names = f.readline().strip().split(",")
    data = np.loadtxt(out / "history.csv", delimiter=",", skiprows=1, ndmin=2)
    return {n: data[:, i] for i, n in enumerate(names)}


def _run(ctx, case, *sets, name="out"):
    """``fem-impact run CASE --set ...`` into a folder of the probe: (history, summary, stderr) or a Verdict."""
    out = ctx.folder / name
    args = [a for s in sets for a in ("--set", s)]
    r = ctx.run("run", case, "-q", "-o", out, *args)
    bad = ctx.succeeded(r)
    if bad is not None:
        return bad
    return _history(out), json.loads((out / "summary.json").read_text()), r.stderr


def _guarantees(h: dict, s: dict, stderr: str = "", balance: float = 1e-8) -> Verdict | None:
    """The default method's guarantees on a run: None when they hold, else a ``wrong`` verdict."""
    E = h["kinetic"] + h["strain"]
    scale = max(E[0] + h["external_work"].max(), E[0], 1e-300)
    floor = s.get("energy_roundoff", 0.0)
    excess = (E - E[0] - h["external_work"]).max()
    if excess > floor + 1e-9 * scale:
        return wrong(f"E exceeded E0 + W_ext by {excess:.3g} J ({excess / scale:.2g} of the scale; round-off "
                     f"{floor:.3g})")
    losses = {"contact + impact": h["contact_loss"] + h["impact_loss"], "damping": h["damping_loss"]}
    if "friction_loss" in h:
        losses["friction"] = h["friction_loss"]
        step = np.diff(h["friction_loss"]).min(initial=0.0)
        if step < -1e-9 * max(scale, h["friction_loss"].max()):
            return wrong(f"the friction loss decreased by {-step:.3g} in a step")
    for what, loss in losses.items():
        if loss.min() < -1e-9 * scale:
            return wrong(f"the {what} loss went below zero: {loss.min():.3g}")
    if np.abs(h["energy_error"]).max() > floor + balance * scale:
        return wrong(f"the balance residual {np.abs(h['energy_error']).max():.3g} is above round-off "
                     f"({floor:.3g} + {balance:g} of {scale:.3g})")
    if s.get("energy_created_at") is not None or "created energy" in stderr:
        return wrong(f"energy created reported: {stderr.strip()[-300:]}")
    return None


def _checked(result, *extra) -> Verdict:
    """ok when ``result`` ran and keeps the guarantees and each of ``extra`` (callables of (h, s) that
    return None or a verdict)."""
    if isinstance(result, Verdict):
        return result
    h, s, stderr = result
    for judge in (lambda h, s: _guarantees(h, s, stderr), *extra):
        verdict = judge(h, s)
        if verdict is not None:
            return verdict
    return ok(f"E0 {h['kinetic'][0] + h['strain'][0]:.4g}, residual {s['max_energy_error_relative']:.2g}")


def _built(function, *args):
    """``function(*args)`` (a mesh of Gmsh's) in a process of its own: importing gmsh sets a signal
    handler, which only the main thread may (the probes run in threads)."""
    import subprocess
    import sys

    from . import ROOT

    code = f"from tools.probes.friction import {function.__name__} as f; f(*{[str(a) if hasattr(a, 'parts') else a for a in args]!r})"
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    if done.returncode:
        raise RuntimeError(f"{function.__name__} failed: {done.stderr.strip()[-300:]}")


# -- supports that hold a tangent ------------------------------------------------------------
def _dropped(dim, length, cells, supports, width=None, mu=0.05, t_end=0.04, hypothesis=None):
    """A block (E 1e7, rho 1000, nu 0.3, quadrilaterals/hexahedra: symmetric about its middle) at the floor
    falling at 0.5 m/s under gravity with friction mu (its bottom spreads on impact; friction resists)."""
    pad = [0.0] * (dim - 2)
    mesh = {"shape": "bar", "dim": dim, "length": length, "height": 0.05, "cells": cells, "elements": "hex"}
    if dim == 3:
        mesh["width"] = width
    points = {"a": [0.0, 0.0], "b": [0.05, 0.0], "c": [0.1, 0.0], "d": [0.0, 0.05], "e": [0.05, 0.025]}
    return {"name": "dropped", "mesh": mesh,
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.3, **({"area": 1.0} if dim == 2 else {})},
            "initial": {"velocity": [0.0, -0.5] + pad}, "loads": [{"body": "all", "acceleration": [0.0, -G] + pad}],
            "supports": supports,
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0] + pad,
                          "gap": 0.0, "friction": mu, "restitution": 0.0}],
            "solver": {"dt": 1e-3, "t_end": t_end},
            "output": {"vtk": False, "probes": {k: v + pad for k, v in points.items()}}}


def _same_as_full(full_data, part_data, parts):
    def body(ctx):
        full = _run(ctx, _write(ctx, full_data, "full.yaml"), name="full")
        part = _run(ctx, _write(ctx, part_data, "part.yaml"), name="part")
        for result in (full, part):
            if isinstance(result, Verdict):
                return result
        (hf, sf, ef), (hp, sp, ep) = full, part
        for h, s, e in ((hf, sf, ef), (hp, sp, ep)):
            bad = _guarantees(h, s, e)
            if bad is not None:
                return bad
        probed = [k for k in hf if k[:2] in ("a.", "b.", "c.", "d.", "e.")]
        for k in probed:
            kind = max(np.abs(hf[j]).max() for j in probed if j[2] == k[2])
            if np.abs(hf[k] - hp[k]).max() > 1e-8 * kind:
                return wrong(f"{k}: the part model differs from the full one by {np.abs(hf[k] - hp[k]).max():.3g} "
                             f"(of {kind:.3g})")
        scale = hf["kinetic"][0] + hf["external_work"].max()
        for k in ("friction_loss", "kinetic", "strain"):
            if abs(hf[k][-1] - parts * hp[k][-1]) > 1e-8 * scale:
                return wrong(f"{k}: full {hf[k][-1]:.10g}, {parts} x part {parts * hp[k][-1]:.10g}")
        if hf["floor.tangential_force"].max() <= 0.0:
            return Verdict("error", "no friction force on the probe's block: no test of friction")
        return ok(f"friction loss {hf['friction_loss'][-1]:.4g} = {parts} x part's")
    return body


probe("friction", "half model on a symmetry plane (2D) = full model")(
    _same_as_full(_dropped(2, 0.2, 8, []), _dropped(2, 0.1, 4, [{"nodes": "right", "fix": ["x"]}]), 2))
probe("friction", "half model on a symmetry plane, mu 0.3 (mostly stick) = full model")(
    _same_as_full(_dropped(2, 0.2, 8, [], mu=0.3), _dropped(2, 0.1, 4, [{"nodes": "right", "fix": ["x"]}], mu=0.3), 2))
probe("friction", "half model (3D, plane x) = full model")(
    _same_as_full(_dropped(3, 0.2, 4, [], width=0.1, t_end=0.02),
                  _dropped(3, 0.1, 2, [{"nodes": "right", "fix": ["x"]}], width=0.1, t_end=0.02), 2))
probe("friction", "quarter model (3D, planes x and z; a corner row without tangents) = full model")(
    _same_as_full(_dropped(3, 0.2, 4, [], width=0.2, t_end=0.02),
                  _dropped(3, 0.1, 2, [{"nodes": "right", "fix": ["x"]}, {"nodes": "front", "fix": ["z"]}],
                           width=0.1, t_end=0.02), 4))


@probe("friction", "the issue's reproduction: sliding_block at rest, left_bottom holding x")
def _issue(ctx):
    def at_rest(h, s):   # (it settles under gravity: no slide)
        if np.abs(h["front.ux"]).max() > 1e-5:
            return wrong(f"a block at rest on a floor slid: its front by {np.abs(h['front.ux']).max():.3g} m")
        return None
    return _checked(_run(ctx, BLOCK, "solver.t_end=0.02", "initial.velocity=[0,0]",
                         "supports=[{nodes: left_bottom, fix: [x]}]"), at_rest)


@probe("friction", "sliding_block launched at 2 m/s with a corner held in x (pinned: it cannot slide)")
def _pinned(ctx):
    return _checked(_run(ctx, BLOCK, "solver.t_end=0.1", "supports=[{nodes: left_bottom, fix: [x]}]"))


@probe("friction", "sliding_block with the whole left side held in x")
def _left(ctx):
    return _checked(_run(ctx, BLOCK, "solver.t_end=0.1", "supports=[{nodes: left, fix: [x]}]"))


@probe("friction", "3D half block sliding along z on its symmetry plane x: slides v0^2 / (2 mu g)")
def _half_slide(ctx):
    mu, v0 = 0.3, 1.0
    data = {"name": "half", "mesh": {"shape": "bar", "dim": 3, "length": 0.1, "height": 0.05, "width": 0.2,
                                     "cells": 2, "elements": "hex"},
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.3}, "initial": {"velocity": [0.0, 0.0, v0]},
            "loads": [{"body": "all", "acceleration": [0.0, -G, 0.0]}],
            "supports": [{"nodes": "right", "fix": ["x"]}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0, 0.0],
                          "gap": 0.0, "friction": mu}],
            "solver": {"dt": 2e-3, "t_end": 1.3 * v0 / (mu * G)}, "output": {"vtk": False}}
    return _checked(_run(ctx, _write(ctx, data)), _slides("bar.pz", v0, mu))


def _slides(column, v0, mu, rel=0.01):
    """The body's travel along ``column``'s axis is v0^2 / (2 mu g) and it stays there."""
    def judge(h, s):
        v = h[column] / s["body_mass"]["bar"]
        t = h["t"]
        travel = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
        exact = v0 ** 2 / (2 * mu * G)
        if abs(travel[-1] - exact) > rel * exact:
            return wrong(f"slid {travel[-1]:.5g} m, Coulomb says {exact:.5g} m")
        after = t > 1.1 * v0 / (mu * G)   # (stopped: its elastic ringing in stick moves it by far less)
        if not after.any() or np.ptp(travel[after]) > 0.01 * exact:
            return wrong(f"not at rest after the stop at {v0 / (mu * G):.3g} s: moved on by "
                         f"{np.ptp(travel[after]) if after.any() else np.nan:.3g} m")
        return None
    return judge


@probe("friction", "axisymmetric rod end-on onto a wall (the axis node's radial tangent held)")
def _axisymmetric(ctx):
    data = {"name": "axi", "mesh": {"shape": "bar", "dim": 2, "length": 0.2, "height": 0.02, "cells": 20,
                                    "hypothesis": "axisymmetric", "axis": "x"},
            "material": {"E": 2.1e11, "rho": 7800.0, "nu": 0.3}, "initial": {"velocity": [-1.0, 0.0]},
            "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0, 0.0], "gap": 0.0,
                          "friction": 0.3}],
            "solver": {"dt": 2e-6, "t_end": 2e-4}, "output": {"vtk": False}}
    return _checked(_run(ctx, _write(ctx, data)))


def _stack_mesh(path, length, cells):
    """Two bodies 0.05 high stacked, meshed apart (quadrilaterals, matching nodes on the interface):
    bodies lower and upper, node groups lower_bottom, lower_top, upper_bottom, right (x = length)."""
    import gmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("stack")
        geo = gmsh.model.geo
        groups = {"right": []}
        for body, y0 in (("lower", 0.0), ("upper", 0.05)):
            p = [geo.addPoint(x, y, 0) for x, y in ((0, y0), (length, y0), (length, y0 + 0.05), (0, y0 + 0.05))]
            lines = [geo.addLine(p[i], p[(i + 1) % 4]) for i in range(4)]
            surface = geo.addPlaneSurface([geo.addCurveLoop(lines)])
            for line, n in zip(lines, (cells, 2, cells, 2)):
                geo.mesh.setTransfiniteCurve(line, n + 1)
            geo.mesh.setTransfiniteSurface(surface)
            geo.mesh.setRecombine(2, surface)
            groups[body] = (2, [surface])
            groups[f"{body}_bottom"], groups[f"{body}_top"] = (1, [lines[0]]), (1, [lines[2]])
            groups["right"].append(lines[1])
        groups["right"] = (1, groups["right"])
        geo.synchronize()
        for name, (dim, tags) in groups.items():
            gmsh.model.setPhysicalName(dim, gmsh.model.addPhysicalGroup(dim, tags), name)
        gmsh.model.mesh.generate(2)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def _stack(mesh, velocity, supports=(), t_end=0.05):
    """The upper body on the lower one (pair contact, mu 0.3), the lower one's bottom held, under gravity."""
    return {"name": "stack", "mesh": {"file": str(mesh)},
            # (two stiffnesses: on impact the upper body's bottom spreads more than the lower one's top)
            "materials": {"lower": {"E": 1e8, "rho": 1000.0, "nu": 0.3, "area": 1.0},
                          "upper": {"E": 1e7, "rho": 1000.0, "nu": 0.3, "area": 1.0}},
            "initial": {"velocity": [{"body": "upper", "value": list(velocity)}]},
            "loads": [{"body": "all", "acceleration": [0.0, -G]}],
            "supports": [{"nodes": "lower_bottom", "fix": ["x", "y"]}, *supports],
            "contacts": [{"name": "joint", "type": "pair", "nodes": ["upper_bottom", "lower_top"],
                          "normal": [0.0, -1.0], "friction": 0.3}],
            "solver": {"dt": 1e-3, "t_end": t_end},
            "output": {"vtk": False, "probes": {"a": [0.0, 0.05], "b": [0.05, 0.1], "c": [0.1, 0.075]}}}


@probe("friction", "pair contact with friction: a body sliding on another whose bottom is held")
def _pair(ctx):
    mesh = ctx.shared("stack8", lambda folder: _built(_stack_mesh, folder / "stack.msh", 0.2, 8)) / "stack.msh"
    return _checked(_run(ctx, _write(ctx, _stack(mesh, (0.5, -0.1)))))


@probe("friction", "pair contact with friction, half model on a symmetry plane through both bodies = full model")
def _pair_symmetry(ctx):
    full = ctx.shared("stack8", lambda folder: _built(_stack_mesh, folder / "stack.msh", 0.2, 8)) / "stack.msh"
    half = ctx.shared("stack4", lambda folder: _built(_stack_mesh, folder / "stack.msh", 0.1, 4)) / "stack.msh"
    results = [_run(ctx, _write(ctx, data, f"{name}.yaml"), name=name) for name, data in
               (("full", _stack(full, (0.0, -0.5))),
                ("half", _stack(half, (0.0, -0.5), [{"nodes": "right", "fix": ["x"]}])))]
    for result in results:
        if isinstance(result, Verdict):
            return result
        bad = _guarantees(*result)
        if bad is not None:
            return bad
    (hf, _, _), (hh, _, _) = results
    probed = [k for k in hf if k[:2] in ("a.", "b.", "c.")]
    for k in probed:
        kind = max(np.abs(hf[j]).max() for j in probed if j[2] == k[2])
        if np.abs(hf[k] - hh[k]).max() > 1e-8 * kind:
            return wrong(f"{k}: the half model differs from the full one by {np.abs(hf[k] - hh[k]).max():.3g}")
    scale = hf["kinetic"][0] + hf["external_work"].max()
    for k in ("friction_loss", "kinetic", "strain"):
        if abs(hf[k][-1] - 2 * hh[k][-1]) > 1e-8 * scale:
            return wrong(f"{k}: full {hf[k][-1]:.10g}, 2 x half {2 * hh[k][-1]:.10g}")
    # (the full model's friction forces cancel by symmetry; the half's are those of one side)
    if hh["joint.tangential_force"].max() <= 1e-3 * hh["joint.force"].max():
        return Verdict("error", "no friction force in the joint: no test of friction")
    return ok(f"friction force up to {hh['joint.tangential_force'].max():.4g} N on a half, friction loss "
              f"{hf['friction_loss'][-1]:.3g} = 2 x the half's")


@probe("friction", "an oblique floor (normal in the y-z plane) under a symmetry plane x (3D)")
def _oblique(ctx):
    s = float(1.0 / np.sqrt(2.0))
    data = {"name": "oblique", "mesh": {"shape": "bar", "dim": 3, "length": 0.1, "height": 0.05, "width": 0.1,
                                        "cells": 2, "elements": "hex"},
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.3}, "initial": {"velocity": [0.0, -0.3, 0.3]},
            "supports": [{"nodes": "right", "fix": ["x"]}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -s, s],
                          "gap": 0.001, "friction": 0.3}],
            "solver": {"dt": 1e-3, "t_end": 0.03}, "output": {"vtk": False}}
    return _checked(_run(ctx, _write(ctx, data)))


@probe("friction", "a contact on nodes whose normal a support holds: refused in one line")
def _normal_held(ctx):
    r = ctx.run("run", BLOCK, "-q", "-o", ctx.folder / "out", "--set", "supports=[{nodes: bottom, fix: [y]}]")
    return ctx.refused(r, "contacts", "normal direction is fixed by a support")


# -- a steel block, mu 0.5, many steps dt ------------------------------------------------------
STEEL = ("material.E=2.1e11", "material.rho=7850.0", "material.nu=0.3", "contacts.0.friction=0.5",
         "parameters.v0=0.2")


def _steel(dt, t_end=0.05, extra=()):
    def body(ctx):
        v0, mu = 0.2, 0.5
        return _checked(_run(ctx, BLOCK, *STEEL, f"solver.dt={dt}", f"solver.t_end={t_end}", "output.every=1",
                             *extra), _slides("bar.px", v0, mu, rel=0.02))
    return body


for _dt in ("2e-5", "2.5e-5", "3e-5", "4e-5", "5e-5", "6e-5", "8e-5", "1e-4", "2e-4", "5e-4", "1e-3", "2e-3"):
    probe("friction", f"steel block, mu 0.5, launched at 0.2 m/s, dt {_dt}: slides v0^2 / (2 mu g)")(_steel(_dt))
probe("friction", "steel block, mu 0.5, dt 5e-5, 24 cells along")(_steel("5e-5", extra=("mesh.cells=24",)))
probe("friction", "steel block, mu 0.5, dt 3e-5, 3D (4 cells)")(
    _steel("3e-5", extra=("mesh.dim=3", "mesh.width=0.05", "mesh.cells=4", "loads.0.acceleration=[0,-g,0]",
                          "contacts.0.normal=[0,-1,0]", "initial.velocity=[v0,0,0]", "output.probes={}")))


# -- a steel disk on a point floor ---------------------------------------------------------------
def _disk_mesh(path, R, rim):
    import gmsh

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("disk")
        surface = gmsh.model.occ.addDisk(0, R, 0, R, R)
        gmsh.model.occ.synchronize()
        gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, [surface]), "disk")
        curves = [t for _, t in gmsh.model.getBoundary([(2, surface)], oriented=False)]
        gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, curves), "rim")
        for c in curves:
            gmsh.model.mesh.setTransfiniteCurve(c, rim + 1)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 4 * 2 * np.pi * R / rim)
        gmsh.model.mesh.generate(2)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()


def _disk(rim, dt, steps, mu=0.2):
    def body(ctx):
        mesh = ctx.shared(f"disk{rim}", lambda folder: _built(_disk_mesh, folder / "disk.msh", 0.1, rim)) / "disk.msh"
        data = {"name": "disk", "mesh": {"file": str(mesh)},
                "material": {"E": 2.1e11, "rho": 7850.0, "nu": 0.3, "area": 1.0},
                "initial": {"velocity": [0.5, 0.0]}, "loads": [{"body": "all", "acceleration": [0.0, -G]}],
                "contacts": [{"name": "floor", "type": "obstacle", "nodes": "rim", "normal": [0.0, -1.0],
                              "point": [0.0, 0.0], "friction": mu}],
                "solver": {"dt": dt, "t_end": steps * dt}, "output": {"vtk": False}}
        return _checked(_run(ctx, _write(ctx, data)))
    return body


for _rim, _dt in ((400, 2e-4), (400, 1e-3), (400, 5e-5), (200, 2e-4)):
    probe("friction", f"steel disk R 0.1, {_rim} rim nodes, point floor, mu 0.2, dt {_dt:g}")(_disk(_rim, _dt, 20))


# -- mu 0 and > 0 ----------------------------------------------------------------------------------
@probe("friction", "sliding_block with friction 0: slides on at v0, no friction loss")
def _mu0(ctx):
    def free(h, s):
        v = h["bar.px"] / s["body_mass"]["bar"]
        if np.abs(v - 2.0).max() > 1e-6:
            return wrong(f"without friction the block's speed changed by {np.abs(v - 2.0).max():.3g}")
        return None
    return _checked(_run(ctx, BLOCK, "contacts.0.friction=0", "solver.t_end=0.2"), free)


for _mu in (1e-6, 0.05, 0.3, 1.0, 5.0):
    probe("friction", f"sliding_block with friction {_mu:g}")(
        lambda ctx, mu=_mu: _checked(_run(ctx, BLOCK, f"contacts.0.friction={mu}", "solver.t_end=0.3")))
probe("friction", "sliding_block, mu 0.3: slides v0^2 / (2 mu g) and stops (the case's own check)")(
    lambda ctx: _checked(_run(ctx, BLOCK), _slides("bar.px", 2.0, 0.3)))


# -- the small 2D problem's statuses switching (the compiled active-set method, then damped Newton) ----------
def _dragged(ratio, mu=0.3, reverse=None):
    """sliding_block from rest, dragged along x by ``ratio`` mu g (with ``reverse``: times cos(pi t / (2
    reverse)), turning round at that time). Set down at rest without its weight's strain, the block rings on
    its floor, and its rows stick and slip in turn (a deformable block: some stick while others slide), so no
    closed-form travel: judged by Coulomb's law on the floor's totals at every output, ``|F_x| <= mu S_N / dt``,
    the guarantees, and the drag's direction (above mu g the block goes with it; reversed, it comes back)."""
    def body(ctx):
        drag = f"{ratio * mu * G!r}" + ("" if reverse is None else f" * cos(pi * t / {2.0 * reverse!r})")
        case = yaml.safe_load(BLOCK.read_text())
        case["initial"]["velocity"] = [0.0, 0.0]
        case["loads"].append({"body": "all", "acceleration": [drag, 0.0]})
        case["contacts"][0]["friction"] = mu
        case["solver"]["t_end"] = 0.3 if reverse is None else 3.0 * reverse   # (the drag most negative at 2 reverse)
        result = _run(ctx, _write(ctx, case))

        def judge(h, s):
            # (the friction columns are the step's whole tangential impulse over dt: the cone is that of the
            # whole normal impulse, S_N / dt, which at the position level differs from the force column)
            normal = h["floor.impulse"] / case["solver"]["dt"]
            excess = np.abs(h["floor.tx"]) - mu * normal
            if excess.max() > 1e-9 * max(mu * np.abs(normal).max(), 1e-300):
                return wrong(f"|F_x| exceeds mu S_N / dt on the floor by {excess.max():.3g} N")
            v, t = h["bar.px"] / s["body_mass"]["bar"], h["t"]
            if reverse is None and ratio > 1.0 and not v[-1] > 0.0:
                return wrong(f"dragged at {ratio} mu g it ends at {v[-1]:.3g} m/s")
            if reverse is not None and not (v[t <= reverse].max() > 0.0 > v[t > reverse].min()):
                return wrong(f"the drag turned round at {reverse} s, the block did not follow: v at most "
                             f"{v[t <= reverse].max():.3g}, then at least {v[t > reverse].min():.3g} m/s")
            return None
        return _checked(result, judge)
    return body


for _ratio in (0.5, 0.999, 1.001, 2.0):
    probe("friction", f"sliding_block from rest dragged at {_ratio:g} mu g: Coulomb's law on the floor's totals")(
        _dragged(_ratio))
probe("friction", "sliding_block dragged at 2 mu g turning round at 0.15 s: the block comes back")(
    _dragged(2.0, reverse=0.15))
probe("friction", "sliding_block dragged at 1.5 mu g with mu 5: Coulomb's law on the floor's totals")(
    _dragged(1.5, mu=5.0))


# -- every method -------------------------------------------------------------------------------
REFUSED = [
    (("solver.method=newmark",), ("contacts[0].friction", "solver.method newmark", "use solver.method: moreau_jean")),
    (("solver.method=central_difference",), ("contacts[0].friction", "solver.method central_difference",
                                             "use solver.method: moreau_jean")),
    (("solver.method=modal", "solver.modes=20", "solver.static_correction=false", "solver.scheme=newmark"),
     ("contacts[0].friction", "solver.scheme newmark", "use solver.scheme: moreau_jean")),
]
for _sets, _needles in REFUSED:
    probe("friction", f"friction refused with {' '.join(_sets)}")(
        lambda ctx, sets=_sets, needles=_needles: ctx.refused(
            ctx.run("run", BLOCK, "-q", "-o", ctx.folder / "out", *[a for s in sets for a in ("--set", s)]),
            *needles))

RUNS = [
    ("moreau_jean (default)", ()),
    ("moreau_jean, level velocity", ("solver.level=velocity",)),
    ("moreau_jean, theta 1", ("solver.theta=1",)),
    ("moreau_jean, theta 0.7, level velocity", ("solver.theta=0.7", "solver.level=velocity")),
    ("modal, 30 modes, no static correction", ("solver.method=modal", "solver.modes=30",
                                               "solver.static_correction=false")),
    ("modal, theta 1", ("solver.method=modal", "solver.modes=30", "solver.static_correction=false",
                        "solver.theta=1")),
    ("modal, 20 modes and the static correction (friction through it)", ("solver.method=modal", "solver.modes=20")),
    ("modal, 4 modes and the static correction", ("solver.method=modal", "solver.modes=4")),
]
for _what, _sets in RUNS:
    probe("friction", f"sliding_block with {_what}: slides v0^2 / (2 mu g)")(
        lambda ctx, sets=_sets: _checked(_run(ctx, BLOCK, *sets), _slides("bar.px", 2.0, 0.3, rel=0.02)))


@probe("friction", "theta 1: the report names the numerical dissipation, the balance closes")
def _theta_report(ctx):
    out = ctx.folder / "out"
    r = ctx.run("run", BLOCK, "-o", out, "--set", "solver.theta=1", "--set", "solver.t_end=0.2")
    bad = ctx.succeeded(r)
    if bad is not None:
        return bad
    if "numerical dissipation" not in r.stdout + r.stderr:
        return wrong(f"the report does not name the numerical dissipation: {r.tail(2)}")
    s = json.loads((out / "summary.json").read_text())
    return _checked((_history(out), s, r.stderr),
                    lambda h, s: None if h["numerical_loss"][-1] > 0.0 else wrong("no numerical dissipation booked"))


# -- the false energy alarm -------------------------------------------------------------------
def _resting(velocity=(0.5, 0.0), dt=1e-4, t_end=0.3, contacts=True, dim=2, **solver):
    pad = [0.0] * (dim - 2)
    mesh = {"shape": "bar", "dim": dim, "length": 0.1, "height": 0.05, "cells": 10}
    if dim == 3:
        mesh.update(width=0.05, cells=4)
    return {"name": "resting", "mesh": mesh,
            "material": {"E": 2.1e11, "rho": 7800.0, "nu": 0.3, **({"area": 0.02} if dim == 2 else {})},
            "initial": {"velocity": list(velocity) + pad}, "loads": [{"body": "all", "acceleration": [0.0, -G] + pad}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0] + pad,
                          "gap": 0.0}] if contacts else [],
            "solver": dict(solver, dt=dt, t_end=t_end), "output": {"vtk": False}}


ALARMS = [
    ("the issue's block: resting at gap 0, launched at 0.5 m/s along the floor", {}),
    ("... for 1 s (0.5 m of travel)", {"t_end": 1.0}),
    ("... dt 1e-5", {"dt": 1e-5, "t_end": 0.1}),
    ("... dt 1e-3", {"dt": 1e-3, "t_end": 1.0}),
    ("... launched up and along (it hops)", {"velocity": (0.5, 0.5)}),
    ("... launched down onto the floor", {"velocity": (0.5, -0.5)}),
    ("... flying, no floor at all", {"contacts": False}),
    ("... level velocity", {"level": "velocity"}),
    ("... theta 0.6", {"theta": 0.6}),
    ("... theta 1", {"theta": 1.0}),
    ("... 3D", {"dim": 3}),
    ("... the reduced model (20 modes)", {"method": "modal", "modes": 20}),
]
for _what, _kw in ALARMS:
    probe("friction", f"no false energy alarm: {_what}")(
        lambda ctx, kw=_kw: _checked(_run(ctx, _write(ctx, _resting(**kw)))))


@probe("friction", "real energy creation is still reported (Newmark, the paper's scheme, beam_stop at Courant 12)")
def _real_alarm(ctx):
    r = ctx.run("run", CASES / "beam_stop.yaml", "-q", "-o", ctx.folder / "out", "--set", "solver.method=newmark",
                "--set", "contacts.0.stiffness=null", "--set", "contacts.0.coupling=each", "--set", "solver.dt=2e-3",
                "--set", "solver.t_end=2")
    bad = ctx.succeeded(r)
    if bad is not None:
        return bad
    return ok("reported") if "created energy" in r.stderr else wrong("Newmark's created energy went unreported")


# -- blow-ups and overflows, named by what is true of the method --------------------------------
def _fails(sets, needles, never=(), case=BLOCK):
    def body(ctx):
        r = ctx.run("run", case, "-q", "-o", ctx.folder / "out", *[a for s in sets for a in ("--set", s)])
        verdict = ctx.refused(r, *needles, status=3)
        if verdict.kind == "ok" and any(n in r.stderr for n in never):
            return wrong(f"says {[n for n in never if n in r.stderr]}: {r.tail(1)}")
        return verdict
    return body


FAILS = [
    ("initial velocity 1e200", ("initial.velocity=[1e200,0]",), ("initial state is not finite",), ("explicit",)),
    ("a load that grows as exp(2000 t), moreau_jean", ("loads=[{body: all, acceleration: [0, 'exp(2000*t)']}]",
                                                      "solver.t_end=0.5"), ("dt is not the cause",), ("explicit",)),
    ("a load of 1e300, newmark (friction 0)", ("contacts.0.friction=0", "solver.method=newmark",
                                              "loads=[{body: all, acceleration: [0, -1e300]}]"),
     ("dt is not the cause",), ("explicit",)),
    ("central difference far above its limit (friction 0)", ("contacts.0.friction=0",
                                                            "solver.method=central_difference"),
     ("explicit and dt is above its stable limit",), ("dt is not the cause",)),
]
for _what, _sets, _needles, _never in FAILS:
    probe("friction", f"a run that cannot go on says why: {_what}")(_fails(_sets, _needles, _never))


# -- the compiled small solve (nonsmooth/small_kernel.py) at its size limit --------------------
def _block_sliding(dim, cells, mu=0.3, v0=1.0):
    pad = [0.0] * (dim - 2)
    mesh = {"shape": "bar", "dim": dim, "length": 0.2, "height": 0.05, "cells": cells, "elements": "hex"}
    if dim == 3:
        mesh["width"] = 0.2
    return {"name": "slider", "mesh": mesh,
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.3, **({"area": 1.0} if dim == 2 else {})},
            "initial": {"velocity": [v0, 0.0] + pad}, "loads": [{"body": "all", "acceleration": [0.0, -G] + pad}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0] + pad,
                          "gap": 0.0, "friction": mu}],
            "solver": {"dt": 2e-3, "t_end": 1.3 * v0 / (mu * G)}, "output": {"vtk": False}}


for _dim, _cells in ((2, 28), (2, 29), (2, 30), (3, 3), (3, 4)):
    # (floor unknowns: 2D 58, 60, 62; 3D 48, 75: the compiled solve takes at most 60, the sweeps the rest)
    def _at_limit(ctx, dim=_dim, cells=_cells):
        return _checked(_run(ctx, _write(ctx, _block_sliding(dim, cells))), _slides("bar.px", 1.0, 0.3))
    probe("friction", f"{_dim}D block on {_cells} cells sliding at 1 m/s, mu 0.3 (the small solve's size limit): "
                      "slides v0^2 / (2 mu g)")(_at_limit)
