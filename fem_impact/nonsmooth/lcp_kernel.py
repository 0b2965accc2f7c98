"""The exact LCP of ``Delassus.solve`` (lcp.py) compiled for small symmetric positive definite matrices,
for steps taken in compiled blocks (fem_impact/integrators/kernels.py, blocks.py).

Block principal pivoting with the rules, tolerances and retries of ``Delassus.solve``; the active
block by its Cholesky factor, kept between calls while the active set stays (a persisting contact:
two triangular solves a call). Where ``Delassus.solve`` would go on to its other factors (LU,
least squares: a matrix not positive definite) or to its convex fallback (pivoting that does not
end), ``solve`` returns False and the caller takes that step in Python.
"""

from __future__ import annotations

import numpy as np

from ..compiled import njit

TINY = np.finfo(float).tiny
RETRIES = 3   # as Delassus.RETRIES


@njit(cache=True)
def _factor(A, active, rows, L) -> int:
    """The Cholesky factor of ``A[rows][:, rows]`` (``rows``: the active indices, in order) into L's
    leading block; returns the block's size, or -1 when it is not positive definite."""
    k = 0
    for i in range(active.size):
        if active[i]:
            rows[k] = i
            k += 1
    for a in range(k):
        for b in range(a + 1):
            s = A[rows[a], rows[b]]
            for c in range(b):
                s -= L[a, c] * L[b, c]
            if a == b:
                if not s > 0.0:
                    return -1
                L[a, a] = np.sqrt(s)
            else:
                L[a, b] = s / L[b, b]
    return k


@njit(cache=True)
def _solve_factored(L, rows, k, q, x, y) -> None:
    """``x[rows] = -A[rows][:, rows]^-1 q[rows]`` through its factor; x is zero elsewhere."""
    x[:] = 0.0
    for a in range(k):
        s = -q[rows[a]]
        for c in range(a):
            s -= L[a, c] * y[c]
        y[a] = s / L[a, a]
    for a in range(k - 1, -1, -1):
        s = y[a]
        for c in range(a + 1, k):
            s -= L[c, a] * y[c]
        y[a] = s / L[a, a]
        x[rows[a]] = y[a]


@njit(cache=True)
def solve(A, q, active, factored, L, rows, x, w, y) -> bool:
    """``w = A x + q >= 0, x >= 0, x . w = 0`` from the active set ``active`` (in: the guess, out: the
    solution's). ``factored`` (in/out) is the active set whose factor L and ``rows`` hold (its
    first entry -1 when none: a bool array cannot say so, the caller keeps an int8 array). Returns
    False where ``Delassus.solve`` would leave pivoting (the caller then solves the step itself)."""
    n = q.size
    if n == 1:
        x[0] = -q[0] / A[0, 0] if q[0] < 0.0 else 0.0
        active[0] = x[0] > 0.0
        w[0] = 0.0 if active[0] else q[0]
        return True
    qmax = 0.0
    anyact = False
    for i in range(n):
        qmax = max(qmax, abs(q[i]))
        anyact = anyact or active[i]
    if not anyact:
        neg = False
        for i in range(n):
            neg = neg or q[i] < 0.0
        if not neg:
            x[:] = 0.0
            w[:] = q
            return True
    tol = 1e-13 * max(qmax, TINY)
    best, retries = n + 1, RETRIES
    for _ in range(4 * n + 10):
        same = factored[0] >= 0
        if same:
            for i in range(n):
                if (factored[i] == 1) != active[i]:
                    same = False
                    break
        if not same:
            k = _factor(A, active, rows, L)
            if k < 0:
                factored[0] = -1
                return False
            for i in range(n):
                factored[i] = 1 if active[i] else 0
        k = 0
        for i in range(n):
            if active[i]:
                k += 1
        _solve_factored(L, rows, k, q, x, y)
        xmax = 0.0
        for i in range(n):
            xmax = max(xmax, abs(x[i]))
        xtol = 1e-13 * max(xmax, TINY)
        count = 0
        first = -1
        for i in range(n):
            if active[i]:
                w[i] = 0.0
                wrong = x[i] < -xtol
            else:
                s = q[i]
                for c in range(k):
                    s += A[i, rows[c]] * x[rows[c]]
                w[i] = s
                wrong = s < -tol
            if wrong:
                count += 1
                if first < 0:
                    first = i
                y[n + i] = 1.0   # (the wrong indices, kept past the solve's scratch)
            else:
                y[n + i] = 0.0
        if not count:
            for i in range(n):
                x[i] = max(x[i], 0.0)
                w[i] = max(w[i], 0.0)
            return True
        if count < best or retries > 0:
            if count < best:
                best, retries = count, RETRIES
            else:
                retries -= 1
            for i in range(n):
                if y[n + i] != 0.0:
                    active[i] = not active[i]
        else:   # Murty's least-index step
            active[first] = not active[first]
    return False

