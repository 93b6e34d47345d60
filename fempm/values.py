"""Checks of scene values: each converts a TOML value or says what is allowed.

A scene key is declared with :func:`key` (its check, default and unit); a check raises
:class:`BadValue` with the allowed values, and :mod:`fempm.scene` adds the key's name.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import field

from fempm.expressions import ALLOWED, BadExpression, Expression

__all__ = ["BadValue", "REQUIRED", "boolean", "cell_count_pair", "cell_list", "choice", "finite", "folder_name", "forms_name",
           "fraction", "in_range", "key", "non_negative", "petsc_table", "point", "points", "positive", "range_pair",
           "square_count", "text", "times", "velocity"]

REQUIRED = object()


class BadValue(ValueError):
    """A value's problem; the caller adds the key."""


def _number(value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BadValue(f"must be a number, got {type(value).__name__} {value!r}")
    return float(value)


def finite(value) -> float:
    """A finite number."""
    x = _number(value)
    if not math.isfinite(x):
        raise BadValue(f"must be a finite number, got {value!r}")
    return x


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


def in_range(low: float, high: float, low_open: bool = True, high_open: bool = False):
    """A finite number between ``low`` and ``high`` (each end open or closed)."""
    brackets = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"

    def check(value) -> float:
        x = _number(value)
        above = x > low if low_open else x >= low
        below = x < high if high_open else x <= high
        if not (math.isfinite(x) and above and below):
            raise BadValue(f"must be a number in {brackets}, got {value!r}")
        return x
    check.__doc__ = f"A number in {brackets}."
    return check


def range_pair(value) -> tuple[float, float]:
    """A pair of finite numbers ``[low, high]`` with ``low < high``."""
    low, high = point(value)
    if not low < high:
        raise BadValue(f"must be [low, high] with low < high, got {value!r}")
    return low, high


def velocity(value) -> tuple[float | str, float | str]:
    """A pair ``[vx, vy]``, each a number or an expression in x and y (m/s), e.g. ``["-100*y", "100*x"]``."""
    if not isinstance(value, list) or len(value) != 2:
        raise BadValue(f"must be a pair [vx, vy] of numbers or expressions in x and y, got {value!r}")
    out = []
    for k, v in enumerate(value):
        if isinstance(v, str):
            try:
                Expression(v)
            except BadExpression as e:
                raise BadValue(f"component {k} {e}") from None
            out.append(v)
        else:
            x = _number(v)
            if not math.isfinite(x):
                raise BadValue(f"must be finite numbers or expressions ({ALLOWED}), got {value!r}")
            out.append(x)
    return tuple(out)


def folder_name(value) -> str:
    """A folder name: a non-empty string without NUL, each part at most 255 bytes."""
    name = text(value)
    if "\0" in name:
        raise BadValue(f"must not contain a NUL character, got {value!r}")
    longest = max((len(os.fsencode(part)) for part in re.split(r"[/\\]", name)), default=0)
    if longest > 255 or len(os.fsencode(name)) > 4095:
        raise BadValue(f"a name of {len(name)} characters is too long for the file system (a part of {longest} "
                       f"bytes; at most 255 per part and 4095 in all)")
    return name


def forms_name(value) -> str:
    """The bare name of a shipped forms file (``incompressible``): a scene names no file of its own."""
    name = text(value)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise BadValue(f"must be the bare name of a shipped forms file (e.g. 'incompressible'), got {value!r}: "
                       f"a forms file is Python code that runs, so a scene cannot name one by path; give your "
                       f"own file on the command line with --forms PATH")
    return name


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
