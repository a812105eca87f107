"""Set-up selection: the fewest fixed tool axes (3+2 set-ups) covering the cloud, with the least overlap.

Pipeline step 5 of ``docs/design.md``; the method is Makki et al. 2010, §3 ("Point cloud segmentation",
§3.1 "Global segmentation method"), made exact:

1. axes that see fewer than ``min_points`` points are dropped (the "reduced visibility matrix");
2. the smallest ``k <= max_setups`` for which some ``k`` axes see at least ``ceil(P_a * n)`` points
   (``n`` counts every point, also those no axis sees);
3. among those ``k``-subsets the one with the fewest points seen by two or more chosen axes
   (the overlap);
4. no point of a functional zone may be seen by two or more chosen axes (hard constraint).

Ties are broken by a total order so that every solver returns the same answer: smallest ``k``, then
smallest overlap, then largest coverage, then the lexicographically smallest sorted tuple of axis
indices.  If no ``k <= max_setups`` reaches the coverage, the result is ``"infeasible"`` and carries
the best subset of at most ``max_setups`` axes: largest coverage, then smallest ``k``, then smallest
overlap, then the smallest tuple.

The paper enumerates every combination with the binomial coefficient.  Here the points are first
merged into weighted classes of identical visibility rows (zone membership is part of the class
key) and identical columns are collapsed to their lowest index (:mod:`planning.setups.problem`); then
either

* ``"branch_and_bound"`` (the default, ``"auto"``): an exact depth-first search over axis
  combinations on the weighted classes (:mod:`planning.setups.search`, its bounds in
  :mod:`planning.setups.bounds`), started from greedy max coverage improved by one- and two-axis
  exchanges (:mod:`planning.setups.heuristics`).  The matrix products are small, so BLAS runs
  single-threaded during the call (see ``_single_threaded_blas``).  Measured
  (``bench/bench_setups.py``): the proven optimum for 100k bone-like normals x 145-206 axes, max 5
  set-ups, in 0.2-0.9 s on the shared 2-core machine.  Infeasibility (no ``k <= max_setups``
  reaches the coverage) is proven for every k at once by an upper bound on the coverage of
  ``max_setups`` axes: Lagrangian prices of the classes from the dual of the LP relaxation of max
  coverage (:mod:`planning.setups.lagrange`, HiGHS); where it falls short of the required count
  no search runs for the proof, and the same prices then bound the search for the best-coverage
  answer (``bench/bench_infeasible.py``).
* ``"cpsat"``: OR-Tools CP-SAT over the same weighted classes (:mod:`planning.setups.cpsat`).  Exact
  too, but its overlap bound is 0 on this problem (``docs/design.md``, Performance, "Set-ups"); kept as
  an independent cross-check and as the model for side constraints.  It does not apply the index
  tie rule (``selected`` may differ on exact ties).
* ``"brute_force"``: the exhaustive reference (:mod:`planning.setups.bruteforce`), small inputs only.

This module is the entry: :func:`select_setups` checks the run's parameters, reduces the problem,
runs the solver and returns a :class:`~planning.setups.result.SetupSelection`.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from planning.errors import ParameterError
from planning.progress import Throttled
from planning.setups.bruteforce import brute_force_setups
from planning.setups.cpsat import _solve_cpsat
from planning.setups.heuristics import _heuristics
from planning.setups.lagrange import _prices
from planning.setups.problem import _Problem, _validate
from planning.setups.result import SetupSelection, _make_result
from planning.setups.search import _MIN_PRICE_R, _small_max_cover, _solve_bnb

__all__ = ["SOLVERS", "CoverageBound", "SetupSelection", "brute_force_setups", "coverage_upper_bound", "select_setups"]

SOLVERS = ("auto", "branch_and_bound", "cpsat", "brute_force")

ProgressCallback = Callable[[float, str], None]


def _validate_run(solver, time_limit_s, progress):
    """Check the run's parameters (solver name, time limit in s, progress callable); raise
    :class:`~planning.errors.ParameterError` otherwise."""
    if solver not in SOLVERS:
        raise ParameterError(
            f"solver must be one of {', '.join(SOLVERS)}, got {solver!r}",
            parameter="solver", value=repr(solver), allowed=list(SOLVERS),
        )
    if isinstance(time_limit_s, (bool, np.bool_)) or not isinstance(
        time_limit_s, (int, float, np.integer, np.floating)
    ) or not math.isfinite(float(time_limit_s)) or float(time_limit_s) <= 0:
        raise ParameterError(
            f"time_limit_s must be a positive number of seconds, got {time_limit_s!r}",
            parameter="time_limit_s", value=repr(time_limit_s), allowed="> 0",
        )
    if progress is not None and not callable(progress):
        raise ParameterError(
            "progress must be a callable progress(fraction, message) or None",
            parameter="progress", value=repr(progress), allowed="callable or None",
        )


@contextlib.contextmanager
def _single_threaded_blas():
    """Run the search's many small matrix products on one BLAS thread, then restore the setting.

    The products here are small (~100 x 2000 x 100); waking OpenBLAS threads for each costs more
    than they save: on the shared 2-core machine the search ran ~5-8x slower with them (a single
    product measured 30 ms instead of 0.6 ms). threadpoolctl changes the process-wide setting for
    the duration of the call.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def select_setups(visibility, *, coverage=0.95, max_setups=5, min_points=1, zone_mask=None,
                  solver="auto", time_limit_s=60.0, progress: ProgressCallback | None = None
                  ) -> SetupSelection:
    """Choose the 3+2 set-ups (tool axes) for a visibility matrix, exactly (Makki et al. 2010, §3.1).

    ``visibility`` is the (n_points, n_axes) boolean global visibility matrix (§2.2): entry [i, j] is
    True when axis j may machine point i.  Axes seeing fewer than ``min_points`` points are dropped;
    then the smallest ``k <= max_setups`` whose best ``k`` axes see at least
    ``ceil(coverage * n_points)`` points is found, and among those subsets the one with the fewest
    points seen by two or more chosen axes (overlap), subject to no point of ``zone_mask`` (functional
    zones) being seen by two chosen axes.  Ties: least overlap, then most covered points, then the
    smallest sorted tuple of axis indices.  When no ``k <= max_setups`` reaches the coverage the
    result is ``"infeasible"`` with the best-coverage subset of at most ``max_setups`` axes (then
    fewest axes, least overlap, smallest tuple); the branch and bound proves it with an LP bound on
    the coverage of ``max_setups`` axes where it can, else by searching.

    ``solver``: ``"auto"`` (= ``"branch_and_bound"``: exact, and fast at scale because its bounds are
    combinatorial; CP-SAT's LP bound on the overlap is 0 here), ``"cpsat"`` (OR-Tools CP-SAT, one
    worker, seed 0: deterministic when it finishes within the time limit; selected axes may differ
    from the other solvers on exact ties of overlap and coverage) or ``"brute_force"``.
    ``time_limit_s`` bounds the search; when hit, the best subset found is returned with status
    ``"feasible"`` and the gap to the proven lower bound on the overlap.  ``progress(fraction,
    message)`` is called as the search advances.
    """
    t0 = time.perf_counter()
    V, cov_target, K, min_points, zone, required = _validate(
        visibility, coverage, max_setups, min_points, zone_mask)
    _validate_run(solver, time_limit_s, progress)
    if solver == "brute_force":
        return brute_force_setups(V, coverage=coverage, max_setups=K, min_points=min_points, zone_mask=zone)
    deadline = t0 + float(time_limit_s)
    if progress is not None:
        progress = Throttled(progress, 0.0)     # every report passed on, the fraction never going back
        progress(0.0, "merging identical visibility rows")
    name = "cpsat" if solver == "cpsat" else "branch_and_bound"
    with _single_threaded_blas():
        prob = _Problem(V, zone, min_points, required)
        if progress is not None:
            progress(0.0, f"{prob.C} classes of identical rows over {prob.n_axes_kept} axes")
        if name == "cpsat":
            out = _solve_cpsat(prob, K, deadline, progress)
        else:
            out = _solve_bnb(prob, K, deadline, progress)
        covered, overlap = prob.evaluate(out.sel)
    if progress is not None:
        progress(1.0, "set-ups chosen", force=True)
    return _make_result(
        status=out.status, sel_orig=prob.axes[out.sel] if out.sel else [], covered=covered,
        overlap=overlap, n=prob.n, required=required, K=K, coverage_target=cov_target,
        lower_bound=out.lower_bound, solver=name, n_classes=prob.C, n_axes_kept=prob.n_axes_kept,
        seconds=time.perf_counter() - t0, note=out.note, min_points=min_points,
    )


@dataclass(frozen=True)
class CoverageBound:
    """What :func:`coverage_upper_bound` proves: no ``max_setups`` axes of the matrix see more than
    ``bound`` points (``greedy`` points are reached by greedy's axes, a lower bound on the best);
    ``required`` = ``ceil(coverage * n_points)``; ``proven_infeasible``: ``bound < required``."""

    bound: int
    greedy: int
    required: int
    n_points: int
    seconds: float

    @property
    def proven_infeasible(self) -> bool:
        return self.bound < self.required


def coverage_upper_bound(visibility, *, coverage=0.95, max_setups=5, min_points=1, zone_mask=None,
                         time_limit_s=10.0) -> CoverageBound:
    """An upper bound on the points any ``max_setups`` axes of ``visibility`` see together, without
    a search: greedy max coverage first (where its ``max_setups`` axes reach ``ceil(coverage * n)``
    no bound can rule the matrix out, and the number of points some axis sees is returned), else the
    price bound of :mod:`planning.setups.lagrange` (the LP dual of max coverage with ``max_setups``
    axes), the same proof :func:`select_setups` runs first (for one or two axes the exact largest
    coverage, from the Gram matrix, instead). Zone conflicts are ignored (they only
    remove subsets), so the bound holds with them. Used where many matrices are to be ruled out
    quickly (:mod:`planning.placement.search`)."""
    t0 = time.perf_counter()
    V, _cov, K, min_points, zone, required = _validate(visibility, coverage, max_setups, min_points, zone_mask)
    _validate_run("auto", time_limit_s, None)
    with _single_threaded_blas():
        prob = _Problem(V, zone, min_points, required)
        seen = int(prob.w.sum())
        kmax = min(K, prob.m)
        if kmax == 0:
            return CoverageBound(0, 0, required, prob.n, time.perf_counter() - t0)
        heur = _heuristics(prob, K)
        greedy = int(max((c for _, c, _ in heur.values()), default=0))
        if greedy >= required:
            return CoverageBound(seen, greedy, required, prob.n, time.perf_counter() - t0)
        if kmax < _MIN_PRICE_R:  # one or two axes: every pair from the Gram matrix, exactly
            bound = _small_max_cover(prob, kmax)
        else:
            _mu, bound = _prices(prob, kmax, heur.get(kmax, (None,))[0], deadline=t0 + float(time_limit_s))
    return CoverageBound(int(min(seen, math.floor(bound + 1e-9))), greedy, required, prob.n,
                         time.perf_counter() - t0)
