"""The exact solve's padded block pattern (fempm.schur): free dofs inside the last pattern keep it,
and the solution is that of a solver that cuts the blocks for these free dofs alone."""

from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import linear
from fempm.scene import load_scene
from fempm.simulation import build_solver

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"


def test_fewer_free_dofs_keep_the_pattern():
    comm = MPI.COMM_SELF
    solver = build_solver(load_scene(SCENE), comm)
    solver.step()
    ls = solver.system.linear_solver
    A, free = solver.region.matrix, ls._previous[1]
    b = A.createVecLeft()
    b.setArray(np.random.default_rng(2).standard_normal(b.getLocalSize()))
    fewer = free[np.random.default_rng(3).random(len(free)) > 0.1]  # a tenth of the free dofs held
    kept = ls.reuses
    x = ls.solve(A, b, fewer).getArray().copy()
    assert ls.reuses == kept + 1 and len(ls._previous[3].order) > len(free) > len(fewer)
    fresh = linear.LinearSolver(comm, "fempm_", fields=solver.system.space.fields).solve(A, b, fewer).getArray()
    held = np.setdiff1d(np.arange(len(x)), fewer)
    assert np.all(x[held] == 0.0)
    assert np.linalg.norm(x - fresh) <= 1e-12 * np.linalg.norm(fresh)  # measured 0 (the same padded pattern)
    lu = linear.LinearSolver(comm, "fempm_lu_", options=linear.DIRECT).solve(A, b, fewer).getArray()
    assert np.linalg.norm(x - lu) <= 1e-12 * np.linalg.norm(lu)  # measured 5e-16
