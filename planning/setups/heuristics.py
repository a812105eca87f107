"""Set-up selection, heuristics: greedy max coverage and one- and two-axis exchanges.

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1.  No proof comes from here: these give the
branch and bound (:mod:`planning.setups.search`) its first incumbent and CP-SAT
(:mod:`planning.setups.cpsat`) its hints, and stand in for both when the time limit is hit before the
number of set-ups is settled (:func:`_timeout_fallback`).  Coverages and overlaps are point counts
(class weights summed), on the reduced :class:`~planning.setups.problem._Problem`.
"""

from __future__ import annotations

import itertools

import numpy as np

from planning.setups.problem import _key_cover, _key_overlap, _Outcome, _Problem, _wgram


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
