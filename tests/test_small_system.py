"""The compiled solve of small systems (fempm.small_system) against MUMPS LU of the whole free block, and
the systems it leaves to PETSc's split: a viscous flow's, a singular one."""

from dataclasses import replace
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import linear, small_system
from fempm.cases import dambreak
from fempm.scene import load_scene
from fempm.simulation import build_solver

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"


def _recording(monkeypatch) -> list:
    """The compiled solve's calls, (grid matrix, free dofs, right-hand side, status), as they are made."""
    calls, solve = [], small_system.solve

    def recorded(grid_matrix, free, b, rtol, x, max_it=20):
        status = solve(grid_matrix, free, b, rtol, x, max_it)
        calls.append((grid_matrix, np.array(free), np.array(b), status))
        return status

    monkeypatch.setattr(small_system, "solve", recorded)
    return calls


def _lu(grid_matrix, free, b) -> np.ndarray:
    rhs = grid_matrix.mat.createVecLeft()
    rhs.setArray(b)
    return linear.LinearSolver(MPI.COMM_SELF, "fempm_lu_", options=linear.DIRECT).solve(grid_matrix.mat, rhs,
                                                                                         free).getArray().copy()


def test_the_dam_breaks_systems_are_solved_to_round_off(monkeypatch):
    """Every solve of the shipped scene to the impact on the far wall (0.3 s) is the compiled one's, in a few
    iterations; the last equals MUMPS LU of the free block to round-off and is zero on the other dofs."""
    calls = _recording(monkeypatch)
    solver = build_solver(load_scene(SCENE), MPI.COMM_SELF)
    while solver.time < 0.3:
        solver.step()
    ls = solver.system.linear_solver
    assert ls.compiled == len(calls) >= 50 and ls.compiled_declined == 0  # measured 60 of 60
    assert max(status for *_, status in calls) <= 4  # measured 3 in every solve
    grid_matrix, free, b, _ = calls[-1]
    x = np.empty_like(b)
    assert small_system.solve(grid_matrix, free, b, linear.EXACT_RTOL, x) > 0
    lu = _lu(grid_matrix, free, b)
    # measured 2.6e-13: both stop at round-off, this one at a residual of 1e-13 |b| (linear.EXACT_RTOL)
    assert np.linalg.norm(x - lu) <= 1e-12 * np.linalg.norm(lu)
    assert np.all(x[np.setdiff1d(np.arange(len(x)), free)] == 0.0)


def test_a_finer_grids_systems_are_solved_to_round_off(monkeypatch):
    """On 60² cells (some 1,600 free dofs at the start, where the split factors S by MUMPS) the compiled solve takes
    every system too, and equals MUMPS LU of the free block."""
    calls = _recording(monkeypatch)
    solver = build_solver(dambreak.scene({"domain.cells": [60, 60]}, files=False), MPI.COMM_SELF)
    for _ in range(3):
        solver.step()
    assert solver.system.linear_solver.compiled == len(calls) == 4  # a_0's solve and three steps
    grid_matrix, free, b, _ = calls[-1]
    assert len(free) > linear.SMALL_SYSTEM  # measured 1,585
    assert max(status for *_, status in calls) <= 5  # measured 4 (the first steps' 10 ms)
    x = np.empty_like(b)
    small_system.solve(grid_matrix, free, b, linear.EXACT_RTOL, x)
    lu = _lu(grid_matrix, free, b)
    assert np.linalg.norm(x - lu) <= 1e-12 * np.linalg.norm(lu)  # measured 5.0e-15


def test_a_viscous_flows_systems_are_left_to_the_split(monkeypatch):
    """At 1 Pa s the velocity block is far from its diagonal (a row's off-diagonal share 0.33 at the scene's
    first step, water's 3e-4): the compiled solve declines at once, and the split solves as MUMPS LU does."""
    calls = _recording(monkeypatch)
    scene = load_scene(SCENE)
    solver = build_solver(replace(scene, fluid=replace(scene.fluid, viscosity=1.0)), MPI.COMM_SELF)
    solver.step()
    ls = solver.system.linear_solver
    assert ls.compiled == 0 and ls.compiled_declined == len(calls) == 2  # a_0's solve and the step's
    assert {status for *_, status in calls} == {small_system.NOT_DIAGONAL}
    grid_matrix, free, b, _ = calls[-1]
    lu = _lu(grid_matrix, free, b)
    split = solver.system.U.vector.array[: len(b)]  # U = the solve's (du, p): the held dofs are zero here
    assert np.linalg.norm(split - lu) <= 1e-12 * np.linalg.norm(lu)  # measured 7.2e-14


def test_a_singular_system_is_declined(monkeypatch):
    """A system with nothing in it (a zero matrix) meets a zero pivot: the status says so, for the split to try."""
    calls = _recording(monkeypatch)
    solver = build_solver(load_scene(SCENE), MPI.COMM_SELF)
    solver.step()
    grid_matrix, free, b, _ = calls[-1]
    grid_matrix.values[:] = 0.0
    assert small_system.solve(grid_matrix, free, b, linear.EXACT_RTOL, np.empty_like(b)) == small_system.ZERO_PIVOT
