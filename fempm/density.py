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

The same pass over the cells gives the momentum's weight ``by_parts`` (``forms/incompressible.py``,
``pressure_work``): the share of the pressure's work taken by parts, ``w . grad p`` for ``-p div w``.
The two forms integrate alike wherever that share times the pressure vanishes on the water's edge, so
the share must fall to zero at the free surface; it is the product, over the cells of a function's
support, of a ramp of ``phi`` at the cell's centre. A product rather than a switch: a share that jumps
as ``phi`` crosses a level made the dam break's wall gauges ripple (a binary mask: 45-60 % of their
mean against 2-4 %). Where the water is still the ramp (:data:`BY_PARTS_STILL`) reaches the surface
cell, whose pressure is nearly zero; where it moves (:data:`BY_PARTS_MOVING`, from :data:`STILL_SPEEDS`
on) it stops a cell and a half below, since near a moving surface the pressure need not fall to zero
within a cell (an impact, a jet: there a ramp to the surface cell stopped the dam break onto an
obstacle and a landing sparse cloud).
"""

from __future__ import annotations

import numba
import numpy as np

from fempm.space import GridFunction, Space

__all__ = ["BY_PARTS_MOVING", "BY_PARTS_STILL", "DEEP", "DeepWater", "STILL_SPEEDS"]

#: a cell is deep inside the material when the wet fraction at its centre reaches this
DEEP = 0.8
#: the wet fractions at a cell's centre between which the pressure's work goes from not at all to wholly by
#: parts, in still water and in moving water (see the module)
BY_PARTS_STILL = (0.3, 0.5)
BY_PARTS_MOVING = (0.6, 0.9)
#: a function's speed over sqrt(|g| h) from which its water moves, and to which it moves wholly
STILL_SPEEDS = (0.05, 0.1)
_RAMPS = np.array([BY_PARTS_STILL, BY_PARTS_MOVING])


class DeepWater:
    """The ``deep`` mask and the ``by_parts`` weight per basis function (see the module) from ``phi_i`` on a
    scalar space's local functions.

    Args:
        space: a scalar space of the basis.
        open_sides: the sides (of ``fempm.options.SIDES``) that let water out: ``by_parts`` is zero on the
            functions of their cells, where ``w . n`` is not.
    """

    def __init__(self, space: Space, open_sides=()):
        grid = space.grid
        self.cells = grid.owned_cells
        i, j = self.cells % grid.nx, self.cells // grid.nx
        edge = {"left": i == 0, "right": i == grid.nx - 1, "bottom": j == 0, "top": j == grid.ny - 1}
        self._unresolved = grid.blocked[self.cells].copy()  # where by_parts is zero (the grid's obstacles are set)
        for side in open_sides:
            self._unresolved |= edge[side]
        self.centre_values = space.basis.tabulate(self.cells, 0.5 * grid.cell_sizes(self.cells) / grid.h, order=0)[:, 0, :]
        self.cell_functions = space.local_functions_of_cells(self.cells)
        self._deep_cells = GridFunction(space, "deep_cells")
        self._ramps = GridFunction(Space(space.basis, {"still": 2, "moving": 2}), "by_parts_ramps")
        # each local function's cells on all ranks: the pass below visits only the cells some water reaches
        # and counts what is not shallow, not zero, so that a dry cell costs no writes
        support = GridFunction(space, "support_cells")
        _count_cells(self.cell_functions, support.values[:, 0])
        support.scatter_reverse_add()
        support.scatter_forward()
        self._support = support.values[:, 0].copy()

    def _counted(self, phi: np.ndarray, by_parts: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """Per local function, over its support's cells: those at or above :data:`DEEP`; with ``by_parts`` also,
        for each ramp (still, moving), the sum of the logarithms of the cells' ramps above zero and the count of
        those (a cell blocked, an obstacle's whose face the basis does not resolve, or along an open side has a
        ramp of zero; owned and ghost, up to date; collective)."""
        sums = [self._deep_cells] + ([self._ramps] if by_parts else [])
        _sum_cells(self.centre_values, self.cell_functions, phi, self._unresolved, _RAMPS,
                   self._deep_cells.values[:, 0], self._ramps.values if by_parts else np.zeros((0, 4)))
        for f in sums:
            f.scatter_reverse_add()
            f.scatter_forward()
        return self._deep_cells.values[:, 0], self._ramps.values if by_parts else None

    def interior(self, phi: np.ndarray) -> np.ndarray:
        """Which local functions have only deep cells in their support, given ``phi`` on the local
        functions (owned and ghost, up to date; collective)."""
        return self._counted(phi)[0] == self._support

    def __call__(self, phi: np.ndarray) -> np.ndarray:
        """``deep`` on the local functions: 1.0 on the interior ones, else 0.0 (collective)."""
        return self.interior(phi).astype(np.float64)

    def masks(self, phi: np.ndarray, velocity: np.ndarray | None = None, unit_speed: float = 1.0,
              out: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``deep`` and ``by_parts`` on the local functions, from one pass over the cells, given each function's
        velocity ``(n, 2)`` and the speed ``sqrt(|g| h)`` its speed is measured in (None: still water, as without
        gravity); into the two arrays ``out`` if given (collective)."""
        deep_cells, ramps = self._counted(phi, by_parts=True)
        deep, by_parts = out if out is not None else (np.empty(len(phi)), np.empty(len(phi)))
        _masks(self._support, deep_cells, ramps, np.exp(ramps[:, 0]), np.exp(ramps[:, 2]),
               np.empty((0, 2)) if velocity is None else velocity, unit_speed, *STILL_SPEEDS, deep, by_parts)
        return deep, by_parts


@numba.njit(cache=True)
def _masks(support, deep_cells, ramps, still_product, moving_product, velocity, unit_speed, slow, fast, deep, by_parts):
    """``deep`` where every cell of the support is deep; ``by_parts``: each ramp's product over the cells (zero
    where one of them is zero), the still one's blended into the moving one's as the speed ``|v| / unit_speed``
    rises from ``slow`` to ``fast`` (the still one alone without velocities)."""
    for i in range(deep.shape[0]):
        deep[i] = 1.0 if support[i] - deep_cells[i] == 0 else 0.0
        still = 0.0 if support[i] - ramps[i, 1] > 0 else still_product[i]
        if velocity.shape[0] == 0:
            by_parts[i] = still
            continue
        moving = 0.0 if support[i] - ramps[i, 3] > 0 else moving_product[i]
        speed = np.sqrt(velocity[i, 0] * velocity[i, 0] + velocity[i, 1] * velocity[i, 1]) / unit_speed
        share = min(max((fast - speed) / (fast - slow), 0.0), 1.0)
        by_parts[i] = moving + share * (still - moving)


@numba.njit(cache=True)
def _count_cells(cell_functions, out):
    """1 to ``out`` for every function of every cell: each function's cells."""
    for c in range(cell_functions.shape[0]):
        for l in range(cell_functions.shape[1]):
            out[cell_functions[c, l]] += 1.0


@numba.njit(cache=True)
def _sum_cells(centre_values, cell_functions, phi, blocked, ramps, deep, sums):
    """For each cell, ``phi`` at its centre ``sum_l N_l(centre) phi_l``; to every function of the cell add
    1 to ``deep`` if it is at or above :data:`DEEP`, and unless ``sums`` is empty, for each ramp ``k`` of
    ``ramps`` (rows ``(none, full)``) whose ``clip((phi - none) / (full - none), 0, 1)`` is above zero and the
    cell not ``blocked``, its logarithm to ``sums[:, 2k]`` and 1 to ``sums[:, 2k + 1]``. A cell that adds
    nothing (dry, or nearly) is left after its centre. ``deep`` and ``sums`` are zeroed first."""
    deep[:] = 0.0
    sums[:] = 0.0
    by_parts = sums.shape[0] > 0
    logs = np.empty(ramps.shape[0])
    for c in range(cell_functions.shape[0]):
        centre = 0.0
        for l in range(cell_functions.shape[1]):
            centre += centre_values[c, l] * phi[cell_functions[c, l]]
        wet = centre >= DEEP
        if by_parts:
            for k in range(ramps.shape[0]):
                ramp = 0.0 if blocked[c] else min(1.0, (centre - ramps[k, 0]) / (ramps[k, 1] - ramps[k, 0]))
                logs[k] = np.log(ramp) if ramp > 0.0 else np.nan  # nan: the ramp is zero
                wet = wet or ramp > 0.0
        if not wet:
            continue
        for l in range(cell_functions.shape[1]):
            f = cell_functions[c, l]
            if centre >= DEEP:
                deep[f] += 1.0
            if by_parts:
                for k in range(ramps.shape[0]):
                    if not np.isnan(logs[k]):
                        sums[f, 2 * k] += logs[k]
                        sums[f, 2 * k + 1] += 1.0
