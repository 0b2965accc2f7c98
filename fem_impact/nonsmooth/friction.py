"""Coulomb friction: the one-step frictional contact problem and its certified solver.

The problem (docs/theory.md s. 11). Every contact row i has a normal unknown ``r_N`` (the
impulse of the step, as in the frictionless LCP) and, where its contact has a friction
coefficient ``mu > 0``, one tangential unknown per tangent direction (one in 2D, two in 3D):
the tangential impulse ``r_T`` that acts on the structure as ``-P_T^T r_T``. The local
velocities are affine in the impulses through the step's Delassus matrix,

    y = W r + q,     y_N = the row's separating velocity (or gap rate), y_T = -P_T V1,

and Coulomb's law with Newton's on the normal part holds in De Saxce's form, row by row,

    K_mu = {|r_T| <= mu r_N},   r in K_mu,   y + mu |y_T| e_N in K_mu*,   r . (y + mu |y_T| e_N) = 0:

no impulse and ``y_N >= 0`` (open), or ``y_N = 0`` and either ``y_T = 0`` with ``|r_T| <= mu
r_N`` (stick) or ``r_T = -mu r_N y_T / |y_T|`` (slip, the impulse opposing the tangential
velocity at the end of the step). Rows without friction have only their normal part.

Solver: nonsmooth Gauss-Seidel over the rows (each row's 2 x 2 or 3 x 3 problem solved
exactly: open, stick, or slip in the direction that makes the tangential velocity parallel to
the friction impulse), warm-started from the previous step; every ``NEWTON_AFTER`` sweeps Alart
and Curnier's semismooth Newton method takes over from the iterate (coupled rows, where
Gauss-Seidel crawls) and is kept when it does better. It stops when the residual below
is under the tolerance; a solve that misses it is reported (``FrictionSolution.converged``),
never accepted in silence.

Residual (the natural map of the cone problem, as Siconos' fc3d_compute_error measures it):
per row ``|r_i - proj_K(r_i - rho_i (y_i + mu |y_T,i| e_N))|`` with ``rho_i = 1 / W_NN,i`` (so
that impulse and velocity compare in the row's own mass), the largest over the rows divided by
the size of the data, ``max(|r|_inf, max_i rho_i |q_i|_inf)``: dimensionless, 0 at a solution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TINY = np.finfo(float).tiny


@dataclass
class FrictionSolution:
    r: np.ndarray          # impulses: normal rows first (p), then the tangent rows (pt)
    y: np.ndarray          # W r + q
    residual: float        # dimensionless natural-map residual (module docstring)
    sweeps: int
    converged: bool
    worst_row: int         # the normal row with the largest residual
    newton: int = 0        # times Newton's method took over from Gauss-Seidel (another solver: a retry)


def project_on_cone(z_n: float, z_t: np.ndarray, mu: float) -> tuple[float, np.ndarray]:
    """The projection of ``(z_n, z_t)`` on the cone ``|r_T| <= mu r_N`` (Euclidean)."""
    norm_t = float(np.sqrt(z_t.dot(z_t)))
    if norm_t <= mu * z_n:
        return z_n, z_t
    if mu * norm_t <= -z_n or (mu == 0.0 and z_n <= 0.0):
        return 0.0, np.zeros_like(z_t)
    if mu == 0.0:
        return z_n, np.zeros_like(z_t)
    r_n = (z_n + mu * norm_t) / (1.0 + mu * mu)
    return r_n, (mu * r_n / norm_t) * z_t


def row_residual(r: np.ndarray, y: np.ndarray, mu: float, rho: float) -> float:
    """``|r - proj_K(r - rho (y + mu |y_T| e_N))|`` for one row (r, y: normal first)."""
    y_t = y[1:]
    shifted = y[0] + mu * float(np.sqrt(y_t.dot(y_t)))
    z_n, z_t = r[0] - rho * shifted, r[1:] - rho * y_t
    p_n, p_t = project_on_cone(z_n, z_t, mu)
    return float(np.sqrt((r[0] - p_n) ** 2 + np.sum((r[1:] - p_t) ** 2)))


def solve_row(W: np.ndarray, q: np.ndarray, mu: float) -> np.ndarray:
    """Exact solution of one row's problem ``y = W r + q`` (W: 1 x 1, 2 x 2 or 3 x 3, SPD).

    Open when ``q_N >= 0``; else stick when ``-W^-1 q`` lies in the cone; else slip: the
    normal impulse closes the row, ``r_N = -q_N / (W_NN - mu W_NT . tau)``, and the direction
    ``tau`` of the tangential velocity solves ``y_T(tau) = |y_T| tau`` (two candidates in 2D;
    in 3D the real roots of a quartic in tan(phi / 2), phi the direction's angle).
    """
    if q[0] >= 0.0:
        return np.zeros(q.size)
    if q.size == 1 or mu == 0.0:
        r = np.zeros(q.size)
        r[0] = -q[0] / W[0, 0]
        return r
    stick = -np.linalg.solve(W, q)
    if stick[0] >= 0.0 and float(np.sqrt(stick[1:].dot(stick[1:]))) <= mu * stick[0] * (1.0 + 1e-14):
        return stick

    def slip(tau: np.ndarray):
        denominator = W[0, 0] - mu * W[0, 1:].dot(tau)
        if denominator <= 0.0:
            return None
        r_n = -q[0] / denominator
        y_t = q[1:] + r_n * (W[1:, 0] - mu * W[1:, 1:].dot(tau))
        return r_n, y_t

    def as_row(r_n: float, tau: np.ndarray) -> np.ndarray:
        return np.concatenate([[r_n], -mu * r_n * tau])

    if q.size == 2:
        best, best_res = None, np.inf
        for sign in (1.0, -1.0):
            tau = np.array([sign])
            out = slip(tau)
            if out is None:
                continue
            r = as_row(out[0], tau)
            res = row_residual(r, W.dot(r) + q, mu, 1.0 / W[0, 0])
            if out[1][0] * sign >= 0.0 and res < best_res:
                best, best_res = r, res
        return best if best is not None else _projected_row(W, q, mu, stick)
    # 3D: the direction tau = (cos phi, sin phi) of the tangential velocity, from y_T(tau) x tau = 0:
    # multiplied by (W_NN - mu W_NT . tau) it is a trigonometric polynomial of degree 2 in phi, a quartic
    # in t = tan(phi / 2) (its roots exact, no iteration); each real root is a candidate.
    best, best_res = None, np.inf
    for tau in _slip_directions(W, q, mu):
        out = slip(tau)
        if out is None or out[0] < 0.0 or out[1].dot(tau) < 0.0:
            continue
        r = as_row(out[0], tau)
        res = row_residual(r, W.dot(r) + q, mu, 1.0 / W[0, 0])
        if res < best_res:
            best, best_res = r, res
    return best if best is not None else _projected_row(W, q, mu, stick)


def _slip_directions(W: np.ndarray, q: np.ndarray, mu: float) -> list[np.ndarray]:
    """Unit directions tau in the tangent plane (3D) where the slip law's tangential velocity is
    parallel to tau: the real roots of the quartic in t = tan(phi / 2), and phi = pi."""
    a, b, D = W[0, 0], W[0, 1:], W[1:, 1:]
    c, q_n, (q1, q2) = W[1:, 0], q[0], q[1:]
    # F(phi) = A1 C + A2 S + A3 C^2 + A4 S^2 + A5 S C with C = cos phi, S = sin phi.
    A1 = a * q2 - q_n * c[1]
    A2 = -a * q1 + q_n * c[0]
    A3 = mu * (q_n * D[0, 1] - b[0] * q2)
    A4 = mu * (b[1] * q1 - q_n * D[0, 1])
    A5 = mu * (b[0] * q1 - b[1] * q2 + q_n * (D[1, 1] - D[0, 0]))
    coefficients = [A3 - A1, 2.0 * (A2 - A5), 4.0 * A4 - 2.0 * A3, 2.0 * (A2 + A5), A1 + A3]
    roots = np.roots(coefficients) if np.any(coefficients) else np.zeros(0)
    phis = [2.0 * np.arctan(t.real) for t in roots if abs(t.imag) <= 1e-9 * max(1.0, abs(t))] + [np.pi]
    return [np.array([np.cos(phi), np.sin(phi)]) for phi in phis]


def _projected_row(W, q, mu, start):
    """Fallback for a row with no closed-form candidate: the projected fixed point
    ``r <- proj_K(r - rho (W r + q + mu |y_T| e_N))`` (its residual decides whether it is kept)."""
    rho = 1.0 / np.linalg.eigvalsh(W).max()
    r = np.concatenate([[max(start[0], 0.0)], np.zeros(q.size - 1)])
    for _ in range(2000):
        y = W.dot(r) + q
        shifted = y[0] + mu * float(np.linalg.norm(y[1:]))
        r_n, r_t = project_on_cone(r[0] - rho * shifted, r[1:] - rho * y[1:], mu)
        new = np.concatenate([[r_n], r_t])
        if np.abs(new - r).max() <= 1e-15 * max(np.abs(new).max(), TINY):
            return new
        r = new
    return r


class FrictionProblem:
    """The frictional contact problem of a step in one Delassus matrix (module docstring).

    ``W``: (p + pt) x (p + pt), normal rows first, then the tangent rows; ``tangent_of[k]`` is the
    normal row of tangent row k; ``mu``: the friction coefficient per normal row.
    """

    TOLERANCE = 1e-10
    MAX_SWEEPS = 2000
    NEWTON_AFTER = 100   # sweeps of Gauss-Seidel before Newton's method takes over (coupled rows)
    NEWTON_SIZE = 600    # unknowns up to which it may (its steps are dense least-squares solves)

    def __init__(self, W: np.ndarray, tangent_of: np.ndarray, mu: np.ndarray):
        self.W = np.ascontiguousarray(W, dtype=float)
        self.p, self.mu = mu.size, np.asarray(mu, dtype=float)
        self.blocks = [np.array([i] + [self.p + k for k in np.flatnonzero(tangent_of == i)])
                       for i in range(self.p)]
        self.local = [self.W[np.ix_(b, b)] for b in self.blocks]
        self.rho = 1.0 / np.diag(self.W)[:self.p]
        self._block_key, self._block_matrix = None, None

    def solve(self, q: np.ndarray, active: np.ndarray, guess: np.ndarray | None = None) -> FrictionSolution:
        """Solve on the ``active`` normal rows (and their tangent rows); the others carry nothing."""
        n = q.size
        rows = np.flatnonzero(active)
        r = np.zeros(n)
        if not rows.size:
            return FrictionSolution(r, q.copy(), 0.0, 0, True, -1)
        idx = np.concatenate([self.blocks[i] for i in rows])
        if guess is not None:
            r[idx] = guess[idx]
        Wa = self._block(idx)
        y = q.copy()
        y[idx] = Wa.dot(r[idx]) + q[idx]
        # Each row's position within idx, for the updates of y.
        where, start = [], 0
        for i in rows:
            where.append(slice(start, start + self.blocks[i].size))
            start += self.blocks[i].size
        ya, ra = y[idx], r[idx]
        residual, worst, sweeps, newton = np.inf, -1, 0, 0
        for sweeps in range(1, self.MAX_SWEEPS + 1):
            for i, s in zip(rows, where):
                Wi = self.local[i]
                qi = ya[s] - Wi.dot(ra[s])
                new = solve_row(Wi, qi, self.mu[i])
                change = new - ra[s]
                if np.count_nonzero(change):
                    ya += Wa[:, s].dot(change)
                    ra[s] = new
            residual, worst = self._residual(ra, ya, q[idx], rows, where)
            if residual <= self.TOLERANCE:
                break
            if sweeps % self.NEWTON_AFTER == 0 and 1 < idx.size <= self.NEWTON_SIZE:
                # Gauss-Seidel crawls where the rows are strongly coupled (a stiff body on many rows at a
                # large step: W nearly singular): Newton's method from where it got to.
                newton += 1
                ra_n = self._newton(Wa, q[idx], ra, rows, where)
                ya_n = Wa.dot(ra_n) + q[idx]
                res_n, worst_n = self._residual(ra_n, ya_n, q[idx], rows, where)
                if res_n < residual:
                    ra, ya, residual, worst = ra_n, ya_n, res_n, worst_n
                    if residual <= self.TOLERANCE:
                        break
        r[idx], y[idx] = ra, Wa.dot(ra) + q[idx]
        return FrictionSolution(r, y, residual, sweeps, residual <= self.TOLERANCE, worst, newton)

    def _newton(self, W: np.ndarray, q: np.ndarray, r: np.ndarray, rows, where, iterations: int = 60) -> np.ndarray:
        """Alart and Curnier's semismooth Newton method on the closed rows (docs/theory.md s. 11).

        ``F(r) = 0`` with, per row (rho = 1 / W_NN), ``F_N = r_N - max(0, r_N - rho y_N)`` and
        ``F_T = r_T - proj_B(r_T - rho y_T)`` on the disk of radius ``mu max(0, r_N - rho y_N)``: the same
        Coulomb law. Each step solves ``J d = -F`` by least squares (W may be singular: many impulses
        give the same velocities) and takes the largest of 1, 1/2, ... that decreases ``|F|``.
        """
        n = r.size

        def evaluate(r, jacobian=True):
            y = W.dot(r) + q
            F = np.empty(n)
            J = np.zeros((n, n)) if jacobian else None
            for i, s in zip(rows, where):
                rho, mu = self.rho[i], self.mu[i]
                k = s.start
                z_n = r[k] - rho * y[k]
                F[k] = r[k] - max(z_n, 0.0)
                if jacobian:
                    J[k, k] = 1.0
                    if z_n > 0.0:
                        J[k] -= -rho * W[k]
                        J[k, k] -= 1.0
                if s.stop - k == 1:
                    continue
                t = slice(k + 1, s.stop)
                z_t = r[t] - rho * y[t]
                radius = mu * max(z_n, 0.0)
                norm = float(np.linalg.norm(z_t))
                if norm <= radius:   # stick: F_T = rho y_T
                    F[t] = rho * y[t]
                    if jacobian:
                        J[t] = rho * W[t]
                elif radius > 0.0:   # slip on the disk's edge
                    u = z_t / norm
                    F[t] = r[t] - radius * u
                    if jacobian:
                        dz_t = -rho * W[t]
                        dz_t[:, t] += np.eye(s.stop - k - 1)
                        dz_n = -rho * W[k]
                        dz_n[k] += 1.0
                        J[t] = -(np.outer(u, mu * dz_n) + radius / norm * (np.eye(u.size) - np.outer(u, u)) @ dz_t)
                        J[t, t] += np.eye(s.stop - k - 1)
                else:                # open: no friction
                    F[t] = r[t]
                    if jacobian:
                        J[t, t] = np.eye(s.stop - k - 1)
            return F, J

        F, J = evaluate(r)
        size = float(F.dot(F))
        for _ in range(iterations):
            if size == 0.0:
                break
            d = np.linalg.lstsq(J, -F, rcond=None)[0]
            step = 1.0
            while step > 1e-6:
                trial = r + step * d
                F_trial, _ = evaluate(trial, jacobian=False)
                if F_trial.dot(F_trial) < size:
                    break
                step *= 0.5
            else:
                break
            r = trial
            F, J = evaluate(r)
            size = float(F.dot(F))
        return r

    def _block(self, idx: np.ndarray) -> np.ndarray:
        """``W[idx][:, idx]``, kept while the closed rows stay the same (a persisting contact copies nothing)."""
        key = idx.tobytes()
        if key != self._block_key:
            self._block_key = key
            self._block_matrix = self.W[np.ix_(idx, idx)]
        return self._block_matrix

    def _residual(self, ra, ya, qa, rows, where) -> tuple[float, int]:
        worst, worst_row, scale = 0.0, -1, float(np.abs(ra).max(initial=0.0))
        for i, s in zip(rows, where):
            scale = max(scale, self.rho[i] * float(np.abs(qa[s]).max()))
            res = row_residual(ra[s], ya[s], self.mu[i], self.rho[i])
            if res > worst:
                worst, worst_row = res, i
        return worst / max(scale, TINY), worst_row
