"""The same numbers on 1 and 2 ranks: assembled norms and a small Stokes solve.

Run by the suite under ``mpirun -n 2`` (see test_mpi_suite.py): each case is
computed on COMM_WORLD and again on COMM_SELF (one rank alone) and compared.
"""

import numpy as np
import pytest
import ufl
from mpi4py import MPI

import fempm
from fempm.linear import LinearSolver

from helpers import BILINEAR


def _stokes_system(comm, Basis):
    grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.125)
    space = fempm.Space(Basis(grid), {"u": 2, "p": 1})
    particles = fempm.Particles(grid)
    particles.seed(fempm.Rectangle((0.0, 0.0), (1.0, 1.0)), per_cell=2, density=1.0)
    constants = {"mu": 1.0, "tau": grid.h**2 / 12.0}

    def stokes(s):
        return BILINEAR["viscous"](s) + BILINEAR["divergence"](s) - BILINEAR["pspg"](s) + 0 * BILINEAR["mass"](s)

    def body_force(s):
        v, q = s.test
        x = s.x
        f = ufl.as_vector([ufl.sin(np.pi * x[1]), x[0] * (1 - x[0])])
        return ufl.inner(f, v) * s.dx - s.constant("tau") * ufl.inner(f, ufl.grad(q)) * s.dx

    A = fempm.ParticleForm(stokes, space, particles, constants=constants).assemble_matrix(particles)
    b = fempm.ParticleForm(body_force, space, particles, constants=constants).assemble_vector(particles)
    return space, A, b


def _in_structured_order(space, vec):
    """The whole vector on every rank, indexed by structured dof (bs * function + component)."""
    comm = space.comm
    owned = space.local_to_global[: space.num_owned_dofs]
    values = np.concatenate(comm.allgather(vec.getArray(readonly=True).copy()))
    glob = np.concatenate(comm.allgather(owned))
    structured_of = np.argsort(space.numbering.global_index)
    out = np.empty_like(values)
    out[space.bs * structured_of[glob // space.bs] + glob % space.bs] = values
    return out


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", [fempm.Q1, fempm.BSpline2])
def test_norms_and_stokes_solution_agree_on_one_and_all_ranks(Basis):
    results = {}
    for name, comm in (("all", MPI.COMM_WORLD), ("one", MPI.COMM_SELF)):
        space, A, b = _stokes_system(comm, Basis)
        walls = np.concatenate([space.wall_dofs("u", c) for c in range(2)])
        pin = [space.bs * space.numbering.global_index[0] + 2] if space.numbering.owner[0] == comm.rank else []
        fixed = np.concatenate([walls, pin]).astype(np.int64)
        owned = space.local_to_global[: space.num_owned_dofs]
        free = np.setdiff1d(owned, fixed)
        x = LinearSolver(comm, prefix=f"stokes_{name}_").solve(A, b.petsc_vec, free)
        results[name] = (A.norm(), b.petsc_vec.norm(), _in_structured_order(space, x))
    (A1, b1, x1), (A2, b2, x2) = results["one"], results["all"]
    assert A2 == pytest.approx(A1, rel=1e-12)
    assert b2 == pytest.approx(b1, rel=1e-12)
    assert np.abs(x2 - x1).max() <= 1e-12 * np.abs(x1).max()
    assert np.abs(x1).max() > 1e-3  # a real flow, not a trivial zero
