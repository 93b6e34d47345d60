"""The demos run and reach their stated accuracy (short versions)."""

import sys
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

sys.path.insert(0, str(Path(__file__).parents[1] / "demos"))

import stokes_particles  # noqa: E402

import fempm  # noqa: E402


@pytest.mark.parametrize("Basis", [fempm.Q1, fempm.BSpline2])
def test_stokes_on_lattice_particles_converges_at_second_order(Basis):
    coarse, fine = (stokes_particles.solve(n, Basis, MPI.COMM_WORLD, jitter=0.0) for n in (8, 16))
    rate = np.log2(coarse / fine)
    assert 1.9 < rate < 2.1
    assert fine < 2e-4  # against the exact solution, L2 norm of the velocity error
