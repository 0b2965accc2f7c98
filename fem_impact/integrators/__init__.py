"""Time integrators, chosen by name from a registry (``solver.method`` in the case file)."""

from .base import EnergyBudget, Operators, SimulationError, StepState, integrate, steps_for
from .central_difference import CentralDifference
from .newmark import Newmark

# solver.method -> integrator (the modal model is integrated with Newmark).
METHODS = {Newmark.name: Newmark, CentralDifference.name: CentralDifference, "modal": Newmark}

__all__ = ["METHODS", "CentralDifference", "EnergyBudget", "Newmark", "Operators", "SimulationError", "StepState",
           "integrate", "steps_for"]
