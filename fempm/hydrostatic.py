"""The pressure known at the solve whose work the momentum balance's split takes by parts: the hydrostatic one
(``solver.pressure_work = "split"``) or the last step's (``"increment"``, :class:`LastPressure`).

In divergence form, ``-p div w`` at the particles, water at rest balances gravity only as well as the particle
quadrature integrates ``div(p w)``; that error times the hydrostatic pressure is a force that grows with the
depth and moves the particles that make it (README, known limits). The split adds to the pressure's work the
divergence of ``D H cof F*^T w`` (``forms/incompressible.py``, ``pressure_work``), an exact zero wherever the
known field ``D H`` vanishes on the water's free edges, so that at the particles the hydrostatic part works
through ``w . grad(D H)``, free of its level. ``H`` is taken here from the wet fractions of the step's P2G::

    H = rho |g| max(min(eta - y, h dist) - BELOW h, 0)

``eta`` the water's depth in the function's column (the wet fraction summed up the column), ``y`` the function's
Greville point (a linear field's coefficients are its values there), ``dist`` the distance in functions to the
water's edge: the least, over all functions ``k``, of the Chebyshev distance to ``k`` plus ``k``'s dryness, which
rises from 0 at a wet fraction of :data:`DRY` to infinity at :data:`FULL`, ``(phi - DRY) / (FULL - phi)`` (the
outside of an open side is dry, the walls' is not). So ``H`` is zero within ``BELOW`` cells of every free surface,
above and beside the water, grows no faster than ``rho |g|`` in any direction, and changes continuously with the
wet fractions (a distance counted to the nearest function below a threshold jumped by a cell as one crossed it, and
made the wall gauges noisier; docs/notes-accuracy.md). Every rank computes it on the whole grid from the gathered wet
fractions: the same numbers on any number of ranks. Gravity along ``-y`` only; otherwise ``H`` is zero.
"""

from __future__ import annotations

import numba
import numpy as np
from mpi4py import MPI

from fempm.space import GridFunction, Space

__all__ = ["BELOW", "DRY", "FULL", "HydrostaticPressure", "LAST_PRESSURE_COURANT", "LastPressure"]

#: cells below every free surface within which ``H`` is zero (measured: docs/notes-accuracy.md, the split)
BELOW = 2.0
#: the wet fractions at and below which a function is dry, and from which it is wholly wet (see the module)
DRY, FULL = 0.3, 0.9
#: the step's Courant number ``max |v| dt / h`` up to which :class:`LastPressure` takes the last step's pressure
#: whole, and from which not at all (measured: docs/notes-accuracy.md, the increment)
LAST_PRESSURE_COURANT = (1.0, 2.0)


@numba.njit(cache=True)
def _distance_to_edge(fraction, open_sides, out):
    """``dist`` of the module for every function of ``fraction`` ``(nfy, nfx)``: each function's dryness, then two
    passes of the chessboard transform; beyond an open side (``open_sides``: left, right, bottom, top) lies a dry
    row, beyond a wall none (at most ``nfx + nfy``)."""
    nfy, nfx = fraction.shape
    far = float(nfx + nfy)
    for j in range(nfy):
        for i in range(nfx):
            phi = fraction[j, i]
            d = 0.0 if phi <= DRY else far if phi >= FULL else min((phi - DRY) / (FULL - phi), far)
            if (open_sides[0] and i == 0) or (open_sides[1] and i == nfx - 1) or \
                    (open_sides[2] and j == 0) or (open_sides[3] and j == nfy - 1):
                d = min(d, 1.0)
            out[j, i] = d
    for j in range(nfy):
        for i in range(nfx):
            d = out[j, i]
            if i > 0:
                d = min(d, out[j, i - 1] + 1.0)
            if j > 0:
                for k in range(max(i - 1, 0), min(i + 1, nfx - 1) + 1):
                    d = min(d, out[j - 1, k] + 1.0)
            out[j, i] = d
    for j in range(nfy - 1, -1, -1):
        for i in range(nfx - 1, -1, -1):
            d = out[j, i]
            if i < nfx - 1:
                d = min(d, out[j, i + 1] + 1.0)
            if j < nfy - 1:
                for k in range(max(i - 1, 0), min(i + 1, nfx - 1) + 1):
                    d = min(d, out[j + 1, k] + 1.0)
            out[j, i] = d


@numba.njit(cache=True)
def _hydrostatic(fraction, widths, heights, h, below, scale, open_sides, out):
    """``out`` ``(nfy, nfx)``: ``H`` of the module's formula from the wet fractions ``fraction`` (at most 1), the
    functions' ``widths`` ``int N_j dy`` and Greville ``heights`` above the grid's lower side along ``y``."""
    nfy, nfx = fraction.shape
    _distance_to_edge(fraction, open_sides, out)
    for i in range(nfx):
        eta = 0.0
        for j in range(nfy):
            eta += fraction[j, i] * widths[j]
        for j in range(nfy):
            depth = min(eta - heights[j], h * out[j, i]) - below
            out[j, i] = scale * depth if depth > 0.0 else 0.0


class HydrostaticPressure:
    """``H`` (see the module) on a scalar space's local functions from their wet fractions.

    Args:
        space: a scalar space of the basis.
        gravity: the body force per mass (2-vector).
        density: the water's density.
        open_sides: the sides (of ``fempm.options.SIDES``) that let water out: beyond them the water ends.
    """

    def __init__(self, space: Space, gravity, density: float, open_sides=()):
        grid, basis = space.grid, space.basis
        self.comm = grid.comm
        self.shape = (basis.nfy, basis.nfx)
        self.functions = space.numbering.local_functions
        self.owned = self.functions[: space.numbering.num_owned]
        g = np.asarray(gravity, dtype=float)
        self.active = g[0] == 0.0 and g[1] < 0.0  # gravity along -y
        self.scale = density * float(np.linalg.norm(g))
        self.h = grid.h
        last = float(grid.last[1])
        self.widths = grid.h * basis.side_integrals(grid.ny, last)
        self.heights = grid.h * basis.greville(grid.ny, last)
        self.open_sides = np.array([side in open_sides for side in ("left", "right", "bottom", "top")])
        self._fraction = np.zeros(self.shape)
        self._out = np.zeros(self.shape)

    def __call__(self, fraction: np.ndarray) -> np.ndarray:
        """``H`` on the local functions, given their wet fractions (owned ones read; collective)."""
        if not self.active:
            return np.zeros(len(self.functions))
        whole = self._fraction.reshape(-1)
        whole[:] = 0.0
        whole[self.owned] = np.minimum(fraction[: len(self.owned)], 1.0)
        if self.comm.size > 1:  # one rank owns each function: the sum is exact
            self.comm.Allreduce(MPI.IN_PLACE, whole, op=MPI.SUM)
        _hydrostatic(self._fraction, self.widths, self.heights, self.h, BELOW * self.h, self.scale, self.open_sides,
                     self._out)
        return self._out.reshape(-1)[self.functions]


class LastPressure:
    """The last step's pressure on a scalar space's local functions, ``p_i = sum_p m_p N_i(x_p) p_p / m_i`` (P2G of
    the particles' pressure, which checkpoints and a retried step's saved state carry; 0 where no particle reaches),
    times a share that falls from 1 to 0 as the step's Courant number crosses :data:`LAST_PRESSURE_COURANT`: with
    it as ``H`` only the step's change of pressure works in divergence form (``solver.pressure_work = "increment"``;
    ``forms/incompressible.py``, ``pressure_work``) while the water moves less than a cell in a step, and the whole
    pressure at larger steps, where the last step's pressure is no estimate of this one's (at ten times the seed's
    step the dam break's energy grew at the wall impact).
    """

    def __init__(self, space: Space):
        self.space = space
        self._weighted = GridFunction(space, "mass_pressure")

    def __call__(self, particles, mass: np.ndarray, courant: float) -> np.ndarray:
        """``H`` given the particles, the P2G masses ``m_i`` of the local functions and the step's Courant number
        (collective)."""
        low, high = LAST_PRESSURE_COURANT
        share = min(max((high - courant) / (high - low), 0.0), 1.0)
        phi, lfun = self.space.tabulate_particles(particles, order=0, exact=False)
        weighted = self._weighted
        weighted.values[:] = 0.0
        _scatter_products(phi, lfun, particles["mass"], particles["pressure"], weighted.values)
        weighted.scatter_reverse_add()
        weighted.scatter_forward()
        out = np.empty(len(mass))
        _shared_ratio(weighted.values, mass, share, out)
        return out


@numba.njit(cache=True)
def _scatter_products(phi, lfun, a, b, out):
    """``out[lfun[p, l], 0] += phi[p, 0, l] (a_p b_p)`` (P2G of a product of two particle fields)."""
    for p in range(lfun.shape[0]):
        ab = a[p] * b[p]
        for l in range(lfun.shape[1]):
            out[lfun[p, l], 0] += phi[p, 0, l] * ab


@numba.njit(cache=True)
def _shared_ratio(weighted, mass, share, out):
    """``out_i = share weighted_i / m_i`` where ``m_i > 0``, else 0."""
    for i in range(out.shape[0]):
        out[i] = share * (weighted[i, 0] / mass[i]) if mass[i] > 0 else 0.0
