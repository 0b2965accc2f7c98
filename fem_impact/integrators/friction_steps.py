"""Moreau-Jean's steps with Coulomb friction (docs/theory.md s. 11): the frictional one-step problem
on ``[P; P_T]``, its impulses at either level, the gaps closed to round-off at the position level,
Carnot's correction as a frictional impact problem in the step's total impulse, and the velocity
level's stick correction. A mixin of ``MoreauJean`` (moreau_jean.py), which holds the state."""

from __future__ import annotations

import time

import numpy as np

from ..errors import ContactSolverError
from ..linalg.backends import DenseAlgebra
from ..nonsmooth.friction import FrictionProblem
from .state import StepState

ROUND_OFF = 1e-12   # a velocity change below this fraction of the step's impulse's is no correction
REGULARIZATION = 1e-10   # of the diagonal: the shift of a singular frictional W (lcp.regularized's)


class FrictionSteps:
    """The frictional parts of Moreau-Jean's step (``MoreauJean`` inherits them)."""

    def _build_friction(self) -> None:
        """The frictional one-step problem on ``[P; P_T]`` (docs/theory.md s. 11).

        The rows with friction take the scheme's level, in De Saxce's form (as Siconos' Moreau-Jean),
        which holds whatever the normal unknown is: at the position level a rigid row's gap at the end
        of the step, closed to round-off (FrictionProblem.close_normal, _close_gaps), then Carnot's
        correction as a frictional impact problem in the step's total impulse, so that the impulse of
        an impact lies in the cone with its whole normal part (_frictional_restitution); at the
        velocity level Newton's law on the velocities (gaps drift) and the stick correction (_stick).
        An elastic stop with friction keeps its gap condition at the end of the step (its normal
        unknown is the same impulse).
        """
        ops = self.ops
        self.rows = ops.with_tangents()
        # Position level: every row (with friction or not) takes its gap at the end of the step, and the
        # rigid rows with mass then get Carnot's correction as a frictional impact problem in the total
        # impulse (_frictional_restitution, on D = [P; P_T] M^-1 [P; P_T]^T). Velocity level: the rigid
        # rows take Newton's law and Coulomb's on the velocities, the persisting ones that stick the
        # tangential correction (_stick).
        self.friction_impact = None
        self.friction_scaled = 0   # corrections that the energy guard scaled down (_frictional_restitution)
        clock = time.perf_counter()
        shifted, self.G_all, roundoff = self.rows.delassus(self.solve_S, norm=self.alg.norm(self.S))
        self.timings["W with tangents"] = time.perf_counter() - clock
        # The one-step problem's compliance on the normal block (in place: W is (p + pt)^2, the largest
        # array of a frictional run); the step's products W r come from the solution's y = W r + q.
        # (kept only where some row is compliant: a p x p product per step otherwise for nothing)
        # A reduced model's static part acts on the tangent rows too: its compliance H S_k H^T over all
        # rows, normal and tangent coupled (_static_rows).
        static = ops.static
        self._soft_t = None   # tangent rows a static part makes compliant (their law on the whole slip)
        if static is not None and static.tangents:
            self.compliance = self._static_rows(shifted)
        else:
            self.compliance = self.lcp.shift_normal_block(shifted, ops.p)
        # (fewer modes than contact unknowns: W singular, unless a static part makes every row compliant)
        self._degenerate = self.alg.sizes[1] < ops.p + ops.pt and not (
            self._soft_t is not None and not np.count_nonzero(static.rigid_rows))
        if self._degenerate:
            # More contact unknowns than the motion has (a reduced model with fewer modes): W is
            # singular, its impulses not unique; the shift selects the smallest (as lcp.regularized,
            # at the price of a velocity error of 1e-10 of the impulse's).
            np.fill_diagonal(shifted, shifted.diagonal() + REGULARIZATION * np.abs(shifted.diagonal()).max())
        self.friction = FrictionProblem(shifted, ops.tangent_of, ops.friction, overwrite=True, roundoff=roundoff)
        self.r_prev = np.zeros(ops.p + ops.pt)
        self._persists, self._r_t = None, np.zeros(ops.pt)
        self._stick_D = self._stick_H = None   # P_T M^-1 P_T^T and M^-1 P_T^T, built on the first stick
        self.friction_residual, self.friction_sweeps, self.friction_retries = 0.0, 0, 0
        if self.level == "position" and np.count_nonzero(self.carnot_rows):
            clock = time.perf_counter()
            D, self._impact_H, roundoff = self.rows.delassus(self.solve_M, norm=self.alg.norm(ops.mass_for_solves()))
            if self._degenerate:   # (as W: the smallest impulses where many give the same velocities)
                np.fill_diagonal(D, D.diagonal() + REGULARIZATION * np.abs(D.diagonal()).max())
            self.friction_impact = FrictionProblem(D, ops.tangent_of, ops.friction, overwrite=True, roundoff=roundoff)
            self.timings["D with tangents"] = time.perf_counter() - clock

    takes_new_rows = True

    def _static_rows(self, shifted: np.ndarray) -> np.ndarray:
        """The reduced model's static part on the rows ``H = [P; P_T]`` (docs/theory.md s. 11): its compliance
        ``C = H S_k H^T / (theta dt^2)`` added to W over all rows (in place), with the laws' on the normal
        diagonal; returns that shift. The rows' gaps at the step's end and their slips over it then hold the
        static displacement ``H S_k (R - H^T lam)`` with ``lam = r / dt`` (W stays symmetric: both conditions
        are divided by theta dt); the compliant rows take Coulomb's law on that whole slip."""
        ops, static, p = self.ops, self.ops.static, self.ops.p
        scale = self.theta * self.dt * self.dt
        shift = static.rows_compliance / scale
        shift[:p, :p] = self.lcp.compliance / scale   # (the static part's normal block and the laws' c)
        shifted += shift
        self._soft_t = ~static.rigid_rows[ops.tangent_of]
        return shift

    def _static_slip(self, st: StepState, t1: float) -> np.ndarray:
        """The compliant tangent rows' q from the static part: with ``Delta(P_T U_s) = Delta(P_T S_k R) -
        C_T (lam1 - lam0)`` (C_T the tangent rows of H S_k H^T) the slip over the step, divided by
        theta dt, holds ``-(Delta(P_T S_k R) + C_T lam0) / (theta dt)``; its ``C_T lam1`` is in W."""
        static, p = self.ops.static, self.ops.p
        lam0 = np.concatenate([st.force, st.tangential])
        change = static.rows_offset(t1)[p:] - static.rows_offset(st.t)[p:] + static.rows_compliance[p:].dot(lam0)
        return np.where(self._soft_t, -change / (self.theta * self.dt), 0.0)

    def _static_terms(self, st: StepState, force: np.ndarray, tangential: np.ndarray, t1: float):
        """The static part's share of a frictional step (``tangential``: the step's tangential impulses): the
        normal rows' static displacement at t1, the rows' forces at t0 and t1 (``[F_N, F_T]``), and the
        static part's contact loss split as booked: the friction's work on the static slip, ``F_T1 .
        Delta(P_T U_s)`` (with the kept modes' part, the friction's work on the whole slip: >= 0 by
        Coulomb's law), and the rest, ``mean(F) . Delta(H U_s) - F_T1 . Delta(P_T U_s)`` (the normal
        rows' share, and 1/2 dF . C dF >= 0 for constant loads: the end-point rule on a convex spring)."""
        static, p = self.ops.static, self.ops.p
        f0 = np.concatenate([st.force, st.tangential])
        f1 = np.concatenate([force, tangential / self.dt])
        u1 = static.displacement(t1, f1)
        slip = u1[p:] - static.displacement(st.t, f0)[p:]
        friction = float(f1[p:].dot(slip))
        rest = static.contact_loss(st.t, t1, f0, f1) - friction
        return u1[:p], f0, f1, friction, rest, slip

    def _friction_velocity(self, pt0: np.ndarray, pt1: np.ndarray) -> np.ndarray:
        """The tangential velocity a step's friction impulses are booked with: the step's mean (an
        impulse's work on the kinetic energy); on the rows under the slip law (a persisting contact),
        the one Coulomb's law holds on, ``(1 - theta) P_T V0 + theta P_T V1``, the same for theta = 1/2.
        Each row's work is so >= 0 at any theta (closing rows: _frictional_impulse's retry); the rest of
        their mean-velocity work is the scheme's dissipation (_numerical_loss)."""
        mean = 0.5 * (pt0 + pt1)
        if self.theta == 0.5 or self._persists is None:
            return mean
        return np.where(self._persists, (1.0 - self.theta) * pt0 + self.theta * pt1, mean)

    def _frictional_impulse(self, st: StepState, t1: float, rhs: np.ndarray):
        """The step's impulses with friction: one cone problem on ``[P; P_T]``, applied to V.

        Returns (normal impulses, tangential impulses, P V, P_T V, the largest normal velocity jump).
        A solve that misses its tolerance stops the run (ContactSolverError, status 3).
        """
        p, V = self.ops.p, self.V
        free = self.rows.project_many(V)[0]
        pv_free, pt_free = free[:p], free[p:]
        self.at_velocity = self.level == "velocity"
        figures = (self.friction_residual, self.friction_sweeps, self.friction_retries)
        try:
            sol, q, q_all, active = self._cone_steps(st, t1, pv_free, pt_free)
        except ContactSolverError:
            if self.at_velocity:
                raise
            # Its cone problem at the position level not solved (De Saxce's form with the gap's rate
            # need not have a solution the solver finds at a large mu, docs/theory.md s. 11):
            # this step at the velocity level, energy-safe, its gaps drifting by (1 - theta) dt |v_N|
            # at most, no Carnot correction (summary: friction_velocity_steps).
            self.at_velocity = True
            self.friction_velocity_steps += 1
            self.friction_residual, self.friction_sweeps, self.friction_retries = figures   # (the solve kept's)
            sol, q, q_all, active = self._cone_steps(st, t1, pv_free, pt_free)
        r = sol.r
        self.r_prev = r
        self._r_t = r[p:]
        if not np.count_nonzero(r):
            return r[:p], r[p:], pv_free, pt_free, 0.0
        self.G_all.subtract_from(V, r)
        self.rows.subtract_transpose(rhs, r)   # the step's equation with the impulses, for K V1
        Wr = sol.y - q_all   # W r with the compliance; without it (the kept modes' velocities):
        if self._soft_t is not None:
            Wr -= self.compliance.dot(r)
        elif self.compliance is not None:
            Wr[:p] -= self.compliance.dot(r[:p])
        if not self.at_velocity:
            return self._close_gaps(r, q, pv_free, free, float(np.abs(Wr[:p]).max()), rhs)
        return r[:p], r[p:], pv_free - Wr[:p], pt_free - Wr[p:], float(np.abs(Wr[:p]).max())

    def _cone_steps(self, st: StepState, t1: float, pv_free: np.ndarray, pt_free: np.ndarray):
        """The step's cone problem solved at ``self.at_velocity``'s level, with the rows it adds to the
        slip law or to the solve: (the solution, q of the normal rows, the whole q, the active rows)."""
        ops, p = self.ops, self.ops.p
        position = not self.at_velocity
        kept = self.position_rows
        if not position:   # (the velocity level's rows: the elastic ones alone take their gap)
            self.position_rows = self.position_rows & self.elastic if self.level == "position" else kept
        try:
            q, active = self._contact_problem(st, pv_free, t1)
        finally:
            self.position_rows = kept
        # Tangent rows of a contact that persists (an impulse in the previous step): Coulomb's law on
        # the slip over the step, (1 - theta) P_T V0 + theta P_T V1, scaled by 1/theta (W stays
        # symmetric); the friction then never does positive work in a step. A row that closes in
        # this step takes it on the velocity at its end, as an impact must.
        # A closing row whose friction would do positive work over the step (its tangential velocity
        # reverses within it, pushed by the rest of the body: the impulse acted along the velocity it
        # started with) takes the slip law too, and the problem is solved again.
        # (Moving obstacles: Coulomb's law on the velocities relative to them, at t0 and t1.)
        pt0 = ops.relative_tangent(st.tangential_velocity, st.t)
        pt_free_rel = ops.relative_tangent(pt_free, t1)
        slip_law = (st.impulse > 0.0)[ops.tangent_of]
        static_slip = 0.0
        if self._soft_t is not None:
            # A row the static part makes compliant has no impact (the compliance takes it, as its normal
            # gap at the step's end does): Coulomb's law on its whole slip over the step, always.
            slip_law |= self._soft_t
            static_slip = self._static_slip(st, t1)
        guess = self.r_prev
        # Rows at the position level are all in the problem, but a row whose free gap stays open and that
        # carried nothing in the previous step is left out of the solve (a face in flight costs nothing);
        # one that the others' impulses would push into the obstacle is added and the problem solved again.
        tried = active & ((q <= 0.0) | (st.impulse > 0.0) | ~self.position_rows) if position else active
        for attempt in range(2 * p + 2):   # (each new solve adds a row to the slip law or to the solve)
            q_t = -pt_free_rel - np.where(slip_law, (1.0 - self.theta) / self.theta * pt0, 0.0) + static_slip
            q_all = np.concatenate([q, q_t])
            sol = self._solve_cone(self.friction, q_all, tried, guess, st.step + 1, t1)
            if position:   # (the gaps closed to round-off, not to the solver's tolerance)
                sol = self.friction.close_normal(sol, q_all, tried)
            closing = active & ~tried & (sol.y[:p] < 0.0)
            if np.count_nonzero(closing):
                tried |= closing
                guess = sol.r
                continue
            r_t = sol.r[p:]   # (P_T V1 = pt_free - W_T r = pt_free - y_T + q_t; relative likewise)
            work = np.bincount(ops.tangent_of, weights=r_t * (pt0 + pt_free_rel - sol.y[p:] + q_t),
                               minlength=p)[ops.tangent_of]
            giving = ~slip_law & (work < 0.0)
            if not np.count_nonzero(giving) or attempt == 2 * p + 1:
                break
            slip_law |= giving
            guess = sol.r
        self._persists = slip_law if np.count_nonzero(slip_law) else None
        return sol, q, q_all, active

    def _close_gaps(self, r: np.ndarray, q: np.ndarray, pv_free: np.ndarray, free: np.ndarray, jump: float, rhs):
        """The gaps of the closed rows measured on the structure and closed there to round-off.

        W (symmetrized, from solves with S) stands for ``[P; P_T] S^-1 [P; P_T]^T`` to the round-off of
        the solves, which grows with S's conditioning (a large step on a stiff model): its ``y_N = 0``
        leaves gaps of that size. From the velocity itself, ``y_N = q_N + P V_free - P V1 + c r_N``, the
        closed rows' normal impulses are corrected with W_NN's factor (friction.close_again) until
        ``y_N`` is at round-off (two passes at most), and P V1, P_T V1 are returned as measured (the next
        step's gaps are taken with them; docs/theory.md s. 11). Returns what _frictional_impulse does."""
        p, V = self.ops.p, self.V
        actual = self.rows.project_many(V)[0]
        scale = 4.0 * np.finfo(float).eps * max(float(np.abs(q).max()), 1e-300)
        for _ in range(2):
            y_n = q + pv_free - actual[:p]
            if self._soft_t is not None:
                y_n += self.compliance[:p].dot(r)
            elif self.compliance is not None:
                y_n += self.compliance.dot(r[:p])
            held = r[:p] > 0.0
            if not np.count_nonzero(held) or np.abs(y_n[held]).max() <= scale:
                break
            change = self.friction.close_again(y_n)
            if change is None or np.any(r[:p] + change < 0.0):
                break
            r[:p] += change
            correction = np.zeros(r.size)
            correction[:p] = change
            self.G_all.subtract_from(V, correction)
            self.rows.subtract_transpose(rhs, correction)
            actual = self.rows.project_many(V)[0]
        return r[:p], r[p:], actual[:p], actual[p:], jump

    def _frictional_restitution(self, impulse: np.ndarray, r_t: np.ndarray, pv: np.ndarray, pt: np.ndarray,
                                pv0: np.ndarray, pu: np.ndarray, normal_loss: float, friction_loss: float, jump: float,
                                step: int, t1: float):
        """Position level with friction: Carnot's correction as a frictional impact problem in the total impulse.

        The rows held at the end of the step (an impulse, or at the obstacle still approaching) leave the
        trapezoidal step with spurious velocities, normal and tangential: a row hit at the start of the
        step rebounds elastically, one that sticks alternates its tangential velocity. The correction
        ``dV = -M^-1 H^T c`` (``H = [P; P_T]`` on those rows, U untouched) is the impulse ``c`` that makes
        the step's total ``R = r + c`` an impact by Newton's law and Coulomb's on the velocity after it:
        De Saxce's cone problem in ``D = H M^-1 H^T`` on the total,

            y = D R + q,   q = -H (V* + M^-1 H^T r) - [e max(P V0, 0); 0],   y = [-P V+ - e max(P V0, 0); -P_T V+],

        so ``R`` is in the cone (Coulomb's law on the whole impulse, as the velocity level's) and the gaps
        stay closed. The kinetic energy it removes, split by Kelvin's theorem into the normal part
        ``c_N . (P V* + P V+)/2`` (impact loss) and the tangential ``c_T . (P_T V* + P_T V+)/2`` (friction
        loss), is not signed in general (the tangential part gives back the excess of a step whose normal
        impulse was twice the impact's); each is added to the step's own loss of its kind (``normal_loss``,
        ``friction_loss``, both >= 0). Should a sum be negative, the correction is scaled by the largest
        ``s`` in [0, 1] that keeps both >= 0: ``r + s c`` stays in the cone (it is convex), and the contacts
        never give energy (``friction_scaled`` counts those steps). Returns (P V+, P_T V+, c, the impact
        loss, the friction loss), or None without a correction. Velocities relative to moving obstacles;
        their work on ``c_T`` is kept in ``_stick_obstacle_work``.
        """
        ops, p = self.ops, self.ops.p
        rel, rel0 = ops.relative(pv, t1), ops.relative(pv0, t1)
        rows = self.carnot_rows & ((impulse > 0.0) | (self._at_obstacle(pu, t1) & (rel >= 0.0)))
        if not np.count_nonzero(rows):
            return None
        held = np.concatenate([rows, rows[ops.tangent_of]])
        r = np.where(held, np.concatenate([impulse, r_t]), 0.0)
        bounce = np.zeros(held.size)
        bounce[:p] = ops.restitution * np.maximum(rel0, 0.0)
        hv = np.concatenate([rel, ops.relative_tangent(pt, t1)])   # H V* relative to the obstacles
        problem = self.friction_impact
        Dr = problem.multiply(r)
        q = -(hv + Dr) - bounce
        sol = self._solve_cone(problem, q, rows, r, step, t1, "frictional impact problem of Carnot's correction",
                               guess_product=Dr)
        sol = problem.close_normal(sol, q, rows)   # (Newton's law on the held rows to round-off)
        c = np.where(held, sol.r - r, 0.0)
        dv = hv + sol.y + bounce   # H V* - H V+ = D c
        if np.abs(dv).max() <= ROUND_OFF * max(jump, float(np.abs(hv).max())):
            return None   # (the held rows end the step as the law says: a persisting contact)
        a_n, b_n = float(c[:p].dot(hv[:p])), float(c[:p].dot(dv[:p]))
        a_t, b_t = float(c[p:].dot(hv[p:])), float(c[p:].dot(dv[p:]))
        # (the losses are sums of impulses times velocities, these the differences of velocities as large as
        # the step's change: their round-off, where a loss is zero but for it)
        roundoff = 16.0 * np.finfo(float).eps * float(np.abs(r).sum() + np.abs(c).sum()) * max(
            jump, float(np.abs(hv).max()), float(np.abs(dv).max()), float(np.abs(rel0).max()))
        scale = min(_largest_safe(normal_loss, a_n, b_n, roundoff), _largest_safe(friction_loss, a_t, b_t, roundoff))
        if scale < 1.0:
            self.friction_scaled += 1
            c *= scale
            dv *= scale
        self._impact_H.subtract_from(self.V, c)
        if ops.moving:
            self._stick_obstacle_work = float(c[p:].dot(ops.obstacle_tangent_velocity(t1)))
        impact = scale * a_n - 0.5 * scale * scale * b_n
        friction = scale * a_t - 0.5 * scale * scale * b_t
        after = self.rows.project_many(self.V)[0]   # (P V+ itself: the next step's gaps are taken with it)
        return after[:p], after[p:], c, impact, friction

    def _solve_cone(self, problem: FrictionProblem, q: np.ndarray, active: np.ndarray, guess, step: int, t1: float,
                    what: str = "frictional contact problem", guess_product: np.ndarray | None = None):
        """One cone problem solved to the tolerance, its figures kept for the summary; a solve that
        misses the tolerance stops the run (ContactSolverError, status 3). ``guess_product``: W guess, where
        the caller computed it (FrictionProblem.solve)."""
        sol = problem.solve(q, active, guess=guess, guess_product=guess_product)
        self.friction_residual = max(self.friction_residual, sol.residual)
        self.friction_sweeps = max(self.friction_sweeps, sol.sweeps)
        self.friction_retries += sol.newton
        if not sol.converged:
            raise ContactSolverError(
                f"the {what} was not solved at t = {t1:.6g} (step {step}): residual "
                f"{sol.residual:.3g} after {sol.sweeps} sweeps (tolerance {problem.TOLERANCE:.0e}), worst "
                f"at contact row {sol.worst_row}{self._row_name(sol.worst_row)}" + self._degenerate_hint())
        return sol

    def _stick(self, impulse: np.ndarray, r_t: np.ndarray, pv: np.ndarray, pt: np.ndarray, jump: float, t1: float):
        """Carnot's correction in the tangent plane, on the persisting rows that stick.

        The slip law of a persisting row sticks when the slip over the step vanishes, which for
        theta = 1/2 leaves ``P_T V1 = -P_T V0``: a row that stops sliding would go on alternating
        its tangential velocity at a fixed position. The smallest velocity change in the norm of
        M that brings those rows' ``P_T V`` to zero, ``dV = -M^-1 P_T^T lam``, ``lam = D_ss^-1
        P_T V`` (``D = P_T M^-1 P_T^T`` on them), removes it and loses ``1/2 x . D_ss^-1 x >= 0``; it is
        kept where the step's total tangential impulse stays in the cone (a row where it would not
        is left as it is). Returns (P V, P_T V, the tangential impulses, the loss). On a moving
        obstacle the velocities are relative to it, and its work on ``lam`` is kept in
        ``_stick_obstacle_work`` (``lam . v_obstacle``, what the external work loses).
        """
        ops, p = self.ops, self.ops.p
        absolute, pt = pt, ops.relative_tangent(pt, t1)
        mu_r_n = (ops.friction * impulse)[ops.tangent_of]
        size = np.sqrt(np.bincount(ops.tangent_of, weights=r_t * r_t, minlength=p))[ops.tangent_of]
        stuck = self._persists & (mu_r_n > 0.0) & (size < (1.0 - 1e-9) * mu_r_n)
        if self._soft_t is not None:   # (a compliant row sticks on its static spring: its modes move)
            stuck &= ~self._soft_t
        stuck &= np.abs(pt) > ROUND_OFF * max(jump, float(np.abs(pt).max()))
        if not np.count_nonzero(stuck):
            return pv, absolute, r_t, 0.0
        if self._stick_D is None:   # (on the tangent rows only: less than half the memory of all rows')
            self._stick_D, self._stick_H = self.ops.tangent_rows().delassus(self.solve_M)
        D = self._stick_D
        for _ in range(2):   # (once more without the rows whose total would leave the cone)
            s = np.flatnonzero(stuck)
            D_ss = D[np.ix_(s, s)]
            lam = np.linalg.solve(D_ss, pt[s])
            total = r_t.copy()
            total[s] += lam
            size = np.sqrt(np.bincount(ops.tangent_of, weights=total * total, minlength=p))[ops.tangent_of]
            outside = stuck & (size > mu_r_n * (1.0 + 1e-12))
            if not np.count_nonzero(outside):
                break
            stuck &= ~outside
            if not np.count_nonzero(stuck):
                return pv, absolute, r_t, 0.0
        else:
            return pv, absolute, r_t, 0.0
        c = np.zeros(ops.pt)
        c[s] = lam
        self._stick_H.subtract_from(self.V, c)
        loss = float(lam.dot(pt[s]) - 0.5 * lam.dot(D_ss.dot(lam)))
        if ops.moving:
            self._stick_obstacle_work = float(c.dot(ops.obstacle_tangent_velocity(t1)))
        new = self.rows.project_many(self.V)[0]   # (the normal rows move too: a sparse product)
        return new[:p], new[p:], total, loss

    def _degenerate_hint(self) -> str:
        """Why a reduced model's frictional problem may not be solved, and what to do."""
        if self._degenerate:
            return (f"; the model has {self.alg.sizes[1]} unknowns of motion (modes) for {self.ops.p + self.ops.pt} "
                    "contact unknowns, so its impulses are not unique: use more modes than contact unknowns, "
                    "or fewer rows (coupling: mean)")
        if isinstance(self.alg, DenseAlgebra) and self.ops.p > 1:
            return ("; in a reduced model the contact rows of a face see only the modes' motion, so their "
                    "problem is nearly singular on many rows: use coupling: mean, or the full model")
        return ""

    def _row_name(self, row: int) -> str:
        names = getattr(self.ops, "row_names", None)
        return f" ({names[row]})" if names is not None and 0 <= row < len(names) else ""


def _largest_safe(start: float, a: float, b: float, roundoff: float = 0.0) -> float:
    """The largest s in [0, 1] such that a correction whose loss is ``a s - b s^2 / 2`` gives back at most
    what the step lost of that kind, ``start`` (when positive), all along [0, s], to round-off (``roundoff``,
    and 1e-12 of the terms): the first root of ``max(start, 0) + a x - b x^2 / 2`` in (0, 1], or 1."""
    value = max(start, 0.0) + roundoff + 1e-12 * (abs(start) + abs(a) + abs(b))
    if b == 0.0:
        return min(1.0, -value / a) if a < 0.0 else 1.0
    disc = a * a + 2.0 * b * value
    if disc < 0.0:
        return 1.0
    roots = sorted(((a - np.sqrt(disc)) / b, (a + np.sqrt(disc)) / b))
    return next((float(x) for x in roots if 0.0 < x <= 1.0), 1.0)
