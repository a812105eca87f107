"""The least label changes the visibility allows (planning/areas/bound.py) against brute force."""

import itertools

import numpy as np
import pytest

from planning.areas.assign import assign_areas
from planning.areas.bound import cut_weight, least_label_changes
from planning.areas.graph import neighbour_graph
from schemas.params import AreasParams


def _random_case(seed: int, n: int, k: int):
    rng = np.random.default_rng(seed)
    pairs = np.array([(a, b) for a in range(n) for b in range(a + 1, n)])
    edges = pairs[rng.random(len(pairs)) < 0.45]
    allowed = rng.random((n, k)) < 0.5
    allowed[np.arange(n), rng.integers(0, k, n)] = True
    weights = rng.integers(1, 5, len(edges)).astype(float)
    return edges, allowed, weights


def _brute(edges, allowed, weights):
    choices = [np.flatnonzero(row) for row in allowed]
    return min(cut_weight(edges, np.array(lab), weights) for lab in itertools.product(*choices))


@pytest.mark.parametrize("seed,n,k", [(s, n, k) for s in range(6) for n, k in ((6, 2), (7, 3), (8, 3), (7, 4))])
def test_bound_is_below_the_least_cut_within_its_gap_and_its_labelling_is_allowed(seed, n, k):
    edges, allowed, weights = _random_case(seed, n, k)
    best = _brute(edges, allowed, weights)
    b = least_label_changes(edges, allowed, weights)
    assert allowed[np.arange(n), b.labels].all()
    assert b.cut == pytest.approx(cut_weight(edges, b.labels, weights))
    assert b.bound <= best + 1e-7 <= b.cut + 2e-7
    assert best <= 2.0 * b.bound + 1e-7                      # the LP's rounding gap
    if b.integral:
        assert b.bound == pytest.approx(best) and b.cut == pytest.approx(best)


def test_two_labels_give_the_exact_minimum_cut():
    # with two labels the LP is a minimum s-t cut: always integral, equal to brute force
    for seed in range(10):
        edges, allowed, weights = _random_case(100 + seed, 9, 2)
        b = least_label_changes(edges, allowed, weights)
        assert b.bound == pytest.approx(_brute(edges, allowed, weights), abs=1e-7)


def test_forced_neighbours_with_no_common_label_are_counted_and_a_free_chain_costs_one_cut():
    # a path 0-1-2-3-4: 0 only sees set-up 0, 4 only set-up 1, the middle sees both -> one cut;
    # 5-6 an edge whose ends share no set-up -> one more
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4], [5, 6]])
    allowed = np.array([[1, 0], [1, 1], [1, 1], [1, 1], [0, 1], [1, 0], [0, 1]], bool)
    b = least_label_changes(edges, allowed)
    assert b.bound == pytest.approx(2.0) and b.cut == pytest.approx(2.0) and b.integral


def test_the_plans_labelling_never_cuts_fewer_edges_than_the_bound():
    rng = np.random.default_rng(3)
    pts = rng.random((400, 3)) * [30.0, 30.0, 0.0]
    normals = np.tile([0.0, 0.0, 1.0], (400, 1))
    sees = np.stack([pts[:, 0] < 20 + rng.normal(0, 2, 400), pts[:, 0] > 10 + rng.normal(0, 2, 400),
                     pts[:, 1] > 15 + rng.normal(0, 2, 400)], axis=1)
    axes = np.array([[0.5, 0.0, 0.866], [-0.5, 0.0, 0.866], [0.0, 0.5, 0.866]])
    a = assign_areas(pts, np.arange(400), normals, sees, np.arange(3), axes, (10, 80), AreasParams())
    g = neighbour_graph(pts, normals, AreasParams().neighbours)
    allowed = sees | ~sees.any(axis=1)[:, None]
    b = least_label_changes(g.edges, allowed)
    assert b.bound <= cut_weight(g.edges, a.labels) + 1e-7
    assert a.label_change_share * len(g.edges) == pytest.approx(cut_weight(g.edges, a.labels))


def _bench():
    import importlib.util
    import os

    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bench", "bench_areas_range.py")
    spec = importlib.util.spec_from_file_location("bench_areas_range_under_test", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _grid_graph(nx, ny):
    from planning.areas.graph import SurfaceGraph

    idx = np.arange(nx * ny).reshape(ny, nx)
    edges = np.concatenate([np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1),
                            np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1)])
    m = edges.shape[0]
    return SurfaceGraph(edges=edges, length_mm=np.ones(m), seam_mm=np.ones(m), normal_angle_deg=np.zeros(m),
                        area_mm2=np.ones(nx * ny), bond=np.zeros(m, bool))


def test_bench_frees_only_forced_specks_under_the_size():
    g = _grid_graph(6, 1)                                 # a path 0-1-2-3-4-5, 1 mm^2 a point
    allowed = np.array([[1, 0], [1, 1], [0, 1], [0, 1], [0, 1], [1, 1]], bool)
    freed = _bench().freed_allowed(g, allowed, 2.0)       # the 1-point speck at 0 goes, the 3-point one stays
    assert freed[0].all() and freed[1].all() and freed[5].all()
    assert (freed[2:5] == allowed[2:5]).all()
    assert least_label_changes(g.edges, freed).bound <= least_label_changes(g.edges, allowed).bound


def test_bench_corridor_joins_two_regions_of_one_visible_piece_by_the_fewest_points():
    # a 7 x 3 grid: set-up 0 on the left and right columns, set-up 1 between; row 0 may be 0 throughout
    g = _grid_graph(7, 3)
    labels = np.ones(21, np.int64)
    labels[[0, 7, 14, 6, 13, 20]] = 0
    allowed = np.ones((21, 2), bool)
    allowed[7:, 0] = False
    allowed[[7, 14, 13, 20], 0] = True
    lab, added = _bench().corridor_join(g, labels, allowed, 0)
    assert added == 5 and (lab[:7] == 0).all() and allowed[np.arange(21), lab].all()
