"""Small builders shared by the tests (particle layouts, scene texts, the forms under test, runs on 1 and 2 ranks)."""

import dataclasses
import os
import re
import subprocess
import sys
from pathlib import Path

import basix
import numpy as np
import ufl
from petsc4py import PETSc

import fempm
from fempm.implicit import ImplicitSolver


def particles_at_gauss_points(grid, degree, density=lambda x: 1.0 + 0 * x[:, 0]):
    """Particles at the Gauss points of every cell, volumes = Gauss weights."""
    pts, wts = basix.make_quadrature(basix.CellType.quadrilateral, degree)
    cells = grid.owned_cells
    x = (grid.cell_origin(cells)[:, None, :] + grid.h * pts[None]).reshape(-1, 2)
    particles = fempm.Particles(grid)
    particles.add_field("velocity_gradient", (2, 2))
    particles.add_points(x, np.tile(wts, len(cells)) * grid.h**2, density=density(x))
    return particles


def random_particles(grid, counts_per_cell, seed=0):
    """In each owned cell a given number of particles (cycled), random positions and volumes."""
    rng = np.random.default_rng(seed + grid.comm.rank)
    cells = np.sort(grid.owned_cells)
    counts = np.resize(np.asarray(counts_per_cell), len(cells))
    cell_of = np.repeat(cells, counts)
    x = grid.cell_origin(cell_of) + grid.h * rng.random((len(cell_of), 2))
    particles = fempm.Particles(grid)
    volume = grid.h**2 * (0.2 + rng.random(len(x)))
    particles.add_points(x, volume, density=1000.0 * (0.5 + rng.random(len(x))))
    return particles


def seed_setup(text: str) -> str:
    """The shipped dam-break scene's text in the seed's set-up: its fixed step, dt = 1 ms, and its
    2 x 2 particles per cell (the scene's own step adapts to the flow): for tests that edit the text of
    a fixed-step scene."""
    text = re.sub(r"^courant = .*\n", "", text, count=1, flags=re.M)
    text = re.sub(r"^particles_per_cell = \d+ ", "particles_per_cell = 4 ", text, count=1, flags=re.M)
    return re.sub(r"^dt = 1\.0e-2 ", "dt = 1.0e-3 ", text, count=1, flags=re.M)


def eps(w):
    return ufl.sym(ufl.grad(w))


# The forms of the method, one term each (method.md eq. 1), on a space {"u": 2, "p": 1}.
def mass(s):
    (u, _), (v, _) = s.trial, s.test
    return s.particle("density") * ufl.inner(u, v) * s.dx


def viscous(s):
    (u, _), (v, _) = s.trial, s.test
    return 2 * s.constant("mu") * ufl.inner(eps(u), eps(v)) * s.dx


def divergence(s):
    (u, p), (v, q) = s.trial, s.test
    return (-p * ufl.div(v) + q * ufl.div(u)) * s.dx


def pspg(s):
    (u, p), (v, q) = s.trial, s.test
    tau = s.constant("tau")
    rho = s.particle("density")
    return tau * (ufl.inner(ufl.grad(p), ufl.grad(q)) + rho * ufl.inner(u, ufl.grad(q))) * s.dx


BILINEAR = {"mass": mass, "viscous": viscous, "divergence": divergence, "pspg": pspg}
CONSTANTS = {"mu": 1.0e-3, "tau": 1.0e-4}


def relative_difference(A, B):
    """||A - B|| / ||B|| (Frobenius) of two PETSc matrices or vectors."""
    D = A.copy()
    D.axpy(-1.0, B)
    return D.norm() / B.norm()


def to_dense(A):
    """A serial PETSc matrix as a dense numpy array."""
    return A.convert(PETSc.Mat.Type.DENSE).getDenseArray().copy()


def resting_water(grid, width: float, depth: float, steps: int = 0, density: float = 1000.0):
    """Water ``depth`` deep over ``[0, width]`` of ``grid``, 2 x 2 particles per cell, B-spline
    implicit solver with default options, after ``steps`` steps."""
    water = fempm.Particles(grid)
    water.seed(fempm.Rectangle((0.0, 0.0), (width, depth)), per_cell=2, density=density)
    solver = ImplicitSolver(fempm.BSpline2(grid), water)
    for _ in range(steps):
        solver.step()
    return solver


def assert_the_dam_break_is_the_same_on_1_and_2_ranks(tmp_path, **solver):
    """The shipped scene cut to its first 100 steps at the seed's step, its ``[solver]`` changed by ``solver``, run by
    ``fempm run`` on 1 and 2 ranks: the fronts agree to 1e-10 m and the gauges to 1e-6 of their largest value."""
    from fempm.cases import dambreak
    from fempm.scene import Output, load_scene, to_toml

    scene_path = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"
    mpirun = str(Path(sys.executable).parent / "mpirun")
    runs = {}
    for ranks in (1, 2):
        folder = tmp_path / f"ranks{ranks}"
        scene = dambreak.at_seed_setup(load_scene(scene_path, end_time=0.1))
        scene = dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, **solver),
                                    output=Output(folder=str(folder), progress=False))
        scene_file = tmp_path / f"scene{ranks}.toml"
        scene_file.write_text(to_toml(scene))
        run = subprocess.run([mpirun, "-n", str(ranks), sys.executable, "-m", "fempm.cli", "run", str(scene_file)],
                             capture_output=True, text=True, timeout=900, env={**os.environ, "OMP_NUM_THREADS": "1"})
        assert run.returncode == 0, run.stderr[-3000:]
        runs[ranks] = [np.loadtxt(folder / name, delimiter=",", skiprows=2) for name in ("front.csv", "gauges.csv")]
    (front1, gauges1), (front2, gauges2) = runs[1], runs[2]
    assert front1.shape == (101, 2) and front1[-1, 1] - front1[0, 1] > 0.02  # the front ran
    assert np.abs(front2 - front1).max() <= 1e-10
    assert np.nanmax(np.abs(gauges2 - gauges1)) <= 1e-6 * np.nanmax(np.abs(gauges1))
