"""Class ``moving-obstacles``: obstacles given a motion (``contacts[].motion``), 1D/2D/3D, every method,
the reduced model, a mean coupling, a plane through a point, friction, 2 MPI ranks, restart and the
response study.

Each probe judges an exact answer where there is one, or a refusal in one line naming the key:

- a free rod at rest (E = rho = L = 1) struck by a wall closing in at v: the contact starts at gap / v,
  lasts 2 L / c and gives the impulse 2 m v; the wall's work is v times that impulse; the balance closes,
  the contact's losses are >= 0 and E <= E0 + W_ext;
- a wall moving along itself as well, frictionless: the same history as the wall moving along its normal
  alone (a frictionless plane's sliding does nothing);
- a block at rest on a belt moving at vb (mu, gravity): carried at mu g;
- what cannot be done is refused (status 2, naming the key) or stops in one line (status 3).
"""

from __future__ import annotations

import csv

import numpy as np

from . import CASES, ok, probe, restart_parts, run_case, solved, wrong

V, GAP, CELLS = 1.0, 0.1, 40
METHODS = {
    "moreau_jean": {"method": "moreau_jean"},
    "newmark": {"method": "newmark"},
    "central_difference": {"method": "central_difference", "mass": "lumped"},
    "modal": {"method": "modal", "modes": 12},
}
MODES = {1: 12, 2: 40, 3: 40}   # (the 2D and 3D rods' bending modes come among the axial ones)


def _mass(dim: int) -> float:
    """The rod's mass: rho L A (A = 1 in 1D, thickness 10 x height 0.1 in 2D, 0.1 x 0.1 in 3D)."""
    return 0.01 if dim == 3 else 1.0


def _rod(dim: int, method: str, motion=None, coupling: str = "each", point: bool = False, mu: float = 0.0) -> dict:
    """A free rod at rest, a wall GAP beyond its left end closing in at V along -x (its normal)."""
    mesh = {"shape": "bar", "dim": dim, "length": 1.0, "cells": CELLS}
    if dim >= 2:
        mesh["height"] = 0.1
    if dim == 3:
        mesh["width"] = 0.1
    material = {"E": 1.0, "rho": 1.0, "nu": 0.0, **({"area": 1.0 if dim == 1 else 10.0} if dim < 3 else {})}
    contact = {"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0] + [0.0] * (dim - 1),
               "restitution": 0.0, "motion": motion or [f"{V}*t"] + [0.0] * (dim - 1)}
    if point:
        contact["point"] = [-GAP] + [0.0] * (dim - 1)
    else:
        contact["gap"] = GAP
    if coupling != "each":
        contact["coupling"] = coupling
    if mu:
        contact["friction"] = mu
    dt = 0.5 / CELLS if method != "central_difference" else (0.5 if dim < 3 else 0.2) / CELLS
    solver = {**METHODS[method], "dt": dt, "t_end": 2.6}
    if method == "modal":
        solver["modes"] = MODES[dim]
    return {"name": "rod", "mesh": mesh, "material": material, "initial": {"velocity": [0.0] * dim},
            "contacts": [contact], "solver": solver,
            "output": {"vtk": False, "every": 1}}


def _budget(h, scale: float, problems: list, closes: float = 1e-9) -> None:
    """The balance closed, the contact's losses >= 0, E <= E0 + W_ext (all to ``closes`` of ``scale``)."""
    if np.abs(h["energy_error"]).max() > closes * scale:
        problems.append(f"balance residual {np.abs(h['energy_error']).max():.3g} of {scale:.3g}")
    contact = h.get("impact_loss", 0.0) + h.get("contact_loss", 0.0)
    if np.min(contact) < -closes * scale:
        problems.append(f"the contact's loss goes to {np.min(contact):.3g}")
    if "friction_loss" in h and h["friction_loss"].min() < -closes * scale:
        problems.append(f"friction loss {h['friction_loss'].min():.3g}")
    energy = h["kinetic"] + h["strain"]
    if np.max(energy - energy[0] - h["external_work"]) > closes * scale:
        problems.append("E > E0 + W_ext")


def _struck(h, dt: float, m: float, problems: list) -> None:
    """The rod struck by the wall: start, duration, impulse 2 m v, the wall's work v times the impulse."""
    t, impulse = h["t"], h["wall.impulse"]
    push = np.flatnonzero(impulse > 0.0)
    if not push.size:
        problems.append("the wall never touched the rod")
        return
    if abs(t[push[0]] - GAP / V) > dt * (1 + 1e-9):
        problems.append(f"first contact at {t[push[0]]:.6g}, exact {GAP / V:.6g}")
    if abs(t[push[-1]] - t[push[0]] - 2.0) > 0.15:
        problems.append(f"contact for {t[push[-1]] - t[push[0]]:.4g}, exact 2 L / c = 2")
    if abs(impulse.sum() - 2.0 * m * V) > 0.03 * 2.0 * m * V:
        problems.append(f"impulse {impulse.sum():.6g}, exact 2 m v = {2 * m * V:g}")
    if abs(h["external_work"][-1] - V * impulse.sum()) > 1e-6 * V * impulse.sum():
        problems.append(f"the wall's work {h['external_work'][-1]:.9g}, v x impulse {V * impulse.sum():.9g}")


def _wall(dim: int, method: str, **keys):
    def body(ctx):
        data = _rod(dim, method, **keys)
        h, bad = solved(ctx, data)
        if bad:
            return bad
        problems: list = []
        _struck(h, data["solver"]["dt"], _mass(dim), problems)
        _budget(h, 2.0 * _mass(dim) * V * V, problems)
        return wrong("; ".join(problems)) if problems else ok(f"impulse {h['wall.impulse'].sum():.4f}")
    return body


for _dim in (1, 2, 3):
    for _method in METHODS:
        probe("moving-obstacles", f"{_dim}D free rod struck by a wall closing in, {_method}")(_wall(_dim, _method))
probe("moving-obstacles", "2D free rod struck by a wall closing in, coupling: mean")(_wall(2, "moreau_jean",
                                                                                           coupling="mean"))
probe("moving-obstacles", "2D free rod struck by a wall through a point closing in")(_wall(2, "moreau_jean",
                                                                                           point=True))
probe("moving-obstacles", "3D free rod struck by a wall through a point closing in, modal")(_wall(3, "modal",
                                                                                                  point=True))


@probe("moving-obstacles", "2D free rod struck by a wall closing in, on 2 MPI ranks as serially")
def _two_ranks(ctx):
    data = _rod(2, "moreau_jean")
    a, bad = solved(ctx, data, out="serial")
    if bad:
        return bad
    b, bad = solved(ctx, data, mpi=2, out="mpi")
    if bad:
        return bad
    energy = max((a["kinetic"] + a["strain"]).max(), 1e-300)

    def scale(name):   # (an energy term on the energy; a vector's component on the vector's largest)
        if name in ("energy_error", "external_work") or name.endswith("_loss"):
            return energy
        if name[-1] in "xyz" and name[-2] in "uvp":
            return max(np.abs(a[c]).max() for c in a if c[:-1] == name[:-1])
        return max(np.abs(a[name]).max(), 1e-300)

    worst = max(np.abs(a[k] - b[k]).max() / scale(k) for k in a)
    return ok(f"{worst:.2g}") if worst <= 1e-10 else wrong(f"2 ranks part from serial by {worst:.3g} of a column")


@probe("moving-obstacles", "frictionless wall sliding along itself too: as the wall moving along its normal")
def _sliding_frictionless(ctx):
    a, bad = solved(ctx, _rod(2, "moreau_jean"), out="normal")
    if bad:
        return bad
    b, bad = solved(ctx, _rod(2, "moreau_jean", motion=[f"{V}*t", "3*sin(40*t)"]), out="sliding")
    if bad:
        return bad
    worst = max(np.abs(a[k] - b[k]).max() for k in ("wall.impulse", "left.ux", "kinetic") if k in a)
    return ok() if worst <= 1e-12 else wrong(f"a frictionless plane's sliding changed the history by {worst:.3g}")


@probe("moving-obstacles", "2D block at rest on a belt (friction) is carried at mu g")
def _belt(ctx):
    mu, g, vb = 0.3, 9.81, 1.0
    data = {"name": "belt", "mesh": {"shape": "bar", "dim": 2, "length": 0.2, "height": 0.05, "cells": 8},
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.0, "area": 1.0},
            "loads": [{"body": "all", "acceleration": [0.0, -g]}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0],
                          "gap": 0.0, "friction": mu, "motion": [f"{vb}*t", 0.0]}],
            "solver": {"dt": 0.002, "t_end": 0.5}, "output": {"vtk": False, "every": 1}}
    h, bad = solved(ctx, data)
    if bad:
        return bad
    mass = 0.2 * 0.05 * 1000.0
    t, v = h["t"], h["bar.px"] / mass
    problems: list = []
    sliding = (t > 0.05) & (t < 0.3)
    if not np.allclose(v[sliding], mu * g * t[sliding], rtol=0.01):
        problems.append(f"speed {v[sliding][-1]:.4g} at t = {t[sliding][-1]:.3g}, mu g t = "
                        f"{mu * g * t[sliding][-1]:.4g}")
    if not np.allclose(v[t > 0.4], vb, rtol=0.01):
        problems.append(f"not carried with the belt: {v[-1]:.4g}, vb = {vb}")
    _budget(h, mass * vb * vb, problems, closes=1e-8)
    return wrong("; ".join(problems)) if problems else ok()


def _refusal(change: dict, status: int, *needles: str):
    def body(ctx):
        data = _rod(1, "moreau_jean")
        data["contacts"][0].update(change)
        r, out = run_case(ctx, data)
        verdict = ctx.refused(r, *needles, status=status)
        if verdict.kind == "ok" and status == 2 and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    return body


for _name, _change, _status, _needles in (
        ("a motion of 2 axes on a 1D rod", {"motion": ["t", "t"]}, 2, ("contacts[0].motion", "2 expression")),
        ("a motion in x", {"motion": ["x*t"]}, 2, ("contacts[0].motion[0]", "x")),
        ("a motion that is not an expression", {"motion": [[1]]}, 2, ("contacts[0].motion[0]",)),
        ("a motion on a pair", {"type": "pair", "nodes": ["left", "right"], "motion": ["t"]}, 2,
         ("contacts[0].motion", "obstacle")),
        ("a motion that blows up at t = 0.2", {"motion": ["1/(0.2 - t)"]}, 3, ("contact wall", "not finite")),
        ("a motion whose velocity blows up", {"motion": ["sqrt(abs(t - 0.2))"]}, 3, ("contact wall", "not finite")),
):
    probe("moving-obstacles", f"refused: {_name}")(_refusal(_change, _status, *_needles))


@probe("moving-obstacles", "restart: a moving wall's run continues exactly; a changed motion is refused")
def _restart(ctx):
    data = _rod(1, "moreau_jean")
    bad, worst = restart_parts(ctx, data, 1.0, 2.6)
    if bad:
        return bad
    if worst > 1e-12:
        return wrong(f"the continued run parts from the whole one by {worst:.3g}")
    data["contacts"][0]["motion"] = ["2*t"]
    r, _ = run_case(ctx, data, "--restart", ctx.folder / "first", out="changed")
    return ctx.refused(r, "contacts.0.motion.0", "--restart")


@probe("moving-obstacles", "study response over a shaken table's amplitude, --flight events and --flight scheme")
def _response(ctx):
    """cases/bouncing_ball.yaml: period 1 at Gamma = 1.3, period 2 at 1.55 (the period doubling at 1.527), with
    both kinds of flight; the event-driven one's orbit meets the table at T/2 with the orbit's speed."""
    verdicts = []
    for flight, settle in (("events", "300"), ("scheme", "150")):
        out = ctx.folder / flight
        r = ctx.run("study", "response", CASES / "bouncing_ball.yaml", "--vary", "parameters.Gamma=1.3,1.55",
                    "--frequency", "f", "--settle", settle, "--periods", "4", "--flight", flight, "-q", "-o", out,
                    timeout=600)
        bad = ctx.succeeded(r)
        if bad:
            return bad
        with open(out / "response.csv", newline="") as f:
            periods = {float(row["parameters.Gamma"]): int(row["period"]) for row in csv.DictReader(f)}
        if periods != {1.3: 1, 1.55: 2}:
            verdicts.append(f"--flight {flight}: periods {periods}, expected 1 at 1.3 and 2 at 1.55")
    return wrong("; ".join(verdicts)) if verdicts else ok()


@probe("moving-obstacles", "a reference (B2) refuses a moving wall: no study measures it against the fixed one")
def _reference(ctx):
    data = _rod(1, "moreau_jean")
    data["reference"] = "b2"
    data["initial"] = {"velocity": [-1.0]}
    case = ctx.folder / "rod.yaml"
    import yaml

    case.write_text(yaml.safe_dump(data, sort_keys=False))
    r = ctx.run("study", "convergence", case, "--vary", "mesh.cells=20,40", "-q", "-o", ctx.folder / "study")
    return ctx.refused(r, "reference", "motion")


@probe("moving-obstacles", "restart under another output.period: the periods start again, not mixed")
def _period_changed(ctx):
    data = _rod(1, "moreau_jean")
    data["output"]["period"] = 0.5
    data["solver"]["t_end"] = 1.3
    _, bad = solved(ctx, data, out="first")
    if bad:
        return bad
    data["solver"]["t_end"] = 2.6
    data["output"]["period"] = 0.4
    r, out = run_case(ctx, data, "--restart", ctx.folder / "first", out="continued")
    bad = ctx.succeeded(r)
    if bad:
        return bad
    import csv

    with open(out / "periods.csv", newline="") as f:
        ends = [float(row["t"]) for row in csv.DictReader(f)]
    want = [2.0, 2.4]   # (from 1.3: [1.2, 1.6) seen in part, then [1.6, 2.0), [2.0, 2.4))
    return ok() if [round(t, 9) for t in ends] == want else wrong(f"periods ending at {ends}, expected {want}")
