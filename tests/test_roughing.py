"""Z-level roughing with a flat or bull-nose end mill (planning.toolpath.roughing).

The references here are independent of the module: the distance from a cloud point to the tool
solid is computed in the tool's meridian half-plane as the distance to the union of its convex
pieces (flat-bottom cylinder, corner disc, full cylinder above the corner), brute force over every
densified path point and every cloud point; coverage is checked by sweeping the tool disc over a
fine grid of the stock; the air moves against a height-map simulation of the stock being cut.
The raster kernels behind the speed (section 7) are checked against scipy (distance transform,
labelling, maximum filter, graph shortest paths) and against brute force.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from roughing_clouds import _dome, _grid, _pockets, _post
from scipy import ndimage, sparse
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from planning.errors import ParameterError
from planning.toolpath.moves import RAPID, USE_CUT, USE_PLUNGE, USE_RAPID, USE_RETRACT
from planning.toolpath.roughing import (
    GAP_MM,
    RoughingPath,
    min_tool_clearance,
    roughing_paths,
)
from planning.toolpath.roughing.common import _argsort_stable
from planning.toolpath.roughing.links import _grid_path_cells
from planning.toolpath.roughing.maps import _disc_max, _square_max, _sweep_top
from planning.toolpath.roughing.regions import _comp_at, _march, _region_runs

RT = 3.0          # tool radius used throughout, mm
ALLOW = 0.5       # stock allowance, mm


# ------------------------------------------------------------------------------------------------
# clouds (area frame: tool axis +Z, top of the part at z = 0)
# ------------------------------------------------------------------------------------------------


def _plate():
    x, y = _grid(-20, 20, -15, 15, 0.5)
    return np.stack([x, y, np.zeros_like(x)], 1)


def _step():
    """A plateau at z = 0 for x <= 0, a floor at z = -6 for x > 0, the wall at x = 0 sampled."""
    x, y = _grid(-15, 15, -10, 10, 0.5)
    top = np.stack([x, y, np.where(x <= 0, 0.0, -6.0)], 1)
    wall = np.array([[0.0, yy, zz] for yy in np.arange(-10, 10 + 1e-9, 0.5) for zz in np.arange(-6, 0 + 1e-9, 0.5)])
    return np.concatenate([top, wall])


# ------------------------------------------------------------------------------------------------
# independent references
# ------------------------------------------------------------------------------------------------

def _dense(xyz, step=0.2):
    """Points every ``step`` mm along every straight move (the first point included)."""
    out = [xyz[:1]]
    for a, b in zip(xyz[:-1], xyz[1:]):
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / step)))
        t = np.linspace(0.0, 1.0, n + 1)[1:, None]
        out.append(a + (b - a) * t)
    return np.concatenate(out)


def _tool_distance(tips, q, Rt, rc, cap=2.0):
    """Smallest distance (0 inside) between the tool solid with its tip at any of ``tips`` and any
    point of ``q``, or ``cap`` when that is larger: in the meridian half-plane (rho, w = height
    above the tip) the solid is the union of [0, Rt - rc] x [0, inf), [0, Rt] x [rc, inf) and the
    disc of radius rc about (Rt - rc, rc); the distance to a union is the least distance to its
    pieces. Every pair is evaluated except those whose XY distance alone exceeds Rt + cap (for
    chunks of consecutive tips, the points outside the chunk's box grown by Rt + cap)."""
    Rf = Rt - rc
    best = cap
    for c0 in range(0, tips.shape[0], 500):
        t = tips[c0:c0 + 500]
        lo, hi = t[:, :2].min(axis=0) - Rt - cap, t[:, :2].max(axis=0) + Rt + cap
        qq = q[np.all((q[:, :2] >= lo) & (q[:, :2] <= hi), axis=1)]
        if qq.size == 0:
            continue
        rho = np.hypot(qq[None, :, 0] - t[:, None, 0], qq[None, :, 1] - t[:, None, 1])
        w = qq[None, :, 2] - t[:, None, 2]
        d = np.minimum(np.hypot(np.maximum(rho - Rf, 0), np.maximum(-w, 0)),
                       np.hypot(np.maximum(rho - Rt, 0), np.maximum(rc - w, 0)))
        if rc > 0:
            d = np.minimum(d, np.maximum(np.hypot(rho - Rf, w - rc) - rc, 0))
        best = min(best, float(d.min()))
    return best


def _level_cuts(rp: RoughingPath, z, step=0.1):
    """Points every ``step`` along the feed moves that run at tip height z."""
    tp = rp.toolpath
    xyz = tp.xyz_mm
    segs = [np.linspace(xyz[i - 1], xyz[i], max(2, int(np.ceil(np.linalg.norm(xyz[i] - xyz[i - 1]) / step)) + 1))
            for i in range(1, tp.n_moves)
            if tp.use[i] == USE_CUT and abs(xyz[i, 2] - z) < 1e-9 and abs(xyz[i - 1, 2] - z) < 1e-9]
    return np.concatenate(segs) if segs else np.zeros((0, 3))


# ------------------------------------------------------------------------------------------------
# (1) gouge safety
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("cloud", ["dome", "post", "pocket"])
@pytest.mark.parametrize("rc", [0.0, 1.0, RT])
def test_no_cloud_point_comes_closer_than_the_allowance(cloud, rc):
    pts = {"dome": _dome, "post": _post, "pocket": lambda: _pockets([(0.0, 0.0)], 12.0)}[cloud]()
    rp = roughing_paths(pts, tool_radius_mm=RT, corner_radius_mm=rc, step_down_mm=2.0, stock_allowance_mm=ALLOW)
    tp = rp.toolpath
    assert tp.n_moves > 0 and tp.tip_offset_mm == 0.0
    # every path point (all moves, rapids included, densified) against every cloud point
    bf = _tool_distance(_dense(tp.xyz_mm, 0.2), pts, RT, rc)
    assert bf >= ALLOW - 1e-6
    # the reported clearance is the exact minimum over the moves: never above the sampled one
    assert ALLOW - 1e-6 <= rp.min_clearance_mm <= bf + 1e-9
    # the tool does go down to the allowance somewhere (the floor level sits on the plane)
    assert rp.min_clearance_mm <= ALLOW + 0.05
    assert np.all(tp.xyz_mm[:, 2] >= rp.levels_mm[-1] - 1e-12)


@pytest.mark.parametrize("rc", [0.0, 1.5])
def test_min_tool_clearance_matches_brute_force(rc):
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-10, 10, 1500), rng.uniform(-10, 10, 1500), rng.uniform(-6, 0, 1500)])
    # horizontal and vertical moves, some of them through the cloud
    xyz = [[0.0, 0.0, 5.0]]
    for k in range(24):
        p = np.array(xyz[-1])
        if k % 2:
            xyz.append([p[0], p[1], rng.uniform(-4, 4)])
        else:
            xyz.append([rng.uniform(-12, 12), rng.uniform(-12, 12), p[2]])
    xyz = np.array(xyz)
    got = min_tool_clearance(xyz, pts, tool_radius_mm=RT, corner_radius_mm=rc, reach_mm=100.0)
    bf = _tool_distance(_dense(xyz, 0.02), pts, RT, rc, cap=100.0)
    # the exact value (negative inside the tool) clipped like the reference at 0; sampling error tiny
    assert max(got.min_mm, 0.0) <= bf + 1e-12
    assert max(got.min_mm, 0.0) >= bf - 1e-2
    # the point it names realises it
    q = pts[got.point:got.point + 1]
    a, b = xyz[max(got.move - 1, 0)], xyz[got.move]
    assert _tool_distance(_dense(np.array([a, b]), 0.005), q, RT, rc, cap=100.0) == pytest.approx(
        max(got.min_mm, 0.0), abs=2e-3)
    # a point-free reach gives inf
    far = min_tool_clearance(xyz + [0, 0, 100.0], pts, tool_radius_mm=RT, corner_radius_mm=rc)
    assert far.min_mm == math.inf and far.point == -1


# ------------------------------------------------------------------------------------------------
# (2) coverage: no stock left above the allowance
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("pattern", ["zigzag", "oneway"])
def test_plate_every_stock_cell_is_swept_at_every_level(pattern):
    pts = _plate()
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=5.0, pattern=pattern)
    np.testing.assert_allclose(rp.levels_mm, [3.0, 1.0, 0.5])
    gx, gy = _grid(-25, 25, -20, 20, 0.25)          # the stock box, every 0.25 mm
    stock = np.stack([gx, gy], 1)
    for z in rp.levels_mm:
        cut = _level_cuts(rp, z)
        d, _ = cKDTree(cut[:, :2]).query(stock)
        assert d.max() <= RT, f"stock left at z={z}: {int((d > RT).sum())} grid points not swept"
    # the material-map estimate accounts for the whole box (a lower bound)
    vol = 50 * 40 * (5.0 - 0.5)
    assert 0.97 * vol <= rp.removed_mm3.sum() <= vol + 1e-6


def test_wall_stock_is_removed_up_to_the_allowance():
    pts = _step()
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=2.0)
    h = rp.cell_mm
    gx, gy = _grid(0, 17, -12, 12, 0.1)             # the stock beside the wall (x >= 0)
    stock = np.stack([gx, gy], 1)
    below = rp.levels_mm[rp.levels_mm < -ALLOW]
    assert below.size == 3
    for z in below:
        cut = _level_cuts(rp, z)
        right = cut[cut[:, 0] > 0]
        # beside the wall (|y| <= 10: beyond, the ring around the plateau is cut) never closer to
        # it than R + allowance (less the 0.25 mm half-spacing of the wall's points) ...
        assert right[np.abs(right[:, 1]) <= 10, 0].min() >= RT + ALLOW - 0.01
        # ... and everything farther than the allowance plus the map's margin (3 cells) is swept
        d, _ = cKDTree(right[:, :2]).query(stock)
        left = stock[d > RT]
        assert left.size == 0 or left[:, 0].max() <= ALLOW + 3 * h


# ------------------------------------------------------------------------------------------------
# (3) levels
# ------------------------------------------------------------------------------------------------

def test_levels_step_down_to_the_floor():
    pts = _dome()
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0)
    top = pts[:, 2].max() + 2.0                      # stock top = highest point + margin
    lv = rp.levels_mm
    assert rp.n_levels == lv.size
    assert lv[0] == pytest.approx(top - 2.0)
    assert np.all(np.diff(lv) < 0) and np.all(-np.diff(lv) <= 2.0 + 1e-12)
    assert lv[-1] == pts[:, 2].min() + ALLOW         # default floor: the lowest point + allowance
    # a floor between steps: full steps, then exactly the floor
    rp2 = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=3.0, floor_z_mm=-5.3)
    np.testing.assert_allclose(rp2.levels_mm, [-1.0, -4.0, -5.3])
    assert rp2.levels_mm[-1] == -5.3
    # cuts happen only at the levels, and every level reached in the stock is entered by a plunge,
    # a helix or a ramp: every run of plunge-feed moves ends at a level (all of it with entry='plunge')
    tp = rp.toolpath
    cut_z = np.unique(tp.xyz_mm[tp.use == USE_CUT, 2])
    assert np.all(np.isin(cut_z, lv))
    pl = tp.use == USE_PLUNGE
    assert set(np.unique(tp.xyz_mm[pl & ~np.append(pl[1:], False), 2])) <= set(lv)
    tpp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, entry="plunge").toolpath
    assert set(np.unique(tpp.xyz_mm[tpp.use == USE_PLUNGE, 2])) <= set(lv)


def test_same_input_same_path_progress_and_no_contour():
    pts = _post()
    calls = []
    a = roughing_paths(pts, tool_radius_mm=RT, corner_radius_mm=1.0, progress=lambda i, n: calls.append((i, n)))
    b = roughing_paths(pts, tool_radius_mm=RT, corner_radius_mm=1.0)
    np.testing.assert_array_equal(a.toolpath.xyz_mm, b.toolpath.xyz_mm)
    np.testing.assert_array_equal(a.toolpath.use, b.toolpath.use)
    assert calls == [(i + 1, a.n_levels) for i in range(a.n_levels)]
    # without the contour pass: the lines only (shorter), still clear of the part
    c = roughing_paths(pts, tool_radius_mm=RT, corner_radius_mm=1.0, contour=False)
    assert c.length_mm < a.length_mm and c.min_clearance_mm >= ALLOW - 1e-6


# ------------------------------------------------------------------------------------------------
# (4) zig-zag and one-way
# ------------------------------------------------------------------------------------------------

def test_zigzag_alternates_and_oneway_rapids_back():
    pts = _plate()
    zz = roughing_paths(pts, tool_radius_mm=RT, stock_margin_mm=5.0, pattern="zigzag")
    ow = roughing_paths(pts, tool_radius_mm=RT, stock_margin_mm=5.0, pattern="oneway")

    def line_dx(rp):
        tp = rp.toolpath
        d = np.diff(tp.xyz_mm, axis=0)
        along = (tp.use[1:] == USE_CUT) & (np.abs(d[:, 1]) < 1e-12) & (np.abs(d[:, 2]) < 1e-12) \
            & (np.abs(d[:, 0]) > 20)
        return d[along, 0]

    dz, do = line_dx(zz), line_dx(ow)
    assert (dz > 0).any() and (dz < 0).any()          # zig-zag: both directions
    assert dz.size == do.size and np.all(do > 0)      # one-way: the same lines, all along +X
    # one-way comes back by rapids (-X) after lifting; zig-zag links at the level
    tpo = ow.toolpath
    back = (tpo.kind[1:] == RAPID) & (np.diff(tpo.xyz_mm[:, 0]) < -20)
    assert back.sum() >= do.size - ow.n_levels
    assert ow.air_mm > zz.air_mm + 20 * back.sum()
    assert np.all(zz.level_retracts == 0) and np.all(ow.level_retracts >= do.size / ow.n_levels - 1)
    assert ow.n_retracts > zz.n_retracts


# ------------------------------------------------------------------------------------------------
# (5) linking
# ------------------------------------------------------------------------------------------------

def test_two_pockets_need_a_retract_one_pocket_none():
    two = _pockets([(-10.0, 0.0), (10.0, 0.0)], 20.0)
    one = _pockets([(0.0, 0.0)], 12.0)
    r2 = roughing_paths(two, tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=0.0)
    r1 = roughing_paths(one, tool_radius_mm=RT, step_down_mm=2.0, stock_margin_mm=0.0)
    np.testing.assert_allclose(r2.levels_mm, [-2.0, -4.0, -5.5])
    # every level: the two pockets are separate regions -> one lift between them
    assert np.all(r2.level_retracts == 1)
    assert np.all(r1.level_retracts == 0)
    # the lift between the pockets clears the block's top (z = 0) by the gap
    tp = r2.toolpath
    x0, x1 = tp.xyz_mm[:-1, 0], tp.xyz_mm[1:, 0]
    across = (tp.kind[1:] == RAPID) & (np.sign(x0) != np.sign(x1))
    assert across.any() and np.all(tp.xyz_mm[1:][across, 2] >= GAP_MM - 1e-9)
    for rp, pts in ((r1, one), (r2, two)):
        assert rp.min_clearance_mm >= ALLOW - 1e-6
        assert _tool_distance(_dense(rp.toolpath.xyz_mm, 0.25), pts, RT, 0.0) >= ALLOW - 1e-6


def test_rapids_only_in_free_air_and_plunges_at_feed():
    """Simulate the stock on a 0.25 mm height map: feed moves lower it under the tool disc; a rapid
    must stay above every remaining height under its disc, so moves into stock are feeds."""
    pts = _dome()
    rp = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0)
    tp = rp.toolpath
    lo, hi = rp.stock_box_mm
    gx, gy = _grid(lo[0], hi[0], lo[1], hi[1], 0.25)
    H = np.full(gx.size, hi[2])
    xyz = tp.xyz_mm
    n_plunge_into_stock = 0
    for i in range(1, tp.n_moves):
        a, b = xyz[i - 1], xyz[i]
        d = b[:2] - a[:2]
        L2 = float(d @ d)
        u = np.clip(((gx - a[0]) * d[0] + (gy - a[1]) * d[1]) / L2, 0, 1) if L2 > 0 else np.zeros(gx.size)
        disc = np.hypot(gx - a[0] - u * d[0], gy - a[1] - u * d[1]) <= RT
        zlow = min(a[2], b[2])
        if not disc.any():
            continue
        if tp.use[i] == USE_RAPID:
            assert H[disc].max() < zlow, f"rapid {i} runs into stock"
        else:
            if tp.use[i] == USE_PLUNGE and H[disc].max() > zlow:
                n_plunge_into_stock += 1
            H[disc] = np.minimum(H[disc], zlow)
    assert n_plunge_into_stock >= rp.n_levels                # every level starts in stock
    assert np.all(tp.use[tp.kind == RAPID] == USE_RAPID)
    # the end: out of the cut at feed, then up to the safe height (stock top + 5 mm) by rapid
    assert tp.use[-2] == USE_RETRACT and xyz[-2, 2] == pytest.approx(rp.levels_mm[-1] + GAP_MM)
    assert tp.use[-1] == USE_RAPID and xyz[-1, 2] == pytest.approx(hi[2] + 5.0)
    # every lift starts with a retract at feed straight up, GAP_MM out of the level
    r = np.flatnonzero(tp.use == USE_RETRACT)
    assert r.size == rp.n_retracts
    np.testing.assert_allclose(xyz[r, :2], xyz[r - 1, :2])
    np.testing.assert_allclose(xyz[r, 2] - xyz[r - 1, 2], GAP_MM)


# ------------------------------------------------------------------------------------------------
# (6) bad input
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, words", [
    (dict(tool_radius_mm=0.0), "tool_radius_mm"),
    (dict(tool_radius_mm=-3.0), "tool_radius_mm"),
    (dict(tool_radius_mm=float("nan")), "tool_radius_mm"),
    (dict(tool_radius_mm=3.0, corner_radius_mm=3.5), "corner_radius_mm"),
    (dict(tool_radius_mm=3.0, corner_radius_mm=-0.1), "corner_radius_mm"),
    (dict(tool_radius_mm=3.0, step_down_mm=0.0), "step_down_mm"),
    (dict(tool_radius_mm=3.0, step_down_mm=float("nan")), "step_down_mm"),
    (dict(tool_radius_mm=3.0, step_down_mm=1e-4), "levels"),
    (dict(tool_radius_mm=3.0, stock_allowance_mm=-1.0), "stock_allowance_mm"),
    (dict(tool_radius_mm=3.0, stepover_mm=6.5), "stepover_mm"),
    (dict(tool_radius_mm=3.0, pattern="spiral"), "pattern"),
    (dict(tool_radius_mm=3.0, floor_z_mm=5.0), "floor_z_mm"),
    (dict(tool_radius_mm=3.0, safe_z_mm=1.0), "safe_z_mm"),
    (dict(tool_radius_mm=3.0, cell_mm=2.0), "cell_mm"),
])
def test_bad_parameters_raise_parameter_error(kwargs, words):
    with pytest.raises(ParameterError, match=words):
        roughing_paths(_dome(), **kwargs)


def test_bad_clouds_raise_parameter_error():
    pts = _dome()
    pts[5, 2] = np.nan
    with pytest.raises(ParameterError, match="NaN"):
        roughing_paths(pts, tool_radius_mm=RT)
    with pytest.raises(ParameterError, match=r"\(N,3\)"):
        roughing_paths(np.zeros((0, 3)), tool_radius_mm=RT)
    with pytest.raises(ParameterError, match=r"\(N,3\)"):
        roughing_paths(np.zeros((10, 2)), tool_radius_mm=RT)


# ------------------------------------------------------------------------------------------------
# (7) raster kernels against independent references
# ------------------------------------------------------------------------------------------------

def _blobs(rng, nx, ny, p):
    """A random boolean map of smooth blobs covering about a fraction p of the cells."""
    f = ndimage.gaussian_filter(rng.normal(size=(nx, ny)), float(rng.uniform(0.5, 3.0)))
    return f > np.quantile(f, 1.0 - p)


def test_disc_maximum_gives_the_distance_transform_map():
    """A cell is within ``reach`` of a cell holding a point above t (distance between centres, as
    the distance transform gives it) exactly when its disc maximum is above t."""
    rng = np.random.default_rng(11)
    for _ in range(40):
        nx, ny = (int(v) for v in rng.integers(1, 50, 2))
        v = np.where(rng.random((nx, ny)) < 0.2, rng.normal(size=(nx, ny)), -np.inf)
        h, reach = float(rng.uniform(0.1, 1.0)), float(rng.uniform(0.05, 6.0))
        got = _disc_max(v, h, reach)
        for t in (-1.0, 0.0, 0.8):
            src = v > t
            ref = ndimage.distance_transform_edt(~src) * h < reach if src.any() else np.zeros_like(src)
            np.testing.assert_array_equal(got > t, ref)


def test_stamping_the_cells_a_second_map_raises_gives_the_disc_maximum_of_both():
    """``_stamp_max(_disc_max(raw), src, raw)`` (the live stock's boundary points added to its line
    reading) equals ``_disc_max(max(raw, src))`` bit for bit, stamping only where ``src`` is above ``raw``."""
    from planning.toolpath.roughing.maps import _stamp_max

    rng = np.random.default_rng(17)
    for _ in range(30):
        nx, ny = (int(v) for v in rng.integers(1, 50, 2))
        raw = np.where(rng.random((nx, ny)) < 0.5, rng.normal(size=(nx, ny)), -np.inf)
        src = np.where(rng.random((nx, ny)) < 0.1, rng.normal(size=(nx, ny)) + 0.5, -np.inf)
        h, reach = float(rng.uniform(0.1, 1.0)), float(rng.uniform(0.05, 6.0))
        out = _disc_max(raw, h, reach)
        _stamp_max(out, src, raw, h, reach)
        np.testing.assert_array_equal(out, _disc_max(np.maximum(raw, src), h, reach))


def test_disc_maximum_is_the_same_in_any_number_of_blocks_of_rows():
    """The rows are shared among the threads in blocks (one per thread); each block filters the rows
    within reach of its edges itself: any number of blocks gives the same map, bit for bit."""
    from planning.toolpath.roughing.maps import _disc_max_blocks

    rng = np.random.default_rng(13)
    for _ in range(20):
        nx, ny = (int(v) for v in rng.integers(1, 60, 2))
        v = np.where(rng.random((nx, ny)) < 0.3, rng.normal(size=(nx, ny)), -np.inf)
        h, reach = float(rng.uniform(0.1, 1.0)), float(rng.uniform(0.05, 8.0))
        one = _disc_max_blocks(v, h, reach, 1)
        for nb in (2, 3, 7, nx):
            np.testing.assert_array_equal(_disc_max_blocks(v, h, reach, min(nb, nx)), one)


def test_disc_of_a_mask_is_the_distance_transform_and_the_disc_maximum():
    """``_disc_any(mask)`` (the slab's cells within reach of material) against the distance transform
    and against ``_disc_max(where(mask, 1, -inf)) > 0`` which it replaces, on blobs and scattered cells,
    in any number of blocks: equal, cell for cell."""
    from planning.toolpath.roughing.maps import _disc_any, _disc_any_kernel

    rng = np.random.default_rng(23)
    for it in range(60):
        nx, ny = (int(v) for v in rng.integers(1, 60, 2))
        src = _blobs(rng, nx, ny, 0.1) if it % 2 else rng.random((nx, ny)) < float(rng.uniform(0.0, 0.3))
        h, reach = float(rng.uniform(0.1, 1.0)), float(rng.uniform(0.05, 8.0))
        got = _disc_any(src, h, reach)
        ref = ndimage.distance_transform_edt(~src) * h < reach if src.any() else np.zeros_like(src)
        np.testing.assert_array_equal(got, ref)
        np.testing.assert_array_equal(got, _disc_max(np.where(src, 1.0, -np.inf), h, reach) > 0.0)
        for nb in (1, 2, 5):
            np.testing.assert_array_equal(_disc_any_kernel(src, h, reach, min(nb, ny)), got)


def test_coarse_maximum_is_the_maximum_over_blocks():
    """``_coarse_max`` (the material map's coarse cells from raster cells) against a padded reshape,
    with -inf cells and the last blocks clipped."""
    from planning.toolpath.roughing.maps import _coarse_max

    rng = np.random.default_rng(29)
    for _ in range(40):
        nx, ny = (int(v) for v in rng.integers(1, 40, 2))
        k = int(rng.integers(1, 5))
        v = np.where(rng.random((nx, ny)) < 0.4, rng.normal(size=(nx, ny)), -np.inf)
        ncx, ncy = -(-nx // k), -(-ny // k)
        pad = np.full((ncx * k, ncy * k), -np.inf)
        pad[:nx, :ny] = v
        np.testing.assert_array_equal(_coarse_max(v, k), pad.reshape(ncx, k, ncy, k).max(axis=(1, 3)))


def test_square_maximum_matches_the_maximum_filter():
    rng = np.random.default_rng(12)
    for _ in range(20):
        nx, ny = (int(v) for v in rng.integers(1, 40, 2))
        a = np.where(rng.random((nx, ny)) < 0.7, rng.normal(size=(nx, ny)), -np.inf)
        k = int(rng.integers(0, 9))
        np.testing.assert_array_equal(_square_max(a, k),
                                      ndimage.maximum_filter(a, size=2 * k + 1, mode="constant", cval=-np.inf))


def test_region_runs_components_and_boundary():
    """Region = inbox and not above the threshold; its 8-connected components numbered as
    scipy.ndimage.label numbers them; the marching-squares loops use every boundary edge between a
    region cell and a non-region cell (outside the raster counts as non-region) exactly once, with
    consecutive edges on one 2 x 2 block."""
    rng = np.random.default_rng(13)
    for _ in range(60):
        nx, ny = (int(v) for v in rng.integers(1, 40, 2))
        G = np.where(_blobs(rng, nx, ny, float(rng.uniform(0.1, 0.9))), 1.0, 0.0) + rng.uniform(0, 0.1, (nx, ny))
        inbox = rng.random((nx, ny)) < 0.97
        region = np.empty((nx, ny), dtype=bool)
        runs = _region_runs(G, 0.5, inbox, region)
        np.testing.assert_array_equal(region, inbox & ~(G > 0.5))
        lab, _ = ndimage.label(region, structure=np.ones((3, 3), bool))
        got = np.array([[_comp_at(*runs, i, j) for j in range(ny)] for i in range(nx)]).reshape(nx, ny)
        np.testing.assert_array_equal(got, lab)
        edges, starts = _march(region, *runs[:3])
        NY = ny + 2
        NH = (nx + 1) * NY
        P = np.zeros((nx + 2, ny + 2), bool)
        P[1:-1, 1:-1] = region
        want = {i * NY + j for i in range(nx + 1) for j in range(NY) if P[i, j] != P[i + 1, j]}
        want |= {NH + i * (NY - 1) + j for i in range(nx + 2) for j in range(NY - 1) if P[i, j] != P[i, j + 1]}
        assert sorted(edges.tolist()) == sorted(want)

        def blocks(e, NH=NH, NY=NY):
            if e < NH:
                i, j = divmod(int(e), NY)
                return {(i, j - 1), (i, j)}
            i, j = divmod(int(e) - NH, NY - 1)
            return {(i - 1, j), (i, j)}
        for k in range(starts.size - 1):
            loop = edges[starts[k]:starts[k + 1]].tolist()
            for a, b in zip(loop, loop[1:] + loop[:1]):
                assert blocks(a) & blocks(b)


def test_grid_search_finds_a_short_enough_path_whenever_one_exists():
    """Against Dijkstra (scipy) on the 8-connected graph of the region cells with true step lengths:
    a path within the limit is always found; the one found is valid and at most 1 % longer than the
    shortest (steps counted 5 and 7)."""
    rng = np.random.default_rng(14)
    h = 0.5
    n_found = 0
    for _ in range(60):
        nx, ny = (int(v) for v in rng.integers(5, 30, 2))
        region = ~_blobs(rng, nx, ny, float(rng.uniform(0.0, 0.5)))
        cells = np.flatnonzero(region.ravel())
        if cells.size < 2:
            continue
        src, dst = (int(c) for c in rng.choice(cells, 2, replace=False))
        rows, cols, w = [], [], []
        for c in cells:
            i, j = divmod(int(c), ny)
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    if (di or dj) and 0 <= i + di < nx and 0 <= j + dj < ny and region[i + di, j + dj]:
                        rows.append(c)
                        cols.append((i + di) * ny + j + dj)
                        w.append(h * math.hypot(di, dj))
        graph = sparse.csr_matrix((w, (rows, cols)), shape=(nx * ny, nx * ny))
        best = float(dijkstra(graph, indices=src)[dst])
        limit = float(rng.uniform(0.5, 1.5)) * (best if np.isfinite(best) else h * (nx + ny))
        n = nx * ny
        got = _grid_path_cells(region.ravel(), nx, ny, h, src, dst, limit, 0, nx, 0, ny,
                                     np.empty(n, np.int32), np.empty(n, np.int32), np.zeros(n, np.int32), 1)
        if best <= limit:
            assert got.size > 0
        if got.size:
            n_found += 1
            assert got[0] == src and got[-1] == dst and region.ravel()[got].all()
            gi, gj = np.divmod(got, ny)
            steps = np.maximum(np.abs(np.diff(gi)), np.abs(np.diff(gj)))
            assert np.all(steps == 1)
            length = h * np.hypot(np.diff(gi), np.diff(gj)).sum()
            assert length <= best * math.sqrt(2) / 1.4 + 1e-9
    assert n_found > 20


def test_material_map_is_lowered_only_where_the_flat_bottom_swept_the_whole_cell():
    """Every cell lowered to the level lies (its part in the stock, corners included) within Rf of
    the moves, within Rt when lowered to z + rc; the cells well inside are lowered; the volume
    returned is the drop of the map."""
    rng = np.random.default_rng(15)

    def dist(q, polys):
        """Distance from each point q (m,2) to the nearest move of the polylines."""
        a = np.concatenate([p[:-1] for p in polys])
        d = np.concatenate([np.diff(p, axis=0) for p in polys])
        L2 = np.maximum((d * d).sum(axis=1), 1e-300)
        u = np.clip(((q[:, None, :] - a[None]) * d[None]).sum(axis=2) / L2, 0, 1)
        return np.hypot(*np.moveaxis(a[None] + u[..., None] * d[None] - q[:, None, :], 2, 0)).min(axis=1)

    for _ in range(25):
        H = float(rng.uniform(0.2, 1.0))
        x0, y0 = rng.uniform(-5, 5, 2)
        ncx, ncy = (int(v) for v in rng.integers(20, 45, 2))
        lo = np.array([x0, y0]) + rng.uniform(0, 3 * H, 2)
        hi = np.array([x0 + ncx * H, y0 + ncy * H]) - rng.uniform(0, 3 * H, 2)
        tl = [np.maximum(o + np.arange(m) * H, l) for o, m, l in ((x0, ncx, lo[0]), (y0, ncy, lo[1]))]
        th = [np.minimum(o + (np.arange(m) + 1) * H, u) for o, m, u in ((x0, ncx, hi[0]), (y0, ncy, hi[1]))]
        cx, cy = (0.5 * (a + b) for a, b in zip(tl, th))
        hx, hy = (np.maximum(0.5 * (b - a), 0) for a, b in zip(tl, th))
        full = [(o + np.arange(m) * H >= l) & (o + (np.arange(m) + 1) * H <= u)
                for o, m, l, u in ((x0, ncx, lo[0], hi[0]), (y0, ncy, lo[1], hi[1]))]
        inside = (hx[:, None] > 0) & (hy[None, :] > 0)
        top = np.where(inside, 10.0, -np.inf)
        polys = [np.array([[xa, y], [xb, y]]) for y, xa, xb in
                 ((rng.uniform(lo[1], hi[1]), *np.sort(rng.uniform(lo[0] - 2, hi[0] + 2, 2))) for _ in range(3))]
        for _ in range(2):
            steps = rng.choice([-1, 0, 1], size=(int(rng.integers(2, 30)), 2)) * H * 0.5
            polys.append(np.cumsum(np.vstack([rng.uniform(lo, hi), steps]), axis=0))
        starts = np.concatenate([[0], np.cumsum([p.shape[0] for p in polys])]).astype(np.int64)
        Rf, rc = float(rng.uniform(1, 4)), float(rng.choice([0.0, 0.8]))
        tol = 0.25 * H
        removed = _sweep_top(top, cx, cy, np.hypot(hx[:, None], hy[None, :]), 4 * hx[:, None] * hy[None, :],
                                   full[0], full[1], np.concatenate(polys), starts, x0, y0, H, 0.0, Rf, Rf + rc,
                                   rc, tol)
        i, j = np.nonzero(inside)
        far = np.max([dist(np.column_stack([cx[i] + sx * hx[i], cy[j] + sy * hy[j]]), polys)
                      for sx in (-1, 1) for sy in (-1, 1)], axis=0)
        t = top[i, j]
        assert np.all(far[t == 0.0] <= Rf + 1e-9)
        mid = (t > 0.0) & (t < 10.0)
        assert np.all(t[mid] == rc) and np.all(far[mid] <= Rf + rc + 1e-9)
        centre = dist(np.column_stack([cx[i], cy[j]]), polys)
        assert np.all(t[centre + np.hypot(hx[i], hy[j]) + 2 * tol + 1e-9 < Rf] == 0.0)
        assert removed == pytest.approx(float(((10.0 - t) * 4 * hx[i] * hy[j]).sum()), rel=1e-9, abs=1e-9)


def test_min_tool_clearance_with_crowded_cells_and_equal_heights():
    """Hundreds of points in one cell (sorted by height with a merge sort) and many equal heights
    (stable order): the same minimum as brute force."""
    rng = np.random.default_rng(16)
    column = np.column_stack([rng.uniform(0, 0.3, 400), rng.uniform(0, 0.3, 400), np.round(rng.uniform(-6, 0, 400))])
    spread = np.column_stack([rng.uniform(-10, 10, 800), rng.uniform(-10, 10, 800), np.round(rng.uniform(-6, 0, 800))])
    pts = np.concatenate([column, spread])
    xyz = np.array([[-8.0, 4.0, 1.0], [-8.0, 4.0, -3.0], [6.0, 4.0, -3.0], [6.0, -1.0, -3.0], [0.5, 3.0, -3.0],
                    [0.5, 3.0, 2.0]])
    for rc in (0.0, 1.0):
        got = min_tool_clearance(xyz, pts, tool_radius_mm=RT, corner_radius_mm=rc, reach_mm=50.0)
        bf = _tool_distance(_dense(xyz, 0.01), pts, RT, rc, cap=50.0)
        assert max(got.min_mm, 0.0) <= bf + 1e-12 and max(got.min_mm, 0.0) >= bf - 1e-2


def test_stable_argsort():
    rng = np.random.default_rng(17)
    for n in (0, 1, 15, 16, 17, 100, 1000, 5000):
        keys = np.round(rng.normal(size=n), 1)            # many equal keys
        np.testing.assert_array_equal(_argsort_stable(keys), np.argsort(keys, kind="stable"))


def test_zone_order_is_the_same_with_distances_by_blocks(monkeypatch):
    """Components with more zone variants than ORDER_DENSE_MAX compute the look-ahead distances in
    blocks: the same order of the same moves."""
    pts = _pockets([(-10.0, 0.0), (10.0, 0.0)], 20.0)
    a = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stepover_mm=1.0)
    monkeypatch.setattr("planning.toolpath.roughing.ordering.ORDER_DENSE_MAX", 3)
    b = roughing_paths(pts, tool_radius_mm=RT, step_down_mm=2.0, stepover_mm=1.0)
    np.testing.assert_array_equal(a.toolpath.xyz_mm, b.toolpath.xyz_mm)
