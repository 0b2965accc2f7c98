"""Rigid bodies in large rotation (``bodies: {NAME: {model: rigid}}``, docs/theory.md s. 12), against exact
answers: a rigid block sliding to rest (Coulomb), a free block spun for ten turns (its kinetic energy and
shape kept), a rod dropped at 30 degrees onto a floor at one end (the rigid-body impact law, with and
without restitution and friction), a disk bouncing on a shaken table (the period-1 orbit's phase); the
balance closes, the losses are >= 0, E <= E0 + W_ext; what a rigid scene does not take yet is refused.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES, run_cli
from fem_impact.build import build_system, make_integrator
from fem_impact.integrators import integrate

G = 9.81


def check_budget(h, scale: float, closes: float = 1e-10) -> None:
    assert np.abs(h["energy_error"]).max() <= closes * scale
    for loss in ("impact_loss", "contact_loss", "friction_loss"):
        if loss in h:
            assert h[loss].min() >= -1e-12 * scale and np.diff(h[loss]).min() >= -1e-12 * scale, loss
    energy = h["kinetic"] + h["strain"]
    assert np.all(energy - energy[0] - h["external_work"] <= 1e-12 * scale)


def test_a_rigid_block_slides_to_rest_where_coulomb_says(tmp_path):
    """cases/sliding_block.yaml with its block rigid: mass and inertia m (L^2 + H^2) / 12 from the mesh,
    deceleration mu g, at rest at v0 / (mu g) (within a step) after losing 1/2 m v0^2 to friction."""
    result = fi.run(fi.load_case(CASES / "sliding_block.yaml", ["bodies={bar: {model: rigid}}", "output.vtk=false"]),
                    tmp_path / "out")
    body = result.summary["rigid_bodies"]["bar"]
    m, L, H, mu, v0 = 10.0, 0.2, 0.05, 0.3, 2.0
    assert body["mass"] == pytest.approx(m, rel=1e-12) and body["centre"] == pytest.approx([L / 2, H / 2], rel=1e-12)
    assert body["inertia"] == pytest.approx(m * (L * L + H * H) / 12.0, rel=1e-12)
    h = result.history
    t, v = h["t"], h["bar.vx"]
    sliding = t < 0.6
    assert v[sliding] == pytest.approx(v0 - mu * G * t[sliding], rel=1e-9, abs=1e-9)
    stop = t[np.flatnonzero(v <= 1e-9)[0]]
    assert abs(stop - v0 / (mu * G)) <= 0.002
    assert np.all(np.abs(v[t > stop]) <= 1e-9) and np.abs(h["bar.omega"]).max() <= 1e-9
    assert h["bar.x"][-1] - L / 2 == pytest.approx(v0 ** 2 / (2 * mu * G), rel=1e-3)
    assert h["friction_loss"][-1] == pytest.approx(0.5 * m * v0 ** 2, rel=1e-9)
    check_budget(h, 0.5 * m * v0 ** 2)


def test_a_free_rigid_block_spun_for_ten_turns_keeps_its_energy_and_its_shape():
    """A 3D block (0.2 x 0.05 x 0.03) spun about an axis near none of its principal ones: over ten turns its
    kinetic energy and the length of its angular momentum stay to 1e-10, its nodes' mutual distances to
    1e-12 of its size (the rotations orthogonal to round-off)."""
    L, H, W = 0.2, 0.05, 0.03
    c = (L / 2, H / 2, W / 2)
    w = np.array([3.0, 20.0, 7.0])
    velocity = [f"{w[1]}*(z-{c[2]}) - {w[2]}*(y-{c[1]})", f"{w[2]}*(x-{c[0]}) - {w[0]}*(z-{c[2]})",
                f"{w[0]}*(y-{c[1]}) - {w[1]}*(x-{c[0]})"]
    turns = 10 * 2 * np.pi / np.linalg.norm(w)
    case = fi.Case.from_dict({"name": "spin", "mesh": {"shape": "bar", "dim": 3, "length": L, "height": H, "width": W,
                                                       "cells": 4},
                              "material": {"E": 1e9, "rho": 1000.0, "nu": 0.0}, "initial": {"velocity": velocity},
                              "bodies": {"bar": {"model": "rigid"}}, "solver": {"dt": 1e-3, "t_end": turns},
                              "output": {"vtk": False}})
    system = build_system(case)
    integrator = make_integrator(case, system.operators, system.rigid)
    X = system.model.node_coords[:system.model.n_owned_nodes, :3]
    J0 = system.rigid.inertia[0]
    rows = []

    class Recorder:
        def write(self, s):
            P = X + s.U.reshape(-1, 3)
            spin = s.bodies[6:9]
            R = integrator.rot[0]
            L_body = J0 @ (R.T @ spin)
            rows.append((s.energy.kinetic, s.energy.error, np.linalg.norm(L_body),
                         *(np.linalg.norm(P[i] - P[j]) for i, j in ((0, -1), (3, 10), (1, 7)))))

    integrate(integrator, system.U0, system.V0, case.solver.t_end, [Recorder()])
    h = np.array(rows)
    assert len(h) > 2900
    kinetic = 0.5 * w @ (J0 @ w)   # (the centre at rest: the initial field is a pure spin)
    assert h[0, 0] == pytest.approx(kinetic, rel=1e-12)
    assert np.abs(h[:, 0] - kinetic).max() <= 1e-10 * kinetic
    assert np.abs(h[:, 1]).max() <= 1e-10 * kinetic
    assert np.abs(h[:, 2] - h[0, 2]).max() <= 1e-10 * h[0, 2]
    assert np.abs(h[:, 3:] - h[0, 3:]).max() <= 1e-12 * L


def rod(e: float, mu: float, v0: float = 1.0, dt: float = 1e-4):
    """A rigid rod (1 x 0.02, 2D) moving at v0 into a floor inclined at 30 degrees that touches its lower
    left corner: the rod at 30 degrees to the floor, struck at one end."""
    s, c = np.sin(np.radians(30.0)), np.cos(np.radians(30.0))
    n = [-s, -c]
    data = {"name": "rod", "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.02, "cells": 20},
            "material": {"E": 1e9, "rho": 1000.0, "nu": 0.0, "area": 1.0},
            "initial": {"velocity": [v0 * n[0], v0 * n[1]]}, "bodies": {"bar": {"model": "rigid"}},
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": n, "point": [0.0, 0.0],
                          "restitution": e, **({"friction": mu} if mu else {})}],
            "solver": {"dt": dt, "t_end": 3 * dt}, "output": {"vtk": False, "every": 1}}
    return fi.run(fi.Case.from_dict(data)), np.array(n)


@pytest.mark.parametrize("e", [0.0, 1.0])
@pytest.mark.parametrize("mu", [0.0, 5.0])
def test_a_rigid_rod_dropped_at_30_degrees_leaves_as_the_impact_law_says(e, mu):
    """Newton's law at the struck corner (its normal speed after, -e times before) and, with a sticking mu,
    no slip there after: the impulses from the 2 x 2 Delassus matrix of the corner, W = I/m + (r x)(r x)^T/J,
    the velocities and spin after to 1e-8."""
    result, n = rod(e, mu)
    h, body = result.history, result.summary["rigid_bodies"]["bar"]
    m, J, c = body["mass"], body["inertia"], np.array(body["centre"])
    r = np.array([0.0, 0.0]) - c                   # the struck corner from the centre
    t = np.array([-n[1], n[0]])                    # the friction's tangent (the normal turned by +90 deg)
    rows = [np.array([d[0], d[1], r[0] * d[1] - r[1] * d[0]]) for d in ((n, t) if mu else (n,))]
    inverse = np.diag([1 / m, 1 / m, 1 / J])
    nu = np.array([n[0], n[1], 0.0])               # v0 = 1 along n, no spin
    W = np.array([[a @ inverse @ b for b in rows] for a in rows])
    before = np.array([a @ nu for a in rows])
    target = np.array([-e * before[0]] + ([0.0] if mu else []))
    P = np.linalg.solve(W, before - target)
    after = nu - inverse @ sum(p * a for p, a in zip(P, rows))
    if mu:
        assert abs(P[1]) <= mu * P[0]   # (the closed form sticks)
    got = np.array([h["bar.vx"][1], h["bar.vy"][1], h["bar.omega"][1]])
    assert got == pytest.approx(after, abs=1e-8)
    assert h["floor.impulse"][1] == pytest.approx(P[0], rel=1e-8)
    check_budget(h, 0.5 * m)


def disk_mesh(folder, radius: float, points: int):
    import gmsh

    gmsh.initialize(["", "-v", "0"])
    try:
        gmsh.model.add("disk")
        surface = gmsh.model.occ.addDisk(0.0, 0.0, 0.0, radius, radius)
        gmsh.model.occ.synchronize()
        gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, [surface]), "disk")
        rim = [tag for _, tag in gmsh.model.getBoundary([(2, surface)], oriented=False)]
        gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, rim), "rim")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 2 * np.pi * radius / points)
        gmsh.model.mesh.generate(2)
        path = folder / "disk.msh"
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return path


@pytest.mark.slow
def test_a_rigid_disk_on_a_shaken_table_settles_on_the_period_one_orbits_phase(tmp_path):
    """A rigid disk (e = 0.5) on a table shaken at 50 Hz, Gamma = 1.3, the table's motion shifted so that the
    period-1 orbit's impacts fall at T/2: impacts.csv's phase within 0.5 deg of 1/2 once settled, one impact a
    period, the disk's mean velocity over a period 0, no spin."""
    f, e, gamma = 50.0, 0.5, 1.3
    T, A = 1.0 / f, gamma * G / (2 * np.pi * f) ** 2
    phi = np.arccos(np.pi * (1 - e) / ((1 + e) * gamma))
    radius = 0.01
    start_gap = 2 * A * np.sin(phi) + 0.8 * G * T * T / 8   # the orbit's apex height, less a fifth
    data = {"name": "disk", "mesh": {"file": str(disk_mesh(tmp_path, radius, 64))},
            "material": {"E": 2e11, "rho": 7800.0, "nu": 0.3, "area": 0.01},
            "bodies": {"disk": {"model": "rigid"}},
            "loads": [{"body": "all", "acceleration": [0.0, -G]}],
            "contacts": [{"name": "table", "type": "obstacle", "nodes": "rim", "normal": [0.0, -1.0],
                          "point": [0.0, -radius - start_gap], "restitution": e,
                          "motion": [0.0, f"{A}*sin(2*pi*{f}*t + {phi} - pi)"]}],
            "solver": {"dt": T / 1000, "t_end": 14 * T}, "output": {"vtk": False, "period": T, "every": 50}}
    result = fi.run(fi.Case.from_dict(data), tmp_path / "out")
    with open(result.outdir / "impacts.csv", newline="") as fh:
        impacts = list(csv.DictReader(fh))
    late = [row for row in impacts if float(row["t"]) > 8 * T]
    assert len(late) == 6
    assert max(abs(float(row["phase"]) - 0.5) * 360 for row in late) <= 0.5
    with open(result.outdir / "periods.csv", newline="") as fh:
        periods = [row for row in csv.DictReader(fh) if float(row["t"]) > 8.5 * T]
    assert all(int(row["table.impacts"]) == 1 for row in periods)
    assert max(abs(float(row["disk.vy_mean"])) for row in periods) <= 2e-3 * G * T / 2
    h = result.history
    assert np.abs(h["disk.omega"]).max() <= 1e-6 * (G * T / 2) / radius   # (struck under its centre: no spin)
    check_budget(h, 0.5 * result.summary["rigid_bodies"]["disk"]["mass"] * (G * T) ** 2)


@pytest.mark.parametrize("change, key, message", [
    ("bodies={bar: {model: rigid}, nobody: {model: rigid}}", "bodies.nobody", "no body nobody"),
    ("solver.method=newmark", "solver.method", "moreau_jean"),
    ("supports=[{nodes: top, fix: [x]}]", "supports", "no supports"),
    ("damping.alpha=1", "damping", "no damping"),
    ("contacts.0.stiffness=1e6", "contacts", "Newton's law"),
    ("initial.displacement=[0.001, 0.0]", "initial.displacement", "starts where its mesh is"),
    ("solver.mass=redistributed", "solver.mass", "keeps its mass on every node"),
])
def test_what_a_rigid_scene_does_not_take_is_refused_naming_the_key(tmp_path, change, key, message):
    out = run_cli("run", str(CASES / "sliding_block.yaml"), "-q", "-o", str(tmp_path / "out"), "--set",
                  "bodies={bar: {model: rigid}}", "--set", change)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert key in out.stderr.replace("[", ".").replace("]", "") and message in out.stderr, out.stderr


def assert_continues_exactly(case, t_end: float, folder) -> None:
    """``case`` run, then continued from its checkpoint to ``t_end``: the uninterrupted run's history to 1e-12."""
    first = fi.run(case, folder / "first")
    longer = case.with_changes({"solver.t_end": t_end})
    whole = fi.run(longer, folder / "whole").history
    continued = fi.run(longer, folder / "continued", restart=first.outdir).history
    n = len(continued["t"])
    for name in whole:
        assert continued[name] == pytest.approx(whole[name][-n:], rel=1e-12, abs=1e-14), name


def test_a_rigid_scenes_run_continues_from_its_checkpoint_exactly(tmp_path):
    case = fi.load_case(CASES / "sliding_block.yaml", ["bodies={bar: {model: rigid}}", "output.vtk=false",
                                                       "solver.t_end=0.3"])
    assert_continues_exactly(case, 0.8, tmp_path)


def test_a_3d_step_whose_spin_does_not_settle_is_refused(monkeypatch):
    """The 3D step's fixed point on the gyroscopic term, cut to one round for a fast asymmetric spin: the
    term's unbooked work is far above round-off, and the run stops saying so instead of answering."""
    from fem_impact.errors import SimulationError
    from fem_impact.rigid import scheme

    monkeypatch.setattr(scheme, "GYRO_ITERATIONS", 1)
    L, H, W = 0.2, 0.05, 0.03
    c = (L / 2, H / 2, W / 2)
    w = (30.0, 200.0, 70.0)
    velocity = [f"{w[1]}*(z-{c[2]}) - {w[2]}*(y-{c[1]})", f"{w[2]}*(x-{c[0]}) - {w[0]}*(z-{c[2]})",
                f"{w[0]}*(y-{c[1]}) - {w[1]}*(x-{c[0]})"]
    case = fi.Case.from_dict({"name": "spin", "mesh": {"shape": "bar", "dim": 3, "length": L, "height": H, "width": W,
                                                       "cells": 2},
                              "material": {"E": 1e9, "rho": 1000.0, "nu": 0.0}, "initial": {"velocity": velocity},
                              "bodies": {"bar": {"model": "rigid"}}, "solver": {"dt": 1e-3, "t_end": 0.01},
                              "output": {"vtk": False}})
    with pytest.raises(SimulationError, match="did not settle"):
        fi.run(case)
