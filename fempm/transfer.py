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

Sums over particles on several ranks meet at the owners of the functions.
"""

from __future__ import annotations

import numba
import numpy as np
from mpi4py import MPI

from fempm.assembly import jets_at_particles
from fempm.space import GridFunction, Space

__all__ = [
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


def smoothed_density(mass: np.ndarray, integrals: np.ndarray) -> np.ndarray:
    """``rho~_i = m_i / int N_i dx`` (method.md eq. 2) from the nodal masses ``m_i = sum_p m_p N_i(x_p)``."""
    return mass / integrals


def density_normalisation(basis, particles) -> np.ndarray:
    """``int N_i dx`` of eq. (2) for every structured function, as the particles measure it.

    When all particles come from one seeding lattice (equal volumes, ``n x n`` per cell) the
    integral is taken by that lattice's rule, so that a region filled with particles at rest has
    ``rho~ = rho`` exactly; otherwise by Gauss quadrature.
    """
    comm = basis.grid.comm
    volumes = particles["volume"]
    v_min = comm.allreduce(float(volumes.min(initial=np.inf)), op=MPI.MIN)
    v_max = comm.allreduce(float(volumes.max(initial=0.0)), op=MPI.MAX)
    side = basis.grid.h / np.sqrt(v_max) if v_max > 0 else 0.0
    if v_max > 0 and v_min == v_max and abs(side - round(side)) < 1e-9:
        return basis.lattice_integrals(int(round(side)))
    return basis.integrals


def flip(velocity: np.ndarray, change: np.ndarray, new: np.ndarray, pic_blend: float) -> np.ndarray:
    """The FLIP/PIC update of a particle quantity: ``(1 - k) (q_p + dq(x_p)) + k q_new(x_p)``.

    FLIP adds the grid's change over the step to the particle's own value; PIC takes the grid's
    new value; ``k = pic_blend`` blends them (0: FLIP, 1: PIC).
    """
    return (1 - pic_blend) * (velocity + change) + pic_blend * new


def _jets(gf: GridFunction, particles, order: int) -> np.ndarray:
    phi, lfun = gf.space.tabulate_particles(particles, order)
    phi = np.ascontiguousarray(phi)
    out = np.empty((len(particles), phi.shape[1], gf.space.bs))
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
