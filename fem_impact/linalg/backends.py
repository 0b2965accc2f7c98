"""The algebra the integrators run on: one integrator code for a distributed and a replicated system.

The integrators work on numpy arrays: the owned entries of distributed PETSc vectors for a
finite-element model (``PETScAlgebra``: each array is the memory of a PETSc ``Vec``, so matrix
products and solves go through PETSc without copies), or small replicated arrays for the reduced
model (``DenseAlgebra``: diagonal or dense matrices, numpy only). Only products, solves and global
sums differ.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from ..parallel import allsum
from .condensed import CondensedFactor
from .factor import DenseFactor, DiagonalFactor, Factor, direct_solver, is_diagonal, mumps_for, solver_options, \
    without_stored_zeros


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
        if kept is not None and spd and mumps_for(A) and not solver_options():
            condensed = CondensedFactor.create(without_stored_zeros(A), kept)
            if condensed is not None:
                return condensed
        return Factor(direct_solver(A, spd), self)

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


def owned_values(x) -> np.ndarray:
    """The owned entries of a PETSc vector, or the array itself."""
    return x.array_r if isinstance(x, PETSc.Vec) else np.asarray(x, dtype=float)
