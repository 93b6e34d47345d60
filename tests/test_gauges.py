"""Gauges (fempm.gauges): pressure at a point, water level along a line, on any number of ranks;
and a scene's [[gauges]] written to gauges.csv and gauges.png."""

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm.errors import InputError
from fempm.gauges import LevelGauge, PressureGauge, Sampler, sample
from fempm.verification import sample as sample_field
from helpers import resting_water

RHO, G, L, H = 1000.0, 9.81, 0.146, 0.292


def column(comm=MPI.COMM_WORLD, steps: int = 0):
    """The dam-break column at rest in a tank as wide as it (10 x 40 cells), after ``steps`` steps."""
    return resting_water(fempm.Grid.from_cells(comm, (0.0, 0.0), (L, 4 * L), (10, 40)), L, H, steps, RHO)


GAUGES = [
    PressureGauge("bottom_right", (L - 1e-4, 0.005)),
    PressureGauge("middle", (0.07, 0.1)),
    PressureGauge("below_surface", (0.07, H - 0.3 * L / 10)),
    PressureGauge("above_surface", (0.07, H + L / 10)),
    LevelGauge("level_wall", 0.0),
    LevelGauge("level_middle", 0.07),
]


@pytest.mark.mpi
def test_gauges_read_a_column_at_rest_alike_on_every_rank():
    solver = column(steps=20)
    readings = sample(GAUGES, solver)
    assert list(readings) == [g.name for g in GAUGES]
    for name, y, bound in (("bottom_right", 0.005, 0.005), ("middle", 0.1, 0.002)):
        assert readings[name] == pytest.approx(RHO * G * (H - y), rel=bound)  # measured 0.33 %, 0.08 %
    assert np.isfinite(readings["below_surface"])
    assert np.isnan(readings["above_surface"])  # dry: one cell above the water
    assert readings["level_wall"] == pytest.approx(H, rel=1e-5)  # measured 1.3e-6
    assert readings["level_middle"] == pytest.approx(H, rel=1e-5)
    # the grid pressure itself where wet, the same numbers on every rank
    assert readings["middle"] == pytest.approx(sample_field(solver.pressure, np.array([[0.07, 0.1]]))[0, 0], rel=1e-12)
    everyone = MPI.COMM_WORLD.allgather(np.array(list(readings.values())))
    for other in everyone[1:]:
        np.testing.assert_array_equal(other, everyone[0])


@pytest.mark.mpi
def test_gauges_on_an_obstacles_face_read_the_water_at_rest_beside_it():
    """The column at rest against an obstacle 30 cells high (the right half of a 20 x 40 grid): on the
    obstacle's face the pressure is hydrostatic and the level the column's height, as at a tank's wall.
    The wet fraction counts only the open cells: over all of them it read about 1/2 on the face (the
    pressure NaN above y = 0.03 m, the level 0.147 m)."""
    grid = fempm.Grid.from_cells(MPI.COMM_WORLD, (0.0, 0.0), (2 * L, 4 * L), (20, 40))
    grid.block([i + 20 * j for j in range(30) for i in range(10, 20)])
    solver = resting_water(grid, L, H, 20, RHO)
    readings = sample([PressureGauge("face_low", (L, 0.005)), PressureGauge("face_middle", (L, 0.1)),
                       LevelGauge("beside", L - 1e-4), LevelGauge("face", L), LevelGauge("in_the_obstacle", 1.5 * L)],
                      solver)
    assert readings["face_low"] == pytest.approx(RHO * G * (H - 0.005), rel=0.005)  # measured 0.16 %
    assert readings["face_middle"] == pytest.approx(RHO * G * (H - 0.1), rel=0.002)  # measured 1.7e-5
    assert readings["beside"] == pytest.approx(H, rel=1e-5)  # measured 3.6e-7
    assert readings["face"] == pytest.approx(H, rel=1e-5)  # measured 3.6e-7
    assert readings["in_the_obstacle"] == 0.0


def test_a_seeded_column_reads_its_height_at_any_line():
    solver = column()
    sampler = Sampler([LevelGauge(f"x{x}", x) for x in (0.0, 0.003, 0.07, L)], solver.basis)
    np.testing.assert_allclose(list(sampler.sample(solver).values()), H, rtol=1e-6)


@pytest.mark.parametrize("gauges, message", [
    ([PressureGauge("a", (1.0, 0.1))], "gauges.a: the point"),
    ([LevelGauge("b", -0.1)], "gauges.b: the point"),
    ([PressureGauge("c", (0.1, 0.1)), LevelGauge("c", 0.1)], "names must be unique"),
])
def test_gauges_outside_the_grid_or_named_twice_are_refused(gauges, message):
    grid = fempm.Grid.from_cells(MPI.COMM_WORLD, (0.0, 0.0), (L, 4 * L), (10, 40))
    with pytest.raises(InputError, match=message):
        Sampler(gauges, fempm.BSpline2(grid))


def test_the_grid_pressure_is_written_only_where_wet(tmp_path):
    import pyvista as pv

    from fempm.gauges import WetFraction
    from fempm.output import GridSeries

    solver = column(steps=2)
    series = GridSeries(tmp_path, solver.basis)
    series.write(solver.velocity, solver.pressure, solver.time, wet=WetFraction(solver.basis)(solver.particles))
    if MPI.COMM_WORLD.rank == 0:
        image = pv.read(tmp_path / series.entries[0][1])
        y, p = np.asarray(image.points)[:, 1], np.asarray(image.point_data["pressure"])
        assert np.all(np.isfinite(p[y < H - 0.005])) and np.all(np.isnan(p[y > H + 0.005]))
        assert np.nanmin(p) > 0  # measured 69 Pa at the highest wet node (y = 0.2847 m): no dry tail
