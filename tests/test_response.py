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
from fem_impact.app.studies.common import StudyInputError
from fem_impact.app.studies.response import response_study
from fem_impact.app.studies.response_period import detect_period
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


@pytest.mark.slow   # (16 s: the shaken table's event-driven sweep finds a period doubling in the default tier)
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


# -- any key at a fixed forcing frequency, the values' forms, what is refused before anything runs -----------
def test_any_key_is_swept_at_the_case_forcing_frequency(tmp_path):
    """The amplitude F0 swept at f = 0.5 (w = 2): the oscillator is linear between impacts against a stop at
    zero gap, so the period-1 orbit scales with F0: impulse per period (1 + r) V(w) F0 / w1 (shooting on the
    exact flights), at the frequency of the case, never at the varied value. The time-stepped levels step
    T / K of that frequency."""
    case = fi.load_case(CASES / "impact_oscillator.yaml")
    result = response_study(case, "parameters.F0=0.6,1.2", tmp_path / "events", settle=0, periods=2,
                            flight="events", quiet=True)
    _, w1, _ = scene(0.5)
    V = exact.impact_speed(2 * np.pi * 0.5 / w1, R)   # (w = 4 f = 2 for the rod's exact w1 = pi / 2)
    for row in result["rows"]:
        assert row["frequency"] == 0.5 and row["orbit1.stable"] == 1
        assert row["orbit1.impulse"] == pytest.approx((1 + R) * V * row["parameters.F0"] / w1, rel=1e-7)
    stepped = response_study(case, "parameters.F0=0.6", tmp_path / "scheme", settle=1, periods=2, steps_per_period=8,
                             quiet=True, shooting=False)
    level = json.loads((tmp_path / "scheme" / "levels" / "up-000-parameters.F0=0.6" / "level.json").read_text())
    assert level["changes"]["solver.dt"] == pytest.approx(1 / (0.5 * 8), rel=1e-12)
    assert level["changes"]["solver.t_end"] == pytest.approx(3 / 0.5, rel=1e-12)
    assert {r["frequency"] for r in stepped["rows"]} == {0.5}


def test_the_values_and_the_keys_a_sweep_takes():
    """START,NEXT,...,END (docs/studies.md's form) gives the evenly spaced values, END included; whole numbers
    stay whole; every other form is one plain refusal naming the option."""
    from fem_impact.app.studies.response import parse_vary

    key, values = parse_vary("parameters.f=23000,23500,...,29000")
    assert key == "parameters.f" and values == list(range(23000, 29001, 500))
    assert parse_vary("parameters.f=0.45,0.5,...,0.65")[1] == [0.45, 0.5, 0.55, 0.6, 0.65]
    assert parse_vary("contacts.0.gap=0,1e-4")[1] == [0, 1e-4]
    for bad in ("parameters.f", "parameters.f=", "=1,2", "parameters.f=a,b", "parameters.f=0.4,0.4",
                "parameters.f=0.4,...,0.7", "parameters.f=0.4,0.5,...,0.73", "parameters.f=0.4,0.5,0.7,...,1",
                "parameters.f=0,1e-9,...,1000", "parameters.f=1,...,2,...,3"):
        with pytest.raises(StudyInputError, match="--vary"):
            parse_vary(bad)


def test_what_the_study_cannot_do_is_refused_before_anything_is_written(tmp_path):
    """Keys the study sets (the step, the length, the start), a frequency the case does not force at, levels
    beyond the size guard: StudyInputError naming the option, nothing written; wrong types: TypeError."""
    osc = fi.load_case(CASES / "impact_oscillator.yaml")
    out = tmp_path / "out"
    refusals = [
        (osc, "solver.dt=0.45,0.5", {}, "--vary solver.dt"),
        (osc, "initial.velocity=1", {}, "--vary initial"),
        (osc, "parameters.f=0.5", {"changes": ["solver.t_end=3"]}, "--set solver.t_end"),
        (osc, "parameters.f=-1,1", {}, "--frequency"),
        (osc, "parameters.f=0.5", {"frequency": "2*g"}, "--frequency"),
        (osc, "parameters.f=0.5", {"periods": 10**8}, "--periods"),
        (osc, "parameters.f=0.5", {"settle": 10**6}, "--settle"),
        (osc, "parameters.f=0.5", {"settle": 10**6, "flight": "events"}, "--settle"),
        (fi.load_case(CASES / "impacting_bar.yaml"), "material.E=1,2", {}, "--frequency: the case has no parameter f"),
        (fi.load_case(CASES / "block_corner.yaml"), "parameters.g=0.5,0.6", {"frequency": "w"},
         "no load or support motion"),
    ]
    for case, vary, options, needle in refusals:
        with pytest.raises(StudyInputError, match=needle.replace("(", r"\(")):
            response_study(case, vary, out, quiet=True, **options)
        assert not out.exists()
    with pytest.raises(TypeError, match="response_study.. takes case as a Case"):
        response_study(None, "parameters.f=0.45", out)
    with pytest.raises(TypeError, match="takes vary as a string"):
        response_study(osc, ["parameters.f=0.45"], out)
    with pytest.raises(TypeError, match="takes changes"):
        response_study(osc, "parameters.f=0.45", out, changes=5)
    assert not out.exists()


def test_sweeps_of_one_folder_share_their_settings(tmp_path):
    """A sweep down into a folder with a sweep up of another restitution, or another --settle, is refused
    (naming the setting); one with the same settings is merged, and study.json records both sweeps, with
    what shooting did in each."""
    case = fi.load_case(CASES / "impact_oscillator.yaml")
    options = dict(settle=20, periods=2, flight="events", quiet=True)
    response_study(case, "parameters.f=0.45,0.5", tmp_path, shooting=False, **options)
    before = (tmp_path / "response.csv").read_text()
    with pytest.raises(StudyInputError, match=r"contacts\.0\.restitution: 0\.8 there, 0\.5 here"):
        response_study(case, "parameters.f=0.45,0.5", tmp_path, down=True, changes=["contacts.0.restitution=0.5"],
                       shooting=False, **options)
    with pytest.raises(StudyInputError, match="settle: 20 there, 30 here"):
        response_study(case, "parameters.f=0.45,0.5", tmp_path, down=True, shooting=False,
                       **{**options, "settle": 30})
    assert (tmp_path / "response.csv").read_text() == before
    down = response_study(case, "parameters.f=0.47", tmp_path, down=True, **options)
    assert {(r["direction"], r["parameters.f"]) for r in down["rows"]} == {("up", 0.45), ("up", 0.5), ("down", 0.47)}
    study = json.loads((tmp_path / "study.json").read_text())
    assert study["sweeps"]["up"]["shooting"] == "not asked (--no-shooting)"
    assert study["sweeps"]["down"]["shooting"] == "done"
    assert study["sweeps"]["up"]["values"] == [0.45, 0.5] and study["sweeps"]["down"]["values"] == [0.47]


# -- the period of the section -----------------------------------------------------------------------------
def test_the_time_step_never_reports_a_period_it_cannot_tell():
    """Swept from w = 2.68 to 2.70 (past the period doubling at 2.6533) with 500 steps a period, the
    time-stepped section locks onto long cycles of the step's own (period 6 at 2.70 before), where the exact
    flights give period 2: a level reports period 2, or period 0 with a note that it is not resolved."""
    case = fi.load_case(CASES / "impact_oscillator.yaml")
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        result = response_study(case, "parameters.f=0.67,0.675", folder, steps_per_period=500, quiet=True,
                                shooting=False)
    for row in result["rows"]:
        assert row["period"] == 2 or (row["period"] == 0 and row["period_note"].startswith("not resolved")), row


def test_a_probe_component_at_round_off_does_not_hide_the_period(tmp_path):
    """A free block resting on a floor, shaken (body acceleration -g + A sin, A = 12 < the lift-off of the
    rigid block plus its elastic modes): its probes' x components are round-off (1e-17) and it is at rest
    every period: period 1, and the floor takes the weight, m g T per period (momentum balance)."""
    case = fi.Case.from_dict({
        "parameters": {"f": 56.0, "g": 9.81, "A": 12.0},
        "mesh": {"shape": "bar", "dim": 2, "length": 0.2, "height": 0.05, "cells": 4},
        "material": {"E": 1.0e7, "rho": 1000.0, "nu": 0.0, "area": 1.0},
        "loads": [{"body": "all", "acceleration": [0.0, "-g + A*sin(2*pi*f*t)"]}],
        "contacts": [{"name": "floor", "type": "obstacle", "nodes": "bottom", "normal": [0.0, -1.0], "gap": 0.0,
                      "restitution": 0.5}],
        "solver": {"method": "modal", "modes": 6, "static_correction": False, "dt": 1e-4, "t_end": 0.1},
        "output": {"probes": {"front": [0.2, 0.0]}, "vtk": False}})
    result = response_study(case, "parameters.A=12", tmp_path, settle=20, periods=4, steps_per_period=100,
                            quiet=True, shooting=False)
    (row,) = result["rows"]
    assert abs(row["front.ux"]) < 1e-12 and row["period"] == 1
    assert row["floor.impulse"] == pytest.approx(0.2 * 0.05 * 1000.0 * 9.81 / 56.0, rel=1e-9)


@pytest.mark.slow
def test_near_the_period_doubling_shooting_gives_the_exact_period_two(tmp_path):
    """The reported case (2000 steps a period, w = 2.68 then 2.70): the time-stepped section is not resolved
    (period 8 and 6 before), shooting from it finds the period-1 orbit unstable and the period-2 orbit stable
    with the impact speeds of the exact flights (0.4510 and 0.4598 at w = 2.70)."""
    case = fi.load_case(CASES / "impact_oscillator.yaml")
    result = response_study(case, "parameters.f=0.67,0.675", tmp_path, steps_per_period=2000, quiet=True)
    for row in result["rows"]:
        assert row["period"] == 2 or (row["period"] == 0 and row["period_note"].startswith("not resolved")), row
    (row, *_) = [r for r in result["rows"] if r["parameters.f"] == 0.675]
    assert row["orbit1.stable"] == 0 and row["orbit2.stable"] == 1 and row["orbit2.impacts"] == 2
    w = 2.70
    orb = exact.period1_orbit(w, R)
    _, _, speeds = exact.simulate(orb.state + [-1e-3, 1e-3], w, R, 600)
    assert sorted(speeds[-2:]) == pytest.approx([0.4510, 0.4598], abs=1e-4)
    _, w1, phi = scene(0.675)
    assert row["orbit2.min_speed"] * w1 / (phi**2 * F0) == pytest.approx(min(speeds[-2:]), rel=1e-6)


# -- shooting and the event-driven flight: free bodies, limits ---------------------------------------------
class _Harmonic:
    """A modal load ``amplitudes cos(w t)``."""

    def __init__(self, w, amplitudes):
        self.w, self.amplitudes = w, np.asarray(amplitudes, float)

    def evaluate(self, t, out):
        out[:] = self.amplitudes * np.cos(self.w * t)
        return out


def _oscillator_with_a_free_coordinate(w):
    """X'' + X = cos(w t) against a stop at X = 0 (r = 0.8), and a rigid coordinate no row sees, forced too."""
    from fem_impact.periodic.shooting import ReducedSystem

    return ReducedSystem(w2=np.array([1.0, 0.0]), damping=np.zeros(2), load=_Harmonic(w, [1.0, 0.3]),
                         P=np.array([[1.0, 0.0]]), d0=np.zeros(1), restitution=np.array([R]))


def test_shooting_leaves_out_the_coordinates_no_row_sees():
    """A rigid drift no contact row sees has the multipliers 1, 1 and makes J - I singular: shooting takes
    the coordinates the rows see, and gives the closed-form orbit and multipliers of the impact oscillator,
    stable."""
    w = 2.0
    system = _oscillator_with_a_free_coordinate(w)
    closed = exact.period1_orbit(w, R)
    start = np.array([closed.state[0] * 1.05, 0.2, closed.state[1] * 0.95, -0.1])   # [Z, Z']
    orbit = shoot(system, start, 2 * np.pi / w, 1)
    assert orbit.unseen == 1 and orbit.stable
    assert orbit.x[[0, 2]] == pytest.approx(closed.state, abs=1e-9)
    assert np.sort_complex(orbit.multipliers) == pytest.approx(
        np.sort_complex(exact.period1_multipliers(w, R).astype(complex)), abs=1e-6)
    assert orbit.x[[1, 3]].tolist() == [0.2, -0.1]   # (left as given)


def test_shooting_stops_at_its_time_limit_and_says_how_it_goes():
    from fem_impact.periodic.shooting import ShootingError

    w = 2.0
    system = _oscillator_with_a_free_coordinate(w)
    start = np.array([-0.5, 0.0, 0.3, 0.0])
    with pytest.raises(ShootingError, match="time limit"):
        shoot(system, start, 2 * np.pi / w, 2, seconds=1e-4)
    said = []
    orbit = shoot(system, start, 2 * np.pi / w, 1, progress=lambda *a: said.append(a))
    assert [a[0] for a in said] == list(range(1, orbit.iterations + 1)) and said[-1][1] <= 1e-10


def _free_block(A):
    """A 2D block (10 kg) free in the plane, against a wall at its left end (one row: the end's mean
    displacement, which no rigid rotation or vertical drift moves), shaken along x: -g + A sin(2 pi f t)."""
    return fi.Case.from_dict({
        "parameters": {"f": 56.0, "g": 9.81, "A": A},
        "mesh": {"shape": "bar", "dim": 2, "length": 0.2, "height": 0.05, "cells": 8},
        "material": {"E": 1.0e7, "rho": 1000.0, "nu": 0.0, "area": 1.0},
        "damping": {"alpha": 0.0, "beta": 1.0e-4},
        "loads": [{"body": "all", "acceleration": ["-g + A*sin(2*pi*f*t)", 0.0]}],
        "contacts": [{"name": "wall", "type": "obstacle", "nodes": "left", "normal": [-1.0, 0.0], "coupling": "mean",
                      "gap": 0.0, "restitution": 0.5}],
        "solver": {"method": "modal", "modes": 6, "static_correction": False, "dt": 1e-4, "t_end": 0.1},
        "output": {"probes": {"end": [0.2, 0.025]}, "vtk": False}})


def test_the_event_flight_of_a_free_block_keeps_its_wall_and_its_momentum():
    """The block rests on the wall part of each period, chatters and lifts off (A = 12 just above g): the
    flight ends (it used to loop on the stop for ever), never lets the block through the wall (it used to
    fly 15 m beyond it), and the wall's impulses, impacts and the holding force while it rests, balance the
    momentum exactly: sum = N m g T + the change of momentum."""
    import time

    from fem_impact.periodic.shooting import impulses, poincare_map

    s = reduced_scene(_free_block(12.0))
    system, n, T = s.system, s.system.n, 1 / 56.0
    assert system.seen.tolist() == [0, 3, 4, 5]   # (modes 1, 2: the vertical drift and the rotation)
    x = s.start.copy()
    deadline = time.monotonic() + 120
    for _ in range(10):
        x = poincare_map(system, x, T, deadline=deadline)
    impacts, held, start = [], np.zeros(1), x.copy()
    N = 10
    for _ in range(N):
        x = poincare_map(system, x, T, impacts=impacts, deadline=deadline, held=held)
        assert system.d0[0] - system.P[0] @ x[:n] > -1e-12
    momentum = lambda y: np.sqrt(10.0) * y[n]   # (the rigid x mode, mass-normalized: 1/sqrt(m) in x)   # noqa: E731
    assert impacts and held[0] > 0
    assert impulses(system, impacts, held)[0] == pytest.approx(N * 10.0 * 9.81 * T + momentum(x) - momentum(start),
                                                               rel=1e-7)


@pytest.mark.slow
def test_a_free_block_periodic_orbit_balances_its_momentum(tmp_path):
    """Shooting on the shaken free block (A = 14): its period-1 orbit takes exactly the weight's impulse per
    period from the wall (m g T: the load's harmonic part gives none over a period), and its multipliers are
    those of the coordinates the wall sees: the vertical drift and the rotation (2 modes) are left out, so no
    multiplier is the neutral 1 of a rigid drift."""
    result = response_study(_free_block(14.0), "parameters.A=14", tmp_path, settle=100, periods=8, flight="events",
                            quiet=True)
    row = result["rows"][0]
    assert row["orbit1.residual"] <= 1e-10 and row["orbit1.unseen_modes"] == 2
    assert row["orbit1.impulse"] == pytest.approx(10.0 * 9.81 / 56.0, rel=1e-9)
    mu = [complex(row[f"orbit1.multiplier{i}.re"], row[f"orbit1.multiplier{i}.im"]) for i in range(1, 5)]
    assert min(abs(m - 1) for m in mu) > 1e-3


def test_a_study_called_from_python_claims_its_folder_as_the_command_does(tmp_path):
    """From Python a study wrote into any folder, over a user's files of its names, and left no manifest: it is
    claimed as on the command line (refused over files fem-impact did not write, the user's file unchanged;
    a result with its manifest, which a rerun replaces)."""
    from fem_impact.app.outdir.manifest import MARKER
    from fem_impact.errors import OutputFolderError

    case = fi.load_case(CASES / "impact_oscillator.yaml")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "response.csv").write_text("my own table\n")
    with pytest.raises(OutputFolderError, match="response.csv"):
        response_study(case, "parameters.F0=0.6", mine, settle=0, periods=2, steps_per_period=8, quiet=True,
                       shooting=False)
    assert (mine / "response.csv").read_text() == "my own table\n" and sorted(p.name for p in mine.iterdir()) == \
        ["response.csv"]
    out = tmp_path / "out"
    for _ in range(2):   # (the second: a rerun over the first result)
        response_study(case, "parameters.F0=0.6", out, settle=0, periods=2, steps_per_period=8, quiet=True,
                       shooting=False)
        files = json.loads((out / MARKER).read_text())["files"]
        assert "response.csv" in files and "study.json" in files


def test_a_case_without_probes_is_studied_on_its_contacts_alone(tmp_path):
    """A case with no output.probes: the section has no columns but the contacts' (numpy compared an empty
    float array of column kinds with a string as one False, and the study stopped with a traceback)."""
    case = fi.load_case(CASES / "impact_oscillator.yaml", ["output.probes={}"])
    result = response_study(case, "parameters.f=0.5", tmp_path, settle=2, periods=2, quiet=True)
    assert result["rows"] and all(row["stop.impulse"] > 0.0 for row in result["rows"])
