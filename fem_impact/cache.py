"""On-disk cache of expensive, reusable results (modes, static solves), keyed by their inputs.

The key hashes the operators themselves (the local CSR arrays of K and M, which carry the
mesh, the materials and the supports) and whatever else the result depends on, so a changed
scene can never pick up a stale result. Entries are ``.npz`` files in ``$FEM_IMPACT_CACHE``
(default ``~/.cache/fem-impact``); deleting the folder is always safe.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
from pathlib import Path

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

log = logging.getLogger(__name__)


def cache_dir() -> Path:
    return Path(os.environ.get("FEM_IMPACT_CACHE", Path.home() / ".cache" / "fem-impact"))


def key(comm: MPI.Comm, *parts) -> str:
    """A hash of PETSc matrices, arrays and plain values, the same on every rank."""
    h = hashlib.sha256(f"{comm.size}".encode())
    for part in parts:
        if isinstance(part, PETSc.Mat):
            for array in part.getValuesCSR():
                h.update(np.ascontiguousarray(array).tobytes())
        elif isinstance(part, np.ndarray):
            h.update(str(part.shape).encode() + np.ascontiguousarray(part).tobytes())
        else:
            h.update(repr(part).encode())
    # Each rank hashed its own rows: combine them so every rank names the same entry.
    return hashlib.sha256("".join(comm.allgather(h.hexdigest())).encode()).hexdigest()[:32]


def load(name: str, comm: MPI.Comm) -> dict | None:
    """The arrays stored under ``name`` for this rank, or None when any rank misses them."""
    path = cache_dir() / f"{name}-r{comm.rank}.npz"
    try:
        with np.load(path) as data:
            found = {k: data[k] for k in data.files}
    except (OSError, ValueError):
        found = None
    return found if comm.allreduce(found is not None, op=MPI.LAND) else None


def save(name: str, comm: MPI.Comm, **arrays) -> None:
    """Store arrays atomically (write then rename); a cache that cannot be written is skipped."""
    folder = cache_dir()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, suffix=".npz")
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, folder / f"{name}-r{comm.rank}.npz")
    except OSError as err:
        log.warning("cache not written (%s): %s", folder, err)
