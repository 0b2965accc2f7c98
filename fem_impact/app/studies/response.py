"""``fem-impact study response``: the settled response of a forced case over a sweep of its forcing frequency.

The varied key is the forcing frequency in Hz (e.g. ``parameters.f``, which the case's loads or a
support's motion use). Each level runs ``settle + periods`` forcing periods at ``steps_per_period``
steps a period (the step follows the frequency), starting from the previous level's last state
(natural continuation: ``initial: {from: ...}``; its last step is a whole number of its own periods,
so every level starts at forcing phase 0). The last ``periods`` periods are sampled on the
stroboscopic Poincare section, the state at forcing phase 0.

The period of the settled response is the smallest k for which the section repeats after k forcing
periods (every point of the second half of the window within ``tolerance`` of the one k periods
before, on the scale of each probe column); 0 when none up to periods / 2 (quasi-periodic or
chaotic, or not settled). ``response.csv`` has one row per Poincare point of the last period found
(or all points when none): the direction of the sweep, the varied key, ``period``, ``point``, per
probe its displacements and velocities at the section, per contact ``NAME.impulse`` (its impulse
over the forcing period that ends at the point) and ``NAME.impacts`` (their number).
``response.png`` is the bifurcation diagram: the Poincare points of the first probe's first
displacement column against the frequency, up and down sweeps in two colours, and the impulse per
period. A sweep down into the same folder keeps the sweep up, and the chart shows both.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from ..outdir import replacing
from .common import StudyInputError, case_record, given_changes, pyplot, save_figure, write_json
from .levels import Level, run_levels, slug

DIRECTIONS = ("up", "down")


def response_study(case, vary: str, outdir, down: bool = False, settle: int = 50, periods: int = 16,
                   steps_per_period: int = 500, tolerance: float = 1e-4, changes=(), quiet: bool = False,
                   allow_failure: bool = False) -> dict:
    key, values = _vary(vary)
    for name, value, least in (("--settle", settle, 0), ("--periods", periods, 2), ("--steps-per-period",
                                                                                  steps_per_period, 4)):
        if value < least:
            raise StudyInputError(f"{name} {value}: give at least {least}")
    if not tolerance > 0:
        raise StudyInputError(f"--tolerance {tolerance}: give a positive number")
    outdir = Path(outdir)
    given = given_changes(changes)
    base = case.with_changes(given) if given else case
    base.with_changes({key: values[0]})   # (CaseError: a key the case does not have, before anything runs)
    direction = "down" if down else "up"
    ordered = sorted(values, reverse=down)
    levels, previous = [], None
    for i, f in enumerate(ordered):
        name = f"{direction}-{i:03d}-{slug(key)}={f:.6g}"
        level_changes = {key: f, "solver.dt": 1.0 / (f * steps_per_period),
                         "solver.t_end": (settle + periods) / f, "output.vtk": False}
        if previous is not None:
            level_changes["initial"] = {"from": str((outdir / "levels" / previous).resolve())}
        levels.append(Level(name, level_changes, info={"direction": direction, "value": f, "index": i}))
        previous = name
    outcomes = run_levels(base, levels, outdir, jobs=1, allow_failure=allow_failure, quiet=quiet)
    rows = []
    for outcome in outcomes:
        if outcome.ok:
            rows += section_rows(outcome.folder, key, outcome.level.info["value"], direction, settle, periods,
                                 steps_per_period, tolerance)
    other = _other_direction(outdir, direction, key)
    all_rows = sorted(other + rows, key=lambda r: (r["direction"], r[key], r["point"]))
    columns = list(all_rows[0]) if all_rows else ["direction", key, "period", "point"]
    _write_rows(outdir / "response.csv", columns, all_rows)
    write_json(outdir / "study.json", {"study": "response", "vary": key, "values": ordered, "direction": direction,
                                       "settle": settle, "periods": periods, "steps_per_period": steps_per_period,
                                       "tolerance": tolerance, **case_record(case, changes)})
    (outdir / f"response-{direction}.json").write_text(json.dumps(rows, indent=1) + "\n")
    chart = plot_response(all_rows, key, outdir / "response.png") if all_rows else None
    return {"rows": all_rows, "key": key, "levels": outcomes, "chart": chart, "outdir": str(outdir)}


def _vary(vary: str) -> tuple[str, list[float]]:
    key, equals, text = str(vary).partition("=")
    try:
        values = [float(v) for v in text.split(",")] if equals else []
    except ValueError:
        values = []
    if not key or not values or any(not v > 0 for v in values):
        raise StudyInputError(f"--vary {vary}: expected KEY=F1,F2,... with positive frequencies in Hz, e.g. "
                              "parameters.f=40,45,50")
    return key.strip(), values


def section_rows(folder: Path, key: str, value: float, direction: str, settle: int, periods: int, steps: int,
                 tolerance: float) -> list[dict]:
    """The Poincare points of one level's run (its history.csv and impacts.csv) as response.csv rows."""
    from ..plots import history_columns

    h = history_columns(folder)
    t = h["t"]
    section = np.arange(settle + 1, settle + periods + 1) * steps   # rows at phase 0 ending each sampled period
    if section[-1] >= t.size:
        raise StudyInputError(f"{folder}: the run has {t.size - 1} steps, the section needs {section[-1]}")
    probes = [name for name in h if "." in name and name.rsplit(".", 1)[1][:1] in "uv"
              and name.rsplit(".", 1)[1][1:] in ("x", "y", "z")]
    contacts = [name[: -len(".impulse")] for name in h if name.endswith(".impulse")]
    states = np.column_stack([h[p][section] for p in probes]) if probes else np.zeros((periods, 0))
    k = detect_period(states, tolerance)
    impacts = _impact_times(folder)
    period = 1.0 / value
    rows = []
    chosen = range(periods - k, periods) if k else range(periods)
    for j in chosen:
        row = {"direction": direction, key: value, "period": k, "point": j - chosen.start}
        row.update({p: float(states[j, i]) for i, p in enumerate(probes)})
        first, last = section[j] - steps, section[j]
        for c in contacts:
            row[f"{c}.impulse"] = float(h[f"{c}.impulse"][first + 1:last + 1].sum())
            t0, t1 = t[first], t[last]
            row[f"{c}.impacts"] = int(np.count_nonzero((impacts.get(c, np.zeros(0)) > t0 + 1e-9 * period)
                                                       & (impacts.get(c, np.zeros(0)) <= t1 + 1e-9 * period)))
        rows.append(row)
    return rows


def detect_period(states: np.ndarray, tolerance: float) -> int:
    """The smallest k <= n / 2 with every point of the second half within ``tolerance`` of the one k
    before it, on the scale of each column (its largest magnitude); 0 when none."""
    n = states.shape[0]
    if n < 2 or states.shape[1] == 0:
        return 0
    scale = np.maximum(np.abs(states).max(axis=0), 1e-300)
    for k in range(1, n // 2 + 1):
        start = max(k, n // 2)
        if np.all(np.abs(states[start:] - states[start - k:n - k]) <= tolerance * scale):
            return k
    return 0


def _impact_times(folder: Path) -> dict[str, np.ndarray]:
    times: dict[str, list] = {}
    path = folder / "impacts.csv"
    if path.is_file():
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                times.setdefault(row["contact"], []).append(float(row["t"]))
    return {name: np.array(v) for name, v in times.items()}


def _other_direction(outdir: Path, direction: str, key: str) -> list[dict]:
    """The rows a sweep the other way left in the folder (response-up.json or response-down.json)."""
    other = DIRECTIONS[1 - DIRECTIONS.index(direction)]
    path = outdir / f"response-{other}.json"
    try:
        rows = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    return [r for r in rows if key in r]


def _write_rows(path: Path, columns, rows) -> None:
    with replacing(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.12g}" if isinstance(v, float) else v for k, v in row.items()})


def plot_response(rows: list[dict], key: str, path: Path) -> Path:
    plt = pyplot()
    probe = next((c for c in rows[0] if c.endswith((".ux", ".uy", ".uz"))), None)
    contacts = [c[: -len(".impulse")] for c in rows[0] if c.endswith(".impulse")]
    fig, axes = plt.subplots(2 if contacts else 1, 1, figsize=(8, 7 if contacts else 4), sharex=True, squeeze=False)
    colours = {"up": "tab:blue", "down": "tab:red"}
    for direction in DIRECTIONS:
        mine = [r for r in rows if r["direction"] == direction]
        if not mine:
            continue
        x = np.array([r[key] for r in mine])
        if probe is not None:
            axes[0, 0].plot(x, [r[probe] for r in mine], ".", ms=4, color=colours[direction],
                            label=f"sweep {direction}")
        if contacts:
            for c in contacts:
                axes[1, 0].plot(x, [r[f"{c}.impulse"] for r in mine], ".", ms=4, color=colours[direction],
                                label=f"{c}, sweep {direction}")
    axes[0, 0].set_ylabel(f"{probe} at forcing phase 0" if probe else "")
    axes[0, 0].set_title("Bifurcation diagram: the stroboscopic Poincare section of the settled response")
    axes[0, 0].legend(loc="best", fontsize=8)
    if contacts:
        axes[1, 0].set_ylabel("impulse per forcing period")
        axes[1, 0].legend(loc="best", fontsize=8)
    axes[-1, 0].set_xlabel(f"{key} (forcing frequency, Hz)")
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def format_response(result: dict) -> str:
    """The table printed at the end: per level the period found and the Poincare points' spread."""
    key = result["key"]
    lines = [f"{'direction':<9} {key:>14} {'period':>6} {'points':>6}  impulse per period"]
    seen = {}
    for r in result["rows"]:
        seen.setdefault((r["direction"], r[key]), []).append(r)
    for (direction, value), rows in sorted(seen.items()):
        impulses = [v for k, v in rows[0].items() if k.endswith(".impulse")]
        per = ", ".join(f"{np.mean([r[k] for r in rows]):.4g}" for k in rows[0] if k.endswith(".impulse"))
        lines.append(f"{direction:<9} {value:>14.6g} {rows[0]['period']:>6} {len(rows):>6}  {per if impulses else ''}")
    lines.append(f"response.csv, response.png in {result['outdir']}")
    return "\n".join(lines)
