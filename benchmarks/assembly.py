"""Particle-quadrature assembly of the velocity-pressure system against DOLFINx's Gauss assembly.

For 1e4, 1e5 and 1e6 particles (2 x 2 per cell on a square grid), Q1 and
B-spline, prints the time of each phase -- locate (cell and reference
coordinates), tabulate (basis jets at the particles), assemble matrix, assemble
vector -- and the ratio of the whole to DOLFINx's ordinary Gauss assembly of the
same forms on the same mesh in the same run (for the B-spline, on the Q2
Lagrange space it extracts from, with and without the P^T A P restriction).

    python benchmarks/assembly.py [--sizes 1e4 1e5 1e6] [--repeat 3]
"""

import argparse
import time

import numpy as np
import ufl
from mpi4py import MPI

import fempm


def eps(w):
    return ufl.sym(ufl.grad(w))


def system_matrix(s):
    """Mass/dt^2 + viscous/dt - p div v + q div u + PSPG, the blocks of method.md eq. (1)."""
    (u, p), (v, q) = s.trial, s.test
    rho, mu, tau, dt = s.particle("density"), s.constant("mu"), s.particle("tau"), s.constant("dt")
    return (rho / dt**2 * ufl.inner(u, v) + 2 * mu / dt * ufl.inner(eps(u), eps(v))
            - p * ufl.div(v) + q * ufl.div(u) / dt
            + tau * (rho / dt**2 * ufl.inner(u, ufl.grad(q)) + ufl.inner(ufl.grad(p), ufl.grad(q)))) * s.dx


def system_vector(s):
    """Inertia of the particle velocity, gravity, and their PSPG counterparts."""
    v, q = s.test
    rho, vel, tau, dt = s.particle("density"), s.particle("velocity"), s.particle("tau"), s.constant("dt")
    g = ufl.as_vector([0.0, -9.81])
    return (rho * ufl.inner(vel / dt + g, v) + tau * rho * ufl.inner(vel / dt + g, ufl.grad(q))) * s.dx


def best_of(repeat, f):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return min(times), out


def run(n_particles, Basis, repeat):
    comm = MPI.COMM_WORLD
    cells = int(round(np.sqrt(n_particles / 4)))
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 1.0 / cells)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    particles = fempm.Particles(grid)
    particles.add_field("tau")
    particles.seed(fempm.Rectangle((0.0, 0.0), (1.0, 1.0)), per_cell=2, density=1000.0)
    rng = np.random.default_rng(0)
    particles.fields["x"] += grid.h * 0.2 * (rng.random(particles.x.shape) - 0.5)
    particles["velocity"][:] = rng.random(particles["velocity"].shape)
    particles["tau"][:] = 1e-4
    constants = {"mu": 1e-3, "dt": 1e-3}
    A_form = fempm.ParticleForm(system_matrix, space, particles, constants=constants)
    b_form = fempm.ParticleForm(system_vector, space, particles, constants=constants)
    A = A_form.assemble_matrix(particles)
    b = b_form.assemble_vector(particles)

    t_locate, _ = best_of(repeat, lambda: grid.locate(particles.x))

    def tabulate():
        particles.cache.clear()
        return space.tabulate_particles(particles, order=1)

    t_tab, _ = best_of(repeat, tabulate)
    t_mat, _ = best_of(repeat, lambda: A_form.assemble_matrix(particles, A))
    t_vec, _ = best_of(repeat, lambda: b_form.assemble_vector(particles, b))
    ours = t_locate + t_tab + t_mat + t_vec

    # DOLFINx's own Gauss assembly of the same forms on the same mesh
    degree = 2 * space.basis.degree + 1
    values = {"density": 1000.0, "tau": 1e-4, "velocity": lambda x: np.vstack([x[0], x[1]])}
    gA = fempm.GaussForm(system_matrix, space, particle_values=values, constants=constants, degree=degree)
    gb = fempm.GaussForm(system_vector, space, particle_values=values, constants=constants, degree=degree)
    import dolfinx.fem.petsc as fp

    A_L = fp.assemble_matrix(gA._compiled)
    A_L.assemble()

    def dolfinx_matrix():
        A_L.zeroEntries()
        fp.assemble_matrix(A_L, gA._compiled)
        A_L.assemble()

    t_dolfinx_mat, _ = best_of(repeat, dolfinx_matrix)
    t_dolfinx_vec, _ = best_of(repeat, lambda: fp.assemble_vector(gb._compiled))
    t_ptap, _ = best_of(repeat, lambda: A_L.PtAP(gA.P)) if Basis is fempm.BSpline2 else (0.0, None)
    gauss = t_dolfinx_mat + t_dolfinx_vec
    n = particles.global_count()
    if comm.rank == 0:
        print(f"{space.basis.name:9s} {n:>9d} {grid.nx:>4d}^2 | locate {t_locate:7.3f} tabulate {t_tab:7.3f} "
              f"matrix {t_mat:7.3f} vector {t_vec:7.3f} = {ours:7.3f} s | DOLFINx Gauss "
              f"{gauss:7.3f} s (+PtAP {t_ptap:6.3f}) | ratio {ours / gauss:5.2f} "
              f"({ours / (gauss + t_ptap):5.2f} with PtAP)")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    if MPI.COMM_WORLD.rank == 0:
        print(f"particle quadrature vs DOLFINx Gauss assembly, {MPI.COMM_WORLD.size} rank(s), best of {args.repeat}")
    for n in args.sizes:
        for Basis in (fempm.Q1, fempm.BSpline2):
            run(int(n), Basis, args.repeat)


if __name__ == "__main__":
    main()
