"""Plane channel flows started from rest: Poiseuille (a body force) and Couette (a sliding wall).

Walls at y = 0 and y = H, no-slip, H = 1, kinematic viscosity nu = 1, density 1, fluid at
rest at t = 0. The channel is infinite: :func:`channel` builds a section of it whose ends are
``outflow`` sides, with particles recycled through them. Each flow's series solution is
:meth:`Flow.exact`; the error is the max over the vertical centre line of
``|u - u_exact| / scale`` (:func:`solve`).

* Poiseuille: body force g = 1 along x; ``u = g y (H - y) / (2 nu)`` less the decaying odd sine
  modes, ``sum_{k odd} 4 g H^2 / (nu pi^3 k^3) sin(k pi y / H) exp(-k^2 pi^2 nu t / H^2)``;
  scale ``u_max = g H^2 / (8 nu)``.
* Couette: the top wall slides at U = 1 from t = 0; ``u = U y / H`` plus
  ``sum_{k >= 1} 2 U (-1)^k / (k pi) sin(k pi y / H) exp(-k^2 pi^2 nu t / H^2)``; scale U.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from mpi4py import MPI

from fempm import output
from fempm.bases import BASES
from fempm.eulerian import EulerianSolver
from fempm.grid import Grid
from fempm.options import Physics, Scheme
from fempm.verification import METHODS, Measurement, advance, filled_solver, max_relative_error, sample

__all__ = ["COUETTE", "Flow", "H", "NU", "POISEUILLE", "Y", "channel", "plot_profiles", "section", "solve",
           "write_results"]

H, NU = 1.0, 1.0
Y = np.linspace(0.0, H, 41)  #: heights where the profile is compared


def _decay(k, t):
    return np.exp(-(k * np.pi) ** 2 * NU * t / H**2)


def _poiseuille(y: np.ndarray, t: float, modes: int = 200, g: float = 1.0) -> np.ndarray:
    k = 2 * np.arange(modes)[:, None] + 1
    decay = 4 * g * H**2 / (NU * np.pi**3 * k**3) * np.sin(k * np.pi * y / H) * _decay(k, t)
    return g * y * (H - y) / (2 * NU) - decay.sum(axis=0)


def _couette(y: np.ndarray, t: float, modes: int = 400, u: float = 1.0) -> np.ndarray:
    k = np.arange(1, modes + 1)[:, None]
    return u * y / H + (2 * u * (-1.0) ** k / (k * np.pi) * np.sin(k * np.pi * y / H) * _decay(k, t)).sum(axis=0)


@dataclass(frozen=True)
class Flow:
    """A channel flow: its forcing, the velocity scale of its error, its times (in H^2/nu), its solution.

    Attributes:
        transient: a time where the profile is far from steady.
        steady: a time where it is steady to the error measured.
        exact: ``exact(y, t)``, the series solution.
    """

    name: str
    body_force: float
    lid_speed: float
    scale: float
    transient: float
    steady: float
    exact: Callable[[np.ndarray, float], np.ndarray]


#: steady at t = 1.5 H^2/nu: the slowest mode has decayed to 4e-7
POISEUILLE = Flow("poiseuille", body_force=1.0, lid_speed=0.0, scale=H**2 / (8 * NU), transient=0.1, steady=1.5,
                  exact=_poiseuille)
#: at t = 0.1 H^2/nu the profile is still far from linear (u(H/2) = 0.30 U); steady to 5e-5 at 1
COUETTE = Flow("couette", body_force=0.0, lid_speed=1.0, scale=1.0, transient=0.1, steady=1.0, exact=_couette)


def channel(method: str, basis: str, cells: int, dt: float, per_cell: int = 2, *, height: float = H,
            density: float = 1.0, viscosity: float = NU, body_force: float = 0.0, lid_speed: float = 0.0,
            pic_blend: float = 0.01, comm: MPI.Comm = MPI.COMM_WORLD):
    """A plane channel flow along x between no-slip walls at y = 0 and y = ``height``, ``cells`` across.

    The grid is a section of the channel ``height / 2`` long whose ends are ``outflow``
    sides: ``u_y = 0`` and zero normal traction, which a flow that is fully developed
    (``u = u(y) e_x``, p constant along x) satisfies exactly, so the section stands for the
    infinite channel. MPM particles that leave through one end re-enter through the other
    (``recycle``): the material is endless too. ``body_force`` drives plane Poiseuille flow,
    ``lid_speed`` (the top wall sliding along +x) plane Couette flow; the fluid starts at rest.
    The volume correction is off (``alpha = 0``): particles in a shear flow along x keep
    their rows and neither crowd nor thin out. The MPM's transfer is FLIP with a PIC share of
    0.01 per step, not the dam break's default (affine-FLIP): blended every step, PIC smooths
    the velocity like an added viscosity of order ``pic_blend h^2 / dt`` (``benchmarks/report.py``
    measures it); the affine transfers were further from the series solution on the Couette
    start-up (README, departures). Nor does the still water's share apply (``rest_pic_rate``): the body
    force drives the flow from rest, and the fluid at rest next to the walls is the solution's own.
    """
    grid = Grid.from_cells(comm, (0.0, 0.0), (height / 2, height), (max(cells // 2, 2), cells))
    walls = {"left": "outflow", "right": "outflow", "bottom": "no-slip", "top": "no-slip"}
    physics = Physics(viscosity=density * viscosity, gravity=(body_force, 0.0), walls=walls,
                      wall_speeds={"top": lid_speed} if lid_speed else {}, recycle=method == "MPM")
    scheme = Scheme(dt=dt, alpha=0.0, transfer="flip", pic_blend=pic_blend, pic_rate=0.0, rest_pic_rate=0.0)
    return filled_solver(method, BASES[basis](grid), physics, scheme, density=density, per_cell=per_cell)


def section(solver, y: np.ndarray) -> np.ndarray:
    """The velocity ``(n, 2)`` along the vertical line through the middle of the grid, at heights ``y``."""
    grid = solver.grid
    x = np.full_like(y, 0.5 * (grid.lower[0] + grid.upper[0]))
    return sample(solver.velocity, np.column_stack([x, y]))


def solve(flow: Flow, method: str, basis: str, cells: int, dt: float, ppc: int = 2, times=None,
          pic_blend: float = 0.01) -> list[Measurement]:
    """Run ``flow`` from rest to each of ``times`` (default: its transient and steady times) and
    measure there ``max |u - exact(y, t)| / scale`` along the centre line: one row per time (its
    wall time counts from the start, its profile at :data:`Y` in ``extra["profile"]``)."""
    solver = channel(method, basis, cells, dt, ppc, body_force=flow.body_force, lid_speed=flow.lid_speed,
                     pic_blend=pic_blend)
    rows, run = [], None
    for t in times or (flow.transient, flow.steady):
        run = advance(solver, t, run=run)
        u = section(solver, Y)[:, 0]
        error = max_relative_error(u, flow.exact(Y, t), flow.scale) if run.status == "completed" else None
        rows.append(Measurement(f"{flow.name} t={t:g}", "FEM-only" if isinstance(solver, EulerianSolver) else "MPM",
                                BASES[basis].name, cells, solver.dt, ppc**2 if method == "MPM" else 0, error,
                                run.wall, run.status, run.cause,
                                {"profile": u.tolist(), "pic_blend": solver.scheme.pic_blend}))
    return rows


def plot_profiles(path, flow: Flow, rows: list[Measurement], title: str, quantity: str):
    """The measured profiles (markers, one style per method) on the series solution at their times."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    for t in sorted({float(r.case.split("t=")[1]) for r in rows}):
        ax.plot(flow.exact(Y, t), Y, "k-", lw=1)
    styles = {"MPM": ("o", 6), "FEM-only": ("x", 4)}
    for r in rows:
        marker, size = styles[r.method]
        ax.plot(r.extra["profile"], Y, marker, ms=size, mfc="none",
                label=f"{r.method}, {r.case}")
    ax.set(xlabel=quantity, ylabel="y / H", title=f"{title}\n(lines: analytic)")
    ax.legend(fontsize=7)
    output.save_figure(fig, path, dpi=120, bbox_inches="tight")


def write_results(folder, flow: Flow, rows: list[Measurement], title: str, quantity: str):
    """On rank 0: a line per row, ``errors.json`` (the rows by method) and ``profile.png`` in ``folder``."""
    if MPI.COMM_WORLD.rank != 0:
        return
    for r in rows:
        print(f"{r.method:8s} {r.case:18s} error {'-' if r.error is None else f'{r.error:.2e}'}  ({r.wall:.1f} s)")
    output.write_json(folder / "errors.json", {m: [r.as_dict() for r in rows if r.method == m] for m in METHODS})
    plot_profiles(folder / "profile.png", flow, rows, title, quantity)
