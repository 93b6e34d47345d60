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
obstacles covering at least one cell centre. Before any of them, :func:`estimate`
sizes the run from the scene alone (cells, unknowns, matrix entries, particles, steps),
so a scene too large for the machine is refused before anything is allocated.
Checking touches nothing on disk: the output folder is only examined, and a scene names
its forms by the bare name of a shipped file (a file of one's own is code, and is given
explicitly, ``forms=``).
"""

from __future__ import annotations

import difflib
import math
import os
import re
import tomllib
from dataclasses import MISSING, asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from fempm.errors import InputError
from fempm.expressions import Expression
from fempm.formsfile import forms_path, shipped_forms
from fempm.grid import cell_counts, cell_shares, last_widths, square_cell_size, touches_only
from fempm.linear import LARGE_SYSTEM
from fempm.options import FLUID_REGION_CELLS, PRESSURE_QUADRATURES, PRESSURE_WORKS, TRANSFERS, Scheme
from fempm.particles import Polygon, Rectangle, sub_cell_centres
from fempm.values import (BadValue, boolean, cell_count_pair, cell_list, choice, finite, folder_name, forms_name,
                          fraction, in_range, key, non_negative, petsc_table, point, points, positive, range_pair,
                          square_count, text, times, velocity)

__all__ = ["Body", "Domain", "Estimate", "Fluid", "Gauge", "MAX_STEPS", "Obstacle", "Output", "Scene", "Solver", "Time",
           "Walls", "available_memory", "describe_grid", "estimate", "load_scene", "parse_scene", "scene_from_text",
           "seeded_bodies", "to_toml"]

MAX_STEPS = 10**8  #: more steps than this in one run are refused (a mistaken time.dt or time.end)

# -- the sections ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Domain:
    """The tank: a rectangle cut into square cells, given by ``cells`` or by ``cell_size``; where a side
    is not a whole number of cells, the last column or row is cut at the tank's face."""

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
        """Cells per direction (the last column and row may be cut, see :attr:`last`)."""
        return tuple(self.cells) if self.cells else cell_counts(self.lower, self.upper, self.cell_size)

    @property
    def last(self) -> tuple[float, float]:
        """The width of the last column and the height of the top row, in cells: in (0, 1], 1 uncut."""
        return last_widths(self.lower, self.upper, self.h)


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
    velocity: tuple[float | str, float | str] = key(velocity, (0.0, 0.0), unit="m/s")

    def velocity_at(self, x: np.ndarray) -> np.ndarray:
        """The initial velocity at the points ``x`` ``(n, 2)``: numbers, or expressions of x and y."""
        return np.column_stack([Expression(v)(x) if isinstance(v, str) else np.full(len(x), v)
                                for v in self.velocity])

    def initial_velocity(self):
        """What :meth:`fempm.Particles.seed` takes: the pair of numbers, or the field as a function."""
        return self.velocity_at if any(isinstance(v, str) for v in self.velocity) else self.velocity

    def asked_area(self) -> float:
        """The area of the body's shape (m^2)."""
        shape = self.geometry()
        return shape.area() if isinstance(shape, Polygon) else float(np.prod(np.subtract(self.upper, self.lower)))


@dataclass(frozen=True)
class Obstacle(_Shaped):
    """A rigid obstacle: the cells whose centres lie in a rectangle or polygon (a cut cell's centre is
    that of its part inside the tank), or listed cells."""

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
        ij = np.stack([all_cells % nx, all_cells // nx], -1)  # a cut cell's centre is that of its part
        centres = np.asarray(domain.lower) + domain.h * (ij + 0.5 * cell_shares(all_cells, (nx, ny), domain.last))
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
    """The simulated span and the time step: fixed, or with ``courant`` adaptive (``dt`` its bound)."""

    end: float = key(positive, unit="s")
    dt: float = key(positive, unit="s")
    courant: float | None = key(in_range(0, 10), None)

    @property
    def steps(self) -> int:
        """Steps from 0 to ``end`` (with an adaptive step: the fewest)."""
        return round(self.end / self.dt)


@dataclass(frozen=True)
class Solver:
    """Discretisation and solver options (see :class:`fempm.options.Scheme`)."""

    basis: str = key(choice("bspline", "q1"), "bspline")
    linear: str = key(choice("direct", "iterative"), "direct")
    pspg: bool = key(boolean, True)
    volume_correction: float = key(fraction, Scheme.alpha)
    volume_correction_rate: float = key(positive, Scheme.alpha_rate, unit="1/s")
    transfer: str = key(choice(*TRANSFERS), Scheme.transfer)
    surface_aware: bool = key(boolean, Scheme.surface_aware)
    shifting: float = key(non_negative, Scheme.shifting)
    shifting_keeps_angular_momentum: bool = key(boolean, Scheme.shifting_keeps_angular_momentum)
    pic_blend: float = key(fraction, Scheme.pic_blend)
    pic_rate: float = key(non_negative, Scheme.pic_rate, unit="1/s")
    noise_rate: float = key(non_negative, Scheme.noise_rate, unit="1/s")
    rest_pic_rate: float = key(non_negative, Scheme.rest_pic_rate, unit="1/s")
    newmark_beta: float = key(in_range(0, 0.5), Scheme.beta)
    newmark_gamma: float = key(in_range(0, 1), Scheme.gamma)
    pressure_limit: float | None = key(positive, None, unit="Pa")
    forms: str = key(forms_name, "incompressible")
    pressure_quadrature: str = key(choice(*PRESSURE_QUADRATURES), Scheme.pressure_quadrature)
    pressure_work: str = key(choice(*PRESSURE_WORKS), Scheme.pressure_work)
    petsc: dict = key(petsc_table, {})


@dataclass(frozen=True)
class Output:
    """What a run writes, and how often (intervals in simulated seconds; absent: not written)."""

    folder: str = key(folder_name)
    progress: bool = key(boolean, True)
    particles_interval: float | None = key(positive, None, unit="s")
    grid_interval: float | None = key(positive, None, unit="s")
    snapshots: tuple[float, ...] = key(times, (), unit="s")
    final_snapshot: bool = key(boolean, False)
    pressure_scale: tuple[float, float] | None = key(range_pair, None, unit="Pa")
    checkpoint_interval: float | None = key(positive, None, unit="s")


@dataclass(frozen=True)
class Gauge:
    """A gauge (:mod:`fempm.gauges`): ``kind = "pressure"`` at a ``position`` (NaN while dry) or
    ``"level"``, the depth of water along the vertical line ``x``; sampled every ``interval``
    seconds (absent: every step) into ``gauges.csv``."""

    name: str = key(text)
    kind: str = key(choice("pressure", "level"))
    position: tuple[float, float] | None = key(point, None, unit="m")
    x: float | None = key(finite, None, unit="m")
    interval: float | None = key(positive, None, unit="s")

    def gauge(self):
        """The :class:`fempm.gauges.PressureGauge` or :class:`~fempm.gauges.LevelGauge`."""
        from fempm.gauges import LevelGauge, PressureGauge

        return PressureGauge(self.name, self.position) if self.kind == "pressure" else LevelGauge(self.name, self.x)


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
    gauges: tuple[Gauge, ...] = ()
    notes: tuple[str, ...] = field(default=(), compare=False)  # what the reading changed, to tell the user

    def blocked_cells(self) -> np.ndarray:
        """Structured indices of all obstacle cells."""
        cells = [o.blocked_cells(self.domain) for o in self.obstacles]
        return np.unique(np.concatenate(cells)) if cells else np.zeros(0, dtype=np.int64)


_TOP = {"name": text, "gravity": point}
_SECTIONS = {"domain": Domain, "fluid": Fluid, "walls": Walls, "time": Time, "solver": Solver, "output": Output}
_LISTS = {"bodies": Body, "obstacles": Obstacle, "gauges": Gauge}


# -- reading ------------------------------------------------------------------------------------------
def load_scene(path: str | Path, folder: str | Path | None = None, end_time: float | None = None,
               forms: str | Path | None = None, max_memory: float | None = None, ranks: int = 1,
               available: float | None = None) -> Scene:
    """Read and check the scene file ``path``.

    Args:
        folder, end_time: override ``output.folder`` and ``time.end``. Snapshots after an
            ``end_time`` given here are left out, and a note in ``Scene.notes`` says so.
        forms: a forms file of the user's own (a path to a ``.py`` file: code that runs),
            used instead of ``solver.forms``.
        max_memory: refuse a scene whose estimated memory exceeds this (GB); default the
            memory available (see :func:`check_size`).
        ranks: the number of MPI ranks the run will use (for the memory estimate).
        available: the memory available (GB), read once for all ranks (see :func:`check_size`).
    """
    name = str(path)
    if "\0" in name:
        raise InputError(f"scene file {name!r}: a file name cannot hold a NUL character")
    path = Path(path)
    try:
        if not path.is_file():
            raise InputError(f"scene file {name!r} does not exist" if not path.exists()
                             else f"scene file {name!r} is not a file")
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    except OSError as e:
        raise InputError(f"scene file {name!r} cannot be read ({e.strerror})") from None
    return scene_from_text(text, path, folder, end_time, forms, max_memory, ranks, available)


def scene_from_text(text: str, source: str | Path, folder: str | Path | None = None,
                    end_time: float | None = None, forms: str | Path | None = None,
                    max_memory: float | None = None, ranks: int = 1, available: float | None = None) -> Scene:
    """Check a scene given as TOML text (see :func:`load_scene`)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{source}: not valid TOML: {e}") from None
    notes = []
    if folder is not None:
        data.setdefault("output", {})["folder"] = str(folder)
    if end_time is not None:
        data.setdefault("time", {})["end"] = end_time
        output = data.get("output", {})
        snapshots = output.get("snapshots") if isinstance(output, dict) else None
        if isinstance(snapshots, list) and all(isinstance(s, int | float) for s in snapshots):
            late = [s for s in snapshots if s > end_time * (1 + 1e-9)]
            if late:
                output["snapshots"] = [s for s in snapshots if s not in late]
                notes.append(f"the end time {end_time:g} s comes before output.snapshots "
                             f"{', '.join(f'{s:g}' for s in late)} s: not taken")
    scene = parse_scene(data, source=source, forms=forms, max_memory=max_memory, ranks=ranks, available=available)
    return replace(scene, notes=tuple(notes)) if notes else scene


def parse_scene(data: dict, source: str | Path = "scene", forms: str | Path | None = None,
                max_memory: float | None = None, ranks: int = 1, names: dict[str, str] | None = None,
                available: float | None = None) -> Scene:
    """Check a scene given as the dictionary of its TOML file and resolve its defaults.

    Args:
        forms: a forms file of the user's own, used instead of ``solver.forms`` (see :func:`load_scene`).
        max_memory, ranks, available: see :func:`load_scene`.
        names: what to call keys in messages, e.g. ``{"time.dt": "--dt"}`` when a program
            made the scene from its command line.

    Raises:
        InputError: the first mistake, as ``source: key = value: what is allowed``.
    """
    source = Path(source)
    try:
        scene = _parse(data, source, forms)
        check_size(scene, max_memory, ranks, available)
        _check_geometry(scene)
        _check_times(scene, fixed_step=scene.time.courant is None)
    except InputError as e:
        message = str(e)
        for name, flag in (names or {}).items():
            message = re.sub(rf"(?<![\w.]){re.escape(name)}(?![\w\[])", flag, message)
        raise InputError(f"{source}: {message}") from None
    return scene


def _parse(data: dict, source: Path, forms: str | Path | None) -> Scene:
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
        if name == "solver" and forms is not None:
            table = {k: v for k, v in table.items() if k != "forms"}  # the user's own file replaces it
        values[name] = _section(cls, table, name)
    for name, cls in _LISTS.items():
        tables = data.get(name, [])
        if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
            raise InputError(f"{name} must be an array of tables [[{name}]], got {tables!r}")
        values[name] = tuple(_section(cls, t, f"{name}[{k}]") for k, t in enumerate(tables))
    if not values["bodies"]:
        raise InputError("the scene has no fluid: add at least one [[bodies]] table")
    solver = values["solver"]
    if forms is not None:
        values["solver"] = replace(solver, forms=str(forms_path(forms, "--forms")))
    elif solver.forms not in shipped_forms():
        raise InputError(f"solver.forms = {solver.forms!r}: no shipped forms of that name; shipped: "
                         f"{', '.join(shipped_forms())} (a file of your own: --forms PATH)")
    elif solver.forms == "gauss_pressure" and solver.pressure_quadrature != "gauss":
        raise InputError("solver.forms = 'gauss_pressure' integrates the pressure's terms at Gauss points: set "
                         "solver.pressure_quadrature = 'gauss'")
    if solver.pressure_work != "divergence" and solver.pressure_quadrature == "gauss":
        raise InputError(f"solver.pressure_work = {solver.pressure_work!r} is a form of the particles' quadrature: with "
                         "solver.pressure_quadrature = 'gauss' the pressure's work is at the Gauss points already; "
                         "set solver.pressure_work = 'divergence' (the shipped dam break sets 'increment')")
    _check_folder(values["output"].folder)
    return Scene(**values)


def _check_folder(name: str):
    """The output folder can be made and written, judged without touching the disk."""
    path = Path(name)
    try:
        if path.exists() and not path.is_dir():
            raise InputError(f"output.folder = {name!r}: exists and is not a folder; name a folder")
        existing = path.absolute()
        while not existing.exists():
            existing = existing.parent
        if not existing.is_dir():
            raise InputError(f"output.folder = {name!r}: cannot be made: {str(existing)!r} is a file")
        if not os.access(existing, os.W_OK | os.X_OK):
            raise InputError(f"output.folder = {name!r}: cannot be written: {str(existing)!r} is not writable")
    except OSError as e:
        raise InputError(f"output.folder = {name!r}: cannot be used ({e.strerror})") from None


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
    if isinstance(item, Gauge):
        _check_gauge_keys(item, table, where)
    return item


def _check_gauge_keys(item: Gauge, table: dict, where: str):
    """A pressure gauge takes a position, a level gauge an x."""
    needed, other = ("position", "x") if item.kind == "pressure" else ("x", "position")
    if other in table:
        raise InputError(f"{where}.{other}: a {item.kind} gauge takes {needed}, not {other}")
    if needed not in table:
        raise InputError(f"{where}.{needed} is missing: a {item.kind} gauge needs "
                         + ("position = [x, y] (m)" if needed == "position" else "x, the line's abscissa (m)"))


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


# -- the grid: square cells from the tank's lower corner, the last column and row cut at its faces --------
def _grid_key(d: Domain) -> str:
    return "domain.cells" if d.cells else "domain.cell_size"


def _resolve_grid(d: Domain) -> tuple[int, int, float]:
    """``(nx, ny, h)`` of the domain, or a message saying what fits.

    The cells are squares of size ``h`` laid from the tank's lower corner, and the tank's faces
    are the walls; where a side is not a whole number of cells, its last column or row is cut
    at the face (:class:`fempm.grid.Grid`). With ``cells = [nx, ny]``, ``h = width / nx`` and
    ``ny`` must be the number of rows covering the height (the top row cut where the height is
    not a whole number of them); a cell larger than a side, or a cut thinner than
    :data:`fempm.grid.MIN_CUT` cells, is refused.
    """
    if (d.cells is None) == (d.cell_size is None):
        raise InputError("domain: give exactly one of cells = [nx, ny] and cell_size = h")
    size = np.subtract(d.upper, d.lower)
    if not np.all(np.isfinite(size)):
        raise InputError(f"domain: the tank {list(d.lower)}..{list(d.upper)} is larger than floating point holds")
    if np.any(size <= 0):
        raise InputError(f"domain.upper {list(d.upper)} must exceed domain.lower {list(d.lower)}")
    if d.cells:
        nx, ny = d.cells
        h = float(size[0] / nx)
        try:
            rows = cell_counts(d.lower, d.upper, h)[1] if h <= size[1] else 0
        except InputError as e:  # a top row cut too thin
            raise InputError(f"domain.cells = {list(d.cells)}: {str(e).removeprefix('grid: ')}") from None
        if rows != ny:
            cut = "" if abs(round(size[1] / h) * h - size[1]) <= 1e-9 * size[1] else ", the top one cut"
            covering = (f"the height {size[1]:g} m takes {rows} rows of them{cut}" if rows
                        else f"the height {size[1]:g} m is less than one of them")
            raise InputError(f"domain.cells = {list(d.cells)}: the cells are square, {size[0]:g} m / {nx} = {h:g} m, "
                             f"and {covering}, not {ny}: take cells = [{nx}, {max(rows, 1)}]"
                             + ("" if rows == 0 else f", or cell_size = {size[1] / ny:.6g} for {ny} whole rows"))
        return nx, ny, h
    h = d.cell_size
    counts = size / h
    if np.any(counts > 1e15):
        return int(min(counts[0], 2**62)), int(min(counts[1], 2**62)), h  # refused by the size estimate
    if np.any(h > size):
        k = int(np.argmax(h > size))
        raise InputError(f"domain.cell_size = {h:g}: larger than the tank's {('width', 'height')[k]} {size[k]:g} m; "
                         f"take at most {size.min():g} (m)")
    try:
        nx, ny = cell_counts(d.lower, d.upper, h)
    except InputError as e:  # a last column or row cut too thin
        raise InputError(f"domain.cell_size = {h:g}: {str(e).removeprefix('grid: ')}") from None
    return nx, ny, h


def describe_grid(nx: int, ny: int, h: float, last) -> str:
    """``"40 x 39 cells of h = 0.015 m, the last column cut to 0.014 m (0.933 h)"``: the grid and its cuts."""
    cuts = [f"the {what} cut to {r * h:.4g} m ({r:.3g} h)"
            for what, r in zip(("last column", "top row"), last) if r < 1]
    return f"{nx} x {ny} cells of h = {h:g} m" + (", " + " and ".join(cuts) if cuts else "")


# -- the size of a run, from the scene alone ---------------------------------------------------------------
@dataclass(frozen=True)
class Estimate:
    """What a scene asks of the machine, worked out before anything is allocated.

    ``memory_gb`` is the peak resident memory summed over the ranks at the start of the
    run (matrix on the water's cells where the grid is large, see ``matrix_region``);
    ``memory_full_gb`` the same with the matrix on the whole grid (the water spread over
    the tank). The coefficients were fitted to the peak memory of runs of the dam-break
    scene refined (see tests/test_faults.py).
    """

    cells: float
    functions: float
    unknowns: float
    particles: float
    matrix_entries: float
    matrix_entries_full: float
    steps: float
    ranks: int
    memory_gb: float
    memory_full_gb: float
    key: str  # the key that most of the memory comes from
    value: object

    def summary(self) -> str:
        """One line for ``fempm check``."""
        return (f"about {self.memory_gb:.2g} GB of memory at the start ({self.memory_full_gb:.2g} GB if the water "
                f"spreads over the whole tank): {self.cells:.3g} cells, {self.unknowns:.3g} unknowns, "
                f"{self.matrix_entries:.3g} matrix entries, {self.particles:.3g} particles, "
                f"{self.steps:.3g} steps, {self.ranks} rank(s)")


# Fitted (least squares of the relative error) to the peak resident memory of 11 runs of the dam-break
# scene refined (serial, B-spline, 40^2 to 640^2 cells, 800 to 2e5 particles, direct and iterative,
# no output files; see tests/test_faults.py).
_BASE = 0.25e9  # bytes per rank: Python, DOLFINx, PETSc, numba, the compiled forms
_PER_CELL = 1.37e3  # the grid, its numbering and the matrix layout (whole grid, whatever the matrix region)
_PER_ENTRY = 11.5  # per matrix entry (value and column index)
_PER_PARTICLE = 2.14e3  # fields, tabulated basis jets, packed kernel data
_PER_FACTOR = 316.0  # MUMPS: per unit of n log2(n), n the free unknowns (nested-dissection fill)


def estimate(scene: Scene, ranks: int = 1) -> Estimate:
    """The size of the run of ``scene`` on ``ranks`` ranks (see :class:`Estimate`); nothing is allocated.

    Water cells are the cells under each body's box; the free unknowns three per function
    over them; the matrix has ``(2k + 1)^2`` functions of three unknowns per row (k the
    degree), on the whole grid, or above :data:`fempm.options.FLUID_REGION_CELLS` cells on
    the water's cells widened by the margin ``ImplicitSolver`` uses.
    """
    d = scene.domain
    nx, ny, h = _resolve_grid(d)
    k = 2 if scene.solver.basis == "bspline" else 1
    cells = float(nx) * float(ny)
    functions = (nx + k) * float(ny + k)
    bs = 3  # (du, p): two velocity components and the pressure
    per_row = (2 * k + 1) ** 2 * bs * bs  # entries per function (its bs rows)
    margin = max(2 * (k + 1), math.ceil(0.05 * max(nx, ny)))
    water, region, particles, most = 0.0, 0.0, 0.0, (-1.0, 0)
    for i, body in enumerate(scene.bodies):
        lo, up = (np.clip(b, d.lower, d.upper) for b in body.geometry().bounds())
        bx, by = (float(n) for n in np.maximum(np.ceil((up - lo) / h), 1))
        seeded = min(body.asked_area() / (h * h), bx * by) * body.particles_per_cell
        particles += seeded
        water += (bx + k) * (by + k)
        region += (bx + 2 * margin + k) * (by + 2 * margin + k)
        most = max(most, (seeded, i))
    water = min(water, functions)
    region = min(region, functions) if cells > FLUID_REGION_CELLS else functions
    free = bs * water
    # LU factors: direct on several ranks, or on one up to LARGE_SYSTEM (above it a multigrid cycle)
    factored = scene.solver.linear == "direct" and (ranks > 1 or free <= LARGE_SYSTEM)
    factor = _PER_FACTOR * free * math.log2(max(free, 2.0)) if factored else 0.0
    copies = ranks if scene.solver.linear == "direct" else 1  # on several ranks each factors a copy

    def total(rows):
        return (ranks * _BASE + _PER_CELL * cells + _PER_ENTRY * per_row * rows + _PER_PARTICLE * particles
                + copies * factor) / 1e9

    grid_part = _PER_CELL * cells + _PER_ENTRY * per_row * region + copies * factor
    if _PER_PARTICLE * most[0] > grid_part:
        key_name, value = f"bodies[{most[1]}].particles_per_cell", scene.bodies[most[1]].particles_per_cell
    else:
        key_name, value = _grid_key(d), (list(d.cells) if d.cells else d.cell_size)
    steps = scene.time.end / scene.time.dt
    return Estimate(cells, functions, bs * functions, particles, per_row * region, per_row * functions, steps,
                    ranks, total(region), total(functions), key_name, value)


def available_memory() -> float | None:
    """Memory available to a new process now (GB): ``MemAvailable`` of /proc/meminfo (None: unknown)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024 / 1e9
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_size(scene: Scene, max_memory: float | None = None, ranks: int = 1,
               available: float | None = None) -> Estimate:
    """Refuse a scene too large for the machine or with an absurd number of steps; returns the estimate.

    Args:
        max_memory: the limit in GB (``--max-memory``); default the memory available.
        available: the memory available (GB); default :func:`available_memory` now. A
            program on several ranks reads it once and passes it, so that all ranks agree.
    """
    t = scene.time
    steps = t.end / t.dt
    if not steps <= MAX_STEPS:
        raise InputError(f"time.end = {t.end:g} s in steps of time.dt = {t.dt:g} s is {steps:.3g} steps; at most "
                         f"{MAX_STEPS:.0e} in one run: check time.dt and time.end")
    e = estimate(scene, ranks)
    if max_memory is not None:
        limit, what = max_memory, "given by --max-memory"
    else:
        limit, what = (available if available is not None else available_memory()), "available"
    if limit is not None and e.memory_gb > limit:
        raise InputError(f"{e.key} = {e.value}: the run would need about {e.memory_gb:.3g} GB of memory "
                         f"({e.cells:.3g} cells, {e.matrix_entries:.3g} matrix entries, {e.particles:.3g} particles"
                         f"{f', {ranks} ranks' if ranks > 1 else ''}), more than the {limit:.3g} GB {what}; use "
                         f"fewer cells or particles, or set the limit with --max-memory GB")
    if e.unknowns >= 2**31 - 1:  # PETSc's indices here are 32-bit
        raise InputError(f"{e.key} = {e.value}: {e.unknowns:.3g} unknowns, more than PETSc's 32-bit indices "
                         f"address ({2**31 - 1}); use fewer cells")
    _check_magnitudes(scene)
    return e


def _check_magnitudes(scene: Scene):
    """Particle volumes, masses and the hydrostatic pressure are ordinary floating-point numbers."""
    d, fluid = scene.domain, scene.fluid
    _, _, h = _resolve_grid(d)
    height = d.upper[1] - d.lower[1]
    for body_index, body in enumerate(scene.bodies):
        volume = h * h / body.particles_per_cell
        if not 1e-300 < volume < math.inf:
            raise InputError(f"domain: the tank {list(d.lower)}..{list(d.upper)} in cells of {h:g} m gives particles "
                             f"of volume {volume:g} m^2 (bodies[{body_index}]), beyond floating point: give the tank "
                             f"in metres")
        if not 1e-300 < fluid.density * volume < math.inf:
            raise InputError(f"fluid.density = {fluid.density:g}: particles of {volume:g} m^2 would have a mass of "
                             f"{fluid.density * volume:g} kg, beyond floating point")
    if not fluid.density * float(np.hypot(*scene.gravity)) * height < 1e300:
        raise InputError(f"gravity = {list(scene.gravity)}: the hydrostatic pressure rho g H is beyond floating point")


# -- checks of the whole ---------------------------------------------------------------------------
def _check_geometry(scene: Scene):
    d = scene.domain
    nx, ny, h = _resolve_grid(d)
    try:
        same = (nx, ny) == tuple(d.shape) and math.isclose(h, d.h)
    except InputError as e:
        raise InputError(f"{_grid_key(d)}: {e}") from None
    if not same:  # the grid's own rule (fempm.grid) and the one above must agree
        raise InputError(f"{_grid_key(d)}: the grid would be {d.shape} cells of {d.h:g} m, not {nx} x {ny} of {h:g}")
    owner = _check_obstacles(scene, nx, ny, h)
    _check_bodies(scene, owner, nx, h)
    _check_gauges(scene, h, owner, nx, ny)


def _check_gauges(scene: Scene, h: float, owner: np.ndarray, nx: int, ny: int):
    """Gauges inside the domain, pressure gauges not inside an obstacle (``owner``: the obstacle of each
    cell, -1 for none), their names unique."""
    d, seen = scene.domain, {}
    lower, upper, tol = np.asarray(d.lower), np.asarray(d.upper), 1e-9 * h
    for k, g in enumerate(scene.gauges):
        where = f"gauges[{k}]"
        if g.name in seen:
            raise InputError(f"{where}.name = {g.name!r}: gauges[{seen[g.name]}] has that name; names must be unique")
        seen[g.name] = k
        if g.kind == "pressure" and (np.any(np.asarray(g.position) < lower - tol)
                                     or np.any(np.asarray(g.position) > upper + tol)):
            raise InputError(f"{where}.position = {list(g.position)}: outside the domain "
                             f"{lower.tolist()}..{upper.tolist()} (m)")
        if g.kind == "pressure":
            _check_gauge_clear(g.position, owner, lower, h, (nx, ny), where)
        if g.kind == "level" and not lower[0] - tol <= g.x <= upper[0] + tol:
            raise InputError(f"{where}.x = {g.x:g}: outside the domain's width {lower[0]:g}..{upper[0]:g} (m)")


def _check_gauge_clear(position, owner: np.ndarray, lower: np.ndarray, h: float, shape, where: str):
    """A pressure gauge at a point that only blocked cells touch would never read water: refused. A point on
    an obstacle's face (an edge between a blocked cell and an open one) is the fluid's."""
    if touches_only(position, lower, h, shape, owner >= 0)[0]:
        nx, ny = shape
        i, j = np.clip(np.floor((np.asarray(position) - lower) / h).astype(int), 0, [nx - 1, ny - 1])
        x0, y0 = lower + h * np.array([i, j])
        raise InputError(f"{where}.position = {list(position)}: inside obstacles[{owner[i + nx * j]}] (its blocked "
                         f"cell [{x0:g}, {x0 + h:g}] x [{y0:g}, {y0 + h:g}] m), where no water goes; a gauge on the "
                         f"obstacle's face lies on an edge between a blocked cell and an open one")


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
    """Bodies inside the domain, resolved by the grid, seeding particles, clear of obstacles, with a
    finite initial velocity."""
    d = scene.domain
    lower, upper, tol = np.asarray(d.lower), np.asarray(d.upper), 1e-9 * h
    for k, body in enumerate(scene.bodies):
        _inside_domain(body, lower, upper, tol, f"bodies[{k}]")
    for k, (body, x, cells, inside) in enumerate(_seeding(scene)):
        where = f"bodies[{k}]"
        lo, up = body.geometry().bounds()
        if np.any(up - lo < 2 * h - tol):
            raise InputError(f"{where}: it is {up[0] - lo[0]:g} x {up[1] - lo[1]:g} m, less than two cells across "
                             f"(h = {h:g} m): the grid is too coarse for it; refine domain.cells or cell_size")
        if not inside.any():
            raise InputError(f"{where}: seeds no particle (it lies within earlier bodies or between "
                             f"particle positions); the grid is too coarse for it")
        hit = inside & (owner[cells] >= 0)
        if hit.any():
            c = cells[np.flatnonzero(hit)[0]]
            raise InputError(f"{where} overlaps obstacles[{owner[c]}] (cell column {c % nx}, row {c // nx}); "
                             f"move the body or the obstacle")
        v = body.velocity_at(x[inside])
        bad = ~np.all(np.isfinite(v), axis=1)
        if bad.any():
            p, component = x[inside][np.flatnonzero(bad)[0]], int(np.flatnonzero(~np.isfinite(v[bad][0]))[0])
            raise InputError(f"{where}.velocity[{component}] = {body.velocity[component]!r} is not finite at "
                             f"({p[0]:g}, {p[1]:g}) (m/s)")


def _seeding(scene: Scene):
    """For each body: the body, the seeding points tried under its box, their cells, and which of them it
    seeds (inside it and not inside an earlier body), as :meth:`fempm.Particles.seed` does."""
    d = scene.domain
    earlier = []
    for body in scene.bodies:
        shape = body.geometry()
        lo, up = shape.bounds()
        x, cells = _seed_points(body, d, lo, up)
        inside = shape.contains(x)
        for other in earlier:
            inside &= ~other.contains(x)
        earlier.append(shape)
        yield body, x, cells, inside


def seeded_bodies(scene: Scene) -> list[tuple[int, float, float]]:
    """For each body: the particles it seeds, the area they stand for and the area asked (m^2).

    Bodies are seeded on the particle lattice (``particles_per_cell`` sub-cell centres per
    cell), so a body's edges are rounded to it; where bodies overlap, the earlier one has
    the particles.
    """
    out = []
    for body, _, cells, inside in _seeding(scene):
        n = math.isqrt(body.particles_per_cell)
        area = _cell_sizes(scene.domain, cells[inside]).prod(axis=1).sum() / n**2  # the particles' volumes
        out.append((int(inside.sum()), float(area), body.asked_area()))
    return out


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
    return sub_cell_centres(origins, _cell_sizes(d, cells), n), np.repeat(cells, n * n)


def _cell_sizes(d: Domain, cells: np.ndarray) -> np.ndarray:
    """Width and height of structured cells, ``(n, 2)`` (as :meth:`fempm.grid.Grid.cell_sizes`)."""
    return d.h * cell_shares(cells, d.shape, d.last)


def _whole_steps(value: float, dt: float, name: str, at_least_one: bool = True):
    """Refuse ``value`` unless it is a whole number of steps of ``dt``, naming the nearest that are."""
    n = value / dt
    low, high = max(math.floor(n + 1e-9 * n), 1 if at_least_one else 0), max(math.ceil(n - 1e-9 * n), 1)
    if at_least_one and n < 1 - 1e-9:
        raise InputError(f"{name} = {value:g} is shorter than time.dt = {dt:g}: must be >= dt (s)")
    if abs(n - round(n)) > 1e-9 * max(n, 1):
        raise InputError(f"{name} = {value:g} is not a whole number of steps of time.dt = {dt:g} ({n:.6g}); take "
                         f"{low * dt:.10g} or {high * dt:.10g} ({low} or {high} steps)")


def _check_times(scene: Scene, fixed_step: bool = True):
    """The run's end and the output times fall on steps.

    With a fixed ``dt`` the end and every output time must be a whole number of steps. An
    adaptive step lands on the output times instead, and its ``dt`` is only a bound:
    ``fixed_step=False`` keeps only the check that holds for any step (snapshots within the run).
    """
    t, o = scene.time, scene.output
    if fixed_step:
        if t.dt > t.end:
            raise InputError(f"time.dt = {t.dt:g} exceeds time.end = {t.end:g}")
        _whole_steps(t.end, t.dt, "time.end")
        for name in ("particles_interval", "grid_interval", "checkpoint_interval"):
            if getattr(o, name) is not None:
                _whole_steps(getattr(o, name), t.dt, f"output.{name}")
        for k, g in enumerate(scene.gauges):
            if g.interval is not None:
                _whole_steps(g.interval, t.dt, f"gauges[{k}].interval")
    for s in o.snapshots:
        if s > t.end * (1 + 1e-9):
            raise InputError(f"output.snapshots: {s:g} s is after the end of the run, time.end = {t.end:g} s")
        if fixed_step:
            _whole_steps(s, t.dt, "output.snapshots: the time", at_least_one=False)


# -- writing ---------------------------------------------------------------------------------------
def to_toml(scene: Scene) -> str:
    """The scene as TOML with every default filled in; :func:`parse_scene` reads it back unchanged."""
    data = _plain(asdict(scene))
    top = [f"{k} = {_toml_value(v)}" for k, v in data.items() if k in _TOP]
    parts = ["\n".join(top)]
    for name in ("domain", "fluid", "bodies", "obstacles", "walls", "time", "solver", "output", "gauges"):
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
