"""Scenes: a study written once as a TOML file, validated whole before anything runs.

A scene names the tank (``[domain]``), the water (``[fluid]``, ``[[bodies]]``), rigid
``[[obstacles]]``, the ``[walls]``, ``gravity``, the ``[time]`` span, the ``[solver]``
and the ``[output]`` (see the README for a complete example). :func:`load_scene`
reads and checks a file into a frozen :class:`Scene`; every mistake raises one
:class:`~fempm.errors.InputError` naming the key and what it accepts. :func:`to_toml`
writes a scene back, with every default filled in (``fempm check`` prints it, a
checkpoint stores it).

Checks that need geometry are done here too, by arithmetic on the structured grid
(no mesh is built): bodies and obstacles inside the domain, bodies at least two
cells across and seeding at least one particle, bodies clear of obstacle cells,
obstacles covering at least one cell centre.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import MISSING, asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np

from fempm.errors import InputError
from fempm.formsfile import FORMS_DIR
from fempm.grid import cell_counts, square_cell_size
from fempm.options import Scheme
from fempm.particles import Polygon, Rectangle, sub_cell_centres
from fempm.values import (BadValue, boolean, cell_count_pair, cell_list, choice, fraction, key, non_negative,
                          petsc_table, point, points, positive, square_count, text, times)

__all__ = ["Body", "Domain", "Fluid", "Obstacle", "Output", "Scene", "Solver", "Time", "Walls",
           "load_scene", "parse_scene", "scene_from_text", "to_toml"]

# -- the sections ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Domain:
    """The tank: a rectangle cut into square cells, given by ``cells`` or by ``cell_size``."""

    lower: tuple[float, float] = key(point, unit="m")
    upper: tuple[float, float] = key(point, unit="m")
    cells: tuple[int, int] | None = key(cell_count_pair, None)
    cell_size: float | None = key(positive, None, unit="m")

    @property
    def h(self) -> float:
        """The cell size."""
        return square_cell_size(self.lower, self.upper, self.cells) if self.cells else self.cell_size

    @property
    def shape(self) -> tuple[int, int]:
        """Cells per direction."""
        return tuple(self.cells) if self.cells else cell_counts(self.lower, self.upper, self.cell_size)


@dataclass(frozen=True)
class Fluid:
    """The fluid's properties (SI units)."""

    density: float = key(positive, 1000.0, unit="kg/m^3")
    viscosity: float = key(non_negative, 1.0e-3, unit="Pa s")


class _Shaped:
    """A body or obstacle drawn as a rectangle (``lower``, ``upper``) or a polygon (``vertices``)."""

    def geometry(self) -> Rectangle | Polygon:
        """The shape as a :class:`~fempm.Rectangle` or :class:`~fempm.Polygon`."""
        return Rectangle(self.lower, self.upper) if self.shape == "rectangle" else Polygon(self.vertices)


@dataclass(frozen=True)
class Body(_Shaped):
    """A region filled with fluid at the start: a rectangle or a polygon."""

    shape: str = key(choice("rectangle", "polygon"))
    lower: tuple[float, float] | None = key(point, None, unit="m")
    upper: tuple[float, float] | None = key(point, None, unit="m")
    vertices: tuple[tuple[float, float], ...] | None = key(points, None, unit="m")
    particles_per_cell: int = key(square_count, 4)
    velocity: tuple[float, float] = key(point, (0.0, 0.0), unit="m/s")


@dataclass(frozen=True)
class Obstacle(_Shaped):
    """A rigid obstacle: the cells whose centres lie in a rectangle or polygon, or listed cells."""

    shape: str = key(choice("rectangle", "polygon", "cells"))
    lower: tuple[float, float] | None = key(point, None, unit="m")
    upper: tuple[float, float] | None = key(point, None, unit="m")
    vertices: tuple[tuple[float, float], ...] | None = key(points, None, unit="m")
    cells: tuple[tuple[int, int], ...] | None = key(cell_list, None)

    def blocked_cells(self, domain: Domain) -> np.ndarray:
        """Structured indices of the cells this obstacle blocks."""
        nx, ny = domain.shape
        if self.shape == "cells":
            return np.array([i + nx * j for i, j in self.cells], dtype=np.int64)
        all_cells = np.arange(nx * ny)
        centres = np.asarray(domain.lower) + domain.h * (np.stack([all_cells % nx, all_cells // nx], -1) + 0.5)
        return all_cells[self.geometry().contains(centres)]


_WALL = choice("slip", "no-slip")


@dataclass(frozen=True)
class Walls:
    """The condition on each side of the tank: ``slip`` (zero normal velocity) or ``no-slip``."""

    left: str = key(_WALL, "slip")
    right: str = key(_WALL, "slip")
    bottom: str = key(_WALL, "slip")
    top: str = key(_WALL, "slip")


@dataclass(frozen=True)
class Time:
    """The simulated span and the time step."""

    end: float = key(positive, unit="s")
    dt: float = key(positive, unit="s")

    @property
    def steps(self) -> int:
        """Steps from 0 to ``end``."""
        return round(self.end / self.dt)


@dataclass(frozen=True)
class Solver:
    """Discretisation and solver options (see :class:`fempm.options.Scheme`)."""

    basis: str = key(choice("bspline", "q1"), "bspline")
    linear: str = key(choice("direct", "iterative"), "direct")
    pspg: bool = key(boolean, True)
    volume_correction: float = key(fraction, Scheme.alpha)
    pic_blend: float = key(fraction, Scheme.pic_blend)
    newmark_beta: float = key(positive, Scheme.beta)
    newmark_gamma: float = key(positive, Scheme.gamma)
    forms: str = key(text, "incompressible")
    petsc: dict = key(petsc_table, {})


@dataclass(frozen=True)
class Output:
    """What a run writes, and how often (intervals in simulated seconds; absent: not written)."""

    folder: str = key(text)
    progress: bool = key(boolean, True)
    particles_interval: float | None = key(positive, None, unit="s")
    grid_interval: float | None = key(positive, None, unit="s")
    snapshots: tuple[float, ...] = key(times, (), unit="s")
    final_snapshot: bool = key(boolean, False)
    pressure_scale: tuple[float, float] | None = key(point, None, unit="Pa")
    checkpoint_interval: float | None = key(positive, None, unit="s")


@dataclass(frozen=True)
class Scene:
    """A whole study; build it with :func:`load_scene` or :func:`parse_scene`."""

    name: str
    gravity: tuple[float, float]
    domain: Domain
    fluid: Fluid
    bodies: tuple[Body, ...]
    obstacles: tuple[Obstacle, ...]
    walls: Walls
    time: Time
    solver: Solver
    output: Output

    def blocked_cells(self) -> np.ndarray:
        """Structured indices of all obstacle cells."""
        cells = [o.blocked_cells(self.domain) for o in self.obstacles]
        return np.unique(np.concatenate(cells)) if cells else np.zeros(0, dtype=np.int64)


_TOP = {"name": text, "gravity": point}
_SECTIONS = {"domain": Domain, "fluid": Fluid, "walls": Walls, "time": Time, "solver": Solver, "output": Output}
_LISTS = {"bodies": Body, "obstacles": Obstacle}


# -- reading ------------------------------------------------------------------------------------------
def load_scene(path: str | Path, folder: str | Path | None = None, end_time: float | None = None) -> Scene:
    """Read and check the scene file ``path``; ``folder`` and ``end_time`` override
    ``output.folder`` and ``time.end``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"scene file {str(path)!r} does not exist" if not path.exists()
                         else f"scene file {str(path)!r} is not a file")
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    return scene_from_text(text, path, folder, end_time)


def scene_from_text(text: str, source: str | Path, folder: str | Path | None = None,
                    end_time: float | None = None) -> Scene:
    """Check a scene given as TOML text (see :func:`load_scene`)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{source}: not valid TOML: {e}") from None
    if folder is not None:
        data.setdefault("output", {})["folder"] = str(folder)
    if end_time is not None:
        data.setdefault("time", {})["end"] = end_time
    return parse_scene(data, source=source)


def parse_scene(data: dict, source: str | Path = "scene") -> Scene:
    """Check a scene given as the dictionary of its TOML file and resolve its defaults.

    Relative ``solver.forms`` files are taken from the folder of ``source``.

    Raises:
        InputError: the first mistake, as ``source: key = value: what is allowed``.
    """
    source = Path(source)
    try:
        scene = _parse(data, source)
        _check_geometry(scene)
        _check_times(scene)
    except InputError as e:
        raise InputError(f"{source}: {e}") from None
    return scene


def _parse(data: dict, source: Path) -> Scene:
    _unknown(data, [*_TOP, *_SECTIONS, *_LISTS], "the scene")
    values = {}
    for name, check in _TOP.items():
        values[name] = _value(check, data.get(name, None), name)
    values["name"] = values["name"] or source.stem
    values["gravity"] = values["gravity"] or (0.0, -9.81)
    for name, cls in _SECTIONS.items():
        table = data.get(name, {})
        if not isinstance(table, dict):
            raise InputError(f"{name} must be a table [{name}], got {table!r}")
        if name == "output":
            table = {"folder": f"results/{values['name'].replace(' ', '_')}", **table}
        values[name] = _section(cls, table, name)
    for name, cls in _LISTS.items():
        tables = data.get(name, [])
        if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
            raise InputError(f"{name} must be an array of tables [[{name}]], got {tables!r}")
        values[name] = tuple(_section(cls, t, f"{name}[{k}]") for k, t in enumerate(tables))
    if not values["bodies"]:
        raise InputError("the scene has no fluid: add at least one [[bodies]] table")
    solver = values["solver"]
    if solver.forms.endswith(".py") and not Path(solver.forms).is_absolute():
        solver = replace(solver, forms=str((source.parent / solver.forms).resolve()))
        values["solver"] = solver
    forms = Path(solver.forms) if solver.forms.endswith(".py") else FORMS_DIR / f"{solver.forms}.py"
    if not forms.is_file():
        raise InputError(f"solver.forms = {solver.forms!r}: no such forms file ({forms}); give a bare name "
                         f"of forms/ (e.g. 'incompressible') or a path ending in .py")
    folder = Path(values["output"].folder)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"output.folder = {str(folder)!r}: exists and is not a folder; name a folder")
    return Scene(**values)


def _unknown(table: dict, allowed, where: str):
    for key in table:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise InputError(f"unknown key {key!r} in {where}{hint}; allowed: {', '.join(allowed)}")


def _value(check, value, where: str, unit: str = ""):
    if value is None:
        return None
    try:
        return check(value)
    except BadValue as e:
        raise InputError(f"{where}: {e}{f' ({unit})' if unit else ''}") from None


def _section(cls, table: dict, where: str):
    keys = [f.name for f in fields(cls)]
    _unknown(table, keys, f"[{where}]")
    values = {}
    for f in fields(cls):
        if f.name not in table:
            if f.metadata["required"]:
                wanted = f.metadata["check"].__doc__.rstrip(".").replace("``", "")
                raise InputError(f"{where}.{f.name} is missing: give {wanted[0].lower()}{wanted[1:]}"
                                 + (f" ({f.metadata['unit']})" if f.metadata["unit"] else ""))
            values[f.name] = f.default_factory() if f.default is MISSING else f.default
        else:
            values[f.name] = _value(f.metadata["check"], table[f.name], f"{where}.{f.name}", f.metadata["unit"])
    item = cls(**values)
    if isinstance(item, _Shaped):
        _check_shape_keys(item, table, where)
    return item


_SHAPE_KEYS = {"rectangle": ("lower", "upper"), "polygon": ("vertices",), "cells": ("cells",)}


def _check_shape_keys(item: _Shaped, table: dict, where: str):
    """A body or obstacle has exactly the keys its shape needs, and they make a shape."""
    needed = _SHAPE_KEYS[item.shape]
    for other in {k for ks in _SHAPE_KEYS.values() for k in ks} - set(needed):
        if other in table:
            raise InputError(f"{where}.{other}: a {item.shape} takes {' and '.join(needed)}, not {other}")
    for key in needed:
        if key not in table:
            raise InputError(f"{where}.{key} is missing: a {item.shape} needs {' and '.join(needed)}")
    if item.shape != "cells":
        try:
            item.geometry()
        except InputError as e:
            raise InputError(f"{where}: {e}") from None


# -- checks of the whole ---------------------------------------------------------------------------
def _check_geometry(scene: Scene):
    d = scene.domain
    if (d.cells is None) == (d.cell_size is None):
        raise InputError("domain: give exactly one of cells = [nx, ny] and cell_size = h")
    try:
        nx, ny = d.shape
        h = d.h
    except InputError as e:
        raise InputError(f"domain.{'cells' if d.cells else 'cell_size'}: {e}") from None
    owner = _check_obstacles(scene, nx, ny, h)
    _check_bodies(scene, owner, nx, h)


def _check_obstacles(scene: Scene, nx: int, ny: int, h: float) -> np.ndarray:
    """Obstacles inside the grid, each blocking a cell; returns the obstacle of each cell (-1: none)."""
    d = scene.domain
    lower, upper, tol = np.asarray(d.lower), np.asarray(d.upper), 1e-9 * h
    owner = np.full(nx * ny, -1)
    for k, obstacle in enumerate(scene.obstacles):
        where = f"obstacles[{k}]"
        if obstacle.shape == "cells":
            bad = [c for c in obstacle.cells if not (c[0] < nx and c[1] < ny)]
            if bad:
                raise InputError(f"{where}.cells: cell {list(bad[0])} is outside the grid of {nx} x {ny} cells "
                                 f"(columns 0..{nx - 1}, rows 0..{ny - 1})")
        else:
            _inside_domain(obstacle, lower, upper, tol, where)
        cells = obstacle.blocked_cells(d)
        if len(cells) == 0:
            raise InputError(f"{where}: covers no cell centre: the grid (h = {h:g} m) is too coarse for it; "
                             f"refine domain.cells or domain.cell_size, or list its cells")
        owner[cells[owner[cells] < 0]] = k
    if np.all(owner >= 0):
        raise InputError("obstacles: they block every cell of the domain")
    return owner


def _check_bodies(scene: Scene, owner: np.ndarray, nx: int, h: float):
    """Bodies inside the domain, resolved by the grid, seeding particles, clear of obstacles."""
    d = scene.domain
    lower, upper, tol = np.asarray(d.lower), np.asarray(d.upper), 1e-9 * h
    earlier: list = []
    for k, body in enumerate(scene.bodies):
        where = f"bodies[{k}]"
        _inside_domain(body, lower, upper, tol, where)
        shape = body.geometry()
        lo, up = shape.bounds()
        if np.any(up - lo < 2 * h - tol):
            raise InputError(f"{where}: it is {up[0] - lo[0]:g} x {up[1] - lo[1]:g} m, less than two cells across "
                             f"(h = {h:g} m): the grid is too coarse for it; refine domain.cells or cell_size")
        x, cells = _seed_points(body, d, lo, up)
        inside = shape.contains(x)
        for other in earlier:
            inside &= ~other.contains(x)
        if not inside.any():
            raise InputError(f"{where}: seeds no particle (it lies within earlier bodies or between "
                             f"particle positions); the grid is too coarse for it")
        hit = inside & (owner[cells] >= 0)
        if hit.any():
            c = cells[np.flatnonzero(hit)[0]]
            raise InputError(f"{where} overlaps obstacles[{owner[c]}] (cell column {c % nx}, row {c // nx}); "
                             f"move the body or the obstacle")
        earlier.append(shape)


def _inside_domain(item: _Shaped, lower, upper, tol, where):
    lo, up = item.geometry().bounds()
    if np.any(lo < lower - tol) or np.any(up > upper + tol):
        raise InputError(f"{where}: its extent {lo.tolist()}..{up.tolist()} is not inside the domain "
                         f"{lower.tolist()}..{upper.tolist()}")


def _seed_points(body: Body, d: Domain, lo, up) -> tuple[np.ndarray, np.ndarray]:
    """The particle positions seeding would try in the cells under the body's box, and their cells."""
    nx, ny = d.shape
    first = np.clip(np.floor((lo - d.lower) / d.h).astype(int), 0, [nx - 1, ny - 1])
    last = np.clip(np.ceil((up - d.lower) / d.h).astype(int), 1, [nx, ny])
    i, j = np.meshgrid(np.arange(first[0], last[0]), np.arange(first[1], last[1]), indexing="xy")
    cells = (i + nx * j).ravel()
    origins = np.asarray(d.lower) + d.h * np.stack([cells % nx, cells // nx], -1)
    n = math.isqrt(body.particles_per_cell)
    return sub_cell_centres(origins, d.h, n), np.repeat(cells, n * n)


def _check_times(scene: Scene):
    t, o = scene.time, scene.output
    if t.dt > t.end:
        raise InputError(f"time.dt = {t.dt:g} exceeds time.end = {t.end:g}")
    if abs(t.steps * t.dt - t.end) > 1e-9 * t.end:
        raise InputError(f"time.end = {t.end:g} is not a whole number of steps of time.dt = {t.dt:g}")
    for name in ("particles_interval", "grid_interval", "checkpoint_interval"):
        value = getattr(o, name)
        if value is not None and value < t.dt * (1 - 1e-9):
            raise InputError(f"output.{name} = {value:g} is shorter than time.dt = {t.dt:g}: must be >= dt (s)")


# -- writing ---------------------------------------------------------------------------------------
def to_toml(scene: Scene) -> str:
    """The scene as TOML with every default filled in; :func:`parse_scene` reads it back unchanged."""
    data = _plain(asdict(scene))
    top = [f"{k} = {_toml_value(v)}" for k, v in data.items() if k in _TOP]
    parts = ["\n".join(top)]
    for name in ("domain", "fluid", "bodies", "obstacles", "walls", "time", "solver", "output"):
        items = data[name] if name in _LISTS else [data[name]]
        for item in items:
            header = f"[[{name}]]" if name in _LISTS else f"[{name}]"
            lines = [header] + [f"{k} = {_toml_value(v)}" for k, v in item.items() if not isinstance(v, dict)]
            for k, v in item.items():
                if isinstance(v, dict):
                    lines += [f"\n[{name}.{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
            parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


def _plain(value):
    """Tuples to lists and keys with value None left out (TOML has no null)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items() if v is not None}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, float):
        return "inf" if value == math.inf else repr(value)
    if isinstance(value, int):
        return str(value)
    return "[" + ", ".join(_toml_value(v) for v in value) + "]"
