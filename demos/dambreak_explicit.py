"""The seed's dam break with the explicit baseline: weakly compressible MUSL MPM (method.md, Fig. 5).

The same tank, water column, grid, basis and particles as ``demos/dambreak.py`` (Koshizuka &
Oka 1996: a 584 mm square tank, 40 x 40 cells, a column 146 mm wide and 292 mm high,
2 x 2 particles per cell), the same outputs, but water is a weakly compressible fluid and
each step is explicit: no system is solved, and the time step is bounded by the sound speed.

Strong form, in the moving material (no pressure unknown)::

    rho dv/dt = div(-p I + 2 mu dev eps(v)) + rho g,    d rho/dt = -rho div v,
    p = K (rho / rho_0 - 1),
    traction-free free surface, zero normal velocity on the walls.

Weak form, the nodal force of a step (integrated at the particles; the mass is lumped)::

    m_i dv_i/dt = - sum_p V_p sigma_p : grad N_i(x_p) + sum_p m_p g N_i(x_p)

in ``forms/weakly_compressible.py`` (edit it, or pass a copy with ``--forms``), advanced
by forward Euler with the stress updated last (MUSL, Sulsky et al. 1995): ``fempm/explicit.py``.

Two choices of compressibility:

* ``--bulk-modulus 2.0e9`` (default): water's own K, the seed's run; c = 1414 m/s and the
  CFL step is about 5e-6 s.
* ``--sound-speed C0``: the weakly compressible practice (PySPH, SPHinXsys, TrixiParticles),
  an artificial sound speed about 10 times the largest flow speed, here
  ``10 sqrt(2 g H) = 23.9 m/s`` (``--sound-speed auto``); density then varies by about 1 %
  and the step is some 50 times larger.

The time step is ``dt = C h / (c + sqrt(2 g H))`` (``--cfl C``, default
``fempm.explicit.DEFAULT_CFL``), or ``--dt``.

The run writes to ``--out`` (default ``results/dambreak_explicit``) what the implicit demo
writes: ``front.csv``/``front.png`` against Koshizuka-Oka and Martin-Moyce,
``snapshot_t0.200.png``, ``snapshot_t0.600.png``, ``snapshot_final.png`` coloured by
pressure, ``particles.pvd`` and ``grid.bp`` for ParaView, ``volume.csv`` and ``summary.json``.

Run (``mpirun -n 2`` works the same)::

    python demos/dambreak_explicit.py --sound-speed auto [--end-time 1.0] ...
"""

# %% imports
from __future__ import annotations

import sys
from math import sqrt

from mpi4py import MPI

from dambreak import GRAVITY, HEIGHT, check_common, common_arguments, record, report, water_column
from fempm.explicit import DEFAULT_CFL, ExplicitScheme, ExplicitSolver
from fempm.options import Physics

#: 10 times the largest flow speed of the collapse, sqrt(2 g H) (the column's free fall).
AUTO_SOUND_SPEED = 10 * sqrt(2 * GRAVITY * HEIGHT)


# %% command line
def parse_arguments(argv=None):
    """The demo's flags (those of the implicit demo without its stabilisations, plus the fluid's)."""
    parser = common_arguments(__doc__, "results/dambreak_explicit", "weakly_compressible", ExplicitScheme.pic_blend)
    parser.add_argument("--bulk-modulus", type=float, default=2.0e9, help="K of the water, Pa (default 2e9)")
    parser.add_argument("--sound-speed", default=None,
                        help="artificial sound speed c0, m/s, instead of K; "
                             f"'auto' = 10 sqrt(2gH) = {AUTO_SOUND_SPEED:.1f}")
    parser.add_argument("--cfl", type=float, default=DEFAULT_CFL, help=f"CFL safety factor (default {DEFAULT_CFL})")
    parser.add_argument("--dt", type=float, default=None, help="time step, s (default: the CFL step)")
    args = parser.parse_args(argv)
    check_common(parser, args)
    if args.sound_speed is not None:
        try:
            args.sound_speed = AUTO_SOUND_SPEED if args.sound_speed == "auto" else float(args.sound_speed)
        except ValueError:
            parser.error(f"--sound-speed must be a number of m/s or 'auto', got {args.sound_speed!r}")
    if args.dt is not None and not args.dt > 0:
        parser.error(f"--dt must be positive, got {args.dt}")
    return args


# %% set-up: the implicit demo's tank and column, the explicit solver
def build(args, comm=MPI.COMM_WORLD) -> ExplicitSolver:
    """The tank, the water column and the explicit solver of the given flags."""
    physics = Physics(viscosity=args.viscosity, gravity=(0.0, -GRAVITY), walls=args.walls)
    scheme = ExplicitScheme(dt=args.dt, cfl=args.cfl, bulk_modulus=args.bulk_modulus, sound_speed=args.sound_speed,
                            max_speed=sqrt(2 * GRAVITY * HEIGHT), pic_blend=args.pic, forms=args.forms)
    return ExplicitSolver(*water_column(args, comm), physics, scheme)


# %% the run: step, record, compare the front, write
def run(args, comm=MPI.COMM_WORLD) -> dict:
    """Run the explicit dam break of ``args``; returns the summary (also written to summary.json)."""
    solver = build(args, comm)
    return record(solver, args, {
        "scheme": "explicit MUSL, weakly compressible", "bulk_modulus_Pa": solver.bulk_modulus,
        "sound_speed_m_per_s": solver.sound_speed, "cfl": args.cfl if args.dt is None else None,
    }, comm)


def main(argv=None) -> int:
    """Run from the command line; exit status 1 if the run stopped early."""
    args = parse_arguments(argv)
    return report("dambreak_explicit", args, lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
