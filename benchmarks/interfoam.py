"""OpenFOAM's interFoam on the seed's dam break: write the case, run it, read what it measured.

The case is fempm's ``scenes/dambreak.toml`` for a VOF code: a closed 0.584 m square tank
(all four walls slip), the water column 0.146 x 0.292 m in the lower-left corner, air
above (rho 1 kg/m^3, nu 1.48e-5 m^2/s), water rho 1000 kg/m^3, nu 1e-6 m^2/s, g 9.81,
surface tension 0.07 N/m; 2-D as N x N x 1 cells with empty front and back. The schemes,
solvers and adjustable time step (maxCo = maxAlphaCo = 1) are those of interFoam's damBreak
tutorial. This is how the converged references in ``data/reference/dambreak`` were made
(``../shared/reference/dambreak/interfoam_dambreak.sh``).

Measured by function objects, written rarely so that output costs nothing:
- the bottom row of cells' ``alpha.water`` every ``sample_interval`` of flow (at the first
  step past each multiple); the front is the largest x where alpha.water = 0.5 along it,
  linear between cell centres (the tank width once the last cell is wet);
- the water volume (volume integral of alpha.water) every step;
- optionally (``probes=True``) the static pressure ``p`` and ``alpha.water`` every step at
  wall points (:data:`PROBES`, cellPoint interpolation: a point 0.1 mm inside a wall reads
  the wall's value), and ``p`` at a 12 x 12 grid of cell values. The tank is closed, so
  interFoam pins p = 0 in the cell at ``pRefPoint`` (a ceiling corner), which the run-up jet
  wets later on; the probe pressure is therefore made relative to the air: each step the
  median of ``p`` over the grid points whose cell holds no water (alpha < 1e-3) is subtracted.

Only ``interFoam`` itself is timed (serial, one process). Debian's ``openfoam`` package puts
the programs on PATH; they need ``WM_PROJECT_DIR`` (for ``etc/controlDict``), set here to
Debian's ``/usr/share/openfoam`` when unset.

    from interfoam import run
    r = run(40, end_time=2.0)        # r.steps, r.wall_s, r.front_t_x, r.volume_drift
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["PROBES", "InterFoamRun", "InterFoamError", "ensure_openfoam", "front_of_rows", "read_water_speed", "run",
           "write_case"]

TANK = 0.584                 #: m, the square tank's side
COLUMN = (0.146, 0.292)      #: m, the water column's width and height
PROGRAMS = ("blockMesh", "setFields", "interFoam")
DEBIAN_PROJECT_DIR = Path("/usr/share/openfoam")
INSTALL = ["apt-get", "install", "-y", "--no-install-recommends", "openfoam"]  # the examples are not needed
_E = 1e-4                    # m: probe points this far inside a wall read the wall's value
#: wall pressure probes: name -> (x, y) in m (the columns of ``InterFoamRun.probes``)
PROBES = {
    "right_y0.005": (TANK - _E, 0.005), "right_y0.0146": (TANK - _E, 0.0146),
    "right_y0.0292": (TANK - _E, 0.0292), "right_y0.0584": (TANK - _E, 0.0584),
    "left_y0.005": (_E, 0.005), "floor_x0.292": (0.5 * TANK, _E),
    "ceiling_right_x0.57816_y0.57816": (0.99 * TANK, 0.99 * TANK),
    "ceiling_left_x0.00584_y0.57816": (0.01 * TANK, 0.99 * TANK),
}
AIR_GRID = 12                # the air level is read on an AIR_GRID x AIR_GRID grid of cell values
DRY = 1e-3                   # alpha.water below which a cell counts as air


class InterFoamError(RuntimeError):
    """interFoam (or blockMesh, setFields) failed or is missing; the message says which and why."""


@dataclass
class InterFoamRun:
    """What one interFoam run measured.

    Attributes:
        front_t_x: ``(n, 2)`` front history, t (s) and x (m), starting at (0, L).
        volume_drift: ``V(end) / V(0) - 1`` of the water volume; ``volume_drift_max`` the largest ``|.|``.
        probes: with ``probes=True``: ``{"t": times, "p": {name: Pa relative to the air},
            "alpha": {name: alpha.water}, "air_level": the solver's p subtracted}``; else None.
        water_speed: with ``water_speed=True``: ``(n, 2)``, t (s) and the water's mean speed (m/s) per step.
    """

    cells: int
    end_time: float
    steps: int
    wall_s: float
    cpu_s: float
    front_t_x: np.ndarray
    volume_drift: float
    volume_drift_max: float
    probes: dict | None = None
    water_speed: np.ndarray | None = None


# -- the programs -----------------------------------------------------------------------------------
def environment() -> dict[str, str]:
    """The process environment with ``WM_PROJECT_DIR`` set (Debian's location when unset)."""
    env = dict(os.environ)
    env.setdefault("WM_PROJECT_DIR", str(DEBIAN_PROJECT_DIR))
    return env


def ensure_openfoam(install: bool = True) -> str | None:
    """None when blockMesh, setFields and interFoam are on PATH, else why not.

    Missing programs are installed with ``apt-get install -y --no-install-recommends openfoam``
    (after ``apt-get update`` if the first try fails) when ``install`` is set and this process
    may (root, apt-get present); that takes minutes on a fresh machine.
    """
    missing = [p for p in PROGRAMS if shutil.which(p) is None]
    can_install = install and shutil.which("apt-get") is not None and os.geteuid() == 0
    if missing and can_install:
        print(f"interfoam: installing Debian's openfoam ({' '.join(INSTALL)}) ...", flush=True)
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        quiet = {"env": env, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
        if subprocess.run(INSTALL, **quiet).returncode != 0:
            subprocess.run(["apt-get", "update"], **quiet)
            subprocess.run(INSTALL, **quiet)
        missing = [p for p in PROGRAMS if shutil.which(p) is None]
    if missing:
        how = f"{' '.join(INSTALL)} failed" if can_install else f"install it as root: {' '.join(INSTALL)}"
        return f"OpenFOAM not available ({', '.join(missing)} not on PATH): {how}"
    project = Path(environment()["WM_PROJECT_DIR"])
    if not (project / "etc" / "controlDict").is_file():
        return f"OpenFOAM's etc/controlDict not found under WM_PROJECT_DIR = {project}"
    return None


# -- the case -------------------------------------------------------------------------------------
def _header(cls: str, name: str) -> str:
    return f"FoamFile\n{{\n    version 2.0;\n    format ascii;\n    class {cls};\n    object {name};\n}}\n"


def _points(xy, z: float) -> str:
    """OpenFOAM point list ``(x y z) ...``."""
    return " ".join(f"({float(x)!r} {float(y)!r} {z!r})" for x, y in xy)


def _bottom_row(cells: int) -> np.ndarray:
    """x of the bottom row's cell centres."""
    return (np.arange(cells) + 0.5) * TANK / cells


def _air_grid() -> list[tuple[float, float]]:
    c = (np.arange(AIR_GRID) + 0.5) * TANK / AIR_GRID
    return [(x, y) for y in c for x in c]


def write_case(folder: str | Path, cells: int, end_time: float, probes: bool = False,
               sample_interval: float = 0.005, water_speed: bool = False) -> Path:
    """Write the dam break's interFoam case into ``folder`` (created), ``cells`` x ``cells`` cells.

    ``cells`` must be a multiple of 4 (the column's edges then lie on cell faces). Fields are
    written once, at ``end_time``; the front row every ``sample_interval`` s of flow; with
    ``water_speed`` the water's mean speed every step (:func:`read_water_speed`).
    """
    if cells < 4 or cells % 4:
        raise ValueError(f"cells must be a positive multiple of 4, got {cells}")
    folder = Path(folder)
    for sub in ("0", "constant", "system"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    W, dz = TANK, TANK / cells
    zc = 0.5 * dz  # mid-depth of the one-cell-thick mesh
    files = {}
    files["system/blockMeshDict"] = _header("dictionary", "blockMeshDict") + f"""
scale 1;
vertices ( (0 0 0) ({W} 0 0) ({W} {W} 0) (0 {W} 0) (0 0 {dz!r}) ({W} 0 {dz!r}) ({W} {W} {dz!r}) (0 {W} {dz!r}) );
blocks ( hex (0 1 2 3 4 5 6 7) ({cells} {cells} 1) simpleGrading (1 1 1) );
edges ();
boundary
(
    leftWall   {{ type wall; faces ((0 4 7 3)); }}
    rightWall  {{ type wall; faces ((1 2 6 5)); }}
    lowerWall  {{ type wall; faces ((0 1 5 4)); }}
    top        {{ type wall; faces ((3 7 6 2)); }}
    frontAndBack {{ type empty; faces ((0 3 2 1) (4 5 6 7)); }}
);
mergePatchPairs ();
"""
    # the box reaches 0.1 mm past the column so that the cells inside it are caught whole
    files["system/setFieldsDict"] = _header("dictionary", "setFieldsDict") + f"""
defaultFieldValues ( volScalarFieldValue alpha.water 0 );
regions ( boxToCell {{ box (0 0 -1) ({COLUMN[0] + 1e-4!r} {COLUMN[1] + 1e-4!r} 1);
          fieldValues ( volScalarFieldValue alpha.water 1 ); }} );
"""

    def field(cls, name, dimensions, internal, walls):
        return _header(cls, name) + f"""
dimensions {dimensions};
internalField uniform {internal};
boundaryField
{{
    "(leftWall|rightWall|lowerWall|top)" {{ {walls} }}
    frontAndBack {{ type empty; }}
}}
"""
    files["0/U"] = field("volVectorField", "U", "[0 1 -1 0 0 0 0]", "(0 0 0)", "type slip;")
    files["0/p_rgh"] = field("volScalarField", "p_rgh", "[1 -1 -2 0 0 0 0]", "0",
                             "type fixedFluxPressure; value uniform 0;")
    files["0/alpha.water.orig"] = field("volScalarField", "alpha.water", "[0 0 0 0 0 0 0]", "0",
                                        "type zeroGradient;")
    files["constant/g"] = (_header("uniformDimensionedVectorField", "g")
                           + "dimensions [0 1 -2 0 0 0 0]; value (0 -9.81 0);\n")
    files["constant/turbulenceProperties"] = _header("dictionary", "turbulenceProperties") + "simulationType laminar;\n"
    files["constant/transportProperties"] = _header("dictionary", "transportProperties") + """
phases (water air);
water { transportModel Newtonian; nu 1e-06; rho 1000; }
air   { transportModel Newtonian; nu 1.48e-05; rho 1; }
sigma 0.07;
"""
    probe_objects = ""
    if probes:
        probe_objects = f"""
    probes
    {{
        type probes; libs (sampling); writeControl timeStep; writeInterval 1;
        fields (p alpha.water); interpolationScheme cellPoint; fixedLocations true;
        probeLocations ( {_points(PROBES.values(), zc)} );
    }}
    airGrid
    {{
        type probes; libs (sampling); writeControl timeStep; writeInterval 1;
        fields (p alpha.water); interpolationScheme cell; fixedLocations true;
        probeLocations ( {_points(_air_grid(), zc)} );
    }}
"""
    speed_objects = """
    speed { type mag; libs (fieldFunctionObjects); field U; result speed; writeControl none; }
    waterSpeed
    {
        type volFieldValue; libs (fieldFunctionObjects); writeControl timeStep; writeInterval 1; log false;
        fields (speed); operation weightedVolAverage; weightField alpha.water; regionType all; writeFields false;
    }
""" if water_speed else ""
    bottom = _points(((x, 0.5 * dz) for x in _bottom_row(cells)), zc)
    files["system/controlDict"] = _header("dictionary", "controlDict") + f"""
application interFoam;
startFrom startTime; startTime 0; stopAt endTime; endTime {end_time!r};
deltaT 0.001;
writeControl adjustable; writeInterval {end_time!r};
purgeWrite 0; writeFormat ascii; writePrecision 8; writeCompression off;
timeFormat general; timePrecision 8; runTimeModifiable no;
adjustTimeStep yes; maxCo 1; maxAlphaCo 1; maxDeltaT 1;
functions
{{
    front
    {{
        type sets; libs (sampling); writeControl runTime; writeInterval {sample_interval!r};
        setFormat raw; interpolationScheme cell; fields (alpha.water);
        sets ( bottom {{ type cloud; axis x; points ( {bottom} ); }} );
    }}
    volume
    {{
        type volFieldValue; libs (fieldFunctionObjects); writeControl timeStep; writeInterval 1; log false;
        fields (alpha.water); operation volIntegrate; regionType all; writeFields false;
    }}
{probe_objects}{speed_objects}}}
"""
    files["system/fvSchemes"] = _header("dictionary", "fvSchemes") + """
ddtSchemes { default Euler; }
gradSchemes { default Gauss linear; }
divSchemes
{
    div(rhoPhi,U)  Gauss linearUpwind grad(U);
    div(phi,alpha)  Gauss vanLeer;
    div(phirb,alpha) Gauss linear;
    div(((rho*nuEff)*dev2(T(grad(U))))) Gauss linear;
}
laplacianSchemes { default Gauss linear corrected; }
interpolationSchemes { default linear; }
snGradSchemes { default corrected; }
"""
    files["system/fvSolution"] = _header("dictionary", "fvSolution") + f"""
solvers
{{
    "alpha.water.*"
    {{
        nAlphaCorr 2; nAlphaSubCycles 1; cAlpha 1; MULESCorr yes; nLimiterIter 5;
        solver smoothSolver; smoother symGaussSeidel; tolerance 1e-8; relTol 0;
    }}
    "pcorr.*" {{ solver PCG; preconditioner DIC; tolerance 1e-5; relTol 0; }}
    p_rgh {{ solver PCG; preconditioner DIC; tolerance 1e-07; relTol 0.05; }}
    p_rghFinal {{ $p_rgh; relTol 0; }}
    U {{ solver smoothSolver; smoother symGaussSeidel; tolerance 1e-06; relTol 0; }}
}}
PIMPLE
{{
    momentumPredictor no; nOuterCorrectors 1; nCorrectors 3; nNonOrthogonalCorrectors 0;
    pRefPoint ({0.99 * W!r} {0.99 * W!r} {zc!r}); pRefValue 0;
}}
relaxationFactors {{ equations {{ ".*" 1; }} }}
"""
    for name, text in files.items():
        (folder / name).write_text(text)
    shutil.copy(folder / "0" / "alpha.water.orig", folder / "0" / "alpha.water")
    return folder


# -- running ---------------------------------------------------------------------------------------
def _program(name: str, folder: Path) -> float:
    """Run one OpenFOAM program in the case folder (log in ``log.<name>``); its wall time in s."""
    start = time.perf_counter()
    with open(folder / f"log.{name}", "w") as log:
        done = subprocess.run([name], cwd=folder, env=environment(), stdout=log, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - start
    text = (folder / f"log.{name}").read_text()
    if done.returncode != 0 or (name == "interFoam" and "\nEnd" not in text):
        tail = "\n".join(text.splitlines()[-20:])
        raise InterFoamError(f"{name} failed (exit status {done.returncode}) in {folder}:\n{tail}")
    return wall


def run(cells: int, end_time: float, probes: bool = False, folder: str | Path | None = None,
        sample_interval: float = 0.005, water_speed: bool = False) -> InterFoamRun:
    """Write, mesh, initialise and run the case; parse its front, volume and probes.

    ``folder``: where to keep the case (default: a temporary folder, removed afterwards).

    Raises:
        InterFoamError: OpenFOAM is missing or one of its programs failed.
    """
    reason = ensure_openfoam()
    if reason:
        raise InterFoamError(reason)
    keep = folder is not None
    case = Path(folder) if keep else Path(tempfile.mkdtemp(prefix=f"interfoam-dambreak-{cells}-"))
    try:
        write_case(case, cells, end_time, probes, sample_interval, water_speed)
        _program("blockMesh", case)
        _program("setFields", case)
        wall = _program("interFoam", case)
        log = (case / "log.interFoam").read_text().splitlines()
        steps = sum(line.startswith("Time = ") for line in log)
        cpu = float([line for line in log if line.startswith("ExecutionTime")][-1].split()[2])
        drift, drift_max = read_volume(case, cells)
        return InterFoamRun(cells=cells, end_time=end_time, steps=steps, wall_s=wall, cpu_s=cpu,
                            front_t_x=read_front(case, cells), volume_drift=drift, volume_drift_max=drift_max,
                            probes=read_probes(case) if probes else None,
                            water_speed=read_water_speed(case) if water_speed else None)
    finally:
        if not keep:
            shutil.rmtree(case, ignore_errors=True)


# -- reading what it measured -------------------------------------------------------------------------
def front_of_rows(alpha: np.ndarray) -> np.ndarray:
    """The front of each row of bottom-row alpha.water values ``(n, cells)``: the largest x where
    alpha = 0.5, linear between cell centres; 0 when no cell is wet, the tank width when the last is."""
    alpha = np.atleast_2d(alpha)
    n, cells = alpha.shape
    xc = _bottom_row(cells)
    wet = alpha > 0.5
    last = np.where(wet.any(axis=1), cells - 1 - np.argmax(wet[:, ::-1], axis=1), -1)
    front = np.where(last == cells - 1, TANK, 0.0)
    inner = (last >= 0) & (last < cells - 1)
    i, r = last[inner], np.flatnonzero(inner)
    a0, a1 = alpha[r, i], alpha[r, i + 1]
    front[inner] = xc[i] + (a0 - 0.5) / (a0 - a1) * (xc[i + 1] - xc[i])
    return front


def read_front(case: Path, cells: int) -> np.ndarray:
    """The front history ``(t, x)`` from the ``front`` sets, starting at the column's edge at t = 0."""
    times, rows = [], []
    for sample in (case / "postProcessing" / "front").iterdir():
        files = list(sample.glob("bottom*"))
        if files:
            values = np.loadtxt(files[0], comments="#", ndmin=2)[:, -1]
            if values.size != cells:
                raise InterFoamError(f"{files[0]}: {values.size} values, expected {cells}")
            times.append(float(sample.name))
            rows.append(values)
    order = np.argsort(times)
    history = np.column_stack([np.asarray(times)[order], front_of_rows(np.asarray(rows)[order])])
    if history[0, 0] > 0:
        history = np.vstack([[0.0, COLUMN[0]], history])  # the set-up: the column's edge, exact on these meshes
    return history


def read_volume(case: Path, cells: int) -> tuple[float, float]:
    """``V(end)/V0 - 1`` and ``max |V/V0 - 1|`` of the water volume, V0 the column's (one cell thick)."""
    files = sorted((case / "postProcessing" / "volume").glob("*/*.dat"))
    table = np.vstack([np.loadtxt(f, comments="#", ndmin=2) for f in files])
    volume = table[np.argsort(table[:, 0]), 1]
    v0 = COLUMN[0] * COLUMN[1] * TANK / cells
    return float(volume[-1] / v0 - 1), float(np.max(np.abs(volume / v0 - 1)))


def read_water_speed(case: Path) -> np.ndarray:
    """``(t, mean speed)`` per step: ``|U|`` averaged over the water, ``sum alpha |U| V / sum alpha V``."""
    files = sorted((case / "postProcessing" / "waterSpeed").glob("*/*.dat"))
    if not files:
        raise InterFoamError(f"{case}: no waterSpeed output")
    table = np.vstack([np.loadtxt(f, comments="#", ndmin=2) for f in files])
    return table[np.argsort(table[:, 0], kind="stable")][:, :2]


def _probe_series(case: Path, name: str, field: str, columns: int) -> tuple[np.ndarray, np.ndarray]:
    files = sorted((case / "postProcessing" / name).glob(f"*/{field}"))
    if not files:
        raise InterFoamError(f"{case}: no {name} output for {field}")
    table = np.vstack([np.loadtxt(f, comments="#", ndmin=2) for f in files])
    if table.shape[1] != 1 + columns:
        raise InterFoamError(f"{files[0]}: {table.shape[1] - 1} probe columns, expected {columns}")
    table = table[np.argsort(table[:, 0], kind="stable")]
    return table[:, 0], table[:, 1:]


def read_probes(case: Path) -> dict:
    """The wall probes' pressure relative to the air, their alpha.water, and the air level, per step."""
    t, p = _probe_series(case, "probes", "p", len(PROBES))
    _, alpha = _probe_series(case, "probes", "alpha.water", len(PROBES))
    _, grid_p = _probe_series(case, "airGrid", "p", AIR_GRID**2)
    _, grid_alpha = _probe_series(case, "airGrid", "alpha.water", AIR_GRID**2)
    dry = grid_alpha < DRY
    if np.any(dry.sum(axis=1) < 10):
        raise InterFoamError(f"{case}: fewer than 10 dry air-grid points at some step: no air level")
    level = np.nanmedian(np.where(dry, grid_p, np.nan), axis=1)
    return {"t": t, "p": {n: p[:, k] - level for k, n in enumerate(PROBES)},
            "alpha": {n: alpha[:, k] for k, n in enumerate(PROBES)}, "air_level": level}
