"""Vortices in the closed unit slip box, no gravity: what the particle-grid transfer dissipates.

* Taylor-Green: ``u = U sin(pi x) cos(pi y)``, ``v = -U cos(pi x) sin(pi y)`` is an exact
  Navier-Stokes solution in the unit box with slip walls (zero normal velocity and zero shear
  stress there); its amplitude decays as ``exp(-2 pi^2 nu t)`` (``|k|^2 = 2 pi^2``), its
  kinetic energy as ``exp(-4 pi^2 nu t)``. The numerical dissipation rate is the fitted
  ``-d ln KE / dt`` less ``4 pi^2 nu``, per unit time.
* Gresho & Chan (1990): the steady inviscid vortex ``u_theta = 5 r`` (r < 0.2), ``2 - 5 r``
  (0.2 <= r < 0.4), 0 beyond, about the box's centre, held by the pressure
  ``p / rho = 5 + 25 r^2 / 2`` (r < 0.2), ``9 - 4 ln 0.2 + 25 r^2 / 2 - 20 r + 4 ln r``
  (r < 0.4), ``3 + 4 ln 2`` beyond. Kinetic energy and angular momentum (with the particles'
  affine parts, :func:`fempm.transfer.angular_momentum`) stay; the profile error is the
  mass-weighted relative L2 difference of the particles' ``u_theta`` from the exact one.

Both start from the exact velocity, its exact Lagrangian acceleration
``Du/Dt = -grad p / rho + nu lap u`` (the Newmark state, given rather than solved: the exact
pressure enters through it)
and, with an affine transfer, the exact velocity and acceleration gradients. Taylor-Green runs
without the volume correction, to measure the transfer's dissipation alone (the correction's
expansion, a share alpha of the crowding per step, feeds energy in at a rate that grows as dt
falls). Gresho runs the default scheme, correction included: over t = 3 the vortex's shear
disorders the particles, and the crowding it leaves behind is what the correction undoes.

:func:`fem_reference` runs either vortex without particles (FEM-only, :mod:`fempm.eulerian`) on the
same grid and step: what the grid and the step lose by themselves.
"""

from __future__ import annotations

import numpy as np
import ufl
from mpi4py import MPI
from petsc4py import PETSc

from fempm import transfer
from fempm.bases import BASES
from fempm.eulerian import EulerianSolver
from fempm.grid import Grid
from fempm.implicit import ImplicitSolver
from fempm.options import Physics, Scheme
from fempm.particles import Particles, Rectangle
from fempm.quadrature import GaussForm
from fempm.verification import advance, sample

__all__ = ["NOISE_ONLY", "NOISE_ONLY_TURNING", "RHO", "SHIFTING", "TURNING", "VARIANTS", "VORTEX_SETTINGS", "WHOLE_SHARE", "angular_momentum",
           "fem_reference", "gresho", "gresho_pressure", "gresho_speed", "kinetic_energy", "largest_change",
           "taylor_green"]

RHO = 1000.0  #: kg/m^3
#: the transfers compared: the seed's FLIP with 10 % PIC per step and the default affine-FLIP
VARIANTS = {"FLIP/PIC": {"transfer": "flip", "pic_blend": 0.1, "pic_rate": 0.0, "rest_pic_rate": 0.0}, "affine-FLIP": {}}
#: the whole PIC share at 100/s alone, the default until the share on the noise joined it (studies' ``pic``)
WHOLE_SHARE = {"pic_rate": 100.0, "noise_rate": 0.0}
#: the share on the particles' noise alone (:class:`fempm.transfer.NoiseFilter`) at 300/s, no whole share
NOISE_ONLY = {"pic_rate": 0.0, "noise_rate": 300.0}
#: shifts that add no angular momentum (``Scheme.shifting_keeps_angular_momentum``), with the default shares
TURNING = {"shifting_keeps_angular_momentum": True}
#: the same with the share on the noise alone
NOISE_ONLY_TURNING = {**NOISE_ONLY, **TURNING}
#: the shipped dam break's handling of the pressure and the shifts (``scenes/dambreak.toml``), which the vortex
#: studies take: the last step's pressure by parts (``Scheme.pressure_work = "increment"``) and shifts that add no
#: angular momentum
VORTEX_SETTINGS = {"pressure_work": "increment", **TURNING}
#: the shipped dam break's particle shifting (``scenes/dambreak.toml``, ``solver.shifting``; fempm.shifting)
SHIFTING = 4.0
CENTRE = np.array([0.5, 0.5])


def box_solver(variant: str, cells: int, dt: float, nu: float, velocity, acceleration, basis: str = "bspline",
               comm=MPI.COMM_WORLD, alpha: float = Scheme.alpha, per_cell: int = 2,
               pspg: bool = Scheme.pspg, shifting: float = Scheme.shifting, solver_type=ImplicitSolver,
               surface_aware: bool = Scheme.surface_aware, pic: dict | None = None,
               gravity=(0.0, 0.0)) -> ImplicitSolver:
    """The unit slip box filled with ``per_cell`` x ``per_cell`` particles per cell at the given
    velocity and acceleration (functions of the positions returning ``(values (n, 2), gradients
    (n, 2, 2))``), with the volume correction ``alpha`` (``surface_aware``: :attr:`Scheme.surface_aware`),
    PSPG on or off and particle ``shifting``; ``pic``: :class:`Scheme` fields of the PIC share and the
    shifting over the variant's (e.g. :data:`NOISE_ONLY`); ``solver_type`` makes the solver from the basis, particles,
    physics and scheme. Under ``gravity`` the box is a full tank: the pressure balances it hydrostatically, and the
    given acceleration is the flow's alone."""
    grid = Grid.from_cells(comm, (0.0, 0.0), (1.0, 1.0), (cells, cells))
    water = Particles(grid)
    water.seed(Rectangle((0.0, 0.0), (1.0, 1.0)), per_cell=per_cell, density=RHO)
    scheme = Scheme(dt=dt, alpha=alpha, surface_aware=surface_aware, pspg=pspg, shifting=shifting,
                    initial_acceleration="given", **{**VARIANTS[variant], **(pic or {})})
    transfer.add_affine_fields(water, scheme.transfer)
    for name, field in (("velocity", velocity), ("acceleration", acceleration)):
        value, grad = field(water.x)
        water[name][:] = value
        if scheme.transfer != "flip":
            water[f"affine_{name}"][:] = grad
    return solver_type(BASES[basis](grid), water, Physics(viscosity=RHO * nu, gravity=tuple(gravity)), scheme)


def kinetic_energy(particles) -> float:
    """``sum_p m_p |v_p|^2 / 2`` on all ranks."""
    v = particles["velocity"]
    return particles.grid.comm.allreduce(float(np.einsum("i,ij,ij->", particles["mass"], v, v)) / 2)


# -- Taylor-Green -----------------------------------------------------------------------------------
def _taylor_green_fields(U: float, nu: float):
    pi = np.pi

    def velocity(x):
        s, c = np.sin(pi * x), np.cos(pi * x)
        v = U * np.column_stack([s[:, 0] * c[:, 1], -c[:, 0] * s[:, 1]])
        grad = U * pi * np.stack([np.column_stack([c[:, 0] * c[:, 1], -s[:, 0] * s[:, 1]]),
                                  np.column_stack([s[:, 0] * s[:, 1], -c[:, 0] * c[:, 1]])], axis=1)
        return v, grad

    def acceleration(x):  # -grad p / rho + nu lap u with p = rho U^2 / 4 (cos 2 pi x + cos 2 pi y)
        v, grad = velocity(x)
        a = 0.5 * pi * U**2 * np.sin(2 * pi * x) - 2 * pi**2 * nu * v
        da = np.zeros_like(grad)
        da[:, 0, 0], da[:, 1, 1] = pi**2 * U**2 * np.cos(2 * pi * x[:, 0]), pi**2 * U**2 * np.cos(2 * pi * x[:, 1])
        return a, da - 2 * pi**2 * nu * grad

    return velocity, acceleration


#: the windows of equal length over which taylor_green also reports the loss (see _window_losses)
WINDOWS = 5


def _window_losses(t: np.ndarray, ke: np.ndarray, viscous: float, windows: int) -> list[tuple[float, float, float]]:
    """``(start, end, -d ln KE/dt - viscous)`` over ``windows`` equal spans of the run, from the
    energy at the steps nearest their ends: how the loss grows as the particles disorder."""
    edges = np.searchsorted(t, np.linspace(t[0], t[-1], windows + 1))
    edges = np.minimum(edges, len(t) - 1)
    return [(float(t[a]), float(t[b]), float(-(np.log(ke[b]) - np.log(ke[a])) / (t[b] - t[a]) - viscous))
            for a, b in zip(edges[:-1], edges[1:]) if t[b] > t[a]]


def taylor_green(variant: str, cells: int, dt: float, nu: float, end: float = 0.25, U: float = 1.0,
                 basis: str = "bspline", per_cell: int = 2, pspg: bool = Scheme.pspg,
                 shifting: float = Scheme.shifting, solver_type=ImplicitSolver, pic: dict | None = None) -> dict:
    """The Taylor-Green vortex to ``end``: ``numerical`` is the fitted ``-d ln KE/dt - 4 pi^2 nu``.

    Also ``rate`` (fitted), ``viscous`` (``4 pi^2 nu``), ``windows`` (the loss over each of
    :data:`WINDOWS` equal spans), ``ke_end`` and ``exact_end`` (KE over its start), ``status``,
    ``cause``, ``t``, ``wall``, and the run's ``per_cell``, ``pspg`` and ``shifting`` (``solver_type``, ``pic``:
    see :func:`box_solver`).
    """
    solver = box_solver(variant, cells, dt, nu, *_taylor_green_fields(U, nu), basis, alpha=0.0,
                        per_cell=per_cell, pspg=pspg, shifting=shifting, solver_type=solver_type, pic=pic)
    times, energy = [0.0], [kinetic_energy(solver.particles)]

    def each(s):
        times.append(s.time)
        energy.append(kinetic_energy(s.particles))

    run = advance(solver, end, each)
    return {"variant": variant, "cells": cells, "dt": dt, "nu": nu, **_decay(times, energy, nu),
            "status": run.status, "cause": run.cause, "t": run.time, "wall": run.wall,
            "per_cell": per_cell, "pspg": pspg, "shifting": shifting}


def _decay(times, energy, nu: float) -> dict:
    """Taylor-Green's energy history measured: the fitted ``rate`` of ``-d ln KE/dt``, the viscous one,
    the ``numerical`` rest, its ``windows`` and ``ke_end`` against the exact ``exact_end``."""
    t, ke = np.array(times), np.array(energy)
    rate = float(-np.polyfit(t, np.log(ke), 1)[0]) if len(t) > 2 else float("nan")
    viscous = 4 * np.pi**2 * nu
    return {"rate": rate, "viscous": viscous, "windows": _window_losses(t, ke, viscous, WINDOWS),
            "numerical": rate - viscous, "ke_end": float(ke[-1] / ke[0]), "exact_end": float(np.exp(-viscous * t[-1]))}


# -- Gresho -----------------------------------------------------------------------------------------
def gresho_speed(r: np.ndarray) -> np.ndarray:
    """``u_theta(r)`` of the Gresho vortex."""
    return np.where(r < 0.2, 5 * r, np.where(r < 0.4, 2 - 5 * r, 0.0))


def gresho_pressure(r: np.ndarray) -> np.ndarray:
    """``p / rho`` of the Gresho vortex (zero at the centre's constant ``5``: the module's formula)."""
    r = np.maximum(r, 1e-300)
    return np.where(r < 0.2, 5 + 12.5 * r**2,
                    np.where(r < 0.4, 9 - 4 * np.log(0.2) + 12.5 * r**2 - 20 * r + 4 * np.log(r), 3 + 4 * np.log(2)))


def _polar(x):
    r = x - CENTRE
    return r, np.maximum(np.hypot(r[:, 0], r[:, 1]), 1e-300)


def _gresho_fields():
    def rotation(x, w):  # the field w(r) (-y, x) and its gradient, w = u_theta / r
        r, radius = _polar(x)
        omega = w(radius)
        step = 1e-7
        slope = (w(radius + step) - w(np.maximum(radius - step, 0.0))) / (radius + step - np.maximum(radius - step, 0))
        perp = np.column_stack([-r[:, 1], r[:, 0]])
        e = r / radius[:, None]
        grad = (slope[:, None, None] * perp[:, :, None] * e[:, None, :]
                + omega[:, None, None] * np.array([[0.0, -1.0], [1.0, 0.0]]))
        return omega[:, None] * perp, grad

    def velocity(x):
        return rotation(x, lambda r: gresho_speed(r) / np.maximum(r, 1e-300))

    def acceleration(x):  # centripetal -u_theta^2 / r e_r = -grad p / rho: -(u_theta / r)^2 r_vec
        r, radius = _polar(x)
        w2 = (gresho_speed(radius) / radius) ** 2
        step = 1e-7
        slope = ((gresho_speed(radius + step) / (radius + step)) ** 2 - w2) / step
        e = r / radius[:, None]
        grad = -(slope[:, None, None] * r[:, :, None] * e[:, None, :] + w2[:, None, None] * np.eye(2))
        return -w2[:, None] * r, grad

    return velocity, acceleration


def angular_momentum(solver) -> float:
    """The particles' angular momentum about the centre, affine parts included, on all ranks."""
    p = solver.particles
    affine = p["affine_velocity"] if "affine_velocity" in p.fields else None
    return transfer.angular_momentum(solver.system.space, p, affine, CENTRE)


def largest_change(values, start: float) -> float:
    """The relative change from ``start`` of largest magnitude among ``values`` (signed)."""
    changes = np.asarray(values, dtype=float) / start - 1
    return float(changes[np.argmax(np.abs(changes))]) if len(changes) else 0.0


def gresho_measures(solver) -> dict:
    """Kinetic energy, angular momentum about the centre (affine parts included) and u_theta's
    mass-weighted relative L2 error."""
    p = solver.particles
    L = angular_momentum(solver)
    r, radius = _polar(p.x)
    u_theta = (r[:, 0] * p["velocity"][:, 1] - r[:, 1] * p["velocity"][:, 0]) / radius
    exact = gresho_speed(radius)
    comm = p.grid.comm
    error = np.sqrt(comm.allreduce(float(np.einsum("i,i->", p["mass"], (u_theta - exact) ** 2)))
                    / comm.allreduce(float(np.einsum("i,i->", p["mass"], exact**2))))
    return {"ke": kinetic_energy(p), "L": L, "profile": float(error)}


def gresho(variant: str, cells: int, dt: float, end: float = 3.0, basis: str = "bspline", per_cell: int = 2,
           shifting: float = Scheme.shifting, solver_type=ImplicitSolver, alpha: float = Scheme.alpha,
           surface_aware: bool = Scheme.surface_aware, pic: dict | None = None, gravity=(0.0, 0.0)) -> dict:
    """The Gresho vortex to ``end`` (``per_cell`` x ``per_cell`` particles per cell, particle ``shifting``):
    relative changes of kinetic energy (``ke``) and angular momentum (``L``) at the end, the angular momentum's
    change of largest magnitude after any step (``L_largest``), the u_theta error at the end
    (``profile``) and at the start (``profile0``), the largest smoothed density over the water's at the
    end (``crowding``, eq. 2: where particles gather) and the smoothed density at the vortex's centre
    (``core``: below 1 where the core has thinned); ``solver_type``, ``alpha``, ``surface_aware``, ``pic``,
    ``gravity``: see :func:`box_solver`."""
    solver = box_solver(variant, cells, dt, 0.0, *_gresho_fields(), basis, alpha=alpha, per_cell=per_cell,
                        shifting=shifting, solver_type=solver_type, surface_aware=surface_aware, pic=pic,
                        gravity=gravity)
    start = gresho_measures(solver)
    history = []
    run = advance(solver, end, lambda s: history.append(angular_momentum(s)))
    final = gresho_measures(solver)
    density = solver.system.fields["smoothed_density"]
    crowding = solver.grid.comm.allreduce(float(density.values.max(initial=0.0)), op=MPI.MAX) / RHO
    core = float(sample(density, CENTRE[None])[0, 0]) / RHO
    return {"variant": variant, "cells": cells, "dt": dt, "ke": final["ke"] / start["ke"] - 1,
            "L": final["L"] / start["L"] - 1, "L_largest": largest_change(history, start["L"]),
            "profile": final["profile"], "profile0": start["profile"], "crowding": crowding, "core": core,
            "status": run.status, "cause": run.cause, "t": run.time, "wall": run.wall}


# -- FEM-only reference -----------------------------------------------------------------------------
def fem_reference(kind: str, cells: int, dt: float, end: float, nu: float = 0.0, basis: str = "bspline") -> dict:
    """A vortex (``taylor_green``, U = 1, or ``gresho``) on the fixed grid: the same forms with Gauss
    quadrature and Oseen convection (:class:`fempm.eulerian.EulerianSolver`, PSPG on),
    started from the L2 projection of the exact velocity onto the basis. What the grid and the step
    lose without particles: Taylor-Green's ``numerical`` loss (and :func:`taylor_green`'s other
    measures of the energy), Gresho's ``ke``, ``L``, ``L_largest`` and ``profile`` (relative L2 error of u_theta
    over the box) as :func:`gresho`'s; ``profile0`` at the start."""
    exact = _at_points(_taylor_green_fields(1.0, nu)[0] if kind == "taylor_green" else _gresho_fields()[0])
    grid = Grid.from_cells(MPI.COMM_WORLD, (0.0, 0.0), (1.0, 1.0), (cells, cells))
    solver = EulerianSolver(BASES[basis](grid), Physics(viscosity=RHO * nu, gravity=(0.0, 0.0)),
                            Scheme(dt=dt), density=RHO)
    _project(solver.system.vector_space, exact, solver.velocity)
    measure = _FieldMeasures(solver.velocity, exact)
    start = measure()
    times, energy, moments = [0.0], [start["ke"]], []

    def each(s):
        times.append(s.time)
        energy.append(measure.energy())
        if kind == "gresho":
            moments.append(measure.angular_momentum())

    run = advance(solver, end, each)
    final = measure()
    result = {"variant": "FEM-only", "kind": kind, "cells": cells, "dt": dt, "nu": nu, "status": run.status,
              "cause": run.cause, "t": run.time, "wall": run.wall}
    if kind == "taylor_green":
        return {**result, **_decay(times, energy, nu)}
    return {**result, "ke": final["ke"] / start["ke"] - 1, "L": final["L"] / start["L"] - 1,
            "L_largest": largest_change(moments, start["L"]), "profile": final["profile"],
            "profile0": start["profile"]}


def _at_points(velocity):
    """A velocity field of :func:`box_solver`'s kind as a callable of DOLFINx's points ``(3, n)``,
    values ``(2, n)``."""
    return lambda x: velocity(np.ascontiguousarray(x[:2].T))[0].T


def _project(space, field, out):
    """``out`` = the L2 projection of ``field`` (a callable of the points ``(3, n)``, values ``(2, n)``)
    onto ``space``, by Gauss quadrature and a direct solve of the mass matrix."""
    mass = GaussForm(lambda s: ufl.inner(s.trial, s.test) * s.dx, space)
    load = GaussForm(lambda s: ufl.inner(s.particle("exact"), s.test) * s.dx, space,
                     particle_values={"exact": field})
    M, b = mass.assemble_matrix(), load.assemble_vector()
    solver = PETSc.KSP().create(space.comm)
    solver.setOperators(M)
    solver.setType("preonly")
    solver.getPC().setType("lu")
    solver.getPC().setFactorSolverType("mumps")
    x = b.duplicate()
    solver.solve(b, x)
    out.values[: space.numbering.num_owned] = x.getArray(readonly=True).reshape(-1, space.bs)
    out.scatter_forward()
    for obj in (solver, M, b, x):
        obj.destroy()


class _FieldMeasures:
    """Kinetic energy, angular momentum about the centre and u_theta's relative L2 error of a grid
    velocity, by Gauss quadrature (each functional compiled once)."""

    def __init__(self, velocity, exact):
        """``exact``: the exact velocity, a callable of the points ``(3, n)`` (:func:`_at_points`)."""
        grids, space = {"velocity": velocity}, velocity.space

        def functional(integrand):
            return GaussForm(lambda s: integrand(s, s.grid("velocity"), s.x - ufl.as_vector(CENTRE)) * s.dx, space,
                             grid_functions=grids, particle_values={"exact": exact})

        def moment(d, v):  # (x - c) x v
            return d[0] * v[1] - d[1] * v[0]

        def u_theta(d, v):
            return moment(d, v) / ufl.sqrt(ufl.inner(d, d))

        self.forms = {
            "ke": functional(lambda s, v, d: 0.5 * RHO * ufl.inner(v, v)),
            "L": functional(lambda s, v, d: RHO * moment(d, v)),
            "error": functional(lambda s, v, d: (u_theta(d, v) - u_theta(d, s.particle("exact"))) ** 2),
            "norm": functional(lambda s, v, d: u_theta(d, s.particle("exact")) ** 2),
        }

    def energy(self) -> float:
        """The kinetic energy alone (a measure taken every step)."""
        return self.forms["ke"].assemble_scalar()

    def angular_momentum(self) -> float:
        """The angular momentum alone (a measure taken every step)."""
        return self.forms["L"].assemble_scalar()

    def __call__(self) -> dict:
        value = {name: form.assemble_scalar() for name, form in self.forms.items()}
        return {"ke": value["ke"], "L": value["L"], "profile": float(np.sqrt(value["error"] / value["norm"]))}
