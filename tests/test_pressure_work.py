"""The pressure's work by parts where the water is deep (``solver.pressure_work = "by-parts"``:
forms/incompressible.py, ``pressure_work``; fempm/density.py, the weight ``by_parts``): the weight, water at
rest from disordered particles, Taylor-Green's loss under refinement, the dam break's wall gauges, and the
dam break on 1 and 2 ranks. The default (``"divergence"``) is the rest of the suite's."""

import sys
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm import density
from fempm.cases import column, dambreak, vortices
from fempm.errors import InputError
from fempm.gauges import WetFraction
from fempm.simulation import build_solver
from helpers import assert_the_dam_break_is_the_same_on_1_and_2_ranks

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import wall_pressure  # noqa: E402

L, H_CELL = column.WIDTH, column.WIDTH / 10
BY_PARTS = {"solver.pressure_work": "by-parts"}


def _weight(top: float, obstacle: bool = False, open_sides=(), speed: float | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The weight ``by_parts`` of the dam break's column (10 x 40 cells) seeded up to ``top``, its water at rest
    (or moving everywhere at ``speed`` over ``sqrt(|g| h)``), with the function's row and column (structured
    indices)."""
    grid = fempm.Grid.from_cells(MPI.COMM_WORLD, (0.0, 0.0), (L, 4 * L), (10, 40))
    if obstacle:  # the column's right half blocked from the floor to 5 cells up
        grid.block([i + 10 * j for i in range(5, 10) for j in range(5)])
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (L if not obstacle else L / 2, top)), per_cell=2, density=1000.0)
    if obstacle:
        water.seed(fempm.Rectangle((L / 2, 5 * H_CELL), (L, top)), per_cell=2, density=1000.0)
    basis = fempm.BSpline2(grid)
    wet = WetFraction(basis)
    phi = wet(water).values[:, 0]
    velocity = None if speed is None else np.column_stack([np.full(len(phi), speed), np.zeros(len(phi))])
    _, weight = density.DeepWater(wet.field.space, open_sides).masks(phi, velocity)
    f = wet.field.space.numbering.local_functions
    return weight, f // basis.nfx, f % basis.nfx


@pytest.mark.mpi
@pytest.mark.parametrize("top", [2 * L, 2 * L - H_CELL / 2])
def test_the_weight_is_one_in_the_water_and_zero_from_its_surface_up(top):
    """Function ``k`` is non-zero in the cell rows ``k-2..k``: the weight is 1 on every function below the
    surface's cell row (20 cells deep, or 19.5: its surface half-way up a cell) and 0 from the row above."""
    weight, row, _ = _weight(top)
    np.testing.assert_allclose(weight, (row <= 19).astype(float), rtol=0, atol=1e-12)  # a half-filled cell: phi 0.5


@pytest.mark.mpi
@pytest.mark.parametrize("top", [2 * L, 2 * L - H_CELL / 2])
def test_in_moving_water_the_weight_stops_a_cell_and_a_half_below_the_surface(top):
    """Moving (from 0.1 sqrt(|g| h) on) the weight is 1 to the function row below the surface's (cells 16-18), below
    1/2 on the next (cells 17-19: 0.21-0.59 with the surface on a cell edge, 0 half-way up a cell), 0 above; half-way
    between still and moving, the mean of the two."""
    still, row, _ = _weight(top)
    moving, _, _ = _weight(top, speed=1.0)
    between, _, _ = _weight(top, speed=0.075)
    assert np.all(moving[row <= 18] == 1.0) and np.all(moving[row >= 20] == 0.0)
    assert moving[row == 19].max(initial=0.0) < (0.6 if top == 2 * L else 1e-12)
    np.testing.assert_allclose(between, (still + moving) / 2, rtol=0, atol=1e-12)


@pytest.mark.mpi
def test_the_weight_is_zero_beside_an_obstacle_and_along_an_open_side():
    """Neither an obstacle's face nor an open side is a boundary the basis resolves (``w . n`` is not zero
    there for free dofs), so the by-parts form would leave out the pressure's push: the weight is 0 on every
    function non-zero in a blocked cell or in a cell along an open side, and 1 in the water away from both."""
    weight, row, col = _weight(2 * L, obstacle=True)
    beside = (col >= 5) & (row <= 6)  # non-zero in a blocked cell (columns 5-9, rows 0-4)
    assert np.all(weight[beside] == 0.0)
    assert np.all(weight[~beside & (row <= 19)] == 1.0)
    weight, row, col = _weight(2 * L, open_sides=("right",))
    assert np.all(weight[col >= 9] == 0.0)  # non-zero in the rightmost column of cells
    assert np.all(weight[(col <= 8) & (row <= 19)] == 1.0)


def _fastest(share: float, end: float, changes: dict) -> list[float]:
    """The dam break's column in a tank as wide as it, the shipped scene's step and solver with ``changes``,
    its particles moved at random by at most ``share`` of their spacing: the fastest particle every second."""
    scene = dambreak.scene({"gauges": None, "time.end": end, "domain.upper": [L, 4 * L], "domain.cells": [10, 40],
                            "bodies.0.upper": [L, column.HEIGHT], **changes}, files=False)
    solver = build_solver(scene, MPI.COMM_WORLD)
    p = solver.particles
    p.fields["x"] = solver.walls.keep_inside(p.x + share * L / 20 * np.random.default_rng(1).uniform(-1, 1, p.x.shape))
    fastest = []
    for t in np.arange(1.0, end + 1e-9):
        while solver.time < t - 1e-9:
            solver.step(until=t)
        fastest.append(solver.fastest())
    return fastest


def test_a_column_from_slightly_disordered_particles_stays_at_rest():
    """Moved by 1e-3 of their spacing, the default's column reaches 0.26 m/s by 2 s (the strict xfail of
    tests/test_transfer_cases.py has 1e-4: 0.20 m/s); by parts it stays below issue 11's 1e-3 m/s."""
    fastest = _fastest(1e-3, 3.0, BY_PARTS)
    print(fastest)
    assert max(fastest) < 1e-3  # measured 5.2e-4, 3.9e-4, 4.6e-4 m/s at 1, 2 and 3 s


def test_a_flows_disorder_stirs_a_column_at_rest_a_tenth_as_fast():
    """Moved by 0.3 of their spacing, the disorder a flow leaves: the default's column stirs at 0.22-0.30 m/s
    (docs/still-water.md); by parts at under a tenth of that, not yet issue 11's 1e-3 m/s."""
    fastest = _fastest(0.3, 3.0, BY_PARTS)
    print(fastest)
    assert max(fastest) < 0.03  # measured 1.90e-2, 1.75e-2, 1.18e-2 m/s at 1, 2 and 3 s


def test_taylor_green_loss_falls_under_refinement():
    """nu = 1e-6, U dt / h = 0.4, to t = 0.25, the shipped particle shifting: with the pressure's work in
    divergence form the loss does not fall from 64² to 128² (4.50e-3, 7.21e-3; docs/pressure-quadrature.md);
    by parts it falls by 2.9 times from 32² to 64² (4.72e-4 at 128²)."""
    coarse, fine = (vortices.taylor_green("affine-FLIP", n, 0.4 / n, 1e-6, shifting=vortices.SHIFTING,
                                          pic={"pressure_work": "by-parts"}) for n in (32, 64))
    print(coarse["numerical"], fine["numerical"])
    assert coarse["status"] == fine["status"] == "completed"
    # measured 5.57e-3 and 1.92e-3 per unit time (in divergence form 4.29e-3 and 4.50e-3)
    assert 0 < fine["numerical"] < 0.4 * coarse["numerical"] < 2.5e-3


@pytest.mark.full
def test_the_gresho_vortex_by_parts_with_turning_shifts_meets_issue_11_at_its_step():
    """64², max u dt/h = 0.4, to t = 3, the surface-aware correction, shifts that add no angular momentum: issue 11's
    kinetic energy within 1 % and angular momentum within 0.1 %, as with the Gauss option and the same shifts
    (tests/test_pressure_points.py), at the margin: at 0.39 the angular momentum is -0.103 %, at half the step the
    energy -1.21 % (docs/notes-accuracy.md)."""
    r = vortices.gresho("affine-FLIP", 64, 0.4 / 64, 3.0, shifting=vortices.SHIFTING, surface_aware=True,
                        pic={"pressure_work": "by-parts", **vortices.TURNING})
    print(r)
    assert r["status"] == "completed"
    # measured with the Krylov iteration to 1e-10 (the box takes S's multigrid cycle), to 1e-13 in (); the angular
    # momentum is at issue 11's margin: as the tolerance moves the last bits (1e-8 ... 1e-14) it ends at -0.075 ...
    # -0.110 % (docs/notes-speed.md), so a change of the last bits alone may take it past 0.1 % (README, known limits)
    assert -0.0100 < r["ke"] < 0  # measured -0.901 % (-0.903 % at ac8940b; -0.899 %; in divergence form -2.00 %)
    assert abs(r["L"]) < 0.0010  # measured -0.0997 % (-0.0998 % at ac8940b; -0.091 %; in divergence form -0.040 %)
    assert abs(r["L_largest"]) < 0.0025  # measured -0.201 % over the run (-0.199 %; in divergence form -0.407 %)


def test_the_right_wall_gauges_of_the_dam_break_stay_steady():
    """Issue 11's gauge targets with the work by parts (the one-sided walls' reaction takes the pressure's
    push back, forms/incompressible.py, wall_force_excess: without it the walls let go of the water and the
    gauges rippled by 30-60 % of their mean)."""
    result, _ = wall_pressure.run(BY_PARTS)
    assert result["status"] == "completed"
    noise = {name: probe["fempm"]["noise"] for name, probe in result["probes"].items() if name.startswith("right_")}
    means = {name: probe["fempm"]["mean_vs_interfoam"] for name, probe in result["probes"].items()
             if name.startswith("right_")}
    print(noise, means)
    assert max(noise.values()) < 0.05  # measured 1.3 / 1.4 / 1.7 / 2.9 % (divergence form 2.7 / 2.7 / 3.2 / 4.3 %)
    assert max(abs(m) for m in means.values()) < 0.10  # measured -0.9 / -0.4 / -1.9 / -7.9 %


def test_by_parts_with_the_gauss_points_is_refused():
    with pytest.raises(InputError, match="pressure_work = 'by-parts'"):
        dambreak.scene({**BY_PARTS, "solver.pressure_quadrature": "gauss"}, files=False)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own mpirun")
def test_the_dam_break_by_parts_is_the_same_on_1_and_2_ranks(tmp_path):
    """The shipped scene cut to its first 100 steps at the seed's step, by parts: the front and the gauges
    agree on 1 and 2 ranks (the weight's sums over a function's cells are taken across ranks)."""
    assert_the_dam_break_is_the_same_on_1_and_2_ranks(tmp_path, pressure_work="by-parts")
