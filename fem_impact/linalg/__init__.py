"""Linear algebra: the algebra the integrators run on (distributed PETSc or small replicated numpy),
direct factorizations, and the PETSc and MUMPS calls their Python bindings do not reach.

The bottom layer of the package: it imports nothing of fem_impact but ``errors`` and ``parallel``.
Every call bound to a PETSc or MUMPS version lives here (``petsc_api.py``, ``mumps_api.py``), so
that an upgrade touches those files only.

- ``backends``: ``PETScAlgebra``, ``DenseAlgebra`` (vectors, products, factorizations, global sums);
- ``factor``: which direct solver a matrix gets, and the factors (``factorize``, ``Factor``, ...);
- ``condensed``: a factorization that keeps the contact dofs out (``CondensedFactor``);
- ``petsc_api``, ``mumps_api``: MUMPS' selected inverse entries and its Schur complement (ctypes).
"""
