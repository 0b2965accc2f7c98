"""Node-to-node pair contact between two free bars (cases/two_bars.yaml, meshes/two_bars.py).

Nondimensional, L = E = rho = A = 1 (c = 1, each bar's mass m = 1), 100 cells per bar,
dt = 0.005 (Courant 0.5).

- bar_a at +1 hits bar_b at rest: momentum conserved, the impulse S = m v = 1 moves to
  bar_b (bar_a stops, bar_b leaves at +1), interface force rho c A v/2 = 0.5 for 2L/c = 2;
- the energy balance closes, no energy is created, the loss at the node is O(1/n_el);
- bar_a at +1 and bar_b at -1: by symmetry the contact plane is a rigid wall, and each bar
  is the discrete B2 problem (cases/impacting_bar.yaml with gap 0.05) step by step.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from conftest import CASES, ROOT, run_case_file

TWO_BARS = CASES / "two_bars.yaml"
MASS = 1.0            # rho A L of each bar
V0 = 1.0              # initial speed of bar_a
T0 = 0.1              # the gap 0.1 closes at approach speed 1
DURATION = 2.0        # 2 L / c
DT = 0.005
SYMMETRIC = "initial.velocity.1.value=[-1.0]"
WALL_MATCH = ("contacts.0.gap=0.05", "mesh.cells=100", f"solver.dt={DT}", "solver.t_end=3")
LATE = 2.5            # both bars separated (t > T0 + DURATION) and ringing freely: average over [LATE, t_end]


def _mesh_script():
    spec = importlib.util.spec_from_file_location("two_bars_mesh", ROOT / "meshes" / "two_bars.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """bar_a at +1, bar_b at rest, the committed 100 + 100 cell mesh."""
    return run_case_file(TWO_BARS, tmp_path_factory.mktemp("pair") / "base")


@pytest.fixture(scope="module")
def coarse(tmp_path_factory):
    """The same problem on 50 + 50 cells at the same Courant number."""
    folder = tmp_path_factory.mktemp("pair_coarse")
    mesh = _mesh_script().build(cells=50, output=folder / "two_bars_50.msh")
    return run_case_file(TWO_BARS, folder / "run", f"mesh.file={mesh}", f"solver.dt={2 * DT}")


@pytest.fixture(scope="module")
def symmetric(tmp_path_factory):
    """bar_a at +1, bar_b at -1 (pair), and the single bar at -1 against a wall (B2)."""
    folder = tmp_path_factory.mktemp("pair_sym")
    pair = run_case_file(TWO_BARS, folder / "pair", SYMMETRIC)
    wall = run_case_file(CASES / "impacting_bar.yaml", folder / "wall", *WALL_MATCH)
    return pair, wall


def bar_velocity(h, bar: str, t_from: float = LATE) -> float:
    """Rigid-body velocity of a bar after separation: its three probes, averaged in time."""
    late = h["t"] >= t_from
    side = {"a": ("a_left", "a_mid", "a_right"), "b": ("b_left", "b_mid", "b_right")}[bar]
    return float(np.mean([h[f"{p}_vx"][late].mean() for p in side]))


def contact_steps(h, name: str = "joint") -> np.ndarray:
    return np.flatnonzero(h[f"{name}_impulse"] > 0.0)


# --- mesh ---------------------------------------------------------------------------------


def test_mesh_file_has_the_documented_groups(tmp_path):
    import gmsh

    path = _mesh_script().build(length=2.0, gap=0.05, cells=7, output=tmp_path / "bars.msh")
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.merge(str(path))
        groups = {gmsh.model.getPhysicalName(d, t): (d, t) for d, t in gmsh.model.getPhysicalGroups()}
        assert sorted(groups) == ["a_left", "a_right", "b_left", "b_right", "bar_a", "bar_b"]
        points = {n: gmsh.model.mesh.getNodesForPhysicalGroup(*groups[n])[1][0] for n in
                  ("a_left", "a_right", "b_left", "b_right")}
        assert points == pytest.approx({"a_left": 0.0, "a_right": 2.0, "b_left": 2.05, "b_right": 4.05})
        for bar, (x0, x1) in (("bar_a", (0.0, 2.0)), ("bar_b", (2.05, 4.05))):
            x = np.sort(gmsh.model.mesh.getNodesForPhysicalGroup(*groups[bar])[1][0::3])
            assert x.size == 8
            assert np.diff(x) == pytest.approx(np.full(7, (x1 - x0) / 7))
    finally:
        gmsh.finalize()
    assert path.read_text().startswith("$MeshFormat\n4.1 ")


# --- bar_a at +1 against bar_b at rest -------------------------------------------------------


def test_momentum_is_conserved_and_transferred(base):
    summary, h = base
    v_a, v_b = bar_velocity(h, "a"), bar_velocity(h, "b")
    S = h["joint_impulse"].sum()
    assert summary["total_impulse"]["joint"] == pytest.approx(S, rel=1e-9)
    # Total momentum m v_a + m v_b stays m V0.
    assert MASS * (v_a + v_b) == pytest.approx(MASS * V0, rel=0.01)
    # The contact impulse is the momentum bar_b gained and bar_a lost.
    assert MASS * v_b == pytest.approx(S, rel=0.01)
    assert MASS * (V0 - v_a) == pytest.approx(S, rel=0.01)
    # Equal bars: the whole momentum moves (bar_a stops, bar_b leaves at V0).
    assert S == pytest.approx(MASS * V0, rel=0.01)
    assert abs(v_a) < 0.01 * V0
    assert v_b == pytest.approx(V0, rel=0.01)


def test_body_momenta_balance_the_impulses_exactly(base):
    """History columns BAR.px = 1_b^T M V: the total momentum stays m V0 and bar_b's is the sum of the
    impulses (``normal`` +1, from bar_a to bar_b) at every step, to round-off (history.csv holds 12
    significant digits) - the discrete scheme transfers exactly the impulses S_N it reports.
    summary.json has each body's mass (rho A L = 1)."""
    summary, h = base
    assert summary["body_mass"] == pytest.approx({"bar_a": MASS, "bar_b": MASS}, rel=1e-12)
    assert h["bar_a_px"] + h["bar_b_px"] == pytest.approx(np.full(len(h), MASS * V0), abs=1e-11)
    assert h["bar_b_px"] == pytest.approx(np.cumsum(h["joint_impulse"]), abs=1e-11)
    assert h["bar_b_px"][-1] == pytest.approx(MASS * V0, rel=0.01)


def test_interface_force_and_duration(base):
    _, h = base
    t, f = h["t"], h["joint_force"]
    on = contact_steps(h)
    # The gap closes exactly at T0: that step carries the impact impulse (Carnot), then forces.
    assert t[on[0]] == pytest.approx(T0, abs=1e-9)
    assert t[on[-1]] - t[on[0]] + DT == pytest.approx(DURATION, abs=2 * DT)
    assert np.all(np.diff(on) == 1)  # one contact phase, no chatter
    # Constant force rho c A v / 2 away from the wave fronts at the start and end.
    plateau = (t > T0 + 0.3) & (t < T0 + DURATION - 0.3)
    assert f[plateau] == pytest.approx(np.full(plateau.sum(), 0.5 * V0), rel=0.01)
    assert h["joint_gap"].min() >= -1e-12
    # The bars separate: the gap opens at bar_b's speed minus bar_a's.
    assert h["joint_gap"][-1] == pytest.approx(V0 * (3.0 - T0 - DURATION), rel=0.02)


def test_energy_balance(base, coarse):
    summary, h = base
    assert summary["max_energy_error_relative"] < 1e-6
    E = h["kinetic"] + h["strain"]
    E0 = 0.5 * MASS * V0**2
    assert E[0] == pytest.approx(E0, rel=1e-12)
    assert E.max() <= E0 * (1.0 + 1e-9)          # no energy is created
    loss = (h["impact_loss"][-1] + h["contact_loss"][-1]) / E0
    assert 0.0 < loss < 1.0 / 100                 # O(1/n_el), n_el = 100 per bar
    assert E[-1] == pytest.approx(E0 * (1.0 - loss), rel=1e-9)
    # ... and it halves with h (at a fixed Courant number).
    summary_c, h_c = coarse
    assert summary_c["max_energy_error_relative"] < 1e-6
    loss_c = (h_c["impact_loss"][-1] + h_c["contact_loss"][-1]) / E0
    assert loss_c / loss == pytest.approx(2.0, rel=0.2)


# --- bar_a at +1, bar_b at -1: each bar is B2 -----------------------------------------------


def test_symmetric_pair_is_the_wall_problem(symmetric):
    (s_pair, p), (s_wall, w) = symmetric
    assert np.array_equal(p["t"], w["t"])
    # Same discrete problem up to round-off: forces and impulses step by step.
    scale = 1.0  # rho c A v0
    diff = np.abs(p["joint_force"] - w["wall_force"])
    assert diff.max() <= 1e-6 * scale
    loaded = np.abs(w["wall_force"]) > 1e-6 * scale  # relative, where the force is not round-off
    assert np.all(diff[loaded] <= 1e-6 * np.abs(w["wall_force"][loaded]))
    assert np.abs(p["joint_impulse"] - w["wall_impulse"]).max() <= 1e-6 * scale * DT
    on_p, on_w = contact_steps(p), contact_steps(w, "wall")
    assert np.array_equal(on_p, on_w)
    assert p["t"][on_p[-1]] - p["t"][on_p[0]] + DT == pytest.approx(DURATION, abs=2 * DT)
    # bar_b is the wall's bar (contact end on the left); bar_a its mirror image.
    for pair_probe, wall_probe in (("b_left", "left"), ("b_right", "right")):
        assert np.abs(p[f"{pair_probe}_vx"] - w[f"{wall_probe}_vx"]).max() <= 1e-6
    assert np.abs(p["a_left_vx"] + w["right_vx"]).max() <= 1e-6
    assert np.abs(p["a_right_vx"] + w["left_vx"]).max() <= 1e-6
    # Two bars: twice the single bar's energies and losses.
    for column in ("kinetic", "strain", "impact_loss", "contact_loss"):
        assert p[column] == pytest.approx(2.0 * w[column], rel=1e-6, abs=1e-12)
    assert s_pair["max_energy_error_relative"] < 1e-6
    assert s_wall["max_energy_error_relative"] < 1e-6


def test_symmetric_pair_matches_b2(symmetric):
    (_, p), _ = symmetric
    t, f = p["t"], p["joint_force"]
    t0 = 0.05  # the gap 0.1 closes at approach speed 2
    on = contact_steps(p)
    assert t[on[0]] == pytest.approx(t0, abs=1e-9)
    plateau = (t > t0 + 0.3) & (t < t0 + DURATION - 0.3)
    assert f[plateau] == pytest.approx(np.ones(plateau.sum()), rel=0.01)  # rho c A v0
    # Each bar rebounds with its velocity reversed (e = 0 at the node costs O(1/n_el)).
    assert bar_velocity(p, "a") == pytest.approx(-V0, rel=0.02)
    assert bar_velocity(p, "b") == pytest.approx(V0, rel=0.02)
    # Zero total momentum throughout the run: the two bars mirror each other.
    assert np.abs(p["a_mid_vx"] + p["b_mid_vx"]).max() <= 1e-9
    assert p["joint_impulse"].sum() == pytest.approx(2.0 * MASS * V0, rel=0.01)
