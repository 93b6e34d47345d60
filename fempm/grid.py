"""The background grid: a structured, axis-aligned mesh of square quadrilaterals.

Cells are numbered structurally, ``cell = i + nx * j`` with ``(i, j)`` the column
and row counted from the lower-left corner. A point is located by arithmetic,
``i = floor((x - x0) / h)``, in O(1) per point. The DOLFINx mesh of the same cells
is distributed over the ranks by DOLFINx's partitioner; ``owner`` and
``local_cell`` translate between the structured numbering and DOLFINx's.

**Any tank size.** The cells are squares of size ``h`` laid from the lower-left corner;
where a side of the tank is not a whole number of cells, the last column (row) is cut
at the tank's face: ``nx = ceil(width / h)`` cells, the last ``last[0] h`` wide
(``0 < last <= 1``, 1 for a whole number). The DOLFINx mesh's last vertex column lies
on the face, so its cells are the tank's; the bases end their knots there
(:mod:`fempm.bases`), and the walls stay on the faces.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from mpi4py import MPI

import dolfinx.mesh

from fempm.errors import InputError, ParticleOutsideGridError

__all__ = ["Grid", "cell_counts", "cell_shares", "last_widths", "square_cell_size", "touches_only"]

# Points within this fraction of a cell outside the grid (round-off of a
# position on a wall) are taken to lie on the wall.
_WALL_TOLERANCE = 1e-10


#: The thinnest cut cell accepted, in cells. The wall's basis function lives in the cut cell alone,
#: and the grid pressure on a cut face falls as the cut thins (measured in the README, "Scenes").
MIN_CUT = 0.25


def _covering(length: float, h: float, name: str) -> tuple[int, float]:
    """Cells of size ``h`` covering ``length`` from its start, and the last one's width in cells
    (1 when ``length`` is a whole number of cells, to a relative 1e-9)."""
    n = round(length / h)
    if n >= 1 and abs(n * h - length) <= 1e-9 * length:
        return int(n), 1.0
    if h > length:
        raise InputError(f"grid: the cell size h = {h:g} exceeds the {name} ({length:g})")
    n = math.ceil(length / h)
    last = (length - (n - 1) * h) / h
    if last < MIN_CUT:
        raise InputError(f"grid: the {name} {length:g} in cells of h = {h:g} leaves a last cell {last:.3g} h thin "
                         f"({last * h:.3g}), less than {MIN_CUT:g} h, too thin to hold the wall: take h = "
                         f"{length / n:.6g} or {length / (n - 1):.6g} ({n} or {n - 1} whole cells), or a cut of at "
                         f"least {MIN_CUT:g} h")
    return int(n), last


def _box(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    if lower.shape != (2,) or upper.shape != (2,):
        raise InputError("grid: lower and upper must be pairs (x, y)")
    if np.any(upper <= lower):
        raise InputError(f"grid: upper {upper.tolist()} must exceed lower {lower.tolist()}")
    return lower, upper


def _sides(lower, upper, h: float) -> tuple[tuple[int, float], tuple[int, float]]:
    lower, upper = _box(lower, upper)
    if not (np.isfinite(h) and h > 0):
        raise InputError(f"grid: the cell size h must be positive, got {h}")
    return _covering(upper[0] - lower[0], h, "width"), _covering(upper[1] - lower[1], h, "height")


def cell_counts(lower, upper, h: float) -> tuple[int, int]:
    """Cells per direction of square cells of size ``h`` covering ``[lower, upper]`` (the last
    column and row cut at the tank's faces where a side is not a whole number of cells).

    Raises:
        InputError: ``h`` is not positive or exceeds a side, or ``upper`` does not exceed ``lower``.
    """
    (nx, _), (ny, _) = _sides(lower, upper, h)
    return nx, ny


def last_widths(lower, upper, h: float) -> tuple[float, float]:
    """The width of the last column and the height of the last row, in cells: in (0, 1], 1 uncut."""
    (_, rx), (_, ry) = _sides(lower, upper, h)
    return rx, ry


def square_cell_size(lower, upper, cells) -> float:
    """The size of the cells when ``cells = (nx, ny)`` cover ``[lower, upper]``.

    The cells are square, ``h = width / nx``; the height is a whole number of them, or
    ``ny`` is the number of rows covering it, ``ceil(height / h)``, the top row cut.
    """
    lower, upper = _box(lower, upper)
    nx, ny = (int(n) for n in cells)
    if nx < 1 or ny < 1:
        raise InputError(f"grid: the number of cells must be positive, got {cells}")
    h = (upper[0] - lower[0]) / nx
    rows, _ = _covering(upper[1] - lower[1], h, "height") if h <= upper[1] - lower[1] else (0, 0.0)
    if rows != ny:
        raise InputError(
            f"grid: cells must be square, but {nx} x {ny} cells over "
            f"{upper[0] - lower[0]:g} x {upper[1] - lower[1]:g} give hx = {h:g}, "
            f"hy = {(upper[1] - lower[1]) / ny:g} (with h = {h:g} the height takes {rows} rows)"
        )
    return h


def cell_shares(cells, counts, last) -> np.ndarray:
    """Width and height of structured cells in cells, ``(n, 2)``: 1, or ``last`` in the last column
    or row of a grid of ``counts = (nx, ny)`` cells (:attr:`Grid.last`)."""
    cells = np.asarray(cells)
    ij = np.stack([cells % counts[0], cells // counts[0]], axis=-1)
    return np.where(ij == np.asarray(counts) - 1, np.asarray(last, dtype=np.float64), 1.0)


#: A point this close to a cell's edge (in cells) touches the cell beyond it too.
_EDGE = 1e-9


def touches_only(points, lower, h: float, counts, marked: np.ndarray) -> np.ndarray:
    """Whether every cell each point ``(n, 2)`` touches (its own, and those whose edge it lies on to
    round-off) is ``marked`` (a boolean per structured cell of ``counts = (nx, ny)`` cells of size ``h``
    from ``lower``): e.g. a point inside an obstacle, not on its face."""
    nx, ny = counts
    u = (np.asarray(points, dtype=float).reshape(-1, 2) - np.asarray(lower)) / h
    top = np.array([nx - 1, ny - 1])
    low = np.clip(np.floor(u - _EDGE), 0, top).astype(np.int64)
    high = np.clip(np.floor(u + _EDGE), 0, top).astype(np.int64)
    out = np.ones(len(u), dtype=bool)
    for i in (low[:, 0], high[:, 0]):
        for j in (low[:, 1], high[:, 1]):
            out &= marked[i + nx * j]
    return out


def bisect(weights: np.ndarray, parts: int) -> np.ndarray:
    """Recursive coordinate bisection of a ``(ny, nx)`` array of cell weights into ``parts``.

    Each cut goes across the longer side of the current block, where the weight on one
    side is proportional to the number of parts it gets. Returns the part of every cell.
    """
    part = np.zeros(weights.shape, dtype=np.int32)

    def split(rows: slice, cols: slice, first: int, count: int):
        if count == 1:
            part[rows, cols] = first
            return
        block = weights[rows, cols]
        left = count // 2
        axis = 1 if block.shape[1] >= block.shape[0] else 0  # cut across the longer side
        profile = np.concatenate([[0.0], np.cumsum(block.sum(axis=1 - axis))])  # weight left of each cut
        target = profile[-1] * left / count
        cut = int(np.argmin(np.abs(profile[1:-1] - target))) + 1 if block.shape[axis] > 1 else 0
        start = (cols if axis else rows).start
        low, high = slice(start, start + cut), slice(start + cut, start + block.shape[axis])
        if axis:
            split(rows, low, first, left), split(rows, high, first + left, count - left)
        else:
            split(low, cols, first, left), split(high, cols, first + left, count - left)

    split(slice(0, weights.shape[0]), slice(0, weights.shape[1]), 0, parts)
    return part


class Grid:
    """A rectangle ``[x0, x1] x [y0, y1]`` cut into square cells of size ``h``.

    Args:
        comm: MPI communicator the DOLFINx mesh is distributed over.
        lower: ``(x0, y0)``.
        upper: ``(x1, y1)``.
        h: cell size, at most the width and the height; where a side is not a whole multiple
            of it, the last column or row is cut at the tank's face (see the module).
        weights: work expected in each structured cell (e.g. its particles), to share
            the cells between the ranks by weighted recursive coordinate bisection.
            Default: DOLFINx's graph partitioner, which shares cells by number, so
            water filling a corner of a tank would sit on one rank.

    Attributes:
        mesh: the DOLFINx quadrilateral mesh.
        nx, ny: cells per direction.
        last: ``(width of the last column, height of the last row)`` in cells, each in (0, 1]
            (1: the side is a whole number of cells).
        cut: whether a side is cut (``last < 1`` in either direction).
        owner: ``owner[cell]`` is the rank owning each structured cell.
        local_cell: ``local_cell[cell]`` is the local DOLFINx cell index on this
            rank, or -1 where this rank does not own the cell.
        owned_cells: structured indices of the cells this rank owns, in DOLFINx's
            local order.
        blocked: ``blocked[cell]`` is True for the cells of rigid obstacles (see
            :meth:`block`); no material may enter them.
    """

    def __init__(self, comm: MPI.Comm, lower, upper, h: float, weights=None):
        (self.nx, rx), (self.ny, ry) = _sides(lower, upper, h)
        self.comm = comm
        self.lower = np.asarray(lower, dtype=np.float64)
        self.upper = np.asarray(upper, dtype=np.float64)
        self.h = float(h)
        self.last = np.array([rx, ry])
        self.cut = bool(np.any(self.last < 1.0))
        self._extent = np.array([self.nx - 1 + rx, self.ny - 1 + ry])  # the tank's size in cells
        self.num_cells = self.nx * self.ny
        # the uniform lattice of the cells; a cut side's last vertices are then moved onto its face
        lattice_upper = np.where(self.last < 1.0, self.lower + self.h * np.array([self.nx, self.ny]), self.upper)
        self.mesh = dolfinx.mesh.create_rectangle(
            comm,
            [self.lower, lattice_upper],
            [self.nx, self.ny],
            dolfinx.mesh.CellType.quadrilateral,
            ghost_mode=dolfinx.mesh.GhostMode.none,
            partitioner=None if weights is None or comm.size == 1 else self._partitioner(weights),
        )
        if self.cut:
            x = self.mesh.geometry.x
            x[:, :2] = np.minimum(x[:, :2], self.upper)
        n_owned = self.mesh.topology.index_map(2).size_local
        mid = dolfinx.mesh.compute_midpoints(self.mesh, 2, np.arange(n_owned, dtype=np.int32))
        ij = np.floor((mid[:, :2] - self.lower) / self.h).astype(np.int64)
        self.owned_cells = ij[:, 0] + self.nx * ij[:, 1]
        self.local_cell = np.full(self.num_cells, -1, dtype=np.int32)
        self.local_cell[self.owned_cells] = np.arange(n_owned, dtype=np.int32)
        owned_by_rank = comm.allgather(self.owned_cells)
        self.owner = np.empty(self.num_cells, dtype=np.int32)
        for rank, cells in enumerate(owned_by_rank):
            self.owner[cells] = rank
        self.blocked = np.zeros(self.num_cells, dtype=bool)

    def _partitioner(self, weights):
        """A DOLFINx cell partitioner sending each cell to its part of a weighted bisection."""
        import dolfinx.cpp.graph

        weights = np.asarray(weights, dtype=np.float64).reshape(self.ny, self.nx)
        # empty cells still hold dofs: give them a little weight so they are shared too
        weights = weights + 1e-3 * max(weights.max(initial=0.0), 1.0)
        part = bisect(weights, self.comm.size).ravel()
        nx, ny = self.nx, self.ny

        def partition(comm, nparts, cell_types, cells):
            # create_rectangle numbers the vertices column by column (y fastest): the lowest
            # vertex of cell (i, j) is j + (ny + 1) i (checked by a test on 2 ranks)
            lowest = np.asarray(cells[0]).reshape(-1, 4).min(axis=1)
            i, j = lowest // (ny + 1), lowest % (ny + 1)
            return dolfinx.cpp.graph.AdjacencyList_int32(part[i + nx * j].astype(np.int32))

        return partition

    @classmethod
    def from_cells(cls, comm: MPI.Comm, lower, upper, cells, weights=None) -> "Grid":
        """A grid given by its number of cells per direction: ``h = width / nx``, ``ny`` the rows covering
        the height (:func:`square_cell_size`)."""
        return cls(comm, lower, upper, square_cell_size(lower, upper, cells), weights)

    def block(self, cells):
        """Mark the given structured cells as rigid obstacle (in addition to earlier ones).

        Solvers hold the velocity at zero on every basis function that is non-zero in
        a blocked cell, and particles that enter one are treated as having left the
        grid (:meth:`fempm.Particles.relocate`).
        """
        cells = np.asarray(cells, dtype=np.int64).ravel()
        if np.any((cells < 0) | (cells >= self.num_cells)):
            raise InputError(f"grid: blocked cells must be in [0, {self.num_cells}), got {cells.min()}..{cells.max()}")
        self.blocked[cells] = True

    def cell_index(self, i, j):
        """Structured cell number of column ``i`` and row ``j``."""
        return np.asarray(i) + self.nx * np.asarray(j)

    def cell_origin(self, cells) -> np.ndarray:
        """Lower-left corners of the given structured cells, shape ``(n, 2)``."""
        cells = np.asarray(cells)
        return self.lower + self.h * np.stack([cells % self.nx, cells // self.nx], axis=-1)

    def cell_sizes(self, cells) -> np.ndarray:
        """Width and height of the given structured cells, shape ``(n, 2)``: ``h``, or less in a
        cut last column or row."""
        return self.h * cell_shares(cells, (self.nx, self.ny), self.last)

    def locate(self, x: np.ndarray, ids: np.ndarray | None = None):
        """Structured cell and reference coordinates in ``[0, 1]^2`` of each point (in a cut
        last column or row, ``xi`` in ``[0, last]``).

        Args:
            x: positions, shape ``(n, 2)``.
            ids: particle ids used in the error message (default: row numbers).

        Raises:
            ParticleOutsideGridError: a point is outside the grid or not finite;
                the message names the first offending point and how many there are.
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1, 2)
        cells, xi, bad = self.place(x)
        if np.any(bad):
            k = np.flatnonzero(bad)
            label = ids[k[0]] if ids is not None else k[0]
            raise ParticleOutsideGridError(
                f"particle {label} at ({x[k[0], 0]:.6g}, {x[k[0], 1]:.6g}) is outside the grid "
                f"[{self.lower[0]:g}, {self.upper[0]:g}] x [{self.lower[1]:g}, {self.upper[1]:g}]"
                + (f" ({len(k)} particles in all)" if len(k) > 1 else "")
            )
        return cells, xi

    def outside(self, x: np.ndarray) -> np.ndarray:
        """Boolean mask of the points outside the tank (or not finite)."""
        return self.place(x)[2]

    def place(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cells, reference coordinates and the outside mask of points ``x`` ``(n, 2)`` (:func:`_place`): as
        :meth:`locate`, with the points outside the tank marked (cell -1, NaN coordinates) instead of an error."""
        x = np.asarray(x, dtype=np.float64).reshape(-1, 2)
        n = len(x)
        cells, xi, outside = np.empty(n, dtype=np.int64), np.empty((n, 2)), np.empty(n, dtype=np.bool_)
        _place(np.ascontiguousarray(x), self.lower, self.h, self.nx, self.ny, self._extent, self.last, self.cut,
               _WALL_TOLERANCE, cells, xi, outside)
        return cells, xi, outside


@numba.njit(cache=True)
def _place(x, lower, h, nx, ny, extent, last, cut, tolerance, cells, xi, outside):
    """Per point: ``s = (x - lower) / h`` in cells; outside where ``s`` is not finite or beyond the
    tank's ``extent`` by more than ``tolerance``; else the column and row ``floor(s)`` clipped to the
    grid, the cell ``i + nx j``, and ``xi = s - (i, j)`` clipped to ``[0, 1]`` (``[0, last]`` in a
    cut last column or row). Outside points get cell -1 and NaN coordinates."""
    n = (nx, ny)
    for p in range(x.shape[0]):
        out = False
        index = 0
        for d in range(2):
            s = (x[p, d] - lower[d]) / h
            if not (s >= -tolerance and s <= extent[d] + tolerance):  # also NaN and infinities
                out = True
                break
            k = min(max(int(np.floor(s)), 0), n[d] - 1)
            upper = last[d] if cut and k == n[d] - 1 else 1.0
            xi[p, d] = min(max(s - k, 0.0), upper)
            index += k if d == 0 else nx * k
        outside[p] = out
        if out:
            cells[p] = -1
            xi[p, 0] = xi[p, 1] = np.nan
        else:
            cells[p] = index
