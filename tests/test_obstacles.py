"""Obstacles and per-side walls: what the scene asks for is what the solver holds.

A block of water falls on a pillar of blocked cells: it must split around it, with no
particle ever in an obstacle cell and the velocity zero on every function non-zero in
one. A particle pushed into an obstacle stops the run on every rank with a message
naming the cell (or is deleted with ``on_exit="delete"``). A no-slip floor holds the
tangential velocity at zero on the floor, a slip floor does not.
"""

from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm.cases import dambreak
from fempm.errors import ParticleOutsideGridError
from fempm.options import Physics
from fempm.scene import scene_from_text
from fempm.simulation import build_solver
from fempm.space import Space
from fempm.walls import Walls

PILLAR = """
[domain]
lower = [0.0, 0.0]
upper = [0.3, 0.3]
cells = [20, 20]
[[bodies]]
shape = "rectangle"
lower = [0.075, 0.09]
upper = [0.225, 0.165]
[[obstacles]]
shape = "rectangle"            # columns 9-10, rows 0-4: x in [0.135, 0.165], y in [0, 0.075]
lower = [0.135, 0.0]
upper = [0.165, 0.075]
[time]
end = 0.12
dt = 1.0e-3
[output]
folder = "unused"
"""


@pytest.mark.mpi
def test_water_falling_on_a_pillar_splits_around_it_and_never_enters():
    comm = MPI.COMM_WORLD
    scene = scene_from_text(PILLAR, "pillar.toml")
    solver = build_solver(scene, comm)
    grid = solver.grid
    assert np.array_equal(np.flatnonzero(grid.blocked), [i + 20 * j for j in range(5) for i in (9, 10)])
    space = solver.system.space
    blocked_dofs = space.cell_dofs("u", np.flatnonzero(grid.blocked))
    owned = space.local_to_global[: space.num_owned_dofs]
    at_obstacle = np.isin(owned, blocked_dofs)
    for _ in range(120):
        solver.step()
        assert not grid.blocked[solver.particles.cell].any()
        assert np.all(solver.system.U.vector.array[: space.num_owned_dofs][at_obstacle] == 0.0)
    x = solver.particles.x
    low = x[:, 1] < 0.075
    count = lambda mask: comm.allreduce(int(mask.sum()))  # noqa: E731
    left, right = count(low & (x[:, 0] < 0.135)), count(low & (x[:, 0] > 0.165))
    assert 46 <= left <= 52 and 46 <= right <= 52  # split both ways, evenly: measured 49 and 49 (FLIP/PIC 43, 43)
    assert count(low & (x[:, 0] > 0.135) & (x[:, 0] < 0.165)) == 0
    assert count(np.ones(len(x), bool)) == 200  # none lost


@pytest.mark.mpi
def test_a_particle_pushed_into_an_obstacle_stops_every_rank_or_is_deleted():
    comm = MPI.COMM_WORLD
    for on_exit in ("error", "delete"):
        grid = fempm.Grid(comm, (0.0, 0.0), (1.0, 1.0), 0.25)
        grid.block([grid.cell_index(2, 1)])
        particles = fempm.Particles(grid, on_exit=on_exit)
        particles.add_points(np.array([[0.1, 0.1], [0.3, 0.3]]) if comm.rank == 0 else np.zeros((0, 2)), 0.01,
                             ids=np.array([0, 1]) if comm.rank == 0 else np.zeros(0, dtype=int))
        particles.fields["x"][particles.id == 1] = (0.6, 0.4)  # into column 2, row 1
        if on_exit == "error":
            with pytest.raises(ParticleOutsideGridError, match=r"particle 1 at \(0.6, 0.4\) entered the obstacle "
                                                               r"cell \(column 2, row 1\)"):
                particles.relocate()
        else:
            particles.relocate()
            assert particles.global_count() == 1 and comm.allreduce(particles.lost_count) == 1


def test_a_particle_past_an_obstacles_face_is_put_back_on_it():
    """As at the tank's walls: a point in a blocked cell goes to the nearest face of that cell with an open
    cell beyond it, a hair's breadth into the open cell; points in open cells stay."""
    grid = fempm.Grid(MPI.COMM_SELF, (0.0, 0.0), (1.0, 1.0), 0.25)
    grid.block([grid.cell_index(1, 0), grid.cell_index(2, 0), grid.cell_index(2, 1)])
    walls = Walls(Space(fempm.BSpline2(grid), {"u": 2, "p": 1}), Physics())
    x = np.array([[0.499, 0.3], [0.5 + 1e-6, 0.26], [0.62, 0.1], [0.1, 0.1]])
    kept = walls.keep_inside(x.copy())
    margin = 1e-9 * 0.25
    np.testing.assert_array_equal(kept, [[0.499, 0.3], [0.5 - margin, 0.26], [0.75 + margin, 0.1], [0.1, 0.1]])
    assert walls.stops == 2
    assert not grid.blocked[grid.locate(kept)[0]].any()


@pytest.mark.mpi
def test_the_dam_break_onto_a_block_at_its_own_step_keeps_every_particle_out_of_the_block():
    """The shipped dam break (its adaptive step, its shifted particles) with the block of scenes/obstacle.toml:
    the water flowing back along the floor comes to rest against the block's downstream face, where the held
    velocity vanishes. A particle on that face lay in the block by round-off and stopped the run at 0.56 s
    (step 150); now it is kept on the open side, as at the tank's walls."""
    block = [{"shape": "rectangle", "lower": [0.292, 0.0], "upper": [0.3358, 0.0584]}]
    solver = build_solver(dambreak.scene({"obstacles": block, "time.end": 1.0}, files=False), MPI.COMM_WORLD)
    while solver.time < 1.0 - 1e-9:
        solver.step(until=1.0)
    assert solver.particles.global_count() == 800
    assert not solver.grid.blocked[solver.particles.cell].any()


@pytest.mark.xfail(strict=True, reason="an open defect: water at rest against an obstacle grows a mode (1.1e-2 m/s at "
                   "1 s, 0.23 m/s at 1.5 s, here), from the tank's bottom corner on the far side; against the tank's own wall "
                   "the column stays at rest (8.7e-5 m/s at 3 s). Also at fixed 1 ms and 3 ms steps, without the end-of-step "
                   "map (slower), without the volume correction, the shifting, the noise and rest shares, with either "
                   "normalisation of the smoothed density and with a direct solve; FLIP holds it to 4.5 s, the Gauss option "
                   "keeps 1e-2 m/s, the pressure's work by parts 1.1e-2 m/s at 2 s (docs/still-water.md; "
                   "docs/notes-accuracy.md, 'Water at rest against an obstacle')")
def test_a_column_at_rest_against_a_block_stays_at_rest():
    """The dam break's column held by a block in place of the gate (the right three quarters of the tank
    blocked 30 cells high), with the shipped scene's step and solver."""
    block = [{"shape": "rectangle", "lower": [0.146, 0.0], "upper": [0.584, 0.438]}]
    scene = dambreak.scene({"obstacles": block, "gauges": None, "time.end": 1.5}, files=False)
    solver = build_solver(scene, MPI.COMM_WORLD)
    while solver.time < 1.5 - 1e-9:
        solver.step(until=1.5)
    assert solver.fastest() < 1e-3  # measured 0.23 m/s (the column against the tank's wall: 8.7e-5 m/s at 3 s)


@pytest.mark.mpi
def test_a_no_slip_floor_holds_the_tangential_velocity_and_a_slip_floor_does_not():
    comm = MPI.COMM_WORLD
    scene_text = (Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml").read_text()
    floor_speed = {}
    for bottom in ("slip", "no-slip"):
        scene = scene_from_text(scene_text.replace('bottom = "slip"', f'bottom = "{bottom}"'), "dambreak.toml")
        solver = build_solver(scene, comm)
        assert solver.physics.wall_conditions() == {"left": "slip", "right": "slip", "bottom": bottom, "top": "slip"}
        for _ in range(20):
            solver.step()
        space = solver.system.space
        floor = np.isin(space.local_to_global[: space.num_owned_dofs], space.wall_dofs("u", 0, "b"))
        floor_speed[bottom] = comm.allreduce(
            float(np.abs(solver.system.U.vector.array[: space.num_owned_dofs][floor]).max(initial=0.0)), op=MPI.MAX)
    assert floor_speed["no-slip"] == 0.0 and floor_speed["slip"] > 3.5e-4  # m per step; measured 3.85e-4
