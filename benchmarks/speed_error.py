"""Speed against error on the dam break: wall time per simulated second and the front's error, both schemes.

The implicit runs of the stability map (dt = 5e-3 ... 5e-4 s), the explicit ones with water's
bulk modulus that ran at least :data:`MEANINGFUL_STEPS` steps, at its CFL step too, and the
explicit one with the artificial sound speed c0 at its CFL step; for each explicit run the
explicit/implicit wall-time ratio against the cheapest implicit run at an equal or better
front error (RMS against Koshizuka & Oka's experiment, T <= 3), and the seed's own pair
(explicit K = 2 GPa at 1e-6 s against implicit at 1e-3 s). Runs shorter than 2 s of flow are
extrapolated linearly to 2 s, and the tables say so. A section of ``docs/implicit-vs-explicit.md``::

    python benchmarks/speed_error.py [--full]
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
import pages
import schemes
import stability_map
from schemes import C0, EXPERIMENT, L, T_SCALE, WATER_K, Run, Windows, pct, two_seconds

MEANINGFUL_STEPS = 10  # runs stopped before this are only in the stability map


@dataclass
class Speed:
    """The runs of the measurement and the explicit runs' ratios ``(run, ratio, matched run, note)``."""

    implicit: list[Run]
    explicit_water: list[Run]
    explicit_c0: list[Run]
    ratios: list[tuple]

    @property
    def explicit(self) -> list[Run]:
        """The explicit runs that took at least :data:`MEANINGFUL_STEPS` steps."""
        return [r for r in self.explicit_water + self.explicit_c0 if r.steps >= MEANINGFUL_STEPS]

    @property
    def finished(self) -> list[Run]:
        """The runs with a front error."""
        return [r for r in self.implicit + self.explicit_water + self.explicit_c0 if r.error is not None]


def measure(w: Windows) -> Speed:
    """The stability map's runs, explicit K = 2 GPa and c0 at their CFL step, and the ratios."""
    runs = stability_map.measure(w)
    water = runs["explicit_water"] + [schemes.dambreak_run("explicit K = 2 GPa, CFL step", "explicit", w.dambreak,
                                                           bulk_modulus=WATER_K)]
    schemes.say("explicit dam break, c0 = 10 sqrt(2 g H)")
    c0 = [schemes.dambreak_run("explicit c0 = 23.9 m/s, CFL step", "explicit", w.dambreak, sound_speed=C0)]
    speed = Speed(runs["implicit"], water, c0, [])
    speed.ratios = [(r, *equal_accuracy_ratio(r, speed.implicit)) for r in speed.explicit]
    return speed


def equal_accuracy_ratio(explicit: Run, implicit: list[Run]) -> tuple[float | None, Run | None, str]:
    """Explicit / implicit wall time per simulated second, against the cheapest implicit run that
    ran the whole window with a front error no worse; if none is as good, against the most
    accurate one that ran the window (and the note says so)."""
    finished = [r for r in implicit if r.error is not None and r.status == "completed"]
    if explicit.error is None or not finished:
        return None, None, "no front error to match"
    as_good = [r for r in finished if r.error <= explicit.error]
    if as_good:
        match = min(as_good, key=lambda r: r.wall_per_second)
        note = "implicit error equal or better"
    else:
        match = min(finished, key=lambda r: r.error)
        note = (f"no implicit run that ran the window is as close to the experiment "
                f"({100 * match.error:.1f} % at best against {100 * explicit.error:.1f} %): "
                "ratio to the most accurate one")
    return explicit.wall_per_second / match.wall_per_second, match, note


def seed_step_ratio(explicit: Run, implicit: list[Run]) -> str:
    """Explicit / implicit wall time per simulated second against implicit at the seed's dt = 1e-3 s."""
    seed = next(r for r in implicit if r.dt == 1e-3)
    return f"{explicit.wall_per_second / seed.wall_per_second:.3g}" if seed.status == "completed" else "–"


def plot_speed_error(path: Path, runs: list[Run]):
    plt = schemes.pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    colours = {"implicit": "tab:blue", "explicit": "tab:orange"}
    for k, r in enumerate(runs):
        ax.scatter(r.wall_per_second, 100 * r.error, color=colours[r.scheme])
        ax.annotate(r.label, (r.wall_per_second, 100 * r.error), textcoords="offset points",
                    xytext=(-60, 6 if k % 2 else -12), fontsize=7)  # alternate: neighbours do not overlap
    ax.set_xscale("log")
    ax.set_xlabel("wall time per simulated second (s), one core")
    ax.set_ylabel("front RMS error vs Koshizuka-Oka, T <= 3 (%)")
    ax.grid(alpha=0.3)
    schemes.save(fig, path)


def plot_fronts(path: Path, runs: list[Run]):
    plt = schemes.pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for r in runs:
        front = np.array(r.front)
        ax.plot(front[:, 0] * T_SCALE, front[:, 1] / L, "--" if r.scheme == "explicit" else "-", label=r.label)
    ax.plot(EXPERIMENT[:, 0], EXPERIMENT[:, 1], "o", color="black", label="Koshizuka & Oka 1996, experiment")
    ax.set_xlim(0, 3.2)
    ax.set_ylim(1, 4.1)
    schemes.save(fig, path, ax, r"$T = t\sqrt{2g/L}$", r"$Z = x_{front}/L$")


def speed_table(runs: list[Run]) -> str:
    def row(r: Run) -> list[str]:
        outcome = f"ran {r.time:.3g} s" if r.status == "completed" else f"stopped at t = {r.time + r.dt:.3g} s"
        return [r.label, f"{r.dt:.3g}", outcome, r.steps, f"{r.ms_per_step:.3g}", f"{r.wall:.4g}", two_seconds(r),
                pct(r.error), f"{r.pressure[0] / 1e3:.3g} … {r.pressure[1] / 1e3:.3g}"]

    return pages.table(["run", "dt (s)", "outcome", "steps", "ms per step", "wall for the window (s)",
                        "wall for 2 s of flow (s)", "front error (T ≤ 3)", "particle pressure range (kPa)"],
                       map(row, runs))


def ratio_table(ratios, implicit: list[Run]) -> str:
    return pages.table(["explicit run", "its front error", "implicit run matched", "its front error",
                        "explicit / implicit wall time", "how matched", "explicit / implicit at dt = 1e-3 s"],
                       ([explicit.label, pct(explicit.error), match.label if match else "–",
                         pct(match.error) if match else "–", "–" if ratio is None else f"{ratio:.3g}", note,
                         seed_step_ratio(explicit, implicit)] for explicit, ratio, match, note in ratios))


def seed_pair(speed: Speed) -> tuple[Run, Run] | None:
    """The seed's own comparison: explicit K = 2 GPa at dt = 1e-6 s against implicit at 1e-3 s."""
    tiny = next(r for r in speed.explicit_water if r.dt == 1e-6)
    implicit = next(r for r in speed.implicit if r.dt == 1e-3)
    return (tiny, implicit) if tiny.status == implicit.status == "completed" else None


def seed_pair_lines(pair) -> list[str]:
    if pair is None:
        return ["The seed's pair (explicit K = 2 GPa at 1e-6 s, implicit at 1e-3 s) did not both run."]
    tiny, implicit = pair
    return [f"The seed's own pair, explicit K = 2 GPa at dt = 1e-6 s against implicit at dt = 1e-3 s: "
            f"{tiny.wall_per_second:.4g} s against {implicit.wall_per_second:.4g} s of wall time per simulated "
            f"second, a ratio of **{tiny.wall_per_second / implicit.wall_per_second:.3g}** (the seed: 4547/324 = 14; "
            f"2 s of flow: {two_seconds(tiny)} s against {two_seconds(implicit)} s; "
            f"front error of the explicit run: {pct(tiny.error)}, of the implicit one {pct(implicit.error)})."]


def summary_sentences(speed: Speed) -> list[str]:
    """The closing note's sentences on speed, each number read from the runs."""
    out = ["- " + line for line in seed_pair_lines(seed_pair(speed))]
    for explicit, ratio, match, note in speed.ratios:
        if ratio is None:
            continue
        verdict = (f"{ratio:.3g} times the implicit one" if ratio >= 1 else
                   f"{1 / ratio:.3g} times faster than the implicit one")
        out.append(f"- **{explicit.label}**: wall time per simulated second {verdict} ({match.label}; {note}); "
                   f"{seed_step_ratio(explicit, speed.implicit)} times that of implicit at dt = 1e-3 s.")
    return out


def figures(folder: Path, speed: Speed):
    """speed_error.png, fronts.png and the end states of implicit dt = 1e-3 s and the explicit CFL-step runs."""
    plot_speed_error(folder / "speed_error.png", speed.finished)
    plot_fronts(folder / "fronts.png", speed.finished)
    next(r for r in speed.implicit if r.dt == 1e-3).picture(folder / "implicit.png")
    speed.explicit_water[-1].picture(folder / "explicit_water.png")
    speed.explicit_c0[-1].picture(folder / "explicit_c0.png")


def report(w: Windows):
    """Measure and print the tables and the closing sentences."""
    speed = measure(w)
    print(speed_table(speed.implicit + speed.explicit))
    print(ratio_table(speed.ratios, speed.implicit))
    print("\n".join(summary_sentences(speed)))


if __name__ == "__main__":
    schemes.run_alone(__doc__, report)
