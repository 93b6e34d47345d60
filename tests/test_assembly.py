"""The particle contractions of fempm.assembly against the element matrix written out with numpy."""

import numpy as np
import pytest

from fempm import assembly


def _contract_pattern(kernels, weights, phis, perm):
    """``sum_p w_p phi_p^T K_p phi_p`` by :func:`fempm.assembly._add_particle_pattern`, the pattern grown
    as :func:`fempm.assembly.assemble_matrix` grows it; ``Ae[C, l, D nl + m]``."""
    bs, nq = perm.shape
    nk, nl = bs * nq, phis.shape[2]
    width = (bs * nl + 3) // 4 * 4
    K, T, Ae = np.zeros(nk * nk + 1), np.zeros((nk + 1, width)), np.zeros((bs, nl, width))
    pattern = np.zeros(nk * nk + 1, dtype=bool)
    pattern[-1] = True
    per_row = (nq + 2) // 3
    tchunks = np.zeros((nk * bs * per_row, 9), dtype=np.int64)
    achunks = np.zeros((bs * per_row, 7), dtype=np.int64)
    n_t = n_a = 0
    for kernel, w, phi in zip(kernels, weights, phis):
        K[:-1] = kernel.ravel()
        if assembly._outside_pattern(K, pattern):
            n_t, n_a = assembly._grow_pattern(K, pattern, perm, nl, nk, tchunks, achunks)
        assembly._add_particle_pattern(K, w, phi, tchunks, n_t, achunks, n_a, T, Ae)
    return Ae[:, :, : bs * nl]


def _dense(kernels, weights, phis, perm):
    """The same sum with numpy: ``Ae[C, l, D, m] = sum_p w_p phi[a, l] K[(C, a), (D, b)] phi[b, m]``."""
    K = np.stack([k[np.ix_(perm.ravel(), perm.ravel())] for k in kernels])  # rows and columns by (C, a)
    bs, nq = perm.shape
    K = K.reshape(len(kernels), bs, nq, bs, nq)
    Ae = np.einsum("p,pal,pcadb,pbm->pcldm", weights, phis, K, phis).sum(axis=0)
    return Ae.reshape(bs, phis.shape[2], -1)


@pytest.mark.parametrize("nq", [3, 6])
def test_pattern_contraction_equals_dense(nq):
    """Random kernels whose non-zero entries change from particle to particle (the pattern grows at
    the 1st, 5th and 9th; a whole row and a whole column stay zero) give the element matrix to round-off."""
    rng = np.random.default_rng(nq)
    bs, nl, n = 3, 9, 12
    perm = (np.arange(bs * nq).reshape(nq, bs).T).copy()  # blocked: kernel dof a * bs + C
    nk = bs * nq
    masks = [rng.random((nk, nk)) < share for share in (0.2, 0.4, 0.7)]
    for mask in masks:
        mask[perm[1, 0], :] = False
        mask[:, perm[2, nq - 1]] = False
    kernels = [rng.standard_normal((nk, nk)) * masks[min(p // 4, 2)] for p in range(n)]
    weights = rng.random(n)
    phis = rng.standard_normal((n, nq, nl))
    Ae = _contract_pattern(kernels, weights, phis, perm)
    reference = _dense(kernels, weights, phis, perm)
    assert np.abs(Ae - reference).max() <= 1e-13 * np.abs(reference).max()


def test_first_order_contraction_equals_pattern():
    """The first-order contraction takes every kernel entry; the pattern's adds the same terms in the
    same order: bit for bit."""
    rng = np.random.default_rng(3)
    bs, nq, nl, n = 3, 3, 9, 8
    perm = (np.arange(bs * nq).reshape(nq, bs).T).copy()
    nk = bs * nq
    kernels = [rng.standard_normal((nk, nk)) * (rng.random((nk, nk)) < 0.5) for _ in range(n)]
    weights, phis = rng.random(n), rng.standard_normal((n, nq, nl))
    width = (bs * nl + 3) // 4 * 4
    T, Ae = np.zeros((nk + 1, width)), np.zeros((bs, nl, width))
    for kernel, w, phi in zip(kernels, weights, phis):
        assembly._add_particle_first_order(np.append(kernel.ravel(), 0.0), perm, w, phi, T, Ae)
    assert np.array_equal(Ae[:, :, : bs * nl], _contract_pattern(kernels, weights, phis, perm))
