"""Scenes: the shipped ones read back as the demo's setup; every bad input gets one clear message.

The table edits the shipped dam-break scene one mistake at a time (or gives a bad
command line) and runs ``fempm check``/``fempm run`` in process: each must end with
exit status 2 and the expected message on stderr, before anything runs.
"""

import math
import re
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm import cli
from fempm.scene import load_scene, parse_scene, scene_from_text, to_toml
from helpers import seed_setup

SCENES = Path(__file__).resolve().parents[1] / "scenes"
DAMBREAK = seed_setup((SCENES / "dambreak.toml").read_text())


def _edit(old: str, new: str, text: str = DAMBREAK) -> str:
    assert old in text, f"the shipped scene no longer contains {old!r}"
    return text.replace(old, new, 1)


COLUMN = ('shape = "rectangle"               # or "polygon" with vertices = [[x, y], ...]\n'
          'lower = [0.0, 0.0]\nupper = [0.146, 0.292]')
OBSTACLE_OVER_COLUMN = '\n[[obstacles]]\nshape = "rectangle"\nlower = [0.1, 0.0]\nupper = [0.2, 0.1]\n'

# (case, scene text or None for the shipped one, extra command-line words, expected message)
BAD_SCENES = [
    ("unknown top-level key", _edit("gravity = ", "gravty = "), [],
     r"unknown key 'gravty' in the scene \(did you mean 'gravity'\?\); allowed: name, gravity, domain"),
    ("unknown key in a section", _edit("cells = [40, 40]", "cellz = [40, 40]"), [],
     r"unknown key 'cellz' in \[domain\] \(did you mean 'cells'\?\); allowed: lower, upper, cells, cell_size"),
    ("wrong type", _edit("density = 1000.0", 'density = "heavy"'), [],
     r"fluid.density: must be a number, got str 'heavy' \(kg/m\^3\)"),
    ("negative cell size", _edit("cells = [40, 40]", "cell_size = -0.0146"), [],
     r"domain.cell_size: must be a number > 0, got -0.0146 \(m\)"),
    ("zero cells", _edit("cells = [40, 40]", "cells = [0, 40]"), [],
     r"domain.cells: must be a pair of whole numbers >= 1 \[nx, ny\], got \[0, 40\]"),
    ("cells not square", _edit("cells = [40, 40]", "cells = [40, 20]"), [],
     r"domain.cells = \[40, 20\]: the cells are square, 0.584 m / 40 = 0.0146 m, and the height 0.584 m takes 40 "
     r"rows of them, not 20: take cells = \[40, 40\], or cell_size = 0.0292 for 20 whole rows"),
    ("cells not covering a cut height", _edit("upper = [0.584, 0.584]", "upper = [0.584, 0.51]")
     .replace("cells = [40, 40]", "cells = [40, 30]"), [],
     r"domain.cells = \[40, 30\]: the cells are square, 0.584 m / 40 = 0.0146 m, and the height 0.51 m takes 35 "
     r"rows of them, the top one cut, not 30: take cells = \[40, 35\], or cell_size = 0.017 for 30 whole rows"),
    ("a cut too thin", _edit("cells = [40, 40]", "cell_size = 0.01456"), [],
     r"domain.cell_size = 0.01456: the width 0.584 in cells of h = 0.01456 leaves a last cell 0.11 h thin \(0.0016\), "
     r"less than 0.25 h, too thin to hold the wall: take h = 0.0142439 or 0.0146 \(41 or 40 whole cells\)"),
    ("a top row cut too thin", _edit("upper = [0.584, 0.584]", "upper = [0.584, 0.586]"), [],
     r"domain.cells = \[40, 40\]: the height 0.586 in cells of h = 0.0146 leaves a last cell 0.137 h thin"),
    ("cell size larger than the tank", _edit("cells = [40, 40]", "cell_size = 0.6"), [],
     r"domain.cell_size = 0.6: larger than the tank's width 0.584 m; take at most 0.584 \(m\)"),
    ("both cells and cell size", _edit("cells = [40, 40]", "cells = [40, 40]\ncell_size = 0.0146"), [],
     r"domain: give exactly one of cells = \[nx, ny\] and cell_size = h"),
    ("zero time step", _edit("dt = 1.0e-3", "dt = 0.0"), [], r"time.dt: must be a number > 0, got 0.0 \(s\)"),
    ("negative time step", _edit("dt = 1.0e-3", "dt = -1.0e-3"), [], r"time.dt: must be a number > 0, got -0.001"),
    ("missing time step", _edit("dt = 1.0e-3", ""), [], r"time.dt is missing: give a finite number > 0 \(s\)"),
    ("end not a whole number of steps", _edit("end = 1.0 ", "end = 1.0005 "), [],
     r"time.end = 1.0005 is not a whole number of steps of time.dt = 0.001"),
    ("courant number zero", _edit("dt = 1.0e-3", "dt = 1.0e-3\ncourant = 0.0"), [],
     r"time.courant: must be a number in \(0, 10\], got 0.0"),
    ("body outside the domain", _edit("upper = [0.146, 0.292]", "upper = [0.146, 0.7]"), [],
     r"bodies\[0\]: its extent \[0.0, 0.0\]..\[0.146, 0.7\] is not inside the domain \[0.0, 0.0\]..\[0.584, 0.584\]"),
    ("body overlapping an obstacle", DAMBREAK + OBSTACLE_OVER_COLUMN, [],
     r"bodies\[0\] overlaps obstacles\[0\] \(cell column 7, row 0\); move the body or the obstacle"),
    ("grid too coarse for the body", _edit("upper = [0.146, 0.292]", "upper = [0.02, 0.292]"), [],
     r"bodies\[0\]: it is 0.02 x 0.292 m, less than two cells across \(h = 0.0146 m\): the grid is too coarse"),
    ("particles per cell not a square", _edit("particles_per_cell = 4", "particles_per_cell = 3"), [],
     r"bodies\[0\].particles_per_cell: must be a square number 1, 4, 9, 16, ... \(n x n particles per cell\), got 3"),
    ("rectangle given vertices", _edit("particles_per_cell = 4", "particles_per_cell = 4\nvertices = [[0, 0], [1, 0], [0, 1]]"),
     [], r"bodies\[0\].vertices: a rectangle takes lower and upper, not vertices"),
    ("polygon of two points", _edit('shape = "rectangle"               # or "polygon" with vertices = [[x, y], ...]\n'
                                    'lower = [0.0, 0.0]\nupper = [0.146, 0.292]',
                                    'shape = "polygon"\nvertices = [[0.0, 0.0], [0.1, 0.1]]'), [],
     r"bodies\[0\].vertices: must be a list of at least three points"),
    ("unknown basis", _edit('basis = "bspline"', 'basis = "q2"'), [],
     r"solver.basis: must be one of 'bspline', 'q1', got 'q2'"),
    ("unknown linear solver", _edit('linear = "direct"', 'linear = "cg"'), [],
     r"solver.linear: must be one of 'direct', 'iterative', got 'cg'"),
    ("unknown wall condition", _edit('left = "slip"', 'left = "sticky"'), [],
     r"walls.left: must be one of 'slip', 'no-slip', got 'sticky'"),
    ("volume correction above one", _edit("volume_correction = 0.1", "volume_correction = 1.5"), [],
     r"solver.volume_correction: must be a number in \[0, 1\], got 1.5"),
    ("volume correction rate zero", _edit("volume_correction_rate = 100.0", "volume_correction_rate = 0.0"), [],
     r"solver.volume_correction_rate: must be a number > 0, got 0.0 \(1/s\)"),
    ("negative viscosity", _edit("viscosity = 1.0e-3", "viscosity = -1.0"), [],
     r"fluid.viscosity: must be a number >= 0, got -1.0 \(Pa s\)"),
    ("boolean as a string", _edit("pspg = true", 'pspg = "yes"'), [], r"solver.pspg: must be true or false, got 'yes'"),
    ("output interval shorter than dt", _edit("particles_interval = 0.05", "particles_interval = 0.0001"), [],
     r"output.particles_interval = 0.0001 is shorter than time.dt = 0.001: must be >= dt"),
    ("forms by path", _edit('pic_rate = 30.0', 'pic_rate = 30.0\nforms = "nowhere.py"'), [],
     r"solver.forms: must be the bare name of a shipped forms file \(e.g. 'incompressible'\), got 'nowhere.py': "
     r"a forms file is Python code that runs, so a scene cannot name one by path; give your own file on the "
     r"command line with --forms PATH"),
    ("forms not shipped", _edit('pic_rate = 30.0', 'pic_rate = 30.0\nforms = "nowhere"'), [],
     r"solver.forms = 'nowhere': no shipped forms of that name; shipped: gauss_pressure, incompressible, "
     r"weakly_compressible"),
    ("unknown pressure quadrature", _edit('pic_rate = 30.0', 'pic_rate = 30.0\npressure_quadrature = "gaus"'), [],
     r"solver.pressure_quadrature: must be one of 'particles', 'gauss', got 'gaus'"),
    ("Gauss-point forms without their points", _edit('pic_rate = 30.0', 'pic_rate = 30.0\nforms = "gauss_pressure"'),
     [], r"solver.forms = 'gauss_pressure' integrates the pressure's terms at Gauss points: set "
     r"solver.pressure_quadrature = 'gauss'"),
    ("no fluid", re.sub(r"\[\[bodies\]\].*?particles_per_cell = 4[^\n]*\n", "", DAMBREAK, flags=re.S), [],
     r"the scene has no fluid: add at least one \[\[bodies\]\] table"),
    ("obstacle finer than the grid", DAMBREAK + '\n[[obstacles]]\nshape = "rectangle"\nlower = [0.4, 0.0]\n'
     'upper = [0.405, 0.005]\n', [], r"obstacles\[0\]: covers no cell centre: the grid \(h = 0.0146 m\) is too coarse"),
    ("obstacle cell outside the grid", DAMBREAK + '\n[[obstacles]]\nshape = "cells"\ncells = [[40, 0]]\n', [],
     r"obstacles\[0\].cells: cell \[40, 0\] is outside the grid of 40 x 40 cells"),
    ("not TOML", "domain = [", [], r"not valid TOML: "),
    ("PETSc option misspelt", _edit("pic_rate = 30.0", "pic_rate = 30.0\npetsc = { ksp_rtoll = 1e-8 }"), [],
     r"solver.petsc.ksp_rtoll: PETSc did not use this option \(-fempm_ksp_rtoll\) .* did you mean ksp_rtol"),
    ("PETSc option with a wrong value", _edit("pic_rate = 30.0", 'pic_rate = 30.0\npetsc = { pc_type = "luu" }'), [],
     r"solver.petsc.pc_type = 'luu': PETSc rejects it \(unknown type\); allowed: .*\bgamg\b.*\blu\b"),
    ("negative end time on the command line", None, ["--end-time", "-1"],
     r"argument --end-time: must be a number of seconds > 0, got '-1'"),
    ("unknown flag", None, ["--bogus"], r"unrecognized arguments: --bogus"),
    # issue 13: no side effects, sizes before allocation, every accepted value used or refused
    ("forms escaping forms/", _edit('pic_rate = 30.0', 'pic_rate = 30.0\nforms = "../../tmp/evil"'), [],
     r"solver.forms: must be the bare name of a shipped forms file .*got '../../tmp/evil'"),
    ("forms not a .py file", None, ["--forms", "x.txt"], r"--forms = 'x.txt': not a .py file"),
    ("PETSc viewer to a file", _edit("pic_rate = 30.0", 'pic_rate = 30.0\npetsc = { ksp_view_mat = "binary:A.dat" }'),
     [], r"solver.petsc.ksp_view_mat = 'binary:A.dat': it writes a file \(a binary viewer\); PETSc options in a "
         r"scene may only print to the terminal"),
    ("PETSc monitor to a file", _edit("pic_rate = 30.0", 'pic_rate = 30.0\npetsc = { ksp_monitor = "ascii:log.txt" }'),
     [], r"solver.petsc.ksp_monitor = 'ascii:log.txt': it writes the file 'log.txt'"),
    ("PETSc drawing", _edit("pic_rate = 30.0", 'pic_rate = 30.0\npetsc = { ksp_monitor = "draw" }'),
     [], r"solver.petsc.ksp_monitor = 'draw': it draws in a window"),
    ("grid too large for the memory", _edit("cells = [40, 40]", "cells = [20000, 20000]"), [],
     r"domain.cells = \[20000, 20000\]: the run would need about 1.\d+e\+03 GB of memory \(4e\+08 cells, .*\), more "
     r"than the .* GB available; use fewer cells or particles, or set the limit with --max-memory GB"),
    ("particles too many for the memory", _edit("particles_per_cell = 4 ", "particles_per_cell = 250000 "), [],
     r"bodies\[0\].particles_per_cell = 250000: the run would need about 107 GB of memory"),
    ("over the memory limit given", None, ["--max-memory", "0.1"],
     r"domain.cells = \[40, 40\]: the run would need about 0.261 GB of memory .*, more than the 0.1 GB given by "
     r"--max-memory"),
    ("cells beyond 32-bit indices", _edit("cells = [40, 40]", "cell_size = 1e-6"), ["--max-memory", "1e9"],
     r"domain.cell_size = 1e-06: 1.02e\+12 unknowns, more than PETSc's 32-bit indices address"),
    ("tank beyond floating point", _edit("upper = [0.584, 0.584]", "upper = [1e300, 1e300]"), [],
     r"domain: the tank \[0.0, 0.0\]..\[1e\+300, 1e\+300\] in cells of 2.5e\+298 m gives particles of volume inf"),
    ("absurd step count", _edit("dt = 1.0e-3 ", "dt = 1.0e-300 "), [],
     r"time.end = 1 s in steps of time.dt = 1e-300 s is 1e\+300 steps; at most 1e\+08 in one run"),
    ("absurd end", _edit("end = 1.0 ", "end = 1.0e12 "), [],
     r"time.end = 1e\+12 s in steps of time.dt = 0.001 s is 1e\+15 steps"),
    ("mass below floating point", _edit("density = 1000.0 ", "density = 1e-320 "), [],
     r"fluid.density = 9.9\d*e-321: particles of 5.329e-05 m\^2 would have a mass of 0 kg, beyond floating point"),
    ("pressure scale reversed", _edit("pressure_scale = [0.0, 2864.52]", "pressure_scale = [2864.52, 0.0]"), [],
     r"output.pressure_scale: must be \[low, high\] with low < high, got \[2864.52, 0.0\] \(Pa\)"),
    ("pressure scale of zero width", _edit("pressure_scale = [0.0, 2864.52]", "pressure_scale = [5.0, 5.0]"), [],
     r"output.pressure_scale: must be \[low, high\] with low < high, got \[5.0, 5.0\]"),
    ("snapshot after the end", _edit("snapshots = [0.2, 0.6]", "snapshots = [0.2, 1.5]"), [],
     r"output.snapshots: 1.5 s is after the end of the run, time.end = 1 s"),
    ("snapshot between steps", _edit("snapshots = [0.2, 0.6]", "snapshots = [0.2005]"), [],
     r"output.snapshots: the time = 0.2005 is not a whole number of steps of time.dt = 0.001 \(200.5\); take 0.2 or "
     r"0.201 \(200 or 201 steps\)"),
    ("interval between whole steps", _edit("particles_interval = 0.05", "particles_interval = 0.0015"), [],
     r"output.particles_interval = 0.0015 is not a whole number of steps of time.dt = 0.001 \(1.5\); take 0.001 or "
     r"0.002 \(1 or 2 steps\)"),
    ("checkpoint interval between whole steps", _edit("checkpoint_interval = 0.1", "checkpoint_interval = 0.1004"), [],
     r"output.checkpoint_interval = 0.1004 is not a whole number of steps .*; take 0.1 or 0.101"),
    ("Newmark beta out of range", _edit("pic_rate = 30.0", "pic_rate = 30.0\nnewmark_beta = 0.7"), [],
     r"solver.newmark_beta: must be a number in \(0, 0.5\], got 0.7"),
    ("Newmark gamma out of range", _edit("pic_rate = 30.0", "pic_rate = 30.0\nnewmark_gamma = 0"), [],
     r"solver.newmark_gamma: must be a number in \(0, 1\], got 0"),
    ("transfer unknown", _edit('transfer = "affine-flip"', 'transfer = "aflip"'), [],
     r"solver.transfer: must be one of 'flip', 'apic', 'tpic', 'affine-flip', got 'aflip'"),
    ("PIC rate negative", _edit("pic_rate = 30.0", "pic_rate = -1.0"), [],
     r"solver.pic_rate: must be a number >= 0, got -1.0 \(1/s\)"),
    ("pressure limit not positive", _edit("pic_rate = 30.0", "pic_rate = 30.0\npressure_limit = -1.0"), [],
     r"solver.pressure_limit: must be a number > 0, got -1.0 \(Pa\)"),
    ("symmetric bow-tie",
     _edit(COLUMN, 'shape = "polygon"\nvertices = [[0.0, 0.0], [0.2, 0.2], [0.2, 0.0], [0.0, 0.2]]'), [],
     r"bodies\[0\]: polygon: edges 0 \(\[0.0, 0.0\]..\[0.2, 0.2\]\) and 2 .* cross or touch: the polygon must be simple"),
    ("asymmetric self-intersecting polygon",
     _edit(COLUMN, 'shape = "polygon"\nvertices = [[0.0, 0.0], [0.3, 0.2], [0.3, 0.0], [0.0, 0.1]]'), [],
     r"bodies\[0\]: polygon: edges 0 \(\[0.0, 0.0\]..\[0.3, 0.2\]\) and 2 .* cross or touch"),
    ("polygon folding back",
     _edit(COLUMN, 'shape = "polygon"\nvertices = [[0.0, 0.0], [0.3, 0.0], [0.1, 0.0], [0.1, 0.2]]'), [],
     r"bodies\[0\]: polygon: edges 0 .* and 1 .* cross or touch"),
    ("velocity expression with a call",
     _edit("particles_per_cell = 4 ", 'particles_per_cell = 4\nvelocity = ["__import__(\'os\').getcwd()", 0]'),
     [], r"bodies\[0\].velocity: component 0 .*: .__import__\(.os.\).getcwd. \(not one of the functions\) is not "
         r"allowed; allowed: numbers, x, y, pi, \+ - \* / \*\*, parentheses and sin cos exp sqrt tanh abs"),
    ("velocity expression with an unknown name", _edit("particles_per_cell = 4 ", 'particles_per_cell = 4\n'
                                                                                  'velocity = ["2*t", 0]'),
     [], r"bodies\[0\].velocity: component 0 '2\*t': the name 't' is not allowed"),
    ("velocity expression not finite", _edit("particles_per_cell = 4 ", 'particles_per_cell = 4\n'
                                                                        'velocity = [0, "sqrt(x - 0.01)"]'),
     [], r"bodies\[0\].velocity\[1\] = 'sqrt\(x - 0.01\)' is not finite at \(0.00365, 0.00365\) \(m/s\)"),
    ("output folder with a NUL", _edit('folder = "results/dambreak"', 'folder = "o\\u0000x"'), [],
     r"output.folder: must not contain a NUL character, got 'o\\x00x'"),
    ("gauge of an unknown kind", _edit('kind = "level"\nx', 'kind = "depth"\nx'), [],
     r"gauges\[4\].kind: must be one of 'pressure', 'level', got 'depth'"),
    ("pressure gauge without a position", _edit('position = [0.5839, 0.005] ', '# '), [],
     r"gauges\[0\].position is missing: a pressure gauge needs position = \[x, y\] \(m\)"),
    ("level gauge given a position", _edit("x = 0.292 ", "position = [0.292, 0.1]\n#"), [],
     r"gauges\[4\].position: a level gauge takes x, not position"),
    ("gauge outside the tank", _edit("position = [0.5839, 0.0584]", "position = [0.6, 0.0584]"), [],
     r"gauges\[3\].position = \[0.6, 0.0584\]: outside the domain \[0.0, 0.0\]..\[0.584, 0.584\] \(m\)"),
    ("pressure gauge inside an obstacle",
     DAMBREAK + '\n[[obstacles]]\nshape = "rectangle"\nlower = [0.5, 0.0]\nupper = [0.584, 0.05]\n', [],
     r"gauges\[0\].position = \[0.5839, 0.005\]: inside obstacles\[0\] \(its blocked cell \[0.5694, 0.584\] x "
     r"\[0, 0.0146\] m\), where no water goes; a gauge on the obstacle's face lies on an edge between a blocked cell "
     r"and an open one"),
    ("two gauges of one name", _edit('name = "right_y0.0146"', 'name = "right_y0.005"'), [],
     r"gauges\[1\].name = 'right_y0.005': gauges\[0\] has that name; names must be unique"),
    ("gauge interval not whole steps", _edit("x = 0.292 ", "x = 0.292\ninterval = 0.0105\n#"), [],
     r"gauges\[4\].interval = 0.0105 is not a whole number of steps of time.dt = 0.001 \(10.5\)"),
    ("output folder name too long", _edit('folder = "results/dambreak"', f'folder = "{"a" * 300}"'), [],
     r"output.folder: a name of 300 characters is too long for the file system \(a part of 300 bytes; at most 255"),
]


@pytest.mark.parametrize("case, text, extra, message", BAD_SCENES, ids=[c[0] for c in BAD_SCENES])
def test_bad_scene_gets_one_clear_message(case, text, extra, message, tmp_path, capsys):
    path = tmp_path / "scene.toml"
    path.write_text(DAMBREAK if text is None else text)
    command = ["run", str(path), "--out", str(tmp_path / "out"), *extra] if extra else ["check", str(path)]
    assert cli.main(command) == 2
    err = capsys.readouterr().err.strip()
    assert re.search(message, err), f"{case}: got {err!r}"
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out").exists()  # nothing ran


def test_bad_command_lines(tmp_path, capsys):
    folder_file = tmp_path / "a_file"
    folder_file.write_text("")
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / "checkpoint.npz").write_bytes(b"")
    scene = str(SCENES / "dambreak.toml")
    cases = [
        (["run"], r"give a scene file or --resume DIR \(not both\)"),
        (["run", str(tmp_path / "missing.toml")], r"scene file '.*missing.toml' does not exist"),
        (["run", "--resume", str(tmp_path)], r"the folder holds no checkpoint.npz"),
        (["run", "--resume", str(earlier)], r"checkpoint.npz cannot be read"),
        (["run", scene, "--out", str(folder_file)], r"output.folder = '.*a_file': exists and is not a folder"),
        (["run", scene, "--out", str(earlier)], r"holds the checkpoint of an earlier run: continue it with "
                                                r"`fempm run --resume .*`, or start afresh with --overwrite"),
        (["run", scene, "--resume", str(earlier)], r"give a scene file or --resume DIR \(not both\)"),
    ]
    for argv, message in cases:
        assert cli.main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert re.search(message, err), f"{argv}: got {err!r}"
        assert len(err.splitlines()) == 1


def test_shipped_scenes_read_back_unchanged_from_their_resolved_form():
    for path in SCENES.glob("*.toml"):
        scene = load_scene(path)
        assert parse_scene(tomllib.loads(to_toml(scene)), path) == scene


def test_dambreak_scene_is_the_seeds_tank_and_water(comm):
    """The shipped scene builds the demo's grid, particles and options exactly: the seed's tank and
    water, 2 x 2 particles per cell (as the seed's), the step adaptive (Courant 0.8, at most 10 ms), the
    particles shifted (A = 4)."""
    from fempm.simulation import build_solver

    scene = load_scene(SCENES / "dambreak.toml")
    solver = build_solver(scene, comm)
    grid = fempm.Grid.from_cells(comm, (0.0, 0.0), (0.584, 0.584), (40, 40))
    seeded = fempm.Particles(grid)
    seeded.seed(fempm.Rectangle((0.0, 0.0), (0.146, 0.292)), per_cell=2, density=1000.0)
    assert solver.grid.h == grid.h and solver.particles.global_count() == 800
    assert np.array_equal(solver.particles.x, seeded.x) and np.array_equal(solver.particles.id, seeded.id)
    physics, scheme = solver.physics, solver.scheme
    assert (scheme.dt, scheme.courant, physics.viscosity, scheme.alpha, scheme.pspg, scheme.pic_blend, physics.gravity) == \
        (1e-2, 0.8, 1e-3, 0.1, True, 0.0, (0.0, -9.81))
    assert (scheme.transfer, scheme.pic_rate, scheme.noise_rate, scheme.surface_aware) == ("affine-flip", 30.0, 300.0, True)
    from fempm.cases import vortices  # the verification's vortices take the scene's shifting

    assert scheme.shifting == vortices.SHIFTING == 4.0
    assert solver.particles["affine_velocity"].shape == solver.particles["affine_acceleration"].shape == (
        len(solver.particles), 2, 2)
    assert set(physics.wall_conditions().values()) == {"slip"} and solver.basis.name == "B-spline"
    assert math.isclose(scene.time.end, 1.0)
    from fempm.cases import dambreak  # the case's constants are the scene's

    assert (scene.domain.upper, scene.bodies[0].upper, scene.gravity[1]) == \
        ((dambreak.TANK, dambreak.TANK), (dambreak.WIDTH, dambreak.HEIGHT), -dambreak.GRAVITY)


def test_check_prints_the_resolved_scene(capsys):
    assert cli.main(["check", str(SCENES / "obstacle.toml")]) == 0
    out = capsys.readouterr().out
    if MPI.COMM_WORLD.rank == 0:
        resolved = tomllib.loads(out.split("\n", 1)[1].rsplit("\n# ", 1)[0])
        assert resolved["solver"]["basis"] == "bspline"  # a default, filled in
        assert resolved["walls"] == {"left": "slip", "right": "slip", "bottom": "slip", "top": "slip"}
        assert "40 x 40 cells of h = 0.0146 m, 12 blocked by obstacles; 800 particles; 600 steps" in out


def test_readme_example_is_a_valid_complete_scene(tmp_path):
    """The README's scene example parses, shows every key of every section, and builds."""
    from dataclasses import fields

    from fempm.scene import Body, scene_from_text
    from fempm.simulation import build_solver

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    text = re.search(r"```toml\n(.*?)```", readme, re.S).group(1)
    scene = scene_from_text(text, "README.md", folder=tmp_path / "out")
    data = tomllib.loads(text)
    keys = lambda section: {f.name for f in fields(section)}  # noqa: E731
    for name in ("fluid", "walls", "time", "solver", "output"):
        assert set(data[name]) == keys(type(getattr(scene, name))), name
    assert set(data["domain"]) == keys(type(scene.domain)) - {"cells"}  # cells is the alternative to cell_size
    assert set(data["bodies"][0]) == keys(Body) - {"vertices"} and "vertices" in data["bodies"][1]
    assert {"name", "gravity", "obstacles"} <= set(data)
    assert {k for g in data["gauges"] for k in g} == keys(type(scene.gauges[0]))
    solver = build_solver(scene, MPI.COMM_WORLD)
    assert solver.particles.global_count() == 2835 and int(solver.grid.blocked.sum()) == 48


def test_check_runs_no_forms_named_by_a_scene_and_writes_nothing(tmp_path, capsys):
    """A scene naming a forms file by path is refused before the file runs; a PETSc viewer to a
    file is refused before PETSc sees it: ``fempm check`` leaves the disk as it was."""
    evil = tmp_path / "evil.py"
    evil.write_text(f"open({str(tmp_path / 'ran')!r}, 'w').write('x')\ndef residual(s):\n    return None\n")
    scenes = {"forms.toml": _edit("pic_rate = 30.0", f'pic_rate = 30.0\nforms = "{evil}"'),
              "viewer.toml": _edit("pic_rate = 30.0", f'pic_rate = 30.0\npetsc = {{ ksp_view_mat = '
                                                      f'"binary:{tmp_path / "A.dat"}", ksp_monitor = "" }}')}
    for name, text in scenes.items():
        (tmp_path / name).write_text(text)
        before = sorted(p.name for p in tmp_path.iterdir())
        assert cli.main(["check", str(tmp_path / name)]) == 2
        assert sorted(p.name for p in tmp_path.iterdir()) == before, name
    err = capsys.readouterr().err
    assert "ksp_view_mat" in err and "solver.forms" in err


def test_an_initial_velocity_field_is_seeded_as_given(comm):
    """``velocity = ["-2*(y-0.146)", "2*(x-0.073)"]``: a rigid rotation about the column's centre."""
    from fempm.simulation import build_material

    text = _edit("particles_per_cell = 4 ", 'particles_per_cell = 4\nvelocity = ["-2*(y-0.146)", "2*(x-0.073)"]')
    scene = scene_from_text(text, "rotating.toml")
    _, particles = build_material(scene, comm)
    x, v = particles.x, particles["velocity"]
    assert np.array_equal(v[:, 0], -2 * (x[:, 1] - 0.146)) and np.array_equal(v[:, 1], 2 * (x[:, 0] - 0.073))
    assert particles.global_count() == 800


def test_check_prints_each_bodys_seeded_area_and_the_size_of_the_run(tmp_path, capsys):
    triangle = _edit(COLUMN, 'shape = "polygon"\nvertices = [[0.0, 0.0], [0.15, 0.0], [0.0, 0.3]]')
    (tmp_path / "triangle.toml").write_text(triangle)
    assert cli.main(["check", str(tmp_path / "triangle.toml")]) == 0
    out = capsys.readouterr().out
    if MPI.COMM_WORLD.rank == 0:
        assert ("# bodies[0]: 420 particles standing for 0.0223818 m^2 of the 0.0225 m^2 asked (-0.53 %: bodies are "
                "rounded to the particle lattice)") in out
        size = re.search(r"# size: about ([\d.]+) GB of memory at the start .*: 1.6e\+03 cells, 5.29e\+03 unknowns, "
                         r"3.97e\+05 matrix entries, 422 particles, 1e\+03 steps", out)  # 420 seeded
        assert size and 0.25 < float(size.group(1)) < 0.27  # printed 0.26


def test_the_pressure_limit_follows_the_scene(comm):
    """20 rho (|g| H + U^2), or solver.pressure_limit: not the default of water under Earth's gravity."""
    from fempm.simulation import build_material, pressure_limit

    def limit(text):
        scene = scene_from_text(text, "scene.toml")
        return pressure_limit(scene, build_material(scene, comm)[1])

    assert limit(DAMBREAK) == pytest.approx(20 * 1000.0 * 9.81 * 0.584, rel=1e-12)  # as ImplicitOptions' default
    drifting = _edit("gravity = [0.0, -9.81]", "gravity = [0.0, 0.0]").replace(
        "particles_per_cell = 4 ", "particles_per_cell = 4\nvelocity = [100.0, 0.0]\n", 1)
    assert limit(drifting) == pytest.approx(20 * 1000.0 * 100.0**2, rel=1e-12)
    light = _edit("density = 1000.0 ", "density = 1.2 ")
    assert limit(light) == pytest.approx(20 * 1.2 * 9.81 * 0.584, rel=1e-12)
    assert limit(_edit("pic_rate = 30.0", "pic_rate = 30.0\npressure_limit = 5.0e5")) == 5.0e5


def test_a_shorter_end_time_leaves_out_later_snapshots_with_a_note():
    scene = load_scene(SCENES / "dambreak.toml", end_time=0.3)
    assert scene.output.snapshots == (0.2,)
    assert scene.notes == ("the end time 0.3 s comes before output.snapshots 0.6 s: not taken",)
    assert parse_scene(tomllib.loads(to_toml(scene)), "resolved.toml") == scene  # the resolved scene is valid


def test_a_tank_not_a_whole_number_of_cells_is_cut_and_check_says_so(capsys, tmp_path):
    """Any tank size: square cells from the lower corner, the last column (row) cut at the face."""
    text = _edit("cells = [40, 40]", "cell_size = 0.015")  # 0.584 / 0.015 = 38.93 cells each way
    scene = scene_from_text(text, "tank.toml")
    assert scene.domain.shape == (39, 39) and scene.domain.h == 0.015
    assert scene.domain.last == pytest.approx((0.584 / 0.015 - 38,) * 2, rel=1e-12)
    path = tmp_path / "tank.toml"
    path.write_text(text)
    assert cli.main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert ("# 39 x 39 cells of h = 0.015 m, the last column cut to 0.014 m (0.933 h) and the top row cut to "
            "0.014 m (0.933 h), 0 blocked by obstacles") in out
    # cells = [nx, ny] on a tank whose height is not a whole number of them: the top row cut
    text = _edit("upper = [0.584, 0.584]", "upper = [0.584, 0.51]").replace("cells = [40, 40]", "cells = [40, 35]")
    domain = scene_from_text(text, "tank.toml").domain
    assert domain.h == pytest.approx(0.0146) and domain.last == pytest.approx((1.0, 0.51 / 0.0146 - 34), rel=1e-9)


def test_an_adaptive_step_lifts_the_whole_step_rule():
    """With time.courant the steps land on the output times, so these need not be whole steps of dt."""
    from fempm.scene import scene_from_text

    text = _edit("dt = 1.0e-3", "dt = 5.0e-3\ncourant = 0.5", _edit("particles_interval = 0.05", "particles_interval = 0.0123"))
    scene = scene_from_text(text, "dambreak.toml")
    assert scene.time.courant == 0.5 and scene.output.particles_interval == 0.0123
    # dt only bounds an adaptive step: it may exceed the run and its output intervals
    text = _edit("dt = 1.0e-3", "dt = 2.0\ncourant = 0.5", _edit("grid_interval = 0.05", "grid_interval = 0.001"))
    scene = scene_from_text(text, "dambreak.toml")
    assert scene.time.dt == 2.0 > scene.time.end and scene.output.grid_interval == 0.001
