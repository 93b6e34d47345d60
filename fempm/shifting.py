"""Particle shifting: keep the particles, the step's quadrature points, evenly spread.

The particles follow the flow, and a shearing or straining flow gathers them along some lines and
leaves gaps elsewhere, within cells, where the grid's smoothed density does not see it. The
particle quadrature of the pressure terms degrades with that disorder: a vortex loses energy at a
rate that grows with the distance the flow has carried its particles, and the quadrature's jumps as
particles cross cells ripple the wall pressure (README, departures). After each step every particle
whose neighbourhood is full moves a little down the gradient of the particles' own concentration,
as in SPH's particle shifting (Lind et al. 2012; the anti-clumping term of Sun et al. 2017)::

    g_i  = sum_j V_j (1 + R (W_ij / W(dp))^4) grad_i W_ij
    dr_i = -min(A s_i dt / dp, RELAXATION) dp^2 g_i / STIFFNESS,   |dr_i| <= MAX_SHIFT dp
    s_i  = |v_i| min(1, |v_i|^2 / v_rest^2),   v_rest = REST_SPEED sqrt(|g| h)  (with the split, else 0)

with ``W`` the Wendland C2 kernel of smoothing length ``h_k = 1.3 dp`` (``dp``: the particles'
spacing, ``sqrt(V)``) and ``R = 0.2``. ``g`` responds to a displacement ``d`` of a lattice by at most
``STIFFNESS d / dp^2``, so a relaxation of 1 undoes that stiffest disorder in one step, and beyond 2
the shifts would overshoot and grow: per step the relaxation is ``A`` times the spacings the particle
moved, at most ``RELAXATION``. Per unit time it is ``A |v| / dp`` whatever the step (less where the
cap holds, at large steps); particles at rest stay. With the hydrostatic pressure's work split off
(``solver.pressure_work = "split"``) the rate fades as ``|v|^3`` below the speed ``v_rest`` (``h`` the grid's cell):
in water at rest the particles' speeds are the transfer's noise, and shifts four times the distance it carries
them, fed back through the quadrature, stirred a column at rest that the split otherwise holds. In divergence form
the column stirs without the shifting, and the fade made a disordered one stir faster (docs/notes-accuracy.md).
Without gravity, and without the split, ``v_rest = 0``.

The shift moves the quadrature points, not the material: a particle keeps its values. (Moved along
its affine parts, ``v += C dr``, particles next to a free surface, shifted step after step the same
way, gathered speed until the energy check stopped the dam break at half the seed's step.) The
moved particles' mean shift (mass-weighted, over all ranks) is taken off theirs, so that shifting
moves no mass against gravity: it leaves the kinetic and the potential energy as they were. A shift
``dr`` of a particle that keeps its velocity adds ``m dr x v`` to the angular momentum (in a vortex
the shifts' sum drifts it steadily). Asked to keep it (``Scheme.shifting_keeps_angular_momentum``), the
moved particles also take a common ``lambda z x (v - v_mean)`` (``v_mean`` their mean velocity, so the
mean shift stays zero) with the one ``lambda`` over all ranks that makes the shifts add none. The
slip walls of the grid's sides are mirrors (the neighbours' images across them count), so a particle
next to a wall sees a full neighbourhood. Only particles whose concentration ``sum_j V_j W_ij`` is
at least ``FULL`` of a lattice's move: along a free surface, where the kernel reaches into air, a
shift down the concentration gradient would push the water outwards.
"""

from __future__ import annotations

import numba
import numpy as np

from fempm import collective
from fempm.particles import counting_order

__all__ = ["REST_SPEED", "ParticleShifting", "concentration_gradients", "kernel_at_spacing", "lattice_concentration", "spacing"]

SMOOTHING = 1.3  #: the kernel's smoothing length over the particle spacing
TENSILE = 0.2  #: R: the anti-clumping term's weight
MAX_SHIFT = 0.25  #: the largest shift per step, in particle spacings
#: the largest response of the shifts' gradient to a displacement of a lattice, ``grad = STIFFNESS d / dp^2``
#: (columns displaced alternately: every other column by ``d``, the others by ``-d``)
STIFFNESS = 3.0
#: the largest relaxation per step, of that stiffest disorder: under 2, where the relaxation would overshoot and grow
RELAXATION = 1.5
FULL = 0.95  #: a particle moves where its concentration is at least this share of a lattice's
#: the speed below which the shifting fades, a share of ``sqrt(|g| h)`` (see the module)
REST_SPEED = 1e-2


@numba.njit(cache=True, inline="always")
def _wendland(t, norm):
    """Wendland C2 kernel ``W`` at ``t = 1 - q / 2`` (``q = r / h_k < 2``), and ``t^3`` (its radial derivative over
    ``h_k r`` is ``-5 norm t^3 / h_k^2``, free of ``r``)."""
    t3 = t * t * t
    return norm * t3 * t * (5.0 - 4.0 * t), t3


@numba.njit(cache=True, inline="always")
def _pair(dx, dy, support2, inv_hk, norm, dnorm, inv_w_dp):
    """For points ``(dx, dy)`` apart: ``W`` and the factor ``f`` of ``grad_i W_ij (1 + R (W / W(dp))^4) = f (dx,
    dy)``; (0, 0) beyond the support."""
    r2 = dx * dx + dy * dy
    if r2 >= support2:
        return 0.0, 0.0
    w, t3 = _wendland(1.0 - 0.5 * np.sqrt(r2) * inv_hk, norm)
    ratio = w * inv_w_dp
    ratio *= ratio
    return w, (1.0 + TENSILE * ratio * ratio) * dnorm * t3


@numba.njit(cache=True)
def _bins(x, lower, nbx, nby, size):
    """The points sorted by square bins of side ``size`` (a counting sort): the order, and each bin's start in it."""
    bin_of = np.empty(x.shape[0], dtype=np.int64)
    for i in range(x.shape[0]):
        bx = min(max(int((x[i, 0] - lower[0]) / size), 0), nbx - 1)
        by = min(max(int((x[i, 1] - lower[1]) / size), 0), nby - 1)
        bin_of[i] = bx + nbx * by
    return counting_order(bin_of, nbx * nby)


#: a bin's neighbours whose pairs it sums (the other half sum theirs with it): right, and the row above
HALF_SHELL = ((1, 0), (-1, 1), (0, 1), (1, 1))


@numba.njit(cache=True)
def concentration_gradients(x, volume, n_own, lower, upper, mirror, hk, w_dp, grad, conc):
    """``grad_i = sum_j V_j (1 + R (W_ij / W(dp))^4) grad_i W_ij`` and ``conc_i = sum_j V_j W_ij`` for the first
    ``n_own`` points, over all points within ``2 h_k`` and their images across the mirrored sides (left,
    right, bottom, top). Each pair of points is taken once, for both (the terms are symmetric)."""
    n = x.shape[0]
    support = 2.0 * hk
    support2, inv_hk, inv_w_dp = support * support, 1.0 / hk, 1.0 / w_dp
    norm = 7.0 / (4.0 * np.pi * hk * hk)
    dnorm = -5.0 * norm * inv_hk * inv_hk
    nbx = max(int((upper[0] - lower[0]) / support) + 1, 1)
    nby = max(int((upper[1] - lower[1]) / support) + 1, 1)
    order, start = _bins(x, lower, nbx, nby, support)
    xs, ys, vs = np.empty(n), np.empty(n), np.empty(n)  # the points in bin order
    for a in range(n):
        xs[a], ys[a], vs[a] = x[order[a], 0], x[order[a], 1], volume[order[a]]
    cs, gx, gy = vs * norm, np.zeros(n), np.zeros(n)  # each point's own W(0)
    for by in range(nby):
        for bx in range(nbx):
            b = bx + nbx * by
            for a in range(start[b], start[b + 1]):
                xa, ya, va = xs[a], ys[a], vs[a]
                ca = gxa = gya = 0.0
                for k in range(len(HALF_SHELL) + 1):  # its own bin's points after it, then the half shell's
                    if k == 0:
                        first, last = a + 1, start[b + 1]
                    else:
                        b2x, b2y = bx + HALF_SHELL[k - 1][0], by + HALF_SHELL[k - 1][1]
                        if b2x < 0 or b2x >= nbx or b2y >= nby:
                            continue
                        first, last = start[b2x + nbx * b2y], start[b2x + nbx * b2y + 1]
                    for c in range(first, last):
                        dx, dy = xa - xs[c], ya - ys[c]
                        w, f = _pair(dx, dy, support2, inv_hk, norm, dnorm, inv_w_dp)
                        ca += vs[c] * w
                        gxa += vs[c] * f * dx
                        gya += vs[c] * f * dy
                        cs[c] += va * w
                        gx[c] -= va * f * dx
                        gy[c] -= va * f * dy
                cs[a] += ca
                gx[a] += gxa
                gy[a] += gya
    _add_images(xs, ys, vs, start, nbx, nby, lower, upper, mirror, support, inv_hk, norm, dnorm, inv_w_dp, cs, gx, gy)
    for a in range(n):
        if order[a] < n_own:
            conc[order[a]], grad[order[a], 0], grad[order[a], 1] = cs[a], gx[a], gy[a]


@numba.njit(cache=True)
def _add_images(xs, ys, vs, start, nbx, nby, lower, upper, mirror, support, inv_hk, norm, dnorm, inv_w_dp, cs, gx,
                gy):
    """Add to each point near a mirrored side the terms of the points' images across it (a side in x and one
    in y at most, and the corner's image of both)."""
    support2 = support * support
    ox, oy, fx, fy = np.empty(4), np.empty(4), np.empty(4), np.empty(4)  # image k of x_j: (ox + fx x_j, oy + fy y_j)
    for a in range(xs.shape[0]):
        xi, yi = xs[a], ys[a]
        images = 1
        ox[0] = oy[0] = 0.0
        fx[0] = fy[0] = 1.0
        if mirror[0] and xi - lower[0] < support or mirror[1] and upper[0] - xi < support:
            ox[1], oy[1], fx[1], fy[1] = 2.0 * (lower[0] if xi - lower[0] < support else upper[0]), 0.0, -1.0, 1.0
            images = 2
        if mirror[2] and yi - lower[1] < support or mirror[3] and upper[1] - yi < support:
            my = 2.0 * (lower[1] if yi - lower[1] < support else upper[1])
            for k in range(images):
                ox[images + k], oy[images + k], fx[images + k], fy[images + k] = ox[k], my, fx[k], -1.0
            images *= 2
        if images == 1:
            continue
        bx = min(max(int((xi - lower[0]) / support), 0), nbx - 1)
        by = min(max(int((yi - lower[1]) / support), 0), nby - 1)
        c = gxa = gya = 0.0
        for b1 in range(max(by - 1, 0), min(by + 2, nby)):
            for b0 in range(max(bx - 1, 0), min(bx + 2, nbx)):
                for j in range(start[b0 + nbx * b1], start[b0 + nbx * b1 + 1]):
                    for k in range(1, images):
                        dx, dy = xi - (ox[k] + fx[k] * xs[j]), yi - (oy[k] + fy[k] * ys[j])
                        w, f = _pair(dx, dy, support2, inv_hk, norm, dnorm, inv_w_dp)
                        c += vs[j] * w
                        gxa += vs[j] * f * dx
                        gya += vs[j] * f * dy
        cs[a] += c
        gx[a] += gxa
        gy[a] += gya


@numba.njit(cache=True)
def _shifts(v, grad, movable, dt, rate, stiffness, cap, rest, mass, shifts):
    """``-min(rate s dt, RELAXATION) grad / stiffness`` (capped at ``cap``), ``s = |v| min(1, |v|^2 / rest^2)``,
    at the ``movable`` particles, 0 elsewhere; returns their mass and mass-weighted sum of shifts (mass, sx, sy)."""
    total = np.zeros(3)
    for i in range(v.shape[0]):
        if not movable[i]:
            continue
        speed2 = v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1]
        speed = np.sqrt(speed2)
        if speed2 < rest * rest:
            speed *= speed2 / (rest * rest)
        s = min(rate * speed * dt, RELAXATION) / stiffness
        dx, dy = -s * grad[i, 0], -s * grad[i, 1]
        length = np.sqrt(dx * dx + dy * dy)
        if length > cap:
            dx, dy = dx * cap / length, dy * cap / length
        shifts[i, 0], shifts[i, 1] = dx, dy
        total[0] += mass[i]
        total[1] += mass[i] * dx
        total[2] += mass[i] * dy
    return total


@numba.njit(cache=True)
def _momentum(v, movable, mass):
    """``sum m v`` over the ``movable`` particles."""
    total = np.zeros(2)
    for i in range(v.shape[0]):
        if movable[i]:
            total[0] += mass[i] * v[i, 0]
            total[1] += mass[i] * v[i, 1]
    return total


@numba.njit(cache=True)
def _turning(v, movable, mass, mean, mean_velocity, shifts):
    """Over the ``movable`` particles: ``sum m (dr - mean) x v``, the angular momentum the shifts less their
    mean would add, and ``sum m |v - mean_velocity|^2``."""
    total = np.zeros(2)
    for i in range(v.shape[0]):
        if movable[i]:
            dx, dy = shifts[i, 0] - mean[0], shifts[i, 1] - mean[1]
            ux, uy = v[i, 0] - mean_velocity[0], v[i, 1] - mean_velocity[1]
            total[0] += mass[i] * (dx * v[i, 1] - dy * v[i, 0])
            total[1] += mass[i] * (ux * ux + uy * uy)
    return total


@numba.njit(cache=True)
def _move(x, v, movable, mean, mean_velocity, turn, shifts):
    """The ``movable`` particles shifted, less the shifts' mean and plus ``turn z x (v - mean_velocity)``."""
    for i in range(x.shape[0]):
        if movable[i]:
            shifts[i, 0] += -mean[0] - turn * (v[i, 1] - mean_velocity[1])
            shifts[i, 1] += -mean[1] + turn * (v[i, 0] - mean_velocity[0])
            x[i, 0] += shifts[i, 0]
            x[i, 1] += shifts[i, 1]


def kernel_at_spacing(hk: float, dp: float) -> float:
    """``W(dp)``, the kernel at one spacing (the anti-clumping term's scale)."""
    return _wendland(1.0 - 0.5 * dp / hk, 7.0 / (4.0 * np.pi * hk * hk))[0]


def _with_neighbours(x: np.ndarray, volume: np.ndarray, reach: float, comm) -> tuple[np.ndarray, np.ndarray]:
    """This rank's particles followed by the other ranks' within ``reach`` of their bounding box."""
    if comm.size == 1:
        return x, volume
    low = x.min(axis=0, initial=np.inf) if len(x) else np.full(2, np.inf)
    high = x.max(axis=0, initial=-np.inf) if len(x) else np.full(2, -np.inf)
    boxes = comm.allgather((low - reach, high + reach))
    outgoing = []
    for rank, (lo, hi) in enumerate(boxes):
        near = np.all((x >= lo) & (x <= hi), axis=1) if rank != comm.rank else np.zeros(len(x), dtype=bool)
        outgoing.append((x[near], volume[near]))
    incoming = comm.alltoall(outgoing)
    xs = [x] + [xi for rank, (xi, _) in enumerate(incoming) if rank != comm.rank]
    vs = [volume] + [vi for rank, (_, vi) in enumerate(incoming) if rank != comm.rank]
    return np.concatenate(xs), np.concatenate(vs)


def spacing(particles) -> float:
    """The particles' spacing ``dp``: the square root of their median volume on all ranks."""
    volume = particles["volume"]
    comm = particles.grid.comm
    values = comm.allgather(float(np.median(volume)) if len(volume) else None)
    return float(np.sqrt(np.median([v for v in values if v is not None])))


def lattice_concentration(hk: float, dp: float) -> float:
    """``sum_j V_j W_ij`` at a point of an unbounded square lattice of spacing ``dp``."""
    k = np.arange(-4, 5) * dp  # the kernel reaches 2 h_k = 2.6 dp
    q = np.hypot(*np.meshgrid(k, k)).ravel() / hk
    t = np.clip(1.0 - 0.5 * q, 0.0, None)
    return float(dp * dp * 7.0 / (4.0 * np.pi * hk * hk) * np.sum(t**4 * (2.0 * q + 1.0)))


class ParticleShifting:
    """The shifting of a run's particles (see the module), its constants set once.

    Args:
        particles: the particles (their median volume sets the spacing ``dp``; collective).
        strength: ``A``, the relaxation per spacing moved.
        mirror: which of the grid's sides (left, right, bottom, top) reflect: its walls.
        keep_angular_momentum: the shifts take the common turn that makes them add no angular momentum.
        rest_speed: ``v_rest`` of the module, below which the shifting fades (0: it does not).
    """

    def __init__(self, particles, strength: float, mirror, keep_angular_momentum: bool = False,
                 rest_speed: float = 0.0):
        self.strength, self.mirror = float(strength), np.asarray(mirror, dtype=np.bool_)
        self.rest_speed = float(rest_speed)
        self.keep_angular_momentum = keep_angular_momentum
        self.dp = spacing(particles)
        self.hk = SMOOTHING * self.dp
        self.w_dp = kernel_at_spacing(self.hk, self.dp)
        self.full = FULL * lattice_concentration(self.hk, self.dp)

    def __call__(self, particles, dt: float) -> np.ndarray:
        """Shift ``particles`` after a step of size ``dt`` (collective); returns the shifts ``(n, 2)``."""
        grid, x, dp = particles.grid, particles.x, self.dp
        n = len(x)
        near, near_volume = _with_neighbours(x, particles["volume"], 2.0 * self.hk, grid.comm)
        shifts, grad, conc = np.zeros((n, 2)), np.empty((n, 2)), np.empty(n)
        concentration_gradients(near, near_volume, n, grid.lower, grid.upper, self.mirror, self.hk, self.w_dp,
                                grad, conc)
        movable = conc >= self.full
        v, mass = particles["velocity"], particles["mass"]
        total = collective.summed(grid.comm, _shifts(v, grad, movable, dt, self.strength / dp, STIFFNESS / dp**2,
                                                      MAX_SHIFT * dp, self.rest_speed, mass, shifts))
        if total[0] == 0:
            return shifts
        mean, mean_velocity, turn = total[1:] / total[0], np.zeros(2), 0.0
        if self.keep_angular_momentum:
            mean_velocity = collective.summed(grid.comm, _momentum(v, movable, mass)) / total[0]
            turning, spread = collective.summed(grid.comm, _turning(v, movable, mass, mean, mean_velocity, shifts))
            turn = turning / spread if spread > 0 else 0.0
        _move(x, v, movable, mean, mean_velocity, turn, shifts)
        return shifts
