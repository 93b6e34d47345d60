"""The solvers of the step against MUMPS LU of the whole system.

One dam-break step from the shipped scene is taken by solvers that differ only in their PETSc
options: the iterative one (Schur fieldsplit + AMG, ``solver.linear = "iterative"``) must agree
with LU to 3e-5 relative at its default tolerance (1e-8 at 1e-13), the default exact Schur solve (one rank) to
round-off while S is solved by LU (by the compiled solve, fempm.small_system, on small systems); the package of
the Schur complement's solver follows the size, and a failed Schur iteration is redone by LU.
Runs on any number of ranks (the MPI suite repeats them on two).
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from fempm import linear
from fempm.errors import InputError
from fempm.scene import load_scene
from fempm.simulation import build_solver

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"


def _norm(a, comm):
    return np.sqrt(comm.allreduce(float(np.dot(a.ravel(), a.ravel()))))


def _one_step(comm, linear_kind="direct", petsc=None, steps=1):
    """The dam break after ``steps`` steps: (du, p) owned, and the step's linear solver."""
    scene = load_scene(SCENE)
    solver = build_solver(replace(scene, solver=replace(scene.solver, linear=linear_kind, petsc=petsc or {})), comm)
    for _ in range(steps):
        solver.step()
    system = solver.system
    owned = system.space.numbering.num_owned
    return {name: system.U.field(name)[:owned].copy() for name in ("u", "p")}, system.linear_solver


def _relative_difference(a, b, comm) -> float:
    return max(_norm(a[name] - b[name], comm) / _norm(b[name], comm) for name in ("u", "p"))


@pytest.mark.mpi
@pytest.mark.parametrize("rtol, bound", [
    # measured 1.45e-5 on one rank (the pressure; the velocity 5.4e-10), 8.5e-6 on two, 13 iterations, stopping at a
    # hundredth of Newton's tolerance (linear.MULTIGRID_RTOL)
    (None, 3e-5),
    # measured 8.4e-9 (one rank), 1.7e-8 (two) with the pressure multigrid's SOR sweeps, 22 iterations; 1.5e-8 on both
    # with its Chebyshev smoother before (the first step, at the scene's largest dt, is the worst conditioned): where in
    # the ball of rtol 1e-13 the iteration stops, times the system's condition
    (1e-13, 2.5e-8),
])
def test_iterative_solver_reproduces_the_direct_step(rtol, bound):
    comm = MPI.COMM_WORLD
    lu, lu_solver = _one_step(comm, petsc=linear.DIRECT if comm.size == 1 else None)
    iterative, solver = _one_step(comm, "iterative", petsc=None if rtol is None else {"ksp_rtol": rtol})
    ksp = solver.ksp
    assert (ksp.getType(), ksp.getPC().getType()) == ("gmres", "fieldsplit") and ksp.getIterationNumber() > 2
    assert ksp.getPCSide() == PETSc.PC.Side.RIGHT  # the true residual, as FGMRES's (every block's solve is fixed)
    assert lu_solver.ksp.getType() == "preonly"
    assert _norm(lu["u"], comm) > 0
    assert _relative_difference(iterative, lu, comm) <= bound


@pytest.mark.mpi
def test_an_inner_krylov_solve_makes_the_iterative_solver_flexible():
    """A user's inner solve of a block varies the preconditioner: the outer solver is FGMRES then; an outer
    solver the user names is theirs; the shipped blocks (Jacobi, one multigrid cycle) are fixed, and GMRES keeps half FGMRES's vectors."""
    assert linear.iterative_options({})["ksp_type"] == "gmres"
    assert linear.iterative_options({"fieldsplit_u_pc_type": "gamg"})["ksp_type"] == "gmres"
    inner = linear.iterative_options({"fieldsplit_p_ksp_type": "cg"})
    assert inner["ksp_type"] == "fgmres" and "ksp_pc_side" not in inner and inner["fieldsplit_p_ksp_type"] == "cg"
    named = linear.iterative_options({"ksp_type": "bcgs"})
    assert named["ksp_type"] == "bcgs" and "ksp_pc_side" not in named  # their solver, on its own default side


def test_default_solver_is_exact(monkeypatch):
    """One rank: the exact Schur solve, equal to MUMPS LU to round-off: at this size (the scene's ~800 free dofs)
    the compiled one (fempm.small_system), and PETSc's split with its LU of S where the compiled one is not taken;
    several ranks: LU (redundant MUMPS)."""
    comm = MPI.COMM_WORLD
    lu, _ = _one_step(comm, petsc=linear.DIRECT if comm.size == 1 else None, steps=3)
    default, solver = _one_step(comm, steps=3)
    # measured 2.5e-13 (the compiled solve stops at a residual of 1e-13 |b|; 0 on two ranks: the same solver)
    assert _relative_difference(default, lu, comm) < 1e-12
    if comm.size == 1:
        assert solver.exact_schur and solver.compiled == 4 and solver.compiled_declined == 0  # 3 steps, a_0's solve
        monkeypatch.setattr(linear, "COMPILED_SYSTEM", 0)
        split, solver = _one_step(comm, steps=3)
        assert _relative_difference(split, lu, comm) < 1e-12  # measured 6.7e-14
        assert solver.compiled == 0 and solver.ksp.getType() == "fgmres" and solver.fallbacks == 0
        assert solver.ksp.getIterationNumber() <= 4  # measured 3
        schur = solver.ksp.getPC().getFieldSplitSubKSP()[1].getPC()
        assert (schur.getType(), schur.getFactorSolverType()) == ("lu", "petsc")
    else:
        assert not solver.exact_schur and solver.ksp.getType() == "preonly"


def test_schur_factor_follows_the_size(monkeypatch):
    comm = MPI.COMM_SELF
    assert linear.schur_factor_options(linear.SMALL_SYSTEM)["fieldsplit_p_pc_factor_mat_solver_type"] == "petsc"
    assert linear.schur_factor_options(linear.SMALL_SYSTEM + 1)["fieldsplit_p_pc_factor_mat_solver_type"] == "mumps"
    small, _ = _one_step(comm)  # the compiled solve (fempm.small_system)
    monkeypatch.setattr(linear, "COMPILED_SYSTEM", 0)  # the split, and its choice of S's LU by size
    monkeypatch.setattr(linear, "SMALL_SYSTEM", 0)
    large, solver = _one_step(comm)
    schur = solver.ksp.getPC().getFieldSplitSubKSP()[1].getPC()
    assert schur.getFactorSolverType() == "mumps"
    assert _relative_difference(large, small, comm) < 1e-12  # measured 4e-16
    named, solver = _one_step(comm, petsc={"fieldsplit_p_pc_factor_mat_solver_type": "mumps"})
    assert not solver.exact_schur  # a package the user names is kept, whatever the size


def test_large_schur_complement_is_solved_by_multigrid(monkeypatch):
    """Above LARGE_SYSTEM free dofs S is solved by a multigrid cycle, to the same solution as LU;
    the solver keeps S's LU for the next, smaller system, and leaves no option in PETSc's database."""
    comm = MPI.COMM_SELF
    lu, _ = _one_step(comm, petsc=linear.DIRECT)
    monkeypatch.setattr(linear, "LARGE_SYSTEM", 0)
    cycled, solver = _one_step(comm)
    schur = solver.ksp.getPC().getFieldSplitSubKSP()[1].getPC()
    assert schur.getType() in ("gamg", "hypre") and solver.fallbacks == 0
    # to linear.MULTIGRID_RTOL: measured 12 iterations (to 1e-13 28, 21 before PSPG's displacement in a step was
    # bounded, which halves still water's tau at this 10 ms step; the first step's dt is the scene's largest; the
    # 28k-particle dam break: 7 a step, 11 to 1e-13)
    assert 4 < solver.ksp.getIterationNumber() <= 16
    assert solver.ksp.getTolerances()[0] == linear.MULTIGRID_RTOL
    # measured 1.66e-5 (the pressure; the velocity 9.7e-7) to 1e-10; to 1e-13 1.5e-8 (3.6e-9 before PSPG's
    # displacement in a step was bounded, the smaller tau conditioning this first step's system worse)
    assert _relative_difference(cycled, lu, comm) < 3e-5
    assert solver.options["fieldsplit_p_pc_type"] == "lu"  # S's LU kept for a smaller system
    assert not any(name.startswith(solver.prefix) for name in PETSc.Options().getAll())  # none left behind


def test_failed_schur_iteration_is_redone_by_lu():
    comm = MPI.COMM_SELF
    lu, _ = _one_step(comm, petsc=linear.DIRECT)
    rescued, solver = _one_step(comm, petsc={"ksp_max_it": 1})  # the Schur iteration needs 3
    assert solver.fallbacks == 2  # the first step's two solves (Scheme.initial_acceleration = "solved")
    assert _relative_difference(rescued, lu, comm) == 0.0


def test_kept_pattern_takes_the_new_values(monkeypatch):
    """A second solve with the same matrix and free dofs keeps the pattern's set-up (orderings,
    symbolic factorisations), yet solves with the matrix's new values, as a new solver would."""
    monkeypatch.setattr(linear, "COMPILED_SYSTEM", 0)  # the split, as for a larger system
    comm = MPI.COMM_SELF
    scene = load_scene(SCENE)
    solver = build_solver(scene, comm)
    solver.step()
    ls = solver.system.linear_solver
    A, free = solver.region.matrix, ls._previous[1]
    b = A.createVecLeft()
    b.setArray(np.random.default_rng(1).standard_normal(b.getLocalSize()))
    kept = ls.reuses
    once = ls.solve(A, b, free).copy()
    A.scale(2.0)
    twice = ls.solve(A, b, free).copy()
    assert ls.reuses == kept + 2
    fresh = linear.LinearSolver(comm, "fempm_", fields=solver.system.space.fields).solve(A, b, free)
    assert np.array_equal(twice.getArray(), fresh.getArray())  # measured: equal to the last bit
    half = once.getArray() / 2
    assert np.linalg.norm(twice.getArray() - half) <= 1e-12 * np.linalg.norm(half)  # measured 0 (the scaling is exact)


def test_a_new_free_set_frees_the_last_block():
    """The block of the last free set (and its index set) is destroyed before a new free set's is
    extracted (one-sided walls change the free set every step: kept until replaced, the old block
    and its preconditioner added to the peak of the next set-up)."""
    comm = MPI.COMM_SELF
    scene = load_scene(SCENE)
    solver = build_solver(replace(scene, solver=replace(scene.solver, petsc=linear.DIRECT)), comm)
    solver.step()
    ls = solver.system.linear_solver
    A, free = solver.region.matrix, ls._previous[1]
    old_index_set, old_block = ls._previous[2], ls._previous[3]
    assert old_block.handle != 0
    b = A.createVecLeft()
    b.set(1.0)
    ls.solve(A, b, free[1:])
    assert (old_block.handle, old_index_set.handle) == (0, 0)  # measured: both destroyed (0 = no PETSc object)
    assert ls._previous[3].getSize() == (len(free) - 1, len(free) - 1)


@pytest.mark.mpi
def test_iterative_split_takes_its_blocks_from_the_matrix_and_keeps_them_for_new_values():
    """The iterative solver's split is a MATNEST of blocks cut from the assembled matrix (no copy of the
    whole free block beside them) with its own ``selfp`` complement: a second solve with the same free
    dofs refills the blocks, and solves with the new values as a new solver would."""
    comm = MPI.COMM_WORLD
    scene = load_scene(SCENE)
    # solved to round-off, so that the kept and the fresh set-ups agree to it
    solver = build_solver(replace(scene, solver=replace(scene.solver, linear="iterative", petsc={"ksp_rtol": 1e-13})),
                          comm)
    solver.step()
    ls = solver.system.linear_solver
    assert ls.ksp.getOperators()[0].getType() == "nest"
    A, free = solver.region.matrix, ls._previous[1]
    b = A.createVecLeft()
    b.setArray(np.random.default_rng(comm.rank).standard_normal(b.getLocalSize()))
    kept = ls.reuses
    once = ls.solve(A, b, free).copy()
    iterations = ls.ksp.getIterationNumber()
    assert 2 < iterations <= 56  # measured 49 on one rank, 50 on two (a random right-hand side), as with PETSc's selfp
    A.scale(2.0)
    twice = ls.solve(A, b, free).copy()
    assert ls.reuses == kept + 2
    fresh = linear.LinearSolver(comm, "fempm_", ls.options, fields=solver.system.space.fields).solve(A, b, free)
    # measured 2.3e-14 on one rank, 0 on two
    assert _norm(twice.getArray() - fresh.getArray(), comm) <= 1e-12 * _norm(fresh.getArray(), comm)
    half = once.getArray() / 2
    assert _norm(twice.getArray() - half, comm) <= 1e-12 * _norm(half, comm)  # measured 6.6e-16 and 0


@pytest.mark.mpi
def test_a_solvers_options_are_its_own():
    """Two solvers under one prefix: the second, given no options, is the default and not the first's
    iterative one, and the first still solves with its own after the second was made (a solver's options
    are in PETSc's database only during its calls; left there, an iterative run's options once turned
    every later default solver of the process iterative)."""
    comm = MPI.COMM_WORLD
    scene = load_scene(SCENE)
    # to round-off, as the exact solve at this size (linear.schur_rtol)
    solver = build_solver(replace(scene, solver=replace(scene.solver, linear="iterative", petsc={"ksp_rtol": 1e-13})),
                          comm)
    solver.step()
    ls = solver.system.linear_solver
    A, free = solver.region.matrix, ls._previous[1]
    b = A.createVecLeft()
    b.setArray(np.random.default_rng(comm.rank).standard_normal(b.getLocalSize()))
    default = linear.LinearSolver(comm, "fempm_", fields=solver.system.space.fields)
    assert default.options == linear.direct_options(comm, solver.system.space.fields)
    opts = PETSc.Options()
    opts["fempm_ksp_max_it"] = 500  # a user's options under the prefix: the solvers' own hold during their calls
    opts.insertString("-fempm_a_flag_nothing_reads")
    try:
        exact = default.solve(A, b, free).copy()
        iterated = ls.solve(A, b, free)
        assert {k: v for k, v in opts.getAll().items() if k.startswith("fempm_")} == {
            "fempm_ksp_max_it": "500", "fempm_a_flag_nothing_reads": None}
    finally:  # not left for the next test of this process
        opts.delValue("fempm_ksp_max_it")
        opts.delValue("fempm_a_flag_nothing_reads")
    assert ls.ksp.getType() == "gmres" and ls.ksp.getIterationNumber() > 2  # measured 49 on one rank, 50 on two
    assert ls.ksp.getPC().getFieldSplitSubKSP()[1].getPC().getType() in ("gamg", "hypre")
    if comm.size == 1:
        assert default.ksp.getType() == "fgmres" and default.ksp.getIterationNumber() <= 6  # measured 4
    else:
        assert default.ksp.getType() == "preonly"
    # measured 2.2e-13 on one rank, 6.5e-14 on two: GMRES to 1e-13 against the exact solve
    assert _norm(iterated.getArray() - exact.getArray(), comm) <= 1e-12 * _norm(exact.getArray(), comm)


def test_options_of_the_large_systems_cycle_pass_the_check():
    """The check's trial system is small, where S is solved by LU; an option of the multigrid cycle that S takes
    above LARGE_SYSTEM is still one the solver reads (it was refused as unused), and a misspelt one still is not."""
    scene = load_scene(SCENE)

    def built(petsc):
        return build_solver(replace(scene, solver=replace(scene.solver, petsc=petsc)), MPI.COMM_SELF)

    # the second is read only by a cycle that coarsens, which a system of a few functions does not
    solver = built({"fieldsplit_p_pc_gamg_threshold": 0.05, "fieldsplit_p_pc_gamg_agg_nsmooths": 0})
    assert solver.system.linear_solver.options["fieldsplit_p_pc_gamg_threshold"] == 0.05
    with pytest.raises(InputError, match=r"fieldsplit_p_pc_gamg_thresold: PETSc did not use this option .* did you "
                                         r"mean fieldsplit_p_pc_gamg_threshold"):
        built({"fieldsplit_p_pc_gamg_thresold": 0.05})
    assert not any(name.startswith("fempm_") for name in PETSc.Options().getAll())  # none left behind


def test_a_users_option_of_the_cycle_holds_over_the_sizes_choice(monkeypatch):
    """Above LARGE_SYSTEM the size's choice of S's solver sets the cycle's options over the default's, not over the
    user's (a user's drop threshold was silently replaced by the default's 0.02)."""
    monkeypatch.setattr(linear, "LARGE_SYSTEM", 0)
    _, solver = _one_step(MPI.COMM_SELF, petsc={"fieldsplit_p_pc_gamg_threshold": 0.05,
                                                "fieldsplit_p_mg_levels_ksp_max_it": 2})
    schur = solver.ksp.getPC().getFieldSplitSubKSP()[1].getPC()
    assert schur.getType() == "gamg" and schur.getMGLevels() > 1
    assert schur.getMGSmoother(1).getTolerances()[3] == 2  # the default's one sweep otherwise


def test_a_users_tolerance_holds_at_every_size(monkeypatch):
    """A scene's ksp_rtol other than the default's is the iteration's whatever S's solver (the size's rule: round-off
    with S's LU, linear.MULTIGRID_RTOL with its cycle)."""
    monkeypatch.setattr(linear, "LARGE_SYSTEM", 0)
    _, solver = _one_step(MPI.COMM_SELF, petsc={"ksp_rtol": 1e-12})
    assert solver.ksp.getPC().getFieldSplitSubKSP()[1].getPC().getType() == "gamg"
    assert solver.ksp.getTolerances()[0] == 1e-12


@pytest.mark.mpi
def test_a_solution_not_finite_on_one_rank_fails_the_solve_on_every_rank():
    """A non-finite value on one rank stops the solve on all of them: a rank raising alone would leave the others
    waiting in the step's next collective call (under ``mpirun -n 2`` only rank 0's solution holds a NaN)."""
    comm = MPI.COMM_WORLD
    with pytest.raises(linear.SolveFailed, match="non-finite"):
        linear._check(0, np.array([1.0, np.nan if comm.rank == 0 else 2.0]), comm)
    linear._check(0, np.ones(2), comm)  # finite on every rank: no failure
