"""The cases that demos, tests and benchmarks share: each case's set-up, its reference and its measure.

* :mod:`fempm.cases.dambreak` -- the seed's dam break: the shipped scene with changes, the
  surge front against the experiments and the converged interFoam run;
* :mod:`fempm.cases.hydrostatic` -- a tank of water at rest, p = rho g d;
* :mod:`fempm.cases.channel` -- plane Poiseuille and Couette flow started from rest;
* :mod:`fempm.cases.cavity` -- the lid-driven cavity at Re = 100 against Ghia et al. (1982);
* :mod:`fempm.cases.hard` -- the hard cases of the implicit scheme and the measures of an eruption;
* :mod:`fempm.cases.vortices` -- the Taylor-Green and Gresho vortices in the closed slip box: what
  the particle-grid transfer dissipates;
* :mod:`fempm.cases.column` -- the dam-break column held at rest: volume and speeds.

What the cases share (timed runs, sampling, :class:`~fempm.verification.Measurement`, rates) is
:mod:`fempm.verification`. The demos (``demos/``) show the cases as literate scripts; the
benchmarks (``benchmarks/``) run their studies and write the pages of ``docs/``.
"""
