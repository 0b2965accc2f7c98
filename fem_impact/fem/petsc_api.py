"""PETSc calls that petsc4py 3.18 does not wrap, through the PETSc library itself (ctypes).

One place for them, so that an upgrade touches one file. Each returns None when it cannot be
done here (no MUMPS factor, a parallel run, the library not found); callers then fall back on
plain solves.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

import numpy as np
from petsc4py import PETSc

_LIBRARIES = ("libpetsc_real.so.3.18", "libpetsc_real.so", "libpetsc.so")
# MUMPS' blocking of the right-hand sides (ICNTL(27)) while it computes inverse entries: the face
# of the 1681-row plate took 11.1 s with its default (-32), 5.7 s with -128, 6.0 s with -512.
INVERSE_BLOCKING = -128


@functools.lru_cache(maxsize=1)
def _library():
    for name in (*_LIBRARIES, ctypes.util.find_library("petsc")):
        if not name:
            continue
        try:
            lib = ctypes.CDLL(name)
            lib.MatMumpsGetInverse.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
            lib.MatMumpsGetInverse.restype = ctypes.c_int
            return lib
        except (OSError, AttributeError):
            continue
    return None


def mumps_inverse_block(factor: PETSc.Mat, dofs: np.ndarray) -> np.ndarray | None:
    """``(A^-1)[dofs][:, dofs]`` (dense, m x m) from a serial MUMPS factor of ``A``.

    MUMPS computes selected entries of the inverse (ICNTL(30)) with the sparsity of the right-
    hand sides: on the face of a 45 000-unknown plate (1681 dofs) several times faster than 1681
    solves. ``dofs`` sorted. None when the factor is not a serial MUMPS factor.
    """
    lib = _library()
    if lib is None or factor.getComm().getSize() > 1 or factor.getType() != "mumps":
        return None
    n, m = factor.getSize()[0], dofs.size
    counts = np.zeros(n, dtype=PETSc.IntType)
    counts[dofs] = m
    indptr = np.zeros(n + 1, dtype=PETSc.IntType)
    np.cumsum(counts, out=indptr[1:])
    indices = np.tile(dofs.astype(PETSc.IntType), m)
    B = PETSc.Mat().createAIJ([n, n], csr=(indptr, indices, np.zeros(m * m)), comm=PETSc.COMM_SELF)
    B.assemble()
    del indices   # (PETSc keeps its own copy: m^2 entries, 1.5 GB at 19 683 dofs)
    Bt = PETSc.Mat().createTranspose(B)   # MUMPS reads the pattern of the wanted entries from B^T
    blocking = factor.getMumpsIcntl(27)
    factor.setMumpsIcntl(27, INVERSE_BLOCKING)
    try:
        if lib.MatMumpsGetInverse(ctypes.c_void_p(factor.handle), ctypes.c_void_p(Bt.handle)):
            return None
    finally:
        factor.setMumpsIcntl(30, 0)   # back to plain solves with this factor
        factor.setMumpsIcntl(27, blocking)
    # Read by blocks of rows into the result (getValuesCSR would copy the whole pattern too).
    values = np.empty((m, m))
    rows = dofs.astype(PETSc.IntType)
    for i in range(0, m, 512):
        values[i:i + 512] = B.getValues(rows[i:i + 512], rows)
    Bt.destroy()
    B.destroy()
    return values
