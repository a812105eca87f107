"""Finishing CL points the tool assembly cannot take, cut out of the passes (planning.toolpath.safety;
issue 16 items 3 and 4).

The references are independent of the module: the collisions of the cutter, shank and holder by
brute-force distances to every cloud point, the holder's disc against a stock box in (x, y),
nearest distances by an O(n m) matrix, and the link moves read move by move.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.geometry.collision import EPS_MM, centres_collision_free
from planning.geometry.fixtures import BoxFixture, TableFixture
from planning.geometry.tool import ball_tool
from planning.simulate.dexel import TriDexel
from planning.toolpath.finishing import FinishingPath, finishing_passes
from planning.toolpath.frames import AreaFrame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_ZX,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
    lines,
)
from planning.toolpath.reduce import fit_arcs, reduce_cl
from planning.toolpath.safety import (
    blocked_cl,
    count_retracts,
    cut_moves,
    cutting_positions,
    guard_finishing,
    unmachined_points,
)

Z = np.array([0.0, 0.0, 1.0])


def _small_tool():
    """Ball R 1, flutes to 4 mm, holder face 10 mm above the tip, a 20 mm holder of radius 4:
    segments (0, 3, 1) cutter, (3, 9, 1) shank, (9, 29, 4) holder above the ball centre."""
    return ball_tool(1.0, flute_length_mm=4.0, stickout_mm=10.0, holder=[(4.0, 20.0, None)])


def _turned_frame() -> AreaFrame:
    """A frame turned 30 degrees about +Z and moved: the tests go through frame.to_part."""
    a = math.radians(30.0)
    rot = np.array([[math.cos(a), math.sin(a), 0.0], [-math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return AreaFrame(rotation=rot, origin_mm=np.array([1.0, 2.0, 3.0]))


def _brute_cloud_blocked(obstacles, centres, tool, t=Z) -> np.ndarray:
    """Per centre: an obstacle point strictly inside a cutter / shank / holder cylinder above it."""
    out = np.zeros(centres.shape[0], dtype=bool)
    for i, c in enumerate(centres):
        d = obstacles - c
        a = d @ t
        rho = np.linalg.norm(d - a[:, None] * t[None, :], axis=1)
        for s in tool.segments:
            hi = np.inf if s.hi_mm is None else s.hi_mm
            out[i] |= bool(np.any((a > s.lo_mm) & (a <= hi) & (rho < s.radius_mm - EPS_MM)))
    return out


def _line_path(n=21, dx=0.5, z=0.0, safe=10.0, lead=1.0, y=0.0, x0=0.0, pass_no=0):
    """A finishing-like stretch along X: rapid over the lead-in start at the safe height, rapid down
    to it, plunge onto the first CL point, n - 1 cuts, lead-out up and rapid to the safe height.
    Returns (xyz, use, pass_index, index of the first CL point)."""
    xs = x0 + dx * np.arange(n)
    cl = np.column_stack([xs, np.full(n, y), np.full(n, z)])
    xyz = np.concatenate([[[xs[0], y, safe], [xs[0], y, z + lead]], cl, [[xs[-1], y, z + lead], [xs[-1], y, safe]]])
    use = np.array([USE_RAPID, USE_RAPID, USE_PLUNGE] + [USE_CUT] * (n - 1) + [USE_RETRACT, USE_RAPID], np.int8)
    pi = np.array([-1, -1] + [pass_no] * n + [-1, -1], np.int32)
    return xyz, use, pi, 2


def _check_cut(tp: Toolpath, res, drop: np.ndarray, pass_index=None):
    """Invariants of any cut: no dropped point is left, every move of the input that is left joins
    two consecutive kept input points as it did, new moves are straight and vertical or at the
    safe height, pass_index aligned."""
    out = res.toolpath
    src = res.source
    assert src.shape == (out.n_moves,)
    kept = src >= 0
    assert not np.any(drop[src[kept]])
    np.testing.assert_array_equal(out.xyz_mm[kept], tp.xyz_mm[src[kept]])
    for j in range(1, out.n_moves):
        if out.use[j] == USE_CUT or out.kind[j] in (ARC_CW, ARC_CCW):
            # cutting moves and arcs only where the input had them, between the same two points
            assert src[j - 1] >= 0 and src[j] == src[j - 1] + 1
            assert out.kind[j] == tp.kind[src[j]] and out.use[j] == tp.use[src[j]]
            if out.kind[j] in (ARC_CW, ARC_CCW):
                np.testing.assert_array_equal(out.centre_mm[j], tp.centre_mm[src[j]])
                assert out.plane[j] == tp.plane[src[j]]
    if pass_index is not None:
        expect = np.where(kept, pass_index[np.maximum(src, 0)], -1)
        np.testing.assert_array_equal(res.pass_index, expect)


# ------------------------------------------------------------------------------------------- cut_moves

def test_line_with_a_block_in_the_middle_splits_into_two_linked_pieces():
    xyz, use, pi, c0 = _line_path()
    tp = lines(xyz, use, tip_offset_mm=1.0)
    drop = np.zeros(tp.n_moves, dtype=bool)
    drop[c0 + 8:c0 + 13] = True                       # CL points 8..12 of 0..20
    res = cut_moves(tp, drop, safe_z_mm=10.0, pass_index=pi, approach_mm=1.0)
    _check_cut(tp, res, drop, pi)
    assert res.n_pieces == 2 and res.n_links == 1 and res.n_dropped_points == 5
    assert res.n_cut_points_lost == 5 and res.n_new_retracts == 1
    assert count_retracts(res.toolpath, 10.0) == count_retracts(tp, 10.0) + 1
    out = res.toolpath
    # the first piece with its lead-in as it was, up to CL point 7
    np.testing.assert_array_equal(out.xyz_mm[:c0 + 8], xyz[:c0 + 8])
    np.testing.assert_array_equal(out.use[:c0 + 8], use[:c0 + 8])
    # the link: feed up 1 mm over point 7, rapid to the safe height, rapid over point 13, rapid
    # down to 1 mm above it, plunge onto it
    p7, p13 = xyz[c0 + 7], xyz[c0 + 13]
    link = out.xyz_mm[c0 + 8:c0 + 13]
    expect = np.array([p7 + [0, 0, 1.0], [p7[0], p7[1], 10.0], [p13[0], p13[1], 10.0], p13 + [0, 0, 1.0], p13])
    np.testing.assert_allclose(link, expect)
    np.testing.assert_array_equal(out.use[c0 + 8:c0 + 13], [USE_RETRACT, USE_RAPID, USE_RAPID, USE_RAPID, USE_PLUNGE])
    np.testing.assert_array_equal(out.kind[c0 + 8:c0 + 13], [FEED, RAPID, RAPID, RAPID, FEED])
    np.testing.assert_array_equal(res.pass_index[c0 + 8:c0 + 13], [-1, -1, -1, -1, 0])
    assert res.source[c0 + 12] == c0 + 13
    # the columns of the link stand over points 7 and 13
    np.testing.assert_array_equal(res.anchor[c0 + 8:c0 + 13], [c0 + 7, c0 + 7, -1, c0 + 12, c0 + 12])
    # the second piece: CL points 13..20 cut as before, then the lead-out as it was
    np.testing.assert_array_equal(out.xyz_mm[c0 + 13:], xyz[c0 + 14:])
    np.testing.assert_array_equal(out.use[c0 + 13:], use[c0 + 14:])
    # every feed move at USE_CUT lies between two kept CL points, 0.5 mm apart along X
    cut = np.flatnonzero(out.use == USE_CUT)
    assert cut.size == 7 + 7
    np.testing.assert_allclose(np.diff(out.xyz_mm[:, 0])[cut - 1], 0.5)


def test_nothing_dropped_is_the_input_and_short_pieces_go():
    xyz, use, pi, c0 = _line_path()
    tp = lines(xyz, use, tip_offset_mm=1.0)
    same = cut_moves(tp, np.zeros(tp.n_moves, dtype=bool), safe_z_mm=10.0, pass_index=pi)
    assert same.toolpath is tp and same.n_pieces == 1 and same.n_new_retracts == 0
    # CL point 10 alone between two dropped points has no cutting move: it goes too
    drop = np.zeros(tp.n_moves, dtype=bool)
    drop[[c0 + 9, c0 + 11]] = True
    res = cut_moves(tp, drop, safe_z_mm=10.0, pass_index=pi)
    _check_cut(tp, res, drop, pi)
    assert res.n_pieces == 2 and c0 + 10 not in res.source and res.n_cut_points_lost == 3
    # the lead-in start dropped: the first CL point is approached from above with a plunge
    drop = np.zeros(tp.n_moves, dtype=bool)
    drop[1] = True
    res = cut_moves(tp, drop, safe_z_mm=10.0, pass_index=pi, approach_mm=2.0)
    _check_cut(tp, res, drop, pi)
    np.testing.assert_allclose(res.toolpath.xyz_mm[:3], [[0, 0, 10.0], [0, 0, 2.0], [0, 0, 0.0]])
    np.testing.assert_array_equal(res.toolpath.use[:3], [USE_RAPID, USE_RAPID, USE_PLUNGE])
    assert res.toolpath.kind[0] == RAPID
    # everything dropped: an empty path
    res = cut_moves(tp, np.ones(tp.n_moves, dtype=bool), safe_z_mm=10.0, pass_index=pi)
    assert res.toolpath.n_moves == 0 and res.n_pieces == 0 and res.pass_index.shape == (0,)


def _arc_path():
    """Rapid over the start, plunge, then 8 arcs (G18, ZX plane) over a bump of radius 5 centred at
    (0, 0, -3), 22.5 degrees each, and a retract. Returns the path and the arcs' move indices."""
    c = np.array([0.0, 0.0, -3.0])
    th = np.radians(np.linspace(180.0, 0.0, 9))
    pts = c + 5.0 * np.column_stack([np.cos(th), np.zeros(9), np.sin(th)])
    xyz = np.concatenate([[[pts[0, 0], 0.0, 10.0]], pts, [[pts[-1, 0], 0.0, 10.0]]])
    use = np.array([USE_RAPID, USE_PLUNGE] + [USE_CUT] * 8 + [USE_RETRACT], np.int8)
    tp = lines(xyz, use, tip_offset_mm=1.0)
    kind, cen, plane = tp.kind.copy(), tp.centre_mm.copy(), tp.plane.copy()
    arcs = np.arange(2, 10)
    for j in arcs:
        # the turn from start to end about +Y (the G18 normal; from -X over +Z to +X is right-handed)
        s, e = xyz[j - 1] - c, xyz[j] - c
        kind[j] = ARC_CCW if np.cross(s, e)[1] > 0 else ARC_CW
        cen[j], plane[j] = c, PLANE_ZX
    return Toolpath(xyz_mm=xyz, kind=kind, centre_mm=cen, plane=plane, use=use, tip_offset_mm=1.0), arcs


def test_arcs_touching_a_dropped_point_disappear():
    tp, arcs = _arc_path()
    assert np.all(tp.kind[arcs] == ARC_CCW)
    pi = np.array([-1] + [0] * 9 + [-1], np.int32)
    drop = np.zeros(tp.n_moves, dtype=bool)
    drop[5] = True                                # the end of arc 5, the start of arc 6
    res = cut_moves(tp, drop, safe_z_mm=10.0, pass_index=pi)
    _check_cut(tp, res, drop, pi)
    out = res.toolpath
    arc_src = res.source[np.isin(out.kind, [ARC_CW, ARC_CCW])]
    # arcs 2, 3, 4 (before) and 8, 9 (after the piece start at point 6, now reached by a plunge)
    np.testing.assert_array_equal(arc_src, [2, 3, 4, 7, 8, 9])
    at6 = int(np.flatnonzero(res.source == 6)[0])
    assert out.kind[at6] == FEED and out.use[at6] == USE_PLUNGE and np.all(np.isnan(out.centre_mm[at6]))
    assert out.plane[at6] == 0
    assert res.n_pieces == 2
    # dropping the start of the first arc leaves the arcs after it, the first one gone
    drop = np.zeros(tp.n_moves, dtype=bool)
    drop[1] = True
    res = cut_moves(tp, drop, safe_z_mm=10.0, pass_index=pi)
    _check_cut(tp, res, drop, pi)
    np.testing.assert_array_equal(res.source[np.isin(res.toolpath.kind, [ARC_CW, ARC_CCW])], np.arange(3, 10))


def _plate(half=(10.0, 6.0), sp=0.4, z=0.0):
    x, y = np.meshgrid(np.arange(-half[0], half[0] + 1e-9, sp), np.arange(-half[1], half[1] + 1e-9, sp),
                       indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def test_pass_index_stays_aligned_and_the_reducer_never_joins_across_a_cut():
    R, tol = 1.0, 0.01
    cloud = _plate()
    fin = finishing_passes(cloud, np.ones(cloud.shape[0], dtype=bool), radius_mm=R, scallop_mm=0.05, tol_mm=tol,
                           safe_z_mm=6.0, margin_mm=0.0)
    tp = fin.toolpath
    drop = (np.abs(tp.xyz_mm[:, 0]) < 2.0) & (tp.xyz_mm[:, 2] < 6.0 - 1e-6)      # a band across all passes
    res = cut_moves(tp, drop, safe_z_mm=6.0, pass_index=fin.pass_index)
    _check_cut(tp, res, drop, fin.pass_index)
    assert res.n_pieces >= fin.n_passes            # zig-zag: the band splits every pass and its links
    assert count_retracts(res.toolpath, 6.0) == fin.n_retracts + res.n_new_retracts
    assert count_retracts(tp, 6.0) == fin.n_retracts
    for reduced in (reduce_cl(res.toolpath, cloud, R, tol_mm=tol, pass_index=res.pass_index),
                    fit_arcs(res.toolpath, cloud, R, tol_mm=tol, pass_index=res.pass_index)):
        assert reduced.n_moves < res.toolpath.n_moves
        # only cutting moves were merged, and none of them crosses the band
        assert np.count_nonzero(reduced.use != USE_CUT) == np.count_nonzero(res.toolpath.use != USE_CUT)
        cut = np.flatnonzero(reduced.use == USE_CUT)
        a, b = reduced.xyz_mm[cut - 1], reduced.xyz_mm[cut]
        assert not np.any(np.sign(a[:, 0]) * np.sign(b[:, 0]) < 0)
        assert not np.any(np.abs(b[:, 0]) < 2.0 - 1e-9)
        # and every one stays on one pass (same y) or is a surface link of the cut path, unchanged
        moves = {(tuple(p), tuple(q)) for p, q in zip(res.toolpath.xyz_mm[:-1], res.toolpath.xyz_mm[1:])}
        across = np.flatnonzero(np.abs(a[:, 1] - b[:, 1]) > 1e-9)
        assert all((tuple(a[i]), tuple(b[i])) in moves for i in across)


# ------------------------------------------------------------------------------------------- blocked_cl

def _plate_and_post(r_post=2.0, h_post=40.0):
    plate = _plate(half=(12.0, 12.0), sp=0.5)
    plate = plate[np.hypot(plate[:, 0], plate[:, 1]) > r_post]
    th = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)
    zz = np.arange(0.0, h_post + 1e-9, 0.5)
    T, H = np.meshgrid(th, zz, indexing="ij")
    side = np.column_stack([r_post * np.cos(T.ravel()), r_post * np.sin(T.ravel()), H.ravel()])
    return np.concatenate([plate, side])


def test_a_holder_next_to_a_tall_post_blocks_the_cl_points_near_it():
    tool = _small_tool()
    frame = _turned_frame()
    cloud = _plate_and_post()
    x, y = np.meshgrid(np.arange(-10.0, 10.01, 0.5), np.arange(-10.0, 10.01, 0.5), indexing="ij")
    c_part = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 1.0)])       # the ball on the plate
    c_part = c_part[np.hypot(c_part[:, 0], c_part[:, 1]) >= 3.0]                  # and clear of the post
    b = blocked_cl(frame.to_frame(c_part), frame, Z, tool=tool, obstacles_part=cloud)
    ref = _brute_cloud_blocked(cloud, c_part, tool)
    np.testing.assert_array_equal(b.reasons["cloud"], ref)
    np.testing.assert_array_equal(b.mask, ref)
    assert set(b.reasons) == {"cloud"} and b.counts["cloud"] == int(ref.sum()) and b.counts["stock"] == 0
    # the holder (radius 4) reaches the post's side (radius 2) from less than 6 mm, not beyond
    d = np.hypot(c_part[:, 0], c_part[:, 1])
    assert np.all(b.mask[d < 5.9]) and not np.any(b.mask[d > 6.1])
    assert 0 < b.n_blocked < c_part.shape[0]


def test_travel_rejecting_x_above_10_blocks_exactly_those():
    tool = _small_tool()
    frame = _turned_frame()
    rng = np.random.default_rng(3)
    c_part = rng.uniform([-20, -20, 0], [20, 20, 10], (500, 3))
    seen = []

    def travel_ok(tips):
        seen.append(tips.copy())
        return tips[:, 0] <= 10.0

    b = blocked_cl(frame.to_frame(c_part), frame, None, tool=tool, obstacles_part=None, travel_ok=travel_ok)
    np.testing.assert_allclose(seen[0], c_part - [0, 0, 1.0], atol=1e-9)          # tips, part frame
    np.testing.assert_array_equal(b.reasons["travel"], c_part[:, 0] > 10.0)
    np.testing.assert_array_equal(b.mask, c_part[:, 0] > 10.0)
    assert b.counts == {"cloud": 0, "fixture": 0, "stock": 0, "travel": int((c_part[:, 0] > 10).sum()),
                        "underside": 0}


def test_underside_rule():
    tool = _small_tool()
    frame = _turned_frame()
    z = np.linspace(-1.0, 3.0, 401)
    c_part = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    b = blocked_cl(frame.to_frame(c_part), frame, Z, tool=tool, obstacles_part=np.zeros((0, 3)),
                   floor_z_part_mm=0.5, tol_mm=0.01)
    np.testing.assert_array_equal(b.reasons["underside"], z - 1.0 < 0.5 - 0.01)
    assert b.mask[z < 1.48].all() and not b.mask[z > 1.5].any()


def test_fixture_and_table():
    tool = _small_tool()
    frame = _turned_frame()
    x = np.arange(-10.0, 10.01, 0.25)
    c_part = np.column_stack([x, np.zeros_like(x), np.full(x.size, 1.0)])
    # a clamp 6 mm to 8 mm in x, 15 mm high, 9 mm above the table; the table at z = -0.5
    fx = [BoxFixture(min_mm=(6.0, -3.0, 9.0), max_mm=(8.0, 3.0, 15.0)), TableFixture(z_mm=-0.5)]
    b = blocked_cl(frame.to_frame(c_part), frame, Z, tool=tool, obstacles_part=None, fixtures=fx)
    # the holder (radius 4, z 10 .. 30) meets the clamp when its disc reaches x in [6, 8]; the ball
    # stays 0.5 mm over the table
    near = (x > 6.0 - 4.0 + 1e-6) & (x < 8.0 + 4.0 - 1e-6)
    np.testing.assert_array_equal(b.reasons["fixture"], near)
    lowered = c_part - [0, 0, 0.6]
    assert blocked_cl(frame.to_frame(lowered), frame, Z, tool=tool, obstacles_part=None, fixtures=fx).mask.all()


def test_a_stock_high_above_the_plate_blocks_through_the_holder():
    tool = _small_tool()
    frame = _turned_frame()
    x, y = np.meshgrid(np.arange(-12.0, 12.01, 0.5), np.arange(-12.0, 12.01, 0.5), indexing="ij")
    c_part = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 1.0)])   # tips at z = 0
    # stock 8 .. 12 mm above the tip over a 10 x 10 mm square: the shank (r 1, to z 10) and the
    # holder (r 4, z 10 .. 30) meet it, the cutting part (to z 4) does not reach it
    stock = TriDexel.box((-5.0, -5.0, 8.0), (5.0, 5.0, 12.0), resolution_mm=0.25)
    b = blocked_cl(frame.to_frame(c_part), frame, Z, tool=tool, obstacles_part=None, stock=stock)
    d = np.hypot(np.maximum(np.abs(c_part[:, 0]) - 5.0, 0.0), np.maximum(np.abs(c_part[:, 1]) - 5.0, 0.0))
    blocked = b.reasons["stock"]
    assert np.all(blocked[d < 4.0 - 0.3]) and not np.any(blocked[d > 4.0 + 0.3])
    # a stock around the cutting part only (up to 3.5 mm above the tip) is what the cut removes
    low = TriDexel.box((-5.0, -5.0, -1.0), (5.0, 5.0, 3.5), resolution_mm=0.25)
    assert not blocked_cl(frame.to_frame(c_part), frame, Z, tool=tool, obstacles_part=None,
                          stock=low).mask.any()


# ------------------------------------------------------------------------------------------- unmachined

def test_unmachined_points_equal_the_brute_force_reference():
    rng = np.random.default_rng(7)
    pts = rng.uniform(-5, 5, (400, 3))
    cen = rng.uniform(-5, 5, (60, 3))
    R, reach = 1.5, 0.2
    d = np.linalg.norm(pts[:, None, :] - cen[None, :, :], axis=2)
    np.testing.assert_array_equal(unmachined_points(pts, cen, R, reach), ~np.any(d <= R + reach, axis=1))
    assert unmachined_points(pts, np.zeros((0, 3)), R, reach).all()
    assert unmachined_points(np.zeros((0, 3)), cen, R, reach).shape == (0,)
    # exactly at R + reach counts as finished
    assert not unmachined_points(np.array([[R + reach, 0, 0]]), np.zeros((1, 3)), R, reach)[0]


def test_unmachined_points_grid_equals_the_kd_tree_on_many_points_and_at_the_reach():
    # the parallel kernel (>= 20000 points), points far outside the centres' box, and points on the
    # sphere of radius R + reach about a centre (within rounding, both sides) as a KD-tree decides
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(11)
    R, reach = 3.0, 0.04
    lim = R + reach
    g = np.arange(-30, 30, 0.7)
    X, Y = np.meshgrid(g, g, indexing="ij")
    cen = np.stack([X.ravel(), Y.ravel(), 0.1 * np.sin(X.ravel())], 1)
    u = rng.normal(size=(5000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    on_sphere = cen[rng.integers(0, cen.shape[0], 5000)] + u * lim * (1 + rng.uniform(-1e-12, 1e-12, (5000, 1)))
    pts = np.concatenate([rng.uniform(-40, 40, (30000, 3)) * [1, 1, 0.15], on_sphere, [[500.0, 0, 0], [0, 0, -99.0]]])
    d, _ = cKDTree(cen).query(pts, k=1, distance_upper_bound=lim * (1 + 1e-12) + 1e-12)
    got = unmachined_points(pts, cen, R, reach)
    np.testing.assert_array_equal(got, ~(d <= lim))
    assert got.any() and not got.all()


# ------------------------------------------------------------------------------------------- guard_finishing

def test_guard_shortens_pieces_whose_link_column_meets_an_overhang():
    """A roof of cloud points 33 mm up over x in [4, 6], above the top of the tool (30 mm over the
    tip) standing on the plate: the CL points under it are free, going straight up from them to
    the safe height (36 mm) is not. The travel cuts the line at x = 5; the pieces must end where
    the holder (radius 4) can rise past the roof: x <= 0 and x >= 10."""
    tool = _small_tool()
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    plate = _plate(half=(16.0, 6.0), sp=0.5, z=0.0)
    rx, ry = np.meshgrid(np.arange(4.0, 6.01, 0.25), np.arange(-2.0, 2.01, 0.25), indexing="ij")
    roof = np.column_stack([rx.ravel(), ry.ravel(), np.full(rx.size, 33.0)])
    cloud = np.concatenate([plate, roof])
    xyz, use, pi, _ = _line_path(n=81, dx=0.25, z=1.0, safe=36.0, x0=-5.0)
    tp = lines(xyz, use, tip_offset_mm=1.0)
    fin = FinishingPath(toolpath=tp, n_passes=1, step_over_mm=0.5, min_clearance_mm=1.0, length_mm=20.0,
                        n_retracts=0, pass_index=pi)
    assert not blocked_cl(xyz, frame, Z, tool=tool, obstacles_part=cloud).mask.any()
    out, fig = guard_finishing(fin, frame, Z, tool=tool, obstacles_part=cloud, area_points_frame=plate,
                               safe_z_mm=36.0, travel_ok=lambda tips: np.abs(tips[:, 0] - 5.0) > 0.3,
                               tol_mm=0.01, scallop_mm=0.05)
    j = np.flatnonzero(out.toolpath.use == USE_CUT)
    cut = out.toolpath.xyz_mm[np.unique(np.concatenate([j - 1, j]))]
    assert cut.size and np.all((cut[:, 0] <= 0.0 + 1e-9) | (cut[:, 0] >= 10.0 - 1e-9))
    assert np.any(np.isclose(cut[:, 0], 0.0)) and np.any(np.isclose(cut[:, 0], 10.0))
    assert fig.blocked["travel"] == 3 and fig.n_column_dropped > 0 and fig.n_pieces == 2
    assert out.n_retracts == 1 == count_retracts(out.toolpath, 36.0)
    # every position on every vertical move of the result clears the roof (brute force)
    tp2 = out.toolpath
    for j in range(1, tp2.n_moves):
        a, b = tp2.xyz_mm[j - 1], tp2.xyz_mm[j]
        if np.allclose(a[:2], b[:2]) and a[2] != b[2]:
            zs = np.linspace(min(a[2], b[2]), max(a[2], b[2]), 200)
            col = np.column_stack([np.full(200, a[0]), np.full(200, a[1]), zs])
            assert not _brute_cloud_blocked(cloud, col, tool).any()
    # the scan points under the cut out CL points are unmachined, those far from them are not
    u = fig.unmachined
    assert fig.n_unmachined == int(u.sum()) > 0
    assert np.all((plate[u, 0] > -0.5) & (plate[u, 0] < 10.5)) and np.all(np.abs(plate[u, 1]) < 1.5)
    assert u[(np.abs(plate[:, 1]) < 0.1) & (np.abs(plate[:, 0] - 5.0) < 3.0)].all()


def test_guard_drops_both_ends_of_a_move_blocked_between_its_cl_points():
    """CL points 4 mm apart along X; a pillar at (2, 3.5) 40 mm high: the holder (radius 4) misses
    it from x = 0 and x = 4 (4.03 mm away), not from x = 2 on the move between them."""
    tool = _small_tool()
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    zz = np.arange(0.0, 40.01, 0.5)
    pillar = np.column_stack([np.full(zz.size, 2.0), np.full(zz.size, 3.5), zz])
    xyz, use, pi, _ = _line_path(n=8, dx=4.0, z=1.0, safe=45.0, x0=-12.0)
    tp = lines(xyz, use, tip_offset_mm=1.0)
    fin = FinishingPath(toolpath=tp, n_passes=1, step_over_mm=0.5, min_clearance_mm=1.0, length_mm=28.0,
                        n_retracts=0, pass_index=pi)
    assert not blocked_cl(xyz, frame, Z, tool=tool, obstacles_part=pillar).mask.any()
    out, fig = guard_finishing(fin, frame, Z, tool=tool, obstacles_part=pillar, area_points_frame=np.zeros((0, 3)),
                               safe_z_mm=45.0, sample_mm=0.25)
    assert fig.n_blocked_points == 0 and fig.n_blocked_moves == 1 and fig.n_pieces == 2
    j = np.flatnonzero(out.toolpath.use == USE_CUT)
    ends = np.unique(out.toolpath.xyz_mm[np.concatenate([j - 1, j]), 0])
    np.testing.assert_allclose(ends, [-12.0, -8.0, -4.0, 8.0, 12.0, 16.0])


# ------------------------------------------------------------------------------------------- post_wall

@pytest.fixture(scope="module")
def post_wall_area():
    from planning.inputs.samples import post_wall
    from planning.toolpath.area_paths import area_toolpaths
    from schemas.params import PathsParams, ToolParams

    s = post_wall(density_per_mm2=0.5, seed=2)
    names = s.meta["label_names"]
    labels = np.where(s.meta["labels"] == names.index("plate_top"), 0, -1)
    tool = ToolParams().assembly()            # R 3, holder 25 mm wide from 30 mm above the tip
    pp = PathsParams(finishing={"scallop_mm": 0.1, "tolerance_mm": 0.01, "reduce": False, "arcs": False},
                     roughing={"enabled": False})
    ap = area_toolpaths(s.points, labels, Z[None, :], tool=tool, paths_params=pp)[0]
    return s, labels, tool, ap


def test_post_wall_no_kept_cutting_cl_point_collides(post_wall_area):
    s, labels, tool, ap = post_wall_area
    fin = ap.finishing_info
    tp = fin.toolpath
    fx = [TableFixture(z_mm=0.0)]
    b = blocked_cl(tp.xyz_mm, ap.frame, Z, tool=tool, obstacles_part=s.points, fixtures=fx, floor_z_part_mm=0.0,
                   tol_mm=0.01)
    assert b.counts["cloud"] > 1000                  # the holder over the plate meets the wall
    res = cut_moves(tp, b.mask, safe_z_mm=ap.safe_z_mm, pass_index=fin.pass_index)
    _check_cut(tp, res, b.mask, fin.pass_index)
    out = res.toolpath
    cut_in = np.flatnonzero((tp.use == USE_CUT) & b.mask)
    assert res.n_pieces > 10 and res.n_cut_points_lost >= cut_in.size > 1000
    cut = np.flatnonzero(np.isin(out.kind, [FEED, ARC_CW, ARC_CCW]) & (out.use == USE_CUT))
    ends = np.unique(np.concatenate([cut - 1, cut]))
    ok = centres_collision_free(s.points, ap.frame.to_part(out.xyz_mm[ends]), Z[None, :], tool)[:, 0]
    assert ok.all()
    # the whole guard on the same area: nothing it keeps is blocked, the figures add up
    area_f = ap.frame.to_frame(s.points[labels == 0])
    g, fig = guard_finishing(fin, ap.frame, Z, tool=tool, obstacles_part=s.points, area_points_frame=area_f,
                             safe_z_mm=ap.safe_z_mm, fixtures=fx, floor_z_part_mm=0.0, tol_mm=0.01, scallop_mm=0.1)
    assert not blocked_cl(g.toolpath.xyz_mm, ap.frame, Z, tool=tool, obstacles_part=s.points, fixtures=fx,
                          floor_z_part_mm=0.0, tol_mm=0.01).mask.any()
    assert g.n_retracts == count_retracts(g.toolpath, ap.safe_z_mm) and g.pass_index.shape == (g.toolpath.n_moves,)
    assert fig.n_dropped_points >= b.n_blocked and fig.blocked == b.counts
    # the unmachined scan points: every one lies near an input CL point that is gone (it was
    # finished by that one alone); the plate between the post and the wall is unmachined (the
    # holder, 12.5 mm in radius, meets the wall from x > 0.5; the ball reaches the plate up to
    # x = 10, 3 mm from the wall's face)
    u = fig.unmachined
    assert fig.n_unmachined == int(u.sum()) > 100
    kept = {tuple(p) for p in g.toolpath.xyz_mm}
    gone = np.array([p for p in cutting_positions(tp, 0.75) if tuple(p) not in kept])
    from scipy.spatial import cKDTree

    d, _ = cKDTree(gone).query(area_f[u])
    assert np.all(d <= 3.0 + fig.reach_mm + 0.75)
    x, y = s.points[labels == 0][:, 0], s.points[labels == 0][:, 1]
    gap = (x > 6.0) & (x < 9.5) & (np.abs(y) < 25.0)
    assert gap.sum() > 50 and u[gap].mean() > 0.9


def test_collides_by_runs_equals_collide_move_by_move():
    """dexel.collides (runs of moves tested as one grown sweep first), as the finishing's check of the
    holder in the stock and the guard's of the tool in the fixtures use it, against collide move by
    move: the same answer, on a wavy path of tips over a stock block with a step, on a tilted axis,
    for zero-length moves (positions) and for the moves between them, the holder and the whole tool."""
    from planning.simulate.dexel import collide, collides
    from planning.simulate.motion import ToolShape

    stock = TriDexel.box([-30.0, -30.0, -20.0], [30.0, 30.0, 0.0], resolution_mm=0.5,
                         domain_lo=[-45.0, -45.0, -25.0], domain_hi=[45.0, 45.0, 40.0])
    step = TriDexel.box([-30.0, -30.0, 0.0], [0.0, 30.0, 6.0], resolution_mm=0.5,
                        domain_lo=[-45.0, -45.0, -25.0], domain_hi=[45.0, 45.0, 40.0])
    stock = stock.union(step)
    shape = ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=0.0, flute_length_mm=10.0,
                      pieces=((10.0, 30.0, 3.0), (30.0, math.inf, 12.0)))
    ax = np.array([0.3, -0.2, 0.93])
    ax /= np.linalg.norm(ax)
    s = np.linspace(0.0, 1.0, 3001)
    # a zigzag of passes over the block, dipping below the top and rising well above it
    x = -35.0 + 70.0 * ((s * 12) % 1.0)
    y = -35.0 + 70.0 * s
    z = -12.0 + 20.0 * (0.5 + 0.5 * np.sin(9.0 * s * np.pi)) + 0.7 * np.sin(x / 3.0)
    tips = np.stack([x, y, z], 1)
    axes = np.tile(ax, (len(tips), 1))
    direct = collide(stock, tips, tips, axes, shape, which="holder") > 0
    assert 200 < direct.sum() < len(tips) - 200            # both kinds of position
    np.testing.assert_array_equal(collides(stock, tips, tips, axes, shape, which="holder"), direct)
    # runs of other lengths, shorter than the input and not dividing it
    for block in (1, 5, 64):
        np.testing.assert_array_equal(collides(stock, tips[:2999], tips[:2999], axes[:2999], shape, "holder",
                                               block=block), direct[:2999])
    # the moves between the positions, the whole tool grown by 0.5 mm
    moving = collide(stock, tips[:-1], tips[1:], axes[1:], shape, which="tool", grow_mm=0.5) > 0
    assert 100 < moving.sum() < len(tips) - 100
    np.testing.assert_array_equal(collides(stock, tips[:-1], tips[1:], axes[1:], shape, "tool", grow_mm=0.5), moving)
    # a run whose moves turn the axis is tested move by move
    turned = axes.copy()
    turned[::7] = [0.0, 0.0, 1.0]
    np.testing.assert_array_equal(collides(stock, tips, tips, turned, shape, "holder"),
                                  collide(stock, tips, tips, turned, shape, which="holder") > 0)
