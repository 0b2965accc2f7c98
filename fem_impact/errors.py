"""Errors that end a run after its input was accepted (importable without dolfinx or PETSc)."""


class SimulationError(RuntimeError):
    """The run cannot go on (blow-up, NaN, a contact problem without solution)."""


class ContactSolverError(SimulationError):
    """The small contact problem could not be solved (singular or ill-posed constraints)."""
