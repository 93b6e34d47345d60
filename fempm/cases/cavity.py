"""The lid-driven cavity at Re = 100 against Ghia, Ghia & Shin (1982): set-up, centre lines, measures.

A unit square cavity full of fluid whose lid (y = L = 1) slides along +x at U = 1; the other
three walls at rest, all four no-slip; rho = 1, nu = 0.01 (Re = U L / nu = 100), no gravity.
From rest the flow spins up to a steady primary vortex. Both methods solve the same forms: the
FEM-only reference (:class:`fempm.eulerian.EulerianSolver`, Oseen convection) and the MPM
(particles filling the cavity carry the convection).

The measure (:func:`run_case`): ``error_u = max_i |u(0.5, y_i) - u_Ghia(y_i)| / U`` over Ghia's
17 points on the vertical centre line and ``error_v`` likewise for v(x, 0.5) on the horizontal
one (Ghia's Tables I and II, ``data/reference/cavity``), of the **mean** profile over the last
:data:`WINDOW` of the run: the MPM's particles, its quadrature points, keep rearranging, so its
instantaneous profile never settles. :func:`write_results` writes a run's tables and figure.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import output, references
from fempm.bases import BASES
from fempm.grid import Grid
from fempm.options import Physics, Scheme
from fempm.progress import Progress
from fempm.verification import Measurement, Run, advance, filled_solver, max_relative_error, sample

__all__ = ["COURANT", "DENSE", "END_TIME", "FEM_DT", "PIC", "WINDOW", "CavityRun", "CentreLines", "Ghia",
           "at_ghia_points", "cavity_solver", "courant_step", "errors", "load_ghia", "occupancy", "plot", "run_case",
           "split_lines", "write_results"]

SIDE = 1.0  # m, the cavity's side L
LID_SPEED = 1.0  # m/s, U
DENSITY = 1.0  # kg/m^3
KINEMATIC_VISCOSITY = 0.01  # m^2/s: Re = U L / nu = 100
END_TIME = 15.0  # s = 15 L/U: the FEM-only run is steady (see demos/cavity.py)
WINDOW = 5.0  # s: the profiles are the mean over the last 5 L/U of the run
HISTORY_INTERVAL = 1.0  # s: history.csv every L/U
COURANT = 0.5  # the MPM's default step: U dt / h = 0.5
FEM_DT = 0.1  # s: the FEM-only step (its steady state does not need the MPM's small one)
DENSE = np.linspace(0.0, SIDE, 101)  # the centre lines drawn in the figure


@dataclass(frozen=True)
class Ghia:
    """Ghia, Ghia & Shin's centre-line velocities at Re = 100: u(0.5, y) and v(x, 0.5), over U."""

    y: np.ndarray
    u: np.ndarray
    x: np.ndarray
    v: np.ndarray


def load_ghia() -> Ghia:
    """The Re = 100 columns of ``data/reference/cavity`` (Tables I and II of the paper)."""
    def table(name):  # a comment line, then the header
        return np.genfromtxt(references.REFERENCE_DIR / "cavity" / name, delimiter=",", skip_header=1, names=True)

    u, v = table("ghia1982_u_vertical_centreline.csv"), table("ghia1982_v_horizontal_centreline.csv")
    return Ghia(y=u["y"], u=u["Re100"] * LID_SPEED, x=v["x"], v=v["Re100"] * LID_SPEED)


def courant_step(cells: int, courant: float = COURANT) -> float:
    """The time step at which the lid moves ``courant`` cells per step."""
    return courant * SIDE / cells / LID_SPEED


# -- the two solvers -----------------------------------------------------------------------------
#: The cavity's walls and fluid: all sides no-slip, the top one sliding at U; no gravity.
PHYSICS = Physics(viscosity=DENSITY * KINEMATIC_VISCOSITY, gravity=(0.0, 0.0), walls="no-slip",
                  wall_speeds={"top": LID_SPEED})


#: the MPM's PIC share per step (FLIP/PIC: see :func:`cavity_solver`)
PIC = 0.1

def cavity_grid(cells: int, comm) -> Grid:
    """The unit cavity cut into ``cells`` x ``cells`` square cells."""
    return Grid.from_cells(comm, (0.0, 0.0), (SIDE, SIDE), (cells, cells))


def cavity_solver(method: str, cells: int, basis: str, dt: float, per_cell: int = 2, comm=MPI.COMM_WORLD,
                  alpha: float = Scheme.alpha, pic: float = PIC):
    """The cavity at rest: the FEM-only reference, or the MPM with ``per_cell`` x ``per_cell``
    particles in every cell (:func:`fempm.verification.filled_solver`).

    The MPM's transfer is FLIP with a PIC share ``pic`` per step, the seed's: a PIC rate of 100/s (the
    default's until its share on the noise) is a share of 1 per step at this case's U dt / h = 0.5 (U = L = 1), i.e. APIC,
    under which the particles opened a hole (0.17 % of the cells empty at 24 cells) and crowded
    a corner."""
    grid = cavity_grid(cells, comm)
    scheme = Scheme(dt=dt, alpha=alpha, transfer="flip", pic_blend=pic, pic_rate=0.0)
    return filled_solver(method, BASES[basis](grid), PHYSICS, scheme, density=DENSITY, per_cell=per_cell)


# -- centre-line velocities: sampled after every step, averaged over the window ------------------
class CentreLines:
    """The step callback of :func:`fempm.verification.advance`: samples u(0.5, y) and v(x, 0.5)
    at Ghia's points and along the whole lines (:data:`DENSE`).

    Attributes:
        mean: the mean sampled velocities over the steps after ``end_time - window``.
        last: those of the last step sampled.
        history: rows ``(t, error_u, error_v, change)`` every :data:`HISTORY_INTERVAL`, ``change``
            the largest change of the sampled velocities since the previous row.
    """

    def __init__(self, ghia: Ghia, end_time: float, window: float, comm, progress: bool):
        self.ghia = ghia
        self.n_u = len(ghia.y) + len(DENSE)
        self.points = np.vstack([
            np.column_stack([np.full(self.n_u, 0.5 * SIDE), np.concatenate([ghia.y, DENSE])]),
            np.column_stack([np.concatenate([ghia.x, DENSE]), np.full(len(ghia.x) + len(DENSE), 0.5 * SIDE)]),
        ])
        self.window_start = end_time - window
        self.sum, self.count = np.zeros(len(self.points)), 0
        self.history, self._previous, self.last = [], None, None
        self.progress = Progress(end_time, comm) if progress else None
        self._clock = time.perf_counter()

    def values(self, velocity) -> np.ndarray:
        """u on the vertical line, then v on the horizontal line (the same on every rank)."""
        both = sample(velocity, self.points)
        return np.concatenate([both[: self.n_u, 0], both[self.n_u:, 1]])

    def __call__(self, solver):
        t, dt = solver.time, solver.dt
        in_window = t > self.window_start + 0.5 * dt
        on_record = abs(t / HISTORY_INTERVAL - round(t / HISTORY_INTERVAL)) * HISTORY_INTERVAL < 0.5 * dt
        if in_window or on_record:
            self.last = self.values(solver.velocity)
        if in_window:
            self.sum += self.last
            self.count += 1
        if on_record:
            change = np.nan if self._previous is None else float(np.abs(self.last - self._previous).max())
            self.history.append((round(t, 9), *errors(self.ghia, self.last), change))
            self._previous = self.last
        if self.progress:
            now = time.perf_counter()
            self.progress.update(t, now - self._clock)
            self._clock = now

    @property
    def mean(self) -> np.ndarray:
        """The mean sampled velocities over the window (NaN before it began)."""
        return self.sum / self.count if self.count else np.full(len(self.points), np.nan)

    def close(self):
        """End the progress line."""
        if self.progress:
            self.progress.close()


def errors(ghia: Ghia, values: np.ndarray) -> tuple[float, float]:
    """``(error_u, error_v)``: max |computed - Ghia| / U at Ghia's points of each centre line."""
    u, v = at_ghia_points(ghia, values)
    return max_relative_error(u, ghia.u, LID_SPEED), max_relative_error(v, ghia.v, LID_SPEED)


def at_ghia_points(ghia: Ghia, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sampled values at Ghia's points only: (u at ``ghia.y``, v at ``ghia.x``)."""
    u, v = split_lines(ghia, values)
    return u[: len(ghia.y)], v[: len(ghia.x)]


def split_lines(ghia: Ghia, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sampled values as (u on the vertical line, v on the horizontal line), Ghia's points first."""
    n_u = len(ghia.y) + len(DENSE)
    return values[:n_u], values[n_u:]


# -- particles: do they stay spread over the cavity? ---------------------------------------------
def occupancy(particles, per_cell: int) -> tuple[dict, np.ndarray]:
    """Particles per cell over the grid (all ranks): a summary and the ``(ny, nx)`` counts.

    The summary: the seeded number per cell, the smallest and largest count, the fraction
    of cells without a particle, and the mean count in each corner's 2 x 2 cells over the
    seeded number (bottom-left, bottom-right, top-left, top-right): 1 is as seeded, above 1
    a pile-up.
    """
    grid = particles.grid
    counts = np.bincount(particles.cell, minlength=grid.num_cells).astype(np.int64)
    grid.comm.Allreduce(MPI.IN_PLACE, counts, op=MPI.SUM)
    counts = counts.reshape(grid.ny, grid.nx)
    seeded = per_cell**2
    corners = [counts[rows, cols].mean() / seeded
               for rows in (slice(0, 2), slice(-2, None)) for cols in (slice(0, 2), slice(-2, None))]
    return {"particles_per_cell_seeded": seeded, "particles_per_cell_min": int(counts.min()),
            "particles_per_cell_max": int(counts.max()), "empty_cell_fraction": float(np.mean(counts == 0)),
            "corner_fill": [round(float(c), 3) for c in corners]}, counts


# -- one run to the steady state -----------------------------------------------------------------
@dataclass
class CavityRun:
    """One run of the cavity: its measurement row, mean profiles, history and particles per cell."""

    measurement: Measurement
    profile: np.ndarray  # mean sampled velocities over the window (see CentreLines)
    history: list = field(default_factory=list)
    counts: np.ndarray | None = None  # MPM: particles per cell at the end, (ny, nx)


def run_case(method: str, basis: str, cells: int, dt: float, per_cell: int = 2, end_time: float = END_TIME,
             window: float = WINDOW, alpha: float = Scheme.alpha, pic: float = PIC,
             comm=MPI.COMM_WORLD, progress: bool = False) -> CavityRun:
    """Run ``method`` (``"MPM"`` or ``"FEM-only"``) from rest to ``end_time`` and measure it.

    ``error`` is the larger of ``error_u`` and ``error_v`` of the mean profile over the last
    ``window``; ``extra`` holds both, those of the last step alone (``error_u_final``, ...),
    the last change per L/U (``unsteadiness``), and for the MPM the particles per cell.
    """
    ghia = load_ghia()
    solver = cavity_solver(method, cells, basis, dt, per_cell, comm, alpha, pic)
    lines = CentreLines(ghia, end_time, window, comm, progress)
    run: Run = advance(solver, end_time, lines)
    lines.close()
    completed = run.status == "completed" and lines.count > 0
    error_u, error_v = errors(ghia, lines.mean) if completed else (None, None)
    extra = {"error_u": error_u, "error_v": error_v, "end_time": end_time, "window": window, "steps": run.steps}
    if completed:
        extra["error_u_final"], extra["error_v_final"] = errors(ghia, lines.last)
        change = lines.history[-1][3] if lines.history else np.nan
        extra["unsteadiness"] = None if np.isnan(change) else change
    counts = None
    if method == "MPM":
        summary, counts = occupancy(solver.particles, per_cell)
        extra.update(summary, alpha=alpha, pic_blend=pic, wall_stops=solver.walls.stops,
                     courant=LID_SPEED * dt * cells / SIDE)
    measurement = Measurement(
        case="cavity", method=method, basis=BASES[basis].name, cells=cells, dt=dt,
        ppc=per_cell**2 if method == "MPM" else 0, error=max(error_u, error_v) if completed else None,
        wall=run.wall, status=run.status, cause=run.cause, extra=extra)
    return CavityRun(measurement, lines.mean, lines.history, counts)


# -- the figure ----------------------------------------------------------------------------------
def plot(path: Path, ghia: Ghia, runs: list[CavityRun]):
    """Mean u(0.5, y) and v(x, 0.5) of each run with Ghia's points; the MPM's particles per cell."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mpm = next((r for r in runs if r.counts is not None), None)
    fig, axes = plt.subplots(1, 3 if mpm else 2, figsize=(15 if mpm else 10, 4.8))
    n_u = len(ghia.y)
    for r, style in zip(runs, ("-", "--")):
        m = r.measurement
        u, v = split_lines(ghia, r.profile)
        label = (f"{m.method}, {m.basis}, {m.cells}$^2$ cells"
                 + (f", {m.ppc} particles/cell" if m.ppc else "")
                 + (f" (errors u {100 * m.extra['error_u']:.1f} %, v {100 * m.extra['error_v']:.1f} %)"
                    if m.error is not None else f" ({m.status})"))
        axes[0].plot(u[n_u:], DENSE, style, label=label)
        axes[1].plot(DENSE, v[len(ghia.x):], style, label=label)
    axes[0].plot(ghia.u, ghia.y, "ko", mfc="none", label="Ghia et al. 1982")
    axes[1].plot(ghia.x, ghia.v, "ko", mfc="none", label="Ghia et al. 1982")
    axes[0].set(xlabel="u(0.5, y) / U", ylabel="y / L", title="vertical centre line")
    axes[1].set(xlabel="x / L", ylabel="v(x, 0.5) / U", title="horizontal centre line")
    for ax in axes[:2]:
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="center right")
    if mpm:
        seeded = mpm.measurement.extra["particles_per_cell_seeded"]
        image = axes[2].imshow(mpm.counts / seeded, origin="lower", extent=(0, SIDE, 0, SIDE), cmap="viridis",
                               vmin=0, vmax=max(2.0, float(mpm.counts.max()) / seeded))
        fig.colorbar(image, ax=axes[2], label="particles per cell / seeded")
        axes[2].set(xlabel="x / L", ylabel="y / L",
                    title=f"MPM particles at t = {mpm.measurement.extra['end_time']:g} L/U")
    fig.suptitle(f"Lid-driven cavity, Re = {LID_SPEED * SIDE / KINEMATIC_VISCOSITY:g}: mean over the last "
                 f"{runs[0].measurement.extra['window']:g} L/U")
    fig.tight_layout()
    output.save_figure(fig, path, dpi=120)


# -- writing the results (rank 0) ----------------------------------------------------------------
def write_results(folder: Path, ghia: Ghia, runs: list[CavityRun]):
    """errors.csv, centrelines.csv, history.csv, summary.json and centrelines.png in ``folder``."""
    rows = [r.measurement for r in runs]
    output.write_csv(folder / "errors.csv", ["method", "basis", "cells", "dt", "particles_per_cell", "error_u",
                                             "error_v", "wall_s", "status"],
                     [[m.method, m.basis, m.cells, m.dt, m.ppc, m.extra["error_u"], m.extra["error_v"],
                       round(m.wall, 3), m.status] for m in rows],
                     comment="error = max |computed - Ghia| / U over Ghia's points, mean profile over the window")
    header = ["line", "coordinate", "ghia"] + [f"{r.measurement.method} {r.measurement.basis}" for r in runs]
    columns = [np.concatenate(at_ghia_points(ghia, r.profile)) for r in runs]
    line = ["u(0.5,y)"] * len(ghia.y) + ["v(x,0.5)"] * len(ghia.x)
    table = zip(line, np.concatenate([ghia.y, ghia.x]), np.concatenate([ghia.u, ghia.v]), *columns)
    output.write_csv(folder / "centrelines.csv", header, [list(row) for row in table],
                     comment="mean centre-line velocities over the window at Ghia's points (coordinate y or x)")
    output.write_csv(folder / "history.csv", ["method", "t", "error_u", "error_v", "change_since_previous"],
                     [[r.measurement.method, *row] for r in runs for row in r.history],
                     comment=f"instantaneous centre-line errors every {HISTORY_INTERVAL:g} L/U; change = max "
                             "change of the sampled velocities since the previous row, over U")
    output.write_json(folder / "summary.json", {"reynolds": LID_SPEED * SIDE / KINEMATIC_VISCOSITY,
                                                "runs": [m.as_dict() for m in rows]})
    plot(folder / "centrelines.png", ghia, runs)
