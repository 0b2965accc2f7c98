"""A reproducible distribution of the cells over the MPI ranks.

dolfinx 0.5 hands the cells' dual graph to PT-Scotch, whose partition changes from run to run on the
same input (sequential Scotch with a fixed seed too). Two runs of a case on as many ranks then sum their matrices and reductions in different
orders and agree only to ~1e-11, and a restart cannot redo the saved run's arithmetic. This
partitioner is a function of the mesh alone:

- the graph is gathered on rank 0 (the mesh was read or built there, so it already held it);
- where the cells' centres are known (``cell_centres``: every mesh fem-impact builds or reads), the
  cells are split by recursive coordinate bisection: at the median across the longest extent, then
  each half again. A bar, a beam or a horn is cut across its length, a plate across its larger side:
  where the cut is small. (The cut is what the ranks exchange each step: on the 72 963-unknown bar
  of benchmarks/scaling.py 154 to 167 ghost vertices a rank, against 313 to 327 from the order below,
  which gave one rank cells all along the bar.)
- otherwise the cells are ordered by reverse Cuthill-McKee, a breadth-first sweep from a low-degree
  cell, and cut into ``nparts`` runs of equal length;
- each cell is also sent, as a ghost, to the parts of its neighbours (dolfinx's ghost layer).
"""

from __future__ import annotations

import contextlib

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

# The centres (n x gdim) of the cells of the mesh being distributed, in the order given to dolfinx,
# on rank 0: set by ``cell_centres`` around the call that builds the mesh.
_centres: np.ndarray | None = None


@contextlib.contextmanager
def cell_centres(centres: np.ndarray | None):
    """Within the block, meshes are distributed by coordinate bisection of these cell centres."""
    global _centres
    _centres = None if centres is None else np.asarray(centres, dtype=float)
    try:
        yield
    finally:
        _centres = None


# Extents within this fraction of each other are equal: the first axis is cut (a square plate is
# cut across x on every machine, whatever the round-off of its centres).
EQUAL_EXTENTS = 1e-9


def coordinate_bisection(centres: np.ndarray, nparts: int) -> np.ndarray:
    """The part of each point (0 .. nparts-1): recursive bisection across the longest extent, the
    parts of equal size (within one point), ties in a coordinate kept in the points' order."""
    parts = np.zeros(centres.shape[0], dtype=np.int32)

    def split(points: np.ndarray, first: int, count: int) -> None:
        if count == 1 or points.size == 0:
            parts[points] = first
            return
        c = centres[points]
        extent = c.max(axis=0) - c.min(axis=0)
        axis = int(np.flatnonzero(extent >= (1.0 - EQUAL_EXTENTS) * extent.max())[0])
        order = points[np.argsort(c[:, axis], kind="stable")]
        left = count // 2
        cut = points.size * left // count
        split(order[:cut], first, left)
        split(order[cut:], first + left, count - left)

    split(np.arange(centres.shape[0]), 0, nparts)
    return parts


def partition_cells(offsets: np.ndarray, neighbours: np.ndarray, nparts: int,
                    centres: np.ndarray | None = None) -> np.ndarray:
    """The part of each cell (0 .. nparts-1) of the graph given by CSR ``offsets``/``neighbours``:
    coordinate bisection of the cells' ``centres`` if given, else runs of equal length of the
    graph's reverse Cuthill-McKee order."""
    n = offsets.size - 1
    if n == 0 or nparts == 1:
        return np.zeros(n, dtype=np.int32)
    if centres is not None:
        if centres.shape[0] != n:
            raise ValueError(f"{centres.shape[0]} cell centres for a graph of {n} cells")
        return coordinate_bisection(centres, nparts)
    rows = np.repeat(np.arange(n), np.diff(offsets))
    graph = sp.csr_matrix((np.ones(neighbours.size, dtype=np.int8), (rows, neighbours)), shape=(n, n))
    order = reverse_cuthill_mckee(graph, symmetric_mode=True)
    parts = np.empty(n, dtype=np.int32)
    parts[order] = (np.arange(n, dtype=np.int64) * nparts // n).astype(np.int32)
    return parts


def destinations(offsets: np.ndarray, neighbours: np.ndarray, parts: np.ndarray, nparts: int,
                 ghosts: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per cell its owner, then (``ghosts``) the other parts that hold a neighbour, as CSR
    (offsets, ranks), the form dolfinx's partitioners return."""
    n = parts.size
    if not ghosts or n == 0:
        return np.arange(n + 1, dtype=np.int32), parts.astype(np.int32)
    rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(offsets))
    other = parts[neighbours]
    cut = other != parts[rows]
    pairs = np.unique(rows[cut] * nparts + other[cut])
    ghost_cell, ghost_part = pairs // nparts, pairs % nparts
    cell = np.concatenate([np.arange(n, dtype=np.int64), ghost_cell])
    rank = np.concatenate([parts.astype(np.int64), ghost_part])
    first = np.concatenate([np.zeros(n, dtype=np.int8), np.ones(ghost_cell.size, dtype=np.int8)])
    order = np.lexsort((rank, first, cell))   # by cell; the owner first, then the ghosts' ranks ascending
    counts = np.bincount(cell, minlength=n)
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int32), rank[order].astype(np.int32)


def distributed_partition(comm, nparts: int, offsets: np.ndarray, neighbours: np.ndarray,
                          ghosts: bool) -> tuple[np.ndarray, np.ndarray]:
    """:func:`destinations` of this rank's rows of a graph distributed over ``comm`` (rows numbered
    globally in rank order, ``neighbours`` in global numbers), computed on rank 0 for the whole graph."""
    sizes = comm.gather(offsets.size - 1, root=0)
    all_offsets = comm.gather(offsets, root=0)
    all_neighbours = comm.gather(np.asarray(neighbours, dtype=np.int64), root=0)
    if comm.rank == 0:
        glued = [np.zeros(1, dtype=np.int64)]
        shift = 0
        for o in all_offsets:
            glued.append(np.asarray(o[1:], dtype=np.int64) + shift)
            shift += int(o[-1]) if o.size else 0
        whole_offsets = np.concatenate(glued)
        whole_neighbours = np.concatenate(all_neighbours)
        parts = partition_cells(whole_offsets, whole_neighbours, nparts, _centres)
        dest_offsets, dest = destinations(whole_offsets, whole_neighbours, parts, nparts, ghosts)
        starts = np.concatenate([[0], np.cumsum(sizes)])
        pieces = []
        for r in range(comm.size):
            lo, hi = dest_offsets[starts[r]], dest_offsets[starts[r + 1]]
            pieces.append((dest_offsets[starts[r]:starts[r + 1] + 1] - lo, dest[lo:hi]))
    else:
        pieces = None
    return comm.scatter(pieces, root=0)
