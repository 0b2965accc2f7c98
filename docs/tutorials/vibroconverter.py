"""The free vibroconverter: a steel horn released in its first mode strikes a stop 5 um from its tip.

    python docs/tutorials/vibroconverter.py               # the case as committed: 50 periods
    python docs/tutorials/vibroconverter.py --periods 2   # the first two impacts only
    python docs/tutorials/vibroconverter.py --modal       # the reduced model (modes: auto)

Each impact is a run of steps whose contact carries an impulse; the script lists them (time in
periods T1 = 1 / 25.944 kHz, impulse in mN s) and checks the energy budget.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import fem_impact

CASE = Path(__file__).resolve().parents[2] / "cases" / "vibroconverter_free.yaml"
T1 = 1 / 25944.0   # s: the first period, c / 2L


def impacts(t: np.ndarray, impulse: np.ndarray) -> list[tuple[float, float]]:
    """(start time, summed impulse) of each run of consecutive steps that carry an impulse."""
    on = impulse > 0
    starts = np.nonzero(on & ~np.r_[False, on[:-1]])[0]
    ends = np.nonzero(on & ~np.r_[on[1:], False])[0]
    return [(t[a], impulse[a:b + 1].sum()) for a, b in zip(starts, ends)]


def main(periods: float = 50, modal: bool = False) -> dict:
    changes = {"solver.t_end": periods * T1, "output.vtk": False}
    if modal:
        changes.update({"solver.method": "modal", "solver.modes": "auto"})
    result = fem_impact.run(fem_impact.load_case(CASE).with_changes(changes))
    h = result.history
    found = impacts(h["t"], h["stop.impulse"])
    for k, (t, s) in enumerate(found, 1):
        print(f"impact {k}: t = {t / T1:.3f} T1, impulse {s * 1e3:.3f} mN s")
    print(f"{result.summary['steps']} steps, {result.summary['dofs']} unknowns, modes {result.summary['modes']}; "
          f"energy residual {result.summary['max_energy_error_relative']:.1e} of the energy scale")
    return {"impacts": found, "summary": result.summary}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--periods", type=float, default=50, help="run length in first periods (default 50)")
    parser.add_argument("--modal", action="store_true", help="the reduced model, modes: auto")
    args = parser.parse_args()
    main(args.periods, args.modal)
