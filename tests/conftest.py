"""Shared fixtures and the --full flag (long studies run only when it is given)."""

import shutil
import tempfile
from pathlib import Path

import pytest
from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx/petsc4py)


def pytest_addoption(parser):
    parser.addoption("--full", action="store_true", help="run the long studies marked 'full'")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--full"):
        return
    skip = pytest.mark.skip(reason="long study: run with --full")
    for item in items:
        if "full" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def comm():
    return MPI.COMM_WORLD


@pytest.fixture
def shared_tmp():
    """A temporary folder, the same on every rank (pytest's tmp_path differs per process)."""
    comm = MPI.COMM_WORLD
    path = Path(comm.bcast(tempfile.mkdtemp(prefix="fempm-") if comm.rank == 0 else None, root=0))
    yield path
    comm.barrier()
    if comm.rank == 0:
        shutil.rmtree(path, ignore_errors=True)
