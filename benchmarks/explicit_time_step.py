"""The explicit scheme's time-step limit: the CFL safety factor C at which the c0 dam break blows up.

The dam break with the artificial sound speed c0 = 10 sqrt(2 g H) at C = 0.5, 0.7, 0.8, 0.9
and 1 (dt = C h / (c0 + sqrt(2 g H))): the measurement behind ``fempm.explicit.DEFAULT_CFL``.
A section of ``docs/implicit-vs-explicit.md``::

    python benchmarks/explicit_time_step.py [--full]
"""

from __future__ import annotations


import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
import pages
import schemes
from schemes import C0, Run, Windows

FACTORS = (0.5, 0.7, 0.8, 0.9, 1.0)


def measure(w: Windows) -> list[Run]:
    """The c0 dam break at each safety factor, for the scan's window."""
    schemes.say("explicit c0 dam break at several CFL safety factors")
    return [schemes.dambreak_run(f"explicit c0, C = {c:g}", "explicit", w.cfl_scan, sound_speed=C0, cfl=c)
            for c in FACTORS]


def table(scan: list[Run]) -> str:
    def row(r: Run) -> list[str]:
        outcome = "ran the window" if r.status == "completed" else f"stopped: {r.cause}"
        return [r.label.split("C = ")[1], f"{r.dt:.3g}", outcome, f"{r.time:.4g} s",
                f"{r.pressure[0] / 1e3:.3g} … {r.pressure[1] / 1e3:.3g}"]

    return pages.table(["C", "dt (s)", "outcome", "simulated time", "pressure range (kPa)"], map(row, scan))


if __name__ == "__main__":
    schemes.run_alone(__doc__, lambda w: print(table(measure(w))))
