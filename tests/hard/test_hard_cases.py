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
#: the bounds below sit a small margin above what was measured: the short versions on this code
#: (tests/hard -s prints them), the full ones from docs/hard-cases.md (three digits) where they differ.
#: Both were re-measured on the end-of-step forms (forms/incompressible.py, end_map) with the default
#: affine-FLIP transfer and one-sided walls; beside them "before" (start configuration's divergence),
#: "affine" (affine-FLIP, two-sided walls) and "FLIP/PIC" (the seed's, two-sided walls). Some full
#: bounds are still those of FLIP/PIC where the new values lie inside them.
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
    """dt = 1e-2 s: the advective CFL max |v| dt / h reaches 2.9 (at the seed's step 0.33); walls
    stop displacements that would cross them. The energy error of the big step shows (3 % of
    the start regained in the sloshing; 13 % with the start configuration's divergence) but stays
    bounded, and the volume holds."""
    o = measured("dt-10x", full)
    # measured 2.241, 1.0, 0.0346 with the walls letting go of water within the step where they pull hard
    # (fempm.walls.Walls.settle; lagged by the step, 10 ms here, they held the run-up jet back: 2.040, the seed's
    # step gives 2.105); 2.040, 1.0, 0.0357 with PSPG's displacement in a step bounded (forms/incompressible.py,
    # TAU_STEP_DISPLACEMENT; held to a share of a cell whatever the flow's speed, the energy check stopped the run at
    # 1.72 s, a particle at 25.7 m/s); 2.060, 1.0, 0.0350 with PSPG's tau free of the step (with tau's T = max(dt, ...), its transient time
    # 10 ms here, not 0.96 ms: 1.886, 1.0, 0.0218) and the scene's particle shifting (without 1.802, 1.0, 0.0300; crowding only
    # 1.791, 1.0, 0.0304; before the crowding tolerance 2.509, 1.0, 0.0306: a run-up jet
    # at 2.5 times free fall; from a_0 = 0: 1.791, 1.0, 0.0290, the whole flow a half step late; start-configuration
    # divergence 1.962, 1.0, 0.128; FLIP/PIC 2.713, 1.01225, 0.0845)
    assert_sound(o, 800, speed_ratio=2.26, energy_max=1.0 + EXACT, energy_rise=0.037)
    # measured 3.356 (with tau's T = max(dt, ...) 2.936 (crowding only 2.918; before the crowding tolerance 4.088; start-configuration divergence 3.197)
    assert o.max_cfl > 2.8
    # measured 1.100 (2 s) with PSPG's displacement bounded; 1.105 (2 s; 1.100 at 4 s) with tau free of the step (with T = max(dt, ...) 1.095), the scene's particle
    # shifting, the water still sloshing (without 1.015; crowding only
    # 0.975 (2 s), 1.02 (4 s); before the crowding tolerance 0.990 (2 s); from a_0 = 0 0.985); FLIP/PIC
    # 0.915 (2 s)
    assert 0.88 <= cell_ratio(o) <= 1.12
    # the walls act: measured 641 (2 s, surface-aware); crowding only 455 (2 s), 498 (4 s) (before the crowding
    # tolerance 567, 674; 604 with PSPG's viscous
    # part, negligible for water here, built; from a_0 = 0 553); FLIP/PIC 1332 (2 s), 1618 (4 s)
    assert o.wall_stops >= 430


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_at_twenty_times_the_seeds_step_the_eruption_is_diagnosed(full):
    """Past the limit: at dt = 2e-2 s (advective CFL 5) particles cross several cells a step
    and pile up on the walls; without a check the water's cells fell to about half and the
    energy rose 56 % above the start by t ~ 0.6 s, the run ending 'completed'. With affine-FLIP,
    one-sided walls and the end-of-step divergence the energy regained rose past the 10 % of
    ``Controls.energy_gain_limit`` and the energy check stopped it (at 0.52 s) while the PIC share was the
    whole one alone (100/s). With the default shares (whole 30/s, then the noise's 300/s) the energy it
    regains stays under the limit, 9.0 %, and the run ends finite, with its mass, the water's cells 0.87 of
    the column's."""
    o = measured("dt-20x", full)
    if o.run.status == "stopped":  # a change that lets it erupt again must be stopped by the check
        assert o.run.cause.startswith("energy growth")
    # measured 0.0898 to 3 s and to 4 s (whole share alone: stopped at 26 steps, 0.52 s, a rise past 0.10)
    assert o.run.status == "completed" and o.energy_rise <= 0.095
    # measured: 26 steps, 0.52 s, with the walls letting go within the step where they pull hard (fempm.walls; lagged
    # 27 steps, 0.54 s); 27 steps, 0.54 s, a rise of 11 %, with PSPG's displacement in a step bounded (forms/incompressible.py,
    # TAU_STEP_DISPLACEMENT: at 20 ms the slow water's tau is a quarter; before it, 148 steps, 2.96 s, the energy 17 %
    # above its lowest), with PSPG's tau free of the step (with tau's
    # T = max(dt, ...), 20 ms here, not 0.96 ms: 35 steps, 0.70 s, a particle at 10.1 m/s), with the scene's particle
    # shifting (without: 32 steps,
    # 0.64 s, a rise of 16 %; before the crowding tolerance 31 steps, 0.62 s, 14 %;
    # start-configuration divergence: 40 steps, 0.8 s, a particle at 9.49 m/s; FLIP/PIC two-sided: 29 steps, 0.58 s;
    # affine-FLIP two-sided: 34 steps, 0.68 s)
    assert (o.finite, o.particles, abs(o.mass_error) <= 1e-14) == (True, 800, True)


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_dam_break_of_water(full):
    """mu = 1e-3 Pa s at the seed's step: the fastest particle is the
    run-up jet at the right wall (t = 0.28 s), 2.25 times free fall from the column's top."""
    o = measured("water", full)
    # measured 2.250, 1.0, 0.0016 at 0.6 s with the default shares (whole 30/s, then the noise's 300/s: the less
    # damped jet runs faster, the energy still never above the start); 2.104, 1.0, 0.0018 at 0.6 s with the scene's particle shifting: the energy no longer rises at the
    # impact; without it 2.018, 1.0076, 0.0084 at 0.6 s and 2 s (before the crowding tolerance 2.022, 1.0082, 0.0085 and
    # 2.02, 1.008, 0.009; from a_0 = 0: 2.025 and 2.085,
    # 1.0083, 0.0086; start-configuration divergence 2.109, 1.0153, 0.0159; FLIP/PIC 1.782, 1.0, 6.3e-5): the
    # affine-FLIP transfer's energy rises by 0.8 % of the start at the wall impact, where FLIP/PIC's only fell
    assert_sound(o, 800, speed_ratio=bound(full, 2.27, 2.3), energy_max=1.0 + bound(full, 0.009, 0.009),
                 energy_rise=bound(full, 0.0095, 0.0095))
    # measured 1.215 (0.6 s), 1.16 (2 s) with the scene's particle shifting (without 1.225, 1.17; from a_0 = 0: 1.215,
    # 1.18); FLIP/PIC 1.16 (0.6 s), 1.10 (2 s)
    assert 1.09 <= cell_ratio(o) <= 1.25
    # measured 61 (0.6 s), 156 (2 s) with the walls letting go within the step where they pull hard (fempm.walls; 435
    # lagged) and the scene's particle shifting, whose moves cut at a wall count too
    # (without 61, 193; before the crowding tolerance 50, 81; from a_0 = 0: 52, 175); FLIP/PIC 0. After 0.6 s the
    # count moves by hundreds with any small change of the scheme: 347 before still water's PIC share, 124 without
    # it, 168 and 275 with it ramped in over the time at rest; 0 and 48 to 3 s with a PIC share of 95 or 105 /s (letting
    # go within the step: 0 and 531)
    assert o.wall_stops <= bound(full, 70, 500)


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_dam_break_of_a_very_viscous_fluid(full):
    """mu = 10 Pa s (Re = rho sqrt(gH) H / mu ~ 50): the viscous term dominates the step's
    velocity block far more than water's, and the column slumps slower (no jet: the speed
    stays near free fall's)."""
    o = measured("viscous", full)
    # measured 1.150, 1.0, 0 with the default shares (whole 30/s, then the noise's 300/s); 1.124 with the whole
    # share alone (100/s) and the scene's particle shifting
    assert_sound(o, 800, speed_ratio=1.17, energy_max=1.0 + bound(full, EXACT, 1e-4),
                 energy_rise=bound(full, EXACT, 1e-4))
    # (without 1.0648, 1.0, 0: the fastest particle, at the impact on the right wall, 14 % faster; before the
    # crowding tolerance 1.0722; from a_0 = 0 1.0783; FLIP/PIC 1.059)
    # measured 1.065 (0.6 s), 1.005 (3 s: the layer flat, nearly the column's 200 cells) with the scene's particle
    # shifting (without 1.095, 1.07; before the crowding tolerance 1.090, 1.07; from a_0 = 0: 1.090); FLIP/PIC
    # 1.055 (0.6 s), 1.06 (3 s)
    assert bound(full, 1.05, 0.99) <= cell_ratio(o) <= 1.10


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_dam_break_onto_an_obstacle(full):
    """scenes/obstacle.toml: the surge hits a block, splashes over it in a thin sheet and
    isolated particles; none enters the block (that would stop the run), none is lost."""
    o = measured("obstacle", full)
    # measured 2.899, 1.0, 0.0013 (before the crowding tolerance 2.923, 1.0001, 0.0011): a wave landing on the thin layer that flows back along the floor
    # squeezes out a jet at 6.89 m/s (from a_0 = 0: 2.427, 1.00009, 0.0014; start-configuration divergence
    # 2.405, 1.00048, 0.0037; FLIP/PIC 1.562)
    assert_sound(o, 800, speed_ratio=2.93, energy_max=1.0 + bound(full, 6e-4, 6e-4),
                 energy_rise=bound(full, 0.004, 0.004))
    # measured 1.235 (0.6 s), 1.145 (2 s) (before the crowding tolerance 1.225, 1.185; from a_0 = 0: 1.235); FLIP/PIC
    # 1.06 (0.6 s), 1.125 (2 s)
    assert 1.05 <= cell_ratio(o) <= 1.24
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
    """No water around it: its pressure is held at zero and it falls as a body in free fall,
    within 2 % of the distance (the functions barely touching it are left out of the solve and
    held at rest, and the noise's share, which damps a particle alone whole, pulls it towards them; from
    a_0 = 0 it also lagged by g dt t / 2), then stops on the slip floor and stays there."""
    o = measured("single-particle", full)
    # measured 0.969, 1.0, 0 (the whole share alone at 100/s: 0.979)
    assert_sound(o, 1, speed_ratio=0.99, energy_max=1.0 + EXACT, energy_rise=EXACT)
    # measured 0.0190 with the default shares (the whole share alone at 100/s: 0.00736; from a_0 = 0 0.01172)
    assert free_fall_error(o, hc.SINGLE[0, 1]) <= 0.020
    x, y = o.history["centroid"][-1]
    assert x == pytest.approx(hc.SINGLE[0, 0], abs=1e-12)  # nothing pushes it sideways
    # the one-sided floor leaves it at rest on the floor: measured 6.5e-6 m (4e-4 of a cell) and 6e-19 m/s at 0.5 s
    # with the default shares (the whole share alone at 100/s: 1.5e-11 m and 7.4e-10 m/s; affine, two-sided:
    # 4.5e-5 m, 3.2e-4 m/s)
    assert 0 <= y <= bound(full, 1e-5, 0.5 * hc.h)  # m
    assert o.history["max_speed"][-1] <= bound(full, 1e-8, 1e-2)  # m/s
    assert o.cells_final == 1 and o.wall_stops <= 1  # measured 1 (FLIP/PIC 0): stopped once at the floor


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_a_sparse_cloud_falls_freely_and_lands(full):
    """48 particles, one in every other cell (every cell around each is empty): no pressure
    holds them until they land; they fall together as one particle does, then spread over the
    floor in a layer a particle or two deep, their energy spent in the landing. The landing is
    fragile (an open defect): a few particles gathered in a corner can hold a tension (-12 to
    -53 kPa) that throws one out; at dt 9e-4 s and 1.1e-3 s a particle leaves at 2.5-3.6 m/s
    (the energy check stops the second)."""
    o = measured("sparse-cloud", full)
    # measured 1.029, 1.0, 0.0080 with the walls letting go within the step where they pull hard (fempm.walls); 1.031, 1.0, 0.0078 (before the crowding tolerance 0.0107; from a_0 = 0: 1.030, 1.0, 0.0237; start-configuration divergence 1.046,
    # 1.0, 0.0094; FLIP/PIC 0.865, 1.0, 0.0025 (0.6 s), 0.004 (2 s)); the full version was not rerun with the
    # end-of-step forms
    assert_sound(o, len(hc.SPARSE), speed_ratio=1.05, energy_max=1.0 + EXACT,
                 energy_rise=bound(full, 0.012, 0.025))
    # measured 0.00056 with the default shares (the whole share alone at 100/s: 0.00036; from a_0 = 0: 0.00457,
    # the half step's lag)
    assert free_fall_error(o, hc.SPARSE[:, 1].min()) <= 0.0006
    # m, 1.6 h; measured 0.0227 (0.6 s; 0.0151 at 2 s) with PSPG's tau free of the step (with tau's T = max(dt, ...)
    # 0.0187; before the crowding tolerance 0.0217; affine 0.0171); FLIP/PIC 0.0165 (0.6 s), 0.0154 (2 s)
    assert o.surface_height <= 0.0235
    # m; 0.0174 at 0.6 s with the walls letting go within the step (0.0167 lagged; before the crowding tolerance 0.0157,
    # FLIP/PIC 0.0165)
    assert o.history["centroid"][-1, 1] <= bound(full, 0.0180, 2 * hc.h)
    # measured 0.0806 at 0.6 s with the walls letting go within the step (0.0682 lagged: the held walls took more); (before the crowding tolerance 0.0754; from a_0 = 0 0.0609, before that 0.0764; FLIP/PIC 0.0486): the layer still moves
    assert o.history["energy"][-1] / o.history["energy"][0] <= bound(full, 0.085, 0.1)


@pytest.mark.mpi
@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_water_driven_into_a_corner(full):
    """A square of water thrown at 2 m/s into the lower-right corner along a gravity tilted
    by 45 degrees: it hits the corner with 3e5 Pa for a step (an impact's pressure impulse,
    not an oscillation: the run goes on), jets along both walls and falls back into the
    corner. The energy only falls."""
    o = measured("corner", full)
    # 20 x 20 particles; measured 1.739, 1.0, 0.00132 with the scene's particle shifting (without 1.880, 1.0, 0.00114;
    # before the crowding tolerance 1.902, 1.0, 0.00231; affine 1.903, 1.0, 0.0021; FLIP/PIC 1.869, 1.0, 0)
    # (3 s: 0.0047 with PSPG's tau free of the step, its transient time 0.96 ms here, not the step's 1 ms: 0.0010)
    assert_sound(o, 400, speed_ratio=1.91, energy_max=1.0 + bound(full, EXACT, 1e-4),
                 energy_rise=bound(full, 0.0024, 0.0050))
    # measured 1.591 with the shifting (without 1.536; 0.5 s; 1.018 at 3 s; from a_0 = 0 1.491; start-configuration
    # divergence 1.455); FLIP/PIC 1.273 (0.5 s), 0.99 (3 s)
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
    if full:  # the energy hardly rises (0.3 % of the start's)
        # measured 2.104, 1.0, 0.0070 with the scene's particle shifting (without 2.085, 1.0083, 0.0086; FLIP/PIC,
        # two-sided walls: 1.78, 1.000, 0.004)
        # measured 0.003 over 40 s with the walls letting go within the step where they pull hard (fempm.walls; 0.0018
        # and 0.0030 to 3 s with a PIC share of 105 or 95 /s). Lagged by a step, the wall held the wave falling back from
        # it at 2.59 s with 209 cells' weight, and the energy jumped by 0.0105 within two steps (0.0040 to 0.0068 to 3 s
        # across such variants)
        assert_sound(o, 800, speed_ratio=2.11, energy_max=1.0 + 0.009, energy_rise=0.005)
    else:  # the big step's energy error, as in test_dam_break_at_ten_times_the_seeds_step
        # measured 2.060, 1.0, 0.035 with PSPG's tau free of the step (with tau's T = max(dt, ...) 1.886, 1.0, 0.022)
        # and the scene's particle shifting (without 1.802, 1.0, 0.030; earlier 2.509,
        # 1.0, 0.0306; from a_0 = 0: 1.791, 1.0, 0.0290; start-configuration divergence 1.962,
        # 1.0, 0.128; FLIP/PIC 2.713)
        assert_sound(o, 800, speed_ratio=2.52, energy_max=1.0 + EXACT, energy_rise=0.037)
    # the layer: 73.6 mm after 5 s with the default shares (whole 30/s, then the noise's 300/s; after 40 s 74.4 mm,
    # docs/hard-cases.md, the full test's mean depth not rerun with them), 69.6 mm with the whole share alone (100/s) and the walls letting go within the step where they pull hard (fempm.walls; lagged
    # 73.8 mm), 73.8 mm with PSPG's displacement in a step bounded (forms/incompressible.py,
    # TAU_STEP_DISPLACEMENT; 70.9 mm before), 70.9 mm with PSPG's tau free of the step (71.4 mm with T = max(dt, ...)) and the scene's
    # particle shifting (66.6 mm without), still sloshing (crowding only 63.9 mm;
    # 68.3 mm before the crowding tolerance, 67.4 mm without PSPG's
    # viscous part; from a_0 = 0 72.1 mm;
    # start-configuration divergence 67.7 mm, FLIP/PIC 68.6 mm; a sloshing surface's snapshot moves with
    # round-off, hence 3 % in CI); after 40 s it still sloshes (fastest particle 0.13-0.33 m/s) and the snapshot
    # read 73.9, 74.5, 76.8 and 68.8 mm (the crowding tolerance) on codes whose layers' mean depths agree within
    # 1 % (from a_0 = 0 77.7 mm; FLIP/PIC 77.6), and 66.7 mm with PSPG's tau free of the step (mean depth 75.8 mm):
    # the full version holds it within 10 % of SETTLED_DEPTH = 73 mm
    assert o.surface_height == pytest.approx(bound(full, 0.0736, SETTLED_DEPTH), rel=bound(full, 0.03, 0.10))
    if full:  # the layer's mean depth over the last 5 s, twice its centroid's height: 75.8 mm, std 1.5 mm, with PSPG's
        # tau free of the step (75.4 mm with tau's T = max(dt, ...)) and the scene's particle shifting (without 76.4 mm, std 1.0 mm over those seconds; before the crowding tolerance 77.05;
        # 76.92 with PSPG's viscous part)
        t, centroid = o.history["t"], np.asarray(o.history["centroid"])
        assert 2 * centroid[t >= t[-1] - 5.0, 1].mean() == pytest.approx(0.0754, rel=0.01)
    # the energy left: a still layer keeps SETTLED_DEPTH / H = 1/4 of the column's; measured 0.264 at 5 s
    # (from a_0 = 0 0.277; start-configuration divergence 0.280)
    assert o.history["energy"][-1] / o.history["energy"][0] <= bound(full, 0.29, 1.4 * SETTLED_DEPTH / hc.H)
