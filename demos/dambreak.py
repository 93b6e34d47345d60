"""The seed's dam break: a water column collapses in a square tank (method.md, Figs. 1-4).

Geometry (Koshizuka & Oka 1996): a 584 mm square tank, 40 x 40 cells (h = 14.6 mm), a
water column L = 146 mm wide and 2L = 292 mm high in the lower-left corner, 2 x 2
particles per cell (800 particles), gravity only, walls slip. Water: rho = 1000 kg/m^3,
mu = 1.0e-3 Pa s. Time step 1.0e-3 s.

Strong form, in the moving material (incompressible Navier-Stokes, Lagrangian)::

    rho dv/dt = div(2 mu eps(v)) - grad p + rho g,   div v = 0,
    traction-free free surface, zero normal velocity on the walls.

Weak form, per step, unknowns the grid displacement increment du and pressure p
(Newmark, PSPG, volume correction): ``forms/incompressible.py`` -- edit it, or pass a
copy with ``--forms``, to change the physics.

The run writes to ``--out`` (default ``results/dambreak``):

* ``front.csv`` and ``front.png``: surge front Z = x/L against T = t sqrt(2g/L), with the
  Koshizuka-Oka experiment and Martin-Moyce's data (the seed's Fig. 2a);
* ``snapshot_t0.200.png``, ``snapshot_t0.600.png``, ``snapshot_final.png``: particles
  coloured by pressure (Figs. 2b, 3);
* ``particles.pvd`` (+ ``particles_*.vtp``) and ``grid.bp``: particles and grid fields
  for ParaView, every ``--output-interval`` seconds;
* ``volume.csv``: cells occupied by water and the mean depth they make (Fig. 4);
* ``summary.json``: front error, steps, wall time by phase, pressure range, max |div v|.

Run (``mpirun -n 2`` works the same)::

    python demos/dambreak.py [--end-time 1.0] [--basis bspline|q1] [--no-pspg] ...
"""

# %% imports
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

import fempm
from fempm import diagnostics, output
from fempm.errors import FempmError
from fempm.implicit import ImplicitOptions, ImplicitSolver, SimulationDiverged
from fempm.progress import Progress

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "reference" / "dambreak"
TANK, WIDTH, HEIGHT = 0.584, 0.146, 0.292
GRAVITY = 9.81


def load_reference(name: str) -> np.ndarray:
    """A reference front history (T, Z) from data/reference/dambreak."""
    return np.loadtxt(REFERENCE / name, delimiter=",", skiprows=2)


# %% command line
def parse_arguments(argv=None) -> tuple[argparse.Namespace, list[str]]:
    """The demo's flags; unknown ``-fempm_...`` flags go to PETSc."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--end-time", type=float, default=1.0, help="simulated time, s (default 1.0)")
    parser.add_argument("--dt", type=float, default=1.0e-3, help="time step, s (default 1e-3)")
    parser.add_argument("--cells", type=int, default=40, help="cells per side of the tank (default 40)")
    parser.add_argument("--ppc", type=int, default=2, help="particles per cell and direction (default 2)")
    parser.add_argument("--basis", choices=("bspline", "q1"), default="bspline", help="grid basis")
    parser.add_argument("--no-pspg", action="store_true", help="switch PSPG off (the run then fails)")
    parser.add_argument("--no-volume-correction", action="store_true", help="alpha = 0 (method.md eq. 3)")
    parser.add_argument("--alpha", type=float, default=ImplicitOptions.alpha, help="volume correction")
    parser.add_argument("--walls", choices=("slip", "no-slip"), default="slip")
    parser.add_argument("--pic", type=float, default=0.0, help="PIC share of the FLIP/PIC blend, 0..1")
    parser.add_argument("--viscosity", type=float, default=1.0e-3, help="Pa s")
    parser.add_argument("--forms", default="incompressible", help="weak forms file (default forms/incompressible.py)")
    parser.add_argument("--out", type=Path, default=Path("results/dambreak"), help="output folder")
    parser.add_argument("--output-interval", type=float, default=0.05, help="ParaView output every, s")
    parser.add_argument("--no-files", action="store_true", help="write only the tables and summary")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    args, rest = parser.parse_known_args(argv)
    bad = [a for a in rest if not a.startswith("-fempm_")]
    if bad:
        parser.error(f"unrecognised arguments: {' '.join(bad)} (PETSc options take the prefix -fempm_)")
    for name in ("end_time", "dt", "output_interval"):
        if not getattr(args, name) > 0:
            parser.error(f"--{name.replace('_', '-')} must be positive, got {getattr(args, name)}")
    if args.cells < 4 or args.cells % 4:
        parser.error(f"--cells must be a positive multiple of 4 (the column is a quarter of the tank), got {args.cells}")
    if args.ppc < 1:
        parser.error(f"--ppc must be at least 1, got {args.ppc}")
    return args, rest


# %% set-up: grid, basis, particles, solver
def build(args, comm=MPI.COMM_WORLD) -> ImplicitSolver:
    """The tank, the water column and the implicit solver of the given flags."""
    grid = fempm.Grid.from_cells(comm, (0.0, 0.0), (TANK, TANK), (args.cells, args.cells))
    basis = fempm.BSpline2(grid) if args.basis == "bspline" else fempm.Q1(grid)
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (WIDTH, HEIGHT)), per_cell=args.ppc, density=1000.0)
    options = ImplicitOptions(
        dt=args.dt, viscosity=args.viscosity, gravity=(0.0, -GRAVITY),
        alpha=0.0 if args.no_volume_correction else args.alpha, pspg=not args.no_pspg,
        pic_blend=args.pic, walls=args.walls, forms=args.forms,
    )
    return ImplicitSolver(basis, water, options)


# %% the run: step, record, write
def run(args, petsc_args=(), comm=MPI.COMM_WORLD) -> dict:
    """Run the dam break of ``args``; returns the summary (also written to summary.json)."""
    PETSc.Options().insertString(" ".join(petsc_args))
    out = output.prepare_folder(args.out, comm)
    solver = build(args, comm)
    water, h = solver.particles, solver.grid.h
    initial_cells = diagnostics.occupied_cells(water)
    front, volume = [(0.0, diagnostics.front_position(water))], [(0.0, initial_cells)]
    particles_out = None if args.no_files else output.ParticleSeries(out)
    grid_out = None if args.no_files else output.GridSeries(out, solver.vector_space, solver.scalar_space)
    snapshot_times = [t for t in (0.2, 0.6) if t <= args.end_time + 1e-12]
    pressure_scale = (0.0, 1000.0 * GRAVITY * HEIGHT)
    progress = Progress(args.end_time, comm) if not args.quiet else None
    next_output, status, cause = 0.0, "completed", None
    n_steps = int(round(args.end_time / args.dt))
    wall0 = time.perf_counter()
    p_min, p_max, div_max = np.inf, -np.inf, 0.0
    try:
        for _ in range(n_steps):
            start = time.perf_counter()
            solver.step()
            t = solver.time
            front.append((t, diagnostics.front_position(water)))
            volume.append((t, diagnostics.occupied_cells(water)))
            low, high = diagnostics.pressure_range(water)
            p_min, p_max, div_max = min(p_min, low), max(p_max, high), max(div_max, solver.max_divergence)
            if not args.no_files:
                if t >= next_output - 1e-12:
                    particles_out.write(water, t)
                    grid_out.write(solver.velocity, solver.pressure, t)
                    next_output += args.output_interval
                for ts in [ts for ts in snapshot_times if abs(t - ts) < 0.5 * args.dt]:
                    output.snapshot(out / f"snapshot_t{ts:.3f}.png", water, title=f"t = {ts:.3f} s",
                                    clim=pressure_scale)
            if progress:
                progress.update(t, time.perf_counter() - start)
    except SimulationDiverged as e:
        status, cause = "stopped", str(e)
    finally:
        if progress:
            progress.close()
        if grid_out:
            grid_out.close()
    wall = time.perf_counter() - wall0
    summary = finish(args, solver, out, front, volume, initial_cells, status, cause, wall,
                     (p_min, p_max), div_max, comm)
    if not args.no_files:
        output.snapshot(out / "snapshot_final.png", water, title=f"t = {solver.time:.3f} s ({status})",
                        clim=pressure_scale)
    return summary


# %% compare with the experiment, write the tables, plot
def finish(args, solver, out, front, volume, initial_cells, status, cause, wall, p_range, div_max, comm):
    """Write front.csv, volume.csv, front.png and summary.json; return the summary."""
    front = np.array(front)
    T = front[:, 0] * np.sqrt(2 * GRAVITY / WIDTH)
    Z = front[:, 1] / WIDTH
    experiment = load_reference("koshizuka_oka_1996_experiment.csv")
    error = diagnostics.front_error(T, Z, experiment) if T[-1] > 0.3 else None
    h = solver.grid.h
    floor = solver.grid.upper[0] - solver.grid.lower[0]
    summary = {
        "status": status, "cause": cause, "time": solver.time, "steps": solver.steps,
        "particles": solver.particles.global_count(), "basis": solver.basis.name,
        "cells": args.cells, "particles_per_cell": args.ppc ** 2, "dt": args.dt,
        "pspg": not args.no_pspg, "alpha": solver.options.alpha,
        "front_rms_error_vs_koshizuka_oka": error,
        "wall_time_s": wall, "wall_time_by_phase_s": dict(solver.timings),
        "pressure_min_Pa": p_range[0], "pressure_max_Pa": p_range[1],
        "max_abs_div_v_per_s": div_max,
        "occupied_cells_initial": initial_cells, "occupied_cells_final": volume[-1][1],
        "mean_depth_final_m": volume[-1][1] * h * h / floor,
        "newton_iterations": solver.newton_iterations,
    }
    if comm.rank == 0:
        output.write_csv(out / "front.csv", ["t", "front_m", "T", "Z"],
                         [(t, x, Ti, Zi) for (t, x), Ti, Zi in zip(front, T, Z)],
                         comment="surge front: largest particle x plus half a particle spacing; T = t sqrt(2g/L), Z = x/L, L = 0.146 m")
        output.write_csv(out / "volume.csv", ["t", "occupied_cells", "occupied_area_m2", "mean_depth_m"],
                         [(t, c, c * h * h, c * h * h / floor) for t, c in volume],
                         comment="cells holding particles; mean depth = occupied area / floor width")
        output.write_json(out / "summary.json", summary)
        plot_front(out / "front.png", T, Z, error, summary)
    return summary


def plot_front(path, T, Z, error, summary):
    """Z against T with the experiments (the seed's Fig. 2a)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.plot(T, Z, "-", color="tab:blue", label=f"fempm ({summary['basis']}, {summary['particles']} particles)")
    ko = load_reference("koshizuka_oka_1996_experiment.csv")
    ax.plot(ko[:, 0], ko[:, 1], "o", color="black", label="Koshizuka & Oka 1996, experiment")
    for name, marker, label in (("martin_moyce_1952_n2_2_a2.25in.csv", "s", "Martin & Moyce 1952, a = 2.25 in"),
                                ("martin_moyce_1952_n2_2_a1.125in.csv", "^", "Martin & Moyce 1952, a = 1.125 in")):
        mm = load_reference(name)
        ax.plot(mm[:, 0], mm[:, 1], marker, mfc="none", color="tab:gray", label=label)
    ax.set_xlim(0, 4.0)  # the front reaches the far wall (Z = 4) at T ~ 3.1
    ax.set_ylim(1, 4.2)
    ax.set_xlabel(r"$T = t\sqrt{2g/L}$")
    ax.set_ylabel(r"$Z = x_{front}/L$")
    if error is not None:
        ax.set_title(f"surge front: RMS error vs experiment (T <= 3) = {100 * error:.1f} %")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with output.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=130)
    plt.close(fig)


def main(argv=None) -> int:
    """Run from the command line; exit status 1 if the run stopped early."""
    args, petsc_args = parse_arguments(argv)
    try:
        summary = run(args, petsc_args)
    except FempmError as e:
        if MPI.COMM_WORLD.rank == 0:
            print(f"dambreak: {e}", file=sys.stderr)
        return 2
    if MPI.COMM_WORLD.rank == 0:
        if summary["status"] != "completed":
            print(f"dambreak: {summary['cause']}; the outputs up to then are in {args.out}", file=sys.stderr)
        else:
            err = summary["front_rms_error_vs_koshizuka_oka"]
            print(f"dambreak: {summary['steps']} steps in {summary['wall_time_s']:.1f} s; front error vs "
                  f"experiment {'-' if err is None else f'{100 * err:.1f} %'}; results in {args.out}")
    return 0 if summary["status"] == "completed" else 1


if __name__ == "__main__":
    sys.exit(main())
