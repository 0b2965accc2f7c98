"""Serial against 2 MPI ranks, per method and size: setup, time per step, peak memory, same history.

The scene: the 3D bar of B2a (cases/impacting_bar.yaml with ``mesh.dim=3``: 1 x 0.05 x 0.05,
cells along x = n and n / 20 across) falling end-on on a wall, one mean contact row, Courant
number 0.5, the wall reached a quarter into the run. Unknowns 3 (n + 1)(n / 20 + 1)^2: n = 100,
200 and 500 give 10 908, 72 963 and 1 016 028. Each configuration runs in a process of its own
(``--one``), serial and under ``mpirun -n 2`` in the same invocation; the table gives both, their
ratio (serial over 2 ranks: above 1 is faster on 2), the largest peak memory of a rank, and the
largest difference between the two histories relative to each column's scale.

The explicit many-row scene (``--plate 4 12 24``, cells through the thickness; ``--plate`` alone:
none): cases/plate_drop.yaml with central difference and a lumped mass, a 1 x 5 x 5 plate of
hexahedra landing face-first, every face node a contact row: 3 (n + 1)(5 n + 1)^2 unknowns and
(5 n + 1)^2 rows (n = 24: 1 098 075 unknowns, 14 641 rows), run through the whole impact (5 n
steps at Courant 0.5, to t = 2.5). Besides the times it checks what the physics guarantees: the
energy (with the scheme's term) never above the initial one, and the plate's momentum changed by
the floor's impulses (the largest gap, relative to the initial momentum).

    python benchmarks/scaling.py [--sizes 100 200 500] [--methods moreau_jean,newmark,central_difference,modal]
                                 [--steps 100] [--plate 4 12 24]

(The reduced model runs 20 times --steps, and its time a step is the best of 5 runs in the process:
its step takes about 0.1 ms, 2000 of them 0.2 s of loop, where this machine's noise gave 0.09 ms
serial against 0.12 on 2 ranks in one run, and equal times in three reruns. More steps do not
help: they are steps of free flight, which go in blocks of microseconds.)

The implicit methods and the reduced model stop at 72 963 unknowns unless a larger size is named
with ``--implicit-up-to`` (a direct factorization of 10^6 3D unknowns takes minutes and > 10 GB).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # as the fem-impact command does

ROOT = Path(__file__).resolve().parents[1]
CASE = ROOT / "cases" / "impacting_bar.yaml"
# Steps of a run, as a multiple of --steps: the reduced model's step takes 0.1 ms, so 100 of them would
# time 10 ms of loop, below this machine's noise; and runs of it, the best time a step kept.
STEPS_TIMES = {"modal": 20}
REPEATS = {"modal": 5}
METHODS = {
    "moreau_jean": ["solver.method=moreau_jean"],   # (the case file says newmark)
    "newmark": ["solver.method=newmark"],
    "central_difference": ["solver.method=central_difference"],
    "modal": ["solver.method=modal", "solver.modes=20"],
}
MPIRUN = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", "2"]


PLATE_CASE = ROOT / "cases" / "plate_drop.yaml"
PLATE = "plate"   # the explicit many-row scene, as a "method" of one()


def unknowns(cells: int) -> int:
    return 3 * (cells + 1) * (cells // 20 + 1) ** 2


def plate_unknowns(cells: int) -> int:
    return 3 * (cells + 1) * (5 * cells + 1) ** 2


def one(method: str, cells: int, steps: int, history_file: str) -> None:
    """Run one configuration in this process (every rank); rank 0 prints a JSON line."""
    import numpy as np
    from mpi4py import MPI

    import fem_impact as fi

    dt = 0.5 / cells   # c = 1, h = 1 / cells
    if method == PLATE:   # the whole impact: contact on [0.1, 2.1], then free
        case = PLATE_CASE
        overrides = [f"mesh.cells={cells}", f"solver.dt={dt}", "solver.method=central_difference",
                     "solver.mass=lumped", "output.vtk=false", "output.every=1"]
    else:
        case = CASE
        overrides = ["mesh.dim=3", f"mesh.cells={cells}", "contacts.0.coupling=mean", f"solver.dt={dt}",
                     f"solver.t_end={steps * dt}", f"contacts.0.gap={steps / 4 * dt}", "output.vtk=false",
                     f"output.every={steps}", *METHODS[method]]
    result = fi.run(fi.load_case(case, overrides))
    loop_s = result.summary["loop_time_s"]
    for _ in range(REPEATS.get(method, 1) - 1):   # (the same run again: its modes from the cache)
        loop_s = min(loop_s, fi.run(fi.load_case(case, overrides)).summary["loop_time_s"])
    comm = MPI.COMM_WORLD
    peak = comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, op=MPI.MAX)
    if comm.rank == 0:
        h = result.history
        np.savez(history_file, **h)
        s = result.summary
        data = {"setup_s": s["setup_time_s"], "step_ms": 1e3 * loop_s / s["steps"], "peak_MiB": peak,
                "dofs": s["dofs"], "ranks": comm.size}
        if method == PLATE:
            energy = h["kinetic"] + h["strain"] + h["scheme_energy"]
            data["energy_over_E0"] = float(energy.max() / energy[0])
            momentum = h["bar.px"] - h["bar.px"][0]
            data["momentum_gap"] = float(np.abs(momentum - np.cumsum(h["floor.impulse"])).max()
                                         / abs(h["bar.px"][0]))
            data["impulse"] = float(h["floor.impulse"].sum())
        print("JSON" + json.dumps(data), flush=True)


def run_child(method: str, cells: int, steps: int, ranks: int, folder: Path) -> dict:
    history = folder / f"{method}-{cells}-{ranks}.npz"
    command = [sys.executable, __file__, "--one", method, str(cells), str(steps), str(history)]
    if ranks > 1:
        command = MPIRUN + command
    # (a process that has initialized MPI itself, e.g. a test run, leaves OMPI_/PMIX_ variables that make
    # a child mpirun think it is nested: they are not passed on)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_", "PMIX_", "OPAL_"))}
    out = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, env=env)
    if out.returncode:
        raise SystemExit(f"{' '.join(command)} failed:\n{out.stderr[-2000:]}")
    data = json.loads(out.stdout.split("JSON", 1)[1].splitlines()[0])
    data["history"] = history
    return data


ENERGIES = {"kinetic", "strain", "external_work", "damping_loss", "impact_loss", "contact_loss", "energy_error",
            "scheme_energy", "friction_loss"}


def family(name: str) -> str:
    """Columns that share a unit and a scale: the energies, a body's momenta, a probe's displacements..."""
    if name in ENERGIES:
        return "energy"
    head, _, tail = name.rpartition(".")
    return f"{head}.{tail[:1]}" if tail[:1] in "puv" and len(tail) == 2 else name


def difference(a: Path, b: Path) -> float:
    """The largest difference between two histories, each column relative to the largest magnitude of its
    family (an energy residual of 1e-19 is judged against the energies, not against itself)."""
    import numpy as np

    x, y = np.load(a), np.load(b)
    scales: dict[str, float] = {}
    for name in x.files:
        scales[family(name)] = max(scales.get(family(name), 0.0), float(np.abs(x[name]).max()))
    worst = 0.0
    for name in x.files:
        scale = scales[family(name)]
        if scale > 0.0:
            worst = max(worst, float(np.abs(x[name] - y[name]).max()) / scale)
    return worst


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 200, 500], help="cells along the bar")
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated, of: " + ", ".join(METHODS))
    parser.add_argument("--steps", type=int, default=100, help="time steps per run (default 100)")
    parser.add_argument("--implicit-up-to", type=int, default=200, help="largest cells for the implicit methods and "
                        "the reduced model (default 200: 72 963 unknowns)")
    parser.add_argument("--plate", type=int, nargs="*", default=[4, 12, 24],
                        help="cells through the thickness of the explicit plate scene (default 4 12 24; none: skip it)")
    parser.add_argument("--one", nargs=4, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        method, cells, steps, history = args.one
        one(method, int(cells), int(steps), history)
        return
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise SystemExit(f"unknown method {unknown[0]!r} (known: {', '.join(METHODS)})")
    print(f"3D bar end-on on a wall, one mean contact row, Courant 0.5, {args.steps} steps; serial and 2 ranks "
          f"(ratio = serial / 2 ranks; > 1: faster on 2)", flush=True)
    print(f"{'method':<20}{'unknowns':>10}{'setup 1':>9}{'setup 2':>9}{'ratio':>7}{'step 1 ms':>11}{'step 2 ms':>11}"
          f"{'ratio':>7}{'peak 1 MiB':>11}{'peak 2 MiB':>11}{'history diff':>14}", flush=True)
    with tempfile.TemporaryDirectory() as folder:
        for method in methods:
            for cells in args.sizes:
                if method != "central_difference" and cells > args.implicit_up_to:
                    continue
                steps = args.steps * STEPS_TIMES.get(method, 1)
                serial = run_child(method, cells, steps, 1, Path(folder))
                pair = run_child(method, cells, steps, 2, Path(folder))
                diff = difference(serial["history"], pair["history"])
                print(f"{method:<20}{unknowns(cells):>10}{serial['setup_s']:>9.2f}{pair['setup_s']:>9.2f}"
                      f"{serial['setup_s'] / pair['setup_s']:>7.2f}{serial['step_ms']:>11.2f}{pair['step_ms']:>11.2f}"
                      f"{serial['step_ms'] / pair['step_ms']:>7.2f}{serial['peak_MiB']:>11.0f}{pair['peak_MiB']:>11.0f}"
                      f"{diff:>14.1e}", flush=True)
        if args.plate:
            print("\nExplicit plate landing face-first (cases/plate_drop.yaml, central difference, lumped mass), every "
                  "face node a row, the whole impact (5 n steps); E max / E0 and the momentum gap on 1 | 2 ranks",
                  flush=True)
            print(f"{'rows':>7}{'unknowns':>10}{'setup 1':>9}{'setup 2':>9}{'ratio':>7}{'step 1 ms':>11}"
                  f"{'step 2 ms':>11}{'ratio':>7}{'peak 1 MiB':>11}{'peak 2 MiB':>11}{'history diff':>14}"
                  f"{'E max / E0, 1 | 2':>32}{'momentum gap, 1 | 2':>22}", flush=True)
        for cells in args.plate:
            serial = run_child(PLATE, cells, 5 * cells, 1, Path(folder))
            pair = run_child(PLATE, cells, 5 * cells, 2, Path(folder))
            diff = difference(serial["history"], pair["history"])
            print(f"{(5 * cells + 1) ** 2:>7}{plate_unknowns(cells):>10}{serial['setup_s']:>9.2f}{pair['setup_s']:>9.2f}"
                  f"{serial['setup_s'] / pair['setup_s']:>7.2f}{serial['step_ms']:>11.2f}{pair['step_ms']:>11.2f}"
                  f"{serial['step_ms'] / pair['step_ms']:>7.2f}{serial['peak_MiB']:>11.0f}{pair['peak_MiB']:>11.0f}"
                  f"{diff:>14.1e}   {serial['energy_over_E0']:.12f} | {pair['energy_over_E0']:.12f}"
                  f"   {serial['momentum_gap']:.1e} | {pair['momentum_gap']:.1e}", flush=True)


if __name__ == "__main__":
    main()
