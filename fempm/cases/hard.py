"""Hard cases of the implicit MPM: does each run to its end, or stop with a diagnosis?

The cases push the scheme where MPM codes break: a time step ten times the seed's
(advective CFL above 1), water and a very viscous fluid, a dam break hitting a block
(splash, thin jets, isolated particles), a single particle and a sparse cloud of
particles (nearly empty cells), water driven into a corner, and a long run; and, for the
record, a step twenty times the seed's, past what the scheme can take. A peer implicit
MPM's dam break was reported to "erupt" mid-run; the measures below show an eruption:
kinetic energy the flow cannot have taken from gravity (``energy_max``, ``energy_rise``)
and particle speeds beyond free fall (``speed_ratio``).

Measured on every case, every step, on all ranks (no loop over particles):

* how the run ended (:class:`fempm.verification.Run`: completed, or stopped with the
  cause and time of :class:`fempm.errors.SimulationDiverged`);
* whether every particle field is finite; the relative change of the total mass;
* the volume measures of :mod:`fempm.diagnostics`: occupied cells, settled surface height;
* the mechanical energy ``E = sum_p m_p (|v_p|^2 / 2 - g . (x_p - x_low))`` with ``x_low``
  the corner of the tank lowest in the direction of gravity: ``energy_max = max E(t) / E(0)``
  (gravity and walls at rest can only take energy away: <= 1 up to the scheme's error) and
  ``energy_rise = max over t of (E(t) - min_{s <= t} E(s)) / E(0)`` (any gain after a loss);
* the largest particle speed against free fall from the highest particle to the lowest
  corner, ``sqrt(|v_0|^2 + 2 |g| dz)`` (``speed_ratio``; a jet squeezed out by pressure can
  exceed 1, an eruption exceeds it by far), and the advective CFL ``max |v| dt / h``
  (a particle stopped at a wall keeps its velocity into the wall, which counts in both);
* ``wall_stops``: displacements cut at a wall (:meth:`fempm.walls.Walls.keep_inside`).

Each case has a short version (CI: ``tests/hard/test_hard_cases.py`` asserts on these
measures) and a long one; ``benchmarks/hard_cases.py`` writes both as ``docs/hard-cases.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from math import sqrt
from typing import Callable

import numpy as np
from mpi4py import MPI

from fempm import diagnostics
from fempm.bases import BSpline2
from fempm.cases import dambreak
from fempm.grid import Grid
from fempm.implicit import ImplicitSolver
from fempm.particles import Particles
from fempm.scene import load_scene
from fempm.simulation import build_solver
from fempm.verification import Run, advance

__all__ = ["CASES", "COLUMNS", "Case", "Outcome", "Watch", "row", "run_case"]

G = dambreak.GRAVITY
TANK, H = dambreak.TANK, dambreak.HEIGHT
CELLS = 40
h = TANK / CELLS
SEED_DT = dambreak.SEED_DT
FIELDS = ("x", "velocity", "acceleration", "pressure")


# -- the cases ----------------------------------------------------------------------------------------
def dam_break(dt: float = SEED_DT, viscosity: float = 1.0e-3):
    """The seed's dam break (:func:`fempm.cases.dambreak.scene`) at another step or viscosity."""
    def build(comm):
        return build_solver(dambreak.scene({**dambreak.seed_setup(dt), "fluid.viscosity": viscosity}, files=False), comm)
    return build


def obstacle(comm):
    """``scenes/obstacle.toml``: the dam break onto a block 3 cells wide and 4 high."""
    return build_solver(load_scene(dambreak.SCENE.parent / "obstacle.toml"), comm)


def loose_particles(x0: np.ndarray, per_cell: int):
    """Particles at ``x0`` (rank 0 adds them) in the dam-break tank, each of volume ``(h / per_cell)^2``,
    at rest, falling from ``t = 0``: no water around them to hold a pressure."""
    def build(comm):
        grid = Grid.from_cells(comm, (0.0, 0.0), (TANK, TANK), (CELLS, CELLS))
        particles = Particles(grid)
        particles.add_points(x0 if comm.rank == 0 else np.zeros((0, 2)), (h / per_cell) ** 2, density=1000.0,
                             ids=np.arange(len(x0)) if comm.rank == 0 else np.zeros(0, dtype=np.int64))
        return ImplicitSolver(BSpline2(grid), particles)
    return build


#: one particle (a seed particle's volume) high in the middle of the empty tank
SINGLE = np.array([[0.5 * TANK, 0.7 * TANK]])
#: one particle in every other cell of a 16 x 6 block of cells, up in the tank: 48 particles
#: with no neighbour in the cells around them
SPARSE = h * (np.stack(np.meshgrid(np.arange(12, 28, 2), np.arange(22, 34, 2)), -1).reshape(-1, 2) + 0.5)

#: gravity at 45 degrees down to the right, and a block of water already moving that way
CORNER_GRAVITY = (G / sqrt(2), -G / sqrt(2))
CORNER_SPEED = 2.0


def corner(comm):
    """A square of water (10 x 10 cells) thrown at the lower-right corner along a tilted gravity."""
    return build_solver(dambreak.scene({
        **dambreak.seed_setup(), "gravity": list(CORNER_GRAVITY), "bodies.0.lower": [0.2, 0.25], "bodies.0.upper": [0.2 + 10 * h, 0.25 + 10 * h],
        "bodies.0.velocity": [CORNER_SPEED / sqrt(2), -CORNER_SPEED / sqrt(2)], "output.progress": False,
    }, files=False), comm)


@dataclass(frozen=True)
class Case:
    """A hard case: how to build it and how long it runs in CI (``short``) and with ``--full``
    (``build_full``, if given, builds the full version)."""

    name: str
    what: str
    build: Callable
    short: float
    full: float
    build_full: Callable | None = None


CASES = {c.name: c for c in (
    Case("dt-10x", "dam break, dt = 1e-2 s (10x the seed's)", dam_break(dt=10 * SEED_DT), 2.0, 4.0),
    Case("dt-20x", "dam break, dt = 2e-2 s (20x the seed's): past the limit, stopped by the energy check",
         dam_break(dt=20 * SEED_DT), 3.0, 4.0),
    Case("water", "dam break, water, mu = 1e-3 Pa s", dam_break(viscosity=1.0e-3), 0.6, 2.0),
    Case("viscous", "dam break, mu = 10 Pa s", dam_break(viscosity=10.0), 0.6, 3.0),
    Case("obstacle", "dam break onto a block 3 x 4 cells (scenes/obstacle.toml)", obstacle, 0.6, 2.0),
    Case("single-particle", "one particle falling from y = 0.41 m in the empty tank", loose_particles(SINGLE, 2),
         0.5, 2.0),
    Case("sparse-cloud", f"{len(SPARSE)} particles, one in every other cell, falling", loose_particles(SPARSE, 1),
         0.6, 2.0),
    Case("corner", f"10 x 10 cells of water thrown at {CORNER_SPEED:g} m/s into the lower-right corner, "
                   "gravity at 45 deg", corner, 0.5, 3.0),
    Case("long", "dam break settling: 5 s at dt = 1e-2 s (--full: 40 s at the seed's 1e-3 s)",
         dam_break(dt=10 * SEED_DT), 5.0, 40.0, build_full=dam_break()),
)}


# -- the measures -------------------------------------------------------------------------------------
@dataclass
class Outcome:
    """What one run of a case measured (the same on every rank); see the module's docstring."""

    case: str
    end_time: float
    dt: float
    run: Run
    particles: int
    finite: bool
    mass_error: float
    cells_initial: int
    cells_final: int
    surface_height: float
    max_speed: float
    speed_bound: float
    max_cfl: float
    energy_max: float
    energy_rise: float
    wall_stops: int
    history: dict = field(default_factory=dict)  # per step: t, centroid, max speed, energy
    solver: ImplicitSolver | None = field(default=None, repr=False)  # as the run left it

    @property
    def speed_ratio(self) -> float:
        """Largest particle speed over the free-fall bound."""
        return self.max_speed / self.speed_bound


class Watch:
    """Takes the measures of a solver's particles after every step (collectively, on all ranks)."""

    def __init__(self, solver: ImplicitSolver):
        self.comm = solver.grid.comm
        p = solver.particles
        self.g = np.asarray(solver.physics.gravity, dtype=float)
        self.x_low = diagnostics.lowest_corner(solver.grid, self.g)
        self.mass0 = self._sum(p["mass"])
        self.cells0 = diagnostics.occupied_cells(p)
        drop = self._max(np.einsum("ij,j->i", p.x - self.x_low, -self.g))  # |g| times the fall height of the highest particle
        self.speed_bound = sqrt(self._max(np.einsum("ij,ij->i", p["velocity"], p["velocity"])) + 2 * drop)
        self.history = {"t": [], "centroid": [], "max_speed": [], "energy": []}
        self.finite = True
        self._record(solver)

    def _sum(self, a) -> float:
        return self.comm.allreduce(float(np.sum(a)))

    def _max(self, a) -> float:
        return self.comm.allreduce(float(np.max(a, initial=-np.inf)), op=MPI.MAX)

    def _record(self, solver):
        p = solver.particles
        m = p["mass"]
        speed2 = np.einsum("ij,ij->i", p["velocity"], p["velocity"])
        energy = diagnostics.mechanical_energy(p, self.g, self.x_low)
        self.history["t"].append(solver.time)
        self.history["centroid"].append(self.comm.allreduce(np.einsum("i,ij->j", m, p.x)) / self.mass0)
        self.history["max_speed"].append(sqrt(self._max(speed2)))
        self.history["energy"].append(energy)
        finite = all(bool(np.all(np.isfinite(p[name]))) for name in FIELDS)
        self.finite &= self.comm.allreduce(finite, op=MPI.LAND)

    def __call__(self, solver):
        """After a step: record the measures."""
        self._record(solver)

    def outcome(self, case: str, solver: ImplicitSolver, end_time: float, run: Run) -> Outcome:
        """The measures of the run so far."""
        p = solver.particles
        history = {k: np.asarray(v) for k, v in self.history.items()}
        energy = history["energy"] / history["energy"][0]
        return Outcome(
            case=case, end_time=end_time, dt=solver.dt, run=run, particles=p.global_count(),
            finite=self.finite, mass_error=self._sum(p["mass"]) / self.mass0 - 1.0,
            cells_initial=self.cells0, cells_final=diagnostics.occupied_cells(p),
            surface_height=diagnostics.surface_height(p), max_speed=float(history["max_speed"].max()),
            speed_bound=self.speed_bound, max_cfl=float(history["max_speed"].max()) * solver.dt / solver.grid.h,
            energy_max=float(energy.max()), energy_rise=float(np.max(energy - np.minimum.accumulate(energy))),
            wall_stops=self.comm.allreduce(solver.walls.stops), history=history, solver=solver,
        )


def run_case(name: str, full: bool = False, comm=MPI.COMM_WORLD, pressure_quadrature: str = "particles",
             pressure_work: str | None = None) -> Outcome:
    """Build case ``name``, run it to its end time (short, or ``full``) and measure it; ``pressure_quadrature``,
    ``pressure_work``: the scheme's (:class:`fempm.options.Scheme`; None: the case's own, the divergence form with
    the Gauss points), the case's solver remade with them if others."""
    case = CASES[name]
    end = case.full if full else case.short
    solver = (case.build_full if full and case.build_full else case.build)(comm)
    if pressure_work is None:
        pressure_work = "divergence" if pressure_quadrature == "gauss" else solver.scheme.pressure_work
    options = {"pressure_quadrature": pressure_quadrature, "pressure_work": pressure_work}
    if any(getattr(solver.scheme, key) != value for key, value in options.items()):
        solver = ImplicitSolver(solver.basis, solver.particles, solver.physics, replace(solver.scheme, **options),
                                solver.controls)
    watch = Watch(solver)
    run = advance(solver, end, watch)
    return watch.outcome(name, solver, end, run)


# -- one line of the table ----------------------------------------------------------------------------
COLUMNS = ("case", "outcome", "end time reached (s)", "steps", "wall (s)", "mass error", "cells (start -> end)",
           "surface height (m)", "max speed (m/s)", "speed / free fall", "max CFL", "E_max / E_0", "E rise / E_0",
           "wall stops")


def row(o: Outcome) -> list[str]:
    """One line of the table."""
    outcome = "completed" if o.run.status == "completed" else f"stopped: {o.run.cause}"
    if not o.finite:
        outcome += " (NaN)"
    return [o.case, outcome, f"{o.run.time:.3f} of {o.end_time:g}", str(o.run.steps), f"{o.run.wall:.1f}",
            f"{o.mass_error:.1e}", f"{o.cells_initial} -> {o.cells_final}", f"{o.surface_height:.4f}",
            f"{o.max_speed:.2f}", f"{o.speed_ratio:.2f}", f"{o.max_cfl:.2f}", f"{o.energy_max:.3f}",
            f"{o.energy_rise:.3f}", str(o.wall_stops)]
