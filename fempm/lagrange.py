"""The DOLFINx Lagrange space that contains a basis, and the extraction matrix.

Q1 is itself a Lagrange space; the quadratic B-splines are C1 functions that are
quadratic in each cell, so they lie in the Q2 Lagrange space of the same grid.
The extraction matrix ``P`` holds the Lagrange nodal values of every basis
function: a field with fempm coefficients ``c`` has Lagrange coefficients
``P c``, and a form assembled on the Lagrange space restricts to the basis as
``A = P^T A_L P``, ``b = P^T b_L``. Used for ordinary Gauss assembly (the
FEM-only reference) and for writing fields that ParaView reads.
"""

from __future__ import annotations

import basix.ufl
import numpy as np
from petsc4py import PETSc

import dolfinx.fem

from fempm.space import Space

__all__ = ["lagrange_element", "lagrange_space", "extraction_matrix"]


def lagrange_element(cell, degree: int, fields: dict[str, int]):
    """Basix/UFL element of the field layout: blocked Lagrange per field, mixed if several."""
    parts = [
        basix.ufl.element("Lagrange", cell, degree, shape=(n,) if n > 1 else ())
        for n in fields.values()
    ]
    return parts[0] if len(parts) == 1 else basix.ufl.mixed_element(parts)


def lagrange_space(space: Space, fields: dict[str, int] | None = None) -> dolfinx.fem.FunctionSpace:
    """The DOLFINx Lagrange space of the basis's degree with the given (default: the space's) fields."""
    mesh = space.grid.mesh
    fields = fields or space.fields
    return dolfinx.fem.functionspace(
        mesh, lagrange_element(mesh.basix_cell(), space.basis.lagrange_degree, fields)
    )


def _component_spaces(V: dolfinx.fem.FunctionSpace, fields: dict[str, int]):
    """Yield (component number, dofs of V) for every scalar component of the layout."""
    component = 0
    for f, n in enumerate(fields.values()):
        sub = V.sub(f) if len(fields) > 1 else V
        for c in range(n):
            scalar = sub.sub(c) if n > 1 else sub
            if scalar is V:
                imap = V.dofmap.index_map
                yield component, V, np.arange(imap.size_local + imap.num_ghosts)
            else:
                collapsed, dofs = scalar.collapse()
                yield component, collapsed, np.asarray(dofs).ravel()
            component += 1


def extraction_matrix(space: Space, V: dolfinx.fem.FunctionSpace | None = None) -> PETSc.Mat:
    """``P``: rows the owned dofs of the Lagrange space ``V``, columns the dofs of ``space``."""
    V = V or lagrange_space(space)
    basis, grid, num = space.basis, space.grid, space.numbering
    imap = V.dofmap.index_map
    bs_v = V.dofmap.index_map_bs
    n_owned_rows = imap.size_local * bs_v
    row_global0 = imap.local_range[0] * bs_v
    rows, cols, vals = [], [], []
    for component, collapsed, dofs in _component_spaces(V, space.fields):
        x = collapsed.tabulate_dof_coordinates()[:, :2]
        owned = dofs < n_owned_rows
        x, dofs = x[owned], dofs[owned]
        cells, xi = grid.locate(x)
        values = basis.tabulate(cells, xi, order=0)[:, 0, :]
        functions = num.global_index[basis.cell_functions(cells)]
        keep = np.abs(values) > 1e-14
        rows.append(np.broadcast_to(dofs[:, None], values.shape)[keep])
        cols.append((space.bs * functions + component)[keep])
        vals.append(values[keep])
    rows, cols, vals = (np.concatenate(a) for a in (rows, cols, vals))
    order = np.lexsort((cols, rows))
    rows, cols, vals = rows[order], cols[order], vals[order]
    indptr = np.searchsorted(rows, np.arange(n_owned_rows + 1))
    P = PETSc.Mat().create(comm=space.comm)
    P.setSizes(((n_owned_rows, PETSc.DECIDE), (space.num_owned_dofs, space.num_global_dofs)))
    P.setType(PETSc.Mat.Type.AIJ)
    P.setPreallocationCSR((indptr.astype(PETSc.IntType), cols.astype(PETSc.IntType), vals))
    P.assemble()
    assert P.getOwnershipRange()[0] == row_global0
    return P
