"""SciPy calls whose spelling changed between versions: one place for them, so that an upgrade touches one file."""

from __future__ import annotations

import inspect


def gmres(A, b, rtol: float, **options):
    """``scipy.sparse.linalg.gmres`` with its relative tolerance named ``tol`` (Debian 12's SciPy 1.10) or
    ``rtol`` (1.12 on)."""
    from scipy.sparse.linalg import gmres as plain

    return plain(A, b, **{_RTOL: rtol}, **options)


def _rtol_name() -> str:
    from scipy.sparse.linalg import gmres as plain

    return "rtol" if "rtol" in inspect.signature(plain).parameters else "tol"


_RTOL = _rtol_name()
