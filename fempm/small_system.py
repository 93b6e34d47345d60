"""The exact solve of a small velocity-pressure system in one compiled call (one rank).

On a few hundred pressure dofs (the shipped dam break: about 300 to 400) PETSc's field split
(:mod:`fempm.schur`, :mod:`fempm.linear`) spends more in set-ups than in arithmetic: its blocks
keep a padded pattern, and each time the water reaches a function outside it (a quarter of the
steps) the blocks, the split and S's symbolic LU are made again. This solve has no pattern to keep.
At every call, from the grid matrix's CSR storage (:mod:`fempm.matrix`) and the free dofs:

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

import numba
import numpy as np

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
def _schur(indptr, columns, values, stencil, nfx, reach, bs, p_dofs, u_dofs, pos, diag, pointer, cols, vals):
    """CSR of ``A11 - A10 diag(A00)^-1 A01`` on the free pressure dofs ``p_dofs`` (columns by ``pos``, in
    increasing order; entries that sum to exactly zero left out)."""
    width, box = 2 * reach + 1, 4 * reach + 1
    places = width * width
    squares = np.zeros((u_dofs.shape[0], places))  # each velocity row of A01 on its stencil, free columns
    for i in range(u_dofs.shape[0]):
        c = u_dofs[i]
        for place in range(places):
            q = stencil[c // bs, place]
            if q >= 0:
                k = indptr[c] + bs * q + bs - 1
                if pos[columns[k]] >= 0:
                    squares[i, place] = values[k]
    corner = np.empty(places, dtype=np.int64)  # a stencil place's stencil, placed in the box
    for place in range(places):
        corner[place] = box * (place // width) + place % width
    acc = np.zeros(box * box)
    count = 0
    for i in range(p_dofs.shape[0]):
        r = p_dofs[i]
        f = r // bs
        fi, fj = f % nfx, f // nfx
        for place in range(places):
            q = stencil[f, place]
            if q < 0:
                continue
            k = indptr[r] + bs * q
            if pos[columns[k + bs - 1]] >= 0:
                acc[corner[place] + (box + 1) * reach] += values[k + bs - 1]
            for D in range(bs - 1):
                c = columns[k + D]
                if pos[c] < 0 or values[k + D] == 0.0:
                    continue
                s = values[k + D] / diag[pos[c]]
                if reach == 2:  # the quadratic B-spline's, as constants: the loops unroll
                    _subtract(acc, corner[place], s, squares[pos[c]], 5, 9)
                else:
                    _subtract(acc, corner[place], s, squares[pos[c]], width, box)
        for by in range(box):
            for bx in range(box):
                b = bx + box * by
                if acc[b] != 0.0:
                    cols[count] = pos[bs * (fi + bx - 2 * reach + nfx * (fj + by - 2 * reach)) + bs - 1]
                    vals[count] = acc[b]
                    count += 1
                    acc[b] = 0.0
        pointer[i + 1] = count


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
def _band(pointer, cols, vals, order):
    """S in band storage in ``order`` (``band[i, j - i + lower]``), its lower bandwidth, and the last
    column of each row."""
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
    band = np.zeros((n, lower + upper + 1))
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
    another (the compiler then vectorises them)."""
    n = band.shape[0]
    pivot_row = np.empty(band.shape[1])
    for k in range(n):
        pivot = band[k, lower]
        if pivot == 0.0 or not np.isfinite(pivot):
            return False
        length = last[k] - k
        for j in range(length):
            pivot_row[j] = band[k, lower + 1 + j]
        for i in range(k + 1, min(n, k + lower + 1)):
            l = band[i, k - i + lower]
            if l == 0.0:
                continue
            l /= pivot
            band[i, k - i + lower] = l
            row, start = band[i], k + 1 - i + lower
            for j in range(length):
                row[start + j] -= l * pivot_row[j]
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
def _products(indptr, columns, values, bs, rows, first, count, x, out):
    """``out[i]`` = row ``rows[i]`` times ``x`` over its columns of components ``first .. first + count - 1``.
    ``rows`` in increasing order: where all three rows of a function (the same columns) are there, they are summed
    side by side, each in its own order, so that the sums' chains of additions overlap."""
    i = 0
    while i < rows.shape[0]:
        r = rows[i]
        if bs == 3 and i + 2 < rows.shape[0] and rows[i + 2] == r + 2 and r % 3 == 0:
            o1, o2 = indptr[r + 1] - indptr[r], indptr[r + 2] - indptr[r]
            s0 = s1 = s2 = 0.0
            for k in range(indptr[r], indptr[r + 1], bs):
                for D in range(first, first + count):
                    xk = x[columns[k + D]]
                    s0 += values[k + D] * xk
                    s1 += values[k + o1 + D] * xk
                    s2 += values[k + o2 + D] * xk
            out[i], out[i + 1], out[i + 2] = s0, s1, s2
            i += 3
            continue
        s = 0.0
        for k in range(indptr[r], indptr[r + 1], bs):
            for D in range(first, first + count):
                s += values[k + D] * x[columns[k + D]]
        out[i] = s
        i += 1


@numba.njit(cache=True)
def _solve(indptr, columns, values, stencil, nfx, reach, bs, free, b, rtol, max_it, x):
    n = b.shape[0]
    pos = np.full(n, -1, dtype=np.int64)  # a free dof's place among its field's
    is_pressure = free % bs == bs - 1
    p_dofs, u_dofs = free[is_pressure], free[~is_pressure]
    pos[p_dofs] = np.arange(p_dofs.shape[0])
    pos[u_dofs] = np.arange(u_dofs.shape[0])
    centre = (stencil.shape[1] - 1) // 2
    diag = np.empty(u_dofs.shape[0])
    for i in range(u_dofs.shape[0]):
        r = u_dofs[i]
        diag[i] = values[indptr[r] + bs * stencil[r // bs, centre] + r % bs]
        off = 0.0
        for k in range(indptr[r], indptr[r + 1], bs):
            for D in range(bs - 1):
                if columns[k + D] != r and pos[columns[k + D]] >= 0:
                    off += abs(values[k + D])
        if not off <= DIAGONAL_SHARE * abs(diag[i]):
            return NOT_DIAGONAL
    npr = p_dofs.shape[0]
    box = 4 * reach + 1
    pointer = np.zeros(npr + 1, dtype=np.int64)
    cols, vals = np.empty(npr * box * box, dtype=np.int64), np.empty(npr * box * box)
    _schur(indptr, columns, values, stencil, nfx, reach, bs, p_dofs, u_dofs, pos, diag, pointer, cols, vals)
    order = np.empty(npr, dtype=np.int64)
    _reverse_cuthill_mckee(pointer, cols, order)
    band, lower, last = _band(pointer, cols, vals, order)
    if not _band_lu(band, lower, last):
        return ZERO_PIVOT
    x[:] = 0.0
    r = np.zeros(n)
    r[free] = b[free]
    norm_b = np.sqrt(np.sum(r * r))
    u_star, p_new = np.zeros(n), np.zeros(n)
    y, t = np.empty(npr), np.empty(npr)
    a01p, ax = np.empty(u_dofs.shape[0]), np.empty(free.shape[0])
    last_norm = norm_b
    for iteration in range(1, max_it + 1):
        for i in range(u_dofs.shape[0]):  # the full factorisation's inverse applied to r
            u_star[u_dofs[i]] = r[u_dofs[i]] / diag[i]
        _products(indptr, columns, values, bs, p_dofs, 0, bs - 1, u_star, t)
        for i in range(npr):
            y[i] = r[p_dofs[order[i]]] - t[order[i]]
        _band_solve(band, lower, last, y)
        for i in range(npr):
            p_new[p_dofs[order[i]]] = y[i]
        _products(indptr, columns, values, bs, u_dofs, bs - 1, 1, p_new, a01p)
        for i in range(u_dofs.shape[0]):
            x[u_dofs[i]] += (r[u_dofs[i]] - a01p[i]) / diag[i]
        for i in range(npr):
            x[p_dofs[i]] += p_new[p_dofs[i]]
        _products(indptr, columns, values, bs, free, 0, bs, x, ax)
        norm = 0.0
        for i in range(free.shape[0]):
            r[free[i]] = b[free[i]] - ax[i]
            norm += r[free[i]] * r[free[i]]
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
    reach = (int(np.sqrt(lay.stencil.shape[1]) + 0.5) - 1) // 2
    return int(_solve(lay.indptr, lay.columns, grid_matrix.values, lay.stencil, space.basis.nfx, reach, space.bs,
                      np.asarray(free, dtype=np.int64), b, rtol, max_it, x))
