"""Set-up selection by exhaustive enumeration: the reference the exact solvers are tested against.

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1 as the paper does it: every combination of
the kept axes (the binomial coefficient), on the point rows themselves (no classes, no column merging),
with the rules and the tie order of :mod:`planning.setups.select`.  Exponential: small inputs only
(tests, ``solver="brute_force"``, and the small cases of ``bench/bench_setups.py``).
"""

from __future__ import annotations

import itertools
import time

import numpy as np

from planning.setups.problem import _Problem, _validate
from planning.setups.result import SetupSelection, _make_result

__all__ = ["brute_force_setups"]


def brute_force_setups(visibility, *, coverage=0.95, max_setups=5, min_points=1, zone_mask=None
                       ) -> SetupSelection:
    """Exhaustive reference for :func:`~planning.setups.select_setups` (Makki et al. 2010, §3.1, as the
    paper does it).

    Enumerates every combination of the kept axes with ``itertools.combinations`` (the binomial
    coefficient of §3.1), directly on the point rows (no classes, no column merging), with the same
    rules and tie order as :func:`~planning.setups.select_setups`.  Exponential: small inputs only
    (tests).
    """
    t0 = time.perf_counter()
    V, cov_target, K, min_points, zone, required = _validate(
        visibility, coverage, max_setups, min_points, zone_mask)
    n = V.shape[0]
    kept = [int(j) for j in np.flatnonzero(V.sum(axis=0) >= min_points)]
    Vi = V.astype(np.int64)
    Vz = Vi[zone] if zone is not None else None
    feasible_best = None  # (ov, -cov, tup) at the smallest k
    cover_best = None  # (-cov, k, ov, tup)
    for k in range(1, min(K, len(kept)) + 1):
        for combo in itertools.combinations(kept, k):
            cols = list(combo)
            if Vz is not None and k > 1 and (Vz[:, cols].sum(axis=1) >= 2).any():
                continue
            deg = Vi[:, cols].sum(axis=1)
            cv = int((deg >= 1).sum())
            ov = int((deg >= 2).sum())
            if cv >= required:
                key = (ov, -cv, combo)
                if feasible_best is None or key < feasible_best:
                    feasible_best = key
            key2 = (-cv, k, ov, combo)
            if cover_best is None or key2 < cover_best:
                cover_best = key2
        if feasible_best is not None:
            break
    try:
        n_classes = _Problem(V, zone, min_points, required).C
    except Exception:  # pragma: no cover - reporting only
        n_classes = -1
    if feasible_best is not None:
        ov, negcov, combo = feasible_best
        status, sel, covered, overlap = "optimal", combo, -negcov, ov
    else:
        status = "infeasible"
        if cover_best is None:
            sel, covered, overlap = (), 0, 0
        else:
            negcov, _, overlap, sel = cover_best
            covered = -negcov
    return _make_result(
        status=status, sel_orig=sel, covered=covered, overlap=overlap, n=n, required=required, K=K,
        coverage_target=cov_target, lower_bound=overlap if status == "optimal" else None,
        solver="brute_force", n_classes=n_classes, n_axes_kept=len(kept),
        seconds=time.perf_counter() - t0, min_points=min_points,
    )
