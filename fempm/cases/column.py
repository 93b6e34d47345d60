"""The dam-break column held at rest: what the transfer and the volume correction do to still water.

The seed's column, L = 146 mm wide and 2L high (rho = 1000 kg/m^3, mu = 1e-3 Pa s, slip walls),
in a tank as wide as the column and 4L high, 10 x 40 cells (the dam break's cell size at 40 x 40),
2 x 2 particles per cell, at rest from ``p = 0``. Nothing should move: the water's volume (its
surface height, :func:`fempm.diagnostics.surface_height`, the tank's width being fixed) must stay
and the particles' speeds must stay small. Under FLIP increments without a PIC share a
grid-scale velocity mode grows in resting water: the case checks that the transfer holds it.
"""

from __future__ import annotations

from mpi4py import MPI

from fempm import diagnostics
from fempm.bases import BASES
from fempm.cases.vortices import VARIANTS
from fempm.grid import Grid
from fempm.implicit import ImplicitSolver
from fempm.options import Physics, Scheme
from fempm.particles import Rectangle
from fempm.references import DAMBREAK_COLUMN_WIDTH
from fempm.verification import advance, filled_solver

__all__ = ["HEIGHT", "WIDTH", "rest"]

WIDTH = DAMBREAK_COLUMN_WIDTH  #: L, m
HEIGHT = 2 * WIDTH  #: the water's depth, m


def rest(variant: str, end: float, basis: str = "bspline", dt: float = 1e-3, comm=MPI.COMM_WORLD,
         solver_type=ImplicitSolver, height: float = HEIGHT, tank_height: float = 2 * HEIGHT, cells: int = 10,
         courant: float | None = None) -> dict:
    """Hold the column (``height`` deep, in a tank ``tank_height`` high, a multiple of a cell, ``cells``
    cells across) ``end`` seconds at a fixed step ``dt`` or, with ``courant``, the adaptive step at most
    ``dt``: ``volume`` (surface height over its start, less 1), the largest particle speed at the end
    (``speed``) and over the run (``peak``), m/s; ``status``, ``cause``, ``t``, ``wall``, ``steps``
    (``solver_type``: see :func:`fempm.verification.filled_solver`)."""
    grid = Grid.from_cells(comm, (0.0, 0.0), (WIDTH, tank_height), (cells, round(cells * tank_height / WIDTH)))
    physics = Physics(viscosity=1.0e-3, gravity=(0.0, -9.81))
    scheme = Scheme(dt=dt, courant=courant, **VARIANTS[variant])
    solver = filled_solver("MPM", BASES[basis](grid), physics, scheme, density=1000.0,
                           body=Rectangle((0.0, 0.0), (WIDTH, height)), solver_type=solver_type)
    water = solver.particles
    start = diagnostics.surface_height(water)
    peak = [0.0]

    def fastest(_):
        peak[0] = max(peak[0], solver.fastest())

    run = advance(solver, end, fastest)
    return {"variant": variant, "basis": basis, "dt": dt, "end": end,
            "volume": diagnostics.surface_height(water) / start - 1, "speed": solver.fastest(), "peak": peak[0],
            "status": run.status, "cause": run.cause, "t": run.time, "wall": run.wall, "steps": solver.steps}
