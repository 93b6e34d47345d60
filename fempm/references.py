"""Reference data of the verification cases, and the dam break's front measure.

The files live in the repository's ``data/reference`` (see its README), installed with the
package as ``fempm.data``. Dam-break fronts
are handled in the dimensionless form of Koshizuka & Oka (1996), ``T = t sqrt(2 g / L)``
and ``Z = x / L`` with ``L`` the column's width.

The accuracy measure of the dam break is :func:`front_difference`: the RMS relative
difference of a front history from a reference history at the reference's own sample
times in ``T_min < T <= T_max``; against the interFoam 160 x 160 run the window is
``0.3 <= T <= 3`` (the front starts to move, and reaches the far wall at T ~ 3.1).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

__all__ = ["DAMBREAK_COLUMN_WIDTH", "REFERENCE_DIR", "dambreak_front", "dimensionless_front", "front_difference",
           "interfoam_front", "interfoam_probes"]


def _reference_dir() -> Path:
    """``data/reference`` of the repository, installed as ``fempm.data``; from a source tree beside ``fempm/``."""
    spec = importlib.util.find_spec("fempm.data")
    if spec is not None and spec.submodule_search_locations:
        return Path(list(spec.submodule_search_locations)[0]).resolve() / "reference"
    return Path(__file__).resolve().parents[1] / "data" / "reference"


REFERENCE_DIR = _reference_dir()
DAMBREAK_COLUMN_WIDTH = 0.146  #: L of the seed's dam break (Koshizuka & Oka 1996), m
GRAVITY = 9.81


def _table(path: Path) -> np.ndarray:
    """The numbers of a reference CSV: lines starting with ``#`` and the header line skipped."""
    with open(path) as f:
        lines = [line for line in f if line.strip() and not line.startswith("#")]
    return np.loadtxt(lines[1:], delimiter=",", ndmin=2)


def dambreak_front(name: str) -> np.ndarray:
    """A published front history ``(T, Z)``, e.g. ``"koshizuka_oka_1996_experiment"``."""
    return _table(REFERENCE_DIR / "dambreak" / f"{name}.csv")


def dimensionless_front(t: np.ndarray, x: np.ndarray, width: float = DAMBREAK_COLUMN_WIDTH,
                        gravity: float = GRAVITY, origin: float = 0.0) -> np.ndarray:
    """``(T, Z) = (t sqrt(2 g / L), (x - origin) / L)`` of a front history ``x(t)``."""
    t, x = np.asarray(t, dtype=float), np.asarray(x, dtype=float)
    return np.column_stack([t * np.sqrt(2 * gravity / width), (x - origin) / width])


def interfoam_front(cells: int = 160) -> np.ndarray:
    """The interFoam front ``(T, Z)`` of the seed's tank at ``cells`` x ``cells`` (40, 80 or 160)."""
    table = _table(REFERENCE_DIR / "dambreak" / f"interfoam_{cells}x{cells}_front.csv")
    return dimensionless_front(table[:, 0], table[:, 1])


def interfoam_probes(cells: int = 160) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The interFoam wall-pressure probes: times (s) and pressure (Pa) by probe name.

    Names as the file's columns, e.g. ``right_y0.005`` (a point 0.1 mm inside the right
    wall, 5 mm above the floor); pressure relative to the air (see the file's first line).
    """
    path = REFERENCE_DIR / "dambreak" / f"interfoam_{cells}x{cells}_probes.csv"
    with open(path) as f:
        header = next(line for line in f if not line.startswith("#")).strip().split(",")
    table = _table(path)
    return table[:, 0], {name: table[:, k] for k, name in enumerate(header) if k > 0}


def front_difference(front: np.ndarray, reference: np.ndarray, T_min: float = 0.3, T_max: float = 3.0) -> float:
    """RMS relative difference of a front history from a reference, both ``(T, Z)``.

    The history is interpolated linearly at the reference's times in
    ``T_min < T <= T_max``; reference times beyond the history's end are left out.

    Raises:
        ValueError: no reference time lies in the window and within the history.
    """
    T_ref, Z_ref = reference[:, 0], reference[:, 1]
    use = (T_ref > T_min) & (T_ref <= T_max) & (T_ref <= front[-1, 0])
    if not np.any(use):
        raise ValueError(f"the front history (to T = {front[-1, 0]:.3g}) reaches no reference time in "
                         f"[{T_min}, {T_max}]")
    Z = np.interp(T_ref[use], front[:, 0], front[:, 1])
    return float(np.sqrt(np.mean(((Z - Z_ref[use]) / Z_ref[use]) ** 2)))
