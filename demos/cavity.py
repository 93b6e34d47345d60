# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Lid-driven cavity at Re = 100: the implicit MPM and FEM-only against Ghia et al. (1982)
#
# The case of Ghia, Ghia & Shin (1982, J. Comput. Phys. 48, 387-411): a unit square cavity
# full of fluid whose lid ($y = L = 1$) slides along $+x$ at $U = 1$; the other three walls are
# at rest, all four no-slip. $\rho = 1$, $\nu = 0.01$, so $Re = UL/\nu = 100$; no gravity.
# From rest the flow spins up to a steady primary vortex.
#
# ## Strong form
#
# Eulerian, in the fixed cavity $\Omega = (0, 1)^2$:
#
# $$
# \rho\Big(\frac{\partial v}{\partial t} + (v\cdot\nabla) v\Big) = \nabla\cdot\big(2\mu\,\varepsilon(v)\big) - \nabla p,
# \qquad \nabla\cdot v = 0,
# \qquad v = (U, 0) \text{ on the lid}, \quad v = 0 \text{ on the other walls}.
# $$
#
# ## Weak forms: two methods, one forms file
#
# Both solve the step of `forms/incompressible.py` (Newmark, PSPG; see `demos/dambreak.py`):
#
# * **FEM-only** (`fempm.eulerian.EulerianSolver`): Gauss quadrature on the fixed grid, and the
#   convective term $\int \rho\,(v_n\cdot\nabla) v_{n+1}\cdot w\,\mathrm{d}x$ (Oseen's rule) that a
#   fixed grid needs;
# * **MPM** (`fempm.implicit.ImplicitSolver`): `--ppc` x `--ppc` particles per cell fill the
#   cavity, are the quadrature points, and carry the convection as they circulate.
#
# At the two top corners the lid's speed jumps from $U$ to 0: fempm holds the basis functions a
# moving wall shares with a side at rest at rest, so the lid speed rises from 0 to $U$ across
# the corner cell, a regularisation that shrinks with the cell size.
#
# ## The measure
#
# $e_u = \max_i |u(0.5, y_i) - u_\text{Ghia}(y_i)| / U$ over Ghia's 17 points on the vertical
# centre line, and $e_v$ likewise for $v(x, 0.5)$ on the horizontal one (Ghia's Tables I and II,
# `data/reference/cavity`), of the **mean** profile over the last `--window` = 5 $L/U$ of a run
# from rest to 15 $L/U$. The FEM-only centre lines are steady by then (they change by less than
# 1e-4 $U$ per $L/U$, `history.csv`); the MPM's never settle to that degree: its particles, its
# quadrature points, keep rearranging, so it is measured on its mean profile too. Ghia's table is
# itself a 129 x 129 finite-difference solution: from 16 to 64 cells the FEM-only errors stay
# near 0.5 % ($u$) and 0.9 % ($v$) while the runs agree among themselves ever more closely, the
# distance between the converged solution and the table (`docs/verification.md`).
#
# ## The MPM's settings
#
# The step is $U\Delta t/h = 0.5$ and the particles 2 x 2 per cell; a smaller step or more
# particles do not help, with the PIC share fixed per step more steps smooth more. The volume
# correction stays at its default $\alpha = 0.1$: the particles move with the interpolated grid
# velocity, which is not exactly divergence-free where they are; without it (`--alpha 0`) they
# crowd into clumps of up to 19 per cell and the errors grow to 27 % / 14 %; `--alpha 0.3` makes
# the profile noisier and 0.5 diverged. The PIC share stays at 0.1: less is noisier, more is too
# viscous (every transfer smooths like a viscosity of order $h^2/\Delta t$). Each of these was
# measured at 32 cells with the flag named; `benchmarks/cavity_study.py` gives the convergence study.

# %%
import argparse
import sys
from pathlib import Path

from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import output
from fempm.bases import BASES
from fempm.cases import cavity
from fempm.errors import FempmError
from fempm.options import Scheme
from fempm.verification import over_bounds

comm = MPI.COMM_WORLD
parser = argparse.ArgumentParser(description="Lid-driven cavity at Re = 100 (see the file's first cells).")
parser.add_argument("--cells", type=int, default=32, help="cells per side (default 32)")
parser.add_argument("--basis", choices=tuple(BASES), default="bspline", help="grid basis (default bspline)")
parser.add_argument("--ppc", type=int, default=2, help="MPM particles per cell and direction (default 2)")
parser.add_argument("--dt", type=float, help=f"MPM time step (default {cavity.COURANT} h/U)")
parser.add_argument("--fem-dt", type=float, default=cavity.FEM_DT, help=f"FEM-only time step (default {cavity.FEM_DT})")
parser.add_argument("--end-time", type=float, default=cavity.END_TIME, help="simulated time (default 15 L/U)")
parser.add_argument("--window", type=float, default=cavity.WINDOW, help="the profiles' mean is over the last WINDOW")
parser.add_argument("--method", choices=("both", "mpm", "fem"), default="both", help="which methods run")
parser.add_argument("--alpha", type=float, default=Scheme.alpha, help="MPM volume correction, 0..1")
parser.add_argument("--pic", type=float, default=cavity.PIC, help="MPM PIC share per step, 0..1")
parser.add_argument("--out", type=Path, default=Path("results/cavity"), help="output folder")
parser.add_argument("--quiet", action="store_true", help="no progress line")
args = parser.parse_args()
times = {name: getattr(args, name) for name in ("dt", "fem_dt", "end_time", "window")}
problems = [f"--{n.replace('_', '-')} must be positive, got {t}" for n, t in times.items()
            if t is not None and not t > 0]
problems += [f"--{name} must be at least {low}, got {getattr(args, name)}" for name, low in (("cells", 4), ("ppc", 1))
             if getattr(args, name) < low]
problems += [f"--{name} must be in [0, 1], got {getattr(args, name)}" for name in ("alpha", "pic")
             if not 0 <= getattr(args, name) <= 1]
if args.window > args.end_time:
    problems.append(f"--window ({args.window:g}) must not exceed --end-time ({args.end_time:g})")
if problems:
    parser.error("; ".join(problems))
try:
    folder = output.prepare_folder(args.out, comm)
except FempmError as e:
    parser.error(str(e))

# %% [markdown]
# ## The runs
#
# `cavity.run_case` builds the cavity at rest (`cavity.cavity_solver`), steps it to the end time
# and samples both centre lines after every step (`cavity.CentreLines`): their mean over the
# window, and every $L/U$ a row of `history.csv`. For the MPM it also counts the particles per
# cell at the end: do they stay spread over the cavity?

# %%
common = dict(end_time=args.end_time, window=args.window, comm=comm, progress=not args.quiet)
runs = []
if args.method in ("both", "fem"):
    runs.append(cavity.run_case("FEM-only", args.basis, args.cells, args.fem_dt, **common))
if args.method in ("both", "mpm"):
    runs.append(cavity.run_case("MPM", args.basis, args.cells, args.dt or cavity.courant_step(args.cells), args.ppc,
                                alpha=args.alpha, pic=args.pic, **common))

# %% [markdown]
# ## Results
#
# `centrelines.png` (both mean profiles with Ghia's points, and the MPM's particles per cell),
# `errors.csv`, `centrelines.csv` (the mean profiles at Ghia's points), `history.csv` and
# `summary.json`, written by rank 0.

# %%
if comm.rank == 0:
    cavity.write_results(folder, cavity.load_ghia(), runs)
    for m in (r.measurement for r in runs):
        if m.error is not None:
            print(f"cavity: {m.method} {m.basis} {m.cells}^2: error vs Ghia u {100 * m.extra['error_u']:.2f} %, "
                  f"v {100 * m.extra['error_v']:.2f} % ({m.extra['steps']} steps, {m.wall:.1f} s)")

# %% [markdown]
# ## The check
#
# Every run must complete, and a run that reaches the steady state (15 $L/U$) must be within the
# bound measured on the default set-up (32 cells, B-spline, 2 x 2 particles per cell): FEM-only
# 0.95 % of $U$ from Ghia's table, the MPM 1.9 % ($\max(e_u, e_v)$). Shorter runs are not checked.

# %%
BOUNDS = {"FEM-only": 0.0095, "MPM": 0.019}  # measured 0.00903 (v) and 0.0179 (v), 32 cells, B-spline
# (the MPM's 0.01443 with the divergence on the start configuration; see tests/test_cavity.py)
rows = [r.measurement for r in runs]
failed = over_bounds(rows, BOUNDS) if args.end_time >= cavity.END_TIME else [
    f"{m.method}: {m.cause}" for m in rows if m.status != "completed"]
if failed:
    if comm.rank == 0:
        print("cavity: " + "; ".join(failed), file=sys.stderr)
    sys.exit(1)
