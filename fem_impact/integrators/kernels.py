"""Compiled steps without contact on a diagonal replicated system (blocks.py), by Numba (Debian's
python3-numba, cached beside this file after the first run; optional: without it every step is a
single step).

Each loop is its scheme's step (moreau_jean.py, newmark.py) with the contact terms zero, operation
by operation in the integrator's order, on each dof: the same products, sums and divisions, and a
fused multiply-add where the integrator's BLAS ``axpy`` fuses (``FUSED``, probed once), so that
the states are the integrator's own to the last bit. That is why the integrators' identities for
``K U`` and ``K V`` (and their products every ``check_every`` steps) appear here too.
"""

from __future__ import annotations

import numpy as np
from numba import types
from numba.extending import intrinsic
from scipy.linalg.blas import daxpy

from ..compiled import njit
from ..nonsmooth.lcp_kernel import solve as lcp_solve


@intrinsic
def _fma(typingctx, a, b, c):
    """``a b + c`` rounded once (LLVM's fma)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)
    return sig, codegen


def blas_fuses() -> bool:
    """Whether this BLAS's ``daxpy`` rounds ``y + a x`` once (a fused multiply-add), as the
    integrators' ``axpy`` computes it: (1 + 2^-30)^2 - 1 keeps its 2^-60 only when fused."""
    x, y = np.array([1.0 + 2.0 ** -30]), np.array([-1.0])
    daxpy(x, y, a=1.0 + 2.0 ** -30)
    return bool(y[0] != 2.0 ** -29)


FUSED = blas_fuses()


@njit(cache=True, inline="always")
def _axpy(fused, a, x, y):
    return _fma(a, x, y) if fused else a * x + y


@njit(cache=True, inline="always")
def _rhs(fused, loaded, damped, coef, R0, R1, mv, cv, ku, kv):
    """A dof's rhs = M V0 + dt R_theta - dt (1 - theta) C V0 - dt K U0 - theta (1 - theta) dt^2 K V0, axpy by
    axpy as MoreauJean.step forms it."""
    r = mv
    if loaded:
        r = _axpy(fused, coef[0], R0, r)
        r = _axpy(fused, coef[1], R1, r)
    if damped:
        r = _axpy(fused, coef[2], cv, r)
    r = _axpy(fused, coef[3], ku, r)
    return _axpy(fused, coef[4], kv, r)


@njit(cache=True, inline="always")
def _finish(fused, damped, identity, coef, r, vi, v0, uh, m, k, d, ku, kv):
    """A dof's end of step from its velocity V1 (``r``: the step's rhs with the impulses, ``uh``: U0 + dt (1 -
    theta) V0): (U1, C V1, A, M V1, K U1, K V1); K V1 from theta^2 dt^2 K V1 = rhs - M V1 - theta dt C V1
    (``identity``), else by products."""
    ui = _axpy(fused, coef[1], vi, uh)
    cvi = d * vi if damped else 0.0
    ai = (vi - v0) * coef[5]
    mvi = m * vi
    if identity:
        kvi = r - mvi
        if damped:
            kvi = _axpy(fused, coef[6], cvi, kvi)
        kvi = kvi * coef[7]
        kui = _axpy(fused, coef[0], kv, ku)
        kui = _axpy(fused, coef[1], kvi, kui)
    else:
        kvi = k * vi
        kui = k * ui
    return ui, cvi, ai, mvi, kui, kvi


@njit(cache=True)
def moreau_jean_steps(first, check_every, fused, loaded, damped, coef, m, k, d, inv_S, R,
                      U0, V0, MV0, KU0, KV0, CV0, U, V, A, KU, KV):
    """MoreauJean.step without impulse, ``U.shape[0]`` times from step ``first``'s vectors (U0, V0,
    M V0, K U0, K V0, C V0); ``R`` (L + 1 x n) the modal loads at the steps' ends; ``coef``: the
    step's scalars as the integrator forms them, [dt (1 - theta), dt theta, -dt (1 - theta), -dt,
    -theta (1 - theta) dt^2, 1 / dt, -theta dt, 1 / (theta^2 dt^2)]. Writes U, V, A, K U and K V
    after each step (L x n)."""
    c0 = coef[0]
    u, v, mv, ku, kv, cv = U0.copy(), V0.copy(), MV0.copy(), KU0.copy(), KV0.copy(), CV0.copy()
    for j in range(U.shape[0]):
        identity = (first + j + 1) % check_every != 0
        for i in range(u.size):
            r = _rhs(fused, loaded, damped, coef, R[j, i], R[j + 1, i], mv[i], cv[i], ku[i], kv[i])
            v0 = v[i]
            vi = inv_S[i] * r                      # the free velocity: S V1 = rhs
            ui, cvi, ai, mvi, kui, kvi = _finish(fused, damped, identity, coef, r, vi, v0,
                                                 _axpy(fused, c0, v0, u[i]), m[i], k[i], d[i], ku[i], kv[i])
            u[i], v[i], mv[i], ku[i], kv[i], cv[i] = ui, vi, mvi, kui, kvi, cvi
            U[j, i], V[j, i], A[j, i], KU[j, i], KV[j, i] = ui, vi, ai, kui, kvi

@njit(cache=True)
def newmark_steps(fused, damped, coef, m, k, d, inv_S, R, U0, V0, A0, MV0, MA0, U, V, A, MV, Up, Vp):
    """Newmark.step without multipliers, ``U.shape[0]`` times from (U0, V0, A0, M V0, M A0); ``R``
    (L + 1 x n) the modal loads at the steps' ends (row 0 unused); ``coef``: [dt, dt^2 (1/2 - beta),
    dt (1 - gamma), beta dt^2, gamma dt]. Writes U, V, A, the scheme's M V and the predictors U~, V~
    (Up, Vp: what its contact rows are projected from) of each step."""
    c0, c1, c2, c3, c4 = coef[0], coef[1], coef[2], coef[3], coef[4]
    u, v, a, mv, ma = U0.copy(), V0.copy(), A0.copy(), MV0.copy(), MA0.copy()
    for j in range(U.shape[0]):
        for i in range(u.size):
            ui = _axpy(fused, c0, v[i], u[i])      # predictors
            ui = _axpy(fused, c1, a[i], ui)
            vi = _axpy(fused, c2, a[i], v[i])
            Up[j, i], Vp[j, i] = ui, vi
            rhs = R[j + 1, i] - k[i] * ui          # S A1 = R1 - K U~ - C V~
            if damped:
                rhs = rhs - d[i] * vi
            ai = inv_S[i] * rhs
            ui = _axpy(fused, c3, ai, ui)
            vi = _axpy(fused, c4, ai, vi)
            mai = m[i] * ai
            mvi = _axpy(fused, c2, ma[i], mv[i])    # M V += dt ((1 - gamma) M A0 + gamma M A1)
            mvi = _axpy(fused, c4, mai, mvi)
            u[i], v[i], a[i], mv[i], ma[i] = ui, vi, ai, mvi, mai
            U[j, i], V[j, i], A[j, i], MV[j, i] = ui, vi, ai, mvi


@njit(cache=True, inline="always")
def take_impulses(fused, damped, identity, coef, pushed, G, P, x, vf, rhs, uh, m, k, d, u, v, mv, ku, kv, cv,
                  U, V, A):
    """The end of a step with the impulses ``x`` (when ``pushed``): each dof's V1 = V* - (G x)_i, its step
    equation's rhs less (P^T x)_i, then ``_finish``; the state (u, v, M v, K u, K v, C v) updated in place,
    U1, V1 and A written into the rows U, V, A."""
    for i in range(u.size):
        vi = vf[i]
        if pushed:
            s, t = 0.0, 0.0
            for a in range(x.size):
                s += G[i, a] * x[a]
                t += P[a, i] * x[a]
            vi -= s
            rhs[i] -= t
        v0 = v[i]
        ui, cvi, ai, mvi, kui, kvi = _finish(fused, damped, identity, coef, rhs[i], vi, v0, uh[i], m[i], k[i], d[i],
                                             ku[i], kv[i])
        u[i], v[i], mv[i], ku[i], kv[i], cv[i] = ui, vi, mvi, kui, kvi, cvi
        U[i], V[i], A[i] = ui, vi, ai


@njit(cache=True)
def moreau_jean_contact_steps(first, check_every, fused, loaded, damped, coef, m, k, d, inv_S, R,
                              U0, V0, MV0, KU0, KV0, CV0, P, G, A_lcp, W, gap_free, pu0, pv0, active,
                              U, V, A, KU, KV, X, PV, PU) -> int:
    """MoreauJean.step with its impulses, on rows that all take their gap at the step's end (every row
    compliant: a static part's, a stop's spring), ``U.shape[0]`` times; as ``moreau_jean_steps`` plus the
    rows: ``P`` (p x n), ``G = S^-1 P^T`` (n x p), ``A_lcp`` the one-step problem's matrix, ``W = P S^-1
    P^T``; ``gap_free`` (L x p) the obstacles' gaps less the static offsets at the steps' ends; ``pu0``,
    ``pv0`` P U (of the modes) and P V of the state; ``active`` (in/out) the rows with an impulse. Writes
    as ``moreau_jean_steps`` and the impulses X, P V and P U (of the modes) after each step (L x p).
    Returns how many steps it took: fewer where the LCP leaves pivoting (lcp_kernel.solve), the step the
    caller takes itself."""
    c0, c1 = coef[0], coef[1]
    n, p = U0.size, P.shape[0]
    u, v, mv, ku, kv, cv = U0.copy(), V0.copy(), MV0.copy(), KU0.copy(), KV0.copy(), CV0.copy()
    pu, pv = pu0.copy(), pv0.copy()
    rhs, vf, uh = np.empty(n), np.empty(n), np.empty(n)
    q, pvf = np.empty(p), np.empty(p)
    factored, L, rows, x, w, y = np.full(p, -1, dtype=np.int8), np.zeros((p, p)), np.zeros(p, dtype=np.int64), \
        np.zeros(p), np.zeros(p), np.zeros(2 * p)
    for j in range(U.shape[0]):
        identity = (first + j + 1) % check_every != 0
        for i in range(n):
            rhs[i] = _rhs(fused, loaded, damped, coef, R[j, i], R[j + 1, i], mv[i], cv[i], ku[i], kv[i])
            uh[i] = _axpy(fused, c0, v[i], u[i])   # U0 + dt (1 - theta) V0
            vf[i] = inv_S[i] * rhs[i]              # the free velocity
        for a in range(p):                         # the rows' problem at the step's end (MoreauJean._contact_problem)
            s = 0.0
            for i in range(n):
                s += P[a, i] * vf[i]
            pvf[a] = s
            q[a] = (gap_free[j, a] - pu[a] - c0 * pv[a]) / c1 - pvf[a]
        if not lcp_solve(A_lcp, q, active, factored, L, rows, x, w, y):
            return j
        pushed = False
        for a in range(p):
            pushed = pushed or x[a] != 0.0
        for a in range(p):
            s = 0.0
            if pushed:
                for b in range(p):
                    s += W[a, b] * x[b]
            pv[a] = pvf[a] - s
        take_impulses(fused, damped, identity, coef, pushed, G, P, x, vf, rhs, uh, m, k, d, u, v, mv, ku, kv, cv,
                      U[j], V[j], A[j])
        KU[j], KV[j] = ku, kv
        for a in range(p):
            s = 0.0
            for i in range(n):
                s += P[a, i] * u[i]
            pu[a] = s
            X[j, a], PV[j, a], PU[j, a] = x[a], pv[a], s
    return U.shape[0]


def warm_up() -> None:
    """Compile the loops (or load them from Numba's cache) now, on arrays of the types the integrators
    pass, so that the time loop does not pay for it."""
    one, row, block = np.ones(1), np.zeros((2, 1)), np.zeros((1, 1))
    moreau_jean_steps(0, 32, FUSED, True, True, np.ones(8), one, one, one, one, row, one, one, one, one, one, one,
                      block, block.copy(), block.copy(), block.copy(), block.copy())
    newmark_steps(FUSED, True, np.ones(5), one, one, one, one, row, one, one, one, one, one, block, block.copy(),
                  block.copy(), block.copy(), block.copy(), block.copy())
    rows, square = np.ones((1, 1)), np.ones((1, 1))
    moreau_jean_contact_steps(0, 32, FUSED, True, True, np.ones(8), one, one, one, one, row, one, one, one, one, one,
                              one, rows, rows.copy(), square, square.copy(), block.copy(), one.copy(), one.copy(),
                              np.zeros(1, dtype=np.bool_), block.copy(), block.copy(), block.copy(), block.copy(),
                              block.copy(), block.copy(), block.copy(), block.copy())
