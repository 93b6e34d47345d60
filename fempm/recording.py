"""The time loop of a run and what it records: histories, ParaView series, pictures, summary.

Works with any solver that has ``step()``, ``time``, ``steps``, ``particles``, ``grid``,
``timings`` (wall time by phase), ``velocity`` and ``pressure`` (grid functions),
``vector_space``, ``scalar_space`` and ``max_divergence``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fempm import diagnostics, output
from fempm.implicit import SimulationDiverged
from fempm.progress import Progress

__all__ = ["Recorder", "RecorderOptions", "run"]


@dataclass
class RecorderOptions:
    """What a run writes.

    Attributes:
        folder: output folder.
        output_interval: seconds of simulated time between ParaView outputs.
        snapshot_times: times of PNG pictures (a picture of the final state is added).
        files: write ParaView series and pictures (False: only tables and summary).
        pressure_scale: colour range of the pictures, Pa.
    """

    folder: Path = Path("results")
    output_interval: float = 0.05
    snapshot_times: tuple[float, ...] = ()
    files: bool = True
    pressure_scale: tuple[float, float] | None = None
    extra: dict = field(default_factory=dict)


class Recorder:
    """Histories of a run (front, occupied cells, pressure range, divergence) and its files."""

    def __init__(self, solver, options: RecorderOptions):
        self.solver, self.options = solver, options
        comm = solver.grid.comm
        self.folder = output.prepare_folder(options.folder, comm)
        particles = solver.particles
        self.initial_cells = diagnostics.occupied_cells(particles)
        self.front = [(solver.time, diagnostics.front_position(particles))]
        self.cells = [(solver.time, self.initial_cells, diagnostics.surface_height(particles))]
        self.pressure_min, self.pressure_max, self.max_divergence = np.inf, -np.inf, 0.0
        self.particle_series = output.ParticleSeries(self.folder) if options.files else None
        self.grid_series = (output.GridSeries(self.folder, solver.vector_space, solver.scalar_space)
                            if options.files else None)
        self._next_output = solver.time
        self._pending_snapshots = sorted(t for t in options.snapshot_times if t >= solver.time)

    def record(self):
        """Take the measures of the current state; write files when they are due."""
        s, particles = self.solver, self.solver.particles
        t = s.time
        self.front.append((t, diagnostics.front_position(particles)))
        self.cells.append((t, diagnostics.occupied_cells(particles), diagnostics.surface_height(particles)))
        low, high = diagnostics.pressure_range(particles)
        self.pressure_min, self.pressure_max = min(self.pressure_min, low), max(self.pressure_max, high)
        self.max_divergence = max(self.max_divergence, s.max_divergence)
        if not self.options.files:
            return
        half_step = 0.5 * getattr(s.options, "dt", 0.0)
        if t >= self._next_output - half_step:
            self.particle_series.write(particles, t)
            self.grid_series.write(s.velocity, s.pressure, t)
            self._next_output += self.options.output_interval
        while self._pending_snapshots and t >= self._pending_snapshots[0] - half_step:
            ts = self._pending_snapshots.pop(0)
            output.snapshot(self.folder / f"snapshot_t{ts:.3f}.png", particles, title=f"t = {ts:.3f} s",
                            clim=self.options.pressure_scale)

    def close(self, status: str, cause: str | None, wall: float) -> dict:
        """Write volume.csv, the final picture and summary.json; return the summary."""
        s = self.solver
        comm, h = s.grid.comm, s.grid.h
        floor = s.grid.upper[0] - s.grid.lower[0]
        if self.grid_series:
            self.grid_series.close()
        summary = {
            "status": status, "cause": cause, "time": s.time, "steps": s.steps,
            "particles": s.particles.global_count(), "basis": s.basis.name,
            "wall_time_s": wall, "wall_time_by_phase_s": dict(s.timings),
            "pressure_min_Pa": self.pressure_min, "pressure_max_Pa": self.pressure_max,
            "max_abs_div_v_per_s": self.max_divergence,
            "occupied_cells_initial": self.initial_cells, "occupied_cells_final": self.cells[-1][1],
            "mean_depth_final_m": self.cells[-1][1] * h * h / floor,
            "surface_height_final_m": self.cells[-1][2],
            "wall_stops": getattr(s, "wall_stops", 0),
            **self.options.extra,
        }
        if comm.rank == 0:
            output.write_csv(self.folder / "volume.csv",
                             ["t", "occupied_cells", "occupied_area_m2", "mean_depth_m", "surface_height_m"],
                             [(t, c, c * h * h, c * h * h / floor, z) for t, c, z in self.cells],
                             comment="cells holding particles; mean depth = occupied area / floor width; "
                                     "surface height = median over columns of the top particle's top")
        if self.options.files:
            output.snapshot(self.folder / "snapshot_final.png", s.particles,
                            title=f"t = {s.time:.3f} s ({status})", clim=self.options.pressure_scale)
        return summary


def run(solver, end_time: float, recorder: Recorder, progress: bool = True) -> dict:
    """Step ``solver`` to ``end_time``, recording; a divergence stops the run cleanly.

    Returns:
        The summary (see :meth:`Recorder.close`); ``status`` is ``"completed"`` or
        ``"stopped"`` with the ``cause`` naming the time and the reason.
    """
    comm = solver.grid.comm
    bar = Progress(end_time, comm, start_time=solver.time) if progress else None
    n_steps = int(round((end_time - solver.time) / solver.options.dt))
    status, cause = "completed", None
    wall0 = time.perf_counter()
    try:
        for _ in range(n_steps):
            start = time.perf_counter()
            solver.step()
            recorder.record()
            if bar:
                bar.update(solver.time, time.perf_counter() - start)
    except SimulationDiverged as e:
        status, cause = "stopped", str(e)
    finally:
        if bar:
            bar.close()
    return recorder.close(status, cause, time.perf_counter() - wall0)
