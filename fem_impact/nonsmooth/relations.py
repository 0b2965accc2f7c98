"""Contact relations as objects: each gives its rows of ``P`` (and of ``P_T``), its gaps and their
time dependence (docs/theory.md s. 2.1, 2.5).

A relation maps the model's displacement to its rows' normal displacements ``P U`` and says where
the obstacle is: the row's gap ``g(t) = d(t) - P U``. The fixed relations here have a constant
``d``; a relation whose obstacle moves overrides ``gap(t)``, ``gap_velocity(t)`` and
``gap_acceleration(t)`` (``d``, ``d'``, ``d''``) and, when it also slides along its plane,
``velocity(t)`` (the obstacle's velocity vector, which gives its tangential rates), and says so
with ``time_dependent``. The integrators read them through ``Operators`` (mechanics/system.py):
the laws act on the motion relative to the obstacle, and the obstacle's work goes to the
external work (docs/theory.md s. 2.6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ..fem.model import Model, NodeSet


@dataclass
class RelationRows:
    """What a relation contributes: columns of ``P^T`` (owned rows, n_local x r), those of its
    tangent rows (one block per tangent direction), and its gaps at t = 0 (r)."""

    normal: sparse.spmatrix
    tangents: list
    gap: np.ndarray
    # each tangent block's unit direction per row (r x dim), where the rows' directions differ (None:
    # the relation's own ``tangents``, the same for every row)
    tangent_dirs: list | None = None


class Relation:
    """Rows of a contact on a model: ``rows(model)`` once, then its gaps ``d(t)`` per step."""

    time_dependent = False

    def __init__(self, normal: np.ndarray, tangents: list[np.ndarray]):
        self.normal, self.tangents = normal, tangents
        self.d0: np.ndarray | None = None

    def rows(self, model: Model) -> RelationRows:
        raise NotImplementedError

    def gap(self, t: float) -> np.ndarray:
        """``d(t)``: the rows' gaps at zero displacement, at time t (constant here)."""
        return self.d0

    def gap_velocity(self, t: float) -> np.ndarray:
        """``d'(t)``: how fast the obstacle recedes along each row's normal (0 here)."""
        return np.zeros_like(self.d0)

    def gap_acceleration(self, t: float) -> np.ndarray:
        """``d''(t)``: the rate of ``d'`` (0 here; a relation moving at a constant speed keeps it)."""
        return np.zeros_like(self.d0)

    def velocity(self, t: float) -> np.ndarray | None:
        """The obstacle's velocity vector at each row (rows x dim), or None when it does not slide
        along its plane (then its tangential rates are 0)."""
        return None

    def _done(self, rows: RelationRows) -> RelationRows:
        self.d0 = rows.gap
        return rows


class FixedPlane(Relation):
    """A rigid plane ``n . u_node <= gap``, a row per node of a group (the same gap for every node)."""

    def __init__(self, nodes: NodeSet, normal, tangents, gap: float):
        super().__init__(normal, tangents)
        self.nodes, self.gap0 = nodes, gap

    def rows(self, model: Model) -> RelationRows:
        n_local, bs = model.U0.getLocalSize(), model.bs
        col = node_rows(n_local, bs, self.normal, self.nodes)
        t_cols = [node_rows(n_local, bs, t, self.nodes) for t in self.tangents]
        return self._done(RelationRows(col, t_cols, np.full(len(self.nodes), self.gap0)))


class PlaneThroughPoint(FixedPlane):
    """A rigid plane through a point: each node's gap is its own distance to the plane."""

    def __init__(self, nodes: NodeSet, normal, tangents, point: np.ndarray):
        super().__init__(nodes, normal, tangents, 0.0)
        self.point = point

    def rows(self, model: Model) -> RelationRows:
        rows = super().rows(model)
        dim = model.meshdata.dim
        rows.gap = (self.point - self.nodes.coords[:, :dim]) @ self.normal
        return self._done(rows)


class NodePair(Relation):
    """Node pairs of two groups matched across the normal: ``n . (u_a - u_b) <= gap`` (each pair's
    distance along n in the mesh without a given gap)."""

    def __init__(self, a: NodeSet, b: NodeSet, normal, tangents, gap: float | None):
        super().__init__(normal, tangents)
        self.a, self.b, self.gap0 = a, b, gap

    def rows(self, model: Model) -> RelationRows:
        n_local, bs, dim = model.U0.getLocalSize(), model.bs, model.meshdata.dim
        a, b = self.a, self.b
        col = node_rows(n_local, bs, self.normal, a) - node_rows(n_local, bs, self.normal, b)
        t_cols = [node_rows(n_local, bs, t, a) - node_rows(n_local, bs, t, b) for t in self.tangents]
        mesh_gap = (b.coords - a.coords)[:, :dim] @ self.normal
        # Coincident nodes (bodies meshed apart that touch) differ by their coordinates' round-off.
        mesh_gap[np.abs(mesh_gap) <= 1e-12 * model.meshdata.extent] = 0.0
        gap = np.full(len(a), self.gap0) if self.gap0 is not None else mesh_gap
        return self._done(RelationRows(col, t_cols, gap))


class MeanPair(NodePair):
    """Two faces, each on its mean motion: one row between the means, whatever the nodes (a pad on
    a flat face: the contact follows the face as it slides along it). Built as a node pair."""

    def rows(self, model: Model) -> RelationRows:
        n_local, bs, dim = model.U0.getLocalSize(), model.bs, model.meshdata.dim
        a, b = self.a, self.b
        col = node_rows(n_local, bs, self.normal, a).mean(axis=1) - node_rows(n_local, bs, self.normal, b).mean(axis=1)
        t_cols = [node_rows(n_local, bs, t, a).mean(axis=1) - node_rows(n_local, bs, t, b).mean(axis=1)
                  for t in self.tangents]
        mesh_gap = (b.coords[:, :dim].mean(axis=0) - a.coords[:, :dim].mean(axis=0)) @ self.normal
        if abs(mesh_gap) <= 1e-12 * model.meshdata.extent:
            mesh_gap = 0.0
        gap = np.array([self.gap0 if self.gap0 is not None else mesh_gap])
        return self._done(RelationRows(col, t_cols, gap))


class MovingPlane(Relation):
    """An obstacle's plane (a ``FixedPlane`` or a ``PlaneThroughPoint``) displaced by a given motion
    ``m(t)`` from where it is at t = 0: ``d(t) = d0 + n . m(t)`` and its rates, exact (the motion's
    derivatives by Taylor arithmetic, ``Expression.time_derivative``); along the plane, the
    obstacle's velocity ``m'(t)`` (docs/theory.md s. 2.6).

    ``motion``: one expression in t per axis of the model (its parameters resolved); ``name``: how
    an error names the contact.
    """

    time_dependent = True

    def __init__(self, inner: FixedPlane, motion: list, name: str = "obstacle"):
        super().__init__(inner.normal, inner.tangents)
        self.inner, self.name = inner, name
        self.motion = [[f.time_derivative(order) for f in motion] for order in range(3)]
        self._known: dict = {}

    def rows(self, model: Model) -> RelationRows:
        rows = self.inner.rows(model)
        # (the motion at t = 0 is where gap or point put the plane: m(0) is subtracted)
        self._start = self._vector(0.0, 0)
        return self._done(rows)

    def _vector(self, t: float, order: int) -> np.ndarray:
        """``m(t)``, ``m'(t)`` or ``m''(t)`` (a step asks for each at a few times, several times: kept)."""
        known = self._known.get((t, order))
        if known is not None:
            return known
        if len(self._known) >= 16:
            self._known.clear()
        value = np.array([f.at_time(t) for f in self.motion[order]])
        if not np.all(np.isfinite(value)):
            from ..errors import SimulationError

            what = ("motion", "velocity", "acceleration")[order]
            raise SimulationError(f"contact {self.name}: the obstacle's {what} is not finite at t = {t:.6g} "
                                  f"(motion: {', '.join(str(f.source) for f in self.motion[0])})")
        value.flags.writeable = False
        self._known[(t, order)] = value
        return value

    def gap(self, t: float) -> np.ndarray:
        return self.d0 + float(self.normal @ (self._vector(t, 0) - self._start))

    def gap_velocity(self, t: float) -> np.ndarray:
        return np.full(self.d0.size, float(self.normal @ self._vector(t, 1)))

    def gap_acceleration(self, t: float) -> np.ndarray:
        return np.full(self.d0.size, float(self.normal @ self._vector(t, 2)))

    def velocity(self, t: float) -> np.ndarray:
        return np.broadcast_to(self._vector(t, 1), (self.d0.size, self.normal.size))


class MeanCoupling(Relation):
    """One row on a relation's mean normal displacement (a distributing coupling): its force
    ``P^T lam`` is shared equally by the nodes, as a load on a node group is. Its gap in time is
    the mean of the inner relation's (an obstacle that moves moves the coupling's)."""

    def __init__(self, inner: Relation):
        super().__init__(inner.normal, inner.tangents)
        self.inner = inner
        self.time_dependent = inner.time_dependent

    def rows(self, model: Model) -> RelationRows:
        rows = self.inner.rows(model)
        return self._done(RelationRows(rows.normal.mean(axis=1), [t.mean(axis=1) for t in rows.tangents],
                                       np.array([rows.gap.mean()])))

    def gap(self, t: float) -> np.ndarray:
        return np.array([self.inner.gap(t).mean()]) if self.time_dependent else self.d0

    def gap_velocity(self, t: float) -> np.ndarray:
        return np.array([self.inner.gap_velocity(t).mean()])

    def gap_acceleration(self, t: float) -> np.ndarray:
        return np.array([self.inner.gap_acceleration(t).mean()])

    def velocity(self, t: float) -> np.ndarray | None:
        inner = self.inner.velocity(t)
        return None if inner is None else inner.mean(axis=0, keepdims=True)


def node_rows(n_local: int, bs: int, normal: np.ndarray, nodes: NodeSet) -> sparse.csr_matrix:
    """Columns of P^T (owned part) for rows ``n . u_node``, one per node of the set."""
    owned = np.flatnonzero(nodes.local_node >= 0)
    dofs = (nodes.local_node[owned][:, None] * bs + np.arange(normal.size)).ravel()
    rows_of = np.repeat(owned, normal.size)
    values = np.tile(normal, owned.size)
    return sparse.csr_matrix((values, (dofs, rows_of)), shape=(n_local, len(nodes)))


class Relations:
    """The relations of a system in row order: the gaps ``d(t)`` of every row and their rates."""

    def __init__(self, relations: list[Relation], slices: list[slice], d0: np.ndarray):
        self.relations, self.slices, self.d0 = relations, slices, d0
        self.time_dependent = any(r.time_dependent for r in relations)
        # The tangent rows (friction): the normal row of each and its unit direction (pt x dim),
        # set where the tangent rows are built (relation.build_constraints).
        self.tangent_of: np.ndarray | None = None
        self.tangent_dirs: np.ndarray | None = None

    @classmethod
    def of(cls, relations: list[Relation]) -> Relations:
        """The relations in row order, from relations whose rows (and gaps at t = 0) are known."""
        sizes = np.cumsum([0] + [r.d0.size for r in relations])
        return cls(relations, [slice(int(a), int(b)) for a, b in zip(sizes[:-1], sizes[1:])],
                   np.concatenate([r.d0 for r in relations]) if relations else np.zeros(0))

    def gap(self, t: float) -> np.ndarray:
        """``d(t)`` of every row (the constant ``d0`` itself when no obstacle moves)."""
        if not self.time_dependent:
            return self.d0
        out = self.d0.copy()
        for r, rows in zip(self.relations, self.slices):
            if r.time_dependent:
                out[rows] = r.gap(t)
        return out

    def gap_velocity(self, t: float) -> np.ndarray:
        """``d'(t)`` of every row."""
        return self._rates(t, "gap_velocity")

    def gap_acceleration(self, t: float) -> np.ndarray:
        """``d''(t)`` of every row."""
        return self._rates(t, "gap_acceleration")

    def _rates(self, t: float, hook: str) -> np.ndarray:
        out = np.zeros(self.d0.size)
        for r, rows in zip(self.relations, self.slices):
            if r.time_dependent:
                out[rows] = getattr(r, hook)(t)
        return out

    def tangent_velocity(self, t: float) -> np.ndarray:
        """The obstacles' velocities along every tangent row's direction (0 where none slides)."""
        pt = 0 if self.tangent_of is None else self.tangent_of.size
        out = np.zeros(pt)
        if not pt:
            return out
        for r, rows in zip(self.relations, self.slices):
            velocity = r.velocity(t) if r.time_dependent else None
            if velocity is None:
                continue
            mine = (self.tangent_of >= rows.start) & (self.tangent_of < rows.stop)
            dirs = self.tangent_dirs[mine]
            out[mine] = np.einsum("ij,ij->i", velocity[self.tangent_of[mine] - rows.start][:, :dirs.shape[1]], dirs)
        return out
