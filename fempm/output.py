"""Files a run writes: CSV and JSON tables, particle series for ParaView, grid fields, pictures.

Every file is written to a temporary name beside its final one and renamed when
complete, so a run stopped at any moment leaves no half-written file. Only rank 0 writes
tables, pictures and series files, one file whatever the number of ranks; particles
and grid samples are gathered to it. A file that cannot be written (disk full, no
permission) raises :class:`OutputError` naming it, on every rank alike.

The files fempm writes are known by name (:data:`OUTPUT_NAMES`): a folder holding some is
an earlier run's, which a new run replaces only when asked (:func:`earlier_outputs`,
:func:`remove_earlier_outputs`); other files in the folder are never touched.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from mpi4py import MPI

from fempm.errors import FempmError, InputError

__all__ = [
    "OUTPUT_NAMES",
    "GridSeries",
    "OutputError",
    "ParticleSeries",
    "agree",
    "atomic_path",
    "earlier_outputs",
    "gather_particles",
    "plot_gauges",
    "prepare_folder",
    "remove_earlier_outputs",
    "save_figure",
    "snapshot",
    "write_csv",
    "write_json",
]

#: Names of the files and folders a run writes (series, pictures, tables, checkpoint, and the
#: temporary names of unfinished ones).
OUTPUT_NAMES = re.compile(
    r"(particles|grid)(_\d{6}\.(vtp|vti)|\.pvd)|grid\.bp|snapshot_(t\d+\.\d+|final)\.png|checkpoint\.npz"
    r"|(front|volume|gauges)\.csv|(front|gauges)\.png|summary\.json|\..+\.tmp\d*(\.\w+)?")


class OutputError(FempmError):
    """A file of the run could not be written (disk full, no permission, ...); the message names it."""


def agree(comm, error: str | None):
    """Raise :class:`OutputError` on every rank if rank 0 reports ``error`` (collective)."""
    error = comm.bcast(error, root=0)
    if error:
        raise OutputError(error)


def _cannot_write(path, error: OSError | str) -> str:
    reason = error if isinstance(error, str) else (error.strerror or str(error))
    return f"cannot write {path}: {reason}"


def prepare_folder(folder: str | Path, comm) -> Path:
    """Create the output folder (all ranks agree), or fail clearly if it is a file or cannot be made."""
    folder = Path(folder)
    error = None
    if comm.rank == 0:
        try:
            if folder.exists() and not folder.is_dir():
                error = f"output folder {str(folder)!r} exists and is not a folder"
            else:
                folder.mkdir(parents=True, exist_ok=True)
                if not os.access(folder, os.W_OK | os.X_OK):
                    error = f"output folder {str(folder)!r} is not writable"
        except (OSError, ValueError) as e:
            error = f"cannot create output folder {str(folder)!r}: {getattr(e, 'strerror', None) or e}"
    error = comm.bcast(error, root=0)
    if error:
        raise InputError(error)
    return folder


def earlier_outputs(folder: str | Path) -> list[str]:
    """The names of the files of :data:`OUTPUT_NAMES` in ``folder`` (sorted; none if it does not exist)."""
    try:
        return sorted(p.name for p in Path(folder).iterdir() if OUTPUT_NAMES.fullmatch(p.name))
    except (FileNotFoundError, NotADirectoryError):
        return []


def remove_earlier_outputs(folder: str | Path, comm):
    """Remove the files a run writes (:data:`OUTPUT_NAMES`) from ``folder``, nothing else (rank 0)."""
    error = None
    if comm.rank == 0:
        for name in earlier_outputs(folder):
            path = Path(folder) / name
            try:
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path)
                else:
                    path.unlink()
            except OSError as e:
                error = f"cannot remove the earlier run's {path}: {e.strerror}"
                break
    agree(comm, error)


@contextmanager
def atomic_path(path: str | Path, complete=None):
    """Yield a temporary path beside ``path``; rename it to ``path`` if the block succeeds.

    Args:
        complete: a check of the written temporary file (returns False when the writer
            stopped short without an error, as VTK's do on a full disk).

    Raises:
        OutputError: the file could not be written, naming ``path``.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}{path.suffix}")
    try:
        yield tmp
        if complete is not None and not complete(tmp):
            raise OutputError(_cannot_write(path, "the file came out incomplete (is the disk full?)"))
        os.replace(tmp, path)
    except OSError as e:
        raise OutputError(_cannot_write(path, e)) from None
    finally:
        try:
            if tmp.exists():
                tmp.unlink()
        except OSError:
            pass


def _ends_with(tail: bytes):
    """A check that a file ends with ``tail`` (after trailing white space)."""
    def check(path: Path) -> bool:
        try:
            with open(path, "rb") as f:
                f.seek(max(path.stat().st_size - 64, 0))
                return f.read().rstrip().endswith(tail)
        except OSError:
            return False
    return check


@contextmanager
def _quiet_vtk():
    """VTK's own error printing off: a failed write is reported once, as :class:`OutputError`."""
    from vtkmodules.vtkCommonCore import vtkObject

    shown = vtkObject.GetGlobalWarningDisplay()
    vtkObject.GlobalWarningDisplayOff()
    try:
        yield
    finally:
        vtkObject.SetGlobalWarningDisplay(shown)


_VTK_COMPLETE = _ends_with(b"</VTKFile>")
_PNG_COMPLETE = _ends_with(b"IEND\xaeB`\x82")


def write_csv(path: str | Path, header: list[str], rows, comment: str | None = None):
    """Write a CSV table (optionally a ``# comment`` first line) atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as f:
            if comment:
                f.write(f"# {comment}\n")
            writer = csv.writer(f)
            writer.writerow(header)
            writer.writerows(rows)


def write_json(path: str | Path, data: dict):
    """Write a JSON document atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, default=_to_builtin) + "\n")


def _to_builtin(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def gather_particles(particles, fields=("velocity", "pressure")) -> dict[str, np.ndarray] | None:
    """All particles' positions, ids and the given fields on rank 0 (None elsewhere), sorted by id."""
    comm = particles.grid.comm
    names = ["x", "id", *fields]
    parts = comm.gather({n: particles[n] for n in names}, root=0)
    if comm.rank != 0:
        return None
    out = {n: np.concatenate([p[n] for p in parts]) for n in names}
    order = np.argsort(out["id"])
    return {n: a[order] for n, a in out.items()}


class _Series:
    """Files written one at a time (``name_000000.ext``, ...) and a ParaView ``name.pvd`` index.

    Every file and every version of the index is written atomically, and the index
    lists only files complete on disk. ``entries`` (time, file name) is the state a
    restarted run passes back to continue the same series.
    """

    extension = ""

    def __init__(self, folder: Path, name: str, entries=()):
        self.folder, self.name = Path(folder), name
        self.entries: list[tuple[float, str]] = [(float(t), str(f)) for t, f in entries]

    def _next_file(self) -> str:
        return f"{self.name}_{len(self.entries):06d}.{self.extension}"

    def _add(self, t: float, filename: str):
        self.entries.append((t, filename))
        collection = "".join(
            f'    <DataSet timestep="{time!r}" file="{file}"/>\n' for time, file in self.entries
        )
        with atomic_path(self.folder / f"{self.name}.pvd", _VTK_COMPLETE) as tmp:
            tmp.write_text(
                '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n'
                f"{collection}  </Collection>\n</VTKFile>\n"
            )


class ParticleSeries(_Series):
    """Particles as VTK PolyData files (``particles_000000.vtp``), gathered to rank 0."""

    extension = "vtp"

    def __init__(self, folder: Path, name: str = "particles", fields=("velocity", "pressure"), entries=()):
        super().__init__(folder, name, entries)
        self.fields = tuple(fields)

    def write(self, particles, t: float):
        """Write the particles at time ``t`` and update the index (collective)."""
        data = gather_particles(particles, self.fields)
        error = None
        if data is not None:
            try:
                self._write(data, t)
            except OutputError as e:
                error = str(e)
        agree(particles.grid.comm, error)

    def _write(self, data, t: float):
        import pyvista as pv

        points = np.column_stack([data["x"], np.zeros(len(data["x"]))])
        cloud = pv.PolyData(points)
        cloud.point_data["id"] = data["id"]
        for field in self.fields:
            cloud.point_data[field] = _three_d(data[field])
        filename = self._next_file()
        with atomic_path(self.folder / filename, _VTK_COMPLETE) as tmp, _quiet_vtk():
            cloud.save(tmp)
        self._add(t, filename)


def _three_d(a: np.ndarray) -> np.ndarray:
    """Vectors of two components padded to three, as VTK expects."""
    if a.ndim == 2 and a.shape[1] == 2:
        return np.column_stack([a, np.zeros(len(a))])
    return a


class GridSeries(_Series):
    """Grid fields (velocity, pressure) as VTK image files (``grid_000000.vti``), one per output.

    The fields are sampled at the nodes of the Lagrange space containing the basis
    (the grid vertices for Q1; vertices, edge midpoints and cell centres for the
    B-spline, whose values there are exact), which ParaView draws bilinearly between
    the nodes. Every rank samples the nodes of its own cells; rank 0 writes one file.
    An image's points are evenly spaced: where the tank's last column or row is cut
    (:class:`fempm.grid.Grid`), the image reaches past the face to the next point, and the
    points beyond the face hold NaN (blank in ParaView).
    """

    extension = "vti"

    def __init__(self, folder: Path, basis, name: str = "grid", entries=()):
        super().__init__(folder, name, entries)
        self.basis = basis
        grid, k = basis.grid, basis.degree
        self.dimensions = (k * grid.nx + 1, k * grid.ny + 1, 1)
        self.spacing = (grid.h / k, grid.h / k, 1.0)
        self.origin = (*grid.lower, 0.0)
        a, b = np.meshgrid(np.arange(self.dimensions[0]), np.arange(self.dimensions[1]), indexing="xy")
        a, b = a.ravel(), b.ravel()
        i, j = np.minimum(a // k, grid.nx - 1), np.minimum(b // k, grid.ny - 1)
        cells = grid.cell_index(i, j)
        points = grid.lower + np.column_stack([a, b]) * (grid.h / k)
        mine = (grid.owner[cells] == grid.comm.rank) & ~grid.outside(points)  # beyond a cut face: NaN
        self.nodes, self.cells = np.flatnonzero(mine), cells[mine]
        self.xi = np.column_stack([a[mine] / k - i[mine], b[mine] / k - j[mine]])
        from fempm.gauges import inside_obstacles

        self.solid = inside_obstacles(grid, points[mine])  # the pressure there is NaN when masked (write)
        self.comm = grid.comm

    def write(self, velocity, pressure, t: float, wet=None):
        """Write grid functions ``velocity`` (2 components) and ``pressure`` at time ``t``.

        With ``wet``, a scalar grid function of the wet fraction (:class:`fempm.gauges.WetFraction`),
        the pressure is NaN (blank in ParaView) where it is below :data:`fempm.gauges.DRY_FRACTION`
        and inside obstacles: the B-spline pressure reaches a cell or so past the water, where it means
        nothing. The particles' pressure (``particles_*.vtp``) is the primary output."""
        p = pressure.evaluate(self.cells, self.xi)[:, 0, 0]
        if wet is not None:
            from fempm.gauges import DRY_FRACTION

            wet_here = (wet.evaluate(self.cells, self.xi)[:, 0, 0] >= DRY_FRACTION) & ~self.solid
            p = np.where(wet_here, p, np.nan)
        local = (self.nodes, velocity.evaluate(self.cells, self.xi)[:, 0, :], p)
        parts = self.comm.gather(local, root=0)
        error = None
        if self.comm.rank == 0:
            try:
                self._write(parts, t)
            except OutputError as e:
                error = str(e)
        agree(self.comm, error)

    def _write(self, parts, t: float):
        import pyvista as pv

        image = pv.ImageData(dimensions=self.dimensions, spacing=self.spacing, origin=self.origin)
        nodes = np.concatenate([p[0] for p in parts])
        for name, k in (("velocity", 1), ("pressure", 2)):
            values = np.concatenate([p[k] for p in parts])
            out = np.full((image.n_points, *values.shape[1:]), np.nan)
            out[nodes] = values
            image.point_data[name] = _three_d(out)
        filename = self._next_file()
        with atomic_path(self.folder / filename, _VTK_COMPLETE) as tmp, _quiet_vtk():
            image.save(tmp)
        self._add(t, filename)

    def write_vtx(self):
        """The whole series once more as one VTX stream, ``grid.bp`` (DOLFINx/ADIOS2, ParaView's
        VTX reader): velocity and pressure as Lagrange functions of the basis's degree, whose
        nodes are the image's points. Written to a temporary folder, then renamed.

        ADIOS2 aborts the process when a write fails, so the free space and the folder's
        permission are checked first (:class:`OutputError` if short); a failure that can
        be caught removes the temporary folder and raises :class:`OutputError`.
        """
        import pyvista as pv

        import dolfinx.fem
        import dolfinx.io

        from fempm.lagrange import lagrange_element

        entries = self.comm.bcast(self.entries, root=0)  # rank 0 keeps the series' index
        if not entries:
            return
        final = self.folder / f"{self.name}.bp"
        tmp = self.folder / f".{self.name}.tmp.bp"
        agree(self.comm, self._room_for_vtx(final, tmp, len(entries)) if self.comm.rank == 0 else None)
        grid, k = self.basis.grid, self.basis.degree
        mesh = grid.mesh
        if grid.cut:  # the stream's nodes are the image's points: the uniform mesh of the image
            import dolfinx.mesh

            corner = grid.lower + grid.h * np.array([grid.nx, grid.ny])
            mesh = dolfinx.mesh.create_rectangle(self.comm, [grid.lower, corner], [grid.nx, grid.ny],
                                                 dolfinx.mesh.CellType.quadrilateral)
        spaces = {name: dolfinx.fem.functionspace(mesh, lagrange_element(mesh.basix_cell(), k, {name: n}))
                  for name, n in (("velocity", 2), ("pressure", 1))}
        functions = {name: dolfinx.fem.Function(V, name=name) for name, V in spaces.items()}
        node = np.rint((spaces["pressure"].tabulate_dof_coordinates()[:, :2] - grid.lower) / (grid.h / k))
        point = (node[:, 0] + self.dimensions[0] * node[:, 1]).astype(np.int64)  # image point of each dof
        error = None
        try:
            try:
                writer = dolfinx.io.VTXWriter(self.comm, str(tmp), list(functions.values()), engine="BP4",
                                              mesh_policy=dolfinx.io.VTXMeshPolicy.reuse)
                try:
                    for t, filename in entries:
                        image = pv.read(self.folder / filename)
                        for name, f in functions.items():
                            values = np.asarray(image.point_data[name])
                            f.x.array[:] = (values[point, :2] if values.ndim == 2 else values[point]).ravel()
                        writer.write(t)
                finally:
                    writer.close()
            except (RuntimeError, OSError, ValueError) as e:
                error = _cannot_write(final, " ".join(str(e).split()) or type(e).__name__)
            errors = self.comm.allreduce([error] if error else [], op=MPI.SUM)
            if self.comm.rank == 0 and not errors:
                try:
                    if final.exists():
                        shutil.rmtree(final)
                    os.replace(tmp, final)
                except OSError as e:
                    errors = [_cannot_write(final, e)]
        finally:  # also when interrupted: no hidden folder is left
            self.comm.barrier()
            if self.comm.rank == 0:
                shutil.rmtree(tmp, ignore_errors=True)
        agree(self.comm, errors[0] if errors else None)

    def _room_for_vtx(self, final: Path, tmp: Path, steps: int) -> str | None:
        """Why ``grid.bp`` cannot be written (None: it can): no permission, or too little free space."""
        try:
            if tmp.exists():
                shutil.rmtree(tmp)
            if not os.access(self.folder, os.W_OK | os.X_OK):
                return _cannot_write(final, "the folder is not writable")
            points = self.dimensions[0] * self.dimensions[1]
            # three values per point and step, and the mesh once (coordinates, cells, offsets)
            needed = 8 * points * (3 * steps + 6) + 65536
            free = shutil.disk_usage(self.folder).free + (_size(final) if final.exists() else 0)
        except OSError as e:
            return _cannot_write(final, e)
        if free < 1.2 * needed:
            return _cannot_write(final, f"it needs about {needed / 1e6:.3g} MB and the disk has {free / 1e6:.3g} MB "
                                        f"free (the .vti series holds the same fields)")
        return None


def plot_gauges(path: str | Path, header: list[str], rows, units: list[str]):
    """``gauges.png``: each gauge's reading against time, one panel per unit (rank 0 calls it).

    ``header`` is ``["t_s", gauge columns...]``, ``rows`` the table (NaN: dry, drawn as a gap;
    None: not sampled then, skipped), ``units`` the unit of each gauge column.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sampled = np.array([[v is not None for v in row] for row in rows], dtype=bool).reshape(-1, len(header))
    table = np.array([[np.nan if v is None else v for v in row] for row in rows], dtype=float).reshape(sampled.shape)
    kinds = sorted(set(units), key=units.index)
    fig, axes = plt.subplots(len(kinds), 1, figsize=(7, 2.8 * len(kinds)), sharex=True, squeeze=False)
    for ax, unit in zip(axes[:, 0], kinds):
        for k, (name, u) in enumerate(zip(header[1:], units)):
            if u == unit:
                rows_k = sampled[:, k + 1]
                ax.plot(table[rows_k, 0], table[rows_k, k + 1], lw=0.8, label=name)
        ax.set_ylabel({"Pa": "pressure (Pa)", "m": "level (m)"}.get(unit, unit))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    axes[-1, 0].set_xlabel("t (s)")
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig, path: str | Path, dpi: int = 110, **options):
    """Write a matplotlib figure to ``path`` as a PNG whole (:func:`atomic_path`), then close it;
    ``options`` go to ``savefig`` (e.g. ``bbox_inches="tight"``)."""
    import matplotlib.pyplot as plt

    try:
        with atomic_path(path, _PNG_COMPLETE) as tmp:
            fig.savefig(tmp, dpi=dpi, format="png", **options)
    finally:
        plt.close(fig)


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def snapshot(path: str | Path, particles, field: str = "pressure", title: str = "",
             clim: tuple[float, float] | None = None, point_size: float = 6.0):
    """A PNG picture of the particles coloured by ``field``, drawn off-screen by pyvista (collective)."""
    data = gather_particles(particles, (field,))
    error = None
    if data is not None:
        try:
            _picture(path, particles.grid, data, field, title, clim, point_size)
        except OutputError as e:
            error = str(e)
    agree(particles.grid.comm, error)


def _picture(path, grid, data, field, title, clim, point_size):
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # no X server needed
    import pyvista as pv

    values = data[field] if data[field].ndim == 1 else np.linalg.norm(data[field], axis=1)
    cloud = pv.PolyData(np.column_stack([data["x"], np.zeros(len(values))]))
    cloud.point_data[field] = values
    box = pv.Box(bounds=(grid.lower[0], grid.upper[0], grid.lower[1], grid.upper[1], 0, 0))
    plotter = pv.Plotter(off_screen=True, window_size=(900, 800))
    plotter.set_background("white")
    plotter.add_mesh(box.outline(), color="black", line_width=2)
    if grid.blocked.any():
        plotter.add_mesh(_cells_as_quads(grid, np.flatnonzero(grid.blocked)), color="gray")
    plotter.add_mesh(cloud, scalars=field, point_size=point_size, render_points_as_spheres=True,
                     cmap="viridis", clim=clim,
                     scalar_bar_args={"title": f"{field} (Pa)" if field == "pressure" else field,
                                      "color": "black", "vertical": False, "position_y": 0.02,
                                      "position_x": 0.2, "width": 0.6})
    if title:
        plotter.add_text(title, position="upper_edge", font_size=12, color="black")
    plotter.view_xy()
    plotter.camera.zoom(1.05)
    try:
        with atomic_path(path, _PNG_COMPLETE) as tmp, _quiet_vtk():
            plotter.screenshot(str(tmp))
    finally:
        plotter.close()


def _cells_as_quads(grid, cells):
    """The given structured cells as one pyvista surface of rectangles (obstacles in pictures)."""
    import pyvista as pv

    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
    points = (grid.cell_origin(cells)[:, None, :] + grid.cell_sizes(cells)[:, None, :] * corners[None]).reshape(-1, 2)
    faces = np.column_stack([np.full(len(cells), 4), np.arange(4 * len(cells)).reshape(-1, 4)])
    return pv.PolyData(np.column_stack([points, np.zeros(len(points))]), faces.ravel())
