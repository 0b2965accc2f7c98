"""``fem-impact study pareto``: the speed-accuracy chart. For every method a ladder of resolutions,
each run timed on this machine in the same study, its errors measured against the case's exact
solution, or, without one, against a reference run of the default method finer than every rung.

Ladders (``rungs`` each, default 5; the case's own resolution is the fourth rung):

- full-model methods on the built-in bar: mesh cells ``cells x 2^(k - 3)``, k = 0..rungs-1 (so
  1/8 to 2 times the case's), the time step following at a fixed Courant number (the case's, or
  ``--courant``); on a mesh file: the time step ``dt / 2^(k - 3)`` on the case's mesh;
- modal methods: kept modes n1 = 5, 10, 20, 40, 80 (``5 x 2^k``), on the case's mesh and time
  step.

A rung above a method's stability limit (``max_courant`` in the registry) is left out. Work is
the whole run (``wall_time_s``: setup with the modes, and the loop; ``--time loop`` for the loop
alone). Writes ``levels/``, ``pareto.csv``, ``pareto.png`` and ``study.json`` into OUTDIR.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

from ...references import ERROR_MEASURES, from_case
from . import methods as registry
from . import resolution
from .common import (
    MEASURE_LABELS,
    StudyInputError,
    base_case,
    case_record,
    study_folder,
    default_outdir,
    fmt,
    given_changes,
    level_row,
    measure,
    pyplot,
    run_reference,
    save_figure,
    write_csv,
    write_json,
)
from .levels import Level, run_levels

DEFAULT_RUNGS = 5
COLUMNS = ("method", "knob", "resolution", "unknowns", "steps", "modes", "setup_time_s", "loop_time_s",
           "wall_time_s", *ERROR_MEASURES, "energy_growth", "status", "reason", "h", "dt", "courant", "reference",
           "jobs")
PANELS = ("err_displacement", "err_impulse", "err_force", "err_energy")


def _rung_factor(k: int) -> float:
    return 2.0 ** (k - 3)


def ladder(method, base, given, courant, rungs) -> tuple[list[Level], list[str]]:
    """The levels of one method (``given`` changes after its own) on the case ``base``, and notes on the rungs
    left out."""
    common = {**registry.changes_for(method, base, given), "output.vtk": False}
    levels, notes = [], []
    if method.knob == "modes":
        for k in range(rungs):
            n1 = 5 * 2 ** k
            levels.append(Level(f"{method.name}-modes-{n1}", {**common, "solver.modes": n1},
                                {"method": method.name, "knob": "modes", "resolution": n1}, f"{method.name} n1={n1}"))
        return levels, notes
    c = resolution.wave_speed(base)
    target = courant if courant is not None else resolution.courant(base)
    for k in range(rungs):
        r = _rung_factor(k)
        if base.mesh.file is None:
            cells = max(2, int(round(base.mesh.cells * r)))
            if any(level.info.get("resolution") == cells for level in levels):
                continue   # (a coarse case: the lowest rungs all clamp to 2 cells, run once)
            dt = target * (base.mesh.length / cells) / c
            extra, knob, value, label = {"mesh.cells": cells, "solver.dt": dt}, "cells", cells, f"cells={cells}"
            cfl = target
        else:
            dt = base.solver.dt / r if courant is None else target * resolution.mesh_size(base) / c / r
            extra, knob, value, label = {"solver.dt": dt}, "dt", dt, f"dt={dt:.4g}"
            cfl = c * dt / resolution.mesh_size(base)
        if method.max_courant is not None and cfl > method.max_courant * (1 + 1e-9):
            notes.append(f"{method.name} {label}: left out, Courant number {cfl:.3g} is above its stability "
                         f"limit {method.max_courant:g}")
            continue
        levels.append(Level(f"{method.name}-{knob}-{k}", {**common, **extra},
                            {"method": method.name, "knob": knob, "resolution": value}, f"{method.name} {label}"))
    return levels, notes


def _reference_level(base, given, courant, rungs) -> Level:
    """The default method one step finer than the top rung of the full-model ladder."""
    method = registry.get(registry.DEFAULT_METHOD)
    top = _rung_factor(rungs)   # one rung beyond the last
    c = resolution.wave_speed(base)
    target = courant if courant is not None else resolution.courant(base)
    if base.mesh.file is None:
        cells = max(2, int(round(base.mesh.cells * top)))
        extra = {"mesh.cells": cells, "solver.dt": target * (base.mesh.length / cells) / c}
        label = f"cells={cells}"
    else:
        dt = (base.solver.dt if courant is None else target * resolution.mesh_size(base) / c) / top
        extra, label = {"solver.dt": dt}, f"dt={dt:.4g}"
    return Level("reference", {**registry.changes_for(method, base, given), "output.vtk": False, **extra},
                 {"method": method.name, "knob": "reference"}, f"reference run ({method.name} {label})")


def pareto_study(case, methods=None, courant=None, rungs=None, time_axis="wall", changes=(), outdir=None, jobs=1,
                 allow_failure=False, quiet=False, stream=None) -> dict:
    """Run the ladders on ``case`` (a :class:`~fem_impact.config.case.Case`), every run with ``changes`` after its
    method's (a mapping, or ``--set`` options); returns {"rows", "fronts", "reference", "skipped", "outdir"}."""
    stream = stream or sys.stderr
    rungs = DEFAULT_RUNGS if rungs is None else rungs
    if rungs < 2:
        raise StudyInputError(f"--levels {rungs}: give at least 2 rungs")
    if courant is not None and not courant > 0:
        raise StudyInputError(f"--courant {courant:g}: must be > 0")
    if time_axis not in ("wall", "loop"):
        raise StudyInputError(f"--time {time_axis}: wall or loop")
    chosen = registry.parse_methods(methods)
    given = given_changes(changes)
    base = base_case(case, given)   # the resolution the ladders start from
    outdir = Path(outdir) if outdir else default_outdir(case, "pareto")
    with study_folder(outdir, "study pareto", case):
        levels, notes, skipped = [], [], {}
        for method in chosen:
            why = registry.availability(method, case, changes)
            if why:
                skipped[method.name] = why
                continue
            lv, nt = ladder(method, base, given, courant, rungs)
            levels += lv
            notes += nt
        if not levels:
            raise StudyInputError("no method to run: " + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
        exact = base.reference is not None
        if exact:
            for lv in levels:
                from_case(case.with_changes(lv.changes))   # CaseError if the case does not fit its reference
        else:
            levels.append(_reference_level(base, given, courant, rungs))
        if not quiet:
            for name, why in skipped.items():
                stream.write(f"note: {name} skipped: {why}\n")
            for note in notes:
                stream.write(f"note: {note}\n")
        outcomes = run_levels(case, levels, outdir, jobs, allow_failure, stream=stream, quiet=quiet)
        if exact:
            references = [from_case(o.case) for o in outcomes]
            label = references[0].label
        else:
            ref_outcome = outcomes.pop()
            if not ref_outcome.ok:
                raise StudyInputError(f"the reference run did not finish ({ref_outcome.reason})")
            label = ref_outcome.level.label
            references = [run_reference(ref_outcome, label)] * len(outcomes)
        rows = []
        for o, ref in zip(outcomes, references, strict=True):
            rows.append({**o.level.info, **level_row(o, jobs), **measure(o, ref), "reference": label})
        time_key = "wall_time_s" if time_axis == "wall" else "loop_time_s"
        fronts = {m: pareto_front(rows, m, time_key) for m in PANELS}
        outdir.mkdir(parents=True, exist_ok=True)
        write_csv(outdir / "pareto.csv", COLUMNS, rows)
        _plot(outdir / "pareto.png", rows, fronts, time_key, label, base.name, jobs)
        record = case_record(case, changes)
        write_json(outdir / "study.json", {
            "study": "pareto", "case": record["case"], "methods": [m.name for m in chosen],
            "skipped": skipped, "notes": notes, "courant": courant, "rungs": rungs, "time": time_key,
            "overrides": record["overrides"], "reference": label, "jobs": jobs,
            "fronts": {m: [f"{rows[i]['method']} {rows[i]['resolution']}" for i in f] for m, f in fronts.items()}})
        return {"rows": rows, "fronts": fronts, "reference": label, "skipped": skipped, "notes": notes,
                "outdir": outdir, "time_key": time_key, "jobs": jobs}


def pareto_front(rows, measure_name: str, time_key: str) -> list[int]:
    """Indices of the rows no other row beats in both time and error (sorted by time)."""
    pts = [(r[time_key], r[measure_name], i) for i, r in enumerate(rows)
           if r["status"] == "ok" and _finite(r[measure_name]) and _finite(r[time_key])]
    front, best = [], math.inf
    for _, e, i in sorted(pts):
        if e < best:
            front.append(i)
            best = e
    return front


def _short(row) -> str:
    """A rung's label on the chart: cells, dt or n1."""
    if row["knob"] == "dt":
        return f"dt {row['resolution']:.3g}"
    return f"{'n1' if row['knob'] == 'modes' else 'cells'} {row['resolution']}"


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)


def format_pareto(result: dict) -> str:
    tk = result["time_key"]
    lines = [f"speed and accuracy; errors against the {result['reference']}; time = "
             f"{'whole run' if tk == 'wall_time_s' else 'time loop'} (s), {result['jobs']} run(s) at a time",
             f"{'method':<20}{'resolution':>12}{'unknowns':>9}{'steps':>8}{'modes':>6}{'setup s':>9}{'loop s':>8}"
             f"{'wall s':>8}{'displ.':>10}{'impulse':>10}{'force':>10}{'energy':>10}"]
    for r in result["rows"]:
        res = fmt(r["resolution"], ".4g") if isinstance(r["resolution"], float) else str(r["resolution"])
        line = (f"{r['method']:<20}{res:>12}{fmt(r['unknowns'], 'd'):>9}{fmt(r['steps'], 'd'):>8}"
                f"{fmt(r['modes'], 'd'):>6}{fmt(r['setup_time_s'], '.3f'):>9}{fmt(r['loop_time_s'], '.3f'):>8}"
                f"{fmt(r['wall_time_s'], '.3f'):>8}" + "".join(f"{fmt(r[m]):>10}" for m in PANELS))
        if r["status"] != "ok":
            line += f"  {r['status']}: {r['reason']}"
        lines.append(line)
    for m in PANELS:
        front = result["fronts"][m]
        if front:
            pts = ", ".join(f"{result['rows'][i]['method']} {fmt(result['rows'][i]['resolution'], '.4g')}"
                            for i in front)
            lines.append(f"Pareto front, {MEASURE_LABELS[m]}: {pts}")
    for name, why in result["skipped"].items():
        lines.append(f"skipped {name}: {why}")
    lines.append(f"results in {result['outdir']}")
    return "\n".join(lines)


def _plot(path: Path, rows, fronts, time_key, label, name, jobs) -> Path:
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(11, 8.5), constrained_layout=True)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    colors = {m: f"C{i}" for i, m in enumerate(methods)}
    for ax, m in zip(axes.ravel(), PANELS, strict=True):
        drawn = False
        for method in methods:
            # In ladder order (coarse to fine), so that a line follows its method's refinement.
            pts = [(r[time_key], r[m], _short(r)) for r in rows
                   if r["method"] == method and r["status"] == "ok" and _finite(r[m]) and r[m] > 0]
            if pts:
                x, y, names = zip(*pts, strict=True)
                ax.loglog(x, y, "o-", color=colors[method], label=method, ms=4)
                for i in {0, len(pts) - 1}:
                    ax.annotate(names[i], (x[i], y[i]), textcoords="offset points", xytext=(4, 3), fontsize=6,
                                color=colors[method])
                drawn = True
        front = [(rows[i][time_key], rows[i][m]) for i in fronts[m] if rows[i][m] > 0]
        if front:
            x, y = zip(*front, strict=True)
            ax.loglog(x, y, "k--", drawstyle="steps-post", lw=1, label="Pareto front")
            ax.loglog(x, y, "o", mfc="none", mec="k", ms=10)
        ax.set_title(MEASURE_LABELS[m], fontsize=10)
        ax.set_xlabel(f"{'whole run' if time_key == 'wall_time_s' else 'time loop'}: wall time (s)")
        ax.set_ylabel("relative error")
        ax.grid(True, which="both", alpha=0.3)
        if drawn:
            ax.legend(fontsize=7, framealpha=0.6)
        else:
            ax.text(0.5, 0.5, "no contact in this case" if m != "err_displacement" else "no data",
                    ha="center", va="center", transform=ax.transAxes)
    note = "" if jobs == 1 else f"; {jobs} runs at a time (timings include each process's imports)"
    fig.suptitle(f"{name}: error against wall time, one line per method\nerrors against the {label}{note}",
                 fontsize=10)
    save_figure(fig, path)
    plt.close(fig)
    return path

