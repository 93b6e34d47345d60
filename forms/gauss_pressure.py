"""The weak forms of ``forms/incompressible.py`` with the pressure's terms at fixed Gauss points.

Chosen by ``solver.pressure_quadrature = "gauss"`` (``fempm.pressure_points``). A step integrates at two
kinds of points, told apart by the particle field ``material``: 1 at a particle, 0 at a Gauss point of a
cell the water reaches.

* At the particles, as in ``incompressible.py``: the lumped inertia, the viscous stress and PSPG.
* At the Gauss points, weighted by the share of water ``wet``: the pressure's work with gravity, which
  balance at rest, and the continuity (method.md eq. 1, the rows of ``p`` and ``q``; eq. 3)::

      int rho a_{n+1} . w dx_lumped + int 2 mu eps_x(v_{n+1}) : eps_x(w) J* dx          (particles)
    + int wet (-p J* div_x w - rho g . w) dx + int wet q volume_rate(v_{n+1}) dx        (Gauss points)
    + int (tau / rho) grad q . (r + p grad(wet) / wet) dx                               (particles, PSPG)

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

#: the share of water PSPG divides by is at least this (its correction is p grad(wet) / wet)
WET_FLOOR = 1.0e-3


def water_share(s, floor=0.0):
    """The share of water at a point: ``clip(k rho~ / rho - (k - 1) / 2, floor, 1)``, ``k = SHARPNESS``."""
    phi = s.grid("smoothed_density") / s.constant("density")
    return ufl.max_value(ufl.min_value(SHARPNESS * phi - (SHARPNESS - 1) / 2, 1), floor)


def residual(s):
    """The residual of a step (module docstring)."""
    du, p = ufl.split(s.grid("U"))
    w, q = s.test
    rho, material = s.particle("density"), s.particle("material")
    dt, beta, gamma, mu = s.constant("dt"), s.constant("beta"), s.constant("gamma"), s.constant("mu")
    v_n, a_n = s.grid("grid_velocity"), s.grid("grid_acceleration")
    a_new = newmark.acceleration(du, v_n, a_n, dt, beta)
    v_new = newmark.velocity(du, v_n, a_n, dt, beta, gamma, a_new=a_new)
    at_particles = material * rho * ufl.inner(a_new, w) * s.dx_lumped
    if switched_on(mu):
        at_particles = at_particles + material * viscous_work(s, mu, v_new, w) * s.dx
    balance = -p * end_divergence(s, w) - rho * ufl.inner(s.constant("gravity"), w)
    at_gauss = (1 - material) * water_share(s) * (balance + q * volume_rate(s, v_new)) * s.dx
    if not switched_on(s.constant("pspg")):
        return at_particles + at_gauss
    v_p, wet = s.particle("velocity"), water_share(s, WET_FLOOR)
    tau = pspg_tau(ufl.sqrt(ufl.inner(v_p, v_p)), s.constant("gravity"), dt, s.h, mu / rho)
    strong = momentum_residual(s) + p * ufl.grad(wet) / wet
    return at_particles + at_gauss + material * s.constant("pspg") * tau / rho * ufl.inner(ufl.grad(q), strong) * s.dx
