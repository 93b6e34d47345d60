"""The FEM-only reference: the step's forms on a fixed grid with Gauss quadrature, no particles.

:class:`EulerianSolver` is built from the same parts as the MPM step
(:class:`~fempm.system.GridSystem`: unknowns, walls, moving walls, pressure pin, Newton, linear
solver; the same forms file), with its own phases::

    project   v_n, a_n <- the previous step's grid solution (the walls' own on held dofs)
    solve     R(U) and dR/dU by DOLFINx with Gauss quadrature on the Lagrange space containing
              the basis, restricted by extraction (P^T A P); Newton as the MPM
    update    v_{n+1}, a_{n+1} by Newmark, kept for the next step

On the fixed grid the forms see: ``density`` a constant, the particle ``velocity`` (the PSPG
parameter's speed) and ``acceleration`` the previous step's grid fields at the Gauss points,
``dx_lumped`` the ordinary ``dx`` (consistent mass), the volume correction off (no particles to
crowd) and the convective term on (``convection = 1``, Oseen: ``rho (v_n . grad) v_{n+1}``).
Every function of the grid carries fluid.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fempm.bases import Basis
from fempm.errors import InputError
from fempm.options import Controls, Physics, Scheme
from fempm.quadrature import GaussForm
from fempm.safeguards import PressureCheck
from fempm.space import GridFunction
from fempm.stepper import Stepper
from fempm.system import GridSystem, StepForms

__all__ = ["EulerianSolver"]


class EulerianSolver(Stepper):
    """The implicit step on a fixed grid filled with fluid (FEM-only).

    Args:
        basis: the grid basis (``fempm.BSpline2`` or ``fempm.Q1``).
        physics, scheme, controls: see :mod:`fempm.options`; the volume correction and the PIC
            share do not apply (no particles).
        density: the fluid's density, kg/m^3.
        degree: degree of the Gauss rule (default that of :class:`~fempm.quadrature.GaussForm`).

    Attributes:
        velocity, acceleration, pressure: grid functions of the last step's v_{n+1}, a_{n+1}, p (set
            ``velocity.values`` before the first step for an initial velocity).
    """

    def __init__(self, basis: Basis, physics: Physics | None = None, scheme: Scheme | None = None,
                 controls: Controls | None = None, density: float = 1000.0, degree: int | None = None):
        if not density > 0:
            raise InputError(f"density must be positive, got {density}")
        physics, controls = physics or Physics(), controls or Controls()
        scheme = replace(scheme or Scheme(), alpha=0.0)
        for part in (physics, scheme, controls):
            part.check()
        super().__init__(scheme.dt)
        self.basis, self.grid, self.density = basis, basis.grid, float(density)
        self.physics, self.scheme, self.controls = physics, scheme, controls
        self.system = s = GridSystem(basis, physics, scheme, controls, convection=1.0, timings=self.timings,
                                    density=self.density)
        self.velocity, self.pressure = s.velocity, s.pressure
        self.acceleration = GridFunction(s.vector_space, "acceleration")
        particle_values = {"density": self.density, "velocity": s.fields["grid_velocity"],
                           "acceleration": s.fields["grid_acceleration"]}
        self.forms = StepForms(scheme.forms, lambda builder: _GaussAssembly(GaussForm(
            builder, s.space, particle_values=particle_values, grid_functions=s.fields, constants=s.constants,
            degree=degree)))
        if "convection" not in self.forms.residual.symbols.used_constants.values():
            raise InputError(f"forms file {str(scheme.forms)!r}: its residual has no convective term "
                             "(it never uses the constant 'convection'), which a fixed grid needs")
        limit = controls.pressure_limit or 20 * 1000.0 * 9.81 * (self.grid.upper[1] - self.grid.lower[1])
        self.check_pressure = PressureCheck(self.grid.comm, limit, limit)
        self.max_divergence = 0.0

    def advance(self, dt: float):
        """One step: v_n, a_n from the last step, Newton, v_{n+1} and a_{n+1} kept (the run's first
        step from a solved ``a_0``, :meth:`solve_initial_acceleration`, unless the scheme says it is
        given)."""
        self.system.set_step(dt)
        if self.steps == 0 and self.scheme.initial_acceleration == "solved" and not self.physics.wall_speeds:
            self.solve_initial_acceleration()
        self._solve_step()
        self.check_pressure(self.system.U.field("p")[: self.system.scalar_space.numbering.num_owned], dt)

    def solve_initial_acceleration(self):
        """Newmark's ``a_0`` consistent with the flow: the first step solved once from the given
        ``a_0`` (zero unless set), its ``a_1`` taken as ``a_0``. With the trapezoidal rule a flow
        started from rest under a body force with ``a_0 = 0`` gains half a step's worth of velocity
        too little and lags by ``dt / 2`` ever after (an error of first order in dt); ``a_1`` is
        ``a(0)`` to O(dt), so that lag becomes O(dt^2). As in the MPM
        (:meth:`fempm.implicit.ImplicitSolver.solve_initial_acceleration`); not with moving walls,
        whose start is an impulse."""
        with self.timings("start"):
            v_0 = self.system.velocity.values.copy()
            self._solve_step()
            self.system.velocity.values[:] = v_0  # the step itself starts from v_0 again

    def _solve_step(self):
        """v_n, a_n from the last step (the walls' own on held dofs), Newton, and ``a_{n+1}`` kept."""
        s = self.system
        with self.timings("project"):
            s.fields["grid_velocity"].values[:] = s.velocity.values
            s.fields["grid_acceleration"].values[:] = self.acceleration.values
            s.impose_walls()
            free = s.free.select(np.ones(s.space.num_owned_dofs, dtype=bool))
        s.solve(self.forms, free, None)
        with self.timings("update"):
            _, a_new = s.end_state()
            self.acceleration.values[:] = a_new


class _GaussAssembly:
    """A :class:`GaussForm` answering :class:`~fempm.quadrature.ParticleForm`'s assembly calls
    (the particles argument is unused): the vector into the step's ghosted vector, the matrix
    ``P^T A P`` into its own storage, made at the first call and refilled at the next."""

    def __init__(self, form: GaussForm):
        self.form = form
        self.symbols, self.ufl_form = form.symbols, form.ufl_form
        self._matrix = None

    @property
    def expanded_form(self):
        return self.form.expanded_form

    def assemble_vector(self, _particles, out):
        b = self.form.assemble_vector()
        out.array[:] = 0.0
        out.array[: self.form.space.num_owned_dofs] = b.getArray(readonly=True)
        b.destroy()
        return out

    def assemble_matrix(self, _particles, _out=None):
        self._matrix = self.form.assemble_matrix(self._matrix)
        return self._matrix
