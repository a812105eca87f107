"""Set-up selection (Makki et al. 2010 §3): exact solvers against exhaustive enumeration."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planning.errors import ParameterError
from planning.setups import SetupSelection, brute_force_setups, select_setups

COVERAGES = (0.5, 0.8, 0.9, 0.95, 1.0)


def random_instance(seed: int, *, zone: bool):
    """A small random instance: n 5..60 points, m 3..12 axes, random density, duplicates."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 61))
    m = int(rng.integers(3, 13))
    V = rng.random((n, m)) < rng.uniform(0.08, 0.6)
    if rng.random() < 0.3:  # repeated rows
        V = V[rng.integers(0, n, n)]
    if rng.random() < 0.3:  # an identical column
        V[:, rng.integers(0, m)] = V[:, rng.integers(0, m)]
    params = dict(
        coverage=float(rng.choice(COVERAGES)),
        max_setups=int(rng.integers(1, 5)),
        min_points=int(rng.integers(1, 4)),
        zone_mask=(rng.random(n) < rng.uniform(0.02, 0.3)) if zone else None,
    )
    return V, params


def summary(r: SetupSelection):
    return r.status, r.k, r.overlap, r.covered


def check_consistent(r: SetupSelection, V, params):
    """Fields agree with each other and with the matrix."""
    n = V.shape[0]
    assert r.n_points == n
    assert r.selected.dtype == np.int64 and r.selected.shape == (r.k,)
    assert list(r.selected) == sorted(set(r.selected.tolist()))
    deg = V[:, r.selected].sum(axis=1) if r.k else np.zeros(n, int)
    assert r.covered == int((deg >= 1).sum())
    assert r.overlap == int((deg >= 2).sum())
    assert r.coverage == pytest.approx(r.covered / n)
    zone = params.get("zone_mask")
    if zone is not None and r.k:
        assert not (deg[zone] >= 2).any(), "a functional-zone point is seen by two set-ups"
    if r.status in ("optimal", "feasible"):
        assert r.covered >= r.required_covered
        assert 1 <= r.k <= params["max_setups"]
    if r.status == "optimal":
        assert r.lower_bound == r.overlap and r.gap == 0.0
    if r.status == "infeasible":
        assert r.best_coverage_at_max == pytest.approx(r.coverage)
        assert r.covered < r.required_covered
    if r.k:
        counts = V[:, r.selected].sum(axis=0)
        assert (counts >= params.get("min_points", 1)).all()
    assert isinstance(r.message, str) and r.message


# ------------------------------------------------------------------------------------------
# property tests against exhaustive enumeration
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("zone", [False, True], ids=["no-zone", "zone"])
@pytest.mark.parametrize("seed", range(60))
def test_solvers_match_brute_force(seed, zone):
    V, params = random_instance(seed, zone=zone)
    ref = brute_force_setups(V, **params)
    check_consistent(ref, V, params)
    bnb = select_setups(V, solver="branch_and_bound", **params)
    check_consistent(bnb, V, params)
    assert summary(bnb) == summary(ref)
    assert bnb.selected.tolist() == ref.selected.tolist()  # same tie order, exactly
    cp = select_setups(V, solver="cpsat", **params)
    check_consistent(cp, V, params)
    assert summary(cp) == summary(ref)
    if ref.status == "infeasible":
        assert bnb.best_coverage_at_max == ref.best_coverage_at_max
        assert cp.best_coverage_at_max == ref.best_coverage_at_max
    assert bnb.n_classes == ref.n_classes and bnb.n_axes_kept == ref.n_axes_kept


def test_random_instances_exercise_every_path():
    """The property instances include deep searches (k >= 3), infeasible cases and zone conflicts."""
    seen = {"k>=3": 0, "infeasible": 0, "zone-binding": 0}
    for seed in range(60):
        V, params = random_instance(seed, zone=True)
        ref = brute_force_setups(V, **params)
        free = brute_force_setups(V, **{**params, "zone_mask": None})
        seen["k>=3"] += ref.k >= 3
        seen["infeasible"] += ref.status == "infeasible"
        seen["zone-binding"] += summary(free) != summary(ref)
    assert seen["k>=3"] >= 5 and seen["infeasible"] >= 5 and seen["zone-binding"] >= 5, seen


@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(
    n=st.integers(5, 60), m=st.integers(3, 14), density=st.floats(0.05, 0.7),
    max_setups=st.integers(1, 5), coverage=st.sampled_from(COVERAGES), min_points=st.integers(1, 3),
    with_zone=st.booleans(), seed=st.integers(0, 2**32 - 1),
)
def test_branch_and_bound_matches_brute_force_hypothesis(n, m, density, max_setups, coverage,
                                                         min_points, with_zone, seed):
    rng = np.random.default_rng(seed)
    V = rng.random((n, m)) < density
    params = dict(coverage=coverage, max_setups=max_setups, min_points=min_points,
                  zone_mask=(rng.random(n) < 0.15) if with_zone else None)
    ref = brute_force_setups(V, **params)
    got = select_setups(V, **params)
    assert summary(got) == summary(ref)
    assert got.selected.tolist() == ref.selected.tolist()


def test_deeper_structured_instance_matches_brute_force():
    """Normals on a ring and axes around it (a turned part): k = 4 from 24 axes."""
    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    normals = np.stack([np.cos(t), np.sin(t), 0.3 * np.sin(5 * t)], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    a = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    axes = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    ang = np.degrees(np.arccos(np.clip(normals @ axes.T, -1, 1)))
    V = (ang >= 10) & (ang <= 60)
    for cov in (0.9, 0.97):
        ref = brute_force_setups(V, coverage=cov, max_setups=5)
        got = select_setups(V, coverage=cov, max_setups=5)
        assert summary(got) == summary(ref) and got.selected.tolist() == ref.selected.tolist()
        assert got.k >= 3


# ------------------------------------------------------------------------------------------
# hand-made cases with known answers
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("solver", ["branch_and_bound", "cpsat", "brute_force"])
def test_two_disjoint_halves_need_two_setups_without_overlap(solver):
    V = np.zeros((10, 3), bool)
    V[:5, 0] = True
    V[5:, 1] = True
    V[:, 2] = np.arange(10) % 2 == 0  # half of each half
    r = select_setups(V, coverage=1.0, max_setups=3, solver=solver)
    assert (r.status, r.k, r.overlap, r.covered) == ("optimal", 2, 0, 10)
    assert r.selected.tolist() == [0, 1]
    assert r.message.startswith("2 set-ups cover 100.0 % with 0 overlap points (proven optimal)")


@pytest.mark.parametrize("solver", ["branch_and_bound", "cpsat", "brute_force"])
def test_zone_forbids_the_otherwise_best_pair(solver):
    # axes 0 and 1 cover everything with overlap 1 (point 4); axes 0 and 2 with overlap 2
    V = np.zeros((8, 3), bool)
    V[0:5, 0] = True
    V[4:8, 1] = True
    V[3:8, 2] = True
    free = select_setups(V, coverage=1.0, max_setups=2, solver=solver)
    assert free.selected.tolist() == [0, 1] and free.overlap == 1
    zone = np.zeros(8, bool)
    zone[4] = True  # a functional zone on the point both would machine
    r = select_setups(V, coverage=1.0, max_setups=2, zone_mask=zone, solver=solver)
    assert r.status == "infeasible"  # 0+2 and 1+2 also see point 4 twice
    zone2 = np.zeros(8, bool)
    zone2[4] = False
    zone2[6] = True  # seen by 1 and 2 only: 0+1 still allowed
    r2 = select_setups(V, coverage=1.0, max_setups=2, zone_mask=zone2, solver=solver)
    assert r2.selected.tolist() == [0, 1]
    # a zone on point 4 with a third axis that avoids it: 0 + 3 is forced
    V4 = np.concatenate([V, np.zeros((8, 1), bool)], axis=1)
    V4[5:8, 3] = True
    r3 = select_setups(V4, coverage=1.0, max_setups=2, zone_mask=zone, solver=solver)
    assert (r3.status, r3.selected.tolist(), r3.overlap) == ("optimal", [0, 3], 0)


@pytest.mark.parametrize("solver", ["branch_and_bound", "cpsat", "brute_force"])
def test_infeasible_reports_best_coverage(solver):
    V = np.eye(6, dtype=bool)  # every axis sees one point
    r = select_setups(V, coverage=0.95, max_setups=2, solver=solver)
    assert r.status == "infeasible"
    assert r.k == 2 and r.covered == 2
    if solver != "cpsat":  # CP-SAT does not apply the index tie rule
        assert r.selected.tolist() == [0, 1]
    assert r.best_coverage_at_max == pytest.approx(2 / 6)
    assert r.lower_bound is None and r.gap is None
    assert r.message == ("no 2 set-ups reach 95 % coverage; the best 2 set-ups cover 33.3 %: "
                         "change the part set-up or raise setups.max_setups")


@pytest.mark.parametrize("solver", ["branch_and_bound", "cpsat", "brute_force"])
def test_min_points_drops_small_axes(solver):
    V = np.zeros((10, 3), bool)
    V[:9, 0] = True
    V[9, 1] = True  # the only axis for point 9, but it sees one point only
    V[:, 2] = False
    r = select_setups(V, coverage=1.0, max_setups=3, min_points=2, solver=solver)
    assert r.status == "infeasible" and r.n_axes_kept == 1 and r.selected.tolist() == [0]
    r = select_setups(V, coverage=0.9, max_setups=3, min_points=2, solver=solver)
    assert (r.status, r.selected.tolist()) == ("optimal", [0])
    none = select_setups(V, coverage=0.9, max_setups=3, min_points=20, solver=solver)
    assert none.status == "infeasible" and none.k == 0 and none.n_axes_kept == 0
    assert "setups.min_points" in none.message


@pytest.mark.parametrize("solver", ["branch_and_bound", "cpsat", "brute_force"])
def test_points_no_axis_sees_count_in_n(solver):
    V = np.zeros((20, 2), bool)
    V[:19, 0] = True  # point 19 is unreachable
    assert select_setups(V, coverage=0.95, max_setups=2, solver=solver).status == "optimal"
    r = select_setups(V, coverage=1.0, max_setups=2, solver=solver)
    assert r.status == "infeasible" and r.covered == 19 and r.n_points == 20


def test_required_covered_uses_the_decimal_coverage():
    assert select_setups(np.ones((20, 1), bool), coverage=0.95).required_covered == 19
    assert select_setups(np.ones((2537, 1), bool), coverage=0.95).required_covered == 2411
    assert select_setups(np.ones((10, 1), bool), coverage=0.1).required_covered == 1
    assert select_setups(np.ones((3, 1), bool), coverage=1.0).required_covered == 3
    assert select_setups(np.ones((7, 1), bool), coverage=0.3).required_covered == math.ceil(2.1)


def test_identical_columns_lowest_index_wins():
    V = np.zeros((6, 4), bool)
    V[:3, 1] = V[:3, 3] = True  # 1 and 3 identical
    V[3:, 2] = True
    for solver in ("branch_and_bound", "brute_force"):
        r = select_setups(V, coverage=1.0, max_setups=3, solver=solver)
        assert r.selected.tolist() == [1, 2]


def test_tie_order_prefers_more_coverage_then_smaller_indices():
    V = np.zeros((10, 4), bool)
    V[0:5, 0] = True
    V[5:9, 1] = True  # 0 + 1: 9 points, overlap 0
    V[5:10, 2] = True  # 0 + 2: 10 points, overlap 0  -> preferred (more coverage)
    V[5:10, 3] = True  # identical to 2 -> 2 wins by index
    for solver in ("branch_and_bound", "cpsat", "brute_force"):
        r = select_setups(V, coverage=0.9, max_setups=2, solver=solver)
        assert (r.k, r.overlap, r.covered) == (2, 0, 10)
        if solver != "cpsat":
            assert r.selected.tolist() == [0, 2]


# ------------------------------------------------------------------------------------------
# reduction, determinism, limits
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(8))
def test_duplicate_rows_do_not_change_the_choice(seed):
    V, params = random_instance(seed, zone=True)
    base = select_setups(V, **params)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(2 * V.shape[0])
    V2 = np.concatenate([V, V])[perm]
    zone = params["zone_mask"]
    params2 = {**params, "zone_mask": None if zone is None else np.concatenate([zone, zone])[perm]}
    twice = select_setups(V2, **params2)
    assert twice.status == base.status and twice.selected.tolist() == base.selected.tolist()
    assert (twice.covered, twice.overlap, twice.n_points) == (2 * base.covered, 2 * base.overlap,
                                                              2 * base.n_points)
    assert twice.n_classes == base.n_classes


def test_zone_flag_is_part_of_the_class_key():
    # two identical rows, one in a zone: merging them would lose (or spread) the zone flag
    V = np.array([[1, 1], [1, 1], [1, 0], [0, 1]], bool)
    zone = np.array([True, False, False, False])
    r = select_setups(V, coverage=1.0, max_setups=2, zone_mask=zone)
    assert r.status == "infeasible" and r.n_classes == 4
    assert select_setups(V, coverage=0.75, max_setups=2, zone_mask=zone).selected.tolist() == [0]


def test_deterministic():
    V, params = random_instance(3, zone=True)
    runs = [select_setups(V, **params) for _ in range(3)]
    assert len({(summary(r), tuple(r.selected.tolist())) for r in runs}) == 1
    cps = [select_setups(V, solver="cpsat", **params) for _ in range(2)]
    assert len({(summary(r), tuple(r.selected.tolist())) for r in cps}) == 1


def test_progress_is_reported():
    V, params = random_instance(5, zone=False)
    calls = []
    select_setups(V, progress=lambda f, msg: calls.append((f, msg)), **params)
    assert calls and calls[-1][0] == 1.0
    assert all(0.0 <= f <= 1.0 and isinstance(msg, str) for f, msg in calls)


def ring_visibility(cone_deg, n_points=300, n_axes=36):
    t = np.linspace(0, 2 * np.pi, n_points, endpoint=False)
    normals = np.stack([np.cos(t), np.sin(t), np.zeros_like(t)], axis=1)
    a = np.linspace(0, 2 * np.pi, n_axes, endpoint=False)
    axes = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1)
    ang = np.degrees(np.arccos(np.clip(normals @ axes.T, -1, 1)))
    return (ang >= cone_deg[0]) & (ang <= cone_deg[1])


@pytest.mark.parametrize("cone", [(10, 60), (0, 70)])
def test_time_limit_gives_a_valid_answer(cone):
    """With a limit already spent the search stops at its first check and says so (no timing is
    asserted: the deadline has passed before the first check whatever the machine)."""
    V = ring_visibility(cone)
    params = dict(coverage=0.95, max_setups=5)
    full = select_setups(V, **params)
    assert full.status == "optimal" and full.k >= 3
    for solver in ("branch_and_bound", "cpsat"):
        r = select_setups(V, solver=solver, time_limit_s=1e-9, **params)
        check_consistent(r, V, params)
        assert r.status in ("optimal", "feasible", "unknown")
        if r.status == "optimal":
            assert summary(r) == summary(full)
        if r.status == "feasible":
            assert r.k >= full.k and "time limit" in r.message
            if r.lower_bound is not None:  # k proven minimal, overlap bounded
                assert r.k == full.k
                assert r.lower_bound <= full.overlap <= r.overlap
                assert 0.0 <= r.gap <= 1.0
    if cone == (0, 70):  # k = 3 reached by the heuristics: the overlap search is what stops
        r = select_setups(V, time_limit_s=1e-9, **params)
        assert r.status == "feasible" and r.k == full.k and r.lower_bound is not None


# ------------------------------------------------------------------------------------------
# parameter validation
# ------------------------------------------------------------------------------------------

V_OK = np.ones((4, 2), bool)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(coverage=0.0), "coverage"),
        (dict(coverage=1.5), "coverage"),
        (dict(coverage=float("nan")), "coverage"),
        (dict(coverage=True), "coverage"),
        (dict(coverage="0.9"), "coverage"),
        (dict(max_setups=0), "max_setups"),
        (dict(max_setups=2.0), "max_setups"),
        (dict(max_setups=True), "max_setups"),
        (dict(min_points=0), "min_points"),
        (dict(min_points=-1), "min_points"),
        (dict(zone_mask=np.ones(3, bool)), "zone_mask"),
        (dict(zone_mask=np.full(4, 2)), "zone_mask"),
        (dict(solver="simplex"), "solver"),
        (dict(time_limit_s=0), "time_limit_s"),
        (dict(time_limit_s=-1.0), "time_limit_s"),
        (dict(time_limit_s=float("inf")), "time_limit_s"),
        (dict(progress="yes"), "progress"),
    ],
)
def test_bad_parameters_are_rejected(kwargs, name):
    with pytest.raises(ParameterError) as exc:
        select_setups(V_OK, **kwargs)
    assert exc.value.code == "invalid_parameter"
    assert exc.value.details["parameter"] == name
    assert name in str(exc.value)


@pytest.mark.parametrize("bad", [np.ones(4, bool), np.ones((0, 3), bool), np.ones((3, 0), bool),
                                 np.full((3, 2), 0.5), np.array([["a", "b"]])])
def test_bad_visibility_is_rejected(bad):
    with pytest.raises(ParameterError) as exc:
        select_setups(bad)
    assert exc.value.details["parameter"] == "visibility"
    with pytest.raises(ParameterError):
        brute_force_setups(bad)


def test_zero_one_integers_are_accepted():
    r = select_setups(np.array([[1, 0], [0, 1]]), coverage=1.0, max_setups=2,
                      zone_mask=np.array([0, 1]))
    assert r.status == "optimal" and r.selected.tolist() == [0, 1]
