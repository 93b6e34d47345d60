"""The pressure's terms at fixed Gauss points (``solver.pressure_quadrature = "gauss"``: fempm/pressure_points.py,
forms/gauss_pressure.py): the point set, a column at rest at the adaptive step's largest step, Taylor-Green's
loss under refinement, the dam break on 1 and 2 ranks."""

import dataclasses

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm import diagnostics, references
from fempm.cases import column, dambreak, hard, vortices
from fempm.implicit import ImplicitSolver
from fempm.options import Physics, Scheme
from fempm.pressure_points import GAUSS_WEIGHTS
from fempm.simulation import build_solver
from fempm.verification import advance
from helpers import assert_the_dam_break_is_the_same_on_1_and_2_ranks



def gauss_solver(basis, particles, physics=None, scheme=None, controls=None):
    """The implicit solver with the pressure's terms at Gauss points."""
    scheme = dataclasses.replace(scheme or Scheme(), pressure_quadrature="gauss")
    return ImplicitSolver(basis, particles, physics, scheme, controls)


@pytest.mark.mpi
def test_the_gauss_points_of_a_full_box_integrate_its_area_and_extend_the_particles_tabulation():
    """A box whose last column and row of cells are cut (0.75 x 0.45 on h = 0.1), full of water: every open
    cell takes its 3 x 3 points, whose weights sum to the box's area to round-off; the Gauss points carry the
    water's density and no velocity, and sit where their cells and reference coordinates say."""
    comm = MPI.COMM_WORLD
    grid = fempm.Grid(comm, (0.0, 0.0), (0.75, 0.45), 0.1)
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (0.75, 0.45)), per_cell=2, density=1000.0)
    solver = gauss_solver(fempm.BSpline2(grid), water, Physics(gravity=(0.0, -9.81)))
    solver.step()
    points = solver.quadrature_points()
    gauss = points.fixed
    assert points.particles is water
    assert comm.allreduce(len(gauss)) == len(GAUSS_WEIGHTS) * 8 * 5  # every cell of the box
    assert comm.allreduce(gauss["volume"].sum()) == pytest.approx(0.75 * 0.45, rel=1e-14)
    assert np.all(gauss["density"] == 1000.0) and not np.any(gauss["velocity"])
    cells, xi = grid.locate(gauss.x)
    assert np.array_equal(cells, gauss.cell) and np.allclose(xi, gauss.xi, rtol=0, atol=1e-12)


def test_forms_at_gauss_points_without_them_get_one_clear_message():
    grid = fempm.Grid.from_cells(MPI.COMM_WORLD, (0.0, 0.0), (1.0, 1.0), (4, 4))
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (1.0, 0.5)), per_cell=2, density=1000.0)
    with pytest.raises(fempm.InputError, match=r"forms gauss_pressure: they integrate over s.dx_fixed \(Gauss points\), "
                       r"but pressure_quadrature is 'particles': set it to 'gauss'"):
        ImplicitSolver(fempm.BSpline2(grid), water, scheme=Scheme(forms="gauss_pressure"))


def test_a_column_at_rest_stays_at_rest_at_10_ms_steps():
    """The dam break's column at the adaptive step's largest step, where with the pressure at the particles a
    vertical mode grew until PSPG's displacement in a step was bounded (tests/test_transfer_cases.py, ten_ms): at
    Gauss points it stays at rest, settling."""
    r = column.rest("affine-FLIP", 5.0, dt=1e-2, solver_type=gauss_solver)
    print(r)
    assert r["status"] == "completed"
    assert r["speed"] < 1e-3  # measured 2.6e-4 m/s (5.5e-4 before PSPG's displacement in a step was bounded)
    assert -0.0050 < r["volume"] < 0  # measured -0.275 % (-0.449 % before the bound): it settles (issue 11 asks 0.2 %;
    # docs/pressure-quadrature.md)


def test_the_dam_break_runs_its_two_seconds():
    """The shipped scene with the Gauss points runs to its end (forms/gauss_pressure.py, WET_FLOOR: with PSPG's
    correction divided by a share of water down to 1e-3 its pressure blew up at t = 0.92 s), its front within
    issue 11's 2.5 % of interFoam 160²."""
    solver = build_solver(dambreak.scene({"output.progress": False, "solver.pressure_quadrature": "gauss",
                                          "solver.pressure_work": "divergence"},
                                         files=False))
    history = [(0.0, diagnostics.front_position(solver.particles))]
    run = advance(solver, 2.0, lambda s: history.append((s.time, diagnostics.front_position(s.particles))))
    h = np.array(history)
    front = references.front_difference(references.dimensionless_front(h[:, 0], h[:, 1]),
                                        references.interfoam_front(160))
    print(run, front)
    assert run.status == "completed"
    assert front < 0.0175  # measured 1.67 % (the pressure at the particles: 1.81 %)


def test_a_lone_particle_falls_freely():
    """Gravity at the Gauss points acts where the share of water is above zero; a particle where it is zero
    (forms/gauss_pressure.py, ``dry``) takes its own, and falls as with the pressure at the particles."""
    o = hard.run_case("single-particle", pressure_quadrature="gauss")
    print(o.speed_ratio, o.max_speed)
    assert o.run.status == "completed"
    # measured 0.969 with the default PIC shares, which damp a lone particle whole towards the grid's held functions
    # (the whole share alone at 100/s: 0.98; without the particle's own gravity: 0, it floated)
    assert 0.96 < o.speed_ratio <= 1.0


def test_taylor_green_loss_falls_under_refinement():
    """nu = 1e-6, U dt / h = 0.4, to t = 0.25, the shipped particle shifting: with the pressure at the particles
    the loss rises from 64² to 128² (the particles' disorder reaches it); at Gauss points it falls."""
    coarse, fine = (vortices.taylor_green("affine-FLIP", n, 0.4 / n, 1e-6, shifting=vortices.SHIFTING,
                                          solver_type=gauss_solver) for n in (32, 64))
    print(coarse["numerical"], fine["numerical"])
    assert coarse["status"] == fine["status"] == "completed"
    # measured 2.60e-3 and 4.51e-4 per unit time (pressure at the particles: 4.63e-3 and 4.40e-3, and 7.45e-3 at 128²)
    assert fine["numerical"] < 0.25 * coarse["numerical"] < 1e-3


def test_the_gresho_vortex_keeps_its_core_filled():
    """64², max u dt/h = 0.4, to t = 1, the shipped particle handling: with the pressure at the particles the
    vortex's core thins into a void (tests/test_transfer_cases.py, a strict xfail); at Gauss points it stays."""
    r = vortices.gresho("affine-FLIP", 64, 0.4 / 64, 1.0, shifting=vortices.SHIFTING, surface_aware=True,
                        solver_type=gauss_solver)
    print(r)
    assert r["status"] == "completed"
    assert r["core"] > 0.99  # measured 1.000 (pressure at the particles: 0.646)


def test_the_gresho_vortex_keeps_its_energy_and_angular_momentum_with_turning_shifts():
    """64², max u dt/h = 0.4, to t = 3 (issue 11: kinetic energy within 1 %, angular momentum within 0.1 %), the
    pressure's terms at Gauss points and shifts that add no angular momentum (``shifting_keeps_angular_momentum``)."""
    r = vortices.gresho("affine-FLIP", 64, 0.4 / 64, 3.0, shifting=vortices.SHIFTING, surface_aware=True,
                        solver_type=gauss_solver, pic=vortices.TURNING)
    print(r)
    assert r["status"] == "completed"
    # measured with the Krylov iteration to 1e-10 (the box's 13,000 free dofs take S's multigrid cycle), to 1e-13 in ()
    assert -0.0100 < r["ke"] < 0  # measured -0.949 % (-0.951 %; pressure at the particles: -2.00 %; Gauss points alone: -1.83 %)
    assert abs(r["L"]) < 0.0010  # measured -0.073 % (-0.090 %; pressure at the particles: -0.040 %; Gauss points alone: -0.36 %)
    assert abs(r["L_largest"]) < 0.0025  # measured -0.223 % over the run (-0.219 %; pressure at the particles: -0.407 %)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own mpirun")
def test_the_dam_break_with_gauss_points_is_the_same_on_1_and_2_ranks(tmp_path):
    """The shipped scene cut to its first 100 steps at the seed's step, with the Gauss points: the front and
    the gauges agree on 1 and 2 ranks (the points are laid out per rank over its own cells)."""
    assert_the_dam_break_is_the_same_on_1_and_2_ranks(tmp_path, pressure_quadrature="gauss", pressure_work="divergence")
