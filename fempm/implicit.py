"""The implicit MPM time step of method.md: one monolithic (du, p) solve per step.

One step, as named phases::

    project   particles -> grid: velocity, acceleration (mass-weighted), smoothed density,
              which functions carry material, which dofs are free
    assemble  residual R(U) and Jacobian dR/dU of forms/incompressible.py at the particles
    solve     Newton on R(U) = 0 (one iteration when R is affine in U), PETSc (MUMPS LU)
    update    grid -> particles: FLIP (optionally blended with PIC) velocity and
              acceleration, positions advanced by the displacement increment, pressure
    relocate  particles to their new cells and ranks

The forms come from a file (``forms/incompressible.py`` by default) loaded at start,
compiled once, and re-assembled every step with the new particle data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import ufl
import ufl.algorithms
from mpi4py import MPI

from fempm import diagnostics, transfer
from fempm.bases import Basis
from fempm.errors import InputError, ParticleOutsideGridError, SimulationDiverged
from fempm.formsfile import load_forms
from fempm.linear import LinearSolver, SolveFailed
from fempm.matrix import GridMatrix
from fempm.particles import Particles
from fempm.quadrature import ParticleForm
from fempm.space import GridFunction, Space
from fempm.timing import PhaseTimes

__all__ = ["FLUID_REGION_CELLS", "ImplicitOptions", "ImplicitSolver", "SimulationDiverged", "dilate"]

#: Grids with more cells than this keep matrix rows only near the water (``matrix_region="auto"``).
FLUID_REGION_CELLS = 100_000

WALLS = ("slip", "no-slip", "outflow", "open")
SIDES = ("left", "right", "bottom", "top")


@dataclass
class ImplicitOptions:
    """Parameters of the implicit scheme (SI units).

    Attributes:
        dt: time step.
        beta, gamma: Newmark parameters (1/4, 1/2: the trapezoidal rule).
        viscosity: dynamic viscosity mu.
        gravity: body acceleration.
        alpha: volume-correction factor of method.md eq. (3), 0 <= alpha <= 1 (0: off).
        pspg: PSPG stabilisation on (method.md: without it the run diverges).
        pic_blend: 0 = pure FLIP, 1 = pure PIC, in between a blend of the two. Default
            0.1: with pure FLIP a Q1 column at rest grew a velocity mode by ~7 % per step
            (0.8 m/s after 1 s); with 5 % PIC the B-spline column kept 1.2e-3 m/s of
            surface motion after 1 s, with 10 % 8e-4 m/s.
        walls: the condition on the four sides, one of :data:`WALLS` for all, or a mapping
            of side (``left``, ``right``, ``bottom``, ``top``) to one (sides not named are
            slip): ``"slip"`` (zero normal velocity), ``"no-slip"`` (zero velocity),
            ``"outflow"`` (zero tangential velocity, normal traction free: the end of a
            channel whose flow is fully developed there, ``u_t = 0`` and
            ``-p + 2 mu du_n/dn = 0``, as plane Poiseuille and Couette flows are) or
            ``"open"`` (nothing held, traction-free: a free surface on a fixed grid).
            Material that crosses an outflow or open side leaves the grid (the run stops,
            unless ``recycle``). Cells blocked by obstacles (``Grid.block``) are no-slip:
            every function non-zero in one has its velocity held at zero.
        recycle: with outflow on the left and right, a particle leaving through one of them
            re-enters through the other at the same height, with all its fields: an endless
            channel of material on a grid that is not periodic (the ends of a fully
            developed channel flow, which the outflow condition holds exactly).
        wall_speeds: tangential speed of moving no-slip walls by side (m/s), along +x on
            the bottom and top, along +y on the left and right; e.g. ``{"top": 1.0}`` for a
            lid-driven cavity. The functions a moving wall shares with a side at rest (the
            corners) stay at rest.
        newton_rtol, newton_max_it: Newton stops when ||R|| <= rtol ||R_0||.
        min_support_fraction: basis functions whose support holds less material than this
            fraction of ``rho * int N_i dx`` are left out of the solve (held at rest: du, v_n
            and a_n zero): they would only add near-singular rows.
        min_pressure_support: the pressure of functions with less material than this
            fraction, or fewer particles in their support than functions per cell, is
            held at zero: the free-surface condition p = 0 where a function barely
            touches water (splashes, the edge of the surface), whose pressure the few
            particles there leave undetermined (after Kularathna & Soga 2017).
        matrix_region: ``"grid"``: the matrix has a row for every function of the grid (its
            sparsity never changes); ``"fluid"``: rows only near the water (the cells
            holding particles, widened by a margin), rebuilt when the water leaves them,
            so memory follows the fluid, not the tank; ``"auto"``: fluid above
            :data:`FLUID_REGION_CELLS` cells.
        pressure_limit: a step whose tension ``-p`` exceeds this (Pa), or whose pressure
            exceeds it by more than an impact's (``ImplicitSolver.impact_pressure``), is taken
            as diverged (pressure oscillation); default 20 rho g times the grid height.
        energy_gain_limit: a step after which the mechanical energy
            (:func:`fempm.diagnostics.mechanical_energy`) stands more than this fraction of its
            starting value above its lowest value so far is taken as diverged ("energy
            growth": gravity and walls at rest only take energy away, so a gain is the scheme
            injecting it, the "eruption" of a too large step). Measured: at 10 times the seed's
            step the dam break gains at most 8 % (particles stopped at a wall keep their
            speed), at 20 times 109 %. Not checked where walls slide, material is recycled or
            a side is open, nor with ``None``.
        forms: file of the weak forms (default ``forms/incompressible.py``).
        petsc_options: PETSc options under the prefix ``fempm_``.
    """

    dt: float = 1.0e-3
    beta: float = 0.25
    gamma: float = 0.5
    viscosity: float = 1.0e-3
    gravity: tuple[float, float] = (0.0, -9.81)
    alpha: float = 0.1
    pspg: bool = True
    pic_blend: float = 0.1
    walls: str | dict = "slip"
    wall_speeds: dict = field(default_factory=dict)
    recycle: bool = False
    newton_rtol: float = 1e-8
    newton_max_it: int = 8
    pressure_limit: float | None = None
    energy_gain_limit: float | None = 0.25
    min_support_fraction: float = 1e-3
    min_pressure_support: float = 0.05
    matrix_region: str = "auto"
    forms: str | Path = "incompressible"
    petsc_options: dict = field(default_factory=dict)

    def check(self):
        """Raise :class:`InputError` naming the first unacceptable option."""
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise InputError(f"dt must be positive, got {self.dt}")
        if not 0 <= self.alpha <= 1:
            raise InputError(f"alpha (volume correction) must be in [0, 1], got {self.alpha}")
        if not 0 <= self.pic_blend <= 1:
            raise InputError(f"pic_blend must be in [0, 1], got {self.pic_blend}")
        if self.viscosity < 0:
            raise InputError(f"viscosity must be >= 0, got {self.viscosity}")
        for side, kind in self.wall_conditions().items():
            if side not in SIDES:
                raise InputError(f"walls: unknown side {side!r}; the sides are {SIDES}")
            if kind not in WALLS:
                raise InputError(f"walls.{side} must be one of {WALLS}, got {kind!r}")
        if self.recycle and {self.wall_conditions()[s] for s in ("left", "right")} != {"outflow"}:
            raise InputError("recycle needs outflow on the left and the right, got "
                             f"{self.wall_conditions()['left']!r} and {self.wall_conditions()['right']!r}")
        for side, speed in self.wall_speeds.items():
            if self.wall_conditions().get(side) != "no-slip":
                raise InputError(f"wall_speeds.{side}: only a no-slip side can move, but {side!r} is "
                                 f"{self.wall_conditions().get(side, 'not a side')!r}")
            if not np.isfinite(speed):
                raise InputError(f"wall_speeds.{side} must be a finite speed, got {speed}")
        if self.energy_gain_limit is not None and not self.energy_gain_limit > 0:
            raise InputError(f"energy_gain_limit must be positive or None, got {self.energy_gain_limit}")
        if not (0 < self.beta <= 0.5 and 0 < self.gamma <= 1):
            raise InputError(f"Newmark needs 0 < beta <= 1/2 and 0 < gamma <= 1, got {self.beta}, {self.gamma}")
        if self.matrix_region not in ("grid", "fluid", "auto"):
            raise InputError(f"matrix_region must be 'grid', 'fluid' or 'auto', got {self.matrix_region!r}")

    def wall_conditions(self) -> dict[str, str]:
        """The condition on each side, ``{"left": "slip", ...}``."""
        if isinstance(self.walls, str):
            return dict.fromkeys(SIDES, self.walls)
        return {**dict.fromkeys(SIDES, "slip"), **self.walls}


class ImplicitSolver:
    """Advances particles of an incompressible viscous fluid by the implicit MPM.

    Args:
        basis: the grid basis (``fempm.BSpline2`` as in the seed, or ``fempm.Q1``).
        particles: the fluid (fields ``density``, ``velocity``, ``acceleration``);
            a ``pressure`` field is added.
        options: :class:`ImplicitOptions`.

    The step's phases are methods (:meth:`project`, :meth:`solve`, :meth:`update`,
    :meth:`relocate`) and the forms are compiled by :meth:`_form`, so that a variant
    on a fixed grid (:class:`fempm.eulerian.EulerianSolver`) shares all the rest.
    """

    def __init__(self, basis: Basis, particles: Particles, options: ImplicitOptions | None = None):
        self.particles = particles
        if "pressure" not in particles.fields:
            particles.add_field("pressure")
        self._setup(basis, options or ImplicitOptions(), convection=0.0)
        # everything G2P needs, side by side: du, dv, da, v_{n+1}, a_{n+1}, p
        self._g2p = GridFunction(Space(basis, {"du": 2, "dv": 2, "da": 2, "v": 2, "a": 2, "p": 1}), "g2p")
        self._p2g = GridFunction(Space(basis, {"m": 1, "mv": 2, "ma": 2, "count": 1}), "p2g")
        self._reference_density = self.comm.allreduce(particles["density"].max(initial=0.0), op=MPI.MAX)
        self._integrals = _normalisation(basis, particles)[self.scalar_space.numbering.local_functions]
        self.impact_pressure = self._impact_pressure()
        self._datum = diagnostics.lowest_corner(self.grid, self.options.gravity)
        self._lowest_energy = self._start_energy = diagnostics.mechanical_energy(particles, self.options.gravity,
                                                                                  self._datum)
        self._energy_watch = self._watches_energy()
        self._compile_forms()

    def _setup(self, basis: Basis, options: ImplicitOptions, convection: float):
        """What every variant of the step holds: spaces, grid functions, constants, the linear
        solver, the wall constraints. ``convection`` is the constant of the convective term
        (0: left out of the forms)."""
        options.check()
        self.options = options
        self.basis, self.grid = basis, basis.grid
        self.comm = self.grid.comm
        self.space = Space(basis, {"u": 2, "p": 1})
        self.vector_space = Space(basis, {"v": 2})
        self.scalar_space = Space(basis, {"m": 1})
        self.U = GridFunction(self.space, "U")
        self.velocity = GridFunction(self.vector_space, "velocity")  # v_{n+1} of the last step
        self._pressure = GridFunction(self.scalar_space, "pressure")
        self.max_divergence = 0.0
        self.wall_stops = 0  # particle displacements cut at a wall (see _inside_walls)
        self.region_rebuilds = 0  # times the matrix's region was widened (matrix_region)
        self.grid_fields = {
            "U": self.U,
            "grid_velocity": GridFunction(self.vector_space, "grid_velocity"),
            "grid_acceleration": GridFunction(self.vector_space, "grid_acceleration"),
            "smoothed_density": GridFunction(self.scalar_space, "smoothed_density"),
        }
        self.constants = {
            "dt": options.dt, "beta": options.beta, "gamma": options.gamma,
            "mu": options.viscosity, "gravity": np.asarray(options.gravity, dtype=float),
            "alpha": options.alpha, "pspg": float(options.pspg), "convection": float(convection),
        }
        self._region = None  # cells with matrix rows (None: all), see matrix_region
        self._fluid_region = self.particles is not None and (options.matrix_region == "fluid" or (
            options.matrix_region == "auto" and self.grid.num_cells > FLUID_REGION_CELLS))
        self.J = self._matrix_for(self.particles)
        self.linear_solver = LinearSolver(self.comm, "fempm_", options.petsc_options, fields=self.space.fields)
        self.time = 0.0
        self.steps = 0
        self.newton_iterations = 0
        self.timings = PhaseTimes()  # wall seconds by phase
        self.pressure_limit = options.pressure_limit or 20 * 1000.0 * 9.81 * (
            self.grid.upper[1] - self.grid.lower[1])
        self.impact_pressure = 0.0  # compression allowed beyond pressure_limit (see _check_pressure)
        self._R = self.space.create_vector()
        self._delta = self.J.createVecLeft()
        held, values = self._walls()
        owned_dofs = self.space.local_to_global[: self.space.num_owned_dofs]
        self._wall_positions = np.searchsorted(owned_dofs, held)
        self._wall_values = values
        bs = self.space.bs  # the same dofs in the velocity grid functions (two per function)
        self._wall_vector_index = self._wall_positions // bs * 2 + self._wall_positions % bs
        self._closed = not {"outflow", "open"} & set(options.wall_conditions().values())
        corner = self.space.numbering.local_index[0]  # the lower-left function, where a closed box pins p
        owns_corner = 0 <= corner < self.space.numbering.num_owned
        self._pin_position = corner * bs + self.space.field_offset("p") if owns_corner else None

    def _compile_forms(self):
        """Compile the residual of the forms file and its Jacobian, once (see :meth:`_form`)."""
        forms = load_forms(self.options.forms, required=("residual",))
        self.residual_form = self._form(forms.residual)
        self.jacobian_form = self._form(lambda s: ufl.derivative(forms.residual(s), s.grid("U")))
        unknown = next(c for c, (kind, name) in self.jacobian_form.symbols.used.items() if name == "U")
        expanded = ufl.algorithms.expand_derivatives(self.jacobian_form.ufl_form)
        self.linear = unknown not in expanded.coefficients()  # R affine in U: one Newton step

    def _form(self, builder):
        """A form integrated at the particles (:class:`ParticleForm`)."""
        return ParticleForm(builder, self.space, particle_shapes=self.particles, grid_functions=self.grid_fields,
                            constants=self.constants)

    # -- one step ------------------------------------------------------------------------
    def step(self):
        """Advance by one time step (raises :class:`SimulationDiverged`)."""
        try:
            with self.timings("project"):
                free = self.project()
            self.solve(free)
            with self.timings("update"):
                self.update()
            with self.timings("relocate"):
                self.relocate()
        except SolveFailed as e:
            raise SimulationDiverged(self.time + self.options.dt, self.steps + 1, str(e)) from None
        except ParticleOutsideGridError as e:
            raise SimulationDiverged(self.time + self.options.dt, self.steps + 1, str(e)) from None
        self.time += self.options.dt
        self.steps += 1

    # -- phases ------------------------------------------------------------------------
    def _matrix_for(self, particles):
        """The Jacobian's matrix: on the whole grid, or on the water's cells widened by a margin."""
        if not self._fluid_region:
            return self.space.create_matrix()
        occupied = np.zeros(self.grid.num_cells, dtype=bool)
        occupied[particles.cell] = True
        self.comm.Allreduce(MPI.IN_PLACE, occupied, op=MPI.LOR)
        margin = max(2 * (self.basis.degree + 1), int(np.ceil(0.05 * max(self.grid.nx, self.grid.ny))))
        self._region = dilate(occupied.reshape(self.grid.ny, self.grid.nx), margin).ravel()
        return GridMatrix(self.space, self._region).mat

    def _keep_region(self):
        """Widen the matrix's region if the water has left it (on every rank alike)."""
        if self._region is None:
            return
        outside = bool(np.any(~self._region[self.particles.cell]))
        if self.comm.allreduce(outside, op=MPI.LOR):
            self.J = self._matrix_for(self.particles)
            self._delta = self.J.createVecLeft()
            self.region_rebuilds += 1

    def project(self) -> np.ndarray:
        """P2G: grid velocity and acceleration, smoothed density; returns the free dofs.

        One scatter carries mass, momentum, mass-weighted acceleration and particle
        counts: ``m_i``, ``v_i = (m v)_i / m_i``, ``a_i = (m a)_i / m_i``,
        ``rho~_i = m_i / int N_i dx`` (eq. 2). At the held wall dofs v_n and a_n are then
        the wall's (see :meth:`_impose_walls`), on the functions left out of the solve zero.
        """
        self._keep_region()
        p = self.particles
        mass = p["mass"][:, None]
        sums = transfer.particles_to_grid(
            self._p2g.space, p, np.hstack([mass, mass * p["velocity"], mass * p["acceleration"]]),
            counts=True, out=self._p2g).values
        m = sums[:, :1]
        rho = self.grid_fields["smoothed_density"]
        rho.values[:] = m / self._integrals[:, None]
        # functions whose support holds less than a fraction of material are left out of the
        # solve, held at rest: v_n = a_n = 0 there too (with the projected v_n kept, Newmark gave
        # them v_{n+1} = -v_n and FLIP dragged the particles near them: a lone particle fell at
        # 0.78 g); the pressure also where a particle fixes at most three numbers (value,
        # gradient) and there are fewer than a third as many particles as a cell has functions
        fraction = rho.values / self._reference_density
        moving = (m > 0) & (fraction >= self.options.min_support_fraction)
        safe = np.where(moving, m, 1.0)
        self.grid_fields["grid_velocity"].values[:] = np.where(moving, sums[:, 1:3] / safe, 0.0)
        self.grid_fields["grid_acceleration"].values[:] = np.where(moving, sums[:, 3:5] / safe, 0.0)
        self._impose_walls()
        owned = self.scalar_space.numbering.num_owned
        fraction = fraction[:owned, 0]
        keep = np.repeat(fraction >= self.options.min_support_fraction, self.space.bs)
        enough = sums[:owned, 5] >= -(-self.basis.functions_per_cell // 3)
        keep.reshape(-1, self.space.bs)[:, 2] &= (fraction >= self.options.min_pressure_support) & enough
        return self._free_dofs(keep)

    def _impose_walls(self):
        """The grid's v_n and a_n at the held wall dofs: the wall's velocity and zero.

        With ``du = dt v_wall`` held there (:meth:`solve`), Newmark then gives
        ``v_{n+1} = v_wall`` and ``a_{n+1} = 0`` on the wall: the wall's own motion, at rest
        or sliding. (With the projected v_n kept, a wall at rest had ``v_{n+1} = -v_n``
        there under the trapezoidal rule.)
        """
        for name, values in (("grid_velocity", self._wall_values), ("grid_acceleration", 0.0)):
            gf = self.grid_fields[name]
            gf.vector.array[self._wall_vector_index] = values
            gf.scatter_forward()

    def _free_dofs(self, keep: np.ndarray) -> np.ndarray:
        """The owned dofs to solve for: those kept, less the walls; in a closed box whose
        pressure nothing fixes (no side outflow or open, no pressure held at zero) also less the
        pressure of the lower-left function, pinned at zero (p is defined up to a constant)."""
        keep[self._wall_positions] = False
        if self._closed:
            pressure_held = np.count_nonzero(~keep.reshape(-1, self.space.bs)[:, self.space.field_offset("p")])
            if self.comm.allreduce(pressure_held) == 0 and self._pin_position is not None:
                keep[self._pin_position] = False
        self._free_mask = keep
        return self.space.local_to_global[: self.space.num_owned_dofs][keep]

    def solve(self, free: np.ndarray):
        """Newton's method on R(U) = 0 over the free dofs, starting from U = 0 (and the wall
        displacement ``dt v_wall`` on the held wall dofs, which the corrections leave alone).

        When R is affine in U (the shipped forms) one iteration solves it exactly and
        no second residual is assembled.
        """
        U = self.U.vector
        U.array[:] = 0.0
        U.array[self._wall_positions] = self.options.dt * self._wall_values
        U.scatter_forward()
        r0 = norm = None
        for iteration in range(self.options.newton_max_it):
            with self.timings("assemble"):
                R = self.residual_form.assemble_vector(self.particles, self._R)
                if not self.linear:
                    norm = self._free_norm(R)
                    r0 = norm if r0 is None else r0
                    if iteration > 0 and norm <= self.options.newton_rtol * max(r0, 1e-300):
                        break
                J = self.jacobian_form.assemble_matrix(self.particles, self.J)
            with self.timings("solve"):
                R.petsc_vec.scale(-1.0)
                delta = self.linear_solver.solve(J, R.petsc_vec, free, self._delta)
                U.array[: self.space.num_owned_dofs] += delta.getArray(readonly=True)
                U.scatter_forward()
            self.newton_iterations += 1
            if not np.all(np.isfinite(U.array)):
                raise SolveFailed("the solution is not finite")
            if self.linear:
                break
        else:
            raise SolveFailed(f"Newton did not converge in {self.options.newton_max_it} iterations "
                              f"(|R| = {norm:.3e}, |R0| = {r0:.3e})")

    def _free_norm(self, R) -> float:
        local = R.array[: self.space.num_owned_dofs][self._free_mask]
        return float(np.sqrt(self.comm.allreduce(np.dot(local, local))))

    def _newmark(self) -> tuple[np.ndarray, np.ndarray]:
        """``v_{n+1}`` and ``a_{n+1}`` on the grid from the solved ``du`` (Newmark); keeps v_{n+1}."""
        o = self.options
        du = self.U.field("u")
        v, a = self.grid_fields["grid_velocity"].values, self.grid_fields["grid_acceleration"].values
        a_new = (du - o.dt * v - o.dt**2 * (0.5 - o.beta) * a) / (o.beta * o.dt**2)
        v_new = v + o.dt * ((1 - o.gamma) * a + o.gamma * a_new)
        self.velocity.values[:] = v_new
        return v_new, a_new

    def update(self):
        """G2P: FLIP (or FLIP/PIC blend) velocity and acceleration, x += du, particle pressure.

        FLIP adds the grid's change ``v_{n+1} - v_n`` to the particle velocity
        (likewise for the acceleration), ``v_n`` as the step used it: on the held wall
        dofs both are the wall's, so the change there is zero (the walls act on the
        particles through the solve). PIC takes ``v_{n+1}`` itself, the walls' included.
        """
        o, p = self.options, self.particles
        g = self._g2p.values
        v_new, a_new = self._newmark()
        v, a = self.grid_fields["grid_velocity"].values, self.grid_fields["grid_acceleration"].values
        g[:, 0:2], g[:, 2:4], g[:, 4:6] = self.U.field("u"), v_new - v, a_new - a
        g[:, 6:8], g[:, 8:10], g[:, 10] = v_new, a_new, self.U.field("p")[:, 0]
        jets = transfer.grid_jets_to_particles(self._g2p, p, order=1)
        values = jets[:, 0]
        k = o.pic_blend
        p["velocity"][:] = (1 - k) * (p["velocity"] + values[:, 2:4]) + k * values[:, 6:8]
        p["acceleration"][:] = (1 - k) * (p["acceleration"] + values[:, 4:6]) + k * values[:, 8:10]
        p["pressure"][:] = values[:, 10]
        p.fields["x"] = self._inside_walls(p.x + values[:, 0:2])
        divergence = (jets[:, 1, 6] + jets[:, 2, 7]) / self.grid.h
        self.max_divergence = self.comm.allreduce(float(np.abs(divergence).max(initial=0.0)), op=MPI.MAX)
        self._check_pressure(p["pressure"])
        if self._energy_watch:
            self._check_energy()

    def _watches_energy(self) -> bool:
        """Whether :meth:`_check_energy` applies: a limit set, a closed box, walls at rest, no recycling."""
        o = self.options
        return (o.energy_gain_limit is not None and self._closed and not o.wall_speeds and not o.recycle
                and self._start_energy > 0)

    def _check_energy(self):
        """Stop (:class:`SolveFailed`) when the mechanical energy has grown by more than
        ``energy_gain_limit`` times its starting value above its lowest so far."""
        energy = diagnostics.mechanical_energy(self.particles, self.options.gravity, self._datum)
        self._lowest_energy = min(self._lowest_energy, energy)
        gain = (energy - self._lowest_energy) / self._start_energy
        if gain > self.options.energy_gain_limit:
            largest = self.comm.allreduce(float(np.linalg.norm(self.particles["velocity"], axis=1).max(initial=0.0)),
                                          op=MPI.MAX)
            raise SolveFailed(f"energy growth: the mechanical energy rose by {100 * gain:.0f} % of its start, "
                              f"which gravity and walls at rest cannot give; the step is too large for the flow "
                              f"(fastest particle {largest:.3g} m/s, {largest * self.options.dt / self.grid.h:.1f} "
                              f"cells per step)")

    def _impact_pressure(self) -> float:
        """``rho U D / dt``: the pressure of water stopped by a wall within one step.

        An incompressible fluid meeting a wall at the speed U takes a pressure impulse
        ``int p dt ~ rho U L``, L the length of the water behind the impact (Cooker &
        Peregrine 1995), all of it within the step that stops it. Bounds: U the fastest
        particle's starting speed plus a free fall through the grid's diagonal D, L <= D.
        """
        p = self.particles
        start = self.comm.allreduce(float(np.linalg.norm(p["velocity"], axis=1).max(initial=0.0)), op=MPI.MAX)
        diagonal = float(np.linalg.norm(self.grid.upper - self.grid.lower))
        fall = np.sqrt(2 * np.linalg.norm(self.options.gravity) * diagonal)
        return self._reference_density * (start + fall) * diagonal / self.options.dt

    def _check_pressure(self, pressure: np.ndarray):
        """Stop (:class:`SolveFailed`) on a pressure that is not finite or beyond the limits: a
        tension above ``pressure_limit`` (the sign-alternating pressure of an unstable step:
        without PSPG, -1.3e5 Pa in the dam break at t = 0.17 s), or a compression above it
        plus :attr:`impact_pressure` (water thrown into a corner at 3 m/s met it with up to
        3.2e5 Pa, single-signed, at dt = 1e-3 s, and ran on)."""
        low = self.comm.allreduce(float(pressure.min(initial=0.0)), op=MPI.MIN)
        high = self.comm.allreduce(float(pressure.max(initial=0.0)), op=MPI.MAX)
        if not np.isfinite(low + high):
            raise SolveFailed("the pressure is not finite")
        if -low > self.pressure_limit:
            raise SolveFailed(f"pressure oscillation: p reached {low:.3g} Pa, a tension beyond the limit "
                              f"{self.pressure_limit:.3g} Pa")
        if high > self.pressure_limit + self.impact_pressure:
            raise SolveFailed(f"pressure oscillation: p reached {high:.3g} Pa, above the limit "
                              f"{self.pressure_limit + self.impact_pressure:.3g} Pa (of which an impact's "
                              f"{self.impact_pressure:.3g} Pa)")

    def relocate(self):
        """The particles to their new cells and ranks."""
        self.particles.relocate()

    def _inside_walls(self, x: np.ndarray) -> np.ndarray:
        """Stop at the wall a particle whose displacement would carry it through one; with
        ``recycle``, bring a particle that left through the left or right side in through the
        other.

        The walls are impermeable; the interpolated displacement of a cell next to a wall
        cannot decelerate within the cell, so at large steps or hard impacts it may take a
        particle a little past the wall. Counted in ``wall_stops``. NaN stays NaN. Outflow
        and open sides are no walls: material crossing them leaves the grid.
        """
        if self.options.recycle:
            x[:, 0] = self.grid.lower[0] + np.mod(x[:, 0] - self.grid.lower[0], self.grid.upper[0] - self.grid.lower[0])
        margin = 1e-9 * self.grid.h
        low, high = self.grid.lower + margin, self.grid.upper - margin
        walls = self.options.wall_conditions()
        impermeable = lambda side: walls[side] in ("slip", "no-slip")  # noqa: E731
        low = np.where([impermeable("left"), impermeable("bottom")], low, -np.inf)
        high = np.where([impermeable("right"), impermeable("top")], high, np.inf)
        outside = np.any((x < low) | (x > high), axis=1)
        if np.any(outside):
            self.wall_stops += int(outside.sum())
            x = np.clip(x, low, high)
        return x

    @property
    def pressure(self) -> GridFunction:
        """The pressure of the last step on the grid."""
        self._pressure.values[:] = self.U.field("p")
        return self._pressure

    # -- helpers -----------------------------------------------------------------------
    def _walls(self) -> tuple[np.ndarray, np.ndarray]:
        """Global numbers of the owned velocity dofs held (on the walls: the normal component,
        or both; on obstacles) and the velocity held on each: zero, or a moving wall's speed
        on its tangential component where no side at rest holds the same dof."""
        held = [self.space.cell_dofs("u", np.flatnonzero(self.grid.blocked))]
        moving, speeds = [], []
        for side, kind in self.options.wall_conditions().items():
            normal = 0 if side in ("left", "right") else 1
            components = {"slip": (normal,), "no-slip": (0, 1), "outflow": (1 - normal,), "open": ()}[kind]
            for component in components:
                dofs = self.space.wall_dofs("u", component, side[0])
                if component != normal and side in self.options.wall_speeds:
                    moving.append(dofs)
                    speeds.append(np.full(len(dofs), float(self.options.wall_speeds[side])))
                else:
                    held.append(dofs)
        at_rest = np.unique(np.concatenate(held))
        moving, speeds = (np.concatenate(a) if a else np.zeros(0) for a in (moving, speeds))
        moving, first = np.unique(moving, return_index=True)  # two moving sides meet: the first named
        speeds = speeds[first]
        sliding = ~np.isin(moving, at_rest)
        dofs = np.concatenate([at_rest, moving[sliding]]).astype(np.int64)
        values = np.concatenate([np.zeros(len(at_rest)), speeds[sliding]])
        order = np.argsort(dofs, kind="stable")
        return dofs[order], values[order]


def dilate(mask: np.ndarray, margin: int) -> np.ndarray:
    """A 2-D boolean mask grown by ``margin`` cells in every direction (a square neighbourhood)."""
    out = mask
    for axis in (0, 1):
        padded = np.concatenate([np.zeros_like(out.take([0], axis=axis)).repeat(margin, axis=axis), out,
                                 np.zeros_like(out.take([0], axis=axis)).repeat(margin, axis=axis)], axis=axis)
        total = np.cumsum(padded, axis=axis, dtype=np.int64)
        total = np.concatenate([np.zeros_like(total.take([0], axis=axis)), total], axis=axis)
        n = out.shape[axis]
        window = total.take(np.arange(n) + 2 * margin + 1, axis=axis) - total.take(np.arange(n), axis=axis)
        out = window > 0
    return out


def _normalisation(basis: Basis, particles: Particles) -> np.ndarray:
    """``int N_i dx`` of eq. (2): by the seeding rule when all particles come from one lattice."""
    comm = basis.grid.comm
    volumes = particles["volume"]
    v_min = comm.allreduce(float(volumes.min(initial=np.inf)), op=MPI.MIN)
    v_max = comm.allreduce(float(volumes.max(initial=0.0)), op=MPI.MAX)
    side = basis.grid.h / np.sqrt(v_max) if v_max > 0 else 0.0
    if v_max > 0 and v_min == v_max and abs(side - round(side)) < 1e-9:
        return basis.lattice_integrals(int(round(side)))
    return basis.integrals


