"""Solving an assembled system on a subset of its dofs (the rest held at zero).

MPM systems have dofs that must not enter the solve: functions no particle
supports (their rows are empty) and wall conditions. The solve is restricted to
the *free* dofs by extracting the submatrix, so the factorisation is as small as
the region the material covers. PETSc options pass through the options database
under the solver's prefix, e.g. ``-fempm_ksp_type gmres``; a solver's own options are set
there only during its calls, so that a second solver under the same prefix does not inherit
them. Two sets of options are named here:

* :data:`EXACT` (the default on one rank, :func:`direct_options`): the velocity-pressure
  system reduced to its pressure Schur complement, solved to round-off. FGMRES on the
  ``full`` Schur factorisation with the velocity block by its diagonal (Jacobi) and the
  ``selfp`` complement ``S ~ D - C diag(A)^-1 B``: the pressure is a third of the unknowns,
  and as the velocity block is nearly diagonal (the mass over ``beta dt^2``) the iteration
  reaches ``rtol = 1e-13`` in a few steps, the same solution as LU to round-off. S is solved
  by what its size makes cheapest, chosen at every solve unless the options name a package
  (:func:`schur_factor_options`): PETSc's own LU with a reverse Cuthill-McKee ordering up to
  :data:`SMALL_SYSTEM` free dofs, MUMPS LU up to :data:`LARGE_SYSTEM`, and above it one
  V-cycle of algebraic multigrid as in :data:`ITERATIVE` (S couples pressures four functions
  apart, so its LU fills in fast). With the cycle each iteration gains about a decade, so the
  iteration stops at :data:`MULTIGRID_RTOL` (1e-10, a hundredth of Newton's tolerance), not at
  round-off (:func:`schur_rtol`; a ``ksp_rtol`` other than :data:`EXACT_RTOL` among the options holds
  at every size). Should the iteration fail, the system is solved again by MUMPS LU (:data:`DIRECT`).
  With these options as they are, a system of up to :data:`COMPILED_SYSTEM` free dofs (where S would be
  factored by LU) is solved by fempm's compiled solve instead (:mod:`fempm.small_system`: the same factorisation
  iterated, S's LU in RCM order, with no split, blocks or pattern to set up), by the split where it declines;
* :data:`DIRECT`: LU of the whole system by MUMPS (on several ranks sequential MUMPS on every
  rank, see :func:`direct_options`);
* :data:`ITERATIVE`: GMRES preconditioned on the right by a Schur-complement field split of the
  velocity-pressure system (Elman, Silvester & Wathen 2014, ch. 9), for large problems: the
  ``selfp`` approximation of the Schur complement ``S ~ D - C diag(A)^-1 B`` by one V-cycle of
  algebraic multigrid (hypre BoomerAMG if this PETSc has it, else PETSc's GAMG with a drop
  threshold, as the B-spline stencil is wide, and an SOR sweep on each level), the velocity block
  by its diagonal: it is the lumped mass over ``beta dt^2`` plus a viscous part smaller by
  ``~ 2 mu dt / (rho h^2)``, for which Jacobi does as well as a multigrid cycle at a fraction of
  the cost. It stops at :data:`MULTIGRID_RTOL`, as the exact solve does with S's cycle
  (``tests/test_iterative.py`` compares it with the direct solve); GMRES restarts rarely, since splashes raise the iteration count. Very viscous flows may want
  ``fieldsplit_u_pc_type = "gamg"``; an inner Krylov solve of a block makes the outer solver FGMRES
  (:func:`iterative_options`).

On one rank a multigrid cycle on S is set up when the blocks get a new pattern and kept while they keep
it (:meth:`LinearSolver.solve`): S's values change from step to step, but a cycle one step old
preconditions the same iteration to the same tolerance in about as many iterations, and its set-up is
a large share of a solve. A run renews it after each checkpoint (:meth:`LinearSolver.renew_preconditioner`),
where a resumed run sets it up afresh, so that the two go on bit for bit alike.

The field split needs the fields of the interleaved dofs; a solver given ``fields``
(e.g. ``{"u": 2, "p": 1}``) numbers the free dofs field by field on each rank and takes each
block of the split straight from the assembled matrix into a ``MATNEST``, the operator itself
(one rank, the default split: the blocks cut from the grid matrix, :mod:`fempm.schur`).
"""

from __future__ import annotations

import contextlib
import difflib
import re

import numpy as np
from petsc4py import PETSc

from fempm import collective, small_system
from fempm.errors import InputError
from fempm.schur import PATTERN_MARGIN, FreeBlocks

__all__ = ["COMPILED_SYSTEM", "DIRECT", "EXACT", "EXACT_RTOL", "ITERATIVE", "LARGE_SYSTEM", "MULTIGRID_RTOL", "SMALL_SYSTEM", "LinearSolver", "SolveFailed", "check_options",
           "direct_options", "iterative_options", "schur_factor_options", "schur_rtol", "set_options", "writing_option"]

DIRECT = {"ksp_type": "preonly", "pc_type": "lu", "pc_factor_mat_solver_type": "mumps"}
# MUMPS's parallel factorisation schedules its work dynamically, so on several ranks its
# result changes in the last bits from one run to the next (two identical 2-rank dam breaks
# part after a few dozen steps). On several ranks every rank
# therefore factors a gathered copy with sequential MUMPS: reproducible runs and restarts,
# the same numbers on any number of ranks; large problems take ITERATIVE.
_DIRECT_PARALLEL = {"ksp_type": "preonly", "pc_type": "redundant", "redundant_pc_type": "lu",
                    "redundant_pc_factor_mat_solver_type": "mumps"}


_AMG = ({"pc_type": "hypre", "pc_hypre_type": "boomeramg"} if PETSc.Sys.hasExternalPackage("hypre")
        else {"pc_type": "gamg"})
#: GAMG on the pressure: a drop threshold, since the B-spline stencil is wide; its first coarsening
#: aggressive without squaring the graph (that wide stencil's square was half the set-up); one symmetric
#: SOR sweep as each level's smoother (fewer iterations than Chebyshev's, no eigenvalue estimates to set up)
_PRESSURE_GAMG = {"pc_gamg_threshold": 0.02, "pc_gamg_aggressive_square_graph": "false",
                  "mg_levels_ksp_type": "richardson", "mg_levels_pc_type": "sor", "mg_levels_ksp_max_it": 1}
#: a pressure block (or Schur complement) by one V-cycle of algebraic multigrid
_PRESSURE_AMG = {f"fieldsplit_p_{k}": v
                 for k, v in {**_AMG, **(_PRESSURE_GAMG if _AMG["pc_type"] == "gamg" else {})}.items()}

#: The Krylov iteration's relative tolerance where S is solved by LU: a few iterations reach round-off.
EXACT_RTOL = 1e-13
#: ... and where S (or the pressure block) is solved by a multigrid cycle, each iteration of which gains about a
#: decade: a hundredth of Newton's own tolerance (``Controls.newton_rtol``).
MULTIGRID_RTOL = 1e-10

#: The Schur complement solved exactly (see the module's docstring); S's solver chosen by size, and with it
#: the tolerance (:func:`schur_rtol`) unless the options name another.
EXACT = {
    "ksp_type": "fgmres", "ksp_rtol": EXACT_RTOL, "ksp_atol": 1e-50, "ksp_max_it": 100,
    "pc_type": "fieldsplit", "pc_fieldsplit_type": "schur",
    "pc_fieldsplit_schur_fact_type": "full", "pc_fieldsplit_schur_precondition": "selfp",
    "fieldsplit_u_ksp_type": "preonly", "fieldsplit_u_pc_type": "jacobi",
    "fieldsplit_p_ksp_type": "preonly", "fieldsplit_p_pc_type": "lu",
}
#: Free dofs up to which a one-rank exact solve with the default options is fempm's compiled one
#: (:mod:`fempm.small_system`: no pattern, set-up or split to keep), PETSc's split where it declines; below
#: :data:`LARGE_SYSTEM` too, where S's LU fills in less than a multigrid cycle costs.
COMPILED_SYSTEM = 4000
#: Free dofs above which S's LU is MUMPS's rather than PETSc's own.
SMALL_SYSTEM = 1500
#: Free dofs above which S is solved by a multigrid cycle rather than LU.
LARGE_SYSTEM = 4000
#: PETSc's multigrid preconditioners: a cycle on S is kept while the blocks keep their pattern (LinearSolver)
_MULTIGRID = ("gamg", "hypre", "ml", "mg")
#: Functions by which the blocks' pattern reaches beyond the free dofs' above LARGE_SYSTEM of them (one below,
#: fempm.schur.PATTERN_MARGIN): where S's cycle is kept while the pattern stays, a wider one lasts more steps.
WIDE_PATTERN_MARGIN = 2


def _pattern_margin(seed_dofs: int) -> int:
    """The blocks' margin about a seed of ``seed_dofs`` free dofs (a function of the seed alone, so that a
    resumed run pads its restored seed as the uninterrupted run did)."""
    return WIDE_PATTERN_MARGIN if seed_dofs > LARGE_SYSTEM else PATTERN_MARGIN


_SCHUR_FACTOR_NAMES = ("fieldsplit_p_pc_factor_mat_solver_type", "fieldsplit_p_pc_factor_mat_ordering_type",
                       "fieldsplit_p_mat_mumps_icntl_7")


def schur_factor_options(free_dofs: int) -> dict:
    """How the Schur complement of a system of ``free_dofs`` is solved: PETSc's LU with reverse
    Cuthill-McKee, MUMPS's LU with approximate minimum degree (QAMD, ``ICNTL(7) = 6``; MUMPS's own
    choice, METIS on large systems, costs more in the analysis than it saves), or a multigrid cycle."""
    if free_dofs > LARGE_SYSTEM:
        return _PRESSURE_AMG
    if free_dofs > SMALL_SYSTEM:
        return {"fieldsplit_p_pc_factor_mat_solver_type": "mumps", "fieldsplit_p_mat_mumps_icntl_7": 6}
    return {"fieldsplit_p_pc_factor_mat_solver_type": "petsc", "fieldsplit_p_pc_factor_mat_ordering_type": "rcm"}


def _compiled_size(free_dofs: int) -> bool:
    """Whether a system of ``free_dofs`` is the compiled solve's: up to :data:`COMPILED_SYSTEM`, where the split
    would factor S by LU (:func:`schur_factor_options`)."""
    return free_dofs <= min(COMPILED_SYSTEM, LARGE_SYSTEM)


def schur_rtol(free_dofs: int) -> float:
    """The exact Schur solve's relative tolerance for a system of ``free_dofs``: round-off while S is solved
    by LU, :data:`MULTIGRID_RTOL` where by a multigrid cycle (:func:`schur_factor_options`)."""
    return MULTIGRID_RTOL if free_dofs > LARGE_SYSTEM else EXACT_RTOL


def direct_options(comm, fields: dict[str, int] | None = None) -> dict:
    """The exact solver's options for ``comm``: :data:`EXACT` on one rank (if ``fields``, given, hold
    a velocity ``u`` and a pressure ``p``; else :data:`DIRECT`); on several, :data:`DIRECT` made
    reproducible (every rank factors a gathered copy)."""
    if comm.size > 1:
        return {**_DIRECT_PARALLEL, "pc_redundant_number": comm.size}
    return EXACT if fields is None or {"u", "p"} <= set(fields) else DIRECT


#: The iterative solver: every block's preconditioner is one fixed linear operator (Jacobi, one multigrid
#: cycle), so GMRES preconditioned on the right iterates as FGMRES would, keeping half its vectors
#: (see :func:`iterative_options` for a user's own inner solves).
ITERATIVE = {
    "ksp_type": "gmres", "ksp_pc_side": "right", "ksp_rtol": MULTIGRID_RTOL, "ksp_atol": 1e-50, "ksp_max_it": 1000,
    "ksp_gmres_restart": 100,
    "pc_type": "fieldsplit", "pc_fieldsplit_type": "schur",
    "pc_fieldsplit_schur_fact_type": "full", "pc_fieldsplit_schur_precondition": "selfp",
    "fieldsplit_u_ksp_type": "preonly", "fieldsplit_u_pc_type": "jacobi",
    "fieldsplit_p_ksp_type": "preonly", **_PRESSURE_AMG,
}


def iterative_options(user: dict) -> dict:
    """:data:`ITERATIVE` under a user's PETSc options. Where these give a block an inner Krylov solve
    (a ``*_ksp_type`` other than ``preonly``) the preconditioner varies from one iteration to the
    next, and the outer solver is FGMRES, which allows that; where they name the outer solver, it is
    theirs, preconditioned on its own default side."""
    inner = any(k.endswith("_ksp_type") and str(v) != "preonly" for k, v in user.items() if k != "ksp_type")
    if inner or "ksp_type" in user:
        flexible = {k: v for k, v in ITERATIVE.items() if k != "ksp_pc_side"}
        return {**flexible, "ksp_type": "fgmres", **user}
    return {**ITERATIVE, **user}


class SolveFailed(RuntimeError):
    """The linear solve did not succeed (singular factorisation, no convergence, NaN)."""


def _check(reason: int, solution: np.ndarray, comm):
    """Raise :class:`SolveFailed` on every rank of ``comm`` if the KSP's converged ``reason`` is a failure or the
    solution is not finite on some rank (one rank raising alone would leave the others in the step's next
    collective call)."""
    if reason < 0:
        raise SolveFailed(f"linear solve failed: {_REASONS.get(reason, reason)}")
    if not collective.all_ranks(comm, bool(np.all(np.isfinite(solution)))):
        raise SolveFailed("linear solve produced non-finite values (singular matrix?)")


class LinearSolver:
    """A PETSc KSP applied to the free-dof block of a system.

    Args:
        comm: communicator of the matrices.
        prefix: PETSc options prefix (``-{prefix}ksp_type`` ...).
        options: PETSc options set under the prefix during this solver's calls (over the database's),
            e.g. ``{"ksp_type": "gmres"}``; :func:`direct_options` when neither these nor the
            options database choose a ``ksp_type`` or ``pc_type`` under the prefix.
        fields: components per field of the interleaved dofs (``{"u": 2, "p": 1}``);
            with ``pc_type fieldsplit`` the splits are these fields, by name.
    """

    def __init__(self, comm, prefix: str = "fempm_", options: dict | None = None,
                 fields: dict[str, int] | None = None):
        self.comm = comm
        self.prefix = prefix
        self.fields = dict(fields or {})
        opts = PETSc.Options()
        # this solver's own options, in force only during its calls (_options_in_force): another solver
        # under the same prefix then reads the database as the user left it, not these
        own = {prefix + key: value for key, value in (options or {}).items()}
        if not any(name in own or opts.hasName(name) for name in (prefix + "ksp_type", prefix + "pc_type")):
            own.update({prefix + key: value for key, value in direct_options(comm, self.fields).items()})
        with _options_in_force(own):
            self.ksp = _ksp_from_options(comm, prefix)
            fieldsplit = self.ksp.getPC().getType() == PETSc.PC.Type.FIELDSPLIT
            if not fieldsplit:  # options naming another solver: drop the default's options it does not read
                for key, value in EXACT.items():
                    name = prefix + key
                    if name in own and ("fieldsplit" in key or not opts.used(name)) and own[name] == value:
                        del own[name]
            # an exact Schur solve (S by LU) whose LU package is not named: chosen by size, MUMPS LU if it fails
            self.exact_schur = (fieldsplit and opts.getString(prefix + "fieldsplit_p_pc_type", "") == "lu"
                                and not any(opts.hasName(prefix + name) for name in _SCHUR_FACTOR_NAMES))
            # ... and its tolerance with it, unless the options name another than the default's
            self._rtol_by_size = self.exact_schur and opts.getReal(prefix + "ksp_rtol", EXACT_RTOL) == EXACT_RTOL
            # a selfp Schur split of two fields: fempm forms the complement (_selfp, or fempm.schur's)
            self.selfp = (len(self.fields) == 2 and fieldsplit
                          and opts.getString(prefix + "pc_fieldsplit_type", "") == "schur"
                          and opts.getString(prefix + "pc_fieldsplit_schur_precondition", "") == "selfp"
                          and not any(name.startswith(prefix) and "ainv" in name for name in opts.getAll()))
        self._own_options = own
        # the default exact solve, no other option: small systems by the compiled solve (fempm.small_system)
        self.compiles_small = (self.exact_schur and self.options == EXACT
                               and not any(name.startswith(prefix) for name in opts.getAll()))
        self.compiled = 0  # solves by the compiled solve
        self.compiled_declined = 0  # systems it declined (a block far from diagonal, a zero pivot, no gain) for the split
        self.fallbacks = 0  # solves the exact Schur iteration failed and MUMPS LU redid
        # one rank, a velocity and a pressure: the blocks and S cut from a grid matrix (fempm.schur)
        self.cuts_blocks = self.selfp and comm.size == 1 and list(self.fields.values()) == [2, 1]
        # a field split otherwise: its blocks taken straight from the assembled matrix into a MATNEST, the
        # operator itself (no copy of the whole free block beside them)
        self.nests_blocks = len(self.fields) > 1 and fieldsplit
        self._fallback = None
        # the last solve's (matrix, free dofs, their index set or the Schur LU's package, the block or blocks;
        # a nest's: matrix, free dofs, their index set in the nest's order, each field's, the nest)
        self._previous = None
        self._restored_seed = None  # a resumed run's blocks' seed, for its first solve (pattern_seed)
        self.reuses = 0  # solves that kept the last one's pattern
        self._renew = False  # the next solve sets the solver up afresh, as a resumed run does (renew_preconditioner)
        self._schur_pc = None  # the blocks' solver of S if a multigrid cycle, else False; None: not yet looked at

    @property
    def options(self) -> dict:
        """The options this solver sets under its prefix during its calls, over the database's (names
        without the prefix, as ``options`` is given: ``LinearSolver(comm, prefix, s.options)`` is another)."""
        return {name[len(self.prefix):]: value for name, value in self._own_options.items()}

    def solve(self, A: PETSc.Mat, b: PETSc.Vec, free: np.ndarray, x: PETSc.Vec | None = None) -> PETSc.Vec:
        """Solve ``A[free, free] x[free] = b[free]``; ``x`` is zero on the other dofs.

        A small system with the default exact options is the compiled solve's (:mod:`fempm.small_system`),
        which keeps nothing. Otherwise, when ``A`` and ``free`` are those of the last solve (the values may
        differ), or with the field split's blocks (:mod:`fempm.schur`) ``free`` lies inside the last solve's
        padded pattern, the block is extracted into the last one's storage and the solver keeps what
        depends on the pattern only (the orderings, symbolic factorisations and products).

        Args:
            A, b: the assembled system (global numbering).
            free: global indices of this rank's owned free dofs.
            x: output vector (created like ``b`` if not given).

        Raises:
            SolveFailed: the solver reports failure or the solution is not finite.
        """
        free = np.asarray(free, dtype=PETSc.IntType)
        grid = A.getAttr("fempm_grid_matrix") if self.cuts_blocks else None
        if grid is not None:
            if self.compiles_small and _compiled_size(len(free)):
                x = b.duplicate() if x is None else x
                if small_system.solve(grid, free, b.getArray(readonly=True), EXACT_RTOL, x.getArray()) > 0:
                    self.compiled += 1
                    return x
                self.compiled_declined += 1
            return self._solve_blocks(A, b, free, x)
        if self.nests_blocks:
            return self._solve_nest(A, b, free, x)
        previous = self._previous
        same = previous is not None and previous[0] is A and np.array_equal(previous[1], free) and not self._renew
        self._renew = False
        same = collective.all_ranks(self.comm, same)
        if same:  # the same block of the same matrix: its pattern, so the set-up's symbolic part, stays
            index_set, A_free = previous[2], previous[3]
            A.createSubMatrix(index_set, index_set, submat=A_free)
            self.reuses += 1
        else:
            self._release_previous()
            index_set = PETSc.IS().createGeneral(free, comm=self.comm)
            A_free = A.createSubMatrix(index_set, index_set)
            self._previous = (A, free.copy(), index_set, A_free)
        self.ksp.setOperators(A_free)
        return self._solve_on(index_set, b, x, lambda: A_free)

    def _solve_nest(self, A: PETSc.Mat, b: PETSc.Vec, free: np.ndarray, x: PETSc.Vec | None) -> PETSc.Vec:
        """:meth:`solve` with the field split's blocks cut from ``A`` into a ``MATNEST``: the free dofs
        numbered field by field on each rank, each block ``A[free_i, free_j]`` extracted once (into the
        last solve's storage while ``A`` and ``free`` stay)."""
        previous = self._previous
        same = previous is not None and previous[0] is A and np.array_equal(previous[1], free) and not self._renew
        self._renew = False
        same = collective.all_ranks(self.comm, same)
        if same:
            order, rows, nest = previous[2], previous[3], previous[4]
            for i, row in enumerate(rows):
                for j, column in enumerate(rows):
                    A.createSubMatrix(row, column, submat=nest.getNestSubMatrix(i, j))
            nest.stateIncrease()
            self.reuses += 1
        else:
            self._release_previous()
            rows = [PETSc.IS().createGeneral(part, comm=self.comm) for part in self._field_parts(free)]
            blocks = [[A.createSubMatrix(row, column) for column in rows] for row in rows]
            first = self.comm.exscan(len(free)) or 0
            splits = []
            for name, row in zip(self.fields, rows):
                splits.append((name, PETSc.IS().createStride(row.getLocalSize(), first, 1, comm=self.comm)))
                first += row.getLocalSize()
            nest = PETSc.Mat().createNest(blocks, isrows=[s for _, s in splits], iscols=[s for _, s in splits],
                                          comm=self.comm)
            for row_blocks in blocks:
                for block in row_blocks:
                    block.destroy()  # the nest holds them
            order = PETSc.IS().createGeneral(np.concatenate([row.getIndices() for row in rows]), comm=self.comm)
            self._previous = (A, free.copy(), order, rows, nest)
            self.ksp.setOperators(nest)
            self.ksp.getPC().setFieldSplitIS(*splits)
        if self.selfp:  # PETSc's own would merge A11's pattern into the product's, a copy of both
            complement = _selfp(nest)
            self.ksp.getPC().setFieldSplitSchurPreType(PETSc.PC.FieldSplitSchurPreType.USER, complement)
            complement.destroy()  # the split holds it
        return self._solve_on(order, b, x, lambda: A.createSubMatrix(order, order))

    def _solve_on(self, index_set: PETSc.IS, b: PETSc.Vec, x: PETSc.Vec | None, free_block) -> PETSc.Vec:
        """The KSP's solve (its operators set) with ``b`` on the dofs of ``index_set``; ``x`` is zero elsewhere.
        A failed exact Schur iteration is redone by LU of ``free_block()``, the block in that order."""
        b_free = b.getSubVector(index_set)
        x_free = b_free.duplicate()
        reason = self._ksp_solve(b_free, x_free, b_free.getSize())
        if reason < 0 and self.exact_schur:
            reason = self._solve_by_lu(free_block(), b_free, x_free)
        b.restoreSubVector(index_set, b_free)
        _check(reason, x_free.getArray(readonly=True), self.comm)
        if x is None:
            x = b.duplicate()
        x.zeroEntries()
        x_sub = x.getSubVector(index_set)
        x_free.copy(x_sub)
        x.restoreSubVector(index_set, x_sub)
        x_free.destroy()
        return x

    def _field_parts(self, free: np.ndarray) -> list[np.ndarray]:
        """This rank's free dofs of each field (global indices, ascending)."""
        bs = sum(self.fields.values())
        component = np.asarray(free) % bs
        parts, first = [], 0
        for n in self.fields.values():
            parts.append(free[(component >= first) & (component < first + n)])
            first += n
        return parts

    def _release_previous(self):
        """Free the last solve's set-up, block and index set before a new free set's are made: the free
        set changes between solves (the size of the operator too), and kept until replaced they
        would add to the peak of the next set-up."""
        self.ksp.reset()
        previous = self._previous
        if previous is not None and isinstance(previous[3], PETSc.Mat):
            previous[2].destroy()
            previous[3].destroy()
        elif previous is not None and len(previous) == 5:  # a nest's (_solve_nest)
            for kept in (previous[2], *previous[3], previous[4]):
                kept.destroy()
        self._previous = None

    def _ksp_solve(self, b: PETSc.Vec, x: PETSc.Vec, size: int) -> int:
        """The KSP's solve, with the Schur complement's LU package chosen by ``size`` (exact Schur
        solve); its converged reason."""
        own = self._own_options
        chosen = _over_defaults(schur_factor_options(size) if self.exact_schur else {}, own, self.prefix)
        if self._rtol_by_size:
            self.ksp.setTolerances(rtol=schur_rtol(size))
        with _options_in_force({**own, **chosen}):
            self.ksp.solve(b, x)  # the split reads its blocks' options while it sets up
        return self.ksp.getConvergedReason()

    def pattern_seed(self) -> list[list[int]] | None:
        """The free dofs the kept blocks' pattern was padded around (:mod:`fempm.schur`), as runs
        ``[first, stop)`` (a checkpoint's), or None (no blocks): what :meth:`restore_pattern` takes."""
        previous = self._previous
        if previous is None or not isinstance(previous[3], FreeBlocks):
            return None
        seed = previous[3].seed
        starts = np.flatnonzero(np.diff(seed, prepend=-2) != 1)
        stops = np.append(starts[1:], len(seed))
        return [[int(seed[a]), int(seed[b - 1]) + 1] for a, b in zip(starts, stops)]

    def restore_pattern(self, seed: list[list[int]] | None):
        """Solve as a run whose blocks had this :meth:`pattern_seed` (a resumed run, bit for bit)."""
        runs = seed or []
        self._restored_seed = np.concatenate([np.arange(a, b) for a, b in runs]) if runs else None

    def _solve_blocks(self, A: PETSc.Mat, b: PETSc.Vec, free: np.ndarray, x: PETSc.Vec | None) -> PETSc.Vec:
        """:meth:`solve` with the field split's blocks and Schur complement cut from the grid matrix
        (:class:`fempm.schur.FreeBlocks`); while the free dofs stay inside the last blocks' padded
        pattern (and the Schur complement's LU package stays) only the values are taken."""
        previous = self._previous
        package = schur_factor_options(len(free)) if self.exact_schur else {}
        kept = False
        if previous is not None and previous[0] is A and previous[2] == package and previous[3].covers(free):
            blocks = previous[3]
            blocks.refill(free)
            self.reuses += 1
            if self._renew:  # as a resumed run's first solve on these blocks: the solver set up afresh
                self._set_up(blocks)
            else:
                kept = self._keep_multigrid(True)
        else:
            seed, self._restored_seed = self._restored_seed, None  # a resumed run's, for its first solve
            if previous is not None and isinstance(previous[3], FreeBlocks):
                if previous[0] is not A:  # another matrix (rows near the water, widened): the same pattern
                    seed = previous[3].seed
                previous[3].destroy()
            blocks = self._new_blocks(A.getAttr("fempm_grid_matrix"), free, package, seed)
            self._previous = (A, free.copy(), package, blocks)
            self._set_up(blocks)
        b_free, x_free = blocks.vectors
        blocks.restrict(b.getArray(readonly=True), b_free.getArray())
        x_free.zeroEntries()  # as a new vector (a guess kept from the last solve would be another start)
        reason = self._ksp_solve(b_free, x_free, len(free))
        if reason < 0 and kept:  # the kept cycle did not do: once more with one set up for this S
            self._keep_multigrid(False)
            x_free.zeroEntries()
            reason = self._ksp_solve(b_free, x_free, len(free))
        self._renew = False
        values = np.zeros(b.getLocalSize())
        if reason < 0 and self.exact_schur:  # LU of the free block in the grid's order, as without blocks
            index_set = PETSc.IS().createGeneral(free, comm=self.comm)
            A_free = A.createSubMatrix(index_set, index_set)
            b_sub = b.getSubVector(index_set)
            x_sub = A_free.createVecRight()
            reason = self._solve_by_lu(A_free, b_sub, x_sub)
            b.restoreSubVector(index_set, b_sub)
            values[free] = x_sub.getArray(readonly=True)
        else:
            blocks.extend(x_free.getArray(readonly=True), values)
        _check(reason, values, self.comm)
        if x is None:
            x = b.duplicate()
        x.setArray(values)
        return x

    def _set_up(self, blocks: FreeBlocks):
        """The KSP reset and given ``blocks``: its next solve sets everything up, as a new solver's first does."""
        self.ksp.reset()
        self._schur_pc = None
        self.ksp.setOperators(blocks.nest)
        pc = self.ksp.getPC()
        pc.setFieldSplitIS(*blocks.index_sets)
        pc.setFieldSplitSchurPreType(PETSc.PC.FieldSplitSchurPreType.USER, blocks.schur)

    def renew_preconditioner(self):
        """Set the solver up afresh at the next solve, as a run resumed here does at its first (called after
        each checkpoint, :meth:`fempm.stepper.Stepper.resume_point`): a kept multigrid cycle, and whatever
        PETSc's set-ups carry from one to the next, would otherwise part the two runs in the last bits."""
        self._renew = True

    def _keep_multigrid(self, keep: bool) -> bool:
        """Whether this solve keeps the Schur complement's preconditioner from its last set-up: only a
        multigrid cycle, and only if ``keep`` (an LU of the last S is no preconditioner of this one: a dof
        freed or held within the pattern spoils it)."""
        if self._schur_pc is None:  # the split's solver of S, as its first set-up on these blocks made it
            pc = self.ksp.getPC().getFieldSplitSubKSP()[-1].getPC()
            self._schur_pc = pc if pc.getType() in _MULTIGRID else False
        if self._schur_pc is False:
            return False
        self._schur_pc.setReusePreconditioner(keep)
        return keep

    def _new_blocks(self, grid_matrix, free: np.ndarray, package: dict, seed: np.ndarray | None) -> FreeBlocks:
        """Blocks for ``free``: padded around ``seed`` (a resumed run's, or the last blocks' on another
        matrix) if those would have been kept (the seed's package, the free dofs inside), else
        around ``free``."""
        if seed is not None and (schur_factor_options(len(seed)) if self.exact_schur else {}) == package:
            blocks = FreeBlocks(grid_matrix, free, self.fields, seed, _pattern_margin(len(seed)))
            if blocks.covers(free):
                return blocks
            blocks.destroy()
        return FreeBlocks(grid_matrix, free, self.fields, margin=_pattern_margin(len(free)))

    def _solve_by_lu(self, A: PETSc.Mat, b: PETSc.Vec, x: PETSc.Vec) -> int:
        """Solve by MUMPS LU (:data:`DIRECT`, set here, not from the options); its converged reason."""
        if self._fallback is None:
            self._fallback = PETSc.KSP().create(self.comm)
        self._fallback.reset()
        self._fallback.setType(DIRECT["ksp_type"])
        self._fallback.getPC().setType(DIRECT["pc_type"])
        self._fallback.getPC().setFactorSolverType(DIRECT["pc_factor_mat_solver_type"])
        self._fallback.setOperators(A)
        self._fallback.solve(b, x)
        self.fallbacks += 1
        return self._fallback.getConvergedReason()


#: the ``selfp`` product on several ranks: each rank multiplies its rows by a sequential gathered copy of the
#: other factor's rows they reach (PETSc's ``seqmpi``), in less time than the default's merged scalable product
_PARALLEL_PRODUCT = {"matmatmult_via": "seqmpi"}


def _selfp(nest: PETSc.Mat) -> PETSc.Mat:
    """PETSc's ``selfp`` Schur complement ``A11 - A10 diag(A00)^-1 A01`` of a 2 x 2 ``MATNEST``, with A11
    added into the product's pattern, which holds all of its couplings in a step's system (any other is
    inserted, as PETSc would)."""
    A00, A01, A10, A11 = (nest.getNestSubMatrix(i, j) for i, j in ((0, 0), (0, 1), (1, 0), (1, 1)))
    inverse = A00.getDiagonal()
    inverse.reciprocal()
    scaled = A01.duplicate(copy=True)
    scaled.diagonalScale(L=inverse)
    with _options_in_force(_PARALLEL_PRODUCT if nest.getComm().getSize() > 1 else {}):
        complement = A10.matMult(scaled)
    scaled.destroy()
    inverse.destroy()
    complement.scale(-1.0)
    complement.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
    complement.axpy(1.0, A11, structure=PETSc.Mat.Structure.SUBSET_NONZERO_PATTERN)
    return complement


def _over_defaults(choice: dict, given: dict, prefix: str) -> dict:
    """The options of ``choice`` (names without ``prefix``) that replace :data:`EXACT`'s defaults among ``given``
    (full names), not a user's value (a cycle's drop threshold, ...): full names to values."""
    return {prefix + name: value for name, value in choice.items()
            if str(given.get(prefix + name, EXACT.get(name))) == str(EXACT.get(name))}


@contextlib.contextmanager
def _options_in_force(values: dict):
    """PETSc options (full names) set in the database for the duration of a call, then as they were."""
    opts = PETSc.Options()
    present = opts.getAll()  # reading values with getString would mark them used (a flag's value: None)
    before = {name: present[name] for name in values if name in present}
    for name, value in values.items():
        opts[name] = value
    try:
        yield
    finally:
        for name in values:
            if name in before:
                opts[name] = "" if before[name] is None else before[name]
            else:
                opts.delValue(name)


def _ksp_from_options(comm, prefix: str) -> PETSc.KSP:
    ksp = PETSc.KSP().create(comm)
    ksp.setOptionsPrefix(prefix)
    ksp.setFromOptions()
    return ksp


def set_options(options: dict, prefix: str = "fempm_"):
    """Make ``options`` the only PETSc options under ``prefix`` (earlier ones are removed)."""
    opts = PETSc.Options()
    for name in opts.getAll():
        if name.startswith(prefix):
            opts.delValue(name)
    for name, value in options.items():
        opts[prefix + name] = value


_VIEWER_NAME = re.compile(r"view|monitor|converged_reason|log|dump|save|draw|_lg_|history")
_WINDOW_NAME = re.compile(r"draw|_lg_")


def writing_option(name: str, value: str) -> str | None:
    """Why the PETSc option ``name = value`` would write a file or open a window (None: it would not).

    PETSc viewers and monitors print to the terminal when their value is empty, ``ascii``,
    ``ascii:stdout`` or ``ascii:stderr`` (with an optional ``:format``); any other viewer
    (``binary:A.dat``, ``ascii:log.txt``, ``hdf5:...``, ``draw``, ``vtk:...``, ...) writes a file
    or draws. Such options are refused, so checking a scene has no side effect.
    """
    value = str(value).strip()
    if _WINDOW_NAME.search(name):
        return "it draws in a window"
    viewer_like = _VIEWER_NAME.search(name) is not None
    if ":" not in value and not viewer_like:
        return None
    if value.lower() in ("true", "false", "yes", "no", "1", "0") and ":" not in value:
        return None  # not a viewer (PETSc says so when the option is tried)
    for part in value.split(","):
        kind, _, rest = part.partition(":")
        target = rest.split(":")[0]
        kind = kind.strip().lower()
        if kind == "draw":
            return "it draws in a window"
        if kind not in ("", "ascii"):
            return f"it writes a file (a {kind} viewer)"
        if target.strip() not in ("", "stdout", "stderr"):
            return f"it writes the file {target.strip()!r}"
    return None


def check_options(comm, names, fields: dict[str, int] | None = None, prefix: str = "fempm_",
                  where: str = "solver.petsc"):
    """Raise :class:`InputError` for the first of the option ``names`` PETSc rejects or ignores,
    or that would write a file or open a window (:func:`writing_option`; checked first, nothing
    runs with it).

    The options under ``prefix`` are tried by one solve of a small system with the
    given fields (every rank holds four functions), so options that PETSc reads only
    while setting up a preconditioner are seen too; where the exact Schur solve chooses S's
    solver by size, once more with the multigrid cycle of large systems on a system it coarsens
    (:data:`_CYCLE_TRIAL` functions a rank), so that options of that cycle
    (``fieldsplit_p_pc_gamg_threshold``, ``fieldsplit_p_pc_gamg_agg_nsmooths``, ...) count as read. An option PETSc never
    read is a misspelling or belongs to a solver not in use; its message suggests close names.
    On an error every option under ``prefix`` is removed from the options database.
    """
    names = list(names)
    opts = PETSc.Options()
    given = opts.getAll()  # reading values with getString would mark them used
    for name in names:
        value = given.get(prefix + name)
        value = "" if value is None else str(value)
        reason = writing_option(name, value)
        if reason:
            set_options({}, prefix)
            raise InputError(f"{where}.{name} = {value!r}: {reason}; PETSc options in a scene may only print to "
                             f"the terminal (e.g. {name} = \"\" or \"ascii:stdout\")")
    PETSc.Sys.pushErrorHandler("python")  # PETSc prints nothing; the error comes back here
    try:
        # S's solver by size: its cycle above LARGE_SYSTEM reads options too, on a system it coarsens
        if _trial_solve(comm, prefix, fields) and names:
            with _options_in_force(_over_defaults(_PRESSURE_AMG, opts.getAll(), prefix)):
                _trial_solve(comm, prefix, fields, _CYCLE_TRIAL)
    except PETSc.Error as e:
        culprit = _rejected_option(comm, prefix, fields, names)
        value = opts.getString(prefix + culprit, "") if culprit else ""
        set_options({}, prefix)  # nothing will run with them (and PETSc would list them as unused)
        raise InputError(_rejection_message(where, culprit, value, e)) from None
    finally:
        PETSc.Sys.popErrorHandler()
    unused = [name for name in names if not opts.used(prefix + name)]
    if unused:
        name = unused[0]
        solver = f"{opts.getString(prefix + 'ksp_type', '?')} / {opts.getString(prefix + 'pc_type', '?')}"
        set_options({}, prefix)
        close = difflib.get_close_matches(name, _KNOWN_OPTIONS, n=3)
        hint = f"; did you mean {' or '.join(close)}?" if close else ""
        raise InputError(f"{where}.{name}: PETSc did not use this option (-{prefix}{name}) with the solver set up "
                         f"({solver}): a misspelling, or an option of another solver{hint}")


#: Functions per rank of the trial system for S's multigrid cycle: enough for the cycle to coarsen (and read
#: its options of coarsening) rather than solve a single level
_CYCLE_TRIAL = 400


def _trial_solve(comm, prefix: str, fields: dict[str, int] | None, per_rank: int = 4) -> bool:
    """One solve with the options under ``prefix`` of a small well-posed block system (``per_rank`` functions on
    each rank); whether its solver chooses the Schur complement's solver by size (``LinearSolver.exact_schur``)."""
    bs = sum((fields or {"u": 1}).values())
    n = per_rank * comm.size
    A = PETSc.Mat().createAIJ(((per_rank * bs, None), (per_rank * bs, None)), bsize=1, nnz=3 * bs, comm=comm)
    A.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, False)
    first, last = A.getOwnershipRange()
    for row in range(first, last):  # a 1-D Laplacian per component, coupled to the last one
        f, c = divmod(row, bs)
        A[row, row] = 3.0
        for g in (f - 1, f + 1):
            if 0 <= g < n:
                A[row, bs * g + c] = -1.0
        if c < bs - 1:
            A[row, bs * f + bs - 1] = 0.5
            A[bs * f + bs - 1, row] = 0.5
    A.assemble()
    solver = LinearSolver(comm, prefix, fields=fields)
    b = A.createVecLeft()
    b.set(1.0)
    try:
        solver.solve(A, b, np.arange(first, last))
    except SolveFailed:
        pass  # a solver that does not converge on this system is still a valid choice of options
    finally:
        solver.ksp.destroy()
        A.destroy()
    return solver.exact_schur


def _rejected_option(comm, prefix, fields, names) -> str | None:
    """The first of ``names`` that, added in order to the ones before it, makes the trial solve fail."""
    opts = PETSc.Options()
    values = {name: opts.getString(prefix + name, None) for name in names}
    for name in names:
        opts.delValue(prefix + name)
    culprit = None
    for name in names:
        opts[prefix + name] = values[name]
        try:
            _trial_solve(comm, prefix, fields)
        except PETSc.Error:
            culprit = name
            break
    for name in names:
        opts[prefix + name] = values[name]
    return culprit


def _rejection_message(where: str, name: str | None, value: str, error: PETSc.Error) -> str:
    reason = {86: "unknown type", 62: "wrong argument value", 56: "not supported"}.get(error.ierr,
                                                                                     f"error {error.ierr}")
    if name is None:
        return f"{where}: PETSc cannot set up the solver with these options ({reason})"
    allowed = next((types for suffix, types in _ALLOWED_TYPES.items() if name.endswith(suffix)), None)
    listing = f"; allowed: {', '.join(sorted(allowed))}" if allowed else ""
    return f"{where}.{name} = {value!r}: PETSc rejects it ({reason}){listing}"


def _type_names(kind) -> list[str]:
    return [getattr(kind, a) for a in dir(kind) if a.isupper() and isinstance(getattr(kind, a), str)]


_ALLOWED_TYPES = {
    "ksp_type": _type_names(PETSc.KSP.Type),
    "pc_type": _type_names(PETSc.PC.Type),
    "pc_factor_mat_solver_type": _type_names(PETSc.Mat.SolverType),
}

# Names offered as corrections of a misspelt option (not a limit on what may be given).
_KNOWN_OPTIONS = sorted({
    *DIRECT, *_DIRECT_PARALLEL, *ITERATIVE, *EXACT, *_SCHUR_FACTOR_NAMES, "ksp_monitor", "ksp_view", "ksp_converged_reason", "ksp_gmres_restart",
    "pc_factor_mat_ordering_type", "mat_mumps_icntl_14", "mat_mumps_icntl_24", "pc_gamg_threshold",
    "pc_gamg_agg_nsmooths", "pc_hypre_boomeramg_strong_threshold", "fieldsplit_u_ksp_rtol",
    "fieldsplit_p_ksp_rtol", "fieldsplit_u_ksp_type", "fieldsplit_p_ksp_type", "pc_fieldsplit_type",
})

_REASONS = {
    getattr(PETSc.KSP.ConvergedReason, name): name
    for name in dir(PETSc.KSP.ConvergedReason)
    if name.startswith("DIVERGED")
}
