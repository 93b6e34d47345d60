"""A tank of water at rest: the pressure must be hydrostatic, ``p = rho g (H - y)``.

The dam-break column with its gate closed: water H = 292 mm deep and W = 146 mm wide,
rho = 1000 kg/m^3, mu = 1e-3 Pa s, slip walls, at rest from ``p = 0``. The MPM tank is 2H
high and the water's top a free surface; the FEM-only domain is the water itself with its top
``open`` (traction free). The error is the max over the vertical centre line, from the floor
to one cell below the surface, of ``|p - rho g (H - y)| / (rho g H)`` after :data:`END`.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

from fempm import output
from fempm.bases import BASES
from fempm.grid import Grid
from fempm.options import Physics, Scheme
from fempm.particles import Rectangle
from fempm.verification import Measurement, advance, filled_solver, sample

__all__ = ["END", "G", "H", "MU", "RHO", "W", "depths", "plot", "solve", "tank"]

RHO, MU, G = 1000.0, 1.0e-3, 9.81
W, H = 0.146, 0.292
END = 0.2  #: s held at rest before the pressure is compared


def tank(method: str, basis: str, cells: int, dt: float, ppc: int = 2, comm=MPI.COMM_WORLD):
    """The solver: ``cells`` across the depth H; MPM in a tank 2H high, FEM-only on the water alone."""
    top = 2 * H if method == "MPM" else H
    grid = Grid.from_cells(comm, (0.0, 0.0), (W, top), (max(cells // 2, 2), cells * round(top / H)))
    walls = {"left": "slip", "right": "slip", "bottom": "slip", "top": "slip" if method == "MPM" else "open"}
    physics = Physics(viscosity=MU, gravity=(0.0, -G), walls=walls)
    return filled_solver(method, BASES[basis](grid), physics, Scheme(dt=dt), density=RHO, per_cell=ppc,
                         body=Rectangle((0.0, 0.0), (W, H)))


def depths(cells: int) -> np.ndarray:
    """Heights of the centre line where the pressure is compared: the floor to a cell below the surface."""
    return np.linspace(0.0, H - H / cells, 4 * cells)


def solve(method: str, basis: str, cells: int, dt: float, ppc: int = 2) -> Measurement:
    """Hold the water at rest for :data:`END`; the pressure error along the centre line.

    ``extra``: the bottom pressure's relative error, the sampled ``y`` and ``pressure``, and for
    the MPM the largest particle speed (m/s).
    """
    solver = tank(method, basis, cells, dt, ppc)
    run = advance(solver, END)
    y = depths(cells)
    p = sample(solver.pressure, np.column_stack([np.full_like(y, W / 2), y]))[:, 0]
    exact = RHO * G * (H - y)
    error = float(np.abs(p - exact).max() / (RHO * G * H)) if run.status == "completed" else None
    extra = {"bottom_error": float(p[0] / (RHO * G * H) - 1), "y": y.tolist(), "pressure": p.tolist(),
             "pic_blend": solver.scheme.pic_blend}
    if method == "MPM":
        speed = np.linalg.norm(solver.particles["velocity"], axis=1).max(initial=0.0)
        extra["max_speed"] = float(solver.grid.comm.allreduce(speed, op=MPI.MAX))
    return Measurement("hydrostatic", method, BASES[basis].name, cells, dt, ppc**2 if method == "MPM" else 0, error,
                       run.wall, run.status, run.cause, extra)


def plot(path, rows: list[Measurement]):
    """Pressure against depth of each run, on ``rho g d``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4))
    d = np.linspace(0.0, H, 2)
    ax.plot(RHO * G * d / 1e3, d, "k-", lw=1, label="rho g d")
    for r, (marker, size) in zip(rows, (("o", 6), ("x", 4))):
        ax.plot(np.asarray(r.extra["pressure"]) / 1e3, H - np.asarray(r.extra["y"]), marker, ms=size, mfc="none",
                label=f"{r.method} ({r.basis}, H/h = {r.cells})")
    ax.invert_yaxis()
    ax.set(xlabel="p, kPa", ylabel="depth d, m", title="Hydrostatic tank")
    ax.legend(fontsize=8)
    output.save_figure(fig, path, dpi=120, bbox_inches="tight")
