"""On-disk cache of expensive, reusable results (modes, static solves), keyed by their inputs and the code.

The key hashes the operators themselves (the local CSR arrays of K and M, which carry the
mesh, the materials and the supports), whatever else the result depends on (the solver's
tolerances and settings, which the caller passes), and always the code that computes it: the
package's version and :func:`code_fingerprint`. So neither a changed scene nor a fixed bug can
pick up a stale result. Entries are ``.npz`` files in ``$FEM_IMPACT_CACHE`` (default
``~/.cache/fem-impact``); deleting the folder is always safe.

Only numpy is imported here (the communicator and the matrices are duck-typed): a light command
(a study resuming its levels) can take :func:`code_fingerprint` from here.
"""

from __future__ import annotations

import hashlib
import logging
import os
import tempfile
from pathlib import Path

import numpy as np

from ._version import __version__

log = logging.getLogger(__name__)

PACKAGE = Path(__file__).resolve().parent
#: Modules (files or folders of the package) that only present results: editing them changes
#: nothing that is computed, so it keeps cache entries and a study's completed levels valid.
PRESENTATION = frozenset({"studies", "plots.py", "animate.py", "paraview_view.py", "cli.py", "references.py",
                          "progress.py", "__main__.py"})


def cache_dir() -> Path:
    return Path(os.environ.get("FEM_IMPACT_CACHE", Path.home() / ".cache" / "fem-impact"))


def code_fingerprint() -> str:
    """A hash of the package's sources that decide what is computed (all but :data:`PRESENTATION`)."""
    h = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] in PRESENTATION:
            continue
        h.update(str(rel).encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:20]


def key(comm, *parts) -> str:
    """A hash of the code (version, :func:`code_fingerprint`), the number of ranks, and ``parts``:
    PETSc matrices, arrays and plain values (a dict of settings by its repr); the same on every rank."""
    h = hashlib.sha256(f"{__version__}\0{code_fingerprint()}\0{comm.size}".encode())
    for part in parts:
        if hasattr(part, "getValuesCSR"):   # a PETSc matrix: its local rows
            for array in part.getValuesCSR():
                h.update(np.ascontiguousarray(array).tobytes())
        elif isinstance(part, np.ndarray):
            h.update(str(part.shape).encode() + np.ascontiguousarray(part).tobytes())
        else:
            h.update(repr(part).encode())
    # Each rank hashed its own rows: combine them so every rank names the same entry.
    return hashlib.sha256("".join(comm.allgather(h.hexdigest())).encode()).hexdigest()[:32]


def load(name: str, comm) -> dict | None:
    """The arrays stored under ``name`` for this rank, or None when any rank misses them."""
    path = cache_dir() / f"{name}-r{comm.rank}.npz"
    try:
        with np.load(path) as data:
            found = {k: data[k] for k in data.files}
    except (OSError, ValueError):
        found = None
    return found if all(comm.allgather(found is not None)) else None


def save(name: str, comm, **arrays) -> None:
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
