"""Particle quadrature of UFL forms against DOLFINx's own assembly and a brute-force sum."""

import basix
import numpy as np
import pytest
import ufl
from scipy.interpolate import BSpline

import fempm
from fempm.errors import InputError

from helpers import (BILINEAR, CONSTANTS, particles_at_gauss_points, random_particles,
                     relative_difference, to_dense)

BASES = [fempm.Q1, fempm.BSpline2]


def _density(x):
    return 900.0 + 200.0 * x[:, 0] * x[:, 1]


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", BASES)
@pytest.mark.parametrize("name", list(BILINEAR))
def test_gauss_point_particles_reproduce_dolfinx_assembly(comm, Basis, name):
    """Particles at the Gauss points with the Gauss weights as volumes = ordinary dx."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.2, 0.8), 0.2)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    degree = 2 * space.basis.degree + 1
    particles = particles_at_gauss_points(grid, degree, _density)
    A = fempm.ParticleForm(BILINEAR[name], space, particles, constants=CONSTANTS).assemble_matrix(particles)
    gauss = fempm.GaussForm(BILINEAR[name], space, constants=CONSTANTS, degree=degree,
                            particle_values={"density": lambda x: _density(x.T)})
    assert relative_difference(A, gauss.assemble_matrix()) < 1e-12


@pytest.mark.parametrize("Basis", BASES)
def test_a_constant_asked_for_but_left_out_of_the_form_takes_no_slot(comm, Basis):
    """forms/incompressible.py asks for ``alpha`` and leaves its term out when it is 0: the
    constants after it must still reach their own slots (they were shifted by one, which put
    alpha's 0 into the PSPG switch of every run without volume correction)."""

    def form(s):
        (u, p), (v, q) = s.trial, s.test
        s.constant("off")  # asked for, not used
        return (s.constant("k") * ufl.inner(ufl.grad(p), ufl.grad(q)) + s.constant("m") * q * p) * s.dx

    grid = fempm.Grid(comm, (0.0, 0.0), (0.8, 0.6), 0.2)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    degree = 2 * space.basis.degree + 1
    particles = particles_at_gauss_points(grid, degree)
    constants = {"off": 0.0, "k": 3.0, "m": 5.0}
    A = fempm.ParticleForm(form, space, particles, constants=constants).assemble_matrix(particles)
    reference = fempm.GaussForm(form, space, constants=constants, degree=degree).assemble_matrix()
    assert relative_difference(A, reference) < 1e-12


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", BASES)
def test_linear_form_with_grid_function_and_particle_vector(comm, Basis):
    """A right-hand side with a grid function, a particle vector field and x."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.2, 0.8), 0.2)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    velocity_space = fempm.Space(space.basis, {"v": 2})
    degree = 3 * space.basis.degree + 1
    particles = particles_at_gauss_points(grid, degree, _density)
    particles["velocity"][:] = np.column_stack([np.sin(particles.x[:, 1]), particles.x[:, 0] ** 2])
    g = fempm.GridFunction(velocity_space, "g")
    xs = grid.lower + grid.h * np.stack(
        [velocity_space.numbering.local_functions % space.basis.nfx,
         velocity_space.numbering.local_functions // space.basis.nfx], axis=-1)
    g.values[:] = np.column_stack([np.cos(xs[:, 0]), xs[:, 1]])

    def rhs(s):
        v, q = s.test
        rho, vel, x = s.particle("density"), s.particle("velocity"), s.x
        return (rho * ufl.inner(vel, v) + ufl.inner(ufl.grad(q), s.grid("g")) * x[0]
                + ufl.div(s.grid("g")) * q) * s.dx

    b = fempm.ParticleForm(rhs, space, particles, grid_functions={"g": g}).assemble_vector(particles)
    gauss = fempm.GaussForm(rhs, space, grid_functions={"g": g}, degree=degree, particle_values={
        "density": lambda x: _density(x.T), "velocity": lambda x: np.vstack([np.sin(x[1]), x[0] ** 2])})
    reference = gauss.assemble_vector()
    assert relative_difference(b.petsc_vec, reference) < 1e-12


@pytest.mark.parametrize("Basis", BASES)
def test_second_derivatives_use_second_order_jets(comm, Basis):
    """A PSPG residual with the viscous term div(grad u) needs jets of order 2."""
    grid = fempm.Grid(comm, (0.0, 0.0), (0.8, 0.6), 0.2)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    degree = 2 * space.basis.degree + 1

    def residual_pspg(s):
        (u, p), (v, q) = s.trial, s.test
        return ufl.inner(-ufl.div(ufl.grad(u)) + ufl.grad(p), ufl.grad(q)) * s.dx

    particles = particles_at_gauss_points(grid, degree)
    form = fempm.ParticleForm(residual_pspg, space, particles)
    assert form.order == 2
    A = form.assemble_matrix(particles)
    reference = fempm.GaussForm(residual_pspg, space, degree=degree).assemble_matrix()
    assert relative_difference(A, reference) < 1e-12


def _basis_values(basis, x):
    """Values and physical gradients of all functions at x: independent implementations."""
    grid = basis.grid
    n = len(x)
    values = np.zeros((n, basis.num_functions))
    grads = np.zeros((n, basis.num_functions, 2))
    if isinstance(basis, fempm.Q1):
        # basix's Q1 on the reference cell; dof order (0,0), (1,0), (0,1), (1,1)
        element = basix.create_element(basix.ElementFamily.P, basix.CellType.quadrilateral, 1)
        ij = np.minimum(np.floor((x - grid.lower) / grid.h).astype(int), [grid.nx - 1, grid.ny - 1])
        xi = (x - grid.lower) / grid.h - ij
        tab = element.tabulate(1, xi)[:, :, :, 0]  # (derivative, point, dof)
        for dof, (a, b) in enumerate([(0, 0), (1, 0), (0, 1), (1, 1)]):
            f = (ij[:, 0] + a) + basis.nfx * (ij[:, 1] + b)
            values[np.arange(n), f] = tab[0, :, dof]
            grads[np.arange(n), f] = tab[1:, :, dof].T / grid.h
        return values, grads
    knots = {}
    for axis, cells in ((0, grid.nx), (1, grid.ny)):
        kn = grid.lower[axis] + grid.h * np.concatenate([[0, 0], np.arange(cells + 1), [cells, cells]])
        one_d = []
        for nu in (0, 1):
            cols = []
            for i in range(cells + 2):
                c = np.zeros(cells + 2)
                c[i] = 1.0
                cols.append(np.nan_to_num(BSpline(kn, c, 2, extrapolate=False)(x[:, axis], nu=nu)))
            one_d.append(np.array(cols).T)
        knots[axis] = one_d
    (bx, dbx), (by, dby) = knots[0], knots[1]
    values = np.einsum("pi,pj->pji", bx, by).reshape(n, -1)
    grads[:, :, 0] = np.einsum("pi,pj->pji", dbx, by).reshape(n, -1)
    grads[:, :, 1] = np.einsum("pi,pj->pji", bx, dby).reshape(n, -1)
    return values, grads


@pytest.mark.parametrize("Basis", BASES)
def test_random_particles_against_a_brute_force_sum(Basis):
    """0, 1 and many particles per cell: the Stokes-PSPG matrix summed in numpy."""
    from mpi4py import MPI

    grid = fempm.Grid(MPI.COMM_SELF, (0.0, 0.0), (1.0, 0.6), 0.2)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    particles = random_particles(grid, [0, 1, 5, 2, 0, 9, 1])
    mu, tau = CONSTANTS["mu"], CONSTANTS["tau"]

    def stokes(s):
        return sum(BILINEAR[k](s) for k in BILINEAR)

    A = to_dense(fempm.ParticleForm(stokes, space, particles, constants=CONSTANTS).assemble_matrix(particles))

    N, G = _basis_values(space.basis, particles.x)
    V, rho = particles["volume"], particles["density"]
    nf = space.basis.num_functions
    ref = np.zeros((nf, 3, nf, 3))  # (test function, test comp, trial function, trial comp)
    w = V[:, None, None]
    # mass rho u.v, viscous 2 mu eps(u):eps(v), divergence -p div v + q div u,
    # PSPG tau (grad p . grad q + rho u . grad q)
    NN = np.einsum("pi,pj->pij", N, N) * w
    for c in range(2):
        ref[:, c, :, c] += np.einsum("p,pij->ij", rho, NN)
        for d in range(2):
            # eps(phi_j e_d) : eps(phi_i e_c) = 1/2 (delta_cd grad_i . grad_j + d_d phi_i d_c phi_j)
            GG = np.einsum("pi,pj->pij", G[:, :, d], G[:, :, c]) * w
            ref[:, c, :, d] += 2 * mu * 0.5 * np.einsum("pij->ij", GG)
            if c == d:
                ref[:, c, :, d] += 2 * mu * 0.5 * np.einsum("pik,pjk->ij", G, G * w)
        ref[:, c, :, 2] -= np.einsum("pi,pj->ij", G[:, :, c] * V[:, None], N)
        ref[:, 2, :, c] += np.einsum("pi,pj->ij", N * V[:, None], G[:, :, c])
        ref[:, 2, :, c] += tau * np.einsum("pi,pj->ij", G[:, :, c] * (V * rho)[:, None], N)
    ref[:, 2, :, 2] += tau * np.einsum("pik,pjk->ij", G, G * w)
    ref = ref.reshape(3 * nf, 3 * nf)
    # fempm's global numbering of the functions (serial: a permutation of the structured one)
    g = space.numbering.global_index
    perm = (3 * g[:, None] + np.arange(3)).ravel()
    reordered = np.zeros_like(ref)
    reordered[np.ix_(perm, perm)] = ref
    assert np.abs(A - reordered).max() / np.abs(reordered).max() < 1e-11


@pytest.mark.parametrize("Basis", BASES)
def test_empty_cells_contribute_nothing(Basis):
    from mpi4py import MPI

    from fempm import transfer

    grid = fempm.Grid(MPI.COMM_SELF, (0.0, 0.0), (1.0, 1.0), 0.25)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    particles = fempm.Particles(grid)
    particles.add_points(np.array([[0.1, 0.1], [0.15, 0.05]]), 0.01)  # all in cell 0
    A = to_dense(fempm.ParticleForm(BILINEAR["mass"], space, particles).assemble_matrix(particles))
    counts = transfer.particles_to_grid(fempm.Space(space.basis, {"count": 1}), particles, np.zeros((2, 0)),
                                        counts=True).values[:, 0]
    by_function = np.zeros(space.basis.num_functions)
    by_function[space.local_to_global[::3] // 3] = counts  # in the global numbering
    active = np.repeat(by_function > 0, 3)
    assert active.sum() == 3 * (space.basis.degree + 1) ** 2
    assert np.all(A[~active] == 0) and np.all(A[:, ~active] == 0)


def test_form_errors_name_the_cause(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.25)
    space = fempm.Space(fempm.Q1(grid), {"u": 1})
    particles = fempm.Particles(grid)
    with pytest.raises(InputError, match="particle field 'viscosity'"):
        fempm.ParticleForm(lambda s: s.particle("viscosity") * s.trial * s.test * s.dx, space, particles)
    with pytest.raises(InputError, match="constant 'dt'"):
        fempm.ParticleForm(lambda s: s.constant("dt") * s.trial * s.test * s.dx, space, particles)
    with pytest.raises(InputError, match=r"cells \(dx\) only"):
        fempm.ParticleForm(lambda s: s.trial * s.test * ufl.ds, space, particles)
    form = fempm.ParticleForm(lambda s: s.trial * s.test * s.dx, space, particles)
    with pytest.raises(InputError, match="bilinear form, not a linear form"):
        form.assemble_vector(particles)


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", BASES)
def test_lumped_quadrature_gives_the_p2g_masses_on_the_diagonal(comm, Basis):
    """dx_lumped: the mass matrix is diagonal with the P2G masses; a residual takes nodal values."""
    from fempm import transfer

    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.2)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    particles = random_particles(grid, [0, 2, 5, 1])
    A = fempm.ParticleForm(
        lambda s: s.particle("density") * ufl.inner(s.trial[0], s.test[0]) * s.dx_lumped, space, particles,
    ).assemble_matrix(particles)
    masses = transfer.lumped_mass(fempm.Space(space.basis, {"m": 1}), particles).values[:, 0]
    owned = space.numbering.num_owned
    diagonal = A.getDiagonal().getArray().reshape(-1, 3)
    np.testing.assert_allclose(diagonal[:, :2], np.column_stack([masses[:owned]] * 2), rtol=1e-13, atol=1e-10)
    assert A.norm() == pytest.approx(np.sqrt(comm.allreduce(2 * np.sum(masses[:owned] ** 2))), rel=1e-13)

    U = fempm.GridFunction(space, "U")
    U.values[:] = np.random.default_rng(3).random(U.values.shape)
    U.scatter_forward()
    b = fempm.ParticleForm(
        lambda s: s.particle("density") * ufl.inner(ufl.split(s.grid("U"))[0], s.test[0]) * s.dx_lumped,
        space, particles, grid_functions={"U": U},
    ).assemble_vector(particles)
    np.testing.assert_allclose(b.array.reshape(-1, 3)[:owned, :2], masses[:owned, None] * U.values[:owned, :2],
                               rtol=1e-12, atol=1e-10)


def test_lumped_integrand_may_not_take_derivatives(comm):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.25)
    space = fempm.Space(fempm.Q1(grid), {"u": 1})
    particles = fempm.Particles(grid)
    with pytest.raises(InputError, match="dx_lumped may not take derivatives"):
        fempm.ParticleForm(lambda s: ufl.inner(ufl.grad(s.trial), ufl.grad(s.test)) * s.dx_lumped, space, particles)


@pytest.mark.parametrize("Basis", BASES)
def test_lumped_quadrature_of_an_integrand_not_affine_in_particle_fields(comm, Basis):
    """rho_p^2 u.v over dx_lumped: evaluated per particle and function, diag = sum_p V_p rho_p^2 N_f."""
    from fempm import transfer

    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.2)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    particles = random_particles(grid, [0, 2, 5, 1])
    form = fempm.ParticleForm(
        lambda s: s.particle("density") ** 2 * ufl.inner(s.trial[0], s.test[0]) * s.dx_lumped, space, particles)
    assert not form._lumped_affine
    A = form.assemble_matrix(particles)
    scalar = fempm.Space(space.basis, {"m": 1})
    expected = transfer.particles_to_grid(scalar, particles, particles["volume"] * particles["density"] ** 2)
    owned = space.numbering.num_owned
    diagonal = A.getDiagonal().getArray().reshape(-1, 3)
    np.testing.assert_allclose(diagonal[:, 0], expected.values[:owned, 0], rtol=1e-13)


def _values(A):
    from fempm.matrix import grid_matrix

    return grid_matrix(A).values.copy()


@pytest.mark.mpi
def test_a_residual_and_its_jacobian_in_one_pass_as_in_two(comm):
    """``assemble_with`` gives the matrix and vector of two passes bit for bit: the shipped forms of a
    stepped dam break (one pass), and a linear form lacking the bilinear form's particle field (two)."""
    from pathlib import Path

    from fempm.scene import load_scene
    from fempm.simulation import build_solver

    solver = build_solver(load_scene(Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"), comm)
    for _ in range(3):
        solver.step()
    forms, particles, A = solver.forms, solver.particles, solver.region.matrix
    assert forms.jacobian._columns_in(forms.residual) is not None
    b = forms.residual.assemble_vector(particles).array.copy()
    two = _values(forms.jacobian.assemble_matrix(particles, A))
    A, one_b = forms.jacobian.assemble_with(forms.residual, particles, A)
    assert np.array_equal(_values(A), two) and np.array_equal(one_b.array, b)

    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 0.6), 0.2)
    space = fempm.Space(fempm.BSpline2(grid), {"u": 2, "p": 1})
    particles = random_particles(grid, [0, 2, 5, 1])
    bilinear = fempm.ParticleForm(
        lambda s: s.particle("density") * ufl.inner(s.trial[0], s.test[0]) * s.dx, space, particles)
    linear = fempm.ParticleForm(lambda s: ufl.inner(ufl.as_vector((1.0, 0.0)), s.test[0]) * s.dx, space, particles)
    assert bilinear._columns_in(linear) is None
    A, b = bilinear.assemble_with(linear, particles)
    assert np.array_equal(_values(A), _values(bilinear.assemble_matrix(particles)))
    assert np.array_equal(b.array, linear.assemble_vector(particles).array)
