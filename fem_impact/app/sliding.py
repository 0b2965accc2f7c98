"""Surface contacts as their bodies slide (docs/theory.md s. 2.7): every step, each row's relative
tangential displacement since its rows were found is compared with a quarter of its cell. Past it,
a scheme that takes new rows (Moreau-Jean on the full model) gets rows found again on the displaced
geometry, between two steps; any other run stops, naming the contact, the node and how far it slid,
instead of going on with partners the node no longer faces."""

from __future__ import annotations

import time

import numpy as np
from scipy import sparse

from ..errors import SimulationError
from ..parallel import allsum


class SlidingWatch:
    """An observer of the time loop (``write``, ``write_block``) over the surface contacts of
    ``cons``; ``integrator`` (and ``fixed``, the model's held dofs) where rows may be found again."""

    # (a restart finds the rows of the checkpoint's step again from the displacement they were found at)
    __checkpoint__ = ("searches", "memory")

    def __init__(self, cons, fields, comm, integrator=None, fixed=None):
        self.cons, self.fields, self.comm = cons, fields, comm
        self.surfaces = [(c, r) for c, r in zip(cons.contacts, cons.relations.relations)
                         if getattr(r, "sliding", None) is not None]
        # (whether the run finds rows again is the model's: the dofs they may reach, set where it does)
        takes = (integrator is not None and getattr(integrator, "takes_new_rows", False)
                 and getattr(integrator.ops, "reach", None) is not None)
        self.integrator = integrator if takes else None
        self.fixed = fixed
        self.origin = {c.name: np.zeros(r.sliding.shape[1]) for c, r in self.surfaces}
        self.searches = 0
        self.seconds: list[float] = []   # each search's wall time (the first builds what the others reuse)
        self._blocks()
        # per surface contact: the displacement its rows were last found at, the rows' origin, their gaps
        sizes = [r.reach_nodes.size * r._geometry[1].shape[1] + r.sliding.shape[1] + (c.rows.stop - c.rows.start)
                 for c, r in self.surfaces]
        self.memory = np.zeros(int(sum(sizes)))

    def __bool__(self) -> bool:
        return bool(self.surfaces)

    @property
    def searching(self) -> bool:
        """Whether rows are found again as the bodies slide (else the run stops past a quarter cell)."""
        return self.integrator is not None

    def _blocks(self) -> None:
        self.parts = []
        for c, relation in self.surfaces:
            T = relation.sliding
            dofs = np.unique(T.nonzero()[0])
            self.parts.append((c, relation, dofs, T[dofs].T.tocsr()))   # (T^T on the dofs it reads)

    def write(self, state) -> None:
        over = False
        for c, relation, dofs, T in self.parts:
            u, _ = self.fields.at(state, dofs)
            slid = allsum(self.comm, T @ u) - self.origin[c.name]
            share = np.abs(slid) / relation.sliding_limit
            worst = int(np.argmax(share)) if share.size else 0
            if not share.size or share[worst] <= 1.0:
                continue
            if self.searching:
                over = True
                continue
            found = relation.found
            row = worst % found.r
            where = ", ".join(f"{v:.6g}" for v in found.x[row])
            limit = relation.sliding_limit[worst] / found.size[row]
            raise SimulationError(
                f"contact {c.name}: the node at ({where}) slid {abs(slid[worst]):.3g} m along the surface by "
                f"t = {state.t:.6g} s, more than {limit:g} of its cell ({found.size[row]:.3g} m): this run keeps "
                "the rows found at t = 0 (small sliding; rows are found again as the bodies slide by method: "
                "moreau_jean on the full model, without rigid bodies or a support moving the surfaces' nodes; "
                "docs/limitations.md)")
        if over:
            clock = time.perf_counter()
            self._search(state)
            self.seconds.append(time.perf_counter() - clock)

    def write_block(self, block) -> None:
        """A block of steps: a run that stops past the limit stops at the block's first step past it, as
        ``write`` step by step would; rows found again are found at the block's last step (the integrator's
        state: no block runs through a contact's search on the full model)."""
        if not self.searching:
            for j in self._over(block):   # (the first that ``write`` finds past the limit raises)
                self.write(block.state(int(j)))
        self.write(block.state(len(block) - 1))

    def _over(self, block) -> np.ndarray:
        """The steps of a block in which a row of a surface contact slid past its limit."""
        over = np.zeros(len(block), dtype=bool)
        for c, relation, dofs, T in self.parts:
            u, _ = self.fields.at_block(block, dofs)
            slid = allsum(self.comm, (T @ u.T).T) - self.origin[c.name]
            over |= (np.abs(slid) / relation.sliding_limit > 1.0).any(axis=1)
        return np.flatnonzero(over)

    def _search(self, state, memory: np.ndarray | None = None) -> None:
        """Every surface contact's rows found again on the displaced geometry (or, ``memory``: where
        the checkpoint says they were found), and the integrator's rows replaced."""
        integ, cons = self.integrator, self.cons
        ops = integ.ops
        U = state.U
        free = np.ones(ops.P_local.shape[0])
        if self.fixed is not None:
            free[self.fixed] = 0.0
        keep = sparse.diags(free)
        P = ops.P_local.tocsc()
        d0 = ops.d0.copy()
        columns = [P]
        order = np.arange(ops.p)
        T = ops.tangents.tocsc() if ops.pt else None
        t_new, t_order = [], np.arange(ops.pt)
        at = 0
        for c, relation in self.surfaces:
            dim = relation._geometry[1].shape[1]
            rows = np.arange(c.rows.start, c.rows.stop)
            size_u, size_o = relation.reach_nodes.size * dim, relation.sliding.shape[1]
            if memory is None:
                u = relation.displacement(U, self.comm)
            else:
                u = memory[at:at + size_u].reshape(-1, dim)
            found, new = relation.search(u)
            normal = (keep @ new.normal).tocsc()
            if memory is None:
                pu = allsum(self.comm, np.asarray(normal.T @ U).ravel())
                old = state.gap[rows]
                # a row's gap as found, never deeper than it was (a held row stays held: no energy from a search)
                gap = np.where(found.paired, np.maximum(found.gap, np.minimum(old, 0.0)), relation.far)
                d0[rows] = gap + pu
            else:
                d0[rows] = memory[at + size_u + size_o:at + size_u + size_o + rows.size]
            order[rows] = P.shape[1] + sum(b.shape[1] for b in columns[1:]) + np.arange(rows.size)
            columns.append(normal)
            if new.tangents:
                mine = np.flatnonzero((ops.tangent_of >= c.rows.start) & (ops.tangent_of < c.rows.stop))
                block = sparse.hstack([keep @ t for t in new.tangents]).tocsc()
                if block.shape[1] != mine.size:
                    raise SimulationError(f"contact {c.name}: its friction rows cannot be found again (a support "
                                          "holds a tangent direction of its nodes)")
                t_order[mine] = T.shape[1] + sum(b.shape[1] for b in t_new) + np.arange(mine.size)
                t_new.append(block)
                cons.tangent_dirs[mine] = np.concatenate(new.tangent_dirs)
            relation_origin = (allsum(self.comm, np.asarray(relation.sliding.T @ U).ravel()) if memory is None
                               else memory[at + size_u:at + size_u + size_o])
            self.origin[c.name] = relation_origin
            self.memory[at:at + size_u] = u.ravel()
            self.memory[at + size_u:at + size_u + size_o] = relation_origin
            self.memory[at + size_u + size_o:at + size_u + size_o + rows.size] = d0[rows]
            at += size_u + size_o + rows.size
        P_new = sparse.hstack(columns).tocsc()[:, order].tocsr()
        tangents = None
        if T is not None:
            tangents = (sparse.hstack([T] + t_new).tocsc()[:, t_order] if t_new else T).tocsr()
        integ.replace_rows(P_new, d0, tangents, same=memory is not None)
        cons.P_local = ops.P_local
        if tangents is not None:
            cons.tangent_local = ops.tangents
        self.searches += 1 if memory is None else 0
        self._blocks()

    def restored(self, state) -> None:
        """After a restart: the rows of the checkpoint's step (collective)."""
        if self.searches and self.searching:
            self._search(state, memory=self.memory.copy())
