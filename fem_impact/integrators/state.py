"""The state after a step, as the time loop, its observers and the outputs see it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mechanics.energy import EnergyBudget


@dataclass(kw_only=True)
class StepState:
    """The state after a step, as observers see it. Arrays are the integrator's own: read only."""

    step: int
    t: float
    U: np.ndarray                    # owned entries of the displacement (or modal coordinates)
    V: np.ndarray
    A: np.ndarray
    gap: np.ndarray                  # d0 - P U per row
    force: np.ndarray                # normal forces F_N at t
    impulse: np.ndarray              # impulses S_N over the step
    energy: EnergyBudget
    normal_displacement: np.ndarray  # P U
    normal_velocity: np.ndarray      # P V (after the impact correction)
    tangential: np.ndarray | None = None            # friction forces r_T / dt per tangent row (with friction)
    tangential_velocity: np.ndarray | None = None   # P_T V per tangent row: the sliding velocity
    # the rows' whole sliding velocity where a static part slides them too (its change over the step / dt)
    sliding: np.ndarray | None = None
    reaction: np.ndarray | None = None              # per moving support pattern (fem/prescribed.py)
    bodies: np.ndarray | None = None                # rigid bodies: per body its centre, velocity and spin
