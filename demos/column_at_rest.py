# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # A column at rest: still water must stay still
#
# A verification case of the implicit MPM's transfers and volume correction (issue 11). The
# dam-break column, $L$ = 146 mm wide and $2L$ deep ($\rho$ = 1000 kg/m³, $\mu$ = 1e-3 Pa s,
# $g$ = 9.81 m/s², slip walls), stands in a tank as wide as itself and $4L$ high, 10 × 40
# cells (the dam break's cell size at 40 × 40), 2 × 2 particles per cell, released at rest with
# $p = 0$. The exact solution is rest with the hydrostatic pressure
#
# $$
# v = 0, \qquad p = \rho g (2L - y),
# $$
#
# so the water's volume (its surface height, the tank's width being fixed) must stay and the
# particles must not move. What can move them: the particles settling as the pressure builds
# from zero, the quadrature on particles (a grid-scale velocity mode grows in resting water
# under FLIP increments without any PIC share), and the volume correction (method.md eq. 3).
#
# The transfers compared (`fempm.cases.vortices.VARIANTS`): the seed's FLIP with 10 % PIC
# per step, and the default affine-FLIP with a PIC share of 30/s and one of 300/s on the noise alone.

# %%
import argparse
import sys

from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import output
from fempm.cases import column
from fempm.cases.vortices import VARIANTS
from fempm.errors import FempmError

parser = argparse.ArgumentParser(description="A column at rest: volume and speeds (see the file's first cells).")
parser.add_argument("--end-time", type=float, default=1.0, help="s held at rest (default 1; the study: 10)")
parser.add_argument("--basis", choices=("bspline", "q1"), default="bspline")
parser.add_argument("--out", default="results/column-at-rest", help="output folder")
args = parser.parse_args()
if not args.end_time > 0:
    parser.error(f"--end-time must be > 0, got {args.end_time}")
try:
    folder = output.prepare_folder(args.out, MPI.COMM_WORLD)
except FempmError as e:
    parser.error(str(e))

# %% [markdown]
# ## Both transfers, held at rest
#
# `column.rest` steps the column (dt = 1 ms) and reports the surface height's relative change
# and the largest particle speed at the end and over the run.

# %%
rows = [column.rest(variant, args.end_time, args.basis) for variant in VARIANTS]
if MPI.COMM_WORLD.rank == 0:
    for r in rows:
        print(f"{r['variant']:12s} t = {r['t']:g} s: volume {100 * r['volume']:+.3f} %, speed {r['speed']:.2e} m/s "
              f"(largest over the run {r['peak']:.2e})  ({r['wall']:.1f} s) {r['cause']}")
    output.write_json(folder / "column.json", rows)

# %% [markdown]
# ## The check
#
# The default transfer must hold the column: volume within 0.2 % and every particle slower than
# 1e-3 m/s at the end (the full 10 s study is in `docs/verification.md`).

# %%
new = rows[list(VARIANTS).index("affine-FLIP")]
if new["status"] != "completed" or not abs(new["volume"]) < 0.002 or not new["speed"] < 1e-3:
    if MPI.COMM_WORLD.rank == 0:
        print(f"column_at_rest: {new['status']} {new['cause']}: volume {new['volume']:+.3%} (bound 0.2 %), "
              f"speed {new['speed']:.2e} m/s (bound 1e-3)", file=sys.stderr)
    sys.exit(1)
