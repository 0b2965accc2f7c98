"""Class ``modal-bodies``: a modal body beside rigid bodies (``bodies: {NAME: {model: modal, modes: N}}``,
docs/theory.md s. 12.6, docs/case_files.md "A modal body"), attacked as a user would: cases/hammer_rod.yaml
with a heavy rigid hammer (1000 times the rod's mass) on the rod made modal, the modes' count, damping, loads,
the output's options, moving walls, the pair written either way, a free modal hammer on a floating rigid rod,
2 MPI ranks, checkpoints, restarts, SIGINT; and what a modal scene refuses (status 2, one line naming the key,
nothing written).

The exact answers judged:

- the heavy hammer (M = 156 kg) presses the rod quasi-statically (its lowest modes bend, the strike excites
  none of them: the static correction alone carries the contact): the contact lasts pi sqrt(M C), C = L / (E A)
  the rod's compliance at its end (within 2 steps), the peak force is v0 sqrt(M / C) (within 0.5 %), the
  compliant rows' gap is zero while they push, so the rod's end follows the hammer's face exactly, the end
  displacement is C times the force; the same for any count of modes (1, 2, 6, 20);
- the balance closes to 1e-10 of the energy scale, every loss >= 0 (damping's non-decreasing), E <= E0 + W_ext,
  the hammer's momentum changes by exactly the reported impulses;
- a force F along the rod on its free end: its end moves by F C from the first step (the static correction of
  the load, no mode excited);
- a wall closing in at V on the rod's free end: the force (V t - gap) / C at each step's end;
- a free modal hammer striking a floating rigid rod: the total momentum conserved to round-off;
- the rod keeping all its modes (no static part) is the rod in full, to round-off.
"""

from __future__ import annotations

import json
import signal
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

from . import CASES, ROOT, Verdict, ok, probe, restart_parts, run_case, solved, wrong

CLS = "modal-bodies"
HAMMER_ROD = CASES / "hammer_rod.yaml"
MESH = ROOT / "meshes" / "hammer_rod.msh"
E, RHO, A, L = 210e9, 7800.0, 1e-4, 0.2      # the rod's (cases/hammer_rod.yaml, meshes/hammer_rod.py)
C = L / (E * A)                              # the rod's compliance at its end, m/N
M = 1000.0 * RHO * A * L                     # the heavy hammer's mass (156 kg)
GAP, DT, T_END = 1e-5, 8e-6, 4.5e-3
X0 = -GAP - 0.01                             # the hammer's centre's x at t = 0
DURATION = np.pi * np.sqrt(M * C)            # the contact's duration (3.83 ms)
PEAK = np.sqrt(M / C)                        # the peak force at v0 = 1 (1.28e5 N)
G = 9.81
FREE_DOFS = 3 * (81 * 4 - 4)                 # the rod's nodes less its held end's, 3 dofs each (960)


# -- the scenes ---------------------------------------------------------------------------------------
def _heavy(modes=2, t_end: float = T_END, dt: float = DT, **top) -> dict:
    """cases/hammer_rod.yaml with the hammer 1000 times the rod's mass, the rod modal with ``modes`` modes, no
    VTK, at ``dt`` to ``t_end``; ``top``: keys replaced."""
    data = yaml.safe_load(HAMMER_ROD.read_text())
    data["mesh"] = {"file": str(MESH)}
    data["materials"]["hammer"]["rho"] = 7.8e7
    data["bodies"] = {"hammer": {"model": "rigid"}, "rod": {"model": "modal", "modes": modes}}
    data["solver"].update(dt=dt, t_end=t_end)
    data["output"] = {"vtk": False, "every": 1000}
    data.update(top)
    return data


def _pair(**extra) -> dict:
    return {"name": "strike", "type": "pair", "nodes": ["hammer_face", "rod_end"], "normal": [1.0, 0.0, 0.0],
            "restitution": 0.0, **extra}


def _budget(h, scale: float, problems: list, closes: float = 1e-10) -> None:
    """The balance closed, the losses >= 0 (damping's non-decreasing), E <= E0 + W_ext; to ``closes`` of
    ``scale``."""
    if np.abs(h["energy_error"]).max() > closes * scale:
        problems.append(f"balance residual {np.abs(h['energy_error']).max():.3g} of {scale:.3g}")
    for loss in ("impact_loss", "contact_loss", "damping_loss", "friction_loss"):
        if loss in h and h[loss].min() < -closes * scale:
            problems.append(f"{loss} {h[loss].min():.3g}")
        if loss in h and np.diff(h[loss]).min() < -closes * scale:
            problems.append(f"{loss} falls by {np.diff(h[loss]).min():.3g} in a step")
    energy = h["kinetic"] + h["strain"]
    if np.max(energy - energy[0] - h["external_work"]) > closes * scale:
        problems.append(f"E > E0 + W_ext by {np.max(energy - energy[0] - h['external_work']):.3g}")


def _contact_time(h, name: str = "strike") -> float:
    on = np.flatnonzero(h[f"{name}.force"] > 0.0)
    return float(h["t"][on[-1]] - h["t"][on[0]]) if on.size else 0.0


def _pressed(h, problems: list, v0: float = 1.0, dt: float = DT, name: str = "strike", steps: float = 2.0,
             peak: float = 5e-3) -> None:
    """The heavy hammer's quasi-static answer: duration, peak, momentum by the impulses, nothing before the gap
    closes."""
    lasted = _contact_time(h, name)
    if abs(lasted - DURATION) > steps * dt:
        problems.append(f"contact time {lasted:.6g}, pi sqrt(M C) = {DURATION:.6g} ({(lasted - DURATION) / dt:.2f} "
                        f"steps off)")
    top = h[f"{name}.force"].max()
    if abs(top - v0 * PEAK) > peak * v0 * PEAK:
        problems.append(f"peak force {top:.6g}, v0 sqrt(M / C) = {v0 * PEAK:.6g}")
    early = h[f"{name}.force"][h["t"] < GAP / v0 - 0.5 * dt]
    if early.size and early.max() != 0.0:
        problems.append(f"a force {early.max():.3g} before the gap closes")
    gained = h["hammer.px"][-1] - h["hammer.px"][0]
    if abs(gained + h[f"{name}.impulse"].sum()) > 1e-9 * M * v0:
        problems.append(f"the hammer's momentum changed by {gained:.12g}, the impulses "
                        f"{h[f'{name}.impulse'].sum():.12g}")
    if not -v0 <= h["hammer.vx"][-1] < -0.97 * v0:
        problems.append(f"the hammer leaves at {h['hammer.vx'][-1]:.6g}, not just above -v0")


def _scale(h: dict, name: str, v0: float = 1.0) -> float:
    energy = max((h["kinetic"] + h["strain"]).max(), 1e-300)
    if name in ("energy_error", "external_work", "kinetic", "strain") or name.endswith("_loss"):
        return energy
    body, _, column = name.partition(".")
    if column in ("px", "py", "pz"):
        return max(M * v0, max(np.abs(h[f"{body}.p{c}"]).max() for c in "xyz" if f"{body}.p{c}" in h))
    if column in ("vx", "vy", "vz", "ux", "uy", "uz", "x", "y", "z"):
        return max(v0, *(np.abs(h[f"{body}.{column[:-1]}{c}"]).max() for c in "xyz" if f"{body}.{column[:-1]}{c}" in h))
    if column in ("wx", "wy", "wz"):
        return v0 / 0.01
    return max(np.abs(h[name]).max(), 1e-300)


def _differ(a: dict, b: dict, tol: float = 1e-10, v0: float = 1.0) -> str | None:
    """Where ``b`` (a run's last rows) parts from ``a``'s, column by column on its scale (None: nowhere)."""
    if set(a) != set(b):
        return f"columns differ: {sorted(set(a) ^ set(b))}"
    n = b["t"].size
    worst = max(((np.abs(a[k][-n:] - b[k]).max() / _scale(a, k, v0), k) for k in a))
    return None if worst[0] <= tol else f"{worst[1]} parts by {worst[0]:.3g} of its scale"


def _verdict(problems: list, detail: str = "") -> Verdict:
    return wrong("; ".join(problems)) if problems else ok(detail)


# -- the heavy hammer's exact answer ------------------------------------------------------------------
def _modes_probe(modes: int):
    def body(ctx):
        h, bad = solved(ctx, _heavy(modes))
        if bad:
            return bad
        problems: list = []
        _pressed(h, problems)
        _budget(h, 0.5 * M, problems)
        summary = json.loads((ctx.folder / "out" / "summary.json").read_text())
        if summary.get("modal_body") != "rod" or summary.get("modes") != modes:
            problems.append(f"summary modal_body {summary.get('modal_body')!r}, modes {summary.get('modes')!r}")
        return _verdict(problems, f"contact {_contact_time(h) / DURATION:.5f} pi sqrt(M C), "
                                  f"peak {h['strike.force'].max() / PEAK:.5f} sqrt(M / C)")
    return body


for _n in (1, 2, 6, 20):
    probe(CLS, f"heavy hammer on the modal rod, modes: {_n}: pi sqrt(M C), v0 sqrt(M / C), balance, momentum",
          timeout=300)(_modes_probe(_n))


@probe(CLS, f"the modal rod keeping all its {FREE_DOFS} modes (no static part): the rod in full's history to 1e-8 "
           "(the modes' own accuracy)", timeout=300)
def _all_modes(ctx):
    histories = []
    for rod, out in (({"model": "modal", "modes": FREE_DOFS}, "modal"), ({"model": "elastic"}, "full")):
        data = _heavy()
        data["bodies"]["rod"] = rod
        data["output"]["every"] = 1
        data["output"]["probes"] = {"tip": [0.0, 0.0, 0.0]}
        h, bad = solved(ctx, data, out=out)
        if bad:
            return bad
        histories.append(h)
    differ = _differ(histories[1], histories[0], tol=1e-8)
    return wrong(f"all modes against the rod in full: {differ}") if differ else ok()


@probe(CLS, "output.probes on the rod's end node: it follows the hammer's face while pressed, u = C F")
def _end_node(ctx):
    data = _heavy()
    data["output"]["probes"] = {"tip": [0.0, 0.0, 0.0]}
    data["output"]["every"] = 1
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    pressed = h["strike.force"] > 0.0
    if not pressed.any():
        return wrong("never pressed")
    face = h["hammer.x"] - X0 - GAP   # (the hammer's face past the rod's end at rest)
    scale = PEAK * C
    off = np.abs(h["tip.ux"][pressed] - face[pressed]).max()
    if off > 1e-6 * scale:
        problems.append(f"the end node parts from the hammer's face by {off:.3g} m while pressed (of {scale:.3g})")
    if np.abs(h["strike.gap"][pressed]).max() > 1e-6 * scale:
        problems.append(f"the pressed rows' gap {np.abs(h['strike.gap'][pressed]).max():.3g}")
    hooke = np.abs(h["tip.ux"][pressed] - C * h["strike.force"][pressed]).max()
    if hooke > 1e-6 * scale:
        problems.append(f"u - C F up to {hooke:.3g} m (of {scale:.3g})")
    if np.abs(h["tip.ux"][h["t"] < GAP - 0.5 * DT]).max() != 0.0:
        problems.append("the end node moved before the contact")
    return _verdict(problems)


# -- the count of modes refused -------------------------------------------------------------------------
def _refusal(make, *needles: str):
    def body(ctx):
        data = make(ctx)
        r, out = run_case(ctx, data)
        verdict = ctx.refused(r, *needles)
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    return body


for _value, _why in ((FREE_DOFS + 1, "more than the rod's free dofs"), (2.5, "2.5"), ("auto", "'auto'"), (-1, "-1"),
                     (True, "true")):
    probe(CLS, f"refused: bodies.rod.modes {_why}", timeout=300)(
        _refusal(lambda ctx, v=_value: _heavy(v, 1e-4), "bodies.rod.modes"))


# -- damping, loads -------------------------------------------------------------------------------------
def _damped(key: str, value: float):
    def body(ctx):
        loads = [{"body": "rod", "acceleration": [0.0, -G, 0.0]}]   # (sideways: the bending modes rung)
        h, bad = solved(ctx, _heavy(damping={key: value}, loads=loads))
        if bad:
            return bad
        problems: list = []
        if not h["damping_loss"][-1] > 0.0:
            problems.append("no damping loss in the rung, damped rod")
        _budget(h, 0.5 * M, problems)
        _pressed(h, problems, steps=4.0, peak=1e-2)
        return _verdict(problems, f"damping loss {h['damping_loss'][-1]:.3g}")
    return body


probe(CLS, "damping.alpha on the modal rod (gravity ringing its bending modes): the balance closes")(
    _damped("alpha", 50.0))
probe(CLS, "damping.beta on the modal rod (gravity ringing its bending modes): the balance closes")(
    _damped("beta", 1e-5))


@probe(CLS, "gravity on both bodies: the hammer falls at g exactly, the strike as without, the balance closes")
def _gravity(ctx):
    data = _heavy(loads=[{"body": b, "acceleration": [0.0, -G, 0.0]} for b in ("rod", "hammer")])
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    t = h["t"]
    if np.abs(h["hammer.vy"] + G * t).max() > 1e-9 * G * t[-1]:
        problems.append(f"hammer.vy off -g t by {np.abs(h['hammer.vy'] + G * t).max():.3g}")
    if not h["external_work"][-1] > 0.0:
        problems.append("gravity did no work")
    _pressed(h, problems, steps=4.0, peak=1e-2)
    _budget(h, 0.5 * M, problems)
    return _verdict(problems)


@probe(CLS, "a force F along the rod on its free end (hammer at rest): the end moves by F C from the first step")
def _end_force(ctx):
    F = 1000.0
    data = _heavy(t_end=2e-4, parameters={"v0": 0.0}, loads=[{"nodes": "rod_end", "force": [F, 0.0, 0.0]}])
    data["output"]["probes"] = {"tip": [0.0, 0.0, 0.0], "mid": [0.1, 0.0, 0.0]}
    data["output"]["every"] = 1
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    moved = h["t"] > 0.5 * DT
    for name, share in (("tip", 1.0), ("mid", 0.5)):
        off = np.abs(h[f"{name}.ux"][moved] - share * F * C).max()
        if off > 1e-6 * F * C:
            problems.append(f"{name}.ux off {share} F C = {share * F * C:.6g} by {off:.3g}")
    if np.abs(h["tip.uy"]).max() + np.abs(h["tip.uz"]).max() > 1e-9 * F * C:
        problems.append("the axial load bent the rod")
    if h["strike.force"].max() != 0.0 or np.abs(h["hammer.vx"]).max() != 0.0:
        problems.append("the hammer was touched")
    _budget(h, F * F * C, problems)
    return _verdict(problems, f"tip {h['tip.ux'][-1] / (F * C):.9f} F C")


@probe(CLS, "a force ramped in time (F t / T) along the rod on its free end: the end at C F(t) every step")
def _ramped_force(ctx):
    F, T = 1000.0, 2e-4
    data = _heavy(t_end=T, parameters={"v0": 0.0}, loads=[{"nodes": "rod_end", "force": [f"{F}*t/{T}", 0.0, 0.0]}])
    data["output"]["probes"] = {"tip": [0.0, 0.0, 0.0]}
    data["output"]["every"] = 1
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    exact = C * F * h["t"] / T
    off = np.abs(h["tip.ux"] - exact).max()
    if off > 1e-6 * F * C:
        problems.append(f"tip.ux off C F t / T by {off:.3g} (of {F * C:.3g})")
    rate = np.abs(h["tip.vx"][1:] - C * F / T).max()
    if rate > 1e-6 * C * F / T:
        problems.append(f"tip.vx off C F / T by {rate:.3g} (of {C * F / T:.3g})")
    _budget(h, F * F * C, problems)
    return _verdict(problems)


@probe(CLS, "an initial velocity along the modal rod (hammer at rest): its kinetic energy at t = 0, or refused, or "
           "a warning naming initial.velocity with the share the kept modes hold")
def _initial_velocity(ctx):
    data = _heavy(t_end=1e-4, parameters={"v0": 0.0},
                  initial={"velocity": [{"body": "rod", "value": [-1.0, 0.0, 0.0]}]})
    r, out = run_case(ctx, data)
    if r.status == 2:
        return ctx.refused(r, "initial.velocity")
    bad = ctx.succeeded(r)
    if bad:
        return bad
    from . import history

    h = history(out)
    want = 0.5 * RHO * A * L * (1.0 - 1.0 / 160)   # (the held end's half cell still: about 0.5 m v^2)
    kept = h["kinetic"][0] / want
    if abs(kept - 1.0) > 0.01 and "initial.velocity: the kept modes hold" in r.tail():
        return ok(f"warned: the kept modes hold {kept:.3g} of it")
    if abs(h["kinetic"][0] - want) > 0.01 * want:
        return wrong(f"accepted, the rod's kinetic energy at t = 0 is {h['kinetic'][0]:.3g} J, the given field's "
                     f"about {want:.3g} J (no warning: {r.tail() or 'nothing on stderr'})")
    return ok()


@probe(CLS, "an oblique frictionless strike (hammer at [v0, 0.5, 0]): hammer.vy kept exactly, the strike as along x")
def _oblique(ctx):
    h, bad = solved(ctx, _heavy(initial={"velocity": [{"body": "hammer", "value": ["v0", 0.5, 0.0]}]}))
    if bad:
        return bad
    problems: list = []
    if np.abs(h["hammer.vy"] - 0.5).max() > 1e-12:
        problems.append(f"hammer.vy off 0.5 by {np.abs(h['hammer.vy'] - 0.5).max():.3g}")
    _pressed(h, problems)
    _budget(h, 0.5 * M * 1.25, problems)
    return _verdict(problems)


@probe(CLS, "friction on the modal rod's pair, an oblique strike (hammer at [v0, 0.5, 0], mu 0.3): Coulomb's cone, "
           "the hammer's momentum changed by the impulses, friction loss >= 0, the balance closed")
def _oblique_friction(ctx):
    data = _heavy(initial={"velocity": [{"body": "hammer", "value": ["v0", 0.5, 0.0]}]})
    data["contacts"][0]["friction"] = 0.3
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    normal, tangential = h["strike.force"], h["strike.tangential_force"]
    if np.any(tangential > 0.3 * normal * (1 + 1e-9) + 1e-9 * normal.max()):
        problems.append(f"|F_T| above mu F_N by {np.max(tangential - 0.3 * normal):.3g}")
    if not tangential.max() > 0.0:
        problems.append("no friction force in an oblique strike")
    dt = DT
    for axis, column in (("x", None), ("y", "strike.ty"), ("z", "strike.tz")):
        gained = h[f"hammer.p{axis}"][-1] - h[f"hammer.p{axis}"][0]
        # (the normal impulse pushes the hammer back along -x; NAME.ty is the friction force on the pair's first
        # group's body, the hammer's)
        want = -h["strike.impulse"].sum() if column is None else h[column][1:].sum() * dt
        if abs(gained - want) > 1e-9 * M * 1.2:
            problems.append(f"hammer.p{axis} changed by {gained:.9g}, the impulses {want:.9g}")
    _budget(h, 0.5 * M * 1.25, problems)
    return _verdict(problems)


@probe(CLS, "output.every 7 against 1: the same rows at the common steps (the static part's velocity per step)")
def _every(ctx):
    rows = []
    for every in (1, 7):
        data = _heavy(t_end=1.5e-3)
        data["output"]["every"] = every
        data["output"]["probes"] = {"tip": [0.0, 0.0, 0.0]}
        h, bad = solved(ctx, data, out=f"every{every}")
        if bad:
            return bad
        rows.append(h)
    a, b = rows
    common = np.isin(np.round(a["t"] / DT).astype(int), np.round(b["t"] / DT).astype(int))
    if common.sum() != b["t"].size:
        return wrong(f"{b['t'].size} rows at every 7, {common.sum()} of them at steps of the every-1 run")
    skip = {"strike.impulse", "strike.force", "impact_loss"} & set(a)   # (impulses are summed between rows)
    worst = max(((np.abs(a[k][common] - b[k]).max() / _scale(a, k), k) for k in a if k not in skip))
    return wrong(f"{worst[1]} parts by {worst[0]:.3g} of its scale") if worst[0] > 1e-12 else ok()


# -- output options -------------------------------------------------------------------------------------
@probe(CLS, "VTK on: frames written (a modal rod's and the hammer's), the history as with VTK off")
def _vtk(ctx):
    off, bad = solved(ctx, _heavy(t_end=1e-3), out="off")
    if bad:
        return bad
    data = _heavy(t_end=1e-3)
    data["output"] = {"vtk": True, "every": 25}
    on, bad = solved(ctx, data, out="on")
    if bad:
        return bad
    problems: list = []
    differ = _differ(off, on, tol=0.0)
    if differ:
        problems.append(f"VTK changed the history: {differ}")
    out = ctx.folder / "on"
    if not (out / "results.pvd").is_file():
        return wrong(f"no results.pvd: {sorted(p.name for p in out.iterdir())}")
    frames = [d.get("file") for d in ET.parse(out / "results.pvd").iter("DataSet")]
    if len(frames) < 5 or any(not (out / f).is_file() for f in frames):
        problems.append(f"frames {frames}")
    return _verdict(problems, f"{len(frames)} frames")


@probe(CLS, "output.period: periods.csv written, its impulses summing to the history's")
def _period(ctx):
    data = _heavy()
    data["output"]["period"] = 1e-3
    data["output"]["every"] = 1
    h, bad = solved(ctx, data)
    if bad:
        return bad
    path = ctx.folder / "out" / "periods.csv"
    if not path.is_file():
        return wrong("no periods.csv")
    import csv

    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if len(rows) < 4:
        return wrong(f"{len(rows)} rows in periods.csv for 4.5 periods")
    column = next((k for k in rows[0] if "impulse" in k), None)
    if column is None:
        return wrong(f"no impulse column in periods.csv: {list(rows[0])}")
    total = sum(float(r[column]) for r in rows)
    whole = h["strike.impulse"][h["t"] <= len(rows) * 1e-3 + 0.5 * DT].sum()
    if abs(total - whole) > 1e-9 * M:
        return wrong(f"periods.csv's {column} sum to {total:.12g}, the history's {whole:.12g}")
    return ok(f"{len(rows)} periods")


# -- walls, the pair's writing ----------------------------------------------------------------------------
@probe(CLS, "a wall closing in at V on the modal rod's free end (hammer at rest): force (V t - gap) / C")
def _wall_on_rod(ctx):
    V, gap, dt = 1.0, 4e-6, 2e-6
    wall = {"name": "wall", "type": "obstacle", "nodes": "rod_end", "normal": [-1.0, 0.0, 0.0], "gap": gap,
            "restitution": 0.0, "motion": [f"{V}*t", 0.0, 0.0]}
    data = _heavy(t_end=2e-4, dt=dt, parameters={"v0": 0.0}, contacts=[_pair(), wall])
    data["output"]["every"] = 1
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    t = h["t"]
    pushed = t > gap / V + 0.5 * dt
    exact = (V * t - gap) / C
    off = np.abs(h["wall.force"][pushed] - exact[pushed]).max()
    if off > 1e-6 * exact[-1]:
        problems.append(f"force off (V t - gap) / C by {off:.3g} of {exact[-1]:.3g}")
    if h["wall.force"][t < gap / V - 0.5 * dt].max() != 0.0:
        problems.append("a force before the wall arrives")
    if h["strike.force"].max() != 0.0 or np.abs(h["hammer.vx"]).max() != 0.0:
        problems.append("the hammer was touched")
    _budget(h, h["external_work"][-1], problems)
    return _verdict(problems, f"force {h['wall.force'][-1] / exact[-1]:.9f} of exact")


@probe(CLS, "a wall closing in on the rigid hammer at rest, e = 1: it leaves at 2 V, the modal rod untouched")
def _wall_on_hammer(ctx):
    V, gap, e = 1.0, 4e-6, 1.0
    wall = {"name": "wall", "type": "obstacle", "nodes": "hammer_face", "normal": [1.0, 0.0, 0.0], "gap": gap,
            "restitution": e, "motion": [f"-{V}*t", 0.0, 0.0]}
    h, bad = solved(ctx, _heavy(t_end=4e-5, dt=4e-7, parameters={"v0": 0.0}, contacts=[_pair(), wall]))
    if bad:
        return bad
    problems: list = []
    impulse = h["wall.impulse"].sum()
    if abs(impulse - (1 + e) * M * V) > 1e-9 * M * V:
        problems.append(f"impulse {impulse:.9g}, (1 + e) M V = {(1 + e) * M * V:.9g}")
    if abs(h["hammer.vx"][-1] + (1 + e) * V) > 1e-9 * V:
        problems.append(f"the hammer leaves at {h['hammer.vx'][-1]:.9g}")
    if h["strike.force"].max() != 0.0 or np.abs(h["rod.px"]).max() != 0.0:
        problems.append("the modal rod moved or was struck")
    _budget(h, M * V * V, problems)
    return _verdict(problems)


@probe(CLS, "the pair written the other way round (rod_end first, normal -x): the same history")
def _reversed(ctx):
    a, bad = solved(ctx, _heavy(), out="forward")
    if bad:
        return bad
    b, bad = solved(ctx, _heavy(contacts=[_pair(nodes=["rod_end", "hammer_face"], normal=[-1.0, 0.0, 0.0])]),
                    out="reversed")
    if bad:
        return bad
    differ = _differ(a, b, tol=1e-9)
    return wrong(differ) if differ else ok()


@probe(CLS, "the pair coupled by its faces' mean motions (coupling: mean): the same quasi-static answer")
def _mean(ctx):
    h, bad = solved(ctx, _heavy(contacts=[_pair(coupling="mean")]))
    if bad:
        return bad
    problems: list = []
    _pressed(h, problems)
    _budget(h, 0.5 * M, problems)
    return _verdict(problems)


# -- a free modal hammer ------------------------------------------------------------------------------------
def _free_hammer(modes) -> dict:
    """The hammer (the rod's mass) modal and free, the rod rigid and floating (no support), at 0.4 us."""
    data = yaml.safe_load(HAMMER_ROD.read_text())
    data["mesh"] = {"file": str(MESH)}
    data["bodies"] = {"hammer": {"model": "modal", "modes": modes}, "rod": {"model": "rigid"}}
    data.pop("supports", None)
    data["solver"].update(dt=4e-7, t_end=1e-4)
    data["output"] = {"vtk": False, "every": 1}
    return data


@probe(CLS, "a free modal hammer (8 modes) on a floating rigid rod: total momentum conserved, the balance closed")
def _free(ctx):
    h, bad = solved(ctx, _free_hammer(8))
    if bad:
        return bad
    problems: list = []
    m = RHO * A * L
    total = h["hammer.px"] + h["rod.px"]
    if np.abs(total - total[0]).max() > 1e-10 * m:
        problems.append(f"hammer.px + rod.px drifts by {np.abs(total - total[0]).max():.3g} (of m v0 = {m:.3g})")
    if abs(total[0] - m) > 1e-9 * m:
        problems.append(f"the initial momentum {total[0]:.9g}, m v0 = {m:.9g}")
    if not h["strike.force"].max() > 0.0:
        problems.append("no strike")
    if not 0.9 < h["rod.vx"][-1] <= 1.0 + 1e-9:
        problems.append(f"the rod leaves at {h['rod.vx'][-1]:.6g} (two equal masses: about v0)")
    _budget(h, 0.5 * m, problems)
    return _verdict(problems, f"rod leaves at {h['rod.vx'][-1]:.5f}, hammer at {h['hammer.px'][-1] / m:.5f}")


probe(CLS, "refused: a free modal hammer keeping 4 modes (it moves in 6 rigid-body modes)", timeout=300)(
    _refusal(lambda ctx: _free_hammer(4), "bodies.hammer.modes"))
probe(CLS, "refused: a free modal hammer keeping 4 modes, the advice naming its true count (modes >= 6)",
      timeout=300)(_refusal(lambda ctx: _free_hammer(4), "bodies.hammer.modes", "modes >= 6"))
probe(CLS, "refused: a free modal hammer keeping 5 modes (one rigid-body mode short)", timeout=300)(
    _refusal(lambda ctx: _free_hammer(5), "bodies.hammer.modes", "modes >= 6"))


@probe(CLS, "a free modal hammer on 2 MPI ranks: the serial history to 1e-10", timeout=400)
def _free_two_ranks(ctx):
    a, bad = solved(ctx, _free_hammer(8), out="serial")
    if bad:
        return bad
    b, bad = solved(ctx, _free_hammer(8), mpi=2, out="mpi")
    if bad:
        return bad
    differ = _differ(a, b)
    return wrong(f"2 ranks: {differ}") if differ else ok()


# -- MPI, checkpoints, restarts, signals --------------------------------------------------------------------
@probe(CLS, "the heavy hammer on 2 MPI ranks: the serial history to 1e-10", timeout=400)
def _two_ranks(ctx):
    a, bad = solved(ctx, _heavy(t_end=2e-3), out="serial")
    if bad:
        return bad
    b, bad = solved(ctx, _heavy(t_end=2e-3), mpi=2, out="mpi")
    if bad:
        return bad
    differ = _differ(a, b)
    return wrong(f"2 ranks: {differ}") if differ else ok()


@probe(CLS, "restart (output.checkpoint_every: 50) in mid-contact: the modal scene continues exactly", timeout=300)
def _restart(ctx):
    data = _heavy()
    data["output"]["checkpoint_every"] = 50
    data["output"]["every"] = 1
    bad, worst = restart_parts(ctx, data, 1.6e-3, 3.2e-3)
    if bad:
        return bad
    return ok() if worst <= 1e-10 * M else wrong(f"the continued run parts from the whole one by {worst:.3g}")


@probe(CLS, "restart on 2 MPI ranks from a serial checkpoint: the serial run's history (or refused cleanly)",
       timeout=400)
def _restart_two_ranks(ctx):
    data = _heavy(t_end=1.6e-3)
    data["output"]["every"] = 1
    _, bad = solved(ctx, data, out="first")
    if bad:
        return bad
    data["solver"]["t_end"] = 3.2e-3
    whole, bad = solved(ctx, data, out="whole")
    if bad:
        return bad
    r, out = run_case(ctx, data, "--restart", ctx.folder / "first", mpi=2, out="continued")
    if r.status == 2:   # (mpirun adds its own lines: fem-impact's must be one)
        verdict = ctx.refused(r, "--restart", max_lines=40)
        own = [line for line in r.lines() if line.startswith("fem-impact:")]
        if verdict.kind == "ok" and (len(own) != 1 or out.exists()):
            return wrong(f"{len(own)} lines of fem-impact's, folder written: {out.exists()}: {r.tail()}")
        return verdict if verdict.kind != "ok" else ok(own[0])
    bad = ctx.succeeded(r)
    if bad:
        return bad
    from . import history

    differ = _differ(whole, history(out))
    return wrong(f"continued on 2 ranks: {differ}") if differ else ok()


@probe(CLS, "restart with bodies.rod.modes changed (2 -> 6): refused naming it, or the modes-6 run's history",
       timeout=300)
def _restart_modes(ctx):
    data = _heavy(t_end=1.6e-3)
    data["output"]["every"] = 1
    _, bad = solved(ctx, data, out="first")
    if bad:
        return bad
    ctx.keep(ctx.folder / "first")
    data = _heavy(6, t_end=3.2e-3)
    data["output"]["every"] = 1
    r, out = run_case(ctx, data, "--restart", ctx.folder / "first", out="continued")
    if r.status == 2:
        verdict = ctx.refused(r, "bodies.rod.modes")
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    bad = ctx.succeeded(r)
    if bad:
        return bad
    from . import history

    continued = history(out)
    whole, bad = solved(ctx, data, out="whole")
    if bad:
        return bad
    differ = _differ(whole, continued, tol=1e-9)
    return wrong(f"accepted, and the continued run is not the modes-6 run: {differ}") if differ else \
        ok("accepted, rebuilt: the modes-6 run's history")


@probe(CLS, "SIGINT to a serial modal run after a checkpoint: the checkpoint kept and named, continues exactly",
       timeout=400)
def _interrupted(ctx):
    name = "m"
    out = ctx.folder / name
    data = _heavy(t_end=2.0)   # (250000 steps: interrupted long before its end)
    data["output"]["checkpoint_every"] = 100
    saved = lambda: bool(list(ctx.folder.glob(f".{name}.checkpoint-*/checkpoint/state.json")))  # noqa: E731
    case = ctx.folder / "long.yaml"
    case.write_text(yaml.safe_dump({**data, "name": "long"}, sort_keys=False))
    r = ctx.run("run", case, "-q", "-o", out, signal_at=(saved, signal.SIGINT))
    if r.traceback:
        return Verdict("traceback", r.tail())
    lines = [line for line in r.lines() if line.startswith("fem-impact:")]
    if len(lines) != 1 or not lines[0].startswith("fem-impact: interrupted by "):
        return wrong(f"status {r.status}: {r.tail(4)}")
    if r.status != 128 + signal.SIGINT:
        return wrong(f"status {r.status}, expected {128 + signal.SIGINT}")
    kept = ctx.folder / f"{name}.checkpoint"
    if not (kept / "state.json").is_file() or f"--restart {kept}" not in lines[0]:
        return wrong(f"no checkpoint kept in {kept}, or not named: {lines[0]}")
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and [p for p in ctx.folder.iterdir() if p.name.startswith(f".{name}.")]:
        time.sleep(0.1)
    t0 = json.loads((kept / "state.json").read_text())["t"]
    data["solver"]["t_end"] = t0 + 100 * DT
    data["output"]["every"] = 1
    continued, bad = solved(ctx, {**data, "name": "long"}, "--restart", kept, out="continued")
    if bad:
        return bad
    whole, bad = solved(ctx, {**data, "name": "long"}, out="whole")
    if bad:
        return bad
    differ = _differ(whole, continued)
    return wrong(f"continued from the kept checkpoint: {differ}") if differ else ok(f"from t = {t0:.4g}")


# -- refusals -------------------------------------------------------------------------------------------
_THREE = '''
import sys
import gmsh
from fem_impact.fem.gmsh_utils import add_named_groups, write_msh

L, b, l, gap, cells = 0.2, 0.01, 0.02, 1e-5, 20
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.model.add("three")
occ = gmsh.model.occ
rod = occ.addBox(0.0, 0.0, 0.0, L, b, b)
rod2 = occ.addBox(0.0, 0.03, 0.0, L, b, b)
block = occ.addBox(-gap - l, 0.0, 0.0, l, b, b)
occ.synchronize()
for volume, along in ((rod, cells), (rod2, cells), (block, 2)):
    surfaces = gmsh.model.getBoundary([(3, volume)], combined=False, oriented=False)
    for curve in {tag for _, tag in gmsh.model.getBoundary(surfaces, combined=False, oriented=False)}:
        x0, _, _, x1, _, _ = gmsh.model.getBoundingBox(1, curve)
        gmsh.model.mesh.setTransfiniteCurve(curve, (along if abs(x1 - x0) > 0.5 * gap else 1) + 1)
    for _, surface in surfaces:
        gmsh.model.mesh.setTransfiniteSurface(surface)
        gmsh.model.mesh.setRecombine(2, surface)
    gmsh.model.mesh.setTransfiniteVolume(volume)
tol = 2.5e-6

def face(x, y):
    return [t for _, t in gmsh.model.getEntitiesInBoundingBox(x - tol, y - tol, -tol, x + tol, y + b + tol, b + tol, 2)]

add_named_groups(3, {"rod": [rod], "rod2": [rod2], "hammer": [block]})
add_named_groups(2, {"rod_end": face(0.0, 0.0), "rod_fixed": face(L, 0.0), "rod2_fixed": face(L, 0.03),
                     "hammer_face": face(-gap, 0.0)})
gmsh.model.mesh.generate(3)
write_msh(sys.argv[1])
gmsh.finalize()
'''


def _three_bodies(ctx) -> Path:
    """A mesh of three bodies: the hammer, the rod (hammer_rod.msh's, 20 cells) and a second rod beside it."""
    def build(folder):
        script = folder / "three.py"
        script.write_text(_THREE)
        r = ctx.run(script, folder / "three.msh", python=True)
        if r.status != 0 or not (folder / "three.msh").is_file():
            raise RuntimeError(f"the three bodies' mesh could not be made: {r.tail()}")
    return ctx.shared("modal-three-bodies", build) / "three.msh"


def _three(ctx, bodies: dict) -> dict:
    data = _heavy(t_end=1e-4, bodies=bodies)
    data["mesh"] = {"file": str(_three_bodies(ctx))}
    data["supports"] = [{"nodes": "rod_fixed", "fix": "all"}, {"nodes": "rod2_fixed", "fix": "all"}]
    data["materials"]["rod2"] = dict(data["materials"]["rod"])
    return data


@probe(CLS, "the three bodies' mesh runs (a rigid hammer, a modal rod, a rigid second rod): the control case",
       timeout=300)
def _three_ok(ctx):
    data = _three(ctx, {"hammer": {"model": "rigid"}, "rod": {"model": "modal", "modes": 2},
                        "rod2": {"model": "rigid"}})
    data["supports"] = [{"nodes": "rod_fixed", "fix": "all"}]
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    _budget(h, 0.5 * M, problems)
    if not h["strike.force"].max() > 0.0:
        problems.append("no strike")
    return _verdict(problems)


def _with(change):
    def make(ctx):
        data = _heavy(t_end=1e-4)
        change(data)
        return data
    return make


for _name, _make, _needles in (
        ("a modal rod without rigid bodies (the hammer elastic)",
         _with(lambda d: d["bodies"].update(hammer={"model": "elastic"})), ("bodies.rod.model",)),
        ("a modal rod and a modal hammer (no rigid body)",
         _with(lambda d: d["bodies"].update(hammer={"model": "modal", "modes": 8})), ("bodies",)),
        ("a modal body beside a body in full (3 bodies: rod2 elastic)",
         lambda ctx: _three(ctx, {"hammer": {"model": "rigid"}, "rod": {"model": "modal", "modes": 2}}),
         ("bodies.rod.model", "rod2")),
        ("two modal bodies beside a rigid hammer (3 bodies)",
         lambda ctx: _three(ctx, {"hammer": {"model": "rigid"}, "rod": {"model": "modal", "modes": 2},
                                  "rod2": {"model": "modal", "modes": 2}}), ("bodies.rod2.model",)),
        ("modes on the rigid hammer", _with(lambda d: d["bodies"]["hammer"].update(modes=2)), ("bodies.hammer.modes",)),
        ("modes on an elastic rod", _with(lambda d: d["bodies"].update(rod={"model": "elastic", "modes": 2})),
         ("bodies.rod.modes",)),
        ("no modes on the modal rod", _with(lambda d: d["bodies"].update(rod={"model": "modal"})),
         ("bodies.rod",)),
        ("a support on the rigid hammer's nodes",
         _with(lambda d: d["supports"].append({"nodes": "hammer_face", "fix": ["y"]})), ("supports",)),
        ("a moving support on the modal rod",
         _with(lambda d: d.update(supports=[{"nodes": "rod_fixed", "fix": ["x", "y", "z"],
                                             "displacement": ["1e-3*t", 0, 0]}])), ("supports",)),
):
    probe(CLS, f"refused: {_name}", timeout=300)(_refusal(_make, *_needles))
