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
    triangular solves and no factorization; a large active set that differs from a factored one
    by a few rows is solved through that factor (``UpdatedFactor``), not factorized again.
    Round-off cycling on an ill-conditioned matrix ends in the equivalent convex problem
    (``_lcp_as_nnls``).

    ``solve(q, guess, rows)`` solves the LCP on the principal submatrix ``A[rows][:, rows]``
    (``rows`` sorted indices, or all), sharing the factors: Carnot's correction solves on the
    closed rows of ``D`` this way. ``A @ x`` as ``dot``; the matrix itself as ``matrix``.
    """

    RETRIES = 3
    KEEP = 4
    # A set of at least UPDATE_FROM rows that differs from a solved one (a base: the last BASES
    # factorized, the last BASES updated) by at most 1/UPDATE_SHARE of its rows is solved through the
    # base: its update costs a solve a row that differs, where a factorization costs about a third of
    # the set's size in solves. An update of an update adds a level (DEPTH at most): the active sets
    # of successive steps differ by a few rows, each from the last, and by many from a factorized one.
    UPDATE_FROM = 256
    UPDATE_SHARE = 32
    BASES = 2
    DEPTH = 4

    def __init__(self, A: np.ndarray, symmetric: bool | None = None):
        self.matrix = np.ascontiguousarray(A, dtype=float)
        if symmetric is None:
            symmetric = _is_symmetric(self.matrix) if self.matrix.size else True
        self.symmetric = symmetric
        self._factors: dict[bytes, tuple] = {}
        self._bases: list[CholeskyFactor] = []          # sets factorized, the last BASES
        self._updates: list[UpdatedFactor] = []         # and updated, the last BASES

    @classmethod
    def regularized(cls, A: np.ndarray, relative: float = 1e-10) -> Delassus:
        """The solver of ``regularized(A)``; on a large matrix the Cholesky factor that shows it
        regular is kept as the factor of the all-active block (a contact of every row)."""
        matrix, factor = _regularized(A, relative)
        solver = cls(matrix, symmetric=True if factor is not None else None)   # (a factor: found symmetric)
        if factor is not None:
            every = np.arange(A.shape[0])
            solver._factors[every.tobytes()] = ("cholesky", (factor, True))
            solver._bases.append(CholeskyFactor(every, (factor, True)))
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
        factor = self._updated(F) if self.symmetric and F.size >= self.UPDATE_FROM else None
        if factor is not None:
            self._updates = self._updates[1 - self.BASES:] + [factor[1]]
            self._keep(key, factor)
            return factor
        block = A if F.size == A.shape[0] else A[np.ix_(F, F)]
        if self.symmetric:
            try:
                factor = ("cholesky", cho_factor(block, lower=True, check_finite=False))
            except np.linalg.LinAlgError:
                factor = None
            if factor is not None and F.size >= self.UPDATE_FROM:
                self._bases = self._bases[1 - self.BASES:] + [CholeskyFactor(F.copy(), factor[1])]
        if factor is None:
            if np.linalg.matrix_rank(block) < F.size:
                factor = ("lstsq", block.copy())
            else:
                factor = ("lu", lu_factor(block, check_finite=False))
        self._keep(key, factor)
        return factor

    def _keep(self, key: bytes, factor: tuple) -> None:
        if len(self._factors) >= self.KEEP:
            self._factors.pop(next(iter(self._factors)))
        self._factors[key] = factor

    def _updated(self, F: np.ndarray) -> tuple | None:
        """``("updated", UpdatedFactor)`` for the rows ``F`` from the base nearest them (fewest rows
        that differ, then fewest levels), if one is near enough (``UPDATE_SHARE``); else None."""
        best, near = None, (max(1, F.size // self.UPDATE_SHARE), self.DEPTH)
        for base in self._bases + [u for u in self._updates if u.depth < self.DEPTH]:
            differ = base.rows.size + F.size - 2 * np.intersect1d(base.rows, F, assume_unique=True).size
            if (differ, base.depth) <= near:
                best, near = base, (differ, base.depth)
        if best is None:
            return None
        try:
            return "updated", UpdatedFactor(self.matrix, best, F)
        except np.linalg.LinAlgError:   # (a complement not positive definite to round-off: factorize)
            return None

    @staticmethod
    def _apply(factor, b: np.ndarray) -> np.ndarray:
        from scipy.linalg import cho_solve, lu_solve

        kind, f = factor
        if kind == "cholesky":
            return cho_solve(f, b, check_finite=False)
        if kind == "updated":
            return f.solve(b)
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


class CholeskyFactor:
    """``A[rows][:, rows]^-1`` by its Cholesky factor (scipy's ``cho_factor`` pair): a base of
    ``UpdatedFactor``."""

    depth = 0

    def __init__(self, rows: np.ndarray, factor: tuple):
        self.rows, self.factor = rows, factor

    def solve(self, b: np.ndarray) -> np.ndarray:
        from scipy.linalg import cho_solve

        return cho_solve(self.factor, b, check_finite=False)


class UpdatedFactor:
    """``A[F][:, F]^-1`` for a symmetric positive definite ``A`` through a solver of ``A[F0][:, F0]``
    (``base``: a ``CholeskyFactor``, or an ``UpdatedFactor`` itself, one level deeper), ``F`` a set
    near ``F0`` (sorted row indices both). On ``U = F0 + added`` (the rows of F not in F0), A's
    block is solved by bordering: the added rows' Schur complement ``S = A_aa - B^T A_00^-1 B``
    (``B = A[F0, added]``). The removed rows ``r`` (of F0, not in F) are then held at zero by as
    many unknowns ``c`` on their equations: with ``Z = A_UU^-1 E_r``, ``y = A_UU^-1 b - Z Z_rr^-1
    (A_UU^-1 b)_r`` is zero on r and solves ``A_FF y_F = b`` (Z_rr, a principal block of an SPD
    inverse, is SPD). To build: a solve with the base a row that differs; to apply: one solve with
    the base and products with the n x k arrays."""

    def __init__(self, A: np.ndarray, base, F: np.ndarray):
        from scipy.linalg import cho_factor, cho_solve

        self._cho_solve = cho_solve
        F0 = base.rows
        self.rows, self.depth = F, base.depth + 1
        added = np.setdiff1d(F, F0, assume_unique=True)
        removed = np.flatnonzero(~np.isin(F0, F, assume_unique=True))   # (positions in F0, and in U)
        self.base, self.n0, self.added = base, F0.size, added.size
        if added.size:
            self.B = A[np.ix_(F0, added)]
            self.Y = base.solve(self.B)                                     # A_00^-1 B
            self.S = cho_factor(A[np.ix_(added, added)] - self.B.T @ self.Y, lower=True, check_finite=False)
        U = np.concatenate([F0, added])
        order = np.argsort(U, kind="stable")
        self.where = order[np.searchsorted(U[order], F)]   # F's rows' positions in U
        self.removed = removed
        if removed.size:
            E = np.zeros((U.size, removed.size))
            E[removed, np.arange(removed.size)] = 1.0
            self.Z = self._solve_u(E)
            self.Zrr = cho_factor(self.Z[removed], lower=True, check_finite=False)

    def _solve_u(self, r: np.ndarray) -> np.ndarray:
        """``A_UU^-1 r`` (U: the base's rows, then the added ones)."""
        y = np.array(r, dtype=float)
        y[:self.n0] = self.base.solve(y[:self.n0])
        if self.added:
            ya = self._cho_solve(self.S, y[self.n0:] - self.B.T @ y[:self.n0], check_finite=False)
            y[:self.n0] -= self.Y @ ya
            y[self.n0:] = ya
        return y

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``A[F][:, F]^-1 b`` (b: F.size, or F.size x k)."""
        r = np.zeros((self.n0 + self.added,) + b.shape[1:])
        r[self.where] = b
        y = self._solve_u(r)
        if self.removed.size:
            y -= self.Z @ self._cho_solve(self.Zrr, y[self.removed], check_finite=False)
        return y[self.where]


def solve_lcp(
    A: np.ndarray, q: np.ndarray, guess: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve ``w = A x + q >= 0, x >= 0, x . w = 0`` exactly (once; see ``Delassus`` for many).

    ``A`` is a ``Delassus`` (its kept factors are used) or a matrix. ``guess`` is the active set
    (x > 0) to start from, usually the previous step's, so a persisting contact state costs one
    small solve. Returns ``(x, w, active)``.
    """
    return (A if isinstance(A, Delassus) else Delassus(A)).solve(q, guess)


def compliant_forces(C: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The forces of rows held by a compliance alone, ``w = C x + q >= 0 _|_ x >= 0`` (a static part's rows
    at the start of a run). ``C`` is positive semi-definite, singular where fewer modes are truncated than
    there are rows: no force where no row is closed (``q >= 0``), and the smallest ones (``regularized``)
    where the plain solve finds ``C`` not positive definite."""
    if not np.any(q < 0.0):
        return np.zeros(q.size)
    try:
        return solve_lcp(C, q)[0]
    except ContactSolverError:
        return Delassus.regularized(C).solve(q)[0]


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

