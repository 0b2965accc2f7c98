"""Friction on small models: the frictional step against the frictionless one, in one run.

Two scenes of few unknowns whose rows are coupled through one body:

- ``block``: a 2D steel block 0.1 x 0.05 m (10 cells, 132 unknowns, 9 floor rows, 2 cm thick) sliding at
  0.5 m/s on a floor under gravity, mu = 0.25, dt = 1e-4, moreau_jean (cases/sliding_block.yaml changed
  by --set);
- ``conveyor``: a steel part 0.1 x 0.05 m (4 cells, 30 unknowns, 5 floor rows) on a vibratory tray seen in
  the tray's frame (the tray's acceleration as an inertial load: A w^2 (cos alpha, sin alpha) sin(w t),
  throw number 0.8, alpha = 30 deg, f = 20 Hz), mu = 0.5, dt = 4e-5.

Each is run with its friction and with mu = 0 (the same rows, no tangent rows), ``--repeat`` times each in
turn; the best loop time a step of each is kept. Prints per scene: ms a step with and without friction, their
ratio, the friction solver's Newton retries (Newton's method after the sweeps) and its largest sweeps and
residual. The target (issue "Speed where users run"): at most 3 times, no retries in steady sliding.

    python benchmarks/small_friction.py [--repeat 3] [--periods 3] [--quick]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the fem-impact command does

import fem_impact as fi  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BLOCK = ["mesh.length=0.1", "mesh.height=0.05", "mesh.cells=10", "material.E=2.1e11", "material.rho=7850",
         "material.nu=0.3", "material.area=0.02", "parameters.v0=0.5", "contacts.0.friction=0.25",
         "solver.dt=1e-4", "solver.t_end=0.3", "output.probes={}", "output.vtk=false"]


def conveyor(periods: float) -> fi.Case:
    f, throw, alpha, g = 20.0, 0.8, 0.5235987755982988, 9.81
    data = {"name": "conveyor_frame", "parameters": {"f": f, "throw": throw, "alpha": alpha, "g": g},
            "mesh": {"shape": "bar", "dim": 2, "length": 0.1, "height": 0.05, "cells": 4},
            "material": {"E": 2.0e11, "rho": 7800.0, "nu": 0.3, "area": 0.02},
            "loads": [{"body": "all", "acceleration": ["throw*g/sin(alpha)*cos(alpha)*sin(2*pi*f*t)",
                                                       "-g + throw*g*sin(2*pi*f*t)"]}],
            "contacts": [{"name": "tray", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0], "gap": 0.0,
                          "friction": 0.5}],
            "solver": {"dt": 4e-5, "t_end": periods / f}, "output": {"vtk": False, "every": 100}}
    return fi.Case.from_dict(data)


def timed(case: fi.Case, folder: Path) -> dict:
    result = fi.run(case, folder)
    s = result.summary
    return {"ms": 1e3 * s["loop_time_s"] / s["steps"], "retries": s.get("friction_retries", 0),
            "sweeps": s.get("max_friction_sweeps", 0), "residual": s.get("max_friction_residual", 0.0),
            "steps": s["steps"], "unknowns": s["dofs"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs of each (the best is kept; default 3)")
    parser.add_argument("--periods", type=float, default=3.0, help="the conveyor's drive periods (default 3)")
    parser.add_argument("--quick", action="store_true", help="a few steps of each, once (that it runs)")
    args = parser.parse_args()
    block = fi.load_case(ROOT / "cases" / "sliding_block.yaml", BLOCK + (["solver.t_end=0.005"] if args.quick else []))
    if args.quick:
        args.repeat, args.periods = 1, 0.1
    scenes = {"block": block, "conveyor": conveyor(args.periods)}
    with tempfile.TemporaryDirectory() as tmp:
        for name, case in scenes.items():
            runs = {"friction": case, "frictionless": case.with_changes({"contacts.0.friction": 0.0})}
            best: dict[str, dict] = {}
            for k in range(args.repeat):
                for kind, c in runs.items():
                    got = timed(c, Path(tmp) / f"{name}-{kind}-{k}")
                    if kind not in best or got["ms"] < best[kind]["ms"]:
                        best[kind] = got
            fr, free = best["friction"], best["frictionless"]
            print(f"{name}: {fr['unknowns']} unknowns, {fr['steps']} steps; friction {fr['ms']:.3f} ms a step, "
                  f"frictionless {free['ms']:.3f} ms: {fr['ms'] / free['ms']:.2f} times; Newton retries "
                  f"{fr['retries']}, largest sweeps {fr['sweeps']}, residual {fr['residual']:.2g}")


if __name__ == "__main__":
    main()
