# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Gresho vortex: a steady inviscid vortex must stay
#
# A verification case of the implicit MPM's transfers (issue 11; Gresho & Chan 1990). In the
# closed unit box with slip walls, no gravity, $\nu = 0$, the vortex about the centre
#
# $$
# u_\theta(r) = \begin{cases} 5r & r < 0.2 \\ 2 - 5r & 0.2 \le r < 0.4 \\ 0 & r \ge 0.4 \end{cases}
# \qquad
# \frac{p}{\rho} = \begin{cases} 5 + \tfrac{25}{2} r^2 & r < 0.2 \\
#   9 - 4\ln 0.2 + \tfrac{25}{2} r^2 - 20 r + 4 \ln r & 0.2 \le r < 0.4 \\
#   3 + 4 \ln 2 & r \ge 0.4 \end{cases}
# $$
#
# is steady: the pressure gradient holds the centripetal acceleration,
# $\partial_r p / \rho = u_\theta^2 / r$. Its kinetic energy and its angular momentum about the
# centre must stay, and so must the profile $u_\theta(r)$. The particles start from the exact
# velocity, the exact acceleration $-u_\theta^2/r\;e_r$ (the exact pressure enters the Newmark
# state through it) and, for the affine transfer, their exact gradients. The angular momentum
# counts the particles' affine parts, $L = \sum_p m_p \left((x_p - c)\times v_p +
# (C_p D_p)_{yx} - (C_p D_p)_{xy}\right)$ (`fempm.transfer.angular_momentum`), which is what
# APIC's transfers conserve.
#
# Measured: kinetic energy and angular momentum as relative changes, and the mass-weighted
# relative L2 difference of the particles' $u_\theta$ from the exact profile.

# %%
import sys

from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import output
from fempm.cases import vortices
from fempm.verification import case_arguments

args, folder = case_arguments("Gresho vortex: kinetic energy, angular momentum, profile (see the file's first "
                              "cells).", cells=32, dt=0.0125, dt_unit="s", out="results/gresho")

# %% [markdown]
# ## Both transfers to t = 0.5
#
# The demo runs a short time at 32² ($\max u_\theta\,\Delta t/h$ = 0.4); the full study
# (`python benchmarks/transfer_study.py --case gresho --full`) runs $t$ = 3 at 32² and 64².

# %%
END = 0.5
rows = [vortices.gresho(variant, args.cells, args.dt, END, basis=args.basis) for variant in vortices.VARIANTS]
if MPI.COMM_WORLD.rank == 0:
    for r in rows:
        print(f"{r['variant']:12s} t = {r['t']:g}: KE {100 * r['ke']:+.2f} %, angular momentum {100 * r['L']:+.2f} %, "
              f"u_theta error {100 * r['profile']:.2f} %  ({r['wall']:.1f} s) {r['cause']}")

# %% [markdown]
# ## The shipped scene's settings
#
# The shipped dam break (`scenes/dambreak.toml`) shifts its particles, corrects the volume surface-aware,
# takes the last step's pressure by parts and shifts without adding angular momentum
# (`solver.pressure_work = "increment"`, `solver.shifting_keeps_angular_momentum = true`;
# `fempm.cases.vortices.VORTEX_SETTINGS`). At 64² and t = 3 that keeps issue 11's 1 % and 0.1 %
# (`docs/verification.md`); here, the demo's grid and time.

# %%
study = vortices.gresho("affine-FLIP", args.cells, args.dt, END, basis=args.basis, shifting=vortices.SHIFTING,
                        surface_aware=True, pic=vortices.VORTEX_SETTINGS)
study["variant"] = "vortex settings"
rows.append(study)
if MPI.COMM_WORLD.rank == 0:
    print(f"{'vortex study':12s} t = {study['t']:g}: KE {100 * study['ke']:+.2f} %, angular momentum "
          f"{100 * study['L']:+.2f} %, u_theta error {100 * study['profile']:.2f} %  ({study['wall']:.1f} s)")

# %% [markdown]
# ## The FEM-only reference
#
# The same forms on the fixed grid, Gauss quadrature and Oseen convection (`fempm.eulerian`), from
# the L2 projection of the exact velocity, same grid and step: what the grid and the step lose by
# themselves. The MPM's loss beyond it is the particles'.

# %%
reference = vortices.fem_reference("gresho", args.cells, args.dt, END, basis=args.basis)
rows.append(reference)
if MPI.COMM_WORLD.rank == 0:
    print(f"{'FEM-only':12s} t = {reference['t']:g}: KE {100 * reference['ke']:+.2f} %, angular momentum "
          f"{100 * reference['L']:+.2f} %, u_theta error {100 * reference['profile']:.2f} %  ({reference['wall']:.1f} s)")
    output.write_json(folder / "gresho.json", rows)

# %% [markdown]
# ## The check
#
# The affine transfer must keep the kinetic energy better than FLIP/PIC, and both measures
# within the bounds below at the default 32², t = 0.5, the vortex settings better still; the FEM-only
# reference must lose less
# than a tenth of the affine transfer's energy. The angular momentum is not conserved
# to round-off, but its error is of second order in the step: the incompressibility holds on the
# predicted end-of-step configuration (`forms/incompressible.py`, `end_divergence`); on the
# start configuration the vortex expanded and its angular momentum grew in proportion to the
# step (+5.7 %). See `docs/verification.md`.

# %%
new, old = (next(r for r in rows if r["variant"] == v) for v in ("affine-FLIP", "FLIP/PIC"))
BOUNDS = {"ke": 0.036, "L": 0.002}  # measured -2.20 % and -0.19 % (32², dt 0.0125, t = 0.5)
failed = [r["variant"] for r in rows if r["status"] != "completed"]
if not abs(reference["ke"]) < 0.1 * abs(new["ke"]):
    failed.append(f"FEM-only KE change {reference['ke']:+.3%} not a tenth of the MPM's")
failed += [f"{k} {new[k]:+.3%}" for k, bound in BOUNDS.items() if not abs(new[k]) < bound]
if abs(new["ke"]) >= abs(old["ke"]):
    failed.append(f"KE change {new['ke']:+.3%} not below FLIP/PIC's {old['ke']:+.3%}")
if abs(study["ke"]) >= abs(new["ke"]):  # measured -1.95 % against -2.20 % (32², dt 0.0125, t = 0.5)
    failed.append(f"the vortex settings' KE change {study['ke']:+.3%} not below the default's {new['ke']:+.3%}")
if failed:
    if MPI.COMM_WORLD.rank == 0:
        print(f"gresho: {'; '.join(failed)}", file=sys.stderr)
    sys.exit(1)
