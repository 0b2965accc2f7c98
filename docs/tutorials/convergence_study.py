"""A study: how B2a's impact loss and contact force converge under mesh refinement.

    python docs/tutorials/convergence_study.py                       # 50, 100, 200, 400 cells
    python docs/tutorials/convergence_study.py --cells 25 50 100     # quicker

Each level is one run of the default case at the case's Courant number (c dt / h = 0.5), with the
default method, nothing written to disk. With restitution 0 at the contact node the impact removes
1/(2 sqrt(3) n_el) of the energy (docs/benchmarks.md B2): the observed order of the loss is 1. The
command ``fem-impact study convergence`` does the same for every error measure, with a table, a
chart and resumable levels (docs/studies.md).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import fem_impact

CASE = Path(__file__).resolve().parents[2] / "cases" / "impacting_bar.yaml"


def order(h: list[float], errors: list[float]) -> float:
    """The least-squares slope of log(error) against log(h)."""
    return float(np.polyfit(np.log(h), np.log(errors), 1)[0])


def main(cells: tuple[int, ...] = (50, 100, 200, 400)) -> dict:
    base = fem_impact.load_case(CASE).with_changes({"solver.method": None, "output.vtk": False})  # the default method
    rows = []
    for n in cells:
        result = fem_impact.run(base.with_changes({"mesh.cells": n, "solver.dt": 0.5 / n}))
        h = result.history
        on = h["wall.impulse"] > 0
        loss = h["impact_loss"][-1] / result.summary["initial_energy"]
        rows.append({"cells": n, "loss": loss, "exact_loss": 1 / (2 * math.sqrt(3) * n),
                     "force_error": abs(h["wall.force"][on].mean() - 1.0),
                     "wall_time_s": result.summary["wall_time_s"]})
        r = rows[-1]
        print(f"{n:5d} cells: impact loss {r['loss']:.4e} of E0 (exact {r['exact_loss']:.4e}), "
              f"mean force error {r['force_error']:.2e}, {r['wall_time_s']:.2f} s")
    h = [1 / r["cells"] for r in rows]
    fitted = {"loss": order(h, [r["loss"] for r in rows])}
    print(f"observed order of the impact loss: {fitted['loss']:.2f} (theory: 1)")
    return {"rows": rows, "orders": fitted}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, nargs="+", default=[50, 100, 200, 400], help="the levels' cells")
    main(tuple(parser.parse_args().cells))
