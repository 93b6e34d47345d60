"""The two bases of the background grid, both tensor products of 1-D pieces.

* ``Q1``: bilinear Lagrange, one function per grid node (DOLFINx's own Q1 space).
* ``BSpline2``: quadratic B-splines on the uniform knots of the grid, clamped
  (open knot vector, the end knots repeated three times) at the walls, so the
  basis interpolates at the walls and is C1 inside. ``nx + 2`` functions per
  direction; functions ``i, i+1, i+2`` are non-zero in cell ``i``.

In one direction a basis is stored as polynomial coefficients per cell,
``N_a(xi) = sum_m c[i, a, m] xi**m`` for the ``k + 1`` functions non-zero in cell
``i`` (``xi`` in [0, 1]).

A tank that is not a whole number of cells has its last column (row) cut at the
face, ``last`` cells wide (:class:`fempm.grid.Grid`): the last knot span is then
``last h`` long (knots ``0, .., 0, 1, 2, .., n-1, n-1+last, .., n-1+last`` in cells),
which is the clamped basis of the tank itself, with as many functions, interpolating
at the face. Only the last cells' coefficients change (``xi`` in [0, last] there);
``xi`` keeps its scale ``h``, so jets, tabulation and the structured numbering do not.

The 2-D functions of a cell are the products, numbered ``a + (k + 1) * b`` locally
and ``(i + a) + nfx * (j + b)`` globally.

Derivatives are *jets*: ``d^(a+b) N / dxi^a deta^b`` in the cell's reference
coordinates, i.e. ``h^(a+b)`` times the physical derivative. The jet order is
listed by :func:`jet_indices`.
"""

from __future__ import annotations

import functools
from functools import cached_property

import numba
import numpy as np

from fempm.grid import Grid

__all__ = ["BASES", "Basis", "BSpline2", "Q1", "jet_indices"]

_NO_NUMBERS = np.zeros(0, dtype=np.int64)  # cell_functions without a renumbering


def jet_indices(order: int) -> list[tuple[int, int]]:
    """Multi-indices ``(a, b)`` of the jet of the given order, in fempm's order.

    Order 1 gives ``[(0, 0), (1, 0), (0, 1)]``: value, d/dxi, d/deta; order 2 adds
    ``(2, 0), (1, 1), (0, 2)``.
    """
    return [(a, s - a) for s in range(order + 1) for a in range(s, -1, -1)]


@numba.njit(cache=True, inline="always")
def _poly_derivatives(c, xi, order, powers, out):
    """Values and derivatives up to ``order`` at ``xi`` of polynomials ``c[a, m]``; ``powers``: room
    for ``xi ** m``, taken once for all the polynomials."""
    n_fun, n_coef = c.shape
    for m in range(n_coef):
        powers[m] = xi ** m
    for a in range(n_fun):
        for d in range(order + 1):
            s = 0.0
            for m in range(d, n_coef):
                f = 1.0
                for t in range(d):
                    f *= m - t
                s += f * c[a, m] * powers[m - d]
            out[d, a] = s


@functools.cache
def _jet_array(order: int) -> np.ndarray:
    """:func:`jet_indices` as an ``(n, 2)`` array (made once per order; read-only)."""
    jets = np.array(jet_indices(order), dtype=np.int64)
    jets.setflags(write=False)
    return jets


@numba.njit(cache=True)
def _cell_functions(cells, nx, nfx, offsets, numbers, out):
    """``out[p, l]``: the structured number of local function ``l`` of cell ``cells[p]`` (its first
    function ``i + nfx j`` plus ``offsets[l]``), or ``numbers`` of it unless that is empty."""
    renumber = numbers.shape[0] > 0
    for p in range(cells.shape[0]):
        first = cells[p] % nx + nfx * (cells[p] // nx)
        for l in range(offsets.shape[0]):
            out[p, l] = numbers[first + offsets[l]] if renumber else first + offsets[l]


@numba.njit(cache=True)
def _tabulate(cells, xi, nx, cx, cy, jets, out):
    """Jets of the (k+1)^2 cell functions at each point (see :meth:`Basis.tabulate`)."""
    k1 = cx.shape[1]
    order = 0
    for q in range(jets.shape[0]):
        order = max(order, jets[q, 0] + jets[q, 1])
    vx = np.empty((order + 1, k1))
    vy = np.empty((order + 1, k1))
    powers = np.empty(cx.shape[2])
    for p in range(cells.shape[0]):
        i = cells[p] % nx
        j = cells[p] // nx
        _poly_derivatives(cx[i], xi[p, 0], order, powers, vx)
        _poly_derivatives(cy[j], xi[p, 1], order, powers, vy)
        for q in range(jets.shape[0]):
            da, db = jets[q, 0], jets[q, 1]
            for b in range(k1):
                for a in range(k1):
                    out[p, q, a + k1 * b] = vx[da, a] * vy[db, b]


class Basis:
    """A tensor-product basis of degree ``k`` on a :class:`~fempm.grid.Grid`.

    Subclasses set ``degree``, ``lagrange_degree`` (the DOLFINx Lagrange space
    that contains the basis) and the per-direction coefficient tables.
    """

    degree: int
    lagrange_degree: int
    name: str

    def __init__(self, grid: Grid):
        self.grid = grid
        self.coef_x = self._coefficients(grid.nx, float(grid.last[0]))
        self.coef_y = self._coefficients(grid.ny, float(grid.last[1]))
        self.nfx = grid.nx + self.functions_per_direction_extra
        self.nfy = grid.ny + self.functions_per_direction_extra
        self.num_functions = self.nfx * self.nfy
        self.functions_per_cell = (self.degree + 1) ** 2

    functions_per_direction_extra: int

    def _coefficients(self, n: int, last: float) -> np.ndarray:
        """Per-cell polynomial coefficients of ``n`` cells, the last ``last`` cells wide."""
        raise NotImplementedError

    def knots(self, n: int, last: float = 1.0) -> np.ndarray:
        """The clamped knot vector (in cells) of ``n`` cells, the last ``last`` wide: the end knots
        repeated ``degree + 1`` times."""
        k = self.degree
        return np.concatenate([np.zeros(k), np.arange(n, dtype=np.float64), np.full(k + 1, n - 1 + last)])

    def greville(self, n: int, last: float = 1.0) -> np.ndarray:
        """The Greville points (in cells from the lower side) of the functions along a side of ``n`` cells: the
        means of ``degree`` consecutive knots. A linear function's coefficients are its values there."""
        t, k = self.knots(n, last), self.degree
        return np.array([t[j + 1: j + k + 1].mean() for j in range(n + k)])

    def side_integrals(self, n: int, last: float = 1.0) -> np.ndarray:
        """``int N_j`` (in cells) of the functions along a side of ``n`` cells: ``(t_{j+k+1} - t_j) / (k + 1)``."""
        t, k = self.knots(n, last), self.degree
        return (t[k + 1:] - t[: -(k + 1)]) / (k + 1)

    def cell_functions(self, cells, numbers: np.ndarray | None = None) -> np.ndarray:
        """Global (structured) indices of the functions non-zero in each cell, or ``numbers`` of them (an
        array indexed by structured index: a renumbering).

        Shape ``(n, (k+1)^2)``, local number ``a + (k+1) * b``.
        """
        cells = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1)
        numbers = _NO_NUMBERS if numbers is None else numbers
        out = np.empty((len(cells), self.functions_per_cell), dtype=numbers.dtype)
        _cell_functions(cells, self.grid.nx, self.nfx, self._cell_offsets, numbers, out)
        return out

    @cached_property
    def _cell_offsets(self) -> np.ndarray:
        """``a + nfx * b`` of local function ``a + (k+1) * b``: its number less its cell's first."""
        k1 = self.degree + 1
        return np.tile(np.arange(k1), k1) + self.nfx * np.repeat(np.arange(k1), k1)

    def tabulate(self, cells, xi, order: int = 1) -> np.ndarray:
        """Jets of the cell functions at points given by cell and reference coordinates.

        Returns:
            Array ``(n, len(jet_indices(order)), (k+1)^2)``; entry ``[p, q, l]`` is
            derivative ``jet_indices(order)[q]`` (in reference coordinates) of local
            function ``l`` of cell ``cells[p]`` at ``xi[p]``.
        """
        cells = np.ascontiguousarray(cells, dtype=np.int64)
        xi = np.ascontiguousarray(xi, dtype=np.float64).reshape(-1, 2)
        jets = _jet_array(order)
        out = np.empty((cells.shape[0], len(jets), self.functions_per_cell))
        _tabulate(cells, xi, self.grid.nx, self.coef_x, self.coef_y, jets, out)
        return out

    def anchor_cell(self, functions) -> np.ndarray:
        """A cell inside the support of each function (the one whose owner owns it)."""
        f = np.asarray(functions, dtype=np.int64)
        half = self.degree // 2
        i = np.clip(f % self.nfx - half, 0, self.grid.nx - 1)
        j = np.clip(f // self.nfx - half, 0, self.grid.ny - 1)
        return i + self.grid.nx * j

    @cached_property
    def integrals(self) -> np.ndarray:
        """``int N_i dx`` over the tank for every function, exact (Gauss; in a cut cell over its part)."""
        return self._gauss_integrals(blocked=True)

    def open_integrals(self) -> np.ndarray:
        """``int N_i dx`` over the cells no obstacle blocks, exact."""
        return self._gauss_integrals(blocked=False)

    def _gauss_integrals(self, blocked: bool) -> np.ndarray:
        """``int N_i dx`` by Gauss quadrature (``blocked``: over the obstacles' cells too)."""
        pts, wts = np.polynomial.legendre.leggauss(self.degree + 1)
        return self._integrals(0.5 * (pts + 1.0), 0.5 * wts, blocked)

    def lattice_integrals(self, per_cell: int, blocked: bool = True) -> np.ndarray:
        """``int N_i dx`` by the rule of ``per_cell x per_cell`` particles at sub-cell centres (``blocked``:
        over the obstacles' cells too, else over the open cells alone).

        What a uniformly seeded material gives for ``sum_p V_p N_i(x_p)`` over a full
        grid: with it the smoothed density of undisturbed seeded particles is exactly
        their density, also for the wall B-splines, which the midpoint rule does not
        integrate exactly. A cut cell has its own lattice, shrunk onto it, as seeding does.
        """
        return self._integrals((np.arange(per_cell) + 0.5) / per_cell, np.full(per_cell, 1.0 / per_cell), blocked)

    def _integrals(self, pts_1d, wts_1d, blocked: bool = True) -> np.ndarray:
        """``sum`` over cells (``blocked``: the obstacles' too) and points of ``w N_i(xi)`` (a rule on the
        unit square, times ``h^2``; in a cut cell shrunk onto it)."""
        grid = self.grid
        xi = np.stack(np.meshgrid(pts_1d, pts_1d, indexing="ij"), -1).reshape(-1, 2)
        w = np.outer(wts_1d, wts_1d).ravel() * grid.h**2
        chosen = np.arange(grid.num_cells) if blocked else np.flatnonzero(~grid.blocked)
        cells = np.repeat(chosen, len(w))
        xi, w = np.tile(xi, (len(chosen), 1)), np.tile(w, len(chosen))
        if grid.cut:
            width = grid.cell_sizes(cells) / grid.h  # 1, or the cut's width in cells
            xi, w = xi * width, w * width.prod(axis=1)
        values = self.tabulate(cells, xi, order=0)[:, 0, :]
        out = np.zeros(self.num_functions)
        np.add.at(out, self.cell_functions(cells), values * w[:, None])
        return out


class Q1(Basis):
    """Bilinear Lagrange functions on the grid nodes."""

    degree = 1
    lagrange_degree = 1
    name = "Q1"
    functions_per_direction_extra = 1

    def _coefficients(self, n: int, last: float) -> np.ndarray:
        c = np.zeros((n, 2, 2))
        c[:, 0] = [1.0, -1.0]  # 1 - xi
        c[:, 1] = [0.0, 1.0]  # xi
        c[-1] = [[1.0, -1.0 / last], [0.0, 1.0 / last]]  # the last node on the face
        return c


def _bspline_values(knots: np.ndarray, degree: int, t: np.ndarray) -> np.ndarray:
    """All B-splines of an open knot vector at points ``t`` (Cox-de Boor), shape (n, m)."""
    n_fun = len(knots) - degree - 1
    last = knots[-1]
    # degree 0: indicator of [t_i, t_{i+1}); the last non-empty span is closed.
    b = np.zeros((len(t), len(knots) - 1))
    for i in range(len(knots) - 1):
        if knots[i + 1] > knots[i]:
            inside = (t >= knots[i]) & ((t < knots[i + 1]) | ((knots[i + 1] == last) & (t == last)))
            b[inside, i] = 1.0
    for p in range(1, degree + 1):
        nb = np.zeros((len(t), len(knots) - 1 - p))
        for i in range(len(knots) - 1 - p):
            d1 = knots[i + p] - knots[i]
            d2 = knots[i + p + 1] - knots[i + 1]
            if d1 > 0:
                nb[:, i] += (t - knots[i]) / d1 * b[:, i]
            if d2 > 0:
                nb[:, i] += (knots[i + p + 1] - t) / d2 * b[:, i + 1]
        b = nb
    return b[:, :n_fun]


class BSpline2(Basis):
    """Quadratic B-splines, clamped at the walls, C1 across interior cell edges."""

    degree = 2
    lagrange_degree = 2
    name = "B-spline"
    functions_per_direction_extra = 2

    def _coefficients(self, n: int, last: float) -> np.ndarray:
        knots = self.knots(n, last)
        samples = np.array([0.25, 0.5, 0.75])  # inside the span: no end-point ambiguity
        c = np.zeros((n, 3, 3))
        # cells 2 .. n-3 see only simple knots of unit spacing (a cut last span reaches back to
        # cell n-2 only): all alike, so compute the two cells at each wall and one interior cell
        # (each evaluation costs O(n))
        explicit = sorted({i for i in (0, 1, 2, n - 2, n - 1) if 0 <= i < n}) if n > 5 else range(n)
        for i in explicit:
            span = last if i == n - 1 else 1.0
            values = _bspline_values(knots, 2, i + span * samples)[:, i : i + 3]  # (samples, functions)
            c[i] = (np.linalg.inv(np.vander(span * samples, 3, increasing=True)) @ values).T
        if n > 5:
            c[3 : n - 2] = c[2]
        return c


#: The bases by the name scenes and command lines use (each class's ``name`` is its label in tables).
BASES: dict[str, type[Basis]] = {"bspline": BSpline2, "q1": Q1}
