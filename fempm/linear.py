"""Solving an assembled system on a subset of its dofs (the rest held at zero).

MPM systems have dofs that must not enter the solve: functions no particle
supports (their rows are empty) and wall conditions. The solve is restricted to
the *free* dofs by extracting the submatrix, so the factorisation is as small as
the region the material covers. Default: LU by MUMPS. PETSc options pass through
the options database under the solver's prefix, e.g. ``-fempm_ksp_type gmres``.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

__all__ = ["LinearSolver", "SolveFailed"]


class SolveFailed(RuntimeError):
    """The linear solve did not succeed (singular factorisation, no convergence, NaN)."""


class LinearSolver:
    """A PETSc KSP applied to the free-dof block of a system.

    Args:
        comm: communicator of the matrices.
        prefix: PETSc options prefix (``-{prefix}ksp_type`` ...).
        options: PETSc options set under the prefix before the first solve,
            e.g. ``{"ksp_type": "gmres"}``; the defaults are direct LU with MUMPS.
    """

    def __init__(self, comm, prefix: str = "fempm_", options: dict | None = None):
        self.comm = comm
        self.prefix = prefix
        opts = PETSc.Options()
        options = dict(options or {})
        chosen = set(options) | {key for key in ("ksp_type", "pc_type") if opts.hasName(prefix + key)}
        if not chosen & {"ksp_type", "pc_type"}:  # nothing chosen: direct LU by MUMPS
            options = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps", **options}
        for key, value in options.items():
            opts[prefix + key] = value
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOptionsPrefix(prefix)
        self.ksp.setFromOptions()

    def solve(self, A: PETSc.Mat, b: PETSc.Vec, free: np.ndarray, x: PETSc.Vec | None = None) -> PETSc.Vec:
        """Solve ``A[free, free] x[free] = b[free]``; ``x`` is zero on the other dofs.

        Args:
            A, b: the assembled system (global numbering).
            free: global indices of this rank's owned free dofs.
            x: output vector (created like ``b`` if not given).

        Raises:
            SolveFailed: the solver reports failure or the solution is not finite.
        """
        index_set = PETSc.IS().createGeneral(np.asarray(free, dtype=PETSc.IntType), comm=self.comm)
        A_free = A.createSubMatrix(index_set, index_set)
        b_free = b.getSubVector(index_set)
        x_free = A_free.createVecRight()
        self.ksp.reset()  # the free set, so the operator's size, changes between solves
        self.ksp.setOperators(A_free)
        self.ksp.solve(b_free, x_free)
        b.restoreSubVector(index_set, b_free)
        reason = self.ksp.getConvergedReason()
        if reason < 0:
            raise SolveFailed(f"linear solve failed: {_REASONS.get(reason, reason)}")
        if not np.all(np.isfinite(x_free.getArray(readonly=True))):
            raise SolveFailed("linear solve produced non-finite values (singular matrix?)")
        if x is None:
            x = b.duplicate()
        x.zeroEntries()
        x_sub = x.getSubVector(index_set)
        x_free.copy(x_sub)
        x.restoreSubVector(index_set, x_sub)
        return x


_REASONS = {
    getattr(PETSc.KSP.ConvergedReason, name): name
    for name in dir(PETSc.KSP.ConvergedReason)
    if name.startswith("DIVERGED")
}
