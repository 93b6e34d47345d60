"""P2G and G2P: consistency with the assembled matrices and exactness on linear fields."""

from mpi4py import MPI
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


@pytest.mark.parametrize("upper", [(1.0, 1.0), (0.97, 0.93)])  # the second cut: its last column 0.7 h, row 0.3 h
@pytest.mark.parametrize("Basis", BASES)
def test_smoothed_density_of_a_full_grid_is_the_density(comm, Basis, upper):
    """eq. (2): water seeded everywhere gives rho~_i = rho at every function, normalised by the
    seeding lattice's rule (a cut cell's lattice shrunk onto it); with Gauss-exact integrals, at
    the interior ones away from a cut (where the lattice's composite midpoint rule is exact)."""
    grid = fempm.Grid(comm, (0.0, 0.0), upper, 0.1)
    space = fempm.Space(Basis(grid), {"rho": 1})
    particles = fempm.Particles(grid)
    particles.seed(fempm.Rectangle((0.0, 0.0), upper), per_cell=4, density=1000.0)
    assert particles.grid.comm.allreduce(particles["volume"].sum()) == pytest.approx(np.prod(upper), rel=1e-13)
    mass = transfer.lumped_mass(space, particles).values
    local = space.numbering.local_functions
    owned = space.numbering.num_owned
    lattice = transfer.density_normalisation(space.basis, particles)[local]
    np.testing.assert_allclose(transfer.smoothed_density(mass[:owned, 0], lattice[:owned]), 1000.0, rtol=1e-12)
    exact = transfer.smoothed_density(mass[:owned, 0], space.basis.integrals[local][:owned])
    i, j = local[:owned] % space.basis.nfx, local[:owned] // space.basis.nfx
    interior = (i >= 2) & (i < space.basis.nfx - 2 - grid.cut) & (j >= 2) & (j < space.basis.nfy - 2 - grid.cut)
    np.testing.assert_allclose(exact[interior], 1000.0, rtol=1e-12)


# -- affine transfers (APIC, TPIC) ---------------------------------------------------------------------
A, B0 = np.array([[0.3, -1.2], [0.7, 0.4]]), np.array([0.5, -2.0])  # an affine field A x + b


def _affine_case(comm, Basis):
    """A 10 x 6 grid, a two-component space and particles (3, 1, 4 in the first cells and on)."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    return grid, fempm.Space(Basis(grid), {"v": 2}), random_particles(grid, [3, 1, 4])


def _owned(space, values):
    return values[: space.numbering.num_owned]


def _affine_p2g(space, particles, C):
    """Mass and momentum on the grid by affine P2G of the particles' velocities with affine parts C."""
    m = particles["mass"]
    values = np.column_stack([m, m[:, None] * particles["velocity"]])
    gradients = np.concatenate([np.zeros((len(m), 1, 2)), m[:, None, None] * C], axis=1)
    return transfer.affine_particles_to_grid(fempm.Space(space.basis, {"m": 1, "mv": 2}), particles, values,
                                             gradients).values


def _grid_angular_momentum(space, mass, velocity):
    """``sum_i m_i x_i x v_i`` over the owned functions of all ranks."""
    x = _owned(space, transfer.function_nodes(space))
    m, v = _owned(space, mass), _owned(space, velocity)
    return space.comm.allreduce(float(np.sum(m * (x[:, 0] * v[:, 1] - x[:, 1] * v[:, 0]))))


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", BASES)
def test_function_nodes_reproduce_linear_fields(comm, Basis):
    """sum_i N_i(x) x_i = x: the Greville abscissae (Q1: the nodes) are the coefficients of x."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    space = fempm.Space(Basis(grid), {"x": 2})
    particles = random_particles(grid, [3])
    f = fempm.GridFunction(space)
    f.values[:] = transfer.function_nodes(space)
    np.testing.assert_allclose(transfer.grid_to_particles(f, particles), particles.x, atol=1e-15)


def test_apic_moments_by_hand(comm):
    """D_p of quadratic B-splines: h^2/4 inside; at a clamped wall, with N = (1-t)^2, 2t - 3t^2/2, t^2/2 on
    the first cell and nodes 0, h/2, 3h/2: D_xx(t) = h^2 ((1-t)^2 t^2 + (2t - 3t^2/2)(1/2 - t)^2 + t^2/2 (3/2 - t)^2),
    7/64 h^2 at t = 1/4. Q1: D_xx = xi (1 - xi) h^2."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    h = grid.h
    particles = fempm.Particles(grid)
    particles.add_points([[0.25 * h, 0.55], [0.55, 0.55], [0.55, 0.25 * h]], h * h)
    if len(particles) < 3:  # the points on another rank
        return
    order = np.argsort(particles.x[:, 0] - particles.x[:, 1])
    D, _ = transfer.affine_moments(fempm.Space(fempm.BSpline2(grid)), particles)
    D = D[order] / h**2  # (0.025, 0.55), (0.55, 0.55), (0.55, 0.025) in that order
    np.testing.assert_allclose(D[0], [[7 / 64, 0], [0, 0.25]], atol=1e-14)
    np.testing.assert_allclose(D[1], 0.25 * np.eye(2), atol=1e-14)
    np.testing.assert_allclose(D[2], [[0.25, 0], [0, 7 / 64]], atol=1e-14)
    D, _ = transfer.affine_moments(fempm.Space(fempm.Q1(grid)), particles)
    np.testing.assert_allclose(D[order][0] / h**2, [[0.1875, 0], [0, 0.25]], atol=1e-14)


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", BASES)
def test_affine_p2g_of_an_affine_field_is_exact(comm, Basis):
    """v_p = A x_p + b with C_p = A lands as v_i = A x_i + b on every function with mass."""
    grid, space, particles = _affine_case(comm, Basis)
    particles["velocity"][:] = particles.x @ A.T + B0
    sums = _affine_p2g(space, particles, np.broadcast_to(A, (len(particles), 2, 2)))
    m = sums[:, 0]
    nodes = transfer.function_nodes(space)
    np.testing.assert_allclose(sums[m > 0, 1:3] / m[m > 0, None], nodes[m > 0] @ A.T + B0, atol=1e-13)


@pytest.mark.mpi
@pytest.mark.parametrize("kind", transfer.AFFINE_KINDS)
@pytest.mark.parametrize("Basis", BASES)
def test_affine_g2p_of_an_affine_field_is_exact(comm, Basis, kind):
    """Grid coefficients A x_i + b give v_p = A x_p + b and C_p = A (so P2G o G2P keeps affine fields)."""
    grid, space, particles = _affine_case(comm, Basis)
    f = fempm.GridFunction(space)
    f.values[:] = transfer.function_nodes(space) @ A.T + B0
    v, C = transfer.affine_grid_to_particles(f, particles, kind)
    np.testing.assert_allclose(v, particles.x @ A.T + B0, atol=1e-13)
    np.testing.assert_allclose(C, np.broadcast_to(A, C.shape), atol=1e-9)  # measured 2.6e-11 (Q1 APIC, small D_p)


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", BASES)
def test_affine_p2g_conserves_momentum_and_angular_momentum(comm, Basis):
    """sum_i m_i v_i = sum_p m_p v_p, and sum_i m_i x_i x v_i = the particles' L with affine parts."""
    grid, space, particles = _affine_case(comm, Basis)
    rng = np.random.default_rng(3 + comm.rank)
    particles["velocity"][:] = rng.standard_normal((len(particles), 2))
    C = rng.standard_normal((len(particles), 2, 2))
    sums = _affine_p2g(space, particles, C)
    total = comm.allreduce(_owned(space, sums[:, 1:3]).sum(axis=0))
    expected = comm.allreduce((particles["mass"][:, None] * particles["velocity"]).sum(axis=0))
    np.testing.assert_allclose(total, expected, rtol=1e-13, atol=1e-13 * np.abs(expected).max())
    m = sums[:, 0]
    L_grid = _grid_angular_momentum(space, m, sums[:, 1:3] / np.where(m > 0, m, 1.0)[:, None])
    L = transfer.angular_momentum(space, particles, C)
    assert L_grid == pytest.approx(L, rel=1e-13, abs=1e-13 * comm.allreduce(particles["mass"].sum()))


@pytest.mark.mpi
@pytest.mark.parametrize("kind", transfer.AFFINE_KINDS)
@pytest.mark.parametrize("Basis", BASES)
def test_affine_g2p_conserves_momentum_and_apic_angular_momentum(comm, Basis, kind):
    """G2P of any grid field: sum_p m_p v_p = sum_i m_i v_i (both); the angular momentum with the
    affine parts equals the grid's for APIC (and TPIC on Q1, where the two coincide), not for TPIC
    on B-splines (its C_p is not B_p D_p^-1)."""
    grid, space, particles = _affine_case(comm, Basis)
    f = fempm.GridFunction(space)
    f.values[:] = np.random.default_rng(5).standard_normal((space.basis.num_functions, 2))[
        space.numbering.local_functions]
    v, C = transfer.affine_grid_to_particles(f, particles, kind)
    particles["velocity"][:] = v
    m = transfer.lumped_mass(fempm.Space(space.basis, {"m": 1}), particles).values[:, 0]
    grid_momentum = comm.allreduce((_owned(space, m)[:, None] * _owned(space, f.values)).sum(axis=0))
    momentum = comm.allreduce((particles["mass"][:, None] * v).sum(axis=0))
    np.testing.assert_allclose(momentum, grid_momentum, rtol=1e-12, atol=1e-12 * np.abs(grid_momentum).max())
    L_grid = _grid_angular_momentum(space, m, f.values)
    L = transfer.angular_momentum(space, particles, C)
    scale = comm.allreduce(particles["mass"].sum())
    if kind == "apic" or Basis is fempm.Q1:
        assert L == pytest.approx(L_grid, abs=1e-12 * scale)
    else:
        assert abs(L - L_grid) > 1e-4 * scale  # measured 0.41 for a total mass of 1141 (TPIC, B-splines)


def test_angular_momentum_of_a_spinning_particle_by_hand(comm):
    """One particle of mass m at rest at an interior cell's centre with C = w [[0, -1], [1, 0]] (a rigid
    rotation): the grid gets v_i = C (x_i - x_p), whose angular momentum about x_p is
    w sum_i m_i |x_i - x_p|^2 = m w tr D_p = m w h^2 / 2 (B-splines); the particle's formula the same."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    particles = fempm.Particles(grid)
    particles.add_points([[0.55, 0.45]], 0.01, density=2.0)
    space = fempm.Space(fempm.BSpline2(grid), {"v": 2})
    w = 3.0
    C = np.broadcast_to(w * np.array([[0.0, -1.0], [1.0, 0.0]]), (len(particles), 2, 2))
    sums = _affine_p2g(space, particles, C)
    m = sums[:, 0]
    velocity = sums[:, 1:3] / np.where(m > 0, m, 1.0)[:, None]
    x = transfer.function_nodes(space) - [0.55, 0.45]
    L_grid = comm.allreduce(float(np.sum(_owned(space, m * (x[:, 0] * velocity[:, 1] - x[:, 1] * velocity[:, 0])))))
    expected = 0.02 * w * grid.h**2 / 2
    assert L_grid == pytest.approx(expected, rel=1e-13)
    assert transfer.angular_momentum(space, particles, C, centre=(0.55, 0.45)) == pytest.approx(expected, rel=1e-13)


@pytest.mark.mpi
@pytest.mark.parametrize("kind", transfer.TRANSFERS)
def test_a_step_of_the_particle_state_keeps_an_affine_field(comm, kind):
    """project_state, then update_state with the projected field as the new one and no change: the
    velocity A x + b with affine part A comes back as it was. FLIP: with no PIC share (its P2G is not
    exact on affine fields); the affine kinds: with a whole PIC share (P2G then G2P exact)."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    basis = fempm.BSpline2(grid)
    particles = random_particles(grid, [3, 1, 4])
    transfer.add_affine_fields(particles, kind)
    particles["velocity"][:] = particles["acceleration"][:] = particles.x @ A.T + B0
    if kind != "flip":
        particles["affine_velocity"][:] = particles["affine_acceleration"][:] = A
    p2g = transfer.project_state(particles, kind, fempm.GridFunction(fempm.Space(basis, {"m": 1, "mv": 2, "ma": 2,
                                                                                       "count": 1})))
    m = np.where(p2g.field("m") > 0, p2g.field("m"), 1.0)
    g2p = fempm.GridFunction(fempm.Space(basis, {"dv": 2, "da": 2, "v": 2, "a": 2}))
    g2p.field("v")[:], g2p.field("a")[:] = p2g.field("mv") / m, p2g.field("ma") / m
    before = particles["velocity"].copy()
    transfer.update_state(g2p, particles, kind, 0.0 if kind == "flip" else 1.0, np.empty((len(particles), 8)),
                          np.empty(len(particles)))
    np.testing.assert_allclose(particles["velocity"], before, atol=1e-12)
    if kind != "flip":
        np.testing.assert_allclose(particles["affine_acceleration"], np.broadcast_to(A, (len(particles), 2, 2)),
                                   atol=1e-9)


@pytest.mark.mpi
def test_g2p_takes_the_values_over_the_functions_the_step_moved(comm):
    """A uniform velocity c on the functions the step moved, zero on those it held (the nodes at x >= 0.8), held
    along x only (along y a wall's zero, a value): with a whole PIC share a particle whose held weight w is at
    most HELD_WEIGHT_RESTORED takes c_x exactly and no affine part along x (the held functions at its value),
    one from twice it keeps (1 - w) c_x, one between (1 - w) c_x / (1 - s w) with s = 2 - w / HELD_WEIGHT_RESTORED;
    every particle keeps (1 - w) c_y."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    basis = fempm.BSpline2(grid)
    particles = random_particles(grid, [3, 1, 4])
    transfer.add_affine_fields(particles, "affine-flip")
    c = np.array([0.7, -0.2])
    g2p = fempm.GridFunction(fempm.Space(basis, {"dv": 2, "da": 2, "v": 2, "a": 2, "held": 2}))
    held = transfer.function_nodes(g2p.space)[:, 0] >= 0.8
    g2p.field("held")[:, 0] = held
    g2p.field("v")[:] = g2p.field("a")[:] = np.where(held[:, None], 0.0, c)
    w = transfer.grid_to_particles(g2p, particles)[:, g2p.space.field_slice("held")][:, 0]
    whole = (w > 0) & (w <= transfer.HELD_WEIGHT_RESTORED)
    for some in (whole, (w > transfer.HELD_WEIGHT_RESTORED) & (w < 2 * transfer.HELD_WEIGHT_RESTORED),
                 w >= 2 * transfer.HELD_WEIGHT_RESTORED):
        assert comm.allreduce(int(some.sum())) > 0
    transfer.update_state(g2p, particles, "affine-flip", 1.0, np.empty((len(particles), 10)), np.empty(len(particles)))
    v, C = particles["velocity"], particles["affine_velocity"]
    share = np.clip(2 - w / transfer.HELD_WEIGHT_RESTORED, 0, 1)
    np.testing.assert_allclose(v[:, 0], (1 - w) * c[0] / (1 - share * w), atol=1e-14)
    np.testing.assert_allclose(v[whole, 0], c[0], atol=1e-14)
    np.testing.assert_allclose(C[whole, 0, :], 0.0, atol=1e-12)
    np.testing.assert_allclose(v[:, 1], (1 - w) * c[1], atol=1e-14)


def test_pic_share():
    """1 for APIC and TPIC; pic_blend + pic_rate dt, at most 1, for FLIP and affine-FLIP."""
    assert transfer.pic_share("apic", 0.0, 0.0, 1e-3) == 1.0
    assert transfer.pic_share("affine-flip", 0.0, 100.0, 1e-3) == pytest.approx(0.1)
    assert transfer.pic_share("flip", 0.1, 0.0, 1e-4) == pytest.approx(0.1)
    assert transfer.pic_share("flip", 0.5, 100.0, 1e-2) == 1.0


def test_rest_share():
    """min(1, rest_pic_rate dt) below 0.01 sqrt(|g| h) for FLIP and affine-FLIP under gravity; none for the
    affine kinds (their share is whole), without gravity or at a rate of 0."""
    expected = (0.3, 0.01 * np.sqrt(9.81 * 0.04))
    assert transfer.rest_share("affine-flip", 300.0, 1e-3, 9.81, 0.04) == pytest.approx(expected)
    assert transfer.rest_share("flip", 300.0, 1e-2, 9.81, 0.04)[0] == 1.0
    assert transfer.rest_share("tpic", 300.0, 1e-3, 9.81, 0.04) == (0.0, 0.0)
    assert transfer.rest_share("affine-flip", 300.0, 1e-3, 0.0, 0.04) == (0.0, 0.0)
    assert transfer.rest_share("affine-flip", 0.0, 1e-3, 9.81, 0.04) == (0.0, 0.0)


def test_the_pic_share_rises_linearly_as_the_water_comes_to_rest(comm):
    """Uniform new grid velocities of speed s, no change over the step: a particle's velocity v becomes
    (1 - k) v + k v_new with k the flowing share above the rest speed and k = share + (rest - share)
    (1 - s / rest_speed) below it."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    basis = fempm.BSpline2(grid)
    share, rest, rest_speed = 0.1, 0.3, 0.02
    for speed in (0.0, 0.005, 0.015, 0.02, 0.5):
        particles = random_particles(grid, [3, 1, 4])
        v0 = np.array([0.7, -0.2])
        particles["velocity"][:] = particles["acceleration"][:] = v0
        g2p = fempm.GridFunction(fempm.Space(basis, {"dv": 2, "da": 2, "v": 2, "a": 2}))
        direction = np.array([0.6, 0.8])
        g2p.field("v")[:] = g2p.field("a")[:] = speed * direction
        transfer.update_state(g2p, particles, "flip", share, np.empty((len(particles), 8)), np.empty(len(particles)),
                              rest=(rest, rest_speed))
        k = share + (rest - share) * max(0.0, 1.0 - speed / rest_speed)
        np.testing.assert_allclose(particles["velocity"], np.broadcast_to((1 - k) * v0 + k * speed * direction,
                                                                          (len(particles), 2)), rtol=0, atol=1e-14)


@pytest.mark.parametrize("kind", transfer.TRANSFERS)
def test_the_particle_state_of_a_rank_without_particles(comm, kind):
    """A rank may hold no particles (the water on the other rank): P2G gives zeros, G2P nothing."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.1)
    basis = fempm.BSpline2(grid)
    particles = fempm.Particles(grid)
    transfer.add_affine_fields(particles, kind)
    p2g = transfer.project_state(particles, kind, fempm.GridFunction(fempm.Space(basis, {"m": 1, "mv": 2, "ma": 2,
                                                                                       "count": 1})))
    assert not p2g.values.any()
    g2p = fempm.GridFunction(fempm.Space(basis, {"dv": 2, "da": 2, "v": 2, "a": 2}))
    transfer.update_state(g2p, particles, kind, 0.1, np.empty((0, 8)), np.empty(0),
                          noise=(transfer.NoiseFilter(basis), 0.3))
    assert particles["velocity"].shape == (0, 2)


def _lattice_with_noise(comm, amplitude: float):
    """2 x 2 particles per cell on a 16² unit box; velocity and acceleration a resolved field (one sine wave
    over the box) plus a particle-scale checkerboard of ``amplitude``; the new grid state zero, no change."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 1 / 16)
    particles = fempm.Particles(grid)
    particles.seed(fempm.Rectangle((0.0, 0.0), (1.0, 1.0)), per_cell=2, density=1000.0)
    transfer.add_affine_fields(particles, "affine-flip")
    x = particles.x
    resolved = np.column_stack([np.sin(2 * np.pi * x[:, 1]), np.cos(2 * np.pi * x[:, 0])])
    index = np.floor(x / (grid.h / 2)).astype(int).sum(axis=1)
    noise = amplitude * np.where(index % 2 == 0, 1.0, -1.0)[:, None] * np.array([1.0, -1.0])
    particles["velocity"][:] = particles["acceleration"][:] = resolved + noise
    g2p = fempm.GridFunction(fempm.Space(fempm.BSpline2(grid), {"dv": 2, "da": 2, "v": 2, "a": 2}))
    return particles, g2p, resolved


def _rms(comm, particles, field):
    return np.sqrt(comm.allreduce(float(particles["mass"] @ (field**2).sum(axis=1)))
                   / comm.allreduce(float(particles["mass"].sum())))


@pytest.mark.mpi
def test_the_noise_filter_damps_the_particles_noise_and_keeps_the_resolved_flow(comm):
    """A whole PIC share towards a grid at rest takes everything; restricted to the noise
    (transfer.NoiseFilter) it takes the checkerboard and leaves the resolved wave, keeping the momentum."""
    filtered = {}
    for noise in (None, transfer.NoiseFilter):
        particles, g2p, resolved = _lattice_with_noise(comm, 0.5)
        momentum = comm.allreduce(particles["mass"] @ particles["velocity"])
        transfer.update_state(g2p, particles, "affine-flip", 0.0 if noise else 1.0, np.empty((len(particles), 8)),
                              np.empty(len(particles)), noise=noise and (noise(g2p.space.basis), 1.0))
        filtered[noise] = _rms(comm, particles, particles["velocity"] - resolved) / _rms(comm, particles, resolved)
        if noise:
            np.testing.assert_allclose(comm.allreduce(particles["mass"] @ particles["velocity"]), momentum,
                                       rtol=0, atol=1e-12 * np.abs(particles["mass"]).sum())
            np.testing.assert_array_equal(particles["acceleration"], particles["velocity"])
    assert filtered[None] == pytest.approx(1.0, abs=1e-12)  # the whole share: the wave is gone
    assert filtered[transfer.NoiseFilter] < 0.05  # measured 0.048 (the wave smoothed by h²/4 of its Laplacian): the checkerboard, 0.71, is gone


@pytest.mark.mpi
def test_the_noise_filter_leaves_a_linear_difference_alone_at_the_walls_too(comm):
    """A difference from the grid that varies linearly is the flow's, not noise: each function's fit
    reproduces it, along the walls (where a function's particles lie on one side of its node) as in the
    middle, so the filter takes nothing. A fit's mean alone (the smoothing before) took up to 0.049 along
    the walls, the fields spanning about 2.5."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.75), 1 / 16)
    particles = fempm.Particles(grid)
    particles.seed(fempm.Rectangle((0.0, 0.0), (1.0, 0.75)), per_cell=2, density=1000.0)
    transfer.add_affine_fields(particles, "affine-flip")
    x = particles.x
    linear = np.column_stack([0.3 + 2.0 * x[:, 0] - 1.0 * x[:, 1], -0.5 + 0.7 * x[:, 0] + 1.5 * x[:, 1]])
    particles["velocity"][:] = particles["acceleration"][:] = linear
    g2p = fempm.GridFunction(fempm.Space(fempm.BSpline2(grid), {"dv": 2, "da": 2, "v": 2, "a": 2}))
    transfer.update_state(g2p, particles, "affine-flip", 0.0, np.empty((len(particles), 8)), np.empty(len(particles)),
                          noise=(transfer.NoiseFilter(g2p.space.basis), 1.0))
    taken = comm.allreduce(float(np.abs(particles["velocity"] - linear).max(initial=0.0)), op=MPI.MAX)
    assert taken < 1e-12  # measured 8.9e-16 (the grid at rest)
    np.testing.assert_array_equal(particles["acceleration"], particles["velocity"])


@pytest.mark.parametrize("share", [1.0, 0.3])
def test_the_noise_filter_damps_a_lone_particle_whole(comm, share):
    """A particle alone in its functions' support is its own smoothing, so its difference from the grid
    would count as resolved: the filter takes its whole difference instead, as PIC does."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.1)
    particles = fempm.Particles(grid)
    particles.add_points(np.array([[0.43, 0.57]]), 0.0025, density=1000.0, ids=np.arange(1))
    transfer.add_affine_fields(particles, "affine-flip")
    particles["velocity"][:] = particles["acceleration"][:] = [[0.7, -1.3]]
    g2p = fempm.GridFunction(fempm.Space(fempm.BSpline2(grid), {"dv": 2, "da": 2, "v": 2, "a": 2}))
    transfer.update_state(g2p, particles, "affine-flip", 0.0, np.empty((1, 8)), np.empty(1),
                          noise=(transfer.NoiseFilter(g2p.space.basis), share))
    # the grid at rest: the share of the difference is gone, whatever the weights (an exact product)
    np.testing.assert_allclose(particles["velocity"], [[0.7 * (1 - share), -1.3 * (1 - share)]], rtol=1e-14)
