"""The study's blended weak forms (``benchmarks/pressure_quadrature.py``): ``forms/incompressible.py`` with the
pressure's terms split between the Gauss points and the particles by a weight ``D``, a ramp of the smoothed
fraction of water ``phi = rho~ / rho`` (eq. 2) from 0 at the points' ``blend_low`` to 1 at their ``blend_high``::

    D = clip((phi - blend_low) / (blend_high - blend_low), 0, 1)

The continuity (method.md eq. 3) is blended always; the pressure's work with gravity (eq. 1, the rows of ``p``),
which balance at rest, where the points' ``blend_terms`` ``A`` is 1 (where it is 0 they stay whole at the
particles). The inertia, the viscous stress and PSPG stay at the particles::

      int rho a_{n+1} . w dx_lumped + int 2 mu eps_x(v_{n+1}) : eps_x(w) J* dx + PSPG
    + int (1 - A D) (-p J* div_x w - rho g . w) + (1 - D) q volume_rate(v_{n+1}) dx
    + int A D (-p J* div_x w - rho g . w) + D q volume_rate(v_{n+1}) dx_fixed

(gravity at the particles' ``dx`` is the default forms' ``dx_lumped`` gravity: it reads no grid function).
"""

import ufl

from fempm import newmark
from fempm.forms.incompressible import end_divergence, pspg, viscous_work, volume_rate
from fempm.formsfile import switched_on


def blend(s):
    """``D``, the Gauss points' share of the blended terms (module docstring)."""
    phi = s.grid("smoothed_density") / s.constant("density")
    low, high = s.particle("blend_low"), s.particle("blend_high")
    return ufl.max_value(ufl.min_value((phi - low) / (high - low), 1), 0)


def residual(s):
    """The blended residual (module docstring)."""
    du, p = ufl.split(s.grid("U"))
    w, q = s.test
    rho, mu, dt = s.particle("density"), s.constant("mu"), s.constant("dt")
    v_n, a_n = s.grid("grid_velocity"), s.grid("grid_acceleration")
    a_new = newmark.acceleration(du, v_n, a_n, dt, s.constant("beta"))
    v_new = newmark.velocity(du, v_n, a_n, dt, s.constant("beta"), s.constant("gamma"), a_new=a_new)
    balance = -p * end_divergence(s, w) - rho * ufl.inner(s.constant("gravity"), w)
    continuity = q * volume_rate(s, v_new)
    D, A = blend(s), s.particle("blend_terms")
    form = (rho * ufl.inner(a_new, w) * s.dx_lumped
            + ((1 - A * D) * balance + (1 - D) * continuity) * s.dx
            + (A * D * balance + D * continuity) * s.dx_fixed)
    if switched_on(mu):
        form = form + viscous_work(s, mu, v_new, w) * s.dx
    return form + pspg(s)
