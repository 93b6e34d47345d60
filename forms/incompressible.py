"""Weak forms of the stabilised implicit MPM for incompressible viscous flow (method.md).

Edit these to change the physics: fempm compiles whatever this module returns, once
per run, and integrates it with the particles as quadrature points. A demo picks
another copy with ``--forms path/to/copy.py``.

Unknowns of a step: the grid displacement increment ``du`` and the pressure ``p``,
gathered in the grid function ``U = (du, p)``. The step solves ``R(U; w, q) = 0``
for all test functions ``(w, q)``, by Newton's method with the Jacobian
``dR/dU`` that UFL derives (one iteration when ``R`` is affine in ``U``, as here;
the matrix is the block system of method.md eq. (1)).

What a form may use (see ``fempm.quadrature.Symbols``):

* particle fields: ``density`` rho_p, ``velocity`` and ``acceleration`` (the
  particle's own values at the start of the step);
* grid functions: ``U`` (the unknowns), ``grid_velocity`` v_n and
  ``grid_acceleration`` a_n (the particle values projected to the grid,
  ``v_i = sum_p m_p v_p N_i / sum_p m_p N_i``), ``smoothed_density`` (rho~ of eq. 2),
  ``deep`` (1 where a function's support lies deep in the water, else 0; see :func:`continuity`),
  ``by_parts`` (the share of the pressure's work taken by parts, 0 to 1; see :func:`pressure_work`),
  ``known_pressure`` (the pressure known at the solve whose work the split takes by parts: the hydrostatic
  one, or with ``solver.pressure_work = "increment"`` the last step's; ``fempm.hydrostatic``);
* constants: ``dt``, ``beta``, ``gamma`` (Newmark), ``mu`` (viscosity), ``density`` (the
  fluid's reference density), ``gravity``
  (a 2-vector), ``alpha`` (volume correction, 0 <= alpha <= 1), ``surface_aware`` (1 or 0,
  its density error, see :func:`continuity`), ``by_parts`` and ``split`` (1 or 0, see :func:`pressure_work`), ``pspg`` (1 or 0),
  ``convection`` (1 on a fixed grid, see :func:`convection`; 0 in the MPM, whose
  grid moves with the material).

Two measures: ``s.dx`` integrates at the particles; ``s.dx_lumped`` too, but with
the grid functions taken at the basis function being tested (nodal quadrature,
row-sum lumping): the inertia over it has the lumped mass matrix of MPM. (A third,
``s.dx_fixed``, integrates at fixed Gauss points: ``forms/gauss_pressure.py``.)

The same forms solve the FEM-only reference (``fempm.eulerian.EulerianSolver``): on a
fixed grid with Gauss quadrature, the particle fields become fields at the Gauss points
(``density`` constant, ``velocity`` the previous step's grid velocity), ``grid_velocity``
and ``grid_acceleration`` the previous step's solution, and ``dx_lumped`` is ``dx``
(consistent mass).

A term whose switch is zero when the form is compiled (``mu`` = 0, ``alpha`` = 0,
``pspg`` = 0, ``convection`` = 0) is left out of the form, so its kernel never computes it: forms are
compiled once per run and these constants do not change during a run (see
:func:`switched_on`); ``dt`` at compilation is the run's largest step.
"""

import numpy as np
import ufl

from fempm import newmark
from fempm.formsfile import constant_value, switched_on  # a constant's value now; whether non-zero now
from fempm.walls import SPEED_TOLERANCE  # motion slower than this times sqrt(|g| h) is rest


def eps(w):
    """Symmetric gradient ``eps(w) = (grad w + grad w^T) / 2``."""
    return ufl.sym(ufl.grad(w))


#: PSPG's transient time under gravity, in units of gravity's time on a cell sqrt(h / |g|) (see pspg_tau)
TAU_GRAVITY_TIME = 0.025
#: the share of a cell PSPG may move water by in a step under gravity, dt tau |g| / h (see pspg_tau)
TAU_STEP_DISPLACEMENT = 0.0015


def pspg_tau(speed, gravity, dt, h, nu):
    """PSPG parameter (after Tezduyar, Mittal, Ray & Shih 1992; Tezduyar 1992, AAM 28)::

        tau0 = ((2 / T)^2 + (2 |v| / h)^2 + (4 nu / h^2)^2)^(-1/2),
        T = TAU_GRAVITY_TIME sqrt(h / |g|)
        tau = tau0 / max(1, dt tau0 |g| / (TAU_STEP_DISPLACEMENT max(h, |v| sqrt(h / |g|))))

    the transient, advective and viscous limits, whichever is smallest dominating. Tezduyar's
    transient limit has ``T = dt``: tau, and with it the stabilised problem, then follows the step
    (Hsu, Bazilevs, Calo, Tezduyar & Hughes 2010 discuss the small steps' side). Under gravity the
    dam break's wall pressure rose as dt fell, and at large adaptive steps the larger tau slowed the
    front (README, "Where fempm departs from method.md"). Here the transient time is a fixed
    fraction of the time gravity takes to move water by a cell, whatever the step; without gravity
    ``T = dt``.

    The last line bounds PSPG's own displacement in a step, ``dt tau |g|``. It moves the particles,
    and where they stand is the next step's quadrature: a loop closed explicitly, stable only while
    that displacement is a small share of a cell (at the shipped grid's largest adaptive step, 10 ms,
    a column at rest grew a vertical mode). Where the flow itself carries a particle further than a
    cell in gravity's time on a cell, the bound is relaxed in proportion: there the flow, not PSPG,
    moves the particles (bounded whatever the flow's speed, the dam break at a fixed 10 ms lost its stability). Steps
    below ``TAU_STEP_DISPLACEMENT / TAU_GRAVITY_TIME * 2 sqrt(h / |g|)`` (0.12 sqrt(h / |g|)) keep ``tau0``.
    """
    g = ufl.sqrt(ufl.inner(gravity, gravity))
    rate = ufl.conditional(ufl.gt(g, 0), 2 / TAU_GRAVITY_TIME * ufl.sqrt(g / h), 2 / dt)
    tau = (rate**2 + (2 * speed / h) ** 2 + (4 * nu / h**2) ** 2) ** -0.5
    carried = speed * ufl.sqrt(h / g)  # how far the flow carries the particle in gravity's time on a cell
    displacement = dt * tau * g / (TAU_STEP_DISPLACEMENT * ufl.max_value(h, carried))
    return ufl.conditional(ufl.gt(g, 0), tau / ufl.max_value(1, displacement), tau)


#: the largest |grad(dt v_n)| the predicted end-of-step map takes at face value (see end_map)
MAP_LIMIT = 0.25


def end_map(s):
    """The material's predicted map over the step, ``F* = I + G`` with ``G = grad(dt v_n)``.

    A Lagrangian grid moves with the material during the step, and the stresses and the
    incompressibility of ``t_{n+1}`` hold on the deformed configuration. Taken on the grid's start
    configuration instead, ``div v_{n+1} = 0`` misses it by ``O(dt |grad v|^2)``: a vortex
    rotating at rate omega expands at ~ ``2 omega^2 dt`` (the Gresho vortex's core grew, and its
    angular momentum, in proportion to dt). The map is predicted from the start of the step, so
    the forms stay linear; a step so large that it would fold (``|G|`` ~ 1: the flow crosses
    cells in a step) is limited back towards the start configuration, and water at rest has none
    (:func:`faded_at_rest`)::

        G = grad(dt v_n) / max(1, |grad(dt v_n)| / MAP_LIMIT)

    ``None`` on a fixed grid (``convection`` = 1), where nothing moves.
    """
    if switched_on(s.constant("convection")):
        return None
    G = ufl.grad(s.constant("dt") * s.grid("grid_velocity"))
    G = G / ufl.max_value(1, ufl.sqrt(ufl.inner(G, G)) / MAP_LIMIT)
    return ufl.Identity(2) + faded_at_rest(s, G)


def faded_at_rest(s, G):
    """The map's gradient where the grid moves no faster than water at rest under gravity::

        G |G|^2 / (|G|^2 + G_rest^2),   G_rest = SPEED_TOLERANCE dt sqrt(|g| / h)

    ``G_rest`` is a step's strain at the speed the walls take for rest, ``SPEED_TOLERANCE
    sqrt(|g| h)`` (``fempm.walls``), over a cell. Still water's grid velocity is the transfer's
    noise, and a map built from it puts into the pressure's work ``-p grad w : cof G`` a force
    linear in ``dt v_n``: the pressure's level times what the particle quadrature makes of the
    null Lagrangian ``grad w : cof G``, no gradient, of either sign, fed back every step; under
    a resting column's hydrostatic pressure it grew a mode in the bottom corner, where the level
    is largest and the quadrature poorest. Faded as ``|G|^3`` below ``G_rest``, the map feeds
    back nothing linear there; at ``|G| >> G_rest`` it is whole. Without gravity ``G_rest = 0``.
    """
    g = ufl.sqrt(ufl.inner(s.constant("gravity"), s.constant("gravity")))
    rest = SPEED_TOLERANCE * s.constant("dt") * ufl.sqrt(g / s.h)
    GG = ufl.inner(G, G)
    return G * ufl.conditional(ufl.gt(GG, 0), GG / (GG + rest**2), 0)


def end_divergence(s, w):
    """``J* div_x w = tr(grad w . J* F*^-1) = grad w : cof F*``: the divergence on the end-of-step
    configuration, over the start one's volume (:func:`end_map`; ``div w`` on a fixed grid).
    ``cof F*`` has no division: in 2D it is linear in ``G``."""
    F = end_map(s)
    return ufl.div(w) if F is None else ufl.inner(ufl.grad(w), ufl.cofac(F))


def viscous_work(s, mu, v, w):
    """``2 mu eps_x(v) : eps_x(w) J*`` with ``eps_x(v) = sym(grad v . F*^-1)``: the viscous stress's
    work on the end-of-step configuration (:func:`end_map`; ``2 mu eps(v) : eps(w)`` on a fixed grid)."""
    F = end_map(s)
    if F is None:
        return 2 * mu * ufl.inner(eps(v), eps(w))
    F_inv = ufl.inv(F)
    return 2 * mu * ufl.inner(ufl.sym(ufl.dot(ufl.grad(v), F_inv)), ufl.sym(ufl.dot(ufl.grad(w), F_inv))) * ufl.det(F)


def convection(s, v_new):
    """Convective acceleration of a fixed (Eulerian) grid, linearised by Oseen's rule::

        (v_n . grad) v_{n+1}

    the previous step's velocity ``v_n`` (``grid_velocity``) carries the new one: the
    step stays linear in the unknowns (semi-implicit; first-order lag in the carrier).
    A Lagrangian MPM leaves it out: its grid moves with the material for the step, and
    its particles carry the convection. ``None`` when ``convection`` is 0 (MPM), so the
    MPM kernels never compute it.
    """
    if not switched_on(s.constant("convection")):
        return None
    return s.constant("convection") * ufl.dot(ufl.grad(v_new), s.grid("grid_velocity"))


# --- the residual -------------------------------------------------------------------
def momentum(s):
    """Momentum balance, Lagrangian, weak (method.md, "Momentum"; eq. 1, first row)::

        int rho (a_{n+1} - g) . w  dx_lumped  +  int (2 mu eps_x(v_{n+1}) : eps_x(w) - p div_x w) J*  dx
        [ + int rho (v_n . grad) v_{n+1} . w  dx   on a fixed grid, see convection() ]

    The inertia is lumped (the M of eq. 1 is the lumped mass matrix ``m_i``) and uses
    the grid fields v_n, a_n, so ``m_i v_i`` is exactly the particles' momentum. A
    consistent mass with particle quadrature is singular where few particles share
    many basis functions (it then gave meaningless nodal values at the free surface
    and particles crossing the walls); a consistent mass paired with particle-valued
    v_n amplified short waves every step. The free surface is traction-free as the
    natural condition. The pressure's term is :func:`pressure_work` (by parts where the
    water is deep with ``solver.pressure_work = "by-parts"``).
    """
    du, p = ufl.split(s.grid("U"))
    w, _ = s.test
    rho = s.particle("density")
    dt, beta, gamma, mu = s.constant("dt"), s.constant("beta"), s.constant("gamma"), s.constant("mu")
    g = s.constant("gravity")
    v_n, a_n = s.grid("grid_velocity"), s.grid("grid_acceleration")
    a_new = newmark.acceleration(du, v_n, a_n, dt, beta)  # the Newmark update of method.md,
    v_new = newmark.velocity(du, v_n, a_n, dt, beta, gamma, a_new=a_new)  # see fempm/newmark.py
    stress = pressure_work(s, p, w)  # on the end-of-step configuration, see end_map()
    if switched_on(mu):
        stress = stress + viscous_work(s, mu, v_new, w)
    carried = convection(s, v_new)
    if carried is not None:
        stress = stress + rho * ufl.inner(carried, w)
    return rho * ufl.inner(a_new - g, w) * s.dx_lumped + stress * s.dx


def pressure_work(s, p, w):
    """The pressure's work in the momentum balance, ``-p J* div_x w`` (eq. 1's ``-B^T p``; see
    :func:`end_divergence`); with ``split`` = 1 (``solver.pressure_work = "split"``) the hydrostatic part's work
    taken by parts, an exact zero added (the grid function ``known_pressure``, ``H``; ``fempm.hydrostatic``)::

        -p J* div_x w + by_parts_excess(H)  =  -(p - D H) J* div_x w + w . cof F* grad(D H)

    whose integral is ``D H w . n`` on the water's edge, zero where ``D H`` vanishes at the free surfaces (``H``
    does within two cells of them; the last step's pressure, below, with ``D``). At the particles the hydrostatic pressure then balances gravity through its
    gradient, not through the quadrature's error in ``div(H w)`` times its level, and the Jacobian is the
    divergence form's (``H`` is known at the solve). With ``solver.pressure_work = "increment"`` (``split`` = 1 too)
    ``H`` is the last step's pressure: only the step's change ``p - D H`` works in divergence form, so the
    quadrature's error meets the change, not the level, of any pressure (hydrostatic, a vortex's, an impact's).
    With ``by_parts`` = 1 (``solver.pressure_work = "by-parts"``)
    the whole pressure's work is taken by parts with the weight ``D`` (the grid function ``by_parts``,
    ``fempm.density``)::

        -(1 - D) p J* div_x w + w . cof F* grad(D p)  =  -p J* div_x w + by_parts_excess

    Where ``D p`` vanishes on the water's edge the two integrate alike (the excess is a divergence, whose
    integral is ``D p w . n`` on the walls, zero for a free dof). At the particles they differ: with
    ``w . grad p`` water at rest (``grad p = rho g``) balances gravity at every particle wherever the
    particles stand, where ``-p div w - rho g . w`` leaves the hydrostatic pressure times the particle
    quadrature's error in ``div(p w)``: a force that grows with the depth and moves the particles that
    make it (a column whose particles were moved by 1e-4 of their spacing grew a circulation from its
    bottom corner to 0.2 m/s; docs/notes-accuracy.md). ``D`` is 1 in the water and falls to 0 at its
    free surface, where the pressure is small, and beside obstacles and open sides, whose faces the
    basis does not resolve; on a held wall dof the by-parts part leaves out the pressure's push on the
    wall, which :func:`wall_force_excess` gives back there.
    """
    work = -p * end_divergence(s, w)
    if switched_on(s.constant("split")):
        return work + by_parts_excess(s, s.grid("known_pressure"), w)
    return work + by_parts_excess(s, p, w) if switched_on(s.constant("by_parts")) else work


def by_parts_excess(s, p, w):
    """``D p J* div_x w + w . cof F* grad(D p)``, the divergence of ``D p cof F*^T w`` (Piola's identity,
    ``div cof F* = 0``): what taking the pressure's work by parts with the weight ``D`` adds to
    ``-p J* div_x w`` (see :func:`pressure_work`)."""
    F = end_map(s)
    C = ufl.Identity(2) if F is None else ufl.cofac(F)
    D = s.grid("by_parts")
    return D * p * end_divergence(s, w) + ufl.inner(w, ufl.dot(C, ufl.grad(D * p)))


def wall_force_excess(s):
    """The residual's excess at a held wall dof over the walls' force on the water (one-sided walls,
    ``fempm.walls``, subtract it there): :func:`by_parts_excess` of what :func:`pressure_work` takes by parts,
    ``div(D p w)`` (or ``div(D H w)`` with the split), whose integral over the water is the push ``D p w . n``
    (``D H w . n``) on the walls."""
    _, p = ufl.split(s.grid("U"))
    w, _ = s.test
    taken = s.grid("known_pressure") if switched_on(s.constant("split")) else p
    return by_parts_excess(s, taken, w) * s.dx


#: crowding the volume correction leaves alone, a share of the density (see continuity)
CROWDING_TOLERANCE = 2.0e-3
#: ``deep`` at a particle all of whose functions are deep: 1 to round-off (see continuity)
WHOLLY_DEEP = 1 - 1e-9


def continuity(s):
    """Continuity with the volume correction (method.md eq. 3, after Asai et al. 2012)::

        int q volume_rate(v_{n+1}) dx

    (see :func:`volume_rate`).
    """
    du, _ = ufl.split(s.grid("U"))
    _, q = s.test
    v_new = newmark.velocity(du, s.grid("grid_velocity"), s.grid("grid_acceleration"), s.constant("dt"),
                             s.constant("beta"), s.constant("gamma"))
    return q * volume_rate(s, v_new) * s.dx


def volume_rate(s, v_new):
    """The rate the continuity asks of ``v_{n+1}`` (method.md eq. 3, after Asai et al. 2012)::

        J* div_x v_{n+1} - (alpha / rho) max(rho~ - rho (1 + CROWDING_TOLERANCE), 0) / dt

    ``rho~`` is the smoothed density of eq. (2), ``rho~_i = sum_p W_i(x_p) m_p``,
    ``W_i = N_i / int N_i dx``: where particles crowd (rho~ > rho) the correction asks
    for expansion, ``alpha`` of the excess per step. method.md writes the correction
    for both signs, ``-(alpha/rho)(rho - rho~)/dt``; we keep only the expansion:
    at a free surface rho~ < rho by construction (the basis functions reach into
    air), and the contraction asked there squeezes a column at rest instead of
    holding it (README, "Where fempm departs from method.md"). Crowding only, thinning
    is never undone, and a free surface that moves swells. Crowding within
    ``CROWDING_TOLERANCE`` of the density is left alone: water at rest stirs its smoothed
    density by that much, and an expansion asked for every such stir, never taken back,
    swelled a column at rest.

    With ``surface_aware`` = 1 instead ``J* div_x v_{n+1} - alpha e / dt`` with, at a
    particle whose functions all lie deep in the water (the grid function ``deep``,
    ``fempm.density.DeepWater``, interpolates to 1 there), both signs ``e = rho~ / rho - 1``, and
    crowding only ``e = max(rho~ / rho - 1 - CROWDING_TOLERANCE, 0)`` in the band along a free
    surface: thinning is undone where it is not the surface's own.

    The divergence is the end-of-step one, ``J* div_x`` (see :func:`end_map`).
    """
    dt, alpha = s.constant("dt"), s.constant("alpha")
    rho = s.particle("density")
    expansion = end_divergence(s, v_new)
    if not switched_on(alpha):
        return expansion
    if switched_on(s.constant("surface_aware")):
        excess = s.grid("smoothed_density") / rho - 1
        error = ufl.conditional(ufl.ge(s.grid("deep"), WHOLLY_DEEP), excess,
                                ufl.max_value(excess - CROWDING_TOLERANCE, 0))
        return expansion - alpha * error / dt
    crowding = ufl.max_value(s.grid("smoothed_density") - rho * (1 + CROWDING_TOLERANCE), 0)
    return expansion - alpha / rho * crowding / dt


def pspg(s):
    """Pressure-stabilising Petrov-Galerkin term (Tezduyar 1992; eq. 1, K_v^stab and K_p^stab)::

        int (tau / rho) grad q . (rho (v_{n+1} - v_n) / dt + grad p - rho g
                                 - div(2 mu eps(v_{n+1}))) dx
        [ + int tau grad q . (v_n . grad) v_{n+1} dx   on a fixed grid, see convection() ]

    the strong momentum residual tested with ``grad q``; it gives the continuity rows a
    pressure diagonal, so equal-order velocity and pressure work. The residual is whole,
    viscous part included (Tezduyar 1992), so the term vanishes on the exact solution
    (steady Poiseuille flow, where viscosity balances the body force, is then exact in
    the B-spline space); where that part is negligible it is left out
    (:func:`viscous_residual_matters`). The second derivatives are taken cell by cell (C^1 B-splines:
    exact; Q1: its mixed derivative only). The inertia is the step's mean acceleration
    ``(v_{n+1} - v_n) / dt``: with the trapezoidal rule the end-point ``a_{n+1}``
    alternates in sign from step to step, and fed into the pressure it grows a
    sign-alternating pressure (README, "Where fempm departs from method.md").
    """
    _, q = s.test
    if not switched_on(s.constant("pspg")):
        return 0
    rho, v_p = s.particle("density"), s.particle("velocity")
    tau = pspg_tau(ufl.sqrt(ufl.inner(v_p, v_p)), s.constant("gravity"), s.constant("dt"), s.h, s.constant("mu") / rho)
    return s.constant("pspg") * tau / rho * ufl.inner(ufl.grad(q), momentum_residual(s)) * s.dx


def momentum_residual(s):
    """The strong momentum residual PSPG tests (see :func:`pspg`)::

        rho (v_{n+1} - v_n) / dt + grad p - rho g - div(2 mu eps(v_{n+1}))  [ + rho (v_n . grad) v_{n+1} ]
    """
    du, p = ufl.split(s.grid("U"))
    rho = s.particle("density")
    dt, beta, mu = s.constant("dt"), s.constant("beta"), s.constant("mu")
    v_n, a_n = s.grid("grid_velocity"), s.grid("grid_acceleration")
    v_new = newmark.velocity(du, v_n, a_n, dt, beta, s.constant("gamma"))
    residual = rho * (v_new - v_n) / dt + ufl.grad(p) - rho * s.constant("gravity")
    if switched_on(mu) and viscous_residual_matters(s):
        residual = residual - ufl.div(2 * mu * eps(v_new))
    carried = convection(s, v_new)
    if carried is not None:
        residual = residual + rho * carried
    return residual


#: PSPG's residual leaves its viscous part out below this diffusion number nu T / h^2 (see viscous_residual_matters)
VISCOUS_RESIDUAL_MIN = 1.0e-3


def viscous_residual_matters(s):
    """Whether PSPG's residual takes its viscous part ``div(2 mu eps(v_{n+1}))``: the diffusion
    number over PSPG's transient time ``T`` (:func:`pspg_tau`) at compilation::

        nu T / h^2 >= VISCOUS_RESIDUAL_MIN,   nu = mu / density,
        T = TAU_GRAVITY_TIME sqrt(h / |g|) under gravity, else the run's largest step

    Left out, the part would have moved the continuity rows by ``tau nu / h^2 <= nu T / (2 h^2)``
    of their divergence (``tau <= T / 2``): below the threshold less than the particle quadrature's
    own error. Taking it needs the second derivatives of the basis, whose jets double the size of
    the kernels. Water under gravity lies below the threshold on cells coarser than about 0.4 mm (the
    number grows as h^(-3/2)); slow viscous flows (Poiseuille, a 10 Pa s column) lie above it.
    """
    mu, dt, density = (constant_value(s.constant(name)) for name in ("mu", "dt", "density"))
    g = float(np.linalg.norm(np.atleast_1d(constant_value(s.constant("gravity")))))
    transient = TAU_GRAVITY_TIME * np.sqrt(s.h / g) if g > 0 else dt
    return bool(mu * transient >= VISCOUS_RESIDUAL_MIN * density * s.h**2)


def residual(s):
    """The residual of a step: momentum + continuity + PSPG (method.md eq. 1)."""
    return momentum(s) + continuity(s) + pspg(s)
