"""Particle shifting (fempm.shifting): a lattice stays, disorder falls, affine fields are carried
exactly, a free surface does not move, and the shifts are the same on one rank and on all."""

import numpy as np
import pytest
from mpi4py import MPI

import fempm  # noqa: F401  (dolfinx_solver first)
from fempm import shifting, transfer
from fempm.grid import Grid
from fempm.particles import Particles, Rectangle

MIRRORS = [True] * 4
DT = 0.01


def _water(comm, upper=(1.0, 1.0), per_cell=4, cells=8, speed=1.0):
    """A block of water ``[0, 1] x [0, upper[1]]`` in the unit box, at a uniform speed."""
    grid = Grid.from_cells(comm, (0.0, 0.0), (1.0, 1.0), (cells, cells))
    water = Particles(grid)
    water.seed(Rectangle((0.0, 0.0), upper), per_cell=per_cell, density=1000.0)
    transfer.add_affine_fields(water, "affine-flip")
    water["velocity"][:] = (speed, 0.0)
    water.relocate()
    return water


def _concentration_spread(water, dp):
    """The relative spread (std / mean) of the kernel concentration over the particles."""
    hk = shifting.SMOOTHING * dp
    conc, grad = np.empty(len(water)), np.empty((len(water), 2))
    t = 1.0 - 0.5 / shifting.SMOOTHING
    w_dp = 7.0 / (4.0 * np.pi * hk * hk) * t**4 * (2.0 / shifting.SMOOTHING + 1.0)
    shifting._concentration_gradients(water.x, water["volume"], len(water), water.grid.lower, water.grid.upper,
                                      np.array(MIRRORS), hk, w_dp, conc, grad)
    return conc.std() / conc.mean()


def test_a_lattice_filling_a_mirrored_box_does_not_move():
    water = _water(MPI.COMM_SELF)
    dp = shifting.spacing(water)
    shifts = shifting.shift(water, DT, 4.0, MIRRORS, dp)
    assert np.abs(shifts).max() < 1e-12 * dp  # measured 0 to round-off


def test_shifting_spreads_a_disordered_lattice_and_carries_an_affine_field_exactly():
    water = _water(MPI.COMM_SELF)
    dp = shifting.spacing(water)
    rng = np.random.default_rng(3)
    water.fields["x"] = np.clip(water.x + rng.uniform(-0.25, 0.25, water.x.shape) * dp, 1e-9, 1 - 1e-9)
    G = np.array([[0.3, -1.0], [1.0, -0.3]])  # a divergence-free affine velocity field
    water["velocity"][:] = 2.0 + water.x @ G.T
    water["affine_velocity"][:] = G
    before = _concentration_spread(water, dp)
    for _ in range(30):
        shifting.shift(water, DT, 4.0, MIRRORS, dp)
    after = _concentration_spread(water, dp)
    assert after < 0.6 * before  # measured 0.037 of 0.074
    assert np.allclose(water["velocity"], 2.0 + water.x @ G.T, rtol=0, atol=1e-13)


def test_particles_at_rest_and_along_a_free_surface_stay():
    water = _water(MPI.COMM_SELF, upper=(1.0, 0.5), speed=0.0)
    dp = shifting.spacing(water)
    assert not shifting.shift(water, DT, 4.0, MIRRORS, dp).any()
    water["velocity"][:] = (1.0, 0.0)
    top = water.x[:, 1] > 0.5 - dp
    x0 = water.x.copy()
    water.fields["x"][:, 0] += 0.1 * dp * np.sin(40 * water.x[:, 1])  # disorder below the surface
    shifts = shifting.shift(water, DT, 4.0, MIRRORS, dp)
    assert not shifts[top].any()  # the top row's support is not full
    assert water.x[:, 1].max() == x0[:, 1].max()


@pytest.mark.mpi
def test_shifts_are_the_same_on_one_rank_and_on_all():
    results = {}
    for name, comm in (("all", MPI.COMM_WORLD), ("one", MPI.COMM_SELF)):
        water = _water(comm)
        dp = shifting.spacing(water)
        water.fields["x"] = water.x + 0.1 * dp * np.sin(17 * water.x[:, ::-1])
        shifts = shifting.shift(water, DT, 4.0, MIRRORS, dp)
        ids = comm.allgather(water.id)
        every = comm.allgather(shifts)
        order = np.argsort(np.concatenate(ids))
        results[name] = np.concatenate(every)[order]
    assert np.abs(results["all"]).max() > 0
    assert np.allclose(results["all"], results["one"], rtol=0, atol=1e-15)
