"""Class ``mixed-blocks``: a modal body's scene stepped many steps at a time in one compiled loop
(``bodies: {NAME: {model: modal, modes: N, blocks: auto | true | false}}``, fem_impact/rigid/blocks.py and
kernel.py, the conditions in rigid/blocks_fit.py; docs/theory.md s. 12.7, docs/case_files.md "A modal body"),
attacked as a user would through the command line.

The scenes: cases/vibromotor_modal.yaml (2D: a rigid slider on a modal driver, one mean coupling row with
friction, loads varying in time, damping) over 600 steps; tests/test_mixed.py's slab (a rigid block launched
along a modal slab under gravity, 21 pair rows with friction, meshes/block_on_slab.py); and a mesh of the
probe's own: two rigid blocks sliding on one modal slab with a third rigid body spinning freely beside them
(40 rad in the run).

The contract each probe judges:

- ``blocks: true`` gives the history of ``blocks: false`` (single steps) to round-off, never to the bit (the
  loop sums in its own order): every column within 1e-8 of its scale (a gap on the largest displacement, or
  1e-16 m; a vector's component on the vector's largest; a rigid body's angle on its motion over 0.1 m, its
  momentum on its mass times its nodes' speed), or one unit of history.csv's 12th digit, the energies within
  1e-10 of the energy scale; the counts of sticking and sliding rows and the largest slip where the
  rows' states agree (a row whose normal impulse is round-off's zero, 4e-18 N s one way and -6e-18 the
  other, is counted loaded in one run and open in the other: a discontinuous count of round-off, not a
  difference of the physics), and those states at all but a few steps; the summary's counts; and the
  summary's ``steps_in_blocks`` shows the steps were taken in blocks (none with ``false``);
- the physics in blocks: the balance closed, no energy created, the damping and friction losses >= 0 (the
  contact loss as the single steps book it); a block sliding on the slab stops at v0 / (mu g), a frictionless
  one keeps v0, a free body spins at its omega exactly;
- the output's options (period, every, probes, VTK and XDMF frames), checkpoints and restarts (switching
  ``blocks`` too, as ``solver.blocks`` may: the same results), SIGINT, a load that stops being finite: as the
  single steps give them;
- a scene the loop cannot take (3D, 2 MPI ranks, a row off the modal body, a moving obstacle) with
  ``blocks: true``: stepped singly, one warning naming ``bodies.NAME.blocks`` and the reason (said once, by
  rank 0, as the project's other warnings), the single steps' history (on 2 ranks to 2e-9: the cone problem
  is solved to a residual of 1e-10);
- what is not a setting (``maybe``, ``1``, ``blocks`` on a rigid or elastic body): refused in one line, status
  2, naming ``bodies.NAME.blocks``, nothing written.
"""

from __future__ import annotations

import copy
import csv
import json
import shutil
import signal
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

from . import CASES, ROOT, Verdict, history, ok, probe, run_case, wrong

CLS = "mixed-blocks"
VIBRO = CASES / "vibromotor_modal.yaml"
TOL = 1e-8        # of a column's scale: blocks against single steps (the claim: round-off)
TOL_E = 1e-10     # of the energy scale: the energies
SAME = 1e-12      # where both runs take single steps
# 2 ranks against 1, single steps both: the rows' cone problem is solved to a residual of 1e-10
# (FrictionProblem.TOLERANCE), so runs that sum in other orders agree on the friction row's force to a few times
# that (2e-10 and 7e-10 of its scale measured), the rest to 1e-10
MPI_TOL = 2e-9
ENERGY = ("kinetic", "strain", "external_work", "damping_loss", "impact_loss", "contact_loss", "energy_error",
          "friction_loss", "numerical_loss", "scheme_energy")
STATES = (".sticking", ".slipping", ".slip")   # (the rows' states: discontinuous in a round-off impulse)
DT = 2.5e-6       # the vibromotor's step
G, MU, V0 = 9.81, 0.3, 0.5   # the slab scene's (tests/test_mixed.py)
BLOCK_MASS = 0.2 * 0.05 * 0.01 * 7800.0


# -- the scenes -------------------------------------------------------------------------------------
def _set(data: dict, path: str, value) -> None:
    keys = path.split(".")
    node = data
    for key in keys[:-1]:
        node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
    if isinstance(node, list):
        node[int(keys[-1])] = value
    else:
        node[keys[-1]] = value


def _vibro(changes: dict | None = None, t_end: float = 600 * DT) -> dict:
    """cases/vibromotor_modal.yaml (its mesh by absolute path), no VTK, to ``t_end``, with ``changes`` (dotted
    keys)."""
    data = yaml.safe_load(VIBRO.read_text())
    data["mesh"] = {"file": str(ROOT / "meshes" / "vibromotor.msh")}
    data["solver"]["t_end"] = t_end
    data["output"]["vtk"] = False
    for path, value in (changes or {}).items():
        _set(data, path, value)
    return data


def _slab_mesh(ctx) -> Path:
    def build(folder):
        r = ctx.run(ROOT / "meshes" / "block_on_slab.py", "-o", folder / "slab.msh", python=True)
        if r.status != 0 or not (folder / "slab.msh").is_file():
            raise RuntimeError(f"meshes/block_on_slab.py failed: {r.tail()}")
    return ctx.shared("mixed-blocks-slab", build) / "slab.msh"


def _slab(ctx, modes: int = 4, changes: dict | None = None) -> dict:
    """tests/test_mixed.py's slab_scene, the slab modal with ``modes`` modes."""
    data = {"name": "slab", "mesh": {"file": str(_slab_mesh(ctx))},
            "material": {"E": 210e9, "rho": 7800.0, "nu": 0.3, "area": 0.01},
            "bodies": {"block": {"model": "rigid"}, "slab": {"model": "modal", "modes": modes}},
            "initial": {"velocity": [{"body": "block", "value": [V0, 0.0]}]},
            "supports": [{"nodes": "base", "fix": "all"}],
            "loads": [{"body": b, "acceleration": [0.0, -G]} for b in ("slab", "block")],
            "contacts": [{"name": "face", "type": "pair", "nodes": ["top", "bottom"], "normal": [0.0, 1.0],
                          "restitution": 0.0, "friction": MU}],
            "solver": {"dt": 2e-4, "t_end": 0.25}, "output": {"vtk": False}}
    for path, value in (changes or {}).items():
        _set(data, path, value)
    return data


_TWO = '''
import sys
import gmsh
from fem_impact.fem.gmsh_utils import add_named_groups, structured_quads, write_msh

GAP, h = 1e-6, 0.01
gmsh.initialize(["", "-v", "0"])
gmsh.model.add("two_on_slab")
occ = gmsh.model.occ
cuts = (0.0, 0.05, 0.25, 0.35, 0.55, 0.6)
pieces = [(2, occ.addRectangle(a, 0.0, 0.0, b - a, 0.05)) for a, b in zip(cuts[:-1], cuts[1:])]
slab = [tag for _, tag in occ.fragment(pieces, [])[0]]
one = occ.addRectangle(0.05, 0.05 + GAP, 0.0, 0.2, 0.05)
two = occ.addRectangle(0.35, 0.05 + GAP, 0.0, 0.2, 0.05)
spinner = occ.addRectangle(0.26, 0.3, 0.0, 0.08, 0.04)
occ.synchronize()
structured_quads((*slab, one, two, spinner), h)


def edge(y, x0, x1):
    return [t for _, t in gmsh.model.getEntitiesInBoundingBox(x0 - 1e-5, y - 2e-7, -1, x1 + 1e-5, y + 2e-7, 1, 1)]


add_named_groups(2, {"slab": slab, "one": [one], "two": [two], "spinner": [spinner]})
add_named_groups(1, {"base": edge(0.0, 0.0, 0.6), "top_one": edge(0.05, 0.05, 0.25),
                     "top_two": edge(0.05, 0.35, 0.55), "bottom_one": edge(0.05 + GAP, 0.05, 0.25),
                     "bottom_two": edge(0.05 + GAP, 0.35, 0.55)})
gmsh.model.mesh.generate(2)
write_msh(sys.argv[1])
gmsh.finalize()
'''
OMEGA, SPIN_CENTRE = 200.0, (0.3, 0.32)      # the free spinner's spin (rad/s) and centre
V_ONE, V_TWO, MU_ONE, MU_TWO = 0.5, -0.3, 0.3, 0.2


def _two_mesh(ctx) -> Path:
    def build(folder):
        script = folder / "two.py"
        script.write_text(_TWO)
        r = ctx.run(script, folder / "two.msh", python=True)
        if r.status != 0 or not (folder / "two.msh").is_file():
            raise RuntimeError(f"the two blocks' mesh could not be made: {r.tail()}")
    return ctx.shared("mixed-blocks-two", build) / "two.msh"


def _two(ctx) -> dict:
    """Two rigid blocks (0.2 x 0.05 m) launched at V_ONE and V_TWO along one modal slab (4 modes) under
    gravity, each on 21 pair rows (mu MU_ONE, MU_TWO); a third rigid body (0.08 x 0.04 m) spinning freely at
    OMEGA above them, no load on it."""
    cx, cy = SPIN_CENTRE
    return {"name": "two", "mesh": {"file": str(_two_mesh(ctx))},
            "material": {"E": 210e9, "rho": 7800.0, "nu": 0.3, "area": 0.01},
            "bodies": {"one": {"model": "rigid"}, "two": {"model": "rigid"}, "spinner": {"model": "rigid"},
                       "slab": {"model": "modal", "modes": 4}},
            "initial": {"velocity": [{"body": "one", "value": [V_ONE, 0.0]}, {"body": "two", "value": [V_TWO, 0.0]},
                                     {"body": "spinner", "value": [f"-{OMEGA}*(y - {cy})", f"{OMEGA}*(x - {cx})"]}]},
            "supports": [{"nodes": "base", "fix": "all"}],
            "loads": [{"body": b, "acceleration": [0.0, -G]} for b in ("slab", "one", "two")],
            "contacts": [{"name": f"face_{b}", "type": "pair", "nodes": [f"top_{b}", f"bottom_{b}"],
                          "normal": [0.0, 1.0], "restitution": 0.0, "friction": mu}
                         for b, mu in (("one", MU_ONE), ("two", MU_TWO))],
            "solver": {"dt": 2e-4, "t_end": 0.2}, "output": {"vtk": False}}


def _modal_name(data: dict) -> str:
    return next(name for name, body in data["bodies"].items() if body.get("model") == "modal")


def _with_blocks(data: dict, blocks) -> dict:
    data = copy.deepcopy(data)
    data["bodies"][_modal_name(data)]["blocks"] = blocks
    return data


# -- runs -------------------------------------------------------------------------------------------
class Run:
    def __init__(self, folder, completed=None):
        self.folder, self.r = Path(folder), completed
        self.h = history(folder)
        self.s = json.loads((self.folder / "summary.json").read_text())


def _run(ctx, data, out, *options, mpi=0):
    """(Run, None) of ``data`` run into ``out``; (None, verdict) when it failed."""
    r, folder = run_case(ctx, data, *options, mpi=mpi, out=out)
    bad = ctx.succeeded(r)
    return (None, bad) if bad else (Run(folder, r), None)


def _pair(ctx, data, *options, mpi=0, blocks=True):
    """The runs of ``data`` with blocks false and ``blocks``: (single, fast, None) or (.., verdict)."""
    single, bad = _run(ctx, _with_blocks(data, False), "single", *options, mpi=mpi)
    if bad:
        return None, None, bad
    fast, bad = _run(ctx, _with_blocks(data, blocks), "blocks", *options, mpi=mpi)
    return single, fast, bad


def _scales(h: dict, masses: dict | None = None) -> dict:
    """Each column's scale: an energy term the energy's; a gap the largest displacement (the probes' and the
    gaps'); a vector's component the vector's largest (a body's velocity, momentum, centre's motion, a
    contact's friction force, a probe's u or v); a body's angle (omega) its centre's motion (speed) over
    0.1 m; a rigid body's momentum at least its mass times its nodes' speed (omega over 0.1 m: a spinning
    body's momentum is round-off's sum of its nodes' large opposite velocities); else the column's own largest
    value."""
    top = lambda names: max([np.abs(h[k]).max() for k in names if k in h] + [0.0])   # noqa: E731
    energy = max(top([k for k in ("kinetic", "strain", "external_work", "contact_loss", "friction_loss",
                                  "damping_loss") if k in h]), np.abs(h["kinetic"] + h["strain"]).max())
    shift = top([k for k in h if k.endswith((".ux", ".uy", ".gap"))])
    scales = {}
    for name, column in h.items():
        own = np.abs(column).max()
        stem, _, tail = name.rpartition(".")
        if name in ENERGY:
            own = max(own, energy)
        elif tail == "gap" or (tail in ("ux", "uy") and f"{stem}.vx" in h and f"{stem}.x" not in h):
            own = max(own, shift)
        elif tail in ("vx", "vy", "px", "py"):
            own = max(own, top([f"{stem}.{tail[0]}x", f"{stem}.{tail[0]}y"]))
            if tail[0] == "p" and f"{stem}.omega" in h and masses and stem in masses:
                own = max(own, masses[stem] * max(top([f"{stem}.vx", f"{stem}.vy"]), top([f"{stem}.omega"]) * 0.1))
        elif tail in ("x", "y") and f"{stem}.angle" in h:   # (a rigid body's centre: its motion)
            own = max(np.abs(h[f"{stem}.x"] - h[f"{stem}.x"][0]).max(),
                      np.abs(h[f"{stem}.y"] - h[f"{stem}.y"][0]).max())
        elif tail == "angle":
            own = max(own, max(np.abs(h[f"{stem}.{c}"] - h[f"{stem}.{c}"][0]).max() for c in "xy") / 0.1)
        elif tail == "omega":
            own = max(own, top([f"{stem}.vx", f"{stem}.vy"]) / 0.1)
        elif tail in ("tangential_force", "tx", "ty"):
            own = top([f"{stem}.tangential_force", f"{stem}.tx", f"{stem}.ty"])
        scales[name] = max(own, 1e-300)
    return scales


def _differ(a: dict, b: dict, tol: float = TOL, tol_e: float = TOL_E, rows: slice = slice(None),
            skip=(), masses: dict | None = None) -> str | None:
    """Where history ``b`` parts from ``a`` (None: nowhere): each column to ``tol`` of its scale, the energies
    to ``tol_e`` of the energy's, or one unit of history.csv's 12th significant digit (a centre's 0.005 m
    written to 1e-14), a gap to 1e-16 m (100 ulps of the mesh's 1e-2 m coordinates it is the difference of);
    the rows' states (sticking, slipping counts, the largest slip) where the counts agree, and the counts at
    all but 1 % of the steps (module docstring)."""
    if list(a) != list(b):
        return f"columns differ: {sorted(set(a) ^ set(b)) or 'their order'}"
    n = b["t"].size
    a = {k: v[rows] for k, v in a.items()}
    if a["t"].size != n:
        return f"{n} rows against {a['t'].size}"
    scales = _scales(a, masses)
    agree = np.ones(n, dtype=bool)
    for name in a:
        if name.endswith((".sticking", ".slipping")):
            agree &= a[name] == b[name]
    if np.count_nonzero(~agree) > max(1, 0.01 * n):
        j = int(np.argmin(agree))
        return f"the rows' states differ at {np.count_nonzero(~agree)} of {n} steps, first at t = {a['t'][j]:.6g}"
    for name in a:
        if name in skip or name.endswith((".sticking", ".slipping")):
            continue
        x, y = a[name], b[name]
        where = agree if name.endswith(".slip") else np.ones(n, dtype=bool)
        allowed = (tol_e if name in ENERGY else tol) * scales[name]
        if name.endswith(".gap"):
            allowed = max(allowed, 1e-16)
        big = np.maximum(np.abs(x), np.abs(y))
        digit = 1.0001 * 10.0 ** (np.floor(np.log10(np.maximum(big, 1e-300))) - 11)
        off = np.where(where & (np.abs(x - y) > digit), np.abs(x - y), 0.0)
        if not np.all(np.isfinite(y)) or off.max() > allowed:
            j = int(np.argmax(np.where(np.isfinite(off), off, np.inf)))
            return (f"{name} at t = {a['t'][j]:.6g}: {y[j]!r} against {x[j]!r} ({abs(x[j] - y[j]) / scales[name]:.2g} "
                    f"of its scale {scales[name]:.3g})")
    return None


def _summary_differs(a: dict, b: dict, tol: float = TOL, restarted: bool = False) -> str | None:
    """The summaries' counts equal, the total impulses to ``tol``. ``restarted``: ``b`` continued from a
    checkpoint, whose impacts.csv and count hold the impacts from the checkpoint on (the one under way
    included, the earlier ones not: single steps alike), so its impacts are not compared."""
    for key in ("steps", "constraints", "modes", "modal_body", "energy_created_at") + (() if restarted else
                                                                                        ("impacts",)):
        if a.get(key) != b.get(key):
            return f"summary {key}: {b.get(key)!r} against {a.get(key)!r}"
    for name, impulse in a["total_impulse"].items():
        if abs(b["total_impulse"][name] - impulse) > tol * max(abs(impulse), 1e-300):
            return f"summary total_impulse {name}: {b['total_impulse'][name]!r} against {impulse!r}"
    return None


def _taken(single: Run, fast: Run, share: float = 0.99) -> str | None:
    """The blocks run took at least ``share`` of its steps in blocks; the single one none."""
    if single.s.get("steps_in_blocks"):
        return f"blocks: false took {single.s['steps_in_blocks']} steps in blocks"
    if fast.s.get("steps_in_blocks", 0) < share * fast.s["steps"]:
        return f"only {fast.s.get('steps_in_blocks')} of {fast.s['steps']} steps in blocks"
    return None


def _budget(h: dict, problems: list, closes: float = TOL_E, contact: bool = False) -> None:
    """The balance closed, E <= E0 + W_ext, the damping and friction losses >= 0, the damping's each step, to
    ``closes`` of the energy scale; the contact loss >= 0 with ``contact`` only (the single steps' own contact
    loss goes below zero in some scenes: 20 modes, -2e-8 of the energy scale; a step of 1e-4 s, -22 %; there the
    blocks are judged by giving the single steps' loss, in the histories' comparison)."""
    scale = max(np.abs(h[k]).max() for k in ("kinetic", "strain", "external_work"))
    scale = max(scale, np.abs(h["kinetic"] + h["strain"]).max())
    if np.abs(h["energy_error"]).max() > closes * scale:
        problems.append(f"balance residual {np.abs(h['energy_error']).max():.3g} of {scale:.3g}")
    total = h["kinetic"] + h["strain"]
    excess = total - total[0] - h["external_work"]
    if excess.max() > closes * scale:
        problems.append(f"E - E0 - W_ext up to {excess.max():.3g} (energy {scale:.3g})")
    for name in ("contact_loss", "damping_loss", "impact_loss", "friction_loss")[0 if contact else 1:]:
        if name in h and h[name].min() < -closes * scale:
            problems.append(f"{name} down to {h[name].min():.3g}")
    if np.diff(h["damping_loss"]).min() < -closes * scale:
        problems.append(f"damping_loss falls over a step by {-np.diff(h['damping_loss']).min():.3g}")


def _same(single: Run, fast: Run, tol: float = TOL, share: float | None = 0.99, tol_e: float = TOL_E) -> str | None:
    return (_differ(single.h, fast.h, tol, tol_e, masses=single.s.get("body_mass"))
            or _summary_differs(single.s, fast.s, tol) or (_taken(single, fast, share) if share is not None else None))


def _done(fast: Run, detail: str = "") -> Verdict:
    return ok(f"{fast.s.get('steps_in_blocks')}/{fast.s['steps']} steps in {fast.s.get('blocks')} blocks"
              + (f"; {detail}" if detail else ""))


# -- blocks true as false -------------------------------------------------------------------------------
def _as_single(make, check=None, share: float = 0.99, budget: bool = True, tol: float = TOL):
    """Blocks true against false on ``make(ctx)``: the same histories and summary counts, ``share`` of the
    steps in blocks, the balance of the blocks run; ``check(single, fast)`` -> a problem or None."""
    def body(ctx):
        single, fast, bad = _pair(ctx, make(ctx))
        if bad:
            return bad
        problems = [p for p in (_same(single, fast, tol, share), check(single, fast) if check else None) if p]
        if budget:
            _budget(fast.h, problems)
        return wrong("; ".join(problems)) if problems else _done(fast)
    return body


def _vibro_of(changes: dict | None = None, t_end: float = 600 * DT):
    return lambda ctx: _vibro(changes, t_end)


def _slides_at(single, fast):
    """The drive moved the slider: its friction loss grew, it left x = 0.005."""
    h = fast.h
    if not h["friction_loss"][-1] > 0.0 or np.abs(h["slider.x"] - 0.005).max() <= 0.0:
        return "the slider did not slide"
    return None


def _frictionless(single, fast):
    h = fast.h
    if "friction_loss" in h and np.abs(h["friction_loss"]).max() != 0.0:
        return f"friction loss {np.abs(h['friction_loss']).max():.3g} without friction"
    return None


def _damped(single, fast):
    h = fast.h
    if not h["damping_loss"][-1] > 0.0:
        return "no damping loss"
    return None


def _undamped(single, fast):
    h = fast.h
    return None if np.abs(h["damping_loss"]).max() == 0.0 else f"damping loss {h['damping_loss'][-1]:.3g} undamped"


SLIDER_LOADS = [
    {"nodes": "tip", "force": ["Fx*cos(2*pi*f*t)*(1 - exp(-f*t))", "Fy*sin(2*pi*f*t)*(1 - exp(-f*t))"]},
    {"nodes": "face", "force": ["-FL + 1.5*sin(2*pi*3100*t)", "-P*(1 + 0.4*sin(2*pi*7300*t + 0.3))"]},
    {"body": "slider", "acceleration": ["200*sin(2*pi*2900*t)", "-9.81 - 300*cos(2*pi*1700*t)"]},
]

for _name, _changes, _check in (
        ("cases/vibromotor_modal.yaml as given (600 steps)", None, _slides_at),
        ("friction 0 (frictionless)", {"contacts.0.friction": 0.0}, _frictionless),
        ("restitution 0.5 (no effect on the compliant row)", {"contacts.0.restitution": 0.5}, None),
        ("damping none", {"damping": None}, _undamped),
        ("damping alpha 3000 1/s alone", {"damping": {"alpha": 3000.0}}, _damped),
        ("damping beta 4e-6 s alone", {"damping": {"beta": 4e-6}}, _damped),
        ("a force varying in sin(t) on the rigid slider's face, a varying body acceleration on the slider",
         {"loads": SLIDER_LOADS}, _slides_at),
        ("gravity on both bodies (constant body accelerations)",
         {"loads": yaml.safe_load(VIBRO.read_text())["loads"] + [{"body": b, "acceleration": [0.0, -G]}
                                                               for b in ("driver", "slider")]}, _slides_at),
        ("modes: 1", {"bodies.driver.modes": 1}, None),
        ("modes: 20", {"bodies.driver.modes": 20}, None),
        ("an initial velocity and spin on the slider (5 rad/s, 0.1 m/s along x)",
         {"initial": {"velocity": [{"body": "slider", "value": ["0.1 - 5*(y - 0.015)", "5*(x - 0.005)"]}]}}, None),
        ("probes on the driver and on the rigid slider's corner",
         {"output.probes": {"tip": [0.005, 0.0088], "corner": [-0.01, 0.02], "mid": [0.005, 0.015]}}, None),
        ("dt 1e-4 (Courant >> 1: 6 periods of the first mode a step)", {"solver.dt": 1e-4}, None),
        ("solver.mass: lumped", {"solver.mass": "lumped"}, None),
        ("solver.level: velocity", {"solver.level": "velocity"}, None),
        ("a fixed obstacle struck by the driver's tip along x (a row of the modal body alone, no rigid body)",
         {"contacts": yaml.safe_load(VIBRO.read_text())["contacts"] + [
             {"name": "stop", "type": "obstacle", "nodes": "tip", "normal": [1.0, 0.0], "gap": 1.2e-6,
              "restitution": 0.0}]}, lambda single, fast: None if fast.s["impacts"].get("stop") else
         "the driver's tip never struck the stop"),
):
    probe(CLS, f"blocks true as false, vibromotor: {_name}")(
        _as_single(_vibro_of(_changes, 600 * _changes["solver.dt"] if _changes and "solver.dt" in _changes
                             else 600 * DT), _check))


@probe(CLS, "blocks true as false, vibromotor: dt 2.5e-9 (1000 times smaller, 600 steps)")
def _small_dt(ctx):
    """The loop's own gaps (kernel.py's GAP) are the single steps' to 1e-22 m; the block hands history.csv and
    the next block the gap of its nodal fields instead (d0 - P U, U as factors), 5 ulps of the 1e-2 m
    coordinates (8.7e-18 m) away: each block's first step starts from it and its force moves by that gap times
    the row's stiffness, 1e-7 N, the static part's rate with it by 1e-7 N / dt. Where the force is small
    (1.5 us: still building, 6.7 N) and dt too, the single steps' history is then left by more than the
    round-off the claim allows (1.5e-8 of the force's scale, 1.8e-8 of the probe's speed): a defect of the
    handover (the loop computes GAP and drops it), not of the sums' order."""
    dt = 2.5e-9
    return _as_single(_vibro_of({"solver.dt": dt}, 600 * dt))(ctx)


@probe(CLS, "blocks true as false, vibromotor: restitution 0.5 in blocks is restitution 0 in single steps "
            "(docs: no effect on a modal body's compliant rows)")
def _restitution_none(ctx):
    single, bad = _run(ctx, _with_blocks(_vibro({"contacts.0.restitution": 0.0}), False), "single")
    if bad:
        return bad
    fast, bad = _run(ctx, _with_blocks(_vibro({"contacts.0.restitution": 0.5}), True), "blocks")
    if bad:
        return bad
    problem = _same(single, fast)
    return wrong(problem) if problem else _done(fast)


def _coulomb(h, problems, block="block", face="face", v0=V0, mu=MU, rel=2e-3):
    """The block stops at |v0| / (mu g) (within ``rel``), its friction force mu times the normal one while it
    slides."""
    v = h[f"{block}.vx"] * np.sign(v0)
    v0 = abs(v0)
    stopped = np.flatnonzero(v <= 1e-3 * v0)
    if not stopped.size:
        problems.append(f"{block} never stops (v = {v[-1]:.4g})")
        return
    stop = h["t"][stopped[0]]
    if abs(stop - v0 / (mu * G)) > rel * v0 / (mu * G):
        problems.append(f"{block} stops at {stop:.6g} s, v0 / (mu g) = {v0 / (mu * G):.6g}")
    sliding = np.flatnonzero((v[:-1] > 1e-2 * v0) & (v[1:] > 1e-2 * v0)) + 1
    pushed = sliding[h[f"{face}.force"][sliding] > 0.0]
    if pushed.size < 0.9 * sliding.size:
        problems.append(f"{face} pushed in {pushed.size} of {sliding.size} sliding steps")
    ratio = h[f"{face}.tangential_force"][pushed] / (mu * h[f"{face}.force"][pushed])
    if pushed.size and np.abs(ratio - 1.0).max() > 1e-9:
        problems.append(f"{face}: friction force / (mu F_N) off 1 by {np.abs(ratio - 1.0).max():.3g} while sliding")


def _slab_probe(modes: int):
    def body(ctx):
        single, fast, bad = _pair(ctx, _slab(ctx, modes))
        if bad:
            return bad
        problems = [p for p in (_same(single, fast),) if p]
        _coulomb(fast.h, problems)
        loss = fast.h["friction_loss"][-1]
        if abs(loss - 0.5 * BLOCK_MASS * V0 ** 2) > 1e-3 * 0.5 * BLOCK_MASS * V0 ** 2:
            problems.append(f"friction loss {loss:.6g}, 1/2 m v0^2 = {0.5 * BLOCK_MASS * V0 ** 2:.6g}")
        _budget(fast.h, problems, closes=1e-9)
        if problems:
            return wrong("; ".join(problems))
        return _done(fast, f"stops at {fast.h['t'][np.flatnonzero(fast.h['block.vx'] <= 1e-3 * V0)[0]]:.5g} s")
    return body


for _n in (1, 4, 20):
    probe(CLS, f"blocks true as false, slab scene (21 rows, friction), modes: {_n}: stops at v0 / (mu g)",
          timeout=300)(_slab_probe(_n))


@probe(CLS, "blocks true as false, slab scene frictionless: the block keeps v0 exactly, no friction loss")
def _slab_frictionless(ctx):
    single, fast, bad = _pair(ctx, _slab(ctx, 4, {"contacts.0.friction": 0.0, "solver.t_end": 0.1}))
    if bad:
        return bad
    problems = [p for p in (_same(single, fast),) if p]
    h = fast.h
    if np.abs(h["block.vx"] - V0).max() > 1e-12 * V0:
        problems.append(f"block.vx parts from v0 by {np.abs(h['block.vx'] - V0).max():.3g}")
    if np.abs(h["block.x"] - h["block.x"][0] - V0 * h["t"]).max() > 1e-12:
        problems.append("block.x is not x0 + v0 t")
    _budget(h, problems, closes=1e-9)
    return wrong("; ".join(problems)) if problems else _done(fast)


@probe(CLS, "blocks true as false, slab scene with the block spinning (omega 2 rad/s) and sliding: rocking on "
            "one corner row")
def _slab_spin(ctx):
    """(until it lands flat at 0.039 s: each flat landing of the rocking block magnifies a difference about 40
    times, as any perturbation: 9e-12 of block.vy before the first, 3.6e-7 after the fourth)"""
    spin = {"initial.velocity.0.value": [f"{V0} - 2*(y - 0.075001)", "2*(x - 0.3)"], "solver.t_end": 0.034}
    single, fast, bad = _pair(ctx, _slab(ctx, 4, spin))
    if bad:
        return bad
    problems = [p for p in (_same(single, fast),) if p]
    _budget(fast.h, problems, closes=1e-9)
    if np.abs(fast.h["block.angle"]).max() <= 1e-4:
        problems.append("the block did not turn")
    return wrong("; ".join(problems)) if problems else _done(fast, f"turns up to "
                                                                    f"{np.abs(fast.h['block.angle']).max():.3g} rad")


# -- two rigid bodies on the modal slab, a free spinner beside ---------------------------------------------
@probe(CLS, "blocks true as false: two rigid blocks sliding on one modal slab, a third body spinning freely "
            "(40 rad)", timeout=300)
def _two_blocks(ctx):
    single, fast, bad = _pair(ctx, _two(ctx))
    if bad:
        return bad
    problems = [p for p in (_same(single, fast),) if p]
    _budget(fast.h, problems, closes=1e-9)
    return wrong("; ".join(problems)) if problems else _done(fast)


@probe(CLS, "two blocks on a modal slab in blocks: each stops at v0 / (mu g), the free spinner turns at omega "
            "exactly (40 rad), its centre still", timeout=300)
def _two_exact(ctx):
    fast, bad = _run(ctx, _with_blocks(_two(ctx), True), "blocks")
    if bad:
        return bad
    h, problems = fast.h, []
    if fast.s.get("steps_in_blocks", 0) < 0.99 * fast.s["steps"]:
        problems.append(f"only {fast.s.get('steps_in_blocks')} of {fast.s['steps']} steps in blocks")
    _coulomb(h, problems, "one", "face_one", V_ONE, MU_ONE, rel=5e-3)
    _coulomb(h, problems, "two", "face_two", V_TWO, MU_TWO, rel=5e-3)
    angle = h["spinner.angle"]
    if np.abs(angle - OMEGA * h["t"]).max() > 1e-10 * OMEGA * h["t"][-1]:
        problems.append(f"spinner.angle parts from omega t by {np.abs(angle - OMEGA * h['t']).max():.3g} rad")
    if np.abs(h["spinner.omega"] - OMEGA).max() > 1e-12 * OMEGA:
        problems.append(f"spinner.omega parts from {OMEGA} by {np.abs(h['spinner.omega'] - OMEGA).max():.3g}")
    drift = max(np.abs(h["spinner.x"] - SPIN_CENTRE[0]).max(), np.abs(h["spinner.y"] - SPIN_CENTRE[1]).max())
    if drift > 1e-12:
        problems.append(f"the spinner's centre moved by {drift:.3g} m")
    _budget(h, problems, closes=1e-9)
    return wrong("; ".join(problems)) if problems else _done(fast, f"spinner at {angle[-1]:.4g} rad")


# -- the output's options ------------------------------------------------------------------------------------
def _csv_rows(path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@probe(CLS, "output.period (the drive's period, 17 periods): periods.csv as in single steps")
def _periods(ctx):
    single, fast, bad = _pair(ctx, _vibro({"output.period": "1/f"}, 1400 * DT))
    if bad:
        return bad
    problem = _same(single, fast)
    if problem:
        return wrong(problem)
    a, b = (_csv_rows(run.folder / "periods.csv") for run in (single, fast))
    if len(a) != len(b) or len(a) < 17:
        return wrong(f"periods.csv: {len(b)} rows in blocks against {len(a)} (17 periods)")
    if list(a[0]) != list(b[0]):
        return wrong(f"periods.csv columns {list(b[0])} against {list(a[0])}")
    energy = max(np.abs(single.h[k]).max() for k in ("kinetic", "strain", "external_work"))
    for name in a[0]:
        x = np.array([float(r[name]) for r in a])
        y = np.array([float(r[name]) for r in b])
        scale = max(np.abs(x).max(), 1e-300)
        if name in ("losses", "external_work") or name.endswith(("_loss", "work")):
            scale = max(scale, energy)
        if np.abs(x - y).max() > TOL * scale:
            return wrong(f"periods.csv {name}: {y.tolist()} in blocks, {x.tolist()} in single steps")
    return _done(fast, f"{len(a)} periods")


def _vtu_frames(folder) -> list[dict]:
    frames = []
    for path in sorted(Path(folder).glob("**/*.vtu")):
        arrays = {}
        for node in ET.parse(path).iter():
            if node.tag.endswith("DataArray") and node.get("Name") in ("u", "v", "a", "contact_force"):
                arrays[node.get("Name")] = np.array((node.text or "").split(), dtype=float)
        frames.append(arrays)
    return frames


@probe(CLS, "vtk true, output.every 7 (frames inside blocks): results.pvd's .vtu frames' u, v, a, contact_force "
            "as single steps")
def _vtu(ctx):
    single, fast, bad = _pair(ctx, _vibro({"output.vtk": True, "output.every": 7}))
    if bad:
        return bad
    problem = _same(single, fast)
    if problem:
        return wrong(problem)
    a, b = _vtu_frames(single.folder), _vtu_frames(fast.folder)
    if len(a) != len(b) or len(a) < 600 // 7 or single.s["vtk_frames"] != fast.s["vtk_frames"]:
        return wrong(f"{len(b)} .vtu frames in blocks, {len(a)} in single steps (every 7 of 600 steps)")
    if not (single.folder / "results.pvd").is_file() or not (fast.folder / "results.pvd").is_file():
        return wrong("no results.pvd")
    for name in ("u", "v", "a", "contact_force"):
        if name not in a[0]:
            continue
        x = np.concatenate([f[name] for f in a])
        y = np.concatenate([f.get(name, np.zeros(0)) for f in b])
        scale = max(np.abs(x).max(), 1e-300)
        if x.size != y.size or np.abs(x - y).max() > TOL * scale:
            return wrong(f"vtu field {name} parts by {np.abs(x - y).max() / scale:.3g} of its scale")
    return _done(fast, f"{len(a)} frames")


@probe(CLS, "output.format xdmf every 40 steps: the fields (u, v, a, contact force and state) as single steps")
def _xdmf(ctx):
    single, fast, bad = _pair(ctx, _vibro({"output.vtk": True, "output.format": "xdmf", "output.every": 40}))
    if bad:
        return bad
    problem = _same(single, fast)
    if problem:
        return wrong(problem)
    import fem_impact

    a, b = fem_impact.Result.load(single.folder).fields(), fem_impact.Result.load(fast.folder).fields()
    if a.t.size != b.t.size or a.t.size < 600 // 40 or np.abs(a.t - b.t).max() > 1e-12:
        return wrong(f"{b.t.size} frames in blocks, {a.t.size} in single steps")
    for name, x in a.values.items():
        y = b.values[name]
        scale = max(np.abs(x).max(), 1e-300)
        if np.shape(x) != np.shape(y) or np.abs(x - y).max() > TOL * scale:
            return wrong(f"xdmf field {name} parts by {np.abs(x - y).max() / scale:.3g} of its scale")
    return _done(fast, f"{b.t.size} frames, fields {sorted(a.values)}")


@probe(CLS, "--stop-on-energy-gain: the run in blocks goes to its end as single steps, energy_created 0")
def _energy_gain(ctx):
    single, fast, bad = _pair(ctx, _vibro(), "--stop-on-energy-gain")
    if bad:
        return bad
    problem = _same(single, fast)
    if not problem and fast.s.get("energy_created"):
        problem = f"energy_created {fast.s['energy_created']!r}"
    return wrong(problem) if problem else _done(fast)


@probe(CLS, "2000 steps in blocks: the balance closes to 1e-10, no energy created, friction and damping losses "
            "only grow")
def _long_budget(ctx):
    fast, bad = _run(ctx, _with_blocks(_vibro(t_end=2000 * DT), True), "blocks")
    if bad:
        return bad
    h, problems = fast.h, []
    _budget(h, problems)
    scale = np.abs(h["external_work"]).max()
    for loss in ("friction_loss", "damping_loss"):
        if np.diff(h[loss]).min() < -1e-12 * scale:
            problems.append(f"{loss} falls over a step by {-np.diff(h[loss]).min():.3g}")
    if fast.s.get("energy_created"):
        problems.append(f"energy_created {fast.s['energy_created']!r}")
    if fast.s.get("steps_in_blocks") != fast.s["steps"]:
        problems.append(f"{fast.s.get('steps_in_blocks')} of {fast.s['steps']} steps in blocks")
    return wrong("; ".join(problems)) if problems else _done(fast)


# -- blocks: auto ------------------------------------------------------------------------------------------
@probe(CLS, "blocks auto (and the key left out): single steps below 4000 steps, blocks from 4000, the same "
            "history", timeout=300)
def _auto(ctx):
    dt = 2.5e-7
    runs = {}
    for label, steps, blocks in (("auto-3999", 3999, "auto"), ("auto-4000", 4000, "auto"),
                                 ("absent-4000", 4000, None), ("false-4000", 4000, False)):
        data = _vibro({"solver.dt": dt}, steps * dt)
        if blocks is not None:
            data = _with_blocks(data, blocks)
        run, bad = _run(ctx, data, label)
        if bad:
            return bad
        runs[label] = run
    if runs["auto-3999"].s.get("steps_in_blocks"):
        return wrong(f"3999 steps, auto: {runs['auto-3999'].s['steps_in_blocks']} in blocks")
    for label in ("auto-4000", "absent-4000"):
        problem = _same(runs["false-4000"], runs[label])
        if problem:
            return wrong(f"{label}: {problem}")
    problem = _differ(runs["auto-4000"].h, runs["auto-3999"].h, rows=slice(0, 4000))
    return wrong(f"3999 steps against 4000: {problem}") if problem else _done(runs["auto-4000"])


# -- the command line -----------------------------------------------------------------------------------
@probe(CLS, "fem-impact run on the case file with --set (blocks true): status 0, its outputs written, the "
            "resolved case keeps blocks; --set bodies.driver.blocks=false: the same history in single steps")
def _command_line(ctx):
    base = ["--set", f"solver.t_end={600 * DT}", "--set", "output.vtk=false"]
    runs = {}
    for label, value in (("true", "true"), ("false", "false")):
        out = ctx.folder / label
        r = ctx.run("run", VIBRO, "-o", out, *base, "--set", f"bodies.driver.blocks={value}")
        bad = ctx.succeeded(r)
        if bad:
            return bad
        missing = [n for n in ("history.csv", "summary.json", "case.resolved.yaml") if not (out / n).is_file()]
        if missing:
            return wrong(f"--set bodies.driver.blocks={value}: {missing} not written")
        runs[label] = Run(out, r)
    resolved = yaml.safe_load((ctx.folder / "true" / "case.resolved.yaml").read_text())
    kept = resolved.get("bodies", {}).get("driver", {}).get("blocks")
    if kept is not True:
        return wrong(f"case.resolved.yaml bodies.driver.blocks: {kept!r}, the run's true")
    problem = _same(runs["false"], runs["true"], share=1.0)
    return wrong(problem) if problem else _done(runs["true"])


@probe(CLS, "the resolved case of a run in blocks runs again to the same history")
def _resolved_again(ctx):
    first, bad = _run(ctx, _with_blocks(_vibro(), True), "first")
    if bad:
        return bad
    again = ctx.folder / "again"
    r = ctx.run("run", first.folder / "case.resolved.yaml", "-q", "-o", again)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    second = Run(again, r)
    problem = _differ(first.h, second.h, SAME, SAME) or (None if second.s.get("steps_in_blocks") == second.s["steps"]
                                                         else f"{second.s.get('steps_in_blocks')} steps in blocks")
    return wrong(problem) if problem else _done(second)


# -- refusals -------------------------------------------------------------------------------------------------
def _refusal(make, *needles: str, sets: tuple = ()):
    def body(ctx):
        r, out = run_case(ctx, make(ctx), *sets)
        verdict = ctx.refused(r, *needles)
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    return body


def _vibro_bodies(bodies: dict):
    def make(ctx):
        data = _vibro()
        data["bodies"] = bodies
        return data
    return make


for _name, _make, _needles, _sets in (
        ("blocks: maybe", lambda ctx: _with_blocks(_vibro(), "maybe"), ("bodies.driver.blocks",), ()),
        ("blocks: 1", lambda ctx: _with_blocks(_vibro(), 1), ("bodies.driver.blocks",), ()),
        ("blocks on the rigid slider", _vibro_bodies({"slider": {"model": "rigid", "blocks": True},
                                                      "driver": {"model": "modal", "modes": 8}}),
         ("bodies.slider.blocks",), ()),
        ("blocks on the driver made elastic", _vibro_bodies({"slider": {"model": "rigid"},
                                                             "driver": {"model": "elastic", "blocks": False}}),
         ("bodies.driver.blocks",), ()),
        ("--set bodies.driver.blocks=sometimes on the command line", lambda ctx: _vibro(),
         ("bodies.driver.blocks",), ("--set", "bodies.driver.blocks=sometimes")),
):
    probe(CLS, f"refused (status 2, one line naming the key, nothing written): {_name}")(
        _refusal(_make, *_needles, sets=_sets))


# -- scenes the loop does not take: single steps, said once -----------------------------------------------------
def _said_once(r, name: str, *needles: str) -> str | None:
    """One line on stderr naming ``bodies.NAME.blocks`` and ``needles`` (mpirun's own lines aside)."""
    lines = [line for line in r.lines() if f"bodies.{name}.blocks" in line]
    if len(lines) != 1:
        return f"{len(lines)} lines naming bodies.{name}.blocks: {r.tail(4)}"
    missing = [n for n in needles if n.lower() not in lines[0].lower()]
    return f"the warning does not name {missing}: {lines[0]}" if missing else None


def _singly(make, name: str, needles: tuple, mpi: int = 0, timeout_serial: bool = True):
    """blocks: true on a scene the loop cannot take: one warning, no step in blocks, the history of blocks:
    false (serial, with ``mpi``: the serial run's to 1e-10)."""
    def body(ctx):
        data = make(ctx)
        single, bad = _run(ctx, _with_blocks(data, False), "single")
        if bad:
            return bad
        fast, bad = _run(ctx, _with_blocks(data, True), "blocks", mpi=mpi)
        if bad:
            return bad
        problems = [p for p in (_said_once(fast.r, name, *needles),) if p]
        if fast.s.get("steps_in_blocks"):
            problems.append(f"{fast.s['steps_in_blocks']} steps in blocks")
        tol = MPI_TOL if mpi else SAME
        problem = _differ(single.h, fast.h, tol, tol) or _summary_differs(single.s, fast.s, tol)
        if problem:
            problems.append(problem)
        quiet = [line for line in single.r.lines() if "blocks" in line]
        if quiet:
            problems.append(f"blocks: false warned: {quiet[0]}")
        return wrong("; ".join(problems)) if problems else ok(_said_once(fast.r, name) or
                                                             [x for x in fast.r.lines() if "blocks" in x][0][:160])
    return body


def _hammer(ctx) -> dict:
    data = yaml.safe_load((CASES / "hammer_rod.yaml").read_text())
    data["mesh"] = {"file": str(ROOT / "meshes" / "hammer_rod.msh")}
    data["bodies"] = {"hammer": {"model": "rigid"}, "rod": {"model": "modal", "modes": 2}}
    data["solver"].update(t_end=4e-5)
    data["output"] = {"vtk": False}
    return data


def _obstacle_on_slider(ctx) -> dict:
    data = _vibro()
    data["contacts"].append({"name": "roof", "type": "obstacle", "nodes": "face", "normal": [0.0, -1.0],
                             "gap": 1e-3})
    return data


def _moving_obstacle(ctx) -> dict:
    data = _vibro()
    data["contacts"].append({"name": "floor", "type": "obstacle", "nodes": "tip", "normal": [0.0, 1.0],
                             "gap": 1e-3, "motion": [0.0, "1e-6*sin(2*pi*1000*t)"]})
    return data


probe(CLS, "blocks true on the 3D hammer_rod scene: one warning naming bodies.rod.blocks and 3D, single steps, "
           "the history of blocks false", timeout=300)(_singly(_hammer, "rod", ("3D",)))
probe(CLS, "blocks true with an obstacle on the rigid slider (a row off the modal body): one warning naming the "
           "reason, single steps, the same history")(_singly(_obstacle_on_slider, "driver", ("off the modal body",)))
probe(CLS, "blocks true with a moving obstacle under the driver: one warning naming moving obstacles, single "
           "steps, the same history")(_singly(_moving_obstacle, "driver", ("moving",)))
probe(CLS, "blocks true on 2 MPI ranks: single steps, one warning (said once, by rank 0) naming MPI, the serial "
           "single steps' history to 2e-9 (the cone solve's tolerance)", timeout=300)(
    _singly(lambda ctx: _vibro(), "driver", ("MPI",), mpi=2))


@probe(CLS, "blocks true on 2 MPI ranks: the serial run in blocks' history to 1e-8 (its claim), single steps (the "
           "warning aside)", timeout=300)
def _two_ranks(ctx):
    data = _with_blocks(_vibro(), True)
    serial, bad = _run(ctx, data, "serial")
    if bad:
        return bad
    ranks, bad = _run(ctx, data, "ranks", mpi=2)
    if bad:
        return bad
    problem = _differ(serial.h, ranks.h, masses=serial.s.get("body_mass")) or _summary_differs(serial.s, ranks.s)
    if not problem and ranks.s.get("steps_in_blocks"):
        problem = f"{ranks.s['steps_in_blocks']} steps in blocks on 2 ranks"
    return wrong(problem) if problem else ok(f"{ranks.s.get('mpi_ranks')} ranks")


# -- checkpoints, restarts, signals -------------------------------------------------------------------------------
T_SPLIT, T_END = 333 * DT, 700 * DT


def _continued(ctx, data, first_blocks, later_blocks, whole_blocks, every: int = 50) -> Verdict | None:
    """The run to T_SPLIT (checkpoints every ``every``), continued to T_END, against the whole run."""
    data = copy.deepcopy(data)
    data["output"]["checkpoint_every"] = every
    data["solver"]["t_end"] = T_SPLIT
    first, bad = _run(ctx, _with_blocks(data, first_blocks), "first")
    if bad:
        return bad
    data["solver"]["t_end"] = T_END
    whole, bad = _run(ctx, _with_blocks(data, whole_blocks), "whole")
    if bad:
        return bad
    later, bad = _run(ctx, _with_blocks(data, later_blocks), "continued", "--restart", first.folder)
    if bad:
        return bad
    n = later.h["t"].size
    problem = _differ(whole.h, later.h, rows=slice(-n, None))
    if not problem and abs(later.h["t"][0] - T_SPLIT) > 1e-3 * DT:
        problem = f"the continued history starts at t = {later.h['t'][0]!r}, the checkpoint's {T_SPLIT!r}"
    if not problem:
        problem = _summary_differs(whole.s, later.s, restarted=True)
    if not problem and later_blocks is True:
        steps = later.s["steps"] - (later.s.get("restarted_from") or {}).get("step", 0)
        if later.s.get("steps_in_blocks", 0) < 0.99 * steps:
            problem = f"the continued run took {later.s.get('steps_in_blocks')} of its {steps} steps in blocks"
    return wrong(problem) if problem else None


@probe(CLS, "checkpoint_every 50 and --restart in blocks: the continued run's history is the uninterrupted one's")
def _restart(ctx):
    return _continued(ctx, _vibro(), True, True, True) or ok()


@probe(CLS, "--restart switching blocks (true to false, false to true): the uninterrupted run's history")
def _restart_switch(ctx):
    for before, after in ((True, False), (False, True)):
        verdict = _continued(ctx, _vibro(), before, after, before)
        if verdict:
            verdict.detail = f"blocks {before} then {after}: {verdict.detail}"
            return verdict
        for name in ("first", "whole", "continued"):
            shutil.rmtree(ctx.folder / name)
    return ok()


@probe(CLS, "--restart in blocks on the slab scene (21 rows, friction), the checkpoint mid-slide: the "
            "uninterrupted run's history", timeout=300)
def _restart_slab(ctx):
    data = _slab(ctx, 4)
    data["output"]["checkpoint_every"] = 100
    data["solver"]["t_end"] = 0.06
    first, bad = _run(ctx, _with_blocks(data, True), "first")
    if bad:
        return bad
    data["solver"]["t_end"] = 0.12
    whole, bad = _run(ctx, _with_blocks(data, True), "whole")
    if bad:
        return bad
    later, bad = _run(ctx, _with_blocks(data, True), "continued", "--restart", first.folder)
    if bad:
        return bad
    n = later.h["t"].size
    problem = _differ(whole.h, later.h, rows=slice(-n, None)) or _summary_differs(whole.s, later.s, restarted=True)
    return wrong(problem) if problem else _done(later)


NAME = "m"


@probe(CLS, "SIGINT to a long run in blocks: one line, status 130, the checkpoint kept and named, the restart "
            "from it continues the uninterrupted run", timeout=300)
def _interrupted(ctx):
    data = _with_blocks(_vibro({"output.checkpoint_every": 2000}, t_end=2.0), True)   # (800000 steps)
    data["name"] = NAME
    case = ctx.folder / f"{NAME}.yaml"
    case.write_text(yaml.safe_dump(data, sort_keys=False))
    out = ctx.folder / NAME
    saved = lambda: bool(list(ctx.folder.glob(f".{NAME}.checkpoint-*/checkpoint/state.json")))  # noqa: E731
    r = ctx.run("run", case, "-q", "-o", out, signal_at=(saved, signal.SIGINT))
    if r.traceback:
        return Verdict("traceback", r.tail())
    lines = [line for line in r.lines() if line.startswith("fem-impact:")]
    if len(lines) != 1 or not lines[0].startswith("fem-impact: interrupted by SIGINT"):
        return wrong(f"status {r.status}: {r.tail(4)}")
    if r.status != 128 + signal.SIGINT:
        return wrong(f"status {r.status}, expected {128 + signal.SIGINT}: {lines[0]}")
    kept = ctx.folder / f"{NAME}.checkpoint"
    if not (kept / "state.json").is_file() or f"--restart {kept}" not in lines[0]:
        return wrong(f"no checkpoint kept in {kept}, or not named: {lines[0]}")
    if out.exists():
        return wrong(f"the interrupted run left {out}")
    t0 = json.loads((kept / "state.json").read_text())["t"]
    t_end = t0 + 300 * DT
    data["solver"]["t_end"] = t_end
    later, bad = _run(ctx, data, "continued", "--restart", kept)
    if bad:
        return bad
    data["output"]["checkpoint_every"] = 0
    whole, bad = _run(ctx, data, "whole")
    if bad:
        return bad
    n = later.h["t"].size
    if abs(later.h["t"][0] - t0) > 1e-9 * t0:
        return wrong(f"the continued history starts at t = {later.h['t'][0]!r}, not the checkpoint's {t0!r}")
    problem = _differ(whole.h, later.h, rows=slice(-n, None)) or _summary_differs(whole.s, later.s, restarted=True)
    steps = later.s["steps"] - later.s["restarted_from"]["step"]
    if not problem and later.s.get("steps_in_blocks", 0) < 0.99 * steps:
        problem = f"the continued run took {later.s.get('steps_in_blocks')} of its {steps} steps in blocks"
    return wrong(problem) if problem else ok(f"interrupted at t >= {t0:.4g}, continued to {t_end:.4g}")


# -- the run stopped: a load no longer finite -------------------------------------------------------------------
def _stopped_as_single(make, needle: str):
    def body(ctx):
        data = make(ctx)
        results = {}
        for blocks in (False, True):
            r, out = run_case(ctx, _with_blocks(data, blocks), out=f"b-{blocks}")
            if r.traceback:
                return Verdict("traceback", r.tail())
            results[blocks] = (r, out)
        (a, _), (b, b_out) = results[False], results[True]
        if a.status != 3:
            return Verdict("error", f"single steps: status {a.status}, not the stop this probe expects: {a.tail()}")
        if b.status != a.status or b.lines() != a.lines():
            return wrong(f"blocks: status {b.status}, {b.tail()}; single steps: status {a.status}, {a.tail()}")
        if needle not in b.stderr or len(b.lines()) != 1:
            return wrong(f"not one line naming {needle!r}: {b.tail()}")
        if b_out.exists():
            return wrong(f"the run stopped, yet {b_out} was written")
        return ok(b.tail(1)[:160])
    return body


probe(CLS, "a load on the modal driver no longer finite mid-run (sqrt(0.0008 - t)): the one-line stop of single "
           "steps, naming the load")(
    _stopped_as_single(lambda ctx: _vibro({"loads.0.force": ["Fx*cos(2*pi*f*t)*sqrt(0.0008 - t)", 0.0]},
                                          t_end=600 * DT), "no longer finite"))
probe(CLS, "a body acceleration on the rigid slider no longer finite mid-run: the one-line stop of single steps, "
           "naming the load")(
    _stopped_as_single(lambda ctx: _vibro({"loads": yaml.safe_load(VIBRO.read_text())["loads"] + [
        {"body": "slider", "acceleration": [0.0, "-9.81*sqrt(0.0008 - t)"]}]}, t_end=600 * DT), "no longer finite"))
