"""Outputs for devices driven at a period (``output.period``): impacts.csv's ``phase`` and periods.csv,
against exact answers.

- cases/bouncing_ball.yaml: a ball on a table shaken at f, settled on the period-1 orbit whose impacts
  fall at t = T/2, 3T/2, ... (the table's motion is shifted by the orbit's phase): phase 1/2 (within
  0.5 deg), one impact a period, the ball's mean velocity 0 over a period (it comes back to where it
  was), and what the table puts in a period is what the impact loses.
- a block at rest on a belt (cases/sliding_block.yaml with a moving floor): its mean velocity over a
  period is mu g at the period's middle while it slides (its velocity is linear in t), then the belt's.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

import fem_impact as fi
from conftest import CASES, run_cli

F, G, R, GAMMA = 50.0, 9.81, 0.5, 1.3


def table(path) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {name: np.array([float(row[name]) if name != "contact" else 0.0 for row in rows]) for name in rows[0]}


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ball")
    return fi.run(fi.load_case(CASES / "bouncing_ball.yaml"), folder / "ball")


def test_the_bouncing_ball_settles_on_its_orbits_phase(ball):
    impacts = table(ball.outdir / "impacts.csv")
    late = impacts["t"] > 0.2   # (settled: the last ten periods, impacts at T/2 of each)
    phase = impacts["phase"][late]
    off = np.abs(phase - 0.5) * 360.0   # degrees from the orbit's impact at phase 1/2
    assert late.sum() == 10 and off.max() <= 0.5
    # the contact time lies within the step that found the impact
    dt = ball.summary["dt"]
    assert np.all((impacts["t_contact"] <= impacts["t"]) & (impacts["t_contact"] >= impacts["t"] - dt * (1 + 1e-9)))
    # the impact's approach speed is the orbit's, relative to the table: g T / 2 + the table's speed at phi
    phi = np.arccos(np.pi * (1 - R) / ((1 + R) * GAMMA))
    table_speed = GAMMA * G / (2 * np.pi * F) * np.cos(phi)
    assert impacts["speed"][late] == pytest.approx(G / (2 * F) + table_speed, rel=0.01)


def test_the_bouncing_balls_periods_balance(ball):
    periods = table(ball.outdir / "periods.csv")
    assert periods["period"].tolist() == list(range(1, 21))
    assert periods["t"] == pytest.approx(np.arange(1, 21) / F, rel=1e-12)
    late = periods["period"] > 10
    assert np.all(periods["table.impacts"][late] == 1)
    take_off = G / (2 * F)
    assert np.abs(periods["bar.vx_mean"][late]).max() <= 1e-3 * take_off
    # a period of the orbit: the table puts in what the impact loses
    assert periods["external_work"][late] == pytest.approx(periods["losses"][late], rel=1e-4)
    # the periods' sums are the run's totals (history.csv at the last period's end)
    h = ball.history
    assert periods["external_work"].sum() == pytest.approx(h["external_work"][-1], rel=1e-9)
    assert periods["table.impulse"].sum() == pytest.approx(ball.summary["total_impulse"]["table"], rel=1e-9)


def test_a_block_on_a_belt_has_the_mean_velocity_of_each_period(tmp_path):
    mu, vb, period = 0.3, 2.0, 0.1
    case = fi.load_case(CASES / "sliding_block.yaml", ["output.vtk=false", "solver.t_end=1.0", "parameters.v0=0.0",
                                                       f"parameters.vb={vb}", "contacts.0.motion=['vb*t', 0.0]",
                                                       f"output.period={period}"])
    periods = table(fi.run(case, tmp_path / "belt").outdir / "periods.csv")
    middle = periods["t"] - period / 2
    sliding = periods["t"] <= 0.6
    assert periods["bar.vx_mean"][sliding] == pytest.approx(mu * G * middle[sliding], rel=0.01)
    assert periods["bar.vx_mean"][periods["t"] > 0.75] == pytest.approx(vb, rel=0.01)


def test_a_restart_continues_the_periods(tmp_path):
    """From a checkpoint in the middle of a period, the periods are those of the uninterrupted run; a restart
    that adds output.period writes the periods it sees whole."""
    case = fi.load_case(CASES / "bouncing_ball.yaml", ["solver.t_end=0.13"])
    first = fi.run(case, tmp_path / "first")
    longer = case.with_changes({"solver.t_end": 0.2})
    whole = table(fi.run(longer, tmp_path / "whole").outdir / "periods.csv")
    continued = table(fi.run(longer, tmp_path / "continued", restart=first.outdir).outdir / "periods.csv")
    for name in whole:
        assert continued[name] == pytest.approx(whole[name], rel=1e-10, abs=1e-14), name
    plain = case.with_changes({"output.period": None})
    fi.run(plain, tmp_path / "plain")
    added = table(fi.run(longer, tmp_path / "added", restart=tmp_path / "plain").outdir / "periods.csv")
    assert added["period"].tolist() == list(range(8, 11))   # (0.14 to 0.20: the 7th period was seen in part)
    for name in whole:
        assert added[name] == pytest.approx(whole[name][7:], rel=1e-10, abs=1e-14), name
    # another period on restart: the saved periods are not continued with it; they start again from the restart
    other = table(fi.run(longer.with_changes({"output.period": 0.04}), tmp_path / "other",
                         restart=first.outdir).outdir / "periods.csv")
    assert other["period"].tolist() == [5] and other["t"].tolist() == pytest.approx([0.2])


@pytest.mark.parametrize("value, message", [("0", "positive"), ("-1/f", "positive"), ("'1/q'", "q"),
                                            ("'t'", "not an allowed name"), ("[1]", "expected a number")])
def test_a_period_that_cannot_be_is_refused_naming_the_key(tmp_path, value, message):
    out = run_cli("run", str(CASES / "bouncing_ball.yaml"), "-q", "-o", str(tmp_path / "out"), "--set",
                  f"output.period={value}")
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert "output.period" in out.stderr and message in out.stderr, out.stderr
