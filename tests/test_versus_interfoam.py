"""The interFoam side of ``benchmarks/versus_interfoam.py``: the case reproduces the stored
reference front, and the script's quick mode runs end to end (both need OpenFOAM's interFoam;
skipped without it). The measure's arithmetic is checked without OpenFOAM."""

import sys
from pathlib import Path

import numpy as np
import pytest

from fempm.references import dimensionless_front, front_difference, interfoam_front

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import interfoam  # noqa: E402
import versus_interfoam  # noqa: E402

MISSING = interfoam.ensure_openfoam(install=False)
needs_interfoam = pytest.mark.skipif(MISSING is not None, reason=f"needs OpenFOAM's interFoam: {MISSING}")


def test_front_of_rows_is_linear_between_cell_centres():
    cells = 8
    h = interfoam.TANK / cells
    alpha = np.array([[1, 1, 0.8, 0.2, 0, 0, 0, 0],     # 0.5 halfway between centres 2 and 3
                      [0, 0, 0, 0, 0, 0, 0, 0],         # dry: 0
                      [1, 1, 1, 1, 1, 1, 1, 0.7],       # last cell wet: the tank width
                      [1, 0.1, 0, 0, 0, 0.9, 0.6, 0]])  # the largest x counts (a detached wet patch)
    front = interfoam.front_of_rows(alpha)
    assert front == pytest.approx([3 * h, 0.0, interfoam.TANK, 6.5 * h + 0.1 / 0.6 * h], rel=1e-12)


def test_wall_at_error_interpolates_log_log():
    rows = [versus_interfoam.Row("x", c, None, 1, w, w, None, None, error=e) for c, w, e in ((40, 1.0, 0.04),
                                                                                          (80, 10.0, 0.01))]
    wall, mark = versus_interfoam.wall_at_error(rows, 0.02)
    assert wall == pytest.approx(10**0.5, rel=1e-12) and mark == ""
    wall, mark = versus_interfoam.wall_at_error(rows, 0.005)  # beyond the finest run: extrapolated
    assert wall == pytest.approx(10**1.5, rel=1e-12) and mark == "*"
    assert versus_interfoam.wall_at_error(rows, 0.05) == (1.0, "≤")  # every run within it: the cheapest's time
    assert versus_interfoam.wall_at_error(rows[:1], 0.02) == (None, "")


@needs_interfoam
def test_interfoam_40_reproduces_the_stored_front():
    """40² to 0.27 s against the stored 40² run (to 2 s: the step, adjusted to hit the end time,
    differs slightly), and against the 160² reference as the reference's README states."""
    run = interfoam.run(40, 0.27)
    front = dimensionless_front(*run.front_t_x.T)
    assert front_difference(front, interfoam_front(40)) < 1e-3  # measured 5.4e-4
    assert 0.019 < front_difference(front, interfoam_front(160)) < 0.022  # measured 0.0205
    assert abs(run.volume_drift_max) < 2e-7  # measured 9.6e-8
    assert run.steps == 53  # measured 53 (the run is deterministic)


@needs_interfoam
def test_quick_mode_runs_end_to_end(tmp_path):
    page = tmp_path / "speed.md"
    assert versus_interfoam.main(["--quick", "--doc", str(page)]) == 0
    text = page.read_text()
    assert "| interFoam | 40² | — | 53 |" in text and "| 2.05 % |" in text  # measured 2.05 %
    assert "| fempm | 40² | 4 | 46 |" in text  # the shipped scene: 2 x 2 particles per cell, 46 steps to 0.27 s
    # (45 with tau's T = max(dt, ...))
    assert (tmp_path / "speed" / "error_vs_time.png").stat().st_size > 10_000


def _cell_field(path: Path, components: int) -> np.ndarray:
    """An OpenFOAM ASCII field's ``internalField nonuniform`` values, ``(cells, components)``."""
    text = path.read_text()
    start = text.index("internalField")
    count_at = text.index("(", start)
    count = int(text[start:count_at].split()[-1])
    body = text[count_at + 1:text.index("\n)", count_at)]
    numbers = np.array(body.replace("(", " ").replace(")", " ").split(), dtype=float)
    return numbers.reshape(count, components)


@needs_interfoam
def test_the_water_speed_is_the_alpha_weighted_mean_of_the_written_fields(tmp_path):
    """interfoam.read_water_speed's last sample against the same average computed from the fields interFoam
    writes at the end time (equal cells: ``sum alpha |U| / sum alpha``)."""
    run = interfoam.run(40, 0.3, folder=tmp_path / "case", water_speed=True)
    t, speed = run.water_speed[-1]
    assert t == pytest.approx(0.3, abs=1e-9)
    alpha = _cell_field(tmp_path / "case" / "0.3" / "alpha.water", 1)[:, 0]
    velocity = _cell_field(tmp_path / "case" / "0.3" / "U", 3)
    expected = np.sum(alpha * np.linalg.norm(velocity, axis=1)) / np.sum(alpha)
    assert speed == pytest.approx(expected, rel=1e-6)  # the fields are written to 8 digits
    assert len(run.water_speed) == run.steps and np.all(np.diff(run.water_speed[:, 0]) > 0)
