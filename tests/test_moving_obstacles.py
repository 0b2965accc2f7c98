"""Obstacles that move as the case file says (``motion:``, docs/theory.md s. 2.6), against exact answers.

- A ball (a point mass) on a table shaken as A sin(w t + phi), e = 0.5, Gamma = A w^2 / g = 1.3,
  started near its period-1 orbit: it settles on the orbit whose impacts fall at the phase
  acos(pi (1 - e) / ((1 + e) Gamma)) (the stable one, sin(phase) > 0), one impact per period.
- A free bar at rest struck by a wall given ``motion: [t]`` (each method): the contact opens at
  gap / v_o, lasts 2 L / c, and gives the impulse 2 m v_o; the wall's work is v_o times the impulse.
- A block at rest on a belt (the floor moving along itself at v_b, friction mu): friction carries it
  at mu g until it moves with the belt, at t = v_b / (mu g); in the belt's frame it is the block
  launched at -v_b on a fixed floor, which a second run checks to round-off (Galilean invariance).

Every run: the balance closes to 1e-10 of the energy scale, the losses are >= 0 and E <= E0 + W_ext,
the obstacle's work in W_ext.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from petsc4py import PETSc

import fem_impact as fi
from conftest import CASES, ConstantLoad, run_cli
from fem_impact.build import build_system, make_integrator
from fem_impact.config.case import load_case
from fem_impact.expressions import parse_expression
from fem_impact.integrators import MoreauJean, Operators, integrate
from fem_impact.nonsmooth import laws
from fem_impact.nonsmooth.relations import FixedPlane, MovingPlane, Relations
from test_relations import check_budget


def one_by_one(value):
    A = PETSc.Mat().createAIJ([1, 1], nnz=1, comm=PETSc.COMM_SELF)
    A.setValue(0, 0, value)
    A.assemble()
    return A


def shaken_ball(e: float, gamma: float, f: float, per_period: int, periods: int, start: float):
    """A unit mass above a table at A sin(w t + phi) (phi the period-1 orbit's impact phase), leaving it
    at t = 0 at ``start`` times the orbit's take-off speed g T / 2. Returns rows (t, impulse), the
    energy budgets, phi."""
    g, w, T = 9.81, 2.0 * np.pi * f, 1.0 / f
    A = gamma * g / w ** 2
    phi = np.arccos(np.pi * (1.0 - e) / ((1.0 + e) * gamma))
    # The ball's height u above where it starts, the table's normal -1 (the ball falls onto it): -u <= d(t).
    table = MovingPlane(FixedPlane(None, np.array([-1.0]), [], 0.0),
                        [parse_expression("A*sin(w*t + phi)", ("t",), {"A": A, "w": w, "phi": phi})])
    table.d0, table._start = np.array([0.0]), table._vector(0.0, 0)   # (a one-dof system: no mesh to place it)
    newton = laws.RowLaws([(laws.law_of("newton", {"restitution": e}), [0])], 1)
    ops = Operators(one_by_one(1.0), one_by_one(0.0), None, ConstantLoad(-g), np.array([[-1.0]]), np.array([0.0]),
                    newton.restitution, laws=newton, relations=Relations.of([table]))
    U0, V0 = PETSc.Vec().createSeq(1), PETSc.Vec().createSeq(1)
    U0.set(0.0)
    V0.set(start * g * T / 2.0)
    rows, budgets = [], []

    class Recorder:
        def write(self, s):
            rows.append((s.t, s.impulse[0]))
            budgets.append(s.energy.copy())

    integrate(MoreauJean(ops, T / per_period), U0, V0, periods * T, [Recorder()])
    return np.array(rows), budgets, phi


def test_a_ball_on_a_shaken_table_settles_on_the_period_one_orbits_impact_phase():
    """Started at 0.8 of the orbit's take-off speed, the ball settles on one impact per period at the
    orbit's phase, to within the step (0.36 deg at 1000 steps a period; the phase is that of the step
    the impact is found in)."""
    f, per_period = 50.0, 1000
    rows, budgets, phi = shaken_ball(e=0.5, gamma=1.3, f=f, per_period=per_period, periods=20, start=0.8)
    t, impulse = rows.T
    hits = t[impulse > 0.0]
    late = hits[hits > 10.0 / f]
    assert np.allclose(np.diff(late) * f, 1.0, atol=1.5 / per_period)   # one impact a period
    phase = np.degrees((2.0 * np.pi * f * late + phi) % (2.0 * np.pi))
    assert np.abs(phase - np.degrees(phi)).max() <= 0.5
    assert np.degrees(phi) == pytest.approx(36.338, abs=1e-3)
    scale = 0.5 * (9.81 / f / 2.0) ** 2   # the orbit's kinetic energy at take-off
    check_budget(budgets, scale)
    assert budgets[-1].external_work > 10 * scale   # (the table keeps putting in what the impacts lose)


def struck_bar(method: str, speed: float = 1.0, gap: float = 0.1):
    """cases/impacting_bar.yaml at rest, its wall moving at ``speed`` toward it (``motion: [t]``)."""
    overrides = ["mesh.cells=50", "initial.velocity=[0.0]", f"contacts.0.gap={gap}",
                 f"contacts.0.motion=['{speed}*t']", "solver.dt=0.005", f"solver.method={method}",
                 "solver.t_end=2.4", "output.vtk=false"]
    overrides += {"modal": ["solver.modes=8"], "central_difference": ["solver.mass=lumped", "solver.dt=0.01"]
                  }.get(method, [])
    case = load_case(CASES / "impacting_bar.yaml", overrides)
    system = build_system(case)
    rows, budgets = [], []

    class Recorder:
        def write(self, s):
            rows.append((s.t, s.gap[0], s.impulse[0]))
            budgets.append(s.energy.copy())

    integrate(make_integrator(case, system.operators), system.U0, system.V0, case.solver.t_end, [Recorder()])
    return np.array(rows), budgets, case.solver.dt


@pytest.mark.parametrize("method", ["moreau_jean", "newmark", "central_difference", "modal"])
def test_a_wall_given_a_motion_strikes_a_bar_at_rest(method):
    """The case file's ``motion`` in every method that takes obstacles, the reduced model included."""
    speed, gap = 1.0, 0.1
    rows, budgets, dt = struck_bar(method, speed, gap)
    t, g, impulse = rows.T
    push = np.flatnonzero(impulse > 0.0)
    assert abs(t[push[0]] - gap / speed) <= dt * (1.0 + 1e-9)
    assert g.min() >= -1e-12 * gap
    assert impulse.sum() == pytest.approx(2.0 * speed, rel=0.03)             # 2 m v_o, m = 1
    assert t[push[-1]] - t[push[0]] == pytest.approx(2.0, abs=0.15)          # 2 L / c
    check_budget(budgets, 2.0 * speed ** 2)
    # The wall moves at a constant speed: its work is v_o times the impulse it gave, exactly.
    assert budgets[-1].external_work == pytest.approx(speed * impulse.sum(), rel=1e-9)


BELT = ["output.vtk=false", "output.every=1", "solver.t_end=0.8", "parameters.v0=0.0"]


@pytest.fixture(scope="module")
def belt_runs(tmp_path_factory):
    """cases/sliding_block.yaml at rest on a floor moving along itself at vb; and, for the belt's frame,
    the block launched at -vb on the fixed floor."""
    folder = tmp_path_factory.mktemp("belt")
    belt = fi.run(fi.load_case(CASES / "sliding_block.yaml", BELT + ["parameters.vb=2.0",
                                                                     "contacts.0.motion=['vb*t', 0.0]"]),
                  folder / "belt")
    fixed = fi.run(fi.load_case(CASES / "sliding_block.yaml", BELT[:-1] + ["parameters.v0=-2.0"]), folder / "fixed")
    return belt, fixed


def test_a_block_on_a_belt_is_carried_at_mu_g_until_it_moves_with_the_belt(belt_runs):
    belt, _ = belt_runs
    h = belt.history
    mass, mu, g, vb = 0.2 * 0.05 * 1000.0, 0.3, 9.81, 2.0
    t, v = h["t"], h["bar.px"] / mass
    sliding = (t > 0.05) & (t < 0.6)
    assert np.allclose(v[sliding], mu * g * t[sliding], rtol=0.01)
    assert np.allclose(v[t > 0.75], vb, rtol=0.01)
    assert h["friction_loss"][-1] == pytest.approx(0.5 * mass * vb ** 2, rel=0.02)   # the belt's frame: it stops
    assert h["external_work"][-1] == pytest.approx(mass * vb ** 2, rel=0.02)        # the belt's work: twice that
    # The balance to the round-off of U^T K U of a block carried 1 m (the run reports it; the fixed floor's
    # block has the same), as in tests/test_friction.py.
    scale, roundoff = mass * vb ** 2, belt.summary["energy_roundoff"]
    assert np.abs(h["energy_error"]).max() <= roundoff + 1e-10 * scale
    assert h["friction_loss"].min() >= -1e-12 * scale and np.all(np.diff(h["friction_loss"]) >= -1e-9 * scale)
    assert np.all(h["kinetic"] + h["strain"] <= h["kinetic"][0] + h["strain"][0] + h["external_work"]
                  + roundoff + 1e-10 * scale)


def test_a_block_on_a_belt_is_the_block_launched_backward_in_the_belts_frame(belt_runs):
    """Coulomb's law acts on the motion relative to the obstacle: the two runs differ by the frame
    (momentum by m vb, the probe's displacement by vb t), up to the block's vibration, which the frictional
    problem leaves free to part the two: a stiff block on 9 rows at Courant number 8 makes W nearly
    singular, so its impulses are not unique beyond the solver's tolerance (measured: the momenta 1.3e-3
    of m vb apart at a step while it slides, their means 3e-4 apart once it moves with the belt, the probe
    1e-4 m, the friction loss 5e-5)."""
    belt, fixed = belt_runs
    a, b = belt.history, fixed.history
    mass, vb = 0.2 * 0.05 * 1000.0, 2.0
    sliding, carried = a["t"] < 0.6, a["t"] > 0.7
    assert np.abs(a["bar.px"] - (b["bar.px"] + mass * vb))[sliding].max() <= 1e-2 * mass * vb
    assert a["bar.px"][carried].mean() == pytest.approx(b["bar.px"][carried].mean() + mass * vb, rel=1e-3)
    assert np.abs(a["front.ux"] - (b["front.ux"] + vb * a["t"])).max() <= 1e-3 * vb * a["t"][-1]
    assert a["friction_loss"][-1] == pytest.approx(b["friction_loss"][-1], rel=1e-3)


@pytest.mark.parametrize("change, key, message", [
    ("contacts=[{name: c, type: pair, nodes: [left, right], normal: [1.0], motion: [t]}]", "contacts[0].motion",
     "for an obstacle"),
    ("contacts.0.motion=[t, t]", "contacts[0].motion", "2 expression"),
    ("contacts.0.motion=['x*t']", "contacts[0].motion[0]", "not an allowed name"),
])
def test_a_motion_that_cannot_be_is_refused_naming_the_key(tmp_path, change, key, message):
    out = run_cli("run", str(CASES / "impacting_bar.yaml"), "-q", "-o", str(tmp_path / "out"), "--set", change)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert key in out.stderr and message in out.stderr, out.stderr


def test_a_motion_that_stops_being_finite_stops_the_run_naming_the_contact(tmp_path):
    out = run_cli("run", str(CASES / "impacting_bar.yaml"), "-q", "-o", str(tmp_path / "out"),
                  "--set", "contacts.0.motion=['1/(0.05 - t)']", "--set", "mesh.cells=20",
                  "--set", "solver.dt=0.01", "--set", "output.vtk=false")
    assert out.returncode == 3 and "Traceback" not in out.stderr, out.stderr
    assert "contact wall" in out.stderr and "not finite" in out.stderr, out.stderr


def test_event_driven_flights_meet_the_shaken_table_exactly():
    """The response study's event-driven flights (periodic/shooting.py) against the moving table of
    cases/bouncing_ball.yaml: shooting finds the period-1 orbit with its impact at T/2 (where the table's
    shifted motion puts the orbit's phase) and its approach speed g T / 2 + A w cos(phi), exactly; its
    multipliers cross -1 at the period doubling's Gamma = sqrt((pi (1 - e) / (1 + e))^2 + (2 (1 + e^2) /
    (1 + e)^2)^2) (bisection: within 0.1 %)."""
    from fem_impact.periodic.shooting import poincare_map, reduced_scene, shoot

    f, g, e = 50.0, 9.81, 0.5
    T = 1.0 / f

    def orbit(gamma):
        scene = reduced_scene(fi.load_case(CASES / "bouncing_ball.yaml", [f"parameters.Gamma={gamma}"]))
        x = scene.start.copy()
        for _ in range(5):   # (near the orbit first: Newton from the settling ball)
            x = poincare_map(scene.system, x, T)
        return shoot(scene.system, x, T, 1)

    settled = orbit(1.3)
    (t, row, speed), = settled.impacts
    phi = np.arccos(np.pi * (1 - e) / ((1 + e) * 1.3))
    assert t == pytest.approx(T / 2, rel=1e-9) and settled.stable
    assert speed == pytest.approx(g * T / 2 + 1.3 * g / (2 * np.pi * f) * np.cos(phi), rel=1e-9)
    low, high = 1.45, 1.6
    assert orbit(low).multipliers.real.min() > -1.0 > orbit(high).multipliers.real.min()
    for _ in range(12):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if orbit(mid).multipliers.real.min() > -1.0 else (low, mid)
    doubling = np.sqrt((np.pi * (1 - e) / (1 + e)) ** 2 + (2 * (1 + e * e) / (1 + e) ** 2) ** 2)
    assert 0.5 * (low + high) == pytest.approx(doubling, rel=1e-3)


@pytest.mark.parametrize("name", ["bouncing_ball.yaml", "bouncing_disk.yaml"])
def test_the_response_study_sweeps_the_shaken_tables_amplitude_with_event_driven_flights(tmp_path, name):
    """``study response --flight events`` over Gamma at the fixed drive frequency: period 1 below the
    period doubling, period 2 above it, and the doubling located (from the shooting's multipliers) within
    0.1 % of sqrt((pi (1 - e) / (1 + e))^2 + (2 (1 + e^2) / (1 + e)^2)^2) = 1.5268: the ball as
    the reduced model's rigid mode, and as a rigid disk (bodies: model: rigid, struck under its centre: flown
    in translation, periodic/rigid.py)."""
    from fem_impact.app.studies.response import response_study

    case = fi.load_case(CASES / name)
    result = response_study(case, "parameters.Gamma=1.3,1.5,1.55", tmp_path, settle=100, periods=4, flight="events",
                            frequency="f", quiet=True)
    periods = {row["parameters.Gamma"]: row["period"] for row in result["rows"]}
    assert periods == {1.3: 1, 1.5: 1, 1.55: 2}
    (mark,) = json.loads((tmp_path / "response-up.json").read_text())["bifurcations"]
    e = 0.5
    doubling = np.sqrt((np.pi * (1 - e) / (1 + e)) ** 2 + (2 * (1 + e * e) / (1 + e) ** 2) ** 2)
    assert mark["kind"] == "period_doubling" and mark["parameters.Gamma"] == pytest.approx(doubling, rel=1e-3)


@pytest.mark.parametrize("change, says", [
    # a table tilted so that no rim node lies on the normal through the centre: the first impact would turn it
    (["contacts.0.normal=[0.05, -0.99875]"], "off the line through the rigid body's centre"),
    (["contacts.0.friction=0.3"], "frictionless contacts only"),
])
def test_event_driven_flights_refuse_what_would_turn_a_rigid_body_in_one_line(tmp_path, change, says):
    args = ["study", "response", str(CASES / "bouncing_disk.yaml"), "--vary", "parameters.Gamma=1.3", "--frequency",
            "f", "--flight", "events", "--settle", "5", "--periods", "2", "-o", str(tmp_path / "out"), "-q"]
    for c in change:
        args += ["--set", c]
    out = run_cli(*args)
    assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
    assert says in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr


@pytest.mark.parametrize("restitution, dt, says", [(0.5, 0.05, True), (0.0, 0.05, False), (0.5, 0.002, False)])
def test_a_restitution_on_an_elastic_body_at_a_long_step_is_explained_once(tmp_path, restitution, dt, says):
    """Nodal e on the full model at a step above 2 / omega_max: the run says once what e does there."""
    out = run_cli("run", str(CASES / "impacting_bar.yaml"), "-q", "-o", str(tmp_path / "out"), "--set",
                  f"contacts.0.restitution={restitution}", "--set", "solver.method=moreau_jean", "--set",
                  "mesh.cells=50", "--set", f"solver.dt={dt}", "--set", "solver.t_end=0.2", "--set", "output.vtk=false")
    assert out.returncode == 0, out.stderr
    assert out.stderr.count("the restitution acts on the contact's nodes alone") == (1 if says else 0), out.stderr
    if says:
        assert "contacts[0] (wall, e = 0.5)" in out.stderr and "cases/bouncing_ball.yaml" in out.stderr


@pytest.mark.parametrize("change", ["contacts.0.motion=['0.5*t']", "bodies={bar: {model: rigid}}"])
def test_an_exact_reference_refuses_a_scene_it_does_not_describe(change):
    """B2's fixed wall and elastic bar: a study would otherwise measure a moving wall or a rigid bar against it."""
    with pytest.raises(fi.CaseError, match="reference"):
        from fem_impact.references import from_case

        from_case(load_case(CASES / "impacting_bar.yaml", [change]))
