"""The vibrodrive: a resonant rod strikes the 30 deg face of a free slider and launches it.

    python docs/tutorials/vibrodrive.py                  # the case as committed: 5 ms, about 10 s
    python docs/tutorials/vibrodrive.py --t-end 6.4e-4   # the first two strikes only

Each strike's normal impulse S pushes the slider along the guide with S sin 30 (the guide takes the
rest): the slider's momentum must equal sin 30 times the sum of the strike impulses, to round-off.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

import fem_impact

CASE = Path(__file__).resolve().parents[2] / "cases" / "vibrodrive.yaml"
T1 = 1 / 17168.8   # s: the drive's period (the first longitudinal mode of stack and rod)


def strikes(t: np.ndarray, impulse: np.ndarray) -> list[tuple[float, float]]:
    """(start time, summed impulse) of each run of consecutive steps that carry an impulse."""
    on = impulse > 0
    starts = np.nonzero(on & ~np.r_[False, on[:-1]])[0]
    ends = np.nonzero(on & ~np.r_[on[1:], False])[0]
    return [(t[a], impulse[a:b + 1].sum()) for a, b in zip(starts, ends)]


def main(t_end: float = 5.0e-3) -> dict:
    result = fem_impact.run(fem_impact.load_case(CASE).with_changes({"solver.t_end": t_end, "output.vtk": False}))
    h, summary = result.history, result.summary
    found = strikes(h["t"], h["strike.impulse"])
    for k, (t, s) in enumerate(found, 1):
        print(f"strike {k}: t = {t / T1:.2f} T1, impulse {s * 1e3:.3f} mN s along the normal")
    mass = summary["body_mass"]["slider"]
    momentum = h["slider.px"][-1] - h["slider.px"][0]
    pushed = math.sin(math.radians(30)) * h["strike.impulse"].sum()
    speed = momentum / mass
    print(f"slider: {mass * 1e3:.1f} g, speed {speed * 1e3:.2f} mm/s at t = {t_end * 1e3:g} ms; momentum "
          f"{momentum:.6e} N s against sin 30 x impulses {pushed:.6e} (relative difference "
          f"{abs(momentum - pushed) / abs(pushed):.1e})")
    return {"strikes": found, "speed": speed, "momentum": momentum, "pushed": pushed, "summary": summary}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--t-end", type=float, default=5.0e-3, help="end time in s (default 5e-3, the case's)")
    main(parser.parse_args().t_end)
