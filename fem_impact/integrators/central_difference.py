"""Explicit central difference with forward-increment Lagrange multipliers (docs/theory.md s. 6)."""

from __future__ import annotations

import logging

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from ..nonsmooth.problem import OneStepProblem
from ..linalg.dense import axpy
from ..mechanics.energy import EnergyBudget
from ..mechanics.system import Operators
from .state import StepState
from .scheme import ContactScheme

log = logging.getLogger(__name__)

CHECK_EVERY = 32   # steps: U^T K U by a product with K instead of from the step's equation
SCHEME_ENERGY = -1.0 / 8.0   # x dt^2 A.M A: the part of the energy the scheme conserves beyond 1/2 V.M V + 1/2 U.K U


class CentralDifference(ContactScheme):
    """Central difference (velocity Verlet: Newmark with beta = 0, gamma = 1/2), explicit.

    ``U_n+1 = U_n + dt V_n + dt^2/2 A_n``, ``(M + dt/2 C) A_n+1 = R_n+1 - K U_n+1 - C (V_n + dt/2 A_n)``,
    ``V_n+1 = V_n + dt/2 (A_n + A_n+1)``. With the lumped mass (``solver.mass: lumped``) and no
    damping the step matrix is diagonal: a step costs two matrix-vector products and no solve.

    Contact by forward-increment Lagrange multipliers (Carpenter, Taylor & Katona, IJNME 32, 1991):
    the force ``lam_n+1 >= 0`` acting at t_n+1 is chosen so that the gaps at t_n+2 are
    non-negative, an LCP in ``dt^2 P S^-1 P^T``. A closing contact thus stops within one step,
    a plastic impact at the node: the restitution coefficient is not used, and there is no
    Carnot correction.

    Stability: conditionally stable, ``dt <= 2 / omega_max``; for a 1D rod with lumped mass
    that is the CFL condition ``c dt / h <= 1``. Above it the run blows up within a few dozen
    steps and stops with an error (``integrate``). The estimate of the limit (a Gershgorin
    bound on ``omega_max``, exact for the lumped rod) is logged at the start.

    Energy. With ``M A + C V + K U = R - P^T lam`` at every step and ``U1 - U0 = dt/2 (V0 + V1)
    - dt^2/4 (A1 - A0)``, the step's identity is ``Delta(1/2 V.M V + 1/2 U.K U - dt^2/8 A.M A) =
    Delta U . mean(R - C V - P^T lam)``: the scheme conserves the energy with the term
    ``-dt^2/8 A.M A`` (``EnergyBudget.scheme``, the history's ``scheme_energy``; O((omega dt)^2)
    of the energy, and the sum is positive for free vibration exactly below the stable limit).
    With it, and the work terms booked with the trapezoidal weights, the balance closes to
    round-off, with damping and contacts too.
    """

    name = "central_difference"
    __checkpoint__ = ContactScheme.__checkpoint__ + ("_stop_force",)   # (the force of the step before, for the stops)
    scheme_energy = True
    unconditionally_stable = False   # dt <= 2 / omega_max
    diagonal_delassus = True   # a lumped mass and node-to-plane rows: a projection per row

    def __init__(self, ops: Operators, dt: float):
        if ops.static is not None:
            raise ValueError("central difference takes no quasi-static part (use static_correction: false)")
        if ops.massless.size:
            raise ValueError("central difference needs mass on every dof (no mass redistribution)")
        S = ops.algebra.combine((1.0, ops.M), (0.5 * dt, ops.C))
        super().__init__(ops, dt, S, impact_correction=False)
        # the laws' rows: g = d(t) - P U + c lam (+ their memory) >= 0 at the step after next
        self.lcp = OneStepProblem(self.W, ops.laws, dt, weight=dt * dt)
        self.start_matrix = None   # (built at the start if a contact needs it: it takes D)
        self.critical_dt = critical_time_step(ops)
        if dt > self.critical_dt * (1.0 + 1e-9):
            log.warning("central difference: dt = %.4g is above the stable limit 2/omega_max = %.4g "
                        "(ratio %.3g): expect the run to blow up", dt, self.critical_dt, dt / self.critical_dt)
        else:
            log.info("central difference: dt = %.4g, stable limit 2/omega_max = %.4g (ratio %.3g)",
                     dt, self.critical_dt, dt / self.critical_dt)

    @classmethod
    def from_solver(cls, ops: Operators, solver) -> CentralDifference:
        """From the case file's ``solver`` section (only ``dt`` matters)."""
        return cls(ops, solver.dt)

    def start(self, U0, V0, t0: float = 0.0) -> StepState:
        """Free initial acceleration, then the force that keeps the gaps at t0 + dt non-negative."""
        ops, dt = self.ops, self.dt
        pu, pv, pa = self._initial_state(U0, V0, t0)
        force = np.zeros(ops.p)
        if ops.p:
            q = ops.gap0(t0 + dt) - (pu + dt * pv + 0.5 * dt * dt * pa)
            if np.any(q < 0.0):   # a contact closes in the first step
                self.start_matrix = OneStepProblem(self.D, ops.laws, dt, weight=0.5 * dt * dt)
                force, _, _ = self.start_matrix.solve(self.start_matrix.q(q, ops.gap0(t0) - pu))
            if force.any():
                self.H.subtract_from(self.A, force)
        energy = EnergyBudget()
        energy.kinetic, energy.strain = self._quadratic_energies()   # (sets M A)
        energy.load_scale = self._start_load_scale
        energy.roundoff = self._start_roundoff
        energy.scheme = SCHEME_ENERGY * dt * dt * float(self.alg.allsum(np.array([self.A @ self.MA]))[0])
        self._stop_force = np.zeros(ops.p)   # at t0 an elastic stop is relaxed (the initial gaps are open)
        energy.initial = energy.total
        self.state = StepState(step=0, t=t0, U=self.U, V=self.V, A=self.A, gap=ops.gap0(t0) - pu, force=force,
                               impulse=np.zeros(ops.p), energy=energy, normal_displacement=pu,
                               normal_velocity=pv)
        return self.state

    def step(self) -> StepState:
        ops, st, dt = self.ops, self.state, self.dt
        t1 = self.t0 + (st.step + 1) * dt
        U, V, A = self.U, self.V, self.A
        self._begin_step()
        # In place: U1 = U + dt V + dt^2/2 A and the predictor V~ = V + dt/2 A; then
        # (M + dt/2 C) A1 = R1 - K U1 - C V~.
        axpy(U, dt, V)
        axpy(U, 0.5 * dt * dt, A)
        axpy(V, 0.5 * dt, A)
        self._evaluate_load(t1)
        self._free_acceleration(U, V, self.solve_S, A)

        p = ops.p
        force = np.zeros(p)
        pu, pv = st.normal_displacement, st.normal_velocity
        d1 = ops.gap0(t1)   # (the obstacles' positions at t1: d0 while none moves)
        if p:
            pu, pv_pred, pa = ops.project_many(U, V, A)
            # Forward increment: the force at t1 keeps the gaps at t1 + dt non-negative.
            q = ops.gap0(t1 + dt) - (pu + dt * pv_pred + dt * dt * pa)
            force, _, _ = self.lcp.solve(self.lcp.q(q, d1 - pu), guess=st.force > 0.0)
            if force.any():
                self.G.subtract_from(A, force)
                pa = pa - self.W @ force
            pv = pv_pred + 0.5 * dt * pa
        axpy(V, 0.5 * dt, A)
        if ops.C is not None:   # C V1: the step solved M A1 + C V1 + K U1 = R1 - P^T lam1
            self.alg.mult(ops.C, V, self.CV)

        energy = st.energy.copy()
        f_mean = 0.5 * (st.force + force)
        impulse = dt * f_mean
        if p:
            self._book_work(energy, f_mean, pu - st.normal_displacement, obstacle=ops.obstacle_moved(st.t, t1))
        # K U1 = R1 - C V1 - M A1 - P^T lam1 (the step's equation): two products, M V and M A
        # (diagonal with the lumped mass), and every CHECK_EVERY-th step one with K instead.
        self.alg.mult(ops.M, V, self.MV)
        self.alg.mult(ops.M, A, self.MA)
        KU_rest = self.MA if (st.step + 1) % CHECK_EVERY else None
        self._step_energies(energy, t1, 0.5, 0.5, self.MV, KU_rest, float(pu.dot(force)) if p else 0.0,
                            scheme_weight=SCHEME_ENERGY * dt * dt)
        # The force of step n keeps the gaps at t_n+1: an elastic stop holds c F_n^2 / 2 at t1.
        gap = d1 - pu
        self._book_stops(energy, (self._stop_force, st.gap), (st.force, gap))
        self._stop_force = st.force
        self.state = StepState(step=st.step + 1, t=t1, U=U, V=V, A=A, gap=gap, force=force,
                               impulse=impulse, energy=energy, normal_displacement=pu, normal_velocity=pv)
        return self.state


def critical_time_step(ops: Operators) -> float:
    """``2 / omega_max`` with ``omega_max^2 <= max_i sum_j |K_ij| / m_i`` (Gershgorin, with the
    diagonal of M): a safe bound for a lumped mass, exact for the lumped rod (``h / c``)."""
    alg = ops.algebra
    m = alg.diagonal(ops.M)
    if isinstance(ops.K, PETSc.Mat):
        indptr, _, values = ops.K.getValuesCSR()
        row_sums = np.add.reduceat(np.abs(values), indptr[:-1]) if values.size else np.zeros(0)
        row_sums[np.diff(indptr) == 0] = 0.0
    else:
        row_sums = np.abs(ops.K) if ops.K.ndim == 1 else np.abs(ops.K).sum(axis=1)
    has_mass = m > 0.0
    local = float(np.max(row_sums[has_mass] / m[has_mass], initial=0.0))
    omega2 = ops.comm.allreduce(local, op=MPI.MAX) if alg.distributed else local
    return 2.0 / np.sqrt(omega2) if omega2 > 0.0 else np.inf
