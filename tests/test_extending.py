"""A new contact law and a new time integrator, defined here and registered without editing the
package, each run through ``fem_impact.run``: the registries are the single lists the case file,
``--help`` and the pipeline read."""

from __future__ import annotations

from typing import Literal

import numpy as np
import pytest
from pydantic import Field

import fem_impact
from fem_impact.integrators import parameters
from fem_impact.integrators.state import StepState
from fem_impact.linalg.backends import owned_values
from fem_impact.mechanics.energy import EnergyBudget
from fem_impact.integrators.parameters import SolverParameters
from fem_impact.nonsmooth import laws

BAR = {   # B2a: a free bar of length 1 (c = 1) at -1 toward a wall 0.1 away
    "mesh": {"shape": "bar", "cells": 100},
    "material": {"E": 1.0, "rho": 1.0},
    "initial": {"velocity": [-1.0]},
    "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0], "gap": 0.1}],
    "solver": {"dt": 0.005, "t_end": 3.0},
    "output": {"vtk": False},
}


class PlasticStop(laws.ContactLaw):
    """A perfectly plastic stop: the normal velocity after an impact is zero, whatever else is said."""

    name = "plastic"
    summary = "perfectly plastic stop"

    def restitution(self) -> float:
        return 0.0


class ExplicitEuler:
    """Forward Euler, ``U1 = U0 + dt V0``, ``V1 = V0 + dt A0``, ``M A = R - K U - C V``: no contact."""

    name = "explicit_euler"

    def __init__(self, ops, dt: float):
        if ops.p:
            raise ValueError("explicit_euler takes no contacts")
        self.ops, self.dt, self.alg = ops, dt, ops.algebra
        self.solve_M = self.alg.factorize(ops.M, spd=True)
        self.U, self.V, self.A, self.R, self.f, self.MV = (self.alg.vector() for _ in range(6))

    @classmethod
    def from_solver(cls, ops, solver):
        return cls(ops, solver.dt)

    def _acceleration(self, t: float) -> None:
        ops, alg = self.ops, self.alg
        ops.load.evaluate(t, self.R)
        alg.mult(ops.K, self.U, self.f)
        np.subtract(self.R, self.f, out=self.f)
        if ops.C is not None:
            self.f -= alg.mult(ops.C, self.V, alg.vector())
        self.solve_M(self.f, self.A)

    def _state(self, step: int, t: float, energy: EnergyBudget) -> StepState:
        alg = self.alg
        sums = alg.allsum(np.array([self.V @ alg.mult(self.ops.M, self.V, self.MV),
                                    self.U @ alg.mult(self.ops.K, self.U, alg.vector())]))
        energy.kinetic, energy.strain = 0.5 * sums[0], 0.5 * sums[1]
        none = np.zeros(0)
        self.state = StepState(step=step, t=t, U=self.U, V=self.V, A=self.A, gap=none, force=none, impulse=none,
                               energy=energy, normal_displacement=none, normal_velocity=none)
        return self.state

    def start(self, U0, V0, t0: float = 0.0) -> StepState:
        self.t0 = t0
        self.U[:], self.V[:] = owned_values(U0), owned_values(V0)
        self._acceleration(t0)
        state = self._state(0, t0, EnergyBudget())
        state.energy.initial = state.energy.total
        return state

    def step(self) -> StepState:
        st, dt = self.state, self.dt
        work = float(self.alg.allsum(np.array([dt * (self.V @ self.R)]))[0])   # (left point: R0 . dt V0)
        self.U += dt * self.V
        self.V += dt * self.A
        t1 = self.t0 + (st.step + 1) * dt
        self._acceleration(t1)
        energy = st.energy.copy()
        energy.external_work += work
        return self._state(st.step + 1, t1, energy)


class ExplicitEulerParameters(SolverParameters):
    """``explicit_euler``: forward Euler, for a test (first order, unstable for any oscillation)."""

    method: Literal["explicit_euler"]


@pytest.fixture
def plastic_law():
    laws.register(PlasticStop)
    yield
    laws.unregister(PlasticStop.name)


@pytest.fixture
def euler():
    parameters.register("explicit_euler", ExplicitEulerParameters, ExplicitEuler, "forward Euler (a test's)")
    yield
    parameters.unregister("explicit_euler")


def with_contact(**keys) -> dict:
    return {**BAR, "contacts": [{**BAR["contacts"][0], **keys}]}


def test_a_registered_contact_law_runs_with_its_own_keys(plastic_law):
    """The plastic stop on B2a gives exactly the history of Newton's law with e = 0, and refuses a
    restitution (its keys are its own)."""
    plastic = fem_impact.run(fem_impact.Case.from_dict(with_contact(law="plastic"))).history
    newton = fem_impact.run(fem_impact.Case.from_dict(with_contact(restitution=0.0))).history
    assert plastic.keys() == newton.keys()
    for column in newton:
        np.testing.assert_array_equal(plastic[column], newton[column], err_msg=column)
    force = newton["wall.force"]
    assert np.median(force[force > 0]) == pytest.approx(1.0, rel=0.02)   # rho c A v0: the bar did hit the wall
    with pytest.raises(fem_impact.CaseError, match="contact law plastic does not use 'restitution'"):
        fem_impact.Case.from_dict(with_contact(law="plastic", restitution=0.5))
    case = fem_impact.Case.from_dict(with_contact(law="plastic"))
    assert case.resolved()["contacts"][0]["law"] == "plastic"
    assert fem_impact.Case.from_dict(case.resolved()).contacts[0].law == "plastic"   # (its dump reads back)


class SoftStopKeys(laws.LawKeys):
    stiffness: float = Field(gt=0.0, description="spring stiffness", json_schema_extra={"unit": "N/m"})


class SoftStop(laws.ContactLaw):
    """An elastic stop under another name: its keys are its own schema's, checked as a case file checks any."""

    name = "soft"
    keys = SoftStopKeys

    def compliance(self) -> float:
        return 1.0 / self.params.stiffness


def test_a_registered_laws_keys_are_reported_in_the_case_files_words():
    laws.register(SoftStop)
    try:
        for value, message in ((-1.0, "contacts[0].stiffness: must be > 0, got -1.0"),
                               ("x", "contacts[0].stiffness: expected a number, got 'x'"),
                               (None, "contacts[0].stiffness: expected a number, got null")):
            with pytest.raises(fem_impact.CaseError) as err:
                fem_impact.Case.from_dict(with_contact(law="soft", stiffness=value))
            assert str(err.value) == message
        with pytest.raises(fem_impact.CaseError, match=r"^contacts\[0\]\.stiffness: missing required key$"):
            fem_impact.Case.from_dict(with_contact(law="soft"))
        assert fem_impact.Case.from_dict(with_contact(law="soft", stiffness=1e3)).contacts[0].law_keys == {
            "stiffness": 1e3}
    finally:
        laws.unregister(SoftStop.name)


def test_an_unregistered_law_is_refused_with_the_registered_ones():
    with pytest.raises(fem_impact.CaseError, match="must be one of newton, elastic_stop; got 'plastic'"):
        fem_impact.Case.from_dict(with_contact(law="plastic"))


def test_a_registered_integrator_runs_and_joins_the_one_list(euler):
    """Forward Euler on a free bar under a uniform body acceleration g: the bar translates rigidly
    (K U = 0), and the scheme's own recurrence gives u_n = g dt^2 n (n - 1) / 2, v_n = g n dt."""
    g, dt, n = -9.81, 0.01, 50
    case = fem_impact.Case.from_dict({
        "mesh": {"shape": "bar", "cells": 20},
        "material": {"E": 1.0, "rho": 1.0},
        "loads": [{"body": "all", "acceleration": [g]}],
        "solver": {"method": "explicit_euler", "dt": dt, "t_end": n * dt},
        "output": {"vtk": False, "probes": {"tip": [1.0]}},
    })
    h = fem_impact.run(case).history
    steps = np.arange(n + 1)
    np.testing.assert_allclose(h["tip.ux"], g * dt * dt * steps * (steps - 1) / 2, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(h["tip.vx"], g * dt * steps, rtol=1e-12)
    assert "explicit_euler" in parameters.METHODS and "explicit_euler" in parameters.help_text()
    with pytest.raises(fem_impact.CaseError, match="explicit_euler"):
        fem_impact.Case.from_dict({**case.resolved(), "solver": {"method": "nope", "dt": dt, "t_end": 1.0}})


def test_the_methods_are_one_list():
    """Every place that names the methods reads the registry: the case file's choices, --help, the
    reduced model's schemes and the integrator classes."""
    from fem_impact.integrators import INTEGRATORS

    full = [m for m in parameters.METHODS if m != parameters.REDUCED]
    assert list(INTEGRATORS) == full
    assert [tag for tag in parameters.SCHEMAS if "/" not in tag] == full
    assert parameters.MODAL_SCHEMES == ["moreau_jean", "newmark"]
    for method in full:
        assert f"method: {method}" in parameters.help_text()
    with pytest.raises(fem_impact.CaseError, match="must be one of " + ", ".join(parameters.METHODS)):
        fem_impact.Case.from_dict({**BAR, "solver": {"method": "nope", "dt": 0.1, "t_end": 1.0}})
