"""Compiled kernels of the frictional contact problem (friction.py): one row's cone projection,
natural-map residual and exact solution, the block Gauss-Seidel sweeps over the rows, and the
products with the symmetric W (in float64, or float32 with its lower part) that make y exact.

A row's unknowns are its normal impulse first, then its 0, 1 (2D) or 2 (3D) tangential ones.
Compiled with Numba (Debian's python3-numba, cached beside this file after the first run): the
sweep is a loop over the rows with a small nonlinear solve in each, which in Python would cost
many times the frictionless step.
"""

from __future__ import annotations

import numpy as np

from ..compiled import njit

ROW = 3   # at most a normal and two tangents
BLOCK = 64   # rows of a block of the sweeps (192 unknowns in 3D: their part of W stays in cache)
INNER = 2    # sweeps within a block per sweep (fewer sweeps in all on coupled rows)


@njit(cache=True)
def project(z_n, z_t, mu, out_t):
    """The Euclidean projection of ``(z_n, z_t)`` on the cone ``|r_T| <= mu r_N``: returns its
    normal part and writes its tangential part into ``out_t``. With mu = 0 the cone is the half
    line ``r_T = 0, r_N >= 0``."""
    norm_t = 0.0
    for a in range(z_t.size):
        norm_t += z_t[a] * z_t[a]
    norm_t = np.sqrt(norm_t)
    if mu == 0.0:
        out_t[:] = 0.0
        return max(z_n, 0.0)
    if norm_t <= mu * z_n:
        out_t[:] = z_t
        return z_n
    if mu * norm_t <= -z_n:
        out_t[:] = 0.0
        return 0.0
    r_n = (z_n + mu * norm_t) / (1.0 + mu * mu)
    for a in range(z_t.size):
        out_t[a] = mu * r_n / norm_t * z_t[a]
    return r_n


@njit(cache=True)
def row_residual(r, y, mu, rho):
    """``|r - proj_K(r - rho (y + mu |y_T| e_N))|`` for one row (normal first)."""
    k = r.size
    return _row_residual_at(r, y, 0, k, mu, rho, np.empty(max(k - 1, 0)), np.empty(max(k - 1, 0)))


@njit(cache=True)
def _row_residual_at(r, y, s, k, mu, rho, z_t, p_t):
    """``row_residual`` of the row whose k unknowns are at s on, with scratch ``z_t``, ``p_t`` (k - 1 each; any
    size where k <= 2)."""
    norm_yt = 0.0
    for a in range(1, k):
        norm_yt += y[s + a] * y[s + a]
    if k == 1:   # (a row without friction: the half line)
        p_n = max(r[s] - rho * y[s], 0.0)
        return abs(r[s] - p_n)
    if k == 2:   # (a 2D row, in scalars: project's arrays cost more than its arithmetic here)
        z_n, z_1 = r[s] - rho * (y[s] + mu * abs(y[s + 1])), r[s + 1] - rho * y[s + 1]
        if mu == 0.0:
            p_n, p_1 = max(z_n, 0.0), 0.0
        elif abs(z_1) <= mu * z_n:
            p_n, p_1 = z_n, z_1
        elif mu * abs(z_1) <= -z_n:
            p_n, p_1 = 0.0, 0.0
        else:
            p_n = (z_n + mu * abs(z_1)) / (1.0 + mu * mu)
            p_1 = mu * p_n * (1.0 if z_1 > 0.0 else -1.0)
        return np.sqrt((r[s] - p_n) ** 2 + (r[s + 1] - p_1) ** 2)
    for a in range(k - 1):
        z_t[a] = r[s + 1 + a] - rho * y[s + 1 + a]
    p_n = project(r[s] - rho * (y[s] + mu * np.sqrt(norm_yt)), z_t, mu, p_t)
    out = (r[s] - p_n) ** 2
    for a in range(k - 1):
        out += (r[s + 1 + a] - p_t[a]) ** 2
    return np.sqrt(out)


@njit(cache=True)
def _slip(W, q, mu, tau0, tau1, out):
    """The slip law along the unit direction ``tau = (tau0, tau1)`` of the tangential velocity (2D:
    tau0 alone): the normal impulse closing the row, ``r_T = -mu r_N tau``. Writes the row into
    ``out``; returns the tangential velocity's component along tau (negative or NaN: not a candidate).
    (The direction in scalars: the sweeps call this for every slipping row, without allocation.)"""
    k = q.size - 1
    denominator = W[0, 0] - mu * W[0, 1] * tau0
    if k == 2:
        denominator -= mu * W[0, 2] * tau1
    if denominator <= 0.0:
        return np.nan
    r_n = -q[0] / denominator
    if r_n < 0.0:
        return np.nan
    out[0] = r_n
    out[1] = -mu * r_n * tau0
    if k == 2:
        out[2] = -mu * r_n * tau1
    along = 0.0
    for a in range(k):
        y_t = q[1 + a]
        for b in range(k + 1):
            y_t += W[1 + a, b] * out[b]
        along += y_t * (tau0 if a == 0 else tau1)
    return along


@njit(cache=True)
def _directions(W, q, mu):
    """Unit directions tau (3D) where the slip law's tangential velocity is parallel to tau:
    ``y_T(tau) x tau = 0`` times ``(W_NN - mu W_NT . tau)`` is a trigonometric polynomial of
    degree 2 in the angle phi, a quartic in t = tan(phi / 2); its real roots, and phi = pi."""
    a, b0, b1 = W[0, 0], W[0, 1], W[0, 2]
    c0, c1, q_n, q1, q2 = W[1, 0], W[2, 0], q[0], q[1], q[2]
    d00, d01, d11 = W[1, 1], W[1, 2], W[2, 2]
    A1 = a * q2 - q_n * c1
    A2 = -a * q1 + q_n * c0
    A3 = mu * (q_n * d01 - b0 * q2)
    A4 = mu * (b1 * q1 - q_n * d01)
    A5 = mu * (b0 * q1 - b1 * q2 + q_n * (d11 - d00))
    coefficients = np.array([A3 - A1, 2.0 * (A2 - A5), 4.0 * A4 - 2.0 * A3, 2.0 * (A2 + A5), A1 + A3])
    start = 0
    while start < 5 and coefficients[start] == 0.0:   # (a lower degree: np.roots needs a leading term)
        start += 1
    phis = [np.pi]
    if start < 4:
        roots = np.roots(coefficients[start:].astype(np.complex128))
        for t in roots:
            if abs(t.imag) <= 1e-9 * max(1.0, abs(t)):
                phis.append(2.0 * np.arctan(t.real))
    out = np.empty((len(phis), 2))
    for i in range(len(phis)):
        out[i, 0], out[i, 1] = np.cos(phis[i]), np.sin(phis[i])
    return out


@njit(cache=True)
def _solve_small_into(W, q, x):
    """``W^-1 q`` into ``x`` for a 2 x 2 or 3 x 3 W (explicitly: no LAPACK call and no allocation in the
    sweeps); NaN where W is singular (no stick candidate: the row's other candidates decide)."""
    if q.size == 2:
        det = W[0, 0] * W[1, 1] - W[0, 1] * W[1, 0]
        if det == 0.0:
            x[:] = np.nan
            return
        x[0] = (W[1, 1] * q[0] - W[0, 1] * q[1]) / det
        x[1] = (W[0, 0] * q[1] - W[1, 0] * q[0]) / det
        return
    c00 = W[1, 1] * W[2, 2] - W[1, 2] * W[2, 1]
    c01 = W[1, 2] * W[2, 0] - W[1, 0] * W[2, 2]
    c02 = W[1, 0] * W[2, 1] - W[1, 1] * W[2, 0]
    det = W[0, 0] * c00 + W[0, 1] * c01 + W[0, 2] * c02
    if det == 0.0:
        x[:] = np.nan
        return
    x[0] = (c00 * q[0] + (W[0, 2] * W[2, 1] - W[0, 1] * W[2, 2]) * q[1]
            + (W[0, 1] * W[1, 2] - W[0, 2] * W[1, 1]) * q[2]) / det
    x[1] = (c01 * q[0] + (W[0, 0] * W[2, 2] - W[0, 2] * W[2, 0]) * q[1]
            + (W[0, 2] * W[1, 0] - W[0, 0] * W[1, 2]) * q[2]) / det
    x[2] = (c02 * q[0] + (W[0, 1] * W[2, 0] - W[0, 0] * W[2, 1]) * q[1]
            + (W[0, 0] * W[1, 1] - W[0, 1] * W[1, 0]) * q[2]) / det


@njit(cache=True)
def _slip_newton(W, q, mu, phi, out):
    """Newton's method on F(phi) = 0 (_directions' trigonometric polynomial) from ``phi``; writes
    the slip row into ``out`` and returns True when it lands on an exact slip solution (the
    row's residual at round-off), else False (the quartic's roots are then searched)."""
    a, b0, b1 = W[0, 0], W[0, 1], W[0, 2]
    q_n, q1, q2 = q[0], q[1], q[2]
    A1 = a * q2 - q_n * W[2, 0]
    A2 = -a * q1 + q_n * W[1, 0]
    A3 = mu * (q_n * W[1, 2] - b0 * q2)
    A4 = mu * (b1 * q1 - q_n * W[1, 2])
    A5 = mu * (b0 * q1 - b1 * q2 + q_n * (W[2, 2] - W[1, 1]))
    for _ in range(30):
        C, S = np.cos(phi), np.sin(phi)
        F = A1 * C + A2 * S + A3 * C * C + A4 * S * S + A5 * S * C
        dF = -A1 * S + A2 * C + 2.0 * (A4 - A3) * S * C + A5 * (C * C - S * S)
        if dF == 0.0:
            return False
        step = F / dF
        phi -= step
        if abs(step) <= 1e-15:
            break
    else:
        return False
    tau0, tau1 = np.cos(phi), np.sin(phi)
    along = _slip(W, q, mu, tau0, tau1, out)
    if not along >= 0.0:
        return False
    # A slip solution when y_T is parallel to tau (y_N = 0 and r on the cone by construction): its
    # natural-map residual is then rho |y_T x tau|, asked at round-off of the row's data.
    y1 = q[1] + W[1, 0] * out[0] + W[1, 1] * out[1] + W[1, 2] * out[2]
    y2 = q[2] + W[2, 0] * out[0] + W[2, 1] * out[1] + W[2, 2] * out[2]
    return abs(y1 * tau1 - y2 * tau0) / a <= 1e-13 * max(abs(out[0]), abs(q[0]) / a)


@njit(cache=True)
def _projected_row(W, q, mu, start_n):
    """Fallback for a row with no closed-form candidate: the projected fixed point
    ``r <- proj_K(r - rho (W r + q + mu |y_T| e_N))`` (its residual decides whether it is kept)."""
    n = q.size
    rho = 1.0 / np.linalg.eigvalsh(W).max()
    r = np.zeros(n)
    r[0] = max(start_n, 0.0)
    z_t, p_t = np.empty(n - 1), np.empty(n - 1)
    for _ in range(2000):
        y = W.dot(r) + q
        norm_yt = np.sqrt(np.sum(y[1:] ** 2))
        for a in range(n - 1):
            z_t[a] = r[1 + a] - rho * y[1 + a]
        p_n = project(r[0] - rho * (y[0] + mu * norm_yt), z_t, mu, p_t)
        change = abs(p_n - r[0])
        for a in range(n - 1):
            change = max(change, abs(p_t[a] - r[1 + a]))
        r[0] = p_n
        r[1:] = p_t
        if change <= 1e-15 * max(np.abs(r).max(), 1e-300):
            break
    return r


@njit(cache=True)
def solve_row(W, q, mu, start=None):
    """Exact solution of one row's problem ``y = W r + q`` (W: 1 x 1, 2 x 2 or 3 x 3, SPD).

    Open when ``q_N >= 0``; else stick when ``-W^-1 q`` lies in the cone; else slip: the normal
    impulse closes the row, ``r_N = -q_N / (W_NN - mu W_NT . tau)``, and the direction ``tau`` of
    the tangential velocity solves ``y_T(tau) = |y_T| tau`` (two candidates in 2D; in 3D the real
    roots of a quartic in tan(phi / 2), phi the direction's angle): the candidate with the
    smallest residual.
    """
    r = np.empty(q.size)
    solve_row_into(W, q, mu, start, r, np.empty(2 * q.size))
    return r


@njit(cache=True)
def solve_row_into(W, q, mu, start, r, scratch):
    """``solve_row`` written into ``r``, with ``scratch`` (twice the row's size): without allocation where the
    row is open, sticks, slips in 2D, or slips in 3D along the direction Newton's method finds from ``start``
    (the sweeps' every row); the quartic's roots only where that fails."""
    n = q.size
    r[:] = 0.0
    if q[0] >= 0.0:
        return
    if n == 1 or mu == 0.0:
        r[0] = -q[0] / W[0, 0]
        return
    stick, y = scratch[:n], scratch[n:2 * n]
    _solve_small_into(W, q, stick)
    norm_t = 0.0
    for a in range(n):
        stick[a] = -stick[a]
        if a:
            norm_t += stick[a] * stick[a]
    norm_t = np.sqrt(norm_t)
    if stick[0] >= 0.0 and norm_t <= mu * stick[0] * (1.0 + 1e-14):
        r[:] = stick
        return
    rho = 1.0 / W[0, 0]
    if n == 3:   # Newton's method on the direction's angle from the row's current one (a sweep's usual case)
        if start is not None and start[1] ** 2 + start[2] ** 2 > 0.0:
            phi = np.arctan2(-start[2], -start[1])
        else:
            phi = np.arctan2(-stick[2], -stick[1])
        if _slip_newton(W, q, mu, phi, r):
            return
        r[:] = 0.0
    start_n, candidate = stick[0], stick   # (the stick candidate is spent: its buffer takes the slip ones)
    best = np.inf
    if n == 2:   # (the two directions, tau = +-1)
        for i in range(2):
            best = _slip_candidate(W, q, mu, 1.0 - 2.0 * i, 0.0, rho, candidate, y, r, best)
    else:
        taus = _directions(W, q, mu)
        for i in range(taus.shape[0]):
            best = _slip_candidate(W, q, mu, taus[i, 0], taus[i, 1], rho, candidate, y, r, best)
    if best == np.inf:
        r[:] = _projected_row(W, q, mu, start_n)


@njit(cache=True)
def _slip_candidate(W, q, mu, tau0, tau1, rho, candidate, y, r, best):
    """The slip law along tau into ``candidate``; copied into ``r`` where it is one with a residual below
    ``best``: returns the best residual so far."""
    along = _slip(W, q, mu, tau0, tau1, candidate)
    if not along >= 0.0:
        return best
    n = q.size
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += W[i, j] * candidate[j]
        y[i] = s + q[i]
    z_t = p_t = candidate[:0]   # (a 2D row's residual takes scalars; a 3D row's, the quartic's rare path, scratch)
    if n == 3:
        z_t, p_t = np.empty(2), np.empty(2)
    res = _row_residual_at(candidate, y, 0, n, mu, rho, z_t, p_t)
    if res < best:
        r[:] = candidate
        return res
    return best


@njit(cache=True)
def residual(r, y, q, rows, start, sizes, mu, rho):
    """The natural-map residual over ``rows`` divided by the size of the data (friction.py):
    returns (that, the row where it is largest). Row i's unknowns are ``start[i]`` on, ``sizes[i]``."""
    worst, worst_row, scale = 0.0, -1, 0.0
    z_t = p_t = r[:0]   # (a 3D row's scratch, allocated at the first: a small problem's solve calls this often)
    for i in rows:
        s, k = start[i], sizes[i]
        for j in range(s, s + k):
            scale = max(scale, abs(r[j]))
            scale = max(scale, rho[i] * abs(q[j]))
        if k == ROW and not z_t.size:
            z_t, p_t = np.empty(ROW - 1), np.empty(ROW - 1)
        res = _row_residual_at(r, y, s, k, mu[i], rho[i], z_t, p_t)
        if not np.isfinite(res):   # (a value not finite: no solution, never a residual of 0)
            return np.nan, i
        if res > worst:
            worst, worst_row = res, i
    if not np.isfinite(scale):
        return np.nan, worst_row
    return worst / max(scale, 1e-300), worst_row


@njit(cache=True)
def blocks_of(upper, lower, rows, start, sizes, block=BLOCK):
    """The blocks of ``block`` consecutive rows of the sweeps: ``first`` (block c's unknowns are
    ``unknowns[first[c]:first[c + 1]]``), ``unknowns``, ``local`` (each row's first unknown within
    its block), each block's part of W = upper + lower (``parts[c]``, float64, zero-padded; lower
    empty when upper is W) and its rows (``rows[row_first[c]:row_first[c + 1]]``): built once per
    set of rows."""
    m = rows.size
    blocks = (m + block - 1) // block
    first = np.zeros(blocks + 1, np.int64)
    for t in range(m):
        first[t // block + 1] += sizes[rows[t]]
    for c in range(blocks):
        first[c + 1] += first[c]
    unknowns = np.empty(first[blocks], np.int64)
    local = np.empty(m, np.int64)
    for t in range(m):
        c = t // block
        offset = local[t - 1] + sizes[rows[t - 1]] if t % block else 0
        local[t] = offset
        for a in range(sizes[rows[t]]):
            unknowns[first[c] + offset + a] = start[rows[t]] + a
    size = 0
    for c in range(blocks):
        size = max(size, first[c + 1] - first[c])
    parts = np.zeros((blocks, size, size))
    for c in range(blocks):
        idx = unknowns[first[c]:first[c + 1]]
        for e in range(idx.size):
            row = upper[idx[e]]
            for f in range(idx.size):
                parts[c, e, f] = row[idx[f]]
            if lower.shape[0]:
                row = lower[idx[e]]
                for f in range(idx.size):
                    parts[c, e, f] += row[idx[f]]
    row_first = np.minimum(np.arange(blocks + 1) * block, m)
    return first, unknowns, local, parts, row_first


@njit(cache=True)
def gauss_seidel(W, q, r, y, rows, start, sizes, mu, rho, tolerance, sweeps, layout, stall=False, inner=INNER):
    """Up to ``sweeps`` sweeps of nonsmooth block Gauss-Seidel over ``rows``; ``r`` and ``y = W r + q``
    (all entries) updated in place.

    The rows are taken in blocks of consecutive rows (``layout``: ``blocks_of``'s); within a block,
    ``inner`` sweeps of Gauss-Seidel, each row solved exactly with the others fixed, on the block's
    own part of W (a few hundred unknowns: it stays in cache); then the rest of y takes the block's
    change at once. A sweep so reads W once whatever ``inner`` (the unknowns are in row order, row
    i's at ``start[i]`` on, and W is symmetric: a row's change is along a contiguous slab of W's
    rows, in memory order), and the inner sweeps settle the strongly coupled neighbours that plain
    Gauss-Seidel leaves to later sweeps. W in float64, or a
    float32 copy: half the memory traffic, y then drifts from W r + q by its round-off (the blocks'
    parts are float64 either way). Returns (sweeps done, residual, worst row) after the first sweep
    whose residual is within the tolerance, or whose residual fell by less than a third (``stall``:
    float32's floor reached), or the last."""
    first, unknowns, local, W_blocks, row_first = layout
    blocks = first.size - 1
    # One row's matrix, data and impulse so far, per size (reused: no allocation per row).
    W_row = [np.empty((k, k)) for k in range(ROW + 1)]
    q_row = [np.empty(k) for k in range(ROW + 1)]
    r_row = [np.empty(k) for k in range(ROW + 1)]
    new_row = [np.empty(k) for k in range(ROW + 1)]
    scratch_row = [np.empty(2 * k) for k in range(ROW + 1)]
    res, worst = np.inf, -1
    done = 0
    for sweep in range(1, sweeps + 1):
        done = sweep
        for c in range(blocks):
            idx = unknowns[first[c]:first[c + 1]]
            W_b = W_blocks[c]
            y_b, r_b = y[idx], r[idx]
            old = r_b.copy()
            for _ in range(inner):
                for t in range(row_first[c], row_first[c + 1]):
                    i, o = rows[t], local[t]
                    k = sizes[i]
                    W_i, q_i, r_i = W_row[k], q_row[k], r_row[k]
                    for a in range(k):
                        value = y_b[o + a]
                        for b in range(k):
                            W_i[a, b] = W_b[o + a, o + b]
                            value -= W_b[o + a, o + b] * r_b[o + b]
                        q_i[a] = value
                        r_i[a] = r_b[o + a]
                    new = new_row[k]
                    solve_row_into(W_i, q_i, mu[i], r_i, new, scratch_row[k])
                    for a in range(k):
                        change = new[a] - r_b[o + a]
                        if change != 0.0:
                            r_b[o + a] = new[a]
                            _axpy1(y_b, W_b[o + a], change)
            # The rest of y (and the block's own, to the same values up to round-off): W[:, block] change.
            for t in range(row_first[c], row_first[c + 1]):
                i, o = rows[t], local[t]
                s, k = start[i], sizes[i]
                moved = False
                for a in range(k):
                    moved |= r_b[o + a] != old[o + a]
                    r[s + a] = r_b[o + a]
                if not moved:
                    continue
                if k == 1:
                    _axpy1(y, W[s], r_b[o] - old[o])
                elif k == 2:
                    _axpy2(y, W[s], W[s + 1], r_b[o] - old[o], r_b[o + 1] - old[o + 1])
                else:
                    _axpy3(y, W[s], W[s + 1], W[s + 2], r_b[o] - old[o], r_b[o + 1] - old[o + 1],
                           r_b[o + 2] - old[o + 2])
        previous = res
        res, worst = residual(r, y, q, rows, start, sizes, mu, rho)
        if res <= tolerance or (stall and sweep > 2 and res > 0.67 * previous):
            break
    return done, res, worst


@njit(cache=True)
def add_product(y, M, d):
    """``y += M d`` for a symmetric M (float32 or float64; in float64), reading M once, three rows
    at a time (its columns), skipping the zeros of d."""
    n = d.shape[0]
    j = 0
    while j + 2 < n:
        if d[j] != 0.0 or d[j + 1] != 0.0 or d[j + 2] != 0.0:
            _axpy3(y, M[j], M[j + 1], M[j + 2], d[j], d[j + 1], d[j + 2])
        j += 3
    while j < n:
        if d[j] != 0.0:
            _axpy1(y, M[j], d[j])
        j += 1


# y += the changes times W's rows: separate functions on 1D arrays, which LLVM vectorizes.
@njit(cache=True, fastmath=True, error_model="numpy")
def _axpy1(y, w0, c0):
    for m in range(y.shape[0]):
        y[m] += c0 * w0[m]


@njit(cache=True, fastmath=True, error_model="numpy")
def _axpy2(y, w0, w1, c0, c1):
    for m in range(y.shape[0]):
        y[m] += c0 * w0[m] + c1 * w1[m]


@njit(cache=True, fastmath=True, error_model="numpy")
def _axpy3(y, w0, w1, w2, c0, c1, c2):
    for m in range(y.shape[0]):
        y[m] += c0 * w0[m] + c1 * w1[m] + c2 * w2[m]


@njit(cache=True)
def alart_curnier(W, q, r, starts, sizes, rho, mu, jacobian):
    """Alart and Curnier's function ``F(r)`` of the closed rows and, with ``jacobian``, its generalized
    Jacobian ``J`` (FrictionProblem._newton: the rows' unknowns at ``starts`` with ``sizes``, their
    ``rho = 1 / W_NN`` and ``mu``): per row ``F_N = r_N - max(0, r_N - rho y_N)``, ``F_T = r_T -
    proj_B(r_T - rho y_T)`` on the disk of radius ``mu max(0, r_N - rho y_N)``, ``y = W r + q``."""
    n = r.size
    y = W @ r + q
    F = np.empty(n)
    J = np.zeros((n, n)) if jacobian else np.zeros((1, 1))
    alart_curnier_into(W, y, r, starts, sizes, rho, mu, F, J, jacobian, np.empty((3, ROW - 1)))
    return F, J


@njit(cache=True)
def alart_curnier_into(W, y, r, starts, sizes, rho, mu, F, J, jacobian, scratch):
    """``alart_curnier``'s F and J written into ``F`` and ``J`` (J zero on entry) from ``y = W r + q``, with
    ``scratch`` (3 x 2): no allocation (small_kernel.py calls it many times a solve)."""
    n = r.size
    z_t, u, dz = scratch[0], scratch[1], scratch[2]
    for b in range(starts.size):
        k, m, rh, friction = starts[b], sizes[b], rho[b], mu[b]
        z_n = r[k] - rh * y[k]
        F[k] = r[k] - max(z_n, 0.0)
        if jacobian:
            J[k, k] = 1.0
            if z_n > 0.0:
                for j in range(n):
                    J[k, j] += rh * W[k, j]
                J[k, k] -= 1.0
        if m == 1:
            continue
        nt = m - 1
        norm = 0.0
        for a in range(nt):
            z_t[a] = r[k + 1 + a] - rh * y[k + 1 + a]
            norm += z_t[a] * z_t[a]
        norm = np.sqrt(norm)
        radius = friction * max(z_n, 0.0)
        if norm <= radius:   # stick: F_T = rho y_T
            for a in range(nt):
                F[k + 1 + a] = rh * y[k + 1 + a]
                if jacobian:
                    for j in range(n):
                        J[k + 1 + a, j] = rh * W[k + 1 + a, j]
        elif radius > 0.0:   # slip on the disk's edge
            for a in range(nt):
                u[a] = z_t[a] / norm
                F[k + 1 + a] = r[k + 1 + a] - radius * u[a]
            if jacobian:
                scale = radius / norm
                for j in range(n):
                    dz_n = -rh * W[k, j] + (1.0 if j == k else 0.0)
                    u_dz = 0.0
                    for a in range(nt):
                        dz[a] = -rh * W[k + 1 + a, j] + (1.0 if j == k + 1 + a else 0.0)
                        u_dz += u[a] * dz[a]
                    for a in range(nt):   # -(u mu dz_n + radius/norm (I - u u^T) dz) + I on the row's own
                        value = -(u[a] * friction * dz_n + scale * (dz[a] - u[a] * u_dz))
                        J[k + 1 + a, j] = value + (1.0 if j == k + 1 + a else 0.0)
        else:                # open: no friction
            for a in range(nt):
                F[k + 1 + a] = r[k + 1 + a]
                if jacobian:
                    J[k + 1 + a, k + 1 + a] = 1.0


@njit(cache=True)
def alart_curnier_blocks(y, r, starts, sizes, rho, mu):
    """``alart_curnier``'s ``F`` and its Jacobian as per-row blocks, ``J = (I - Q) + rho Q W`` (``y = W r + q``
    given): ``Q`` (rows x 3 x 3, a row of m unknowns in its leading m x m) is the derivative of the row's
    projection, ``F = r - proj(r - rho y)``: 1 on a pressed row's normal, the identity on a sticking row's
    tangents, ``mu u`` and ``radius / |z_T| (I - u u^T)`` on a slipping one's (FrictionProblem._newton_iterative)."""
    n = r.size
    F = np.empty(n)
    Q = np.zeros((starts.size, 3, 3))
    for b in range(starts.size):
        k, m, rh, friction = starts[b], sizes[b], rho[b], mu[b]
        z_n = r[k] - rh * y[k]
        F[k] = r[k] - max(z_n, 0.0)
        if z_n > 0.0:
            Q[b, 0, 0] = 1.0
        if m == 1:
            continue
        nt = m - 1
        norm = 0.0
        for a in range(nt):
            z = r[k + 1 + a] - rh * y[k + 1 + a]
            norm += z * z
        norm = np.sqrt(norm)
        radius = friction * max(z_n, 0.0)
        if norm <= radius:   # stick
            for a in range(nt):
                F[k + 1 + a] = rh * y[k + 1 + a]
                Q[b, 1 + a, 1 + a] = 1.0
        elif radius > 0.0:   # slip on the disk's edge
            scale = radius / norm
            for a in range(nt):
                u_a = (r[k + 1 + a] - rh * y[k + 1 + a]) / norm
                F[k + 1 + a] = r[k + 1 + a] - radius * u_a
                Q[b, 1 + a, 0] = friction * u_a
                for c in range(nt):
                    u_c = (r[k + 1 + c] - rh * y[k + 1 + c]) / norm
                    Q[b, 1 + a, 1 + c] = scale * ((1.0 if a == c else 0.0) - u_a * u_c)
        else:                # open
            for a in range(nt):
                F[k + 1 + a] = r[k + 1 + a]
    return F, Q
