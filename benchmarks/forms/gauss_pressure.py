"""The study's weak forms: ``forms/gauss_pressure.py`` with the share of water a field of the Gauss points
(``benchmarks/pressure_quadrature.py``) and PSPG's correction switched by the particles' ``correction``.

The step integrates at two kinds of points:

* at the particles (``s.dx``, ``s.dx_lumped``), as shipped: the lumped inertia, the viscous stress and PSPG;
* at the Gauss points of the cells around the water (``s.dx_fixed``), weighted by their share ``wet`` of
  water, which the study's weighting gives: the pressure's work with gravity, which balance at rest, and
  the continuity::

    int wet (-p J* div_x w - rho g . w) dx_fixed,   int wet q volume_rate(v_{n+1}) dx_fixed

With ``correction`` = 1 at the particles, PSPG's residual is that of these terms' strong form,
``grad(wet p) / wet - rho g`` for ``grad p - rho g``, with ``wet`` the grid's sharpened smoothed
fraction ``clip(sharpness rho~ / rho - offset, 1e-3, 1)``: a water column at rest then leaves PSPG's
residual zero.
"""

import ufl

from fempm.forms.gauss_pressure import weighted_residual


def grid_wet(s):
    """The smoothed fraction of water, sharpened: ``clip(k rho~ / rho - c, 1e-3, 1)``, ``k`` the particles'
    ``sharpness``, ``c`` their ``offset`` (``(k - 1) / 2``, or the conserving one of the ``conserved`` weighting)."""
    k = s.particle("sharpness")
    phi = s.grid("smoothed_density") / s.constant("density")
    return ufl.max_value(ufl.min_value(k * phi - s.particle("offset"), 1), 1.0e-3)


def residual(s):
    """``forms/gauss_pressure.py``'s, with the study's share of water at the Gauss points."""
    return weighted_residual(s, s.particle("wet"), grid_wet(s), s.particle("correction"))
