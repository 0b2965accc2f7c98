"""Moreau-Jean: the theta-method with contact impulses (docs/theory.md s. 4), the default method.

Why it holds where the paper's scheme does not. With theta = 1/2 the smooth part is the
trapezoidal rule, the same as Newmark's (beta 1/4, gamma 1/2). The two differ only in how the
contact acts over a step:

- Newmark (the paper) books the contact forces with the trapezoidal weights: over a step the
  contact does the work ``-Delta(P U) . (F_n + lam0_n+1)/2``, which by complementarity at both
  ends (``F . g = 0``, ``g = d(t) - P U``) is ``(F_n . g_n+1 - lam0_n+1 . g_n) / 2``. The first
  term is energy *given* to the structure by a row that carried a force at t_n and is open at
  t_n+1; at Courant numbers far above 1 the stiff modes ring with period 2 dt, rows open and
  close every step, and those release terms win: energy is created while the balance still
  closes (tests/test_energy_stability.py shows it on two masses).
- Moreau-Jean applies the contact as an impulse ``p`` at the end of the step: its work is
  ``-p . P (V_n + V_n+1)/2``, with no share of the previous step's force, so no release term.

Two levels of the condition on a row, both energy-safe for theta = 1/2, any step, any number of
rows and e in [0, 1]:

- ``position`` (the default): the gap at the end of every step, ``g_n+1 >= 0 _|_ p >= 0``. The
  work is ``-p . Delta(P U) / dt = -(p / dt) . g_n <= 0``: the paper's position-level scheme with
  its contact work fixed, gaps exact to round-off. The trapezoidal step leaves a held row with a
  spurious velocity; Carnot's correction then sets it to ``-e`` times the approach speed (the
  paper's law), or, should that give energy back, scales it by e (``_restitution``). With
  friction the same, Carnot's correction then a frictional impact problem in the step's total
  impulse, scaled down where it would give energy back (``_frictional_restitution``).
- ``velocity``: Newton's law ``gdot_n+1 + e gdot_n >= 0 _|_ p >= 0`` (``gdot = -P V``) on the
  rows whose gap, predicted to mid-step, is closed (Siconos' MoreauJeanOSI). The work is
  ``p (1 - e) gdot_n / 2 <= 0`` while ``gdot_n <= 0``; a row active while separating (only after
  a drift into the obstacle) takes e = 1, work zero. The price: the gap drifts into the
  obstacle by up to about dt times the impact speed per impact.

On an elastic row (a stop's spring, the reduced model's static compliance) the gap condition is
always taken at the end of the step with the force ``lam = p / dt``: the spring energy ``phi`` is
convex, so ``phi(x1) - phi(x0) <= phi'(x1) (x1 - x0)``: the stop stores at most what it receives.
"""

from __future__ import annotations

import numpy as np

from ..nonsmooth.lcp import compliant_forces
from ..nonsmooth.problem import OneStepProblem, carnot_projection
from .blocks import OpenStep, OpenSteps, diagonal
from ..linalg.dense import axpy
from ..mechanics.energy import EnergyBudget
from ..mechanics.system import Operators
from .state import StepState
from .friction_steps import FrictionSteps
from .scheme import ContactScheme

CHECK_EVERY = 32   # steps: K U and K V by products with K instead of from the step's identity
LEVELS = ("velocity", "position")
# The loads' work on a static part (the reduced model's) with the trapezoidal weights whatever theta: the
# static part's energy, the contact loss's share of it (_static_contact_loss) and that work then balance
# exactly, its energy being quadratic (with theta's weight they left (theta - 1/2) (dc G dc - d(L c) . dF)
# a step unbooked).
STATIC_WEIGHT = 0.5


class MoreauJean(FrictionSteps, ContactScheme):
    """Moreau-Jean theta-method for ``M U'' + C U' + K U + P^T lam = R(t)``, ``P U <= d(t)``, ``lam >= 0``.

    Parameters (``solver.theta``, ``solver.level``):

    - ``theta = 1/2`` (the default): the trapezoidal rule for the smooth forces, second order
      between impacts, unconditionally stable, and the contacts never create energy (see the
      module's docstring). The energy balance closes to round-off.
    - ``theta in (1/2, 1]``: numerical damping of the high frequencies, first order; theta = 1
      is backward Euler. The balance then has the scheme's own dissipation as its residual.
    - ``level``: ``position`` (the default: gaps closed at every step's end, with friction too,
      Carnot's correction for the restitution) or ``velocity`` (Newton's law on velocities; gaps
      drift).

    A step: ``(M + theta dt C + theta^2 dt^2 K) V1 = M V0 + dt R_theta - dt (1 - theta) C V0
    - dt K (U0 + theta (1 - theta) dt V0) - P^T p``, ``U1 = U0 + dt (theta V1 + (1 - theta) V0)``,
    one LCP for the impulses ``p`` in ``W = P S^-1 P^T`` (plus ``c / (theta dt^2)`` on elastic
    rows). The impulse ``p`` is reported as S_N, ``p / dt`` as the force F_N. Mass redistribution
    (no mass on the contact nodes) is allowed; such rows get no Carnot correction.

    Per step: one solve for the free velocity, a second one when some row carries an impulse
    (none with a condensed factor of S: the impulse is found between the halves of the first),
    one product with M (and C); K U and K V follow from the step's own equation (products with K
    after a Carnot correction, and every CHECK_EVERY-th step, so that the balance checks the solves).
    """

    name = "moreau_jean"
    unconditionally_stable = True   # theta >= 1/2
    takes_friction = True   # Coulomb friction: a cone problem on [P; P_T] (_build_friction)
    # K U and K V (kept by the step), P U of the dynamic part; with friction the last impulses and the
    # friction solver's warm start (its guess), and the solver's extremes over the run (the summary's)
    __checkpoint__ = ContactScheme.__checkpoint__ + ("KU", "KV", "_pu_dyn", "r_prev", "friction", "friction_residual",
                                                     "friction_sweeps", "friction_retries", "friction_impact",
                                                     "friction_scaled", "friction_velocity_steps")

    def __init__(self, ops: Operators, dt: float, theta: float = 0.5, level: str = "position"):
        if not 0.5 <= theta <= 1.0:
            raise ValueError(f"Moreau-Jean needs theta in [1/2, 1], got {theta}")
        if level not in LEVELS:
            raise ValueError(f"level must be one of {', '.join(LEVELS)}, got {level!r}")
        self.theta, self.level = theta, level
        S = ops.algebra.combine((1.0, ops.M), (theta * dt, ops.C), (theta * theta * dt * dt, ops.K))
        super().__init__(ops, dt, S, impact_correction=False)
        static = ops.static
        # The one-step problem in the impulses, rows divided by theta dt (W stays symmetric): the laws'
        # compliance and a static part's on the diagonal, the laws' memory in q (nonsmooth/problem.py).
        self.lcp = OneStepProblem(self.W, ops.laws, dt, compliance_scale=theta * dt * dt, row_scale=theta * dt,
                                  static=static.compliance if static is not None else None)
        # Elastic rows: a law's compliance (an elastic stop's), or a row the reduced model's static part
        # makes compliant.
        self.elastic = self.lcp.elastic.copy()
        if static is not None:
            self.elastic |= ~static.rigid_rows
        # Position level: every row takes its gap at the end of the step (a rigid row as an elastic
        # one without compliance); the rigid rows with mass then get Carnot's correction.
        self.position_rows = np.ones(ops.p, dtype=bool) if level == "position" else self.elastic
        self.carnot_rows = ~self.elastic & ~ops.massless_rows if level == "position" else np.zeros(ops.p, bool)
        self.friction = self.r_prev = self.friction_impact = None
        self.friction_residual, self.friction_sweeps, self.friction_retries, self.friction_scaled = 0.0, 0, 0, 0
        self.friction_velocity_steps = 0   # steps whose position-level cone problem fell back to the velocity level
        self._soft_t = None   # tangent rows a static part makes compliant (_build_friction)
        if ops.pt:
            self._build_friction()
        new = self.alg.vector
        self.KU, self.KV, self.KV_prev = new(), new(), new()

    def _condensed_impulse(self, st: StepState, t1: float, rhs: np.ndarray, V: np.ndarray):
        """The free velocity and the impulse in one solve with the condensed factor of S."""
        pv_free, impulse = self._condensed_solve(rhs, V, lambda pv: self._impulse(st, pv, t1))
        pv, jump = pv_free, 0.0
        if np.count_nonzero(impulse):
            self.ops.subtract_transpose(rhs, impulse)   # the step's equation with the impulse, for K V1
            Wp = self.W.dot(impulse)
            pv, jump = pv_free - Wp, float(np.abs(Wp).max())
        return impulse, pv, jump

    def replace_rows(self, P_local, d0: np.ndarray, tangents=None, same: bool = False) -> None:
        """New rows between two steps (ContactScheme.replace_rows): the one-step problem on the new W,
        the frictional problem on the new rows (its guess and figures kept: the rows are the same
        nodes'), and the state's projections on the new rows (the state itself does not change).
        ``same``: the rows the run had (a restart's): the solvers' last ``W r``, restored with them,
        hold too (on new rows they would not: W changed)."""
        super().replace_rows(P_local, d0, tangents)
        self._contact_args = None   # (compiled contact steps: on the new rows)
        ops, static = self.ops, self.ops.static
        self.lcp = OneStepProblem(self.W, ops.laws, self.dt, compliance_scale=self.theta * self.dt * self.dt,
                                  row_scale=self.theta * self.dt,
                                  static=static.compliance if static is not None else None)
        if self.friction is not None:   # (the guess kept; a restart's solvers as restored)
            kept = (self.r_prev, self.friction_residual, self.friction_sweeps, self.friction_retries,
                    self.friction_scaled)
            warm = [getattr(problem, "_last", None) for problem in (self.friction, self.friction_impact)]   # (r, W r)
            self._build_friction()
            (self.r_prev, self.friction_residual, self.friction_sweeps, self.friction_retries,
             self.friction_scaled) = kept
            for problem, last in zip((self.friction, self.friction_impact), warm):
                if same and problem is not None and last is not None:
                    problem._last = last
        st = self.state
        pu, pv = ops.project_many(self.U, self.V)
        self._pu_dyn = pu
        st.normal_displacement, st.normal_velocity, st.gap = pu, pv, ops.gap0(st.t) - pu
        if self.friction is not None:
            st.tangential_velocity = self.rows.project_many(self.V)[0][ops.p:]

    @classmethod
    def from_solver(cls, ops: Operators, solver) -> MoreauJean:
        """From the case file's ``solver`` section."""
        return cls(ops, solver.dt, theta=solver.theta, level=solver.level)

    def open_step(self) -> OpenStep | None:
        """The step without impulse, on a replicated diagonal system without friction (blocks.py)."""
        diag = diagonal(self.ops)
        if diag is None or self.friction is not None:
            return None
        return OpenStep(*diag, self.theta, ~self.position_rows, self.theta - 0.5, static_weight=STATIC_WEIGHT)

    def open_steps(self, loads: np.ndarray) -> OpenSteps:
        """``len(loads) - 1`` steps without impulse from the state, the loads ``loads`` at the state's
        time and at each step's end (L + 1 x n): the compiled ``step`` (kernels.py)."""
        ops = self.ops
        if getattr(self, "_open_args", None) is None:   # (the step's constants, as step() forms them)
            from .kernels import FUSED, moreau_jean_steps

            dt, theta, n = self.dt, self.theta, self.U.size
            coef = np.array([dt * (1.0 - theta), dt * theta, -dt * (1.0 - theta), -dt,
                             -theta * (1.0 - theta) * dt * dt, 1.0 / dt, -theta * dt, 1.0 / (theta * theta * dt * dt)])
            damped = ops.C is not None
            self._open_args = (moreau_jean_steps, FUSED, self.loaded, damped, coef, ops.M, ops.K,
                               ops.C if damped else np.zeros(n), self.solve_S.inverse)
        U, V, A, KU, KV = np.empty((5, loads.shape[0] - 1, self.U.size))
        CV = self.CV if ops.C is not None else self.U   # (not read without damping)
        kernel, *args = self._open_args
        kernel(self.state.step, CHECK_EVERY, *args, loads, self.U, self.V, self.MV, self.KU, self.KV, CV,
               U, V, A, KU, KV)
        P = ops._P_block   # (p x n, dense on a replicated system)
        return OpenSteps(U, V, A, V * ops.M, np.einsum("ji,ji->j", U, KU), U @ P.T, V @ P.T, {"KU": KU, "KV": KV})

    def contact_step(self) -> bool:
        """Whether its steps with impulses can be taken in compiled blocks (blocks.py, kernels.py): a
        diagonal replicated system without friction (``open_step``) whose rows all take their gap at the
        step's end with a compliance (a static part's, an elastic stop's: no Carnot correction), the laws
        without memory and storing 1/2 c F^2 at most, on fixed obstacles, their work in contact_loss."""
        ops = self.ops
        return bool(self.open_step() is not None and ops.p and self.elastic.all()
                    and not np.count_nonzero(self.carnot_rows) and ops.laws.plain
                    and not self.lcp.has_memory and not ops.moving and self._condensed is None
                    and isinstance(self.lcp.matrix, np.ndarray)
                    and set(ops.laws.columns) <= {"contact_loss"})

    def contact_steps(self, loads: np.ndarray, gap_free: np.ndarray) -> tuple[int, OpenSteps, np.ndarray]:
        """Up to ``len(loads) - 1`` steps with impulses from the state (``contact_step``), the loads as for
        ``open_steps``, ``gap_free`` (L x p) the gaps less the static offsets at the steps' ends: the
        compiled step (kernels.py). Returns (steps taken, their OpenSteps, their impulses, L x p); fewer
        steps than asked where the one-step problem needs the solver's fallback (that step is then the
        integrator's own)."""
        ops = self.ops
        if getattr(self, "_contact_args", None) is None:
            from .kernels import moreau_jean_contact_steps

            self.open_steps(loads[:1])   # (the open step's constants)
            P = np.ascontiguousarray(ops._P_block)
            G = np.ascontiguousarray(self.solve_S.inverse[:, None] * P.T)
            self._contact_args = (moreau_jean_contact_steps, P, G, np.ascontiguousarray(self.lcp.matrix),
                                  np.ascontiguousarray(P @ G))
        kernel, P, G, A_lcp, W = self._contact_args
        _, *args = self._open_args
        size, n, p = loads.shape[0] - 1, self.U.size, ops.p
        U, V, A, KU, KV = np.empty((5, size, n))
        X, PV, PU = np.empty((3, size, p))
        CV = self.CV if ops.C is not None else self.U
        st = self.state
        taken = kernel(st.step, CHECK_EVERY, *args, loads, self.U, self.V, self.MV, self.KU, self.KV, CV,
                       P, G, A_lcp, W, np.ascontiguousarray(gap_free), self._pu_dyn, st.normal_velocity,
                       st.impulse > 0.0, U, V, A, KU, KV, X, PV, PU)
        U, V, A, KU, KV, X, PV, PU = (x[:taken] for x in (U, V, A, KU, KV, X, PV, PU))
        steps = OpenSteps(U, V, A, V * ops.M, np.einsum("ji,ji->j", U, KU), PU, PV, {"KU": KU, "KV": KV})
        return taken, steps, X

    def block_ready(self, state: StepState) -> bool:
        """The previous force enters a step only through a static part or an elastic stop's spring
        (their energy and work): without them any state will do."""
        return (self.ops.static is None and not self._elastic_stops) or super().block_ready(state)

    def resume(self, state: StepState, carry: dict) -> None:
        super().resume(state, carry)
        np.copyto(self.KU, carry["KU"])
        np.copyto(self.KV, carry["KV"])
        if self.ops.p:
            self._pu_dyn, pv = self.ops.project_many(self.U, self.V)
            self._resume_rows(self._pu_dyn, pv)

    def start(self, U0, V0, t0: float = 0.0) -> StepState:
        """The state at t0: no impulse yet (a row closed and approaching is handled by the first step)."""
        ops, alg = self.ops, self.alg
        pu, pv, _ = self._initial_state(U0, V0, t0)
        self._pu_dyn = pu   # P U of the dynamic part (without a static part's offset)
        force = np.zeros(ops.p)
        if ops.static:   # forces of the compliant rows that the initial state already loads
            c = ~ops.static.rigid_rows
            force[c] = compliant_forces(ops.static.compliance[c][:, c], (ops.gap0(t0) - ops.static.offset(t0) - pu)[c])
            pu = pu + ops.static.offset(t0) - ops.static.compliance @ force
        energy = EnergyBudget()
        energy.kinetic, energy.strain = self._quadratic_energies()
        energy.load_scale = self._start_load_scale
        energy.roundoff = self._start_roundoff
        alg.mult(ops.K, self.U, self.KU)
        alg.mult(ops.K, self.V, self.KV)
        if ops.C is not None:
            alg.mult(ops.C, self.V, self.CV)
        gap = ops.gap0(t0) - pu
        self._book_stops(energy, (force, gap), (force, gap))
        if ops.static:
            energy.strain += ops.static.energy(t0, force)
        energy.initial = energy.total
        self.state = StepState(step=0, t=t0, U=self.U, V=self.V, A=self.A, gap=gap, force=force,
                               impulse=np.zeros(ops.p), energy=energy, normal_displacement=pu,
                               normal_velocity=pv)
        if self.friction is not None:
            self.state.tangential = np.zeros(ops.pt)
            self.state.tangential_velocity = self.rows.project_many(self.V)[0][ops.p:]
        return self.state

    def step(self) -> StepState:
        ops, alg, st, dt, theta = self.ops, self.alg, self.state, self.dt, self.theta
        t1 = self.t0 + (st.step + 1) * dt
        U, V, A, rhs = self.U, self.V, self.A, self.rhs
        self._begin_step()   # U_prev = U0; C V0 kept in CV_prev
        self.KV, self.KV_prev = self.KV_prev, self.KV

        # rhs = M V0 + dt R_theta - dt (1 - theta) C V0 - dt K U0 - theta (1 - theta) dt^2 K V0
        # (M V0 is the previous step's M V1; R_theta = theta R1 + (1 - theta) R0).
        np.copyto(rhs, self.MV)
        if self.loaded:
            axpy(rhs, dt * (1.0 - theta), self.R)
            self._evaluate_load(t1)
            axpy(rhs, dt * theta, self.R)
        if ops.C is not None:
            axpy(rhs, -dt * (1.0 - theta), self.CV_prev)
        axpy(rhs, -dt, self.KU)
        axpy(rhs, -theta * (1.0 - theta) * dt * dt, self.KV_prev)
        axpy(U, dt * (1.0 - theta), V)   # U0 + dt (1 - theta) V0; the theta V1 part below
        np.copyto(A, V)                  # V0, for the mean acceleration (V1 - V0) / dt

        p = ops.p
        impulse = np.zeros(p)
        pu, pv = st.normal_displacement, st.normal_velocity
        jump = 0.0   # the largest change of a normal velocity the impulse made
        tangential = pt = None
        if self._condensed is not None and self.friction is None:   # one solve, the impulse between its halves
            impulse, pv, jump = self._condensed_impulse(st, t1, rhs, V)
        else:
            self.solve_S(rhs, V)         # the free velocity
            if p and self.friction is not None:
                impulse, tangential, pv, pt, jump = self._frictional_impulse(st, t1, rhs)
            elif p:
                pv_free = ops.project_many(V)[0]
                impulse = self._impulse(st, pv_free, t1)
                pv = pv_free
                if np.count_nonzero(impulse):
                    self.G.subtract_from(V, impulse)
                    ops.subtract_transpose(rhs, impulse)   # the step's equation with the impulse, for K V1
                    Wp = self.W.dot(impulse)
                    pv, jump = pv_free - Wp, float(np.abs(Wp).max())
        axpy(U, dt * theta, V)
        if ops.C is not None:   # C V1 of the step's equation (before Carnot's correction): its damping work
            alg.mult(ops.C, V, self.CV)
        pv_star, pt_star, restitution_loss, percussion = pv, pt, 0.0, impulse
        stick_loss = self._stick_obstacle_work = 0.0
        numerical_loss = self._numerical_loss(st, impulse, tangential, pv, pt) if theta != 0.5 else 0.0
        if tangential is not None and self.friction_impact is None and self._persists is not None:
            pv, pt, tangential, stick_loss = self._stick(impulse, tangential, pv, pt, jump, t1)
        carnot = friction_carnot = None
        friction_work = obstacle_friction_work = 0.0
        if tangential is not None:   # the friction impulses' work (_friction_velocity), relative to the obstacles
            slide = self._friction_velocity(st.tangential_velocity, pt_star)
            if ops.moving:
                obstacle = self._friction_velocity(ops.obstacle_tangent_velocity(st.t), ops.obstacle_tangent_velocity(t1))
                slide = slide - obstacle
                obstacle_friction_work = float(self._r_t.dot(obstacle))
            friction_work = float(self._r_t.dot(slide))
        if p:   # the work of the impulse with the step's mean velocity (exact for theta = 1/2)
            # (moving obstacles: their mean rate over the step, (d(t1) - d(t0)) / dt, is theirs, and the
            # laws book the work on the velocity relative to it; a row held at both ends loses nothing)
            moved = ops.obstacle_moved(st.t, t1)
            obstacle_rate = None if moved is None else moved / dt
            step_contact_loss = float(impulse.dot(0.5 * (st.normal_velocity + pv_star)))
            if np.count_nonzero(self.carnot_rows) and not getattr(self, "at_velocity", False):
                pu_end = self._pu_dyn + dt * ((1.0 - theta) * st.normal_velocity + theta * pv_star)
                guard = step_contact_loss if moved is None else step_contact_loss - float(impulse.dot(obstacle_rate))
                if self.friction_impact is not None:
                    friction_carnot = self._frictional_restitution(impulse, tangential, pv, pt, st.normal_velocity,
                                                                   pu_end, guard, friction_work, jump, st.step + 1, t1)
                    if friction_carnot is not None:   # (the history's impulses: the step's totals, as _stick's)
                        pv, pt, carnot, restitution_loss, stick_loss = friction_carnot
                        tangential = tangential + carnot[p:]
                        carnot = carnot[:p]
                else:
                    pv, restitution_loss, carnot = self._restitution(impulse, st.normal_velocity, pv, pu_end, guard,
                                                                     jump, t1)
                if carnot is not None:   # Carnot's correction is an impulse too: the step's total (history)
                    percussion = impulse + carnot
        np.subtract(V, A, out=A)
        A *= 1.0 / dt
        force = impulse / dt

        # K V1 from the step's equation S V1 = rhs: theta^2 dt^2 K V1 = rhs - M V1 - theta dt C V1.
        alg.mult(ops.M, V, self.MV)
        corrected = pv is not pv_star   # Carnot's correction changed V: products below
        if (st.step + 1) % CHECK_EVERY and not corrected:
            np.subtract(rhs, self.MV, out=self.KV)
            if ops.C is not None:
                axpy(self.KV, -theta * dt, self.CV)
            self.KV *= 1.0 / (theta * theta * dt * dt)
            axpy(self.KU, dt * (1.0 - theta), self.KV_prev)
            axpy(self.KU, dt * theta, self.KV)
        else:
            alg.mult(ops.K, V, self.KV)
            alg.mult(ops.K, U, self.KU)

        energy = st.energy.copy()
        static_terms = sliding = None
        if p:
            pu = self._pu_dyn = ops.project_many(U)[0]
            if self._soft_t is not None and tangential is not None:   # (a static part on the tangent rows too)
                static_terms = self._static_terms(st, force, tangential, t1)
                pu = pu + static_terms[0]
                # (the compliant rows' whole slip over the step, divided by dt: the history's slip)
                sliding = (1.0 - theta) * st.tangential_velocity + theta * pt_star + static_terms[5] / dt
            elif ops.static:
                pu = pu + ops.static.offset(t1) - ops.static.compliance.dot(force)
            self._book_work(energy, impulse, 0.5 * (st.normal_velocity + pv_star), total=step_contact_loss,
                            obstacle=obstacle_rate)
            energy.impact_loss += restitution_loss
            if carnot is not None:
                self._book_impulse(energy, carnot, t1)
            if tangential is not None:
                energy.external_work -= obstacle_friction_work + self._stick_obstacle_work
                energy.friction_loss += friction_work + stick_loss
            if static_terms is not None:   # the friction's work on the static slip; the rest is the contacts'
                energy.friction_loss += static_terms[3]
                energy.contact_loss += static_terms[4]
            elif ops.static:
                energy.contact_loss += self._static_contact_loss(st, force, t1)
        energy.numerical_loss += numerical_loss
        self._step_energies(energy, t1, 1.0 - theta, theta, self.MV, KU=self.KU)
        if corrected and ops.C is not None:   # the next step starts from the corrected velocity
            alg.mult(ops.C, V, self.CV)
        gap = ops.gap0(t1) - pu
        self._book_stored(energy, st, force, gap, t1, STATIC_WEIGHT,
                          None if static_terms is None else static_terms[1:3])
        self.state = StepState(step=st.step + 1, t=t1, U=U, V=V, A=A, gap=gap, force=force,
                               impulse=percussion, energy=energy, normal_displacement=pu, normal_velocity=pv)
        if tangential is not None:
            if corrected:   # a velocity correction moved the tangent rows' dofs too
                pt = self.rows.project_many(V)[0][p:]
            self.state.tangential, self.state.tangential_velocity = tangential / dt, pt
            if sliding is not None:   # (a rigid row's: its velocity at the step's end, as without a static part)
                self.state.sliding = np.where(self._soft_t, sliding, pt)
        return self.state

    def _numerical_loss(self, st: StepState, impulse: np.ndarray, r_t: np.ndarray | None, pv: np.ndarray,
                        pt: np.ndarray | None) -> float:
        """The energy the theta weighting removes in the step (before any velocity correction).

        With ``dU = dt V_theta``, ``V_theta = (1 - theta) V0 + theta V1`` and the step's equation ``M dV =
        dt (R_theta - K U_theta - C V_theta) - Q^T r`` (r every impulse, Q its rows), the kinetic energy
        changes by ``1/2 (V0 + V1) . M dV`` and ``1/2 (V0 + V1) = V_theta - (theta - 1/2) dV``: the loads,
        the damping and the impulses do the work the budget books (the impulses with the step's mean
        velocity, Kelvin's), the strain energy changes by ``dU . K U_theta - (theta - 1/2) dU . K dU``,
        and what is left is ``(theta - 1/2) (dV . M dV + dU . K dU + r . Q dV)``: the scheme's own
        dissipation (no physical term), which closes the balance to round-off for any theta. (The
        friction rows under the slip law book their work with V_theta, which holds their part of
        ``r . Q dV``: only the other rows' part is left here.)
        """
        ops, alg, theta, dt = self.ops, self.alg, self.theta, self.dt
        if getattr(self, "_dV", None) is None:
            self._dV, self._MdV = alg.vector(), alg.vector()
        dV, product = self._dV, self._MdV
        np.subtract(self.V, self.A, out=dV)   # (A holds V0 until the step's end)
        alg.mult(ops.M, dV, product)
        local = [dV @ product]
        dV *= 1.0 - theta                      # V_theta = V1 - (1 - theta) dV, in place
        np.subtract(self.V, dV, out=dV)
        alg.mult(ops.K, dV, product)
        local.append(dt * dt * (dV @ product))
        sums = alg.allsum(np.array(local))
        contact = float(impulse.dot(pv - st.normal_velocity)) if ops.p else 0.0
        if r_t is not None:   # (the slip law's rows book their work with V_theta already: _friction_velocity)
            closing = ~self._persists if self._persists is not None else slice(None)
            contact += float(r_t[closing].dot((pt - st.tangential_velocity)[closing]))
        return (theta - 0.5) * (float(sums[0] + sums[1]) + contact)

    def _impulse(self, st: StepState, pv_free: np.ndarray, t1: float) -> np.ndarray:
        """The step's impulses from one LCP over the active rows (see the class docstring)."""
        q, active = self._contact_problem(st, pv_free, t1)
        impulse = np.zeros(self.ops.p)
        if not np.count_nonzero(active):
            return impulse
        if np.count_nonzero(active) == active.size:
            impulse = self.lcp.solve(q, guess=st.impulse > 0.0)[0]
        else:
            a = np.flatnonzero(active)
            impulse[a] = self.lcp.solve(q[a], guess=st.impulse[a] > 0.0, rows=a)[0]
        return impulse

    def _contact_problem(self, st: StepState, pv_free: np.ndarray, t1: float) -> tuple[np.ndarray, np.ndarray]:
        """``(q, active)`` of the step's normal problem ``w = W p + q`` (the class docstring)."""
        ops, dt, theta = self.ops, self.dt, self.theta
        pv0 = st.normal_velocity   # P V0 (the dynamic part: a static part has no velocity of its own)
        gap0 = st.gap
        # Rigid rows: active when the gap predicted to mid-step is closed. Newton's law on the
        # velocities relative to the obstacles, -P V1 - e' P V0 >= 0, with e' = e while approaching
        # (P V0 >= 0), 1 while separating.
        rel0 = ops.relative(pv0, st.t)
        e = np.where(rel0 >= 0.0, ops.restitution, 1.0)
        q = -ops.relative(pv_free, t1) - e * rel0
        active = self.position_rows | (gap0 - 0.5 * dt * rel0 <= 0.0)
        if np.count_nonzero(self.position_rows):
            # Elastic rows (and every row at the position level): d(t1) - P U1 + c p / dt >= 0 with
            # P U1 = P U0 + dt ((1 - theta) P V0 + theta P V1), divided by theta dt to keep the LCP
            # matrix symmetric.
            el = self.position_rows
            offset = ops.static.offset(t1) if ops.static else 0.0
            g_free = (ops.gap0(t1) - offset - self._pu_dyn - dt * (1.0 - theta) * pv0) / (theta * dt) - pv_free
            q = self.lcp.q(np.where(el, g_free, q), gap0)
        return q, active

    def _restitution(self, impulse: np.ndarray, pv0: np.ndarray, pv: np.ndarray, pu: np.ndarray,
                     contact_loss: float, jump: float, t1: float) -> tuple[np.ndarray, float, np.ndarray | None]:
        """Position level: Carnot's correction on the rigid rows held at the end of the step.

        A row held by a position-level impulse leaves the trapezoidal step with a spurious
        velocity ``P V*`` (a row hit mid-step ends at rest, one hit at the start of the step
        rebounds elastically). The smallest velocity change in the norm of M, ``dV = -M^-1 P_a^T
        lam`` with ``lam = D_aa^-1 (P_a V* - d)``, sets the normal velocity to ``d = -e max(P V0,
        0)``: Newton's law on the approach speed at the start of the step (the paper's choice;
        e = 0: the row stops). With the impulse of the step this loses ``contact_loss + lam .
        (P V* - 1/2 D lam)``; should that be negative (it is not for a point mass, nor for e = 0),
        the target becomes ``d = e P V*``, which loses ``(1 - e^2)/2 P V* . D^-1 P V* >= 0``
        (e the smallest on those rows): the contacts never give energy. Returns (P V+, its loss, the
        correction's impulses ``lam`` per row, or None without a correction).
        """
        # The rows held by an impulse, and those that end the step at the obstacle still
        # approaching without one (a gap closing exactly at the step's end: whether round-off
        # then gives an impulse of 1e-15 or none must not decide whether the row stops).
        ops = self.ops
        at_obstacle = self._at_obstacle(pu, t1)
        rel, rel0 = ops.relative(pv, t1), ops.relative(pv0, t1)   # (relative to the obstacles)
        rows = np.flatnonzero(self.carnot_rows & ((impulse > 0.0) | (at_obstacle & (rel >= 0.0))))
        if not rows.size:
            return pv, 0.0, None
        e = self.ops.restitution[rows]
        # (In a persisting contact the held rows end the step at rest to round-off, P V* = -P V0 = 0:
        # no correction, and no solve with M.)
        found = carnot_projection(self.carnot, rows, rel[rows], -e * np.maximum(rel0[rows], 0.0), e, contact_loss,
                                  jump)
        if found is None:
            return pv, 0.0, None
        lam_a, loss = found
        carnot = self.carnot
        lam = np.zeros(self.ops.p)
        lam[rows] = lam_a
        self.H.subtract_from(self.V, lam)
        return pv - carnot.dot(lam), loss, lam

    def _static_contact_loss(self, st: StepState, force: np.ndarray, t1: float) -> float:
        """What the reduced model's static part adds to the contact loss over a step.

        The static part stores ``E_s(t, lam) = 1/2 c G c - lam . L c + 1/2 lam . C lam`` (c: the
        load's time functions, L c = P S_k R, C = P S_k P^T) and the loads work on it as
        ``StaticCorrection.work`` books. With the dynamic part's exact identity, the balance closes
        when the contact loss also holds ``mean(lam) . Delta(L c) - Delta(1/2 lam . C lam)``. For
        constant loads, complementarity at the end of the step makes the whole contact loss at
        least ``1/2 Delta lam . C Delta lam >= 0`` (the end-point rule on a convex spring).
        """
        static = self.ops.static
        f0 = st.force
        loss = 0.5 * float((f0 + force).dot(static.offset(t1) - static.offset(st.t)))
        return loss - 0.5 * float(force.dot(static.compliance.dot(force)) - f0.dot(static.compliance.dot(f0)))
