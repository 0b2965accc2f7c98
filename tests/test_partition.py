"""The reproducible distribution of cells over ranks (fem_impact/fem/partition.py)."""

import numpy as np
import pytest

from fem_impact.fem.partition import destinations, partition_cells


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
