"""The one place that turns a Case into the domain objects the physics layers take."""

from __future__ import annotations

from ..fem.specs import ModelSpec, ReductionSpec
from .case import Case


def model_spec(case: Case) -> ModelSpec:
    """What builds the finite-element model (fem_impact.fem.model.build_model)."""
    groups = [(("contacts", i, "nodes"), group) for i, contact in enumerate(case.contacts) for group in contact.nodes]
    return ModelSpec(case.material, dict(case.materials or {}), case.damping, case.initial, list(case.supports),
                     list(case.loads), case.solver.mass, case.mesh.hypothesis, case.mesh.axis or "y", groups)


def reduction_spec(case: Case) -> ReductionSpec:
    """The reduced model's choices of a ``method: modal`` case (fem_impact.fem.reduced)."""
    solver = case.solver
    return ReductionSpec(solver.modes, solver.tolerance, solver.static_correction, solver.dt, solver.t_end,
                         case.output.every,
                         case.damping.alpha, case.damping.beta)
