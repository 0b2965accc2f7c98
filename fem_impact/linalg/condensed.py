"""A factorization that keeps the contact dofs out: solves through their Schur complement.

Where a face of many contact rows needs ``W = P A^-1 P^T`` from the inverse of A's Schur complement
on the rows' dofs C (docs/theory.md s. 3.2), the factorization that yields that complement,

    S_C = A_CC - A_CO A_OO^-1 A_OC,

also solves with A, split at C:

    condense:  r_C = b_C - A_CO A_OO^-1 b_O      (the others' forward elimination)
    x_C = S_C^-1 r_C                              (the dense Cholesky factor of S_C)
    expand:    x_O = A_OO^-1 (b_O - A_OC x_C)     (their backward one)

so ``A`` is factorized once, not once plainly and once more for W. A contact step needs the free
solution on C alone (``P x`` reads only C) before its impulse, and the impulse's correction
``A^-1 P^T c`` changes x_C by ``S_C^-1 P_C^T c`` (the expansion is linear in x_C, and ``P^T c`` is
zero off C): so the step condenses once, solves its contact problem on C, and expands once
(``begin``, ``finish``), where a plain factor takes two solves.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc
from scipy.linalg import lapack

from .mumps_api import SchurFactor, mirror_lower

# The condensed factorization is taken where eliminating the other dofs takes more than this many times
# m^3 flops (m kept dofs; the dense factorizations of S_C take m^3): W then costs about one factorization,
# against several for MUMPS' selected inverse entries. Below (a mass matrix, or friction's tangent rows
# on 3D elasticity), a plain factor and selected entries are cheaper.
SCHUR_FLOPS = 2.0


class CondensedFactor:
    """``A^-1`` for a serial SPD ``A`` from a MUMPS factorization that keeps the dofs ``kept`` out
    (``mumps_api.SchurFactor``) and the dense Cholesky factor of their Schur complement:
    ``solve(b, x)``, ``many(B)``, a solve in two halves (``begin``, ``finish``) with the kept
    values in between, and ``inverse_block(dofs)`` for dofs among the kept ones. Build with
    :meth:`create`."""

    @classmethod
    def create(cls, A: PETSc.Mat, kept: np.ndarray) -> CondensedFactor | None:
        """None where it does not pay (A's elimination estimated at fewer than ``SCHUR_FLOPS`` m^3
        flops) or cannot be done here (no MUMPS 5.5, a parallel A, a complement that is not
        positive definite); the caller then factorizes A plainly."""
        m = kept.size
        factor = SchurFactor.create(A, kept, min_flops=SCHUR_FLOPS * float(m) ** 3)
        if factor is None:
            return None
        # (LAPACK on the Fortran view: its upper triangle is the complement's lower one, S_C = U^T U)
        cholesky, info = lapack.dpotrf(factor.complement.T, lower=0, clean=0, overwrite_a=1)
        if info != 0:
            factor.close()
            return None
        return cls(factor, cholesky)

    def __init__(self, factor: SchurFactor, cholesky: np.ndarray):
        self.factor, self.cholesky = factor, cholesky
        self.kept, self.n, self.m = factor.kept, factor.n, factor.m
        self._R = np.empty(self.n)
        self._reduced = np.empty(self.m)
        self._inverse: np.ndarray | None = None

    def dense(self, reduced: np.ndarray) -> np.ndarray:
        """``S_C^-1 reduced`` (m, or m x k), in place where LAPACK allows."""
        x, info = lapack.dpotrs(self.cholesky, reduced, lower=0, overwrite_b=1)
        if info != 0:
            raise RuntimeError(f"LAPACK dpotrs: argument {-info} is invalid")
        return x

    def __call__(self, b: np.ndarray, x: np.ndarray) -> None:
        self.finish(self.begin(b), x)

    def begin(self, b: np.ndarray) -> np.ndarray:
        """The first half of ``A^-1 b``: its values on the kept dofs (m; a work array, valid until
        the next call), the others' forward elimination held for :meth:`finish`. The kept values
        may change in between: adding ``S_C^-1 r`` (:meth:`dense`) for an ``r`` on the kept dofs,
        ``finish`` gives ``A^-1 (b + r)`` (the expansion is linear in them, and ``r`` has no part
        to eliminate elsewhere)."""
        R, reduced = self._R, self._reduced
        R[:] = b
        self.factor.condense(R, reduced)
        reduced[:] = self.dense(reduced)
        return reduced

    def finish(self, x_kept: np.ndarray, x: np.ndarray) -> None:
        """The solution into ``x`` from its values ``x_kept`` on the kept dofs (after :meth:`begin`)."""
        if x_kept is not self._reduced:
            self._reduced[:] = x_kept
        self.factor.expand(self._R, self._reduced)
        x[:] = self._R

    def many(self, B: np.ndarray) -> np.ndarray:
        """``A^-1 B`` (n x k)."""
        R = np.array(B, dtype=float, order="F", copy=True)
        reduced = np.empty((self.m, R.shape[1]), order="F")
        self.factor.condense(R, reduced)
        reduced = np.asfortranarray(self.dense(reduced))
        self.factor.expand(R, reduced)
        return np.ascontiguousarray(R)

    def inverse_block(self, dofs: np.ndarray) -> np.ndarray:
        """``(A^-1)[dofs][:, dofs]`` for sorted ``dofs`` among the kept ones: the inverse of the
        complement (of its block). The whole inverse is handed over, not kept: the caller may
        overwrite it (W is permuted in its memory); a later call inverts again."""
        if self._inverse is None:
            self._inverse = self._invert()
        if dofs.size == self.m and np.array_equal(dofs, self.kept):
            inverse, self._inverse = self._inverse, None
            return inverse
        where = self.positions(dofs)
        if where is None:
            raise ValueError("inverse_block: dofs outside the kept ones")
        return self._inverse[np.ix_(where, where)]

    def positions(self, dofs: np.ndarray) -> np.ndarray | None:
        """The positions of ``dofs`` among the kept dofs; None if one is not kept."""
        where = np.searchsorted(self.kept, dofs)
        if np.any(where >= self.m) or not np.array_equal(self.kept[np.minimum(where, self.m - 1)], dofs):
            return None
        return where

    def _invert(self) -> np.ndarray:
        inverse = np.array(self.cholesky.T, order="C", copy=True)   # (C order: the Fortran view is the factor)
        result, info = lapack.dpotri(inverse.T, lower=0, overwrite_c=1)
        if info != 0:
            raise RuntimeError(f"LAPACK dpotri: the complement's factor is singular at {info}")
        if not np.shares_memory(result, inverse):
            inverse[...] = result.T
        mirror_lower(inverse)   # (dpotri filled the Fortran view's upper triangle: the lower one here)
        return inverse
