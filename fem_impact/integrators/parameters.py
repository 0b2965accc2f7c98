"""The registry of time-integration methods, and what each takes in the case file's ``solver`` section.

One typed schema per method (pydantic): its keys, defaults, ranges, units and meaning, in one
place. :func:`register` puts a method in the registry, the single list of methods (``METHODS``)
that the case file, ``--help``, the pipeline and the studies read: its schema, its integrator
class, and whether it can step the reduced model (then ``method: modal, scheme: NAME`` takes the
reduction's keys and the method's, a schema derived here). :func:`solver_schema` is their union,
discriminated by ``method`` (and, for the reduced model, by ``scheme``). A key that a method does
not use is refused (``extra="forbid"``).

This module is light on purpose (pydantic only, no PETSc): a case file is validated before
anything heavy is imported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, ClassVar, Literal, Union

from pydantic import (BaseModel, ConfigDict, Discriminator, Field, PlainValidator, Tag, TypeAdapter,
                      create_model, field_validator, model_validator)

DEFAULT_METHOD = "moreau_jean"
REDUCED = "modal"   # the method that is a choice of model: the reduced one, stepped by its `scheme`


class KeyProblem(ValueError):
    """A check across keys that names the key to change (the case file reports it on that key)."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


def _number(unit: str, doc: str, default=..., **bounds):
    return Field(default, description=doc, json_schema_extra={"unit": unit}, **bounds)


def _count_or_auto(value):
    """``modes``: an integer >= 1 (integral floats such as 1e2 too), or ``auto``."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if value == "auto" or (isinstance(value, int) and not isinstance(value, bool) and value >= 1):
        return value
    raise ValueError(f"expected 'auto' or an integer >= 1, got {value!r}" if not isinstance(value, (dict, list))
                     else "expected 'auto' or an integer >= 1")


def _flag_or_auto(value):
    """``blocks``: true, false or ``auto``."""
    if isinstance(value, bool) or value == "auto":
        return value
    raise ValueError(f"expected true, false or 'auto', got {value!r}" if not isinstance(value, (dict, list))
                     else "expected true, false or 'auto'")


class SolverParameters(BaseModel):
    """Keys every method takes: the time step, the end time, the mass matrix."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)
    # Whether the method's contact step takes Coulomb friction (the cone problem): the case file is
    # checked against it without importing the integrator.
    takes_friction: ClassVar[bool] = False

    method: str
    dt: float = _number("s", "time step", gt=0)
    t_end: float = _number("s", "end time of the run", gt=0)
    mass: Literal["consistent", "lumped", "redistributed"] = Field(
        "consistent", description="mass matrix: consistent, lumped (row sums), or redistributed (no mass on "
                                  "the contact nodes; Khenous, Laborde & Renard 2008)")

    def as_case(self) -> dict:
        """The keys as a case file gives them (method and scheme first), to read back the same."""
        data = self.model_dump()
        return {key: data[key] for key in valid_keys(type(self)) if key in self._written()}

    def _written(self) -> set[str]:
        return set(type(self).model_fields)

    @model_validator(mode="after")
    def _dt_within_t_end(self):
        if self.dt > self.t_end:
            raise KeyProblem("dt", f"must be <= t_end ({self.t_end:g}), got {self.dt:g}")
        return self


class _MoreauJeanKeys(BaseModel):
    theta: float = _number("-", "theta of the smooth forces: 1/2 the trapezoidal rule (energy-conserving), "
                                "1 backward Euler (dissipative)", 0.5, ge=0.5, le=1.0)
    level: Literal["position", "velocity"] = Field(
        "position", description="position: gaps held exactly at the end of every step (with friction too), "
                                "Carnot's correction for the restitution (with friction a frictional impact "
                                "problem); velocity: Newton's impact law on the velocities, gaps drift by up to "
                                "dt times the impact speed")


class _NewmarkKeys(BaseModel):
    beta: float = _number("-", "Newmark's beta (1/4: trapezoidal rule)", 0.25, gt=0)
    gamma: float = _number("-", "Newmark's gamma (1/2: no numerical damping; above, first order)", 0.5, ge=0)
    impact_correction: bool = Field(True, description="Carnot's velocity correction at impacts (the paper's "
                                                      "scheme); false: position-level multipliers only")

    @field_validator("gamma")
    @classmethod
    def _gamma_at_least_half(cls, gamma):
        if gamma < 0.5:
            raise ValueError(f"must be >= 0.5 (below, Newmark amplifies every mode), got {gamma:g}")
        return gamma


class _ReductionKeys(BaseModel):
    modes: Annotated[int | str, PlainValidator(_count_or_auto)] = Field(
        "auto", description="kept eigenmodes n1, or auto: the fewest whose neglected flexibility per contact "
                            "row is at most `tolerance`")
    static_correction: bool = Field(True, description="static compliance of the truncated modes at the "
                                                      "contact rows (Barauskas 1992)")
    tolerance: float = _number("-", "modes: auto: the largest neglected flexibility per contact row, as a "
                                    "fraction of the row's static flexibility", 0.01, gt=0, lt=1)
    blocks: Annotated[bool | str, PlainValidator(_flag_or_auto)] = Field(
        "auto", description="take the steps between contacts many at a time (the same results to round-off), "
                            "and the contact steps of compliant rows (the static correction's, an elastic "
                            "stop's: the same to 1e-10) with Moreau-Jean (Numba); auto: when the run has at "
                            "least 4000 steps (below, loading the compiled steps costs more than they save); "
                            "false: one at a time")

    def _written(self) -> set[str]:
        keys = super()._written()
        return keys if self.modes == "auto" else keys - {"tolerance"}   # (a count of modes takes none)

    @model_validator(mode="after")
    def _tolerance_needs_auto(self):
        if self.modes != "auto" and "tolerance" in self.model_fields_set:
            raise KeyProblem("tolerance", f"applies to modes: auto only; modes is {self.modes}: remove it")
        return self


class MoreauJeanParameters(_MoreauJeanKeys, SolverParameters):
    """``moreau_jean`` (default): Moreau-Jean time stepping, contact impulses at the end of each step.

    Unconditionally stable; the contacts never create energy, at any time step.
    """

    method: Literal["moreau_jean"] = "moreau_jean"
    takes_friction: ClassVar[bool] = True


class NewmarkParameters(_NewmarkKeys, SolverParameters):
    """``newmark``: the paper's scheme, Newmark with position-level multipliers and Carnot's correction.

    Its contact forces can create energy at large steps in persistent contact (docs/methods.md).
    """

    method: Literal["newmark"]


class CentralDifferenceParameters(SolverParameters):
    """``central_difference``: explicit, with the lumped mass by default; stable for c dt / h <= 1."""

    method: Literal["central_difference"]
    mass: Literal["consistent", "lumped"] = Field("lumped", description="mass matrix: lumped (no solve per "
                                                                        "step) or consistent")


@dataclass(frozen=True)
class Method:
    """A registered time-integration method."""

    name: str          # solver.method
    schema: type[SolverParameters]
    integrator: str | type   # the class, or "module:Class" (imported on first use: PETSc loads late)
    summary: str       # what it is, in a few words
    title: str         # its name in a sentence ("Moreau-Jean")
    reduced: bool      # may step the reduced model (``method: modal, scheme: NAME``)


_REGISTRY: dict[str, Method] = {}
# Views of the registry, updated in place by register() (modules import them once):
METHODS: dict[str, str] = {}                          # solver.method -> what it is (the single list)
SCHEMAS: dict[str, type[SolverParameters]] = {}       # the union's tags: NAME, modal/NAME
MODAL_SCHEMES: list[str] = []                          # the reduced model's time schemes
_adapter: list = []                                    # the union's validator, built on first use


def register(name: str, schema: type[SolverParameters], integrator: str | type, summary: str,
             title: str | None = None, reduced: bool = False) -> None:
    """Make ``name`` a ``solver.method``: ``schema`` validates its keys (a subclass of
    ``SolverParameters`` whose ``method`` is ``Literal[name]``), ``integrator`` steps it
    (``integrator.from_solver(operators, solver)``; ``start(U0, V0, t0)`` and ``step()`` return a
    ``StepState``). With ``reduced``, ``method: modal, scheme: name`` steps the reduced model."""
    if name == REDUCED:
        raise ValueError(f"'{REDUCED}' is the reduced model, not an integrator's name")
    _REGISTRY[name] = Method(name, schema, integrator, summary, title or name, reduced)
    _refresh()


def unregister(name: str) -> None:
    """Remove a method registered by :func:`register` (a test's, a plugin's)."""
    del _REGISTRY[name]
    _refresh()


def _refresh() -> None:
    """The registry's views, in place."""
    METHODS.clear()
    METHODS.update({m.name: m.summary for m in _REGISTRY.values()})
    METHODS[REDUCED] = "reduced model: kept modes plus the static correction"
    MODAL_SCHEMES[:] = [m.name for m in _REGISTRY.values() if m.reduced]
    SCHEMAS.clear()
    SCHEMAS.update({m.name: m.schema for m in _REGISTRY.values()})
    SCHEMAS.update({f"{REDUCED}/{m}": _reduced_schema(_REGISTRY[m]) for m in MODAL_SCHEMES})
    _adapter.clear()


def _reduced_schema(method: Method) -> type[SolverParameters]:
    """``modal`` with ``scheme: NAME``: the reduction's keys and the method's."""
    default = " (default)" if method.name == MODAL_SCHEMES[0] else ""
    return create_model(
        f"Modal{method.schema.__name__}", __base__=(_ReductionKeys, method.schema),
        __doc__=f"``{REDUCED}`` with ``scheme: {method.name}``{default}: the reduced model stepped by {method.title}.",
        method=(Literal[REDUCED], ...),
        scheme=(Literal[method.name], method.name if default else ...),
        mass=(Literal["consistent", "lumped"], Field("consistent", description="mass matrix of the modes")))


def integrator_class(name: str) -> type:
    """The integrator of a registered method (a time scheme: for the reduced model, its ``scheme``)."""
    integrator = _REGISTRY[name].integrator
    if isinstance(integrator, str):
        import importlib

        module, _, cls = integrator.partition(":")
        integrator = getattr(importlib.import_module(module), cls)
    return integrator


def is_reduced(solver) -> bool:
    """Whether a validated ``solver`` section asks for the reduced model."""
    return solver.method == REDUCED


def scheme_of(solver) -> str:
    """The time scheme of a validated ``solver`` section (the reduced model's: its ``scheme``)."""
    return solver.scheme if is_reduced(solver) else solver.method


def steps_for(duration: float, dt: float) -> int:
    """Number of steps of size dt that cover ``duration`` (tolerant of round-off in t_end/dt; a ratio
    beyond 1e300 counts as 10**300 steps rather than overflowing)."""
    ratio = duration / dt
    return max(1, math.ceil(ratio - 1e-9)) if ratio < 1e300 else 10**300


def tag(data) -> str | None:
    """The schema of a ``solver`` mapping: its method, and for ``modal`` its scheme."""
    if not isinstance(data, dict):
        return None
    method = data.get("method") if data.get("method") is not None else DEFAULT_METHOD
    if method == REDUCED:
        scheme = data.get("scheme") if data.get("scheme") is not None else MODAL_SCHEMES[0]
        return f"{REDUCED}/{scheme}" if isinstance(scheme, str) else None
    return method if isinstance(method, str) else None


def solver_schema() -> TypeAdapter:
    """The union of every registered method's schema, discriminated by :func:`tag`."""
    if not _adapter:
        union = Union[tuple(Annotated[schema, Tag(name)] for name, schema in SCHEMAS.items())]
        _adapter.append(TypeAdapter(Annotated[union, Discriminator(tag)]))
    return _adapter[0]


def valid_keys(schema: type[BaseModel]) -> list[str]:
    """The keys a schema takes, in declaration order (method first)."""
    keys = list(schema.model_fields)
    keys.remove("method")
    return ["method", *(["scheme"] if "scheme" in keys else []), *(k for k in keys if k != "scheme")]


def describe(schema: type[BaseModel]) -> str:
    """A method's keys as text: ``name (unit, default): meaning``, one per line (for --help and docs)."""
    lines = []
    for name in valid_keys(schema):
        info = schema.model_fields[name]
        unit = (info.json_schema_extra or {}).get("unit") if isinstance(info.json_schema_extra, dict) else None
        default = "required" if info.is_required() else f"default {info.default!r}"
        lines.append(f"{name} ({', '.join(filter(None, [unit, default]))}): {info.description or ''}".rstrip(": "))
    return "\n".join(lines)


def help_text(width: int = 100) -> str:
    """Every method's keys (``fem-impact run --help``): each method's first docstring line, then its keys."""
    import textwrap

    parts = []
    for name, schema in SCHEMAS.items():
        method, _, scheme = name.partition("/")
        title = f"method: {method}" + (f", scheme: {scheme}" if scheme else "")
        summary = (schema.__doc__ or "").strip().splitlines()[0].replace("``", "")
        lines = [f"  {title}", *textwrap.wrap(summary, width, initial_indent="    ", subsequent_indent="    ")]
        for line in describe(schema).splitlines():
            if not line.startswith(("method ", "scheme ")):   # (the title says them)
                lines += textwrap.wrap(line.replace("`", ""), width, initial_indent="      ",
                                       subsequent_indent="        ")
        parts.append("\n".join(lines))
    return "solver keys of each method (any other is refused):\n" + "\n".join(parts) + "\n"


register("moreau_jean", MoreauJeanParameters, "fem_impact.integrators.moreau_jean:MoreauJean",
         "Moreau-Jean (full model)", "Moreau-Jean", reduced=True)
register("newmark", NewmarkParameters, "fem_impact.integrators.newmark:Newmark",
         "Newmark, the paper's scheme (full model)", "the paper's Newmark scheme", reduced=True)
register("central_difference", CentralDifferenceParameters, "fem_impact.integrators.central_difference:"
         "CentralDifference", "explicit central difference (full model)", "central difference")
