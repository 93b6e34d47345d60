"""Scenes: the shipped ones read back as the demo's setup; every bad input gets one clear message.

The table edits the shipped dam-break scene one mistake at a time (or gives a bad
command line) and runs ``fempm check``/``fempm run`` in process: each must end with
exit status 2 and the expected message on stderr, before anything runs.
"""

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

import fempm
from fempm import cli
from fempm.scene import load_scene, parse_scene, to_toml

SCENES = Path(__file__).resolve().parents[1] / "scenes"
DAMBREAK = (SCENES / "dambreak.toml").read_text()


def _edit(old: str, new: str, text: str = DAMBREAK) -> str:
    assert old in text, f"the shipped scene no longer contains {old!r}"
    return text.replace(old, new, 1)


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
     r"domain.cells: grid: cells must be square, but 40 x 20 cells"),
    ("cell size not dividing the tank", _edit("cells = [40, 40]", "cell_size = 0.05"), [],
     r"domain.cell_size: grid: the width \(0.584\) is not a whole number of cells of size h = 0.05"),
    ("both cells and cell size", _edit("cells = [40, 40]", "cells = [40, 40]\ncell_size = 0.0146"), [],
     r"domain: give exactly one of cells = \[nx, ny\] and cell_size = h"),
    ("zero time step", _edit("dt = 1.0e-3", "dt = 0.0"), [], r"time.dt: must be a number > 0, got 0.0 \(s\)"),
    ("negative time step", _edit("dt = 1.0e-3", "dt = -1.0e-3"), [], r"time.dt: must be a number > 0, got -0.001"),
    ("missing time step", _edit("dt = 1.0e-3", ""), [], r"time.dt is missing: give a finite number > 0 \(s\)"),
    ("end not a whole number of steps", _edit("end = 1.0 ", "end = 1.0005 "), [],
     r"time.end = 1.0005 is not a whole number of steps of time.dt = 0.001"),
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
    ("negative viscosity", _edit("viscosity = 1.0e-3", "viscosity = -1.0"), [],
     r"fluid.viscosity: must be a number >= 0, got -1.0 \(Pa s\)"),
    ("boolean as a string", _edit("pspg = true", 'pspg = "yes"'), [], r"solver.pspg: must be true or false, got 'yes'"),
    ("output interval shorter than dt", _edit("particles_interval = 0.05", "particles_interval = 0.0001"), [],
     r"output.particles_interval = 0.0001 is shorter than time.dt = 0.001: must be >= dt"),
    ("missing forms file", _edit('pic_blend = 0.1', 'pic_blend = 0.1\nforms = "nowhere.py"'), [],
     r"solver.forms = '.*nowhere.py': no such forms file"),
    ("no fluid", re.sub(r"\[\[bodies\]\].*?particles_per_cell = 4[^\n]*\n", "", DAMBREAK, flags=re.S), [],
     r"the scene has no fluid: add at least one \[\[bodies\]\] table"),
    ("obstacle finer than the grid", DAMBREAK + '\n[[obstacles]]\nshape = "rectangle"\nlower = [0.4, 0.0]\n'
     'upper = [0.405, 0.005]\n', [], r"obstacles\[0\]: covers no cell centre: the grid \(h = 0.0146 m\) is too coarse"),
    ("obstacle cell outside the grid", DAMBREAK + '\n[[obstacles]]\nshape = "cells"\ncells = [[40, 0]]\n', [],
     r"obstacles\[0\].cells: cell \[40, 0\] is outside the grid of 40 x 40 cells"),
    ("not TOML", "domain = [", [], r"not valid TOML: "),
    ("PETSc option misspelt", _edit("pic_blend = 0.1", "pic_blend = 0.1\npetsc = { ksp_rtoll = 1e-8 }"), [],
     r"solver.petsc.ksp_rtoll: PETSc did not use this option \(-fempm_ksp_rtoll\) .* did you mean ksp_rtol"),
    ("PETSc option with a wrong value", _edit("pic_blend = 0.1", 'pic_blend = 0.1\npetsc = { pc_type = "luu" }'), [],
     r"solver.petsc.pc_type = 'luu': PETSc rejects it \(unknown type\); allowed: .*\bgamg\b.*\blu\b"),
    ("negative end time on the command line", None, ["--end-time", "-1"],
     r"argument --end-time: must be a number of seconds > 0, got '-1'"),
    ("unknown flag", None, ["--bogus"], r"unrecognized arguments: --bogus"),
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


def test_dambreak_scene_is_the_seed_setup(comm):
    """The shipped scene builds the demo's grid, particles and options exactly."""
    from fempm.simulation import build_solver

    scene = load_scene(SCENES / "dambreak.toml")
    solver = build_solver(scene, comm)
    grid = fempm.Grid.from_cells(comm, (0.0, 0.0), (0.584, 0.584), (40, 40))
    seeded = fempm.Particles(grid)
    seeded.seed(fempm.Rectangle((0.0, 0.0), (0.146, 0.292)), per_cell=2, density=1000.0)
    assert solver.grid.h == grid.h and solver.particles.global_count() == 800
    assert np.array_equal(solver.particles.x, seeded.x) and np.array_equal(solver.particles.id, seeded.id)
    physics, scheme = solver.physics, solver.scheme
    assert (scheme.dt, physics.viscosity, scheme.alpha, scheme.pspg, scheme.pic_blend, physics.gravity) == \
        (1e-3, 1e-3, 0.1, True, 0.1, (0.0, -9.81))
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
    solver = build_solver(scene, MPI.COMM_WORLD)
    assert solver.particles.global_count() == 2835 and int(solver.grid.blocked.sum()) == 48
