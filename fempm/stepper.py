"""What the time loop sees of a scheme: its clock, the choice of its step, and how a failed step ends.

A scheme advances by :meth:`Stepper.step`: it takes the step size (fixed, or chosen by a
:class:`StepControl` from the particle speeds), calls the scheme's :meth:`Stepper.advance`, and
moves the clock. With a step control a failed step is retried from its saved state at half the
size (Tesserae.jl's dam break does the same) before the run is declared diverged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fempm.errors import InputError, ParticleOutsideGridError, SimulationDiverged
from fempm.linear import SolveFailed
from fempm.timing import PhaseTimes

__all__ = ["PRESSURE_COURANT", "StepControl", "Stepper"]

#: Relative tolerance of time comparisons (a step that lands on a target time).
TIME_TOLERANCE = 1e-9
#: the largest ``dt sqrt(p / rho) / h`` of an adaptive step, whatever its Courant number (see StepControl; measured
#: in the README's departures table)
PRESSURE_COURANT = 0.8


@dataclass
class StepControl:
    """An adaptive step: ``dt = C h / max |v_p|``, at most ``PRESSURE_COURANT h / max sqrt(p_p / rho_p)``,
    at most ``largest``, at most ``growth`` times the previous step; a failed step is retried at half its
    size up to ``retries`` times.

    The pressure's bound is one of stability, not of accuracy, so it does not follow C: the implicit step
    integrates the pressure's work at the particles, whose places are updated explicitly; as a particle
    moves by ``dx`` that work changes by about ``p dx / h`` per cell, a stiffness ``p / h^2`` that an
    explicit update of the places follows stably only while ``dt sqrt(p / rho) / h`` stays below about 1.
    At larger steps still water many cells deep grew a mode, cells alternately up and down (README,
    departures table).

    Attributes:
        courant: C, the fraction of a cell the fastest particle may cross in a step.
        largest: the largest step, s.
        growth: how much larger than the previous step a step may be.
        retries: halvings of a failed step before the run is declared diverged.
    """

    courant: float
    largest: float
    growth: float = 1.25
    retries: int = 3

    def check(self):
        """Raise :class:`InputError` naming the first unacceptable value."""
        if not (math.isfinite(self.courant) and 0 < self.courant <= 10):
            raise InputError(f"courant must be in (0, 10], got {self.courant}")
        if not (math.isfinite(self.largest) and self.largest > 0):
            raise InputError(f"the largest step must be positive, got {self.largest}")
        if not self.growth >= 1:
            raise InputError(f"the step growth must be >= 1, got {self.growth}")
        if not (int(self.retries) == self.retries and self.retries >= 0):
            raise InputError(f"retries must be a whole number >= 0, got {self.retries}")

    def choose(self, fastest: float, h: float, previous: float | None, pressure_speed: float = 0.0) -> float:
        """The step for particles whose fastest moves at ``fastest`` m/s on cells of size ``h``, under a
        largest ``sqrt(p / rho)`` of ``pressure_speed`` m/s."""
        dt = self.largest
        if fastest > 0:
            dt = min(dt, self.courant * h / fastest)
        if pressure_speed > 0:
            dt = min(dt, PRESSURE_COURANT * h / pressure_speed)
        if previous is not None:
            dt = min(dt, self.growth * previous)
        return dt


class Stepper:
    """The clock of a time-stepping scheme; subclasses implement :meth:`advance`.

    Args:
        dt: the fixed step, or the first step's bound with a ``control``.
        control: an adaptive step (:class:`StepControl`); None: the step is always ``dt``.

    Attributes:
        dt: the last step's size (before the first step: the fixed step or its bound).
        time, steps: simulated time and steps taken.
        timings: wall seconds by phase (:class:`~fempm.timing.PhaseTimes`).
        retries: ``(time, step, failed size, cause)`` of every retried step.
    """

    def __init__(self, dt: float, control: StepControl | None = None):
        if control is not None:
            control.check()
        self.dt, self.control = dt, control
        self.time = 0.0
        self.steps = 0
        self.timings = PhaseTimes()
        self.retries: list[tuple[float, int, float, str]] = []
        self._previous: float | None = None  # the last step taken, for the growth limit

    def step(self, until: float | None = None):
        """Advance by one step, not past ``until`` (a time the step then lands on exactly).

        Raises:
            SimulationDiverged: the step failed (after its retries, with a step control).
        """
        until = None if until is None or until == float("inf") else float(until)
        dt = self._size(until)
        saved = self.save() if self.control else None
        tried = []
        for attempt in range(self.control.retries + 1 if self.control else 1):
            try:
                self.advance(dt)
                break
            except (SolveFailed, ParticleOutsideGridError) as failure:
                tried.append(dt)
                if not self.control or attempt == self.control.retries:
                    raise SimulationDiverged(self.time + dt, self.steps + 1, str(failure) + _halvings(tried)) from None
                self.retries.append((self.time, self.steps + 1, dt, str(failure)))
                self.restore(saved)
                dt /= 2
        landed = until is not None and abs(self.time + dt - until) <= TIME_TOLERANCE * max(abs(until), dt)
        self.time = until if landed else self.time + dt
        self.steps += 1
        self._previous = dt
        if self.control:
            self.dt = dt  # a fixed step stays what it was, after a last shorter one too

    def _size(self, until: float | None) -> float:
        """The step: fixed, or the control's choice; shortened to land on ``until`` without a sliver
        (what is left is cut into equal steps)."""
        if self.control is None:
            dt = self.dt
        else:
            dt = self.control.choose(self.fastest(), self.cell_size(), self._previous, self.pressure_speed())
        if until is None:
            return dt
        remaining = until - self.time
        if self.control is None:  # a fixed step: only a last, shorter one to land on ``until``
            return min(dt, remaining)
        if remaining <= dt * (1 + TIME_TOLERANCE):
            return remaining
        return remaining / math.ceil(remaining / dt * (1 - TIME_TOLERANCE))

    def clock_state(self) -> dict:
        """What a resumed run needs to choose the same steps (JSON-able)."""
        return {"dt": self.dt, "previous": self._previous, "retries": [list(r) for r in self.retries]}

    def restore_clock(self, state: dict):
        """Continue from a :meth:`clock_state` (an empty one: as at the start)."""
        self.dt = state.get("dt", self.dt)
        self._previous = state.get("previous", self._previous)
        self.retries = [tuple(r) for r in state.get("retries", [])]

    def resume_point(self):
        """A checkpoint was just written: from here the run goes on as one resumed from it would. Nothing to
        do unless the scheme keeps what a checkpoint does not hold."""

    # -- what a scheme provides ----------------------------------------------------------------
    def advance(self, dt: float):
        """One step of size ``dt``; raises :class:`~fempm.linear.SolveFailed` or
        :class:`~fempm.errors.ParticleOutsideGridError` when it fails."""
        raise NotImplementedError

    def fastest(self) -> float:
        """The largest particle speed on all ranks (for a step control)."""
        raise NotImplementedError

    def pressure_speed(self) -> float:
        """``max sqrt(p / rho)`` over the particles, where the pressure's work is integrated at them (for a
        step control; 0: the scheme's steps do not depend on it)."""
        return 0.0

    def cell_size(self) -> float:
        """The grid's cell size (for a step control)."""
        raise NotImplementedError

    def save(self):
        """What :meth:`restore` needs to undo a failed step (for a step control)."""
        raise NotImplementedError

    def restore(self, saved):
        """Undo a failed step."""
        raise NotImplementedError


def _halvings(tried: list[float]) -> str:
    """What a failure's message adds when the step was halved before it: the sizes tried, since a
    failure that halving does not cure is not the step's size alone."""
    if len(tried) < 2:
        return ""
    sizes = ", ".join(f"{dt:.3g}" for dt in tried)
    return f" (the step failed at {sizes} s: halving it {len(tried) - 1} times did not help)"
