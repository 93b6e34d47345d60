"""Matrices with a fixed structured sparsity, filled directly in CSR storage.

Two basis functions couple when their supports share a cell, i.e. when their
structured indices differ by at most the degree ``k`` in both directions: each
row has the same stencil of at most ``(2k+1)^2`` functions times ``bs``
components, whatever the particles do, so the sparsity never changes. By default
every function of the grid has its row; a *region* (a set of cells) keeps only
the rows of functions non-zero in it, the others empty, so a large tank holding a
little water stores a matrix the size of the water's neighbourhood.

Assembly adds element matrices straight into the CSR value array of this
rank's *local* rows (owned, then ghost): the position of an entry follows from
the structured offset of its column function, looked up in ``stencil``. The
ghost rows are then added into their owners' rows (the same stencil in the same
column order on both ranks) and the owned rows are handed to PETSc, sharing
memory in serial and by ``MatUpdateMPIAIJWithArray`` in parallel. This avoids
a search per entry in ``MatSetValues``.
"""

from __future__ import annotations

import ctypes
import weakref

import numba
import numpy as np
from petsc4py import PETSc

import dolfinx.fem.petsc

from fempm.space import Space

__all__ = ["GridMatrix", "MatrixLayout", "create_matrix", "grid_matrix", "layout"]

_CHUNK = 1 << 15  # functions per chunk while building the column indices

_petsc = ctypes.CDLL(str(dolfinx.fem.petsc.get_petsc_lib()))
_petsc.MatUpdateMPIAIJWithArray.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
_petsc.MatUpdateMPIAIJWithArray.restype = ctypes.c_int


class MatrixLayout:
    """CSR pattern of a space's local rows and the communication of its ghost rows.

    Attributes:
        indptr: row pointer of the local dof rows (owned then ghost), scalar rows.
        columns: global column indices, sorted within each row.
        stencil: ``stencil[f, (di + k) + (2k + 1) * (dj + k)]`` is the position of
            neighbour ``(di, dj)`` of local function ``f`` in its sorted neighbour
            list (-1 outside the grid); entry ``(f, C) x (g, D)`` sits at
            ``indptr[bs * f + C] + bs * stencil[f, .] + D``.
    """

    def __init__(self, space: Space, region: np.ndarray | None = None):
        self.space, self.region = space, region
        b, num, bs = space.basis, space.numbering, space.bs
        k = b.degree
        width = 2 * k + 1
        f = num.local_functions
        i, j = f % b.nfx, f // b.nfx
        d = np.arange(-k, k + 1)
        di, dj = np.tile(d, width), np.repeat(d, width)  # stencil index (di+k) + width*(dj+k)
        ni, nj = i[:, None] + di, j[:, None] + dj
        valid = (ni >= 0) & (ni < b.nfx) & (nj >= 0) & (nj < b.nfy)
        big = np.iinfo(np.int64).max
        neighbour = np.where(valid, num.global_index[np.where(valid, ni + b.nfx * nj, 0)], big)
        order = np.argsort(neighbour, axis=1, kind="stable")
        rank_in_row = np.empty_like(order)
        np.put_along_axis(rank_in_row, order, np.arange(width * width)[None, :], axis=1)
        self.stencil = np.where(valid, rank_in_row, -1).astype(np.int32)
        count = valid.sum(axis=1)
        if region is not None:  # rows only for functions non-zero in the region's cells
            in_region = np.zeros(b.num_functions, dtype=bool)
            in_region[b.cell_functions(np.flatnonzero(region)).ravel()] = True
            count = np.where(in_region[f], count, 0)
        sorted_neighbours = np.take_along_axis(neighbour, order, axis=1)
        del neighbour, order, rank_in_row, valid, ni, nj
        self.indptr = np.concatenate([[0], np.cumsum(np.repeat(count * bs, bs))]).astype(PETSc.IntType)
        self.columns = np.empty(int(self.indptr[-1]), dtype=PETSc.IntType)
        for start in range(0, len(f), _CHUNK):  # in chunks: whole-grid int64 temporaries took 3x the matrix
            stop = min(start + _CHUNK, len(f))
            keep = np.arange(width * width)[None, :] < count[start:stop, None]
            # every row of a function holds its neighbours' dofs, neighbour-major, component-minor
            columns = (bs * sorted_neighbours[start:stop, :, None] + np.arange(bs)).reshape(stop - start, -1)
            keep = np.repeat(keep, bs, axis=1)
            self.columns[self.indptr[bs * start]: self.indptr[bs * stop]] = np.repeat(columns, bs, axis=0)[
                np.repeat(keep, bs, axis=0)]
        self.num_owned_rows = num.num_owned * bs
        self.num_owned_entries = int(self.indptr[self.num_owned_rows])
        self._plan_ghost_rows()

    def _plan_ghost_rows(self):
        """Where each ghost row goes (rank, and position in the owner's value array)."""
        space, num = self.space, self.space.numbering
        comm = space.comm
        ghosts = num.local_functions[num.num_owned :]
        owner = num.owner[ghosts]
        order = np.argsort(owner, kind="stable")
        bs = space.bs
        rows = (bs * (num.num_owned + order)[:, None] + np.arange(bs)).ravel()
        lengths = self.indptr[rows + 1] - self.indptr[rows]
        self.send_entries = self._entries_of_rows(rows)
        self.send_counts = np.bincount(
            np.repeat(owner[order], bs), weights=lengths, minlength=comm.size
        ).astype(np.int64)
        # tell the owners which of their functions they receive, to find the positions
        send_functions = num.global_index[ghosts[order]]
        function_counts = np.bincount(owner, minlength=comm.size).astype(np.int64)
        recv_function_counts = np.empty_like(function_counts)
        comm.Alltoall(function_counts, recv_function_counts)
        received = np.empty(recv_function_counts.sum(), dtype=np.int64)
        comm.Alltoallv([send_functions, function_counts], [received, recv_function_counts])
        first_global = num.global_index[num.local_functions[0]] if num.num_owned else 0
        local_rows = (bs * (received - first_global)[:, None] + np.arange(bs)).ravel()
        self.recv_entries = self._entries_of_rows(local_rows)
        self.recv_counts = np.empty_like(self.send_counts)
        comm.Alltoall(self.send_counts, self.recv_counts)


    def _entries_of_rows(self, rows: np.ndarray) -> np.ndarray:
        """Positions in the value array of all entries of the given rows, row after row."""
        start, stop = self.indptr[rows].astype(np.int64), self.indptr[rows + 1].astype(np.int64)
        length = stop - start
        offsets = np.concatenate([[0], np.cumsum(length)])[:-1]
        return np.repeat(start - offsets, length) + np.arange(length.sum())


@numba.njit(cache=True)
def _mark(functions, written):
    for f in functions.ravel():
        written[f] = True


@numba.njit(cache=True)
def _mark_positive(weights, written):
    for f in range(weights.shape[0]):
        if weights[f] > 0.0:
            written[f] = True


@numba.njit(cache=True)
def _zero_rows(written, indptr, bs, values):
    """Zero the rows of the written functions and forget them."""
    for f in range(written.shape[0]):
        if written[f]:
            values[indptr[bs * f]: indptr[bs * (f + 1)]] = 0.0
            written[f] = False


@numba.njit(cache=True)
def _multiply_rows(written, indptr, columns, values, bs, x, rows, y):
    """``y[i] = (A x)[rows[i]]``, zero for a row of a function not written (it holds no values)."""
    for i in range(rows.shape[0]):
        r = rows[i]
        s = 0.0
        if written[r // bs]:
            for e in range(indptr[r], indptr[r + 1]):
                s += values[e] * x[columns[e]]
        y[i] = s


class GridMatrix:
    """A PETSc matrix of a space with the full-grid sparsity and direct CSR access.

    ``values`` holds the local rows (owned then ghost); after filling it call
    :meth:`finalize` to add the ghost rows into their owners and update PETSc.
    ``mat`` is the PETSc matrix (AIJ, block size ``bs``, global numbering).

    A writer that names the functions whose rows it filled (:meth:`mark_written`) lets
    :meth:`zero` clear only those rows and :meth:`multiply` skip the others, which are zero: a
    large grid holding a little water then costs per step what the water's rows do.
    """

    def __init__(self, space: Space, region: np.ndarray | None = None):
        self.space = space
        self.layout = layout(space) if region is None else MatrixLayout(space, region)
        lay = self.layout
        self.values = np.zeros(len(lay.columns))
        n, big_n = space.num_owned_dofs, space.num_global_dofs
        owned = slice(0, lay.num_owned_entries)
        csr = (lay.indptr[: lay.num_owned_rows + 1], lay.columns[owned], self.values[owned])
        self.mat = PETSc.Mat().createAIJWithArrays(((n, big_n), (n, big_n)), csr, bsize=space.bs, comm=space.comm)
        self.mat.setAttr("fempm_grid_matrix", self)
        self._shared = space.comm.size == 1  # a SeqAIJ made from arrays shares self.values
        self._written = None  # per local function: its rows may hold values (None: not known)

    def zero(self):
        """Set every stored value to zero (the sparsity stays): the rows of the functions marked
        written since the last zero (and those ghost rows of other ranks add into), or all."""
        if self._written is None:
            self.values[:] = 0.0
            self._written = np.zeros(len(self.space.numbering.local_functions), dtype=np.bool_)
        else:
            _zero_rows(self._written, self.layout.indptr, self.space.bs, self.values)
            self.values[self.layout.recv_entries] = 0.0

    def mark_written(self, functions: np.ndarray):
        """Record that the rows of these local functions (any shape) were filled since :meth:`zero`."""
        if self._written is not None:
            _mark(np.ascontiguousarray(functions), self._written)

    def mark_written_where(self, weights: np.ndarray):
        """Record that the rows of the local functions ``f`` with ``weights[f] > 0`` were filled since :meth:`zero`."""
        if self._written is not None:
            _mark_positive(weights, self._written)

    def multiply(self, x: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray | None:
        """``A x`` at the owned ``rows`` (default all) on one rank when the written rows are known
        (``x`` by global dof); None otherwise (use PETSc)."""
        if not self._shared or self._written is None:
            return None
        lay = self.layout
        rows = np.arange(lay.num_owned_rows) if rows is None else np.asarray(rows, dtype=np.int64)
        y = np.empty(len(rows))
        _multiply_rows(self._written, lay.indptr, lay.columns, self.values, self.space.bs, x, rows, y)
        return y

    def finalize(self) -> PETSc.Mat:
        """Add ghost rows into their owners and pass the owned rows to PETSc."""
        lay, comm = self.layout, self.space.comm
        if comm.size > 1:
            send = self.values[lay.send_entries]
            recv = np.empty(lay.recv_counts.sum())
            comm.Alltoallv([send, lay.send_counts], [recv, lay.recv_counts])
            np.add.at(self.values, lay.recv_entries, recv)
        if self._shared:
            self.mat.stateIncrease()
        else:
            owned = np.ascontiguousarray(self.values[: lay.num_owned_entries])
            err = _petsc.MatUpdateMPIAIJWithArray(self.mat.handle, owned.ctypes.data)
            if err:
                raise RuntimeError(f"MatUpdateMPIAIJWithArray failed with PETSc error {err}")
        return self.mat


_layouts: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def layout(space: Space) -> MatrixLayout:
    """The matrix layout of a space (built once per space)."""
    if space not in _layouts:
        _layouts[space] = MatrixLayout(space)
    return _layouts[space]


def create_matrix(space: Space) -> PETSc.Mat:
    """A PETSc AIJ matrix (block size ``bs``) of ``space`` with the full-grid sparsity, all zero.

    Particle forms assemble into its CSR storage directly.
    """
    return GridMatrix(space).finalize()


def grid_matrix(mat: PETSc.Mat) -> GridMatrix:
    """The :class:`GridMatrix` behind a PETSc matrix made by :func:`create_matrix`."""
    gm = mat.getAttr("fempm_grid_matrix")
    if gm is None:
        raise TypeError("this PETSc matrix was not created by fempm.matrix.create_matrix()")
    return gm
