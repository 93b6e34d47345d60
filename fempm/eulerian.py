"""The FEM-only reference: the step's forms on a fixed grid with Gauss quadrature, no particles.

:class:`EulerianSolver` is :class:`~fempm.implicit.ImplicitSolver` with three phases
changed and the rest shared (walls, moving walls, pressure pin, Newton, linear solver,
failure diagnosis)::

    project   v_n, a_n <- the previous step's grid solution (the walls' own on held dofs)
    assemble  R(U) and dR/dU of the same forms file by DOLFINx with Gauss quadrature on
              the Lagrange space containing the basis, restricted by extraction (P^T A P)
    solve     as the MPM: Newton (one iteration for the shipped forms), MUMPS LU
    update    v_{n+1}, a_{n+1} by Newmark, kept for the next step
    relocate  nothing moves

On the fixed grid the forms see: ``density`` a constant, the particle ``velocity`` (the
PSPG parameter's speed) and ``acceleration`` the previous step's grid fields at the
Gauss points, ``dx_lumped`` the ordinary ``dx`` (consistent mass), the volume
correction off (``alpha = 0``: no particles to crowd) and the convective term on
(``convection = 1``, Oseen: ``rho (v_n . grad) v_{n+1}``, see
``forms/incompressible.py``). Every function of the grid carries fluid: the domain is
the whole grid.
"""

from __future__ import annotations

from dataclasses import replace

from fempm.bases import Basis
from fempm.errors import InputError
from fempm.implicit import ImplicitOptions, ImplicitSolver
from fempm.quadrature import GaussForm
from fempm.space import GridFunction

import numpy as np

__all__ = ["EulerianSolver"]


class EulerianSolver(ImplicitSolver):
    """The implicit step of :mod:`fempm.implicit` on a fixed grid filled with fluid (FEM-only).

    Args:
        basis: the grid basis (``fempm.BSpline2`` or ``fempm.Q1``).
        options: :class:`~fempm.implicit.ImplicitOptions`; ``alpha`` and ``pic_blend``
            do not apply (no particles).
        density: the fluid's density, kg/m^3.
        degree: degree of the Gauss rule (default that of :class:`~fempm.quadrature.GaussForm`).

    Attributes:
        velocity, acceleration: grid functions of the last step's v_{n+1}, a_{n+1} (set
            ``velocity.values`` before the first step for an initial velocity).
    """

    def __init__(self, basis: Basis, options: ImplicitOptions | None = None, density: float = 1000.0,
                 degree: int | None = None):
        if not density > 0:
            raise InputError(f"density must be positive, got {density}")
        self.particles = None
        self.density, self._degree = float(density), degree
        self._setup(basis, replace(options or ImplicitOptions(), alpha=0.0), convection=1.0)
        self.acceleration = GridFunction(self.vector_space, "acceleration")
        self._compile_forms()
        if "convection" not in self.residual_form.symbols.used_constants.values():
            raise InputError(f"forms file {str(self.options.forms)!r}: its residual has no convective term "
                             "(it never uses the constant 'convection'), which a fixed grid needs")

    def _form(self, builder):
        """The form by Gauss quadrature, behind the particle form's assembly calls."""
        fields = self.grid_fields
        particle_values = {"density": self.density, "velocity": fields["grid_velocity"],
                           "acceleration": fields["grid_acceleration"]}
        return _GaussAssembly(GaussForm(builder, self.space, particle_values=particle_values, grid_functions=fields,
                                        constants=self.constants, degree=self._degree))

    def project(self) -> np.ndarray:
        """v_n and a_n: the last step's solution (the walls' own on their held dofs); returns the free dofs."""
        self.grid_fields["grid_velocity"].values[:] = self.velocity.values
        self.grid_fields["grid_acceleration"].values[:] = self.acceleration.values
        self._impose_walls()
        return self._free_dofs(np.ones(self.space.num_owned_dofs, dtype=bool))

    def update(self):
        """Keep v_{n+1} and a_{n+1} for the next step; stop on a non-finite or runaway pressure."""
        _, a_new = self._newmark()
        self.acceleration.values[:] = a_new
        self._check_pressure(self.U.field("p")[: self.scalar_space.numbering.num_owned])

    def relocate(self):
        """Nothing moves on a fixed grid."""


class _GaussAssembly:
    """A :class:`GaussForm` answering :class:`~fempm.quadrature.ParticleForm`'s assembly calls
    (the particles argument is unused): the vector into the step's ghosted vector, the matrix
    ``P^T A P`` into its own storage, made at the first call and refilled at the next."""

    def __init__(self, form: GaussForm):
        self.form = form
        self.symbols, self.ufl_form = form.symbols, form.ufl_form
        self._matrix = None

    def assemble_vector(self, _particles, out):
        b = self.form.assemble_vector()
        out.array[:] = 0.0
        out.array[: self.form.space.num_owned_dofs] = b.getArray(readonly=True)
        b.destroy()
        return out

    def assemble_matrix(self, _particles, _out=None):
        self._matrix = self.form.assemble_matrix(self._matrix)
        return self._matrix
