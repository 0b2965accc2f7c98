"""The integration methods besides the default (issue 5's list), each against an exact answer:
central difference with forward-increment multipliers, Newmark with numerical damping, Newmark
without the Carnot correction, and mass redistribution. Where each fails is shown in the
stability studies; here each does what its definition says."""

from __future__ import annotations

import numpy as np
import pytest
from mpi4py import MPI

from conftest import CASES, run_case_file, run_cli
from fem_impact.build import finite_element_model, model_and_constraints
from fem_impact.config.case import load_case
from fem_impact.errors import SimulationError
from fem_impact.integrators import Operators
from fem_impact.integrators.central_difference import critical_time_step
from test_bar_benchmarks import assert_b2

BAR = CASES / "impacting_bar.yaml"


def model_of(case_file, *overrides):
    case = load_case(case_file, list(overrides))
    return (case, *model_and_constraints(case, MPI.COMM_WORLD))


def test_central_difference_meets_b2a_and_conserves_its_energy(tmp_path):
    """Lumped rod at Courant 0.5: the B2 tolerances of the default method; the scheme conserves
    kinetic + strain + ``scheme_energy`` (-dt^2/8 A.M A), so the balance closes to round-off, and
    nothing grows."""
    summary, h = run_case_file(BAR, tmp_path, "solver.method=central_difference", "output.vtk=false")
    assert_b2(h)
    e0 = h["kinetic"][0] + h["strain"][0] + h["scheme_energy"][0]
    assert summary["max_energy_error"] < 1e-10 * e0   # (1.3e-12 measured, 2000 steps)
    assert (h["kinetic"] + h["strain"] + h["scheme_energy"]).max() <= e0 * (1 + 1e-9)
    assert summary["max_penetration"] < 1e-12   # forward increment: the gap is closed, never crossed


def test_central_difference_stable_limit_of_the_lumped_rod_is_h_over_c():
    """omega_max of the lumped rod is 2 c / h exactly, so 2 / omega_max = h / c (the CFL limit)."""
    for cells, E, rho in [(50, 1.0, 1.0), (200, 210e9, 7800.0)]:
        _, model, cons = model_of(BAR, f"mesh.cells={cells}", "solver.mass=lumped", f"material.E={E}",
                                  f"material.rho={rho}")
        ops = Operators(model.M, model.K, None, model.load, cons.P_local, cons.d0, cons.restitution)
        assert critical_time_step(ops) == pytest.approx((1.0 / cells) / np.sqrt(E / rho), rel=1e-12)


@pytest.mark.parametrize("courant, fails", [(1.0, False), (1.05, True)])
def test_central_difference_blows_up_above_the_cfl_limit_and_is_stopped(tmp_path, courant, fails):
    """At c dt / h = 1 the run completes; 5 % above, the energy runs away and the command stops
    with status 3 and a message that says so, long before the end (2000 steps)."""
    out = tmp_path / "out"
    result = run_cli("run", str(BAR), "-o", str(out), "-q", "--set", "solver.method=central_difference",
                     "--set", f"solver.dt={courant / 250}", "--set", "output.vtk=false")
    if not fails:
        assert result.returncode == 0, result.stderr
        return
    assert result.returncode == 3
    assert "blew up" in result.stderr and "above the stable limit" in result.stderr
    step = int(result.stderr.split("(step ")[1].split(")")[0])
    assert step < 200
    assert not out.exists() and "Traceback" not in result.stderr


def test_damped_newmark_dissipates_at_first_order(tmp_path):
    """gamma = 0.6, beta = (gamma + 1/2)^2 / 4: high frequencies damped, the scheme first order, so
    the energy it loses on B2a halves when dt halves (mesh fixed); the balance residual is that
    numerical loss (negative) and the default trapezoidal rule has none."""
    losses = []
    for dt in (0.004, 0.002):
        summary, h = run_case_file(BAR, tmp_path / str(dt), "solver.gamma=0.6", "solver.beta=0.3025",
                                   f"solver.dt={dt}", "contacts=[]", "solver.t_end=2", "output.vtk=false",
                                   "initial.velocity=[\"sin(pi*x)\"]")
        e = h["kinetic"] + h["strain"]
        losses.append(1.0 - e[-1] / e[0])
        assert np.all(np.diff(e) <= 1e-14 * e[0])           # only ever loses energy
        assert h["energy_error"][-1] == pytest.approx(-losses[-1] * e[0], rel=1e-9)
    order = np.log2(losses[0] / losses[1])
    assert order == pytest.approx(1.0, abs=0.15)
    summary, h = run_case_file(BAR, tmp_path / "trap", "solver.dt=0.002", "contacts=[]", "solver.t_end=2",
                               "output.vtk=false", "initial.velocity=[\"sin(pi*x)\"]")
    assert abs(h["energy_error"]).max() < 1e-12


def test_position_multipliers_alone_close_the_balance_but_let_the_bar_chatter(tmp_path):
    """Without Carnot's correction the node pinned by lam0 keeps the trapezoidal rule's spurious
    velocity: the contact opens and closes, the position-level forces pump energy in (a negative
    contact loss) and the force oscillates about rho c A v0 = 1 by more than its own size. Every
    term is still booked: the balance closes to round-off."""
    summary, h = run_case_file(BAR, tmp_path, "solver.impact_correction=false", "output.vtk=false")
    e0 = h["kinetic"][0] + h["strain"][0]
    assert summary["max_energy_error"] < 1e-9 * e0
    assert h["impact_loss"][-1] == 0.0
    assert (h["kinetic"] + h["strain"]).max() > 2 * e0       # energy pumped in (docs/theory.md s. 3.5)
    assert h["contact_loss"][-1] < -e0
    busy = (h["t"] > 0.2) & (h["t"] < 2.0)
    assert np.sqrt(np.mean((h["wall_force"][busy] - 1.0) ** 2)) > 1.0


def test_mass_redistribution_removes_the_contact_mass_and_keeps_the_total(tmp_path):
    """No mass on the contact node, the same total mass; B2a within its tolerances, energy conserved
    to round-off (the trapezoidal rule with a massless contact node needs no impact law)."""
    _, model, _ = model_of(BAR, "solver.mass=redistributed", "mesh.cells=20")
    _, consistent, _ = model_of(BAR, "mesh.cells=20")
    ones, m_red, m_cons = model.M.createVecs()[0], *model.M.createVecs()
    ones.set(1.0)
    model.M.mult(ones, m_red)
    consistent.M.mult(ones, m_cons)
    assert m_red.sum() == pytest.approx(m_cons.sum(), rel=1e-14)     # rho A L = 1
    dense = model.M.convert("dense").getDenseArray()
    assert not dense[0].any() and not dense[:, 0].any()               # node x = 0 (the wall) is massless
    assert list(model.massless) == [0]

    summary, h = run_case_file(BAR, tmp_path, "solver.mass=redistributed", "output.vtk=false")
    assert_b2(h)
    e0 = h["kinetic"][0] + h["strain"][0]
    assert summary["max_energy_error"] < 1e-9 * e0
    assert h["impact_loss"][-1] == 0.0                   # nothing for Carnot to correct
    assert (h["kinetic"] + h["strain"])[-1] > e0 * (1 - 1e-4)   # the bar leaves with all its energy
    # Momentum from the redistributed mass: m v0 = -1 before the wall, the massless node carries none.
    assert summary["body_mass"]["bar"] == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(h["bar_px"][h["t"] < 0.1], -1.0, rtol=1e-12)


def test_mass_redistribution_starts_the_massless_node_in_equilibrium(tmp_path):
    """B1 starts with a stressed free end (u0 = (1 - x)/2): a massless end node cannot hold that,
    so it starts where its row of K U = R holds (the first element's strain energy, 1/(8 n), is
    not part of the initial state), and the budget closes to round-off from there."""
    summary, h = run_case_file(CASES / "signorini_bar.yaml", tmp_path, "solver.mass=redistributed",
                               "solver.t_end=3", "output.vtk=false")
    n = 200
    assert h["kinetic"][0] + h["strain"][0] == pytest.approx(1 / 8 * (1 - 1 / n), rel=1e-9)
    assert summary["max_energy_error"] < 1e-9 / 8


def _state(total, work=0.0, contact_loss=0.0, t=0.1):
    from fem_impact.integrators.state import StepState
    from fem_impact.mechanics.energy import EnergyBudget

    e = EnergyBudget(kinetic=total, external_work=work, contact_loss=contact_loss, initial=1.0)
    return StepState(step=1, t=t, U=np.zeros(1), V=np.zeros(1), A=np.zeros(1), gap=np.zeros(0), force=np.zeros(0),
                     impulse=np.zeros(0), energy=e, normal_displacement=np.zeros(0), normal_velocity=np.zeros(0))


def test_blow_up_guard_stops_a_runaway_energy():
    """The guard's bound is E0 + W_ext(t) reached so far (work taken out does not raise it); a state
    100 times above it stops the run."""
    from fem_impact.mechanics.energy import EnergyWatch

    watch = EnergyWatch()
    watch.check(_state(0.5, work=-10.0))      # work taken out: the bound stays E0 = 1
    with pytest.raises(SimulationError, match="blew up"):
        watch.check(_state(101.0, work=-10.0))
    watch = EnergyWatch()
    watch.check(_state(50.0))
    watch.check(_state(900.0, work=10.0))     # energy put in raises the bound to 11
    with pytest.raises(SimulationError, match="blew up"):
        watch.check(_state(1200.0))
    with pytest.raises(SimulationError, match="no longer finite"):
        EnergyWatch().check(_state(np.nan))


@pytest.mark.parametrize("scheme, stable, says, never", [
    ("moreau_jean", True, ("stable at any dt, so dt is not the cause", "overflowed float64"), "explicit"),
    ("newmark", True, ("stable at any dt, so dt is not the cause",), "explicit"),
    ("central_difference", False, ("explicit and dt is above its stable limit",), "overflowed"),
    ("newmark", False, ("beta < gamma / 2 is stable only below a step limit",), "overflowed"),
])
def test_a_blow_up_says_what_is_true_of_the_scheme_that_ran(scheme, stable, says, never):
    """A state no longer finite (or energy far past E0 + W_ext) was 'the scheme blew up (for an explicit
    method: is dt above its stable limit?)' whatever the method: an implicit one has no step limit."""
    from fem_impact.mechanics.energy import EnergyWatch

    with pytest.raises(SimulationError) as info:
        EnergyWatch(scheme=scheme, stable=stable).check(_state(np.inf))
    assert all(text in str(info.value) for text in says) and never not in str(info.value)
    watch = EnergyWatch(scheme=scheme, stable=stable)
    watch.check(_state(1.0))
    with pytest.raises(SimulationError, match="blew up") as info:
        watch.check(_state(1000.0))
    if scheme == "moreau_jean":
        assert "dt is not the cause" in str(info.value) and "report it" in str(info.value)
    if scheme == "newmark" and stable:
        assert "use solver.method: moreau_jean" in str(info.value)


@pytest.mark.parametrize("changes, says", [
    ({"initial.velocity": [1e200]}, "the initial state is not finite"),
    ({"loads": [{"nodes": "right", "force": ["exp(400*t)"]}]}, "Moreau-Jean is stable at any dt, so dt is not the cause"),
])
@pytest.mark.filterwarnings("ignore:overflow:RuntimeWarning")   # (numpy's, on the way to the overflow)
def test_an_overflow_with_the_default_method_is_named_as_such(changes, says):
    import fem_impact as fi

    case = load_case(BAR).with_changes({"solver": {"dt": 0.002, "t_end": 2.0}, "output.vtk": False, **changes})
    with pytest.raises(SimulationError, match=says) as info:
        fi.run(case)
    assert "explicit" not in str(info.value)


def test_energy_watch_records_created_energy_and_when_it_began():
    """E above E0 + W_ext(t), or the contacts' losses (contact + impact) below zero, by more than 1e-6
    of the scale is energy created; its size and the time it began are recorded, or the run stops
    (EnergyCreated)."""
    from fem_impact.mechanics.energy import EnergyCreated, EnergyWatch

    watch = EnergyWatch()
    watch.check(_state(1.0 + 0.5e-6, t=0.1))                 # within the tolerance: round-off
    assert not watch.energy_was_created
    watch.check(_state(1.5, work=0.4, t=0.2))                # 0.1 above E0 + W_ext = 1.4
    watch.check(_state(1.2, work=0.4, contact_loss=-0.3, t=0.3))   # a negative contact loss of 0.3
    assert watch.energy_was_created and watch.created_at == 0.2
    assert watch.created == pytest.approx(0.3) and watch.created_relative == pytest.approx(0.3 / 1.4)
    assert watch.max_ratio == pytest.approx(1.5 / 1.4)
    strict = EnergyWatch(stop_on_energy_gain=True)
    strict.check(_state(1.0))
    with pytest.raises(EnergyCreated, match="t = 0.2"):
        strict.check(_state(1.01, t=0.2))


@pytest.mark.parametrize("fault, bound", [(None, 1e-11), ("solve", 1e-7), ("step matrix", 1e-10)])
def test_energy_balance_sees_a_faulty_solve(fault, bound):
    """Newmark's strain energy comes from the equation of motion at the end of the step (no
    product with K), which holds only as far as its solves are right; every CHECK_EVERY-th step
    it is a product with K, so that the balance still sees a wrong solve. B2a's free bar into
    its contact, with solves scaled by 1 + 1e-6 or S factorized with K (1 + 1e-6): the residual
    rises from round-off (6e-14 of E0) to 8.6e-7 and 2.4e-9 of E0, as with products with K at
    every step. (From the equation of motion alone the scaled solve went unseen: 5e-14.)"""
    from fem_impact.integrators import Newmark, integrate

    case, model, cons = model_of(BAR, "mesh.cells=100", "solver.dt=0.005", "solver.t_end=1.0")
    ops = Operators(model.M, model.K, model.C, model.load, cons.P_local, cons.d0, cons.restitution)
    dt = case.solver.dt
    newmark = Newmark(ops, dt)
    solve = newmark.solve_S
    if fault == "solve":
        def faulty(b, x):
            solve(b, x)
            x *= 1.0 + 1e-6
        newmark.solve_S = faulty
    elif fault == "step matrix":
        newmark.solve_S = ops.algebra.factorize(ops.algebra.combine((1.0, ops.M), (0.25 * dt * dt * (1 + 1e-6), ops.K)))

    class Residual:
        worst = 0.0

        def write(self, state):
            self.worst = max(self.worst, abs(state.energy.error) / state.energy.initial)

    residual = Residual()
    final = integrate(newmark, model.U0, model.V0, case.solver.t_end, [residual])
    assert final.force.sum() > 0   # (in contact since t = 0.1)
    assert (residual.worst < bound) if fault is None else (residual.worst > bound)


def test_explicit_method_defaults_to_the_lumped_mass(tmp_path):
    """central_difference without solver.mass gets the lumped (diagonal) mass it is meant for, and the
    resolved case says so; Newmark keeps the consistent mass."""
    case = load_case(BAR, ["solver.method=central_difference"])
    assert case.solver.mass == "lumped"
    assert case.resolved()["solver"]["mass"] == "lumped"
    assert load_case(BAR).solver.mass == "consistent"
    assert load_case(BAR, ["solver.method=central_difference", "solver.mass=consistent"]).solver.mass == "consistent"


def test_a_diagonal_system_is_divided_not_factorized():
    """A lumped mass (diagonal) is inverted entry by entry: under MPI every other system goes to MUMPS,
    which made central difference 14 times slower on 2 ranks than on 1 (issue 21; measured here on
    the 3D bar of 72 963 unknowns: 36.9 ms a step before, 1.9 ms after, 2.8 to 3.0 ms serial)."""
    from mpi4py import MPI

    from fem_impact.linalg.backends import PETScAlgebra
    from fem_impact.linalg.factor import DiagonalFactor, Factor, is_diagonal

    case = load_case(CASES / "impacting_bar.yaml", ["mesh.dim=2", "mesh.cells=40"])   # (newmark: consistent mass)
    model = finite_element_model(case, MPI.COMM_WORLD)
    alg = PETScAlgebra(model.M)
    assert not is_diagonal(model.M) and not is_diagonal(model.K)
    lumped = load_case(CASES / "impacting_bar.yaml", ["mesh.dim=2", "mesh.cells=40", "solver.method=central_difference",
                                                      "solver.mass=lumped"])
    M = finite_element_model(lumped, MPI.COMM_WORLD).M
    solve = alg.factorize(M, spd=True)
    assert is_diagonal(M) and isinstance(solve, DiagonalFactor)
    assert isinstance(alg.factorize(model.M, spd=True), Factor)
    b, x = alg.vector(), alg.vector()
    b[:] = np.linspace(1.0, 2.0, b.size)
    solve(b, x)
    assert np.allclose(x, b / M.getDiagonal().array_r, rtol=1e-15, atol=0)
    assert np.array_equal(solve.many(np.column_stack([b, 2 * b])), np.column_stack([x, 2 * x]))
