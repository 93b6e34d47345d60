"""The implicit solver on the seed's cases: column at rest, dam break, failures, ranks.

Short versions run in CI; the 40 s runs of method.md Fig. 4 are marked ``full``.
"""

import json
from dataclasses import replace

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm import diagnostics, references, simulation
from fempm.cases import dambreak
from fempm.implicit import ImplicitSolver
from fempm.options import Controls, Scheme

RHO, G, L, H = 1000.0, 9.81, 0.146, 0.292


def column_at_rest(Basis, comm=MPI.COMM_WORLD, scheme: Scheme | None = None):
    """The dam-break column with its gate closed: a tank as wide as the column (10 x 40 cells)."""
    grid = fempm.Grid.from_cells(comm, (0.0, 0.0), (L, 4 * L), (10, 40))
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (L, H)), per_cell=2, density=RHO)
    return ImplicitSolver(Basis(grid), water, scheme=scheme)


@pytest.mark.parametrize("Basis, scheme, pressure, speed, height", [  # bottom p / rho g H, speed (m/s), height / H - 1
    # measured 1.00053, 2.16e-4, -4.73e-4 (before the crowding tolerance 1.00247, 2.68e-4, +1.15e-4; FLIP/PIC: 5.32e-4,
    # 9.4e-5): the correction leaves the column's settling within the tolerance, and the pressure nearer rho g H
    (fempm.BSpline2, None, 1.00053, 2.9e-4, 5.5e-4),
    # Q1 under affine-FLIP grows a mode (0.39 m/s after 1 s at the default 100/s; at 300/s with two-sided walls it
    # held, with one-sided walls the bottom pressure reaches 2.9-5 rho g H); APIC proper holds it
    (fempm.Q1, Scheme(transfer="apic"), 1.0, 1e-12, 1e-12),  # measured 1.00000, 1.0e-14, 0 (FLIP/PIC: 8e-15)
])
def test_hydrostatic_column_stays_at_rest_for_one_second(Basis, scheme, pressure, speed, height):
    solver = column_at_rest(Basis, scheme=scheme)
    water = solver.particles
    cells0 = diagnostics.occupied_cells(water)
    for _ in range(1000):
        solver.step()
    x = np.linspace(0.01, L - 0.01, 9)
    cells, xi = solver.grid.locate(np.column_stack([x, np.zeros_like(x)]))
    bottom = solver.pressure.evaluate(cells, xi)[:, 0, 0] / (RHO * G * H)
    fastest = np.linalg.norm(water["velocity"], axis=1).max()
    top = (water.x[:, 1] + 0.5 * np.sqrt(water["volume"])).max()
    print(f"{Basis.name}: bottom pressure / rho g H {bottom.min():.6f} .. {bottom.max():.6f}, largest speed "
          f"{fastest:.3g} m/s, height / H - 1 {top / H - 1:.3g}")
    np.testing.assert_allclose(bottom, pressure, rtol=1e-4)
    assert fastest < speed
    assert abs(top / H - 1) <= height  # the column's height, i.e. its volume
    assert diagnostics.occupied_cells(water) == cells0


def run_dambreak(folder, changes: dict, files: bool = False, comm=MPI.COMM_WORLD) -> tuple[dict, np.ndarray]:
    """The seed's dam break with ``changes`` (scene keys), written to ``folder``: its summary and front (T, Z)."""
    scene = dambreak.scene({"output.folder": str(folder), "output.progress": False, **changes}, files=files)
    summary = simulation.run_scene(scene, comm, overwrite=True)
    front = comm.bcast(dambreak.read_front(folder) if comm.rank == 0 else None, root=0)
    return summary, front


@pytest.fixture(scope="module")
def dambreak_fronts(tmp_path_factory):
    """Fronts to T = 3.2 of the shipped dam break and of a run with a 2x finer grid and 4x the particles."""
    return {name: run_dambreak(tmp_path_factory.mktemp(name), {"time.end": 0.28, "domain.cells": [cells, cells]})
            for name, cells in (("seed", 40), ("fine", 80))}


def test_dambreak_front_is_converged_against_a_finer_run(dambreak_fronts):
    """The shipped resolution (40², 2 x 2 particles per cell) against 80 x 80 cells and 3200 particles,
    same front measure (its own distance from interFoam and the experiment: ``demos/dambreak.py``,
    tests/test_demos.py)."""
    (_, coarse), (_, fine) = dambreak_fronts["seed"], dambreak_fronts["fine"]
    numerical = references.front_difference(coarse, fine)
    fine_measures = dambreak.front_measures(fine)
    print(f"front RMS difference, seed resolution vs 2x finer: {100 * numerical:.2f} %; finer run vs interFoam "
          f"160: {100 * fine_measures['front_difference_vs_interfoam_160']:.2f} %")
    # measured 1.21 %
    assert numerical <= 0.013
    # measured 0.53 %: closer; issue 11 asks 1.2 % of 80² cells
    assert fine_measures["front_difference_vs_interfoam_160"] <= 0.006


def front_error(dt: float, initial_acceleration: str) -> float:
    """The seed's dam break to T = 3 at step ``dt`` with Newmark's ``a_0`` solved or given (zero):
    its front's difference from interFoam 160²."""
    solver = simulation.build_solver(dambreak.scene({"time.end": 0.28, **dambreak.seed_setup(dt)}, files=False))
    solver.scheme = replace(solver.scheme, initial_acceleration=initial_acceleration)
    history = [(0.0, diagnostics.front_position(solver.particles))]
    while solver.time < 0.28 - 1e-9:
        solver.step()
        history.append((solver.time, diagnostics.front_position(solver.particles)))
    t, x = np.array(history).T
    return references.front_difference(references.dimensionless_front(t, x), references.interfoam_front(160))


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial runs")
def test_a_solved_initial_acceleration_takes_the_step_out_of_the_front():
    """Released from rest with ``a_0 = 0``, the trapezoidal rule's first step gains half a step's
    worth of velocity too little, and the whole flow lags by dt / 2: the front's error grows with
    the step. With ``a_0`` solved (the default) it hardly moves from 1 to 4 ms."""
    solved = [front_error(dt, "solved") for dt in (1e-3, 4e-3)]
    zero = [front_error(dt, "given") for dt in (1e-3, 4e-3)]
    # measured 1.99, 1.94 %
    assert max(solved) < 0.0205
    assert solved[1] - solved[0] < 0.0008  # measured -0.05 points
    # measured 2.22, 2.90 %: 0.68 points
    assert zero[1] - zero[0] > 0.0065


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial runs")
def test_the_shipped_scenes_front_is_no_worse_at_half_and_a_quarter_of_its_step(tmp_path):
    """Issue 11: the shipped scene's adaptive step (Courant 0.8) against Courant 0.4 and 0.2, to T = 3.2:
    the front's difference from interFoam 160² does not grow as the step falls."""
    errors = []
    for courant in (0.8, 0.4, 0.2):
        summary, front = run_dambreak(tmp_path / f"c{courant}", {"time.end": 0.28, "time.courant": courant})
        errors.append(dambreak.front_measures(front)["front_difference_vs_interfoam_160"])
    print(errors)
    # measured 1.874, 1.840, 1.837 % (on 2026-11-30 01:00 the split 1.783, 1.742, 1.754 %; the divergence form 1.800,
    # 1.766, 1.799 %)
    assert errors[0] <= 0.0190
    assert max(errors[1:]) <= errors[0] + 0.0005


def test_an_unknown_initial_acceleration_is_refused():
    with pytest.raises(fempm.InputError, match="initial_acceleration must be one of"):
        Scheme(initial_acceleration="zero").check()


def test_without_pspg_the_run_stops_with_a_diagnosis(tmp_path):
    """method.md Fig. 3: without PSPG the seed's run (its fixed step, 1 ms) diverged at 0.175 s (FLIP/PIC
    here: 0.171 s)."""
    summary, front = run_dambreak(tmp_path, {**dambreak.seed_setup(), "time.end": 0.3, "solver.pspg": False, "output.particles_interval": 0.05,
                                             "output.grid_interval": 0.05}, files=True)
    assert summary["status"] == "stopped"
    assert "pressure" in summary["cause"] and f"t = {summary['time'] + 0.001:.3f} s" in summary["cause"]
    assert summary["time"] == pytest.approx(0.255, abs=0.0015)  # measured 0.255 s (the seed: 0.175 s)
    # everything written until then is whole
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["status"] == "stopped"
    t = np.loadtxt(tmp_path / "front.csv", delimiter=",", skiprows=2)[:, 0]
    assert t[-1] == pytest.approx(summary["time"])
    assert len(list(tmp_path.glob("particles_*.vtp"))) == 6  # t = 0, 0.05, ..., 0.25
    assert not list(tmp_path.glob(".*tmp*"))


@pytest.mark.full
@pytest.mark.parametrize("alpha", [0.1, 0.0])
def test_forty_seconds_of_dambreak_keep_the_volume(alpha):
    """method.md Fig. 4: after 40 s the water lies about 5 cells deep, 73 mm: the column's area over the floor's
    width. The layer still sloshes, so its depth is the mean over the last 5 s of twice the particles' mean height
    (the median of the columns' tops at the last instant moves with round-off: 72.5 and 70.7 mm with the correction,
    59.0 and 68.9 mm without, in runs that differ in the last bits). With the shipped handling (the last step's pressure
    by parts, turning shifts) the water keeps its volume without the volume correction too; with it, it swells a little."""
    solver = simulation.build_solver(dambreak.scene({"time.end": 40.0, "solver.volume_correction": alpha}, files=False))
    t, height = [], []
    while solver.time < 40.0 - 1e-9:
        solver.step()
        t.append(solver.time)
        height.append(solver.particles.x[:, 1].mean())
    t, height = np.array(t), np.array(height)
    depth = 2 * height[t >= t[-1] - 5.0].mean()
    print(f"alpha = {alpha}: the layer's depth over the last 5 s {1000 * depth:.1f} mm")
    # measured 75.8 mm with the correction, 73.1 mm without (72.0 mm with PETSc's split instead of the compiled solve of
    # small systems, the same solutions to 3e-13), std 1.6-1.8 mm over those 5 s (2026-11-30). In divergence form (the
    # shipped handling until 2026-11-29) the run without the correction lost water: its surface at 40 s 45.1 mm, 141
    # occupied cells of 200 (this test's measure then)
    assert depth == pytest.approx(0.073, rel=0.05)


@pytest.mark.mpi
def test_a_matrix_on_the_water_region_gives_the_same_steps_as_one_on_the_grid():
    """matrix_region = "fluid" keeps rows only near the water and widens them as it flows."""
    fronts, rebuilds = {}, {}
    for region in ("grid", "fluid"):
        grid = fempm.Grid.from_cells(MPI.COMM_WORLD, (0.0, 0.0), (0.584, 0.584), (40, 40))
        water = fempm.Particles(grid)
        water.seed(fempm.Rectangle((0.0, 0.0), (L, H)), per_cell=2, density=RHO)
        solver = ImplicitSolver(fempm.BSpline2(grid), water, controls=Controls(matrix_region=region))
        front = []
        for _ in range(150):
            solver.step()
            front.append(diagnostics.front_position(water))
        fronts[region], rebuilds[region] = np.array(front), solver.region.rebuilds
    assert rebuilds["grid"] == 0 and rebuilds["fluid"] >= 1
    np.testing.assert_allclose(fronts["fluid"], fronts["grid"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("viscosity, cells, order", [(1.0e-3, 40, 1), (1.0e-3, 236, 1), (10.0, 40, 2)])
def test_pspg_takes_its_viscous_part_only_where_the_grid_diffusion_number_reaches_the_threshold(viscosity, cells,
                                                                                               order):
    """Water under gravity needs first derivatives only: nu T / h^2 with PSPG's transient time
    T = 0.025 sqrt(h / |g|) is 4.5e-6 on the shipped grid and 6.5e-5 on 236² cells (the 10 ms bound in
    place of T, as before, put that grid at 1.6e-3, over the 1e-3 threshold); a 10 Pa s fluid (0.045)
    takes PSPG's viscous part, and with it second derivatives."""
    scene = dambreak.scene({"fluid.viscosity": viscosity, "domain.cells": [cells, cells]}, files=False)
    forms = simulation.build_solver(scene).forms
    assert (forms.residual.order, forms.jacobian.order) == (order, order)
