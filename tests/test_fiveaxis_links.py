"""Links of a 5-axis finishing path planned on the stock (issue 33 item 1,
planning/toolpath/fiveaxis/links.py): up the local axis to a clearance over the stock, across, down,
checked when planned; measured here against the stock's own boxes by plain geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.simulate.dexel import TriDexel
from planning.simulate.motion import ToolShape
from planning.toolpath.fiveaxis.links import StockLinks, air_links
from planning.toolpath.frames import AreaFrame
from planning.toolpath.guard import run_on_stock
from planning.toolpath.moves import FEED, RAPID, USE_CUT, USE_PLUNGE, USE_RAPID, USE_RETRACT, Toolpath

R = 3.0
BALL = ToolShape(number=1, kind="ball", radius_mm=R, corner_radius_mm=R, flute_length_mm=20.0,
                 pieces=((20.0, math.inf, 10.0),), gauge_length_mm=100.0)
FRAME = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
CLEAR = 1.0
SAFE = 60.0


def _stock(ridge_top: float) -> tuple[TriDexel, list]:
    """A slab (top 0.5 mm over the finished surface z = 0) with a ridge across x in [-5, 5]."""
    boxes = [((-45.0, -20.0, -30.0), (45.0, 20.0, 0.5)), ((-5.0, -20.0, 0.0), (5.0, 20.0, ridge_top))]
    lo, hi = (-60.0, -35.0, -35.0), (60.0, 35.0, max(ridge_top, 0.5) + 80.0)
    m = TriDexel.box(*boxes[0], resolution_mm=0.5, domain_lo=lo, domain_hi=hi)
    m = m.union(TriDexel.box(*boxes[1], resolution_mm=0.5, domain_lo=lo, domain_hi=hi))
    return m, boxes


def _path() -> tuple[Toolpath, np.ndarray]:
    """Two passes along y, at x = -20 (axis leaning -x) and x = +20 (leaning +x), joined by the
    finishing's short link: up 5 mm, across, down."""
    ua = np.array([-0.3, 0.0, 1.0]) / math.hypot(0.3, 1.0)
    ub = np.array([0.3, 0.0, 1.0]) / math.hypot(0.3, 1.0)
    y = np.linspace(-10.0, 10.0, 11)
    p1 = np.stack([np.full_like(y, -20.0), y, np.full_like(y, R)], 1)
    p2 = np.stack([np.full_like(y, 20.0), y[::-1], np.full_like(y, R)], 1)
    link = np.array([[-20.0, 10.0, R + 5.0], [20.0, 10.0, R + 5.0]])
    xyz = np.concatenate([p1[:1] + [0, 0, 10], p1, link, p2])
    kind = np.array([RAPID, FEED] + [FEED] * 10 + [FEED, RAPID] + [FEED] * 11, np.int8)
    use = np.array([USE_RAPID, USE_PLUNGE] + [USE_CUT] * 10 + [USE_RETRACT, USE_RAPID, USE_PLUNGE] + [USE_CUT] * 10,
                   np.int8)
    axis = np.concatenate([np.repeat(ua[None], 12, 0), np.repeat(ub[None], 2 + 11, 0)])
    P = xyz.shape[0]
    pi = np.concatenate([[-1], np.zeros(11), [-1, -1], np.ones(11)]).astype(np.int32)
    tp = Toolpath(xyz_mm=xyz, kind=kind, centre_mm=np.full((P, 3), np.nan), plane=np.zeros(P, np.int8), use=use,
                  tip_offset_mm=R, axis=axis)
    return tp, pi


def _tool_distance(points: np.ndarray, tip: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Distance from each point to the tool at ``tip`` along ``axis`` (a ball-ended cylinder of radius R
    up to the flute length, then the holder, radius 10, unbounded): plain geometry, no dexels."""
    rel = points - tip
    s = rel @ axis
    radial = np.linalg.norm(rel - np.outer(s, axis), axis=1)
    # the cutter: a capsule from the ball centre (s = R) to the flute top
    sc = np.clip(s, R, BALL.flute_length_mm)
    d_cut = np.hypot(radial, s - sc) - R
    # the holder: a cylinder from the flute top up
    below = np.maximum(BALL.flute_length_mm - s, 0.0)
    d_hold = np.hypot(np.maximum(radial - 10.0, 0.0), below)
    return np.minimum(d_cut, d_hold)


def _slerp1(a, b, t):
    w = math.acos(float(np.clip(a @ b, -1.0, 1.0)))
    if w < 1e-12:
        return a
    return (math.sin((1 - t) * w) * a + math.sin(t * w) * b) / math.sin(w)


def _box_surface(lo, hi, step=0.5) -> np.ndarray:
    g = [np.arange(a, b + 1e-9, step) for a, b in zip(lo, hi)]
    pts = []
    for f in range(3):
        for v in (lo[f], hi[f]):
            o = [g[(f + 1) % 3], g[(f + 2) % 3]]
            A, B = np.meshgrid(*o, indexing="ij")
            q = np.empty((A.size, 3))
            q[:, f], q[:, (f + 1) % 3], q[:, (f + 2) % 3] = v, A.ravel(), B.ravel()
            pts.append(q)
    return np.concatenate(pts)


@pytest.mark.parametrize("ridge", [2.0, 12.0])
def test_the_link_goes_up_each_axis_and_over_the_stock(ridge):
    stock, boxes = _stock(ridge)
    tp, pi = _path()
    a, b = air_links(tp)
    assert a.tolist() == [11] and b.tolist() == [14]
    # over the high ridge the finishing's own link runs into the stock
    before, _, _ = run_on_stock(tp, FRAME, BALL, stock, None, None, rapid_clearance_mm=CLEAR)
    assert before.rapid.any() == (ridge > 5)

    links = StockLinks(FRAME, BALL, stock, None, None, safe_z_mm=SAFE, clearance_mm=CLEAR + 0.5)
    out, opi = links(tp, pi)
    f = links.figures
    assert f.n_links == 1 and f.n_planned == 1 and f.n_kept == 0
    # the cutting positions, their axes and passes are the same
    touch = (tp.kind == FEED) & np.isin(tp.use, (USE_CUT, USE_PLUNGE))
    touch2 = (out.kind == FEED) & np.isin(out.use, (USE_CUT, USE_PLUNGE))
    assert np.array_equal(out.xyz_mm[touch2], tp.xyz_mm[touch])
    assert np.allclose(out.axis[touch2], tp.axis[touch])
    assert np.array_equal(opi[touch2], pi[touch])
    # the new link: up a's axis, across (rapids through evenly spaced points), down b's axis, a plunge
    j = 12
    ua, ub = tp.axis[11], tp.axis[14]
    new = out.xyz_mm[j:j + 7]
    up, top_a, top_b, down = new[0], new[1], new[5], new[6]
    for p, base, u in ((up, tp.xyz_mm[11], ua), (top_a, tp.xyz_mm[11], ua), (top_b, tp.xyz_mm[14], ub),
                       (down, tp.xyz_mm[14], ub)):
        d = p - base
        assert np.linalg.norm(np.cross(d, u)) < 1e-9 and d @ u > 0
    assert np.allclose(new[2:5], top_a + np.array([[0.25], [0.5], [0.75]]) * (top_b - top_a))
    assert out.kind[j:j + 8].tolist() == [FEED] + [RAPID] * 6 + [FEED]
    assert out.use[j + 7] == USE_PLUNGE and (opi[j:j + 7] == -1).all()
    # the rapids, sampled finely (0.1 mm, 0.25 degree), keep the clearance from every box of the stock
    # (the dexel's rays are 0.5 mm apart: a sample of the boxes' faces 0.5 mm apart, less half a ray)
    surf = np.concatenate([_box_surface(lo, hi) for lo, hi in boxes])
    pts, ax = out.xyz_mm[j:j + 7], out.axis[j:j + 7]
    worst = np.inf
    for k in range(6):
        ang = math.degrees(math.acos(np.clip(ax[k] @ ax[k + 1], -1, 1)))
        n = int(max(np.ceil(np.linalg.norm(pts[k + 1] - pts[k]) / 0.1), np.ceil(ang / 0.25), 1))
        for t in np.linspace(0.0, 1.0, n + 1):
            axis = _slerp1(ax[k], ax[k + 1], t)
            ref = pts[k] + t * (pts[k + 1] - pts[k])
            worst = min(worst, float(_tool_distance(surf, ref - R * axis, axis).min()))
    assert worst >= CLEAR - 0.3
    # the lift follows the stock: over the high ridge the link rises above it
    assert top_a[2] > (ridge + R if ridge > 5 else 0.5 + R)
    # and the guard finds nothing on the new path
    after, _, _ = run_on_stock(out, FRAME, BALL, stock, None, None, rapid_clearance_mm=CLEAR)
    assert not (after.rapid.any() or after.holder.any())


def test_a_link_no_lift_clears_is_kept():
    stock, _ = _stock(200.0)                 # a wall higher than any lift: no link over it
    tp, pi = _path()
    links = StockLinks(FRAME, BALL, stock, None, None, safe_z_mm=SAFE, clearance_mm=CLEAR + 0.5)
    out, opi = links(tp, pi)
    assert links.figures.n_planned == 0 and links.figures.n_kept == 1
    assert sum(links.figures.kept_by.values()) == 1
    assert np.array_equal(out.xyz_mm, tp.xyz_mm) and np.array_equal(opi, pi)


def test_a_link_without_a_rapid_is_not_a_link_in_the_air():
    tp, _ = _path()
    kind = tp.kind.copy()
    kind[13] = FEED                           # the step-over fed on the surface
    use = tp.use.copy()
    use[13] = USE_RETRACT
    tp2 = Toolpath(xyz_mm=tp.xyz_mm, kind=kind, centre_mm=tp.centre_mm, plane=tp.plane, use=use,
                   tip_offset_mm=R, axis=tp.axis)
    a, b = air_links(tp2)
    assert a.size == 0 and b.size == 0


@pytest.mark.parametrize("profile", ["compact_trunnion_bc", "fork_head_ac"])
def test_the_travel_check_takes_the_solution_the_posts_walk_keeps(profile):
    """The links' travel check (branch_angles) against the posts' own walk (rotary_path) on random
    smooth paths of axes away from the pole: the same tilt, the same rotary angle up to whole turns."""
    from planning.post.simultaneous import rotary_path
    from planning.toolpath.fiveaxis.links import branch_angles
    from schemas.machine import load_profile

    p = load_profile(profile)
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(12):
        # a wandering axis, tilt 15..60 degrees off the spindle's pole, azimuth turning
        n = 200
        tilt = np.radians(np.clip(35 + np.cumsum(rng.normal(0, 0.6, n)), 15, 60))
        az = np.radians(rng.uniform(0, 360) + np.cumsum(rng.normal(0, 2.0, n)))
        from planning.orientations.kinematics import tool_axis_from_angles
        pole = tool_axis_from_angles(np.zeros((1, 2)), p)[0]
        u = np.cross(pole, [1.0, 0.0, 0.0] if abs(pole[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(pole, u)
        axes = (np.cos(tilt)[:, None] * pole + np.sin(tilt)[:, None] * (np.cos(az)[:, None] * u + np.sin(az)[:, None] * w))
        walk, feas = rotary_path(axes, p)
        if not feas.all():
            continue
        sign = -1.0 if walk[0, 0] < 0 else 1.0
        ang, valid = branch_angles(axes, p, sign)
        assert valid.all()
        assert np.allclose(ang[:, 0], walk[:, 0], atol=1e-6)
        dc = (ang[:, 1] - walk[:, 1] + 180.0) % 360.0 - 180.0
        assert np.allclose(dc, 0.0, atol=1e-6)
        checked += 1
    assert checked >= 6


class _PoleOnly:
    """The part of an Admissible the links read for the rotary pole (no machine: no travel): the pole
    along the frame's +Z, 3 degrees of clearance."""

    machine = None
    pole_f = np.array([0.0, 0.0, 1.0])
    cos_pole = math.cos(math.radians(3.0))

    def arc_clear_of_pole(self, a0, a1):
        from planning.toolpath.fiveaxis.finishing import Admissible

        return Admissible.arc_clear_of_pole(self, a0, a1)


def test_a_link_whose_axis_would_pass_through_the_pole_turns_round_it():
    """The two passes' axes lean 16.7 degrees either side of the pole: the great circle between them
    runs through it (the rotary axis would swing half a turn at once). The planned link turns the
    axis round the pole, every sampled axis at least the clearance from it, and stays off the stock."""
    stock, _ = _stock(2.0)
    tp, pi = _path()
    links = StockLinks(FRAME, BALL, stock, None, _PoleOnly(), safe_z_mm=SAFE, clearance_mm=CLEAR + 0.5)
    out, _ = links(tp, pi)
    assert links.figures.n_planned == 1 and links.figures.n_round_pole == 1
    ax = out.axis[11:21]
    pole = np.array([0.0, 0.0, 1.0])
    closest = min(math.degrees(math.acos(_slerp1(ax[k], ax[k + 1], t) @ pole))
                  for k in range(9) for t in np.linspace(0, 1, 201))
    assert closest >= 3.0
    # the straight great circle would have passed through it
    assert min(math.degrees(math.acos(min(1.0, _slerp1(ax[0], ax[-1], t) @ pole))) for t in np.linspace(0, 1, 201)) < 0.5
    after, _, _ = run_on_stock(out, FRAME, BALL, stock, None, None, rapid_clearance_mm=CLEAR)
    assert not (after.rapid.any() or after.holder.any())


def test_only_the_links_through_the_safe_height_when_the_guard_relinks():
    """After a cut the guard plans again only the links that reach the safe height (the ones the cut
    made); the figures add up over the calls."""
    stock, _ = _stock(2.0)
    tp, pi = _path()
    links = StockLinks(FRAME, BALL, stock, None, None, safe_z_mm=SAFE, clearance_mm=CLEAR + 0.5)
    once, opi = links(tp, pi)
    assert links.figures.n_planned == 1
    again, api = links(once, opi, only_high=True)          # the planned link stays below the safe height
    assert np.array_equal(again.xyz_mm, once.xyz_mm) and links.figures.n_links == 1
    # a link through the safe height (as cut_moves makes it) is planned again, and counted
    high = tp.xyz_mm.copy()
    high[12:14, 2] = SAFE
    tp2 = Toolpath(xyz_mm=high, kind=tp.kind, centre_mm=tp.centre_mm, plane=tp.plane, use=tp.use,
                   tip_offset_mm=R, axis=tp.axis)
    out, _ = links(tp2, pi, only_high=True)
    assert links.figures.n_links == 2 and links.figures.n_planned == 2
    assert out.xyz_mm[12:19, 2].max() < SAFE


class _PoleAndMachine(_PoleOnly):
    """The pole of the compact trunnion (B C) machine with the area frame the part frame, for the C
    bookkeeping of the turns round the pole."""

    def __init__(self):
        from planning.orientations.kinematics import tool_axis_from_angles
        from planning.simulate.kinematics import MachineModel

        self.machine = MachineModel("compact_trunnion_bc", np.zeros(3))
        self.gauge = 100.0
        self.pole_f = tool_axis_from_angles(np.zeros((1, 2)), self.machine.profile)[0]


def test_turns_round_the_pole_do_not_wind_c_up():
    """Eight links back and forth across the pole (axes 10 degrees either side). Going round it on the
    side each arc's plane gives turns C the same way every time (a full turn per pair); choosing the
    way that brings C nearer 0 keeps it within a turn."""
    adm = _PoleAndMachine()
    p = adm.pole_f
    e = np.cross(p, [1.0, 0.0, 0.0] if abs(p[0]) < 0.9 else [0.0, 1.0, 0.0])
    e /= np.linalg.norm(e)
    t = math.radians(10.0)
    u0, u1 = math.cos(t) * p + math.sin(t) * e, math.cos(t) * p - math.sin(t) * e
    n = 8
    ua = np.array([u0 if i % 2 == 0 else u1 for i in range(n)])
    ub = np.array([u1 if i % 2 == 0 else u0 for i in range(n)])
    stock, _ = _stock(2.0)
    links = StockLinks(FRAME, BALL, stock, None, adm, safe_z_mm=SAFE, clearance_mm=CLEAR + 0.5)
    sign = np.ones(n)

    def c_range(vias):
        dc = links._c_turn(ua, vias, ub, sign)
        assert np.all(np.abs(np.abs(dc) - 180.0) < 20.0)          # half a turn each, round the pole
        c = np.cumsum(dc)
        return float(np.abs(c).max())

    plain, rnd = links._vias(ua, ub)
    assert rnd.all()
    # the walk before: C at each link's start, and the link's turn (back and forth through the pole)
    c0 = np.array([0.0 if i % 2 == 0 else 180.0 for i in range(n)])
    dc_old = np.array([180.0 if i % 2 == 0 else -180.0 for i in range(n)])
    chosen, _ = links._vias(ua, ub, sign, (c0, dc_old))
    assert c_range(plain) >= 3 * 360.0 - 1e-6
    assert c_range(chosen) <= 360.0 + 1e-6


def test_a_link_whose_way_off_the_surface_meets_an_overhang_is_planned_and_counted():
    """Stock overhangs the first pass (a shelf the holder meets on the way up a's axis): that feed is
    the same at every lift and for any link, so the link is still planned over the stock and counted
    for the guard, whose run on the stock finds the holder on exactly that move."""
    lo, hi = (-60.0, -35.0, -35.0), (60.0, 35.0, 80.0)
    stock = TriDexel.box((-45.0, -20.0, -30.0), (45.0, 20.0, 0.5), resolution_mm=0.5, domain_lo=lo, domain_hi=hi)
    stock = stock.union(TriDexel.box((-45.0, -20.0, 24.0), (-30.0, 20.0, 30.0), resolution_mm=0.5,
                                     domain_lo=lo, domain_hi=hi))
    tp, pi = _path()
    links = StockLinks(FRAME, BALL, stock, None, None, safe_z_mm=SAFE, clearance_mm=CLEAR + 0.5)
    out, _ = links(tp, pi)
    assert links.figures.n_planned == 1 and links.figures.n_holder == 1
    off, _, _ = run_on_stock(out, FRAME, BALL, stock, None, None, rapid_clearance_mm=CLEAR)
    assert off.holder[12] and not off.rapid[12:20].any()        # (move 0 starts inside the shelf)
