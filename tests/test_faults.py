"""Faults and hostile input, through the ``fempm`` command: one line, the documented exit status.

Each case runs ``fempm`` in its own process (as a user would) and checks the exit status
(README: 0 done, 1 stopped early, 2 bad input, 128 + n on signal n), that stderr holds
one line and no traceback, and what is left on disk: a forms file's mistakes, a full disk
mid-run and at the end (a small tmpfs, where this process may mount one), unwritable folders,
SIGINT during start-up, output folders of earlier runs, and the memory estimate against the peak memory measured.
"""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fempm.scene import estimate, scene_from_text
from helpers import seed_setup

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own processes")

ROOT = Path(__file__).resolve().parents[1]
FEMPM = str(Path(sys.executable).parent / "fempm")
DAMBREAK = seed_setup((ROOT / "scenes" / "dambreak.toml").read_text())
FORMS = (ROOT / "forms" / "incompressible.py").read_text()


def _short(end=0.02, **replace) -> str:
    """The shipped dam break cut to ``end`` with frequent outputs (every kind of file within a few steps)."""
    text = (DAMBREAK.replace("end = 1.0 ", f"end = {end} ")
            .replace("particles_interval = 0.05", "particles_interval = 0.005")
            .replace("grid_interval = 0.05", "grid_interval = 0.01")
            .replace("snapshots = [0.2, 0.6]", f"snapshots = [{min(end, 0.01)}]")
            .replace("checkpoint_interval = 0.1", "checkpoint_interval = 0.01"))
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    return text


def fempm(*args, cwd=None, timeout=600):
    """Run ``fempm args``; returns (exit status, stdout, stderr)."""
    run = subprocess.run([FEMPM, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=timeout,
                         env={**os.environ, "OMP_NUM_THREADS": "1"})
    return run.returncode, run.stdout, run.stderr


def one_line(err: str) -> str:
    lines = [line for line in err.strip().splitlines() if not line.startswith("fempm: note:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# -- forms files: code, and their mistakes -----------------------------------------------------------------
FORMS_MISTAKES = [
    ("syntax error", ("def residual(s):", "def residual(s)"),
     r"forms file '.*forms.py', line \d+ \(def residual\(s\)\): SyntaxError: expected ':'"),
    ("exception at import", ("import ufl\n", "import ufl\n1 / 0\n"),
     r"forms file '.*', line \d+, in <module> \(1 / 0\): ZeroDivisionError: division by zero"),
    ("missing import", ("import ufl\n", ""),
     r"forms file '.*', line \d+, in momentum \(du, p = ufl.split\(s.grid\(\"U\"\)\)\): NameError: name 'ufl' is not "
     r"defined"),
    ("residual returning None", ("    return momentum(s) + continuity(s) + pspg(s)", "    momentum(s)"),
     r"forms file '.*': residual\(\) returned None \(a missing return\?\)"),
    ("vector-valued residual", ("    return momentum(s) + continuity(s) + pspg(s)", "    return s.test[0] * s.dx"),
     r"forms file '.*', line \d+, in residual \(return s.test\[0\] \* s.dx\): ValueError: Can only integrate scalar "
     r"expressions. The integrand is a tensor expression with value shape \(2,\)"),
    ("dot of a vector and a scalar",
     ("    return q * volume_rate(s, v_new) * s.dx\n", "    return ufl.dot(v_new, q) * s.dx\n"),
     r"forms file '.*', line \d+, in continuity \(return ufl.dot\(v_new, q\) \* s.dx\): ValueError: Dot product "
     r"requires non-scalar arguments, got arguments with ranks 1 and 0."),
    ("forgotten measure",
     ("    return momentum(s) + continuity(s) + pspg(s)", "    return s.test[1] * ufl.div(s.test[0])"),
     r"forms file '.*': residual\(\) returned an expression, not an integral: multiply it by a measure, s.dx or "
     r"s.dx_lumped \(a `\* s.dx` forgotten\?\)"),
    ("trial function in the residual", ("    return momentum(s) + continuity(s) + pspg(s)",
                                        "    return momentum(s) + s.trial[1] * s.test[1] * s.dx"),
     r"forms file '.*': residual\(\) contains a trial function \(s.trial\)"),
    ("not linear in the test functions", ("    return momentum(s) + continuity(s) + pspg(s)",
                                          "    return momentum(s) + s.test[1] ** 2 * s.dx"),
     r"forms file '.*': residual\(\) is not linear in the test functions: Applying nonlinear operator Power"),
    ("no residual", ("def residual(s):", "def residuals(s):"),
     r"forms file '.*' does not define the function residual"),
]


@pytest.mark.parametrize("case, edit, message", FORMS_MISTAKES, ids=[c[0] for c in FORMS_MISTAKES])
def test_a_mistake_in_a_forms_file_is_one_message_naming_file_function_and_line(case, edit, message, tmp_path):
    """In process for speed (the command's own handling is the same: see the next test)."""
    from fempm import cli

    old, new = edit
    assert old in FORMS
    forms = tmp_path / "forms.py"
    forms.write_text(FORMS.replace(old, new, 1))
    (tmp_path / "scene.toml").write_text(DAMBREAK.replace("volume_correction = 0.1 ", "volume_correction = 0.0 "))
    err = _in_process(cli.main, ["check", str(tmp_path / "scene.toml"), "--forms", str(forms)], status=2)
    assert re.search(message, one_line(err)), err


def _in_process(main, argv, status):
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        assert main(argv) == status
    return err.getvalue()


def test_the_command_reports_a_forms_mistake_with_status_2_and_an_edited_switch_works(tmp_path):
    forms = tmp_path / "forms.py"
    forms.write_text(FORMS.replace("    return q * volume_rate(s, v_new) * s.dx\n", "    return ufl.dot(v_new, q) * s.dx\n"))
    scene = tmp_path / "scene.toml"
    scene.write_text(DAMBREAK.replace("volume_correction = 0.1 ", "volume_correction = 0.0 "))
    status, out, err = fempm("check", scene, "--forms", forms)
    assert status == 2 and "ValueError: Dot product requires non-scalar arguments" in one_line(err)
    # the ordinary edit `mu = 1.0e4 * mu` before `if switched_on(mu)` compiles and runs
    forms.write_text(FORMS.replace("    stress = -p", "    mu = 1.0e4 * mu\n    stress = -p", 1))
    scene.write_text(_short(end=0.002))
    status, out, err = fempm("run", scene, "--forms", forms, "--out", tmp_path / "out", "--quiet")
    assert status == 0, err
    # resuming a run made with one's own forms asks for them again: a checkpoint names them, but they are code
    status, out, err = fempm("run", "--resume", tmp_path / "out", "--end-time", "0.003")
    assert status == 2 and re.search(r"the run used the forms file '.*forms.py', which is Python code: to run it "
                                     r"again give --forms", one_line(err))
    status, out, err = fempm("run", "--resume", tmp_path / "out", "--end-time", "0.003", "--forms", forms, "--quiet")
    assert status == 0, err


# -- sizes ----------------------------------------------------------------------------------------------------------
#: Runs `fempm run` and prints the process's own peak resident memory (VmHWM of its memory map, which starts
#: at exec: the ru_maxrss of a child counts the image forked from the test process, hundreds of MB late in the suite)
_MEASURED_RUN = ("import re, sys, fempm_command\n"
                 "sys.argv[0] = 'fempm'\ntry:\n    status = fempm_command.main()\n"
                 "finally:\n    print(re.search(r'VmHWM:\\s*(\\d+)', open('/proc/self/status').read()).group(1), file=sys.stderr)\n"
                 "sys.exit(status)")


def _peak_memory(scene_text: str, tmp_path) -> float:
    """Peak resident memory (GB) of `fempm run` of a scene."""
    scene = tmp_path / "scene.toml"
    scene.write_text(scene_text)
    done = subprocess.run([sys.executable, "-c", _MEASURED_RUN, "run", str(scene), "--out", str(tmp_path / "out"),
                           "--quiet", "--overwrite"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert done.returncode == 0, done.stderr
    return int(done.stderr.split()[-1]) * 1024 / 1e9


def _refined(cells: int, steps: int = 2) -> str:
    dt = 1e-3 * 40 / cells
    text = (DAMBREAK.replace("cells = [40, 40]", f"cells = [{cells}, {cells}]").replace("dt = 1.0e-3 ", f"dt = {dt!r} ")
            .replace("end = 1.0 ", f"end = {steps * dt!r} "))
    return "\n".join(line for line in text.splitlines() if line.split("=")[0].strip() not in
                     ("particles_interval", "grid_interval", "snapshots", "final_snapshot", "checkpoint_interval"))


def test_the_memory_estimate_is_close_to_the_measured_peak(tmp_path):
    """Two sizes of the refined dam break: 800 and 12 800 particles, direct solver, two steps.

    Fitted on 11 runs up to 2e5 particles (ratios measured/estimated 0.97 to 1.05) and
    within 0.91 to 1.23 of the README's scaling table up to 1e6 particles on 2 ranks. The
    small run is mostly the imports, whose size depends on the machine (0.26 GB here, 0.32 to
    0.36 GB on the CI machine): the small run is not bounded on its own, the growth between
    the two sizes and the larger run with the small run's excess over its estimate taken off are."""
    _peak_memory(_refined(40), tmp_path)  # compiles what the caches lack: its memory is not the run's
    measured = {cells: _peak_memory(_refined(cells), tmp_path) for cells in (40, 160)}
    estimated = {cells: estimate(scene_from_text(_refined(cells), "refined.toml")).memory_gb for cells in (40, 160)}
    imports = measured[40] - estimated[40]  # this machine's, over the fit's
    # measured 0.996 (1.090 without the correction; before the multigrid cycle above 4,000 free dofs
    # 0.989 to 1.023 without it, CI 1.175)
    assert 0.85 < (measured[160] - imports) / estimated[160] < 1.15, (measured, estimated)
    growth = (measured[160] - measured[40]) / (estimated[160] - estimated[40])
    assert 0.75 < growth < 1.15, (measured, estimated)  # measured 0.987 (before the multigrid cycle 0.984; CI 0.86)


def test_a_scene_beyond_the_memory_limit_is_refused_before_allocating(tmp_path):
    (tmp_path / "scene.toml").write_text(DAMBREAK.replace("cells = [40, 40]", "cells = [20000, 20000]"))
    start = time.monotonic()
    status, out, err = fempm("check", tmp_path / "scene.toml")
    # 1.19e3 GB (2.4e3 GB while one rank's exact solve factored S at any size)
    assert status == 2 and re.search(r"domain.cells = \[20000, 20000\]: the run would need about 1.\d+e\+03 GB of "
                                     r"memory", one_line(err))
    assert time.monotonic() - start < 120  # refused from arithmetic (on main it grew past 8.6 GB in ~35 s)


# -- output folders -------------------------------------------------------------------------------------------------
def test_overwrite_replaces_the_earlier_runs_files_and_nothing_else(tmp_path):
    from fempm import cli

    scene, out = tmp_path / "scene.toml", tmp_path / "out"
    scene.write_text(_short())
    assert _in_process(cli.main, ["run", str(scene), "--out", str(out), "--quiet"], status=0) == ""
    longer = sorted(p.name for p in out.iterdir())
    (out / "notes.txt").write_text("mine")
    err = _in_process(cli.main, ["run", str(scene), "--out", str(out), "--quiet", "--end-time", "0.01"], status=2)
    assert "holds the checkpoint of an earlier run" in one_line(err)
    (out / "checkpoint.npz").unlink()
    err = _in_process(cli.main, ["run", str(scene), "--out", str(out), "--quiet", "--end-time", "0.01"], status=2)
    assert re.search(r"holds the outputs of an earlier run \(front.csv, gauges.csv, gauges.png, ...; no checkpoint to "
                     r"continue from\): start afresh with --overwrite", one_line(err))
    _in_process(cli.main, ["run", str(scene), "--out", str(out), "--quiet", "--end-time", "0.01", "--overwrite"],
                status=0)
    shorter = sorted(p.name for p in out.iterdir())
    assert "notes.txt" in shorter and (out / "notes.txt").read_text() == "mine"
    assert len([n for n in longer if n.startswith("particles_")]) == 5  # t = 0, 0.005, ..., 0.02
    assert [n for n in shorter if n.startswith("particles_")] == ["particles_000000.vtp", "particles_000001.vtp",
                                                                  "particles_000002.vtp"]
    assert "snapshot_t0.010.png" in shorter and not [n for n in shorter if n.startswith(".")]


# -- faults -------------------------------------------------------------------------------------------------------
def _tmpfs(path: Path, size: str) -> bool:
    path.mkdir()
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True).returncode == 0


def _hidden(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("size, fails_at", [("200k", "mid-run"), ("900k", "at the end")])
def test_a_full_disk_stops_the_run_naming_the_file(tmp_path, size, fails_at):
    """A small tmpfs (mounting needs root; a file-size limit instead stops MPI's start): exit status
    1, one line naming the file, a summary, no temporary file; at the end grid.bp is refused before
    ADIOS2 would abort the process (on main: an OSError traceback mid-run; exit 134 and a hidden
    folder at the end)."""
    disk = tmp_path / "disk"
    if not _tmpfs(disk, size):  # a full disk needs a file system of its own; CI runs as root and mounts it
        pytest.skip("needs a small file system (mount -t tmpfs; this process may not mount)")
    try:
        (tmp_path / "scene.toml").write_text(_short())
        out = disk / "out"
        status, _, err = fempm("run", tmp_path / "scene.toml", "--out", out, "--quiet")
        message = one_line(err)
        assert status == 1, err
        if fails_at == "mid-run":
            assert re.search(r"cannot write .*out/[\w.]+"  # whichever output the disk ran out on
                             r": (the file came out incomplete \(is the disk full\?\)|No space left on device|File too "
                             r"large); the outputs up to then are in", message), message
        else:
            assert re.search(r"cannot write .*out/grid.bp: it needs about [\d.]+ MB and the disk has [\d.]+ MB free",
                             message), message
        assert not _hidden(out)
        summary = json.loads((out / "summary.json").read_text())
        assert summary["status"] == "stopped" and summary["cause"] in message
    finally:
        subprocess.run(["umount", str(disk)], check=True)


def test_an_output_folder_that_cannot_be_made_is_bad_input(tmp_path):
    (tmp_path / "a_file").write_text("")
    status, _, err = fempm("check", ROOT / "scenes" / "dambreak.toml", cwd=tmp_path)  # results/ can be made here
    assert status == 0, err
    for folder, message in ((tmp_path / "a_file" / "out", r"output.folder = '.*a_file/out': cannot be made: '.*a_file' "
                                                          r"is a file"),
                            ("/proc/fempm/out", r"cannot create output folder '/proc/fempm/out': No such file")):
        status, _, err = fempm("run", ROOT / "scenes" / "dambreak.toml", "--out", folder, "--quiet")
        assert status == 2 and re.search(message, one_line(err)), err


def test_a_signal_inside_llvmlite_is_taken_again_once_out_of_it():
    """A stop signal while numba compiles can land in llvmlite's Python callback, whose C caller drops any
    exception (the run then went on to its end with status 0, as this file's start-up test sometimes found).
    There the handler raises nothing and sends the signal again; outside, it raises."""
    from fempm import cli

    namespace = {}
    exec(compile("import sys\ndef callback():\n    return sys._getframe()", f"{os.sep}x{os.sep}llvmlite{os.sep}"
                 f"binding{os.sep}executionengine.py", "exec"), namespace)
    inside = namespace["callback"]()
    received = []
    previous = signal.signal(signal.SIGUSR1, lambda signum, frame: received.append(signum))
    try:
        assert cli._interrupt(signal.SIGUSR1, inside) is None
        deadline = time.monotonic() + 5.0
        while not received and time.monotonic() < deadline:
            time.sleep(0.005)
        assert received == [signal.SIGUSR1]  # sent again, 10 ms later
        with pytest.raises(cli.Interrupted):
            cli._interrupt(signal.SIGUSR1, sys._getframe())
    finally:
        signal.signal(signal.SIGUSR1, previous)


@pytest.mark.parametrize("delay", [0.5, 2.0, 4.0])
def test_sigint_during_start_up_is_a_clean_stop(tmp_path, delay):
    """At 0.5 s fempm is still being imported, later it is checking the scene or compiling the forms
    (or, on a fast machine, already stepping): always status 130, one line, no traceback. The run is
    made long enough (20 s of flow) to be still going at the latest signal on any machine: on a fast
    one the scene's own 1 s can end before it."""
    process = subprocess.Popen([FEMPM, "run", ROOT / "scenes" / "dambreak.toml", "--out", tmp_path / "out", "--quiet",
                                "--end-time", "20"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, "OMP_NUM_THREADS": "1"})
    time.sleep(delay)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=300)
    assert process.returncode == 130, err
    assert re.search(r"fempm: interrupted by SIGINT", one_line(err))
    if (tmp_path / "out").exists():
        assert not _hidden(tmp_path / "out")


def test_a_fast_body_without_gravity_is_not_stopped_by_a_limit_made_for_water_at_rest(tmp_path):
    """On main the default limit was 20 rho g H of water under Earth's gravity whatever the scene:
    a body at 100 m/s without gravity stopped at step 1 with "pressure oscillation" (-1.8e7 Pa).
    At 0.7 cells per step (dt 1e-4 s): at 7 (dt 1e-3 s) the scheme's energy error of the big step
    (a rise of 14 % of the start) is an eruption the energy check rightly stops."""
    from fempm import cli

    text = (_short(end=0.003).replace("gravity = [0.0, -9.81]", "gravity = [0.0, 0.0]")
            .replace("particles_per_cell = 4 ", "particles_per_cell = 4\nvelocity = [100.0, 0.0]\n", 1)
            .replace("upper = [0.146, 0.292]", "upper = [0.146, 0.146]").replace("dt = 1.0e-3 ", "dt = 1.0e-4 "))
    (tmp_path / "scene.toml").write_text(text)
    _in_process(cli.main, ["run", str(tmp_path / "scene.toml"), "--out", str(tmp_path / "out"), "--quiet"], status=0)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["steps"] == 30  # the lowest pressure: -1.3e8 Pa
    assert np.isfinite(summary["pressure_min_Pa"])
