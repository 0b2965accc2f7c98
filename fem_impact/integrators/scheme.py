"""What the time-stepping schemes with contact share: the constant operators built once, the
state vectors, the initial acceleration, the energy budget of a step, the step's report."""

from __future__ import annotations

import logging
import time

import numpy as np
from scipy import sparse

from ..nonsmooth.laws import RowLaws
from ..nonsmooth.lcp import TINY, Delassus, compliant_forces, delassus_solver
from ..nonsmooth.problem import ImpactResult, impact_correction
from ..linalg.backends import owned_values
from ..linalg.condensed import CondensedFactor
from ..mechanics.energy import EnergyBudget
from ..mechanics.system import Operators
from .state import StepState

log = logging.getLogger(__name__)
EPS = np.finfo(float).eps


class ContactScheme:
    """Base of the integrators: ``M U'' + C U' + K U + P^T lam = R(t)``, ``P U <= d(t)``, ``lam >= 0``.

    Built once: the factorization of the step matrix ``S`` (given by the subclass) and of ``M``,
    ``G = S^-1 P^T``, ``H = M^-1 P^T`` and the p x p matrices ``W = P G`` and ``D = P H``.
    ``impact_rows`` are the rows that get Carnot's velocity correction and the acceleration
    projection: rigid (no static compliance, no elastic stop), with mass on their dofs, and the
    correction switched on. ``H`` and ``D`` are built on first use (a scheme whose rows get no
    Carnot correction pays nothing for them). ``G`` and ``H`` are stored columns for few rows
    and solves with the factor for many (``Operators.delassus``): either way
    ``G.subtract_from(y, c)`` is ``y -= S^-1 P^T c``.
    """

    name = ""
    # The state a checkpoint saves (fem_impact/app/checkpoint/): what a step reads of the one before
    # (the state vectors, the products M V, M A, C V and the load R at its time, the StepState with its
    # energy budget) and the start time; the rest the restarted run builds from its case.
    __checkpoint__ = ("t0", "U", "V", "A", "MV", "MA", "R", "CV", "state")
    # W and D as sparse diagonals where they are (Operators.delassus): the schemes whose contact
    # step takes them that way
    diagonal_delassus = False
    scheme_energy = False   # whether the scheme conserves an energy term beyond kinetic + strain (EnergyBudget.scheme)
    # Whether the scheme is stable at any dt on a linear system (what a blow-up says of dt: EnergyWatch);
    # None: not known.
    unconditionally_stable: bool | None = None

    def __init__(self, ops: Operators, dt: float, S, impact_correction: bool = True):
        alg = ops.algebra
        if ops.laws is None:   # (rows given by arrays: Newton's law and elastic stops)
            ops.laws = RowLaws.from_arrays(ops.restitution, ops.stop_compliance, ops.friction)
        self.ops, self.alg, self.dt = ops, alg, dt
        self.S = S
        self.timings: dict[str, float] = {}   # seconds of the setup's stages (benchmarks read them)
        clock = time.perf_counter()
        # (M, C, K symmetric, M positive definite; the contact dofs kept out where W takes S^-1 on them)
        self.solve_S = alg.factorize(S, spd=True, kept=ops.condensed_dofs())
        self.timings["factorize S"] = time.perf_counter() - clock
        clock = time.perf_counter()
        self.solve_M = alg.factorize(ops.mass_for_solves(), spd=True)
        self.timings["factorize M"] = time.perf_counter() - clock
        clock = time.perf_counter()
        # P S^-1 P^T (p x p, every rank); S^-1 P^T
        self.W, self.G = ops.delassus(self.solve_S, diagonal=self.diagonal_delassus)
        self.timings["W"] = time.perf_counter() - clock
        self._condensed = self._condensed_rows()
        self._D = self._H = self._carnot = None
        static = ops.static
        rigid = static.rigid_rows if static else np.ones(ops.p, dtype=bool)
        self.impact_rows = rigid & ~ops.laws.elastic(dt) & ~ops.massless_rows & bool(impact_correction)
        self._abs_d0 = np.abs(ops.d0)
        self._elastic_stops = ops.laws.stores(dt)   # (rows that store energy: their booking is not skipped)
        new = alg.vector
        # State, products and work vectors, allocated once; pairs are swapped by reference. U and V
        # are updated in place; U_prev keeps the step's starting U where the work terms need it.
        self.U, self.V, self.A, self.U_prev = new(), new(), new(), new()
        self.MV, self.MA, self.MA_prev = new(), new(), new()   # M V, M A: see _step_energies
        self.rhs, self.work = new(), new()
        self.R = new()
        self.R_prev = new() if ops.load.time_dependent else self.R   # a constant load: one vector, no copies
        self.CV, self.CV_prev = (new(), new()) if ops.C is not None else (None, None)
        self.loaded = self.track_du = True   # (known at the start)
        # 1/2 dt^2 / m_i per dof (lumped: row sums of M; 0 without mass): R . (this R) is the kinetic
        # energy the load gives the free nodes in one step, the load's energy scale (_load_energy).
        masses = alg.row_sums(ops.M)
        self._load_weights = np.divide(0.5 * dt * dt, masses, out=np.zeros_like(masses), where=masses > 0.0)
        self.t0 = 0.0
        self.state: StepState | None = None

    # Whether the scheme takes new rows between steps (replace_rows: a surface contact searched again
    # as its bodies slide); the others keep the rows of t = 0.
    takes_new_rows = False

    def replace_rows(self, P_local, d0: np.ndarray, tangents=None, same: bool = False) -> None:
        """New rows of the same count between two steps: the operators' rows and what the scheme built
        on them (W, G, the condensed factor's rows, Carnot's operators, rebuilt on use)."""
        ops = self.ops
        ops.replace_rows(P_local, d0, tangents)
        clock = time.perf_counter()
        self.W, self.G = ops.delassus(self.solve_S, diagonal=self.diagonal_delassus)
        self.timings["W again"] = self.timings.get("W again", 0.0) + time.perf_counter() - clock
        self._condensed = self._condensed_rows()
        built = self._D is not None
        self._D = self._H = self._carnot = None
        if built:   # (again now, where a search is timed, not at the next impact)
            self._build_mass_operators()
        self._abs_d0 = np.abs(ops.d0)

    # -- operators of Carnot's correction, built on first use ------------------------------
    def _build_mass_operators(self) -> None:
        clock = time.perf_counter()
        D, self._H = self.ops.delassus(self.solve_M, diagonal=self.diagonal_delassus)   # P M^-1 P^T; M^-1 P^T
        self._carnot = delassus_solver(D)
        self._D = self._carnot.matrix
        self.timings["D"] = time.perf_counter() - clock
        log.info("Carnot's correction on %d rows: D = P M^-1 P^T in %.3g s", self.ops.p, self.timings["D"])

    @property
    def D(self) -> np.ndarray:
        """``P M^-1 P^T`` (p x p, every rank; regularized when singular)."""
        if self._D is None:
            self._build_mass_operators()
        return self._D

    @property
    def H(self):
        """``M^-1 P^T`` as corrections: ``H.subtract_from(y, c)`` is ``y -= M^-1 P^T c``."""
        if self._H is None:
            self._build_mass_operators()
        return self._H

    @property
    def carnot(self) -> Delassus:
        """LCP solver on ``D``, keeping the factor of its active block between steps."""
        if self._carnot is None:
            self._build_mass_operators()
        return self._carnot

    # -- pieces of a step ----------------------------------------------------------------
    def _free_acceleration(self, U: np.ndarray, V: np.ndarray, solve, out: np.ndarray,
                           massless_at_rest: bool = False) -> None:
        """``out = solve(R - K U - C V)`` (``_free_rhs``)."""
        solve(self._free_rhs(U, V, massless_at_rest), out)

    def _free_rhs(self, U: np.ndarray, V: np.ndarray, massless_at_rest: bool = False) -> np.ndarray:
        """``R - K U - C V`` into ``self.rhs``, with the load in ``self.R``; C V is kept in ``self.CV``.

        ``massless_at_rest``: a zero right-hand side on the massless dofs (for the solve with M,
        whose unit diagonal there is a placeholder; a step matrix S holds their equation).
        """
        ops, alg, rhs = self.ops, self.alg, self.rhs
        alg.mult(ops.K, U, rhs)
        np.subtract(self.R, rhs, out=rhs)
        if ops.C is not None:
            alg.mult(ops.C, V, self.CV)
            rhs -= self.CV
        if massless_at_rest:
            rhs[ops.massless] = 0.0
        return rhs

    def _condensed_rows(self):
        """(S's factor, P on its kept dofs: p x m) where S was factorized keeping the rows' dofs out
        (``CondensedFactor``): a step then solves its contact problem between the halves of one
        solve (``_condensed_solve``). Else None."""
        solve, P = self.solve_S, self.ops._P
        if not isinstance(solve, CondensedFactor) or not self.ops.p:
            return None
        where = solve.positions(P.indices)
        if where is None:
            return None
        return solve, sparse.csr_matrix((P.data, where, P.indptr), shape=(P.shape[0], solve.m))

    def _condensed_solve(self, rhs: np.ndarray, x: np.ndarray, contact) -> tuple[np.ndarray, np.ndarray]:
        """``x = S^-1 (rhs - P^T lam)`` with ``lam = contact(P S^-1 rhs)``, in one solve with the
        condensed factor (``self._condensed``): the values on the rows' dofs first (``begin``),
        ``lam`` from them, its change ``S_C^-1 P_C^T lam`` of those values, then the rest
        (``finish``; docs/theory.md s. 3.2). Returns ``P S^-1 rhs`` and ``lam``."""
        factor, P_kept = self._condensed
        x_kept = factor.begin(rhs)
        free = P_kept @ x_kept
        lam = contact(free)
        if np.count_nonzero(lam):
            x_kept -= factor.dense(P_kept.T @ lam)
        factor.finish(x_kept, x)
        return free, lam

    def _evaluate_load(self, t: float) -> None:
        """R(t) into ``self.R`` (the previous one is kept in ``self.R_prev``)."""
        if self.ops.load.time_dependent:
            self.R, self.R_prev = self.R_prev, self.R
            self.ops.load.evaluate(t, self.R)

    def _begin_step(self) -> None:
        """Keep what the step's work terms need of the state it starts from."""
        if self.ops.C is not None:
            self.CV, self.CV_prev = self.CV_prev, self.CV
        if self.track_du:
            np.copyto(self.U_prev, self.U)

    def _closed(self, pu: np.ndarray, lam0: np.ndarray, t: float) -> np.ndarray:
        """Impact rows closed at the end of a step (at t): pushed by lam0, or at zero gap up to round-off."""
        closed = lam0 > 0.0
        if np.count_nonzero(closed) < closed.size:   # (all pushed: the common case in a contact)
            closed |= self._at_obstacle(pu, t)
        return closed & self.impact_rows

    def _at_obstacle(self, pu: np.ndarray, t: float) -> np.ndarray:
        """The rows at zero gap ``d(t) - P U`` up to round-off."""
        d = self.ops.gap0(t)
        scale = self._abs_d0 if d is self.ops.d0 else np.abs(d)
        return d - pu <= 1e-10 * (scale + np.abs(pu)) + TINY

    def _apply_corrections(self, res: ImpactResult, pv: np.ndarray, energy: EnergyBudget, t: float) -> np.ndarray:
        """Velocity (-H lam1) and acceleration (-H lam2) corrections at t; returns the new P V. The
        kinetic energy that dV = -H lam1 removes, 1/2 V-MV- - 1/2 V+MV+ (exactly, in p x p terms),
        is the impact loss in the obstacles' frame plus the work of moving obstacles on the impulse
        (``_book_impulse``)."""
        Dlam1 = self.D.dot(res.lam1)
        if np.count_nonzero(res.lam1):
            self.H.subtract_from(self.V, res.lam1)
            pv = pv - Dlam1
        if np.count_nonzero(res.lam2):
            self.H.subtract_from(self.A, res.lam2)
        energy.impact_loss += float(res.lam1.dot(self.ops.relative(pv, t) + 0.5 * Dlam1))
        self._book_impulse(energy, res.lam1, t)
        return pv

    def _book_impulse(self, energy: EnergyBudget, impulse: np.ndarray, t: float) -> None:
        """What moving obstacles give the structure through an impulse at t: ``-impulse . d'(t)``,
        external work (the obstacle that approaches a row pushes it)."""
        if self.ops.moving:
            energy.external_work -= float(impulse.dot(self.ops.d_rate(t)))

    def _book_work(self, energy: EnergyBudget, force: np.ndarray, motion: np.ndarray, total: float | None = None,
                   obstacle: np.ndarray | None = None) -> None:
        """The contact forces' work over the step, ``force . motion``, in each law's loss column.

        ``obstacle``: the obstacles' motion in the units of ``motion`` (``Operators.obstacle_moved``,
        per unit of time where ``motion`` is a velocity), None when none moves. The laws then book
        the work on the motion relative to the obstacles, and the obstacles' own work on the
        structure, ``-force . obstacle``, goes to the external work.
        """
        if obstacle is not None:
            moved = float(force.dot(obstacle))
            energy.external_work -= moved
            motion = motion - obstacle
            total = None if total is None else total - moved
        for column, work in self.ops.laws.work(force, motion, total).items():
            energy.add_loss(column, work)

    def _book_stops(self, energy: EnergyBudget, before: tuple, after: tuple) -> None:
        """What the rows' laws store (an elastic stop's spring, ...; their ``stored`` hook, from the rows'
        (force, gap) ``before`` and ``after`` the step): that part of the contact work moves from the
        laws' loss columns to the strain energy."""
        if not self._elastic_stops:   # (then nothing to book: skip the small-array arithmetic)
            return
        laws = self.ops.laws
        stored, previous = laws.stored(*after), laws.stored(*before)
        for column, value in stored.items():
            energy.add_loss(column, -(value - previous[column]))
            energy.strain += value

    def _book_stored(self, energy: EnergyBudget, st: StepState, force: np.ndarray, gap: np.ndarray, t1: float,
                     weight: float, static_forces: tuple | None = None) -> None:
        """What the step stores off the structure's own dofs: the laws' (elastic stops' springs) and a
        static part's energy, with the loads' work on the static part (``weight``: the scheme's for t1;
        ``static_forces``: the static part's forces at t0 and t1 where they are not the normal ones, with
        friction ``[F_N, F_T]``)."""
        self._book_stops(energy, (st.force, st.gap), (force, gap))
        static = self.ops.static
        if static:
            f0, f1 = static_forces if static_forces is not None else (st.force, force)
            energy.strain += static.energy(t1, f1)
            energy.external_work += static.work(st.t, t1, f0, f1, weight)

    def _load_energy(self) -> float:
        """This rank's part of the load's energy scale at the step: ``1/2 dt^2 R . M_L^-1 R``."""
        return float(np.einsum("i,i,i->", self.R, self.R, self._load_weights)) if self.loaded else 0.0

    def _static_load_energy(self, t: float) -> float:
        """What the load alone stores in a static part (the reduced model's), replicated."""
        static = self.ops.static
        return static.energy(t, np.zeros(self.ops.p)) if static is not None and self.loaded else 0.0

    def _quadratic_energies(self) -> tuple[float, float]:
        """Kinetic and strain energy from products with M and K; sets ``MV`` and ``MA`` (at the start)."""
        ops, alg = self.ops, self.alg
        alg.mult(ops.M, self.V, self.MV)
        alg.mult(ops.M, self.A, self.MA)
        alg.mult(ops.K, self.U, self.work)
        sums = alg.allsum(np.array([self.V @ self.MV, self.U @ self.work, self._load_energy(), self._roundoff(self.U)]))
        self._start_load_scale = sums[2] + self._static_load_energy(self.t0)
        self._start_roundoff = EPS * sums[3]
        return 0.5 * sums[0], 0.5 * sums[1]

    def _roundoff(self, U: np.ndarray) -> float:
        """This rank's part of ``|U|^T |K| |U|``: exactly for a replicated K (the reduced model's: a rigid
        mode has no stiffness, whatever its coordinate), else its bound ``||K||_inf |U|^2`` (no product)."""
        if getattr(self, "_abs_K", None) is None:
            K = self.ops.K
            self._abs_K = np.abs(K) if isinstance(K, np.ndarray) else self.alg.norm(K)
        weights = self._abs_K
        if isinstance(weights, float):
            return weights * float(U @ U)
        return float(U @ (weights * U) if weights.ndim == 1 else U @ (weights @ U))

    def _step_energies(self, energy: EnergyBudget, t1: float, w_prev: float, w_new: float, MV: np.ndarray,
                       KU_rest: np.ndarray | None = None, force_work: float = 0.0,
                       scheme_weight: float = 0.0, KU: np.ndarray | None = None) -> None:
        """Kinetic and strain energy at the new step (t1); external work and damping loss over the step.

        ``MV = M V`` comes from the scheme. ``U^T K U``: with ``KU`` (K U, kept by the scheme),
        directly; with ``KU_rest``, from the equation of motion that the step solved, ``K U = R - CV
        - KU_rest - P^T F`` (``CV`` = ``self.CV``, its damping force; the replicated ``force_work =
        (P U) . F``), without a product with K; else by one.

        Work terms use the weights (w_prev, w_new) of the scheme's own rule for the forces over a
        step (the trapezoidal rule: 1/2, 1/2), with ``Delta U``: for the trapezoidal rule the
        balance then closes to round-off; with gamma > 1/2 its residual is the scheme's own
        numerical dissipation, which no term books. ``scheme_weight``: the scheme's own energy is
        ``scheme_weight A.M A`` (``self.MA`` = M A at the step).
        """
        U, R, CV = self.U, self.R, self.CV
        sums = np.zeros(7)
        sums[5] = self._load_energy()
        sums[6] = self._roundoff(U)
        sums[0] = self.V @ MV
        if KU is not None:
            sums[1] = U @ KU
            force_work = 0.0
        elif KU_rest is None:
            self.alg.mult(self.ops.K, U, self.work)
            sums[1] = U @ self.work
            force_work = 0.0
        else:
            sums[1] = -(U @ KU_rest)
            if self.loaded:
                sums[1] += U @ R
            if CV is not None:
                sums[1] -= U @ CV
        if self.track_du:
            du = np.subtract(U, self.U_prev, out=self.work)
            if self.loaded:
                sums[2] = (w_prev + w_new) * (du @ R) if self.R_prev is R else \
                    w_prev * (du @ self.R_prev) + w_new * (du @ R)
            if CV is not None:
                sums[3] = w_prev * (du @ self.CV_prev) + w_new * (du @ CV)
        if scheme_weight:
            sums[4] = self.A @ self.MA
        self.alg.allsum(sums)
        energy.kinetic, energy.strain = 0.5 * sums[0], 0.5 * (sums[1] - force_work)
        energy.external_work += sums[2]
        energy.damping_loss += sums[3]
        energy.scheme = scheme_weight * sums[4]
        energy.load_scale = sums[5] + self._static_load_energy(t1)
        energy.roundoff = EPS * sums[6] + self._start_roundoff

    def _initial_state(self, U0, V0, t0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """U, V from (U0, V0); R(t0); the free initial acceleration ``M A = R - K U - C V``; (P U, P V, P A)."""
        ops = self.ops
        self.t0 = t0
        self._open_args = None   # (open_steps' constants: formed again for this start)
        self.U[:] = owned_values(U0)
        self.V[:] = owned_values(V0)
        ops.load.evaluate(t0, self.R)
        self._track_work()
        move = ops.equilibrate_massless(self.U, self.R)   # (collective: every rank calls it)
        if move:
            log.info("mass redistribution: the massless contact nodes start in static equilibrium "
                     "(moved by up to %.3g)", move)
        self._free_acceleration(self.U, self.V, self.solve_M, self.A, massless_at_rest=True)
        if ops.p:
            return tuple(ops.project_many(self.U, self.V, self.A))
        return (np.zeros(0),) * 3

    def _initial_contacts(self, pu, pv, pa, energy: EnergyBudget):
        """Closed contacts at t0: the static part's forces, Carnot's correction and the force that
        keeps them closed. Returns (force, impulse, P U, P V)."""
        ops, static, p, t0 = self.ops, self.ops.static, self.ops.p, self.t0
        force = np.zeros(p)
        if static:  # forces of the compliant rows that the initial state already loads
            c = ~static.rigid_rows
            force[c] = compliant_forces(static.compliance[c][:, c], (ops.gap0(t0) - static.offset(t0) - pu)[c])
            if force.any():
                self.H.subtract_from(self.A, force)
                pa = pa - self.D @ force
            pu = pu + static.offset(t0) - static.compliance @ force
        closed = self._closed(pu, force, t0)
        if not np.count_nonzero(closed):   # (nothing to correct: D and H are not needed)
            return force, np.zeros(p), pu, pv
        rel = ops.relative(pv, t0)   # (Newton's law on the velocity relative to the obstacle)
        res = impact_correction(self.carnot, closed, np.zeros(p), rel, rel, ops.relative_acceleration(pa, t0), force,
                                ops.restitution)
        pv = self._apply_corrections(res, pv, energy, t0)
        return res.force, res.lam1.copy(), pu, pv

    def _track_work(self) -> None:
        """Work terms only where there is a load (R at the state's time, or one that varies) or damping
        (collective: every rank calls it)."""
        ops = self.ops
        self.loaded = ops.load.time_dependent or bool(self.alg.allsum(np.array([float(np.any(self.R))]))[0])
        self.track_du = self.loaded or ops.C is not None

    def restored(self) -> StepState:
        """The state restored from a checkpoint, to go on from (fem_impact/app/checkpoint/), under the
        case's load (collective)."""
        self._track_work()
        return self.state

    # -- many steps at a time between contacts (blocks.py, docs/theory.md s. 8.8) ---------------
    def open_step(self):
        """What the scheme's step without contact is (a ``blocks.OpenStep``), where the system allows
        taking such steps in blocks (replicated, diagonal operators: the reduced model); None for a
        scheme that cannot."""
        return None

    def block_ready(self, state: StepState) -> bool:
        """Whether the step after ``state`` is the step without contact when no row acts in it: no
        contact force of ``state`` enters it (a scheme that books the previous force, as the first
        half of a trapezoidal impulse, says no while one is left)."""
        return not np.count_nonzero(state.force)

    def resume(self, state: StepState, carry: dict) -> None:
        """Continue from ``state``, the last step of a block (blocks.py), as the step itself would
        have left it: the state vectors, what the next step reads of them (M V, M A, C V, R), and
        (in a scheme's own ``resume``) ``carry``, what the scheme's ``open_steps`` said it carries."""
        ops, alg = self.ops, self.alg
        np.copyto(self.U, state.U)
        np.copyto(self.V, state.V)
        np.copyto(self.A, state.A)
        alg.mult(ops.M, self.V, self.MV)
        alg.mult(ops.M, self.A, self.MA)
        if ops.C is not None:
            alg.mult(ops.C, self.V, self.CV)
        if ops.load.time_dependent:   # (the block's R(t), as the load's evaluate gives it)
            np.copyto(self.R, carry["R"])
        state.U, state.V, state.A = self.U, self.V, self.A   # (observers read the integrator's own arrays)
        self.state = state

    def _resume_rows(self, pu_dyn: np.ndarray, pv: np.ndarray) -> None:
        """The resumed state's contact rows from P U and P V of the kept modes as the step forms them
        (the static part's offset at its time added; no force)."""
        st, static = self.state, self.ops.static
        pu = pu_dyn + static.offset(st.t) - static.compliance.dot(st.force) if static is not None else pu_dyn
        st.normal_displacement, st.normal_velocity, st.gap = pu, pv, self.ops.gap0(st.t) - pu

    def start(self, U0, V0, t0: float = 0.0) -> StepState:
        """Initial acceleration from the equation of motion; closed contacts get their impulse and force."""
        ops = self.ops
        pu, pv, pa = self._initial_state(U0, V0, t0)
        energy = EnergyBudget()
        force, impulse = np.zeros(ops.p), np.zeros(ops.p)
        if ops.p:
            force, impulse, pu, pv = self._initial_contacts(pu, pv, pa, energy)
        energy.kinetic, energy.strain = self._quadratic_energies()
        energy.load_scale = self._start_load_scale
        energy.roundoff = self._start_roundoff
        gap = ops.gap0(t0) - pu
        self._book_stops(energy, (force, gap), (force, gap))
        if ops.static:
            energy.strain += ops.static.energy(t0, force)
        energy.initial = energy.total + energy.impact_loss - energy.external_work   # (before the correction)
        self.state = StepState(step=0, t=t0, U=self.U, V=self.V, A=self.A, gap=gap, force=force,
                               impulse=impulse, energy=energy, normal_displacement=pu, normal_velocity=pv)
        return self.state
