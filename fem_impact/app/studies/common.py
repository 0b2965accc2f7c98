"""What the three studies share: input errors, the output folder, atomic CSV/JSON/PNG writing,
the per-level figures (resolution, times, errors) and the log-log fit of an order."""

from __future__ import annotations

import csv
import json
import math
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import yaml

from ...config.case import CaseError, yaml_value
from ..outdir.writes import replacing
from ...references import ERROR_MEASURES, RunReference, energy_growth, errors
from . import resolution
from .levels import Outcome

MEASURE_LABELS = {
    "err_displacement": "displacement (RMS in time)",
    "err_impulse": "contact impulse (total)",
    "err_force": "contact force (mean over the contact phases)",
    "force_oscillation": "contact-force oscillation (RMS over the contact phases)",
    "err_energy": "energy (max deviation)",
}


class StudyInputError(ValueError):
    """Bad study options (reported like bad input: one line, status 2, nothing written)."""


def default_outdir(case, study: str) -> Path:
    return Path.cwd() / "results" / f"{case.name}-{study}"


def study_folder(outdir: Path, command: str, case):
    """The study's folder claimed under the output-folder policy (``outdir.in_place.written_in_place``: checked,
    locked, its manifest written at the end), unless this process claimed it already (the command line does)."""
    from ..outdir.in_place import in_place
    from ..outdir.policy import case_inputs

    return in_place(outdir, command, protect=case_inputs(case), source=case.path)


def given_changes(changes) -> dict:
    """The changes given for every run of a study, applied after each method's (so that they win): a
    mapping of dotted key paths to values, or ``--set`` options ``KEY.PATH=VALUE`` (values read as YAML)."""
    if isinstance(changes, Mapping):
        return dict(changes)
    out = {}
    for option in changes:
        key, equals, text = option.partition("=")
        key = key.strip()
        if not equals or not key:
            raise CaseError("--set", None, None, f"expected KEY.PATH=VALUE, got {option!r}")
        try:
            out[key] = yaml_value(text)
        except yaml.YAMLError as err:
            raise CaseError("--set", key, None, f"cannot read the value {text!r}: {' '.join(str(err).split())}") \
                from None
    return out


def base_case(case, given: dict):
    """The case a study's ladders and sweeps start from (its step, restitution, length): the given
    changes but a method's own solver keys, which only the methods that take them receive (after
    their own changes), e.g. ``--set solver.modes=40`` on a newmark file for the modal methods."""
    shared = {key: value for key, value in given.items()
              if not key.startswith("solver.") or key in ("solver.dt", "solver.t_end")}
    return case.with_changes(shared) if shared else case


def case_record(case, changes) -> dict:
    """study.json's ``case`` (the case file) and ``overrides`` (the given changes, as ``--set`` options)."""
    options = [f"{k}={v}" for k, v in changes.items()] if isinstance(changes, Mapping) else list(changes)
    return {"case": str(Path(case.path).resolve()) if case.path is not None else None, "overrides": options}


def write_csv(path: Path, columns, rows) -> Path:
    """Write rows (dicts) atomically; floats with 6 significant digits, None and NaN as empty."""
    with replacing(path) as tmp, open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(columns), extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _cell(v) for k, v in row.items()})
    return path


def _cell(value):
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


def write_json(path: Path, data) -> Path:
    with replacing(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=_json_default) + "\n")
    return path


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


def save_figure(fig, path: Path) -> Path:
    with replacing(path) as tmp, warnings.catch_warnings():   # (a blown-up level's huge error overflows the log axis)
        warnings.simplefilter("ignore", RuntimeWarning)
        fig.savefig(tmp, dpi=110)
    return path


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def fit_order(x, err) -> float:
    """Least-squares slope of log(err) against log(x) over the finite positive errors (NaN if < 2)."""
    x, err = np.asarray(x, dtype=float), np.asarray(err, dtype=float)
    keep = np.isfinite(err) & (err > 0) & np.isfinite(x) & (x > 0)
    if keep.sum() < 2 or np.ptp(np.log(x[keep])) == 0:
        return math.nan
    return float(np.polyfit(np.log(x[keep]), np.log(err[keep]), 1)[0])


def level_row(outcome: Outcome, jobs: int) -> dict:
    """The figures every study tabulates for a level: resolution, work and times."""
    case = outcome.case
    h, c = resolution.mesh_size(case), resolution.wave_speed(case)
    s = outcome.summary or {}
    return {
        "status": outcome.status, "reason": outcome.reason,
        "h": h, "dt": case.solver.dt, "courant": c * case.solver.dt / h,
        "unknowns": s.get("dofs"), "steps": s.get("steps"), "modes": s.get("modes"),
        "setup_time_s": s.get("setup_time_s"), "loop_time_s": s.get("loop_time_s"),
        "wall_time_s": s.get("wall_time_s"), "max_penetration": s.get("max_penetration"),
        "jobs": jobs,
    }


def run_reference(outcome: Outcome, label: str) -> RunReference:
    """A finished level as the reference of the others."""
    case = outcome.case
    return RunReference(outcome.history(), case.output.probes, [c.name for c in case.contacts], label)


def measure(outcome: Outcome, reference, history=None) -> dict:
    """Error measures of a finished level against ``reference`` (NaN for a level that did not finish)."""
    if not outcome.ok:
        return {**dict.fromkeys(ERROR_MEASURES, math.nan), "energy_growth": math.nan, "energy_created": math.nan,
                "energy_created_at": None}
    h = outcome.history() if history is None else history
    # The run's own verdict (EnergyWatch): energy created by the contacts, relative to E0 + W_ext.
    created = outcome.summary.get("energy_created_relative", 0.0)
    return {**errors(h, reference), "energy_growth": energy_growth(h), "energy_created": created,
            "energy_created_at": outcome.summary.get("energy_created_at")}


def fmt(value, spec=".3g") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, spec)
