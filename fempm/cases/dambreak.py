"""The seed's dam break (Koshizuka & Oka 1996; method.md Figs. 1-4): its scene, its front and the references.

The set-up is the shipped scene ``scenes/dambreak.toml``: a 584 mm square tank, a water
column L = 146 mm wide and 2L high in its lower-left corner. :func:`scene` applies changes to
it given as dotted scene keys (``{"time.dt": 2e-3, "bodies.0.particles_per_cell": 9}``), so
that a command-line flag is one ``argparse`` line whose ``dest`` is the key it sets.

The surge front is compared in the dimensionless form ``T = t sqrt(2 g / L)``,
``Z = x / L`` (:func:`fempm.references.dimensionless_front`) with the converged interFoam
160 x 160 run (the accuracy measure, 0.3 < T <= 3), the Koshizuka-Oka experiment and
Martin & Moyce's (T <= 3; the experiments hold a gate and wall friction that slip walls
leave out).
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from collections.abc import Mapping
from dataclasses import asdict, replace
from math import sqrt
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import output, references
from fempm.errors import InputError
from fempm.explicit import ExplicitScheme, ExplicitSolver
from fempm.options import Physics, Scheme
from fempm.scene import Scene, parse_scene
from fempm.simulation import build_material, check_folder

__all__ = ["AUTO_SOUND_SPEED", "FREE_FALL", "GRAVITY", "HEIGHT", "SCENE", "SEED_PARTICLES", "SEED_PER_CELL", "SPLIT", "TANK", "WIDTH", "add_flags", "changes",
           "at_seed_setup", "compare_front", "explicit_solver", "flag_names", "front_measures", "petsc_options", "plot_front",
           "prepare_folder", "read_front", "scene", "seed_setup", "stop"]

#: the repository's scene (``scenes/`` is not installed with the package: a demo passes its own path)
SCENE = Path(__file__).resolve().parents[2] / "scenes" / "dambreak.toml"
WIDTH = references.DAMBREAK_COLUMN_WIDTH  #: L, the column's width, m
HEIGHT = 2 * WIDTH  #: the column's height, m
TANK = 4 * WIDTH  #: the square tank's side, m
GRAVITY = references.GRAVITY  #: m/s^2
SEED_DT = Scheme.dt  #: the seed's fixed step, 1 ms (the shipped scene's step adapts to the flow)
SEED_PER_CELL = 4  #: the seed's particles per cell, 2 x 2 (the shipped scene's too)
SEED_PARTICLES = {"bodies.0.particles_per_cell": SEED_PER_CELL}  #: the :func:`scene` change to the seed's particles
#: the :func:`scene` changes back to the shipped pressure handling of 2026-11-29/30: the hydrostatic pressure's work
#: alone by parts, each particle shifted on its own (the scene now takes the last step's pressure, turning shifts)
SPLIT = {"solver.pressure_work": "split", "solver.shifting_keeps_angular_momentum": False}
FREE_FALL = sqrt(2 * GRAVITY * HEIGHT)  #: the column's free-fall speed, the flow's largest, m/s
AUTO_SOUND_SPEED = 10 * FREE_FALL  #: the weakly compressible practice's artificial sound speed, m/s
#: the outputs ``files=False`` leaves out: ParaView series, pictures, checkpoints
FILES = ("particles_interval", "grid_interval", "snapshots", "final_snapshot", "checkpoint_interval")
#: the front history must reach this T for the measures (the front reaches the far wall at T ~ 3.1)
T_END = 3.0


def scene(changes: Mapping[str, object] | None = None, files: bool = True, source: str | Path = SCENE,
          names: Mapping[str, str] | None = None) -> Scene:
    """The shipped dam break with ``changes`` applied, checked as any scene is.

    Args:
        changes: dotted scene keys to values, e.g. ``{"time.end": 0.27, "domain.cells": [80, 80]}``;
            a number in the path indexes a list (``"bodies.0.particles_per_cell"``); the value
            None removes the key (``{"time.courant": None, "time.dt": 1e-3}``: a fixed step). A
            ``solver.forms`` ending in ``.py`` is a forms file of the user's own (code: it runs).
        files: False leaves out the :data:`FILES` (only the tables and summary are written).
        source: the scene file to start from.
        names: what to call the keys in messages (the flags that set them, :func:`flag_names`);
            given, messages come from the "command line", not the scene file.

    Raises:
        InputError: a value the scene does not accept (named by its key or flag).
    """
    changes = dict(changes or {})
    own = changes.get("solver.forms")
    own = changes.pop("solver.forms") if isinstance(own, str) and own.endswith(".py") else None
    data = tomllib.loads(Path(source).read_text())
    for key, value in changes.items():
        *path, last = key.split(".")
        table = data
        for part in path:
            table = table[int(part)] if isinstance(table, list) else table.setdefault(part, {})
        if value is None:
            table.pop(last, None)
        else:
            table[int(last) if isinstance(table, list) else last] = value
    if not files:
        for key in FILES:
            data["output"].pop(key, None)
    end = data.get("time", {}).get("end")
    if isinstance(end, int | float) and "snapshots" in data["output"]:  # a shorter run keeps the pictures it reaches
        data["output"]["snapshots"] = [t for t in data["output"]["snapshots"] if not t > end]
    return parse_scene(data, source="command line" if names else source, forms=own, names=names)


def seed_setup(dt: float = SEED_DT) -> dict[str, object]:
    """The :func:`scene` changes of the seed's set-up: a fixed step ``dt`` (the seed's 1 ms) and
    :data:`SEED_PER_CELL` particles per cell (the scene's own step adapts to the flow)."""
    return {"time.courant": None, "time.dt": dt, **SEED_PARTICLES}


def at_seed_setup(scene_: Scene, dt: float = SEED_DT) -> Scene:
    """``scene_`` in the seed's set-up (:func:`seed_setup` for a scene object): a fixed step ``dt``
    and :data:`SEED_PER_CELL` particles per cell in every body."""
    bodies = tuple(replace(b, particles_per_cell=SEED_PER_CELL) for b in scene_.bodies)
    return replace(scene_, time=replace(scene_.time, courant=None, dt=dt), bodies=bodies)


def flag_names(parser: argparse.ArgumentParser) -> dict[str, str]:
    """The scene keys a parser's flags set (their ``dest``), each named by its flag, for messages."""
    return {a.dest.replace(".0.", "[0]."): a.option_strings[0] for a in parser._actions
            if "." in a.dest and a.option_strings}


def prepare_folder(scene_: Scene, overwrite: bool, comm=MPI.COMM_WORLD):
    """The rule of ``fempm run`` for a demo's output folder: one holding an earlier run's files is
    refused (naming ``--out``) unless ``overwrite``, which removes those files and nothing else."""
    if check_folder(scene_.output.folder, comm, overwrite, key="--out"):
        output.remove_earlier_outputs(scene_.output.folder, comm)


def explicit_solver(scene_: Scene, comm=MPI.COMM_WORLD, **scheme) -> ExplicitSolver:
    """The explicit baseline (:class:`~fempm.explicit.ExplicitSolver`) on a dam-break scene's grid,
    water, fluid and walls; ``scheme``: fields of :class:`~fempm.explicit.ExplicitScheme` (its
    ``max_speed`` defaults to :data:`FREE_FALL`)."""
    physics = Physics(viscosity=scene_.fluid.viscosity, gravity=scene_.gravity, walls=asdict(scene_.walls))
    return ExplicitSolver(*build_material(scene_, comm), physics, ExplicitScheme(**{"max_speed": FREE_FALL, **scheme}))


def _cells(text: str) -> list[int]:
    """``--cells N``: N x N cells, N a multiple of 4 (the column is a quarter of the tank)."""
    n = int(text)
    if n < 4 or n % 4:
        raise argparse.ArgumentTypeError(f"must be a positive multiple of 4, got {text}")
    return [n, n]


def _forms(text: str) -> str:
    """``--forms``: a name of the shipped forms, or a ``.py`` file of the user's own (made absolute)."""
    return str(Path(text).resolve()) if text.endswith(".py") else text


def add_flags(parser: argparse.ArgumentParser):
    """The flags of the tank, the water and the outputs, which every dam-break demo has.

    Each flag's ``dest`` is the scene key it sets (:func:`changes` collects them); left out, a
    flag keeps the scene's value. ``--walls`` sets every side, ``--output-interval`` both
    ParaView series, ``--no-files`` is :func:`scene`'s ``files``.
    """
    flag = parser.add_argument
    flag("--end-time", dest="time.end", type=float, metavar="T", help="simulated time, s (scene: 1)")
    flag("--cells", dest="domain.cells", type=_cells, metavar="N", help="N x N cells (scene: 40)")
    flag("--ppc", dest="bodies.0.particles_per_cell", type=lambda n: int(n) ** 2, metavar="N",
         help="N x N particles per cell (scene: 4; the seed: 2)")
    flag("--basis", dest="solver.basis", choices=("bspline", "q1"), help="grid basis (scene: bspline)")
    flag("--walls", choices=("slip", "no-slip"), help="every wall (scene: slip)")
    flag("--viscosity", dest="fluid.viscosity", type=float, metavar="MU", help="Pa s (scene: 1e-3)")
    flag("--pic", dest="solver.pic_blend", type=float, metavar="SHARE", help="PIC share per step, 0..1 (scene: 0)")
    flag("--forms", dest="solver.forms", type=_forms, metavar="FORMS", help="weak forms: a forms/ name or a .py file")
    flag("--out", dest="output.folder", metavar="DIR", help="output folder")
    flag("--overwrite", action="store_true", help="replace an earlier run's files in the output folder")
    flag("--output-interval", type=float, metavar="S", help="ParaView series every S seconds (scene: 0.05)")
    flag("--no-files", dest="files", action="store_false", help="only the tables, front.png and summary.json")
    flag("--quiet", dest="output.progress", action="store_const", const=False, help="no progress line")


def changes(args: argparse.Namespace) -> dict[str, object]:
    """The scene keys the flags of ``args`` set (see :func:`add_flags`)."""
    out = {key: value for key, value in vars(args).items() if "." in key and value is not None}
    if getattr(args, "walls", None):
        out["walls"] = dict.fromkeys(("left", "right", "bottom", "top"), args.walls)
    if getattr(args, "output_interval", None):
        out["output.particles_interval"] = out["output.grid_interval"] = args.output_interval
    return out


def petsc_options(arguments) -> dict[str, str]:
    """``-fempm_name [value] ...`` as a table of PETSc options (a flag alone has the value "").

    Raises:
        InputError: an argument that is neither such an option nor its value.
    """
    table, arguments = {}, list(arguments)
    for k, arg in enumerate(arguments):
        if arg.startswith("-fempm_"):
            value = arguments[k + 1] if k + 1 < len(arguments) and not arguments[k + 1].startswith("-fempm_") else ""
            table[arg[len("-fempm_"):]] = value
        elif not (k and arguments[k - 1].startswith("-fempm_")):
            raise InputError(f"unrecognised argument {arg!r} (PETSc options take the prefix -fempm_)")
    return table


def read_front(folder: str | Path) -> np.ndarray:
    """The front history ``(T, Z)`` of a run's ``front.csv`` (t, x)."""
    t, x = np.loadtxt(Path(folder) / "front.csv", delimiter=",", skiprows=2, ndmin=2).T
    return references.dimensionless_front(t, x, WIDTH, GRAVITY)


def front_measures(front: np.ndarray) -> dict[str, float]:
    """A front history ``(T, Z)`` against the references, if it reaches T = 3 (else empty).

    ``front_difference_vs_interfoam_160``: RMS relative difference from interFoam 160 x 160 at
    its times in 0.3 < T <= 3 (:func:`fempm.references.front_difference`);
    ``front_rms_error_vs_koshizuka_oka`` and ``front_rms_error_vs_martin_moyce``: the same against
    the experiments' points with T <= 3.
    """
    if front[-1, 0] < T_END:
        return {}
    return {
        "front_difference_vs_interfoam_160": references.front_difference(front, references.interfoam_front(160)),
        "front_rms_error_vs_koshizuka_oka": references.front_difference(
            front, references.dambreak_front("koshizuka_oka_1996_experiment"), T_min=0.0),
        "front_rms_error_vs_martin_moyce": references.front_difference(
            front, references.dambreak_front("martin_moyce_1952_n2_2_a2.25in"), T_min=0.0),
    }


def compare_front(folder: str | Path, summary: dict, label: str, comm=MPI.COMM_WORLD) -> dict[str, float]:
    """A finished run's front (``front.csv`` in ``folder``) against the references: its
    :func:`front_measures`, the same on every rank, join ``summary`` and ``summary.json``, and
    ``front.png`` draws the front labelled ``label`` over the references (rank 0)."""
    front = comm.bcast(read_front(folder) if comm.rank == 0 else None, root=0)
    measures = front_measures(front)
    summary.update(measures)
    if comm.rank == 0:
        output.write_json(Path(folder) / "summary.json", summary)
        plot_front(Path(folder) / "front.png", front, label, measures)
    return measures


def plot_front(path: str | Path, front: np.ndarray, label: str, measures: Mapping[str, float]):
    """``Z`` against ``T`` over interFoam 160 x 160 and the experiments (the seed's Fig. 2a)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.plot(front[:, 0], front[:, 1], "-", color="tab:blue", label=label)
    foam = references.interfoam_front(160)
    ax.plot(foam[:, 0], foam[:, 1], "-", color="black", lw=1, label="interFoam 160 x 160 (converged)")
    ko = references.dambreak_front("koshizuka_oka_1996_experiment")
    ax.plot(ko[:, 0], ko[:, 1], "o", color="black", label="Koshizuka & Oka 1996, experiment")
    for name, marker, text in (("martin_moyce_1952_n2_2_a2.25in", "s", "Martin & Moyce 1952, a = 2.25 in"),
                               ("martin_moyce_1952_n2_2_a1.125in", "^", "Martin & Moyce 1952, a = 1.125 in")):
        mm = references.dambreak_front(name)
        ax.plot(mm[:, 0], mm[:, 1], marker, mfc="none", color="tab:gray", label=text)
    ax.set_xlim(0, 4.0)  # the front reaches the far wall (Z = 4) at T ~ 3.1
    ax.set_ylim(1, 4.2)
    ax.set_xlabel(r"$T = t\sqrt{2g/L}$")
    ax.set_ylabel(r"$Z = x_{front}/L$")
    if measures:
        ax.set_title(f"surge front, T <= 3: {100 * measures['front_difference_vs_interfoam_160']:.1f} % from "
                     f"interFoam 160², {100 * measures['front_rms_error_vs_koshizuka_oka']:.1f} % from the experiment",
                     fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    output.save_figure(fig, path, dpi=130)


def stop(program: str, message: str, status: int, comm=MPI.COMM_WORLD):
    """End a demo with ``program: message`` (rank 0) and exit ``status``: 1 the run failed, 2 bad input."""
    if comm.rank == 0:
        print(f"{program}: {message}", file=sys.stderr, flush=True)
    sys.exit(status)
