"""The lid-driven cavity at Re = 100 (demos/cavity.py) against Ghia, Ghia & Shin (1982).

Each run starts from rest and ends at the demo's steady end time (15 L/U); its error is that of
the mean centre-line profile over the last 5 L/U, as in the demo: max |computed - Ghia| / U
over Ghia's points, for u(0.5, y) and v(x, 0.5) separately. Coarse grids keep the file short.
"""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI

sys.path.insert(0, str(Path(__file__).parents[1] / "demos"))
import cavity  # noqa: E402


@pytest.mark.parametrize("basis, cells", [("bspline", 16), ("q1", 32)])
def test_fem_only_centre_lines_are_within_two_percent_of_ghia(basis, cells):
    """Measured: B-spline, 16 cells: 0.53 % (u), 0.80 % (v); Q1, 32 cells: 0.70 %, 0.58 %."""
    m = cavity.run_case("FEM-only", basis, cells, cavity.FEM_DT).measurement
    print(f"FEM-only {basis} {cells}: error u {100 * m.extra['error_u']:.2f} %, v {100 * m.extra['error_v']:.2f} %")
    assert m.status == "completed"
    assert m.extra["unsteadiness"] < 1e-4  # steady: the centre lines changed by less than 1e-4 U in the last L/U
    assert m.extra["error_u"] <= 0.02
    assert m.extra["error_v"] <= 0.02


def test_mpm_centre_lines_are_within_five_percent_of_ghia_and_the_particles_stay_spread():
    """B-spline, 24 cells, 2 x 2 particles per cell, U dt / h = 0.5. Measured: 2.7 % (u), 1.2 % (v);
    1 to 8 particles per cell (4 seeded), no empty cell, corners' 2 x 2 cells filled to 0.88-1.0."""
    m = cavity.run_case("MPM", "bspline", 24, cavity.courant_step(24), per_cell=2).measurement
    e = m.extra
    print(f"MPM 24: error u {100 * e['error_u']:.2f} %, v {100 * e['error_v']:.2f} %; particles per cell "
          f"{e['particles_per_cell_min']}..{e['particles_per_cell_max']}, empty {e['empty_cell_fraction']:.4f}, "
          f"corners {e['corner_fill']}")
    assert m.status == "completed"
    assert e["error_u"] <= 0.05
    assert e["error_v"] <= 0.05
    assert e["particles_per_cell_max"] <= 3 * e["particles_per_cell_seeded"]  # no pile-up
    assert e["empty_cell_fraction"] <= 0.01  # no holes
    assert all(0.5 <= fill <= 1.5 for fill in e["corner_fill"])  # corners neither crowded nor emptied


@pytest.mark.mpi
def test_the_demo_writes_its_files_on_any_number_of_ranks(tmp_path):
    comm = MPI.COMM_WORLD
    out = Path(comm.bcast(str(tmp_path), root=0)) / "cavity"
    status = cavity.main(["--cells", "8", "--end-time", "1", "--window", "0.5", "--quiet", "--out", str(out)])
    assert status == 0
    if comm.rank == 0:
        for name in ("centrelines.png", "errors.csv", "centrelines.csv", "history.csv", "summary.json"):
            assert (out / name).stat().st_size > 0, name
        assert not list(out.glob(".*tmp*"))
        runs = json.loads((out / "summary.json").read_text())["runs"]
        assert [r["method"] for r in runs] == ["FEM-only", "MPM"]
        assert all(r["status"] == "completed" and 0 < r["error"] < 1 for r in runs)
        errors = np.genfromtxt(out / "errors.csv", delimiter=",", skip_header=1, names=True, dtype=None)
        np.testing.assert_allclose(errors["error_u"], [r["extra"]["error_u"] for r in runs])


@pytest.mark.parametrize("flags, message", [
    (["--cells", "2"], "--cells must be at least 4"),
    (["--ppc", "0"], "--ppc must be at least 1"),
    (["--dt", "-0.1"], "--dt must be positive"),
    (["--end-time", "4", "--window", "5"], "--window (5) must not exceed --end-time (4)"),
    (["--pic", "1.5"], "--pic must be in [0, 1]"),
    (["--basis", "p2"], "invalid choice: 'p2'"),
])
def test_bad_flags_are_refused_with_a_message(flags, message, capsys):
    with pytest.raises(SystemExit) as stop:
        cavity.parse_arguments(flags)
    assert stop.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.full
def test_the_short_study_converges_in_space():
    """The study's short version (3 grids, ~3 min): MPM B-spline errors fall with the grid, and
    the FEM-only B-spline runs converge towards the finest one (rate above 2)."""
    rows = cavity.study(full=False)
    grid = {(m.method, m.basis, m.cells): m for m in rows if "grid" in m.extra["series"]}
    assert all(m.status == "completed" for m in rows)
    mpm = [grid[("MPM", "B-spline", n)].error for n in (16, 24, 32)]
    assert mpm[0] > mpm[1] > mpm[2]
    assert grid[("FEM-only", "B-spline", 24)].extra["rate_vs_finest_fem"] > 2
