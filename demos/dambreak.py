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

The set-up is the scene ``scenes/dambreak.toml`` (``fempm run scenes/dambreak.toml`` runs
it too); the flags below change it. The run writes to ``--out`` (default
``results/dambreak-demo``; a folder holding an earlier run is refused without ``--overwrite``):

* ``front.csv`` (t, x_front) and ``front.png``: surge front Z = x/L against
  T = t sqrt(2g/L), with the Koshizuka-Oka experiment and Martin-Moyce's data (the
  seed's Fig. 2a);
* ``snapshot_t0.200.png``, ``snapshot_t0.600.png``, ``snapshot_final.png``: particles
  coloured by pressure (Figs. 2b, 3);
* ``particles.pvd`` (+ ``particles_*.vtp``), ``grid.pvd`` (+ ``grid_*.vti``) and ``grid.bp``
  (the grid series as one VTX stream, written when the run ends):
  particles and grid fields for ParaView, every ``--output-interval`` seconds;
* ``volume.csv``: cells occupied by water and the mean depth they make (Fig. 4);
* ``summary.json``: front error, steps, wall time by phase, pressure range, max |div v|;
* ``checkpoint.npz``: for ``fempm run --resume results/dambreak-demo``.

Run (``mpirun -n 2`` works the same)::

    python demos/dambreak.py [--end-time 1.0] [--basis bspline|q1] [--no-pspg] ...
"""

# %% imports
from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

import numpy as np
from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import output, recording, references, simulation
from fempm.errors import FempmError
from fempm.bases import BASES
from fempm.options import Scheme
from fempm.recording import Recorder, RecorderOptions
from fempm.scene import Scene, load_scene, parse_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"
_SHIPPED = load_scene(SCENE)
TANK = _SHIPPED.domain.upper[0]  # 0.584 m
WIDTH, HEIGHT = _SHIPPED.bodies[0].upper  # the column, L = 0.146 m and 2L
GRAVITY = -_SHIPPED.gravity[1]


# %% command line
def common_arguments(description: str, out: str, forms: str, pic: float) -> argparse.ArgumentParser:
    """The flags every dam-break demo has (tank, particles, fluid, outputs)."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--end-time", type=float, default=1.0, help="simulated time, s (default 1.0)")
    parser.add_argument("--cells", type=int, default=40, help="cells per side of the tank (default 40)")
    parser.add_argument("--ppc", type=int, default=2, help="particles per cell and direction (default 2)")
    parser.add_argument("--basis", choices=("bspline", "q1"), default="bspline", help="grid basis")
    parser.add_argument("--walls", choices=("slip", "no-slip"), default="slip")
    parser.add_argument("--pic", type=float, default=pic, help=f"PIC share of the FLIP/PIC blend, 0..1 (default {pic})")
    parser.add_argument("--viscosity", type=float, default=1.0e-3, help="Pa s")
    parser.add_argument("--forms", default=forms, help=f"weak forms file (default forms/{forms}.py)")
    parser.add_argument("--out", type=Path, default=Path(out), help=f"output folder (default {out})")
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier run's files in the folder")
    parser.add_argument("--output-interval", type=float, default=0.05, help="ParaView output every, s")
    parser.add_argument("--no-files", action="store_true", help="write only the tables and summary")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    return parser


def check_common(parser: argparse.ArgumentParser, args: argparse.Namespace):
    """Reject values of the common flags that cannot make a run."""
    for name in ("end_time", "output_interval"):
        if not getattr(args, name) > 0:
            parser.error(f"--{name.replace('_', '-')} must be positive, got {getattr(args, name)}")
    if args.cells < 4 or args.cells % 4:
        parser.error(f"--cells must be a positive multiple of 4 (the column is a quarter of the tank), got {args.cells}")
    if args.ppc < 1:
        parser.error(f"--ppc must be at least 1, got {args.ppc}")


def parse_arguments(argv=None) -> tuple[argparse.Namespace, list[str]]:
    """The demo's flags; unknown ``-fempm_...`` flags (with their values) go to PETSc."""
    parser = common_arguments(__doc__, "results/dambreak-demo", "incompressible", Scheme.pic_blend)
    parser.add_argument("--dt", type=float, default=1.0e-3, help="time step, s (default 1e-3)")
    parser.add_argument("--no-pspg", action="store_true", help="switch PSPG off (the run then fails)")
    parser.add_argument("--no-volume-correction", action="store_true", help="alpha = 0 (method.md eq. 3)")
    parser.add_argument("--alpha", type=float, default=Scheme.alpha, help="volume correction")
    args, rest = parser.parse_known_args(argv)
    bad = [a for k, a in enumerate(rest) if not a.startswith("-fempm_") and not (k and rest[k - 1].startswith("-fempm_"))]
    if bad:
        parser.error(f"unrecognised arguments: {' '.join(bad)} (PETSc options take the prefix -fempm_)")
    check_common(parser, args)
    return args, rest


# %% set-up: the shipped scene, changed by the flags
def tank(args) -> dict:
    """``scenes/dambreak.toml`` (as TOML data) with the common flags applied."""
    data = tomllib.loads(SCENE.read_text())
    data["time"]["end"] = args.end_time
    data["domain"]["cells"] = [args.cells, args.cells]
    data["bodies"][0]["particles_per_cell"] = args.ppc**2
    data["fluid"]["viscosity"] = args.viscosity
    data["walls"] = dict.fromkeys(data["walls"], args.walls)
    data["solver"].update(basis=args.basis, pic_blend=args.pic)
    data["output"].update(folder=str(args.out), progress=not args.quiet)
    data["output"]["snapshots"] = [t for t in data["output"].get("snapshots", []) if t <= args.end_time]
    if args.no_files:
        for key in ("particles_interval", "grid_interval", "snapshots", "final_snapshot"):
            data["output"].pop(key, None)
    else:
        data["output"].update(particles_interval=args.output_interval, grid_interval=args.output_interval)
    return data


def scene_of(args, petsc_args=()) -> Scene:
    """The implicit demo's scene: the tank with every flag applied (checked as any scene is)."""
    data = tank(args)
    data["time"]["dt"] = args.dt
    own = args.forms.endswith(".py") or "/" in args.forms  # a file of the user's own, not a shipped name
    data["solver"].update(pspg=not args.no_pspg, forms=args.forms if not own else "incompressible",
                          petsc=_petsc_table(petsc_args),
                          volume_correction=0.0 if args.no_volume_correction else args.alpha)
    return parse_scene(data, source="command line", forms=args.forms if own else None, names=FLAGS)


def build(args, comm=MPI.COMM_WORLD):
    """The implicit solver of the flags, ready to step (nothing is written)."""
    return simulation.build_solver(scene_of(args), comm)


def water_column(args, comm=MPI.COMM_WORLD) -> tuple:
    """The tank's basis and the water column of the common flags, for another scheme."""
    return simulation.build_material(parse_scene(tank(args), source="command line", names=FLAGS), comm)


# the scene's keys the flags set, named as flags in messages
FLAGS = {"time.end": "--end-time", "time.dt": "--dt", "domain.cells": "--cells",
         "bodies[0].particles_per_cell": "--ppc", "fluid.viscosity": "--viscosity", "solver.pic_blend": "--pic",
         "solver.volume_correction": "--alpha",
         "output.folder": "--out", "output.particles_interval": "--output-interval",
         "output.grid_interval": "--output-interval", "solver.forms": "--forms"}


def _petsc_table(petsc_args) -> dict:
    """``-fempm_name [value] ...`` as a table of options (a flag alone has the value "")."""
    table, args = {}, list(petsc_args)
    for k, arg in enumerate(args):
        if arg.startswith("-fempm_"):
            value = args[k + 1] if k + 1 < len(args) and not args[k + 1].startswith("-fempm_") else ""
            table[arg[len("-fempm_"):]] = value
    return table


# %% the run: step, record, write
def run(args, petsc_args=(), comm=MPI.COMM_WORLD) -> dict:
    """Run the dam break of ``args``; returns the summary (also written to summary.json)."""
    scene = scene_of(args, petsc_args)
    simulation.check_folder(scene.output.folder, comm, args.overwrite, key="--out")  # refused unless --overwrite
    summary = simulation.run_scene(scene, comm, overwrite=True, progress=not args.quiet)
    summary["scheme"] = "implicit"
    compare_front(Path(scene.output.folder), summary, comm)
    return summary


def record(solver, args, extra: dict, comm=MPI.COMM_WORLD) -> dict:
    """Step another scheme's ``solver`` to ``--end-time`` writing the dam break's outputs."""
    o = parse_scene(tank(args), source="command line", names=FLAGS).output
    if simulation.check_folder(o.folder, comm, args.overwrite, key="--out"):
        output.remove_earlier_outputs(o.folder, comm)
    recorder = Recorder(solver, RecorderOptions(
        folder=Path(o.folder), particles_interval=o.particles_interval, grid_interval=o.grid_interval,
        snapshot_times=o.snapshots, final_snapshot=o.final_snapshot, pressure_scale=o.pressure_scale,
        extra={"dt": solver.dt, **extra},
    ))
    summary = recording.run(solver, args.end_time, recorder, progress=not args.quiet)
    compare_front(recorder.folder, summary, comm)
    return summary


# %% compare the front with the experiment, write it and plot it
def compare_front(folder: Path, summary: dict, comm):
    """Front error against Koshizuka-Oka (T <= 3); front.png; completes summary.json."""
    error = None
    if comm.rank == 0:
        front = np.loadtxt(folder / "front.csv", delimiter=",", skiprows=2, ndmin=2)
        T = front[:, 0] * np.sqrt(2 * GRAVITY / WIDTH)
        Z = front[:, 1] / WIDTH
        history = np.column_stack([T, Z])
        experiment = references.dambreak_front("koshizuka_oka_1996_experiment")
        error = references.front_difference(history, experiment, T_min=0.0) if T[-1] >= 3.0 else None
        summary["front_rms_error_vs_koshizuka_oka"] = error
        if T[-1] >= 3.0:
            martin_moyce = references.dambreak_front("martin_moyce_1952_n2_2_a2.25in")
            summary["front_rms_error_vs_martin_moyce"] = references.front_difference(history, martin_moyce, T_min=0.0)
        output.write_json(folder / "summary.json", summary)
        plot_front(folder / "front.png", T, Z, error, summary)
    summary["front_rms_error_vs_koshizuka_oka"] = comm.bcast(error, root=0)


def plot_front(path, T, Z, error, summary):
    """Z against T with the experiments (the seed's Fig. 2a)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    label = f"fempm, {summary['scheme']} ({summary['basis']}, {summary['particles']} particles)"
    ax.plot(T, Z, "-", color="tab:blue", label=label)
    ko = references.dambreak_front("koshizuka_oka_1996_experiment")
    ax.plot(ko[:, 0], ko[:, 1], "o", color="black", label="Koshizuka & Oka 1996, experiment")
    for name, marker, label in (("martin_moyce_1952_n2_2_a2.25in", "s", "Martin & Moyce 1952, a = 2.25 in"),
                                ("martin_moyce_1952_n2_2_a1.125in", "^", "Martin & Moyce 1952, a = 1.125 in")):
        mm = references.dambreak_front(name)
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


# %% convergence and cost (benchmarks/report.py)
def study(full: bool = False) -> list:
    """Front error (T <= 3) against Koshizuka-Oka and wall time, against cells across the tank,
    particles per cell, time step and basis. In ``extra``: the error against Martin-Moyce and
    the RMS relative difference from the finest B-spline run (the numerical error; the
    experiments hold wall friction and a gate that slip walls leave out)."""
    import tempfile

    from fempm.verification import Measurement

    def one(cells=40, ppc=2, dt=1e-3, basis="bspline"):
        with tempfile.TemporaryDirectory() as folder:
            args, _ = parse_arguments(["--end-time", "0.28", "--cells", str(cells), "--ppc", str(ppc), "--dt", str(dt),
                                       "--basis", basis, "--no-files", "--quiet", "--out", folder])
            s = run(args)
            front = np.loadtxt(Path(folder) / "front.csv", delimiter=",", skiprows=2, ndmin=2)
        history = np.column_stack([front[:, 0] * np.sqrt(2 * GRAVITY / WIDTH), front[:, 1] / WIDTH])
        return Measurement("dam break", "MPM", BASES[basis].name, cells, dt, ppc**2,
                           s["front_rms_error_vs_koshizuka_oka"], s["wall_time_s"], s["status"], s.get("cause") or "",
                           {"martin_moyce": s.get("front_rms_error_vs_martin_moyce"), "pic_blend": args.pic,
                            "history": history})

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


def main(argv=None) -> int:
    """Run from the command line; exit status 1 if the run stopped early."""
    args, petsc_args = parse_arguments(argv)
    return report("dambreak", args, lambda: run(args, petsc_args))


def report(name: str, args, run_demo) -> int:
    """Call ``run_demo()`` and say on rank 0 how it ended: 0 completed, 1 stopped early, 2 bad input."""
    try:
        summary = run_demo()
    except FempmError as e:
        if MPI.COMM_WORLD.rank == 0:
            print(f"{name}: {e}", file=sys.stderr)
        return 2
    if MPI.COMM_WORLD.rank == 0:
        if summary["status"] != "completed":
            print(f"{name}: {summary['cause']}; the outputs up to then are in {args.out}", file=sys.stderr)
        else:
            err = summary["front_rms_error_vs_koshizuka_oka"]
            print(f"{name}: {summary['steps']} steps in {summary['wall_time_s']:.1f} s; front error vs "
                  f"experiment {'-' if err is None else f'{100 * err:.1f} %'}; results in {args.out}")
    return 0 if summary["status"] == "completed" else 1


if __name__ == "__main__":
    sys.exit(main())
