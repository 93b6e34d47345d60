"""The cost of one implicit step by phase, this checkout against another (main), side by side.

Runs the seed's dam break (``--cells N``: N x N cells, 2 x 2 particles per cell in the column,
N^2 / 2 particles, or n x n) for ``--warm`` steps, then times ``--steps`` steps, phase by phase
(``project`` = P2G, ``assemble``, ``solve``, ``update`` = G2P, ``relocate``, and the step's
rest, Python between the phases), and splits the solve by PETSc's event log (free-dof and
field-split extraction, symbolic and numeric LU, the Krylov iteration). The same number of steps
again, with each compiled (numba) function of fempm's modules timed per call, splits the step into
the time inside compiled kernels and the time outside them (Python, numpy, PETSc, MPI). Each version runs in its
own process, the two alternating ``--rounds`` times (first one, then the other first), so that both see the same
load; the table gives the median over the rounds of the CPU time per step (less sensitive to the shared machine's
load than the wall time, which is given too) and the ratio this / other. It also gives each step's wall time in the
round where that step ran fastest, averaged over the steps: the two versions take the same steps (the same
scene, and bit for bit where a change keeps the arithmetic), and a burst of another tenant's load in one round drops
out, where it moves a median of a few rounds by several per cent.

    python benchmarks/step_cost.py --case 40:100:300 --case 236:60:10 --against ../main --page docs/speed-step.md

A case is ``CELLS:WARM:STEPS`` or ``CELLS:WARM:STEPS:N`` with N x N particles per cell (default 2,
the seed's and the shipped scene's; 236 cells at 2 x 2: 27,848 particles, the size of Tesserae.jl's dam
break; 40:100:300:4 gives 3200, the scene until its particles were shifted). ``--against DIR`` is a checkout with its own ``.venv`` (its ``fempm`` is imported from
DIR); ``--page`` writes the tables into a Markdown page (``benchmarks/templates/speed-step.md``).
``--interfoam``: in every round of a 40² case also OpenFOAM's interFoam on the same tank at 40² to 2 s of
flow (``benchmarks/interfoam.py``), whose time a step measures the machine in the same run: issue 12's
2.5 ms at 800 particles was set where interFoam took 2.2 s for its 571 steps (3.85 ms a step). The table gives
each version's step over interFoam's twice: the ratio of the medians, and the median of each round's ratio (the
round's step over the same round's interFoam), which a load that drifts from round to round moves less, and the
time outside compiled kernels over interFoam's step likewise (issue 12's 0.5 ms of Python a step at that speed).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pages

PHASES = ("project", "assemble", "solve", "update", "relocate")
#: PETSc events that split the solve (seconds summed over the run)
EVENTS = {
    "extract": ("MatCreateSubMat", "MatCreateSubMats"),
    "LU symbolic": ("MatLUFactorSym",),
    "LU numeric": ("MatLUFactorNum",),
    "Schur product": ("MatMatMultSym", "MatMatMultNum", "MatAXPY"),
    "Krylov": ("KSPSolve",),
}


def worker(cells: int, warm: int, steps: int, petsc: dict, per_cell: int = 2) -> dict:
    """Time ``steps`` steps after ``warm``; phase and event CPU milliseconds per step."""
    from mpi4py import MPI

    import fempm  # noqa: F401  (imports dolfinx before petsc4py)
    import fempm.timing

    fempm.timing.time = SimpleNamespace(perf_counter=time.process_time)  # phases in CPU time
    from petsc4py import PETSc

    from fempm.cases import dambreak
    from fempm.simulation import build_solver

    # per_cell x per_cell particles per cell (the seed's 2 x 2: issue 12's sizes, 800 particles at 40²),
    # written out so that a checkout from before the scene's 4 x 4 runs the same case
    changes = {"time.end": 10.0, "domain.cells": [cells, cells], "bodies.0.particles_per_cell": per_cell**2}
    if petsc:
        changes["solver.petsc"] = petsc
    scene = dambreak.scene(changes, files=False)
    solver = build_solver(scene, MPI.COMM_WORLD)
    for _ in range(warm):
        solver.step()
    solver.timings.clear()
    PETSc.Log.begin()
    events = {name: [PETSc.Log.Event(e) for e in names] for name, names in EVENTS.items()}
    before = {name: sum(e.getPerfInfo()["time"] for e in evs) for name, evs in events.items()}
    # phases: wall time per phase (PhaseTimes); the step's CPU time from the process clock; each step's wall time
    each = []
    wall, cpu = time.perf_counter(), time.process_time()
    for _ in range(steps):
        start = time.perf_counter()
        solver.step()
        each.append(1e3 * (time.perf_counter() - start))
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    per = 1e3 / steps
    phases = {p: solver.timings.get(p, 0.0) * per for p in PHASES}
    out = {"particles": len(solver.particles), "step wall": wall * per, "step cpu": cpu * per, "each step": each,
           **phases, "rest": cpu * per - sum(phases.values())}
    for name, evs in events.items():
        out[name] = (sum(e.getPerfInfo()["time"] for e in evs) - before[name]) * per
    out["kernels"], out["outside"] = _kernel_share(solver, steps)
    out["free dofs"] = int(solver.grid.comm.allreduce(solver.system.free.mask.sum()))
    out["pattern kept"] = getattr(solver.system.linear_solver, "reuses", 0)
    return out


def _kernel_share(solver, steps: int) -> tuple[float, float]:
    """Milliseconds a step inside fempm's compiled (numba) functions, and outside them (Python, numpy, PETSc, MPI),
    over ``steps`` more steps (wall time): every compiled function a module of fempm holds is wrapped by a timer.
    Calls from one compiled function to another are inside; a compiled function imported by name into another
    module is not wrapped, so its time counts as outside."""
    import importlib
    import pkgutil

    import numba

    import fempm

    inside = [0.0]

    def timed(function):
        def call(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                inside[0] += time.perf_counter() - start
        return call

    for info in pkgutil.iter_modules(fempm.__path__):
        module = importlib.import_module(f"fempm.{info.name}")
        for name, value in list(vars(module).items()):
            if isinstance(value, numba.core.registry.CPUDispatcher):
                setattr(module, name, timed(value))
    start = time.perf_counter()
    for _ in range(steps):
        solver.step()
    total = time.perf_counter() - start
    return inside[0] / steps * 1e3, (total - inside[0]) / steps * 1e3


def run(python: str, root: Path, case: tuple[int, ...], petsc: dict) -> dict:
    """One worker process with ``python`` importing fempm from ``root``."""
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"}
    cells, warm, steps, per_cell = (*case, 2)[:4]
    command = [python, str(Path(__file__).resolve()), "--worker", "--cells", str(cells), "--warm",
               str(warm), "--steps", str(steps), "--per-cell", str(per_cell), "--petsc", json.dumps(petsc)]
    done = subprocess.run(command, env=env, cwd=root, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def median(values):
    values = sorted(values)
    n = len(values)
    return 0.5 * (values[(n - 1) // 2] + values[n // 2])


def interfoam_step() -> tuple[float, float, int]:
    """interFoam on the dam break's tank at 40² cells to 2 s of flow: its wall and CPU milliseconds a step, and
    its steps (the interFoam process alone, as ``benchmarks/versus_interfoam.py`` times it)."""
    import interfoam

    done = interfoam.run(40, end_time=2.0)
    return 1e3 * done.wall_s / done.steps, 1e3 * done.cpu_s / done.steps, done.steps


def compare(case: tuple[int, ...], versions: dict, rounds: int, with_interfoam: bool = False) -> tuple[str, str]:
    """Run the versions alternately (and interFoam 40², ``with_interfoam``); a heading line and the Markdown
    table of medians and ratios."""
    cells, warm, steps, per_cell = (*case, 2)[:4]
    load_start = os.getloadavg()
    results = {name: [] for name in versions}
    foam = []
    for round_ in range(rounds):
        order = list(versions.items())
        if round_ % 2:  # the order turns each round: no version always runs first after interFoam or the other
            order.reverse()
        for name, (python, root, petsc) in order:
            results[name].append(run(python, root, case, petsc))
        if with_interfoam:
            foam.append(interfoam_step())
    load_end = os.getloadavg()
    keys = ["step cpu", "step wall", "step fastest", *PHASES, "rest", "kernels", "outside", *EVENTS]
    table = {name: {k: median([r[k] for r in rs]) for k in keys if k != "step fastest"} for name, rs in results.items()}
    for name, rs in results.items():  # each step's fastest round: a burst of load in one round drops out
        table[name]["step fastest"] = sum(map(min, zip(*(r["each step"] for r in rs)))) / steps
    first = results["this"][0]
    heading = (f"{cells}² cells, {per_cell} × {per_cell} per cell: {first['particles']} particles "
               f"({first['free dofs']} free dofs at the last step), "
               f"{steps} steps timed after {warm}, {rounds} alternating rounds; load average "
               f"{', '.join(f'{x:.2f}' for x in load_start)} at the start, "
               f"{', '.join(f'{x:.2f}' for x in load_end)} at the end; solves that kept the last one's "
               f"pattern: " + ", ".join(f"{name} {rs[0]['pattern kept']}" for name, rs in results.items()))
    if foam:
        wall, cpu = median([f[0] for f in foam]), median([f[1] for f in foam])
        heading += (f"; interFoam 40² to 2 s of flow in the same rounds: {foam[0][2]} steps, {wall:.3f} ms a step "
                    f"(wall), {cpu:.3f} (CPU)")
        for name in versions:
            table[name]["interfoam"] = table[name]["step cpu"] / cpu
            # each round's step over that round's interFoam: a load that drifts between rounds cancels
            table[name]["interfoam paired"] = median([r["step cpu"] / f[1] for r, f in zip(results[name], foam)])
            table[name]["outside interfoam"] = median([r["outside"] / f[0] for r, f in zip(results[name], foam)])
        keys += ["interfoam", "interfoam paired", "outside interfoam"]
    label = {"step cpu": "step, CPU", "step wall": "step, wall",
             "step fastest": "step, wall, each step in its fastest round (the mean over the steps)",
             "rest": "rest (Python between phases)",
             "kernels": "in compiled kernels (wall, the same steps again, timed per call)",
             "outside": "outside them: Python, numpy, PETSc, MPI (the same)",
             "interfoam": "step, CPU, over interFoam 40²'s (issue 12: 2.5 / 3.85 = 0.65)",
             "interfoam paired": "the same, each round's over its interFoam's, the median",
             "outside interfoam": ("outside compiled kernels over interFoam 40²'s step (wall), each round's, the median "
                                   "(issue 12: 0.5 / 3.85 = 0.13)"),
             **{k: f"solve: {k} (wall)" for k in EVENTS}}
    rows = []
    for k in keys:
        row = [label.get(k, k)] + [f"{table[name][k]:.3f}" for name in versions]
        if "other" in versions:
            row.append(f"{table['this'][k] / table['other'][k]:.2f}" if table["other"][k] > 0 else "—")
        rows.append(row)
    head = ["ms per step", *versions] + (["this / other"] if "other" in versions else [])
    return heading, pages.table(head, rows)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--case", action="append", type=lambda t: tuple(int(v) for v in t.split(":")),
                        metavar="CELLS:WARM:STEPS[:N]", help="a case (repeatable; default 40:100:300)")
    parser.add_argument("--rounds", type=int, default=3, help="runs of each version, alternating (default 3)")
    parser.add_argument("--against", type=Path, default=None, help="a checkout to compare with (its .venv)")
    parser.add_argument("--petsc", default="{}", help="PETSc options (JSON) for this checkout's runs")
    parser.add_argument("--page", type=Path, default=None, help="write the tables into this Markdown page")
    parser.add_argument("--interfoam", action="store_true",
                        help="also interFoam 40² in every round of a 40² case (the machine's speed in the same run)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--cells", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--warm", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--steps", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--per-cell", type=int, default=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.cells, args.warm, args.steps, json.loads(args.petsc), args.per_cell)))
        return
    here = Path(__file__).resolve().parents[1]
    versions = {"this": (sys.executable, here, json.loads(args.petsc))}
    if args.against:
        versions["other"] = (str(args.against.resolve() / ".venv" / "bin" / "python"), args.against.resolve(), {})
    sections = []
    with_interfoam = args.interfoam
    if with_interfoam:
        import interfoam

        reason = interfoam.ensure_openfoam()
        if reason:
            print(f"step_cost.py: interFoam skipped: {reason}", file=sys.stderr)
            with_interfoam = False
    for case in args.case or [(40, 100, 300)]:
        heading, text = compare(case, versions, args.rounds, with_interfoam and case[0] == 40)
        print(heading + "\n\n" + text + "\n", flush=True)
        sections.append(f"### {heading}\n\n{text}\n")
    if args.page:
        other = f"`{args.against}` (commit {_commit(args.against)})" if args.against else "none"
        command = "python benchmarks/step_cost.py " + " ".join(sys.argv[1:])
        pages.write(args.page, pages.fill("speed-step.md", command=command, other=other, tables="\n".join(sections),
                                          **pages.provenance()))


def _commit(root: Path) -> str:
    done = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True)
    return done.stdout.strip() or "?"


if __name__ == "__main__":
    main()
