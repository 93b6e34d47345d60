"""The ``fempm`` command's entry point: stop requests are taken before fempm is even imported.

Importing fempm (DOLFINx, PETSc, numba) takes about a second. A SIGINT or SIGTERM in that
time is noted, not raised: an exception thrown through a half-initialised extension module
(MPI, PETSc) can crash the interpreter at exit. Once the import is complete the command ends
with one line and the status 128 + the signal number. Everything else is
:func:`fempm.cli.main`. This module is top-level (not in the package) because importing
anything in ``fempm`` first runs ``fempm/__init__.py``.
"""

import signal
import sys

_received: list[int] = []


def _note(signum, frame):
    _received.append(signum)


def main() -> int:
    """Run ``fempm`` (see :mod:`fempm.cli`)."""
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, _note)
    from fempm.cli import main as run

    if _received:
        name = signal.Signals(_received[0]).name
        print(f"fempm: interrupted by {name} while starting: nothing was run", file=sys.stderr, flush=True)
        return 128 + _received[0]
    return run()  # which takes the signals over at once


if __name__ == "__main__":
    sys.exit(main())
