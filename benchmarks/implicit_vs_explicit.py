"""Implicit against explicit MPM on the seed's dam break, side by side in one run: ``docs/implicit-vs-explicit.md``.

The seed (method.md, "Explicit comparison") ran an explicit MUSL MPM with water's bulk
modulus, 2.0 GPa: it diverged at dt = 1e-3, 1e-4 and 1e-5 s, ran at 1e-6 s with noisy,
partly negative pressures, and took 4547 s against the implicit scheme's 324 s for 2 s of
flow. This makes that comparison in one code -- the same grid (40 x 40 cells), basis
(quadratic B-splines), particles (800) and transfers -- and adds what weakly compressible
practice does instead: an artificial sound speed c0 = 10 sqrt(2 g H). It runs, in one
process, the four measurements (each a script of its own) and fills ``templates/implicit-vs-explicit.md``:

* ``stability_map.py``: which time steps each scheme survives;
* ``explicit_time_step.py``: the CFL safety factor at which the c0 run blows up;
* ``speed_error.py``: wall time per simulated second against the front's error, and the ratios;
* ``column_pressure.py``: pressure quality in a settled column.

Default: a short window (t <= 0.26 s, which covers T <= 3; a few minutes). ``--full``: 2 s of
flow, the seed's measure, with longer windows for the slow explicit runs (tens of minutes).

    python benchmarks/implicit_vs_explicit.py [--full] [--doc docs/implicit-vs-explicit.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from math import sqrt
from pathlib import Path

from mpi4py import MPI

import column_pressure
import explicit_time_step
import pages
import schemes
import speed_error
import stability_map
from fempm.explicit import ExplicitScheme
from schemes import C0, RHO, T_SCALE, WATER_K


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full", action="store_true", help="2 s of flow and long explicit windows (tens of minutes)")
    parser.add_argument("--doc", type=Path, default=pages.ROOT / "docs" / "implicit-vs-explicit.md",
                        help="the page to write")
    args = parser.parse_args(argv)
    if MPI.COMM_WORLD.size > 1:
        parser.error("run on one process: the study times one core")
    started, load = time.perf_counter(), os.getloadavg()
    w, mode = (schemes.FULL, "full") if args.full else (schemes.SHORT, "short")
    schemes.warm_up()
    runs = stability_map.measure(w)
    scan = explicit_time_step.measure(w)
    speed = speed_error.measure(w)
    columns = column_pressure.measure(w)

    figures = args.doc.parent / "implicit-vs-explicit"
    figures.mkdir(parents=True, exist_ok=True)
    stability_map.plot(figures / "stability.png", runs)
    speed_error.figures(figures, speed)
    column_pressure.plot(figures / "column_pressure.png", columns)
    pages.write(args.doc, pages.fill(
        "implicit-vs-explicit.md", flags=" --full" if args.full else "", mode=mode, load_start=f"{load[0]:.1f}",
        load_end=f"{os.getloadavg()[0]:.1f}", seconds=f"{time.perf_counter() - started:.0f}",
        h_mm=f"{1e3 * schemes.CELL:.1f}", c_water=f"{sqrt(WATER_K / RHO):.0f}", c0=f"{C0:.1f}",
        k0=f"{RHO * C0**2 / 1e6:.3g}", cfl=ExplicitScheme.cfl, w_dambreak=w.dambreak, t3=f"{3 / T_SCALE:.3f}",
        w_tiny=w.tiny_dt, w_scan=w.cfl_scan, w_column=w.column, stability_table=stability_map.table(runs),
        cfl_table=explicit_time_step.table(scan), speed_table=speed_error.speed_table(speed.implicit + speed.explicit),
        ratio_table=speed_error.ratio_table(speed.ratios, speed.implicit),
        seed_pair="\n".join(speed_error.seed_pair_lines(speed_error.seed_pair(speed))),
        column_table=column_pressure.table(columns),
        closing="\n".join(speed_error.summary_sentences(speed) + column_pressure.summary_sentences(columns)),
        **pages.provenance()))
    schemes.say(f"wrote {args.doc} in {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
