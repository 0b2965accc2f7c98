"""The contact laws (fem_impact/nonsmooth/laws.py) and their one-step problem (problem.py): the laws'
terms and energy hooks, the exact LCP solver, B0 (the bouncing mass) under Newton's law, and a
damped stop defined and registered here, in this file alone, run by every method that takes
elastic stops against the closed-form damped oscillator (docs/theory.md s. 2.5)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from petsc4py import PETSc

from pydantic import Field

import fem_impact
from conftest import ConstantLoad
from fem_impact.integrators import CentralDifference, MoreauJean, Newmark, Operators, integrate
from fem_impact.nonsmooth import laws
from fem_impact.nonsmooth.lcp import CholeskyFactor, Delassus, UpdatedFactor, solve_lcp
from fem_impact.nonsmooth.problem import OneStepProblem

# The schemes B0 holds for: the paper's, and Moreau-Jean at the position level (the default) and
# at the velocity level (Newton's law on velocities; its position drifts by up to dt x speed).
SCHEMES = {"newmark": Newmark, "moreau_jean": MoreauJean,
           "moreau_jean_velocity": lambda ops, dt: MoreauJean(ops, dt, level="velocity")}
EXACT_REST = ("newmark", "moreau_jean")   # the schemes that hold the gap exactly


def brute_force_lcp(A, q):
    """Enumerate all active sets; the LCP with a P-matrix has exactly one solution."""
    n = q.size
    for active in itertools.product([False, True], repeat=n):
        active = np.array(active)
        x = np.zeros(n)
        if active.any():
            x[active] = np.linalg.solve(A[np.ix_(active, active)], -q[active])
        w = A @ x + q
        if np.all(x >= -1e-12) and np.all(w >= -1e-12):
            return x
    raise AssertionError("no solution")


@pytest.mark.parametrize("seed", range(20))
def test_lcp_matches_enumeration_on_random_spd_problems(seed):
    rng = np.random.default_rng(seed)
    n = rng.integers(1, 7)
    B = rng.normal(size=(n, n))
    A = B @ B.T + 0.1 * np.eye(n)
    q = rng.normal(size=n)
    guess = rng.random(n) < 0.5
    x, w, active = solve_lcp(A, q, guess=guess)
    np.testing.assert_allclose(x, brute_force_lcp(A, q), atol=1e-10)
    assert np.all(x >= 0) and np.all(w >= 0)
    assert abs(x @ w) < 1e-10
    np.testing.assert_allclose(w, A @ x + q, atol=1e-10)


def test_lcp_without_contact_returns_the_free_gap():
    x, w, active = solve_lcp(np.eye(2), np.array([0.3, 0.0]))
    assert not x.any() and not active.any()
    np.testing.assert_array_equal(w, [0.3, 0.0])


@pytest.mark.parametrize("added,removed", [(0, 9), (7, 0), (6, 11)])
def test_a_block_near_a_factored_one_is_solved_through_its_factor(added, removed):
    """``UpdatedFactor``: the block of an SPD matrix on a set that differs from a factored one by
    rows added and removed, solved through the factored one's Cholesky factor, is its inverse to
    round-off (one right-hand side and several)."""
    from scipy.linalg import cho_factor

    rng = np.random.default_rng(added + 10 * removed)
    n = 400
    B = rng.normal(size=(n, n))
    A = B @ B.T + n * np.eye(n)
    base_rows = np.sort(rng.choice(n, 300, replace=False))
    rows = np.setdiff1d(base_rows, rng.choice(base_rows, removed, replace=False))
    rows = np.union1d(rows, rng.choice(np.setdiff1d(np.arange(n), base_rows), added, replace=False))
    base = CholeskyFactor(base_rows, cho_factor(A[np.ix_(base_rows, base_rows)], lower=True))
    factor = UpdatedFactor(A, base, rows)
    block = A[np.ix_(rows, rows)]
    for b in (rng.normal(size=rows.size), rng.normal(size=(rows.size, 3))):
        np.testing.assert_allclose(block @ factor.solve(b), b, rtol=0, atol=1e-11 * np.abs(b).max())
    # an update of the update (a level deeper): two rows more out, one back in
    again = np.union1d(np.setdiff1d(rows, rows[[3, 50]]), np.setdiff1d(base_rows, rows)[:1])
    deeper = UpdatedFactor(A, factor, again)
    b = rng.normal(size=again.size)
    assert deeper.depth == 2
    np.testing.assert_allclose(A[np.ix_(again, again)] @ deeper.solve(b), b, rtol=0, atol=1e-11 * np.abs(b).max())


def test_pivoting_through_updated_factors_finds_the_factorized_solutions():
    """An LCP of 600 rows solved 20 times as its right-hand side drifts (its active set changes by a
    few rows a time): through updated factors (``Delassus.UPDATE_FROM``) and by a factorization of
    every active block, the same active sets and forces to round-off; at least one solve was
    updated."""
    rng = np.random.default_rng(5)
    n = 600
    B = rng.normal(size=(n, n))
    A = B @ B.T + n * np.eye(n)
    updating, factorizing = Delassus(A), Delassus(A)
    factorizing.UPDATE_FROM = n + 1
    q = rng.normal(size=n)
    kinds, a1, a2 = set(), None, None
    for _ in range(20):
        q += 0.05 * rng.normal(size=n)
        x1, w1, a1 = updating.solve(q, guess=a1)
        x2, w2, a2 = factorizing.solve(q, guess=a2)
        kinds |= {kind for kind, _ in updating._factors.values()}
        np.testing.assert_array_equal(a1, a2)
        np.testing.assert_allclose(x1, x2, rtol=0, atol=1e-12 * np.abs(x2).max())
        assert np.all(x1 >= 0) and np.all(w1 >= 0) and abs(x1 @ w1) <= 1e-9 * np.abs(q).max() * np.abs(x1).max()
    assert "updated" in kinds


# --- B0: a point mass dropped on a rigid floor (docs/benchmarks.md B0) --------------------

def one_by_one(value):
    A = PETSc.Mat().createAIJ([1, 1], nnz=1, comm=PETSc.COMM_SELF)
    A.setValue(0, 0, value)
    A.assemble()
    return A


class Recorder:
    def __init__(self):
        self.rows = []

    def write(self, s):
        self.rows.append((s.t, s.U[0], s.V[0], s.impulse[0], s.force[0], s.energy.error,
                          s.energy.impact_loss + s.energy.contact_loss))

    def array(self):
        return np.array(self.rows)


def drop_mass(e, t_end, dt=1e-4, m=2.0, g=9.81, h0=1.0, scheme="newmark"):
    """Mass m at height h0 above the floor: u is the displacement (up), P u = -u <= h0; Newton's law."""
    newton = laws.RowLaws([(laws.law_of("newton", {"restitution": e}), [0])], 1)
    ops = Operators(one_by_one(m), one_by_one(0.0), None, ConstantLoad(-m * g),
                    np.array([[-1.0]]), np.array([h0]), newton.restitution, laws=newton)
    U0 = PETSc.Vec().createSeq(1)
    V0 = U0.duplicate()
    U0.set(0.0)
    V0.set(0.0)
    rec = Recorder()
    integrate(SCHEMES[scheme](ops, dt), U0, V0, t_end, [rec])
    return rec.array()


def impacts(h, dt):
    """(time, velocity after) of each impact: steps with an impulse, consecutive ones merged."""
    idx = np.flatnonzero(h[:, 3] > 1e-9)
    idx = idx[np.r_[True, np.diff(idx) > 1]] if idx.size else idx
    return h[idx, 0], h[idx, 2]


G, H0, DT = 9.81, 1.0, 2e-4
T1 = np.sqrt(2 * H0 / G)
V1 = np.sqrt(2 * G * H0)


@pytest.mark.parametrize("scheme", SCHEMES)
@pytest.mark.parametrize("e", [1.0, 0.8])
def test_b0_impact_times_and_rebound_speeds(e, scheme):
    h = drop_mass(e, 3.0, DT, scheme=scheme)
    times, v_after = impacts(h, DT)
    assert len(times) >= 3   # (three flights in 3 s at e = 0.8 and e = 1)
    k = np.arange(min(len(times), 6))
    exact_t = T1 + 2 * T1 * np.array([sum(e**j for j in range(1, i + 1)) for i in k])
    exact_v = e ** (k + 1) * V1
    # Impacts are resolved at step ends: time within 2 dt per impact, speed within g dt.
    assert np.all(np.abs(times[k] - exact_t) <= 2 * DT * (k + 1))
    assert np.all(np.abs(v_after[k] - exact_v) <= 2 * G * DT + 1e-3 * exact_v)
    assert np.abs(h[:, 5]).max() < 1e-9 * 2.0 * G * H0   # energy balance of the scheme
    assert h[-1, 6] >= -1e-12                            # impact + contact losses are losses


@pytest.mark.parametrize("scheme", SCHEMES)
def test_b0_passes_the_accumulation_point_and_rests(scheme):
    e = 0.8
    t_inf = T1 * (1 + 2 * e / (1 - e))  # 4.06 s
    h = drop_mass(e, t_inf + 1.0, DT, scheme=scheme)
    assert h[-1, 0] == pytest.approx(t_inf + 1.0, abs=DT)  # every step was taken
    rest = h[:, 0] > t_inf + 0.05
    drift = 1e-12 if scheme in EXACT_REST else DT * V1   # velocity level: at most dt x impact speed
    np.testing.assert_allclose(h[rest, 1], -H0, atol=drift)   # on the floor
    np.testing.assert_allclose(h[rest, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(h[rest, 4], 2.0 * G, rtol=1e-9)  # the floor carries m g
    loss = h[-1, 6]
    assert loss == pytest.approx(2.0 * G * (H0 + H0 + h[-1, 1]), rel=1e-6)   # all potential energy is dissipated


@pytest.mark.parametrize("scheme", SCHEMES)
def test_b0_plastic_impact_sticks_at_once(scheme):
    h = drop_mass(0.0, 1.0, DT, scheme=scheme)
    times, v_after = impacts(h, DT)
    assert times[0] == pytest.approx(T1, abs=2 * DT)
    after = h[:, 0] > T1 + 2 * DT
    np.testing.assert_allclose(h[after, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(h[after, 1], -H0, atol=1e-12 if scheme in EXACT_REST else DT * V1)
    assert h[-1, 6] == pytest.approx(0.5 * 2.0 * V1**2, rel=2 * G * DT / V1 * 2)


# --- the laws' hooks and the one-step problem ------------------------------------------------

def test_built_in_laws_give_their_terms_and_stored_energy():
    newton, stop = laws.law_of("newton", {"restitution": 0.7}), laws.law_of("elastic_stop", {"stiffness": 4.0})
    assert newton.one_step(1e-3) == laws.LawTerms(restitution=0.7)
    assert stop.one_step(1e-3) == laws.LawTerms(compliance=0.25)
    np.testing.assert_allclose(stop.stored(np.array([2.0, 0.0]), np.array([-0.5, 0.1])), [0.5, 0.0])
    assert not newton.stored(np.array([3.0]), np.array([0.0])).any()
    assert {"newton", "elastic_stop"} <= set(laws.LAWS)
    assert laws.LAWS["elastic_stop"].keys.model_fields["stiffness"].metadata   # (gt=0: the case's range)


def test_row_laws_place_each_law_on_its_rows_and_book_per_column(damped_stop):
    rows = laws.RowLaws([(laws.law_of("newton", {"restitution": 0.5}), [0, 2]),
                         (laws.law_of("damped_stop", {"stiffness": 100.0, "damping": 10.0}), [1])],
                        3, cones=[(laws.Coulomb(0.3), np.array([2]))])
    h = 0.01
    c, m = rows.terms(h)
    np.testing.assert_allclose(c, [0.0, 1.0 / (100.0 + 10.0 / h), 0.0])
    np.testing.assert_allclose(m, [0.0, (10.0 / h) / (100.0 + 10.0 / h), 0.0])
    np.testing.assert_array_equal(rows.restitution, [0.5, 0.0, 0.5])
    np.testing.assert_array_equal(rows.friction, [0.0, 0.0, 0.3])
    assert rows.extra_columns() == ["stop_damping_loss"]
    work = rows.work(np.array([1.0, 2.0, 3.0]), np.array([1.0, 1.0, 1.0]))
    assert work == {"contact_loss": 4.0, "stop_damping_loss": 2.0}
    stored = rows.stored(np.array([1.0, 5.0, 0.0]), np.array([0.0, -0.1, 0.2]))
    assert stored == pytest.approx({"contact_loss": 0.0, "stop_damping_loss": 0.5 * 100.0 * 0.01})
    np.testing.assert_allclose(rows.memory(h, np.array([-1.0, -0.2, 0.5])), [0.0, 0.2 * m[1], 0.0])


def test_one_step_problem_is_the_integrators_lcp_with_the_laws_terms(damped_stop):
    """The assembled LCP is ``a W + diag(c)/(tau sigma)`` and ``q_free + m max(-g0, 0)/sigma``; its
    solution is the damped stop's force ``max(0, k delta + c_d (delta - delta0+)/h)``."""
    k, c_d, h, W = 100.0, 10.0, 0.01, np.array([[2.0]])
    rows = laws.RowLaws([(laws.law_of("damped_stop", {"stiffness": k, "damping": c_d}), [0])], 1)
    problem = OneStepProblem(W, rows, h, weight=0.25 * h * h, compliance_scale=1.0)
    kh = k + c_d / h
    np.testing.assert_allclose(problem.matrix, 0.25 * h * h * W + 1.0 / kh)
    for delta_free, delta0 in [(0.02, 0.0), (0.02, 0.015), (0.005, 0.02), (-0.01, -0.02), (0.03, -0.01)]:
        q = problem.q(np.array([-delta_free]), np.array([-delta0]))
        force = problem.solve(q)[0][0]
        delta = delta_free - 0.25 * h * h * W[0, 0] * force      # the penetration the force leaves
        expected = max(0.0, k * delta + c_d / h * (delta - max(delta0, 0.0)))
        assert force == pytest.approx(expected, rel=1e-12, abs=1e-12)
    # Moreau-Jean's scaling: impulses, rows divided by theta h.
    theta = 0.5
    mj = OneStepProblem(W, rows, h, compliance_scale=theta * h * h, row_scale=theta * h)
    np.testing.assert_allclose(mj.matrix, W + 1.0 / kh / (theta * h * h))
    np.testing.assert_allclose(mj.q(np.zeros(1), np.array([-0.02])), rows.memory(h, np.array([-0.02])) / (theta * h))
    # Rigid and elastic laws alone: no memory, q unchanged (the very array).
    rigid = OneStepProblem(W, laws.RowLaws.from_arrays(np.array([0.5])), h)
    q = np.array([-1.0])
    assert rigid.q(q, np.array([0.3])) is q and isinstance(rigid.solver, Delassus)


# --- a damped stop, defined and registered here alone ------------------------------------------

class DampedStopKeys(laws.LawKeys):
    stiffness: float = Field(gt=0.0, description="spring stiffness (N/m)")
    damping: float = Field(ge=0.0, description="dashpot coefficient in parallel with the spring (N s/m)")


class DampedStop(laws.ContactLaw):
    """A Kelvin-Voigt stop that cannot pull: ``F = max(0, k delta + c delta')`` while pressed
    (docs/theory.md s. 2.5: the spring at the step's end, the dashpot on the step's mean rate)."""

    name = "damped_stop"
    keys = DampedStopKeys
    summary = "a spring and a dashpot in parallel on each row, pushing only"
    column = "stop_damping_loss"

    def compliance(self) -> float:
        return 1.0 / self.params.stiffness

    def one_step(self, h: float) -> laws.LawTerms:
        k, c = self.params.stiffness, self.params.damping
        return laws.LawTerms(compliance=1.0 / (k + c / h), memory=(c / h) / (k + c / h))

    def stored(self, force: np.ndarray, gap: np.ndarray) -> np.ndarray:
        return 0.5 * self.params.stiffness * np.maximum(-gap, 0.0) ** 2


@pytest.fixture
def damped_stop():
    laws.register(DampedStop)
    yield DampedStop
    laws.unregister(DampedStop.name)


M_, K_, V0_, GAP_ = 2.0, 8.0e4, 1.5, 0.01   # kg, N/m, m/s, m
OMEGA = np.sqrt(K_ / M_)
STOP_SCHEMES = {"newmark": Newmark, "moreau_jean": MoreauJean, "central_difference": CentralDifference,
                "moreau_jean_theta": lambda ops, dt: MoreauJean(ops, dt, theta=0.6)}


def rebound_ratio(zeta):
    """A stop that cannot pull lets go where its force vanishes: omega_d t = pi - 2 asin(zeta)."""
    return np.exp(-zeta * (np.pi - 2.0 * np.arcsin(zeta)) / np.sqrt(1.0 - zeta * zeta))


class StopRecorder:
    def __init__(self):
        self.rows = []

    def write(self, s):
        e = s.energy
        self.rows.append((s.t, s.U[0], s.V[0], s.force[0], e.kinetic, e.strain, e.error,
                          e.losses.get("stop_damping_loss", 0.0), e.contact_loss, e.impact_loss + e.numerical_loss))

    def array(self):
        return np.array(self.rows)


def damped_bounce(scheme, zeta, dt):
    """A mass at v0 toward a damped stop a gap away (no gravity): P u = u <= gap."""
    stop = laws.law_of("damped_stop", {"stiffness": K_, "damping": 2.0 * M_ * OMEGA * zeta})
    rows = laws.RowLaws([(stop, [0])], 1)
    ops = Operators(one_by_one(M_), one_by_one(0.0), None, ConstantLoad(0.0), np.array([[1.0]]),
                    np.array([GAP_]), rows.restitution, laws=rows)
    U0, V0 = PETSc.Vec().createSeq(1), PETSc.Vec().createSeq(1)
    U0.set(0.0)
    V0.set(V0_)
    rec = StopRecorder()
    integrate(STOP_SCHEMES[scheme](ops, dt), U0, V0, GAP_ / V0_ + 3.0 / OMEGA * np.pi, [rec])
    return rec.array()


@pytest.mark.parametrize("scheme", STOP_SCHEMES)
@pytest.mark.parametrize("zeta", [0.05, 0.3])
def test_a_damped_stop_defined_here_rebounds_as_the_damped_oscillator(damped_stop, scheme, zeta):
    """Rebound ratio exp(-zeta (pi - 2 asin zeta) / sqrt(1 - zeta^2)); the stop's column holds the
    kinetic energy lost; the balance closes to 1e-10 of the energy; the force never pulls."""
    dt = 1e-3 / OMEGA
    h = damped_bounce(scheme, zeta, dt)
    u, v, f = h[:, 1], h[:, 2], h[:, 3]
    e0 = 0.5 * M_ * V0_**2
    exact = rebound_ratio(zeta)
    # (first order in omega dt: the dashpot acts on the step's mean rate, central difference one step late)
    tol = 5.0 * OMEGA * dt
    assert -v[-1] / V0_ == pytest.approx(exact, rel=tol)
    assert np.abs(h[:, 6]).max() < 1e-10 * e0                       # the balance closes
    assert f.min() >= 0.0 and f.max() > 0.0                         # pushes, never pulls
    assert h[-1, 7] == pytest.approx(e0 * (1.0 - exact**2), rel=2 * tol)   # the stop's loss: what the mass lost
    assert h[-1, 7] + h[-1, 8] + h[-1, 9] == pytest.approx(e0 - h[-1, 4], rel=1e-10)
    assert abs(h[-1, 8]) <= 1e-12 * e0   # (nothing of it booked as the rigid rows' contact loss)
    assert h[-1, 5] == 0.0 and u[-1] < GAP_                         # left the stop: it stores nothing
    touching = np.flatnonzero(f > 0.0)
    omega_d = OMEGA * np.sqrt(1.0 - zeta**2)
    assert (touching[-1] - touching[0] + 1) * dt == pytest.approx((np.pi - 2 * np.arcsin(zeta)) / omega_d,
                                                                  rel=tol, abs=3 * dt)


def test_a_damped_stop_converges_at_first_order(damped_stop):
    """Moreau-Jean's error in the rebound ratio halves with the step."""
    zeta = 0.2
    errors = [abs(-damped_bounce("moreau_jean", zeta, dt)[-1, 2] / V0_ - rebound_ratio(zeta))
              for dt in (4e-3 / OMEGA, 2e-3 / OMEGA)]
    assert errors[1] < 0.6 * errors[0]


BAR = {   # B2a: a free bar of length 1 (c = 1) at -1 toward a wall 0.1 away, here a damped stop
    "mesh": {"shape": "bar", "cells": 50},
    "material": {"E": 1.0, "rho": 1.0},
    "initial": {"velocity": [-1.0]},
    "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0], "gap": 0.1,
                  "law": "damped_stop", "stiffness": 50.0, "damping": 2.0}],
    "solver": {"dt": 0.01, "t_end": 3.0},
    "output": {"vtk": False},
}


@pytest.mark.parametrize("method", ["moreau_jean", "newmark", "central_difference", "modal"])
def test_a_registered_damped_stop_runs_in_every_method_that_takes_elastic_stops(damped_stop, method):
    """From the case file: the law's keys validated by its schema, its loss in its own history
    column, the balance closed to 1e-10 of the energy scale (the paper's Newmark and central
    difference book position-level forces, which may give some of it back within an impact)."""
    solver = {"method": method}
    if method == "central_difference":
        solver.update(dt=0.005, mass="lumped")
    if method == "modal":
        solver.update(modes=12)
    case = fem_impact.Case.from_dict({**BAR, "solver": {**BAR["solver"], **solver}})
    history = fem_impact.run(case).history
    loss = history["stop_damping_loss"]
    e0 = 0.5
    assert np.abs(history["energy_error"]).max() < 1e-10 * e0
    assert loss[-1] > 1e-3 * e0 and history["wall.force"].max() > 0.0
    if method == "moreau_jean":   # (its contacts never give energy back: the loss grows step by step)
        assert np.all(np.diff(loss) >= -1e-12 * e0)
    # Without its dashpot the law is the elastic stop: the same history, the stop's loss in its own column.
    undamped = fem_impact.run(case.with_changes({"contacts.0.damping": 0.0})).history
    stop = {**BAR["contacts"][0], "law": "elastic_stop"}
    del stop["damping"]
    elastic = fem_impact.run(fem_impact.Case.from_dict({**BAR, "contacts": [stop],
                                                        "solver": {**BAR["solver"], **solver}})).history
    for name in ("wall.gap", "wall.force", "kinetic", "strain"):
        np.testing.assert_allclose(undamped[name], elastic[name], rtol=0, atol=1e-12 * max(np.abs(elastic[name]).max(), e0))
    # (the reduced model's static part books its own share in contact_loss, as with any law)
    np.testing.assert_allclose(undamped["stop_damping_loss"] + undamped["contact_loss"], elastic["contact_loss"],
                               rtol=0, atol=1e-12 * e0)


def test_a_damped_stops_keys_are_its_schemas(damped_stop):
    with pytest.raises(fem_impact.CaseError, match="does not use 'restitution'"):
        fem_impact.Case.from_dict({**BAR, "contacts": [{**BAR["contacts"][0], "restitution": 0.5}]})
    with pytest.raises(fem_impact.CaseError, match="damping"):
        fem_impact.Case.from_dict({**BAR, "contacts": [{**BAR["contacts"][0], "damping": -1.0}]})


def test_a_damped_stops_loss_column_is_part_of_a_checkpoint(damped_stop, tmp_path):
    """A run continued from its checkpoint books the law's column on from where it stood."""
    from test_restart import assert_same_from

    case = fem_impact.Case.from_dict(BAR)
    full = fem_impact.run(case, tmp_path / "full")
    fem_impact.run(case.with_changes({"solver.t_end": 1.5}), tmp_path / "half")
    continued = fem_impact.run(case, tmp_path / "continued", restart=tmp_path / "half")
    assert full.history["stop_damping_loss"][-1] > 0.0
    assert_same_from(full.history, continued.history)
