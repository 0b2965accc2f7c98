"""A small frictional contact problem solved whole in one compiled call (friction.py's small path).

On a few closed rows (a block on its floor, at most ``FrictionProblem.SMALL`` unknowns) the
arithmetic of a solve is far less than the Python around compiled pieces (the layout, the dense
block, Newton's loop and its line search) that it took (docs/performance.md has the figures).
Here the whole of ``FrictionProblem.solve``'s small path runs in one call:
the closed rows' unknowns gathered, Alart and Curnier's Newton method on their dense block
(``cone.alart_curnier``; each direction by an LU factorization with partial pivoting, the step
the largest of 1, 1/2, ... that lowers |F|, only full steps once |F| is far below the tolerance:
friction.py's ``_newton``), then ``y = W r + q`` on every row and the certified residual
(``cone.residual``). What it cannot finish (a Jacobian with an exact zero pivot, a residual
above the tolerance, more unknowns than it takes) it hands back, and the general path goes on.

In 2D (every row a normal and at most one tangent) the cone is a pair of half-planes, the problem piecewise
linear: Newton's method with full steps is then an active-set method (``_active_set``). Each row's status
(open, sticking, slipping either way) is read from the natural map at the iterate, as Newton's Jacobian reads
it; the linear system of those statuses is solved on its own unknowns only (a slipping row's tangential
impulse is ``+-mu`` times its normal one: one unknown; an open row's none), and the statuses are read again.
Where they no longer change and the residual is below the tolerance, that is the solution, often after a
few small eliminations where Newton's damped steps on every unknown took more. Where the statuses cycle
or a system is singular, the damped Newton method above starts over from the caller's guess.
"""

from __future__ import annotations

import numpy as np

from ..compiled import njit
from .cone import alart_curnier_into, residual

DONE, SINGULAR, SHORT, TOO_MANY = 0, 1, 2, 3   # the outcome: solved; J singular; above the tolerance; not small
ITERATIONS = 60   # Newton's steps at most (friction.py's _newton)
# The active-set method's: a row's status, and its steps at most (beyond them the statuses cycle: damped Newton)
OPEN, STICK, SLIP_UP, SLIP_DOWN = 0, 1, 2, 3   # (SLIP_UP: r_T = +mu r_N, the row sliding towards -T)
ACTIVE_STEPS = 12


@njit(cache=True, error_model="numpy")
def _lu_solve(A, b):
    """``A x = b`` by Gaussian elimination with partial pivoting, A and b overwritten (x in b); False where a
    pivot is exactly zero (LAPACK's dgetrf reports the same)."""
    n = b.size
    for k in range(n):
        p, big = k, abs(A[k, k])
        for i in range(k + 1, n):
            if abs(A[i, k]) > big:
                p, big = i, abs(A[i, k])
        if big == 0.0:
            return False
        if p != k:
            for j in range(n):
                A[k, j], A[p, j] = A[p, j], A[k, j]
            b[k], b[p] = b[p], b[k]
        pivot = A[k, k]
        for i in range(k + 1, n):
            f = A[i, k] / pivot
            if f != 0.0:
                for j in range(k + 1, n):
                    A[i, j] -= f * A[k, j]
                b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, n):
            s -= A[k, j] * b[j]
        b[k] = s / A[k, k]
    return True


@njit(cache=True, error_model="numpy")
def _velocities(W, q, r, y):
    """``y = W r + q`` by loops (a small W: Numba's @ calls out), each entry summed from q[i] on."""
    n = r.size
    for i in range(n):
        s = q[i]
        for j in range(n):
            s += W[i, j] * r[j]
        y[i] = s


@njit(cache=True, error_model="numpy")
def _evaluate(W, q, r, starts, sizes, rho, mu, y, F, J, scratch):
    """Alart and Curnier's F and J at r into the buffers (y = W r + q by loops: a small W); returns |F|^2."""
    n = r.size
    _velocities(W, q, r, y)
    for i in range(n):
        for j in range(n):
            J[i, j] = 0.0
    alart_curnier_into(W, y, r, starts, sizes, rho, mu, F, J, True, scratch)
    size = 0.0   # (|F|^2 and below max |F| by loops: Numba's @ and np.abs(F).max() call out or allocate)
    for i in range(n):
        size += F[i] * F[i]
    return size


@njit(cache=True, error_model="numpy")
def _newton(W, q, r, starts, sizes, rho, mu, tolerance, work):
    """friction.py's ``_newton`` on the dense block ``W`` (m x m) of the closed rows, from ``r``: returns
    (r, whether every direction was found). Its arrays are cut from ``work`` (5 m + 2 m^2 + 6): no
    allocation."""
    n = r.size
    scale = 1e-300
    for j in range(n):
        scale = max(scale, abs(r[j]))
    for b in range(starts.size):
        for j in range(starts[b], starts[b] + sizes[b]):
            scale = max(scale, rho[b] * abs(q[j]))
    near = 1e-3 * tolerance * scale
    y, F, F_trial, trial, d = work[:n], work[n:2 * n], work[2 * n:3 * n], work[3 * n:4 * n], work[4 * n:5 * n]
    J = work[5 * n:5 * n + n * n].reshape((n, n))
    J_trial = work[5 * n + n * n:5 * n + 2 * n * n].reshape((n, n))
    scratch = work[5 * n + 2 * n * n:5 * n + 2 * n * n + 6].reshape((3, 2))
    size = _evaluate(W, q, r, starts, sizes, rho, mu, y, F, J, scratch)
    for _ in range(ITERATIONS):
        largest = 0.0
        for j in range(n):
            largest = max(largest, abs(F[j]))
        if size == 0.0 or largest <= 1e-3 * near:   # round-off: 1e-16 of the data's size
            break
        for j in range(n):
            d[j] = -F[j]
        if not _lu_solve(J, d):
            return r, False
        step, shortest = 1.0, (1.0 if largest <= near else 1e-6)
        improved = False
        while step >= shortest:
            for j in range(n):
                trial[j] = r[j] + step * d[j]
            size_trial = _evaluate(W, q, trial, starts, sizes, rho, mu, y, F_trial, J_trial, scratch)
            if size_trial < size:
                improved = True
                break
            step *= 0.5
        if not improved:
            break
        r, trial = trial, r
        F, F_trial = F_trial, F
        J, J_trial = J_trial, J
        size = size_trial
    return r, True


@njit(cache=True, error_model="numpy")
def _statuses(r, y, starts, sizes, rho, mu, status):
    """Each row's status at (r, y) by the natural map's regions (Alart and Curnier's, as ``_evaluate`` reads
    them); returns how many changed."""
    changed = 0
    for b in range(starts.size):
        k = starts[b]
        z_n = r[k] - rho[b] * y[k]
        if z_n <= 0.0:
            new = OPEN
        elif sizes[b] == 1:
            new = STICK
        else:
            z_t = r[k + 1] - rho[b] * y[k + 1]
            new = STICK if abs(z_t) <= mu[b] * z_n else (SLIP_UP if z_t > 0.0 else SLIP_DOWN)
        changed += new != status[b]
        status[b] = new
    return changed


@njit(cache=True, error_model="numpy")
def _unknowns(status, size):
    """A row's unknowns (and equations) under its status: none open, two sticking in 2D, else its normal."""
    return 0 if status == OPEN else 2 if status == STICK and size == 2 else 1


@njit(cache=True, error_model="numpy")
def _active_set(W, q, r, starts, sizes, rho, mu, work, ints):
    """The 2D problem (every row of at most two unknowns) by the active-set method (module docstring), from
    ``r``, overwritten: True where the statuses settle (the caller's residual then certifies ``r``).
    ``work``: 2 m + m^2 floats, ``ints``: 2 x rows (no allocation)."""
    n, count = r.size, starts.size
    y, x = work[:n], work[n:2 * n]
    status, column = ints[:count], ints[count:2 * count]
    for b in range(count):
        status[b] = -1
    _velocities(W, q, r, y)
    _statuses(r, y, starts, sizes, rho, mu, status)
    for _ in range(ACTIVE_STEPS):
        k = 0   # the unknowns of these statuses: a closed row's normal, a sticking 2D row's tangent
        for b in range(count):
            column[b] = k
            k += _unknowns(status[b], sizes[b])
        A = work[2 * n:2 * n + k * k].reshape((k, k))
        for b in range(count):   # the equations: y_N = 0 on a closed row, y_T = 0 on a sticking one
            for t in range(_unknowns(status[b], sizes[b])):
                e, row = column[b] + t, starts[b] + t
                x[e] = -q[row]
                for c in range(count):
                    if status[c] == OPEN:
                        continue
                    a, kc = column[c], starts[c]
                    A[e, a] = W[row, kc]
                    if status[c] == STICK and sizes[c] == 2:
                        A[e, a + 1] = W[row, kc + 1]
                    elif status[c] == SLIP_UP:
                        A[e, a] += mu[c] * W[row, kc + 1]
                    elif status[c] == SLIP_DOWN:
                        A[e, a] -= mu[c] * W[row, kc + 1]
        if not _lu_solve(A, x[:k]):
            return False
        for b in range(count):
            kb, a = starts[b], column[b]
            r[kb] = 0.0 if status[b] == OPEN else x[a]
            if sizes[b] == 2:
                r[kb + 1] = (0.0 if status[b] == OPEN else x[a + 1] if status[b] == STICK else
                             mu[b] * x[a] if status[b] == SLIP_UP else -mu[b] * x[a])
        _velocities(W, q, r, y)
        if _statuses(r, y, starts, sizes, rho, mu, status) == 0:
            return True
    return False


@njit(cache=True, error_model="numpy")
def solve(W, q, guess, active, numbers, layout, tolerance, small):
    """The small path of ``FrictionProblem.solve`` whole. ``W``: every unknown in row order (n x n, float64);
    ``q``, ``guess`` (empty: none): the caller's order, normal rows first, then the tangent rows; ``active``:
    the closed rows (p); ``numbers``: mu, then rho (p each); ``layout``: ``order`` (the caller's index of
    unknown j, n), then each row's first unknown and number of unknowns (p each). Returns one array: r and
    y in the caller's order (n each), the residual, the worst row and the outcome (DONE ...); r and y are
    meaningful with DONE, and after SHORT (Newton's best, y exact)."""
    n, p = q.size, active.size
    mu, rho = numbers[:p], numbers[p:2 * p]
    order, start, sizes = layout[:n], layout[n:n + p], layout[n + p:n + 2 * p]
    out = np.zeros(2 * n + 3)
    count, m = 0, 0
    for i in range(p):
        if active[i]:
            count += 1
            m += sizes[i]
    if count == 0:
        out[n:2 * n] = q
        out[2 * n + 1] = -1.0
        return out
    if m > small:
        out[2 * n + 2] = TOO_MANY
        return out
    ints = np.empty(5 * count + m, dtype=np.int64)
    rows, starts, block_sizes, idx = ints[:count], ints[count:2 * count], ints[2 * count:3 * count], ints[3 * count:]
    work = np.empty(2 * count + 3 * m * m + 3 * n + 8 * m + 6)
    rho_b, mu_b, W_b = work[:count], work[count:2 * count], work[2 * count:2 * count + m * m].reshape((m, m))
    at = 2 * count + m * m
    q_row, r_row, y_row, r_b = work[at:at + n], work[at + n:at + 2 * n], work[at + 2 * n:at + 3 * n], \
        work[at + 3 * n:at + 3 * n + m]
    newton_work = work[at + 3 * n + m:]
    b, a = 0, 0
    for i in range(p):
        if active[i]:
            rows[b], starts[b], block_sizes[b], rho_b[b], mu_b[b] = i, a, sizes[i], rho[i], mu[i]
            for j in range(start[i], start[i] + sizes[i]):
                idx[a] = j
                a += 1
            b += 1
    for j in range(n):
        q_row[j] = q[order[j]]
    for a in range(m):
        r_b[a] = guess[order[idx[a]]] if guess.size else 0.0
        for c in range(m):
            W_b[a, c] = W[idx[a], idx[c]]
    q_b = newton_work[:m]   # (the closed rows' q: in the part of the work Newton leaves alone)
    newton_work = newton_work[m:]
    for a in range(m):
        q_b[a] = q_row[idx[a]]
    planar = True
    for b in range(count):
        planar = planar and block_sizes[b] <= 2
    if planar:   # (2D: the active-set method first, on a copy of the guess: Newton's start where it fails)
        r_a = newton_work[:m]
        r_a[:] = r_b
        if _active_set(W_b, q_b, r_a, starts, block_sizes, rho_b, mu_b, newton_work[m:], ints[3 * count + m:]):
            if _finish(W, q_row, r_a, idx, order, rows, start, sizes, mu, rho, r_row, y_row, out) <= tolerance:
                out[2 * n + 2] = DONE
                return out
    r_b, found = _newton(W_b, q_b, r_b, starts, block_sizes, rho_b, mu_b, tolerance, newton_work[m:])
    if not found:
        out[:] = 0.0
        out[2 * n + 2] = SINGULAR
        return out
    res = _finish(W, q_row, r_b, idx, order, rows, start, sizes, mu, rho, r_row, y_row, out)
    out[2 * n + 2] = DONE if res <= tolerance else SHORT
    return out


@njit(cache=True, error_model="numpy")
def _finish(W, q_row, r_b, idx, order, rows, start, sizes, mu, rho, r_row, y_row, out):
    """The closed rows' ``r_b`` spread to every row, ``y = W r + q`` on every row (an open row shows where it
    would go), both in the caller's order into ``out`` with the residual and the worst row; returns the
    residual."""
    n = q_row.size
    r_row[:] = 0.0
    y_row[:] = q_row
    for a in range(r_b.size):
        c = idx[a]
        r_row[c] = r_b[a]
        if r_b[a] != 0.0:
            for j in range(n):   # (W symmetric: its row c, read in order)
                y_row[j] += W[c, j] * r_b[a]
    res, worst = residual(r_row, y_row, q_row, rows, start, sizes, mu, rho)
    for j in range(n):
        out[order[j]], out[n + order[j]] = r_row[j], y_row[j]
    out[2 * n], out[2 * n + 1] = res, worst
    return res
