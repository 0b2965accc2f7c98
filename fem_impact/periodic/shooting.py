"""Periodic orbits of a reduced model by shooting (docs/impact_oscillator.md s. 8): event-driven flights,
the stroboscopic Poincare map, Newton on ``P^k(x) = x``, Floquet multipliers.

The reduced model without static correction (``method: modal``, ``static_correction: false``) is
``Z'' + c Z' + w^2 Z = Y1^T R(t)`` between impacts, with rigid rows ``g = d0 - (P Y1) Z >= 0``. A
time-stepping scheme puts each impact at the end of a step: its impact instant, and so the orbit,
carry an error of the order of the step (measured on the impact oscillator: 0.1 to 1.5 % in the
impact speed at 500 to 1000 steps a period). Shooting needs the map's derivative, which depends
on the impact instants (the saltation matrix): here the flight is integrated by an adaptive
Runge-Kutta method (DOP853, relative tolerance 1e-12) with the gaps as events, so that an impact
is located to the tolerance, and Newton's law is applied there, row by row:
``Z'+ = Z'- - (1 + r) (P_j Z'-) P_j^T / |P_j|^2`` (unit modal masses). The Jacobian of ``P^k``
is taken by central differences, which then include the saltation.

It handles isolated impacts (every orbit a frequency sweep follows); a row that meets its stop
at a vanishing speed (sticking, chatter) stops the flight with :class:`ShootingError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from ..errors import SimulationError

RTOL = 1e-12
ATOL_FACTOR = 1e-14          # of the state's scale
MAX_IMPACTS = 200            # per forcing period
STICK_SPEED = 1e-7           # of the velocity scale: a rebound slower than this sticks
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
        return cls(w2, c, ops.load, P, np.asarray(ops.d0, float), np.asarray(ops.restitution, float))

    @property
    def n(self) -> int:
        return self.w2.size


@dataclass
class Orbit:
    """A periodic orbit of ``P^k``: its point on the section, its Floquet multipliers and impacts."""

    x: np.ndarray            # [Z, Z'] at forcing phase 0
    k: int
    multipliers: np.ndarray  # eigenvalues of the Jacobian of P^k (complex)
    residual: float          # |P^k(x) - x| / scale
    iterations: int
    impacts: list            # (t, row, approach speed) over the k periods

    @property
    def stable(self) -> bool:
        return bool(np.max(np.abs(self.multipliers)) < 1.0)


def flight(system: ReducedSystem, x: np.ndarray, t0: float, t1: float, impacts: list | None = None) -> np.ndarray:
    """The state [Z, Z'] at t1 from ``x`` at t0: exact to the tolerance, impacts located as events.

    A row that meets its stop at a vanishing speed (below ``STICK_SPEED`` of the velocity scale: the
    end of a chatter sequence) or starts on it at rest while the load presses it on, sticks: its
    acceleration is held at zero by a force ``lam = P_j a_free / |P_j|^2`` until that force would turn
    negative (an event: the row leaves its stop). One row at a time sticks; two at once is refused.
    """
    n = system.n
    force = np.zeros(n)
    # Scales: the state's, or (a start at rest) the static response to the load over the span
    system.load.evaluate(0.5 * (t0 + t1), force)
    reach = max(np.abs(system.load.evaluate(t0, np.zeros(n))).max(), np.abs(force).max()) / max(system.w2.min(), 1e-300)
    scale = max(np.abs(x[:n]).max(), reach, np.abs(system.d0).max(initial=0.0), 1e-300)
    vscale = max(np.abs(x[n:]).max(), scale * np.sqrt(system.w2.max()), 1e-300)
    scale = max(scale, np.abs(x[n:]).max())
    stuck: list[int] = []

    def free_acceleration(t, y):
        system.load.evaluate(t, force)
        return force - system.damping * y[n:] - system.w2 * y[:n]

    def holding(t, y, j):
        row = system.P[j]
        return float(row @ free_acceleration(t, y)) / float(row @ row)

    def rhs(t, y):
        a = free_acceleration(t, y)
        for j in stuck:
            row = system.P[j]
            a = a - (row @ a) / (row @ row) * row
        return np.concatenate([y[n:], a])

    def gap_event(j):
        def event(t, y):
            return system.d0[j] - system.P[j] @ y[:n] if j not in stuck else 1.0
        event.terminal, event.direction = True, -1
        return event

    def release_event(t, y):
        return holding(t, y, stuck[0]) if stuck else 1.0
    release_event.terminal, release_event.direction = True, -1

    events = [gap_event(j) for j in range(system.P.shape[0])] + [release_event]
    t, y, count = t0, np.array(x, dtype=float), 0
    span = t1 - t0
    for j in range(system.P.shape[0]):   # starting at rest on a stop that the load presses: stuck
        row = system.P[j]
        if abs(system.d0[j] - row @ y[:n]) <= 1e-12 * max(scale, abs(system.d0[j])) and \
                abs(row @ y[n:]) <= STICK_SPEED * vscale and holding(t, y, j) > 0.0:
            _stick(y, n, row, stuck, j)
    while t < t1:
        sol = solve_ivp(rhs, (t, t1), y, method="DOP853", rtol=RTOL, atol=ATOL_FACTOR * scale,
                        events=events, dense_output=False)
        if sol.status == -1:
            raise ShootingError(f"the flight's integration failed at t = {t:.6g}: {sol.message}")
        hit = None
        if sol.status == 1:   # an event: the first (not at the very start: a row just left, or just stuck)
            for j, times in enumerate(sol.t_events):
                for k, te in enumerate(times):
                    if te > t + 1e-12 * span and (hit is None or te < hit[0]):
                        hit = (te, j, sol.y_events[j][k])
        if hit is None:
            if sol.status == 1 and sol.t[-1] < t1:
                t, y = sol.t[-1], sol.y[:, -1]
                continue
            return sol.y[:, -1]
        t, j, y = hit[0], hit[1], hit[2].copy()
        if j == len(events) - 1:   # the stuck row's force reached zero: it leaves its stop
            stuck.clear()
            continue
        if stuck:
            raise ShootingError(f"row {j} meets its stop at t = {t:.6g} while row {stuck[0]} sticks: two rows at "
                                "once are not followed")
        row = system.P[j]
        speed = float(row @ y[n:])   # approach speed (>= 0)
        count += 1
        if count > MAX_IMPACTS * max(1.0, span):
            raise ShootingError(f"more than {MAX_IMPACTS} impacts a period at t = {t:.6g}: chatter that does not end")
        if impacts is not None:
            impacts.append((t, j, speed))
        y[n:] -= (1.0 + system.restitution[j]) * speed * row / (row @ row)
        if system.restitution[j] * speed <= STICK_SPEED * vscale and holding(t, y, j) > 0.0:
            _stick(y, n, row, stuck, j)   # the end of a chatter sequence (or a plastic impact): it stays
    return y


def _stick(y, n, row, stuck, j) -> None:
    y[n:] -= (row @ y[n:]) / (row @ row) * row
    stuck.append(j)


def poincare_map(system: ReducedSystem, x: np.ndarray, period: float, k: int = 1, impacts=None) -> np.ndarray:
    """``P^k(x)``: the state after k forcing periods from forcing phase 0."""
    return flight(system, x, 0.0, k * period, impacts)


def jacobian(system: ReducedSystem, x: np.ndarray, period: float, k: int) -> np.ndarray:
    scale = max(np.abs(x).max(), 1e-300)
    J = np.zeros((x.size, x.size))
    for i in range(x.size):
        h = DIFFERENCE_STEP * max(abs(x[i]), scale)
        plus, minus = x.copy(), x.copy()
        plus[i] += h
        minus[i] -= h
        J[:, i] = (poincare_map(system, plus, period, k) - poincare_map(system, minus, period, k)) / (2 * h)
    return J


def shoot(system: ReducedSystem, x0: np.ndarray, period: float, k: int = 1) -> Orbit:
    """Newton on ``P^k(x) - x = 0`` from ``x0``; the orbit with the multipliers of its Jacobian."""
    x = np.array(x0, dtype=float)
    for iteration in range(1, NEWTON_ITERATIONS + 1):
        scale = max(np.abs(x).max(), 1e-300)
        residual = poincare_map(system, x, period, k) - x
        J = jacobian(system, x, period, k)
        if np.abs(residual).max() <= NEWTON_TOL * scale:
            impacts: list = []
            poincare_map(system, x, period, k, impacts)
            return Orbit(x, k, np.linalg.eigvals(J), float(np.abs(residual).max() / scale), iteration, impacts)
        try:
            step = np.linalg.solve(J - np.eye(x.size), -residual)
        except np.linalg.LinAlgError:
            raise ShootingError("Newton's matrix J - I is singular (a multiplier at +1: a fold)") from None
        # damped: never more than the state's scale in one step (a far start)
        x = x + step * min(1.0, scale / max(np.abs(step).max(), 1e-300))
    raise ShootingError(f"Newton did not converge in {NEWTON_ITERATIONS} iterations (residual "
                        f"{np.abs(residual).max() / scale:.3g} of the state's scale)")


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

    from ..app.output import find_probes
    from ..app.pipeline import reduced_model
    from ..config.build import model_spec
    from ..fem.mesh import build_mesh
    from ..fem.model import build_model
    from ..integrators import is_reduced
    from ..nonsmooth.relation import build_constraints

    if not is_reduced(case.solver):
        raise ShootingError("shooting takes the reduced model (solver.method: modal, static_correction: false)")
    model = build_model(model_spec(case), build_mesh(case.mesh, MPI.COMM_SELF))
    cons = build_constraints(case.contacts, model)
    red = reduced_model(case, model, cons)
    system = ReducedSystem.from_operators(red.operators)
    probes = find_probes(case, model)
    Y1 = red.fields.Y1
    rows = np.array([[Y1[d] for d in dofs] for dofs in probes.owned_dofs]).reshape(-1, Y1.shape[1])
    start = np.concatenate([np.asarray(red.U0, float), np.asarray(red.V0, float)])
    return ReducedScene(system, start, probes.names, rows, probes.dim, [(c.name, c.rows) for c in cons.contacts])


def impulses(system: ReducedSystem, impacts: list) -> np.ndarray:
    """The impulse each row took in ``impacts`` ((t, row, approach speed), Newton's law)."""
    out = np.zeros(system.P.shape[0])
    for _, j, speed in impacts:
        row = system.P[j]
        out[j] += (1.0 + system.restitution[j]) * speed / (row @ row)
    return out
