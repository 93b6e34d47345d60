"""The pressure's terms at fixed Gauss points, beside the particles (``Scheme.pressure_quadrature``).

With ``pressure_quadrature = "gauss"`` a step integrates at two kinds of points
(``forms/gauss_pressure.py``): the particles (``s.dx``, ``s.dx_lumped``) carry the inertia, the
viscous stress and PSPG; the 3 x 3 Gauss points of every cell where the water reaches
(``s.dx_fixed``) carry the pressure's work, gravity and the continuity, weighted there by the share of water the
forms take from the smoothed density (eq. 2). At the particles these terms follow the particles'
disorder, and a cell's rule jumps each time one crosses its edge; at fixed points they do not
(``docs/pressure-quadrature.md``).

:class:`GaussPoints` lays out the points of this rank's cells once per run and picks a step's cells;
:class:`StepPoints` holds the step's particles (``s.dx``, ``s.dx_lumped``) and its Gauss points
(:class:`FixedPoints`, ``s.dx_fixed``), each read by the forms' assembly as it reads particles.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from mpi4py import MPI

from fempm.errors import InputError

__all__ = ["GAUSS_WEIGHTS", "GAUSS_XI", "SHARPNESS", "FixedPoints", "GaussPoints", "StepPoints", "wet_threshold"]

#: how much the share of water sharpens the smoothed fraction phi = rho~ / rho: ``clip(k phi - (k - 1) / 2, 0, 1)``
SHARPNESS = 2.0

_GAUSS_1D = np.array([0.5 - 0.5 * np.sqrt(0.6), 0.5, 0.5 + 0.5 * np.sqrt(0.6)])
_WEIGHTS_1D = np.array([5.0, 8.0, 5.0]) / 18.0
#: the 3 x 3 Gauss points of the unit square, and their weights (exact for degree 5 in each direction)
GAUSS_XI = np.stack(np.meshgrid(_GAUSS_1D, _GAUSS_1D, indexing="ij"), axis=-1).reshape(-1, 2)
GAUSS_WEIGHTS = np.outer(_WEIGHTS_1D, _WEIGHTS_1D).ravel()


def wet_threshold(sharpness: float = SHARPNESS) -> float:
    """The smoothed fraction at and below which the sharpened share of water is zero: ``(k - 1) / (2 k)``."""
    return (sharpness - 1) / (2 * sharpness)


class FixedPoints:
    """One step's Gauss points, read by the forms' assembly as it reads particles (``s.dx_fixed``).

    A field is the Gauss points' own where given (``fields``), the water's ``density``, their ``volume`` (the
    quadrature weight), else zero, shaped as the particles' field of that name.
    """

    def __init__(self, particles, cells: np.ndarray, xi: np.ndarray, x: np.ndarray, volume: np.ndarray,
                 density: float, fields: dict | None = None):
        self.particles = particles  # whose fields' shapes the points' take
        self.cell, self.xi = cells, xi
        self.cache: dict = {}
        self._fields = {"x": x, "volume": volume, "density": np.full(len(cells), density)}
        self._given = dict(fields or {})

    def __len__(self) -> int:
        return len(self.cell)

    @property
    def x(self) -> np.ndarray:
        return self._fields["x"]

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._fields:
            shape = (len(self), *self.particles[name].shape[1:])
            given = self._given.get(name)
            self._fields[name] = np.zeros(shape) if given is None else np.broadcast_to(given, shape).copy()
        return self._fields[name]


@dataclasses.dataclass(frozen=True)
class StepPoints:
    """A step's two point sets: the particles (``s.dx``, ``s.dx_lumped``) and the fixed points (``s.dx_fixed``)."""

    particles: object
    fixed: FixedPoints


class GaussPoints:
    """The Gauss points of this rank's owned open cells, laid out once; a step's set of them with
    :meth:`points`.

    Args:
        space: the grid's scalar space (its local function numbers).
        density: the water's density (every particle's: the Gauss points carry one).
    """

    def __init__(self, space, density: float):
        grid = space.basis.grid
        self.density = density
        cells = grid.owned_cells[~grid.blocked[grid.owned_cells]]
        sizes = grid.cell_sizes(cells)
        offsets = GAUSS_XI[None] * sizes[:, None]  # (cells, 9, 2)
        self.cells = cells
        self.functions = space.local_functions_of_cells(cells)  # (cells, functions per cell)
        self.x = grid.cell_origin(cells)[:, None] + offsets  # (cells, 9, 2), and so on
        self.xi = offsets / grid.h  # in the cell, in cell sizes h
        self.volume = GAUSS_WEIGHTS[None] * np.prod(sizes, axis=1)[:, None]  # quadrature weights

    @staticmethod
    def check(particles):
        """One density for all the water (a Gauss point carries the water's), else :class:`InputError`."""
        comm = particles.grid.comm
        density = particles["density"]
        low = comm.allreduce(density.min(initial=np.inf), op=MPI.MIN)
        high = comm.allreduce(density.max(initial=-np.inf), op=MPI.MAX)
        if low < high:
            raise InputError(f"solver.pressure_quadrature = 'gauss' needs one density for all the material, "
                             f"got {low:g} to {high:g} kg/m^3; use 'particles'")

    def wet_cells(self, fraction: np.ndarray, threshold: float = wet_threshold()) -> np.ndarray:
        """Which of :attr:`cells` have a function whose smoothed fraction ``fraction`` (per local
        function) exceeds ``threshold``: where a share of water above zero may be."""
        return fraction[self.functions].max(axis=1) > threshold

    def points(self, particles, wet: np.ndarray, fields=None) -> StepPoints:
        """The particles and the Gauss points of the cells ``wet`` (boolean per cell of :attr:`cells`);
        ``fields``: a function of those cells' indices in :attr:`cells` giving fields at their points."""
        n = len(GAUSS_WEIGHTS)
        chosen = np.flatnonzero(wet)
        fixed = FixedPoints(particles, np.repeat(self.cells[chosen], n), self.xi[chosen].reshape(-1, 2),
                            self.x[chosen].reshape(-1, 2), self.volume[chosen].ravel(), self.density,
                            fields(chosen) if fields else None)
        return StepPoints(particles, fixed)
