"""Numba for the compiled kernels, its on-disk cache kept per version of their sources together.

Numba checks a cached function against its own source file only: a kernel that calls one of another
module (small_kernel.py calls cone.py's, integrators/kernels.py lcp_kernel.py's) would load its old
machine code after that other module changed, and compute with the old one. So the kernels' cache
goes to a directory named by a hash of every kernel module's source (``KERNELS``): a change to any of
them starts from a fresh cache. A cache directory set by the user (NUMBA_CACHE_DIR) is left alone.
Every module with compiled kernels imports ``njit`` from here, and is listed in ``KERNELS``
(tests/test_compiled.py checks both).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba
from numba import njit

__all__ = ["njit", "KERNELS", "source_key"]

PACKAGE = Path(__file__).resolve().parent
KERNELS = ("nonsmooth/cone.py", "nonsmooth/small_kernel.py", "nonsmooth/lcp_kernel.py", "integrators/kernels.py",
           "rigid/kernel.py")


def source_key(paths) -> str:
    """A short hash of the files' contents, in order."""
    digest = hashlib.sha256()
    for path in paths:
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()[:16]


if not os.environ.get("NUMBA_CACHE_DIR"):
    numba.config.CACHE_DIR = str(PACKAGE / "__pycache__" / "numba" / source_key(PACKAGE / k for k in KERNELS))
