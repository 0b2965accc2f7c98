"""Studies that run a case several times: the reduction table (modes with and without the
static correction against the project's own full model)."""

from __future__ import annotations

import csv
import logging
import re
from pathlib import Path

import numpy as np
from mpi4py import MPI

from ...errors import CaseError
from ...integrators.parameters import MODAL_SCHEMES, REDUCED
from ..outdir.policy import case_inputs
from ..outdir.writes import writing
from ..pipeline import run, staged_directory
from ..plots import history_columns, plot_reduction

log = logging.getLogger(__name__)

REDUCTION_COLUMNS = ("model", "modes", "static_correction", "cutoff_hz", "displacement_error", "velocity_error",
                     "displacement_error_band", "velocity_error_band", "displacement_error_max",
                     "velocity_error_max", "displacement_error_peak", "velocity_error_peak", "impulse_error",
                     "wall_time_s", "loop_time_s", "neglected_flexibility")


def relative_l2(a: np.ndarray, b: np.ndarray) -> float:
    """``||a - b|| / ||b||`` over the time samples (the RMS difference against the RMS of b)."""
    scale = np.sqrt(np.mean(b**2))
    return float(np.sqrt(np.mean((a - b) ** 2)) / scale) if scale > 0 else 0.0


def low_pass(signal: np.ndarray, dt: float, cutoff_hz: float) -> np.ndarray:
    """The part of a history below ``cutoff_hz``: a zero-phase 4th-order Butterworth filter.

    Compares what a reduced model claims to represent (its kept modes' band) apart from the
    content above it, which it leaves out by construction.
    """
    from scipy.signal import butter, sosfiltfilt

    nyquist = 0.5 / dt
    if not cutoff_hz or cutoff_hz >= 0.99 * nyquist or signal.size < 30:
        return signal
    return sosfiltfilt(butter(4, cutoff_hz, fs=1.0 / dt, output="sos"), signal)


def peak_error(a: np.ndarray, b: np.ndarray) -> float:
    """``| max|a| - max|b| | / max|b|``: the error of a history's extreme value, wherever it falls."""
    scale = np.abs(b).max()
    return float(abs(np.abs(a).max() - scale) / scale) if scale > 0 else 0.0


def _probe_component(history: dict, probe: str | None) -> str:
    """The displacement column of the probe that moves most (the first probe by default)."""
    names = [c for c in history if re.fullmatch(r"[^.]+\.u[xyz]", c)]
    wanted = probe if probe is not None else (names[0].split(".")[0] if names else None)
    names = [c for c in names if c.split(".")[0] == wanted]
    if not names:
        raise ValueError(f"the case has no probe {probe or ''} to compare (add one under output.probes)")
    return max(names, key=lambda c: np.abs(history[c]).max())


def reduction_table(case, modes=(2, 5, 10, 20), outdir=None, probe=None, comm: MPI.Comm = MPI.COMM_WORLD) -> list[dict]:
    """Run the full model and the modal model for each n1, with and without static correction (without:
    where the case allows it; a moving support needs the static correction, and a warning says so).

    ``case`` is a :class:`~fem_impact.config.case.Case`; every run is a copy of it with changes (VTK off;
    the modal method, its scheme, n1 and the static correction), run by :func:`fem_impact.run`.
    Errors against the full model, for a probe's displacement and velocity (the component that
    moves most): the relative L2 norm over the run (RMS of the difference over the RMS of the
    full model's history), the same for both histories filtered below the reduced model's
    cut-off frequency (``_band``: the error in what the kept modes represent), and the max norm
    relative to the full model's maximum (``_max``), the error of the extreme value (largest
    magnitude) of the band-limited history (``_peak``: what a reference that tests a history's
    peak value measures, e.g. B3's); and the error of the total contact impulse. Writes
    ``reduction.csv``, ``reduction.png`` (the histories) and every run's folder into ``outdir``.
    """
    stem = Path(case.path).stem if case.path is not None else case.name
    outdir = Path(outdir or Path.cwd() / "results" / f"{stem}-reduction")
    rows = []
    with staged_directory(outdir, comm, "reduction", protect=case_inputs(case)) as stage:
        full_case = case.with_changes({"output.vtk": False})
        full_summary = run(full_case, stage / "full", comm=comm).summary
        full = history_columns(stage / "full")
        u_col = _probe_component(full, probe)
        v_col = u_col.replace(".u", ".v")
        impulse_cols = [c for c in full if c.endswith(".impulse")]
        impulse_full = sum(full[c].sum() for c in impulse_cols)
        dt = float(full["t"][1] - full["t"][0])
        rows.append(_row("full", None, None, dict.fromkeys(REDUCTION_COLUMNS[4:13], 0.0), full_summary))
        histories = {"full": full}
        # The reduced model steps with the full model's scheme, so that the table measures the reduction alone.
        scheme = {"solver.scheme": full_summary["method"]} if full_summary["method"] in MODAL_SCHEMES else {}
        for n1 in modes:
            for static in (True, False):
                name = f"modal-{n1}-{'static' if static else 'plain'}"
                try:
                    reduced = full_case.with_changes({"solver.method": REDUCED, **scheme, "solver.modes": n1,
                                                      "solver.static_correction": static})
                except CaseError as err:
                    if static:
                        raise
                    # (a case the plain truncation refuses, e.g. a moving support: the study goes on without it)
                    log.warning("%s: not run: %s", name, err.message)
                    continue
                summary = run(reduced, stage / name, comm=comm).summary
                h = history_columns(stage / name)
                histories[f"{n1} modes, {'static correction' if static else 'plain'}"] = h
                cut = summary["cutoff_hz"]
                errors = {}
                for what, col in (("displacement", u_col), ("velocity", v_col)):
                    reduced_band, full_band = low_pass(h[col], dt, cut), low_pass(full[col], dt, cut)
                    errors[f"{what}_error"] = relative_l2(h[col], full[col])
                    errors[f"{what}_error_band"] = relative_l2(reduced_band, full_band)
                    errors[f"{what}_error_max"] = float(np.abs(h[col] - full[col]).max() / np.abs(full[col]).max())
                    errors[f"{what}_error_peak"] = peak_error(reduced_band, full_band)
                errors["impulse_error"] = abs(sum(h[c].sum() for c in impulse_cols) - impulse_full) / abs(impulse_full)
                rows.append(_row(REDUCED, n1, static, errors, summary))
                log.info("%s: %s", name, rows[-1])
        if comm.rank == 0:
            with writing(stage / "reduction.png"):
                plot_reduction(histories, u_col, stage / "reduction.png",
                               f"{stem}: reduced models against the full one")
            with writing(stage / "reduction.csv"), open(stage / "reduction.csv", "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=REDUCTION_COLUMNS)
                writer.writeheader()
                writer.writerows(rows)
    return rows


def _row(model, n1, static, errors: dict, summary) -> dict:
    neglected = summary.get("neglected_flexibility") or {}
    return {"model": model, "modes": n1, "static_correction": static, "cutoff_hz": summary.get("cutoff_hz"),
            **errors, "wall_time_s": summary["wall_time_s"], "loop_time_s": summary["loop_time_s"],
            "neglected_flexibility": max(neglected.values()) if neglected else None}


def format_reduction(rows: list[dict]) -> str:
    lines = [f"{'model':<7}{'modes':>6}{'static':>7}{'cut-off Hz':>11}{'disp L2':>9}{'vel L2':>9}{'disp band':>10}"
             f"{'vel band':>10}{'disp max':>10}{'vel max':>9}{'disp peak':>10}{'vel peak':>9}{'impulse':>9}"
             f"{'wall s':>8}{'loop s':>8}"
             f"{'neglected':>10}"]
    for r in rows:
        flex = f"{r['neglected_flexibility']:.3g}" if r["neglected_flexibility"] is not None else "-"
        cut = f"{r['cutoff_hz']:.4g}" if r["cutoff_hz"] else "-"
        pct = [f"{100 * r[k]:.2f}%" for k in REDUCTION_COLUMNS[4:13]]
        lines.append(
            f"{r['model']:<7}{r['modes'] if r['modes'] else '-':>6}"
            f"{({True: 'yes', False: 'no'}.get(r['static_correction'], '-')):>7}{cut:>11}"
            f"{pct[0]:>9}{pct[1]:>9}{pct[2]:>10}{pct[3]:>10}{pct[4]:>10}{pct[5]:>9}{pct[6]:>10}{pct[7]:>9}{pct[8]:>9}"
            f"{r['wall_time_s']:>8.2f}{r['loop_time_s']:>8.2f}{flex:>10}"
        )
    lines.append("errors of the reduced model against the full one: probe displacement and velocity in the relative "
                 "L2 norm over the run (L2), the same below the\nkept modes' cut-off frequency (band), the max norm "
                 "relative to the full model's max (max), the error of the band-limited history's extreme value "
                 "(peak);\ntotal contact impulse. neglected = (P S_k P^T)_jj / ((P K^-1 P^T)_jj + the stop's "
                 "compliance), largest row.")
    return "\n".join(lines)
