"""Does the volume correction keep a free surface where it is? (issue 11, item 4)

Two cases (ported from the spike's benchmark onto fempm.options), each with the scheme's
volume correction ``--alpha`` (method.md eq. 3; 0: off):

* ``column``: the dam-break column at rest in a tank as wide as it (10 x 40 cells, 2 x 2
  particles per cell) for ``--column-time`` seconds (default 10; issue 11's target: volume
  within 0.2 %, speeds below 1e-3 m/s);
* ``slosh``: water 0.15 m deep in a 0.4 x 0.3 m tank (20 x 15 cells), released at rest with its
  surface tilted by +-2 cm (the first sloshing mode, period about 0.8 s), ``--slosh-time``
  seconds (default 5).

The volume of a case is its width times the mean over the grid's columns of the height of the
free surface, found on each column's centre line as the highest point where the wet fraction
(:class:`fempm.gauges.WetFraction`) reaches 1/2 (linear between points an eighth of a cell
apart). (The particles' own volume is constant; what the correction changes is how far apart
they stand, so the surface's height.) A sloshing surface's volume so measured swings by about
0.1 % within a period, so beside the change at the end each case reports the change of the
mean over its last 1.6 s (two sloshing periods) and the drift per second, the slope of a
straight line fitted to the volume after the first half second, over the starting volume::

    python benchmarks/free_surface_volume.py [--cases column slosh] [--alpha 0.1] [--surface-aware] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from mpi4py import MPI

import fempm
from fempm.errors import SimulationDiverged
from fempm.gauges import WetFraction, _Points
from fempm.implicit import ImplicitSolver
from fempm.options import Scheme

RHO = 1000.0


class SurfaceLevel:
    """The mean height of the free surface over a grid's columns (the wet fraction's 1/2 level)."""

    def __init__(self, basis, per_cell: int = 8):
        grid = basis.grid
        x = grid.lower[0] + grid.h * (np.arange(grid.nx) + 0.5)
        self.y = grid.lower[1] + grid.h * np.arange(grid.ny * per_cell + 1) / per_cell
        self.points = _Points(grid, np.column_stack([np.repeat(x, len(self.y)), np.tile(self.y, len(x))]))
        self.wet, self.shape, self.grid, self.tilt = WetFraction(basis), (len(x), len(self.y)), grid, 0.0

    def __call__(self, particles) -> float:
        values = self.grid.comm.allreduce(self.points.local(self.wet(particles))).reshape(self.shape)
        wet = values >= 0.5
        k = np.clip(len(self.y) - 1 - np.argmax(wet[:, ::-1], axis=1), 0, len(self.y) - 2)  # highest wet point
        columns = np.arange(len(k))
        below, above = values[columns, k], values[columns, k + 1]
        share = np.clip((below - 0.5) / np.where(below > above, below - above, 1.0), 0.0, 1.0)
        top = np.where(wet.any(axis=1), self.y[k] + share * (self.y[1] - self.y[0]), self.grid.lower[1])
        self.tilt = float(top[0] - top[-1]) / 2  # half the difference between the end columns
        return float(np.mean(top) - self.grid.lower[1])


def column(scheme: Scheme, per_cell: int = 2, comm=MPI.COMM_WORLD) -> ImplicitSolver:
    """The dam-break column at rest between walls as far apart as it is wide."""
    grid = fempm.Grid.from_cells(comm, (0.0, 0.0), (0.146, 0.584), (10, 40))
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (0.146, 0.292)), per_cell=per_cell, density=RHO)
    return ImplicitSolver(fempm.BSpline2(grid), water, scheme=scheme)


def slosh(scheme: Scheme, per_cell: int = 2, comm=MPI.COMM_WORLD) -> ImplicitSolver:
    """Water 0.15 m deep in a 0.4 m wide tank, its surface tilted by +-2 cm."""
    width, depth, tilt = 0.4, 0.15, 0.02
    grid = fempm.Grid.from_cells(comm, (0.0, 0.0), (width, 0.3), (20, 15))
    water = fempm.Particles(grid)
    water.seed(fempm.Polygon(((0.0, 0.0), (width, 0.0), (width, depth - tilt), (0.0, depth + tilt))),
               per_cell=per_cell, density=RHO)
    return ImplicitSolver(fempm.BSpline2(grid), water, scheme=scheme)


CASES = {"column": column, "slosh": slosh}


#: the time (s) at the end of a run over which the volume is averaged: two periods of the slosh
LATE = 1.6


def run_case(name: str, scheme: Scheme, end_time: float, every: float = 0.01, per_cell: int = 2) -> dict:
    """Run a case (``per_cell`` x ``per_cell`` particles per cell); its volume's change at the end and of its
    mean over the last :data:`LATE` seconds, its drift and final speeds."""
    solver = CASES[name](scheme, per_cell)
    level = SurfaceLevel(solver.basis)
    width = solver.grid.upper[0] - solver.grid.lower[0]
    k = max(int(round(every / scheme.dt)), 1)
    history = [(0.0, level(solver.particles) * width, level.tilt)]
    status, start = "completed", time.perf_counter()
    try:
        for n in range(int(round(end_time / scheme.dt))):
            solver.step()
            if (n + 1) % k == 0:
                history.append((solver.time, level(solver.particles) * width, level.tilt))
    except SimulationDiverged as e:
        status = f"stopped: {e}"
    h = np.array(history)
    late = h[:, 0] >= 0.5
    slope = float(np.polyfit(h[late, 0], h[late, 1], 1)[0]) if np.count_nonzero(late) > 2 else float("nan")
    speed = solver.grid.comm.allreduce(float(np.abs(solver.particles["velocity"]).max(initial=0.0)), op=MPI.MAX)
    return {"case": name, "status": status, "time": solver.time, "wall_s": time.perf_counter() - start,
            "volume_start_m2": h[0, 1], "volume_end_m2": h[-1, 1], "change": h[-1, 1] / h[0, 1] - 1,
            "late_change": float(h[h[:, 0] > h[-1, 0] - LATE, 1].mean() / h[0, 1] - 1),
            "drift_per_s": slope / h[0, 1], "max_speed_end": speed,
            "tilt_first_s": float(np.abs(h[h[:, 0] <= 1.0, 2]).max()),
            "tilt_last_s": float(np.abs(h[h[:, 0] >= h[-1, 0] - 1.0, 2]).max())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--alpha", type=float, default=Scheme.alpha, help="volume correction (default 0.1)")
    parser.add_argument("--surface-aware", action="store_true", help="Scheme.surface_aware (fempm.density)")
    parser.add_argument("--shifting", type=float, default=Scheme.shifting, help="Scheme.shifting (fempm.shifting)")
    parser.add_argument("--column-time", type=float, default=10.0)
    parser.add_argument("--slosh-time", type=float, default=5.0)
    parser.add_argument("--per-cell", type=int, default=2, help="N x N particles per cell (default 2)")
    parser.add_argument("--out", help="write the results as JSON here")
    args = parser.parse_args(argv)
    scheme = Scheme(alpha=args.alpha, surface_aware=args.surface_aware, shifting=args.shifting)
    results = [run_case(name, scheme, args.column_time if name == "column" else args.slosh_time,
                        per_cell=args.per_cell) for name in args.cases]
    if MPI.COMM_WORLD.rank == 0:
        for r in results:
            print(f"{r['case']:7s} alpha {args.alpha:g}{' surface-aware' if args.surface_aware else ''}{f' shifting {args.shifting:g}' if args.shifting else ''}, "
                  f"{args.per_cell} x {args.per_cell} per cell: {r['status']}, t = {r['time']:.2f} s, volume change "
                  f"{r['change']:+.3%} (its last {LATE:g} s {r['late_change']:+.3%}), drift {r['drift_per_s']:+.3%}/s, max speed {r['max_speed_end']:.2e} m/s, "
                  f"tilt {1000 * r['tilt_first_s']:.1f} -> {1000 * r['tilt_last_s']:.1f} mm")
        if args.out:
            with open(args.out, "w") as f:
                json.dump({"alpha": args.alpha, "surface_aware": args.surface_aware, "shifting": args.shifting, "results": results}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
