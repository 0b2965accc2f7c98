"""The reproducible distribution of cells over ranks (fem_impact/fem/partition.py)."""

import numpy as np
import pytest

from fem_impact.fem.partition import coordinate_bisection, destinations, partition_cells


def grid_graph(nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    """The dual graph of an nx x ny grid of squares (neighbours across edges), as CSR."""
    index = np.arange(nx * ny).reshape(ny, nx)
    lists = [[] for _ in range(nx * ny)]
    for a, b in ((index[:, :-1], index[:, 1:]), (index[:-1, :], index[1:, :])):
        for i, j in zip(a.ravel(), b.ravel()):
            lists[i].append(j)
            lists[j].append(i)
    offsets = np.concatenate([[0], np.cumsum([len(n) for n in lists])])
    return offsets, np.concatenate([sorted(n) for n in lists]).astype(np.int64)


@pytest.mark.parametrize("nparts", [2, 3, 4])
def test_a_long_body_is_cut_across_its_length_into_equal_parts(nparts):
    """A 60 x 6 strip: parts of equal size (to one cell), each cut about as short as the strip is wide."""
    offsets, neighbours = grid_graph(60, 6)
    parts = partition_cells(offsets, neighbours, nparts)
    sizes = np.bincount(parts, minlength=nparts)
    assert sizes.max() - sizes.min() <= 1 and sizes.sum() == 360
    rows = np.repeat(np.arange(360), np.diff(offsets))
    cut = np.count_nonzero(parts[rows] != parts[neighbours]) // 2
    assert cut <= 2 * 6 * (nparts - 1)     # a straight cut across is 6 edges; a staircase up to twice that
    # and it is a function of the graph alone: the same parts every time
    assert np.array_equal(parts, partition_cells(offsets, neighbours, nparts))


def test_each_cell_goes_to_its_owner_then_to_the_parts_of_its_neighbours():
    # a chain 0-1-2-3 split 0,0 | 1,1: cells 1 and 2 are ghosts of the other part
    offsets = np.array([0, 1, 3, 5, 6])
    neighbours = np.array([1, 0, 2, 1, 3, 2])
    parts = np.array([0, 0, 1, 1], dtype=np.int32)
    dest_offsets, ranks = destinations(offsets, neighbours, parts, 2, ghosts=True)
    per_cell = [list(ranks[a:b]) for a, b in zip(dest_offsets[:-1], dest_offsets[1:])]
    assert per_cell == [[0], [0, 1], [1, 0], [1]]
    dest_offsets, ranks = destinations(offsets, neighbours, parts, 2, ghosts=False)
    assert list(dest_offsets) == [0, 1, 2, 3, 4] and list(ranks) == [0, 0, 1, 1]


def test_one_part_and_no_cells():
    offsets, neighbours = grid_graph(5, 5)
    assert not partition_cells(offsets, neighbours, 1).any()
    assert partition_cells(np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), 2).size == 0


def test_cell_centres_cut_a_long_body_straight_across_and_a_square_across_its_first_axis():
    """Coordinate bisection: a 60 x 6 strip of squares into 2, 3, 4 parts of equal size, each part a run
    of whole columns (the cut straight across, 6 edges); a square cut across x, the first axis."""
    offsets, neighbours = grid_graph(60, 6)
    column, row = np.meshgrid(np.arange(60) + 0.5, np.arange(6) + 0.5)   # (cell index = row * 60 + column)
    centres = np.column_stack([column.ravel(), row.ravel()])
    for nparts in (2, 3, 4):
        parts = partition_cells(offsets, neighbours, nparts, centres)
        sizes = np.bincount(parts, minlength=nparts)
        assert sizes.max() - sizes.min() <= 6 and sizes.sum() == 360
        # every column in one part, the parts in the order of x
        by_column = parts.reshape(6, 60)
        assert (by_column == by_column[0]).all() and np.all(np.diff(by_column[0]) >= 0)
    square, _ = np.meshgrid(np.arange(8) + 0.5, np.arange(8) + 0.5)
    centres = np.column_stack([square.ravel(), square.T.ravel()])
    parts = coordinate_bisection(centres, 2)
    assert np.array_equal(parts, (centres[:, 0] > 4.0).astype(np.int32))
    with pytest.raises(ValueError, match="3 cell centres for a graph of 360 cells"):
        partition_cells(offsets, neighbours, 2, centres[:3])


@pytest.mark.parametrize("shape", ["interval", "triangle", "quadrilateral", "tetrahedron", "hexahedron"])
def test_the_centres_given_for_a_built_mesh_follow_the_order_dolfinx_builds_its_cells_in(shape):
    """``_grid_centres`` against the cells dolfinx builds (their ``original_cell_index``): each cell lies in
    the grid square (cube) whose centre is given for it. An upgrade that changes the order fails here."""
    from mpi4py import MPI
    from dolfinx import mesh

    from fem_impact.fem.dolfinx_api import _grid_centres

    n, size = {"interval": ((5,), (2.5,)), "triangle": ((4, 3), (2.0, 1.5)), "quadrilateral": ((4, 3), (2.0, 1.5)),
               "tetrahedron": ((4, 3, 2), (2.0, 1.5, 1.0)), "hexahedron": ((4, 3, 2), (2.0, 1.5, 1.0))}[shape]
    comm = MPI.COMM_SELF
    if shape == "interval":
        msh, given = mesh.create_interval(comm, n[0], [0.0, size[0]]), _grid_centres(n, size, fastest=0)
    elif len(n) == 2:
        cell = getattr(mesh.CellType, shape)
        msh = mesh.create_rectangle(comm, [np.zeros(2), np.array(size)], list(n), cell_type=cell)
        hex = shape == "quadrilateral"
        given = _grid_centres(n, size, fastest=1 if hex else 0, per_square=1 if hex else 2)
    else:
        cell = getattr(mesh.CellType, shape)
        msh = mesh.create_box(comm, [np.zeros(3), np.array(size)], list(n), cell_type=cell)
        given = _grid_centres(n, size, fastest=0, per_square=1 if shape == "hexahedron" else 6)
    tdim = msh.topology.dim
    cells = msh.topology.index_map(tdim).size_local
    nodes = msh.geometry.dofmap.array.reshape(cells, -1)
    centres = np.empty((cells, tdim))
    centres[np.asarray(msh.topology.original_cell_index)] = msh.geometry.x[nodes].mean(axis=1)[:, :tdim]
    h = np.array(size) / np.array(n)
    assert given.shape == centres.shape
    assert np.array_equal(np.floor(centres / h), np.floor(given / h))
