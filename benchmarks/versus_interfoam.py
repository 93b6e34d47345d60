"""fempm against OpenFOAM's interFoam on the seed's dam break, side by side in one invocation.

Runs interFoam (``benchmarks/interfoam.py``: the same tank, column and walls, VOF with air)
at 40² and 80² cells (and 160² with ``--full``), and fempm's ``scenes/dambreak.toml`` as it
stands (2 x 2 particles per cell, an adaptive step, Courant 0.8, dt <= 10 ms, particle shifting) and
at Courant 1; without the shifting; at the seed's fixed step of 1 ms; with 4 x 4 particles per cell
at Courant 0.6; and at finer grids (60² and 80², Courant 1; 80² also at Courant 0.5), each to 2 s of
flow, one after the other on one core. The accuracy measure is the surge
front's RMS relative difference from interFoam's converged 160² front over 0.3 < T <= 3 (``fempm.references.front_difference``; the
stored reference, or this invocation's own 160² run with ``--full``), i.e. over the first
0.27 s. Prints a table (grid, steps, wall time, front difference) and each code's wall time
to reach a given front difference, interpolated log-log along its error-against-wall-time
curve, with the fempm / interFoam ratio; then alternates interFoam 40² and the scene
``HEAD_TO_HEAD`` times for the headline's ratio, whose single runs vary as much as the two codes
differ; records the load average at the start and the end. Writes ``docs/speed.md`` and ``docs/speed/error_vs_time.png``.

    python benchmarks/versus_interfoam.py [--full] [--quick] [--doc docs/speed.md]

``--quick``: interFoam 40² and fempm's scene to 0.27 s only, no page unless ``--doc`` is given
(a smoke run). interFoam's wall time is the interFoam process alone (not blockMesh or
setFields); fempm's is the whole ``run_scene`` call (grid, particles and compiled forms
included) and, beside it, its summary's ``wall_time_s`` (the steps alone), after a one-step run
that loads what a process loads once. Run serially.
When OpenFOAM is missing and cannot be installed, the interFoam runs are skipped with a
message and no page is written.
"""

from __future__ import annotations

import os

for _threads in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_threads, "1")  # one core per code: no threaded BLAS inside fempm's solve

import argparse  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from datetime import datetime, timezone  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

import interfoam  # noqa: E402
from fempm.output import atomic_path, save_figure  # noqa: E402
from fempm.references import dimensionless_front, front_difference, interfoam_front  # noqa: E402

SCENE = ROOT / "scenes" / "dambreak.toml"
END_TIME, QUICK_END_TIME = 2.0, 0.27     # s of flow; the front measure needs t <= 0.27 s
WARM_UP_TIME = 0.01                      # s of flow of the run before fempm's timed ones (one step)
HEAD_TO_HEAD = 5                         # pairs of interFoam 40² and the shipped scene, alternated, for the headline
TARGETS = (0.025, 0.012)                 # front differences at which the wall times are compared
FAST = {"courant": 1.0, "dt": 1e-2}      # an adaptive step: its Courant number and largest step
SMALL = {"courant": 0.6, "dt": 1e-2}     # a smaller adaptive step, for 4 x 4 particles per cell
HALF = {"courant": 0.5, "dt": 1e-2}
SEED_STEP = {"courant": None, "dt": 1e-3}  # the seed's fixed step (None leaves the scene's courant out)
UNSHIFTED = {"shifting": 0.0}            # the [solver] change: no particle shifting (fempm.shifting)
#: fempm's runs after the scene as it stands: (cells per side, particles per cell) or None for the
#: scene's 40² and 2 x 2 per cell (60²: the column 15 x 30 cells), the step (None: the scene's) and
#: the changes of [solver] (None: none)
FEMPM_RUNS = ((None, FAST, None), (None, None, UNSHIFTED), (None, SEED_STEP, None), ((40, 16), SMALL, None),
              ((60, 4), FAST, None), ((80, 4), FAST, None), ((80, 4), HALF, None))
STORED = (40, 80, 160)                   # grids of the stored interFoam fronts


@dataclass
class Row:
    """One run: ``wall_s`` is interFoam's process or fempm's whole call, ``cpu_s`` the CPU time of
    the same; ``steps_s`` fempm's steps alone (wall)."""

    code: str
    cells: int
    particles_per_cell: int | None
    steps: int
    wall_s: float
    cpu_s: float
    steps_s: float | None
    front: np.ndarray          # (T, Z)
    note: str = ""
    error: float | None = None
    step: str = ""             # fempm's step, short: "C 0.5" or "dt 0.001"


# -- the runs ----------------------------------------------------------------------------------------
def interfoam_row(cells: int, end_time: float) -> Row:
    """An interFoam run; its note gives the water volume drift and the front's difference from the
    stored run at the same grid (a check that this OpenFOAM reproduces the references)."""
    r = interfoam.run(cells, end_time)
    front = dimensionless_front(*r.front_t_x.T)
    note = f"water volume drift {r.volume_drift:+.1e}"
    if cells in STORED:
        note += f"; vs the stored {cells}² front {100 * front_difference(front, interfoam_front(cells)):.2f} %"
    return Row("interFoam", cells, None, r.steps, r.wall_s, r.cpu_s, None, front, note=note)


def fempm_row(end_time: float, cells: int | None = None, particles_per_cell: int | None = None,
              step: dict | None = None, solver: dict | None = None) -> Row:
    """The dam-break scene (its grid, particles, [time] and [solver] keys changed when given) run
    through the public API."""
    from fempm.scene import parse_scene
    from fempm.simulation import run_scene

    data = tomllib.loads(SCENE.read_text())
    if cells:
        data["domain"] = {**data["domain"], "cells": [cells, cells]}
        data["domain"].pop("cell_size", None)
    if particles_per_cell:
        data["bodies"] = [{**b, "particles_per_cell": particles_per_cell} for b in data["bodies"]]
    folder = Path(tempfile.mkdtemp(prefix="fempm-versus-interfoam-"))
    try:
        data["time"] = {k: v for k, v in {**data["time"], **(step or {}), "end": end_time}.items() if v is not None}
        data["solver"] = {**data["solver"], **(solver or {})}
        data["output"] = {"folder": str(folder), "progress": False}  # histories and summary only,
        data.pop("gauges", None)  # no gauges either (their plot alone costs a second or two)
        scene = parse_scene(data, source=SCENE)
        start, start_cpu = time.perf_counter(), time.process_time()
        summary = run_scene(scene, overwrite=True, progress=False)
        wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu
        lines = [line for line in (folder / "front.csv").read_text().splitlines() if not line.startswith("#")]
        t, x = np.loadtxt(lines[1:], delimiter=",", unpack=True)  # after the header line t,front_m
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    if summary["status"] != "completed":
        print(f"versus_interfoam: fempm run ended {summary['status']}: {summary['cause']}", flush=True)
    return Row("fempm", scene.domain.shape[0], scene.bodies[0].particles_per_cell, summary["steps"], wall, cpu,
               summary["wall_time_s"], dimensionless_front(t, x),
               note=_step_note(scene.time) + ("" if scene.solver.shifting else ", no shifting")
               + f"; {summary['particles']} particles",
               step=f"C {scene.time.courant:g}" if scene.time.courant else f"dt {scene.time.dt:g}")


def _step_note(t) -> str:
    return f"adaptive step, C = {t.courant:g}, dt <= {t.dt:g} s" if t.courant else f"fixed step {t.dt:g} s"


# -- equal error -----------------------------------------------------------------------------------
def wall_at_error(rows: list[Row], error: float, time_of=lambda r: r.wall_s) -> tuple[float | None, str]:
    """Time (``time_of`` a run, default its wall time) at which a code's error-against-time curve
    reaches ``error``, and a mark: linear in log-log between consecutive runs (by time), the
    cheapest bracketing pair (mark ``""``); below every run's error, the finest pair's line
    extrapolated (``"*"``); above every run's error, the cheapest run's time, an upper bound (``"≤"``)."""
    pts = sorted((time_of(r), r.error) for r in rows if r.error and r.error > 0)
    if len(pts) < 2:
        return None, ""
    lw, le = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    e = math.log(error)
    for k in range(len(pts) - 1):
        if min(le[k], le[k + 1]) <= e <= max(le[k], le[k + 1]) and le[k] != le[k + 1]:
            return float(np.exp(lw[k] + (e - le[k]) * (lw[k + 1] - lw[k]) / (le[k + 1] - le[k]))), ""
    if e > le.max():
        return pts[0][0], "≤"
    k = len(pts) - 2
    if le[k] == le[k + 1]:
        return None, "*"
    return float(np.exp(lw[k] + (e - le[k]) * (lw[k + 1] - lw[k]) / (le[k + 1] - le[k]))), "*"


def equal_error(rows: list[Row]) -> list[tuple]:
    """Per target: (target, then (time, mark) of interFoam's wall, fempm's call, fempm's steps,
    interFoam's CPU, fempm's call CPU)."""
    foam = [r for r in rows if r.code == "interFoam"]
    mpm = [r for r in rows if r.code == "fempm"]
    cpu = lambda r: r.cpu_s  # noqa: E731
    return [(e, wall_at_error(foam, e), wall_at_error(mpm, e), wall_at_error(mpm, e, lambda r: r.steps_s),
             wall_at_error(foam, e, cpu), wall_at_error(mpm, e, cpu)) for e in TARGETS]


# -- the outputs --------------------------------------------------------------------------------------
def _seconds(value: float | None, mark: str = "") -> str:
    return "n/a" if value is None else ("≤ " if mark == "≤" else "") + f"{value:.1f}" + ("*" if mark == "*" else "")


def _ratio(a: float | None, b: float | None) -> str:
    return "n/a" if a is None or b is None else f"{a / b:.1f}"


def tables(rows: list[Row], reference: str) -> str:
    """The runs and the equal-error comparison as Markdown tables."""
    lines = ["| code | grid | particles per cell | steps | wall time (s) | CPU time (s) | fempm steps alone (s) | "
             f"front vs {reference} | note |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        err = "reference" if r.error is None else f"{100 * r.error:.2f} %"
        lines.append(f"| {r.code} | {r.cells}² | {r.particles_per_cell or '—'} | {r.steps} | {r.wall_s:.1f} | "
                     f"{r.cpu_s:.1f} | {_seconds(r.steps_s) if r.steps_s else '—'} | {err} | {r.note} |")
    lines += ["", "| front difference | interFoam wall (s) | fempm wall, whole call (s) | fempm / interFoam | "
              "fempm wall, steps alone (s) | fempm / interFoam | CPU time: fempm call / interFoam |",
              "|---|---|---|---|---|---|---|"]
    for e, foam, call, steps, foam_cpu, call_cpu in equal_error(rows):
        lines.append(f"| {100 * e:.1f} % | {_seconds(*foam)} | {_seconds(*call)} | {_ratio(call[0], foam[0])} | "
                     f"{_seconds(*steps)} | {_ratio(steps[0], foam[0])} | {_ratio(call_cpu[0], foam_cpu[0])} |")
    return "\n".join(lines)


def _fastest_to_each_error(runs: list[Row]) -> list[Row]:
    """The runs, by wall time, each with a smaller error than every faster one (the front of
    error against time that the line joins)."""
    front = []
    for r in sorted(runs, key=lambda r: r.wall_s):
        if not front or r.error < front[-1].error:
            front.append(r)
    return front


def plot(rows: list[Row], path: Path, reference: str):
    """Front difference against wall time, log-log: every run a marker, each code's line joining
    the runs that reach a smaller error than any faster run of the same code."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.2, 4.8))
    for code, colour, marker in (("interFoam", "C0", "s"), ("fempm", "C1", "o")):
        runs = sorted((r for r in rows if r.code == code and r.error), key=lambda r: r.wall_s)
        if runs:
            ax.plot([r.wall_s for r in runs], [100 * r.error for r in runs], marker, color=colour,
                    label=f"{code}, wall time")
            ax.plot([r.cpu_s for r in runs], [100 * r.error for r in runs], marker, color=colour, mfc="none",
                    label=f"{code}, CPU time")
            best = _fastest_to_each_error(runs)  # the runs no other run beats in both time and error
            ax.plot([r.wall_s for r in best], [100 * r.error for r in best], "-", color=colour, lw=1)
            for i, r in enumerate(runs):
                per_cell = f" {math.isqrt(r.particles_per_cell)}×{math.isqrt(r.particles_per_cell)}" \
                    if r.particles_per_cell else ""
                ax.annotate(f"{r.cells}²{per_cell}" + (f", {r.step}" if r.step else ""), (r.wall_s, 100 * r.error),
                            textcoords="offset points", xytext=(5, 4 if i % 2 else -10), fontsize=7)
    for e in TARGETS:
        ax.axhline(100 * e, color="grey", lw=0.6, ls=":")
    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):  # ticks at 1, 2, 5 per decade, as plain numbers
        axis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("time for the run, one core (s)")
    ax.set_ylabel(f"front difference vs {reference} (%)")
    ax.set_title("seed's dam break: error against wall time")
    ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path)


PAGE = """# Speed: fempm against interFoam on the seed's dam break

Generated by `{command}` on {date} ({machine}).
Load average (1, 5, 15 min): {load_start} at the start, {load_end} at the end.
Both codes ran in this one invocation, one after the other, one core each; wall times are
comparable only within the page.

The case is `scenes/dambreak.toml` (0.584 m square closed tank, slip walls, water column
0.146 × 0.292 m), to {end_time:g} s of flow. interFoam (OpenFOAM v1912, Debian's `openfoam`,
`benchmarks/interfoam.py`) solves it with air above the water, the damBreak tutorial's schemes and
adjustable step (maxCo 1); its wall time is the interFoam process alone. fempm runs the scene through
`fempm.simulation.run_scene`; its wall time is the whole call (grid, particles, compiled forms
included) and, beside it, its summary's `wall_time_s` (the steps alone). CPU time (interFoam's own
`ExecutionTime`, fempm's process CPU time over the call) depends less on the machine's load.
Before fempm's rows a run of one step loads what a Python process loads once (UFL's first
derivation of the forms, numba's cached kernels), so that every fempm row is timed alike; like
Python's imports, that loading (under a second) is in no row.

The front difference is `fempm.references.front_difference` against
{reference_long}:
the RMS relative difference of the surge front over 0.3 < T ≤ 3 (T = t √(2g/L), L = 0.146 m),
i.e. over the first 0.27 s.

{tables}

The second table gives each code's time to reach a front difference, interpolated linearly in
log-log between its runs (* extrapolated beyond its finest runs, along their line; ≤ every run of the
code is within the difference already: its cheapest run's time, an upper bound).

![front difference against wall time]({figure})

## The headline, repeated

One run of each code varies by a few tenths of a second on this shared machine, so a single pair
can mislead. After the runs above, interFoam 40² and the shipped scene alternate
{pairs} times, each pair one right after the other (wall times; the scene's whole call):

{head_to_head}
"""


def write_page(path: Path, rows: list[Row], reference: str, reference_long: str, argv: list[str],
               loads: tuple, end_time: float, pairs: list[tuple[float, float]]):
    figure = path.parent / path.stem / "error_vs_time.png"
    plot(rows, figure, reference)
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor()) if Path("/proc/cpuinfo").exists() else ""
    page = PAGE.format(
        command=" ".join(["python benchmarks/versus_interfoam.py", *argv]),
        date=datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        machine=f"{cpu}, {os.cpu_count()} cores", load_start=_load(loads[0]), load_end=_load(loads[1]),
        end_time=end_time, reference_long=reference_long, tables=tables(rows, reference),
        head_to_head=head_to_head(pairs) or "Not run (`--quick`).", pairs=HEAD_TO_HEAD,
        figure=figure.relative_to(path.parent).as_posix())
    with atomic_path(path) as tmp:
        tmp.write_text(page)


def _load(load: tuple) -> str:
    return ", ".join(f"{v:.2f}" for v in load)


# -- main -------------------------------------------------------------------------------------------
def run_all(quick: bool, full: bool) -> tuple[list[Row], str, str, str | None, list[tuple[float, float]]]:
    """All runs, their errors set; also the reference's short and long names, why interFoam was
    skipped (None when it ran), and the head-to-head pairs' wall times (interFoam 40², the scene)."""
    end_time = QUICK_END_TIME if quick else END_TIME
    skipped = interfoam.ensure_openfoam()
    if skipped:
        print(f"versus_interfoam: interFoam runs skipped: {skipped}", flush=True)
    foam_cells = [] if skipped else [40] if quick else [40, 80, 160] if full else [40, 80]
    rows = []
    for cells in foam_cells:
        rows.append(interfoam_row(cells, end_time))
        print(f"versus_interfoam: interFoam {cells}²: {rows[-1].steps} steps, {rows[-1].wall_s:.1f} s", flush=True)
    fempm_row(WARM_UP_TIME)  # the process's one-off loading, which every later run finds done
    rows.append(fempm_row(end_time))
    if not quick:
        for grid, step, solver in FEMPM_RUNS:
            rows.append(fempm_row(end_time, *(grid or (None, None)), step=step, solver=solver))
    reference = "interFoam 160²"
    ref, reference_long = interfoam_front(160), "the stored interFoam 160² front (`fempm.references.interfoam_front(160)`)"
    if full and not skipped:
        own = next(r for r in rows if r.code == "interFoam" and r.cells == 160)
        ref, reference_long = own.front, "this invocation's own interFoam 160² run"
    for r in rows:
        if not (full and r.code == "interFoam" and r.cells == 160 and not skipped):
            r.error = front_difference(r.front, ref)
    pairs = [] if quick or skipped else [head_to_head_pair(end_time) for _ in range(HEAD_TO_HEAD)]
    return rows, reference, reference_long, skipped, pairs


def head_to_head_pair(end_time: float) -> tuple[float, float]:
    """Wall times of interFoam 40² and of the shipped scene, run one right after the other."""
    foam, scene = interfoam_row(40, end_time).wall_s, fempm_row(end_time).wall_s
    print(f"versus_interfoam: head to head: interFoam 40² {foam:.2f} s, the scene {scene:.2f} s", flush=True)
    return foam, scene


def head_to_head(pairs: list[tuple[float, float]]) -> str:
    """The pairs' table and the median of their ratios (empty without pairs)."""
    if not pairs:
        return ""
    ratios = [scene / foam for foam, scene in pairs]
    lines = ["| pair | interFoam 40² wall (s) | fempm scene wall (s) | fempm / interFoam |", "|---|---|---|---|"]
    lines += [f"| {i + 1} | {foam:.2f} | {scene:.2f} | {scene / foam:.2f} |" for i, (foam, scene) in enumerate(pairs)]
    return "\n".join(lines + ["", f"Median ratio {np.median(ratios):.2f} (range {min(ratios):.2f}–{max(ratios):.2f})."])


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full", action="store_true", help="also interFoam 160², the reference of this run")
    parser.add_argument("--quick", action="store_true", help="interFoam 40² and fempm's scene to 0.27 s (smoke run)")
    parser.add_argument("--doc", type=Path, help="page to write (default docs/speed.md; none with --quick); "
                                                 "its figure goes to <folder>/<page name>/error_vs_time.png")
    args = parser.parse_args(argv)
    if args.full and args.quick:
        print("versus_interfoam: --full and --quick exclude each other", file=sys.stderr)
        return 2
    from mpi4py import MPI

    if MPI.COMM_WORLD.size > 1:
        print("versus_interfoam: run serially (one core per code), not under mpirun", file=sys.stderr)
        return 2
    doc = args.doc or (None if args.quick else ROOT / "docs" / "speed.md")
    if doc and (doc.is_dir() or doc.suffix != ".md"):
        print(f"versus_interfoam: --doc {doc}: expected the path of a Markdown page (*.md)", file=sys.stderr)
        return 2
    load_start = os.getloadavg()
    rows, reference, reference_long, skipped, pairs = run_all(args.quick, args.full)
    load_end = os.getloadavg()
    print(tables(rows, reference))
    print(head_to_head(pairs))
    print(f"load average (1, 5, 15 min): {_load(load_start)} at the start, {_load(load_end)} at the end")
    if doc and skipped:
        print(f"versus_interfoam: no page written (interFoam skipped): {doc}")
    elif doc:
        write_page(doc, rows, reference, reference_long, argv, (load_start, load_end),
                   QUICK_END_TIME if args.quick else END_TIME, pairs)
        print(f"versus_interfoam: wrote {doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
