"""The time loop: an integrator's steps from a start to an end time, each checked by the energy
watch and handed to the observers (one by one, or as blocks of steps without contact)."""

from __future__ import annotations

from typing import Protocol

from ..mechanics.energy import EnergyWatch
from .parameters import steps_for
from .state import StepState


class Observer(Protocol):
    def write(self, state: StepState) -> None: ...


def integrate(integrator, U0, V0, t_end: float, observers=(), t0: float = 0.0, progress=None,
              watch: EnergyWatch | None = None, resume: bool = False, blocks=None) -> StepState:
    """Run ``integrator`` from (U0, V0) at ``t0`` to ``t_end``, calling each observer every step.

    ``watch`` (an EnergyWatch; a default one when None) checks every step before the observers see
    it: a run whose state stops being finite or whose energy blows up stops with a
    SimulationError, and energy created by the contacts is recorded (or stops the run).

    ``blocks`` (a ``BlockStepper`` of ``integrator``, fem_impact/integrators/blocks.py; None: one
    step at a time) takes the steps without contact many at a time, the same to round-off. Each
    of their steps still reaches every observer: as a block (``write_block(block)``) when every
    observer takes one, else as ``StepState``s one by one, in the order single steps would give
    them; ``progress`` is then called once a block. The integrator's own state (its vectors) is
    that of a block's last step: an observer that reads it at given steps (a checkpoint) says
    which with ``next_stop(step)`` (the next such step after ``step``, or None), and no block
    runs past it.
    """
    n_steps = steps_for(t_end - t0, integrator.dt)
    watch = EnergyWatch() if watch is None else watch
    # resume: the integrator's state was restored from a checkpoint at t0 (fem_impact/app/checkpoint/)
    state = integrator.restored() if resume else integrator.start(U0, V0, t0)
    watch.check(state)
    for obs in observers:
        obs.write(state)
    whole = all(hasattr(obs, "write_block") for obs in observers)
    stops = [obs.next_stop for obs in observers if hasattr(obs, "next_stop")]
    done = 0
    while done < n_steps:
        block = None
        if blocks is not None:
            limit = n_steps - done
            for stop in stops:
                at = stop(state.step)
                if at is not None and at > state.step:
                    limit = min(limit, at - state.step)
            block = blocks.advance(limit)
        size = watch.check_block(block) if block is not None else 0
        if size:
            block = block.head(size) if size < len(block) else block
            blocks.commit(block)
            if whole:
                for obs in observers:
                    obs.write_block(block)
            else:
                for one in block.states():
                    for obs in observers:
                        obs.write(one)
            done += size
            state = integrator.state
        else:
            state = integrator.step()
            watch.check(state)
            for obs in observers:
                obs.write(state)
            done += 1
        if progress is not None:
            progress(state.step, n_steps)
    return state
