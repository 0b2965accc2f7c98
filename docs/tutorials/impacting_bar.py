"""The default case (B2a): a free bar hits a rigid wall; read the contact and the rebound from its history.

    python docs/tutorials/impacting_bar.py              # the case as committed: 250 cells
    python docs/tutorials/impacting_bar.py --cells 50   # coarser (the test suite's quick run)

The exact answer (docs/benchmarks.md B2): contact on [0.1, 2.1], force rho c A v0 = 1, the bar leaves
at +1; with restitution 0 at the node the impact removes 1/(2 sqrt(3) n_el) of the energy
(docs/theory.md s. 9). The run is the case file's (the paper's Newmark scheme), then the same with the default method.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import fem_impact

CASE = Path(__file__).resolve().parents[2] / "cases" / "impacting_bar.yaml"


def contact(result) -> dict:
    """The contact's start and end (the steps that carry an impulse), its mean force, the bar's rebound
    velocity (its momentum over its mass), the impact loss and the energy balance's residual."""
    h, summary = result.history, result.summary
    t, impulse = h["t"], h["wall.impulse"]
    on = np.nonzero(impulse > 0)[0]
    start, end = t[on[0] - 1], t[on[-1]]              # an impulse is booked at the end of its step
    return {"start": start, "end": end, "impulse": impulse.sum(), "force": impulse.sum() / (end - start),
            "rebound": h["bar.px"][-1] / summary["body_mass"]["bar"],
            "loss": h["impact_loss"][-1] / summary["initial_energy"],
            "residual": summary["max_energy_error_relative"]}


def main(cells: int = 250) -> dict:
    case = fem_impact.load_case(CASE)
    # keep the Courant number c dt / h = 0.5 of the case file when the mesh changes
    case = case.with_changes({"mesh.cells": cells, "solver.dt": 0.5 / cells, "output.vtk": False})
    rows = {}
    for method in ("newmark", "moreau_jean"):
        result = fem_impact.run(case.with_changes({"solver.method": method}))   # nothing written to disk
        rows[method] = contact(result)
    print(f"{'method':<12} {'start':>7} {'end':>7} {'impulse':>8} {'force':>7} {'rebound':>8} {'loss':>9} "
          f"{'residual':>9}")
    print(f"{'exact':<12} {0.1:7.4f} {2.1:7.4f} {2.0:8.4f} {1.0:7.4f} {1.0:8.4f} {1 / (2 * 3**0.5 * cells):9.2e}")
    for method, r in rows.items():
        print(f"{method:<12} {r['start']:7.4f} {r['end']:7.4f} {r['impulse']:8.4f} {r['force']:7.4f} "
              f"{r['rebound']:8.4f} {r['loss']:9.2e} {r['residual']:9.1e}")
    return rows


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", type=int, default=250, help="cells along the bar (default 250)")
    main(parser.parse_args().cells)
