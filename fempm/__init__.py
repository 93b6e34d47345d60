"""fempm: a DOLFINx-assisted implicit material point method.

The material points are the quadrature points of weak forms written in UFL
(``forms/``); DOLFINx's form compiler turns each form into a kernel once per run,
fempm evaluates it at every particle and assembles PETSc objects.

``dolfinx_solver`` must be imported before ``dolfinx`` or ``petsc4py`` (it orders
MPI ahead of the compiled bindings); this module is the one place that does it.
"""

import dolfinx_solver  # noqa: F401  (must precede dolfinx / petsc4py)

from fempm.bases import BSpline2, Q1, Basis
from fempm.errors import FempmError, InputError, ParticleOutsideGridError
from fempm.grid import Grid
from fempm.particles import Particles, Polygon, Rectangle
from fempm.quadrature import GaussForm, ParticleForm, Symbols
from fempm.space import GridFunction, Space

__all__ = [
    "Basis",
    "BSpline2",
    "FempmError",
    "GaussForm",
    "Grid",
    "GridFunction",
    "InputError",
    "ParticleForm",
    "ParticleOutsideGridError",
    "Particles",
    "Polygon",
    "Q1",
    "Rectangle",
    "Space",
    "Symbols",
]
