"""Plane Couette flow started impulsively: the top wall slides, the fluid follows by viscosity.

Verification case of the implicit MPM against the series solution and against the same
forms solved by ordinary finite elements (FEM-only, ``fempm.eulerian``).

Set-up: walls at y = 0 (at rest) and y = H (sliding at U along x from t = 0), both
no-slip, H = 1, U = 1, kinematic viscosity nu = 1, density 1, no body force, fluid at rest
at t = 0. Strong form::

    du/dt = nu d2u/dy2,   u(0, t) = 0,   u(H, t) = U,   u(y, 0) = 0.

Solution: the linear profile less the decaying sine modes of its start-up::

    u(y, t) = U y / H + sum_{k >= 1} 2 U (-1)^k / (k pi) sin(k pi y / H) exp(-k^2 pi^2 nu t / H^2)

The channel is infinite: a section H/2 long with ``outflow`` ends and particles recycled
through them (``fempm.verification.channel``). The error is the max over the vertical
centre line of ``|u - u_exact| / U`` at t = 0.1 H^2/nu, where the profile is still far
from linear (u(H/2) = 0.30 U), and at t = 1 H^2/nu (steady to 5e-5).

Run (``mpirun -n 2`` works the same)::

    python demos/couette.py [--cells 16] [--ppc 2] [--dt 0.001] [--basis bspline|q1] [--out results/couette]

It writes ``profile.png`` and ``errors.json``; :func:`study` gives the convergence runs of
``benchmarks/report.py``.
"""

# %% imports
from __future__ import annotations

import sys

import numpy as np

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm.bases import BASES
from fempm.verification import METHODS, Measurement, channel, profile_demo, profile_errors

H, NU, U = 1.0, 1.0, 1.0
TRANSIENT, STEADY = 0.1 * H**2 / NU, 1.0 * H**2 / NU
Y = np.linspace(0.0, H, 41)  # where the profile is compared


# %% the series solution
def exact(y: np.ndarray, t: float, modes: int = 400) -> np.ndarray:
    """u(y, t) of the impulsively started flow (the series above, ``modes`` terms)."""
    k = np.arange(1, modes + 1)[:, None]
    modes_ = 2 * U * (-1.0) ** k / (k * np.pi) * np.sin(k * np.pi * y / H) * np.exp(-(k * np.pi) ** 2 * NU * t / H**2)
    return U * y / H + modes_.sum(axis=0)


# %% one run
def solve(method: str, basis: str, cells: int, dt: float, ppc: int = 2, times=(TRANSIENT, STEADY),
          pic_blend: float = 0.01) -> list[Measurement]:
    """Run the start-up flow to each of ``times``; the profile error there, relative to U."""
    solver = channel(method, basis, cells, dt, ppc, height=H, viscosity=NU, lid_speed=U, pic_blend=pic_blend)
    return profile_errors("couette", solver, times, Y, exact, U, basis, cells, ppc)


# %% convergence and cost
def study(full: bool = False) -> list[Measurement]:
    """Error at t = 0.1 H^2/nu and wall time against grid size (both methods, both bases; at
    dt = 2.5e-4 H^2/nu, where the time error is below the grid's), time step and particles per cell.
    The impulsive start makes the time error first order in dt (measured)."""
    grids = (8, 16, 32, 64) if full else (8, 16, 32)
    rows = [r for m in METHODS for b in BASES for n in grids for r in solve(m, b, n, 0.00025, times=(TRANSIENT,))]
    steps = (0.004, 0.002, 0.001, 0.0005) if full else (0.004, 0.002, 0.001)
    rows += [r for m in METHODS for dt in steps for r in solve(m, "bspline", 32, dt, times=(TRANSIENT,))]
    rows += [r for ppc in (1, 2, 3, 4) for r in solve("MPM", "bspline", 16, 0.001, ppc, times=(TRANSIENT,))]
    return rows


# %% main
def main(argv=None) -> int:
    """Run both methods on one grid, print their errors, plot their profiles."""
    return profile_demo(argv, "Plane Couette flow, started impulsively", solve, exact, Y, (TRANSIENT, STEADY),
                        "results/couette", "u / U")


if __name__ == "__main__":
    sys.exit(main())
