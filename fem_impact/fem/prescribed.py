"""Prescribed motion of supports (docs/theory.md s. 2.4): ``u = g_k(t)`` on the held dofs of pattern k.

The held dofs stay out of the unknowns; the free dofs see the motion as loads,
``R - M_fp g'' - C_fp g' - K_fp g``: one vector per pattern and matrix, each with a derivative of
g_k as its time function, added to the model's load. Every method then runs unchanged: the full
model integrates the free dofs' total displacement; the reduced model projects these loads on the
fixed-base modes and its static correction takes their quasi-static response, which holds the
support's quasi-static motion exactly (``-K_ff^-1 K_fp g``).

What the integrators report is the free dofs' system. ``MotionView`` turns it into the whole
structure's: fields plus ``e_k g_k``; kinetic and strain energy with the cross terms
``X = g'.(M_pf V) + 1/2 g' M_pp g' + g.(K_pf U) + 1/2 g K_pp g``; the support's work
``W_s = W_loads + X - X(0) + D_s`` (D_s: the damping the support's velocity drives,
``int 2 g'.(C_pf V) + g' C_pp g'``, booked as a loss too); and the reaction per pattern,
``e_k^T (M A + C V + K U - R)`` over the whole structure.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from petsc4py import PETSc
from scipy import sparse

from ..errors import ModelInputError, SimulationError
from ..parallel import allsum

AXES = "xyz"


@dataclass
class PrescribedMotion:
    """The moving supports of a model: patterns e_k (unit on their held dofs), g_k(t), couplings."""

    names: list[str]                 # history columns: GROUP.reaction (GROUP.reaction_x, ... for several)
    functions: list                  # g_k: Expressions in t
    patterns: sparse.csr_matrix      # owned dofs x nk: e_k
    rows: np.ndarray                 # owned free dofs coupled to a held dof (M, K or C)
    coupling: dict                   # "M", "K", "C": (len(rows) x nk) rows of M e_k, ... (C: None without damping)
    held: dict                       # "M", "K", "C": nk x nk, e_j^T M e_k, ... (replicated)
    # The loads on the held dofs (which the supports take): e_k . b_i per load term, constant first
    held_load: np.ndarray = None     # nl x nk
    load_functions: list = None      # the time functions of b_1, ...

    def held_load_at(self, t: float) -> np.ndarray:
        if self.load_functions is None:
            return 0.0
        # (the model's LoadVector has checked these functions at t already)
        return self.held_load[0] + sum(f.at_time(t) * row for f, row in zip(self.load_functions, self.held_load[1:]))

    @property
    def count(self) -> int:
        return len(self.functions)

    def values(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """g(t), g'(t), g''(t) per pattern (the fields and the energies ask several times a step: kept)."""
        if getattr(self, "_last", (None,))[0] == t:
            return self._last[1]
        out = np.array([[f.time_derivative(k).at_time(t) for f in self.functions] for k in range(3)])
        if not np.all(np.isfinite(out)):
            bad = int(np.argwhere(~np.isfinite(out))[0, 1])
            raise_not_finite(self.functions[bad], t)
        self._last = (t, (out[0], out[1], out[2]))
        return self._last[1]

    def moving_dofs(self) -> np.ndarray:
        """Owned dofs that a support moves: the rows of the patterns that hold an entry, but for a
        motion that is the constant 0 (its dofs are held still, as a support without motion holds them)."""
        still = [k for k, f in enumerate(self.functions) if is_still(f)]
        moving = self.patterns[:, [k for k in range(self.count) if k not in still]]
        return np.flatnonzero(moving.getnnz(axis=1))

    def view(self, integrator, fields, comm) -> tuple[MotionView, MovingFields]:
        """The run as the whole structure: an integrator whose states carry its energies and
        reactions, and fields with the supports' motion added."""
        moving = MovingFields(fields, self, comm)
        return MotionView(integrator, self, fields, comm), moving


def is_still(function) -> bool:
    """Whether a support's motion is the constant 0."""
    return function.is_constant and function.at_time(0.0) == 0.0


def raise_not_finite(function, t):
    raise SimulationError(f"the support's motion '{function.source}' (or its derivatives) is no longer finite at "
                          f"t = {t:.6g}")


def build_motion(spec, meshdata, node_set, bs: int, M: PETSc.Mat, K: PETSc.Mat, damping, first_dof: int,
                 fixed_key, axis: np.ndarray | None = None) -> PrescribedMotion | None:
    """The patterns, their couplings and what the load needs, from M and K before the supports
    zero their rows (``M``, ``K``: with every dof). None when no support moves. ``axis``: the owned
    dofs an axisymmetric model holds on its axis (no support may move them)."""
    comm = M.getComm().tompi4py()
    dim = meshdata.dim
    names, functions, columns, owners = [], [], [], []
    n_local = M.getLocalSize()[0]
    for i, support in enumerate(spec.supports):
        if support.displacement is None:
            continue
        comps = [c for c in support.fix if c < dim]
        if support.all_components and len(support.displacement) != dim:
            raise ModelInputError(("supports", i, "displacement"),
                                  f"gives {len(support.displacement)} expressions for 'fix: all' in {dim}D: give "
                                  f"{dim}, one per component")
        if len(comps) != len(support.fix) and not support.all_components:
            raise ModelInputError(("supports", i, "fix"), f"a component does not exist in {dim}D")
        for expr in support.displacement:
            if expr.variables - {"t"}:
                raise ModelInputError(("supports", i, "displacement"),
                                      f"'{expr.source}' may depend on t only (and parameters)")
        nodes = node_set(support.nodes, ("supports", i, "nodes"))
        owned = nodes.local_node[nodes.local_node >= 0]
        several = len(comps) > 1
        for comp, expr in zip(comps, support.displacement):
            names.append(f"{support.nodes}.reaction" + (f"_{AXES[comp]}" if several else ""))
            functions.append(expr)
            column = np.zeros(n_local)
            column[owned * bs + comp] = 1.0
            columns.append(column)
            owners.append((i, comp))
    if not functions:
        return None
    _check_held_still(spec, node_set, bs, dim, n_local, functions, columns, owners, axis, comm)
    seen: dict[str, int] = {}
    for k, name in enumerate(names):   # two supports of one group: the second gets its index
        if name in seen:
            names[k] = f"{name}{k}"
        seen[name] = k
    E = np.column_stack(columns)
    if comm.allreduce(int(np.count_nonzero(E.sum(axis=1) > 1.0))):
        raise ModelInputError(fixed_key, "two supports prescribe the motion of the same dof")
    x, y = M.createVecs()
    products = {}
    for key, A in (("M", M), ("K", K)):
        cols = []
        for k in range(E.shape[1]):
            x.array[:] = E[:, k]
            A.mult(x, y)
            cols.append(y.array_r.copy())
        products[key] = np.column_stack(cols)
    if damping.alpha or damping.beta:
        products["C"] = damping.alpha * products["M"] + damping.beta * products["K"]
    held = {key: allsum(comm, E.T @ P) for key, P in products.items()}
    moving = E.sum(axis=1) > 0.0
    coupled = np.zeros(n_local, dtype=bool)
    for P in products.values():
        coupled |= np.any(P != 0.0, axis=1)
    rows = np.flatnonzero(coupled & ~moving)
    coupling = {key: products[key][rows] if key in products else None for key in ("M", "K", "C")}
    return PrescribedMotion(names, functions, sparse.csr_matrix(E), rows, coupling, held)


def _check_held_still(spec, node_set, bs, dim, n_local, functions, columns, owners, axis, comm) -> None:
    """A dof that one support holds still (no displacement, or an axisymmetric model's axis) and
    another moves is a contradiction the held dofs would settle silently for the motion: refused.
    (A component whose motion is the constant 0 holds still too, and agrees.)"""
    still = []   # (what holds it, owned dof mask)
    for j, support in enumerate(spec.supports):
        if support.displacement is not None:
            continue
        mask = np.zeros(n_local, dtype=bool)
        nodes = node_set(support.nodes, ("supports", j, "nodes"))
        owned = nodes.local_node[nodes.local_node >= 0]
        for comp in support.fix:
            if comp < dim:
                mask[owned * bs + comp] = True
        still.append((f"supports[{j}] (group '{support.nodes}', no displacement)", mask))
    if axis is not None and axis.size:
        mask = np.zeros(n_local, dtype=bool)
        mask[axis] = True
        still.append(("the symmetry axis of the axisymmetric model (its radial displacement is 0)", mask))
    for f, column, (i, comp) in zip(functions, columns, owners):
        if is_still(f):
            continue
        for what, mask in still:
            shared = comm.allreduce(int(np.count_nonzero(mask & (column > 0.0))))
            if shared:
                raise ModelInputError(("supports", i, "displacement"),
                                      f"moves the {AXES[comp]} component of {shared} node(s) that {what} holds "
                                      "still: a node cannot be both; take those nodes out of one of the groups")


def effective_loads(motion: PrescribedMotion, template: PETSc.Vec, fixed: np.ndarray) -> list:
    """The loads the free dofs see: ``(g_k'', -M e_k)``, ``(g_k', -C e_k)``, ``(g_k, -K e_k)`` on
    the free rows, as (time function, vector) pairs for the model's LoadVector."""
    terms = []
    comm = template.getComm().tompi4py()
    for key, order in (("M", 2), ("C", 1), ("K", 0)):
        block = motion.coupling[key]
        if block is None:
            continue
        # (decided on all ranks together: every rank holds the same load terms)
        coupled = comm.allreduce(np.any(block != 0.0, axis=0).astype(int))
        for k, f in enumerate(motion.functions):
            if not coupled[k]:
                continue
            vec = template.duplicate()
            vec.set(0.0)
            vec.array[motion.rows] = -block[:, k]
            vec.array[fixed] = 0.0
            term = f.time_derivative(order)
            term.what = f"the support's motion '{f.source}' (or its derivatives)"
            terms.append((term, vec))
    return terms


class MovingFields:
    """Physical fields with the supports' motion: the inner reader's plus ``e_k g_k(t)`` (and rates)."""

    def __init__(self, inner, motion: PrescribedMotion, comm):
        self.inner, self.motion, self.comm = inner, motion, comm
        self.E = motion.patterns

    def at(self, state, dofs: np.ndarray):
        u, v = self.inner.at(state, dofs)
        g, g1, _ = self.motion.values(state.t)
        block = self.E[dofs.ravel()]
        return u + (block @ g).reshape(u.shape), v + (block @ g1).reshape(v.shape)

    def inertial_at(self, state, dofs: np.ndarray):
        v, a = self.inner.inertial_at(state, dofs)
        _, g1, g2 = self.motion.values(state.t)
        block = self.E[dofs.ravel()]
        return v + block @ g1, a + block @ g2

    def frame(self, state) -> dict:
        out = dict(self.inner.frame(state))
        for name, g in zip(("u", "v", "a"), self.motion.values(state.t)):
            out[name] = out[name] + self.E @ g
        return out

    def velocity_functionals(self, rows: np.ndarray, comm):
        read = self.inner.velocity_functionals(rows, comm)
        moved = allsum(comm, np.asarray(self.E.T @ rows)).T   # k x nk: rows^T e_k

        def read_moving(state):
            return read(state) + moved @ self.motion.values(state.t)[1]
        return read_moving

    def write(self, state) -> None:
        if hasattr(self.inner, "write"):
            self.inner.write(state)


class MotionView:
    """The integrator seen as the whole structure's (module docstring): its states carry the
    kinetic and strain energy with the supports' motion, their work as external work and the
    reactions (``StepState.reaction``); everything else is the integrator's own."""

    # (a checkpoint's: fem_impact/app/checkpoint/; the reaction of the last state, which a restart under
    # other loads reports again as the saved run did)
    __checkpoint__ = ("_x0", "_damping", "_phi", "_t", "_reaction")

    def __init__(self, integrator, motion: PrescribedMotion, fields, comm):
        self.integrator, self.motion, self.fields, self.comm = integrator, motion, fields, comm
        self._x0 = 0.0
        self._damping = 0.0       # D_s so far
        self._phi = 0.0           # at the previous step: (g', C_pf^T V) per pattern, concatenated
        self._t = 0.0
        self._reaction = None     # at the last state

    def __getattr__(self, name):   # dt, name, scheme_energy, friction, ...: the integrator's
        return getattr(self.integrator, name)

    def _products(self, state):
        """(M_pf V, K_pf U, C_pf V, M_pf A) per pattern: one reduction."""
        m, rows = self.motion, self.motion.rows
        u = self.fields.at(state, rows)[0] if rows.size else np.zeros(0)
        # the velocity and acceleration that carry mass and damping (the reduced model's static part has neither)
        v, a = self.fields.inertial_at(state, rows) if rows.size else (np.zeros(0), np.zeros(0))
        C = m.coupling["C"]
        parts = [m.coupling["M"].T @ v, m.coupling["K"].T @ u,
                 C.T @ v if C is not None else np.zeros(m.count), m.coupling["M"].T @ a]
        return allsum(self.comm, np.concatenate(parts)).reshape(4, m.count)

    def _state(self, state, first: bool):
        m, held = self.motion, self.motion.held
        g, g1, g2 = m.values(state.t)
        mv, ku, cv, ma = self._products(state)
        kinetic = float(g1 @ mv + 0.5 * g1 @ held["M"] @ g1)
        strain = float(g @ ku + 0.5 * g @ held["K"] @ g)
        phi = np.concatenate([g1, cv])
        reaction = ma + cv + ku + held["M"] @ g2 + held["K"] @ g - m.held_load_at(state.t)
        if "C" in held:
            reaction += held["C"] @ g1
        e = state.energy.copy()
        if first:
            self._x0, self._damping = kinetic + strain, 0.0
        elif "C" in held:
            # D_s with the step's mean rates, as the integrators book the free dofs' damping (dU . C V_mean,
            # dU = dt V_mean at theta = 1/2): the whole structure's loss is then dt V_mean^T C V_mean >= 0 in
            # every step; the trapezoidal rule on the cross terms alone could book a gain (of order dt^2).
            rate = lambda g1, cv: float(2.0 * g1 @ cv + g1 @ held["C"] @ g1)   # noqa: E731
            if np.ndim(self._phi) == 1:
                self._damping += (state.t - self._t) * rate(*(0.5 * (self._phi + phi)).reshape(2, -1))
            else:   # (a checkpoint written before: its integrand at the step's start, the trapezoidal rule)
                self._damping += 0.5 * (state.t - self._t) * (self._phi + rate(g1, cv))
        self._phi, self._t = phi, state.t
        e.kinetic += kinetic
        e.strain += strain
        e.initial += self._x0
        e.external_work += kinetic + strain - self._x0 + self._damping
        e.damping_loss += self._damping
        self._reaction = reaction
        return replace(state, energy=e, reaction=reaction)

    def start(self, U0, V0, t0: float = 0.0):
        return self._state(self.integrator.start(U0, V0, t0), first=True)

    def step(self):
        return self._state(self.integrator.step(), first=False)

    def restored(self):
        saved = self._reaction
        state = self._state(self.integrator.restored(), first=False)   # (a step of length 0: nothing booked)
        if saved is not None:   # (the loads on the held dofs at that time were the saved run's)
            state.reaction = self._reaction = saved
        return state
