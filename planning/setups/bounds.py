"""Set-up selection, the bounds of the branch and bound: which subtrees cannot hold the answer.

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1 made exact by :mod:`planning.setups.search`.
All quantities are weights of classes, i.e. point counts (float64 arrays holding integers): ``cov``
and ``ov`` are what a node's chosen axes cover and see twice; per candidate axis ``g`` is the weight it
would newly cover and ``h`` the weight it would turn into overlap; ``P`` and ``Q`` are the weighted
Gram matrices of the candidates over the still uncovered and the once-covered classes.  ``floor`` is the
coverage a completion must reach; ``inc`` is the incumbent key ``(overlap, -covered, tuple)`` where the
overlap bounds apply (mode "overlap" with an incumbent), else ``None``.  Bounds:

- the last two axes are evaluated exactly, all pairs at once (in the search itself):
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
  children at once on (j, l, q) arrays.
"""

from __future__ import annotations

import numpy as np

from planning.setups.problem import _Problem

_INF = np.inf
_TENSOR_MAX = 80  # largest candidate count for the (j, l, q) pre-check arrays (80^3 doubles = 4 MB)


def _top_sums(g: np.ndarray, rc: int):
    """(sum of the rc largest g, g + sum of the rc - 1 largest g): min of the two bounds the best
    coverage gain of rc axes that include a given axis."""
    if rc == 1:
        return g, g
    top = -np.partition(-g, rc - 1)[:rc] if g.size > rc else g.copy()
    top = np.sort(top)[::-1]
    return np.full(g.shape, top[:rc].sum()), g + top[: rc - 1].sum()


def _branch_bounds(cov, ov, g, h, P, Q, allowed, r, floor, mode, lub=None):
    """Bounds of each child j of a node with r >= 3 axes to add (``allowed``: the pairs j < l that
    may stand together).  Returns (viable, k1, k2, lb): which children may reach ``floor``, the
    child's lower key (k1, k2) in the order of ``mode`` and its overlap lower bound ``lb`` (in mode
    "cover" simply ``ov + h``)."""
    M = allowed.shape[0]
    # Hunter chain bound on the union of the next t axes, starting at each axis
    bs = [None, g]
    b = g
    for _ in range(2, r + 1):
        T = np.where(allowed, b[None, :] - P, -_INF)
        b = g + T.max(axis=1)
        bs.append(b)
    cub = cov + bs[r]
    if lub is not None:  # the price bound of planning.setups.lagrange, where the search has prices
        cub = np.minimum(cub, lub)
    viable = cub >= floor
    if mode == "overlap":
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
    return viable, k1, k2, lb


def _pairs_exist(node, allowed, floor, inc):
    """For a node with three axes to add: which children j can still be completed by a pair
    (l, q), by the pair pre-check of :func:`_completable` run for all j at once on (j, l, q) arrays."""
    cov, ov, g, h, P, Q = (node[x] for x in ("cov", "ov", "g", "h", "P", "Q"))
    ok = allowed[:, :, None] & allowed[:, None, :] & allowed[None, :, :]  # j < l < q
    m1 = np.minimum(P[:, :, None], P[:, None, :])  # (j, l, q)
    p_lo = np.maximum(P[None, :, :] - m1, 0.0)
    gl = g[None, :] - P  # child j's gain of l
    cub = (cov + g)[:, None, None] + gl[:, :, None] + gl[:, None, :] - p_lo
    ok &= cub >= floor
    if inc is not None:
        hl = h[None, :] + P - Q  # child j's added overlap of l
        q_hi = np.minimum(np.minimum(hl[:, :, None], hl[:, None, :]), Q[None, :, :] + m1)
        lbo = (ov + h)[:, None, None] + hl[:, :, None] + hl[:, None, :] - q_hi + p_lo
        inc1, inc2 = inc[0], inc[1]
        ok &= (lbo < inc1) | ((lbo == inc1) & (-cub <= inc2))
    return ok.any(axis=(1, 2))


def _completable(prob: _Problem, node, after, keep, s1, g, h, cov, ov, rc, floor, inc) -> bool:
    """Pair pre-check of a child that still has rc >= 2 axes to add, from the parent's matrices,
    before any Gram product.

    The child is the parent ``node`` plus one axis; ``after`` are its candidates (positions into the
    parent's), ``s1`` the weight the new axis shares with each of them among the uncovered classes,
    ``g``/``h`` the child's gains, ``cov``/``ov`` its totals.  For two more axes l, q: the classes
    newly covered by the new axis and seen by both weigh at most min(s1_l, s1_q), which bounds the
    child's P_lq from below, hence the coverage of the three (plus the best rc - 2 other gains) from
    above and their overlap from below.  Every pair of a completion must pass, so a completion is a
    clique of rc axes in the graph of passing pairs: axes with fewer than rc - 1 partners are peeled
    off; with rc == 3, the axes in no passing triple too.  Clears those axes in ``keep`` (a bool mask
    over ``after``, changed in place); False when no completion is left.
    """
    sub = np.flatnonzero(keep)
    ok, p_lo, gg, hh, q_hi = _pair_graph(prob, node, after, sub, s1, g, h, cov, ov, rc, floor, inc)
    alive = _peel(ok, rc)
    if np.count_nonzero(alive) < rc:
        return False
    if rc == 3 and np.count_nonzero(alive) <= _TENSOR_MAX:
        al, used3 = _triples_used(ok, alive, p_lo, gg, hh, q_hi, cov, ov, floor, inc)
        if not used3.any():
            return False
        alive[al[~used3]] = False
    keep[sub[~alive]] = False
    return True


def _pair_graph(prob: _Problem, node, after, sub, s1, g, h, cov, ov, rc, floor, inc):
    """The passing pairs among the candidates ``after[sub]`` of a child (see :func:`_completable`):
    (ok, p_lo, gg, hh, q_hi) with ``ok`` the (len(sub), len(sub)) graph of passing pairs, ``p_lo``
    the lower bound of the child's P, ``gg``/``hh`` the gains of those candidates and ``q_hi`` the
    upper bound of the child's Q (``hh`` and ``q_hi`` are None where ``inc`` is None)."""
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
    if prob.has_conflicts:
        cand = node["cand"]
        ok &= ~prob.conflict[np.ix_(cand[a], cand[a])]
    hh = q_hi = None
    if inc is not None:
        hh = h[sub]
        q_hi = np.minimum(np.minimum(hh[:, None], hh[None, :]), node["Q"][ix] + m1)
        lbo = ov + hh[:, None] + hh[None, :] - q_hi + p_lo
        inc1, inc2 = inc[0], inc[1]
        ok &= (lbo < inc1) | ((lbo == inc1) & (-cub <= inc2))
    return ok, p_lo, gg, hh, q_hi


def _peel(ok, rc):
    """Which vertices of the graph ``ok`` of passing pairs may lie in a clique of rc: those with
    fewer than rc - 1 partners are removed, repeatedly (their rows and columns of ``ok`` are cleared
    in place)."""
    alive = np.ones(ok.shape[0], bool)
    while True:
        partners = np.count_nonzero(ok, axis=1)
        dead = alive & (partners < rc - 1)
        if not dead.any():
            break
        alive &= ~dead
        ok[dead, :] = False
        ok[:, dead] = False
    return alive


def _triples_used(ok, alive, p_lo, gg, hh, q_hi, cov, ov, floor, inc):
    """Triples of passing pairs among the ``alive`` vertices (a child with three axes to add):
    (al, used3), ``al`` the alive positions and ``used3`` which of them lie in a passing triple.

    Union <= sum g - (sum P - min P) (inclusion-exclusion with the triple term at most min P);
    overlap >= once-covered classes hit (Bonferroni: sum h - sum Q) + the largest pair among the
    uncovered classes.
    """
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
    if inc is not None:
        inc1, inc2 = inc[0], inc[1]
        h3 = hh[al]
        qh = q_hi[np.ix_(al, al)]
        hsum = h3[:, None, None] + h3[None, :, None] + h3[None, None, :]
        qsum = qh[:, :, None] + qh[:, None, :] + qh[None, :, :]
        pmax = np.maximum(np.maximum(pl[:, :, None], pl[:, None, :]), pl[None, :, :])
        lboT = ov + hsum - qsum + pmax
        okT &= (lboT < inc1) | ((lboT == inc1) & (-cubT <= inc2))
    return al, okT.any(axis=(1, 2))
