"""The mechanical system the integrators step: ``M U'' + C U' + K U + P^T lam = R(t)``, ``P U <= d(t)``.

``Operators`` holds its matrices, loads and contact rows, with nothing of meshes (a 1-dof system
or a finite-element model alike), and the Delassus matrix ``W = P A^-1 P^T`` of a factorized step
matrix ``A`` with the corrections ``y -= A^-1 P^T c`` (``Columns`` and its kin).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from scipy import sparse
from scipy.linalg.blas import daxpy, dgemv

from ..linalg.backends import DenseAlgebra, PETScAlgebra
from ..linalg.dense import axpy, permuted_in_place
from ..linalg.factor import DiagonalFactor

if TYPE_CHECKING:   # (the contact layer sits above: an integrator builds the laws when none are given)
    from ..nonsmooth.laws import RowLaws

DENSE_BLOCK = 4096  # entries: up to this size the block of P on the dofs it touches is kept dense
KEEP_COLUMNS = 1 << 22   # entries (N x p, 32 MB): up to this size S^-1 P^T is stored; above, applied by a solve
# contact rows: from these on (serial MUMPS), W from selected entries of A^-1, or from the inverse of A's
# Schur complement on the rows' dofs where A is factorized keeping them out (linalg/condensed.py)
INVERSE_ENTRIES_FROM = 64
REACH_BLOCK_BYTES = 2 ** 30   # the inverse's block kept for rows found again (a 3D face of 1681 nodes a side: 0.8 GB)
RHS_BLOCK = 256      # right-hand sides per multi-RHS solve (fewer on large models: N x block <= RHS_ENTRIES)
RHS_ENTRIES = 1 << 25


class TimeDependentLoad(Protocol):
    time_dependent: bool

    def evaluate(self, t: float, out: np.ndarray) -> np.ndarray: ...


class StaticPart(Protocol):
    """A massless, quasi-static part of the displacement, ``U_s = S_k (R(t) - P^T lam)``.

    The reduced model's residual flexibility (docs/theory.md s. 8.2): the contact rows see
    ``P U = P U_dyn + offset(t) - compliance lam``, so the contact becomes compliant; the
    energy of U_s and the work of the loads on it enter the energy budget.
    """

    compliance: np.ndarray     # P S_k P^T (p x p)
    rigid_rows: np.ndarray     # rows without compliance (they get Carnot's impact correction)

    def offset(self, t: float) -> np.ndarray: ...                      # P S_k R(t)

    def energy(self, t: float, force: np.ndarray) -> float: ...        # 1/2 f^T S_k f

    def work(self, t0: float, t1: float, f0: np.ndarray, f1: np.ndarray, gamma: float) -> float: ...


@dataclass
class Operators:
    """Plain operators of ``M U'' + C U' + K U + P^T lam = R(t)``, ``P U <= d0``.

    ``M``, ``K``, ``C`` (or None) are distributed PETSc matrices (a finite-element model) or
    numpy arrays (a small replicated system; 1D = diagonal); the algebra follows from their
    type. ``P_local`` holds the owned rows of ``P^T`` (n_local x p, sparse or dense); the
    p-vectors ``d0`` and ``restitution`` are known on every rank. ``massless`` lists the owned
    dofs without mass (mass redistribution): their rows of M are zero. ``stop_compliance``
    (p-vector, m/N, or None: all rigid) makes a row an elastic stop: the gap condition becomes
    ``d0 - P U + c lam >= 0``, a massless spring in series. ``laws`` (a ``RowLaws``, or None: Newton's
    law with ``restitution`` and elastic stops with ``stop_compliance``) are the rows' contact laws,
    from which those arrays and ``friction`` then follow. Nothing here knows
    about meshes, so the integrators run as well on a 1-dof system as on a finite-element model.
    """

    M: PETSc.Mat | np.ndarray
    K: PETSc.Mat | np.ndarray
    C: PETSc.Mat | np.ndarray | None
    load: TimeDependentLoad
    P_local: sparse.spmatrix | np.ndarray
    d0: np.ndarray
    restitution: np.ndarray
    static: StaticPart | None = None
    massless: np.ndarray | None = None
    stop_compliance: np.ndarray | None = None
    # Coulomb friction: mu per row (None: frictionless), the owned rows of P_T^T (n_local x pt) and
    # the normal row of each tangent row (fem_impact.nonsmooth.relation.Constraints).
    friction: np.ndarray | None = None
    tangents: sparse.spmatrix | np.ndarray | None = None
    tangent_of: np.ndarray | None = None
    laws: RowLaws | None = None   # (an integrator makes it from the arrays when None: ContactScheme)
    # The rows' relations (a ``Relations``: their obstacles' positions ``d(t)`` and rates), or None:
    # every obstacle fixed at ``d0``.
    relations: object | None = None
    # Owned dofs that new rows may touch beyond the present ones (a surface contact's nodes and
    # surface, where the run finds its rows again as they slide; build.full_system), else None: W and D
    # come from the inverse's blocks on all of them, built at setup and kept (_inverse_block).
    reach: np.ndarray | None = None

    def __post_init__(self):
        self.algebra = PETScAlgebra(self.K) if isinstance(self.K, PETSc.Mat) else DenseAlgebra(self.K)
        self.comm: MPI.Comm = self.algebra.comm
        self._index_rows()

    def replace_rows(self, P_local, d0: np.ndarray, tangents=None) -> None:
        """New rows of the same count (a surface contact's search as its bodies slide): ``P_local``,
        the gaps ``d0`` (written into the array the relations share) and the tangent rows."""
        self.P_local = P_local
        self.d0[:] = d0
        if tangents is not None:
            self.tangents = tangents
        self._index_rows()

    def _index_rows(self) -> None:
        self.P_local = sparse.csr_matrix(self.P_local)
        self._P = self.P_local.T.tocsr()  # owned columns of P
        # P on the owned dofs it touches (a few per row; every coordinate of a replicated small
        # system): P x and P^T lam read and write only those, by one small product (dense while
        # small, where it is faster than a sparse one).
        self._dofs = np.unique(self._P.indices) if self.algebra.distributed else slice(None)
        if self.algebra.distributed and self._dofs.size and self._dofs[-1] - self._dofs[0] < 2 * self._dofs.size:
            self._dofs = slice(int(self._dofs[0]), int(self._dofs[-1]) + 1)   # nearly contiguous: views, not copies
        block = self._P[:, self._dofs]
        dense = not self.algebra.distributed or block.shape[0] * block.shape[1] <= DENSE_BLOCK
        self._P_block = block.toarray() if dense else block
        self._Pt_block = self._P_block.T
        if self.massless is None:
            self.massless = np.zeros(0, dtype=np.int64)
        if self.laws is not None:
            self.restitution, self.stop_compliance = self.laws.restitution, self.laws.compliance
            if self.friction is None and self.tangent_of is not None:
                self.friction = self.laws.friction
        if self.stop_compliance is None:
            self.stop_compliance = np.zeros(self.p)
        # Rows of P that touch a dof without mass: no velocity jump there, so no Carnot correction.
        touches = np.zeros(self.P_local.shape[0])
        touches[self.massless] = 1.0
        self.massless_rows = self.algebra.allsum(np.asarray(abs(self.P_local).T @ touches, dtype=float)) > 0.0

    @property
    def p(self) -> int:
        return self.d0.size

    @property
    def moving(self) -> bool:
        """Whether an obstacle of the rows moves (a time-dependent relation)."""
        return self.relations is not None and self.relations.time_dependent

    def gap0(self, t: float) -> np.ndarray:
        """``d(t)``: the rows' gaps at zero displacement at time t (``d0`` itself when nothing moves)."""
        return self.relations.gap(t) if self.moving else self.d0

    def d_rate(self, t: float) -> np.ndarray:
        """``d'(t)``: how fast each row's obstacle recedes along its normal (zeros when nothing moves)."""
        return self.relations.gap_velocity(t) if self.moving else np.zeros(self.p)

    def relative(self, pv: np.ndarray, t: float) -> np.ndarray:
        """The rows' normal velocities relative to their obstacles, ``P V - d'(t)`` (``pv`` itself
        when nothing moves): what the impact laws act on."""
        return pv - self.relations.gap_velocity(t) if self.moving else pv

    def relative_acceleration(self, pa: np.ndarray, t: float) -> np.ndarray:
        """The rows' normal accelerations relative to their obstacles, ``P A - d''(t)`` (``pa``
        itself when nothing moves): what a closed row's acceleration condition is on."""
        return pa - self.relations.gap_acceleration(t) if self.moving else pa

    def relative_tangent(self, pt: np.ndarray, t: float) -> np.ndarray:
        """The tangent rows' velocities relative to their obstacles (``pt`` itself when nothing
        moves): what Coulomb's law acts on."""
        return pt - self.relations.tangent_velocity(t) if self.moving else pt

    def obstacle_tangent_velocity(self, t: float) -> np.ndarray:
        """The obstacles' velocities along the tangent rows (zeros when nothing moves)."""
        return self.relations.tangent_velocity(t) if self.moving else np.zeros(self.pt)

    def obstacle_moved(self, t0: float, t1: float) -> np.ndarray | None:
        """How far each row's obstacle receded over ``[t0, t1]``, ``d(t1) - d(t0)``, or None when
        nothing moves (the obstacles then do no work)."""
        return self.relations.gap(t1) - self.relations.gap(t0) if self.moving else None

    @property
    def pt(self) -> int:
        """Tangent rows (rows with friction, times 1 in 2D, 2 in 3D)."""
        return 0 if self.tangent_of is None else self.tangent_of.size

    def with_tangents(self) -> Operators:
        """The same system with the rows ``[P; P_T]``: normal rows first, then the tangent rows (its
        ``project_many``, ``subtract_transpose`` and ``delassus`` act on all of them)."""
        p_all = self.p + self.pt
        rows = Operators(self.M, self.K, self.C, self.load,
                         sparse.hstack([sparse.csr_matrix(self.P_local), sparse.csr_matrix(self.tangents)]).tocsr(),
                         np.zeros(p_all), np.zeros(p_all), massless=self.massless)
        rows.algebra = self.algebra   # one algebra: its vectors are the ones the factors solve with
        return rows

    def tangent_rows(self) -> Operators:
        """The same system with the tangent rows ``P_T`` alone (the stick correction's)."""
        rows = Operators(self.M, self.K, self.C, self.load, sparse.csr_matrix(self.tangents),
                         np.zeros(self.pt), np.zeros(self.pt), massless=self.massless)
        rows.algebra = self.algebra
        return rows

    def project(self, local) -> np.ndarray:
        """``P x`` (or ``P X`` for a block of columns, dense or sparse) from owned entries: one global sum."""
        product = self._P @ local
        return self.algebra.allsum(np.ascontiguousarray(product.toarray() if sparse.issparse(product) else product))

    def project_many(self, *arrays: np.ndarray) -> list[np.ndarray]:
        """``P x`` for several vectors with a single reduction."""
        block, dofs = self._P_block, self._dofs
        parts = [block.dot(x[dofs]) for x in arrays]
        if self.comm.size > 1:
            p = self.p
            stacked = self.algebra.allsum(np.concatenate(parts))
            parts = [stacked[k * p:(k + 1) * p] for k in range(len(arrays))]
        return parts

    def subtract_transpose(self, y: np.ndarray, lam: np.ndarray) -> None:
        """``y -= P^T lam`` on the owned entries, in place (only the dofs that P touches)."""
        y[self._dofs] -= self._Pt_block.dot(lam)

    def mass_for_solves(self):
        """M, with a unit diagonal on the massless dofs so that it can be factorized.

        (Only a finite-element model has massless dofs: the case refuses mass redistribution
        for the reduced model.)
        """
        if not self.algebra.distributed or not self.comm.allreduce(self.massless.size, op=MPI.SUM):
            return self.M
        M = self.M.copy()
        first = self.M.getOwnershipRange()[0]
        M.zeroRowsColumns((self.massless + first).astype(np.int32), diag=1.0)
        return M

    def equilibrate_massless(self, U: np.ndarray, R: np.ndarray) -> float:
        """Move the massless dofs of ``U`` to their static equilibrium ``(K U)_c = R_c``, in place.

        Without mass they follow the rest of the structure instantly: an initial state that
        does not satisfy this (a stressed free end) would snap in the first step, with an
        energy change no term of the budget books. Returns the largest move.
        """
        alg = self.algebra
        if not alg.distributed or not self.comm.allreduce(self.massless.size, op=MPI.SUM):
            return 0.0
        first = self.K.getOwnershipRange()[0]
        massive = np.setdiff1d(np.arange(alg.sizes[0]), self.massless)
        Q = self.K.copy()
        Q.zeroRows((massive + first).astype(np.int32), diag=1.0)   # massive rows: U_j = U_j (kept)
        b, x = alg.vector(), alg.vector()
        b[:] = R
        b[massive] = U[massive]
        alg.factorize(Q)(b, x)
        move = self.comm.allreduce(float(np.max(np.abs(x - U), initial=0.0)), op=MPI.MAX)
        U[:] = x
        return move

    def solve_columns(self, solve) -> np.ndarray:
        """``A^-1 P^T`` (owned rows, n_local x p) for a factorized ``A``: p solves, once per run."""
        if hasattr(solve, "many"):
            return solve.many(self.P_local.toarray())
        b, x = self.algebra.vector(), self.algebra.vector()
        out = np.empty(self.P_local.shape)
        for j in range(self.p):
            b[:] = self._P[j].toarray().ravel()
            solve(b, x)
            out[:, j] = x
        return out

    def delassus(self, solve, diagonal: bool = False, norm: float | None = None
                 ) -> tuple[np.ndarray, Columns | SolvedColumns] | tuple[np.ndarray, Columns | SolvedColumns, np.ndarray]:
        """``W = P A^-1 P^T`` (p x p, on every rank) and the correction ``y -= A^-1 P^T c``; with ``norm``
        (``||A||_inf``) also the round-off bound of W's entries, s (p) with ``|dW_ij| <= s_i s_j``.

        W from solves: ``A (x_j + dx_j) = p_j + r_j`` with ``|r_j| <= c EPS ||A|| |x_j|`` (a backward-
        stable direct solve) gives ``dW_ij = x_i . r_j``: ``s_j = sqrt(EPS ||A||) |x_j|`` (``c`` in the
        margin of whoever judges it: friction.symmetrize). W from entries of ``A^-1`` (MUMPS, the
        Schur complement), where no x_j is formed: ``s_i = sqrt(EPS kappa) (|P| sqrt(diag A^-1))_i``
        with ``kappa = 2 k_i + ||A|| max diag A^-1`` (k_i the dofs of row i: the products with P; the
        second term, at most A's condition number, for the entries' own round-off).

        ``diagonal``: when ``A`` is diagonal (a lumped mass) and no dof is touched by two rows
        (node-to-plane rows, no friction), W is diagonal, ``W_jj = sum_k P_jk^2 / A_kk``: it is
        returned as a sparse diagonal, with corrections on P's dofs alone (``DiagonalColumns``).
        Nothing of size p x p or N x p: a face of 10^4 rows costs a p-vector.

        ``A^-1 P^T`` is computed in blocks of columns (multi-RHS solves with the factor), so
        that memory stays N x block; it is kept (``Columns``) only while N x p is small
        (``KEEP_COLUMNS``), else the correction is a solve with the factor (``SolvedColumns``).
        The choice depends on global sizes only, so every rank makes the same (solves are
        collective).
        """
        if diagonal and norm is None:
            found = self._diagonal_delassus(solve)
            if found is not None:
                return found
        p, N = self.p, self.algebra.sizes[1]
        eps = np.finfo(float).eps
        sizes = np.zeros(p)   # |x_j|^2, summed over the ranks' rows

        def found(W, columns):
            if norm is None:
                return W, columns
            return W, columns, np.sqrt(eps * norm * self.algebra.allsum(sizes))

        if self._keeps_columns():
            X = self.solve_columns(solve)
            sizes = np.einsum("ij,ij->j", X, X) if norm is not None else sizes
            return found(self.project(X), Columns(X))
        # Serial MUMPS: (A^-1) on the dofs P touches, as the inverse of A's Schur complement on them
        # (a CondensedFactor) or selected entries of the inverse.
        dofs = np.unique(self._P.indices)
        if p >= INVERSE_ENTRIES_FROM and hasattr(solve, "inverse_block"):
            block, where = self._inverse_block(solve, dofs)
            if block is not None:
                Pd = sparse.csr_matrix(self._P[:, dofs])   # (a few entries a row: two products of p m nnz)
                if where is not None:   # (the block kept for rows found again: P on its dofs, the block shared)
                    Pd = sparse.csr_matrix((Pd.data, where[Pd.indices], Pd.indptr), shape=(p, block.shape[0]))
                scale = None
                if norm is not None:   # (serial: the entries' bound needs no sum over ranks)
                    diag = np.abs(np.diagonal(block))
                    condition = 2.0 * np.diff(Pd.indptr) + norm * diag.max(initial=0.0)
                    scale = np.sqrt(eps * condition) * (abs(Pd) @ np.sqrt(diag))
                finish = (lambda W: (W, SolvedColumns(self, solve))) if norm is None else \
                    (lambda W: (W, SolvedColumns(self, solve), scale))
                if where is None and Pd.shape[0] == Pd.shape[1] and np.all(np.diff(Pd.indptr) == 1) and \
                        np.unique(Pd.indices).size == Pd.shape[1]:
                    # One dof a row, each dof once (normals and tangents along axes): W is the block
                    # permuted and signed, in its own memory (no second copy of the largest array).
                    W = permuted_in_place(block, Pd.indices)
                    W *= Pd.data[:, None]
                    W *= Pd.data[None, :]
                    return finish(W)
                return finish(np.asarray(Pd @ np.asarray(Pd @ block).T))
        W = np.empty((p, p))
        block = max(16, min(RHS_BLOCK, RHS_ENTRIES // max(N, 1)))
        for j0 in range(0, p, block):
            j1 = min(p, j0 + block)
            X = solve.many(self.P_local[:, j0:j1].toarray())
            W[:, j0:j1] = self.project(X)
            if norm is not None:
                sizes[j0:j1] = np.einsum("ij,ij->j", X, X)
        return found(W, SolvedColumns(self, solve))

    def _inverse_block(self, solve, dofs: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """``(block, where)``: ``(A^-1)[dofs][:, dofs]`` as a new array (``where`` None), or, where new rows
        may come (``reach``: a surface contact found again as its bodies slide), the block on every dof
        they may touch, kept with the factor and shared (read only), ``where`` the positions of
        ``dofs`` in it: the rows found again take W from it by two sparse products, without the factor
        (its memory bounded by ``REACH_BLOCK_BYTES``)."""
        kept = getattr(solve, "_reach_block", None)
        if kept is not None:
            where = np.minimum(np.searchsorted(kept[0], dofs), kept[0].size - 1)
            if np.array_equal(kept[0][where], dofs):
                return kept[1], where
        if self.reach is not None:
            every = np.union1d(dofs, self.reach)
            if 8 * every.size ** 2 <= REACH_BLOCK_BYTES:
                block = solve.inverse_block(every)
                if block is not None:
                    solve._reach_block = (every, block)
                    return block, np.searchsorted(every, dofs)
        return solve.inverse_block(dofs), None

    def _keeps_columns(self) -> bool:
        """Whether ``delassus`` stores ``A^-1 P^T`` (few rows, or a small replicated system)."""
        return self.algebra.sizes[1] * self.p <= KEEP_COLUMNS or not self.algebra.distributed

    def condensed_dofs(self) -> np.ndarray | None:
        """The dofs of the rows, and of the tangent rows if any, where ``delassus`` is to take W from a
        block of ``A^-1`` (a serial model, from ``INVERSE_ENTRIES_FROM`` rows, too many to store
        ``A^-1 P^T``): the factorization of the step matrix may keep them out (``CondensedFactor``),
        with the dofs of rows found again (``reach``), so that the steps after a search solve the
        same way. Else None."""
        rows = self.with_tangents() if self.pt else self
        if self.comm.size > 1 or rows.p < INVERSE_ENTRIES_FROM or rows._keeps_columns():
            return None
        dofs = np.unique(rows._P.indices)
        if self.reach is not None:   # (and those of rows found again, where their block is kept: _inverse_block)
            every = np.union1d(dofs, self.reach)
            if 8 * every.size ** 2 <= REACH_BLOCK_BYTES:
                return every
        return dofs

    def _diagonal_delassus(self, solve) -> tuple[sparse.csr_matrix, DiagonalColumns] | None:
        if not isinstance(solve, DiagonalFactor) or not self.algebra.distributed:
            return None
        P = self.P_local.copy()
        P.eliminate_zeros()
        one_row_a_dof = bool(np.all(np.diff(P.indptr) <= 1))
        if not self.comm.allreduce(one_row_a_dof, op=MPI.LAND):
            return None
        w = self.algebra.allsum(np.asarray(P.multiply(P).T @ solve.inverse, dtype=float).ravel())
        return sparse.diags(w, format="csr"), DiagonalColumns(self, solve.inverse)


class DiagonalColumns:
    """``X = A^-1 P^T`` for a diagonal ``A``: the corrections ``y -= X c`` touch P's dofs alone."""

    def __init__(self, ops: Operators, inverse: np.ndarray):
        self.dofs, self.Pt = ops._dofs, ops._Pt_block
        self.scale = np.ascontiguousarray(inverse[ops._dofs])

    def subtract_from(self, y: np.ndarray, c: np.ndarray) -> None:
        y[self.dofs] -= self.scale * self.Pt.dot(c)


class Columns:
    """A tall block ``X = A^-1 P^T`` (owned rows, n_local x p) for the corrections ``y -= X c``.

    Its columns decay away from the contact dofs, in a long model down to exact zeros: it is kept
    on the range of rows where it is nonzero, and a correction touches only that range, with the
    same result.
    """

    def __init__(self, X: np.ndarray):
        nonzero = np.flatnonzero(X.any(axis=1))
        self.rows = slice(int(nonzero[0]), int(nonzero[-1]) + 1) if nonzero.size else slice(0, 0)
        self.X = np.ascontiguousarray(X[self.rows])

    def subtract_from(self, y: np.ndarray, c: np.ndarray) -> None:
        """``y -= X c``, in place, in one pass (BLAS)."""
        y, X = y[self.rows], self.X
        if not y.size:
            return
        if X.shape[1] == 1:   # one contact row: a contiguous column, an axpy
            daxpy(X[:, 0], y, a=-c[0])
        else:
            dgemv(-1.0, X.T, c, beta=1.0, y=y, overwrite_y=1, trans=1)


class SolvedColumns:
    """``X = A^-1 P^T`` never formed: the corrections ``y -= X c`` are one solve with A's factor
    each (for many contact rows, where N x p would not fit or cost more than the solve)."""

    def __init__(self, ops: Operators, solve):
        self.ops, self.solve = ops, solve
        self.b, self.x = ops.algebra.vector(), ops.algebra.vector()

    def subtract_from(self, y: np.ndarray, c: np.ndarray) -> None:
        """``y -= A^-1 P^T c``, in place (collective: every rank calls it)."""
        b = self.b
        b.fill(0.0)
        self.ops.subtract_transpose(b, -c)
        self.solve(b, self.x)
        axpy(y, -1.0, self.x)
