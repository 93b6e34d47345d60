"""Checkpoints and restarts: a run continues from its last checkpoint as if never stopped.

A checkpoint, ``checkpoint.npz`` in the output folder, holds everything the next step
depends on: every particle field (gathered to rank 0, ordered by id), the time and
step count, the scene (TOML, defaults resolved) and the recorder's histories and
series indices. The solver keeps nothing else between steps (grid fields are
projected afresh every step), so a resumed run on the same number of ranks repeats
the uninterrupted run bit for bit. The file is written to a temporary name and
renamed, so a kill at any moment leaves the previous checkpoint intact.

:class:`StopSignals` turns SIGINT and SIGTERM into a stop request that the run loop
sees after the step in progress (on every rank at the same step); the run then
writes a final checkpoint and ends cleanly.
"""

from __future__ import annotations

import json
import signal
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm.errors import InputError
from fempm.output import atomic_path, gather_particles
from fempm.recording import steps_between

__all__ = ["CHECKPOINT", "Checkpoint", "Checkpoints", "StopSignals", "read_checkpoint", "restore",
           "write_checkpoint"]

CHECKPOINT = "checkpoint.npz"
_PARTICLE = "particle:"


@dataclass
class Checkpoint:
    """A checkpoint as read back: ``particles`` holds the fields on rank 0, empty arrays elsewhere."""

    scene: str
    time: float
    steps: int
    ranks: int
    recorder: dict
    lost: tuple[float, int]
    particles: dict[str, np.ndarray]


def write_checkpoint(folder: Path, solver, recorder, scene_text: str):
    """Write ``folder/checkpoint.npz`` atomically (collective; rank 0 writes)."""
    particles = solver.particles
    comm = particles.grid.comm
    data = gather_particles(particles, [n for n in particles.fields if n not in ("x", "id")])
    lost = (comm.allreduce(particles.lost_mass), comm.allreduce(particles.lost_count))
    if comm.rank != 0:
        return
    meta = {"time": solver.time, "steps": solver.steps, "ranks": comm.size, "lost": lost,
            "recorder": recorder.state()}
    arrays = {f"{_PARTICLE}{name}": a for name, a in data.items()}
    with atomic_path(Path(folder) / CHECKPOINT) as tmp:
        np.savez(tmp, scene=np.array(scene_text), meta=np.array(json.dumps(meta)), **arrays)


def read_checkpoint(folder: str | Path, comm) -> Checkpoint:
    """Read ``folder/checkpoint.npz`` (rank 0 reads; the rest is broadcast).

    Raises:
        InputError: no folder, no checkpoint in it, or a file that is not one.
    """
    path = Path(folder) / CHECKPOINT
    head, arrays, error = None, {}, None
    if comm.rank == 0:
        if not Path(folder).is_dir():
            error = f"--resume {str(folder)!r}: no such folder"
        elif not path.is_file():
            error = f"--resume {str(folder)!r}: the folder holds no {CHECKPOINT} (was the run started with " \
                    f"output.checkpoint_interval?)"
        else:
            try:
                with np.load(path, allow_pickle=False) as f:
                    head = (str(f["scene"]), json.loads(str(f["meta"])))
                    arrays = {k[len(_PARTICLE):]: f[k] for k in f.files if k.startswith(_PARTICLE)}
            except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile) as e:
                error = f"--resume {str(folder)!r}: {CHECKPOINT} cannot be read ({e})"
    error = comm.bcast(error, root=0)
    if error:
        raise InputError(error)
    scene, meta = comm.bcast(head, root=0)
    shapes = comm.bcast({k: (a.dtype.str, a.shape[1:]) for k, a in arrays.items()}, root=0)
    if comm.rank != 0:
        arrays = {k: np.zeros((0, *shape), dtype=dtype) for k, (dtype, shape) in shapes.items()}
    return Checkpoint(scene, meta["time"], meta["steps"], meta["ranks"], meta["recorder"],
                      tuple(meta["lost"]), arrays)


def restore(solver, recorder, checkpoint: Checkpoint):
    """Put a checkpoint's state into a solver (built from its scene) and recorder."""
    particles = solver.particles
    particles.replace(checkpoint.particles)
    first = particles.grid.comm.rank == 0
    particles.lost_mass, particles.lost_count = checkpoint.lost if first else (0.0, 0)
    solver.time, solver.steps = checkpoint.time, checkpoint.steps
    recorder.restore(checkpoint.recorder)


class Checkpoints:
    """Writes a checkpoint every ``interval`` of simulated time, at the end of a run and on a stop request.

    Args:
        folder: the output folder.
        scene_text: the scene, stored in each checkpoint.
        interval: seconds of simulated time between checkpoints (whole steps of ``dt``);
            None: a checkpoint only when the run is interrupted.
        dt: the time step.
    """

    def __init__(self, folder: Path, scene_text: str, interval: float | None, dt: float):
        self.folder, self.scene_text = Path(folder), scene_text
        self.every = steps_between(interval, dt)
        self.last_step = None

    def after_step(self, solver, recorder):
        """Write a checkpoint if one is due at this step."""
        if self.every and solver.steps % self.every == 0:
            self.write(solver, recorder)

    def finish(self, solver, recorder, status: str):
        """At the end of a run: a last checkpoint, if periodic ones are asked for or the run was interrupted."""
        if self.every or status == "interrupted":
            self.write(solver, recorder)

    def write(self, solver, recorder):
        """Write the histories so far, then the checkpoint (once per step)."""
        if self.last_step == solver.steps:
            return
        recorder.write_histories()
        write_checkpoint(self.folder, solver, recorder, self.scene_text)
        self.last_step = solver.steps


class StopSignals:
    """While active, SIGINT and SIGTERM request a clean stop instead of killing the process.

    A second signal acts as usual (stops at once). :meth:`requested` tells every rank
    whether any rank received one, so all stop after the same step.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.received = 0
        self._previous = {}

    def __enter__(self) -> "StopSignals":
        self._previous = {s: signal.signal(s, self._handle) for s in self.SIGNALS}
        return self

    def __exit__(self, *exc):
        for s, handler in self._previous.items():
            signal.signal(s, handler)

    def _handle(self, signum, frame):
        self.received = signum
        for s, handler in self._previous.items():
            signal.signal(s, handler)

    def requested(self, comm) -> str | None:
        """The name of the signal received by any rank (None if none), the same on all ranks."""
        signum = comm.allreduce(self.received, op=MPI.MAX)
        return signal.Signals(signum).name if signum else None
