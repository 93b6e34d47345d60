"""Numbers reduced over the ranks, as a step needs them several times.

mpi4py's lowercase ``allreduce`` pickles its operands, a few microseconds a call even on one
rank; a step takes a dozen such reductions. These take a number (or an array, summed in place)
through MPI's buffer interface instead, and on one rank return it as it is.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI

__all__ = ["all_ranks", "any_rank", "largest", "smallest", "summed", "total"]


def _reduced(comm, value, dtype, op):
    if comm.size == 1:
        return value
    buffer = np.array([value], dtype=dtype)
    comm.Allreduce(MPI.IN_PLACE, buffer, op=op)
    return buffer[0].item()


def total(comm, value):
    """The sum over the ranks of an int (an int) or a float (a float)."""
    return _reduced(comm, value, np.int64 if isinstance(value, (int, np.integer)) else np.float64, MPI.SUM)


def largest(comm, value: float) -> float:
    """The largest of a float over the ranks."""
    return _reduced(comm, float(value), np.float64, MPI.MAX)


def smallest(comm, value: float) -> float:
    """The smallest of a float over the ranks."""
    return _reduced(comm, float(value), np.float64, MPI.MIN)


def any_rank(comm, flag: bool) -> bool:
    """Whether ``flag`` holds on some rank."""
    return bool(_reduced(comm, bool(flag), np.bool_, MPI.LOR))


def all_ranks(comm, flag: bool) -> bool:
    """Whether ``flag`` holds on every rank."""
    return bool(_reduced(comm, bool(flag), np.bool_, MPI.LAND))


def summed(comm, local: np.ndarray) -> np.ndarray:
    """``local`` (float64) summed over the ranks, in place."""
    if comm.size > 1:
        comm.Allreduce(MPI.IN_PLACE, local, op=MPI.SUM)
    return local
