"""The implicit MPM time step of method.md: one monolithic (du, p) solve per step.

One step, as named phases::

    project   P2G: grid v_n, a_n (mass-weighted), smoothed density (eq. 2); which dofs are free
    solve     Newton on R(U) = 0 of forms/incompressible.py at the particles (one iteration
              when R is affine in U), PETSc (MUMPS LU) on the free dofs
    update    G2P: velocity and acceleration (Scheme.transfer), x += du, pressure; safeguards
    relocate  particles to their new cells and ranks

The parts it is made of: :class:`~fempm.system.GridSystem` (unknowns, grid fields, walls, free
dofs, Newton), :class:`~fempm.region.MatrixRegion` (the Jacobian's rows),
:mod:`fempm.transfer` (P2G, G2P) and :mod:`fempm.safeguards`.
"""

from __future__ import annotations

import numba
import numpy as np
from mpi4py import MPI

from fempm import collective, diagnostics, transfer
from fempm.bases import Basis
from fempm.density import DeepWater
from fempm.errors import InputError
from fempm.hydrostatic import HydrostaticPressure, LastPressure
from fempm.options import SIDES, Controls, Physics, Scheme
from fempm.pressure_points import GaussPoints
from fempm.particles import Particles
from fempm.quadrature import ParticleForm
from fempm.region import MatrixRegion
from fempm.shifting import REST_SPEED, ParticleShifting
from fempm.safeguards import EnergyWatch, PressureCheck, impact_impulse
from fempm.space import GridFunction, Space
from fempm.stepper import StepControl, Stepper
from fempm.system import GridSystem, StepForms

__all__ = ["ImplicitSolver", "WALL_RESOLVES"]

#: solves of a step again, at most, after wall dofs that pulled hard were released (fempm.walls)
WALL_RESOLVES = 2


@numba.njit(cache=True)
def _grid_state(p2g, m, mv, ma, count, rho, reference, min_support, min_pressure, min_count, velocity,
                acceleration, held, keep, pressure):
    """:meth:`ImplicitSolver.project`'s grid fields from the P2G sums ``p2g`` (columns ``m``, ``mv``,
    ``ma``, ``count``) and the smoothed density ``rho``, function by function: ``v = (m v) / m`` and
    ``a = (m a) / m`` where the material's fraction ``rho / reference`` reaches ``min_support`` (else
    0, and ``held`` 1 in both directions); for the owned functions (the rows of ``keep``) every dof kept there,
    the pressure only where the fraction reaches ``min_pressure`` and ``min_count`` particles or more share the
    support."""
    for f in range(p2g.shape[0]):
        mass, fraction = p2g[f, m], rho[f] / reference
        moving = mass > 0 and fraction >= min_support
        held[f, 0] = held[f, 1] = 0.0 if moving else 1.0
        for c in range(2):
            velocity[f, c] = p2g[f, mv + c] / mass if moving else 0.0
            acceleration[f, c] = p2g[f, ma + c] / mass if moving else 0.0
        if f < keep.shape[0]:
            keep[f, :] = fraction >= min_support
            keep[f, pressure] &= fraction >= min_pressure and p2g[f, count] >= min_count


@numba.njit(cache=True)
def _g2p_fields(U, u, p, v_n, a_n, v_new, a_new, held, out, du, dv, da, v, a, pressure, held_at):
    """:meth:`ImplicitSolver.update`'s grid fields into ``out`` (at the components from ``du``, ``dv``,
    ``da``, ``v``, ``a``, ``pressure``, ``held_at``): the solved ``du`` and ``p`` (of ``U``, from ``u`` and
    ``p``), the changes ``v_{n+1} - v_n`` and ``a_{n+1} - a_n``, the new values, and ``held``."""
    for f in range(out.shape[0]):
        out[f, held_at] = held[f, 0]
        out[f, held_at + 1] = held[f, 1]
        for c in range(2):
            out[f, du + c] = U[f, u + c]
            out[f, dv + c] = v_new[f, c] - v_n[f, c]
            out[f, da + c] = a_new[f, c] - a_n[f, c]
            out[f, v + c] = v_new[f, c]
            out[f, a + c] = a_new[f, c]
        out[f, pressure] = U[f, p]


@numba.njit(cache=True)
def _move(values, du, p, x, pressure):
    """:meth:`ImplicitSolver.update`'s ``x += du`` and pressure, in place, from the grid fields' ``values``
    at the particles (the components ``du`` and ``p``)."""
    for q in range(x.shape[0]):
        for c in range(2):
            x[q, c] = x[q, c] + values[q, du + c]
        pressure[q] = values[q, p]


@numba.njit(cache=True)
def _largest_magnitude(values):
    """``max |values|``, 0 for none (NaN if one is NaN)."""
    largest = 0.0
    for value in values:
        if abs(value) > largest:
            largest = abs(value)
        elif value != value:
            return value
    return largest


class ImplicitSolver(Stepper):
    """Advances particles of an incompressible viscous fluid by the implicit MPM.

    Args:
        basis: the grid basis (``fempm.BSpline2`` as in the seed, or ``fempm.Q1``).
        particles: the fluid (fields ``density``, ``velocity``, ``acceleration``); a ``pressure``
            field is added.
        physics, scheme, controls: see :mod:`fempm.options` (defaults: the seed's water and scheme).

    Attributes:
        system: the grid side of the step (:class:`~fempm.system.GridSystem`).
        walls: the held wall dofs and impermeable sides (``walls.stops``: displacements cut at a wall).
        region: where the Jacobian has rows (``region.rebuilds``: times it was widened).
        velocity, pressure: grid functions of the last step's ``v_{n+1}`` and ``p``.
        max_divergence: largest ``|div v_{n+1}|`` at the particles in the last step, 1/s.
    """

    def __init__(self, basis: Basis, particles: Particles, physics: Physics | None = None,
                 scheme: Scheme | None = None, controls: Controls | None = None):
        physics, scheme, controls = physics or Physics(), scheme or Scheme(), controls or Controls()
        for part in (physics, scheme, controls):
            part.check()
        control = (StepControl(scheme.courant, scheme.dt, controls.step_growth, controls.step_retries)
                   if scheme.courant else None)
        super().__init__(scheme.dt, control)
        self.basis, self.grid, self.particles = basis, basis.grid, particles
        self.physics, self.scheme, self.controls = physics, scheme, controls
        if "pressure" not in particles.fields:
            particles.add_field("pressure")
        transfer.add_affine_fields(particles, scheme.transfer)
        self._reference_density = self.grid.comm.allreduce(particles["density"].max(initial=0.0), op=MPI.MAX)
        self.system = GridSystem(basis, physics, scheme, controls, convection=0.0, timings=self.timings,
                                 density=self._reference_density)
        self.walls, self.velocity, self.pressure = self.system.walls, self.system.velocity, self.system.pressure
        self.region = MatrixRegion(self.system.space, controls.matrix_region, particles)
        s = self.system
        self._gauss_points = None
        if scheme.pressure_quadrature == "gauss":  # fempm.pressure_points
            GaussPoints.check(particles)
            self._gauss_points = GaussPoints(s.scalar_space, self._reference_density)
        self.forms = StepForms(scheme.step_forms(), lambda builder: ParticleForm(
            builder, s.space, particle_shapes=particles, grid_functions=s.fields, constants=s.constants))
        if self.forms.residual.fixed and self._gauss_points is None:
            raise InputError(f"forms {scheme.step_forms()!s}: they integrate over s.dx_fixed (Gauss points), but "
                             f"pressure_quadrature is 'particles': set it to 'gauss'")
        self._jet_order = max(self.forms.residual.order, self.forms.jacobian.order)  # the jets the forms read
        self._p2g = GridFunction(Space(basis, {"m": 1, "mv": 2, "ma": 2, "count": 1}), "p2g")
        self._g2p = GridFunction(Space(basis, {"du": 2, "dv": 2, "da": 2, "v": 2, "a": 2, "p": 1, "held": 2}), "g2p")
        self._held = GridFunction(Space(basis, {"held": 2}), "held")  # 1 where a step held at rest (project)
        self._integrals = transfer.density_normalisation(basis, particles)[s.scalar_space.numbering.local_functions]
        walls = physics.wall_conditions()
        open_sides = [side for side in SIDES if walls[side] in ("outflow", "open")]
        self._deep_water = DeepWater(s.scalar_space, open_sides)
        # the pressure the split takes by parts (fempm.hydrostatic): the hydrostatic one or the last step's
        self._hydrostatic = (HydrostaticPressure(s.scalar_space, physics.gravity, self._reference_density, open_sides)
                             if scheme.pressure_work == "split" else None)
        self._last_pressure = LastPressure(s.scalar_space) if scheme.pressure_work == "increment" else None
        self.check_pressure = self._pressure_check()
        self.check_energy = self._energy_watch()
        self.max_divergence = 0.0
        self._gravity = float(np.linalg.norm(physics.gravity))  # |g|
        # with the split (either known pressure) the shifting fades at rest (fempm.shifting)
        rest_speed = (REST_SPEED * np.sqrt(self._gravity * self.grid.h)
                      if s.constants["split"] else 0.0)
        self._shifting = (ParticleShifting(particles, scheme.shifting, [walls[side] in ("slip", "no-slip") for side in SIDES],
                                           scheme.shifting_keeps_angular_momentum, rest_speed)
                          if scheme.shifting > 0 else None)
        self._values, self._divergence = np.empty((0, self._g2p.space.bs)), np.empty(0)  # G2P's (_particle_room)
        self._noise = (transfer.NoiseFilter(basis) if scheme.noise_rate > 0 and scheme.transfer in transfer.NOISE_FILTERED
                       else None)

    # -- one step (Stepper.step chooses dt, retries, moves the clock) ---------------------------
    def advance(self, dt: float):
        """One step of size ``dt``: P2G, Newton, G2P, relocation (the run's first step from a solved
        ``a_0``, :meth:`solve_initial_acceleration`, unless the scheme says it is given)."""
        self.system.set_step(dt)
        if self.steps == 0 and self.scheme.initial_acceleration == "solved" and not self.physics.wall_speeds:
            self.solve_initial_acceleration()
        with self.timings("project"):
            self.system.space.tabulate_particles(self.particles, self._jet_order)  # one for P2G, forms, G2P
            free = self.project()
        points = self.quadrature_points()
        reaction = self.solve(free, points)
        if reaction is not None:  # one-sided walls: the next step's held set (fempm.walls)
            self.walls.update(reaction, self.system.U.array, self._reference_density, dt)
        with self.timings("update"):
            self.update()
        with self.timings("relocate"):
            self.particles.relocate()

    def solve(self, free: np.ndarray, points) -> np.ndarray | None:
        """The step's solve over the ``free`` dofs; with one-sided walls, solved again (at most
        :data:`WALL_RESOLVES` times) while the held wall dofs change within the step, those that pull with
        more than a cell of water's weight let go (:meth:`fempm.walls.Walls.settle`), and the reaction at
        the contact dofs."""
        self.system.solve(self.forms, free, self.region.matrix, points)
        if not self.walls.one_sided:
            return None
        reaction = self.system.reaction(self.forms, points, self.walls.normal)
        for _ in range(WALL_RESOLVES):
            if not self.walls.settle(reaction, self.system.U.array, self._reference_density, self.system.dt):
                break
            for name, projected in self._projected.items():  # v_n and a_n as projected on the released dofs
                self.system.fields[name].values[:] = projected
            self.system.impose_walls()
            self.system.solve(self.forms, self.system.free.select(self._material.copy()), self.region.matrix, points)
            reaction = self.system.reaction(self.forms, points, self.walls.normal)
        return reaction

    def solve_initial_acceleration(self):
        """Newmark's ``a_0`` consistent with the flow: the step (of the size last set) solved once
        from the particles' own ``a_0``, its end-of-step acceleration ``a_1`` taken at the particles
        where they stand (values, and affine parts for an affine transfer) as their ``a_0``.

        With the trapezoidal rule ``v_1 = v_0 + dt (a_0 + a_1) / 2``: a column released from rest
        with ``a_0 = 0`` gains half a step's worth of velocity too little in its first step and
        lags by ``dt / 2`` ever after, an error of first order in dt (the dam-break front moved
        with the step). ``a_1`` is ``a(0)`` to O(dt), so that lag becomes O(dt^2).
        """
        p, g = self.particles, self._g2p
        with self.timings("start"):
            self.system.space.tabulate_particles(p, self._jet_order)
            free = self.project()
            self.solve(free, self.quadrature_points())
            _, a_new = self.system.end_state()
            g.values[:] = 0.0
            g.field("a")[:] = a_new
            g.field("held")[:] = self._held.values
            jets = transfer.grid_jets_to_particles(g, p, order=1)
            transfer.restore_held(g.space, jets[:, 0, :])  # over the functions the step moved
            p["acceleration"][:] = jets[:, 0, g.space.field_slice("a")]
            if self.scheme.transfer != "flip":
                _, affine = transfer.affine_grid_to_particles(g, p, transfer.affine_rule(self.scheme.transfer), jets,
                                                              g.space.field_slice("a"))
                p[transfer.AFFINE_FIELDS[1]][:] = affine

    def quadrature_points(self):
        """The points the step's forms integrate at, after P2G: the particles, and with
        ``Scheme.pressure_quadrature = "gauss"`` the Gauss points of the cells the water reaches
        (:mod:`fempm.pressure_points`)."""
        if self._gauss_points is None:
            return self.particles
        fraction = self.system.fields["smoothed_density"].values[:, 0] / self._reference_density
        return self._gauss_points.points(self.particles, self._gauss_points.wet_cells(fraction))

    def project(self) -> np.ndarray:
        """P2G: grid velocity and acceleration, smoothed density; returns the free dofs.

        One scatter carries mass, momentum, mass-weighted acceleration and particle counts (with
        the particles' affine parts for an affine transfer, :func:`~fempm.transfer.project_state`):
        ``v_i = (m v)_i / m_i``, ``a_i = (m a)_i / m_i``, ``rho~_i = m_i / int N_i dx`` (eq. 2).
        Functions whose support holds less than ``min_support_fraction`` of material are left
        out of the solve and held at rest (v_n = a_n = 0); the pressure also where there is less
        than ``min_pressure_support``, or fewer particles than a third of the functions of a cell
        (a particle fixes at most the value and gradient: three numbers). On the held wall dofs
        v_n and a_n are the walls' own.
        """
        self.region.follow(self.particles)
        p, s, c = self.particles, self.system, self.controls
        p2g = transfer.project_state(p, self.scheme.transfer, self._p2g)
        rho = s.fields["smoothed_density"].values
        transfer.smoothed_density(p2g.field("m"), self._integrals[:, None], out=rho)
        keep = np.empty((s.scalar_space.numbering.num_owned, s.space.bs), dtype=np.bool_)
        _grid_state(p2g.values, *(p2g.space.field_offset(name) for name in ("m", "mv", "ma", "count")), rho[:, 0],
                    self._reference_density, c.min_support_fraction, c.min_pressure_support,
                    -(-self.basis.functions_per_cell // 3), s.fields["grid_velocity"].values,
                    s.fields["grid_acceleration"].values, self._held.values, keep, s.space.field_offset("p"))
        phi = rho[:, 0] / self._reference_density  # the wet fraction (fempm.density)
        if s.constants["by_parts"] or s.constants["split"]:  # the weight of the work by parts, the correction's deep water
            g = self._gravity
            self._deep_water.masks(phi, s.fields["grid_velocity"].values if g > 0 else None, np.sqrt(g * self.grid.h),
                                   out=(s.fields["deep"].values[:, 0], s.fields["by_parts"].values[:, 0]))
            known = s.fields["known_pressure"].values[:, 0]  # what the split takes by parts (fempm.hydrostatic)
            if self._hydrostatic is not None:
                known[:] = self._hydrostatic(phi)
            elif self._last_pressure is not None:
                known[:] = self._last_pressure(p, p2g.field("m")[:, 0], self.fastest() * s.dt / self.grid.h)
        elif s.constants["alpha"] > 0 and self.scheme.surface_aware:  # the volume correction's deep water
            s.fields["deep"].values[:, 0] = self._deep_water(phi)
        s.walls.start_step(keep.ravel(), s.fields["grid_velocity"])  # one-sided walls: this step's held dofs
        s.walls.clear(self._held)  # a wall's motion is a value, not a held function's zero
        # for a solve again with fewer held walls (solve): the material's dofs, v_n and a_n before the walls'
        self._material = keep.ravel().copy()
        self._projected = {name: s.fields[name].values.copy() for name in ("grid_velocity", "grid_acceleration")}
        s.impose_walls()
        return s.free.select(keep.ravel())

    def update(self):
        """G2P: velocity and acceleration (:func:`~fempm.transfer.update_state`), ``x += du``, pressure;
        then the safeguards.

        FLIP adds the grid's change ``v_{n+1} - v_n`` to the particle velocity (likewise the
        acceleration), ``v_n`` as the step used it: on the held wall dofs both are the wall's, so
        the change there is zero (the walls act on the particles through the solve).
        """
        p, s, g = self.particles, self.system, self._g2p
        v_new, a_new = s.end_state()
        _g2p_fields(s.U.values, s.space.field_offset("u"), s.space.field_offset("p"), s.fields["grid_velocity"].values,
                    s.fields["grid_acceleration"].values, v_new, a_new, self._held.values, g.values,
                    *(g.space.field_offset(name) for name in ("du", "dv", "da", "v", "a", "p", "held")))
        sc = self.scheme
        values, divergence = self._particle_room(len(p), g.space.bs)
        share = transfer.pic_share(sc.transfer, sc.pic_blend, sc.pic_rate, s.dt)
        rest = transfer.rest_share(sc.transfer, sc.rest_pic_rate, s.dt, self._gravity, self.grid.h)
        noise = None if self._noise is None else (self._noise, min(1.0, sc.noise_rate * s.dt))
        transfer.update_state(g, p, sc.transfer, share, values, divergence, rest, noise)
        x = p.x
        _move(values, g.space.field_offset("du"), g.space.field_offset("p"), x, p["pressure"])
        p.fields["x"] = s.walls.keep_inside(x)
        if self._shifting:  # the particles spread evenly again (fempm.shifting)
            self._shifting(p, s.dt)
            p.fields["x"] = s.walls.keep_inside(p.x)
        self.max_divergence = collective.largest(self.grid.comm, _largest_magnitude(divergence))
        self.check_pressure(p["pressure"], s.dt)
        if self.check_energy:
            self.check_energy(s.dt)

    def _particle_room(self, n: int, bs: int) -> tuple[np.ndarray, np.ndarray]:
        """Room for G2P's values ``(n, bs)`` and divergences ``(n,)`` at ``n`` particles, kept from step to
        step while the count of particles stays."""
        if len(self._divergence) != n:
            self._values, self._divergence = np.empty((n, bs)), np.empty(n)
        return self._values, self._divergence

    # -- what an adaptive step needs ---------------------------------------------------------
    def fastest(self) -> float:
        """The largest particle speed on all ranks."""
        return diagnostics.fastest(self.particles)

    def pressure_speed(self) -> float:
        """``max sqrt(p / rho)`` over the particles on all ranks."""
        return diagnostics.pressure_speed(self.particles)

    def cell_size(self) -> float:
        """The grid's cell size."""
        return self.grid.h

    def clock_state(self) -> dict:
        """The clock's, the energy watch's start and lowest energy, the walls' active set, and the
        pattern the linear solver keeps (:meth:`fempm.linear.LinearSolver.pattern_seed`)."""
        watch = self.check_energy
        return {**super().clock_state(), "energy": [watch.start, watch.lowest] if watch else None,
                **self.walls.contact_state(), "solve_pattern": self.system.linear_solver.pattern_seed()}

    def restore_clock(self, state: dict):
        """Continue from a :meth:`clock_state`."""
        super().restore_clock(state)
        self.walls.restore_contact(state)
        self.system.linear_solver.restore_pattern(state.get("solve_pattern"))
        if self.check_energy and state.get("energy"):
            self.check_energy.start, self.check_energy.lowest = state["energy"]

    def resume_point(self):
        """After a checkpoint the linear solver is set up afresh at its next solve, as a resumed run's is."""
        self.system.linear_solver.renew_preconditioner()

    def save(self):
        """The particles, the walls' stop count and the energy watch's lowest energy."""
        return (self.particles.state(), self.walls.stops, self.check_energy.lowest if self.check_energy else None,
                (self.walls.active.copy(), self.walls.wet.copy()))

    def restore(self, saved):
        """Back to a :meth:`save`."""
        particles, self.walls.stops, lowest, (active, wet) = saved
        self.particles.restore(particles)
        self.walls.active, self.walls.wet = active.copy(), wet.copy()
        if self.check_energy:
            self.check_energy.lowest = lowest

    # -- safeguards ------------------------------------------------------------------------
    def _pressure_check(self) -> PressureCheck:
        """A tension above the pressure limit (the sign-alternating pressure of an unstable step)
        or a compression above it plus an impact's (:func:`~fempm.safeguards.impact_impulse` over
        the step) stops the run. Default limit: 20 rho g times the grid's height."""
        grid = self.grid
        limit = self.controls.pressure_limit or 20 * 1000.0 * 9.81 * (grid.upper[1] - grid.lower[1])
        extent = float(np.linalg.norm(grid.upper - grid.lower))
        impulse = impact_impulse(self._reference_density, self.fastest(), self.physics.gravity, extent)
        return PressureCheck(grid.comm, limit, limit, impulse)

    def _energy_watch(self) -> EnergyWatch | None:
        """The energy check, where it applies: a limit set, a closed box, walls at rest, no recycling,
        some energy to start from."""
        ph, limit = self.physics, self.controls.energy_gain_limit
        if limit is None or not ph.closed or ph.wall_speeds or ph.recycle:
            return None
        watch = EnergyWatch(self.particles, ph.gravity, limit)
        return watch if watch.start > 0 else None
