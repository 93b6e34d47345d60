"""Hard cases of the implicit MPM: does each run to its end, or stop with a diagnosis? (``docs/hard-cases.md``)

Runs the cases of :mod:`fempm.cases.hard` (a step ten and twenty times the seed's, water and
a 10 Pa s fluid, an obstacle, a lone particle, a sparse cloud, a corner, a long run), prints
each one's measures as a row and writes ``docs/hard-cases.md`` from ``templates/hard-cases.md``::

    python benchmarks/hard_cases.py [--full] [--doc docs/hard-cases.md] [--case NAME ...]
    python benchmarks/hard_cases.py --pressure-quadrature gauss    # docs/hard-cases-gauss.md
    python benchmarks/hard_cases.py --pressure-work by-parts       # docs/hard-cases-by-parts.md
    python benchmarks/hard_cases.py --pressure-work divergence     # docs/hard-cases-divergence.md
    python benchmarks/hard_cases.py --pressure-work split          # docs/hard-cases-split.md

Default: the short versions the tests run in CI; ``--full``: the long ones too (hours: the
40 s dam break at the seed's step among them).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
import pages
from fempm.cases.hard import CASES, COLUMNS, Outcome, row, run_case
from fempm.options import PRESSURE_QUADRATURES, PRESSURE_WORKS


#: an option's flag, page and note on its page
OPTIONS = {
    "gauss": (" --pressure-quadrature gauss", "hard-cases-gauss.md", " This page: the same cases with the pressure's "
              "terms at Gauss points (`solver.pressure_quadrature = \"gauss\"`), which the tests do not assert on."),
    "by-parts": (" --pressure-work by-parts", "hard-cases-by-parts.md", " This page: the same cases with the "
                 "pressure's work by parts where the water is deep (`solver.pressure_work = \"by-parts\"`), which the "
                 "tests do not assert on."),
    "divergence": (" --pressure-work divergence", "hard-cases-divergence.md", " This page: the same cases with the "
                   "pressure's work in divergence form throughout (`solver.pressure_work = \"divergence\"`, method.md's "
                   "`-p div w`; the shipped dam break's until 2026-11-29), which the tests do not assert on."),
    "split": (" --pressure-work split", "hard-cases-split.md", " This page: the same cases with the hydrostatic "
              "pressure's work alone split off and taken by parts (`solver.pressure_work = \"split\"`, the shipped "
              "dam break's until 2026-11-30, then with each particle shifted on its own; here with the scene's turning "
              "shifts), on which the tests assert only that the dam break at ten times the seed's step completes "
              "(`tests/test_hydrostatic.py`)."),
}


def markdown(short: list[Outcome], full: list[Outcome], option: str | None = None) -> str:
    """``docs/hard-cases.md``: the cases, the tables, how they were made (``option``: a key of :data:`OPTIONS`)."""
    cases = pages.table(["case", "set-up", "short (s)", "full (s)"],
                        ([c.name, c.what, f"{c.short:g}", f"{c.full:g}"] for c in CASES.values()))
    longer = f"\n## Full versions\n\n{pages.table(COLUMNS, map(row, full))}\n" if full else ""
    flags, _, note = OPTIONS[option] if option else ("", "", "")
    return pages.fill("hard-cases.md", flags=(" --full" if full else "") + flags, note=note, ranks=MPI.COMM_WORLD.size, cases=cases,
                      short=pages.table(COLUMNS, map(row, short)), full=longer, **pages.provenance())


def main(argv=None):
    """Run the cases (short, and with ``--full`` also full), print the rows, write the page."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full", action="store_true", help="the long versions too")
    parser.add_argument("--doc", type=Path, default=None, help="markdown output (default docs/hard-cases.md, "
                        "with an option docs/hard-cases-<option>.md)")
    parser.add_argument("--pressure-quadrature", choices=PRESSURE_QUADRATURES, default="particles",
                        help="where the pressure's terms are integrated (solver.pressure_quadrature)")
    parser.add_argument("--pressure-work", choices=PRESSURE_WORKS, default=None,
                        help="how the momentum takes the pressure's work (solver.pressure_work; default: each case's "
                        "own, the last step's pressure by parts in the dam break's)")
    parser.add_argument("--case", nargs="+", choices=list(CASES), default=list(CASES), help="only these cases")
    args = parser.parse_args(argv)
    if args.pressure_quadrature == "gauss" and args.pressure_work not in (None, "divergence"):
        parser.error(f"--pressure-work {args.pressure_work} is a form of the particles' quadrature: not with "
                     "--pressure-quadrature gauss")
    outcomes = {False: [], True: []}
    for full in (False, True) if args.full else (False,):
        for name in args.case:
            outcomes[full].append(run_case(name, full, pressure_quadrature=args.pressure_quadrature,
                                           pressure_work=args.pressure_work))
            if MPI.COMM_WORLD.rank == 0:
                print(f"{'full' if full else 'short'}: " + " | ".join(
                    f"{k}: {v}" for k, v in zip(COLUMNS, row(outcomes[full][-1]))), flush=True)
    if MPI.COMM_WORLD.rank == 0:
        option = "gauss" if args.pressure_quadrature == "gauss" else args.pressure_work
        text = markdown(outcomes[False], outcomes[True], option)
        print(text)
        pages.write(args.doc or pages.ROOT / "docs" / (OPTIONS[option][1] if option else "hard-cases.md"), text)


if __name__ == "__main__":
    main()
