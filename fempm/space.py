"""Equal-order function spaces on a basis, their parallel numbering and ghosted vectors.

A :class:`Space` is one basis carrying named fields, e.g. ``{"u": 2, "p": 1}``
for velocity and pressure. Its unknowns are interleaved per basis function,
``dof = bs * function + component`` with ``bs`` the total number of components,
so every matrix has block size ``bs`` and a field is a stride of the vector.

Parallel layout: a basis function is owned by the rank owning its anchor cell
(:meth:`fempm.bases.Basis.anchor_cell`). A rank's local functions are its owned
ones, numbered contiguously in the global numbering, followed by the ghosts: the
functions non-zero in its cells but owned elsewhere. The numbering is kept in a
DOLFINx ``IndexMap``, so vectors are DOLFINx ``la.Vector`` objects whose
``petsc_vec`` is a ghosted PETSc vector.
"""

from __future__ import annotations

import weakref
from functools import cached_property

import numpy as np

import dolfinx.la
from dolfinx.common import IndexMap

from fempm.bases import Basis
from fempm.errors import InputError

__all__ = ["GridFunction", "Numbering", "Space", "vector_values"]


class Numbering:
    """Parallel numbering of the functions of a basis (shared by all its spaces).

    Attributes:
        owner: rank owning each structured function.
        global_index: global number of each structured function.
        local_functions: structured indices of this rank's owned then ghost functions.
        local_index: local number of each structured function, -1 if not local.
        index_map: the DOLFINx ``IndexMap`` (block size 1) of the functions.
    """

    def __init__(self, basis: Basis):
        grid = basis.grid
        comm = grid.comm
        nf = basis.num_functions
        structured = np.arange(nf, dtype=np.int64)
        self.owner = grid.owner[basis.anchor_cell(structured)]
        by_owner = np.lexsort((structured, self.owner))
        self.global_index = np.empty(nf, dtype=np.int64)
        self.global_index[by_owner] = structured
        owned = by_owner[self.owner[by_owner] == comm.rank]
        touched = np.unique(basis.cell_functions(grid.owned_cells))
        ghosts = touched[self.owner[touched] != comm.rank]
        self.num_owned = len(owned)
        self.local_functions = np.concatenate([owned, ghosts])
        self.local_index = np.full(nf, -1, dtype=np.int32)
        self.local_index[self.local_functions] = np.arange(len(self.local_functions), dtype=np.int32)
        self.index_map = IndexMap(
            comm, self.num_owned, self.global_index[ghosts], self.owner[ghosts].astype(np.int32), 0
        )

    @property
    def num_local(self) -> int:
        """Owned plus ghost functions on this rank."""
        return len(self.local_functions)


def numbering(basis: Basis) -> Numbering:
    """The (cached) parallel numbering of a basis."""
    if not hasattr(basis, "_numbering"):
        basis._numbering = Numbering(basis)
    return basis._numbering


class Space:
    """Named fields of given component counts on one basis, unknowns interleaved.

    Args:
        basis: :class:`~fempm.bases.Q1` or :class:`~fempm.bases.BSpline2`.
        fields: mapping of field name to number of components, in order;
            e.g. ``{"u": 2, "p": 1}``. Default: one scalar field ``"u"``.
    """

    def __init__(self, basis: Basis, fields: dict[str, int] | None = None):
        fields = dict(fields or {"u": 1})
        for name, n in fields.items():
            if int(n) != n or n < 1:
                raise InputError(f"space: field {name!r} needs a positive number of components, got {n}")
        self.basis = basis
        self.grid = basis.grid
        self.comm = basis.grid.comm
        self.fields = {name: int(n) for name, n in fields.items()}
        self.bs = sum(self.fields.values())
        self.numbering = numbering(basis)
        starts = np.cumsum([0, *self.fields.values()])
        self._slices = {name: slice(int(a), int(b)) for name, a, b in zip(self.fields, starts[:-1], starts[1:])}
        self._components = {}  # by tuple of names (components)
        self._offsets = {}  # by tuple of names (offsets)

    def __repr__(self) -> str:
        return f"Space({self.basis.name}, {self.fields})"

    def field_offset(self, name: str) -> int:
        """First component of field ``name`` within a block of ``bs`` dofs."""
        return self.field_slice(name).start

    def field_slice(self, name: str) -> slice:
        """The components of field ``name`` within a block of ``bs`` dofs."""
        try:
            return self._slices[name]
        except KeyError:
            raise InputError(f"space has no field {name!r}; its fields are {list(self.fields)}") from None

    def offsets(self, *names: str) -> np.ndarray:
        """The first component of each named field within a block of ``bs`` dofs (read-only, made once per
        tuple of names)."""
        index = self._offsets.get(names)
        if index is None:
            index = np.array([self.field_offset(name) for name in names], dtype=np.int64)
            index.setflags(write=False)
            self._offsets[names] = index
        return index

    def components(self, *names: str) -> np.ndarray:
        """The components of the named fields within a block of ``bs`` dofs, field after field
        (read-only, made once per tuple of names)."""
        index = self._components.get(names)
        if index is None:
            index = np.concatenate([np.arange(self.bs)[self.field_slice(name)] for name in names])
            index.setflags(write=False)
            self._components[names] = index
        return index

    def wall_dofs(self, name: str, component: int, walls: str = "lrbt") -> np.ndarray:
        """Global indices of owned dofs of one component of a field on the given walls.

        ``walls`` is any of ``l``, ``r``, ``b``, ``t`` (left, right, bottom, top). Both
        bases interpolate at the walls, so fixing these coefficients fixes the
        field's values there.
        """
        b, num = self.basis, self.numbering
        owned = num.local_functions[: num.num_owned]
        i, j = owned % b.nfx, owned // b.nfx
        on = np.zeros(len(owned), dtype=bool)
        for wall, mask in (("l", i == 0), ("r", i == b.nfx - 1), ("b", j == 0), ("t", j == b.nfy - 1)):
            if wall in walls:
                on |= mask
        first = self.field_offset(name)
        if not 0 <= component < self.fields[name]:
            raise InputError(f"field {name!r} has {self.fields[name]} components, not {component + 1}")
        return self.bs * num.global_index[owned[on]] + first + component

    def cell_dofs(self, name: str, cells) -> np.ndarray:
        """Global indices of owned dofs of field ``name`` whose function is non-zero in any given cell."""
        num = self.numbering
        touching = np.zeros(self.basis.num_functions, dtype=bool)
        touching[self.basis.cell_functions(np.asarray(cells, dtype=np.int64)).ravel()] = True
        owned = num.local_functions[: num.num_owned]
        first = self.field_offset(name)
        comps = np.arange(first, first + self.fields[name])
        return (self.bs * num.global_index[owned[touching[owned]]][:, None] + comps).ravel()

    @property
    def num_owned_dofs(self) -> int:
        """Dofs owned by this rank."""
        return self.numbering.num_owned * self.bs

    @property
    def num_global_dofs(self) -> int:
        """Dofs on all ranks."""
        return self.basis.num_functions * self.bs

    @cached_property
    def local_to_global(self) -> np.ndarray:
        """Global index of every local (owned, then ghost) dof."""
        g = self.numbering.global_index[self.numbering.local_functions]
        return (self.bs * g[:, None] + np.arange(self.bs)).ravel()

    def local_functions_of_cells(self, cells: np.ndarray) -> np.ndarray:
        """Local function numbers of the functions non-zero in each (local) cell."""
        return self.basis.cell_functions(cells, self.numbering.local_index)

    def tabulate_particles(self, particles, order: int = 1, exact: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Jets of the basis at the particles and their local function numbers.

        Cached on the particles until they are relocated; a cached higher order
        serves a lower one (jets are listed by total order): as a contiguous copy of its first
        jets, kept for the next caller, or with ``exact=False`` as it is (more jets than asked,
        for a reader that takes the first ones: no copy).

        Returns:
            ``phi`` of shape ``(n, len(jet_indices(order)), (k+1)^2)`` (``exact=False``: perhaps
            more jets) and ``lfun`` of shape ``(n, (k+1)^2)``.
        """
        num_jets = (order + 1) * (order + 2) // 2
        for cached_order in (order, order + 1, order + 2):
            hit = particles.cache.get((id(self.basis), cached_order))
            if hit is not None:
                if cached_order != order and exact:  # kept contiguous for the next caller of this order
                    hit = (np.ascontiguousarray(hit[0][:, :num_jets]), *hit[1:])
                    particles.cache[(id(self.basis), order)] = hit
                return hit[0], hit[1]
        phi = self.basis.tabulate(particles.cell, particles.xi, order)
        lfun = self.local_functions_of_cells(particles.cell)
        # the basis is kept with its tabulation: alive, its id cannot be reused by another basis
        particles.cache[(id(self.basis), order)] = (phi, lfun, self.basis)
        return phi, lfun

    # -- vectors ----------------------------------------------------------------------
    def create_vector(self) -> dolfinx.la.Vector:
        """A DOLFINx vector with ghosts (``.array`` is owned then ghost dofs).

        Keep the vector itself while its ``petsc_vec`` is in use: the PETSc vector wraps
        its memory. Each vector holds MPI neighbourhood communicators, so a time loop
        should create its vectors once and reuse them.
        """
        return dolfinx.la.vector(self.numbering.index_map, self.bs)


_VALUES = weakref.WeakKeyDictionary()  # vector -> its values' view (vector_values)


def vector_values(vector: dolfinx.la.Vector) -> np.ndarray:
    """``vector.array``, the view made once per vector: DOLFINx makes a new one at each access (about a
    microsecond), and a vector's storage never moves."""
    values = _VALUES.get(vector)
    if values is None:
        values = _VALUES[vector] = vector.array
    return values


class GridFunction:
    """Coefficients of a :class:`Space` on this rank's local functions (owned and ghost).

    ``values`` has shape ``(num_local_functions, bs)``; after changing owned
    values call :meth:`scatter_forward` to update the ghosts.
    """

    def __init__(self, space: Space, name: str = "f"):
        self.space = space
        self.name = name
        self.vector = space.create_vector()
        self._array = vector_values(self.vector)
        self._values = self._array.reshape(-1, space.bs)

    @property
    def array(self) -> np.ndarray:
        """View of the local coefficients as the vector holds them, dof by dof (``vector.array``)."""
        return self._array

    @property
    def values(self) -> np.ndarray:
        """View of the local coefficients, shape ``(num_local_functions, bs)``."""
        return self._values

    def field(self, name: str) -> np.ndarray:
        """View of the components of one field, shape ``(num_local_functions, ncomp)``."""
        return self.values[:, self.space.field_slice(name)]

    def scatter_forward(self):
        """Copy owned values to the ghosts on other ranks."""
        self.vector.scatter_forward()

    def scatter_reverse_add(self):
        """Add ghost contributions into their owners (after a local accumulation)."""
        self.vector.scatter_reverse(dolfinx.la.InsertMode.add)

    def evaluate(self, cells: np.ndarray, xi: np.ndarray, order: int = 0) -> np.ndarray:
        """Jets of the function at points on this rank's cells.

        Returns:
            ``(n, len(jet_indices(order)), bs)``; derivatives are with respect to the
            reference coordinates (divide by ``h**(a+b)`` for physical ones).
        """
        phi = self.space.basis.tabulate(cells, xi, order)
        lf = self.space.local_functions_of_cells(cells)
        return np.einsum("pql,plc->pqc", phi, self.values[lf])
