"""The exact solve's padded block pattern (fempm.schur): free dofs inside the last pattern keep it,
and the solution is that of a solver that cuts the blocks for these free dofs alone; a resumed run
gets the pattern back. (The shipped scene's systems are small enough for the compiled solve,
fempm.small_system: here the split takes them, as it does larger ones.)"""

from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import linear
from fempm.region import MatrixRegion
from fempm.scene import load_scene
from fempm.schur import FreeBlocks
from fempm.simulation import build_solver

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"


def test_fewer_free_dofs_keep_the_pattern(monkeypatch):
    monkeypatch.setattr(linear, "COMPILED_SYSTEM", 0)
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


def test_a_resumed_run_solves_on_the_kept_pattern(monkeypatch):
    """The pattern's seed, as a checkpoint keeps it, makes a new solver solve bit for bit as the one
    that kept the pattern, also on a matrix with rows only near the water."""
    monkeypatch.setattr(linear, "COMPILED_SYSTEM", 0)
    comm = MPI.COMM_SELF
    solver = build_solver(load_scene(SCENE), comm)
    solver.step()
    ls, fields = solver.system.linear_solver, solver.system.space.fields
    A, free = solver.region.matrix, ls._previous[1]
    b = A.createVecLeft()
    b.setArray(np.random.default_rng(4).standard_normal(b.getLocalSize()))
    fewer = free[free // 3 != free[-1] // 3]  # the last free function held: a pattern of its own would differ
    kept = ls.solve(A, b, fewer).getArray().copy()
    seed = ls.pattern_seed()
    resumed = linear.LinearSolver(comm, "fempm_", fields=fields)
    resumed.restore_pattern(seed)
    assert np.array_equal(resumed.solve(A, b, fewer).getArray(), kept)
    assert resumed.pattern_seed() == seed and resumed.reuses == 0
    own = FreeBlocks(A.getAttr("fempm_grid_matrix"), fewer, fields)
    assert len(own.order) < len(resumed._previous[3].order)  # without the seed: another pattern
    near_water = MatrixRegion(solver.system.space, "fluid", solver.particles).matrix
    for matrix in (A, near_water):
        solver.forms.jacobian.assemble_matrix(solver.particles, matrix)
    assert near_water.getAttr("fempm_grid_matrix").layout.indptr[-1] < A.getAttr("fempm_grid_matrix").layout.indptr[-1]
    solutions = []
    for matrix in (A, near_water):
        other = linear.LinearSolver(comm, "fempm_", fields=fields)
        other.restore_pattern(seed)
        solutions.append(other.solve(matrix, b, fewer).getArray().copy())
    assert np.array_equal(*solutions)
