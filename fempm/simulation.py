"""A scene made real: the grid, particles and solver it describes, run with its outputs.

Only what the scene enables is built: obstacle constraints only with obstacles, the
viscous, volume-correction and PSPG terms only when switched on (the forms leave out
a term whose constant is zero), output series only at the intervals asked for, and
checkpoints only with ``output.checkpoint_interval`` (or when a run is interrupted). The solve covers the dofs the
fluid touches (``ImplicitSolver.project``).

An output folder holding an earlier run's files is refused unless the run starts afresh
(``overwrite``, which removes those files and nothing else) or continues it (:func:`resume`).
"""

from __future__ import annotations

import contextlib
import math
import signal
import sys
import threading
from dataclasses import asdict
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import diagnostics, linear, output, recording
from fempm.bases import BASES
from fempm.errors import InputError
from fempm.formsfile import reporting_errors
from fempm.grid import Grid, cell_shares
from fempm.implicit import ImplicitSolver
from fempm.options import Controls, Physics, Scheme
from fempm.particles import Particles, sub_cell_centres
from fempm.recording import Recorder, RecorderOptions
from fempm.restart import (CHECKPOINT, Checkpoints, StopSignals, check_against, check_time, read_checkpoint,
                           restore)
from fempm.scene import Scene, scene_from_text, to_toml

__all__ = ["build_material", "build_solver", "check_folder", "pressure_limit", "recorder_for", "resume", "run_scene"]

FIELDS = {"u": 2, "p": 1}  # the unknowns of the implicit step, for the PETSc option check


def build_solver(scene: Scene, comm=MPI.COMM_WORLD) -> ImplicitSolver:
    """The grid, obstacles, particles and implicit solver of a scene (nothing is written).

    The scene's PETSc options are checked first (see :func:`fempm.linear.check_options`).
    """
    fluid, sv = scene.fluid, scene.solver
    if sv.linear == "direct":
        petsc = {**linear.direct_options(comm), **sv.petsc}
    else:
        petsc = linear.iterative_options(sv.petsc)
    linear.set_options(petsc)
    linear.check_options(comm, list(sv.petsc), FIELDS)
    linear.set_options({})  # the solver holds them (Controls): none left behind for another solver
    basis, particles = build_material(scene, comm)
    physics = Physics(viscosity=fluid.viscosity, gravity=scene.gravity, walls=asdict(scene.walls))
    scheme = Scheme(dt=scene.time.dt, courant=scene.time.courant, beta=sv.newmark_beta, gamma=sv.newmark_gamma, alpha=sv.volume_correction,
                    alpha_rate=sv.volume_correction_rate,
                    surface_aware=sv.surface_aware, shifting=sv.shifting, shifting_keeps_angular_momentum=sv.shifting_keeps_angular_momentum, pspg=sv.pspg, transfer=sv.transfer, pic_blend=sv.pic_blend,
                    pic_rate=sv.pic_rate, noise_rate=sv.noise_rate, rest_pic_rate=sv.rest_pic_rate, forms=sv.forms, pressure_quadrature=sv.pressure_quadrature,
                    pressure_work=sv.pressure_work)
    controls = Controls(petsc_options=petsc, pressure_limit=pressure_limit(scene, particles))
    # The forms are compiled here: their mistakes name the file, and a stop request waits until the
    # compiler is done (stopped half-way, FFCx leaves its cache waiting for the compile).
    main = threading.current_thread() is threading.main_thread()  # where signal handlers can be set
    with reporting_errors(scheme.step_forms()), (StopSignals() if main else contextlib.nullcontext()) as stop:
        solver = ImplicitSolver(basis, particles, physics, scheme, controls)
    if stop is not None and stop.received:
        signal.raise_signal(stop.received)  # now as the handler outside would have had it
    return solver


def pressure_limit(scene: Scene, particles: Particles) -> float:
    """The pressure beyond which a step is taken as diverged (``Controls.pressure_limit``).

    ``solver.pressure_limit`` if the scene sets it, else ``20 rho (|g| H + U^2)`` with the
    scene's density and gravity, H the tank's height and U the fastest initial speed (at
    least 1 % of a cell per step): twenty times the larger of the hydrostatic pressure and
    the dynamic pressure of the initial motion.
    """
    if scene.solver.pressure_limit is not None:
        return scene.solver.pressure_limit
    speed = diagnostics.fastest(particles)
    d = scene.domain
    height, gravity = d.upper[1] - d.lower[1], float(np.hypot(*scene.gravity))
    scale = max(gravity * height + speed**2, (0.01 * d.h / scene.time.dt) ** 2)
    return 20 * scene.fluid.density * scale


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
                       velocity=body.initial_velocity())
    return BASES[scene.solver.basis](grid), particles


def body_weights(scene: Scene) -> np.ndarray:
    """Particles each cell starts with (the seeding points inside the bodies), ``(ny, nx)``."""
    d = scene.domain
    (nx, ny), h = d.shape, d.h
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    origins = np.column_stack([d.lower[0] + h * i.ravel(), d.lower[1] + h * j.ravel()])
    sizes = h * cell_shares(np.arange(nx * ny), (nx, ny), d.last)
    weights = np.zeros(nx * ny)
    for body in scene.bodies:
        per_cell = math.isqrt(body.particles_per_cell)
        inside = body.geometry().contains(sub_cell_centres(origins, sizes, per_cell))
        weights += inside.reshape(nx * ny, per_cell**2).sum(axis=1)
    return weights.reshape(ny, nx)


def run_scene(scene: Scene, comm=MPI.COMM_WORLD, overwrite: bool = False, progress: bool | None = None) -> dict:
    """Run a scene from its start; returns the summary (also in ``summary.json``).

    Args:
        overwrite: start afresh in a folder holding an earlier run's files: they
            (:data:`fempm.output.OUTPUT_NAMES`) are removed once the scene is built; other files stay.
        progress: print a progress line (default: the scene's ``output.progress``).

    Raises:
        InputError: the folder holds an earlier run's files and ``overwrite`` is False,
            or the scene cannot be built.
    """
    folder = Path(scene.output.folder)
    earlier = check_folder(folder, comm, overwrite)
    solver = build_solver(scene, comm)
    if earlier:
        output.remove_earlier_outputs(folder, comm)
    return _run(scene, solver, None, progress)


def check_folder(folder: str | Path, comm=MPI.COMM_WORLD, overwrite: bool = False, key: str = "output.folder") -> list:
    """The earlier run's files in ``folder`` (:func:`fempm.output.earlier_outputs`), which a new run may
    replace only with ``overwrite``.

    Raises:
        InputError: the folder holds an earlier run's files and ``overwrite`` is False.
    """
    earlier = comm.bcast(output.earlier_outputs(folder) if comm.rank == 0 else None, root=0)
    if earlier and not overwrite:
        if CHECKPOINT in earlier:
            raise InputError(f"{key} = {str(folder)!r} holds the checkpoint of an earlier run: continue it "
                             f"with `fempm run --resume {folder}`, or start afresh with --overwrite")
        shown = ", ".join(earlier[:3]) + (", ..." if len(earlier) > 3 else "")
        raise InputError(f"{key} = {str(folder)!r} holds the outputs of an earlier run ({shown}; no checkpoint "
                         f"to continue from): start afresh with --overwrite (removes them), or choose another folder")
    return earlier


def resume(folder: str | Path, comm=MPI.COMM_WORLD, end_time: float | None = None,
           progress: bool | None = None, forms: str | Path | None = None, max_memory: float | None = None,
           available: float | None = None) -> dict:
    """Continue the run whose checkpoint is in ``folder``, writing on into ``folder``.

    Args:
        end_time: a new end time (default: the scene's), e.g. to extend a finished run.
        forms: the forms file of the user's own that the run used (a checkpoint names it, but
            a forms file is code: it is loaded only when given again here).
        max_memory, available: see :func:`fempm.scene.load_scene`.
    """
    checkpoint = read_checkpoint(folder, comm)
    source = Path(folder) / CHECKPOINT
    if forms is None:
        used = _forms_of(checkpoint.scene)
        if used is not None and ("/" in used or used.endswith(".py")):
            raise InputError(f"--resume {str(folder)!r}: the run used the forms file {used!r}, which is Python code: "
                             f"to run it again give --forms {used}")
    scene = scene_from_text(checkpoint.scene, source, folder=folder, end_time=end_time, forms=forms,
                            max_memory=max_memory, ranks=comm.size, available=available)
    if checkpoint.ranks != comm.size and comm.rank == 0:
        print(f"fempm: note: resuming on {comm.size} rank(s) a run checkpointed on {checkpoint.ranks}: it goes on "
              f"correctly, but bit-identical continuation holds only on the same number of ranks", file=sys.stderr)
    if scene.time.courant is None:  # a fixed step: the time is the step count times dt
        check_time(checkpoint, scene.time.dt, folder)
    if scene.time.end < checkpoint.time - 0.5 * scene.time.dt:
        raise InputError(f"--end-time {scene.time.end:g} is before the checkpoint's time {checkpoint.time:g} s")
    solver = build_solver(scene, comm)
    check_against(checkpoint, solver, folder)
    return _run(scene, solver, checkpoint, progress)


def _forms_of(scene_text: str) -> str | None:
    """``solver.forms`` of a scene's TOML (None: absent or unreadable; the scene check says why)."""
    import tomllib

    try:
        forms = tomllib.loads(scene_text).get("solver", {}).get("forms")
    except (tomllib.TOMLDecodeError, AttributeError):
        return None
    return forms if isinstance(forms, str) else None


def recorder_for(scene: Scene, solver, extra: dict | None = None) -> Recorder:
    """The recorder of a scene's ``[output]`` for ``solver`` (any scheme); ``extra`` joins the summary."""
    o = scene.output
    return Recorder(solver, RecorderOptions(
        folder=Path(o.folder), particles_interval=o.particles_interval, grid_interval=o.grid_interval,
        snapshot_times=o.snapshots, final_snapshot=o.final_snapshot, pressure_scale=o.pressure_scale,
        gauges=tuple((g.gauge(), g.interval) for g in scene.gauges),
        extra={"scene": scene.name, "dt": solver.dt, **(extra or {})},
    ))


def _run(scene: Scene, solver: ImplicitSolver, checkpoint, progress: bool | None) -> dict:
    o = scene.output
    recorder = recorder_for(scene, solver, {"resumed_from_step": checkpoint.steps if checkpoint else None})
    if checkpoint:
        restore(solver, recorder, checkpoint)
    checkpoints = Checkpoints(recorder.folder, to_toml(scene), o.checkpoint_interval)
    with StopSignals() as stop:
        return recording.run(solver, scene.time.end, recorder, progress=o.progress if progress is None else progress,
                             checkpoints=checkpoints, stop=stop)
