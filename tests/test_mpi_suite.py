"""Runs every test marked ``mpi`` again on two MPI ranks, inside the ordinary suite."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from mpi4py import MPI

RANKS = 2


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="already running under mpirun")
def test_mpi_marked_tests_pass_on_two_ranks(request):
    mpirun = Path(sys.executable).parent / "mpirun"
    mpirun = str(mpirun) if mpirun.exists() else shutil.which("mpirun")
    assert mpirun, "mpirun not found next to the Python interpreter or on PATH"
    args = [mpirun, "-n", str(RANKS), sys.executable, "-m", "pytest", "-q", "-m", "mpi",
            "-p", "no:cacheprovider", str(Path(__file__).parent)]
    if request.config.getoption("--full"):
        args.append("--full")
    run = subprocess.run(args, capture_output=True, text=True, timeout=1800,
                         env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert run.returncode == 0, f"tests failed on {RANKS} ranks:\n{run.stdout[-6000:]}\n{run.stderr[-3000:]}"
