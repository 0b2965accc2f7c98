"""The reduced model (METHOD.md s. 3): kept modes dynamically, the truncated ones statically.

``U = Y1 Z + S_k (R(t) - P^T lam)`` with ``S_k = K^-1 - Y1 diag(1/w1^2) Y1^T`` on the elastic
subspace. The modal equations ``Z'' + diag(mu1) Z' + diag(w1^2) Z + (P Y1)^T lam = Y1^T R`` are
handed to the same Newmark integrator and contact law as the full model, as small operators
replicated on every rank; the residual flexibility makes the contact rows compliant
(``P S_k P^T``). Nothing of size N is touched in the loop: physical fields are rebuilt from
precomputed columns only for probes (a few dofs) and output frames.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from .constraints import Constraints
from .integrators import Operators, StepState
from .integrators.base import factorize
from .model import Model

log = logging.getLogger(__name__)

RIGID_ROW = 1e-9   # neglected flexibility ratio below which a row counts as rigid (no compliance)


def _allsum(comm: MPI.Comm, local: np.ndarray) -> np.ndarray:
    local = np.ascontiguousarray(local, dtype=float)
    if comm.size > 1:
        comm.Allreduce(MPI.IN_PLACE, local, op=MPI.SUM)
    return local


def _diagonal(values: np.ndarray) -> PETSc.Mat:
    """A small diagonal matrix on this rank alone (the reduced system is replicated)."""
    A = PETSc.Mat().createAIJ([values.size, values.size], nnz=1, comm=PETSc.COMM_SELF)
    d = PETSc.Vec().createWithArray(np.array(values, dtype=float), comm=PETSc.COMM_SELF)
    A.setDiagonal(d)
    A.assemble()
    return A


class Flexibility:
    """Static solves on the elastic subspace: ``x = K^+ f`` with rigid-body modes projected out.

    For free bodies ``K`` is singular: the load is first freed of its rigid-body resultant
    (inertia relief, ``f - M Phi_r Phi_r^T f``), then ``(K + sigma M) x = f + sigma M x`` is
    iterated from a shifted factorization (each sweep divides the error by ``1 + w_1^2/sigma``)
    and the result is made mass-orthogonal to the rigid modes.
    """

    def __init__(self, K: PETSc.Mat, M: PETSc.Mat, rigid_local: np.ndarray, first_elastic_w2: float):
        self.M, self.rigid = M, rigid_local
        self.comm = K.getComm().tompi4py()
        self.sigma = 1e-3 * first_elastic_w2 if rigid_local.shape[1] else 0.0
        A = K.copy()
        if self.sigma:
            A.axpy(self.sigma, M, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        self.solve = factorize(A)
        self.b, self.x = K.createVecs()
        self.Mx = K.createVecs()[0]

    def _remove_rigid(self, local: np.ndarray, use_mass_on_left: bool) -> np.ndarray:
        """``f - M Phi (Phi^T f)`` (loads) or ``x - Phi (Phi^T M x)`` (displacements)."""
        if not self.rigid.shape[1]:
            return local
        if use_mass_on_left:
            coef = _allsum(self.comm, self.rigid.T @ local)
            return local - self._mass(self.rigid @ coef)
        coef = _allsum(self.comm, self.rigid.T @ self._mass(local))
        return local - self.rigid @ coef

    def _mass(self, local: np.ndarray) -> np.ndarray:
        self.b.array[:] = local
        self.M.mult(self.b, self.Mx)
        return self.Mx.array_r.copy()

    def apply(self, f_local: np.ndarray) -> np.ndarray:
        """K^+ f for one column (owned entries)."""
        f = self._remove_rigid(f_local, use_mass_on_left=True)
        x = np.zeros_like(f)
        for _ in range(8 if self.sigma else 1):
            self.b.array[:] = f + self.sigma * self._mass(x) if self.sigma else f
            self.solve(self.b, self.x)
            x = self.x.array_r.copy()
        return self._remove_rigid(x, use_mass_on_left=False)


class ModalLoad:
    """``Y1^T R(t)`` from the projected load vectors, on a small replicated vector."""

    def __init__(self, constant: np.ndarray, varying: list):
        self.constant, self.varying = constant, varying
        self.time_dependent = bool(varying)

    def evaluate(self, t: float, out: PETSc.Vec) -> PETSc.Vec:
        values = self.constant.copy()
        for f, r in self.varying:
            values += float(f.evaluate(t=t)) * r
        out.array[:] = values
        return out


@dataclass
class StaticCorrection:
    """The quasi-static part ``S_k (R(t) - P^T lam)`` seen from the contact rows (``StaticPart``)."""

    compliance: np.ndarray         # P S_k P^T
    rigid_rows: np.ndarray
    load_offsets: np.ndarray       # P S_k [R_c, b_1, ...]           (p x nl)
    load_gram: np.ndarray          # [R_c, b_i]^T S_k [R_c, b_i]      (nl x nl)
    functions: list                # the time functions of b_1, ... (R_c has 1)

    def coefficients(self, t: float) -> np.ndarray:
        return np.array([1.0] + [float(f.evaluate(t=t)) for f in self.functions])

    def offset(self, t: float) -> np.ndarray:
        return self.load_offsets @ self.coefficients(t)

    def energy(self, t: float, force: np.ndarray) -> float:
        """1/2 f^T S_k f with f = R(t) - P^T force."""
        c = self.coefficients(t)
        return 0.5 * (c @ self.load_gram @ c) - force @ (self.load_offsets @ c) + 0.5 * force @ self.compliance @ force

    def work(self, t0: float, t1: float, f0: np.ndarray, f1: np.ndarray, gamma: float) -> float:
        """Work of the loads on the static displacement over a step: R_mean^T S_k (f1 - f0)."""
        c0, c1 = self.coefficients(t0), self.coefficients(t1)
        c_mean = (1.0 - gamma) * c0 + gamma * c1
        return c_mean @ self.load_gram @ (c1 - c0) - c_mean @ self.load_offsets.T @ (f1 - f0)


class ReducedFields:
    """Physical fields from the modal state: ``u = Y1 Z + X_R c(t) - X_P F`` (+ velocities)."""

    def __init__(self, Y1: np.ndarray, XR: np.ndarray | None, XP: np.ndarray | None, static, cons: Constraints, dt):
        self.Y1, self.XR, self.XP, self.static, self.cons, self.dt = Y1, XR, XP, static, cons, dt
        self._previous = None   # (t, force) of the previous step, for the static part's velocity

    def _static(self, rows, t: float, force: np.ndarray) -> np.ndarray:
        if self.static is None:
            return 0.0
        return self.XR[rows] @ self.static.coefficients(t) - self.XP[rows] @ force

    def _parts(self, state: StepState, rows):
        u = self.Y1[rows] @ state.U.array_r + self._static(rows, state.t, state.force)
        v = self.Y1[rows] @ state.V.array_r
        if self.static is not None and self._previous is not None and self._previous[0] < state.t:
            t0, f0 = self._previous
            v = v + (self._static(rows, state.t, state.force) - self._static(rows, t0, f0)) / (state.t - t0)
        return u, v

    def at(self, state: StepState, dofs: np.ndarray):
        u, v = self._parts(state, dofs)
        return u, v

    def frame(self, state: StepState) -> dict[str, np.ndarray]:
        rows = slice(None)
        u, v = self._parts(state, rows)
        return {"u": u, "v": v, "a": self.Y1 @ state.A.array_r, "contact_force": -(self.cons.P_local @ state.force)}

    def write(self, state: StepState) -> None:
        """Observer hook, registered last: remembers the step for the next velocity difference."""
        self._previous = (state.t, state.force.copy())


@dataclass
class ReducedModel:
    operators: Operators
    fields: ReducedFields
    Z0: PETSc.Vec
    Zdot0: PETSc.Vec
    modes: int
    cutoff_hz: float
    neglected_flexibility: np.ndarray   # per contact row: (P S_k P^T)_jj / (P K^+ P^T)_jj
    flexibility_columns: np.ndarray     # K^+ [P^T, R_c, b_1, ...] (owned rows): reusable


def static_load_columns(model: Model, cons: Constraints) -> np.ndarray:
    """[P^T, R_c, b_1, ...]: the load patterns whose static response the reduction needs (owned rows)."""
    load = model.load
    R_cols = [load.constant.array_r.copy()] + [b.array_r.copy() for _, b in load.varying]
    return np.column_stack([cons.P_local.toarray()] + R_cols)


def build_reduced(model: Model, cons: Constraints, modes, n1: int, static_correction: bool, alpha: float,
                  beta: float, dt: float, flexibility_columns: np.ndarray | None = None) -> ReducedModel:
    """The reduced operators for the first ``n1`` modes of ``modes`` (rigid ones included).

    ``flexibility_columns`` (K^+ applied to ``static_load_columns``, from an earlier run of the
    same scene) skips the static solves.
    """
    comm = model.comm
    Y1 = np.ascontiguousarray(modes.Y_local[:, :n1])
    w2 = np.asarray(modes.omega2[:n1], dtype=float)
    P_local = cons.P_local
    Pr = _allsum(comm, (P_local.T @ Y1))                       # P Y1 (p x n1)
    load = model.load
    columns = static_load_columns(model, cons)
    R_cols = [columns[:, k] for k in range(cons.p, columns.shape[1])]
    R_modal = [_allsum(comm, Y1.T @ r) for r in R_cols]
    modal_load = ModalLoad(R_modal[0], [(f, r) for (f, _), r in zip(load.varying, R_modal[1:], strict=True)])

    M_U0, M_V0 = model.M.createVecs()
    model.M.mult(model.U0, M_U0)
    model.M.mult(model.V0, M_V0)
    Z0 = PETSc.Vec().createWithArray(_allsum(comm, Y1.T @ M_U0.array_r), comm=PETSc.COMM_SELF)
    Zdot0 = PETSc.Vec().createWithArray(_allsum(comm, Y1.T @ M_V0.array_r), comm=PETSc.COMM_SELF)

    # Residual flexibility of the truncated modes, from static solves on the elastic subspace.
    elastic = ~modes.rigid
    if flexibility_columns is None:
        rigid_local = modes.Y_local[:, modes.rigid]
        first_w2 = float(modes.omega2[elastic][0]) if elastic.any() else 1.0
        flex = Flexibility(model.regular_stiffness(), model.M, rigid_local, first_w2)
        flexibility_columns = np.column_stack([flex.apply(columns[:, j]) for j in range(columns.shape[1])])
    full = flexibility_columns
    kept_elastic = elastic[:n1]
    Y1e, w1e = Y1[:, kept_elastic], w2[kept_elastic]
    P_dense = columns[:, : cons.p]
    X = full - Y1e @ (_allsum(comm, Y1e.T @ columns) / w1e[:, None])
    XP, XR = X[:, : cons.p], X[:, cons.p:]
    flex_full = np.diag(_allsum(comm, P_dense.T @ full[:, : cons.p])) if cons.p else np.zeros(0)
    compliance = _allsum(comm, P_dense.T @ XP)
    compliance = 0.5 * (compliance + compliance.T)
    neglected = np.divide(np.diag(compliance), flex_full, out=np.zeros(cons.p), where=flex_full > 0)

    static = None
    if static_correction:
        rigid_rows = neglected <= RIGID_ROW
        static = StaticCorrection(
            compliance=np.where(np.outer(rigid_rows, rigid_rows), 0.0, compliance),
            rigid_rows=rigid_rows,
            load_offsets=_allsum(comm, P_dense.T @ XR).reshape(cons.p, -1),
            load_gram=_allsum(comm, np.column_stack(R_cols).T @ XR),
            functions=[f for f, _ in load.varying],
        )
    C = _diagonal(alpha + beta * w2) if (alpha or beta) else None
    ops = Operators(_diagonal(np.ones(n1)), _diagonal(w2), C, modal_load, Pr.T.copy(), cons.d0, cons.restitution,
                    static=static)
    fields = ReducedFields(Y1, XR if static else None, XP if static else None, static, cons, dt)
    cutoff = float(np.sqrt(w2[-1]) / (2 * np.pi))
    log.info("reduced model: %d modes (cut-off %.4g Hz), static correction %s", n1, cutoff, static_correction)
    return ReducedModel(ops, fields, Z0, Zdot0, n1, cutoff, neglected, full)
