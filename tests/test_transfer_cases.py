"""The transfers on the cases of issue 11: Taylor-Green, Gresho, the column at rest, the dam break.

The short versions run in the default suite; the studies of ``benchmarks/transfer_study.py``
(``docs/verification.md``) are marked ``full``. FLIP/PIC is the seed's transfer (10 % PIC per
step), affine-FLIP the default (APIC's affine parts, FLIP increments, a PIC share of 100/s).
"""

import numpy as np
import pytest
from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import diagnostics
from fempm.cases import column, dambreak, vortices
from fempm.simulation import build_solver

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial studies")


def held_at_rest(r: dict, speed: float, volume: float = 0.0020):
    """A column.rest run ended completed, slower than ``speed`` m/s, its volume grown by less than ``volume``."""
    print(r)
    assert r["status"] == "completed"
    assert r["speed"] < speed
    assert 0 < r["volume"] < volume


def test_the_largest_change_is_the_signed_change_of_largest_magnitude():
    assert vortices.largest_change([1.01, 0.97, 1.02], 1.0) == pytest.approx(-0.03)
    assert vortices.largest_change([], 2.0) == 0.0


def test_taylor_green_dissipation_of_affine_flip_falls_with_dt_and_flip_pic_grows():
    """32², nu = 1e-6, t = 0.25: the numerical dissipation rate (beyond 4 pi^2 nu) of affine-FLIP is
    below 1 % per unit time and falls as dt falls; FLIP/PIC's is ten times larger and grows."""
    coarse = vortices.taylor_green("affine-FLIP", 32, 0.0125, 1e-6)
    fine = vortices.taylor_green("affine-FLIP", 32, 0.003125, 1e-6)
    print(coarse["numerical"], fine["numerical"])
    assert 0 < coarse["numerical"] < 0.0050  # measured 4.67e-3 per unit time (start-configuration divergence 7.19e-3)
    assert 0 < fine["numerical"] < 0.8 * coarse["numerical"]  # measured 3.36e-3 (0.72 of it)
    old = vortices.taylor_green("FLIP/PIC", 32, 0.003125, 1e-6)
    print(old["numerical"])
    assert old["numerical"] > 0.25  # measured 0.307 (8.3e-2 at dt 0.0125)


def test_taylor_green_at_re_100_decays_at_the_viscous_rate():
    """32², Re = 100 (nu = 0.01), t = 0.25: the energy decays at 4 pi^2 nu, affine-FLIP's numerical part
    under 1 % of it and FLIP/PIC's about 19 % (issue 11 reports both Reynolds numbers)."""
    new = vortices.taylor_green("affine-FLIP", 32, 0.0125, 0.01)
    old = vortices.taylor_green("FLIP/PIC", 32, 0.0125, 0.01)
    print(new["numerical"], old["numerical"], new["viscous"])
    assert new["status"] == old["status"] == "completed"
    assert 0 < new["numerical"] < 0.0025  # measured 1.70e-3 per unit time (the viscous rate 0.395)
    assert abs(new["ke_end"] / new["exact_end"] - 1) < 6e-4  # measured 3.9e-4 below the exact exp(-4 pi^2 nu t)
    assert old["numerical"] > 0.06  # measured 7.58e-2


def test_gresho_vortex_short():
    """32², t = 0.25, u dt/h = 0.4: affine-FLIP keeps the kinetic energy within 2 % (FLIP/PIC loses 9 %)
    and the angular momentum within 0.14 % (0.1 % with the whole share alone at 100/s; -0.05 % at dt/4). With the divergence on the start
    configuration the vortex expanded and its angular momentum grew in proportion to dt: +2.9 %,
    +0.75 % at dt/4."""
    new = vortices.gresho("affine-FLIP", 32, 0.0125, 0.25)
    old = vortices.gresho("FLIP/PIC", 32, 0.0125, 0.25)
    print(new, old)
    assert new["status"] == old["status"] == "completed"
    # measured -1.18 % (the whole PIC share alone at 100/s -1.91 %; start-configuration divergence, alpha 0: -2.38 %)
    assert -0.020 < new["ke"] < 0
    assert old["ke"] < -0.085  # measured -8.86 % (before the crowding tolerance -8.81 %)
    # measured -0.126 %, profile 3.77 % (FLIP/PIC's profile 6.56 %; with the start configuration's divergence +2.87 %,
    # 6.29 %)
    assert -0.0014 < new["L"] < 0
    assert new["profile"] < 0.052


def test_fem_only_reference_keeps_both_vortices():
    """The FEM-only reference (the same forms on the fixed grid with Gauss quadrature and Oseen convection,
    ``vortices.fem_reference``) at 32², u dt/h = 0.4, t = 0.25: Taylor-Green at nu = 1e-6 decays at the
    viscous rate, Gresho keeps its energy and angular momentum: what the MPM loses beyond them on the same
    grid and step (the two tests above) its particles lose."""
    tg = vortices.fem_reference("taylor_green", 32, 0.0125, 0.25, 1e-6)
    gresho = vortices.fem_reference("gresho", 32, 0.0125, 0.25)
    print(tg, gresho)
    assert tg["status"] == gresho["status"] == "completed"
    assert abs(tg["numerical"]) < 1e-6  # measured 9.8e-8 per unit time (the MPM's 4.67e-3)
    assert -5e-4 < gresho["ke"] < 0  # measured -0.026 % (the MPM's -1.91 %)
    assert abs(gresho["L"]) < 2e-4  # measured -0.008 % (the MPM's -0.092 %)
    assert gresho["profile"] < 0.016  # measured 1.49 %, 1.00 % at the start (the MPM's 4.91 %)


def test_gresho_energy_loss_falls_under_refinement_with_the_scenes_particle_handling():
    """32² and 64², t = 0.5, max u dt/h = 0.4, handled as the shipped dam break handles its particles
    (shifting, the surface-aware correction): the energy's loss falls fourfold or more as h halves, the
    angular momentum's and the profile's too (at t = 3 and on 128² too: ``transfer_study.py --full --case
    scene_vortices``, docs/verification.md)."""
    coarse, fine = (vortices.gresho("affine-FLIP", n, 0.4 / n, 0.5, shifting=vortices.SHIFTING, surface_aware=True)
                    for n in (32, 64))
    print(coarse, fine)
    assert coarse["status"] == fine["status"] == "completed"
    assert -0.040 < coarse["ke"] < 0  # measured -2.63 % (the whole share alone at 100/s: -3.86 %)
    assert max(-0.0085, 0.25 * coarse["ke"]) < fine["ke"] < 0  # measured -0.574 % (0.22 of 32²'s; -0.80 %, 0.21)
    assert -0.0050 < coarse["L"] < 0  # measured -0.463 % (the whole share alone at 100/s: -0.374 %)
    assert 0.5 * coarse["L"] < fine["L"] < 0  # measured -0.122 % (-0.118 %)
    assert fine["profile"] < 0.5 * coarse["profile"]  # measured 2.14 % against 5.32 % (2.60 % against 6.40 %)


def test_the_pic_share_on_the_noise_alone_keeps_more_of_the_gresho_vortex():
    """64², t = 0.5, the shipped particle handling: the PIC share on the particles' noise alone
    (vortices.NOISE_ONLY, transfer.NoiseFilter) loses less energy and a smaller profile error than the
    whole share alone at 100/s (vortices.WHOLE_SHARE; t = 3: ``transfer_study.py --full --case noise_filter``)."""
    r = vortices.gresho("affine-FLIP", 64, 0.4 / 64, 0.5, shifting=vortices.SHIFTING, surface_aware=True,
                        pic=vortices.NOISE_ONLY)
    print(r)
    assert r["status"] == "completed"
    # measured -0.489 % with the noise's linear fit (-0.471 % with its mean; the whole share alone: -0.797 %; the
    # default: -0.574 %)
    assert -0.0055 < r["ke"] < 0
    assert -0.0016 < r["L"] < 0  # measured -0.144 % with the noise's linear fit (-0.124 % with its mean; -0.118 %; -0.122 %)
    assert r["profile"] < 0.019  # measured 1.29 % with the noise's linear fit (1.86 % with its mean; 2.60 %; 2.14 %)


def test_shifts_that_add_no_angular_momentum_keep_the_gresho_vortex_s_angular_momentum():
    """As above, with the shifts also keeping the angular momentum (vortices.NOISE_ONLY_TURNING,
    shifting.ParticleShifting): the angular momentum's drift is a sixth (t = 3: ``transfer_study.py --full
    --case noise_filter``)."""
    r = vortices.gresho("affine-FLIP", 64, 0.4 / 64, 0.5, shifting=vortices.SHIFTING, surface_aware=True,
                        pic=vortices.NOISE_ONLY_TURNING)
    print(r)
    assert r["status"] == "completed"
    assert -0.0025 < r["ke"] < 0  # measured -0.216 % (the noise-only share alone: -0.471 %)
    assert abs(r["L"]) < 0.0003  # measured -0.019 % (-0.124 %)


def _vortex_settings_beside(defect):
    """A test over the vortex settings (``vortices.VORTEX_SETTINGS``, which pass) and the divergence form (``defect``,
    a strict expected failure)."""
    return pytest.mark.parametrize("scheme", [vortices.VORTEX_SETTINGS, pytest.param({}, marks=defect)],
                                   ids=["vortex-settings", "divergence"])


_CORE_DEFECT = pytest.mark.xfail(strict=True, reason=(
    "an open defect of the divergence form (solver.pressure_work = 'divergence', or the split, which without gravity "
    "is the same): from t ~ 0.3 the vortex's core thins, PSPG turning the particle quadrature's pressure error into a "
    "source at the centre, and once below fempm.density.DEEP the surface-aware correction takes the void for a free "
    "surface and leaves it open (the smoothed density at the centre 0.911 at t = 0.5, 0.646 at t = 1, 0.419 at t = 3; "
    "without PSPG, with the pressure's terms at Gauss points, or with the last step's pressure by parts the core stays "
    "filled: tests/test_pressure_points.py; docs/notes-accuracy.md)"))


@_vortex_settings_beside(_CORE_DEFECT)
def test_the_gresho_vortex_keeps_its_core_filled(scheme):
    """64², max u dt/h = 0.4, t = 1, the shipped particle handling: the smoothed density at the vortex's
    centre stays within 10 % of the water's."""
    r = vortices.gresho("affine-FLIP", 64, 0.4 / 64, 1.0, shifting=vortices.SHIFTING, surface_aware=True, pic=scheme)
    print(r)
    assert r["status"] == "completed"
    assert r["core"] > 0.9  # measured 1.000 with the vortex settings (the divergence form 0.646)


def test_column_stays_at_rest_with_affine_flip():
    """The dam-break column held 0.5 s (dt 1 ms): volume within 0.2 %, speeds below 1e-3 m/s."""
    r = column.rest("affine-FLIP", 0.5)
    print(r)
    assert r["status"] == "completed"
    assert abs(r["volume"]) < 0.002  # measured -5.8e-4 (before the crowding tolerance -1.5e-4)
    # measured 6.88e-4 m/s (before the crowding tolerance 4.65e-4; largest over the run 1.16e-3, while settling)
    assert r["speed"] < 7.5e-4


def test_particle_shifting_lowers_the_taylor_green_loss_at_64_cells():
    """nu = 1e-6, 64², U dt/h = 0.4, to t = 0.25: the dam break's particle shifting keeps the particles, the
    quadrature points, evenly spread (fempm.shifting)."""
    shifted = vortices.taylor_green("affine-FLIP", 64, 0.4 / 64, 1e-6, shifting=vortices.SHIFTING)["numerical"]
    unshifted = vortices.taylor_green("affine-FLIP", 64, 0.4 / 64, 1e-6)["numerical"]
    assert 0 < shifted < 0.0047  # measured 4.59e-3 per unit time (the whole share alone at 100/s: 4.40e-3)
    assert unshifted > 0.0050  # measured 5.13e-3


@pytest.mark.full
def test_taylor_green_at_64_cells():
    """nu = 1e-6, 64², U dt/h = 0.4, 0.2, 0.1, the dam break's particle shifting: below 1 % per unit time and
    falling as dt falls. (Under refinement it does not fall: 32² loses 4.39e-3, below 64²'s 4.59e-3; with the
    whole share alone at 100/s 4.63e-3 and 4.40e-3, and without shifting 4.67e-3 and 5.13e-3: see the strict
    expected failure below.)"""
    rates = [vortices.taylor_green("affine-FLIP", 64, c / 64, 1e-6, shifting=vortices.SHIFTING)["numerical"]
             for c in (0.4, 0.2, 0.1)]
    print(rates)
    assert max(rates) < 0.005  # measured 4.50e-3, 2.57e-3, 1.77e-3
    assert rates[2] < rates[1] < rates[0]


_REFINEMENT_DEFECT = pytest.mark.xfail(strict=True, reason="in divergence form (or the split, the same without "
                   "gravity) the loss does not fall from 64² to 128² at U dt/h = 0.4 (to t = 0.25): "
                   "4.59e-3 / 7.03e-3 with the particle shifting and the default PIC shares (the whole share alone "
                   "4.40e-3 / 7.46e-3; without shifting 5.13e-3 / 3.25e-2; without PSPG 1.44e-3 at 128², and with "
                   "shifting 8.5e-4 / 9.0e-4). Without shifting the loss followed the particles' disorder in cells, which a finer "
                   "grid reaches sooner (docs/verification.md, 'How it grows'); with it too: the particles reseeded onto "
                   "the lattice every 5 steps lose 3.4e-3 / 4.3e-4 / 5.4e-5 at 32² / 64² / 128², but each reseed is a "
                   "pressure impulse under gravity (docs/notes-accuracy.md, 'The particles reseeded'). PSPG's share: "
                   "its term at half and a quarter gives 6.2e-3 and 5.1e-3 at 128² against 3.7e-3 and 3.2e-3 at 64², the "
                   "loss falling fast only as the term goes (1.44e-3 without). The pressure's terms at fixed Gauss "
                   "points (solver.pressure_quadrature = 'gauss', an option) give 4.5e-4 / 7.6e-5 "
                   "(tests/test_pressure_points.py, docs/pressure-quadrature.md); the vortex settings (the last step's "
                   "pressure by parts, turning shifts) 2.10e-3 / 7.10e-4")


@pytest.mark.full
@_vortex_settings_beside(_REFINEMENT_DEFECT)
def test_taylor_green_loss_falls_under_refinement(scheme):
    """nu = 1e-6, U dt/h = 0.4, the dam break's particle shifting: the loss at 128² below the loss at 64²."""
    fine, coarse = (vortices.taylor_green("affine-FLIP", n, 0.4 / n, 1e-6, shifting=vortices.SHIFTING,
                                          pic=scheme)["numerical"] for n in (128, 64))
    print(fine, coarse)
    assert fine < 0.5 * coarse  # measured 7.10e-4 against 2.10e-3 with the vortex settings


_TURNOVER_DEFECT = pytest.mark.xfail(strict=True, reason="in divergence form (or the split) over one turnover the "
                   "energy falls to 0.983 at t = 1 with the particle "
                   "shifting, a fitted loss of 1.85e-2 per unit time (the whole PIC share alone: 0.981, 1.96e-2), growing from t ~ 0.5 (without shifting 0.696 "
                   "and 0.43, the drop starting at t ~ 0.25-0.45 as the particles' disorder grew; FLIP/PIC 0.708)")


@pytest.mark.full
@_vortex_settings_beside(_TURNOVER_DEFECT)
def test_taylor_green_over_one_turnover(scheme):
    """nu = 1e-6, 64², U dt/h = 0.4, to t = 1, the dam break's particle shifting: issue 11's 1 % per unit
    time over a whole turnover."""
    result = vortices.taylor_green("affine-FLIP", 64, 0.4 / 64, 1e-6, end=1.0, shifting=vortices.SHIFTING, pic=scheme)
    print(result)
    assert result["status"] == "completed"
    assert result["numerical"] < 0.01  # measured 3.26e-3 with the vortex settings, the energy 0.9975 at t = 1


@pytest.mark.full
def test_gresho_vortex_to_t_3():
    """64², t = 3 (issue 11's targets, KE within 1 % and angular momentum within 0.1 %, are not met by
    either transfer, nor with the particle shifting: the particles' disorder grows after t ~ 1); affine-FLIP
    loses less energy, and less again with the shifting."""
    new, old = (vortices.gresho(v, 64, 0.4 / 64, 3.0) for v in ("affine-FLIP", "FLIP/PIC"))
    print(new, old)
    assert new["status"] == old["status"] == "completed"
    assert old["ke"] < new["ke"] < -0.085  # measured -11.5 % (FLIP/PIC -43.1 %)
    assert 0 < new["L"] < 0.0080  # measured +0.703 % (FLIP/PIC +0.019 %)
    # the dam break's particle shifting: the energy kept 7 times better, the angular momentum as far off, the other way
    shifted = vortices.gresho("affine-FLIP", 64, 0.4 / 64, 3.0, shifting=vortices.SHIFTING)
    print(shifted)
    assert max(new["ke"], -0.030) < shifted["ke"] < 0  # measured -1.69 %
    assert -0.0080 < shifted["L"] < 0  # measured -0.420 %


@pytest.mark.full
def test_gresho_vortex_with_turning_shifts_at_half_the_step_meets_issue_11():
    """64², t = 3, max u dt/h = 0.2, 2 × 2 per cell, the default PIC shares and shifts that add no angular
    momentum (vortices.TURNING): kinetic energy within 1 % and angular momentum within 0.1 %, at the end and
    over the run. Without the turning shifts the default loses -1.32 % (-2.01 % at twice the step); the whole
    share alone at 100/s, the default before, lost more at this step than at twice it (-2.97 % against
    -2.61 %; transfer_study.py --full --case noise_filter)."""
    r = vortices.gresho("affine-FLIP", 64, 0.2 / 64, 3.0, shifting=vortices.SHIFTING, surface_aware=True,
                        pic=vortices.TURNING)
    print(r)
    assert r["status"] == "completed"
    assert -0.0095 < r["ke"] < 0  # measured -0.90 %
    assert abs(r["L"]) < 0.0010  # measured +0.018 % at the end
    assert abs(r["L_largest"]) < 0.0010  # measured -0.097 % at worst (the FEM-only reference's own: +0.139 %)


@pytest.mark.full
def test_gresho_vortex_with_both_options_at_3_by_3_per_cell_keeps_its_energy_to_1_percent():
    """64², t = 3, 3 × 3 per cell, the PIC share on the noise alone and shifts that add no angular momentum
    (vortices.NOISE_ONLY_TURNING): issue 11's kinetic energy within 1 % holds. Its angular momentum within
    0.1 % does not: it swings by a few tenths of a per cent over the run at 2 × 2 and 3 × 3, with either share
    and with or without the turning shifts (transfer_study.py --full --case noise_filter)."""
    r = vortices.gresho("affine-FLIP", 64, 0.4 / 64, 3.0, per_cell=3, shifting=vortices.SHIFTING, surface_aware=True,
                        pic=vortices.NOISE_ONLY_TURNING)
    print(r)
    assert r["status"] == "completed"
    assert -0.0080 < r["ke"] < 0  # measured -0.652 %
    assert -0.0050 < r["L_largest"] < 0  # measured -0.359 %, at the end


@pytest.mark.full
def test_column_at_rest_for_10_s():
    """Speeds far below 1e-3 m/s; the volume grows by 0.18 %, within issue 11's 0.2 % (FLIP/PIC: 0.16 %):
    the one-sided volume correction's, not the transfer's; 0.33 % before the correction left crowding within
    its tolerance alone (forms/incompressible.py, CROWDING_TOLERANCE). With the end-of-step map whole at rest
    (forms/incompressible.py, faded_at_rest) a mode in the bottom corner grew 4x per 0.5 s from
    t ~ 8.5 s, to 1.88e-3 m/s at 10 s."""
    r = column.rest("affine-FLIP", 10.0)
    print(r)
    assert r["status"] == "completed"
    assert 0 < r["volume"] < 0.0020  # measured 0.00182
    # measured 2.3e-5 m/s at the end (7.2e-4 at most, while settling); the bound is issue 11's 1e-3 less a margin
    assert r["speed"] < 5e-4


def test_the_shipped_scenes_column_at_rest_for_10_s():
    """Issue 11's column at rest with the shipped scene's step and solver (the dam break's column in a tank as wide as
    it, 10 x 40 cells, docs/still-water.md's): speeds below 1e-3 m/s after it settles, the volume within 0.2 %."""
    width = column.WIDTH
    changes = {"gauges": None, "time.end": 10.0, "domain.upper": [width, 4 * width], "domain.cells": [10, 40],
               "bodies.0.upper": [width, column.HEIGHT]}
    solver = build_solver(dambreak.scene(changes, files=False), MPI.COMM_WORLD)
    start, settled = diagnostics.surface_height(solver.particles), 0.0
    while solver.time < 10.0 - 1e-9:
        solver.step(until=10.0)
        if solver.time > 1.0:
            settled = max(settled, solver.fastest())
    volume = diagnostics.surface_height(solver.particles) / start - 1
    print(solver.fastest(), settled, volume)
    assert solver.fastest() < 1e-4  # measured 8.8e-6 m/s at 10 s (the split 3.8e-5)
    assert settled < 1e-3  # measured 3.6e-4 m/s at most after the first second
    assert abs(volume) < 0.002  # measured -0.180 %, near issue 11's bound (the split +0.102 %)


def test_column_stays_at_rest_for_14_s():
    """Past the 10 s of issue 11. Without a PIC share of its own for water at rest (Scheme.rest_pic_rate = 0) a
    mode of the bottom corner cell's particles, turning about its centre, grew about 4 times per 0.5 s from
    t ~ 9 s (dt 1 ms; from 8.5 s at 0.5 ms), to 0.17 m/s at 14 s, the volume +1.08 %; the seed's FLIP/PIC stayed
    at rest (4.2e-5 m/s). With the share rising to 300/s below 0.01 sqrt(|g| h) it stays (at 0.25 ms to 10 s:
    3.1e-5 m/s, +0.178 %)."""
    r = column.rest("affine-FLIP", 14.0)
    print(r)
    assert r["status"] == "completed"
    assert r["speed"] < 1e-4  # measured 1.12e-5 m/s (without the rest share 0.17 m/s)
    assert 0 < r["volume"] < 0.0021  # measured +0.197 %


_DIVERGENCE_DEFECT = pytest.mark.xfail(strict=True, reason=(
    "an open defect of the divergence form (solver.pressure_work = 'divergence', the shipped scene's until 2026-11-29): "
    "its column holds at rest only from the seeding lattice. Its particles moved by at most 1e-4 of their spacing, at "
    "random, it reaches 9.4e-2 m/s at 1.5 s (by 1e-5: 1.2e-2 m/s at 6 s; by 1e-3: 0.11 m/s at 0.5 s; by 0.3, a flow's "
    "disorder: 0.2-0.4 m/s from 0.5 s on); also at a fixed 1 ms step, without the end-of-step map (later), the "
    "shifting, the volume correction, with PSPG's tau 4 or 1/4 times. FLIP holds this start (8e-5 m/s at 4 s) but not "
    "a flow's disorder (0.08-0.18 m/s), the Gauss option both (2.4e-4 m/s; 4e-3 to 9e-3 m/s), the pressure's work by "
    "parts this start (2.8e-4 m/s at 2 s, tests/test_pressure_work.py) but not a flow's disorder (1e-2 m/s), the split "
    "this start (1.0e-4 m/s at 2 s, 1.0e-3 at 8 s) and a flow's disorder to 6.0e-2 m/s (tests/test_hydrostatic.py): the "
    "hydrostatic pressure times the particle quadrature's error in div(p w) (docs/notes-accuracy.md, 'Water at rest "
    "from a disordered start' and 'Where the disordered column's energy comes from')"))


@pytest.mark.parametrize("work", ["increment", "split", pytest.param("divergence", marks=_DIVERGENCE_DEFECT)])
def test_a_column_at_rest_from_slightly_disordered_particles_stays_at_rest(work):
    """The dam break's column in a tank as wide as it, the shipped scene's step and solver, its particles moved
    at random by at most 1e-4 of their spacing (0.73 micrometres): a start no flow ever leaves as exact as a lattice."""
    width = column.WIDTH
    changes = {"gauges": None, "time.end": 2.0, "domain.upper": [width, 4 * width], "domain.cells": [10, 40],
               "bodies.0.upper": [width, column.HEIGHT], "solver.pressure_work": work}
    solver = build_solver(dambreak.scene(changes, files=False), MPI.COMM_WORLD)
    spacing = width / 20
    p = solver.particles
    p.fields["x"] = solver.walls.keep_inside(p.x + 1e-4 * spacing * np.random.default_rng(1).uniform(-1, 1, p.x.shape))
    while solver.time < 2.0 - 1e-9:
        solver.step(until=2.0)
    print(work, solver.fastest())
    # measured 1.9e-4 m/s with the shipped increment; 1.0e-4 m/s with the split (the divergence form 0.17 m/s; from the
    # lattice 9.3e-5 m/s); each with the scene's turning shifts
    assert solver.fastest() < 1e-3


def test_column_stays_at_rest_at_ten_ms_steps():
    """At a fixed 10 ms step, the adaptive step's largest (which water at rest takes), for 14 s. Before PSPG's
    displacement in a step was bounded (forms/incompressible.py, TAU_STEP_DISPLACEMENT) a vertical mode grew, cells
    alternately up and down: 9e-3 m/s at 2 s, 0.3 m/s at 4 s, the volume -2 %; also without the end-of-step map,
    without the volume correction, with alpha 1, two-sided walls, gamma 0.6, at every PIC share and 3 x 3 per cell.
    The bound at twice its value (0.003) does not hold it (3.6e-3 m/s at 2 s, 0.21 m/s at 4 s)."""
    # measured 2.79e-5 m/s (without the bound 0.33 m/s at 4 s; 5.5e-4 while settling), +0.133 %
    held_at_rest(column.rest("affine-FLIP", 14.0, dt=1e-2), speed=1e-4)


@pytest.mark.full
@pytest.mark.xfail(strict=True, reason="an open defect: past 16 s at 10 ms steps a mode grows again (1.1e-3 m/s at "
                   "18 s, 0.27 m/s at 20 s; with the bound halved, from 20 s: 4.5e-4 at 20 s, 9.3e-2 at 22 s). On cells half "
                   "as large (20 x 80) the column fails at 5 ms with the bound or without (1.2 m/s at 2 s; "
                   "without, 0.72 m/s at 8 s) and from 12 s at 2.5 ms (0.34 m/s at 14 s; the bound does not bind there), the seed's FLIP/PIC too: the "
                   "particles' quadrature of the pressure in water many cells deep. With the pressure's terms at Gauss points "
                   "(solver.pressure_quadrature = 'gauss') that column stays at rest (tests/test_pressure_points.py)")
def test_column_stays_at_rest_at_ten_ms_steps_for_20_s():
    """The column 20 cells deep, as the dam break's, at 10 ms steps past 16 s."""
    r = column.rest("affine-FLIP", 20.0, dt=1e-2)
    print(r)
    assert r["status"] == "completed"
    assert r["speed"] < 1e-3  # measured 0.27 m/s


@pytest.mark.full
def test_a_column_40_cells_deep_stays_at_rest_at_5_ms_steps():
    """Twice the dam break's depth (0.584 m, 40 cells, in a tank twice as high) at 5 ms steps for 14 s; at
    10 ms it does not (next)."""
    # measured 1.0e-5 m/s, +0.087 %
    held_at_rest(column.rest("affine-FLIP", 14.0, dt=5e-3, height=2 * column.HEIGHT, tank_height=4 * column.HEIGHT),
                 speed=1e-4)


@pytest.mark.full
@pytest.mark.xfail(strict=True, reason="an open defect: a column 40 cells deep at 10 ms steps grows a mode within 2 s "
                   "(1.9 m/s at 2 s; the energy check stops it at 2.24 s, the volume -18 %), with PSPG's displacement in "
                   "a step bounded to 0.0015 of a cell, to half of it, or to a share scaled by the particle's pressure head "
                   "(each stopped by 2.5 s): not PSPG's loop. 20 cells deep it holds to 16 s, and 40 deep at 5 ms to 14 s; "
                   "the adaptive step, which the pressure's speed sqrt(p / rho) bounds (fempm.stepper.StepControl), holds it")
def test_a_column_40_cells_deep_stays_at_rest_at_10_ms_steps():
    r = column.rest("affine-FLIP", 4.0, dt=1e-2, height=2 * column.HEIGHT, tank_height=4 * column.HEIGHT)
    print(r)
    assert r["status"] == "completed"
    assert r["speed"] < 1e-3


def test_the_adaptive_step_holds_a_column_40_cells_deep_at_rest():
    """The shipped scene's step (Courant 0.8, at most 10 ms) on a column 40 cells deep: the pressure's speed
    sqrt(p / rho) at its floor (2.4 m/s) bounds the step at about 4.9 ms, where a fixed 10 ms grows a mode (above)."""
    r = column.rest("affine-FLIP", 14.0, dt=1e-2, height=2 * column.HEIGHT, tank_height=4 * column.HEIGHT, courant=0.8)
    # measured 1.03e-5 m/s (at a fixed 10 ms the energy check stopped it at 2.24 s), +0.087 %
    held_at_rest(r, speed=1e-4)
    assert 2700 < r["steps"] < 3000  # measured 2860: 4.9 ms on average


@pytest.mark.full
def test_the_adaptive_step_holds_a_column_on_cells_half_as_large_at_rest():
    """The dam break's column on 20 x 80 cells (40 cells deep): at fixed 5 ms it grows a mode within 2 s; the adaptive
    step (Courant 0.8, at most 10 ms) takes about 3.5 ms."""
    # measured 7.4e-6 m/s (fixed 5 ms: 1.2 m/s at 2 s), +0.087 %
    held_at_rest(column.rest("affine-FLIP", 14.0, dt=1e-2, cells=20, courant=0.8), speed=1e-4)


@pytest.mark.full
def test_dambreak_front_converges_as_dt_falls():
    """40², fixed steps of 1, 0.5, 0.25 and 0.125 ms: within 2.5 % of interFoam 160², the fronts' differences from one
    halving to the next falling (converging in dt), so that the error's change as dt falls is its approach to the grid's
    own limit, not a loss that grows with the steps."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import transfer_study

    rows = transfer_study.dambreak_step_halvings("affine-FLIP", 40, (1e-3, 5e-4, 2.5e-4, 1.25e-4))["rows"]
    errors, halvings = [r["error"] for r in rows], [r["halving"] for r in rows[1:]]
    print(errors, halvings)
    # measured 1.990, 1.967, 1.965, 1.968 % with the last step's pressure by parts and turning shifts (the scene's since
    # 2026-11-30), falling as dt does; 1.861, 1.868, 1.878, 1.887 % (6.25e-5 s: 1.891 %) in divergence form with the
    # noise's linear fit; with its mean before 1.988, 2.029, 2.064 %; the whole share alone at 100/s 1.933, 1.943, 1.959 %
    assert max(errors) < 0.0205
    # measured 0.261, 0.089, 0.039 % with the last step's pressure by parts and turning shifts; 0.206, 0.132, 0.048 %
    # with the hydrostatic pressure's work split off (the errors 1.865, 1.871, 1.883, 1.891 %); in divergence form
    # 0.230, 0.097, 0.058 % (then 0.025 %): about first order
    assert halvings[1] < 0.7 * halvings[0] and halvings[2] < 0.75 * halvings[1]
    assert max(errors[1:3]) <= errors[0] + 0.0003  # measured +0.017 points at dt/4 (+0.076 with the mean)


def test_the_gauss_pressure_study_holds_a_column_whose_surface_is_on_a_cell_edge_to_round_off():
    """benchmarks/pressure_quadrature.py, weighting ``cells``: the pressure's terms at Gauss points weighted 1
    in every cell the column fills are exact for its hydrostatic pressure, so it stays at rest at 10 ms steps
    (where the shipped quadrature grows a vertical mode, the test above); half-way up a cell it does not."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import pressure_quadrature

    on_edge = column.rest("affine-FLIP", 1.0, dt=1e-2, solver_type=pressure_quadrature.solver_type("cells"))
    mid_cell = column.rest("affine-FLIP", 1.0, dt=1e-2, solver_type=pressure_quadrature.solver_type("cells"),
                           height=1.95 * column.WIDTH)
    print(on_edge, mid_cell)
    assert on_edge["status"] == mid_cell["status"] == "completed"
    assert on_edge["peak"] < 1e-12  # measured 3.2e-15 m/s (1.3e-14 to 15 s, docs/pressure-quadrature.md)
    assert abs(on_edge["volume"]) < 1e-12
    assert mid_cell["peak"] > 1e-4  # measured 1.75e-3 m/s (to 15 s: 1.3e-1 at most)
