"""Particle-to-grid (P2G) and grid-to-particle (G2P) transfers.

With ``N_i`` the basis functions and ``p`` the particles:

* P2G of a particle quantity ``q_p`` with weight ``w_p``: ``Q_i = sum_p w_p q_p N_i(x_p)``;
  the lumped mass is ``m_i = sum_p m_p N_i(x_p)`` (the row sums of the particle
  mass matrix ``sum_p m_p N_i N_j``, the basis being a partition of unity) and the
  momentum ``(m v)_i = sum_p m_p v_p N_i(x_p)``.
* G2P: ``f(x_p) = sum_i f_i N_i(x_p)`` and ``grad f(x_p) = sum_i f_i grad N_i(x_p)``.
* The smoothed density of method.md eq. (2):
  ``rho~_i = sum_p W_i(x_p) m_p`` with ``W_i = N_i / int N_i dx``.
* The FLIP/PIC update of a particle quantity from the grid's change and new value.
* Affine transfers (APIC, Jiang et al. 2015; TPIC, Nakamura et al. 2023): a particle
  carries with its value ``q_p`` an affine part ``C_p`` (a gradient) and P2G spreads the
  affine field, ``Q_i = sum_p w_p N_i(x_p) (q_p + C_p (x_i - x_p))``; ``x_i`` is the
  function's node (:func:`function_nodes`). G2P gives ``C_p = B_p D_p^-1`` (APIC) with
  ``B_p = sum_i f_i N_i(x_p) (x_i - x_p)^T`` and ``D_p = sum_i N_i(x_p) (x_i - x_p)(x_i - x_p)^T``,
  or the grid gradient ``grad f(x_p)`` (TPIC).
* The particle state of the implicit step (:func:`project_state`, :func:`update_state`): one
  of :data:`TRANSFERS`, with a PIC share per step that may grow with the step (:func:`pic_share`).

Sums over particles on several ranks meet at the owners of the functions.
"""

from __future__ import annotations

import weakref

import numba
import numpy as np
from llvmlite import ir
from mpi4py import MPI
from numba.core import types
from numba.extending import intrinsic

from fempm.assembly import jets_at_particles, particle_jets
from fempm.bases import jet_indices
from fempm.options import TRANSFERS
from fempm.space import GridFunction, Space

__all__ = [
    "AFFINE_FIELDS",
    "AFFINE_KINDS",
    "TRANSFERS",
    "add_affine_fields",
    "affine_rule",
    "affine_grid_to_particles",
    "affine_moments",
    "affine_particles_to_grid",
    "angular_momentum",
    "function_nodes",
    "NOISE_FILTERED",
    "NoiseFilter",
    "pic_share",
    "project_state",
    "update_state",
    "density_normalisation",
    "flip",
    "gradient",
    "grid_jets_to_particles",
    "grid_to_particles",
    "grid_gradient_to_particles",
    "lumped_mass",
    "momentum",
    "particles_to_grid",
    "smoothed_density",
]


@numba.njit(cache=True)
def _scatter(phi0, lfun, values, out, counts):
    """``out[lfun[p, l], c] += phi0[p, l] * values[p, c]`` over particles ``p``; with
    ``counts`` also ``out[lfun[p, l], -1] += 1``."""
    nc = values.shape[1]
    for p in range(phi0.shape[0]):
        for l in range(phi0.shape[1]):
            f = lfun[p, l]
            for c in range(nc):
                out[f, c] += phi0[p, l] * values[p, c]
            if counts:
                out[f, nc] += 1.0


def particles_to_grid(space: Space, particles, values, name: str = "p2g", counts: bool = False,
                      out: GridFunction | None = None) -> GridFunction:
    """``Q_i = sum_p values_p N_i(x_p)`` for ``values`` of shape ``(n,)`` or ``(n, bs)``.

    With ``counts`` the space has one component more, the last, which receives the
    number of particles in each function's support. ``out`` (a grid function of
    ``space``) is reused if given: a time loop should not create vectors every step.
    """
    values = np.asarray(values, dtype=np.float64)
    values = np.ascontiguousarray(values.reshape(len(particles), int(np.prod(values.shape[1:], dtype=int))))
    if values.shape[1] + counts != space.bs:
        raise ValueError(f"P2G: {values.shape[1]} components given for a space of {space.bs}")
    phi, lfun = space.tabulate_particles(particles, order=0)
    out = out if out is not None else GridFunction(space, name)
    out.values[:] = 0.0
    _scatter(np.ascontiguousarray(phi[:, 0, :]), lfun, values, out.values, counts)
    out.scatter_reverse_add()
    out.scatter_forward()
    return out


def lumped_mass(space: Space, particles, out: GridFunction | None = None) -> GridFunction:
    """Nodal masses ``m_i = sum_p m_p N_i(x_p)`` on a scalar space (into ``out`` if given)."""
    return particles_to_grid(space, particles, particles["mass"], "mass", out=out)


def momentum(space: Space, particles, out: GridFunction | None = None) -> GridFunction:
    """Nodal momenta ``sum_p m_p v_p N_i(x_p)`` on a two-component space (into ``out`` if given)."""
    return particles_to_grid(space, particles, particles["mass"][:, None] * particles["velocity"], "momentum",
                             out=out)


def smoothed_density(mass: np.ndarray, integrals: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``rho~_i = m_i / int N_i dx`` (method.md eq. 2) from the nodal masses ``m_i = sum_p m_p N_i(x_p)`` (into
    ``out`` if given)."""
    return np.divide(mass, integrals, out=out)


def density_normalisation(basis, particles, blocked: bool = True) -> np.ndarray:
    """``int N_i dx`` of eq. (2) for every structured function, as the particles measure it
    (``blocked``: over the obstacles' cells too; else over the open cells alone, where particles go).

    When all particles come from one seeding lattice (``n x n`` per cell, the volumes ``h^2 / n^2``,
    or in a cut cell its area over ``n^2``) the integral is taken by that lattice's rule, so that
    a region filled with particles at rest has ``rho~ = rho`` exactly; otherwise by Gauss quadrature.
    """
    grid = basis.grid
    comm = grid.comm
    volumes = particles["volume"]
    v_max = comm.allreduce(float(volumes.max(initial=0.0)), op=MPI.MAX)
    side = grid.h / np.sqrt(v_max) if v_max > 0 else 0.0
    if v_max > 0 and abs(side - round(side)) < 1e-9:
        n = int(round(side))
        shares = np.array([[1.0, 1.0], [grid.last[0], 1.0], [1.0, grid.last[1]], grid.last])
        lattice = (grid.h * shares).prod(axis=1) / n**2  # as Particles.seed computes them
        nearest = np.abs(volumes[:, None] - lattice).min(axis=1, initial=np.inf) if len(volumes) else volumes
        if comm.allreduce(bool(np.all(nearest <= 1e-12 * v_max)), op=MPI.LAND):
            return basis.lattice_integrals(n, blocked)
    return basis.integrals if blocked else basis.open_integrals()


def flip(velocity: np.ndarray, change: np.ndarray, new: np.ndarray, pic_blend: float) -> np.ndarray:
    """The FLIP/PIC update of a particle quantity: ``(1 - k) (q_p + dq(x_p)) + k q_new(x_p)``.

    FLIP adds the grid's change over the step to the particle's own value; PIC takes the grid's
    new value; ``k = pic_blend`` blends them (0: FLIP, 1: PIC).
    """
    return (1 - pic_blend) * (velocity + change) + pic_blend * new


_flip = numba.njit(cache=True)(flip)  # the same formula on numbers, for the kernels


def _jets(gf: GridFunction, particles, order: int) -> np.ndarray:
    phi, lfun = gf.space.tabulate_particles(particles, order, exact=False)
    out = np.empty((len(particles), len(jet_indices(order)), gf.space.bs))
    jets_at_particles(phi, lfun, np.ascontiguousarray(gf.values), out)
    return out


def grid_jets_to_particles(gf: GridFunction, particles, order: int = 1) -> np.ndarray:
    """Values and reference derivatives at the particles, ``(n, len(jet_indices(order)), bs)``.

    Physical derivatives are these divided by ``h ** (a + b)``.
    """
    return _jets(gf, particles, order)


def grid_to_particles(gf: GridFunction, particles) -> np.ndarray:
    """Values ``sum_i f_i N_i(x_p)`` at the particles, shape ``(n, bs)``."""
    return _jets(gf, particles, 0)[:, 0, :]


def grid_gradient_to_particles(gf: GridFunction, particles) -> np.ndarray:
    """Physical gradients at the particles, shape ``(n, bs, 2)``: ``[p, c, d] = d f_c / d x_d``."""
    return gradient(_jets(gf, particles, 1), gf.space.grid.h)


def gradient(jets: np.ndarray, h: float) -> np.ndarray:
    """Physical gradients ``(n, bs, 2)`` from jets of order >= 1 (:func:`grid_jets_to_particles`)."""
    return np.transpose(jets[:, 1:3, :], (0, 2, 1)) / h


# -- affine transfers --------------------------------------------------------------------------------
AFFINE_KINDS = ("apic", "tpic")


def function_nodes(space: Space) -> np.ndarray:
    """The node ``x_i`` of every local function (owned, then ghosts), shape ``(n, 2)``.

    Both bases are clamped B-splines on the grid's uniform knots (Q1 of degree 1), and the
    node is the function's Greville abscissa, the mean of its ``k`` inner knots: the grid
    nodes for Q1; the cell centres and the walls for the quadratic B-splines (a cut last cell's
    centre and the face, :mod:`fempm.bases`). With these,
    ``sum_i N_i(x) x_i = x`` everywhere (the bases reproduce linear fields with these
    coefficients), which makes affine P2G and G2P exact on affine fields and
    ``sum_i N_i(x_p) (x_i - x_p) = 0``, on which the conservation of momentum rests.

    Kept on the basis, whose spaces share one numbering (read-only: every transfer reads it).
    """
    basis = space.basis
    cached = getattr(basis, "_function_nodes", None)
    if cached is None:
        grid, k = basis.grid, basis.degree

        def greville(n, last):  # the mean of knots i+1 .. i+k of function i
            knots = basis.knots(n, last)
            return np.lib.stride_tricks.sliding_window_view(knots[1:], k).mean(axis=1)[: n + k]

        gx, gy = greville(grid.nx, float(grid.last[0])), greville(grid.ny, float(grid.last[1]))
        f = np.arange(basis.num_functions)
        nodes = np.column_stack([grid.lower[0] + grid.h * gx[f % basis.nfx],
                                 grid.lower[1] + grid.h * gy[f // basis.nfx]])
        cached = np.ascontiguousarray(nodes[space.numbering.local_functions])
        cached.setflags(write=False)
        basis._function_nodes = cached
    return cached


@numba.njit(cache=True, inline="always")
def _spread_affine(phi_p, lfun_p, nodes, x_p, values_p, gradients_p, out, counts):
    """One particle's ``out[f, c] += phi_p[l] (values_p[c] + gradients_p[c] . (nodes[f] - x_p))`` with
    ``f = lfun_p[l]``; with ``counts`` also ``out[f, -1] += 1``."""
    nc = values_p.shape[0]
    for l in range(lfun_p.shape[0]):
        f = lfun_p[l]
        rx, ry = nodes[f, 0] - x_p[0], nodes[f, 1] - x_p[1]
        w = phi_p[l]
        for c in range(nc):
            out[f, c] += w * (values_p[c] + gradients_p[c, 0] * rx + gradients_p[c, 1] * ry)
        if counts:
            out[f, nc] += 1.0


@numba.njit(cache=True)
def _scatter_affine(phi0, lfun, nodes, x, values, gradients, out, counts):
    """:func:`_spread_affine` of every particle."""
    for p in range(phi0.shape[0]):
        _spread_affine(phi0[p], lfun[p], nodes, x[p], values[p], gradients[p], out, counts)


def affine_particles_to_grid(space: Space, particles, values, gradients, name: str = "p2g", counts: bool = False,
                             out: GridFunction | None = None) -> GridFunction:
    """Affine P2G: ``Q_i = sum_p N_i(x_p) (values_p + gradients_p (x_i - x_p))``.

    ``values`` ``(n, nc)``, ``gradients`` ``(n, nc, 2)`` with ``[p, c, d]`` the derivative of
    component ``c`` along ``x_d`` (zero for a component without an affine part, e.g. the mass);
    ``x_i`` are the :func:`function_nodes`. Weight by the mass yourself (``m_p v_p``,
    ``m_p C_p``). ``counts`` and ``out`` as in :func:`particles_to_grid`. Since
    ``sum_i N_i(x_p) (x_i - x_p) = 0`` the sum over the grid of ``Q_i`` is that of the
    particles' ``values`` (momentum is conserved), and an affine field ``q(x)`` given with its
    gradient lands exactly as ``Q_i = q(x_i) sum_p N_i(x_p)``.
    """
    values = np.asarray(values, dtype=np.float64)
    values = np.ascontiguousarray(values.reshape(len(particles), int(np.prod(values.shape[1:], dtype=int))))
    gradients = np.ascontiguousarray(np.asarray(gradients, dtype=np.float64).reshape(len(particles), -1, 2)
                                     if len(particles) else np.zeros((0, values.shape[1], 2)))
    if values.shape[1] + counts != space.bs or gradients.shape[1] != values.shape[1]:
        raise ValueError(f"affine P2G: {values.shape[1]} values and {gradients.shape[1]} gradients for a space "
                         f"of {space.bs} components")
    phi, lfun = space.tabulate_particles(particles, order=0)
    out = out if out is not None else GridFunction(space, name)
    out.values[:] = 0.0
    _scatter_affine(np.ascontiguousarray(phi[:, 0, :]), lfun, function_nodes(space), np.ascontiguousarray(particles.x),
                    values, gradients, out.values, counts)
    out.scatter_reverse_add()
    out.scatter_forward()
    return out


@numba.njit(cache=True, inline="always")
def _second_moments(phi_p, lfun_p, nodes, x_p):
    """One particle's ``D = sum_l phi_p[0, l] (x_f - x_p)(x_f - x_p)^T`` as ``(d00, d01, d11)``, each sum
    over ``l`` in order from 0."""
    d00 = d01 = d11 = 0.0
    for l in range(lfun_p.shape[0]):
        f, w = lfun_p[l], phi_p[0, l]
        rx, ry = nodes[f, 0] - x_p[0], nodes[f, 1] - x_p[1]
        d00 += w * rx * rx
        d01 += w * rx * ry
        d11 += w * ry * ry
    return d00, d01, d11


@numba.njit(cache=True, inline="always")
def _first_moment(phi_p, lfun_p, nodes, x_p, grid_values, c):
    """One particle's ``B_c = sum_l phi_p[0, l] f_c (x_f - x_p)`` of component ``c`` of ``grid_values``,
    each sum over ``l`` in order from 0."""
    bx = by = 0.0
    for l in range(lfun_p.shape[0]):
        f = lfun_p[l]
        wf = phi_p[0, l] * grid_values[f, c]
        bx += wf * (nodes[f, 0] - x_p[0])
        by += wf * (nodes[f, 1] - x_p[1])
    return bx, by


@numba.njit(cache=True)
def _apic_moments(phi, lfun, nodes, x, grid_values, components, B, D):
    """APIC's moments of every particle into ``B`` ``(n, nc, 2)`` (:func:`_first_moment` of the ``components``)
    and ``D`` ``(n, 2, 2)`` (:func:`_second_moments`)."""
    for p in range(lfun.shape[0]):
        d00, d01, d11 = _second_moments(phi[p], lfun[p], nodes, x[p])
        D[p, 0, 0], D[p, 0, 1], D[p, 1, 0], D[p, 1, 1] = d00, d01, d01, d11
        for k in range(components.shape[0]):
            B[p, k, 0], B[p, k, 1] = _first_moment(phi[p], lfun[p], nodes, x[p], grid_values, components[k])


def affine_moments(space: Space, particles, grid_values: np.ndarray | None = None,
                   components=slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """APIC's ``D_p = sum_i N_i(x_p) (x_i - x_p)(x_i - x_p)^T`` ``(n, 2, 2)`` and, for the
    ``components`` of grid values ``(num_local_functions, bs)`` (``nc`` of them),
    ``B_p = sum_i f_i N_i(x_p) (x_i - x_p)^T`` ``(n, nc, 2)``.

    ``D_p`` is computed particle by particle, so that it is exact for the clamped wall
    B-splines and for Q1 (``h^2/4 I`` only for interior quadratic B-splines). It is
    diagonal for both (tensor products reproducing linear fields), and it vanishes where a
    single function is non-zero (a particle on a clamped wall, or on a Q1 node), where
    ``B_p`` vanishes alike.
    """
    phi, lfun = space.tabulate_particles(particles, order=0, exact=False)
    grid_values = np.zeros((1, 0)) if grid_values is None else np.asarray(grid_values, dtype=np.float64)
    index = np.arange(grid_values.shape[1])[components]
    B = np.empty((len(particles), len(index), 2))
    D = np.empty((len(particles), 2, 2))
    _apic_moments(phi, lfun, function_nodes(space), np.ascontiguousarray(particles.x), grid_values, index, B, D)
    return D, B


def affine_grid_to_particles(gf: GridFunction, particles, kind: str = "apic", jets: np.ndarray | None = None,
                             components=slice(None)) -> tuple[np.ndarray, np.ndarray]:
    """Affine G2P of ``gf``'s ``components``: values ``(n, nc)`` and affine parts ``(n, nc, 2)``.

    ``kind`` ``"apic"``: ``C_p = B_p D_p^-1`` (Jiang et al. 2015), the least-squares
    gradient of the nodal values weighted by ``N_i(x_p)``; with it P2G and G2P conserve
    angular momentum (:func:`angular_momentum`). ``"tpic"``: ``C_p = grad f(x_p)``, the
    gradient of the grid field (Nakamura et al. 2023). Both are exact on affine fields; for Q1
    they coincide (``N_i D_p^-1 (x_i - x_p) = grad N_i``). ``jets`` (from
    :func:`grid_jets_to_particles` of ``gf``, order >= 1) saves tabulating again.
    """
    if kind not in AFFINE_KINDS:
        raise ValueError(f"affine transfer must be one of {AFFINE_KINDS}, got {kind!r}")
    if jets is None:
        jets = grid_jets_to_particles(gf, particles, order=1)
    values = jets[:, 0, components]
    if kind == "tpic":
        return values, gradient(jets, gf.space.grid.h)[:, components]
    D, B = affine_moments(gf.space, particles, gf.values, components)
    C = np.empty_like(B)
    _apic_affine_parts(B, D, _moment_floor(gf.space.grid.h), C)
    return values, C


def _moment_floor(h: float) -> float:
    """The least diagonal moment :func:`_times_inverse_moments` divides by: a vanishing moment (a particle on
    a clamped wall or a Q1 node, where B vanishes too) is floored at ``1e-14 h^2``, its part of ``C`` then zero."""
    return 1e-14 * h * h


@intrinsic
def _fma(typingctx, a, b, c):
    """``a b + c`` rounded once, in kernels: LLVM's ``llvm.fma.f64`` (the hardware's fused multiply-add)."""
    def codegen(context, builder, signature, args):
        double = ir.DoubleType()
        fma = builder.module.declare_intrinsic("llvm.fma", [double], ir.FunctionType(double, [double] * 3))
        return builder.call(fma, args)
    return types.float64(types.float64, types.float64, types.float64), codegen


@numba.njit(cache=True, inline="always")
def _times_inverse_moments(b, d00, d01, d11, floor, C):
    """``C = b D^-1`` of one particle, ``b`` ``(nc, 2)``, ``D`` symmetric with entries ``d00``, ``d01``,
    ``d11``, its diagonal floored at ``floor`` (``max`` keeps a NaN, as ``np.maximum``). Each entry
    is ``fma(b_1, Dinv_1e, b_0 Dinv_0e)``, as a BLAS product ``B @ D^-1`` rounds it on FMA hardware."""
    a = floor if d00 < floor else d00
    d = floor if d11 < floor else d11
    det = a * d - d01 * d01
    i00, i01, i11 = d / det, -d01 / det, a / det
    for c in range(b.shape[0]):
        C[c, 0] = _fma(b[c, 1], i01, b[c, 0] * i00)
        C[c, 1] = _fma(b[c, 1], i11, b[c, 0] * i01)


@numba.njit(cache=True)
def _apic_affine_parts(B, D, floor, C):
    """APIC's ``C_p = B_p D_p^-1`` (:func:`_times_inverse_moments`) of every particle."""
    for p in range(B.shape[0]):
        _times_inverse_moments(B[p], D[p, 0, 0], D[p, 0, 1], D[p, 1, 1], floor, C[p])


def angular_momentum(space: Space, particles, gradients: np.ndarray | None = None, centre=(0.0, 0.0)) -> float:
    """Angular momentum about ``centre`` of the particles on all ranks, with their affine parts::

        L = sum_p m_p ((x_p - c) x v_p + (C_p D_p)_yx - (C_p D_p)_xy)

    (2-D cross products, ``C_p`` the ``gradients``, ``D_p`` of :func:`affine_moments`): what
    APIC's P2G and G2P conserve, equal to the grid's ``sum_i m_i (x_i - c) x v_i`` before and
    after a transfer. Without ``gradients`` only the first term.
    """
    m, v = particles["mass"], particles["velocity"]
    r = particles.x - np.asarray(centre, dtype=float)
    local = float(np.einsum("i,i->", m, r[:, 0] * v[:, 1] - r[:, 1] * v[:, 0]))
    if gradients is not None:
        D, _ = affine_moments(space, particles)
        CD = np.asarray(gradients) @ D
        local += float(np.einsum("i,i->", m, CD[:, 1, 0] - CD[:, 0, 1]))
    return space.comm.allreduce(local)


# -- the particle state of the implicit step ---------------------------------------------------------
#: the particles' affine parts of velocity and acceleration, ``[p, c, d] = d q_c / d x_d``
AFFINE_FIELDS = ("affine_velocity", "affine_acceleration")


def pic_share(kind: str, pic_blend: float, pic_rate: float, dt: float) -> float:
    """The PIC share ``k`` of a step's G2P: 1 for ``apic`` and ``tpic``, else ``min(1, pic_blend + pic_rate dt)``.

    A share per step damps per unit time as ``k / dt``, which grows as the step falls; a share
    ``pic_rate dt`` damps at a rate of ``pic_rate`` times the share of a mode that one PIC
    transfer takes, independent of dt, and with affine parts that share falls fast with h.
    """
    return 1.0 if kind in AFFINE_KINDS else min(1.0, pic_blend + pic_rate * dt)


#: water slower than this times ``sqrt(|g| h)`` is at rest for :func:`rest_share`
REST_SPEED = 1.0e-2


def rest_share(kind: str, rest_pic_rate: float, dt: float, g: float, h: float) -> tuple[float, float]:
    """The PIC share of water at rest and the speed below which it sets in: ``(min(1, rest_pic_rate dt),
    REST_SPEED sqrt(|g| h))``; ``(0, 0)`` (none) for ``apic`` and ``tpic`` (whose share is whole) and
    without gravity. Between that speed and zero a particle's share rises linearly from the flowing
    share (:func:`pic_share`) to it (:func:`update_state`): a step whose water is at rest damps the
    slow modes the particle quadrature's errors grow there, at a rate that does not grow as dt falls.
    ``g``: gravity's magnitude ``|g|``.
    """
    if kind in AFFINE_KINDS or g == 0.0 or rest_pic_rate == 0.0:
        return 0.0, 0.0
    return min(1.0, rest_pic_rate * dt), REST_SPEED * np.sqrt(g * h)


def affine_rule(kind: str) -> str:
    """How a transfer ``kind`` takes its affine parts at G2P (:func:`affine_grid_to_particles`): the
    grid gradient for ``tpic``, APIC's ``B_p D_p^-1`` for ``apic`` and ``affine-flip``."""
    return "tpic" if kind == "tpic" else "apic"


def add_affine_fields(particles, kind: str):
    """Give the particles the affine parts :data:`AFFINE_FIELDS` (zero) if ``kind`` carries them."""
    if kind != "flip":
        for name in AFFINE_FIELDS:
            if name not in particles.fields:
                particles.add_field(name, (2, 2))


def project_state(particles, kind: str, out: GridFunction) -> GridFunction:
    """P2G of mass, momentum, mass-weighted acceleration and particle counts into ``out``
    (fields ``m``, ``mv``, ``ma``, ``count``): ``(m v)_i = sum_p m_p N_i(x_p) (v_p + C_p (x_i - x_p))``,
    ``C_p`` the particle's affine part (none for ``flip``), likewise the acceleration."""
    if kind == "flip":
        mass = particles["mass"][:, None]
        values = np.hstack([mass, mass * particles["velocity"], mass * particles["acceleration"]])
        return particles_to_grid(out.space, particles, values, counts=True, out=out)
    phi, lfun = out.space.tabulate_particles(particles, order=0, exact=False)
    out.values[:] = 0.0
    _scatter_state(phi, lfun, function_nodes(out.space), np.ascontiguousarray(particles.x), particles["mass"],
                   particles["velocity"], particles["acceleration"], particles[AFFINE_FIELDS[0]],
                   particles[AFFINE_FIELDS[1]], out.values)
    out.scatter_reverse_add()
    out.scatter_forward()
    return out


@numba.njit(cache=True)
def _scatter_state(phi, lfun, nodes, x, mass, velocity, acceleration, affine_velocity, affine_acceleration, out):
    """:func:`project_state`'s affine P2G particle by particle (:func:`_spread_affine`): the values
    ``[m, m v, m a]`` with the affine parts ``[0, m C_v, m C_a]``, and the counts."""
    values, gradients = np.empty(5), np.zeros((5, 2))
    for p in range(lfun.shape[0]):
        m = mass[p]
        values[0] = m
        for c in range(2):
            values[1 + c] = m * velocity[p, c]
            values[3 + c] = m * acceleration[p, c]
            for d in range(2):
                gradients[1 + c, d] = m * affine_velocity[p, c, d]
                gradients[3 + c, d] = m * affine_acceleration[p, c, d]
        _spread_affine(phi[p, 0], lfun[p], nodes, x[p], values, gradients, out, True)


#: how :func:`_g2p_state` takes the affine parts (:func:`affine_rule`), by index (-1: none, for FLIP)
_G2P_RULES = ("apic", "tpic")


def update_state(g2p: GridFunction, particles, kind: str, share: float, values: np.ndarray,
                 divergence: np.ndarray, rest: tuple[float, float] = (0.0, 0.0),
                 noise: tuple[NoiseFilter, float] | None = None):
    """G2P of velocity and acceleration from ``g2p`` (fields ``dv``, ``da``: the step's changes;
    ``v``, ``a``: the new values), in one pass over the particles.

    The values by :func:`flip` with the PIC ``share``, at a particle where the grid's new speed is below
    ``rest[1]`` rising linearly to ``rest[0]`` at zero (:func:`rest_share`); for the affine kinds also the affine
    parts of ``v_{n+1}`` and ``a_{n+1}``, taken whole (``B_p D_p^-1`` for ``apic`` and
    ``affine-flip``, the grid gradient for ``tpic``). The acceleration, Newmark's state, goes
    as the velocity, so that the next step starts from one transferred pair. With a ``noise``
    filter and its share (``affine-flip``), that share of the particles' noise is taken after
    (:class:`NoiseFilter`).

    For the rest of a caller's G2P, into its buffers (reused from step to step): ``values``
    ``(n, bs)``, all of ``g2p`` at the particles, and ``divergence`` ``(n,)``, ``div v_{n+1}`` there.

    With a two-component field ``held`` in ``g2p`` (1 along the directions the step held at rest for want
    of material, else 0), a particle's values of the other vector fields are taken over the functions the
    step moved where the held ones weigh little, ``sum_i N_i f_i / (1 - s sum_i N_i held_i)`` (:func:`_restore_held`).
    """
    if noise is not None and kind in NOISE_FILTERED:
        update_state(g2p, particles, kind, share, values, divergence, rest)
        noise[0].damp(g2p.space, particles, values, noise[1])
        return
    space = g2p.space
    phi, lfun = space.tabulate_particles(particles, order=1, exact=False)
    if kind == "flip":
        rule, affine = -1, (np.empty((0, 2, 2)),) * 2
    else:
        rule, affine = _G2P_RULES.index(affine_rule(kind)), (particles[name] for name in AFFINE_FIELDS)
    _g2p_state(phi, lfun, function_nodes(space), np.ascontiguousarray(particles.x), g2p.values,
               space.offsets("dv", "da", "v", "a"), *_held_fields(space),
               float(share),
               float(rest[0]), float(rest[1]), rule,
               space.grid.h, _moment_floor(space.grid.h), particles["velocity"], particles["acceleration"], *affine,
               values, divergence)


#: the transfers whose particles a :class:`NoiseFilter` damps (``flip`` stays the seed's FLIP/PIC blend)
NOISE_FILTERED = ("affine-flip",)


class NoiseFilter:
    """A PIC share that damps only what the grid cannot see.

    A particle's difference from the grid, ``d_p = v_p - v_{n+1}(x_p)`` (likewise the acceleration),
    holds a smooth part the grid resolves (near a kink of the flow, or where the grid lags a
    particle's own history) and particle-to-particle noise in the null space of P2G, which FLIP
    never damps. The smooth part is ``S d``, the difference fitted linearly over each function's
    particles and taken back: per function ``i`` the mass-weighted least-squares fit
    ``db_i + g_i . (x - xb_i)`` (weights ``m_p N_i(x_p)``, ``xb_i`` their centre, the gradient's normal
    matrix's smallest eigenvalue raised to :data:`FIT_FLOOR` ``h^2`` where the particles barely spread), and
    ``(S d)_p = sum_i N_i(x_p) (db_i + g_i . (x_p - xb_i))``. The share damps ``d - S d`` alone:
    ``v_p <- v_p - k (d_p - (S d)_p)``, which keeps linear momentum (``sum_p m_p (S d)_p = sum_p m_p d_p``:
    each fit's gradient term has zero weighted mean). Like XPIC (Hammerquist & Nairn 2017), it filters the
    null-space noise without PIC's smoothing of the resolved flow. The fit takes a difference that varies
    linearly as smooth everywhere; a fit's mean alone (P2G and G2P) does only where a function's
    particles lie evenly around its node, not along a wall or a free surface, where it took the flow's
    gradient there for noise and slowed water sliding along a floor, more as the step fell
    (docs/notes-accuracy.md, "The PIC shares").

    A particle alone in its functions' support is its own smoothing (``S d = d``), so its noise
    would never be damped: where the particle's own weight in its smoothing,
    ``o_p = sum_i N_i(x_p)^2 m_p / m_i``, exceeds :data:`LONE_WEIGHT`, a share of its smooth part is
    taken too, ``k l_p (S d)_p`` with ``l_p`` ramped from 0 there to 1 at ``o_p = 1`` (a particle with
    no neighbour, whose whole difference the share then takes, as PIC does, and with it momentum towards
    the grid's).
    """

    def __init__(self, basis):
        self._grid = GridFunction(Space(basis, {"m": 1, "r": 2, "rr": 3, "d": 4, "rd": 8}), "noise")
        self._difference = np.empty((0, 4))

    def damp(self, space: Space, particles, values: np.ndarray, share: float):
        """Take ``share`` of the noise off the particles' velocity and acceleration (of a lone particle's
        whole difference); ``values``: the grid fields of ``space`` (``v``, ``a``) at the particles
        (:func:`update_state`'s buffer)."""
        if share == 0.0:
            return
        phi, lfun = space.tabulate_particles(particles, order=0, exact=False)
        if self._difference.shape[0] != len(particles):
            self._difference = np.empty((len(particles), 4))
        grid, velocity, acceleration = self._grid, particles["velocity"], particles["acceleration"]
        grid.values[:] = 0.0
        nodes, x = function_nodes(space), np.ascontiguousarray(particles.x)
        _noise_moments(phi, lfun, nodes, x, particles["mass"], velocity, acceleration, values, space.field_offset("v"),
                       space.field_offset("a"), self._difference, grid.values)
        grid.scatter_reverse_add()
        grid.scatter_forward()
        _fit_noise(grid.values, FIT_FLOOR * space.grid.h**2)
        _take_noise(phi, lfun, nodes, x, particles["mass"], grid.values, self._difference, float(share), velocity,
                    acceleration)


@numba.njit(cache=True)
def _noise_moments(phi, lfun, nodes, x, mass, velocity, acceleration, values, v, a, difference, out):
    """``difference[p]``: the particle's velocity and acceleration less the grid's (``values``, fields at offsets
    ``v``, ``a``); P2G into ``out`` of the moments of a linear fit of it per function:
    ``m``, ``m r`` (2), ``m r r^T`` (xx, xy, yy), ``m d`` (4), ``m r_a d_c`` (8, ``4 a + c``), ``r = x_p - x_i``."""
    for p in range(lfun.shape[0]):
        m = mass[p]
        for c in range(2):
            difference[p, c] = velocity[p, c] - values[p, v + c]
            difference[p, 2 + c] = acceleration[p, c] - values[p, a + c]
        for l in range(lfun.shape[1]):
            f, w = lfun[p, l], phi[p, 0, l]
            wm = w * m
            r0, r1 = x[p, 0] - nodes[f, 0], x[p, 1] - nodes[f, 1]
            out[f, 0] += wm
            out[f, 1] += wm * r0
            out[f, 2] += wm * r1
            out[f, 3] += wm * r0 * r0
            out[f, 4] += wm * r0 * r1
            out[f, 5] += wm * r1 * r1
            for c in range(4):
                out[f, 6 + c] += wm * difference[p, c]
                out[f, 10 + c] += wm * r0 * difference[p, c]
                out[f, 14 + c] += wm * r1 * difference[p, c]


@numba.njit(cache=True)
def _fit_noise(grid, floor):
    """Per function, from the moments of :func:`_noise_moments`, the weighted least-squares linear fit of the
    difference: the mean offset ``rb`` (columns 1, 2), the mean ``db`` (6..9) and the gradient ``g`` (10 + 4 a + c),
    ``g = (C + e I)^-1 cov(r, d)``, ``C`` the particles' spread, ``e`` what raises its smallest eigenvalue to
    ``floor`` (0 where it is above)."""
    for f in range(grid.shape[0]):
        m = grid[f, 0]
        if m <= 0.0:
            grid[f, 1:] = 0.0
            continue
        r0, r1 = grid[f, 1] / m, grid[f, 2] / m
        cxx = grid[f, 3] / m - r0 * r0
        cxy = grid[f, 4] / m - r0 * r1
        cyy = grid[f, 5] / m - r1 * r1
        smallest = 0.5 * (cxx + cyy - np.sqrt((cxx - cyy) ** 2 + 4.0 * cxy * cxy))
        raised = max(floor - smallest, 0.0)  # the smallest spread raised to the floor, the fit exact above it
        cxx, cyy = cxx + raised, cyy + raised
        det = cxx * cyy - cxy * cxy
        grid[f, 1], grid[f, 2] = r0, r1
        for c in range(4):
            db = grid[f, 6 + c] / m
            k0 = grid[f, 10 + c] / m - r0 * db
            k1 = grid[f, 14 + c] / m - r1 * db
            grid[f, 6 + c] = db
            grid[f, 10 + c] = (cyy * k0 - cxy * k1) / det
            grid[f, 14 + c] = (cxx * k1 - cxy * k0) / det


@numba.njit(cache=True)
def _take_noise(phi, lfun, nodes, x, mass, grid, difference, share, velocity, acceleration):
    """``state_p -= share (d_p - (1 - l_p) (S d)_p)``, ``(S d)_p = sum_i N_i(x_p) (db_i + g_i . (x_p - x_i - rb_i))``
    from the fits of :func:`_fit_noise` (``grid``), ``l_p`` the particle's loneness (:class:`NoiseFilter`)."""
    smooth = np.empty(4)
    for p in range(lfun.shape[0]):
        own = 0.0
        smooth[:] = 0.0
        for l in range(lfun.shape[1]):
            f, w = lfun[p, l], phi[p, 0, l]
            if w == 0.0:
                continue
            own += w * w * mass[p] / grid[f, 0]
            e0 = x[p, 0] - nodes[f, 0] - grid[f, 1]
            e1 = x[p, 1] - nodes[f, 1] - grid[f, 2]
            for c in range(4):
                smooth[c] += w * (grid[f, 6 + c] + grid[f, 10 + c] * e0 + grid[f, 14 + c] * e1)
        kept = 1.0 - min(max((own - LONE_WEIGHT) / (1.0 - LONE_WEIGHT), 0.0), 1.0)
        for c in range(2):
            velocity[p, c] -= share * (difference[p, c] - kept * smooth[c])
            acceleration[p, c] -= share * (difference[p, 2 + c] - kept * smooth[2 + c])


#: a particle's own weight in its difference's smoothing above which it counts as (partly) alone (NoiseFilter)
LONE_WEIGHT = 0.5
#: NoiseFilter's fits raise their particles' spread (the gradient's normal matrix per unit mass) to at least this
#: times h^2 along every direction: where a function's particles lie along a line the fit across it is its mean
FIT_FLOOR = 1.0e-3


@numba.njit(cache=True, inline="always")
def _particle_derivative(phi_p, lfun_p, grid_values, d, c):
    """``sum_l phi_p[1 + d, l] grid_values[lfun_p[l], c]``: one particle's derivative along reference
    coordinate ``d`` of component ``c`` of a grid function, the sum over ``l`` in order from 0.0."""
    s = 0.0
    for l in range(lfun_p.shape[0]):
        s += phi_p[1 + d, l] * grid_values[lfun_p[l], c]
    return s


def _held_fields(space: Space) -> tuple[int, np.ndarray]:
    """The offset of the two-component field ``held`` in ``space`` (-1 without it) and the components
    :func:`_restore_held` takes over the moved functions, rows ``(component, d)``: those of the other
    two-component fields, each with its direction ``d`` (the component of ``held`` it goes by; made once per
    space)."""
    known = _HELD_FIELDS.get(space)
    if known is not None:
        return known
    if "held" not in space.fields:
        known = -1, np.empty((0, 2), dtype=np.int64)
    else:
        known = space.field_offset("held"), np.array([(space.field_offset(name) + d, d) for name, size in
                                                      space.fields.items() if name != "held" and size == 2
                                                      for d in range(2)], dtype=np.int64)
    known[1].setflags(write=False)
    _HELD_FIELDS[space] = known
    return known


#: :func:`_held_fields` of the spaces it was asked for, while they live
_HELD_FIELDS = weakref.WeakKeyDictionary()


#: :func:`_restore_held` takes the held functions at a particle's value up to this weight of them, then less,
#: none from twice it
HELD_WEIGHT_RESTORED = 0.1


@numba.njit(cache=True, inline="always")
def _restored_share(at, held, d):
    """The share ``s`` of its value a particle gives the held functions along direction ``d``, by their
    weight ``w = at[held + d]``: 1 up to :data:`HELD_WEIGHT_RESTORED`, falling linearly to 0 at twice it
    (0 without a field ``held``, ``held`` < 0)."""
    if held < 0:
        return 0.0
    w = at[held + d]
    return min(max(2.0 - w / HELD_WEIGHT_RESTORED, 0.0), 1.0) if w > 0.0 else 0.0


@numba.njit(cache=True, inline="always")
def _restore_held(at, held, restored):
    """A particle's grid values ``at`` with the held functions at the particle's value times ``s``
    (:func:`_restored_share`): ``at[c] / (1 - s at[held + d])`` for the components ``c`` of ``restored`` (rows
    ``(c, d)``).

    A function with less material than a solve needs (``min_support_fraction``) is held at rest: its
    values are zero, not the flow's (``held`` 1 there, by direction; 0 where a wall holds the direction, whose
    value is the wall's own motion). A particle at the edge of the water, or alone (a drop), that weighs it
    would take a share of zero into its change, its new velocity and its displacement: a drop fell short of
    free fall by that share. The partition of unity over the moved functions restores the whole where the held
    ones weigh little; a particle that leans on them more, whose few moved functions say little of it, is
    divided by no less than ``1 - HELD_WEIGHT_RESTORED`` and, from twice that weight, left as it is."""
    for i in range(restored.shape[0]):
        c, d = restored[i, 0], restored[i, 1]
        share = _restored_share(at, held, d)
        if share > 0.0:
            at[c] = at[c] / (1.0 - share * at[held + d])


def restore_held(space: Space, values: np.ndarray):
    """:func:`_restore_held` on each row of ``values`` ``(n, bs)``, the fields of ``space`` at the particles."""
    held, restored = _held_fields(space)
    if held >= 0:
        _restore_held_rows(values, held, restored)


@numba.njit(cache=True)
def _restore_held_rows(values, held, restored):
    for p in range(values.shape[0]):
        _restore_held(values[p], held, restored)


@numba.njit(cache=True)
def _g2p_state(phi, lfun, nodes, x, grid_values, offsets, held, restored, share, rest_share, rest_speed, rule, h,
               floor, velocity, acceleration, affine_velocity, affine_acceleration, values, divergence):
    """:func:`update_state` particle by particle: the values of ``grid_values`` into ``values[p]`` (over the
    moved functions, :func:`_restore_held`, ``held`` the offset of that field, -1 without), the
    :func:`flip` of velocity and acceleration (``offsets``: of ``dv``, ``da``, ``v``, ``a``; the PIC share
    rising from ``share`` to ``rest_share`` as the new speed falls from ``rest_speed`` to zero), ``div v``,
    and with ``rule`` the affine parts of ``v`` and ``a`` (0: APIC's ``B D^-1``, 1: the grid gradient; -1: none)."""
    dv, da, v, a = offsets[0], offsets[1], offsets[2], offsets[3]
    components = np.array([v, v + 1, a, a + 1])
    b, C = np.empty((4, 2)), np.empty((4, 2))
    for p in range(lfun.shape[0]):
        phi_p, lfun_p, at = phi[p], lfun[p], values[p]
        particle_jets(phi_p, lfun_p, grid_values, values[p:p + 1])  # the values: the first jet
        _restore_held(at, held, restored)
        k = share
        if rest_share > share:
            speed = np.sqrt(at[v] * at[v] + at[v + 1] * at[v + 1])
            if speed < rest_speed:
                k = share + (rest_share - share) * (1.0 - speed / rest_speed)
        for c in range(2):
            velocity[p, c] = _flip(velocity[p, c], at[dv + c], at[v + c], k)
            acceleration[p, c] = _flip(acceleration[p, c], at[da + c], at[a + c], k)
        divergence[p] = (_particle_derivative(phi_p, lfun_p, grid_values, 0, v) / h
                         + _particle_derivative(phi_p, lfun_p, grid_values, 1, v + 1) / h)
        if rule == 0:
            d00, d01, d11 = _second_moments(phi_p, lfun_p, nodes, x[p])
            for k in range(4):
                b[k, 0], b[k, 1] = _first_moment(phi_p, lfun_p, nodes, x[p], grid_values, components[k])
            for d in range(2):  # the held functions at s f_p (_restore_held): B += s f_p sum_held N_i (x_i - x_p)
                given = _restored_share(at, held, d)
                if given > 0.0:
                    m0, m1 = _first_moment(phi_p, lfun_p, nodes, x[p], grid_values, held + d)
                    for k in (d, 2 + d):
                        b[k, 0] += given * at[components[k]] * m0
                        b[k, 1] += given * at[components[k]] * m1
            _times_inverse_moments(b, d00, d01, d11, floor, C)
        elif rule == 1:
            for k in range(4):
                for d in range(2):
                    C[k, d] = _particle_derivative(phi_p, lfun_p, grid_values, d, components[k]) / h
        if rule >= 0:
            affine_velocity[p] = C[:2]
            affine_acceleration[p] = C[2:]
