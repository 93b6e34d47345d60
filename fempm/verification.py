"""What the verification cases share: timed runs, sampling a grid field, errors, rates.

The cases (:mod:`fempm.cases`) each return :class:`Measurement` rows: one run, its
parameters, its error against the reference and its wall time. ``benchmarks/report.py``
gathers them into ``docs/verification.md``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
from mpi4py import MPI

from fempm.bases import BASES, Basis
from fempm.errors import InputError, SimulationDiverged
from fempm.eulerian import EulerianSolver
from fempm.implicit import ImplicitSolver
from fempm.options import Physics, Scheme
from fempm.particles import Particles, Rectangle
from fempm.stepper import TIME_TOLERANCE

__all__ = ["METHODS", "Measurement", "Run", "advance", "case_arguments", "filled_solver", "max_relative_error",
           "over_bounds", "rates", "sample"]

METHODS = ("MPM", "FEM-only")


def filled_solver(method: str, basis: Basis, physics: Physics, scheme: Scheme, density: float = 1.0,
                  per_cell: int = 2, body: Rectangle | None = None, solver_type=ImplicitSolver):
    """The solver of a closed-domain case: ``"FEM-only"`` (:class:`~fempm.eulerian.EulerianSolver`
    on the whole grid) or ``"MPM"`` (``solver_type``, by default :class:`~fempm.implicit.ImplicitSolver`,
    from the basis, particles, physics and scheme, with ``per_cell x per_cell`` particles per cell at
    rest in ``body``, by default the whole grid)."""
    if method == "FEM-only":
        return EulerianSolver(basis, physics, scheme, density=density)
    if method != "MPM":
        raise InputError(f"method must be one of {METHODS}, got {method!r}")
    grid = basis.grid
    fluid = Particles(grid)
    fluid.seed(body or Rectangle(grid.lower, grid.upper), per_cell=per_cell, density=density)
    return solver_type(basis, fluid, physics, scheme)


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


def over_bounds(rows: list[Measurement], bounds: dict[str, float]) -> list[str]:
    """A demo's check: each row whose run stopped, or whose error is above ``bounds[row.method]``, as a line."""
    return [f"{r.method} {r.case}: {r.cause or f'error {r.error:.3g} above {bounds[r.method]:g}'}" for r in rows
            if r.error is None or r.error > bounds[r.method]]


def case_arguments(description: str, cells: int, dt: float, dt_unit: str, out: str, argv=None):
    """The command line the verification demos share (``--cells --ppc --dt --basis --out``),
    checked, with its output folder created (all ranks agree); returns the arguments and the folder.
    A bad value ends the program with argparse's message and exit status 2."""
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
