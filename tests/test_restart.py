"""Checkpoints and restarts: a resumed run is the uninterrupted run, bit for bit.

A checkpoint edited by hand (or not fempm's) is refused field by field before anything is
built from it.

The dam-break scene is run short (60 steps) with every output on. In process (and on
two ranks by the MPI suite): a run stopped at step 30 and resumed to 60 equals one run
to 60. In subprocesses: SIGKILL after a checkpoint leaves only complete files and the
resumed run ends as the uninterrupted one; SIGTERM (serial) and SIGINT (two ranks,
forwarded by mpirun, and SIGTERM sent to mpirun) stop after the step in progress with a final
checkpoint.
"""

import json
import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fempm.cases import dambreak
from fempm.restart import CHECKPOINT
from fempm.scene import load_scene, to_toml
from fempm.simulation import resume, run_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"
END = 0.06


def _scene(folder, end=END, courant=None):
    scene = load_scene(SCENE, folder=folder, end_time=end)
    scene = dambreak.at_seed_setup(scene)  # the seed's particles (and step, unless adaptive)
    if courant:
        scene = replace(scene, time=replace(scene.time, courant=courant, dt=5e-3))
    return replace(scene, output=replace(scene.output, particles_interval=0.01, grid_interval=0.02,
                                                    snapshots=(min(end, 0.03),), checkpoint_interval=0.01,
                                                    progress=False))


def _state(folder):
    """Particle fields of the checkpoint and the bytes of every table and index."""
    with np.load(Path(folder) / CHECKPOINT) as f:
        particles = {k: f[k] for k in f.files if k.startswith("particle:")}
        meta = json.loads(str(f["meta"]))
    tables = {name: (Path(folder) / name).read_bytes() for name in ("front.csv", "volume.csv", "gauges.csv", "particles.pvd",
                                                                "grid.pvd")}
    return particles, meta, tables


def _assert_same_run(a, b):
    pa, ma, ta = _state(a)
    pb, mb, tb = _state(b)
    assert ma["steps"] == mb["steps"] and ma["time"] == mb["time"]
    for name in pa:
        assert np.array_equal(pa[name], pb[name]), f"particle field {name} differs"
    assert ta == tb
    files = lambda folder: sorted(p.name for p in Path(folder).iterdir() if p.suffix in (".vtp", ".vti", ".png"))  # noqa: E731
    assert files(a) == files(b)
    for name in files(a):
        if name.endswith((".vtp", ".vti")):
            assert (Path(a) / name).read_bytes() == (Path(b) / name).read_bytes(), name


@pytest.mark.mpi
@pytest.mark.parametrize("courant", [None, 0.05], ids=["fixed step", "adaptive step"])
def test_resume_is_bit_identical_to_the_uninterrupted_run(shared_tmp, courant):
    comm = MPI.COMM_WORLD
    whole, part = shared_tmp / "whole", shared_tmp / "part"
    complete = run_scene(_scene(whole, courant=courant), comm)
    assert complete["status"] == "completed"
    first = run_scene(_scene(part, end=0.03, courant=courant), comm)
    # adaptive: from the bound 5e-3 s at rest to the Courant limit, growing at most 25 % a step (measured 15, 57;
    # from a_0 = 0: 13, 52)
    assert first["steps"] == (30 if courant is None else 15)  # FLIP/PIC: 14
    summary = resume(part, comm, end_time=END, progress=False)
    assert summary["status"] == "completed" and summary["resumed_from_step"] == first["steps"]
    assert summary["steps"] == complete["steps"] == (60 if courant is None else 57)  # FLIP/PIC: 53
    # the wall times add up over the two parts (on main the summary kept only the resumed part's): the first
    # part counts until its last checkpoint, before the files written at its end (measured 3.971 of 3.979 s);
    # each the largest over the ranks, the same on every rank
    earlier = summary["wall_time_s"] - summary["wall_time_this_part_s"]
    assert 0.8 * first["wall_time_s"] < earlier <= first["wall_time_s"] + 1e-9
    assert comm.allgather(summary["wall_time_s"]) == [summary["wall_time_s"]] * comm.size
    assert summary["wall_time_by_phase_s"]["solve"] > first["wall_time_by_phase_s"]["solve"]
    comm.barrier()
    if comm.rank == 0:
        _assert_same_run(whole, part)
        with np.load(part / "checkpoint.npz") as saved:  # the affine parts of the default transfer are saved
            n = len(saved["particle:id"])
            assert saved["particle:affine_velocity"].shape == saved["particle:affine_acceleration"].shape == (n, 2, 2)
        front = np.loadtxt(part / "front.csv", delimiter=",", skiprows=2)
        assert len(front) == complete["steps"] + 1 and front[-1, 1] > front[0, 1] + 0.01  # the water moved
        # the scene's gauges: a row per step, none twice after the resume (the wall's are dry this early)
        gauges = np.genfromtxt(part / "gauges.csv", delimiter=",", skip_header=2)
        assert len(gauges) == complete["steps"] + 1 and len(np.unique(gauges[:, 0])) == len(gauges)
        assert np.all(np.isfinite(gauges[:, -1])) and np.all(np.isnan(gauges[:, 1]))  # level every step; wall dry
        assert (part / "gauges.png").is_file()


def test_resume_with_the_last_steps_pressure_by_parts_is_bit_identical(tmp_path):
    """``solver.pressure_work = "increment"`` takes the last step's pressure from the particles' (fempm.hydrostatic,
    ``LastPressure``), which the checkpoint carries: the resumed run is the whole one, to the bit."""
    def scene(folder, end):
        s = _scene(folder, end=end)
        return replace(s, solver=replace(s.solver, pressure_work="increment"))

    whole, part = tmp_path / "whole", tmp_path / "part"
    assert run_scene(scene(whole, END), MPI.COMM_WORLD)["status"] == "completed"
    assert run_scene(scene(part, 0.03), MPI.COMM_WORLD)["status"] == "completed"
    assert resume(part, MPI.COMM_WORLD, end_time=END, progress=False)["status"] == "completed"
    _assert_same_run(whole, part)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="the multigrid cycle is kept on one rank only")
def test_resume_keeping_the_pressure_multigrid_is_bit_identical(tmp_path):
    """104² cells (4,300 free dofs and more): the Schur complement by a multigrid cycle, set up with each new
    pattern and kept while it stays (fempm.linear). A checkpoint renews it, as a resumed run's first solve
    sets it up afresh; without that the resumed run parted from the whole one in the last bits."""
    from fempm.simulation import build_solver

    def scene(folder, end):
        s = _scene(folder, end=end)
        return replace(s, domain=replace(s.domain, cells=(104, 104)))

    solver = build_solver(scene(tmp_path / "probe", 0.002), MPI.COMM_WORLD)
    solver.step()
    assert solver.system.linear_solver.ksp.getPC().getFieldSplitSubKSP()[-1].getPC().getType() == "gamg"
    whole, part = tmp_path / "whole", tmp_path / "part"
    assert run_scene(scene(whole, END), MPI.COMM_WORLD)["status"] == "completed"
    assert run_scene(scene(part, 0.03), MPI.COMM_WORLD)["status"] == "completed"
    assert resume(part, MPI.COMM_WORLD, end_time=END, progress=False)["status"] == "completed"
    _assert_same_run(whole, part)


def _fempm(*args, ranks=1):
    mpirun = str(Path(sys.executable).parent / "mpirun")
    prefix = [mpirun, "-n", str(ranks)] if ranks > 1 else []
    return subprocess.Popen([*prefix, sys.executable, "-m", "fempm.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})


def _wait_for(path, process, timeout=120):
    start = time.monotonic()
    while not path.exists():
        assert process.poll() is None, f"the run ended early: {process.communicate()}"
        assert time.monotonic() - start < timeout, f"{path} did not appear"
        time.sleep(0.01)


def _assert_only_complete_files(folder) -> int:
    """No temporary file; every index lists files that exist, every table and series file reads.

    Returns the step of the checkpoint."""
    import pyvista as pv

    names = sorted(p.name for p in folder.iterdir())
    assert not [n for n in names if n.startswith(".")], names
    for index in folder.glob("*.pvd"):
        for entry in ET.parse(index).getroot().iter("DataSet"):
            assert (folder / entry.get("file")).exists()
    for series in [*folder.glob("*.vtp"), *folder.glob("*.vti")]:
        assert pv.read(series).n_points > 0
    np.loadtxt(folder / "front.csv", delimiter=",", skiprows=2)
    with np.load(folder / CHECKPOINT) as f:
        return json.loads(str(f["meta"]))["steps"]


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own processes")
def test_sigkill_loses_only_the_steps_since_the_checkpoint_and_no_file_is_half_written(tmp_path):
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text(to_toml(_scene(tmp_path / "killed", end=0.2)))
    run_scene(_scene(tmp_path / "whole", end=0.2), MPI.COMM_SELF)
    killed = tmp_path / "killed"
    process = _fempm("run", str(scene_file))
    _wait_for(killed / CHECKPOINT, process)
    process.send_signal(signal.SIGKILL)
    process.communicate()
    assert process.returncode == -signal.SIGKILL
    assert _assert_only_complete_files(killed) % 10 == 0  # a periodic checkpoint, every 10 steps
    process = _fempm("run", "--resume", str(killed))
    out, err = process.communicate()
    assert process.returncode == 0, err
    _assert_same_run(tmp_path / "whole", killed)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own processes")
@pytest.mark.parametrize("ranks, signum", [(1, signal.SIGTERM), (2, signal.SIGINT), (2, signal.SIGTERM)])
def test_a_stop_signal_writes_a_final_checkpoint_and_ends_cleanly(tmp_path, ranks, signum):
    folder = tmp_path / "run"
    scene_file = tmp_path / "scene.toml"
    scene_file.write_text(to_toml(_scene(folder, end=1.0)))
    process = _fempm("run", str(scene_file), ranks=ranks)
    _wait_for(folder / CHECKPOINT, process)
    process.send_signal(signum)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 128 + signum, err
    assert "Traceback" not in err and f"interrupted by {signum.name}" in err
    summary = json.loads((folder / "summary.json").read_text())
    with np.load(folder / CHECKPOINT) as f:
        steps = json.loads(str(f["meta"]))["steps"]
    assert summary["status"] == "interrupted" and steps == summary["steps"] and 10 <= steps < 1000
    assert len(np.loadtxt(folder / "front.csv", delimiter=",", skiprows=2)) == steps + 1
    assert _assert_only_complete_files(folder) == steps


@pytest.fixture(scope="module")
def checkpointed(tmp_path_factory):
    """A folder with a run of 10 steps and its checkpoint."""
    folder = tmp_path_factory.mktemp("checkpointed") / "run"
    assert run_scene(_scene(folder, end=0.01), MPI.COMM_SELF)["status"] == "completed"
    return folder


def _with_meta(change):
    def edit(meta, arrays):
        change(meta)
    return edit


def _with_array(name, make):
    def edit(meta, arrays):
        arrays[f"particle:{name}"] = make(arrays.get(f"particle:{name}"))
    return edit


def _drop(name):
    def edit(meta, arrays):
        del arrays[f"particle:{name}"]
    return edit


def _volume_negative(volume):
    volume = volume.copy()
    volume[3] = -volume[3]
    return volume


def _position_nan(x):
    x = x.copy()
    x[5, 1] = np.nan
    return x


EDITS = [
    ("steps missing", _with_meta(lambda m: m.pop("steps")), r"meta.steps is missing \(a whole number >= 0\)"),
    ("time a string", _with_meta(lambda m: m.update(time="x")), r"meta.time = 'x': must be a finite number >= 0"),
    ("steps negative", _with_meta(lambda m: m.update(steps=-1)), r"meta.steps = -1: must be a whole number >= 0"),
    ("lost empty", _with_meta(lambda m: m.update(lost=[])), r"meta.lost = \[\]: must be \[mass >= 0, count >= 0\]"),
    ("front row short", _with_meta(lambda m: m["recorder"].update(front=[[1]])),
     r"meta.recorder.front: row 0 is \[1\], not \[a finite number, a finite number\]"),
    ("front too short", _with_meta(lambda m: m["recorder"].update(front=m["recorder"]["front"][:-1])),
     r"meta.recorder.front has 10 rows, but a run at step 10 has 11"),
    ("series entry a path", _with_meta(lambda m: m["recorder"]["particle_series"][0].__setitem__(1, "/etc/passwd")),
     r"meta.recorder.particle_series: row 0 is \[0.0, '/etc/passwd'\], not \[a finite number, a series file name\]"),
    ("time not steps times dt", _with_meta(lambda m: m.update(time=0.5)),
     r"meta.time = 0.5 is not meta.steps = 10 times the scene's time.dt = 0.001"),
    ("velocity of width 3", _with_array("velocity", lambda v: np.zeros((len(v), 3))),
     r"particle field 'velocity' has shape \(800, 3\), expected \(800, 2\) \(one row per particle\)"),
    ("ids as floats", _with_array("id", lambda i: i.astype(float)),
     r"particle field 'id' holds float64, expected int64"),
    ("ids repeated", _with_array("id", lambda i: np.zeros_like(i)),
     r"particle field 'id' must hold distinct whole numbers >= 0"),
    ("a volume negative", _with_array("volume", _volume_negative), r"particle field 'volume' must be positive"),
    ("a position NaN", _with_array("x", _position_nan), r"particle field 'x' holds values that are not finite"),
    ("a field missing", _drop("pressure"), r"particle fields \['pressure'\] are missing"),
    ("affine part flat", _with_array("affine_velocity", lambda c: c.reshape(len(c), 4)),
     r"particle field 'affine_velocity' has shape \(800, 4\), expected \(800, 2, 2\)"),
    ("affine part missing", _drop("affine_acceleration"), r"particle fields \['affine_acceleration'\] are missing"),
    ("affine part NaN", _with_array("affine_velocity", lambda c: np.full_like(c, np.nan)),
     r"particle field 'affine_velocity' holds values that are not finite"),
    ("a field extra", _with_array("colour", lambda _: np.zeros(800)),
     r"particle fields \['colour'\] are not fields of this scene's particles"),
]


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="one rank edits the file")
@pytest.mark.parametrize("case, edit, message", EDITS, ids=[e[0] for e in EDITS])
def test_a_checkpoint_is_checked_field_by_field(checkpointed, tmp_path, case, edit, message):
    import shutil

    from fempm.errors import InputError

    folder = tmp_path / "run"
    shutil.copytree(checkpointed, folder)
    with np.load(folder / CHECKPOINT) as f:
        arrays = {k: f[k] for k in f.files}
    meta = json.loads(str(arrays["meta"]))
    edit(meta, arrays)
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(folder / CHECKPOINT, **arrays)
    with pytest.raises(InputError, match=rf"--resume '.*run': checkpoint.npz: {message}"):
        resume(folder, MPI.COMM_SELF, progress=False)


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="one rank edits the folder")
def test_a_checkpoint_whose_series_files_are_gone_is_refused(checkpointed, tmp_path):
    import shutil

    from fempm.errors import InputError

    folder = tmp_path / "run"
    shutil.copytree(checkpointed, folder)
    (folder / "particles_000001.vtp").unlink()
    with pytest.raises(InputError, match=r"meta.recorder.particle_series lists particles_000001.vtp, which is not in "
                                         r"the folder \(1 missing\)"):
        resume(folder, MPI.COMM_SELF, progress=False)
