"""Shared fixtures and the --full flag (long studies run only when it is given)."""

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
