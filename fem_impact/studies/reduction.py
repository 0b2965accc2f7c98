"""Studies that run a case several times: the reduction table (modes with and without the
static correction against the project's own full model)."""

from __future__ import annotations

import csv
import logging
import re
from pathlib import Path

import numpy as np
from mpi4py import MPI

from ..plots import read_history
from ..run import run_case, staged_directory

log = logging.getLogger(__name__)

REDUCTION_COLUMNS = ("model", "modes", "static_correction", "displacement_error", "velocity_error",
                     "impulse_error", "wall_time_s", "loop_time_s", "neglected_flexibility")


def _history(outdir: Path) -> dict[str, np.ndarray]:
    columns, data = read_history(outdir / "history.csv")
    return {name: data[:, i] for i, name in enumerate(columns)}


def _probe_component(history: dict, probe: str | None) -> str:
    """The displacement column of the probe that moves most (the first probe by default)."""
    names = [c for c in history if re.fullmatch(r"[^.]+\.u[xyz]", c)]
    wanted = probe if probe is not None else (names[0].split(".")[0] if names else None)
    names = [c for c in names if c.split(".")[0] == wanted]
    if not names:
        raise ValueError(f"the case has no probe {probe or ''} to compare (add one under output.probes)")
    return max(names, key=lambda c: np.abs(history[c]).max())


def reduction_table(case, modes=(2, 5, 10, 20), outdir=None, overrides=(), probe=None,
                    comm: MPI.Comm = MPI.COMM_WORLD) -> list[dict]:
    """Run the full model and the modal model for each n1, with and without static correction.

    Errors against the full model, in the max norm over time relative to the full model's
    maximum: displacement and velocity of a probe (the component that moves most), and the
    total contact impulse. Writes ``reduction.csv`` and every run's folder into ``outdir``.
    """
    case = Path(case)
    outdir = Path(outdir or Path.cwd() / "results" / f"{case.stem}-reduction")
    rows = []
    with staged_directory(outdir, comm) as stage:
        full_summary = run_case(case, stage / "full", [*overrides, "output.vtk=false"], comm=comm, progress=False)
        full = _history(stage / "full")
        u_col = _probe_component(full, probe)
        v_col = u_col.replace(".u", ".v")
        impulse_cols = [c for c in full if c.endswith(".impulse")]
        impulse_full = sum(full[c].sum() for c in impulse_cols)
        rows.append(_row("full", None, None, 0.0, 0.0, 0.0, full_summary))
        for n1 in modes:
            for static in (True, False):
                name = f"modal-{n1}-{'static' if static else 'plain'}"
                summary = run_case(case, stage / name, [*overrides, "output.vtk=false", "solver.method=modal",
                                                        f"solver.modes={n1}", f"solver.static_correction={static}"],
                                   comm=comm, progress=False)
                h = _history(stage / name)
                rows.append(_row(
                    "modal", n1, static,
                    np.abs(h[u_col] - full[u_col]).max() / np.abs(full[u_col]).max(),
                    np.abs(h[v_col] - full[v_col]).max() / np.abs(full[v_col]).max(),
                    abs(sum(h[c].sum() for c in impulse_cols) - impulse_full) / abs(impulse_full),
                    summary,
                ))
                log.info("%s: %s", name, rows[-1])
        if comm.rank == 0:
            with open(stage / "reduction.csv", "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=REDUCTION_COLUMNS)
                writer.writeheader()
                writer.writerows(rows)
    return rows


def _row(model, n1, static, du, dv, dS, summary) -> dict:
    neglected = summary.get("neglected_flexibility") or {}
    return {"model": model, "modes": n1, "static_correction": static, "displacement_error": du,
            "velocity_error": dv, "impulse_error": dS, "wall_time_s": summary["wall_time_s"],
            "loop_time_s": summary["loop_time_s"],
            "neglected_flexibility": max(neglected.values()) if neglected else None}


def format_reduction(rows: list[dict]) -> str:
    lines = [f"{'model':<8}{'modes':>6}{'static':>8}{'disp. err':>11}{'vel. err':>10}{'impulse err':>13}"
             f"{'wall s':>8}{'loop s':>8}{'neglected':>11}"]
    for r in rows:
        flex = f"{r['neglected_flexibility']:.3g}" if r["neglected_flexibility"] is not None else "-"
        lines.append(
            f"{r['model']:<8}{r['modes'] if r['modes'] else '-':>6}"
            f"{({True: 'yes', False: 'no'}.get(r['static_correction'], '-')):>8}"
            f"{100 * r['displacement_error']:>10.2f}%{100 * r['velocity_error']:>9.2f}%"
            f"{100 * r['impulse_error']:>12.2f}%{r['wall_time_s']:>8.2f}{r['loop_time_s']:>8.2f}{flex:>11}"
        )
    lines.append("errors against the full model, max over time relative to its max (probe displacement and "
                 "velocity), total contact impulse; neglected = (P S_k P^T)_jj / (P K^-1 P^T)_jj, largest row")
    return "\n".join(lines)
