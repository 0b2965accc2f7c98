"""A parameter study in a loop: a free bar hits a rigid wall (docs/benchmarks.md B2) and stays in
contact for exactly 2 L / c, whatever its length L. Each run is a changed copy of one case,
run in memory (nothing is written to disk).

    python examples/parameter_study.py            # 400 cells per unit length
    python examples/parameter_study.py --coarse   # 50 (what the test suite runs)
"""

import sys

import numpy as np

import fem_impact

E, RHO, V0, GAP = 1.0, 1.0, 1.0, 0.1   # Pa, kg/m^3, m/s, m (nondimensional B2a)


def main(coarse: bool = False) -> list[dict]:
    cells_per_length = 50 if coarse else 400
    c = np.sqrt(E / RHO)   # wave speed
    base = fem_impact.Case.from_dict({
        "mesh": {"shape": "bar", "length": 1.0, "cells": cells_per_length},
        "material": {"E": E, "rho": RHO},
        "initial": {"velocity": [-V0]},
        "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0], "gap": GAP}],
        "solver": {"dt": 0.5 / (cells_per_length * c), "t_end": 1.0},   # Courant number 0.5
    })
    rows = []
    print(f"{'L (m)':>6} {'contact (s)':>12} {'2L/c (s)':>9} {'force (N)':>10} {'rho c A v0':>10}")
    for length in (0.5, 1.0, 2.0):
        case = base.with_changes({"mesh.length": length, "mesh.cells": int(cells_per_length * length),
                                  "solver.t_end": GAP / V0 + 2 * length / c + 0.5})
        h = fem_impact.run(case).history
        touching = h["wall.impulse"] > 0.0
        duration = h["t"][touching][-1] - h["t"][touching][0] + case.solver.dt   # (impulses over whole steps)
        force = h["wall.force"][touching].mean()
        rows.append({"length": length, "duration": duration, "exact": 2 * length / c, "force": force})
        print(f"{length:6.2f} {duration:12.4f} {2 * length / c:9.4f} {force:10.4f} {RHO * c * V0:10.4f}")
    return rows


if __name__ == "__main__":
    main(coarse="--coarse" in sys.argv)
