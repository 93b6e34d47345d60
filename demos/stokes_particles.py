"""Stokes flow integrated on particles: a weak form written once in UFL, solved on Q1 and B-splines.

This demo shows fempm's engine without time stepping: the material points are
the quadrature points of the weak form.

Strong form (a manufactured solution on the unit square, no-slip walls)::

    -mu lap u + grad p = f,   div u = 0   in (0, 1)^2,   u = 0 on the walls,

with ``u = curl psi``, ``psi = x^2 (1 - x)^2 y^2 (1 - y)^2`` and
``p = (x - 1/2)(y - 1/2)``; ``f`` follows from them.

Weak form with PSPG stabilisation (Tezduyar 1992, equal-order velocity and pressure)::

    int 2 mu eps(u):eps(v) - p div v + q div u
        + tau (-mu lap u + grad p - f) . grad q  dx  =  int f . v dx

``tau = h^2 / (12 mu)``. The integrals are sums over particles, 2 x 2 per cell
with volume h^2/4: once on the lattice (the composite midpoint rule) and once
with every particle moved off its site by up to 20 % of the spacing, as moving
material points are. Run::

    python demos/stokes_particles.py [--levels 8 16 32] [--out results/stokes_particles]

It prints the velocity error (L2, against the exact solution) of each grid for
the two bases with the observed convergence rate, and plots them. On the
lattice both bases converge at second order; with jittered particles the
quadrature error of the particles takes over and the rate drops towards one,
more for the B-splines -- the known price of integrating on material points.
"""

# %% imports
import argparse
from pathlib import Path

import numpy as np
import ufl
from mpi4py import MPI

import fempm
from fempm.linear import LinearSolver

MU = 1.0


# %% the exact solution, in UFL (so that f is derived from it symbolically)
def exact(x):
    psi = x[0] ** 2 * (1 - x[0]) ** 2 * x[1] ** 2 * (1 - x[1]) ** 2
    u = ufl.as_vector([psi.dx(1), -psi.dx(0)])
    p = (x[0] - 0.5) * (x[1] - 0.5)
    return u, p


def body_force(x):
    u, p = exact(x)
    return -MU * ufl.div(ufl.grad(u)) + ufl.grad(p)


def eps(w):
    return ufl.sym(ufl.grad(w))


# %% the weak form, written once
def stokes(s):
    """Left-hand side: viscous, pressure-divergence coupling, PSPG."""
    (u, p), (v, q) = s.trial, s.test
    tau = s.constant("tau")
    return (2 * MU * ufl.inner(eps(u), eps(v)) - p * ufl.div(v) + q * ufl.div(u)
            + tau * ufl.inner(-MU * ufl.div(ufl.grad(u)) + ufl.grad(p), ufl.grad(q))) * s.dx


def load(s):
    """Right-hand side: body force and its PSPG counterpart."""
    v, q = s.test
    f = body_force(s.x)
    return (ufl.inner(f, v) + s.constant("tau") * ufl.inner(f, ufl.grad(q))) * s.dx


def velocity_error(s):
    """``|u_h - u|^2``, integrated to give the squared L2 error."""
    u_h, _ = ufl.split(s.grid("solution"))
    u, _ = exact(s.x)
    return ufl.inner(u_h - u, u_h - u) * s.dx


# %% one grid: seed particles, assemble, constrain, solve, measure
def solve(cells: int, Basis, comm, jitter: float) -> float:
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 1.0 / cells)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    particles = fempm.Particles(grid)
    particles.seed(fempm.Rectangle((0.0, 0.0), (1.0, 1.0)), per_cell=2, density=1.0)
    rng = np.random.default_rng(1 + comm.rank)
    particles.fields["x"] += jitter * grid.h / 2 * (2 * rng.random(particles.x.shape) - 1)
    particles.relocate()

    constants = {"tau": grid.h**2 / (12 * MU)}
    A = fempm.ParticleForm(stokes, space, particles, constants=constants).assemble_matrix(particles)
    b = fempm.ParticleForm(load, space, particles, constants=constants).assemble_vector(particles)

    # walls: both velocity components; pressure: held at zero at one corner (it is defined up to a
    # constant, which the velocity does not see)
    walls = np.concatenate([space.wall_dofs("u", c) for c in range(2)])
    owned = space.local_to_global[: space.num_owned_dofs]
    corner = space.bs * space.numbering.global_index[0] + 2
    free = np.setdiff1d(owned, np.append(walls, corner))
    solution = fempm.GridFunction(space, "solution")
    x = LinearSolver(comm, prefix="stokes_").solve(A, b.petsc_vec, free)
    solution.vector.array[: space.num_owned_dofs] = x.getArray(readonly=True)
    solution.scatter_forward()

    error = fempm.GaussForm(velocity_error, space, grid_functions={"solution": solution}, degree=8)
    return np.sqrt(error.assemble_scalar())


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--levels", nargs="+", type=int, default=[8, 16, 32], help="cells per direction")
    parser.add_argument("--out", type=Path, default=Path("results/stokes_particles"))
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    table = {}
    for Basis in (fempm.Q1, fempm.BSpline2):
        for arrangement, jitter in (("on the lattice", 0.0), ("jittered by 20 %", 0.2)):
            errors = [solve(n, Basis, comm, jitter) for n in args.levels]
            table[f"{Basis.name}, {arrangement}"] = errors
            if comm.rank == 0:
                print(f"{Basis.name}, particles {arrangement}: L2 velocity error")
                for k, (n, e) in enumerate(zip(args.levels, errors)):
                    rate = np.log(errors[k - 1] / e) / np.log(n / args.levels[k - 1]) if k else float("nan")
                    print(f"  h = 1/{n:<3d}  {e:.3e}   rate {rate:4.2f}")

    # %% plot error against h
    if comm.rank == 0:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        args.out.mkdir(parents=True, exist_ok=True)
        fig, ax = plt.subplots(figsize=(5, 4))
        h = 1.0 / np.array(args.levels)
        for name, errors in table.items():
            ax.loglog(h, errors, "o-", label=name)
        ax.set_xlabel("h")
        ax.set_ylabel("L2 error of the velocity")
        ax.set_title("Stokes integrated on particles (2 x 2 per cell)")
        ax.legend()
        fig.tight_layout()
        tmp = args.out / ".convergence.png"
        fig.savefig(tmp, dpi=120)
        tmp.replace(args.out / "convergence.png")
        print(f"wrote {args.out / 'convergence.png'}")


if __name__ == "__main__":
    main()
