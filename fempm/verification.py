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

from fempm.implicit import SimulationDiverged

__all__ = ["Measurement", "Run", "advance", "max_relative_error", "rates", "sample"]


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
    The wall time is that of the steps and ``each_step`` calls (set-up excluded); a ``run``
    given carries on accumulating.
    """
    run = run or Run()
    n = int(round((end_time - solver.time) / solver.options.dt))
    start = time.perf_counter()
    try:
        for _ in range(n):
            solver.step()
            if each_step:
                each_step(solver)
    except SimulationDiverged as e:
        run.status, run.cause = "stopped", str(e)
    run.wall += time.perf_counter() - start
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
