"""The contact law on the small p x p level: an exact LCP solver and the Carnot impact correction."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ContactSolverError

TINY = np.finfo(float).tiny


def regularized(A: np.ndarray, relative: float = 1e-10) -> np.ndarray:
    """``A`` itself when regular; else ``A + eps I`` with eps a tiny fraction of its diagonal.

    More contact rows than the motion can tell apart (a reduced model with fewer modes than
    pairs, nodes sharing a constraint) make the Delassus matrix singular: the LCP then has
    many solutions and pivoting may cycle. The shift selects the smallest-norm forces, at the
    price of a gap error of ``eps * lam`` (1e-10 relative).
    """
    if A.size == 0 or np.linalg.cond(A) < 1.0 / (relative * 100):
        return A
    return A + relative * np.abs(np.diag(A)).max() * np.eye(A.shape[0])


def solve_lcp(
    A: np.ndarray, q: np.ndarray, guess: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve ``w = A x + q >= 0, x >= 0, x . w = 0`` exactly.

    Murty's least-index principal pivoting: finite for any start when ``A`` is a P-matrix (here
    a Delassus matrix ``P S^-1 P^T``, symmetric positive definite when the rows of P are
    independent). ``guess`` is the active set (x > 0) to start from, usually the previous
    step's, so a persisting contact state costs one small solve.

    Returns ``(x, w, active)``.
    """
    n = q.size
    if n == 1:  # the common case of one contact row, in closed form
        q0 = float(q[0])
        x = -q0 / float(A[0, 0]) if q0 < 0.0 else 0.0
        return np.array([x]), np.array([0.0 if x > 0.0 else q0]), np.array([x > 0.0])
    active = np.zeros(n, dtype=bool) if guess is None else guess.copy()
    if n == 0 or (not active.any() and np.all(q >= 0.0)):
        return np.zeros(n), q.copy(), np.zeros(n, dtype=bool)
    scale = max(np.abs(q).max(), TINY)
    tol = 1e-13 * scale
    for _ in range(4 * n + 10):
        x = np.zeros(n)
        if active.any():
            block = A[active][:, active]
            try:
                x[active] = np.linalg.solve(block, -q[active])
            except np.linalg.LinAlgError:
                x[active] = np.linalg.lstsq(block, -q[active], rcond=None)[0]
        w = A @ x + q
        xtol = 1e-13 * max(np.abs(x).max(), TINY)
        wrong = (active & (x < -xtol)) | (~active & (w < -tol))
        if not wrong.any():
            x[~active] = 0.0
            w[active] = 0.0
            return np.maximum(x, 0.0), np.maximum(w, 0.0), active
        j = int(np.argmax(wrong))
        active[j] = not active[j]
    # Pivoting is finite for P-matrices but may take many steps (and round-off can make it
    # cycle on ill-conditioned ones): fall back on the equivalent convex problem.
    return _lcp_as_nnls(A, q)


def _lcp_as_nnls(A: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The LCP with symmetric positive definite ``A`` is ``min 1/2 x'Ax + q'x, x >= 0``, i.e. the
    non-negative least-squares problem ``min |L'x + L^-1 q|`` with ``A = L L'`` (Lawson-Hanson)."""
    from scipy.optimize import nnls

    try:
        L = np.linalg.cholesky(0.5 * (A + A.T))
    except np.linalg.LinAlgError:
        raise ContactSolverError(f"contact problem of size {q.size} is not positive definite "
                                 "(dependent or conflicting constraints)") from None
    x = nnls(L.T, -np.linalg.solve(L, q), maxiter=50 * q.size)[0]
    w = A @ x + q
    active = x > 0.0
    w[active] = 0.0
    return x, np.maximum(w, 0.0), active


@dataclass
class ImpactResult:
    """Outcome of the velocity and acceleration projections on the closed contacts."""

    lam1: np.ndarray     # velocity-correction impulses, dV = -M^-1 P^T lam1 (may be negative:
                         # they remove the spurious rebound of the trapezoidal rule)
    lam2: np.ndarray     # acceleration-correction forces, dA = -M^-1 P^T lam2
    force: np.ndarray    # F_N = lam0 + lam2 at the end of the step


def impact_correction(
    D: np.ndarray,
    closed: np.ndarray,
    s0: np.ndarray,
    v_star: np.ndarray,
    v_minus: np.ndarray,
    a_normal: np.ndarray,
    lam0: np.ndarray,
    restitution: np.ndarray,
) -> ImpactResult:
    """Carnot's velocity correction and the acceleration projection on the closed rows.

    The sign condition is put on the whole impulse of the step ``S = s0 + lam1 >= 0``
    (``s0`` = the impulse of the position-level forces), complementary to the separating
    velocity ``w = -(P V+) - e max(P V-, 0) >= 0``: an LCP in ``D = P M^-1 P^T``. Contacts
    that stay closed (w = 0) then get the force ``F >= 0`` that keeps their normal
    acceleration non-positive; separating contacts carry no force.

    All arguments are per-row p-vectors (``D`` is p x p); only rows in ``closed`` change.
    """
    # (Small arrays: .dot and count_nonzero cost half of @ and .any().)
    p = s0.size
    lam1, lam2, force = np.zeros(p), np.zeros(p), lam0.copy()
    a = _rows(closed)
    Daa, s0a, lam0a = D[a][:, a], s0[a], lam0[a]
    q1 = -(Daa.dot(s0a) + v_star[a])
    if np.count_nonzero(restitution):
        q1 -= restitution[a] * np.maximum(v_minus[a], 0.0)
    S, w, active = solve_lcp(Daa, q1, guess=lam0a > 0.0)
    lam1[a] = S - s0a
    # Normal accelerations after the velocity change are unchanged by it: project them.
    stays = active | (w <= 0.0)
    n_stay = np.count_nonzero(stays)
    if n_stay == stays.size:
        b, Dbb, lam0b = a, Daa, lam0a
        q2 = -(Dbb.dot(lam0b) + a_normal[b])
    else:
        rows = np.arange(p)[a]
        b, leaving = rows[stays], rows[~stays]
        force[leaving] = 0.0
        Dbb, lam0b = D[b][:, b], lam0[b]
        q2 = -(Dbb.dot(lam0b) + a_normal[b] + D[b][:, leaving].dot(lam0[leaving]))
    if n_stay:
        force[b] = solve_lcp(Dbb, q2, guess=lam0b > 0.0)[0]
    lam2[a] = force[a] - lam0a
    return ImpactResult(lam1, lam2, force)


ALL = slice(None)   # every row: indexing with it gives views, no copies


def _rows(mask: np.ndarray):
    """The rows set in ``mask``: ``ALL`` when all are (the common case in a contact)."""
    return ALL if np.count_nonzero(mask) == mask.size else np.flatnonzero(mask)
