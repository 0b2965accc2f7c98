"""The reduced model's steps between contacts, many at a time (docs/theory.md s. 8.8).

On a replicated system with diagonal ``M``, ``C`` and ``K`` (the reduced model: ``M = I``, ``K =
diag(w^2)``, ``C = diag(alpha + beta w^2)``) a step of Moreau-Jean or Newmark in which no contact
row acts is a fixed affine map of the state, dof by dof, driven by the load at the step's ends:
no contact problem, no solve, nothing that couples the dofs. From a state the integrator reached,
:class:`BlockStepper`

1. evaluates the load's time functions on a block of step times at once (numpy);
2. runs the scheme's step without contact through the block: a compiled loop (kernels.py) that
   performs the integrator's own operations in its order, so the states are its own to the bit;
3. keeps the steps before the first one where a contact row might act: its gap at the step's
   end (and, for rows that Moreau-Jean's velocity level decides at a step's start, the gap
   predicted to mid-step) within ``SAFETY`` of the magnitudes it is made of;
4. books each kept step's energy budget as the scheme does (``_step_energies``, ``_book_stored``
   with the contact terms zero), with numpy over the block.

The step that may close, and every step of a contact, goes through the integrator itself, which
resumes from the block's last state (``resume``); except where the scheme compiles its steps with
impulses too (``contact_step``: Moreau-Jean on rows that are all compliant, docs/theory.md s. 8.8):
those blocks run through the contact, the impulses' terms added to the budget. The kept steps come as
a :class:`StepBlock`:
what a ``StepState`` holds, as arrays over the steps; observers that accept a block
(``write_block``) read it at once, others get its ``StepState``s one by one (``integrate``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from functools import cached_property

import numpy as np

from ..nonsmooth.lcp import TINY
from ..mechanics.energy import EnergyBudget
from .state import StepState

SAFETY = 1e-9          # a gap counts as open above this fraction of the magnitudes it is made of
# solver.blocks: auto takes blocks from this many steps on: loading Numba and the compiled steps costs
# a fixed time a run (more the first time, compiling), which the steps in blocks then save.
AUTO_FROM = 4000
MIN_BLOCK = 32         # steps: the first block's length, and the shortest one tried
MAX_BLOCK = 4096       # steps: the longest block (memory: a few arrays of MAX_BLOCK x n)
_ENERGY = [f.name for f in fields(EnergyBudget) if f.name != "losses"]   # (the laws' columns: constant in a block)
# StepBlock's fields that only some scenes' steps carry (friction, rigid bodies): StepState's of the same names
_OPTIONAL = ("tangential", "tangential_velocity", "bodies", "sliding")


@dataclass
class OpenStep:
    """What a scheme's step without contact is on a diagonal system (``open_step()`` of an
    integrator): the diagonals of M, K and C (or None), the weight of the step's end in its work
    terms (theta, gamma: a force f works ``Delta U . ((1 - weight) f0 + weight f1)`` over a
    step), and the contact rows whose activity the scheme decides at a step's start from the gap
    predicted to mid-step (Moreau-Jean's velocity level; every other row acts only when its gap
    at the step's end closes)."""

    mass: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray | None
    weight: float
    predicted_rows: np.ndarray
    # the scheme's own dissipation that its budget books, this times dV.M dV + dU.K dU a step
    # (Moreau-Jean: theta - 1/2, EnergyBudget.numerical_loss); 0: none booked
    dissipation: float = 0.0
    # the weight of the step's end in the loads' work on a static part (None: ``weight``; Moreau-Jean: 1/2)
    static_weight: float | None = None


@dataclass
class OpenSteps:
    """A scheme's steps without contact from its state (``open_steps(loads)``), per step: U, V, A
    (L x n); ``MV`` (L x n), the M V its budget books the kinetic energy with; ``UKU`` (L), U^T K U
    as its budget books the strain energy; ``PU``, ``PV`` (L x p), P U and P V of the kept modes as
    its step reports them; ``carry``: what it carries to its next step (name -> L x n), read by
    its ``resume``."""

    U: np.ndarray
    V: np.ndarray
    A: np.ndarray
    MV: np.ndarray
    UKU: np.ndarray
    PU: np.ndarray
    PV: np.ndarray
    carry: dict = field(default_factory=dict)

    def head(self, k: int) -> OpenSteps:
        return OpenSteps(self.U[:k], self.V[:k], self.A[:k], self.MV[:k], self.UKU[:k], self.PU[:k], self.PV[:k],
                         {name: value[:k] for name, value in self.carry.items()})


def diagonal(ops) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
    """``(m, k, c)`` when ``ops`` is a replicated system with diagonal M, K (and C), else None."""
    if ops.algebra.distributed or ops.massless.size:
        return None
    M, K, C = ops.M, ops.K, ops.C
    if not (isinstance(M, np.ndarray) and isinstance(K, np.ndarray) and M.ndim == 1 and K.ndim == 1):
        return None
    if C is not None and not (isinstance(C, np.ndarray) and C.ndim == 1):
        return None
    return M, K, C


def compiled() -> bool:
    """Whether the compiled steps load (Numba installed); loads them now, not in the time loop."""
    try:
        from . import kernels
    except ImportError:
        return False
    kernels.warm_up()
    return True


@dataclass
class BlockEnergy(EnergyBudget):
    """An ``EnergyBudget`` whose terms are arrays over a block's steps; ``total`` and ``error``
    (EnergyBudget's, the same operations on each step) computed once. A term given as a number
    (one not given: its default) is that number at every step."""

    def __post_init__(self):
        size = np.shape(self.kinetic)
        for name in _ENERGY:
            if np.ndim(getattr(self, name)) == 0:
                setattr(self, name, np.full(size, float(getattr(self, name))))

    @cached_property
    def total(self) -> np.ndarray:
        return EnergyBudget.total.fget(self)

    @cached_property
    def error(self) -> np.ndarray:
        return EnergyBudget.error.fget(self)


@dataclass
class StepBlock:
    """Consecutive steps without contact impulse, as arrays over the steps (first axis).

    The fields are those of ``StepState``: ``U``, ``V``, ``A`` (L x n), ``gap``, ``force``,
    ``impulse``, ``normal_displacement``, ``normal_velocity`` (L x p), ``energy`` (an
    ``EnergyBudget`` whose every term is an array of L values); ``previous`` is the state
    before the block's first step, ``coefficients`` the static part's load coefficients at each
    step (L x nl, or None without a static part), ``carry`` what the integrator carries from
    each step to the next (its ``resume``).
    """

    step: np.ndarray
    t: np.ndarray
    U: np.ndarray
    V: np.ndarray
    A: np.ndarray
    gap: np.ndarray
    force: np.ndarray
    impulse: np.ndarray
    energy: EnergyBudget
    normal_displacement: np.ndarray
    normal_velocity: np.ndarray
    previous: StepState
    coefficients: np.ndarray | None = None
    carry: dict = field(default_factory=dict)
    tangential: np.ndarray | None = None
    tangential_velocity: np.ndarray | None = None
    bodies: np.ndarray | None = None
    sliding: np.ndarray | None = None

    def __len__(self) -> int:
        return self.t.size

    def head(self, k: int) -> StepBlock:
        """The block's first k steps."""
        cut = {name: getattr(self, name)[:k] for name in ("step", "t", "U", "V", "A", "gap", "force", "impulse",
                                                          "normal_displacement", "normal_velocity")}
        energy = BlockEnergy(**{name: getattr(self.energy, name)[:k] for name in _ENERGY}, losses=self.energy.losses)
        cut.update({name: None if getattr(self, name) is None else getattr(self, name)[:k]
                    for name in ("coefficients", *_OPTIONAL)})
        return StepBlock(**cut, energy=energy, previous=self.previous,
                         carry={name: value[:k] for name, value in self.carry.items()})

    def state(self, j: int) -> StepState:
        """Step j of the block as a ``StepState`` (its arrays: views of the block's)."""
        energy = EnergyBudget(**{name: float(getattr(self.energy, name)[j]) for name in _ENERGY},
                              losses=dict(self.energy.losses))
        return StepState(step=int(self.step[j]), t=float(self.t[j]), U=self.U[j], V=self.V[j], A=self.A[j],
                         gap=self.gap[j], force=self.force[j], impulse=self.impulse[j], energy=energy,
                         normal_displacement=self.normal_displacement[j],
                         normal_velocity=self.normal_velocity[j],
                         **{name: None if getattr(self, name) is None else getattr(self, name)[j]
                            for name in _OPTIONAL})

    def states(self):
        """The steps one by one, as ``StepState``s."""
        return (self.state(j) for j in range(len(self)))


class BlockStepper:
    """An integrator's steps between contacts, many at a time (module docstring).

    ``advance(limit)`` gives the next block of at most ``limit`` steps from the integrator's
    state, or None when the next step may involve a contact (take it with
    ``integrator.step()``); ``commit(block)`` (or of its head) hands the block's last state to the
    integrator. ``steps`` and ``blocks`` count what was done in blocks.
    """

    def __init__(self, integrator, open_step: OpenStep):
        self.integrator, self.open_step = integrator, open_step
        ops = integrator.ops
        self.ops, self.static = ops, ops.static
        self.abs_Pt = np.abs(ops.P_local.toarray())   # |P^T| (n x p), dense: a few modes and rows
        self.abs_d0 = np.abs(ops.d0)
        self.predicted = open_step.predicted_rows if np.count_nonzero(open_step.predicted_rows) else None
        self.steps = 0
        self.blocks = 0
        self.length = MIN_BLOCK   # the next block's length: twice the last open phase's (or block's)
        self._closing = False     # the last block stopped before a step where a row may act
        self._phase = 0           # steps of the open phase the last block ended (in blocks since a single step)
        self._end = -1            # the last block's last step
        self._single = False      # the next step is the integrator's own (a load not finite, an LCP it solves)
        self.contact = bool(getattr(integrator, "contact_step", lambda: False)())   # steps with impulses compiled
        self.contact_length = MIN_BLOCK

    @classmethod
    def of(cls, integrator) -> BlockStepper | None:
        """A stepper for ``integrator``, or None when its steps cannot be taken in blocks: a
        finite-element model, friction, dense operators, a wrapper (moving supports), no Numba."""
        method = getattr(type(integrator), "open_step", None)   # (the class's own, not a wrapper's delegate)
        open_step = method(integrator) if method is not None else None
        if open_step is None or not compiled():
            return None
        ops = integrator.ops
        if ops.load.time_dependent and not hasattr(ops.load, "evaluate_block"):
            return None
        if ops.static is not None and not hasattr(ops.static, "coefficients_block"):
            return None
        return cls(integrator, open_step)

    def advance(self, limit: int) -> StepBlock | None:
        """Up to ``limit`` steps from the integrator's state, stopped before the first step in which a
        contact row may act (or, on a scheme with compiled contact steps, through the contact: steps
        with impulses); None when the next step is the integrator's own."""
        it, ops, static = self.integrator, self.ops, self.static
        st = it.state
        closing, single = self._closing, self._single
        self._closing = self._single = False
        if single or limit <= 0 or (closing and not self.contact):
            return None
        open_ok = not closing and it.block_ready(st)
        if not (open_ok or self.contact):
            return None
        size = min(limit, self.length if open_ok else self.contact_length)
        t = it.t0 + np.arange(st.step + 1, st.step + size + 1) * it.dt   # (the integrators' own t1)
        loads = np.empty((size + 1, it.R.size))
        loads[0] = it.R
        finite = np.ones(size, dtype=bool)
        if ops.load.time_dependent:
            loads[1:] = ops.load.evaluate_block(t)
            finite &= np.isfinite(loads[1:]).all(axis=1)
        else:
            loads[1:] = it.R
        coefficients = None
        if static is not None:
            coefficients = static.coefficients_block(np.concatenate(([st.t], t)))
            finite &= np.isfinite(coefficients[1:]).all(axis=1)
        if not finite.all():   # a load no longer finite: the single step there stops the run with its name
            size = int(np.argmin(finite))
            if not size:
                return None
            self._single = True
            t, loads = t[:size], loads[:size + 1]
            coefficients = coefficients[:size + 1] if coefficients is not None else None
        pu_static = None if static is None else static.offsets_for(coefficients[1:])
        if open_ok:
            steps = it.open_steps(loads)
            pu = steps.PU if static is None else steps.PU + pu_static
            keep = self._open_count(st, t, steps, pu)
            phase = keep + (self._phase if st.step == self._end else 0)   # the open phase's steps so far
            self.length = min(MAX_BLOCK, max(MIN_BLOCK, 2 * (phase if keep < size else size)))
            if keep:
                if keep < size:   # (the step after the block may close: the next call does not try again)
                    self._closing = True
                return self._block(st, t[:keep], steps.head(keep), pu[:keep], loads[:keep + 1],
                                   coefficients[:keep + 1] if coefficients is not None else None)
            if not self.contact:
                return None
        # Steps with impulses, compiled (moreau_jean.contact_steps): the rows' gaps less the static offsets
        gaps = self._gaps(t)[0]
        taken, steps, impulse = it.contact_steps(loads, gaps - pu_static if static is not None else
                                                 np.broadcast_to(gaps, (t.size, ops.p)))
        self.contact_length = min(MAX_BLOCK, max(MIN_BLOCK, 2 * taken))
        if taken < t.size:
            self._single = True   # (the step the compiled one could not take)
        if not taken:
            return None
        pu = steps.PU
        if static is not None:
            pu = pu + pu_static[:taken] - (impulse / it.dt) @ static.compliance.T
        return self._block(st, t[:taken], steps, pu, loads[:taken + 1],
                           coefficients[:taken + 1] if coefficients is not None else None, impulse)

    def _open_count(self, st: StepState, t, steps: OpenSteps, pu) -> int:
        """How many of the block's first steps no contact row can act in (module docstring); ``pu``:
        P U after each step (L x p)."""
        ops = self.ops
        if not ops.p:
            return t.size
        d, abs_d = self._gaps(t)
        scale = np.abs(steps.U) @ self.abs_Pt   # |P| |U| + |d| + |offset| >= what P U and d are made of
        scale += abs_d
        scale += np.abs(pu - steps.PU)
        gap = d - pu
        ok = gap > SAFETY * scale + TINY
        if self.predicted is not None:   # rows decided at a step's start: the gap predicted to mid-step
            rows = self.predicted
            pv = steps.PV[:, rows]
            if ops.moving:   # (velocities relative to the obstacles, at each step's start)
                pv = pv - np.array([ops.d_rate(tj) for tj in t])[:, rows]
            gap0 = np.concatenate((st.gap[None, rows], gap[:-1, rows]))
            pv0 = np.concatenate((ops.relative(st.normal_velocity, st.t)[None, rows], pv[:-1]))
            abs_d0 = self.abs_d0 if d is ops.d0 else np.abs(ops.gap0(st.t))
            scale0 = np.concatenate(((abs_d0 + np.abs(st.normal_displacement))[None, rows], scale[:-1, rows]))
            ok[:, rows] &= gap0 - 0.5 * self.integrator.dt * pv0 > SAFETY * scale0 + TINY
        good = ok.all(axis=1)
        return t.size if good.all() else int(np.argmin(good))

    def _gaps(self, t) -> tuple[np.ndarray, np.ndarray]:
        """The obstacles' positions ``d`` at the steps' times ``t`` (L x p) and ``|d|``; ``d0`` itself
        (and its kept ``|d0|``) while no obstacle moves."""
        ops = self.ops
        if not ops.moving:
            return ops.d0, self.abs_d0
        d = np.array([ops.gap0(tj) for tj in t])
        return d, np.abs(d)

    def _block(self, st: StepState, t, steps: OpenSteps, pu, loads, coefficients,
               impulse: np.ndarray | None = None) -> StepBlock:
        """The StepBlock of the kept steps: contact rows and the energy budget of each step (``impulse``:
        the steps' impulses, L x p, on rows a static part makes compliant; None: steps without contact)."""
        it, ops, static = self.integrator, self.ops, self.static
        w, size, p = self.open_step.weight, t.size, ops.p
        U, V = steps.U, steps.V
        zeros = np.zeros((size, p))
        force = zeros if impulse is None else impulse / it.dt
        force0 = None if impulse is None else np.concatenate((st.force[None], force[:-1]))

        # The budget as _step_energies and _book_stored book it, with the contact terms zero.
        e0 = st.energy
        du = U - np.concatenate((it.U[None], U[:-1]))
        kinetic = 0.5 * _rows_dot(V, steps.MV)
        strain = 0.5 * steps.UKU
        work, load_scale = np.zeros(size), np.zeros(size)
        if it.loaded:
            if ops.load.time_dependent:
                work = (1.0 - w) * _rows_dot(du, loads[:-1]) + w * _rows_dot(du, loads[1:])
            else:
                work = ((1.0 - w) + w) * (du @ it.R)
            load_scale = np.einsum("ji,ji,i->j", loads[1:], loads[1:], it._load_weights)
        damping = None
        if self.open_step.damping is not None:
            CV = V * self.open_step.damping
            damping = (1.0 - w) * _rows_dot(du, np.concatenate((it.CV[None], CV[:-1]))) + w * _rows_dot(du, CV)
        static_work = contact_loss = None
        if static is not None:
            strain += static.energies_for(coefficients[1:], None if impulse is None else force)
            static_work = static.works_for(coefficients[:-1], coefficients[1:],
                                           w if self.open_step.static_weight is None else self.open_step.static_weight,
                                           *((None, None) if impulse is None else (force0, force)))
            if it.loaded:
                load_scale += static.energies_for(coefficients[1:])
        pv0 = np.concatenate((st.normal_velocity[None], steps.PV[:-1])) if impulse is not None else None
        if impulse is not None:   # the impulses' work with the steps' mean velocities, the static part's share,
            stops = None          # and what the stops' springs store (1/2 c F^2) moved to the strain energy
            if it._elastic_stops:
                stored = np.concatenate(([st.force @ (st.force * ops.laws.compliance)],
                                         (force * force) @ ops.laws.compliance)) * 0.5
                stops = -(stored[1:] - stored[:-1])
                strain += stored[1:]
            contact_loss = _accumulate(e0.contact_loss, _rows_dot(impulse, 0.5 * (pv0 + steps.PV)),
                                       static.contact_losses(coefficients, force0, force) if static is not None
                                       else None, stops)
        numerical = None
        if self.open_step.dissipation:
            V0 = np.concatenate((it.V[None], V[:-1]))
            dV, V_w = V - V0, (1.0 - w) * V0 + w * V
            terms = dV * dV @ self.open_step.mass + it.dt ** 2 * (V_w * V_w @ self.open_step.stiffness)
            if impulse is not None:
                terms += _rows_dot(impulse, steps.PV - pv0)
            numerical = self.open_step.dissipation * terms
        constant = lambda value: np.full(size, value)   # noqa: E731
        energy = BlockEnergy(
            kinetic=kinetic, strain=strain, external_work=_accumulate(e0.external_work, work, static_work),
            damping_loss=_accumulate(e0.damping_loss, damping) if damping is not None else constant(e0.damping_loss),
            impact_loss=constant(e0.impact_loss),
            contact_loss=contact_loss if contact_loss is not None else constant(e0.contact_loss),
            initial=constant(e0.initial), scheme=np.zeros(size), load_scale=load_scale,
            friction_loss=constant(e0.friction_loss),
            numerical_loss=_accumulate(e0.numerical_loss, numerical) if numerical is not None else
            constant(e0.numerical_loss),
            roundoff=np.finfo(float).eps * ((U * U) @ np.abs(self.open_step.stiffness)) + it._start_roundoff,
            losses=dict(e0.losses))
        return StepBlock(np.arange(st.step + 1, st.step + size + 1), t, U, V, steps.A, self._gaps(t)[0] - pu, force,
                         zeros.copy() if impulse is None else impulse, energy, pu, steps.PV, st,
                         coefficients[1:] if coefficients is not None else None, dict(steps.carry, R=loads[1:]))

    def commit(self, block: StepBlock) -> None:
        """The integrator continues from the block's last step."""
        last = len(block) - 1
        self.integrator.resume(block.state(last), {name: value[last] for name, value in block.carry.items()})
        self._phase = len(block) + (self._phase if block.previous.step == self._end else 0)
        self._end = int(block.step[last])
        self.steps += len(block)
        self.blocks += 1


def _rows_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a[j] . b[j]`` for each row j."""
    return np.einsum("ji,ji->j", a, b)


def _accumulate(start: float, increments: np.ndarray, *more: np.ndarray | None) -> np.ndarray:
    """The running total after each step, ``start`` plus each step's increments (``increments[j]``,
    then each of ``more[j]`` that is not None), added in the order step by step adds them."""
    parts = [increments, *(m for m in more if m is not None)]
    if len(parts) > 1:
        increments = np.column_stack(parts).ravel()
    total = np.cumsum(np.concatenate(([start], increments)))[1:]
    return total[len(parts) - 1::len(parts)]
