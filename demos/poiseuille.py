"""Plane Poiseuille flow: a body force drives a viscous fluid between two walls at rest.

Verification case of the implicit MPM against the analytic solution and against the same
forms solved by ordinary finite elements (FEM-only, ``fempm.eulerian``).

Set-up: walls at y = 0 and y = H (no-slip), H = 1, kinematic viscosity nu = 1,
density 1, body force g = 1 along x, fluid at rest at t = 0. Strong form::

    du/dt = nu d2u/dy2 + g,   u(0, t) = u(H, t) = 0,   u(y, 0) = 0.

Solution: the steady parabola less the decaying odd sine modes::

    u(y, t) = g y (H - y) / (2 nu)
              - sum_{k odd} 4 g H^2 / (nu pi^3 k^3) sin(k pi y / H) exp(-k^2 pi^2 nu t / H^2)

The channel is infinite; the grid is a section H/2 long whose ends are ``outflow`` sides
(u_y = 0, zero normal traction: what the fully developed flow satisfies), and particles
leaving one end re-enter through the other (``fempm.verification.channel``). The error is
the max over the vertical centre line of ``|u - u_exact| / u_max`` with
``u_max = g H^2 / (8 nu)``, taken at t = 0.1 H^2/nu (transient) and at t = 1.5 H^2/nu
(steady: the slowest mode has decayed to 4e-7).

Run (``mpirun -n 2`` works the same)::

    python demos/poiseuille.py [--cells 16] [--ppc 2] [--basis bspline|q1] [--out results/poiseuille]

It writes ``profile.png`` (MPM and FEM-only profiles on the analytic ones) and
``errors.json``. :func:`study` gives the convergence runs of ``benchmarks/report.py``.
"""

# %% imports
from __future__ import annotations

import sys

import numpy as np

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm.bases import BASES
from fempm.verification import METHODS, Measurement, channel, profile_demo, profile_errors

H, NU, G = 1.0, 1.0, 1.0
U_MAX = G * H**2 / (8 * NU)
TRANSIENT, STEADY = 0.1 * H**2 / NU, 1.5 * H**2 / NU
Y = np.linspace(0.0, H, 41)  # where the profile is compared


# %% the analytic solution
def exact(y: np.ndarray, t: float, modes: int = 200) -> np.ndarray:
    """u(y, t) of the start-up flow (the series above, ``modes`` odd terms)."""
    k = 2 * np.arange(modes)[:, None] + 1
    decay = 4 * G * H**2 / (NU * np.pi**3 * k**3) * np.sin(k * np.pi * y / H) * np.exp(-(k * np.pi) ** 2 * NU * t / H**2)
    return G * y * (H - y) / (2 * NU) - decay.sum(axis=0)


# %% one run
def solve(method: str, basis: str, cells: int, dt: float, ppc: int = 2, times=(TRANSIENT, STEADY),
          pic_blend: float = 0.01) -> list[Measurement]:
    """Run the start-up flow to each of ``times``; the profile error there, relative to u_max."""
    solver = channel(method, basis, cells, dt, ppc, height=H, viscosity=NU, body_force=G, pic_blend=pic_blend)
    return profile_errors("poiseuille", solver, times, Y, exact, U_MAX, basis, cells, ppc)


# %% convergence and cost
def study(full: bool = False) -> list[Measurement]:
    """Error and wall time against grid size (both methods, both bases), particles per cell, time step
    and the MPM's PIC share (steady runs at dt = 0.01 H^2/nu; time steps at t = 0.1 H^2/nu)."""
    grids = (8, 16, 32, 64) if full else (8, 16, 32)
    rows = [r for m in METHODS for b in BASES for n in grids for r in solve(m, b, n, 0.01, times=(STEADY,))]
    rows += [r for ppc in (1, 2, 3, 4) for r in solve("MPM", "bspline", 16, 0.01, ppc, times=(STEADY,))]
    steps = (0.01, 0.005, 0.0025, 0.00125) if full else (0.01, 0.005, 0.0025)
    rows += [r for m in METHODS for dt in steps for r in solve(m, "bspline", 16, dt, times=(TRANSIENT,))]
    rows += [r for pic in (0.0, 0.1) for dt in (0.01, 0.001) for r in solve("MPM", "bspline", 16, dt, times=(STEADY,),
                                                                          pic_blend=pic)]
    return rows


# %% main
def main(argv=None) -> int:
    """Run both methods on one grid, print their errors, plot their profiles."""
    return profile_demo(argv, "Plane Poiseuille flow", solve, exact, Y, (TRANSIENT, STEADY), "results/poiseuille",
                        "u / (g H^2 / nu)")


if __name__ == "__main__":
    sys.exit(main())
