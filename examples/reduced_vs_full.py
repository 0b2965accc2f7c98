"""The reduced model against the full model on B3 (cases/beam_stop.yaml): a clamped beam whose tip,
pushed by a constant force, hits an elastic stop. The reduced model keeps n1 eigenmodes plus the
static compliance of the truncated ones (Barauskas 1992); without that correction it misses the
contact compliance whatever n1. Compared: the stop's total impulse and the tip's largest deflection.

    python examples/reduced_vs_full.py            # the case as committed (60 x 10 cells)
    python examples/reduced_vs_full.py --coarse   # 20 cells along, a shorter run (the test suite)
"""

import sys
from pathlib import Path

import fem_impact

CASE = Path(__file__).resolve().parents[1] / "cases" / "beam_stop.yaml"


def main(coarse: bool = False) -> dict:
    full = fem_impact.load_case(CASE).with_changes({"solver.method": "moreau_jean"})
    if coarse:
        full = full.with_changes({"mesh.cells": 20, "solver.t_end": 0.05})
    runs = {"full": full}
    for n1 in (2, 5, 10):
        for static in (True, False):
            runs[f"{n1} modes{' + static' if static else ''}"] = full.with_changes(
                {"solver.method": "modal", "solver.modes": n1, "solver.static_correction": static})
    rows = {}
    print(f"{'model':<18} {'unknowns':>8} {'stop impulse (N s)':>19} {'max tip deflection (m)':>23} {'loop (s)':>8}")
    for name, case in runs.items():
        result = fem_impact.run(case)
        h, s = result.history, result.summary
        rows[name] = {"impulse": h["stop.impulse"].sum(), "deflection": -h["tip.uy"].min(),
                      "unknowns": s["modes"] or s["dofs"]}
        print(f"{name:<18} {rows[name]['unknowns']:>8} {rows[name]['impulse']:>19.5g} "
              f"{rows[name]['deflection']:>23.5g} {s['loop_time_s']:>8.2f}")
    return rows


if __name__ == "__main__":
    main(coarse="--coarse" in sys.argv)
