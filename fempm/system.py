"""What an implicit step solves on the grid, shared by the MPM and the FEM-only reference.

:class:`GridSystem` holds the unknowns ``U = (du, p)``, the grid fields the forms read
(``grid_velocity`` v_n, ``grid_acceleration`` a_n, ``smoothed_density``), the constants of the
forms, the walls and free dofs, and solves ``R(U) = 0`` by Newton's method with the Jacobian
UFL derives (:class:`StepForms`, compiled once).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numba
import numpy as np
import ufl

from fempm import collective, newmark
from fempm.bases import Basis
from fempm.formsfile import load_forms
from fempm.linear import LinearSolver, SolveFailed
from fempm.options import Controls, Physics, Scheme
from fempm.particles import ParticleSubset
from fempm.quadrature import ParticleForm
from fempm.space import GridFunction, Space, vector_values
from fempm.timing import PhaseTimes
from fempm.walls import FreeDofs, Walls

__all__ = ["GridSystem", "StepForms"]


_acceleration, _end_velocity = (numba.njit(cache=True)(f) for f in (newmark.acceleration, newmark.end_velocity))


@numba.njit(cache=True)
def _all_finite(values) -> bool:
    """Whether every entry of the 1-D ``values`` is finite."""
    for i in range(values.shape[0]):
        if not np.isfinite(values[i]):
            return False
    return True


@numba.njit(cache=True)
def _end_state(du, v, a, dt, beta, gamma, v_new, a_new):
    """:mod:`fempm.newmark`'s ``a_{n+1}`` and ``v_{n+1}`` entry by entry (its own functions, compiled)."""
    for f in range(du.shape[0]):
        for c in range(du.shape[1]):
            a_new[f, c] = _acceleration(du[f, c], v[f, c], a[f, c], dt, beta)
            v_new[f, c] = _end_velocity(v[f, c], a[f, c], a_new[f, c], dt, gamma)


@numba.njit(cache=True)
def _touching(marks, functions):
    """Which particles (rows of ``functions``, their local functions) have a function whose ``marks`` is not zero."""
    out = np.zeros(functions.shape[0], dtype=np.bool_)
    for p in range(functions.shape[0]):
        for f in functions[p]:
            if marks[f] != 0.0:
                out[p] = True
                break
    return out


class StepForms:
    """The ``residual`` of a forms file and its Jacobian ``dR/dU``, each compiled once by ``compile``
    (a function of a form builder returning an assembled form: particle or Gauss quadrature).

    Attributes:
        linear: R is affine in U (the shipped forms), so one Newton iteration solves the step.
    """

    def __init__(self, forms_file, compile: Callable):
        forms = load_forms(forms_file, required=("residual",))
        self.residual = compile(forms.residual)
        self.jacobian = compile(lambda s: ufl.derivative(forms.residual(s), s.grid("U")))
        unknown = next(c for c, (kind, name) in self.jacobian.symbols.used.items() if name == "U")
        self.linear = unknown not in self.jacobian.expanded_form.coefficients()
        excess = getattr(forms, "wall_force_excess", None)
        self._wall_force_excess = (lambda: compile(excess)) if callable(excess) else None

    @functools.cached_property
    def wall_force_excess(self):
        """The forms file's ``wall_force_excess`` compiled (on first use), or None: what the residual at a
        held wall dof holds beyond the walls' force on the water (``forms/incompressible.py``)."""
        return None if self._wall_force_excess is None else self._wall_force_excess()

    @functools.cached_property
    def excess_in_pass(self) -> bool:
        """Whether :attr:`wall_force_excess` can be assembled in the residual's pass: a particle form free of U
        (with the pressure's work split it reads the known pressure) that joins the residual's pass."""
        excess = self.wall_force_excess
        if not isinstance(excess, ParticleForm) or not isinstance(self.jacobian, ParticleForm):
            return False
        unknown = next((c for c, (kind, name) in excess.symbols.used.items() if name == "U"), None)
        return unknown not in excess.expanded_form.coefficients() and excess.joins(self.residual)

    def assemble(self, particles, J=None, R=None, excess=None):
        """The Jacobian and the residual (into ``J`` and ``R`` if given), in one pass over the particles
        for particle forms (:meth:`fempm.quadrature.ParticleForm.assemble_with`); with ``excess``, a vector and a
        mask of the particles (where :attr:`excess_in_pass`), the wall force excess over those into it in the same pass."""
        if isinstance(self.jacobian, ParticleForm):
            alongside = None if excess is None else (self.wall_force_excess, *excess)
            return self.jacobian.assemble_with(self.residual, particles, J, R, alongside)
        R = self.residual.assemble_vector(particles, R)
        return self.jacobian.assemble_matrix(particles, J), R


class GridSystem:
    """The unknowns, grid fields, constants, constraints and Newton solve of an implicit step.

    Args:
        basis: the grid basis.
        physics, scheme, controls: see :mod:`fempm.options`.
        convection: the constant ``convection`` of the forms: 1 on a fixed grid, 0 in the MPM
            (whose grid moves with the material for the step; the term is then left out).
        density: the fluid's reference density, the forms' constant ``density``.
        timings: where the solve's phases (assemble, solve) add their wall time.

    Attributes:
        space: ``{"u": 2, "p": 1}`` on the basis; ``vector_space``, ``scalar_space`` likewise.
        U: the unknowns of the step, ``(du, p)``.
        fields: the grid functions the forms read, by name (``U`` among them).
        velocity, pressure: ``v_{n+1}`` and ``p`` of the last step on the grid (see :meth:`end_state`).
        constants: the forms' constants by name.
        walls, free: the held wall dofs and the free-dof selection.
        newton_iterations: Newton iterations so far.
    """

    def __init__(self, basis: Basis, physics: Physics, scheme: Scheme, controls: Controls, convection: float,
                 timings: PhaseTimes, density: float):
        self.basis, self.grid, self.comm = basis, basis.grid, basis.grid.comm
        self.physics, self.scheme, self.controls, self.timings = physics, scheme, controls, timings
        self.space = Space(basis, {"u": 2, "p": 1})
        self.vector_space = Space(basis, {"v": 2})
        self.scalar_space = Space(basis, {"m": 1})
        self.U = GridFunction(self.space, "U")
        self.fields = {
            "U": self.U,
            "grid_velocity": GridFunction(self.vector_space, "grid_velocity"),
            "grid_acceleration": GridFunction(self.vector_space, "grid_acceleration"),
            "smoothed_density": GridFunction(self.scalar_space, "smoothed_density"),
            "deep": GridFunction(self.scalar_space, "deep"),  # fempm.density.DeepWater
            "by_parts": GridFunction(self.scalar_space, "by_parts"),  # fempm.density.DeepWater; 0 on a fixed grid
            "known_pressure": GridFunction(self.scalar_space, "known_pressure"),  # fempm.hydrostatic; 0 on a fixed grid
        }
        self.velocity = GridFunction(self.vector_space, "velocity")
        self.pressure = GridFunction(self.scalar_space, "pressure")
        self.constants = {
            "dt": scheme.dt, "beta": scheme.beta, "gamma": scheme.gamma, "mu": physics.viscosity,
            "gravity": np.asarray(physics.gravity, dtype=float), "alpha": scheme.volume_share(scheme.dt), "pspg": float(scheme.pspg),
            "surface_aware": float(scheme.surface_aware), "by_parts": float(scheme.pressure_work == "by-parts"),
            "split": float(scheme.pressure_work in ("split", "increment")),
            "convection": float(convection), "density": float(density),
        }
        self.walls = Walls(self.space, physics)
        self.free = FreeDofs(self.space, self.walls)
        self.linear_solver = LinearSolver(self.comm, "fempm_", controls.petsc_options, fields=self.space.fields)
        self.newton_iterations = 0
        self._R = self.space.create_vector()
        self._R_values = vector_values(self._R)
        self._rows_marked = GridFunction(self.scalar_space, "reaction_rows")  # see _adding_to
        self._delta, self._delta_of, self._delta_values = None, None, None  # the solve's increment, its matrix, view
        self._excess, self._excess_assembled = None, False  # the wall force excess of the solve's pass
        self._end = None  # end_state's arrays
        self._touching_of = (None, None)  # (rows, their functions): _touching_rows

    @property
    def dt(self) -> float:
        """The step being taken (the forms' constant ``dt``)."""
        return self.constants["dt"]

    def set_step(self, dt: float):
        """The size of the step about to be taken (read by the forms at assembly, with the volume
        correction's share of it)."""
        self.constants["dt"] = dt
        self.constants["alpha"] = self.scheme.volume_share(dt)

    def impose_walls(self):
        """v_n and a_n on the held wall dofs: the walls' own (so ``v_{n+1} = v_wall``, ``a_{n+1} = 0``)."""
        self.walls.impose(self.fields["grid_velocity"], self.fields["grid_acceleration"])

    def solve(self, forms: StepForms, free: np.ndarray, J, particles=None):
        """Newton on R(U) = 0 over the free dofs, from U = 0 and ``du = dt v_wall`` on the held wall
        dofs (which the corrections leave alone); ``J`` is the matrix to assemble into (None: the
        forms' own).

        One iteration, and no second residual, when R is affine in U.

        Raises:
            SolveFailed: the linear solve failed, U is not finite, or Newton did not converge.
        """
        c = self.controls
        U, u = self.U.vector, self.U.array  # the vector, and its values' view (made once)
        u[:] = 0.0
        u[self.walls.positions] = self.dt * self.walls.values
        U.scatter_forward()
        r0 = norm = None
        self._excess_assembled = False
        for iteration in range(c.newton_max_it):
            with self.timings("assemble"):
                if forms.linear:  # one iteration: no norm to check first
                    excess = self._excess_alongside(forms, particles)
                    J, R = forms.assemble(particles, J, self._R, excess)
                    self._excess_assembled = excess is not None
                else:
                    R = forms.residual.assemble_vector(particles, self._R)
                    norm = self._free_norm(R)
                    r0 = norm if r0 is None else r0
                    if iteration > 0 and norm <= c.newton_rtol * max(r0, 1e-300):
                        break
                    J = forms.jacobian.assemble_matrix(particles, J)
            if self._delta_of is not J:  # a new matrix (the first, or a widened region); the view of its values
                self._delta, self._delta_of = J.createVecLeft(), J
                self._delta_values = self._delta.getArray(readonly=True)
            with self.timings("solve"):
                rhs = R.petsc_vec
                rhs.scale(-1.0)
                self.linear_solver.solve(J, rhs, free, self._delta)
                u[: self.space.num_owned_dofs] += self._delta_values
                U.scatter_forward()
            self.newton_iterations += 1
            if not collective.all_ranks(self.comm, _all_finite(u)):  # every rank raises, or none
                raise SolveFailed("the solution is not finite")
            if forms.linear:
                break
        else:
            raise SolveFailed(f"Newton did not converge in {c.newton_max_it} iterations "
                              f"(|R| = {norm:.3e}, |R0| = {r0:.3e})")

    def reaction(self, forms: StepForms, particles=None, rows: np.ndarray | None = None) -> np.ndarray:
        """The residual ``R(U)`` of the solved step at the owned dofs ``rows`` (default all), less the forms'
        ``wall_force_excess`` with the pressure's work by parts or split: on a held dof the force its constraint exerts
        (one-sided walls, :meth:`fempm.walls.Walls.update`). For forms affine in U ``R(U_0) + J delta`` from the
        solve's own vectors, else assembled again."""
        rows = np.arange(self.space.num_owned_dofs) if rows is None else np.asarray(rows, dtype=np.int64)
        excess = forms.wall_force_excess if self.constants["by_parts"] or self.constants["split"] else None
        if excess is None:
            excess = 0.0
        elif self._excess_assembled and (rows is self.walls.normal or np.array_equal(rows, self.walls.normal)):
            excess = self._excess.array[rows]
        else:
            excess = excess.assemble_vector(self._adding_to(rows, particles)).array[rows]
        if not forms.linear:
            return forms.residual.assemble_vector(particles, self._R).array[rows] - excess
        # the solve scaled R(U_0) by -1; delta = U - U_0
        gm = self._delta_of.getAttr("fempm_grid_matrix")
        product = gm.multiply(self._delta_values, rows) if gm is not None else None
        if product is None:
            whole = self._delta_of.createVecLeft()
            self._delta_of.mult(self._delta, whole)
            product = whole.getArray(readonly=True)[rows]
        return product - self._R_values[rows] - excess

    def _excess_alongside(self, forms: StepForms, particles):
        """Where the solve's pass assembles the wall force excess that :meth:`reaction` subtracts at the contact
        dofs, and over which particles: those that add to them (one-sided walls, the pressure's work by parts or
        split, an excess free of U: :attr:`StepForms.excess_in_pass`); else None."""
        if not (self.walls.one_sided and (self.constants["by_parts"] or self.constants["split"])
                and forms.excess_in_pass):
            return None
        if self._excess is None:
            self._excess = GridFunction(self.space, "wall_force_excess")
        return self._excess.vector, self._touching_rows(self.walls.normal, particles)

    def _touching_rows(self, rows: np.ndarray, particles) -> np.ndarray:
        """Which particles have a basis function among those of the owned dofs ``rows`` (collective)."""
        marked = self._rows_marked
        if self._touching_of[0] is not rows:  # the walls' contact dofs, the same array step after step
            self._touching_of = (rows, rows // self.space.bs)
        marked.values[:] = 0.0
        marked.values[self._touching_of[1], 0] = 1.0
        marked.scatter_forward()  # a rank's particles add to the ghosts of other ranks' rows
        _, functions = self.scalar_space.tabulate_particles(particles, 0, exact=False)
        return _touching(marked.values[:, 0], functions)

    def _adding_to(self, rows: np.ndarray, particles):
        """The particles whose basis functions include one of the owned dofs ``rows``: those that add to these rows
        of a vector (a :class:`~fempm.particles.ParticleSubset`; a step's Gauss points are taken whole; collective)."""
        if getattr(particles, "fixed", None) is not None:
            return particles
        return ParticleSubset(particles, np.flatnonzero(self._touching_rows(rows, particles)))

    def _free_norm(self, R) -> float:
        local = R.array[: self.space.num_owned_dofs][self.free.mask]
        return float(np.sqrt(collective.total(self.comm, float(np.einsum("i,i->", local, local)))))

    def end_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``v_{n+1}`` and ``a_{n+1}`` on the grid from the solved ``du`` (Newmark; arrays the next call
        overwrites); keeps ``v_{n+1}`` and the pressure in :attr:`velocity` and :attr:`pressure`."""
        s = self.scheme
        v, a = self.fields["grid_velocity"].values, self.fields["grid_acceleration"].values
        if self._end is None:
            self._end = np.empty_like(v), np.empty_like(a)
        v_new, a_new = self._end
        _end_state(self.U.field("u"), v, a, float(self.dt), float(s.beta), float(s.gamma), v_new, a_new)
        self.velocity.values[:] = v_new
        self.pressure.values[:] = self.U.field("p")
        return v_new, a_new
