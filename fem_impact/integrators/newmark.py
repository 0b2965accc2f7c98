"""Generalized Newmark with position-level multipliers and Carnot's impact correction (METHOD.md s. 2)."""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from ..contact import TINY, impact_correction, regularized, solve_lcp
from .base import EnergyBudget, Operators, SimulationError, StepState, factorize


class Newmark:
    """Newmark (beta, gamma) for ``M U'' + C U' + K U + P^T lam = R(t)``, ``P U <= d0``, ``lam >= 0``.

    Parameters: ``beta`` and ``gamma`` (trapezoidal rule: 1/4, 1/2, the default: second order,
    unconditionally stable and energy conserving without contact). Unconditionally stable for
    ``2 beta >= gamma >= 1/2``; ``gamma > 1/2`` damps high frequencies numerically (first order).
    ``beta = 0`` (explicit) is not handled here: the position-level contact problem needs
    ``beta > 0``.

    Everything constant over the loop is built once: the factorizations of
    ``S = M + gamma dt C + beta dt^2 K`` and of ``M``, ``G = S^-1 P^T``, ``H = M^-1 P^T`` and the
    p x p matrices ``W = P G`` and ``D = P H``. A step is vector updates, one solve with ``S``
    and p x p problems.
    """

    name = "newmark"

    def __init__(self, ops: Operators, dt: float, beta: float = 0.25, gamma: float = 0.5):
        if beta <= 0.0:
            raise ValueError("Newmark needs beta > 0 for position-level contact multipliers")
        self.ops, self.dt, self.beta, self.gamma = ops, dt, beta, gamma
        # Supports may have removed diagonal entries from K's pattern: let PETSc merge patterns.
        S = ops.K.copy()
        S.scale(beta * dt * dt)
        S.axpy(1.0, ops.M, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        if ops.C is not None:
            S.axpy(gamma * dt, ops.C, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
        self.S = S
        self.solve_S = factorize(S)
        self.solve_M = factorize(ops.M)
        self.G = ops.solve_columns(self.solve_S)   # S^-1 P^T, owned rows (n_local x p)
        self.H = ops.solve_columns(self.solve_M)   # M^-1 P^T
        self.W = ops.project(self.G)               # P S^-1 P^T (p x p, on every rank)
        self.D = ops.project(self.H)               # P M^-1 P^T
        # A quasi-static part (reduced model) makes the contact rows compliant: lam0 then
        # solves an LCP in beta dt^2 W + P S_k P^T, and only rigid rows get Carnot's correction.
        static = ops.static
        self.lcp_matrix = regularized(beta * dt * dt * self.W + (static.compliance if static else 0.0))
        self.D = regularized(self.D)
        self.rigid = static.rigid_rows if static else np.ones(ops.p, dtype=bool)
        new = lambda: ops.K.createVecs()[0]  # noqa: E731
        # State and work vectors, allocated once; "_prev" ones are swapped by reference.
        self.U, self.V, self.A, self.U_prev = new(), new(), new(), new()
        self.Up, self.Vp, self.rhs, self.work = new(), new(), new(), new()
        self.R, self.R_prev = new(), new()
        self.CV, self.CV_prev = (new(), new()) if ops.C is not None else (None, None)
        self._du = np.empty(self.U.getLocalSize())
        self.t0 = 0.0
        self.state: StepState | None = None

    # -- initial state ------------------------------------------------------------------
    def start(self, U0: PETSc.Vec, V0: PETSc.Vec, t0: float = 0.0) -> StepState:
        """Initial acceleration from the equation of motion; closed contacts get their impulse and force."""
        ops, U, V, A = self.ops, self.U, self.V, self.A
        self.t0 = t0
        U0.copy(U)
        V0.copy(V)
        ops.load.evaluate(t0, self.R)
        ops.K.mult(U, self.rhs)
        self.rhs.aypx(-1.0, self.R)
        if ops.C is not None:
            ops.C.mult(V, self.CV)  # C V*_0, before any correction, as in the step
            self.rhs.axpy(-1.0, self.CV)
        self.solve_M(self.rhs, A)
        p, static = ops.p, ops.static
        pu, pv, pa = ops.project_many(U, V, A) if p else (np.zeros(0),) * 3
        force = lam1 = np.zeros(p)
        energy = EnergyBudget()
        if p:
            if static:  # forces of the compliant rows that the initial state already loads
                force = np.zeros(p)
                c = ~self.rigid
                force[c] = solve_lcp(static.compliance[c][:, c], (ops.d0 - static.offset(t0) - pu)[c])[0]
                if force.any():
                    A.array[:] -= self.H @ force
                    pa = pa - self.D @ force
                pu = pu + static.offset(t0) - static.compliance @ force
            res = impact_correction(self.D, self._closed(pu, force) & self.rigid, np.zeros(p), pv, pv, pa,
                                    force, ops.restitution)
            lam1, force = res.lam1, res.force
            pv = self._apply_corrections(res, pv)
            energy.impact_loss = self._impact_loss(res.lam1, pv)
        energy.kinetic, energy.strain = self._quadratic_energies()
        if static:
            energy.strain += static.energy(t0, force)
        energy.initial = energy.total + energy.impact_loss
        self.state = StepState(0, t0, U, V, A, ops.d0 - pu, force, lam1.copy(), energy, pu, pv)
        return self.state

    def _closed(self, pu: np.ndarray, lam0: np.ndarray) -> np.ndarray:
        """Rows closed at the end of a step: pushed by lam0, or at zero gap up to round-off."""
        gap = self.ops.d0 - pu
        return (lam0 > 0.0) | (gap <= 1e-10 * (np.abs(self.ops.d0) + np.abs(pu)) + TINY)

    def _apply_corrections(self, res, pv: np.ndarray) -> np.ndarray:
        """Velocity (-H lam1) and acceleration (-H lam2) corrections; returns the new P V."""
        if res.lam1.any():
            self.V.array[:] -= self.H @ res.lam1
            pv = pv - self.D @ res.lam1
        if res.lam2.any():
            self.A.array[:] -= self.H @ res.lam2
        return pv

    def _impact_loss(self, lam1: np.ndarray, pv_after: np.ndarray) -> float:
        """Kinetic energy removed by dV = -H lam1: 1/2 V-MV- - 1/2 V+MV+, exactly, in p x p terms."""
        return float(lam1 @ (pv_after + 0.5 * self.D @ lam1))

    def _quadratic_energies(self) -> tuple[float, float]:
        ops, work = self.ops, self.work
        ops.M.mult(self.V, work)
        kinetic = 0.5 * work.dot(self.V)
        ops.K.mult(self.U, work)
        return kinetic, 0.5 * work.dot(self.U)

    # -- one step -----------------------------------------------------------------------
    def step(self) -> StepState:
        ops, st, dt, beta, gamma = self.ops, self.state, self.dt, self.beta, self.gamma
        t1 = self.t0 + (st.step + 1) * dt   # not accumulated, so no drift over long runs
        U, V, A, Up, Vp, rhs = self.U, self.V, self.A, self.Up, self.Vp, self.rhs
        self.R, self.R_prev = self.R_prev, self.R
        if ops.C is not None:
            self.CV, self.CV_prev = self.CV_prev, self.CV

        # Predictors, then the free acceleration: S A = R(t1) - C V~ - K U~.
        Up.waxpy(dt, V, U)
        Up.axpy(dt * dt * (0.5 - beta), A)
        Vp.waxpy(dt * (1.0 - gamma), A, V)
        if ops.load.time_dependent:
            ops.load.evaluate(t1, self.R)
        else:
            self.R_prev.copy(self.R)
        ops.K.mult(Up, rhs)
        rhs.aypx(-1.0, self.R)
        if ops.C is not None:
            ops.C.mult(Vp, self.work)
            rhs.axpy(-1.0, self.work)
        self.solve_S(rhs, A)

        # Position-level multipliers: g = d0 - P U_free + beta dt^2 W lam0 >= 0, lam0 >= 0.
        p = ops.p
        lam0 = np.zeros(p)
        if p:
            pu_pred, pv_pred, pa = ops.project_many(Up, Vp, A)
            offset = ops.static.offset(t1) if ops.static else 0.0
            q = ops.d0 - offset - (pu_pred + beta * dt * dt * pa)
            lam0, _, _ = solve_lcp(self.lcp_matrix, q, guess=st.force > 0.0)
            if lam0.any():
                A.array[:] -= self.G @ lam0
                pa = pa - self.W @ lam0
        self.U, self.U_prev = self.U_prev, self.U
        U, U_prev = self.U, self.U_prev
        U.waxpy(beta * dt * dt, A, Up)
        V.waxpy(gamma * dt, A, Vp)  # V* (before the impact correction)
        if ops.C is not None:
            ops.C.mult(V, self.CV)

        # Carnot correction and acceleration projection on the closed rows.
        energy = st.energy.copy()
        force, impulse = lam0, np.zeros(p)
        pu, pv = st.normal_displacement, st.normal_velocity
        if p:
            pu = pu_pred + beta * dt * dt * pa
            if ops.static:
                pu = pu + offset - ops.static.compliance @ lam0
            pv_star = pv_pred + gamma * dt * pa
            f_mean = (1.0 - gamma) * st.force + gamma * lam0
            s0 = dt * f_mean
            res = impact_correction(self.D, self._closed(pu, lam0) & self.rigid, s0, pv_star, st.normal_velocity,
                                    pa, lam0, ops.restitution)
            force, impulse = res.force, s0 + res.lam1
            pv = self._apply_corrections(res, pv_star)
            energy.impact_loss += self._impact_loss(res.lam1, pv)
            # Work absorbed by the position-level forces over the step (METHOD.md s. 4).
            energy.contact_loss += float((pu - st.normal_displacement) @ f_mean)

        # Energy budget: kinetic and strain energy from the state; work terms with the
        # scheme's own weights (1 - gamma, gamma), so that the balance closes to round-off.
        du = np.subtract(U.array_r, U_prev.array_r, out=self._du)
        work = self.work
        sums = np.empty(4)
        ops.M.mult(V, work)
        sums[0] = work.array_r @ V.array_r
        ops.K.mult(U, work)
        sums[1] = work.array_r @ U.array_r
        # Delta U . ((1 - gamma) R_n + gamma R_n+1) and the same with C V*: dots, no temporaries.
        sums[2] = (1.0 - gamma) * (du @ self.R_prev.array_r) + gamma * (du @ self.R.array_r)
        if ops.C is not None:
            sums[3] = (1.0 - gamma) * (du @ self.CV_prev.array_r) + gamma * (du @ self.CV.array_r)
        else:
            sums[3] = 0.0
        if ops.comm.size > 1:
            ops.comm.Allreduce(MPI.IN_PLACE, sums, op=MPI.SUM)
        energy.kinetic, energy.strain = 0.5 * sums[0], 0.5 * sums[1]
        energy.external_work += sums[2]
        if ops.static:
            energy.strain += ops.static.energy(t1, force)
            energy.external_work += ops.static.work(st.t, t1, st.force, force, gamma)
        energy.damping_loss += sums[3]
        if not np.isfinite(energy.kinetic + energy.strain):
            raise SimulationError(f"the solution is no longer finite at t = {t1:.6g} (step {st.step + 1})")

        self.state = StepState(st.step + 1, t1, U, V, A, ops.d0 - pu, force, impulse, energy, pu, pv)
        return self.state
