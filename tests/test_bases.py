"""The Q1 and quadratic B-spline bases against independent references."""

import numpy as np
import pytest
from scipy.interpolate import BSpline

import fempm
from fempm.bases import jet_indices


def _grid(comm):
    return fempm.Grid(comm, (0.0, 0.0), (1.4, 0.8), 0.2)  # 7 x 4 cells


def _random_points(grid, n, seed=1):
    rng = np.random.default_rng(seed)
    return grid.lower + rng.random((n, 2)) * (grid.upper - grid.lower)


def _scipy_bspline_1d(n_cells, h, t, deriv):
    """All clamped quadratic B-splines of n_cells spans at t, by scipy (independent code)."""
    knots = np.concatenate([[0, 0], np.arange(n_cells + 1), [n_cells, n_cells]]) * h
    n_fun = n_cells + 2
    out = np.zeros((len(t), n_fun))
    for i in range(n_fun):
        c = np.zeros(n_fun)
        c[i] = 1.0
        out[:, i] = BSpline(knots, c, 2, extrapolate=False)(t, nu=deriv)
    return np.nan_to_num(out)


@pytest.mark.parametrize("Basis", [fempm.Q1, fempm.BSpline2])
def test_partition_of_unity_and_non_negativity(comm, Basis):
    grid = _grid(comm)
    basis = Basis(grid)
    cells, xi = grid.locate(_random_points(grid, 2000))
    jets = basis.tabulate(cells, xi, order=2)
    np.testing.assert_allclose(jets[:, 0].sum(axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(jets[:, 1:].sum(axis=2), 0.0, atol=1e-12)
    assert jets[:, 0].min() >= -1e-15


def test_bspline_matches_scipy_values_and_derivatives(comm):
    grid = _grid(comm)
    basis = fempm.BSpline2(grid)
    x = _random_points(grid, 500)
    cells, xi = grid.locate(x)
    jets = basis.tabulate(cells, xi, order=2)
    functions = basis.cell_functions(cells)
    for q, (a, b) in enumerate(jet_indices(2)):
        bx = _scipy_bspline_1d(grid.nx, grid.h, x[:, 0], a)
        by = _scipy_bspline_1d(grid.ny, grid.h, x[:, 1], b)
        fi, fj = functions % basis.nfx, functions // basis.nfx
        rows = np.arange(len(x))[:, None]
        expected = bx[rows, fi] * by[rows, fj] * grid.h ** (a + b)  # reference derivatives
        np.testing.assert_allclose(jets[:, q], expected, atol=1e-12)


def test_bspline_is_c1_across_cell_edges(comm):
    grid = _grid(comm)
    basis = fempm.BSpline2(grid)
    coefficients = np.random.default_rng(2).random(basis.num_functions)

    def jets(cells, xi):
        phi = basis.tabulate(cells, xi, order=1)
        return np.einsum("pql,pl->pq", phi, coefficients[basis.cell_functions(cells)])

    # every interior vertical edge, evaluated from the cell on its left and on its right
    y = np.linspace(0.01, 0.79, 9)
    row, eta = np.floor(y / grid.h).astype(int), (y / grid.h) % 1
    for i in range(1, grid.nx):
        from_left = jets(grid.cell_index(i - 1, row), np.column_stack([np.ones_like(y), eta]))
        from_right = jets(grid.cell_index(i, row), np.column_stack([np.zeros_like(y), eta]))
        np.testing.assert_allclose(from_left, from_right, atol=1e-12)  # value and gradient


def test_bspline_interpolates_at_the_walls(comm):
    grid = _grid(comm)
    basis = fempm.BSpline2(grid)
    y = np.linspace(0.0, 0.8, 17)
    x = np.column_stack([np.zeros_like(y), y])
    cells, xi = grid.locate(x)
    values = basis.tabulate(cells, xi, order=0)[:, 0]
    functions = basis.cell_functions(cells)
    on_wall = functions % basis.nfx == 0
    # only the wall functions are non-zero on the wall, and they sum to one
    np.testing.assert_allclose(np.where(on_wall, 0, values), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.where(on_wall, values, 0).sum(axis=1), 1.0, atol=1e-14)
    # at the corner the corner function is one
    cells, xi = grid.locate(np.array([[0.0, 0.0]]))
    assert basis.tabulate(cells, xi, order=0)[0, 0, 0] == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("Basis", [fempm.Q1, fempm.BSpline2])
def test_integrals_of_the_basis(comm, Basis):
    grid = _grid(comm)
    basis = Basis(grid)
    assert basis.integrals.sum() == pytest.approx(1.4 * 0.8, rel=1e-14)
    interior = basis.integrals.reshape(basis.nfy, basis.nfx)[3, 3]
    assert interior == pytest.approx(grid.h**2, rel=1e-14)
