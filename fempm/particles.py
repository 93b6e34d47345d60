"""Material points: a struct-of-arrays store, seeding, location and migration.

Every particle is held by the rank that owns the grid cell it lies in, and the
particles of a rank are kept sorted by (cell, id) so that sums over particles
are taken in the same order whatever the number of ranks.

Standard fields: ``x`` (position), ``volume``, ``mass``, ``velocity``,
``acceleration``, ``id`` (a stable integer); more are added with
:meth:`Particles.add_field` (``density`` is added by seeding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from fempm import collective
from fempm.errors import InputError, ParticleOutsideGridError
from fempm.grid import Grid

__all__ = ["ParticleSubset", "Particles", "Polygon", "Rectangle", "sub_cell_centres"]


@dataclass(frozen=True)
class Rectangle:
    """The rectangle ``[x0, x1] x [y0, y1]``."""

    lower: tuple[float, float]
    upper: tuple[float, float]

    def __post_init__(self):
        if not np.all(np.asarray(self.upper, float) > np.asarray(self.lower, float)):
            raise InputError(f"rectangle: upper {self.upper} must exceed lower {self.lower}")

    def contains(self, x: np.ndarray) -> np.ndarray:
        """Boolean mask of the points inside (boundary included)."""
        lo, up = np.asarray(self.lower), np.asarray(self.upper)
        return np.all((x >= lo) & (x <= up), axis=1)

    def bounds(self):
        """``(lower, upper)`` corners of the bounding box."""
        return np.asarray(self.lower, float), np.asarray(self.upper, float)


@dataclass(frozen=True)
class Polygon:
    """A simple polygon given by its vertices in order (even-odd inside test).

    Simple: no two edges meet except neighbours at their shared vertex; a polygon whose
    edges cross (a bow-tie) or touch is refused, whatever area it would enclose.
    """

    vertices: tuple[tuple[float, float], ...]

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=float)
        if v.ndim != 2 or v.shape[0] < 3 or v.shape[1] != 2:
            raise InputError("polygon: needs at least three (x, y) vertices")
        if not np.all(np.isfinite(v)):
            raise InputError("polygon: the vertices must be finite")
        repeated = np.flatnonzero(np.all(v == np.roll(v, -1, axis=0), axis=1))
        if len(repeated):
            k = int(repeated[0])
            raise InputError(f"polygon: vertices {k} and {(k + 1) % len(v)} are the same point {v[k].tolist()}")
        crossing = _crossing_edges(v)
        if crossing:
            i, j = crossing
            raise InputError(f"polygon: edges {i} ({v[i].tolist()}..{v[(i + 1) % len(v)].tolist()}) and {j} "
                             f"({v[j].tolist()}..{v[(j + 1) % len(v)].tolist()}) cross or touch: the polygon "
                             f"must be simple (its edges meet only at shared vertices)")
        if self.area() == 0.0:
            raise InputError("polygon: the vertices enclose no area")

    def area(self) -> float:
        """The enclosed area (shoelace formula)."""
        v = np.asarray(self.vertices, dtype=float)
        return float(abs(0.5 * np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])))

    def contains(self, x: np.ndarray) -> np.ndarray:
        """Boolean mask of the points inside."""
        v = np.asarray(self.vertices, dtype=float)
        inside = np.zeros(len(x), dtype=bool)
        for (xa, ya), (xb, yb) in zip(v, np.roll(v, -1, axis=0)):
            crosses = (ya > x[:, 1]) != (yb > x[:, 1])
            with np.errstate(divide="ignore", invalid="ignore"):
                x_cross = xa + (x[:, 1] - ya) * (xb - xa) / (yb - ya)
            inside ^= crosses & (x[:, 0] < x_cross)
        return inside

    def bounds(self):
        """``(lower, upper)`` corners of the bounding box."""
        v = np.asarray(self.vertices, dtype=float)
        return v.min(axis=0), v.max(axis=0)


def _crossing_edges(v: np.ndarray) -> tuple[int, int] | None:
    """The first pair of edges ``(i, j)`` of the closed polygon ``v`` that meet other than at a vertex
    the two share as neighbours: a crossing, a touch, or neighbours folding back along each other."""
    n = len(v)
    a, d = v, np.roll(v, -1, axis=0) - v  # edge k runs from a[k] to a[k] + d[k]
    i, j = np.triu_indices(n, 1)
    scale = float(np.abs(v).max() + np.ptp(v, axis=0).max())
    tol = 1e-12 * scale**2  # of a cross product of two edge-sized vectors

    def cross(u, w):
        return u[..., 0] * w[..., 1] - u[..., 1] * w[..., 0]

    def side(o):  # -1, 0 or 1: a point right of, on, or left of a line
        return np.where(o > tol, 1, np.where(o < -tol, -1, 0))

    def within(p, s, e):  # p in the box of segment s..e
        margin = 1e-12 * scale
        return np.all((p >= np.minimum(s, e) - margin) & (p <= np.maximum(s, e) + margin), axis=-1)

    b = a + d
    s1, s2 = side(cross(d[i], a[j] - a[i])), side(cross(d[i], b[j] - a[i]))
    s3, s4 = side(cross(d[j], a[i] - a[j])), side(cross(d[j], b[i] - a[j]))
    proper = (s1 * s2 < 0) & (s3 * s4 < 0)
    touch = (((s1 == 0) & within(a[j], a[i], b[i])) | ((s2 == 0) & within(b[j], a[i], b[i]))
             | ((s3 == 0) & within(a[i], a[j], b[j])) | ((s4 == 0) & within(b[i], a[j], b[j])))
    neighbours = (j == i + 1) | ((i == 0) & (j == n - 1))
    folds = (np.abs(cross(d[i], d[j])) <= tol) & (np.einsum("kc,kc->k", d[i], d[j]) < 0)
    hit = np.flatnonzero(np.where(neighbours, folds, proper | touch))
    return (int(i[hit[0]]), int(j[hit[0]])) if len(hit) else None


def sub_cell_centres(origins: np.ndarray, sizes, per_cell: int) -> np.ndarray:
    """Centres of the ``per_cell x per_cell`` sub-cells of cells with the given lower-left corners
    and sizes (a number, the side of square cells, or ``(n, 2)`` widths and heights: a cut cell's
    lattice is its own, shrunk), cell by cell (x fastest): where :meth:`Particles.seed` puts particles."""
    sub = (np.arange(per_cell) + 0.5) / per_cell
    sub_xi = np.stack(np.meshgrid(sub, sub, indexing="xy"), -1).reshape(-1, 2)
    sizes = np.asarray(sizes, dtype=np.float64)
    scale = sizes if sizes.ndim == 0 else sizes[:, None, :]
    return (np.asarray(origins)[:, None, :] + scale * sub_xi[None]).reshape(-1, 2)


_STANDARD = {"x": (2,), "volume": (), "mass": (), "velocity": (2,), "acceleration": (2,)}


def lattice_points(grid: Grid, body, n: int, earlier: list, first_id: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``n x n`` sub-cell centres of this rank's cells inside ``body`` and outside the
    ``earlier`` bodies, with their ids ``first_id + cell * n**2 + sub`` (independent of the ranks)
    and the volumes they stand for (``h^2 / n^2``; in a cut cell its area over ``n^2``)."""
    cells = np.sort(grid.owned_cells)
    sizes = grid.cell_sizes(cells)
    x = sub_cell_centres(grid.cell_origin(cells), sizes, n)
    keep = body.contains(x)
    for other in earlier:
        keep &= ~other.contains(x)
    ids = (first_id + cells[:, None] * n * n + np.arange(n * n)).ravel()[keep]
    volumes = np.repeat(sizes.prod(axis=1) / n**2, n * n)[keep]
    return x[keep], ids, volumes


class Particles:
    """The particles held by this rank, as a struct of arrays.

    Args:
        grid: the background grid.
        on_exit: what :meth:`relocate` does with a particle outside the grid:
            ``"error"`` (default) raises :class:`ParticleOutsideGridError` naming it;
            ``"delete"`` removes it and adds its mass to :attr:`lost_mass`.

    Attributes:
        fields: every per-particle array by name, first axis the particle.
        cell, xi: structured cell and reference coordinates, set by :meth:`relocate`.
        lost_mass, lost_count: mass and number of particles deleted on this rank.
    """

    def __init__(self, grid: Grid, on_exit: str = "error"):
        if on_exit not in ("error", "delete"):
            raise InputError(f"particles: on_exit must be 'error' or 'delete', got {on_exit!r}")
        self.grid = grid
        self.on_exit = on_exit
        self.fields: dict[str, np.ndarray] = {
            name: np.zeros((0, *shape)) for name, shape in _STANDARD.items()
        }
        self.fields["id"] = np.zeros(0, dtype=np.int64)
        self.cell = np.zeros(0, dtype=np.int64)
        self.xi = np.zeros((0, 2))
        self.lost_mass = 0.0
        self.lost_count = 0
        self.cache: dict = {}  # data that holds until the particles move (tabulations)
        self._bodies: list = []
        self._next_id = 0

    # -- access ------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.fields["id"])

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.fields[name]
        except KeyError:
            raise KeyError(f"particles have no field {name!r}; they have {sorted(self.fields)}") from None

    @property
    def x(self) -> np.ndarray:
        """Positions, shape ``(n, 2)``."""
        return self.fields["x"]

    @property
    def id(self) -> np.ndarray:
        """Stable global ids."""
        return self.fields["id"]

    def add_field(self, name: str, shape: tuple[int, ...] = (), value=0.0) -> np.ndarray:
        """Add a per-particle array ``name`` of the given value shape, filled with ``value``."""
        if name in self.fields:
            raise InputError(f"particles: field {name!r} exists already")
        self.fields[name] = np.full((len(self), *shape), value, dtype=np.float64)
        return self.fields[name]

    def global_count(self) -> int:
        """Number of particles on all ranks."""
        return self.grid.comm.allreduce(len(self))

    # -- seeding ------------------------------------------------------------------
    def seed(self, body, per_cell: int, density: float, **values) -> int:
        """Add ``per_cell x per_cell`` particles per cell, at sub-cell centres inside ``body``
        (in a cut cell of the tank's last column or row, the centres of its own sub-cells).

        Sub-cell centres already inside an earlier body are skipped (bodies are
        unions). Ids are ``offset + cell * per_cell**2 + sub``, independent of the
        number of ranks. Only this rank's cells are seeded.

        Args:
            body: a :class:`Rectangle` or :class:`Polygon` inside the grid.
            per_cell: particles per cell and direction.
            density: mass density; ``volume = h**2 / per_cell**2`` (a cut cell's area over
                ``per_cell**2`` there), ``mass = density * volume``.
            **values: initial values of other fields (scalars or per-component sequences), or
                functions of the positions ``(n, 2)`` returning them (an initial velocity field).

        Returns:
            The number of particles seeded on all ranks.
        """
        if int(per_cell) != per_cell or per_cell < 1:
            raise InputError(f"seed: particles per cell must be a positive integer, got {per_cell}")
        if not (np.isfinite(density) and density > 0):
            raise InputError(f"seed: density must be positive, got {density}")
        lo, up = body.bounds()
        tol = 1e-9 * self.grid.h
        if np.any(lo < self.grid.lower - tol) or np.any(up > self.grid.upper + tol):
            raise InputError(
                f"seed: body with bounds {lo.tolist()}..{up.tolist()} is not inside the grid "
                f"{self.grid.lower.tolist()}..{self.grid.upper.tolist()}"
            )
        x, ids, volumes = lattice_points(self.grid, body, int(per_cell), self._bodies, self._next_id)
        self._bodies.append(body)
        self._next_id += self.grid.num_cells * int(per_cell) ** 2
        values = {name: value(x) if callable(value) else value for name, value in values.items()}
        return self.add_points(x, volumes, density, ids=ids, **values)

    def add_points(self, x, volume, density: float = 1.0, ids=None, **values) -> int:
        """Add particles at the given positions (on any rank; they move to their owners).

        Args:
            x: positions, shape ``(n, 2)``.
            volume: volume of each particle (a number or one per particle).
            density: mass density (a number or one per particle); ``mass = density * volume``.
            ids: global ids; by default the next unused ones, numbered rank by rank.
            **values: initial values of other existing fields.

        Returns:
            The number of particles added on all ranks.
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1, 2)
        n = len(x)
        comm = self.grid.comm
        if ids is None:
            first = comm.exscan(n) if comm.size > 1 else 0
            ids = self._next_id + (first or 0) + np.arange(n)
            self._next_id += comm.allreduce(n)
        new = {name: np.zeros((n, *a.shape[1:]), dtype=a.dtype) for name, a in self.fields.items()}
        new["x"][:] = x
        new["volume"][:] = volume
        new["id"][:] = ids
        if "density" not in self.fields:
            self.add_field("density")
            new["density"] = np.zeros(n)
        new["density"][:] = density
        new["mass"][:] = new["density"] * new["volume"]
        for name, value in values.items():
            if name not in self.fields:
                raise InputError(f"particles: unknown field {name!r}; add it with add_field first")
            new[name][:] = value
        self._append(new)
        self.relocate()
        return comm.allreduce(n)

    def replace(self, fields: dict[str, np.ndarray]):
        """Replace all particles by the given ones (e.g. read from a checkpoint on rank 0).

        Any rank may pass any particles (others pass empty arrays); they are sent to
        their owners and sorted as :meth:`relocate` does. ``fields`` must hold exactly
        the fields these particles have.
        """
        if set(fields) != set(self.fields):
            raise InputError(f"particles: the replacement has fields {sorted(fields)}, "
                             f"these particles have {sorted(self.fields)}")
        self.fields = {name: np.asarray(fields[name], dtype=a.dtype).reshape(-1, *a.shape[1:])
                       for name, a in self.fields.items()}
        self.relocate()

    def state(self) -> dict:
        """A copy of this rank's particles (fields, cells, reference coordinates, losses), for :meth:`restore`."""
        return {"fields": {name: a.copy() for name, a in self.fields.items()}, "cell": self.cell.copy(),
                "xi": self.xi.copy(), "lost": (self.lost_mass, self.lost_count)}

    def restore(self, state: dict):
        """Back to a :meth:`state` of these particles (on the same rank)."""
        self.fields = {name: a.copy() for name, a in state["fields"].items()}
        self.cell, self.xi = state["cell"].copy(), state["xi"].copy()
        self.lost_mass, self.lost_count = state["lost"]
        self.cache.clear()

    def _append(self, new: dict[str, np.ndarray]):
        for name in self.fields:
            self.fields[name] = np.concatenate([self.fields[name], new[name]])

    def _remove(self, mask: np.ndarray):
        """Delete the particles of ``mask``, adding them to the lost mass and count."""
        self.lost_mass += float(self.fields["mass"][mask].sum())
        self.lost_count += int(mask.sum())
        keep = np.flatnonzero(~mask)
        for name in self.fields:
            self.fields[name] = self.fields[name][keep]

    def _take(self, index: np.ndarray):
        for name in self.fields:
            self.fields[name] = _rows(self.fields[name], index)
        self.cell = self.cell[index]
        self.xi = _rows(self.xi, index)

    # -- validation, location, migration --------------------------------------------
    def check(self):
        """Raise a clear error for a non-finite position or a non-positive volume or mass."""
        if _all_valid(self.fields["volume"], self.fields["mass"], self.x):  # nothing to name
            return
        for name in ("volume", "mass"):
            bad = np.flatnonzero(~(self.fields[name] > 0))
            if bad.size:
                k = bad[0]
                raise InputError(f"particle {self.id[k]}: {name} must be positive, got {self.fields[name][k]}")
        bad = np.flatnonzero(~np.all(np.isfinite(self.x), axis=1))
        if bad.size:
            k = bad[0]
            raise ParticleOutsideGridError(f"particle {self.id[k]} has a non-finite position "
                                           f"({self.x[k, 0]}, {self.x[k, 1]})")

    def relocate(self):
        """Locate every particle, send it to the rank owning its cell, sort by (cell, id).

        Particles outside the grid, or in a cell blocked by an obstacle
        (:meth:`fempm.Grid.block`), raise :class:`ParticleOutsideGridError` on every
        rank or, with ``on_exit="delete"``, are removed and counted in :attr:`lost_mass`.
        """
        self.check()
        cells, xi, gone = self.grid.place(self.x)
        if self.grid.blocked.any():
            gone |= (cells >= 0) & self.grid.blocked[cells]
        if self.on_exit == "delete" and gone.any():
            self._remove(gone)
            cells, xi = self.grid.locate(self.x, ids=self.id)
        elif self.on_exit != "delete":
            raise_if_any_gone(self.grid, self.x, self.id, gone)
        self.cell, self.xi = cells, xi
        if self.grid.comm.size > 1:
            self.fields = exchange(self.fields, self.grid.owner[self.cell], self.grid.comm)
            self.cell, self.xi = self.grid.locate(self.x, ids=self.id)
        self._take(_cell_id_order(self.cell, self.id, self.grid.num_cells))
        self.cache.clear()


@numba.njit(cache=True)
def _all_valid(volume, mass, x) -> bool:
    """Whether every volume and mass is positive and every position finite (NaN fails the comparisons)."""
    for p in range(volume.shape[0]):
        if not (volume[p] > 0 and mass[p] > 0 and np.isfinite(x[p, 0]) and np.isfinite(x[p, 1])):
            return False
    return True


@numba.njit(cache=True)
def counting_order(keys, count):
    """The indices of ``keys`` (integers in ``[0, count)``) by increasing key, in their own order within a key (a
    counting sort), and where each key's run starts (``count + 1`` entries)."""
    start = np.zeros(count + 1, dtype=np.int64)
    for i in range(keys.shape[0]):
        start[keys[i] + 1] += 1
    for k in range(count):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(keys.shape[0], dtype=np.int64)
    for i in range(keys.shape[0]):
        order[fill[keys[i]]] = i
        fill[keys[i]] += 1
    return order, start


@numba.njit(cache=True)
def _cell_id_order(cell, ids, num_cells):
    """The particles in order of (cell, id): by cell (:func:`counting_order`, which keeps the last order within a
    cell), then each cell's few particles by id (an insertion sort of what is mostly in order already)."""
    order, start = counting_order(cell, num_cells)
    for c in range(num_cells):
        for i in range(start[c] + 1, start[c + 1]):
            q = order[i]
            j = i
            while j > start[c] and ids[order[j - 1]] > ids[q]:
                order[j] = order[j - 1]
                j -= 1
            order[j] = q
    return order


class ParticleSubset:
    """Some of a rank's particles (``index``, kept in their order), read by the forms' assembly as the particles
    are: a vector assembled over them equals the one over all the particles at every dof no other particle adds to."""

    def __init__(self, particles: Particles, index: np.ndarray):
        self._particles, self._index = particles, index
        self.cell, self.xi = particles.cell[index], _rows(particles.xi, index)
        self.cache: dict = {}  # their tabulations (fempm.space.Space.tabulate_particles)
        self._fields: dict[str, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self._index)

    @property
    def x(self) -> np.ndarray:
        return self["x"]

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._fields:
            self._fields[name] = _rows(self._particles[name], self._index)
        return self._fields[name]


def _rows(a: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``a[index]``; by ``np.take`` for arrays of more than one axis, where indexing takes a slower path."""
    return a[index] if a.ndim == 1 else np.take(a, index, axis=0)


def exchange(fields: dict[str, np.ndarray], destination: np.ndarray, comm) -> dict[str, np.ndarray]:
    """Send row ``k`` of every array to rank ``destination[k]``; returns what this rank receives."""
    order = np.argsort(destination, kind="stable")
    counts = np.bincount(destination, minlength=comm.size)
    recv_counts = np.empty_like(counts)
    comm.Alltoall(counts, recv_counts)
    received = {}
    for name, a in fields.items():
        a = np.ascontiguousarray(a[order])
        width = int(np.prod(a.shape[1:], dtype=np.int64))
        out = np.empty((recv_counts.sum(), *a.shape[1:]), dtype=a.dtype)
        comm.Alltoallv([a, counts * width], [out, recv_counts * width])
        received[name] = out
    return received


def raise_if_any_gone(grid: Grid, x: np.ndarray, ids: np.ndarray, gone: np.ndarray):
    """Raise :class:`ParticleOutsideGridError` on all ranks if any rank has a particle ``gone``,
    naming the first one and where it went."""
    comm = grid.comm
    if collective.total(comm, int(np.count_nonzero(gone))) == 0:
        return
    message = None
    if np.any(gone):
        k = np.flatnonzero(gone)
        y = x[k[0]]
        try:
            cell = grid.locate(y[None], ids=ids[k[:1]])[0][0]
            message = (f"particle {ids[k[0]]} at ({y[0]:.6g}, {y[1]:.6g}) entered the obstacle "
                       f"cell (column {cell % grid.nx}, row {cell // grid.nx})")
        except ParticleOutsideGridError as outside:
            message = str(outside)
    first = next(m for m in comm.allgather(message) if m is not None)
    total = comm.allreduce(int(gone.sum()))
    raise ParticleOutsideGridError(first + (f" ({total} particles in all)" if total > 1 else ""))
