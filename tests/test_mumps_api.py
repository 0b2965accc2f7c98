"""MUMPS' Schur complement and split solves through its C interface (fem_impact/linalg/mumps_api.py), and the
factor that solves through them (fem_impact/linalg/condensed.py), against dense algebra."""

import numpy as np
import pytest
import scipy.sparse as sp
from petsc4py import PETSc

from fem_impact.linalg import mumps_api

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
def test_the_schur_complement_and_the_split_solves_are_the_dense_ones(n, kept):
    """SchurFactor: the complement A_kk - A_ko A_oo^-1 A_ok, and condense, (dense solve on the kept
    variables), expand giving A^-1 b, for one right-hand side and for a block (Fortran order)."""
    A, dense = spd_matrix(n, seed=n)
    kept = np.array(kept)
    others = np.setdiff1d(np.arange(n), kept)
    expected = dense[np.ix_(kept, kept)] - dense[np.ix_(kept, others)] @ np.linalg.solve(
        dense[np.ix_(others, others)], dense[np.ix_(others, kept)])
    factor = mumps_api.SchurFactor.create(A, kept)
    S = factor.complement
    assert np.abs(S - expected).max() <= 1e-13 * np.abs(expected).max()
    assert np.array_equal(S, S.T)
    B = np.random.default_rng(n).standard_normal((n, 3))
    for b in (B[:, 0].copy(), np.asfortranarray(B)):
        reduced = np.empty((kept.size,) + b.shape[1:], order="F")
        factor.condense(b, reduced)
        reduced[...] = np.linalg.solve(S, reduced)
        factor.expand(b, reduced)
        x = np.linalg.solve(dense, B[:, 0] if b.ndim == 1 else B)
        assert np.abs(b - x).max() <= 1e-12 * np.abs(x).max()
    factor.close()


def test_a_condensed_factor_solves_and_gives_the_inverse_block_of_the_dense_matrix(monkeypatch):
    """CondensedFactor: solves (one, a block, one in two halves with the kept values corrected between)
    and the block of A^-1 on the kept dofs or some of them, against dense algebra; None where it does
    not pay."""
    from fem_impact.linalg import condensed

    n, kept = 300, np.arange(1, 300, 4)
    A, dense = spd_matrix(n, seed=7)
    inverse = np.linalg.inv(dense)
    monkeypatch.setattr(condensed, "SCHUR_FLOPS", 1e30)
    assert condensed.CondensedFactor.create(A, kept) is None
    monkeypatch.setattr(condensed, "SCHUR_FLOPS", 0.0)
    factor = condensed.CondensedFactor.create(A, kept)
    rng = np.random.default_rng(8)
    b, x = rng.standard_normal(n), np.empty(n)
    factor(b, x)
    assert np.abs(x - inverse @ b).max() <= 1e-12 * np.abs(inverse @ b).max()
    B = rng.standard_normal((n, 5))
    assert np.abs(factor.many(B) - inverse @ B).max() <= 1e-12 * np.abs(inverse @ B).max()
    # in two halves, the kept values corrected in between: A^-1 (b + r) for an r on the kept dofs
    r = np.zeros(n)
    r[kept] = rng.standard_normal(kept.size)
    x_kept = factor.begin(b)
    assert np.abs(x_kept - (inverse @ b)[kept]).max() <= 1e-12 * np.abs(inverse @ b).max()
    x_kept += factor.dense(r[kept].copy())
    factor.finish(x_kept, x)
    assert np.abs(x - inverse @ (b + r)).max() <= 1e-12 * np.abs(inverse @ (b + r)).max()
    some = kept[::3]
    block = factor.inverse_block(some)
    assert np.abs(block - inverse[np.ix_(some, some)]).max() <= 1e-12 * np.abs(inverse).max()
    whole = factor.inverse_block(kept)   # (handed over: a second call inverts again)
    assert np.abs(whole - inverse[np.ix_(kept, kept)]).max() <= 1e-12 * np.abs(inverse).max()
    whole[...] = 0.0
    assert np.abs(factor.inverse_block(kept) - inverse[np.ix_(kept, kept)]).max() <= 1e-12 * np.abs(inverse).max()
    with pytest.raises(ValueError, match="outside the kept"):
        factor.inverse_block(np.array([0]))


def test_the_upper_triangle_is_mirrored_from_the_lower_one_by_blocks():
    rng = np.random.default_rng(3)
    S = rng.standard_normal((23, 23))
    expected = np.tril(S) + np.tril(S, -1).T
    mumps_api.mirror_lower(S, block=7)   # (blocks of 7, the last of 2)
    assert np.array_equal(S, expected)
