"""Set-up selection, Lagrangian prices: an upper bound on the coverage of any r axes.

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1 made exact.  Give every class c of
:class:`~planning.setups.problem._Problem` a price ``mu_c`` with ``0 <= mu_c <= w_c`` (its weight, in
points).  For a node of the search (chosen axes S, uncovered classes U) and any r further axes T::

    covered(S + T) <= W - M + (sum of the r largest s_a)

where ``W`` is the weight of every class some axis sees, ``M`` the price of the uncovered classes and
``s_a`` the price of the uncovered classes axis a sees (a class of U that T covers pays at most its
price through one axis of T; one it leaves uncovered counts ``w_c - mu_c >= 0``).  The bound holds
for every price vector (weak duality of the Lagrangian relaxation of ``y_c <= sum_a x_a``); the best
prices are the dual of the LP relaxation of max coverage with r axes (``max sum w_c y_c``,
``y_c <= sum_{a sees c} x_a``, ``sum x_a <= r``, ``0 <= x, y <= 1``), which :func:`_prices` solves
with HiGHS (dual simplex) in its dual form: one row per axis, one column per class.  On the
femur-like case (31k classes x 138 axes) that LP bounds 5 axes at 94,878 points against the best
94,727; the sum of the 5 best single-axis gains is far above the number of points.

Prices are rounded to a dyadic grid (:func:`_price_step`; any vector in [0, w] is still a valid
price), so that every sum the search forms, in float32 as in
:class:`~planning.setups.problem._Problem`, stays exact.
"""

from __future__ import annotations

import time

import numpy as np

from planning.setups.problem import _Problem


def _top_r_sum(s: np.ndarray, r: int) -> float:
    """Sum of the r largest entries of s (all of them when there are fewer)."""
    if r <= 0 or s.size == 0:
        return 0.0
    if s.size <= r:
        return float(s.sum())
    return float(-np.partition(-s, r - 1)[:r].sum())


def _price_bound(prob: _Problem, mu: np.ndarray, r: int) -> float:
    """The bound ``W - sum mu + top_r(A^T mu)`` at the root: no r axes cover more points."""
    s = (prob.AT.astype(np.float64) @ mu) if prob.m else np.zeros(0)
    return float(prob.w.sum()) - float(mu.sum()) + _top_r_sum(s, r)


def _price_step(prob: _Problem) -> float:
    """The grid of the prices, 2^-q: fine enough to lose little of the LP bound, coarse enough that
    every sum of prices the search forms (at most n) is exact in ``prob.ftype``."""
    mant = 24 if prob.ftype == np.float32 else 53
    q = max(0, min(10, mant - 1 - int(np.ceil(np.log2(prob.n + 1)))))
    return 2.0 ** -q


def _solve_dual(prob: _Problem, cols: np.ndarray, r: int, presolve: bool, seconds: float | None):
    """HiGHS dual simplex on the LP dual restricted to the classes ``cols`` (the others priced 0):
    (prices of ``cols``, axis values x of the primal LP) or None."""
    from scipy import sparse
    from scipy.optimize import linprog

    m = prob.m
    ra, rc = np.nonzero(prob.AT[:, cols])
    A_mu = sparse.csr_matrix((np.ones(ra.size), (ra, rc)), shape=(m, cols.size))
    # min  -sum mu + r lam + sum nu   s.t.  A^T mu - lam - nu <= 0  (one row per axis),  0 <= mu <= w
    A_ub = sparse.hstack([A_mu, -sparse.identity(m, format="csr"), -np.ones((m, 1))], format="csr")
    cost = np.concatenate([-np.ones(cols.size), np.ones(m), [float(r)]])
    upper = np.concatenate([prob.w[cols].astype(np.float64), np.full(m + 1, np.inf)])
    bounds = np.stack([np.zeros(cols.size + m + 1), upper], axis=1)
    options = {"presolve": presolve}
    if seconds is not None:
        options["time_limit"] = max(0.01, seconds)
    try:
        res = linprog(cost, A_ub=A_ub, b_ub=np.zeros(m), bounds=bounds, method="highs-ds",
                      options=options)
    except Exception:  # noqa: BLE001  # pragma: no cover - any solver failure: no prices
        return None
    if res.status != 0 or res.x is None:
        return None
    return res.x[: cols.size], -np.asarray(res.ineqlin.marginals, dtype=np.float64)


def _prices(prob: _Problem, r: int, start=None, rounds: int = 4, deadline: float | None = None,
            min_gain: float | None = None) -> tuple[np.ndarray, float]:
    """Prices (C,) in [0, w] on a dyadic grid from the LP dual for r axes, and the root bound.

    The LP runs on a subset of the classes (column generation): the classes that ``start`` (a good
    r-subset, e.g. greedy's) covers at most once, where the prices concentrate; a class left out
    (price 0) whose LP cover ``sum_{a sees c} x_a`` is below 1 would lower the bound, so those are
    added and the LP solved again, at most ``rounds`` times.  On the femur-like case the first
    subset is already optimal (12k of 31k classes; 0.3-0.4 s instead of 2-4 s for the whole LP
    with presolve).  Any prices are valid, so stopping early only weakens the bound; zero prices
    (bound: every seen point) if the solver fails or ``deadline`` (``time.perf_counter()``) passes.
    ``min_gain``: also stop once a round lowered the bound by less than this many points (the
    search's use: on the range half sphere the rounds after the second moved it by 0.03-0.1 points
    and cost a solve each, issue 32)."""
    C, m = prob.C, prob.m
    mu = np.zeros(C)
    if C == 0 or m == 0:
        return mu, 0.0
    if start is not None and len(start):
        cols = np.flatnonzero(prob.AT[list(start)].sum(axis=0) <= 1)
    else:
        cols = np.arange(C)
    Af = None
    last = np.inf  # the bound after the last round (where min_gain is given)
    for _ in range(rounds):
        left = None if deadline is None else deadline - time.perf_counter()
        if left is not None and left <= 0:
            break
        got = _solve_dual(prob, cols, r, False, left) if cols.size else None
        if got is None and cols.size:
            left = None if deadline is None else deadline - time.perf_counter()
            got = _solve_dual(prob, cols, r, True, left) if left is None or left > 0 else None
        if got is None:
            break
        mu[:] = 0.0
        mu[cols] = got[0]
        if cols.size == C:
            break
        if Af is None:
            Af = prob.A.astype(np.float64)
        if min_gain is not None:
            b = float(prob.w.sum()) - float(mu.sum()) + _top_r_sum(mu @ Af, r)
            if last - b < min_gain:
                break
            last = b
        out = np.ones(C, bool)
        out[cols] = False
        add = np.flatnonzero(out & (Af @ got[1] < 1.0 - 1e-7))
        if add.size == 0:
            break
        cols = np.union1d(cols, add)
    step = _price_step(prob)
    mu = np.clip(np.floor(mu / step + 0.5) * step, 0.0, prob.w.astype(np.float64))
    return mu, _price_bound(prob, mu, r)
