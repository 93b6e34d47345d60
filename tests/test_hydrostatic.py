"""The split of the pressure's work (``solver.pressure_work = "split"``, fempm.hydrostatic): the hydrostatic
pressure it takes by parts, and what it does to water at rest and to the dam break."""

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm.cases import dambreak, hard, vortices
from fempm.errors import InputError
from fempm.hydrostatic import BELOW, DRY, FULL, HydrostaticPressure
from fempm.simulation import build_solver
from fempm.space import Space

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import still_water  # noqa: E402
import wall_pressure  # noqa: E402
from helpers import assert_the_dam_break_is_the_same_on_1_and_2_ranks  # noqa: E402

RHO, G = 1000.0, 9.81


def _dryness(phi: float, far: float) -> float:
    return 0.0 if phi <= DRY else far if phi >= FULL else min((phi - DRY) / (FULL - phi), far)


def _brute_force(fraction, basis, grid, open_sides):
    """``H`` of fempm.hydrostatic written out: every pair of functions for the distance to the water's edge."""
    nfy, nfx = fraction.shape
    h, far = grid.h, float(nfx + nfy)
    heights = h * basis.greville(grid.ny, float(grid.last[1]))
    widths = h * basis.side_integrals(grid.ny, float(grid.last[1]))
    sources = [(j, i, _dryness(fraction[j, i], far)) for j, i in itertools.product(range(nfy), range(nfx))]
    sources += [(j, -1, 0.0) for j in range(nfy)] if "left" in open_sides else []
    sources += [(nfy, i, 0.0) for i in range(nfx)] if "top" in open_sides else []
    out = np.zeros((nfy, nfx))
    for j, i in itertools.product(range(nfy), range(nfx)):
        distance = min(far, min(d + max(abs(j - b), abs(i - a)) for b, a, d in sources))
        depth = min(widths @ fraction[:, i] - heights[j], h * distance) - BELOW * h
        out[j, i] = RHO * G * max(depth, 0.0)
    return out


@pytest.mark.mpi
@pytest.mark.parametrize("open_sides", [(), ("left", "top")])
def test_the_hydrostatic_pressure_is_the_brute_force_one_on_every_rank(open_sides):
    """A wet region with a step in its surface, a dry hole, partly wet functions and a lone wet function above it,
    on a grid whose top cell is cut: on every rank the local functions' ``H`` is the brute-force one's, to round-off."""
    grid = fempm.Grid(MPI.COMM_WORLD, (0.0, 0.0), (0.3, 0.34), 0.025)  # 12 x 14 cells, the top one 0.6 of a cell
    basis = fempm.BSpline2(grid)
    space = Space(basis, {"m": 1})
    nfy, nfx = basis.nfy, basis.nfx
    j, i = np.meshgrid(np.arange(nfy), np.arange(nfx), indexing="ij")
    fraction = np.where(j < np.where(i < 6, 10, 7), 1.0, 0.0)
    fraction[3:5, 2:4] = 0.2  # a dry hole
    fraction[12, 9] = 0.9  # a lone wet function above the water
    fraction[9, 4] = 0.7  # partly wet ones in the water
    fraction[6, 9] = 0.45
    fraction[9, 1] = 0.35
    local = space.numbering.local_functions
    H = HydrostaticPressure(space, (0.0, -G), RHO, open_sides)(fraction.reshape(-1)[local])
    expected = _brute_force(fraction, basis, grid, open_sides).reshape(-1)[local]
    np.testing.assert_allclose(H, expected, rtol=1e-13, atol=1e-9)  # measured equal to the last bits
    deepest = grid.comm.allreduce(float(expected.max(initial=0.0)), op=MPI.MAX)
    assert deepest > 3 * RHO * G * grid.h  # measured 4 rho g h: the test reaches water deeper than BELOW


def test_the_hydrostatic_pressure_is_zero_without_gravity_along_y():
    grid = fempm.Grid.from_cells(MPI.COMM_SELF, (0.0, 0.0), (1.0, 1.0), (4, 4))
    space = Space(fempm.BSpline2(grid), {"m": 1})
    n = len(space.numbering.local_functions)
    assert not HydrostaticPressure(space, (G / 2**0.5, -G / 2**0.5), RHO)(np.ones(n)).any()
    assert not HydrostaticPressure(space, (0.0, 0.0), RHO)(np.ones(n)).any()


@pytest.mark.parametrize("variant, share, time, bound", [
    ("the split", 1e-4, 2.0, 1e-3),  # measured 9.7e-5 m/s (the divergence form: 0.20 m/s, the work by parts 2.8e-4)
    # a flow's disorder: measured 6.0e-2 m/s (the divergence form: 0.22, the work by parts 8.0e-3)
    ("the split", 0.3, 4.0, 0.1),
    ("shipped", 1e-4, 2.0, 1e-3),  # the last step's pressure by parts: measured 1.9e-4 m/s
    ("shipped", 0.3, 4.0, 0.015),  # measured 8.2e-3 m/s
])
def test_the_split_and_the_increment_keep_a_disordered_column_calmer(variant, share, time, bound):
    """The dam break's column in a tank as wide as it, the shipped scene's step and solver (or the split, each particle
    shifted on its own), its particles moved at random by at most ``share`` of their spacing (docs/still-water.md's
    study): its fastest particle at ``time``."""
    fastest = still_water.fastest_at("column", variant, share)[still_water.REST_TIMES.index(time)]
    print(variant, share, time, fastest)
    assert float(fastest) < bound


@pytest.mark.parametrize("variant, bound", [("the split", 5e-3), ("shipped", 1e-3)])
def test_the_split_and_the_increment_hold_a_column_moved_by_1e_4_of_a_spacing_to_8_s(variant, bound):
    """The column of the last test moved by 1e-4 of a spacing, to 8 s: the shifting fades at rest (fempm.shifting),
    so that shifts larger than the particles' own motion do not stir it."""
    changes = {"gauges": None, "time.end": 8.0, **still_water.CONTAINERS["column"], **still_water.VARIANTS[variant]}
    solver = build_solver(dambreak.scene(changes, files=False), MPI.COMM_WORLD)
    still_water.disorder(solver, 1e-4)
    while solver.time < 8.0 - 1e-9:
        solver.step(until=8.0)
    print(variant, solver.fastest())
    # measured: the split 1.0e-3 m/s (without the fade 3.2e-2; the divergence form 0.26 at 4 s); the shipped 6.5e-4 m/s
    assert solver.fastest() < bound


def test_the_split_leaves_the_dam_break_and_its_large_steps_as_they_were():
    """The front, the gauges and ten times the seed's step (which the work by parts does not survive); each shift
    on its own, as the scene took the split until 2026-11-30."""
    result, _ = wall_pressure.run(dambreak.SPLIT, end_time=3.2)
    assert result["status"] == "completed"
    assert result["front_vs_interfoam"] < 0.02  # measured 1.79 % (the divergence form: 1.80 %)
    noise = [result["probes"][name]["fempm"]["noise"] for name in ("right_y0.005", "right_y0.0584")]
    assert noise[0] < 0.035 and noise[1] < 0.05  # measured 2.4 % and 4.3 % (the divergence form: 2.7 % and 4.3 %)
    outcome = hard.run_case("dt-10x", pressure_work="split")
    assert outcome.run.status == "completed"  # the work by parts stops at 0.30 s


def _gresho_in_a_full_tank(pressure_work: str, **scheme) -> dict:
    """The Gresho vortex (64², max u dt/h = 0.4, the verification cases' particle handling) in the unit box full of
    water under gravity, to t = 1: the flow's shear disorders the particles in water 64 cells deep."""
    return vortices.gresho("affine-FLIP", 64, 0.4 / 64, 1.0, shifting=vortices.SHIFTING, surface_aware=True,
                           pic={"pressure_work": pressure_work, **scheme}, gravity=(0.0, -9.81))


def test_the_split_keeps_a_vortex_in_a_full_tank_under_gravity():
    """Under gravity the hydrostatic pressure times the particle quadrature's error drives the disordered particles
    in divergence form (next test); with its work by parts the vortex keeps as it does without gravity."""
    r = _gresho_in_a_full_tank("split")
    assert r["status"] == "completed"
    assert abs(r["ke"]) < 0.015  # measured -0.77 % (without gravity, divergence form: -1.09 % at t = 1)
    assert abs(r["L"]) < 0.008  # measured -0.376 % (without gravity, divergence form: -0.19 %)
    assert r["profile"] < 0.04  # measured 2.6 % (without gravity, divergence form: 2.5 %)


def test_the_shipped_scheme_keeps_a_vortex_in_a_full_tank_under_gravity():
    """As above with the shipped scene's handling (the last step's pressure by parts, turning shifts)."""
    r = _gresho_in_a_full_tank(**vortices.VORTEX_SETTINGS)
    print(r)
    assert r["status"] == "completed"
    assert abs(r["ke"]) < 0.005  # measured -0.35 % (the split -0.77 %)
    assert abs(r["L"]) < 0.0012  # measured -0.075 % (the split -0.376 %)
    assert r["profile"] < 0.03  # measured 2.4 % (the split 2.6 %)


@pytest.mark.xfail(strict=True, reason="an open defect of the divergence form (README, known limits): in a full tank "
                   "under gravity the vortex gains 21.8 % of its energy by t = 1 and its profile is 37 % off (at t = 3: "
                   "+58 %, the angular momentum -36 %); the split keeps it (last test)")
def test_in_divergence_form_a_vortex_in_a_full_tank_under_gravity_keeps_its_energy():
    r = _gresho_in_a_full_tank("divergence")
    assert abs(r["ke"]) < 0.015 and r["profile"] < 0.04


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own mpirun")
def test_the_dam_break_split_is_the_same_on_1_and_2_ranks(tmp_path):
    """The shipped scene cut to its first 100 steps at the seed's step, split: the front and the gauges agree on 1
    and 2 ranks (every rank takes H from the gathered wet fractions)."""
    assert_the_dam_break_is_the_same_on_1_and_2_ranks(tmp_path, pressure_work="split")


def test_the_split_with_the_gauss_points_is_refused():
    with pytest.raises(InputError, match="pressure_work = 'split' is a form of the particles' quadrature"):
        dambreak.scene({"solver.pressure_work": "split", "solver.pressure_quadrature": "gauss"}, files=False)


@pytest.mark.mpi
@pytest.mark.parametrize("work", ["split", "by-parts"])
def test_the_walls_excess_from_the_particles_near_them_is_the_whole_ones(work):
    """The walls' reaction takes the forms' ``wall_force_excess`` at the contact dofs over the particles whose
    functions include one of them (``GridSystem._adding_to``): at those rows the same numbers, to the bit, as
    over all the particles, on one rank and on two (where particles add to other ranks' rows)."""
    solver = build_solver(dambreak.scene({"solver.pressure_work": work}, files=False), MPI.COMM_WORLD)
    for _ in range(60):
        solver.step()
    rows = solver.walls.normal
    near = solver.system._adding_to(rows, solver.particles)
    whole = solver.forms.wall_force_excess.assemble_vector(solver.particles).array[rows].copy()
    part = solver.forms.wall_force_excess.assemble_vector(near).array[rows]
    comm = solver.grid.comm
    assert comm.allreduce(len(near)) < 0.35 * solver.particles.global_count()  # measured: 229 and 227 of 800
    assert comm.allreduce(int(np.count_nonzero(whole)), op=MPI.SUM) > 0
    assert comm.allreduce(bool(np.array_equal(part, whole)), op=MPI.LAND)


@pytest.mark.mpi
@pytest.mark.parametrize("work", ["increment", "split", "by-parts"])
def test_the_walls_excess_in_the_steps_pass_is_its_own_assembly(work):
    """With the pressure's work split (the known pressure: ``increment``, ``split``) the walls' excess is free of U
    and is assembled in the step's one pass over the particles (``StepForms.excess_in_pass``), at those that add to
    the contact dofs: there the same numbers, to the bit, as its own assembly, on one rank and on two. By parts it
    reads the solved pressure: assembled after the solve."""
    solver = build_solver(dambreak.scene({"solver.pressure_work": work}, files=False), MPI.COMM_WORLD)
    for _ in range(60):
        solver.step()
    forms, particles, system = solver.forms, solver.particles, solver.system
    assert forms.excess_in_pass == (work != "by-parts")
    assert system._excess_assembled == (work != "by-parts")  # the last step's solve took it from its pass
    if work == "by-parts":
        return
    system.space.tabulate_particles(particles, solver._jet_order)  # a step's P2G, as ImplicitSolver.advance
    solver.project()
    excess, near = system._excess_alongside(forms, particles)
    forms.assemble(particles, solver.region.matrix, None, (excess, near))
    rows = solver.walls.normal
    own = forms.wall_force_excess.assemble_vector(particles).array[rows]
    comm = solver.grid.comm
    assert comm.allreduce(int(np.count_nonzero(near))) < 0.35 * particles.global_count()  # measured: 229 of 800
    assert comm.allreduce(int(np.count_nonzero(own))) > 0
    assert comm.allreduce(bool(np.array_equal(excess.array[rows], own)), op=MPI.LAND)
