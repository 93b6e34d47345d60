"""The particle-grid transfers measured (issue 11): the seed's FLIP/PIC against the default affine-FLIP.

The cases, the first four run with both transfers (``fempm.cases.vortices.VARIANTS``):

* the dam break (40 x 40, 2 x 2 particles per cell, to t = 0.27 s): the front's RMS relative
  difference from interFoam 160 x 160 over 0.3 < T <= 3 at several time steps, and 80 x 80;
* the Taylor-Green vortex (``fempm.cases.vortices.taylor_green``): numerical dissipation rate per
  unit time at nu = 1e-6 and Re = 100, two grids, three steps (U dt / h = 0.4, 0.2, 0.1);
* the Gresho vortex (``fempm.cases.vortices.gresho``): kinetic energy, angular momentum and the
  u_theta error, two grids;
* the dam-break column at rest (``fempm.cases.column.rest``): volume and speeds;
* where the Taylor-Green loss comes from (affine-FLIP, nu = 1e-6, U dt / h = 0.4): three grids at
  2 x 2, 3 x 3 and 4 x 4 particles per cell, and at 2 x 2 without PSPG; and how it grows in time
  on 64² and 128²;
* both vortices with the shipped dam-break scene's particle handling (particle shifting, the
  surface-aware volume correction: :func:`scene_vortex`), by grid, step and particles per cell;
* both vortices so handled with the default PIC shares (a whole share, then one on the particles' noise:
  ``noise_filter``, ``Scheme.noise_rate``, :class:`fempm.transfer.NoiseFilter`) beside each share alone;
* both vortices so handled with the last step's pressure by parts (``increment_vortices``,
  ``Scheme.pressure_work = "increment"``), with and without turning shifts, by grid and step;
* both vortices without particles, the FEM-only reference (``fempm.cases.vortices.fem_reference``).

The results go to ``docs/verification/transfers.json`` and, through the template
``templates/verification-transfers.md``, to the transfers section of ``docs/verification.md``
(the page's other sections, written by ``report.py``, are kept as they are; each case's entry says
which command made it, so that cases may be rerun one at a time)::

    python benchmarks/transfer_study.py                 # the short studies (about 15 minutes)
    python benchmarks/transfer_study.py --full          # t = 3 Gresho, 10 s column, all steps (hours)
    python benchmarks/transfer_study.py --case taylor_green gresho
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
import pages
from fempm import diagnostics, output, references
from fempm.cases import column, dambreak, vortices
from fempm.simulation import build_solver
from fempm.verification import advance

RESULTS = pages.ROOT / "docs" / "verification" / "transfers.json"
PAGE = pages.ROOT / "docs" / "verification.md"
MARKER = "## Transfers: FLIP/PIC against affine-FLIP"


def _front_run(cells: int, dt: float, end: float, scheme: dict):
    """The dam break at a fixed step to ``end``: its front ``(T, Z)`` every step, and the run's outcome."""
    changes = {"time.end": end, **dambreak.seed_setup(dt), "domain.cells": [cells, cells], "output.progress": False,
               **{f"solver.{k}": v for k, v in scheme.items()}}
    solver = build_solver(dambreak.scene(changes, files=False))
    history = [(0.0, diagnostics.front_position(solver.particles))]
    run = advance(solver, end, lambda s: history.append((s.time, diagnostics.front_position(s.particles))))
    return references.dimensionless_front(*np.array(history).T), run


def _outcome_fields(run) -> dict:
    return {"status": run.status, "cause": run.cause, "t": run.time, "wall": run.wall}


def dambreak_front(variant: str, cells: int = 40, dt: float = 1e-3, end: float = 0.27) -> dict:
    """The dam break's front difference from interFoam 160^2 (0.3 < T <= 3) with a transfer."""
    front, run = _front_run(cells, dt, end, vortices.VARIANTS[variant])
    return {"variant": variant, "cells": cells, "dt": dt,
            "error": references.front_difference(front, references.interfoam_front(160)), **_outcome_fields(run)}


def dambreak_step_halvings(variant: str, cells: int, steps: tuple[float, ...], end: float = 0.27) -> dict:
    """The dam break with a transfer at fixed steps halved in turn: each front's difference from
    interFoam 160^2 and from the front at twice its step (the same window). Differences from one halving to
    the next that fall show the fronts converging in dt, so that a front error that moves as dt falls
    approaches the grid's own limit rather than growing with the number of steps."""
    fronts, rows = [], []
    for dt in steps:
        front, run = _front_run(cells, dt, end, vortices.VARIANTS[variant])
        rows.append({"dt": dt, "error": references.front_difference(front, references.interfoam_front(160)),
                     "halving": references.front_difference(front, fronts[-1]) if fronts else None,
                     **_outcome_fields(run)})
        fronts.append(front)
    return {"variant": variant, "cells": cells, "rows": rows}


#: the PIC shares :func:`scene_vortex` compares, by name: the default (a whole share at 30/s, then one on the
#: noise at 300/s), the whole share alone at 100/s (the default before) and the share on the noise alone
SHARES = {"default": {}, "whole": vortices.WHOLE_SHARE, "noise": vortices.NOISE_ONLY}
#: how the noise_filter table names them
SHARE_NAMES = {"default": "default: whole 30/s + noise 300/s", "whole": "whole alone, 100/s",
               "noise": "noise alone, 300/s"}


def scene_vortex(kind: str, cells: int, courant: float, per_cell: int, end: float, share: str = "default",
                 turning: bool = False, work: str | None = None) -> dict:
    """A vortex (``taylor_green`` at nu = 1e-6, or ``gresho``) handled as the shipped dam-break scene
    handles its particles (``scenes/dambreak.toml``): affine-FLIP, particle shifting of strength
    :data:`fempm.cases.vortices.SHIFTING`, and for Gresho the surface-aware volume correction (in a
    closed box: of both signs everywhere); Taylor-Green runs without a correction, as in its own study.
    ``courant``: U dt / h (Gresho: max u_theta dt / h); ``share``: the PIC shares, a name of :data:`SHARES`;
    ``turning``: shifts that add no angular momentum (``Scheme.shifting_keeps_angular_momentum``); ``work``: a
    ``Scheme.pressure_work`` (None: the Scheme's, which without gravity is the split's)."""
    dt = courant / cells
    pic = {**SHARES[share], **({"shifting_keeps_angular_momentum": True} if turning else {}),
           **({"pressure_work": work} if work else {})}
    if kind == "taylor_green":
        run = vortices.taylor_green("affine-FLIP", cells, dt, 1e-6, end=end, per_cell=per_cell,
                                    shifting=vortices.SHIFTING, pic=pic)
    else:
        run = vortices.gresho("affine-FLIP", cells, dt, end=end, per_cell=per_cell, shifting=vortices.SHIFTING,
                              surface_aware=True, pic=pic)
    return {**run, "kind": kind, "courant": courant, "per_cell": per_cell, "share": share, "turning": turning,
            "work": work}


def studies(full: bool) -> dict:
    """Which runs each case makes (short or full)."""
    return {
        "dambreak": [(v, 40, dt) for v in vortices.VARIANTS for dt in (1e-3, 5e-4, 2.5e-4)]
        + [("affine-FLIP", 80, 1e-3)] + ([("FLIP/PIC", 80, 1e-3)] if full else []),
        "dambreak_steps": [(v, 40, tuple(1e-3 / 2**k for k in range(5 if full else 3))) for v in vortices.VARIANTS],
        "taylor_green": [(v, n, c / n, nu) for v in vortices.VARIANTS for nu in (1e-6, 1e-2) for n in (32, 64)
                         for c in (0.4, 0.2, 0.1) if full or nu == 1e-6]
        + [(v, n, 0.4 / n, 1e-6, 1.0) for v in vortices.VARIANTS for n in (32, 64)],  # one turnover
        "gresho": [(v, n, 0.4 / n, 3.0 if full else 0.5) for v in vortices.VARIANTS for n in (32, 64)],
        "column": [(v, 10.0 if full else 1.0) for v in vortices.VARIANTS],
        "loss_sources": [("affine-FLIP", n, 0.4 / n, 1e-6, 0.25, 1.0, "bspline", per_cell, pspg)
                         for per_cell, pspg in ((2, True), (3, True), (4, True), (2, False)) for n in (32, 64, 128)],
        "loss_growth": [("affine-FLIP", 64, 0.4 / 64, 1e-6, 0.5), ("affine-FLIP", 128, 0.4 / 128, 1e-6, 0.25)],
        "scene_vortices": [("taylor_green", n, c, k, 0.25) for n, c, k in
                           ((64, 0.4, 2), (128, 0.4, 2), (64, 0.2, 2), (64, 0.1, 2), (64, 0.4, 3), (128, 0.4, 3))]
        + [("gresho", n, c, k, 3.0 if full else 0.5) for n, c, k in
           ((32, 0.4, 2), (64, 0.4, 2), (64, 0.2, 2), (64, 0.4, 3)) + (((128, 0.4, 2),) if full else ())],
        "noise_filter": [("gresho", 64, c, 2, 3.0 if full else 0.5, share, turning) for c in (0.4, 0.2)
                         for share, turning in (("default", False), ("whole", False), ("noise", False),
                                                ("default", True))]
        + [("taylor_green", n, c, 2, 0.25, share) for n, c in ((64, 0.4), (64, 0.1), (128, 0.4))
           for share in ("default", "whole")],
        "increment_vortices": [("taylor_green", n, c, 2, 0.25, "default", turning, "increment")
                               for n, c, turning in ((32, 0.4, True), (64, 0.4, True), (128, 0.4, True), (64, 0.2, True),
                                                     (64, 0.1, True), (64, 0.4, False), (128, 0.4, False))]
        + [("gresho", n, c, 2, 3.0 if full else 0.5, "default", turning, "increment")
           for n, c, turning in ((32, 0.4, True), (64, 0.4, True), (64, 0.2, True), (64, 0.4, False))
           + (((128, 0.4, True),) if full else ())],
        "fem_vortices": [("taylor_green", n, c / n, 0.25, 1e-6)
                         for n, c in ((64, 0.4),) + (((128, 0.4),) if full else ()) + ((64, 0.2), (64, 0.1))]
        + [("gresho", n, c / n, 3.0 if full else 0.5) for n, c in ((32, 0.4), (64, 0.4), (64, 0.2))],
    }


RUNS = {"dambreak": dambreak_front, "dambreak_steps": dambreak_step_halvings, "taylor_green": vortices.taylor_green,
        "gresho": vortices.gresho, "column": column.rest, "loss_sources": vortices.taylor_green, "loss_growth": vortices.taylor_green,
        "scene_vortices": scene_vortex, "noise_filter": scene_vortex, "increment_vortices": scene_vortex,
        "fem_vortices": vortices.fem_reference}


def _outcome(r: dict) -> str:
    return "completed" if r["status"] == "completed" else f"stopped at {r['t']:.3g}: {r['cause']}"


def _made(case: dict) -> str:
    return (f"`{case['command']}` on {case['date']} UTC, fempm {case['commit']}, {case['machine']} shared with other "
            f"work ({case['seconds']:.0f} s).")


def _loss_sources(rows: list[dict]) -> str:
    """The Taylor-Green loss by grid (columns) for each particle count and PSPG setting (rows)."""
    cells = sorted({r["cells"] for r in rows})
    settings = list(dict.fromkeys((r["per_cell"], r["pspg"]) for r in rows))
    loss = {(r["per_cell"], r["pspg"], r["cells"]): r for r in rows}
    return pages.table(["particles per cell", "PSPG"] + [f"{n}²" for n in cells], [
        [f"{k} × {k}", "on" if pspg else "off"] + [
            f"{loss[k, pspg, n]['numerical']:.2e}" if loss[k, pspg, n]["status"] == "completed"
            else _outcome(loss[k, pspg, n]) for n in cells]
        for k, pspg in settings])


def _largest(r: dict) -> str:
    """The angular momentum's change of largest magnitude over a Gresho run (runs before it was kept: "—")."""
    return f"{100 * r['L_largest']:+.3f} %" if "L_largest" in r else "—"


def section(data: dict) -> str:
    """The transfers section of ``docs/verification.md`` from the stored results (one entry per case:
    its rows and how they were made)."""
    rows = {case: entry["rows"] for case, entry in data.items()}
    pct = lambda x, d=2: f"{100 * x:.{d}f} %"  # noqa: E731
    tables = {
        "dambreak": pages.table(["transfer", "cells", "dt (s)", "front vs interFoam 160²", "wall (s)", "outcome"], [
            [r["variant"], r["cells"], f"{r['dt']:g}", pct(r["error"]), f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("dambreak", [])]),
        "dambreak_steps": pages.table(["transfer", "cells", "dt (s)", "front vs interFoam 160²", "front vs the run at 2 dt",
                                       "wall (s)", "outcome"], [
            [case["variant"], case["cells"], f"{r['dt']:g}", pct(r["error"], 3),
             pct(r["halving"], 3) if r["halving"] is not None else "—", f"{r['wall']:.0f}", _outcome(r)]
            for case in rows.get("dambreak_steps", []) for r in case["rows"]]),
        "taylor_green": pages.table(["transfer", "ν", "cells", "dt", "t", "numerical dissipation (1/unit time)",
                                     "KE(t)/KE(0) (exact)", "wall (s)", "outcome"], [
            [r["variant"], f"{r['nu']:g}", r["cells"], f"{r['dt']:.3g}", f"{r['t']:g}", f"{r['numerical']:.2e}",
             f"{r['ke_end']:.5f} ({r['exact_end']:.5f})", f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("taylor_green", [])]),
        "gresho": pages.table(["transfer", "cells", "dt", "t", "KE change", "angular momentum change",
                               "u_θ L2 error", "wall (s)", "outcome"], [
            [r["variant"], r["cells"], f"{r['dt']:.3g}", f"{r['t']:g}", f"{100 * r['ke']:+.2f} %",
             f"{100 * r['L']:+.3f} %", pct(r["profile"]), f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("gresho", [])]),
        "column": pages.table(["transfer", "basis", "t (s)", "volume change", "speed at the end (m/s)",
                               "largest speed (m/s)", "wall (s)", "outcome"], [
            [r["variant"], r["basis"], f"{r['t']:g}", f"{100 * r['volume']:+.3f} %", f"{r['speed']:.1e}",
             f"{r['peak']:.1e}", f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("column", [])]),
        "loss_sources": _loss_sources(rows.get("loss_sources", [])),
        "loss_growth": pages.table(["cells", "window", "U t / h at its end", "numerical dissipation (1/unit time)"], [
            [r["cells"], f"{a:.3f}–{b:.3f}", f"{b * r['cells']:.0f}", f"{loss:.2e}"]
            for r in rows.get("loss_growth", []) for a, b, loss in r["windows"]]),
        "scene_taylor_green": pages.table(["cells", "particles per cell", "U dt / h", "t",
                                           "numerical dissipation (1/unit time)", "wall (s)", "outcome"], [
            [r["cells"], f"{r['per_cell']} × {r['per_cell']}", f"{r['courant']:g}", f"{r['t']:g}",
             f"{r['numerical']:.2e}", f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("scene_vortices", []) if r["kind"] == "taylor_green"]),
        "scene_gresho": pages.table(["cells", "particles per cell", "max u_θ dt / h", "t", "KE change",
                                     "angular momentum change", "u_θ L2 error", "largest ρ̃/ρ", "wall (s)", "outcome"], [
            [r["cells"], f"{r['per_cell']} × {r['per_cell']}", f"{r['courant']:g}", f"{r['t']:g}",
             f"{100 * r['ke']:+.2f} %", f"{100 * r['L']:+.3f} %", pct(r["profile"]), f"{r['crowding']:.2f}",
             f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("scene_vortices", []) if r["kind"] == "gresho"]),
        "noise_filter": pages.table(["vortex", "cells", "particles per cell", "U dt / h", "t", "PIC share",
                                     "KE change or loss per unit time", "angular momentum change (largest over the run)",
                                     "u_θ L2 error", "wall (s)", "outcome"], [
            [r["kind"].replace("_", "–").title(), r["cells"], f"{r['per_cell']} × {r['per_cell']}", f"{r['courant']:g}",
             f"{r['t']:g}",
             SHARE_NAMES[r["share"]] + (", shifts keeping L" if r.get("turning") else ""),
             f"{100 * r['ke']:+.2f} %" if r["kind"] == "gresho" else f"{r['numerical']:.2e}",
             f"{100 * r['L']:+.3f} % ({_largest(r)})" if r["kind"] == "gresho" else "—",
             pct(r["profile"]) if r["kind"] == "gresho" else "—", f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("noise_filter", [])]),
        "increment_vortices": pages.table(["vortex", "cells", "U dt / h", "t", "shifts",
                                           "KE change or loss per unit time",
                                           "angular momentum change (largest over the run)", "u_θ L2 error",
                                           "largest ρ̃/ρ", "wall (s)", "outcome"], [
            [r["kind"].replace("_", "–").title(), r["cells"], f"{r['courant']:g}", f"{r['t']:g}",
             "keeping L" if r["turning"] else "default",
             f"{100 * r['ke']:+.2f} %" if r["kind"] == "gresho" else f"{r['numerical']:.2e}",
             f"{100 * r['L']:+.3f} % ({_largest(r)})" if r["kind"] == "gresho" else "—",
             pct(r["profile"]) if r["kind"] == "gresho" else "—",
             f"{r['crowding']:.2f}" if r["kind"] == "gresho" else "—", f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("increment_vortices", [])]),
        "fem_taylor_green": pages.table(["cells", "U dt / h", "t", "numerical dissipation (1/unit time)", "wall (s)",
                                         "outcome"], [
            [r["cells"], f"{r['dt'] * r['cells']:g}", f"{r['t']:g}", f"{r['numerical']:.2e}", f"{r['wall']:.0f}",
             _outcome(r)]
            for r in rows.get("fem_vortices", []) if r["kind"] == "taylor_green"]),
        "fem_gresho": pages.table(["cells", "max u_θ dt / h", "t", "KE change",
                                   "angular momentum change (largest over the run)", "u_θ L2 error (start)", "wall (s)",
                                   "outcome"], [
            [r["cells"], f"{r['dt'] * r['cells']:g}", f"{r['t']:g}", f"{100 * r['ke']:+.3f} %",
             f"{100 * r['L']:+.3f} % ({_largest(r)})",
             f"{pct(r['profile'])} ({pct(r['profile0'])})", f"{r['wall']:.0f}", _outcome(r)]
            for r in rows.get("fem_vortices", []) if r["kind"] == "gresho"]),
    }
    made = {f"{case}_made": _made(data[case]) if case in data else "Not run yet." for case in RUNS}
    return pages.fill("verification-transfers.md", marker=MARKER, **tables, **made)


def write_section(page: Path = PAGE, results: Path = RESULTS):
    """Put the stored results' section at the end of the page, in place of an earlier one."""
    text = page.read_text() if page.exists() else ""
    kept = text.split(MARKER)[0].rstrip("\n")
    pages.write(page, (kept + "\n\n" if kept else "") + section(json.loads(results.read_text())))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--full", action="store_true", help="the whole studies (hours)")
    parser.add_argument("--case", nargs="+", choices=tuple(RUNS), default=list(RUNS))
    parser.add_argument("--page-only", action="store_true", help="rewrite the section from the stored results")
    args = parser.parse_args(argv)
    if not args.page_only:
        plan = studies(args.full)
        for case in args.case:
            start, rows = time.perf_counter(), []
            for run in plan[case]:
                rows.append(RUNS[case](*run))
                print(case, json.dumps(rows[-1]), flush=True)
            made = {k: v for k, v in pages.provenance().items() if k != "node"}
            command = f"python benchmarks/transfer_study.py{' --full' if args.full else ''} --case {case}"
            # read again just before writing: another invocation may have stored a case meanwhile
            stored = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
            stored[case] = {"rows": rows, "command": command, "seconds": time.perf_counter() - start, **made}
            RESULTS.parent.mkdir(parents=True, exist_ok=True)
            output.write_json(RESULTS, stored)
    write_section()
    return 0


if __name__ == "__main__":
    sys.exit(main())
