"""``fem-impact study response`` and shooting on the impact oscillator (cases/impact_oscillator.yaml) against
the closed forms of docs/impact_oscillator.md (fem_impact/periodic/oscillator.py).

The case is a clamped-free rod reduced to its first mode without static correction, forced at its
tip, a rigid stop there at zero gap, r = 0.8: in tau = w1 t and X = u w1^2 / (phi^2 F0) (phi: the
mass-normalized mode's tip value) it is X'' + X = cos(w tau), w = 2 pi f / w1, with
X' = u' w1 / (phi^2 F0). The impulse per period of the period-1 orbit is (1 + r) V / phi^2.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import fem_impact as fi
from fem_impact.app.studies.response import detect_period, response_study
from fem_impact.periodic import oscillator as exact
from fem_impact.periodic.shooting import reduced_scene, shoot

from conftest import CASES

R = 0.8
F0 = np.pi / 4


def scene(f):
    s = reduced_scene(fi.load_case(CASES / "impact_oscillator.yaml", [f"parameters.f={f}"]))
    w1, phi = np.sqrt(s.system.w2[0]), s.probe_rows[0, 0]
    return s, w1, phi


def test_shooting_finds_the_period_one_orbit_and_its_multipliers():
    for f in (0.45, 0.6):
        s, w1, phi = scene(f)
        w = 2 * np.pi * f / w1
        orbit = shoot(s.system, s.start + np.array([-0.3, 0.1]), 1.0 / f, 1)
        closed = exact.period1_orbit(w, R)
        # the orbit's point on the section, scaled: X = u w1^2 / (phi^2 F0), X' = u' w1 / (phi^2 F0)
        X = phi * orbit.x[0] * w1**2 / (phi**2 * F0)
        Xdot = phi * orbit.x[1] * w1 / (phi**2 * F0)
        assert X == pytest.approx(closed.state[0], rel=1e-4, abs=1e-4 * abs(closed.speed))
        assert Xdot == pytest.approx(closed.state[1], rel=1e-4, abs=1e-4 * abs(closed.speed))
        (t, _, speed), = orbit.impacts   # one impact a period, at the closed form's speed
        assert speed * w1 / (phi**2 * F0) == pytest.approx(closed.speed, rel=1e-4)   # (speed: the tip's, u')
        # the flight keeps area, each impact scales it by r^2 (docs/impact_oscillator.md s. 4)
        assert np.prod(orbit.multipliers).real == pytest.approx(R**2, rel=1e-6)
        assert orbit.stable and orbit.residual <= 1e-10


def test_an_up_sweep_finds_period_one_then_period_two_past_the_period_doubling(tmp_path):
    """Event-driven levels: the settled section has period 1 below the period doubling and 2 above;
    the period-1 points give the closed-form impact speed; the shooting's multiplier crosses -1 at
    the closed form's w_PD (cos^2(pi/w)(w^2 - rho^2) = 1), located within 0.005 in w."""
    values = [0.45, 0.5, 0.64, 0.66, 0.6645, 0.667]
    case = fi.load_case(CASES / "impact_oscillator.yaml")
    result = response_study(case, "parameters.f=" + ",".join(map(str, values)), tmp_path, settle=150, periods=8,
                            flight="events", quiet=True)
    rows = {}
    for row in result["rows"]:
        rows.setdefault(row["parameters.f"], []).append(row)
    assert [rows[f][0]["period"] for f in values] == [1, 1, 1, 1, 2, 2]
    _, w1, phi = scene(0.5)
    for f in (0.45, 0.5):
        V = rows[f][0]["stop.impulse"] * phi**2 / (1 + R)          # the physical approach speed
        assert V * w1 / (phi**2 * F0) == pytest.approx(exact.impact_speed(2 * np.pi * f / w1, R), rel=0.005)
        assert rows[f][0]["stop.impacts"] == 1
    (mark,) = result["bifurcations"]
    assert mark["kind"] == "period_doubling" and mark["between"] == [0.66, 0.6645]
    w_pd = 2 * np.pi * mark["parameters.f"] / w1
    assert w_pd == pytest.approx(exact.period_doubling_frequency(R), abs=0.005)
    # the period-2 points alternate: two impacts of different impulse
    assert abs(rows[0.667][0]["stop.impulse"] - rows[0.667][1]["stop.impulse"]) > 1e-3 * rows[0.667][0]["stop.impulse"]
    import csv

    with open(tmp_path / "response.csv", newline="") as f:
        marked = {r["bifurcation"] for r in csv.DictReader(f)
                  if r["direction"] == "up" and float(r["parameters.f"]) == 0.6645}
    assert marked == {f"period_doubling at {mark['parameters.f']:.6g}"}
    study = json.loads((tmp_path / "study.json").read_text())
    assert study["bifurcations_up"][0]["kind"] == "period_doubling"
    assert (tmp_path / "response.png").stat().st_size > 10_000
    # a sweep down into the same folder keeps the sweep up: both in response.csv
    down = response_study(case, "parameters.f=0.66,0.667", tmp_path, down=True, settle=150, periods=8,
                          flight="events", quiet=True)
    assert {r["direction"] for r in down["rows"]} == {"up", "down"}


@pytest.mark.slow
def test_the_time_stepped_sweep_gives_the_closed_form_impact_speed(tmp_path):
    """The default flight, the case's Moreau-Jean steps (1000 a period): its impacts fall at the ends of
    steps, so its impact speed carries an error of the step's order (measured: 0.12 % at f = 0.45
    with 1000 steps a period)."""
    case = fi.load_case(CASES / "impact_oscillator.yaml")
    result = response_study(case, "parameters.f=0.45,0.5", tmp_path, settle=100, periods=6, steps_per_period=1000,
                            quiet=True)
    _, w1, phi = scene(0.5)
    for f in (0.45, 0.5):
        (row,) = [r for r in result["rows"] if r["parameters.f"] == f]
        assert row["period"] == 1
        V = row["stop.impulse"] * phi**2 / (1 + R)
        assert V * w1 / (phi**2 * F0) == pytest.approx(exact.impact_speed(2 * np.pi * f / w1, R), rel=0.005)
        assert row["orbit1.stable"] == 1   # shooting from the run's last state (its checkpoint)


def test_the_period_is_the_smallest_repeat_of_the_section():
    rng = np.random.default_rng(1)
    two = np.tile([[1.0, 2.0], [1.5, 1.0]], (6, 1))
    assert detect_period(two, 1e-6) == 2
    assert detect_period(np.ones((8, 2)), 1e-6) == 1
    assert detect_period(rng.normal(size=(12, 2)), 1e-6) == 0
    three = np.tile([[1.0], [2.0], [3.0]], (4, 1)) * (1 + 1e-9 * rng.normal(size=(12, 1)))
    assert detect_period(three, 1e-6) == 3
