"""MUMPS' C interface (``dmumps_c``), for what PETSc 3.18 does not reach: a sequential
factorization that keeps a set of variables out and returns their Schur complement
(ICNTL(19)), with the other variables ordered as MUMPS would order them alone, and solves
split at that set (ICNTL(26)).

One place for it: the structure below is MUMPS 5.5's ``DMUMPS_STRUC_C`` (dmumps_c.h, 32-bit
integers), and an upgrade touches this file only. Without the library, or with another version,
:meth:`SchurFactor.create` returns None and callers keep their other path.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import weakref

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

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


def _ordering_around(lib, n, rows, cols, values, kept) -> tuple[np.ndarray, float] | None:
    """A pivot order (MUMPS' PERM_IN: each variable's position, 1-based) with the variables ``kept``
    last and the others in the order MUMPS' analysis gives them alone, and that analysis' estimate
    of the flops of their elimination (RINFOG(1)); None if it fails."""
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
        return order, float(mumps.s.rinfog[0])
    finally:
        mumps.close()


class SchurFactor:
    """A sequential MUMPS factorization of an SPD matrix that keeps the variables ``kept`` out:
    ``complement`` is their Schur complement ``A_kk - A_ko A_oo^-1 A_ok`` (dense, symmetric, m x m),
    and a solve splits into ``condense`` (the others' forward elimination; the reduced right-hand
    side ``b_k - A_ko A_oo^-1 b_o``) and ``expand`` (the others from the kept ones' values),
    MUMPS' ICNTL(19) = 1 and ICNTL(26) = 1, 2.

    MUMPS orders by AMD alone once it is to keep a Schur complement, which is slow on 3D models;
    the other variables are ordered here as MUMPS' analysis orders them without the kept
    ones, the kept ones last. Build with :meth:`create`; ``close`` frees MUMPS' memory.
    """

    @classmethod
    def create(cls, A: PETSc.Mat, kept: np.ndarray, min_flops: float = 0.0) -> SchurFactor | None:
        """For a serial SPD ``A`` and ``kept`` (sorted, 0-based). None without MUMPS 5.5, when it
        fails, or when the analysis estimates the elimination of the others at fewer than
        ``min_flops`` (checked before the factorization: a caller's threshold)."""
        lib = _library()
        if lib is None or A.getComm().getSize() > 1:
            return None
        n = A.getSize()[0]
        indptr, cols, values = A.getValuesCSR()
        rows = np.repeat(np.arange(n, dtype=np.int32), np.diff(indptr))
        upper = cols >= rows
        rows, cols, values = rows[upper], cols[upper], values[upper]
        mumps = _Instance(lib)
        if not mumps.version.startswith(VERSION):
            mumps.close()
            return None
        found = _ordering_around(lib, n, rows, cols, values, kept)
        if found is None or found[1] < min_flops:
            mumps.close()
            return None
        factor = cls(mumps, n, kept)
        if not factor._factorize(rows, cols, values, found[0]):
            factor.close()
            return None
        return factor

    def __init__(self, mumps: _Instance, n: int, kept: np.ndarray):
        self._mumps, self.n, self.m = mumps, n, kept.size
        self.kept = kept
        self.complement = np.empty((self.m, self.m))
        self._close = weakref.finalize(self, mumps.close)   # (MUMPS' memory, when this is dropped)

    def _factorize(self, rows, cols, values, order) -> bool:
        mumps, m = self._mumps, self.m
        mumps.matrix(self.n, rows, cols, values)
        s = mumps.s
        s.icntl[7 - 1], s.icntl[19 - 1], s.size_schur = 1, 1, m
        mumps.point("perm_in", order, _P_INT)
        mumps.point("listvar_schur", np.ascontiguousarray(self.kept + 1, dtype=np.int32), _P_INT)
        if not mumps.run(1):
            return False
        s.schur_lld = m
        mumps.point("schur", self.complement, _P_REAL)
        if not mumps.run(2, retry=True):
            return False
        # MUMPS' result is the lower triangle by rows (the upper one may hold its work values)
        mirror_lower(self.complement)
        return True

    def _solve(self, R: np.ndarray, reduced: np.ndarray, phase: int) -> None:
        s = self._mumps.s
        s.icntl[26 - 1] = phase
        s.nrhs = 1 if R.ndim == 1 else R.shape[1]
        s.lrhs, s.lredrhs = self.n, self.m
        s.rhs, s.redrhs = R.ctypes.data_as(_P_REAL), reduced.ctypes.data_as(_P_REAL)
        if not self._mumps.run(3):
            raise RuntimeError(f"MUMPS' solve stopped with INFOG(1) = {s.infog[0]}")

    def condense(self, R: np.ndarray, reduced: np.ndarray) -> None:
        """The forward elimination of ``R`` (n, or n x k in Fortran order), in place (``expand``
        reads it); the reduced right-hand sides into ``reduced`` (m, or m x k in Fortran order)."""
        self._solve(R, reduced, 1)

    def expand(self, R: np.ndarray, reduced: np.ndarray) -> None:
        """The solution into ``R`` (as ``condense`` left it; zeros for a right-hand side that is zero
        outside the kept variables) from the kept variables' values in ``reduced``."""
        self._solve(R, reduced, 2)

    def close(self) -> None:
        """Free MUMPS' factor now (the complement array stays)."""
        self._close()


def mirror_lower(S: np.ndarray, block: int = 512) -> None:
    """S's upper triangle from its lower one, in place, by blocks of rows."""
    m = S.shape[0]
    for i0 in range(0, m, block):
        i1 = min(i0 + block, m)
        D = S[i0:i1, i0:i1]
        D[np.triu_indices(i1 - i0, 1)] = D.T[np.triu_indices(i1 - i0, 1)]
        S[i0:i1, i1:] = S[i1:, i0:i1].T
