"""Coulomb friction (docs/theory.md s. 11) against exact answers.

- A point mass hitting a floor obliquely (v_N = -1, v_T = 0.5 in 2D, (0.3, 0.4) in 3D, e = 0.5): with
  mu = 0.2 it leaves sliding, |v_T| reduced by mu (1 + e) |v_N|; with mu = 0.5 it sticks (v_T = 0).
- An elastic block sliding on a floor under gravity with speed v0 decelerates at mu g and stops at
  v0 / (mu g) after v0^2 / (2 mu g), then stays where it stopped.
- A block on an incline (gravity turned by theta) stays at rest when tan(theta) <= mu, else slides
  with acceleration g (sin theta - mu cos theta).
- A free strip hitting a wall end-on while sliding along it: its tangential momentum changes by mu
  times the change of its normal momentum, against the slip.
- The position level (the default, docs/theory.md s. 11): a point mass landing within a step holds its
  gap and leaves by Newton's and Coulomb's impact laws on the whole impulse; the sliding block and a
  plate landing while sliding at Courant numbers 5 and 50 keep their gaps to round-off at every step
  (the velocity level lets them sink), the block's whole tangential impulse mu times its normal one.
Every run: the friction loss never decreases from one step to the next, and E <= E0 + W_ext.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import CASES, ConstantLoad
import fem_impact as fi
from fem_impact.errors import CaseError, ContactSolverError
from fem_impact.integrators import MoreauJean, Operators, integrate
from fem_impact.nonsmooth.friction import FrictionProblem, project_on_cone, row_residual, solve_row
from fem_impact.nonsmooth.relation import tangent_basis

G = 9.81


class Rows:
    def __init__(self):
        self.states = []

    def write(self, s):
        self.states.append((s.t, s.V.copy(), s.energy.copy()))


def point_impact(dim, mu, e=0.5, m=2.0, dt=1e-3):
    """A point mass at the floor (gap 0) moving down at 1 and along it: v after three steps."""
    normal = np.zeros(dim)
    normal[1] = -1.0
    tangents = tangent_basis(normal)
    v0 = np.zeros(dim)
    v0[1] = -1.0
    v_t = np.array([0.5]) if dim == 2 else np.array([0.3, 0.4])
    for t, c in zip(tangents, v_t):
        v0 += c * t
    ops = Operators(np.full(dim, m), np.zeros(dim), None, ConstantLoad(0.0), normal[:, None], np.zeros(1),
                    np.array([e]), friction=np.array([mu]), tangents=np.array(tangents).T,
                    tangent_of=np.zeros(dim - 1, dtype=int))
    rec = Rows()
    integrate(MoreauJean(ops, dt), np.zeros(dim), v0.copy(), 3 * dt, [rec])
    v = rec.states[-1][1]
    return v.dot(normal), np.array([v.dot(t) for t in tangents]), v_t, rec


@pytest.mark.parametrize("dim", [2, 3])
def test_an_oblique_impact_that_slides_loses_mu_1_plus_e_of_the_normal_speed(dim):
    v_n, v_t, v_t0, rec = point_impact(dim, mu=0.2)
    assert v_n == pytest.approx(-0.5, abs=1e-12)    # leaves at e |v_N| (the normal points into the floor)
    speed0 = np.linalg.norm(v_t0)
    expected = v_t0 * (speed0 - 0.2 * 1.5) / speed0  # same direction, reduced by mu (1 + e) |v_N|
    assert np.allclose(v_t, expected, rtol=0, atol=1e-8)
    for _, _, energy in rec.states:
        assert energy.friction_loss >= 0.0 and energy.error == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_an_oblique_impact_inside_the_cone_sticks(dim):
    v_n, v_t, _, rec = point_impact(dim, mu=0.5)
    assert v_n == pytest.approx(-0.5, abs=1e-12)
    assert np.abs(v_t).max() <= 1e-8
    # The friction impulse took the whole tangential kinetic energy, 1/2 m |v_T|^2 = 0.25 J.
    assert rec.states[-1][2].friction_loss == pytest.approx(0.25, rel=1e-9)


def test_a_point_mass_sliding_to_rest_stops_where_coulomb_says_and_stays():
    """m = 2 sliding at 2 m/s on a floor under gravity, mu = 0.3, dt = 0.01 (68 steps to the stop): it
    stops after v0^2 / (2 mu g) and then has no velocity at all (the slip law alone would leave it
    alternating +-1.2e-3 m/s: Carnot's correction, a frictional impact problem at the position level,
    removes that, as the tangential one at the velocity level); the friction
    loss grows every step (a persisting contact) and the balance closes."""
    m, mu, v0, dt = 2.0, 0.3, 2.0, 1e-2
    ops = Operators(np.full(2, m), np.zeros(2), None, ConstantLoad(np.array([0.0, -m * G])),
                    np.array([[0.0], [-1.0]]), np.zeros(1), np.zeros(1), friction=np.array([mu]),
                    tangents=np.array([[1.0], [0.0]]), tangent_of=np.zeros(1, dtype=int))
    rec = Rows()
    integrate(MoreauJean(ops, dt), np.zeros(2), np.array([v0, 0.0]), 1.0, [rec])
    t = np.array([s[0] for s in rec.states])
    v = np.array([s[1][0] for s in rec.states])
    loss = np.array([s[2].friction_loss for s in rec.states])
    stop = v0 / (mu * G)
    assert np.all(v[t > stop + dt] == 0.0)
    sliding = t < stop - dt
    assert np.allclose(v[sliding], v0 - mu * G * t[sliding], rtol=0, atol=1e-12)   # exact: a constant force
    assert np.all(np.diff(loss) >= 0.0)
    assert loss[-1] == pytest.approx(0.5 * m * v0 ** 2, rel=1e-12)                   # all of it, to friction
    assert max(abs(s[2].error) for s in rec.states) <= 1e-12 * loss[-1]


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("e", [0.0, 0.5])
@pytest.mark.parametrize("within", [0.0, 0.3, 0.7])
def test_a_point_mass_landing_within_a_step_holds_its_gap_and_takes_the_impact_law(dim, e, within):
    """The position level (the default): a point mass 2 kg hitting the floor at v_N = 1 and sliding at 0.5
    (2D; (0.3, 0.4) in 3D), from a gap ``within`` times v_N dt, mu = 0.2. The step holds the gap (0 to
    round-off at its end) with a normal impulse 2 m v_N (1 - within), its friction mu times that;
    Carnot's correction, a frictional impact problem in the total impulse, leaves the total m v_N (1 + e)
    with mu times it tangentially, whatever ``within``: the velocity level's impact, exactly. The
    contacts lose (1 - e^2)/2 m v_N^2 normally and the friction what it took."""
    m, mu, dt = 2.0, 0.2, 1e-3
    normal = np.zeros(dim)
    normal[1] = -1.0
    tangents = tangent_basis(normal)
    v_t0 = np.array([0.5]) if dim == 2 else np.array([0.3, 0.4])
    v0 = normal + sum(c * t for t, c in zip(tangents, v_t0))   # (P V = 1: approaching)
    ops = Operators(np.full(dim, m), np.zeros(dim), None, ConstantLoad(0.0), normal[:, None],
                    np.array([within * dt]), np.array([e]), friction=np.array([mu]), tangents=np.array(tangents).T,
                    tangent_of=np.zeros(dim - 1, dtype=int))
    scheme = MoreauJean(ops, dt)
    gaps = []

    class Gaps(Rows):
        def write(self, s):
            super().write(s)
            gaps.append(float(s.gap[0]))

    rec = Gaps()
    integrate(scheme, np.zeros(dim), v0.copy(), 3 * dt, [rec])
    assert abs(gaps[1]) <= 1e-15 * dt                                 # held at the end of the impact's step
    assert min(gaps) >= -1e-15 * dt
    v = rec.states[1][1]
    assert v.dot(normal) == pytest.approx(-e, abs=1e-12)              # Newton: it leaves at e v_N
    speed0 = np.linalg.norm(v_t0)
    expected = v_t0 * (speed0 - mu * (1.0 + e)) / speed0              # Coulomb on the whole impulse
    assert np.allclose([v.dot(t) for t in tangents], expected, rtol=0, atol=1e-12)
    energy = rec.states[-1][2]
    normal_loss = energy.impact_loss + energy.contact_loss
    assert normal_loss == pytest.approx(0.5 * m * (1.0 - e * e), rel=1e-9)
    slide_loss = 0.5 * m * (speed0 ** 2 - (speed0 - mu * (1.0 + e)) ** 2)
    assert energy.friction_loss == pytest.approx(slide_loss, rel=1e-9)
    assert scheme.friction_scaled == 0
    assert max(abs(s[2].error) for s in rec.states) <= 1e-12


def test_the_cone_projection_and_the_row_solver_agree_with_the_law():
    rng = np.random.default_rng(3)
    for _ in range(200):
        dim = int(rng.integers(2, 4))
        A = rng.normal(size=(dim, dim))
        W = A @ A.T + dim * np.eye(dim)
        q = rng.normal(size=dim)
        mu = float(rng.uniform(0.0, 1.5))
        # From no start, and (3D: the slip direction is sought by Newton's method from the start's
        # direction, then among the quartic's roots) from any start.
        for start in (None, rng.normal(size=dim), np.zeros(dim)):
            r = solve_row(W, q, mu, start)
            assert row_residual(r, W @ r + q, mu, 1.0 / W[0, 0]) <= 1e-9 * max(np.abs(q).max(), 1.0)
            assert np.linalg.norm(r[1:]) <= mu * r[0] * (1 + 1e-12) + 1e-15
    r_n, r_t = project_on_cone(1.0, np.array([3.0, 4.0]), 0.5)   # onto the cone's surface
    assert np.linalg.norm(r_t) == pytest.approx(0.5 * r_n)


def test_the_sweeps_row_solve_into_reused_buffers_is_the_row_solvers():
    """The sweeps solve each row into buffers reused from row to row (cone.solve_row_into): whatever an earlier
    row left in them, the answer is solve_row's, to the bit, on open, sticking and slipping rows in 2D and 3D."""
    from fem_impact.nonsmooth import cone

    rng = np.random.default_rng(8)
    r, scratch = {2: np.empty(2), 3: np.empty(3)}, {2: np.empty(4), 3: np.empty(6)}
    kinds = set()
    for _ in range(300):
        dim = int(rng.integers(2, 4))
        A = rng.normal(size=(dim, dim))
        W = A @ A.T + dim * np.eye(dim)
        q, mu, start = rng.normal(size=dim), float(rng.uniform(0.0, 1.5)), rng.normal(size=dim)
        cone.solve_row_into(W, q, mu, start, r[dim], scratch[dim])
        expected = solve_row(W, q, mu, start)
        assert np.array_equal(r[dim], expected)
        kinds.add("open" if not expected[0] else "stick" if np.linalg.norm(W @ expected + q) < 1e-12 else "slip")
    assert kinds == {"open", "stick", "slip"}


@pytest.mark.parametrize("single", [False, True], ids=["float64 W", "float32 parts"])
def test_a_start_whose_product_the_caller_gives_is_solved_to_the_same_bits(monkeypatch, single):
    """Carnot's frictional problem hands the solve W guess, which its q needed anyway (guess_product): the
    start's y is then taken from it, not from a second product, and the solution is the same to the bit. A
    guess with impulses off the active rows is not the start: its product is left unused."""
    if single:
        monkeypatch.setattr(FrictionProblem, "SINGLE_FROM", 0)
    rng = np.random.default_rng(11)
    rows = 40   # 3D: 120 unknowns, past the small path
    A = rng.normal(size=(3 * rows, 3 * rows)) / np.sqrt(3 * rows)
    W = A @ A.T + np.eye(3 * rows)
    tangent_of, mu = np.repeat(np.arange(rows), 2), np.full(rows, 0.3)
    q = np.concatenate([-rng.uniform(0.5, 1.0, rows), rng.normal(size=2 * rows)])
    active = rng.random(rows) < 0.8
    held = np.concatenate([active, active[tangent_of]])
    products = []
    counted = FrictionProblem.product
    monkeypatch.setattr(FrictionProblem, "product", lambda self, x: products.append(1) or counted(self, x))
    starts = (np.where(held, rng.uniform(0.0, 0.2, 3 * rows), 0.0), rng.uniform(0.0, 0.2, 3 * rows))
    for guess, saved in zip(starts, (1, 0), strict=True):
        products.clear()
        plain = FrictionProblem(W, tangent_of, mu).solve(q, active, guess)
        count = len(products)
        problem = FrictionProblem(W, tangent_of, mu)
        product = problem.multiply(guess)
        products.clear()
        given = problem.solve(q, active, guess, guess_product=product)
        assert len(products) == count - saved
        assert plain.converged and given.converged and given.sweeps == plain.sweeps
        assert np.array_equal(given.r, plain.r) and np.array_equal(given.y, plain.y)


def test_a_start_that_newton_replaced_does_not_take_the_callers_product(monkeypatch):
    """A small problem's compiled Newton may hand the sweeps its own best start (short of the tolerance): the
    caller's product of its guess is then not that start's, and must be left unused (here a wrong one: the same
    bits as without it)."""
    monkeypatch.setattr(FrictionProblem, "TOLERANCE", 0.0)   # (Newton's best is short of it: the sweeps go on)
    monkeypatch.setattr(FrictionProblem, "MAX_SWEEPS", 3)
    rng = np.random.default_rng(12)
    rows = 4   # 2D: 8 unknowns, the small path
    A = rng.normal(size=(2 * rows, 2 * rows))
    W = A @ A.T + 2 * rows * np.eye(2 * rows)
    tangent_of, mu, active = np.arange(rows), np.full(rows, 0.3), np.ones(rows, bool)
    q = np.concatenate([-rng.uniform(0.5, 1.0, rows), rng.normal(size=rows)])
    guess = rng.uniform(0.0, 0.2, 2 * rows)
    plain = FrictionProblem(W, tangent_of, mu).solve(q, active, guess)
    given = FrictionProblem(W, tangent_of, mu).solve(q, active, guess, guess_product=np.zeros(2 * rows))
    assert plain.sweeps == given.sweeps == 3 and not given.converged
    assert np.array_equal(given.r, plain.r) and np.array_equal(given.y, plain.y)


def test_the_float32_sweeps_end_on_the_same_certified_solution(monkeypatch):
    """Many rows: the sweeps run on a float32 copy of W, y = W r + q is made exact between rounds and
    the residual is judged on it. The solution is the float64 sweeps' to the tolerance."""
    rng = np.random.default_rng(5)
    rows = 60   # 3D: 180 unknowns, coupled like neighbouring nodes of a face
    A = rng.normal(size=(3 * rows, 3 * rows)) / np.sqrt(3 * rows)
    W = A @ A.T + np.eye(3 * rows)
    q = np.concatenate([-rng.uniform(0.5, 1.0, rows), rng.normal(size=2 * rows)])
    tangent_of, mu, active = np.repeat(np.arange(rows), 2), np.full(rows, 0.3), np.ones(rows, bool)
    plain = FrictionProblem(W, tangent_of, mu).solve(q, active)
    monkeypatch.setattr(FrictionProblem, "SINGLE_FROM", 0)
    single = FrictionProblem(W, tangent_of, mu)
    assert single.lower.size and single.upper.dtype == np.float32   # (W as two float32 parts)
    sol = single.solve(q, active)
    assert plain.converged and sol.converged and sol.residual <= FrictionProblem.TOLERANCE
    assert np.abs(sol.y - (W @ sol.r + q)).max() <= 1e-12 * np.abs(q).max()
    assert np.abs(sol.r - plain.r).max() <= 1e-8 * np.abs(plain.r).max()
    again = single.solve(q + 0.01, active, guess=sol.r)   # warm start: the last solution's W r reused
    in_place = FrictionProblem(W.copy(), tangent_of, mu, overwrite=True)   # (W permuted in its own memory)
    np.testing.assert_array_equal(in_place.upper, single.upper)
    np.testing.assert_array_equal(in_place.lower, single.lower)
    W_ordered = W[np.ix_(single.order, single.order)]
    assert np.abs(single.upper.astype(float) + single.lower - W_ordered).max() <= 1e-14 * np.abs(W).max()
    assert again.converged and np.abs(again.y - (W @ again.r + q + 0.01)).max() <= 1e-12 * np.abs(q).max()


def test_friction_without_numba_says_what_to_install(monkeypatch):
    import sys

    from fem_impact.errors import SimulationError

    import fem_impact.nonsmooth

    monkeypatch.setitem(sys.modules, "fem_impact.nonsmooth.cone", None)   # (as if Numba could not be imported)
    monkeypatch.delattr(fem_impact.nonsmooth, "cone", raising=False)
    with pytest.raises(SimulationError, match="python3-numba"):
        FrictionProblem(np.eye(2), np.array([0]), np.array([0.3]))


def test_an_unsolved_contact_problem_is_reported_not_accepted(monkeypatch):
    """Coupled rows need several sweeps: with one allowed, the solve misses its tolerance and says so. (A
    small problem starts with Newton's method, which solves this one to round-off without a sweep.)"""
    W = np.array([[2.0, 0.9, 0.5, 0.3], [0.9, 2.0, 0.2, 0.4], [0.5, 0.2, 1.0, 0.1], [0.3, 0.4, 0.1, 1.0]])
    q = np.array([-1.0, -0.5, 0.8, -0.6])
    problem = FrictionProblem(W, np.array([0, 1]), np.array([0.3, 0.3]), newton_first=False)
    monkeypatch.setattr(FrictionProblem, "MAX_SWEEPS", 1)
    sol = problem.solve(q, np.array([True, True]))
    assert not sol.converged and sol.residual > FrictionProblem.TOLERANCE
    first = FrictionProblem(W, np.array([0, 1]), np.array([0.3, 0.3])).solve(q, np.array([True, True]))
    assert first.converged and first.sweeps == 0 and first.residual <= 1e-15
    monkeypatch.setattr(FrictionProblem, "MAX_SWEEPS", 2000)
    sol = problem.solve(q, np.array([True, True]))
    assert sol.converged and sol.residual <= FrictionProblem.TOLERANCE
    assert sol.r == pytest.approx(first.r, rel=1e-9, abs=1e-12)


# --- an elastic block on a rigid floor ------------------------------------------------------

def block(dim, mu, gravity, v0=0.0, dt=2e-3, t_end=1.0, cells=8, solver=None):
    """A block 0.2 x 0.05 (x 0.05), E = 1e7, rho = 1000 (c = 100 m/s, h = 0.025: dt = 2e-3 is a
    Courant number of 8), nu = 0, on a floor at its bottom face, under the acceleration ``gravity``."""
    mesh = {"shape": "bar", "dim": dim, "length": 0.2, "height": 0.05, "cells": cells}
    pad = [0.0] * (dim - 2)
    if dim == 3:
        mesh["width"] = 0.05
    data = {"name": "block", "mesh": mesh,
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.0, **({"area": 1.0} if dim == 2 else {})},
            "initial": {"velocity": [v0, 0.0] + pad},
            "loads": [{"body": "all", "acceleration": list(gravity) + pad}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0] + pad,
                          "gap": 0.0, "friction": mu}],
            "solver": {"dt": dt, "t_end": t_end, **(solver or {})}, "output": {"vtk": False}}
    result = fi.run(fi.Case.from_dict(data))
    h = result.history
    return h, h["bar.px"] / result.summary["body_mass"]["bar"], result.summary


def check_energy(h, tolerance=1e-9, balance=1e-9):
    """E <= E0 + W_ext, the losses non-negative, and the balance closed (to ``balance`` of the scale)."""
    energy = h["kinetic"] + h["strain"]
    scale = max(energy[0] + h["external_work"].max(), 1e-300)
    assert np.all(energy - energy[0] - h["external_work"] <= tolerance * scale)
    # Every step, to round-off of the friction's own work (a block held on an incline: 1e-4 J in all).
    assert np.diff(h["friction_loss"]).min() >= -1e-9 * max(scale, h["friction_loss"].max())
    assert np.abs(h["energy_error"]).max() <= balance * scale


@pytest.mark.parametrize("dim", [2, 3])
def test_a_sliding_block_stops_where_coulomb_says(dim):
    mu, v0 = 0.3, 2.0
    h, v, summary = block(dim, mu, (0.0, -G), v0=v0, t_end=0.9, cells=8 if dim == 2 else 4)
    t = h["t"]
    sliding = (t > 0.05) & (t < 0.6)
    slope, intercept = np.polyfit(t[sliding], v[sliding], 1)
    assert slope == pytest.approx(-mu * G, rel=0.01)
    assert -intercept / slope == pytest.approx(v0 / (mu * G), rel=0.01)    # the stop
    travel = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    assert travel[-1] == pytest.approx(v0 ** 2 / (2 * mu * G), rel=0.01)
    after = t > 1.05 * v0 / (mu * G)
    assert np.ptp(travel[after]) <= 0.01 * travel[-1]                        # at rest
    check_energy(h)
    assert summary["max_friction_residual"] <= FrictionProblem.TOLERANCE


def test_a_sliding_block_holds_its_gaps_every_step_and_slides_by_coulombs_law():
    """The position level with friction (the default): the block of the test above stops at v0 / (mu g)
    with its bottom face on the floor to round-off at the end of every step (the velocity level lets it
    sink by 2e-5 m, dt times the speeds its bottom nodes bounce at), and while it slides every step's
    whole tangential impulse is mu times its whole normal impulse (Carnot's correction included: the
    cone problem holds Coulomb's law on the total)."""
    mu, v0, dt = 0.3, 2.0, 2e-3
    h, v, summary = block(2, mu, (0.0, -G), v0=v0, t_end=0.9, dt=dt)
    t = h["t"]
    sliding = (t > 0.05) & (t < 0.6)
    slope, intercept = np.polyfit(t[sliding], v[sliding], 1)
    assert slope == pytest.approx(-mu * G, rel=0.01)
    assert -intercept / slope == pytest.approx(v0 / (mu * G), rel=0.01)
    assert h["floor.gap"].min() >= -1e-12 * v0 * dt                              # every step: round-off
    ratio = h["floor.tangential_force"][sliding] * dt / h["floor.impulse"][sliding]
    assert np.abs(ratio - mu).max() <= 1e-12 * mu
    check_energy(h)
    assert summary["energy_created"] == 0.0 and summary["friction_corrections_scaled"] == 0
    drift = block(2, mu, (0.0, -G), v0=v0, t_end=0.9, dt=dt, solver={"level": "velocity"})[0]["floor.gap"].min()
    assert drift < -1e-6


def plate_sliding(cells, courant, level="position", t_end=12.0):
    """The plate of verification.md's friction map (cases/plate_drop.yaml, nu = 0, mu = 0.3, e = 0): it falls
    at 1 onto the floor 0.1 away while sliding at (0.5, 0.3) and pushed down at 0.5, so it lands again and
    again; its displacement scale v0 L / c is 1."""
    case = fi.load_case(CASES / "plate_drop.yaml")
    dt = courant / cells
    changes = {"mesh.cells": cells, "solver.dt": dt, "solver.t_end": t_end + 4 * dt, "contacts.0.friction": 0.3,
               "initial.velocity": [-1.0, 0.5, 0.3], "loads": [{"body": "all", "acceleration": [-0.5, 0.0, 0.0]}],
               "solver.level": level, "output.vtk": False}
    return fi.run(case.with_changes(changes))


@pytest.mark.parametrize("courant, iterative", [(5.0, False), (50.0, False), (50.0, True)],
                         ids=["5", "50", "50-gmres-newton"])
def test_a_plate_landing_while_sliding_far_above_courant_one_holds_its_gaps_and_gives_no_energy(courant, iterative,
                                                                                               monkeypatch):
    """121 rows with friction landing while they slide, at Courant numbers 5 and 50: with friction the
    gaps close at the end of every step as without it (round-off of the displacement scale; the velocity
    level leaves the face up to 1.4 of it inside the floor at Courant 5), E <= E0 + W_ext at every step,
    every loss grows, the balance closes, and the contact stays the cone problem's (every solve within
    its tolerance). At Courant 50 the sweeps crawl and Newton's method takes over: its direction by dense LU
    here, and by GMRES (the path of 1500 unknowns and more, FrictionProblem._newton_iterative) with the
    threshold lowered to these 363."""
    if iterative:
        monkeypatch.setattr(FrictionProblem, "ITERATIVE_FROM", 300)
    result = plate_sliding(2, courant)
    h, summary = result.history, result.summary
    assert summary["constraints"] == 121
    assert h["friction_loss"][-1] > 0.0 and np.count_nonzero(h["floor.impulse"] > 0.0) >= 2   # it landed and slid
    assert h["floor.gap"].min() >= -1e-13
    check_energy(h)
    normal = h["impact_loss"] + h["contact_loss"]   # (the step's and its correction's: one guard each, s. 11)
    assert np.diff(normal).min() >= -1e-12 * (h["kinetic"][0] + h["external_work"].max())
    assert summary["energy_created"] == 0.0
    assert summary["max_friction_residual"] <= FrictionProblem.TOLERANCE
    if courant == 5.0:
        assert plate_sliding(2, courant, "velocity").history["floor.gap"].min() < -0.1
    if courant == 50.0:   # (the sweeps did not solve it alone)
        assert summary["friction_retries"] > 0


@pytest.mark.parametrize("dim, seed", [(3, 0), (3, 1), (2, 0)])
def test_newtons_direction_by_gmres_solves_a_nearly_rigid_face_as_the_dense_one(dim, seed, monkeypatch):
    """A nearly rigid body on many rows (600 unknowns in 2D and 3D; W = H B M^-1 B^T H^T of a rigid block, plus
    a compliance 1e-4 of it), landing while it slides, mu 0.3, a tenth of its rows open (not active): the
    sweeps crawl; Newton's method with its direction by GMRES (FrictionProblem._newton_iterative, its
    threshold lowered from 1500 unknowns to these) and by dense LU reach the tolerance, with the same
    impulses (unique here: W positive definite) to 1e-7 of their size, none on the open rows, and Coulomb's
    law on the solution."""
    rng = np.random.default_rng(seed)
    p = 200 if dim == 3 else 300
    nt = dim - 1
    x = np.column_stack([rng.uniform(-1, 1, p), rng.uniform(-1, 1, p), np.zeros(p)])
    frames = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    if dim == 2:   # (the plane x, z: normal -z, tangent x, rotation about y)
        frames = frames[:2]
    full = np.zeros((p * dim, 6))   # rows in the caller's order: normals first, then each row's tangents
    for k, axis in enumerate(frames):
        rows = np.arange(p) if k == 0 else p + nt * np.arange(p) + (k - 1)
        full[rows, :3] = axis
        full[rows, 3:] = np.cross(x, axis)   # (axis . (w x x) = w . (x x axis))
    H = full if dim == 3 else full[:, [0, 2, 4]]
    M = np.diag([1.0, 1.0, 1.0, 0.3, 0.3, 0.6]) if dim == 3 else np.diag([1.0, 1.0, 0.3])
    L = rng.standard_normal((p * dim, p * dim)) / np.sqrt(p * dim)
    W = H @ np.linalg.inv(M) @ H.T + 1e-4 * (L @ L.T + np.eye(p * dim))
    tangent_of = np.repeat(np.arange(p), nt)
    q = np.concatenate([np.full(p, -1.0), np.tile([0.5, 0.3][:nt], p)])   # approaching at 1, sliding
    mu = np.full(p, 0.3)
    active = rng.random(p) > 0.1
    solutions = {}
    for name, threshold in (("gmres", 500), ("dense", 10 ** 9)):
        monkeypatch.setattr(FrictionProblem, "ITERATIVE_FROM", threshold)
        sol = FrictionProblem(W, tangent_of, mu).solve(q, active)
        assert sol.converged and sol.residual <= FrictionProblem.TOLERANCE, name
        assert sol.newton > 0, name   # (the sweeps did not solve it alone)
        solutions[name] = sol
    a, b = solutions["gmres"].r, solutions["dense"].r
    assert np.abs(a - b).max() <= 1e-7 * np.abs(b).max()
    assert not np.count_nonzero(a[:p][~active]) and not np.count_nonzero(a[p:][np.repeat(~active, nt)])
    y = W @ a + q   # Coulomb's law on the solution: y_N >= 0 where pressed, r_N >= 0, |r_T| <= mu r_N
    assert a[:p].min() >= 0.0 and y[:p][a[:p] > 0].min() >= -1e-9 * np.abs(q).max()
    r_t = np.sqrt(np.bincount(tangent_of, weights=a[p:] ** 2, minlength=p))
    assert (r_t <= mu * a[:p] * (1 + 1e-9) + 1e-12 * a[:p].max()).all()


@pytest.mark.parametrize("solver", [{"theta": 1.0}, {"theta": 0.7, "level": "velocity"}],
                         ids=["theta-1", "theta-0.7-velocity"])
def test_theta_above_one_half_slides_the_block_and_books_its_own_dissipation(solver):
    """theta > 1/2: a persisting row's Coulomb law holds on (1 - theta) P_T V0 + theta P_T V1, whose
    work is booked (>= 0 every step: with the mean velocity it went below zero in steps), and the
    scheme's own dissipation is booked as numerical_loss: the balance closes as at theta = 1/2."""
    mu, v0 = 0.3, 2.0
    h, v, summary = block(2, mu, (0.0, -G), v0=v0, t_end=0.9, solver=solver)
    t = h["t"]
    travel = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    assert travel[-1] == pytest.approx(v0 ** 2 / (2 * mu * G), rel=0.01)
    check_energy(h)
    assert h["numerical_loss"][-1] > 0.0 and summary["numerical_loss"] == h["numerical_loss"][-1]


def test_the_reduced_model_slides_the_block_as_the_full_one():
    """Friction on the modes alone (without the static correction): 30 modes (3 rigid) of the sliding block."""
    mu, v0 = 0.3, 2.0
    h, v, summary = block(2, mu, (0.0, -G), v0=v0, t_end=0.9,
                          solver={"method": "modal", "modes": 30, "static_correction": False})
    assert summary["modes"] == 30
    t = h["t"]
    sliding = (t > 0.05) & (t < 0.6)
    slope, intercept = np.polyfit(t[sliding], v[sliding], 1)
    assert slope == pytest.approx(-mu * G, rel=0.01)
    assert -intercept / slope == pytest.approx(v0 / (mu * G), rel=0.01)
    check_energy(h)


@pytest.mark.parametrize("theta_deg, mu", [(10.0, 0.3), (25.0, 0.3)])
def test_a_block_on_an_incline_holds_or_slides(theta_deg, mu):
    theta = np.radians(theta_deg)
    gravity = (G * np.sin(theta), -G * np.cos(theta))
    h, v, _ = block(2, mu, gravity, t_end=0.5)
    t = h["t"]
    travel = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    frictionless = 0.5 * G * np.sin(theta) * t[-1] ** 2
    if np.tan(theta) <= mu:
        assert abs(travel[-1]) <= 0.01 * frictionless
    else:
        late = t > 0.1
        slope = np.polyfit(t[late], v[late], 1)[0]
        assert slope == pytest.approx(G * (np.sin(theta) - mu * np.cos(theta)), rel=0.01)
    check_energy(h)


def test_a_strip_hitting_a_wall_while_sliding_loses_mu_times_its_normal_momentum():
    """A free strip 1 x 0.1 (E = rho = 1, nu = 0) moving at -1 along x onto a wall at its left end and at
    3 along y: every row slides throughout, so the friction impulse is mu times the normal one."""
    mu = 0.25
    data = {"name": "strip", "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.1, "cells": 20},
            "material": {"E": 1.0, "rho": 1.0, "nu": 0.0, "area": 1.0},
            "initial": {"velocity": [-1.0, 3.0]},
            "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0, 0.0],
                          "gap": 0.01, "restitution": 0.0, "friction": mu}],
            "solver": {"dt": 0.01, "t_end": 3.0}, "output": {"vtk": False}}
    result = fi.run(fi.Case.from_dict(data))
    h = result.history
    m = result.summary["body_mass"]["bar"]
    dpx = h["bar.px"][-1] - h["bar.px"][0]
    dpy = h["bar.py"][-1] - h["bar.py"][0]
    assert dpx > 0.5 * m                                  # the wall pushed it back (it leaves at rest or rebounding)
    assert dpy == pytest.approx(-mu * dpx, rel=1e-6)       # against the slip (+y)
    assert h["wall.slip"][h["wall.force"] > 0].min() > 0.0  # sliding throughout the contact
    check_energy(h)


def test_friction_is_refused_where_it_cannot_be_solved():
    base = {"name": "x", "mesh": {"shape": "bar", "dim": 2, "length": 1.0, "height": 0.1, "cells": 4},
            "material": {"E": 1.0, "rho": 1.0, "area": 1.0},
            "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0, 0.0],
                          "gap": 0.01, "friction": 0.2}],
            "solver": {"dt": 0.01, "t_end": 0.1}}
    with pytest.raises(CaseError, match=r"contacts\[0\]\.friction: solver.method newmark cannot take friction"):
        fi.Case.from_dict({**base, "solver": {"dt": 0.01, "t_end": 0.1, "method": "newmark"}})
    # the reduced model takes friction; its Newmark scheme does not: the scheme is named
    with pytest.raises(CaseError, match=r"contacts\[0\]\.friction: solver.scheme newmark cannot take friction .*"
                                        r"use solver.scheme: moreau_jean"):
        fi.Case.from_dict({**base, "solver": {"dt": 0.01, "t_end": 0.1, "method": "modal", "modes": 4,
                                              "static_correction": False, "scheme": "newmark"}})
    # (the reduced model's static correction takes friction: tests/test_reduced_friction.py)
    fi.Case.from_dict({**base, "solver": {"dt": 0.01, "t_end": 0.1, "method": "modal", "modes": 4}})
    with pytest.raises(CaseError, match=r"contacts\[0\]\.friction: must be >= 0"):
        fi.Case.from_dict({**base, "contacts": [{**base["contacts"][0], "friction": -0.1}]})
    one_d = {**base, "mesh": {"shape": "bar", "length": 1.0, "cells": 4},
             "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0], "gap": 0.01,
                           "friction": 0.2}]}
    with pytest.raises(CaseError, match=r"contacts\[0\]\.friction: friction needs a tangent direction"):
        fi.run(fi.Case.from_dict(one_d))


def test_a_disk_thrown_onto_a_floor_slips_then_rolls_at_two_thirds_of_its_speed(tmp_path):
    """A disk R = 1 (E = 1e11, rho = 1000, nu = 0.3, a little stiffness damping for its contact ringing),
    thrown at v0 = 0.5 without spin onto a floor through a point (each rim node its own gap; the mesh
    graded from 3 mm at the contact point). Friction slows it at mu g and spins it up at 2 mu g / R
    until v0 / (3 mu g), when it rolls at 2 v0 / 3. The model is linear (small rotations): at the
    end of the slip the disk has turned by 0.0094 rad, three rim nodes' spacing, and by 0.0172 rad
    at the end, when the contact (one or two rows at a time) has moved 17 mm ahead."""
    import gmsh

    R, v0, mu = 1.0, 0.5, 0.3
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("disk")
        surface = gmsh.model.occ.addDisk(0, R, 0, R, R)
        gmsh.model.occ.synchronize()
        gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, [surface]), "disk")
        rim = [t for _, t in gmsh.model.getBoundary([(2, surface)], oriented=False)]
        gmsh.model.setPhysicalName(1, gmsh.model.addPhysicalGroup(1, rim), "rim")
        field = gmsh.model.mesh.field.add("MathEval")
        gmsh.model.mesh.field.setString(field, "F", "0.003 + 0.04*Sqrt(x*x + y*y)")
        gmsh.model.mesh.field.setAsBackgroundMesh(field)
        for option in ("Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature", "Mesh.MeshSizeExtendFromBoundary"):
            gmsh.option.setNumber(option, 0)
        gmsh.model.mesh.generate(2)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.write(str(tmp_path / "disk.msh"))
    finally:
        gmsh.finalize()
    data = {"name": "disk", "mesh": {"file": str(tmp_path / "disk.msh")},
            "material": {"E": 1e11, "rho": 1000.0, "nu": 0.3, "area": 1.0}, "damping": {"beta": 1e-4},
            "initial": {"velocity": [v0, 0.0]}, "loads": [{"body": "all", "acceleration": [0.0, -G]}],
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "rim", "normal": [0.0, -1.0],
                          "point": [0.0, 0.0], "friction": mu}],
            "solver": {"dt": 1e-4, "t_end": 0.08}, "output": {"vtk": False}}
    # The rim node in contact at the end: where s^2 / (2 R) - theta s is least, s = theta R ahead
    # (theta: mu g stop^2 while slipping, then 2 v0 / (3 R) a second).
    stop = v0 / (3 * mu * G)
    theta_end = mu * G * stop**2 + 2 * v0 / (3 * R) * (0.08 - stop)
    data["output"]["probes"] = {"first": [0.0, 0.0], "ahead": [theta_end * R, 0.5 * theta_end**2 * R]}
    result = fi.run(fi.Case.from_dict(data))
    h = result.history
    t, v = h["t"], h["disk.px"] / result.summary["body_mass"]["disk"]
    sliding = (t > 0.1 * stop) & (t < 0.9 * stop)
    assert np.polyfit(t[sliding], v[sliding], 1)[0] == pytest.approx(-mu * G, rel=0.01)
    slipping = np.flatnonzero(h["floor.slip"] > 1e-3 * v0)
    assert t[slipping[-1]] == pytest.approx(stop, rel=0.01)                     # then it rolls
    assert np.interp(1.1 * stop, t, v) == pytest.approx(2 * v0 / 3, rel=0.01)
    assert np.all(h["floor.sticking"][t > 1.05 * stop] >= 1)
    # The contact leaves its first node: one rim node at the start, the nodes ahead of it once the
    # disk has turned (linear kinematics: the rim ahead dips by theta s, so the patch grows forward).
    # The contact has moved on: the first node left the floor and the node ahead came down to it, each
    # by about theta^2 R / 2 (a rigid roll; measured -14 % and +9 %: the disk's flattening).
    lift = 0.5 * theta_end**2 * R
    assert h["first.uy"][-1] == pytest.approx(lift, rel=0.25)
    assert h["ahead.uy"][-1] == pytest.approx(-lift, rel=0.25)
    # (The same disk without friction closes its balance to 6.5e-9 of the energy: round-off that
    # accumulates over 800 steps of a model this stiff, E = 1e11 with 3 mm cells.)
    check_energy(h, balance=1e-8)


# --- where friction must never give energy: a family of landings -----------------------------

def landing(dim, mu, e, courant, steps=60, modes=None):
    """The block of ``block`` (4 cells along: 5 rows in 2D, 10 in 3D) falling from 1 mm onto the floor at
    0.5 m/s while sliding along it at 1 m/s (and 0.5 m/s across in 3D), restitution e, at a Courant
    number c dt / h (c = 100 m/s, h = 0.05 m), for ``steps`` steps; full, or reduced to ``modes``."""
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
                          "gap": 1e-3, "friction": mu, "restitution": e}],
            "solver": {"dt": dt, "t_end": steps * dt}, "output": {"vtk": False}}
    if modes:
        data["solver"].update({"method": "modal", "modes": modes, "static_correction": False})
    return fi.run(fi.Case.from_dict(data))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("courant", [0.5, 8.0, 50.0])
@pytest.mark.parametrize("mu, e", [(0.3, 0.0), (1.0, 0.0), (0.3, 1.0), (1.0, 1.0)])
@pytest.mark.parametrize("reduced", [False, True])
def test_friction_never_gives_energy_in_a_family_of_landings(dim, courant, mu, e, reduced):
    """Full and reduced (16 modes of 20 in 2D, 40 of 75 in 3D: more than the 10 or 30 contact
    unknowns, so that the impulses are unique)."""
    modes = (16 if dim == 2 else 40) if reduced else None
    result = landing(dim, mu, e, courant, modes=modes)
    h = result.history
    assert h["friction_loss"][-1] > 0.0 and h["floor.impulse"].sum() > 0.0   # it landed and slid
    check_energy(h)
    assert result.summary["energy_created"] == 0.0
    assert result.summary["max_friction_residual"] <= FrictionProblem.TOLERANCE
    if courant == 50.0 and dim == 2 and not modes:   # a nearly rigid block on 5 rows: Newton's method solves it,
        # the sweeps (where it falls short) never crawl beyond their second round (the first, at the velocity level)
        assert result.summary["max_friction_sweeps"] <= 2 * FrictionProblem.NEWTON_AFTER_SMALL


def plate_landing(cells, courant, mu, e, modes=None):
    """cases/plate_drop.yaml (every node of its 5 x 5 face a row: 121, 441, 1681 rows for 2, 4, 8
    cells through the thickness; nu = 0.3 here) landing while sliding at (0.5, 0.3) along the
    floor, at a Courant number c dt / h (c = 1, h = 1 / cells), until 3 time units after it (the
    contact lasts about 2 L / c = 2), full or reduced (``modes``, without the static correction)."""
    case = fi.load_case(CASES / "plate_drop.yaml")
    dt = courant / cells
    changes = {"mesh.cells": cells, "material.nu": 0.3, "solver.dt": dt, "solver.t_end": 3.2 + 4 * dt,
               "initial.velocity": [-1.0, 0.5, 0.3], "contacts.0.gap": 0.2, "contacts.0.friction": mu,
               "contacts.0.restitution": e, "output.vtk": False}
    if modes:
        changes.update({"solver.method": "modal", "solver.modes": modes, "solver.static_correction": False})
    return fi.run(case.with_changes(changes))


@pytest.mark.parametrize("cells, courant, mu, e, modes", [
    (2, 0.5, 0.3, 0.0, None), (2, 8.0, 1.0, 1.0, None), (2, 50.0, 0.3, 1.0, None), (2, 0.5, 1.0, 0.0, None),
    (4, 0.5, 0.3, 0.0, None), (4, 50.0, 1.0, 0.0, None),
    # (401 modes, not 400: the square plate's 400th and 401st frequencies are equal (w^2 = 22.443144957038,
    # 1.4e-15 apart), so a 400th mode is one vector of their plane that round-off picks, and with it W: at
    # Courant 8 one machine solved the face, another stalled at 7.7e-6 on every run)
    *[pytest.param(2, courant, mu, e, 401, marks=pytest.mark.slow) for courant, mu, e in [(0.5, 0.3, 0.0), (8.0, 1.0, 1.0)]],
    *[pytest.param(8, courant, mu, e, None, marks=pytest.mark.slow)
      for courant, mu, e in [(0.5, 0.3, 0.0), (8.0, 1.0, 1.0), (8.0, 0.3, 1.0), (0.5, 1.0, 1.0)]]])
def test_friction_never_gives_energy_on_a_plate_of_many_rows(cells, courant, mu, e, modes):
    """The family on 121 to 1681 rows (a 3D face), full and reduced (401 modes of 1089: more than the
    363 contact unknowns; the blocks of 5 and 10 rows above too): every step's friction loss >= 0,
    E <= E0 + W_ext, no energy created, each cone problem solved to the tolerance. Courant number 50 up to 441 rows: there the plate is nearly rigid, Gauss-Seidel
    crawls and Newton's method takes over (dense LU: 1323 unknowns, 5 s a run; at 1681 rows, 5043
    unknowns, minutes a step)."""
    result = plate_landing(cells, courant, mu, e, modes)
    h, summary = result.history, result.summary
    assert summary["constraints"] == (5 * cells + 1) ** 2
    assert h["friction_loss"][-1] > 0.0 and h["floor.impulse"].sum() > 0.0   # it landed and slid
    check_energy(h)
    assert summary["energy_created"] == 0.0
    assert summary["max_friction_residual"] <= FrictionProblem.TOLERANCE


def test_a_reduced_face_with_fewer_modes_than_contact_unknowns_stops_and_says_why():
    """Where the solver fails: the plate's 121 face rows (363 contact unknowns) on 60 modes: W is
    singular, the impulses are not unique, and neither Gauss-Seidel nor Newton's method reaches
    the tolerance. The run stops (status 3) at its first contact step and says what to do."""
    with pytest.raises(ContactSolverError, match="60 unknowns of motion .modes. for 363 contact unknowns"):
        plate_landing(2, 8.0, 1.0, 1.0, 60)


@pytest.mark.slow   # (8 s: 2000 sweeps and 20 Newton hand-overs before it gives up)
def test_a_nearly_rigid_reduced_face_stops_and_says_why():
    """With 401 modes (more than the 363 unknowns) the same face solves at Courant numbers 0.5 and 8
    (above), not at 50: the plate nearly rigid, W nearly singular (its smallest eigenvalue 1e-13 of
    its largest), the residual stalls near 2e-6."""
    with pytest.raises(ContactSolverError, match="nearly singular on many rows: use coupling: mean"):
        plate_landing(2, 50.0, 1.0, 1.0, 401)


def test_an_unsolved_contact_problem_stops_the_run_and_says_where(monkeypatch, tmp_path):
    """One sweep allowed: the landing's coupled rows cannot be solved; the run stops (status 3 on the
    command line: a SimulationError) naming the time, the step and the row, and writes nothing."""
    from fem_impact.errors import SimulationError

    monkeypatch.setattr(FrictionProblem, "MAX_SWEEPS", 1)
    monkeypatch.setattr(FrictionProblem, "SMALL", 0)   # (no Newton's method first: the sweeps alone)
    with pytest.raises(SimulationError, match=r"the frictional contact problem was not solved at t = .* \(step \d+\): "
                                               r"residual .* after 1 sweeps .* contact row \d+"):
        landing(2, 0.3, 0.0, 8.0)


# --- supports that hold a tangent: symmetry planes ------------------------------------------

def dropped_block(dim, length, cells, supports, width=None, mu=0.05, t_end=0.04):
    """A block (E = 1e7, rho = 1000, nu = 0.3, hexahedra / quadrilaterals: a mesh symmetric about its
    middle) at the floor falling at 0.5 m/s under gravity, friction mu: on impact its bottom spreads
    (Poisson) and the friction resists, sticking in the middle and slipping near the ends."""
    pad = [0.0] * (dim - 2)
    mesh = {"shape": "bar", "dim": dim, "length": length, "height": 0.05, "cells": cells, "elements": "hex"}
    if dim == 3:
        mesh["width"] = width
    points = {"a": [0.0, 0.0], "b": [0.05, 0.0], "c": [0.1, 0.0], "d": [0.0, 0.05], "e": [0.05, 0.025]}
    data = {"name": "half", "mesh": mesh,
            "material": {"E": 1e7, "rho": 1000.0, "nu": 0.3, **({"area": 1.0} if dim == 2 else {})},
            "initial": {"velocity": [0.0, -0.5] + pad}, "loads": [{"body": "all", "acceleration": [0.0, -G] + pad}],
            "supports": supports,
            "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0] + pad,
                          "gap": 0.0, "friction": mu, "restitution": 0.0}],
            "solver": {"dt": 1e-3, "t_end": t_end},
            "output": {"vtk": False, "probes": {k: v + pad for k, v in points.items()}}}
    return fi.run(fi.Case.from_dict(data))


def same_motion(full, part, parts):
    """The part model moves as the full one's part: every probe to round-off, the momentum, the friction
    loss and the energies as ``parts`` times the part's."""
    hf, hp = full.history, part.history
    probed = [k for k in hf if k[:2] in ("a.", "b.", "c.", "d.", "e.")]
    for k in probed:   # (each quantity against the largest of its kind: ux against the uy of the fall)
        kind = [j for j in probed if j[2] == k[2]]
        assert np.abs(hf[k] - hp[k]).max() <= 1e-9 * max(np.abs(hf[j]).max() for j in kind), k
    assert np.abs(hf["bar.py"] - parts * hp["bar.py"]).max() <= 1e-9 * np.abs(hf["bar.py"]).max()
    for k in ("friction_loss", "kinetic", "strain", "external_work"):
        assert hf[k][-1] == pytest.approx(parts * hp[k][-1], rel=1e-8), k
    assert hf["friction_loss"][-1] > 1e-4 * hf["kinetic"][0]   # it slid
    assert np.abs(hf["c.ux"]).max() <= 1e-9 * np.abs(hf["c.uy"]).max()   # the middle stays in its plane
    check_energy(hp)


def test_a_half_model_on_a_symmetry_plane_slides_as_the_full_one():
    """A row on the symmetry plane (its node's x held) has no tangent motion: Coulomb's law leaves its
    friction undetermined (it is the support's reaction) and its row of W singular (a division by zero
    in the row's stick solve, once). The held tangent is dropped: the half model is the full one."""
    full = dropped_block(2, 0.2, 8, [])
    half = dropped_block(2, 0.1, 4, [{"nodes": "right", "fix": ["x"]}])
    same_motion(full, half, 2)


def test_a_quarter_model_on_two_symmetry_planes_slides_as_the_full_one():
    """3D: the rows on the plane x = L/2 keep their tangent along z, those on z = W/2 along x, the corner
    row none."""
    full = dropped_block(3, 0.2, 4, [], width=0.2, t_end=0.02)
    quarter = dropped_block(3, 0.1, 2, [{"nodes": "right", "fix": ["x"]}, {"nodes": "front", "fix": ["z"]}],
                            width=0.1, t_end=0.02)
    same_motion(full, quarter, 4)


def test_a_tangent_direction_held_obliquely_is_found_and_dropped():
    """free_tangents on 3 nodes: a floor normal in the y-z plane, x held at node 0 (the tangent along x
    dropped, the other kept as it was); x and y held at node 2 under the normal (1, 1, 0) / sqrt(2) (the
    tangent in the x-y plane dropped); the free node keeps both."""
    from mpi4py import MPI
    from scipy import sparse

    from fem_impact.nonsmooth.relation import free_tangents

    def rows(tangents):
        T = np.zeros((9, 6))
        for k, t in enumerate(tangents):
            for node in range(3):
                T[3 * node:3 * node + 3, 3 * k + node] = t
        return sparse.csr_matrix(T), np.tile(np.arange(3), 2), np.repeat(tangents, 3, axis=0)

    for normal, held, gone in ((np.array([0.0, -1.0, 1.0]), [0], np.array([1.0, 0.0, 0.0])),
                               (np.array([1.0, 1.0, 0.0]), [6, 7], np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0))):
        tangents = tangent_basis(normal / np.linalg.norm(normal))
        T, tangent_of, dirs = rows(np.array(tangents))
        free = np.ones(9)
        free[held] = 0.0
        node = held[0] // 3
        Tn, of, d = free_tangents(T, free, tangent_of, dirs, MPI.COMM_SELF)
        assert np.count_nonzero(of == node) == 1 and np.count_nonzero(of != node) == 4
        kept = d[of == node][0]
        assert abs(kept @ gone) <= 1e-12 and abs(kept @ normal) <= 1e-12 and np.linalg.norm(kept) == pytest.approx(1.0)
        assert np.allclose(Tn[:, np.flatnonzero(of == node)].toarray().ravel()[3 * node:3 * node + 3], kept * free[3 * node:3 * node + 3])
        # the other nodes: their tangents, unchanged
        assert np.allclose(np.sort(d[of != node], axis=0), np.sort(dirs[tangent_of != node], axis=0))


# --- W from the solves: symmetric to their round-off ---------------------------------------------

def test_a_stiff_block_at_a_large_step_runs_whatever_the_round_off_of_w():
    """A steel block (8 cells) sliding at dt = 1 ms, a Courant number of 200: W = P S^-1 P^T from the
    solves is symmetric to 6e-13 of its entries, 0.015 of the solves' round-off bound EPS ||S|| |x_i|
    |x_j| (it once stopped the run at 1e-13 of its largest entry, with a traceback). Its symmetric part is
    solved, and the block decelerates at mu g."""
    case = fi.load_case(CASES / "sliding_block.yaml")
    result = fi.run(case.with_changes({"material.E": 2.1e11, "material.rho": 7850.0, "material.nu": 0.3,
                                       "contacts.0.friction": 0.5, "solver.dt": 1e-3, "solver.t_end": 0.1,
                                       "output.vtk": False}))
    h, s = result.history, result.summary
    v = h["bar.px"] / s["body_mass"]["bar"]
    late = h["t"] > 0.02
    assert np.polyfit(h["t"][late], v[late], 1)[0] == pytest.approx(-0.5 * G, rel=0.01)
    assert s["energy_created_at"] is None and s["max_friction_residual"] <= FrictionProblem.TOLERANCE
    # (the balance to the round-off of U^T K U for a steel block moved by 0.2 m, 3e-8 of its energy: the run
    # reports it)
    scale = h["kinetic"][0] + h["external_work"].max()
    assert np.abs(h["energy_error"]).max() <= s["energy_roundoff"] + 1e-10 * scale
    check_energy(h, tolerance=s["energy_roundoff"] / scale + 1e-10, balance=s["energy_roundoff"] / scale + 1e-10)


def test_a_w_that_is_not_symmetric_beyond_round_off_is_a_plain_error_not_a_traceback():
    from fem_impact.nonsmooth.friction import symmetrize

    W = np.array([[2.0, 0.5, 0.1], [0.5, 1.0, 0.2], [0.1, 0.2, 1.0]])
    noisy = W + np.array([[0.0, 1e-15, 0.0], [0.0, 0.0, 0.0], [0.0, -1e-15, 0.0]])
    problem = FrictionProblem(noisy.copy(), np.array([0, 0]), np.array([0.3]))
    assert problem.asymmetry < 1.0
    assert np.array_equal(problem.dense(np.arange(3)), problem.dense(np.arange(3)).T)
    copy = noisy.copy()
    symmetrize(copy, np.ones(3))
    assert np.array_equal(copy, copy.T) and np.abs(copy - W).max() <= 1e-15
    wrong = W.copy()
    wrong[0, 1] = 0.4   # (a W built wrong: its two halves disagree)
    with pytest.raises(ContactSolverError, match="not symmetric: W_ij and W_ji differ by .* times the round-off"):
        FrictionProblem(wrong, np.array([0, 0]), np.array([0.3]))
    with pytest.raises(ContactSolverError, match="not finite"):
        FrictionProblem(np.full((3, 3), np.nan), np.array([0, 0]), np.array([0.3]))


def test_the_friction_solver_calls_its_compiled_sweeps_without_a_type_search(monkeypatch):
    """Every argument of the sweeps' kernel given (its defaults omitted made Numba search its compiled
    versions on every call, a millisecond a step: 19 % of the sliding block's step)."""
    from numba.core import dispatcher

    from fem_impact.nonsmooth.friction import FrictionProblem

    W = np.array([[2.0, 0.3, 0.1, 0.0], [0.3, 2.0, 0.0, 0.1], [0.1, 0.0, 1.0, 0.2], [0.0, 0.1, 0.2, 1.0]])
    q = np.array([-1.0, -0.5, 0.4, -0.2])

    def solves():   # (a new problem each time: the same calls, in the same order)
        problem = FrictionProblem(W, np.array([0, 1]), np.array([0.3, 0.3]))
        return [problem.solve(scale * q, np.array([True, True])).converged for scale in (1.0, 2.0, 0.5)]

    solves()   # (the first calls of each kernel may compile, or load from the cache)
    searches = []
    original = dispatcher.Dispatcher._compile_for_args
    monkeypatch.setattr(dispatcher.Dispatcher, "_compile_for_args",
                        lambda self, *a, **k: searches.append(self.py_func.__name__) or original(self, *a, **k))
    assert all(solves())
    assert searches == []


@pytest.mark.parametrize("tangents", [1, 2])
def test_the_compiled_alart_curnier_jacobian_is_the_derivative_of_its_function(tangents):
    """Newton's function and Jacobian (nonsmooth/cone.py: alart_curnier) on rows open, sticking and
    slipping: J against central differences of F, away from the kinks."""
    from fem_impact.nonsmooth import cone

    rng = np.random.default_rng(7)
    rows, m = 4, 1 + tangents
    n = rows * m
    B = rng.normal(size=(n, n))
    W = B @ B.T + n * np.eye(n)
    q = rng.normal(size=n)
    starts, sizes = np.arange(rows, dtype=np.int64) * m, np.full(rows, m, dtype=np.int64)
    rho, mu = 1.0 / np.diag(W)[starts], np.array([0.3, 0.3, 2.0, 0.3])
    kinds = set()
    for _ in range(20):
        r = rng.normal(size=n)
        F, J = cone.alart_curnier(W, q, r, starts, sizes, rho, mu, True)
        y = W @ r + q
        for b, k in enumerate(starts):
            z_n = r[k] - rho[b] * y[k]
            z_t = r[k + 1:k + m] - rho[b] * y[k + 1:k + m]
            kinds.add("open" if z_n <= 0 else "stick" if np.linalg.norm(z_t) <= mu[b] * z_n else "slip")
        h, numeric = 1e-7, np.empty((n, n))
        for j in range(n):
            e = np.zeros(n)
            e[j] = h
            numeric[:, j] = (cone.alart_curnier(W, q, r + e, starts, sizes, rho, mu, False)[0]
                             - cone.alart_curnier(W, q, r - e, starts, sizes, rho, mu, False)[0]) / (2 * h)
        assert np.abs(J - numeric).max() <= 1e-6 * max(1.0, np.abs(J).max())
    assert kinds == {"open", "stick", "slip"}


def test_a_block_sticking_at_mu_5_at_a_large_step_runs_through_steps_the_position_level_cannot_solve():
    """cases/sliding_block.yaml at mu = 5 (dt 2 ms): a few steps' cone problems at the position level have
    no solution the solver finds (the block sticks on rows that ring); those steps are taken at the
    velocity level (summary friction_velocity_steps: 3 in the run measured) instead of stopping the run: it runs
    to its end (at mu = 5 the block's bottom bounces and rocks: no exact answer for its motion), every
    other cone problem within the tolerance, no energy created, and the gaps within the velocity level's
    drift of those steps (measured 9e-5 m), far less than the velocity level's whole run (2.6 mm)."""
    case = fi.load_case(CASES / "sliding_block.yaml", ["contacts.0.friction=5.0", "solver.t_end=0.3",
                                                       "output.vtk=false", "output.probes={}"])
    result = fi.run(case, None)
    s = result.summary
    assert s["t_end"] == pytest.approx(0.3)
    assert s["energy_created"] == 0.0 and s["max_friction_residual"] <= 1e-10
    assert s["max_penetration"] <= 0.1 * 2.6e-3
