"""The sides of the grid and the obstacles as constraints on a step: held dofs, and positions kept inside.

Both bases interpolate at the sides, so holding a function's coefficient holds the field's value
on the side. :class:`Walls` lists the held velocity dofs of a space (a side's normal component
for ``slip``, both for ``no-slip``, the tangential one for ``outflow``, none for ``open``; both
on every function non-zero in an obstacle cell) and the value held on each (zero, or a moving
wall's speed); it also stops particles at the impermeable sides. :class:`FreeDofs` picks the dofs
an implicit step solves for.
"""

from __future__ import annotations

import numpy as np

from fempm.options import Physics
from fempm.space import GridFunction, Space

__all__ = ["FreeDofs", "Walls"]

_COMPONENTS = {"slip": "normal", "no-slip": "both", "outflow": "tangential", "open": "none"}


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
        stops: particle displacements cut at an impermeable side so far (see :meth:`keep_inside`).
    """

    def __init__(self, space: Space, physics: Physics, field: str = "u"):
        self.space, self.physics, self.field = space, physics, field
        self.conditions = physics.wall_conditions()
        self.dofs, self.values = self._held()
        owned = space.local_to_global[: space.num_owned_dofs]
        self.positions = np.searchsorted(owned, self.dofs)
        bs, first = space.bs, space.field_offset(field)
        # the same dofs in a two-component grid function (a velocity or an acceleration)
        self._vector_index = self.positions // bs * 2 + self.positions % bs - first
        self.stops = 0

    def _held(self) -> tuple[np.ndarray, np.ndarray]:
        space, grid = self.space, self.space.grid
        held = [space.cell_dofs(self.field, np.flatnonzero(grid.blocked))]
        moving, speeds = [], []
        for side, kind in self.conditions.items():
            normal = 0 if side in ("left", "right") else 1
            components = {"normal": (normal,), "both": (0, 1), "tangential": (1 - normal,), "none": ()}
            for component in components[_COMPONENTS[kind]]:
                dofs = space.wall_dofs(self.field, component, side[0])
                if component != normal and side in self.physics.wall_speeds:
                    moving.append(dofs)
                    speeds.append(np.full(len(dofs), float(self.physics.wall_speeds[side])))
                else:
                    held.append(dofs)
        at_rest = np.unique(np.concatenate(held))
        moving, speeds = (np.concatenate(a) if a else np.zeros(0) for a in (moving, speeds))
        moving, first = np.unique(moving, return_index=True)  # two moving sides meet: the first named
        speeds = speeds[first]
        sliding = ~np.isin(moving, at_rest)
        dofs = np.concatenate([at_rest, moving[sliding]]).astype(np.int64)
        values = np.concatenate([np.zeros(len(at_rest)), speeds[sliding]])
        order = np.argsort(dofs, kind="stable")
        return dofs[order], values[order]

    def impose(self, velocity: GridFunction, acceleration: GridFunction | None = None):
        """The walls' own motion on the held dofs of two-component grid functions: their velocity
        in ``velocity``, zero in ``acceleration`` (ghosts updated)."""
        velocity.vector.array[self._vector_index] = self.values
        velocity.scatter_forward()
        if acceleration is not None:
            acceleration.vector.array[self._vector_index] = 0.0
            acceleration.scatter_forward()

    def held_mask(self, vector_space: Space) -> np.ndarray:
        """Boolean ``(local functions, 2)``: the components held, owned and ghost, on a space of
        the same basis with one two-component field."""
        flag = GridFunction(vector_space, "held")
        flag.vector.array[self._vector_index] = 1.0
        flag.scatter_forward()
        return flag.values > 0.5

    def keep_inside(self, x: np.ndarray) -> np.ndarray:
        """Positions ``x`` stopped at the impermeable sides; with ``recycle``, a particle that left
        through the left or right side brought in through the other.

        The interpolated displacement of a cell next to a wall cannot decelerate within the cell,
        so at large steps or hard impacts it may carry a particle a little past the wall: it is
        stopped there, and counted in :attr:`stops`. Outflow and open sides are no walls. NaN stays NaN.
        """
        grid = self.space.grid
        if self.physics.recycle:
            width = grid.upper[0] - grid.lower[0]
            x[:, 0] = grid.lower[0] + np.mod(x[:, 0] - grid.lower[0], width)
        margin = 1e-9 * grid.h
        impermeable = {side: kind in ("slip", "no-slip") for side, kind in self.conditions.items()}
        low = np.where([impermeable["left"], impermeable["bottom"]], grid.lower + margin, -np.inf)
        high = np.where([impermeable["right"], impermeable["top"]], grid.upper - margin, np.inf)
        outside = np.any((x < low) | (x > high), axis=1)
        if np.any(outside):
            self.stops += int(outside.sum())
            x = np.clip(x, low, high)
        return x


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
        self.mask = np.ones(space.num_owned_dofs, dtype=bool)

    def select(self, keep: np.ndarray) -> np.ndarray:
        """Global numbers of the free dofs, given ``keep`` (boolean per owned dof; changed in place)."""
        keep[self.walls.positions] = False
        if self.walls.physics.closed:
            pressure_held = np.count_nonzero(~keep.reshape(-1, self.space.bs)[:, self._pressure])
            if self.space.comm.allreduce(pressure_held) == 0 and self._pin is not None:
                keep[self._pin] = False
        self.mask = keep
        return self.space.local_to_global[: self.space.num_owned_dofs][keep]
