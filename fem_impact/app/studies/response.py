"""``fem-impact study response``: the settled response of a forced case over a sweep of one of its keys.

The forcing frequency is explicit: ``frequency``, an expression of the case's parameters in Hz (by
default the parameter ``f``), evaluated at each level; the varied key is any key of the case (the
frequency's own parameter, an amplitude, a gap, a restitution), the frequency then following it or
fixed. Each level runs ``settle + periods`` forcing periods at ``steps_per_period`` steps a period
(the step follows the frequency), starting from the previous level's last state (natural
continuation: ``initial: {from: ...}``; its last step is a whole number of its own periods, so
every level starts at forcing phase 0). The last ``periods`` periods are sampled on the
stroboscopic Poincare section, the state at forcing phase 0.

The period of the settled response is the smallest k for which the section repeats after k forcing
periods: every point of the window's second half within ``tolerance`` of every other point of its
class modulo k, on the scale of the probes' displacements (and velocities) over the window. A
time-stepped flight puts each impact at the end of a step: a difference of the order of that timing
error (the step times the largest velocity jump, for displacements) is not resolved, so a period is
reported only when every smaller lag differs by more than ``RESOLUTION_MARGIN`` timing errors; else
the period is 0 with a ``period_note`` that says it is not resolved (0 with a note also when none
repeats: quasi-periodic, chaotic or not settled). ``response.csv`` has one row per Poincare point of
the last period found (or all points when none): the direction of the sweep, the varied key,
``frequency``, ``period``, ``period_note``, ``point``, per probe its displacements and velocities
at the section, per contact ``NAME.impulse`` (its impulse over the forcing period that ends at the
point) and ``NAME.impacts`` (their number). ``response.png`` is the bifurcation diagram. A sweep the
other way into the same folder with the same settings (the case, the varied key, the frequency and
every option but the values) keeps the first: both are in response.csv, the chart and study.json; a
sweep with other settings is refused there.
"""

from __future__ import annotations

import csv
import json
import math
import numbers
import os
import sys
import time
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from ...config.case import Case
from ...errors import CaseError, SimulationError, type_name
from ..outdir.writes import replacing
from .common import StudyInputError, case_record, given_changes, pyplot, save_figure, study_folder, write_json
from .levels import Level, run_levels, slug

DIRECTIONS = ("up", "down")
FLIGHTS = ("scheme", "events")
MAX_LEVELS = 1000            # values of one sweep
MAX_PERIODS = 10_000         # --periods: the sampled window
MAX_EVENT_PERIODS = 100_000  # settle + periods of an event-driven level
RESOLUTION_MARGIN = 10       # a lag whose section differs by fewer step timing errors than this is not resolved
ROUND_OFF = 1e-12            # of the element size: displacements below it are round-off
SHOOTING_SECONDS = 300.0     # the time limit of one orbit's shooting
SLOW_SHOOTING = 5.0          # seconds: beyond, shooting says each of Newton's iterations
STUDY_KEYS = ("solver.dt", "solver.t_end", "output.vtk", "initial")   # what the study sets at every level


def response_study(case, vary, outdir, down: bool = False, settle: int = 50, periods: int = 16,
                   steps_per_period: int = 500, tolerance: float = 1e-4, changes=(), quiet: bool = False,
                   allow_failure: bool = False, flight: str = "scheme", shooting: bool = True, frequency=None,
                   shooting_seconds: float = SHOOTING_SECONDS) -> dict:
    """Sweep ``vary`` (``"KEY=V1,V2,..."`` or ``"KEY=A,B,...,Z"``) at the forcing frequency ``frequency``
    (an expression of the case's parameters in Hz; default the parameter ``f``) into ``outdir``.

    Returns ``rows`` (response.csv's, both directions), ``key``, ``levels``, ``bifurcations``,
    ``shooting``, ``chart`` and ``outdir``. Raises TypeError for an argument of a wrong Python type,
    StudyInputError (a ValueError) for bad options and CaseError for values the case refuses, before
    anything is written.
    """
    _check_types(case, vary, outdir, down, settle, periods, steps_per_period, tolerance, quiet, allow_failure,
                 flight, shooting, frequency, shooting_seconds)
    changes = _changes_argument(changes)
    key, values = parse_vary(vary)
    for name, value, least, most in (("--settle", settle, 0, None), ("--periods", periods, 2, MAX_PERIODS),
                                     ("--steps-per-period", steps_per_period, 4, None)):
        if value < least or (most is not None and value > most):
            raise StudyInputError(f"{name} {value}: give at least {least}" + (f" and at most {most}" if most else ""))
    if not (tolerance > 0 and math.isfinite(tolerance)):
        raise StudyInputError(f"--tolerance {tolerance}: give a positive number")
    if not shooting_seconds > 0:
        raise StudyInputError(f"--shooting-time {shooting_seconds}: give a positive number of seconds")
    if flight not in FLIGHTS:
        raise StudyInputError(f"--flight {flight}: scheme (the case's time stepping) or events (event-driven)")
    if flight == "events" and settle + periods > MAX_EVENT_PERIODS:
        raise StudyInputError(f"--settle {settle} --periods {periods}: an event-driven level flies at most "
                              f"{MAX_EVENT_PERIODS} forcing periods")
    outdir = Path(outdir)
    with study_folder(outdir, "study response", case):
        given = given_changes(changes)
        _refuse_study_keys(key, given)
        base = case.with_changes(given) if given else case
        expression = frequency_expression(base, frequency)
        direction = "down" if down else "up"
        ordered = sorted(values, reverse=down)
        cases = {}
        for v in ordered:   # (CaseError: a key the case does not have, a value it refuses, before anything runs)
            cases[v] = base.with_changes({key: v})
        freq = {v: forcing_frequency(cases[v], expression, key, v) for v in ordered}
        settings = _settings(base, key, expression, settle, periods, steps_per_period, tolerance, flight)
        other = _other_sweep(outdir, direction, settings)
        if flight == "scheme":
            _check_sizes(cases, freq, key, settle, periods, steps_per_period, outdir)
        say = (lambda line: None) if quiet else (lambda line: (sys.stderr.write(line + "\n"), sys.stderr.flush()))
        floor = ROUND_OFF * _element_size(base)
        outcomes = ()
        if flight == "events":
            rows, ends, candidates = _event_levels(cases, key, ordered, freq, direction, settle, periods, tolerance,
                                                   floor, say)
        else:
            levels, previous = [], None
            for i, v in enumerate(ordered):
                f = freq[v]
                name = f"{direction}-{i:03d}-{slug(key)}={v:.6g}"
                level_changes = {key: v, "solver.dt": 1.0 / (f * steps_per_period),
                                 "solver.t_end": (settle + periods) / f, "output.vtk": False}
                if previous is not None:
                    level_changes["initial"] = {"from": str((outdir / "levels" / previous).resolve())}
                levels.append(Level(name, level_changes, info={"direction": direction, "value": v, "index": i,
                                                               "frequency": f}))
                previous = name
            outcomes = run_levels(base, levels, outdir, jobs=1, allow_failure=allow_failure, quiet=quiet)
            rows, ends, candidates = [], {}, {}
            for outcome in outcomes:
                v = outcome.level.info["value"]
                if outcome.ok:
                    mine, candidates[v] = _section(outcome.folder, key, v, freq[v], direction, settle, periods,
                                                   steps_per_period, tolerance, floor)
                    rows += mine
                    ends[v] = outcome.folder
                elif outcome.status == "skipped" and not _after_failure(outcome, outcomes):
                    raise StudyInputError(f"level {outcome.level.label}: {outcome.reason}")
            if not ends:
                first = next(o for o in outcomes if not o.ok)
                raise SimulationError(f"no level of the sweep completed (level {first.level.label}: {first.reason})")
        note = "not asked (--no-shooting)"
        orbits = {}
        if shooting:
            orbits, note = shoot_branch(cases, key, ordered, freq, ends, rows, shooting_seconds, say, candidates)
            for row in rows:
                row.update(orbits.get(row[key], {}))
        return _finish(case, changes, outdir, key, expression, ordered, freq, direction, settings, rows, orbits, note,
                       other, outcomes)


def _check_types(case, vary, outdir, down, settle, periods, steps, tolerance, quiet, allow_failure, flight,
                 shooting, frequency, seconds) -> None:
    """TypeError, saying what response_study() takes, for an argument of a wrong Python type."""
    call = "response_study()"

    def wrong(takes, value):
        return TypeError(f"{call} takes {takes}, got {type_name(value)}")

    if not isinstance(case, Case):
        raise wrong("case as a Case: fem_impact.load_case(path) or Case.from_dict(data)", case)
    if not isinstance(vary, str):
        raise wrong("vary as a string 'KEY=V1,V2,...', e.g. 'parameters.f=0.45,0.5'", vary)
    if not isinstance(outdir, (str, os.PathLike)):
        raise wrong("outdir as a folder (str or os.PathLike)", outdir)
    for name, value in (("down", down), ("quiet", quiet), ("allow_failure", allow_failure), ("shooting", shooting)):
        if not isinstance(value, bool):
            raise wrong(f"{name} as true or false", value)
    for name, value in (("settle", settle), ("periods", periods), ("steps_per_period", steps)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise wrong(f"{name} as a whole number", value)
    for name, value in (("tolerance", tolerance), ("shooting_seconds", seconds)):
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise wrong(f"{name} as a number", value)
    if not isinstance(flight, str):
        raise wrong("flight as 'scheme' or 'events'", flight)
    if frequency is not None and (isinstance(frequency, bool) or not isinstance(frequency, (str, numbers.Real))):
        raise wrong("frequency as an expression of the case's parameters (a string), a number of Hz or None", frequency)


def _changes_argument(changes):
    """``changes`` as a mapping of key paths or a list of ``KEY.PATH=VALUE`` strings; TypeError otherwise."""
    takes = "changes as a mapping {'key.path': value} or a list of 'KEY.PATH=VALUE' strings"
    if isinstance(changes, Mapping):
        if all(isinstance(k, str) for k in changes):
            return changes
    elif not isinstance(changes, (str, bytes)) and isinstance(changes, Iterable):
        changes = list(changes)
        if all(isinstance(c, str) for c in changes):
            return changes
    raise TypeError(f"response_study() takes {takes}, got {type_name(changes)}")


# -- the options -------------------------------------------------------------------------------
VARY_FORMS = "KEY=V1,V2,... or KEY=START,NEXT,...,END (evenly spaced), e.g. parameters.f=40,45,...,60"


def parse_vary(vary: str) -> tuple[str, list]:
    """``KEY=V1,V2,...`` or ``KEY=A,B,...,Z`` (the values from A in steps of B - A up to Z, which the steps
    must reach) as (key, values): numbers as YAML reads them (whole numbers stay whole), all different."""
    from ...config.case import yaml_value

    key, equals, text = str(vary).partition("=")
    key = key.strip()
    if not equals or not key or not text.strip():
        raise StudyInputError(f"--vary {vary}: expected {VARY_FORMS}")
    items = [item.strip() for item in text.split(",")]

    def number(item):
        try:
            value = yaml_value(item) if item else None
        except Exception:
            value = None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise StudyInputError(f"--vary {vary}: {item!r} is not a number (expected {VARY_FORMS})")
        return value

    if "..." in items:
        where = items.index("...")
        if items.count("...") > 1 or where < 2 or where != len(items) - 2:
            raise StudyInputError(f"--vary {vary}: the ellipsis goes between two or more evenly spaced first "
                                  "values and the last one, e.g. parameters.f=40,45,...,60")
        head, end = [number(i) for i in items[:where]], number(items[-1])
        step = head[1] - head[0]
        size = max(abs(v) for v in (*head, end))
        if step == 0 or any(abs((b - a) - step) > 1e-9 * size for a, b in zip(head, head[1:])):
            raise StudyInputError(f"--vary {vary}: the values before '...' must be evenly spaced and different")
        count = (end - head[0]) / step
        if not count >= len(head) - 1 or abs(count - round(count)) > 1e-6 or count + 1 > MAX_LEVELS:
            raise StudyInputError(
                f"--vary {vary}: " + (f"more than {MAX_LEVELS} values" if count + 1 > MAX_LEVELS else
                                      f"steps of {step:g} from {head[0]:g} do not reach {end:g}"))
        whole = all(isinstance(v, int) for v in (*head, end))
        values = [head[0] + j * step if whole else float(f"{head[0] + j * step:.12g}")
                  for j in range(round(count) + 1)]
    else:
        values = [number(item) for item in items]
    if len(values) > MAX_LEVELS:
        raise StudyInputError(f"--vary {vary}: more than {MAX_LEVELS} values")
    if len(set(values)) != len(values):
        raise StudyInputError(f"--vary {vary}: a value is given twice")
    return key, values


def _refuse_study_keys(key: str, given: dict) -> None:
    """The keys every level's run gets from the study: not to be varied, nor set for every level."""
    def study_key(k):
        return next((s for s in STUDY_KEYS if k == s or k.startswith(s + ".")), None)

    why = {"solver.dt": "from --steps-per-period and the forcing frequency",
           "solver.t_end": "from --settle, --periods and the forcing frequency",
           "output.vtk": "to false (no fields are written)",
           "initial": "to the previous level's last state (the first level starts from the case's)"}
    if study_key(key):
        raise StudyInputError(f"--vary {key}: the study sets {study_key(key)} at every level, {why[study_key(key)]}")
    for k in given:
        if study_key(k) in ("solver.dt", "solver.t_end", "output.vtk"):
            raise StudyInputError(f"--set {k}: the study sets {study_key(k)} at every level, {why[study_key(k)]}")


def frequency_expression(case, frequency) -> str:
    """The forcing frequency's expression (Hz, of the case's parameters): the given one, else ``f``
    when the case has that parameter. Its parameters must be used by a load or a support's motion."""
    from ...expressions import ExpressionError, parse_expression

    if frequency is None:
        if "f" not in case.parameters:
            raise StudyInputError(
                "--frequency: the case has no parameter f; give the forcing frequency in Hz as an expression of "
                f"its parameters ({', '.join(sorted(case.parameters)) or 'none'}) or a number, e.g. --frequency 50")
        frequency = "f"
    text = frequency if isinstance(frequency, str) else repr(float(frequency))
    try:
        expr = parse_expression(text, (), case.parameters)
    except ExpressionError as err:
        raise StudyInputError(f"--frequency {text}: {err}") from None
    forcing = set()
    for e in _forcing_expressions(case):
        forcing |= e.constants
    unused = sorted(expr.constants - forcing)
    if unused:
        raise StudyInputError(f"--frequency {text}: no load or support motion of the case varies in time with "
                              f"{', '.join(unused)}: it is not the frequency of a forcing")
    return text.strip()


def _forcing_expressions(case):
    """The case's expressions of time: loads and supports' prescribed motion."""
    for _, expr in case.expressions():
        if "t" in expr.variables:
            yield expr
    for support in case.supports:
        for expr in support.displacement or ():
            if "t" in expr.variables:
                yield expr


def forcing_frequency(case, expression: str, key: str, value) -> float:
    """The forcing frequency (Hz) of a level's case: positive and finite, else StudyInputError."""
    from ...expressions import parse_expression

    f = parse_expression(expression, (), case.parameters).evaluate()
    if not (math.isfinite(f) and f > 0):
        raise StudyInputError(f"--frequency {expression} = {f:g} at {key}={value:g}: the forcing frequency must be a "
                              "positive number of Hz")
    return f


def _element_size(case) -> float:
    from .resolution import mesh_size

    try:
        return float(mesh_size(case))
    except Exception:   # (a mesh file gmsh cannot read: the run itself will say so)
        return 1.0


def _check_sizes(cases, freq, key, settle, periods, steps, outdir) -> None:
    """Every level within the size guard (fem_impact.app.limits), before any runs: else the option to change."""
    from mpi4py import MPI

    from ..limits import FORCE, check_limits

    for v, case in cases.items():
        f = freq[v]
        level = case.with_changes({"solver.dt": 1.0 / (f * steps), "solver.t_end": (settle + periods) / f,
                                   "output.vtk": False})
        try:
            check_limits(level, outdir, MPI.COMM_SELF)
        except CaseError as err:
            why = err.message.split(" (from the change")[0].replace(FORCE, "")
            raise StudyInputError(f"level {key}={v:g} ({settle} + {periods} forcing periods of {steps} steps at "
                                  f"{f:g} Hz): {why}; lower --settle, --periods or --steps-per-period") from None


def _after_failure(outcome, outcomes) -> bool:
    """A level that could not start because a level before it failed (--allow-failure): its start is missing."""
    index = outcome.level.info["index"]
    return any(o.status == "failed" and o.level.info["index"] < index for o in outcomes)


# -- the settings of a sweep, and the other direction's --------------------------------------------
def _flat(data, prefix="") -> dict:
    if isinstance(data, dict):
        out = {}
        for k, v in data.items():
            out.update(_flat(v, f"{prefix}{k}."))
        return out
    if isinstance(data, list):
        out = {}
        for i, v in enumerate(data):
            out.update(_flat(v, f"{prefix}{i}."))
        return out or {prefix[:-1]: []}
    return {prefix[:-1]: data}


def _settings(base, key, expression, settle, periods, steps, tolerance, flight) -> dict:
    """What makes two sweeps of one folder comparable: the case (its varied key and what the study sets
    aside), the varied key, the frequency and the options but the values."""
    resolved = json.loads(json.dumps(base.resolved(), default=str))
    keep = {k: v for k, v in _flat(resolved).items()
            if k != key and not k.startswith(key + ".") and not any(k == s or k.startswith(s + ".")
                                                                     for s in STUDY_KEYS)}
    return {"vary": key, "frequency": expression, "settle": settle, "periods": periods,
            "steps_per_period": steps if flight == "scheme" else None, "tolerance": tolerance, "flight": flight,
            "case": keep}


def _other_sweep(outdir: Path, direction: str, settings: dict) -> dict:
    """The other direction's sweep in the folder (response-up.json or response-down.json), if any: refused
    (StudyInputError) when its settings differ from this sweep's."""
    other = DIRECTIONS[1 - DIRECTIONS.index(direction)]
    path = outdir / f"response-{other}.json"
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        data = None
    theirs = data.get("settings") if isinstance(data, dict) else None
    if not isinstance(theirs, dict):
        raise StudyInputError(f"{outdir}: holds a sweep {other} whose settings are not recorded (an earlier version "
                              f"or a damaged {path.name}): sweep into another folder (-o), or remove {path.name}")
    differ = [name for name in ("vary", "frequency", "flight", "settle", "periods", "steps_per_period", "tolerance")
              if theirs.get(name) != settings[name]]
    mine, case = settings["case"], theirs.get("case") if isinstance(theirs.get("case"), dict) else {}
    differ += sorted(k for k in set(mine) | set(case) if mine.get(k, "(none)") != case.get(k, "(none)"))
    if differ:
        shown = "; ".join(f"{name}: {_setting(theirs, name)} there, {_setting(settings, name)} here"
                          for name in differ[:3])
        more = f" (and {len(differ) - 3} more)" if len(differ) > 3 else ""
        raise StudyInputError(f"{outdir}: holds a sweep {other} with other settings ({shown}{more}): the sweeps of "
                              "one folder must differ in their values only; sweep into another folder (-o)")
    return data


def _setting(settings: dict, name: str):
    if name in settings:
        return settings[name]
    return settings.get("case", {}).get(name, "(none)")


# -- the Poincare section and its period ------------------------------------------------------------
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
    kinds = np.array([name.rsplit(".", 1)[1][0] for name in names])
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
    columns = np.column_stack([h[p][window] for p in probes]) if probes else np.zeros((1, 0))
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


# -- event-driven levels and shooting (the reduced model without static correction) -----------
def _event_levels(cases, key, ordered, freq, direction, settle, periods, tolerance, floor, say):
    """Each level iterates the event-driven Poincare map (fem_impact/periodic/shooting.py): exact impact
    instants instead of a time step's. Returns (rows, ends, candidates): ``ends[v]`` the level's last state."""
    from ...periodic.shooting import ShootingError, impulses, poincare_map, reduced_scene

    rows, ends, candidates, x = [], {}, {}, None
    clock = time.perf_counter()
    for i, v in enumerate(ordered):
        try:
            scene = reduced_scene(cases[v])
        except ShootingError as err:
            raise StudyInputError(f"--flight events: {err}") from None
        x = scene.start if x is None else x
        f = freq[v]
        T = 1.0 / f
        states, kicks = [], []
        try:
            for j in range(settle + periods):
                impacts: list = []
                held = np.zeros(scene.system.P.shape[0])
                x = poincare_map(scene.system, x, T, 1, impacts, held=held)
                if j >= settle:
                    states.append(x.copy())
                    kicks.append((impulses(scene.system, impacts, held), impacts))
        except ShootingError as err:
            raise StudyInputError(f"--flight events at {key}={v:g}: {err}") from None
        states = np.array(states)
        n = scene.system.n
        names = [f"{name}.{kind}{'xyz'[c]}" for name in scene.probes for kind in "uv" for c in range(scene.dim)]
        section = np.zeros((periods, len(names)))
        for j in range(periods):
            u, w = scene.probe_rows @ states[j, :n], scene.probe_rows @ states[j, n:]
            for p, name in enumerate(scene.probes):
                for c in range(scene.dim):
                    section[j, names.index(f"{name}.u{'xyz'[c]}")] = u[p * scene.dim + c]
                    section[j, names.index(f"{name}.v{'xyz'[c]}")] = w[p * scene.dim + c]
        tol = section_tolerance(names, section, 2 * np.pi * f, tolerance, floor)
        k, note, candidates[v] = period_of(section, tol)
        chosen = range(periods - k, periods) if k else range(periods)
        for j in chosen:
            row = {"direction": direction, key: v, "frequency": f, "period": k, "period_note": note,
                   "point": j - chosen.start}
            row.update({name: float(section[j, c]) for c, name in enumerate(names)})
            lam, impacts = kicks[j]
            for name, crows in scene.contacts:
                mine = set(np.arange(lam.size)[crows].tolist())   # (rows: a slice or indices)
                row[f"{name}.impulse"] = float(lam[crows].sum())
                row[f"{name}.impacts"] = sum(1 for _, r, _ in impacts if r in mine)
            rows.append(row)
        ends[v] = x.copy()
        say(f"[{i + 1}/{len(ordered)}] {key}={v:.6g}: period {k}{' (' + note + ')' if note else ''} "
            f"({settle + periods} periods at {f:.6g} Hz, event-driven; elapsed {time.perf_counter() - clock:.1f} s)")
    return rows, ends, candidates


def _end_state(end):
    """A level's last state [Z, Z']: the event-driven sweep's, or the time-stepped run's checkpoint."""
    if isinstance(end, np.ndarray):
        return end
    import h5py

    with h5py.File(Path(end) / "checkpoint" / "rank-0.h5", "r") as f:
        return np.concatenate([f["integrator"]["U"][()], f["integrator"]["V"][()]])


def shoot_branch(cases, key, ordered, freq, ends, rows, seconds=SHOOTING_SECONDS, say=None,
                 candidates=None) -> tuple[dict, str]:
    """Along the sweep: the period-1 orbit by shooting, continued from level to level (from the previous
    orbit, else the level's last state), and the settled response's own period where it is longer (or
    the periods an unresolved section leaves open). Per level the columns response.csv adds; (orbits,
    "done") or ({}, "not done: why")."""
    from ...periodic.shooting import ShootingError, impulses, least_period, reduced_scene, shoot

    say = say or (lambda line: None)
    clock = time.perf_counter()
    periods, candidates = {}, candidates or {}
    for row in rows:
        periods[row[key]] = row["period"]
    out, previous = {}, None
    for v in ordered:
        if v not in ends:
            continue
        try:
            scene = reduced_scene(cases[v])
        except ShootingError as err:
            return {}, f"not done: {err}"
        T = 1.0 / freq[v]
        last = _end_state(ends[v])
        info, said = {}, []
        for k in sorted({1, periods.get(v, 0), *candidates.get(v, [])} - {0}):
            def progress(iteration, residual, elapsed, k=k):   # (a line per iteration once it takes a while)
                if elapsed > SLOW_SHOOTING:
                    say(f"  shooting the period-{k} orbit at {key}={v:.6g}: Newton iteration {iteration}, residual "
                        f"{residual:.3g} of the state's scale ({elapsed:.0f} s, limit {seconds:g} s)")

            start = previous if (k == 1 and previous is not None) else last
            try:
                orbit = shoot(scene.system, start, T, k, seconds=seconds, progress=progress)
                if k == 1 and previous is not None and orbit.residual > 1e-6:
                    raise ShootingError("no convergence from the previous orbit")
            except ShootingError as first:
                if start is last:
                    info[f"orbit{k}.note"] = str(first)
                    said.append(f"period {k}: none ({first})")
                    continue
                try:
                    orbit = shoot(scene.system, last, T, k, seconds=seconds, progress=progress)
                except ShootingError as err:
                    info[f"orbit{k}.note"] = str(err)
                    said.append(f"period {k}: none ({err})")
                    continue
            if k > 1:
                try:
                    m = least_period(scene.system, orbit, T, seconds)
                except ShootingError as err:
                    m, why = None, str(err)
                if m != k:
                    info[f"orbit{k}.note"] = (f"the orbit found is the period-{m} orbit" if m else
                                              f"its least period is not known: {why}")
                    said.append(f"period {k}: " + (f"the period-{m} orbit" if m else "least period not known"))
                    continue
            mu = orbit.multipliers[np.argsort(-np.abs(orbit.multipliers))]
            info[f"orbit{k}.residual"] = orbit.residual
            info[f"orbit{k}.stable"] = int(orbit.stable)
            info[f"orbit{k}.impulse"] = float(impulses(scene.system, orbit.impacts, orbit.held).sum()) / k
            info[f"orbit{k}.impacts"] = len(orbit.impacts)
            info[f"orbit{k}.min_speed"] = min((s for _, _, s in orbit.impacts), default=0.0)
            for i, m in enumerate(mu[:4], start=1):
                info[f"orbit{k}.multiplier{i}.re"] = float(m.real)
                info[f"orbit{k}.multiplier{i}.im"] = float(m.imag)
            info[f"orbit{k}.det_plus"] = float(np.prod(1.0 + orbit.multipliers).real)    # 0: a multiplier at -1
            info[f"orbit{k}.det_minus"] = float(np.prod(1.0 - orbit.multipliers).real)   # 0: a multiplier at +1
            if orbit.unseen:
                info[f"orbit{k}.unseen_modes"] = orbit.unseen
            if k == 1:
                previous = orbit.x
            said.append(f"period {k}: {'stable' if orbit.stable else 'unstable'} ({orbit.iterations} iterations)")
        out[v] = info
        say(f"shooting at {key}={v:.6g}: " + "; ".join(said) + f" (elapsed {time.perf_counter() - clock:.1f} s)")
    return out, "done"


def find_bifurcations(key, ordered, orbits) -> list[dict]:
    """Where the period-1 orbit's multipliers cross -1 (period doubling: prod(1 + mu) changes sign) or +1
    (saddle-node: prod(1 - mu)), between two levels of the sweep, the value interpolated linearly;
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


def _finish(case, changes, outdir, key, expression, ordered, freq, direction, settings, rows, orbits, note, other,
            outcomes):
    """response.csv, study.json, response-DIRECTION.json, response.png (both directions of the folder)."""
    bifurcations = find_bifurcations(key, ordered, orbits)
    for row in rows:   # response.csv says where: on the rows of the level past each crossing
        marks = [f"{b['kind']} at {b[key]:.6g}" for b in bifurcations if b["between"][1] == row[key]]
        if bifurcations:
            row["bifurcation"] = "; ".join(marks)
    outdir.mkdir(parents=True, exist_ok=True)   # (the event-driven levels write no level folder)
    theirs = [r for r in other.get("rows", []) if isinstance(r, dict) and key in r]
    all_rows = sorted(theirs + rows, key=lambda r: (r["direction"], r[key], r["point"]))
    columns = list(dict.fromkeys(c for r in all_rows for c in r)) if all_rows else \
        ["direction", key, "frequency", "period", "period_note", "point"]
    _write_rows(outdir / "response.csv", columns, all_rows)
    sweep = {"values": ordered, "frequencies": [freq[v] for v in ordered], "shooting": note,
             "bifurcations": bifurcations, "settings": settings,
             "levels": {o.level.info["value"]: o.status for o in outcomes} if outcomes else None}
    write_json(outdir / f"response-{direction}.json", {**sweep, "rows": rows})
    sweeps = {direction: {k: v for k, v in sweep.items() if k != "settings"}}
    if other:
        sweeps[DIRECTIONS[1 - DIRECTIONS.index(direction)]] = {k: other.get(k) for k in sweep if k != "settings"}
    s = settings
    write_json(outdir / "study.json", {"study": "response", "vary": key, "frequency": expression,
                                       "settle": s["settle"], "periods": s["periods"],
                                       "steps_per_period": s["steps_per_period"], "tolerance": s["tolerance"],
                                       "flight": s["flight"], "sweeps": sweeps, "direction": direction,
                                       "values": ordered, "shooting": note,
                                       f"bifurcations_{direction}": bifurcations,
                                       **({f"bifurcations_{d}": sweeps[d].get("bifurcations") or []
                                           for d in sweeps if d != direction}),
                                       **case_record(case, changes)})
    marks = bifurcations + list(other.get("bifurcations") or [])
    frequency_axis = key == f"parameters.{expression}"
    chart = plot_response(all_rows, key, outdir / "response.png", marks, frequency_axis) if all_rows else None
    missing = [(direction, o.level.info["value"], "FAILED: " + o.reason if o.status == "failed" else
                "not run: a level before it failed, and each level starts from the one before")
               for o in outcomes if not o.ok]
    return {"rows": all_rows, "key": key, "frequency": expression, "levels": list(outcomes), "chart": chart,
            "outdir": str(outdir), "bifurcations": bifurcations, "shooting": note, "missing": missing}


def _write_rows(path: Path, columns, rows) -> None:
    with replacing(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.12g}" if isinstance(v, float) else v for k, v in row.items()})


def plot_response(rows: list[dict], key: str, path: Path, marks=(), frequency_axis: bool = True) -> Path:
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
    axes[-1, 0].set_xlabel(f"{key} (forcing frequency, Hz)" if frequency_axis else key)
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return path


def format_response(result: dict) -> str:
    """The table printed at the end: per level the period found (``?``: not resolved) and the impulses."""
    key = result["key"]
    frequency = result.get("frequency")
    own = frequency is None or key == f"parameters.{frequency}"
    lines = [f"{'direction':<9} {key:>14} " + ("" if own else f"{'Hz':>10} ") +
             f"{'period':>6} {'points':>6}  impulse per period"]
    seen, notes = {}, []
    for r in result["rows"]:
        seen.setdefault((r["direction"], r[key]), []).append(r)
    for (direction, value), rows in sorted(seen.items()):
        names = [k for k in rows[0] if k.endswith(".impulse") and not k.startswith("orbit")]
        per = ", ".join(f"{np.mean([r[k] for r in rows]):.4g}" for k in names)
        note = rows[0].get("period_note") or ""
        period = "?" if note.startswith("not resolved") else rows[0]["period"]
        hz = "" if own else f"{rows[0].get('frequency', float('nan')):>10.6g} "
        lines.append(f"{direction:<9} {value:>14.6g} {hz}{period:>6} {len(rows):>6}  {per}")
        if period == "?":
            notes.append(f"{direction} {key}={value:.6g}: period {note}")
    lines += notes
    lines += [f"{direction} {key}={value:.6g}: {why}" for direction, value, why in result.get("missing", [])]
    for mark in result.get("bifurcations", []):
        lines.append(f"{mark['kind'].replace('_', ' ')} at {key} = {mark[key]:.6g} (between {mark['between'][0]:.6g} "
                     f"and {mark['between'][1]:.6g})")
    if result.get("shooting") not in (None, "done"):
        lines.append(f"shooting {result['shooting']}")
    lines.append(f"response.csv, response.png in {result['outdir']}")
    return "\n".join(lines)
