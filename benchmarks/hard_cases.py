"""Hard cases of the implicit MPM: does each run to its end, or stop with a diagnosis? (``docs/hard-cases.md``)

Runs the cases of :mod:`fempm.cases.hard` (a step ten and twenty times the seed's, water and
a 10 Pa s fluid, an obstacle, a lone particle, a sparse cloud, a corner, a long run), prints
each one's measures as a row and writes ``docs/hard-cases.md`` from ``templates/hard-cases.md``::

    python benchmarks/hard_cases.py [--full] [--doc docs/hard-cases.md] [--case NAME ...]

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


def markdown(short: list[Outcome], full: list[Outcome]) -> str:
    """``docs/hard-cases.md``: the cases, the tables, how they were made."""
    cases = pages.table(["case", "set-up", "short (s)", "full (s)"],
                        ([c.name, c.what, f"{c.short:g}", f"{c.full:g}"] for c in CASES.values()))
    longer = f"\n## Full versions\n\n{pages.table(COLUMNS, map(row, full))}\n" if full else ""
    return pages.fill("hard-cases.md", flags=" --full" if full else "", ranks=MPI.COMM_WORLD.size, cases=cases,
                      short=pages.table(COLUMNS, map(row, short)), full=longer, **pages.provenance())


def main(argv=None):
    """Run the cases (short, and with ``--full`` also full), print the rows, write the page."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full", action="store_true", help="the long versions too")
    parser.add_argument("--doc", type=Path, default=pages.ROOT / "docs" / "hard-cases.md", help="markdown output")
    parser.add_argument("--case", nargs="+", choices=list(CASES), default=list(CASES), help="only these cases")
    args = parser.parse_args(argv)
    outcomes = {False: [], True: []}
    for full in (False, True) if args.full else (False,):
        for name in args.case:
            outcomes[full].append(run_case(name, full))
            if MPI.COMM_WORLD.rank == 0:
                print(f"{'full' if full else 'short'}: " + " | ".join(
                    f"{k}: {v}" for k, v in zip(COLUMNS, row(outcomes[full][-1]))), flush=True)
    if MPI.COMM_WORLD.rank == 0:
        text = markdown(outcomes[False], outcomes[True])
        print(text)
        pages.write(args.doc, text)


if __name__ == "__main__":
    main()
