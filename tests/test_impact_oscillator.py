"""The impact oscillator's exact reference against its closed forms (docs/impact_oscillator.md).

X'' + X = cos(w t), X <= 0, X'+ = -r X'- at the stop; r = 0.8. The event-driven map settles on
the closed-form period-1 orbit, shooting finds it, its multipliers multiply to r^2, one of them
crosses -1 at the derived period-doubling frequency, and the response doubles its period there.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from fem_impact.periodic import oscillator as osc

R = 0.8
W_PD = 2.653347727855323        # cos^2(pi/w) (w^2 - rho^2) = 1, rho = (1 - r)/(1 + r), solved once


@pytest.mark.parametrize("w", [0.5, 1.0, 2.3])
def test_flight_solves_the_equation(w):
    """The closed-form flight (also at resonance, w = 1) against an accurate ODE integration."""
    x0, v0, t0, t1 = -0.3, 0.7, 0.4, 6.0
    sol = solve_ivp(lambda t, y: [y[1], -y[0] + np.cos(w * t)], (t0, t1), [x0, v0], method="DOP853",
                    rtol=1e-13, atol=1e-13, dense_output=True)
    t = np.linspace(t0, t1, 9)
    x, v = osc.flight(x0, v0, t0, t, w)
    assert np.abs(x - sol.sol(t)[0]).max() < 1e-10
    assert np.abs(v - sol.sol(t)[1]).max() < 1e-10


def test_next_impact_finds_a_grazing_excursion_between_samples():
    """A flight that rises 1e-6 above the stop between two grid samples: the first crossing is
    found, to round-off, although every sample is below the stop."""
    w, tm = 2.0, np.pi / 2                        # at tm: X = 1e-6, X' = 0, X'' = -1 - 1e-6 (a top)
    t0 = tm - 0.3
    x0, v0 = osc.flight(1e-6, 0.0, tm, t0, w)     # the same flight, taken back to t0
    t_hit = osc.next_impact(float(x0), float(v0), t0, t0 + 3.0, w, cells_per_period=4)
    grid = np.linspace(t0, t0 + 3.0, int(np.ceil(3.0 / (np.pi / 4))) + 1)   # the search's samples
    assert grid[0] < tm < grid[1] and osc.flight(x0, v0, t0, grid[:3], w)[0].max() < 0   # none sees it
    assert t_hit is not None and tm - 2e-3 < t_hit < tm
    assert abs(osc.flight(x0, v0, t0, t_hit, w)[0]) < 1e-15
    before = np.linspace(t0, t_hit, 2001)[:-1]
    assert osc.flight(x0, v0, t0, before, w)[0].max() < 0    # and it is the first one


@pytest.mark.parametrize("w", [2.0, 2.4])
def test_simulation_settles_on_the_closed_form_orbit(w):
    """From a start 5 % off the orbit, the event-driven response settles on one impact a period at
    the closed-form speed V and phase."""
    orb = osc.period1_orbit(w, R)
    assert osc.period1_exists(w, R) and osc.period1_stable(w, R)
    _, times, speeds = osc.simulate(orb.state * np.array([1.05, 0.95]), w, R, 300)
    T = 2 * np.pi / w
    assert len(speeds) == 300 and np.all(np.diff(times) > 0.5 * T)   # one impact per period
    assert np.abs(speeds[-5:] - orb.speed).max() < 1e-8
    phase = np.angle(np.exp(1j * w * times[-1]))
    assert abs(np.angle(np.exp(1j * (phase - orb.phase)))) < 1e-8


@pytest.mark.parametrize("w", [1.5, 2.0, 2.4])
@pytest.mark.parametrize("jacobian", ["analytic", "fd"])
def test_shooting_finds_the_closed_form_orbit(w, jacobian):
    """Newton on P(x) = x from 10 % off converges to the closed-form orbit; its Jacobian's
    determinant is r^2 and its trace the closed form; the analytic and finite-difference Jacobians agree."""
    orb = osc.period1_orbit(w, R)
    res = osc.shoot(orb.state * 1.1, w, R, jacobian=jacobian)
    assert np.abs(res.state - orb.state).max() < 1e-10
    assert len(res.impact_speeds) == 1 and abs(res.impact_speeds[0] - orb.speed) < 1e-10
    assert abs(res.impact_times[0] - orb.impact_time) < 1e-10
    assert abs(np.prod(res.multipliers) - R**2) < 1e-8
    assert abs(np.linalg.det(res.jacobian) - R**2) < 1e-8
    assert abs(np.trace(res.jacobian) - osc.period1_trace(w, R)) < 1e-6
    closed = osc.period1_multipliers(w, R).astype(complex)
    np.testing.assert_allclose(np.sort_complex(res.multipliers), np.sort_complex(closed), atol=1e-6)
    if jacobian == "analytic":
        assert np.abs(osc.finite_difference_jacobian(res.state, w, R) - res.jacobian).max() < 1e-6


def test_closed_forms():
    """V and the phase at w = 2 by hand (cos phi = 0); the period-doubling frequency; the existence
    boundary (grazing) seen the same by the margin and by the impact search."""
    assert osc.impact_speed(2.0, R) == pytest.approx(2 / (3 * 0.2 / 2), rel=1e-14)
    assert osc.impact_phase(2.0, R) == pytest.approx(np.pi / 2, rel=1e-14)
    assert osc.impact_speed(1.0, R) == pytest.approx(np.pi / (1 + R), rel=1e-14)   # the limit at w = 1
    assert osc.period_doubling_frequency(R) == pytest.approx(W_PD, abs=1e-12)
    assert abs(osc.period_doubling_function(W_PD, R)) < 1e-14
    assert osc.period1_trace(W_PD, R) == pytest.approx(-(1 + R**2), abs=1e-12)
    wg = osc.grazing_frequency(R, (1.003, 1.1))
    assert not osc.period1_exists(wg - 1e-6, R) and osc.period1_exists(wg + 1e-6, R)


def test_a_multiplier_crosses_minus_one_at_the_period_doubling():
    """Shooting just below, at and just above the derived frequency: the larger multiplier is
    real and passes -1 there."""
    lam = {}
    for dw in (-1e-5, 0.0, 1e-5):
        w = W_PD + dw
        orb = osc.period1_orbit(w, R)
        res = osc.shoot(orb.state, w, R)
        assert abs(np.prod(res.multipliers) - R**2) < 1e-8
        assert np.all(np.isreal(res.multipliers))
        lam[dw] = res.multipliers[0].real
    assert -1 < lam[-1e-5] < -1 + 1e-3
    assert abs(lam[0.0] + 1) < 1e-8
    assert -1 - 1e-3 < lam[1e-5] < -1


def test_the_response_doubles_its_period_above_the_period_doubling():
    """From the same small offset of the period-1 orbit: just below W_PD the response settles on
    it, just above on two alternating impact speeds (a period-2 orbit, which shooting on P^2
    confirms, stable, with multipliers of product r^4)."""
    below, above = W_PD - 0.005, W_PD + 0.005
    orb = osc.period1_orbit(below, R)
    _, _, speeds = osc.simulate(orb.state + [-1e-3, 1e-3], below, R, 300)
    assert np.abs(speeds[-6:] - orb.speed).max() < 1e-8

    orb = osc.period1_orbit(above, R)
    states, _, speeds = osc.simulate(orb.state + [-1e-3, 1e-3], above, R, 600)
    a, b = speeds[-2], speeds[-1]
    assert abs(a - b) > 1e-3                                     # two different speeds...
    assert np.abs(speeds[-6::2] - a).max() < 1e-8 and np.abs(speeds[-5::2] - b).max() < 1e-8   # ...alternating
    p2 = osc.shoot(states[-1], above, R, periods=2)
    assert len(p2.impact_speeds) == 2 and np.abs(np.sort(p2.impact_speeds) - np.sort([a, b])).max() < 1e-8
    assert np.all(np.abs(p2.multipliers) < 1)
    assert abs(np.prod(p2.multipliers) - R**4) < 1e-8
