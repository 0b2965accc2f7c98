"""fem-impact: dynamics of elastic structures with unilateral constraints (impacts), on FEniCSx.

The Python API (the command ``fem-impact`` is a thin layer over it)::

    import fem_impact

    case = fem_impact.load_case("cases/impacting_bar.yaml")          # or Case.from_dict({...})
    result = fem_impact.run(case.with_changes({"solver.dt": 1e-3}))  # nothing written to disk
    result.history["wall.force"], result.summary["max_penetration"]

- :func:`load_case`, :meth:`Case.from_dict`, :meth:`Case.with_changes`: validated cases;
- :func:`run` -> :class:`Result` (``summary``, ``history``, ``outdir``);
- :class:`FemImpactError`, the base of :class:`CaseError` (bad input, names the key) and
  :class:`SimulationError` (a run that cannot go on); an argument of a wrong Python type is a
  TypeError that says what the function takes. Nothing else escapes.
"""

import os as _os

from . import mpi_start as _mpi_start
from ._version import __version__

from .errors import CaseError, FemImpactError, SimulationError

# PETSc's own handler answers SIGTERM, SIGHUP and SIGQUIT with MPI_Abort: no cleanup, a staging folder and
# a lock left, and a process that may wait for ever. A run's handlers (app/outdir/interruption.py) answer them instead,
# also in the second while PETSc has started and they are not installed again yet.
if "-no_signal_handler" not in _os.environ.get("PETSC_OPTIONS", "").split():
    _os.environ["PETSC_OPTIONS"] = (_os.environ.get("PETSC_OPTIONS", "") + " -no_signal_handler").strip()
_mpi_start.own_session()   # (a process started by one of fem-impact's, with its settings for one process)

__all__ = ["Case", "CaseError", "FemImpactError", "Result", "SimulationError", "__version__", "load_case", "run"]


def __getattr__(name):
    # Imported on first use, so that `import fem_impact` stays light: run and Result need MPI, and the case
    # format numpy and YAML (the command line installs its signal handlers before any of them loads).
    if name in ("run", "Result"):
        from .app import pipeline

        return getattr(pipeline, name)
    if name in ("Case", "load_case"):
        from .config import case

        return getattr(case, name)
    raise AttributeError(f"module 'fem_impact' has no attribute {name!r}")
