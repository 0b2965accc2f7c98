"""Many contact rows: the LCP solver at a few hundred rows, and a plate falling face-first with
every face node a contact row against the same bar in 1D (cases/plate_drop.yaml)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

from conftest import CASES
from fem_impact.nonsmooth.lcp import Delassus, regularized, solve_lcp

PLATE = CASES / "plate_drop.yaml"
BAR_1D = ["mesh.dim=1", "mesh.height=null", "mesh.width=null", "mesh.elements=simplex", "initial.velocity=[-1.0]",
          "contacts.0.normal=[-1.0]",
          "output.probes.left=[0.0]", "output.probes.right=[1.0]"]


def lcp_by_nnls(A, q):
    """The LCP with SPD ``A`` as ``min 1/2 x'Ax + q'x, x >= 0``: ``min |L'x + L^-1 q|`` (A = L L')."""
    L = np.linalg.cholesky(A)
    return nnls(L.T, -np.linalg.solve(L, q), maxiter=50 * q.size)[0]


@pytest.mark.parametrize("seed", range(6))
def test_block_pivoting_matches_nnls_at_a_few_hundred_rows(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(200, 400))
    B = rng.normal(size=(n, n // 2))
    A = B @ B.T + 0.05 * n * np.eye(n)     # SPD, like a Delassus matrix
    q = rng.normal(size=n)
    guess = rng.random(n) < 0.5
    solver = Delassus(A)
    x, w, active = solver.solve(q, guess=guess)
    reference = lcp_by_nnls(A, q)
    scale = np.abs(reference).max()
    np.testing.assert_allclose(x, reference, atol=1e-9 * scale)
    assert np.all(x >= 0) and np.all(w >= 0) and abs(x @ w) < 1e-9 * scale * np.abs(q).max() * n
    np.testing.assert_allclose(w, A @ x + q, atol=1e-9 * np.abs(q).max())
    # Warm start from the solution: the kept factor, no pivoting, the same answer.
    x2, _, active2 = solver.solve(q, guess=active)
    np.testing.assert_array_equal(active2, active)
    np.testing.assert_allclose(x2, x, rtol=0, atol=1e-12 * scale)
    # The wrapper gives the same.
    np.testing.assert_allclose(solve_lcp(A, q, guess=guess)[0], x, atol=1e-12 * scale)


def test_lcp_on_a_principal_submatrix_shares_the_solver():
    rng = np.random.default_rng(7)
    n = 250
    B = rng.normal(size=(n, n))
    A = B @ B.T + n * np.eye(n)
    rows = np.sort(rng.choice(n, size=120, replace=False))
    q = rng.normal(size=rows.size)
    x = Delassus(A).solve(q, rows=rows)[0]
    np.testing.assert_allclose(x, lcp_by_nnls(A[np.ix_(rows, rows)], q), atol=1e-9 * np.abs(x).max())


def test_regularized_shifts_a_singular_large_matrix_only():
    rng = np.random.default_rng(3)
    n = 300
    B = rng.normal(size=(n, n))
    A = B @ B.T + n * np.eye(n)
    assert regularized(A) is A and Delassus.regularized(A).matrix is A
    C = rng.normal(size=(n, n // 2))
    singular = C @ C.T                     # rank n/2: more rows than the motion tells apart
    shifted = regularized(singular)
    assert shifted is not singular and np.all(np.linalg.eigvalsh(shifted) > 0)
    np.testing.assert_allclose(Delassus.regularized(singular).matrix, shifted)


def _plate_against_bar(run, cells: int, *extra: str, tol: float = 1e-6):
    dt = 0.5 / cells
    common = [f"mesh.cells={cells}", f"solver.dt={dt}", "solver.t_end=2.5", "output.every=1", "output.vtk=false",
              *extra]
    _, plate = run(PLATE, *common)
    _, bar = run(PLATE, *common, *BAR_1D)
    assert plate["floor_impulse"].sum() > 0.9 * 2 * 25.0    # the contact happened (exact: 2 rho c A v0 = 50)
    for name in bar.dtype.names:
        if name in ("t", "energy_error"):
            continue
        scale = max(np.abs(bar[name]).max(), 1e-300)
        assert np.abs(plate[name] - bar[name]).max() <= tol * scale, name
    return plate


def test_plate_with_441_contact_rows_is_the_1d_bar(run):
    """With nu = 0 a face moving as a whole is an exact solution of the discrete 3D equations
    (hexahedra: the element matrices are tensor products), so the plate's face forces sum to
    the bar's force, step by step."""
    _plate_against_bar(run, 4)


def test_explicit_plate_with_441_rows_is_the_1d_bar_row_by_row(run):
    """Central difference with a lumped mass: W = P M^-1 P^T is diagonal (each face node its own row),
    so the contact step is a projection per row. The plate is the lumped 1D bar to round-off (each face
    node a scaled copy of the bar's end), its momentum changes by the floor's impulses, and its energy
    (with the scheme's term) never exceeds the initial one."""
    plate = _plate_against_bar(run, 4, "solver.method=central_difference", "solver.mass=lumped", tol=1e-10)
    dp = plate["bar_px"] - plate["bar_px"][0]
    np.testing.assert_allclose(dp, np.cumsum(plate["floor_impulse"]), rtol=0, atol=1e-9 * 25.0)
    energy = plate["kinetic"] + plate["strain"] + plate["scheme_energy"]
    assert energy.max() <= energy[0] * (1 + 1e-12)
    plateau = plate["floor_force"][(plate["t"] > 0.5) & (plate["t"] < 1.8)]   # (4 cells: +-14 % about it)
    assert plateau.mean() == pytest.approx(25.0, rel=0.02)      # rho c A v0


def test_diagonal_lcp_is_the_pivoting_solver_on_a_diagonal_matrix():
    """DiagonalDelassus (a projection per row) against block pivoting on the same diagonal matrix, on all
    rows and on a subset (Carnot's closed rows), with rows pushed, free and exactly at zero."""
    from fem_impact.nonsmooth.lcp import DiagonalDelassus

    rng = np.random.default_rng(5)
    a = rng.uniform(0.5, 2.0, 300)
    q = rng.normal(size=300)
    q[:10] = 0.0
    for rows in (None, np.sort(rng.choice(300, 120, replace=False))):
        qq = q if rows is None else q[rows]
        x, w, active = DiagonalDelassus(a).solve(qq, rows=rows)
        reference = Delassus(np.diag(a)).solve(qq, rows=rows)[0]
        np.testing.assert_allclose(x, reference, rtol=0, atol=1e-14)
        assert np.all(x >= 0) and np.all(w >= 0) and np.all(x * w == 0)
        np.testing.assert_allclose(w, (a if rows is None else a[rows]) * x + qq, atol=1e-14)
    with pytest.raises(Exception, match="touches no mass"):
        DiagonalDelassus(np.array([1.0, 0.0]))


def test_diagonal_delassus_equals_the_solves():
    """The explicit method's W on a diagonal mass: a sparse diagonal equal to P M^-1 P^T from solves
    (each face node a row, or the face's mean: one row); rows that share a dof keep the dense W."""
    from mpi4py import MPI
    from scipy import sparse

    from fem_impact.build import model_and_constraints
    from fem_impact.config.case import load_case
    from fem_impact.integrators import Operators

    for coupling, rows in (("each", 441), ("mean", 1)):
        case = load_case(PLATE, ["mesh.cells=4", "solver.mass=lumped", f"contacts.0.coupling={coupling}"])
        model, cons = model_and_constraints(case, MPI.COMM_WORLD)
        ops = Operators(model.M, model.K, model.C, model.load, cons.P_local, cons.d0, cons.restitution)
        solve = ops.algebra.factorize(model.M)
        W, G = ops.delassus(solve, diagonal=True)
        dense = ops.project(ops.solve_columns(solve))
        assert ops.p == rows and sparse.issparse(W)
        assert np.abs(W.toarray() - dense).max() <= 1e-14 * np.abs(dense).max()
        c, y = np.linspace(1.0, 2.0, rows), ops.algebra.vector()
        G.subtract_from(y, c)
        np.testing.assert_allclose(ops.project(y), -dense @ c, rtol=1e-13)
    # two rows on the same dofs (the mean row twice): W has off-diagonal entries, and stays dense
    P = sparse.csr_matrix(cons.P_local)
    shared = Operators(model.M, model.K, model.C, model.load, sparse.hstack([P, P]).tocsr(), np.zeros(2),
                       np.zeros(2))
    W, _ = shared.delassus(solve, diagonal=True)
    assert not sparse.issparse(W) and W.shape == (2, 2) and W[0, 1] == pytest.approx(W[0, 0])


@pytest.mark.slow
def test_plate_with_1681_contact_rows_is_the_1d_bar(run):
    _plate_against_bar(run, 8)


@pytest.mark.parametrize("entries", [None, 200_000])
def test_w_from_inverse_entries_in_place_equals_the_solves(monkeypatch, entries):
    """441 face rows with their tangents (1323 rows, one dof each, each dof once): W from MUMPS'
    inverse entries, permuted and signed in place, equals P S^-1 P^T from solves; also when the
    entries are asked for in blocks of columns (151 columns a block: 9 blocks, the last short)."""
    from mpi4py import MPI

    from fem_impact.linalg import petsc_api

    if entries is not None:
        monkeypatch.setattr(petsc_api, "INVERSE_ENTRIES", entries)

    from fem_impact.build import make_integrator, model_and_constraints
    from fem_impact.config.case import load_case
    from fem_impact.integrators import Operators

    case = load_case(PLATE, ["contacts.0.friction=0.3", "mesh.cells=4"])
    model, cons = model_and_constraints(case, MPI.COMM_WORLD)
    ops = Operators(model.M, model.K, model.C, model.load, cons.P_local, cons.d0, cons.restitution,
                    friction=cons.friction, tangents=cons.tangent_local, tangent_of=cons.tangent_of)
    rows = ops.with_tangents()
    solve = make_integrator(case, ops).solve_S
    assert hasattr(solve, "inverse_block") and rows.p == 1323
    W = rows.delassus(solve)[0]
    reference = rows.project(rows.solve_columns(solve))
    assert np.abs(W - reference).max() <= 1e-12 * np.abs(reference).max()


@pytest.mark.parametrize("method, courant", [("moreau_jean", 0.5), ("moreau_jean", 8.0), ("newmark", 0.5)])
def test_a_condensed_step_matrix_gives_w_and_the_contact_steps_of_a_plain_factor(monkeypatch, method, courant):
    """441 face rows without friction: S factorized keeping the rows' dofs out (S's elimination takes
    about 11 m^3 flops, above SCHUR_FLOPS). W = P S^-1 P^T is the inverse of its Schur complement
    and D = P M^-1 P^T comes from MUMPS' inverse entries (M's three decoupled components: 1.4 m^3),
    each equal to P A^-1 P^T from a plain factor's solves; and the contact steps of Moreau-Jean and
    of the paper's scheme, each one solve with the impulse between its halves, are those of the
    plain factor's two solves; Moreau-Jean's energy never above E0 + W_ext with its losses >= 0, at
    Courant numbers 0.5 and 8."""
    from mpi4py import MPI

    from fem_impact.build import make_integrator, model_and_constraints
    from fem_impact.config.case import load_case
    from fem_impact.integrators import Operators
    from fem_impact.linalg import factor
    from fem_impact.linalg.condensed import CondensedFactor
    from fem_impact.mechanics import system

    monkeypatch.setattr(system, "KEEP_COLUMNS", 0)   # (6615 x 441 columns would be kept: W from them)
    routes = []
    original = factor.mumps_inverse_block
    monkeypatch.setattr(factor, "mumps_inverse_block", lambda *a: routes.append(a[1].size) or original(*a))
    dt = courant * 0.25   # (c = 1, h = 1/4)
    case = load_case(PLATE, ["mesh.cells=4", f"solver.dt={dt}", f"contacts.0.gap={1.5 * dt}", f"solver.method={method}"])
    model, cons = model_and_constraints(case, MPI.COMM_WORLD)

    def integrator(condensed: bool):
        ops = Operators(model.M, model.K, model.C, model.load, cons.P_local, cons.d0, cons.restitution)
        if not condensed:
            monkeypatch.setattr(ops, "condensed_dofs", lambda: None)
        made = make_integrator(case, ops)
        made.start(model.U0, model.V0)
        return ops, made

    ops, condensed = integrator(True)
    assert ops.p == 441 and isinstance(condensed.solve_S, CondensedFactor) and routes == []
    plain_ops, plain = integrator(False)
    assert not isinstance(plain.solve_S, CondensedFactor) and routes == [441]   # (W by selected entries)
    for W, solve in ((condensed.W, plain.solve_S), (condensed.D, plain.solve_M)):
        reference = plain_ops.project(plain_ops.solve_columns(solve))
        assert np.abs(W - reference).max() <= 1e-12 * np.abs(reference).max()
    assert routes == [441, 441]   # (D by selected entries, for the condensed run's M)
    impulses = 0.0
    for _ in range(6):   # the floor reached at the second step: contact steps, Carnot's correction
        a, b = condensed.step(), plain.step()
        impulses += a.impulse.sum()
        for name in ("U", "V"):
            x, y = getattr(a, name), getattr(b, name)
            assert np.abs(x - y).max() <= 1e-10 * np.abs(y).max(), name
        assert np.abs(a.impulse - b.impulse).max() <= 1e-10 * max(np.abs(b.impulse).max(), 1e-300)
        assert abs(a.energy.total - b.energy.total) <= 1e-10 * b.energy.initial
        e = a.energy
        if method == "moreau_jean":
            assert e.total <= e.initial + e.external_work + 1e-12 * e.initial
            assert min(e.impact_loss, e.contact_loss) >= -1e-12 * e.initial
    assert impulses > 0.0   # (the steps were contact steps)
