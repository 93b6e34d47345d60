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
    stop displacements that would cross them. The energy error of the big step shows (3–6 % of
    the start regained in the sloshing, at one splash, which round-off moves; 13 % with the start
    configuration's divergence) but stays bounded, and the volume holds."""
    o = measured("dt-10x", full)
    # measured 1.875, 1.0, 0.0284 with G2P over the moved functions (2.040, 1.0, 0.0273 over all of them): the
    # fastest particle is a splash's, chaotic in the step: at 1/105 ... 1/90 s 1.93-2.04 and 0.025-0.033 (before
    # 1.82-2.23 and 0.025-0.053), while at 1/110 s a drop landing at 3.5 cells a step was thrown off at 29 m/s and
    # the energy check stopped the run at 1.42 s (README, departures table). FLIP/PIC: 2.713, 1.01225, 0.0845
    # with the last step's pressure by parts (the scene's since 2026-11-30) the known pressure's share falls to zero
    # from a step Courant number of 2 (fempm.hydrostatic.LAST_PRESSURE_COURANT): taken whole, the energy grew at the
    # wall impact and the energy check stopped this run at 0.30 s; measured 1.980, 1.0, 0.0309
    # with the compiled solve of small systems (fempm.small_system, 2026-11-30; the same solutions to 3e-13) 1.980, 1.0,
    # 0.0560: the energy's largest rise is one splash's, and round-off moves it. At dt = 1/105, 1/100, 1/95, 1/90 s
    # the compiled solve gives 0.0280 / 0.0560 / 0.0332 / 0.0353 (speeds 2.18 / 1.98 / 1.93 / 1.72), PETSc's split
    # 0.0733 / 0.0309 / 0.0332 / 0.0353 (2.79 / 1.98 / 1.93 / 1.72): the bound of 0.037 held in one of those runs
    assert_sound(o, 800, speed_ratio=2.1, energy_max=1.0 + EXACT, energy_rise=0.06)
    # measured 3.356 (with tau's T = max(dt, ...) 2.936 (crowding only 2.918; before the crowding tolerance 4.088; start-configuration divergence 3.197)
    assert o.max_cfl > 2.8
    # measured 1.140 (2 s) with the last step's pressure by parts and turning shifts (the scene's since 2026-11-30: the
    # water less damped at this step, still sloshing and throwing spray at 2 s; 1.085 with the compiled solve of small
    # systems, whose last bits differ); 1.100 (2 s) with PSPG's displacement bounded; 1.105 (2 s; 1.100 at 4 s) with tau free of the step (with T = max(dt, ...) 1.095), the scene's particle
    # shifting, the water still sloshing (without 1.015; crowding only
    # 0.975 (2 s), 1.02 (4 s); before the crowding tolerance 0.990 (2 s); from a_0 = 0 0.985); FLIP/PIC
    # 0.915 (2 s)
    assert 0.88 <= cell_ratio(o) <= 1.16
    # the walls act: measured 641 (2 s, surface-aware); crowding only 455 (2 s), 498 (4 s) (before the crowding
    # tolerance 567, 674; 604 with PSPG's viscous
    # part, negligible for water here, built; from a_0 = 0 553); FLIP/PIC 1332 (2 s), 1618 (4 s)
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
    # measured: stopped at 0.62 s, a rise of 0.098 (12 % at the check) with G2P over the moved functions; at 1/55 and
    # 1/45 s completed (0.070) and stopped at 0.47 s. Before: completed, 0.0898; at 1/55 and 1/45 s stopped at 0.75
    # and 0.71 s. The whole PIC share alone (100/s): stopped at 0.52 s
    if o.run.status == "stopped":
        assert o.run.cause.startswith("energy growth") and o.run.time >= 0.4
    else:
        assert o.run.status == "completed" and o.energy_rise <= 0.10
    assert (o.finite, o.particles, abs(o.mass_error) <= 1e-14) == (True, 800, True)


@pytest.mark.parametrize("full", SHORT_AND_FULL)
def test_dam_break_of_water(full):
    """mu = 1e-3 Pa s at the seed's step: the fastest particle is the
    run-up jet at the right wall (t = 0.28 s), 2.25 times free fall from the column's top."""
    o = measured("water", full)
    # measured 2.412, 1.0, 0.0015 at 0.6 s with the last step's pressure by parts and turning shifts (the scene's since
    # 2026-11-30: a faster run-up jet, the energy still never above the start; 2.23 with the split);
    # 2.279, 1.0, 0.0018 at 0.6 s with G2P over the moved functions; 2.250, 1.0, 0.0016 with the default shares (whole 30/s, then the noise's 300/s: the less
    # damped jet runs faster, the energy still never above the start); 2.104, 1.0, 0.0018 at 0.6 s with the scene's particle shifting: the energy no longer rises at the
    # impact; without it 2.018, 1.0076, 0.0084 at 0.6 s and 2 s (before the crowding tolerance 2.022, 1.0082, 0.0085 and
    # 2.02, 1.008, 0.009; from a_0 = 0: 2.025 and 2.085,
    # 1.0083, 0.0086; start-configuration divergence 2.109, 1.0153, 0.0159; FLIP/PIC 1.782, 1.0, 6.3e-5): the
    # affine-FLIP transfer's energy rises by 0.8 % of the start at the wall impact, where FLIP/PIC's only fell
    assert_sound(o, 800, speed_ratio=bound(full, 2.5, 2.5), energy_max=1.0 + bound(full, 0.009, 0.009),
                 energy_rise=bound(full, 0.0095, 0.0095))
    # measured 1.215 (0.6 s), 1.16 (2 s) with the scene's particle shifting (without 1.225, 1.17; from a_0 = 0: 1.215,
    # 1.18); FLIP/PIC 1.16 (0.6 s), 1.10 (2 s)
    assert 1.09 <= cell_ratio(o) <= 1.25
    # measured 89 (0.6 s) with the last step's pressure by parts and turning shifts (the scene's since 2026-11-30);
    # 61 (0.6 s), 156 (2 s) with the walls letting go within the step where they pull hard (fempm.walls; 435
    # lagged) and the scene's particle shifting, whose moves cut at a wall count too
    # (without 61, 193; before the crowding tolerance 50, 81; from a_0 = 0: 52, 175); FLIP/PIC 0. After 0.6 s the
    # count moves by hundreds with any small change of the scheme: 347 before still water's PIC share, 124 without
    # it, 168 and 275 with it ramped in over the time at rest; 0 and 48 to 3 s with a PIC share of 95 or 105 /s (letting
    # go within the step: 0 and 531)
    assert o.wall_stops <= bound(full, 100, 500)


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
    # measured 2.553, 1.0, 0.0023 with the noise's linear fit (2.522, 1.0, 7.5e-5 with its mean); with G2P over the
    # moved functions (2.88, 1.0, 0.0013 over all of them; before the
    # crowding tolerance 2.923, 1.0001, 0.0011): a wave landing on the thin layer that flows back along the floor
    # squeezes out a jet (6.89 m/s at 2.899) (from a_0 = 0: 2.427, 1.00009, 0.0014; start-configuration divergence
    # 2.405, 1.00048, 0.0037; FLIP/PIC 1.562)
    assert_sound(o, 800, speed_ratio=2.93, energy_max=1.0 + bound(full, 6e-4, 6e-4),
                 energy_rise=bound(full, 0.004, 0.004))
    # measured 1.245 (0.6 s) with the noise's linear fit, which leaves the splash's sheet more of its own motion
    # (1.200 with its mean); 1.235 (0.6 s), 1.145 (2 s) before G2P over the moved functions (before the crowding
    # tolerance 1.225, 1.185; from a_0 = 0: 1.235); FLIP/PIC 1.06 (0.6 s), 1.125 (2 s)
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
    # measured 0.984, 1.0, 0 (0.969 with G2P over all functions)
    assert_sound(o, 1, speed_ratio=0.99, energy_max=1.0 + EXACT, energy_rise=EXACT)
    # measured 1.0e-6 with G2P over the moved functions (0.0190 over all of them; the whole share alone at 100/s: 0.00736)
    assert free_fall_error(o, hc.SINGLE[0, 1]) <= 5e-6
    x, y = o.history["centroid"][-1]
    assert x == pytest.approx(hc.SINGLE[0, 0], abs=1e-12)  # nothing pushes it sideways
    # the one-sided floor leaves it at rest on the floor: measured 8.6e-6 m (6e-4 of a cell) and 2e-17 m/s at 0.5 s
    # (6.5e-6 m and 6e-19 m/s with G2P over all functions; the whole share alone at 100/s: 1.5e-11 m and 7.4e-10 m/s;
    # affine, two-sided: 4.5e-5 m, 3.2e-4 m/s)
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
    # measured 0.988, 1.0, 0.0092 with the noise's linear fit (2 s: 0.988, 1.0, 0.0092); 1.029, 1.0, 0.0080 with the walls letting go within the step where they pull hard (fempm.walls); 1.031, 1.0, 0.0078 (before the crowding tolerance 0.0107; from a_0 = 0: 1.030, 1.0, 0.0237; start-configuration divergence 1.046,
    # 1.0, 0.0094; FLIP/PIC 0.865, 1.0, 0.0025 (0.6 s), 0.004 (2 s)); the full version was not rerun with the
    # end-of-step forms
    assert_sound(o, len(hc.SPARSE), speed_ratio=1.05, energy_max=1.0 + EXACT,
                 energy_rise=bound(full, 0.012, 0.025))
    # measured 0.00016 with G2P over the moved functions (0.00056 over all of them; the whole share alone at 100/s:
    # 0.00036): the particles of the cloud's edge lean on functions held for want of material
    assert free_fall_error(o, hc.SPARSE[:, 1].min()) <= 0.0002
    # m, 1.6 h; measured 0.0227 (0.6 s; 0.0151 at 2 s) with PSPG's tau free of the step (with tau's T = max(dt, ...)
    # 0.0187; before the crowding tolerance 0.0217; affine 0.0171); FLIP/PIC 0.0165 (0.6 s), 0.0154 (2 s)
    assert o.surface_height <= 0.0235
    # m; 0.0197 at 0.6 s with the noise's linear fit, the layer settling later and lower (0.0100 at 1 s, 0.0084 at
    # 2 s); 0.0174 at 0.6 s with its mean and the walls letting go within the step (0.0167 lagged; before the
    # crowding tolerance 0.0157, FLIP/PIC 0.0165)
    assert o.history["centroid"][-1, 1] <= bound(full, 0.0210, 2 * hc.h)
    # measured 0.0926 at 0.6 s with the noise's linear fit, the layer settling later (its centroid above); 0.0806 at 0.6 s
    # with its mean and the walls letting go within the step (0.0682 lagged: the held walls took more); (before the crowding tolerance 0.0754; from a_0 = 0 0.0609, before that 0.0764; FLIP/PIC 0.0486): the layer still moves
    assert o.history["energy"][-1] / o.history["energy"][0] <= bound(full, 0.1, 0.1)


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
        # measured 2.280, 1.0, 0.0020 to 40 s with G2P over the moved functions (2.250, 1.0, 0.003 with the default
        # shares, docs/hard-cases.md): its first 2 s are test_dam_break_of_water's, whose jet this is
        # with the hydrostatic pressure's work split off: the energy's largest rise 0.0066 over 40 s; 2.412, 1.0, 0.0016
        # with the last step's pressure by parts and turning shifts (the scene's since 2026-11-30; the faster jet of
        # test_dam_break_of_water)
        assert_sound(o, 800, speed_ratio=2.5, energy_max=1.0 + 0.009, energy_rise=0.008)
    else:  # the big step's energy error: the first 2 s are test_dam_break_at_ten_times_the_seeds_step's
        assert_sound(o, 800, speed_ratio=2.1, energy_max=1.0 + EXACT, energy_rise=0.06)
    t, centroid = o.history["t"], np.asarray(o.history["centroid"])
    if full:  # the layer's surface after 40 s, at one instant of a layer still sloshing: 73.5 mm with the compiled solve
        # of small systems (2026-11-30), 65.8 mm with the last step's
        # pressure by parts and turning shifts (the scene's since 2026-11-30), 72.8 mm with the split, 74.4 mm before
        # (docs/hard-cases.md; 66.7-76.8 mm on earlier codes): it moves with round-off, the mean below does not
        assert o.surface_height == pytest.approx(SETTLED_DEPTH, rel=0.12)
        # its mean depth over the last 5 s, twice its centroid's height: 75.8 mm, std 1.5 mm, with PSPG's tau free of
        # the step (75.4 mm with tau's T = max(dt, ...)) and the scene's particle shifting (without 76.4 mm, std 1.0 mm
        # over those seconds; before the crowding tolerance 77.05; 76.92 with PSPG's viscous part); 76.3 mm with the
        # hydrostatic pressure's work split off; 76.1 mm, std 1.8 mm, with the last step's pressure by parts and turning
        # shifts (the scene's since 2026-11-30); 76.5 mm, std 1.9 mm, with the compiled solve of small systems
        assert 2 * centroid[t >= t[-1] - 5.0, 1].mean() == pytest.approx(0.0763, rel=0.01)
    else:  # after 5 s the layer still sloshes, and its surface at one instant moves with round-off (75.1 and 67.4 mm
        # for two codes that differ in the shifting's last bits): its mean depth over the last second, twice its
        # centroid's height, measured 78.1 mm with the last step's pressure by parts and turning shifts (the scene's
        # since 2026-11-30: less damped at this step, the layer sloshes higher; 76.1 mm with the compiled solve of small
        # systems, whose last bits differ), 76.5 mm with the hydrostatic
        # pressure's work split off (the divergence form 75.3 and 74.6 mm, std 1.5 mm), within 8 % of SETTLED_DEPTH = 73 mm
        assert 2 * centroid[t >= t[-1] - 1.0, 1].mean() == pytest.approx(SETTLED_DEPTH, rel=0.08)
    # the energy left: a still layer keeps SETTLED_DEPTH / H = 1/4 of the column's; measured 0.292 at 5 s with the
    # last step's pressure by parts and turning shifts (0.276 with the compiled solve of small systems; 0.283 with the
    # split); 0.264 at 5 s
    # (from a_0 = 0 0.277; start-configuration divergence 0.280)
    assert o.history["energy"][-1] / o.history["energy"][0] <= bound(full, 0.30, 1.4 * SETTLED_DEPTH / hc.H)
