"""What the time loop sees of a scheme: its clock, its phase timings, and how a failed step ends a run."""

from __future__ import annotations

from contextlib import contextmanager

from fempm.errors import ParticleOutsideGridError, SimulationDiverged
from fempm.linear import SolveFailed
from fempm.timing import PhaseTimes

__all__ = ["Stepper"]


class Stepper:
    """The clock of a time-stepping scheme.

    Attributes:
        dt: the time step.
        time, steps: simulated time and steps taken.
        timings: wall seconds by phase (:class:`~fempm.timing.PhaseTimes`).
    """

    def __init__(self, dt: float):
        self.dt = dt
        self.time = 0.0
        self.steps = 0
        self.timings = PhaseTimes()

    @contextmanager
    def advancing(self):
        """The body of one step: on success the clock moves by ``dt``; a failure of the solve, a
        safeguard or a particle leaving the grid raises :class:`SimulationDiverged` instead."""
        try:
            yield
        except (SolveFailed, ParticleOutsideGridError) as e:
            raise SimulationDiverged(self.time + self.dt, self.steps + 1, str(e)) from None
        self.time += self.dt
        self.steps += 1
