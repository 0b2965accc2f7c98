"""Physical fields from the state the time loop integrates: nodal values for the full model, the
modes and the static correction for the reduced one (docs/theory.md s. 8)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from ..parallel import allsum

if TYPE_CHECKING:   # (type hints only)
    from ..integrators.state import StepState
    from ..nonsmooth.relation import Constraints


class StateFields:
    """Physical fields from the integrated state: the state vectors themselves for the full model
    (``StateFields(cons)``), or ``u = Y1 Z + X_R c(t) - X_P F`` (+ velocities) from the reduced
    model's modal coordinates (``StateFields(cons, Y1, XR, XP, static, dt)``). Observers read
    either the same way, never needing to know which model produced a step.

    Modal: the static part is massless, its velocity is its change over the last step divided by
    dt. Probes read the same few rows every step, so their rows of Y1, X_R and X_P are cut out once
    and the static part of the previous step is kept, not recomputed. The modal state is replicated
    on every rank (``replicated``): a probe is read there without a reduction (``point_reader``).
    """

    def __init__(self, cons: Constraints, Y1: np.ndarray | None = None, XR: np.ndarray | None = None,
                 XP: np.ndarray | None = None, static=None, dt: float | None = None):
        self.Y1, self.XR, self.XP, self.static, self.cons, self.dt = Y1, XR, XP, static, cons, dt
        self.replicated = Y1 is not None   # the modal state: the same on every rank
        # (the steps the static part's velocity differences from: a modal run's state; the full model has none)
        self.__checkpoint__ = ("_previous", "_before") if self.replicated else ()
        self._previous = None   # (t, force) of the previous step, for the static part's velocity
        self._before = None     # ... and of the one before it (a step read again: a restarted run's first)
        self._blocks: dict[bytes, tuple] = {}     # rows -> (Y1, X_R, X_P rows, [t, static part])
        self._readers: dict[bytes, object] = {}   # point_reader's, by their dofs

    def _block(self, rows):
        if isinstance(rows, slice):
            return self.Y1, self.XR, self.XP, None
        key = rows.tobytes()
        if key not in self._blocks:
            static = self.static is not None
            self._blocks[key] = (self.Y1[rows], self.XR[rows] if static else None, self.XP[rows] if static else None,
                                 [None, None])
        return self._blocks[key]

    def _force(self, state: StepState) -> np.ndarray:
        """The forces the static part takes: the normal ones, and with friction ``[F_N, F_T]`` (its
        columns X_P are then ``S_k [P^T, P_T^T]``)."""
        if self.XP is None or self.XP.shape[1] == state.force.size:
            return state.force
        return np.concatenate([state.force, state.tangential])

    def _static_and_rate(self, XR, XP, state: StepState, last: list | None = None):
        """The static part ``X_R c(t) - X_P F`` seen through (XR, XP), and its change over the last
        step divided by dt (0 on the first). ``last``: [t, value] of the previous call, reused."""
        now = XR @ self.static.coefficients(state.t) - XP @ self._force(state)
        rate = 0.0
        reference = self._previous
        if reference is not None and reference[0] >= state.t:
            reference = self._before
        if reference is not None and reference[0] < state.t:
            t0, f0 = reference
            before = last[1] if last is not None and last[0] == t0 else XR @ self.static.coefficients(t0) - XP @ f0
            rate = (now - before) / (state.t - t0)
        if last is not None:
            last[:] = [state.t, now]
        return now, rate

    def _parts(self, state: StepState, rows):
        Y, XR, XP, last = self._block(rows)
        u = Y @ state.U
        v = Y @ state.V
        if self.static is None:
            return u, v
        now, rate = self._static_and_rate(XR, XP, state, last)
        return u + now, v + rate

    def at(self, state: StepState, dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Displacement and velocity at a few owned dofs."""
        if not self.replicated:
            return state.U[dofs], state.V[dofs]
        return self._parts(state, dofs)

    def _static_block(self, XR, XP, block, last: list | None = None, shape=None):
        """``_static_and_rate`` for each step of a block: (L x k) each, for the rows XR, XP (k x nl, k x p);
        ``last`` keeps the last step's value in ``shape``."""
        now = block.coefficients @ XR.T
        if np.count_nonzero(block.force):   # (steps with impulses: compiled contact steps)
            now -= block.force @ XP.T
        rate = np.empty_like(now)
        t = block.t
        rate[0] = 0.0
        if self._previous is not None and self._previous[0] < t[0]:
            t0, f0 = self._previous
            first = last[1] if last is not None and last[0] == t0 else XR @ self.static.coefficients(t0) - XP @ f0
            rate[0] = (now[0] - np.ravel(first)) / (t[0] - t0)
        rate[1:] = (now[1:] - now[:-1]) / (t[1:] - t[:-1])[:, None]
        if last is not None:
            last[:] = [float(t[-1]), now[-1].reshape(shape) if shape is not None else now[-1]]
        return now, rate

    def at_block(self, block, dofs: np.ndarray):
        """``at`` for every step of a block (fem_impact/integrators/blocks.py): arrays (L, *dofs.shape)."""
        if not self.replicated:   # (the nodal fields themselves)
            return block.U[:, dofs], block.V[:, dofs]
        Y, XR, XP, last = self._block(dofs)
        shape = Y.shape[:-1]
        flat = lambda X: X.reshape(int(np.prod(shape)), X.shape[-1])   # noqa: E731
        u, v = block.U @ flat(Y).T, block.V @ flat(Y).T
        if self.static is not None:
            now, rate = self._static_block(flat(XR), flat(XP), block, last, shape)
            u, v = u + now, v + rate
        return u.reshape(len(block), *shape), v.reshape(len(block), *shape)

    def frame_in(self, block, j: int) -> dict[str, np.ndarray]:
        """``frame`` of step j of a block (its static part's rate from the block's step before)."""
        state = block.state(j)
        saved = self._previous
        if j:
            self._previous = (float(block.t[j - 1]), block.force[j - 1])
        try:
            return self.frame(state)
        finally:
            self._previous = saved

    def inertial_at(self, state: StepState, dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and acceleration at a few owned dofs, of what carries mass and damping: all of it
        for the full model, the kept modes for the reduced one (the static part has neither)."""
        if not self.replicated:
            return state.V[dofs], state.A[dofs]
        Y = self._block(dofs)[0]
        return Y @ state.V, Y @ state.A

    def frame(self, state: StepState) -> dict[str, np.ndarray]:
        """Owned values of u, v, a and the contact force on the structure (-P^T F_N, and -P_T^T F_T
        with friction: normal and tangential parts in one vector, as ParaView's arrows show it)."""
        force = -(self.cons.P_local @ state.force)
        if state.tangential is not None:   # friction
            force -= self.cons.tangent_local @ state.tangential
        if not self.replicated:
            return {"u": state.U, "v": state.V, "a": state.A, "contact_force": force}
        u, v = self._parts(state, slice(None))
        return {"u": u, "v": v, "a": self.Y1 @ state.A, "contact_force": force}

    def velocity_functionals(self, rows: np.ndarray, comm: MPI.Comm):
        """A reader of ``rows^T v`` at each step for a few fixed rows (owned entries, n_local x k),
        e.g. body momenta: for the full model k dot products and one reduction per step; for the
        reduced one the rows are projected on the modes and the static columns once, so a step
        costs k x n1 operations on replicated data and no reduction."""
        if not self.replicated:
            owned = np.ascontiguousarray(rows.T)

            def read_nodal(state: StepState) -> np.ndarray:
                return allsum(comm, owned @ state.V)

            def read_nodal_block(block) -> np.ndarray:   # (L x k, one reduction)
                return allsum(comm, block.V @ owned.T)
            read_nodal.block = read_nodal_block
            return read_nodal
        rows_Y = allsum(comm, rows.T @ self.Y1)
        rows_R = allsum(comm, rows.T @ self.XR) if self.static is not None else None
        rows_P = allsum(comm, rows.T @ self.XP) if self.static is not None else None
        last = [None, None]

        def read(state: StepState) -> np.ndarray:
            values = rows_Y @ state.V
            if self.static is not None:
                values = values + self._static_and_rate(rows_R, rows_P, state, last)[1]
            return values

        def read_block(block) -> np.ndarray:
            values = block.V @ rows_Y.T
            if self.static is not None:
                values = values + self._static_block(rows_R, rows_P, block, last)[1]
            return values
        read.block = read_block   # (L x k) for a block of steps
        return read

    def point_reader(self, dofs: np.ndarray, comm: MPI.Comm):
        """A reader of (u, v) at a few points' dofs (n x dim, the owner's local dof, -1 elsewhere), as
        ``at`` on every rank: their rows of the modes and static columns gathered once, so a step
        costs no reduction (the reduced model's step is replicated; a probe's sum would be the one
        collective of its step). Built on the first call (collective), kept for the same dofs."""
        key = dofs.tobytes() + str(dofs.shape).encode()
        if key in self._readers:
            return self._readers[key]
        mine = dofs >= 0
        picked = lambda X: allsum(comm, np.where(mine[..., None], X[np.where(mine, dofs, 0)], 0.0))  # noqa: E731
        Y = picked(self.Y1)
        XR, XP = (picked(self.XR), picked(self.XP)) if self.static is not None else (None, None)
        last = [None, None]

        def read(state: StepState) -> tuple[np.ndarray, np.ndarray]:
            u, v = Y @ state.U, Y @ state.V
            if self.static is None:
                return u, v
            now, rate = self._static_and_rate(XR, XP, state, last)
            return u + now, v + rate
        self._readers[key] = read
        return read

    def write(self, state: StepState) -> None:
        """Observer hook, registered last: remembers the step for the next velocity difference
        (the reduced model's static part; nothing for the full model)."""
        if not self.replicated:
            return
        if self._previous is None or self._previous[0] < state.t:
            self._before = self._previous
        self._previous = (state.t, self._force(state).copy())

    def write_block(self, block) -> None:
        if not self.replicated:
            return
        self._before = (float(block.t[-2]), block.force[-2].copy()) if len(block) > 1 else self._previous
        self._previous = (float(block.t[-1]), block.force[-1].copy())
