"""Moreau-Jean for rigid bodies in large rotation (docs/theory.md s. 12), with the contact layer's rows.

Each body's generalized velocity ``nu = (v, omega)``; the generalized mass ``diag(m I, J)`` (J = R J0
R^T in 3D); the nodes' velocities ``V = B(q) nu`` (``NodalMap``), so a contact row's velocity is
``P V = H nu`` with ``H = P B(q)``. A step of length h, theta = 1/2:

- the free velocity: translation ``v* = v0 + h F / m`` (the loads' resultant, the nodal load R(t)
  at the mid-step time); rotation in 2D ``omega* = omega0 + h tau / J``; in 3D the implicit midpoint
  rule on Euler's equations in the body frame, ``J0 (W1 - W0) = h T - h W_m x J0 W_m``
  (``W_m = (W0 + W1)/2``), which keeps the kinetic energy of a free body exactly (a quadratic
  invariant), solved by fixed-point iteration to round-off;
- the impulses ``r`` at the velocity level (Newton's law on the rows whose gap, predicted to
  mid-step, is closed; Coulomb's cone on their tangent rows): one LCP, or the cone problem, in
  ``W = H M^-1 H^T``; ``nu1 = nu* - M^-1 H^T r`` (3D: the gyroscopic term taken again at the new
  mid-step velocity, and the impulses with it, until both settle);
- positions: ``x1 = x0 + h v_m``; the angle ``+ h omega_m`` (2D), or ``R1 = R0 cay(h W_m)`` (3D,
  orthogonal to round-off): the nodes at ``x + R X`` exactly, whatever the rotation.

The energy budget: ``Delta T = h F . nu_m - r . H nu_m`` exactly (theta = 1/2, the gyroscopic term
does no work at W_m): the loads' work ``h F . nu_m``, the impulses' work in the laws' and the
friction's loss columns on the motion relative to moving obstacles (the obstacles' own work in the
external work), as the elastic integrators book them.
"""

from __future__ import annotations

import numpy as np

from ..errors import ContactSolverError
from ..integrators.state import StepState
from ..mechanics.energy import EnergyBudget
from ..nonsmooth.friction import FrictionProblem
from ..nonsmooth.lcp import solve_lcp
from .bodies import NodalMap, RigidBodies, cayley, rotation_2d

AT_OBSTACLE = 1e-9    # of a body's size: a row this close to its obstacle counts as closed
GYRO_ITERATIONS = 50


class RigidMoreauJean:
    """Moreau-Jean on rigid bodies (see the module's docstring); the integrator interface of the time loop."""

    name = "moreau_jean"
    scheme_energy = False
    unconditionally_stable = True
    takes_friction = True
    __checkpoint__ = ("t0", "U", "V", "A", "xs", "rots", "angle", "nu", "state", "_r_prev", "friction_residual",
                      "friction_sweeps", "friction_retries")

    def __init__(self, ops, bodies: RigidBodies, dt: float):
        self.ops, self.bodies, self.dt = ops, bodies, dt
        self.alg = ops.algebra
        self.map = NodalMap(bodies)
        nb, dim, size = len(bodies.names), bodies.dim, bodies.size
        self.size = size
        new = self.alg.vector
        self.U, self.V, self.A, self.R = new(), new(), new(), new()
        self.x = bodies.centre.copy()                       # centres now (nb x dim)
        self.rot = np.tile(np.eye(dim), (nb, 1, 1))         # rotations now (nb x dim x dim)
        self.angle = np.zeros(nb)                           # 2D: the bodies' angles (not wrapped)
        self.nu = np.zeros(nb * size)                       # generalized velocities (3D: spins in the body frame)
        self.t0 = 0.0
        self.state: StepState | None = None
        self.timings: dict[str, float] = {}
        self.extent = max(float(np.abs(bodies.offset).max(initial=0.0)), 1e-300)
        self.friction = None       # the last step's frictional problem, and its impulses (the next one's start)
        self._r_prev = None
        self.friction_residual, self.friction_sweeps, self.friction_retries = 0.0, 0, 0
        self._rows = ops.with_tangents() if ops.pt else ops
        # (constant over the run: the inverse inertia in the body frame; the previous step's V)
        self._inverse_inertia = (1.0 / bodies.inertia if dim == 2 else np.linalg.inv(bodies.inertia))
        self._V_prev = new()

    # The centres (nb x dim) and rotations (nb x dim x dim), kept flat (a checkpoint's arrays are).
    @property
    def x(self) -> np.ndarray:
        return self.xs.reshape(-1, self.bodies.dim)

    @x.setter
    def x(self, value: np.ndarray) -> None:
        self.xs = np.ascontiguousarray(value, dtype=float).ravel()

    @property
    def rot(self) -> np.ndarray:
        dim = self.bodies.dim
        return self.rots.reshape(-1, dim, dim)

    @rot.setter
    def rot(self, value: np.ndarray) -> None:
        self.rots = np.ascontiguousarray(value, dtype=float).ravel()

    # -- generalized quantities ------------------------------------------------------------------
    def _split(self, nu: np.ndarray):
        nb, dim = len(self.bodies.names), self.bodies.dim
        blocks = nu.reshape(nb, self.size)
        return blocks[:, :dim], blocks[:, dim:]

    def _spatial_spins(self, spins: np.ndarray) -> np.ndarray:
        """The spins in global axes (3D: R W; 2D: the angle's rate itself)."""
        return spins if self.bodies.dim == 2 else np.einsum("bij,bj->bi", self.rot, spins)

    def _inverse_mass(self) -> np.ndarray:
        """``M^-1`` of the generalized velocities in global axes (block diagonal, nb * size square)."""
        b, dim, size = self.bodies, self.bodies.dim, self.size
        inv = np.zeros((len(b.names) * size,) * 2)
        for k in range(len(b.names)):
            s = k * size
            inv[s:s + dim, s:s + dim] = np.eye(dim) / b.mass[k]
            if dim == 2:
                inv[s + 2, s + 2] = self._inverse_inertia[k]
            else:
                R = self.rot[k]
                inv[s + 3:s + 6, s + 3:s + 6] = R @ self._inverse_inertia[k] @ R.T
        return inv

    def _global(self, nu: np.ndarray) -> np.ndarray:
        """``nu`` with its spins in global axes (what B and H take)."""
        v, w = self._split(nu)
        return np.concatenate([v, self._spatial_spins(w)], axis=1).ravel()

    def _kinetic(self, nu: np.ndarray) -> float:
        b = self.bodies
        v, w = self._split(nu)
        rot = 0.5 * np.sum(b.inertia * w[:, 0] ** 2) if b.dim == 2 else 0.5 * np.einsum("bi,bij,bj->", w, b.inertia, w)
        return float(0.5 * np.sum(b.mass[:, None] * v * v) + rot)

    def _loads(self, t: float) -> np.ndarray:
        """The loads' generalized force in global axes, ``B^T R(t)`` (resultant and moment about the centre)."""
        self.ops.load.evaluate(t, self.R)
        return self.alg.allsum(self._B.T @ self.R)

    def _nodal(self) -> None:
        """U and V of the nodes from the bodies' motion now."""
        v, w = self._split(self.nu)
        self.map.displacement(self.x, self.rot, self.U)
        self.map.velocity(v, self._spatial_spins(w), self.rot, self.V)

    # -- the time loop's interface ----------------------------------------------------------------
    def start(self, U0, V0, t0: float = 0.0) -> StepState:
        """The bodies at their meshes' places; their rigid velocities with the momentum and angular
        momentum of the initial velocity field."""
        self.t0 = t0
        V0 = np.asarray(V0.array_r if hasattr(V0, "array_r") else V0, dtype=float)
        self._B = self.map.columns(self.rot)
        given, M_V = self.alg.vector(), self.alg.vector()
        given[:] = V0
        self.alg.mult(self.ops.M, given, M_V)
        momenta = self.alg.allsum(self._B.T @ M_V)   # generalized momenta, global axes
        nu = np.zeros_like(momenta)
        b, dim, size = self.bodies, self.bodies.dim, self.size
        for k in range(len(b.names)):
            s = k * size
            nu[s:s + dim] = momenta[s:s + dim] / b.mass[k]
            nu[s + dim:s + size] = (momenta[s + 2] / b.inertia[k] if dim == 2
                                    else np.linalg.solve(b.inertia[k], momenta[s + 3:s + 6]))
        self.nu = nu
        self._nodal()
        self.A[:] = 0.0
        energy = EnergyBudget()
        energy.kinetic = self._kinetic(self.nu)
        energy.initial = energy.total
        ops = self.ops
        pu, pv = (ops.project_many(self.U, self.V) if ops.p else (np.zeros(0), np.zeros(0)))
        self.state = StepState(step=0, t=t0, U=self.U, V=self.V, A=self.A, gap=ops.gap0(t0) - pu,
                               force=np.zeros(ops.p), impulse=np.zeros(ops.p), energy=energy,
                               normal_displacement=pu, normal_velocity=pv)
        if ops.pt:
            self.state.tangential = np.zeros(ops.pt)
            self.state.tangential_velocity = self._rows.project_many(self.V)[0][ops.p:]
        self.state.bodies = self._body_values()
        return self.state

    def restored(self) -> StepState:
        self._B = self.map.columns(self.rot)
        return self.state

    def open_step(self):
        return None

    def block_ready(self, state) -> bool:
        return False

    def step(self) -> StepState:
        st = self.state
        t1 = self.t0 + (st.step + 1) * self.dt
        step = self.prepare(st)
        nu1, impulse_all = self.settle(st, step, t1)
        energy = st.energy.copy()
        self.advance(st, step, nu1, impulse_all, t1, energy)
        ops, p, pt = self.ops, self.ops.p, self.ops.pt
        normal, tangent = impulse_all[:p], impulse_all[p:]
        pu, pv = (ops.project_many(self.U, self.V) if p else (np.zeros(0), np.zeros(0)))
        self.state = StepState(step=st.step + 1, t=t1, U=self.U, V=self.V, A=self.A, gap=ops.gap0(t1) - pu,
                               force=normal / self.dt, impulse=normal, energy=energy, normal_displacement=pu,
                               normal_velocity=pv)
        if pt:
            self.state.tangential = tangent / self.dt
            self.state.tangential_velocity = self._rows.project_many(self.V)[0][p:]
        self.state.bodies = self._body_values()
        return self.state

    # -- a step in three parts (a mixed scene's step puts the elastic bodies' between them: mixed.py) ---
    def prepare(self, st: StepState) -> tuple:
        """What the step reads at its start: the loads' generalized force (global axes, at mid-step),
        the rows' ``H = P B`` ([P; P_T] with friction) and the inverse generalized mass."""
        self._B = self.map.columns(self.rot)   # B at the step's start (its rotations)
        force = self._loads(st.t + 0.5 * self.dt)
        H_all = self._rows.project(self._B) if self.ops.p else None   # rows x generalized velocities
        return force, H_all, self._inverse_mass()

    def settle(self, st: StepState, step: tuple, t1: float, elastic=None) -> tuple[np.ndarray, np.ndarray]:
        """The new generalized velocities and the step's impulses (normal rows, then tangent rows).
        ``elastic``: the elastic bodies' share of the rows (``ElasticShare``: their velocities at the
        step's start and without impulses, and their Delassus matrix), in a mixed scene."""
        b, dim = self.bodies, self.bodies.dim
        force, H_all, inv = step
        F = force.reshape(len(b.names), self.size)
        p = self.ops.p
        nu0 = self.nu
        impulse_all = np.zeros(p + self.ops.pt)
        nu1, settled = None, dim == 2
        for _ in range(GYRO_ITERATIONS if dim == 3 else 1):
            free = self._free(nu0, F, nu1)
            if p:
                impulse_all = self._impulses(st, H_all, inv, free, nu0, t1, elastic)
            change = (inv @ (H_all.T @ impulse_all)) if p and np.count_nonzero(impulse_all) else 0.0
            new = self._from_global(self._global(free) - change)
            moved = np.inf if nu1 is None else np.abs(new - nu1).max() / max(np.abs(new).max(), 1e-300)
            nu1 = new
            if moved <= 1e-15:
                settled = True
                break
        if not settled:
            self._check_settled(nu0, nu1, t1)
        return nu1, impulse_all

    def advance(self, st: StepState, step: tuple, nu1: np.ndarray, impulse_all: np.ndarray, t1: float,
                energy, obstacles: bool = True) -> None:
        """The bodies moved to t1 with ``nu1`` (positions from the mean velocity), their nodes' U, V, A,
        and the step's energy terms booked in ``energy``: the loads' work ``h F . nu_m``, the impulses'
        on the rows' mean velocity (the rigid bodies' share of it in a mixed scene, ``obstacles``
        False: the elastic part books the obstacles' work)."""
        ops, h, b = self.ops, self.dt, self.bodies
        dim, nb = b.dim, len(b.names)
        force, H_all, _ = step
        nu0 = self.nu
        # positions from the mean velocity (g_mid: it in global axes at the step's start, as B and H take it)
        numid = 0.5 * (nu0 + nu1)
        g_mid = self._global(numid)
        vm, wm = self._split(numid)
        self.x = self.x + h * vm
        if dim == 2:
            self.angle = self.angle + h * wm[:, 0]
            self.rot = np.array([rotation_2d(a) for a in self.angle])
        else:
            self.rot = np.array([self.rot[k] @ cayley(h * wm[k]) for k in range(nb)])
        np.copyto(self._V_prev, self.V)
        self.nu = nu1
        self._nodal()
        np.subtract(self.V, self._V_prev, out=self.A)
        self.A *= 1.0 / h
        energy.external_work += h * float(force @ g_mid)
        p, pt = ops.p, ops.pt
        normal, tangent = impulse_all[:p], impulse_all[p:]
        if p:
            rates = H_all @ g_mid
            moved = ops.obstacle_moved(st.t, t1) if obstacles else None
            obstacle = None if moved is None else moved / h
            for column, work in ops.laws.work(normal, rates[:p] - (0.0 if obstacle is None else obstacle)).items():
                energy.add_loss(column, work)
            if obstacle is not None:
                energy.external_work -= float(normal @ obstacle)
            if pt:
                slide = rates[p:]
                if ops.moving and obstacles:
                    along = 0.5 * (ops.obstacle_tangent_velocity(st.t) + ops.obstacle_tangent_velocity(t1))
                    energy.external_work -= float(tangent @ along)
                    slide = slide - along
                energy.friction_loss += float(tangent @ slide)
        energy.kinetic = self._kinetic(self.nu)

    def _body_values(self) -> np.ndarray:
        """Per body: centre, velocity, then 2D angle and its rate, 3D the spin in global axes."""
        v, w = self._split(self.nu)
        spin = np.column_stack([self.angle, w[:, 0]]) if self.bodies.dim == 2 else self._spatial_spins(w)
        return np.concatenate([self.x, v, spin], axis=1).ravel()

    # -- pieces of a step ------------------------------------------------------------------------
    def _free(self, nu0: np.ndarray, F: np.ndarray, nu1: np.ndarray | None) -> np.ndarray:
        """The velocity without impulses (spins: 2D global, 3D body frame); 3D: the gyroscopic term at the
        mid-step spin of ``nu1`` (the step's latest estimate; None: the free flight's own)."""
        b, h, dim = self.bodies, self.dt, self.bodies.dim
        v0, w0 = self._split(nu0)
        v = v0 + h * F[:, :dim] / b.mass[:, None]
        if dim == 2:
            w = w0 + h * F[:, 2:3] / b.inertia[:, None]
            return np.concatenate([v, w], axis=1).ravel()
        torque = np.einsum("bji,bj->bi", self.rot, F[:, 3:])   # body frame
        w = np.empty_like(w0)
        self._mid_spins = np.empty_like(w0)   # (the mid-step spins the gyroscopic term is taken at)
        for k in range(len(b.names)):
            J = b.inertia[k]
            if nu1 is None:   # the free flight: Euler's equations by fixed point at their own midpoint
                w1 = w0[k].copy()
                for _ in range(GYRO_ITERATIONS):
                    wm = self._mid_spins[k] = 0.5 * (w0[k] + w1)
                    nxt = w0[k] + np.linalg.solve(J, h * torque[k] - h * np.cross(wm, J @ wm))
                    if np.abs(nxt - w1).max() <= 1e-16 * max(np.abs(nxt).max(), 1e-300):
                        w1 = nxt
                        break
                    w1 = nxt
                w[k] = w1
            else:
                wm = self._mid_spins[k] = 0.5 * (w0[k] + self._split(nu1)[1][k])
                w[k] = w0[k] + np.linalg.solve(J, h * torque[k] - h * np.cross(wm, J @ wm))
        return np.concatenate([v, w], axis=1).ravel()

    def _check_settled(self, nu0: np.ndarray, nu1: np.ndarray, t1: float) -> None:
        """A 3D step whose spins did not settle (the impulses' active set may alternate between rounds): the
        gyroscopic term taken at the last round's mid-step spin does the work ``h W_m . (W_u x J0 W_u)``,
        which the budget does not book; below 1e-10 of the kinetic energy it is round-off, above it the
        step is refused rather than answered."""
        b, h = self.bodies, self.dt
        w_m = 0.5 * (self._split(nu0)[1] + self._split(nu1)[1])
        used = self._mid_spins
        work = abs(h * float(np.einsum("bi,bi->", w_m, np.cross(used, np.einsum("bij,bj->bi", b.inertia, used)))))
        scale = max(self._kinetic(nu0), self._kinetic(nu1), 1e-300)
        if work > 1e-10 * scale:
            from ..errors import SimulationError

            raise SimulationError(f"the rigid bodies' step at t = {t1:.6g} did not settle: the spins and the impulses "
                                  f"still change after {GYRO_ITERATIONS} rounds (the gyroscopic term would do "
                                  f"{work / scale:.3g} of the kinetic energy in work); a smaller solver.dt will")

    def _from_global(self, g: np.ndarray) -> np.ndarray:
        """Generalized velocities with global spins back to the state's (3D: body-frame spins)."""
        if self.bodies.dim == 2:
            return g
        nb, size = len(self.bodies.names), self.size
        blocks = g.reshape(nb, size).copy()
        blocks[:, 3:] = np.einsum("bji,bj->bi", self.rot, blocks[:, 3:])
        return blocks.ravel()

    def _impulses(self, st: StepState, H: np.ndarray, inv: np.ndarray, free: np.ndarray, nu0: np.ndarray,
                  t1: float, elastic=None) -> np.ndarray:
        """The step's impulses (normal, then tangent rows): Newton's law at the velocity level on the rows
        whose gap, predicted to mid-step, is closed; Coulomb's cone on their tangent rows. ``elastic``:
        the elastic bodies' share of the rows' velocities and of W (a mixed scene)."""
        ops, h, p, pt = self.ops, self.dt, self.ops.p, self.ops.pt
        g_free, g0 = self._global(free), self._global(nu0)
        rates_free, rates0 = H @ g_free, H @ g0
        if elastic is not None:
            rates_free, rates0 = rates_free + elastic.free, rates0 + elastic.start
        rel0 = ops.relative(rates0[:p], st.t)
        e = np.where(rel0 >= 0.0, ops.restitution, 1.0)
        q = -ops.relative(rates_free[:p], t1) - e * rel0
        active = st.gap - 0.5 * h * rel0 <= AT_OBSTACLE * self.extent
        compliant = elastic is not None and elastic.position is not None
        if compliant:
            # A modal body's compliant rows take the gap at the step's end, g1 = g_free + (h/2) W r + C r / h
            # >= 0 (C: its static part's compliance, lam = r / h), divided by h/2 as the velocity rows are:
            # the gap at the start (its static part's C lam0 in it) moved by the obstacles, by both parts'
            # mean free velocity and by the static part's offset (docs/theory.md s. 12.6).
            position = elastic.position
            static0 = elastic.moved + elastic.compliance @ elastic.force0   # (p, or p + pt with friction)
            g_free = (st.gap + (ops.gap0(t1) - ops.gap0(st.t)) - 0.5 * h * (rates0[:p] + rates_free[:p])
                      - static0[:p])
            q = np.where(position, g_free / (0.5 * h), q)
            active = active | position
        out = np.zeros(p + pt)
        if not np.count_nonzero(active):
            return out
        W = H @ inv @ H.T
        if elastic is not None:
            W = W + elastic.W
        if compliant:
            n = elastic.compliance.shape[0]
            W[:n, :n] += elastic.compliance / (0.5 * h * h)
        if not pt:
            a = np.flatnonzero(active)
            out[a] = solve_lcp(W[np.ix_(a, a)], q[a])[0]
            return out
        q_t = -ops.relative_tangent(rates_free[p:], t1)
        if compliant and elastic.sliding is not None:
            # A compliant tangent row: Coulomb's law on its whole slip over the step (the kept modes' and the
            # rigid part's mean velocity, and the static part's change, C_T lam1 of it in W), divided by h/2.
            slip = ops.relative_tangent(rates0[p:], st.t) + ops.relative_tangent(rates_free[p:], t1)
            q_t = np.where(elastic.sliding, -slip - static0[p:] / (0.5 * h), q_t)
        # (W changes as the bodies turn: the problem is built each step, warm-started from the last impulses)
        self.friction = FrictionProblem(W.copy(), ops.tangent_of, ops.friction, newton_first=elastic is not None)
        sol = self.friction.solve(np.concatenate([q, q_t]), active, guess=self._r_prev)
        self.friction_residual = max(self.friction_residual, sol.residual)
        self.friction_sweeps = max(self.friction_sweeps, sol.sweeps)
        self.friction_retries += sol.newton
        if not sol.converged:
            raise ContactSolverError(f"the frictional contact problem of the rigid bodies was not solved at t = "
                                     f"{t1:.6g}: residual {sol.residual:.3g} after {sol.sweeps} sweeps")
        self._r_prev = sol.r
        return sol.r
