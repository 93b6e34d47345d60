"""Lid-driven cavity at Re = 100: the implicit MPM and the FEM-only reference against Ghia et al. (1982).

The case (Ghia, Ghia & Shin 1982, J. Comput. Phys. 48, 387-411): a unit square cavity
full of fluid whose lid (y = L = 1) slides along +x at U = 1; the other three walls are at
rest, all four no-slip. rho = 1, mu = 0.01 (nu = 0.01), so Re = U L / nu = 100; no
gravity. From rest the flow spins up to a steady primary vortex.

Strong form (Eulerian)::

    rho (dv/dt + (v . grad) v) = div(2 mu eps(v)) - grad p,   div v = 0   in (0, 1)^2,
    v = (U, 0) on the lid y = 1,   v = 0 on the other walls.

Both methods solve the same weak forms, ``forms/incompressible.py`` (Newmark, PSPG):

* **FEM-only** (:class:`fempm.eulerian.EulerianSolver`): Gauss quadrature on the fixed
  grid, convection by Oseen's rule ``rho (v_n . grad) v_{n+1}``;
* **MPM** (:class:`fempm.implicit.ImplicitSolver`): ``--ppc`` x ``--ppc`` particles per cell
  fill the cavity and circulate with the flow; they carry the convection.

At the two top corners the lid's speed jumps from U to 0. fempm holds the basis
functions a moving wall shares with a side at rest at rest, so the lid speed rises from
0 to U across the corner cell: a regularisation that shrinks with the cell size.

The numbers below come from this script: ``python demos/cavity.py`` (32 cells, B-spline,
2 x 2 particles per cell, U dt / h = 0.5 for the MPM) writes them to ``results/cavity/``;
the flags named reproduce the variants; :func:`study` runs the convergence study.

**Steady state.** ``history.csv`` holds, every L/U, each method's centre-line errors and
the largest change of its centre-line velocities since the previous row. In the default
run the FEM-only change falls from 9.6e-4 U per L/U at t = 10 L/U to 6.8e-5 U at t = 15
L/U, where the run ends (``--end-time 15``). The MPM's centre lines never settle to that
degree: its particles, which are its quadrature points, keep rearranging, and its
instantaneous profile changes by 3 to 4.5 % of U per L/U from t = 9 L/U on, its errors
against Ghia between 1.2 and 3.5 %. Both methods are therefore measured on the **mean
profile over the last** ``--window`` **= 5 L/U** (t = 10 to 15 L/U), which moves the
FEM-only errors by 0.03 % of U from those of its last step (``error_u_final``,
``error_v_final`` in ``summary.json``).

**The measure.** ``error_u = max_i |u(0.5, y_i) - u_Ghia(y_i)| / U`` over Ghia's 17
points on the vertical centre line, and ``error_v`` likewise for v(x, 0.5) on the
horizontal one (Ghia's Tables I and II, ``data/reference/cavity``). Ghia's table is itself
a 129 x 129 finite-difference solution. From 16 to 64 cells the FEM-only B-spline errors
against it stay at 0.47 to 0.53 % (u) and 0.80 to 0.90 % (v), while the runs agree among
themselves ever more closely (the 32-cell profile lies within 0.04 % of U of the 64-cell
one, the 48-cell one within 0.01 %): that floor is the distance between the converged
solution and the table, not the discretisation error of these grids (Q1, converging from
the other side, crosses it: 0.13 % in v at 48 cells). :func:`study` therefore also gives
each run's difference from the finest FEM-only B-spline run
(``difference_from_finest_fem``), whose rates show the discretisation.

**Convergence** (``--method mpm --cells N``, 2 x 2 particles per cell, U dt / h = 0.5;
difference from the 64-cell FEM-only B-spline profile): the B-spline MPM is 5.9, 2.9,
1.6, 1.4 and 1.2 % of U away at 16, 24, 32, 48 and 64 cells, Q1 16.5, 7.2, 3.2, 2.0 and
2.0 %: about second order up to 32 cells (observed orders 1.7 to 2.8), then slowly (0.3
and 0.6 for the B-spline, 1.1 and 0 for Q1). Against Ghia, B-spline: 5.6 / 5.8 %
(u / v) at 16 cells, 1.4 / 0.6 % at 32, 1.3 / 0.5 % at 64. At 32 cells a smaller step does
not help (U dt / h = 1, 0.5, 0.25: 1.7 / 2.0, 1.4 / 0.6, 2.6 / 2.2 %; ``--dt``): with the
PIC share fixed per step, more steps smooth more. Nor do more particles than 2 x 2 per
cell (``--ppc 1, 2, 3, 4``: 4.9 / 4.5, 1.4 / 0.6, 1.6 / 0.6, 1.9 / 1.1 %); 1 per cell leaves
21 % of the cells empty.

**MPM settings** (measured with ``--method mpm`` and the flag named, 32 cells; errors
u / v of the mean profile). ``alpha``, the volume correction of method.md eq. (3), stays
at its default 0.1 (1.4 % / 0.6 %): the particles move with the interpolated grid
velocity, which is not exactly divergence-free where they are; without the correction
(``--alpha 0``) they crowd into clumps of up to 19 particles per cell (4 seeded), 5.7 %
of the cells empty, and the errors are 27 % / 14 %. More correction (``--alpha 0.3``,
1.7 % / 1.2 %) makes the profile noisier (its last step alone: 5.8 % / 3.6 %, against
1.7 % / 1.5 % with 0.1), and ``--alpha 0.5`` diverged at t = 7.2 L/U with 8.6 times the
seeded particles in the top-right corner. ``pic_blend`` stays at its default 0.1: PIC
damps the FLIP noise but every transfer also smooths the velocity, a numerical
viscosity that scales as h^2/dt (as 2 U h at U dt / h = 0.5). Less PIC
(``--pic 0``: 1.2 % / 2.2 %, its last step 3.3 % / 9.5 %) is noisier, more is smoother but
too viscous (``--pic 0.5``: 4.3 % / 3.8 %; ``--pic 1``: 5.2 % / 5.1 %). With the defaults
the particles stay spread over the whole cavity: 0 to 9 per cell (4 seeded), 0.1 % of
the cells empty, each corner's 2 x 2 cells holding 0.81 to 0.94 times the seeded
number (``summary.json``; the figure maps them).

Run (``mpirun -n 2`` works the same; only rank 0 writes)::

    python demos/cavity.py [--cells 32] [--basis bspline|q1] [--ppc 2] [--dt DT] [--end-time 15] ...

Outputs in ``--out`` (default ``results/cavity``): ``centrelines.png`` (both profiles with
Ghia's points, and the MPM's particles per cell), ``errors.csv`` (error and wall time of
each method), ``centrelines.csv`` (the mean profiles at Ghia's points), ``history.csv``,
``summary.json``.
"""

# %% imports
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import output
from fempm.errors import FempmError
from fempm.bases import BASES
from fempm.options import Physics, Scheme
from fempm.progress import Progress
from fempm.verification import Measurement, Run, advance, filled_solver, max_relative_error, rates, sample

# %% the case
SIDE = 1.0  # m, the cavity's side L
LID_SPEED = 1.0  # m/s, U
DENSITY = 1.0  # kg/m^3
KINEMATIC_VISCOSITY = 0.01  # m^2/s: Re = U L / nu = 100
END_TIME = 15.0  # s = 15 L/U: steady to 1e-4 U per L/U (see the module's docstring)
WINDOW = 5.0  # s: the profiles are the mean over the last 5 L/U of the run
HISTORY_INTERVAL = 1.0  # s: history.csv every L/U
COURANT = 0.5  # the MPM's default step: U dt / h = 0.5
FEM_DT = 0.1  # s: the FEM-only step (its steady state does not need the MPM's small one)
REFERENCE = Path(__file__).resolve().parents[1] / "data" / "reference" / "cavity"
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
        return np.genfromtxt(REFERENCE / name, delimiter=",", skip_header=1, names=True)

    u, v = table("ghia1982_u_vertical_centreline.csv"), table("ghia1982_v_horizontal_centreline.csv")
    return Ghia(y=u["y"], u=u["Re100"] * LID_SPEED, x=v["x"], v=v["Re100"] * LID_SPEED)


def courant_step(cells: int, courant: float = COURANT) -> float:
    """The time step at which the lid moves ``courant`` cells per step."""
    return courant * SIDE / cells / LID_SPEED


# %% the two solvers
#: The cavity's walls and fluid: all sides no-slip, the top one sliding at U; no gravity.
PHYSICS = Physics(viscosity=DENSITY * KINEMATIC_VISCOSITY, gravity=(0.0, 0.0), walls="no-slip",
                  wall_speeds={"top": LID_SPEED})


def cavity_grid(cells: int, comm) -> fempm.Grid:
    """The unit cavity cut into ``cells`` x ``cells`` square cells."""
    return fempm.Grid.from_cells(comm, (0.0, 0.0), (SIDE, SIDE), (cells, cells))


def cavity_solver(method: str, cells: int, basis: str, dt: float, per_cell: int = 2, comm=MPI.COMM_WORLD,
                  alpha: float = Scheme.alpha, pic: float = Scheme.pic_blend):
    """The cavity at rest: the FEM-only reference, or the MPM with ``per_cell`` x ``per_cell``
    particles in every cell (:func:`fempm.verification.filled_solver`)."""
    grid = cavity_grid(cells, comm)
    return filled_solver(method, BASES[basis](grid), PHYSICS, Scheme(dt=dt, alpha=alpha, pic_blend=pic), density=DENSITY,
                         per_cell=per_cell)


# %% centre-line velocities: sampled after every step, averaged over the window
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


# %% particles: do they stay spread over the cavity?
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


# %% one run to the steady state
@dataclass
class CavityRun:
    """One run of the cavity: its measurement row, mean profiles, history and particles per cell."""

    measurement: Measurement
    profile: np.ndarray  # mean sampled velocities over the window (see CentreLines)
    history: list = field(default_factory=list)
    counts: np.ndarray | None = None  # MPM: particles per cell at the end, (ny, nx)


def run_case(method: str, basis: str, cells: int, dt: float, per_cell: int = 2, end_time: float = END_TIME,
             window: float = WINDOW, alpha: float = Scheme.alpha, pic: float = Scheme.pic_blend,
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
        extra.update(summary, alpha=alpha, pic_blend=pic, wall_stops=solver.walls.stops, courant=LID_SPEED * dt * cells / SIDE)
    measurement = Measurement(
        case="cavity", method=method, basis=BASES[basis].name, cells=cells, dt=dt,
        ppc=per_cell**2 if method == "MPM" else 0, error=max(error_u, error_v) if completed else None,
        wall=run.wall, status=run.status, cause=run.cause, extra=extra)
    return CavityRun(measurement, lines.mean, lines.history, counts)


# %% the figure
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
        axes[2].set(xlabel="x / L", ylabel="y / L", title=f"MPM particles at t = {mpm.measurement.extra['end_time']:g} L/U")
    fig.suptitle(f"Lid-driven cavity, Re = {LID_SPEED * SIDE / KINEMATIC_VISCOSITY:g}: mean over the last "
                 f"{runs[0].measurement.extra['window']:g} L/U")
    fig.tight_layout()
    with output.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120)
    plt.close(fig)


# %% writing the results (rank 0)
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


# %% the convergence study (called by the verification report)
def study(full: bool = False, comm=MPI.COMM_WORLD, progress: bool = False) -> list[Measurement]:
    """Convergence of both methods against Ghia, each run's wall time beside its error.

    Every run starts from rest and ends at :data:`END_TIME`; its error is that of the mean
    profile over the last :data:`WINDOW` (see :func:`run_case`). The runs:

    * grid: FEM-only (dt :data:`FEM_DT`) and MPM (2 x 2 particles per cell, Courant
      number :data:`COURANT`), B-spline and Q1, at 16, 24 and 32 cells (``full``: also 48, 64);
    * particles per cell: MPM, B-spline, 1, 4, 9 and 16 per cell, on the sweep grid
      (16 cells; ``full``: 32);
    * time step: MPM, B-spline, Courant numbers 1, 0.5 and 0.25, on the sweep grid.

    The run shared by the series (2 x 2 particles, Courant 0.5, sweep grid) is run once;
    ``extra["series"]`` names the series a row belongs to. ``extra`` also gives
    ``difference_from_finest_fem`` (max over Ghia's points of |profile - that of the finest
    FEM-only B-spline run| / U: Ghia's table has errors of its own, see the module's
    docstring) and, along the grid series of each method and basis, the observed orders
    from the previous grid, ``rate_vs_ghia`` and ``rate_vs_finest_fem``
    (:func:`fempm.verification.rates`).

    Cost on one core of the shared 2-core machine: the short version 2.7 min of CPU
    (17 runs); the full one's runs, each measured alone with this demo, step for 24 min
    together, 11 min of it the two MPM runs at 64 cells.
    """
    grids = (16, 24, 32, 48, 64) if full else (16, 24, 32)
    sweep = 32 if full else 16
    runs: dict[tuple, CavityRun] = {}

    def once(series, method, basis, cells, dt, per_cell=2):
        key = (method, basis, cells, dt, per_cell)
        if key not in runs:
            runs[key] = run_case(method, basis, cells, dt, per_cell, comm=comm, progress=progress)
        runs[key].measurement.extra.setdefault("series", []).append(series)
        return runs[key]

    for cells in grids:
        for basis in BASES:
            once("grid", "FEM-only", basis, cells, FEM_DT)
            once("grid", "MPM", basis, cells, courant_step(cells))
    for per_cell in (1, 2, 3, 4):
        once("particles per cell", "MPM", "bspline", sweep, courant_step(sweep), per_cell)
    for courant in (1.0, 0.5, 0.25):
        once("time step", "MPM", "bspline", sweep, courant_step(sweep, courant))

    ghia = load_ghia()
    finest = np.concatenate(at_ghia_points(ghia, runs[("FEM-only", "bspline", grids[-1], FEM_DT, 2)].profile))
    for r in runs.values():
        r.measurement.extra["difference_from_finest_fem"] = None if r.measurement.error is None else (
            max_relative_error(np.concatenate(at_ghia_points(ghia, r.profile)), finest, LID_SPEED))
    measures = {"rate_vs_ghia": lambda m: m.error,
                "rate_vs_finest_fem": lambda m: m.extra["difference_from_finest_fem"]}
    for method in ("FEM-only", "MPM"):
        for basis in BASES:
            series = [r.measurement for key, r in runs.items()
                      if key[:2] == (method, basis) and "grid" in r.measurement.extra["series"]]
            for name, measure in measures.items():
                observed = rates([SIDE / m.cells for m in series], [measure(m) for m in series])
                for m, rate in zip(series[1:], observed):
                    m.extra[name] = None if np.isnan(rate) else rate
    return [r.measurement for r in runs.values()]


# %% command line
def parse_arguments(argv=None) -> argparse.Namespace:
    """The demo's flags, checked."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cells", type=int, default=32, help="cells per side (default 32)")
    parser.add_argument("--basis", choices=tuple(BASES), default="bspline", help="grid basis (default bspline)")
    parser.add_argument("--ppc", type=int, default=2, help="MPM particles per cell and direction (default 2)")
    parser.add_argument("--dt", type=float, default=None,
                        help=f"MPM time step (default {COURANT} h/U: the lid crosses {COURANT} cells per step)")
    parser.add_argument("--fem-dt", type=float, default=FEM_DT, help=f"FEM-only time step (default {FEM_DT})")
    parser.add_argument("--end-time", type=float, default=END_TIME, help=f"simulated time (default {END_TIME:g} L/U)")
    parser.add_argument("--window", type=float, default=WINDOW,
                        help=f"the profiles are averaged over the run's last WINDOW (default {WINDOW:g} L/U)")
    parser.add_argument("--method", choices=("both", "mpm", "fem"), default="both", help="which methods run")
    parser.add_argument("--alpha", type=float, default=Scheme.alpha, help="MPM volume correction, 0..1")
    parser.add_argument("--pic", type=float, default=Scheme.pic_blend, help="MPM PIC share, 0..1")
    parser.add_argument("--out", type=Path, default=Path("results/cavity"), help="output folder")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    args = parser.parse_args(argv)
    if args.cells < 4:
        parser.error(f"--cells must be at least 4, got {args.cells}")
    if args.ppc < 1:
        parser.error(f"--ppc must be at least 1, got {args.ppc}")
    for name in ("dt", "fem_dt", "end_time", "window"):
        value = getattr(args, name)
        if value is not None and not (np.isfinite(value) and value > 0):
            parser.error(f"--{name.replace('_', '-')} must be positive, got {value}")
    if args.window > args.end_time:
        parser.error(f"--window ({args.window:g}) must not exceed --end-time ({args.end_time:g})")
    for name in ("alpha", "pic"):
        if not 0 <= getattr(args, name) <= 1:
            parser.error(f"--{name} must be in [0, 1], got {getattr(args, name)}")
    if args.dt is None:
        args.dt = courant_step(args.cells)
    return args


def run(args, comm=MPI.COMM_WORLD) -> list[CavityRun]:
    """Run the methods of ``args`` and write their results (rank 0); returns the runs."""
    folder = output.prepare_folder(args.out, comm)
    common = dict(end_time=args.end_time, window=args.window, comm=comm, progress=not args.quiet)
    runs = []
    if args.method in ("both", "fem"):
        runs.append(run_case("FEM-only", args.basis, args.cells, args.fem_dt, **common))
    if args.method in ("both", "mpm"):
        runs.append(run_case("MPM", args.basis, args.cells, args.dt, args.ppc, alpha=args.alpha, pic=args.pic,
                             **common))
    if comm.rank == 0:
        write_results(folder, load_ghia(), runs)
    return runs


def main(argv=None) -> int:
    """Run from the command line; exit status 0 if every run completed, 1 if one stopped, 2 on bad input."""
    args = parse_arguments(argv)
    comm = MPI.COMM_WORLD
    try:
        runs = run(args, comm)
    except FempmError as e:
        if comm.rank == 0:
            print(f"cavity: {e}", file=sys.stderr)
        return 2
    if comm.rank == 0:
        for r in runs:
            m = r.measurement
            if m.status == "completed":
                print(f"cavity: {m.method} {m.basis} {m.cells}^2: error vs Ghia u {100 * m.extra['error_u']:.2f} %, "
                      f"v {100 * m.extra['error_v']:.2f} % ({m.extra['steps']} steps, {m.wall:.1f} s)")
            else:
                print(f"cavity: {m.method} {m.basis}: {m.cause}", file=sys.stderr)
        print(f"cavity: results in {args.out}")
    return 0 if all(r.measurement.status == "completed" for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
