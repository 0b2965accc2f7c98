"""The limits of a case: the numbers the floats can hold once the model multiplies them (checked when a case
is validated), and the size guard: a run's steps, memory and output estimated from the case before anything
is built, and refused as bad input beyond sane limits (unless ``--force``).

The figures per unknown come from runs of the built-in bar (docs/performance.md, the size guard); they
are meant to catch a mistyped exponent (``solver.dt=1e-12``, ``mesh.cells=1e9``), not to predict a
run's memory to the megabyte.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from ..config.case import Case
from ..config.numbers import divisions
from ..integrators.parameters import steps_for

MAX_STEPS = 10**8
MAX_FRAMES = 10**5           # VTK frames: one .vtu per rank each, plus a .pvtu under MPI
# Peak memory of a run beyond the interpreter and libraries (BASE_MEMORY), per unknown: matrices,
# the factorization and the work vectors, each a little above docs/performance.md's size-guard table.
BASE_MEMORY = 200e6          # Python, dolfinx, PETSc and a small model
BYTES_PER_DOF = {1: 1.5e3, 2: 5.0e3, 3: 1.5e4}   # (3D: the LU fill grows)
HISTORY_BYTES_PER_VALUE = 20   # "%.17g" and a comma
VTK_BYTES_PER_NODE = {1: 140, 2: 250, 3: 400}   # per frame: fields, geometry, cells
# A checkpoint (every run saves one at its end): its state vectors per unknown (the full model's; the reduced
# one needs less), plus HDF5's and state.json's bytes per rank file; two at once while the next one is written.
CHECKPOINT_BYTES_PER_DOF = 130
CHECKPOINT_BYTES_PER_RANK = 60e3


@dataclass
class Estimate:
    steps: int
    nodes: int
    dofs: int
    memory: float      # bytes
    history: float     # bytes of history.csv
    frames: int
    vtk: float         # bytes of the VTK series
    checkpoints: float = 0.0   # bytes of the checkpoints on disk at once

    @property
    def output(self) -> float:
        return self.history + self.vtk + self.checkpoints


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
    checkpoints = 2.0 * (CHECKPOINT_BYTES_PER_DOF * float(dofs) + CHECKPOINT_BYTES_PER_RANK * ranks)
    return Estimate(steps, nodes, dofs, memory, history, frames, vtk, checkpoints)


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
        est = dataclasses.replace(est, memory=est.memory + est.history, frames=0, vtk=0.0, checkpoints=0.0)
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
        key = max([(est.vtk, ("output", "every")), (est.history, ("solver", "dt")), (est.checkpoints, key)])[1]
        raise case.error(key, f"the run would write about {_size(est.output)} (history {_size(est.history)}, VTK "
                              f"{_size(est.vtk)}, checkpoints {_size(est.checkpoints)}), more than the "
                              f"{_size(disk)} free on the disk{FORCE}")
    return est
