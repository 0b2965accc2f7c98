"""Periodic orbits of a reduced model by shooting (docs/impact_oscillator.md s. 8): event-driven flights,
the stroboscopic Poincare map, Newton on ``P^k(x) = x``, Floquet multipliers.

The reduced model without static correction (``method: modal``, ``static_correction: false``) is
``Z'' + c Z' + w^2 Z = Y1^T R(t)`` between impacts, with rigid rows ``g = d(t) - (P Y1) Z >= 0`` (``d = d0``
for fixed stops; an obstacle's motion moves it, and Newton's law acts on the speed relative to it). A
time-stepping scheme puts each impact at the end of a step: its impact instant, and so the orbit,
carry an error of the order of the step (docs/impact_oscillator.md). Shooting needs the map's derivative, which depends
on the impact instants (the saltation matrix): here the flight is integrated by an adaptive
Runge-Kutta method (DOP853, relative tolerance 1e-12) with the gaps as events, so that an impact
is located to the tolerance, and Newton's law is applied there, row by row:
``Z'+ = Z'- - (1 + r) (P_j Z'- - d_j'(t)) P_j^T / |P_j|^2`` (unit modal masses). The Jacobian of ``P^k``
is taken by central differences, which then include the saltation.

It handles isolated impacts (every orbit a frequency sweep follows); a row that meets its stop
at a vanishing speed (sticking, chatter) stops the flight with :class:`ShootingError`.

Newton and the multipliers take the coordinates that some contact row sees (a column of ``P`` that
is not zero): the others (a free body's rigid drift along its stops, a mode with no motion at any
row) are linear, forced alone and never change an impact, and their neutral multipliers (exactly 1
for a rigid drift) say nothing of the impacting orbit's stability. Every flight is bounded (impacts
per forcing period, steps that do not advance, a deadline), so shooting ends with an orbit or a
:class:`ShootingError` saying why.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from ..errors import SimulationError

RTOL = 1e-12
ATOL_FACTOR = 1e-14          # of the state's scale
MAX_IMPACTS = 200            # per forcing period
MAX_STALLS = 50              # integrations in a row that end at their start (an event the flight cannot leave)
UNSEEN = 1e-9                # of the largest entry of P: a coordinate no row sees
STICK_SPEED = 1e-7           # of the velocity scale: a rebound slower than this sticks
HOP = 100                    # a rebound that rises less than this many times the stop's resolution sticks
NEWTON_TOL = 1e-10           # |P^k(x) - x| on the state's scale
NEWTON_ITERATIONS = 30
DIFFERENCE_STEP = 1e-6       # central differences, on the state's scale


class ShootingError(SimulationError):
    """A flight the event-driven integration does not follow (chatter), or Newton did not converge."""


@dataclass
class ReducedSystem:
    """The modal equations of a reduced model without static correction, as plain arrays."""

    w2: np.ndarray               # n1
    damping: np.ndarray          # n1 (zeros without damping)
    load: object                 # .evaluate(t, out): Y1^T R(t)
    P: np.ndarray                # p x n1: P Y1
    d0: np.ndarray
    restitution: np.ndarray
    # The rows' relations when an obstacle moves (their d(t), d'(t), d''(t): docs/theory.md s. 2.6), else None
    obstacles: object | None = None
    # A rigid body in translation (periodic/rigid.py): the rows whose impulse would turn it, else None
    spins: np.ndarray | None = None

    def gap0(self, t: float) -> np.ndarray:
        """``d(t)``: the rows' stops at time t."""
        return self.obstacles.gap(t) if self.obstacles is not None else self.d0

    def stop_rate(self, t: float) -> np.ndarray:
        """``d'(t)``: how fast each stop recedes (0 for fixed ones)."""
        return self.obstacles.gap_velocity(t) if self.obstacles is not None else np.zeros(self.d0.size)

    def stop_acceleration(self, t: float) -> np.ndarray:
        """``d''(t)``."""
        return self.obstacles.gap_acceleration(t) if self.obstacles is not None else np.zeros(self.d0.size)

    @classmethod
    def from_operators(cls, ops) -> ReducedSystem:
        if ops.static is not None:
            raise ShootingError("shooting takes the reduced model without static correction "
                                "(solver.static_correction: false): its rows must be rigid")
        if np.any(ops.stop_compliance):
            raise ShootingError("shooting takes rigid stops only (no contact stiffness)")
        if ops.pt:
            raise ShootingError("shooting takes frictionless contacts only")
        w2 = np.asarray(ops.K, dtype=float).copy()
        c = np.zeros_like(w2) if ops.C is None else np.asarray(ops.C, dtype=float).copy()
        P = np.asarray(ops.P_local.toarray() if hasattr(ops.P_local, "toarray") else ops.P_local).T.copy()
        return cls(w2, c, ops.load, P, np.asarray(ops.d0, float), np.asarray(ops.restitution, float),
                   ops.relations if ops.moving else None)

    @property
    def n(self) -> int:
        return self.w2.size

    @property
    def seen(self) -> np.ndarray:
        """Indices of the coordinates some contact row sees: the impacts depend on these alone, and the
        others (no row sees them: a rigid drift along the stops, a mode still at every row) on none."""
        size = np.abs(self.P).max(initial=0.0)
        return np.flatnonzero(np.abs(self.P).max(axis=0, initial=0.0) > UNSEEN * size)


@dataclass
class Orbit:
    """A periodic orbit of ``P^k``: its point on the section, its Floquet multipliers and impacts."""

    x: np.ndarray            # [Z, Z'] at forcing phase 0
    k: int
    multipliers: np.ndarray  # eigenvalues of the Jacobian of P^k on the coordinates the rows see (complex)
    residual: float          # |P^k(x) - x| / scale, on those coordinates
    iterations: int
    impacts: list            # (t, row, approach speed) over the k periods
    unseen: int = 0          # coordinates left out (no row sees them): 2 entries of x each
    held: np.ndarray | None = None   # per row, the impulse that held it stuck over the k periods

    @property
    def stable(self) -> bool:
        return bool(np.max(np.abs(self.multipliers)) < 1.0)


class _OutOfTime(Exception):
    pass


def flight(system: ReducedSystem, x: np.ndarray, t0: float, t1: float, impacts: list | None = None,
           max_impacts: int = MAX_IMPACTS, deadline: float | None = None, held: np.ndarray | None = None) -> np.ndarray:
    """The state [Z, Z'] at t1 from ``x`` at t0: exact to the tolerance, impacts located as events.

    ``impacts`` gets (t, row, approach speed) of every impact; ``held`` (one entry a row) adds the impulse
    of the force that holds a row stuck on its stop (integrated with the flight).

    At most ``max_impacts`` impacts (callers pass ``MAX_IMPACTS`` per forcing period of the span),
    and no later than ``deadline`` (``time.monotonic()``); beyond either, and when the integration
    keeps stopping where it starts (an event it cannot leave), a :class:`ShootingError`.

    A row that meets its stop at a vanishing speed (below ``STICK_SPEED`` of the velocity scale: the
    end of a chatter sequence) or starts on it at rest while the load presses it on, sticks: its
    acceleration is held at zero by a force ``lam = P_j a_free / |P_j|^2`` until that force would turn
    negative (an event: the row leaves its stop). One row at a time sticks; two at once is refused.
    """
    n, n2 = system.n, 2 * system.n
    force = np.zeros(n)
    span = t1 - t0
    # Scales: the state's, or (a start at rest) the response to the load over the span: static for a mode
    # stiffer than the span, the motion under it for a softer one (a rigid mode: w2 = 0)
    system.load.evaluate(0.5 * (t0 + t1), force)
    load = np.maximum(np.abs(system.load.evaluate(t0, np.zeros(n))), np.abs(force))
    reach = float((load / np.maximum(system.w2, 1.0 / max(t1 - t0, 1e-300) ** 2)).max(initial=0.0))
    stops = np.abs(system.gap0(t0)).max(initial=0.0)
    scale = max(np.abs(x[:n]).max(), reach, stops, 1e-300)
    vscale = max(np.abs(x[n:]).max(), scale * np.sqrt(system.w2.max()), scale / span, 1e-300)
    scale = max(scale, np.abs(x[n:]).max())
    stuck: list[int] = []

    def free_acceleration(t, y):
        system.load.evaluate(t, force)
        return force - system.damping * y[n:n2] - system.w2 * y[:n]

    def holding(t, y, j):
        """The force that keeps row j on its stop (moving with the stop's acceleration)."""
        row = system.P[j]
        return (float(row @ free_acceleration(t, y)) - float(system.stop_acceleration(t)[j])) / float(row @ row)

    def rhs(t, y):
        if deadline is not None and time.monotonic() > deadline:
            raise _OutOfTime
        a = free_acceleration(t, y)
        lam = 0.0
        for j in stuck:
            row = system.P[j]
            lam = (row @ a - system.stop_acceleration(t)[j]) / (row @ row)
            a = a - lam * row
        return np.concatenate([y[n:n2], a, [lam]])   # (the last: the impulse that holds the stuck row)

    def gap_event(j):   # (crossing a hair beyond the stop: a row that starts on it, at zero, is seen coming back)
        def event(t, y):
            return system.gap0(t)[j] - system.P[j] @ y[:n] + at_stop if j not in stuck else 1.0
        event.terminal, event.direction = True, -1
        return event

    def release_event(t, y):
        return holding(t, y, stuck[0]) if stuck else 1.0
    release_event.terminal, release_event.direction = True, -1

    events = [gap_event(j) for j in range(system.P.shape[0])] + [release_event]
    t, y, count, stalls = t0, np.concatenate([np.asarray(x, dtype=float), [0.0]]), 0, 0
    atol = np.full(n2 + 1, ATOL_FACTOR * scale)
    atol[-1] = ATOL_FACTOR * vscale / max(np.linalg.norm(system.P, axis=1).max(initial=0.0), 1e-300)
    at_stop = 1e-12 * max(scale, stops)   # a row this close is on its stop
    lost = 1e-9 * scale                                                  # a row this far beyond it was lost
    pressed = 1e-10 * max(vscale * np.sqrt(system.w2.max()), vscale / span, load.max())   # |acceleration| of a row

    def turns(t, j):
        """A rigid body in translation struck off its centre's line would turn: not this flight's."""
        if system.spins is not None and system.spins[j]:
            raise ShootingError(f"row {j} meets its obstacle at t = {t:.6g} off the line through the rigid body's "
                                "centre: the impact would turn it, and the event-driven flight takes it in "
                                "translation (--flight scheme integrates its rotation)")

    def impact(t, j, y):
        nonlocal count
        turns(t, j)
        if stuck:
            raise ShootingError(f"row {j} meets its stop at t = {t:.6g} while row {stuck[0]} sticks: two rows at "
                                "once are not followed")
        row = system.P[j]
        speed = float(row @ y[n:n2]) - float(system.stop_rate(t)[j])   # approach speed to the stop (>= 0)
        count += 1
        if count > max_impacts:
            raise ShootingError(f"more than {max_impacts} impacts at t = {t:.6g} ({MAX_IMPACTS} a forcing period): "
                                "chatter that does not end")
        if impacts is not None:
            impacts.append((t, j, speed))
        y[n:n2] -= (1.0 + system.restitution[j]) * speed * row / (row @ row)
        rebound, pull = system.restitution[j] * speed, holding(t, y, j) * float(row @ row)
        if pull > 0.0 and (rebound <= STICK_SPEED * vscale or rebound ** 2 <= 2.0 * pull * HOP * at_stop):
            _stick(y, n, row, stuck, j, held, system.stop_rate(t)[j])   # the end of a chatter sequence: it stays

    def on_stops(t, y):
        """Rows on their stops where a flight starts or goes on (an event cannot see a gap that starts at
        zero): moving in, an impact now; at rest (to the sticking speed) and pressed by the load, stuck."""
        for j in range(system.P.shape[0]):
            row = system.P[j]
            gap = system.gap0(t)[j] - row @ y[:n]
            if j in stuck or gap > at_stop:
                continue
            if gap < 0.0:   # (on it: at the event a hair beyond, or round-off)
                y[:n] += gap / (row @ row) * row
            speed = float(row @ y[n:n2]) - float(system.stop_rate(t)[j])
            if speed > STICK_SPEED * vscale:
                impact(t, j, y)
            elif speed > -STICK_SPEED * vscale and holding(t, y, j) * np.linalg.norm(row) > pressed:
                turns(t, j)
                if stuck:
                    raise ShootingError(f"rows {stuck[0]} and {j} stick at once at t = {t:.6g}: two rows at once "
                                        "are not followed")
                _stick(y, n, row, stuck, j, held, system.stop_rate(t)[j])

    on_stops(t, y)
    while t < t1:
        try:
            sol = solve_ivp(rhs, (t, t1), y, method="DOP853", rtol=RTOL, atol=atol,
                            events=events, dense_output=False)
        except _OutOfTime:
            raise ShootingError(f"the flight reached its time limit at t = {t:.6g}") from None
        if sol.status == -1 or not np.all(np.isfinite(sol.y[:, -1])):
            raise ShootingError(f"the flight's integration failed at t = {t:.6g}: {sol.message}")
        free = [j for j in range(system.P.shape[0]) if j not in stuck]
        stops_then = (system.d0[:, None] if system.obstacles is None
                      else np.column_stack([system.gap0(ti) for ti in sol.t]))
        depth = (system.P[free] @ sol.y[:n] - stops_then[free]).max(initial=-np.inf) if free else -np.inf
        if depth > lost:   # (a row beyond its stop between two events: the flight lost a contact)
            raise ShootingError(f"a row went {depth:.3g} beyond its stop after t = {t:.6g}: a contact the "
                                "event-driven flight lost")
        hit = None
        if sol.status == 1:   # an event: the first (not at the very start: a row just left, or just stuck)
            for j, times in enumerate(sol.t_events):
                for k, te in enumerate(times):
                    if te > t + 1e-12 * span and (hit is None or te < hit[0]):
                        hit = (te, j, sol.y_events[j][k])
        end = sol.y[:, -1] if hit is None else hit[2]
        if stuck and held is not None:
            held[stuck[0]] += end[-1]
        if hit is None:
            if sol.t[-1] < t1:
                stalls = stalls + 1 if sol.t[-1] <= t + 1e-12 * span else 0
                if stalls > MAX_STALLS:
                    raise ShootingError(f"the flight does not advance at t = {t:.6g}: a row stays at its stop "
                                        "in a way the event-driven flight does not follow")
                t, y = sol.t[-1], sol.y[:, -1].copy()
                y[-1] = 0.0
                on_stops(t, y)
                continue
            return sol.y[:n2, -1]
        stalls = 0
        t, j, y = hit[0], hit[1], hit[2].copy()
        y[-1] = 0.0
        if j == len(events) - 1:   # the stuck row's force reached zero: it leaves its stop
            stuck.clear()
        else:
            impact(t, j, y)
        on_stops(t, y)
    return y[:n2]


def _stick(y, n, row, stuck, j, held, rate: float = 0.0) -> None:
    """Row j stays on its stop: its remaining approach speed (relative to the stop, which recedes at
    ``rate``) is taken by an impulse (counted in ``held``)."""
    lam = (row @ y[n:2 * n] - rate) / (row @ row)
    y[n:2 * n] -= lam * row
    if held is not None:
        held[j] += lam
    stuck.append(j)


def poincare_map(system: ReducedSystem, x: np.ndarray, period: float, k: int = 1, impacts=None,
                 deadline: float | None = None, held: np.ndarray | None = None) -> np.ndarray:
    """``P^k(x)``: the state after k forcing periods from forcing phase 0 (``impacts``, ``held``: :func:`flight`)."""
    return flight(system, x, 0.0, k * period, impacts, max_impacts=MAX_IMPACTS * k, deadline=deadline, held=held)


def _coordinates(system: ReducedSystem) -> np.ndarray:
    """The entries of [Z, Z'] that shooting solves for: those of the coordinates a row sees."""
    seen = system.seen
    return np.concatenate([seen, system.n + seen])


def jacobian(system: ReducedSystem, x: np.ndarray, period: float, k: int, deadline: float | None = None,
             entries: np.ndarray | None = None) -> np.ndarray:
    """Central differences of ``P^k`` at ``x`` on ``entries`` of the state (default all): rows and columns."""
    entries = np.arange(x.size) if entries is None else entries
    scale = max(np.abs(x[entries]).max(initial=0.0), 1e-300)
    J = np.zeros((entries.size, entries.size))
    for col, i in enumerate(entries):
        h = DIFFERENCE_STEP * max(abs(x[i]), scale)
        plus, minus = x.copy(), x.copy()
        plus[i] += h
        minus[i] -= h
        J[:, col] = (poincare_map(system, plus, period, k, deadline=deadline)[entries]
                     - poincare_map(system, minus, period, k, deadline=deadline)[entries]) / (2 * h)
    return J


def shoot(system: ReducedSystem, x0: np.ndarray, period: float, k: int = 1, seconds: float | None = None,
          progress=None) -> Orbit:
    """Newton on ``P^k(x) - x = 0`` from ``x0``; the orbit with the multipliers of its Jacobian.

    Newton and the multipliers take the coordinates some contact row sees (:attr:`ReducedSystem.seen`);
    the others keep their values of ``x0``. ``seconds``: a time limit (ShootingError beyond it);
    ``progress(iteration, residual, elapsed)`` is called after each of Newton's iterations.
    """
    start = time.monotonic()
    deadline = None if seconds is None else start + seconds
    entries = _coordinates(system)
    if entries.size == 0:
        raise ShootingError("no contact row sees any of the kept modes: there are no impacts to follow")
    x = np.array(x0, dtype=float)
    try:
        for iteration in range(1, NEWTON_ITERATIONS + 1):
            scale = max(np.abs(x[entries]).max(), 1e-300)
            residual = (poincare_map(system, x, period, k, deadline=deadline) - x)[entries]
            J = jacobian(system, x, period, k, deadline, entries)
            if progress is not None:
                progress(iteration, float(np.abs(residual).max() / scale), time.monotonic() - start)
            if np.abs(residual).max() <= NEWTON_TOL * scale:
                impacts: list = []
                held = np.zeros(system.P.shape[0])
                poincare_map(system, x, period, k, impacts, deadline=deadline, held=held)
                return Orbit(x, k, np.linalg.eigvals(J), float(np.abs(residual).max() / scale), iteration, impacts,
                             system.n - entries.size // 2, held)
            try:
                step = np.linalg.solve(J - np.eye(entries.size), -residual)
            except np.linalg.LinAlgError:
                raise ShootingError("Newton's matrix J - I is singular (a multiplier at +1: a fold)") from None
            # damped: never more than the state's scale in one step (a far start)
            x[entries] += step * min(1.0, scale / max(np.abs(step).max(), 1e-300))
    except ShootingError as err:
        if deadline is not None and time.monotonic() > deadline:
            raise ShootingError(f"shooting stopped at its time limit of {seconds:g} s (iteration {iteration}): "
                                f"{err}") from None
        raise
    raise ShootingError(f"Newton did not converge in {NEWTON_ITERATIONS} iterations (residual "
                        f"{np.abs(residual).max() / scale:.3g} of the state's scale)")


def least_period(system: ReducedSystem, orbit: Orbit, period: float, seconds: float | None = None) -> int:
    """The orbit's least period: the smallest divisor m of its k with ``P^m(x) = x`` (to far below the
    differences Newton's tolerance leaves): a fixed point of ``P^6`` may be the period-2 orbit."""
    deadline = None if seconds is None else time.monotonic() + seconds
    entries = _coordinates(system)
    scale = max(np.abs(orbit.x[entries]).max(), 1e-300)
    for m in range(1, orbit.k):
        if orbit.k % m == 0:
            back = poincare_map(system, orbit.x, period, m, deadline=deadline)[entries]
            if np.abs(back - orbit.x[entries]).max() <= 1e3 * NEWTON_TOL * scale:
                return m
    return orbit.k


@dataclass
class ReducedScene:
    """A case's reduced model as the shooting and the event-driven sweep use it (serial)."""

    system: ReducedSystem
    start: np.ndarray          # [Z0, Z0'] of the case's initial state
    probes: list               # names
    probe_rows: np.ndarray     # (probes x dim) x n1: Y1 at the probes' dofs
    dim: int
    contacts: list             # (name, rows)


def reduced_scene(case) -> ReducedScene:
    """Build the case's reduced model (its modes from the cache after the first time); ShootingError
    when it is not one shooting takes (the method is not modal, a static correction, elastic stops)."""
    from mpi4py import MPI

    from ..build import build_system
    from ..integrators import is_reduced
    from .rigid import rigid_system

    rigid = any(model == "rigid" for model in case.bodies.values())
    if not (rigid or is_reduced(case.solver)):
        raise ShootingError("shooting takes the reduced model (solver.method: modal, static_correction: false) "
                            "or a rigid body (bodies: {NAME: {model: rigid}})")
    built = build_system(case, MPI.COMM_SELF, probes=True)
    probes = built.probes
    if rigid:
        system, start, rows = rigid_system(built, ReducedSystem, ShootingError)
        return ReducedScene(system, start, probes.names, rows, probes.dim,
                            [(c.name, c.rows) for c in built.constraints.contacts])
    system = ReducedSystem.from_operators(built.operators)
    Y1 = built.fields.Y1
    rows = np.array([[Y1[d] for d in dofs] for dofs in probes.owned_dofs]).reshape(-1, Y1.shape[1])
    start = np.concatenate([np.asarray(built.U0, float), np.asarray(built.V0, float)])
    return ReducedScene(system, start, probes.names, rows, probes.dim,
                        [(c.name, c.rows) for c in built.constraints.contacts])


def impulses(system: ReducedSystem, impacts: list, held: np.ndarray | None = None) -> np.ndarray:
    """The impulse each row took in ``impacts`` ((t, row, approach speed), Newton's law), plus ``held``
    (the impulse of the forces that held rows stuck)."""
    out = np.zeros(system.P.shape[0]) if held is None else np.array(held, dtype=float)
    for _, j, speed in impacts:
        row = system.P[j]
        out[j] += (1.0 + system.restitution[j]) * speed / (row @ row)
    return out
