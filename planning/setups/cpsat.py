"""Set-up selection with OR-Tools CP-SAT (``solver="cpsat"``): the same problem as a partial set cover.

Stage 5 (set-ups) of the pipeline, Makki et al. 2010 §3.1, made exact.  The model runs over the same
weighted classes as the branch and bound (:class:`~planning.setups.problem._Problem`): a coverage and an
overlap boolean per class (weights are point counts; one worker, seed 0).  Exact too, but its LP
relaxation gives an overlap bound of 0 on this problem (``docs/design.md``, Performance, "Set-ups"): on
the 100k case it still reports a lower bound of 0 after 60 s.  It is kept as an independent
cross-check and as the model for side constraints.  It does not apply the index tie rule
(``selected`` may differ on exact ties).

Stages, as in :mod:`planning.setups.search`: the smallest ``k`` that reaches the coverage (one
feasibility model per ``k``), then the least overlap at that ``k`` (one objective:
``(n + 1) * overlap - covered``); where no ``k`` reaches the coverage, the best coverage and then the
fewest set-ups and least overlap at it.  Hints come from :mod:`planning.setups.heuristics`.
"""

from __future__ import annotations

import math
import time

import numpy as np

from planning.setups.heuristics import _heuristics, _local_search, _timeout_fallback
from planning.setups.problem import _Outcome, _Problem


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
