"""A vibratory conveyor (cases/vibratory_conveyor.yaml): a part on a tray moving obliquely, the tray an
obstacle given a motion. The rigid block's theory is integrated here on a point mass, at a step 25 to 100
times finer than the runs':

- the sliding regime (throw number 0.8: the tray's normal acceleration stays below g, the normal force is
  m (g + a_n(t)) throughout), Coulomb's law at the velocity level: the part's mean speed over a period
  (periods.csv) settles on it within 1 %, elastic (the case) or rigid;
- the hopping regime (1.5: the part leaves the tray each period and lands on it, e = 0), the flight and
  the landing's impulse in Coulomb's cone: a rigid part's first ten periods within 1 %. (An elastic part
  rebounds from its landings through its waves, whatever the nodes' e: it is not the rigid theory's.)
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


def hopping_speeds(f: float, throw: float, alpha: float, mu: float, g: float, periods: int,
                   per_period: int = 20000) -> np.ndarray:
    """A point mass on the tray, Moreau-Jean at the velocity level: in flight under gravity; where its
    gap, predicted to mid-step, is closed, the normal impulse that stops its approach (e = 0) and the
    tangential one toward the tray's speed, within mu times it (a unit mass: the two decouple)."""
    w = 2 * np.pi * f
    A = throw * g / (w * w * np.sin(alpha))
    h, ca, sa = 1.0 / (f * per_period), np.cos(alpha), np.sin(alpha)
    y = vx = vy = 0.0
    means = []
    for k in range(periods):
        area = 0.0
        for j in range(per_period):
            t0 = (k * per_period + j) * h
            t1 = t0 + h
            gap, approach = y - A * sa * np.sin(w * t0), -(vy - A * w * sa * np.cos(w * t0))
            vx1, vy1 = vx, vy - g * h
            if gap - 0.5 * h * approach <= 1e-12:
                normal = max(0.0, A * w * sa * np.cos(w * t1) - vy1)
                vy1 += normal
                vx1 -= np.clip(vx1 - A * w * ca * np.cos(w * t1), -mu * normal, mu * normal)
            area += 0.5 * (vx + vx1) * h
            y += 0.5 * (vy + vy1) * h
            vx, vy = vx1, vy1
        means.append(area * f)
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


@pytest.mark.slow   # (the default tier: docs/tutorials/shaken_table.py's rigid part, against the same figure)
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


@pytest.mark.slow
def test_a_rigid_part_hops_along_at_the_theorys_speed(tmp_path):
    theory = hopping_speeds(periods=10, **{**THEORY, "throw": 1.5})
    case = fi.load_case(CASES / "vibratory_conveyor.yaml", ["bodies={bar: {model: rigid}}", "parameters.throw=1.5",
                                                            "solver.dt=6.25e-5", "solver.t_end=0.5",
                                                            "output.vtk=false"])
    result = fi.run(case, tmp_path / "hopping")
    assert mean_speeds(result) == pytest.approx(theory, rel=0.01)
    assert result.summary["impacts"]["tray"] >= 10   # (it lands every period)
