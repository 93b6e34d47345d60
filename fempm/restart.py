"""Checkpoints and restarts: a run continues from its last checkpoint as if never stopped.

A checkpoint, ``checkpoint.npz`` in the output folder, holds everything the next step
depends on: every particle field (gathered to rank 0, ordered by id), the time and
step count, the scene (TOML, defaults resolved) and the recorder's histories and
series indices. The solver keeps nothing else between steps (grid fields are
projected afresh every step), so a resumed run on the same number of ranks repeats
the uninterrupted run bit for bit. The file is written to a temporary name and
renamed, so a kill at any moment leaves the previous checkpoint intact. A checkpoint
read back is checked field by field (:func:`read_checkpoint`, :func:`check_against`)
before anything is built from it: a hand-edited or foreign file gets one message naming
the field.

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
from fempm.output import OUTPUT_NAMES, OutputError, agree, atomic_path, gather_particles
from fempm.recording import Schedule

__all__ = ["CHECKPOINT", "Checkpoint", "Checkpoints", "StopSignals", "check_against", "check_time", "read_checkpoint",
           "restore", "write_checkpoint"]

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
    clock: dict


def write_checkpoint(folder: Path, solver, recorder, scene_text: str):
    """Write ``folder/checkpoint.npz`` atomically (collective; rank 0 writes)."""
    particles = solver.particles
    comm = particles.grid.comm
    data = gather_particles(particles, [n for n in particles.fields if n not in ("x", "id")])
    lost = (comm.allreduce(particles.lost_mass), comm.allreduce(particles.lost_count))
    state = recorder.state()  # collective
    error = None
    if comm.rank == 0:
        meta = {"time": solver.time, "steps": solver.steps, "ranks": comm.size, "lost": lost, "recorder": state,
                "clock": solver.clock_state()}
        arrays = {f"{_PARTICLE}{name}": a for name, a in data.items()}
        try:
            with atomic_path(Path(folder) / CHECKPOINT) as tmp:
                np.savez(tmp, scene=np.array(scene_text), meta=np.array(json.dumps(meta)), **arrays)
        except OutputError as e:
            error = str(e)
    agree(comm, error)
    solver.resume_point()


def read_checkpoint(folder: str | Path, comm) -> Checkpoint:
    """Read ``folder/checkpoint.npz`` (rank 0 reads; the rest is broadcast).

    Raises:
        InputError: no folder, no checkpoint in it, a file that is not one, or metadata
            that are not what a checkpoint holds (the message names the field).
    """
    path = Path(folder) / CHECKPOINT
    head, arrays, error = None, {}, None
    if comm.rank == 0:
        try:
            if "\0" in str(folder):
                error = f"--resume {str(folder)!r}: a folder name cannot hold a NUL character"
            elif not Path(folder).is_dir():
                error = f"--resume {str(folder)!r}: no such folder"
            elif not path.is_file():
                error = f"--resume {str(folder)!r}: the folder holds no {CHECKPOINT} (was the run started with " \
                        f"output.checkpoint_interval?)"
            else:
                with np.load(path, allow_pickle=False) as f:
                    head = (str(f["scene"]), json.loads(str(f["meta"])))
                    arrays = {k[len(_PARTICLE):]: f[k] for k in f.files if k.startswith(_PARTICLE)}
                problem = _check_meta(head[1])
                if problem:
                    error = f"--resume {str(folder)!r}: {CHECKPOINT}: {problem}"
        except (OSError, EOFError, KeyError, ValueError, zipfile.BadZipFile) as e:
            error = f"--resume {str(folder)!r}: {CHECKPOINT} cannot be read ({' '.join(str(e).split())})"
    error = comm.bcast(error, root=0)
    if error:
        raise InputError(error)
    scene, meta = comm.bcast(head, root=0)
    shapes = comm.bcast({k: (a.dtype.str, a.shape[1:]) for k, a in arrays.items()}, root=0)
    if comm.rank != 0:
        arrays = {k: np.zeros((0, *shape), dtype=dtype) for k, (dtype, shape) in shapes.items()}
    return Checkpoint(scene, meta["time"], meta["steps"], meta["ranks"], meta["recorder"],
                      tuple(meta["lost"]), arrays, meta.get("clock", {}))


def _number(x) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def _whole(x, low: int = 0) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= low


def _rows(value, kinds) -> str | None:
    """Why ``value`` is not a list of rows of the given kinds (None: it is)."""
    if not isinstance(value, list):
        return f"must be a list, got {type(value).__name__}"
    for k, row in enumerate(value):
        if not isinstance(row, list) or len(row) != len(kinds) or not all(ok(v) for ok, v in zip(kinds, row)):
            return f"row {k} is {row!r}, not [{', '.join(ok.__doc__ for ok in kinds)}]"
    return None


def _finite(x) -> bool:
    """a finite number"""
    return _number(x) and bool(np.isfinite(x))


def _count(x) -> bool:
    """a whole number >= 0"""
    return _whole(x)


def _series_file(x) -> bool:
    """a series file name"""
    return isinstance(x, str) and OUTPUT_NAMES.fullmatch(x) is not None and "/" not in x


def _check_meta(meta) -> str | None:
    """What is wrong with a checkpoint's metadata, naming the field (None: nothing)."""
    if not isinstance(meta, dict):
        return f"meta must be a table, got {type(meta).__name__}"
    expected = {"time": "a finite number >= 0", "steps": "a whole number >= 0", "ranks": "a whole number >= 1",
                "lost": "[mass >= 0, count >= 0]", "recorder": "a table"}
    for name, what in expected.items():
        if name not in meta:
            return f"meta.{name} is missing ({what})"
    checks = {"time": _finite(meta["time"]) and meta["time"] >= 0, "steps": _whole(meta["steps"]),
              "ranks": _whole(meta["ranks"], 1),
              "lost": (isinstance(meta["lost"], list) and len(meta["lost"]) == 2 and _finite(meta["lost"][0])
                       and meta["lost"][0] >= 0 and _whole(meta["lost"][1])),
              "recorder": isinstance(meta["recorder"], dict)}
    for name, ok in checks.items():
        if not ok:
            return f"meta.{name} = {meta[name]!r}: must be {expected[name]}"
    r = meta["recorder"]
    for name in ("front", "cells", "pressure_min", "pressure_max", "max_divergence", "particle_series", "grid_series"):
        if name not in r:
            return f"meta.recorder.{name} is missing"
    for name, kinds in (("front", (_finite, _finite)), ("cells", (_finite, _count, _finite)),
                        ("particle_series", (_finite, _series_file)), ("grid_series", (_finite, _series_file))):
        problem = _rows(r[name], kinds)
        if problem:
            return f"meta.recorder.{name}: {problem}"
    for name in ("pressure_min", "pressure_max", "max_divergence"):
        if not _number(r[name]) or np.isnan(r[name]):
            return f"meta.recorder.{name} = {r[name]!r}: must be a number"
    for name in ("front", "cells"):
        if len(r[name]) != meta["steps"] + 1:
            return (f"meta.recorder.{name} has {len(r[name])} rows, but a run at step {meta['steps']} has "
                    f"{meta['steps'] + 1} (one per step and the start)")
    clock = meta.get("clock", {})
    if not isinstance(clock, dict) or not all(isinstance(k, str) and (v is None or _finite(v) or isinstance(v, list))
                                              for k, v in clock.items()):
        return f"meta.clock = {clock!r}: must be a table of numbers"
    if "wall_time_s" in r and not (_finite(r["wall_time_s"]) and r["wall_time_s"] >= 0):
        return f"meta.recorder.wall_time_s = {r['wall_time_s']!r}: must be a number >= 0"
    phases = r.get("wall_time_by_phase_s", {})
    if not isinstance(phases, dict) or not all(isinstance(k, str) and _finite(v) for k, v in phases.items()):
        return f"meta.recorder.wall_time_by_phase_s = {phases!r}: must be a table of seconds"
    return None


def check_against(checkpoint: Checkpoint, solver, folder: str | Path):
    """Raise :class:`InputError` unless the checkpoint fits the solver built from its scene.

    Checked field by field on rank 0: the particle fields are those of the solver's
    particles, each with one row per particle, the solver's value shape and kind
    (ids whole and distinct), finite, with volume and mass positive; the series files the
    checkpoint lists are in ``folder`` (the time: :func:`check_time`).
    """
    particles = solver.particles
    comm = particles.grid.comm
    error = None
    if comm.rank == 0:
        error = _particle_problem(checkpoint.particles, particles.fields)
        if error is None:
            for key in ("particle_series", "grid_series"):
                missing = [f for _, f in checkpoint.recorder[key] if not (Path(folder) / f).is_file()]
                if missing:
                    error = (f"meta.recorder.{key} lists {missing[0]}, which is not in the folder "
                             f"({len(missing)} missing)")
                    break
    error = comm.bcast(error, root=0)
    if error:
        raise InputError(f"--resume {str(folder)!r}: {CHECKPOINT}: {error}")


def check_time(checkpoint: Checkpoint, dt: float, folder: str | Path):
    """Raise :class:`InputError` unless the checkpoint's time is its step count times ``dt``."""
    if abs(checkpoint.time - checkpoint.steps * dt) > 0.5 * dt:
        raise InputError(f"--resume {str(folder)!r}: {CHECKPOINT}: meta.time = {checkpoint.time!r} is not meta.steps = "
                         f"{checkpoint.steps} times the scene's time.dt = {dt:g}")


def _particle_problem(arrays: dict[str, np.ndarray], fields: dict[str, np.ndarray]) -> str | None:
    """What is wrong with the checkpoint's particle arrays against the solver's fields (None: nothing)."""
    names, expected = set(arrays), set(fields)
    if names != expected:
        extra, missing = sorted(names - expected), sorted(expected - names)
        return (f"particle fields {missing} are missing" if missing else "") + (" and " if missing and extra else "") \
            + (f"particle fields {extra} are not fields of this scene's particles" if extra else "")
    counts = {name: a.shape[0] if a.ndim else None for name, a in arrays.items()}
    n = counts.get("id")
    for name in sorted(arrays):
        a, like = arrays[name], fields[name]
        shape = (n, *like.shape[1:])
        if a.shape != shape:
            return f"particle field {name!r} has shape {a.shape}, expected {shape} (one row per particle)"
        integer = np.issubdtype(like.dtype, np.integer)
        if not np.issubdtype(a.dtype, np.integer if integer else np.floating):
            return f"particle field {name!r} holds {a.dtype}, expected {like.dtype}"
        if not integer and not np.all(np.isfinite(a)):
            return f"particle field {name!r} holds values that are not finite"
    if n == 0:
        return "it holds no particles"
    if len(np.unique(arrays["id"])) != n or arrays["id"].min() < 0:
        return "particle field 'id' must hold distinct whole numbers >= 0"
    for name in ("volume", "mass"):
        if not np.all(arrays[name] > 0):
            return f"particle field {name!r} must be positive"
    return None


def restore(solver, recorder, checkpoint: Checkpoint):
    """Put a checkpoint's state into a solver (built from its scene) and recorder."""
    particles = solver.particles
    particles.replace(checkpoint.particles)
    first = particles.grid.comm.rank == 0
    particles.lost_mass, particles.lost_count = checkpoint.lost if first else (0.0, 0)
    solver.time, solver.steps = checkpoint.time, checkpoint.steps
    solver.restore_clock(checkpoint.clock)
    recorder.restore(checkpoint.recorder)


class Checkpoints:
    """Writes a checkpoint every ``interval`` of simulated time, at the end of a run and on a stop request.

    Args:
        folder: the output folder.
        scene_text: the scene, stored in each checkpoint.
        interval: seconds of simulated time between checkpoints; None: a checkpoint only when the
            run is interrupted.
    """

    def __init__(self, folder: Path, scene_text: str, interval: float | None):
        self.folder, self.scene_text = Path(folder), scene_text
        self.schedule = Schedule(interval) if interval else None
        self.last_step = None

    def next_time(self, t: float) -> float:
        """The first time after ``t`` a checkpoint is due (``inf``: none)."""
        return self.schedule.after(t) if self.schedule else np.inf

    def after_step(self, solver, recorder):
        """Write a checkpoint if one is due at this time."""
        if self.schedule and solver.steps and self.schedule.due(solver.time):
            self.write(solver, recorder)

    def finish(self, solver, recorder, status: str):
        """At the end of a run: a last checkpoint, if periodic ones are asked for or the run was interrupted."""
        if self.schedule or status == "interrupted":
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
