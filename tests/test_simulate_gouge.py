"""Exact confirmation of suspected gouges (planning/simulate/gouge.py) against analytic answers."""

from __future__ import annotations

import math

import numpy as np

from planning.simulate.gouge import penetration_mm
from planning.simulate.motion import FEED, RAPID, ProgramMotion, ToolShape

BALL = ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=3.0, flute_length_mm=15.0,
                 pieces=((15.0, math.inf, 5.0),), gauge_length_mm=90.0)
FLAT = ToolShape(number=2, kind="flat", radius_mm=5.0, corner_radius_mm=0.0, flute_length_mm=25.0,
                 pieces=((25.0, math.inf, 10.0),), gauge_length_mm=90.0)


def _motion(start, end, tool, kind=FEED, axis=(0.0, 0.0, 1.0)) -> ProgramMotion:
    s, e = np.atleast_2d(np.asarray(start, float)), np.atleast_2d(np.asarray(end, float))
    P = s.shape[0]
    return ProgramMotion(program="t", area=0, line=np.arange(1, P + 1), kind=np.full(P, kind, np.int8),
                         tool=np.full(P, tool), start_mm=s, end_mm=e,
                         axis=np.broadcast_to(np.asarray(axis, float), (P, 3)).copy(),
                         machine_mm=np.zeros((P, 3)), rotary_deg=np.zeros((P, 2)))


def test_ball_depth_is_radius_minus_distance_to_the_centre_line():
    # the ball's tip runs along y at z = -0.05: its centre 2.95 above the points on z = 0
    m = _motion([[-10, 0, -0.05]], [[10, 0, -0.05]], 1)
    pts = np.array([[0, 0, 0], [3, 0, 0], [0, 1, 0.0], [0, 10, 0], [12.0, 0, 0]])
    pen = penetration_mm(pts, [m], {1: BALL})
    expect = 3.0 - np.hypot(pts[:, 1], 2.95 - pts[:, 2])
    expect[4] = 3.0 - math.hypot(2.0, 2.95)
    finite = np.isfinite(pen)
    assert np.allclose(pen[finite], expect[finite], atol=1e-9)
    assert pen[0] > 0.049 and pen[3] < 0


def test_flat_depth_is_the_nearer_of_the_bottom_face_and_the_side():
    m = _motion([[-20, 0, -1.0]], [[20, 0, -1.0]], 2)
    pts = np.array([[0, 0, 0.0],        # 1 mm above the bottom face, on the axis: depth 1
                    [0, 4.7, 3.0],      # 0.3 mm inside the side
                    [0, 5.2, 0.0],      # outside the radius
                    [0, 0, 30.0]])      # above the flutes
    pen = penetration_mm(pts, [m], {2: FLAT})
    assert np.isclose(pen[0], 1.0, atol=1e-9)
    assert np.isclose(pen[1], 0.3, atol=1e-9)
    assert not pen[2] > 0 and not pen[3] > 0


def test_a_tilted_plunge_and_rapids():
    a = np.array([1.0, 0.0, 1.0]) / math.sqrt(2)
    # a plunge along the axis ending with the tip 0.5 below the point along the axis
    p = np.array([[0.0, 0.0, 0.0]])
    m = _motion([p[0] + 10 * a], [p[0] - 0.5 * a], 2, axis=a)
    assert np.isclose(penetration_mm(p, [m], {2: FLAT})[0], 0.5, atol=1e-9)
    # the same move as a rapid cuts nothing
    r = _motion([p[0] + 10 * a], [p[0] - 0.5 * a], 2, kind=RAPID, axis=a)
    assert penetration_mm(p, [r], {2: FLAT})[0] == -np.inf


def test_against_dense_sampling_on_random_moves():
    """A ball without a fluted cylinder above it (flute length R): the exact depth equals a dense
    sampling of the ball centre along every move."""
    ball_only = ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=3.0, flute_length_mm=3.0)
    rng = np.random.default_rng(3)
    s = rng.uniform(-5, 5, (40, 3))
    e = s + rng.uniform(-6, 6, (40, 3))
    pts = rng.uniform(-6, 6, (60, 3))
    pen = penetration_mm(pts, [_motion(s, e, 1)], {1: ball_only})
    t = np.linspace(0, 1, 4001)
    c = s[:, None, :] + t[None, :, None] * (e - s)[:, None, :] + np.array([0, 0, 3.0])   # ball centres
    ref = 3.0 - np.linalg.norm(pts[:, None, None, :] - c[None], axis=3).min(axis=(1, 2))
    reached = ref > 0.0
    assert reached.sum() > 5
    assert np.allclose(pen[reached], ref[reached], atol=2e-3)
    assert np.all(np.maximum(pen, 0) >= np.maximum(ref, 0) - 1e-9)
