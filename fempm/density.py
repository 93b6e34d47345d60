"""Where the water is deep: the volume correction's switch between both signs and crowding only.

``phi_i = rho~_i / rho`` (the smoothed density of eq. 2 over the density: the share of function
``i``'s support the particles' volumes cover) measures crowding (``phi_i > 1``) and thinning
(``phi_i < 1``) of the particles, but only where the support lies inside the water: where it
reaches into air ``phi_i < 1`` by construction, and a correction of both signs contracts every
free surface (method.md's form squeezed a column at rest), while a correction of crowding only
never undoes thinning, so a free surface that moves swells. So a function is *deep* when every
cell of its support is (``phi >= DEEP`` at the cell's centre: filled, some way below any free
surface), and the grid function ``deep`` is 1 there, 0 elsewhere. The surface-aware continuity
(``forms/incompressible.py``) corrects both signs at a particle all of whose functions are deep
(``deep`` interpolates to 1 there) and crowding only at the others, the band along a free surface.
The error is taken at the particles, as the crowding-only correction's is: a per-function error
interpolated to the particles rippled the dam break's upper wall gauge more.
"""

from __future__ import annotations

import numba
import numpy as np

from fempm.space import GridFunction, Space

__all__ = ["DEEP", "DeepWater"]

#: a cell is deep inside the material when the wet fraction at its centre reaches this
DEEP = 0.8


class DeepWater:
    """The ``deep`` mask per basis function (see the module) from ``phi_i`` on a scalar space's local functions.

    Args:
        space: a scalar space of the basis.
    """

    def __init__(self, space: Space):
        grid = space.grid
        cells = grid.owned_cells
        self.centre_values = space.basis.tabulate(cells, 0.5 * grid.cell_sizes(cells) / grid.h, order=0)[:, 0, :]
        self.cell_functions = space.local_functions_of_cells(cells)
        self._shallow = GridFunction(space, "shallow_cells")

    def interior(self, phi: np.ndarray) -> np.ndarray:
        """Which local functions have only deep cells in their support, given ``phi`` on the local
        functions (owned and ghost, up to date; collective)."""
        shallow = self._shallow
        shallow.values[:] = 0.0
        _count_shallow_cells(self.centre_values, self.cell_functions, phi, shallow.values[:, 0])
        shallow.scatter_reverse_add()
        shallow.scatter_forward()
        return shallow.values[:, 0] == 0

    def __call__(self, phi: np.ndarray) -> np.ndarray:
        """``deep`` on the local functions: 1.0 on the interior ones, else 0.0 (collective)."""
        return self.interior(phi).astype(np.float64)


@numba.njit(cache=True)
def _count_shallow_cells(centre_values, cell_functions, phi, counts):
    """Add 1 to ``counts`` at every function of each cell whose ``phi`` at the centre,
    ``sum_l N_l(centre) phi_l``, is below :data:`DEEP`."""
    for c in range(cell_functions.shape[0]):
        centre = 0.0
        for l in range(cell_functions.shape[1]):
            centre += centre_values[c, l] * phi[cell_functions[c, l]]
        if centre < DEEP:
            for l in range(cell_functions.shape[1]):
                counts[cell_functions[c, l]] += 1.0
