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

import time
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import ufl
import ufl.algorithms
from mpi4py import MPI

from fempm import transfer
from fempm.bases import Basis
from fempm.errors import FempmError, InputError, ParticleOutsideGridError
from fempm.formsfile import load_forms
from fempm.linear import LinearSolver, SolveFailed
from fempm.particles import Particles
from fempm.quadrature import ParticleForm
from fempm.space import GridFunction, Space

__all__ = ["ImplicitOptions", "ImplicitSolver", "SimulationDiverged"]

WALLS = ("slip", "no-slip")
SIDES = ("left", "right", "bottom", "top")


class SimulationDiverged(FempmError):
    """The run cannot go on; ``time``, ``step`` and ``cause`` say when and why."""

    def __init__(self, time: float, step: int, cause: str):
        super().__init__(f"stopped at t = {time:.6g} s (step {step}): {cause}")
        self.time, self.step, self.cause = time, step, cause


@dataclass
class ImplicitOptions:
    """Parameters of the implicit scheme (SI units).

    Attributes:
        dt: time step.
        beta, gamma: Newmark parameters (1/4, 1/2: the trapezoidal rule).
        viscosity: dynamic viscosity mu.
        gravity: body acceleration.
        alpha: volume-correction factor of method.md eq. (3), 0 <= alpha <= 1 (0: off).
        bulk_modulus: K of the fluid (Pa), enters as 1/K (``inf``: strictly incompressible).
        pspg: PSPG stabilisation on (method.md: without it the run diverges).
        pic_blend: 0 = pure FLIP, 1 = pure PIC, in between a blend of the two.
        walls: ``"slip"`` (zero normal velocity) or ``"no-slip"`` on the four walls, or a
            mapping of side (``left``, ``right``, ``bottom``, ``top``) to one of them
            (sides not named are slip). Cells blocked by obstacles (``Grid.block``) are
            no-slip: every function non-zero in one has its velocity held at zero.
        newton_rtol, newton_max_it: Newton stops when ||R|| <= rtol ||R_0||.
        min_support_fraction: basis functions whose support holds less material than this
            fraction of ``rho * int N_i dx`` are left out of the solve (their dofs held at
            zero): they would only add near-singular rows.
        pressure_limit: a step whose |p| exceeds this (Pa) is taken as diverged
            (pressure oscillation); default 20 rho g times the grid height.
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
    bulk_modulus: float = 2.2e9
    pic_blend: float = 0.0
    walls: str | dict = "slip"
    newton_rtol: float = 1e-8
    newton_max_it: int = 8
    pressure_limit: float | None = None
    min_support_fraction: float = 1e-3
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
        if not self.bulk_modulus > 0:
            raise InputError(f"bulk_modulus must be positive (inf for none), got {self.bulk_modulus}")
        if self.viscosity < 0:
            raise InputError(f"viscosity must be >= 0, got {self.viscosity}")
        for side, kind in self.wall_conditions().items():
            if side not in SIDES:
                raise InputError(f"walls: unknown side {side!r}; the sides are {SIDES}")
            if kind not in WALLS:
                raise InputError(f"walls.{side} must be one of {WALLS}, got {kind!r}")
        if not (0 < self.beta <= 0.5 and 0 < self.gamma <= 1):
            raise InputError(f"Newmark needs 0 < beta <= 1/2 and 0 < gamma <= 1, got {self.beta}, {self.gamma}")

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
    """

    def __init__(self, basis: Basis, particles: Particles, options: ImplicitOptions | None = None):
        self.options = options = options or ImplicitOptions()
        options.check()
        self.basis, self.particles, self.grid = basis, particles, basis.grid
        self.comm = self.grid.comm
        if "pressure" not in particles.fields:
            particles.add_field("pressure")
        self.space = Space(basis, {"u": 2, "p": 1})
        self.vector_space = Space(basis, {"v": 2})
        self.scalar_space = Space(basis, {"m": 1})
        self.U = GridFunction(self.space, "U")
        self.velocity = GridFunction(self.vector_space, "velocity")  # v_{n+1} of the last step
        self._pressure = GridFunction(self.scalar_space, "pressure")
        # everything G2P needs, side by side: du, dv, da, v_{n+1}, a_{n+1}, p
        self._g2p = GridFunction(Space(basis, {"du": 2, "dv": 2, "da": 2, "v": 2, "a": 2, "p": 1}), "g2p")
        self.max_divergence = 0.0
        self.grid_fields = {
            "U": self.U,
            "grid_velocity": GridFunction(self.vector_space, "grid_velocity"),
            "grid_acceleration": GridFunction(self.vector_space, "grid_acceleration"),
            "smoothed_density": GridFunction(self.scalar_space, "smoothed_density"),
        }
        self.constants = {
            "dt": options.dt, "beta": options.beta, "gamma": options.gamma,
            "mu": options.viscosity, "gravity": np.asarray(options.gravity, dtype=float),
            "alpha": options.alpha, "pspg": float(options.pspg),
            "compressibility": 1.0 / options.bulk_modulus,
        }
        forms = load_forms(options.forms, required=("residual",))
        kw = dict(particle_shapes=particles, grid_functions=self.grid_fields, constants=self.constants)
        self.residual_form = ParticleForm(forms.residual, self.space, **kw)
        self.jacobian_form = ParticleForm(
            lambda s: ufl.derivative(forms.residual(s), s.grid("U")), self.space, **kw
        )
        unknown = next(c for c, (kind, name) in self.jacobian_form.symbols.used.items() if name == "U")
        expanded = ufl.algorithms.expand_derivatives(self.jacobian_form.ufl_form)
        self.linear = unknown not in expanded.coefficients()  # R affine in U: one Newton step
        self.J = self.space.create_matrix()
        self.linear_solver = LinearSolver(self.comm, "fempm_", options.petsc_options, fields=self.space.fields)
        self.time = 0.0
        self.steps = 0
        self.newton_iterations = 0
        self.timings: dict[str, float] = defaultdict(float)
        self.pressure_limit = options.pressure_limit or 20 * 1000.0 * 9.81 * (
            self.grid.upper[1] - self.grid.lower[1])
        self._wall_dofs = self._walls()
        self._reference_density = self.comm.allreduce(particles["density"].max(initial=0.0), op=MPI.MAX)

    # -- one step ------------------------------------------------------------------------
    def step(self):
        """Advance the particles by one time step (raises :class:`SimulationDiverged`)."""
        try:
            with self._phase("project"):
                free = self.project()
            self.solve(free)
            with self._phase("update"):
                self.update_particles()
            with self._phase("relocate"):
                self.particles.relocate()
        except SolveFailed as e:
            raise SimulationDiverged(self.time + self.options.dt, self.steps + 1, str(e)) from None
        except ParticleOutsideGridError as e:
            raise SimulationDiverged(self.time + self.options.dt, self.steps + 1, str(e)) from None
        self.time += self.options.dt
        self.steps += 1

    @contextmanager
    def _phase(self, name: str):
        start = time.perf_counter()
        yield
        self.timings[name] += time.perf_counter() - start

    # -- phases ------------------------------------------------------------------------
    def project(self) -> np.ndarray:
        """P2G: grid velocity and acceleration, smoothed density; returns the free dofs."""
        p = self.particles
        mass = transfer.lumped_mass(self.scalar_space, p)
        m = mass.values[:, :1]
        safe = np.where(m > 0, m, 1.0)
        for name, field_ in (("grid_velocity", "velocity"), ("grid_acceleration", "acceleration")):
            momentum = transfer.particles_to_grid(self.vector_space, p, p["mass"][:, None] * p[field_])
            self.grid_fields[name].values[:] = np.where(m > 0, momentum.values / safe, 0.0)
        rho = self.grid_fields["smoothed_density"]
        rho.values[:] = m / self.basis.integrals[self.scalar_space.numbering.local_functions][:, None]
        # functions whose support holds less than a fraction of material are left out
        fraction = m[:, 0] / (self._reference_density * self.basis.integrals[
            self.scalar_space.numbering.local_functions])
        owned = self.scalar_space.numbering.num_owned
        keep = np.repeat(fraction[:owned] >= self.options.min_support_fraction, self.space.bs)
        active = self.space.local_to_global[: self.space.num_owned_dofs][keep]
        return np.setdiff1d(active, self._wall_dofs, assume_unique=True)

    def solve(self, free: np.ndarray):
        """Newton's method on R(U) = 0 over the free dofs, starting from U = 0."""
        U = self.U.vector
        U.array[:] = 0.0
        r0 = None
        for iteration in range(self.options.newton_max_it):
            with self._phase("assemble"):
                R = self.residual_form.assemble_vector(self.particles)
                norm = _free_norm(R, free, self.space)
                if r0 is None:
                    r0 = norm
                if iteration > 0 and norm <= self.options.newton_rtol * max(r0, 1e-300):
                    break
                J = self.jacobian_form.assemble_matrix(self.particles, self.J)
            with self._phase("solve"):
                R.petsc_vec.scale(-1.0)
                delta = self.linear_solver.solve(J, R.petsc_vec, free)
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

    def update_particles(self):
        """G2P: FLIP (or FLIP/PIC blend) velocity and acceleration, x += du, particle pressure.

        FLIP adds the grid's change ``v_{n+1} - v_n`` to the particle velocity
        (likewise for the acceleration); PIC takes ``v_{n+1}`` itself.
        """
        o, p = self.options, self.particles
        g = self._g2p.values
        du = self.U.field("u")
        v, a = self.grid_fields["grid_velocity"].values, self.grid_fields["grid_acceleration"].values
        a_new = (du - o.dt * v - o.dt**2 * (0.5 - o.beta) * a) / (o.beta * o.dt**2)
        v_new = v + o.dt * ((1 - o.gamma) * a + o.gamma * a_new)
        self.velocity.values[:] = v_new
        g[:, 0:2], g[:, 2:4], g[:, 4:6] = du, v_new - v, a_new - a
        g[:, 6:8], g[:, 8:10], g[:, 10] = v_new, a_new, self.U.field("p")[:, 0]
        jets = transfer.grid_jets_to_particles(self._g2p, p, order=1)
        values = jets[:, 0]
        k = o.pic_blend
        p["velocity"][:] = (1 - k) * (p["velocity"] + values[:, 2:4]) + k * values[:, 6:8]
        p["acceleration"][:] = (1 - k) * (p["acceleration"] + values[:, 4:6]) + k * values[:, 8:10]
        p["pressure"][:] = values[:, 10]
        p.fields["x"] = p.x + values[:, 0:2]
        divergence = (jets[:, 1, 6] + jets[:, 2, 7]) / self.grid.h
        self.max_divergence = self.comm.allreduce(float(np.abs(divergence).max(initial=0.0)), op=MPI.MAX)
        peak = self.comm.allreduce(float(np.abs(p["pressure"]).max(initial=0.0)), op=MPI.MAX)
        if not np.isfinite(peak):
            raise SolveFailed("the pressure is not finite")
        if peak > self.pressure_limit:
            raise SolveFailed(
                f"pressure oscillation: |p| reached {peak:.3g} Pa, above the limit {self.pressure_limit:.3g} Pa"
            )

    @property
    def pressure(self) -> GridFunction:
        """The pressure of the last step on the grid."""
        self._pressure.values[:] = self.U.field("p")
        return self._pressure

    # -- helpers -----------------------------------------------------------------------
    def _walls(self) -> np.ndarray:
        """Owned velocity dofs held at zero: on the walls (normal component, or both) and obstacles."""
        dofs = [self.space.cell_dofs("u", np.flatnonzero(self.grid.blocked))]
        for side, kind in self.options.wall_conditions().items():
            normal = 0 if side in ("left", "right") else 1
            for component in (0, 1) if kind == "no-slip" else (normal,):
                dofs.append(self.space.wall_dofs("u", component, side[0]))
        return np.unique(np.concatenate(dofs))


def _free_norm(R, free, space) -> float:
    owned = space.local_to_global[: space.num_owned_dofs]
    local = R.array[: space.num_owned_dofs][np.isin(owned, free, assume_unique=True)]
    return float(np.sqrt(space.comm.allreduce(np.dot(local, local))))

