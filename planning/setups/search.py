"""Set-up selection by branch and bound (``solver="branch_and_bound"``, also ``"auto"``).

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1 made exact.  The paper enumerates every
combination with the binomial coefficient; here an exact depth-first search runs over axis
combinations on the weighted classes of :class:`~planning.setups.problem._Problem` (axes ordered by
size; a subset is visited once, in that order).  Every node keeps, for its remaining candidate axes,
the weight (points) each would newly cover (``g``), the weight it would turn into overlap (``h``) and
the weighted Gram matrices of the candidates over the still uncovered classes (``P``) and over the
classes covered exactly once (``Q``); a child's ``g`` and ``h`` are read off the parent's ``P`` and
``Q`` rows, so only a child that survives the bounds (:mod:`planning.setups.bounds`) pays for its two
small Gram products.  Pruning compares (lower bound, upper bound, smallest reachable index tuple) with
the incumbent's key, so ties resolve exactly as in the brute force.

The drivers (:func:`_solve_bnb`) find the smallest ``k`` that reaches the coverage, then the least
overlap at that ``k``.  The incumbent comes from greedy max coverage improved by one- and two-axis
exchanges (:mod:`planning.setups.heuristics`; the exchange of two axes is evaluated for all incoming
pairs at once from Gram matrices).  The matrix products are small, so BLAS runs single-threaded during
the call (see :func:`planning.setups.select._single_threaded_blas`).  Measured
(``bench/bench_setups.py``): the proven optimum for 100k bone-like normals x 145-206 axes, max 5
set-ups, in 0.2-0.9 s on the shared 2-core machine.

Infeasibility.  Where greedy misses the coverage with ``max_setups`` = K axes, the price bound of
:mod:`planning.setups.lagrange` is computed first: Lagrangian prices of the classes from the dual of
the LP relaxation of max coverage with K axes (HiGHS), which bound the coverage of any K axes, and so
of any k <= K (coverage never falls as axes are added; the relaxation ignores zone conflicts, which
only remove subsets).  When that bound is below the required count, no k <= K reaches the coverage:
proven at the root, without the existence search per k the search needed before.  Otherwise the
existence searches run as in the feasible case, with the prices as an extra bound.  The answer of
an infeasible call (:func:`_bnb_best_cover`) is then one "cover" search at K from the greedy
incumbent (most covered, least overlap, smallest tuple), pruned by the prices (child bounds
``W - M + s_j + (r - 1 best s_l - Pm_jl)``, see :meth:`_Search._price_bounds`), then the smaller k
that reach the same coverage (most ruled out by the price bound at the root); with zone conflicts a
search per k.  Measured (``bench/bench_infeasible.py --before 43c11a9``, shared 2-core machine under
a load of 4-6): the femur-like defaults (100k points x 145 axes, best 94.1 % against 95 %) in 1.3 s
instead of 47 s, a 10k-point subsample of it in 0.2 s instead of 16 s (same answers; the feasible
0.90 in 3.2 s and 0.7 s); the LP bound there is 94,878 points against the best 94,727 and the
required 95,631.  On a time-out the best found is returned with the price bound as the most any
selection can cover.

Range scans (issue 32, ``bench/bench_proofs_range.py``).  Three things made proofs on simulated range
scans (10k-25k sampled points, 8k-18k classes x 130 axes) take seconds: (1) for one or two set-ups
the LP was solved (0.5-2.5 s) although the search settles them at its root; they are now proven
from the Gram matrix (:func:`_small_max_cover`); (2) where the price bound does not prove
infeasibility, an existence search at max_setups and then the "cover" search for the answer ran
over the same tree; the "cover" search now runs first and settles both (it stops at the first
subset reaching the coverage when there is one); (3) a node paid for the Gram matrix of the
once-covered classes (the largest set below the root) and for copying whole class rows: only the
least-overlap search keeps ``Q`` and ``h`` now, the coverage searches evaluate the overlap at the
leaves of the best coverage, build ``P`` from the still uncovered classes where they are fewer
than the newly covered ones, and gather only the candidates' columns.  Range half sphere R 100 mm
(25,359 sampled points): 0.97 with max 2 set-ups 1.75 s -> 0.05 s, 0.995 with 3 1.52 s -> 0.62 s,
0.999 with 4 18.0 s -> 3.1 s; coverage 1.0 with 5 (the best 5 leave 8 points) still takes ~50 s:
there the LP relaxation covers every point and the search has no strong bound.  The leaves are what
it costs there: the coverage searches now count the last two to four axes on bit sets
(:mod:`planning.setups.kernels`, where at most ``_BITS_SHARE`` of the points may be left uncovered),
a subset dropped after the first words of classes it leaves uncovered; nodes with three or four axes
to add hand all their children to one kernel call (no child states, Gram matrices or pre-checks
below them).  Same matrix, same run against 7f7b0d2: 1.0 with 5 49 s -> 1.6 s, 0.999 with 4
3.1 s -> 0.7 s, 0.995 with 3 1.1 s -> 0.7 s (of which the LP is 0.5 s).
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np

from planning.setups.bounds import (
    _TENSOR_MAX,
    _branch_bounds,
    _completable,
    _pairs_exist,
    _top_sums,
)
from planning.setups.heuristics import _heuristics, _local_search, _timeout_fallback
from planning.setups.kernels import _Bits
from planning.setups.lagrange import _price_bound, _prices
from planning.setups.problem import (
    _key_cover,
    _key_overlap,
    _Outcome,
    _Problem,
    _wgram,
    _wgram_t,
)


def _gather(prob: _Problem, rows, cols) -> np.ndarray:
    """The axes x classes matrix at ``rows`` x ``cols``, as floats: the boolean rows first, then
    their columns (a quarter of the time of a 2-D fancy index of the float matrix: 0.7 against 3 ms
    for 100 axes x 4,500 classes, the size of a range scan's node one axis below the root)."""
    return np.take(prob.AT[rows], cols, axis=1).astype(prob.ftype)


def _bits_of(prob: _Problem) -> _Bits:
    """The problem's classes as bit sets (built once per problem)."""
    b = getattr(prob, "_bits", None)
    if b is None:
        b = prob._bits = _Bits(prob.A, prob.w)
    return b


class _Timeout(Exception):
    pass


class _Found(Exception):
    pass


class _Budget(Exception):
    """A probe search without prices visited more nodes than ``max_nodes``: worth the LP."""


# nodes an existence search runs without prices before the price bound is computed and the search
# restarted with it (a search that needs more is a hard one; the LP then costs less than the nodes
# it saves, and often settles the search at the root)
_PROBE_NODES = 40
# the least-overlap search at k* gets the prices where greedy's k* axes cover at most this share of
# the points more than required: near the largest coverage the price bound prunes most subtrees
# (femur-like, 0.94: 677 -> 93 nodes), far below it it prunes little and costs a Gram product a node
_NEAR_CEILING = 0.005
# the LP's column generation stops once a round lowered the bound by less than this many points
# (planning.setups.lagrange._prices; a weaker bound only prunes less, the answers stay exact)
_PRICE_MIN_GAIN = 1.0
# the fewest axes the prices are computed for: a search for one or two axes is settled at its root
# (every pair evaluated exactly from the Gram matrix, a few milliseconds), while the LP costs 0.5-2 s
# on range-scan matrices (18k classes x 133 axes: range half sphere R 100 mm, issue 32)
_MIN_PRICE_R = 3
# the last two to four axes of a coverage search are counted on bit sets (planning.setups.kernels)
# where at most this share of the points may be left uncovered: there a subset that misses is seen
# to miss after a word or two; far below the largest coverage (femur-like 0.90: 7.5 %) every subset
# is counted to its end, and the Gram matrices were quicker
_BITS_SHARE = 0.05
# progress from inside a search: the children of the nodes down to this depth (the root 0) tell where
# the search is, the root's always, the deeper ones at most every _PROGRESS_EVERY_S seconds (a root
# child of a least-overlap search on a range scan took up to 0.7 s, issue 34)
_PROGRESS_DEPTH = 2
_PROGRESS_EVERY_S = 0.1


class _Search:
    """Exact DFS over k-subsets of reduced axes (one run = one k, one mode).

    mode "overlap": minimise (overlap, -covered, tuple) subject to covered >= floor.
    mode "cover":   minimise (-covered, overlap, tuple) subject to covered >= floor.
    mode "max":     the largest covered >= floor, nothing else: only a strictly larger coverage
                    than the incumbent's is looked for (ties are settled by the caller).
    ``stop_at_first``: stop as soon as any subset with covered >= floor is found (existence).
    ``stop_cover``: stop as soon as a subset covers at least this many points.

    The state every method shares: the incumbent (``best_key``, ``best_sel``), the open frames of
    the DFS (each with its children's lower bounds, read for the bound reported at a time-out) and
    the node count.  The bound arithmetic lives in :mod:`planning.setups.bounds`; a node is a dict
    (``S`` chosen axes, ``cov``/``ov`` point counts, ``cand`` candidate axes, ``g``, ``h``, ``P``,
    ``Q`` and ``deg`` the classes' coverage degree capped at 2, or ``U`` the uncovered classes as
    indices where the overlap is not tracked, see ``track_overlap``).
    """

    def __init__(self, prob: _Problem, k: int, mode: str, floor: float, deadline: float,
                 incumbent=None, stop_at_first=False, progress=None, prices=None, max_nodes=None,
                 stop_cover=None):
        self.p = prob
        # Lagrangian prices of the classes (planning.setups.lagrange), or None: no price bound
        self.mu = None if prices is None else np.asarray(prices, dtype=prob.ftype)
        self.W = float(prob.w.sum())
        self.k = k
        self.mode = mode
        self.floor = float(floor)
        self.deadline = deadline
        self.stop_at_first = stop_at_first
        self.stop_cover = stop_cover  # stop once a subset covers this much (None: never)
        self.keyf = _key_overlap if mode == "overlap" else _key_cover
        self.strict = mode == "max"
        if self.strict:
            self.mode = mode = "cover"
        # only the least-overlap search keeps the once-covered Gram matrix Q and the gains h: in
        # the other modes overlap only breaks exact ties of coverage, so it is evaluated at the
        # leaves that tie the best coverage (on range scans the once-covered classes outnumber the
        # newly covered ones 2:1 below the root, and Q was the largest product; issue 32)
        self.track_overlap = mode == "overlap"
        # the last two axes of a coverage search: every pair counted on bit sets, stopping at the
        # first words that show it misses the coverage (planning.setups.kernels), not from P
        self.bits = None if self.track_overlap or prob.has_conflicts else _bits_of(prob)
        self.best_key = None
        self.best_sel = None
        if incumbent is not None:
            sel, key = incumbent
            if key is not None:
                self.best_key, self.best_sel = key, list(sel)
        self.frames: list = []
        self.nodes = 0
        self.progress = progress
        self._path: list = []             # (child, children) at each depth down to _PROGRESS_DEPTH
        self._reported = -math.inf        # when progress was last called (s, perf_counter)
        self.timeout_bound = None
        self.max_nodes = max_nodes

    # incumbent handling -------------------------------------------------------------------
    def _offer(self, sel, cov, ov):
        key = self.keyf(int(round(ov)), int(round(cov)), self.p.tuple_of(sel))
        if self.best_key is None or key < self.best_key:
            self.best_key, self.best_sel = key, list(sel)
        if self.stop_at_first or (self.stop_cover is not None and cov >= self.stop_cover):
            raise _Found

    def _floor(self) -> float:
        """Coverage a subtree must still be able to reach: the constraint, and in "cover" mode
        also the incumbent's coverage (ties may still win on overlap or indices)."""
        if self.mode == "cover" and self.best_key is not None:
            return max(self.floor, float(-self.best_key[0]) + (1.0 if self.strict else 0.0))
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
            S=[], deg=np.zeros(p.C, np.uint8), U=np.arange(p.C), cov=0.0, ov=0.0, cand=cand,
            g=p.sizes[cand].copy(), h=np.zeros(cand.size),
            P=p.gram[np.ix_(cand, cand)] if k >= 2 else None,
            Q=np.zeros((cand.size, cand.size)) if k >= 2 and self.track_overlap else None,
        )
        if self.mu is not None:
            Pm = _wgram(p.Af, self.mu)[np.ix_(cand, cand)]
            node.update(M=float(self.mu.sum(dtype=np.float64)), s=np.diag(Pm).copy(),
                        Pm=Pm if k >= 2 else None)
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

    def _bits_now(self) -> bool:
        """Whether the last axes are counted on bit sets now: in the coverage searches without zone
        conflicts, once the coverage still allowed to be missed is at most :data:`_BITS_SHARE` of
        the points (the floor only rises, so a node built for them keeps them)."""
        return self.bits is not None and self.W - self._floor() <= _BITS_SHARE * self.W

    def _count_node(self, count=1):
        self.nodes += count
        if self.max_nodes is not None and self.nodes > self.max_nodes:
            raise _Budget

    def _node(self, node, r):
        self._count_node()
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
        ok = covs >= floor
        if not ok.any():
            return
        idx = np.flatnonzero(ok)
        ovs = (ov + h)[idx] if self.track_overlap else None
        self._pick(S, [(int(i),) for i in idx], covs[idx], ovs, cand)

    def _leaves2(self, node):
        floor = self._floor()
        cov, ov, g, h, cand, S = node["cov"], node["ov"], node["g"], node["h"], node["cand"], node["S"]
        M = cand.size
        if M < 2:
            return
        if node["P"] is None or self._bits_now():
            self._bit_pairs(S, cand, self.bits.uncovered(S))
            return
        allowed = self._allowed(cand)
        covm = cov + g[:, None] + g[None, :] - node["P"]
        ok = allowed & (covm >= floor)
        if not ok.any():
            return
        ia, ib = np.nonzero(ok)
        covs = covm[ia, ib]
        ovs = None
        if self.track_overlap:
            Q, P = node["Q"], node["P"]
            ovs = ov + h[ia] + h[ib] - Q[ia, ib] + P[ia, ib]
        self._pick(S, list(zip(ia.tolist(), ib.tolist(), strict=True)), covs, ovs, cand)

    def _bit_triples(self, S, cand, order):
        """The children ``order`` (positions into ``cand``, in that order) of a node with three axes
        to add: every triple j < l < q reaching the floor, counted at once on bit sets
        (:mod:`planning.setups.kernels`), then each child's offered as :meth:`_leaves2` would offer
        its pairs (filtered again by the floor, which rises as the incumbent improves).  Each child
        counts as a node; a child without such a triple costs nothing more."""
        self._check_time()
        self._count_node(order.size)
        smax = math.floor(self.W - self._floor() + 1e-9)
        if smax < 0:
            return
        leaves = self.bits.triples_within(self.bits.uncovered(S), cand, order, smax)
        self._offer_children(S, cand, order, leaves)

    def _bit_quads(self, S, cand, g, P, order) -> bool:
        """The children ``order`` of a node with four axes to add, as :meth:`_bit_triples` one level
        up: each child's candidates filtered by their gains (from the node's ``g`` and ``P``, as
        :meth:`_child` filters them), then every quadruple reaching the floor counted on bit sets
        and offered per child.  False (nothing done) where too many quadruples reach the floor."""
        self._check_time()
        smax = math.floor(self.W - self._floor() + 1e-9)
        if smax < 0:
            return True
        leaves, nodes = self.bits.quads_within(self.bits.uncovered(S), cand, g, P, order, smax)
        if leaves is None:
            return False
        self._count_node(int(nodes.sum()))
        self._offer_children(S, cand, order, leaves)
        return True

    def _offer_children(self, S, cand, order, leaves):
        """A kernel's leaves (rows: positions into ``cand``, the child first, the weight left last,
        grouped by child in the order of ``order``) offered child by child as the search would
        (filtered by the floor of the moment), with the progress reports of the children of a node
        down to :data:`_PROGRESS_DEPTH`."""
        depth = len(S)
        report = self.progress is not None and depth <= _PROGRESS_DEPTH
        if leaves.shape[0] == 0 and not report:
            return
        pos = np.empty(cand.size, np.int64)
        pos[order] = np.arange(order.size)
        starts = np.searchsorted(pos[leaves[:, 0]], np.arange(order.size + 1))
        for t in (range(order.size) if report else np.flatnonzero(np.diff(starts))):
            if report:
                self._report(depth, int(t), order.size)
            rows = leaves[starts[t]:starts[t + 1]]
            rows = rows[rows[:, -1] <= math.floor(self.W - self._floor() + 1e-9)]
            if rows.shape[0]:
                self._pick(S, [tuple(x) for x in rows[:, :-1].tolist()], self.W - rows[:, -1].astype(np.float64),
                           None, cand)

    def _bit_pairs(self, S, cand, unc):
        """The leaves of a node with two axes to add (chosen ``S``, its uncovered classes ``unc`` as
        bit set words): every pair of ``cand`` reaching the floor, counted on bit sets
        (:mod:`planning.setups.kernels`), offered as :meth:`_leaves2` offers them."""
        smax = math.floor(self.W - self._floor() + 1e-9)
        if smax < 0 or cand.size < 2:
            return
        ia, ib, left = self.bits.pairs_within(unc, cand, smax)
        if ia.size:
            self._pick(S, list(zip(ia.tolist(), ib.tolist(), strict=True)), self.W - left.astype(np.float64),
                       None, cand)

    def _pick(self, S, pos_tuples, covs, ovs, cand):
        """Best of the evaluated leaves (positions into cand) offered to the incumbent; ``ovs`` None
        (overlap not tracked): evaluated exactly for the leaves of the best coverage only."""
        if ovs is None:
            m1 = float(covs.max())
            if self.best_key is not None and -m1 > self.best_key[0]:
                return
            top = np.flatnonzero(covs == m1)
            pos_tuples = [pos_tuples[b] for b in top]
            covs = covs[top]
            ovs = np.array([float(self.p.evaluate(S + [int(cand[q]) for q in t])[1]) for t in pos_tuples])
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

    def _overlap_incumbent(self):
        """The incumbent key where the overlap bounds apply (mode "overlap"), else None."""
        return self.best_key if self.mode == "overlap" else None

    def _branch(self, node, r):
        """Children of a node with r >= 3 axes to add, best lower key first, bounded and pruned."""
        floor = self._floor()
        cov, ov, g, h, P, Q, cand, S = (node[x] for x in ("cov", "ov", "g", "h", "P", "Q", "cand", "S"))
        M = cand.size
        if M < r:
            return
        allowed = self._allowed(cand)
        if P is None:  # three axes left on bit sets (no Gram matrix): the best gains bound the children
            cub = cov + np.minimum(*_top_sums(g, r))
            if node.get("s") is not None:
                cub = np.minimum(cub, self.W - node["M"] + np.minimum(*_top_sums(node["s"], r)))
            viable, k1, k2, lb = cub >= floor, -cub, ov + h, ov + h
        else:
            lub = self._price_bounds(node, allowed, r) if node.get("Pm") is not None else None
            viable, k1, k2, lb = _branch_bounds(cov, ov, g, h, P, Q, allowed, r, floor, self.mode, lub)
        if r == 3 and P is not None and M <= _TENSOR_MAX and viable.any() and not self._bits_now():
            viable &= _pairs_exist(node, allowed, floor, self._overlap_incumbent())
        idx = np.flatnonzero(viable)
        if idx.size == 0:
            return
        order = idx[np.lexsort((idx, k2[idx], k1[idx]))]
        if self.mode == "overlap":
            frame_lbs = lb[order]
        else:
            frame_lbs = np.zeros(order.size)
        frame = [frame_lbs, 0]
        if r == 3 and (P is None or self._bits_now()):
            self._bit_triples(S, cand, order)
            return
        if r == 4 and self._bits_now() and self._bit_quads(S, cand, g, P, order):
            return
        self.frames.append(frame)
        depth = len(S)
        try:
            for t, j in enumerate(order):
                frame[1] = t
                self._check_time()
                if self.progress is not None and depth <= _PROGRESS_DEPTH:
                    self._report(depth, t, order.size)
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

    def _report(self, depth, t, size):
        """Progress: the share of the root's children done, refined by the child's place at each depth
        down to :data:`_PROGRESS_DEPTH` (``t`` of ``size`` at ``depth``), so that a root child that
        takes seconds still moves it; the root's children always, deeper ones at most every
        :data:`_PROGRESS_EVERY_S`. Never backwards within one search (a deeper share stays below the
        next sibling's)."""
        del self._path[depth:]
        self._path.append((t, size))
        now = time.perf_counter()
        if depth > 0 and now - self._reported < _PROGRESS_EVERY_S:
            return
        self._reported = now
        f, scale = 0.0, 1.0
        for ti, si in self._path:
            f += scale * ti / si
            scale /= si
        self.progress(f)

    def _price_bounds(self, node, allowed, r):
        """Price bound (planning.setups.lagrange) of each child j of a node with r axes to add: the
        coverage of j and any r - 1 allowed later axes is at most ``W - M + s_j`` plus the r - 1
        largest ``s_l - Pm_jl`` (the prices l still collects once j covers its classes)."""
        s, Pm = node["s"], node["Pm"]
        T = np.where(allowed, s[None, :] - Pm, -np.inf)
        t = r - 1
        if T.shape[1] > t:
            T = -np.partition(-T, t - 1, axis=1)[:, :t]
        return self.W - node["M"] + s + T.sum(axis=1)

    def _child(self, node, j, after, rc):
        """State after adding candidate position j; rc = axes still to add (>= 1); None when the
        bounds rule the child out before its Gram products are paid for."""
        floor = self._floor()
        if after.size < rc:
            return None
        cand = node["cand"]
        axis = int(cand[j])
        cov = node["cov"] + node["g"][j]
        ov = node["ov"] + node["h"][j]
        # the parent's Gram rows of j are the weights j shares with each candidate among the
        # uncovered (P) and once-covered (Q) classes: the child's g and h without touching classes
        s1 = node["P"][j, after]
        g = node["g"][after] - s1
        if self.track_overlap:
            h = node["h"][after] + s1 - node["Q"][j, after]
        else:
            h = node["h"][after]  # zeros: not tracked
        inc = self._overlap_incumbent()
        # single-axis filters: an axis whose own added overlap, or whose best coverage together
        # with the best other gains, already rules it out cannot appear in this subtree
        keep = cov + np.minimum(*_top_sums(g, rc)) >= floor
        sc = Mc = None
        if node.get("Pm") is not None:  # the same with the prices: W - M + (best rc price gains)
            sc = node["s"][after] - node["Pm"][j, after]
            Mc = node["M"] - node["s"][j]
            keep &= self.W - Mc + np.minimum(*_top_sums(sc, rc)) >= floor
        if inc is not None:
            keep &= ov + h <= inc[0]
        if np.count_nonzero(keep) < rc:
            return None
        bits = self._bits_now()  # the child's last two or three axes on bit sets: no P, no pre-check
        if (rc == 2 or (rc == 3 and not bits)) and not _completable(
                self.p, node, after, keep, s1, g, h, cov, ov, rc, floor, inc):
            return None
        if not keep.all():
            sub = np.flatnonzero(keep)
            after, g, h = after[sub], g[sub], h[sub]
            if sc is not None:
                sc = sc[sub]
        return self._build_child(node, axis, after, cov, ov, g, h, rc, sc, Mc)

    def _build_child(self, node, axis, after, cov, ov, g, h, rc, sc=None, Mc=None):
        """The child's state: its candidates ``after`` (positions into the parent's) with gains g, h;
        with rc >= 2 axes still to add also P, Q and the class degrees, updated by two small weighted
        Gram products over the classes the new axis covers first and turns into overlap."""
        p = self.p
        cand2 = node["cand"][after]
        child = dict(S=node["S"] + [axis], cov=cov, ov=ov, cand=cand2, g=g, h=h,
                     P=None, Q=None, deg=None, U=None)
        if rc == 4 and self._bits_now():  # its quadruples on bit sets: the prices no longer needed
            sc = None
        if rc >= 4 or (rc >= 2 and not self._bits_now()):  # two or three left on bit sets: no P
            col = p.AT[axis]
            ix = np.ix_(after, after)
            # the candidates' rows of the axes x classes matrix over the classes that count only:
            # a child has few candidates (21 of 133 axes on average on range scans, over 3k + 7k
            # classes), and copying whole class rows first cost 6x the products (issue 32)
            R0 = None
            if self.track_overlap:
                deg = node["deg"]
                R1 = np.flatnonzero((deg == 0) & col)  # classes j covers first
                if rc >= 3:  # the child's children need its degrees
                    d = deg + col  # 0, 1 or 2 (= two or more): all the search needs
                    np.minimum(d, 2, out=d)
                    child["deg"] = d
            else:  # the uncovered classes as indices: few below the root
                U = node["U"]
                inside = col[U]
                R1, R0 = U[inside], U[~inside]  # covered first by j / still uncovered
                if rc >= 3:
                    child["U"] = R0
                if R0.size >= R1.size:  # P from scratch over R0 where fewer
                    R0 = None
            if R0 is not None:
                Y0 = _gather(p, cand2, R0)
                child["P"] = _wgram_t(Y0, p.wf[R0])
                if sc is not None:
                    child["Pm"] = _wgram_t(Y0, self.mu[R0])
            else:
                Y1 = _gather(p, cand2, R1)
                G1 = _wgram_t(Y1, p.wf[R1])
                child["P"] = node["P"][ix] - G1
                if sc is not None:
                    child["Pm"] = node["Pm"][ix] - _wgram_t(Y1, self.mu[R1])
            if self.track_overlap:
                R2 = np.flatnonzero((deg == 1) & col)  # classes j turns into overlap
                Y2 = _gather(p, cand2, R2)
                child["Q"] = node["Q"][ix] + G1 - _wgram_t(Y2, p.wf[R2])
        if sc is not None:
            child.update(s=sc, M=Mc)
        return child


# --------------------------------------------------------------------------------------------
# drivers
# --------------------------------------------------------------------------------------------


def _small_max_cover(prob: _Problem, k: int) -> float:
    """The largest coverage of at most k <= 2 reduced axes, exactly (zone conflicts respected), from
    the sizes and the Gram matrix: the root proof where the LP is not worth its cost."""
    if prob.m == 0 or k < 1:
        return 0.0
    best = float(prob.sizes.max())
    if k >= 2 and prob.m >= 2:
        ok = np.triu(np.ones((prob.m, prob.m), bool), 1) & ~prob.conflict
        if ok.any():
            cov = prob.sizes[:, None] + prob.sizes[None, :] - prob.gram
            best = max(best, float(cov[ok].max()))
    return best


def _root_bound(prob: _Problem, prices, k: int) -> float:
    """No k axes cover more than this: exact for k <= 2, else the price bound (inf without prices)."""
    if k < _MIN_PRICE_R:
        return _small_max_cover(prob, k)
    return math.inf if prices is None else _price_bound(prob, prices, k)


def _progress_fn(progress, lo, hi, text):
    """progress(fraction) of one search mapped onto [lo, hi] of the whole call, with ``text``."""
    if progress is None:
        return None
    return lambda f: progress(lo + (hi - lo) * float(f), text)


def _best_cover_at(prob, k, floor, incumbent, deadline, prices, running, stop_cover=None):
    """The best k-subset in the infeasible order (most covered, least overlap, smallest tuple)
    among those covering at least ``floor``: a "cover" search from the ``incumbent`` (sel or None).
    Returns the search (``best_sel`` None where no k axes reach ``floor``); the search is also put
    in the list ``running`` first, so that a caller catching _Timeout can read its best found."""
    inc = None
    if incumbent:
        c, o = prob.evaluate(incumbent)
        if c >= floor:
            inc = (list(incumbent), _key_cover(o, c, prob.tuple_of(incumbent)))
    s = _Search(prob, k, "cover", floor, deadline, incumbent=inc, prices=prices, stop_cover=stop_cover)
    running.append(s)
    s.run()
    return s


def _bnb_best_cover(prob, K, deadline, heur, progress, prices, bound, at_kmax=None):
    """Infeasible case (proven before the call): the best subset of at most K axes, in the order of
    :mod:`planning.setups.select` (most covered, then fewest axes, least overlap, smallest tuple).

    Without zone conflicts coverage never falls when an axis is added, so one "cover" search at K,
    from the greedy incumbent and bounded by the prices of :mod:`planning.setups.lagrange`, settles
    the largest coverage C* and the least overlap and smallest tuple at K; then each smaller k is
    asked whether it reaches C* too (the price bound rules most of them out at the root; else an
    existence search with floor C*), and the first that does is searched again.  With zone conflicts
    a subset may not extend, so every k is searched in turn, a larger k needing strictly more.
    ``at_kmax``: that "cover" search at K, already run to its end (by :func:`_solve_bnb`, which
    settles infeasibility with it where the price bound does not).
    Returns (sel, note); the note says what a time-out left unproven (``bound``: the price bound,
    no selection of at most K axes covers more)."""
    kmax = min(K, prob.m)
    if kmax == 0:
        return [], ""
    best = None  # (covered, k, sel)
    ks = range(1, kmax + 1) if prob.has_conflicts else [kmax]
    cstar = None  # the largest coverage, once proven
    running: list = []  # the searches started, the last one is what a time-out interrupts
    if at_kmax is not None and not prob.has_conflicts:
        ks = []
        best = (-at_kmax.best_key[0], kmax, list(at_kmax.best_sel))
    try:
        for k in ks:
            floor = 1 if best is None else best[0] + 1  # a larger k must cover strictly more
            if progress:
                progress(0.5 + 0.4 * (k - 1) / kmax, f"best coverage with {k} set-ups")
            s = _best_cover_at(prob, k, floor, heur[k][0] if k in heur else None, deadline, prices,
                               running)
            if s.best_sel is not None:
                best = (-s.best_key[0], k, list(s.best_sel))
        if best is None:
            return [], ""
        cstar = best[0]
        if not prob.has_conflicts:  # the smallest k that reaches C* too
            for k in range(1, kmax):
                if _root_bound(prob, prices, k) < cstar:
                    continue  # the price bound (exact for k <= 2): no k axes reach C*
                if progress:
                    progress(0.9, f"do {k} set-up(s) reach the best coverage?")
                if k in heur and heur[k][1] >= cstar:
                    best = (cstar, k, list(heur[k][0]))
                else:
                    e = _Search(prob, k, "cover", cstar, deadline, stop_at_first=True, prices=prices)
                    e.run()
                    if e.best_sel is None:
                        continue
                    best = (cstar, k, list(e.best_sel))
                s = _best_cover_at(prob, k, cstar, best[2], deadline, prices, running)
                best = (cstar, k, list(s.best_sel))
                break
    except _Timeout:
        if cstar is not None:
            return best[2], ("time limit reached: the coverage shown is the maximum; fewer set-ups "
                             "or less overlap may reach it too")
        s = running[-1] if running else None
        if s is not None and s.best_sel is not None:
            c = -s.best_key[0]
            if best is None or c > best[0]:
                best = (c, len(s.best_sel), list(s.best_sel))
        if best is None:
            return [], "time limit reached before any selection was found"
        if bound is None:
            return best[2], "time limit reached: the best coverage shown may not be the maximum"
        return best[2], (f"time limit reached: the best coverage shown may not be the maximum; no "
                         f"selection covers more than {math.floor(bound)} points")
    return best[2], ""


def _solve_bnb(prob: _Problem, K: int, deadline: float, progress) -> _Outcome:
    """Branch and bound for at most K set-ups: stage 1, the smallest k reaching ``prob.required``
    (the greedy answer where it reaches it, else an existence search); stage 2, the least overlap at
    that k from the locally improved incumbent.

    Where greedy does not reach the coverage with K axes, the price bound of
    :mod:`planning.setups.lagrange` (the LP dual of max coverage with K axes) is tried first: below
    ``prob.required`` it proves at once that no k <= K reaches it (coverage never falls as axes are
    added, and the bound holds for fewer axes too), and its prices then bound every search.  Above
    it (and without zone conflicts) the "cover" search at K settles it: its largest coverage is
    the answer of the infeasible case, or it stops at a K-subset reaching the coverage, and the
    smaller k are then asked as below.  For K <= 2 the exact largest coverage of one or two axes
    (:func:`_small_max_cover`) takes the place of the LP.  Where
    greedy reaches it, the existence searches first run without prices; one that needs more than
    ``_PROBE_NODES`` nodes is restarted with the prices for its k (often settled by the root bound
    then).  The least-overlap search gets the prices for k* where the required coverage lies within
    ``_NEAR_CEILING`` of greedy's and of the price bound (see there)."""
    req = prob.required
    if progress:
        progress(0.0, "greedy axes and local exchanges")
    heur = _heuristics(prob, K)
    kmax = min(K, prob.m)
    prices = bound = None
    price_r = None  # the number of axes the prices were computed for
    kmax_found = None  # a kmax-subset reaching the coverage, where the search at kmax found one
    if 1 <= kmax < _MIN_PRICE_R and not (kmax in heur and heur[kmax][1] >= req):
        bound = _small_max_cover(prob, kmax)  # exact: every pair from the Gram matrix
        if bound < req:
            sel, note = _bnb_best_cover(prob, K, deadline, heur, progress, None, bound)
            return _Outcome("infeasible", sel, None, note)
    if kmax >= _MIN_PRICE_R and not (kmax in heur and heur[kmax][1] >= req):
        if progress:
            progress(0.05, f"can {kmax} set-ups reach the coverage at all?")
        prices, bound = _prices(prob, kmax, heur.get(kmax, (None,))[0], deadline=deadline, min_gain=_PRICE_MIN_GAIN)
        price_r = kmax
        if bound < req:
            sel, note = _bnb_best_cover(prob, K, deadline, heur, progress, prices, bound)
            return _Outcome("infeasible", sel, None, note)
        if not prob.has_conflicts and kmax in heur:
            # the price bound does not settle it: the largest coverage of kmax axes does (coverage
            # never falls as axes are added).  That search is the answer of the infeasible case
            # too, so a proof near the ceiling runs one search instead of an existence search and
            # then this one; it stops at the first subset reaching the coverage (issue 32)
            if progress:
                progress(0.1, f"the best coverage of {kmax} set-ups")
            running: list = []
            try:
                s = _best_cover_at(prob, kmax, 1, heur[kmax][0], deadline, prices, running,
                                   stop_cover=req)
            except _Timeout:
                return _timeout_fallback(prob, heur, 1, kmax)
            if -s.best_key[0] < req:
                sel, note = _bnb_best_cover(prob, K, deadline, heur, progress, prices, bound, at_kmax=s)
                return _Outcome("infeasible", sel, None, note)
            kmax_found = list(s.best_sel)
    kstar, found = None, None
    for k in range(1, kmax + 1):
        if progress:
            progress(0.3 * (k - 1) / kmax, f"is {k} set-up(s) enough?")
        if k in heur and heur[k][1] >= req:
            kstar, found = k, heur[k][0]
            break
        if k == kmax and kmax_found is not None:
            kstar, found = k, kmax_found
            break
        enough = _progress_fn(progress, 0.3 * (k - 1) / kmax, 0.3 * k / kmax, f"is {k} set-up(s) enough?")
        s = _Search(prob, k, "cover", req, deadline, stop_at_first=True, prices=prices,
                    max_nodes=None if prices is not None else _PROBE_NODES, progress=enough)
        try:
            try:
                s.run()
            except _Budget:  # a hard proof: the prices for k, then the search again with them
                prices, _ = _prices(prob, k, heur.get(k, (None,))[0], deadline=deadline, min_gain=_PRICE_MIN_GAIN)
                price_r = k
                if _price_bound(prob, prices, k) < req:
                    continue  # proven at the root: no k axes reach the coverage
                s = _Search(prob, k, "cover", req, deadline, stop_at_first=True, prices=prices, progress=enough)
                s.run()
        except _Timeout:
            return _timeout_fallback(prob, heur, k, kmax)
        if s.best_sel is not None:
            kstar, found = k, s.best_sel
            break
    if kstar is None:
        if price_r != kmax and kmax >= _MIN_PRICE_R:
            prices, bound = _prices(prob, kmax, heur.get(kmax, (None,))[0], deadline=deadline, min_gain=_PRICE_MIN_GAIN)
        sel, note = _bnb_best_cover(prob, K, deadline, heur, progress, prices, bound)
        return _Outcome("infeasible", sel, None, note)
    # stage 2: least overlap at k*
    inc = _local_search(prob, found, "overlap", req)
    if (price_r != kstar and kstar >= _MIN_PRICE_R and kstar in heur
            and heur[kstar][1] - req <= _NEAR_CEILING * prob.n):
        prices, bound = _prices(prob, kstar, heur[kstar][0], deadline=deadline, min_gain=_PRICE_MIN_GAIN)
        # kept only where the bound is near the coverage asked (it prunes nothing far above it)
        price_r = kstar if bound - req <= _NEAR_CEILING * prob.n and bound < prob.w.sum() else None
    s = _Search(prob, kstar, "overlap", req, deadline, incumbent=inc,
                prices=prices if price_r == kstar else None,
                progress=_progress_fn(progress, 0.3, 1.0, f"least overlap with {kstar} set-ups"))
    try:
        s.run()
    except _Timeout:
        ov = s.best_key[0]
        lb = ov if s.timeout_bound is None else min(ov, int(math.ceil(s.timeout_bound - 1e-9)))
        return _Outcome("feasible", s.best_sel, lb, "time limit reached")
    return _Outcome("optimal", s.best_sel, s.best_key[0])
