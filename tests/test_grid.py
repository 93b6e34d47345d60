"""The background grid: arithmetic point location and its errors."""

import numpy as np
import pytest

import fempm
from fempm.errors import InputError, ParticleOutsideGridError
from fempm.grid import touches_only


def test_locate_matches_cell_geometry(comm):
    grid = fempm.Grid(comm, (-1.0, 0.5), (2.0, 2.0), 0.25)
    assert (grid.nx, grid.ny) == (12, 6)
    rng = np.random.default_rng(0)
    x = grid.lower + rng.random((1000, 2)) * (grid.upper - grid.lower)
    cells, xi = grid.locate(x)
    np.testing.assert_allclose(grid.cell_origin(cells) + grid.h * xi, x, rtol=0, atol=1e-14)
    assert np.all((xi >= 0) & (xi <= 1))


def test_points_on_walls_belong_to_the_grid(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    cells, xi = grid.locate(np.array([[1.0, 1.0], [0.0, 0.0], [1.0, 0.35]]))
    assert cells.tolist() == [99, 0, 39]
    np.testing.assert_allclose(xi[0], [1.0, 1.0])


def test_every_cell_has_exactly_one_owner(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (2.0, 1.0), 0.125)
    counts = np.zeros(grid.num_cells, dtype=np.int64)
    counts[grid.owned_cells] = 1
    total = comm.allreduce(counts)
    assert np.all(total == 1)
    assert np.all(grid.owner[grid.owned_cells] == comm.rank)
    # the structured numbering agrees with the DOLFINx cells' midpoints
    import dolfinx.mesh

    mid = dolfinx.mesh.compute_midpoints(grid.mesh, 2, grid.local_cell[grid.owned_cells])
    np.testing.assert_allclose(grid.cell_origin(grid.owned_cells) + grid.h / 2, mid[:, :2], atol=1e-14)


def test_outside_point_names_the_particle(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    with pytest.raises(ParticleOutsideGridError, match=r"particle 7 at \(1\.5, 0\.5\) is outside"):
        grid.locate(np.array([[1.5, 0.5]]), ids=np.array([7]))
    with pytest.raises(ParticleOutsideGridError, match="particle 3"):
        grid.locate(np.array([[np.nan, 0.5]]), ids=np.array([3]))


@pytest.mark.parametrize(
    "lower, upper, cells, message",
    [
        ((0, 0), (1.0, 1.0), (10, 5), "cells must be square"),
        ((0, 0), (1.0, 1.0), (0, 5), "number of cells must be positive"),
    ],
)
def test_non_square_cells_are_refused(comm, lower, upper, cells, message):
    with pytest.raises(InputError, match=message):
        fempm.Grid.from_cells(comm, lower, upper, cells)


@pytest.mark.parametrize(
    "upper, h, message",
    [((1.0, 1.0), -0.1, "must be positive"), ((0.0, 1.0), 0.1, "must exceed lower"),
     ((1.0, 0.5), 0.6, r"the cell size h = 0.6 exceeds the height \(0.5\)"),
     ((1.01, 1.0), 0.1, r"the width 1.01 in cells of h = 0.1 leaves a last cell 0.1 h thin \(0.01\), less than 0.25 h, "
                        r"too thin to hold the wall: take h = 0.0918182 or 0.101 \(11 or 10 whole cells\)")],
)
def test_bad_grid_sizes_are_refused(comm, upper, h, message):
    with pytest.raises(InputError, match=message):
        fempm.Grid(comm, (0.0, 0.0), upper, h)


def test_a_tank_not_a_whole_number_of_cells_has_its_last_column_and_row_cut(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.3)
    assert (grid.nx, grid.ny) == (4, 4) and grid.last == pytest.approx([1 / 3, 1 / 3], rel=1e-12)
    assert grid.cell_sizes([0, 3, 15]) == pytest.approx(np.array([[0.3, 0.3], [0.1, 0.3], [0.1, 0.1]]), rel=1e-12)
    # cells = [nx, ny]: h from the width, the rows covering the height, the top one cut
    grid = fempm.Grid.from_cells(comm, (0.0, 0.0), (1.0, 0.75), (10, 8))
    assert grid.h == pytest.approx(0.1) and grid.last == pytest.approx([1.0, 0.5], rel=1e-12)
    with pytest.raises(InputError, match=r"with h = 0.1 the height takes 8 rows"):
        fempm.Grid.from_cells(comm, (0.0, 0.0), (1.0, 0.75), (10, 7))


@pytest.mark.mpi
def test_weighted_partition_shares_a_corner_column_between_ranks(comm):
    """Water in the lower-left eighth of a tank: weighted bisection gives every rank its share."""
    weights = np.zeros((40, 40))
    weights[:20, :10] = 4.0  # the dam break's column, 4 particles per cell
    grid = fempm.Grid.from_cells(comm, (0.0, 0.0), (0.584, 0.584), (40, 40), weights=weights)
    mine = weights.ravel()[grid.owned_cells].sum()
    shares = comm.allgather(mine)
    assert sum(shares) == 800
    assert max(shares) - min(shares) <= 4 * 20  # at most one column of the water apart
    counts = np.zeros(grid.num_cells, dtype=np.int64)
    counts[grid.owned_cells] = 1
    assert np.all(comm.allreduce(counts) == 1)


def test_bisection_splits_weight_in_proportion():
    from fempm.grid import bisect

    weights = np.ones((6, 9))
    part = bisect(weights, 3)
    assert sorted(np.bincount(part.ravel())) == [18, 18, 18]


def test_a_point_touches_only_marked_cells_when_every_cell_at_its_edges_is_marked():
    """``touches_only``: inside a block of marked cells, yes; on its face or at a corner shared with an open cell,
    no (the point touches that open cell too); round-off off an edge counts as on it."""
    marked = np.zeros(4 * 3, dtype=bool)
    marked[[1, 2, 5, 6]] = True  # columns 1-2, rows 0-1 of a 4 x 3 grid of cells of 0.5 from (0, 0)
    points = [(0.75, 0.25), (1.0, 0.5), (0.5, 0.5), (1.5 - 1e-12, 0.25), (0.5, 1.0), (1.25, 0.75), (1.75, 0.25)]
    got = touches_only(points, (0.0, 0.0), 0.5, (4, 3), marked)
    assert got.tolist() == [True, True, False, False, False, True, False]
