"""Unit tests of the contact law on tiny systems: the exact LCP solver and B0, the bouncing mass."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from petsc4py import PETSc

from conftest import ConstantLoad
from fem_impact.nonsmooth.lcp import solve_lcp
from fem_impact.integrators import MoreauJean, Newmark, Operators, integrate

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
    """Mass m at height h0 above the floor: u is the displacement (up), P u = -u <= h0."""
    ops = Operators(one_by_one(m), one_by_one(0.0), None, ConstantLoad(-m * g),
                    np.array([[-1.0]]), np.array([h0]), np.array([e]))
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
