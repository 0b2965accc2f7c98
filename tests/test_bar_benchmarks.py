"""Verification of the full model on bars with exact solutions: B2 (free bar on a wall) and B1
(clamped bar against an obstacle), docs/benchmarks.md; and the same bar in 2D and 3D. (Their orders of
convergence, and the impact loss with e = 0 vanishing like h: tests/test_convergence.py.)"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import CASES, b1_exact_u0, b2_checks, contact_window, run_case_file

TOLERANCES = {"start": 0.02, "duration": 0.02, "mean_force": 0.02, "impulse": 0.01, "rebound": 0.02,
              "contact_end_u": 0.03}


B2A = dict(L=1.0, E=1.0, rho=1.0, A=1.0, v0=1.0, g0=0.1)   # cases/impacting_bar.yaml


def assert_b2(h, **bar):
    """Every B2 figure within issue 2's tolerances (``bar``: b2_checks's L, E, rho, A, v0, g0)."""
    errors = b2_checks(h, **{**B2A, **bar})
    for key, tol in TOLERANCES.items():
        assert errors[key] < tol, f"{key}: {errors[key]:.3g} >= {tol}"


def assert_energy(summary, h, rtol=1e-6):
    e0 = h["kinetic"][0] + h["strain"][0]
    assert summary["max_energy_error"] < rtol * e0
    total = h["kinetic"] + h["strain"]
    assert total.max() <= e0 * (1 + rtol), "energy grew"


# The paper's scheme (the case files' method) and the default, Moreau-Jean at the position level:
# the same smooth integrator, and at Courant 0.5 the same answers within the tolerances.
METHODS = ["newmark", "moreau_jean"]


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("cells", [250, 400])
def test_b2a_free_bar_on_a_wall(tmp_path, cells, method):
    """B2a at Courant number 0.5 with 250 and 400 cells."""
    summary, h = run_case_file(CASES / "impacting_bar.yaml", tmp_path, f"mesh.cells={cells}",
                               f"solver.dt={0.5 / cells}", "output.vtk=false", f"solver.method={method}")
    assert_b2(h)
    assert_energy(summary, h)
    assert summary["max_penetration"] < 1e-12


def test_b2b_steel_bar(tmp_path):
    """B2b in SI units: contact on [5.000e-4, 8.854e-4] s, 1270.8 N, 0.48984 N s."""
    summary, h = run_case_file(CASES / "impacting_bar_steel.yaml", tmp_path, "output.vtk=false")
    assert_b2(h, E=210e9, rho=7800.0, A=3.14e-4, v0=0.1, g0=5e-5)
    # The published figures themselves (docs/benchmarks.md B2), to their quoted digits.
    assert h["wall_impulse"].sum() == pytest.approx(0.48984, rel=0.01)
    start, end = contact_window(h, "wall")
    assert start == pytest.approx(5.000e-4, rel=0.01) and end == pytest.approx(8.854e-4, rel=0.01)
    assert_energy(summary, h)


@pytest.mark.parametrize("method", METHODS)
def test_b1_clamped_bar_against_an_obstacle(tmp_path, method):
    """B1 over four periods at 200 cells: u(0, t), the contact stress, the energy."""
    summary, h = run_case_file(CASES / "signorini_bar.yaml", tmp_path, "output.vtk=false", f"solver.method={method}")
    t = h["t"]
    rms = np.sqrt(np.mean((h["left_ux"] - b1_exact_u0(t)) ** 2))
    assert rms < 0.03 * 0.5
    tau = np.mod(t, 3.0)
    contact = (tau > 1.0) & (tau < 2.0)
    assert h["obstacle_force"][contact].mean() == pytest.approx(0.5, rel=0.05)
    energy = h["kinetic"] + h["strain"]
    assert energy[0] == pytest.approx(1 / 8, rel=1e-12)
    assert energy.max() <= 1 / 8 + 1e-6 / 8
    assert energy[-1] > 0.98 / 8
    assert summary["max_energy_error"] < 1e-6 / 8


@pytest.mark.parametrize("dim, cells", [(2, 100), (3, 40)])
def test_bar_in_2d_and_3d_reproduces_1d(tmp_path, dim, cells):
    """Plane stress strip and solid box with nu = 0 behave as the rod: same case file, --set mesh.dim."""
    common = [f"mesh.cells={cells}", f"solver.dt={0.5 / cells}", "solver.t_end=2.5", "output.vtk=false"]
    _, h1 = run_case_file(CASES / "impacting_bar.yaml", tmp_path / "1d", *common)
    summary, hd = run_case_file(CASES / "impacting_bar.yaml", tmp_path / f"{dim}d", f"mesh.dim={dim}", *common)
    height = 1.0 / 20  # built-in default: length / 20; area is the thickness in 2D
    section = height * 1.0 if dim == 2 else height * height
    s1, e1 = contact_window(h1, "wall")
    sd, ed = contact_window(hd, "wall")
    assert (ed - sd) == pytest.approx(e1 - s1, rel=0.05)
    assert hd["wall_impulse"].sum() / section == pytest.approx(h1["wall_impulse"].sum(), rel=0.05)
    busy = (h1["t"] > s1) & (h1["t"] < e1)
    assert hd["wall_force"][busy].mean() / section == pytest.approx(h1["wall_force"][busy].mean(), rel=0.05)
    late = h1["t"] > 2.2
    assert hd["right_vx"][late].mean() == pytest.approx(h1["right_vx"][late].mean(), rel=0.05)
    assert_energy(summary, hd)
