"""Scenes that mix rigid and elastic bodies (docs/theory.md s. 12.5): one Moreau-Jean step for both.

The unknowns of a step are the elastic bodies' nodal velocities ``V_e`` and the rigid bodies'
generalized velocities ``nu``; a contact row sees ``P_e V_e + H nu`` (``P_e``: P on the elastic
dofs, ``H = P B(q)`` on the rigid ones), so the step's impulses ``r`` solve one problem in

    W = P_e S^-1 P_e^T + H M_r^-1 H^T,

the elastic bodies' Delassus matrix (their theta-method's step matrix S, constant) beside the rigid
bodies' (changing as they turn), with Newton's law at the velocity level and Coulomb's cone on the
rows' total velocities. Then ``V_e1 = V_e* - S^-1 P_e^T r`` and ``nu1 = nu* - M_r^-1 H^T r``: each
part takes its share of the same impulses, so momentum passes between them exactly.

The elastic part is Moreau-Jean itself (theta = 1/2, the velocity level) on the model with the
rigid bodies' dofs held out (``ElasticPart``); the rigid part is ``RigidMoreauJean``'s step in its
three pieces. The energy budget is the sum of the two parts': the impulses' work on each part's
share of the rows' mean velocity, the obstacles' work booked once (by the elastic part).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..integrators.moreau_jean import MoreauJean
from ..integrators.scheme import ContactScheme
from ..integrators.state import StepState
from ..mechanics.energy import EnergyBudget
from .bodies import RigidBodies
from .scheme import RigidMoreauJean

SHARED = "shared with the rigid bodies"   # ElasticPart.friction: its rows' cone problem is the mixed step's


@dataclass
class ElasticShare:
    """The elastic bodies' share of a step's rows ([P; P_T] with friction): their velocities at the
    step's start and without the step's impulses, and their Delassus matrix ``P_e S^-1 P_e^T``. A modal
    body's static part makes rows compliant: ``position`` marks them (they take the gap condition at the
    step's end), ``compliance`` is its C (p x p; with friction over [P; P_T], (p + pt)^2), ``force0`` the
    rows' forces at the step's start and ``moved`` its offsets' change over the step (p, or p + pt),
    ``sliding`` the tangent rows it makes compliant, whose law acts on their whole slip (docs/theory.md
    s. 12.6)."""

    start: np.ndarray
    free: np.ndarray
    W: np.ndarray
    position: np.ndarray | None = None
    compliance: np.ndarray | None = None
    force0: np.ndarray | None = None
    moved: np.ndarray | None = None
    sliding: np.ndarray | None = None


class ElasticPart(MoreauJean):
    """The elastic bodies of a mixed scene: Moreau-Jean (theta = 1/2, velocity level) on the model
    with the rigid bodies' dofs held, whose contact rows the rigid bodies share. Its step asks
    ``share(free)`` (set by ``MixedMoreauJean``) for the impulses, given its rows' free velocities."""

    __checkpoint__ = ContactScheme.__checkpoint__ + ("KU", "KV", "_pu_dyn")

    def __init__(self, ops, dt: float):
        self.share = None
        super().__init__(ops, dt, theta=0.5, level="velocity")
        if not ops.pt:
            self.W_all = np.asarray(self.W.toarray() if hasattr(self.W, "toarray") else self.W)

    def _build_friction(self) -> None:
        """[P; P_T] and their W, G; the cone problem itself is the mixed step's (W changes with the
        rigid bodies' rotations)."""
        ops = self.ops
        self.rows = ops.with_tangents()
        self.W_all, self.G_all = self.rows.delassus(self.solve_S)
        self.friction = SHARED
        self.r_prev, self._persists, self._r_t, self.compliance = None, None, np.zeros(ops.pt), None
        static = ops.static   # (a modal body's static part on the tangent rows too: their law on the whole slip)
        self._soft_t = ~static.rigid_rows[ops.tangent_of] if static is not None and static.tangents else None
        self.friction_residual, self.friction_sweeps, self.friction_retries = 0.0, 0, 0

    def start_rates(self) -> np.ndarray:
        """The rows' velocities from the elastic bodies at the state's time ([P; P_T] V_e)."""
        st = self.state
        return st.normal_velocity if not self.ops.pt else np.concatenate([st.normal_velocity,
                                                                         st.tangential_velocity])

    def _impulse(self, st: StepState, pv_free: np.ndarray, t1: float) -> np.ndarray:
        return self.share(pv_free)

    def _frictional_impulse(self, st: StepState, t1: float, rhs: np.ndarray):
        p, V = self.ops.p, self.V
        free = self.rows.project_many(V)[0]
        r = self.share(free)
        self._r_t = r[p:]
        if not np.count_nonzero(r):
            return r[:p], r[p:], free[:p], free[p:], 0.0
        self.G_all.subtract_from(V, r)
        self.rows.subtract_transpose(rhs, r)   # the step's equation with the impulses, for K V1
        Wr = self.W_all @ r
        return r[:p], r[p:], free[:p] - Wr[:p], free[p:] - Wr[p:], float(np.abs(Wr[:p]).max())


def combined(elastic: EnergyBudget, rigid: EnergyBudget) -> EnergyBudget:
    """The scene's budget: each term the sum of the parts'."""
    out = elastic.copy()
    for term in dataclasses.fields(EnergyBudget):
        if term.name != "losses":
            setattr(out, term.name, getattr(elastic, term.name) + getattr(rigid, term.name))
    for column, value in rigid.losses.items():
        out.losses[column] = out.losses.get(column, 0.0) + value
    return out


def _of_rigid_part(name: str) -> property:
    """An attribute of a mixed scene's integrator that is its rigid part's."""
    return property(lambda self: getattr(self.rigid, name), lambda self, value: setattr(self.rigid, name, value))


class MixedMoreauJean:
    """Moreau-Jean on a scene of rigid and elastic bodies (see the module's docstring); the integrator
    interface of the time loop. ``ops``: the scene's rows on every node; ``elastic_ops``: the model with
    the rigid bodies' dofs held and P on the elastic dofs alone."""

    name = "moreau_jean"
    scheme_energy = False
    unconditionally_stable = True
    takes_friction = True
    __checkpoint__ = ("t0", "U", "V", "A", "elastic", "rigid", "rigid_energy", "state", "static_before")

    def __init__(self, ops, elastic_ops, bodies: RigidBodies, dt: float, modal=None):
        """``modal``: the reduced model (fem/reduced.py) whose modal equations ``elastic_ops`` are (a modal
        body), or None (elastic bodies in full)."""
        self.ops, self.dt, self.alg = ops, dt, ops.algebra
        self.rigid = RigidMoreauJean(ops, bodies, dt)
        self.elastic = ElasticPart(elastic_ops, dt)
        self.elastic.share = self._share
        self.modal = modal
        self.static_before = None   # a modal body's static part: (t, force) of the last state, for its velocity
        new = self.alg.vector
        self.U, self.V, self.A = new(), new(), new()
        self.rigid_dofs = self.rigid.map.on
        self.t0 = 0.0
        self.state: StepState | None = None
        self.rigid_energy = EnergyBudget()
        self.timings = self.elastic.timings
        self._step = self._t1 = self._found = None

    # (the frictional solver's extremes over the run, and its last problem: the rigid part solves the scene's)
    friction_residual = _of_rigid_part("friction_residual")
    friction_sweeps = _of_rigid_part("friction_sweeps")
    friction_retries = _of_rigid_part("friction_retries")
    friction = _of_rigid_part("friction")

    def start(self, U0, V0, t0: float = 0.0) -> StepState:
        """The elastic bodies from (U0, V0) on their dofs; the rigid bodies at their meshes' places with
        the momentum and angular momentum of V0 on theirs."""
        self.t0 = t0
        on = self.rigid_dofs
        own = [np.array(x.array_r if hasattr(x, "array_r") else x, dtype=float) for x in (U0, V0)]
        for x in own:
            x[on] = 0.0
        if self.modal is not None:   # (its modal coordinates: Z0 = Y1^T M U0 on the body's own dofs)
            own = [self.modal.Z0, self.modal.Zdot0]
        self.elastic.start(*own, t0)
        st_r = self.rigid.start(U0, V0, t0)
        self.rigid_energy = st_r.energy.copy()
        self.state = self._state(0, t0, np.zeros(self.ops.p + self.ops.pt), self.rigid_energy)
        return self.state

    def restored(self) -> StepState:
        self.elastic.restored()
        self.rigid.restored()
        return self.state

    def open_step(self):
        return None

    def block_ready(self, state) -> bool:
        return False

    def step(self) -> StepState:
        st = self.state
        t1 = self.t0 + (st.step + 1) * self.dt
        self._step, self._t1, self._found = self.rigid.prepare(st), t1, None
        self.elastic.step()   # (its contact step calls _share: the scene's impulses)
        if self._found is None:   # (no contact rows: the rigid bodies fly alone)
            self._found = self.rigid.settle(st, self._step, t1)
        nu1, impulse_all = self._found
        energy = self.rigid_energy.copy()
        self.rigid.advance(st, self._step, nu1, impulse_all, t1, energy, obstacles=False)
        self.rigid_energy = energy
        self.state = self._state(st.step + 1, t1, impulse_all, energy)
        return self.state

    def _share(self, free: np.ndarray) -> np.ndarray:
        """The step's impulses on every row, given the elastic bodies' free velocities of the rows."""
        e = self.elastic
        elastic = ElasticShare(e.start_rates(), free, e.W_all)
        static = e.ops.static
        if static is not None and np.any(e.position_rows):
            elastic.position = e.position_rows
            if e._soft_t is None:
                elastic.compliance, elastic.force0 = e.lcp.compliance, e.state.force
                elastic.moved = static.offset(self._t1) - static.offset(self.state.t)
            else:   # (friction: the static part over [P; P_T])
                elastic.compliance, elastic.sliding = static.rows_compliance, e._soft_t
                elastic.force0 = np.concatenate([e.state.force, e.state.tangential])
                elastic.moved = static.rows_offset(self._t1) - static.rows_offset(self.state.t)
        self._found = self.rigid.settle(self.state, self._step, self._t1, elastic)
        return self._found[1] if self.ops.pt else self._found[1][:self.ops.p]

    def _modal_fields(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A modal body's nodal U, V, A now: ``Y1 Z`` plus its static part ``X_R c(t) - X_P F`` (massless: its
        velocity is its change over the last step, no acceleration; docs/theory.md s. 8.5)."""
        fields, st = self.modal.fields, self.elastic.state
        U, V, A = fields.Y1 @ st.U, fields.Y1 @ st.V, fields.Y1 @ st.A
        if fields.static is not None:
            part = lambda t, force: fields.XR @ fields.static.coefficients(t) - fields.XP @ force   # noqa: E731
            force = fields._force(st)   # (with friction [F_N, F_T])
            now = part(st.t, force)
            U += now
            if self.static_before is not None and self.static_before[0] < st.t:
                t0, force0 = self.static_before
                V += (now - part(t0, force0)) / (st.t - t0)
            self.static_before = (st.t, force.copy())
        return U, V, A

    def _state(self, step: int, t: float, impulse_all: np.ndarray, rigid_energy: EnergyBudget) -> StepState:
        """The scene's state: the parts' nodal fields summed (each is zero on the other's dofs), the rows
        from them, the budgets summed."""
        ops, p, pt, dt = self.ops, self.ops.p, self.ops.pt, self.dt
        e, r = self.elastic, self.rigid
        U_e, V_e, A_e = (e.U, e.V, e.A) if self.modal is None else self._modal_fields()
        np.add(U_e, r.U, out=self.U)
        np.add(V_e, r.V, out=self.V)
        np.add(A_e, r.A, out=self.A)
        pu, pv = (ops.project_many(self.U, self.V) if p else (np.zeros(0), np.zeros(0)))
        normal, tangent = impulse_all[:p], impulse_all[p:]
        state = StepState(step=step, t=t, U=self.U, V=self.V, A=self.A, gap=ops.gap0(t) - pu, force=normal / dt,
                          impulse=normal, energy=combined(e.state.energy, rigid_energy), normal_displacement=pu,
                          normal_velocity=pv)
        if pt:
            state.tangential = tangent / dt
            state.tangential_velocity = r._rows.project_many(self.V)[0][p:]
        state.bodies = r._body_values()
        return state
