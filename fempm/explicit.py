"""The explicit MPM baseline: forward Euler, Modified Update Stress Last, weakly compressible fluid.

The scheme of method.md's explicit comparison (Sulsky, Zhou & Schreyer 1995, with the
stress updated last as in Sulsky, Chen & Schreyer 1994 / Nairn 2003 "MUSL"), on the
same grid, bases, particles, transfers and walls (:class:`~fempm.walls.Walls`) as
:mod:`fempm.implicit`. One step, as named
phases::

    project   P2G: lumped mass m_i and momentum (m v)_i; which functions carry material
    forces    f_i = -sum_p V_p sigma_p : grad N_i + sum_p m_p g N_i (forms/weakly_compressible.py)
    grid      (m v)_i += dt f_i; zero normal momentum on the walls; v_i = (m v)_i / m_i
    update    G2P: FLIP (optionally blended with PIC) velocity, x_p += dt v(x_p)
    stress    MUSL: P2G of the new particle momentum, walls, velocity gradient L_p at the
              particles; volume V_p *= det(I + dt L_p), density m_p / V_p, pressure from
              the equation of state, viscous stress from L_p
    relocate  particles to their new cells and ranks

The step is stable only below a time step of the order of the time sound takes to cross
a cell (Courant, Friedrichs & Lewy 1928)::

    dt = C min(h / (c + |v|_max), h^2 / (4 nu)),     c = sqrt(K / rho_0),

which :func:`stable_time_step` computes; ``C`` is the safety factor
:data:`DEFAULT_CFL` (see there why that value). A run is stopped with
:class:`~fempm.errors.SimulationDiverged` naming the cause when a velocity or pressure
is not finite, a particle moves more than a cell in one step, a particle's volume
collapses, the pressure leaves the range the equation of state is meant for, or a
particle leaves the grid.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm import transfer
from fempm.bases import Basis
from fempm.errors import InputError
from fempm.formsfile import load_forms
from fempm.linear import SolveFailed
from fempm.options import Controls, Physics
from fempm.particles import Particles
from fempm.quadrature import ParticleForm
from fempm.space import GridFunction, Space
from fempm.stepper import Stepper
from fempm.walls import Walls

__all__ = ["DEFAULT_CFL", "ExplicitScheme", "ExplicitSolver", "stable_time_step"]

#: Safety factor C of the CFL condition. ``h / (c + |v|)`` is the limit of the lumped-mass linear
#: wave equation in 1-D; the dam break's flow reaches about twice the estimate ``sqrt(2 g H)`` at the
#: impact on the far wall, and particles crowd, so C stays well below 1 (the stability map of
#: docs/implicit-vs-explicit.md measures where it breaks).
DEFAULT_CFL = 0.5


@dataclass
class ExplicitScheme:
    """The explicit scheme (SI units).

    Attributes:
        dt: time step; ``None`` takes :func:`stable_time_step` with ``cfl``.
        cfl: safety factor C of the CFL condition (0 < C <= 1).
        bulk_modulus: K of the equation of state (2.0 GPa: water, method.md's run).
        sound_speed: an artificial sound speed c_0; if given, K = rho_0 c_0^2 replaces
            ``bulk_modulus`` (weakly compressible practice: c_0 about 10 |v|_max).
        max_speed: the largest flow speed expected, for the CFL condition
            (the dam break: sqrt(2 g H)); the run stops if a particle moves a cell in a step.
        pic_blend: 0 = pure FLIP, 1 = pure PIC, in between a blend of the two.
        forms: file of the forms (default ``forms/weakly_compressible.py``).
    """

    dt: float | None = None
    cfl: float = DEFAULT_CFL
    bulk_modulus: float = 2.0e9
    sound_speed: float | None = None
    max_speed: float = 0.0
    pic_blend: float = 0.0
    forms: str | Path = "weakly_compressible"

    def check(self):
        """Raise :class:`InputError` naming the first unacceptable value."""
        if self.dt is not None and not (np.isfinite(self.dt) and self.dt > 0):
            raise InputError(f"dt must be positive (or None for the CFL step), got {self.dt}")
        if not 0 < self.cfl <= 1:
            raise InputError(f"cfl (safety factor) must be in (0, 1], got {self.cfl}")
        if not (np.isfinite(self.bulk_modulus) and self.bulk_modulus > 0):
            raise InputError(f"bulk_modulus must be positive and finite, got {self.bulk_modulus}")
        if self.sound_speed is not None and not (np.isfinite(self.sound_speed) and self.sound_speed > 0):
            raise InputError(f"sound_speed must be positive, got {self.sound_speed}")
        if not self.max_speed >= 0:
            raise InputError(f"max_speed must be >= 0, got {self.max_speed}")
        if not 0 <= self.pic_blend <= 1:
            raise InputError(f"pic_blend must be in [0, 1], got {self.pic_blend}")


def stable_time_step(h: float, sound_speed: float, max_speed: float, kinematic_viscosity: float,
                     cfl: float = DEFAULT_CFL) -> float:
    """``dt = C min(h / (c + |v|_max), h^2 / (4 nu))``: the CFL step of sound and of diffusion."""
    limits = [h / (sound_speed + max_speed)]
    if kinematic_viscosity > 0:
        limits.append(h * h / (4 * kinematic_viscosity))
    return cfl * min(limits)


class ExplicitSolver(Stepper):
    """Advances particles of a weakly compressible viscous fluid by explicit MUSL MPM.

    Args:
        basis: the grid basis (``fempm.BSpline2`` or ``fempm.Q1``).
        particles: the fluid (fields ``density``, ``velocity``); ``pressure`` and
            ``velocity_gradient`` fields are added if missing, zero: the fluid starts
            without stress. The pressure then follows the density by the equation of state.
        physics: viscosity, gravity and walls (``slip`` or ``no-slip`` sides only).
        scheme: :class:`ExplicitScheme`.
        controls: ``min_support_fraction`` (functions with less material get no velocity:
            ``1 / m_i`` is unbounded there) and ``pressure_limit`` (|p| beyond it is a blow-up;
            default K / 2, a density change of 50 %) apply.

    Attributes:
        scheme: the scheme with ``dt`` resolved.
        reference_density: rho_0 of the equation of state (the particles' largest density).
        bulk_modulus, sound_speed: K and c = sqrt(K / rho_0) in use.
    """

    def __init__(self, basis: Basis, particles: Particles, physics: Physics | None = None,
                 scheme: ExplicitScheme | None = None, controls: Controls | None = None):
        physics, scheme, controls = physics or Physics(), scheme or ExplicitScheme(), controls or Controls()
        for part in (physics, scheme, controls):
            part.check()
        open_sides = [side for side, kind in physics.wall_conditions().items() if kind not in ("slip", "no-slip")]
        if open_sides:
            raise InputError(f"explicit solver: walls.{open_sides[0]} must be 'slip' or 'no-slip' (the "
                             f"explicit scheme has no outflow or open sides)")
        self.basis, self.particles, self.grid = basis, particles, basis.grid
        self.physics, self.controls = physics, controls
        self.comm = self.grid.comm
        for name, shape in (("pressure", ()), ("velocity_gradient", (2, 2))):
            if name not in particles.fields:
                particles.add_field(name, shape)
        self.reference_density = self.comm.allreduce(particles["density"].max(initial=0.0), op=MPI.MAX)
        if not self.reference_density > 0:
            raise InputError("explicit solver: no particle has a positive density")
        rho0 = self.reference_density
        if scheme.sound_speed is not None:
            self.sound_speed, self.bulk_modulus = scheme.sound_speed, rho0 * scheme.sound_speed**2
        else:
            self.sound_speed, self.bulk_modulus = np.sqrt(scheme.bulk_modulus / rho0), scheme.bulk_modulus
        if scheme.dt is None:
            scheme = dataclasses.replace(scheme, dt=stable_time_step(
                self.grid.h, self.sound_speed, scheme.max_speed, physics.viscosity / rho0, scheme.cfl))
        self.scheme = scheme
        super().__init__(scheme.dt)
        self.pressure_limit = controls.pressure_limit or 0.5 * self.bulk_modulus
        self.vector_space = Space(basis, {"v": 2})
        self.scalar_space = Space(basis, {"m": 1})
        self.velocity = GridFunction(self.vector_space, "velocity")  # after the MUSL re-projection
        self._g2p = GridFunction(Space(basis, {"dv": 2, "v": 2}), "g2p")
        self.constants = {"mu": physics.viscosity, "gravity": np.asarray(physics.gravity, dtype=float)}
        forms = load_forms(scheme.forms, required=("force", "pressure"))
        self.equation_of_state = forms.pressure
        self.force_form = ParticleForm(forms.force, self.vector_space, particle_shapes=particles,
                                       constants=self.constants)
        self._force = self.vector_space.create_vector()
        # grid buffers made once: every vector holds MPI communicators
        self._mass = GridFunction(self.scalar_space, "mass")
        self._momentum = GridFunction(self.vector_space, "momentum")
        self._pressure = GridFunction(self.scalar_space, "pressure")
        self.walls = Walls(self.vector_space, physics, field="v")
        self._held = self.walls.held_mask(self.vector_space)
        self.max_divergence = 0.0

    # -- one step ------------------------------------------------------------------------
    def advance(self, dt: float):
        """One step: P2G, forces, grid update, G2P, stress (MUSL), relocation."""
        with self.timings("project"):
            momentum = self.project()
        with self.timings("forces"):
            force = self.forces()
        with self.timings("grid"):
            v_old, v_new = self.update_grid(momentum, force, dt)
        with self.timings("update"):
            self.update_particles(v_old, v_new, dt)
        with self.timings("stress"):
            x_old = self.update_stress(dt)
        self._stop_if_diverged(x_old, dt)
        with self.timings("relocate"):
            self.particles.relocate()

    # -- phases ------------------------------------------------------------------------
    def project(self) -> np.ndarray:
        """P2G: lumped mass (kept as ``1 / m_i``, zero where too little material) and momentum."""
        p = self.particles
        self.vector_space.tabulate_particles(p, order=1)  # one tabulation serves every phase
        m = transfer.lumped_mass(self.scalar_space, p, self._mass).values[:, 0]
        integrals = self.basis.integrals[self.scalar_space.numbering.local_functions]
        active = (m > 0) & (m >= self.controls.min_support_fraction * self.reference_density * integrals)
        self._inverse_mass = np.where(active, 1.0 / np.where(active, m, 1.0), 0.0)[:, None]
        return transfer.momentum(self.vector_space, p, self._momentum).values.copy()

    def forces(self) -> np.ndarray:
        """Nodal force of forms/weakly_compressible.py (internal + gravity), owned and ghost."""
        self.force_form.assemble_vector(self.particles, self._force)
        self._force.scatter_forward()
        return self._force.array.reshape(-1, 2)

    def update_grid(self, momentum: np.ndarray, force: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Forward Euler on the grid momentum with the walls; returns ``v_n`` and ``v_{n+1}``."""
        new = np.where(self._held, 0.0, momentum + dt * force)
        return momentum * self._inverse_mass, new * self._inverse_mass

    def update_particles(self, v_old: np.ndarray, v_new: np.ndarray, dt: float):
        """G2P: FLIP ``v_p += sum_i (v_i^{n+1} - v_i^n) N_i(x_p)`` (or a PIC blend) and ``a_p``."""
        p, g = self.particles, self._g2p
        g.field("dv")[:] = v_new - v_old
        g.field("v")[:] = v_new
        at = transfer.grid_to_particles(g, p)
        change, new = at[:, g.space.field_slice("dv")], at[:, g.space.field_slice("v")]
        p["velocity"][:] = transfer.flip(p["velocity"], change, new, self.scheme.pic_blend)
        p["acceleration"][:] = change / dt

    def update_stress(self, dt: float) -> np.ndarray:
        """MUSL: grid velocity re-projected from the new particle momenta; then x_p, L_p, volume, pressure.

        The re-projected ``v_i = sum_p m_p v_p N_i / m_i`` is a mass-weighted mean of
        particle velocities, so it stays bounded where a function carries little mass
        (``f_i / m_i`` does not), and it is zero normal to the walls. The positions move
        with it too, ``x_p += dt sum_i v_i N_i(x_p)``: with the velocity of the grid update
        instead, functions at the edge of the water next to a wall reached tens of m/s
        and carried particles through the wall.

        Returns the positions before the move (for the divergence check).
        """
        p = self.particles
        momentum = transfer.momentum(self.vector_space, p, self._momentum).values
        self.velocity.values[:] = np.where(self._held, 0.0, momentum) * self._inverse_mass
        jets = transfer.grid_jets_to_particles(self.velocity, p, order=1)
        x_old = p.x
        p.fields["x"] = x_old + dt * jets[:, 0]
        L = transfer.gradient(jets, self.grid.h)  # L[p, c, d] = d v_c / d x_d
        p["velocity_gradient"][:] = L
        # det(I + dt L): the volume ratio of the step's deformation-gradient increment
        ratio = (1 + dt * L[:, 0, 0]) * (1 + dt * L[:, 1, 1]) - dt * dt * L[:, 0, 1] * L[:, 1, 0]
        self._volume_ratio = ratio
        p["volume"][:] *= ratio
        p["density"][:] = p["mass"] / p["volume"]
        p["pressure"][:] = self.equation_of_state(p["density"], self.reference_density, self.bulk_modulus)
        divergence = np.abs(L[:, 0, 0] + L[:, 1, 1]).max(initial=0.0)
        self.max_divergence = self.comm.allreduce(float(divergence), op=MPI.MAX)
        return x_old

    @property
    def pressure(self) -> GridFunction:
        """The particle pressure projected to the grid, ``sum_p m_p p_p N_i / m_i``."""
        p = self.particles
        out = transfer.particles_to_grid(self.scalar_space, p, p["mass"] * p["pressure"], out=self._pressure)
        mass = transfer.lumped_mass(self.scalar_space, p, self._mass).values
        out.values[:] = np.where(mass > 0, out.values / np.where(mass > 0, mass, 1.0), 0.0)
        return out

    # -- divergence ----------------------------------------------------------------------
    def _stop_if_diverged(self, x_old: np.ndarray, dt: float):
        """Raise :class:`~fempm.linear.SolveFailed` on every rank if any rank finds a cause."""
        causes = self.comm.allgather(self._local_cause(x_old, dt))
        cause = next((c for c in causes if c), None)
        if cause:
            raise SolveFailed(cause)

    def _local_cause(self, x_old: np.ndarray, dt: float) -> str | None:
        p, h = self.particles, self.grid.h

        def first(bad: np.ndarray) -> int:
            return int(p.id[np.flatnonzero(bad)[0]])

        velocity, pressure = p["velocity"], p["pressure"]
        bad = ~np.all(np.isfinite(velocity), axis=1)
        if bad.any():
            return f"the velocity of particle {first(bad)} is not finite ({bad.sum()} particles)"
        moved = np.linalg.norm(p.x - x_old, axis=1) / h
        if moved.max(initial=0.0) > 1.0:
            k = int(np.argmax(moved))
            return (f"particle {p.id[k]} moved {moved[k]:.3g} cells in one step (|v| dt > h): "
                    f"dt = {dt:.3g} s violates the CFL condition")
        bad = ~(self._volume_ratio > 0)
        if bad.any():
            return (f"the volume of particle {first(bad)} collapsed (det(I + dt L) = "
                    f"{self._volume_ratio[bad][0]:.3g} <= 0)")
        peak = np.abs(pressure).max(initial=0.0)
        if not np.isfinite(peak):
            return "the pressure is not finite"
        if peak > self.pressure_limit:
            return f"pressure blow-up: |p| reached {peak:.3g} Pa, above the limit {self.pressure_limit:.3g} Pa"
        bad = self.grid.outside(p.x)
        if bad.any():
            k = np.flatnonzero(bad)[0]
            return f"particle {p.id[k]} left the grid at ({p.x[k, 0]:.4g}, {p.x[k, 1]:.4g})"
        return None
