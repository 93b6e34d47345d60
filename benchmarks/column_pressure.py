"""Pressure quality in a settled column: particle pressure about rho g depth, implicit against explicit.

The dam break's column (146 x 292 mm, 800 particles) between the walls of a 146 mm wide tank
(10 x 40 cells, the dam break's h), released from rest with zero pressure: the implicit scheme
at dt = 1e-3 s and the explicit one at its CFL step with c0 = 10 sqrt(2 g H) and with water's
K = 2 GPa. A particle's hydrostatic pressure is rho g (H - y0), y0 its initial height (the
weight of the material above it, exact also for the compressible fluid). Neither scheme is
damped, so the scatter is given at the end, as its mean over the window's second half, and for
each particle's pressure averaged over that half. A section of ``docs/implicit-vs-explicit.md``::

    python benchmarks/column_pressure.py [--full]
"""

from __future__ import annotations

from math import sqrt
from pathlib import Path

import numpy as np
from mpi4py import MPI

import fempm
import pages
import schemes
from fempm import diagnostics
from fempm.explicit import ExplicitScheme, ExplicitSolver
from fempm.implicit import ImplicitSolver
from fempm.options import Scheme
from fempm.verification import advance
from schemes import C0, G, H, L, RHO, WATER_K, Windows


def column_particles() -> tuple[fempm.Basis, fempm.Particles]:
    """The dam break's column, 146 x 292 mm, held between the walls of a 146 mm wide tank."""
    grid = fempm.Grid.from_cells(MPI.COMM_WORLD, (0.0, 0.0), (L, schemes.dambreak.TANK), (10, 40))
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (L, H)), per_cell=2, density=RHO)
    return fempm.BSpline2(grid), water


def column_run(label: str, make_solver, window: float, samples: int = 100) -> dict:
    """Release the column from rest without pressure; follow its pressure and volume.

    Every ``window / samples`` seconds: the scatter of the particle pressure about
    rho g depth, the number of negative pressures and the surface height; over the
    second half of the window also each particle's mean pressure.
    """
    solver = make_solver(*column_particles())
    p = solver.particles
    ids = np.sort(p.id)
    hydrostatic = RHO * G * (H - p.x[np.argsort(p.id), 1])  # by id: rho g depth of the initial place
    surface0, volume0 = diagnostics.front_position(p, axis=1), p["volume"].sum()
    history, mean_pressure, averaged = [], np.zeros(len(ids)), 0
    next_sample = window / samples

    def by_id():
        out = np.empty(len(ids))
        out[np.searchsorted(ids, p.id)] = p["pressure"]
        return out

    def record(s):
        nonlocal next_sample, averaged
        if s.time >= 0.5 * window:
            mean_pressure[:] += by_id()
            averaged += 1
        if s.time >= next_sample - 0.5 * s.dt:
            history.append((s.time, float(np.std(by_id() - hydrostatic)), int(np.sum(p["pressure"] < 0)),
                            diagnostics.front_position(p, axis=1) / surface0 - 1))
            next_sample += window / samples

    stepped = advance(solver, window, record)
    status, cause, wall = stepped.status, stepped.cause, stepped.wall
    history = np.array(history)
    late = history[history[:, 0] >= 0.5 * window]
    result = {
        "label": label, "dt": solver.dt, "status": status, "cause": cause, "time": solver.time,
        "steps": solver.steps, "wall": wall, "history": history,
        "std": float(np.std(by_id() - hydrostatic)),
        "std_late": float(late[:, 1].mean()) if len(late) else float("nan"),
        "std_averaged": float(np.std(mean_pressure / max(averaged, 1) - hydrostatic)),
        "negative": int(np.sum(p["pressure"] < 0)), "negative_late": int(late[:, 2].max()) if len(late) else 0,
        "surface_drift": diagnostics.front_position(p, axis=1) / surface0 - 1,
        "volume_drift": p["volume"].sum() / volume0 - 1,
        "max_speed": float(np.linalg.norm(p["velocity"], axis=1).max()),
        "depth": hydrostatic / (RHO * G), "pressure": by_id(),
    }
    schemes.say(f"  {label:<38s} dt {result['dt']:8.2e} s  {status:9s} {solver.steps:7d} steps {wall:7.1f} s wall  "
        f"std {result['std']:8.1f} Pa (late mean {result['std_late']:.1f})  negative {result['negative']}  "
        f"surface drift {100 * result['surface_drift']:+.2f} %  {cause}")
    return result


def measure(w: Windows) -> list[dict]:
    """The column for ``w.column`` seconds: implicit, explicit c0, explicit K = 2 GPa."""
    schemes.say("settled column")
    speed = sqrt(2 * G * H)
    return [
        column_run("implicit dt = 1e-3 s", lambda b, p: ImplicitSolver(b, p, scheme=Scheme(dt=1e-3)), w.column),
        column_run("explicit c0 = 23.9 m/s, CFL step", lambda b, p: ExplicitSolver(
            b, p, scheme=ExplicitScheme(sound_speed=C0, max_speed=speed)), w.column),
        column_run("explicit K = 2 GPa, CFL step", lambda b, p: ExplicitSolver(
            b, p, scheme=ExplicitScheme(bulk_modulus=WATER_K, max_speed=speed)), w.column),
    ]


def plot(path: Path, columns: list[dict]):
    """Particle pressure against depth at the end (one panel per run), and the scatter against time."""
    plt = schemes.pyplot()
    fig, axes = plt.subplots(1, len(columns) + 1, figsize=(3.3 * (len(columns) + 1), 3.9))
    for ax, c in zip(axes, columns):
        ax.scatter(c["pressure"] / 1e3, c["depth"], s=4)
        depth = np.linspace(0, H, 2)
        ax.plot(RHO * G * depth / 1e3, depth, color="black", lw=1, label=r"$\rho g$ depth")
        ax.set_title(f"{c['label']}\nt = {c['time']:.3g} s", fontsize=8)
        ax.set_xlabel("particle pressure (kPa)")
        ax.set_ylabel("depth of the initial position (m)", fontsize=8)
        ax.invert_yaxis()
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    ax = axes[-1]
    for c in columns:
        ax.semilogy(c["history"][:, 0], c["history"][:, 1], label=c["label"])
    schemes.save(fig, path, ax, "t (s)", r"std of $p - \rho g$ depth (Pa)", legend=6)


def table(columns: list[dict]) -> str:
    def row(c: dict) -> list[str]:
        outcome = "ran the window" if c["status"] == "completed" else f"stopped: {c['cause']}"
        vol = "– (fixed by the scheme)" if c["label"].startswith("implicit") else f"{100 * c['volume_drift']:+.2f} %"
        return [c["label"], f"{c['dt']:.3g}", outcome, c["steps"], f"{c['wall']:.3g}", f"{c['std']:.4g}",
                f"{c['std_late']:.4g}", f"{c['std_averaged']:.4g}", f"{c['negative']} of 800 ({c['negative_late']})",
                f"{100 * c['surface_drift']:+.2f} %", vol, f"{c['max_speed']:.3g}"]

    return pages.table(["run", "dt (s)", "outcome", "steps", "wall (s)", "std of p − ρ g depth at the end (Pa)",
                        "its mean over the second half (Pa)",
                        "std of the particles' mean pressure over the second half (Pa)",
                        "negative pressures at the end (most at once, second half)", "surface height drift",
                        "particle volume drift", "largest speed at the end (m/s)"], map(row, columns))


def summary_sentences(columns: list[dict]) -> list[str]:
    """The closing note's sentences on the column, each number read from the runs."""
    implicit, *explicit = columns
    return [f"- Settled column, **{c['label']}**: pressure scatter about ρ g depth {c['std']:.3g} Pa "
            f"against {implicit['std']:.3g} Pa implicit at the end ({c['std_late']:.3g} against "
            f"{implicit['std_late']:.3g} Pa over the second half, {c['std_averaged']:.3g} against "
            f"{implicit['std_averaged']:.3g} Pa for each particle's pressure averaged over that half); "
            f"{c['negative']} negative particle "
            f"pressures at the end against {implicit['negative']}; surface drift "
            f"{100 * c['surface_drift']:+.2f} % against {100 * implicit['surface_drift']:+.2f} %."
            for c in explicit]


def report(w: Windows):
    """Measure and print the table and the closing sentences."""
    columns = measure(w)
    print(table(columns))
    print("\n".join(summary_sentences(columns)))


if __name__ == "__main__":
    schemes.run_alone(__doc__, report)
