"""``fem-impact study convergence``: run a case at several resolutions, measure its errors against the
case's exact solution (``reference:``) or against the finest level, and fit the observed orders.

Refinement follows docs/benchmarks.md s. 1: when the mesh varies, the time step follows it at a
fixed Courant number ``c dt / h`` (the case's own unless ``--courant``; ``--dt`` fixes dt instead);
for time convergence vary ``solver.dt`` on a fixed mesh. The refinement parameter of the fit is
``h`` when the mesh varies, else ``dt`` when the time step varies, else ``1/n1`` for
``solver.modes``, else the varied value itself. The order is the least-squares slope of
log(error) against log(parameter) over the levels (the finest left out when it is the
reference).

Writes into OUTDIR: ``levels/`` (one run per level), ``convergence.csv`` (one row per level),
``convergence.png`` (log-log errors with the fitted orders) and ``study.json`` (options and orders).
"""

from __future__ import annotations

import math
from pathlib import Path

from ...config.case import CaseError, yaml_value
from ...references import ERROR_MEASURES, from_case
from . import methods as registry
from . import resolution
from .common import (
    MEASURE_LABELS,
    StudyInputError,
    case_record,
    study_folder,
    default_outdir,
    fit_order,
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
from .levels import Level, run_levels, slug

COLUMNS_HEAD = ("level",)
COLUMNS_TAIL = ("parameter", "h", "dt", "courant", "unknowns", "steps", "modes", "setup_time_s", "loop_time_s",
                "wall_time_s", "status", "reason", *ERROR_MEASURES, "energy_growth", "reference", "jobs")


def parse_vary(options: list[str]) -> list[tuple[str, list[str]]]:
    """``["mesh.cells=50,100", ...]`` -> [(key, [values])]; numeric values, equal counts."""
    if not options:
        raise StudyInputError("--vary: give at least one KEY=V1,V2,..., e.g. --vary mesh.cells=50,100,200,400")
    out = []
    for option in options:
        key, equals, text = option.partition("=")
        key = key.strip()
        values = [v.strip() for v in text.split(",")]
        if not equals or not key or not all(values):
            raise StudyInputError(f"--vary {option}: expected KEY=V1,V2,... (e.g. mesh.cells=50,100,200)")
        for v in values:
            try:
                float(v)
            except ValueError:
                raise StudyInputError(f"--vary {key}: level {v!r} is not a number") from None
        if len(values) < 2:
            raise StudyInputError(f"--vary {key}: give at least two levels")
        if any(k == key for k, _ in out):
            raise StudyInputError(f"--vary {key}: given twice")
        out.append((key, values))
    counts = {len(v) for _, v in out}
    if len(counts) > 1:
        raise StudyInputError("--vary: every varied key needs the same number of levels (they are taken together)")
    return out


def plan(case, vary, courant=None, dt=None, method=None, changes=(), against=None):
    """The levels and how to read them, validated (StudyInputError or CaseError; nothing run)."""
    method = registry.get(method or registry.DEFAULT_METHOD)
    given = given_changes(changes)
    note = registry.availability(method, case, changes)
    if note:
        raise StudyInputError(f"--method {method.name}: {note}")
    keys = [k for k, _ in vary]
    if courant is not None and dt is not None:
        raise StudyInputError("--courant and --dt: give one of them")
    if "solver.dt" in keys and (courant is not None or dt is not None):
        raise StudyInputError("--vary solver.dt cannot be combined with --courant or --dt")
    if courant is not None and not courant > 0:
        raise StudyInputError(f"--courant {courant:g}: must be > 0")
    if dt is not None and not dt > 0:
        raise StudyInputError(f"--dt {dt:g}: must be > 0")
    common = {**method.changes, **given, "output.vtk": False}
    base = case.with_changes(common)
    n = len(vary[0][1])
    varied = []   # per level: (its --vary changes, the case with them)
    for i in range(n):
        extra = {k: yaml_value(values[i]) for k, values in vary}
        try:
            varied.append((extra, base.with_changes(extra)))
        except CaseError as err:
            shown = ", ".join(f"{k}={values[i]}" for k, values in vary)
            raise StudyInputError(f"--vary {shown}: {err}") from None
    sizes = [resolution.mesh_size(c) for _, c in varied]
    mesh_varies = max(sizes) > min(sizes) * (1 + 1e-9)
    steps = []
    if dt is not None:
        steps = [{"solver.dt": dt}] * n
    elif "solver.dt" not in keys and (mesh_varies or courant is not None):
        target = courant if courant is not None else resolution.courant(base)
        steps = [{"solver.dt": resolution.dt_for(c, target)} for _, c in varied]
    levels, cases = [], []
    for i, (extra, level_case) in enumerate(varied):
        step = steps[i] if steps else {}
        label = " ".join(f"{k}={values[i]}" for k, values in vary)
        levels.append(Level(f"{i:02d}-{slug(label)}", {**common, **extra, **step},
                            {"values": [v[i] for _, v in vary]}, label))
        cases.append(level_case.with_changes(step) if step else level_case)
    if mesh_varies:
        parameter, xs = "h", [resolution.mesh_size(c) for c in cases]
    elif "solver.dt" in keys:
        parameter, xs = "dt", [c.solver.dt for c in cases]
    elif "solver.modes" in keys:
        parameter, xs = "1/n1", [1.0 / float(v) for v in vary[keys.index("solver.modes")][1]]
    else:
        parameter, xs = keys[0], [float(v) for v in vary[0][1]]
    if against is None:
        against = "exact" if base.reference else "finest"
    if against == "exact":
        if base.reference is None:
            raise StudyInputError(f"--against exact: {case.file or 'the case'} declares no reference (add "
                                  "'reference:', e.g. b2, or compare against the finest level)")
        for c in cases:
            from_case(c)   # refuses a case it does not fit (CaseError)
    if parameter in ("h", "dt", "1/n1"):
        finest = min(range(n), key=lambda i: xs[i])
    else:
        finest = n - 1
    return {"method": method, "levels": levels, "parameter": parameter, "x": xs, "against": against,
            "finest": finest, "keys": keys}


def convergence_study(case, vary_options, courant=None, dt=None, method=None, changes=(), against=None,
                      outdir=None, jobs=1, allow_failure=False, quiet=False, stream=None) -> dict:
    """Run the study on ``case`` (a :class:`~fem_impact.config.case.Case`), every level with ``changes`` after the
    method's (a mapping, or ``--set`` options); returns {"rows", "orders", "reference", "parameter", "outdir"}."""
    vary = parse_vary(vary_options)
    p = plan(case, vary, courant, dt, method, changes, against)
    outdir = Path(outdir) if outdir else default_outdir(case, "convergence")
    with study_folder(outdir, "study convergence", case):
        outcomes = run_levels(case, p["levels"], outdir, jobs, allow_failure, stream=stream, quiet=quiet)
        finest = outcomes[p["finest"]]
        rows = []
        if p["against"] == "exact":
            references = [from_case(o.case) for o in outcomes]
            label = references[0].label
        else:
            if not finest.ok:
                raise StudyInputError(f"the finest level ({finest.level.label}) did not finish ({finest.reason}): "
                                      "no reference to measure the other levels against")
            label = f"finest level ({finest.level.label})"
            references = [run_reference(finest, label)] * len(outcomes)
        for i, (o, ref, x) in enumerate(zip(outcomes, references, p["x"], strict=True)):
            row = {"level": o.level.label, **dict(zip(p["keys"], o.level.info["values"], strict=True)),
                   **level_row(o, jobs), "parameter": x, "reference": label}
            is_ref = p["against"] == "finest" and i == p["finest"]
            row.update(dict.fromkeys(ERROR_MEASURES, math.nan) if is_ref else measure(o, ref))
            rows.append(row)
        fit = [i for i in range(len(rows)) if not (p["against"] == "finest" and i == p["finest"])]
        orders = {m: fit_order([rows[i]["parameter"] for i in fit], [rows[i][m] for i in fit]) for m in ERROR_MEASURES}
        columns = [*COLUMNS_HEAD, *p["keys"], *COLUMNS_TAIL]
        outdir.mkdir(parents=True, exist_ok=True)
        write_csv(outdir / "convergence.csv", columns, rows)
        _plot(outdir / "convergence.png", rows, orders, p, label, case.name)
        record = case_record(case, changes)
        write_json(outdir / "study.json", {
            "study": "convergence", "case": record["case"], "method": p["method"].name,
            "vary": dict(vary), "courant": courant, "dt": dt, "overrides": record["overrides"], "parameter": p["parameter"],
            "reference": label, "orders": orders, "jobs": jobs})
        return {"rows": rows, "orders": orders, "reference": label, "parameter": p["parameter"], "outdir": outdir,
                "method": p["method"].name, "keys": p["keys"]}


def format_convergence(result: dict) -> str:
    """The printed table: one line per level, then the fitted orders."""
    keys, rows = result["keys"], result["rows"]
    short = {"err_displacement": "displ.", "err_impulse": "impulse", "err_force": "force",
             "force_oscillation": "force osc.", "err_energy": "energy"}
    head = "".join(f"{k:>14}" for k in keys) + f"{result['parameter']:>12}{'steps':>8}{'loop s':>8}"
    head += "".join(f"{short[m]:>12}" for m in ERROR_MEASURES)
    lines = [f"convergence of {result['method']}; errors against the {result['reference']}", head]
    for r in rows:
        line = "".join(f"{r[k]:>14}" for k in keys)
        line += f"{fmt(r['parameter'], '.4g'):>12}{fmt(r['steps'], 'd'):>8}{fmt(r['loop_time_s'], '.2f'):>8}"
        line += "".join(f"{fmt(r[m]):>12}" for m in ERROR_MEASURES)
        if r["status"] != "ok":
            line += f"  {r['status']}: {r['reason']}"
        lines.append(line)
    lines.append(f"{'fitted order':>{14 * len(keys) + 28}}"
                 + "".join(f"{fmt(result['orders'][m], '.2f'):>12}" for m in ERROR_MEASURES))
    lines.append(f"(error ~ {result['parameter']}^order, least squares over the levels; results in {result['outdir']})")
    return "\n".join(lines)


def _plot(path: Path, rows, orders, p, label, name) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 5.5), constrained_layout=True)
    for m in ERROR_MEASURES:
        pts = [(r["parameter"], r[m]) for r in rows if isinstance(r[m], float) and math.isfinite(r[m]) and r[m] > 0]
        if len(pts) < 1:
            continue
        x, y = zip(*sorted(pts), strict=True)
        order = orders[m]
        text = f"order {order:.2f}" if math.isfinite(order) else "no fit"
        ax.loglog(x, y, "o-", label=f"{MEASURE_LABELS[m]}: {text}")
    ax.set_xlabel({"h": "mesh size h", "dt": "time step dt", "1/n1": "1 / kept modes n1"}.get(p["parameter"],
                                                                                             p["parameter"]))
    ax.set_ylabel("relative error")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"{name}: convergence of {p['method'].name}\nagainst the {label}", fontsize=9)
    save_figure(fig, path)
    plt.close(fig)
    return path
