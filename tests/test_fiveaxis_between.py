"""The motion between two 5-axis cutting positions is checked along the move, not at its midpoint
alone (planning.toolpath.fiveaxis.finishing.between_ok): on a long move whose axis turns far, the
flutes above the ball can meet the scan between the ends (issue 33: the range femur's passes across
holes and down walls, whose flutes cut 0.09 mm into the scan beside them)."""

from __future__ import annotations

import math

import numpy as np

from planning.geometry.tool import ball_tool
from planning.toolpath.fiveaxis.axes import slerp
from planning.toolpath.fiveaxis.finishing import (
    Admissible,
    _between_fractions,
    between_ok,
)
from planning.toolpath.frames import AreaFrame

R = 3.0
TOOL = ball_tool(R, flute_length_mm=12.0)
FRAME = AreaFrame(np.eye(3), np.zeros(3))


def inside_flutes(q, c, a) -> bool:
    """The rule of planning.geometry.axis_collision for the cutter alone: 0 < height <= 9, rho < R."""
    d = q - c
    h = float(d @ a)
    return 0.0 < h <= 12.0 - R and float(np.linalg.norm(d - h * a)) < R - 1e-6


def long_turning_move():
    """A 4 mm move whose axis turns 40 degrees, and one scan point beside it inside its flutes from
    about 0.68 to 0.93 of the way along (outside them at both ends and halfway)."""
    c0, c1 = np.array([0.0, 0.0, 0.0]), np.array([4.0, 0.0, 0.0])
    t = math.radians(40.0)
    a0, a1 = np.array([0.0, 0.0, 1.0]), np.array([math.sin(t), 0.0, math.cos(t)])
    u = 0.8
    cu, au = c0 + u * (c1 - c0), slerp(a0[None], a1[None], u)[0]
    q = cu + 1.5 * au + (R - 0.05) * np.array([0.0, 1.0, 0.0])      # beside the pass, 1.5 mm up the flutes
    return c0, c1, a0, a1, q


def test_a_point_met_only_late_in_a_long_turning_move_blocks_the_move():
    c0, c1, a0, a1, q = long_turning_move()
    # the premise: the midpoint and both ends leave the point outside (the former check passed it)
    assert not inside_flutes(q, c0, a0) and not inside_flutes(q, c1, a1)
    assert not inside_flutes(q, 0.5 * (c0 + c1), slerp(a0[None], a1[None], 0.5)[0])
    assert inside_flutes(q, c0 + 0.8 * (c1 - c0), slerp(a0[None], a1[None], 0.8)[0])
    ok = Admissible(FRAME, q[None], TOOL, max_swing_deg=90.0)
    assert ok(np.array([c0, c1, 0.5 * (c0 + c1)]), np.array([a0, a1, slerp(a0[None], a1[None], 0.5)[0]])).all()
    assert not between_ok(ok, c0[None], c1[None], a0[None], a1[None])[0]
    # the same move with the point moved off the flutes' way is admissible
    far = Admissible(FRAME, (q + np.array([0.0, 0.0, 20.0]))[None], TOOL, max_swing_deg=90.0)
    assert between_ok(far, c0[None], c1[None], a0[None], a1[None])[0]


def test_the_points_checked_are_at_most_a_step_and_a_degree_apart():
    # the long turning move is checked every 0.25 mm and every degree (its ends count as checked)
    rng = np.random.default_rng(3)
    c0, c1, a0, a1, _ = long_turning_move()
    owner, u = _between_fractions(c0[None], c1[None], a0[None], a1[None])
    assert (owner == 0).all() and np.all(np.diff(u) > 0)
    gap_mm = np.diff(np.r_[0.0, u, 1.0]).max() * 4.0
    turn = np.diff(np.r_[0.0, u, 1.0]).max() * 40.0
    assert gap_mm <= 0.25 + 1e-12 and turn <= 1.0 + 1e-12
    # short, slowly turning moves keep their midpoint alone
    o2, u2 = _between_fractions(np.zeros((5, 3)), rng.uniform(-0.1, 0.1, (5, 3)), np.tile(a0, (5, 1)),
                                np.tile(a0, (5, 1)))
    assert np.array_equal(o2, np.arange(5)) and np.allclose(u2, 0.5)
