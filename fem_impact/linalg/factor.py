"""Direct solvers: which one a PETSc matrix gets (PETSc's LU or MUMPS), and the factors the
integrators solve with (PETSc, diagonal, small dense).

``PETScAlgebra.factorize`` (backends.py) picks among these; the thresholds here are also part of
the reduced model's cache keys (``direct_solver_settings``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from ..errors import SimulationError
from .petsc_api import mumps_inverse_block

if TYPE_CHECKING:
    from .backends import PETScAlgebra

MUMPS_FROM = 5000    # unknowns: serial systems from this size on with 3D fill (MUMPS_FILL entries a row
MUMPS_FILL = 30      # or more) are factorized by MUMPS (Cholesky if SPD); smaller or sparser ones by PETSc
OPTIONS_PREFIX = "fem_impact_"   # PETSc options of the direct solver, e.g. -fem_impact_pc_factor_mat_solver_type


def factorize(A: PETSc.Mat, spd: bool = False) -> Callable[[PETSc.Vec, PETSc.Vec], None]:
    """A direct PETSc solver for ``A``, factorized now: ``solve(b, x)`` on PETSc vectors.

    Serial runs use PETSc's own sparse LU where its factor is cheap (1D and 2D models, small ones:
    its solves cost a fraction of MUMPS' there). Parallel runs, and serial ones of 3D fill
    (``MUMPS_FILL`` entries a row) from ``MUMPS_FROM`` unknowns on, use MUMPS: as a Cholesky
    factorization when the caller knows ``A`` to be symmetric positive definite. PETSc's options
    with the prefix ``fem_impact_`` override the choice
    (``PETSC_OPTIONS="-fem_impact_pc_factor_mat_solver_type superlu_dist"``).
    """
    return direct_solver(A, spd).solve


def solver_options() -> list[tuple[str, str]]:
    """The user's PETSc options for the direct solver (``OPTIONS_PREFIX``), sorted."""
    return sorted((k, v) for k, v in PETSc.Options().getAll().items() if k.startswith(OPTIONS_PREFIX))


def direct_solver_settings() -> dict:
    """What decides the solver :func:`factorize` picks besides the matrix (for cache keys): the
    thresholds, whether PETSc has MUMPS, the user's options with the prefix, PETSc's version."""
    return {"mumps": PETSc.Sys.hasExternalPackage("mumps"), "mumps_from": MUMPS_FROM, "mumps_fill": MUMPS_FILL,
            "options": solver_options(), "petsc": PETSc.Sys.getVersion()}


def mumps_for(A: PETSc.Mat) -> bool:
    """Whether ``A`` goes to MUMPS: on several ranks, or serial with 3D fill from ``MUMPS_FROM`` unknowns."""
    n = A.getSize()[0]
    dense_fill = n >= MUMPS_FROM and A.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"] >= MUMPS_FILL * n
    return PETSc.Sys.hasExternalPackage("mumps") and (A.getComm().getSize() > 1 or dense_fill)


def direct_solver(A: PETSc.Mat, spd: bool) -> PETSc.KSP:
    comm = A.getComm()
    ksp = PETSc.KSP().create(comm)
    ksp.setOperators(A)
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    mumps = mumps_for(A)
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
    factorizes the pattern it is given: without them it sees three decoupled components, and
    factorizes (and inverts on a face) several times faster, to the same values. (The diagonal is
    kept: a factorization needs every pivot.)
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
