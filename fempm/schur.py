"""The free-dof system of a grid matrix as velocity and pressure blocks, cut from its CSR storage.

On one rank the step's exact solve (:mod:`fempm.linear`) is a Schur-complement field split of the
free dofs. PETSc would extract the free-dof block from the matrix, then the four blocks of the
split from that, and form the ``selfp`` complement ``S = A11 - A10 diag(A00)^-1 A01`` by a
sparse product, all again whenever the free dofs change (nearly every step). Here the four blocks
``A00, A01, A10, A11`` (velocity dofs first, then pressure, each in increasing order) and ``S``
are cut straight from the grid matrix's CSR arrays (:mod:`fempm.matrix`) in one pass each.

The blocks' pattern is that of a *padded* set of dofs: those of the functions within a margin
(:data:`PATTERN_MARGIN` functions by default) of a free one (the *seed*). A dof of the pattern that is not free
this step has an identity row and column (its solution is zero, and the free dofs' equations are
those of the free block), so while the free dofs stay inside the pattern (the water moves a cell
in several steps) a solve takes only new values, and the solver keeps its orderings and symbolic
factorisations. The pattern is a function of the seed alone (the dofs of the functions, not the
rows the matrix happens to store), so a run resumed with its seed
(:meth:`fempm.linear.LinearSolver.pattern_seed`), or one whose matrix has rows only near the
water, solves as the uninterrupted run on the whole grid does. The blocks form a PETSc
``MATNEST`` whose field split takes them as they are.
"""

from __future__ import annotations

import numba
import numpy as np
from petsc4py import PETSc

__all__ = ["PATTERN_MARGIN", "FreeBlocks"]

#: Functions by which the blocks' pattern reaches beyond the free dofs' functions.
PATTERN_MARGIN = 1


@numba.njit(cache=True)
def _numbering(free, field_of_component, num_dofs):
    """Field of every dof (-1: not free), its position within its field's block, and the dofs of
    each field (increasing)."""
    bs = field_of_component.shape[0]
    field = np.full(num_dofs, -1, dtype=np.int8)
    position = np.empty(num_dofs, dtype=np.int32)
    counts = np.zeros(2, dtype=np.int64)
    for g in free:
        f = field_of_component[g % bs]
        field[g] = f
        position[g] = counts[f]
        counts[f] += 1
    rows0 = np.empty(counts[0], dtype=np.int64)
    rows1 = np.empty(counts[1], dtype=np.int64)
    for g in free:
        if field[g] == 0:
            rows0[position[g]] = g
        else:
            rows1[position[g]] = g
    return field, position, rows0, rows1


@numba.njit(cache=True)
def _row_blocks(indptr, stencil, nfx, nfy, bs, rows, field, position):
    """CSR patterns of the two blocks of ``rows``: the pattern's dofs (``field`` >= 0) among those of
    the functions in the stencil of the row's function, by field; row pointers, columns (block
    numbering, increasing as the grid matrix's are), every entry's place in the grid matrix's
    values (-1 in a row the matrix does not store: rows only near the water) and the place of its
    column's function in the row's function's stencil (``(di + k) + (2k + 1) (dj + k)``, ``k`` the
    stencil's reach). The pattern follows from the functions alone, whichever rows the matrix
    stores."""
    n = rows.shape[0]
    width = int(np.sqrt(stencil.shape[1]) + 0.5)
    k = (width - 1) // 2
    capacity = n * width * width * bs
    pointer0, pointer1 = np.zeros(n + 1, dtype=np.int32), np.zeros(n + 1, dtype=np.int32)
    cols0, cols1 = np.empty(capacity, dtype=np.int32), np.empty(capacity, dtype=np.int32)
    source0, source1 = np.empty(capacity, dtype=np.int64), np.empty(capacity, dtype=np.int64)
    place0, place1 = np.empty(capacity, dtype=np.int32), np.empty(capacity, dtype=np.int32)
    count0 = count1 = 0
    for i in range(n):
        r = rows[i]
        f = r // bs
        fi, fj = f % nfx, f // nfx
        stored = indptr[r + 1] > indptr[r]
        for gj in range(max(fj - k, 0), min(fj + k, nfy - 1) + 1):
            for gi in range(max(fi - k, 0), min(fi + k, nfx - 1) + 1):
                place = (gi - fi + k) + width * (gj - fj + k)
                base = indptr[r] + bs * stencil[f, place] if stored else -1
                for D in range(bs):
                    c = bs * (gi + nfx * gj) + D
                    b = field[c]
                    if b == 0:
                        cols0[count0] = position[c]
                        source0[count0] = base + D if stored else -1
                        place0[count0] = place
                        count0 += 1
                    elif b == 1:
                        cols1[count1] = position[c]
                        source1[count1] = base + D if stored else -1
                        place1[count1] = place
                        count1 += 1
        pointer0[i + 1] = count0
        pointer1[i + 1] = count1
    return ((pointer0, cols0[:count0].copy(), source0[:count0].copy(), place0[:count0].copy()),
            (pointer1, cols1[:count1].copy(), source1[:count1].copy(), place1[:count1].copy()))


@numba.njit(cache=True)
def _diagonal_positions(pointer, cols):
    """Position of the diagonal entry of every row of a square block (-1: none stored)."""
    n = pointer.shape[0] - 1
    out = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        for k in range(pointer[i], pointer[i + 1]):
            if cols[k] == i:
                out[i] = k
    return out


@numba.njit(cache=True)
def _masked_values(pointer, cols, source, row_free, col_free, square, grid_values, out):
    """A block's values: the grid matrix's where row and column are free; elsewhere the identity
    (``square``: a diagonal block) or zero."""
    for i in range(pointer.shape[0] - 1):
        start, stop = pointer[i], pointer[i + 1]
        if row_free[i]:  # (its diagonal entry's column is free too)
            for k in range(start, stop):
                out[k] = grid_values[source[k]] if col_free[np.uintp(cols[k])] else 0.0  # an index >= 0
        else:
            out[start:stop] = 0.0
            if square:
                for k in range(start, stop):
                    if cols[k] == i:
                        out[k] = 1.0


@numba.njit(cache=True)
def _schur_pattern(rows, position, bs, near, k):
    """Pattern of ``A11 - A10 diag(A00)^-1 A01`` for the pressure ``rows`` (global dofs), columns
    increasing within each row (block numbering: ``position``), and every entry's place in its
    row's box (:func:`_schur_values`).

    ``near`` ``(nfy, nfx)``: the pattern's functions (all of a function's dofs are in it or none);
    the blocks couple functions within ``k`` of each other on both axes (their stencil). So the
    column of the pressure dof of function ``g`` is in the row of function ``f`` where a pattern
    function ``m`` lies within ``k`` of both (through ``A10`` and ``A01``; ``m = f`` for ``A11``):
    a count over the box of such ``m``, by 2-D prefix sums, for each ``g`` within ``2k`` of ``f``,
    visited in increasing order."""
    nfy, nfx = near.shape
    total = np.zeros((nfy + 1, nfx + 1), dtype=np.int64)  # functions of the pattern in [0, j) x [0, i)
    for j in range(nfy):
        for i in range(nfx):
            total[j + 1, i + 1] = total[j, i + 1] + total[j + 1, i] - total[j, i] + near[j, i]
    n = rows.shape[0]
    pointer = np.zeros(n + 1, dtype=np.int32)
    box = 4 * k + 1
    cols = np.empty(n * box**2, dtype=np.int32)
    in_box = np.empty(n * box**2, dtype=np.int64)
    count = 0
    for r in range(n):
        f, component = rows[r] // bs, rows[r] % bs
        fi, fj = f % nfx, f // nfx
        for gj in range(max(fj - 2 * k, 0), min(fj + 2 * k, nfy - 1) + 1):
            j0, j1 = max(max(fj, gj) - k, 0), min(min(fj, gj) + k, nfy - 1) + 1
            for gi in range(max(fi - 2 * k, 0), min(fi + 2 * k, nfx - 1) + 1):
                if not near[gj, gi]:
                    continue
                i0, i1 = max(max(fi, gi) - k, 0), min(min(fi, gi) + k, nfx - 1) + 1
                if total[j1, i1] - total[j0, i1] - total[j1, i0] + total[j0, i0] > 0:
                    cols[count] = position[bs * (gi + nfx * gj) + component]
                    in_box[count] = box * (gj - fj + 2 * k) + (gi - fi + 2 * k)
                    count += 1
        pointer[r + 1] = count
    return pointer, cols[:count].copy(), in_box[:count].copy()


@numba.njit(cache=True)
def _fill_squares(p01, v01, place01, squares):
    """The rows of ``A01`` on their functions' stencils (``squares[m]``, in the places of
    :func:`_row_blocks`; zero where a row has no entry)."""
    for m in range(p01.shape[0] - 1):
        for q in range(p01[m], p01[m + 1]):
            squares[m, place01[q]] = v01[q]


@numba.njit(cache=True, inline="always")
def _subtract_pair(acc, corner, s0, s1, square0, square1, side, box):
    """``acc -= s0 square0 + s1 square1`` on the square at ``corner`` of the box, entry by entry
    (the first dof's product first)."""
    for dy in range(side):
        row = corner + box * dy
        for dx in range(side):
            partial = acc[row + dx] - s0 * square0[side * dy + dx]
            acc[row + dx] = partial - s1 * square1[side * dy + dx]


@numba.njit(cache=True)
def _schur_values(pointer, in_box, reach, p11, v11, place11, p10, c10, v10, place10, squares, diagonal, out):
    """``out`` = the values of ``A11 - A10 diag(A00)^-1 A01`` on its pattern (:func:`_schur_pattern`).

    A row of function ``f`` is summed on a dense *box*, the functions within ``2 reach`` of ``f``
    (side ``4 reach + 1``, row by row): ``A11``'s entries, then for each velocity function of the
    row of ``A10`` in turn (its two dofs, side by side) its rows of ``A01`` whole, on their stencils
    (:func:`_fill_squares`: side ``2 reach + 1``) within the box. ``place11``, ``place10``: the
    entries' places in ``f``'s stencil (:func:`_row_blocks`); ``in_box``: the pattern's places in
    the box. Each sum is added to in the same order as entry by entry over the sparse rows; the
    stencils' zeros add nothing (the sums start at +0 and never become -0, so subtracting a zero
    product leaves them as they are)."""
    side, box = 2 * reach + 1, 4 * reach + 1
    corner = np.empty(side * side, dtype=np.int64)  # by place in f's stencil: that function's stencil in the box
    for place in range(side * side):
        corner[place] = box * (place // side) + place % side
    acc = np.empty(box * box)
    for i in range(pointer.shape[0] - 1):
        acc[:] = 0.0
        for k in range(p11[i], p11[i + 1]):
            acc[corner[place11[k]] + (box + 1) * reach] += v11[k]
        for k in range(p10[i], p10[i + 1], 2):
            a0, a1 = v10[k], v10[k + 1]
            if a0 == 0.0 and a1 == 0.0:  # a pair or a row not free this solve: adds nothing
                continue
            m = c10[k]
            s0 = a0 / diagonal[m]
            s1 = a1 / diagonal[m + 1]
            if reach == 2:  # the quadratic B-spline's, as constants: the loops unroll
                _subtract_pair(acc, corner[place10[k]], s0, s1, squares[m], squares[m + 1], 5, 9)
            else:
                _subtract_pair(acc, corner[place10[k]], s0, s1, squares[m], squares[m + 1], side, box)
        for k in range(pointer[i], pointer[i + 1]):
            out[k] = acc[in_box[k]]


@numba.njit(cache=True)
def _near(free, bs, nfx, nfy, margin):
    """The functions ``(nfy, nfx)`` within ``margin`` of a free dof's function on both axes
    (structured numbering: one rank)."""
    near = np.zeros((nfy, nfx), dtype=np.bool_)
    for g in free:
        f = g // bs
        fi, fj = f % nfx, f // nfx
        for j in range(max(fj - margin, 0), min(fj + margin, nfy - 1) + 1):
            for i in range(max(fi - margin, 0), min(fi + margin, nfx - 1) + 1):
                near[j, i] = True
    return near


class FreeBlocks:
    """The free dofs of a grid matrix (one rank) as a 2 x 2 ``MATNEST`` of velocity and pressure
    blocks on a padded pattern (see the module's docstring), and the ``selfp`` Schur complement of
    its (1, 1) block.

    Args:
        grid_matrix: the :class:`fempm.matrix.GridMatrix` behind the system.
        free: the free dofs (global numbers, increasing) whose values the blocks take.
        fields: components per field of the interleaved dofs: a velocity of two, then one more.
        seed: the free dofs the pattern is padded around (default ``free``).
        margin: functions by which the pattern reaches beyond the seed's.

    Attributes:
        nest: the PETSc ``MATNEST`` ``[[A00, A01], [A10, A11]]``.
        schur: ``A11 - A10 diag(A00)^-1 A01`` (AIJ).
        order: the global dof of every row of ``nest`` (the first field's dofs, then the second's).
        index_sets: the rows of each field in ``nest`` (named as ``fields``).
        seed: as given.
    """

    def __init__(self, grid_matrix, free: np.ndarray, fields: dict[str, int], seed: np.ndarray | None = None,
                 margin: int = PATTERN_MARGIN):
        self.grid_matrix, self.seed = grid_matrix, np.asarray(free if seed is None else seed, dtype=np.int64)
        lay, space = grid_matrix.layout, grid_matrix.space
        names = list(fields)
        if len(fields) != 2 or fields[names[0]] != 2:
            raise ValueError(f"the blocks need a two-component field and another, not {fields}")
        field_of_component = np.repeat(np.arange(2), [fields[names[0]], fields[names[1]]]).astype(np.int64)
        near = _near(self.seed, space.bs, space.basis.nfx, space.basis.nfy, margin)
        pattern = (space.bs * np.flatnonzero(near)[:, None] + np.arange(space.bs)).ravel()  # the dofs, increasing
        field, position, rows0, rows1 = _numbering(pattern, field_of_component, lay.num_owned_rows)
        self._field = field
        self.order = np.concatenate([rows0, rows1])
        self._sizes = (len(rows0), len(rows1))
        rows = (rows0, rows1)
        self._blocks, self._places = {}, {}  # the places of the blocks the Schur complement reads
        for i in range(2):
            cut = _row_blocks(lay.indptr, lay.stencil, space.basis.nfx, space.basis.nfy, space.bs, rows[i], field,
                              position)
            for j, (pointer, cols, source, place) in enumerate(cut):
                self._blocks[i, j] = (pointer, cols, source, np.empty(len(cols)))
                if i + j > 0:
                    self._places[i, j] = place
        self._diagonal = _diagonal_positions(self._blocks[0, 0][0], self._blocks[0, 0][1])
        if np.any(self._diagonal < 0):
            raise ValueError("a velocity dof has no diagonal entry")
        self._fill_blocks(free)
        self._mats = [[PETSc.Mat().createAIJWithArrays((len(rows[i]), len(rows[j])), self._block_arrays(i, j),
                                                       comm=PETSc.COMM_SELF) for j in range(2)] for i in range(2)]
        self.nest = PETSc.Mat().createNest(self._mats, comm=PETSc.COMM_SELF)
        self._reach = (int(np.sqrt(lay.stencil.shape[1]) + 0.5) - 1) // 2  # the stencil's reach
        self._schur_pointer, self._schur_cols, self._in_box = _schur_pattern(rows1, position, space.bs, near,
                                                                             self._reach)
        self._schur_values = np.empty(len(self._schur_cols))
        self._squares = np.zeros((len(rows0), lay.stencil.shape[1]))
        self._fill_schur()
        n1 = len(rows1)
        self.schur = PETSc.Mat().createAIJWithArrays(
            (n1, n1), (self._schur_pointer, self._schur_cols, self._schur_values), comm=PETSc.COMM_SELF)
        isets = self.nest.getNestISs()[0]
        self.index_sets = [(names[0], isets[0]), (names[1], isets[1])]
        # a right-hand side and a solution in the rows of nest, kept with the pattern
        self.vectors = tuple(PETSc.Vec().createSeq(len(self.order), comm=PETSc.COMM_SELF) for _ in range(2))

    def covers(self, free: np.ndarray) -> bool:
        """Whether every one of the ``free`` dofs is in the pattern."""
        return bool(np.all(self._field[free] >= 0))

    def _block_arrays(self, i, j):
        pointer, cols, _, values = self._blocks[i, j]
        return pointer, cols, values

    def _fill_blocks(self, free: np.ndarray):
        is_free = np.zeros(len(self._field), dtype=np.bool_)
        is_free[free] = True
        self._free = is_free[self.order]  # per row of nest: free in this solve
        n0 = self._sizes[0]
        part = (self._free[:n0], self._free[n0:])
        for (i, j), (pointer, cols, source, values) in self._blocks.items():
            _masked_values(pointer, cols, source, part[i], part[j], i == j, self.grid_matrix.values, values)

    def refill(self, free: np.ndarray):
        """Take the grid matrix's current values for these ``free`` dofs (:meth:`covers` them)."""
        self._fill_blocks(free)
        for row in self._mats:
            for m in row:
                m.stateIncrease()
        self.nest.stateIncrease()
        self._fill_schur()
        self.schur.stateIncrease()

    def _fill_schur(self):
        p01, _, _, v01 = self._blocks[0, 1]
        _fill_squares(p01, v01, self._places[0, 1], self._squares)
        (p11, _, _, v11), (p10, c10, _, v10) = self._blocks[1, 1], self._blocks[1, 0]
        _schur_values(self._schur_pointer, self._in_box, self._reach, p11, v11, self._places[1, 1], p10, c10, v10,
                      self._places[1, 0], self._squares, self._blocks[0, 0][3][self._diagonal], self._schur_values)

    def restrict(self, vector: np.ndarray, out: np.ndarray):
        """A vector by global dof into ``out`` in the rows of ``nest``, zero on the dofs not free."""
        np.take(vector, self.order, out=out)
        out[~self._free] = 0.0

    def extend(self, solution: np.ndarray, out: np.ndarray):
        """The free rows of a solution in the rows of ``nest`` into ``out``, by global dof."""
        out[self.order[self._free]] = solution[self._free]

    def destroy(self):
        for row in self._mats:
            for m in row:
                m.destroy()
        self.nest.destroy()
        self.schur.destroy()
        for vector in self.vectors:
            vector.destroy()
