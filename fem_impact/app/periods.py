"""``periods.csv``: a row per period of the drive (``output.period``), what a device designer reads of a
run: per body its mean velocity over the period, per contact its impulse and impacts, the energy put
in and lost (docs/running.md, "What a run writes").

The mean velocity is the time mean of the body's momentum over the period divided by its mass, the
momentum integrated by the trapezoidal rule over the steps and interpolated linearly to the period's
ends; the energies are the differences of the cumulative terms at the period's ends, interpolated
likewise. A step's impulse counts in the period its step ends in; an impact in the period its
contact time (``impacts.csv``'s interpolated ``t_contact``) falls in (the ``ImpactLog`` given, an
observer written before this one).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..integrators.state import StepState

AXES = "xyz"


def lost(energy) -> float | np.ndarray:
    """Every loss of a budget (a step's, or a block's arrays) together: damping, impacts, contacts,
    friction, the scheme's own and the laws' columns."""
    return (energy.damping_loss + energy.impact_loss + energy.contact_loss + energy.friction_loss
            + energy.numerical_loss + energy.law_losses)


class PeriodLog:
    """Accumulates the steps into periods of length ``period`` from t = 0 (``write``, ``write_block``);
    ``save`` writes the completed ones with the impacts of ``impacts`` (an ``ImpactLog``)."""

    # (a restart continues the period under way from where the checkpoint left it)
    __checkpoint__ = ("period", "rows", "_t", "_p", "_cum", "_integral", "_start", "_impulse", "_k", "_partial",
                      "_count")

    def __init__(self, period: float, contacts: list, momenta, impacts=None):
        self.period, self.contacts, self.momenta, self.impacts = period, contacts, momenta, impacts
        self._count = np.zeros(len(contacts))   # the period's impacts so far, per contact
        self.rows: list[list[float]] = []
        self._t = None                # the last step's time, momenta (flat) and cumulative terms
        self._p = None
        self._cum = None              # [external work, losses] at the last step
        self._integral = None         # the momenta integrated from the period's start to the last step
        self._start = None            # [external work, losses] at the period's start
        self._impulse = None          # per contact, summed over the period's steps
        self._k = 0                   # the period under way (0: [0, T))
        self._partial = False         # the period under way started with the run, not at its start (a restart)
        self._seen = 0                # the impacts ImpactLog had finished at the last step written

    def write(self, state: StepState) -> None:
        if self._t is not None and state.t <= self._t:   # (a restart's first state: written before its checkpoint)
            return
        e = state.energy
        impulse = np.array([state.impulse[c.rows].sum() for c in self.contacts]) if self.contacts else np.zeros(0)
        self._advance(np.array([state.t]), self.momenta.values(state)[None, :],
                      np.array([[e.external_work, lost(e)]]), impulse[None, :])
        for i, t_contact in self._impacts_from(state.t, state.t):   # the impacts that start at this step
            self._count_impact(i, t_contact)

    def write_block(self, block) -> None:
        """The block's steps; the impacts that start within it (steps with impulses: compiled contact steps)
        counted at their steps, as ``write`` counts them."""
        e = block.energy
        shape = block.t.shape
        t = np.asarray(block.t, float)
        cum = np.column_stack([np.broadcast_to(e.external_work, shape), np.broadcast_to(lost(e), shape)])
        impulse = (np.column_stack([block.impulse[:, c.rows].sum(axis=1) for c in self.contacts])
                   if self.contacts else np.zeros((len(block), 0)))
        p = self.momenta.values_block(block)
        done = 0
        starts = self._impacts_from(float(t[0]), float(t[-1])) if np.count_nonzero(block.impulse) else []
        for j, i, t_contact in sorted((int(np.searchsorted(t, t0)), i, tc) for (t0, i, tc) in starts):
            self._advance(t[done:j + 1], p[done:j + 1], cum[done:j + 1], impulse[done:j + 1])
            done = max(done, j + 1)
            self._count_impact(i, t_contact)
        self._advance(t[done:], p[done:], cum[done:], impulse[done:])

    def _impacts_from(self, t0: float, t1: float) -> list:
        """The impacts (``ImpactLog``'s) whose first step ends in [t0, t1]: (that time, contact index, contact
        time) each; with ``t0 == t1`` as (contact index, contact time) of the step's."""
        if self.impacts is None:
            return []
        index = {c.name: i for i, c in enumerate(self.contacts)}
        events = self.impacts.events[self._seen:] + list(self.impacts._open.values())
        self._seen = len(self.impacts.events)
        found = [(e[0], index[e[1]], e[-1]) for e in events if e[1] in index and t0 <= e[0] <= t1]
        return [(i, tc) for _, i, tc in found] if t0 == t1 else found

    def _count_impact(self, i: int, t_contact: float) -> None:
        """An impact of contact i in the period its contact time falls in."""
        if t_contact >= self._k * self.period * (1.0 - 1e-12) or not self.rows:
            self._count[i] += 1
        else:   # (it closed before the period that began within its first step)
            self.rows[-1][2 + self._n_velocity + len(self.contacts) + i] += 1

    def _advance(self, t: np.ndarray, p: np.ndarray, cum: np.ndarray, impulse: np.ndarray) -> None:
        if not t.size:
            return
        if self._t is None:   # the first state (t0): the period it falls in starts here
            self._t, self._p, self._cum = float(t[0]), p[0].copy(), cum[0].copy()
            self._k = int(np.floor(self._t / self.period + 1e-9))
            self._partial = abs(self._t / self.period - round(self._t / self.period)) > 1e-9
            self._integral, self._start = np.zeros_like(p[0]), cum[0].copy()
            self._impulse = np.zeros(impulse.shape[1])
            t, p, cum, impulse = t[1:], p[1:], cum[1:], impulse[1:]
        for j in range(t.size):   # (a block's steps: few boundaries among many steps, each found by search)
            t1, p1, c1 = float(t[j]), p[j], cum[j]
            end = (self._k + 1) * self.period
            while t1 >= end * (1.0 - 1e-12):   # the period ends within this step: close it at its end
                w = (end - self._t) / (t1 - self._t) if t1 > self._t else 1.0
                p_end, c_end = self._p + w * (p1 - self._p), self._cum + w * (c1 - self._cum)
                self._integral += 0.5 * (end - self._t) * (self._p + p_end)
                self._close(end, c_end)   # (the step's impulse goes to the period it ends in, below)
                self._t, self._p, self._cum = end, p_end, c_end
                end = (self._k + 1) * self.period
            self._integral += 0.5 * (t1 - self._t) * (self._p + p1)
            self._impulse += impulse[j]
            self._t, self._p, self._cum = t1, p1.copy(), c1.copy()

    def _close(self, end: float, cum_end: np.ndarray) -> None:
        masses = np.repeat([self.momenta.mass[name] for name in self.momenta.names], self.momenta.dim)
        mean_velocity = self._integral / (self.period * masses) if masses.size else np.zeros(0)
        work, losses = cum_end - self._start
        if not self._partial:   # (a period the run saw only part of has no row)
            self.rows.append([self._k + 1, end, *mean_velocity, *self._impulse, *self._count, work, losses])
        self._partial = False
        self._count = np.zeros_like(self._count)
        self._k += 1
        self._integral = np.zeros_like(self._integral)
        self._impulse = np.zeros_like(self._impulse)
        self._start = cum_end.copy()

    @property
    def _n_velocity(self) -> int:
        return len(self.momenta.names) * self.momenta.dim

    def columns(self) -> list[str]:
        velocity = [f"{name}.v{AXES[c]}_mean" for name in self.momenta.names for c in range(self.momenta.dim)]
        return ["period", "t", *velocity, *(f"{c.name}.impulse" for c in self.contacts),
                *(f"{c.name}.impacts" for c in self.contacts), "external_work", "losses"]

    def save(self, path: Path) -> None:
        """The completed periods."""
        n = 2 + self._n_velocity + len(self.contacts)
        with open(path, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(self.columns())
            for row in self.rows:
                writer.writerow([int(row[0]), *(f"{x:.12g}" for x in row[1:n]),
                                 *(int(x) for x in row[n:n + len(self.contacts)]),
                                 *(f"{x:.12g}" for x in row[n + len(self.contacts):])])
