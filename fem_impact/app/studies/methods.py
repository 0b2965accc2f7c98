"""The integration methods the studies compare, by name: the case changes that select each, what it
is, its stability limit and the resolution knob its Pareto ladder turns.

A method is *available* when the case takes its changes: a key or value this version does not
know (a CaseError) means the method has not landed yet, and studies skip it with a note. (A run
that still refuses it when it starts, e.g. a method name the case accepts but no model runs yet,
is recorded as a skipped level with the run's message.)

:func:`apply` selects a method on a case. The changes given to a study (the command line's
``--set`` options) come after the method's, so that they win and may set the method's own keys
(``solver.modes``), which the case as written may not take.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from ...config.case import Case, CaseError
from ...integrators.parameters import DEFAULT_METHOD as DEFAULT_SOLVER_METHOD
from ...integrators.parameters import REDUCED


@dataclass(frozen=True)
class Method:
    """One integration method of a study.

    Attributes
    ----------
    name : str
        The name used on the command line (``--methods``) and in the CSV files.
    changes : mapping of str to value
        The case changes selecting it, dotted key paths to values (``{"solver.method": "newmark"}``),
        on top of the case as given; ``solver.method`` first.
    description : str
        One line: what it is.
    stability : str
        Its stability limit, in words.
    knob : str
        What its Pareto ladder refines: ``"mesh"`` (mesh cells at a fixed Courant number on the
        built-in bar, the time step on a mesh file) or ``"modes"`` (kept modes n1).
    max_courant : float or None
        Courant number ``c dt / h`` above which it is known to be unstable (None: no limit);
        the Pareto ladder keeps below it, the stability sweep does not.
    """

    name: str
    changes: Mapping[str, object] = field(hash=False)
    description: str
    stability: str
    knob: str = "mesh"
    max_courant: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "changes", MappingProxyType(dict(self.changes)))


# Newmark with gamma = 0.6 and the beta of the widest stability, (gamma + 1/2)^2 / 4 = 0.3025.
_DAMPED = {"solver.gamma": 0.6, "solver.beta": 0.3025}
# The modal methods keep 20 modes unless a ladder sets solver.modes (`modes: auto` would follow the
# time step through the output rate, which the stability sweep varies).
_MODAL = {"solver.method": REDUCED, "solver.modes": 20}
_NEWMARK = {"solver.method": "newmark"}

METHODS: dict[str, Method] = {m.name: m for m in (
    Method("trapezoidal", _NEWMARK,
           "Newmark trapezoidal (beta 1/4, gamma 1/2), position-level multipliers and Carnot's velocity "
           "correction (the paper's method)",
           "unconditionally stable without contact; its contact forces create energy at large steps in "
           "persistent contact"),
    Method("moreau-jean", {"solver.method": "moreau_jean"},
           "Moreau-Jean theta = 1/2 at the position level: trapezoidal smooth forces, contact impulses at the "
           "end of the step holding the gaps, Carnot's correction for e (the default method)",
           "unconditionally stable; the contacts never create energy; gaps exact"),
    Method("moreau-jean-velocity", {"solver.method": "moreau_jean", "solver.level": "velocity"},
           "Moreau-Jean theta = 1/2 with Newton's impact law on velocities (as Siconos)",
           "unconditionally stable; the contacts never create energy; gaps drift up to dt x impact speed"),
    Method("position-only", {**_NEWMARK, "solver.impact_correction": False},
           "Newmark trapezoidal with position-level multipliers only (no velocity correction)",
           "unconditionally stable without contact; the contact force oscillates"),
    Method("damped-newmark", {**_NEWMARK, **_DAMPED},
           "Newmark with numerical damping: gamma 0.6, beta 0.3025, Carnot correction",
           "unconditionally stable (2 beta >= gamma >= 1/2); first order"),
    Method("central-difference", {"solver.method": "central_difference", "solver.mass": "lumped"},
           "explicit central difference, lumped mass, forward-increment Lagrange multipliers",
           "conditionally stable: c dt / h <= 1 (1D, lumped mass)", max_courant=1.0),
    Method("mass-redistribution", {**_NEWMARK, "solver.mass": "redistributed"},
           "Newmark trapezoidal with no mass on the contact nodes (Khenous, Laborde & Renard 2008)",
           "unconditionally stable; no contact-force oscillation"),
    Method("modal-static", {**_MODAL, "solver.scheme": "newmark", "solver.static_correction": True},
           "reduced model: n1 modes plus the static correction of the truncated ones (trapezoidal rule)",
           "unconditionally stable; converges to the full model as n1 grows", knob="modes"),
    Method("modal-moreau-jean", {**_MODAL, "solver.scheme": "moreau_jean", "solver.static_correction": True},
           "reduced model: n1 modes plus the static correction, stepped by Moreau-Jean",
           "unconditionally stable; the contacts never create energy", knob="modes"),
    Method("modal-truncated", {**_MODAL, "solver.scheme": "newmark", "solver.static_correction": False},
           "reduced model: n1 modes, plain truncation (trapezoidal rule)",
           "unconditionally stable; the contact compliance is wrong whatever dt", knob="modes"),
)}

# The default of a case (the references of studies without an exact solution): the preset that selects it.
DEFAULT_METHOD = next(m.name for m in METHODS.values() if m.changes == {"solver.method": DEFAULT_SOLVER_METHOD})


class UnknownMethod(ValueError):
    """A method name that is not in the registry."""


def get(name: str) -> Method:
    try:
        return METHODS[name]
    except KeyError:
        raise UnknownMethod(f"unknown method '{name}' (known: {', '.join(METHODS)})") from None


def parse_methods(text: str | None) -> list[Method]:
    """``"a,b"`` -> the methods, in registry order when None (all of them)."""
    if text is None:
        return list(METHODS.values())
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise UnknownMethod(f"no method named in {text!r} (known: {', '.join(METHODS)})")
    return [get(n) for n in dict.fromkeys(names)]


def apply(method: Method | str, case: Case, changes=()) -> Case:
    """A copy of ``case`` that runs ``method``, then with ``changes`` (a mapping, or ``--set`` options: they
    win, and may set the method's own keys, e.g. ``solver.modes``); CaseError when the case does not take them.

    A solver key of ``changes`` goes to the methods that take it only (:func:`taken`).
    """
    method = get(method) if isinstance(method, str) else method
    try:
        selected = case.with_changes(method.changes)
    except CaseError as refused:
        # The method alone may be refused where the given changes mend it (a modal method on a case
        # with friction, given ``solver.static_correction=false``): both then in one change.
        from .common import given_changes

        try:
            return case.with_changes({**method.changes, **given_changes(changes)})
        except CaseError:
            raise refused from None
    changes = taken(selected, changes)
    return selected.with_changes(changes) if changes else selected


def taken(selected: Case, changes):
    """The ``changes`` (a mapping, or ``--set`` options) that the method of ``selected`` takes: a solver key of
    another method's is left out, so that ``--set solver.modes=40`` sets the modal methods' n1 in a study and
    leaves the others as they are (their schema would refuse it)."""
    takes = type(selected.solver).model_fields

    def wanted(key: str) -> bool:
        parts = key.strip().split(".")
        return not (parts[0] == "solver" and len(parts) > 1 and parts[1] not in takes)

    if isinstance(changes, Mapping):
        return {key: value for key, value in changes.items() if wanted(key)}
    return [option for option in changes if wanted(option.partition("=")[0])]


def changes_for(method: Method | str, case: Case, given: dict) -> dict:
    """A level's changes for ``method``: its own, then the ``given`` ones it takes (a mapping)."""
    method = get(method) if isinstance(method, str) else method
    try:
        return {**method.changes, **taken(case.with_changes(method.changes), given)}
    except CaseError:   # (the method alone refused, the given changes mending it: see apply)
        return {**method.changes, **given}


def availability(method: Method | str, case: Case, changes=()) -> str | None:
    """None when ``method`` (with ``changes`` after it) runs on the case in this version, else why not (one line)."""
    try:
        apply(method, case, changes)
    except CaseError as err:
        return f"does not run on this case ({err.key}: {err.message})" if err.key else str(err)
    return None


def available(name: str, case: Case) -> bool:
    """Whether the method ``name`` runs on the case (``availability`` says why not)."""
    return availability(name, case) is None


def describe_methods() -> str:
    """The registry as text, for --help."""
    return "\n".join(f"  {m.name:<20} {m.description}; {m.stability}" for m in METHODS.values())
