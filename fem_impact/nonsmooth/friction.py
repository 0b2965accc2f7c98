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
the friction impulse), warm-started from the previous step, compiled (cone.py); every
``NEWTON_AFTER`` sweeps Alart
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

from ..linalg.dense import permuted_in_place


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
    cone = _kernels()
    z_t = np.asarray(z_t, dtype=float)
    out = np.empty_like(z_t)
    return float(cone.project(float(z_n), z_t, float(mu), out)), out


def row_residual(r: np.ndarray, y: np.ndarray, mu: float, rho: float) -> float:
    """``|r - proj_K(r - rho (y + mu |y_T| e_N))|`` for one row (r, y: normal first)."""
    return float(_kernels().row_residual(np.asarray(r, dtype=float), np.asarray(y, dtype=float), float(mu), float(rho)))


def solve_row(W: np.ndarray, q: np.ndarray, mu: float, start: np.ndarray | None = None) -> np.ndarray:
    """Exact solution of one row's problem ``y = W r + q`` (cone.solve_row; ``start``: the row's
    impulse so far, whose direction starts the 3D slip direction's search)."""
    cone = _kernels()
    W, q = np.ascontiguousarray(W, dtype=float), np.ascontiguousarray(q, dtype=float)
    return cone.solve_row(W, q, float(mu), None if start is None else np.ascontiguousarray(start, dtype=float))


def _kernels():
    """The compiled kernels (cone.py): Numba is imported, and the kernels loaded from its cache, only
    where friction is."""
    try:
        from . import cone
    except ImportError as exc:
        from ..errors import SimulationError

        raise SimulationError(f"friction needs Numba, which is missing ({exc}): install Debian's python3-numba "
                              "(`make setup` does)") from None
    return cone


_NONE = np.zeros(0)   # (no warm start, to the compiled small path)


def _small():
    """small_kernel.py (compiled; loaded on the first small solve)."""
    global _SMALL_KERNEL
    if _SMALL_KERNEL is None:
        from . import small_kernel as _SMALL_KERNEL
    return _SMALL_KERNEL


_SMALL_KERNEL = None


EPS = np.finfo(float).eps

# |W_ij - W_ji| above this many times the round-off bound s_i s_j of the two entries: not round-off (a
# backward-stable solve stays below the bound itself).
ASYMMETRY_MARGIN = 100.0


def symmetrize(W: np.ndarray, scale: np.ndarray, rows: int = 512) -> float:
    """``W <- (W + W^T) / 2`` in place, by blocks (no temporary of W's size); returns the largest
    ``|W_ij - W_ji| / (s_i s_j)``, the asymmetry against the round-off bound of the entries (``scale``:
    s, non-negative).

    W = P S^-1 P^T is symmetric, but computed from solves with S (or from S^-1's entries) each
    entry carries round-off of order ``EPS ||S|| |S^-1 p_i| |S^-1 p_j|``, which grows with S's
    conditioning (a large step on a stiff model): W and W^T then differ by that much. The sweeps
    read W's rows as its columns, so they work on the symmetric part, the problem W stands for.
    """
    n = W.shape[0]
    worst = 0.0
    for i in range(0, n, rows):
        for j in range(i, n, rows):
            a, b = W[i:i + rows, j:j + rows], W[j:j + rows, i:i + rows]
            if not (np.isfinite(a).all() and np.isfinite(b).all()):
                return np.nan
            gap = np.abs(a - b.T)
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = np.where(gap > 0.0, gap / np.outer(scale[i:i + rows], scale[j:j + rows]), 0.0)
            worst = max(worst, float(ratio.max(initial=0.0)))
            mean = 0.5 * (a + b.T)
            a[...] = mean
            b[...] = mean.T
    return worst


class FrictionProblem:
    """The frictional contact problem of a step in one Delassus matrix (module docstring).

    ``W``: (p + pt) x (p + pt), normal rows first, then the tangent rows; ``tangent_of[k]`` is the
    normal row of tangent row k; ``mu``: the friction coefficient per normal row.
    """

    TOLERANCE = 1e-10
    MAX_SWEEPS = 2000
    NEWTON_AFTER = 100   # sweeps of Gauss-Seidel before Newton's method takes over (coupled rows)
    # ... and on a small problem, whose dense Newton step costs less than a few sweeps: a block on its floor
    # (a handful of rows coupled through the block) crawls for the 100 sweeps and then needs Newton anyway
    SMALL, NEWTON_AFTER_SMALL = 60, 8
    NEWTON_SIZE = 6000   # unknowns up to which it may (its steps are dense LU solves)
    # From this many unknowns Newton's direction comes from GMRES preconditioned by J's row blocks (no dense
    # J, no LU: _newton_iterative), after this many sweeps
    ITERATIVE_FROM, NEWTON_AFTER_ITERATIVE = 1500, 20
    LEAST_SQUARES_SIZE = 600   # ... and least-squares ones where J is singular
    SINGLE_FROM = 2000   # unknowns from which W is kept as two float32 parts (the sweeps are memory-bound)
    __checkpoint__ = ("_last",)   # the warm start: part of a run's state (fem_impact/app/checkpoint/)
    SINGLE_TARGET = 1e-7  # the first float32 round's (above its round-off floor)

    def __init__(self, W: np.ndarray, tangent_of: np.ndarray, mu: np.ndarray, overwrite: bool = False,
                 roundoff: np.ndarray | None = None, newton_first: bool = True):
        """``roundoff``: s per unknown (W's order), the round-off bound of W's entries ``|dW_ij| <= s_i s_j``
        (``Operators.delassus``); by default that of an entry computed to a few ulps of its size,
        ``sqrt(64 EPS W_ii)``. ``newton_first``: a small problem starts with Newton's method (False: with
        the sweeps, for a W of low rank by construction, a rigid body's rows: Newton's J is singular there
        and stalls short of round-off, where the sweeps settle the rows' velocities)."""
        self.newton_first = newton_first
        _kernels()   # (fails here, and clearly, without Numba)
        self.p, self.mu = mu.size, np.ascontiguousarray(mu, dtype=float)
        self.blocks = [np.array([i] + [self.p + k for k in np.flatnonzero(tangent_of == i)])
                       for i in range(self.p)]
        # Inside, the unknowns are in row order: row i's normal and tangents at start[i] on, so that
        # a Gauss-Seidel sweep streams W's rows once, in order (cone.gauss_seidel). W is kept only so.
        self.order = np.concatenate(self.blocks)
        self.sizes = np.array([b.size for b in self.blocks], dtype=np.int64)
        self.start = np.concatenate([[0], np.cumsum(self.sizes)[:-1]]).astype(np.int64)
        if overwrite and isinstance(W, np.ndarray) and W.dtype == float and W.flags.c_contiguous:
            W = permuted_in_place(W, self.order)   # (the caller's W, no second copy: the largest array)
        else:
            W = np.ascontiguousarray(np.asarray(W, dtype=float)[np.ix_(self.order, self.order)])
        # The sweeps update y along rows of W, which are its columns: W = H S^-1 H^T is symmetric, to
        # the round-off of the solves that made it. Its symmetric part is taken; an asymmetry beyond
        # that round-off is no round-off, but a W that is not what it should be.
        if roundoff is None:
            roundoff = np.sqrt(64.0 * EPS * np.abs(np.diagonal(W)))
        scale = np.ascontiguousarray(np.asarray(roundoff, dtype=float)[self.order])
        self.asymmetry = symmetrize(W, scale)
        if not self.asymmetry <= ASYMMETRY_MARGIN:
            from ..errors import ContactSolverError

            what = "holds values that are not finite" if np.isnan(self.asymmetry) else (
                f"is not symmetric: W_ij and W_ji differ by {self.asymmetry:.3g} times the round-off of the "
                "solves that made them")
            raise ContactSolverError(f"the frictional contact problem's Delassus matrix W = P S^-1 P^T {what} (S, "
                                     "the step matrix, singular or W built wrong): this is a defect, please report it")
        self.rho = 1.0 / W[self.start, self.start]
        if W.shape[0] >= self.SINGLE_FROM:
            # Many rows: W kept as upper + lower, both float32, equal to W to float32's round-off
            # squared (1e-15): the sweeps read the upper part alone (half of W's bytes: the sweeps
            # stream W from memory), y is made exact by the lower part's product (solve), and the
            # two take the memory of W alone.
            self.upper = W.astype(np.float32)
            self.lower = np.empty_like(self.upper)
            for i in range(0, W.shape[0], 512):   # (by rows: no temporary of W's size)
                self.lower[i:i + 512] = W[i:i + 512] - self.upper[i:i + 512]
        else:
            self.upper, self.lower = W, np.zeros((0, 0), dtype=np.float32)
        self._last = None   # (r, W r) of the last solution, in row order: the next warm start's y
        self.closing = None   # the closed rows of the last close_normal (close_again's)
        self._normal_factors = None   # (rows, the solve with their W_NN's factor): _normal_factor
        self.tangent_of = np.asarray(tangent_of, dtype=np.int64)
        self._layout = (None, None)   # (the active rows, the sweeps' blocks of them: cone.blocks_of)
        # small_kernel.solve's data (with W in float64 and Newton first): mu, rho; order, start, sizes
        self._small_numbers = self._small_layout = None
        if newton_first and not self.lower.size:
            self._small_numbers = np.concatenate([self.mu, self.rho])
            self._small_layout = np.concatenate([self.order, self.start, self.sizes]).astype(np.int64)

    def product(self, x: np.ndarray) -> np.ndarray:
        """``W x`` (in row order)."""
        cone = _kernels()
        y = np.zeros(x.size)
        cone.add_product(y, self.upper, x)
        if self.lower.size:
            cone.add_product(y, self.lower, x)
        return y

    def multiply(self, x: np.ndarray) -> np.ndarray:
        """``W x`` with ``x`` and the result in the caller's order (normal rows first, then tangents)."""
        out = np.empty(x.size)
        out[self.order] = self.product(np.ascontiguousarray(np.asarray(x, dtype=float)[self.order]))
        return out

    def dense(self, idx: np.ndarray) -> np.ndarray:
        """``W[idx][:, idx]`` in float64."""
        block = self.upper[np.ix_(idx, idx)].astype(float)
        if self.lower.size:
            block += self.lower[np.ix_(idx, idx)]
        return block

    def solve(self, q: np.ndarray, active: np.ndarray, guess: np.ndarray | None = None,
              guess_product: np.ndarray | None = None) -> FrictionSolution:
        """Solve on the ``active`` normal rows (and their tangent rows); the others carry nothing.
        ``y = W r + q`` on every row (a row that is not active may show where it would go).
        ``guess_product``: ``W guess`` (``multiply(guess)``) where the caller has it, used where the start is the
        guess itself (nothing of it off the active rows): the start's y then costs no product."""
        newton_done = False
        if self._small_numbers is not None:
            # A small problem solved whole in one compiled call (small_kernel.py: in 2D the active-set method,
            # then Newton's method, from the warm start); what it does not finish goes on below, from Newton's
            # best where it has one.
            q, active = np.ascontiguousarray(q, dtype=float), np.asarray(active, dtype=np.bool_)
            guess = None if guess is None else np.ascontiguousarray(guess, dtype=float)
            n = q.size
            if n != self.upper.shape[0] or active.size != self.p or (guess is not None and guess.size != n):
                raise ValueError(f"FrictionProblem.solve: q ({n}), active ({active.size}) and guess "
                                 f"({'none' if guess is None else guess.size}) do not fit W ({self.upper.shape[0]} "
                                 f"unknowns, {self.p} rows)")   # (the kernel reads them unchecked)
            out = _small().solve(self.upper, q, _NONE if guess is None else guess, active, self._small_numbers,
                                 self._small_layout, self.TOLERANCE, self.SMALL)
            outcome = out[2 * n + 2]
            if outcome == 0.0:   # (small_kernel.DONE)
                return FrictionSolution(out[:n], out[n:2 * n], float(out[2 * n]), 0, True, int(out[2 * n + 1]))
            if outcome == 2.0:   # (SHORT)
                guess, newton_done, guess_product = out[:n], True, None   # (a new start: its product unknown)
        cone = _kernels()
        n = q.size
        rows = np.flatnonzero(active).astype(np.int64)
        if not rows.size:
            return FrictionSolution(np.zeros(n), np.array(q, dtype=float), 0.0, 0, True, -1)
        q = np.ascontiguousarray(np.asarray(q, dtype=float)[self.order])
        if not np.array_equal(self._layout[0], rows):
            self._layout = (rows, cone.blocks_of(self.upper, self.lower, rows, self.start, self.sizes))
        layout = self._layout[1]
        idx = layout[1]   # the active rows' unknowns, row after row
        r = np.zeros(n)
        start = None if guess is None else np.asarray(guess, dtype=float)[self.order]
        if start is not None:
            r[idx] = start[idx]
        if not np.count_nonzero(r):
            y = q.copy()
        elif self._last is not None and np.array_equal(r, self._last[0]):
            y = self._last[1] + q   # (the last solution again: its W r is known)
        elif guess_product is not None and np.array_equal(r, start):
            y = np.asarray(guess_product, dtype=float)[self.order] + q   # (multiply's own product: the same bits)
        else:
            y = self.product(r) + q
        split = self.lower.size > 0
        residual, worst, sweeps, newton, exact = np.inf, -1, 0, 0, False

        def sweep(target, most, stall):
            """Sweeps on the upper part; with W split, y made exact after them by the lower part."""
            nonlocal residual, worst, sweeps, exact
            before = r.copy() if split else None
            done, residual, worst = cone.gauss_seidel(self.upper, q, r, y, rows, self.start, self.sizes,
                                                      self.mu, self.rho, target, most, layout, stall, cone.INNER)
            sweeps += done
            exact = split
            if split:
                cone.add_product(y, self.lower, r - before)
                residual, worst = cone.residual(r, y, q, rows, self.start, self.sizes, self.mu, self.rho)

        # With W split (float32 parts), the sweeps converge to a problem perturbed at float32's
        # round-off: a first round to 1e-7, y made exact, a second from there to the tolerance (its
        # changes are small: so is their round-off). The residual is always judged on y = W r + q.
        small = 1 < idx.size <= self.SMALL
        # Many unknowns: Newton's direction by GMRES (no dense J), so it takes over from the sweeps sooner.
        iterative = idx.size >= self.ITERATIVE_FROM
        after = (self.NEWTON_AFTER_SMALL if small else self.NEWTON_AFTER_ITERATIVE if iterative else
                 self.NEWTON_AFTER)
        for target in ((self.SINGLE_TARGET, self.TOLERANCE) if split else ()):
            sweep(target, after, True)
            if residual <= self.TOLERANCE:
                break

        def newton_step() -> bool:
            """Newton's method from r; kept where it lowers the residual. Whether it reached the tolerance."""
            nonlocal residual, worst, exact
            if iterative:
                trial = self._newton_iterative(q, r, rows, idx)
            else:
                trial = np.zeros(n)
                trial[idx] = self._newton(self.dense(idx), q[idx], r[idx], rows, self._where(rows))
            y_n = self.product(trial) + q
            res_n, worst_n = cone.residual(trial, y_n, q, rows, self.start, self.sizes, self.mu, self.rho)
            if res_n < residual:
                r[:], y[:], residual, worst, exact = trial, y_n, res_n, worst_n, True
            return residual <= self.TOLERANCE

        # A small problem (a block's rows on its floor, coupled through the block): Newton's method first,
        # from the warm start (a few dense steps, where the sweeps crawl); the sweeps if it falls short.
        if small and self.newton_first and not split and not newton_done and newton_step():
            sweeps = 0
        while sweeps < self.MAX_SWEEPS and residual > self.TOLERANCE:
            sweep(self.TOLERANCE, min(after, self.MAX_SWEEPS - sweeps), False)
            if residual <= self.TOLERANCE or sweeps >= self.MAX_SWEEPS:
                break
            if 1 < idx.size <= self.NEWTON_SIZE or iterative:
                # Gauss-Seidel crawls where the rows are strongly coupled (a stiff body on many rows at a
                # large step: W nearly singular): Newton's method from where it got to (a retry).
                newton += 1
                if newton_step():
                    break
        if not exact:   # y exactly (the sweeps updated it row by row): the residual the solution is judged by
            y = self.product(r) + q
            residual, worst = cone.residual(r, y, q, rows, self.start, self.sizes, self.mu, self.rho)
        self._last = (r, y - q)
        out_r, out_y = np.empty(n), np.empty(n)
        out_r[self.order], out_y[self.order] = r, y
        return FrictionSolution(out_r, out_y, residual, sweeps, residual <= self.TOLERANCE, worst, newton)

    def close_normal(self, sol: FrictionSolution, q: np.ndarray, active: np.ndarray, passes: int = 4
                     ) -> FrictionSolution:
        """The normal part of a solution brought to round-off: ``y_N = 0`` on its closed rows exactly.

        A solve stops at the tolerance of the natural map (1e-10 of the data): where ``y_N`` is a gap
        (the position level) the gaps would be closed to that, not to round-off. With each row's state
        kept (closed or open, stick or slip, the slip's direction), the normal impulses of the closed
        rows then solve ``W_NN dr_N = -y_N`` (a Cholesky factor of their block, kept while the closed
        rows stay the same: W does not change from step to step), and the slip rows' tangential
        impulses follow them (``|r_T| = mu r_N``, the same direction); their change moves ``y_N`` again
        by a fraction of the change (the rows' normal-tangent coupling times mu), so a few passes reach
        round-off. Rows the tolerance left slightly inside (``r = 0``, ``y_N < 0``) join the closed
        rows, slipping against their tangential velocity. Should a normal impulse turn negative, the
        solution is returned as it was (it is within the tolerance anyway).
        """
        p, mu = self.p, self.mu
        r, y = sol.r.copy(), sol.y.copy()
        owner, tangent = self.tangent_of, p + np.arange(self.tangent_of.size)
        self.closing = None
        rows = None
        for _ in range(passes):
            scale = max(float(np.abs(q[:p][active]).max(initial=0.0)), 1e-300)
            closed = active & ((r[:p] > 0.0) | (y[:p] < 0.0))
            if not np.count_nonzero(closed) or np.abs(y[:p][closed]).max() <= 4.0 * EPS * scale:
                break
            rows = np.flatnonzero(closed)
            new = r[:p].copy()
            new[rows] += self._normal_factor(rows)(-y[rows])
            if np.any(new[rows] < 0.0):
                return sol
            if owner.size:
                r_t, y_t = r[tangent], y[tangent]
                size = np.sqrt(np.bincount(owner, weights=r_t * r_t, minlength=p))[owner]
                speed = np.sqrt(np.bincount(owner, weights=y_t * y_t, minlength=p))[owner]
                old, now, m = r[:p][owner], new[owner], mu[owner]
                joining = closed[owner] & (old == 0.0) & (speed > 0.0)   # (it slips against its velocity)
                slipping = closed[owner] & (old > 0.0) & (size >= (1.0 - 1e-9) * m * old) & (size > 0.0)
                r_t = np.where(joining, -m * now * y_t / np.where(speed > 0.0, speed, 1.0), r_t)
                r_t = np.where(slipping, r_t * (m * now / np.where(size > 0.0, size, 1.0)), r_t)
                r[tangent] = r_t
            r[:p] = new
            y = self.multiply(r) + q
        cone = _kernels()
        rows_all = np.flatnonzero(active).astype(np.int64)
        ro, yo, qo = r[self.order], y[self.order], np.ascontiguousarray(q[self.order])
        residual, worst = cone.residual(ro, yo, qo, rows_all, self.start, self.sizes, self.mu, self.rho)
        if residual > self.TOLERANCE and residual > sol.residual:
            return sol
        if rows is not None and np.array_equal(rows, np.flatnonzero(active & (r[:p] > 0.0))):
            self.closing = rows
        self._last = (ro, yo - qo)
        return FrictionSolution(r, y, residual, sol.sweeps, True, worst, sol.newton)

    def _normal_factor(self, rows: np.ndarray):
        """``x -> W_NN[rows, rows]^-1 x`` (Cholesky; LU where the block is not positive definite to working
        precision), the factor kept while the rows stay the same."""
        from scipy.linalg import LinAlgError, cho_factor, cho_solve, lu_factor, lu_solve

        kept = self._normal_factors
        if kept is not None and np.array_equal(kept[0], rows):
            return kept[1]
        block = self.dense(self.start[rows])
        try:
            factor = cho_factor(block, check_finite=False)
            solve = (lambda x: cho_solve(factor, x, check_finite=False))
        except LinAlgError:
            factor = lu_factor(block, check_finite=False)
            solve = (lambda x: lu_solve(factor, x, check_finite=False))
        self._normal_factors = (rows, solve)
        return solve

    def close_again(self, y_n: np.ndarray) -> np.ndarray | None:
        """The normal impulses' change that brings the closed rows of the last ``close_normal`` to ``y_N =
        0`` from ``y_n`` (p, measured on the structure itself, whose operator W stands for to round-off),
        with the factor of their block; None without one."""
        if getattr(self, "closing", None) is None:
            return None
        rows = self.closing
        change = np.zeros(self.p)
        change[rows] = self._normal_factor(rows)(-y_n[rows])
        return change

    def _row_blocks(self) -> np.ndarray:
        """W's diagonal block of each row (rows x 3 x 3, a row of m unknowns in its leading m x m), float64."""
        if getattr(self, "_blocks_of_rows", None) is None:
            at = self.start[:, None] + np.arange(3)
            inside = np.arange(3) < self.sizes[:, None]
            at = np.where(inside, at, self.start[:, None])
            pick = (at[:, :, None], at[:, None, :])
            blocks = self.upper[pick].astype(float)
            if self.lower.size:
                blocks += self.lower[pick]
            self._blocks_of_rows = blocks * (inside[:, :, None] & inside[:, None, :])
        return self._blocks_of_rows

    def _newton_iterative(self, q: np.ndarray, r: np.ndarray, rows: np.ndarray, idx: np.ndarray,
                          iterations: int = 30) -> np.ndarray:
        """Alart and Curnier's Newton method (``_newton``) on many unknowns without a dense Jacobian: per row
        ``J = (I - Q) + rho Q W`` (cone.alart_curnier_blocks), its direction by GMRES on products with W (its
        float32 part where W is split: a direction need not be exact), preconditioned by the inverse of J's
        row blocks ``(I - Q) + rho Q W_ii``; the tolerance of each solve follows |F| (a loose direction far
        from the solution, a tight one near it), the step the largest of 1, 1/2, ... that lowers |F|.
        ``q``, ``r``: every unknown, in row order; returns the new r (those of other rows zero)."""
        from scipy.sparse.linalg import LinearOperator

        from ..linalg.scipy_api import gmres

        cone = _kernels()
        n = r.size
        starts, sizes = self.start[rows], self.sizes[rows]
        rho, mu = self.rho[rows], self.mu[rows]
        at = starts[:, None] + np.arange(3)
        inside = np.arange(3) < sizes[:, None]
        at = np.where(inside, at, starts[:, None])
        D = self._row_blocks()[rows]
        pad = np.where(inside, 0.0, 1.0)[:, :, None] * np.eye(3)   # (identity on a short row's padding)

        def rows_of(x):   # a vector of every unknown as rows x 3 (zero in the padding)
            return np.where(inside, x[at], 0.0)

        def to_vector(blocks, out):
            out[at[inside]] = blocks[inside]
            return out

        def product(x, exact):
            y = np.zeros(n)
            cone.add_product(y, self.upper, x)
            if exact and self.lower.size:
                cone.add_product(y, self.lower, x)
            return y

        def evaluate(x):
            y = product(x, True) + q
            F, Q = cone.alart_curnier_blocks(y, x, starts, sizes, rho, mu)
            return F[idx], Q

        r = np.where(np.isin(np.arange(n), idx), r, 0.0)
        F, Q = evaluate(r)
        size = float(F.dot(F))
        scale = max(float(np.abs(r).max(initial=0.0)), float(np.abs(np.repeat(rho, sizes) * q[idx]).max(initial=0.0)),
                    1e-300)
        whole = np.zeros(n)
        for _ in range(iterations):
            if size == 0.0 or np.abs(F).max() <= 1e-3 * self.TOLERANCE * scale:
                break
            A, B = np.eye(3) - Q, rho[:, None, None] * Q
            E_inv = np.linalg.inv(A + B @ D + pad)

            def jacobian(v, A=A, B=B):
                whole[idx] = v
                Wv = product(whole, False)
                out = np.einsum("bij,bj->bi", A, rows_of(whole)) + np.einsum("bij,bj->bi", B, rows_of(Wv))
                return to_vector(out, np.zeros(n))[idx]

            def preconditioner(v, E_inv=E_inv):
                whole[idx] = v
                return to_vector(np.einsum("bij,bj->bi", E_inv, rows_of(whole)), np.zeros(n))[idx]

            J = LinearOperator((idx.size, idx.size), matvec=jacobian)
            M = LinearOperator((idx.size, idx.size), matvec=preconditioner)
            forcing = min(1e-2, max(float(np.abs(F).max()) / scale, 1e-12))
            d = gmres(J, -F, forcing, M=M, restart=min(200, idx.size), maxiter=10, atol=0.0)[0]
            step = 1.0
            while step >= 1e-6:
                trial = r.copy()
                trial[idx] += step * d
                F_trial, Q_trial = evaluate(trial)
                if F_trial.dot(F_trial) < size:
                    break
                step *= 0.5
            else:
                break
            r, F, Q, size = trial, F_trial, Q_trial, float(F_trial.dot(F_trial))
        return r

    @staticmethod
    def _newton_direction(J: np.ndarray, F: np.ndarray) -> np.ndarray:
        """``J d = -F`` by LU; by least squares where J is singular to working precision (W may be:
        many impulses give the same velocities) and small enough for it."""
        from scipy.linalg.lapack import dgetrf, dgetrs

        lu, piv, info = dgetrf(J)   # (LAPACK itself: info > 0 where U has an exact zero on its diagonal)
        if info == 0:
            d, info = dgetrs(lu, piv, -F)
            if info == 0 and np.isfinite(d).all():
                return d
        if F.size > FrictionProblem.LEAST_SQUARES_SIZE:
            return np.zeros_like(F)
        return np.linalg.lstsq(J, -F, rcond=None)[0]

    def _where(self, rows: np.ndarray) -> list[slice]:
        """Each row's unknowns as a slice of the active unknowns (its normal, then its tangents)."""
        where, start = [], 0
        for i in rows:
            where.append(slice(start, start + self.blocks[i].size))
            start += self.blocks[i].size
        return where

    def _newton(self, W: np.ndarray, q: np.ndarray, r: np.ndarray, rows, where, iterations: int = 60) -> np.ndarray:
        """Alart and Curnier's semismooth Newton method on the closed rows (docs/theory.md s. 11).

        ``F(r) = 0`` with, per row (rho = 1 / W_NN), ``F_N = r_N - max(0, r_N - rho y_N)`` and
        ``F_T = r_T - proj_B(r_T - rho y_T)`` on the disk of radius ``mu max(0, r_N - rho y_N)``: the same
        Coulomb law. Each step solves ``J d = -F`` by least squares (W may be singular: many impulses
        give the same velocities) and takes the largest of 1, 1/2, ... that decreases ``|F|``.
        """
        cone = _kernels()
        W = np.ascontiguousarray(W, dtype=float)
        starts = np.array([s.start for s in where], dtype=np.int64)
        sizes = np.array([s.stop - s.start for s in where], dtype=np.int64)
        rho, mu = np.asarray(self.rho[rows], dtype=float), np.asarray(self.mu[rows], dtype=float)

        q = np.ascontiguousarray(q, dtype=float)

        def evaluate(r, jacobian=True):
            return cone.alart_curnier(W, q, np.ascontiguousarray(r, dtype=float), starts, sizes, rho, mu, jacobian)

        # Once |F| is far below what the caller's residual accepts (F is that residual's per-row numerator:
        # the tolerance times the data's size), only full steps are tried, down to round-off: no line
        # search halving twenty times in round-off at the end.
        near = 1e-3 * self.TOLERANCE * max(float(np.abs(r).max(initial=0.0)),
                                           float(np.abs(np.repeat(rho, sizes) * q).max(initial=0.0)), 1e-300)
        trial_jacobian = r.size <= 4 * self.SMALL   # (a trial's Jacobian, kept when the step is taken: small J only)
        F, J = evaluate(r)
        size = float(F.dot(F))
        for _ in range(iterations):
            if size == 0.0 or np.abs(F).max() <= 1e-3 * near:   # (round-off: 1e-16 of the data's size)
                break
            d = self._newton_direction(J, F)
            step = 1.0
            shortest = 1.0 if np.abs(F).max() <= near else 1e-6
            while step >= shortest:
                trial = r + step * d
                F_trial, J_trial = evaluate(trial, jacobian=trial_jacobian)
                if F_trial.dot(F_trial) < size:
                    break
                step *= 0.5
            else:
                break
            r = trial
            F, J = (F_trial, J_trial) if trial_jacobian else evaluate(r)
            size = float(F.dot(F))
        return r
