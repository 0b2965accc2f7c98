"""Natural modes of the finite-element model: ``K y = w^2 M y`` with SLEPc (docs/theory.md s. 8.1).

The eigenproblem is solved on the free dofs only: the rows and columns that supports hold
(``model.fixed``) are taken out of M and K (``createSubMatrix``), so they neither give
spurious modes nor make the mass matrix singular; the mode shapes are zero there.

SLEPc runs a Krylov-Schur iteration on the shift-and-invert operator ``(K - sigma M)^-1 M``
with one direct LU factorization (MUMPS when PETSc has it). The shift ``sigma`` is negative
and small (:data:`SHIFT` times a stiffness/mass scale), so ``K - sigma M`` stays regular for
free bodies, whose rigid-body modes (``w = 0``) make ``K`` singular, and the modes nearest to
it are the lowest ones. The converged vectors then go through a Rayleigh-Ritz step
(``Y^T K Y c = w^2 Y^T M Y c``), which makes them exactly M-orthonormal (also in clusters of
equal frequencies, e.g. the two bending modes of a square section) and gives the best
frequencies in their span; every mode is checked by its own residual.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from mpi4py import MPI
from petsc4py import PETSc

from ..errors import SimulationError
from ..parallel import allsum

log = logging.getLogger(__name__)

AXES = "xyz"

#: Largest accepted relative residual ``||K y - w^2 M y|| / (||K y|| + w^2 ||M y||)``.
RESIDUAL_LIMIT = 1e-6
#: A mode with ``w^2 < RIGID * scale`` is a rigid-body mode (``scale`` = max of diag(K)/diag(M),
#: of the order of the largest eigenvalue of the mesh).
RIGID = 1e-11
#: The shift is ``-SHIFT * scale``: far below any elastic ``w^2`` of a sound mesh, and
#: ``K - sigma M`` is still well conditioned enough (~1/SHIFT) for a direct solve.
SHIFT = 1e-8
#: The count check looks below ``(1 - COUNT_MARGIN)`` times the highest eigenvalue found.
COUNT_MARGIN = 1e-6
#: Eigenvalues within this fraction of each other are one multiple eigenvalue (round-off apart: a
#: square-section cantilever of hexahedra gives its two first bending modes 5e-11 apart).
CLUSTER = 1e-8
#: SLEPc's convergence tolerance (the default of :func:`compute_modes`) and iteration limit.
TOLERANCE = 1e-10
MAX_ITERATIONS = 1000


class ModesError(SimulationError):
    """The eigensolver did not deliver the modes asked for (no convergence, large residuals)."""


class ModeCountError(ValueError):
    """Fewer than 1 mode, or at least as many modes as the model has free dofs, were asked for.

    ``available`` is the number of free dofs; at most ``available - 1`` modes can be computed
    iteratively, or all of them on a small serial model (a dense solve).
    """

    def __init__(self, requested: int, available: int):
        self.requested, self.available = requested, available
        if requested < 1:
            message = f"asked for {requested} modes; ask for at least 1"
        else:
            most = available if available <= DENSE_LIMIT else available - 1
            message = (f"asked for {requested} modes but the model has only {available} free dofs; "
                       f"ask for at most {most}")
        super().__init__(message)


@dataclass
class Modes:
    """The lowest ``n`` modes, sorted by frequency.

    ``Y_local`` holds the owned rows (this rank's owned dofs, in the model's local order, zero
    on supported dofs) of the mass-normalized shapes, one column per mode: ``Y^T M Y = I``.
    ``omega2`` are the eigenvalues ``w^2`` (exactly 0 for rigid-body modes, flagged in
    ``rigid``), ``residual`` the relative residual of each mode (for a rigid-body mode
    ``||K y|| / (scale ||M y||)``). ``scale`` is the stiffness/mass scale of the mesh (max of
    diag(K)/diag(M) over the free dofs) and ``shift`` the spectral shift that was used.
    """

    omega2: np.ndarray
    Y_local: np.ndarray
    residual: np.ndarray
    rigid: np.ndarray
    scale: float
    shift: float
    comm: MPI.Comm

    @property
    def n(self) -> int:
        return self.omega2.size

    @property
    def omega(self) -> np.ndarray:
        return np.sqrt(self.omega2)

    @property
    def frequency_hz(self) -> np.ndarray:
        return np.sqrt(self.omega2) / (2.0 * np.pi)

    @property
    def n_rigid(self) -> int:
        return int(self.rigid.sum())


DENSE_LIMIT = 2000   # free dofs up to which all modes may be asked for (dense eigensolver)


def free_dof_count(model) -> int:
    """Number of dofs not held by supports (all ranks)."""
    return model.dofs - model.comm.allreduce(int(model.fixed.size), op=MPI.SUM)


def solver_settings(tol: float | None = None, check_count: bool = True) -> dict:
    """What decides the modes :func:`compute_modes` returns besides the operators: part of their
    cache key (fem_impact.cache), so that a changed tolerance or library never reuses old modes."""
    import slepc4py

    return {"tol": TOLERANCE if tol is None else tol, "max_it": MAX_ITERATIONS, "shift": SHIFT, "rigid": RIGID,
            "residual_limit": RESIDUAL_LIMIT, "check_count": check_count, "count_margin": COUNT_MARGIN,
            "dense_limit": DENSE_LIMIT, "mumps": PETSc.Sys.hasExternalPackage("mumps"),
            "petsc": PETSc.Sys.getVersion(), "slepc": slepc4py.__version__, "orientation": "field-1"}


def compute_modes(model, n: int, tol: float | None = None, check_count: bool = True) -> Modes:
    """The ``n`` lowest modes of ``K y = w^2 M y`` on the free dofs of ``model``.

    ``tol`` is SLEPc's convergence tolerance (None: :data:`TOLERANCE`). With ``check_count`` (and MUMPS), one more
    factorization counts the eigenvalues below the highest mode found (Sylvester's law of
    inertia of ``K - s M``): a mode the Krylov iteration skipped, e.g. one of a multiple
    eigenvalue, is an error instead of a silent gap.

    Raises
    ------
    ModeCountError
        ``n < 1`` or ``n >= free_dof_count(model)``.
    ModesError
        SLEPc converged fewer than ``n`` modes, a mode's residual is above
        :data:`RESIDUAL_LIMIT`, or the count found modes missing.
    """
    comm = model.comm
    tol = TOLERANCE if tol is None else tol
    available = free_dof_count(model)
    # All modes (a check of the reduction on small models) come from a dense solve; the
    # Krylov solver finds at most one fewer than the dimension.
    dense = n == available and available <= DENSE_LIMIT and comm.size == 1
    if n < 1 or (n >= available and not dense):
        raise ModeCountError(n, available)
    n_local = model.M.getLocalSize()[0]
    free = np.ones(n_local, dtype=bool)
    free[model.fixed] = False
    start = model.M.getOwnershipRange()[0]
    index_set = PETSc.IS().createGeneral((start + np.flatnonzero(free)).astype(PETSc.IntType), comm=comm)
    K = model.K.createSubMatrix(index_set, index_set)
    M = model.M.createSubMatrix(index_set, index_set)
    index_set.destroy()

    try:
        scale = _stiffness_scale(K, M, comm)
        shift = -SHIFT * scale
        if dense:
            X = scipy.linalg.eigh(K.convert("dense").getDenseArray(), M.convert("dense").getDenseArray())[1]
            return _finish(model, comm, K, M, X, free, n_local, scale, shift, check_count=False)
        eps = _solver(K, M, n, shift, tol, comm)
        eps.solve()
        converged = eps.getConverged()
        if converged < n:
            reason = eps.getConvergedReason()
            its = eps.getIterationNumber()
            eps.destroy()
            raise ModesError(f"the eigensolver converged {converged} of the {n} modes asked for after {its} "
                             f"iterations (SLEPc reason {reason}); ask for fewer modes or a looser tolerance")
        log.info("modes: %d of %d converged in %d iterations (shift %.3g)", converged, n,
                 eps.getIterationNumber(), shift)

        vec = K.createVecs()[0]
        X = np.empty((vec.getLocalSize(), n))
        for i in range(n):
            eps.getEigenvector(i, vec)
            X[:, i] = vec.array_r
        eps.destroy()
        return _finish(model, comm, K, M, X, free, n_local, scale, shift, check_count)
    finally:
        K.destroy()
        M.destroy()


def warn_if_split(modes: Modes, n: int) -> None:
    """Warn when the first ``n`` of ``modes`` end inside a multiple eigenvalue (modes n and n + 1
    within ``CLUSTER``): they then hold only part of its subspace, and which part is decided by
    round-off (a reduced model built on them changes from machine to machine)."""
    if n >= modes.n:
        return
    last, following = float(modes.omega2[n - 1]), float(modes.omega2[n])
    if abs(following - last) <= CLUSTER * max(abs(last), RIGID * modes.scale):
        log.warning("modes: the %d modes kept end inside a multiple eigenvalue (modes %d and %d both at "
                    "%.6g Hz): which of its vectors are kept is decided by round-off; keep more modes, "
                    "all of that frequency", n, n, n + 1, np.sqrt(max(last, 0.0)) / (2.0 * np.pi))


def _finish(model, comm, K, M, X, free, n_local, scale, shift, check_count) -> Modes:
    """Rayleigh-Ritz on the converged vectors, rigid modes, signs, residual checks."""
    n = X.shape[1]
    # Rayleigh-Ritz in span(X): M-orthonormal vectors and the best w^2 in that subspace.
    KX, MX = _apply(K, X), _apply(M, X)
    Kr = comm.allreduce(X.T @ KX, op=MPI.SUM)
    Mr = comm.allreduce(X.T @ MX, op=MPI.SUM)
    Kr, Mr = 0.5 * (Kr + Kr.T), 0.5 * (Mr + Mr.T)
    if not (np.isfinite(Kr).all() and np.isfinite(Mr).all()):   # (vectors of NaN: scales far from 1)
        raise ModesError(f"the eigensolver's vectors are not finite (largest stiffness over mass {scale:.3g}): "
                         "the model's scales are beyond what it resolves; use other units")
    omega2, C = scipy.linalg.eigh(Kr, Mr)
    rigid = omega2 < RIGID * scale
    # Rigid-body modes are any basis of their subspace: order them as translations x, y, z
    # first (each the M-projection of the unit translation onto the subspace), then the rest.
    if rigid.sum() > 1:
        T = comm.allreduce((MX @ C[:, rigid]).T @ _translations(free, model.bs), op=MPI.SUM)
        Q = scipy.linalg.qr(T, mode="full")[0]
        C[:, rigid] = C[:, rigid] @ Q
    X, KX, MX = X @ C, KX @ C, MX @ C
    # A deterministic sign: the entry of largest magnitude is positive.
    X, KX, MX = (A * _signs(X, comm) for A in (X, KX, MX))

    omega2 = np.where(rigid, 0.0, omega2)
    norm = lambda A: np.sqrt(comm.allreduce(np.einsum("ij,ij->j", A, A), op=MPI.SUM))  # noqa: E731
    k_norm, m_norm = norm(KX), norm(MX)
    res_norm = norm(KX - MX * omega2)
    denominator = np.where(rigid, scale * m_norm, k_norm + omega2 * m_norm)
    residual = res_norm / denominator
    bad = np.flatnonzero(~(residual <= RESIDUAL_LIMIT))
    if bad.size:
        raise ModesError(f"mode {bad[0] + 1} has a relative residual {residual[bad[0]]:.2g} (limit "
                         f"{RESIDUAL_LIMIT:g}; {n - bad.size} of the {n} modes are within it)")
    if check_count:
        _check_count(K, M, omega2, comm)
    Y_local = np.zeros((n_local, n))
    Y_local[free] = X
    _orient(model, Y_local)
    return Modes(omega2, Y_local, residual, rigid, scale, shift, comm)


def _orient(model, Y_local: np.ndarray) -> None:
    """Each mode's sign, the same on any count of ranks and any partition: positive against a fixed,
    generic field of the node coordinates (so that a restart's modal state means what it meant)."""
    coords = model.node_coords[: model.n_owned_nodes]
    bs = model.bs
    field = (1.0 + 0.37 * coords[:, 0] + 0.61 * coords[:, 1] + 0.83 * coords[:, 2])[:, None] \
        + 0.29 * np.arange(bs)[None, :]
    against = allsum(model.comm, field.reshape(-1) @ Y_local)
    Y_local[:, against < 0.0] *= -1.0


def participation(modes: Modes, model) -> np.ndarray:
    """Effective modal mass fraction (n, dim): ``(y_i^T M r_d)^2 / (r_d^T M r_d)``.

    ``r_d`` is the unit translation in direction ``d`` of the free dofs (zero on supported
    dofs, which do not move). Over all modes the fractions of a direction sum to 1.
    """
    bs = model.bs
    r = model.M.createVecs()[0]
    Mr = r.duplicate()
    out = np.empty((modes.n, bs))
    for d in range(bs):
        values = np.zeros(r.getLocalSize())
        values.reshape(-1, bs)[:, d] = 1.0
        values[model.fixed] = 0.0
        r.array[:] = values
        model.M.mult(r, Mr)
        total = r.dot(Mr)
        coupling = modes.comm.allreduce(modes.Y_local.T @ Mr.array_r, op=MPI.SUM)
        out[:, d] = coupling**2 / total if total > 0 else 0.0
    r.destroy()
    Mr.destroy()
    return out


def at_point(modes: Modes, model, group: str, direction: int, key: tuple = ("--at",)) -> dict[str, np.ndarray]:
    """Each mode seen from a node group along one direction (a single-dof oscillator per mode).

    With mass-normalized shapes, the group's mean displacement along ``direction`` is ``phi_i``;
    the modal mass at the group is ``1 / phi_i^2`` (a unit force there excites mode i as a mass
    ``1 / phi_i^2`` on a spring ``w_i^2 / phi_i^2``), inf where the mode does not move it. The
    participation factor is ``Gamma_i = y_i^T M r`` (r the unit translation along the direction;
    its square is the effective mass). Returns ``mass``, ``stiffness``, ``phi``, ``participation``.
    """
    nodes = model.node_set(group, key)
    owned = nodes.local_node[nodes.local_node >= 0]
    phi = modes.comm.allreduce(modes.Y_local[owned * model.bs + direction].sum(axis=0), op=MPI.SUM) / len(nodes)
    mass = np.full_like(phi, np.inf)
    moved = phi != 0.0
    mass[moved] = 1.0 / phi[moved] ** 2
    r = np.zeros(modes.Y_local.shape[0])
    r.reshape(-1, model.bs)[:, direction] = 1.0
    r[model.fixed] = 0.0
    Mr = _apply(model.M, r[:, None])[:, 0]
    gamma = modes.comm.allreduce(modes.Y_local.T @ Mr, op=MPI.SUM)
    return {"mass": mass, "stiffness": modes.omega2 * mass, "phi": phi, "participation": gamma}


def describe(modes: Modes, model) -> list[str]:
    """Per mode, which bodies move and along which axis: the shares of its kinetic energy (lumped
    masses: the momentum rows), e.g. ``horn_small 81 %, horn_large 19 %; x 100 %``."""
    out = []
    shares_b, shares_d = [], []
    for body, rows in model.momentum_rows.items():   # (owned dofs x directions: rho int phi_j on its direction)
        energy = rows.sum(axis=1)[:, None] * modes.Y_local**2
        shares_b.append((body, modes.comm.allreduce(energy.sum(axis=0), op=MPI.SUM)))
        shares_d.append(np.stack([modes.comm.allreduce(energy[d::model.bs].sum(axis=0), op=MPI.SUM)
                                  for d in range(model.bs)]))
    per_direction = np.sum(shares_d, axis=0)   # (dim, n)
    total = per_direction.sum(axis=0)
    x = model.meshdata.mesh.geometry.x[:, :model.bs]   # (this rank's part: the extents over all ranks)
    extent = [modes.comm.allreduce(float(x[:, d].max(initial=-np.inf)), op=MPI.MAX)
              - modes.comm.allreduce(float(x[:, d].min(initial=np.inf)), op=MPI.MIN) for d in range(model.bs)]
    long_axis = int(np.argmax(extent))
    for i in range(modes.n):
        if total[i] <= 0.0:
            out.append("")
            continue
        bodies = sorted(((share[i] / total[i], body) for body, share in shares_b), reverse=True)
        moving = ", ".join(f"{body} {100 * f:.0f} %" for f, body in bodies if f >= 0.05)
        axes = ", ".join(f"{AXES[d]} {100 * per_direction[d, i] / total[i]:.0f} %" for d in
                         np.argsort(-per_direction[:, i]) if per_direction[d, i] >= 0.05 * total[i])
        main = int(np.argmax(per_direction[:, i]))
        kind = ("mixed" if per_direction[main, i] < 0.5 * total[i] else
                "longitudinal" if main == long_axis else f"transverse ({AXES[main]})")
        out.append(f"{kind}: {moving}; {axes}")
    return out


def _stiffness_scale(K: PETSc.Mat, M: PETSc.Mat, comm: MPI.Comm) -> float:
    k, m = K.getDiagonal().array_r, M.getDiagonal().array_r
    ratio = np.abs(k[m > 0]) / m[m > 0]
    scale = comm.allreduce(float(ratio.max()) if ratio.size else 0.0, op=MPI.MAX)
    if not scale > 0.0:
        raise ModesError("the stiffness matrix has a zero diagonal on every free dof")
    return scale


def _solver(K: PETSc.Mat, M: PETSc.Mat, n: int, shift: float, tol: float, comm: MPI.Comm):
    from slepc4py import SLEPc

    eps = SLEPc.EPS().create(comm)
    eps.setOperators(K, M)
    eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps.setDimensions(nev=n)
    eps.setTolerances(tol=tol, max_it=MAX_ITERATIONS)
    eps.setTarget(shift)
    eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    st = eps.getST()
    st.setType(SLEPc.ST.Type.SINVERT)
    st.setShift(shift)
    ksp = st.getKSP()
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.LU)
    if PETSc.Sys.hasExternalPackage("mumps"):
        pc.setFactorSolverType("mumps")
    elif comm.size > 1:
        raise ModesError("computing modes in parallel needs PETSc with MUMPS (a parallel direct solver)")
    return eps


def _translations(free: np.ndarray, bs: int) -> np.ndarray:
    """Unit translations (owned free rows x bs): column d is 1 on the free dofs of component d."""
    component = np.arange(free.size) % bs
    return (component[free, None] == np.arange(bs)).astype(float)


def _check_count(K: PETSc.Mat, M: PETSc.Mat, omega2: np.ndarray, comm: MPI.Comm) -> None:
    """Compare the modes found with the number of eigenvalues below ``s`` = just under the highest."""
    if not omega2[-1] > 0.0 or not PETSc.Sys.hasExternalPackage("mumps"):
        return
    s = omega2[-1] * (1.0 - COUNT_MARGIN)
    A = K.copy()
    A.axpy(-s, M, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    ksp = PETSc.KSP().create(comm)
    ksp.setOperators(A)
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.CHOLESKY)
    pc.setFactorSolverType("mumps")
    pc.setFactorSetUpSolverType()
    factor = pc.getFactorMatrix()
    factor.setMumpsIcntl(13, 1)  # no ScaLAPACK on the root front: needed for the inertia in parallel
    factor.setMumpsIcntl(24, 1)  # null pivot detection: needed for the inertia
    pc.setUp()
    below = factor.getInertia()[0]
    ksp.destroy()
    A.destroy()
    found = int((omega2 < s).sum())
    if below != found:
        raise ModesError(f"the eigensolver missed {below - found} mode(s) below {np.sqrt(s) / (2 * np.pi):.6g} Hz "
                         f"({below} eigenvalues there, {found} found): a cluster the Krylov iteration did not resolve; "
                         "try a tighter tolerance")


def _apply(A: PETSc.Mat, X: np.ndarray) -> np.ndarray:
    """A @ X column by column (X holds owned rows)."""
    x, y = A.createVecs()
    out = np.empty_like(X)
    for i in range(X.shape[1]):
        x.array[:] = X[:, i]
        A.mult(x, y)
        out[:, i] = y.array_r
    x.destroy()
    y.destroy()
    return out


def _signs(X: np.ndarray, comm: MPI.Comm) -> np.ndarray:
    """+-1 per column so that the entry of largest magnitude (over all ranks) is positive."""
    if X.shape[0]:
        rows = np.abs(X).argmax(axis=0)
        peak = X[rows, np.arange(X.shape[1])]
    else:
        peak = np.zeros(X.shape[1])
    peaks = np.array(comm.allgather(peak))          # ranks x n
    best = peaks[np.abs(peaks).argmax(axis=0), np.arange(X.shape[1])]
    return np.where(best < 0, -1.0, 1.0)
