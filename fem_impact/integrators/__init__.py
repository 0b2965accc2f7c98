"""Time integrators, chosen by name from a registry (``solver.method`` in the case file)."""

from .base import (EnergyBudget, EnergyCreated, EnergyWatch, Operators, SimulationError, StepState, integrate,
                   steps_for)
from .central_difference import CentralDifference
from .moreau_jean import MoreauJean
from .newmark import Newmark

# solver.method -> integrator of the full model; the reduced model (method modal) is integrated
# with the one its solver.scheme names.
METHODS = {MoreauJean.name: MoreauJean, Newmark.name: Newmark, CentralDifference.name: CentralDifference}

__all__ = ["METHODS", "CentralDifference", "EnergyBudget", "EnergyCreated", "EnergyWatch", "MoreauJean", "Newmark",
           "Operators", "SimulationError", "StepState", "integrate", "steps_for"]
