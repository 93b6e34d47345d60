"""The time loop of a run and what it records: histories, ParaView series, pictures, summary.

Works with any solver that is a :class:`~fempm.stepper.Stepper` (``step()``, ``time``,
``steps``, ``dt``, ``timings``) and has ``particles``, ``grid``, ``basis``, ``velocity`` and
``pressure`` (grid functions) and ``max_divergence``.

Files are due at times (every interval from 0, or given times: :class:`Schedule`), and the
loop makes each step land on the next of them, so a run resumed from a checkpoint writes
exactly what the uninterrupted run writes, whatever its steps; the wall times in the summary add up over the parts of a resumed run. A file that cannot be
written (:class:`fempm.output.OutputError`) stops the run like a divergence, with the
file named in the cause.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import diagnostics, output
from fempm.errors import SimulationDiverged
from fempm.gauges import UNITS, Sampler, WetFraction
from fempm.output import OutputError
from fempm.progress import Progress
from fempm.stepper import TIME_TOLERANCE

__all__ = ["Recorder", "RecorderOptions", "Schedule", "run"]


class Schedule:
    """Times at which something is due: every ``interval`` from 0, and the given ``times``.

    Stateless (a resumed run asks the same questions of the same times). Times within
    :data:`~fempm.stepper.TIME_TOLERANCE` of one another are the same.
    """

    def __init__(self, interval: float | None = None, times=()):
        self.interval, self.times = interval, sorted(times)

    def _tolerance(self, t: float) -> float:
        return TIME_TOLERANCE * max(abs(t), self.interval or 0.0, 1e-300)

    def due(self, t: float) -> bool:
        """Whether ``t`` is one of the times."""
        tol = self._tolerance(t)
        on_interval = self.interval is not None and abs(t - round(t / self.interval) * self.interval) <= tol
        return on_interval or any(abs(t - s) <= tol for s in self.times)

    def after(self, t: float) -> float:
        """The first time after ``t`` (``inf``: none)."""
        tol = self._tolerance(t)
        later = [s for s in self.times if s > t + tol]
        if self.interval is not None:
            later.append(float((np.floor((t + tol) / self.interval) + 1) * self.interval))
        return min(later, default=np.inf)


@dataclass
class RecorderOptions:
    """What a run writes (intervals in simulated seconds; None: not written).

    Attributes:
        folder: output folder.
        particles_interval: particles as ``particles_*.vtp`` + ``particles.pvd``.
        grid_interval: grid velocity and pressure as ``grid_*.vti`` + ``grid.pvd``.
        snapshot_times: times of PNG pictures of the particles coloured by pressure.
        final_snapshot: a picture of the last state.
        pressure_scale: colour range of the pictures, Pa.
        gauges: ``(gauge, interval)`` pairs (:mod:`fempm.gauges`; interval in seconds, None: every
            step), written to ``gauges.csv`` and ``gauges.png``.
        extra: entries added to the summary.

    ``front.csv``, ``volume.csv`` and ``summary.json`` are always written.
    """

    folder: Path = Path("results")
    particles_interval: float | None = None
    grid_interval: float | None = None
    snapshot_times: tuple[float, ...] = ()
    final_snapshot: bool = False
    pressure_scale: tuple[float, float] | None = None
    gauges: tuple = ()
    extra: dict = field(default_factory=dict)


class Recorder:
    """Histories of a run (front, occupied cells, pressure range, divergence) and its files."""

    def __init__(self, solver, options: RecorderOptions):
        self.solver, self.options = solver, options
        self.folder = output.prepare_folder(options.folder, solver.grid.comm)
        self.front: list[tuple[float, float]] = []
        self.cells: list[tuple[float, int, float]] = []  # (t, occupied cells, surface height)
        self.pressure_min, self.pressure_max, self.max_divergence = np.inf, -np.inf, 0.0
        self.particles_due = Schedule(options.particles_interval)
        self.grid_due = Schedule(options.grid_interval)
        self.snapshots_due = Schedule(times=options.snapshot_times)
        self.particle_series = output.ParticleSeries(self.folder) if options.particles_interval else None
        self.grid_series = output.GridSeries(self.folder, solver.basis) if options.grid_interval else None
        self._wet = WetFraction(solver.basis) if options.grid_interval else None  # grid pressure only where wet
        self.wall_before, self.phases_before = 0.0, {}  # of the earlier parts of a resumed run
        self.gauges = Sampler([g for g, _ in options.gauges], solver.basis) if options.gauges else None
        self.gauges_due = [Schedule(interval) if interval else None for _, interval in options.gauges]
        self.gauge_rows: list[list] = []  # (t, reading of each gauge; NaN: dry; None: not due then)
        self._started = None

    def start_clock(self):
        """Start counting this part's wall time (the run loop calls it)."""
        self._started = time.perf_counter()

    def wall_time(self) -> float:
        """Wall seconds of this part of the run so far (this rank's clock)."""
        return time.perf_counter() - self._started if self._started is not None else 0.0

    def _times(self, part: float) -> tuple[float, float, dict[str, float]]:
        """This part's wall time, the run's (earlier parts included) and the run's by phase, each the
        largest over the ranks, so that every rank reports the same (collective)."""
        comm = self.solver.grid.comm
        part = comm.allreduce(part, op=MPI.MAX)
        local = dict(self.solver.timings)
        names = sorted(set().union(*comm.allgather(list(local))))
        phases = dict(self.phases_before)
        for name in names:
            phases[name] = phases.get(name, 0.0) + comm.allreduce(local.get(name, 0.0), op=MPI.MAX)
        return part, self.wall_before + part, phases

    def next_time(self, t: float) -> float:
        """The first time after ``t`` at which a file is due (``inf``: none)."""
        schedules = [self.particles_due, self.grid_due, self.snapshots_due, *filter(None, self.gauges_due)]
        return min(schedule.after(t) for schedule in schedules)

    def record(self):
        """Take the measures of the current state; write the files due at this time."""
        s, particles = self.solver, self.solver.particles
        t = s.time
        self.front.append((t, diagnostics.front_position(particles)))
        self.cells.append((t, diagnostics.occupied_cells(particles), diagnostics.surface_height(particles)))
        low, high = diagnostics.pressure_range(particles)
        self.pressure_min, self.pressure_max = min(self.pressure_min, low), max(self.pressure_max, high)
        self.max_divergence = max(self.max_divergence, s.max_divergence)
        if self.particle_series and self.particles_due.due(t):
            self.particle_series.write(particles, t)
        if self.grid_series and self.grid_due.due(t):
            self.grid_series.write(s.velocity, s.pressure, t, wet=self._wet(particles))
        due = [schedule is None or schedule.due(t) for schedule in self.gauges_due]
        if any(due):
            readings = self.gauges.sample(s)
            self.gauge_rows.append([t] + [v if d else None for v, d in zip(readings.values(), due)])
        if self.snapshots_due.due(t):
            output.snapshot(self.folder / f"snapshot_t{t:.3f}.png", particles, title=f"t = {t:.3f} s",
                            clim=self.options.pressure_scale)

    def write_histories(self):
        """Write ``front.csv`` and ``volume.csv`` with the histories so far (rank 0 writes; collective)."""
        grid = self.solver.grid
        error = None
        if grid.comm.rank == 0:
            h, floor = grid.h, grid.upper[0] - grid.lower[0]
            try:
                output.write_csv(self.folder / "front.csv", ["t", "front_m"], self.front,
                                 comment="surge front: largest particle x plus half a particle spacing")
                output.write_csv(self.folder / "volume.csv",
                                 ["t", "occupied_cells", "occupied_area_m2", "mean_depth_m", "surface_height_m"],
                                 [(t, c, c * h * h, c * h * h / floor, z) for t, c, z in self.cells],
                                 comment="cells holding particles; mean depth = occupied area / floor width; "
                                         "surface height = median over columns of the top particle's top")
                if self.gauges:
                    output.write_csv(self.folder / "gauges.csv", *self._gauge_table(),
                                     comment="gauges (fempm.gauges): pressure at a point, nan where the wet fraction "
                                             "is below 1/2 (dry); level: depth of water along a vertical line; "
                                             "empty: not sampled at that time (the gauge's interval)")
            except OutputError as e:
                error = str(e)
        output.agree(grid.comm, error)

    def _gauge_table(self) -> tuple[list[str], list[list[float]]]:
        """The header (names with units) and rows of ``gauges.csv``."""
        units = [UNITS[g.kind] for g in self.gauges.gauges]
        return ["t_s"] + [f"{name}_{unit}" for name, unit in zip(self.gauges.names, units)], self.gauge_rows

    def plot_gauges(self):
        """Write ``gauges.png`` (rank 0 draws; collective)."""
        error = None
        if self.solver.grid.comm.rank == 0 and self.gauge_rows:
            try:
                output.plot_gauges(self.folder / "gauges.png", *self._gauge_table(),
                                   [UNITS[g.kind] for g in self.gauges.gauges])
            except OutputError as e:
                error = str(e)
        output.agree(self.solver.grid.comm, error)

    def state(self) -> dict:
        """Everything :meth:`restore` needs to continue these histories and series (JSON-able; collective)."""
        _, total, phases = self._times(self.wall_time())
        return {
            "front": self.front, "cells": self.cells, "pressure_min": self.pressure_min,
            "pressure_max": self.pressure_max, "max_divergence": self.max_divergence,
            "particle_series": self.particle_series.entries if self.particle_series else [],
            "grid_series": self.grid_series.entries if self.grid_series else [],
            "wall_time_s": total, "wall_time_by_phase_s": phases, "gauges": self.gauge_rows,
        }

    def restore(self, state: dict):
        """Continue from a :meth:`state` (of a run of the same scene, read from a checkpoint)."""
        self.front = [tuple(e) for e in state["front"]]
        self.cells = [tuple(e) for e in state["cells"]]
        self.pressure_min, self.pressure_max = state["pressure_min"], state["pressure_max"]
        self.max_divergence = state["max_divergence"]
        for series, key in ((self.particle_series, "particle_series"), (self.grid_series, "grid_series")):
            if series:
                series.entries = [(t, f) for t, f in state[key]]
        self.wall_before = float(state.get("wall_time_s", 0.0))  # absent from checkpoints before it was kept
        self.phases_before = dict(state.get("wall_time_by_phase_s", {}))
        self.gauge_rows = [list(row) for row in state.get("gauges", [])]  # rewritten whole: no row twice

    def close(self, status: str, cause: str | None, wall: float) -> dict:
        """Write the histories, the VTX stream, the final picture and summary.json; return the summary.

        ``wall`` is the wall time of this part of the run (the summary adds the earlier parts'
        of a resumed run). A file that cannot be written turns a completed run into a stopped
        one with that cause; the others are still tried.
        """
        s = self.solver
        h, floor = s.grid.h, s.grid.upper[0] - s.grid.lower[0]

        def attempt(write):
            nonlocal status, cause
            try:
                write()
            except OutputError as e:
                if status != "stopped":
                    status, cause = "stopped", str(e)

        attempt(self.write_histories)
        if self.gauges:
            attempt(self.plot_gauges)
        if self.grid_series:
            attempt(self.grid_series.write_vtx)
        if self.options.final_snapshot:
            attempt(lambda: output.snapshot(self.folder / "snapshot_final.png", s.particles,
                                            title=f"t = {s.time:.3f} s ({status})", clim=self.options.pressure_scale))
        part, total, phases = self._times(wall)
        summary = {
            "status": status, "cause": cause, "time": s.time, "steps": s.steps,
            "particles": s.particles.global_count(), "basis": s.basis.name, "ranks": s.grid.comm.size,
            "wall_time_s": total, "wall_time_this_part_s": part, "wall_time_by_phase_s": phases,
            "pressure_min_Pa": self.pressure_min, "pressure_max_Pa": self.pressure_max,
            "max_abs_div_v_per_s": self.max_divergence,
            "occupied_cells_initial": self.cells[0][1], "occupied_cells_final": self.cells[-1][1],
            "mean_depth_final_m": self.cells[-1][1] * h * h / floor,
            "surface_height_final_m": self.cells[-1][2],
            "wall_stops": s.walls.stops,
            "step_retries": [{"time": t, "step": n, "failed_dt": dt, "cause": c} for t, n, dt, c in s.retries],
            **self.options.extra,
        }
        error = None
        if s.grid.comm.rank == 0:
            try:
                output.write_json(self.folder / "summary.json", summary)
            except OutputError as e:
                error = str(e)
        error = s.grid.comm.bcast(error, root=0)
        if error and summary["status"] != "stopped":
            summary.update(status="stopped", cause=error)
        return summary


def run(solver, end_time: float, recorder: Recorder, progress: bool = True, checkpoints=None,
        stop=None) -> dict:
    """Step ``solver`` to ``end_time``, recording; a divergence or a stop request ends the run cleanly.

    Args:
        solver, recorder: as above; a recorder without history first records the
            current (initial) state.
        end_time: simulated time to reach.
        progress: print a progress line (rank 0).
        checkpoints: an object with ``after_step(solver, recorder)`` (called after each
            step) and ``finish(solver, recorder, status)`` (called at the end unless the
            run diverged), e.g. :class:`fempm.restart.Checkpoints`.
        stop: an object whose ``requested(comm)`` returns the name of a stop request
            (e.g. a signal), the same on every rank, or None; checked after each step.

    Returns:
        The summary (see :meth:`Recorder.close`); ``status`` is ``"completed"``,
        ``"interrupted"`` or ``"stopped"`` (diverged), with the ``cause``.
    """
    comm = solver.grid.comm
    bar = Progress(end_time, comm, start_time=solver.time) if progress else None
    status, cause = "completed", None
    wall0 = time.perf_counter()
    recorder.start_clock()
    try:
        if not recorder.front:
            recorder.record()
        while solver.time < end_time - TIME_TOLERANCE * max(end_time, solver.dt):
            start = time.perf_counter()
            due = [end_time, recorder.next_time(solver.time), checkpoints.next_time(solver.time) if checkpoints else np.inf]
            solver.step(until=min(due))
            step_seconds = time.perf_counter() - start  # the step alone: the outputs below are not its cost
            recorder.record()
            if checkpoints:
                checkpoints.after_step(solver, recorder)
            if bar:
                bar.update(solver.time, step_seconds)
            request = stop.requested(comm) if stop else None
            if request:
                status, cause = "interrupted", f"{request} at t = {solver.time:.6g} s (step {solver.steps})"
                break
    except (SimulationDiverged, OutputError) as e:
        status, cause = "stopped", str(e)
    finally:
        if bar:
            bar.close()
    if checkpoints and status != "stopped":
        try:
            checkpoints.finish(solver, recorder, status)
        except OutputError as e:
            status, cause = "stopped", str(e)
    return recorder.close(status, cause, time.perf_counter() - wall0)
