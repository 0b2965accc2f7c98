"""Time integrators, chosen by name from a registry (``solver.method`` in the case file).

``parameters`` (light: pydantic only) holds the registry, the single list of methods, and what
each takes; the integrators themselves (PETSc) load on first use, so that a case file is
validated without them. A new method is a class and a :func:`register` call.
"""

from .parameters import (DEFAULT_METHOD, METHODS, MODAL_SCHEMES, REDUCED, SCHEMAS, integrator_class, is_reduced,
                         register, scheme_of, solver_schema)

# name -> the module (relative to the package fem_impact) that defines it
_LAZY = {"EnergyBudget": "mechanics.energy", "EnergyCreated": "mechanics.energy", "EnergyWatch": "mechanics.energy",
         "Operators": "mechanics.system", "SimulationError": "errors", "StepState": "integrators.state",
         "integrate": "integrators.loop", "steps_for": "integrators.parameters",
         "CentralDifference": "integrators.central_difference", "MoreauJean": "integrators.moreau_jean",
         "Newmark": "integrators.newmark", "BlockStepper": "integrators.blocks", "StepBlock": "integrators.blocks"}

__all__ = ["DEFAULT_METHOD", "INTEGRATORS", "METHODS", "MODAL_SCHEMES", "REDUCED", "SCHEMAS", "integrator_class",
           "is_reduced", "register", "scheme_of", "solver_schema", *_LAZY]


def __getattr__(name):
    import importlib

    if name in _LAZY:
        return getattr(importlib.import_module(f"fem_impact.{_LAZY[name]}"), name)
    if name == "INTEGRATORS":   # the integrator of each time scheme (the reduced model uses its solver.scheme's)
        return {method: integrator_class(method) for method in METHODS if method != REDUCED}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
