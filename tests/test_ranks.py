"""The dam break on 1, 2 and 4 ranks (4 oversubscribed on a 2-core machine): the same front.

Each run is a separate ``mpirun -n N fempm run`` of the shipped scene cut to its first
100 steps, writing only its histories; the front histories must agree to 1e-10 m.
"""

import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

from fempm.cases import dambreak
from fempm.scene import Output, load_scene, to_toml

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns its own mpirun")
def test_front_history_is_the_same_on_1_2_and_4_ranks(tmp_path):
    mpirun = str(Path(sys.executable).parent / "mpirun")
    fronts = {}
    for ranks in (1, 2, 4):
        folder = tmp_path / f"ranks{ranks}"
        scene = load_scene(SCENE, end_time=0.1)
        scene = dambreak.at_seed_setup(scene)  # the seed's step: the times then match exactly, whatever the ranks
        scene_file = tmp_path / f"scene{ranks}.toml"
        scene_file.write_text(to_toml(replace(scene, output=Output(folder=str(folder), progress=False))))
        run = subprocess.run([mpirun, "-n", str(ranks), sys.executable, "-m", "fempm.cli", "run", str(scene_file)],
                             capture_output=True, text=True, timeout=900, env={**os.environ, "OMP_NUM_THREADS": "1"})
        assert run.returncode == 0, run.stderr[-3000:]
        assert sorted(p.name for p in folder.iterdir()) == ["front.csv", "gauges.csv", "gauges.png", "summary.json",
                                                                 "volume.csv"]
        fronts[ranks] = np.loadtxt(folder / "front.csv", delimiter=",", skiprows=2)
    assert fronts[1].shape == (101, 2) and fronts[1][-1, 1] - fronts[1][0, 1] > 0.02  # the front ran
    for ranks in (2, 4):
        assert np.array_equal(fronts[ranks][:, 0], fronts[1][:, 0])
        assert np.abs(fronts[ranks][:, 1] - fronts[1][:, 1]).max() <= 1e-10
