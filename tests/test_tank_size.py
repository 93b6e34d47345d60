"""Any tank size: a side that is not a whole number of cells has its last column (row) cut at the face.

The basis itself is checked in tests/test_bases.py (the cut knots against scipy, whole tanks bit
for bit); here the solvers: the Gauss assembly of the FEM-only reference integrates over the
tank, a column at rest in a cut tank is as hydrostatic as in a whole one and stays inside, the
FEM-only steady Poiseuille parabola is still exact, and the dam break in a tank of 0.584 m with
cells of 0.015 m runs with the front of the same grid in a whole tank.
"""

import numpy as np
import pytest
from mpi4py import MPI
from pathlib import Path

import fempm
from fempm import diagnostics, references, simulation
from fempm.cases import channel, dambreak
from fempm.eulerian import EulerianSolver
from fempm.options import Physics, Scheme
from fempm.scene import scene_from_text
from fempm.verification import advance, sample
from helpers import resting_water, seed_setup

RHO, G = 1000.0, 9.81
DAMBREAK = seed_setup((Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml").read_text())


@pytest.mark.mpi
@pytest.mark.parametrize("Basis", [fempm.Q1, fempm.BSpline2])
def test_gauss_assembly_integrates_over_the_cut_tank(comm, Basis):
    """``int N_i dx`` assembled by DOLFINx on the cut mesh (its last vertices on the faces) is the basis's
    own exact integral over the tank (tested against the knot formula in tests/test_bases.py)."""
    grid = fempm.Grid(comm, (0.0, 0.0), (1.33, 0.71), 0.2)  # last column 0.65 h, top row 0.55 h
    space = fempm.Space(Basis(grid))
    b = fempm.GaussForm(lambda s: s.test * s.dx, space).assemble_vector()
    owned = space.numbering.local_functions[: space.numbering.num_owned]
    error = np.abs(b.array - space.basis.integrals[owned]).max(initial=0.0) / grid.h**2
    assert comm.allreduce(error, op=MPI.MAX) < 1e-14  # measured 1.4e-15 (Q1), 1.0e-15 (B-spline)
    area = fempm.GaussForm(lambda s: (0 * s.x[0] + 1) * s.dx, space).assemble_scalar()
    assert area == pytest.approx(1.33 * 0.71, rel=1e-14)  # measured 4.0e-15, -3.1e-15


def _resting_water(comm, width=0.5, height=0.3, depth=0.2, steps=0, h=0.04):
    """Water ``depth`` deep across a tank ``width`` x ``height`` (default 12.5 x 7.5 cells), 2 x 2 particles
    per cell, after ``steps`` steps of 1 ms."""
    return resting_water(fempm.Grid(comm, (0.0, 0.0), (width, height), h), width, depth, steps, RHO)


def _column(comm, width, height, h=0.04, depth=0.2, steps=200):
    """Water ``depth`` deep across a tank ``width`` x ``height`` held at rest for ``steps`` ms: the pressure's
    largest error on three vertical lines (middle, a quarter cell from each side wall) over rho g depth, the
    largest particle x over the run and the fastest particle at the end."""
    solver = _resting_water(comm, width, height, depth, h=h)
    grid, water = solver.grid, solver.particles
    right = -np.inf
    for _ in range(steps):
        solver.step()
        right = max(right, comm.allreduce(float(water.x[:, 0].max(initial=-np.inf)), op=MPI.MAX))
    y = np.linspace(0.0, depth - h, 40)
    errors = []
    for x in (width / 2, width - h / 4, h / 4):
        p = sample(solver.pressure, np.column_stack([np.full_like(y, x), y]))[:, 0]
        errors.append(np.abs(p - RHO * G * (depth - y)).max() / (RHO * G * depth))
    speed = comm.allreduce(float(np.linalg.norm(water["velocity"], axis=1).max(initial=0.0)), op=MPI.MAX)
    return grid, np.array(errors), right, speed


@pytest.mark.mpi
def test_column_at_rest_in_a_cut_tank_is_as_hydrostatic_as_in_a_whole_one(comm):
    """0.5 x 0.3 m with h = 0.04 (12.5 x 7.5 cells), and 0.492 m wide (the last column 0.3 h), against
    0.48 x 0.32 m (12 x 8 whole cells): the same water, 0.2 s at rest."""
    _, whole, whole_right, whole_speed = _column(comm, 0.48, 0.32)
    print(f"whole 12 x 8: pressure errors {whole}, largest x {whole_right:.6g}, speed {whole_speed:.3g} m/s")
    assert whole.max() < 0.0155  # measured 0.014822 (5 cells deep, 2 x 2 particles per cell)
    for width, last in ((0.5, 0.5), (0.492, 0.3)):
        grid, cut, right, speed = _column(comm, width, 0.3)
        print(f"{width} x 0.3: pressure errors {cut}, largest x {right:.6g}, speed {speed:.3g} m/s")
        assert grid.last == pytest.approx([last, 0.5], rel=1e-9)
        assert np.abs(cut - whole).max() < 1e-12  # measured 4.3e-14 and 7.7e-14: the cut changes nothing
        assert abs(speed - whole_speed) < 1e-12  # measured 1.1e-14, 7.6e-15 m/s apart (of 1.15e-3 m/s)
        assert right <= width  # the water never leaves the tank: measured 0.495 and 0.4905


def test_fem_only_is_exact_in_a_cut_tank(comm):
    """The FEM-only reference (Gauss quadrature on the cut mesh): a tank of water 0.492 x 0.3 m with an
    open top (hydrostatic p lies in the space) and a cut channel section 0.45 x 1 with h = 0.07 (the
    last column 0.43 h, the top row 0.29 h; the steady Poiseuille parabola lies in the space)."""
    grid = fempm.Grid(comm, (0.0, 0.0), (0.492, 0.3), 0.04)
    physics = Physics(viscosity=1e-3, gravity=(0.0, -G), walls={"left": "slip", "right": "slip", "bottom": "slip",
                                                                   "top": "open"})
    solver = EulerianSolver(fempm.BSpline2(grid), physics, Scheme(dt=0.001), density=RHO)
    assert advance(solver, 0.05).status == "completed"
    y = np.linspace(0.0, 0.3, 30)
    worst = 0.0
    for x in (0.246, 0.487):  # the middle and the cut column
        p = sample(solver.pressure, np.column_stack([np.full_like(y, x), y]))[:, 0]
        worst = max(worst, np.abs(p - RHO * G * (0.3 - y)).max() / (RHO * G * 0.3))
    assert worst < 1e-13  # measured 3.5e-14

    flow = channel.POISEUILLE
    grid = fempm.Grid(comm, (0.0, 0.0), (0.45, 1.0), 0.07)
    physics = Physics(viscosity=1.0, gravity=(1.0, 0.0), walls={"left": "outflow", "right": "outflow",
                                                                "bottom": "no-slip", "top": "no-slip"})
    solver = EulerianSolver(fempm.BSpline2(grid), physics, Scheme(dt=0.01, alpha=0.0), density=1.0)
    assert advance(solver, flow.steady).status == "completed"
    u = sample(solver.velocity, np.column_stack([np.full_like(channel.Y, 0.225), channel.Y]))[:, 0]
    error = np.abs(u - flow.exact(channel.Y, flow.steady)).max() / flow.scale
    assert error < 7e-8  # measured 5.75e-8, 9.2e-8 from a_0 = 0 (whole cells of H/16: 4.32e-8, tests/test_verification.py)


def _dambreak_front(comm, text: str, end: float = 0.3, explicit: bool = False):
    """The dam break of a scene text stepped to ``end`` (the implicit scheme, or the explicit one with the
    artificial sound speed): its front history (T, Z), largest particle x and grid."""
    scene = scene_from_text(text, "dambreak.toml")
    solver = (dambreak.explicit_solver(scene, comm, sound_speed=dambreak.AUTO_SOUND_SPEED) if explicit
              else simulation.build_solver(scene, comm))
    front, right = [(0.0, diagnostics.front_position(solver.particles))], -np.inf
    while solver.time < end - 1e-9:
        solver.step()
        front.append((solver.time, diagnostics.front_position(solver.particles)))
        right = max(right, comm.allreduce(float(solver.particles.x[:, 0].max(initial=-np.inf)), op=MPI.MAX))
    t, x = np.array(front).T
    return references.dimensionless_front(t, x, dambreak.WIDTH, dambreak.GRAVITY), right, solver.grid


def test_dambreak_in_a_tank_not_a_whole_number_of_cells(comm):
    """The shipped dam break (0.584 m square) with cell_size = 0.015 (38.93 cells: the last column and the
    top row cut to 0.933 h), to 0.3 s (the front reaches the far wall at 0.27 s and runs up the cut column),
    against the same cells in a whole tank 0.585 m square (39 x 39)."""
    text = DAMBREAK.replace("cells = [40, 40]", "cell_size = 0.015", 1)
    cut, right, grid = _dambreak_front(comm, text)
    assert (grid.nx, grid.ny) == (39, 39) and grid.last == pytest.approx([0.584 / 0.015 - 38] * 2, rel=1e-12)
    whole, _, _ = _dambreak_front(comm, text.replace("upper = [0.584, 0.584]", "upper = [0.585, 0.585]", 1))
    interfoam = references.interfoam_front(160)
    difference = references.front_difference(cut, interfoam)
    print(f"front vs interFoam 160: cut tank {100 * difference:.4f} %, whole 0.585 m tank "
          f"{100 * references.front_difference(whole, interfoam):.4f} %; largest x {right:.6g}")
    assert difference < 0.034  # measured 0.03271 (40 cells of 14.6 mm: 0.0198; 15 mm cells round the column to -2.2 %)
    assert abs(difference - references.front_difference(whole, interfoam)) < 1e-5  # measured 3.3e-7
    assert right <= 0.584  # measured 0.583948


def test_explicit_dambreak_in_a_tank_not_a_whole_number_of_cells(comm):
    """The explicit scheme (c0 = 10 sqrt(2 g H)) on the same cut tank, against the same whole 0.585 m tank."""
    text = DAMBREAK.replace("cells = [40, 40]", "cell_size = 0.015", 1)
    cut, right, _ = _dambreak_front(comm, text, explicit=True)
    whole, _, _ = _dambreak_front(comm, text.replace("upper = [0.584, 0.584]", "upper = [0.585, 0.585]", 1),
                                  explicit=True)
    interfoam = references.interfoam_front(160)
    difference = references.front_difference(cut, interfoam)
    print(f"explicit front vs interFoam 160: cut tank {100 * difference:.4f} %, whole 0.585 m tank "
          f"{100 * references.front_difference(whole, interfoam):.4f} %; largest x {right:.6g}")
    assert difference < 0.042  # measured 0.04093
    assert abs(difference - references.front_difference(whole, interfoam)) < 1e-5  # measured 1.3e-6
    assert right <= 0.584  # measured 0.583625


@pytest.mark.mpi
def test_gauges_in_a_cut_tank(comm):
    """Level gauges integrate up to the cut top face (a tank full to it reads its height), a pressure gauge
    in the cut column reads rho g (H - y)."""
    from fempm.gauges import LevelGauge, PressureGauge, Sampler

    gauges = [LevelGauge(f"x{x}", x) for x in (0.0, 0.25, 0.49, 0.5)]
    for depth in (0.2, 0.3):  # 0.3: to the top face, through the cut row
        solver = _resting_water(comm, depth=depth)
        levels = np.array(list(Sampler(gauges, solver.basis).sample(solver).values()))
        assert np.abs(levels / depth - 1).max() < 1e-12  # measured 5.6e-16 for both
    solver = _resting_water(comm, steps=20)
    readings = Sampler([PressureGauge("cut", (0.495, 0.05))], solver.basis).sample(solver)
    assert readings["cut"] == pytest.approx(RHO * G * 0.15, rel=0.004)  # measured -0.17 %


@pytest.mark.mpi
def test_grid_output_of_a_cut_tank_is_nan_past_the_faces(comm, tmp_path):
    """The .vti image is evenly spaced: its points past the cut faces hold NaN, those inside the field; the VTX
    stream (on the image's own mesh) is written."""
    import pyvista as pv

    from fempm.output import GridSeries

    solver = _resting_water(comm, steps=2)
    folder = Path(comm.bcast(str(tmp_path) if comm.rank == 0 else None, root=0))
    series = GridSeries(folder, solver.basis)
    series.write(solver.velocity, solver.pressure, solver.time)
    series.write_vtx()
    if comm.rank == 0:
        image = pv.read(folder / series.entries[0][1])
        assert image.dimensions == (27, 17, 1)  # 13 x 8 cells of the B-spline's Q2 nodes
        x, p = np.asarray(image.points)[:, :2], np.asarray(image.point_data["pressure"])
        v = np.asarray(image.point_data["velocity"])[:, :2]
        beyond = (x[:, 0] > 0.5 + 1e-12) | (x[:, 1] > 0.3 + 1e-12)
        assert beyond.sum() == 27 + 17 - 1  # the last column and row of points
        assert np.all(np.isnan(p[beyond])) and np.all(np.isnan(v[beyond]))
        assert np.all(np.isfinite(p[~beyond])) and np.all(np.isfinite(v[~beyond]))
        at = np.flatnonzero(np.all(np.isclose(x, [0.5, 0.0]), axis=1))  # the bottom right corner, on the face
        assert p[at][0] == pytest.approx(RHO * G * 0.2, rel=0.015)  # measured +1.1 % (after 2 steps)
        assert (folder / "grid.bp").is_dir()
