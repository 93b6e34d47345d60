"""The sides of the grid and the obstacles as constraints on a step: held dofs, and positions kept inside.

Both bases interpolate at the sides, so holding a function's coefficient holds the field's value
on the side. :class:`Walls` lists the held velocity dofs of a space (a side's normal component
for ``slip``, both for ``no-slip``, the tangential one for ``outflow``, none for ``open``; both
on every function non-zero in an obstacle cell) and the value held on each (zero, or a moving
wall's speed); it also stops particles at the impermeable sides and at the obstacles' faces.
:class:`FreeDofs` picks the dofs an implicit step solves for.

**One-sided walls** (contact with separation, Signorini at the velocity level). Held always, a
slip or no-slip wall is two-sided: it pulls water that would leave it, so water thrown at the
lid glides along it instead of falling, and a particle can rest in an upper corner. A wall at
rest should only push::

    v . n <= 0,   lambda >= 0,   lambda (v . n) = 0

``n`` the outward normal, ``lambda`` the wall's push on the water. The reaction of a held dof is
its row's residual at the solution (the momentum balance the constraint force closes): the wall
pushes where ``R_i n_i < 0``. The normal dofs of slip and no-slip sides at rest form an active
set (:meth:`Walls.start_step`, :meth:`Walls.update`; a primal-dual active set, Hintermueller,
Ito & Kunisch 2002), lagged by one step so that a step costs one solve: after a solve, held dofs
that pull are released and free dofs that moved into the wall are held; the next step starts
from that set, with the dofs that were dry held and those whose projected velocity enters the
wall held. A held dof that pulls hard, with more than a cell of water's weight, is released within
the step instead, which is then solved again (:meth:`Walls.settle`; lagged, a wave falling back from a wall is held
for a step by many cells' weight, and the energy jumps).
On a no-slip wall the tangential dof of a function is held and released with its
normal one. Where the step's water has no free surface (every function has material in its
support: a full box or channel, whose pressure level a pin or an outflow fixes) a reaction has
no sign to separate by, and every wall dof stays held (two-sided). Moving walls and obstacles are always held.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from petsc4py import PETSc

from fempm import collective
from fempm.options import Physics
from fempm.space import GridFunction, Space

__all__ = ["FORCE_TOLERANCE", "FreeDofs", "SPEED_TOLERANCE", "STRONG_PULL", "Walls"]

_COMPONENTS = {"slip": "normal", "no-slip": "both", "outflow": "tangential", "open": "none"}
#: the component normal to each side, and the outward normal's sign
_NORMALS = {"left": (0, -1.0), "right": (0, 1.0), "bottom": (1, -1.0), "top": (1, 1.0)}
FORCE_TOLERANCE = 1e-3  #: pulls below this times rho |g| h^2 do not release a wall dof
STRONG_PULL = 1.0  #: pulls above this times rho |g| h^2 (a cell of water's weight) release within the step
SPEED_TOLERANCE = 1e-3  #: motion into a wall below this times sqrt(|g| h) does not hold one


class Walls:
    """The held velocity dofs of a space, and impermeable sides for the particles.

    Args:
        space: a space with a two-component velocity field.
        physics: the sides' conditions, moving walls and recycling.
        field: the name of the velocity field in ``space``.

    Attributes:
        dofs: global numbers of this rank's held owned dofs (sorted).
        values: the velocity held on each: zero, or a moving wall's tangential speed (on dofs no
            side at rest also holds).
        positions: the held dofs as positions among this rank's owned dofs.
        normal: the contact dofs, the normal ones of slip and no-slip sides at rest (positions among
            the owned dofs): the dofs :meth:`update` needs the reaction at.
        stops: particle displacements cut at an impermeable side so far (see :meth:`keep_inside`).
        one_sided: whether :meth:`start_step` releases wall dofs (see the module); False: two-sided.
        released: contact dofs released so far (counted over the steps, this rank).
    """

    def __init__(self, space: Space, physics: Physics, field: str = "u"):
        self.space, self.physics, self.field = space, physics, field
        self.conditions = physics.wall_conditions()
        self._fixed, self._fixed_values = self._held()  # held always (global numbers)
        owned = space.local_to_global[: space.num_owned_dofs]
        self._owned = owned
        self._contact_of(owned)
        self.one_sided = True
        self.free_surface = False  # in this step (see start_step)
        self.released = 0
        self._state = {}
        self.stops = 0
        self._held_for = None  # the active set the held dofs were made for
        self._fixed_positions = np.searchsorted(owned, self._fixed)
        self._value_at = np.zeros(len(owned))  # the velocity held at each owned dof, if held
        self._value_at[self._fixed_positions] = self._fixed_values
        self._set_held()
        # fixed for the run: whether any rank has contact dofs, the contact dofs' structured numbers,
        # and the scale of the tolerances
        self._any_contact = space.comm.allreduce(len(self.normal)) > 0
        functions = space.numbering.local_functions[self.normal // space.bs]
        self._contact_ids = functions * space.bs + self.normal % space.bs
        self._gravity = max(float(np.linalg.norm(physics.gravity)), 1.0)
        self._weighs = float(np.linalg.norm(physics.gravity)) > 0.0  # water has a weight to measure pulls by
        grid, margin = space.grid, 1e-9 * space.grid.h  # where keep_inside stops particles
        impermeable = {side: kind in ("slip", "no-slip") for side, kind in self.conditions.items()}
        self._inside = (np.where([impermeable["left"], impermeable["bottom"]], grid.lower + margin, -np.inf),
                        np.where([impermeable["right"], impermeable["top"]], grid.upper - margin, np.inf))
        self._obstacles = bool(grid.blocked.any())

    def _contact_of(self, owned: np.ndarray):
        """The normal dofs of slip and no-slip sides at rest (positions among the owned dofs), the
        outward normal's sign of each and its no-slip tangential partner (position, or -1)."""
        space = self.space
        normal, sign, partner, orphans = [], [], [], []
        for side, kind in self.conditions.items():
            if kind not in ("slip", "no-slip") or side in self.physics.wall_speeds:
                continue
            component, outward = _NORMALS[side]
            dofs = space.wall_dofs(self.field, component, side[0])
            held = np.isin(dofs, self._fixed)  # held for another reason (an outflow side's, an obstacle's)
            if kind == "no-slip":  # their tangential partners stay held too
                orphans.append(dofs[held] + (1 - 2 * component))
            dofs = dofs[~held]
            tangential = dofs + (1 - 2 * component)  # the other component of the same function
            pair = np.where(np.isin(tangential, self._fixed) | (kind == "slip"), -1,
                            np.searchsorted(owned, tangential))
            normal.append(np.searchsorted(owned, dofs))
            sign.append(np.full(len(dofs), outward))
            partner.append(pair)
        join = lambda parts, dtype: np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)  # noqa: E731
        self.normal, self.sign, self.partner = join(normal, np.int64), join(sign, float), join(partner, np.int64)
        bs, first = space.bs, space.field_offset(self.field)
        self._normal_in_vector = self.normal // bs * 2 + self.normal % bs - first  # in a two-component function
        orphans = np.setdiff1d(join(orphans, np.int64), self._fixed)
        self._fixed = np.concatenate([self._fixed, orphans])
        self._fixed_values = np.concatenate([self._fixed_values, np.zeros(len(orphans))])
        self.active = np.ones(len(self.normal), dtype=bool)  # held now
        self._let_go = np.zeros(len(self.normal), dtype=bool)  # released within this step (settle)
        self._entering = np.zeros(len(self.normal), dtype=bool)  # water projected into the wall this step
        self.wet = np.zeros(len(self.normal), dtype=bool)  # material in the function's support last step

    def _set_held(self):
        """:attr:`dofs`, :attr:`values`, :attr:`positions`: the fixed dofs and the active contact dofs
        (kept when the active set is that of the last call, as it mostly is from one step to the next)."""
        if self._held_for is not None and np.array_equal(self._held_for, self.active):
            return
        self._held_for = self.active.copy()
        bs, first = self.space.bs, self.space.field_offset(self.field)
        # the positions, and the same dofs in a two-component grid function (a velocity or an acceleration)
        self.positions, self._vector_index = _held_positions(len(self._owned), self._fixed_positions, self.normal,
                                                             self.partner, self.active, bs, first)
        self.dofs, self.values = self._owned[self.positions], self._value_at[self.positions]

    def tolerances(self, density: float, dt: float) -> tuple[float, float]:
        """The pull (per unit thickness) below which a held dof stays held,
        ``FORCE_TOLERANCE rho |g| h^2`` (a thousandth of a cell of water's weight), and the
        displacement into a wall below which a free dof stays free, ``SPEED_TOLERANCE sqrt(|g| h) dt``;
        ``|g|`` at least 1 m/s^2 (a case without gravity keeps a scale)."""
        g, h = self._gravity, self.space.grid.h
        return FORCE_TOLERANCE * density * g * h**2, SPEED_TOLERANCE * math.sqrt(g * h) * dt

    def start_step(self, keep: np.ndarray, velocity: GridFunction):
        """This step's held dofs, before the projected ``v_n`` is overwritten on them (collective).

        ``keep``: boolean per owned dof of the space, the dofs the step keeps (material in the
        function's support); ``velocity``: the projected grid velocity (two components). With a
        free surface (some function without material, on any rank: air in the tank) the last
        step's active set, with the dofs that were dry then held, and those whose projected
        velocity enters the wall faster than ``SPEED_TOLERANCE sqrt(|g| h)``; without, every wall dof.
        """
        if not self.one_sided or not self._any_contact:
            return
        all_kept = _all_kept(keep, self.space.bs, self.space.field_offset(self.field))
        self.free_surface = collective.any_rank(self.space.comm, not all_kept)
        _start_active(self.free_surface, keep, velocity.array, self.normal, self._normal_in_vector, self.sign,
                      self.tolerances(0.0, 1.0)[1], self.active, self.wet, self._entering, self._let_go)
        self._set_held()

    def settle(self, reaction: np.ndarray, displacement: np.ndarray, density: float, dt: float) -> bool:
        """Within the step, for it to be solved again: the held dofs whose reaction pulls harder than
        ``STRONG_PULL rho |g| h^2`` released, and those so released in this step that the solve moved into
        the wall (beyond the motion tolerance) held again; whether the set changed on any rank (collective).

        The active set is otherwise lagged by a step (:meth:`update`): water leaving a wall fast, as
        a wave falling back from it, would be held by a pull of many cells' weight for that step. Dofs
        where the projected water enters the wall are not released (an isolated particle's landing gives
        its B-spline dofs reactions of both signs), nor any without gravity (no weight to measure by).
        """
        if not self.one_sided or not self._any_contact or not self.free_surface or not self._weighs:
            return False
        force, motion = self.tolerances(density, dt)
        cell_weight = force / FORCE_TOLERANCE  # rho |g| h^2
        count, back = _settle(self.active, self._entering, self._let_go, reaction, displacement, self.normal, self.sign,
                              STRONG_PULL * cell_weight, motion)
        if collective.total(self.space.comm, count + back) == 0:
            return False
        self.released += count
        self._set_held()
        return True

    def update(self, reaction: np.ndarray, displacement: np.ndarray, density: float, dt: float):
        """The active set after a solve, for the next step: held dofs whose reaction pulls
        (``R n`` above the force tolerance) released, free dofs displaced into the wall (beyond
        the motion tolerance) held (see :meth:`tolerances`).

        ``reaction``: the residual at the solution at the contact dofs (:attr:`normal`, positions among
        the owned dofs); ``displacement``: the solved ``du`` at the owned dofs.
        """
        if not self.one_sided or not self._any_contact:
            return
        if not self.free_surface:  # two-sided this step; the state as start_step left it
            self._gather_state()
            return
        force, motion = self.tolerances(density, dt)
        self.released += _update_active(self.active, reaction, displacement, self.normal, self.sign, force, motion)
        self._gather_state()

    def _gather_state(self):
        """Every rank's released and dry contact dofs (structured numbers: the same whatever the
        ranks), by rank; sorted into lists only when a checkpoint asks (:meth:`contact_state`)."""
        released, dry = _released_and_dry(self._contact_ids, self.active, self.wet)
        comm = self.space.comm
        gather = lambda ids: comm.allgather(ids) if comm.size > 1 else [ids]  # noqa: E731
        self._state = {"walls_released": gather(released), "walls_dry": gather(dry)}

    def contact_state(self) -> dict:
        """The active set after the last step: ``walls_released`` and ``walls_dry``, the structured
        numbers of the released and of the dry contact dofs, the same on every rank (not collective:
        gathered at each :meth:`update`; JSON-able lists, for a checkpoint). Empty before the first step."""
        return {k: np.sort(np.concatenate(parts)).tolist() for k, parts in self._state.items()}

    def restore_contact(self, state: dict | None):
        """Back to a :meth:`contact_state`, or a table holding it (without: every wall dof held, all
        dry, as at the start)."""
        ids = self._contact_ids
        state = {k: state[k] for k in ("walls_released", "walls_dry") if k in (state or {})}
        self.active = ~np.isin(ids, state.get("walls_released", []))
        self.wet = ~np.isin(ids, state["walls_dry"]) if "walls_dry" in state else np.zeros(len(ids), bool)
        self._state = {k: [np.asarray(v, dtype=np.int64)] for k, v in state.items()}
        self._set_held()

    def _held(self) -> tuple[np.ndarray, np.ndarray]:
        space, grid = self.space, self.space.grid
        held = [space.cell_dofs(self.field, np.flatnonzero(grid.blocked))]
        contact, moving, speeds = [], [], []  # contact: slip and no-slip sides at rest (one-sided)
        for side, kind in self.conditions.items():
            normal = 0 if side in ("left", "right") else 1
            components = {"normal": (normal,), "both": (0, 1), "tangential": (1 - normal,), "none": ()}
            for component in components[_COMPONENTS[kind]]:
                dofs = space.wall_dofs(self.field, component, side[0])
                if component != normal and side in self.physics.wall_speeds:
                    moving.append(dofs)
                    speeds.append(np.full(len(dofs), float(self.physics.wall_speeds[side])))
                else:
                    at_rest_wall = kind in ("slip", "no-slip") and side not in self.physics.wall_speeds
                    (contact if at_rest_wall else held).append(dofs)
        at_rest = np.unique(np.concatenate(held + contact))
        moving, speeds = (np.concatenate(a) if a else np.zeros(0) for a in (moving, speeds))
        moving, first = np.unique(moving, return_index=True)  # two moving sides meet: the first named
        speeds = speeds[first]
        sliding = ~np.isin(moving, at_rest)
        fixed = np.unique(np.concatenate(held))
        dofs = np.concatenate([fixed, moving[sliding]]).astype(np.int64)
        values = np.concatenate([np.zeros(len(fixed)), speeds[sliding]])
        order = np.argsort(dofs, kind="stable")
        return dofs[order], values[order]

    def impose(self, velocity: GridFunction, acceleration: GridFunction | None = None):
        """The walls' own motion on the held dofs of two-component grid functions: their velocity
        in ``velocity``, zero in ``acceleration`` (ghosts updated)."""
        velocity.array[self._vector_index] = self.values
        velocity.scatter_forward()
        if acceleration is not None:
            acceleration.array[self._vector_index] = 0.0
            acceleration.scatter_forward()

    def clear(self, flag: GridFunction):
        """Zero on the held dofs of a two-component grid function ``flag`` (ghosts updated)."""
        flag.array[self._vector_index] = 0.0
        flag.scatter_forward()

    def held_mask(self, vector_space: Space) -> np.ndarray:
        """Boolean ``(local functions, 2)``: the components held, owned and ghost, on a space of
        the same basis with one two-component field."""
        flag = GridFunction(vector_space, "held")
        flag.array[self._vector_index] = 1.0
        flag.scatter_forward()
        return flag.values > 0.5

    def keep_inside(self, x: np.ndarray) -> np.ndarray:
        """Positions ``x`` stopped at the impermeable sides (in place; returned); with ``recycle``, a particle that
        left through the left or right side brought in through the other.

        The interpolated displacement of a cell next to a wall cannot decelerate within the cell,
        so at large steps or hard impacts it may carry a particle a little past the wall: it is
        stopped there, and counted in :attr:`stops`. Outflow and open sides are no walls. An
        obstacle's faces are walls alike: a particle that crossed one into a blocked cell is put back
        on the nearest face of that cell with an open cell beyond it (:func:`_stop_at_obstacle_faces`).
        NaN stays NaN.
        """
        grid = self.space.grid
        if self.physics.recycle:
            width = grid.upper[0] - grid.lower[0]
            x[:, 0] = grid.lower[0] + np.mod(x[:, 0] - grid.lower[0], width)
        low, high = self._inside
        self.stops += _stop_outside(x, low, high)
        if self._obstacles:
            self.stops += _stop_at_obstacle_faces(x, grid.lower, grid.h, grid.nx, grid.ny, grid.blocked,
                                                  1e-9 * grid.h)
        return x


@numba.njit(cache=True)
def _all_kept(keep, bs, component):
    """Whether ``keep`` (boolean per owned dof, ``bs`` a function) holds for ``component`` of every function."""
    for i in range(component, keep.shape[0], bs):
        if not keep[i]:
            return False
    return True


@numba.njit(cache=True)
def _start_active(free_surface, keep, velocity, normal, normal_in_vector, sign, entering_speed, active, wet, entering,
                  let_go):
    """:meth:`Walls.start_step` on the contact dofs ``normal`` (in place): without a free surface all held; with one,
    those dry last step (not ``wet``) and those whose projected ``velocity`` (a two-component function's values,
    ``normal_in_vector``) enters the wall faster than ``entering_speed`` held too. Then ``wet`` from ``keep`` and
    no dof let go yet."""
    for i in range(normal.shape[0]):
        if not free_surface:
            active[i] = True
        else:
            entering[i] = velocity[normal_in_vector[i]] * sign[i] > entering_speed
            active[i] = active[i] or not wet[i] or entering[i]
        wet[i] = keep[normal[i]]
        let_go[i] = False


@numba.njit(cache=True)
def _settle(active, entering, let_go, reaction, displacement, normal, sign, strong_pull, motion):
    """:meth:`Walls.settle`'s changes, in place: an active contact dof not entering whose reaction pulls above
    ``strong_pull`` released (and let go), one let go in this step that moved into the wall beyond ``motion``
    held again; returns how many of each."""
    pulled = back = 0
    for i in range(normal.shape[0]):
        if active[i] and not entering[i] and reaction[i] * sign[i] > strong_pull:
            active[i], let_go[i] = False, True
            pulled += 1
        elif let_go[i] and not active[i] and displacement[normal[i]] * sign[i] > motion:
            active[i] = True
            back += 1
    return pulled, back


@numba.njit(cache=True)
def _update_active(active, reaction, displacement, normal, sign, force, motion):
    """:meth:`Walls.update`'s changes, in place: a held contact dof whose reaction pulls above ``force`` released, a
    free one that moved into the wall beyond ``motion`` held; returns how many were released."""
    released = 0
    for i in range(normal.shape[0]):
        if active[i]:
            if reaction[i] * sign[i] > force:
                active[i] = False
                released += 1
        elif displacement[normal[i]] * sign[i] > motion:
            active[i] = True
    return released


@numba.njit(cache=True)
def _released_and_dry(ids, active, wet):
    """The ``ids`` of the contact dofs not ``active`` and of those not ``wet``, in order."""
    return ids[~active], ids[~wet]


@numba.njit(cache=True)
def _held_positions(owned, fixed, normal, partner, active, bs, first):
    """The held dofs by position among the ``owned`` ones (increasing): the ``fixed`` ones, the ``active``
    contact dofs (``normal``) and their tangential ``partner`` (-1: none); and the same dofs in a two-component
    grid function, given the space's block size ``bs`` and the velocity's first component ``first``."""
    held = np.zeros(owned, dtype=np.bool_)
    for position in fixed:
        held[position] = True
    for i in range(normal.shape[0]):
        if active[i]:
            held[normal[i]] = True
            if partner[i] >= 0:
                held[partner[i]] = True
    positions = np.flatnonzero(held)
    return positions, positions // bs * 2 + positions % bs - first


@numba.njit(cache=True)
def _stop_at_obstacle_faces(x, lower, h, nx, ny, blocked, margin):
    """Points ``x`` ``(n, 2)`` in a ``blocked`` cell moved, in place, to ``margin`` beyond the nearest face of
    that cell that has an open cell of the grid beyond it; returns how many were moved. A point with no
    such face (deep in an obstacle) stays where it is, for relocation to report."""
    moved = 0
    for p in range(x.shape[0]):
        s0, s1 = (x[p, 0] - lower[0]) / h, (x[p, 1] - lower[1]) / h
        if not (np.isfinite(s0) and np.isfinite(s1)):
            continue
        i, j = min(max(int(np.floor(s0)), 0), nx - 1), min(max(int(np.floor(s1)), 0), ny - 1)
        if not blocked[i + nx * j]:
            continue
        best, axis, target = np.inf, -1, 0.0
        for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            a, b = i + di, j + dj
            if a < 0 or a >= nx or b < 0 or b >= ny or blocked[a + nx * b]:
                continue
            if di != 0:  # the left or right face: the coordinate x
                face = lower[0] + h * (i + (di > 0))
                distance, beyond, k = abs(x[p, 0] - face), face + di * margin, 0
            else:
                face = lower[1] + h * (j + (dj > 0))
                distance, beyond, k = abs(x[p, 1] - face), face + dj * margin, 1
            if distance < best:
                best, axis, target = distance, k, beyond
        if axis >= 0:
            x[p, axis] = target
            moved += 1
    return moved


@numba.njit(cache=True)
def _stop_outside(x, low, high):
    """The points ``x`` ``(n, 2)`` below ``low`` or above ``high`` in a coordinate (NaN is neither) moved there, in
    place (as ``np.clip``); returns how many."""
    count = 0
    for p in range(x.shape[0]):
        outside = False
        for d in range(2):
            if x[p, d] < low[d]:
                x[p, d], outside = low[d], True
            elif x[p, d] > high[d]:
                x[p, d], outside = high[d], True
        count += outside
    return count


class FreeDofs:
    """The owned dofs an implicit step solves for.

    Those the step keeps (functions carrying material), less the held walls; in a closed box whose
    pressure nothing fixes (no side outflow or open, no pressure held at zero) also less the
    pressure of the lower-left function, pinned at zero (p is defined up to a constant).

    Attributes:
        mask: after :meth:`select`, boolean per owned dof: free.
    """

    def __init__(self, space: Space, walls: Walls):
        self.space, self.walls = space, walls
        self._pressure = space.field_offset("p")
        corner = space.numbering.local_index[0]  # the lower-left function
        owns_corner = 0 <= corner < space.numbering.num_owned
        self._pin = corner * space.bs + self._pressure if owns_corner else None
        self._closed = walls.physics.closed
        self._owned = space.local_to_global[: space.num_owned_dofs].astype(PETSc.IntType)  # as PETSc numbers dofs
        self.mask = np.ones(space.num_owned_dofs, dtype=bool)

    def select(self, keep: np.ndarray) -> np.ndarray:
        """Global numbers of the free dofs, given ``keep`` (boolean per owned dof; changed in place)."""
        pressure_held = _hold(keep, self.walls.positions, self.space.bs, self._pressure)
        if self._closed and collective.total(self.space.comm, pressure_held) == 0 and self._pin is not None:
            keep[self._pin] = False
        self.mask = keep
        return self._owned[keep]


@numba.njit(cache=True)
def _hold(keep, positions, bs, component):
    """``keep`` false at ``positions`` (in place); returns at how many functions (``bs`` dofs each) ``keep`` is false
    for ``component``."""
    for i in positions:
        keep[i] = False
    held = 0
    for i in range(component, keep.shape[0], bs):
        held += not keep[i]
    return held
