"""What the verification cases share: timed runs, sampling a grid field, errors, rates.

The cases (``demos/hydrostatic.py``, ``poiseuille.py``, ``couette.py``, ``cavity.py``,
``dambreak.py``) each return :class:`Measurement` rows: one run, its parameters, its
error against the reference and its wall time. ``benchmarks/report.py`` gathers them
into ``docs/verification.md``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from mpi4py import MPI

from fempm.bases import BASES, Basis
from fempm.errors import InputError, SimulationDiverged
from fempm.eulerian import EulerianSolver
from fempm.grid import Grid
from fempm.implicit import ImplicitSolver
from fempm.options import Physics, Scheme
from fempm.particles import Particles, Rectangle
from fempm.stepper import TIME_TOLERANCE

__all__ = ["METHODS", "Measurement", "Run", "advance", "case_arguments", "channel", "filled_solver",
           "max_relative_error", "profile_demo", "profile_errors", "rates", "sample", "section"]

METHODS = ("MPM", "FEM-only")


def filled_solver(method: str, basis: Basis, physics: Physics, scheme: Scheme, density: float = 1.0,
                  per_cell: int = 2, body: Rectangle | None = None):
    """The solver of a closed-domain case: ``"FEM-only"`` (:class:`~fempm.eulerian.EulerianSolver`
    on the whole grid) or ``"MPM"`` (:class:`~fempm.implicit.ImplicitSolver` with
    ``per_cell x per_cell`` particles per cell at rest in ``body``, by default the whole grid)."""
    if method == "FEM-only":
        return EulerianSolver(basis, physics, scheme, density=density)
    if method != "MPM":
        raise InputError(f"method must be one of {METHODS}, got {method!r}")
    grid = basis.grid
    fluid = Particles(grid)
    fluid.seed(body or Rectangle(grid.lower, grid.upper), per_cell=per_cell, density=density)
    return ImplicitSolver(basis, fluid, physics, scheme)


def channel(method: str, basis: str, cells: int, dt: float, per_cell: int = 2, *, height: float = 1.0,
            density: float = 1.0, viscosity: float = 1.0, body_force: float = 0.0, lid_speed: float = 0.0,
            pic_blend: float = 0.01, comm: MPI.Comm = MPI.COMM_WORLD):
    """A plane channel flow along x between no-slip walls at y = 0 and y = ``height``, ``cells`` across.

    The grid is a section of the channel ``height / 2`` long whose ends are ``outflow``
    sides: ``u_y = 0`` and zero normal traction, which a flow that is fully developed
    (``u = u(y) e_x``, p constant along x) satisfies exactly, so the section stands for the
    infinite channel. MPM particles that leave through one end re-enter through the other
    (``recycle``): the material is endless too. ``body_force`` drives plane Poiseuille flow,
    ``lid_speed`` (the top wall sliding along +x) plane Couette flow; the fluid starts at rest.
    The volume correction is off (``alpha = 0``): particles in a shear flow along x keep
    their rows and neither crowd nor thin out. The PIC share of the MPM update is 0.01,
    not the dam break's 0.1: blended every step, PIC smooths the velocity like an added
    viscosity of order ``pic_blend h^2 / dt`` (``benchmarks/report.py`` measures it).
    """
    grid = Grid.from_cells(comm, (0.0, 0.0), (height / 2, height), (max(cells // 2, 2), cells))
    walls = {"left": "outflow", "right": "outflow", "bottom": "no-slip", "top": "no-slip"}
    physics = Physics(viscosity=density * viscosity, gravity=(body_force, 0.0), walls=walls,
                      wall_speeds={"top": lid_speed} if lid_speed else {}, recycle=method == "MPM")
    scheme = Scheme(dt=dt, alpha=0.0, pic_blend=pic_blend)
    return filled_solver(method, BASES[basis](grid), physics, scheme, density=density, per_cell=per_cell)


def section(solver, y: np.ndarray) -> np.ndarray:
    """The velocity ``(n, 2)`` along the vertical line through the middle of the grid, at heights ``y``."""
    grid = solver.grid
    x = np.full_like(y, 0.5 * (grid.lower[0] + grid.upper[0]))
    return sample(solver.velocity, np.column_stack([x, y]))


@dataclass
class Run:
    """How a stepped run ended: ``completed`` or ``stopped`` (with the diagnosis), when, at what cost."""

    status: str = "completed"
    cause: str = ""
    time: float = 0.0
    steps: int = 0
    wall: float = 0.0


def advance(solver, end_time: float, each_step=None, run: Run | None = None) -> Run:
    """Step ``solver`` to ``end_time``, calling ``each_step(solver)`` after every step.

    A divergence ends the run cleanly (``status = "stopped"``, ``cause`` its diagnosis).
    The wall time is that of the steps alone (set-up and ``each_step`` excluded); a ``run``
    given carries on accumulating.
    """
    run = run or Run()
    try:
        while solver.time < end_time - TIME_TOLERANCE * max(end_time, solver.dt):
            start = time.perf_counter()
            solver.step(until=end_time)
            run.wall += time.perf_counter() - start
            if each_step:
                each_step(solver)
    except SimulationDiverged as e:
        run.status, run.cause = "stopped", e.cause
    run.time, run.steps = solver.time, solver.steps
    return run


def sample(gf, points: np.ndarray) -> np.ndarray:
    """Values of a grid function at ``points`` ``(n, 2)``, the same on every rank.

    Each rank evaluates the points in the cells it owns; the values are summed over the
    ranks (a point on a cell edge is taken in one cell only, by :meth:`fempm.Grid.locate`).
    """
    grid = gf.space.grid
    cells, xi = grid.locate(np.asarray(points, dtype=float))
    mine = grid.owner[cells] == grid.comm.rank
    out = np.zeros((len(cells), gf.space.bs))
    if np.any(mine):
        out[mine] = gf.evaluate(cells[mine], xi[mine])[:, 0, :]
    return grid.comm.allreduce(out)


def max_relative_error(computed: np.ndarray, exact: np.ndarray, scale: float) -> float:
    """``max |computed - exact| / scale`` (the max norm relative to a reference magnitude)."""
    return float(np.max(np.abs(np.asarray(computed) - np.asarray(exact))) / scale)


def rates(sizes, errors) -> list[float]:
    """Observed orders ``log(e_{k-1}/e_k) / log(h_{k-1}/h_k)`` between successive levels (NaN
    where an error is missing or zero)."""
    out = []
    for (h0, e0), (h1, e1) in zip(zip(sizes, errors), list(zip(sizes, errors))[1:]):
        ok = e0 and e1 and e0 > 0 and e1 > 0 and h0 != h1
        out.append(float(np.log(e0 / e1) / np.log(h0 / h1)) if ok else float("nan"))
    return out


@dataclass
class Measurement:
    """One run of a verification case: what it was, its error against the reference, its cost.

    Attributes:
        case: the case (``hydrostatic``, ``poiseuille``, ...).
        method: ``MPM`` or ``FEM-only``.
        basis: ``B-spline`` or ``Q1``.
        cells: cells across the case's length scale (H/h).
        dt: time step, s.
        ppc: particles per cell (0 for FEM-only).
        error: the case's error measure (None if the run stopped before it could be taken).
        wall: wall time of the steps, s.
        status, cause: how the run ended.
        extra: further measures of the case (named, JSON-able).
    """

    case: str
    method: str
    basis: str
    cells: int
    dt: float
    ppc: int
    error: float | None
    wall: float
    status: str = "completed"
    cause: str = ""
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        """The row as a plain dictionary (for JSON)."""
        return asdict(self)


def profile_errors(case: str, solver, times, y: np.ndarray, exact, scale: float, basis: str, cells: int,
                   per_cell: int) -> list[Measurement]:
    """Advance ``solver`` to each of ``times`` and measure there the max error of the velocity's x
    component along the vertical centre line, ``max |u - exact(y, t)| / scale``: one row per time
    (its wall time counts from the start, its profile in ``extra["profile"]``)."""
    method = "FEM-only" if isinstance(solver, EulerianSolver) else "MPM"
    rows, run = [], None
    for t in times:
        run = advance(solver, t, run=run)
        u = section(solver, y)[:, 0]
        error = max_relative_error(u, exact(y, t), scale) if run.status == "completed" else None
        rows.append(Measurement(f"{case} t={t:g}", method, BASES[basis].name, cells, solver.dt,
                                per_cell**2 if method == "MPM" else 0, error, run.wall, run.status, run.cause,
                                {"profile": u.tolist(), "pic_blend": solver.scheme.pic_blend}))
    return rows


def case_arguments(argv, description: str, cells: int, dt: float, dt_unit: str, out: str):
    """The command line every verification demo shares (``--cells --ppc --dt --basis --out``),
    checked, with its output folder created (all ranks agree); returns the arguments and the folder."""
    import argparse

    from fempm import output
    from fempm.errors import FempmError

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--cells", type=int, default=cells, help=f"cells across the case's height (default {cells})")
    parser.add_argument("--ppc", type=int, default=2, help="MPM particles per cell and direction (default 2)")
    parser.add_argument("--dt", type=float, default=dt, help=f"time step, {dt_unit} (default {dt:g})")
    parser.add_argument("--basis", choices=tuple(BASES), default="bspline")
    parser.add_argument("--out", default=out, help=f"output folder (default {out})")
    args = parser.parse_args(argv)
    if args.cells < 4 or args.ppc < 1 or not args.dt > 0:
        parser.error("--cells must be >= 4, --ppc >= 1 and --dt > 0")
    try:
        folder = output.prepare_folder(args.out, MPI.COMM_WORLD)
    except FempmError as e:
        parser.error(str(e))
    return args, folder


def profile_demo(argv, description: str, solve, exact, y: np.ndarray, times, out: str, quantity: str) -> int:
    """The command line of a profile case (``demos/poiseuille.py``, ``couette.py``): run both methods
    on one grid with ``solve(method, basis, cells, dt, ppc)`` (rows with ``extra["profile"]``
    at ``y``, one per time of ``times``), print the errors, write ``errors.json`` and
    ``profile.png`` (the profiles on ``exact(y, t)``) in ``out``."""
    from fempm import output

    args, folder = case_arguments(argv, description, cells=16, dt=0.001, dt_unit="H^2/nu", out=out)
    runs = {m: solve(m, args.basis, args.cells, args.dt, args.ppc) for m in METHODS}
    if MPI.COMM_WORLD.rank == 0:
        for r in (r for rows in runs.values() for r in rows):
            error = "-" if r.error is None else f"{r.error:.2e}"
            print(f"{r.method:8s} {r.case:18s} error {error}  ({r.wall:.1f} s) {r.cause}")
        output.write_json(folder / "errors.json", {m: [r.as_dict() for r in rows] for m, rows in runs.items()})
        _plot_profiles(folder / "profile.png", runs, exact, y, times, description, quantity)
    return 0 if all(r.status == "completed" for rows in runs.values() for r in rows) else 1


def _plot_profiles(path, runs, exact, y, times, title: str, quantity: str):
    """Velocity profiles of each method at each time, on the analytic ones (lines)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fempm import output

    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    for t in times:
        ax.plot(exact(y, t), y, "k-", lw=1)
    for (method, rows), (marker, size) in zip(runs.items(), (("o", 6), ("x", 4))):
        for r in rows:
            ax.plot(r.extra["profile"], y, marker, ms=size, mfc="none", label=f"{method}, {r.case}")
    ax.set(xlabel=quantity, ylabel="y / H", title=f"{title}\n(lines: analytic)")
    ax.legend(fontsize=7)
    with output.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format="png")
    plt.close(fig)
