"""A tank of water at rest: the pressure must be hydrostatic, p = rho g d.

Verification case of the implicit MPM against the analytic pressure and against the same
forms solved by ordinary finite elements (FEM-only, ``fempm.eulerian``).

Set-up (the dam-break column with its gate closed): water H = 292 mm deep and
W = 146 mm wide, rho = 1000 kg/m^3, mu = 1e-3 Pa s, g = 9.81 m/s^2, walls slip, at rest.
The MPM tank is 2H high, the water's top a free surface (traction free as the natural
condition, method.md); the FEM-only domain is the water itself with its top ``open``
(traction free). Strong form and solution::

    grad p = rho g,  v = 0,   p = rho g (H - y).

The error is the max over the vertical centre line, from the floor to one cell below
the surface, of ``|p - rho g (H - y)| / (rho g H)`` after 0.2 s (200 steps of 1 ms from
rest, p = 0); the bottom pressure's relative error and the largest particle speed are
reported beside it.

Run (``mpirun -n 2`` works the same)::

    python demos/hydrostatic.py [--cells 20] [--ppc 2] [--dt 0.001] [--basis B-spline|Q1] [--out results/hydrostatic]

It writes ``pressure.png`` (pressure against depth) and ``errors.json``; :func:`study`
gives the convergence runs of ``benchmarks/report.py``.
"""

# %% imports
from __future__ import annotations

import sys

import numpy as np
from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import output
from fempm.grid import Grid
from fempm.bases import BASES
from fempm.options import Physics, Scheme
from fempm.particles import Rectangle
from fempm.verification import METHODS, Measurement, advance, case_arguments, filled_solver, sample

RHO, MU, G = 1000.0, 1.0e-3, 9.81
W, H = 0.146, 0.292
END = 0.2


# %% the tank
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


# %% one run
def solve(method: str, basis: str, cells: int, dt: float, ppc: int = 2) -> Measurement:
    """Hold the water at rest for 0.2 s; the pressure error along the centre line."""
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
    return Measurement("hydrostatic", method, BASES[basis].name, cells, dt, ppc**2 if method == "MPM" else 0, error, run.wall,
                       run.status, run.cause, extra)


# %% convergence and cost
def study(full: bool = False) -> list[Measurement]:
    """Error and wall time against cells across the depth (both methods and bases), particles per cell
    and time step."""
    grids = (10, 20, 40, 80) if full else (10, 20, 40)
    rows = [solve(m, b, n, 0.001) for m in METHODS for b in BASES for n in grids]
    rows += [solve("MPM", "bspline", 20, 0.001, ppc) for ppc in (1, 2, 3, 4)]
    rows += [solve("MPM", "bspline", 20, dt) for dt in (0.004, 0.002, 0.001, 0.0005)[: 4 if full else 3]]
    return rows


# %% main
def main(argv=None) -> int:
    """Run both methods on one grid, print their errors, plot pressure against depth."""
    args, folder = case_arguments(argv, "Hydrostatic tank: p = rho g d", cells=20, dt=0.001, dt_unit="s",
                                  out="results/hydrostatic")
    rows = [solve(m, args.basis, args.cells, args.dt, args.ppc) for m in METHODS]
    if MPI.COMM_WORLD.rank == 0:
        for r in rows:
            error = "-" if r.error is None else f"{r.error:.2e}"
            print(f"{r.method:8s} error {error}, bottom {100 * r.extra['bottom_error']:+.2f} %  ({r.wall:.1f} s) {r.cause}")
        output.write_json(folder / "errors.json", [r.as_dict() for r in rows])
        plot(folder / "pressure.png", rows)
    return 0 if all(r.status == "completed" for r in rows) else 1


def plot(path, rows: list[Measurement]):
    """Pressure against depth of each method, on rho g d."""
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
    with output.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, bbox_inches="tight", format="png")
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
