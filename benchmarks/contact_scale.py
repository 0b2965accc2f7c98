"""Cost of many contact rows: a plate falling face-first, every node of its face a contact row.

cases/plate_drop.yaml (a 1 x 5 x 5 plate of hexahedra, n cells through the thickness and 5 n
across, so (5 n + 1)^2 face nodes) with ``coupling: each`` (one row per face node) against the
same plate with ``coupling: mean`` (one row on the face's mean displacement), with the default
method (moreau_jean at the position level) or ``--method newmark`` (the paper's scheme) or
``--method velocity`` (moreau_jean at the velocity level). Courant number 0.5 (``--courant C``: dt
= C / n, c = 1), the gap 1.5 dt so that the floor is reached at the second step, and the timed steps
are contact steps (the LCPs on all rows, Carnot's correction where the method has one). The contact
lasts 2 L / c = 2 n / C steps: 4 n at Courant 0.5; at Courant 50 (n = 2, 4, 8) the plate lands in one
step (``1st``) and leaves in the next, the one timed step. For each size and coupling it prints:
the factorization of S, the building of W = P S^-1 P^T and D = P M^-1 P^T, the whole setup
(case, mesh, assembly, factorizations, W, D, the LCP matrices), the median time of a contact
step, and the peak memory of the process (each configuration runs in a process of its own).
Targets (issues 10 and 21): at 1681 and at 6561 rows a step costs at most 2x, the setup at most
3x the one-row plate's; 6561 rows runs within 24 GiB.

    python benchmarks/contact_scale.py [--sizes 2 4 8 16] [--steps 12] [--courant 0.5] [--quick]
    python benchmarks/contact_scale.py --friction 0.3 --sizes 8 [--courant 50] [--method velocity]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the fem-impact command does

CASE = Path(__file__).resolve().parents[1] / "cases" / "plate_drop.yaml"


METHODS = {"moreau_jean": ["solver.method=moreau_jean"],
           "velocity": ["solver.method=moreau_jean", "solver.level=velocity"],
           "newmark": ["solver.method=newmark"]}


def measure(cells: int, coupling: str, steps: int, method: str, friction: float = 0.0, courant: float = 0.5) -> dict:
    """One configuration, in this process."""
    import numpy as np
    from mpi4py import MPI

    from fem_impact.config.case import load_case
    from fem_impact.integrators import Operators
    from fem_impact.build import make_integrator, model_and_constraints

    dt = courant / cells   # (c = 1, h = 1 / cells)
    # the contact lasts 2 L / c = 2 n / C steps (4 n at Courant 0.5); two at least, the plate landing
    # within one; the last step run, whatever it is, is not timed
    n_steps = min(steps, max(4, math.ceil(2.0 * cells / courant)))
    overrides = [f"mesh.cells={cells}", f"solver.dt={dt}", f"solver.t_end={max(2.5, n_steps * dt)}",
                 f"contacts.0.gap={1.5 * dt}",
                 f"contacts.0.coupling={coupling}", *METHODS[method]]
    if friction:   # every row with friction, the plate sliding along its face as it lands
        overrides += [f"contacts.0.friction={friction}", "initial.velocity=[-1.0, 0.5, 0.3]"]
    t0 = time.perf_counter()
    case = load_case(CASE, overrides)
    model, cons = model_and_constraints(case, MPI.COMM_WORLD)
    ops = Operators(model.M, model.K, model.C, model.load, cons.P_local, cons.d0, cons.restitution,
                    friction=cons.friction if cons.pt else None, tangents=cons.tangent_local,
                    tangent_of=cons.tangent_of)
    integrator = make_integrator(case, ops)
    integrator.start(model.U0, model.V0)
    if method != "velocity":
        _ = integrator.D   # (built on the first closing otherwise: count it in the setup)
    setup = time.perf_counter() - t0
    times, contact = [], []
    for _ in range(n_steps):
        t0 = time.perf_counter()
        state = integrator.step()
        times.append(time.perf_counter() - t0)
        contact.append(np.count_nonzero(state.force) >= 0.5 * ops.p)
    assert all(contact[1:-1]), "the timed steps should be contact steps"
    timings = integrator.timings
    extra = {"sweeps": getattr(integrator, "friction_sweeps", 0), "newton": getattr(integrator, "friction_retries", 0),
             "residual": getattr(integrator, "friction_residual", 0.0),   # (the worst of the run's cone problems)
             "velocity_steps": getattr(integrator, "friction_velocity_steps", 0)}   # (position level's fall-backs)
    return {**extra, "cells": cells, "coupling": coupling, "rows": ops.p, "dofs": model.dofs, "courant": courant,
            "factorize_s": timings["factorize S"], "W_s": timings["W"], "D_s": timings.get("D", 0.0),
            "setup_s": setup,
            "first_contact_ms": 1e3 * times[1], "step_ms": 1e3 * float(np.median(times[2:-1])),
            "peak_MiB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def run_child(cells: int, coupling: str, steps: int, method: str, friction: float = 0.0, courant: float = 0.5) -> dict:
    out = subprocess.run([sys.executable, __file__, "--one", str(cells), coupling, "--steps", str(steps),
                          "--method", method, "--friction", str(friction), "--courant", str(courant)],
                         capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(out.stderr)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[2, 4, 8, 16],
                        help="cells through the thickness (face rows (5 n + 1)^2; default 2 4 8 16)")
    parser.add_argument("--steps", type=int, default=12, help="time steps per run (default 12; >= 4)")
    parser.add_argument("--quick", action="store_true", help="the smallest plate only (for CI)")
    parser.add_argument("--method", choices=sorted(METHODS), default="moreau_jean",
                        help="moreau_jean (the default), velocity (moreau_jean, level velocity), newmark")
    parser.add_argument("--friction", type=float, default=0.0,
                        help="Coulomb's mu on every row, the plate sliding as it lands (moreau_jean): the "
                             "frictional step against the frictionless one of the same rows")
    parser.add_argument("--courant", type=float, default=0.5,
                        help="Courant number c dt / h: dt = C / n (default 0.5); the gap 1.5 dt")
    parser.add_argument("--one", nargs=2, metavar=("CELLS", "COUPLING"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(measure(int(args.one[0]), args.one[1], max(4, args.steps), args.method, args.friction,
                                 args.courant)))
        return
    if args.friction:
        friction_table(args)
        return
    sizes = [2] if args.quick else args.sizes
    header = (f"{'rows':>6}{'coupling':>9}{'unknowns':>9}{'factor s':>9}{'W s':>8}{'D s':>8}{'setup s':>9}"
              f"{'1st ms':>9}{'step ms':>9}{'peak MiB':>9}{'step x':>8}{'setup x':>8}")
    print(f"method: {args.method}, Courant {args.courant:g}")
    print(header)
    print("-" * len(header))
    for cells in sizes:
        mean = run_child(cells, "mean", args.steps, args.method, courant=args.courant)
        each = run_child(cells, "each", args.steps, args.method, courant=args.courant)
        for r in (mean, each):
            ratios = (f"{r['step_ms'] / mean['step_ms']:>8.2f}{r['setup_s'] / mean['setup_s']:>8.2f}"
                      if r is each else f"{'':>8}{'':>8}")
            print(f"{r['rows']:>6}{r['coupling']:>9}{r['dofs']:>9}{r['factorize_s']:>9.2f}{r['W_s']:>8.2f}"
                  f"{r['D_s']:>8.2f}{r['setup_s']:>9.2f}{r['first_contact_ms']:>9.1f}{r['step_ms']:>9.1f}"
                  f"{r['peak_MiB']:>9.0f}" + ratios, flush=True)
    print("factor: the factorization of S; W, D: P S^-1 P^T and P M^-1 P^T (with their corrections' setup);\n"
          "setup: case to the started integrator, D included; 1st: the step in which the floor is reached;\n"
          "step: median contact step; step x, setup x: the many-row plate against the one-row plate.")


def friction_table(args) -> None:
    """Per size, every face node a row: the contact step with friction against the frictionless one."""
    header = (f"{'rows':>6}{'unknowns':>9}{'no friction ms':>15}{'friction ms':>12}{'ratio':>7}{'1st ms':>9}"
              f"{'sweeps':>7}{'newton':>7}{'residual':>10}{'peak MiB':>9}")
    if args.method == "newmark":
        sys.exit("contact_scale: --friction takes moreau_jean (either level: --method moreau_jean or velocity)")
    print(f"method: {args.method}, mu = {args.friction}, the plate sliding at (0.5, 0.3) as it lands, "
          f"Courant {args.courant:g}")
    print(header)
    print("-" * len(header))
    for cells in ([2] if args.quick else args.sizes):
        plain = run_child(cells, "each", args.steps, args.method, courant=args.courant)
        rough = run_child(cells, "each", args.steps, args.method, args.friction, args.courant)
        print(f"{rough['rows']:>6}{rough['dofs']:>9}{plain['step_ms']:>15.1f}{rough['step_ms']:>12.1f}"
              f"{rough['step_ms'] / plain['step_ms']:>7.2f}{rough['first_contact_ms']:>9.1f}{rough['sweeps']:>7}"
              f"{rough['newton']:>7}{rough['residual']:>10.1e}{rough['peak_MiB']:>9.0f}", flush=True)
    print("friction ms: median contact step after the landing; 1st: the landing step (with friction); sweeps: the\n"
          "most in one cone problem; newton: Newton's retries in the run; residual: the worst cone problem's; peak:\n"
          "the process with friction")


if __name__ == "__main__":
    main()
