"""Compile the package's Numba kernels into their cache now: ``python -m fem_impact.app.warm``.

``make setup`` runs it. Without it the first run (or test) that reaches each kernel compiles it
(20 s or so in all), and processes started side by side before the cache exists (a test suite's
workers, a study's runs) each compile the same kernels. The calls below reach every kernel with
the argument types the package passes it; a kernel met with other types later compiles then, as
before. The cache is keyed on the kernels' sources (fem_impact/compiled.py): after a change to one
of them this compiles again, and removes the caches of their earlier versions.
"""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import numpy as np


def _cone_problem(dim: int, p: int = 4, seed: int = 0):
    """A small well-posed frictional problem: W symmetric positive definite, every row pressed."""
    rng = np.random.default_rng(seed)
    n = p * dim
    A = rng.normal(size=(n, n))
    W = A @ A.T / n + np.eye(n)
    q = np.concatenate([-np.ones(p), rng.normal(size=p * (dim - 1))])
    return W, np.repeat(np.arange(p), dim - 1), np.full(p, 0.3), q


def warm() -> None:
    """Reach every kernel of fem_impact.compiled.KERNELS once."""
    from ..integrators import kernels
    from ..nonsmooth import cone
    from ..nonsmooth.friction import FrictionProblem

    kernels.warm_up()   # the compiled blocks (and the LCP kernel they call)
    from ..rigid import kernel

    kernel.warm_up()    # the mixed scenes' compiled steps (and the small cone solve they call)

    class Split(FrictionProblem):   # (W kept as two float32 parts from a few unknowns: that path's kernels)
        SINGLE_FROM = 4

    for dim in (2, 3):
        W, tangent_of, mu, q = _cone_problem(dim)
        active = np.ones(mu.size, dtype=np.bool_)
        for problem in (FrictionProblem(W, tangent_of, mu), FrictionProblem(W, tangent_of, mu, newton_first=False),
                        Split(W, tangent_of, mu)):
            problem.solve(q, active)
            problem.solve(q, active, guess=np.zeros(q.size))
        row, q_row = np.ascontiguousarray(W[:dim, :dim]), q[:dim].copy()   # (contiguous, as the package's are)
        cone.solve_row(row, q_row, 0.3)
        cone.solve_row(row, q_row, 0.3, np.ones(dim))
        cone.row_residual(np.ones(dim), np.ones(dim), 0.3, 1.0)
        cone.project(1.0, np.ones(dim - 1), 0.3, np.empty(dim - 1))
        starts = np.arange(0, q.size, dim, dtype=np.int64)
        sizes = np.full(mu.size, dim, dtype=np.int64)
        rho = 1.0 / W[starts, starts]
        cone.alart_curnier(W, q, np.zeros(q.size), starts, sizes, rho, mu, True)
        cone.alart_curnier_blocks(q.copy(), np.zeros(q.size), starts, sizes, rho, mu)


def prune() -> list[Path]:
    """Remove the caches of earlier versions of the kernels' sources (beside this version's, in the package's
    own folder; a cache directory set by NUMBA_CACHE_DIR is left alone). Returns what it removed."""
    import shutil

    import numba

    from .. import compiled

    current = Path(numba.config.CACHE_DIR)
    if os.environ.get("NUMBA_CACHE_DIR") or current.parent != compiled.PACKAGE / "__pycache__" / "numba" or \
            not current.parent.is_dir():   # (a fresh clone: no cache at all yet)
        return []
    # (only the folders compiled.py names, a 16-digit hex key: nothing else there is this program's to remove)
    stale = [path for path in current.parent.iterdir()
             if path.is_dir() and path != current and re.fullmatch(r"[0-9a-f]{16}", path.name)]
    for path in stale:
        shutil.rmtree(path, ignore_errors=True)
    return stale


def main() -> None:
    t0 = time.perf_counter()
    prune()
    warm()
    print(f"fem-impact: Numba kernels compiled or loaded from their cache in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
