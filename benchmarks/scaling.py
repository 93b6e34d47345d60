"""Strong scaling of the dam break: time per step and peak memory, direct against iterative, 1 against 2 ranks.

The shipped dam-break scene (``scenes/dambreak.toml``) refined until it holds about
1e4, 1e5 and 1e6 particles (2 x 2 per cell, the column an eighth of the tank, so
``N x N`` cells give ``N^2 / 2`` particles). Each case runs in its own
``mpirun -n R`` process: build the scene, take one step (warm-up), then time
``--steps`` steps. Peak memory is the sum over the ranks of each process's peak
resident set. Prints one table; the strong-scaling ratio is t(1 rank) / t(2 ranks).

"direct" is the default exact solve: on one rank the Schur complement solved to round-off
(``fempm.linear.EXACT``), on several ranks MUMPS LU of a whole copy on every rank (see
``fempm.linear.direct_options``), so its memory grows with the ranks: above
``--direct-limit`` particles it runs on one rank only (1e6 particles took 14.5 GB on
one rank; on two the machine's 23 GB ran out).

    python benchmarks/scaling.py [--sizes 1e4 1e5 1e6] [--steps 2] [--ranks 1 2] [--direct-limit 2e5]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"


def cells_for(particles: float) -> int:
    """Cells per side (a multiple of 4, so the column is whole cells) for about ``particles`` particles."""
    return max(4 * round((2 * particles) ** 0.5 / 4), 8)


def measure(particles: float, linear: str, steps: int) -> dict:
    """Build the refined scene on COMM_WORLD, warm up one step, time ``steps`` steps."""
    import fempm  # noqa: F401
    from mpi4py import MPI

    from fempm.cases import dambreak
    from fempm.scene import Output, load_scene
    from fempm.simulation import build_solver

    comm = MPI.COMM_WORLD
    n = cells_for(particles)
    scene = load_scene(SCENE)
    scene = replace(dambreak.at_seed_setup(scene), domain=replace(scene.domain, cells=(n, n)),  # the table's step
                    output=Output(folder="unused"), solver=replace(scene.solver, linear=linear))
    start = time.perf_counter()
    solver = build_solver(scene, comm)
    build = time.perf_counter() - start
    solver.step()
    solver.timings.clear()
    comm.barrier()
    start = time.perf_counter()
    for _ in range(steps):
        solver.step()
    comm.barrier()
    per_step = (time.perf_counter() - start) / steps
    peak_kb = comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, op=MPI.SUM)
    return {"particles": solver.particles.global_count(), "cells": n, "ranks": comm.size, "linear": linear,
            "build_s": build, "step_s": per_step, "peak_GB": peak_kb / 1024**2,
            "phases_s": {k: v / steps for k, v in solver.timings.items()},
            "iterations": solver.system.linear_solver.ksp.getIterationNumber()}


def run_case(particles: float, linear: str, ranks: int, steps: int) -> dict:
    """One case in its own ``mpirun -n ranks`` process."""
    mpirun = str(Path(sys.executable).parent / "mpirun")
    command = [mpirun, "-n", str(ranks), sys.executable, __file__, "--measure", str(particles), linear,
               "--steps", str(steps)]
    result = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    if result.returncode != 0:
        return {"error": f"failed ({result.returncode})"}
    return json.loads(result.stdout.strip().splitlines()[-1])


def main(argv=None):
    """Run every case and print the table."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    parser.add_argument("--steps", type=int, default=2, help="timed steps per case (after one warm-up step)")
    parser.add_argument("--ranks", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--direct-limit", type=float, default=2e5,
                        help="above this many particles the direct solver runs on one rank only")
    parser.add_argument("--measure", nargs=2, metavar=("PARTICLES", "LINEAR"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.measure:
        result = measure(float(args.measure[0]), args.measure[1], args.steps)
        from mpi4py import MPI

        if MPI.COMM_WORLD.rank == 0:
            print(json.dumps(result))
        return
    print(f"dam break, one step (mean of {args.steps} after a warm-up step); time s / peak memory GB "
          f"(sum over ranks); OMP_NUM_THREADS=1; ranks {args.ranks}")
    header = f"{'particles':>10} {'cells':>7} {'solver':>9} " + " ".join(
        f"{f'{r} rank':>18}" for r in args.ranks) + f" {'t1/t2':>6} {'its':>4}  phases, s ({' | '.join(map(str, args.ranks))} ranks)"
    print(header)
    for size in args.sizes:
        for linear in ("direct", "iterative"):
            skip = linear == "direct" and size > args.direct_limit
            results = {r: {"error": "skipped (memory)"} if skip and r > 1 else run_case(size, linear, r, args.steps)
                       for r in args.ranks}
            first = next((v for v in results.values() if "error" not in v), None)
            cells = f"{cells_for(size)}^2"
            count = first["particles"] if first else "-"  # counted by a run only
            columns = " ".join(f"{v['error']:>18}" if "error" in v else
                               f"{v['step_s']:8.3f} s {v['peak_GB']:5.2f} GB" for v in results.values())
            ok = [v for v in results.values() if "error" not in v]
            ratio = f"{ok[0]['step_s'] / ok[-1]['step_s']:6.2f}" if len(ok) == len(results) > 1 else f"{'-':>6}"
            phases = " ".join(f"{k} " + " | ".join(f"{v['phases_s'][k]:.2f}" for v in ok)
                              for k in ok[0]["phases_s"]) if ok else ""
            iterations = ok[-1]["iterations"] if ok else 0
            print(f"{count:>10} {cells:>7} {linear:>9} {columns} {ratio} {iterations:>4}  {phases}", flush=True)


if __name__ == "__main__":
    main()
