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

import json
import math
import numbers
import os
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path

from ...config.case import Case
from ...errors import CaseError, SimulationError, type_name
from .common import StudyInputError, given_changes, study_folder
from .levels import Level, run_levels, slug
from .response_orbits import SHOOTING_SECONDS, _event_levels, shoot_branch
from .response_output import DIRECTIONS, _finish
from .response_period import _section

FLIGHTS = ("scheme", "events")
MAX_LEVELS = 1000            # values of one sweep
MAX_PERIODS = 10_000         # --periods: the sampled window
MAX_EVENT_PERIODS = 100_000  # settle + periods of an event-driven level
ROUND_OFF = 1e-12            # of the element size: displacements below it are round-off
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
