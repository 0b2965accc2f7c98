"""Time integrators, chosen by name from a registry (``solver.method`` in the case file).

``parameters`` (light: pydantic only) says what each method takes; the integrators themselves
(PETSc) load on first use, so that a case file is validated without them.
"""

from .parameters import DEFAULT_METHOD, MODAL_SCHEMES, SCHEMAS, SOLVER

_LAZY = {"EnergyBudget": "base", "EnergyCreated": "base", "EnergyWatch": "base", "Operators": "base",
         "SimulationError": "base", "StepState": "base", "integrate": "base", "steps_for": "base",
         "CentralDifference": "central_difference", "MoreauJean": "moreau_jean", "Newmark": "newmark"}

__all__ = ["DEFAULT_METHOD", "INTEGRATORS", "MODAL_SCHEMES", "SCHEMAS", "SOLVER", *_LAZY]


def __getattr__(name):
    import importlib

    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    if name == "INTEGRATORS":   # the integrator of each time scheme (the reduced model uses its solver.scheme's)
        from .central_difference import CentralDifference
        from .moreau_jean import MoreauJean
        from .newmark import Newmark

        return {MoreauJean.name: MoreauJean, Newmark.name: Newmark, CentralDifference.name: CentralDifference}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
