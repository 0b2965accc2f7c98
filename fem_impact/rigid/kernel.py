"""The mixed step of rigid bodies beside a modal body, compiled (blocks.py; docs/theory.md s. 12.7).

One loop runs ``MixedMoreauJean.step`` (mixed.py) many times in 2D where every row is compliant (the
modal body's static part on each): the modal equations' Moreau-Jean step (theta = 1/2, the same
operations as integrators/kernels.py), the rigid bodies' free velocities, the rows' one cone problem
(small_kernel.solve: Alart and Curnier's Newton method, certified by its residual) in

    W = H M_r^-1 H^T + W_e + C / (h^2 / 2),   q_N = g_free / (h / 2),   q_T = -slip - dC_T / (h / 2),

the impulses' shares to both parts, and the bodies moved by their mean velocity. Every matrix of a row
is constant but H, which is linear in each body's cos and sin (``H = H_t + cos H_c + sin H_s`` on its
spin column): no sparse matrix, no allocation of the problem's size in the loop.
"""

from __future__ import annotations

import numpy as np

from ..compiled import njit
from ..integrators.kernels import FUSED, _axpy, _rhs, take_impulses
from ..nonsmooth.small_kernel import DONE
from ..nonsmooth.small_kernel import solve as small_solve


@njit(cache=True)
def _rows_h(Ht, Hc, Hs, cos, sin, H):
    """H at the bodies' angles now (rows x 3 nb): the translation columns constant, each spin column
    ``cos H_c + sin H_s`` of its body."""
    q, nb = Hc.shape
    for a in range(q):
        for b in range(nb):
            H[a, 3 * b] = Ht[a, 3 * b]
            H[a, 3 * b + 1] = Ht[a, 3 * b + 1]
            H[a, 3 * b + 2] = cos[b] * Hc[a, b] + sin[b] * Hs[a, b]


@njit(cache=True)
def mixed_steps(coef, fused, loaded, damped, m, k, d, inv_S, R, Pe, Ge, We, C, offsets, d0, p,
                Ht, Hc, Hs, inv_mass, Ft, Fc, Fs, h, numbers, layout, tolerance,
                u0, v0, cv0, pe0, f0, gap0, x0_ref, x_in, angle_in, nu_in, guess_in,
                U, V, A, CV, X, PE, NU, XS, ANG, RIG, GAP):
    """``U.shape[0]`` mixed steps from the state (``u0``, ``v0``, ``cv0``: the modes' U, V, C V; ``pe0``:
    the modal rows' velocities P_e V; ``f0``: the rows' forces; ``gap0``: the normal rows' gaps; the bodies'
    centres, angles and generalized velocities; ``guess_in``: the last impulses, or empty).

    ``coef``: Moreau-Jean's scalars (kernels.moreau_jean_steps); ``R`` (L + 1 x n) the modal loads at the
    steps' ends; ``Pe`` (q x n) the rows on the modes, ``Ge = S^-1 Pe^T``, ``We = Pe S^-1 Pe^T``, ``C``
    the static part's compliance (q x q), ``offsets`` (L + 1 x q) its offsets at the steps' ends; ``d0``
    the obstacles' gaps (p); ``H_t``, ``H_c``, ``H_s`` the rows' H pieces; ``inv_mass`` (3 nb) the inverse
    generalized masses; ``Ft`` (L x 3 nb), ``Fc``, ``Fs`` (L x nb) the loads' generalized force at each
    mid-step, its moment ``cos Fc + sin Fs``; ``numbers`` (mu, then 0 for rho), ``layout`` the cone
    problem's (small_kernel.solve).

    Writes per step: U, V, A, C V of the modes, the impulses X (L x q), P_e V (PE), the bodies'
    generalized velocities NU, centres XS (L x 2 nb), angles ANG, the rigid part's work terms RIG (L x 3:
    the loads', the normal and the tangent impulses' on the mean velocity) and the normal rows' gaps GAP.
    Returns (steps taken, the largest residual): fewer steps where a cone problem is not solved whole (the
    caller's own step takes it)."""
    n, q, nb = u0.size, Pe.shape[0], inv_mass.size // 3
    c0 = coef[0]
    u, v, cv, pe, f, gap = u0.copy(), v0.copy(), cv0.copy(), pe0.copy(), f0.copy(), gap0.copy()
    x, angle, nu = x_in.copy(), angle_in.copy(), nu_in.copy()
    guess = guess_in.copy()
    kv = np.empty(n)
    ku = np.empty(n)
    mv = np.empty(n)
    for i in range(n):
        kv[i], ku[i], mv[i] = k[i] * v[i], k[i] * u[i], m[i] * v[i]
    rhs, uh, vf = np.empty(n), np.empty(n), np.empty(n)
    fe, rates0, ratesf, qv, r = np.empty(q), np.empty(q), np.empty(q), np.empty(q), np.empty(q)
    H, Wm, Wrow = np.empty((q, 3 * nb)), np.empty((q, q)), np.empty((q, q))
    cos, sin = np.empty(nb), np.empty(nb)
    free, nu1, mid, F = np.empty(3 * nb), np.empty(3 * nb), np.empty(3 * nb), np.empty(3 * nb)
    active = np.ones(p, dtype=np.bool_)
    order, start = layout[:q], layout[q:q + p]
    half = 0.5 * h
    worst = 0.0
    for j in range(U.shape[0]):
        for i in range(n):   # the modes' free velocity (MoreauJean.step)
            rhs[i] = _rhs(fused, loaded, damped, coef, R[j, i], R[j + 1, i], mv[i], cv[i], ku[i], kv[i])
            uh[i] = _axpy(fused, c0, v[i], u[i])   # U0 + dt (1 - theta) V0
            vf[i] = inv_S[i] * rhs[i]
        for a in range(q):
            s = 0.0
            for i in range(n):
                s += Pe[a, i] * vf[i]
            fe[a] = s
        for b in range(nb):   # the rigid bodies' free velocity (RigidMoreauJean._free, 2D)
            cos[b], sin[b] = np.cos(angle[b]), np.sin(angle[b])
            F[3 * b], F[3 * b + 1] = Ft[j, 3 * b], Ft[j, 3 * b + 1]
            F[3 * b + 2] = Ft[j, 3 * b + 2] + cos[b] * Fc[j, b] + sin[b] * Fs[j, b]
        for c in range(3 * nb):
            free[c] = nu[c] + h * F[c] * inv_mass[c]
        _rows_h(Ht, Hc, Hs, cos, sin, H)
        for a in range(q):   # the rows' velocities at the start and free, the static part's change
            s0, s1 = pe[a], fe[a]
            for c in range(3 * nb):
                s0 += H[a, c] * nu[c]
                s1 += H[a, c] * free[c]
            rates0[a], ratesf[a] = s0, s1
        for a in range(q):
            moved = offsets[j + 1, a] - offsets[j, a]
            for b in range(q):
                moved += C[a, b] * f[b]
            if a < p:   # the gap at the step's end, divided by h/2 (RigidMoreauJean._impulses)
                qv[a] = (gap[a] - half * (rates0[a] + ratesf[a]) - moved) / half
            else:       # Coulomb's law on the whole slip
                qv[a] = -(rates0[a] + ratesf[a]) - moved / half
        for a in range(q):   # W in the cone problem's row order, its symmetric part
            for b in range(q):
                s = We[a, b] + C[a, b] / (half * h)
                for c in range(3 * nb):
                    s += H[a, c] * inv_mass[c] * H[b, c]
                Wm[a, b] = s
        for a in range(q):
            for b in range(q):
                Wrow[a, b] = 0.5 * (Wm[order[a], order[b]] + Wm[order[b], order[a]])
        for i in range(p):
            numbers[p + i] = 1.0 / Wrow[start[i], start[i]]
        out = small_solve(Wrow, qv, guess, active, numbers, layout, tolerance, q + 1)
        if out[2 * q + 2] != DONE:
            return j, worst
        worst = max(worst, out[2 * q])
        pushed = False
        for a in range(q):
            r[a] = out[a]
            pushed = pushed or r[a] != 0.0
        guess = r.copy()
        for c in range(3 * nb):   # nu1 = free - M^-1 H^T r
            s = 0.0
            for a in range(q):
                s += H[a, c] * r[a]
            nu1[c] = free[c] - inv_mass[c] * s
            mid[c] = 0.5 * (nu[c] + nu1[c])
        work_load = 0.0
        for c in range(3 * nb):
            work_load += h * F[c] * mid[c]
        work_n, work_t = 0.0, 0.0
        for a in range(q):
            s = 0.0
            for c in range(3 * nb):
                s += H[a, c] * mid[c]
            if a < p:
                work_n += r[a] * s
            else:
                work_t += r[a] * s
        # the modes take their share: V1 = V* - G r, the step's equation with it
        # (K V and K U by products, not the step equation's identity: the modes' K is diagonal)
        take_impulses(fused, damped, False, coef, pushed, Ge, Pe, r, vf, rhs, uh, m, k, d, u, v, mv, ku, kv, cv,
                      U[j], V[j], A[j])
        CV[j] = cv
        for a in range(q):
            s = 0.0
            for i in range(n):
                s += Pe[a, i] * v[i]
            pe[a] = s
            f[a] = r[a] / h
            X[j, a], PE[j, a] = r[a], s
        for b in range(nb):   # positions from the mean velocity (RigidMoreauJean.advance)
            x[2 * b] += h * mid[3 * b]
            x[2 * b + 1] += h * mid[3 * b + 1]
            angle[b] += h * mid[3 * b + 2]
            cos[b], sin[b] = np.cos(angle[b]), np.sin(angle[b])
            XS[j, 2 * b], XS[j, 2 * b + 1], ANG[j, b] = x[2 * b], x[2 * b + 1], angle[b]
        for c in range(3 * nb):
            nu[c] = nu1[c]
            NU[j, c] = nu1[c]
        RIG[j, 0], RIG[j, 1], RIG[j, 2] = work_load, work_n, work_t
        for a in range(p):   # the normal rows' gaps at the step's end: d0 - P (Y Z + static part + rigid)
            s = offsets[j + 1, a]
            for i in range(n):
                s += Pe[a, i] * u[i]
            for b in range(q):
                s -= C[a, b] * f[b]
            for b in range(nb):
                s += Ht[a, 3 * b] * (x[2 * b] - x0_ref[2 * b]) + Ht[a, 3 * b + 1] * (x[2 * b + 1] - x0_ref[2 * b + 1])
                s += sin[b] * Hc[a, b] - (cos[b] - 1.0) * Hs[a, b]
            gap[a] = d0[a] - s
            GAP[j, a] = gap[a]
    return U.shape[0], worst


def _warm_arguments() -> tuple:
    """Arguments of the kernel's types (one mode, one row, one body): to compile it before a run."""
    one, row, sq = np.ones(1), np.zeros((2, 1)), np.eye(1)
    layout = np.array([0, 0, 1], dtype=np.int64)
    out = lambda *shape: np.zeros(shape)   # noqa: E731
    return (np.ones(8), FUSED, True, True, one, one, one, one, row, sq.copy(), sq.copy(), sq.copy(), sq.copy(),
            row.copy(), one.copy(), 1, np.zeros((1, 3)), sq.copy(), sq.copy(), np.ones(3), out(1, 3), out(1, 1),
            out(1, 1), 1e-3, np.zeros(2), layout, 1e-10, one.copy(), one.copy(), one.copy(), one.copy(), one.copy(),
            one.copy(), np.zeros(2), np.zeros(2), np.zeros(1), np.zeros(3), np.zeros(0), out(1, 1), out(1, 1),
            out(1, 1), out(1, 1), out(1, 1), out(1, 1), out(1, 3), out(1, 2), out(1, 1), out(1, 3), out(1, 1))


def warm_up() -> None:
    """Compile the loop (or load it from Numba's cache) on arrays of the types the stepper passes."""
    mixed_steps(*_warm_arguments())
