"""Wall time of a time step's named phases, summed over the run."""

from __future__ import annotations

import time
from collections import defaultdict
from contextlib import contextmanager

__all__ = ["PhaseTimes"]


class PhaseTimes(defaultdict):
    """Seconds spent in each phase, by name; ``with times("assemble"): ...`` adds the block's time."""

    def __init__(self):
        super().__init__(float)

    @contextmanager
    def __call__(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self[name] += time.perf_counter() - start
