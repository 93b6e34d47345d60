"""The exact solve of a small velocity-pressure system in one compiled call (one rank).

On a few hundred pressure dofs (the shipped dam break: about 300 to 400) PETSc's field split
(:mod:`fempm.schur`, :mod:`fempm.linear`) spends more in set-ups than in arithmetic: its blocks
keep a padded pattern, and each time the water reaches a function outside it (a quarter of the
steps) the blocks, the split and S's symbolic LU are made again. This solve has no pattern to keep.
At every call, from the grid matrix's CSR storage (:mod:`fempm.matrix`) and the free dofs:

0. the three rows of each function with a free dof copied side by side, block by block (:func:`_block_rows`):
   the passes below read them in order and one column a block, a function's three rows summed together;
1. ``S = A11 - A10 diag(A00)^-1 A01`` on the free pressure dofs, each row summed on a dense box
   of the functions within twice the stencil's reach (as :func:`fempm.schur._schur_values` does);
2. S's rows and columns in reverse Cuthill-McKee order (a breadth-first search from a function of
   least degree), S in band storage, and its LU without pivoting (as PETSc's own LU of S, which
   does not pivot either), each row's upper part only as far as its fill reaches;
3. Richardson's iteration on the whole free system preconditioned by the full Schur factorisation
   with ``diag(A00)`` for ``A00`` (``u* = D^-1 r_u``, ``S p = r_p - A10 u*``, ``u = D^-1 (r_u - A01 p)``),
   to the residual ``rtol |b|``. The velocity block is the lumped mass over ``beta dt^2`` plus a viscous
   part smaller by ``~ 2 mu dt / (rho h^2)``, so each iteration gains as many decades as FGMRES's
   iterations on the same factorisation do (three to round-off in the dam break).

A velocity block far from diagonal (a very viscous flow: :data:`DIAGONAL_SHARE`, checked first), a zero
pivot, or an iteration that stops gaining (round-off's floor above the tolerance) returns a negative
status: the caller then solves by PETSc's split, whose FGMRES does not need the block diagonal
(:meth:`fempm.linear.LinearSolver.solve`). Nothing is kept between calls, so a run resumed from a
checkpoint solves as the uninterrupted run does.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from fempm.schur import _subtract_pair

__all__ = ["DIAGONAL_SHARE", "NOT_CONVERGED", "NOT_DIAGONAL", "ZERO_PIVOT", "solve"]

#: statuses of :func:`solve` other than the iterations taken
ZERO_PIVOT, NOT_CONVERGED, NOT_DIAGONAL = -1, -2, -3

#: the largest share of a velocity row's diagonal its off-diagonal velocity entries may sum to: the iteration's
#: error shrinks each time by about the velocity block's departure from its diagonal, the viscous part over the
#: mass over ``beta dt^2``, ``~ 2 mu beta dt^2 / (rho h^2)`` (water on the shipped grid: below 1e-3)
DIAGONAL_SHARE = 0.1


@numba.njit(cache=True, inline="always")
def _subtract(acc, corner, s, square, side, box):
    """``acc -= s square`` on the ``side`` x ``side`` square at ``corner`` of the box (rows of ``box``)."""
    for dy in range(side):
        row = corner + box * dy
        for dx in range(side):
            acc[row + dx] -= s * square[side * dy + dx]


@numba.njit(cache=True)
def _block_rows(indptr, columns, values, functions, rows, first_column, blocks):
    """The three rows of each function ``functions[i]`` side by side, block by block:
    ``rows[i, q, D, C]`` is entry ``D`` of block ``q`` of row ``(f, C)`` (a function's rows have the same
    columns), ``first_column[i, q]`` the block's first column, ``blocks[i]`` the blocks in a row. A product
    over a function's rows then reads one array in order and one column a block."""
    for i in range(functions.shape[0]):
        r = 3 * functions[i]
        k0 = indptr[r]
        length = indptr[r + 1] - k0
        blocks[i] = length // 3
        for q in range(blocks[i]):
            first_column[i, q] = columns[k0 + 3 * q]
            for D in range(3):
                for C in range(3):
                    rows[i, q, D, C] = values[k0 + C * length + 3 * q + D]


@numba.njit(cache=True)
def _schur(rows, first_column, function_at, stencil, nfx, reach, p_dofs, u_dofs, pos, diag, pointer, cols, vals,
           squares):
    """CSR of ``A11 - A10 diag(A00)^-1 A01`` on the free pressure dofs ``p_dofs`` (columns by ``pos``, in
    increasing order; entries that sum to exactly zero left out), from :func:`_block_rows`; ``squares``: room for
    each velocity row of A01 on its stencil."""
    width, box = 2 * reach + 1, 4 * reach + 1
    places = width * width
    squares[:] = 0.0  # each velocity row of A01 on its stencil, free columns
    for j in range(u_dofs.shape[0]):
        c = u_dofs[j]
        if c % 3 == 1 and j > 0 and u_dofs[j - 1] == c - 1:
            continue  # done with its function's first row
        i = function_at[c // 3]
        both = c % 3 == 0 and j + 1 < u_dofs.shape[0] and u_dofs[j + 1] == c + 1
        for place in range(places):
            q = stencil[c // 3, place]
            if q >= 0 and pos[first_column[i, q] + 2] >= 0:
                squares[j, place] = rows[i, q, 2, c % 3]
                if both:
                    squares[j + 1, place] = rows[i, q, 2, 1]
    corner = np.empty(places, dtype=np.int64)  # a stencil place's stencil, placed in the box
    for place in range(places):
        corner[place] = box * (place // width) + place % width
    acc = np.zeros(box * box)
    count = 0
    for n in range(p_dofs.shape[0]):
        f = p_dofs[n] // 3
        i = function_at[f]
        fi, fj = f % nfx, f // nfx
        for place in range(places):
            q = stencil[f, place]
            if q < 0:
                continue
            c0 = first_column[i, q]
            if pos[c0 + 2] >= 0:
                acc[corner[place] + (box + 1) * reach] += rows[i, q, 2, 2]
            a0, a1 = rows[i, q, 0, 2], rows[i, q, 1, 2]
            if reach == 2 and pos[c0] >= 0 and a0 != 0.0 and pos[c0 + 1] >= 0 and a1 != 0.0:
                # the quadratic B-spline's, as constants: the loops unroll
                _subtract_pair(acc, corner[place], a0 / diag[pos[c0]], a1 / diag[pos[c0 + 1]], squares[pos[c0]],
                               squares[pos[c0 + 1]], 5, 9)
                continue
            for D in range(2):
                c = c0 + D
                if pos[c] < 0 or rows[i, q, D, 2] == 0.0:
                    continue
                s = rows[i, q, D, 2] / diag[pos[c]]
                if reach == 2:
                    _subtract(acc, corner[place], s, squares[pos[c]], 5, 9)
                else:
                    _subtract(acc, corner[place], s, squares[pos[c]], width, box)
        for by in range(box):
            for bx in range(box):
                b = bx + box * by
                if acc[b] != 0.0:
                    cols[count] = pos[3 * (fi + bx - 2 * reach + nfx * (fj + by - 2 * reach)) + 2]
                    vals[count] = acc[b]
                    count += 1
                    acc[b] = 0.0
        pointer[n + 1] = count


@numba.njit(cache=True)
def _reverse_cuthill_mckee(pointer, cols, order):
    """``order``: the rows of the pattern in reverse Cuthill-McKee order (each component from a row
    of least degree, neighbours by increasing degree)."""
    n = order.shape[0]
    degree = pointer[1:] - pointer[:-1]
    visited = np.zeros(n, dtype=np.bool_)
    head = tail = 0
    while tail < n:
        start, least = -1, np.iinfo(np.int64).max
        for v in range(n):
            if not visited[v] and degree[v] < least:
                start, least = v, degree[v]
        order[tail] = start
        visited[start] = True
        tail += 1
        while head < tail:
            v = order[head]
            head += 1
            first = tail
            for k in range(pointer[v], pointer[v + 1]):
                w = cols[k]
                if visited[w]:
                    continue
                visited[w] = True
                j = tail
                while j > first and degree[order[j - 1]] > degree[w]:
                    order[j] = order[j - 1]
                    j -= 1
                order[j] = w
                tail += 1
    order[:] = order[::-1].copy()


@numba.njit(cache=True)
def _band(pointer, cols, vals, order, room):
    """S in band storage in ``order`` (``band[i, j - i + lower]``; in ``room`` if it fits), its lower bandwidth,
    and the last column of each row."""
    n = order.shape[0]
    at = np.empty(n, dtype=np.int64)
    at[order] = np.arange(n)
    lower, upper = 0, 0
    last = np.arange(n)
    for old in range(n):
        i = at[old]
        for k in range(pointer[old], pointer[old + 1]):
            j = at[cols[k]]
            lower = max(lower, i - j)
            upper = max(upper, j - i)
            last[i] = max(last[i], j)
    size = n * (lower + upper + 1)
    band = room[:size].reshape((n, lower + upper + 1)) if size <= room.shape[0] else np.empty((n, lower + upper + 1))
    band[:] = 0.0
    for old in range(n):
        i = at[old]
        for k in range(pointer[old], pointer[old + 1]):
            band[i, at[cols[k]] - i + lower] = vals[k]
    return band, lower, last


@numba.njit(cache=True)
def _band_lu(band, lower, last):
    """LU without pivoting in place (unit L below the diagonal); a row's upper part is taken only up to
    its ``last`` column, which the elimination widens as fill reaches further. False at a zero pivot.
    The pivot row's upper part is copied out first, so that the row updates read one array and write
    another, each a contiguous slice of the band's flat storage: the compiler then vectorises them (indexed
    through the 2-D array, it gathered)."""
    n, w = band.shape
    flat = band.reshape(n * w)
    pivot_row = np.empty(w)
    for k in range(n):
        pivot = flat[k * w + lower]
        if pivot == 0.0 or not np.isfinite(pivot):
            return False
        length = last[k] - k
        for j in range(length):
            pivot_row[j] = flat[k * w + lower + 1 + j]
        for i in range(k + 1, min(n, k + lower + 1)):
            at = i * w + k - i + lower
            l = flat[at]
            if l == 0.0:
                continue
            l /= pivot
            flat[at] = l
            seg = flat[at + 1: at + 1 + length]
            for j in range(length):
                seg[j] -= l * pivot_row[j]
            last[i] = max(last[i], last[k])
    return True


@numba.njit(cache=True)
def _band_solve(band, lower, last, y):
    """``y = U^-1 L^-1 y`` with the factors of :func:`_band_lu`."""
    n = band.shape[0]
    for i in range(n):
        s = y[i]
        for j in range(max(0, i - lower), i):
            s -= band[i, j - i + lower] * y[j]
        y[i] = s
    for i in range(n - 1, -1, -1):
        s = y[i]
        for j in range(i + 1, last[i] + 1):
            s -= band[i, j - i + lower] * y[j]
        y[i] = s / band[i, lower]


@numba.njit(cache=True)
def _functions_of(free):
    """The functions of the dofs ``free`` (in increasing order), each once."""
    functions = np.empty(free.shape[0], dtype=np.int64)
    count = 0
    for i in range(free.shape[0]):
        f = free[i] // 3
        if count == 0 or functions[count - 1] != f:
            functions[count] = f
            count += 1
    return functions[:count]


@numba.njit(cache=True)
def _solve(indptr, columns, values, stencil, nfx, reach, free, b, rtol, max_it, x, reals, integers):
    n = b.shape[0]
    pos = np.full(n, -1, dtype=np.int64)  # a free dof's place among its field's
    is_pressure = free % 3 == 2
    p_dofs, u_dofs = free[is_pressure], free[~is_pressure]
    pos[p_dofs] = np.arange(p_dofs.shape[0])
    pos[u_dofs] = np.arange(u_dofs.shape[0])
    functions = _functions_of(free)
    function_at = np.full(stencil.shape[0], -1, dtype=np.int64)
    function_at[functions] = np.arange(functions.shape[0])
    places = stencil.shape[1]
    nf, box = functions.shape[0], 4 * reach + 1
    npr, nu = p_dofs.shape[0], u_dofs.shape[0]
    at = np.cumsum(np.array([0, 9 * places * nf, places * nu, box * box * npr]))  # the scratch's parts
    rows = reals[at[0]: at[1]].reshape((nf, places, 3, 3))
    squares = reals[at[1]: at[2]].reshape((nu, places))
    vals = reals[at[2]: at[3]]
    first_column = integers[: places * nf].reshape((nf, places))
    cols = integers[places * nf: places * nf + box * box * npr]
    blocks = np.empty(nf, np.int64)
    _block_rows(indptr, columns, values, functions, rows, first_column, blocks)
    centre = (places - 1) // 2
    diag = np.empty(u_dofs.shape[0])
    for i in range(functions.shape[0]):  # a function's two velocity rows side by side
        d = 3 * functions[i]
        if pos[d] < 0 and pos[d + 1] < 0:
            continue
        off0 = off1 = 0.0
        for q in range(blocks[i]):
            for D in range(2):
                c = first_column[i, q] + D
                if pos[c] >= 0:
                    if c != d:
                        off0 += abs(rows[i, q, D, 0])
                    if c != d + 1:
                        off1 += abs(rows[i, q, D, 1])
        q = stencil[functions[i], centre]
        for C in range(2):
            if pos[d + C] >= 0:
                diag[pos[d + C]] = rows[i, q, C, C]
                if not (off0 if C == 0 else off1) <= DIAGONAL_SHARE * abs(rows[i, q, C, C]):
                    return NOT_DIAGONAL
    pointer = np.zeros(npr + 1, dtype=np.int64)
    _schur(rows, first_column, function_at, stencil, nfx, reach, p_dofs, u_dofs, pos, diag, pointer, cols, vals,
           squares)
    order = np.empty(npr, dtype=np.int64)
    _reverse_cuthill_mckee(pointer, cols, order)
    band, lower, last = _band(pointer, cols, vals, order, reals[at[3]:])
    if not _band_lu(band, lower, last):
        return ZERO_PIVOT
    x[:] = 0.0
    r = np.zeros(n)
    r[free] = b[free]
    norm_b = np.sqrt(np.sum(r * r))
    u_star, p_new = np.zeros(n), np.zeros(n)
    y, t = np.empty(npr), np.empty(npr)
    last_norm = norm_b
    for iteration in range(1, max_it + 1):
        for j in range(u_dofs.shape[0]):  # the full factorisation's inverse applied to r
            u_star[u_dofs[j]] = r[u_dofs[j]] / diag[j]
        for i in range(functions.shape[0]):  # A10 u*
            d = 3 * functions[i] + 2
            if pos[d] < 0:
                continue
            s = 0.0
            for q in range(blocks[i]):
                c = first_column[i, q]
                s += rows[i, q, 0, 2] * u_star[c]
                s += rows[i, q, 1, 2] * u_star[c + 1]
            t[pos[d]] = s
        for j in range(npr):
            y[j] = r[p_dofs[order[j]]] - t[order[j]]
        _band_solve(band, lower, last, y)
        for j in range(npr):
            p_new[p_dofs[order[j]]] = y[j]
        for i in range(functions.shape[0]):  # u = D^-1 (r_u - A01 p)
            d = 3 * functions[i]
            if pos[d] < 0 and pos[d + 1] < 0:
                continue
            s0 = s1 = 0.0
            for q in range(blocks[i]):
                p = p_new[first_column[i, q] + 2]
                s0 += rows[i, q, 2, 0] * p
                s1 += rows[i, q, 2, 1] * p
            if pos[d] >= 0:
                x[d] += (r[d] - s0) / diag[pos[d]]
            if pos[d + 1] >= 0:
                x[d + 1] += (r[d + 1] - s1) / diag[pos[d + 1]]
        for j in range(npr):
            x[p_dofs[j]] += p_new[p_dofs[j]]
        norm = 0.0
        for i in range(functions.shape[0]):  # r = b - A x, a function's three rows side by side
            d = 3 * functions[i]
            s0 = s1 = s2 = 0.0
            for q in range(blocks[i]):
                c = first_column[i, q]
                for D in range(3):
                    xc = x[c + D]
                    s0 += rows[i, q, D, 0] * xc
                    s1 += rows[i, q, D, 1] * xc
                    s2 += rows[i, q, D, 2] * xc
            for C in range(3):
                if pos[d + C] >= 0:
                    r[d + C] = b[d + C] - (s0 if C == 0 else s1 if C == 1 else s2)
                    norm += r[d + C] * r[d + C]
        norm = np.sqrt(norm)
        if norm <= rtol * norm_b:
            return iteration
        if not norm <= 0.5 * last_norm:  # round-off's floor, or a flow the factorisation does not fit
            return NOT_CONVERGED
        last_norm = norm
    return NOT_CONVERGED


def solve(grid_matrix, free: np.ndarray, b: np.ndarray, rtol: float, x: np.ndarray, max_it: int = 20) -> int:
    """``A[free, free] x[free] = b[free]`` for a grid matrix of a velocity (two components) and a pressure
    (the last), one rank; ``x`` (by dof, as ``b``) zero on the other dofs.

    Returns:
        the iterations taken, or :data:`NOT_DIAGONAL` (a velocity row past :data:`DIAGONAL_SHARE`), :data:`ZERO_PIVOT`
        or :data:`NOT_CONVERGED` (``x`` is then not a solution).
    """
    lay, space = grid_matrix.layout, grid_matrix.space
    if space.bs != 3:
        raise ValueError(f"the compiled solve takes two velocity components and a pressure, not {space.bs} dofs "
                         "a function")
    reach = (math.isqrt(lay.stencil.shape[1]) - 1) // 2
    reals, integers = _scratch(len(free), lay.stencil.shape[1], 4 * reach + 1)
    return int(_solve(lay.indptr, lay.columns, grid_matrix.values, lay.stencil, space.basis.nfx, reach,
                      _integers(free), b, rtol, max_it, x, reals, integers))


def _integers(free) -> np.ndarray:
    """``free`` as an array of integers, of its own width if it is one (PETSc's dofs: no copy)."""
    free = np.asarray(free)
    return free if free.dtype.kind == "i" else free.astype(np.int64)


#: the solves' scratch memory (reals, integers), kept from call to call: the same memory, still in cache, rather
#: than new; what a solve reads of it, it has written first
_SCRATCH = [np.empty(0), np.empty(0, dtype=np.int64)]


def _scratch(free_dofs: int, places: int, box: int) -> list[np.ndarray]:
    """Scratch memory for a solve of ``free_dofs`` (:data:`_SCRATCH`, grown by half again if too small, so that
    a region that grows a little from step to step does not renew it each time): the block rows, the squares of
    A01, S's values and a band of twice S's stencil (a wider one is allocated), and their integers."""
    reals, integers = free_dofs * (9 * places + places + 3 * box * box), free_dofs * (places + box * box)
    if _SCRATCH[0].shape[0] < reals:
        _SCRATCH[0] = np.empty(reals * 3 // 2)
    if _SCRATCH[1].shape[0] < integers:
        _SCRATCH[1] = np.empty(integers * 3 // 2, dtype=np.int64)
    return _SCRATCH
