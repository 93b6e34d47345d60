"""Still water: does water at rest stay at rest, and does settling water move as it should? (issue 11)

Both studies run the shipped scene's step and solver (``scenes/dambreak.toml``: Courant 0.8, dt at
most 10 ms, affine-FLIP, particle shifting with turning shifts, the surface-aware volume correction, the last
step's pressure's work by parts, ``solver.pressure_work = "increment"``) and five of its options: the hydrostatic
pressure's work alone split off (``"split"``, each particle shifted on its own: the shipped scene's until
2026-11-30), the divergence form (``"divergence"``, method.md's), with it ``solver.transfer = "flip"`` and
``solver.pressure_quadrature = "gauss"``, and ``solver.pressure_work = "by-parts"``:

* ``rest``: the dam break's column (L = 146 mm wide, 2L deep, 2 x 2 particles per cell) in a tank as
  wide as it (10 x 40 cells), its particles moved at random before the first step by at most a share
  ``a`` of their spacing (uniform in each coordinate, a fixed seed; ``a = 0``: the seeding lattice);
  and, from the lattice, the column half a cell less deep (its surface half-way up a cell), the column held by a block in place of the gate (the dam-break tank's right
  three quarters blocked 30 cells high) and water 20 cells deep over a block 4 cells high in the right
  half of a tank twice as wide as the column. Each reports its fastest particle at 1, 2 and 4 s.
* ``settling``: the dam break from 10 to 20 s of flow, the water's mean speed every 0.5 s (fempm: the
  particles' mean ``|v|``; interFoam: ``|U|`` averaged over the water, weighted by ``alpha.water``,
  :func:`interfoam.read_water_speed`) against interFoam 40² and 80² (``--no-interfoam``: without).

Writes ``docs/still-water.md`` and its figure with ``--page`` (template
``benchmarks/templates/still-water.md``); else prints the tables::

    python benchmarks/still_water.py [--page] [--no-interfoam]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

import interfoam
import pages
from fempm import output
from fempm.cases import column, dambreak
from fempm.errors import SimulationDiverged
from fempm.simulation import build_solver

#: the variants each study runs: label -> scene changes
DIVERGENCE = {"solver.pressure_work": "divergence"}  #: method.md's -p div w, the shipped scene's until 2026-11-29
VARIANTS = {"shipped": {}, "the split": dambreak.SPLIT, "divergence form": DIVERGENCE,
            "FLIP": {"solver.transfer": "flip", **DIVERGENCE},
            "Gauss option": {"solver.pressure_quadrature": "gauss", **DIVERGENCE},
            "work by parts": {"solver.pressure_work": "by-parts"}}
#: shares of the particle spacing the column's particles are moved by (0: the lattice)
DISORDER = (0.0, 1e-5, 1e-4, 1e-3, 0.3)
REST_TIMES = (1.0, 2.0, 4.0)  #: s, when the rest study reads the fastest particle
SETTLING = np.arange(10.0, 20.0 + 1e-9, 0.5)  #: s, when the settling study reads the mean speed
WIDTH, DEPTH = column.WIDTH, column.HEIGHT
H = WIDTH / 10  #: the cell size of both studies' grids
#: the rest study's containers: label -> scene changes (with the variant's)
CONTAINERS = {
    "column": {"domain.upper": [WIDTH, 4 * WIDTH], "domain.cells": [10, 40], "bodies.0.upper": [WIDTH, DEPTH]},
    "column, its surface half-way up a cell": {"domain.upper": [WIDTH, 4 * WIDTH], "domain.cells": [10, 40],
                                               "bodies.0.upper": [WIDTH, DEPTH - H / 2]},
    "column held by a block": {"obstacles": [{"shape": "rectangle", "lower": [WIDTH, 0.0], "upper": [4 * WIDTH, 30 * H]}]},
    "water over a block": {
        "domain.upper": [2 * WIDTH, 4 * WIDTH], "domain.cells": [20, 40],
        "bodies": [{"shape": "rectangle", "lower": [0.0, 0.0], "upper": [WIDTH, DEPTH]},
                   {"shape": "rectangle", "lower": [WIDTH, 4 * H], "upper": [2 * WIDTH, DEPTH]}],
        "obstacles": [{"shape": "rectangle", "lower": [WIDTH, 0.0], "upper": [2 * WIDTH, 4 * H]}]},
}


def disorder(solver, share: float, seed: int = 1):
    """Move every particle by at most ``share`` of the spacing in each coordinate, at random (kept in the tank)."""
    if share == 0.0:
        return
    particles = solver.particles
    spacing = float(np.sqrt(np.median(particles["volume"])))
    moved = particles.x + share * spacing * np.random.default_rng(seed).uniform(-1.0, 1.0, particles.x.shape)
    particles.fields["x"] = solver.walls.keep_inside(moved)


def fastest_at(container: str, variant: str, share: float) -> list[str]:
    """The fastest particle (m/s) at each of :data:`REST_TIMES` (or where the run stopped)."""
    changes = {"gauges": None, "time.end": REST_TIMES[-1], **CONTAINERS[container], **VARIANTS[variant]}
    solver = build_solver(dambreak.scene(changes, files=False), MPI.COMM_WORLD)
    disorder(solver, share)
    cells = []
    for t in REST_TIMES:
        try:
            while solver.time < t - 1e-9:
                solver.step(until=t)
        except SimulationDiverged as stopped:
            return cells + [f"stopped at {stopped.time:.2f} s"] * (len(REST_TIMES) - len(cells))
        cells.append(f"{solver.fastest():.1e}")
    return cells


def rest_rows() -> list[list[str]]:
    """The rest study's rows: each variant on the column at every share of :data:`DISORDER`, then on the blocks."""
    rows = []
    for variant in VARIANTS:
        for share in DISORDER:
            rows.append(["column", f"{share:g}" if share else "0 (the lattice)", variant,
                         *fastest_at("column", variant, share)])
        for container in ("column, its surface half-way up a cell", "column held by a block", "water over a block"):
            rows.append([container, "0 (the lattice)", variant, *fastest_at(container, variant, 0.0)])
    return rows


def fempm_settling(variant: str, step: float = 0.1) -> np.ndarray:
    """``(t, mean speed)`` of the dam break to the last of :data:`SETTLING`, every ``step`` s."""
    end = float(SETTLING[-1])
    solver = build_solver(dambreak.scene({"gauges": None, "time.end": end, **VARIANTS[variant]}, files=False),
                          MPI.COMM_WORLD)
    series = []
    for t in np.arange(step, end + 1e-9, step):
        while solver.time < t - 1e-9:
            solver.step(until=t)
        series.append((solver.time, float(np.linalg.norm(solver.particles["velocity"], axis=1).mean())))
    return np.array(series)


def settling_rows(runs: dict[str, tuple[np.ndarray, float]], reference: str) -> list[list[str]]:
    """Per run: the mean of its mean speed at the :data:`SETTLING` times (interpolated), over the ``reference``
    run's ("" without it), the range, and the wall time."""
    means = {label: np.interp(SETTLING, series[:, 0], series[:, 1]) for label, (series, _) in runs.items()}
    rows = []
    for label, (_, wall) in runs.items():
        sampled = means[label]
        ratio = f"{sampled.mean() / means[reference].mean():.2f}" if reference in means else ""
        rows.append([label, f"{sampled.mean():.3f}", ratio, f"{sampled.min():.3f}–{sampled.max():.3f}", f"{wall:.0f}"])
    return rows


def plot(path: Path, runs: dict[str, np.ndarray]):
    """The water's mean speed against time, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.5))
    for label, series in runs.items():
        style = "k-" if label.startswith("interFoam 80") else "-"
        ax.plot(series[:, 0], series[:, 1], style, lw=0.8 if "interFoam" in label else 1.0, label=label)
    ax.axvspan(SETTLING[0], SETTLING[-1], color="0.93")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("the water's mean speed (m/s)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    output.save_figure(fig, path)


REFERENCE = "interFoam 80²"  #: the settling study's reference run


def settling(with_interfoam: bool) -> tuple[dict[str, tuple[np.ndarray, float]], str]:
    """The settling study's runs (label: the ``(t, mean speed)`` series and the wall time) and a note on
    interFoam (why it is missing, if it is)."""
    runs = {}
    note = (interfoam.ensure_openfoam() or "") if with_interfoam else "--no-interfoam"
    for cells in (80, 40) if not note else ():
        run = interfoam.run(cells, float(SETTLING[-1]), water_speed=True)
        runs[f"interFoam {cells}²"] = (run.water_speed, run.wall_s)
    for variant in VARIANTS:
        start = time.perf_counter()
        series = fempm_settling(variant)
        runs[f"fempm 40², {variant}"] = (series, time.perf_counter() - start)
    return runs, note


REST_HEAD = ["water", "particles moved by (share of their spacing)", "scheme",
             *[f"fastest at {t:g} s (m/s)" for t in REST_TIMES]]
SETTLING_HEAD = ["run", f"mean speed, {SETTLING[0]:g}–{SETTLING[-1]:g} s (m/s)", f"over {REFERENCE}'s", "its range",
                 "wall (s)"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--page", action="store_true", help="write docs/still-water.md and its figure")
    parser.add_argument("--no-interfoam", action="store_true", help="the settling study without interFoam")
    args = parser.parse_args(argv)
    rest = pages.table(REST_HEAD, rest_rows())
    runs, note = settling(not args.no_interfoam)
    settled = pages.table(SETTLING_HEAD, settling_rows(runs, REFERENCE))
    if not args.page:
        print(rest, settled, note, sep="\n\n")
        return 0
    folder = pages.ROOT / "docs" / "still-water"
    folder.mkdir(exist_ok=True)
    plot(folder / "settling.png", {label: series for label, (series, _) in runs.items()})
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    text = pages.fill("still-water.md", **pages.provenance(), command="python benchmarks/still_water.py --page",
                      load=load, rest=rest, settling=settled,
                      interfoam_note=f"(interFoam not run: {note})" if note else "")
    pages.write(pages.ROOT / "docs" / "still-water.md", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
