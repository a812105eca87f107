"""How few label changes the visibility allows (issue 32 item 2): a lower bound for the benches.

The label-change share of a labelling (:func:`planning.areas.regions.seam_totals`) counts the graph
edges whose two ends carry different set-ups. Each point may only take a set-up that sees it
(``allowed`` (n,k); a leftover no chosen set-up sees may take any), so a point seen by one chosen
set-up alone forces its label, and two neighbours with no common allowed set-up force a change
between them. The least total weight of cut edges over all allowed labellings is a multiway cut
with per-point label lists, NP-hard for three labels or more; its linear relaxation (Kleinberg &
Tardos 2002, the uniform metric labelling LP)

    min  sum_e w_e / 2 * sum_j d_ej
    s.t. d_ej >= x_pj - x_qj,  d_ej >= x_qj - x_pj   (e = pq),
         sum_j x_pj = 1,  0 <= x_pj <= allowed_pj,

is a lower bound on it, never below half of it (the rounding gap of that LP is at most 2), and
equal to it when the LP's solution is integral (as it is, or nearly, on the range-scan samples).
Solved by HiGHS through :func:`scipy.optimize.linprog`; seconds on a few thousand points, so the
plan does not call it: ``bench/bench_areas_range.py --bound`` does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: x values within this of 0 or 1 count as integral.
INTEGRAL_TOL = 1e-6


@dataclass(frozen=True)
class LabelChangeBound:
    """``bound``: no allowed labelling cuts less edge weight than this (the LP's value);
    ``labels`` (n,) int64: an allowed labelling (the LP's largest label per point), with cut weight
    ``cut`` >= ``bound`` (equal when ``integral``); ``fractional_points``: points whose LP labels
    are not 0/1."""

    bound: float
    labels: np.ndarray
    cut: float
    integral: bool
    fractional_points: int


def cut_weight(edges: np.ndarray, labels: np.ndarray, weights: np.ndarray | None = None) -> float:
    """Total weight (1 per edge when ``weights`` is None) of the edges whose ends differ."""
    if edges.shape[0] == 0:
        return 0.0
    cut = labels[edges[:, 0]] != labels[edges[:, 1]]
    return float(cut.sum()) if weights is None else float(np.asarray(weights, float)[cut].sum())


def least_label_changes(edges: np.ndarray, allowed: np.ndarray, weights: np.ndarray | None = None) -> LabelChangeBound:
    """The LP bound of the module docstring over the graph ``edges`` (E,2) with per-edge
    ``weights`` (E,) (1 when None) and per-point allowed set-ups ``allowed`` (n,k) bool (every row
    needs one True). Vectorised sparse assembly; one LP."""
    from scipy.optimize import linprog
    from scipy.sparse import coo_matrix

    allowed = np.asarray(allowed, dtype=bool)
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    n, k = allowed.shape
    if n and not allowed.any(axis=1).all():
        raise ValueError("every point needs an allowed label")
    w = np.ones(edges.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    if n == 0 or k == 0:
        return LabelChangeBound(0.0, np.zeros(n, np.int64), 0.0, True, 0)
    # x variables only where allowed; d only where the label is allowed at both ends (one end only:
    # d = x at that end, its cost folds into x's; neither: 0)
    xid = np.full((n, k), -1, np.int64)
    xid[allowed] = np.arange(int(allowed.sum()))
    nx = int(allowed.sum())
    p, q = edges[:, 0], edges[:, 1]
    ap, aq = allowed[p], allowed[q]                           # (E,k)
    c = np.zeros(nx)
    one_p, one_q = ap & ~aq, aq & ~ap
    ei, j = np.nonzero(one_p)
    np.add.at(c, xid[p[ei], j], 0.5 * w[ei])
    ei, j = np.nonzero(one_q)
    np.add.at(c, xid[q[ei], j], 0.5 * w[ei])
    ei, j = np.nonzero(ap & aq)
    nd = ei.shape[0]
    c = np.r_[c, 0.5 * w[ei]]
    xp, xq, dd = xid[p[ei], j], xid[q[ei], j], nx + np.arange(nd)
    r = np.arange(nd)
    rows = np.r_[r, r, r, nd + r, nd + r, nd + r]
    cols = np.r_[xp, xq, dd, xp, xq, dd]
    vals = np.r_[np.ones(nd), -np.ones(nd), -np.ones(nd), -np.ones(nd), np.ones(nd), -np.ones(nd)]
    a_ub = coo_matrix((vals, (rows, cols)), shape=(2 * nd, nx + nd)).tocsr()
    pi, _ = np.nonzero(allowed)                                # xid order is row-major over allowed
    a_eq = coo_matrix((np.ones(nx), (pi, np.arange(nx))), shape=(n, nx + nd)).tocsr()
    res = linprog(c, A_ub=a_ub if nd else None, b_ub=np.zeros(2 * nd) if nd else None, A_eq=a_eq,
                  b_eq=np.ones(n), bounds=(0.0, 1.0), method="highs")
    if res.status != 0:
        raise RuntimeError(f"the label-change LP failed: {res.message}")
    x = np.zeros((n, k))
    x[allowed] = res.x[:nx]
    labels = np.argmax(np.where(allowed, x, -1.0), axis=1).astype(np.int64)
    frac = int(np.any((x > INTEGRAL_TOL) & (x < 1.0 - INTEGRAL_TOL), axis=1).sum())
    return LabelChangeBound(bound=float(res.fun), labels=labels, cut=cut_weight(edges, labels, weights),
                            integral=frac == 0, fractional_points=frac)
