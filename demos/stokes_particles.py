# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Stokes flow integrated on particles: a weak form written once in UFL, solved on Q1 and B-splines
#
# fempm's engine without time stepping: the material points are the quadrature points of a
# weak form. A manufactured solution on the unit square with no-slip walls,
#
# $$
# -\mu\,\Delta u + \nabla p = f, \qquad \nabla\cdot u = 0 \quad \text{in } (0, 1)^2, \qquad u = 0 \text{ on the walls},
# $$
#
# with $u = \operatorname{curl}\psi$, $\psi = x^2 (1 - x)^2 y^2 (1 - y)^2$, $p = (x - \tfrac12)(y - \tfrac12)$,
# and $f$ derived from them symbolically (UFL).
#
# ## Weak form
#
# With PSPG stabilisation (Tezduyar 1992; equal-order velocity and pressure), $\tau = h^2 / (12\mu)$:
# find $(u, p)$ such that for all $(v, q)$
#
# $$
# \int 2\mu\,\varepsilon(u):\varepsilon(v) - p\,\nabla\cdot v + q\,\nabla\cdot u
#   + \tau\,(-\mu\,\Delta u + \nabla p - f)\cdot\nabla q \,\mathrm{d}x = \int f\cdot v\,\mathrm{d}x.
# $$
#
# The integrals are sums over particles, 2 x 2 per cell with volume $h^2/4$: once on the lattice
# (the composite midpoint rule) and once with every particle moved off its site by up to 20 % of
# the spacing, as moving material points are. On the lattice both bases converge at second
# order; with jittered particles the quadrature error of the particles takes over and the rate
# drops towards one, more for the B-splines: the known price of integrating on material points.

# %%
import argparse
import sys
from pathlib import Path

import numpy as np
import ufl
from mpi4py import MPI

import fempm
from fempm import output
from fempm.linear import LinearSolver

MU = 1.0

# %% [markdown]
# ## The exact solution and the forms
#
# The exact solution is written in UFL, so the body force follows from it symbolically; the
# forms are functions of a `Symbols` object `s` (`s.dx` integrates at the particles), as in
# `forms/incompressible.py`.


# %%
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


# %% [markdown]
# ## One grid
#
# Seed the particles (and jitter them), assemble the system at the particles, hold the walls'
# velocity and the pressure at one corner (it is defined up to a constant), solve with PETSc and
# integrate the velocity error with Gauss quadrature.


# %%
def solve(cells: int, Basis, comm, jitter: float) -> float:
    """The L2 velocity error on ``cells`` x ``cells`` cells of ``Basis``, particles jittered by ``jitter``."""
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


# %% [markdown]
# ## Both bases, on the lattice and jittered, under refinement

# %%
parser = argparse.ArgumentParser(description="Stokes flow integrated on particles (see the file's first cells).")
parser.add_argument("--levels", nargs="+", type=int, default=[8, 16, 32], help="cells per direction")
parser.add_argument("--out", type=Path, default=Path("results/stokes_particles"))
args = parser.parse_args()
comm = MPI.COMM_WORLD
table = {}
for Basis in (fempm.Q1, fempm.BSpline2):
    for arrangement, jitter in (("on the lattice", 0.0), ("jittered by 20 %", 0.2)):
        errors = [solve(n, Basis, comm, jitter) for n in args.levels]
        rates = [float(np.log(e0 / e1) / np.log(n1 / n0))
                 for (n0, e0), (n1, e1) in zip(zip(args.levels, errors), list(zip(args.levels, errors))[1:])]
        table[f"{Basis.name}, {arrangement}"] = {"levels": args.levels, "errors": errors, "rates": rates}
        if comm.rank == 0:
            print(f"{Basis.name}, particles {arrangement}: L2 velocity error "
                  + ", ".join(f"{e:.3e} (h = 1/{n})" for n, e in zip(args.levels, errors))
                  + "; rates " + ", ".join(f"{r:.2f}" for r in rates))

# %% [markdown]
# ## Error against h, written to `convergence.png` and `errors.json`

# %%
if comm.rank == 0:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = output.prepare_folder(args.out, MPI.COMM_SELF)
    output.write_json(folder / "errors.json", table)
    fig, ax = plt.subplots(figsize=(5, 4))
    for name, row in table.items():
        ax.loglog(1.0 / np.array(row["levels"]), row["errors"], "o-", label=name)
    ax.set(xlabel="h", ylabel="L2 error of the velocity", title="Stokes integrated on particles (2 x 2 per cell)")
    ax.legend()
    fig.tight_layout()
    output.save_figure(fig, folder / "convergence.png", dpi=120)

# %% [markdown]
# ## The check
#
# On the lattice both bases must converge at second order: every observed rate within 0.1 of 2.

# %%
lattice = [rate for name, row in table.items() if name.endswith("lattice") for rate in row["rates"]]
if any(abs(rate - 2) > 0.1 for rate in lattice):  # measured 1.97 to 2.00 (levels 8, 16, 32)
    if comm.rank == 0:
        print(f"stokes_particles: rates on the lattice {lattice}, not within 0.1 of 2", file=sys.stderr)
    sys.exit(1)
