"""The ``fem-impact modes`` command: case file -> modes.csv, modes.pvd (one frame per mode)."""

from __future__ import annotations

import csv
import time
from pathlib import Path

from mpi4py import MPI

from ..errors import ModelInputError
from .outdir.claim import claim
from .outdir.interruption import install_signal_handlers
from .outdir.policy import case_inputs
from .outdir.writes import writing

DEFAULT_COUNT = 10


def default_outdir(case) -> Path:
    return Path.cwd() / "results" / f"{case.name}-modes"


def run_modes(path, outdir=None, overrides=(), n: int | None = None, comm: MPI.Comm = MPI.COMM_WORLD,
              at: str | None = None, direction: str = "x") -> dict:
    """Modal analysis of a case file, written atomically into ``outdir``.

    ``n`` is the number of modes; None takes ``solver.modes`` of the case when it is a
    number, else :data:`DEFAULT_COUNT` (at most the free dofs less one). An explicit ``n``
    that does not fit the model raises :class:`ModeCountError`; a bad ``solver.modes``, a
    ``CaseError``. ``at`` (a node group) and ``direction`` (x, y or z) add each mode's modal
    mass and stiffness there and its participation factor along that direction
    (:func:`fem_impact.fem.modes.at_point`). Returns a summary with the table (``columns``, ``rows``).
    """
    from ..config.case import load_case

    t_start = time.perf_counter()
    case = load_case(path, overrides)
    outdir = Path(outdir) if outdir is not None else default_outdir(case)
    with claim(outdir, comm, "modes", protect=case_inputs(case), source=case.path) as out, case.errors_at_keys():
        return _run_modes(case, out, n, comm, t_start, at, direction)


def _run_modes(case, out, n, comm, t_start, at=None, direction="x") -> dict:
    from ..build import finite_element_model
    from ..fem.dolfinx_api import VTKSeries
    from ..fem.modes import AXES, ModeCountError, at_point, compute_modes, describe, free_dof_count, participation

    outdir = out.path
    install_signal_handlers()   # (after PETSc's own: dolfinx_api loaded it)
    model = finite_element_model(case, comm)
    available = free_dof_count(model)
    if n is None:
        if isinstance(getattr(case.solver, "modes", None), int):   # (only the reduced model's solver has modes)
            n = case.solver.modes
            if n >= available:
                raise ModelInputError(("solver", "modes"), str(ModeCountError(n, available)))
        else:
            n = min(DEFAULT_COUNT, available - 1)
    if at is not None:
        d = AXES.index(direction)
        if d >= model.bs:
            raise ModelInputError(("--direction",), f"{direction}: the model is {model.bs}D (directions: "
                                                     f"{', '.join(AXES[:model.bs])})")
        model.node_set(at, ("--at",))   # (an unknown group: a clear error before the eigensolve)
    modes = compute_modes(model, n)
    translations = translation_axes(case, model.bs)
    fractions = participation(modes, model)[:, translations]
    described = describe(modes, model)
    point = at_point(modes, model, at, AXES.index(direction)) if at is not None else None
    solve_time = time.perf_counter() - t_start

    columns = (["mode", "frequency_hz", "type"] + [f"mass_{AXES[d]}_percent" for d in translations]
               + ["residual", "moves"])
    point_keys = ("mass", "stiffness", "phi", "participation")
    if point is not None:
        columns += [f"{at}.{direction}.modal_mass", f"{at}.{direction}.modal_stiffness", f"{at}.{direction}.shape"]
        if AXES.index(direction) in translations:   # (Gamma is a translation's participation)
            columns.append(f"participation_{direction}")
        else:
            point_keys = point_keys[:3]
    rows = [[i + 1, float(modes.frequency_hz[i]), "rigid" if modes.rigid[i] else "elastic",
             *(100.0 * fractions[i]).tolist(), float(modes.residual[i]), described[i]]
            + ([float(point[k][i]) for k in point_keys] if point else [])
            for i in range(n)]
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
        "at": at, "direction": direction if at is not None else None,
        "case": case.name, "dofs": model.dofs, "free_dofs": available, "modes": n, "rigid": modes.n_rigid,
        "dim": model.bs, "columns": columns, "rows": rows, "mass_total_percent": (100.0 * fractions.sum(0)).tolist(),
        "mass_axes": [AXES[d] for d in translations], "axisymmetric": case.mesh.hypothesis == "axisymmetric",
        "wall_time_s": time.perf_counter() - t_start, "solve_time_s": solve_time, "mpi_ranks": comm.size,
        "outdir": str(outdir.resolve()),
    }


def translation_axes(case, dim: int) -> list[int]:
    """The directions in which the model can translate, those of the effective masses: every axis, but an
    axisymmetric model's axis alone (a uniform radial displacement is a ring's expansion, no translation)."""
    if case.mesh.hypothesis == "axisymmetric":
        return [0 if case.mesh.axis == "x" else 1]
    return list(range(dim))


def format_table(summary: dict) -> str:
    """The table printed by ``fem-impact modes``."""
    from ..fem.modes import AXES

    axes = summary.get("mass_axes", AXES[: summary["dim"]])
    header = f"{'mode':>5}  {'frequency [Hz]':>15}  {'type':<7}" + "".join(f"  {'mass ' + a + ' [%]':>10}"
                                                                          for a in axes) + f"  {'residual':>9}"
    at = summary.get("at")
    if at:
        header += f"  {'modal mass':>11}  {'stiffness':>11}  {'Gamma':>10}"
    header += "  moves (kinetic energy)"
    lines = [f"{summary['case']}: {summary['modes']} modes of {summary['dofs']} dofs "
             f"({summary['free_dofs']} free), {summary['rigid']} rigid-body", header]
    for row in summary["rows"]:
        mode, freq, kind = row[:3]
        mass, (residual, moves) = row[3:3 + len(axes)], row[3 + len(axes):5 + len(axes)]
        line = f"{mode:>5}  {freq:>15.8g}  {kind:<7}" + "".join(f"  {m:>10.3f}" for m in mass) + f"  {residual:>9.2g}"
        if at:
            modal_mass, stiffness, _, *gamma = row[5 + len(axes):]
            line += f"  {modal_mass:>11.5g}  {stiffness:>11.5g}  " + (f"{gamma[0]:>10.4g}" if gamma else f"{'-':>10}")
        lines.append(line + f"  {moves}")
    lines.append(f"{'sum':>5}  {'':>15}  {'':<7}" + "".join(f"  {m:>10.3f}" for m in summary["mass_total_percent"]))
    if at:
        gamma = (f"Gamma = y^T M r, the participation factor along {summary['direction']}."
                 if summary["direction"] in axes else
                 f"no Gamma: {summary['direction']} is the radius, along which an axisymmetric model does not "
                 "translate.")
        lines.append(f"Modal mass and stiffness at {at} along {summary['direction']}: 1 / phi^2 and w^2 / phi^2, phi "
                     f"the mass-normalized mode's mean displacement there (units of the case: mass, force/length); "
                     + gamma)
    radial = [a for a in AXES[: summary["dim"]] if a not in axes]
    lines.append("Effective mass: share of the free mass that each mode carries in a translation"
                 + (f" (along the axis {axes[0]} only: axisymmetric, a uniform {radial[0]} displacement is a "
                    "ring's expansion, no translation)" if summary.get("axisymmetric") and radial else "") + ". "
                 f"Wall time {summary['wall_time_s']:.2f} s on {summary['mpi_ranks']} rank(s). "
                 f"Results in {summary['outdir']} (modes.csv, modes.pvd: mass-normalized shapes, "
                 f"frame t = mode number).")
    return "\n".join(lines)
