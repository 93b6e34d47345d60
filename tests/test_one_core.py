"""A run on one rank keeps to one core.

numpy's OpenBLAS splits a product over more than about 10,000 entries (a dot product over all
particles, a residual's norm) across its threads, which then spin between calls: a one-rank run of
28k particles used two cores for the wall time of one, and two such runs side by side on two cores
each took 1.6 times as long. fempm's per-step reductions are ``np.einsum`` sums, which no BLAS
thread takes. The check counts the CPU ticks of the process's threads other than the main one
while a 12,800-particle dam break steps, its BLAS given two threads.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from mpi4py import MPI

SCRIPT = """
import os
from mpi4py import MPI
import fempm
from fempm.cases import dambreak
from fempm.simulation import build_solver

solver = build_solver(dambreak.scene({"domain.cells": [160, 160], "bodies.0.particles_per_cell": 4}, files=False),
                      MPI.COMM_WORLD)


def ticks():
    main = others = 0
    for tid in os.listdir("/proc/self/task"):
        with open(f"/proc/self/task/{tid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
        used = int(fields[11]) + int(fields[12])  # utime + stime
        if int(tid) == os.getpid():
            main += used
        else:
            others += used
    return main, others


solver.step()
main, others = ticks()
for _ in range(20):
    solver.step()
print(*(after - before for after, before in zip(ticks(), (main, others))))
"""


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own interpreter")
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads the threads' CPU ticks from /proc")
def test_a_one_rank_run_leaves_the_blas_threads_idle():
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
    run = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    main, others = map(int, run.stdout.split()[-2:])
    print(main, others)
    assert main > 0
    # measured 0 ticks against the main thread's 78; with the products as BLAS calls, 79 against 78
    assert others <= 0.05 * main
