"""Where a method fails, shown rather than hidden: the tip section of a beam (11 nodes, a contact row
each) pressed on a rigid stop, stepped at a Courant number of about 12, as an implicit run is chosen
for. The paper's Newmark scheme creates energy there (its contact forces give back work at every
release); Moreau-Jean does not. Every run checks E <= E0 + W_ext itself (summary: max_energy_ratio,
energy_created_at); with stop_on_energy_gain it stops with a SimulationError at the first gain.

    python examples/large_steps.py            # 2 s (1000 steps)
    python examples/large_steps.py --coarse   # 0.4 s (the test suite)
"""

import sys
from pathlib import Path

import fem_impact

CASE = Path(__file__).resolve().parents[1] / "cases" / "face_on_stop.yaml"


def main(coarse: bool = False) -> dict:
    base = fem_impact.load_case(CASE, ["output.vtk=false"] + (["solver.t_end=0.4"] if coarse else []))
    ratios = {}
    for method in ("newmark", "moreau_jean"):
        s = fem_impact.run(base.with_changes({"solver.method": method})).summary
        ratios[method] = s["max_energy_ratio"]
        verdict = (f"creates energy from t = {s['energy_created_at']:.3g} s" if s["energy_created_at"] is not None
                   else "never exceeds E0 + W_ext")
        print(f"{method:<12} max E / (E0 + W_ext) = {s['max_energy_ratio']:7.3f}: {verdict}")
    try:
        fem_impact.run(base.with_changes({"solver.method": "newmark"}), stop_on_energy_gain=True)
    except fem_impact.SimulationError as err:
        print(f"with stop_on_energy_gain: {type(err).__name__}: {err}")
    return ratios


if __name__ == "__main__":
    main(coarse="--coarse" in sys.argv)
