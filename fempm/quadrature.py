"""Particle quadrature of UFL forms: the particles are the quadrature points.

A weak form is written once, as a Python function of a :class:`Symbols` object
that hands out the UFL objects (test and trial functions, per-particle fields,
grid functions, constants, the measure ``dx``)::

    def mass(s):
        rho = s.particle("density")
        return rho * ufl.inner(s.trial, s.test) * s.dx

The same function is compiled for two integration targets:

* :class:`ParticleForm` -- ``sum_p V_p f(x_p)``: the integral with the particles
  as quadrature points and their volumes as weights. The form is compiled by
  DOLFINx/FFCx, once, on a *jet cell*: an h x h square whose reference origin is
  put on the particle, carrying an element whose degrees of freedom are the
  value and the derivatives at that origin. A one-point rule (the origin, weight 1)
  makes the kernel return the integrand's tensor in terms of the jets of the test
  and trial functions at the particle; :mod:`fempm.assembly` contracts it with
  the jets of the grid basis (Q1 or B-spline) and assembles into PETSc. This is
  exact for any integrand, polynomial or not, on any basis.
* :class:`GaussForm` -- the ordinary DOLFINx assembly with Gauss quadrature on the
  Lagrange space that contains the basis, restricted by extraction
  (``P^T A_L P``): the FEM reference, and the oracle of the exactness tests.

On the particle target ``s.particle(name)`` is the particle's own value; on the
Gauss target it is a field at the Gauss points given by a number, a callable of ``x``
or a grid function (read at every assembly: the FEM-only reference's particle
velocity is the previous step's grid velocity).
"""

from __future__ import annotations

import functools
import hashlib
import platform
from collections.abc import Callable, Mapping

import basix
import basix.ufl
import numpy as np
import ufl
import ufl.algorithms
from cffi import FFI
from mpi4py import MPI
from petsc4py import PETSc

import dolfinx.fem
import dolfinx.fem.petsc
import dolfinx.la
import dolfinx.mesh

from fempm import assembly
from fempm.bases import jet_indices
from fempm.errors import InputError
from fempm.lagrange import extraction_matrix, lagrange_space
from fempm.matrix import create_matrix, grid_matrix, layout
from fempm.space import GridFunction, Space, vector_values

__all__ = ["GaussForm", "ParticleForm", "Symbols"]

FormBuilder = Callable[["Symbols"], ufl.Form]


def _cpu_tag() -> str:
    """A short hash of this CPU's model and instruction-set flags (Linux; else the machine's name)."""
    try:
        with open("/proc/cpuinfo") as f:
            lines = [line for line in f if line.startswith(("model name", "flags"))][:2]
    except OSError:
        lines = [platform.machine(), platform.processor()]
    return hashlib.sha1("".join(lines).encode()).hexdigest()[:12]


# the kernels are compiled on the machine that runs them: its vector instructions, but no fused
# multiply-adds (-ffp-contract=off), so the kernels' numbers are those of a plain build. -O3 unrolls
# FFCx's loops over the jet element's tables (mostly zeros and ones) and folds them; without
# -ffast-math it may not change a result. FFCx's cache is keyed by these arguments, not by the CPU:
# the CPU's tag in a (unused) define keeps a kernel built for one CPU from being loaded on another
# that shares the cache (an HPC home folder)
_JIT_OPTIONS = {"cffi_extra_compile_args": ["-O3", "-march=native", "-ffp-contract=off", f"-DFEMPM_CPU={_cpu_tag()}"]}
_REGULAR, _LUMPED, _FIXED = 0, 1, 2  # subdomain ids of s.dx, s.dx_lumped and s.dx_fixed on the jet cell
_ffi = FFI()
_NO_VALUES = np.zeros((1, 0))  # the coefficients of no grid function (all are zero): no jets to take
_NO_SLOTS, _NO_COLUMNS = np.zeros((0, 0), dtype=np.int64), np.zeros(0, dtype=np.int64)  # nowhere to write them
_NO_FIELDS = (np.zeros((0, 1)),)  # a form without particle fields: nothing to copy


# --------------------------------------------------------------------------------------
# The jet cell
# --------------------------------------------------------------------------------------
def jet_element(order: int):
    """Scalar element on the reference square whose dofs are ``d^(a+b) f / dX^a dY^b (0, 0)``.

    The dual basis is ``X^a Y^b / (a! b!)`` for ``a + b <= order``, in the order of
    :func:`fempm.bases.jet_indices`; all dofs are interior (the element is discontinuous).
    """
    cell = basix.CellType.quadrilateral
    alphas = jet_indices(order)
    pts, wts = basix.make_quadrature(cell, 2 * order + 2)
    legendre = basix.tabulate_polynomials(basix.PolynomialType.legendre, cell, order, pts)
    from math import factorial

    monomials = np.array(
        [pts[:, 0] ** a * pts[:, 1] ** b / (factorial(a) * factorial(b)) for a, b in alphas]
    )
    wcoeffs = (monomials * wts) @ legendre.T
    n_derivs = (order + 1) * (order + 2) // 2
    M = np.zeros((len(alphas), 1, 1, n_derivs))
    for k, (a, b) in enumerate(alphas):
        M[k, 0, 0, basix.index(a, b)] = 1.0
    none_x = np.zeros((0, 2))
    none_m = np.zeros((0, 1, 0, n_derivs))
    x = [[none_x] * 4, [none_x] * 4, [np.zeros((1, 2))]]
    m = [[none_m] * 4, [none_m] * 4, [M]]
    return basix.ufl.custom_element(
        cell, [], wcoeffs, x, m, order, basix.MapType.identity, basix.SobolevSpace.L2,
        False, 0, order,
    )


class _JetCell:
    """A one-cell DOLFINx mesh of size h x h and the spaces the particle target needs."""

    def __init__(self, h: float, order: int):
        self.h, self.order = h, order
        self.mesh = dolfinx.mesh.create_rectangle(
            MPI.COMM_SELF, [[0.0, 0.0], [h, h]], [1, 1], dolfinx.mesh.CellType.quadrilateral
        )
        self.jet = jet_element(order)
        self.num_jets = len(jet_indices(order))

    def space(self, fields: dict[str, int]) -> dolfinx.fem.FunctionSpace:
        """Jet space of a field layout: blocked per field, mixed if several."""
        parts = [basix.ufl.blocked_element(self.jet, shape=(n,)) if n > 1 else self.jet for n in fields.values()]
        element = parts[0] if len(parts) == 1 else basix.ufl.mixed_element(parts)
        return dolfinx.fem.functionspace(self.mesh, element)

    def dof_index(self, fields: dict[str, int]) -> np.ndarray:
        """``index[C, a]``: element dof of component ``C`` (over all fields) and jet ``a``."""
        out, offset = [], 0
        for n in fields.values():
            for c in range(n):
                out.append([offset + a * n + c for a in range(self.num_jets)])
            offset += n * self.num_jets
        return np.array(out, dtype=np.int64)


def _derivative_order(expanded: ufl.Form, subdomain: int) -> int:
    """Highest number of nested gradients acting on a function in the integrals over ``subdomain``
    of a form whose derivatives are expanded (``ufl.algorithms.expand_derivatives``)."""
    from ufl.classes import Grad, ReferenceGrad
    from ufl.corealg.traversal import unique_pre_traversal

    order = 0
    for integral in expanded.integrals():
        if integral.subdomain_id() not in (subdomain, (subdomain,)):
            continue
        for node in unique_pre_traversal(integral.integrand()):
            depth = 0
            while isinstance(node, (Grad, ReferenceGrad)):
                depth, node = depth + 1, node.ufl_operands[0]
            order = max(order, depth)
    return order


# --------------------------------------------------------------------------------------
# Symbols: the UFL objects a form is written with
# --------------------------------------------------------------------------------------
class Symbols:
    """The UFL objects a weak form is written with, for one integration target.

    Attributes:
        trial, test: trial and test functions; a tuple with one entry per field for a
            space with several fields (``(u, p), (v, q) = s.trial, s.test``).
        dx: the integration measure (particles, or Gauss points).
        dx_lumped: nodal (row-sum lumped) quadrature on the particles: the integrand is
            evaluated per particle and basis function ``f`` with every grid function
            replaced by its coefficient at ``f``, and weighted by ``V_p N_f(x_p)``; a mass
            term over it gives the lumped (diagonal) mass matrix. Its integrand may not
            take derivatives. On the Gauss target it is the ordinary ``dx``.
        dx_fixed: quadrature at the step's fixed points, when it has them beside the particles
            (:mod:`fempm.pressure_points`: Gauss points of the cells the water reaches); a particle
            field there is the fixed points' own. On the Gauss target it is the ordinary ``dx``.
        x: the spatial coordinate.
        h: the grid cell size (a number).
    """

    def __init__(self, target, space: Space, particle_shapes, grid_functions, constants):
        self._target = target
        self._particle_shapes = dict(particle_shapes)
        self._grid_functions = dict(grid_functions)
        self._constants = dict(constants)
        self.used: dict[ufl.Coefficient, tuple[str, str]] = {}
        self.used_constants: dict[ufl.Constant, str] = {}
        self._cache: dict[tuple[str, str], object] = {}
        V = target.space(space.fields)
        self.function_space = V
        self.trial = self._split(ufl.TrialFunction(V), space.fields)
        self.test = self._split(ufl.TestFunction(V), space.fields)
        self.dx = target.dx
        self.dx_lumped = target.dx_lumped
        self.dx_fixed = target.dx_fixed
        self.x = ufl.SpatialCoordinate(target.mesh)
        self.h = space.grid.h

    @staticmethod
    def _split(u, fields):
        return ufl.split(u) if len(fields) > 1 else u

    def particle(self, name: str):
        """The per-particle field ``name`` (a number per particle, or a vector/tensor)."""
        if name not in self._particle_shapes:
            raise InputError(
                f"form uses particle field {name!r}, but the particles have {sorted(self._particle_shapes)}"
            )
        key = ("particle", name)
        if key not in self._cache:
            f = self._target.particle_coefficient(name, self._particle_shapes[name])
            self._cache[key] = f
            self.used[f] = key
        return self._cache[key]

    def grid(self, name: str):
        """The grid function ``name`` (whole; split a multi-field one with ``ufl.split``)."""
        if name not in self._grid_functions:
            raise InputError(
                f"form uses grid function {name!r}, but only {sorted(self._grid_functions)} were given"
            )
        key = ("grid", name)
        if key not in self._cache:
            f = self._target.grid_coefficient(name, self._grid_functions[name].space.fields)
            self._cache[key] = f
            self.used[f] = key
        return self._cache[key]

    def constant(self, name: str):
        """The constant ``name`` (its value is read from the constants mapping at assembly)."""
        if name not in self._constants:
            raise InputError(f"form uses constant {name!r}, but only {sorted(self._constants)} were given")
        key = ("constant", name)
        if key not in self._cache:
            c = dolfinx.fem.Constant(self._target.mesh, np.asarray(self._constants[name], dtype=np.float64))
            self._cache[key] = c
            self.used_constants[c] = name
        return self._cache[key]


class _ParticleTarget:
    """Where ``s.dx`` means the particles (see the module docstring)."""

    def __init__(self, jet_cell: _JetCell):
        self.jet_cell = jet_cell
        self.mesh = jet_cell.mesh
        rule = {
            "quadrature_rule": "custom",
            "quadrature_points": np.zeros((1, 2)),
            "quadrature_weights": np.ones(1),
        }
        measure = ufl.Measure("dx", domain=self.mesh, metadata=rule)
        self.dx, self.dx_lumped, self.dx_fixed = measure(_REGULAR), measure(_LUMPED), measure(_FIXED)
        self._spaces: dict[tuple, dolfinx.fem.FunctionSpace] = {}

    def space(self, fields):
        key = tuple(fields.items())
        if key not in self._spaces:
            self._spaces[key] = self.jet_cell.space(fields)
        return self._spaces[key]

    def particle_coefficient(self, name, shape):
        element = basix.ufl.element("DG", self.mesh.basix_cell(), 0, shape=shape)
        return dolfinx.fem.Function(dolfinx.fem.functionspace(self.mesh, element), name=f"particle:{name}")

    def grid_coefficient(self, name, fields):
        return dolfinx.fem.Function(self.space(fields), name=f"grid:{name}")


class _GaussTarget:
    """Where ``s.dx`` means Gauss quadrature of a given degree on the grid.

    ``grid_valued`` names the particle fields given by grid functions (their field
    layouts): those are Lagrange functions, which Gauss quadrature evaluates at its points.
    """

    def __init__(self, space: Space, degree: int, grid_valued: Mapping[str, dict] | None = None):
        self.grid_space = space
        self.grid_valued = dict(grid_valued or {})
        self.mesh = space.grid.mesh
        self.degree = degree
        self.dx = ufl.Measure("dx", domain=self.mesh, metadata={"quadrature_degree": degree})
        self.dx_lumped = self.dx  # Gauss quadrature has no nodal rule for B-splines: consistent
        self.dx_fixed = self.dx
        self._spaces: dict[tuple, dolfinx.fem.FunctionSpace] = {}

    def space(self, fields):
        key = tuple(fields.items())
        if key not in self._spaces:
            self._spaces[key] = lagrange_space(self.grid_space, fields)
        return self._spaces[key]

    def particle_coefficient(self, name, shape):
        if name in self.grid_valued:
            return dolfinx.fem.Function(self.space(self.grid_valued[name]), name=f"particle:{name}")
        element = basix.ufl.quadrature_element(self.mesh.basix_cell(), value_shape=shape, degree=self.degree)
        return dolfinx.fem.Function(dolfinx.fem.functionspace(self.mesh, element), name=f"particle:{name}")

    def grid_coefficient(self, name, fields):
        return dolfinx.fem.Function(self.space(fields), name=f"grid:{name}")


def _affine_in_particle_fields(integrals, symbols) -> bool:
    """Whether the integrands are affine in the particle fields jointly and do not use ``x``.

    Then the nodal quadrature ``sum_p w_p N_f(x_p) g(particle fields_p, grid at f)`` equals
    ``W_f g(averaged particle fields, grid at f)`` with ``W_f = sum_p w_p N_f(x_p)`` and the
    averages weighted alike: one kernel call per basis function instead of one per
    particle and function.
    """
    from ufl.classes import SpatialCoordinate
    from ufl.corealg.traversal import unique_pre_traversal

    if not integrals:
        return False
    if any(isinstance(node, SpatialCoordinate) for i in integrals for node in unique_pre_traversal(i.integrand())):
        return False
    form = ufl.Form(integrals)
    fields = [c for c in form.coefficients() if symbols.used.get(c, ("",))[0] == "particle"]
    for first in fields:
        once = ufl.derivative(form, first)
        for second in fields:
            if not ufl.algorithms.expand_derivatives(ufl.derivative(once, second)).empty():
                return False
    return True


def _check_cell_integrals(form: ufl.Form):
    kinds = {integral.integral_type() for integral in form.integrals()}
    if kinds - {"cell"}:
        raise InputError(f"fempm forms integrate over cells (dx) only; this form has {sorted(kinds)}")


def _constant_array(constants: Mapping, names: list[str]) -> np.ndarray:
    """The values of the named constants side by side, in the kernel's order."""
    return np.concatenate(
        [np.ravel(np.asarray(constants[name], dtype=np.float64)) for name in names]
        or [np.zeros(1)]
    )


# --------------------------------------------------------------------------------------
# Particle quadrature
# --------------------------------------------------------------------------------------
class _Coefficients:
    """A compiled form's coefficients in its kernel's order, packed per particle: particle fields
    as they are, grid functions as their jets at the particle (values and derivatives).

    The layout (where each coefficient's entries go) is fixed by the form and worked out once."""

    def __init__(self, coefficients, used, grid_functions, jet_cell, shapes):
        self.coefficients, self.used, self.grid_functions = coefficients, used, grid_functions
        self.jet_cell, self.shapes = jet_cell, shapes
        self._parts = []  # (kind, name, offset, size, index: [C, a] -> element dof of a grid function)
        offset = 0
        for coefficient in coefficients:
            kind, name = used[coefficient]
            if kind == "particle":
                index, size = None, int(np.prod(shapes[name], dtype=int))
            else:
                index = np.ascontiguousarray(jet_cell.dof_index(grid_functions[name].space.fields))
                size = index.size
            self._parts.append((kind, name, offset, size, index))
            offset += size
        self.width = max(offset, 1)  # as wide as what pack returns
        self._nodal_positions, self._particle_slots = self._positions()
        self._particle_parts = [(name, offset, size) for kind, name, offset, size, _ in self._parts if kind == "particle"]
        self._field_offsets = np.array([offset for _, offset, _ in self._particle_parts], dtype=np.int64)
        self._grid_parts = [(name, offset + index) for kind, name, offset, _, index in self._parts if kind != "particle"]
        self._jet_slots = {}  # which grid functions are non-zero -> (their slots, the zero ones' columns in pack)

    def pack(self, particles, phi, lfun) -> np.ndarray:
        """Per-particle coefficient arrays in the kernel's order (particle fields, grid jets): the
        grid functions side by side, their jets in one pass over the particles; a function that is
        zero everywhere (U at the start of a step between walls at rest) gets zero jets without the pass."""
        n = len(particles)
        if not self._parts:
            return np.zeros((n, 1))
        out = np.empty((n, self.width))
        fields = tuple(np.ascontiguousarray(particles[name].reshape(n, size))
                       for name, _, size in self._particle_parts) or _NO_FIELDS
        slots, zero, kept = _NO_SLOTS, _NO_COLUMNS, _NO_VALUES
        if self._grid_parts:
            values = tuple(self.grid_functions[name].values for name, _ in self._grid_parts)
            nonzero = assembly.nonzero_arrays(values)
            slots, zero = self._slots_of(nonzero)
            if slots.size:
                kept = assembly.side_by_side(v for v, keep in zip(values, nonzero) if keep)
        assembly.pack_coefficients(phi, lfun, kept, slots, zero, fields, self._field_offsets, out)
        return out

    def _slots_of(self, nonzero: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the jets of the non-zero grid functions go, and the columns of the zero ones (kept per set)."""
        key = nonzero.tobytes()
        if key not in self._jet_slots:
            slots = [index for (_, index), keep in zip(self._grid_parts, nonzero) if keep]
            zero = [index.ravel() for (_, index), keep in zip(self._grid_parts, nonzero) if not keep]
            self._jet_slots[key] = (np.concatenate(slots) if slots else _NO_SLOTS,
                                    np.concatenate(zero) if zero else _NO_COLUMNS)
        return self._jet_slots[key]

    def nodal_slots(self):
        """For lumped integrals: the grid functions' coefficients side by side, and where
        their values (``slot_pos`` <- column ``slot_col``) and derivatives (``zero_pos``) go."""
        columns = [self.grid_functions[name].values for kind, name, *_ in self._parts if kind != "particle"]
        G = assembly.side_by_side(columns) if columns else np.zeros((1, 1))
        return (G, *self._nodal_positions)

    def _positions(self):
        """``slot_pos, slot_col, zero_pos`` of :meth:`nodal_slots` and the particle fields' slots: fixed
        by the form, worked out once."""
        slot_pos, slot_col, zero_pos, particle = [], [], [], []
        column = 0
        for kind, name, offset, size, index in self._parts:
            if kind == "particle":
                particle.extend(range(offset, offset + size))
                continue
            bs = self.grid_functions[name].space.bs
            slot_pos.extend(offset + index[:, 0])
            slot_col.extend(column + np.arange(bs))
            zero_pos.extend(offset + index[:, 1:].ravel())
            column += bs
        as_int = lambda a: np.asarray(a, dtype=np.int64)  # noqa: E731
        return (as_int(slot_pos), as_int(slot_col), as_int(zero_pos)), as_int(particle)

    def particle_slots(self) -> np.ndarray:
        """Positions of the particle fields in the packed coefficients."""
        return self._particle_slots


class ParticleForm:
    """A UFL form integrated with the particles as quadrature points, compiled once.

    Args:
        builder: function of :class:`Symbols` returning a UFL form (rank 0, 1 or 2).
        space: the space of the test and trial functions.
        particle_shapes: value shape of every per-particle field the form may use,
            e.g. ``{"density": (), "velocity": (2,)}``; or pass a
            :class:`~fempm.particles.Particles` to take them from its fields.
        grid_functions: grid functions by name; their values are read at assembly.
        constants: constants by name; the mapping is read at every assembly, so
            changing a value in it (e.g. the time step) needs no recompilation.
    """

    def __init__(
        self,
        builder: FormBuilder,
        space: Space,
        particle_shapes=None,
        grid_functions: Mapping[str, GridFunction] | None = None,
        constants: Mapping | None = None,
    ):
        if hasattr(particle_shapes, "fields"):
            particle_shapes = {k: v.shape[1:] for k, v in particle_shapes.fields.items()}
        self.space = space
        self.grid_functions = grid_functions if grid_functions is not None else {}
        self.constants = constants if constants is not None else {}
        for name, gf in self.grid_functions.items():
            if gf.space.basis is not space.basis:
                raise InputError(f"grid function {name!r} is on another basis than the form's space")
        shapes = particle_shapes or {}
        order = 1
        while True:
            target = _ParticleTarget(_JetCell(space.grid.h, order))
            symbols = Symbols(target, space, shapes, self.grid_functions, self.constants)
            form = builder(symbols)
            _check_cell_integrals(form)
            expanded = ufl.algorithms.expand_derivatives(form)  # the slow part of building a form: once
            if _derivative_order(expanded, _LUMPED) > 0:
                raise InputError("an integral over dx_lumped may not take derivatives (it uses nodal values)")
            needed = max(_derivative_order(expanded, _REGULAR), _derivative_order(expanded, _FIXED), 1)
            if needed <= order:
                break
            if needed > 2:
                raise InputError(f"fempm jets go to second derivatives; the form takes {needed}")
            order = needed
        self.order = order
        self.ufl_form, self.expanded_form = form, expanded
        self.symbols = symbols
        # the kernel reads the constants the form holds, in the form's order: a constant
        # asked for but left out of the form (a term switched off) has no slot
        self._constant_names = [symbols.used_constants[c] for c in form.constants()]
        self._constant_values = None  # (array, slots): the kernel's constants, refilled at each assembly
        self._columns_of = (None, None)  # (residual, where this form's coefficients sit in its): _columns_in
        self._slots_of = (None, None, False)  # (residual, this form's particle fields' columns in it, same?): _slots_in
        self.rank = len(form.arguments())
        self._compiled = dolfinx.fem.form(form, jit_options=_JIT_OPTIONS)
        ufcx = self._compiled.ufcx_form
        # subdomain id -> address of the kernel of the regular, the lumped and the fixed points' integral
        self._kernels = {}
        for i in range(ufcx.form_integral_offsets[0], ufcx.form_integral_offsets[1]):
            address = int(_ffi.cast("intptr_t", ufcx.form_integrals[i].tabulate_tensor_float64))
            self._kernels[ufcx.form_integral_ids[i]] = address
        self.fixed = _FIXED in self._kernels  # whether it integrates over s.dx_fixed
        original = form.coefficients()
        coefficients = [original[ufcx.original_coefficient_positions[i]] for i in range(ufcx.num_coefficients)]
        lumped = [i for i in expanded.integrals() if i.subdomain_id() in (_LUMPED, (_LUMPED,))]
        lumped_grid = {c for i in lumped for c in ufl.algorithms.extract_coefficients(i.integrand())
                       if symbols.used.get(c, ("",))[0] == "grid"}
        self._lumped_per_function = bool(lumped_grid)  # else one kernel call per particle will do
        self._lumped_affine = _affine_in_particle_fields(lumped, symbols)
        self._nodal_sums = None  # per-function weights and weighted particle fields, made once
        self._perm = target.jet_cell.dof_index(space.fields)
        self._packing = _Coefficients(coefficients, symbols.used, self.grid_functions, target.jet_cell,
                                      {n: tuple(v) for n, v in symbols._particle_shapes.items()})

    def _function_sums(self, phi0, lfun, weight, coeffs, slots) -> np.ndarray:
        """``[W_f, sum_p w_p N_f(x_p) c_p]`` per local function, summed over all ranks; ``c_p`` the
        particle fields, columns ``slots`` of ``coeffs``."""
        if self._nodal_sums is None:  # the vector and its table, made once
            sums = dolfinx.la.vector(self.space.numbering.index_map, 1 + len(slots))
            self._nodal_sums = sums, vector_values(sums).reshape(-1, 1 + len(slots))
        sums, table = self._nodal_sums
        table[:] = 0.0
        assembly.nodal_sums(phi0, lfun, weight, coeffs, slots, table)
        sums.scatter_reverse(dolfinx.la.InsertMode.add)
        return table

    def particle_shape(self, name: str) -> tuple[int, ...]:
        """Value shape of a particle field the form uses."""
        return tuple(self.symbols._particle_shapes[name])

    def _basis_values(self, particles) -> np.ndarray:
        """``N_l(x_p)``, ``(n, (k+1)^2)`` (a view of the step's tabulation)."""
        return self.space.tabulate_particles(particles, 0, exact=False)[0][:, 0, :]

    def _particle_data(self, particles):
        phi, lfun = self.space.tabulate_particles(particles, self.order)
        phi = np.ascontiguousarray(phi)
        weight = particles["volume"] / self.space.grid.h**2
        coeffs = self._packing.pack(particles, phi, lfun)
        consts = self._constants_now()
        return phi, lfun, weight, coeffs, consts

    # -- assembly --------------------------------------------------------------------
    def assemble_matrix(self, particles, A: PETSc.Mat | None = None) -> PETSc.Mat:
        """The matrix ``A_ij = sum_p V_p a(phi_j, phi_i)(x_p)``, assembled (zeroed first if given)."""
        self._require_rank(2)
        target = self._zeroed_target(A)
        particles, fixed = _point_sets(particles, self)
        phi, lfun, weight, coeffs, consts = self._particle_data(particles)
        if _REGULAR in self._kernels:
            self._regular_matrix(target, particles, phi, lfun, weight, coeffs, np.arange(coeffs.shape[1]), consts)
        self._lumped_matrix(target, particles, lfun, weight, coeffs, self._packing.particle_slots(), consts)
        if _FIXED in self._kernels:
            phi, lfun, weight, coeffs, consts = self._particle_data(fixed)
            self._regular_matrix(target, fixed, phi, lfun, weight, coeffs, np.arange(coeffs.shape[1]), consts,
                                 kind=_FIXED)
        return target.finalize()

    def assemble_vector(self, particles, b: dolfinx.la.Vector | None = None) -> dolfinx.la.Vector:
        """The vector ``b_i = sum_p V_p L(phi_i)(x_p)``; owned entries complete, ghosts zero."""
        self._require_rank(1)
        b, values = self._zeroed_vector(b)
        particles, fixed = _point_sets(particles, self)
        phi, lfun, weight, coeffs, consts = self._particle_data(particles)
        if _REGULAR in self._kernels:
            self._regular_vector(values, particles, phi, lfun, weight, coeffs, consts)
        self._lumped_vector(values, particles, lfun, weight, coeffs, consts)
        if _FIXED in self._kernels:
            self._regular_vector(values, fixed, *self._particle_data(fixed), kind=_FIXED)
        b.scatter_reverse(dolfinx.la.InsertMode.add)
        return b

    def _regular_vector(self, values, points, phi, lfun, weight, coeffs, consts, kind=_REGULAR):
        """The ``dx`` part of the vector into its ``values`` (``kind`` = ``_FIXED``: the ``dx_fixed`` part, at the
        fixed points)."""
        assembly.assemble_vector(self._kernels[kind], values, points.x, points.cell, weight, phi, lfun, coeffs,
                                 consts, self._perm, self.space.grid.h)

    def assemble_with(self, residual: ParticleForm, particles, A: PETSc.Mat | None = None,
                      b: dolfinx.la.Vector | None = None, alongside=None) -> tuple[PETSc.Mat, dolfinx.la.Vector]:
        """This bilinear form's matrix and the vector of ``residual``, a linear form whose coefficients
        include this one's (the residual this form is the Jacobian of), in one pass over the particles.

        The coefficients are packed once, the residual's: this form's kernel reads its own among them,
        and a lumped part takes the residual's nodal sums. Two passes (:meth:`assemble_vector`, then
        :meth:`assemble_matrix`) where that cannot be: another space or jet order, a coefficient or
        a regular integral one of them lacks, or a lumped part not affine in the particle fields.

        ``alongside``: None, or ``(form, vector, where)``, a linear form that :meth:`joins` ``residual``'s pass,
        assembled into ``vector`` in it as well, over the particles ``where`` (a boolean mask) is true.
        """
        self._require_rank(2)
        columns = self._columns_in(residual)
        if alongside is not None and not (columns is not None and alongside[0].joins(residual)):
            raise ValueError("the form alongside cannot be assembled in the residual's pass")
        if columns is None:
            b = residual.assemble_vector(particles, b)
            return self.assemble_matrix(particles, A), b
        target, (b, values) = self._zeroed_target(A), residual._zeroed_vector(b)
        particles, fixed = _point_sets(particles, self)
        if _FIXED in self._kernels:  # the fixed points' integrals, in one pass too
            phi, lfun, weight, coeffs, consts_r = residual._particle_data(fixed)
            vector = (residual._kernels[_FIXED], values, consts_r, residual._perm)
            self._regular_matrix(target, fixed, phi, lfun, weight, coeffs, columns, self._constants_now(), vector,
                                 kind=_FIXED)
        phi, lfun, weight, coeffs, consts_r = residual._particle_data(particles)
        consts = self._constants_now()
        vector = (residual._kernels[_REGULAR], values, consts_r, residual._perm)
        extra = None
        if alongside is not None:
            form, out, where = alongside
            out_values = vector_values(out)
            out_values[:] = 0.0
            extra = (form._kernels[_REGULAR], out_values, form._constants_now(), form._perm, form._columns_in(residual),
                     where)
        self._regular_matrix(target, particles, phi, lfun, weight, coeffs, columns, consts, vector, alongside=extra)
        if alongside is not None:
            alongside[1].scatter_reverse(dolfinx.la.InsertMode.add)
        sums = residual._lumped_vector(values, particles, lfun, weight, coeffs, consts_r)
        slots, same_slots = self._slots_in(residual)
        self._lumped_matrix(target, particles, lfun, weight, coeffs, slots, consts, sums if same_slots else None)
        b.scatter_reverse(dolfinx.la.InsertMode.add)
        return target.finalize(), b

    def joins(self, residual: ParticleForm) -> bool:
        """Whether this linear form can be assembled in ``residual``'s pass (:meth:`assemble_with`'s
        ``alongside``): a regular integral alone, the residual's space and jets, its coefficients among the
        residual's, and no fixed points in that pass."""
        return (self.rank == 1 and set(self._kernels) == {_REGULAR} and _FIXED not in residual._kernels
                and self._columns_in(residual) is not None)

    def _constants_now(self) -> np.ndarray:
        """The constants' current values side by side in the kernel's order (:func:`_constant_array`),
        written into the same array at every assembly (their sizes are the form's)."""
        if self._constant_values is None:
            values = _constant_array(self.constants, self._constant_names)
            sizes = [np.size(self.constants[name]) for name in self._constant_names]
            starts = np.cumsum([0, *sizes])
            self._constant_values = values, [(name, slice(int(a), int(b)))
                                             for name, a, b in zip(self._constant_names, starts[:-1], starts[1:])]
            return values
        values, slots = self._constant_values
        for name, slot in slots:
            values[slot] = self.constants[name]
        return values

    def _columns_in(self, residual) -> np.ndarray | None:
        """Where this form's packed coefficients sit among ``residual``'s, if one pass can assemble
        both (see :meth:`assemble_with`); else None. Fixed by the two forms: worked out once."""
        if self._columns_of[0] is not residual:
            columns = self._find_columns(residual)
            if columns is not None:
                columns.setflags(write=False)
            self._columns_of = (residual, columns)
        return self._columns_of[1]

    def _slots_in(self, residual) -> tuple[np.ndarray, bool]:
        """This form's particle fields' columns among ``residual``'s packed coefficients (:meth:`_columns_in`), and
        whether they are the residual's own, so that its nodal sums serve this form's too (worked out once)."""
        if self._slots_of[0] is not residual:
            slots = self._columns_in(residual)[self._packing.particle_slots()]
            self._slots_of = (residual, slots, bool(np.array_equal(slots, residual._packing.particle_slots())))
        return self._slots_of[1], self._slots_of[2]

    def _find_columns(self, residual) -> np.ndarray | None:
        if (not isinstance(residual, ParticleForm) or residual.rank != 1 or residual.space is not self.space
                or residual.order != self.order or _REGULAR not in self._kernels
                or _REGULAR not in residual._kernels or (_FIXED in self._kernels) != (_FIXED in residual._kernels)
                or any(_LUMPED in form._kernels and not form._lumped_affine for form in (self, residual))):
            return None
        theirs = {(kind, name): (offset, size) for kind, name, offset, size, _ in residual._packing._parts}
        columns = []
        for kind, name, _, size, _ in self._packing._parts:
            offset, their_size = theirs.get((kind, name), (0, None))
            if their_size != size:
                return None
            columns.append(np.arange(offset, offset + size))
        return np.concatenate(columns) if columns else np.zeros(0, dtype=np.int64)

    def _zeroed_target(self, A: PETSc.Mat | None):
        """The grid matrix behind ``A`` (a new one if None), checked against the space and zeroed."""
        if A is None:
            A = create_matrix(self.space)
        target = grid_matrix(A)
        if target.space is not self.space and target.layout is not layout(self.space):
            raise InputError("the matrix was created by another space than the form's")
        target.zero()
        return target

    def _zeroed_vector(self, b: dolfinx.la.Vector | None) -> tuple[dolfinx.la.Vector, np.ndarray]:
        """``b`` (a new vector of the space if None), zeroed, and its values."""
        if b is None:
            b = self.space.create_vector()
        values = vector_values(b)
        values[:] = 0.0
        return b, values

    def _regular_matrix(self, target, particles, phi, lfun, weight, coeffs, columns, consts, vector=None,
                        kind=_REGULAR, alongside=None):
        """The ``dx`` part of the matrix (and of ``vector``'s and ``alongside``'s forms, see
        :func:`fempm.assembly.assemble_matrix`; ``kind`` = ``_FIXED``: the ``dx_fixed`` parts, at the fixed points)."""
        lay = target.layout
        assembly.assemble_matrix(
            self._kernels[kind], target.values, lay.indptr, lay.stencil, particles.x, particles.cell,
            weight, phi, lfun, coeffs, columns, consts, self._perm, self.space.grid.h, vector, alongside,
        )
        target.mark_written(lfun)

    def _lumped_matrix(self, target, particles, lfun, weight, coeffs, slots, consts, sums=None):
        """The ``dx_lumped`` part of the matrix. ``coeffs``: this form's packed coefficients, or for a part
        affine in the particle fields any whose columns ``slots`` hold those fields (``sums``: their
        nodal sums, if already made, :meth:`_function_sums`)."""
        if _LUMPED not in self._kernels:
            return
        lay, h = target.layout, self.space.grid.h
        if self._lumped_affine:
            if sums is None:
                sums = self._function_sums(self._basis_values(particles), lfun, weight, coeffs, slots)
            target.mark_written_where(sums[: self.space.numbering.num_owned, 0])  # other ranks' too
            assembly.assemble_matrix_nodal_affine(
                self._kernels[_LUMPED], target.values, lay.indptr, lay.stencil,
                sums, self.space.numbering.num_owned,
                self._packing.particle_slots(), self._packing.width, consts, self._perm, h, self._packing.nodal_slots(),
            )
        else:
            assembly.assemble_matrix_lumped(
                self._kernels[_LUMPED], target.values, lay.indptr, lay.stencil, particles.x, weight,
                self._basis_values(particles), lfun, coeffs, consts, self._perm, h, self._packing.nodal_slots(),
                self._lumped_per_function,
            )

    def _lumped_vector(self, values, particles, lfun, weight, coeffs, consts) -> np.ndarray | None:
        """The ``dx_lumped`` part of the vector, into its ``values``; the nodal sums it made (None: none)."""
        if _LUMPED not in self._kernels:
            return None
        h, slots = self.space.grid.h, self._packing.particle_slots()
        if not self._lumped_affine:
            assembly.assemble_vector_lumped(
                self._kernels[_LUMPED], values, particles.x, weight, self._basis_values(particles),
                lfun, coeffs, consts, self._perm, h, self._packing.nodal_slots(), self._lumped_per_function,
            )
            return None
        sums = self._function_sums(self._basis_values(particles), lfun, weight, coeffs, slots)
        assembly.assemble_vector_nodal_affine(
            self._kernels[_LUMPED], values, sums, self.space.numbering.num_owned, slots, self._packing.width,
            consts, self._perm, h, self._packing.nodal_slots(),
        )
        return sums

    def assemble_scalar(self, particles) -> float:
        """``sum_p V_p f(x_p)`` over the particles of all ranks."""
        self._require_rank(0)
        if _LUMPED in self._kernels or _FIXED in self._kernels:
            raise InputError("a functional cannot integrate over dx_lumped or dx_fixed")
        _, _, weight, coeffs, consts = self._particle_data(particles)
        local = assembly.assemble_scalar(
            self._kernels[_REGULAR], particles.x, weight, coeffs, consts, self.space.grid.h)
        return self.space.comm.allreduce(local)

    def _require_rank(self, rank: int):
        if self.rank != rank:
            names = {0: "a functional", 1: "a linear form", 2: "a bilinear form"}
            raise InputError(f"this form is {names[self.rank]}, not {names[rank]}")


def _point_sets(points, form: ParticleForm) -> tuple:
    """The particles and the fixed points of a step's points (``points.particles`` and ``points.fixed``,
    :class:`fempm.pressure_points.StepPoints`; or particles alone and None), for ``form``."""
    fixed = getattr(points, "fixed", None)
    if fixed is None and _FIXED in form._kernels:
        raise InputError("the forms integrate over s.dx_fixed, but the step has no fixed points: set "
                         "solver.pressure_quadrature = 'gauss'")
    return (points if fixed is None else points.particles), fixed


# --------------------------------------------------------------------------------------
# Ordinary Gauss quadrature (FEM reference)
# --------------------------------------------------------------------------------------
class GaussForm:
    """The same UFL form assembled by DOLFINx with Gauss quadrature, restricted to the basis.

    Args:
        builder, space, grid_functions, constants: as for :class:`ParticleForm`.
        particle_values: value of each per-particle field the form uses: a number, a
            callable of the points ``x`` (shape ``(3, n)``), or a :class:`GridFunction`
            on the form's basis (read at every assembly, like ``grid_functions``).
        degree: degree of the Gauss rule (default exact for products of two
            basis functions and their derivatives with a basis-degree coefficient).
    """

    def __init__(
        self,
        builder: FormBuilder,
        space: Space,
        particle_values: Mapping | None = None,
        grid_functions: Mapping[str, GridFunction] | None = None,
        constants: Mapping | None = None,
        degree: int | None = None,
    ):
        self.space = space
        self.particle_values = dict(particle_values or {})
        self.grid_functions = grid_functions if grid_functions is not None else {}
        self.constants = constants if constants is not None else {}
        self.degree = degree if degree is not None else 3 * space.basis.degree + 1
        grid_valued = {name: v for name, v in self.particle_values.items() if isinstance(v, GridFunction)}
        target = _GaussTarget(space, self.degree, {name: gf.space.fields for name, gf in grid_valued.items()})
        shapes = {name: _value_shape(v) for name, v in self.particle_values.items()}
        self.symbols = Symbols(target, space, shapes, self.grid_functions, self.constants)
        self.ufl_form = builder(self.symbols)
        _check_cell_integrals(self.ufl_form)
        self.rank = len(self.ufl_form.arguments())
        self._compiled = dolfinx.fem.form(self.ufl_form, jit_options=_JIT_OPTIONS)
        self._lagrange = target.space(space.fields)
        self.P = extraction_matrix(space, self._lagrange)
        self._grid_extraction = {}  # coefficient -> (grid function, its extraction matrix)
        for coefficient, (kind, name) in self.symbols.used.items():
            gf = self.grid_functions[name] if kind == "grid" else grid_valued.get(name)
            if gf is not None:
                self._grid_extraction[coefficient] = (gf, extraction_matrix(gf.space, coefficient.function_space))
        self._lagrange_matrix = None  # A_L of the last assembly, reused with ``out``
        self._fill_particle_values()

    @functools.cached_property
    def expanded_form(self):
        """The form with its derivatives applied (made when first asked for: DOLFINx's compilation
        does not need it)."""
        return ufl.algorithms.expand_derivatives(self.ufl_form)

    def _fill_particle_values(self):
        for coefficient, (kind, name) in self.symbols.used.items():
            value = self.particle_values.get(name)
            if kind != "particle" or isinstance(value, GridFunction):
                continue
            if callable(value):
                coefficient.interpolate(value)
            else:
                coefficient.x.array.reshape(-1, max(1, int(np.prod(np.shape(value)))))[:] = np.ravel(value)
                coefficient.x.scatter_forward()

    def _update(self):
        for coefficient, (gf, P) in self._grid_extraction.items():
            P.mult(gf.vector.petsc_vec, coefficient.x.petsc_vec)
            coefficient.x.scatter_forward()
        for constant, name in self.symbols.used_constants.items():
            constant.value = np.asarray(self.constants[name], dtype=np.float64)

    def assemble_matrix(self, out: PETSc.Mat | None = None) -> PETSc.Mat:
        """``P^T A_L P`` with ``A_L`` DOLFINx's Gauss assembly on the Lagrange space.

        ``out``, a matrix this method returned before, is filled again (its sparsity and
        the Lagrange matrix are reused: a stepped FEM-only run assembles into the same
        storage every step)."""
        self._update()
        if out is None or self._lagrange_matrix is None:
            self._lagrange_matrix = dolfinx.fem.petsc.create_matrix(self._compiled)
        A_L = self._lagrange_matrix
        A_L.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(A_L, self._compiled)
        A_L.assemble()
        return A_L.PtAP(self.P, result=out)

    def assemble_vector(self) -> PETSc.Vec:
        """``P^T b_L`` with ``b_L`` DOLFINx's Gauss assembly on the Lagrange space."""
        self._update()
        b_L = dolfinx.fem.petsc.assemble_vector(self._compiled)
        b_L.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        b = self.P.createVecRight()
        self.P.multTranspose(b_L, b)
        return b

    def assemble_scalar(self) -> float:
        """The functional by Gauss quadrature over all ranks."""
        self._update()
        return self.space.comm.allreduce(dolfinx.fem.assemble_scalar(self._compiled))


def _value_shape(value) -> tuple[int, ...]:
    """Value shape of a Gauss-target particle field: a number, a callable of ``x``, a grid function."""
    if isinstance(value, GridFunction):
        return (value.space.bs,) if value.space.bs > 1 else ()
    return np.shape(value(np.zeros((3, 1))))[:-1] if callable(value) else np.shape(value)
