"""The numeric range of a case: every number the model squares and multiplies, and every scale the
built-in bar forms from them, within [SMALLEST, LARGEST] (checked on its key when a case is validated)."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:   # case.py calls check_numbers while it validates: no import back at run time
    from .case import Case

# The model squares and multiplies the case's numbers: energies (rho v^2, E u^2), the element matrices
# (rho V, E V / h^2), the step matrix M + dt C + dt^2 K, the contact problem's dt^2 / m. A number within
# [SMALLEST, LARGEST] has a square, and any product of two such numbers, within 1e-200 and 1e+200: a
# margin of 1e108 to the limits of the floats for the sums of assembly and the solvers' own products
# (norms, pivots, scalings: at 1e+150 the step matrix's factorization already gave NaN). The scales the
# model forms on the built-in bar are held to the same range. Far beyond any physical case in any units:
# a value outside is a typo or a probe, refused on its key before anything is built.

SMALLEST, LARGEST = 1e-100, 1e100
_WHY = "the model squares these values and multiplies them together: beyond, floats overflow or lose all precision"


def divisions(case: Case) -> tuple[int, ...]:
    """Cells of the built-in bar along its length, height and width (as fem_impact.mesh divides it)."""
    spec = case.mesh
    height, width = spec.bar_dimensions()
    across = [max(1, round(min(spec.cells * size / spec.length, 1e15))) for size in (height, width)]
    return (spec.cells, *across[: spec.bar_dim - 1])


def _dimensional(section: str) -> list[str]:
    """The keys of a section that are numbers with a unit (as its schema declares them)."""
    from .schema import SECTIONS

    return [name for name, info in SECTIONS[section].model_fields.items() if info.annotation is float
            and (info.json_schema_extra or {}).get("unit", "-") != "-"]


def _values(case: Case):
    """(key path, value) of every dimensional number of the case that is not 0."""
    materials = ({("material",): case.material} if case.material is not None
                 else {("materials", body): material for body, material in case.materials.items()})
    for prefix, material in materials.items():
        yield from ((prefix + (name,), getattr(material, name)) for name in _dimensional("material"))
    if case.mesh.file is None:
        yield from ((("mesh", name), getattr(case.mesh, name)) for name in _dimensional("mesh"))
    yield from ((("damping", name), getattr(case.damping, name)) for name in _dimensional("damping"))
    for index, contact in enumerate(case.contacts):
        yield from ((("contacts", index, name), getattr(contact, name)) for name in ("gap", "stiffness", "friction"))
        # A registered law's own numbers (those the contact does not hold under the same name already)
        yield from ((("contacts", index, name), value) for name, value in contact.law_keys.items()
                    if isinstance(value, float) and getattr(contact, name, None) is None)
        yield from ((("contacts", index, "point", k), x) for k, x in enumerate(contact.point or []))
    yield from ((("solver", name), getattr(case.solver, name)) for name in ("dt", "t_end"))
    # A method's own coefficients (Newmark's beta and gamma, Moreau-Jean's theta): a subnormal beta
    # makes the contact problem's matrix beta dt^2 P S^-1 P^T zero.
    yield from ((("solver", name), getattr(case.solver, name)) for name in ("beta", "gamma", "theta")
                if isinstance(getattr(case.solver, name, None), float))


@dataclass
class _Scale:
    """A product of powers of the case's numbers: ``terms`` (key path or None, power, value)."""

    what: str
    terms: list
    lower: bool = True   # bounded below too (a matrix that is inverted), or only above (a term of a sum)

    def power(self, power: float) -> list:
        """The terms of this scale to the given power."""
        return [(key, p * power, value) for key, p, value in self.terms]

    @property
    def log10(self) -> float:
        return sum(p * math.log10(value) for _, p, value in self.terms)

    def culprit(self, high: bool) -> tuple:
        """The key that pushes the scale furthest beyond the range (the likeliest typo)."""
        share: dict = {}
        for key, p, value in self.terms:
            if key is not None:
                share[key] = share.get(key, 0.0) + p * math.log10(value)
        return (max if high else min)(share, key=share.get)


def _bar_scales(case: Case, prefix: tuple, material) -> list[_Scale]:
    """The scales the model forms on the built-in bar with one material (an element's size, mass, stiffness,
    and their terms in the step matrix and the contact problem)."""
    spec, dt = case.mesh, case.solver.dt
    length, cells = ("mesh", "length"), ("mesh", "cells")
    along = [(length, 1, spec.length), (cells, -1, spec.cells)]
    sizes = [_Scale("the mesh size h", along)]
    height, width = spec.bar_dimensions()
    for name, size, count in zip(("height", "width"), (height, width), divisions(case)[1:]):
        own = [(("mesh", name), 1, size)] if getattr(spec, name) is not None else [(length, 1, spec.length / 20)]
        if count > 1:   # then the size across is about the size along
            own = along + [(None, 1, size / count / (spec.length / spec.cells))]
        sizes.append(_Scale("the mesh size h", own))
    h = min(sizes, key=lambda scale: scale.log10)
    dim = spec.bar_dim
    volume = [term for scale in sizes for term in scale.terms] + ([(prefix + ("area",), 1, material.area)]
                                                                     if dim < 3 else [])
    nu = material.nu   # the modulus of a wave along the element: E, E/(1-nu^2) in plane stress, E(1-nu)/((1+nu)(1-2nu))
    modulus = {1: 1.0, 2: 1 / (1 - nu * nu), 3: (1 - nu) / ((1 + nu) * (1 - 2 * nu))}[dim]
    mass = _Scale("the element mass rho V", [(prefix + ("rho",), 1, material.rho), *volume])
    stiffness = _Scale("the element stiffness E V / h^2", [(prefix + ("E",), 1, material.E),
                                                          (prefix + ("nu",), 1, modulus), *volume, *h.power(-2)])
    step = [(("solver", "dt"), 2, dt)]
    scales = [h, mass, stiffness,
              _Scale("the stiffness term of the step matrix dt^2 k", step + stiffness.terms, lower=False),
              _Scale("the contact problem's scale dt^2 / m", step + mass.power(-1), lower=False)]
    if case.damping.alpha:
        scales.append(_Scale("the damping term of the step matrix alpha dt m", [
            (("damping", "alpha"), 1, case.damping.alpha), (("solver", "dt"), 1, dt), *mass.terms], lower=False))
    if case.damping.beta:
        scales.append(_Scale("the damping term of the step matrix beta dt k", [
            (("damping", "beta"), 1, case.damping.beta), (("solver", "dt"), 1, dt), *stiffness.terms], lower=False))
    for index, contact in enumerate(case.contacts):
        if contact.stiffness is not None:
            scales.append(_Scale(f"the term of contact '{contact.name}' in the step matrix stiffness dt^2",
                                 [(("contacts", index, "stiffness"), 1, contact.stiffness), *step], lower=False))
    return scales


def _about(log10: float) -> str:
    exponent = math.floor(log10)
    return f"{10 ** (log10 - exponent):.2g}e{exponent:+d}"


def check_numbers(case: Case) -> None:
    """Refuse (CaseError on its key) a number, or a scale the model forms from them, beyond [SMALLEST, LARGEST]."""
    for key, value in _values(case):
        if value and not SMALLEST <= abs(value) <= LARGEST:
            raise case.error(key, f"must be within {SMALLEST:g} and {LARGEST:g} in magnitude, got {value!r} ({_WHY}; "
                                  f"use other units)")
    if case.mesh.file is not None:   # (element sizes are the mesh file's: the solvers report what overflows)
        return
    # dolfinx's generator of the built-in bar takes a side shorter than the machine epsilon for zero
    height, width = case.mesh.bar_dimensions()
    for name, size in list(zip(("length", "height", "width"), (case.mesh.length, height, width)))[:case.mesh.bar_dim]:
        if size < sys.float_info.epsilon:
            key = ("mesh", name if getattr(case.mesh, name) is not None else "length")
            raise case.error(key, f"the built-in bar's {name} would be {size!r}, below {sys.float_info.epsilon:.3g} "
                                  "(the mesh generator takes it for zero): use other units")
    materials = ({("material",): case.material} if case.material is not None
                 else {("materials", body): material for body, material in case.materials.items()})
    for prefix, material in materials.items():
        for scale in _bar_scales(case, prefix, material):
            log10 = scale.log10
            high = log10 > math.log10(LARGEST)
            if high or (scale.lower and log10 < math.log10(SMALLEST)):
                key = scale.culprit(high)
                inputs = {**dict(_values(case)), ("mesh", "cells"): case.mesh.cells, prefix + ("nu",): material.nu}
                raise case.error(key, f"with this value ({inputs[key]!r}) {scale.what} would be about {_about(log10)}, "
                                      f"{'above' if high else 'below'} {LARGEST if high else SMALLEST:g}: the run's "
                                      f"matrices would {'overflow' if high else 'lose all precision'}; use other "
                                      f"units (every value, and every scale the model forms from them, must lie "
                                      f"within {SMALLEST:g} and {LARGEST:g})")


