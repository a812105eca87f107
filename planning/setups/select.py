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
key) and identical columns are collapsed to their lowest index; then either

* ``"branch_and_bound"`` (the default, ``"auto"``): an exact depth-first search over axis
  combinations on the weighted classes (axes ordered by size; a subset is visited once, in that
  order).  Every node keeps, for its remaining candidate axes, the weight each would newly cover
  (``g``), the weight it would turn into overlap (``h``) and the weighted Gram matrices of the
  candidates over the still uncovered classes (``P``) and over the classes covered exactly once
  (``Q``); a child's ``g`` and ``h`` are read off the parent's ``P`` and ``Q`` rows, so only a
  child that survives the bounds pays for its two small Gram products.  Bounds:

  - the last two axes are evaluated exactly, all pairs at once:
    covered ``+ g_a + g_b - P_ab``, overlap ``+ h_a + h_b - Q_ab + P_ab``;
  - coverage: Hunter's spanning-tree bound on a union, along increasing chains
    (``g_a + (g_b - P_ab) + (g_c - P_bc) + ...``, a dynamic programme), and "the best remaining
    gains" per axis; for three axes ``sum g - (sum P - min P)`` (inclusion-exclusion with the
    triple term at most the smallest pair);
  - overlap: the exact overlap of any pair of added axes is a lower bound, so every completion
    holds the next axis with at least the smallest such pair, and at least the (r-1)-th smallest;
    for three axes ``sum h - sum Q + max P`` (Bonferroni);
  - before building a child, pairs (and triples) of further axes are checked with the child's
    ``P``/``Q`` bounded from the parent's (the classes the child covers and two others both see
    weigh at most the smaller shared weight); a completion must be a clique of passing pairs,
    so axes with too few partners are peeled off, and a child with no passing pair or triple is
    not built.  At nodes with three axes to add and few candidates this check runs for all
    children at once on (j, l, q) arrays;
  - pruning compares (lower bound, upper bound, smallest reachable index tuple) with the
    incumbent's key, so ties resolve exactly as in the brute force.

  The incumbent comes from greedy max coverage improved by one- and two-axis exchanges (the
  exchange of two axes is evaluated for all incoming pairs at once from Gram matrices).  The
  matrix products are small, so BLAS runs single-threaded during the call (see
  ``_single_threaded_blas``).  Measured (``bench/bench_setups.py``): the proven optimum for 100k
  bone-like normals x 145-206 axes, max 5 set-ups, in 0.2-0.9 s on the shared 2-core machine.
* ``"cpsat"``: OR-Tools CP-SAT over the same weighted classes (a coverage and an overlap boolean per
  class; one worker, seed 0).  Exact too, but its LP relaxation gives an overlap bound of 0 on this
  problem (``docs/design.md``, Performance, "Set-ups"): on the 100k case it still reports a lower bound
  of 0 after 60 s.  It is kept as an independent cross-check and as the model for side
  constraints.  It does not apply the index tie rule (``selected`` may differ on exact ties).
"""

from __future__ import annotations

import contextlib
import itertools
import math
import time
from dataclasses import dataclass
from fractions import Fraction
from collections.abc import Callable

import numpy as np
from threadpoolctl import threadpool_limits

from planning.errors import ParameterError

__all__ = ["SetupSelection", "select_setups", "brute_force_setups", "SOLVERS"]

SOLVERS = ("auto", "branch_and_bound", "cpsat", "brute_force")

ProgressCallback = Callable[[float, str], None]


@dataclass(frozen=True)
class SetupSelection:
    """The chosen set-ups (tool axes) and what they achieve.

    ``status`` is ``"optimal"`` (the order of Makki §3 with the tie rules above is proven),
    ``"feasible"`` (the time limit was hit; ``selected`` reaches the coverage and ``gap`` bounds its
    distance to the optimal overlap; ``lower_bound`` is ``None`` where not even ``k`` was proven
    minimal), ``"infeasible"`` (proven: no ``k <= max_setups`` reaches the coverage; ``selected`` is
    the best-coverage subset) or ``"unknown"`` (the time limit was hit before a subset reaching the
    coverage was found and before infeasibility was proven; ``selected`` is the best found).
    """

    status: str
    selected: np.ndarray
    k: int
    n_points: int
    covered: int
    coverage: float
    overlap: int
    required_covered: int
    lower_bound: int | None
    gap: float | None
    best_coverage_at_max: float | None
    solver: str
    n_classes: int
    n_axes_kept: int
    seconds: float
    message: str


# --------------------------------------------------------------------------------------------
# validation and reduction
# --------------------------------------------------------------------------------------------


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def _validate(visibility, coverage, max_setups, min_points, zone_mask):
    try:
        V = np.asarray(visibility)
    except Exception as exc:  # pragma: no cover - exotic inputs
        raise ParameterError(
            f"visibility must be a 2-D boolean array (points x axes): {exc}", parameter="visibility"
        ) from None
    if V.ndim != 2:
        raise ParameterError(
            f"visibility must be a 2-D boolean array (points x axes), got {V.ndim} dimension(s)",
            parameter="visibility", value=list(V.shape), allowed="shape (n_points, n_axes)",
        )
    if V.shape[0] < 1 or V.shape[1] < 1:
        raise ParameterError(
            f"visibility must have at least one point and one axis, got shape {V.shape}",
            parameter="visibility", value=list(V.shape), allowed="n_points >= 1, n_axes >= 1",
        )
    if V.dtype != bool and (V.dtype.kind not in "iuf" or not np.all((V == 0) | (V == 1))):
        raise ParameterError(
            "visibility must hold booleans (or only 0 and 1)",
            parameter="visibility", value=str(V.dtype), allowed="bool",
        )
    V = np.ascontiguousarray(V, dtype=bool)
    n = V.shape[0]

    if isinstance(coverage, (bool, np.bool_)) or not isinstance(
        coverage, (int, float, np.integer, np.floating)
    ):
        raise ParameterError(
            f"setups.coverage must be a number in (0, 1], got {coverage!r}",
            parameter="coverage", value=repr(coverage), allowed="(0, 1]",
        )
    cov = float(coverage)
    if not math.isfinite(cov) or not 0.0 < cov <= 1.0:
        raise ParameterError(
            f"setups.coverage must be in (0, 1] (a fraction of the points, e.g. 0.95), got {coverage!r}",
            parameter="coverage", value=cov, allowed="(0, 1]",
        )
    if not _is_int(max_setups) or max_setups < 1:
        raise ParameterError(
            f"setups.max_setups must be an integer >= 1, got {max_setups!r}",
            parameter="max_setups", value=repr(max_setups), allowed=">= 1",
        )
    if not _is_int(min_points) or min_points < 1:
        raise ParameterError(
            f"setups.min_points must be an integer >= 1, got {min_points!r}",
            parameter="min_points", value=repr(min_points), allowed=">= 1",
        )
    zone = None
    if zone_mask is not None:
        Z = np.asarray(zone_mask)
        if Z.shape != (n,):
            raise ParameterError(
                f"zone_mask must be a boolean array of shape ({n},) (one flag per point), "
                f"got shape {Z.shape}",
                parameter="zone_mask", value=list(Z.shape), allowed=f"shape ({n},)",
            )
        if Z.dtype != bool and (Z.dtype.kind not in "iu" or not np.all((Z == 0) | (Z == 1))):
            raise ParameterError(
                "zone_mask must hold booleans (or only 0 and 1)",
                parameter="zone_mask", value=str(Z.dtype), allowed="bool",
            )
        zone = np.ascontiguousarray(Z, dtype=bool)
        if not zone.any():
            zone = None
    required = math.ceil(Fraction(repr(cov)) * n)  # exact: 0.95 * 20 -> 19, 0.95 * 2537 -> 2411
    required = max(1, min(n, required))
    return V, cov, int(max_setups), int(min_points), zone, required


def _validate_run(solver, time_limit_s, progress):
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


def _unique_rows(B: np.ndarray):
    """Unique rows of a 2-D bool array: (first index of each class, counts), by packed bytes."""
    packed = np.ascontiguousarray(np.packbits(B, axis=1))
    if packed.shape[1] == 0:  # pragma: no cover - no columns
        return np.zeros(1, np.int64), np.array([B.shape[0]])
    keys = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()
    _, first, counts = np.unique(keys, return_index=True, return_counts=True)
    return first.astype(np.int64), counts.astype(np.int64)


def _wgram(X: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted Gram matrix ``X^T diag(w) X`` (classes x axes -> axes x axes), as float64: entry
    (a, b) is the weight of the classes both axes a and b see."""
    return ((X * w[:, None]).T @ X).astype(np.float64)


class _Problem:
    """The reduced instance: weighted classes x distinct kept axes (Makki §3.1 reduced matrix)."""

    def __init__(self, V: np.ndarray, zone: np.ndarray | None, min_points: int, required: int):
        n = V.shape[0]
        self.n = n
        self.required = required
        counts = V.sum(axis=0)
        kept = np.flatnonzero(counts >= min_points)
        self.n_axes_kept = int(kept.size)
        Vk = V[:, kept]
        key = Vk if zone is None else np.concatenate([Vk, zone[:, None]], axis=1)
        if kept.size:
            first, w = _unique_rows(key)
        else:
            first, w = np.zeros(0, np.int64), np.zeros(0, np.int64)
        A = Vk[first]
        zc = zone[first] if zone is not None else np.zeros(first.size, bool)
        seen = A.any(axis=1) if kept.size else np.zeros(first.size, bool)
        A, w, zc = A[seen], w[seen], zc[seen]
        # identical columns: keep the lowest index (it wins the lexicographic tie, and a minimal-k
        # solution never holds two identical columns)
        if kept.size and A.shape[0]:
            colfirst, _ = _unique_rows(np.ascontiguousarray(A.T))
            cols = np.sort(colfirst)
        else:
            cols = np.zeros(0, np.int64)
        A = np.ascontiguousarray(A[:, cols])
        self.axes = kept[cols].astype(np.int64)  # original column index of each reduced axis
        self.A = A  # (C, m) bool
        self.AT = np.ascontiguousarray(A.T)  # (m, C) bool
        self.w = w.astype(np.int64)
        self.zone = zc
        self.C, self.m = A.shape
        self.ftype = np.float32 if n < 2**24 else np.float64  # integer sums stay exact
        self.Af = A.astype(self.ftype)
        self.wf = self.w.astype(self.ftype)
        self.sizes = (self.wf @ self.Af).astype(np.float64) if self.m else np.zeros(0)
        if self.m:
            self.gram = _wgram(self.Af, self.wf)
        else:
            self.gram = np.zeros((0, 0))
        # zone conflicts: two axes that both see a zone class may not be chosen together
        if zc.any() and self.m:
            Az = A[zc].astype(np.float32)
            self.conflict = (Az.T @ Az) > 0
            np.fill_diagonal(self.conflict, False)
        else:
            self.conflict = np.zeros((self.m, self.m), bool)
        self.has_conflicts = bool(self.conflict.any())

    # -- evaluation ----------------------------------------------------------------------------
    def evaluate(self, sel) -> tuple[int, int]:
        """(covered, overlap) of reduced axes ``sel``."""
        sel = list(sel)
        if not sel:
            return 0, 0
        deg = self.AT[sel].sum(axis=0)
        return int(self.w[deg >= 1].sum()), int(self.w[deg >= 2].sum())

    def tuple_of(self, sel) -> tuple[int, ...]:
        return tuple(sorted(int(self.axes[s]) for s in sel))


# --------------------------------------------------------------------------------------------
# BLAS threads
# --------------------------------------------------------------------------------------------

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


# --------------------------------------------------------------------------------------------
# keys (the total order of the module docstring)
# --------------------------------------------------------------------------------------------


def _key_overlap(ov, cov, tup):
    return (ov, -cov, tup)


def _key_cover(ov, cov, tup):
    return (-cov, ov, tup)


# --------------------------------------------------------------------------------------------
# heuristics (incumbents and CP-SAT hints)
# --------------------------------------------------------------------------------------------


def _greedy(prob: _Problem, k: int) -> list[int]:
    """Greedy max coverage with zone conflicts; ties: less added overlap, then lower index."""
    sel: list[int] = []
    deg = np.zeros(prob.C, np.int16)
    banned = np.zeros(prob.m, bool)
    for _ in range(k):
        g = (prob.wf * (deg == 0)) @ prob.Af
        h = (prob.wf * (deg == 1)) @ prob.Af
        ok = ~banned
        ok[sel] = False
        if not ok.any():
            break
        score = np.where(ok, g.astype(np.float64) * (prob.n + 1) - h, -np.inf)
        j = int(np.argmax(score))
        sel.append(j)
        deg += prob.AT[j]
        banned |= prob.conflict[j]
    return sel


def _local_search(prob: _Problem, sel: list[int], mode: str, floor: int, max_rounds: int = 20):
    """Improve ``sel`` by exchanging one or two axes (best exchange per round) for the key of
    ``mode`` subject to covered >= floor.  Returns (sel, key) or (sel, None) if never feasible.

    A two-axis exchange is evaluated exactly for every pair of incoming axes at once from the
    Gram matrices of the remaining uncovered and once-covered classes (as in the search).
    """
    keyf = _key_overlap if mode == "overlap" else _key_cover
    cov, ov = prob.evaluate(sel)
    best = keyf(ov, cov, prob.tuple_of(sel)) if cov >= floor else None
    sel = list(sel)
    k = len(sel)
    if k == 0:
        return sel, best

    def primary(covs, ovs):
        return (ovs, -covs) if mode == "overlap" else (-covs, ovs)

    for _ in range(max_rounds):
        move = None  # (key, new selection)
        removals = [(a,) for a in range(k)] + list(itertools.combinations(range(k), 2))
        for rem in removals:
            rest = [s_ for i, s_ in enumerate(sel) if i not in rem]
            deg = prob.AT[rest].sum(axis=0) if rest else np.zeros(prob.C, np.int64)
            c0 = float(prob.w[deg >= 1].sum())
            o0 = float(prob.w[deg >= 2].sum())
            U = deg == 0
            D1 = deg == 1
            g = (prob.wf * U) @ prob.Af
            h = (prob.wf * D1) @ prob.Af
            free = np.ones(prob.m, bool)
            free[rest] = False
            if rest and prob.has_conflicts:
                free &= ~prob.conflict[rest].any(axis=0)
            if len(rem) == 1:
                covs, ovs = c0 + g, o0 + h
                ok = free & (covs >= floor)
                if not ok.any():
                    continue
                idx = np.flatnonzero(ok)
                p1, p2 = primary(covs[idx], ovs[idx])
                t = idx[np.lexsort((idx, p2, p1))[0]]
                new = rest + [int(t)]
                key = keyf(int(ovs[t]), int(covs[t]), prob.tuple_of(new))
            else:
                XU = prob.Af[U]
                XD = prob.Af[D1]
                P = _wgram(XU, prob.wf[U])
                Q = _wgram(XD, prob.wf[D1])
                covs = c0 + g[:, None] + g[None, :] - P
                ovs = o0 + h[:, None] + h[None, :] - Q + P
                ok = np.triu(free[:, None] & free[None, :], 1) & (covs >= floor)
                if prob.has_conflicts:
                    ok &= ~prob.conflict
                if not ok.any():
                    continue
                ia, ib = np.nonzero(ok)
                cv, ovv = covs[ia, ib], ovs[ia, ib]
                p1, p2 = primary(cv, ovv)
                t = np.lexsort((ib, ia, p2, p1))[0]
                new = rest + [int(ia[t]), int(ib[t])]
                key = keyf(int(ovv[t]), int(cv[t]), prob.tuple_of(new))
            if (best is None or key < best) and (move is None or key < move[0]):
                move = (key, new)
        if move is None:
            break
        best, sel = move
    return sel, best


# --------------------------------------------------------------------------------------------
# branch and bound
# --------------------------------------------------------------------------------------------


class _Timeout(Exception):
    pass


class _Found(Exception):
    pass


_INF = np.inf
_TENSOR_MAX = 80  # largest candidate count for the (j, l, q) pre-check arrays (80^3 doubles = 4 MB)


class _Search:
    """Exact DFS over k-subsets of reduced axes (one run = one k, one mode).

    mode "overlap": minimise (overlap, -covered, tuple) subject to covered >= floor.
    mode "cover":   minimise (-covered, overlap, tuple) subject to covered >= floor.
    ``stop_at_first``: stop as soon as any subset with covered >= floor is found (existence).
    """

    def __init__(self, prob: _Problem, k: int, mode: str, floor: float, deadline: float,
                 incumbent=None, stop_at_first=False, progress=None):
        self.p = prob
        self.k = k
        self.mode = mode
        self.floor = float(floor)
        self.deadline = deadline
        self.stop_at_first = stop_at_first
        self.keyf = _key_overlap if mode == "overlap" else _key_cover
        self.best_key = None
        self.best_sel = None
        if incumbent is not None:
            sel, key = incumbent
            if key is not None:
                self.best_key, self.best_sel = key, list(sel)
        self.frames: list = []
        self.nodes = 0
        self.progress = progress
        self.timeout_bound = None

    # incumbent handling -------------------------------------------------------------------
    def _offer(self, sel, cov, ov):
        key = self.keyf(int(round(ov)), int(round(cov)), self.p.tuple_of(sel))
        if self.best_key is None or key < self.best_key:
            self.best_key, self.best_sel = key, list(sel)
        if self.stop_at_first:
            raise _Found

    def _floor(self) -> float:
        """Coverage a subtree must still be able to reach: the constraint, and in "cover" mode
        also the incumbent's coverage (ties may still win on overlap or indices)."""
        if self.mode == "cover" and self.best_key is not None:
            return max(self.floor, float(-self.best_key[0]))
        return self.floor

    def _dominated(self, lo1, lo2, S, cand_after, r):
        """True when the subtree's lower key (lo1, lo2, min tuple) >= incumbent key."""
        if self.best_key is None:
            return False
        a, b, tup = self.best_key
        if lo1 != a:
            return lo1 > a
        if lo2 != b:
            return lo2 > b
        # equal on the numbers: the lexicographically smallest tuple reachable decides
        orig = self.p.axes
        extra = np.sort(orig[cand_after])[:r]
        if extra.size < r:
            return True
        mt = tuple(sorted([int(orig[s]) for s in S] + [int(x) for x in extra]))
        return mt >= tup

    # the search -------------------------------------------------------------------------------
    def run(self):
        p = self.p
        k = self.k
        if p.m < k:
            return
        # axis order: larger coverage first (ties by index)
        order = np.lexsort((np.arange(p.m), -p.sizes))
        cand = order.astype(np.int64)
        node = dict(
            S=[], deg=np.zeros(p.C, np.uint8), cov=0.0, ov=0.0, cand=cand,
            g=p.sizes[cand].copy(), h=np.zeros(cand.size),
            P=p.gram[np.ix_(cand, cand)] if k >= 2 else None,
            Q=np.zeros((cand.size, cand.size)) if k >= 2 else None,
        )
        with contextlib.suppress(_Found):
            self._node(node, k)

    def _check_time(self):
        if time.perf_counter() > self.deadline:
            bound = None
            for lbs, idx in self.frames:
                if idx < len(lbs):
                    v = float(np.min(lbs[idx:]))
                    bound = v if bound is None else min(bound, v)
            self.timeout_bound = bound
            raise _Timeout

    def _node(self, node, r):
        self.nodes += 1
        if r == 1:
            self._leaves1(node)
        elif r == 2:
            self._leaves2(node)
        else:
            self._branch(node, r)

    def _allowed(self, cand):
        M = cand.size
        allowed = np.triu(np.ones((M, M), bool), 1)
        if self.p.has_conflicts:
            allowed &= ~self.p.conflict[np.ix_(cand, cand)]
        return allowed

    def _leaves1(self, node):
        floor = self._floor()
        cov, ov, g, h, cand, S = node["cov"], node["ov"], node["g"], node["h"], node["cand"], node["S"]
        if cand.size == 0:
            return
        covs = cov + g
        ovs = ov + h
        ok = covs >= floor
        if not ok.any():
            return
        idx = np.flatnonzero(ok)
        self._pick(S, [(int(i),) for i in idx], covs[idx], ovs[idx], cand)

    def _leaves2(self, node):
        floor = self._floor()
        cov, ov, g, h, cand, S = node["cov"], node["ov"], node["g"], node["h"], node["cand"], node["S"]
        M = cand.size
        if M < 2:
            return
        allowed = self._allowed(cand)
        covm = cov + g[:, None] + g[None, :] - node["P"]
        ok = allowed & (covm >= floor)
        if not ok.any():
            return
        ia, ib = np.nonzero(ok)
        covs = covm[ia, ib]
        Q, P = node["Q"], node["P"]
        ovs = ov + h[ia] + h[ib] - Q[ia, ib] + P[ia, ib]
        self._pick(S, list(zip(ia.tolist(), ib.tolist(), strict=True)), covs, ovs, cand)

    def _pick(self, S, pos_tuples, covs, ovs, cand):
        """Best of the evaluated leaves (positions into cand) offered to the incumbent."""
        if self.mode == "overlap":
            k1, k2 = ovs, -covs
        else:
            k1, k2 = -covs, ovs
        m1 = k1.min()
        sel1 = k1 == m1
        m2 = k2[sel1].min()
        best = np.flatnonzero(sel1 & (k2 == m2))
        if self.best_key is not None and (m1, m2) > (self.best_key[0], self.best_key[1]):
            return
        bi = best[0]
        if best.size > 1:  # exact tie on the numbers: smallest tuple of original indices
            tups = [self.p.tuple_of(S + [int(cand[q]) for q in pos_tuples[b]]) for b in best]
            bi = best[min(range(len(best)), key=lambda t: tups[t])]
        sel = S + [int(cand[q]) for q in pos_tuples[bi]]
        self._offer(sel, float(covs[bi]), float(ovs[bi]))

    def _branch(self, node, r):
        floor = self._floor()
        cov, ov, g, h, P, Q, cand, S = (node[x] for x in ("cov", "ov", "g", "h", "P", "Q", "cand", "S"))
        M = cand.size
        if M < r:
            return
        allowed = self._allowed(cand)
        # Hunter chain bound on the union of the next t axes, starting at each axis
        bs = [None, g]
        b = g
        for _ in range(2, r + 1):
            T = np.where(allowed, b[None, :] - P, -_INF)
            b = g + T.max(axis=1)
            bs.append(b)
        cub = cov + bs[r]
        viable = cub >= floor
        if self.mode == "overlap":
            # overlap created by j and the next axis l of the chain (exact for the pair), and the
            # (r-1)-th smallest pair overlap of j: every completion holds r-1 axes after j
            chain = allowed & ((cov + g[:, None] - P + bs[r - 1][None, :]) >= floor)
            pv = h[:, None] + h[None, :] - Q + P
            lb = ov + np.where(chain, pv, _INF).min(axis=1)
            pva = np.where(allowed, pv, _INF)
            if r - 1 <= M:
                lb = np.maximum(lb, ov + np.partition(pva, r - 2, axis=1)[:, r - 2])
            viable &= np.isfinite(lb)
            k1, k2 = lb, -cub
        else:
            lb = ov + h
            k1, k2 = -cub, lb
        if r == 3 and M <= _TENSOR_MAX and viable.any():
            viable &= self._pairs_exist(node, allowed, floor)
        idx = np.flatnonzero(viable)
        if idx.size == 0:
            return
        order = idx[np.lexsort((idx, k2[idx], k1[idx]))]
        if self.mode == "overlap":
            frame_lbs = lb[order]
        else:
            frame_lbs = np.zeros(order.size)
        frame = [frame_lbs, 0]
        self.frames.append(frame)
        depth = len(S)
        try:
            for t, j in enumerate(order):
                frame[1] = t
                self._check_time()
                if depth == 0 and self.progress is not None:
                    self.progress(t / order.size)
                j = int(j)
                after = np.flatnonzero(allowed[j])
                if self._dominated(k1[j], k2[j], S + [int(cand[j])], cand[after], r - 1):
                    if k1[j] > self.best_key[0]:
                        break  # children are sorted by k1: all following ones are dominated too
                    continue
                child = self._child(node, j, after, r - 1)
                if child is not None:
                    self._node(child, r - 1)
        finally:
            self.frames.pop()

    def _pairs_exist(self, node, allowed, floor):
        """For a node with three axes to add: which children j can still be completed by a pair
        (l, q), by the pair pre-check of :meth:`_child` run for all j at once on (j, l, q) arrays."""
        cov, ov, g, h, P, Q = (node[x] for x in ("cov", "ov", "g", "h", "P", "Q"))
        ok = allowed[:, :, None] & allowed[:, None, :] & allowed[None, :, :]  # j < l < q
        m1 = np.minimum(P[:, :, None], P[:, None, :])  # (j, l, q)
        p_lo = np.maximum(P[None, :, :] - m1, 0.0)
        gl = g[None, :] - P  # child j's gain of l
        cub = (cov + g)[:, None, None] + gl[:, :, None] + gl[:, None, :] - p_lo
        ok &= cub >= floor
        if self.mode == "overlap" and self.best_key is not None:
            hl = h[None, :] + P - Q  # child j's added overlap of l
            q_hi = np.minimum(np.minimum(hl[:, :, None], hl[:, None, :]), Q[None, :, :] + m1)
            lbo = (ov + h)[:, None, None] + hl[:, :, None] + hl[:, None, :] - q_hi + p_lo
            inc1, inc2 = self.best_key[0], self.best_key[1]
            ok &= (lbo < inc1) | ((lbo == inc1) & (-cub <= inc2))
        return ok.any(axis=(1, 2))

    def _child(self, node, j, after, rc):
        """State after adding candidate position j; rc = axes still to add (>= 1)."""
        floor = self._floor()
        p = self.p
        if after.size < rc:
            return None
        cand = node["cand"]
        axis = int(cand[j])
        cov = node["cov"] + node["g"][j]
        ov = node["ov"] + node["h"][j]
        # the parent's Gram rows of j are the weights j shares with each candidate among the
        # uncovered (P) and once-covered (Q) classes: the child's g and h without touching classes
        s1 = node["P"][j, after]
        s2 = node["Q"][j, after]
        g = node["g"][after] - s1
        h = node["h"][after] + s1 - s2
        # single-axis filters: an axis whose own added overlap, or whose best coverage together
        # with the best other gains, already rules it out cannot appear in this subtree
        keep = cov + np.minimum(*_top_sums(g, rc)) >= floor
        if self.mode == "overlap" and self.best_key is not None:
            keep &= ov + h <= self.best_key[0]
        if np.count_nonzero(keep) < rc:
            return None
        if rc >= 2:
            # pair pre-check from the parent's matrices, before any Gram product.  For two more
            # axes l, q: the classes newly covered by j and seen by both weigh at most
            # min(s1_l, s1_q), which bounds the child's P_lq from below, hence the coverage of
            # {j, l, q} (plus the best rc - 2 other gains) from above and their overlap from below.
            # Every pair of a completion must pass, so a completion is a clique of rc axes in the
            # graph of passing pairs: axes with fewer than rc - 1 partners are peeled off.
            sub = np.flatnonzero(keep)
            a = after[sub]
            ix = np.ix_(a, a)
            ss = s1[sub]
            m1 = np.minimum(ss[:, None], ss[None, :])
            p_lo = np.maximum(node["P"][ix] - m1, 0.0)  # lower bound of the child's P
            gg = g[sub]
            extra = 0.0
            if rc > 2:
                top = -np.partition(-gg, rc - 3)[: rc - 2] if gg.size > rc - 2 else gg
                extra = float(top.sum())
            cub = cov + gg[:, None] + gg[None, :] - p_lo + extra
            ok = cub >= floor
            np.fill_diagonal(ok, False)
            if p.has_conflicts:
                ok &= ~p.conflict[np.ix_(cand[a], cand[a])]
            if self.mode == "overlap" and self.best_key is not None:
                hh = h[sub]
                q_hi = np.minimum(np.minimum(hh[:, None], hh[None, :]), node["Q"][ix] + m1)
                lbo = ov + hh[:, None] + hh[None, :] - q_hi + p_lo
                inc1, inc2 = self.best_key[0], self.best_key[1]
                ok &= (lbo < inc1) | ((lbo == inc1) & (-cub <= inc2))
            alive = np.ones(sub.size, bool)
            while True:
                partners = np.count_nonzero(ok, axis=1)
                dead = alive & (partners < rc - 1)
                if not dead.any():
                    break
                alive &= ~dead
                ok[dead, :] = False
                ok[:, dead] = False
            if np.count_nonzero(alive) < rc:
                return None
            if rc == 3 and np.count_nonzero(alive) <= _TENSOR_MAX:
                # triples of passing pairs: union <= sum g - (sum P - min P) (inclusion-exclusion
                # with the triple term at most min P); overlap >= once-covered classes hit
                # (Bonferroni: sum h - sum Q) + the largest pair among the uncovered classes
                al = np.flatnonzero(alive)
                okA = ok[np.ix_(al, al)]
                okT = okA[:, :, None] & okA[:, None, :] & okA[None, :, :]
                pl = p_lo[np.ix_(al, al)]
                g3 = gg[al]
                gsum = g3[:, None, None] + g3[None, :, None] + g3[None, None, :]
                psum = pl[:, :, None] + pl[:, None, :] + pl[None, :, :]
                pmin = np.minimum(np.minimum(pl[:, :, None], pl[:, None, :]), pl[None, :, :])
                cubT = cov + gsum - (psum - pmin)
                okT &= cubT >= floor
                if self.mode == "overlap" and self.best_key is not None:
                    h3 = hh[al]
                    qh = q_hi[np.ix_(al, al)]
                    hsum = h3[:, None, None] + h3[None, :, None] + h3[None, None, :]
                    qsum = qh[:, :, None] + qh[:, None, :] + qh[None, :, :]
                    pmax = np.maximum(np.maximum(pl[:, :, None], pl[:, None, :]), pl[None, :, :])
                    lboT = ov + hsum - qsum + pmax
                    okT &= (lboT < inc1) | ((lboT == inc1) & (-cubT <= inc2))
                used3 = okT.any(axis=(1, 2))
                if not used3.any():
                    return None
                alive[al[~used3]] = False
            keep[sub[~alive]] = False
        if not keep.all():
            sub = np.flatnonzero(keep)
            after, g, h = after[sub], g[sub], h[sub]
        cand2 = cand[after]
        child = dict(S=node["S"] + [axis], cov=cov, ov=ov, cand=cand2, g=g, h=h,
                     P=None, Q=None, deg=None)
        if rc >= 2:
            col = p.AT[axis]
            deg = node["deg"]
            R1 = np.flatnonzero((deg == 0) & col)  # classes j covers first
            R2 = np.flatnonzero((deg == 1) & col)  # classes j turns into overlap
            X1 = np.take(np.take(p.Af, R1, axis=0), cand2, axis=1)
            X2 = np.take(np.take(p.Af, R2, axis=0), cand2, axis=1)
            G1 = _wgram(X1, p.wf[R1])
            G2 = _wgram(X2, p.wf[R2])
            ix = np.ix_(after, after)
            child["P"] = node["P"][ix] - G1
            child["Q"] = node["Q"][ix] + G1 - G2
            d = deg + col  # 0, 1 or 2 (= two or more): all the search needs
            np.minimum(d, 2, out=d)
            child["deg"] = d
        return child


def _top_sums(g: np.ndarray, rc: int):
    """(sum of the rc largest g, g + sum of the rc - 1 largest g): min of the two bounds the best
    coverage gain of rc axes that include a given axis."""
    if rc == 1:
        return g, g
    top = -np.partition(-g, rc - 1)[:rc] if g.size > rc else g.copy()
    top = np.sort(top)[::-1]
    return np.full(g.shape, top[:rc].sum()), g + top[: rc - 1].sum()


# --------------------------------------------------------------------------------------------
# drivers
# --------------------------------------------------------------------------------------------


class _Outcome:
    """What a solver found, in reduced axis indices (converted to a SetupSelection at the end)."""

    def __init__(self, status, sel, lower_bound=None, note=""):
        self.status = status
        self.sel = list(sel)
        self.lower_bound = lower_bound
        self.note = note


def _progress_fn(progress, lo, hi, text):
    if progress is None:
        return None
    return lambda f: progress(lo + (hi - lo) * float(f), text)


def _heuristics(prob: _Problem, K: int) -> dict[int, tuple[list[int], int, int]]:
    """Greedy incumbent for every k <= K: the greedy run is deterministic, so its k-axis answer
    is the first k picks of the longest run (absent where zone conflicts stop it earlier)."""
    picks = _greedy(prob, min(K, prob.m))
    out = {}
    for k in range(1, len(picks) + 1):
        sel = picks[:k]
        c, o = prob.evaluate(sel)
        out[k] = (sel, c, o)
    return out


def _timeout_fallback(prob, heur, k_from, kmax) -> _Outcome:
    """Time limit hit before the smallest k was settled: best effort from the heuristics (local
    search, a fraction of a second even at 100k points x 200 axes), with no proof."""
    req = prob.required
    best = None
    for k in range(k_from, kmax + 1):
        if k not in heur:
            continue
        sel, c = heur[k][0], heur[k][1]
        if c < req:
            sel, _ = _local_search(prob, sel, "cover", 0)
            c = prob.evaluate(sel)[0]
        if c >= req:
            sel, _ = _local_search(prob, sel, "overlap", req)
            return _Outcome("feasible", sel, None,
                            "time limit reached before the number of set-ups was proven minimal")
        if best is None or c > best[0]:
            best = (c, sel)
    return _Outcome("unknown", best[1] if best else [], None, "time limit reached")


def _bnb_best_cover(prob, K, deadline, heur, progress):
    """Infeasible case: best subset of size <= K (max covered, min k, min overlap, min tuple)."""
    best = None  # (cov, k, key, sel)
    timed_out = False
    for k in range(1, min(K, prob.m) + 1):
        floor = 1 if best is None else best[0] + 1  # a larger k must cover strictly more
        inc = None
        if k in heur and heur[k][1] >= floor:
            inc = _local_search(prob, heur[k][0], "cover", floor)
        s = _Search(prob, k, "cover", floor, deadline, incumbent=inc,
                    progress=_progress_fn(progress, 0.5 + 0.5 * (k - 1) / K, 0.5 + 0.5 * k / K,
                                          f"best coverage with {k} set-ups"))
        try:
            s.run()
        except _Timeout:
            timed_out = True
        if s.best_sel is not None:
            c, _ = prob.evaluate(s.best_sel)
            if best is None or c > best[0]:
                best = (c, k, s.best_key, s.best_sel)
        if timed_out:
            break
    return (best[3] if best else []), timed_out


def _solve_bnb(prob: _Problem, K: int, deadline: float, progress) -> _Outcome:
    req = prob.required
    heur = _heuristics(prob, K)
    kmax = min(K, prob.m)
    kstar, found = None, None
    for k in range(1, kmax + 1):
        if progress:
            progress(0.3 * (k - 1) / kmax, f"is {k} set-up(s) enough?")
        if k in heur and heur[k][1] >= req:
            kstar, found = k, heur[k][0]
            break
        s = _Search(prob, k, "cover", req, deadline, stop_at_first=True)
        try:
            s.run()
        except _Timeout:
            return _timeout_fallback(prob, heur, k, kmax)
        if s.best_sel is not None:
            kstar, found = k, s.best_sel
            break
    if kstar is None:
        sel, timed_out = _bnb_best_cover(prob, K, deadline, heur, progress)
        note = "time limit reached: the best coverage shown may not be the maximum" if timed_out else ""
        return _Outcome("infeasible", sel, None, note)
    # stage 2: least overlap at k*
    inc = _local_search(prob, found, "overlap", req)
    s = _Search(prob, kstar, "overlap", req, deadline, incumbent=inc,
                progress=_progress_fn(progress, 0.3, 1.0, f"least overlap with {kstar} set-ups"))
    try:
        s.run()
    except _Timeout:
        ov = s.best_key[0]
        lb = ov if s.timeout_bound is None else min(ov, int(math.ceil(s.timeout_bound - 1e-9)))
        return _Outcome("feasible", s.best_sel, lb, "time limit reached")
    return _Outcome("optimal", s.best_sel, s.best_key[0])


# --------------------------------------------------------------------------------------------
# CP-SAT
# --------------------------------------------------------------------------------------------


class _CpModelBuilder:
    """CP-SAT model over weighted classes (Makki §3 as a partial set cover with overlap)."""

    def __init__(self, prob: _Problem):
        self.p = prob
        rows, cols = np.nonzero(prob.A)
        starts = np.searchsorted(rows, np.arange(prob.C + 1))
        self.inc = [cols[starts[c]:starts[c + 1]].tolist() for c in range(prob.C)]

    def build(self, *, k=None, kmax=None, min_cov=None, with_overlap=False):
        from ortools.sat.python import cp_model

        p = self.p
        model = cp_model.CpModel()
        x = [model.NewBoolVar(f"x{j}") for j in range(p.m)]
        cov_terms, ov_terms = [], []
        for c, J in enumerate(self.inc):
            w = int(p.w[c])
            xs = [x[j] for j in J]
            if len(J) == 1:
                cv = xs[0]
            else:
                cv = model.NewBoolVar(f"c{c}")
                model.AddBoolOr(xs).OnlyEnforceIf(cv)  # covered => some chosen axis sees it
            cov_terms.append((w, cv))
            if len(J) >= 2:
                if p.zone[c]:
                    model.AddAtMostOne(xs)  # functional zone: never seen twice
                elif with_overlap:
                    ov = model.NewBoolVar(f"o{c}")
                    # sum x - 1 <= (deg - 1) * ov, written with an enforcement literal
                    model.Add(sum(xs) <= 1).OnlyEnforceIf(ov.Not())
                    ov_terms.append((w, ov))
        if k is not None:
            model.Add(sum(x) == k)
        if kmax is not None:
            model.Add(sum(x) <= kmax)
            model.Add(sum(x) >= 1)
        cov_expr = sum(w * v for w, v in cov_terms)
        if min_cov is not None:
            model.Add(cov_expr >= int(min_cov))
        ov_expr = sum(w * v for w, v in ov_terms) if ov_terms else 0
        return model, x, cov_expr, ov_expr


def _cp_solve(model, deadline):
    from ortools.sat.python import cp_model

    solver = cp_model.CpSolver()
    solver.parameters.max_time_in_seconds = max(0.01, deadline - time.perf_counter())
    solver.parameters.num_workers = 1  # one worker: the search is deterministic
    solver.parameters.random_seed = 0
    status = solver.Solve(model)
    return solver, status


def _chosen(solver, x) -> list[int]:
    """Reduced axis indices set in a CP-SAT solution."""
    return [j for j, v in enumerate(x) if solver.Value(v)]


def _hint(model, x, sel):
    model.ClearHints()
    s = set(sel)
    for j, v in enumerate(x):
        model.AddHint(v, 1 if j in s else 0)


def _solve_cpsat(prob: _Problem, K: int, deadline: float, progress) -> _Outcome:
    from ortools.sat.python import cp_model

    OPT, FEAS, INF = cp_model.OPTIMAL, cp_model.FEASIBLE, cp_model.INFEASIBLE
    req = prob.required
    heur = _heuristics(prob, K)
    kmax = min(K, prob.m)
    builder = _CpModelBuilder(prob)

    kstar, found = None, None
    for k in range(1, kmax + 1):
        if progress:
            progress(0.3 * (k - 1) / kmax, f"CP-SAT: is {k} set-up(s) enough?")
        model, x, _, _ = builder.build(k=k, min_cov=req)
        if k in heur:
            _hint(model, x, heur[k][0])
        solver, st = _cp_solve(model, deadline)
        if st in (OPT, FEAS):
            kstar, found = k, _chosen(solver, x)
            break
        if st != INF:  # time limit
            return _timeout_fallback(prob, heur, k, kmax)
    if kstar is None:
        return _cpsat_best_cover(prob, builder, K, deadline, heur)
    if progress:
        progress(0.4, f"CP-SAT: least overlap with {kstar} set-ups")
    starts = [found] + ([heur[kstar][0]] if kstar in heur and heur[kstar][1] >= req else [])
    start = min((_local_search(prob, st_, "overlap", req) for st_ in starts),
                key=lambda t: t[1])[0]  # warm start: the better of the two improved subsets
    # stage 2: least overlap, then most coverage, as one objective: (n + 1) * overlap - covered
    model, x, cov_expr, ov_expr = builder.build(k=kstar, min_cov=req, with_overlap=True)
    _hint(model, x, start)
    scale = prob.n + 1
    model.Minimize(scale * ov_expr - cov_expr)
    solver, st = _cp_solve(model, deadline)
    if st not in (OPT, FEAS):  # no time left at all: keep the stage-1 answer
        return _Outcome("feasible", start, None, "time limit reached")
    sel = _chosen(solver, x)
    if st == OPT:
        return _Outcome("optimal", sel, prob.evaluate(sel)[1])
    # covered <= n, so overlap >= bound / (n + 1)
    lb = int(math.ceil(solver.BestObjectiveBound() / scale - 1e-9))
    c1, o1 = prob.evaluate(sel)
    c0, o0 = prob.evaluate(start)
    if (o0, -c0) < (o1, -c1):
        sel, o1 = start, o0
    return _Outcome("feasible", sel, max(0, min(lb, o1)), "time limit reached")


def _cpsat_best_cover(prob, builder, K, deadline, heur) -> _Outcome:
    from ortools.sat.python import cp_model

    OPT, FEAS = cp_model.OPTIMAL, cp_model.FEASIBLE
    if prob.m == 0:
        return _Outcome("infeasible", [], None)
    kmax = min(K, prob.m)
    best_h = max(heur.values(), key=lambda t: (t[1], -len(t[0])))[0] if heur else []
    note = "time limit reached: the best coverage shown may not be the maximum"

    model, x, cov_expr, _ = builder.build(kmax=kmax)
    model.Maximize(cov_expr)
    _hint(model, x, best_h)
    solver, st = _cp_solve(model, deadline)
    if st not in (OPT, FEAS):
        return _Outcome("infeasible", best_h, None, note)
    sel = _chosen(solver, x)
    if st != OPT:
        return _Outcome("infeasible", sel, None, note)
    cbest = prob.evaluate(sel)[0]
    # fewest set-ups at that coverage, then least overlap
    model, x, cov_expr, ov_expr = builder.build(kmax=kmax, with_overlap=True)
    model.Add(cov_expr >= cbest)
    model.Minimize((prob.n + 1) * sum(x) + ov_expr)  # lexicographic: k first, then overlap
    _hint(model, x, sel)
    solver, st = _cp_solve(model, deadline)
    if st == OPT:
        return _Outcome("infeasible", _chosen(solver, x), None)
    if st == FEAS:
        sel2 = _chosen(solver, x)
        if len(sel2) < len(sel) or (len(sel2) == len(sel) and prob.evaluate(sel2)[1] < prob.evaluate(sel)[1]):
            sel = sel2
    return _Outcome("infeasible", sel, None,
                    "time limit reached: fewest set-ups at the best coverage not proven")


# --------------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------------


def _setups(k: int) -> str:
    """'1 set-up covers' / '3 set-ups cover'."""
    return f"{k} set-up covers" if k == 1 else f"{k} set-ups cover"


def _make_result(*, status, sel_orig, covered, overlap, n, required, K, coverage_target, lower_bound,
                 solver, n_classes, n_axes_kept, seconds, note="", min_points=1) -> SetupSelection:
    sel_orig = np.array(sorted(int(s) for s in sel_orig), dtype=np.int64)
    k = int(sel_orig.size)
    frac = covered / n
    target = f"{coverage_target * 100:g}"
    gap = None
    best_at_max = None
    head = f"{_setups(k)} {frac * 100:.1f} % with {overlap} overlap points"
    if status == "optimal":
        gap = 0.0
        lower_bound = overlap
        msg = f"{head} (proven optimal)"
    elif status == "feasible":
        note = note or "time limit reached"
        if lower_bound is not None:
            gap = (overlap - lower_bound) / max(overlap, 1)
            msg = (f"{head} ({note}; best found: at least {lower_bound} overlap points are "
                   f"unavoidable, gap {gap * 100:.1f} %)")
        else:
            msg = f"{head} ({note}; not proven)"
    elif status == "infeasible":
        lower_bound = None
        best_at_max = frac
        if n_axes_kept == 0:
            msg = (f"no tool axis sees at least {min_points} points, so no set-up reaches {target} % "
                   f"coverage: change the part set-up or lower setups.min_points")
        else:
            none = "no single set-up reaches" if K == 1 else f"no {K} set-ups reach"
            msg = (f"{none} {target} % coverage; the best {_setups(k)} {frac * 100:.1f} %: "
                   f"change the part set-up or raise setups.max_setups")
            if note:
                msg += f" ({note})"
    else:  # unknown
        lower_bound = None
        msg = (f"time limit reached before {target} % coverage was reached or proven unreachable; "
               f"the best found, {_setups(k)} {frac * 100:.1f} %: raise the time limit")
    return SetupSelection(
        status=status, selected=sel_orig, k=k, n_points=n, covered=int(covered), coverage=frac,
        overlap=int(overlap), required_covered=int(required), lower_bound=lower_bound, gap=gap,
        best_coverage_at_max=best_at_max, solver=solver, n_classes=int(n_classes),
        n_axes_kept=int(n_axes_kept), seconds=float(seconds), message=msg,
    )


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
    result is ``"infeasible"`` with the best-coverage subset of at most ``max_setups`` axes.

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
    if progress:
        progress(0.0, "merging identical visibility rows")
    name = "cpsat" if solver == "cpsat" else "branch_and_bound"
    with _single_threaded_blas():
        prob = _Problem(V, zone, min_points, required)
        if name == "cpsat":
            out = _solve_cpsat(prob, K, deadline, progress)
        else:
            out = _solve_bnb(prob, K, deadline, progress)
        covered, overlap = prob.evaluate(out.sel)
    if progress:
        progress(1.0, "set-ups chosen")
    return _make_result(
        status=out.status, sel_orig=prob.axes[out.sel] if out.sel else [], covered=covered,
        overlap=overlap, n=prob.n, required=required, K=K, coverage_target=cov_target,
        lower_bound=out.lower_bound, solver=name, n_classes=prob.C, n_axes_kept=prob.n_axes_kept,
        seconds=time.perf_counter() - t0, note=out.note, min_points=min_points,
    )


def brute_force_setups(visibility, *, coverage=0.95, max_setups=5, min_points=1, zone_mask=None
                       ) -> SetupSelection:
    """Exhaustive reference for :func:`select_setups` (Makki et al. 2010, §3.1, as the paper does it).

    Enumerates every combination of the kept axes with ``itertools.combinations`` (the binomial
    coefficient of §3.1), directly on the point rows (no classes, no column merging), with the same
    rules and tie order as :func:`select_setups`.  Exponential: small inputs only (tests).
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
