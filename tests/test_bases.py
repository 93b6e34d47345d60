"""The Q1 and quadratic B-spline bases against independent references."""

import numpy as np
import pytest
from scipy.interpolate import BSpline

import fempm
from fempm.bases import jet_indices


def _grid(comm):
    return fempm.Grid(comm, (0.0, 0.0), (1.4, 0.8), 0.2)  # 7 x 4 cells


def _cut_grid(comm):
    return fempm.Grid(comm, (0.0, 0.0), (1.33, 0.71), 0.2)  # 7 x 4 cells, the last 0.65 h wide, 0.55 h high


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
@pytest.mark.parametrize("cut", [False, True])
def test_partition_of_unity_and_non_negativity(comm, Basis, cut):
    grid = _cut_grid(comm) if cut else _grid(comm)
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


# -- a tank that is not a whole number of cells: the last column and row cut at the faces --------------
def _cut_knots(n_cells, h, length):
    return np.concatenate([[0, 0], np.arange(n_cells) * h, [length] * 3])


def _scipy_cut_bspline_1d(n_cells, h, length, t, deriv):
    """All clamped quadratic B-splines on the knots 0, 0, 0, h, .., (n-1) h, L, L, L, by scipy."""
    knots = _cut_knots(n_cells, h, length)
    out = np.zeros((len(t), n_cells + 2))
    for i in range(n_cells + 2):
        out[:, i] = BSpline.basis_element(knots[i : i + 4], extrapolate=False)(t, nu=deriv)
    return np.nan_to_num(out)


def test_cut_grid_covers_the_tank(comm):
    grid = _cut_grid(comm)
    assert (grid.nx, grid.ny) == (7, 4) and grid.cut
    np.testing.assert_allclose(grid.last, [0.65, 0.55], rtol=1e-12)
    x = grid.mesh.geometry.x[:, :2]  # the DOLFINx mesh's last vertices lie on the faces
    assert x[:, 0].max() == 1.33 and x[:, 1].max() == 0.71
    points = np.array([[1.33, 0.71], [1.33 + 1e-6, 0.3], [0.5, 0.71 + 1e-6]])
    assert grid.outside(points).tolist() == [False, True, True]
    cells, xi = grid.locate(np.array([[1.33, 0.71]]))
    assert cells[0] == grid.num_cells - 1 and xi[0] == pytest.approx([0.65, 0.55], rel=1e-12)


def test_cut_bspline_matches_scipy_values_and_derivatives(comm):
    """The cut basis is the clamped basis of the tank's own knot vector (scipy, independent code)."""
    grid = _cut_grid(comm)
    basis = fempm.BSpline2(grid)
    x = _random_points(grid, 2000)
    x[:200, 0] = grid.upper[0] - 0.13 * np.random.default_rng(3).random(200)  # many in the cut column
    cells, xi = grid.locate(x)
    jets = basis.tabulate(cells, xi, order=2)
    functions = basis.cell_functions(cells)
    fi, fj = functions % basis.nfx, functions // basis.nfx
    rows = np.arange(len(x))[:, None]
    worst = 0.0
    for q, (a, b) in enumerate(jet_indices(2)):
        bx = _scipy_cut_bspline_1d(grid.nx, grid.h, 1.33, x[:, 0], a)
        by = _scipy_cut_bspline_1d(grid.ny, grid.h, 0.71, x[:, 1], b)
        expected = bx[rows, fi] * by[rows, fj] * grid.h ** (a + b)
        worst = max(worst, np.abs(jets[:, q] - expected).max())
        # no function outside the cell's three per direction is non-zero there
        assert np.abs(bx.sum(axis=1) - bx[rows, fi].reshape(len(x), 3, 3)[:, 0].sum(axis=1)).max() < 1e-12
    assert worst < 1e-12  # measured 9.9e-14 (second derivatives times h^2)


def test_cut_q1_matches_hat_functions(comm):
    grid = _cut_grid(comm)
    basis = fempm.Q1(grid)
    x = _random_points(grid, 1000)
    cells, xi = grid.locate(x)
    phi = basis.tabulate(cells, xi, order=0)[:, 0]
    functions = basis.cell_functions(cells)
    nodes_x, nodes_y = np.append(np.arange(7) * 0.2, 1.33), np.append(np.arange(4) * 0.2, 0.71)
    hat = lambda nodes, t, i: np.interp(t, nodes, np.eye(len(nodes))[i])  # noqa: E731
    expected = np.array([[hat(nodes_x, x[p, 0], f % basis.nfx) * hat(nodes_y, x[p, 1], f // basis.nfx)
                          for f in functions[p]] for p in range(len(x))])
    assert np.abs(phi - expected).max() < 1e-12  # measured 1.9e-15


@pytest.mark.parametrize("Basis", [fempm.Q1, fempm.BSpline2])
def test_cut_basis_is_c1_and_interpolates_at_the_cut_faces(comm, Basis):
    grid = _cut_grid(comm)
    basis = Basis(grid)
    coefficients = np.random.default_rng(2).random(basis.num_functions)

    def jets(x):
        cells, xi = grid.locate(x)
        phi = basis.tabulate(cells, xi, order=1)
        return phi, np.einsum("pql,pl->pq", phi, coefficients[basis.cell_functions(cells)]) / [1, grid.h, grid.h]

    # across the edge into the cut column: the value (and for the B-spline the gradient) continuous
    y = np.linspace(0.01, 0.7, 9)
    edge = 6 * grid.h
    _, left = jets(np.column_stack([np.full_like(y, edge - 1e-9), y]))
    _, right = jets(np.column_stack([np.full_like(y, edge + 1e-9), y]))
    assert np.abs(left[:, 0] - right[:, 0]).max() < 1e-7  # measured 6.1e-9 (the 2e-9 step times the slope)
    if Basis is fempm.BSpline2:
        assert np.abs(left - right).max() < 1e-6  # measured 1.5e-7 (the step times the curvature)
    # on the right face only the last function of each row is non-zero
    phi, _ = jets(np.column_stack([np.full_like(y, 1.33), y]))
    cells, _ = grid.locate(np.column_stack([np.full_like(y, 1.33), y]))
    on_face = basis.cell_functions(cells) % basis.nfx == basis.nfx - 1
    assert np.abs(np.where(on_face, 0.0, phi[:, 0])).max() < 1e-14
    phi, _ = jets(np.array([[1.33, 0.71]]))
    assert phi[0, 0, -1] == pytest.approx(1.0, abs=1e-14)  # the corner function at the corner


@pytest.mark.parametrize("Basis", [fempm.Q1, fempm.BSpline2])
def test_cut_integrals_cover_the_tank(comm, Basis):
    grid = _cut_grid(comm)
    basis = Basis(grid)
    assert basis.integrals.sum() == pytest.approx(1.33 * 0.71, rel=1e-14)
    assert basis.integrals.min() > 0
    # the lattice rule of seeding, a cut cell's lattice shrunk onto it: its weights fill the tank too
    assert basis.lattice_integrals(2).sum() == pytest.approx(1.33 * 0.71, rel=1e-14)
    # a B-spline of degree k on knots t_i .. t_{i+k+1} integrates to (t_{i+k+1} - t_i) / (k + 1)
    k = basis.degree

    def exact(n, length):
        knots = np.concatenate([[0.0] * k, np.arange(n) * grid.h, [length] * (k + 1)])
        return (knots[k + 1:] - knots[: -k - 1]) / (k + 1)

    reference = np.outer(exact(grid.ny, 0.71), exact(grid.nx, 1.33)).ravel()
    assert np.abs(basis.integrals - reference).max() / grid.h**2 < 1e-14  # measured 5.2e-16


def _coefficients_before_cut_cells(Basis, n):
    """The coefficient tables as fempm computed them before tanks could be cut (a copy of that code)."""
    from fempm.bases import _bspline_values

    if Basis is fempm.Q1:
        c = np.zeros((n, 2, 2))
        c[:, 0] = [1.0, -1.0]
        c[:, 1] = [0.0, 1.0]
        return c
    knots = np.concatenate([[0.0, 0.0], np.arange(n + 1.0), [n, n]])
    samples = np.array([0.25, 0.5, 0.75])
    vandermonde_inv = np.linalg.inv(np.vander(samples, 3, increasing=True))
    c = np.zeros((n, 3, 3))
    explicit = sorted({i for i in (0, 1, 2, n - 2, n - 1) if 0 <= i < n}) if n > 5 else range(n)
    for i in explicit:
        values = _bspline_values(knots, 2, i + samples)[:, i : i + 3]
        c[i] = (vandermonde_inv @ values).T
    if n > 5:
        c[3 : n - 2] = c[2]
    return c


@pytest.mark.parametrize("Basis", [fempm.Q1, fempm.BSpline2])
@pytest.mark.parametrize("n", [1, 3, 7, 40])
def test_a_whole_number_of_cells_gives_the_uncut_basis_bit_for_bit(comm, Basis, n):
    grid = fempm.Grid(comm, (0.0, 0.0), (0.0146 * n, 0.0146 * max(n, 2)), 0.0146)
    assert not grid.cut and grid.last.tolist() == [1.0, 1.0]
    basis = Basis(grid)
    assert np.array_equal(basis.coef_x, _coefficients_before_cut_cells(Basis, n))
    assert np.array_equal(basis.coef_y, _coefficients_before_cut_cells(Basis, max(n, 2)))
