"""What every integrator shares: the operators it works on, its state, the energy budget, the loop."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc
from scipy import sparse

from ..errors import SimulationError  # noqa: F401  (re-exported)


class TimeDependentLoad(Protocol):
    time_dependent: bool

    def evaluate(self, t: float, out: PETSc.Vec) -> PETSc.Vec: ...


class StaticPart(Protocol):
    """A massless, quasi-static part of the displacement, ``U_s = S_k (R(t) - P^T lam)``.

    The reduced model's residual flexibility (METHOD.md s. 3): the contact rows see
    ``P U = P U_dyn + offset(t) - compliance lam``, so the contact becomes compliant; the
    energy of U_s and the work of the loads on it enter the energy budget.
    """

    compliance: np.ndarray     # P S_k P^T (p x p)
    rigid_rows: np.ndarray     # rows without compliance (they get Carnot's impact correction)

    def offset(self, t: float) -> np.ndarray: ...                      # P S_k R(t)

    def energy(self, t: float, force: np.ndarray) -> float: ...        # 1/2 f^T S_k f

    def work(self, t0: float, t1: float, f0: np.ndarray, f1: np.ndarray, gamma: float) -> float: ...


@dataclass
class Operators:
    """Plain operators of ``M U'' + C U' + K U + P^T lam = R(t)``, ``P U <= d0``.

    ``M``, ``K``, ``C`` (or None) are distributed PETSc matrices; ``P_local`` holds the owned
    rows of ``P^T`` (n_local x p, sparse or dense); the p-vectors ``d0`` and ``restitution`` are
    known on every rank. Nothing here knows about meshes, so the integrators run as well on
    a 1-dof system as on a finite-element model.
    """

    M: PETSc.Mat
    K: PETSc.Mat
    C: PETSc.Mat | None
    load: TimeDependentLoad
    P_local: sparse.spmatrix | np.ndarray
    d0: np.ndarray
    restitution: np.ndarray
    static: StaticPart | None = None

    def __post_init__(self):
        self.comm: MPI.Comm = self.K.getComm().tompi4py()
        self.P_local = sparse.csr_matrix(self.P_local)
        self._P = self.P_local.T.tocsr()  # owned columns of P, for P x in O(nnz)
        coo = self._P.tocoo()
        self._rows, self._cols, self._vals = coo.row, coo.col, coo.data

    @property
    def p(self) -> int:
        return self.d0.size

    def project(self, local: np.ndarray) -> np.ndarray:
        """``P x`` (or ``P X`` for a block of columns) from owned entries: one global sum."""
        part = np.ascontiguousarray(self._P @ local)
        comm = self.comm
        if comm.size > 1:
            comm.Allreduce(MPI.IN_PLACE, part, op=MPI.SUM)
        return part

    def project_many(self, *vecs: PETSc.Vec) -> list[np.ndarray]:
        """``P x`` for several PETSc vectors with a single reduction."""
        # A few nonzeros per row: one gather and one bincount per vector beat a sparse product.
        p, rows, cols, vals = self.p, self._rows, self._cols, self._vals
        # (astype: bincount of an empty array, on a rank without constraint dofs, gives ints)
        parts = [np.bincount(rows, vals * v.array_r[cols], minlength=p).astype(float, copy=False) for v in vecs]
        if self.comm.size > 1:
            stacked = np.concatenate(parts)
            self.comm.Allreduce(MPI.IN_PLACE, stacked, op=MPI.SUM)
            parts = [stacked[k * p:(k + 1) * p] for k in range(len(vecs))]
        return parts

    def solve_columns(self, solve: Callable[[PETSc.Vec, PETSc.Vec], None]) -> np.ndarray:
        """``A^-1 P^T`` (owned rows) for a factorized ``A``: p solves, once per run."""
        b, x = self.K.createVecs()
        out = np.empty(self.P_local.shape)
        for j in range(self.p):
            b.array[:] = self._P[j].toarray().ravel()
            solve(b, x)
            out[:, j] = x.array_r
        return out


def factorize(A: PETSc.Mat) -> Callable[[PETSc.Vec, PETSc.Vec], None]:
    """A direct solver for ``A``, factorized now, once.

    Serial runs use PETSc's own sparse LU (for small systems its per-solve overhead is a
    fraction of MUMPS'); parallel runs use MUMPS.
    """
    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOperators(A)
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.LU)
    if A.getComm().getSize() > 1 and PETSc.Sys.hasExternalPackage("mumps"):
        pc.setFactorSolverType("mumps")
    ksp.setUp()
    return ksp.solve


@dataclass
class EnergyBudget:
    """Energies at a step; work and loss terms cumulative from the start (METHOD.md s. 4)."""

    kinetic: float = 0.0
    strain: float = 0.0
    external_work: float = 0.0
    damping_loss: float = 0.0
    impact_loss: float = 0.0
    contact_loss: float = 0.0
    initial: float = 0.0

    @property
    def total(self) -> float:
        return self.kinetic + self.strain

    @property
    def error(self) -> float:
        """Residual of the balance: E - E0 - W_ext + damping + impact + contact losses."""
        return (
            self.total - self.initial - self.external_work
            + self.damping_loss + self.impact_loss + self.contact_loss
        )

    def copy(self) -> EnergyBudget:
        return EnergyBudget(self.kinetic, self.strain, self.external_work, self.damping_loss, self.impact_loss,
                            self.contact_loss, self.initial)


@dataclass
class StepState:
    """The state after a step, as observers see it. Vectors are the integrator's own: read only."""

    step: int
    t: float
    U: PETSc.Vec
    V: PETSc.Vec
    A: PETSc.Vec
    gap: np.ndarray                  # d0 - P U per row
    force: np.ndarray                # normal forces F_N at t
    impulse: np.ndarray              # impulses S_N over the step
    energy: EnergyBudget
    normal_displacement: np.ndarray  # P U
    normal_velocity: np.ndarray      # P V (after the impact correction)


class Observer(Protocol):
    def write(self, state: StepState) -> None: ...


def integrate(integrator, U0, V0, t_end: float, observers=(), t0: float = 0.0, progress=None) -> StepState:
    """Run ``integrator`` from (U0, V0) at ``t0`` to ``t_end``, calling each observer every step."""
    n_steps = steps_for(t_end - t0, integrator.dt)
    state = integrator.start(U0, V0, t0)
    for obs in observers:
        obs.write(state)
    for _ in range(n_steps):
        state = integrator.step()
        for obs in observers:
            obs.write(state)
        if progress is not None:
            progress(state.step, n_steps)
    return state


def steps_for(duration: float, dt: float) -> int:
    """Number of steps of size dt that cover ``duration`` (tolerant of round-off in t_end/dt)."""
    return max(1, int(np.ceil(duration / dt - 1e-9)))
