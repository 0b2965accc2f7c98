"""Cost of the reduced model: against the full one on B3's 2D cantilever (about 20 000 unknowns,
its elastic stop on the tip section), and its steps between contacts taken in blocks against one
at a time on a one-mode impact oscillator.

B3: prints the time for the modes, for the static solves (residual flexibility), for the loop and
per step, for the full model and the modal model (n1 modes, static correction) at equal dt,
their speed-ups (loop, whole run) and the contact-impulse difference. Issue 3's targets: loop
at least 100x and whole run at least 10x faster, at an impulse error under 2 %. The reduced
loop is timed one step at a time (`solver.blocks: false`, the path before issue 19) and with
its steps between contacts in blocks (the default).

The oscillator (issue 19): a clamped-free rod (c = L = 1, first mode 0.25 Hz) reduced to its
first mode without static correction, driven at its tip by F0 sin(2 pi f t) (f = 0.5 Hz: one
impact a period) against a rigid stop at its tip at zero gap (restitution 0.8), the default
method (Moreau-Jean), 150 steps a period: ``fem_impact.run`` of the same case with
``solver.blocks`` false (one step at a time: the reference) and true, loop time per step of
each, their ratio (target: at least 20x), the steps taken in blocks and the largest difference
of any history column (relative to the column's largest value).

The strip on its stop (cases/strip_on_stop.yaml): a clamped steel strip (1 x 0.1 m, 200 x 20
cells, 8442 unknowns) whose end section (21 rows) rests on a stop at zero gap, pressed onto it by a force
of 1000 N on the section and a body load that varies (50 (1 + 0.5 sin(2 pi 300 t)) m/s^2): every row
closed every step.
The full model (moreau_jean) against ten modes with the static correction, one step at a time and with
its steps, the contact steps included, in compiled blocks (the default from 4000 steps); loop time per
step (best of ``--repeat``), the ratio full / blocks (target: at least 50, at most about 18 us a step)
and the largest difference between the reduced model's two histories (target: 1e-10 of each column's
scale; an energy term on the energy's, a probe's component on its largest).

    python benchmarks/reduced_model.py [--cells 240] [--modes 10] [--steps 1600] [--periods 300]
                                       [--per-period 150] [--repeat 3] [--only b3|oscillator|strip]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the fem-impact command does

import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

import fem_impact  # noqa: E402
from fem_impact.build import full_system, model_and_constraints, reduced_operators  # noqa: E402
from fem_impact.config.case import load_case  # noqa: E402
from fem_impact.fem.modes import compute_modes  # noqa: E402
from fem_impact.fem.reduced import build_reduced  # noqa: E402
from fem_impact.integrators import Newmark, integrate  # noqa: E402
from fem_impact.integrators.blocks import BlockStepper  # noqa: E402

CASE = Path(__file__).resolve().parents[1] / "cases" / "beam_stop.yaml"


class Impulse:
    def __init__(self):
        self.total = 0.0

    def write(self, state):
        self.total += state.impulse.sum()

    def write_block(self, block):
        self.total += block.impulse.sum()


def b3(args) -> None:
    t0 = time.perf_counter()
    case = load_case(CASE, [f"mesh.cells={args.cells}"])
    model, cons = model_and_constraints(case, MPI.COMM_WORLD)
    t_model = time.perf_counter() - t0
    dt, t_end = case.solver.dt, args.steps * case.solver.dt

    t0 = time.perf_counter()
    full = Newmark(full_system(case, model, cons).operators, dt)   # the case's operators, its elastic stop included
    t_full_setup = time.perf_counter() - t0
    impulse_full = Impulse()
    t0 = time.perf_counter()
    integrate(full, model.U0, model.V0, t_end, [impulse_full])
    t_full_loop = time.perf_counter() - t0

    t0 = time.perf_counter()
    modes = compute_modes(model, args.modes)
    t_modes = time.perf_counter() - t0
    t0 = time.perf_counter()
    red = build_reduced(model, cons, modes, args.modes, True, 0.0, 0.0, dt)
    t_static = time.perf_counter() - t0
    t0 = time.perf_counter()
    reduced = Newmark(reduced_operators(red, cons), dt)
    t_red_setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    blocks = BlockStepper.of(reduced)   # (imports Numba, loads the compiled steps)
    t_numba = time.perf_counter() - t0
    loops, impulses = {}, {}
    for name, stepper in (("one at a time", None), ("in blocks", blocks)):
        impulses[name] = Impulse()
        t0 = time.perf_counter()
        integrate(reduced, red.Z0, red.Zdot0, t_end, [impulses[name]], blocks=stepper)
        loops[name] = time.perf_counter() - t0
    t_red_loop = loops["in blocks"]

    n = args.steps
    full_total = t_model + t_full_setup + t_full_loop
    red_total = t_model + t_modes + t_static + t_red_setup + t_numba + t_red_loop
    single_total = t_model + t_modes + t_static + t_red_setup + loops["one at a time"]
    print(f"B3: {model.dofs} unknowns, {cons.p} contact rows, {n} steps of {dt:g} s; mesh and assembly "
          f"{t_model:.2f} s")
    print(f"full model:    factorizations {t_full_setup:6.2f} s, loop {t_full_loop:7.2f} s "
          f"({1e3 * t_full_loop / n:.3f} ms/step), whole run {full_total:.2f} s")
    print(f"modal, {args.modes:3d} modes: modes {t_modes:.2f} s, static solves {t_static:.2f} s, loop "
          f"{t_red_loop:.3f} s ({1e3 * t_red_loop / n:.4f} ms/step; one step at a time "
          f"{loops['one at a time']:.3f} s, {1e3 * loops['one at a time'] / n:.4f} ms/step; {blocks.steps} of "
          f"{n} steps in {blocks.blocks} blocks; loading Numba and the compiled steps {t_numba:.2f} s), whole run "
          f"{red_total:.2f} s (one step at a time, without Numba: {single_total:.2f} s)")
    print(f"speed-up: loop {t_full_loop / t_red_loop:.1f}x (one step at a time: "
          f"{t_full_loop / loops['one at a time']:.1f}x), whole run {full_total / red_total:.1f}x; "
          f"contact impulse {impulses['in blocks'].total:.5g} against {impulse_full.total:.5g} N s "
          f"({100 * abs(impulses['in blocks'].total / impulse_full.total - 1):.2f} %)")


def oscillator_case(periods: int, per_period: int, scheme: str = "moreau_jean", f: float = 0.5,
                    force: float = 0.1, restitution: float = 0.8) -> fem_impact.Case:
    """The one-mode impact oscillator (module docstring)."""
    return fem_impact.Case.from_dict({
        "name": "impact_oscillator",
        "mesh": {"shape": "bar", "dim": 1, "cells": 20},
        "material": {"E": 1.0, "rho": 1.0, "nu": 0.0},
        "supports": [{"nodes": "left", "fix": ["x"]}],
        "loads": [{"nodes": "right", "force": [f"{force}*sin(2*pi*{f}*t)"]}],
        "contacts": [{"name": "stop", "type": "obstacle", "nodes": "right", "normal": [1.0], "gap": 0.0,
                      "restitution": restitution}],
        "solver": {"method": "modal", "scheme": scheme, "modes": 1, "static_correction": False,
                   "dt": 1.0 / (f * per_period), "t_end": periods / f},
        "output": {"vtk": False},
    })


def oscillator(args) -> None:
    case = oscillator_case(args.periods, args.per_period)
    fem_impact.run(oscillator_case(2, args.per_period))   # (imports, compiled steps loaded: not timed below)
    per_step, results = {False: [], True: []}, {}
    for _ in range(args.repeat):
        for blocks in (False, True):
            result = fem_impact.run(case.with_changes({"solver.blocks": blocks}))
            per_step[blocks].append(result.summary["loop_time_s"] / result.summary["steps"])
            results[blocks] = result
    single, fast = min(per_step[False]), min(per_step[True])
    s = results[True].summary
    a, b = results[False].history, results[True].history
    difference = max(float(np.abs(a[k] - b[k]).max() / max(np.abs(a[k]).max(), 1e-300)) for k in a)
    print(f"one-mode impact oscillator: {s['steps']} steps ({args.periods} periods of {args.per_period} steps), "
          f"{s['impacts']['stop']} impacts, {s['steps_in_blocks']} steps in {s['blocks']} blocks")
    print(f"loop per step: one step at a time {1e6 * single:.2f} us, in blocks {1e6 * fast:.3f} us, "
          f"ratio {single / fast:.1f}x (best of {args.repeat}; all: "
          f"{', '.join(f'{1e6 * x:.1f}' for x in per_step[False])} and "
          f"{', '.join(f'{1e6 * x:.2f}' for x in per_step[True])} us)")
    print(f"largest history difference between the two: {difference:.2g} of the column's largest value")


def strip_case(method: str, steps: int, blocks: bool | None = None) -> fem_impact.Case:
    """The strip on its stop (cases/strip_on_stop.yaml): the full model, or the reduced one with ``blocks``."""
    case = fem_impact.load_case(CASE.parent / "strip_on_stop.yaml")
    changes = {"solver.t_end": steps * case.solver.dt, "output.vtk": False}
    if method != "modal":
        changes["solver.method"] = method
    else:
        changes["solver.blocks"] = blocks
    return case.with_changes(changes)


def history_difference(a: dict, b: dict) -> tuple[float, str]:
    """The largest difference of two histories over each column's scale (an energy term on the energy's, a
    probe's component and the gaps on the probes' largest displacement), and its column."""
    energy = max(np.abs(a[k]).max() for k in ("kinetic", "strain", "external_work", "contact_loss"))
    worst = (0.0, "")
    for name in a:
        scale = max(np.abs(a[name]).max(), 1e-300)
        if name in ("energy_error", "damping_loss", "numerical_loss"):
            scale = energy
        for group in ((".gap", ".ux", ".uy"), (".vx", ".vy"), (".px", ".py")):
            if name.endswith(group):
                scale = max(scale, *(np.abs(a[k]).max() for k in a if k.endswith(group[-2:])))
        worst = max(worst, (float(np.abs(a[name] - b[name]).max() / scale), name))
    return worst


def strip(args) -> None:
    steps = args.strip_steps
    fem_impact.run(strip_case("modal", 50, True))   # (imports, compiled steps loaded: not timed below)
    per_step, results = {"full": [], "single": [], "blocks": []}, {}
    for _ in range(args.repeat):
        for name in per_step:
            if name == "full" and per_step["full"] and len(per_step["full"]) >= 2:
                continue   # (two runs of the full model are enough: its step is 100 times longer)
            case = strip_case("moreau_jean", steps) if name == "full" else strip_case("modal", steps, name == "blocks")
            result = fem_impact.run(case)
            per_step[name].append(result.summary["loop_time_s"] / result.summary["steps"])
            results[name] = result
    best = {name: min(times) for name, times in per_step.items()}
    s, h = results["blocks"].summary, results["blocks"].history
    closed = int(np.count_nonzero(h["stop.force"][1:] > 0.0))
    difference, column = history_difference(results["single"].history, h)
    full = results["full"].summary
    print(f"strip on its stop: {full['dofs']} unknowns, {full['constraints']} contact rows, {s['steps']} steps, "
          f"contact force > 0 in {closed} of them; {s['steps_in_blocks']} steps in {s['blocks']} blocks")
    print(f"loop per step: full model {1e6 * best['full']:.1f} us, reduced one step at a time "
          f"{1e6 * best['single']:.2f} us, reduced in blocks {1e6 * best['blocks']:.2f} us (best of "
          f"{args.repeat}; blocks: {', '.join(f'{1e6 * x:.2f}' for x in per_step['blocks'])} us)")
    print(f"ratio full / blocks {best['full'] / best['blocks']:.1f}x (one step at a time "
          f"{best['full'] / best['single']:.1f}x); largest history difference blocks / single steps "
          f"{difference:.2g} of its scale ({column})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cells", type=int, default=240, help="cells along the beam (default 240: ~20 700 unknowns)")
    parser.add_argument("--modes", type=int, default=10)
    parser.add_argument("--steps", type=int, default=1600, help="time steps (default: the whole case, 1600)")
    parser.add_argument("--periods", type=int, default=300, help="the oscillator's forcing periods")
    parser.add_argument("--per-period", type=int, default=150, help="the oscillator's steps per forcing period")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each path of the oscillator (best taken)")
    parser.add_argument("--strip-steps", type=int, default=4000, help="the strip's time steps (default 4000)")
    parser.add_argument("--only", choices=("b3", "oscillator", "strip"), help="one of the three measurements")
    args = parser.parse_args()
    if args.only in (None, "b3"):
        b3(args)
    if args.only in (None, "oscillator"):
        oscillator(args)
    if args.only in (None, "strip"):
        strip(args)


if __name__ == "__main__":
    main()
