"""Time integrators, chosen by name from a registry (``solver.method`` in the case file)."""

from .base import EnergyBudget, Operators, SimulationError, StepState, integrate, steps_for
from .newmark import Newmark

METHODS = {Newmark.name: Newmark}

__all__ = ["METHODS", "EnergyBudget", "Newmark", "Operators", "SimulationError", "StepState", "integrate", "steps_for"]
