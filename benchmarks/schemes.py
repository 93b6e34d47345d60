"""What the implicit-against-explicit measurements share: the seed's dam break run by either scheme.

``benchmarks/stability_map.py``, ``explicit_time_step.py``, ``speed_error.py`` and
``column_pressure.py`` each measure one thing; ``implicit_vs_explicit.py`` runs them in one
process and writes ``docs/implicit-vs-explicit.md``. A dam-break run (:func:`dambreak_run`) is
kept by its set-up, so that the measurements that share a run (the stability map and the speed
table share the implicit runs) step it once per process.

Wall time is that of the steps alone (set-up and compilation excluded, every solver kind warmed
up first by :func:`warm_up`), measured by ``time.perf_counter``.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from math import sqrt
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import diagnostics, output, references
from fempm.cases import dambreak
from fempm.explicit import ExplicitScheme
from fempm.particles import Particles
from fempm.simulation import build_solver
from fempm.verification import advance

__all__ = ["C0", "FULL", "SHORT", "Run", "Windows", "dambreak_run", "pct", "pyplot", "run_alone", "save", "two_seconds",
           "warm_up"]

G, L, H, RHO = dambreak.GRAVITY, dambreak.WIDTH, dambreak.HEIGHT, 1000.0
C0 = dambreak.AUTO_SOUND_SPEED
WATER_K = ExplicitScheme.bulk_modulus  # 2 GPa
T_SCALE = sqrt(2 * G / L)  # T = t sqrt(2 g / L)
FLOW_SECONDS = 2.0  # the seed's wall-time measure: 2 s of flow
CELL = dambreak.TANK / 40  # h of the seed's grid
EXPERIMENT = references.dambreak_front("koshizuka_oka_1996_experiment")


@dataclass
class Windows:
    """Simulated seconds each kind of run covers."""

    dambreak: float  # implicit, explicit c0, explicit K = 2 GPa at its CFL step and at 1e-5 s
    tiny_dt: float  # explicit K = 2 GPa at 1e-6 s
    cfl_scan: float  # explicit c0 at several safety factors
    column: float  # the settled column


#: default: T <= 3 is covered (a few minutes); --full: 2 s of flow, the seed's measure (tens of minutes)
SHORT = Windows(dambreak=0.26, tiny_dt=0.005, cfl_scan=0.5, column=0.25)
FULL = Windows(dambreak=2.0, tiny_dt=0.05, cfl_scan=2.0, column=1.0)


@dataclass
class Run:
    """One dam-break run: what it was, how far it got, what it cost, how its front compares."""

    label: str
    scheme: str
    dt: float
    window: float
    status: str = "completed"
    cause: str = ""
    time: float = 0.0
    steps: int = 0
    wall: float = 0.0
    front: list = field(default_factory=list)
    error: float | None = None
    pressure: tuple[float, float] = (0.0, 0.0)
    particles: Particles | None = field(default=None, repr=False)  # as the run left them

    @property
    def wall_per_second(self) -> float:
        """Wall seconds per simulated second."""
        return self.wall / self.time if self.time > 0 else float("nan")

    @property
    def ms_per_step(self) -> float:
        return 1e3 * self.wall / max(self.steps, 1)

    def picture(self, path: Path):
        """The particles at the end of the run, coloured by pressure (0 to rho g H)."""
        output.snapshot(path, self.particles, title=f"{self.label}, t = {self.time:.3f} s", clim=(0.0, RHO * G * H))


def say(message: str):
    print(message, flush=True)


def solver(scheme: str, **options):
    """The seed's dam break: ``"implicit"`` at ``dt``, or ``"explicit"`` with ExplicitScheme ``options``."""
    if scheme == "implicit":
        return build_solver(dambreak.scene(dambreak.seed_setup(options["dt"]), files=False), MPI.COMM_WORLD)
    return dambreak.explicit_solver(dambreak.scene(files=False), MPI.COMM_WORLD, **options)


_runs: dict[tuple, Run] = {}


def dambreak_run(label: str, scheme: str, window: float, **options) -> Run:
    """Run the dam break of :func:`solver` for ``window`` simulated seconds, recording the front
    every step; kept by its set-up, so that asking again returns the same run."""
    key = (label, scheme, window, tuple(sorted(options.items())))
    if key in _runs:
        return _runs[key]
    s = solver(scheme, **options)
    run = Run(label, scheme, s.dt, window)
    run.front.append((0.0, diagnostics.front_position(s.particles)))
    low, high = np.inf, -np.inf

    def record(s):
        nonlocal low, high
        run.front.append((s.time, diagnostics.front_position(s.particles)))
        p_low, p_high = diagnostics.pressure_range(s.particles)
        low, high = min(low, p_low), max(high, p_high)

    stepped = advance(s, window, record)
    run.status, run.cause, run.wall = stepped.status, stepped.cause, stepped.wall
    run.time, run.steps, run.pressure, run.particles = s.time, s.steps, (low, high), s.particles
    front = np.array(run.front)
    if front[-1, 0] * T_SCALE >= 3.0:
        run.error = references.front_difference(np.column_stack([front[:, 0] * T_SCALE, front[:, 1] / L]), EXPERIMENT,
                                                T_min=0.0)
    say(f"  {label:<38s} dt {run.dt:8.2e} s  {run.status:9s} t = {run.time:7.4f} s  {run.steps:7d} steps  "
        f"{run.wall:8.1f} s wall  {run.ms_per_step:6.2f} ms/step  error "
        f"{'-' if run.error is None else f'{100 * run.error:.1f} %'}  {run.cause}")
    _runs[key] = run
    return run


def warm_up():
    """A few steps of each solver kind, so that no measured run pays for loading compiled code."""
    for s in (solver("implicit", dt=1e-3), solver("explicit", sound_speed=C0)):
        advance(s, 3 * s.dt)


def pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.1f} %"


def two_seconds(r: Run) -> str:
    """Wall time of 2 s of flow: measured if the run covered them, else extrapolated (marked *)."""
    if r.status != "completed":
        return "–"
    value = r.wall_per_second * FLOW_SECONDS
    return f"{value:.4g}" + ("" if r.time >= FLOW_SECONDS - 0.5 * r.dt else " *")


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path: Path, ax=None, xlabel: str = "", ylabel: str = "", legend: float = 7):
    """Label ``ax`` (axes, grid, legend) if given, lay out and write the figure."""
    if ax is not None:
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=legend)
    fig.tight_layout()
    output.save_figure(fig, path, dpi=120)


def run_alone(description: str, report):
    """A measurement run by itself: ``--full`` chooses the windows, every solver kind is warmed up,
    then ``report(windows)`` measures and prints."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full", action="store_true", help="the long windows (tens of minutes)")
    args = parser.parse_args()
    warm_up()
    report(FULL if args.full else SHORT)
