"""Particle shifting (fempm.shifting): the neighbour sums are those of every pair and mirror image, a
lattice stays, disorder falls, the particles keep their values, particles at rest or along a free surface
stay, no mass moves on the whole, and the shifts are the same on one rank and on all."""

import numpy as np
import pytest
from mpi4py import MPI

import fempm  # noqa: F401  (dolfinx_solver first)
from fempm import shifting, transfer
from fempm.grid import Grid
from fempm.particles import Particles, Rectangle

MIRRORS = [True] * 4
DT = 0.01
A = 4.0


def _water(comm, upper=(1.0, 1.0), per_cell=4, cells=8, speed=1.0):
    """A block of water ``[0, 1] x [0, upper[1]]`` in the unit box, at a uniform speed."""
    grid = Grid.from_cells(comm, (0.0, 0.0), (1.0, 1.0), (cells, cells))
    water = Particles(grid)
    water.seed(Rectangle((0.0, 0.0), upper), per_cell=per_cell, density=1000.0)
    transfer.add_affine_fields(water, "affine-flip")
    water["velocity"][:] = (speed, 0.0)
    water.relocate()
    return water


def _disorder(water, dp):
    """The RMS over the particles of the shifts' gradient, times dp (0 on a lattice)."""
    hk = shifting.SMOOTHING * dp
    grad, conc = np.empty((len(water), 2)), np.empty(len(water))
    shifting.concentration_gradients(water.x, water["volume"], len(water), water.grid.lower, water.grid.upper,
                                     np.array(MIRRORS), hk, shifting.kernel_at_spacing(hk, dp), grad, conc)
    return float(np.sqrt(np.mean(np.sum(grad**2, axis=1)))) * dp


def _direct_sums(x, volume, n_own, mirror, hk, w_dp):
    """The module's ``g_i`` and ``conc_i`` summed over every point and every image of it across the mirrored
    sides of the unit box (and across both at a corner), pair by pair in numpy: the reference."""
    norm = 7.0 / (4.0 * np.pi * hk * hk)
    images = [x]
    for axis, (low, high) in enumerate((mirror[:2], mirror[2:])):
        for side, on in ((0.0, low), (1.0, high)):
            if on:
                images += [np.column_stack([2 * side - y[:, 0], y[:, 1]]) if axis == 0
                           else np.column_stack([y[:, 0], 2 * side - y[:, 1]]) for y in list(images)]
    others = np.concatenate(images)
    weights = np.tile(volume, len(images))
    d = x[:n_own, None, :] - others[None, :, :]
    r = np.linalg.norm(d, axis=2)
    q = r / hk
    t = np.clip(1.0 - 0.5 * q, 0.0, None)
    w = norm * t**4 * (2.0 * q + 1.0)
    dw_dr = -5.0 * norm * q * t**3 / hk
    factor = weights * (1.0 + shifting.TENSILE * (w / w_dp) ** 4) * np.divide(dw_dr, r, out=np.zeros_like(r), where=r > 0)
    return np.einsum("ij,ijk->ik", factor, d), (weights * w).sum(axis=1)


def test_the_neighbour_sums_are_those_of_every_pair_and_image():
    """The binned sums, each pair taken once for both points, against every pair and image summed directly:
    disordered points of which the last 30 are another rank's (they count for the others, their own sums are not
    asked), a side without a mirror, points in the corners."""
    water = _water(MPI.COMM_SELF)
    dp = shifting.spacing(water)
    rng = np.random.default_rng(7)
    x = np.clip(water.x + rng.uniform(-0.3, 0.3, water.x.shape) * dp, 1e-9, 1 - 1e-9)
    volume = water["volume"] * rng.uniform(0.8, 1.2, len(x))
    n_own, mirror = len(x) - 30, np.array([True, False, True, True])
    hk = shifting.SMOOTHING * dp
    w_dp = shifting.kernel_at_spacing(hk, dp)
    grad, conc = np.full((n_own, 2), np.nan), np.full(n_own, np.nan)
    shifting.concentration_gradients(x, volume, n_own, water.grid.lower, water.grid.upper, mirror, hk, w_dp, grad,
                                     conc)
    expected_grad, expected_conc = _direct_sums(x, volume, n_own, mirror, hk, w_dp)
    assert np.abs(grad - expected_grad).max() < 1e-13 * np.abs(expected_grad).max()  # measured 1.5e-15
    assert np.abs(conc - expected_conc).max() < 1e-13 * expected_conc.max()  # measured 4.6e-16 (without the images 0.40)


def test_a_lattice_filling_a_mirrored_box_does_not_move():
    water = _water(MPI.COMM_SELF)
    dp = shifting.spacing(water)
    shifts = shifting.ParticleShifting(water, A, MIRRORS)(water, DT)
    assert np.abs(shifts).max() < 1e-12 * dp  # measured 3e-17 dp


def test_shifting_spreads_a_disordered_lattice_and_the_particles_keep_their_values():
    water = _water(MPI.COMM_SELF)
    dp = shifting.spacing(water)
    rng = np.random.default_rng(3)
    water.fields["x"] = np.clip(water.x + rng.uniform(-0.25, 0.25, water.x.shape) * dp, 1e-9, 1 - 1e-9)
    state = {name: water[name].copy() for name in ("velocity", "acceleration", "affine_velocity")}
    before = _disorder(water, dp)
    shift = shifting.ParticleShifting(water, A, MIRRORS)
    for _ in range(30):
        shift(water, DT)
    after = _disorder(water, dp)
    assert after < 0.08 * before  # measured 0.019 of 0.433
    assert all(np.array_equal(water[name], value) for name, value in state.items())


def test_particles_at_rest_or_along_a_free_surface_stay_and_the_mass_does_not_move():
    water = _water(MPI.COMM_SELF, upper=(1.0, 0.5), speed=0.0)
    dp = shifting.spacing(water)
    water.fields["x"][:, 0] += 0.1 * dp * np.sin(40 * water.x[:, 1])  # disorder
    shift = shifting.ParticleShifting(water, A, MIRRORS)
    assert not shift(water, DT).any()
    water["velocity"][:] = (1.0, 0.0)
    top = water.x[:, 1] > 0.5 - dp  # the top row: its kernel (2.6 dp) reaches well into air, not full
    x0 = water.x.copy()
    shifts = shift(water, DT)
    assert np.array_equal(water.x[top], x0[top])
    assert np.abs(shifts).max() > 0.05 * dp  # measured 0.091 dp
    assert np.abs(water["mass"] @ shifts).max() < 1e-15 * water["mass"].sum() * dp  # measured 2e-19


def test_below_the_rest_speed_the_shifts_fade_as_the_speed_squared():
    """A disordered lattice at one speed: at half the rest speed the shifts are a quarter of those without a rest
    speed (each particle's and their mean alike), at twice it the same to the bit."""
    shifts = {}
    for speed, rest in ((0.1, 0.0), (0.1, 0.2), (0.4, 0.0), (0.4, 0.2)):  # no shift reaches the cap
        water = _water(MPI.COMM_SELF, speed=speed)
        dp = shifting.spacing(water)
        water.fields["x"] = np.clip(water.x + np.random.default_rng(3).uniform(-0.25, 0.25, water.x.shape) * dp,
                                    1e-9, 1 - 1e-9)
        shifts[speed, rest] = shifting.ParticleShifting(water, A, MIRRORS, rest_speed=rest)(water, DT)
    assert np.abs(shifts[0.1, 0.0]).max() > 0.01 * dp  # measured 0.047 dp: the case moves
    assert np.allclose(shifts[0.1, 0.2], 0.25 * shifts[0.1, 0.0], rtol=1e-12, atol=0.0)
    assert np.array_equal(shifts[0.4, 0.2], shifts[0.4, 0.0])


@pytest.mark.mpi
def test_shifts_are_the_same_on_one_rank_and_on_all():
    results = {}
    for name, comm in (("all", MPI.COMM_WORLD), ("one", MPI.COMM_SELF)):
        water = _water(comm)
        dp = shifting.spacing(water)
        water.fields["x"] = water.x + 0.1 * dp * np.sin(17 * water.x[:, ::-1])
        shifts = shifting.ParticleShifting(water, A, MIRRORS)(water, DT)
        order = np.argsort(np.concatenate(comm.allgather(water.id)))
        results[name] = np.concatenate(comm.allgather(shifts))[order]
    assert np.abs(results["all"]).max() > 0
    assert np.allclose(results["all"], results["one"], rtol=0, atol=1e-15)  # the same to round-off


def _cross(a, b):
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


@pytest.mark.mpi
def test_the_shifts_of_a_rotating_body_add_no_angular_momentum(comm):
    """A disordered lattice in rigid rotation: the shifts move it (so they would add ``sum m dr x v``) but
    take a common turn that leaves the angular momentum as it was, and the mass does not move."""
    water = _water(comm)
    dp = shifting.spacing(water)
    water.fields["x"] = water.x + 0.1 * dp * np.sin(17 * water.x[:, ::-1])
    r = water.x - 0.5
    water["velocity"][:] = np.column_stack([-r[:, 1], r[:, 0]]) + (0.3, 0.0)

    def angular_momentum():
        return comm.allreduce(float(water["mass"] @ _cross(water.x - 0.5, water["velocity"])))

    before = angular_momentum()
    shifts = shifting.ParticleShifting(water, A, MIRRORS, keep_angular_momentum=True)(water, DT)
    size = comm.allreduce(float(water["mass"] @ np.linalg.norm(shifts, axis=1)))
    assert comm.allreduce(np.abs(shifts).max(initial=0.0), op=MPI.MAX) > 0.05 * dp  # measured 0.087 dp
    # measured 0 (without the turn: -0.28 times sum m |dr|, in units of the speed)
    assert abs(angular_momentum() - before) < 1e-13 * size
    assert np.abs(comm.allreduce(water["mass"] @ shifts)).max() < 1e-13 * size  # measured 1.5e-15
