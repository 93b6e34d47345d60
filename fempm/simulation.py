"""A scene made real: the grid, particles and solver it describes, run with its outputs.

Only what the scene enables is built: obstacle constraints only with obstacles, the
viscous, volume-correction and PSPG terms only when switched on (the forms leave out
a term whose constant is zero), output series only at the intervals asked for, and
checkpoints only with ``output.checkpoint_interval`` (or when a run is interrupted). The solve covers the dofs the
fluid touches (``ImplicitSolver.project``).
"""

from __future__ import annotations

import math
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import linear, recording
from fempm.bases import BASES
from fempm.errors import InputError
from fempm.grid import Grid
from fempm.implicit import ImplicitSolver
from fempm.options import Controls, Physics, Scheme
from fempm.particles import Particles, sub_cell_centres
from fempm.recording import Recorder, RecorderOptions
from fempm.restart import CHECKPOINT, Checkpoints, StopSignals, read_checkpoint, restore
from fempm.scene import Scene, scene_from_text, to_toml

__all__ = ["build_material", "build_solver", "recorder_for", "resume", "run_scene"]

FIELDS = {"u": 2, "p": 1}  # the unknowns of the implicit step, for the PETSc option check


def build_solver(scene: Scene, comm=MPI.COMM_WORLD) -> ImplicitSolver:
    """The grid, obstacles, particles and implicit solver of a scene (nothing is written).

    The scene's PETSc options are checked first (see :func:`fempm.linear.check_options`).
    """
    fluid, sv = scene.fluid, scene.solver
    preset = linear.direct_options(comm) if sv.linear == "direct" else linear.ITERATIVE
    petsc = {**preset, **sv.petsc}
    linear.set_options(petsc)
    linear.check_options(comm, list(sv.petsc), FIELDS)
    basis, particles = build_material(scene, comm)
    physics = Physics(viscosity=fluid.viscosity, gravity=scene.gravity, walls=asdict(scene.walls))
    scheme = Scheme(dt=scene.time.dt, beta=sv.newmark_beta, gamma=sv.newmark_gamma, alpha=sv.volume_correction,
                    pspg=sv.pspg, pic_blend=sv.pic_blend, forms=sv.forms)
    return ImplicitSolver(basis, particles, physics, scheme, Controls(petsc_options=petsc))


def build_material(scene: Scene, comm=MPI.COMM_WORLD) -> tuple:
    """The grid (with its obstacles), the basis and the seeded particles of a scene."""
    d, fluid = scene.domain, scene.fluid
    weights = body_weights(scene) if comm.size > 1 else None  # share the water, not the tank
    grid = (Grid.from_cells(comm, d.lower, d.upper, d.cells, weights) if d.cells
            else Grid(comm, d.lower, d.upper, d.cell_size, weights))
    grid.block(scene.blocked_cells())
    particles = Particles(grid)
    for body in scene.bodies:
        particles.seed(body.geometry(), per_cell=math.isqrt(body.particles_per_cell), density=fluid.density,
                       velocity=body.velocity)
    return BASES[scene.solver.basis](grid), particles


def body_weights(scene: Scene) -> np.ndarray:
    """Particles each cell starts with (the seeding points inside the bodies), ``(ny, nx)``."""
    d = scene.domain
    (nx, ny), h = d.shape, d.h
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    origins = np.column_stack([d.lower[0] + h * i.ravel(), d.lower[1] + h * j.ravel()])
    weights = np.zeros(nx * ny)
    for body in scene.bodies:
        per_cell = math.isqrt(body.particles_per_cell)
        inside = body.geometry().contains(sub_cell_centres(origins, h, per_cell))
        weights += inside.reshape(nx * ny, per_cell**2).sum(axis=1)
    return weights.reshape(ny, nx)


def run_scene(scene: Scene, comm=MPI.COMM_WORLD, overwrite: bool = False, progress: bool | None = None) -> dict:
    """Run a scene from its start; returns the summary (also in ``summary.json``).

    Args:
        overwrite: start even if the output folder holds the checkpoint of an earlier run.
        progress: print a progress line (default: the scene's ``output.progress``).

    Raises:
        InputError: the folder holds an earlier run's checkpoint and ``overwrite`` is False,
            or the scene cannot be built.
    """
    folder = Path(scene.output.folder)
    if not overwrite and comm.bcast((folder / CHECKPOINT).exists(), root=0):
        raise InputError(f"output.folder = {str(folder)!r} holds the checkpoint of an earlier run: continue it "
                         f"with `fempm run --resume {folder}`, or start afresh with --overwrite")
    return _run(scene, build_solver(scene, comm), None, progress)


def resume(folder: str | Path, comm=MPI.COMM_WORLD, end_time: float | None = None,
           progress: bool | None = None) -> dict:
    """Continue the run whose checkpoint is in ``folder``, writing on into ``folder``.

    Args:
        end_time: a new end time (default: the scene's), e.g. to extend a finished run.
    """
    checkpoint = read_checkpoint(folder, comm)
    scene = scene_from_text(checkpoint.scene, Path(folder) / CHECKPOINT, folder=folder, end_time=end_time)
    if checkpoint.ranks != comm.size and comm.rank == 0:
        print(f"fempm: note: resuming on {comm.size} rank(s) a run checkpointed on {checkpoint.ranks}: it goes on "
              f"correctly, but bit-identical continuation holds only on the same number of ranks", file=sys.stderr)
    if scene.time.end < checkpoint.time - 0.5 * scene.time.dt:
        raise InputError(f"--end-time {scene.time.end:g} is before the checkpoint's time {checkpoint.time:g} s")
    return _run(scene, build_solver(scene, comm), checkpoint, progress)


def recorder_for(scene: Scene, solver, extra: dict | None = None) -> Recorder:
    """The recorder of a scene's ``[output]`` for ``solver`` (any scheme); ``extra`` joins the summary."""
    o = scene.output
    return Recorder(solver, RecorderOptions(
        folder=Path(o.folder), particles_interval=o.particles_interval, grid_interval=o.grid_interval,
        snapshot_times=o.snapshots, final_snapshot=o.final_snapshot, pressure_scale=o.pressure_scale,
        extra={"scene": scene.name, "dt": solver.dt, **(extra or {})},
    ))


def _run(scene: Scene, solver: ImplicitSolver, checkpoint, progress: bool | None) -> dict:
    o = scene.output
    recorder = recorder_for(scene, solver, {"resumed_from_step": checkpoint.steps if checkpoint else None})
    if checkpoint:
        restore(solver, recorder, checkpoint)
    checkpoints = Checkpoints(recorder.folder, to_toml(scene), o.checkpoint_interval, scene.time.dt)
    with StopSignals() as stop:
        return recording.run(solver, scene.time.end, recorder, progress=o.progress if progress is None else progress,
                             checkpoints=checkpoints, stop=stop)
