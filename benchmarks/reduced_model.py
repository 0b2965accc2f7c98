"""Cost of the reduced model against the full one on B3's 2D cantilever (about 20 000 unknowns, its
elastic stop on the tip section).

Prints the time for the modes, for the static solves (residual flexibility), for the loop and
per step, for the full model and the modal model (n1 modes, static correction) at equal dt,
their speed-ups (loop, whole run) and the contact-impulse difference. Issue 3's targets: loop
at least 100x and whole run at least 10x faster, at an impulse error under 2 %.

    python benchmarks/reduced_model.py [--cells 240] [--modes 10] [--steps 400]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the fem-impact command does

from mpi4py import MPI  # noqa: E402

from fem_impact.config.case import load_case  # noqa: E402
from fem_impact.nonsmooth.relation import build_constraints  # noqa: E402
from fem_impact.integrators import Newmark, integrate  # noqa: E402
from fem_impact.fem.mesh import build_mesh  # noqa: E402
from fem_impact.fem.model import build_model  # noqa: E402
from fem_impact.config.build import model_spec
from fem_impact.fem.modes import compute_modes  # noqa: E402
from fem_impact.fem.reduced import build_reduced  # noqa: E402
from fem_impact.app.pipeline import full_model  # noqa: E402

CASE = Path(__file__).resolve().parents[1] / "cases" / "beam_stop.yaml"


class Impulse:
    def __init__(self):
        self.total = 0.0

    def write(self, state):
        self.total += state.impulse.sum()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cells", type=int, default=240, help="cells along the beam (default 240: ~20 700 unknowns)")
    parser.add_argument("--modes", type=int, default=10)
    parser.add_argument("--steps", type=int, default=1600, help="time steps (default: the whole case, 1600)")
    args = parser.parse_args()
    t0 = time.perf_counter()
    case = load_case(CASE, [f"mesh.cells={args.cells}"])
    model = build_model(model_spec(case), build_mesh(case.mesh, MPI.COMM_WORLD))
    cons = build_constraints(case.contacts, model)
    t_model = time.perf_counter() - t0
    dt, t_end = case.solver.dt, args.steps * case.solver.dt

    t0 = time.perf_counter()
    full = Newmark(full_model(case, model, cons).operators, dt)   # the case's operators, its elastic stop included
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
    reduced = Newmark(red.operators, dt)
    t_red_setup = time.perf_counter() - t0
    impulse_red = Impulse()
    t0 = time.perf_counter()
    integrate(reduced, red.Z0, red.Zdot0, t_end, [impulse_red])
    t_red_loop = time.perf_counter() - t0

    n = args.steps
    full_total = t_model + t_full_setup + t_full_loop
    red_total = t_model + t_modes + t_static + t_red_setup + t_red_loop
    print(f"model: {model.dofs} unknowns, {cons.p} contact rows, {n} steps of {dt:g} s; mesh and assembly "
          f"{t_model:.2f} s")
    print(f"full model:    factorizations {t_full_setup:6.2f} s, loop {t_full_loop:7.2f} s "
          f"({1e3 * t_full_loop / n:.3f} ms/step), whole run {full_total:.2f} s")
    print(f"modal, {args.modes:3d} modes: modes {t_modes:.2f} s, static solves {t_static:.2f} s, loop "
          f"{t_red_loop:.2f} s ({1e3 * t_red_loop / n:.3f} ms/step), whole run {red_total:.2f} s")
    print(f"speed-up: loop {t_full_loop / t_red_loop:.1f}x, whole run {full_total / red_total:.1f}x; "
          f"contact impulse {impulse_red.total:.5g} against {impulse_full.total:.5g} N s "
          f"({100 * abs(impulse_red.total / impulse_full.total - 1):.2f} %)")


if __name__ == "__main__":
    main()
