"""Numba loops that evaluate a compiled form kernel at every particle and assemble.

For each particle ``p`` (sorted by cell) the kernel of the form, compiled on a
*jet cell* (see :mod:`fempm.quadrature`), returns the integrand's element tensor
``K_p`` with respect to the jets (value and reference derivatives) of the test and
trial functions at the particle. The contribution of the particle to the cell's
element matrix is

    A_e[C l, C' m] += w_p * sum_{a, b} phi_p[a, l] * K_p[(C, a), (C', b)] * phi_p[b, m]

with ``phi_p[a, l]`` jet ``a`` of local basis function ``l``, ``C`` a component and
``w_p = V_p / h^2`` (the kernel integrates over the h x h jet cell with weight 1).
When the cell changes, ``A_e`` is added into the CSR storage of the matrix
(:mod:`fempm.matrix`). The sum is taken as ``T = w_p K_p phi_p``, then
``A_e += phi_p^T T``, three jets at a time. With first-order jets every entry of
``K_p`` is taken; with higher ones only those in the pattern of the entries
found non-zero so far, grown when a particle's kernel has one outside it: the
skipped entries are zero at that particle, so the sums are the same.

Integrals over ``dx_lumped`` use nodal quadrature instead (row-sum lumping):
``sum_p V_p sum_f N_f(x_p) g(x_p; grid functions at f)``, the integrand evaluated
once per particle and basis function with the grid functions replaced by that
function's coefficient; a lumped mass matrix is diagonal per function.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

__all__ = [
    "assemble_matrix",
    "assemble_matrix_lumped",
    "assemble_scalar",
    "assemble_vector",
    "assemble_vector_lumped",
    "jets_at_particles",
    "pack_coefficients",
    "particle_jets",
    "side_by_side",
]



@intrinsic
def _tabulate(typingctx, kernel, A, w, c, coords):
    """FFCx's ``tabulate_tensor(A, w, c, coords, NULL, NULL, NULL)`` of the kernel at address ``kernel`` (an
    integer, as :class:`fempm.quadrature.ParticleForm` keeps its kernels): a ctypes function passed to a compiled
    loop would be converted at every call of it."""
    if not (isinstance(kernel, types.Integer) and all(isinstance(a, types.Array) for a in (A, w, c, coords))):
        return None

    def codegen(context, builder, signature, args):
        pointer = ir.IntType(8).as_pointer()
        function = ir.FunctionType(ir.VoidType(), [pointer] * 7).as_pointer()
        data = [builder.bitcast(context.make_array(ty)(context, builder, value).data, pointer)
                for ty, value in zip(signature.args[1:], args[1:])]
        null = ir.Constant(pointer, None)
        builder.call(builder.inttoptr(args[0], function), [*data, null, null, null])
        return context.get_dummy_value()

    return types.void(kernel, A, w, c, coords), codegen


@numba.njit(cache=True)
def _jet_cell(x, h, coords):
    """Vertices of the h x h jet cell whose reference origin is the particle."""
    for v in range(4):
        coords[3 * v] = x[0] + h * (v % 2)
        coords[3 * v + 1] = x[1] + h * (v // 2)
        coords[3 * v + 2] = 0.0


@numba.njit(cache=True)
def _outside_pattern(K, pattern):
    """Number of non-zero entries of ``K`` outside ``pattern`` (a mask over ``K``'s entries); a
    comparison per entry, no branch, so that it vectorises (a NaN counts as non-zero)."""
    count = 0
    for i in range(K.shape[0]):
        count += (K[i] != 0.0) & (not pattern[i])
    return count


@numba.njit(cache=True)
def _active_jets(pattern, perm, C):
    """Jets ``a`` of component ``C`` whose kernel row ``(C, a)`` has an entry in ``pattern``, ascending."""
    bs, nq = perm.shape
    nk = bs * nq
    active = np.empty(nq, dtype=np.int64)
    count = 0
    for a in range(nq):
        r = perm[C, a] * nk
        if pattern[r: r + nk].any():
            active[count] = a
            count += 1
    return active[:count]


@numba.njit(cache=True)
def _row_chunks(pattern, perm, r, g, nl, tchunks, t):
    """The chunks of :func:`_add_particle_pattern` that make ``T[g]`` from kernel row ``r``: per component
    ``D``, its pattern's jets ``b`` in threes, ascending, the first three padded in front; from ``t`` on
    in ``tchunks``; returns the next free chunk."""
    bs, nq = perm.shape
    nk = bs * nq
    jets = np.empty(nq, dtype=np.int64)
    for D in range(bs):
        count = 0
        for b in range(nq):
            if pattern[r * nk + perm[D, b]]:
                jets[count] = b
                count += 1
        chunks = max((count + 2) // 3, 1)  # at least one: it writes the block's zeros
        pad = 3 * chunks - count
        for i in range(3 * chunks):
            c, slot = t + i // 3, i % 3
            if slot == 0:
                tchunks[c, 0], tchunks[c, 1], tchunks[c, 8] = g, D * nl, i == 0
            if i < pad:
                tchunks[c, 2 + slot], tchunks[c, 5 + slot] = nk * nk, 0  # K's zero entry
            else:
                b = jets[i - pad]
                tchunks[c, 2 + slot], tchunks[c, 5 + slot] = r * nk + perm[D, b], b
        t += chunks
    return t


@numba.njit(cache=True)
def _grow_pattern(K, pattern, perm, nl, zero_row, tchunks, achunks):
    """Add ``K``'s non-zero entries to ``pattern`` and remake the chunks of :func:`_add_particle_pattern`
    (``tchunks``, ``achunks``); returns how many of each.

    The kernel rows with an entry in the pattern get a row ``g`` of ``T`` each, component by component;
    a component's rows go into ``achunks`` in threes, the first three padded in front with ``T``'s
    row ``zero_row``, which stays zero."""
    bs = perm.shape[0]
    pattern |= K != 0.0
    g = t = n_a = 0
    for C in range(bs):
        active = _active_jets(pattern, perm, C)
        chunks = (active.size + 2) // 3
        pad = 3 * chunks - active.size
        for i in range(3 * chunks):
            c, slot = n_a + i // 3, i % 3
            achunks[c, 0] = C
            if i < pad:
                achunks[c, 1 + slot], achunks[c, 4 + slot] = zero_row, 0
                continue
            a = active[i - pad]
            achunks[c, 1 + slot], achunks[c, 4 + slot] = g, a
            t = _row_chunks(pattern, perm, perm[C, a], g, nl, tchunks, t)
            g += 1
        n_a += chunks
    return t, n_a


@numba.njit(cache=True, fastmath=True)
def _add_particle_pattern(K, w, phi_p, tchunks, n_t, achunks, n_a, T, Ae):
    """``Ae += w * phi_p^T K phi_p`` over the entries of ``K`` in a pattern that holds all its non-zero
    ones (:func:`_grow_pattern`), three jets at a time so that the loops vectorise whole.

    ``T[g, D nl + m] = w sum_b K[r_g, (D, b)] phi_p[b, m]`` for the kernel rows ``r_g`` with pattern
    entries, a chunk ``(g, D nl, three entries of K, their jets b, first)`` adding three terms (writing
    them if first); then ``Ae[C, l, :] += sum_a phi_p[a, l] T[g_a, :]``, a chunk ``(C, three rows
    g_a, their jets a)`` adding three rows. Padding (K's zero entry, ``T``'s zero row) and the pattern's
    entries that are zero at this particle add exact zeros: the sums are those over the non-zero
    entries, in the order of the loop over all of them. ``Ae`` is ``(bs, nl, width)``, a row of
    ``bs nl`` contiguous entries per ``(C, l)`` padded to ``width``.
    """
    nl = phi_p.shape[1]
    width = T.shape[1]
    for c in range(n_t):
        g, base, first = tchunks[c, 0], tchunks[c, 1], tchunks[c, 8]
        k0, k1, k2 = w * K[tchunks[c, 2]], w * K[tchunks[c, 3]], w * K[tchunks[c, 4]]
        b0, b1, b2 = tchunks[c, 5], tchunks[c, 6], tchunks[c, 7]
        if first:
            for m in range(nl):
                T[g, base + m] = k0 * phi_p[b0, m] + k1 * phi_p[b1, m] + k2 * phi_p[b2, m]
        else:
            for m in range(nl):
                T[g, base + m] += k0 * phi_p[b0, m] + k1 * phi_p[b1, m] + k2 * phi_p[b2, m]
    for c in range(n_a):
        C, g0, g1, g2 = achunks[c, 0], achunks[c, 1], achunks[c, 2], achunks[c, 3]
        a0, a1, a2 = achunks[c, 4], achunks[c, 5], achunks[c, 6]
        for l in range(nl):
            f0, f1, f2 = phi_p[a0, l], phi_p[a1, l], phi_p[a2, l]
            for e in range(width):
                Ae[C, l, e] += f0 * T[g0, e] + f1 * T[g1, e] + f2 * T[g2, e]


@numba.njit(cache=True, fastmath=True)
def _add_particle_first_order(K, perm, w, phi_p, T, Ae):
    """``Ae += w * phi_p^T K phi_p`` for jets of value and first derivatives (three per component), every
    entry of ``K`` taken, the jet sums written out: with few zero entries to skip this is cheaper than
    :func:`_add_particle_pattern`'s look-ups, and adds the same terms in the same order.

    ``T[(C, a), D nl + m] = w sum_b K[(C, a), (D, b)] phi_p[b, m]``, then
    ``Ae[C, l, :] += sum_a phi_p[a, l] T[(C, a), :]`` (``perm[C, a]``: kernel dof of jet ``a`` of ``C``).
    """
    bs = perm.shape[0]
    nk = 3 * bs
    nl = phi_p.shape[1]
    width = T.shape[1]
    for C in range(bs):
        for a in range(3):
            row = perm[C, a] * nk
            r = 3 * C + a
            for D in range(bs):
                base = D * nl
                k0, k1, k2 = w * K[row + perm[D, 0]], w * K[row + perm[D, 1]], w * K[row + perm[D, 2]]
                for m in range(nl):
                    T[r, base + m] = k0 * phi_p[0, m] + k1 * phi_p[1, m] + k2 * phi_p[2, m]
    for C in range(bs):
        r = 3 * C
        for l in range(nl):
            f0, f1, f2 = phi_p[0, l], phi_p[1, l], phi_p[2, l]
            for e in range(width):
                Ae[C, l, e] += f0 * T[r, e] + f1 * T[r + 1, e] + f2 * T[r + 2, e]


@numba.njit(cache=True)
def _add_to_csr(Ae, lfun_p, k1, values, indptr, stencil, offsets):
    """Add the element matrix of one cell, ``Ae[C, l, D nl + m]``, into the CSR values (see
    fempm.matrix); ``offsets``: room for the column offsets of one row's functions."""
    bs, nl = Ae.shape[0], Ae.shape[1]
    k = k1 - 1
    width = 2 * k + 1
    for l in range(nl):
        f = lfun_p[l]
        la, lb = l % k1, l // k1
        for m in range(nl):
            offsets[m] = bs * stencil[f, (m % k1 - la + k) + width * (m // k1 - lb + k)]
        for C in range(bs):
            row = indptr[bs * f + C]
            for m in range(nl):
                base = row + offsets[m]
                for D in range(bs):
                    values[base + D] += Ae[C, l, D * nl + m]


@numba.njit(cache=True)
def assemble_matrix(kernel, values, indptr, stencil, x, cell, weight, phi, lfun, coeffs, columns, consts, perm, h,
                    vector=None, alongside=None):
    """Add the particle-quadrature matrix of a bilinear form into CSR ``values``; the kernel's
    coefficients of particle ``p`` are ``coeffs[p, columns]``.

    ``vector``: None, or ``(kernel, out, consts, perm)`` of a linear form whose kernel reads
    ``coeffs[p]`` whole (the residual whose Jacobian this is), added into ``out`` in the same pass
    as :func:`assemble_vector` would. ``alongside``: None, or ``(kernel, out, consts, perm, columns, where)`` of
    one more linear form, whose kernel reads ``coeffs[p, columns]``, likewise at the particles ``where`` is true.
    First-order jets go through :func:`_add_particle_first_order`, others through :func:`_add_particle_pattern` over the pattern of the kernel's non-zero entries, grown
    at a particle whose kernel has one outside it (second-order jets: most kernel rows are zero, the
    second derivatives entering through a few terms). The element matrix's rows are padded to a
    multiple of 4 entries: the vectorised inner loops then have no scalar remainder."""
    n = cell.shape[0]
    bs, nq = perm.shape
    nl = phi.shape[2]
    nk = bs * nq
    k1 = int(np.sqrt(nl) + 0.5)
    K = np.zeros(nk * nk + 1)  # the last entry stays zero: the pattern's padding reads it
    w = np.empty(columns.shape[0])
    width = (bs * nl + 3) // 4 * 4
    T = np.zeros((nk + 1, width))  # the last row stays zero: the pattern's padding reads it
    Ae = np.zeros((bs, nl, width))
    offsets = np.empty(nl, dtype=np.int64)
    coords = np.zeros(12)
    pattern = np.zeros(nk * nk + 1, dtype=np.bool_)
    pattern[-1] = True
    per_row = (nq + 2) // 3
    tchunks = np.zeros((nk * bs * per_row, 9), dtype=np.int64)
    achunks = np.zeros((bs * per_row, 7), dtype=np.int64)
    n_t = n_a = 0
    if vector is not None:
        Kv = np.zeros(vector[3].size)
    if alongside is not None:
        Ka, wa = np.zeros(alongside[3].size), np.zeros(max(alongside[4].shape[0], 1))
    cur = -1
    for p in range(n + 1):
        c = cell[p] if p < n else -1
        if c != cur or p == n:  # a new cell, or the end (also of no particles)
            if cur >= 0:
                _add_to_csr(Ae, lfun[p - 1], k1, values, indptr, stencil, offsets)
            if p == n:
                break
            Ae[:] = 0.0
            cur = c
        _jet_cell(x[p], h, coords)
        if vector is not None:
            Kv[:] = 0.0
            _tabulate(vector[0], Kv, coeffs[p], vector[2], coords)
            _add_vector_particle(Kv, weight[p], phi[p], lfun[p], vector[3], vector[1])
        if alongside is not None and alongside[5][p]:
            for i in range(alongside[4].shape[0]):
                wa[i] = coeffs[p, alongside[4][i]]
            Ka[:] = 0.0
            _tabulate(alongside[0], Ka, wa, alongside[2], coords)
            _add_vector_particle(Ka, weight[p], phi[p], lfun[p], alongside[3], alongside[1])
        for i in range(columns.shape[0]):
            w[i] = coeffs[p, columns[i]]
        K[:] = 0.0
        _tabulate(kernel, K, w, consts, coords)
        if nq == 3:
            _add_particle_first_order(K, perm, weight[p], phi[p], T, Ae)
            continue
        if _outside_pattern(K, pattern):
            n_t, n_a = _grow_pattern(K, pattern, perm, nl, nk, tchunks, achunks)
        _add_particle_pattern(K, weight[p], phi[p], tchunks, n_t, achunks, n_a, T, Ae)
    return 0


@numba.njit(cache=True, fastmath=True)
def _add_vector_particle(K, w, phi_p, lfun_p, perm, out):
    """``out[(l, C)] += w sum_a phi_p[a, l] K[(C, a)]``: one particle's part of a vector."""
    bs, nq = perm.shape
    nl = phi_p.shape[1]
    for C in range(bs):
        for l in range(nl):
            s = 0.0
            for a in range(nq):
                s += phi_p[a, l] * K[perm[C, a]]
            out[bs * lfun_p[l] + C] += w * s


@numba.njit(cache=True, fastmath=True)
def assemble_vector(kernel, out, x, cell, weight, phi, lfun, coeffs, consts, perm, h):
    """Add the particle-quadrature vector of a linear form into ``out`` (local dofs)."""
    K = np.zeros(perm.size)
    coords = np.zeros(12)
    for p in range(cell.shape[0]):
        K[:] = 0.0
        _jet_cell(x[p], h, coords)
        _tabulate(kernel, K, coeffs[p], consts, coords)
        _add_vector_particle(K, weight[p], phi[p], lfun[p], perm, out)
    return 0


@numba.njit(cache=True)
def _nodal_kernel(kernel, K, w, f, nodal, consts, coords):
    """``K`` = the kernel of coefficients ``w`` with every grid function taken at function ``f``:
    its coefficient as the value, no derivatives (``nodal = (G, slot_pos, slot_col, zero_pos)``)."""
    G, slot_pos, slot_col, zero_pos = nodal
    for s in range(slot_pos.shape[0]):
        w[slot_pos[s]] = G[f, slot_col[s]]
    for s in range(zero_pos.shape[0]):
        w[zero_pos[s]] = 0.0
    K[:] = 0.0
    _tabulate(kernel, K, w, consts, coords)


@numba.njit(cache=True)
def assemble_matrix_lumped(kernel, values, indptr, stencil, x, weight, phi0, lfun, coeffs, consts,
                           perm, h, nodal, per_function):
    """Nodal (row-sum lumped) quadrature of a bilinear form into CSR ``values``.

    ``A[(f, C), (f, D)] += w_p N_f(x_p) K[(C, 0), (D, 0)]`` with the kernel evaluated
    with every grid function taken at function ``f``; once per particle when
    ``per_function`` is false (the integrand has no grid function).
    """
    n, nl = phi0.shape
    bs, nq = perm.shape
    nk = bs * nq
    k1 = int(np.sqrt(nl) + 0.5)
    centre = (k1 - 1) + (2 * k1 - 1) * (k1 - 1)
    K = np.zeros(nk * nk)
    w = np.empty(coeffs.shape[1])
    coords = np.zeros(12)
    for p in range(n):
        _jet_cell(x[p], h, coords)
        for l in range(nl):
            f = lfun[p, l]
            if per_function or l == 0:
                w[:] = coeffs[p]
                _nodal_kernel(kernel, K, w, f, nodal, consts, coords)
            scale = weight[p] * phi0[p, l]
            s = stencil[f, centre]
            for C in range(bs):
                base = indptr[bs * f + C] + bs * s
                for D in range(bs):
                    values[base + D] += scale * K[perm[C, 0] * nk + perm[D, 0]]
    return 0


@numba.njit(cache=True)
def assemble_vector_lumped(kernel, out, x, weight, phi0, lfun, coeffs, consts, perm, h, nodal, per_function):
    """Nodal (row-sum lumped) quadrature of a linear form: ``b[(f, C)] += w_p N_f(x_p) k[(C, 0)]``."""
    n, nl = phi0.shape
    bs, nq = perm.shape
    K = np.zeros(bs * nq)
    w = np.empty(coeffs.shape[1])
    coords = np.zeros(12)
    for p in range(n):
        _jet_cell(x[p], h, coords)
        for l in range(nl):
            f = lfun[p, l]
            if per_function or l == 0:
                w[:] = coeffs[p]
                _nodal_kernel(kernel, K, w, f, nodal, consts, coords)
            scale = weight[p] * phi0[p, l]
            for C in range(bs):
                out[bs * f + C] += scale * K[perm[C, 0]]
    return 0


@numba.njit(cache=True)
def nodal_sums(phi0, lfun, weight, coeffs, particle_slots, out):
    """``out[f, 0] += w_p N_f(x_p)``, ``out[f, 1 + s] += w_p N_f(x_p) coeffs[p, particle_slots[s]]``."""
    for p in range(phi0.shape[0]):
        for l in range(phi0.shape[1]):
            f = lfun[p, l]
            wn = weight[p] * phi0[p, l]
            out[f, 0] += wn
            for s in range(particle_slots.shape[0]):
                out[f, 1 + s] += wn * coeffs[p, particle_slots[s]]


@numba.njit(cache=True)
def _function_kernel(kernel, K, w, f, sums, particle_slots, nodal, consts, coords):
    """The kernel at function ``f``: particle fields averaged with the weights ``w_p N_f(x_p)``,
    grid functions at their coefficient, no derivatives."""
    w[:] = 0.0
    for s in range(particle_slots.shape[0]):
        w[particle_slots[s]] = sums[f, 1 + s] / sums[f, 0]
    _nodal_kernel(kernel, K, w, f, nodal, consts, coords)


@numba.njit(cache=True)
def assemble_matrix_nodal_affine(kernel, values, indptr, stencil, sums, n_owned, particle_slots, width,
                                 consts, perm, h, nodal):
    """Nodal quadrature of a bilinear form affine in the particle fields: once per owned function,
    ``A[(f, C), (f, D)] += W_f K[(C, 0), (D, 0)]`` with ``W_f = sum_p w_p N_f(x_p)``."""
    bs, nq = perm.shape
    nk = bs * nq
    nl_side = int(np.sqrt(stencil.shape[1]) + 0.5)
    centre = (nl_side * nl_side - 1) // 2
    K = np.zeros(nk * nk)
    w = np.empty(width)
    coords = np.zeros(12)
    _jet_cell(np.zeros(2), h, coords)
    for f in range(n_owned):
        if sums[f, 0] <= 0.0:
            continue
        _function_kernel(kernel, K, w, f, sums, particle_slots, nodal, consts, coords)
        s = stencil[f, centre]
        for C in range(bs):
            base = indptr[bs * f + C] + bs * s
            for D in range(bs):
                values[base + D] += sums[f, 0] * K[perm[C, 0] * nk + perm[D, 0]]
    return 0


@numba.njit(cache=True)
def assemble_vector_nodal_affine(kernel, out, sums, n_owned, particle_slots, width, consts, perm, h, nodal):
    """Nodal quadrature of a linear form affine in the particle fields: ``b[(f, C)] += W_f k[(C, 0)]``."""
    bs, nq = perm.shape
    K = np.zeros(bs * nq)
    w = np.empty(width)
    coords = np.zeros(12)
    _jet_cell(np.zeros(2), h, coords)
    for f in range(n_owned):
        if sums[f, 0] <= 0.0:
            continue
        _function_kernel(kernel, K, w, f, sums, particle_slots, nodal, consts, coords)
        for C in range(bs):
            out[bs * f + C] += sums[f, 0] * K[perm[C, 0]]
    return 0


@numba.njit(cache=True)
def assemble_scalar(kernel, x, weight, coeffs, consts, h):
    """Sum over particles of a functional's integrand times the particle weight."""
    K = np.zeros(1)
    coords = np.zeros(12)
    total = 0.0
    for p in range(x.shape[0]):
        K[0] = 0.0
        _jet_cell(x[p], h, coords)
        _tabulate(kernel, K, coeffs[p], consts, coords)
        total += weight[p] * K[0]
    return total


@numba.njit(cache=True)
def pack_coefficients(phi, lfun, values, index, zero, fields, field_offsets, out):
    """A form's coefficients at the particles, row ``p`` of ``out`` where its kernel reads them: the particle
    fields (``fields[k]``, ``(n, size)``, from column ``field_offsets[k]``); the jets of grid functions (their
    coefficients side by side in ``values``), ``out[p, index[c, a]] = sum_l phi[p, a, l] * values[lfun[p, l], c]``;
    and ``out[p, zero] = 0`` (the jets of functions known to be zero)."""
    n, nq, nl = phi.shape
    bs = values.shape[1]
    jets = np.empty((nq, bs))
    for p in range(n):
        for k in range(field_offsets.shape[0]):
            field = fields[k]
            for c in range(field.shape[1]):
                out[p, field_offsets[k] + c] = field[p, c]
        for k in range(zero.shape[0]):
            out[p, zero[k]] = 0.0
        particle_jets(phi[p], lfun[p], values, jets)
        for a in range(nq):
            for c in range(bs):
                out[p, index[c, a]] = jets[a, c]


@numba.njit(cache=True, inline="always")
def particle_jets(phi_p, lfun_p, values, jets):
    """``jets[a, c] = sum_l phi_p[a, l] * values[lfun_p[l], c]`` for ``a < jets.shape[0]``, each sum
    taken over ``l`` in order from 0.0 (the functions outermost: the components run contiguous): one
    particle's jets of a grid function, for kernels that go over the particles (inlined in them)."""
    nq, bs = jets.shape
    jets[:] = 0.0
    for l in range(lfun_p.shape[0]):
        f = lfun_p[l]
        for a in range(nq):
            w = phi_p[a, l]
            for c in range(bs):
                jets[a, c] += w * values[f, c]


@numba.njit(cache=True)
def nonzero_arrays(arrays):
    """Which of some 2-D float arrays (a tuple, each C-contiguous) have a non-zero entry."""
    flags = np.zeros(len(arrays), dtype=np.bool_)
    i = 0
    for a in arrays:
        for v in a.ravel():
            if v != 0.0:
                flags[i] = True
                break
        i += 1
    return flags


def side_by_side(arrays) -> np.ndarray:
    """``np.concatenate(arrays, axis=1)`` of 2-D float arrays with the same rows, contiguous (numpy copies
    narrow columns element by element); one contiguous array is its own (not a copy: read it only)."""
    arrays = tuple(np.ascontiguousarray(a, dtype=np.float64) for a in arrays)
    if len(arrays) == 1:
        return arrays[0]
    out = np.empty((arrays[0].shape[0], sum(a.shape[1] for a in arrays)))
    _side_by_side(arrays, out)
    return out


@numba.njit(cache=True)
def _side_by_side(arrays, out):
    first = 0
    for a in arrays:
        for i in range(a.shape[0]):
            for c in range(a.shape[1]):
                out[i, first + c] = a[i, c]
        first += a.shape[1]


@numba.njit(cache=True)
def jets_at_particles(phi, lfun, values, out):
    """``out[p, a, c] = sum_l phi[p, a, l] * values[lfun[p, l], c]``: jets of a grid function, the
    first ``out.shape[1]`` of ``phi``'s (a tabulation of a higher order serves). A particle's
    coefficients are gathered once for all its jets."""
    for p in range(lfun.shape[0]):
        particle_jets(phi[p], lfun[p], values, out[p])
