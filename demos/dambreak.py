# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Dam break: a water column collapses in a square tank
#
# The seed's case (method.md, Figs. 1-4; the geometry of Koshizuka & Oka's 1996 experiment):
# a 584 mm square tank, a water column $L$ = 146 mm wide and $2L$ high in its lower-left
# corner, released at $t = 0$ under gravity. 40 x 40 cells, 2 x 2 particles per cell (800
# particles, as the seed's), slip walls, a step that adapts to the flow (Courant 0.8; the
# seed: $\Delta t$ = 1 ms), the particles shifted back to an even spread after each step. The demo runs it, records the surge front and
# compares it with the converged interFoam run and the experiment, and ends by checking its
# front.
#
# ## Strong form
#
# In the water $\Omega_t$, which moves with the flow (incompressible Navier-Stokes, Lagrangian):
#
# $$
# \rho \frac{\mathrm{D} v}{\mathrm{D} t} = \nabla\cdot\big(2\mu\,\varepsilon(v)\big) - \nabla p + \rho g,
# \qquad \nabla\cdot v = 0 \quad \text{in } \Omega_t,
# $$
#
# with $\varepsilon(v) = (\nabla v + \nabla v^T)/2$, $\rho$ = 1000 kg/m³, $\mu$ = 1e-3 Pa s,
# a traction-free free surface ($\sigma n = 0$) and no flow through the walls ($v \cdot n = 0$).
#
# ## Weak form of one step
#
# The unknowns live on the grid: the displacement increment $\Delta u$ over the step and the
# pressure $p$ at its end. Newmark's rule (the grid is reset every step) gives the end-of-step
# kinematics from $\Delta u$ and the projected $v_n$, $a_n$:
#
# $$
# a_{n+1} = \frac{\Delta u - \Delta t\, v_n - \Delta t^2 (\tfrac12 - \beta)\, a_n}{\beta\,\Delta t^2},
# \qquad v_{n+1} = v_n + \Delta t\,\big((1-\gamma)\, a_n + \gamma\, a_{n+1}\big).
# $$
#
# Find $(\Delta u, p)$ such that for all test functions $(w, q)$
#
# $$
# \begin{aligned}
# &\int_{\Omega} \rho\,(a_{n+1} - g)\cdot w \,\mathrm{d}x_\text{lumped}
#  + \int_{\Omega} 2\mu\,\varepsilon(v_{n+1}) : \varepsilon(w) - p\,\nabla\cdot w \,\mathrm{d}x = 0, \\
# &\int_{\Omega} q\,\Big(\nabla\cdot v_{n+1}
#   - \frac{\alpha}{\rho}\,\frac{\max(\tilde\rho - \rho, 0)}{\Delta t}\Big)\,\mathrm{d}x
#  + \int_{\Omega} \frac{\tau}{\rho}\,\nabla q \cdot r(v_{n+1}, p)\,\mathrm{d}x = 0,
# \end{aligned}
# $$
#
# with the PSPG residual
# $r = \rho\,(v_{n+1} - v_n)/\Delta t + \nabla p - \rho g - \nabla\cdot(2\mu\,\varepsilon(v_{n+1}))$
# (Tezduyar 1992), $\tau = \big((2/\Delta t)^2 + (2|v|/h)^2 + (4\nu/h^2)^2\big)^{-1/2}$, and the
# volume correction of method.md eq. (3): $\tilde\rho$ is the smoothed density of the particles,
# and where they crowd ($\tilde\rho > \rho$) the step asks for expansion. The integrals are sums
# over the particles, $\int f\,\mathrm{d}x = \sum_p V_p f(x_p)$; the inertia is lumped.
# The shipped scene adds to the pressure's work an exact zero, $\int \nabla\cdot(D H w)\,\mathrm{d}x$, with $H$ the
# last step's pressure (the particles' pressure projected to the grid) and $D$ a weight that vanishes at the free
# surface: at the particles the last step's pressure then works through $w\cdot\nabla(DH)$, and only the step's
# change of pressure meets the quadrature's error in $\nabla\cdot(p\,w)$, so that still or deep water and
# vortices stay calm (`solver.pressure_work = "increment"`, `fempm/hydrostatic.py`).
# These forms are `forms/incompressible.py`, one function per term: edit it, or pass a copy with
# `--forms`, to change the physics.

# %%
import argparse
import time
from functools import partial
from pathlib import Path

from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import simulation
from fempm.cases import dambreak
from fempm.errors import FempmError, SimulationDiverged
from fempm.options import TRANSFERS
from fempm.progress import Progress

comm = MPI.COMM_WORLD
SCENE = Path(__file__).resolve().parents[1] / "scenes" / "dambreak.toml"


stop = partial(dambreak.stop, "dambreak")  # one line on rank 0, then the exit status


# %% [markdown]
# ## Set-up: the shipped scene, changed by flags
#
# The set-up is the scene `scenes/dambreak.toml` (`fempm run scenes/dambreak.toml` runs it
# too, with checkpoints). Each flag sets one key of it: its `dest` is the key, so a new flag
# is one line. `add_flags` gives the flags of the tank, the water and the outputs that the
# explicit demo shares (`--end-time --cells --ppc --basis --walls --viscosity --pic --forms
# --out --output-interval --no-files --quiet`); those of the implicit scheme follow
# (`--transfer flip --pic 0.1 --pic-rate 0` is the seed's FLIP with 10 % PIC per step). Flags
# left out keep the scene's values; `-fempm_NAME [VALUE]` are PETSc options of the linear solve.

# %%
parser = argparse.ArgumentParser(description="The seed's dam break (see the file's first cells).",
                                 epilog="-fempm_NAME [VALUE]: PETSc options of the linear solve")
dambreak.add_flags(parser)
flag = parser.add_argument
flag("--dt", dest="time.dt", type=float, metavar="DT", help="largest time step, s (scene: 0.01), or with --fixed-step the step")
step = parser.add_mutually_exclusive_group()
step.add_argument("--courant", dest="time.courant", type=float, metavar="C", help="adaptive step: max |v| dt / h = C (scene: 0.6)")
step.add_argument("--fixed-step", action="store_true", help="a fixed step DT (the seed's: --fixed-step --dt 1e-3)")
flag("--alpha", dest="solver.volume_correction", type=float, metavar="ALPHA",
     help="volume correction, largest share per step (scene: 0.1)")
flag("--alpha-rate", dest="solver.volume_correction_rate", type=float, metavar="RATE",
     help="volume correction per second, 1/s: a share min(ALPHA, RATE dt) per step (scene: 100)")
flag("--no-volume-correction", dest="solver.volume_correction", action="store_const", const=0.0)
flag("--no-pspg", dest="solver.pspg", action="store_const", const=False, help="PSPG off (the run then fails)")
flag("--transfer", dest="solver.transfer", choices=TRANSFERS, help="particle-grid transfer (scene: affine-flip)")
flag("--pic-rate", dest="solver.pic_rate", type=float, metavar="RATE",
     help="PIC share per second, 1/s: a share RATE dt per step of the whole difference (scene: 30)")
flag("--noise-rate", dest="solver.noise_rate", type=float, metavar="RATE",
     help="then a share RATE dt per step of the particles' noise alone, 1/s (scene: 300; 0: none)")

parser.set_defaults(**{"output.folder": "results/dambreak-demo"})
args, rest = parser.parse_known_args()
try:
    petsc = dambreak.petsc_options(rest)
    fixed = {"time.courant": None} if args.fixed_step else {}
    scene = dambreak.scene({**dambreak.changes(args), **fixed, "solver.petsc": petsc}, files=args.files, source=SCENE,
                           names=dambreak.flag_names(parser))
except FempmError as e:
    stop(str(e), 2)

# %% [markdown]
# ## The grid, the water and the solver
#
# `build_solver` cuts the tank into square cells, seeds 2 x 2 particles in every cell of the
# column (each carries the volume $h^2/4$ and the mass $\rho h^2/4$; `--ppc 4` seeds 4 x 4, whose
# front lies closer to the converged one: `docs/speed.md`) and builds the implicit
# solver on quadratic B-splines. The forms of `forms/incompressible.py` are compiled here,
# once (DOLFINx's form compiler, a kernel per form evaluated at the particles); the time
# loop only assembles and solves. The output folder follows `fempm run`'s rule: an earlier
# run's files are replaced only with `--overwrite`.

# %%
try:
    solver = simulation.build_solver(scene, comm)
    dambreak.prepare_folder(scene, args.overwrite, comm)
except FempmError as e:
    stop(str(e), 2)
recorder = simulation.recorder_for(scene, solver, {"scheme": "implicit"})

# %% [markdown]
# ## The time loop
#
# `solver.step()` is one step of the implicit MPM (`ImplicitSolver.step` in `fempm/implicit.py`,
# which reads in one screen):
#
# 1. **P2G** (`project`): the particles' mass, momentum and acceleration are scattered to the
#    grid with their affine parts, $m_i v_i = \sum_p m_p N_i(x_p)\,(v_p + C_p (x_i - x_p))$:
#    $v_n$, $a_n$ and the smoothed density $\tilde\rho$; basis functions that barely touch
#    water are left out of the solve.
# 2. **Newton** (`system.solve`): $R(\Delta u, p)$ and its Jacobian assembled at the particles,
#    one exact linear solve on the free dofs ($R$ is affine in the unknowns: one iteration; on one
#    rank the pressure's Schur complement, factored, `fempm.linear`).
# 3. **G2P** (`update`): particle velocity and acceleration by FLIP increments blended with PIC
#    at a share of 30/s (`pic_rate` $\Delta t$ per step), then a share of 300/s of the particles'
#    noise alone (`noise_rate`, `fempm.transfer.NoiseFilter`), their affine parts $C_p$ by APIC
#    (Jiang et al. 2015), `fempm.transfer.update_state`;
#    $x_p \leftarrow x_p + \Delta u(x_p)$, the particle pressure; then the safeguards, and the
#    particles are relocated to their cells and ranks.
#
# After each step the recorder takes the measures (front, occupied cells, pressure range) and
# writes the files due (ParaView series, snapshots). Each step ends at most at the next time a
# file is due, so that an adaptive step (`time.courant`) lands on it. A step the safeguards
# reject raises `SimulationDiverged`, which ends the loop with its diagnosis.

# %%
end = scene.time.end
progress = Progress(end, comm) if scene.output.progress else None
status, cause = "completed", None
start = time.perf_counter()
recorder.record()  # the initial state
while solver.time < end * (1 - 1e-9):
    step_start = time.perf_counter()
    try:
        solver.step(until=min(end, recorder.next_time(solver.time)))
    except SimulationDiverged as e:
        status, cause = "stopped", str(e)
        break
    step_seconds = time.perf_counter() - step_start  # the step alone, without the files written after it
    recorder.record()
    if progress:
        progress.update(solver.time, step_seconds)
if progress:
    progress.close()
summary = recorder.close(status, cause, time.perf_counter() - start)

# %% [markdown]
# ## Comparison with data
#
# The front $x$ (the largest particle $x$ plus half a particle spacing) in Koshizuka & Oka's
# dimensionless form $T = t\sqrt{2g/L}$, $Z = x/L$, against the converged interFoam 160 x 160
# run (`data/reference/dambreak`): the RMS relative difference
# $\big(\frac{1}{N}\sum_i ((Z(T_i) - Z_i)/Z_i)^2\big)^{1/2}$ at its times $0.3 < T_i \le 3$ (at
# $T \approx 3.1$ the front reaches the far wall), and the same against the experiments over
# $T \le 3$. The measures join `summary.json`; `front.png` draws the front over the references.

# %%
measures = dambreak.compare_front(scene.output.folder, summary,
                                  f"fempm ({summary['basis']}, {summary['particles']} particles)", comm)

# %% [markdown]
# ## The check
#
# The run must reach its end, and its front must stay within 2.1 % of interFoam 160² (issue 11's
# target: 2.5 %; interFoam's own 40² run: 2.0 %): the shipped resolution is 1.9 % away (4 x 4
# particles per cell 1.3 %, 80 x 80 cells 0.7 %: `docs/speed.md`; the seed's FLIP with 10 % PIC per
# step was 5.4 % away, and further as the step falls). A run shorter than $t$ = 0.27 s ends before
# $T = 3$ and is not checked.

# %%
BOUND = 0.021  # measured 0.0195 (40 x 40 cells, 800 particles, Courant 0.8; 3200 particles at Courant 0.6: 0.0125)
difference = measures.get("front_difference_vs_interfoam_160")
if status != "completed" or (difference or 0) > BOUND:
    stop(cause or f"the front is {100 * difference:.2f} % from interFoam 160², above {100 * BOUND:g} %", 1)
if comm.rank == 0:
    print(f"dambreak: {summary['steps']} steps in {summary['wall_time_s']:.1f} s; front vs interFoam 160²: "
          f"{'not checked (ends before T = 3)' if difference is None else f'{100 * difference:.2f} %'}; "
          f"results in {scene.output.folder}")
