"""Candidate tool axes on the Gaussian sphere (planning/orientations/candidates.py, Makki 2010 §2.2.1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import SphericalVoronoi, cKDTree

from planning.errors import ParameterError
from planning.orientations.candidates import (
    MAX_AXES,
    CandidateAxes,
    candidate_axes,
    phi_theta_axes,
    uniform_axes,
)


def _sph(phi_deg, theta_deg):
    p, t = math.radians(phi_deg), math.radians(theta_deg)
    return np.array([math.sin(p) * math.cos(t), math.sin(p) * math.sin(t), math.cos(p)])


def _min_pair_angle_deg(axes: np.ndarray) -> float:
    d, _ = cKDTree(axes).query(axes, k=2)
    return math.degrees(2 * math.asin(min(1.0, d[:, 1].min() / 2)))


def _covering_radius_deg(axes: np.ndarray) -> float:
    """Exact covering radius: the farthest point from the set is a spherical Voronoi vertex."""
    sv = SphericalVoronoi(axes)
    d, _ = cKDTree(axes).query(sv.vertices)
    return math.degrees(2 * math.asin(min(1.0, d.max() / 2)))


def _check_consistent(c: CandidateAxes):
    m = len(c)
    assert c.axes.shape == (m, 3) and c.phi_deg.shape == (m,) and c.theta_deg.shape == (m,)
    assert c.axes.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(c.axes, axis=1), 1.0, atol=1e-15)
    assert np.all((c.phi_deg >= 0) & (c.phi_deg <= 180))
    assert np.all((c.theta_deg >= 0) & (c.theta_deg < 360))
    expect = np.stack([np.sin(np.radians(c.phi_deg)) * np.cos(np.radians(c.theta_deg)),
                       np.sin(np.radians(c.phi_deg)) * np.sin(np.radians(c.theta_deg)),
                       np.cos(np.radians(c.phi_deg))], axis=1)
    np.testing.assert_allclose(c.axes, expect, atol=1e-12)


# ---------------------------------------------------------------------------------------- phi_theta


def test_default_grid_count_order_and_poles():
    c = phi_theta_axes()
    assert len(c) == 17 * 12 + 2 == 206
    _check_consistent(c)
    # poles once, first and last, theta 0
    assert np.sum(c.phi_deg == 0) == 1 and np.sum(c.phi_deg == 180) == 1
    assert c.phi_deg[0] == 0 and c.theta_deg[0] == 0 and c.phi_deg[-1] == 180 and c.theta_deg[-1] == 0
    np.testing.assert_array_equal(c.axes[0], [0, 0, 1])
    np.testing.assert_array_equal(c.axes[-1], [0, 0, -1])
    # phi ascending then theta ascending
    order = np.lexsort((c.theta_deg, c.phi_deg))
    np.testing.assert_array_equal(order, np.arange(len(c)))
    ring = c.phi_deg[1:-1].reshape(17, 12)
    np.testing.assert_array_equal(ring[:, 0], np.arange(10, 180, 10))
    np.testing.assert_array_equal(c.theta_deg[1:13], np.arange(0, 360, 30))
    # no duplicate directions
    assert _min_pair_angle_deg(c.axes) > 1.0


def test_exact_values_and_paper_pair():
    c = phi_theta_axes(10, 30)
    i = np.flatnonzero((c.phi_deg == 50) & (c.theta_deg == 30))
    assert i.size == 1
    np.testing.assert_allclose(c.axes[i[0]], _sph(50, 30), atol=1e-15)
    np.testing.assert_allclose(c.axes[i[0]], [0.663, 0.383, 0.643], atol=5e-4)
    # the paper's best pair on its half sphere: [0.663 0.383 0.642; -0.813 -0.469 -0.342]
    for paper, (phi, theta) in (([0.663, 0.383, 0.642], (50, 30)), ([-0.813, -0.469, -0.342], (110, 210))):
        d = np.linalg.norm(c.axes - np.array(paper), axis=1)
        j = int(np.argmin(d))
        assert d[j] < 2e-3
        assert (c.phi_deg[j], c.theta_deg[j]) == (phi, theta)


def test_exact_zeros_at_right_angles():
    c = phi_theta_axes(10, 30)
    for phi, theta, v in ((90, 0, [1, 0, 0]), (90, 90, [0, 1, 0]), (90, 180, [-1, 0, 0]), (90, 270, [0, -1, 0])):
        j = np.flatnonzero((c.phi_deg == phi) & (c.theta_deg == theta))[0]
        np.testing.assert_array_equal(c.axes[j], v)
    assert not np.any((c.axes == 0) & np.signbit(c.axes))   # no negative zeros


@pytest.mark.parametrize("phi_step, theta_step, n_rings, south, n_theta", [
    (10, 30, 17, True, 12),
    (7, 30, 25, False, 12),        # 180 not a multiple of 7: last ring at 175, no south pole
    (180, 30, 0, True, 12),        # only the two poles
    (100, 45, 1, False, 8),
    (10, 25, 17, True, 15),        # 360 not a multiple of 25: theta 0..350
    (10, 360, 17, True, 1),
    (0.5, 90, 359, True, 4),
    (45, 0.25, 3, True, 1440),
])
def test_grid_counts(phi_step, theta_step, n_rings, south, n_theta):
    c = phi_theta_axes(phi_step, theta_step)
    assert len(c) == 1 + n_rings * n_theta + int(south)
    _check_consistent(c)
    assert np.sum(c.phi_deg == 0) == 1
    assert np.sum(c.phi_deg == 180) == int(south)
    if n_rings:                    # the poles alone have theta 0 only
        assert np.unique(c.theta_deg).size == n_theta
    assert _min_pair_angle_deg(c.axes) > 1e-3


@settings(max_examples=60, deadline=None)
@given(phi_step=st.floats(1.0, 180.0), theta_step=st.floats(1.0, 360.0))
def test_grid_properties(phi_step, theta_step):
    c = phi_theta_axes(phi_step, theta_step)
    _check_consistent(c)
    assert np.sum(np.all(c.axes == [0, 0, 1], axis=1)) == 1
    assert np.sum(c.phi_deg == 0) == 1 and np.sum(c.phi_deg == 180) <= 1
    inner = (c.phi_deg > 0) & (c.phi_deg < 180)
    assert np.all(c.theta_deg[~inner] == 0)
    # phi values are multiples of the step, theta values multiples of the theta step
    k = c.phi_deg[inner] / phi_step
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    assert np.all(c.theta_deg + 1e-9 < 360)
    assert _min_pair_angle_deg(c.axes) > 1e-6


# ----------------------------------------------------------------------------------------- uniform


@pytest.mark.parametrize("res", [90, 60, 45, 30, 20, 15, 10, 7.5, 5, 3])
def test_uniform_covering_radius_exact(res):
    c = uniform_axes(res)
    _check_consistent(c)
    assert _covering_radius_deg(c.axes) <= res
    # and not wastefully fine: the covering radius is close to the resolution
    assert _covering_radius_deg(c.axes) >= 0.85 * res or len(c) == 4


@pytest.mark.parametrize("res", [30, 10, 5])
def test_uniform_random_directions_within_resolution(res):
    rng = np.random.default_rng(1)
    v = rng.normal(size=(50_000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = np.vstack([v, [[0, 0, 1], [0, 0, -1], [1, 0, 0]]])
    c = uniform_axes(res)
    d, _ = cKDTree(c.axes).query(v)
    assert np.degrees(2 * np.arcsin(d / 2)).max() <= res


def test_uniform_count_scales_as_inverse_square():
    n = {r: len(uniform_axes(r)) for r in (20, 10, 5, 2.5)}
    assert n[10] == 247
    for a, b in ((20, 10), (10, 5), (5, 2.5)):
        assert n[b] / n[a] == pytest.approx(4.0, rel=0.03)
    # mean nearest-neighbour angle is about 1.24 x resolution (documented)
    c = uniform_axes(5)
    d, _ = cKDTree(c.axes).query(c.axes, k=2)
    nn = np.degrees(2 * np.arcsin(d[:, 1] / 2)).mean()
    assert 1.1 * 5 < nn < 1.4 * 5


def test_uniform_deterministic_and_distinct():
    a, b = uniform_axes(8), uniform_axes(8)
    np.testing.assert_array_equal(a.axes, b.axes)
    np.testing.assert_array_equal(a.phi_deg, b.phi_deg)
    assert _min_pair_angle_deg(a.axes) > 4.0
    # whole sphere: balanced between hemispheres
    assert abs(np.sum(a.axes[:, 2] > 0) - np.sum(a.axes[:, 2] < 0)) <= 1
    np.testing.assert_allclose(a.axes.mean(axis=0), 0, atol=0.02)


# ---------------------------------------------------------------------------------- candidate_axes


def test_candidate_axes_dispatch():
    a = candidate_axes("phi_theta", phi_step_deg=20, theta_step_deg=45)
    np.testing.assert_array_equal(a.axes, phi_theta_axes(20, 45).axes)
    b = candidate_axes("uniform", resolution_deg=12)
    np.testing.assert_array_equal(b.axes, uniform_axes(12).axes)
    assert len(candidate_axes("phi_theta")) == 206


def test_candidate_axes_unknown_sampling():
    with pytest.raises(ParameterError) as ei:
        candidate_axes("random")
    msg = str(ei.value)
    assert "orientations.sampling" in msg and "'random'" in msg and "phi_theta" in msg and "uniform" in msg
    assert ei.value.code == "invalid_parameter"


# ------------------------------------------------------------------------------------- validation


@pytest.mark.parametrize("kwargs, name, rng", [
    ({"phi_step_deg": 0}, "orientations.phi_step_deg", "(0, 180]"),
    ({"phi_step_deg": -10}, "orientations.phi_step_deg", "(0, 180]"),
    ({"phi_step_deg": 180.5}, "orientations.phi_step_deg", "(0, 180]"),
    ({"phi_step_deg": float("nan")}, "orientations.phi_step_deg", "(0, 180]"),
    ({"phi_step_deg": float("inf")}, "orientations.phi_step_deg", "(0, 180]"),
    ({"phi_step_deg": "10"}, "orientations.phi_step_deg", "(0, 180]"),
    ({"phi_step_deg": True}, "orientations.phi_step_deg", "(0, 180]"),
    ({"theta_step_deg": 0}, "orientations.theta_step_deg", "(0, 360]"),
    ({"theta_step_deg": 361}, "orientations.theta_step_deg", "(0, 360]"),
])
def test_phi_theta_validation(kwargs, name, rng):
    with pytest.raises(ParameterError) as ei:
        phi_theta_axes(**kwargs)
    msg = str(ei.value)
    assert name in msg and rng in msg
    value = next(iter(kwargs.values()))
    assert (repr(value) in msg) or (f"{float(value):g}" in msg)


@pytest.mark.parametrize("res", [0, -1, 90.01, float("nan")])
def test_uniform_validation(res):
    with pytest.raises(ParameterError, match=r"orientations\.resolution_deg.*\(0, 90\]"):
        uniform_axes(res)


def test_too_many_axes_rejected():
    with pytest.raises(ParameterError, match=str(MAX_AXES)):
        phi_theta_axes(0.01, 0.01)
    with pytest.raises(ParameterError, match=r"orientations\.resolution_deg"):
        uniform_axes(0.05)


def test_boundary_steps_accepted():
    assert len(phi_theta_axes(180, 360)) == 2
    assert len(uniform_axes(90)) == 4
