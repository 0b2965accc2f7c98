"""The checks across sections of a validated case: what a key means depends on another section's
(the axisymmetric section, friction and the method, a moved support and the reduced model, a
parameter set and the expressions that use it, a declared exact solution and the case)."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from ..errors import CaseError
from ..integrators.parameters import SCHEMAS, is_reduced, scheme_of
from .loader import _dotted

if TYPE_CHECKING:   # case.py runs these checks on the Case it builds: no import back at run time
    from .case import Case

log = logging.getLogger(__name__)


def check_case(case: Case, changed) -> None:
    """Every check across sections; `changed` the key paths the changes of this validation set."""
    from .numbers import check_numbers

    check_numbers(case)
    _check_section(case)
    _check_friction(case)
    _check_moving_supports(case)
    _check_set_parameters(case, changed)
    _check_reference(case, changed)


def _check_reference(case: Case, changed) -> None:
    """A declared exact solution must fit the case (fem_impact.references: what the studies measure against).

    Where the case is written (a file, a dict, or a change of ``reference`` itself) a reference that does not
    fit is bad input. Changes of other keys may take the case out of its reference (a benchmark used as a
    template: ``--set loads=...``): the reference is then left behind, as a change of method leaves the
    previous method's keys: the run and its resolved dump have none, and ``references.from_case`` still says
    why the case does not fit it (the studies refuse to measure against it).
    """
    if case.reference is None:
        return
    from ..references import from_case

    try:
        from_case(case)
    except CaseError as misfit:
        if not changed or ("reference",) in changed:
            raise
        log.info("%s: the changes took the case out of its reference, which is left behind", misfit)
        case.reference = None


def _check_section(case: Case) -> None:
    """An axisymmetric model's section is the circle, 2 pi r: a given ``area`` would be ignored (a null
    one is not given, as everywhere in a case file: ``--set material.area=null`` takes it out)."""
    if case.mesh.hypothesis != "axisymmetric":
        return
    source = case.source if isinstance(case.source, dict) else {}
    material = source.get("material")
    where = [("material", "area")] if isinstance(material, dict) and material.get("area") is not None else []
    materials = source.get("materials")
    for body, values in (materials.items() if isinstance(materials, dict) else ()):
        if isinstance(values, dict) and values.get("area") is not None:
            where.append(("materials", body, "area"))
    if where:
        raise case.error(where[0], "an axisymmetric model's section is the whole circle, 2 pi r (forces are totals "
                                   f"over it): remove area (or give it null: --set {_dotted(where[0])}=null)")


def _check_friction(case: Case) -> None:
    """Friction needs a method that solves the cone problem (Moreau-Jean, on the full model or the reduced one,
    with or without its static correction); the method's schema says whether it does (the integrator, and
    PETSc, are not loaded to validate a case)."""
    for i, contact in enumerate(case.contacts):
        if not contact.friction:
            continue
        if not SCHEMAS[scheme_of(case.solver)].takes_friction:
            # (the reduced model's time scheme is the cause: the model itself takes friction)
            key, use = (("solver.scheme", "solver.scheme: moreau_jean") if is_reduced(case.solver) else
                        ("solver.method", "solver.method: moreau_jean"))
            raise case.error(("contacts", i, "friction"),
                             f"{key} {scheme_of(case.solver)} cannot take friction (its contact step is an "
                             f"LCP on normal forces only): use {use}")


def _check_moving_supports(case: Case) -> None:
    """The reduced model holds a support's quasi-static motion in its static correction: the
    fixed-base modes alone carry only the share their mass takes part in (docs/theory.md s. 2.4)."""
    if not is_reduced(case.solver) or case.solver.static_correction:
        return
    for i, support in enumerate(case.supports):
        if any(not (f.is_constant and f.at_time(0.0) == 0.0) for f in support.displacement or ()):
            raise case.error(("solver", "static_correction"),
                             f"supports[{i}] moves (displacement), and the reduced model holds a support's motion "
                             "in its static correction (the fixed-base modes alone leave most of it out): set "
                             "solver.static_correction: true, or use the full model (solver.method: moreau_jean)")


def _check_set_parameters(case: Case, changed) -> None:
    """A parameter set with --set (or a change) that no expression uses is a typo, not a silent no-op."""
    used = set()
    for _, expr in case.expressions():
        used |= expr.constants
    for path in changed:
        names = [path[1]] if len(path) == 2 and path[0] == "parameters" else (
            sorted(case.parameters) if path == ("parameters",) else [])
        for name in names:
            if name in case.parameters and name not in used:
                known = ", ".join(sorted(used)) or "none"
                raise case.error(("parameters", name), f"no expression of the case uses parameter '{name}' "
                                                       f"(used: {known})")
