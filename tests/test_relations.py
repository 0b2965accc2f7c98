"""A moving obstacle defined here, in this file alone, as a new relation (a fixed plane whose
position moves at a constant speed): every method that takes obstacles steps it through the
relations' ``gap(t)`` and ``gap_velocity(t)``, with no integrator knowing of it.

A free mass at rest, struck by a plane moving toward it at v_o with restitution e, leaves at
(1 + e) v_o (e = 0: it rides on the plane, at gap 0), the impact at t* = d0 / v_o within a step. A
free elastic bar at rest, struck at an end by a wall moving at v_o (e = 0), has its end ride on the
wall for 2 L / c and leaves with the impulse 2 m v_o (the wall's frame: a bar rebounding from a wall).
The obstacle's work on the structure is external work (the laws book the work on the motion
relative to it): the balance closes, no loss is negative, and the energy never exceeds the
initial energy plus that work. On the struck mass the obstacle's work is exact: the kinetic energy
it leaves with plus the impact loss, 1/2 m ((1 + e) v_o)^2 + 1/2 m (1 - e^2) v_o^2 = m (1 + e) v_o^2.
"""

from __future__ import annotations

import numpy as np
import pytest
from petsc4py import PETSc

from mpi4py import MPI

from conftest import CASES, ConstantLoad
from fem_impact.build import full_system, make_integrator, model_and_constraints, reduced_system
from fem_impact.config.case import load_case
from fem_impact.integrators import CentralDifference, MoreauJean, Newmark, Operators, integrate
from fem_impact.integrators.blocks import BlockStepper
from fem_impact.nonsmooth import laws
from fem_impact.nonsmooth.relations import FixedPlane, Relations


class MovingPlane(FixedPlane):
    """A rigid plane moving along its normal: ``d(t) = d0 + speed t``."""

    time_dependent = True

    def __init__(self, nodes, normal, tangents, gap: float, speed: float):
        super().__init__(nodes, normal, tangents, gap)
        self.speed = speed

    def gap(self, t: float) -> np.ndarray:
        return self.d0 + self.speed * t

    def gap_velocity(self, t: float) -> np.ndarray:
        return np.full_like(self.d0, self.speed)


M_, D0, V_O = 2.0, 0.01003, 1.0   # kg, m (the plane's distance at t = 0), m/s (its speed toward the mass)
T_STAR = D0 / V_O
DT = 1e-4
SCHEMES = {"newmark": Newmark, "moreau_jean": MoreauJean,
           "moreau_jean_velocity": lambda ops, dt: MoreauJean(ops, dt, level="velocity"),
           "central_difference": CentralDifference}


def one_by_one(value):
    A = PETSc.Mat().createAIJ([1, 1], nnz=1, comm=PETSc.COMM_SELF)
    A.setValue(0, 0, value)
    A.assemble()
    return A


def struck_mass(scheme: str, e: float, replicated: bool = False):
    """The mass (u along the plane's normal, P u = u <= d(t)) at rest; the plane at d0 moving at -v_o.
    ``replicated``: the system as the reduced model's (numpy, diagonal), stepped in blocks between
    contacts. Returns rows (t, u, v, gap, impulse)."""
    plane = MovingPlane(None, np.array([1.0]), [], D0, -V_O)
    plane.d0 = np.array([D0])   # (a one-dof system: its row and gap given, not from a mesh)
    newton = laws.RowLaws([(laws.law_of("newton", {"restitution": e}), [0])], 1)
    mass, stiffness = (np.full(1, M_), np.zeros(1)) if replicated else (one_by_one(M_), one_by_one(0.0))
    ops = Operators(mass, stiffness, None, ConstantLoad(0.0), np.array([[1.0]]), np.array([D0]),
                    newton.restitution, laws=newton, relations=Relations.of([plane]))
    if replicated:
        U0, V0 = np.zeros(1), np.zeros(1)
    else:
        U0, V0 = PETSc.Vec().createSeq(1), PETSc.Vec().createSeq(1)
        U0.set(0.0)
        V0.set(0.0)
    rows, budgets = [], []

    class Recorder:
        def write(self, s):
            rows.append((s.t, s.U[0], s.V[0], s.gap[0], s.impulse[0] + s.force[0]))
            budgets.append(s.energy.copy())

    it = SCHEMES[scheme](ops, DT)
    blocks = BlockStepper.of(it) if replicated else None
    integrate(it, U0, V0, 2.0 * T_STAR, [Recorder()], blocks=blocks)
    struck_mass.budgets = budgets
    return np.array(rows), blocks


def check_budget(budgets, scale: float, closes: float = 1e-10):
    """The balance closes to ``closes`` of ``scale``; the normal contact's loss (Carnot's and the
    position-level forces' together: Newmark's correction may take back part of what its forces booked,
    in the obstacle's frame as at a fixed one), the friction's and the damping's are >= 0 (to round-off);
    the energy never exceeds the initial energy plus the work put in (the obstacle's included)."""
    for e in budgets:
        assert abs(e.error) <= closes * scale, (e.error, scale)
        losses = [e.impact_loss + e.contact_loss + sum(e.losses.values()), e.friction_loss, e.damping_loss]
        assert min(losses) >= -1e-12 * scale, losses
        assert e.total <= e.initial + e.external_work + 1e-12 * scale


def check(h, scheme, e):
    t, u, v, gap, push = h.T
    first = int(np.flatnonzero(push > 0.0)[0])
    assert abs(t[first] - T_STAR) <= DT * (1.0 + 1e-9)            # the impact within a step of d0 / v_o
    assert np.all(v[:first] == 0.0) and np.all(u[:first] == 0.0)   # at rest until struck
    np.testing.assert_allclose(gap[:first], D0 - V_O * t[:first], rtol=0, atol=1e-15)   # the reported gap: d(t) - u
    leaves = -(1.0 + e) * V_O
    after = first + 2   # (central difference: its force acts one step late)
    assert v[after:] == pytest.approx(leaves, rel=1e-12)
    drift = V_O * DT if scheme == "moreau_jean_velocity" else 1e-12 * D0   # (the velocity level: up to dt x speed)
    assert gap.min() >= -drift
    if e == 0.0 and scheme != "moreau_jean_velocity":   # it rides on the plane
        assert np.abs(gap[after:]).max() <= 1e-12 * D0
    if e > 0.0:   # it leaves the plane: the gap opens at e v_o
        np.testing.assert_allclose(np.diff(gap[after:]), e * V_O * DT, rtol=1e-9)
    budgets = struck_mass.budgets
    scale = M_ * (1.0 + e) * V_O ** 2
    check_budget(budgets, scale)
    end = budgets[-1]
    assert end.external_work == pytest.approx(scale, rel=1e-9)   # the plane's work: m (1 + e) v_o^2
    assert end.kinetic == pytest.approx(0.5 * M_ * ((1.0 + e) * V_O) ** 2, rel=1e-9)


@pytest.mark.parametrize("e", [0.0, 0.5])
@pytest.mark.parametrize("scheme", ["newmark", "moreau_jean", "moreau_jean_velocity"])
def test_a_moving_plane_strikes_a_mass_at_rest(scheme, e):
    check(struck_mass(scheme, e)[0], scheme, e)


def test_central_difference_a_moving_plane_strikes_plastically():
    """Central difference's forward-increment contact is plastic at the node (it takes no restitution)."""
    check(struck_mass("central_difference", 0.0)[0], "central_difference", 0.0)


@pytest.mark.parametrize("e", [0.0, 0.5])
@pytest.mark.parametrize("scheme", ["newmark", "moreau_jean"])
def test_the_reduced_models_block_steps_see_the_moving_plane(scheme, e):
    """The reduced model's form (replicated, diagonal): the steps before the impact go in blocks, which
    stop before the moving plane arrives; the history is that of the one-step-at-a-time run."""
    h, blocks = struck_mass(scheme, e, replicated=True)
    if blocks is None:
        pytest.skip("no compiled steps (Numba)")
    assert blocks.steps > 0
    check(h, scheme, e)
    np.testing.assert_allclose(h, struck_mass(scheme, e)[0], rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("method", ["newmark", "moreau_jean", "central_difference", "modal"])
def test_a_moving_wall_strikes_a_free_bar(method):
    """The case's fixed plane swapped for the moving one on the built constraints (the relations only:
    no integrator, no builder told): the contact starts at gap / v_o within a step, the gap never
    closes past round-off, the struck end rides on the wall (the full model's Carnot rows), and the
    bar (rho = E = A = L = 1) takes the impulse 2 m v_o."""
    gap, speed = 0.1, 1.0
    overrides = ["mesh.cells=50", "initial.velocity=[0.0]", "solver.dt=0.005", f"solver.method={method}",
                 "solver.t_end=2.4", "output.vtk=false"]
    overrides += {"modal": ["solver.modes=8"], "central_difference": ["solver.mass=lumped", "solver.dt=0.01"]
                  }.get(method, [])
    case = load_case(CASES / "impacting_bar.yaml", overrides)
    model, cons = model_and_constraints(case, MPI.COMM_SELF)
    fixed = cons.relations.relations[0]
    wall = MovingPlane(fixed.nodes, fixed.normal, fixed.tangents, gap, -speed)
    wall.rows(model)
    cons.relations = Relations.of([wall])
    system = (reduced_system if method == "modal" else full_system)(case, model, cons)
    rows, budgets = [], []

    class Recorder:
        def write(self, s):
            rows.append((s.t, s.gap[0], s.impulse[0], s.normal_velocity[0]))
            budgets.append(s.energy.copy())

    integrate(make_integrator(case, system.operators), system.U0, system.V0, case.solver.t_end, [Recorder()])
    t, g, impulse, pv = np.array(rows).T
    push = np.flatnonzero(impulse > 0.0)
    dt = case.solver.dt
    assert abs(t[push[0]] - gap / speed) <= dt * (1.0 + 1e-9)
    assert g.min() >= -1e-12 * gap
    assert impulse.sum() == pytest.approx(2.0 * speed, rel=0.03)
    assert t[push[-1]] - t[push[0]] == pytest.approx(2.0, abs=0.15)   # 2 L / c in contact
    if method != "modal":   # (the reduced model's rows are compliant: no Carnot correction)
        np.testing.assert_allclose(pv[push[1:-1]], -speed, rtol=1e-9)
    # (the bar's mass is 1: the wall's work is of the order of m v_o^2)
    check_budget(budgets, max(1.0, max(b.external_work for b in budgets)))
