"""Observed orders of convergence (issue 5, "Done when" 1), measured with `fem-impact study convergence`
(fem_impact.app.studies.convergence) against the exact solutions of fem_impact.references.

- Free vibration without contact (cases/free_vibration.yaml, a free-free bar in its first mode):
  time-step refinement on a fine mesh; second order for the trapezoidal rule, first order with
  numerical damping (gamma = 0.6).
- B2 (free bar on a wall) and B1 (clamped bar against an obstacle) with contact: mesh refinement at
  Courant number 0.5; the orders are those of non-smooth solutions (see the tests).
- The impact loss with e = 0 vanishes like h (order 1).
- Truncation without static correction stays wrong as dt shrinks; the corrected model does not.

Errors (fem_impact.references): displacement = RMS over time of the probes' error relative to the
displacement scale; impulse = total contact impulse; force = mean contact force over the exact
contact phases; energy = largest deviation of kinetic + strain energy from the exact (constant)
energy, i.e. the energy lost.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import CASES
from fem_impact.config.case import load_case
from fem_impact.app.studies.convergence import convergence_study

VIBRATION = CASES / "free_vibration.yaml"
BAR = CASES / "impacting_bar.yaml"
SIGNORINI = CASES / "signorini_bar.yaml"
DTS = [0.1, 0.05, 0.025, 0.0125]


def study(case, tmp, vary, overrides=(), **options):
    # (the --set options go after the method's changes, as the command line passes them)
    return convergence_study(load_case(case), vary, changes=overrides, outdir=tmp, quiet=True, **options)


@pytest.fixture(scope="module")
def b2(tmp_path_factory):
    """B2a refined at Courant 0.5 (the case's): 50 to 400 cells, 400 to 3200 steps."""
    return study(BAR, tmp_path_factory.mktemp("b2"), ["mesh.cells=50,100,200,400"], overrides=["solver.t_end=2.5"])


@pytest.mark.parametrize("method, order, formula", [
    # The trapezoidal rule keeps the amplitude and shortens the period: tan(w_h dt/2) = w dt/2, so
    # w_h = w (1 - (w dt)^2/12 + ...). The phase error w t (w dt)^2/12 gives the end probe (amplitude a)
    # the error a (w dt)^2 w t/12 |sin w t|, whose RMS over [0, T] is a (w dt)^2 w T/(12 sqrt 6).
    ("trapezoidal", 2.0, lambda dt: (math.pi * dt) ** 2 * math.pi * 4.0 / (12 * math.sqrt(6))),
    # gamma = 0.6 damps with the ratio (gamma - 1/2) w dt/2 + O(dt^2): first order.
    ("damped-newmark", 1.0, None),
])
def test_free_vibration_converges_in_dt_with_the_order_of_the_scheme(tmp_path, method, order, formula):
    """Free-free bar in mode 1 (w = pi, two periods), 400 cells (mode 1's spatial error 2.6e-6 of its
    frequency, below the time error of the finest step by a factor 50): dt = 0.1 ... 0.0125.
    Measured: order 2.00 (trapezoidal), 1.05 (damped)."""
    result = study(VIBRATION, tmp_path, [f"solver.dt={','.join(map(str, DTS))}"], method=method,
                   overrides=["mesh.cells=400"])
    assert result["parameter"] == "dt" and result["reference"].startswith("exact bar_mode (mode 1")
    assert result["orders"]["err_displacement"] == pytest.approx(order, abs=0.1)
    if formula is not None:   # the error itself, not only its slope (5 %: the next term in (w dt)^2)
        errors = [r["err_displacement"] for r in result["rows"]]
        np.testing.assert_allclose(errors, [formula(dt) for dt in DTS], rtol=0.05)
    csv = (tmp_path / "convergence.csv").read_text().splitlines()
    assert csv[0].startswith("level,solver.dt,parameter,h,dt,courant") and len(csv) == 5
    assert (tmp_path / "convergence.png").stat().st_size > 10_000


def test_b2_orders_with_contact(b2):
    """B2a, h = 1/50 ... 1/400 at Courant 0.5. The exact solution is piecewise linear with kinks
    (velocity jumps of v0 running along the bar), so no second order: dispersion spreads each kink
    into a wave train whose pointwise displacement error decays like h^(2/3) (the front widens like
    (h^2 c t)^(1/3)); Doyen, Ern & Piperno (SIAM J. Sci. Comput. 2011) report orders between 1/2
    and 1 for such problems in L2-type norms. Measured (to t = 2.5, just after the contact):
    displacement 0.63, impulse 0.65, mean force 0.57 (0.65, 0.65, 0.57 to t = 4); asserted within
    0.1 and inside that bracket."""
    orders = b2["orders"]
    for measure, measured in (("err_displacement", 0.63), ("err_impulse", 0.65), ("err_force", 0.57)):
        assert orders[measure] == pytest.approx(measured, abs=0.1), measure
        assert 0.5 <= orders[measure] <= 1.0, measure
    assert b2["parameter"] == "h" and all(r["courant"] == pytest.approx(0.5) for r in b2["rows"])


def test_b2_impact_loss_with_plastic_node_vanishes_like_h(b2):
    """With e = 0 one impact removes about 1/(2 sqrt(3) n_el) of the energy (consistent mass,
    docs/benchmarks.md B2; docs/theory.md s. 10): the energy error of B2 is that loss. Order 1 +- 0.1
    (measured 1.00), and the loss itself within 10 % of the formula (measured 0.1 %)."""
    cells = np.array([50, 100, 200, 400])
    losses = np.array([r["err_energy"] for r in b2["rows"]])
    assert b2["orders"]["err_energy"] == pytest.approx(1.0, abs=0.1)
    np.testing.assert_allclose(losses, 1 / (2 * np.sqrt(3) * cells), rtol=0.1)


def test_b1_orders_with_contact(tmp_path):
    """B1 over four periods, 20 ... 160 cells at Courant 0.5 (the meshes of docs/benchmarks.md B1).
    Kinks as in B2 (velocity jumps of a c/L at each contact change): measured displacement 0.67,
    impulse 0.63, mean force 0.59; the energy lost over the four impacts (e = 0 at the node) 1.08
    (the loss per impact ~ h, as in B2). Asserted within 0.1 (energy 0.15)."""
    result = study(SIGNORINI, tmp_path, ["mesh.cells=20,40,80,160"])
    orders = result["orders"]
    for measure, measured in (("err_displacement", 0.67), ("err_impulse", 0.63), ("err_force", 0.59)):
        assert orders[measure] == pytest.approx(measured, abs=0.1), measure
    assert orders["err_energy"] == pytest.approx(1.0, abs=0.15)
    assert result["rows"][-1]["err_displacement"] < 0.01   # 0.79 % at 160 cells


@pytest.mark.parametrize("method", ["modal-truncated", "modal-static"])
def test_truncation_stays_wrong_as_dt_shrinks_the_static_correction_does_not(tmp_path, method):
    """B2a, 250 cells, 10 modes, dt = 0.004 ... 0.0005. Plain truncation keeps the wrong contact
    compliance (docs/theory.md s. 8.6): its errors converge in dt to a wrong limit (force 5.2 %,
    displacement 4.2 %, fitted order 0.00); with the static correction the same dt refinement
    converges to the full model's accuracy on this mesh (displacement 0.523 % at dt = 0.0005,
    the full model 0.528 %; force 0.28 %)."""
    result = study(BAR, tmp_path, ["solver.dt=0.004,0.002,0.001,0.0005"], method=method,
                   overrides=["solver.modes=10"])
    force = np.array([r["err_force"] for r in result["rows"]])
    displacement = np.array([r["err_displacement"] for r in result["rows"]])
    if method == "modal-truncated":
        assert np.all(force > 0.045) and np.all(displacement > 0.04)
        assert abs(result["orders"]["err_force"]) < 0.05 and abs(result["orders"]["err_displacement"]) < 0.05
    else:
        assert np.all(force < 0.005) and np.all(displacement < 0.006)
        steps = np.abs(np.diff(displacement))   # Cauchy: each halving of dt changes less
        assert np.all(steps[1:] < 0.5 * steps[:-1])
        assert displacement[-1] == pytest.approx(0.00528, rel=0.03)   # the full model at 250 cells
