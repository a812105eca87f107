"""Set-up selection when no k <= max_setups reaches the coverage (issue 17): the price bound
(planning.setups.lagrange) that proves it, and the best-coverage answer, against exhaustive enumeration."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planning.setups import brute_force_setups, search, select_setups
from planning.setups.lagrange import _price_bound, _prices
from planning.setups.problem import _Problem


def answer(r):
    return r.status, r.k, r.covered, r.overlap, r.selected.tolist(), r.best_coverage_at_max


def assert_same(V, **params):
    ref = brute_force_setups(V, **params)
    got = select_setups(V, **params)
    assert answer(got) == answer(ref), params
    return ref, got


def hard_instance(seed: int):
    """A small random instance biased towards infeasibility: high coverage, few set-ups, sparse
    rows, some points no axis sees, repeated rows and columns, sometimes a functional zone."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(8, 70))
    m = int(rng.integers(3, 13))
    V = rng.random((n, m)) < rng.uniform(0.05, 0.45)
    if rng.random() < 0.4:  # a few points nobody sees: the coverage has a ceiling below 100 %
        V[rng.random(n) < 0.1] = False
    if rng.random() < 0.3:
        V = V[rng.integers(0, n, n)]
    if rng.random() < 0.3:
        V[:, rng.integers(0, m)] = V[:, rng.integers(0, m)]
    params = dict(
        coverage=float(rng.choice([0.8, 0.9, 0.95, 0.99, 1.0])),
        max_setups=int(rng.integers(1, 6)),
        min_points=int(rng.integers(1, 3)),
        zone_mask=(rng.random(n) < rng.uniform(0.02, 0.2)) if rng.random() < 0.3 else None,
    )
    return V, params


@pytest.mark.parametrize("seed", range(150))
def test_random_instances_match_brute_force(seed):
    V, params = hard_instance(seed)
    assert_same(V, **params)


def test_random_instances_are_mostly_infeasible_and_exercise_every_path(monkeypatch):
    """The seeded instances reach every branch of the infeasible case: proven at the root by the
    price bound, proven only by the searches, the best coverage reached with fewer than max_setups
    axes, and zone conflicts."""
    seen = {"infeasible": 0, "price-proof": 0, "search-proof": 0, "fewer-axes": 0, "zone": 0}
    real_prices = search._prices
    real_best = search._bnb_best_cover
    state = {}

    def prices(prob, r, start=None, **kw):
        mu, bound = real_prices(prob, r, start, **kw)
        state["price-proof"] = bound < prob.required
        return mu, bound

    def best(prob, K, *a, **kw):
        state["best"] = True
        state["zone"] = prob.has_conflicts
        return real_best(prob, K, *a, **kw)

    monkeypatch.setattr(search, "_prices", prices)
    monkeypatch.setattr(search, "_bnb_best_cover", best)
    for seed in range(150):
        state.clear()
        V, params = hard_instance(seed)
        r = select_setups(V, **params)
        if r.status != "infeasible" or not state.get("best"):
            continue
        seen["infeasible"] += 1
        seen["price-proof" if state.get("price-proof") else "search-proof"] += 1
        seen["fewer-axes"] += 0 < r.k < min(params["max_setups"], r.n_axes_kept)
        seen["zone"] += bool(state.get("zone"))
    assert seen["infeasible"] >= 60 and seen["price-proof"] >= 30, seen
    assert min(seen.values()) >= 3, seen


@settings(max_examples=120, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(6, 50), m=st.integers(2, 12), density=st.floats(0.03, 0.5),
    max_setups=st.integers(1, 5), coverage=st.sampled_from((0.9, 0.95, 1.0)),
    unseen=st.floats(0.0, 0.15), with_zone=st.booleans(), seed=st.integers(0, 2**32 - 1),
)
def test_hypothesis_matches_brute_force(n, m, density, max_setups, coverage, unseen, with_zone, seed):
    rng = np.random.default_rng(seed)
    V = rng.random((n, m)) < density
    V[rng.random(n) < unseen] = False
    zone = (rng.random(n) < 0.15) if with_zone else None
    assert_same(V, coverage=coverage, max_setups=max_setups, zone_mask=zone)


def ring(n_points=240, n_axes=24, cone=(10, 50), wobble=0.3, seed=0):
    """Normals around a turned part and axes around it, some points turned away from every axis."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.random(n_points)) * 2 * np.pi
    normals = np.stack([np.cos(t), np.sin(t), wobble * np.sin(5 * t)], axis=1)
    normals[rng.random(n_points) < 0.03, 2] = -3.0  # facing down, out of every cone
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    a = np.linspace(0, 2 * np.pi, n_axes, endpoint=False)
    axes = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    ang = np.degrees(np.arccos(np.clip(normals @ axes.T, -1, 1)))
    return (ang >= cone[0]) & (ang <= cone[1])


@pytest.mark.parametrize("max_setups", [3, 4, 5])
@pytest.mark.parametrize("seed", range(3))
def test_deep_structured_infeasible_instances(max_setups, seed):
    """k up to 5 from 24 axes: the searches at depth, the answer exactly as enumerated."""
    V = ring(seed=seed)
    ref, _ = assert_same(V, coverage=0.99, max_setups=max_setups)
    assert ref.status == "infeasible" and ref.k == max_setups


def test_best_coverage_with_fewer_axes_than_allowed():
    """Two axes already see every point any axis sees: the answer is those two, not four."""
    V = np.zeros((10, 4), bool)
    V[0:4, 0] = True
    V[4:8, 1] = True
    V[0:2, 2] = True
    V[5:7, 3] = True  # points 8 and 9: nobody
    r = select_setups(V, coverage=1.0, max_setups=4)
    assert (r.status, r.selected.tolist(), r.covered, r.overlap) == ("infeasible", [0, 1], 8, 0)
    assert answer(r) == answer(brute_force_setups(V, coverage=1.0, max_setups=4))


def test_zone_conflicts_keep_the_exact_answer():
    """With a zone a subset may not extend: the best coverage can need fewer axes than allowed."""
    V = np.zeros((9, 3), bool)
    V[0:5, 0] = True
    V[4:8, 1] = True
    V[3:9, 2] = True
    zone = np.zeros(9, bool)
    zone[4] = True  # every pair sees point 4 twice
    r = select_setups(V, coverage=1.0, max_setups=3, zone_mask=zone)
    ref = brute_force_setups(V, coverage=1.0, max_setups=3, zone_mask=zone)
    assert answer(r) == answer(ref) and r.k == 1


def test_time_limit_in_the_infeasible_case_gives_a_valid_answer():
    V = ring(n_points=400, n_axes=36, seed=1)
    full = select_setups(V, coverage=0.995, max_setups=5)
    assert full.status == "infeasible"
    r = select_setups(V, coverage=0.995, max_setups=5, time_limit_s=1e-9)
    assert r.status in ("infeasible", "unknown")
    assert r.covered <= full.covered
    if r.status == "infeasible" and r.covered < full.covered:
        assert "time limit" in r.message


# ------------------------------------------------------------------------------------------
# the price bound itself
# ------------------------------------------------------------------------------------------


def max_cover(V, r):
    return max(int(V[:, list(c)].any(axis=1).sum()) for k in range(1, r + 1)
               for c in itertools.combinations(range(V.shape[1]), k))


@pytest.mark.parametrize("seed", range(40))
def test_any_prices_bound_the_coverage_of_r_axes(seed):
    """W - sum mu + (r largest price gains) >= the best coverage of r axes, for any mu in [0, w];
    the LP prices give the smallest such bound up to their rounding."""
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(5, 40)), int(rng.integers(2, 9))
    V = rng.random((n, m)) < rng.uniform(0.1, 0.5)
    prob = _Problem(V, None, 1, n)
    if prob.m == 0:
        return
    # reduced axes: the best coverage is that of the original columns (identical ones merged)
    for r in range(1, min(4, prob.m) + 1):
        best = max_cover(V, r)
        for _ in range(5):
            mu = np.floor(rng.random(prob.C) * (prob.w + 1)).clip(0, prob.w).astype(np.float64)
            assert _price_bound(prob, mu, r) >= best
        mu, bound = _prices(prob, r)
        assert np.all((0 <= mu) & (mu <= prob.w))
        assert best <= bound <= prob.w.sum()
        assert bound == _price_bound(prob, mu, r)


def test_lp_prices_prove_a_clear_infeasibility_at_the_root(monkeypatch):
    """Six disjoint patches of 10 points and two axes allowed: the LP bound (20 points) is below the
    required 57 and no search runs."""
    V = np.zeros((60, 6), bool)
    for j in range(6):
        V[10 * j:10 * (j + 1), j] = True
    runs = []
    real = search._Search.run

    def run(self):
        runs.append((self.k, self.mode, self.stop_at_first))
        return real(self)

    monkeypatch.setattr(search._Search, "run", run)
    r = select_setups(V, coverage=0.95, max_setups=2)
    assert (r.status, r.covered, r.selected.tolist()) == ("infeasible", 20, [0, 1])
    assert not any(first for _, _, first in runs)  # no existence search was needed


@pytest.mark.parametrize("seed", range(60))
def test_searches_restarted_with_prices_keep_the_exact_answer(seed, monkeypatch):
    """With no probe budget every existence search of the feasible case restarts with the prices at
    once, and the least-overlap search always has them: the same answers."""
    monkeypatch.setattr(search, "_PROBE_NODES", 0)
    monkeypatch.setattr(search, "_NEAR_CEILING", 1.0)
    rng = np.random.default_rng(seed)
    V, params = hard_instance(1000 + seed)
    params.update(coverage=float(rng.choice([0.4, 0.6, 0.75])), max_setups=int(rng.integers(3, 6)))
    assert_same(V, **params)
