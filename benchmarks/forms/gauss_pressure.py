"""The shipped weak forms with the pressure's terms at fixed Gauss points (``benchmarks/pressure_quadrature.py``).

The step integrates at two kinds of points (``material``: 1 at a particle, 0 at a Gauss point):

* at the particles, as shipped: the lumped inertia, the viscous stress and PSPG;
* at the Gauss points of the cells around the water, weighted by their share ``wet`` of water:
  the pressure's work with gravity, which balance at rest, and the continuity::

    int wet (-p J* div_x w - rho g . w) dx_gauss,   int wet q volume_rate(v_{n+1}) dx_gauss

With ``gauss_inertia`` = 1 (at every point) the inertia is lumped at the Gauss points, weighted, instead of
at the particles. With ``correction`` = 1 at the particles, PSPG's residual is that of these terms' strong form,
``grad(wet p) / wet - rho g`` for ``grad p - rho g``, with ``wet`` the grid's sharpened smoothed
fraction ``clip(sharpness rho~ / rho - (sharpness - 1) / 2, 1e-3, 1)``: a water column at rest then
leaves PSPG's residual zero.
"""

import ufl

from fempm import newmark
from fempm.forms.incompressible import (end_divergence, momentum_residual, pspg_tau, switched_on, viscous_work,
                                        volume_rate)


def grid_wet(s):
    """The smoothed fraction of water, sharpened: ``clip(k rho~ / rho - c, 1e-3, 1)``, ``c`` the particles' ``offset``
    (``(k - 1) / 2``, or the conserving one of the study's ``conserved`` weighting)."""
    k = s.particle("sharpness")
    phi = s.grid("smoothed_density") / s.constant("density")
    return ufl.max_value(ufl.min_value(k * phi - s.particle("offset"), 1), 1.0e-3)


def residual(s):
    du, p = ufl.split(s.grid("U"))
    w, q = s.test
    rho, material, wet = s.particle("density"), s.particle("material"), s.particle("wet")
    dt, beta, gamma, mu = s.constant("dt"), s.constant("beta"), s.constant("gamma"), s.constant("mu")
    v_n, a_n = s.grid("grid_velocity"), s.grid("grid_acceleration")
    a_new = newmark.acceleration(du, v_n, a_n, dt, beta)
    v_new = newmark.velocity(du, v_n, a_n, dt, beta, gamma, a_new=a_new)
    inertia_share = material * (1 - s.particle("gauss_inertia")) + (1 - material) * wet * s.particle("gauss_inertia")
    at_particles = inertia_share * rho * ufl.inner(a_new, w) * s.dx_lumped
    if switched_on(mu):
        at_particles = at_particles + material * viscous_work(s, mu, v_new, w) * s.dx
    balance = -p * end_divergence(s, w) - rho * ufl.inner(s.constant("gravity"), w)
    at_gauss = (1 - material) * wet * (balance + q * volume_rate(s, v_new)) * s.dx
    if not switched_on(s.constant("pspg")):
        return at_particles + at_gauss
    v_p, phi = s.particle("velocity"), grid_wet(s)
    tau = pspg_tau(ufl.sqrt(ufl.inner(v_p, v_p)), s.constant("gravity"), dt, s.h, mu / rho)
    strong = momentum_residual(s) + s.particle("correction") * p * ufl.grad(phi) / phi
    return at_particles + at_gauss + material * s.constant("pspg") * tau / rho * ufl.inner(ufl.grad(q), strong) * s.dx
