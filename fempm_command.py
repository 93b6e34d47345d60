"""The ``fempm`` command's entry point: stop requests are taken before fempm is even imported.

Importing fempm (DOLFINx, PETSc, numba) takes about a second; a SIGINT or SIGTERM in that
time ends the command with one line and the status 128 + the signal number instead of a
traceback. Everything else is :func:`fempm.cli.main`. This module is top-level (not in
the package) because importing anything in ``fempm`` first runs ``fempm/__init__.py``.
"""

import signal
import sys


class _Interrupted(BaseException):
    pass


def _interrupt(signum, frame):
    raise _Interrupted(signum)


def main() -> int:
    """Run ``fempm`` (see :mod:`fempm.cli`)."""
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, _interrupt)
    try:
        from fempm.cli import main as run

        return run()  # which takes the signals over at once
    except _Interrupted as stop:
        name = signal.Signals(stop.args[0]).name
        print(f"fempm: interrupted by {name} while starting: nothing was run", file=sys.stderr, flush=True)
        return 128 + stop.args[0]


if __name__ == "__main__":
    sys.exit(main())
