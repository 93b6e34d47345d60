"""Forms of the explicit baseline: a weakly compressible Newtonian fluid (method.md, "Explicit comparison").

Edit these to change the physics of ``fempm.explicit``: fempm compiles the linear
form :func:`force` once per run and integrates it with the particles as quadrature
points; :func:`pressure` is evaluated at the particles with numpy arrays (it uses
arithmetic only, so the same function would also accept UFL expressions).

Strong form, in the moving material (Lagrangian, no pressure unknown)::

    rho dv/dt = div sigma + rho g,    sigma = -p I + 2 mu dev(eps(v)),
    d rho / dt = -rho div v,          p = p(rho)  (equation of state),

traction-free free surface, zero normal velocity on the walls (set on the grid).

One explicit step (forward Euler, Modified Update Stress Last, Sulsky et al. 1995)
needs only the nodal force ``f_i = -int sigma : grad N_i dx + int rho g N_i dx`` of the
stress carried by the particles; the mass is the lumped ``m_i = sum_p m_p N_i(x_p)``
(``fempm.transfer.lumped_mass``), so no matrix is assembled.

What a form may use (see ``fempm.quadrature.Symbols``):

* particle fields: ``density`` rho_p, ``pressure`` p_p, ``velocity_gradient`` L_p
  (``L[c, d] = d v_c / d x_d``, from the grid velocity of the last step);
* constants: ``mu`` (viscosity), ``gravity`` (a 2-vector).
"""

import ufl


def pressure(density, reference_density, bulk_modulus):
    """Linear equation of state (a stiffened fluid; e.g. Monaghan 1994 with gamma = 1)::

        p = K (rho / rho_0 - 1),    K = rho_0 c_0^2

    ``K`` is the bulk modulus (2.0 GPa for water in method.md's explicit run) or the
    artificial one of a chosen sound speed ``c_0`` (weakly compressible practice:
    c_0 about 10 times the largest flow speed keeps density changes near 1 %).
    Tension is allowed (p < 0 where the material has expanded).
    """
    return bulk_modulus * (density / reference_density - 1.0)


def stress(s):
    """Cauchy stress of a Newtonian fluid at the particle::

        sigma = -p I + 2 mu dev(eps(v)),    eps(v) = (L + L^T) / 2,

    ``dev`` the two-dimensional deviator ``A - tr(A) I / 2``: the viscous stress does
    no work on a pure compression, which the equation of state carries alone
    (Stokes' hypothesis, zero bulk viscosity).
    """
    L = s.particle("velocity_gradient")
    return -s.particle("pressure") * ufl.Identity(2) + 2 * s.constant("mu") * ufl.dev(ufl.sym(L))


def internal_force(s):
    """Internal force (Sulsky, Zhou & Schreyer 1995, eq. 21, particle quadrature)::

        f_i^int = - int sigma : grad N_i dx = - sum_p V_p sigma_p : grad N_i(x_p)
    """
    return -ufl.inner(stress(s), ufl.grad(s.test)) * s.dx


def gravity(s):
    """External (body) force::

        f_i^ext = int rho g . N_i dx = sum_p m_p g N_i(x_p)    (m_p = rho_p V_p)
    """
    return s.particle("density") * ufl.inner(s.constant("gravity"), s.test) * s.dx


def force(s):
    """The nodal force of a step: internal + external (the free surface is traction-free)."""
    return internal_force(s) + gravity(s)
