"""The small cone problem solved whole in one compiled call (nonsmooth/small_kernel.py) against the general
solver (the sweeps with Newton's retries, friction.py) and against Coulomb's law itself, row by row."""

from __future__ import annotations

import numpy as np
import pytest

from fem_impact.nonsmooth import small_kernel
from fem_impact.nonsmooth.friction import FrictionProblem


def random_problem(rng, hard=False):
    """A cone problem of 1 to 7 rows in 2D or 3D, some rows without friction, a fifth of them open. ``hard``:
    W singular or nearly (a rigid body's rows), mu up to 5: Newton's method may stop short there."""
    dim, p = int(rng.integers(2, 4)), int(rng.integers(1, 8))
    n = p * dim
    A = rng.normal(size=(n, n))
    if hard:
        W = A @ A.T * float(rng.choice([1e-3, 1.0])) + float(rng.choice([0.0, 0.01])) * np.eye(n)
        mu = rng.choice([0.0, 0.3, 1.0, 5.0], size=p)
    else:   # (W well conditioned, mu small: one solution)
        W = A @ A.T / n + np.eye(n)
        mu = rng.choice([0.0, 0.1, 0.3, 0.5], size=p)
    q = np.concatenate([rng.normal(size=p) - 0.5, rng.normal(size=p * (dim - 1))])
    return W, np.repeat(np.arange(p), dim - 1), mu, q, rng.random(p) < 0.8


def assert_coulomb(W, tangent_of, mu, q, active, sol, tol=1e-8):
    """Signorini's and Coulomb's conditions on every row, from r and y = W r + q themselves."""
    p = mu.size
    y = W @ sol.r + q
    np.testing.assert_allclose(sol.y, y, rtol=0, atol=1e-12 * max(1.0, np.abs(q).max()))
    size = tol * max(1.0, np.abs(q).max(), np.abs(sol.r).max())
    for i in range(p):
        t = p + np.flatnonzero(tangent_of == i)
        r_n, r_t, y_n, y_t = sol.r[i], sol.r[t], y[i], y[t]
        if not active[i]:
            assert r_n == 0.0 and not np.any(r_t)
            continue
        assert r_n >= -size and y_n >= -size and abs(r_n * y_n) <= size * max(1.0, abs(r_n), abs(y_n))
        if mu[i] == 0.0 or not t.size:
            assert np.abs(r_t).max(initial=0.0) <= size
            continue
        assert np.linalg.norm(r_t) <= mu[i] * r_n + size
        if r_n > size and np.linalg.norm(y_t) > size:   # slipping: the impulse opposes the velocity, on the edge
            np.testing.assert_allclose(r_t, -mu[i] * r_n * y_t / np.linalg.norm(y_t), rtol=0, atol=10 * size)


def test_the_compiled_small_solve_is_the_general_solvers_on_random_problems():
    rng = np.random.default_rng(11)
    for _ in range(300):
        W, tangent_of, mu, q, active = random_problem(rng)
        small = FrictionProblem(W, tangent_of, mu)
        sol = small.solve(q, active)
        general = FrictionProblem(W, tangent_of, mu, newton_first=False).solve(q, active)   # (no compiled path)
        assert sol.converged and general.converged and sol.sweeps == 0 and sol.newton == 0
        assert sol.residual <= FrictionProblem.TOLERANCE
        np.testing.assert_allclose(sol.r, general.r, rtol=0, atol=1e-8 * max(1.0, np.abs(general.r).max()))
        assert_coulomb(W, tangent_of, mu, q, active, sol)
        again = small.solve(q, active, guess=sol.r)   # (warm-started from its own solution: the same)
        np.testing.assert_allclose(again.r, sol.r, rtol=0, atol=1e-12 * max(1.0, np.abs(sol.r).max()))


def test_what_the_compiled_solve_cannot_finish_goes_on_in_the_general_solver():
    """Where Newton's method stops short (singular W, mu up to 5) the sweeps go on from its best iterate: the
    solve converges wherever the general solver does, and the answer obeys Coulomb's law."""
    rng = np.random.default_rng(1)
    outcomes = []
    for _ in range(400):
        W, tangent_of, mu, q, active = random_problem(rng, hard=True)
        problem = FrictionProblem(W, tangent_of, mu)
        kernel = small_kernel.solve(problem.upper, q, np.zeros(0), active, problem._small_numbers,
                                    problem._small_layout, FrictionProblem.TOLERANCE, FrictionProblem.SMALL)
        outcomes.append(int(kernel[-1]))
        sol = problem.solve(q, active)
        general = FrictionProblem(W, tangent_of, mu, newton_first=False).solve(q, active)
        assert sol.converged or not general.converged
        if sol.converged:
            assert sol.residual <= FrictionProblem.TOLERANCE
    assert small_kernel.SHORT in outcomes and small_kernel.DONE in outcomes


def test_a_singular_jacobian_hands_the_problem_over():
    """A sticking guess on a tangent row whose W row is zero: Newton's J has an exact zero pivot (the kernel
    says SINGULAR); the sweeps find the slip, r = (1, -mu)."""
    W, q = np.array([[1.0, 0.0], [0.0, 0.0]]), np.array([-1.0, 0.1])
    problem = FrictionProblem(W, np.array([0]), np.array([0.3]))
    out = small_kernel.solve(problem.upper, q, np.zeros(0), np.array([True]), problem._small_numbers,
                             problem._small_layout, FrictionProblem.TOLERANCE, FrictionProblem.SMALL)
    assert out[-1] == small_kernel.SINGULAR
    sol = problem.solve(q, np.array([True]))
    assert sol.converged and sol.r == pytest.approx([1.0, -0.3], abs=1e-14)


def test_no_closed_row_and_too_many_unknowns():
    rng = np.random.default_rng(2)
    p = 40   # 2D: 80 unknowns, more than SMALL (60): the general solver, the same answer
    A = rng.normal(size=(2 * p, 2 * p))
    W = A @ A.T / (2 * p) + np.eye(2 * p)
    q = np.concatenate([rng.normal(size=p) - 0.5, rng.normal(size=p)])
    tangent_of, mu = np.arange(p), np.full(p, 0.3)
    problem = FrictionProblem(W, tangent_of, mu)
    none = problem.solve(q, np.zeros(p, bool))
    assert none.converged and not np.any(none.r) and np.array_equal(none.y, q)
    out = small_kernel.solve(problem.upper, q, np.zeros(0), np.ones(p, bool), problem._small_numbers,
                             problem._small_layout, FrictionProblem.TOLERANCE, FrictionProblem.SMALL)
    assert out[-1] == small_kernel.TOO_MANY
    sol = problem.solve(q, np.ones(p, bool))
    assert sol.converged and sol.sweeps > 0
    assert_coulomb(W, tangent_of, mu, q, np.ones(p, bool), sol)
    few = np.zeros(p, bool)
    few[:20] = True   # (40 unknowns closed of 80: the compiled path)
    sol = problem.solve(q, few)
    assert sol.converged and sol.sweeps == 0
    assert_coulomb(W, tangent_of, mu, q, few, sol)


def test_the_2d_row_residual_in_scalars_is_the_cone_projections():
    """cone._row_residual_at takes a 2D row in scalars: against the natural map through project_on_cone, on
    every branch (inside the cone, in its polar cone, on its edge; mu = 0; sliding either way)."""
    from fem_impact.nonsmooth.friction import project_on_cone, row_residual

    rng = np.random.default_rng(5)
    for _ in range(2000):
        r, y = rng.normal(size=2) * rng.choice([0.0, 1.0], size=2), rng.normal(size=2)
        mu, rho = float(rng.choice([0.0, 0.2, 1.0, 3.0])), float(rng.uniform(0.1, 10.0))
        z_n, z_t = r[0] - rho * (y[0] + mu * abs(y[1])), np.array([r[1] - rho * y[1]])
        p_n, p_t = project_on_cone(z_n, z_t, mu)
        expected = np.hypot(r[0] - p_n, r[1] - p_t[0])
        assert row_residual(r, y, mu, rho) == pytest.approx(expected, rel=1e-12, abs=1e-14)


def _planar(rng, p):
    """A 2D problem of p rows, each a normal and one tangent, in the kernel's row order (N, T per row)."""
    A = rng.normal(size=(2 * p, 2 * p))
    W = A @ A.T / (2 * p) + np.eye(2 * p)
    q = rng.normal(size=2 * p)
    q[0::2] -= 0.5
    return W, q, rng.choice([0.0, 0.1, 0.3, 0.8], size=p)


def test_the_active_set_method_solves_planar_problems_by_itself():
    """In 2D the kernel's active-set method (statuses read from the natural map, each status's linear system
    solved on its own unknowns) settles on its own where W is well conditioned, and where it settles Coulomb's
    law holds on every row and the solution is the general solver's."""
    rng = np.random.default_rng(21)
    ended = 0
    for _ in range(300):
        p = int(rng.integers(1, 11))
        W, q, mu = _planar(rng, p)
        starts, sizes = np.arange(0, 2 * p, 2), np.full(p, 2)
        rho = 1.0 / np.diag(W)[0::2]
        r = np.zeros(2 * p)
        work, ints = np.empty(4 * p + 4 * p * p), np.empty(2 * p, dtype=np.int64)
        done = small_kernel._active_set(W, q, r, starts, sizes, rho, mu, work, ints)
        if not done:   # (statuses cycling: the damped Newton method's, tested above)
            continue
        ended += 1
        caller = np.r_[0:2 * p:2, 1:2 * p:2]   # (normal rows first, then the tangents)
        W_c, q_c = W[np.ix_(caller, caller)], q[caller]
        sol = FrictionProblem(W_c, np.arange(p), mu).solve(q_c, np.ones(p, bool))
        general = FrictionProblem(W_c, np.arange(p), mu, newton_first=False).solve(q_c, np.ones(p, bool))
        np.testing.assert_allclose(r[caller], general.r, rtol=0, atol=1e-8 * max(1.0, np.abs(general.r).max()))
        np.testing.assert_allclose(sol.r, r[caller], rtol=0, atol=1e-12 * max(1.0, np.abs(r).max()))
        assert_coulomb(W_c, np.arange(p), mu, q_c, np.ones(p, bool), sol)
    assert ended >= 270   # (on these it cycles rarely: the fallback is not the rule)


def test_the_active_set_method_reads_each_status():
    """One row, W = diag(2, 1), mu = 0.5: pressed and dragged below mu |r_N| it sticks (y = 0), above it slips
    with r_T = -+mu r_N and y_N = 0, pulled away it stays open; the exact impulses of each case."""
    W, mu = np.diag([2.0, 1.0]), np.array([0.5])
    for q, expected in (([-2.0, 0.3], [1.0, -0.3]),       # stick: r = -W^-1 q
                        ([-2.0, 0.9], [1.0, -0.5]),       # slip: r_N = 1, r_T = -mu r_N
                        ([-2.0, -0.9], [1.0, 0.5]),
                        ([0.5, 0.9], [0.0, 0.0])):        # open
        r = np.zeros(2)
        done = small_kernel._active_set(W, np.array(q), r, np.array([0]), np.array([2]), np.array([0.5]), mu,
                                        np.empty(8), np.empty(2, dtype=np.int64))
        assert done and r == pytest.approx(expected, abs=1e-15)
