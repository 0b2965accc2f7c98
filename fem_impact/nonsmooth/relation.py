"""The constraint matrix P, the gaps d0 and the rows' laws from the contacts of a case (node pairs
known in advance): each contact becomes a relation object (relations.py) and a law (laws.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from mpi4py import MPI
from scipy import sparse
from scipy.spatial import cKDTree

from ..errors import ModelInputError
from ..fem.model import Model, NodeSet, pad_vector
from ..parallel import allsum
from .laws import Coulomb, RowLaws, law_of
from .relations import (FixedPlane, MeanCoupling, MeanPair, MovingPlane, NodePair, PlaneThroughPoint, Relation,
                        Relations, node_rows)
from .specs import Contact


@dataclass
class ContactRows:
    """Rows of ``P`` that belong to one named contact of the case file."""

    name: str
    index: int          # position in the case file's contacts list
    rows: slice


@dataclass
class Constraints:
    """``P U <= d0``: ``P_local`` holds this rank's owned rows of ``P^T`` (sparse, n_local x p).

    Every rank holds all p rows, so the small p x p contact problems can be solved redundantly.
    ``laws`` are the rows' contact laws (restitution, compliance, friction per row follow from
    them), ``relations`` the contacts' relation objects (their gaps in time).
    """

    P_local: sparse.csr_matrix
    d0: np.ndarray
    contacts: list[ContactRows]
    laws: RowLaws
    relations: Relations
    # Coulomb friction (docs/theory.md s. 11): the tangent rows of the rows with mu > 0
    # (owned rows of P_T^T, n_local x pt; 1 per row in 2D, 2 in 3D), the normal row of each, and
    # its unit direction in global axes (pt x dim).
    tangent_local: sparse.csr_matrix | None = None
    tangent_of: np.ndarray | None = None
    tangent_dirs: np.ndarray | None = None

    @property
    def restitution(self) -> np.ndarray:
        return self.laws.restitution

    @property
    def compliance(self) -> np.ndarray:
        """1/stiffness of an elastic stop per row (m/N); 0 on rigid rows."""
        return self.laws.compliance

    @property
    def friction(self) -> np.ndarray:
        """Coulomb's mu per row (0: frictionless)."""
        return self.laws.friction

    @property
    def pt(self) -> int:
        return 0 if self.tangent_of is None else self.tangent_of.size

    @property
    def p(self) -> int:
        return self.d0.size

    def project(self, local_values: np.ndarray, comm: MPI.Comm) -> np.ndarray:
        """P x for a distributed vector given by its owned entries (a global sum over ranks)."""
        return allsum(comm, self.P_local.T @ local_values)


STICK = 1e-9   # relative margin inside the friction cone that counts as sticking
OPEN, STUCK, SLIDING = 0, 1, 2   # a row's state (row_states)


def row_states(cons: Constraints, state, dt: float | None = None) -> np.ndarray:
    """Each row's state at a step (int8, p): ``OPEN`` (no normal force), ``STUCK`` (closed, its
    friction force strictly inside the cone, by ``STICK``), ``SLIDING`` (closed, on the cone, or
    without friction). The force is the step's whole normal impulse over ``dt`` (with a Carnot
    correction's); without ``dt`` the force at the step's end. ``state`` may be a block of steps
    (integrators/blocks.py): then L x p, each step's row as a ``StepState`` of it gives."""
    normal = state.force if dt is None else state.impulse / dt
    loaded = normal > 0.0
    states = np.where(loaded, SLIDING, OPEN).astype(np.int8)
    if state.tangential is not None and cons.pt:
        f = state.tangential
        per_row = np.sqrt(tangent_sums(cons, f * f))
        states[loaded & (per_row < (1.0 - STICK) * cons.friction * normal)] = STUCK
    return states


def tangent_sums(cons: Constraints, values: np.ndarray) -> np.ndarray:
    """Per row, the sum of ``values`` (..., pt) over its tangent rows (..., p), added from 0 in the tangent
    rows' order (as ``np.bincount`` adds them): the same bits for a step and for each step of a block."""
    if values.ndim == 1:   # (a step: bincount itself)
        return np.bincount(cons.tangent_of, weights=values, minlength=cons.p)
    sums = np.zeros(values.shape[:-1] + (cons.p,))
    for rows, mine in _tangent_passes(cons.tangent_of):   # (one pass per tangent direction: 1 in 2D, 2 in 3D)
        sums[..., rows] += values[..., mine]
    return sums


_PASSES: dict[int, tuple] = {}   # id(tangent_of) -> (tangent_of, its passes): the arrays are never changed in place


def _tangent_passes(of: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """``tangent_sums``' passes over the tangent rows ``of`` (each row's k-th tangent row in pass k): (the rows,
    their tangent rows) each, made once per array (a step's observers ask twice a step)."""
    entry = _PASSES.get(id(of))
    if entry is not None and entry[0] is of:
        return entry[1]
    order = np.argsort(of, kind="stable")
    ranked = of[order]
    first = np.concatenate(([True], ranked[1:] != ranked[:-1]))
    rank = np.empty(of.size, dtype=np.int64)   # each tangent row's place among its row's
    rank[order] = np.arange(of.size) - np.maximum.accumulate(np.where(first, np.arange(of.size), 0))
    passes = [(of[mine], mine) for mine in (np.flatnonzero(rank == k)
                                            for k in range(int(rank.max(initial=-1)) + 1))]
    if len(_PASSES) >= 8:
        _PASSES.pop(next(iter(_PASSES)))
    _PASSES[id(of)] = (of, passes)
    return passes


def nodal_states(cons: Constraints, states: np.ndarray, bs: int) -> np.ndarray:
    """A row state per owned node (float, the owned nodes of ``P_local``'s rows): the largest of the
    rows that touch it (``OPEN`` where none does), for the output's ``contact_state``."""
    P = cons.P_local.tocsr()
    per_dof = np.zeros(P.shape[0])
    touched = np.flatnonzero(np.diff(P.indptr))
    if touched.size and states.size:
        per_dof[touched] = np.maximum.reduceat(states[P.indices], P.indptr[touched])
    return per_dof.reshape(-1, bs).max(axis=1)


def relation_of(contact: Contact, model: Model, key: tuple) -> Relation:
    """The relation object of a contact of the case file (its rows, gaps and their time dependence)."""
    dim = model.meshdata.dim
    if contact.type == "surface":
        from .surface import SurfaceContact

        return SurfaceContact(contact.nodes[0], contact.surface, key, contact.name, contact.friction > 0.0)
    normal = np.asarray(pad_vector(contact.normal, dim, key + ("normal",), "normal"), dtype=float)
    normal /= np.linalg.norm(normal)
    tangents = tangent_basis(normal) if contact.friction > 0.0 else []
    if contact.friction > 0.0 and not tangents:
        raise ModelInputError(key + ("friction",), "friction needs a tangent direction: a 1D model has none")
    if contact.type == "obstacle":
        nodes = model.node_set(contact.nodes[0], key + ("nodes",))
        if contact.point is not None:
            point = np.asarray(pad_vector(contact.point, dim, key + ("point",), "point"), dtype=float)
            relation = PlaneThroughPoint(nodes, normal, tangents, point)
        else:
            relation = FixedPlane(nodes, normal, tangents, contact.gap if contact.gap is not None else 0.0)
        if contact.motion is not None:
            if len(contact.motion) != dim:
                raise ModelInputError(key + ("motion",), f"gives {len(contact.motion)} expression(s) for a {dim}D "
                                                          f"model: give one per axis ({', '.join('xyz'[:dim])})")
            relation = MovingPlane(relation, contact.motion, contact.name)
        return MeanCoupling(relation) if contact.coupling == "mean" else relation
    a = model.node_set(contact.nodes[0], key + ("nodes",))
    b = model.node_set(contact.nodes[1], key + ("nodes",))
    if contact.coupling == "mean":
        return MeanPair(a, b, normal, tangents, contact.gap)
    order = match_pairs(key, a, b, normal)
    b = NodeSet(b.name, b.coords[order], b.global_node[order], b.local_node[order])
    return NodePair(a, b, normal, tangents, contact.gap)


def build_constraints(specs: list[Contact], model: Model) -> Constraints:
    """``P``, ``d0`` and the rows' laws of the contacts ``specs`` on ``model``."""
    n_local = model.U0.getLocalSize()
    columns, gaps, contacts, relations, groups = [], [], [], [], []
    cones, tangent_columns, tangent_of, tangent_dirs = [], [], [], []
    for i, contact in enumerate(specs):
        key = ("contacts", i)
        relation = relation_of(contact, model, key)
        rows = relation.rows(model)
        gap = rows.gap
        col = sparse.csr_matrix(rows.normal)
        t_cols = [sparse.csr_matrix(t) for t in rows.tangents]
        start = sum(len(g) for g in gaps)
        dirs = rows.tangent_dirs or [np.tile(t, (len(gap), 1)) for t in relation.tangents]
        for t_dirs, t_col in zip(dirs, t_cols):
            tangent_columns.append(t_col)
            tangent_of.append(np.arange(start, start + len(gap)))
            tangent_dirs.append(t_dirs)
        contacts.append(ContactRows(contact.name, i, slice(start, start + len(gap))))
        relations.append(relation)
        columns.append(col)
        gaps.append(gap)
        groups.append((law_of(contact.law, contact.law_keys), np.arange(start, start + len(gap))))
        cones.append((Coulomb(contact.friction), np.arange(start, start + len(gap))))
    if not columns:
        return Constraints(sparse.csr_matrix((n_local, 0)), np.zeros(0), [], RowLaws([], 0), Relations([], [], np.zeros(0)))
    if model.motion is not None:   # a gap that a support's motion changes: not in the relation (refused)
        moving = np.zeros(n_local)
        moving[model.motion.moving_dofs()] = 1.0
        touched = model.comm.allreduce(np.asarray(abs(sparse.hstack(columns)).T @ moving).ravel(), op=MPI.SUM)
        for c in contacts:
            if np.any(touched[c.rows] > 0.0):
                raise ModelInputError(("contacts", c.index, "nodes"),
                                      "acts on nodes whose motion a support prescribes (supports: displacement); "
                                      "put the contact on nodes the support does not hold")
    # Supports act first: a held dof cannot move, so it does not enter a constraint.
    free = np.ones(n_local)
    free[model.fixed] = 0.0
    P_local = (sparse.diags(free) @ sparse.hstack(columns)).tocsr()
    P_local.eliminate_zeros()
    d0 = np.concatenate(gaps)
    cons = Constraints(P_local, d0, contacts, RowLaws(groups, d0.size, cones=cones),
                       Relations(relations, [c.rows for c in contacts], d0))
    if tangent_columns:
        # A support's held dofs take no part in a tangent row either (its force there goes to the support).
        cons.tangent_local, cons.tangent_of, cons.tangent_dirs = free_tangents(
            sparse.hstack(tangent_columns).tocsr(), free, np.concatenate(tangent_of), np.concatenate(tangent_dirs),
            model.comm)
        cons.relations.tangent_of, cons.relations.tangent_dirs = cons.tangent_of, cons.tangent_dirs
    norms = np.sqrt(model.comm.allreduce(np.asarray(P_local.power(2).sum(axis=0)).ravel(), op=MPI.SUM))
    for c in contacts:
        if np.any(norms[c.rows] == 0.0):
            raise ModelInputError(("contacts", c.index, "nodes"),
                                  "acts on nodes whose normal direction is fixed by a support")
    return cons


HELD = 1e-12   # a tangent direction whose free part has at most this share of its squared norm is held


def free_tangents(T: sparse.csr_matrix, free: np.ndarray, tangent_of: np.ndarray, dirs: np.ndarray,
                  comm: MPI.Comm) -> tuple[sparse.csr_matrix, np.ndarray, np.ndarray]:
    """The tangent rows without the directions a support holds: ``(P_T^T, tangent_of, dirs)``.

    ``T`` (owned rows of P_T^T, n_local x pt) holds each row's orthonormal tangents (1 in 2D, 2 in
    3D, equal norms), ``free`` is 0 on the held dofs. On the free dofs alone, a direction of a row's
    tangent plane in which every dof it moves is held (a node on a symmetry plane that the plane's
    support holds, a radial dof on an axisymmetric axis) has a zero column: no sliding along it, and
    an impulse along it that moves nothing, so Coulomb's law leaves it undetermined and the Delassus
    block singular. Its friction force is the support's reaction: that direction is dropped. A row's
    two tangents are first turned in their plane to the eigenvectors of the Gram matrix of their free
    parts (held directions: eigenvalue 0), so an oblique held direction is found too; rows with none
    keep their tangents unchanged.
    """
    Tf = (sparse.diags(free) @ T).tocsr()
    Tf.eliminate_zeros()
    pt = tangent_of.size
    norms = allsum(comm, np.asarray(T.multiply(T).sum(axis=0)).ravel())
    gram = allsum(comm, np.asarray(Tf.multiply(Tf).sum(axis=0)).ravel())
    # The rows' tangent slots: a row's first tangent, and its second in 3D (-1 in 2D).
    order = np.argsort(tangent_of, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(tangent_of[order]) != 0])
    first = order[starts]
    sizes = np.diff(np.r_[starts, pt])
    second = np.where(sizes == 2, order[np.minimum(starts + 1, pt - 1)], -1)
    pairs = second >= 0
    a, b = first[pairs], second[pairs]
    cross = allsum(comm, np.asarray(Tf[:, a].multiply(Tf[:, b]).sum(axis=0)).ravel()) if a.size else np.zeros(0)
    # Each row: the eigenpairs of the Gram matrix of its free tangents, relative to the full ones'.
    lam = np.zeros((first.size, 2))
    vec = np.tile(np.eye(2), (first.size, 1, 1))
    lam[:, 0] = gram[first] / norms[first]
    lam[~pairs, 1] = 1.0
    if a.size:
        G = np.stack([np.stack([gram[a], cross], -1), np.stack([cross, gram[b]], -1)], -2) / norms[a][:, None, None]
        lam[pairs], vec[pairs] = np.linalg.eigh(G)
        # (a sign per eigenvector: its larger component positive; unturned rows keep their own tangents)
        big = np.take_along_axis(vec, np.abs(vec).argmax(axis=1)[:, None, :], axis=1)
        vec *= np.sign(big)
    held = lam <= HELD
    if not held.any():
        return Tf, tangent_of, dirs
    turned = pairs & held.any(axis=1)
    # R (pt x kept): each kept direction as a combination of its row's tangents, in the slot of the
    # row's first tangent where the row was turned (it keeps one direction at most), the kept
    # directions in slot order.
    keep_first = ~held[:, 0]
    keep_second = pairs & ~held[:, 1]
    plain = [(first[~turned & keep_first], first[~turned & keep_first], np.ones(np.count_nonzero(~turned & keep_first))),
             (second[~turned & keep_second], second[~turned & keep_second],
              np.ones(np.count_nonzero(~turned & keep_second)))]
    for e, keep in enumerate((keep_first, keep_second)):
        r = turned & keep
        plain += [(first[r], first[r], vec[r, 0, e]), (second[r], first[r], vec[r, 1, e])]
    rows, slots, values = (np.concatenate(x) for x in zip(*plain))
    kept = np.unique(slots)
    R = sparse.csr_matrix((values, (rows, np.searchsorted(kept, slots))), shape=(pt, kept.size))
    Tn = (Tf @ R).tocsr()
    Tn.eliminate_zeros()
    return Tn, tangent_of[kept], np.asarray(R.T @ dirs)


def tangent_basis(normal: np.ndarray) -> list[np.ndarray]:
    """Unit tangent directions orthogonal to a unit ``normal``: none in 1D, one in 2D (the normal
    turned by +90 degrees), two in 3D (right-handed with the normal: t1 x t2 = n)."""
    if normal.size == 1:
        return []
    if normal.size == 2:
        return [np.array([-normal[1], normal[0]])]
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    t1 = np.cross(helper, normal)
    t1 /= np.linalg.norm(t1)
    return [t1, np.cross(normal, t1)]


_rows = node_rows   # (the name before relations.py)


def _nodes(n: int) -> str:
    return f"{n} node" if n == 1 else f"{n} nodes"


def match_pairs(key: tuple, a: NodeSet, b: NodeSet, normal: np.ndarray) -> np.ndarray:
    """For each node of ``a``, the index of the node of ``b`` facing it along ``normal``."""
    dim = normal.size
    if len(a) != len(b):
        raise ModelInputError(
            key + ("nodes",),
            f"pair groups '{a.name}' ({_nodes(len(a))}) and '{b.name}' ({_nodes(len(b))}) do not match up",
        )
    # Pairs face each other along the normal: compare positions projected on the plane normal to it.
    def tangential(x):
        x = x[:, :dim]
        return x - np.outer(x @ normal, normal)

    ta, tb = tangential(a.coords), tangential(b.coords)
    scale = max(np.ptp(np.vstack([a.coords, b.coords]), axis=0).max(), 1e-300)
    dist, order = cKDTree(tb).query(ta)
    if np.any(dist > 1e-6 * scale) or len(np.unique(order)) != len(order):
        worst = int(np.argmax(dist))
        raise ModelInputError(
            key + ("nodes",),
            f"pair groups '{a.name}' and '{b.name}' do not match up along the normal: node at "
            f"{np.round(a.coords[worst, :dim], 6).tolist()} has no partner (off by {dist[worst]:.3g})",
        )
    shared = np.flatnonzero(a.global_node == b.global_node[order])
    if shared.size:
        where = np.round(a.coords[shared[0], :dim], 6).tolist()
        raise ModelInputError(
            key + ("nodes",),
            f"pair groups '{a.name}' and '{b.name}' share the node at {where}: a pair joins nodes of two "
            "bodies (mesh the bodies apart, with a node of each where they touch)",
        )
    return order


def check_initial_state(cons: Constraints, model: Model) -> None:
    """The initial displacement must satisfy P U0 <= d0."""
    if cons.p == 0:
        return
    violation = cons.project(model.U0.array_r, model.comm) - cons.d0
    # Lengths: the gaps, the initial displacement, and the model's size (gaps may all be zero).
    scale = max(np.abs(cons.d0).max(), np.abs(model.U0.norm(3)), model.meshdata.extent, 1e-300)
    for c in cons.contacts:
        worst = violation[c.rows].max()
        if worst > 1e-9 * scale:
            raise ModelInputError(
                ("contacts", c.index),
                f"the initial state violates contact '{c.name}': penetration {worst:.4g} at t = 0 "
                "(check the gap, the normal and initial.displacement)",
            )
