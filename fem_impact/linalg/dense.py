"""Dense, in-place array operations of the integrators and the contact problem (numpy and BLAS only,
no PETSc: the contact problem's modules import this)."""

from __future__ import annotations

import numpy as np
from scipy.linalg.blas import daxpy


def axpy(y: np.ndarray, a: float, x: np.ndarray) -> np.ndarray:
    """``y += a x`` in place, one pass and no temporary (BLAS)."""
    if y.size:
        daxpy(x, y, a=a)
    return y


def permuted_in_place(W: np.ndarray, order: np.ndarray) -> np.ndarray:
    """``W[order][:, order]`` in W's own memory (one row of scratch): each row's entries, then the rows
    along the permutation's cycles. For the large dense matrices of many contact rows, where a copy
    would not fit beside them."""
    for i in range(W.shape[0]):
        W[i] = W[i, order]
    done = order == np.arange(order.size)
    for start in np.flatnonzero(~done):
        if done[start]:
            continue
        held, j = W[start].copy(), start
        while True:
            done[j] = True
            source = order[j]
            if source == start:
                W[j] = held
                break
            W[j] = W[source]
            j = source
    return W
