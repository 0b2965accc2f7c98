"""A vibratory conveyor in its sliding regime (cases/vibratory_conveyor.yaml): a part on a tray moving
obliquely, the tray an obstacle given a motion. The rigid block's stick-slip theory is integrated here, at
a step a hundred times finer than the runs' (Coulomb's law at the velocity level on a point mass; the
tray's normal acceleration stays below g, so the normal force is m (g + a_n(t)) throughout); the part's
mean speed over a period (periods.csv) settles on it within 1 %, elastic (the case) or rigid.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES


def stick_slip_speeds(f: float, throw: float, alpha: float, mu: float, g: float, periods: int,
                      per_period: int = 40000) -> np.ndarray:
    """The block's mean speed over each period: v' = -mu N sign(v - u) while it slips, v = u while it sticks
    (the tray's speed u(t), its normal acceleration a_n(t), N = g + a_n per unit mass)."""
    w = 2 * np.pi * f
    A = throw * g / (w * w * np.sin(alpha))
    h, v, means = 1.0 / (f * per_period), 0.0, []
    for k in range(periods):
        t = k / f + h * np.arange(per_period + 1)
        u = A * w * np.cos(alpha) * np.cos(w * t)
        grip = mu * h * (g - A * w * w * np.sin(alpha) * np.sin(w * (t[:-1] + 0.5 * h)))
        speeds = np.empty(per_period + 1)
        speeds[0] = v
        for j in range(per_period):   # (a point mass: the tray's grip moves it toward the tray's speed)
            slip = v - u[j + 1]
            v = u[j + 1] if abs(slip) <= grip[j] else v - np.sign(slip) * grip[j]
            speeds[j + 1] = v
        means.append(0.5 * h * (speeds[1:] + speeds[:-1]).sum() * f)
    return np.array(means)


def mean_speeds(result) -> np.ndarray:
    with open(result.outdir / "periods.csv", newline="") as f:
        return np.array([float(row["bar.vx_mean"]) for row in csv.DictReader(f)])


THEORY = dict(f=20.0, throw=0.8, alpha=np.radians(30.0), mu=0.4, g=9.81)


@pytest.fixture(scope="module")
def theory():
    return stick_slip_speeds(periods=12, **THEORY)


def test_the_stick_slip_theory_settles(theory):
    assert theory[-1] == pytest.approx(0.04838, rel=1e-3) and abs(theory[-1] - theory[-3]) <= 1e-6


def test_a_rigid_part_is_conveyed_at_the_theorys_speed(tmp_path, theory):
    case = fi.load_case(CASES / "vibratory_conveyor.yaml", ["bodies={bar: {model: rigid}}", "solver.dt=1.25e-4",
                                                            "solver.t_end=0.5", "output.vtk=false"])
    speeds = mean_speeds(fi.run(case, tmp_path / "rigid"))
    assert speeds[6:] == pytest.approx(theory[6:10], rel=0.01)


@pytest.mark.slow
def test_an_elastic_part_is_conveyed_at_the_theorys_speed(tmp_path, theory):
    result = fi.run(fi.load_case(CASES / "vibratory_conveyor.yaml", ["output.vtk=false"]), tmp_path / "elastic")
    assert mean_speeds(result)[6:] == pytest.approx(theory[6:], rel=0.01)
    h = result.history
    assert np.abs(h["energy_error"]).max() <= result.summary["energy_roundoff"] + 1e-9 * h["external_work"].max()
    assert np.diff(h["friction_loss"]).min() >= -1e-9 * h["friction_loss"].max()
