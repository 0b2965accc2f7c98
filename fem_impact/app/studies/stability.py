"""``fem-impact study stability``: where each method fails. For every method three sweeps about the
case as written: the Courant number ``c dt / h`` (at the case's restitution and length), the
restitution coefficient of every contact (at the case's Courant number) and the run length in
multiples of ``t_end`` (more impacts). Failures are expected here: a run that blows up is recorded,
never stops the study.

Each run is classified, in this order (thresholds below, with why):

- ``failed``: the run stopped (SimulationError: blow-up, NaN); the contacts created energy (the
  run's own check: ``E > E0 + W_ext(t)`` or a loss below zero, by more than 1e-6 of the energy
  scale, ``energy_created`` in its summary); kinetic + strain energy grew above
  ``E(0) + W_ext(t)`` by more than ENERGY_GROWTH of ``E(0) + max |W_ext|``; the largest
  penetration exceeds PENETRATION of the displacement scale; or chattering without end: the
  contact state (force or impulse carried, or not) still switches at the last step, in a stretch
  of at least CHATTER_SWITCHES switches at most CHATTER_STEPS steps apart;
- ``inaccurate``: the contact force oscillates (``force_oscillation`` above FORCE_OSCILLATION),
  or an error (displacement, impulse, force, energy) is above the tolerance (default 5 %);
- ``accurate`` otherwise.

Errors are against the case's exact solution, or against reference runs of the default method at
half the case's time step, one per restitution coefficient, over the longest run length.
Writes ``levels/``, ``stability.csv``, ``stability.png`` and ``study.json`` into OUTDIR.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from ...references import ERROR_MEASURES, contact_spells, from_case
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
from .levels import Level, run_levels, slug

DEFAULT_COURANTS = (0.1, 0.25, 0.5, 1.0, 2.0, 4.0)
DEFAULT_RESTITUTIONS = (0.0, 0.5, 1.0)
DEFAULT_LENGTHS = (1.0, 4.0)
DEFAULT_TOLERANCE = 0.05
# Every method here closes its energy balance to round-off and only loses energy in the contacts
# (the trapezoidal rule's position-level forces give some back on an opening step, a small
# fraction of E0: docs/verification.md): 10 % is growth no discretization error explains.
ENERGY_GROWTH = 0.1
# Position-level multipliers close the gap exactly at every step (penetration 0 to round-off):
# 1 % of the displacement scale (B2: v0 L/c, B1: the initial end displacement) is a failure.
PENETRATION = 0.01
# The contact force's RMS deviation over the contact phases, relative to the exact force: with
# Carnot's correction a fraction of it, the ringing of the discrete bar at the start and end of a
# contact; position-level multipliers alone make the force jump between 0 and a few times its value.
FORCE_OSCILLATION = 0.5
# Chattering: switches at most this many steps apart, at least this many in a row, to the end.
CHATTER_STEPS = 4
CHATTER_SWITCHES = 20
COLUMNS = ("method", "sweep", "value", "courant", "restitution", "length", "dt", "steps", "impacts", "outcome",
           "reason", *ERROR_MEASURES, "energy_growth", "energy_created", "penetration", "chatter_switches",
           "loop_time_s", "wall_time_s", "reference", "level", "jobs")
COLORS = {"accurate": "#43a047", "inaccurate": "#ffb300", "failed": "#e53935", "skipped": "#bdbdbd"}
SWEEPS = (("courant", "Courant number c dt / h"), ("restitution", "restitution e"),
          ("length", "run length (x t_end)"))


def chattering(h: dict, contacts) -> tuple[bool, int]:
    """(still chattering at the last step, the most switches in one stretch) over the contacts."""
    to_end, most = False, 0
    for name in contacts:
        closed = (h[f"{name}.force"] > 0) | (h[f"{name}.impulse"] > 0)
        switches = np.flatnonzero(np.diff(closed.astype(np.int8))) + 1
        if switches.size == 0:
            continue
        breaks = np.flatnonzero(np.diff(switches) > CHATTER_STEPS)
        sizes = np.diff(np.concatenate([[0], breaks + 1, [switches.size]]))
        most = max(most, int(sizes.max()))
        last = int(sizes[-1])
        if last >= CHATTER_SWITCHES and switches[-1] >= closed.size - 1 - CHATTER_STEPS:
            to_end = True
    return to_end, most


def impacts(h: dict, contacts) -> int:
    """Contact spells (openings of at most CHATTER_STEPS steps bridged), summed over the contacts."""
    return sum(len(contact_spells((h[f"{c}.force"] > 0) | (h[f"{c}.impulse"] > 0), merge=CHATTER_STEPS))
               for c in contacts)


def classify(status: str, reason: str, m: dict, tolerance: float) -> tuple[str, str, str]:
    """(outcome, reason, short code for the map)."""
    if status == "skipped":
        return "skipped", reason, "n/a"
    if status != "ok":
        return "failed", reason, "NaN" if "finite" in reason else "blow-up"
    if _finite(m.get("energy_created")) and m["energy_created"] > 0.0:
        return ("failed", f"the contacts created energy: {m['energy_created']:.3g} of E0 + W_ext, from t = "
                          f"{m['energy_created_at']:.4g}", "E+")
    if m["energy_growth"] > ENERGY_GROWTH:
        return "failed", f"energy grew by {m['energy_growth']:.3g} of E0 + input work (> {ENERGY_GROWTH:g})", "E+"
    if m["penetration"] > PENETRATION:
        return "failed", f"penetration {m['penetration']:.3g} of the displacement scale (> {PENETRATION:g})", "pen"
    if m["chatter_to_end"]:
        return ("failed", f"chattering without end: {m['chatter_switches']} contact-state switches at most "
                          f"{CHATTER_STEPS} steps apart, still switching at the last step", "chat")
    if _finite(m["force_oscillation"]) and m["force_oscillation"] > FORCE_OSCILLATION:
        return ("inaccurate", f"the contact force oscillates: RMS deviation {m['force_oscillation']:.3g} of the "
                              f"force (> {FORCE_OSCILLATION:g})", "osc")
    worst = max(((m[k], k) for k in ("err_displacement", "err_impulse", "err_force", "err_energy")
                 if _finite(m[k])), default=(0.0, None))
    if worst[0] > tolerance:
        name = MEASURE_LABELS[worst[1]].split(" (")[0]
        return "inaccurate", f"{name} error {worst[0]:.3g} (> {tolerance:g})", f"{worst[0]:.0%}"
    return "accurate", "", "ok"


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)


def stability_study(case, methods=None, courants=None, restitutions=None, lengths=None, tolerance=None,
                    changes=(), outdir=None, jobs=1, quiet=False, stream=None) -> dict:
    """Run the sweeps on ``case`` (a :class:`~fem_impact.config.case.Case`), every run with ``changes`` after its
    method's (a mapping, or ``--set`` options); returns {"rows", "reference", "skipped", "outdir"}."""
    stream = stream or sys.stderr
    courants = list(DEFAULT_COURANTS if courants is None else courants)
    lengths = list(DEFAULT_LENGTHS if lengths is None else lengths)
    tolerance = DEFAULT_TOLERANCE if tolerance is None else tolerance
    for option, values in (("--courant", courants), ("--length", lengths)):
        if not values or any(not v > 0 for v in values):
            raise StudyInputError(f"{option}: every value must be > 0")
    if not tolerance > 0:
        raise StudyInputError(f"--tolerance {tolerance:g}: must be > 0")
    chosen = registry.parse_methods(methods)
    given = given_changes(changes)
    base = base_case(case, given)   # the step, restitution and length swept about
    if restitutions is None:
        restitutions = list(DEFAULT_RESTITUTIONS) if base.contacts else []
    elif not base.contacts:
        raise StudyInputError(f"--restitution: {base.file or 'the case'} has no contact")
    if any(not 0 <= e <= 1 for e in restitutions):
        raise StudyInputError("--restitution: every value must be in [0, 1]")
    outdir = Path(outdir) if outdir else default_outdir(case, "stability")
    with study_folder(outdir, "study stability", case):
        e_case = base.contacts[0].restitution if base.contacts else None
        same_e = all(c.restitution == e_case for c in base.contacts)

        def e_changes(e):
            if same_e and e == e_case:
                return {}
            return {f"contacts.{i}.restitution": e for i in range(len(base.contacts))}

        def dt_changes(courant):
            dt = resolution.dt_for(base, courant)
            return {} if abs(dt - base.solver.dt) <= 1e-9 * base.solver.dt else {"solver.dt": dt}

        def length_changes(k):
            return {} if k == 1 else {"solver.t_end": k * base.solver.t_end}

        by_changes: dict[tuple, Level] = {}
        plan, skipped = [], {}   # plan: (method, sweep, value, level name, e, length)
        for method in chosen:
            why = registry.availability(method, case, changes)
            if why:
                skipped[method.name] = why
                continue
            common = {**registry.changes_for(method, base, given), "output.vtk": False}
            points = [("courant", c, dt_changes(c), e_case, 1.0) for c in courants]
            points += [("restitution", e, e_changes(e), e, 1.0) for e in restitutions]
            points += [("length", k, length_changes(k), e_case, k) for k in lengths]
            for sweep, value, extra, e, k in points:
                level_changes = {**common, **extra}
                key = json.dumps(level_changes, sort_keys=True, default=str)   # (values may be lists: loads=[...])
                if key not in by_changes:
                    name = slug(f"{method.name}-{sweep}-{value:g}")
                    by_changes[key] = Level(name, level_changes, {"method": method.name},
                                            f"{method.name} {sweep} {value:g}")
                plan.append((method.name, sweep, value, by_changes[key].name, e, k))
        if not plan:
            raise StudyInputError("no method to run: " + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
        levels = list(by_changes.values())
        exact = base.reference is not None
        ref_levels = {}
        if exact:
            for lv in levels:
                from_case(case.with_changes(lv.changes))   # CaseError if the case does not fit its reference
        else:   # the default method at half the case's step, per restitution, over the longest length
            default = registry.get(registry.DEFAULT_METHOD)
            for e in dict.fromkeys([e_case, *restitutions]):
                if e is None and base.contacts:
                    continue
                k = max(lengths) if e == e_case else 1.0
                ref_changes = {**registry.changes_for(default, base, given), "output.vtk": False,
                               "solver.dt": base.solver.dt / 2,
                               **e_changes(e), **length_changes(k)}
                ref_levels[e] = Level(slug(f"reference-e{e:g}" if e is not None else "reference"), ref_changes,
                                      {"method": default.name}, f"reference run ({default.name}, dt/2"
                                      + (f", e = {e:g}" if e is not None else "") + ")")
        if not quiet:
            for name, why in skipped.items():
                stream.write(f"note: {name} skipped: {why}\n")
        outcomes = run_levels(case, [*levels, *ref_levels.values()], outdir, jobs, allow_failure=True,
                              stream=stream, quiet=quiet)
        by_name = {o.level.name: o for o in outcomes}
        references = {}
        if not exact:
            for e, lv in ref_levels.items():
                o = by_name[lv.name]
                if not o.ok:
                    raise StudyInputError(f"the {lv.label} did not finish ({o.reason})")
                references[e] = run_reference(o, lv.label)
        rows = []
        for method, sweep, value, name, e, k in plan:
            o = by_name[name]
            ref = from_case(o.case) if exact else references[e]
            h = o.history() if o.ok else None
            m = measure(o, ref, h)
            row = {"method": method, "sweep": sweep, "value": value, "level": name, **level_row(o, jobs), **m,
                   "restitution": e, "length": k, "reference": ref.label}
            names = [c.name for c in o.case.contacts]
            if o.ok:
                m["chatter_to_end"], m["chatter_switches"] = chattering(h, names)
                m["penetration"] = (o.summary["max_penetration"] or 0.0) / ref.length_scale
                row["impacts"] = impacts(h, names)
            else:
                m["chatter_to_end"], m["chatter_switches"], m["penetration"] = False, None, math.nan
            row["outcome"], row["reason"], row["code"] = classify(o.status, o.reason, m, tolerance)
            row.update(penetration=m["penetration"], chatter_switches=m["chatter_switches"])
            rows.append(row)
        outdir.mkdir(parents=True, exist_ok=True)
        write_csv(outdir / "stability.csv", COLUMNS, rows)
        label = (from_case(by_name[levels[0].name].case).label if exact
                 else "reference runs of the default method at dt/2")
        _plot(outdir / "stability.png", rows, [m.name for m in chosen], skipped, courants, restitutions, lengths,
              base.name, label, tolerance)
        record = case_record(case, changes)
        write_json(outdir / "study.json", {
            "study": "stability", "case": record["case"], "methods": [m.name for m in chosen],
            "skipped": skipped, "courant": courants, "restitution": restitutions, "length": lengths,
            "tolerance": tolerance, "overrides": record["overrides"], "reference": label, "jobs": jobs,
            "thresholds": {"energy_growth": ENERGY_GROWTH, "penetration": PENETRATION,
                           "force_oscillation": FORCE_OSCILLATION, "chatter_steps": CHATTER_STEPS,
                           "chatter_switches": CHATTER_SWITCHES}})
        return {"rows": rows, "reference": label, "skipped": skipped, "outdir": outdir, "tolerance": tolerance}


def format_stability(result: dict) -> str:
    lines = [f"stability; errors against the {result['reference']}, tolerance {result['tolerance']:g}",
             f"{'method':<20}{'sweep':<12}{'value':>7}{'steps':>8}{'impacts':>8}{'displ.':>10}{'force':>10}"
             f"{'osc.':>10}{'energy':>10}  outcome"]
    for r in result["rows"]:
        line = (f"{r['method']:<20}{r['sweep']:<12}{fmt(r['value'], '.3g'):>7}{fmt(r['steps'], 'd'):>8}"
                f"{fmt(r.get('impacts'), 'd'):>8}{fmt(r['err_displacement']):>10}{fmt(r['err_force']):>10}"
                f"{fmt(r['force_oscillation'], '.2g'):>10}{fmt(r['err_energy']):>10}  {r['outcome']}")
        if r["reason"]:
            line += f": {r['reason']}"
        lines.append(line)
    for name, why in result["skipped"].items():
        lines.append(f"skipped {name}: {why}")
    lines.append(f"results in {result['outdir']}")
    return "\n".join(lines)


def _plot(path, rows, methods, skipped, courants, restitutions, lengths, name, label, tolerance) -> Path:
    plt = pyplot()
    from matplotlib.patches import Patch

    sweeps = [(s, title, vals) for (s, title), vals in zip(SWEEPS, (courants, restitutions, lengths), strict=True)
              if vals]
    widths = [len(v) for _, _, v in sweeps]
    fig, axes = plt.subplots(1, len(sweeps), figsize=(3 + 1.1 * sum(widths), 1.6 + 0.55 * len(methods)),
                             gridspec_kw={"width_ratios": widths}, constrained_layout=True, squeeze=False)
    for ax, (sweep, title, values) in zip(axes[0], sweeps, strict=True):
        for i, method in enumerate(methods):
            for j, value in enumerate(values):
                row = next((r for r in rows if r["method"] == method and r["sweep"] == sweep
                            and _same(r, sweep, value)), None)
                outcome, code = (row["outcome"], row["code"]) if row else ("skipped", "n/a")
                ax.add_patch(plt.Rectangle((j, i), 1, 1, color=COLORS[outcome], ec="white", lw=2))
                ax.text(j + 0.5, i + 0.5, code, ha="center", va="center", fontsize=7)
        ax.set_xlim(0, len(values))
        ax.set_ylim(len(methods), 0)
        ax.set_xticks(np.arange(len(values)) + 0.5, [f"{v:g}" for v in values])
        ax.set_yticks(np.arange(len(methods)) + 0.5,
                      [m + (" (n/a)" if m in skipped else "") for m in methods] if ax is axes[0][0] else [])
        ax.set_xlabel(title)
        ax.tick_params(length=0)
        for spine in ax.spines.values():
            spine.set_visible(False)
    handles = [Patch(color=c, label=k) for k, c in COLORS.items()]
    axes[0][-1].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    fig.suptitle(f"{name}: outcome of each run against the {label}\ncodes: ok; error above {tolerance:g} (the "
                 f"largest, in %); osc = force oscillation; blow-up, NaN, E+ = energy created, pen = penetration, "
                 f"chat = chattering without end; n/a = not available", fontsize=8)
    save_figure(fig, path)
    plt.close(fig)
    return path


def _same(row, sweep, value) -> bool:
    return abs(row["value"] - value) <= 1e-9 * max(1.0, abs(value))
