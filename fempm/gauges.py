"""Gauges: the pressure at a point and the water level along a vertical line, sampled from a solver.

Usable from any script (``fempm.gauges.sample(gauges, solver)``, or a :class:`Sampler` built once
in a time loop), and from a scene's ``[[gauges]]`` tables (written to ``gauges.csv``). Both kinds
read the state a solver leaves after a step (its particles, its grid pressure), the same on every
rank, at the cost of one scatter of the particle volumes onto the grid and a few basis
evaluations at points fixed once:

* the **wet fraction** ``phi(x) = sum_i phi_i N_i(x)``, ``phi_i = sum_p V_p N_i(x_p) / int N_i dx``
  (:func:`wet_fraction`): the share of a basis function's support the particles' volumes cover
  (the smoothed density of method.md eq. 2 over the density), 1 inside uniformly seeded water,
  0 in air, about 1/2 on a free surface (the kernel is symmetric);
* :class:`PressureGauge` reads the grid pressure ``p(x)`` of the last step (the field whose
  values at the particles are the particle pressures). **Dry rule**: a point where
  ``phi < 1/2`` (:data:`DRY_FRACTION`; outside the water's half-level set, as a VOF code's
  ``alpha = 1/2``) reads **NaN**: the B-spline pressure reaches past the water, so a dry point
  would otherwise read a number. ``phi`` is taken at the point moved to at least half a cell
  inside the walls and off the obstacles' faces (:func:`off_the_walls`): a particle stands for a
  small square around it, and where water is stretched along a wall the particles leave a gap of
  up to half a cell between themselves and the wall although the water is there. Beside an
  obstacle ``int N_i dx`` is taken over the open cells alone (over the obstacle's cells too, where
  no particle goes, still water on its face read about 1/2);
* :class:`LevelGauge` reads the depth of water along the vertical line ``x`` (moved to at least
  half a cell from the side walls and the obstacles' faces, likewise; inside an obstacle nothing),
  ``int phi(x, y) dy`` from the grid's bottom to its top (as OpenFOAM's ``interfaceHeight``
  integrates ``alpha``: robust to the particle spacing; a splash above the surface adds its own
  thickness). A dry line reads 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fempm import transfer
from fempm.errors import InputError
from fempm.grid import touches_only
from fempm.space import GridFunction, Space

__all__ = ["DRY_FRACTION", "LevelGauge", "PressureGauge", "Sampler", "UNITS", "WetFraction", "inside_obstacles",
           "off_the_walls", "sample", "wet_fraction"]

#: Points whose wet fraction is below this are dry (pressure gauges read NaN there).
DRY_FRACTION = 0.5
#: The unit of each kind's reading.
UNITS = {"pressure": "Pa", "level": "m"}


@dataclass(frozen=True)
class PressureGauge:
    """The grid pressure (Pa) at ``point`` (m); NaN where dry (wet fraction below :data:`DRY_FRACTION`)."""

    name: str
    point: tuple[float, float]
    kind = "pressure"


@dataclass(frozen=True)
class LevelGauge:
    """The depth of water (m) along the vertical line at ``x`` (m): ``int phi dy`` over the grid's height."""

    name: str
    x: float
    kind = "level"


def wet_fraction(particles, integrals: np.ndarray, out: GridFunction) -> GridFunction:
    """``phi_i = sum_p V_p N_i(x_p) / int N_i dx`` into the scalar grid function ``out`` (ghosts
    updated); ``integrals`` per structured function (:func:`fempm.transfer.density_normalisation`)."""
    transfer.particles_to_grid(out.space, particles, particles["volume"], out=out)
    out.values[:, 0] /= integrals[out.space.numbering.local_functions]
    return out


class WetFraction:
    """The wet fraction of a basis's functions from particles, into one grid function reused
    (the normalisation taken from the particles at the first call)."""

    def __init__(self, basis):
        self.basis = basis
        self.field = GridFunction(Space(basis, {"phi": 1}), "wet_fraction")
        self._integrals = None

    def __call__(self, particles) -> GridFunction:
        """:func:`wet_fraction` now (collective)."""
        if self._integrals is None:  # over the open cells: 1 in water at rest beside an obstacle too
            integrals = transfer.density_normalisation(self.basis, particles, blocked=False)
            self._integrals = np.where(integrals > 0, integrals, np.inf)  # a function inside an obstacle: 0
        return wet_fraction(particles, self._integrals, self.field)


def _blocked_near(grid, u: np.ndarray, axis: int, shift: float) -> np.ndarray:
    """Whether the cell at ``u + shift`` along ``axis`` (``u``: points in cells from the grid's lower corner)
    is an obstacle's."""
    ij = np.floor(u + shift * np.eye(2)[axis]).astype(np.int64)
    ij = np.clip(ij, 0, np.array([grid.nx, grid.ny]) - 1)
    return grid.blocked[ij[:, 0] + grid.nx * ij[:, 1]]


def inside_obstacles(grid, points: np.ndarray) -> np.ndarray:
    """Whether each point lies inside an obstacle: every cell it touches (to round-off) is blocked."""
    return touches_only(points, grid.lower, grid.h, (grid.nx, grid.ny), grid.blocked)


def off_the_walls(grid, points: np.ndarray, axes=(0, 1)) -> np.ndarray:
    """Where the wet fraction at ``points`` ``(n, 2)`` is read: moved along ``axes`` to at least half a
    cell inside the tank's walls, then, axis by axis, to half a cell off an obstacle's face that lies
    within half a cell (into the open cell beside it; a gap one cell wide: its middle). Points inside an
    obstacle stay."""
    h = grid.h
    out = np.array(points, dtype=float).reshape(-1, 2)
    for axis in axes:
        out[:, axis] = np.clip(out[:, axis], grid.lower[axis] + h / 2, grid.upper[axis] - h / 2)
    if not grid.blocked.any():
        return out
    inside = inside_obstacles(grid, out)
    for axis in axes:
        u = (out - grid.lower) / h
        below, above = _blocked_near(grid, u, axis, -0.5), _blocked_near(grid, u, axis, 0.5)
        k_below, k_above = np.floor(u[:, axis] - 0.5), np.floor(u[:, axis] + 0.5)
        moved = np.where(below, k_below + 1.5, np.where(above, k_above - 0.5, u[:, axis]))
        out[:, axis] = np.where(inside, out[:, axis], grid.lower[axis] + h * moved)
    return out


class _Points:
    """Fixed points of a grid, located once: a grid function's values there, summed over ranks."""

    def __init__(self, grid, points: np.ndarray):
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        cells, xi = grid.locate(points) if len(points) else (np.zeros(0, np.int64), np.zeros((0, 2)))
        mine = grid.owner[cells] == grid.comm.rank
        self.count, self.rows, self.cells, self.xi = len(points), np.flatnonzero(mine), cells[mine], xi[mine]

    def local(self, gf: GridFunction) -> np.ndarray:
        """This rank's share of ``f(x_k)`` (zero at points in other ranks' cells)."""
        out = np.zeros(self.count)
        if len(self.rows):
            out[self.rows] = gf.evaluate(self.cells, self.xi)[:, 0, 0]
        return out


class Sampler:
    """Samples a fixed list of gauges from a solver's state (build once, call :meth:`sample` often).

    Args:
        gauges: :class:`PressureGauge` and :class:`LevelGauge` objects, names unique.
        basis: the solver's basis (its grid holds the gauges).
        level_points: Gauss points per cell along a level gauge's line (3: exact for the
            quadratic B-splines and Q1).

    Raises:
        InputError: a gauge outside the grid, of neither kind, or two gauges of one name.
    """

    def __init__(self, gauges, basis, level_points: int = 3):
        self.gauges = list(gauges)
        names = [g.name for g in self.gauges]
        if len(set(names)) != len(names):
            raise InputError(f"gauges: names must be unique, got {names}")
        grid = basis.grid
        for g in self.gauges:
            if not isinstance(g, (PressureGauge, LevelGauge)):
                raise InputError(f"gauges: {g!r} is neither a PressureGauge nor a LevelGauge")
            x = np.asarray(g.point if isinstance(g, PressureGauge) else (g.x, grid.lower[1]), dtype=float)
            if x.shape != (2,) or bool(grid.outside(x[None])[0]):
                raise InputError(f"gauges.{g.name}: the point {tuple(x.tolist())} is outside the grid "
                                 f"[{grid.lower[0]:g}, {grid.upper[0]:g}] x [{grid.lower[1]:g}, {grid.upper[1]:g}]")
        self.basis = basis
        self._wet = WetFraction(basis)
        self._pressure = [g for g in self.gauges if isinstance(g, PressureGauge)]
        self._level = [g for g in self.gauges if isinstance(g, LevelGauge)]
        points = np.array([g.point for g in self._pressure], dtype=float).reshape(-1, 2)
        self._points = _Points(grid, points)
        self._wet_points = _Points(grid, off_the_walls(grid, points))  # where phi is read, see the module
        gauss, weights = np.polynomial.legendre.leggauss(level_points)
        rows = np.where(np.arange(grid.ny) == grid.ny - 1, grid.last[1], 1.0)[:, None]  # a cut top row's height
        y = grid.lower[1] + grid.h * (np.arange(grid.ny)[:, None] + rows * 0.5 * (gauss + 1.0)).ravel()
        weights = (rows * 0.5 * weights * grid.h).ravel()
        lines = [np.column_stack([np.full_like(y, g.x), y]) for g in self._level]
        # a line's points inside an obstacle weigh nothing; the others read phi off the walls
        self._weights = np.array([np.where(inside_obstacles(grid, line), 0.0, weights) for line in lines]
                                 ).reshape(len(lines), len(y))
        lines = [off_the_walls(grid, line, axes=(0,)) for line in lines]
        self._lines = _Points(grid, np.concatenate(lines) if lines else np.zeros((0, 2)))
        self._per_line = len(y)
        self.comm = grid.comm

    @property
    def names(self) -> list[str]:
        """The gauges' names, in order."""
        return [g.name for g in self.gauges]

    def sample(self, solver) -> dict[str, float]:
        """The gauges' readings now, by name (the same on every rank; collective)."""
        phi = self._wet(solver.particles)
        local = np.concatenate([self._wet_points.local(phi), self._points.local(solver.pressure),
                                self._lines.local(phi)])
        total = self.comm.allreduce(local)
        n = self._points.count
        wet, pressure, along = total[:n], total[n: 2 * n], total[2 * n:]
        pressure = np.where(wet >= DRY_FRACTION, pressure, np.nan)
        levels = (along.reshape(len(self._level), self._per_line) * self._weights).sum(axis=1)
        readings = {g.name: float(v) for g, v in zip(self._pressure, pressure)}
        readings.update({g.name: float(v) for g, v in zip(self._level, levels)})
        return {name: readings[name] for name in self.names}


def sample(gauges, solver) -> dict[str, float]:
    """The readings of ``gauges`` from ``solver`` now (collective; in a time loop build a
    :class:`Sampler` once instead)."""
    return Sampler(gauges, solver.basis).sample(solver)
