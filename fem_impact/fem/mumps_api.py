"""MUMPS' C interface (``dmumps_c``), for what PETSc 3.18 does not reach: a sequential
factorization that keeps a set of variables out and returns their Schur complement
(ICNTL(19)), with the other variables ordered as MUMPS would order them alone.

One place for it: the structure below is MUMPS 5.5's ``DMUMPS_STRUC_C`` (dmumps_c.h, 32-bit
integers), and an upgrade touches this file only. Without the library, or with another version,
:func:`inverse_by_schur` returns None and callers keep their other path.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from scipy.linalg import lapack

from .petsc_api import first_library

_INT, _INT8, _REAL = ctypes.c_int, ctypes.c_int64, ctypes.c_double
_P_INT, _P_REAL = ctypes.POINTER(_INT), ctypes.POINTER(_REAL)
# Only a library that names the version: the structure is filled by MUMPS' first call, before its
# version string could be read, so another version's layout must not be called at all.
_LIBRARIES = ("libdmumps-5.5.so",)
VERSION = "5.5"   # the layout below is this version's


class _Struc(ctypes.Structure):
    """``DMUMPS_STRUC_C`` of MUMPS 5.5, field for field."""
    _fields_ = [
        ("sym", _INT), ("par", _INT), ("job", _INT), ("comm_fortran", _INT),
        ("icntl", _INT * 60), ("keep", _INT * 500), ("cntl", _REAL * 15), ("dkeep", _REAL * 230),
        ("keep8", _INT8 * 150), ("n", _INT), ("nblk", _INT), ("nz_alloc", _INT),
        ("nz", _INT), ("nnz", _INT8), ("irn", _P_INT), ("jcn", _P_INT), ("a", _P_REAL),
        ("nz_loc", _INT), ("nnz_loc", _INT8), ("irn_loc", _P_INT), ("jcn_loc", _P_INT), ("a_loc", _P_REAL),
        ("nelt", _INT), ("eltptr", _P_INT), ("eltvar", _P_INT), ("a_elt", _P_REAL),
        ("blkptr", _P_INT), ("blkvar", _P_INT), ("perm_in", _P_INT), ("sym_perm", _P_INT), ("uns_perm", _P_INT),
        ("colsca", _P_REAL), ("rowsca", _P_REAL), ("colsca_from_mumps", _INT), ("rowsca_from_mumps", _INT),
        ("rhs", _P_REAL), ("redrhs", _P_REAL), ("rhs_sparse", _P_REAL), ("sol_loc", _P_REAL), ("rhs_loc", _P_REAL),
        ("irhs_sparse", _P_INT), ("irhs_ptr", _P_INT), ("isol_loc", _P_INT), ("irhs_loc", _P_INT),
        ("nrhs", _INT), ("lrhs", _INT), ("lredrhs", _INT), ("nz_rhs", _INT), ("lsol_loc", _INT),
        ("nloc_rhs", _INT), ("lrhs_loc", _INT),
        ("schur_mloc", _INT), ("schur_nloc", _INT), ("schur_lld", _INT),
        ("mblock", _INT), ("nblock", _INT), ("nprow", _INT), ("npcol", _INT),
        ("info", _INT * 80), ("infog", _INT * 80), ("rinfo", _REAL * 40), ("rinfog", _REAL * 40),
        ("deficiency", _INT), ("pivnul_list", _P_INT), ("mapping", _P_INT),
        ("size_schur", _INT), ("listvar_schur", _P_INT), ("schur", _P_REAL),
        ("instance_number", _INT), ("wk_user", _P_REAL),
        ("version_number", ctypes.c_char * 32), ("ooc_tmpdir", ctypes.c_char * 256),
        ("ooc_prefix", ctypes.c_char * 64), ("write_problem", ctypes.c_char * 256), ("lwk_user", _INT),
        ("save_dir", ctypes.c_char * 256), ("save_prefix", ctypes.c_char * 256), ("metis_options", _INT * 40),
    ]


def _declare(lib) -> None:
    lib.dmumps_c.argtypes = [ctypes.POINTER(_Struc)]
    lib.dmumps_c.restype = None


@functools.lru_cache(maxsize=1)
def _library():
    found = ctypes.util.find_library("dmumps")
    return first_library((*_LIBRARIES, found if found and f"-{VERSION}." in found else None), _declare)


# MUMPS' working-space relaxation (ICNTL(14), per cent), raised and retried while a factorization
# runs short of the space its analysis estimated (INFOG(1) among these).
RELAXATION = 20
SHORT_OF_SPACE = (-8, -9, -11, -12, -14, -15, -17, -20)


class _Instance:
    """One sequential MUMPS instance (symmetric positive definite), silent, freed by ``close``."""

    def __init__(self, lib):
        self.lib, self.s = lib, _Struc()
        s = self.s
        s.sym, s.par, s.job, s.comm_fortran = 1, 1, -1, MPI.COMM_SELF.py2f()
        lib.dmumps_c(ctypes.byref(s))
        self.version = s.version_number.decode()
        for k, v in {1: -1, 2: -1, 3: -1, 4: 0, 14: RELAXATION}.items():
            s.icntl[k - 1] = v
        self._arrays = []   # what MUMPS points to, alive as long as the instance

    def matrix(self, n: int, rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> None:
        """The upper triangle, 0-based."""
        irn = np.ascontiguousarray(rows + 1, dtype=np.int32)
        jcn = np.ascontiguousarray(cols + 1, dtype=np.int32)
        a = np.ascontiguousarray(values, dtype=float)
        self._arrays += [irn, jcn, a]
        s = self.s
        s.n, s.nnz = n, a.size
        s.irn, s.jcn, s.a = (irn.ctypes.data_as(_P_INT), jcn.ctypes.data_as(_P_INT), a.ctypes.data_as(_P_REAL))

    def point(self, field: str, array: np.ndarray, kind) -> None:
        self._arrays.append(array)
        setattr(self.s, field, array.ctypes.data_as(kind))

    def run(self, job: int, retry: bool = False) -> bool:
        """Run ``job``; False if MUMPS stopped with an error."""
        s = self.s
        s.job = job
        for _ in range(4):
            self.lib.dmumps_c(ctypes.byref(s))
            if not (retry and s.infog[0] in SHORT_OF_SPACE):
                break
            s.icntl[14 - 1] = 2 * s.icntl[14 - 1] + 20
        return s.infog[0] >= 0

    def close(self) -> None:
        self.s.job = -2
        self.lib.dmumps_c(ctypes.byref(self.s))
        self._arrays.clear()


def _ordering_around(lib, n, rows, cols, values, kept) -> np.ndarray | None:
    """A pivot order (MUMPS' PERM_IN: each variable's position, 1-based) with the variables ``kept``
    last and the others in the order MUMPS' analysis gives them alone; None if it fails."""
    inner = np.ones(n, dtype=bool)
    inner[kept] = False
    number = np.cumsum(inner) - 1   # (a variable's number among the others)
    both = inner[rows] & inner[cols]
    mumps = _Instance(lib)
    try:
        mumps.matrix(n - kept.size, number[rows[both]], number[cols[both]], values[both])
        if not mumps.run(1):
            return None
        order = np.empty(n, dtype=np.int32)
        order[inner] = np.ctypeslib.as_array(mumps.s.sym_perm, shape=(n - kept.size,))
        order[kept] = np.arange(n - kept.size + 1, n + 1)
        return order
    finally:
        mumps.close()


def schur_complement(A: PETSc.Mat, kept: np.ndarray) -> np.ndarray | None:
    """``A_kk - A_ko A_oo^-1 A_ok`` (dense, symmetric, m x m) of a serial SPD ``A`` on the variables
    ``kept`` (sorted, 0-based), from a MUMPS factorization that leaves them out (ICNTL(19) = 1).

    MUMPS orders by AMD alone once it is to keep a Schur complement (the 6561-row plate's S:
    168 s); the other variables are ordered here as MUMPS' analysis orders them without the kept
    ones (PORD on this machine), the kept ones last (80 s). None without MUMPS 5.5 or if it fails.
    """
    lib = _library()
    if lib is None or A.getComm().getSize() > 1:
        return None
    n, m = A.getSize()[0], kept.size
    indptr, cols, values = A.getValuesCSR()
    rows = np.repeat(np.arange(n, dtype=np.int32), np.diff(indptr))
    upper = cols >= rows
    rows, cols, values = rows[upper], cols[upper], values[upper]
    mumps = _Instance(lib)
    try:
        if not mumps.version.startswith(VERSION):
            return None
        order = _ordering_around(lib, n, rows, cols, values, kept)
        if order is None:
            return None
        mumps.matrix(n, rows, cols, values)
        del rows, cols, values
        s = mumps.s
        s.icntl[7 - 1], s.icntl[19 - 1], s.size_schur = 1, 1, m
        mumps.point("perm_in", order, _P_INT)
        mumps.point("listvar_schur", np.ascontiguousarray(kept + 1, dtype=np.int32), _P_INT)
        if not mumps.run(1):
            return None
        schur = np.empty((m, m))
        s.schur_lld = m
        mumps.point("schur", schur, _P_REAL)
        if not mumps.run(2, retry=True):
            return None
    finally:
        mumps.close()
    # MUMPS' result is the lower triangle by rows (the upper one may hold its work values)
    _mirror_lower(schur)
    return schur


def inverse_by_schur(A: PETSc.Mat, dofs: np.ndarray) -> np.ndarray | None:
    """``(A^-1)[dofs][:, dofs]`` (dense, m x m) of a serial SPD ``A`` as the inverse of its Schur
    complement on ``dofs`` (sorted): one factorization and a dense inversion (m^3 flops), against
    the selected entries of the inverse, which cost several factorizations when m is large
    (``petsc_api.mumps_inverse_block``). None when it cannot be done here."""
    S = schur_complement(A, dofs)
    if S is None:
        return None
    # (LAPACK on the Fortran view of S, in place: its upper triangle is S's lower one)
    factor, info = lapack.dpotrf(S.T, lower=0, clean=0, overwrite_a=1)
    if info != 0:
        return None
    inverse, info = lapack.dpotri(factor, lower=0, overwrite_c=1)
    if info != 0:
        return None
    if not np.shares_memory(inverse, S):   # (LAPACK worked on a copy after all)
        S[...] = inverse.T
    _mirror_lower(S)
    return S


def _mirror_lower(S: np.ndarray, block: int = 512) -> None:
    """S's upper triangle from its lower one, in place, by blocks of rows."""
    m = S.shape[0]
    for i0 in range(0, m, block):
        i1 = min(i0 + block, m)
        D = S[i0:i1, i0:i1]
        D[np.triu_indices(i1 - i0, 1)] = D.T[np.triu_indices(i1 - i0, 1)]
        S[i0:i1, i1:] = S[i1:, i0:i1].T
