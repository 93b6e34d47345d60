"""The hard-case stability suite of issue 5: each case runs to its end or stops with a diagnosis.

The cases and their measures are those of :mod:`fempm.cases.hard` (:func:`run_case`);
``benchmarks/hard_cases.py`` writes them as ``docs/hard-cases.md``. Each test runs the short version in CI and the
long one with ``--full``, and asserts: the outcome (every case here runs to its end
time), finite particle fields, the total mass to round-off, a volume measure, and
bounds that an "eruption" would break: the mechanical energy never above its start
(gravity and walls at rest only take energy away) and the particle speeds within a
small factor of free fall. The factors allow what the scheme measurably does (a jet
squeezed out at a wall impact, the energy error of a step ten times the seed's) and
nothing near an eruption, whose energy and speeds grow without bound.
"""

import numpy as np
import pytest

from fempm.cases import hard as hc

SHORT_AND_FULL = [False, pytest.param(True, marks=pytest.mark.full)]
#: the bounds below sit a small margin above what was measured: the short versions on this code (tests/hard -s
#: prints them), the full ones from docs/hard-cases.md where they differ. Where a measure moves with the last bits
#: (a splash's speed or energy) the comment says by how much; earlier codes' figures are in git's history of this
#: file and in docs/notes-accuracy.md.
EXACT = 1e-9  # E_max - 1 where the energy never rose above its start (measured 1.0000000)
#: the dam break's water spread over the floor: its area over the tank's width
SETTLED_DEPTH = hc.dambreak.WIDTH * hc.H / hc.TANK


def measured(name: str, full: bool) -> hc.Outcome:
    """Run a case and print its row of the table."""
    o = hc.run_case(name, full)
    print(" | ".join(f"{k}: {v}" for k, v in zip(hc.COLUMNS, hc.row(o))))
    e = o.history["energy"]
    print(f"{name}: speed ratio {o.speed_ratio:.5f}, E_max - 1 {o.energy_max - 1:.3g}, E rise {o.energy_rise:.3g}, "
          f"E end {e[-1] / e[0]:.5f}, cells {o.cells_final / o.cells_initial:.4f}, CFL {o.max_cfl:.4f}, "
          f"last speed {o.history['max_speed'][-1]:.3g}, centroid {o.history['centroid'][-1]}")
    return o


def assert_sound(o: hc.Outcome, particles: int, speed_ratio: float, energy_max: float, energy_rise: float):
    """Ran to its end time, every field finite, mass to round-off, no particle lost, no eruption."""
    assert (o.run.status, o.run.cause) == ("completed", "")
    assert o.run.time == pytest.approx(o.end_time, abs=1e-9)
    assert o.finite
    assert o.particles == particles
    assert abs(o.mass_error) <= 1e-14
    assert o.speed_ratio <= speed_ratio
    assert o.energy_max <= energy_max
    assert o.energy_rise <= energy_rise


def cell_ratio(o: hc.Outcome) -> float:
    """Occupied cells at the end over those at the start."""
    return o.cells_final / o.cells_initial


def bound(full: bool, short: float, long: float) -> float:
    """The bound of the short version, or of the full one where the two were measured apart."""
    return long if full else short


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_dam_break_at_ten_times_the_seeds_step(full):
    """dt = 1e-2 s: the advective CFL max |v| dt / h reaches 3.2 (at the seed's step 0.39); walls
    stop displacements that would cross them. The energy error of the big step shows (3–6 % of
    the start regained in the sloshing, at one splash, which round-off moves) but stays bounded,
    and the volume holds."""
    o = measured("dt-10x", full)
    # measured 1.980, 1.0, 0.0560 (2 s and 4 s): the fastest particle and the energy's largest rise are one splash's,
    # which the last bits move (at dt = 1/105, 1/100, 1/95, 1/90 s: rises 0.028 / 0.056 / 0.033 / 0.035, speeds 2.18 /
    # 1.98 / 1.93 / 1.72)
    assert_sound(o, 800, speed_ratio=2.1, energy_max=1.0 + EXACT, energy_rise=0.06)
    # measured 3.226
    assert o.max_cfl > 2.8
    # measured 1.085 (2 s), 1.055 (4 s): the water still sloshing, throwing spray
    assert 0.88 <= cell_ratio(o) <= 1.16
    # the walls act: measured 3910 (2 s), 4148 (4 s)
    assert o.wall_stops >= 430


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_at_twenty_times_the_seeds_step_the_eruption_is_diagnosed(full):
    """Past the limit: at dt = 2e-2 s (advective CFL 5) particles cross several cells a step
    and pile up on the walls; without a check the water's cells fell to about half and the
    energy rose 56 % above the start by t ~ 0.6 s, the run ending 'completed'. Now the energy the
    sloshing regains comes near the 10 % of ``Controls.energy_gain_limit``, and whether it crosses it is
    chance: either the energy check stops the run with its diagnosis, or the run ends finite with the
    energy regained under the limit, with its mass."""
    o = measured("dt-20x", full)
    # measured: stopped by the energy check at 0.48 s, a rise of 0.092; in divergence form the run completes regaining
    # 0.093 (docs/hard-cases-divergence.md); earlier codes ended either way at 18, 20 and 22 ms
    if o.run.status == "stopped":
        assert o.run.cause.startswith("energy growth") and o.run.time >= 0.4
    else:
        assert o.run.status == "completed" and o.energy_rise <= 0.10
    assert (o.finite, o.particles, abs(o.mass_error) <= 1e-14) == (True, 800, True)


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_dam_break_of_water(full):
    """mu = 1e-3 Pa s at the seed's step: the fastest particle is the
    run-up jet at the right wall (t = 0.28 s), 2.4 times free fall from the column's top."""
    o = measured("water", full)
    # measured 2.412, 1.0, 0.0015 (0.6 s; 0.002 to 2 s): the run-up jet, faster than the split's 2.23 (README, Known
    # limits); the energy never above the start
    assert_sound(o, 800, speed_ratio=bound(full, 2.5, 2.5), energy_max=1.0 + bound(full, 0.009, 0.009),
                 energy_rise=bound(full, 0.0095, 0.0095))
    # measured 1.195 (0.6 s and 2 s)
    assert 1.09 <= cell_ratio(o) <= 1.25
    # measured 89 (0.6 s), 174 (2 s); after 0.6 s the count moves by hundreds with any small change of the scheme
    assert o.wall_stops <= bound(full, 100, 500)


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_dam_break_of_a_very_viscous_fluid(full):
    """mu = 10 Pa s (Re = rho sqrt(gH) H / mu ~ 50): the viscous term dominates the step's
    velocity block far more than water's, and the column slumps slower (no jet: the speed
    stays near free fall's)."""
    o = measured("viscous", full)
    # measured 1.134, 1.0, 0
    assert_sound(o, 800, speed_ratio=1.17, energy_max=1.0 + bound(full, EXACT, 1e-4),
                 energy_rise=bound(full, EXACT, 1e-4))
    # measured 1.085 (0.6 s), 1.000 (3 s: the layer flat, the column's 200 cells)
    assert bound(full, 1.05, 0.99) <= cell_ratio(o) <= 1.10


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_dam_break_onto_an_obstacle(full):
    """scenes/obstacle.toml: the surge hits a block, splashes over it in a thin sheet and
    isolated particles; none enters the block (that would stop the run), none is lost."""
    o = measured("obstacle", full)
    # measured 2.553, 1.0, 0.0023 (0.6 s and 2 s): a wave landing on the thin layer that flows back along the floor
    # squeezes out a jet
    assert_sound(o, 800, speed_ratio=2.93, energy_max=1.0 + bound(full, 6e-4, 6e-4),
                 energy_rise=bound(full, 0.004, 0.004))
    # measured 1.245 (0.6 s), 1.155 (2 s)
    assert 1.05 <= cell_ratio(o) <= 1.26
    assert not o.solver.grid.blocked[o.solver.particles.cell].any()


def free_fall_error(o: hc.Outcome, lowest: float) -> float:
    """Largest error of the centroid's height against ``y0 - g t^2 / 2`` while the lowest particle
    would be (in free fall) more than two cells above the floor, relative to the distance it fell."""
    t, y = o.history["t"], o.history["centroid"][:, 1]
    exact = y[0] - 0.5 * hc.G * t**2
    falling = lowest - 0.5 * hc.G * t**2 > 2 * hc.h
    assert falling.sum() > 100
    error = float(np.max(np.abs(y - exact)[falling]) / (y[0] - exact[falling].min()))
    print(f"free-fall error {error:.5f} over {falling.sum()} steps")
    return error


@pytest.mark.mpi
@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_a_single_particle_falls_freely_and_comes_to_rest_on_the_floor(full):
    """No water around it: its pressure is held at zero and it falls as a body in free fall, to
    round-off in the distance fallen (the functions barely touching it are held at rest for want of
    material, and G2P takes its values over the others: taken at their zero, they pulled it back by 2 %),
    then stops on the slip floor and stays there."""
    o = measured("single-particle", full)
    # measured 0.984, 1.0, 0
    assert_sound(o, 1, speed_ratio=0.99, energy_max=1.0 + EXACT, energy_rise=EXACT)
    # measured 1.0e-6
    assert free_fall_error(o, hc.SINGLE[0, 1]) <= 5e-6
    x, y = o.history["centroid"][-1]
    assert x == pytest.approx(hc.SINGLE[0, 0], abs=1e-12)  # nothing pushes it sideways
    # the one-sided floor leaves it at rest on the floor: measured 8.6e-6 m (6e-4 of a cell) and 1.8e-17 m/s at 0.5 s
    assert 0 <= y <= bound(full, 1e-5, 0.5 * hc.h)  # m
    assert o.history["max_speed"][-1] <= bound(full, 1e-8, 1e-2)  # m/s
    assert o.cells_final == 1 and o.wall_stops <= 1  # measured 0 (earlier codes 1: stopped once at the floor)


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_a_sparse_cloud_falls_freely_and_lands(full):
    """48 particles, one in every other cell (every cell around each is empty): no pressure
    holds them until they land; they fall together as one particle does, then spread over the
    floor in a layer a particle or two deep, their energy spent in the landing. The landing is
    fragile (an open defect): a few particles gathered in a corner can hold a tension (-12 to
    -53 kPa) that throws one out; at dt 9e-4 s and 1.1e-3 s a particle leaves at 2.5-3.6 m/s
    (the energy check stops the second)."""
    o = measured("sparse-cloud", full)
    # measured 0.988, 1.0, 0.0092 (0.6 s and 2 s)
    assert_sound(o, len(hc.SPARSE), speed_ratio=1.05, energy_max=1.0 + EXACT,
                 energy_rise=bound(full, 0.012, 0.025))
    # measured 0.00016: the particles of the cloud's edge lean on functions held for want of material
    assert free_fall_error(o, hc.SPARSE[:, 1].min()) <= 0.0002
    # m, 1.6 h; measured 0.0204 (0.6 s), 0.0156 (2 s)
    assert o.surface_height <= 0.0235
    # m; measured 0.0197 at 0.6 s, the layer still settling
    assert o.history["centroid"][-1, 1] <= bound(full, 0.0210, 2 * hc.h)
    # measured 0.0926 at 0.6 s: the layer still moves
    assert o.history["energy"][-1] / o.history["energy"][0] <= bound(full, 0.1, 0.1)


@pytest.mark.mpi
@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_water_driven_into_a_corner(full):
    """A square of water thrown at 2 m/s into the lower-right corner along a gravity tilted
    by 45 degrees: it hits the corner with 3e5 Pa for a step (an impact's pressure impulse,
    not an oscillation: the run goes on), jets along both walls and falls back into the
    corner. The energy only falls."""
    o = measured("corner", full)
    # 20 x 20 particles; measured 1.794, 1.0, 0.0024 (0.5 s), 0.002 (3 s)
    assert_sound(o, 400, speed_ratio=1.91, energy_max=1.0 + bound(full, EXACT, 1e-4),
                 energy_rise=bound(full, 0.0024, 0.0050))
    # measured 1.564 (0.5 s), 1.045 (3 s)
    assert 0.98 <= cell_ratio(o) <= 1.60
    # the centroid's distance from the corner along gravity: 2/3 of the depth sqrt(A) of the
    # right-angled triangle of area A the water settles into
    if full:
        direction = np.asarray(hc.CORNER_GRAVITY) / hc.G
        depth = (np.array([hc.TANK, 0.0]) - o.history["centroid"][-1]) @ direction
        assert depth == pytest.approx(2 / 3 * np.sqrt(o.particles * (hc.h / 2) ** 2), rel=0.1)


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_a_long_run_settles_with_its_volume(full):
    """The dam break run on until the water settles: 5 s at dt = 1e-2 s in CI, the seed's 40 s
    at 1e-3 s with --full (method.md Fig. 4). The water ends as a layer as deep as the column's
    area over the floor's width (73 mm)."""
    o = measured("long", full)
    if full:  # the energy hardly rises: measured 2.412, 1.0, 0.002 over 40 s (its first 2 s are
        # test_dam_break_of_water's, whose jet this is)
        assert_sound(o, 800, speed_ratio=2.5, energy_max=1.0 + 0.009, energy_rise=0.008)
    else:  # the big step's energy error: the first 2 s are test_dam_break_at_ten_times_the_seeds_step's
        assert_sound(o, 800, speed_ratio=2.1, energy_max=1.0 + EXACT, energy_rise=0.06)
    t, centroid = o.history["t"], np.asarray(o.history["centroid"])
    if full:  # the layer's surface after 40 s, at one instant of a layer still sloshing: measured 73.5 mm; it moves
        # with round-off (65.8-76.8 mm on earlier codes), the mean below does not
        assert o.surface_height == pytest.approx(SETTLED_DEPTH, rel=0.12)
        # its mean depth over the last 5 s, twice its centroid's height: measured 76.5 mm, std 1.9 mm (75.4-77.1 mm
        # on earlier codes; the volume correction's swell, README, Known limits)
        assert 2 * centroid[t >= t[-1] - 5.0, 1].mean() == pytest.approx(0.0763, rel=0.01)
    else:  # after 5 s the layer still sloshes and its surface at one instant moves with round-off: its mean depth
        # over the last second, twice its centroid's height, measured 76.3 mm, within 8 % of SETTLED_DEPTH = 73 mm
        assert 2 * centroid[t >= t[-1] - 1.0, 1].mean() == pytest.approx(SETTLED_DEPTH, rel=0.08)
    # the energy left: a still layer keeps SETTLED_DEPTH / H = 1/4 of the column's; measured 0.275 at 5 s
    assert o.history["energy"][-1] / o.history["energy"][0] <= bound(full, 0.30, 1.4 * SETTLED_DEPTH / hc.H)
