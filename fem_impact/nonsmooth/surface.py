"""Contact between surfaces meshed apart (``type: surface``): the rows of ``P`` found by a search on
the geometry at t = 0 (docs/theory.md s. 2.7).

2D: mortar rows with dual multipliers. A row per node ``j`` of the contact's node group,
``n_j . (u_j - sum_k w_jk u_k) <= g_j`` with ``w_jk = M_jk / D_j``, ``M_jk = int psi_j N_k ds``
over the slave segments projected on the surface, ``D_j = int N_j ds`` and ``g_j = int psi_j g ds
/ D_j``: ``psi_j`` is the dual basis of the slave segments (``int psi_j N_i = delta_ij D_j``), so
each row holds one node of the group and the surface nodes it faces, the Delassus matrix stays as
sparse as node pairs', and a uniform pressure and a linear displacement field cross the interface
exactly (the contact patch test). A node whose segments the surface does not cover entirely (the
end of a face that overhangs the other) takes a node-to-segment row, a node that faces no segment
a row on itself alone with a far gap (every node keeps its row: their count never changes).

3D: node-to-segment rows: each node of the group projected on the facet (quadrilateral or
triangle) it faces, ``-n_m . (u_j - sum_k N_k(xi) u_k) <= g_j``.

The rows are found on the mesh's geometry at t = 0 and again, on the displaced one, each time a row
slid ``SLIDING_LIMIT`` of a cell (``SurfaceContact.search``, driven by fem_impact/app/sliding.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from mpi4py import MPI
from scipy.spatial import cKDTree

from ..errors import ModelInputError
from ..fem import dolfinx_api as dx
from ..fem.model import Model
from .relations import Relation, RelationRows

SLIDING_LIMIT = 0.25   # the share of a cell a row may slide before its partners would change
FAR = 10.0             # the gap of a node that faces no facet, in the model's size: it never closes
FACING = -0.5          # cosine of the angle between two facets' outward normals, at most: they face each other
CANDIDATES = 8         # facets tried per node or segment (the nearest by centre)
ROUND_OFF = 1e-12      # a unit normal's component below it is round-off's (a face flat along an axis)


@dataclass
class Surface:
    """The boundary facets of a node group, on every rank in one order: their nodes' global numbers
    (f x k), coordinates (f x k x dim), outward unit normals at their centres (f x dim) and sizes (f:
    a segment's length, the square root of a face's area). Moved by the bodies' displacement
    (``_moved``), the facets keep their normals from the mesh's geometry, ``x0`` (docs/theory.md
    s. 2.7: the linear model's small strains)."""

    nodes: np.ndarray
    x: np.ndarray
    normal: np.ndarray
    size: np.ndarray
    x0: np.ndarray | None = None   # the facets' nodes at t = 0, where the normals are taken (None: x)

    @property
    def frame(self) -> np.ndarray:
        """The coordinates the normals are taken at (the mesh's)."""
        return self.x if self.x0 is None else self.x0

    def __len__(self) -> int:
        return self.nodes.shape[0]


def gather_surface(model: Model, group: str, key: tuple) -> Surface:
    """The boundary facets whose nodes are all in ``group`` (edges in 2D, faces in 3D)."""
    meshdata = model.meshdata
    dim = meshdata.dim
    if group not in meshdata.node_groups:
        model.node_set(group, key)   # (its error: no such group, the groups there are)
    nodes, x, inside = dx.boundary_facet_nodes(model.V, meshdata.node_groups[group])
    parts = meshdata.comm.allgather((nodes, x[..., :dim], inside[:, :dim]))
    k = dim
    if dim == 3:
        k = max([p[0].shape[1] for p in parts if p[0].size] or [4])
    nodes = np.concatenate([p[0].reshape(-1, k) for p in parts]).astype(np.int64)
    x = np.concatenate([p[1].reshape(-1, k, dim) for p in parts])
    inside = np.concatenate([p[2].reshape(-1, dim) for p in parts])
    # (a facet on a ghost cell is gathered from two ranks: once, in an order independent of the partition)
    _, first = np.unique(np.sort(nodes, axis=1), axis=0, return_index=True)
    nodes, x, inside = nodes[first], x[first], inside[first]
    if len(nodes) == 0:
        what = "edge" if dim == 2 else "face"
        raise ModelInputError(key, f"node group '{group}' holds no boundary {what} of the mesh: a surface is made "
                                   f"of the {what}s whose nodes are all in the group")
    normal, size = _facet_normals(x)
    centre = x.mean(axis=1)
    normal *= np.where(np.einsum("ij,ij->i", normal, centre - inside) < 0.0, -1.0, 1.0)[:, None]
    return Surface(nodes, x, _axis_exact(normal), size)


def _axis_exact(normal: np.ndarray) -> np.ndarray:
    """Unit normals (..., dim) without their components of round-off's size: a face flat along an
    axis to round-off (its coordinates as a mesher wrote them) has its normal along it exactly, so
    that its rows touch that axis' dofs alone."""
    normal = np.where(np.abs(normal) < ROUND_OFF, 0.0, normal)
    return normal / np.linalg.norm(normal, axis=-1, keepdims=True)


def _moved(surface: Surface, x: np.ndarray) -> Surface:
    """The surface with its facets' nodes at ``x`` and their sizes there; the normals the mesh's (a
    facet turns by its material's rotation, of the order of the strain, which the linear model
    neglects: a row's direction is the one its equations are written in; docs/theory.md s. 2.7)."""
    _, size = _facet_normals(x)
    return Surface(surface.nodes, x, surface.normal, size, surface.frame)


def _facet_normals(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (either side) at the facets' centres and their sizes."""
    if x.shape[2] == 2:
        d = x[:, 1] - x[:, 0]
        length = np.linalg.norm(d, axis=1)
        return np.column_stack([d[:, 1], -d[:, 0]]) / length[:, None], length
    if x.shape[1] == 3:
        n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        area = 0.5 * np.linalg.norm(n, axis=1)
    else:   # a quadrilateral in tensor order: its diagonals' cross product, twice its (projected) area
        n = np.cross(x[:, 3] - x[:, 0], x[:, 2] - x[:, 1])
        area = 0.5 * np.linalg.norm(n, axis=1)
    return n / (2.0 * area)[:, None], np.sqrt(area)


@dataclass
class SurfaceRows:
    """Rows found on the geometry: entries ``(row, node, weight)`` of ``u_j - sum_k w_jk u_k`` (the
    node's weight 1, the surface's -w), each row's unit normal (r x dim; the direction in which the
    node approaches the surface), gap (r), cell size (r) and whether it is a mortar row (r)."""

    entry_row: np.ndarray
    entry_node: np.ndarray
    entry_weight: np.ndarray
    normal: np.ndarray
    gap: np.ndarray
    size: np.ndarray
    mortar: np.ndarray
    node: np.ndarray      # each row's node (global number)
    x: np.ndarray         # and its coordinates (r x dim)
    area: np.ndarray      # a mortar row's D_j (its node's share of the face: force / area is the pressure); nan
    paired: np.ndarray    # whether the node faces a facet (else its row is the node's alone, far from anything)

    @property
    def r(self) -> int:
        return self.gap.size


def node_to_segment(node: np.ndarray, x: np.ndarray, master: Surface) -> dict:
    """Each node (global numbers ``node``, coordinates ``x``, n x dim) projected on the nearest facet
    of ``master`` that faces it: ``{i: rows}`` for the nodes that find one, as arrays (node index,
    facet, shape function values at the projection, normal -n_m, gap, facet size)."""
    n, dim = x.shape
    if n == 0:
        return _no_projection(master, dim)
    k = min(CANDIDATES, len(master))
    _, cand = cKDTree(master.x.mean(axis=1)).query(x, k=k)
    cand = cand.reshape(n, k)
    xi, point, normal = _project(x[:, None, :], master, cand)                # (n, k, ...)
    nodes_of = master.nodes[cand]                                           # (n, k, m)
    shape = _shape(master, xi)                                              # (n, k, m)
    s = np.einsum("nkd,nkd->nk", x[:, None, :] - point, normal)              # distance outside the facet
    dist = np.linalg.norm(x[:, None, :] - point, axis=2)
    tol = 1e-9
    inside = np.all(shape >= -tol, axis=2) & (s > -0.5 * master.size[cand])
    inside &= ~np.any(nodes_of == node[:, None, None], axis=2)    # not its own facet
    score = np.where(inside, dist, np.inf)
    best = np.argmin(score, axis=1)
    found = np.isfinite(score[np.arange(n), best])
    i = np.flatnonzero(found)
    b = best[i]
    shape = np.clip(shape[i, b], 0.0, 1.0)
    shape[shape < 1e-12] = 0.0   # (a node at a facet's corner: that corner's alone, not round-off's others)
    shape /= shape.sum(axis=1, keepdims=True)
    return {"index": i, "facet": cand[i, b], "shape": shape, "normal": -normal[i, b], "gap": s[i, b],
            "size": master.size[cand[i, b]]}


def _no_projection(master: Surface, dim: int) -> dict:
    m = master.nodes.shape[1]
    return {"index": np.zeros(0, dtype=np.int64), "facet": np.zeros(0, dtype=np.int64), "shape": np.zeros((0, m)),
            "normal": np.zeros((0, dim)), "gap": np.zeros(0), "size": np.zeros(0)}


def _shape(master: Surface, xi: np.ndarray) -> np.ndarray:
    """The facets' shape functions at parametric points ``xi`` (..., dim - 1)."""
    m = master.nodes.shape[1]
    if m == 2:
        a = xi[..., 0]
        return np.stack([1.0 - a, a], axis=-1)
    a, b = xi[..., 0], xi[..., 1]
    if m == 3:
        return np.stack([1.0 - a - b, a, b], axis=-1)
    return np.stack([(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b], axis=-1)


def _project(x: np.ndarray, master: Surface, cand: np.ndarray):
    """Closest points of the candidate facets ``cand`` (n, k) to the points ``x`` (n, 1, dim): their
    parametric coordinates, the points, and the facets' outward normals there (on the mesh's
    geometry, ``Surface.frame``)."""
    X = master.x[cand]                                   # (n, k, m, dim)
    m = X.shape[2]
    if m == 2:
        d = X[:, :, 1] - X[:, :, 0]
        xi = np.einsum("nkd,nkd->nk", x - X[:, :, 0], d) / np.einsum("nkd,nkd->nk", d, d)
        xi = xi[..., None]
    elif m == 3:
        a, b = X[:, :, 1] - X[:, :, 0], X[:, :, 2] - X[:, :, 0]
        r = x - X[:, :, 0]
        G = np.stack([np.stack([(a * a).sum(-1), (a * b).sum(-1)], -1), np.stack([(a * b).sum(-1), (b * b).sum(-1)], -1)], -2)
        rhs = np.stack([(r * a).sum(-1), (r * b).sum(-1)], -1)
        xi = np.linalg.solve(G, rhs[..., None])[..., 0]
    else:   # bilinear: Newton on the closest point's conditions (a few steps: the facets are nearly flat)
        xi = np.full(X.shape[:2] + (2,), 0.5)
        for _ in range(12):
            a, b = xi[..., 0:1], xi[..., 1:2]
            p = (1 - a) * (1 - b) * X[:, :, 0] + a * (1 - b) * X[:, :, 1] + (1 - a) * b * X[:, :, 2] + a * b * X[:, :, 3]
            ta = (1 - b) * (X[:, :, 1] - X[:, :, 0]) + b * (X[:, :, 3] - X[:, :, 2])
            tb = (1 - a) * (X[:, :, 2] - X[:, :, 0]) + a * (X[:, :, 3] - X[:, :, 1])
            tab = X[:, :, 0] - X[:, :, 1] - X[:, :, 2] + X[:, :, 3]
            r = p - x
            F = np.stack([(r * ta).sum(-1), (r * tb).sum(-1)], -1)
            off = (ta * tb).sum(-1) + (r * tab).sum(-1)
            J = np.stack([np.stack([(ta * ta).sum(-1), off], -1), np.stack([off, (tb * tb).sum(-1)], -1)], -2)
            step = np.linalg.solve(J, F[..., None])[..., 0]
            xi = np.clip(xi - step, -1.0, 2.0)
            if np.max(np.abs(step)) < 1e-14:
                break
    N = _shape(master, xi)
    point = np.einsum("nkm,nkmd->nkd", N, X)
    if m == 2:
        normal = np.broadcast_to(master.normal[cand], point.shape)
    else:
        X = master.frame[cand]
        if m == 3:
            t1, t2 = X[:, :, 1] - X[:, :, 0], X[:, :, 2] - X[:, :, 0]
        else:
            a, b = xi[..., 0:1], xi[..., 1:2]
            t1 = (1 - b) * (X[:, :, 1] - X[:, :, 0]) + b * (X[:, :, 3] - X[:, :, 2])
            t2 = (1 - a) * (X[:, :, 2] - X[:, :, 0]) + a * (X[:, :, 3] - X[:, :, 1])
        normal = np.cross(t1, t2)
        normal = _axis_exact(normal / np.linalg.norm(normal, axis=-1, keepdims=True))
        normal *= np.sign(np.einsum("nkd,nkd->nk", normal, master.normal[cand]))[..., None]
    return xi, point, normal


def mortar_2d(node: np.ndarray, x: np.ndarray, slave: Surface | None, master: Surface) -> SurfaceRows:
    """Rows for the nodes ``node`` (global numbers, coordinates ``x``) of a 2D contact: mortar rows
    with dual multipliers where the node's segments (``slave``, the group's boundary edges) are all
    covered by the surface ``master``, node-to-segment rows elsewhere."""
    n = node.size
    mortar_ok = np.zeros(n, dtype=bool)
    parts = []
    if slave is not None and len(slave):
        parts, mortar_ok = _mortar_rows(node, x, slave, master)
    rest = np.flatnonzero(~mortar_ok)
    nts = node_to_segment(node[rest], x[rest], master)
    parts.append(_nts_part(rest[nts["index"]], nts, master))
    return _assemble(parts, node, x)


def _nts_part(index: np.ndarray, nts: dict, master: Surface) -> dict:
    m = master.nodes.shape[1]
    return {"index": index, "nodes": master.nodes[nts["facet"]].reshape(-1, m), "weights": nts["shape"],
            "normal": nts["normal"], "gap": nts["gap"], "size": nts["size"], "mortar": np.zeros(index.size, dtype=bool)}


def _mortar_rows(node, x, slave: Surface, master: Surface):
    """The mortar rows of the nodes all of whose slave segments the surface covers."""
    ns = len(slave)
    xs = slave.x                                   # (ns, 2, 2)
    L = slave.size
    t = (xs[:, 1] - xs[:, 0]) / L[:, None]
    k = min(CANDIDATES, len(master))
    _, cand = cKDTree(master.x.mean(axis=1)).query(xs.mean(axis=1), k=k)
    cand = cand.reshape(ns, k)
    Xm = master.x[cand]                            # (ns, k, 2, 2)
    # The master segment's ends projected on the slave segment along its normal: xi in [0, 1] on it.
    xi_m = np.einsum("skad,sd->ska", Xm - xs[:, None, None, 0], t) / L[:, None, None]
    lo = np.clip(xi_m.min(axis=2), 0.0, 1.0)
    hi = np.clip(xi_m.max(axis=2), 0.0, 1.0)
    facing = np.einsum("sd,skd->sk", slave.normal, master.normal[cand]) <= FACING
    shared = np.any(slave.nodes[:, None, :, None] == master.nodes[cand][:, :, None, :], axis=(2, 3))
    valid = facing & ~shared & (hi - lo > 1e-12) & (np.abs(xi_m[..., 1] - xi_m[..., 0]) > 1e-12)
    # the distance across at the overlap's middle: where two candidates overlap, the nearer is the partner
    mid = 0.5 * (lo + hi)
    eta_mid = (mid - xi_m[..., 0]) / np.where(valid, xi_m[..., 1] - xi_m[..., 0], 1.0)
    pm = Xm[:, :, 0] + eta_mid[..., None] * (Xm[:, :, 1] - Xm[:, :, 0])
    ps = xs[:, None, 0] + mid[..., None] * (L[:, None, None] * t[:, None, :])
    across = np.abs(np.einsum("skd,sd->sk", pm - ps, slave.normal))
    across = np.where(valid, across, np.inf)
    both = np.minimum(hi[:, :, None], hi[:, None, :]) - np.maximum(lo[:, :, None], lo[:, None, :]) > 1e-9
    nearer = (across[:, None, :] < across[:, :, None]) | (
        (across[:, None, :] == across[:, :, None]) & (np.arange(k)[None, :] < np.arange(k)[:, None])[None])
    valid &= ~np.any(both & nearer & valid[:, None, :], axis=2)
    covered = np.where(valid, hi - lo, 0.0).sum(axis=1)
    full = covered >= 1.0 - 1e-9
    # Nodes: their segments, and which of them are covered.
    order = np.argsort(node)
    pos = np.searchsorted(node, slave.nodes, sorter=order)
    local = order[np.clip(pos, 0, node.size - 1)]
    local = np.where(node[local] == slave.nodes, local, -1)     # (ns, 2): each segment end's node index
    n = node.size
    has_segment = np.zeros(n, dtype=bool)
    all_covered = np.ones(n, dtype=bool)
    ends = local.reshape(-1)
    ok = ends >= 0
    has_segment[ends[ok]] = True
    np.logical_and.at(all_covered, ends[ok], np.repeat(full, 2)[ok])
    mortar_ok = has_segment & all_covered
    D = np.zeros(n)
    np.add.at(D, ends[ok], np.repeat(0.5 * L, 2)[ok])
    # Two Gauss points per overlap (exact: psi_j N_k is quadratic on it, the gap linear).
    s_idx, c_idx = np.nonzero(valid)
    g = np.array([0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0)])
    a, b = lo[s_idx, c_idx], hi[s_idx, c_idx]
    xi = a[:, None] + (b - a)[:, None] * g[None, :]                      # (q, 2)
    w = 0.5 * (b - a)[:, None] * L[s_idx][:, None]                      # (q, 1)
    e1, e2 = xi_m[s_idx, c_idx, 0], xi_m[s_idx, c_idx, 1]
    eta = (xi - e1[:, None]) / (e2 - e1)[:, None]
    psi = np.stack([2.0 - 3.0 * xi, 3.0 * xi - 1.0], axis=-1)            # (q, 2 gauss, 2 slave ends)
    Nm = np.stack([1.0 - eta, eta], axis=-1)                             # (q, 2 gauss, 2 master ends)
    M = np.einsum("qg,qga,qgb->qab", np.broadcast_to(w, xi.shape), psi, Nm)
    Xq = Xm[s_idx, c_idx]
    pm = Xq[:, None, 0] + eta[..., None] * (Xq[:, None, 1] - Xq[:, None, 0])     # (q, 2, 2)
    ps = xs[s_idx][:, None, 0] + (xi * L[s_idx][:, None])[..., None] * t[s_idx][:, None, :]
    # Each row's normal: the surface's, where the node's segments face it (weights int N_j ds over the
    # overlaps): a frictionless contact on a flat surface pushes along its normal alone, and the gap is
    # the distance to it, as a node-to-segment row's.
    nodal = np.zeros((n, 2))
    for end in (0, 1):
        j = local[s_idx, end]
        keep = j >= 0
        share = (np.broadcast_to(w, xi.shape) * (1.0 - xi if end == 0 else xi)).sum(axis=1)
        np.add.at(nodal, j[keep], -(share[:, None] * master.normal[cand[s_idx, c_idx]])[keep])
    nodal /= np.maximum(np.linalg.norm(nodal, axis=1, keepdims=True), 1e-300)
    rows, cols, vals, gap_rows, gap_vals = [], [], [], [], []
    for end in (0, 1):
        j = local[s_idx, end]
        keep = (j >= 0)
        keep &= mortar_ok[np.maximum(j, 0)]
        jj = j[keep]
        across = np.einsum("qgd,qd->qg", (pm - ps)[keep], nodal[jj])
        gap_rows.append(jj)
        gap_vals.append((np.broadcast_to(w, xi.shape)[keep] * psi[keep, :, end] * across).sum(axis=1))
        for other in (0, 1):
            rows.append(jj)
            cols.append(master.nodes[cand[s_idx, c_idx], other][keep])
            vals.append(M[keep, end, other])
    gap = np.zeros(n)
    np.add.at(gap, np.concatenate(gap_rows), np.concatenate(gap_vals))
    # The cell size of a row: the smallest of its node's segments and of the surface's it faces.
    size = np.full(n, np.inf)
    np.minimum.at(size, ends[ok], np.repeat(L, 2)[ok])
    for end in (0, 1):
        j = local[s_idx, end]
        keep = j >= 0
        np.minimum.at(size, j[keep], master.size[cand[s_idx, c_idx]][keep])
    rows, cols, vals = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
    # One entry per (row, surface node), the weights w_jk = M_jk / D_j.
    key = np.unique(np.column_stack([rows, cols]), axis=0, return_inverse=True)
    pairs, inverse = key
    summed = np.zeros(len(pairs))
    np.add.at(summed, inverse.reshape(-1), vals)
    idx = np.flatnonzero(mortar_ok)
    part = {"index": pairs[:, 0], "flat_nodes": pairs[:, 1], "flat_weights": summed / D[pairs[:, 0]],
            "rows": idx, "normal": nodal[idx], "gap": gap[idx] / D[idx], "size": size[idx],
            "mortar": np.ones(idx.size, dtype=bool), "area": D[idx]}
    return [part], mortar_ok


def _assemble(parts: list[dict], node: np.ndarray, x: np.ndarray) -> SurfaceRows:
    """A row for every node of the group, in its order: the parts' rows, and for a node that faces no
    facet a row on the node alone (``paired`` False; its gap is set far by the relation)."""
    n, dim = x.shape
    normal, gap, size = np.zeros((n, dim)), np.full(n, np.inf), np.full(n, np.inf)
    mortar, area, paired = np.zeros(n, dtype=bool), np.full(n, np.nan), np.zeros(n, dtype=bool)
    e_row, e_node, e_weight = [], [], []
    for part in parts:
        if "flat_nodes" in part:     # mortar: entries (row's node index, surface node, weight)
            rows = part["rows"]
            e_row.append(part["index"])
            e_node.append(part["flat_nodes"])
            e_weight.append(-part["flat_weights"])
        else:
            rows = part["index"]
            m = part["nodes"].shape[1]
            e_row.append(np.repeat(rows, m))
            e_node.append(part["nodes"].reshape(-1))
            e_weight.append(-part["weights"].reshape(-1))
        normal[rows], gap[rows], size[rows], mortar[rows] = part["normal"], part["gap"], part["size"], part["mortar"]
        area[rows] = part.get("area", np.nan)
        paired[rows] = True
    if paired.any():   # (a node alone: the mean direction of the others, which it never reaches)
        mean = normal[paired].sum(axis=0)
        normal[~paired] = mean / max(np.linalg.norm(mean), 1e-300)
    e_row = np.concatenate(e_row + [np.arange(n)])
    e_node = np.concatenate(e_node + [node])
    e_weight = np.concatenate(e_weight + [np.ones(n)])
    return SurfaceRows(e_row, e_node, e_weight, normal, gap, size, mortar, node, x, area, paired)


def surface_rows(node: np.ndarray, x: np.ndarray, slave: Surface | None, master: Surface) -> SurfaceRows:
    """The rows of a surface contact: mortar rows in 2D, node-to-segment rows in 3D."""
    if x.shape[1] == 2:
        return mortar_2d(node, x, slave, master)
    nts = node_to_segment(node, x, master)
    return _assemble([_nts_part(nts["index"], nts, master)], node, x)


def tangent_directions(normal: np.ndarray, previous: np.ndarray | None = None) -> list[np.ndarray]:
    """Unit tangents of each row (r x dim each): one in 2D (the normal turned by +90 degrees), two
    in 3D (right-handed with the normal). ``previous``: the rows' first tangents before (3D): each
    new one is the old turned into the new plane, so that a row's tangential impulses (the friction
    solver's warm start, the outputs) keep their meaning across a search."""
    if normal.shape[1] == 2:
        return [np.column_stack([-normal[:, 1], normal[:, 0]])]
    helper = np.eye(3)[np.argmin(np.abs(normal), axis=1)]
    t1 = np.cross(helper, normal)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    if previous is not None:
        turned = previous - np.einsum("ij,ij->i", previous, normal)[:, None] * normal
        size = np.linalg.norm(turned, axis=1, keepdims=True)
        t1 = np.where(size > 0.5, turned / np.maximum(size, 1e-300), t1)
    return [t1, np.cross(normal, t1)]


class SurfaceContact(Relation):
    """``type: surface``: the nodes of a group against the boundary facets of another, on rows found
    by a search on the geometry (mortar rows in 2D, node-to-segment in 3D), at t = 0 and as the
    bodies slide (``search``)."""

    def __init__(self, nodes: str, surface: str, key: tuple, name: str, friction: bool):
        super().__init__(None, [])
        self.group, self.surface, self.key, self.name, self.with_friction = nodes, surface, key, name, friction
        self.found: SurfaceRows | None = None
        self.sliding: sparse.csr_matrix | None = None   # owned rows of the rows' tangents (n_local x r (dim - 1))
        self.sliding_limit: np.ndarray | None = None

    def rows(self, model: Model) -> RelationRows:
        dim, bs = model.meshdata.dim, model.bs
        if dim == 1:
            raise ModelInputError(self.key + ("type",), "a surface contact needs a 2D or 3D mesh (in 1D use an "
                                                        "obstacle or a pair)")
        if self.group == self.surface:
            raise ModelInputError(self.key + ("surface",), f"is the contact's own node group '{self.group}': "
                                                           "give the surface as another group")
        nodes = model.node_set(self.group, self.key + ("nodes",))
        master = gather_surface(model, self.surface, self.key + ("surface",))
        try:
            slave = gather_surface(model, self.group, self.key + ("nodes",)) if dim == 2 else None
        except ModelInputError:
            slave = None   # (a group of nodes with no edge between them: node-to-segment rows)
        x = nodes.coords[:, :dim]
        found = surface_rows(nodes.global_node, x, slave, master)
        if not found.paired.any():
            raise ModelInputError(self.key + ("surface",), f"no node of '{self.group}' faces the surface "
                                                           f"'{self.surface}' (none projects on a facet of it whose "
                                                           "outward normal is against the node's side)")
        found.gap[np.abs(found.gap) <= 1e-12 * model.meshdata.extent] = 0.0
        self.far = FAR * model.meshdata.extent
        found.gap[~found.paired] = self.far
        self.found, self.unpaired = found, int(np.count_nonzero(~found.paired))
        n_owned, first = dx.owned_nodes(model.V)
        self._layout = (n_owned, first, bs, model.U0.getLocalSize())
        self._geometry = (nodes.global_node, x, slave, master)
        # the nodes a search reads: the group's and the surfaces', in global numbers, and where their
        # owned dofs are on this rank
        parts = [nodes.global_node, master.nodes.ravel()] + ([slave.nodes.ravel()] if slave is not None else [])
        self.reach_nodes = np.unique(np.concatenate(parts))
        local = self.reach_nodes - first
        self._owned = np.flatnonzero((local >= 0) & (local < n_owned))
        self.read_dofs = (local[self._owned][:, None] * bs + np.arange(dim)).ravel()
        # the dofs rows found again may touch: the reach's nodes, along the axes of the surface's
        # normals (on the mesh: a flat face's one axis), all axes with friction's tangents
        axes = np.arange(dim) if self.with_friction else np.flatnonzero(np.any(master.normal != 0.0, axis=0))
        self.reach_dofs = (local[self._owned][:, None] * bs + axes).ravel()
        return self._done(self._rows_of(found))

    def _rows_of(self, found: SurfaceRows) -> RelationRows:
        """The columns of P^T (and of P_T^T with friction) of ``found``, and the sliding watch's."""
        layout = self._layout
        normal_col = _columns(found, found.normal, *layout)
        tangents = tangent_directions(found.normal, getattr(self, "_first_tangent", None))
        self._first_tangent = tangents[0] if len(tangents) > 1 else None
        columns = [_columns(found, t, *layout) for t in tangents]
        # the relative tangential displacement of each row, watched for sliding (app/sliding.py)
        self.sliding = sparse.hstack(columns).tocsr()
        self.sliding_limit = np.tile(SLIDING_LIMIT * found.size, len(tangents))
        rows = RelationRows(normal_col, columns if self.with_friction else [], found.gap)
        rows.tangent_dirs = tangents if self.with_friction else None
        return rows

    def displacement(self, U: np.ndarray, comm) -> np.ndarray:
        """The displacement (len(reach_nodes) x dim, every rank) of the nodes a search reads, from the
        owned entries ``U`` of the full model's displacement."""
        dim = self._geometry[1].shape[1]
        out = np.zeros((self.reach_nodes.size, dim))
        out[self._owned] = U[self.read_dofs].reshape(-1, dim)
        return comm.allreduce(out, op=MPI.SUM) if comm.size > 1 else out

    def search(self, u: np.ndarray) -> tuple[SurfaceRows, RelationRows]:
        """The rows found on the geometry displaced by ``u`` (``displacement``): the mesh's coordinates
        plus u for the group's nodes and the surfaces' facets, each node's facet and weights there,
        its direction the facet's normal on the mesh (``_moved``). Gaps: the distances there along
        it (a node alone: far)."""
        node, x, slave, master = self._geometry
        at = lambda g: u[np.searchsorted(self.reach_nodes, g)]   # noqa: E731
        moved = lambda f: None if f is None else _moved(f, f.x + at(f.nodes))   # noqa: E731
        found = surface_rows(node, x + at(node), moved(slave), moved(master))
        found.gap[~found.paired] = self.far
        self.found, self.unpaired = found, int(np.count_nonzero(~found.paired))
        return found, self._rows_of(found)

    def describe(self) -> str:
        f = self.found
        nts = int(np.count_nonzero(f.paired & ~f.mortar))
        kind = f"{int(f.mortar.sum())} mortar, {nts} node-to-segment" if f.x.shape[1] == 2 else f"{nts} node-to-segment"
        alone = f", {self.unpaired} node(s) of '{self.group}' facing no facet" if self.unpaired else ""
        return f"{f.r} rows ({kind}{alone})"


def _columns(found: SurfaceRows, direction: np.ndarray, n_owned: int, first: int, bs: int,
             n_local: int) -> sparse.csr_matrix:
    """Columns of P^T (owned part) for the rows ``d_j . (u_j - sum_k w_jk u_k)``, direction d per row."""
    local = found.entry_node - first
    owned = (local >= 0) & (local < n_owned)
    dim = direction.shape[1]
    rows = found.entry_row[owned]
    dofs = (local[owned][:, None] * bs + np.arange(dim)).ravel()
    values = (found.entry_weight[owned][:, None] * direction[rows]).ravel()
    columns = sparse.csr_matrix((values, (dofs, np.repeat(rows, dim))), shape=(n_local, found.r))
    columns.eliminate_zeros()   # (a normal along an axis touches one dof a node: W from the fewest)
    return columns
