"""Tool axes per position for simultaneous 5-axis finishing (planning/toolpath/fiveaxis/axes.py; Chui 2008 eq. 12)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.toolpath.fiveaxis.axes import (
    clamp_to_cone,
    contact_normals,
    feed_directions,
    limit_axis_rate,
    plan_axes,
    turn_deg,
)

R = 3.0


def _cylinder_pass(rc: float, z0: float, n: int, *, vertical: bool = False):
    """Ball centres of one pass on the outside of the cylinder x^2 + y^2 = rc^2 (axis +Z), the exact
    outward normals and the feed tangents: a horizontal circle (counter-clockwise) or a vertical line."""
    if vertical:
        z = np.linspace(z0, z0 + 20.0, n)
        phi = np.full(n, 0.3)
        t = np.tile([0.0, 0.0, 1.0], (n, 1))
    else:
        phi = np.linspace(0.0, 1.5 * math.pi, n)
        z = np.full(n, z0)
        t = np.stack([-np.sin(phi), np.cos(phi), np.zeros(n)], axis=1)
    r = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], axis=1)
    centres = (rc + R) * r + np.stack([np.zeros(n), np.zeros(n), z], axis=1)
    return centres, r, t


@pytest.mark.parametrize("frame", ["frenet", "surface"])
@pytest.mark.parametrize("vertical", [False, True])
def test_a_cylinder_wall_with_a_constant_tilt_gets_the_analytic_axis(frame, vertical):
    centres, r, t = _cylinder_pass(20.0, 5.0, 200, vertical=vertical)
    tilt, lead = 15.0, 5.0
    plan = plan_axes(centres, np.zeros(len(centres), int), r, lead_deg=lead, tilt_deg=tilt, cone_deg=(10, 60),
                     max_rate_deg_per_mm=10.0, frame=frame)
    th, ld = math.radians(tilt), math.radians(lead)
    a0 = math.cos(th) * r + math.sin(th) * np.cross(t, r)     # eq. 12 with the outward normal
    want = math.cos(ld) * a0 + math.sin(ld) * t
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    assert not plan.blocked.any() and not plan.breaks.any()
    assert np.abs(plan.axes - want).max() < 1e-9       # the ends too: the end circle's tangent
    # the angle to the normal is the tilt and lead combined, constant along the pass
    ang = turn_deg(plan.axes, r)
    assert np.ptp(ang) < 1e-9


def test_the_horizontal_circle_s_axis_leans_down_by_the_tilt():
    # counter-clockwise seen from +Z: t x r = -Z, so a positive tilt leans the spindle down
    centres, r, _ = _cylinder_pass(20.0, 0.0, 100)
    plan = plan_axes(centres, np.zeros(100, int), r, lead_deg=0.0, tilt_deg=20.0, cone_deg=(10, 60),
                     max_rate_deg_per_mm=10.0)
    assert np.allclose(plan.axes[:, 2], -math.sin(math.radians(20.0)), atol=1e-9)


def test_contact_normals_from_the_scan_match_the_cylinder_normals():
    rng = np.random.default_rng(3)
    n = 400_000                             # about 0.1 mm apart
    phi = rng.uniform(0, 2 * math.pi, n)
    z = rng.uniform(-10, 20, n)
    cloud = np.stack([20 * np.cos(phi), 20 * np.sin(phi), z], axis=1)
    centres, r, _ = _cylinder_pass(20.0, 5.0, 100)
    nrm = contact_normals(centres, cloud)
    spacing = math.sqrt(2 * math.pi * 20 * 30 / n)
    # the nearest scan point lies within about a spacing of the contact: an error of asin(spacing / R)
    assert turn_deg(nrm, r).max() < math.degrees(math.asin(2 * spacing / R))


def test_axes_too_close_to_or_too_far_from_the_normal_are_turned_into_the_cone():
    rng = np.random.default_rng(0)
    nrm = rng.normal(size=(5000, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    a = rng.normal(size=(5000, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    a[:10] = nrm[:10]                       # along the normal: needs the fallback direction
    out = clamp_to_cone(a, nrm, (10.0, 60.0), fallback=np.cross(nrm, [[0.0, 0.0, 1.0]]) + 1e-3)
    ang = turn_deg(out, nrm)
    assert ang.min() >= 10.0 - 1e-9 and ang.max() <= 60.0 + 1e-9
    inside = (turn_deg(a, nrm) >= 10) & (turn_deg(a, nrm) <= 60)
    assert np.array_equal(out[inside], a[inside])
    # turned in the plane of the normal and the axis: the direction about the normal is kept
    p_in = a - np.einsum("ij,ij->i", a, nrm)[:, None] * nrm
    p_out = out - np.einsum("ij,ij->i", out, nrm)[:, None] * nrm
    keep = np.linalg.norm(p_in, axis=1) > 1e-6
    cos = np.einsum("ij,ij->i", p_in[keep], p_out[keep]) / (
        np.linalg.norm(p_in[keep], axis=1) * np.linalg.norm(p_out[keep], axis=1))
    assert cos.min() > 1 - 1e-9


def test_the_rate_limit_holds_exactly_between_linked_neighbours():
    rng = np.random.default_rng(1)
    n = 3000
    axes = rng.normal(size=(n, 3)) + [0, 0, 3]
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    centres = np.cumsum(rng.uniform(0.05, 0.5, size=(n, 3)) * [1, 0.1, 0.1], axis=0)
    linked = rng.random(n) > 0.05
    out = limit_axis_rate(axes, centres, linked, 4.0)
    d = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    turn = turn_deg(out[1:], out[:-1])
    lk = linked[1:]
    assert (turn[lk] <= 4.0 * d[lk] + 1e-9).all()
    # unlinked starts keep their wanted axis on the forward sweep's side
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0)
    # and a limit that is never reached changes nothing
    loose = limit_axis_rate(axes, centres, linked, 1e6)
    assert np.allclose(loose, axes)


def _ridge_path(n: int = 200):
    """Centres of a ball rolling over a sharp ridge z = 8 - |x|: up the left flank, round the apex on
    a circle of radius R (the normal turns 90 degrees in R pi / 2 mm), down the right flank."""
    x = np.linspace(-10, 0, n, endpoint=False)
    left = np.stack([x, np.zeros(n), 8 + x], axis=1)
    n_l = np.tile([-1.0, 0.0, 1.0], (n, 1)) / math.sqrt(2)
    th = np.linspace(-math.pi / 4, math.pi / 4, 60)
    n_a = np.stack([np.sin(th), np.zeros(60), np.cos(th)], axis=1)
    apex = np.zeros((60, 3)) + [0.0, 0.0, 8.0]
    right = left[::-1] * [-1, 1, 1]
    n_r = n_l * [-1, 1, 1]
    surf = np.concatenate([left, apex, right])
    nrm = np.concatenate([n_l, n_a, n_r])
    return surf + R * nrm, nrm


def test_plan_axes_stays_in_the_cone_and_under_the_rate_limit_over_a_sharp_ridge():
    centres, nrm = _ridge_path()
    rate = 6.0
    plan = plan_axes(centres, np.zeros(len(centres), int), nrm, lead_deg=0.0, tilt_deg=15.0, cone_deg=(10, 60),
                     max_rate_deg_per_mm=rate)
    ok = ~plan.blocked
    ang = turn_deg(plan.axes[ok], nrm[ok])
    assert ang.min() >= 10 - 1e-9 and ang.max() <= 60 + 1e-9
    d = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    turn = turn_deg(plan.axes[1:], plan.axes[:-1])
    limited = ~plan.breaks[1:] & ok[1:] & ok[:-1]
    assert (turn[limited] <= rate * d[limited] + 1e-6).all()
    # the cone leaves room (the normal turns 90 degrees; a vertical axis is 45 degrees from both flanks)
    assert not plan.breaks.any()
    # the ideal axes turn faster than the limit round the apex
    assert (turn_deg(plan.ideal[1:], plan.ideal[:-1]) > rate * d + 1e-3).any()


def test_positions_whose_axes_fail_the_test_take_an_admissible_one_or_are_blocked():
    centres, r, _ = _cylinder_pass(20.0, 0.0, 200)
    # admissible: axes leaning up (z >= 0.2); the tilt of 20 degrees leans them down
    ok = lambda c, a: a[:, 2] >= 0.2                                   # noqa: E731
    plan = plan_axes(centres, np.zeros(200, int), r, lead_deg=0.0, tilt_deg=20.0, cone_deg=(10, 60),
                     max_rate_deg_per_mm=10.0, ok=ok)
    assert not plan.blocked.any()
    assert plan.n_alternatives == 200
    assert (plan.axes[:, 2] >= 0.2).all()
    ang = turn_deg(plan.axes, r)
    assert ang.min() >= 10 - 1e-9 and ang.max() <= 60 + 1e-9
    # nothing admissible: every position is blocked, none is cut with a failing axis
    never = lambda c, a: np.zeros(c.shape[0], dtype=bool)               # noqa: E731
    plan = plan_axes(centres, np.zeros(200, int), r, lead_deg=0.0, tilt_deg=20.0, cone_deg=(10, 60),
                     max_rate_deg_per_mm=10.0, ok=never)
    assert plan.blocked.all()


def test_the_ring_search_memo_gives_the_same_axes_and_searches_each_position_once():
    centres, r, _ = _cylinder_pass(20.0, 0.0, 200)
    tested = []

    def ok(c, a):                  # admissible: leaning up, and off a band of x (some positions blocked)
        tested.append(c.shape[0])
        return (a[:, 2] >= 0.2) & ~((c[:, 0] > 5.0) & (c[:, 0] < 8.0))

    kw = {"lead_deg": 0.0, "tilt_deg": 20.0, "cone_deg": (10, 60), "max_rate_deg_per_mm": 10.0, "ok": ok}
    plain = plan_axes(centres, np.zeros(200, int), r, **kw)
    n_plain = sum(tested)
    memo: dict = {}
    tested.clear()
    first = plan_axes(centres, np.zeros(200, int), r, memo=memo, **kw)
    n_first = sum(tested)
    tested.clear()
    again = plan_axes(centres, np.zeros(200, int), r, memo=memo, **kw)
    n_again = sum(tested)
    for p in (first, again):
        assert np.array_equal(p.axes, plain.axes) and np.array_equal(p.blocked, plain.blocked)
        assert p.n_alternatives == plain.n_alternatives
    assert plain.blocked.any() and plain.n_alternatives > 0
    assert n_first <= n_plain
    # planned again (as five_axis_path does after cutting out a few positions): no ring is searched again,
    # only the positions' own axes are tested
    assert n_again < n_plain / 4, (n_plain, n_first, n_again)


def test_feed_directions_follow_each_pass_and_restart_on_the_next():
    centres = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 1, 5], [1, 1, 5], [0, 1, 5.0]])
    t = feed_directions(centres, np.array([0, 0, 0, 1, 1, 1]))
    assert np.allclose(t[:3], [1, 0, 0]) and np.allclose(t[3:], [-1, 0, 0])
