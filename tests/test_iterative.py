"""The iterative solver (Schur fieldsplit + AMG, ``solver.linear = "iterative"``) against MUMPS.

One dam-break step from the shipped scene is taken by two solvers that differ only in
``solver.linear``; the displacement increments and the pressures must agree to 1e-8
relative. Runs on any number of ranks (the MPI suite repeats it on two).
"""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fempm.scene import load_scene
from fempm.simulation import build_solver

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"


def _norm(a, comm):
    return np.sqrt(comm.allreduce(float(np.dot(a.ravel(), a.ravel()))))


@pytest.mark.mpi
def test_iterative_solver_reproduces_the_direct_step():
    comm = MPI.COMM_WORLD
    scene = load_scene(SCENE)
    steps = {}
    for kind in ("direct", "iterative"):
        solver = build_solver(replace(scene, solver=replace(scene.solver, linear=kind)), comm)
        solver.step()
        system = solver.system
        owned = system.space.numbering.num_owned
        steps[kind] = {name: system.U.field(name)[:owned].copy() for name in ("u", "p")}
        ksp = system.linear_solver.ksp
        steps[kind]["solver"] = (ksp.getType(), ksp.getPC().getType(), ksp.getIterationNumber())
    ksp_type, pc_type, iterations = steps["iterative"]["solver"]
    assert (ksp_type, pc_type) == ("fgmres", "fieldsplit") and iterations > 2
    assert steps["direct"]["solver"][0] == "preonly"
    for name in ("u", "p"):
        direct, iterative = steps["direct"][name], steps["iterative"][name]
        assert _norm(direct, comm) > 0
        assert _norm(iterative - direct, comm) <= 1e-8 * _norm(direct, comm), name
