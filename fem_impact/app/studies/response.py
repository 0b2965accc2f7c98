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
                   allow_failure: bool = False, flight: str = "scheme", shooting: bool = True) -> dict:
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
    if flight not in ("scheme", "events"):
        raise StudyInputError(f"--flight {flight}: scheme (the case's time stepping) or events (event-driven)")
    if flight == "events":
        return _finish(case, changes, outdir, key, ordered, direction, settle, periods, steps_per_period, tolerance,
                       *_event_levels(base, key, ordered, direction, settle, periods, tolerance, quiet),
                       shooting, flight)
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
    rows, ends = [], {}
    for outcome in outcomes:
        if outcome.ok:
            f = outcome.level.info["value"]
            rows += section_rows(outcome.folder, key, f, direction, settle, periods, steps_per_period, tolerance)
            ends[f] = outcome.folder
    return _finish(case, changes, outdir, key, ordered, direction, settle, periods, steps_per_period, tolerance,
                   base, rows, ends, shooting, flight, outcomes)


def _finish(case, changes, outdir, key, ordered, direction, settle, periods, steps_per_period, tolerance, base, rows,
            ends, shooting, flight, outcomes=()):
    """Shooting along the sweep, response.csv, study.json, response.png."""
    orbits, note = {}, None
    if shooting:
        orbits, note = shoot_branch(base, key, ordered, ends, rows)
        for row in rows:
            row.update(orbits.get(row[key], {}))
    bifurcations = find_bifurcations(key, ordered, orbits)
    for row in rows:   # response.csv says where: on the rows of the level past each crossing
        marks = [f"{b['kind']} at {b[key]:.6g}" for b in bifurcations if b["between"][1] == row[key]]
        if bifurcations:
            row["bifurcation"] = "; ".join(marks)
    other = _other_direction(outdir, direction, key)
    all_rows = sorted(other + rows, key=lambda r: (r["direction"], r[key], r["point"]))
    columns = list(dict.fromkeys(c for r in all_rows for c in r)) if all_rows else ["direction", key, "period",
                                                                                     "point"]
    _write_rows(outdir / "response.csv", columns, all_rows)
    write_json(outdir / "study.json", {"study": "response", "vary": key, "values": ordered, "direction": direction,
                                       "settle": settle, "periods": periods, "steps_per_period": steps_per_period,
                                       "tolerance": tolerance, "flight": flight, "shooting": note or "done",
                                       f"bifurcations_{direction}": bifurcations, **case_record(case, changes)})
    write_json(outdir / f"response-{direction}.json", {"rows": rows, "bifurcations": bifurcations})
    marks = bifurcations + _other_bifurcations(outdir, direction)
    chart = plot_response(all_rows, key, outdir / "response.png", marks) if all_rows else None
    return {"rows": all_rows, "key": key, "levels": list(outcomes), "chart": chart, "outdir": str(outdir),
            "bifurcations": bifurcations, "shooting": note or "done"}


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


def _other(outdir: Path, direction: str) -> dict:
    other = DIRECTIONS[1 - DIRECTIONS.index(direction)]
    try:
        data = json.loads((outdir / f"response-{other}.json").read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _other_direction(outdir: Path, direction: str, key: str) -> list[dict]:
    """The rows a sweep the other way left in the folder (response-up.json or response-down.json)."""
    return [r for r in _other(outdir, direction).get("rows", []) if key in r]


def _other_bifurcations(outdir: Path, direction: str) -> list[dict]:
    return list(_other(outdir, direction).get("bifurcations", []))


# -- event-driven levels and shooting (the reduced model without static correction) -----------
def _event_levels(base, key, ordered, direction, settle, periods, tolerance, quiet):
    """Each level iterates the event-driven Poincare map (fem_impact/periodic/shooting.py): exact impact
    instants instead of a time step's. Returns (base, rows, ends): ``ends[f]`` the level's last state."""
    import sys
    import time

    from ...periodic.shooting import ShootingError, impulses, poincare_map, reduced_scene

    rows, ends, x = [], {}, None
    clock = time.perf_counter()
    for i, f in enumerate(ordered):
        case = base.with_changes({key: f})
        try:
            scene = reduced_scene(case)
        except ShootingError as err:
            raise StudyInputError(f"--flight events: {err}") from None
        x = scene.start if x is None else x
        T = 1.0 / f
        states, kicks = [], []
        for j in range(settle + periods):
            impacts: list = []
            x = poincare_map(scene.system, x, T, 1, impacts)
            if j >= settle:
                states.append(x.copy())
                kicks.append((impulses(scene.system, impacts), impacts))
        states = np.array(states)
        k = detect_period(states, tolerance)
        chosen = range(periods - k, periods) if k else range(periods)
        n = scene.system.n
        for j in chosen:
            u, v = scene.probe_rows @ states[j, :n], scene.probe_rows @ states[j, n:]
            row = {"direction": direction, key: f, "period": k, "point": j - chosen.start}
            for p, name in enumerate(scene.probes):
                for c in range(scene.dim):
                    row[f"{name}.u{'xyz'[c]}"] = float(u[p * scene.dim + c])
                for c in range(scene.dim):
                    row[f"{name}.v{'xyz'[c]}"] = float(v[p * scene.dim + c])
            lam, impacts = kicks[j]
            for name, crows in scene.contacts:
                mine = set(np.arange(lam.size)[crows].tolist())   # (rows: a slice or indices)
                row[f"{name}.impulse"] = float(lam[crows].sum())
                row[f"{name}.impacts"] = sum(1 for _, r, _ in impacts if r in mine)
            rows.append(row)
        ends[f] = x.copy()
        if not quiet:
            sys.stderr.write(f"[{i + 1}/{len(ordered)}] {key}={f:.6g}: period {k} ({settle + periods} periods, "
                             f"event-driven; elapsed {time.perf_counter() - clock:.1f} s)\n")
    return base, rows, ends


def _end_state(end):
    """A level's last state [Z, Z']: the event-driven sweep's, or the time-stepped run's checkpoint."""
    if isinstance(end, np.ndarray):
        return end
    import h5py

    with h5py.File(Path(end) / "checkpoint" / "rank-0.h5", "r") as f:
        return np.concatenate([f["integrator"]["U"][()], f["integrator"]["V"][()]])


def shoot_branch(base, key, ordered, ends, rows) -> tuple[dict, str | None]:
    """Along the sweep: the period-1 orbit by shooting, continued from level to level (from the previous
    orbit, else the level's last state), and the settled response's own period where it is longer.
    Per level the columns that response.csv adds; (orbits, None) or ({}, why there is none)."""
    from ...periodic.shooting import ShootingError, impulses, reduced_scene, shoot

    periods = {}
    for row in rows:
        periods[row[key]] = row["period"]
    out, previous = {}, None
    for f in ordered:
        if f not in ends:
            continue
        try:
            scene = reduced_scene(base.with_changes({key: f}))
        except ShootingError as err:
            return {}, f"not done: {err}"
        T = 1.0 / f
        last = _end_state(ends[f])
        info = {}
        for k in sorted({1, periods.get(f, 0)} - {0}):
            start = previous if (k == 1 and previous is not None) else last
            try:
                orbit = shoot(scene.system, start, T, k)
                if k == 1 and previous is not None and orbit.residual > 1e-6:
                    raise ShootingError("no convergence from the previous orbit")
            except ShootingError:
                try:
                    orbit = shoot(scene.system, last, T, k)
                except ShootingError as err:
                    info[f"orbit{k}.note"] = str(err)
                    continue
            mu = orbit.multipliers[np.argsort(-np.abs(orbit.multipliers))]
            info[f"orbit{k}.residual"] = orbit.residual
            info[f"orbit{k}.stable"] = int(orbit.stable)
            info[f"orbit{k}.impulse"] = float(impulses(scene.system, orbit.impacts).sum()) / k
            info[f"orbit{k}.impacts"] = len(orbit.impacts)
            info[f"orbit{k}.min_speed"] = min((s for _, _, s in orbit.impacts), default=0.0)
            for i, m in enumerate(mu[:4], start=1):
                info[f"orbit{k}.multiplier{i}.re"] = float(m.real)
                info[f"orbit{k}.multiplier{i}.im"] = float(m.imag)
            info[f"orbit{k}.det_plus"] = float(np.prod(1.0 + orbit.multipliers).real)    # 0: a multiplier at -1
            info[f"orbit{k}.det_minus"] = float(np.prod(1.0 - orbit.multipliers).real)   # 0: a multiplier at +1
            if k == 1:
                previous = orbit.x
        out[f] = info
    return out, None


def find_bifurcations(key, ordered, orbits) -> list[dict]:
    """Where the period-1 orbit's multipliers cross -1 (period doubling: prod(1 + mu) changes sign) or +1
    (saddle-node: prod(1 - mu)), between two levels of the sweep, the frequency interpolated linearly;
    and grazing, where its slowest impact's speed falls to zero or shooting loses it."""
    found = []
    known = [(f, orbits[f]) for f in ordered if f in orbits and "orbit1.det_plus" in orbits[f]]
    for (f0, a), (f1, b) in zip(known, known[1:]):
        for name, column in (("period_doubling", "orbit1.det_plus"), ("saddle_node", "orbit1.det_minus")):
            g0, g1 = a[column], b[column]
            if g0 * g1 < 0:
                found.append({"kind": name, key: f0 + (f1 - f0) * g0 / (g0 - g1), "between": [f0, f1]})
    for f in ordered:
        info = orbits.get(f, {})
        if "orbit1.note" in info and "vanishing speed" in info["orbit1.note"]:
            found.append({"kind": "grazing", key: f, "between": [f, f]})
    return found


def _write_rows(path: Path, columns, rows) -> None:
    with replacing(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.12g}" if isinstance(v, float) else v for k, v in row.items()})


def plot_response(rows: list[dict], key: str, path: Path, marks=()) -> Path:
    plt = pyplot()
    probe = next((c for c in rows[0] if c.endswith((".ux", ".uy", ".uz"))), None)
    contacts = [c[: -len(".impulse")] for c in rows[0] if c.endswith(".impulse") and not c.startswith("orbit")]
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
        if contacts and any("orbit1.impulse" in r for r in mine):   # the period-1 orbit from shooting
            orbit = sorted({r[key]: r for r in mine if "orbit1.impulse" in r}.values(), key=lambda r: r[key])
            stable = np.array([r["orbit1.stable"] for r in orbit], dtype=bool)
            xs, ys = np.array([r[key] for r in orbit]), np.array([r["orbit1.impulse"] for r in orbit])
            axes[1, 0].plot(xs[stable], ys[stable], "o", mfc="none", ms=7, color="k",
                            label="period-1 orbit (shooting), stable" if direction == "up" else None)
            axes[1, 0].plot(xs[~stable], ys[~stable], "x", ms=7, color="k",
                            label="period-1 orbit (shooting), unstable" if direction == "up" else None)
    for mark in marks:
        for ax in axes[:, 0]:
            ax.axvline(mark[key], ls="--", lw=0.8, color="tab:green" if mark["kind"] == "period_doubling"
                       else "tab:orange" if mark["kind"] == "saddle_node" else "tab:gray")
        axes[0, 0].annotate(mark["kind"].replace("_", " "), (mark[key], 1.0), xycoords=("data", "axes fraction"),
                            rotation=90, va="top", ha="right", fontsize=7)
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
        names = [k for k in rows[0] if k.endswith(".impulse") and not k.startswith("orbit")]
        impulses = [rows[0][k] for k in names]
        per = ", ".join(f"{np.mean([r[k] for r in rows]):.4g}" for k in names)
        lines.append(f"{direction:<9} {value:>14.6g} {rows[0]['period']:>6} {len(rows):>6}  {per if impulses else ''}")
    for mark in result.get("bifurcations", []):
        lines.append(f"{mark['kind'].replace('_', ' ')} at {key} = {mark[key]:.6g} (between {mark['between'][0]:.6g} "
                     f"and {mark['between'][1]:.6g})")
    if result.get("shooting") not in (None, "done"):
        lines.append(f"shooting {result['shooting']}")
    lines.append(f"response.csv, response.png in {result['outdir']}")
    return "\n".join(lines)
