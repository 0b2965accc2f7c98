"""Many mixed steps at a time: rigid bodies beside a modal body, every row compliant (docs/theory.md s. 12.7).

A scene of rigid bodies and one modal body whose every contact row the modal body's static part makes
compliant (the row takes its gap at the step's end) has a step made of small dense data alone: the modes'
diagonal equations, the bodies' generalized velocities, the rows' matrices on the modes and the static
compliance (constant), and the rows' H on the bodies (linear in each body's cos and sin). Such steps run
as one compiled loop (kernel.py), many at a time, as :class:`~fem_impact.integrators.blocks.BlockStepper`
runs the reduced model's: the loads' time functions evaluated on the block's times at once, the loop,
then what the observers read (the nodal fields, the rows, the bodies, the energy budget step by step as
``MixedMoreauJean.step`` books it) with numpy over the block. What the loop cannot take (a cone problem it
does not solve whole, a load no longer finite) is left to the integrator's own step. The states agree
with the single steps' to round-off, not to the bit: the loop sums in its own order.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from ..integrators.blocks import MAX_BLOCK, MIN_BLOCK, BlockEnergy, StepBlock, compiled
from ..integrators.state import StepState
from ..mechanics.energy import EnergyBudget
from .bodies import rotation_2d

EPS = np.finfo(float).eps


def _dense(matrix) -> np.ndarray:
    return matrix.toarray() if sparse.issparse(matrix) else np.asarray(matrix)


class RigidNodes:
    """The rigid bodies' nodes' values over a block's steps, ``T[j, b, c] + P1[j, b] a + P2[j, b] b + k`` at a
    dof of body b along axis c (its arm's ``a``, ``b`` and constant ``k``): a displacement (T the centre, P1
    and P2 the cos and sin of the angle), a velocity (T the centre's, P1 and P2 omega cos and omega sin) or
    their change over a step (the differences of those)."""

    def __init__(self, T, P1, P2, a, b, k, body, comp):
        self.T, self.P1, self.P2, self.a, self.b, self.k, self.body, self.comp = T, P1, P2, a, b, k, body, comp

    def steps(self, steps) -> RigidNodes:
        return RigidNodes(self.T[steps], self.P1[steps], self.P2[steps], self.a, self.b, self.k, self.body,
                          self.comp)

    def at(self, idx) -> np.ndarray:
        """Every step at the dofs ``idx`` (positions among the bodies' dofs): L x len(idx)."""
        b = self.body[idx]
        return self.T[:, b, self.comp[idx]] + self.P1[:, b] * self.a[idx] + self.P2[:, b] * self.b[idx] + self.k[idx]

    def times(self, rows: np.ndarray) -> np.ndarray:
        """``values @ rows`` (rows: the bodies' dofs x k, dense): L x k."""
        nb = self.T.shape[1]
        groups = sparse.csr_matrix((np.ones(self.body.size), (np.arange(self.body.size), 2 * self.body + self.comp)),
                                   shape=(self.body.size, 2 * nb))
        by_body = sparse.csr_matrix((np.ones(self.body.size), (np.arange(self.body.size), self.body)),
                                    shape=(self.body.size, nb))
        out = self.T.reshape(len(self.T), 2 * nb) @ (groups.T @ rows)
        out += self.P1 @ (by_body.T @ (self.a[:, None] * rows)) + self.P2 @ (by_body.T @ (self.b[:, None] * rows))
        return out + self.k @ rows


class NodalSeries:
    """A block's nodal field (L steps x n dofs) kept as factors, ``sum_k coef_k basis_k^T`` (the modes, the
    static part's columns) plus the rigid bodies' nodes (``RigidNodes`` on their dofs ``on``), computed where
    it is read: a step (``series[j]``), a few dofs (``series[:, dofs]``), the first steps (``series[:k]``),
    or products with a few columns (``series @ rows``, n x k). Observers read no more than that of a block."""

    ndim = 2

    def __init__(self, terms: list, rigid: RigidNodes, on: np.ndarray, n: int):
        self.terms, self.rigid, self.on = terms, rigid, on
        self.shape = (rigid.T.shape[0], n)

    def __len__(self) -> int:
        return self.shape[0]

    def _at(self, dofs) -> np.ndarray:
        """Every step at ``dofs`` (an index array): L x len(dofs)."""
        out = sum(coef @ basis[dofs].T for coef, basis in self.terms)
        where = np.searchsorted(self.on, dofs)
        mine = (where < self.on.size) & (self.on[np.minimum(where, self.on.size - 1)] == dofs)
        out[:, mine] += self.rigid.at(where[mine])
        return out

    def __getitem__(self, key):
        if isinstance(key, tuple):
            steps, dofs = key
            if isinstance(steps, (int, np.integer)):
                return self[int(steps)][dofs]
            idx = np.arange(self.shape[1])[dofs]
            part = self[steps]
            return part._at(np.atleast_1d(idx).ravel()).reshape(len(part), *np.shape(idx))
        if isinstance(key, slice):
            return NodalSeries([(coef[key], basis) for coef, basis in self.terms], self.rigid.steps(key), self.on,
                               self.shape[1])
        j = int(key)
        out = sum(basis @ coef[j] for coef, basis in self.terms)
        out[self.on] += self.rigid.steps(slice(j, j + 1)).at(np.arange(self.on.size))[0]
        return out

    def __matmul__(self, rows) -> np.ndarray:
        """``series @ rows`` (rows: n x k, dense or sparse): L x k."""
        out = sum(coef @ np.asarray(rows.T @ basis).T for coef, basis in self.terms)
        on_rows = rows[self.on]
        return out + self.rigid.times(_dense(on_rows))

    def __array__(self, dtype=None):
        out = sum(coef @ basis.T for coef, basis in self.terms)
        out[:, self.on] += self.rigid.at(np.arange(self.on.size))
        return out if dtype is None else out.astype(dtype)


class MixedBlocks:
    """The stepper of ``MixedMoreauJean``'s steps in blocks (module docstring): ``advance(limit)`` gives the
    next block of at most ``limit`` steps from the integrator's state (None: take the next step singly),
    ``commit(block)`` hands its last state to the integrator; ``steps`` and ``blocks`` count them."""

    def __init__(self, integrator):
        from .kernel import mixed_steps

        self.integrator, self.kernel = integrator, mixed_steps
        it, e, r = integrator, integrator.elastic, integrator.rigid
        ops, eops, static = it.ops, e.ops, e.ops.static
        self.p, self.pt = ops.p, ops.pt
        n = e.U.size
        h = it.dt
        # the modes' step (MoreauJean.open_steps' constants), the rows on the modes
        self.coef = np.array([0.5 * h, 0.5 * h, -0.5 * h, -h, -0.25 * h * h, 1.0 / h, -0.5 * h, 4.0 / (h * h)])
        rows = e.rows if self.pt else eops
        self.Pe = np.ascontiguousarray(np.column_stack([rows.project_many(col)[0] for col in np.eye(n)]))
        inv_S = np.ascontiguousarray(e.solve_S.inverse)
        self.Ge = np.ascontiguousarray(inv_S[:, None] * self.Pe.T)
        self.We = np.ascontiguousarray(self.Pe @ self.Ge)
        self.C = np.ascontiguousarray(static.rows_compliance if self.pt else static.compliance)
        self.offsets = static.rows_offsets if self.pt else static.load_offsets
        self.static = static
        self.m, self.k, self.inv_S = eops.M, eops.K, inv_S
        self.d = eops.C if eops.C is not None else np.zeros(n)
        # the rigid bodies: H = H_t + cos H_c + sin H_s, the loads' generalized force likewise
        b = r.bodies
        nb = len(b.names)
        B0, B90 = r.map.columns(np.tile(np.eye(2), (nb, 1, 1))), r.map.columns(np.tile(rotation_2d(0.5 * np.pi),
                                                                                        (nb, 1, 1)))
        H0, H90 = (_dense(r._rows.project(B)) for B in (B0, B90))
        spin = np.arange(nb) * 3 + 2
        self.Ht = np.ascontiguousarray(H0.copy())
        self.Ht[:, spin] = 0.0
        self.Hc, self.Hs = np.ascontiguousarray(H0[:, spin]), np.ascontiguousarray(H90[:, spin])
        load = ops.load
        vectors = [load._constant] + [vec for _, vec in load._varying]
        self.functions = [f for f, _ in load._varying]
        keep = np.ones(3 * nb)
        keep[spin] = 0.0
        Bt = B0 @ sparse.diags(keep)
        self.Qt = np.array([Bt.T @ vec for vec in vectors])          # (terms x 3 nb)
        self.Qc = np.array([B0[:, spin].T @ vec for vec in vectors])  # (terms x nb)
        self.Qs = np.array([B90[:, spin].T @ vec for vec in vectors])
        self.inv_mass = np.column_stack([1.0 / b.mass, 1.0 / b.mass, 1.0 / b.inertia]).ravel()
        self.mass = b.mass
        self.inertia = b.inertia
        self.x_ref = np.ascontiguousarray(b.centre.ravel(), dtype=float)
        self.d0 = np.ascontiguousarray(ops.d0[:self.p], dtype=float)
        mu = np.asarray(ops.friction, dtype=float) if self.pt else np.zeros(self.p)
        self.numbers = np.concatenate([mu, np.zeros(self.p)])
        tangent_of = np.asarray(ops.tangent_of if self.pt else np.zeros(0, dtype=np.int64))
        blocks = [np.array([i] + [self.p + k for k in np.flatnonzero(tangent_of == i)]) for i in range(self.p)]
        sizes = np.array([x.size for x in blocks], dtype=np.int64)
        self.layout = np.concatenate([np.concatenate(blocks), np.concatenate([[0], np.cumsum(sizes)[:-1]]),
                                      sizes]).astype(np.int64)
        # the nodal fields: the modal body's Y1 Z + X_R c - X_P F, the bodies' nodes; the rows on them (n x q)
        self.P_rows = (sparse.hstack([sparse.csr_matrix(ops.P_local), sparse.csr_matrix(ops.tangents)]) if self.pt
                       else sparse.csr_matrix(ops.P_local)).tocsr()
        fields = it.modal.fields
        self.Y1, self.XR, self.XP = fields.Y1, fields.XR, fields.XP
        m = r.map
        self.on, self.body, self.comp = m.on, m.b, m.c
        first, second = m.X[:, 0], m.X[:, 1]
        along_x = m.c == 0
        # per dof on a body: its arm along its axis, cos a + sin b; its spin's velocity, cos alpha + sin beta
        self.arm_a, self.arm_b = np.where(along_x, first, second), np.where(along_x, -second, first)
        self.spin_a, self.spin_b = np.where(along_x, -second, first), np.where(along_x, -first, -second)
        self.u_const = -self.x_ref.reshape(nb, 2)[m.b, m.c] - self.arm_a   # (U: x - x0 + (cos - 1) a + sin b)
        self.zeros = np.zeros(m.on.size)
        self.length = MIN_BLOCK
        self.steps = self.blocks = 0
        self._single = False
        self.worst = 0.0

    @staticmethod
    def refusal(integrator) -> str | None:
        """Why ``integrator``'s steps cannot be taken in blocks, or None where they can."""
        from .blocks_fit import refusal

        return refusal(integrator)

    @classmethod
    def of(cls, integrator) -> MixedBlocks | None:
        """A stepper for ``integrator``, or None where ``refusal`` names a reason (or Numba is missing)."""
        if cls.refusal(integrator) is not None or not compiled():
            return None
        from . import kernel

        kernel.warm_up()
        return cls(integrator)

    # -- a block ------------------------------------------------------------------------------------------
    def advance(self, limit: int) -> StepBlock | None:
        it = self.integrator
        e, r = it.elastic, it.rigid
        st, est = it.state, e.state
        if self._single or limit <= 0:
            self._single = False
            return None
        size = min(limit, self.length)
        h = it.dt
        t = it.t0 + np.arange(st.step + 1, st.step + size + 1) * h
        times = np.concatenate(([st.t], t))
        loads = np.empty((size + 1, e.U.size))
        loads[0] = e.R
        loads[1:] = e.ops.load.evaluate_block(t) if e.ops.load.time_dependent else e.R
        coefficients = self.static.coefficients_block(times)
        mid = st.t + (np.arange(size) + 0.5) * h
        terms = np.column_stack([np.ones(size)] + [f.at_times(mid) for f in self.functions])
        finite = np.isfinite(loads[1:]).all(axis=1) & np.isfinite(coefficients[1:]).all(axis=1) \
            & np.isfinite(terms).all(axis=1)
        if not finite.all():   # (a load no longer finite: the single step there stops the run with its name)
            size = int(np.argmin(finite))
            self._single = True
            if not size:
                return None
            t, times, loads, coefficients, terms = t[:size], times[:size + 1], loads[:size + 1], \
                coefficients[:size + 1], terms[:size]
        offsets = np.ascontiguousarray(coefficients @ self.offsets.T)
        Ft, Fc, Fs = terms @ self.Qt, terms @ self.Qc, terms @ self.Qs
        n, q, nb = e.U.size, self.p + self.pt, len(r.bodies.names)
        U, V, A, CV = np.empty((4, size, n))
        X, PE = np.empty((2, size, q))
        NU, XS, ANG, RIG = np.empty((size, 3 * nb)), np.empty((size, 2 * nb)), np.empty((size, nb)), np.empty((size, 3))
        GAP = np.empty((size, self.p))
        from ..integrators.kernels import FUSED
        from ..nonsmooth.friction import FrictionProblem

        force0 = self._forces(est)
        guess = r._r_prev if r._r_prev is not None and r._r_prev.size == q else np.zeros(0)
        pe0 = np.concatenate([est.normal_velocity, est.tangential_velocity]) if self.pt else est.normal_velocity
        taken, worst = self.kernel(
            self.coef, FUSED, e.loaded, e.ops.C is not None, self.m, self.k, self.d, self.inv_S, loads, self.Pe,
            self.Ge, self.We, self.C, offsets, self.d0, self.p, self.Ht, self.Hc, self.Hs, self.inv_mass,
            np.ascontiguousarray(Ft), np.ascontiguousarray(Fc), np.ascontiguousarray(Fs), h, self.numbers.copy(),
            self.layout, FrictionProblem.TOLERANCE, e.U, e.V, e.CV if e.ops.C is not None else np.zeros(n),
            np.ascontiguousarray(pe0, dtype=float), force0, np.ascontiguousarray(st.gap, dtype=float), self.x_ref,
            np.ascontiguousarray(r.xs), np.ascontiguousarray(r.angle, dtype=float), np.ascontiguousarray(r.nu),
            np.ascontiguousarray(guess, dtype=float), U, V, A, CV, X, PE, NU, XS, ANG, RIG, GAP)
        self.length = min(MAX_BLOCK, max(MIN_BLOCK, 2 * taken))
        if taken < size:
            self._single = True   # (the step the loop could not take: the integrator's own)
        if not taken:
            return None
        self.worst = max(self.worst, worst)
        cut = slice(0, taken)
        return self._block(st, est, t[cut], loads[:taken + 1], coefficients[:taken + 1], offsets[:taken + 1],
                           U[cut], V[cut], A[cut], CV[cut], X[cut], PE[cut], NU[cut], XS[cut], ANG[cut], RIG[cut],
                           GAP[cut], force0, pe0)

    def _forces(self, est: StepState) -> np.ndarray:
        """The rows' forces of the elastic part's state (with friction [F_N, F_T])."""
        f = np.concatenate([est.force, est.tangential]) if self.pt else est.force
        return np.ascontiguousarray(f, dtype=float)

    def _block(self, st, est, t, loads, coefficients, offsets, U, V, A, CV, X, PE, NU, XS, ANG, RIG, GAP, force0,
               pe0) -> StepBlock:
        it, p, pt, h = self.integrator, self.p, self.pt, self.integrator.dt
        r = it.rigid
        L, nb = t.size, len(r.bodies.names)
        F1 = X / h
        F0 = np.concatenate((force0[None], F1[:-1]))
        # the nodal fields, as factors (NodalSeries): the modal body's Y1 Z + X_R c - X_P F (its static part's
        # rate its change over the step, from the state before on the first, as _modal_fields takes it), the bodies'
        disp = offsets[1:] - F1 @ self.C.T   # the static part on the rows (L x q)
        before = it.static_before
        dc, dF = np.empty_like(coefficients[1:]), np.empty_like(F1)
        dc[1:], dF[1:] = (coefficients[2:] - coefficients[1:-1]) / h, (F1[1:] - F1[:-1]) / h
        if before is not None and before[0] < t[0]:
            span = t[0] - before[0]
            dc[0] = (coefficients[1] - self.static.coefficients(before[0])) / span
            dF[0] = (F1[0] - np.asarray(before[1], dtype=float)) / span
        else:
            dc[0], dF[0] = 0.0, 0.0
        cos, sin = np.cos(ANG), np.sin(ANG)
        xs, vs = XS.reshape(L, nb, 2), NU.reshape(L, nb, 3)
        spins = NU[:, 2::3]
        parts = (self.body, self.comp)
        U_r = RigidNodes(xs, cos, sin, self.arm_a, self.arm_b, self.u_const, *parts)
        V_r = RigidNodes(vs[:, :, :2], spins * cos, spins * sin, self.spin_a, self.spin_b, self.zeros, *parts)
        # (the nodes' acceleration: their velocity's change over each step, from the state before the block)
        omega0, angle0 = r.nu[2::3], r.angle
        first = (r.nu.reshape(nb, 3)[None, :, :2], (omega0 * np.cos(angle0))[None], (omega0 * np.sin(angle0))[None])
        changes = (np.diff(np.concatenate((f0, now)), axis=0) / h
                   for f0, now in zip(first, (V_r.T, V_r.P1, V_r.P2), strict=True))
        A_r = RigidNodes(*changes, self.spin_a, self.spin_b, self.zeros, *parts)
        n = it.U.size
        U_n = NodalSeries([(U, self.Y1), (coefficients[1:], self.XR), (-F1, self.XP)], U_r, self.on, n)
        V_n = NodalSeries([(V, self.Y1), (dc, self.XR), (-dF, self.XP)], V_r, self.on, n)
        A_n = NodalSeries([(A, self.Y1)], A_r, self.on, n)
        rows_v = V_n @ self.P_rows   # (as the single step's state projects its nodal velocity)
        energy, elastic_energy, rigid_energy = self._energies(st, est, loads, coefficients, offsets, U, V, CV, X,
                                                              F0, F1, PE, pe0, NU, RIG)
        bodies = np.concatenate([xs, vs[:, :, :2], ANG[:, :, None], spins[:, :, None]], axis=2).reshape(L, -1)
        # (the rows' gaps the loop found: the next step's start, in a block or singly; P U of the nodal fields is
        # the same to round-off of the nodes' coordinates, which a stiff row would turn into a force's jump)
        block = StepBlock(np.arange(st.step + 1, st.step + L + 1), t, U_n, V_n, A_n, GAP, F1[:, :p],
                          X[:, :p], energy, self.d0[None] - GAP, rows_v[:, :p], st, None,
                          carry={"Z": U, "Zdot": V, "Zddot": A, "R": loads[1:], "X": X, "PE": PE, "NU": NU, "XS": XS,
                                 "ANG": ANG, "disp": disp,
                                 **{f"elastic.{k}": v for k, v in elastic_energy.items()},
                                 **{f"rigid.{k}": v for k, v in rigid_energy.items()}},
                          tangential=F1[:, p:] if pt else None, tangential_velocity=rows_v[:, p:] if pt else None,
                          bodies=bodies)
        return block

    def _energies(self, st, est, loads, coefficients, offsets, U, V, CV, X, F0, F1, PE, pe0, NU, RIG):
        """The budget of each step as ``MixedMoreauJean.step`` books it (the elastic part's terms, the rigid
        part's, summed), and the two parts' budgets themselves (dicts of arrays)."""
        it, p = self.integrator, self.p
        e, static = it.elastic, self.static
        e0, r0 = est.energy, it.rigid_energy
        L = X.shape[0]
        rows_dot = lambda a, b: np.einsum("ji,ji->j", a, b)   # noqa: E731
        du = U - np.concatenate((e.U[None], U[:-1]))
        pe_prev = np.concatenate((pe0[None], PE[:-1]))
        mean = 0.5 * (pe_prev + PE)
        contact = rows_dot(X[:, :p], mean[:, :p])
        friction = rows_dot(X[:, p:], mean[:, p:]) if self.pt else np.zeros(L)
        # the static part: its energy, the loads' work on it, the forces' loss on it (its tangent share: friction)
        G = static.load_gram
        stored = 0.5 * np.einsum("ji,ik,jk->j", coefficients[1:], G, coefficients[1:])
        load_energy = stored.copy()
        stored += -rows_dot(F1, offsets[1:]) + 0.5 * rows_dot(F1, F1 @ self.C.T)
        c_mean = 0.5 * (coefficients[:-1] + coefficients[1:])
        static_work = np.einsum("ji,ik,jk->j", c_mean, G, coefficients[1:] - coefficients[:-1]) \
            - rows_dot(c_mean @ self.offsets.T, F1 - F0)
        static_loss = 0.5 * rows_dot(F0 + F1, offsets[1:] - offsets[:-1]) \
            - 0.5 * (rows_dot(F1, F1 @ self.C.T) - rows_dot(F0, F0 @ self.C.T))
        static_friction = np.zeros(L)
        if self.pt:
            u1 = offsets[1:] - F1 @ self.C.T
            u0 = offsets[:-1] - F0 @ self.C.T
            static_friction = rows_dot(F1[:, p:], u1[:, p:] - u0[:, p:])
        work = 0.5 * rows_dot(du, loads[:-1]) + 0.5 * rows_dot(du, loads[1:]) if e.loaded else np.zeros(L)
        damping = None
        if e.ops.C is not None:
            CV0 = np.concatenate((e.CV[None], CV[:-1]))
            damping = 0.5 * rows_dot(du, CV0) + 0.5 * rows_dot(du, CV)
        run = lambda start, *steps: start + np.cumsum(np.sum(steps, axis=0))   # noqa: E731
        elastic = {
            "kinetic": 0.5 * rows_dot(V, V * self.m), "strain": 0.5 * rows_dot(U, U * self.k) + stored,
            "external_work": run(e0.external_work, work, static_work),
            "damping_loss": run(e0.damping_loss, damping) if damping is not None else np.full(L, e0.damping_loss),
            "contact_loss": run(e0.contact_loss, contact, static_loss - static_friction),
            "friction_loss": run(e0.friction_loss, friction, static_friction),
            "load_scale": (np.einsum("ji,ji,i->j", loads[1:], loads[1:], e._load_weights) + load_energy
                           if e.loaded else np.zeros(L)),
            "roundoff": EPS * rows_dot(U, U * np.abs(self.k)) + e._start_roundoff,
        }
        spins = NU[:, 2::3]
        vel = NU.reshape(L, -1, 3)[:, :, :2]
        rigid = {
            "kinetic": 0.5 * np.einsum("b,jbi,jbi->j", self.mass, vel, vel) + 0.5 * (spins * spins) @ self.inertia,
            "external_work": run(r0.external_work, RIG[:, 0]),
            "contact_loss": run(r0.contact_loss, RIG[:, 1]),
            "friction_loss": run(r0.friction_loss, RIG[:, 2]),
        }
        total = {}
        for name in ("kinetic", "strain", "external_work", "damping_loss", "impact_loss", "contact_loss",
                     "friction_loss", "numerical_loss", "load_scale", "roundoff", "initial", "scheme"):
            total[name] = elastic.get(name, getattr(e0, name)) + rigid.get(name, getattr(r0, name))
        losses = dict(e0.losses)
        for column, value in r0.losses.items():
            losses[column] = losses.get(column, 0.0) + value
        return BlockEnergy(**total, losses=losses), elastic, rigid

    # -- the integrator goes on from a block's last step ------------------------------------------------
    def commit(self, block: StepBlock) -> None:
        it, p, h = self.integrator, self.p, self.integrator.dt
        e, r = it.elastic, it.rigid
        j = len(block) - 1
        c = {name: value[j] for name, value in block.carry.items()}
        last = block.state(j)
        t = float(block.t[j])
        # the elastic part: its modes, rows and budget
        force = c["X"] / h
        energy = e.state.energy.copy()
        for name, value in c.items():
            if name.startswith("elastic."):
                setattr(energy, name.partition(".")[2], float(value))
        pu = c["disp"][:p] + self.Pe[:p] @ c["Z"]
        est = StepState(step=last.step, t=t, U=c["Z"], V=c["Zdot"], A=c["Zddot"], gap=self.d0 - pu,
                        force=force[:p], impulse=c["X"][:p], energy=energy, normal_displacement=pu,
                        normal_velocity=c["PE"][:p])
        e.resume(est, {"R": c["R"], "KU": self.k * c["Z"], "KV": self.k * c["Zdot"]})
        st_e = e.state
        st_e.normal_displacement, st_e.gap, st_e.normal_velocity = pu, self.d0 - pu, c["PE"][:p].copy()
        e._pu_dyn = self.Pe[:p] @ e.U
        if self.pt:
            st_e.tangential, st_e.tangential_velocity = force[p:], c["PE"][p:].copy()
            e._r_t = c["X"][p:].copy()
        # the rigid part: its bodies, nodes and budget; the warm start of the next cone problem
        nb = len(r.bodies.names)
        r.x = c["XS"].reshape(nb, 2)
        r.angle = c["ANG"].copy()
        r.rot = np.array([rotation_2d(a) for a in r.angle])
        r.nu = c["NU"].copy()
        r._nodal()
        r.A[:] = 0.0
        r.A[self.on] = block.A[j][self.on]   # (the modal body's fields are zero on the bodies' dofs)
        r._r_prev = c["X"].copy()
        r.friction_residual = max(r.friction_residual, self.worst)
        rigid_energy = it.rigid_energy.copy()
        for name, value in c.items():
            if name.startswith("rigid."):
                setattr(rigid_energy, name.partition(".")[2], float(value))
        it.rigid_energy = rigid_energy
        # the scene's state: the block's last, on the integrator's own arrays
        for mine, theirs in ((it.U, last.U), (it.V, last.V), (it.A, last.A)):
            np.copyto(mine, theirs)
        last.U, last.V, last.A = it.U, it.V, it.A
        last.energy = EnergyBudget(**{name: float(getattr(block.energy, name)[j])
                                      for name in EnergyBudget.__dataclass_fields__ if name != "losses"},
                                   losses=dict(block.energy.losses))
        it.state = last
        it.static_before = (t, np.concatenate([force[:p], force[p:]]) if self.pt else force[:p].copy())
        self.steps += len(block)
        self.blocks += 1
