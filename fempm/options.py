"""What an implicit run is given, in three plain-data parts (no heavy imports: scenes use them).

* :class:`Physics` -- the flow: viscosity, gravity, the condition on each side of the grid;
* :class:`Scheme` -- the discretisation of method.md: time step, Newmark, volume correction,
  PSPG, the transfer, the forms file;
* :class:`Controls` -- numerical safeguards and thresholds: Newton, which functions enter the
  solve, where the matrix has rows, when a run is declared diverged, PETSc options.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fempm.errors import InputError

__all__ = ["Controls", "INITIAL_ACCELERATIONS", "PRESSURE_QUADRATURES", "PRESSURE_WORKS", "Physics", "SIDES", "Scheme", "TRANSFERS", "WALLS"]

SIDES = ("left", "right", "bottom", "top")
#: The conditions a side may have (see :class:`Physics`).
WALLS = ("slip", "no-slip", "outflow", "open")
#: The particle-grid transfers (see :class:`Scheme` and :mod:`fempm.transfer`).
TRANSFERS = ("flip", "apic", "tpic", "affine-flip")
#: where the pressure's terms are integrated (fempm.pressure_points)
PRESSURE_QUADRATURES = ("particles", "gauss")
#: how the momentum balance takes the pressure's work (:attr:`Scheme.pressure_work`)
PRESSURE_WORKS = ("divergence", "by-parts", "split", "increment")
#: how the implicit step gets Newmark's a_0 (:attr:`Scheme.initial_acceleration`)
INITIAL_ACCELERATIONS = ("solved", "given")
#: ``Controls.matrix_region = "auto"`` keeps rows only near the water above this many cells.
FLUID_REGION_CELLS = 100_000


@dataclass
class Physics:
    """The flow (SI units).

    Attributes:
        viscosity: dynamic viscosity mu.
        gravity: body acceleration.
        walls: one condition of :data:`WALLS` for all sides, or a mapping of side to condition
            (sides not named are slip): ``slip`` (zero normal velocity), ``no-slip`` (zero
            velocity), ``outflow`` (zero tangential velocity, normal traction free: the end of a
            channel whose flow is fully developed there) or ``open`` (traction free). Material that
            crosses an outflow or open side leaves the grid. Cells blocked by obstacles are no-slip.
        wall_speeds: tangential speed of moving no-slip sides (m/s), along +x on the bottom and top,
            along +y on the left and right (a lid-driven cavity: ``{"top": 1.0}``).
        recycle: with outflow on the left and right, a particle leaving through one re-enters
            through the other at the same height: an endless channel on a grid that is not periodic.
    """

    viscosity: float = 1.0e-3
    gravity: tuple[float, float] = (0.0, -9.81)
    walls: str | dict = "slip"
    wall_speeds: dict = field(default_factory=dict)
    recycle: bool = False

    def check(self):
        """Raise :class:`InputError` naming the first unacceptable value."""
        if not (np.isfinite(self.viscosity) and self.viscosity >= 0):
            raise InputError(f"viscosity must be >= 0, got {self.viscosity}")
        if not (len(self.gravity) == 2 and np.all(np.isfinite(self.gravity))):
            raise InputError(f"gravity must be two finite numbers, got {self.gravity}")
        conditions = self.wall_conditions()
        for side, kind in conditions.items():
            if side not in SIDES:
                raise InputError(f"walls: unknown side {side!r}; the sides are {SIDES}")
            if kind not in WALLS:
                raise InputError(f"walls.{side} must be one of {WALLS}, got {kind!r}")
        if self.recycle and {conditions["left"], conditions["right"]} != {"outflow"}:
            raise InputError("recycle needs outflow on the left and the right, got "
                             f"{conditions['left']!r} and {conditions['right']!r}")
        for side, speed in self.wall_speeds.items():
            if conditions.get(side) != "no-slip":
                raise InputError(f"wall_speeds.{side}: only a no-slip side can move, but {side!r} is "
                                 f"{conditions.get(side, 'not a side')!r}")
            if not np.isfinite(speed):
                raise InputError(f"wall_speeds.{side} must be a finite speed, got {speed}")

    def wall_conditions(self) -> dict[str, str]:
        """The condition on each side, ``{"left": "slip", ...}``."""
        if isinstance(self.walls, str):
            return dict.fromkeys(SIDES, self.walls)
        return {**dict.fromkeys(SIDES, "slip"), **self.walls}

    @property
    def closed(self) -> bool:
        """No side lets material out (no outflow or open side)."""
        return not {"outflow", "open"} & set(self.wall_conditions().values())


@dataclass
class Scheme:
    """The implicit scheme of method.md (SI units).

    Attributes:
        dt: the time step; with ``courant``, the largest step.
        courant: an adaptive step ``dt = C h / max |v_p|`` with this C, bounded for stability by the
            pressure's speed too (None: the step is ``dt``; :class:`fempm.stepper.StepControl`).
        beta, gamma: Newmark parameters (1/4, 1/2: the trapezoidal rule).
        alpha: the volume correction's largest share per step, the alpha of method.md eq. (3),
            0 to 1 (0: left out).
        alpha_rate: its rate per unit time (1/s): the forms' alpha is ``min(alpha, alpha_rate dt)``
            (:meth:`volume_share`). A share alpha at every step corrects at a rate ``alpha / dt``
            that grows as the step falls; below ``alpha / alpha_rate`` the share falls with the
            step instead. Above it the share stays alpha: a larger one over-corrects (at 10 times
            the seed's step a whole share per step fed the energy check).
        surface_aware: the volume correction's density error of both signs deep in the water,
            crowding only along a free surface (:mod:`fempm.density`); False: crowding only, everywhere.
        shifting: the strength ``A`` of the particle shifting after each step (:mod:`fempm.shifting`:
            particles whose neighbourhood is full move down the gradient of the particles'
            concentration, relaxing ``A`` times the spacings they moved in the step of their
            disorder, at most 1.5 times its stiffest mode); 0: none.
        shifting_keeps_angular_momentum: the shifts take a common turn so that they add no angular
            momentum (:class:`fempm.shifting.ParticleShifting`); False: positions only.
        pspg: PSPG stabilisation (method.md: without it the run diverges).
        transfer: how velocity and acceleration go between particles and grid, one of
            :data:`TRANSFERS` (:mod:`fempm.transfer`): ``flip`` (FLIP increments blended with PIC,
            the seed's), ``apic`` (Jiang et al. 2015), ``tpic`` (Nakamura et al. 2023) or
            ``affine-flip`` (APIC's affine parts, FLIP increments blended with PIC for the values;
            Fei et al. 2021). The affine kinds give the particles the fields ``affine_velocity``
            and ``affine_acceleration``.
        pic_blend: PIC share per step of ``flip`` and ``affine-flip``, 0 (FLIP) to 1 (PIC); it
            damps per unit time as 1/dt, more as the step falls.
        pic_rate: PIC share per unit time (1/s) of ``flip`` and ``affine-flip``: the share per
            step is ``min(1, pic_blend + pic_rate dt)``, a damping that does not grow as dt falls
            and that the affine parts make vanish fast as h falls. It takes the particle's whole
            difference from the grid, the resolved flow's share of it too. Without any PIC share, FLIP
            increments let a column at rest grow a grid-scale velocity mode; on Q1 a share of
            100/s does not hold it either (``apic`` does: ``tests/test_implicit.py``).
        noise_rate: the share per unit time (1/s) of ``affine-flip`` that damps only the particles'
            noise, their difference from the grid less its smooth part, after the whole share
            (:class:`fempm.transfer.NoiseFilter`: ``min(1, noise_rate dt)`` per step; a particle alone in
            its functions' support, whose difference is its own smoothing, is damped whole). 0: none.
        rest_pic_rate: PIC share per unit time (1/s) of water at rest under gravity, for ``flip`` and
            ``affine-flip``: a particle where the grid's new velocity is below
            ``transfer.REST_SPEED sqrt(|g| h)`` takes a share rising linearly as its speed falls, from
            the flowing share to ``min(1, rest_pic_rate dt)`` at zero (:func:`fempm.transfer.rest_share`).
            Still water otherwise grows slow modes from the particle quadrature's errors (a column's
            bottom corner); flowing water keeps ``pic_rate``. 0: none.
        forms: the weak forms, a file of ``forms/`` by bare name or a path to a ``.py`` file.
        initial_acceleration: Newmark's ``a_0``, one of :data:`INITIAL_ACCELERATIONS`: ``solved``
            (the first step is solved once from the particles' own ``a_0``, and its end-of-step
            acceleration, taken at the particles where they stand, becomes ``a_0``: a column
            released from rest starts with the acceleration its pressure gives it, not zero;
            :meth:`fempm.implicit.ImplicitSolver.solve_initial_acceleration`; not with moving
            walls, whose start is an impulse) or ``given`` (the particles' ``acceleration`` field
            as it is, e.g. an exact one).
        pressure_quadrature: where the implicit step integrates the pressure's work, gravity and the
            continuity, one of :data:`PRESSURE_QUADRATURES`: ``particles`` (every term there, method.md)
            or ``gauss`` (the Gauss points of the cells the water reaches, :mod:`fempm.pressure_points`,
            with ``forms/gauss_pressure.py`` in place of the default forms; one density for all material).
        pressure_work: how the momentum balance takes the pressure's work, one of :data:`PRESSURE_WORKS`:
            ``divergence`` (``-p div w``, method.md) or ``by-parts`` (``w . grad p`` where the water is deep,
            the forms' constant ``by_parts``; ``forms/incompressible.py``, ``pressure_work``): water at rest
            then balances gravity at every particle, wherever the particles stand; or ``split`` (the divergence
            form, and the hydrostatic pressure's work taken by parts, the forms' constant ``split``;
            :mod:`fempm.hydrostatic`): still water stirs far less, the Jacobian is the divergence form's; or
            ``increment`` (the split with the last step's pressure in place of the hydrostatic one: only the
            step's change of pressure works in divergence form).
    """

    dt: float = 1.0e-3
    courant: float | None = None
    beta: float = 0.25
    gamma: float = 0.5
    alpha: float = 0.1
    alpha_rate: float = 100.0
    surface_aware: bool = False
    shifting: float = 0.0
    shifting_keeps_angular_momentum: bool = False
    pspg: bool = True
    transfer: str = "affine-flip"
    pic_blend: float = 0.0
    pic_rate: float = 30.0
    noise_rate: float = 300.0
    rest_pic_rate: float = 300.0
    forms: str | Path = "incompressible"
    initial_acceleration: str = "solved"
    pressure_quadrature: str = "particles"
    pressure_work: str = "divergence"

    def step_forms(self) -> str | Path:
        """The forms a step compiles: :attr:`forms`; with the Gauss points' quadrature, the shipped
        ``gauss_pressure`` in place of the default ``incompressible``."""
        if self.pressure_quadrature == "gauss" and str(self.forms) == "incompressible":
            return "gauss_pressure"
        return self.forms

    def check(self):
        """Raise :class:`InputError` naming the first unacceptable value."""
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise InputError(f"dt must be positive, got {self.dt}")
        if self.courant is not None and not (np.isfinite(self.courant) and 0 < self.courant <= 10):
            raise InputError(f"courant must be in (0, 10] or None, got {self.courant}")
        if not (0 < self.beta <= 0.5 and 0 < self.gamma <= 1):
            raise InputError(f"Newmark needs 0 < beta <= 1/2 and 0 < gamma <= 1, got {self.beta}, {self.gamma}")
        if not 0 <= self.alpha <= 1:
            raise InputError(f"alpha (volume correction) must be in [0, 1], got {self.alpha}")
        if not (np.isfinite(self.alpha_rate) and self.alpha_rate > 0):
            raise InputError(f"alpha_rate (volume correction) must be a finite number > 0 (1/s), got {self.alpha_rate}")
        if not (np.isfinite(self.shifting) and self.shifting >= 0):
            raise InputError(f"shifting must be a finite number >= 0, got {self.shifting}")
        if not 0 <= self.pic_blend <= 1:
            raise InputError(f"pic_blend must be in [0, 1], got {self.pic_blend}")
        if self.transfer not in TRANSFERS:
            raise InputError(f"transfer must be one of {TRANSFERS}, got {self.transfer!r}")
        if self.pressure_quadrature not in PRESSURE_QUADRATURES:
            raise InputError(f"pressure_quadrature must be one of {PRESSURE_QUADRATURES}, got {self.pressure_quadrature!r}")
        if self.pressure_work not in PRESSURE_WORKS:
            raise InputError(f"pressure_work must be one of {PRESSURE_WORKS}, got {self.pressure_work!r}")
        if not (np.isfinite(self.pic_rate) and self.pic_rate >= 0):
            raise InputError(f"pic_rate must be a finite number >= 0 (1/s), got {self.pic_rate}")
        if not (np.isfinite(self.noise_rate) and self.noise_rate >= 0):
            raise InputError(f"noise_rate must be a finite number >= 0 (1/s), got {self.noise_rate}")
        if not (np.isfinite(self.rest_pic_rate) and self.rest_pic_rate >= 0):
            raise InputError(f"rest_pic_rate must be a finite number >= 0 (1/s), got {self.rest_pic_rate}")
        if self.initial_acceleration not in INITIAL_ACCELERATIONS:
            raise InputError(f"initial_acceleration must be one of {INITIAL_ACCELERATIONS}, "
                             f"got {self.initial_acceleration!r}")

    def volume_share(self, dt: float) -> float:
        """The volume correction's share of a step of size ``dt``: the forms' ``alpha``."""
        return min(self.alpha, self.alpha_rate * dt)


@dataclass
class Controls:
    """Numerical safeguards and thresholds; each scheme uses those that apply to it.

    Attributes:
        newton_rtol, newton_max_it: Newton stops when ||R|| <= rtol ||R_0|| (implicit).
        min_support_fraction: basis functions whose support holds less material than this fraction
            of ``rho int N_i dx`` are left out of the solve, held at rest: they would only add
            near-singular rows.
        min_pressure_support: the pressure of functions with less material than this fraction, or
            fewer particles in their support than a third of the functions per cell, is held at zero:
            the free-surface condition p = 0 where a function barely touches water (after Kularathna
            & Soga 2017).
        matrix_region: ``"grid"``: the matrix has a row for every function (fixed sparsity);
            ``"fluid"``: rows only near the water, rebuilt when the water leaves them; ``"auto"``:
            fluid above :data:`FLUID_REGION_CELLS` cells.
        pressure_limit: Pa; a pressure beyond it stops the run as diverged (each scheme says how;
            ``None``: the scheme's default).
        step_growth: with an adaptive step, how much larger than the previous step a step may be.
        step_retries: with an adaptive step, halvings of a failed step before the run is diverged.
        energy_gain_limit: a step after which the mechanical energy stands more than this fraction
            of its start above its lowest value so far is diverged ("energy growth": gravity and
            walls at rest only take energy away). ``None``: not checked.
        petsc_options: PETSc options under the prefix ``fempm_``.
    """

    newton_rtol: float = 1e-8
    newton_max_it: int = 8
    min_support_fraction: float = 1e-3
    min_pressure_support: float = 0.05
    matrix_region: str = "auto"
    pressure_limit: float | None = None
    energy_gain_limit: float | None = 0.1
    step_growth: float = 1.25
    step_retries: int = 3
    petsc_options: dict = field(default_factory=dict)

    def check(self):
        """Raise :class:`InputError` naming the first unacceptable value."""
        if self.matrix_region not in ("grid", "fluid", "auto"):
            raise InputError(f"matrix_region must be 'grid', 'fluid' or 'auto', got {self.matrix_region!r}")
        if self.energy_gain_limit is not None and not self.energy_gain_limit > 0:
            raise InputError(f"energy_gain_limit must be positive or None, got {self.energy_gain_limit}")
        if self.pressure_limit is not None and not self.pressure_limit > 0:
            raise InputError(f"pressure_limit must be positive or None, got {self.pressure_limit}")
        if not (self.newton_rtol > 0 and self.newton_max_it >= 1):
            raise InputError(f"Newton needs rtol > 0 and at least one iteration, got {self.newton_rtol}, "
                             f"{self.newton_max_it}")
