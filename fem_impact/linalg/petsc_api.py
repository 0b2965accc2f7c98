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
# MUMPS' blocking of the right-hand sides (ICNTL(27)) while it computes inverse entries: wider blocks
# than its default (-32) take about half the time on a face of many rows.
INVERSE_BLOCKING = -128
# Entries of A^-1 asked for in one call (the pattern: 12 bytes an entry, 400 MB).
INVERSE_ENTRIES = 1 << 25


def first_library(names, declare) -> ctypes.CDLL | None:
    """The first of the shared libraries ``names`` (None entries skipped) that loads and has the
    functions ``declare(lib)`` sets the types of; None if none has."""
    for name in names:
        if not name:
            continue
        try:
            lib = ctypes.CDLL(name)
            declare(lib)
            return lib
        except (OSError, AttributeError):
            continue
    return None


def _declare(lib) -> None:
    lib.MatMumpsGetInverse.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    lib.MatMumpsGetInverse.restype = ctypes.c_int


@functools.lru_cache(maxsize=1)
def _library():
    return first_library((*_LIBRARIES, ctypes.util.find_library("petsc")), _declare)


def mumps_inverse_block(factor: PETSc.Mat, dofs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray | None:
    """``(A^-1)[dofs][:, dofs]`` (dense, m x m) from a serial MUMPS factor of a symmetric ``A``.

    MUMPS computes selected entries of the inverse (ICNTL(30)) with the sparsity of the right-
    hand sides, much faster than a solve per dof. The entries are asked for by blocks of columns,
    each from its diagonal down (the rest by symmetry: half the entries), so that the pattern PETSc
    and MUMPS hold (12 bytes an entry) stays near INVERSE_ENTRIES whatever m (the whole pattern of
    a large face would take gigabytes beside the result). ``dofs`` sorted; ``out`` (m x m, float64)
    is filled if given. None when the factor is not a serial MUMPS factor.
    """
    lib = _library()
    if lib is None or factor.getComm().getSize() > 1 or factor.getType() != "mumps":
        return None
    n, m = factor.getSize()[0], dofs.size
    values = np.empty((m, m)) if out is None else out
    rows = dofs.astype(PETSc.IntType)
    blocking = factor.getMumpsIcntl(27)
    factor.setMumpsIcntl(27, INVERSE_BLOCKING)
    try:
        j0 = 0
        while j0 < m:
            wanted = rows[j0:]   # rows j0.. of the block's columns (those above: from earlier blocks)
            width = max(1, min(m - j0, INVERSE_ENTRIES // wanted.size))
            block = rows[j0:j0 + width]
            # B's row j lists the wanted rows of column j of A^-1 (MUMPS reads the pattern from B^T).
            counts = np.zeros(n, dtype=PETSc.IntType)
            counts[block] = wanted.size
            indptr = np.zeros(n + 1, dtype=PETSc.IntType)
            np.cumsum(counts, out=indptr[1:])
            B = PETSc.Mat().createAIJ([n, n], csr=(indptr, np.tile(wanted, width), np.zeros(width * wanted.size)),
                                      comm=PETSc.COMM_SELF)
            B.assemble()
            Bt = PETSc.Mat().createTranspose(B)
            try:
                if lib.MatMumpsGetInverse(ctypes.c_void_p(factor.handle), ctypes.c_void_p(Bt.handle)):
                    return None
                # (read in slices: getValuesCSR would copy the whole pattern)
                for i in range(0, width, 512):
                    part = B.getValues(block[i:i + 512], wanted)
                    values[j0 + i:j0 + i + part.shape[0], j0:] = part
                    values[j0:, j0 + i:j0 + i + part.shape[0]] = part.T
            finally:
                Bt.destroy()
                B.destroy()
            j0 += width
    finally:
        factor.setMumpsIcntl(30, 0)   # back to plain solves with this factor
        factor.setMumpsIcntl(27, blocking)
    return values
