"""Set-up proofs on range-scan matrices (issue 32): the answers near the largest coverage, where the
price bound does not settle infeasibility and the search at max_setups does, against exhaustive
enumeration; one or two set-ups proven from the Gram matrix without the LP; the overlap evaluated
only at the leaves of the best coverage in the coverage searches (ties); the last two or three axes
of a coverage search counted on bit sets (planning.setups.kernels)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from planning.setups import brute_force_setups, kernels, search, select_setups
from planning.setups.problem import _Problem


def answer(r):
    return r.status, r.k, r.covered, r.overlap, r.selected.tolist(), r.best_coverage_at_max


@pytest.fixture(scope="module")
def range_matrices():
    """The set-up stage's matrix of three small simulated range scans (scan lines, holes, noise,
    outliers, registration errors), through the pipeline's normals, orientations and visibility."""
    from planning import pipeline as pl
    from planning.inputs import Cloud
    from planning.inputs.samples import range_scan
    from planning.orientations import load_profile
    from schemas.params import PlanConfig

    cfg = PlanConfig()
    profile = load_profile(cfg.machine.profile)
    ori = pl._orientations(cfg, profile)
    out = {}
    for shape in ("half_sphere", "slot", "femur_like"):
        s = range_scan(shape, n_points=3000, seed=0)
        cloud = Cloud(points=s.points, normals=None, source_format="generated")
        nrm = pl._normals(cloud, cfg, None)
        _, gv = pl._visibility(cloud.points, nrm, ori, cfg, cfg.tool.assembly(), profile, None, None)
        out[shape] = np.ascontiguousarray(pl.selection_matrix(gv.visible, ori.axes, nrm.normals, cfg))
    return out


def column_subset(V, m, seed):
    """m columns of V that see something (the largest two and m - 2 drawn with ``seed``), in order."""
    rng = np.random.default_rng(seed)
    seen = np.flatnonzero(V.sum(axis=0) > 0)
    top = seen[np.argsort(-V[:, seen].sum(axis=0), kind="stable")[:2]]
    rest = np.setdiff1d(seen, top)
    cols = np.sort(np.concatenate([top, rng.choice(rest, m - 2, replace=False)]))
    return np.ascontiguousarray(V[:, cols])


def coverage_for(required, n):
    """A coverage whose ceil(coverage * n) is exactly ``required``."""
    return (required - 0.5) / n


@pytest.fixture
def paths(monkeypatch):
    """Which proofs ran: the number of axes each LP was solved for, and the best-coverage answers
    that reused the search at max_setups."""
    seen = {"lp": [], "at_kmax": 0}
    real_prices, real_best = search._prices, search._bnb_best_cover

    def prices(prob, r, *a, **kw):
        seen["lp"].append(r)
        return real_prices(prob, r, *a, **kw)

    def best(*a, **kw):
        if kw.get("at_kmax") is not None:
            seen["at_kmax"] += 1
        return real_best(*a, **kw)

    monkeypatch.setattr(search, "_prices", prices)
    monkeypatch.setattr(search, "_bnb_best_cover", best)
    return seen


@pytest.mark.parametrize("shape", ["half_sphere", "slot", "femur_like"])
def test_targets_around_the_largest_coverage_match_brute_force(range_matrices, shape, paths):
    """For 2, 3 and 4 set-ups on 16 columns of the matrix: the largest coverage C* (brute force),
    then the targets C* - 1, C* (feasible at the ceiling) and C* + 1 (infeasible by one point):
    the same answer as the exhaustive enumeration, the proof for one or two set-ups without an LP."""
    n = range_matrices[shape].shape[0]
    for seed in range(2):
        V = column_subset(range_matrices[shape], 16, seed)
        for K in (2, 3, 4):
            top = brute_force_setups(V, coverage=1.0, max_setups=K)
            cstar = top.covered
            for req in (cstar - 1, cstar, cstar + 1):
                if not 1 <= req <= n:
                    continue
                params = {"coverage": coverage_for(req, n), "max_setups": K}
                ref = brute_force_setups(V, **params)
                got = select_setups(V, **params)
                assert answer(got) == answer(ref), (shape, seed, K, req)
                assert (ref.status == "infeasible") == (req > cstar)
    assert all(r >= 3 for r in paths["lp"])  # one or two set-ups: the exact pair bound, no LP


def test_near_ceiling_infeasibility_is_settled_by_the_search_at_max_setups(range_matrices, paths):
    """Instances where greedy misses the coverage, the price bound does not prove it and no K axes
    reach it: the one search at max_setups gives both the proof and the answer (equal to brute
    force), and that path is taken here."""
    hits = 0
    for shape, Vfull in range_matrices.items():
        n = Vfull.shape[0]
        for seed in range(3):
            V = column_subset(Vfull, 14, 10 + seed)
            for K in (3, 4):
                cstar = brute_force_setups(V, coverage=1.0, max_setups=K).covered
                if cstar >= n:
                    continue
                before = paths["at_kmax"]
                params = {"coverage": coverage_for(cstar + 1, n), "max_setups": K}
                got = select_setups(V, **params)
                assert answer(got) == answer(brute_force_setups(V, **params)), (shape, seed, K)
                assert got.status == "infeasible" and got.covered == cstar
                hits += paths["at_kmax"] - before
    assert hits >= 3


def test_full_range_matrix_proof_is_tight(range_matrices):
    """On every column of the half sphere's matrix (too many for brute force): the best coverage of
    5 and 3 set-ups that an infeasible answer reports is reached (the same selection proven
    optimal at that coverage) and one point more is proven infeasible with the same answer."""
    V = range_matrices["half_sphere"]
    n = V.shape[0]
    for K in (3, 5):
        inf = select_setups(V, coverage=1.0, max_setups=K)
        if inf.status != "infeasible":
            continue
        cstar = inf.covered
        one_more = select_setups(V, coverage=coverage_for(cstar + 1, n), max_setups=K)
        assert answer(one_more)[:5] == answer(inf)[:5]
        at = select_setups(V, coverage=coverage_for(cstar, n), max_setups=K)
        assert at.status == "optimal" and at.covered >= cstar
        # the fewest axes at C*: none of the smaller k reaches it
        if at.k > 1:
            assert select_setups(V, coverage=coverage_for(cstar, n), max_setups=at.k - 1).status == "infeasible"


def tie_instance(seed):
    """Columns built from a few blocks of points, so that many subsets cover exactly as much and
    overlap and index order decide; some points unseen (a ceiling below 100 %)."""
    rng = np.random.default_rng(seed)
    blocks = int(rng.integers(4, 9))
    size = rng.integers(1, 6, blocks)
    owner = np.repeat(np.arange(blocks), size)
    n = owner.size + int(rng.integers(0, 4))
    m = int(rng.integers(5, 11))
    cols = rng.random((blocks, m)) < 0.4
    V = np.zeros((n, m), bool)
    V[: owner.size] = cols[owner]
    return V, int(rng.integers(2, 5))


@pytest.mark.parametrize("seed", range(60))
def test_coverage_ties_match_brute_force(seed):
    """Exact ties of coverage in the coverage searches (the overlap is computed only for the leaves
    of the best coverage): the least overlap, then the smallest tuple, as brute force."""
    V, K = tie_instance(seed)
    n = V.shape[0]
    cstar = brute_force_setups(V, coverage=1.0, max_setups=K).covered
    for req in {max(1, cstar - 1), max(1, cstar), min(n, cstar + 1)}:
        params = {"coverage": coverage_for(req, n), "max_setups": K}
        assert answer(select_setups(V, **params)) == answer(brute_force_setups(V, **params)), (seed, req)


def test_zone_conflicts_on_a_range_matrix_match_brute_force(range_matrices):
    """A functional zone (every fifth point) on 12 columns of the slot block's matrix: the search
    per k of the infeasible case and the feasible case, as brute force."""
    V = column_subset(range_matrices["slot"], 12, 3)
    n = V.shape[0]
    zone = np.zeros(n, bool)
    zone[::5] = True
    for K in (2, 3):
        cstar = brute_force_setups(V, coverage=1.0, max_setups=K, zone_mask=zone).covered
        for req in (cstar, cstar + 1):
            if req > n:
                continue
            params = {"coverage": coverage_for(req, n), "max_setups": K, "zone_mask": zone}
            assert answer(select_setups(V, **params)) == answer(brute_force_setups(V, **params)), (K, req)


def test_small_max_cover_is_the_exact_best_of_one_and_two_axes(range_matrices):
    """The root proof for one or two set-ups: the largest coverage of any one or two reduced axes,
    exactly (every pair counted on the point rows)."""
    V = column_subset(range_matrices["femur_like"], 20, 7)
    prob = _Problem(V, None, 1, 1)
    cols = V.astype(np.int64)
    one = int(cols.sum(axis=0).max())
    two = max(int(((cols[:, a] + cols[:, b]) > 0).sum()) for a in range(V.shape[1]) for b in range(a + 1, V.shape[1]))
    assert search._small_max_cover(prob, 1) == one
    assert search._small_max_cover(prob, 2) == max(one, two)


@pytest.fixture
def kernel_calls(monkeypatch):
    """How many times the coverage searches counted pairs and triples on bit sets."""
    seen = {"pairs": 0, "triples": 0, "quads": 0}
    real_pairs, real_triples = kernels._Bits.pairs_within, kernels._Bits.triples_within
    real_quads = kernels._Bits.quads_within

    def pairs(self, *a, **kw):
        seen["pairs"] += 1
        return real_pairs(self, *a, **kw)

    def triples(self, *a, **kw):
        seen["triples"] += 1
        return real_triples(self, *a, **kw)

    def quads(self, *a, **kw):
        seen["quads"] += 1
        return real_quads(self, *a, **kw)

    monkeypatch.setattr(kernels._Bits, "pairs_within", pairs)
    monkeypatch.setattr(kernels._Bits, "quads_within", quads)
    monkeypatch.setattr(kernels._Bits, "triples_within", triples)
    return seen


@pytest.mark.parametrize("seed", range(12))
def test_bit_set_counts_are_exact(seed):
    """The kernels' pairs and triples and the weight each leaves uncovered, against sums over the
    class rows: every allowance from none to all, including those between the number of classes
    left and their weight (a subset is first dropped by the count, then by the weight)."""
    rng = np.random.default_rng(seed)
    C, m = int(rng.integers(1, 300)), int(rng.integers(4, 12))
    A = rng.random((C, m)) < rng.uniform(0.2, 0.7)
    w = rng.integers(1, int(rng.integers(2, 200)), C)
    bits = kernels._Bits(A, w)
    sel = [0]
    cand = np.arange(1, m)
    u = bits.uncovered(sel)
    left = ~A[:, sel].any(axis=1)

    def weight_left(*pos):
        return int(w[left & ~A[:, cand[list(pos)]].any(axis=1)].sum())

    pairs = [(a, b, weight_left(a, b)) for a, b in itertools.combinations(range(cand.size), 2)]
    triples = [(j, q, r, weight_left(j, q, r)) for j, q, r in itertools.combinations(range(cand.size), 3)]
    counts = sorted({int((left & ~A[:, cand[[a, b]]].any(axis=1)).sum()) for a, b, _ in pairs})
    js = rng.permutation(cand.size)
    for smax in {0, counts[0], counts[len(counts) // 2], int(np.median([t[2] for t in pairs])), 10**9}:
        ia, ib, got = bits.pairs_within(u, cand, smax)
        assert sorted(zip(ia.tolist(), ib.tolist(), got.tolist(), strict=True)) == [t for t in pairs if t[2] <= smax]
        rows = bits.triples_within(u, cand, js, smax)
        rank = {int(j): i for i, j in enumerate(js)}
        ref = sorted((t for t in triples if t[3] <= smax), key=lambda t: (rank[t[0]], t[1], t[2]))
        assert [tuple(r) for r in rows.tolist()] == ref


@pytest.mark.parametrize("seed", range(8))
def test_bit_set_quadruples_are_exact(seed):
    """The quadruples kernel, with its filter of each child's candidates by their gains (from the
    node's Gram matrix), against sums over the class rows: it returns every quadruple that leaves
    at most the allowance, and only those, in the children's order, however many parallel blocks
    share the children."""
    rng = np.random.default_rng(100 + seed)
    C, m = int(rng.integers(1, 250)), int(rng.integers(5, 12))
    A = rng.random((C, m)) < rng.uniform(0.2, 0.7)
    w = rng.integers(1, int(rng.integers(2, 100)), C)
    bits = kernels._Bits(A, w)
    cand = np.arange(1, m)
    u = bits.uncovered([0])
    left = ~A[:, 0]
    Y, wl = A[left][:, cand].astype(float), w[left].astype(float)
    g, P = wl @ Y, (Y * wl[:, None]).T @ Y
    quads = [(*t, int(w[left & ~A[:, cand[list(t)]].any(axis=1)].sum()))
             for t in itertools.combinations(range(cand.size), 4)]
    js = rng.permutation(cand.size)
    rank = {int(j): i for i, j in enumerate(js)}
    for smax in {0, 3, int(np.median([q[4] for q in quads])), 10**6}:
        ref = sorted((q for q in quads if q[4] <= smax), key=lambda q: (rank[q[0]], *q[1:4]))
        for blocks in (None, 1, 2, 3):  # the children shared out over parallel blocks: the same rows
            rows, nodes = bits.quads_within(u, cand, g, P, js, smax, blocks=blocks)
            assert [tuple(r) for r in rows.tolist()] == ref
            assert nodes[0] == js.size
    for blocks in (1, 3):  # more rows than room: None, whichever block overflows
        assert bits.quads_within(u, cand, g, P, js, 10**6, cap=1, blocks=blocks)[0] is None or len(quads) <= 1


@pytest.mark.parametrize("shape", ["half_sphere", "slot", "femur_like"])
def test_infeasible_by_a_few_points_with_four_and_five_setups_match_brute_force(range_matrices, shape,
                                                                                kernel_calls):
    """Three, four and five set-ups on 15 columns, targets one and a few points above the largest
    coverage C* (and C* itself): the same answer as the exhaustive enumeration, with the last three
    and four axes of the searches counted on bit sets."""
    n = range_matrices[shape].shape[0]
    for seed in range(2):
        V = column_subset(range_matrices[shape], 15, 20 + seed)
        for K in (3, 4, 5):
            cstar = brute_force_setups(V, coverage=1.0, max_setups=K).covered
            for req in (cstar, cstar + 1, cstar + 3):
                if req > n:
                    continue
                params = {"coverage": coverage_for(req, n), "max_setups": K}
                ref = brute_force_setups(V, **params)
                assert answer(select_setups(V, **params)) == answer(ref), (shape, seed, K, req)
                assert (ref.status == "infeasible") == (req > cstar)
    assert kernel_calls["triples"] > 0 and kernel_calls["quads"] > 0


def test_bit_sets_only_near_the_largest_coverage(range_matrices):
    """The kernels count the last axes only where at most search._BITS_SHARE of the points may be
    left uncovered (far below the ceiling every subset is counted to its end there); never in the
    least-overlap search or with zone conflicts."""
    V = range_matrices["half_sphere"]
    prob = _Problem(V, None, 1, 1)
    W = float(prob.w.sum())
    near = search._Search(prob, 3, "cover", W * (1 - search._BITS_SHARE / 2), 1e18)
    far = search._Search(prob, 3, "cover", W * (1 - search._BITS_SHARE * 2), 1e18)
    assert near._bits_now() and not far._bits_now()
    assert not search._Search(prob, 3, "overlap", W * 0.999, 1e18)._bits_now()
    zone = np.zeros(V.shape[0], bool)
    zone[::3] = True
    assert not search._Search(_Problem(V, zone, 1, 1), 3, "cover", W * 0.999, 1e18)._bits_now()


def test_price_rounds_stop_when_the_bound_stops_falling(range_matrices, monkeypatch):
    """The search's LP (min_gain): column generation stops after the first round that lowered the
    bound by less than min_gain points; the prices stay valid (the bound never below the best
    coverage of r axes), and without min_gain every round runs as before."""
    from planning.setups import lagrange
    from planning.setups.heuristics import _heuristics

    solves = []
    real = lagrange._solve_dual

    def solve(*a, **kw):
        solves.append(1)
        return real(*a, **kw)

    monkeypatch.setattr(lagrange, "_solve_dual", solve)
    more = 0
    for shape, r in itertools.product(range_matrices, (3, 4, 5)):
        prob = _Problem(range_matrices[shape], None, 1, 1)
        start = _heuristics(prob, r)[r][0]
        runs = {}
        for gain in (None, 0.0, np.inf):
            solves.clear()
            runs[gain] = (lagrange._prices(prob, r, start, min_gain=gain)[1], len(solves))
        assert runs[0.0] == runs[None]
        assert runs[np.inf][1] == min(2, runs[None][1])
        more += runs[None][1] > 2
        assert runs[np.inf][0] >= runs[None][0] - 1e-9
        best = select_setups(range_matrices[shape], coverage=1.0, max_setups=r).covered
        assert runs[np.inf][0] >= best
    assert more  # some LP here needs more than two rounds without min_gain
