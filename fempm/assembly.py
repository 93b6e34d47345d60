"""Numba loops that evaluate a compiled form kernel at every particle and assemble.

For each particle ``p`` (sorted by cell) the kernel of the form, compiled on a
*jet cell* (see :mod:`fempm.quadrature`), returns the integrand's element tensor
``K_p`` with respect to the jets (value and reference derivatives) of the test and
trial functions at the particle. The contribution of the particle to the cell's
element matrix is

    A_e[C l, C' m] += w_p * sum_{a, b} phi_p[a, l] * K_p[(C, a), (C', b)] * phi_p[b, m]

with ``phi_p[a, l]`` jet ``a`` of local basis function ``l``, ``C`` a component and
``w_p = V_p / h^2`` (the kernel integrates over the h x h jet cell with weight 1).
When the cell changes, ``A_e`` goes to PETSc with ``MatSetValuesLocal``.
"""

from __future__ import annotations

import numba
import numpy as np

from petsc4py import PETSc

from dolfinx.fem.petsc import numba_utils

__all__ = ["assemble_matrix", "assemble_vector", "assemble_scalar", "jets_at_particles"]

_MatSetValuesLocal = numba_utils.MatSetValuesLocal
_ADD_VALUES = int(PETSc.InsertMode.ADD_VALUES)


@numba.njit(cache=True)
def _jet_cell(x, h, coords):
    """Vertices of the h x h jet cell whose reference origin is the particle."""
    for v in range(4):
        coords[3 * v] = x[0] + h * (v % 2)
        coords[3 * v + 1] = x[1] + h * (v // 2)
        coords[3 * v + 2] = 0.0


@numba.njit(cache=True, fastmath=True)
def assemble_matrix(kernel, mat, x, cell, weight, phi, lfun, coeffs, consts, perm, h):
    """Add the particle-quadrature matrix of a bilinear form into PETSc matrix ``mat``."""
    n = cell.shape[0]
    bs, nq = perm.shape
    nl = phi.shape[2]
    nk = bs * nq
    ne = bs * nl
    K = np.zeros(nk * nk)
    T = np.zeros((nk, ne))
    Ae = np.zeros((ne, ne))
    dofs = np.zeros(ne, dtype=np.int32)
    coords = np.zeros(12)
    block_nonzero = np.zeros((bs, bs), dtype=np.bool_)
    cur = -1
    for p in range(n + 1):
        c = cell[p] if p < n else -1
        if c != cur:
            if cur >= 0:
                q = p - 1
                for C in range(bs):
                    for l in range(nl):
                        dofs[C * nl + l] = bs * lfun[q, l] + C
                _MatSetValuesLocal(mat, ne, dofs.ctypes, ne, dofs.ctypes, Ae.ctypes, _ADD_VALUES)
            if p == n:
                break
            Ae[:] = 0.0
            cur = c
        K[:] = 0.0
        _jet_cell(x[p], h, coords)
        kernel(K.ctypes.data, coeffs[p].ctypes.data, consts.ctypes.data, coords.ctypes.data, 0, 0, 0)
        w = weight[p]
        # T[(C, a), (C', m)] = sum_b K[(C, a), (C', b)] phi[b, m], skipping zero blocks
        for C in range(bs):
            for D in range(bs):
                nz = False
                for a in range(nq):
                    for b in range(nq):
                        if K[perm[C, a] * nk + perm[D, b]] != 0.0:
                            nz = True
                block_nonzero[C, D] = nz
                if not nz:
                    continue
                for a in range(nq):
                    row = perm[C, a] * nk
                    for m in range(nl):
                        s = 0.0
                        for b in range(nq):
                            s += K[row + perm[D, b]] * phi[p, b, m]
                        T[C * nq + a, D * nl + m] = w * s
        for C in range(bs):
            for D in range(bs):
                if not block_nonzero[C, D]:
                    continue
                for l in range(nl):
                    for m in range(nl):
                        s = 0.0
                        for a in range(nq):
                            s += phi[p, a, l] * T[C * nq + a, D * nl + m]
                        Ae[C * nl + l, D * nl + m] += s
    return 0


@numba.njit(cache=True, fastmath=True)
def assemble_vector(kernel, out, x, cell, weight, phi, lfun, coeffs, consts, perm, h):
    """Add the particle-quadrature vector of a linear form into ``out`` (local dofs)."""
    n = cell.shape[0]
    bs, nq = perm.shape
    nl = phi.shape[2]
    K = np.zeros(bs * nq)
    coords = np.zeros(12)
    for p in range(n):
        K[:] = 0.0
        _jet_cell(x[p], h, coords)
        kernel(K.ctypes.data, coeffs[p].ctypes.data, consts.ctypes.data, coords.ctypes.data, 0, 0, 0)
        w = weight[p]
        for C in range(bs):
            for l in range(nl):
                s = 0.0
                for a in range(nq):
                    s += phi[p, a, l] * K[perm[C, a]]
                out[bs * lfun[p, l] + C] += w * s
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
        kernel(K.ctypes.data, coeffs[p].ctypes.data, consts.ctypes.data, coords.ctypes.data, 0, 0, 0)
        total += weight[p] * K[0]
    return total


@numba.njit(cache=True)
def jets_at_particles(phi, lfun, values, out):
    """``out[p, a, c] = sum_l phi[p, a, l] * values[lfun[p, l], c]``: jets of a grid function."""
    n, nq, nl = phi.shape
    bs = values.shape[1]
    for p in range(n):
        for a in range(nq):
            for c in range(bs):
                s = 0.0
                for l in range(nl):
                    s += phi[p, a, l] * values[lfun[p, l], c]
                out[p, a, c] = s
