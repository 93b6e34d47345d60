"""Wall time of 2 s of the seed's dam break on one core, split by phase.

The seed (method.md) reports 324 s for 2 s of flow with its implicit MPM. This runs
the same case (40 x 40 cells, 800 particles, dt = 1e-3 s, B-spline) and, side by
side in the same invocation, the Q1 basis and the B-spline at dt = 2e-3 s, and
prints the time per phase and the ratio to the seed's 324 s.

    python benchmarks/dambreak_speed.py [--end-time 2.0]
"""

import argparse
import time

from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm.cases import dambreak
from fempm.simulation import build_solver

SEED_SECONDS = 324.0


def timed_run(end_time: float, basis: str, dt: float) -> dict:
    """Run the dam break without output files; the solver's phase timings and the total."""
    scene = dambreak.scene({"solver.basis": basis, "time.end": end_time, **dambreak.seed_setup(dt)}, files=False)
    solver = build_solver(scene, MPI.COMM_WORLD)
    start = time.perf_counter()
    for _ in range(scene.time.steps):
        solver.step()
    total = time.perf_counter() - start
    return {"total": total, **solver.timings, "steps": solver.steps}


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--end-time", type=float, default=2.0, help="simulated seconds (default 2)")
    args = parser.parse_args()
    cases = [
        ("B-spline, dt = 1e-3 s (the seed's)", "bspline", 1e-3),
        ("B-spline, dt = 2e-3 s", "bspline", 2e-3),
        ("Q1, dt = 1e-3 s", "q1", 1e-3),
    ]
    phases = ("project", "assemble", "solve", "update", "relocate")
    if MPI.COMM_WORLD.rank == 0:
        print(f"dam break, {args.end_time:g} s of flow, {MPI.COMM_WORLD.size} rank(s); seconds")
        print(f"{'case':36s} {'total':>7s} " + " ".join(f"{p:>9s}" for p in phases) + "   seed / this")
    for name, basis, dt in cases:
        t = timed_run(args.end_time, basis, dt)
        if MPI.COMM_WORLD.rank == 0:
            scaled_seed = SEED_SECONDS * args.end_time / 2.0
            print(f"{name:36s} {t['total']:7.2f} " + " ".join(f"{t.get(p, 0.0):9.2f}" for p in phases)
                  + f"   {scaled_seed / t['total']:6.1f}x")


if __name__ == "__main__":
    main()
