"""Class ``mixed-scenes``: scenes mixing rigid and elastic bodies (``bodies: {NAME: {model: rigid}}`` beside
elastic ones): cases/hammer_rod.yaml (a rigid hammer striking a 3D steel rod held at its far end, a node-to-node
pair) as it is and combined with damping, gravity, a force on the hammer, a moving wall on either body,
friction, the output's options, 2 MPI ranks, checkpoints, restarts, a damaged checkpoint and SIGINT; a rigid
block sliding on an elastic slab (2D, a mesh of the probe's own); and what a mixed scene refuses.

Each probe judges an exact answer where there is one, or a refusal in one line naming the key:

- the hammer (mass M = the rod's) on the rod (impedance Z = rho c A, c = sqrt(E / rho)): the contact force
  Z v0 exp(-Z t / M) within 2 % of Z v0 from six cell transits after the contact to six before the wave's
  return at 2 L / c, the impulse until then M v0 (1 - exp(-2 Z L / (c M))) within 1 %; the hammer's
  momentum changes by the impulses reported; the balance closes, the losses are >= 0, E <= E0 + W_ext;
- loads on the rigid hammer alone (gravity, a force on its face): its exact rigid motion before contact;
- a wall closing in at V on the hammer at rest: it leaves at (1 + e) V, the wall's work V times the impulse;
  on the rod's free end: the force Z V until the wave returns;
- what a mixed scene does not take is refused (status 2, naming the key, nothing written).
"""

from __future__ import annotations

import json
import shutil
import signal
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import yaml

from . import CASES, ROOT, Verdict, ok, probe, restart_parts, run_case, solved, wrong

HAMMER_ROD = CASES / "hammer_rod.yaml"
MESH = ROOT / "meshes" / "hammer_rod.msh"
E, RHO, A, L = 210e9, 7800.0, 1e-4, 0.2      # the rod's (cases/hammer_rod.yaml, meshes/hammer_rod.py)
C = np.sqrt(E / RHO)
Z = RHO * C * A                              # the rod's impedance, kg/s
M, GAP, DT = RHO * A * L, 1e-5, 4e-7         # the hammer's mass (the rod's), its distance, the case's step
J = (M * (0.01 ** 2 + 0.01 ** 2) / 12, M * (0.02 ** 2 + 0.01 ** 2) / 12)   # about x; about y and z
CENTRE = (-GAP - 0.01, 0.005, 0.005)         # the hammer's centre at t = 0
RETURN = 2.0 * L / C                         # the wave's return to the struck end
TRANSIT = L / 80 / C                         # a cell's transit
G = 9.81


# -- the scenes ---------------------------------------------------------------------------------------
def _hammer(t_end: float = 3e-4, **top) -> dict:
    """cases/hammer_rod.yaml as a dict (its mesh by its absolute path), no VTK, to ``t_end``; ``top``: keys
    replaced."""
    data = yaml.safe_load(HAMMER_ROD.read_text())
    data["mesh"] = {"file": str(MESH)}
    data["solver"]["t_end"] = t_end
    data["output"] = {"vtk": False}
    data.update(top)
    return data


def _pair(**extra) -> dict:
    return {"name": "strike", "type": "pair", "nodes": ["hammer_face", "rod_end"], "normal": [1.0, 0.0, 0.0],
            "restitution": 0.0, **extra}


def _budget(h, scale: float, problems: list, closes: float = 1e-9, friction_step: float = 0.0) -> None:
    """The balance closed, the losses >= 0 (friction: each step's within ``friction_step`` of ``scale``, the
    documented mean-velocity booking, and >= 0 in total), E <= E0 + W_ext; all to ``closes`` of ``scale``."""
    if np.abs(h["energy_error"]).max() > closes * scale:
        problems.append(f"balance residual {np.abs(h['energy_error']).max():.3g} of {scale:.3g}")
    for loss in ("impact_loss", "contact_loss", "damping_loss"):
        if loss in h and h[loss].min() < -closes * scale:
            problems.append(f"{loss} {h[loss].min():.3g}")
    if "damping_loss" in h and np.diff(h["damping_loss"]).min() < -closes * scale:
        problems.append(f"damping_loss falls by {np.diff(h['damping_loss']).min():.3g} in a step")
    if "friction_loss" in h:
        friction = h["friction_loss"]
        if friction.min() < -closes * scale or np.diff(friction).min() < -(friction_step + closes) * scale:
            problems.append(f"friction loss {friction.min():.3g}, a step of {np.diff(friction).min():.3g}")
    energy = h["kinetic"] + h["strain"]
    if np.max(energy - energy[0] - h["external_work"]) > closes * scale:
        problems.append(f"E > E0 + W_ext by {np.max(energy - energy[0] - h['external_work']):.3g}")


def _struck(h, v0: float, problems: list, name: str = "strike") -> None:
    """The hammer's impedance force (see the module's docstring), nothing before the gap closes, the hammer's
    momentum changed by the impulses."""
    t0 = GAP / v0
    s = h["t"] - t0
    a, b = np.maximum(s - DT, 0.0), np.maximum(s, 0.0)
    exact = M * v0 * (np.exp(-Z * a / M) - np.exp(-Z * b / M)) / DT   # (the exact force's mean over the step)
    error = np.abs(h[f"{name}.force"] - exact) / (Z * v0)
    inside = (s > 6 * TRANSIT) & (s <= RETURN - 6 * TRANSIT)
    if not inside.any() or error[inside].max() > 0.02:
        problems.append(f"force off Z v0 exp(-Z t / M) by {error[inside].max():.3g} of Z v0")
    early = h[f"{name}.force"][s <= 0.0]
    if early.size and early.max() != 0.0:
        problems.append(f"a force {early.max():.3g} before the gap closes")
    impulse = h[f"{name}.impulse"][s <= RETURN].sum()
    want = M * v0 * (1.0 - np.exp(-Z * RETURN / M))
    if abs(impulse - want) > 0.01 * want:
        problems.append(f"impulse until the return {impulse:.6g}, exact {want:.6g}")
    gained = h["hammer.px"][-1] - h["hammer.px"][0]
    if abs(gained + h[f"{name}.impulse"].sum()) > 1e-9 * M * v0:
        problems.append(f"the hammer's momentum changed by {gained:.9g}, the impulses {h[f'{name}.impulse'].sum():.9g}")


def _scale(h: dict, name: str, v0: float = 1.0) -> float:
    """A column's physical scale (round-off in a column of zeros is not a difference)."""
    energy = max((h["kinetic"] + h["strain"]).max(), 1e-300)
    if name in ("energy_error", "external_work", "kinetic", "strain") or name.endswith("_loss"):
        return energy
    body, _, column = name.partition(".")
    if column in ("px", "py", "pz"):
        return max(M * v0, max(np.abs(h[f"{body}.p{c}"]).max() for c in "xyz" if f"{body}.p{c}" in h))
    if column in ("vx", "vy", "vz", "ux", "uy", "uz", "x", "y", "z"):
        return max(v0, *(np.abs(h[f"{body}.{column[:-1]}{c}"]).max() for c in "xyz" if f"{body}.{column[:-1]}{c}" in h))
    if column in ("wx", "wy", "wz"):
        return v0 / 0.01   # (the hammer's speed over its half length)
    return max(np.abs(h[name]).max(), 1e-300)


def _differ(a: dict, b: dict, tol: float = 1e-10, v0: float = 1.0) -> str | None:
    """Where ``b`` (a run's last rows) parts from ``a``'s, column by column on its scale (None: nowhere)."""
    if set(a) != set(b):
        return f"columns differ: {sorted(set(a) ^ set(b))}"
    n = b["t"].size
    worst = max(((np.abs(a[k][-n:] - b[k]).max() / _scale(a, k, v0), k) for k in a))
    return None if worst[0] <= tol else f"{worst[1]} parts by {worst[0]:.3g} of its scale"


# -- the hammer's exact answers -----------------------------------------------------------------------
@probe("mixed-scenes", "hammer_rod as it is: the impedance force, the impulse, the balance, the hammer's mass")
def _as_is(ctx):
    h, bad = solved(ctx, _hammer())
    if bad:
        return bad
    problems: list = []
    _struck(h, 1.0, problems)
    _budget(h, 0.5 * M, problems)
    summary = json.loads((ctx.folder / "out" / "summary.json").read_text())
    body = summary.get("rigid_bodies", {}).get("hammer", {})
    if abs(body.get("mass", 0.0) - M) > 1e-12 * M or not np.allclose(body.get("centre", []), CENTRE, rtol=1e-12):
        problems.append(f"summary rigid_bodies.hammer {body}")
    if np.abs(h["hammer.py"]).max() + np.abs(h["hammer.pz"]).max() > 1e-12 * M:
        problems.append("the hammer gained a sideways momentum in a frictionless strike along x")
    return wrong("; ".join(problems)) if problems else ok(f"impulse {h['strike.impulse'].sum():.5f}")


@probe("mixed-scenes", "hammer_rod at v0 = 2.5 (parameters.v0): the force scales, from the earlier contact")
def _faster(ctx):
    data = _hammer(parameters={"v0": 2.5})
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    _struck(h, 2.5, problems)
    _budget(h, 0.5 * M * 2.5 ** 2, problems)
    return wrong("; ".join(problems)) if problems else ok()


@probe("mixed-scenes", "the pair written the other way round (rod_end first, normal -x): the same history")
def _reversed(ctx):
    a, bad = solved(ctx, _hammer(1.2e-4), out="forward")
    if bad:
        return bad
    data = _hammer(1.2e-4, contacts=[_pair(nodes=["rod_end", "hammer_face"], normal=[-1.0, 0.0, 0.0])])
    b, bad = solved(ctx, data, out="reversed")
    if bad:
        return bad
    differ = _differ(a, b, tol=1e-9)
    return wrong(differ) if differ else ok()


@probe("mixed-scenes", "the pair coupled by its faces' mean motions (coupling: mean): the plane wave's force")
def _mean(ctx):
    h, bad = solved(ctx, _hammer(contacts=[_pair(coupling="mean")]))
    if bad:
        return bad
    problems: list = []
    _struck(h, 1.0, problems)
    _budget(h, 0.5 * M, problems)
    return wrong("; ".join(problems)) if problems else ok()


@probe("mixed-scenes", "solver.level: position is taken as the velocity level (as documented): the same history")
def _level(ctx):
    a, bad = solved(ctx, _hammer(1.2e-4), out="default")
    if bad:
        return bad
    data = _hammer(1.2e-4)
    data["solver"]["level"] = "position"
    b, bad = solved(ctx, data, out="position")
    if bad:
        return bad
    differ = _differ(a, b, tol=1e-12)
    return wrong(differ) if differ else ok()


def _damped(key: str, value: float):
    def body(ctx):
        h, bad = solved(ctx, _hammer(1.5e-4, damping={key: value}))
        if bad:
            return bad
        problems: list = []
        before = h["t"] < GAP - 0.5 * DT
        if np.abs(h["hammer.vx"][before] - 1.0).max() > 0.0:
            problems.append(f"the rigid hammer slowed before the contact: vx {h['hammer.vx'][before].min():.15g}")
        if not h["damping_loss"][-1] > 0.0:
            problems.append("no damping loss in the struck rod")
        _budget(h, 0.5 * M, problems)
        return wrong("; ".join(problems)) if problems else ok(f"damping loss {h['damping_loss'][-1]:.3g}")
    return body


probe("mixed-scenes", "damping.alpha on the rod: the hammer untouched before contact, the balance closes")(
    _damped("alpha", 2000.0))
probe("mixed-scenes", "damping.beta on the rod: the hammer untouched before contact, the balance closes")(
    _damped("beta", 1e-7))


@probe("mixed-scenes", "gravity on both bodies: the hammer falls at g exactly, the strike unchanged along x")
def _gravity(ctx):
    data = _hammer(loads=[{"body": b, "acceleration": [0.0, -G, 0.0]} for b in ("rod", "hammer")])
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    t = h["t"]
    if np.abs(h["hammer.vy"] + G * t).max() > 1e-9 * G * t[-1]:
        problems.append(f"hammer.vy off -g t by {np.abs(h['hammer.vy'] + G * t).max():.3g}")
    fall = CENTRE[1] - 0.5 * G * t ** 2
    if np.abs(h["hammer.y"] - fall).max() > 1e-12:
        problems.append(f"hammer.y off the parabola by {np.abs(h['hammer.y'] - fall).max():.3g}")
    if not h["external_work"][-1] > 0.0:
        problems.append("gravity did no work")
    _struck(h, 1.0, problems)
    _budget(h, 0.5 * M, problems)
    return wrong("; ".join(problems)) if problems else ok()


@probe("mixed-scenes", "a sideways force on the hammer's face node group: its resultant and moment, exactly")
def _face_force(ctx):
    F = 1000.0
    data = _hammer(2e-5, parameters={"v0": 0.0}, loads=[{"nodes": "hammer_face", "force": [0.0, F, 0.0]}])
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    t = h["t"]
    vy, wz = F * t / M, 0.01 * F * t / J[1]   # (the face 0.01 ahead of the centre: a moment 0.01 F about z)
    if np.abs(h["hammer.vy"] - vy).max() > 1e-9 * vy[-1]:
        problems.append(f"hammer.vy {h['hammer.vy'][-1]:.9g}, F t / M = {vy[-1]:.9g}")
    if np.abs(h["hammer.wz"] - wz).max() > 1e-6 * wz[-1]:
        problems.append(f"hammer.wz {h['hammer.wz'][-1]:.9g}, 0.01 F t / Jz = {wz[-1]:.9g}")
    if h["strike.force"].max() != 0.0:
        problems.append("the hammer touched the rod")
    work = h["external_work"][-1]
    if abs(work - h["kinetic"][-1]) > 1e-9 * work:
        problems.append(f"the force's work {work:.9g}, the kinetic energy {h['kinetic'][-1]:.9g}")
    _budget(h, work, problems)
    return wrong("; ".join(problems)) if problems else ok()


def _wall_on_hammer(e: float):
    def body(ctx):
        V, gap = 1.0, 4e-6
        wall = {"name": "wall", "type": "obstacle", "nodes": "hammer_face", "normal": [1.0, 0.0, 0.0], "gap": gap,
                "restitution": e, "motion": [f"-{V}*t", 0.0, 0.0]}
        data = _hammer(3e-5, parameters={"v0": 0.0}, contacts=[_pair(), wall])
        h, bad = solved(ctx, data)
        if bad:
            return bad
        problems: list = []
        impulse = h["wall.impulse"].sum()
        if abs(impulse - (1 + e) * M * V) > 1e-9 * M * V:
            problems.append(f"impulse {impulse:.9g}, exact (1 + e) M V = {(1 + e) * M * V:.9g}")
        if abs(h["hammer.vx"][-1] + (1 + e) * V) > 1e-9 * V:
            problems.append(f"the hammer leaves at {h['hammer.vx'][-1]:.9g}, exact {-(1 + e) * V}")
        first = h["t"][np.flatnonzero(h["wall.impulse"] > 0)]
        if first.size and abs(first[0] - gap / V) > DT * (1 + 1e-9):
            problems.append(f"first contact at {first[0]:.6g}, exact {gap / V:.6g}")
        if abs(h["external_work"][-1] - V * impulse) > 1e-9 * V * impulse:
            problems.append(f"the wall's work {h['external_work'][-1]:.9g}, V x impulse {V * impulse:.9g}")
        if h["strike.force"].max() != 0.0 or np.abs(h["rod.px"]).max() != 0.0:
            problems.append("the rod moved or was struck")
        _budget(h, M * V * V, problems)
        return wrong("; ".join(problems)) if problems else ok()
    return body


for _e in (0.0, 1.0):
    probe("mixed-scenes", f"a wall closing in on the rigid hammer at rest, e = {_e}: it leaves at (1 + e) V")(
        _wall_on_hammer(_e))


@probe("mixed-scenes", "a wall closing in on the rod's free end (hammer at rest): the force Z V until the return")
def _wall_on_rod(ctx):
    V, gap = 1.0, 4e-6
    wall = {"name": "wall", "type": "obstacle", "nodes": "rod_end", "normal": [-1.0, 0.0, 0.0], "gap": gap,
            "restitution": 0.0, "motion": [f"{V}*t", 0.0, 0.0]}
    h, bad = solved(ctx, _hammer(1e-4, parameters={"v0": 0.0}, contacts=[_pair(), wall]))
    if bad:
        return bad
    problems: list = []
    s = h["t"] - gap / V
    inside = (s > 6 * TRANSIT) & (s <= RETURN - 6 * TRANSIT)
    error = np.abs(h["wall.force"][inside] - Z * V).max() / (Z * V)
    if error > 0.02:
        problems.append(f"force off Z V by {error:.3g} of Z V")
    if abs(h["external_work"][-1] - V * h["wall.impulse"].sum()) > 1e-9 * V * h["wall.impulse"].sum():
        problems.append("the wall's work is not V times its impulse")
    if np.abs(h["hammer.vx"]).max() != 0.0 or h["strike.force"].max() != 0.0:
        problems.append("the hammer at rest moved, or was struck by the rod moving away from it")
    _budget(h, h["external_work"][-1], problems)
    return wrong("; ".join(problems)) if problems else ok(f"force {h['wall.force'][inside].mean() / Z:.4f} Z V")


@probe("mixed-scenes", "friction on the pair, an oblique strike: Coulomb's cone, momentum by the impulses, budget")
def _friction(ctx):
    mu = 0.3
    data = _hammer(1.5e-4, contacts=[_pair(friction=mu)],
                   initial={"velocity": [{"body": "hammer", "value": ["v0", 0.5, 0.0]}]})
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    N, T = h["strike.force"], h["strike.tangential_force"]
    if np.any(T > mu * N * (1 + 1e-9) + 1e-9 * Z):
        problems.append(f"outside the cone: T / N up to {np.max(T[N > 0] / N[N > 0]):.9g}, mu = {mu}")
    if not np.any((N > 0) & (T > 0.99 * mu * N)):
        problems.append("never slipped, though struck sideways at half its speed")
    dy = h["hammer.py"][-1] - h["hammer.py"][0]
    if abs(dy - h["strike.ty"].sum() * DT) > 1e-9 * M:
        problems.append(f"the hammer's y momentum changed by {dy:.9g}, its friction impulses "
                        f"{h['strike.ty'].sum() * DT:.9g}")
    if not h["friction_loss"][-1] > 0.0:
        problems.append("no friction loss")
    _budget(h, 0.5 * M * 1.25, problems, friction_step=1e-6)
    return wrong("; ".join(problems)) if problems else ok(f"friction loss {h['friction_loss'][-1]:.3g}")


# -- output options -------------------------------------------------------------------------------------
@probe("mixed-scenes", "output.period: periods.csv's impulses, impacts, losses and the hammer's mean speed")
def _period(ctx):
    T = 5e-5
    data = _hammer()
    data["output"]["period"] = T
    h, bad = solved(ctx, data)
    if bad:
        return bad
    out = ctx.folder / "out"
    p = _csv(out / "periods.csv")
    problems: list = []
    if not np.allclose(p["t"], T * np.arange(1, 7), rtol=1e-12):
        problems.append(f"periods end at {p['t']}")
    if abs(p["strike.impulse"].sum() - h["strike.impulse"].sum()) > 1e-9 * h["strike.impulse"].sum():
        problems.append(f"the periods' impulse {p['strike.impulse'].sum():.9g}, "
                        f"history's {h['strike.impulse'].sum():.9g}")
    impacts = json.loads((out / "summary.json").read_text())["impacts"]["strike"]
    if p["strike.impacts"].sum() != impacts:
        problems.append(f"{p['strike.impacts'].sum():g} impacts in the periods, {impacts} in the summary")
    t, losses = h["t"], h["contact_loss"] + h["impact_loss"]
    for k, end in enumerate(p["t"]):
        a, b = np.argmin(np.abs(t - end + T)), np.argmin(np.abs(t - end))
        mean = np.sum(0.5 * (h["hammer.vx"][a + 1:b + 1] + h["hammer.vx"][a:b]) * np.diff(t[a:b + 1])) / T
        if abs(p["hammer.vx_mean"][k] - mean) > 1e-9:
            problems.append(f"period {k + 1}: hammer.vx_mean {p['hammer.vx_mean'][k]:.9g}, the history's {mean:.9g}")
        if abs(p["losses"][k] - (losses[b] - losses[a])) > 1e-9 * 0.5 * M:
            problems.append(f"period {k + 1}: losses {p['losses'][k]:.9g}, the history's {losses[b] - losses[a]:.9g}")
    return wrong("; ".join(problems[:3])) if problems else ok()


def _csv(path) -> dict:
    import csv

    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    values = np.array(rows[1:], dtype=float)
    return {name: values[:, k] for k, name in enumerate(rows[0])}


@probe("mixed-scenes", "output.probes on the rigid hammer (its translation) and on the rod's end (the hammer's speed)")
def _probes(ctx):
    data = _hammer(1.5e-4)
    data["output"]["probes"] = {"back": [-GAP - 0.02, 0.0, 0.0], "centre": list(CENTRE), "tip": [0.0, 0.005, 0.005]}
    h, bad = solved(ctx, data)
    if bad:
        return bad
    problems: list = []
    missing = [f"{p}.{c}" for p in ("back", "centre", "tip") for c in ("ux", "vx") if f"{p}.{c}" not in h]
    if missing:
        return wrong(f"no columns {missing}")
    moved = h["hammer.x"] - CENTRE[0]
    for p in ("back", "centre"):
        if np.abs(h[f"{p}.ux"] - moved).max() > 1e-9 * np.abs(moved).max():
            problems.append(f"{p}.ux parts from hammer.x - x0 by {np.abs(h[f'{p}.ux'] - moved).max():.3g}")
        if np.abs(h[f"{p}.vx"] - h["hammer.vx"]).max() > 1e-9:
            problems.append(f"{p}.vx parts from hammer.vx by {np.abs(h[f'{p}.vx'] - h['hammer.vx']).max():.3g}")
    # Newton's law at the velocity level on the pushed steps (docs/theory.md s. 4.3): the closing rate at the
    # step's end -e' times the one at its start, e' = e = 0 while the row approaches, 1 while it separates
    closing = h["hammer.vx"] - h["tip.vx"]
    pushed = np.flatnonzero(h["strike.force"][1:] > 0.0) + 1
    start = closing[pushed - 1]
    law = closing[pushed] + np.where(start >= 0.0, 0.0, 1.0) * start
    if np.abs(law).max() > 1e-9:
        k = pushed[np.argmax(np.abs(law))]
        problems.append(f"Newton's law off by {np.abs(law).max():.3g} m/s at t = {h['t'][k]:.6g} (the closing rate "
                        f"{closing[k - 1]:.6g} at the step's start, {closing[k]:.6g} at its end)")
    if np.abs(h["tip.ux"][h["t"] < GAP]).max() != 0.0:
        problems.append("the rod's end moved before the contact")
    return wrong("; ".join(problems)) if problems else ok()


def _frame(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A .vtu frame's points, u and v."""
    arrays = {}
    points = None
    for node in ET.parse(path).iter("DataArray"):
        values = np.array(node.text.split(), dtype=float)
        if node.get("Name") in ("u", "v"):
            arrays[node.get("Name")] = values.reshape(-1, 3)
        elif points is None and node.get("NumberOfComponents") == "3" and node.get("Name") is None:
            points = values.reshape(-1, 3)
    return points, arrays["u"], arrays["v"]


@probe("mixed-scenes", "VTK on: the frames show the rigid hammer's motion, the history as with VTK off")
def _vtk(ctx):
    off, bad = solved(ctx, _hammer(1e-4), out="off")
    if bad:
        return bad
    data = _hammer(1e-4)
    data["output"] = {"vtk": True, "every": 50}
    on, bad = solved(ctx, data, out="on")
    if bad:
        return bad
    problems: list = []
    differ = _differ(off, on, tol=0.0)
    if differ:
        problems.append(f"VTK changed the history: {differ}")
    out = ctx.folder / "on"
    frames = [(float(d.get("timestep")), d.get("file")) for d in ET.parse(out / "results.pvd").iter("DataSet")]
    times = [t for t, _ in frames]
    if not np.allclose(times, 50 * DT * np.arange(6), rtol=1e-9, atol=1e-15):
        return wrong(f"frames at {times}, expected every 50 steps to 1e-4")
    last = ET.parse(out / frames[-1][1]).getroot()
    pieces = [p.get("Source") for p in last.iter("Piece")]
    for piece in pieces:
        points, u, v = _frame(out / piece)
        hammer = points[:, 0] < -0.5 * GAP
        if not hammer.any():
            problems.append("no hammer node in the last frame")
            break
        if np.abs(u[hammer, 0] - (on["hammer.x"][-1] - CENTRE[0])).max() > 1e-9 * 1e-4 or \
                np.abs(v[hammer, 0] - on["hammer.vx"][-1]).max() > 1e-9:
            problems.append(f"the last frame's hammer u_x {u[hammer, 0].mean():.9g}, v_x {v[hammer, 0].mean():.9g}; "
                            f"the history's {on['hammer.x'][-1] - CENTRE[0]:.9g}, {on['hammer.vx'][-1]:.9g}")
    return wrong("; ".join(problems)) if problems else ok(f"{len(frames)} frames")


# -- MPI, checkpoints, restarts, signals ----------------------------------------------------------------
@probe("mixed-scenes", "hammer_rod on 2 MPI ranks: the serial history", timeout=300)
def _two_ranks(ctx):
    a, bad = solved(ctx, _hammer(), out="serial")
    if bad:
        return bad
    b, bad = solved(ctx, _hammer(), mpi=2, out="mpi")
    if bad:
        return bad
    differ = _differ(a, b)
    return wrong(f"2 ranks: {differ}") if differ else ok()


@probe("mixed-scenes", "restart (output.checkpoint_every: 10): a mixed scene continues exactly", timeout=300)
def _restart(ctx):
    data = _hammer()
    data["output"]["checkpoint_every"] = 10
    bad, worst = restart_parts(ctx, data, 6e-5, 1.5e-4)
    if bad:
        return bad
    return ok() if worst <= 1e-12 else wrong(f"the continued run parts from the whole one by {worst:.3g}")


@probe("mixed-scenes", "restart on 2 MPI ranks from a 2-rank checkpoint: the serial run's history", timeout=400)
def _restart_two_ranks(ctx):
    data = _hammer(6e-5)
    _, bad = solved(ctx, data, mpi=2, out="first")
    if bad:
        return bad
    data["solver"]["t_end"] = 1.5e-4
    whole, bad = solved(ctx, data, out="whole")
    if bad:
        return bad
    continued, bad = solved(ctx, data, "--restart", ctx.folder / "first", mpi=2, out="continued")
    if bad:
        return bad
    differ = _differ(whole, continued)
    return wrong(f"continued on 2 ranks: {differ}") if differ else ok()


def _saved(ctx) -> Path:
    """A saved run of the hammer to 4e-5 (built once, copied into the probe's folder)."""
    def build(folder):
        r, _ = run_case(ctx, _hammer(4e-5), out=str(folder / "run"))
        if r.status != 0:
            raise RuntimeError(f"the saved run failed: {r.tail()}")
    return ctx.shared("mixed-saved", build) / "run"


def _restart_changed(what: str, change, *needles: str):
    def body(ctx):
        saved = _saved(ctx)
        ctx.keep(saved)
        data = _hammer(1e-4)
        change(data)
        r, out = run_case(ctx, data, "--restart", saved)
        verdict = ctx.refused(r, *needles, "--restart")
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    probe("mixed-scenes", f"restart with {what}: refused, naming the key")(body)


_restart_changed("the hammer made elastic", lambda d: d.update(bodies={"hammer": {"model": "elastic"}}), "bodies")
_restart_changed("the rod made rigid too (its support taken off)",
                 lambda d: d.update(bodies={"hammer": {"model": "rigid"}, "rod": {"model": "rigid"}}, supports=[]),
                 "bodies")
_restart_changed("v0 changed", lambda d: d["parameters"].update(v0=2.0), "parameters.v0")
_restart_changed("the hammer's density changed", lambda d: d["materials"]["hammer"].update(rho=50000.0),
                 "materials.hammer.rho")


@probe("mixed-scenes", "restart from a checkpoint whose rank-0.h5 was cut short: one line naming it, nothing written")
def _damaged(ctx):
    saved = _saved(ctx)
    folder = ctx.folder / "damaged"
    shutil.copytree(saved, folder)
    file = folder / "checkpoint" / "rank-0.h5"
    data = file.read_bytes()
    file.write_bytes(data[:len(data) // 2])
    ctx.keep(folder)
    r, out = run_case(ctx, _hammer(1e-4), "--restart", folder)
    verdict = ctx.refused(r, str(file), "--restart")
    lines = [line for line in r.lines() if line.startswith("fem-impact:")]
    if verdict.kind == "ok" and len(lines) != 1:
        return wrong(f"{len(lines)} lines of fem-impact's: {r.tail()}")
    if verdict.kind == "ok" and out.exists():
        return wrong(f"refused, yet {out} was written")
    return verdict


def _interrupted(mpi: int):
    @probe("mixed-scenes", f"SIGINT to {'mpirun -n 2' if mpi else 'a serial run'} after a checkpoint: the earlier "
                           f"result kept, the checkpoint continues exactly", timeout=400)
    def body(ctx):
        name = "m"
        out = ctx.folder / name
        r, _ = run_case(ctx, _hammer(2e-5), out=name)   # (the earlier result, which the interrupted run must keep)
        bad = ctx.succeeded(r)
        if bad:
            return bad
        ctx.keep(out)
        data = _hammer(0.05)   # (125000 steps: interrupted long before its end)
        data["output"]["checkpoint_every"] = 100
        saved = lambda: bool(list(ctx.folder.glob(f".{name}.checkpoint-*/checkpoint/state.json")))  # noqa: E731
        case = ctx.folder / "long.yaml"
        case.write_text(yaml.safe_dump({**data, "name": "long"}, sort_keys=False))
        r = ctx.run("run", case, "-q", "-o", out, mpi=mpi, signal_at=(saved, signal.SIGINT))
        if r.traceback:
            return Verdict("traceback", r.tail())
        lines = [line for line in r.lines() if line.startswith("fem-impact:")]
        if len(lines) != 1 or not lines[0].startswith("fem-impact: interrupted by "):
            return wrong(f"status {r.status}: {r.tail(4)}")
        if not mpi and r.status != 128 + signal.SIGINT:
            return wrong(f"status {r.status}, expected {128 + signal.SIGINT}")
        kept = ctx.folder / f"{name}.checkpoint"
        if not (kept / "state.json").is_file() or f"--restart {kept}" not in lines[0]:
            return wrong(f"no checkpoint kept in {kept}, or not named: {lines[0]}")
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and [p for p in ctx.folder.iterdir() if p.name.startswith(f".{name}.")]:
            time.sleep(0.1)
        left = [p.name for p in ctx.folder.iterdir() if p.name.startswith(f".{name}.")]
        if left:
            return wrong(f"left beside the folder: {left}")
        t0 = json.loads((kept / "state.json").read_text())["t"]
        data["solver"]["t_end"] = t0 + 100 * DT
        continued, bad = solved(ctx, {**data, "name": "long"}, "--restart", kept, mpi=mpi, out="continued")
        if bad:
            return bad
        if abs(continued["t"][0] - t0) > 1e-9 * t0:
            return wrong(f"the continued history starts at {continued['t'][0]}, the checkpoint is at {t0}")
        whole, bad = solved(ctx, {**data, "name": "long"}, out="whole")
        if bad:
            return bad
        differ = _differ(whole, continued)
        return wrong(f"continued from the kept checkpoint: {differ}") if differ else ok(f"from t = {t0:.4g}")
    return body


_interrupted(0)
_interrupted(2)


# -- a 2D scene: a rigid block on an elastic slab ---------------------------------------------------------


def _slab_mesh(ctx) -> Path:
    """meshes/block_on_slab.py's slab (body ``slab``, node groups ``base`` and ``top``) under a block (body
    ``block``, node groups ``bottom`` and ``lid``, its top), written once by Gmsh in a process of its own."""
    def build(folder):
        r = ctx.run(str(ROOT / "meshes" / "block_on_slab.py"), "-o", folder / "slab.msh", python=True)
        if r.status != 0 or not (folder / "slab.msh").is_file():
            raise RuntimeError(f"the slab's mesh could not be made: {r.tail()}")
    return ctx.shared("mixed-slab-mesh", build) / "slab.msh"


def _slab(ctx, mu: float = 0.3, v0: float = 0.5) -> dict:
    return {"name": "slab", "mesh": {"file": str(_slab_mesh(ctx))},
            "material": {"E": 210e9, "rho": 7800.0, "nu": 0.3, "area": 0.01},
            "bodies": {"block": {"model": "rigid"}},
            "initial": {"velocity": [{"body": "block", "value": [v0, 0.0]}]},
            "supports": [{"nodes": "base", "fix": "all"}],
            "loads": [{"body": b, "acceleration": [0.0, -G]} for b in ("slab", "block")],
            "contacts": [{"name": "face", "type": "pair", "nodes": ["top", "bottom"], "normal": [0.0, 1.0],
                          "restitution": 0.0, "friction": mu}],
            "solver": {"dt": 2e-4, "t_end": 0.25}, "output": {"vtk": False}}


@probe("mixed-scenes", "2D: a rigid block sliding on an elastic slab stops where mu g says, mu N while it slips",
       timeout=300)
def _slab_sliding(ctx):
    mu, v0 = 0.3, 0.5
    h, bad = solved(ctx, _slab(ctx, mu, v0))
    if bad:
        return bad
    problems: list = []
    t, v = h["t"], h["block.vx"]
    stopped = np.flatnonzero(v <= 1e-3 * v0)
    if not stopped.size:
        return wrong(f"never stopped: {v[-1]:.4g} at the end")
    stop = t[stopped[0]]
    if abs(stop - v0 / (mu * G)) > 0.01 * v0 / (mu * G):
        problems.append(f"stops at {stop:.5g}, v0 / (mu g) = {v0 / (mu * G):.5g}")
    sliding = np.flatnonzero((v[:-1] > 1e-2 * v0) & (v[1:] > 1e-2 * v0)) + 1
    pushed = sliding[h["face.force"][sliding] > 0.0]
    if pushed.size and np.abs(h["face.tangential_force"][pushed] - mu * h["face.force"][pushed]).max() > \
            1e-9 * h["face.force"][pushed].max():
        problems.append("a slipping step's friction force is not mu times the normal one")
    m = 0.2 * 0.05 * 0.01 * 7800.0
    _budget(h, 0.5 * m * v0 ** 2, problems, friction_step=1e-6)
    return wrong("; ".join(problems)) if problems else ok(f"stops at {stop:.4f} s")


# -- refusals ---------------------------------------------------------------------------------------------
def _refusal(change, *needles: str, slab: bool = False):
    def body(ctx):
        data = _slab(ctx) if slab else _hammer(2e-5)
        change(ctx, data)
        r, out = run_case(ctx, data)
        verdict = ctx.refused(r, *needles)
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    return body


def _set(path: str, value):
    """A change setting the key ``path`` (dots; list items by index) to ``value``."""
    def change(ctx, data):
        *head, last = path.split(".")
        node = data
        for key in head:
            node = node[int(key)] if isinstance(node, list) else node.setdefault(key, {})
        node[int(last) if isinstance(node, list) else last] = value
    return change


def _from_saved(ctx, data):
    data["initial"] = {"from": str(_saved(ctx))}


for _name, _change, _needles in (
        ("bodies naming a body the mesh lacks", _set("bodies.anvil", {"model": "rigid"}), ("bodies", "anvil")),
        ("a model typo (rigd)", _set("bodies.hammer.model", "rigd"), ("bodies.hammer.model", "rigd")),
        ("an unknown key in a body's entry", _set("bodies.hammer.mass", 1.0), ("bodies.hammer", "mass")),
        ("a support on the rigid hammer's nodes",
         _set("supports", [{"nodes": "rod_fixed", "fix": "all"}, {"nodes": "hammer_face", "fix": ["y"]}]),
         ("supports",)),
        ("the held rod made rigid", _set("bodies.rod", {"model": "rigid"}), ("supports",)),
        ("solver.method: newmark", _set("solver.method", "newmark"), ("solver.method", "moreau_jean")),
        ("solver.method: central_difference (lumped mass)",
         lambda ctx, d: d["solver"].update(method="central_difference", mass="lumped"),
         ("solver.method", "moreau_jean")),
        ("solver.method: modal", lambda ctx, d: d["solver"].update(method="modal", modes=10),
         ("solver.method", "moreau_jean")),
        ("solver.theta: 0.7", _set("solver.theta", 0.7), ("solver.theta",)),
        ("solver.mass: redistributed", _set("solver.mass", "redistributed"), ("solver.mass",)),
        ("an elastic stop (law: elastic_stop)", lambda ctx, d: d["contacts"].__setitem__(0, {
            **{k: v for k, v in d["contacts"][0].items() if k != "restitution"}, "law": "elastic_stop",
            "stiffness": 1e9}), ("contacts", "Newton")),
        ("an initial displacement of the rod",
         _set("initial.displacement", [{"body": "rod", "value": [1e-6, 0.0, 0.0]}]), ("initial.displacement",)),
        ("initial.from a saved run", _from_saved, ("initial.from",)),
        ("a moving support on the rod",
         _set("supports", [{"nodes": "rod_fixed", "fix": ["x", "y", "z"], "displacement": ["1e-3*t", 0, 0]}]),
         ("supports",)),
):
    probe("mixed-scenes", f"refused: {_name}")(_refusal(_change, *_needles))

probe("mixed-scenes", "refused: a pair within the rigid block (2D)")(_refusal(
    lambda ctx, d: d["contacts"].append({"name": "inside", "type": "pair", "nodes": ["bottom", "lid"],
                                         "normal": [0.0, 1.0]}), "contacts", "one rigid body", slab=True))
