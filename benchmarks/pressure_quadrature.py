"""A study: the pressure's terms integrated at fixed Gauss points instead of at the particles.

The particles are the step's quadrature points, and the open accuracy defects point at that
quadrature of the pressure's terms: Taylor-Green's loss grows with the particles' disorder, so
that it rises under refinement; a column at rest grows a mode in which corner particles pair
under the hydrostatic pressure (docs/notes-accuracy.md). Here the pressure's work, with gravity (which
balances it at rest), and the continuity are integrated at the 3 x 3 Gauss points of the cells
around the water, weighted by a share of water, and the particles keep the inertia, the viscous
stress and PSPG (the forms: ``benchmarks/forms/gauss_pressure.py``). The weightings
(:data:`WEIGHTINGS`):

* ``gauss (shipped: pressure_quadrature)``: the ``sharp`` one as fempm ships it, ``Scheme.pressure_quadrature =
  "gauss"`` (``fempm.pressure_points``, ``forms/gauss_pressure.py``; its cells: where the share may be above zero);
* ``particles, work by parts (shipped: pressure_work)``: no Gauss points; every term at the particles, the
  momentum's pressure work ``w . grad p`` where the water is deep (``Scheme.pressure_work = "by-parts"``,
  ``forms/incompressible.py``, ``pressure_work``);
* ``particles, the last step's pressure by parts (shipped: pressure_work)``: the same, the last step's pressure
  taken by parts and the step's change in divergence form (``Scheme.pressure_work = "increment"``,
  ``fempm.hydrostatic``, ``LastPressure``);
* ``smooth``: the smoothed fraction of water ``rho~ / rho`` (eq. 2) at the point, clipped to 1,
  with PSPG's residual that of the weighted terms, ``grad(wet p) / wet``;
* ``smooth, PSPG uncorrected``: the same with PSPG's residual as shipped;
* ``sharp``: ``clip(2 rho~ / rho - 1/2, 0, 1)``, a surface band half as wide, PSPG corrected (``sharper``:
  ``clip(2.5 rho~ / rho - 3/4, 0, 1)``);
* ``cells``: 1 in a cell deep in the water (``fempm.density.DEEP`` at its centre), else the share
  of the cell the particles' volumes fill; PSPG as shipped;
* ``sharp`` variants: at most the smoothed fraction itself (the pressure's force follows thinning
  water) everywhere, or deep in the water only (blended by the grid's deep functions), or there only
  below 0.9; and ``conserved``, the
  offset ``c`` of ``clip(2 rho~ / rho - c, 0, 1)`` chosen each step (within 1/4 of 1/2) so that the
  wet Gauss points hold the particles' volume;
* ``blended``: the terms split between the Gauss points, with a weight ``D`` rising from 0 to 1 as the smoothed
  fraction rises over the range named, and the particles, with ``1 - D``: the pressure's work, gravity and the
  continuity, or the continuity alone (the momentum balance whole at the particles; forms:
  ``benchmarks/forms/blended_pressure.py``).

Each against the shipped particle quadrature (``particles``) on the dam break's front (to
t = 0.28 s, against interFoam 160²), its CPU time per step (the least of three blocks of 100), its right-wall gauges (``benchmarks/wall_pressure.py``), Taylor-Green's loss (nu = 1e-6, U dt / h = 0.4, to t = 0.25,
64² and 128²), the Gresho vortex (64², to t = 3) and the dam break's column at rest (10 x 40 cells,
1 ms to 14 s and 10 ms to 15 s; and 19.5 cells deep, its surface half-way up a cell, 1 ms to 5 s and
10 ms to 15 s); the Gresho vortex and the columns on a cell edge also with the shipped scene's
surface-aware volume correction (``Scheme.surface_aware``) instead of the cases' crowding-only one. Serial. Results go to ``docs/pressure-quadrature.json``, the page
to ``docs/pressure-quadrature.md``::

    python benchmarks/pressure_quadrature.py                         # all (the columns take longest)
    python benchmarks/pressure_quadrature.py --case column_1ms --weighting cells
    python benchmarks/pressure_quadrature.py --quick                 # short runs, nothing stored
    python benchmarks/pressure_quadrature.py --page-only             # the page from the stored results
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

import fempm  # noqa: F401  (imports dolfinx_solver before dolfinx and petsc4py)
import pages
import wall_pressure
from fempm import diagnostics, references
from fempm.cases import column, dambreak, vortices
from fempm.density import DEEP
from fempm.implicit import ImplicitSolver
from fempm.options import Scheme
from fempm.pressure_points import GAUSS_WEIGHTS, StepPoints
from fempm.simulation import build_solver
from fempm.verification import advance

FORMS = Path(__file__).resolve().parent / "forms" / "gauss_pressure.py"
BLENDED_FORMS = FORMS.with_name("blended_pressure.py")
RESULTS = pages.ROOT / "docs" / "pressure-quadrature.json"
PAGE = pages.ROOT / "docs" / "pressure-quadrature.md"


@dataclasses.dataclass(frozen=True)
class Weighting:
    """How a Gauss point's share of water is taken: ``smooth`` (the sharpened smoothed fraction,
    ``clip(sharpness rho~ / rho - (sharpness - 1) / 2, 0, 1)``) or ``cells``; ``corrected``: PSPG's
    residual is the weighted terms' (see the forms)."""

    wet: str
    sharpness: float = 1.0
    corrected: bool = False
    #: where the share is at most the smoothed fraction itself, so that the pressure's force scales with thinning
    #: water: "" nowhere, "everywhere", or "deep" (blended by the grid's deep functions, ``fempm.density``)
    thinned: str = ""
    thinned_below: float = 1.0  #: the fraction below which the share follows it (at most ``fraction / thinned_below``)
    #: the sharpened fraction's offset chosen each step so that the wet points hold the particles' volume
    #: (``clip(sharpness rho~ / rho - c, 0, 1)``, ``c`` within ``OFFSET_RANGE`` of ``(sharpness - 1) / 2``)
    conserved: bool = False


@dataclasses.dataclass(frozen=True)
class Blend:
    """The pressure's terms split between the Gauss points (weight ``D``, a ramp of the smoothed fraction from 0
    at ``low`` to 1 at ``high``) and the particles (``1 - D``): the continuity, and with ``all_terms`` the
    pressure's work with gravity too (``benchmarks/forms/blended_pressure.py``)."""

    low: float
    high: float
    all_terms: bool = True


#: the shipped option, ``Scheme.pressure_quadrature = "gauss"`` (``fempm.pressure_points``, ``forms/gauss_pressure.py``)
SHIPPED = "shipped"
#: the shipped option ``Scheme.pressure_work = "by-parts"`` (every term at the particles, ``forms/incompressible.py``)
BY_PARTS = "by-parts"
#: the shipped option ``Scheme.pressure_work = "increment"`` (the last step's pressure by parts, fempm.hydrostatic)
INCREMENT = "increment"
WEIGHTINGS = {
    "particles": None,  # the shipped forms and quadrature
    "gauss (shipped: pressure_quadrature)": SHIPPED,
    "particles, work by parts (shipped: pressure_work)": BY_PARTS,
    "particles, the last step's pressure by parts (shipped: pressure_work)": INCREMENT,
    "smooth": Weighting("smooth", corrected=True),
    "smooth, PSPG uncorrected": Weighting("smooth"),
    "sharp": Weighting("smooth", sharpness=2.0, corrected=True),
    "sharper (2.5)": Weighting("smooth", sharpness=2.5, corrected=True),
    "sharp, thinned": Weighting("smooth", sharpness=2.0, corrected=True, thinned="everywhere"),
    "sharp, thinned deep in the water": Weighting("smooth", sharpness=2.0, corrected=True, thinned="deep"),
    "sharp, thinned below 0.9 deep in the water": Weighting("smooth", sharpness=2.0, corrected=True, thinned="deep",
                                                             thinned_below=0.9),
    "sharp, conserved": Weighting("smooth", sharpness=2.0, corrected=True, conserved=True),
    "cells": Weighting("cells"),
    "blended 0.75-0.95": Blend(0.75, 0.95),
    "blended 0.75-0.95, continuity alone": Blend(0.75, 0.95, all_terms=False),
    "blended 0.5-0.75, continuity alone": Blend(0.5, 0.75, all_terms=False),
}
#: how far a conserved weighting's offset may move from ``(sharpness - 1) / 2``
OFFSET_RANGE = 0.25


def _set_fields(particles, fields: dict):
    """Every particle takes these fields' values (the fields added where missing): the study's forms read them."""
    for name, value in fields.items():
        if name not in particles.fields:
            particles.add_field(name)
        particles[name][:] = value


class GaussPressure(ImplicitSolver):
    """The implicit MPM with the pressure's terms at Gauss points weighted by ``weighting`` (module)."""

    def __init__(self, weighting: Weighting, basis, particles, physics=None, scheme=None, controls=None):
        self.weighting = weighting
        self.offsets = []  # the conserved weighting's offsets, step by step
        fields = {"wet": 0.0, "sharpness": weighting.sharpness,
                  "offset": (weighting.sharpness - 1) / 2,
                  "correction": float(weighting.corrected)}
        _set_fields(particles, fields)
        super().__init__(basis, particles, physics, dataclasses.replace(
            scheme or Scheme(), forms=str(FORMS), pressure_quadrature="gauss", pressure_work="divergence"), controls)

    def quadrature_points(self) -> StepPoints:
        """The particles and the Gauss points of the cells holding particles and their neighbours
        (``fempm.pressure_points``), with the weighting's shares of water at the Gauss points."""
        gp = self._gauss_points
        around = np.isin(gp.cells, self._cells_around_water())

        def fields(chosen):
            n = len(GAUSS_WEIGHTS)
            cells = gp.cells[chosen]
            wet = self._wet(cells, np.repeat(cells, n), gp.xi[chosen].reshape(-1, 2), gp.volume[chosen].ravel())
            return {"wet": wet}
        return gp.points(self.particles, around, fields)

    def _cells_around_water(self) -> np.ndarray:
        g = self.grid
        occupied = np.zeros(g.num_cells, dtype=bool)
        occupied[self.particles.cell] = True
        rows = occupied.reshape(g.ny, g.nx)
        grown = rows.copy()
        grown[1:] |= rows[:-1]
        grown[:-1] |= rows[1:]
        around = grown.copy()
        around[:, 1:] |= grown[:, :-1]
        around[:, :-1] |= grown[:, 1:]
        return np.flatnonzero(around.ravel())

    def _wet(self, cells: np.ndarray, point_cells: np.ndarray, xi: np.ndarray, volume: np.ndarray) -> np.ndarray:
        """The Gauss points' shares of water (``xi``: their places in their cells, in cell sizes h;
        ``volume``: their weights)."""
        g, w = self.grid, self.weighting
        phi = self.system.fields["smoothed_density"].values[:, 0] / self._reference_density
        if w.wet == "smooth":
            values = self.basis.tabulate(point_cells, xi, order=0)[:, 0, :]
            functions = self.system.scalar_space.local_functions_of_cells(point_cells)
            at_points = np.einsum("pl,pl->p", values, phi[functions])
            offset = (w.sharpness - 1) / 2
            if w.conserved:
                offset = self._conserving_offset(w.sharpness * at_points, volume, offset)
                self.particles["offset"][:] = offset
            wet = np.clip(w.sharpness * at_points - offset, 0.0, 1.0)
            if not w.thinned:
                return wet
            thinned = np.minimum(wet, at_points / w.thinned_below)
            if w.thinned == "everywhere":
                return thinned
            deep = np.einsum("pl,pl->p", values, self._deep_water(phi)[functions])
            return deep * thinned + (1 - deep) * wet
        filled = np.bincount(self.particles.cell, self.particles["volume"], minlength=g.num_cells)
        share = np.minimum(filled / np.prod(g.cell_sizes(np.arange(g.num_cells)), axis=1), 1.0)
        deep = self._deep_water
        centre = np.einsum("cl,cl->c", deep.centre_values, phi[deep.cell_functions])
        share[g.owned_cells[centre >= DEEP]] = 1.0
        return np.repeat(share[cells], len(GAUSS_WEIGHTS))


    def _conserving_offset(self, sharpened: np.ndarray, volume: np.ndarray, offset: float) -> float:
        """The offset ``c`` whose ``sum volume clip(sharpened - c, 0, 1)`` is the particles' volume (bisection;
        the sum falls as ``c`` rises), within ``OFFSET_RANGE`` of ``offset``."""
        comm = self.grid.comm
        target = comm.allreduce(float(self.particles["volume"].sum()))
        lo, hi = offset - OFFSET_RANGE, offset + OFFSET_RANGE
        for _ in range(40):
            c = (lo + hi) / 2
            if comm.allreduce(float(volume @ np.clip(sharpened - c, 0.0, 1.0))) > target:
                lo = c
            else:
                hi = c
        self.offsets.append((lo + hi) / 2)
        return (lo + hi) / 2


class BlendedPressure(ImplicitSolver):
    """The implicit MPM with the pressure's terms blended between Gauss points and particles (:class:`Blend`)."""

    def __init__(self, blend: Blend, basis, particles, physics=None, scheme=None, controls=None):
        self.fields = {"blend_low": blend.low, "blend_high": blend.high, "blend_terms": float(blend.all_terms)}
        _set_fields(particles, self.fields)
        super().__init__(basis, particles, physics, dataclasses.replace(
            scheme or Scheme(), forms=str(BLENDED_FORMS), pressure_quadrature="gauss", pressure_work="divergence"), controls)

    def quadrature_points(self) -> StepPoints:
        """The particles and the Gauss points of the cells where ``D`` may be above zero (a function's
        smoothed fraction above ``blend_low``), which carry the blend's fields."""
        fraction = self.system.fields["smoothed_density"].values[:, 0] / self._reference_density
        gp = self._gauss_points
        return gp.points(self.particles, gp.wet_cells(fraction, self.fields["blend_low"]), lambda chosen: self.fields)


def solver_type(weighting: str, surface_aware: bool = False):
    """The solver class (or factory) of a weighting, as the cases take it; ``surface_aware``: with the shipped
    scene's volume correction (``Scheme.surface_aware``, ``fempm.density``) instead of the case's."""
    made = _maker(WEIGHTINGS[weighting])
    if not surface_aware:
        return made

    def make(basis, particles, physics=None, scheme=None, controls=None):
        return made(basis, particles, physics, dataclasses.replace(scheme or Scheme(), surface_aware=True), controls)
    return make


def scene_solver(weighting: str, scene) -> ImplicitSolver:
    """The solver of a scene with a weighting's quadrature."""
    solver = build_solver(scene)
    return _maker(WEIGHTINGS[weighting])(solver.basis, solver.particles, solver.physics, solver.scheme, solver.controls)


def _maker(w):
    """The solver type of a weighting (``None``: the particles, in divergence form, whatever the scene's treatment;
    :data:`SHIPPED`: ``pressure_quadrature = "gauss"``; :data:`BY_PARTS`, :data:`INCREMENT`: that ``pressure_work``)."""
    if w in (None, SHIPPED, BY_PARTS, INCREMENT):  # the study's rows compare with the divergence form at the particles
        option = {None: {"pressure_work": "divergence"}, SHIPPED: {"pressure_quadrature": "gauss", "pressure_work": "divergence"},
                  BY_PARTS: {"pressure_work": "by-parts"}, INCREMENT: {"pressure_work": "increment"}}[w]

        def shipped(basis, particles, physics=None, scheme=None, controls=None):
            return ImplicitSolver(basis, particles, physics, dataclasses.replace(scheme or Scheme(), **option), controls)
        return shipped
    return functools.partial(BlendedPressure if isinstance(w, Blend) else GaussPressure, w)


# -- the cases: each returns a dict of its measures ----------------------------------------------
def dambreak_front(weighting: str, quick: bool) -> dict:
    end = 0.28
    solver = scene_solver(weighting, dambreak.scene({"time.end": end, "output.progress": False}, files=False))
    history = [(0.0, diagnostics.front_position(solver.particles))]
    run = advance(solver, end, lambda s: history.append((s.time, diagnostics.front_position(s.particles))))
    h = np.array(history)
    front = references.dimensionless_front(h[:, 0], h[:, 1])
    return {"front": references.front_difference(front, references.interfoam_front(160)), "status": run.status,
            "cause": run.cause, "t": run.time, "wall": run.wall, "steps": run.steps}


def step_cost(weighting: str, quick: bool) -> dict:
    """The shipped dam break's CPU time per step after its first 20 steps (which compile and settle): the least
    of three blocks of 100 steps (the machine's noise only adds)."""
    solver = scene_solver(weighting, dambreak.scene({"time.end": 2.0, "output.progress": False}, files=False))
    first, block = (5, 10) if quick else (20, 100)
    for _ in range(first):
        solver.step()
    blocks = []
    for _ in range(3):
        start = time.process_time()
        for _ in range(block):
            solver.step()
        blocks.append((time.process_time() - start) / block)
    return {"ms_per_step": 1e3 * min(blocks), "steps": 3 * block,
            "points": len(solver.particles) + len(getattr(solver.quadrature_points(), "fixed", ())),
            "particles": len(solver.particles)}


def right_wall_gauges(weighting: str, quick: bool) -> dict:
    """The shipped dam break's right-wall gauges against interFoam 160² (``benchmarks/wall_pressure.py``):
    noise and mean per probe, 0.3-0.6 s."""
    result, _ = wall_pressure.run(build=functools.partial(scene_solver, weighting))
    cause = result["cause"].split(": ", 1)[-1]  # after the run's "stopped at t = ... (step n): "
    return {"status": result["status"], "cause": cause, "t": result["time"],
            "probes": {name: {key: probe["fempm"].get(key) for key in ("noise", "mean_vs_interfoam")}
                       for name, probe in result["probes"].items() if name.startswith("right_")}}


def taylor_green(cells: int):
    def run(weighting: str, quick: bool) -> dict:
        n = cells // 2 if quick else cells
        return vortices.taylor_green("affine-FLIP", n, 0.4 / n, 1e-6, shifting=vortices.SHIFTING,
                                     solver_type=solver_type(weighting))
    return run


def gresho(alpha: float, surface_aware: bool = False):
    """The Gresho vortex with the volume correction ``alpha``: in a closed box the pressure is pinned at the
    lower-left function, whose continuity row goes with it, and there a crowding-only correction, which a
    closed box cannot satisfy, is taken up; the surface-aware one (``surface_aware``) takes both signs in a
    full box, whose errors sum to about zero."""
    def run(weighting: str, quick: bool) -> dict:
        return vortices.gresho("affine-FLIP", 64, 0.4 / 64, 0.5 if quick else 3.0, shifting=vortices.SHIFTING,
                               solver_type=solver_type(weighting, surface_aware), alpha=alpha)
    return run


def column_at_rest(dt: float, end: float, cells: float = 20.0, surface_aware: bool = False):
    """The column, ``cells`` cells deep (20: the dam break's; 19.5: its surface half-way up a cell), with the
    crowding-only volume correction or the ``surface_aware`` one."""
    def run(weighting: str, quick: bool) -> dict:
        return column.rest("affine-FLIP", end / 7 if quick else end, dt=dt,
                           solver_type=solver_type(weighting, surface_aware), height=cells * column.WIDTH / 10)
    return run


CASES = {
    "dambreak": dambreak_front,
    "step_cost": step_cost,
    "gauges": right_wall_gauges,
    "taylor_green_64": taylor_green(64),
    "taylor_green_128": taylor_green(128),
    "gresho": gresho(Scheme.alpha),
    "gresho_uncorrected": gresho(0.0),
    "column_1ms": column_at_rest(1e-3, 14.0),
    "column_10ms": column_at_rest(1e-2, 15.0),
    "column_mid_cell_1ms": column_at_rest(1e-3, 5.0, cells=19.5),
    "column_mid_cell_10ms": column_at_rest(1e-2, 15.0, cells=19.5),
    "gresho_surface_aware": gresho(Scheme.alpha, surface_aware=True),
    "column_1ms_surface_aware": column_at_rest(1e-3, 14.0, surface_aware=True),
    "column_10ms_surface_aware": column_at_rest(1e-2, 15.0, surface_aware=True),
}


# -- the page ------------------------------------------------------------------------------------
def _stopped(r: dict) -> str:
    return "" if r["status"] == "completed" else f" (stopped at {r['t']:.3g} s: {r['cause'].split(':')[0]})"


def _cell(case: str, r: dict | None) -> str:
    if r is None:
        return "not run"
    if case == "dambreak":
        return f"{100 * r['front']:.2f} %" + _stopped(r)
    if case == "step_cost":
        return f"{r['ms_per_step']:.2f} ms ({r['points']} points)"
    if case.startswith("taylor_green"):
        return f"{r['numerical']:.2e}" + _stopped(r)
    if case == "gauges":
        probes = r["probes"].values()
        return (" / ".join(f"{100 * p['noise']:.1f}" for p in probes) + " % (means "
                + " / ".join(f"{100 * p['mean_vs_interfoam']:+.1f}" for p in probes) + " %)" + _stopped(r))
    if case.startswith("gresho"):
        return f"{100 * r['ke']:+.2f} % / {100 * r['L']:+.3f} % / {r['crowding']:.3g}" + _stopped(r)
    return f"{r['speed']:.1e} / {r['peak']:.1e} / {100 * r['volume']:+.3f} %" + _stopped(r)


def write_page(data: dict):
    head = ["weighting", "dam-break front vs interFoam 160²", "CPU per step, dam break (quadrature points)",
            "right-wall gauges 5 / 14.6 / 29.2 / 58.4 mm: noise (mean vs interFoam 160²)", "Taylor–Green loss, 64²", "128²",
            "Gresho, 64², t = 3: KE / L / largest ρ̃/ρ", "the same, without the volume correction (α = 0)", "column, 1 ms, 14 s: speed at the end / largest (m/s) / volume",
            "column, 10 ms, 15 s: the same", "column 19.5 cells deep, 1 ms, 5 s", "the same, 10 ms, 15 s",
            "surface-aware correction: Gresho", "column, 1 ms", "column, 10 ms"]
    rows = [[name] + [_cell(case, data.get(name, {}).get(case)) for case in CASES] for name in WEIGHTINGS]
    made = data.get("made", {})
    pages.write(PAGE, pages.fill("pressure-quadrature.md", table=pages.table(head, rows), **{
        key: made.get(key, "?") for key in ("date", "commit", "machine", "load")}))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--case", nargs="+", choices=tuple(CASES), default=list(CASES))
    parser.add_argument("--weighting", nargs="+", choices=tuple(WEIGHTINGS), default=list(WEIGHTINGS))
    parser.add_argument("--quick", action="store_true", help="short runs, printed and not stored")
    parser.add_argument("--page-only", action="store_true", help="rewrite the page from the stored results")
    args = parser.parse_args(argv)
    if args.page_only:
        write_page(json.loads(RESULTS.read_text()))
        return 0
    if MPI.COMM_WORLD.size > 1:
        print("pressure_quadrature.py runs serially", file=sys.stderr)
        return 2
    made = {**{k: v for k, v in pages.provenance().items() if k != "node"},
            "load": ", ".join(f"{x:.2f}" for x in os.getloadavg())}
    new = {}
    for case in args.case:
        for name in args.weighting:
            start = time.time()
            r = CASES[case](name, args.quick)
            print(f"{case:18s} {name:26s} {_cell(case, r)}  ({time.time() - start:.0f} s)", flush=True)
            new.setdefault(name, {})[case] = r
    if not args.quick:  # merged into the stored results as they are now (another invocation may have added)
        data = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
        data = {name: cases for name, cases in data.items() if name in WEIGHTINGS}  # none of retired weightings
        for name, cases in new.items():
            data.setdefault(name, {}).update(cases)
        data["made"] = made
        pages.write(RESULTS, json.dumps(data, indent=1))
        write_page(data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
