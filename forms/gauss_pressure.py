"""The weak forms of ``forms/incompressible.py`` with the pressure's terms at fixed Gauss points.

Chosen by ``solver.pressure_quadrature = "gauss"`` (``fempm.pressure_points``). A step integrates at two
kinds of points: the particles (``s.dx``, ``s.dx_lumped``) and the Gauss points of the cells the water
reaches (``s.dx_fixed``, where a particle field is the points' own: ``density`` the water's).

* At the particles, as in ``incompressible.py``: the lumped inertia, the viscous stress and PSPG.
* At the Gauss points, weighted by the share of water ``wet``: the pressure's work with gravity, which
  balance at rest, and the continuity (method.md eq. 1, the rows of ``p`` and ``q``; eq. 3)::

      int rho a_{n+1} . w dx_lumped - int dry rho g . w dx + int 2 mu eps_x(v_{n+1}) : eps_x(w) J* dx
    + int wet (-p J* div_x w - rho g . w) dx_fixed + int wet q volume_rate(v_{n+1}) dx_fixed
    + int (tau / rho) grad q . (r + p grad(wet) / wet) dx

``dry`` is 1 at a particle where ``wet`` is zero (gravity acts there at the particle), else 0;
``wet = clip(k rho~ / rho - (k - 1) / 2, 0, 1)``, ``k = SHARPNESS``: the smoothed fraction of water (eq. 2)
sharpened to a band half a cell wide about its half level. ``r`` is the strong momentum residual
(``incompressible.momentum_residual``); the term ``p grad(wet) / wet`` makes it that of the weighted
terms, ``grad(wet p) / wet - rho g``, so that PSPG leaves a column at rest alone. The Gauss points'
cells are those where ``wet`` may be above zero (``fempm.pressure_points.wet_threshold``): edit
``water_share`` together with ``SHARPNESS``.
"""

import ufl

from fempm import newmark
from fempm.forms.incompressible import end_divergence, momentum_residual, pspg_tau, viscous_work, volume_rate
from fempm.formsfile import switched_on  # whether a constant is non-zero now
from fempm.pressure_points import SHARPNESS

#: the share of water PSPG divides by is at least this (its correction is p grad(wet) / wet): a particle
#: thrown clear of the water, where the share is near zero and steep, otherwise gets a correction as large
#: as the pressure over a small fraction of a cell; with floors near zero the dam break's pressure blew up
#: as its jets landed, at 1/4 the jet onto the obstacle's (docs/notes-accuracy.md, the Gauss points)
WET_FLOOR = 0.5


def water_share(s, floor=0.0):
    """The share of water at a point: ``clip(k rho~ / rho - (k - 1) / 2, floor, 1)``, ``k = SHARPNESS``."""
    phi = s.grid("smoothed_density") / s.constant("density")
    return ufl.max_value(ufl.min_value(SHARPNESS * phi - (SHARPNESS - 1) / 2, 1), floor)


def dry(s):
    """1 at a particle where the share of water is zero (a drop or a thin jet, which the Gauss points'
    gravity does not reach), else 0: gravity acts there at the particle."""
    return ufl.conditional(ufl.gt(water_share(s), 0), 0, 1)


def residual(s):
    """The residual of a step (module docstring)."""
    return weighted_residual(s, water_share(s), water_share(s, WET_FLOOR))


def weighted_residual(s, wet, pspg_wet, correction=1.0):
    """The residual with the Gauss points' terms weighted by ``wet``, gravity at the particles where the
    share of water is zero (:func:`dry`) and PSPG's residual corrected by
    ``correction p grad(pspg_wet) / pspg_wet`` (``pspg_wet`` a grid expression, above zero)."""
    du, p = ufl.split(s.grid("U"))
    w, q = s.test
    rho = s.particle("density")
    dt, beta, gamma, mu = s.constant("dt"), s.constant("beta"), s.constant("gamma"), s.constant("mu")
    v_n, a_n = s.grid("grid_velocity"), s.grid("grid_acceleration")
    a_new = newmark.acceleration(du, v_n, a_n, dt, beta)
    v_new = newmark.velocity(du, v_n, a_n, dt, beta, gamma, a_new=a_new)
    g = s.constant("gravity")
    at_particles = rho * ufl.inner(a_new, w) * s.dx_lumped - dry(s) * rho * ufl.inner(g, w) * s.dx
    if switched_on(mu):
        at_particles = at_particles + viscous_work(s, mu, v_new, w) * s.dx
    balance = -p * end_divergence(s, w) - rho * ufl.inner(g, w)
    at_gauss = wet * (balance + q * volume_rate(s, v_new)) * s.dx_fixed
    if not switched_on(s.constant("pspg")):
        return at_particles + at_gauss
    v_p = s.particle("velocity")
    tau = pspg_tau(ufl.sqrt(ufl.inner(v_p, v_p)), s.constant("gravity"), dt, s.h, mu / rho)
    strong = momentum_residual(s) + correction * p * ufl.grad(pspg_wet) / pspg_wet
    return at_particles + at_gauss + s.constant("pspg") * tau / rho * ufl.inner(ufl.grad(q), strong) * s.dx
