"""Class ``rigid-bodies``: scenes of rigid bodies (``bodies: {NAME: {model: rigid}}``), 2D and 3D, with
obstacles fixed, through a point and moving, friction, gravity, 2 MPI ranks, restart, VTK, and what a rigid
scene refuses.

Each probe judges an exact answer where there is one, or a refusal in one line naming the key:

- a block launched along a floor under gravity (mu): it decelerates at mu g and stops at v0 / (mu g), its
  friction loss 1/2 m v0^2, with its spin and its height unchanged;
- a block dropped flat onto a floor (e): it leaves at e times its speed, unturned;
- a free block spun in 3D: its kinetic energy kept;
- what a rigid scene does not take yet is refused (status 2, naming the key).
"""

from __future__ import annotations

import numpy as np

from . import ok, probe, restart_parts, run_case, solved, wrong

G = 9.81


def _block(dim: int, **extra) -> dict:
    mesh = {"shape": "bar", "dim": dim, "length": 0.2, "height": 0.05, "cells": 8}
    if dim == 3:
        mesh["width"] = 0.05
    material = {"E": 1e7, "rho": 1000.0, "nu": 0.0, **({"area": 1.0} if dim == 2 else {})}
    pad = [0.0] * (dim - 2)
    data = {"name": "block", "mesh": mesh, "material": material, "bodies": {"bar": {"model": "rigid"}},
            "loads": [{"body": "all", "acceleration": [0.0, -G] + pad}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0] + pad,
                          "gap": 0.0}],
            "solver": {"dt": 0.002, "t_end": 0.9}, "output": {"vtk": False}}
    for key, value in extra.items():
        data[key] = value
    return data


def _budget(h, scale: float, problems: list) -> None:
    if np.abs(h["energy_error"]).max() > 1e-9 * scale:
        problems.append(f"balance residual {np.abs(h['energy_error']).max():.3g} of {scale:.3g}")
    for loss in ("impact_loss", "contact_loss", "friction_loss"):
        if loss in h and h[loss].min() < -1e-12 * scale:
            problems.append(f"{loss} {h[loss].min():.3g}")
    energy = h["kinetic"] + h["strain"]
    if np.max(energy - energy[0] - h["external_work"]) > 1e-9 * scale:
        problems.append("E > E0 + W_ext")


def _sliding(dim: int, mpi: int = 0, moving: bool = False):
    def body(ctx):
        mu, v0, vb = 0.3, 2.0, 1.0
        data = _block(dim, initial={"velocity": [v0] + [0.0] * (dim - 1)})
        data["contacts"][0]["friction"] = mu
        if moving:   # the floor a belt at vb along the block's motion: it slides at v0 - vb relative
            data["contacts"][0]["motion"] = [f"{vb}*t"] + [0.0] * (dim - 1)
        h, bad = solved(ctx, data, mpi=mpi)
        if bad:
            return bad
        problems: list = []
        t, v = h["t"], h["bar.vx"]
        stop = (v0 - (vb if moving else 0.0)) / (mu * G)
        sliding = t < 0.9 * stop
        want = v0 - mu * G * t[sliding]
        if np.abs(v[sliding] - want).max() > 1e-6 * v0:
            problems.append(f"speed off mu g by {np.abs(v[sliding] - want).max():.3g}")
        final = vb if moving else 0.0
        if abs(v[-1] - final) > 1e-6 * v0:
            problems.append(f"ends at {v[-1]:.6g}, expected {final}")
        if np.abs(h["bar.y"] - 0.025).max() > 1e-6 * 0.05:
            problems.append(f"the centre's height moved by {np.abs(h['bar.y'] - 0.025).max():.3g}")
        _budget(h, 0.5 * 10.0 * v0 * v0 * (0.05 if dim == 3 else 1.0), problems)
        return wrong("; ".join(problems)) if problems else ok()
    return body


for _dim in (2, 3):
    probe("rigid-bodies", f"{_dim}D rigid block slides to rest under friction")(_sliding(_dim))
    probe("rigid-bodies", f"{_dim}D rigid block slides on a belt until it moves with it")(_sliding(_dim, moving=True))
probe("rigid-bodies", "2D rigid block slides to rest under friction, 2 MPI ranks")(_sliding(2, mpi=2))


def _dropped(dim: int, e: float):
    def body(ctx):
        v0 = 1.0
        data = _block(dim, initial={"velocity": [0.0, -v0] + [0.0] * (dim - 2)}, loads=[])
        data["contacts"][0].update({"gap": 0.01, "restitution": e})
        data["solver"].update({"dt": 1e-4, "t_end": 0.02})
        h, bad = solved(ctx, data)
        if bad:
            return bad
        problems: list = []
        if abs(h["bar.vy"][-1] - e * v0) > 1e-9:
            problems.append(f"leaves at {h['bar.vy'][-1]:.9g}, e v0 = {e * v0}")
        spin = ["bar.omega"] if dim == 2 else ["bar.wx", "bar.wy", "bar.wz"]
        if max(np.abs(h[s]).max() for s in spin) > 1e-9:
            problems.append("it turned")
        if abs(h["floor.impulse"].sum() - (1 + e) * v0 * (10.0 if dim == 2 else 0.5)) > 1e-9:
            problems.append(f"impulse {h['floor.impulse'].sum():.9g}")
        _budget(h, 0.5 * (10.0 if dim == 2 else 0.5) * v0 * v0, problems)
        return wrong("; ".join(problems)) if problems else ok()
    return body


for _dim in (2, 3):
    for _e in (0.0, 0.5, 1.0):
        probe("rigid-bodies", f"{_dim}D rigid block dropped flat, e = {_e}")(_dropped(_dim, _e))


@probe("rigid-bodies", "3D free block spun, VTK written, the energy kept")
def _spin(ctx):
    w = (3.0, 20.0, 7.0)
    c = (0.1, 0.025, 0.025)
    velocity = [f"{w[1]}*(z-{c[2]}) - {w[2]}*(y-{c[1]})", f"{w[2]}*(x-{c[0]}) - {w[0]}*(z-{c[2]})",
                f"{w[0]}*(y-{c[1]}) - {w[1]}*(x-{c[0]})"]
    data = _block(3, initial={"velocity": velocity}, loads=[], contacts=[])
    data["solver"].update({"dt": 1e-3, "t_end": 0.5})
    data["output"] = {"vtk": True, "every": 50}
    h, bad = solved(ctx, data)
    if bad:
        return bad
    drift = np.abs(h["kinetic"] - h["kinetic"][0]).max() / h["kinetic"][0]
    if drift > 1e-10:
        return wrong(f"kinetic energy drifts by {drift:.3g}")
    if not (ctx.folder / "out" / "results.pvd").is_file():
        return wrong("no results.pvd")
    return ok(f"drift {drift:.2g}")


@probe("rigid-bodies", "restart: a rigid scene continues exactly")
def _restart(ctx):
    data = _block(2, initial={"velocity": [2.0, 0.0]})
    data["contacts"][0]["friction"] = 0.3
    bad, worst = restart_parts(ctx, data, 0.3, 0.8)
    if bad:
        return bad
    return ok() if worst <= 1e-12 else wrong(f"the continued run parts from the whole one by {worst:.3g}")


def _refusal(change: dict, *needles: str):
    def body(ctx):
        data = _block(2)
        for key, value in change.items():
            if key.startswith("contacts."):
                data["contacts"][0][key.split(".", 1)[1]] = value
            else:
                data[key] = value
        r, out = run_case(ctx, data)
        verdict = ctx.refused(r, *needles)
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    return body


for _name, _change, _needles in (
        ("an unknown body", {"bodies": {"bar": {"model": "rigid"}, "other": {"model": "rigid"}}}, ("bodies", "other")),
        ("an unknown model", {"bodies": {"bar": {"model": "floppy"}}}, ("bodies", "model")),
        ("newmark", {"solver": {"method": "newmark", "dt": 0.002, "t_end": 0.1}}, ("solver.method", "moreau_jean")),
        ("supports", {"supports": [{"nodes": "top", "fix": ["x"]}]}, ("supports",)),
        ("damping", {"damping": {"alpha": 1.0}}, ("damping",)),
        ("an elastic stop", {"contacts.stiffness": 1e6}, ("contacts", "Newton")),
        ("a pair within one rigid body", {"contacts.type": "pair", "contacts.nodes": ["bottom", "top"]},
         ("contacts", "one rigid body")),
        ("an initial displacement", {"initial": {"displacement": [0.001, 0.0]}}, ("initial.displacement",)),
        ("mass redistributed", {"solver": {"mass": "redistributed", "dt": 0.002, "t_end": 0.1}}, ("solver.mass",)),
):
    probe("rigid-bodies", f"refused: {_name}")(_refusal(_change, *_needles))
