"""Coulomb friction through the reduced model's static correction (docs/theory.md s. 8.9) against exact answers.

- The rows' compliance ``H S_k H^T`` over normal and tangent rows (``H = [P; P_T]``, coupled) is the sum over
  the truncated modes of a dense eigendecomposition.
- An elastic block reduced to 4 and 10 modes with the static correction, sliding at v0 on a floor under gravity,
  stops after v0^2 / (2 mu g) and stays there, as the full model does; its energy budget closes, E <= E0 + W_ext
  and the friction and contact losses grow at every step.
- The block pressed on the floor by its weight and dragged by a body force: below mu g it sticks, and its
  displacement is the clamped block's static one (from the model's K), which with the rigid-body modes alone
  is all the static part's; above mu g it slides with acceleration a - mu g.
- Landings while sliding (2D and 3D, Courant numbers 8 and 50): the contacts never give energy.
- Where friction cannot act through the static correction (a compliance not symmetric positive semi-definite,
  Newmark's scheme) the case is refused naming the key.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from mpi4py import MPI

from conftest import CASES
import fem_impact as fi
from fem_impact.build import model_and_constraints
from fem_impact.errors import CaseError, ModelInputError
from fem_impact.fem.modes import compute_modes
from fem_impact.fem.reduced import build_reduced
from fem_impact.nonsmooth.friction import FrictionProblem

G = 9.81
MU = 0.3


def block_case(solver=None, v0=0.0, ax=0.0, ramp=None, t_end=0.9, dt=2e-3, beta=0.0, dim=2, mu=MU):
    """The sliding block of tests/test_friction.py (cases/sliding_block.yaml: 0.2 x 0.05 m, E = 1e7, rho = 1000,
    nu = 0, 8 cells along, 9 floor rows), with a horizontal body acceleration ``ax`` (ramped from 0 over
    ``ramp`` s), stiffness damping ``beta``, and probes at the top's middle and the bottom's front."""
    mesh = {"shape": "bar", "dim": dim, "length": 0.2, "height": 0.05, "cells": 8 if dim == 2 else 4}
    pad = [0.0] * (dim - 2)
    if dim == 3:
        mesh["width"] = 0.05
    drive = f"{ax}*min(t/{ramp}, 1)" if ramp else ax
    data = {"name": "block", "mesh": mesh,
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.0, **({"area": 1.0} if dim == 2 else {})},
            "initial": {"velocity": [v0, 0.0] + pad},
            "loads": [{"body": "all", "acceleration": [drive, -G] + pad}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0] + pad,
                          "gap": 0.0, "friction": mu}],
            "solver": {"dt": dt, "t_end": t_end, **(solver or {})},
            "output": {"vtk": False, "probes": {"top": [0.1, 0.05] + pad, "front": [0.2, 0.0] + pad}}}
    if beta:
        data["damping"] = {"beta": beta}
    return fi.Case.from_dict(data)


def reduced(modes, **extra):
    return {"method": "modal", "modes": modes, "static_correction": True, **extra}


def budget(h, balance=1e-10):
    """E <= E0 + W_ext, the friction and contact losses >= 0 at every step (to 1e-14 of the scale: round-off),
    and the balance closed to ``balance`` of the energy scale. Returns (balance residual, largest excess) on
    the scale. (For theta > 1/2 the contact loss with the scheme's own dissipation: the impulses' work is
    booked with the step's mean velocity, the rest of it on the compliant rows in numerical_loss,
    MoreauJean._numerical_loss; each alone dips, by 3e-8 of the scale on the sliding block at theta = 1, as
    without friction.)"""
    energy = h["kinetic"] + h["strain"]
    scale = max(energy[0] + h["external_work"].max(), 1e-300)
    excess = float((energy - energy[0] - h["external_work"]).max()) / scale
    assert excess <= 1e-12
    assert np.diff(h["friction_loss"]).min() >= -1e-14 * scale
    numerical = h["numerical_loss"] if "numerical_loss" in h else 0.0
    assert np.diff(h["contact_loss"] + numerical).min() >= -1e-14 * scale
    residual = float(np.abs(h["energy_error"]).max()) / scale
    assert residual <= balance
    return residual, excess


def travel(h, mass):
    v = h["bar.px"] / mass
    return v, np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(h["t"]))])


def test_the_rows_static_compliance_over_normal_and_tangent_rows_is_the_truncated_modes_sum():
    """``H S_k H^T`` (H = [P; P_T]: the 9 floor rows' normals, then their tangents) from static solves with
    inertia relief equals ``H Y2 diag(1/w2^2) Y2^T H^T`` of a dense eigendecomposition, with its coupling of
    normal and tangent rows; its normal block is the frictionless static part's compliance, and its offsets
    are ``H S_k R`` of the same sum (R: the weight and a force on the top face, which the truncated modes take
    a part of)."""
    case = block_case(reduced(5), v0=2.0).with_changes({"loads": [
        {"body": "all", "acceleration": [0.0, -G]}, {"nodes": "top", "force": [5.0, -3.0]}]})
    model, cons = model_and_constraints(case, MPI.COMM_SELF)
    n1 = 5
    red = build_reduced(model, cons, compute_modes(model, n1), n1, True, 0.0, 0.0, 0.01)
    static = red.static
    assert static.tangents and static.rows_compliance.shape == (18, 18) and not static.rigid_rows.any()
    K = model.K.convert("dense").getDenseArray()
    M = model.M.convert("dense").getDenseArray()
    w2, Y = scipy.linalg.eigh(K, M)
    H = np.hstack([cons.P_local.toarray(), cons.tangent_local.toarray()]).T
    HY = H @ Y[:, n1:]
    exact = HY @ np.diag(1.0 / w2[n1:]) @ HY.T
    tol = 1e-8 * np.abs(exact).max()
    np.testing.assert_allclose(static.rows_compliance, exact, rtol=0, atol=tol)
    assert np.abs(exact[:9, 9:]).max() > 0.05 * np.abs(exact).max()   # the rows are coupled
    np.testing.assert_array_equal(static.compliance, static.rows_compliance[:9, :9])
    offsets = HY @ ((Y[:, n1:].T @ model.load.constant.array_r) / w2[n1:])
    assert np.abs(offsets[9:]).max() > 0.1 * np.abs(offsets).max() > 0.0
    np.testing.assert_allclose(static.rows_offsets[:, 0], offsets, rtol=0, atol=1e-8 * np.abs(offsets).max())


@pytest.mark.parametrize("modes, scheme", [(4, {}), (10, {}), (4, {"theta": 1.0}), (4, {"level": "velocity"})],
                         ids=["4", "10", "4-theta-1", "4-velocity"])
def test_a_reduced_block_with_the_static_correction_slides_v0_squared_over_2_mu_g_and_stops(modes, scheme):
    """4 modes (3 rigid) and 10, fewer than the 18 contact unknowns: without the static correction W is singular
    there (its impulses not unique); with it every row is compliant and the cone problem solves to round-off.
    Measured: the slide within 8e-7 of v0^2 / (2 mu g) at both counts (1e-6 at theta = 1, whose own
    dissipation is booked: numerical_loss), the block still to 1e-8 m after. The velocity level is the same
    problem here (a compliant row keeps its gap condition at the step's end)."""
    v0 = 2.0
    result = fi.run(block_case(reduced(modes, **scheme), v0=v0))
    h, summary = result.history, result.summary
    assert summary["modes"] == modes and summary["static_correction"] is True
    v, x = travel(h, summary["body_mass"]["bar"])
    t = h["t"]
    assert x[-1] == pytest.approx(v0 ** 2 / (2 * MU * G), rel=0.01)
    stop = v0 / (MU * G)
    sliding = (t > 0.05) & (t < 0.6)
    assert np.polyfit(t[sliding], v[sliding], 1)[0] == pytest.approx(-MU * G, rel=0.01)
    after = t > 1.05 * stop
    assert abs(v[after].mean()) <= 1e-5 * v0 and np.ptp(x[after]) <= 1e-6 * x[-1]   # stopped, and stays
    assert h["floor.slipping"][-1] == 0 and h["floor.sticking"][-1] == 9
    budget(h)
    assert summary["energy_created"] == 0.0
    assert summary["max_friction_residual"] <= FrictionProblem.TOLERANCE


def test_modes_auto_keeps_nearly_every_mode_and_slides_the_block():
    """``modes: auto`` (the tolerance 0.01 on the floor rows' neglected flexibility) keeps 53 of the block's 54
    modes: one truncated mode for 9 rows, so the static compliance is singular. The run starts (no row closed:
    no static force, where the LCP on that compliance has no positive definite block) and slides the block
    v0^2 / (2 mu g) within 1 % (measured 4e-4), its budget closed; without friction it starts as well."""
    v0 = 2.0
    result = fi.run(block_case(reduced("auto"), v0=v0))
    h, summary = result.history, result.summary
    assert summary["modes"] == 53
    assert travel(h, summary["body_mass"]["bar"])[1][-1] == pytest.approx(v0 ** 2 / (2 * MU * G), rel=0.01)
    budget(h)
    assert fi.run(block_case(reduced(53), v0=v0, mu=0.0, t_end=0.05)).summary["steps"] == 25


def test_the_reduced_block_slides_and_settles_as_the_full_one():
    """The block of the test above, full (Moreau-Jean) and reduced to 4 modes with the static correction: the
    same slide (measured 3.5e-4 apart), both at rest after it, and the same static sag of the top under the
    block's weight, rho g h^2 / (2 E) for this column (nu = 0) within 1 % (the 4th mode alone would not carry
    it: the static part does). The reduced budget closes to 1e-10 of the energy scale (measured 5e-13), the
    full one to 1e-9 as in tests/test_friction.py."""
    v0 = 2.0
    full = fi.run(block_case(v0=v0))
    red = fi.run(block_case(reduced(4), v0=v0))
    hf, hr = full.history, red.history
    vf, xf = travel(hf, full.summary["body_mass"]["bar"])
    vr, xr = travel(hr, red.summary["body_mass"]["bar"])
    assert xr[-1] == pytest.approx(xf[-1], rel=1e-3)
    assert hr["top.ux"][-1] == pytest.approx(hf["top.ux"][-1], rel=1e-3)
    late = hr["t"] > 0.8
    assert abs(vr[late].mean()) <= 1e-5 * v0 and abs(vf[late].mean()) <= 1e-4 * v0
    sag = 1000.0 * G * 0.05 ** 2 / (2 * 1e7)
    assert -hr["top.uy"][late].mean() == pytest.approx(sag, rel=0.01)
    assert -hf["top.uy"][late].mean() == pytest.approx(sag, rel=0.1)   # (the full block still rings)
    budget(hr)
    budget(hf, balance=1e-9)
    assert hr["friction_loss"][-1] == pytest.approx(hf["friction_loss"][-1], rel=1e-3)


def clamped(case):
    """The block clamped at its bottom nodes (the floor rows' normal and tangent held) under the case's constant
    load, from the model's matrices: ``K u + H^T lam = R``, ``H u = 0``. Returns (u, normal and tangential
    reactions per row, the model)."""
    model, cons = model_and_constraints(case, MPI.COMM_SELF)
    K = model.K.convert("dense").getDenseArray()
    H = np.hstack([cons.P_local.toarray(), cons.tangent_local.toarray()]).T
    n, m = K.shape[0], H.shape[0]
    solution = np.linalg.solve(np.block([[K, H.T], [H, np.zeros((m, m))]]),
                               np.concatenate([model.load.constant.array_r, np.zeros(m)]))
    return solution[:n], solution[n:n + cons.p], solution[n + cons.p:], model


def node_dofs(model, point):
    node = np.flatnonzero(np.all(np.isclose(model.node_coords[:, :2], point), axis=1))[0]
    return model.bs * node + np.arange(2)


@pytest.mark.parametrize("modes", [3, 10])
def test_a_preloaded_reduced_block_sticks_on_its_static_compliance_below_mu_g_and_slides_above(modes):
    """The block resting on the floor under its weight, dragged by a horizontal body acceleration a ramped up over
    0.05 s and then held, a little stiffness damping (beta = 9e-5: 10 % at its first shear mode) to settle.

    a = 0.5 mu g: it sticks. The exact answer is the block clamped at its bottom (every row's traction inside
    the cone there: tangential / normal 0.16 at most), from the model's K: the top's displacement (0.42 um of
    shear, 1.2 um of sag) is reproduced to 1e-8 (measured 1e-13) with 10 modes and with the 3 rigid-body modes
    alone, where all of it is the static part's, through its compliance on the tangent rows; the bottom front
    does not move, and the floor holds m a.
    a = 1.5 mu g: it slides from when a reaches mu g, at a - mu g once a is held."""
    a, ramp, t_end = 0.5 * MU * G, 0.05, 0.15
    case = block_case(reduced(modes), ax=a, ramp=ramp, t_end=t_end, dt=5e-4, beta=9e-5)
    u, normal, tangential, model = clamped(block_case(ax=a, t_end=t_end))
    assert normal.min() > 0.0 and (np.abs(tangential) < MU * normal).all()   # the clamped state is Coulomb's
    result = fi.run(case)
    h, mass = result.history, result.summary["body_mass"]["bar"]
    top = u[node_dofs(model, [0.1, 0.05])]
    assert abs(top[0]) > 0.3 * abs(top[1]) > 0.0
    assert h["top.ux"][-1] == pytest.approx(top[0], rel=1e-8)
    assert h["top.uy"][-1] == pytest.approx(top[1], rel=1e-8)
    assert abs(h["front.ux"][-1]) <= 1e-9 * abs(top[0])
    assert np.abs(h["front.ux"]).max() <= 1e-9 * abs(top[0])   # stuck throughout
    assert h["floor.sticking"][-1] == 9 and h["floor.slip"].max() <= 1e-12
    assert h["floor.tangential_force"][-1] == pytest.approx(mass * a, rel=1e-8)
    budget(h)

    a = 1.5 * MU * G
    result = fi.run(block_case(reduced(modes), ax=a, ramp=ramp, t_end=t_end, dt=5e-4, beta=9e-5))
    h = result.history
    v = h["bar.px"] / mass
    start, held = ramp * MU * G / a, t_end - ramp   # (a reaches mu g at start)
    v_ramp = a / (2 * ramp) * (ramp ** 2 - start ** 2) - MU * G * (ramp - start)
    x_ramp = a / (2 * ramp) * ((ramp ** 3 - start ** 3) / 3 - start ** 2 * (ramp - start)) \
        - MU * G * (ramp - start) ** 2 / 2
    assert v[-1] == pytest.approx(v_ramp + (a - MU * G) * held, rel=0.01)
    assert h["front.ux"][-1] == pytest.approx(x_ramp + v_ramp * held + (a - MU * G) * held ** 2 / 2, rel=0.01)
    late = h["t"] > ramp + 0.01
    assert np.polyfit(h["t"][late], v[late], 1)[0] == pytest.approx(a - MU * G, rel=0.01)
    assert np.abs(h["front.ux"][h["t"] < 0.9 * start]).max() <= 1e-9 * abs(top[0])   # stuck until then
    assert h["floor.slipping"][-1] == 9
    budget(h)


@pytest.mark.parametrize("dim, modes", [(2, 3), (2, 8), (3, 6)])
@pytest.mark.parametrize("courant, mu", [(8.0, 0.3), (50.0, 1.0)])
def test_a_reduced_block_landing_while_sliding_never_gives_energy(dim, modes, courant, mu):
    """The landing of tests/test_friction.py (4 cells, nu = 0.3, falling at 0.5 m/s from 1 mm while sliding at
    1 m/s) reduced with the static correction, fewer modes than contact unknowns: every row is compliant
    (no impact: restitution has no effect), Coulomb's law on each row's whole slip over the step; the gaps
    held at every step's end, the losses grow, E <= E0 + W_ext, the balance closes (measured 4e-14)."""
    pad = [0.0] * (dim - 2)
    mesh = {"shape": "bar", "dim": dim, "length": 0.2, "height": 0.05, "cells": 4}
    if dim == 3:
        mesh["width"] = 0.05
    dt = courant * 0.05 / 100.0
    data = {"name": "landing", "mesh": mesh,
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.3, **({"area": 1.0} if dim == 2 else {})},
            "initial": {"velocity": [1.0, -0.5] + ([0.5] if dim == 3 else [])},
            "loads": [{"body": "all", "acceleration": [0.0, -G] + pad}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0] + pad,
                          "gap": 1e-3, "friction": mu}],
            "solver": {"dt": dt, "t_end": 60 * dt, **reduced(modes)}, "output": {"vtk": False}}
    result = fi.run(fi.Case.from_dict(data))
    h = result.history
    assert h["friction_loss"][-1] > 0.0 and h["floor.impulse"].sum() > 0.0   # it landed and slid
    budget(h)
    assert h["floor.gap"].min() >= -1e-15
    assert result.summary["energy_created"] == 0.0
    assert result.summary["max_friction_residual"] <= FrictionProblem.TOLERANCE


@pytest.mark.parametrize("courant", [8.0, 50.0])
def test_a_reduced_face_with_fewer_modes_than_contact_unknowns_solves_through_the_static_correction(courant):
    """The plate of tests/test_friction.py (cases/plate_drop.yaml, 121 face rows: 363 contact unknowns) landing
    while sliding on 60 modes, mu = 1, e = 1: on the modes alone W is singular and the run stops
    (test_a_reduced_face_with_fewer_modes_than_contact_unknowns_stops_and_says_why); through the static
    correction every row sees the plate's whole flexibility, W is positive definite and every step's cone
    problem solves to the tolerance, with no energy created. (The gaps: at Courant 8 the first landing step's
    stay at the solver's tolerance, 4e-10 of the displacement scale measured, where the round-off pass on the
    normal impulses alone would take the sticking rows' tangential law past it; 5e-15 at Courant 50.)"""
    cells = 2
    dt = courant / cells
    case = fi.load_case(CASES / "plate_drop.yaml").with_changes({
        "mesh.cells": cells, "material.nu": 0.3, "solver.dt": dt, "solver.t_end": 3.2 + 4 * dt,
        "initial.velocity": [-1.0, 0.5, 0.3], "contacts.0.gap": 0.2, "contacts.0.friction": 1.0,
        "contacts.0.restitution": 1.0, "output.vtk": False, "solver.method": "modal", "solver.modes": 60,
        "solver.static_correction": True})
    result = fi.run(case)
    h, summary = result.history, result.summary
    assert summary["constraints"] == 121 and summary["modes"] == 60
    assert h["friction_loss"][-1] > 0.0 and h["floor.impulse"].sum() > 0.0   # it landed and slid
    budget(h)
    assert h["floor.gap"].min() >= -1e-9
    assert summary["energy_created"] == 0.0
    assert summary["max_friction_residual"] <= FrictionProblem.TOLERANCE


def test_friction_through_the_static_correction_is_refused_where_it_cannot_act(monkeypatch):
    """Newmark's scheme has no cone problem: refused naming solver.scheme, as without the static correction. A
    static compliance on the rows that is not symmetric positive semi-definite (here the static solves' sign
    turned, as a broken solve could leave it) would give the static part an energy without sign: refused
    naming solver.static_correction."""
    with pytest.raises(CaseError, match=r"contacts\[0\]\.friction: solver.scheme newmark cannot take friction .*"
                                        r"use solver.scheme: moreau_jean"):
        block_case(reduced(4, scheme="newmark"), v0=2.0)
    block_case(reduced(4, level="velocity", theta=1.0), v0=2.0)   # (both levels and any theta take it)
    import fem_impact.fem.reduced as reduction

    solves = reduction.static_solves
    monkeypatch.setattr(reduction, "_flexibility", lambda model, cons, modes, scene, reused, tangents=False:
                        -solves(model, modes, reduction.static_load_columns(model, cons, tangents)))
    with pytest.raises((CaseError, ModelInputError), match=r"solver\.static_correction: the static correction's "
                                                           r"compliance on the rows with friction is not symmetric "
                                                           r"positive semi-definite"):
        fi.run(block_case(reduced(4), v0=2.0, t_end=0.01))
