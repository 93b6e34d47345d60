"""Measures of a flow computed from the particles (all ranks), for histories and tests."""

from __future__ import annotations

import numba
import numpy as np
from mpi4py import MPI

from fempm import collective

__all__ = ["fastest", "front_position", "lowest_corner", "mechanical_energy", "occupied_cells", "pressure_range",
           "pressure_speed", "surface_height"]


@numba.njit(cache=True)
def _largest_square(v):
    """``max_p |v_p|^2`` (0 for no particles; NaN if a speed is NaN)."""
    largest = 0.0
    for p in range(v.shape[0]):
        square = v[p, 0] * v[p, 0] + v[p, 1] * v[p, 1]
        if square > largest:
            largest = square
        elif square != square:
            return square
    return largest


def fastest(particles) -> float:
    """The largest particle speed on all ranks (the root of the largest square: the same number)."""
    local = float(np.sqrt(_largest_square(particles["velocity"])))
    return collective.largest(particles.grid.comm, local)


@numba.njit(cache=True)
def _largest_ratio(a, b):
    """``max_p a_p / b_p``, at least 0 (NaN if a ratio is NaN)."""
    largest = 0.0
    for p in range(a.shape[0]):
        ratio = a[p] / b[p]
        if ratio > largest:
            largest = ratio
        elif ratio != ratio:
            return ratio
    return largest


def pressure_speed(particles) -> float:
    """``max sqrt(p / rho)`` over the particles of all ranks (0 where no pressure is positive): the speed at
    which the pressure's work at the particles changes as they move (see :class:`fempm.stepper.StepControl`)."""
    head = float(_largest_ratio(particles["pressure"], particles["density"]))
    return float(np.sqrt(collective.largest(particles.grid.comm, head)))


def lowest_corner(grid, gravity) -> np.ndarray:
    """The corner of the grid lowest in the direction of ``gravity`` (least potential ``-g . x``)."""
    corners = np.array([[x, y] for x in (grid.lower[0], grid.upper[0]) for y in (grid.lower[1], grid.upper[1])])
    return corners[np.argmax(corners @ np.asarray(gravity, dtype=float))]


def mechanical_energy(particles, gravity, datum) -> float:
    """Kinetic plus potential energy of the material on all ranks::

        E = sum_p m_p (|v_p|^2 / 2 - g . (x_p - datum))

    With ``datum`` the :func:`lowest_corner`, E >= 0; gravity and walls at rest can only
    take it away (viscosity, the scheme's dissipation)."""
    (gx, gy), (x0, y0) = gravity, datum
    local = _energy(particles.x, particles["velocity"], particles["mass"], float(gx), float(gy), float(x0), float(y0))
    return collective.total(particles.grid.comm, local)


@numba.njit(cache=True)
def _energy(x, v, m, gx, gy, x0, y0):
    """``sum_p m_p (|v_p|^2 / 2 - g . (x_p - x0))`` on this rank."""
    total = 0.0
    for p in range(m.shape[0]):
        height = (x[p, 0] - x0) * gx + (x[p, 1] - y0) * gy
        total += m[p] * (0.5 * (v[p, 0] * v[p, 0] + v[p, 1] * v[p, 1]) - height)
    return total


def front_position(particles, axis: int = 0) -> float:
    """Leading edge of the material: the largest particle coordinate plus half a particle spacing.

    A particle of volume V stands for a square of side sqrt(V) around it, so at t = 0 the
    front of a seeded column is exactly the column's edge.
    """
    x = particles.x[:, axis]
    local = float(np.max(x + 0.5 * np.sqrt(particles["volume"]), initial=-np.inf))
    return particles.grid.comm.allreduce(local, op=MPI.MAX)


def occupied_cells(particles) -> int:
    """Number of grid cells holding at least one particle (method.md Fig. 4's measure)."""
    return particles.grid.comm.allreduce(int(np.count_nonzero(np.bincount(particles.cell))))


def surface_height(particles) -> float:
    """Height of the free surface of a settled layer: the median over the grid's columns of
    the top of their highest particle (its y plus half a particle spacing), above the grid's
    bottom. Columns without particles are left out."""
    grid = particles.grid
    column = particles.cell % grid.nx
    top = np.full(grid.nx, -np.inf)
    np.maximum.at(top, column, particles.x[:, 1] + 0.5 * np.sqrt(particles["volume"]))
    grid.comm.Allreduce(MPI.IN_PLACE, top, op=MPI.MAX)
    tops = np.sort(top[np.isfinite(top)])  # the median of a few dozen numbers, without np.median's overhead
    n = len(tops)
    return float(0.5 * (tops[(n - 1) // 2] + tops[n // 2]) - grid.lower[1]) if n else 0.0


def pressure_range(particles) -> tuple[float, float]:
    """Smallest and largest particle pressure on all ranks."""
    p = particles["pressure"]
    extremes = np.array([-np.min(p, initial=np.inf), np.max(p, initial=-np.inf)])
    particles.grid.comm.Allreduce(MPI.IN_PLACE, extremes, op=MPI.MAX)  # one reduction for both
    return float(-extremes[0]), float(extremes[1])
