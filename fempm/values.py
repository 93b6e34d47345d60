"""Checks of scene values: each converts a TOML value or says what is allowed.

A scene key is declared with :func:`key` (its check, default and unit); a check raises
:class:`BadValue` with the allowed values, and :mod:`fempm.scene` adds the key's name.
"""

from __future__ import annotations

import math
from dataclasses import field

__all__ = ["BadValue", "REQUIRED", "boolean", "cell_count_pair", "cell_list", "choice", "fraction", "key",
           "non_negative", "petsc_table", "point", "points", "positive", "square_count",
           "text", "times"]

REQUIRED = object()


class BadValue(ValueError):
    """A value's problem; the caller adds the key."""


def _number(value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BadValue(f"must be a number, got {type(value).__name__} {value!r}")
    return float(value)


def positive(value) -> float:
    """A finite number > 0."""
    x = _number(value)
    if not (math.isfinite(x) and x > 0):
        raise BadValue(f"must be a number > 0, got {value!r}")
    return x


def non_negative(value) -> float:
    """A finite number >= 0."""
    x = _number(value)
    if not (math.isfinite(x) and x >= 0):
        raise BadValue(f"must be a number >= 0, got {value!r}")
    return x


def fraction(value) -> float:
    """A number in [0, 1]."""
    x = _number(value)
    if not 0 <= x <= 1:
        raise BadValue(f"must be a number in [0, 1], got {value!r}")
    return x


def boolean(value) -> bool:
    """``true`` or ``false``."""
    if not isinstance(value, bool):
        raise BadValue(f"must be true or false, got {value!r}")
    return value


def text(value) -> str:
    """A non-empty string."""
    if not isinstance(value, str) or not value:
        raise BadValue(f"must be a non-empty string, got {value!r}")
    return value


def choice(*allowed: str):
    """One of the given strings."""
    def check(value) -> str:
        """One of the allowed strings."""
        if value not in allowed:
            raise BadValue(f"must be one of {', '.join(repr(a) for a in allowed)}, got {value!r}")
        return value
    check.__doc__ = f"One of {', '.join(repr(a) for a in allowed)}."
    return check


def point(value) -> tuple[float, float]:
    """A pair of finite numbers ``[x, y]``."""
    if not isinstance(value, list) or len(value) != 2:
        raise BadValue(f"must be a pair of numbers [x, y], got {value!r}")
    x = tuple(_number(v) for v in value)
    if not all(math.isfinite(v) for v in x):
        raise BadValue(f"must be a pair of finite numbers, got {value!r}")
    return x


def points(value) -> tuple[tuple[float, float], ...]:
    """A list of at least three points ``[[x, y], ...]``."""
    if not isinstance(value, list) or len(value) < 3:
        raise BadValue(f"must be a list of at least three points [[x, y], ...], got {value!r}")
    return tuple(point(v) for v in value)


def cell_count_pair(value) -> tuple[int, int]:
    """A pair of whole numbers >= 1 ``[nx, ny]``."""
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value)):
        raise BadValue(f"must be a pair of whole numbers >= 1 [nx, ny], got {value!r}")
    return tuple(value)


def cell_list(value) -> tuple[tuple[int, int], ...]:
    """A non-empty list of cells ``[[column, row], ...]`` (whole numbers from 0)."""
    if (not isinstance(value, list) or not value
            or not all(isinstance(c, list) and len(c) == 2
                       and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in c)
                       for c in value)):
        raise BadValue(f"must be a non-empty list of cells [[column, row], ...] (whole numbers >= 0), got {value!r}")
    return tuple(tuple(c) for c in value)


def square_count(value) -> int:
    """A perfect square >= 1 (1, 4, 9, ...): particles per cell on an n x n lattice."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1 or math.isqrt(value) ** 2 != value:
        raise BadValue(f"must be a square number 1, 4, 9, 16, ... (n x n particles per cell), got {value!r}")
    return value


def times(value) -> tuple[float, ...]:
    """A list of times >= 0."""
    if not isinstance(value, list):
        raise BadValue(f"must be a list of times in seconds, got {value!r}")
    return tuple(non_negative(v) for v in value)


def petsc_table(value) -> dict[str, str]:
    """A table of PETSc option names (without ``-`` and prefix) to strings, numbers or booleans."""
    if not isinstance(value, dict):
        raise BadValue(f"must be a table of PETSc options, e.g. {{ ksp_rtol = 1e-8 }}, got {value!r}")
    out = {}
    for name, v in value.items():
        if isinstance(v, dict | list):
            raise BadValue(f"option {name!r} must have a string, number or boolean value, got {v!r}")
        out[name.lstrip("-")] = str(v).lower() if isinstance(v, bool) else str(v)
    return out


def key(check, default=REQUIRED, unit: str = ""):
    """A scene key: its check, its default (none: required) and its unit (for messages)."""
    metadata = {"check": check, "required": default is REQUIRED, "unit": unit}
    if isinstance(default, dict):
        return field(default_factory=dict, metadata=metadata)
    return field(default=None if default is REQUIRED else default, metadata=metadata)
