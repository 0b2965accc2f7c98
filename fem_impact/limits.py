"""The limits of a case: the numbers the floats can hold once the model multiplies them (checked when a case
is validated), and the size guard: a run's steps, memory and output estimated from the case before anything
is built, and refused as bad input beyond sane limits (unless ``--force``).

The figures per unknown were measured on the built-in bar (README, "Running cases"); they are
meant to catch a mistyped exponent (``solver.dt=1e-12``, ``mesh.cells=1e9``), not to predict a
run's memory to the megabyte.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from .integrators.parameters import steps_for

if TYPE_CHECKING:   # case.py calls check_numbers while it validates: no import back at run time
    from .case import Case

MAX_STEPS = 10**8
MAX_FRAMES = 10**5           # VTK frames: one .vtu per rank each, plus a .pvtu under MPI
# Peak memory of a run beyond the interpreter and libraries (BASE_MEMORY), per unknown: matrices,
# the factorization and the work vectors (measured: see the README's table of the size guard).
BASE_MEMORY = 200e6          # measured 150-180 MB: Python, dolfinx, PETSc and a small model
BYTES_PER_DOF = {1: 1.5e3, 2: 5.0e3, 3: 1.5e4}   # measured 1.2, 4.5 and 10 kB (3D: the LU fill grows)
HISTORY_BYTES_PER_VALUE = 20   # "%.17g" and a comma
VTK_BYTES_PER_NODE = {1: 140, 2: 250, 3: 400}   # per frame (measured 133, 239, 382): fields, geometry, cells


@dataclass
class Estimate:
    steps: int
    nodes: int
    dofs: int
    memory: float      # bytes
    history: float     # bytes of history.csv
    frames: int
    vtk: float         # bytes of the VTK series

    @property
    def output(self) -> float:
        return self.history + self.vtk


# --- numeric limits ----------------------------------------------------------------------------
#
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


def _values(case: Case):
    """(key path, value) of every dimensional number of the case that is not 0."""
    materials = ({("material",): case.material} if case.material is not None
                 else {("materials", body): material for body, material in case.materials.items()})
    for prefix, material in materials.items():
        yield from ((prefix + (name,), getattr(material, name)) for name in ("E", "rho", "area"))
    if case.mesh.file is None:
        yield from ((("mesh", name), getattr(case.mesh, name)) for name in ("length", "height", "width"))
    yield from ((("damping", name), getattr(case.damping, name)) for name in ("alpha", "beta"))
    for index, contact in enumerate(case.contacts):
        yield from ((("contacts", index, name), getattr(contact, name)) for name in ("gap", "stiffness"))
    yield from ((("solver", name), getattr(case.solver, name)) for name in ("dt", "t_end"))


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


def _nodes(case: Case) -> tuple[int, int]:
    """(nodes, dimension) of the mesh the case asks for; a mesh file's from its size."""
    spec = case.mesh
    if spec.file is not None:
        dim = spec.dim or 3
        try:
            size = Path(spec.file).stat().st_size
        except OSError:
            size = 0
        return max(1, size // 60), dim   # an ASCII .msh holds about 60 bytes per node and its cells
    return math.prod([n + 1 for n in divisions(case)]), spec.bar_dim


def estimate(case: Case, ranks: int = 1) -> Estimate:
    """What the run would take, from the case alone (before the mesh is built)."""
    solver = case.solver
    steps = steps_for(solver.t_end, solver.dt)
    nodes, dim = _nodes(case)
    nodes = min(nodes, 10**300)   # (a mistyped cells: 1e400 must not overflow the floats below)
    dofs = nodes * dim
    memory = BASE_MEMORY * ranks + BYTES_PER_DOF[dim] * float(dofs)
    columns = 1 + 3 * len(case.contacts) + 2 * dim * len(case.output.probes) + 7 + dim * max(
        1, len(case.materials or {}))
    history = (float(steps) + 1) * columns * HISTORY_BYTES_PER_VALUE
    frames = steps // case.output.every + 2 if case.output.vtk else 0
    vtk = float(frames) * (float(nodes) * VTK_BYTES_PER_NODE[dim] + 2000 * ranks)
    return Estimate(steps, nodes, dofs, memory, history, frames, vtk)


def available_memory() -> float:
    """MemAvailable of /proc/meminfo (bytes), else the physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))


def free_disk(folder: Path) -> float:
    p = Path(folder)
    while not p.exists():
        p = p.parent
    return float(shutil.disk_usage(p).free)


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"


FORCE = "; pass --force to run it anyway"


def check_limits(case: Case, outdir: Path | None, comm, force: bool = False) -> Estimate:
    """Refuse (CaseError on the key to change) a run beyond the limits; returns the estimate.

    ``outdir`` None: a run that writes nothing (its history is held in memory).
    """
    est = estimate(case, comm.size)
    if force:
        return est
    if est.steps > MAX_STEPS:
        raise case.error(("solver", "dt"), f"the run would take {est.steps:.3g} steps (t_end / dt = "
                                           f"{case.solver.t_end:g} / {case.solver.dt:g}), more than the limit "
                                           f"{MAX_STEPS:.0e}{FORCE}")
    key = ("mesh", "file") if case.mesh.file is not None else ("mesh", "cells")
    memory = available_memory()
    if outdir is None:   # a run that writes nothing keeps its history in memory, and writes no frame
        est = dataclasses.replace(est, memory=est.memory + est.history, frames=0, vtk=0.0)
    if est.memory > memory:
        raise case.error(key, f"the run would need about {_size(est.memory)} of memory ({est.dofs:.3g} unknowns), "
                              f"more than the {_size(memory)} available{FORCE}")
    if est.frames > MAX_FRAMES:
        raise case.error(("output", "every"), f"the run would write {est.frames:.3g} VTK frames ({est.steps:.3g} "
                                              f"steps, a frame every {case.output.every}), more than the limit "
                                              f"{MAX_FRAMES:.0e}: raise output.every or set output.vtk: false"
                                              f"{FORCE}")
    disk = free_disk(outdir.parent) if outdir is not None else math.inf
    if est.output > disk:
        raise case.error(("output", "every") if est.vtk > est.history else ("solver", "dt"),
                         f"the run would write about {_size(est.output)} (history {_size(est.history)}, VTK "
                         f"{_size(est.vtk)}), more than the {_size(disk)} free on the disk{FORCE}")
    return est
