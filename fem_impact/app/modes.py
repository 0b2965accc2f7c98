"""The ``fem-impact modes`` command: case file -> modes.csv, modes.pvd (one frame per mode)."""

from __future__ import annotations

import csv
import time
from pathlib import Path

from mpi4py import MPI

from ..errors import ModelInputError
from .outdir import case_inputs, claim, install_signal_handlers, writing

DEFAULT_COUNT = 10


def default_outdir(case) -> Path:
    return Path.cwd() / "results" / f"{case.name}-modes"


def run_modes(path, outdir=None, overrides=(), n: int | None = None, comm: MPI.Comm = MPI.COMM_WORLD) -> dict:
    """Modal analysis of a case file, written atomically into ``outdir``.

    ``n`` is the number of modes; None takes ``solver.modes`` of the case when it is a
    number, else :data:`DEFAULT_COUNT` (at most the free dofs less one). An explicit ``n``
    that does not fit the model raises :class:`ModeCountError`; a bad ``solver.modes``, a
    ``CaseError``. Returns a summary with the table (``columns``, ``rows``).
    """
    from ..config.case import load_case

    t_start = time.perf_counter()
    case = load_case(path, overrides)
    outdir = Path(outdir) if outdir is not None else default_outdir(case)
    with claim(outdir, comm, "modes", protect=case_inputs(case), source=case.path) as out, case.errors_at_keys():
        return _run_modes(case, out, n, comm, t_start)


def _run_modes(case, out, n, comm, t_start) -> dict:
    from ..config.build import model_spec
    from ..fem.dolfinx_api import VTKSeries
    from ..fem.mesh import build_mesh
    from ..fem.model import build_model
    from ..fem.modes import AXES, ModeCountError, compute_modes, free_dof_count, participation

    outdir = out.path
    meshdata = build_mesh(case.mesh, comm)
    install_signal_handlers()   # (after PETSc's own)
    model = build_model(model_spec(case), meshdata)
    available = free_dof_count(model)
    if n is None:
        if isinstance(getattr(case.solver, "modes", None), int):   # (only the reduced model's solver has modes)
            n = case.solver.modes
            if n >= available:
                raise ModelInputError(("solver", "modes"), str(ModeCountError(n, available)))
        else:
            n = min(DEFAULT_COUNT, available - 1)
    modes = compute_modes(model, n)
    fractions = participation(modes, model)
    solve_time = time.perf_counter() - t_start

    columns = (["mode", "frequency_hz", "type"] + [f"mass_{AXES[d]}_percent" for d in range(model.bs)]
               + ["residual"])
    rows = [[i + 1, float(modes.frequency_hz[i]), "rigid" if modes.rigid[i] else "elastic",
             *(100.0 * fractions[i]).tolist(), float(modes.residual[i])] for i in range(n)]
    with out.staged() as stage:
        series = VTKSeries(comm, stage / "modes.pvd", model.V, ["mode"])
        try:
            for i in range(n):
                series.write(float(i + 1), {"mode": modes.Y_local[:, i]})
        finally:
            series.close()
            # dolfinx's VTKFile writes the .pvd once more when it is destroyed: let that
            # happen here, inside the staging folder, not after it was moved into place.
            del series
        if comm.rank == 0:
            with writing(stage / "modes.csv"), open(stage / "modes.csv", "w", newline="") as f:
                writer = csv.writer(f)
                writer.writerow(columns)
                for row in rows:
                    writer.writerow([f"{v:.10g}" if isinstance(v, float) else v for v in row])
            with writing(stage / "case.resolved.yaml"):
                case.write_resolved(stage / "case.resolved.yaml")
    return {
        "case": case.name, "dofs": model.dofs, "free_dofs": available, "modes": n, "rigid": modes.n_rigid,
        "dim": model.bs, "columns": columns, "rows": rows, "mass_total_percent": (100.0 * fractions.sum(0)).tolist(),
        "wall_time_s": time.perf_counter() - t_start, "solve_time_s": solve_time, "mpi_ranks": comm.size,
        "outdir": str(outdir.resolve()),
    }


def format_table(summary: dict) -> str:
    """The table printed by ``fem-impact modes``."""
    from ..fem.modes import AXES

    axes = AXES[: summary["dim"]]
    header = f"{'mode':>5}  {'frequency [Hz]':>15}  {'type':<7}" + "".join(f"  {'mass ' + a + ' [%]':>10}"
                                                                          for a in axes) + f"  {'residual':>9}"
    lines = [f"{summary['case']}: {summary['modes']} modes of {summary['dofs']} dofs "
             f"({summary['free_dofs']} free), {summary['rigid']} rigid-body", header]
    for mode, freq, kind, *rest in summary["rows"]:
        *mass, residual = rest
        lines.append(f"{mode:>5}  {freq:>15.8g}  {kind:<7}" + "".join(f"  {m:>10.3f}" for m in mass)
                     + f"  {residual:>9.2g}")
    lines.append(f"{'sum':>5}  {'':>15}  {'':<7}" + "".join(f"  {m:>10.3f}" for m in summary["mass_total_percent"]))
    lines.append(f"Effective mass: share of the free mass that each mode carries in a translation. "
                 f"Wall time {summary['wall_time_s']:.2f} s on {summary['mpi_ranks']} rank(s). "
                 f"Results in {summary['outdir']} (modes.csv, modes.pvd: mass-normalized shapes, "
                 f"frame t = mode number).")
    return "\n".join(lines)
