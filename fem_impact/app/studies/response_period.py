"""The stroboscopic Poincare section of a level's settled response and its period: the smallest lag whose
classes of points repeat within the tolerance, reported only when the flights' timing error resolves it."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from .common import StudyInputError

RESOLUTION_MARGIN = 10       # a lag whose section differs by fewer step timing errors than this is not resolved


def period_of(states: np.ndarray, tol: np.ndarray, timing: np.ndarray | None = None,
              margin: float = RESOLUTION_MARGIN) -> tuple[int, str, list]:
    """The period of a section (``states``: points x columns) and why there is none.

    ``tol``: per column, how close two points of a period's class must be; ``timing``: per column, the
    flights' timing error (None: exact flights). Returns (k, note, candidates): k the smallest lag
    whose classes (points k apart, over the window's second half and the k before it) each lie within
    ``tol``, with an empty note, when every smaller lag differs by more than ``margin`` timing errors;
    else 0, the note (not resolved, or none), and the lags that repeat within the flights' accuracy.
    """
    n, c = states.shape
    if c == 0:
        return 0, "no probe: the section has no columns", []
    if n < 2:
        return 0, "fewer than 2 sampled periods", []
    tol = np.maximum(np.asarray(tol, float), 1e-300)
    spreads = []
    for k in range(1, n // 2 + 1):
        window = states[max(k, n // 2) - k:]
        rows = -(-window.shape[0] // k)
        padded = np.full((rows * k, c), np.nan)
        padded[:window.shape[0]] = window
        classes = padded.reshape(rows, k, c)
        spreads.append(np.nanmax(np.nanmax(classes, axis=0) - np.nanmin(classes, axis=0), axis=0))
    spreads = np.array(spreads)                                   # lags x columns
    within = np.all(spreads <= tol, axis=1)
    timing = None if timing is None else np.maximum(np.asarray(timing, float), 1e-300)
    # per lag: how many timing errors its classes span (in the column that tells them apart best)
    close = np.max(spreads / timing, axis=1) if timing is not None else np.full(len(spreads), np.inf)
    if np.any(within):
        k = int(np.argmax(within)) + 1
        unresolved = [m for m in range(1, k) if close[m - 1] <= margin]
        if not unresolved:
            return k, "", []
        m = unresolved[0]
        return 0, (f"not resolved: period {k} within the tolerance, but the section repeats after {m} within "
                   f"{close[m - 1]:.2g} time-step timing errors: the step cannot tell them apart (more "
                   "--steps-per-period, or --flight events)"), [m, k]
    near = [k for k in range(1, len(close) + 1) if close[k - 1] <= margin]
    if near:
        k = near[0]
        return 0, (f"not resolved: the section repeats after {k} periods within {close[k - 1]:.2g} time-step "
                   "timing errors, not within the tolerance (not settled: more --settle; or the step's jitter: more "
                   "--steps-per-period, or --flight events)"), [k]
    return 0, f"no period up to {n // 2} within the tolerance (quasi-periodic, chaotic or not settled)", []


def detect_period(states: np.ndarray, tolerance: float) -> int:
    """The smallest k <= n / 2 whose classes of points k apart lie within ``tolerance`` of the largest
    magnitude of the section (exact points); 0 when none."""
    scale = max(np.abs(states).max(initial=0.0), 1e-300)
    return period_of(np.asarray(states, float), np.full(states.shape[1], tolerance * scale))[0]


def _kinds(names) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the displacement and velocity columns among probe columns ``P.ux`` ... ``P.vz``."""
    kinds = np.array([name.rsplit(".", 1)[1][0] for name in names], dtype=str)   # (str: a case without probes too)
    return kinds == "u", kinds == "v"


def section_tolerance(names, values: np.ndarray, omega: float, tolerance: float, floor: float) -> np.ndarray:
    """Per probe column: ``tolerance`` of its probe's displacement scale (the largest of its displacements in
    ``values``, or of its velocities / omega) or velocity scale (omega times it), never below round-off
    (``floor``): the components of a probe share its scale, so that one it does not move in stays round-off."""
    u, v = _kinds(names)
    probe = np.array([name.rsplit(".", 1)[0] for name in names])
    tol = np.empty(len(names))
    for p in set(probe.tolist()):
        mine = probe == p
        scale = max(float(np.abs(values[:, mine & u]).max(initial=0.0)),
                    float(np.abs(values[:, mine & v]).max(initial=0.0)) / omega, floor)
        tol[mine] = tolerance * np.where(u[mine], scale, omega * scale)
    return tol


def _probe_columns(names) -> list[str]:
    return [name for name in names if "." in name and name.rsplit(".", 1)[1][:1] in ("u", "v")
            and name.rsplit(".", 1)[1][1:] in ("x", "y", "z") and not name.startswith("orbit")]


def section_rows(folder: Path, key: str, value, frequency: float, direction: str, settle: int, periods: int,
                 steps: int, tolerance: float, floor: float = 0.0) -> list[dict]:
    """The Poincare points of one level's run (its history.csv and impacts.csv) as response.csv rows."""
    return _section(folder, key, value, frequency, direction, settle, periods, steps, tolerance, floor)[0]


def _section(folder, key, value, frequency, direction, settle, periods, steps, tolerance, floor):
    """(rows, candidates): section_rows and the periods that repeat within the flights' accuracy."""
    from ..plots import history_columns

    h = history_columns(folder)
    t = h["t"]
    section = np.arange(settle + 1, settle + periods + 1) * steps   # rows at phase 0 ending each sampled period
    if section[-1] >= t.size:
        raise StudyInputError(f"{folder}: the run has {t.size - 1} steps, the section needs {section[-1]}")
    probes = _probe_columns(h)
    contacts = [name[: -len(".impulse")] for name in h if name.endswith(".impulse")]
    states = np.column_stack([h[p][section] for p in probes]) if probes else np.zeros((periods, 0))
    window = slice(section[0] - steps, section[-1] + 1)
    u, v = _kinds(probes)
    columns = np.column_stack([h[p][window] for p in probes]) if probes else np.zeros((t[window].size, 0))
    omega = 2 * np.pi * frequency
    tol = section_tolerance(probes, columns, omega, tolerance, floor)
    # The timing error of an impact placed at the end of a step: the step times the velocity's jump in
    # displacement, the velocity's change over a step without impulse (times 1 + r <= 2) in velocity.
    dt = 1.0 / (frequency * steps)
    jumps = np.abs(np.diff(columns[:, v], axis=0)) if v.any() else np.zeros((0, 0))
    smooth = np.ones(columns.shape[0] - 1, dtype=bool)
    for c in contacts:
        smooth &= h[f"{c}.impulse"][window][1:] == 0
    if jumps.size:
        timing_u = dt * jumps.max()
        timing_v = 2 * (jumps[smooth] if smooth.any() else jumps).max()
    else:
        timing_u = timing_v = 0.0
    timing = np.where(u, max(timing_u, floor), max(timing_v, omega * floor))
    k, note, candidates = period_of(states, tol, timing)
    impacts = _impact_times(folder)
    period = 1.0 / frequency
    rows = []
    chosen = range(periods - k, periods) if k else range(periods)
    for j in chosen:
        row = {"direction": direction, key: value, "frequency": frequency, "period": k, "period_note": note,
               "point": j - chosen.start}
        row.update({p: float(states[j, i]) for i, p in enumerate(probes)})
        first, last = section[j] - steps, section[j]
        for c in contacts:
            row[f"{c}.impulse"] = float(h[f"{c}.impulse"][first + 1:last + 1].sum())
            t0, t1 = t[first], t[last]
            row[f"{c}.impacts"] = int(np.count_nonzero((impacts.get(c, np.zeros(0)) > t0 + 1e-9 * period)
                                                       & (impacts.get(c, np.zeros(0)) <= t1 + 1e-9 * period)))
        rows.append(row)
    return rows, candidates


def _impact_times(folder: Path) -> dict[str, np.ndarray]:
    times: dict[str, list] = {}
    path = folder / "impacts.csv"
    if path.is_file():
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                times.setdefault(row["contact"], []).append(float(row["t"]))
    return {name: np.array(v) for name, v in times.items()}
