"""Verification report: every case's error against its reference and wall time, MPM against FEM-only.

Runs each case's study (``benchmarks/studies.py``) in one process and writes
``docs/verification.md`` from ``templates/verification.md`` with, per case, the table of runs
(method, basis, cells, time step, particles per cell, error, wall time of the steps), the
observed convergence rates under grid refinement, and PNG plots of error against wall time and
against cell size (in ``docs/verification/``). The raw rows go to ``docs/verification/results.json``.

    python benchmarks/report.py [--full] [--cases poiseuille couette ...] [--doc docs/verification.md]

Default: the short studies (about ten minutes on one core); ``--full`` adds a finer grid
and time step to each (an hour or more). Run serially: wall times are of one process.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
import pages
import studies
import transfer_study
from fempm import output
from fempm.verification import Measurement, rates

CASES = {  # demo module: what its error measures, and the further measures its table shows
    "hydrostatic": ("max |p - rho g d| / (rho g H) on the centre line after 0.2 s; beside it the bottom "
                    "pressure's relative error and the largest particle speed (m/s)", ("bottom_error", "max_speed")),
    "poiseuille": ("max |u - u_exact| / u_max on the centre line (steady: t = 1.5 H^2/nu; start-up: "
                   "t = 0.1 H^2/nu)", ()),
    "couette": ("max |u - u_exact| / U on the centre line at t = 0.1 H^2/nu", ()),
    "cavity": ("max |u - u_Ghia| / U over both centre lines (Ghia, Ghia & Shin 1982, Re = 100), of the mean "
               "profile over the last 5 L/U; beside it each line's error and the difference from the finest "
               "FEM-only B-spline run (Ghia's table is itself a 129 x 129 solution: see demos/cavity.py); the "
               "MPM's step is U dt / h = 0.5", ("error_u", "error_v", "difference_from_finest_fem")),
    "dambreak": ("RMS relative front error against Koshizuka & Oka 1996 over T <= 3; beside it the same against "
                 "Martin & Moyce 1952 (a = 2.25 in) and against the finest B-spline run (`vs_finest`, the "
                 "numerical error: the experiments hold wall friction and a gate that slip walls leave out)",
                 ("martin_moyce", "vs_finest")),
}


def series(rows: list[Measurement]) -> dict[tuple, list[Measurement]]:
    """Rows that differ only in the cell count, by (case, method, basis, dt, ppc), sorted by cells."""
    groups = defaultdict(dict)
    for r in rows:
        if r.error is not None:
            step = ("U dt/h", r.extra["courant"]) if "courant" in r.extra else ("dt", r.dt)  # the step held fixed
            groups[(r.case, r.method, r.basis, step, r.ppc, r.extra.get("pic_blend"))][r.cells] = r
    return {k: [g[c] for c in sorted(g)] for k, g in groups.items() if len(g) >= 2}


def fmt(x) -> str:
    return "-" if x is None else f"{x:.2e}"


def case_table(rows: list[Measurement], extras: tuple[str, ...]) -> str:
    """The runs of one case as a Markdown table, with the named further measures."""
    def row(r: Measurement) -> list[str]:
        pic = r.extra.get("pic_blend")
        return [r.case, r.method, r.basis, str(r.cells), f"{r.dt:g}", str(r.ppc) if r.ppc else "-",
                "-" if pic is None or r.method != "MPM" else f"{pic:g}", fmt(r.error),
                *(fmt(r.extra.get(k)) for k in extras), f"{r.wall:.2f}",
                r.status if r.status == "completed" else f"{r.status}: {r.cause}"]

    head = ["case", "method", "basis", "cells", "dt", "ppc", "PIC", "error", *extras, "wall (s)", "outcome"]
    return pages.table(head, map(row, rows))


def rate_lines(rows: list[Measurement]) -> list[str]:
    """Observed orders between successive grids of each series."""
    lines = []
    for (case, method, basis, (step, value), ppc, pic), runs in series(rows).items():
        cells = [r.cells for r in runs]
        ppc_text = f", {ppc} particles per cell" if method == "MPM" else ""
        if max(r.error for r in runs) < 1e-6:
            lines.append(f"- {case}, {method}, {basis}, {step} = {value:g}{ppc_text}: the solution lies in the space; "
                         f"what is left is round-off and time error (largest {max(r.error for r in runs):.1e})")
            continue
        orders = rates([1 / c for c in cells], [r.error for r in runs])
        lines.append(f"- {case}, {method}, {basis}, {step} = {value:g}{ppc_text}: errors "
                     + ", ".join(f"{r.error:.2e} ({c})" for r, c in zip(runs, cells))
                     + "; observed orders " + ", ".join(f"{o:.2f}" for o in orders))
    return lines


def plot_case(path: Path, case: str, rows: list[Measurement]):
    """Error against wall time (left) and against cell count (right), one marker per method and basis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    styles = {("MPM", "B-spline"): ("o", "tab:blue"), ("MPM", "Q1"): ("s", "tab:orange"),
              ("FEM-only", "B-spline"): ("^", "tab:green"), ("FEM-only", "Q1"): ("v", "tab:red")}
    done = [r for r in rows if r.error is not None and r.error > 0]
    for (method, basis), (marker, colour) in styles.items():
        mine = [r for r in done if (r.method, r.basis) == (method, basis)]
        if mine:
            left.scatter([r.wall for r in mine], [r.error for r in mine], marker=marker, color=colour,
                         label=f"{method}, {basis}")
    for (c, method, basis, (step, value), ppc, pic), runs in series(rows).items():
        marker, colour = styles[(method, basis)]
        right.plot([r.cells for r in runs], [r.error for r in runs], marker=marker, color=colour,
                   label=f"{method}, {basis}, {step} {value:g}" + (f", {ppc} ppc" if method == "MPM" else ""))
    left.set(xscale="log", yscale="log", xlabel="wall time of the steps (s)", ylabel="error", title=f"{case}: cost")
    right.set(xscale="log", yscale="log", xlabel="cells across the length scale", ylabel="error",
              title=f"{case}: refinement")
    for ax in (left, right):
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.tight_layout()
    output.save_figure(fig, path)


def write_page(doc: Path, results: dict[str, list[Measurement]], full: bool, seconds: float):
    """docs/verification.md, its plots and the raw rows."""
    figures = doc.with_suffix("")
    figures.mkdir(parents=True, exist_ok=True)
    output.write_json(figures / "results.json", {c: [r.as_dict() for r in rows] for c, rows in results.items()})
    sections = []
    for case, rows in results.items():
        plot_case(figures / f"{case}.png", case, rows)
        measure, extras = CASES[case]
        orders = "".join(f"{line}\n" for line in rate_lines(rows))
        sections.append(pages.fill("verification-case.md", case=case, measure=measure, table=case_table(rows, extras),
                                   rates=f"Under grid refinement:\n\n{orders}\n" if orders else "",
                                   figures=figures.name).rstrip("\n"))
    pages.write(doc, pages.fill("verification.md", flags=" --full" if full else "", seconds=f"{seconds:.0f}",
                                cases="\n\n".join(sections), **pages.provenance()))
    if transfer_study.RESULTS.exists():  # the transfers' section, from its own (long) study's stored results
        transfer_study.write_section(doc)


def main(argv=None) -> int:
    """Run the studies and write the page."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--full", action="store_true", help="the complete studies (an hour or more)")
    parser.add_argument("--cases", nargs="+", choices=tuple(CASES), default=list(CASES), help="which cases")
    parser.add_argument("--doc", type=Path, default=pages.ROOT / "docs" / "verification.md", help="the page to write")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    results = {}
    for case in args.cases:
        begin = time.perf_counter()
        results[case] = studies.STUDIES[case](full=args.full)
        print(f"report: {case}: {len(results[case])} runs in {time.perf_counter() - begin:.0f} s", flush=True)
    write_page(args.doc, results, args.full, time.perf_counter() - start)
    print(f"report: wrote {args.doc}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
