"""The harmonically forced impact oscillator: exact event-driven reference (docs/impact_oscillator.md).

Scaled equation, natural frequency 1, no damping but the impacts::

    X'' + X = cos(w t)        while X < 0
    X'+ = -r X'-              when X = 0 and X' > 0      (0 <= r < 1)

Between impacts the flight is the closed-form solution of the linear equation; an impact is
the first zero of that closed form in the step, bracketed on a grid and refined by brentq to
machine precision. On top of it: the stroboscopic Poincare map over one forcing period
``T = 2 pi / w`` (time 0 at forcing phase 0) with its exact Jacobian (flow and saltation
matrices), Newton shooting for a fixed point of ``P^k``, Floquet multipliers, and the closed
forms of the symmetric period-1 orbit (impact speed, impact phase, multipliers, period
doubling) derived in docs/impact_oscillator.md.

The reference handles isolated impacts (every periodic orbit of the study); a sticking phase or
an accumulation of impacts (chatter) is reported as an error, not integrated.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import brentq

__all__ = [
    "MapResult", "Period1", "ShootResult",
    "flight", "flow_matrix", "saltation_matrix", "next_impact", "poincare_map", "simulate",
    "shoot", "floquet_multipliers", "finite_difference_jacobian",
    "impact_speed", "impact_phase", "period1_orbit", "period1_exists", "period1_margin", "grazing_frequency",
    "period1_trace",
    "period1_multipliers", "period1_stable", "period_doubling_function", "period_doubling_frequency",
    "period_doubling_frequencies",
]

EPS = np.finfo(float).eps
# brentq's smallest relative tolerance: the roots are then exact to a few ulps.
_RTOL = 4 * EPS
_XTOL = 1e-300
CELLS_PER_PERIOD = 64      # grid cells per period of the faster of the two frequencies (1 and w)
MAX_IMPACTS = 1000         # per forcing period: more is chatter, which the reference does not follow


# --------------------------------------------------------------------------------------------
# The flight


def _forced_parts(s, w):
    """``C = (cos ws - cos s)/(1 - w^2)``, ``S = (sin ws - w sin s)/(1 - w^2)``, written without the
    division so that they hold at and near resonance (w = 1: ``C = s sin s / 2``,
    ``S = (sin s - s cos s)/2``)."""
    e = 0.5 * s * np.sinc((w - 1.0) * s / (2.0 * np.pi))     # sin((w - 1) s/2) / (w - 1)
    half = 0.5 * (w + 1.0) * s
    return 2.0 * np.sin(half) * e / (1.0 + w), (np.sin(s) - 2.0 * np.cos(half) * e) / (1.0 + w)


def flight(x0, v0, t0, t, w):
    """The exact free flight from ``(x0, v0)`` at time ``t0`` to time(s) ``t``: ``(X(t), X'(t))``.

    ``X = x0 cos s + v0 sin s + cos(w t0) C(s) - sin(w t0) S(s)``, ``s = t - t0``: the
    homogeneous solution plus the particular one ``cos(w t)/(1 - w^2)`` corrected to start at zero
    (docs/impact_oscillator.md, s. 2). ``t`` may be an array.
    """
    s = np.asarray(t, dtype=float) - t0
    c, sn = np.cos(s), np.sin(s)
    cf, sf = _forced_parts(s, w)
    a, b = np.cos(w * t0), np.sin(w * t0)
    x = x0 * c + v0 * sn + a * cf - b * sf
    v = -x0 * sn + v0 * c + a * (sn - w * sf) - b * w * cf
    return x, v


def flow_matrix(s):
    """d(state after a flight of duration s)/d(state before): the rotation ``[[cos s, sin s], [-sin s, cos s]]``."""
    c, sn = np.cos(s), np.sin(s)
    return np.array([[c, sn], [-sn, c]])


def saltation_matrix(v, t, w, r):
    """Jacobian of the impact at time t with approach speed ``v > 0`` (X = 0), including the shift
    of the impact instant: ``[[-r, 0], [(1 + r) a / v, -r]]``, ``a = cos(w t)`` the acceleration
    at the wall. Its determinant is ``r^2``."""
    return np.array([[-r, 0.0], [(1.0 + r) * np.cos(w * t) / v, -r]])


# --------------------------------------------------------------------------------------------
# Impacts


def next_impact(x0, v0, t0, t_end, w, cells_per_period=CELLS_PER_PERIOD):
    """The first time in ``(t0, t_end]`` at which the flight from ``(x0, v0)`` at ``t0`` reaches
    ``X = 0`` from below, or None.

    ``X`` and ``X'`` are sampled on a grid of ``cells_per_period`` cells per period of the faster
    frequency. A cell is examined when it ends at ``X >= 0`` or holds a maximum of ``X`` (``X'``
    from + to -), since a grazing excursion above 0 may lie between two samples. The cell is split
    at its turning point (brentq on ``X'``); on the first piece on which X rises from below 0 to
    0 or above, brentq on ``X`` gives the root to a few ulps. A start on the wall (``x0 = 0``,
    ``v0 < 0``) is not an impact. What the grid cannot see: two turning points of X within one
    cell (an excursion of height of order ``|X'''| h^3``).
    """
    if t_end <= t0:
        return None
    h = 2.0 * np.pi / (max(1.0, w) * cells_per_period)
    n = int(np.ceil((t_end - t0) / h))
    t = np.linspace(t0, t_end, n + 1)
    x, v = flight(x0, v0, t0, t, w)
    cells = np.flatnonzero((x[1:] >= 0.0) | ((v[:-1] > 0.0) & (v[1:] < 0.0)))

    def X(tt):
        return flight(x0, v0, t0, tt, w)[0]

    def V(tt):
        return flight(x0, v0, t0, tt, w)[1]

    for k in cells:                                   # in time order; usually one or two cells
        a, b = t[k], t[k + 1]
        pieces = [(a, b)]
        if v[k] * v[k + 1] < 0.0:
            tc = brentq(V, a, b, xtol=_XTOL, rtol=_RTOL)
            pieces = [(a, tc), (tc, b)]
        for p, q in pieces:
            xp, xq = X(p), X(q)
            if xp < 0.0 <= xq:
                return q if xq == 0.0 else brentq(X, p, q, xtol=_XTOL, rtol=_RTOL)
    return None


# --------------------------------------------------------------------------------------------
# The stroboscopic Poincare map


class MapResult(NamedTuple):
    """The state after the map, its Jacobian (None unless asked), and the impacts on the way:
    times (from the start of the map) and approach speeds."""

    state: np.ndarray
    jacobian: np.ndarray | None
    impact_times: np.ndarray
    impact_speeds: np.ndarray


def poincare_map(state, w, r, periods=1, jacobian=False, max_impacts=MAX_IMPACTS):
    """``P^periods(state)``: the state ``(X, X')`` at forcing phase 0, ``periods`` forcing periods on.

    ``state`` is taken at time 0, where the forcing is ``cos(0) = 1``. With ``jacobian=True``
    the exact Jacobian is the product of the flights' rotations and the impacts' saltation
    matrices (docs/impact_oscillator.md, s. 4). A state on the wall moving into it (``X >= 0``
    to round-off, ``X' > 0``) impacts at once.
    """
    x, v = (float(z) for z in state)
    if x > 1e-12 * max(1.0, abs(v)):
        raise ValueError(f"the state X = {x} is beyond the stop (X <= 0)")
    T = 2.0 * np.pi / w
    J = np.eye(2)
    times, speeds = [], []
    for j in range(periods):
        t = 0.0
        if x >= 0.0 and v > 0.0:                       # on the wall, moving in: impact now
            times.append(j * T)
            speeds.append(v)
            if jacobian:
                J = saltation_matrix(v, 0.0, w, r) @ J
            x, v = 0.0, -r * v
        count = 0
        while True:
            ti = next_impact(x, v, t, T, w)
            if ti is None:
                if jacobian:
                    J = flow_matrix(T - t) @ J
                x, v = flight(x, v, t, T, w)
                x, v = float(x), float(v)
                break
            _, vi = flight(x, v, t, ti, w)
            vi = float(vi)
            if jacobian:
                J = saltation_matrix(vi, ti, w, r) @ flow_matrix(ti - t) @ J
            times.append(j * T + ti)
            speeds.append(vi)
            x, v, t = 0.0, -r * vi, ti
            count += 1
            if count > max_impacts:
                raise RuntimeError(f"more than {max_impacts} impacts in one forcing period (chatter) at w = {w}")
    return MapResult(np.array([x, v]), J if jacobian else None, np.array(times), np.array(speeds))


def simulate(state, w, r, periods):
    """Iterate the map: the states at forcing phase 0 (``periods + 1`` rows) and every impact
    (times from the start, approach speeds)."""
    states = np.empty((periods + 1, 2))
    states[0] = state
    times, speeds = [], []
    T = 2.0 * np.pi / w
    for j in range(periods):
        res = poincare_map(states[j], w, r)
        states[j + 1] = res.state
        times.append(j * T + res.impact_times)
        speeds.append(res.impact_speeds)
    return states, np.concatenate(times), np.concatenate(speeds)


def finite_difference_jacobian(state, w, r, periods=1, step=1e-7):
    """Central differences of ``P^periods`` (a check of the analytic Jacobian)."""
    state = np.asarray(state, dtype=float)
    J = np.empty((2, 2))
    for i in range(2):
        d = np.zeros(2)
        d[i] = step * max(1.0, abs(state[i]))
        plus, minus = poincare_map(state + d, w, r, periods).state, poincare_map(state - d, w, r, periods).state
        J[:, i] = (plus - minus) / (2 * d[i])
    return J


class ShootResult(NamedTuple):
    """A fixed point of ``P^k``: the state at forcing phase 0, the Jacobian of ``P^k`` there, its
    Floquet multipliers, the impacts over the k periods, Newton's iterations and the last
    residual ``|P^k(x) - x|``."""

    state: np.ndarray
    jacobian: np.ndarray
    multipliers: np.ndarray
    impact_times: np.ndarray
    impact_speeds: np.ndarray
    iterations: int
    residual: float


def shoot(state, w, r, periods=1, jacobian="analytic", tol=1e-13, maxiter=40):
    """Newton's method on ``P^k(x) - x = 0`` from ``state`` (k = ``periods``).

    ``jacobian``: ``"analytic"`` (flows and saltations) or ``"fd"`` (central differences). Stops
    when the residual is below ``tol (1 + |x|)``; raises RuntimeError if it does not converge.
    """
    x = np.asarray(state, dtype=float).copy()
    for it in range(1, maxiter + 1):
        res = poincare_map(x, w, r, periods, jacobian=(jacobian == "analytic"))
        J = res.jacobian if jacobian == "analytic" else finite_difference_jacobian(x, w, r, periods)
        F = res.state - x
        residual = float(np.linalg.norm(F))
        if residual <= tol * (1.0 + np.linalg.norm(x)):
            return ShootResult(x, J, floquet_multipliers(J), res.impact_times, res.impact_speeds, it, residual)
        x = x - np.linalg.solve(J - np.eye(2), F)
        if x[0] > 0.0:                                  # a Newton step beyond the stop: onto the wall
            x[0] = 0.0
    raise RuntimeError(f"shooting did not converge in {maxiter} iterations (residual {residual:.3g})")


def floquet_multipliers(J):
    """Eigenvalues of a monodromy (Jacobian) matrix, largest modulus first."""
    lam = np.linalg.eigvals(J)
    return lam[np.argsort(-np.abs(lam), kind="stable")]


# --------------------------------------------------------------------------------------------
# Closed forms of the symmetric period-1 orbit (docs/impact_oscillator.md, s. 3 to 5)


def _q(w):
    """``(1 - w^2) / tan(pi/w)``, finite at w = 1 (``2/pi``): with ``u = pi (1 - w)/w``,
    ``tan(pi/w) = tan u`` and ``q = w (1 + w)/pi * u/tan u``."""
    u = np.pi * (1.0 - w) / w
    return w * (1.0 + w) / np.pi * np.cos(u) / np.sinc(u / np.pi)


def impact_speed(w, r):
    """``V = 2 / (|1 - w^2| sqrt((1 - r)^2/w^2 + (1 + r)^2/tan^2(pi/w)))``, the approach speed of
    the period-1 orbit (finite at w = 1: ``pi/(1 + r)``)."""
    w = np.asarray(w, dtype=float)
    return 2.0 / np.hypot((1.0 - w * w) * (1.0 - r) / w, (1.0 + r) * _q(w))


def impact_phase(w, r):
    """The forcing phase ``phi = w t_i (mod 2 pi)`` at the impact, in (-pi, pi]:
    ``sin phi = -(1 - r)(1 - w^2) V/(2 w)``, ``cos phi = (1 + r)(1 - w^2) V/(2 tan(pi/w))``."""
    w = np.asarray(w, dtype=float)
    V = impact_speed(w, r)
    return np.arctan2(-(1.0 - r) * (1.0 - w * w) * V / (2.0 * w), 0.5 * (1.0 + r) * _q(w) * V)


class Period1(NamedTuple):
    """The closed-form period-1 orbit: approach speed, forcing phase at the impact, impact time
    in ``[0, T)``, the state at forcing phase 0, the period."""

    speed: float
    phase: float
    impact_time: float
    state: np.ndarray
    period: float


def period1_orbit(w, r):
    """The period-1 orbit from the closed forms (whether it exists: :func:`period1_exists`)."""
    V, phi = float(impact_speed(w, r)), float(impact_phase(w, r))
    T = 2.0 * np.pi / w
    ti = np.mod(phi, 2.0 * np.pi) / w
    x, v = flight(0.0, -r * V, ti, T, w)            # from the rebound at t_i to phase 0 (t = T)
    return Period1(V, phi, ti, np.array([float(x), float(v)]), T)


def period1_exists(w, r):
    """True when the closed-form orbit is a motion: its flight leaves the stop into X < 0 (for
    r = 0, whose rebound speed is 0, the acceleration ``cos phi`` must pull away: else it sticks),
    stays below the stop at every turning point (:func:`period1_margin` < 0), and meets it next one
    period later (the impact search from the rebound)."""
    orb = period1_orbit(w, r)
    if r == 0.0 and np.cos(orb.phase) >= 0.0:
        return False
    T = orb.period
    t1 = next_impact(0.0, -r * orb.speed, orb.impact_time, orb.impact_time + 1.5 * T, w)
    return t1 is not None and abs(t1 - orb.impact_time - T) <= 1e-9 * T and period1_margin(w, r) < 0.0


def period1_margin(w, r, cells_per_period=CELLS_PER_PERIOD):
    """The largest value of X at a turning point inside the flight of the closed-form orbit (the
    flight's highest excursion): negative where the orbit exists, zero at a grazing (-inf when
    X has no interior maximum)."""
    orb = period1_orbit(w, r)
    x0, v0, t0 = 0.0, -r * orb.speed, orb.impact_time
    n = int(np.ceil(cells_per_period * max(1.0, w) / w))
    t = np.linspace(t0, t0 + orb.period, n + 1)
    v = flight(x0, v0, t0, t, w)[1]
    k = np.flatnonzero((v[:-1] > 0.0) & (v[1:] < 0.0))
    tops = [brentq(lambda s: flight(x0, v0, t0, s, w)[1], t[i], t[i + 1], xtol=_XTOL, rtol=_RTOL) for i in k]
    return max((float(flight(x0, v0, t0, tc, w)[0]) for tc in tops), default=-np.inf)


def grazing_frequency(r, bracket):
    """The frequency in ``bracket`` at which the flight of the period-1 orbit grazes the stop
    (:func:`period1_margin` = 0): an end of the orbit's existence."""
    return brentq(period1_margin, *bracket, args=(r,), xtol=_XTOL, rtol=_RTOL)


def period1_trace(w, r):
    """``tr J = -2 r cos(2 pi/w) + (1 + r)^2 (1 - w^2) cos^2(pi/w)`` (det J = r^2)."""
    w = np.asarray(w, dtype=float)
    c = np.cos(np.pi / w)
    return -2.0 * r * np.cos(2.0 * np.pi / w) + (1.0 + r) ** 2 * (1.0 - w * w) * c * c


def period1_multipliers(w, r):
    """The two Floquet multipliers, roots of ``lam^2 - tr lam + r^2 = 0``, largest modulus first."""
    tr = complex(period1_trace(w, r))
    d = np.sqrt(tr * tr - 4.0 * r * r)
    lam = np.array([(tr + d) / 2.0, (tr - d) / 2.0])
    lam = lam[np.argsort(-np.abs(lam), kind="stable")]
    return lam.real if np.all(np.abs(lam.imag) == 0.0) else lam


def period1_stable(w, r):
    """Both multipliers inside the unit circle: ``|tr J| < 1 + r^2``."""
    return np.abs(period1_trace(w, r)) < 1.0 + r * r


def period_doubling_function(w, r):
    """``cos^2(pi/w) (w^2 - rho^2) - 1``, ``rho = (1 - r)/(1 + r)``: zero where a multiplier is -1,
    negative where ``tr J > -(1 + r^2)`` (``tr J + 1 + r^2 = -(1 + r)^2`` times this function)."""
    w = np.asarray(w, dtype=float)
    rho = (1.0 - r) / (1.0 + r)
    return np.cos(np.pi / w) ** 2 * (w * w - rho * rho) - 1.0


def period_doubling_frequency(r, bracket=(2.0, 4.0)):
    """The period doubling of the period-1 orbit above w = 2 (the only one there: the function
    rises from -1 at w = 2 and is positive at w = 4)."""
    return brentq(period_doubling_function, *bracket, args=(r,), xtol=_XTOL, rtol=_RTOL)


def period_doubling_frequencies(r, w_min, w_max, samples=4001):
    """Every simple zero of :func:`period_doubling_function` in ``[w_min, w_max]`` (sign changes on
    a grid of ``samples`` points, refined by brentq)."""
    w = np.linspace(w_min, w_max, samples)
    g = period_doubling_function(w, r)
    k = np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)
    return np.array([brentq(period_doubling_function, w[i], w[i + 1], args=(r,), xtol=_XTOL, rtol=_RTOL) for i in k])
