"""Stability map of the dam break: which time steps each scheme survives, and when and why the others stop.

The implicit scheme at dt = 5e-3, 2e-3, 1e-3 and 5e-4 s, the explicit one with water's bulk
modulus (K = 2 GPa) at 1e-3, 1e-4, 1e-5 and 1e-6 s (the seed: the first three diverged, 1e-6
ran), each for the window of :mod:`schemes`. A section of ``docs/implicit-vs-explicit.md``::

    python benchmarks/stability_map.py [--full]
"""

from __future__ import annotations

from math import sqrt
from pathlib import Path

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
import pages
import schemes
from schemes import RHO, WATER_K, Run, Windows

IMPLICIT_STEPS = (5e-3, 2e-3, 1e-3, 5e-4)
EXPLICIT_STEPS = (1e-3, 1e-4, 1e-5, 1e-6)


def measure(w: Windows) -> dict[str, list[Run]]:
    """The implicit runs and the explicit K = 2 GPa runs at the map's steps."""
    schemes.say("implicit dam break")
    implicit = [schemes.dambreak_run(f"implicit dt = {dt:g} s", "implicit", w.dambreak, dt=dt) for dt in IMPLICIT_STEPS]
    schemes.say("explicit dam break, K = 2 GPa (water)")
    explicit = [schemes.dambreak_run(f"explicit K = 2 GPa dt = {dt:g} s", "explicit",
                                     w.tiny_dt if dt == 1e-6 else w.dambreak, bulk_modulus=WATER_K, dt=dt)
                for dt in EXPLICIT_STEPS]
    return {"implicit": implicit, "explicit_water": explicit}


def plot(path: Path, runs: dict[str, list[Run]]):
    plt = schemes.pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    rows = {"implicit": runs["implicit"], "explicit, K = 2 GPa": runs["explicit_water"]}
    for y, (name, row) in enumerate(rows.items()):
        for r in row:
            ok = r.status == "completed"
            ax.scatter(r.dt, y, s=140, marker="o" if ok else "X", color="tab:green" if ok else "tab:red")
            ax.annotate(f"{r.time:.3g} s" if ok else f"stopped\nt = {r.time + r.dt:.2g} s", (r.dt, y),
                        textcoords="offset points", xytext=(0, 12), ha="center", fontsize=7)
    ax.set_xscale("log")
    ax.set_yticks(range(len(rows)), list(rows))
    ax.set_ylim(-0.6, len(rows) - 0.2)
    ax.set_xlabel("time step dt (s)")
    ax.set_title("stability map: o ran the window (time reached), X stopped", fontsize=9)
    ax.grid(alpha=0.3, axis="x")
    schemes.save(fig, path)


def table(runs: dict[str, list[Run]]) -> str:
    def row(r: Run) -> list[str]:
        courant = "–" if r.scheme == "implicit" else f"{sqrt(WATER_K / RHO) * r.dt / schemes.CELL:.3g}"
        outcome = ("ran the window" if r.status == "completed" else
                   f"stopped at t = {r.time + r.dt:.3g} s (step {r.steps + 1}): {r.cause}")
        return [r.scheme, f"{r.dt:g}", courant, outcome, f"{r.time:.4g} s", r.steps, f"{r.wall:.3g}",
                f"{r.wall_per_second:.4g}"]

    return pages.table(["scheme", "dt (s)", "CFL number c dt / h", "outcome", "simulated time", "steps", "wall (s)",
                        "wall per simulated s (s)"], map(row, runs["implicit"] + runs["explicit_water"]))


if __name__ == "__main__":
    schemes.run_alone(__doc__, lambda w: print(table(measure(w))))
