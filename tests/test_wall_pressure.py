"""The dam break's right-wall pressure against the interFoam 160² probes (benchmarks/wall_pressure.py):
its measures on known signals and on interFoam's own probes, and (--full) fempm's run to 0.6 s."""

import sys
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fempm import references
from fempm.cases import dambreak

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import wall_pressure  # noqa: E402

RHO_G_L = 1000.0 * 9.81 * references.DAMBREAK_COLUMN_WIDTH


def test_the_noise_of_a_ripple_on_a_mean_is_its_rms_over_the_mean():
    t = np.arange(0.0, 0.7, 1e-3)
    ripple = 100.0 * np.sin(2 * np.pi * t / 0.004)  # 4 ms: well inside the 20 ms moving mean
    m = wall_pressure.metrics(t, 2000.0 + ripple)
    assert m["mean_Pa"] == pytest.approx(2000.0, rel=1e-3)
    assert m["noise"] == pytest.approx(100.0 / np.sqrt(2) / 2000.0, rel=0.02)  # measured 0.2 % off
    assert m["min_window_over_rhogL"] == pytest.approx(1900.0 / RHO_G_L, rel=1e-3)
    # a dry sample is left out of the measures and counted
    dry = np.where(np.abs(t - 0.45) < 0.0015, np.nan, 2000.0)
    assert wall_pressure.metrics(t, dry)["dry_in_window"] == 3


def test_interfoams_own_wall_pressure_is_smooth_and_its_probe_points_are_read():
    points = wall_pressure.probe_points()
    assert points["right_y0.005"] == (0.5839, 0.005) and len(points) == 8
    t, probes = references.interfoam_probes(160)
    m = wall_pressure.metrics(t, probes["right_y0.005"])
    assert m["noise"] < 0.005  # measured 0.2 %: the target's 5 % is far above the reference's own
    assert m["mean_Pa"] == pytest.approx(1924, rel=1e-3)  # measured 1924 Pa over 0.3-0.6 s
    assert m["min_window_over_rhogL"] > 0.5  # measured 0.77


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="one run, serial")
@pytest.mark.parametrize("changes, noise, mean, lowest", [
    # the seed's fixed 1 ms step: measured noise 1.7 %, mean -1.8 %, lowest 0.784 rho g L
    (dambreak.seed_setup(), 0.03, 0.035, 0.70),
    # a quarter of it: measured 2.2 %, -2.1 %, 0.682 (the split's lowest a single-step dip as the walls' contact set
    # flickers: 0.57-0.68 in runs that differ in the last bits; README, the notes)
    (dambreak.seed_setup(2.5e-4), 0.035, 0.035, 0.6),
    # 3 x 3 per cell at the seed's step: measured 1.05 %, -1.64 %, 0.697
    ({**dambreak.seed_setup(), "bodies.0.particles_per_cell": 9}, 0.02, 0.02, 0.65),
], ids=["seed-step", "quarter-seed-step", "3x3-per-cell-seed-step"])
def test_the_right_wall_gauges_of_the_dam_break(changes, noise, mean, lowest):
    """The gauge 5 mm up the right wall, 0.3-0.6 s, against interFoam 160²: the noise about a 20 ms
    moving mean, the mean, and the lowest sample (no dip after the impact)."""
    result, table = wall_pressure.run(changes)
    assert result["status"] == "completed"
    m = result["probes"]["right_y0.005"]["fempm"]
    assert m["noise"] < noise
    assert abs(m["mean_vs_interfoam"]) < mean
    assert m["min_window_over_rhogL"] > lowest
    assert m["dry_in_window"] == 0


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="one run, serial")
def test_every_right_wall_gauge_of_the_shipped_scene_meets_issue_11():
    """The shipped scene's four right-wall gauges, 0.3-0.6 s, against interFoam 160²: issue 11's noise below 5 % of
    the mean, mean within 10 %, no sample below -0.05 rho g L; the 5 mm gauge never dips after the impact."""
    result, _ = wall_pressure.run({})
    assert result["status"] == "completed"
    probes = {name: probe["fempm"] for name, probe in result["probes"].items() if name.startswith("right_")}
    print({name: (m["noise"], m["mean_vs_interfoam"], m["min_window_over_rhogL"]) for name, m in probes.items()},
          result["front_vs_interfoam"])
    assert len(probes) == 4 and all(m["dry_in_window"] == 0 for m in probes.values())
    # measured 1.50 / 1.51 / 2.21 / 3.14 % (5.2 and 6.0 % at the highest gauge at Courant 0.78 and 0.81)
    assert max(m["noise"] for m in probes.values()) < 0.04
    # measured -1.4 / -1.1 / -2.6 / -9.1 %: the highest gauge, 4 cells up the wall, reads low at large steps (README,
    # Known limits) and swings with the last bits of a run (-6.0 to -10.3 % at Courant 0.78-0.82): issue 11's bound,
    # met here at the shipped 0.8 and on average nearby (the next test)
    assert max(abs(m["mean_vs_interfoam"]) for m in probes.values()) < 0.10
    # measured 0.763 / 0.694 / 0.578 / 0.366 rho g L
    assert min(m["min_window_over_rhogL"] for m in probes.values()) > 0.3
    # 5 mm: measured lowest 0.763 rho g L (the other handlings' and variants': docs/wall-pressure.md)
    assert probes["right_y0.005"]["min_window_over_rhogL"] > 0.70
    assert result["front_vs_interfoam"] < 0.0195  # measured 1.87 % (the split 1.79 %; issue 11: 2.5 %)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="five runs, serial")
def test_the_right_wall_gauges_meet_issue_11_on_average_over_nearby_steps():
    """Issue 11's gauge targets on the average over the shipped scene at Courant 0.78-0.82: where the run-up reaches
    the wall the flow is chaotic, and one run's mean at the highest gauge moves by a few points with its last bits
    (docs/wall-pressure.md, the nearby steps' table)."""
    spread = wall_pressure.nearby()
    print({name: (g["mean_vs_interfoam"], g["noise"], g["lowest_over_rhogL"]) for name, g in spread.items()})
    assert len(spread) == 4 and all(g["completed"] and g["dry_in_window"] == 0 for g in spread.values())
    # measured -1.40 / -1.12 / -2.65 / -8.43 % (the highest: -6.0 / -9.4 / -9.1 / -8.7 / -9.0 % run by run); issue 11: 10 %
    assert max(abs(g["mean_vs_interfoam"]) for g in spread.values()) < 0.10
    # measured 1.37 / 1.42 / 1.77 / 4.16 % (the highest: 5.2 / 3.3 / 3.1 / 6.0 / 3.2 % run by run); issue 11: 5 %
    assert max(g["noise"] for g in spread.values()) < 0.05
    # measured 0.362 rho g L at the lowest; issue 11: above -0.05
    assert min(g["lowest_over_rhogL"] for g in spread.values()) > 0.3
