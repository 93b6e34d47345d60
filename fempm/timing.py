"""Wall time of a time step's named phases, summed over the run."""

from __future__ import annotations

import time
from collections import defaultdict

__all__ = ["PhaseTimes"]


class PhaseTimes(defaultdict):
    """Seconds spent in each phase, by name; ``with times("assemble"): ...`` adds the block's time."""

    def __init__(self):
        super().__init__(float)

    def __call__(self, name: str) -> _Phase:
        return _Phase(self, name)


class _Phase:
    """One timed block of :class:`PhaseTimes` (a plain context manager: a generator-based one costs
    several times more, and a step times several phases)."""

    __slots__ = ("times", "name", "start")

    def __init__(self, times: PhaseTimes, name: str):
        self.times, self.name = times, name

    def __enter__(self):
        self.start = time.perf_counter()

    def __exit__(self, *exception):
        self.times[self.name] += time.perf_counter() - self.start
        return False
