"""The contact law on the small p x p level: an exact LCP solver and the Carnot impact correction."""

from __future__ import annotations

import numpy as np

from ..errors import ContactSolverError

TINY = np.finfo(float).tiny
ALL = slice(None)   # every row: indexing with it gives views, no copies


SMALL = 200   # rows: up to this size the condition number is computed exactly (an SVD)


def regularized(A: np.ndarray, relative: float = 1e-10) -> np.ndarray:
    """``A`` itself when regular; else ``A + eps I`` with eps a tiny fraction of its diagonal.

    More contact rows than the motion can tell apart (a reduced model with fewer modes than
    pairs, nodes sharing a constraint) make the Delassus matrix singular: the LCP then has
    many solutions and pivoting may cycle. The shift selects the smallest-norm forces, at the
    price of a gap error of ``eps * lam`` (1e-10 relative).

    "Regular" is a condition number below ``1 / (100 relative)``: computed exactly for up to
    ``SMALL`` rows; above, from a Cholesky factor (LAPACK's 1-norm estimate, O(p^2) after the
    O(p^3 / 3) factorization), and a failed Cholesky (not positive definite) shifts too.

    A matrix with an infinite or NaN entry (the step matrix overflowed, or is singular to
    working precision) has no condition number: ContactSolverError.
    """
    return _regularized(A, relative)[0]


def _regularized(A: np.ndarray, relative: float) -> tuple[np.ndarray, np.ndarray | None]:
    """(``regularized(A)``, the Cholesky factor that showed a large ``A`` regular, or None)."""
    if A.size == 0:
        return A, None
    _check_finite(A)
    if A.shape[0] <= SMALL:
        if np.linalg.cond(A) < 1.0 / (relative * 100):
            return A, None
    else:
        factor, rcond = _cholesky_rcond(A)
        if rcond > relative * 100:
            return A, factor
    return A + relative * np.abs(np.diag(A)).max() * np.eye(A.shape[0]), None


def _check_finite(A: np.ndarray) -> None:
    if not np.isfinite(A).all():
        raise ContactSolverError(f"the contact problem's matrix (P S^-1 P^T, {A.shape[0]} rows) is not finite: the "
                                 "step matrix S overflowed a float or is singular to working precision (a free "
                                 "body's mass lost beside its stiffness at this time step); see the material, the "
                                 "mesh sizes and the time step")


def _cholesky_rcond(A: np.ndarray) -> tuple[np.ndarray | None, float]:
    """The lower Cholesky factor of a symmetric ``A`` and its reciprocal condition number estimate;
    (None, 0) if ``A`` is not positive definite (or not symmetric)."""
    from scipy.linalg import lapack

    if not _is_symmetric(A):
        return None, 0.0
    factor, info = lapack.dpotrf(A, lower=1, clean=0)
    if info != 0:
        return None, 0.0
    rcond, info = lapack.dpocon(factor, np.linalg.norm(A, 1), uplo=b"L")
    return (factor, float(rcond)) if info == 0 else (None, 0.0)


def _is_symmetric(A: np.ndarray) -> bool:
    scale = np.abs(A).max(initial=0.0)
    return bool(np.all(np.abs(A - A.T) <= 1e-10 * scale))




def delassus_solver(A, shift: np.ndarray | None = None) -> Delassus | DiagonalDelassus:
    """The LCP solver of the Delassus matrix ``A + diag(shift)``: row by row when ``A`` is a sparse
    diagonal (``Operators.delassus(..., diagonal=True)``), else :meth:`Delassus.regularized`."""
    from scipy import sparse

    if sparse.issparse(A):
        return DiagonalDelassus(A.diagonal() + (0.0 if shift is None else shift))
    return Delassus.regularized(A if shift is None else A + np.diag(shift))


class DiagonalDelassus:
    """LCPs ``w = a x + q >= 0, x >= 0, x . w = 0`` with a diagonal ``a > 0``: the rows are
    independent, and each is a projection, ``x = max(0, -q / a)``.

    The Delassus matrix of rows that touch disjoint dofs of a diagonal step matrix (a lumped mass,
    node-to-plane rows: the explicit method on a face of many nodes): no p x p matrix, no pivoting.
    ``matrix`` is the sparse diagonal; the interface is :class:`Delassus`'.
    """

    def __init__(self, diagonal: np.ndarray):
        self.diagonal = np.ascontiguousarray(diagonal, dtype=float)
        _check_finite(self.diagonal)
        if np.any(self.diagonal <= 0.0):
            raise ContactSolverError("a contact row's entry of the diagonal Delassus matrix is not positive: "
                                     "the row touches no mass")
        from scipy import sparse

        self.matrix = sparse.diags(self.diagonal, format="csr")

    @property
    def shape(self) -> tuple[int, int]:
        return (self.diagonal.size, self.diagonal.size)

    def dot(self, x: np.ndarray) -> np.ndarray:
        return self.diagonal * x

    def solve(self, q: np.ndarray, guess: np.ndarray | None = None, rows=None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x, w, active)`` of the LCP on ``rows`` (all when None)."""
        a = self.diagonal if rows is None or rows is ALL else self.diagonal[rows]
        x = np.maximum(-q / a, 0.0)
        active = x > 0.0
        w = np.where(active, 0.0, q)
        return x, w, active


class Delassus:
    """LCPs ``w = A x + q >= 0, x >= 0, x . w = 0`` in one matrix ``A``, solved exactly, many times.

    Block principal pivoting (Judice & Pires, Comput. Oper. Res. 21 (1994) 587-596): from a
    starting active set (x > 0, usually the previous step's) solve ``A_FF x_F = -q_F``, then
    flip *all* infeasible indices (x_F < 0 or w_G < 0) at once; when the number of infeasible
    indices has not decreased for ``RETRIES`` flips in a row, flip only the least infeasible
    index (Murty's rule), which is finite for P-matrices (a Delassus matrix ``P S^-1 P^T`` with
    independent rows is symmetric positive definite). The factor of the active block is kept
    (keyed by the active set, the last ``KEEP``), so a persisting contact state costs two
    triangular solves and no factorization. Round-off cycling on an ill-conditioned matrix ends
    in the equivalent convex problem (``_lcp_as_nnls``).

    ``solve(q, guess, rows)`` solves the LCP on the principal submatrix ``A[rows][:, rows]``
    (``rows`` sorted indices, or all), sharing the factors: Carnot's correction solves on the
    closed rows of ``D`` this way. ``A @ x`` as ``dot``; the matrix itself as ``matrix``.
    """

    RETRIES = 3
    KEEP = 2

    def __init__(self, A: np.ndarray):
        self.matrix = np.ascontiguousarray(A, dtype=float)
        self.symmetric = _is_symmetric(self.matrix) if self.matrix.size else True
        self._factors: dict[bytes, tuple] = {}

    @classmethod
    def regularized(cls, A: np.ndarray, relative: float = 1e-10) -> Delassus:
        """The solver of ``regularized(A)``; on a large matrix the Cholesky factor that shows it
        regular is kept as the factor of the all-active block (a contact of every row)."""
        matrix, factor = _regularized(A, relative)
        solver = cls(matrix)
        if factor is not None:
            solver._factors[np.arange(A.shape[0]).tobytes()] = ("cholesky", (factor, True))
        return solver

    @property
    def shape(self) -> tuple[int, int]:
        return self.matrix.shape

    def dot(self, x: np.ndarray) -> np.ndarray:
        return self.matrix.dot(x)

    def solve_block(self, rows: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``A[rows][:, rows]^-1 b`` (rows: sorted indices), with the factor kept for the next call."""
        return self._apply(self._factor(np.asarray(rows)), b)

    def _factor(self, F: np.ndarray):
        """Factor of ``A[F][:, F]`` (F: sorted global indices), from the cache or new."""
        from scipy.linalg import cho_factor, lu_factor

        key = F.tobytes()
        if key in self._factors:
            return self._factors[key]
        A = self.matrix
        block = A if F.size == A.shape[0] else A[np.ix_(F, F)]
        factor = None
        if self.symmetric:
            try:
                factor = ("cholesky", cho_factor(block, lower=True, check_finite=False))
            except np.linalg.LinAlgError:
                factor = None
        if factor is None:
            if np.linalg.matrix_rank(block) < F.size:
                factor = ("lstsq", block.copy())
            else:
                factor = ("lu", lu_factor(block, check_finite=False))
        if len(self._factors) >= self.KEEP:
            self._factors.pop(next(iter(self._factors)))
        self._factors[key] = factor
        return factor

    @staticmethod
    def _apply(factor, b: np.ndarray) -> np.ndarray:
        from scipy.linalg import cho_solve, lu_solve

        kind, f = factor
        if kind == "cholesky":
            return cho_solve(f, b, check_finite=False)
        if kind == "lu":
            return lu_solve(f, b, check_finite=False)
        return np.linalg.lstsq(f, b, rcond=None)[0]

    def solve(self, q: np.ndarray, guess: np.ndarray | None = None, rows=None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(x, w, active)`` of the LCP in ``A[rows][:, rows]`` (all rows when None)."""
        A, n = self.matrix, q.size
        full = rows is None or rows is ALL
        if n == 1:  # the common case of one contact row, in closed form
            q0 = float(q[0])
            j = 0 if full else int(rows[0])
            x = -q0 / float(A[j, j]) if q0 < 0.0 else 0.0
            return np.array([x]), np.array([0.0 if x > 0.0 else q0]), np.array([x > 0.0])
        idx = np.arange(n) if full else np.asarray(rows)
        active = np.zeros(n, dtype=bool) if guess is None else np.array(guess, dtype=bool)
        if n == 0 or (not active.any() and np.all(q >= 0.0)):
            return np.zeros(n), q.copy(), np.zeros(n, dtype=bool)
        tol = 1e-13 * max(np.abs(q).max(), TINY)
        best, retries = n + 1, self.RETRIES
        for _ in range(4 * n + 10):
            x = np.zeros(n)
            if active.any():
                x[active] = self._apply(self._factor(idx[active]), -q[active])
            w = np.zeros(n)
            free = ~active
            if free.all():
                w[:] = q
            elif free.any():   # w on the inactive rows only (zero on the active ones by construction)
                G = idx[free]
                if not full:
                    w[free] = A[G][:, idx].dot(x) + q[free]
                elif 2 * G.size >= n:
                    w[free] = A.dot(x)[free] + q[free]     # a product, no copy of A
                else:
                    w[free] = A[G].dot(x) + q[free]        # a copy of the few rows
            xtol = 1e-13 * max(np.abs(x).max(), TINY)
            wrong = (active & (x < -xtol)) | (free & (w < -tol))
            count = int(np.count_nonzero(wrong))
            if not count:
                return np.maximum(x, 0.0), np.maximum(w, 0.0), active
            if count < best:
                best, retries = count, self.RETRIES
                active ^= wrong
            elif retries > 0:
                retries -= 1
                active ^= wrong
            else:   # Murty's least-index step: finite for P-matrices
                j = int(np.argmax(wrong))
                active[j] = not active[j]
        # Pivoting is finite for P-matrices but may take many steps (and round-off can make it
        # cycle on ill-conditioned ones): fall back on the equivalent convex problem.
        return _lcp_as_nnls(A if full else A[np.ix_(idx, idx)], q)


def solve_lcp(
    A: np.ndarray, q: np.ndarray, guess: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve ``w = A x + q >= 0, x >= 0, x . w = 0`` exactly (once; see ``Delassus`` for many).

    ``A`` is a ``Delassus`` (its kept factors are used) or a matrix. ``guess`` is the active set
    (x > 0) to start from, usually the previous step's, so a persisting contact state costs one
    small solve. Returns ``(x, w, active)``.
    """
    return (A if isinstance(A, Delassus) else Delassus(A)).solve(q, guess)


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

