"""The command line: ``fempm check SCENE``, ``fempm run SCENE``, ``fempm run --resume DIR``.

Every mistake in a scene or on the command line ends with one message on stderr
(``fempm: ...``) and exit status 2 before anything runs. Exit status 0: the run
completed; 1: it stopped early (diverged, or a file could not be written; the outputs so
far are kept); 128 + the signal number: interrupted by SIGINT or SIGTERM (after writing a
final checkpoint if the run had started). Under ``mpirun`` every rank runs the same
command; rank 0 prints.

A forms file of one's own is Python code that runs: a scene cannot name one, it is given
here with ``--forms PATH``.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading

from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
from fempm import simulation
from fempm.errors import FempmError
from fempm.scene import available_memory, check_size, describe_grid, load_scene, seeded_bodies, to_toml

__all__ = ["Interrupted", "main"]


class _ArgumentError(FempmError):
    """A command-line mistake (argparse's message, without the usage text)."""


class Interrupted(BaseException):
    """SIGINT or SIGTERM received before the run's own handling took over (start-up, the end)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _interrupt(signum, frame):
    """Raise :class:`Interrupted`, or, where the exception would be lost, take the signal again shortly.

    numba compiles through llvmlite, which calls back into Python from C; an exception raised in such a
    callback is printed and dropped at its C boundary, and the run went on to its end. There the signal
    is sent again 10 ms later, by when the compiler is back in Python's own frames (or the run's own
    handling, :class:`fempm.restart.StopSignals`, has taken it over).
    """
    if _inside_llvmlite(frame):
        threading.Timer(0.01, os.kill, (os.getpid(), signum)).start()
        return
    raise Interrupted(signum)


def _inside_llvmlite(frame) -> bool:
    """Whether ``frame`` or one of its callers is llvmlite's Python code."""
    while frame is not None:
        if f"{os.sep}llvmlite{os.sep}" in frame.f_code.co_filename:
            return True
        frame = frame.f_back
    return False


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise _ArgumentError(f"{self.prog}: {message} (see {self.prog} --help)")


def _positive(unit: str):
    """An argument type: a finite number > 0 of ``unit``."""
    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not (value > 0 and value < float("inf")):
            raise argparse.ArgumentTypeError(f"must be a number of {unit} > 0, got {text!r}")
        return value
    return convert


def parser() -> argparse.ArgumentParser:
    """The argument parser of ``fempm``."""
    top = _Parser(prog="fempm", description="Implicit MPM for incompressible viscous free-surface flow: "
                  "check and run scenes (TOML files; see scenes/ and the README).")
    commands = top.add_subparsers(dest="command", required=True, parser_class=_Parser)
    forms_help = ("a forms file of your own (Python code, which runs) instead of the scene's solver.forms")
    memory_help = "refuse a scene estimated to need more memory than this (GB); default: what is available now"
    check = commands.add_parser("check", help="validate a scene and print it resolved (all defaults filled in), "
                                              "with the size of its run; nothing is written")
    check.add_argument("scene", help="the scene file (.toml)")
    check.add_argument("--forms", metavar="PATH", help=forms_help)
    check.add_argument("--max-memory", type=_positive("GB"), metavar="GB", help=memory_help)
    run = commands.add_parser("run", help="run a scene, or resume a run from its checkpoint")
    run.add_argument("scene", nargs="?", help="the scene file (.toml); not with --resume")
    run.add_argument("--resume", metavar="DIR", help="continue the run whose checkpoint is in DIR")
    run.add_argument("--out", metavar="DIR", help="output folder (overrides output.folder)")
    run.add_argument("--end-time", type=_positive("seconds"), metavar="T",
                     help="simulated end time, s (overrides time.end)")
    run.add_argument("--overwrite", action="store_true",
                     help="start afresh in a folder holding an earlier run: its files are removed, others kept")
    run.add_argument("--quiet", action="store_true", help="no progress line")
    run.add_argument("--forms", metavar="PATH", help=forms_help)
    run.add_argument("--max-memory", type=_positive("GB"), metavar="GB", help=memory_help)
    return top


def main(argv=None) -> int:
    """Run the command line; returns the exit status."""
    comm = MPI.COMM_WORLD
    previous = {s: signal.signal(s, _interrupt) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return _main(argv, comm)
    except Interrupted as stop:
        _say(comm, f"fempm: interrupted by {stop} (before the first step, or by a second signal): no final "
                   f"checkpoint was written")
        return 128 + stop.signum
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _main(argv, comm) -> int:
    try:
        args = parser().parse_args(argv)
        memory = {"max_memory": args.max_memory, "ranks": comm.size,  # read once: all ranks refuse or none
                  "available": comm.bcast(available_memory() if comm.rank == 0 else None, root=0)}
        if args.command == "check":
            return _check(args, comm, memory)
        if (args.scene is None) == (args.resume is None):
            raise _ArgumentError("fempm run: give a scene file or --resume DIR (not both)")
        if args.resume and (args.out or args.overwrite):
            raise _ArgumentError("fempm run: --resume writes on into DIR; --out and --overwrite do not apply")
        progress = False if args.quiet else None
        if args.resume:
            summary = simulation.resume(args.resume, comm, end_time=args.end_time, progress=progress,
                                        forms=args.forms, max_memory=args.max_memory, available=memory["available"])
            folder = args.resume
        else:
            scene = load_scene(args.scene, folder=args.out, end_time=args.end_time, forms=args.forms, **memory)
            _notes(scene, comm)
            summary = simulation.run_scene(scene, comm, overwrite=args.overwrite, progress=progress)
            folder = scene.output.folder
    except FempmError as e:
        _say(comm, f"fempm: {e}" if not isinstance(e, _ArgumentError) else str(e))
        return 2
    return _report(summary, folder, comm)


def _check(args, comm, memory: dict) -> int:
    scene = load_scene(args.scene, forms=args.forms, **memory)
    size = check_size(scene, **memory)
    solver = simulation.build_solver(scene, comm)
    bodies = seeded_bodies(scene)
    if comm.rank == 0:
        print(f"# {args.scene}: valid. The resolved scene (every default filled in):\n")
        print(to_toml(scene))
        for note in scene.notes:
            print(f"# note: {note}")
        for k, (count, seeded, asked) in enumerate(bodies):
            print(f"# bodies[{k}]: {count} particles standing for {seeded:.6g} m^2 of the {asked:.6g} m^2 asked "
                  f"({round(100 * (seeded - asked) / asked, 2) + 0.0:+.2f} %: bodies are rounded to the particle "
                  f"lattice)")
        print(f"# size: {size.summary()}")
        grid = solver.grid
        print(f"# {describe_grid(grid.nx, grid.ny, grid.h, grid.last)}, "
              f"{int(solver.grid.blocked.sum())} blocked by obstacles; {solver.particles.global_count()} particles; "
              f"{scene.time.steps} steps of {scene.time.dt:g} s; {comm.size} rank(s)")
    return 0


def _notes(scene, comm):
    for note in scene.notes:
        _say(comm, f"fempm: note: {note}")


def _report(summary: dict, folder, comm) -> int:
    status = summary["status"]
    if status == "completed":
        _say(comm, f"fempm: {summary['steps']} steps to t = {summary['time']:.6g} s in "
                   f"{summary['wall_time_s']:.1f} s; results in {folder}", sys.stdout)
        return 0
    if status == "interrupted":
        _say(comm, f"fempm: interrupted by {summary['cause']}; a checkpoint and the outputs so "
                   f"far are in {folder}; continue with `fempm run --resume {folder}`")
        name = summary["cause"].split()[0]
        return 128 + int(getattr(signal, name, 0))
    _say(comm, f"fempm: {summary['cause']}; the outputs up to then are in {folder}")
    return 1


def _say(comm, message: str, stream=None):
    if comm.rank == 0:
        print(message, file=stream or sys.stderr, flush=True)


if __name__ == "__main__":
    sys.exit(main())
