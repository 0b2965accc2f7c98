"""The energy budget of a run and the watch on it: every step books kinetic and strain energy, the
work put in and each loss, and the watch stops a run that blows up or (when asked) creates energy.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from ..errors import SimulationError

if TYPE_CHECKING:
    from ..integrators.state import StepState

BLOW_UP = 100.0  # kinetic + strain energy above this many times the energy put in: the run blew up
# Energy above E0 + W_ext (or a loss below zero) by more than this fraction of the energy scale: the
# scheme created it (round-off and a closed balance leave 1e-12 .. 1e-10).
ENERGY_TOLERANCE = 1e-6


@dataclass(kw_only=True)
class EnergyBudget:
    """Energies at a step; work and loss terms cumulative from the start (docs/theory.md s. 9)."""

    kinetic: float = 0.0
    strain: float = 0.0
    external_work: float = 0.0
    damping_loss: float = 0.0
    impact_loss: float = 0.0
    contact_loss: float = 0.0
    initial: float = 0.0
    # The part of the energy a scheme conserves beyond kinetic + strain: central difference's
    # -dt^2/8 A.M A (docs in CentralDifference); zero for the other methods.
    scheme: float = 0.0
    # Not a term of the balance: the energy the load R(t) can give the structure at the step
    # (ContactScheme._load_energy), the watch's scale while E0 + W_ext is still zero or tiny.
    load_scale: float = 0.0
    friction_loss: float = 0.0   # the work of the friction impulses, lost (docs/theory.md s. 11)
    # The scheme's own dissipation: Moreau-Jean with theta > 1/2 damps the high frequencies, by
    # (theta - 1/2) (dV.M dV + dU.K dU + r.Q dV) a step (MoreauJean.step); zero for theta = 1/2.
    numerical_loss: float = 0.0
    # Not a term of the balance: how far round-off alone may take E - E0 at the step, EPS |U|^T |K| |U|
    # (bounded: ContactScheme._roundoff) at the step and at the start. U^T K U is computed from a K U
    # whose entries carry EPS (|K| |U|)_i each, and K's stored entries do not sum to zero over a rigid
    # translation exactly: a stiff body displaced far from where K U = 0 (sliding, flying) has a small
    # strain energy known only to that. The watch does not call that created.
    roundoff: float = 0.0
    # The loss columns contact laws declare beyond contact_loss (nonsmooth/laws.py: ``column``), by name.
    losses: dict[str, float] = field(default_factory=dict)

    @property
    def total(self) -> float:
        return self.kinetic + self.strain + self.scheme

    @property
    def error(self) -> float:
        """Residual of the balance: E - E0 - W_ext + damping + impact + contact losses."""
        return (
            self.total - self.initial - self.external_work
            + self.damping_loss + self.impact_loss + self.contact_loss + self.friction_loss + self.numerical_loss
            + self.law_losses
        )

    @property
    def law_losses(self) -> float:
        """The laws' own loss columns together (0 without)."""
        return sum(self.losses.values()) if self.losses else 0.0

    def add_loss(self, column: str, value: float) -> None:
        """Book ``value`` in a loss column: ``contact_loss`` or a law's own."""
        if column == "contact_loss":
            self.contact_loss += value
        else:
            self.losses[column] = self.losses.get(column, 0.0) + value

    def copy(self) -> EnergyBudget:
        return replace(self, losses=dict(self.losses))


# The schemes' names in a sentence (EnergyWatch's messages).
TITLES = {"moreau_jean": "Moreau-Jean", "newmark": "Newmark (beta >= gamma / 2)", "central_difference": "central difference"}


class EnergyCreated(SimulationError):
    """The contacts created energy and the run was asked to stop on it (``stop_on_energy_gain``)."""


class EnergyWatch:
    """Watches the energy of every step: that none is created, and that the run has not blown up.

    A scheme that holds keeps ``E(t) <= E0 + W_ext(t)`` (every loss >= 0; the balance residual is
    round-off). The watch records the largest amount by which the energy exceeds that bound (beyond
    what round-off can put into the strain energy's measure, ``EnergyBudget.roundoff``) or a loss
    falls below zero (the contacts' -- contact plus impact loss -- or the damping's), and when
    it first did so by more than
    ``tolerance`` of the energy scale, ``max E0 + W_ext`` reached so far: energy created, although
    the balance may still close (position-level contact forces doing negative work). With
    ``stop_on_energy_gain`` the run stops there (EnergyCreated).

    Growth past ``blow_up`` times the scale is no accuracy problem but a runaway instability (an
    explicit scheme above its step limit): the run always stops with a SimulationError instead of
    writing ever larger numbers (and then NaN).
    """

    __checkpoint__ = ("scale", "created", "created_at", "max_ratio", "roundoff")   # (what it found so far: a restart goes on)

    def __init__(self, stop_on_energy_gain: bool = False, tolerance: float = ENERGY_TOLERANCE,
                 blow_up: float = BLOW_UP, scheme: str = "", stable: bool | None = None):
        self.stop, self.tolerance, self.factor = stop_on_energy_gain, tolerance, blow_up
        # The integrator's name, and whether it is stable at any dt (``unconditionally_stable``): what a
        # blow-up says of its cause.
        self.scheme, self.stable = scheme, stable
        self.scale = 0.0          # E0 + W_ext(t) or the load's energy scale, the largest so far
        self.created = 0.0        # the largest excess (energy units)
        self.created_at: float | None = None
        self.max_ratio = 0.0      # max E / scale
        self.roundoff = 0.0       # the largest round-off bound of E - E0 (EnergyBudget.roundoff)

    @property
    def created_relative(self) -> float:
        return self.created / self.scale if self.scale > 0.0 else 0.0

    def check(self, state: StepState) -> None:
        e = state.energy
        if not np.isfinite(e.total):
            raise SimulationError(self._not_finite(state))
        # A run from rest has E0 = 0 and, over its first steps, W_ext tiny against what round-off leaves
        # in E: the load's own energy scale keeps the measure sound from the first step.
        self.scale = max(self.scale, e.initial + e.external_work, e.initial, e.load_scale)
        if self.scale <= 0.0:
            return
        # The contacts' losses together: Carnot's impulses and the position-level forces are one
        # contact model (on an impact the forces may give back a little of what the impulse took).
        excess = max(e.total - e.initial - e.external_work - e.roundoff, -(e.contact_loss + e.impact_loss + e.law_losses),
                     -e.damping_loss, -e.friction_loss)
        self.max_ratio = max(self.max_ratio, e.total / self.scale)
        self.roundoff = max(self.roundoff, e.roundoff)
        if excess > self.created:
            self.created = excess
            if self.created_at is None and excess > self.tolerance * self.scale:
                self.created_at = state.t
                if self.stop:
                    raise EnergyCreated(f"the contacts created energy at t = {state.t:.6g} (step {state.step}): "
                                        f"{self.describe()}")
        # (Kinetic + strain: a scheme's own term, central difference's, stays bounded as it blows up.)
        physical = e.kinetic + e.strain
        if physical > self.factor * self.scale:
            raise SimulationError(
                f"blew up at t = {state.t:.6g} (step {state.step}): kinetic + strain energy {physical:.4g} is "
                f"{physical / self.scale:.3g} times the initial energy plus the work put in so far "
                f"({self.scale:.4g}); {self._growth_cause()}")

    def _not_finite(self, state: StepState) -> str:
        """Why the energy is no longer finite, as far as the scheme that ran tells."""
        e = state.energy
        if state.step == 0:
            return (f"the initial state is not finite (kinetic energy {e.kinetic:.4g}, strain energy {e.strain:.4g}): "
                    "initial.velocity and initial.displacement must be numbers whose squares float64 holds (below "
                    "about 1e150)")
        where = f"the solution is no longer finite at t = {state.t:.6g} (step {state.step}): "
        if self.stable is False:
            return where + "the scheme blew up: " + self._step_limit()
        overflow = ("the energies overflowed float64 (1.8e308), from a load or an initial value too large for it "
                    f"(the load's energy over the last step: {e.load_scale:.3g})")
        if self.stable:
            return where + f"{TITLES.get(self.scheme, self.scheme)} is stable at any dt, so dt is not the cause: " + overflow
        return where + "the scheme blew up (is dt above a stable limit?), or " + overflow

    def _step_limit(self) -> str:
        """A conditionally stable scheme's limit, in words."""
        if self.scheme == "central_difference":
            return ("central difference is explicit and dt is above its stable limit, 2 / omega_max (c dt / h <= 1 "
                    "on the smallest cell): use a smaller dt, or solver.method: moreau_jean")
        if self.scheme == "newmark":
            return ("Newmark with beta < gamma / 2 is stable only below a step limit: use beta >= gamma / 2 (the "
                    "trapezoidal rule: beta 1/4, gamma 1/2), or a smaller dt")
        return "dt is above the scheme's stable limit"

    def _growth_cause(self) -> str:
        """What energy growing far past E0 + W_ext means for the scheme that ran."""
        if self.stable is False:
            return self._step_limit()
        if self.scheme == "newmark":
            return ("the paper's Newmark scheme is stable at any dt without contact, but its position-level contact "
                    "forces create energy at large steps in persistent contact: use solver.method: moreau_jean (its "
                    "contacts cannot create energy), or a smaller dt")
        if self.scheme == "moreau_jean":
            return ("Moreau-Jean (theta >= 1/2) is stable at any dt and its contacts cannot create energy, so dt is "
                    "not the cause (the reduced model's compliant rows aside: under loads that vary within a step "
                    "they gain energy of order dt^2); otherwise this is a defect: please report it")
        return "the scheme is unstable at this time step"

    def check_block(self, block) -> int:
        """``check`` on each step of a block of steps (fem_impact/integrators/blocks.py) at once.

        Returns how many of its first steps pass, the watch updated as by ``check`` on each of
        them; the first step on which ``check`` would stop the run (not finite, blown up, or
        energy created under ``stop_on_energy_gain``) is not counted: the loop takes it as a
        single step, whose ``check`` stops the run with its message.
        """
        e = block.energy
        total = e.total
        size = total.size
        finite = np.isfinite(total)
        if not finite.all():
            size = int(np.argmin(finite))
        if not size:
            return 0
        initial, work = e.initial[:size], e.external_work[:size]
        scale = np.maximum(initial + work, e.load_scale[:size])   # the scale after each step
        np.maximum(scale, initial, out=scale)
        scale[0] = max(scale[0], self.scale)
        np.maximum.accumulate(scale, out=scale)
        a = int(np.argmax(scale > 0.0)) if scale[0] <= 0.0 else 0   # steps before a: no scale yet, no check
        if scale[-1] <= 0.0:
            self.scale = float(scale[-1])
            return size
        live = slice(a, size)
        excess = total[live] - initial[a:] - work[a:] - e.roundoff[live]
        np.maximum(excess, -(e.contact_loss[live] + e.impact_loss[live] + e.law_losses), out=excess)
        np.maximum(excess, -e.damping_loss[live], out=excess)
        np.maximum(excess, -e.friction_loss[live], out=excess)
        at = scale[a:]
        stop, created_at = size, None
        blown = e.kinetic[live] + e.strain[live] > self.factor * at
        if blown.any():
            stop = a + int(np.argmax(blown))
        if self.created_at is None:
            over = excess > self.tolerance * at
            if over.any():
                before = np.maximum.accumulate(np.concatenate(([self.created], excess[:-1])))   # self.created then
                first = over & (excess > before)
                if first.any():
                    created_at = a + int(np.argmax(first))
                    if self.stop:
                        stop = min(stop, created_at)
        if not stop:
            return 0
        self.scale = float(scale[stop - 1])
        if stop > a:
            kept = stop - a
            self.created = max(self.created, float(excess[:kept].max()))
            self.max_ratio = max(self.max_ratio, float((total[a:stop] / at[:kept]).max()))
            self.roundoff = max(self.roundoff, float(e.roundoff[a:stop].max()))
            if created_at is not None and created_at < stop:
                self.created_at = float(block.t[created_at])
        return stop

    def describe(self) -> str:
        """The finding in words, for a warning or an error."""
        return (f"the energy exceeded E0 + W_ext (or the contacts' losses went below zero) by {self.created:.4g} "
                f"({self.created_relative:.3g} of the energy scale {self.scale:.4g}; max E / (E0 + W_ext) = "
                f"{self.max_ratio:.3g}), first at t = {self.created_at:.6g}")

    @property
    def energy_was_created(self) -> bool:
        return self.created_at is not None
