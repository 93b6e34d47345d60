"""Where the Jacobian has rows: the whole grid, or only near the water.

On a large tank holding a little water, a matrix with a row for every function of the grid
costs memory for nothing. :class:`MatrixRegion` keeps rows only for the functions non-zero in
the cells holding particles, widened by a margin, and rebuilds the matrix when the water
leaves that region (on every rank alike).
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from fempm import collective
from fempm.matrix import GridMatrix, create_matrix
from fempm.options import FLUID_REGION_CELLS
from fempm.space import Space

__all__ = ["MatrixRegion", "dilate"]


class MatrixRegion:
    """The matrix of a space for a step: on the grid (``mode="grid"``), near the water
    (``"fluid"``), or chosen by size (``"auto"``: fluid above :data:`FLUID_REGION_CELLS` cells).

    Attributes:
        matrix: the PETSc matrix to assemble into.
        cells: boolean per cell of the rows' region (None: the whole grid).
        rebuilds: times the region was widened.
    """

    def __init__(self, space: Space, mode: str, particles):
        self.space, self.grid = space, space.grid
        self.follows_fluid = mode == "fluid" or (mode == "auto" and self.grid.num_cells > FLUID_REGION_CELLS)
        self.cells = None
        self.rebuilds = 0
        self.matrix = self._build(particles)

    def _build(self, particles) -> PETSc.Mat:
        if not self.follows_fluid:
            return create_matrix(self.space)
        grid = self.grid
        occupied = np.zeros(grid.num_cells, dtype=bool)
        occupied[particles.cell] = True
        grid.comm.Allreduce(MPI.IN_PLACE, occupied, op=MPI.LOR)
        margin = max(2 * (self.space.basis.degree + 1), int(np.ceil(0.05 * max(grid.nx, grid.ny))))
        self.cells = dilate(occupied.reshape(grid.ny, grid.nx), margin).ravel()
        return GridMatrix(self.space, self.cells).mat

    def follow(self, particles) -> bool:
        """Widen the region if the water has left it; True if the matrix was rebuilt."""
        if self.cells is None:
            return False
        outside = bool(np.any(~self.cells[particles.cell]))
        if not collective.any_rank(self.grid.comm, outside):
            return False
        self.matrix = self._build(particles)
        self.rebuilds += 1
        return True


def dilate(mask: np.ndarray, margin: int) -> np.ndarray:
    """A 2-D boolean mask grown by ``margin`` cells in every direction (a square neighbourhood)."""
    out = mask
    for axis in (0, 1):
        pad = np.zeros_like(out.take([0], axis=axis)).repeat(margin, axis=axis)
        padded = np.concatenate([pad, out, pad], axis=axis)
        total = np.cumsum(padded, axis=axis, dtype=np.int64)
        total = np.concatenate([np.zeros_like(total.take([0], axis=axis)), total], axis=axis)
        n = out.shape[axis]
        window = total.take(np.arange(n) + 2 * margin + 1, axis=axis) - total.take(np.arange(n), axis=axis)
        out = window > 0
    return out
