"""``fem-impact sweep``: run a case once per value of one key; tabulate and plot the mean speed.

Each run is the case with ``KEY=VALUE`` set as by ``--set`` (``Case.with_changes``; VTK output off
unless the case sets ``output.vtk`` itself), run by :func:`fem_impact.run`; what is kept of it is
read back from its ``history.csv`` and ``summary.json``:

- the mean velocity of the target over the second half of the run, per axis: for a probe
  ``(u(t_end) - u(t_h)) / (t_end - t_h)`` (the time mean of its velocity exactly), for a body the
  time mean of its centre-of-mass velocity ``p / m`` (history columns ``BODY.px``..., mass from
  ``summary.json``; trapezoid rule over the stored steps); ``t_h`` is the first stored time at or
  after ``t_end / 2``;
- the final displacement: the probe's, or the body's centre-of-mass displacement since t = 0
  (the trapezoid integral of ``p / m``; exact for the trapezoidal rule except on the steps where
  an impact correction changes the velocity);
- the total impulse of every contact and the run's wall time.

Everything is checked before the first run (the key and every value are applied to the case and
validated; the probe or body must exist), and written through a staging folder: a failed or
interrupted sweep leaves OUTDIR as it was.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from mpi4py import MPI

from ..config.case import yaml_value
from .plots import history_columns

log = logging.getLogger(__name__)
AXES = "xyz"


class SweepError(ValueError):
    """A command-line option of the sweep that does not fit (reported like bad input)."""


@dataclass
class Target:
    """What the sweep measures: a probe of the case or a body of its mesh."""

    kind: str   # "probe" or "body"
    name: str


def parse_vary(text: str) -> tuple[str, list[str], list]:
    """``KEY=v1,v2,...`` -> (key, value texts, values typed as in YAML)."""
    key, equals, rest = text.partition("=")
    key = key.strip()
    texts = [v.strip() for v in rest.split(",")]
    if not equals or not key or not all(re.fullmatch(r"[^.\s=]+", s) for s in key.split(".")) or not all(texts):
        raise SweepError(f"--vary {text}: give KEY.PATH=v1,v2,... (scalar values separated by commas), "
                         "e.g. --vary parameters.f=20e3,21e3,22e3")
    values = []
    for item in texts:
        try:
            value = yaml_value(item)
        except yaml.YAMLError:
            value = None
        if isinstance(value, (dict, list)) or value is None:
            raise SweepError(f"--vary {key}: '{item}' is not a scalar value")
        values.append(value)
    return key, texts, values


def check(case, key: str, texts: list[str], target: Target | None, comm: MPI.Comm) -> tuple[Target, list]:
    """Apply every value to the case (CaseError on a bad one) and settle the target; nothing is written.

    Returns the target and the case of each run.
    """
    # VTK off by default: a sweep reads histories (unless the case was given output.vtk, e.g. by --set).
    base = case if _given(case, "output.vtk") else case.with_changes({"output.vtk": False})
    cases = [base.with_changes([f"{key}={text}"]) for text in texts]
    first = cases[0]
    probes = list(first.output.probes)
    if target is None:
        if not probes:
            raise SweepError(f"{case.file or 'the case'}: the case has no probe; give --probe NAME or --body NAME")
        target = Target("probe", probes[0])
    if target.kind == "probe":
        missing = [c for c in cases if target.name not in c.output.probes]
        if missing:
            known = ", ".join(probes) or "none"
            raise SweepError(f"--probe {target.name}: no such probe in the case (probes: {known})")
    else:
        from ..fem.mesh import build_mesh

        with first.errors_at_keys():   # (a mesh file that does not fit: the builder's error, at its key)
            bodies = sorted(build_mesh(first.mesh, comm).bodies)
        if target.name not in bodies:
            raise SweepError(f"--body {target.name}: no such body in the mesh (bodies: {', '.join(bodies)})")
    return target, cases


def _given(case, key: str) -> bool:
    """Whether ``key`` (a dotted path), or a mapping above it, was given to the case by ``--set`` or a change."""
    path = tuple(key.split("."))
    return any(tuple(str(s) for s in p) == path[:len(p)] for p in case.overrides)


def measure(outdir: Path, target: Target) -> dict:
    """Mean velocity over the second half, final displacement, impulses and wall time of one run."""
    col = history_columns(outdir)
    summary = json.loads((outdir / "summary.json").read_text())
    t = col["t"]
    half = int(np.searchsorted(t, 0.5 * t[-1] * (1 - 1e-12)))
    half = min(half, len(t) - 2)
    span = t[-1] - t[half]
    speeds, displacements = {}, {}
    axes = [a for a in AXES if f"{target.name}.{'u' if target.kind == 'probe' else 'p'}{a}" in col]
    for a in axes:
        if target.kind == "probe":
            u = col[f"{target.name}.u{a}"]
            speeds[f"{target.name}.mean_v{a}"] = (u[-1] - u[half]) / span
            displacements[f"{target.name}.u{a}"] = u[-1]
        else:
            v = col[f"{target.name}.p{a}"] / summary["body_mass"][target.name]
            speeds[f"{target.name}.mean_v{a}"] = float(np.trapz(v[half:], t[half:])) / span
            displacements[f"{target.name}.u{a}"] = float(np.trapz(v, t))
    row = {**speeds, **displacements}
    for contact, impulse in summary["total_impulse"].items():
        row[f"{contact}.impulse"] = impulse
    row["wall_time_s"] = summary["wall_time_s"]
    return row


def run_sweep(case, vary: str, target: Target | None = None, outdir=None, comm: MPI.Comm = MPI.COMM_WORLD,
              progress: bool = True, report=print) -> tuple[Path, list[dict]]:
    """Run the sweep on ``case`` (a :class:`~fem_impact.config.case.Case`); returns (OUTDIR, rows). Writes sweep.csv,
    sweep.png and the runs' folders.

    Raises SweepError or CaseError on bad input before anything runs or is written.
    """
    from .outdir.policy import case_inputs
    from .outdir.writes import writing
    from .output import Progress
    from .pipeline import run, staged_directory

    key, texts, values = parse_vary(vary)
    target, cases = check(case, key, texts, target, comm)
    outdir = Path(outdir) if outdir is not None else Path.cwd() / "results" / f"{case.name}-sweep"
    rows = []
    with staged_directory(outdir, comm, "sweep", protect=case_inputs(case)) as stage:
        for i, (text, value, one) in enumerate(zip(texts, values, cases, strict=True)):
            label = f"[{i + 1}/{len(texts)}] {key}={text}"
            run_dir = stage / f"run{i + 1:02d}"
            t0 = time.perf_counter()
            run(one, run_dir, comm=comm, progress=Progress(comm, label=label) if progress else False)
            row = {key: value, **measure(run_dir, target), "run": run_dir.name}
            rows.append(row)
            if comm.rank == 0 and report:
                speeds = ", ".join(f"{name.rsplit('.', 1)[1]} {v:.4g}" for name, v in row.items()
                                   if name.startswith(f"{target.name}.mean_v"))
                report(f"{label}: {target.kind} {target.name} mean velocity over the second half {speeds} "
                       f"({time.perf_counter() - t0:.1f} s)")
        if comm.rank == 0:
            with writing(stage / "sweep.csv"):
                write_csv(stage / "sweep.csv", rows)
            with writing(stage / "sweep.png"):
                plot_sweep(stage / "sweep.png", rows, key, target, case.name)
    return outdir.resolve(), rows


def write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def plot_sweep(path: Path, rows: list[dict], key: str, target: Target, title: str) -> Path:
    """Mean velocity (second half of each run) against the varied value, one line per axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values = [row[key] for row in rows]
    numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)
    x = values if numeric else list(range(len(values)))
    fig, ax = plt.subplots(figsize=(7, 4.2), constrained_layout=True)
    for name in rows[0]:
        if name.startswith(f"{target.name}.mean_v"):
            ax.plot(x, [row[name] for row in rows], "o-", label=f"mean v{name[-1]}")
    if not numeric:
        ax.set_xticks(x, [str(v) for v in values])
    ax.axhline(0.0, color="grey", lw=0.8)
    ax.set_xlabel(key)
    ax.set_ylabel("mean velocity over the second half of the run")
    ax.set_title(f"{title}: {target.kind} {target.name}", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def format_sweep(rows: list[dict]) -> str:
    """The sweep as a plain table (the sweep.csv columns, numbers to 5 significant digits)."""
    names = [n for n in rows[0] if n != "run"]   # the varied key first: its values as given
    shown = [[str(row[n]) if i == 0 or not isinstance(row[n], float) else f"{row[n]:.5g}"
              for i, n in enumerate(names)] for row in rows]
    widths = [max(len(n), *(len(r[i]) for r in shown)) for i, n in enumerate(names)]
    lines = ["  ".join(n.rjust(w) for n, w in zip(names, widths, strict=True))]
    lines += ["  ".join(v.rjust(w) for v, w in zip(r, widths, strict=True)) for r in shown]
    return "\n".join(lines)
