"""Rest roughing from the current stock (planning.toolpath.roughing, ``stock_points_mm``).

The stocks here are height fields (material from the bottom of the box up to ``top(x, y)``), given
to the roughing the way the caller gives a tri-dexel stock: the end points of the material
intervals along rays parallel to X, Y and Z spaced ``s`` apart (:func:`_dexel_points`). The
references are independent of the module: the air cut is measured against the true top function
(distance transform of the material above each level on a fine grid), the rapids against a
height-map simulation of that stock being cut by the feed moves (flat end mill).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from roughing_clouds import _dexel_points, _dome, _grid
from scipy import ndimage

from planning.errors import ParameterError
from planning.toolpath.moves import USE_CUT, USE_RAPID
from planning.toolpath.roughing import GAP_MM, roughing_paths

RT = 3.0          # tool radius, mm
ALLOW = 0.5       # stock allowance, mm
SP = 1.0          # stock sampling spacing, mm


# ------------------------------------------------------------------------------------------------
# clouds and stocks (area frame: tool axis +Z)
# ------------------------------------------------------------------------------------------------


def _plate(hx=12.0, hy=9.0):
    x, y = _grid(-hx, hx, -hy, hy, 0.5)
    return np.stack([x, y, np.zeros_like(x)], 1)


def _in_box(lo, hi, x, y):
    return (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])


# ------------------------------------------------------------------------------------------------
# independent references
# ------------------------------------------------------------------------------------------------

def _level_samples(rp, step=0.2):
    """(points (k,3), lengths (k,)): samples along the feed moves at a level (USE_CUT, both ends at
    one height), each standing for a piece of at most ``step`` mm."""
    tp = rp.toolpath
    x = tp.xyz_mm
    pts, lens = [], []
    for i in range(1, tp.n_moves):
        if tp.use[i] != USE_CUT or x[i, 2] != x[i - 1, 2]:
            continue
        L = float(np.linalg.norm(x[i, :2] - x[i - 1, :2]))
        if L == 0:
            continue
        n = max(1, int(math.ceil(L / step)))
        t = (np.arange(n) + 0.5)[:, None] / n
        pts.append(x[i - 1] + (x[i] - x[i - 1]) * t)
        lens.append(np.full(n, L / n))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0)
    return np.concatenate(pts), np.concatenate(lens)


def _air_length(rp, top, lo, hi, reach, g=0.1):
    """Length of the feed at the levels whose sample has no material of the stock ``top`` above its
    level within ``reach`` (XY), on a grid of g mm: the distance transform of the material above
    each level."""
    p, L = _level_samples(rp)
    gx = np.arange(lo[0] - 2 * RT, hi[0] + 2 * RT, g)
    gy = np.arange(lo[1] - 2 * RT, hi[1] + 2 * RT, g)
    GX, GY = np.meshgrid(gx, gy, indexing="ij")
    T = np.where(_in_box(lo, hi, GX, GY), top(GX, GY), -np.inf)
    air = 0.0
    for z in np.unique(p[:, 2]):
        sel = p[:, 2] == z
        mat = T > z + 1e-9
        if not mat.any():
            air += L[sel].sum()
            continue
        d = ndimage.distance_transform_edt(~mat, sampling=g)
        ix = np.clip(np.round((p[sel, 0] - gx[0]) / g).astype(int), 0, gx.size - 1)
        iy = np.clip(np.round((p[sel, 1] - gy[0]) / g).astype(int), 0, gy.size - 1)
        air += L[sel][d[ix, iy] > reach].sum()
    return air, L.sum()


def _rapids_into_stock(rp, top, lo, hi, g=0.2):
    """Moves that are rapids whose tool (the cylinder of radius RT from the tip upwards) meets the
    stock (height field ``top`` in the box) as the feed moves before it left it: the height map is
    lowered under every feed move's disc to the move's lower end (a flat end mill removes all the
    material above its tip there). Returns the indices of the offending rapids."""
    tp = rp.toolpath
    gx, gy = _grid(lo[0], hi[0], lo[1], hi[1], g)
    H = top(gx, gy).astype(np.float64)
    xyz = tp.xyz_mm
    bad = []
    for i in range(1, tp.n_moves):
        a, b = xyz[i - 1], xyz[i]
        d = b[:2] - a[:2]
        L2 = float(d @ d)
        u = np.clip(((gx - a[0]) * d[0] + (gy - a[1]) * d[1]) / L2, 0, 1) if L2 > 0 else np.zeros(gx.size)
        disc = np.hypot(gx - a[0] - u * d[0], gy - a[1] - u * d[1]) <= RT
        if not disc.any():
            continue
        zlow = min(a[2], b[2])
        if tp.use[i] == USE_RAPID:
            if H[disc].max() >= zlow:
                bad.append(i)
        else:
            H[disc] = np.minimum(H[disc], zlow)
    return bad


# ------------------------------------------------------------------------------------------------
# (1) the full box as the stock: the same roughing
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("entry", ["plunge", "helix"])
def test_full_box_stock_gives_the_box_roughing(entry):
    pts = _dome()
    box = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, entry=entry)
    lo, hi = box.stock_box_mm
    sp = _dexel_points(lambda x, y: np.where(_in_box(lo, hi, x, y), hi[2], -np.inf), lo, hi)
    rest = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, entry=entry, stock_points_mm=sp,
                          stock_spacing_mm=SP)
    assert rest.rest and not box.rest
    np.testing.assert_allclose(rest.levels_mm, box.levels_mm, atol=1e-9)
    assert rest.length_mm == pytest.approx(box.length_mm, rel=0.15 if entry == "helix" else 0.03)
    # the clearing itself (lines and contours at the levels) is the same within a few %
    cut_box, cut_rest = _level_samples(box)[1].sum(), _level_samples(rest)[1].sum()
    assert cut_rest == pytest.approx(cut_box, rel=0.03)
    assert rest.min_clearance_mm >= ALLOW - 1e-6
    assert rest.air_cut_mm <= 0.01 * cut_rest
    assert rest.stock_before_mm3 >= box.stock_before_mm3 > rest.stock_after_mm3 > 0
    np.testing.assert_allclose(rest.stock_box_mm, box.stock_box_mm)


# ------------------------------------------------------------------------------------------------
# (2) a stock cut down to a plane
# ------------------------------------------------------------------------------------------------

def test_stock_cut_down_to_a_plane_has_no_level_above_it():
    pts = _plate()
    kw = dict(tool_radius_mm=RT, step_down_mm=1.0, stock_margin_mm=10.0)
    box = roughing_paths(pts, **kw)
    lo, hi = box.stock_box_mm
    assert box.n_levels == 10
    for c in (1.2, 3.4):
        sp = _dexel_points(lambda x, y, c=c: np.where(_in_box(lo, hi, x, y), c, -np.inf), lo, hi)
        rp = roughing_paths(pts, stock_points_mm=sp, stock_spacing_mm=SP, **kw)
        assert rp.levels_mm.max() <= c + 1e-9 and rp.levels_mm[-1] == pytest.approx(ALLOW)
        assert rp.n_levels == (1 if c < 2 else 3)
        assert rp.length_mm < (0.15 if c < 2 else 0.4) * box.length_mm
        assert rp.min_clearance_mm >= ALLOW - 1e-6
        # the volume above the floor: an upper bound (the top map's fringe of the spacing + a cell included)
        vol = (c - ALLOW) * (hi[0] - lo[0]) * (hi[1] - lo[1])
        assert vol <= rp.stock_before_mm3 <= 1.4 * vol and rp.stock_after_mm3 < 0.1 * vol
    # nothing left above the floor: no level and no move
    sp = _dexel_points(lambda x, y: np.where(_in_box(lo, hi, x, y), 0.3, -np.inf), lo, hi)
    rp = roughing_paths(pts, stock_points_mm=sp, stock_spacing_mm=SP, **kw)
    assert rp.n_levels == 0 and rp.toolpath.n_moves == 0 and rp.length_mm == 0.0
    # no stock at all
    rp = roughing_paths(pts, stock_points_mm=np.zeros((0, 3)), stock_spacing_mm=SP, **kw)
    assert rp.n_levels == 0 and rp.toolpath.n_moves == 0


# ------------------------------------------------------------------------------------------------
# (3) a pocket already cut: no air cutting inside it
# ------------------------------------------------------------------------------------------------

def test_pocket_already_cut_is_not_cut_again():
    pts = _plate(15.0, 12.0)
    kw = dict(tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=8.0)
    box = roughing_paths(pts, **kw)
    lo, hi = box.stock_box_mm

    def top(x, y):
        return np.where(_in_box(lo, hi, x, y), np.where(np.hypot(x - 3.0, y) < 14.0, 1.0, hi[2]), -np.inf)

    rp = roughing_paths(pts, stock_points_mm=_dexel_points(top, lo, hi), stock_spacing_mm=SP, **kw)
    h = rp.cell_mm
    np.testing.assert_allclose(rp.levels_mm, box.levels_mm)
    # a feed sample at a level is in air when no stock above the level lies within the tool radius;
    # allowed: the map's slack (one cell, the top's disc of the spacing + one cell) and short side entries
    air, total = _air_length(rp, top, lo, hi, RT + 2 * h + SP + 0.15)
    air_box, total_box = _air_length(box, top, lo, hi, RT + 2 * h + SP + 0.15)
    assert air <= 0.02 * total
    assert air_box > 0.08 * total_box                # the box roughing cuts the pocket's air
    assert total < total_box - 0.5 * air_box
    assert rp.air_cut_mm <= 0.02 * total
    assert rp.min_clearance_mm >= ALLOW - 1e-6
    assert not _rapids_into_stock(rp, top, lo, hi)


# ------------------------------------------------------------------------------------------------
# (4) brute force on a small case: bounded air, rapids clear of the stock model
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("entry", ["helix", "plunge"])
def test_small_case_air_is_bounded_and_rapids_clear_the_stock(entry):
    pts = _plate(10.0, 8.0)
    kw = dict(tool_radius_mm=RT, step_down_mm=1.5, stock_margin_mm=6.0, entry=entry)
    lo = np.array([-16.0, -14.0, 0.0])
    hi = np.array([16.0, 14.0, 6.0])

    def top(x, y):
        slope = np.clip(1.0 + 0.3 * (x + 16.0), 1.0, 6.0)                     # a ramp up along x
        step = np.where(y > 5.0, np.minimum(slope, 2.5), slope)               # a shelf cut along +y
        hole = np.where(np.hypot(x - 6.0, y + 5.0) < 4.0, 0.8, step)          # a hole cut to z = 0.8
        return np.where(_in_box(lo, hi, x, y), hole, -np.inf)

    rp = roughing_paths(pts, stock_points_mm=_dexel_points(top, lo, hi), stock_spacing_mm=SP, **kw)
    h = rp.cell_mm
    assert rp.rest and rp.n_levels >= 3 and rp.levels_mm[0] <= 6.0
    air, total = _air_length(rp, top, lo, hi, RT + 2 * h + SP + 0.15)
    assert total > 0 and air <= 0.03 * total
    assert not _rapids_into_stock(rp, top, lo, hi)
    assert rp.min_clearance_mm >= ALLOW - 1e-6
    # every move stays at or below the safe height, and the stock is clear of it by the gap
    assert rp.toolpath.xyz_mm[:, 2].max() <= rp.safe_z_mm + 1e-9
    assert rp.safe_z_mm >= 6.0 + GAP_MM - 1e-9


def test_stock_above_the_safe_height_raises_it():
    pts = _plate()
    lo = np.array([-14.0, -11.0, 0.0])
    hi = np.array([14.0, 11.0, 20.0])
    sp = _dexel_points(lambda x, y: np.where(_in_box(lo, hi, x, y), 20.0, -np.inf), lo, hi)
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=4.0, safe_z_mm=7.0, stock_points_mm=sp,
                        stock_spacing_mm=SP)
    assert rp.levels_mm[0] == pytest.approx(16.0)          # the levels start at the stock's top
    assert rp.safe_z_mm >= 20.0 + GAP_MM - 1e-9
    assert rp.toolpath.xyz_mm[:, 2].max() <= rp.safe_z_mm + 1e-9
    assert not _rapids_into_stock(rp, lambda x, y: np.where(_in_box(lo, hi, x, y), 20.0, -np.inf), lo, hi)


@pytest.mark.parametrize("kwargs, words", [
    (dict(stock_points_mm=np.zeros((4, 2)), stock_spacing_mm=1.0), "stock_points_mm"),
    (dict(stock_points_mm=np.full((4, 3), np.nan), stock_spacing_mm=1.0), "stock_points_mm"),
    (dict(stock_points_mm=np.zeros((4, 3))), "stock_spacing_mm"),
    (dict(stock_points_mm=np.zeros((4, 3)), stock_spacing_mm=0.0), "stock_spacing_mm"),
    (dict(stock_spacing_mm=1.0), "stock_spacing_mm"),
])
def test_bad_stock_arguments_raise(kwargs, words):
    with pytest.raises(ParameterError, match=words):
        roughing_paths(_plate(), tool_radius_mm=RT, **kwargs)


def test_a_retract_beside_a_wall_steps_off_it_instead_of_feeding_up_it():
    """With a rapid clearance, a retract feeds up until the grown tool clears the material beside it; by
    a wall that is the wall's whole height. Where a point ``w.gap`` off at the level (in the region)
    clears lower, the retract steps off to it at 45 degrees and the rapid rises from there; where none
    does (or there is no level to ask), it feeds straight up as before."""
    from types import SimpleNamespace

    from planning.toolpath.moves import USE_RAPID, USE_RETRACT
    from planning.toolpath.roughing.links import _retract, _Writer

    def writer(wall_x):
        w = _Writer()
        w.gap = 0.65
        # the column at x is clear from 10 mm up within 0.5 mm of the wall (x >= wall_x - 0.5), else at once
        w.column_clear = lambda x, y, z, top: 10.0 if x >= wall_x - 0.5 else z
        w.column_clear_many = lambda pts, top: np.where(pts[:, 0] >= wall_x - 0.5, 10.0, pts[:, 2])
        return w

    lv = SimpleNamespace(z=0.0, visible=lambda a, b: True)
    w = writer(0.0)
    end = _retract(w, (0.0, 0.0, 0.0), 20.0, lv)
    pts, codes = np.concatenate(w.pts), np.repeat(w.codes, w.counts)
    assert codes[0] == USE_RETRACT and codes[-1] == USE_RAPID
    assert pts[0, 2] == pytest.approx(0.65) and np.hypot(*pts[0, :2]) == pytest.approx(0.65)
    assert pts[0, 0] < -0.5 + 1e-9                    # off the wall, where the column clears at once
    assert np.allclose(end, pts[0, :2]) and pts[-1, 2] == 20.0
    # outside the region (none of it off the wall) the step is taken where the grown tool clears at once
    w = writer(0.0)
    end = _retract(w, (0.0, 0.0, 0.0), 20.0, SimpleNamespace(z=0.0, visible=lambda a, b: False,
                                                             reachable=lambda a, b: True))
    pts = np.concatenate(w.pts)
    assert pts[0, 2] == pytest.approx(0.65) and pts[0, 0] < -0.5 + 1e-9 and np.allclose(end, pts[0, :2])
    # no level to ask, or nowhere off the wall in the region nor within the machine's travel: straight up
    # the wall at feed, as before
    for lv2 in (None, SimpleNamespace(z=0.0, visible=lambda a, b: False, reachable=lambda a, b: False)):
        w = writer(0.0)
        end = _retract(w, (0.0, 0.0, 0.0), 20.0, lv2)
        pts, codes = np.concatenate(w.pts), np.repeat(w.codes, w.counts)
        assert np.allclose(pts[:, :2], 0.0) and codes[0] == USE_RETRACT and pts[0, 2] == 10.0
        assert np.allclose(end, 0.0)


def test_a_lift_beside_a_wall_comes_down_off_it_only_where_that_column_is_air():
    """A lift's rapid down at q stops where the grown tool clears the material beside (by a wall: high)
    and the rest is fed straight down. Where a point ``w.gap`` off at the level has its column clear
    down to ``w.gap`` above the level, the lift comes down there by rapid and feeds in to q at 45
    degrees; where that column is clear only higher up (material under it), it does not (a feed
    straight down there could plunge into it) and the lift is as before."""
    from types import SimpleNamespace

    from planning.toolpath.moves import USE_PLUNGE, USE_RAPID
    from planning.toolpath.roughing.links import _lift, _Writer

    def run(off_clear_from):
        w = _Writer()
        w.gap = 0.65
        w.column_clear = lambda x, y, z, top: max(z, 8.0) if x >= -0.5 else z          # the wall at x >= -0.5
        w.column_clear_many = lambda pts, top: np.where(pts[:, 0] >= -0.5, 8.0, np.maximum(pts[:, 2], off_clear_from))
        w.rapid_clear = lambda a, b, z, top: z
        lv = SimpleNamespace(z=0.0, visible=lambda a, b: True, corridor_top=lambda a, b: 10.0, top_at=lambda q: 0.0)
        _lift(w, lv, (-20.0, 0.0, 0.0), np.array([0.0, 0.0]), 0.0, 30.0, top_q=0.0)
        return np.concatenate(w.pts), np.repeat(w.codes, w.counts)

    pts, codes = run(0.0)
    assert np.allclose(pts[-1], [0.0, 0.0, 0.0]) and codes[-1] == USE_PLUNGE
    # the last feed comes in from w.gap off and w.gap above at 45 degrees, after a rapid down to there
    assert pts[-2, 0] < -0.5 and pts[-2, 2] == pytest.approx(0.65) and codes[-2] == USE_RAPID
    assert np.hypot(*pts[-2, :2]) == pytest.approx(0.65)
    pts, codes = run(3.0)                 # off the wall the column is air only from 3 mm up: as before
    assert np.allclose(pts[-1], [0.0, 0.0, 0.0]) and np.allclose(pts[-2], [0.0, 0.0, 8.0])
    assert codes[-1] == USE_PLUNGE and codes[-2] == USE_RAPID
