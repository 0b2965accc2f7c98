"""Generalized Newmark with position-level multipliers and Carnot's impact correction (docs/theory.md s. 3)."""

from __future__ import annotations

import logging

import numpy as np

from ..nonsmooth.problem import OneStepProblem, impact_correction
from .blocks import OpenStep, OpenSteps, diagonal
from ..linalg.dense import axpy
from ..mechanics.system import Operators
from .state import StepState
from .scheme import ContactScheme

log = logging.getLogger(__name__)

CHECK_EVERY = 32   # steps: the strain energy by a product with K (see the end of Newmark.step)


class Newmark(ContactScheme):
    """Newmark (beta, gamma) for ``M U'' + C U' + K U + P^T lam = R(t)``, ``P U <= d(t)``, ``lam >= 0``.

    Parameters (``solver.beta``, ``solver.gamma``, ``solver.impact_correction``):

    - ``beta = 1/4, gamma = 1/2`` (the default): the trapezoidal rule, second order,
      unconditionally stable, energy conserving without contact.
    - ``gamma > 1/2`` with ``beta = (gamma + 1/2)^2 / 4``: numerical damping of the high
      frequencies (first order); unconditionally stable for ``2 beta >= gamma >= 1/2``.
    - ``beta = 0`` (explicit) is not handled here: the position-level contact problem needs
      ``beta > 0`` (see ``CentralDifference``).
    - ``impact_correction: false`` keeps only the position-level multipliers: no Carnot
      correction of the velocities and no acceleration projection (docs/theory.md s. 3.5: the contact
      force then oscillates and the contact chatters; for comparison studies).

    A step is vector updates, one solve with ``S = M + gamma dt C + beta dt^2 K``, a product
    with K (and C) for its right-hand side and one with M for the energy budget, and p x p
    problems: the LCP for ``lam0``, then Carnot's correction and the acceleration projection
    on the closed rows.
    """

    name = "newmark"

    def __init__(self, ops: Operators, dt: float, beta: float = 0.25, gamma: float = 0.5,
                 impact_correction: bool = True):
        if beta <= 0.0:
            raise ValueError("Newmark needs beta > 0 for position-level contact multipliers")
        self.beta, self.gamma = beta, gamma
        self.unconditionally_stable = 2.0 * beta >= gamma   # (gamma >= 1/2: the case refuses less)
        S = ops.algebra.combine((1.0, ops.M), (beta * dt * dt, ops.K), (gamma * dt, ops.C))
        super().__init__(ops, dt, S, impact_correction)
        # A quasi-static part (reduced model) makes the contact rows compliant: lam0 then
        # solves an LCP in beta dt^2 W + P S_k P^T; the laws add their compliance on the diagonal
        # (g = d(t) - P U + c lam0 >= 0) and their memory to q (nonsmooth/problem.py).
        static = ops.static
        self.lcp = OneStepProblem(self.W, ops.laws, dt, weight=beta * dt * dt,
                                  static=static.compliance if static else None)
        self._check_stop_stiffness()

    def _check_stop_stiffness(self) -> None:
        """Warn when an elastic stop is stiffer than the step resolves.

        ``r = c / (beta dt^2 W_jj)`` compares the stop's compliance with the row's own over a
        step: below 1 the spring-on-node oscillation (omega dt > 2) is not resolved, the row
        opens and closes within steps and, with no Carnot correction on an elastic row, pumps
        energy in as position-level multipliers alone do (the further below 1, the more).
        Rows with a static compliance in series or without mass do not do this.
        """
        ops, dt = self.ops, self.dt
        rigid = ops.static.rigid_rows if ops.static else np.ones(ops.p, dtype=bool)
        compliance = self.lcp.stop_compliance
        rows = (compliance > 0.0) & rigid & ~ops.massless_rows
        if not rows.any():
            return
        ratio = compliance[rows] / (self.beta * dt * dt * np.diag(self.W)[rows])
        worst = float(ratio.min())
        if worst < 1.0:
            log.warning("an elastic stop is stiffer than the time step resolves: c / (beta dt^2 W) = %.3g < 1 "
                        "(%d of %d elastic rows): expect chattering and energy gain. Use dt <= %.3g, a rigid "
                        "stop (no stiffness), mass: redistributed, or the modal model with static correction",
                        worst, int((ratio < 1.0).sum()), int(rows.sum()), dt * np.sqrt(worst))

    @classmethod
    def from_solver(cls, ops: Operators, solver) -> Newmark:
        """From the case file's ``solver`` section."""
        return cls(ops, solver.dt, beta=solver.beta, gamma=solver.gamma, impact_correction=solver.impact_correction)

    def open_step(self) -> OpenStep | None:
        """The step without multipliers, on a replicated diagonal system (blocks.py)."""
        diag = diagonal(self.ops)
        if diag is None:
            return None
        return OpenStep(*diag, self.gamma, np.zeros(self.ops.p, dtype=bool))

    def open_steps(self, loads: np.ndarray) -> OpenSteps:
        """``len(loads) - 1`` steps without multipliers from the state, the loads ``loads`` at the
        state's time and at each step's end (L + 1 x n): the compiled ``step`` (kernels.py)."""
        ops, dt, beta, gamma = self.ops, self.dt, self.beta, self.gamma
        size = loads.shape[0] - 1
        damped = ops.C is not None
        if getattr(self, "_open_args", None) is None:   # (the step's constants, as step() forms them)
            from .kernels import FUSED, newmark_steps

            coef = np.array([dt, dt * dt * (0.5 - beta), dt * (1.0 - gamma), beta * dt * dt, gamma * dt])
            self._open_args = (newmark_steps, FUSED, damped, coef, ops.M, ops.K,
                               ops.C if damped else np.zeros(self.U.size), self.solve_S.inverse)
        U, V, A, MV, Up, Vp = np.empty((6, size, self.U.size))
        kernel, *args = self._open_args
        kernel(*args, loads, self.U, self.V, self.A, self.MV, self.MA, U, V, A, MV, Up, Vp)
        # U^T K U as step() books it: from its equation of motion, by a product every CHECK_EVERY-th step.
        rows = lambda a, b: np.einsum("ji,ji->j", a, b)   # noqa: E731
        UKU = -rows(U, A * ops.M)
        if self.loaded:
            UKU += rows(U, loads[1:])
        if damped:
            UKU -= rows(U, V * ops.C)
        product = (self.state.step + 1 + np.arange(size)) % CHECK_EVERY == 0
        if product.any():
            UKU[product] = rows(U[product], U[product] * ops.K)
        # P U and P V as step() reports them: from the predictors' projections and P A.
        P = ops._P_block
        PA = A @ P.T
        PU, PV = Up @ P.T + beta * dt * dt * PA, Vp @ P.T + gamma * dt * PA
        return OpenSteps(U, V, A, MV, UKU, PU, PV, {"MV": MV, "U~": Up, "V~": Vp})

    def resume(self, state: StepState, carry: dict) -> None:
        super().resume(state, carry)
        np.copyto(self.MV, carry["MV"])   # (accumulated by the steps, not M V)
        if self.ops.p:
            dt = self.dt
            pu_pred, pv_pred, pa = self.ops.project_many(carry["U~"], carry["V~"], self.A)
            self._resume_rows(pu_pred + self.beta * dt * dt * pa, pv_pred + self.gamma * dt * pa)

    def step(self) -> StepState:
        ops, st, dt, beta, gamma = self.ops, self.state, self.dt, self.beta, self.gamma
        t1 = self.t0 + (st.step + 1) * dt   # not accumulated, so no drift over long runs
        U, V, A = self.U, self.V, self.A
        self._begin_step()

        # Predictors, in place: U~ = U + dt V + dt^2 (1/2 - beta) A, V~ = V + dt (1 - gamma) A;
        # then the free acceleration: S A = R(t1) - C V~ - K U~.
        axpy(U, dt, V)
        axpy(U, dt * dt * (0.5 - beta), A)
        axpy(V, dt * (1.0 - gamma), A)
        self._evaluate_load(t1)
        rhs = self._free_rhs(U, V)

        # Position-level multipliers: g = d(t1) - P U_free + beta dt^2 W lam0 >= 0, lam0 >= 0.
        # (Small arrays below: .dot and count_nonzero cost half of @ and .any().)
        p, bdt2, gdt = ops.p, beta * dt * dt, gamma * dt
        lam0 = np.zeros(p)
        d1 = ops.gap0(t1)   # (the obstacles' positions at t1: d0 while none moves)
        if p:
            offset = ops.static.offset(t1) if ops.static else 0.0
            guess = st.force > 0.0
            if self._condensed is not None:   # one solve, the multipliers between its halves
                pu_pred, pv_pred = ops.project_many(U, V)
                q_pred = d1 - offset - pu_pred
                pa, lam0 = self._condensed_solve(
                    rhs, A, lambda pa: self.lcp.solve(self.lcp.q(q_pred - bdt2 * pa, st.gap), guess=guess)[0])
            else:
                self.solve_S(rhs, A)
                pu_pred, pv_pred, pa = ops.project_many(U, V, A)
                lam0 = self.lcp.solve(self.lcp.q(d1 - offset - (pu_pred + bdt2 * pa), st.gap), guess=guess)[0]
                if np.count_nonzero(lam0):
                    self.G.subtract_from(A, lam0)
            if np.count_nonzero(lam0):
                pa = pa - self.W.dot(lam0)
        else:
            self.solve_S(rhs, A)
        axpy(U, bdt2, A)
        axpy(V, gdt, A)   # V* (before the impact correction)
        if ops.C is not None:
            self.alg.mult(ops.C, V, self.CV)

        # Carnot correction and acceleration projection on the closed rows.
        energy = st.energy.copy()
        force, impulse = lam0, np.zeros(p)
        pu, pv = st.normal_displacement, st.normal_velocity
        pu_dyn = pu
        if p:
            pu = pu_dyn = pu_pred + bdt2 * pa
            if ops.static:
                pu = pu + offset - ops.static.compliance.dot(lam0)
            pv_star = pv_pred + gdt * pa
            f_mean = (1.0 - gamma) * st.force + gamma * lam0
            s0 = dt * f_mean
            closed = self._closed(pu, lam0, t1)
            if np.count_nonzero(closed):   # (Newton's law on the velocities relative to the obstacles)
                res = impact_correction(self.carnot, closed, s0, ops.relative(pv_star, t1),
                                        ops.relative(st.normal_velocity, t1), ops.relative_acceleration(pa, t1), lam0,
                                        ops.restitution)
                force, impulse = res.force, s0 + res.lam1
                pv = self._apply_corrections(res, pv_star, energy, t1)
                # M V: -P^T lam1 for the velocity correction, + gamma dt P^T lam2 as the update
                # below takes M A after the acceleration correction (M H = P^T: the corrected
                # rows touch no massless dof).
                jump = res.lam1 - gdt * res.lam2
                if np.count_nonzero(jump):
                    ops.subtract_transpose(self.MV, jump)
            else:
                impulse, pv = s0, pv_star
            # Work absorbed by the position-level forces over the step (docs/theory.md s. 9).
            self._book_work(energy, f_mean, pu - st.normal_displacement, obstacle=ops.obstacle_moved(st.t, t1))

        # Energy budget: kinetic and strain energy of the state; work terms with the scheme's own
        # weights (1 - gamma, gamma), so that the balance closes to round-off. One product per
        # step, M A. M V follows the velocity update, M V += dt ((1 - gamma) M A0 + gamma M A1),
        # and the corrections above. U^T K U from M A + C V* + K U = R - P^T F at the end of the
        # step; that holds as far as the solves are right, so every CHECK_EVERY-th step U^T K U
        # is a product with K instead, and the balance checks them too.
        self.MA, self.MA_prev = self.MA_prev, self.MA
        self.alg.mult(ops.M, A, self.MA)
        axpy(self.MV, dt * (1.0 - gamma), self.MA_prev)
        axpy(self.MV, dt * gamma, self.MA)
        KU_rest = self.MA if (st.step + 1) % CHECK_EVERY else None
        self._step_energies(energy, t1, 1.0 - gamma, gamma, self.MV, KU_rest, float(pu_dyn.dot(force)) if p else 0.0)
        gap = d1 - pu
        self._book_stored(energy, st, force, gap, t1, gamma)

        self.state = StepState(step=st.step + 1, t=t1, U=U, V=V, A=A, gap=gap, force=force,
                               impulse=impulse, energy=energy, normal_displacement=pu, normal_velocity=pv)
        return self.state
