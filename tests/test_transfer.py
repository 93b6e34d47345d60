"""P2G and G2P: consistency with the assembled matrices and exactness on linear fields."""

import numpy as np
import pytest
import ufl

import fempm
from fempm import transfer

from helpers import random_particles

BASES = [fempm.Q1, fempm.BSpline2]


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", BASES)
def test_lumped_mass_is_the_row_sum_of_the_particle_mass_matrix(comm, Basis):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    space = fempm.Space(Basis(grid), {"m": 1})
    particles = random_particles(grid, [0, 3, 1, 7])
    M = fempm.ParticleForm(lambda s: s.particle("density") * s.trial * s.test * s.dx, space, particles)
    A = M.assemble_matrix(particles)
    ones, rows = A.createVecs()
    ones.set(1.0)
    A.mult(ones, rows)
    m = transfer.lumped_mass(space, particles)
    owned = m.values[: space.numbering.num_owned, 0]
    np.testing.assert_allclose(owned, rows.getArray(), rtol=1e-13, atol=1e-13 * owned.max())
    total = comm.allreduce(owned.sum())
    assert total == pytest.approx(comm.allreduce(particles["mass"].sum()), rel=1e-13)


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", BASES)
def test_momentum_matches_the_linear_form(comm, Basis):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    space = fempm.Space(Basis(grid), {"v": 2})
    particles = random_particles(grid, [2, 1, 4])
    particles["velocity"][:] = np.column_stack([particles.x[:, 1], -particles.x[:, 0] ** 2])
    form = fempm.ParticleForm(
        lambda s: s.particle("density") * ufl.inner(s.particle("velocity"), s.test) * s.dx, space, particles)
    b = form.assemble_vector(particles)
    p = transfer.momentum(space, particles)
    n = space.num_owned_dofs
    np.testing.assert_allclose(p.vector.array[:n], b.array[:n], rtol=1e-12, atol=1e-12 * np.abs(b.array).max())


@pytest.mark.parametrize("Basis", BASES)
def test_g2p_reproduces_linear_fields_and_their_gradients(comm, Basis):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    space = fempm.Space(Basis(grid), {"v": 2})
    particles = random_particles(grid, [3])
    # both bases reproduce linear functions: fit coefficients by the nodal rule of each basis
    lf = space.numbering.local_functions
    i, j = lf % space.basis.nfx, lf // space.basis.nfx
    if Basis is fempm.Q1:
        xc, yc = i * grid.h, j * grid.h
    else:  # Greville abscissae of the clamped quadratic B-splines
        greville = lambda k, n: grid.h * np.clip(k - 0.5, 0, n)  # noqa: E731
        xc, yc = greville(i, grid.nx), greville(j, grid.ny)
    f = fempm.GridFunction(space)
    f.values[:] = np.column_stack([2 + 3 * xc - yc, 0.5 * yc])
    values = transfer.grid_to_particles(f, particles)
    x = particles.x
    np.testing.assert_allclose(values, np.column_stack([2 + 3 * x[:, 0] - x[:, 1], 0.5 * x[:, 1]]), atol=1e-13)
    grads = transfer.grid_gradient_to_particles(f, particles)
    np.testing.assert_allclose(grads[:, 0], np.tile([3.0, -1.0], (len(x), 1)), atol=1e-12)
    np.testing.assert_allclose(grads[:, 1], np.tile([0.0, 0.5], (len(x), 1)), atol=1e-12)


@pytest.mark.parametrize("Basis", BASES)
def test_smoothed_density_of_a_full_grid_is_the_density(comm, Basis):
    """eq. (2): water seeded everywhere gives rho~_i = rho at every function, normalised by the
    seeding lattice's rule; with Gauss-exact integrals, at the interior ones (where the
    lattice's composite midpoint rule is exact)."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    space = fempm.Space(Basis(grid), {"rho": 1})
    particles = fempm.Particles(grid)
    particles.seed(fempm.Rectangle((0.0, 0.0), (1.0, 1.0)), per_cell=4, density=1000.0)
    mass = transfer.lumped_mass(space, particles).values
    local = space.numbering.local_functions
    owned = space.numbering.num_owned
    lattice = transfer.density_normalisation(space.basis, particles)[local]
    np.testing.assert_allclose(transfer.smoothed_density(mass[:owned, 0], lattice[:owned]), 1000.0, rtol=1e-12)
    exact = transfer.smoothed_density(mass[:owned, 0], space.basis.integrals[local][:owned])
    i, j = local[:owned] % space.basis.nfx, local[:owned] // space.basis.nfx
    interior = (i >= 2) & (i < space.basis.nfx - 2) & (j >= 2) & (j < space.basis.nfy - 2)
    np.testing.assert_allclose(exact[interior], 1000.0, rtol=1e-12)
