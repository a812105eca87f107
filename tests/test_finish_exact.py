"""The finish measured exactly from the finishing moves (issue 31 item 1, planning/simulate/finish.py):
analytic answers for a ball run over a plane and along a concave groove, a cut below the surface,
points the finishing never comes near, 5-axis moves with their own axes, and the figures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.simulate.finish import finish_left_mm
from planning.simulate.motion import FEED, RAPID, ProgramMotion, ToolShape
from planning.simulate.verify import finish_figures

R = 3.0
BALL = ToolShape(number=1, kind="ball", radius_mm=R, corner_radius_mm=R, flute_length_mm=20.0,
                 pieces=((20.0, 60.0, 4.0),))


def _motion(start, end, axis=(0.0, 0.0, 1.0), kind=None, tool=None) -> ProgramMotion:
    start, end = np.asarray(start, float).reshape(-1, 3), np.asarray(end, float).reshape(-1, 3)
    n = start.shape[0]
    ax = np.broadcast_to(np.asarray(axis, float), (n, 3)).copy()
    return ProgramMotion(program="t", area=0, line=np.arange(1, n + 1),
                         kind=np.full(n, FEED, np.int8) if kind is None else np.asarray(kind, np.int8),
                         tool=np.ones(n, np.int64) if tool is None else np.asarray(tool, np.int64),
                         start_mm=start, end_mm=end, axis=ax, machine_mm=np.zeros((n, 3)), rotary_deg=np.zeros((n, 2)))


def test_parallel_passes_over_a_plane_leave_the_distance_to_the_nearest_ball():
    """Passes along x at y = 0, s, 2s... with the tip on the plane z = 0: a point of the plane at y
    lies sqrt(d^2 + R^2) - R from the swept ball (d: its distance to the nearest pass), exactly; the
    largest, midway, is what the step over leaves."""
    s = 1.2
    ys = np.arange(0, 6) * s
    m = _motion([(-10, y, 0) for y in ys], [(10, y, 0) for y in ys])
    rng = np.random.default_rng(0)
    p = np.column_stack([rng.uniform(-8, 8, 500), rng.uniform(0, ys[-1], 500), np.zeros(500)])
    d = np.abs(p[:, 1:2] - ys[None]).min(axis=1)
    got = finish_left_mm(p, [m], BALL)
    np.testing.assert_allclose(got, np.sqrt(d * d + R * R) - R, atol=1e-12)
    assert got.max() <= math.sqrt((s / 2) ** 2 + R * R) - R + 1e-12


def test_a_concave_groove_leaves_more_than_the_plane_formula_says():
    """A groove of radius rho = 2 R (a concave cylinder along x, its axis at z = rho): passes along x
    with the ball resting in the groove at angles phi_k (its centre c_k at rho - R from the axis)
    leave over a point p of the groove min |p - c_k| - R (x free), exactly. Midway between two passes
    that is about rho / (rho - R) times what a plane leaves with its ball centres as far apart (issue
    31: the plane formula's step on a concave surface)."""
    rho = 2 * R
    phis = np.linspace(-0.6, 0.6, 7)
    centres = np.column_stack([np.zeros(7), (rho - R) * np.sin(phis), rho - (rho - R) * np.cos(phis)])
    tips = centres - np.array([0.0, 0.0, R])
    m = _motion(tips + [-10, 0, 0], tips + [10, 0, 0])
    theta = np.linspace(-0.55, 0.55, 301)
    p = np.column_stack([np.zeros_like(theta), rho * np.sin(theta), rho - rho * np.cos(theta)])
    got = finish_left_mm(p, [m], BALL)
    # analytic: distance from the point to each centre line (x free) less R, the least
    dy = p[:, 1:2] - centres[None, :, 1]
    dz = p[:, 2:3] - centres[None, :, 2]
    ref = np.sqrt(dy * dy + dz * dz).min(axis=1) - R
    np.testing.assert_allclose(got, ref, atol=1e-12)
    # midway between passes k and k+1, against a plane planned with the same distance between the
    # ball centres (the plane formula's step): about rho / (rho - R) = 2 times as much is left
    mid = 0.5 * (phis[3] + phis[4])
    pm = np.array([[0.0, rho * math.sin(mid), rho - rho * math.cos(mid)]])
    step = (rho - R) * (phis[4] - phis[3])
    plane = math.sqrt((step / 2) ** 2 + R * R) - R
    assert finish_left_mm(pm, [m], BALL)[0] / plane == pytest.approx(rho / (rho - R), rel=0.02)


def test_a_ball_below_the_surface_reads_negative_and_far_points_are_not_reached():
    m = _motion([(0, 0, -0.3)], [(10, 0, -0.3)])
    p = np.array([[5.0, 0.0, 0.0], [5.0, 0.0, 50.0], [100.0, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    got = finish_left_mm(p, [m], BALL)
    assert got[0] == pytest.approx(-0.3, abs=1e-12)
    assert np.isinf(got[1]) and got[1] > 0 and np.isinf(got[2]) and np.isinf(got[3])


def _left_brute(points, m) -> np.ndarray:
    """min over the feed moves of dist(p, ball-centre segment) - R, pair by pair."""
    c0, c1 = m.start_mm + R * m.axis, m.end_mm + R * m.axis
    d = c1 - c0
    w = points[:, None, :] - c0[None]
    t = np.clip((w * d[None]).sum(axis=2) / np.maximum((d * d).sum(axis=1), 1e-300)[None], 0.0, 1.0)
    return np.linalg.norm(w - t[:, :, None] * d[None], axis=2).min(axis=1) - R


@pytest.mark.parametrize("seed", range(4))
def test_within_the_reach_it_is_the_brute_force_and_never_below_it_beyond(seed):
    """The reach the module promises (``BEYOND_MM``): every point with at most that much left is
    measured exactly (the least over all moves, against brute force); farther points are either not
    reached (+inf: the moves are found near their tips, so a point up by the shank 2.4 mm from the
    ball's sphere can be) or read at least the brute force (the least over the moves found)."""
    from planning.simulate.finish import BEYOND_MM

    rng = np.random.default_rng(seed)
    n = 60
    s = rng.uniform(-20, 20, (n, 3))
    e = s + rng.normal(size=(n, 3)) * rng.uniform(0.1, 12.0, (n, 1))
    ax = rng.normal(size=(n, 3)) + [0.0, 0.0, 2.0]
    ax /= np.linalg.norm(ax, axis=1, keepdims=True)
    m = _motion(s, e)
    m.axis[:] = ax
    pts = np.concatenate([rng.uniform(-30, 30, (4000, 3)),
                          s + R * ax + rng.normal(size=(n, 3)) * 3.5])      # near the balls too
    ref = _left_brute(pts, m)
    got = finish_left_mm(pts, [m], BALL)
    within = ref <= BEYOND_MM
    assert within.sum() > 50 and (~within).sum() > 1000
    np.testing.assert_allclose(got[within], ref[within], atol=1e-9)
    assert (got[~within] >= ref[~within] - 1e-9).all()
    # the reach is not a sphere about the ball: beside the shank, above the ball's centre, 2.4 mm left
    # is not reached, while 2.4 mm left below the tip is
    one = _motion([(0, 0, 0)], [(4, 0, 0)])
    far = finish_left_mm(np.array([[7.0, 0.0, 7.5], [4.0, 0.0, -2.4]]), [one], BALL)
    assert np.isinf(far[0]) and far[1] == pytest.approx(2.4, abs=1e-12)


def test_a_turning_step_starts_from_the_ball_centre_the_step_before_left():
    """A 5-axis move as the reader's steps, each with its end's axis: the ball's centre runs from the
    centre where the step before ended (its tip plus R times ITS axis) to this step's end centre. A
    step read with its end axis at both ends would put the centre at its start R times the turn off
    (here 5 degrees: 0.26 mm) and read a cut of 0.011 mm below a point of the swept surface just past
    the turn, which the tool never made."""
    a0 = np.array([0.0, 0.0, 1.0])
    t = np.radians(5.0)
    a1 = np.array([np.sin(t), 0.0, np.cos(t)])
    # the tips: the ball centre stays on the line z = R while the axis turns (as the post keeps it)
    c0, c1, c2 = np.array([0.0, 0, R]), np.array([5.0, 0, R]), np.array([10.0, 0, R])
    s = np.array([c0 - R * a0, c1 - R * a0])
    e = np.array([c1 - R * a0, c2 - R * a1])
    m = _motion(s, e)
    m.axis[:] = np.array([a0, a1])
    rng = np.random.default_rng(3)
    pts = np.concatenate([np.array([[5.3, 0.0, 0.0], [5.0, 0.0, -0.05]]),
                          rng.uniform([-2, -4, -1], [12, 4, 1], (400, 3))])
    got = finish_left_mm(pts, [m], BALL)
    seg = np.array([[c0, c1], [c1, c2]])                   # the true ball-centre segments
    d = seg[:, 1] - seg[:, 0]
    w = pts[:, None, :] - seg[None, :, 0]
    tt = np.clip((w * d[None]).sum(axis=2) / (d * d).sum(axis=1)[None], 0.0, 1.0)
    ref = np.linalg.norm(w - tt[:, :, None] * d[None], axis=2).min(axis=1) - R
    np.testing.assert_allclose(got, ref, atol=1e-9)
    # on the swept surface just past the turn: nothing left, nothing cut (the end axis at both ends of
    # the second step read -0.0113 mm there); 0.05 mm under the turn: 0.05 mm left
    assert got[0] == pytest.approx(0.0, abs=1e-9) and got[1] == pytest.approx(0.05, abs=1e-9)


def test_only_the_finishing_tools_feed_moves_count_each_on_its_own_axis():
    """Rapids and another tool's moves leave nothing; a move with a tilted axis has its ball centre
    up that axis (5-axis moves as the reader cut them, each chord its own axis)."""
    tilt = np.array([math.sin(0.5), 0.0, math.cos(0.5)])
    m = _motion([(0, 0, 0), (0, 0, 0), (0, 0, 0)], [(10, 0, 0), (10, 0, 0), (10, 0, 0)], axis=tilt,
                kind=[FEED, RAPID, FEED], tool=[1, 1, 2])
    p = np.array([[5.0, 0.0, 0.0], [5.0, 4.0, 1.0]])
    got = finish_left_mm(p, [m], BALL)
    # the centre segment runs along x at R * tilt from the tip's line; both points project inside it
    off = p - R * tilt
    ref = np.hypot(off[:, 1], off[:, 2]) - R
    np.testing.assert_allclose(got, ref, atol=1e-12)
    with pytest.raises(ValueError):
        finish_left_mm(p, [m], ToolShape(number=1, kind="flat", radius_mm=3, corner_radius_mm=0, flute_length_mm=10))


def test_the_figures_count_finished_reached_and_below():
    left = np.array([0.0, 0.005, 0.02, 0.5, -0.004, -0.05, np.inf, 3.0])
    f = finish_figures(left, scallop_mm=0.01, tolerance_mm=0.01)
    assert f.n_points == 8 and f.limit_mm == pytest.approx(0.02)
    assert f.finished_share == pytest.approx(4 / 8)            # 0, 0.005, 0.02, -0.004
    assert f.reached_share == pytest.approx(7 / 8)
    assert f.n_below_tolerance == 1 and f.below_max_mm == pytest.approx(0.05)
    assert f.left_max_mm == pytest.approx(3.0)
    assert f.scallop_p95_mm == pytest.approx(np.percentile([0.0, 0.005, 0.02, 0.0], 95), abs=1e-4)
    wider = finish_figures(left, scallop_mm=0.01, tolerance_mm=0.01, below_mm=0.06)
    assert wider.finished_share == pytest.approx(5 / 8) and wider.n_below_tolerance == 0
    empty = finish_figures(np.full(3, np.inf), 0.01, 0.01)
    assert empty.finished_share == 0.0 and empty.reached_share == 0.0


def test_the_points_measured_are_all_or_a_fixed_sample():
    from planning.simulate.verify import finish_sample

    assert np.array_equal(finish_sample(10, 50), np.arange(10))
    assert np.array_equal(finish_sample(10, 0), np.arange(10))
    a, b = finish_sample(1000, 100), finish_sample(1000, 100)
    assert np.array_equal(a, b) and a.size == 100 and np.unique(a).size == 100
    assert np.all(np.diff(a) > 0) and a.min() >= 0 and a.max() < 1000
