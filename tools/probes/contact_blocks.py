"""Class ``contact-blocks``: the reduced model's steps with impulses in compiled blocks (
fem_impact/integrators/kernels.py ``moreau_jean_contact_steps``, nonsmooth/lcp_kernel.py, docs/theory.md
s. 8.8 "Steps with impulses, compiled"): Moreau-Jean's contact steps on rows that are all compliant (the
static correction's, an elastic stop's spring), as a user meets them through the command line.

The scene is tests/test_contact_blocks.py's strip: a steel strip (1 x 0.1 m) clamped at its left end,
its right end section on a stop at zero gap, pressed on it by a force on the section and a body load
that varies; ten modes with the static correction (every row compliant). Variants: lifting off and
striking again, a gap, theta 0.7 with damping, theta 1, the velocity level, more rows than modes, two
contacts, a node two contacts share, an elastic stop (with and without the static correction), a 3D bar, a
1D rod, a beam lying on a floor, cases/face_on_stop.yaml.

The contract each probe judges:

- ``solver.blocks: true`` gives the history of ``false`` to 1e-10 of each column's scale (an energy term
  on the energy's, a probe's or a body's vector component on the vector's largest, a gap on the largest
  displacement; or one unit of history.csv's 12th digit), the same impacts and impacts.csv row for row,
  the same summary counts, periods.csv and fields; and the summary's ``steps_in_blocks`` shows the
  contact steps were taken in blocks;
- the physics in blocks: a held contact's gaps closed and its nodes on the stop, the balance closed,
  ``E <= E0 + W_ext``, the losses >= 0 (constant loads), a body's momentum changed by the loads' and the
  contacts' impulses;
- what the compiled step does not take (a moving obstacle, rigid rows without the static correction and
  Carnot's correction, beside an elastic stop too, friction, Newmark's scheme) is stepped one at a time:
  the single steps' history to 1e-12, no step in blocks while held;
- a restart inside the contact continues the uninterrupted run, under ``solver.blocks`` switched too; a
  changed load is refused naming the key (the static correction holds the saved loads);
- SIGINT to a long run, serial and on 2 ranks: one line, the checkpoint kept, a restart from it
  continues the uninterrupted run;
- a load that stops being finite, or energies that overflow, in the held contact: the one-line stop
  (status 3) of single steps, with the same message.
"""

from __future__ import annotations

import copy
import csv
import json
import shutil
import signal
import xml.etree.ElementTree as ET

import numpy as np
import yaml

from . import CASES, Verdict, history, ok, probe, run_case, wrong

CLS = "contact-blocks"
TOL = 1e-10      # of each column's scale: the agreement of blocks with single steps
SAME = 1e-12     # where the contact steps stay single steps (their open steps may still go in blocks)
DT = 1e-5
ENERGY = ("kinetic", "strain", "external_work", "damping_loss", "impact_loss", "contact_loss", "energy_error",
          "numerical_loss", "friction_loss", "scheme_energy")
STRIP = {
    "name": "strip",
    "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.1, "cells": 60},
    "material": {"E": 2.1e11, "rho": 7800.0, "nu": 0.3, "area": 0.01},
    "supports": [{"nodes": "left", "fix": ["x", "y"]}],
    "loads": [{"nodes": "right", "force": [0.0, -1000.0]},
              {"body": "all", "acceleration": [0.0, "-50*(1 + 0.5*sin(2*pi*300*t))"]}],
    "contacts": [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [0.0, -1.0], "gap": 0.0,
                  "restitution": 0.0}],
    "solver": {"method": "modal", "modes": 10, "static_correction": True, "dt": DT, "t_end": 1500 * DT},
    "output": {"vtk": False, "probes": {"tip": [1.0, 0.05], "middle": [0.5, 0.05]}},
}
LIFT_OFF = {"loads.1.acceleration": [0.0, "-500*sin(2*pi*40*t)"], "loads.0.force": [0.0, 0.0],
            "solver.t_end": 3000 * DT}


# -- cases ------------------------------------------------------------------------------------------
def _set(data: dict, path: str, value) -> None:
    keys = path.split(".")
    node = data
    for key in keys[:-1]:
        node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
    last = keys[-1]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value


def _strip(changes: dict | None = None, **more) -> dict:
    """The strip (module docstring) with ``changes`` (dotted keys, list indices as numbers)."""
    data = copy.deepcopy(STRIP)
    for path, value in {**(changes or {}), **more}.items():
        _set(data, path, value)
    return data


def _rod() -> dict:
    """A steel rod (1D, 100 cells) clamped at its left end, its right end on a stop at zero gap, pressed on it
    by its weight along the axis (a body load that varies): one contact row, the scalar LCP."""
    return {"name": "rod", "mesh": {"shape": "bar", "dim": 1, "length": 1.0, "cells": 100},
            "material": {"E": 2.1e11, "rho": 7800.0, "area": 1e-4},
            "supports": [{"nodes": "left", "fix": ["x"]}],
            "loads": [{"body": "all", "acceleration": ["2000*(1 + 0.5*sin(2*pi*2000*t))"]}],
            "contacts": [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [1.0], "gap": 0.0}],
            "solver": {"method": "modal", "modes": 5, "dt": 1e-6, "t_end": 2e-3},
            "output": {"vtk": False, "probes": {"mid": [0.5]}}}


def _box() -> dict:
    """A 3D steel bar (1 x 0.1 x 0.1 m, 40 cells along: 25 nodes on its end face) clamped at its left end,
    its right face on a stop, pressed as the strip."""
    return {"name": "box", "mesh": {"shape": "bar", "dim": 3, "length": 1.0, "height": 0.1, "width": 0.1,
                                    "cells": 40},
            "material": {"E": 2.1e11, "rho": 7800.0, "nu": 0.3},
            "supports": [{"nodes": "left", "fix": ["x", "y", "z"]}],
            "loads": [{"nodes": "right", "force": [0.0, 0.0, -1000.0]},
                      {"body": "all", "acceleration": [0.0, 0.0, "-50*(1 + 0.5*sin(2*pi*300*t))"]}],
            "contacts": [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [0.0, 0.0, -1.0],
                          "gap": 0.0}],
            "solver": {"method": "modal", "modes": 10, "dt": DT, "t_end": 800 * DT},
            "output": {"vtk": False, "probes": {"tip": [1.0, 0.05, 0.05]}}}


def _floor() -> dict:
    """The strip lying on a floor along its bottom (61 rows on 10 modes), held at its left end along x only:
    free to move along y (a rigid mode), pressed on the floor by its weight and a force on its end."""
    data = _strip({"supports": [{"nodes": "left", "fix": ["x"]}],
                   "loads.0.force": [0.0, "-1000*(1 + 0.5*sin(2*pi*300*t))"],
                   "loads.1.acceleration": [0.0, -9.81],
                   "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0],
                                 "gap": 0.0}]})
    data["name"] = "beam"
    return data


# -- runs -------------------------------------------------------------------------------------------
class Run:
    def __init__(self, folder):
        self.folder = folder
        self.h = history(folder)
        self.s = json.loads((folder / "summary.json").read_text())


def _sets(options: dict) -> list[str]:
    return [x for key, value in options.items() for x in ("--set", f"{key}={json.dumps(value)}")]


def _run(ctx, data, out, *options, mpi=0, **sets):
    """(Run, None) of ``data`` run into ``out`` with ``--set`` ``sets``; (None, verdict) when it failed."""
    r, folder = run_case(ctx, data, *options, *_sets(sets), mpi=mpi, out=out)
    bad = ctx.succeeded(r)
    return (None, bad) if bad else (Run(folder), None)


def _pair(ctx, data, *options, mpi=0):
    """The runs of ``data`` with solver.blocks false and true: (single, blocks, None) or (.., verdict)."""
    single, bad = _run(ctx, data, "single", *options, mpi=mpi, **{"solver.blocks": False})
    if bad:
        return None, None, bad
    fast, bad = _run(ctx, data, "blocks", *options, mpi=mpi, **{"solver.blocks": True})
    return single, fast, bad


def _scales(h: dict) -> dict:
    """Each column's scale: an energy term on the energy's, a vector's component on the vector's largest
    (the probes' and the gaps' displacements together), else its own largest value."""
    top = lambda names: max([np.abs(h[k]).max() for k in names] + [0.0])   # noqa: E731
    energy = top([k for k in ("kinetic", "strain", "external_work", "contact_loss") if k in h])
    shift = top([k for k in h if k.endswith((".ux", ".uy", ".uz", ".gap"))])
    speed = top([k for k in h if k[-3:] in (".vx", ".vy", ".vz")])
    scales = {}
    for name, column in h.items():
        own = np.abs(column).max()
        if name in ENERGY:
            own = max(own, energy)
        elif name.endswith((".ux", ".uy", ".uz", ".gap")):
            own = max(own, shift)
        elif name[-3:] in (".vx", ".vy", ".vz"):
            own = max(own, speed)
        elif name[-3:] in (".px", ".py", ".pz"):
            own = max(own, top([k for k in h if k[:-1] == name[:-1]]))
        scales[name] = max(own, 1e-300)
    return scales


def _differ(a: dict, b: dict, tol: float, skip=(), rows: slice = slice(None)) -> str | None:
    """Where history ``b`` parts from ``a`` (None: nowhere): each column to ``tol`` of its scale (the balance
    residual to 10 tol of the energy's: round-off of the static part's stored energy), or one unit of
    history.csv's 12th significant digit."""
    if list(a) != list(b):
        return f"columns differ: {sorted(set(a) ^ set(b)) or 'their order'}"
    scales = _scales(a)
    for name in a:
        x, y = a[name][rows], b[name]
        if x.size != y.size:
            return f"{y.size} rows against {x.size}"
        if name in skip:
            continue
        allowed = (10 if name == "energy_error" else 1) * tol * scales[name]
        big = np.maximum(np.abs(x), np.abs(y))
        digit = 10.0 ** (np.floor(np.log10(np.maximum(big, 1e-300))) - 11)
        bad = np.abs(x - y) > np.maximum(allowed, 1.0001 * digit)
        if bad.any():
            j = int(np.argmax(bad))
            return (f"{name} at t = {a['t'][rows][j]:.6g}: {y[j]!r} against {x[j]!r} "
                    f"({abs(x[j] - y[j]) / scales[name]:.2g} of its scale)")
    return None


def _summary_differs(a: dict, b: dict, tol: float, shift: float) -> str | None:
    """The summaries' counts equal, the total impulses to ``tol``, the largest penetration and stop
    compression to ``tol`` of ``shift`` (the displacements' scale)."""
    for key in ("steps", "impacts", "energy_created_at", "constraints", "modes"):
        if a.get(key) != b.get(key):
            return f"summary {key}: {b.get(key)!r} against {a.get(key)!r}"
    for key in ("max_penetration", "max_stop_compression"):
        if abs(a[key] - b[key]) > tol * max(shift, abs(a[key]), 1e-300):
            return f"summary {key}: {b[key]!r} against {a[key]!r}"
    for name, impulse in a["total_impulse"].items():
        if abs(b["total_impulse"][name] - impulse) > tol * max(abs(impulse), 1e-300):
            return f"total_impulse {name}: {b['total_impulse'][name]!r} against {impulse!r}"
    return None


def _impacts(folder) -> list[dict]:
    with open(folder / "impacts.csv", newline="") as f:
        return list(csv.DictReader(f))


def _impacts_differ(a_folder, b_folder, tol: float = TOL) -> str | None:
    """impacts.csv row for row: the same contacts, steps and rows; impulse, speed and t_contact to ``tol``
    of their column's largest (or history.csv's 12th digit)."""
    a, b = _impacts(a_folder), _impacts(b_folder)
    if len(a) != len(b):
        return f"impacts.csv: {len(b)} rows against {len(a)}"
    if a and list(a[0]) != list(b[0]):
        return f"impacts.csv columns {list(b[0])} against {list(a[0])}"
    for name in a[0] if a else ():
        if name in ("contact", "rows"):
            for i, (x, y) in enumerate(zip(a, b, strict=False)):
                if x[name] != y[name]:
                    return f"impacts.csv row {i + 1} {name}: {y[name]} against {x[name]}"
            continue
        x = np.array([float(row[name]) for row in a])
        y = np.array([float(row[name]) for row in b])
        scale = max(np.abs(x).max(), 1e-300)
        digit = 10.0 ** (np.floor(np.log10(np.maximum(np.maximum(np.abs(x), np.abs(y)), 1e-300))) - 11)
        bad = np.abs(x - y) > np.maximum(tol * scale, 1.0001 * digit)
        if bad.any():
            i = int(np.argmax(bad))
            return f"impacts.csv row {i + 1} {name}: {y[i]!r} against {x[i]!r}"
    return None


def _shift(h: dict) -> float:
    """The displacements' scale: the largest of the probes' components and the gaps."""
    return max([np.abs(v).max() for k, v in h.items() if k.endswith((".ux", ".uy", ".uz", ".gap"))] + [0.0])


def _same_runs(single: Run, fast: Run, tol: float = TOL, skip=()) -> str | None:
    return (_differ(single.h, fast.h, tol, skip) or _summary_differs(single.s, fast.s, tol, _shift(single.h))
            or _impacts_differ(single.folder, fast.folder, tol))


def _budget(h: dict, problems: list, losses_grow: bool = False, closes: float = 1e-9) -> None:
    """The balance closed, E <= E0 + W_ext, the losses >= 0 (each step's too with ``losses_grow``), to
    ``closes`` of the energy scale."""
    scale = max(np.abs(h[k]).max() for k in ("kinetic", "strain", "external_work"))
    if np.abs(h["energy_error"]).max() > closes * scale:
        problems.append(f"balance residual {np.abs(h['energy_error']).max():.3g} of {scale:.3g}")
    total = h["kinetic"] + h["strain"]
    excess = total - total[0] - h["external_work"]
    if excess.max() > closes * scale:
        problems.append(f"E - E0 - W_ext up to {excess.max():.3g} (energy {scale:.3g})")
    for name in ("contact_loss", "damping_loss", "impact_loss", "numerical_loss"):
        if name not in h:
            continue
        if h[name].min() < -closes * scale:
            problems.append(f"{name} down to {h[name].min():.3g}")
        if losses_grow and np.diff(h[name]).min() < -closes * scale:
            problems.append(f"{name} falls over a step by {-np.diff(h[name]).min():.3g}")


def _taken(single: Run, fast: Run, share: float = 0.99) -> str | None:
    """The blocks run took at least ``share`` of its steps in blocks; the single one none."""
    s = fast.s
    if single.s["steps_in_blocks"]:
        return f"solver.blocks false took {single.s['steps_in_blocks']} steps in blocks"
    if s["steps_in_blocks"] < share * s["steps"]:
        return f"only {s['steps_in_blocks']} of {s['steps']} steps in blocks"
    return None


def _persists(h: dict, contact: str = "stop") -> str | None:
    """The contact carries a force at every step after the first."""
    force = h[f"{contact}.force"][1:]
    if force.min() <= 0.0:
        return f"{contact} lets go at t = {h['t'][1:][int(np.argmin(force))]:.6g}"
    return None


# -- blocks true as false ----------------------------------------------------------------------------
def _same_as_single(data_of, *options, share=0.99, check=None, tol=TOL, skip=(), mpi=0):
    """Blocks true against false: the same runs (history, summary, impacts.csv); at least ``share`` of the
    steps in blocks; ``check(single, fast)`` -> a problem or None."""
    def body(ctx):
        single, fast, bad = _pair(ctx, data_of(), *options, mpi=mpi)
        if bad:
            return bad
        problem = _same_runs(single, fast, tol, skip) or (share is not None and _taken(single, fast, share)) \
            or (check(single, fast) if check else None)
        if problem:
            return wrong(problem)
        return ok(f"{fast.s['steps_in_blocks']}/{fast.s['steps']} steps in {fast.s['blocks']} blocks, "
                  f"{fast.s['constraints']} rows, {fast.s['modes']} modes")
    return body


def _held(single, fast):
    return _persists(fast.h) or (f"{fast.s['impacts']['stop']} impacts, one expected (held from the start)"
                                 if fast.s["impacts"]["stop"] != 1 else None)


def _impacts_again(single, fast):
    h = fast.h
    if fast.s["impacts"]["stop"] < 2 or not (h["stop.force"] == 0.0).any():
        return f"{fast.s['impacts']['stop']} impacts: the strip never lifted off and struck again"
    return None


def _hits_and_stays(single, fast):
    h = fast.h
    touched = np.flatnonzero(h["stop.impulse"] > 0.0)
    if fast.s["impacts"]["stop"] != 1 or not touched.size or touched[0] < 2:
        return f"{fast.s['impacts']['stop']} impacts, first impulse at row {touched[:1]}: one impact after a flight"
    if h["stop.force"][touched[0]:].min() <= 0.0:
        return "the end left the stop after it hit"
    return None


def _damped(single, fast):
    h = fast.h
    problems = []
    for name in ("damping_loss", "numerical_loss"):
        if h[name][-1] <= 0.0:
            problems.append(f"no {name}")
    if np.diff(h["damping_loss"]).min() < -1e-12 * h["damping_loss"].max():
        problems.append("damping_loss falls")
    return "; ".join(problems) or None


def _touches(single, fast):
    force = fast.h["stop.force"][1:]
    if not fast.s["impacts"]["stop"] or np.count_nonzero(force > 0.0) < 0.1 * force.size:
        return f"the stop carried a force in {np.count_nonzero(force > 0.0)} of {force.size} steps"
    return None


def _two_contacts(single, fast):
    return _persists(fast.h, "stop") or _persists(fast.h, "axial")


def _two_stops() -> dict:
    """The strip with a second stop at its end section, along x, the end pushed on it too."""
    data = _strip({"loads.0.force": [500.0, -1000.0]})
    data["contacts"].append({"name": "axial", "type": "obstacle", "nodes": "right", "normal": [1.0, 0.0],
                             "gap": 0.0})
    return data


def _pressed_stop(single, fast):
    """An elastic stop pressed for the whole run: compressed, and the balance closed with its spring."""
    h = fast.h
    problems = [p for p in (_persists(h),) if p]
    if not h["stop.gap"].min() < 0.0 or fast.s["max_stop_compression"] <= 0.0:
        problems.append("the stop was never compressed")
    _budget(h, problems)
    return "; ".join(problems) or None


def _both_modes(single, fast):
    return None if fast.s["modes"] < fast.s["constraints"] else \
        f"{fast.s['modes']} modes for {fast.s['constraints']} rows: not more rows than modes"


for _name, _data, _options, _check, _share in (
        ("strip held on its stop (7 rows, 10 modes)", lambda: _strip(), (), _held, 0.99),
        ("strip lifting off and striking again", lambda: _strip(LIFT_OFF), (), _impacts_again, 0.9),
        ("strip 2 um above its stop: the end hits, then stays",
         lambda: _strip({"contacts.0.gap": 2e-6, "solver.t_end": 1000 * DT}), (), _hits_and_stays, 0.9),
        ("strip thrown onto its stop (initial velocity)",
         lambda: _strip({"initial": {"velocity": [0.0, -0.05]}, "loads.0.force": [0.0, 0.0],
                         "contacts.0.gap": 1e-6, "solver.t_end": 1000 * DT}), (), _touches, 0.9),
        ("theta 0.7 with Rayleigh damping", lambda: _strip({"solver.theta": 0.7, "damping": {"alpha": 20.0,
                                                                                             "beta": 2e-6}}),
         (), _damped, 0.99),
        ("theta 1 (backward Euler)", lambda: _strip({"solver.theta": 1.0}), (), _held, 0.99),
        ("solver.level: velocity (compliant rows take the end of the step)",
         lambda: _strip({"solver.level": "velocity"}), (), _held, 0.99),
        ("restitution 0.5 on compliant rows", lambda: _strip({"contacts.0.restitution": 0.5}), (), _held, 0.99),
        ("coupling: mean (one row for the section)", lambda: _strip({"contacts.0.coupling": "mean"}), (), None, 0.99),
        ("solver.mass: lumped", lambda: _strip({"solver.mass": "lumped"}), (), _held, 0.99),
        ("modes: auto", lambda: _strip({"solver.modes": "auto"}), (), _held, 0.99),
        ("22 rows on 3 modes (a taller strip)", lambda: _strip({"mesh.height": 0.35, "solver.modes": 3,
                                                                 "output.probes": {"tip": [1.0, 0.175]}}),
         (), _both_modes, 0.99),
        ("two contacts on the end section, along y and along x (14 rows)", _two_stops, (), _two_contacts, 0.99),
        ("3D bar: its end face (25 rows) on a stop", _box, (), _touches, 0.99),
        ("1D rod on a stop (one row: the scalar LCP)", _rod, (), _touches, 0.99),
        ("a run of 3 steps", lambda: _strip({"solver.t_end": 3 * DT}), (), _held, 0.99),
        ("an elastic stop (stiffness 1e9 N/m) with the static correction",
         lambda: _strip({"contacts.0.stiffness": 1e9, "contacts.0.restitution": None}), (), _pressed_stop, 0.99),
        ("an elastic stop without the static correction (the spring alone)",
         lambda: _strip({"contacts.0.stiffness": 1e9, "contacts.0.restitution": None,
                         "solver.static_correction": False}), (), _pressed_stop, 0.99),
        ("a soft elastic stop 1 um away, no static correction: struck, then pressed",
         lambda: _strip({"contacts.0.stiffness": 1e7, "contacts.0.restitution": None, "contacts.0.gap": 1e-6,
                         "solver.static_correction": False}), (), _hits_and_stays, 0.9),
        ("checkpoints every step (blocks of one step)",
         lambda: _strip({"solver.t_end": 150 * DT, "output.checkpoint_every": 1}), (), _held, 0.99),
):
    probe(CLS, f"blocks as single steps: {_name}")(_same_as_single(_data, *_options, check=_check, share=_share))


@probe(CLS, "blocks as single steps: cases/face_on_stop.yaml with solver.method=modal, impacts.csv row for row")
def _face_on_stop(ctx):
    runs = {}
    for blocks in ("false", "true"):
        out = ctx.folder / blocks
        r = ctx.run("run", CASES / "face_on_stop.yaml", "-q", "-o", out, "--set", "solver.method=modal",
                    "--set", "output.vtk=false", "--set", f"solver.blocks={blocks}")
        bad = ctx.succeeded(r)
        if bad:
            return bad
        runs[blocks] = Run(out)
    single, fast = runs["false"], runs["true"]
    problem = _same_runs(single, fast) or _taken(single, fast, 0.9)
    if not problem and fast.s["impacts"]["stop"] < 2:
        problem = f"{fast.s['impacts']['stop']} impacts: the face never rang and bounced"
    return wrong(problem) if problem else ok(f"{fast.s['impacts']['stop']} impacts, "
                                             f"{fast.s['steps_in_blocks']}/{fast.s['steps']} steps in blocks")


@probe(CLS, "cases/strip_on_stop.yaml as given (8442 unknowns, 21 rows, blocks auto at 4000 steps), xdmf fields: "
           "as single steps")
def _strip_case(ctx):
    runs = {}
    for blocks in ("false", "auto"):
        out = ctx.folder / blocks
        r = ctx.run("run", CASES / "strip_on_stop.yaml", "-q", "-o", out, "--set", "output.format=xdmf",
                    "--set", f"solver.blocks={blocks}")
        bad = ctx.succeeded(r)
        if bad:
            return bad
        runs[blocks] = Run(out)
    single, fast = runs["false"], runs["auto"]
    problem = _same_runs(single, fast) or _taken(single, fast) or _held(single, fast)
    if problem:
        return wrong(problem)
    import fem_impact

    a, b = fem_impact.Result.load(single.folder).fields(), fem_impact.Result.load(fast.folder).fields()
    if a.t.size != b.t.size or a.t.size < 4000 // 40:
        return wrong(f"{b.t.size} frames in blocks, {a.t.size} in single steps (every 40 of 4000 steps)")
    for name, x in a.values.items():
        scale = max(np.abs(x).max(), 1e-300)
        if np.abs(x - b.values[name]).max() > TOL * scale:
            return wrong(f"field {name} parts by {np.abs(x - b.values[name]).max() / scale:.3g} of its scale")
    return ok(f"{fast.s['constraints']} rows, {fast.s['steps_in_blocks']} steps in {fast.s['blocks']} blocks, "
              f"{b.t.size} frames")


# -- the physics in blocks ---------------------------------------------------------------------------
@probe(CLS, "held in blocks: gaps closed, the corner node on the stop, the contact force every step")
def _held_physics(ctx):
    data = _strip({"output.probes": {"tip": [1.0, 0.05], "corner": [1.0, 0.0], "middle": [0.5, 0.05]}})
    fast, bad = _run(ctx, data, "blocks", **{"solver.blocks": True})
    if bad:
        return bad
    h, s = fast.h, fast.s
    shift = max(np.abs(h[k]).max() for k in h if k.endswith((".ux", ".uy")))
    problems = []
    if s["steps_in_blocks"] < 0.99 * s["steps"]:
        problems.append(f"only {s['steps_in_blocks']} steps in blocks")
    held = _persists(h)
    if held:
        problems.append(held)
    for name in ("stop.gap", "corner.uy", "tip.uy"):
        if np.abs(h[name]).max() > 1e-9 * shift:
            problems.append(f"{name} up to {np.abs(h[name]).max():.3g}, the displacements' scale {shift:.3g}")
    if s["max_penetration"] > 1e-9 * shift:
        problems.append(f"max_penetration {s['max_penetration']:.3g}")
    if abs(sum(h["stop.impulse"]) - s["total_impulse"]["stop"]) > 1e-9 * s["total_impulse"]["stop"]:
        problems.append(f"total_impulse {s['total_impulse']['stop']!r}, history's sum {sum(h['stop.impulse'])!r}")
    _budget(h, problems)
    return wrong("; ".join(problems)) if problems else ok(f"force {h['stop.force'][1:].min():.4g} N or more")


@probe(CLS, "constant loads, damped, in blocks: the balance closes, every loss grows, E <= E0 + W_ext")
def _constant_loads(ctx):
    """(theta 1/2: at theta > 1/2 the impulses' work with the step's mean velocity is the contact loss and
    their share of the scheme's dissipation goes to numerical_loss, which a step may make negative)"""
    data = _strip({"loads.1.acceleration": [0.0, -50.0], "damping": {"alpha": 5.0}})
    single, fast, bad = _pair(ctx, data)
    if bad:
        return bad
    problems = [p for p in (_differ(single.h, fast.h, TOL), _taken(single, fast)) if p]
    _budget(fast.h, problems, losses_grow=True)
    return wrong("; ".join(problems)) if problems else ok(f"contact_loss {fast.h['contact_loss'][-1]:.3g} J")


@probe(CLS, "theta 0.7, the strip held under its varying load: the balance closes, in blocks as in single steps")
def _theta_budget(ctx):
    """Moreau-Jean's budget closes to round-off for any theta (its numerical_loss holds the scheme's own
    dissipation), with the static part's energy, work and contact loss booked beside it."""
    single, fast, bad = _pair(ctx, _strip({"solver.theta": 0.7}))
    if bad:
        return bad
    problems = []
    for label, run in (("blocks", fast), ("single steps", single)):
        found = []
        _budget(run.h, found)
        problems += [f"{label}: {p}" for p in found if p.startswith("balance")]
    return wrong("; ".join(problems)) if problems else ok()


@probe(CLS, "a beam lying on a floor (61 rows, free along y): its momentum changes by the loads' and the floor's "
            "impulses, in blocks")
def _momentum(ctx):
    single, fast, bad = _pair(ctx, _floor())
    if bad:
        return bad
    problem = _same_runs(single, fast) or _taken(single, fast)
    if problem:
        return wrong(problem)
    (body, m), = fast.s["body_mass"].items()
    h = fast.h
    t = h["t"]
    load = -m * 9.81 - 1000.0 * (1.0 + 0.5 * np.sin(2.0 * np.pi * 300.0 * t))
    loads = np.concatenate(([0.0], np.cumsum(0.5 * (load[1:] + load[:-1]) * DT)))   # (theta 1/2: the mean)
    floor = np.cumsum(h["floor.impulse"])   # (along +y: the normal is -y)
    residual = np.abs(h[f"{body}.py"] - h[f"{body}.py"][0] - loads - floor).max()
    if residual > 1e-9 * np.abs(floor).max():
        return wrong(f"the momentum parts from the impulses by {residual:.3g} N s (the floor's {floor[-1]:.4g})")
    return ok(f"residual {residual:.2g} N s of {floor[-1]:.4g}")


@probe(CLS, "a node two contacts of one normal share: their total force and every other column as single steps")
def _shared_node(ctx):
    """The beam on its floor and a stop under its end section, both along -y: the corner node is in both,
    its two rows one constraint. How the force splits between the two is round-off's (the regularized
    problem, condition about 1e10), not the physics': the total and the other columns are judged, the
    energy terms (quadratic in the split forces) to 1e-8 of the energy's scale."""
    data = _floor()
    data["contacts"].append({"name": "tip", "type": "obstacle", "nodes": "right", "normal": [0.0, -1.0],
                             "gap": 0.0})
    single, fast, bad = _pair(ctx, data)
    if bad:
        return bad
    split = ("floor.force", "floor.impulse", "tip.force", "tip.impulse")
    problem = _differ(single.h, fast.h, TOL, skip=split + ENERGY) \
        or _differ(single.h, fast.h, 100 * TOL, skip=split) or _taken(single, fast)
    if not problem:
        problems = []
        _budget(fast.h, problems)
        problem = "; ".join(problems)
    if problem:
        return wrong(problem)
    for k in ("force", "impulse"):
        a = single.h[f"floor.{k}"] + single.h[f"tip.{k}"]
        b = fast.h[f"floor.{k}"] + fast.h[f"tip.{k}"]
        if np.abs(a - b).max() > TOL * np.abs(a).max():
            return wrong(f"the total {k} parts by {np.abs(a - b).max() / np.abs(a).max():.3g} of its scale")
    worst = max(np.abs(single.h[k] - fast.h[k]).max() / np.abs(single.h[k]).max() for k in split)
    return ok(f"the split between the two contacts differs by {worst:.2g} of its scale (round-off's)")


# -- output ----------------------------------------------------------------------------------------------
def _xdmf_fields(ctx):
    data = _strip({"solver.t_end": 600 * DT, "output.vtk": True, "output.format": "xdmf", "output.every": 50})
    single, fast, bad = _pair(ctx, data)
    if bad:
        return bad
    import fem_impact

    a, b = fem_impact.Result.load(single.folder).fields(), fem_impact.Result.load(fast.folder).fields()
    if a.t.size != b.t.size or np.abs(a.t - b.t).max() > 1e-12:
        return wrong(f"frames at {b.t} against {a.t}")
    for name, x in a.values.items():
        y = b.values[name]
        scale = max(np.abs(x).max(), 1e-300)
        if np.abs(x - y).max() > TOL * scale:
            return wrong(f"field {name} parts by {np.abs(x - y).max() / scale:.3g} of its scale")
    if not np.abs(b.values["contact_force"]).max() > 0.0:
        return wrong("no contact force in the fields")
    problem = _same_runs(single, fast)
    return wrong(problem) if problem else ok(f"{b.t.size} frames")


probe(CLS, "xdmf fields every 50 steps: u, v, a, contact_force, contact_state as single steps")(_xdmf_fields)


def _vtu_arrays(folder) -> list[dict]:
    """Every .vtu piece of a run (sorted by name): its point data arrays by name."""
    frames = []
    for path in sorted(folder.glob("**/*.vtu")):
        arrays = {}
        for node in ET.parse(path).iter():
            if node.tag.endswith("DataArray") and node.get("Name") in ("u", "v", "a", "contact_force"):
                arrays[node.get("Name")] = np.array((node.text or "").split(), dtype=float)
        frames.append(arrays)
    return frames


@probe(CLS, "vtu fields at output.every=7 (frames within blocks): as single steps")
def _vtu_fields(ctx):
    data = _strip({"solver.t_end": 300 * DT, "output.vtk": True, "output.every": 7})
    single, fast, bad = _pair(ctx, data)
    if bad:
        return bad
    a, b = _vtu_arrays(single.folder), _vtu_arrays(fast.folder)
    if len(a) != len(b) or len(a) < 300 // 7:
        return wrong(f"{len(b)} vtu frames against {len(a)} (every 7 of 300 steps)")
    if single.s["vtk_frames"] != fast.s["vtk_frames"]:
        return wrong(f"vtk_frames {fast.s['vtk_frames']} against {single.s['vtk_frames']}")
    for name in ("u", "v", "a", "contact_force"):
        x = np.concatenate([f[name] for f in a])
        y = np.concatenate([f[name] for f in b])
        scale = max(np.abs(x).max(), 1e-300)
        if x.size != y.size or np.abs(x - y).max() > TOL * scale:
            return wrong(f"field {name} parts by {np.abs(x - y).max() / scale:.3g} of its scale")
    problem = _same_runs(single, fast)
    return wrong(problem) if problem else ok(f"{len(a)} frames")


@probe(CLS, "output.period: periods.csv (impulses, impacts, work, losses a period) as single steps")
def _periods(ctx):
    data = _strip(LIFT_OFF, **{"output.period": "1/40"})
    single, fast, bad = _pair(ctx, data)
    if bad:
        return bad
    problem = _same_runs(single, fast)
    if problem:
        return wrong(problem)
    rows = []
    for run in (single, fast):
        with open(run.folder / "periods.csv", newline="") as f:
            rows.append(list(csv.DictReader(f)))
    a, b = rows
    if len(a) != len(b) or len(a) < 1:
        return wrong(f"periods.csv: {len(b)} rows against {len(a)}")
    for name in a[0]:
        x = np.array([float(r[name]) for r in a])
        y = np.array([float(r[name]) for r in b])
        scale = max(np.abs(x).max(), 1e-300)
        if name in ("losses", "external_work"):
            scale = max(scale, max(np.abs(single.h[k]).max() for k in ("kinetic", "strain")))
        digit = 10.0 ** (np.floor(np.log10(np.maximum(np.maximum(np.abs(x), np.abs(y)), 1e-300))) - 11)
        if (np.abs(x - y) > np.maximum(TOL * scale, 1.0001 * digit)).any():
            return wrong(f"periods.csv {name}: {y.tolist()} in blocks, {x.tolist()} in single steps")
    impacts = sum(float(r["stop.impacts"]) for r in b)
    return ok(f"{len(a)} periods, {impacts:.0f} impacts in them")


@probe(CLS, "--stop-on-energy-gain: the held strip runs to its end in blocks, as single steps")
def _energy_gain_watch(ctx):
    single, fast, bad = _pair(ctx, _strip(), "--stop-on-energy-gain")
    if bad:
        return bad
    problem = _same_runs(single, fast) or _taken(single, fast)
    if not problem and fast.s["energy_created"]:
        problem = f"energy_created {fast.s['energy_created']!r}"
    return wrong(problem) if problem else ok()


# -- blocks: auto ------------------------------------------------------------------------------------------
@probe(CLS, "blocks auto: single steps below 4000 steps, blocks from 4000, the same history")
def _auto(ctx):
    runs = {}
    for label, steps, blocks in (("auto-3999", 3999, "auto"), ("auto-4000", 4000, "auto"),
                                 ("false-4000", 4000, False)):
        run, bad = _run(ctx, _strip({"solver.t_end": steps * DT}), label, **{"solver.blocks": blocks})
        if bad:
            return bad
        runs[label] = run
    if runs["auto-3999"].s["steps_in_blocks"]:
        return wrong(f"3999 steps, auto: {runs['auto-3999'].s['steps_in_blocks']} in blocks")
    problem = _same_runs(runs["false-4000"], runs["auto-4000"]) or _taken(runs["false-4000"], runs["auto-4000"])
    if not problem:
        problem = _differ(runs["auto-4000"].h, runs["auto-3999"].h, TOL, rows=slice(0, 4000))
    return wrong(problem) if problem else ok(f"{runs['auto-4000'].s['blocks']} blocks at 4000 steps")


# -- what the compiled step does not take: single steps, as before ------------------------------------------
def _rigid_beside_stop() -> dict:
    """No static correction: an elastic stop under the end section, a rigid one beside it along x."""
    data = _strip({"solver.static_correction": False, "loads.0.force": [500.0, -1000.0],
                   "contacts.0.stiffness": 1e9, "contacts.0.restitution": None})
    data["contacts"].append({"name": "axial", "type": "obstacle", "nodes": "right", "normal": [1.0, 0.0],
                             "gap": 0.0})
    return data


def _stepped_singly(changes: dict, held: bool = True, data_of=None):
    def body(ctx):
        data = data_of() if data_of else _strip(changes)
        single, fast, bad = _pair(ctx, data)
        if bad:
            return bad
        problem = _same_runs(single, fast, SAME)
        if not problem and held and fast.s["steps_in_blocks"]:
            problem = f"{fast.s['steps_in_blocks']} steps in blocks in a contact held at every step"
        return wrong(problem) if problem else ok(f"{fast.s['steps_in_blocks']}/{fast.s['steps']} steps in blocks")
    return body


for _name, _changes in (
        ("a moving obstacle (contacts[].motion)", {"contacts.0.motion": [0.0, "1e-6*sin(2*pi*100*t)"],
                                                    "solver.t_end": 500 * DT}),
        ("rigid rows (static_correction: false, Carnot's correction)", {"solver.static_correction": False}),
        ("friction (static_correction: false, coupling: mean)",
         {"solver.static_correction": False, "contacts.0.friction": 0.3, "contacts.0.coupling": "mean",
          "loads.0.force": [300.0, -1000.0], "solver.t_end": 500 * DT}),
        ("the paper's scheme (solver.scheme: newmark)", {"solver.scheme": "newmark"}),
):
    probe(CLS, f"stepped one at a time, as single steps to 1e-12: {_name}")(_stepped_singly(_changes))
probe(CLS, "stepped one at a time, as single steps to 1e-12: a rigid stop (Carnot's correction) beside an elastic "
           "one, no static correction")(_stepped_singly({}, data_of=_rigid_beside_stop))


# Friction through the static correction (docs/theory.md s. 8.9): its contact steps are single steps, the same
probe(CLS, "stepped one at a time, as single steps to 1e-12: friction through the static correction (coupling: "
           "mean)")(_stepped_singly({"contacts.0.friction": 0.3, "contacts.0.coupling": "mean",
                                     "loads.0.force": [300.0, -1000.0], "solver.t_end": 500 * DT}))


# -- the run stopped: loads that stop being finite, energies that overflow ------------------------------------
def _stopped_as_single(changes: dict, needle: str):
    def body(ctx):
        data = _strip(changes)
        results = {}
        for blocks in (False, True):
            r, out = run_case(ctx, data, "--set", f"solver.blocks={str(blocks).lower()}", out=f"b-{blocks}")
            if r.traceback:
                return Verdict("traceback", r.tail())
            results[blocks] = (r, out)
        (a, _), (b, b_out) = results[False], results[True]
        if a.status != 3:
            return Verdict("error", f"single steps: status {a.status}, not the stop this probe expects: {a.tail()}")
        if b.status != 3 or b.lines() != a.lines():
            return wrong(f"blocks: status {b.status}, {b.tail()}; single steps: {a.tail()}")
        if needle not in b.stderr or len(b.lines()) != 1:
            return wrong(f"not one line naming {needle!r}: {b.tail()}")
        if b_out.exists():
            return wrong(f"the run stopped, yet {b_out} was written")
        return ok(b.tail(1)[:160])
    return body


probe(CLS, "a load no longer finite in the held contact (sqrt(0.005 - t)): the one-line stop of single steps")(
    _stopped_as_single({"loads.1.acceleration": [0.0, "-50*(1 + 0.5*sin(2*pi*300*t))*sqrt(0.005 - t)"]},
                       "no longer finite"))
probe(CLS, "a load whose energies overflow in the held contact: the one-line stop of single steps")(
    _stopped_as_single({"loads.0.force": [0.0, "-1000 - 1e300*max(0, (t - 0.005)/1e-5)"]}, "no longer finite"))


# -- restarts -----------------------------------------------------------------------------------------------
T_SPLIT, T_END = 777 * DT, 1500 * DT


def _continued(ctx, data, first_sets: dict, later_sets: dict, whole_sets: dict, t_split=T_SPLIT, t_end=T_END):
    """The run to ``t_split`` (``first_sets``), continued to ``t_end`` (``later_sets``) against the whole run
    (``whole_sets``): history, summary and impacts.csv; None, or a verdict."""
    first, bad = _run(ctx, data, "first", **{**first_sets, "solver.t_end": t_split})
    if bad:
        return bad
    whole, bad = _run(ctx, data, "whole", **{**whole_sets, "solver.t_end": t_end})
    if bad:
        return bad
    later, bad = _run(ctx, data, "continued", "--restart", first.folder, **{**later_sets, "solver.t_end": t_end})
    if bad:
        return bad
    n = later.h["t"].size
    problem = _differ(whole.h, later.h, TOL, rows=slice(-n, None))
    if not problem and abs(later.h["t"][0] - t_split) > 1e-12:
        problem = f"the continued history starts at t = {later.h['t'][0]!r}, the checkpoint's is {t_split!r}"
    if not problem:
        problem = _summary_differs(whole.s, later.s, TOL, _shift(whole.h)) or _impacts_differ(whole.folder,
                                                                                           later.folder)
    return wrong(problem) if problem else None


@probe(CLS, "restart inside the held contact (checkpoints every 77 steps): continues the uninterrupted run")
def _restart(ctx):
    sets = {"solver.blocks": True, "output.checkpoint_every": 77}
    return _continued(ctx, _strip(), sets, sets, sets) or ok()


@probe(CLS, "restart inside lift-offs and impacts: continues the uninterrupted run, impacts.csv too")
def _restart_impacts(ctx):
    sets = {"solver.blocks": True}
    return _continued(ctx, _strip(LIFT_OFF), sets, sets, sets, 1234 * DT, 3000 * DT) or ok()


@probe(CLS, "restart inside the held contact with output.period: periods.csv continues the uninterrupted run")
def _restart_periods(ctx):
    sets = {"solver.blocks": True, "output.period": 500 * DT}
    verdict = _continued(ctx, _strip(), sets, sets, sets)
    if verdict:
        return verdict
    rows = []
    for name in ("whole", "continued"):
        with open(ctx.folder / name / "periods.csv", newline="") as f:
            rows.append(list(csv.DictReader(f)))
    whole, later = rows
    if len(whole) != 3 or len(later) != 3:
        return wrong(f"periods.csv: {len(later)} rows continued, {len(whole)} uninterrupted (3 periods)")
    for name in whole[0]:
        x = np.array([float(r[name]) for r in whole])
        y = np.array([float(r[name]) for r in later])
        if np.abs(x - y).max() > TOL * max(np.abs(x).max(), 1e-300) + 1e-11 * np.abs(x).max():
            return wrong(f"periods.csv {name}: continued {y.tolist()}, uninterrupted {x.tolist()}")
    return ok()


@probe(CLS, "restart switching solver.blocks (false to true, true to false): the uninterrupted run")
def _restart_switch(ctx):
    for before, after in ((False, True), (True, False)):
        verdict = _continued(ctx, _strip(), {"solver.blocks": before}, {"solver.blocks": after},
                             {"solver.blocks": before})
        if verdict:
            verdict.detail = f"blocks {before} then {after}: {verdict.detail}"
            return verdict
        for name in ("first", "whole", "continued"):
            shutil.rmtree(ctx.folder / name)
    return ok()


@probe(CLS, "restart from the held contact with a changed load: refused, naming loads.0.force")
def _restart_changed_load(ctx):
    data = _strip()
    first, bad = _run(ctx, data, "first", **{"solver.blocks": True, "solver.t_end": T_SPLIT})
    if bad:
        return bad
    r, out = run_case(ctx, _strip({"loads.0.force": [0.0, -2000.0]}), "--restart", first.folder,
                      "--set", "solver.blocks=true", out="continued")
    verdict = ctx.refused(r, "loads.0.force", "--restart")
    if verdict.kind == "ok" and out.exists():
        return wrong(f"refused, yet {out} was written")
    return verdict


# -- 2 ranks, signals ---------------------------------------------------------------------------------------
@probe(CLS, "2 MPI ranks: blocks true as false, the contact steps in blocks on every rank", timeout=240)
def _two_ranks(ctx):
    single, fast, bad = _pair(ctx, _strip(LIFT_OFF, **{"solver.t_end": 1500 * DT}), mpi=2)
    if bad:
        return bad
    problem = _same_runs(single, fast) or _taken(single, fast, 0.9)
    return wrong(problem) if problem else ok(f"{fast.s['steps_in_blocks']}/{fast.s['steps']} in blocks, "
                                             f"{fast.s['mpi_ranks']} ranks")


NAME = "m"


def _interrupt_and_continue(mpi: int):
    def body(ctx):
        data = _strip({"solver.blocks": True, "solver.t_end": 10.0, "output.checkpoint_every": 20000})
        data["name"] = NAME
        case = ctx.folder / f"{NAME}.yaml"
        case.write_text(yaml.safe_dump(data, sort_keys=False))
        out = ctx.folder / NAME
        saved = lambda: bool(list(ctx.folder.glob(f".{NAME}.checkpoint-*/checkpoint/state.json")))  # noqa: E731
        r = ctx.run("run", case, "-q", "-o", out, mpi=mpi, signal_at=(saved, signal.SIGINT))
        if r.traceback:
            return Verdict("traceback", r.tail())
        lines = [line for line in r.lines() if line.startswith("fem-impact:")]
        # (mpirun passes SIGTERM to its ranks whatever it received: the line names it)
        if len(lines) != 1 or not lines[0].startswith("fem-impact: interrupted by SIG" if mpi else
                                                      "fem-impact: interrupted by SIGINT"):
            return wrong(f"status {r.status}: {r.tail(4)}")
        if (not mpi and r.status != 128 + signal.SIGINT) or r.status in (0, None):
            return wrong(f"status {r.status}: {lines[0]}")
        kept = ctx.folder / f"{NAME}.checkpoint"
        if not (kept / "state.json").is_file() or f"--restart {kept}" not in lines[0]:
            return wrong(f"no checkpoint kept in {kept}, or not named: {lines[0]}")
        if out.exists():
            return wrong(f"the interrupted run left {out}")
        t0 = json.loads((kept / "state.json").read_text())["t"]
        t_end = t0 + 300 * DT
        later, bad = _run(ctx, data, "continued", "--restart", kept, mpi=mpi, **{"solver.t_end": t_end})
        if bad:
            return bad
        whole, bad = _run(ctx, data, "whole", mpi=mpi, **{"solver.t_end": t_end, "output.checkpoint_every": 0})
        if bad:
            return bad
        n = later.h["t"].size
        if abs(later.h["t"][0] - t0) > 1e-9 * t0:
            return wrong(f"the continued history starts at t = {later.h['t'][0]!r}, not the checkpoint's {t0!r}")
        problem = _differ(whole.h, later.h, TOL, rows=slice(-n, None)) \
            or _summary_differs(whole.s, later.s, TOL, _shift(whole.h))
        steps = later.s["steps"] - later.s["restarted_from"]["step"]   # (steps_in_blocks: this run's own)
        if not problem and later.s["steps_in_blocks"] < 0.99 * steps:
            problem = f"the continued run took {later.s['steps_in_blocks']} of its {steps} steps in blocks"
        return wrong(problem) if problem else ok(f"interrupted at t >= {t0:.4g}, continued to {t_end:.4g}")
    return body


probe(CLS, "SIGINT to a serial run in the held contact, in blocks: one line, checkpoint kept, the restart "
           "continues the uninterrupted run", timeout=240)(_interrupt_and_continue(0))
probe(CLS, "SIGINT to mpirun -n 2 in the held contact, in blocks: one line, checkpoint kept, the restart on 2 ranks "
           "continues the uninterrupted run", timeout=300)(_interrupt_and_continue(2))
