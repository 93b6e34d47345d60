"""A progress line for long runs: simulated time, wall time of the last step, ETA."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """Prints ``t = ... / T s [####....] 42 % | step 3.1 ms | ETA 12 s`` on rank 0.

    On a terminal the line is redrawn at most every ``interval`` seconds; in a log
    (not a terminal) a line is printed at every tenth of the run.
    """

    def __init__(self, end_time: float, comm, start_time: float = 0.0, interval: float = 0.25,
                 stream=None):
        self.end_time, self.start_time = end_time, start_time
        self.show = comm.rank == 0
        self.stream = stream or sys.stdout
        self.tty = self.stream.isatty()
        self.interval = interval
        self._wall0 = time.perf_counter()
        self._last_draw = -1.0
        self._last_tenth = -1

    def update(self, t: float, step_seconds: float):
        """Report simulated time ``t`` after a step that took ``step_seconds``."""
        if not self.show:
            return
        span = max(self.end_time - self.start_time, 1e-300)
        done = min(max((t - self.start_time) / span, 0.0), 1.0)
        now = time.perf_counter()
        tenth = int(done * 10)
        if self.tty and now - self._last_draw < self.interval and done < 1.0:
            return
        if not self.tty and tenth == self._last_tenth and done < 1.0:
            return
        self._last_draw, self._last_tenth = now, tenth
        elapsed = now - self._wall0
        eta = elapsed * (1 - done) / done if done > 0 else float("nan")
        bar = "#" * int(done * 20) + "." * (20 - int(done * 20))
        line = (f"t = {t:.4f} / {self.end_time:g} s [{bar}] {100 * done:3.0f} % | "
                f"step {1e3 * step_seconds:6.1f} ms | elapsed {elapsed:6.1f} s | ETA {eta:6.1f} s")
        self.stream.write(("\r" + line) if self.tty else (line + "\n"))
        self.stream.flush()

    def close(self):
        """End the line on a terminal."""
        if self.show and self.tty:
            self.stream.write("\n")
            self.stream.flush()
