"""MUMPS' Schur complement through its C interface (fem_impact/fem/mumps_api.py), against dense algebra."""

import numpy as np
import pytest
import scipy.sparse as sp
from petsc4py import PETSc

from fem_impact.fem import mumps_api

pytestmark = pytest.mark.skipif(mumps_api._library() is None, reason="MUMPS 5.5's C library is not installed")


def spd_matrix(n: int, seed: int) -> tuple[PETSc.Mat, np.ndarray]:
    """A sparse SPD matrix (a random symmetric pattern, diagonally dominant), as PETSc and dense."""
    R = sp.random(n, n, density=0.03, random_state=seed)
    A = (R + R.T + sp.diags(np.asarray(abs(R).sum(axis=0) + abs(R).sum(axis=1).T).ravel() + 1.0)).tocsr()
    M = PETSc.Mat().createAIJ([n, n], csr=(A.indptr.astype(PETSc.IntType), A.indices.astype(PETSc.IntType), A.data),
                              comm=PETSc.COMM_SELF)
    M.assemble()
    return M, A.toarray()


@pytest.mark.parametrize("n, kept", [(200, [0, 5, 77, 150, 199]), (400, list(range(0, 400, 3)))])
def test_schur_complement_and_the_inverse_block_are_the_dense_ones(n, kept):
    A, dense = spd_matrix(n, seed=n)
    kept = np.array(kept)
    others = np.setdiff1d(np.arange(n), kept)
    expected = dense[np.ix_(kept, kept)] - dense[np.ix_(kept, others)] @ np.linalg.solve(
        dense[np.ix_(others, others)], dense[np.ix_(others, kept)])
    S = mumps_api.schur_complement(A, kept)
    assert np.abs(S - expected).max() <= 1e-13 * np.abs(expected).max()
    assert np.array_equal(S, S.T)
    inverse = np.linalg.inv(dense)[np.ix_(kept, kept)]
    W = mumps_api.inverse_by_schur(A, kept)
    assert np.abs(W - inverse).max() <= 1e-12 * np.abs(inverse).max()
    assert np.array_equal(W, W.T)


def test_the_upper_triangle_is_mirrored_from_the_lower_one_by_blocks():
    rng = np.random.default_rng(3)
    S = rng.standard_normal((23, 23))
    expected = np.tril(S) + np.tril(S, -1).T
    mumps_api._mirror_lower(S, block=7)   # (blocks of 7, the last of 2)
    assert np.array_equal(S, expected)
