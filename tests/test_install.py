"""A wheel of fempm, installed (not editable) into a fresh environment, runs the shipped scene.

The wheel is built from a copy of the files the package is made of, installed without
dependencies into a new venv that sees the project environment's packages (DOLFINx,
PETSc, ...) through a ``.pth`` file, and ``fempm run`` takes a few steps of
``scenes/dambreak.toml`` from a folder outside the repository: the shipped forms and
reference data must come from the installed package.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "fempm_command.py", "fempm", "forms", "data")


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own processes")
def test_a_wheel_in_a_fresh_environment_runs_the_shipped_scene(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    for name in SOURCES:
        copy = shutil.copytree if (ROOT / name).is_dir() else shutil.copy2
        copy(ROOT / name, source / name, **({"ignore": shutil.ignore_patterns("__pycache__")}
                                            if (ROOT / name).is_dir() else {}))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", str(source), "--no-deps", "--no-build-isolation", "-w", str(tmp_path / "wheel")],
                   check=True, capture_output=True, cwd=tmp_path)
    wheel = next((tmp_path / "wheel").glob("fempm-*.whl"))
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    # the project environment's packages, behind the new environment's own (where the wheel goes)
    Path(site, "project.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([*pip, "--python", str(python), "install", "--no-deps", str(wheel)], check=True,
                   capture_output=True)
    away = tmp_path / "elsewhere"
    away.mkdir()
    # the MPI library of the PyPI mpich wheel lives in the project environment's lib/
    env = {**os.environ, "OMP_NUM_THREADS": "1",
           "LD_LIBRARY_PATH": os.pathsep.join([str(Path(sys.prefix) / "lib"), os.environ.get("LD_LIBRARY_PATH", "")])}
    where = subprocess.run([python, "-c", "import fempm.formsfile as f, fempm.references as r; "
                            "print(f.FORMS_DIR); print(r.REFERENCE_DIR); print(r.interfoam_front(160).shape)"],
                           check=True, capture_output=True, text=True, cwd=away, env=env).stdout.split()
    assert all(Path(p).is_relative_to(venv) for p in where[:2]), where  # the installed copies, not the repository's
    run = subprocess.run([venv / "bin" / "fempm", "run", str(ROOT / "scenes" / "dambreak.toml"), "--out", "out",
                          "--end-time", "0.003", "--quiet"], capture_output=True, text=True, cwd=away, env=env)
    assert run.returncode == 0, run.stderr
    summary = json.loads((away / "out" / "summary.json").read_text())
    # the scene's adaptive step: from rest the first step may take the whole 3 ms
    assert summary["status"] == "completed" and summary["steps"] == 1 and summary["particles"] == 800
