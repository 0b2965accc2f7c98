"""Class ``response``: ``fem-impact study response`` with every kind of ``--vary`` key (the frequency's
parameter, an amplitude, a gap, the keys the study sets, keys that do not exist, malformed value lists, the
documented form), sizes beyond the guard, sweeps up and down into one folder, ``--no-shooting``,
``--flight events``, a free body, ``-q``, and the Python API with bad arguments. A probe judges an exact
or physical answer where there is one (the impact oscillator's closed forms, linearity in the amplitude,
a free body's momentum balance), else a plain refusal (status 2, one line naming the option), with
nothing written."""

from __future__ import annotations

import csv
import json
import math

from . import CASES, lost, ok, probe, wrong

OSC = CASES / "impact_oscillator.yaml"
BAR = CASES / "impacting_bar.yaml"
CORNER = CASES / "block_corner.yaml"
QUICK = ("--settle", "2", "--periods", "2", "--steps-per-period", "8", "--no-shooting")


def _rows(folder):
    with open(folder / "response.csv", newline="") as f:
        return list(csv.DictReader(f))


def _refusal(case, args, *needles, extra=()):
    """``study response CASE ARGS``: status 2, a message naming ``needles``, no output folder."""
    def body(ctx):
        out = ctx.folder / "out"
        r = ctx.run("study", "response", case, "-o", out, *args, *extra)
        verdict = ctx.refused(r, *needles)
        if verdict.kind == "ok" and out.exists():
            return wrong(f"refused, yet {out} was written")
        return verdict
    return body


REFUSALS = [
    # keys the study sets at every level
    (OSC, ("--vary", "solver.dt=0.45,0.5"), ("solver.dt",)),
    (OSC, ("--vary", "solver.t_end=1,2"), ("solver.t_end",)),
    (OSC, ("--vary", "initial.velocity=1"), ("initial",)),
    (OSC, ("--vary", "output.vtk=1"), ("output.vtk",)),
    (OSC, ("--vary", "parameters.f=0.5", "--set", "solver.dt=0.1"), ("--set solver.dt",)),
    # keys that do not exist, or that nothing uses
    (OSC, ("--vary", "nokey.x=1,2"), ("nokey",)),
    (OSC, ("--vary", "parameters.nothing=1,2"), ("nothing",)),
    (OSC, ("--vary", "contacts.5.gap=0,1"), ("contacts",)),
    # malformed value lists
    (OSC, ("--vary", "parameters.f="), ("--vary",)),
    (OSC, ("--vary", "parameters.f"), ("--vary",)),
    (OSC, ("--vary", "=1,2"), ("--vary",)),
    (OSC, ("--vary", "parameters.f=a,b"), ("'a'",)),
    (OSC, ("--vary", "parameters.f=0.4,,0.5"), ("--vary",)),
    (OSC, ("--vary", "parameters.f=0.4,0.4"), ("twice",)),
    (OSC, ("--vary", "parameters.f=0.4,...,0.7"), ("ellipsis",)),
    (OSC, ("--vary", "parameters.f=0.4,0.5,...,0.73"), ("do not reach",)),
    (OSC, ("--vary", "parameters.f=0.4,0.5,0.7,...,1"), ("evenly spaced",)),
    (OSC, ("--vary", "parameters.f=0,1e-9,...,1000"), ("more than",)),
    (OSC, ("--vary", "parameters.f=nan,1"), ("--vary",)),
    # values the case refuses, frequencies that are not
    (OSC, ("--vary", "contacts.0.restitution=0.5,1.5"), ("restitution",)),
    (OSC, ("--vary", "parameters.f=-1,1"), ("--frequency", "positive")),
    (OSC, ("--vary", "parameters.f=0.5", "--frequency", "g"), ("--frequency", "'g'")),
    (OSC, ("--vary", "parameters.f=0.5", "--frequency", "2*"), ("--frequency",)),
    (OSC, ("--vary", "parameters.f=0.5", "--frequency", "0"), ("--frequency", "positive")),
    (BAR, ("--vary", "material.E=1,2"), ("--frequency", "no parameter f")),
    (CORNER, ("--vary", "parameters.g=0.5,0.6", "--frequency", "w"), ("--frequency", "no load")),
    # sizes and options
    (OSC, ("--vary", "parameters.f=0.45", "--periods", "100000000"), ("--periods",)),
    (OSC, ("--vary", "parameters.f=0.45", "--settle", "1000000"), ("--settle", "steps")),
    (OSC, ("--vary", "parameters.f=0.45", "--steps-per-period", "1000000000"), ("--steps-per-period",)),
    (OSC, ("--vary", "parameters.f=0.45", "--settle", "1000000", "--flight", "events"), ("--settle",)),
    (OSC, ("--vary", "parameters.f=0.45", "--steps-per-period", "2"), ("--steps-per-period",)),
    (OSC, ("--vary", "parameters.f=0.45", "--tolerance", "0"), ("--tolerance",)),
    (OSC, ("--vary", "parameters.f=0.45", "--shooting-time", "-1"), ("--shooting-time",)),
    (OSC, ("--vary", "parameters.f=0.45", "-j", "2"), ("-j",)),
    (CASES / "vibroconverter_forced.yaml", ("--vary", "parameters.f=25000", "--flight", "events"),
     ("--flight events", "reduced")),
]

for _case, _args, _needles in REFUSALS:
    probe("response", f"{_case.stem} {' '.join(_args)}: refused")(_refusal(_case, _args, *_needles))
    if _args[1] == "parameters.f=0.45" and _args[2] == "--periods":   # the size guard's refusal is not silent with -q
        probe("response", f"{_case.stem} {' '.join(_args)} -q: refused aloud")(
            _refusal(_case, _args, *_needles, extra=("-q",)))


@probe("response", "the amplitude swept at the case's frequency: the orbit scales with F0 (linear, gap 0)")
def _amplitude(ctx):
    out = ctx.folder / "out"
    r = ctx.run("study", "response", OSC, "--vary", "parameters.F0=0.6,1.2", "--flight", "events", "--settle", "0",
                "--periods", "2", "-q", "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    rows = {float(row["parameters.F0"]): row for row in _rows(out)}
    if {row.get("frequency") for row in rows.values()} != {"0.5"}:
        return wrong(f"the forcing frequency is not the case's 0.5: {[row.get('frequency') for row in rows.values()]}")
    if not all(row.get("orbit1.impulse") for row in rows.values()):
        return wrong(f"no period-1 orbit: {[row.get('orbit1.note') for row in rows.values()]}")
    ratio = float(rows[1.2]["orbit1.impulse"]) / float(rows[0.6]["orbit1.impulse"])
    return ok(f"impulse ratio {ratio:.10f}") if abs(ratio - 2) < 1e-7 else wrong(f"impulse ratio {ratio}, not 2")


@probe("response", "the documented START,NEXT,...,END form, event-driven: the closed-form impact speed")
def _readme_form(ctx):
    out = ctx.folder / "out"
    r = ctx.run("study", "response", OSC, "--vary", "parameters.f=0.45,0.5,...,0.55", "--flight", "events",
                "--settle", "0", "--periods", "2", "-q", "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    from fem_impact.periodic.oscillator import impact_speed

    rows = {float(row["parameters.f"]): row for row in _rows(out)}
    if sorted(rows) != [0.45, 0.5, 0.55]:
        return wrong(f"levels {sorted(rows)}, expected 0.45, 0.5, 0.55")
    for f, row in rows.items():
        if not row.get("orbit1.min_speed"):
            return wrong(f"f = {f}: no period-1 orbit ({row.get('orbit1.note')})")
        # the rod's tip: phi^2 = 2, F0 = pi/4, w1 = pi/2 (to the mesh's 1e-5): the tip's speed is the scaled one
        V = float(row["orbit1.min_speed"])
        if abs(V / impact_speed(4 * f, 0.8) - 1) > 1e-4:
            return wrong(f"f = {f}: impact speed {V}, closed form {impact_speed(4 * f, 0.8)}")
    return ok()


@probe("response", "a gap swept at the case's frequency (time-stepped): every level at 0.5 Hz, T / K steps")
def _gap(ctx):
    out = ctx.folder / "out"
    r = ctx.run("study", "response", OSC, "--vary", "contacts.0.gap=0,0.1", *QUICK, "-q", "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    for level in (out / "levels").iterdir():
        changes = json.loads((level / "level.json").read_text())["changes"]
        if not math.isclose(changes["solver.dt"], 1 / (0.5 * 8), rel_tol=1e-12):
            return wrong(f"{level.name}: dt {changes['solver.dt']}, not T / 8 at 0.5 Hz")
    return ok() if {row.get("frequency") for row in _rows(out)} == {"0.5"} else wrong("no frequency 0.5 column")


def _sweep(ctx, out, *args):
    return ctx.run("study", "response", OSC, "--vary", "parameters.f=0.45,0.5", "--flight", "events", "--settle", "20",
                   "--periods", "2", "-q", "-o", out, *args)


@probe("response", "up, then down with another restitution into the same folder: refused, the sweep up kept")
def _other_settings(ctx):
    out = ctx.folder / "out"
    bad = ctx.succeeded(_sweep(ctx, out, "--no-shooting"))
    if bad:
        return bad
    ctx.keep(out)
    verdict = ctx.refused(_sweep(ctx, out, "--down", "--no-shooting", "--set", "contacts.0.restitution=0.5"),
                          "restitution")
    if verdict.kind != "ok":
        return verdict
    return ok() if not ctx.lost_files() else lost(f"the refused sweep changed {ctx.lost_files()}")


@probe("response", "up, then down with another --settle: refused")
def _other_settle(ctx):
    out = ctx.folder / "out"
    bad = ctx.succeeded(_sweep(ctx, out, "--no-shooting"))
    if bad:
        return bad
    return ctx.refused(ctx.run("study", "response", OSC, "--vary", "parameters.f=0.45,0.5", "--flight", "events",
                               "--settle", "30", "--periods", "2", "-q", "-o", out, "--down", "--no-shooting"),
                       "settle")


@probe("response", "up (--no-shooting), then down (shooting): merged, study.json says what each did")
def _merged(ctx):
    out = ctx.folder / "out"
    bad = ctx.succeeded(_sweep(ctx, out, "--no-shooting")) or ctx.succeeded(_sweep(ctx, out, "--down"))
    if bad:
        return bad
    directions = {row["direction"] for row in _rows(out)}
    study = json.loads((out / "study.json").read_text())
    shooting = {d: sweep.get("shooting") for d, sweep in study.get("sweeps", {}).items()}
    if directions != {"up", "down"}:
        return wrong(f"response.csv holds {directions}")
    if shooting != {"up": "not asked (--no-shooting)", "down": "done"}:
        return wrong(f"study.json says shooting {shooting}")
    return ok()


@probe("response", "near the period doubling, time-stepped (w = 2.68, 2.70): never a period the step made up")
def _bifurcation(ctx):
    out = ctx.folder / "out"
    r = ctx.run("study", "response", OSC, "--vary", "parameters.f=0.67,0.675", "--steps-per-period", "500",
                "--no-shooting", "-q", "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    for row in _rows(out):
        note = row.get("period_note") or ""
        if not (row["period"] == "2" or (row["period"] == "0" and note.startswith("not resolved"))):
            return wrong(f"f = {row['parameters.f']}: period {row['period']} ({note}); the exact flights give 2")
    return ok()


@probe("response", "near the period doubling with shooting: the exact period-2 orbit, stable")
def _bifurcation_shooting(ctx):
    out = ctx.folder / "out"
    r = ctx.run("study", "response", OSC, "--vary", "parameters.f=0.67,0.675", "--steps-per-period", "500", "-q",
                "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    row = next(row for row in _rows(out) if row["parameters.f"] == "0.675")
    if row.get("orbit1.stable") != "0" or row.get("orbit2.stable") != "1":
        return wrong(f"orbit1.stable {row.get('orbit1.stable')}, orbit2.stable {row.get('orbit2.stable')} "
                     f"({row.get('orbit2.note', '')}): the exact period-1 orbit is unstable, the period-2 one stable")
    return ok()


FREE = """\
name: free_block
parameters: {f: 56.0, g: 9.81, A: 14.0}
mesh: {shape: bar, dim: 2, length: 0.2, height: 0.05, cells: 8}
material: {E: 1.0e7, rho: 1000.0, nu: 0.0, area: 1.0}
damping: {alpha: 0.0, beta: 1.0e-4}
loads:
  - {body: all, acceleration: ["-g + A*sin(2*pi*f*t)", 0.0]}
contacts:
  - {name: wall, type: obstacle, nodes: left, normal: [-1.0, 0.0], coupling: mean, gap: 0.0, restitution: 0.5}
solver: {method: modal, modes: 6, static_correction: false, dt: 1.0e-4, t_end: 0.1}
output:
  vtk: false
  probes: {end: [0.2, 0.025]}
"""
WEIGHT_IMPULSE = 0.2 * 0.05 * 1000.0 * 9.81 / 56.0   # m g T


@probe("response", "a free block against a wall, event-driven with shooting: it ends, and the orbit takes m g T",
       timeout=400)
def _free_block(ctx):
    case = ctx.folder / "free_block.yaml"
    case.write_text(FREE)
    out = ctx.folder / "out"
    r = ctx.run("study", "response", case, "--vary", "parameters.A=14", "--flight", "events", "--settle", "100",
                "--periods", "8", "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    row = _rows(out)[0]
    if "orbit1.impulse" not in row:
        return wrong(f"no period-1 orbit: {row.get('orbit1.note')}")
    if row.get("orbit1.unseen_modes") != "2":
        return wrong(f"orbit1.unseen_modes {row.get('orbit1.unseen_modes')}: the drift and the rotation are 2 "
                     f"modes no row sees ({row.get('orbit1.note', '')})")
    impulse = float(row["orbit1.impulse"])
    if abs(impulse / WEIGHT_IMPULSE - 1) > 1e-9:
        return wrong(f"orbit1.impulse {impulse}, the momentum balance says m g T = {WEIGHT_IMPULSE}")
    if "shooting at parameters.A=14" not in r.stderr:
        return wrong(f"no progress line for shooting: {r.tail()}")
    return ok(f"{r.seconds:.0f} s")


@probe("response", "a free block resting on a floor, time-stepped: round-off columns, period 1, m g T")
def _resting_block(ctx):
    case = ctx.folder / "resting.yaml"
    case.write_text(FREE.replace("A: 14.0", "A: 12.0").replace("cells: 8", "cells: 4")
                    .replace('["-g + A*sin(2*pi*f*t)", 0.0]', '[0.0, "-g + A*sin(2*pi*f*t)"]')
                    .replace("nodes: left, normal: [-1.0, 0.0], coupling: mean", "nodes: bottom, normal: [0.0, -1.0]")
                    .replace("end: [0.2, 0.025]", "front: [0.2, 0.0]"))
    out = ctx.folder / "out"
    r = ctx.run("study", "response", case, "--vary", "parameters.A=12", "--settle", "20", "--periods", "4",
                "--steps-per-period", "100", "--no-shooting", "-q", "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    rows = _rows(out)
    row = rows[-1]
    if len(rows) != 1 or row["period"] != "1":
        return wrong(f"period {row['period']} ({row.get('period_note')}): the block rests, period 1")
    impulse = float(row["wall.impulse"])
    return ok() if abs(impulse / WEIGHT_IMPULSE - 1) < 1e-9 else wrong(f"impulse {impulse}, m g T {WEIGHT_IMPULSE}")


@probe("response", "--allow-failure, every level blows up: status 3 and a message, even with -q")
def _all_failed(ctx):
    r = ctx.run("study", "response", OSC, "--vary", "parameters.f=0.1", "--set", "solver.method=central_difference",
                *QUICK, "--allow-failure", "-q", "-o", ctx.folder / "out")
    if r.traceback:
        return ctx.refused(r)
    return ok() if r.status == 3 and "no level" in r.stderr else wrong(f"status {r.status}: {r.tail()}")


@probe("response", "--allow-failure, one level blows up: the table names it")
def _one_failed(ctx):
    r = ctx.run("study", "response", OSC, "--vary", "parameters.f=0.45,0.1,0.5", "--down",
                "--set", "solver.method=central_difference", "--settle", "2", "--periods", "2", "--no-shooting",
                "--allow-failure", "-o", ctx.folder / "out")
    bad = ctx.succeeded(r)
    if bad:
        return bad
    return ok() if "parameters.f=0.1: FAILED" in r.stdout else wrong(f"the table does not name the failed level: "
                                                                      f"{r.stdout.strip()[-300:]}")


API = """\
import fem_impact as fi
from fem_impact.app.studies.response import response_study
case = fi.load_case({case!r})
try:
    response_study({args})
except TypeError as err:
    print("TypeError:", err)
"""


def _api(args, needle):
    def body(ctx):
        code = API.format(case=str(OSC), args=args)
        r = ctx.run("-c", code, python=True)
        if r.traceback:
            return ctx.refused(r)
        out = r.stdout.strip()
        return ok(out) if out.startswith("TypeError:") and needle in out else wrong(f"{out or r.tail()}")
    return body


for _args, _needle in [
    ("None, 'parameters.f=0.45', 'out'", "case"),
    ("case, None, 'out'", "vary"),
    ("case, 'parameters.f=0.45', None", "outdir"),
    ("case, 'parameters.f=0.45', 'out', settle=2.5", "settle"),
    ("case, 'parameters.f=0.45', 'out', changes=5", "changes"),
    ("case, 'parameters.f=0.45', 'out', frequency=['f']", "frequency"),
    ("case, 'parameters.f=0.45', 'out', down='yes'", "down"),
]:
    probe("response", f"response_study({_args})")(_api(_args, _needle))


@probe("response", "a free block resting on its wall part of each period, event-driven: it ends, never through the wall",
       timeout=300)
def _free_block_rests(ctx):
    case = ctx.folder / "free_block.yaml"
    case.write_text(FREE.replace("A: 14.0", "A: 12.0"))
    out = ctx.folder / "out"
    r = ctx.run("study", "response", case, "--vary", "parameters.A=12", "--flight", "events", "--settle", "20",
                "--periods", "4", "--no-shooting", "-q", "-o", out)
    bad = ctx.succeeded(r)
    if bad:
        return bad
    deepest = min(float(row["end.ux"]) for row in _rows(out))
    return ok() if deepest > -1e-4 else wrong(f"the block's end went {deepest} m into the wall")
