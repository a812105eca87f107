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
from planning.toolpath.moves import (
    FEED,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
)

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
    again, _ = links(once, opi, only_high=True)          # the planned link stays below the safe height
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


def test_every_arc_round_the_pole_clears_it_with_ends_just_off_it():
    """Axes 0.02-1 degree outside the 3-degree pole clearance at random azimuths, going round the pole
    the way the arc's midpoint gives: every arc between neighbouring axes keeps the clearance from
    the pole (sampled, plain geometry). (Going the long way round in steps of 90 degrees or more, no
    held tilt clears an end that close; such a link fails the pole check and is kept.)"""
    adm = _PoleAndMachine()
    pole = adm.pole_f
    e1 = np.cross(pole, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(pole, e1)
    rng = np.random.default_rng(7)
    n = 400
    t0, t1 = (np.radians(3.0 + rng.uniform(0.02, 1.0, n)) for _ in range(2))
    p0 = rng.uniform(0, 2 * np.pi, n)
    p1 = p0 + rng.uniform(0.5, 2 * np.pi - 0.5, n)

    def at(t, ph):
        return (np.cos(t)[:, None] * pole + np.sin(t)[:, None] * (np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2))

    ua, ub = at(t0, p0), at(t1, p1)
    stock, _ = _stock(2.0)
    links = StockLinks(FRAME, BALL, stock, None, adm, safe_z_mm=SAFE, clearance_mm=CLEAR + 0.5)

    def closest(vias):
        seq = np.concatenate([ua[:, None], vias, ub[:, None]], axis=1)
        out = np.full(n, 180.0)
        for i in range(seq.shape[1] - 1):
            for t in np.linspace(0, 1, 101):
                v = np.array([_slerp1(seq[j, i], seq[j, i + 1], t) for j in range(n)])
                out = np.minimum(out, np.degrees(np.arccos(np.clip(v @ pole, -1, 1))))
        return out

    vias, rnd = links._vias(ua, ub)
    assert rnd.sum() > n // 2                      # the arc between most pairs passes the pole
    assert closest(vias)[rnd].min() >= 3.0 - 1e-6


class _FemurPole(_PoleOnly):
    """The compact trunnion's pole in the area frame of set-up 0 of the 50k-point femur-like 5axis
    plan (the frame's rotation as planned)."""

    def __init__(self):
        from planning.simulate.kinematics import MachineModel

        self.machine = MachineModel("compact_trunnion_bc", np.zeros(3))
        self.gauge = 115.0
        self.pole_f = np.array([0.00607142082599305, 0.939673006640418, 0.3420201433256687])


FEMUR_FRAME = AreaFrame(rotation=np.array([[0.9999791270623429, 0.00220981646036539, 0.00607142082599305],
                                           [-0.006461071090369147, 0.3420130043605396, 0.939673006640418],
                                           [0.0, -0.9396926207859084, 0.3420201433256687]]), origin_mm=np.zeros(3))


def test_the_femur_links_kept_for_the_pole_go_round_it(monkeypatch):
    """The two links of the 50k-point femur-like plan that no level planned (kept for the pole): ends
    3.08 and 3.13 degrees off the pole, C already wound to -2,782 and -4,176 degrees, so each goes
    round the long way (about 300 degrees of azimuth in four steps). With the held tilt
    at the larger end's plus 2 degrees the first or last arc passes within the 3-degree clearance;
    grown, every arc clears it."""
    from planning.toolpath.fiveaxis import links as L

    adm = _FemurPole()
    ua = np.array([[0.014085709261137279, 0.9564202439101848, 0.2916537499045632],
                   [0.057594919342950066, 0.9501598151168129, 0.3063970479672793]])
    ub = np.array([[-0.027987164239363482, 0.954147188785436, 0.29802661084320736],
                   [-0.001045165330596131, 0.9568247539363341, 0.2906635475667795]])
    c_walk = (np.array([-2781.5275706011143, -4175.847559054088]), np.array([-44.93534177611764, -61.76020852383499]))
    stock, _ = _stock(2.0)
    links = StockLinks(FEMUR_FRAME, BALL, stock, None, adm, safe_z_mm=SAFE, clearance_mm=CLEAR + 0.5)

    def closest(vias):
        seq = np.concatenate([ua[:, None], vias, ub[:, None]], axis=1)
        return min(math.degrees(math.acos(min(1.0, _slerp1(seq[j, i], seq[j, i + 1], t) @ adm.pole_f)))
                   for j in range(2) for i in range(seq.shape[1] - 1) for t in np.linspace(0, 1, 201))

    vias, rnd = links._vias(ua, ub, np.ones(2), c_walk)
    assert rnd.all()
    assert abs(links._c_turn(ua, vias, ub, np.ones(2))).min() > 180.0       # the long way round
    assert closest(vias) >= 3.0 - 1e-6
    monkeypatch.setattr(L, "ROUND_TILT_STEPS", 0)
    assert closest(links._vias(ua, ub, np.ones(2), c_walk)[0]) < 3.0


class _Machine:
    """The machine part of an Admissible (travel, no pole): the compact trunnion, the part on a 150 mm
    riser, the make-run tool's gauge length."""

    def __init__(self):
        from planning.simulate.kinematics import MachineModel

        self.machine = MachineModel("compact_trunnion_bc", np.array([0.0, 0.0, 150.0]))
        self.gauge = 115.0
        self.pole_f = None


def test_a_link_the_table_tilted_past_90_degrees_would_take_out_of_travel_goes_higher():
    """A link of the 50k-point femur-like plan: 312 mm along the part, the table tilted 93 degrees at
    one end and 113 at the other. At every lift up to 50 mm the tip's way across (the part's far side
    swung down halfway) takes the spindle below the machine's Z travel; at 100 mm it stays within.
    The planned link, sampled every 0.25 degree and 1 mm with the angles the posts' own walk gives
    (``rotary_path``, not the planner's branch choice), stays within the linear travel; the same link
    at 50 mm does not."""
    from planning.post.simultaneous import rotary_path

    adm = _Machine()
    prof = adm.machine.profile
    ua = np.array([0.347, 0.937, -0.046])
    ub = np.array([-0.627, 0.676, -0.388])
    ua, ub = ua / np.linalg.norm(ua), ub / np.linalg.norm(ub)
    ta, tb = np.array([156.27, 33.44, 13.03]), np.array([-156.44, 41.57, 6.46])
    a, b = ta + R * ua, tb + R * ub
    side_a = np.cross(ua, [0.0, 0.0, 1.0])
    side_a /= np.linalg.norm(side_a)
    side_b = np.cross(ub, [0.0, 0.0, 1.0])
    side_b /= np.linalg.norm(side_b)
    pass_a = a[None] + np.linspace(-4, 0, 5)[:, None] * side_a
    pass_b = b[None] + np.linspace(0, 4, 5)[:, None] * side_b
    xyz = np.concatenate([pass_a, [a + 2 * ua, b + 2 * ub], pass_b])
    kind = np.array([FEED] * 5 + [FEED, RAPID] + [FEED] * 5, np.int8)
    use = np.array([USE_CUT] * 5 + [USE_RETRACT, USE_RAPID, USE_PLUNGE] + [USE_CUT] * 4, np.int8)
    axis = np.concatenate([np.repeat(ua[None], 6, 0), np.repeat(ub[None], 6, 0)])
    P = xyz.shape[0]
    pi = np.array([0] * 5 + [-1, -1] + [1] * 5, np.int32)
    tp = Toolpath(xyz_mm=xyz, kind=kind, centre_mm=np.full((P, 3), np.nan), plane=np.zeros(P, np.int8), use=use,
                  tip_offset_mm=R, axis=axis)
    # an empty stock (a small block far from the link): only the travel decides
    lo, hi = (-250.0, -250.0, -250.0), (250.0, 250.0, 250.0)
    stock = TriDexel.box((-240.0, -240.0, -240.0), (-238.0, -238.0, -238.0), resolution_mm=2.0, domain_lo=lo,
                         domain_hi=hi)
    links = StockLinks(FRAME, BALL, stock, None, adm, safe_z_mm=400.0, clearance_mm=CLEAR + 0.5)

    def lowest_margin(path_xyz, path_axis):
        """The smallest distance (mm) of the controlled point inside the Z travel's floor, and whether
        X and Y stay within theirs, over the path sampled finely, at the posts' walk's angles."""
        refs, axes = [], []
        for k in range(path_xyz.shape[0] - 1):
            ang = math.degrees(math.acos(np.clip(path_axis[k] @ path_axis[k + 1], -1, 1)))
            m = int(max(np.ceil(np.linalg.norm(path_xyz[k + 1] - path_xyz[k]) / 1.0), np.ceil(ang / 0.25), 1))
            for t in np.linspace(0.0, 1.0, m + 1)[1:]:
                refs.append(path_xyz[k] + t * (path_xyz[k + 1] - path_xyz[k]))
                axes.append(_slerp1(path_axis[k], path_axis[k + 1], t))
        refs, axes = np.array(refs), np.array(axes)
        angles, ok = rotary_path(axes, prof)
        mpos = adm.machine.machine_from_tip(refs - R * axes, angles, adm.gauge)
        (x0, x1), (y0, y1), (z0, _) = prof.linear_limits_mm
        inside_xy = bool(np.all((mpos[:, 0] >= x0) & (mpos[:, 0] <= x1) & (mpos[:, 1] >= y0) & (mpos[:, 1] <= y1)))
        return float((mpos[:, 2] - z0).min()), inside_xy and bool(ok.all())

    out, _ = links(tp, pi)
    f = links.figures
    assert f.n_planned == 1 and f.n_kept == 0
    assert "100" in f.by_lift                                 # no lower lift passed
    margin, inside = lowest_margin(out.xyz_mm, out.axis)
    assert inside and margin >= 0.0
    # the same link 50 mm up: out of the Z travel halfway; 80 mm up: within it (BENCHMARKS.md)
    def at_lift(lift):
        h = 1.0 + lift
        pts = np.array([a, a + 1.0 * ua, a + h * ua, b + h * ub, b + 1.0 * ub, b])
        return lowest_margin(pts, np.array([ua, ua, ua, ub, ub, ub]))

    assert at_lift(50.0)[0] < -5.0
    margin80, inside80 = at_lift(80.0)
    assert inside80 and margin80 >= 0.0
