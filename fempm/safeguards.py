"""Checks after a step that stop a run which has left what the scheme can represent.

Each raises :class:`~fempm.linear.SolveFailed` with a diagnosis; the stepper turns it into
:class:`~fempm.errors.SimulationDiverged`, and the run ends cleanly with its outputs so far.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from mpi4py import MPI

from fempm import diagnostics
from fempm.linear import SolveFailed

__all__ = ["EnergyWatch", "PressureCheck", "impact_impulse"]


def impact_impulse(density: float, start_speed: float, gravity, extent: float) -> float:
    """``rho U D``: the pressure impulse of water stopped by a wall (Pa s).

    An incompressible fluid meeting a wall at the speed U takes a pressure impulse ``int p dt ~ rho U L``,
    L the length of the water behind the impact (Cooker & Peregrine 1995), all of it within the step
    that stops it. Bounds: U the fastest starting speed plus a free fall through the extent D, L <= D.
    """
    fall = np.sqrt(2 * np.linalg.norm(gravity) * extent)
    return density * (start_speed + fall) * extent


@numba.njit(cache=True)
def _extremes(pressure):
    """``[-min(p, 0), max(p, 0)]`` over the 1-D ``pressure`` (NaN in both if one is NaN)."""
    low = high = 0.0
    for p in pressure:
        if p < low:
            low = p
        elif p > high:
            high = p
        elif p != p:
            return np.array([np.nan, np.nan])
    return np.array([-low, high])


class PressureCheck:
    """Stops on a pressure that is not finite, a tension beyond ``tension_limit`` or a compression
    beyond ``compression_limit`` plus an impact's ``impulse / dt`` (Pa); ``label`` names the failure."""

    def __init__(self, comm, tension_limit: float, compression_limit: float, impulse: float = 0.0,
                 label: str = "pressure oscillation"):
        self.comm, self.label, self.impulse = comm, label, impulse
        self.tension_limit, self.compression_limit = tension_limit, compression_limit

    def __call__(self, pressure: np.ndarray, dt: float):
        extremes = _extremes(np.ravel(pressure))  # one reduction for both
        if not math.isfinite(extremes[0] + extremes[1]):
            extremes[:] = np.inf  # NaN on one rank: not finite on all
        if self.comm.size > 1:
            self.comm.Allreduce(MPI.IN_PLACE, extremes, op=MPI.MAX)
        low, high = -float(extremes[0]), float(extremes[1])
        if not math.isfinite(low + high):
            raise SolveFailed("the pressure is not finite")
        if -low > self.tension_limit:
            raise SolveFailed(f"{self.label}: p reached {low:.3g} Pa, a tension beyond the limit "
                              f"{self.tension_limit:.3g} Pa")
        impact = self.impulse / dt
        if high > self.compression_limit + impact:
            raise SolveFailed(f"{self.label}: p reached {high:.3g} Pa, above the limit "
                              f"{self.compression_limit + impact:.3g} Pa (of which an impact's {impact:.3g} Pa)")


class EnergyWatch:
    """Stops when the mechanical energy (:func:`fempm.diagnostics.mechanical_energy`) stands more
    than ``gain_limit`` times its starting value above its lowest value so far: gravity and walls
    at rest only take energy away, so a gain is the scheme injecting it (the "eruption" of a too
    large step). An eruption that crowds the water loses potential energy as it gains kinetic, so
    a particle faster than ``sqrt((FALL_FACTOR v_fall)^2 + (START_FACTOR v_0)^2)`` stops the run as
    well: ``v_fall = sqrt(2 |g| H)`` a fall from the top of the box, ``v_0`` the fastest start (the
    jets of a body thrown at a wall outrun it: 2.5 times at 100 m/s; a wave landing on a thin layer
    squeezes out a jet at about twice a fall: ``scenes/obstacle.toml``)."""

    FALL_FACTOR, START_FACTOR = 2.5, 3.0

    def __init__(self, particles, gravity, gain_limit: float):
        self.particles, self.gravity, self.gain_limit = particles, gravity, gain_limit
        grid = particles.grid
        self.datum = diagnostics.lowest_corner(grid, gravity)
        self.start = self.lowest = diagnostics.mechanical_energy(particles, gravity, self.datum)
        corners = np.array([[x, y] for x in (grid.lower[0], grid.upper[0]) for y in (grid.lower[1], grid.upper[1])])
        drop = float(np.max(-(corners - self.datum) @ np.asarray(gravity, dtype=float)))  # |g| H
        self.fall_speed = np.sqrt(2 * drop)
        self.speed_limit = np.hypot(self.FALL_FACTOR * self.fall_speed, self.START_FACTOR * diagnostics.fastest(self.particles))

    def __call__(self, dt: float):
        energy = diagnostics.mechanical_energy(self.particles, self.gravity, self.datum)
        self.lowest = min(self.lowest, energy)
        gain = (energy - self.lowest) / self.start
        largest, h = diagnostics.fastest(self.particles), self.particles.grid.h
        if largest > self.speed_limit:
            raise SolveFailed(f"energy growth: a particle reached {largest:.3g} m/s, above {self.speed_limit:.3g} "
                              f"m/s ({self.FALL_FACTOR:g} times a fall from the top of the box, "
                              f"{self.fall_speed:.3g} m/s, with {self.START_FACTOR:g} times the fastest start), "
                              f"as a step too large for the flow does ({largest * dt / h:.1f} cells per step)")
        if gain > self.gain_limit:
            grid = self.particles.grid
            raise SolveFailed(f"energy growth: the mechanical energy rose by {100 * gain:.0f} % of its start, "
                              f"which gravity and walls at rest cannot give, as a step too large for the flow does "
                              f"(fastest particle {largest:.3g} m/s, {largest * dt / grid.h:.1f} cells per step)")
