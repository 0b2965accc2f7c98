"""What every integrator shares: the linear algebra it runs on, the operators, its state, the
energy budget and the time loop.

The integrators work on numpy arrays: the owned entries of distributed PETSc vectors for a
finite-element model (``PETScAlgebra``: each array is the memory of a PETSc ``Vec``, so
matrix products and solves go through PETSc without copies), or small replicated arrays for
the reduced model (``DenseAlgebra``: diagonal or dense matrices, numpy only). The same
integrator code runs on both; only products, solves and global sums differ.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from scipy import sparse
from scipy.linalg.blas import daxpy, dgemv

from ..errors import SimulationError
from ..parallel import allsum
from ..fem.petsc_api import mumps_inverse_block
from ..nonsmooth.lcp import permuted_in_place
from .condensed import CondensedFactor
from .parameters import steps_for   # (the one definition; integrators re-exports it)

BLOW_UP = 100.0  # kinetic + strain energy above this many times the energy put in: the run blew up
# Energy above E0 + W_ext (or a loss below zero) by more than this fraction of the energy scale: the
# scheme created it (round-off and a closed balance leave 1e-12 .. 1e-10).
ENERGY_TOLERANCE = 1e-6
DENSE_BLOCK = 4096  # entries: up to this size the block of P on the dofs it touches is kept dense
KEEP_COLUMNS = 1 << 22   # entries (N x p, 32 MB): up to this size S^-1 P^T is stored; above, applied by a solve
# contact rows: from these on (serial MUMPS), W from selected entries of A^-1, or from the inverse of A's
# Schur complement on the rows' dofs where A is factorized keeping them out (condensed.py)
INVERSE_ENTRIES_FROM = 64
MUMPS_FROM = 5000    # unknowns: serial systems from this size on with 3D fill (MUMPS_FILL entries a row
MUMPS_FILL = 30      # or more) are factorized by MUMPS (Cholesky if SPD); smaller or sparser ones by PETSc
RHS_BLOCK = 256      # right-hand sides per multi-RHS solve (fewer on large models: N x block <= RHS_ENTRIES)
RHS_ENTRIES = 1 << 25
OPTIONS_PREFIX = "fem_impact_"   # PETSc options of the direct solver, e.g. -fem_impact_pc_factor_mat_solver_type


class PETScAlgebra:
    """Distributed vectors as numpy arrays of their owned entries, each backed by a PETSc ``Vec``."""

    distributed = True

    def __init__(self, template: PETSc.Mat):
        self.comm: MPI.Comm = template.getComm().tompi4py()
        self._petsc_comm = template.getComm()
        self.sizes = template.getSizes()[0]   # (owned, global)
        self._vecs: dict[int, tuple[np.ndarray, PETSc.Vec]] = {}

    def vector(self) -> np.ndarray:
        array = np.zeros(self.sizes[0])
        vec = PETSc.Vec().createWithArray(array, size=self.sizes, comm=self._petsc_comm)
        self._vecs[id(array)] = (array, vec)   # keeps both alive; products look the Vec up by the array
        return array

    def _vec(self, array: np.ndarray) -> PETSc.Vec:
        return self._vecs[id(array)][1]

    def mult(self, A: PETSc.Mat, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out = A x`` (both arrays made by ``vector()``)."""
        A.mult(self._vec(x), self._vec(out))
        return out

    def combine(self, *terms) -> PETSc.Mat:
        """``sum c_i A_i`` over the terms (c, A) whose A is not None (patterns merged)."""
        # Start from the widest pattern: PETSc 3.18's MatAXPY that widens a matrix's pattern (a
        # lumped, diagonal M plus a damping C in 2D) leaves it with stale internals on which LU
        # then gives inf (a copy is sound again).
        nonzeros = lambda A: A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]   # (the same on every rank)
        terms = sorted(((c, A) for c, A in terms if A is not None), key=lambda term: -nonzeros(term[1]))
        (c0, A0), *rest = terms
        S = A0.copy()
        S.scale(c0)
        for c, A in rest:
            # Supports may have removed diagonal entries from one pattern: let PETSc merge them.
            S.axpy(c, A, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        if rest and nonzeros(S) > nonzeros(A0):
            S = S.copy()   # the pattern grew all the same
        return S

    def factorize(self, A: PETSc.Mat, spd: bool = False, kept: np.ndarray | None = None
                  ) -> Factor | CondensedFactor | DiagonalFactor:
        """A direct solver for ``A``, factorized now, once: ``solve(b, x)`` on arrays from ``vector()``,
        ``solve.many(B)`` on a block of columns. See ``factorize`` for the choice of solver; a
        diagonal ``A`` (a lumped mass) is inverted entry by entry on each rank, no factorization.
        ``kept``: the contact dofs whose block of ``A^-1`` W will take (``Operators.condensed_dofs``):
        an SPD ``A`` that MUMPS is to factorize is then factorized keeping them out, where that pays
        (``CondensedFactor``)."""
        if is_diagonal(A):
            return DiagonalFactor(A.getDiagonal().array_r.copy())
        if kept is not None and spd and _mumps_for(A) and not _solver_options():
            condensed = CondensedFactor.create(without_stored_zeros(A), kept)
            if condensed is not None:
                return condensed
        return Factor(_direct_solver(A, spd), self)

    def diagonal(self, A: PETSc.Mat) -> np.ndarray:
        return A.getDiagonal().array_r.copy()

    @staticmethod
    def norm(A: PETSc.Mat) -> float:
        """``||A||_inf``, the largest row sum of |A| (collective)."""
        return float(A.norm(PETSc.NormType.INFINITY))

    def row_sums(self, A: PETSc.Mat) -> np.ndarray:
        ones, sums = A.createVecs()
        ones.set(1.0)
        A.mult(ones, sums)
        return sums.array_r.copy()

    def allsum(self, local: np.ndarray) -> np.ndarray:
        """Sum over ranks, in place for a contiguous float64 array (one reduction)."""
        return allsum(self.comm, local)


class DenseAlgebra:
    """A small system replicated on every rank: matrices are numpy arrays, 1D for a diagonal."""

    distributed = False

    def __init__(self, template: np.ndarray):
        self.comm = MPI.COMM_SELF
        self.sizes = (template.shape[0], template.shape[0])

    def vector(self) -> np.ndarray:
        return np.zeros(self.sizes[0])

    @staticmethod
    def mult(A: np.ndarray, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        if A.ndim == 1:
            return np.multiply(A, x, out=out)
        return np.dot(A, x, out=out)

    @staticmethod
    def combine(*terms) -> np.ndarray:
        terms = [(c, A) for c, A in terms if A is not None]
        if all(A.ndim == 1 for _, A in terms):
            return sum(c * A for c, A in terms)
        return sum(c * (np.diag(A) if A.ndim == 1 else A) for c, A in terms)

    @staticmethod
    def factorize(A: np.ndarray, spd: bool = False, kept: np.ndarray | None = None) -> DenseFactor:
        return DenseFactor(A)

    @staticmethod
    def diagonal(A: np.ndarray) -> np.ndarray:
        return A.copy() if A.ndim == 1 else np.diag(A).copy()

    @staticmethod
    def norm(A: np.ndarray) -> float:
        """``||A||_inf``, the largest row sum of |A|."""
        return float(np.abs(A).max(initial=0.0) if A.ndim == 1 else np.abs(A).sum(axis=1).max(initial=0.0))

    @staticmethod
    def row_sums(A: np.ndarray) -> np.ndarray:
        return A.copy() if A.ndim == 1 else A.sum(axis=1)

    @staticmethod
    def allsum(local: np.ndarray) -> np.ndarray:
        return local


def factorize(A: PETSc.Mat, spd: bool = False) -> Callable[[PETSc.Vec, PETSc.Vec], None]:
    """A direct PETSc solver for ``A``, factorized now: ``solve(b, x)`` on PETSc vectors.

    Serial runs use PETSc's own sparse LU where its factor is cheap (1D and 2D models, small
    ones): its solves cost a fraction of MUMPS' there (a 1D bar of 10 000 cells: 0.04 ms
    against 7-12 ms, a 2D strip of 20 000 unknowns: 1.2 against 5-6 ms, measured). Parallel
    runs, and serial ones of 3D fill (``MUMPS_FILL`` entries a row) from ``MUMPS_FROM`` unknowns
    on, use MUMPS: as a Cholesky factorization when the caller knows ``A`` to be symmetric
    positive definite (a 45 000-unknown plate of hexahedra: 2 s against PETSc's LU 20 s, and
    multi-RHS solves at 6-9 ms a column against 60). PETSc's options with the prefix
    ``fem_impact_`` override the choice
    (``PETSC_OPTIONS="-fem_impact_pc_factor_mat_solver_type superlu_dist"``).
    """
    return _direct_solver(A, spd).solve


def _solver_options() -> list[tuple[str, str]]:
    """The user's PETSc options for the direct solver (``OPTIONS_PREFIX``), sorted."""
    return sorted((k, v) for k, v in PETSc.Options().getAll().items() if k.startswith(OPTIONS_PREFIX))


def direct_solver_settings() -> dict:
    """What decides the solver :func:`factorize` picks besides the matrix (for cache keys): the
    thresholds, whether PETSc has MUMPS, the user's options with the prefix, PETSc's version."""
    return {"mumps": PETSc.Sys.hasExternalPackage("mumps"), "mumps_from": MUMPS_FROM, "mumps_fill": MUMPS_FILL,
            "options": _solver_options(), "petsc": PETSc.Sys.getVersion()}


def _mumps_for(A: PETSc.Mat) -> bool:
    """Whether ``A`` goes to MUMPS: on several ranks, or serial with 3D fill from ``MUMPS_FROM`` unknowns."""
    n = A.getSize()[0]
    dense_fill = n >= MUMPS_FROM and A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"] >= MUMPS_FILL * n
    return PETSc.Sys.hasExternalPackage("mumps") and (A.getComm().getSize() > 1 or dense_fill)


def _direct_solver(A: PETSc.Mat, spd: bool) -> PETSc.KSP:
    comm = A.getComm()
    ksp = PETSc.KSP().create(comm)
    ksp.setOperators(A)
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    mumps = _mumps_for(A)
    if mumps:
        A = without_stored_zeros(A)
        ksp.setOperators(A)
    if mumps and spd:
        A.setOption(PETSc.Mat.Option.SPD, True)
        pc.setType(PETSc.PC.Type.CHOLESKY)
    else:
        pc.setType(PETSc.PC.Type.LU)
    if mumps:
        pc.setFactorSolverType("mumps")
    else:
        # PETSc's own LU takes a pivot below 1e-12 *absolute* for zero: a model in units far from 1 (a
        # step matrix of 1e-40) would stop there. Only an exact zero is one; a singular matrix then
        # shows as non-finite solves, which the contact problem and the energy watch report.
        pc.setFactorPivot(zeropivot=0.0)
    ksp.setOptionsPrefix(OPTIONS_PREFIX)
    ksp.setFromOptions()
    ksp.setUp()
    return ksp


# A share of stored zeros from which a factorization gets the matrix without them.
STORED_ZEROS = 0.25


def without_stored_zeros(A: PETSc.Mat) -> PETSc.Mat:
    """``A``, or a copy without its stored zeros when they are at least ``STORED_ZEROS`` of its entries.

    A vector space's matrices are assembled on 3 x 3 blocks per node pair; a mass matrix has no
    coupling between components, so two thirds of its entries are stored zeros. MUMPS orders and
    factorizes the pattern it is given: without them it sees three decoupled components (the
    1681-row plate's M: factorization 1.45 s -> 0.58 s, its inverse on the face 3.62 s -> 0.78 s;
    the same values to 5e-16). (The diagonal is kept: a factorization needs every pivot.)
    """
    indptr, indices, values = A.getValuesCSR()
    first = A.getOwnershipRange()[0]
    rows = np.repeat(np.arange(first, first + indptr.size - 1), np.diff(indptr))
    keep = (values != 0.0) | (indices == rows)
    stored_zeros = values.size - np.count_nonzero(keep)
    comm = A.getComm().tompi4py()
    if comm.allreduce(stored_zeros) < STORED_ZEROS * comm.allreduce(values.size):
        return A
    counts = np.bincount(rows[keep] - first, minlength=indptr.size - 1)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(PETSc.IntType)
    B = PETSc.Mat().createAIJ(size=A.getSizes(), csr=(offsets, indices[keep].astype(PETSc.IntType), values[keep]),
                              comm=A.getComm())
    B.assemble()
    return B


class Factor:
    """A factorized PETSc matrix on the arrays of a ``PETScAlgebra``: ``solve(b, x)``, and
    ``many(B)`` for a block of columns (owned rows, n_local x k) in one multi-RHS solve."""

    def __init__(self, ksp: PETSc.KSP, algebra: PETScAlgebra):
        self.ksp, self.algebra = ksp, algebra
        self._solve, self._vec = ksp.solve, algebra._vec

    def __call__(self, b: np.ndarray, x: np.ndarray) -> None:
        self._solve(self._vec(b), self._vec(x))

    def inverse_block(self, dofs: np.ndarray) -> np.ndarray | None:
        """``(A^-1)[dofs][:, dofs]`` from a serial MUMPS factor (its selected inverse entries), else None."""
        try:
            F = self.ksp.getPC().getFactorMatrix()
        except PETSc.Error:
            return None
        return mumps_inverse_block(F, dofs)

    def many(self, B: np.ndarray) -> np.ndarray:
        """``A^-1 B`` for the owned rows ``B`` (n_local x k)."""
        alg = self.algebra
        n, k = alg.sizes, B.shape[1]
        if k == 0:   # (no contact rows: MUMPS refuses a solve with no right-hand side under MPI)
            return np.zeros(B.shape)
        pc = self.ksp.getPC()
        try:
            F = pc.getFactorMatrix()
        except PETSc.Error:   # not a direct solver (chosen by options): column by column
            F = None
        if F is None or pc.getType() not in (PETSc.PC.Type.LU, PETSc.PC.Type.CHOLESKY):
            X = np.empty_like(B)
            b, x = alg.vector(), alg.vector()
            for j in range(k):
                b[:] = B[:, j]
                self(b, x)
                X[:, j] = x
            return X
        comm = alg._petsc_comm
        Bm = PETSc.Mat().createDense((n, (PETSc.DECIDE, k)), array=np.asfortranarray(B), comm=comm)
        Xm = PETSc.Mat().createDense((n, (PETSc.DECIDE, k)), comm=comm)
        Xm.setUp()
        Bm.assemble()
        Xm.assemble()
        F.matSolve(Bm, Xm)
        X = np.array(Xm.getDenseArray(), copy=True)
        Bm.destroy()
        Xm.destroy()
        return X


def is_diagonal(A: PETSc.Mat) -> bool:
    """Whether every owned row of ``A`` holds its diagonal entry alone (collective)."""
    first = A.getOwnershipRange()[0]
    indptr, indices, values = A.getValuesCSR()
    counts = np.diff(indptr)
    rows = np.arange(first, first + counts.size)
    local = bool(np.all(counts <= 1) and np.all(indices == rows[counts == 1])) if counts.size else True
    # (a stored zero off the diagonal does not count)
    if not local and counts.size:
        row_of = np.repeat(rows, counts)
        local = bool(np.all((values == 0.0) | (indices == row_of)))
    return A.getComm().tompi4py().allreduce(local, op=MPI.LAND)


class DiagonalFactor:
    """The inverse of a diagonal PETSc matrix on each rank's owned entries: ``solve(b, x)``, ``many(B)``.

    Under MPI every other system goes to MUMPS; a lumped mass needs no factorization, only a
    division per entry (central difference's step matrix M + dt/2 C with a lumped M and no C).
    """

    def __init__(self, diagonal: np.ndarray):
        if np.any(diagonal == 0.0):
            raise SimulationError("a diagonal system matrix has a zero on its diagonal")
        self.inverse = 1.0 / diagonal

    def __call__(self, b: np.ndarray, x: np.ndarray) -> None:
        np.multiply(self.inverse, b, out=x)

    def many(self, B: np.ndarray) -> np.ndarray:
        return self.inverse[:, None] * B


class DenseFactor:
    """The inverse of a small replicated matrix (a diagonal when 1D): ``solve(b, x)``, ``many(B)``."""

    def __init__(self, A: np.ndarray):
        if A.ndim == 1:
            if np.any(A == 0.0):
                raise SimulationError("a diagonal operator of the reduced system is singular")
            self.inverse = 1.0 / A
            self.diagonal = True
        else:
            self.inverse = np.linalg.inv(A)   # a few dozen unknowns at most
            self.diagonal = False

    def __call__(self, b: np.ndarray, x: np.ndarray) -> None:
        if self.diagonal:
            np.multiply(self.inverse, b, out=x)
        else:
            np.dot(self.inverse, b, out=x)

    def many(self, B: np.ndarray) -> np.ndarray:
        return self.inverse[:, None] * B if self.diagonal else self.inverse @ B


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
    ``d0 - P U + c lam >= 0``, a massless spring in series. Nothing here knows
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

    def __post_init__(self):
        self.algebra = PETScAlgebra(self.K) if isinstance(self.K, PETSc.Mat) else DenseAlgebra(self.K)
        self.comm: MPI.Comm = self.algebra.comm
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

    def project(self, local: np.ndarray) -> np.ndarray:
        """``P x`` (or ``P X`` for a block of columns) from owned entries: one global sum."""
        return self.algebra.allsum(np.ascontiguousarray(self._P @ local))

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
            block = solve.inverse_block(dofs)
            if block is not None:
                Pd = sparse.csr_matrix(self._P[:, dofs])   # (a few entries a row: two products of p m nnz)
                scale = None
                if norm is not None:   # (serial: the entries' bound needs no sum over ranks)
                    diag = np.abs(np.diagonal(block))
                    condition = 2.0 * np.diff(Pd.indptr) + norm * diag.max(initial=0.0)
                    scale = np.sqrt(eps * condition) * (abs(Pd) @ np.sqrt(diag))
                finish = (lambda W: (W, SolvedColumns(self, solve))) if norm is None else \
                    (lambda W: (W, SolvedColumns(self, solve), scale))
                if Pd.shape[0] == Pd.shape[1] and np.all(np.diff(Pd.indptr) == 1) and \
                        np.unique(Pd.indices).size == Pd.shape[1]:
                    # One dof a row, each dof once (normals and tangents along axes): W is the block
                    # permuted and signed, in its own memory (at 6561 rows with friction, 3.1 GB each).
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

    def _keeps_columns(self) -> bool:
        """Whether ``delassus`` stores ``A^-1 P^T`` (few rows, or a small replicated system)."""
        return self.algebra.sizes[1] * self.p <= KEEP_COLUMNS or not self.algebra.distributed

    def condensed_dofs(self) -> np.ndarray | None:
        """The dofs of the rows, and of the tangent rows if any, where ``delassus`` is to take W from a
        block of ``A^-1`` (a serial model, from ``INVERSE_ENTRIES_FROM`` rows, too many to store
        ``A^-1 P^T``): the factorization of the step matrix may keep them out (``CondensedFactor``).
        Else None."""
        rows = self.with_tangents() if self.pt else self
        if self.comm.size > 1 or rows.p < INVERSE_ENTRIES_FROM or rows._keeps_columns():
            return None
        return np.unique(rows._P.indices)

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

    Its columns decay away from the contact dofs, in a long model down to exact zeros (a 1D
    bar of 10 000 cells: 372 nonzero rows): it is kept on the range of rows where it is
    nonzero, and a correction touches only that range, with the same result.
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


def axpy(y: np.ndarray, a: float, x: np.ndarray) -> np.ndarray:
    """``y += a x`` in place, one pass and no temporary (BLAS)."""
    if y.size:
        daxpy(x, y, a=a)
    return y


def owned_values(x) -> np.ndarray:
    """The owned entries of a PETSc vector, or the array itself."""
    return x.array_r if isinstance(x, PETSc.Vec) else np.asarray(x, dtype=float)


@dataclass
class EnergyBudget:
    """Energies at a step; work and loss terms cumulative from the start (docs/theory.md s. 9)."""

    kinetic: float = 0.0
    strain: float = 0.0
    external_work: float = 0.0
    damping_loss: float = 0.0
    impact_loss: float = 0.0
    contact_loss: float = 0.0
    initial: float = 0.0
    # The part of the energy a scheme conserves beyond kinetic + strain: central difference's
    # -dt^2/8 A.M A (docs in CentralDifference); zero for the other methods.
    scheme: float = 0.0
    # Not a term of the balance: the energy the load R(t) can give the structure at the step
    # (ContactScheme._load_energy), the watch's scale while E0 + W_ext is still zero or tiny.
    load_scale: float = 0.0
    friction_loss: float = 0.0   # the work of the friction impulses, lost (docs/theory.md s. 11)
    # The scheme's own dissipation: Moreau-Jean with theta > 1/2 damps the high frequencies, by
    # (theta - 1/2) (dV.M dV + dU.K dU + r.Q dV) a step (MoreauJean.step); zero for theta = 1/2.
    numerical_loss: float = 0.0
    # Not a term of the balance: how far round-off alone may take E - E0 at the step, EPS |U|^T |K| |U|
    # (bounded: ContactScheme._roundoff) at the step and at the start. U^T K U is computed from a K U
    # whose entries carry EPS (|K| |U|)_i each, and K's stored entries do not sum to zero over a rigid
    # translation exactly: a stiff body displaced far from where K U = 0 (sliding, flying) has a small
    # strain energy known only to that. The watch does not call that created.
    roundoff: float = 0.0

    @property
    def total(self) -> float:
        return self.kinetic + self.strain + self.scheme

    @property
    def error(self) -> float:
        """Residual of the balance: E - E0 - W_ext + damping + impact + contact losses."""
        return (
            self.total - self.initial - self.external_work
            + self.damping_loss + self.impact_loss + self.contact_loss + self.friction_loss + self.numerical_loss
        )

    def copy(self) -> EnergyBudget:
        return EnergyBudget(self.kinetic, self.strain, self.external_work, self.damping_loss, self.impact_loss,
                            self.contact_loss, self.initial, self.scheme, self.load_scale, self.friction_loss,
                            self.numerical_loss, self.roundoff)


@dataclass
class StepState:
    """The state after a step, as observers see it. Arrays are the integrator's own: read only."""

    step: int
    t: float
    U: np.ndarray                    # owned entries of the displacement (or modal coordinates)
    V: np.ndarray
    A: np.ndarray
    gap: np.ndarray                  # d0 - P U per row
    force: np.ndarray                # normal forces F_N at t
    impulse: np.ndarray              # impulses S_N over the step
    energy: EnergyBudget
    normal_displacement: np.ndarray  # P U
    normal_velocity: np.ndarray      # P V (after the impact correction)
    tangential: np.ndarray | None = None            # friction forces r_T / dt per tangent row (with friction)
    tangential_velocity: np.ndarray | None = None   # P_T V per tangent row: the sliding velocity
    reaction: np.ndarray | None = None              # per moving support pattern (fem/prescribed.py)


class Observer(Protocol):
    def write(self, state: StepState) -> None: ...


# The schemes' names in a sentence (EnergyWatch's messages).
TITLES = {"moreau_jean": "Moreau-Jean", "newmark": "Newmark (beta >= gamma / 2)", "central_difference": "central difference"}


class EnergyCreated(SimulationError):
    """The contacts created energy and the run was asked to stop on it (``stop_on_energy_gain``)."""


class EnergyWatch:
    """Watches the energy of every step: that none is created, and that the run has not blown up.

    A scheme that holds keeps ``E(t) <= E0 + W_ext(t)`` (every loss >= 0; the balance residual is
    round-off). The watch records the largest amount by which the energy exceeds that bound (beyond
    what round-off can put into the strain energy's measure, ``EnergyBudget.roundoff``) or a loss
    falls below zero (the contacts' -- contact plus impact loss -- or the damping's), and when
    it first did so by more than
    ``tolerance`` of the energy scale, ``max E0 + W_ext`` reached so far: energy created, although
    the balance may still close (position-level contact forces doing negative work). With
    ``stop_on_energy_gain`` the run stops there (EnergyCreated).

    Growth past ``blow_up`` times the scale is no accuracy problem but a runaway instability (an
    explicit scheme above its step limit): the run always stops with a SimulationError instead of
    writing ever larger numbers (and then NaN).
    """

    __checkpoint__ = ("scale", "created", "created_at", "max_ratio", "roundoff")   # (what it found so far: a restart goes on)

    def __init__(self, stop_on_energy_gain: bool = False, tolerance: float = ENERGY_TOLERANCE,
                 blow_up: float = BLOW_UP, scheme: str = "", stable: bool | None = None):
        self.stop, self.tolerance, self.factor = stop_on_energy_gain, tolerance, blow_up
        # The integrator's name, and whether it is stable at any dt (``unconditionally_stable``): what a
        # blow-up says of its cause.
        self.scheme, self.stable = scheme, stable
        self.scale = 0.0          # E0 + W_ext(t) or the load's energy scale, the largest so far
        self.created = 0.0        # the largest excess (energy units)
        self.created_at: float | None = None
        self.max_ratio = 0.0      # max E / scale
        self.roundoff = 0.0       # the largest round-off bound of E - E0 (EnergyBudget.roundoff)

    @property
    def created_relative(self) -> float:
        return self.created / self.scale if self.scale > 0.0 else 0.0

    def check(self, state: StepState) -> None:
        e = state.energy
        if not np.isfinite(e.total):
            raise SimulationError(self._not_finite(state))
        # A run from rest has E0 = 0 and, over its first steps, W_ext tiny against what round-off leaves
        # in E: the load's own energy scale keeps the measure sound from the first step.
        self.scale = max(self.scale, e.initial + e.external_work, e.initial, e.load_scale)
        if self.scale <= 0.0:
            return
        # The contacts' losses together: Carnot's impulses and the position-level forces are one
        # contact model (on an impact the forces may give back a little of what the impulse took).
        excess = max(e.total - e.initial - e.external_work - e.roundoff, -(e.contact_loss + e.impact_loss),
                     -e.damping_loss, -e.friction_loss)
        self.max_ratio = max(self.max_ratio, e.total / self.scale)
        self.roundoff = max(self.roundoff, e.roundoff)
        if excess > self.created:
            self.created = excess
            if self.created_at is None and excess > self.tolerance * self.scale:
                self.created_at = state.t
                if self.stop:
                    raise EnergyCreated(f"the contacts created energy at t = {state.t:.6g} (step {state.step}): "
                                        f"{self.describe()}")
        # (Kinetic + strain: a scheme's own term, central difference's, stays bounded as it blows up.)
        physical = e.kinetic + e.strain
        if physical > self.factor * self.scale:
            raise SimulationError(
                f"blew up at t = {state.t:.6g} (step {state.step}): kinetic + strain energy {physical:.4g} is "
                f"{physical / self.scale:.3g} times the initial energy plus the work put in so far "
                f"({self.scale:.4g}); {self._growth_cause()}")

    def _not_finite(self, state: StepState) -> str:
        """Why the energy is no longer finite, as far as the scheme that ran tells."""
        e = state.energy
        if state.step == 0:
            return (f"the initial state is not finite (kinetic energy {e.kinetic:.4g}, strain energy {e.strain:.4g}): "
                    "initial.velocity and initial.displacement must be numbers whose squares float64 holds (below "
                    "about 1e150)")
        where = f"the solution is no longer finite at t = {state.t:.6g} (step {state.step}): "
        if self.stable is False:
            return where + "the scheme blew up: " + self._step_limit()
        overflow = ("the energies overflowed float64 (1.8e308), from a load or an initial value too large for it "
                    f"(the load's energy over the last step: {e.load_scale:.3g})")
        if self.stable:
            return where + f"{TITLES.get(self.scheme, self.scheme)} is stable at any dt, so dt is not the cause: " + overflow
        return where + "the scheme blew up (is dt above a stable limit?), or " + overflow

    def _step_limit(self) -> str:
        """A conditionally stable scheme's limit, in words."""
        if self.scheme == "central_difference":
            return ("central difference is explicit and dt is above its stable limit, 2 / omega_max (c dt / h <= 1 "
                    "on the smallest cell): use a smaller dt, or solver.method: moreau_jean")
        if self.scheme == "newmark":
            return ("Newmark with beta < gamma / 2 is stable only below a step limit: use beta >= gamma / 2 (the "
                    "trapezoidal rule: beta 1/4, gamma 1/2), or a smaller dt")
        return "dt is above the scheme's stable limit"

    def _growth_cause(self) -> str:
        """What energy growing far past E0 + W_ext means for the scheme that ran."""
        if self.stable is False:
            return self._step_limit()
        if self.scheme == "newmark":
            return ("the paper's Newmark scheme is stable at any dt without contact, but its position-level contact "
                    "forces create energy at large steps in persistent contact: use solver.method: moreau_jean (its "
                    "contacts cannot create energy), or a smaller dt")
        if self.scheme == "moreau_jean":
            return ("Moreau-Jean (theta >= 1/2) is stable at any dt and its contacts cannot create energy, so dt is "
                    "not the cause (the reduced model's compliant rows aside: under loads that vary within a step "
                    "they gain energy of order dt^2); otherwise this is a defect: please report it")
        return "the scheme is unstable at this time step"

    def check_block(self, block) -> int:
        """``check`` on each step of a block of steps (fem_impact/integrators/blocks.py) at once.

        Returns how many of its first steps pass, the watch updated as by ``check`` on each of
        them; the first step on which ``check`` would stop the run (not finite, blown up, or
        energy created under ``stop_on_energy_gain``) is not counted: the loop takes it as a
        single step, whose ``check`` stops the run with its message.
        """
        e = block.energy
        total = e.total
        size = total.size
        finite = np.isfinite(total)
        if not finite.all():
            size = int(np.argmin(finite))
        if not size:
            return 0
        initial, work = e.initial[:size], e.external_work[:size]
        scale = np.maximum(initial + work, e.load_scale[:size])   # the scale after each step
        np.maximum(scale, initial, out=scale)
        scale[0] = max(scale[0], self.scale)
        np.maximum.accumulate(scale, out=scale)
        a = int(np.argmax(scale > 0.0)) if scale[0] <= 0.0 else 0   # steps before a: no scale yet, no check
        if scale[-1] <= 0.0:
            self.scale = float(scale[-1])
            return size
        live = slice(a, size)
        excess = total[live] - initial[a:] - work[a:] - e.roundoff[live]
        np.maximum(excess, -(e.contact_loss[live] + e.impact_loss[live]), out=excess)
        np.maximum(excess, -e.damping_loss[live], out=excess)
        np.maximum(excess, -e.friction_loss[live], out=excess)
        at = scale[a:]
        stop, created_at = size, None
        blown = e.kinetic[live] + e.strain[live] > self.factor * at
        if blown.any():
            stop = a + int(np.argmax(blown))
        if self.created_at is None:
            over = excess > self.tolerance * at
            if over.any():
                before = np.maximum.accumulate(np.concatenate(([self.created], excess[:-1])))   # self.created then
                first = over & (excess > before)
                if first.any():
                    created_at = a + int(np.argmax(first))
                    if self.stop:
                        stop = min(stop, created_at)
        if not stop:
            return 0
        self.scale = float(scale[stop - 1])
        if stop > a:
            kept = stop - a
            self.created = max(self.created, float(excess[:kept].max()))
            self.max_ratio = max(self.max_ratio, float((total[a:stop] / at[:kept]).max()))
            self.roundoff = max(self.roundoff, float(e.roundoff[a:stop].max()))
            if created_at is not None and created_at < stop:
                self.created_at = float(block.t[created_at])
        return stop

    def describe(self) -> str:
        """The finding in words, for a warning or an error."""
        return (f"the energy exceeded E0 + W_ext (or the contacts' losses went below zero) by {self.created:.4g} "
                f"({self.created_relative:.3g} of the energy scale {self.scale:.4g}; max E / (E0 + W_ext) = "
                f"{self.max_ratio:.3g}), first at t = {self.created_at:.6g}")

    @property
    def energy_was_created(self) -> bool:
        return self.created_at is not None


def integrate(integrator, U0, V0, t_end: float, observers=(), t0: float = 0.0, progress=None,
              watch: EnergyWatch | None = None, resume: bool = False, blocks=None) -> StepState:
    """Run ``integrator`` from (U0, V0) at ``t0`` to ``t_end``, calling each observer every step.

    ``watch`` (an EnergyWatch; a default one when None) checks every step before the observers see
    it: a run whose state stops being finite or whose energy blows up stops with a
    SimulationError, and energy created by the contacts is recorded (or stops the run).

    ``blocks`` (a ``BlockStepper`` of ``integrator``, fem_impact/integrators/blocks.py; None: one
    step at a time) takes the steps without contact many at a time, the same to round-off. Each
    of their steps still reaches every observer: as a block (``write_block(block)``) when every
    observer takes one, else as ``StepState``s one by one, in the order single steps would give
    them; ``progress`` is then called once a block. The integrator's own state (its vectors) is
    that of a block's last step: an observer that reads it at given steps (a checkpoint) says
    which with ``next_stop(step)`` (the next such step after ``step``, or None), and no block
    runs past it.
    """
    n_steps = steps_for(t_end - t0, integrator.dt)
    watch = EnergyWatch() if watch is None else watch
    # resume: the integrator's state was restored from a checkpoint at t0 (fem_impact/app/checkpoint.py)
    state = integrator.restored() if resume else integrator.start(U0, V0, t0)
    watch.check(state)
    for obs in observers:
        obs.write(state)
    whole = all(hasattr(obs, "write_block") for obs in observers)
    stops = [obs.next_stop for obs in observers if hasattr(obs, "next_stop")]
    done = 0
    while done < n_steps:
        block = None
        if blocks is not None:
            limit = n_steps - done
            for stop in stops:
                at = stop(state.step)
                if at is not None and at > state.step:
                    limit = min(limit, at - state.step)
            block = blocks.advance(limit)
        size = watch.check_block(block) if block is not None else 0
        if size:
            block = block.head(size) if size < len(block) else block
            blocks.commit(block)
            if whole:
                for obs in observers:
                    obs.write_block(block)
            else:
                for one in block.states():
                    for obs in observers:
                        obs.write(one)
            done += size
            state = integrator.state
        else:
            state = integrator.step()
            watch.check(state)
            for obs in observers:
                obs.write(state)
            done += 1
        if progress is not None:
            progress(state.step, n_steps)
    return state


