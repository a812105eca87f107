"""Set-up selection, the last two to four axes of a coverage search on bit sets (numba).

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1 made exact by :mod:`planning.setups.search`.
Near the largest coverage (range scans, issue 32: the best 4 or 5 axes leave a handful of points) the
search's bounds prune little above the leaves (the LP relaxation covers every point there), and most
of its time went into nodes with two axes still to add, each paying for a weighted Gram matrix of its
candidates over its uncovered classes (``P``) to evaluate every pair.  There, almost every subset
leaves far more than the allowed few points uncovered, which a count over the uncovered classes shows
after a word or two: the classes are kept as bit sets (one 64-bit word per 64 classes, per axis; the
classes seen by the fewest axes first, where a subset that misses leaves its points), the weights as
bit planes, and a subset is dropped as soon as the number of classes it leaves uncovered (each weighs
at least 1) exceeds the allowance; the weight is summed only for the few that pass.  Every subset
that reaches the coverage is returned with its exact uncovered weight: the same leaves the Gram
matrices give, so the search's answer does not change.

* :func:`_pairs_within`: a node with two axes to add, every pair of its candidates;
* :func:`_triples_within`: a node with three axes to add, the pairs under each of its children at
  once (no child state, no Gram matrix, no pair or triple pre-check: the count is cheaper);
* :func:`_quads_block`: a node with four axes to add, the triples under each child, whose
  candidates are first filtered by their gains after the child (from the node's gains and Gram
  matrix, as :meth:`planning.setups.search._Search._child` filters them) and enumerated by falling
  gain, so that the gain bound ends a loop instead of skipping one subset.

Measured (``bench/bench_proofs_range.py``, range half sphere R 100 mm, 25,359 sampled points, 18,415
classes x 133 axes, same run against 7f7b0d2): coverage 1.0 with 5 set-ups 49 s -> 1.6 s, 0.999 with
4 3.1 s -> 0.7 s.  Used only where at most ``search._BITS_SHARE`` of the points may be left uncovered:
far below the ceiling every subset is counted to its end and the Gram matrices are quicker.

A node's children are shared out to ``numba.get_num_threads()`` Python threads (:func:`_quads_block`
releases the GIL; the children interleaved, the rows sorted afterwards, so the answer does not
depend on the thread count).  On the same range half sphere, 2 cores, 1.0 / 5: the proof 0.94 s with
``NUMBA_NUM_THREADS=1`` against 0.80 s with 2 (``bench/bench_proofs_range.py``, BENCHMARKS.md); the
rest is the children's Gram products and Python.  Counting the words a pair leaves only over the words
the node's first two axes leave (a compacted index) made the kernel slower (a scratch timing, not kept).

The kernels are ``@njit(cache=True)`` with explicit signatures: compiled (or loaded from numba's
cache, :mod:`planning.kernel_cache`) when this module is imported, never in the middle of a search.
"""

from __future__ import annotations

import numpy as np
from concurrent.futures import ThreadPoolExecutor

import numba
from numba import njit

_M1 = np.uint64(0x5555555555555555)
_M2 = np.uint64(0x3333333333333333)
_M4 = np.uint64(0x0F0F0F0F0F0F0F0F)
_H01 = np.uint64(0x0101010101010101)
_S1 = np.uint64(1)
_S2 = np.uint64(2)
_S4 = np.uint64(4)
_S56 = np.uint64(56)


@njit("int64(uint64)", cache=True)
def _popcount(x):
    """Set bits of a 64-bit word (SWAR)."""
    x = x - ((x >> _S1) & _M1)
    x = (x & _M2) + ((x >> _S2) & _M2)
    x = (x + (x >> _S4)) & _M4
    return np.int64((x * _H01) >> _S56)


@njit("int64(uint64[::1], uint64[::1], uint64[::1], uint64[:, ::1])", cache=True)
def _weight(x, b1, b2, planes):
    """Weight of the classes in ``x`` that neither ``b1`` nor ``b2`` holds (weights as bit planes). The
    kernels below count those classes first, word by word, and call this only when the count stays
    within the allowance; that count is written out in each of them rather than called (a shared
    ``_left_within(x, B[q], B[s], planes, smax)`` made the range half sphere's 1.0 / 5 proof 1.0 ->
    1.8 s, 2.3 s without inlining: the row views per call)."""
    acc = 0
    for i in range(x.shape[0]):
        y = x[i] & ~b1[i] & ~b2[i]
        if y != 0:
            for p in range(planes.shape[0]):
                acc += _popcount(y & planes[p, i]) << p
    return acc


@njit("int64(uint64[::1], uint64[:, ::1], uint64[:, ::1], int64, int64[::1], int64[::1], int64[::1])",
      cache=True)
def _pairs_within(unc, B, planes, smax, ia, ib, uo):
    """Pairs a < b of the rows of ``B`` (candidate axes x words: the classes each sees) that leave at
    most ``smax`` weight of ``unc`` (the uncovered classes, same words) uncovered; ``planes`` (bit
    planes x words): bit p of each class's weight.  Writes the pairs and their uncovered weight into
    ``ia``, ``ib``, ``uo`` (room for every pair) and returns how many there are."""
    M, nw = B.shape
    xa = np.empty(nw, np.uint64)
    n = 0
    for a in range(M):
        for i in range(nw):
            xa[i] = unc[i] & ~B[a, i]
        for b in range(a + 1, M):
            acc = 0
            for i in range(nw):  # every class weighs at least 1: the count bounds the weight
                acc += _popcount(xa[i] & ~B[b, i])
                if acc > smax:
                    break
            if acc <= smax:
                acc = _weight(xa, B[b], B[b], planes)
            if acc <= smax:
                ia[n] = a
                ib[n] = b
                uo[n] = acc
                n += 1
    return n


@njit("int64(uint64[::1], uint64[:, ::1], uint64[:, ::1], int64[::1], int64, int64[:, ::1])", cache=True)
def _triples_within(unc, B, planes, js, smax, out):
    """Triples j < l < q of the rows of ``B``, j among ``js`` (in that order), that leave at most
    ``smax`` weight of ``unc`` uncovered (as :func:`_pairs_within`).  Writes rows (j, l, q, weight
    left) into ``out`` (room for every triple) in the order of ``js``, then l, then q; returns how
    many."""
    M, nw = B.shape
    xj = np.empty(nw, np.uint64)
    n = 0
    for t in range(js.shape[0]):
        j = js[t]
        for i in range(nw):
            xj[i] = unc[i] & ~B[j, i]
        for ll in range(j + 1, M):
            for q in range(ll + 1, M):
                acc = 0
                for i in range(nw):  # every class weighs at least 1: the count bounds the weight
                    acc += _popcount(xj[i] & ~B[ll, i] & ~B[q, i])
                    if acc > smax:
                        break
                if acc <= smax:
                    acc = _weight(xj, B[ll], B[q], planes)
                if acc <= smax:
                    out[n, 0] = j
                    out[n, 1] = ll
                    out[n, 2] = q
                    out[n, 3] = acc
                    n += 1
    return n


@njit("float64(float64[::1], boolean[::1], int64)", cache=True)
def _top_sum(g, ok, r):
    """Sum of the r largest ``g`` where ``ok`` (all of them where fewer)."""
    best = np.full(r, -1.0)
    for i in range(g.shape[0]):
        if ok[i] and g[i] > best[r - 1]:
            t = r - 1
            while t > 0 and best[t - 1] < g[i]:
                best[t] = best[t - 1]
                t -= 1
            best[t] = g[i]
    tot = 0.0
    for t in range(r):
        if best[t] > 0.0:
            tot += best[t]
    return tot


@njit("int64(uint64[::1], uint64[:, ::1], uint64[:, ::1], float64[::1], float64[:, ::1], float64, int64[::1], "
      "int64, int64[:, ::1], int64[::1], int64, int64)", cache=True, nogil=True)
def _quads_block(unc, B, planes, g, P, wunc, js, smax, out, nodes, b, nb):
    """Quadruples j < l < q < s of the rows of ``B``, j among ``js`` (in that order), that leave at
    most ``smax`` weight of ``unc`` (total weight ``wunc``) uncovered.  ``g`` and ``P``: the weight of
    ``unc`` each row sees and each pair sees together (the node's gains and Gram matrix), from which
    each j's later rows are filtered first as the search filters a child's candidates (the weight
    left by j, less the three best gains after j, or the gain of l and the two best others, must
    not exceed ``smax``: each row's gain after j is ``g_l - P_jl``).  Writes rows (j, l, q, s, weight
    left) into ``out``; returns how many, or -1 when ``out`` is too small.  ``nodes[0]`` counts the
    children j and ``nodes[1]`` the l kept under them.  Only the children ``js[b::nb]``: block ``b`` of
    ``nb``, interleaved so that the costly first children are shared out (:meth:`_Bits.quads_within`
    runs the blocks on threads)."""
    M, nw = B.shape
    xj = np.empty(nw, np.uint64)
    xl = np.empty(nw, np.uint64)
    gj = np.empty(M)
    gjl = np.empty(M)
    keep = np.zeros(M, np.bool_)
    n = 0
    for t in range(b, js.shape[0], nb):
        j = js[t]
        nodes[0] += 1
        left_j = wunc - g[j]
        for ll in range(M):
            gj[ll] = g[ll] - P[j, ll]
            keep[ll] = ll > j
        for _ in range(2):  # the child's candidates, then the child's children among them
            top3 = _top_sum(gj, keep, 3)
            top2 = _top_sum(gj, keep, 2)
            for ll in range(j + 1, M):
                if keep[ll] and (left_j - min(top3, gj[ll] + top2) > smax + 1e-9):
                    keep[ll] = False
        # the kept rows after j by falling gain: a row's gain after j and l is at most its gain after
        # j, so the weight j and l leave less the gains of the two rows added bounds what a
        # quadruple leaves from below, and once that bound fails it fails for every later row
        idx = np.flatnonzero(keep)
        idx = idx[np.argsort(-gj[idx], kind="mergesort")]
        K = idx.shape[0]
        for i in range(nw):
            xj[i] = unc[i] & ~B[j, i]
        for a in range(K - 2):
            ll = idx[a]
            left_l = left_j - gj[ll]
            if left_l - gj[idx[a + 1]] - gj[idx[a + 2]] > smax + 1e-9:
                break
            nodes[1] += 1
            for i in range(nw):
                xl[i] = xj[i] & ~B[ll, i]
            # a row's gain after j and l: the classes after j that l sees too weigh at least
            # P_lq less those j sees as well (at most the smaller of P_jl, P_jq)
            for c in range(a + 1, K):
                q = idx[c]
                gjl[q] = gj[q] - max(0.0, P[ll, q] - min(P[j, ll], P[j, q]))
            for bq in range(a + 1, K - 1):
                q = idx[bq]
                if left_l - gj[q] - gj[idx[bq + 1]] > smax + 1e-9:
                    break
                if left_l - gjl[q] - gj[idx[bq + 1]] > smax + 1e-9:
                    continue
                for c in range(bq + 1, K):
                    s = idx[c]
                    if left_l - gj[q] - gj[s] > smax + 1e-9:
                        break
                    if left_l - gjl[q] - gjl[s] > smax + 1e-9:
                        continue
                    acc = 0
                    for i in range(nw):  # every class weighs at least 1: the count bounds the weight
                        acc += _popcount(xl[i] & ~B[q, i] & ~B[s, i])
                        if acc > smax:
                            break
                    if acc <= smax:
                        acc = _weight(xl, B[q], B[s], planes)
                    if acc <= smax:
                        if n >= out.shape[0]:
                            return -1
                        r0, r1, r2 = ll, q, s  # the three in increasing order
                        if r0 > r1:
                            r0, r1 = r1, r0
                        if r1 > r2:
                            r1, r2 = r2, r1
                        if r0 > r1:
                            r0, r1 = r1, r0
                        out[n, 0] = j
                        out[n, 1] = r0
                        out[n, 2] = r1
                        out[n, 3] = r2
                        out[n, 4] = acc
                        n += 1
    return n


#: The threads :meth:`_Bits.quads_within` shares a node's children out to (:func:`_quads_block` releases
#: the GIL). Python threads, not a ``prange`` kernel: a parallel kernel compiled when this module is
#: imported would start GNU OpenMP in the service's fork server, which is not fork-safe.
_POOL: ThreadPoolExecutor | None = None
_POOL_SIZE = 0


def _blocks_map(fn, n: int, nth: int) -> list:
    """``[fn(b) for b in range(n)]`` on ``nth`` threads (inline for one)."""
    global _POOL, _POOL_SIZE
    if nth <= 1 or n <= 1:
        return [fn(b) for b in range(n)]
    if _POOL is None or _POOL_SIZE != nth:
        _POOL = ThreadPoolExecutor(max_workers=nth, thread_name_prefix="setups")
        _POOL_SIZE = nth
    return list(_POOL.map(fn, range(n)))


class _Bits:
    """The classes of a :class:`~planning.setups.problem._Problem` as bit sets: ``axes`` (m, words)
    the classes each reduced axis sees, ``planes`` (bit planes, words) the weights, ``valid`` (words,)
    the classes that exist (the last word is partly empty)."""

    def __init__(self, A: np.ndarray, w: np.ndarray):
        C = A.shape[0]
        nw = max(1, (C + 63) // 64)
        pad = nw * 64 - C

        def pack(rows):  # (k, C) bool -> (k, nw) uint64, class c at bit c % 64 of word c // 64
            rows = np.concatenate([rows, np.zeros((rows.shape[0], pad), bool)], axis=1)
            return np.ascontiguousarray(np.packbits(rows, axis=1, bitorder="little").view("<u8").astype(np.uint64))

        # the classes seen by the fewest axes first: the words a subset that misses the coverage
        # leaves uncovered come first among those of a node (see _words)
        perm = np.argsort(A.sum(axis=1), kind="stable")
        A, w = A[perm], w[perm]
        self.axes = pack(np.ascontiguousarray(A.T))
        nplanes = max(1, int(w.max(initial=1)).bit_length())
        self.planes = pack(((w[None, :] >> np.arange(nplanes)[:, None]) & 1).astype(bool))
        self.valid = pack(np.ones((1, C), bool))[0]

    def uncovered(self, sel) -> np.ndarray:
        """The words of the classes no axis of ``sel`` sees."""
        u = self.valid.copy()
        for a in sel:
            u &= ~self.axes[a]
        return u

    def pairs_within(self, u: np.ndarray, cand: np.ndarray, smax: int):
        """(ia, ib, left): the pairs of positions ia < ib into ``cand`` (reduced axes) that leave at
        most ``smax`` weight of the classes ``u`` (words, e.g. :meth:`uncovered`) uncovered, with the
        weight they leave."""
        M = cand.size
        cap = M * (M - 1) // 2
        ia, ib, uo = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
        if cap == 0:
            return ia, ib, uo
        n = _pairs_within(*self._words(u, cand), int(smax), ia, ib, uo)
        return ia[:n], ib[:n], uo[:n]

    def triples_within(self, u: np.ndarray, cand: np.ndarray, js: np.ndarray, smax: int) -> np.ndarray:
        """Rows (j, l, q, left) of the triples of positions j < l < q into ``cand``, j among ``js`` (in
        that order), that leave at most ``smax`` weight of ``u`` uncovered, with the weight left."""
        M = cand.size
        cap = M * (M - 1) * (M - 2) // 6
        out = np.empty((max(cap, 1), 4), np.int64)
        if cap == 0 or js.size == 0:
            return out[:0]
        n = _triples_within(*self._words(u, cand), np.ascontiguousarray(js, dtype=np.int64), int(smax), out)
        return out[:n]

    def quads_within(self, u: np.ndarray, cand: np.ndarray, g, P, js: np.ndarray, smax: int,
                     cap: int = 1 << 16, blocks: int | None = None):
        """(rows, nodes): rows (j, l, q, s, left) of the quadruples of positions j < l < q < s into
        ``cand`` (j among ``js``, in that order) leaving at most ``smax`` weight of ``u`` uncovered,
        with l, q, s among the candidates that pass the gain filters of :func:`_quads_block` (``g``,
        ``P``: the gains and Gram matrix of ``cand`` over ``u``); ``nodes`` (children, grandchildren
        visited).  Rows None when more than ``cap`` quadruples qualify.  The children are shared out in
        ``blocks`` (default: numba's thread count, at most one per child) counted in parallel; the
        rows and counts do not depend on it."""
        if cand.size < 4 or js.size == 0:
            return np.empty((0, 5), np.int64), np.zeros(2, np.int64)
        nth = max(1, numba.get_num_threads())
        nb = max(1, min(nth if blocks is None else int(blocks), js.size))
        out = np.empty((nb, cap, 5), np.int64)  # each block room for all: untouched pages cost nothing
        nodes = np.zeros((nb, 2), np.int64)
        args = (*self._words(u, cand), np.ascontiguousarray(g, dtype=np.float64),
                np.ascontiguousarray(P, dtype=np.float64), float(self.weight_of(u)),
                np.ascontiguousarray(js, dtype=np.int64), int(smax))
        counts = np.array(_blocks_map(lambda b: _quads_block(*args, out[b], nodes[b], b, nb), nb, min(nth, nb)))
        nodes = nodes.sum(axis=0)
        if counts.min() < 0 or counts.sum() > cap:
            return None, nodes
        out = np.concatenate([out[b, :counts[b]] for b in range(nb)])
        rank = np.empty(cand.size, np.int64)
        rank[js] = np.arange(js.size)
        return out[np.lexsort((out[:, 3], out[:, 2], out[:, 1], rank[out[:, 0]]))], nodes

    def weight_of(self, u) -> int:
        """The weight of the classes of ``u``."""
        return int(sum(int(np.bitwise_count(self.planes[p] & u).sum()) << p for p in range(self.planes.shape[0])))

    def _words(self, u, cand):
        """The words of ``u`` that hold classes, with the candidates' and the weights' words: in class
        order, the classes seen by the fewest axes first (a subset that misses the coverage is seen
        to miss after a few words; on the range half sphere this beat ordering the node's words by
        their uncovered count, 0.63 against 0.78 s of kernel for 1.0 / 5)."""
        order = np.flatnonzero(u)
        return (np.ascontiguousarray(u[order]), np.ascontiguousarray(self.axes[np.ix_(cand, order)]),
                np.ascontiguousarray(self.planes[:, order]))
