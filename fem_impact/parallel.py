"""MPI helpers shared by the model, the integrators, the reduction and the outputs."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI


def allsum(comm: MPI.Comm, local) -> np.ndarray:
    """Sum of ``local`` over the ranks of ``comm``, in one reduction (none on a single rank).

    The sum is done in place, and ``local`` itself returned, when it is a C-contiguous float64
    array; anything else (a list, a transposed view, integers) is summed as a float64 copy, which
    is returned.
    """
    local = np.ascontiguousarray(local, dtype=float)
    if comm.size > 1:
        comm.Allreduce(MPI.IN_PLACE, local, op=MPI.SUM)
    return local
