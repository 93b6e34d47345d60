"""The runs of each verification case's study: error against the reference and wall time, per run.

One function per case of :mod:`fempm.cases`, each returning :class:`~fempm.verification.Measurement`
rows: the case under grid refinement (both methods and bases), particles per cell, time step
(and for the channel its PIC share). ``full`` adds a finer grid and step to each.
``benchmarks/report.py`` runs them and writes ``docs/verification.md``.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import references, simulation
from fempm.bases import BASES
from fempm.cases import cavity as cav
from fempm.cases import channel, dambreak, hydrostatic
from fempm.verification import METHODS, Measurement, max_relative_error, rates

__all__ = ["STUDIES", "cavity", "couette", "dam_break", "hydrostatic_tank", "poiseuille"]


def hydrostatic_tank(full: bool = False) -> list[Measurement]:
    """Error and wall time against cells across the depth (both methods and bases), particles per cell
    and time step."""
    grids = (10, 20, 40, 80) if full else (10, 20, 40)
    rows = [hydrostatic.solve(m, b, n, 0.001) for m in METHODS for b in BASES for n in grids]
    rows += [hydrostatic.solve("MPM", "bspline", 20, 0.001, ppc) for ppc in (1, 2, 3, 4)]
    rows += [hydrostatic.solve("MPM", "bspline", 20, dt) for dt in (0.004, 0.002, 0.001, 0.0005)[: 4 if full else 3]]
    return rows


def poiseuille(full: bool = False) -> list[Measurement]:
    """Error and wall time against grid size (both methods, both bases), particles per cell, time step
    and the MPM's PIC share (steady runs at dt = 0.01 H^2/nu; time steps at t = 0.1 H^2/nu)."""
    flow = channel.POISEUILLE
    steady, transient = (flow.steady,), (flow.transient,)
    grids = (8, 16, 32, 64) if full else (8, 16, 32)
    rows = [r for m in METHODS for b in BASES for n in grids for r in channel.solve(flow, m, b, n, 0.01, times=steady)]
    rows += [r for ppc in (1, 2, 3, 4) for r in channel.solve(flow, "MPM", "bspline", 16, 0.01, ppc, times=steady)]
    steps = (0.01, 0.005, 0.0025, 0.00125) if full else (0.01, 0.005, 0.0025)
    rows += [r for m in METHODS for dt in steps for r in channel.solve(flow, m, "bspline", 16, dt, times=transient)]
    rows += [r for pic in (0.0, 0.1) for dt in (0.01, 0.001)
             for r in channel.solve(flow, "MPM", "bspline", 16, dt, times=steady, pic_blend=pic)]
    return rows


def couette(full: bool = False) -> list[Measurement]:
    """Error at t = 0.1 H^2/nu and wall time against grid size (both methods, both bases; at
    dt = 2.5e-4 H^2/nu, where the time error is below the grid's), time step and particles per cell.
    The impulsive start makes the time error first order in dt (measured)."""
    flow, transient = channel.COUETTE, (channel.COUETTE.transient,)
    grids = (8, 16, 32, 64) if full else (8, 16, 32)
    rows = [r for m in METHODS for b in BASES for n in grids for r in channel.solve(flow, m, b, n, 0.00025,
                                                                                     times=transient)]
    steps = (0.004, 0.002, 0.001, 0.0005) if full else (0.004, 0.002, 0.001)
    rows += [r for m in METHODS for dt in steps for r in channel.solve(flow, m, "bspline", 32, dt, times=transient)]
    rows += [r for ppc in (1, 2, 3, 4) for r in channel.solve(flow, "MPM", "bspline", 16, 0.001, ppc, times=transient)]
    return rows


def cavity(full: bool = False, comm=MPI.COMM_WORLD, progress: bool = False) -> list[Measurement]:
    """Convergence of both methods against Ghia, each run's wall time beside its error.

    Every run starts from rest and ends at ``END_TIME``; its error is that of the mean
    profile over the last ``WINDOW`` (see :func:`fempm.cases.cavity.run_case`). The runs:

    * grid: FEM-only (dt ``FEM_DT``) and MPM (2 x 2 particles per cell, Courant
      number ``COURANT``), B-spline and Q1, at 16, 24 and 32 cells (``full``: also 48, 64);
    * particles per cell: MPM, B-spline, 1, 4, 9 and 16 per cell, on the sweep grid
      (16 cells; ``full``: 32);
    * time step: MPM, B-spline, Courant numbers 1, 0.5 and 0.25, on the sweep grid.

    The run shared by the series (2 x 2 particles, Courant 0.5, sweep grid) is run once;
    ``extra["series"]`` names the series a row belongs to. ``extra`` also gives
    ``difference_from_finest_fem`` (max over Ghia's points of |profile - that of the finest
    FEM-only B-spline run| / U: Ghia's table has errors of its own, see demos/cavity.py) and,
    along the grid series of each method and basis, the observed orders from the previous grid,
    ``rate_vs_ghia`` and ``rate_vs_finest_fem`` (:func:`fempm.verification.rates`).

    Short: 17 runs; ``full`` adds the 48- and 64-cell grids (the MPM at 64 cells the longest).
    """
    grids = (16, 24, 32, 48, 64) if full else (16, 24, 32)
    sweep = 32 if full else 16
    runs: dict[tuple, cav.CavityRun] = {}

    def once(series, method, basis, cells, dt, per_cell=2):
        key = (method, basis, cells, dt, per_cell)
        if key not in runs:
            runs[key] = cav.run_case(method, basis, cells, dt, per_cell, comm=comm, progress=progress)
        runs[key].measurement.extra.setdefault("series", []).append(series)
        return runs[key]

    for cells in grids:
        for basis in BASES:
            once("grid", "FEM-only", basis, cells, cav.FEM_DT)
            once("grid", "MPM", basis, cells, cav.courant_step(cells))
    for per_cell in (1, 2, 3, 4):
        once("particles per cell", "MPM", "bspline", sweep, cav.courant_step(sweep), per_cell)
    for courant in (1.0, 0.5, 0.25):
        once("time step", "MPM", "bspline", sweep, cav.courant_step(sweep, courant))

    ghia = cav.load_ghia()
    finest = np.concatenate(cav.at_ghia_points(ghia, runs[("FEM-only", "bspline", grids[-1], cav.FEM_DT, 2)].profile))
    for r in runs.values():
        r.measurement.extra["difference_from_finest_fem"] = None if r.measurement.error is None else (
            max_relative_error(np.concatenate(cav.at_ghia_points(ghia, r.profile)), finest, cav.LID_SPEED))
    measures = {"rate_vs_ghia": lambda m: m.error,
                "rate_vs_finest_fem": lambda m: m.extra["difference_from_finest_fem"]}
    for method in ("FEM-only", "MPM"):
        for basis in BASES:
            series = [r.measurement for key, r in runs.items()
                      if key[:2] == (method, basis) and "grid" in r.measurement.extra["series"]]
            for name, measure in measures.items():
                observed = rates([cav.SIDE / m.cells for m in series], [measure(m) for m in series])
                for m, rate in zip(series[1:], observed):
                    m.extra[name] = None if np.isnan(rate) else rate
    return [r.measurement for r in runs.values()]


def dam_break(full: bool = False) -> list[Measurement]:
    """Front error (T <= 3) against Koshizuka-Oka and wall time, against cells across the tank,
    particles per cell, time step and basis. In ``extra``: the error against Martin-Moyce and
    the RMS relative difference from the finest B-spline run (the numerical error; the
    experiments hold wall friction and a gate that slip walls leave out)."""

    def one(cells=40, ppc=2, dt=1e-3, basis="bspline"):
        with tempfile.TemporaryDirectory() as folder:
            scene = dambreak.scene({"time.end": 0.28, **dambreak.seed_setup(dt), "domain.cells": [cells, cells],
                                    "bodies.0.particles_per_cell": ppc**2, "solver.basis": basis,
                                    "output.folder": folder, "output.progress": False}, files=False)
            s = simulation.run_scene(scene, MPI.COMM_WORLD, overwrite=True)
            front = dambreak.read_front(Path(folder))
        measures = dambreak.front_measures(front) if s["status"] == "completed" else {}
        return Measurement("dam break", "MPM", BASES[basis].name, cells, dt, ppc**2,
                           measures.get("front_rms_error_vs_koshizuka_oka"), s["wall_time_s"], s["status"],
                           s.get("cause") or "", {"martin_moyce": measures.get("front_rms_error_vs_martin_moyce"),
                                                  "pic_blend": scene.solver.pic_blend, "history": front})

    grids = (20, 40, 80, 160) if full else (20, 40, 80)
    rows = [one(cells=n, basis=b) for b in ("bspline", "q1") for n in grids]
    rows += [one(ppc=ppc) for ppc in (1, 3, 4)]
    rows += [one(dt=dt) for dt in ((5e-3, 2e-3, 5e-4) if full else (5e-3, 2e-3))]
    finest = rows[len(grids) - 1].extra["history"]
    for r in rows:
        history = r.extra.pop("history")
        if r.status == "completed" and r is not rows[len(grids) - 1]:
            r.extra["vs_finest"] = references.front_difference(history, finest, T_min=0.0)
    return rows


#: the study of each case, by the name its section of the page has
STUDIES = {"hydrostatic": hydrostatic_tank, "poiseuille": poiseuille, "couette": couette, "cavity": cavity,
           "dambreak": dam_break}
