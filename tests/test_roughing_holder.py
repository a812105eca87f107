"""Holder-aware Z-level roughing (planning.toolpath.roughing, ``holder_pieces``).

The holder is given as the simulation gives it (:attr:`planning.simulate.motion.ToolShape.pieces`:
cylinders ``(z0, z1, r)`` above the tip). The references are independent of the module: the cloud
is searched with a k-d tree, and the material is a height map on a fine grid, started from the
stock box (or the given stock's height field) and lowered under every feed move's disc (radius Rt)
to the move's higher end (never more than a flat end mill removes), in the order of the moves.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from roughing_clouds import _grid
from scipy.spatial import cKDTree

from planning.errors import ParameterError
from planning.toolpath.moves import USE_CUT, USE_RAPID
from planning.toolpath.roughing import roughing_paths
from planning.toolpath.roughing.links import GAP_MM, _Level, _link_height, _Scratch
from planning.toolpath.roughing.maps import (
    HOLDER_GAP_MM,
    HOLDER_PIECES,
    _holder_pieces,
    _HolderMap,
    _MaterialMap,
    _raster,
)

ALLOW = 0.5       # stock allowance (the default), mm


# ------------------------------------------------------------------------------------------------
# clouds and stocks (area frame: tool axis +Z)
# ------------------------------------------------------------------------------------------------


def _walls(x0, x1, y0, y1, z0, z1, sp):
    """Points on the four vertical walls of the box [x0, x1] x [y0, y1], from z0 to z1."""
    out = []
    zz = np.arange(z0, z1 + 1e-9, sp)
    for a0, a1, fixed, along_x in ((x0, x1, y0, True), (x0, x1, y1, True), (y0, y1, x0, False), (y0, y1, x1, False)):
        S, Z = np.meshgrid(np.arange(a0, a1 + 1e-9, sp), zz, indexing="ij")
        S, Z = S.ravel(), Z.ravel()
        F = np.full_like(S, fixed)
        out.append(np.stack([S, F, Z] if along_x else [F, S, Z], 1))
    return np.concatenate(out)


def _pocket(half=25.0, ph=8.0, depth=40.0, island=0.0, sp=0.5):
    """A block (top z = 0, [-half, half]^2) with a square pocket [-ph, ph]^2 ``depth`` deep, and in
    it a square island [-island, island]^2 up to z = 0 (none when 0)."""
    x, y = _grid(-half, half, -half, half, sp)
    out = []
    top = ~((np.abs(x) < ph) & (np.abs(y) < ph))
    if island > 0:
        top |= (np.abs(x) <= island) & (np.abs(y) <= island)
    out.append(np.stack([x[top], y[top], np.zeros(top.sum())], 1))
    fx, fy = _grid(-ph, ph, -ph, ph, sp)
    fl = ~((np.abs(fx) <= island) & (np.abs(fy) <= island)) if island > 0 else np.ones(fx.size, bool)
    out.append(np.stack([fx[fl], fy[fl], np.full(fl.sum(), -depth)], 1))
    out.append(_walls(-ph, ph, -ph, ph, -depth, 0.0, sp))
    if island > 0:
        out.append(_walls(-island, island, -island, island, -depth, 0.0, sp))
    return np.concatenate(out)


WALL_X, WALL_TOP = 8.0, 10.0      # the wall case: stock up to 10 mm for x > 8, up to 0 elsewhere


def _wall_top(x, y):
    """The wall case's stock top (-inf beyond the stock's 40 x 40 mm)."""
    inside = (np.abs(x) <= 20.0) & (np.abs(y) <= 20.0)
    return np.where(inside, np.where(x > WALL_X, WALL_TOP, 0.0), -np.inf)


def _wall_case(sp=1.0):
    """A plate (the part, z = -30) under a stock whose top is 0, with a wall up to WALL_TOP for
    x > WALL_X; the window is the half x <= 0 (tool centres within 1 mm of it). Returns (cloud, stock
    points, window, spacing)."""
    x, y = _grid(-20, 20, -20, 20, 0.5)
    cloud = np.stack([x, y, np.full(x.size, -30.0)], 1)
    sx, sy = _grid(-20, 20, -20, 20, sp)
    stock = [np.stack([sx, sy, _wall_top(sx, sy)], 1)]
    fy, fz = _grid(-20, 20, 0.0, WALL_TOP, sp)       # the wall's face
    stock.append(np.stack([np.full(fy.size, WALL_X), fy, fz], 1))
    win = cloud[cloud[:, 0] <= 0.0, :2]
    return cloud, np.concatenate(stock), win, sp


# ------------------------------------------------------------------------------------------------
# the independent reference
# ------------------------------------------------------------------------------------------------

def _holder_violations(rp, cloud, pieces, top0, lo, hi, Rt, g=0.25, stop=False):
    """Where the holder meets the cloud or the material: (feed moves whose end has a piece meeting a
    cloud point (within its radius, above its bottom), moves (feed ends, rapids sampled g apart)
    whose piece meets the reference material or the cloud). The reference: the height field ``top0`` on a grid
    of g mm over lo..hi (XY), lowered under every feed move's disc (Rt) to the move's higher end,
    in order; a move is checked against the material left by the moves before it. ``stop``: return
    at the first violation."""
    tp = rp.toolpath
    xyz, use = tp.xyz_mm, tp.use
    gx = np.arange(lo[0] + 0.5 * g, hi[0], g)
    gy = np.arange(lo[1] + 0.5 * g, hi[1], g)
    GX, GY = np.meshgrid(gx, gy, indexing="ij")
    M = np.asarray(top0(GX, GY), dtype=np.float64).copy()
    tree = cKDTree(cloud[:, :2])
    C = np.full(M.shape, -np.inf)                     # the cloud's highest point per cell (a quick bound)
    ci = np.clip(np.floor((cloud[:, 0] - gx[0] + 0.5 * g) / g).astype(int), 0, gx.size - 1)
    cj = np.clip(np.floor((cloud[:, 1] - gy[0] + 0.5 * g) / g).astype(int), 0, gy.size - 1)
    np.maximum.at(C, (ci, cj), cloud[:, 2])

    def window(x0, x1, y0, y1):
        i0, i1 = np.searchsorted(gx, [x0, x1])
        j0, j1 = np.searchsorted(gy, [y0, y1])
        return slice(max(i0 - 1, 0), i1 + 1), slice(max(j0 - 1, 0), j1 + 1)

    def material_hit(p):
        for z0, _, r in pieces:
            si, sj = window(p[0] - r, p[0] + r, p[1] - r, p[1] + r)
            d = np.hypot(GX[si, sj] - p[0], GY[si, sj] - p[1])
            m = M[si, sj][d < r]
            if m.size and m.max() >= p[2] + z0:
                return True
        return False

    def cloud_hit(p):
        for z0, _, r in pieces:
            si, sj = window(p[0] - r - g, p[0] + r + g, p[1] - r - g, p[1] + r + g)
            dx = np.maximum(np.abs(GX[si, sj] - p[0]) - 0.5 * g, 0.0)
            dy = np.maximum(np.abs(GY[si, sj] - p[1]) - 0.5 * g, 0.0)
            c = C[si, sj][np.hypot(dx, dy) < r]          # the cells that can hold a point within r
            if not (c.size and c.max() >= p[2] + z0):
                continue
            idx = tree.query_ball_point(p[:2], r)
            if idx and cloud[idx, 2].max() >= p[2] + z0:
                return True
        return False

    bad_cloud, bad_mat = [], []
    for i in range(1, tp.n_moves):
        a, b = xyz[i - 1], xyz[i]
        if use[i] == USE_RAPID:
            if np.array_equal(a[:2], b[:2]):          # straight up or down: the lower end is the worst
                samples = [a if a[2] < b[2] else b]
            else:
                n = max(1, int(math.ceil(np.linalg.norm(b - a) / g)))
                samples = [a + (b - a) * k / n for k in range(n + 1)]
            if any(material_hit(p) or cloud_hit(p) for p in samples):
                bad_mat.append(i)
            continue
        if cloud_hit(b):
            bad_cloud.append(i)
        if material_hit(b):
            bad_mat.append(i)
        if stop and (bad_cloud or bad_mat):
            break
        d = b[:2] - a[:2]
        L2 = float(d @ d)
        si, sj = window(min(a[0], b[0]) - Rt, max(a[0], b[0]) + Rt, min(a[1], b[1]) - Rt, max(a[1], b[1]) + Rt)
        X, Y = GX[si, sj], GY[si, sj]
        u = np.clip(((X - a[0]) * d[0] + (Y - a[1]) * d[1]) / L2, 0, 1) if L2 > 0 else 0.0
        disc = np.hypot(X - a[0] - u * d[0], Y - a[1] - u * d[1]) <= Rt
        sub = M[si, sj]
        sub[disc] = np.minimum(sub[disc], max(a[2], b[2]))
    return bad_cloud, bad_mat


def _level_cuts(rp):
    """The ends (k, 3) of the cutting moves at a level (USE_CUT, both ends at one height)."""
    x, use = rp.toolpath.xyz_mm, rp.toolpath.use
    at = np.flatnonzero((use[1:] == USE_CUT) & (x[1:, 2] == x[:-1, 2])) + 1
    return np.concatenate([x[at - 1], x[at]])


def _fingerprint(rp):
    x = rp.toolpath.xyz_mm
    return (rp.toolpath.n_moves, rp.n_levels, rp.n_retracts, rp.length_mm, rp.air_mm, float(x.sum()),
            float(np.abs(x).sum()))


# ------------------------------------------------------------------------------------------------
# the tests
# ------------------------------------------------------------------------------------------------

def test_holder_pieces_are_checked_and_reduced():
    with pytest.raises(ParameterError):
        roughing_paths(_pocket(half=12, ph=4, depth=6), tool_radius_mm=3.0, holder_pieces=[(20.0, 10.0, 8.0)])
    for bad in ([(-1.0, math.inf, 8.0)], [(20.0, math.inf, 0.0)], [(20.0, math.nan, 8.0)], [(20.0, 8.0)], 5):
        with pytest.raises(ParameterError):
            _holder_pieces(bad)
    # a cone sliced into 0.1 mm cylinders and a flange: at most HOLDER_PIECES pieces, each original
    # piece inside one of them as seen from below (bottom no higher, radius no smaller)
    cone = [(30.0 + 0.4 * k, 30.4 + 0.4 * k, 6.0 + 0.1 * (k + 1)) for k in range(60)]
    pieces = cone + [(54.0, 94.0, 25.0), (40.0, 41.0, 3.0)]
    red = _holder_pieces(pieces)
    assert 1 <= red.shape[0] <= HOLDER_PIECES
    for z0, _, r in pieces:
        assert np.any((red[:, 0] <= z0) & (red[:, 1] >= r))
    assert red[0, 0] == 30.0 and red[-1, 1] == 25.0
    assert _holder_pieces([]).shape == (0, 2)


def test_deep_narrow_pocket_stops_where_the_holder_would_enter():
    cloud = _pocket()                                # 16 mm wide, 40 mm deep, rim at z = 0
    z0, r = 20.0, 8.0
    free = roughing_paths(cloud, tool_radius_mm=3.0, cell_mm=0.5)
    held = roughing_paths(cloud, tool_radius_mm=3.0, cell_mm=0.5, holder_pieces=[(z0, math.inf, r)])
    assert free.deepest_cut_mm == pytest.approx(-40.0 + ALLOW) and free.n_holder_blocked_cells == 0
    assert not free.holder and held.holder
    np.testing.assert_array_equal(held.levels_mm, free.levels_mm)
    # no cut with the holder's bottom below the rim (z = 0) within its radius of the rim: here the
    # whole pocket (the tool centre is at most 8 mm from the rim)
    cuts = _level_cuts(held)
    rim_d = 8.0 - np.max(np.abs(cuts[:, :2]), axis=1)
    assert np.all(rim_d < r)
    assert cuts[:, 2].min() >= 0.0 - z0
    # the stock box's top (2 mm above the rim) stays on the block: the holder stops where its bottom
    # comes within HOLDER_GAP_MM (0.5 mm) of it, between -16 and -18
    assert held.deepest_cut_mm == pytest.approx(-16.0)
    assert np.all(held.holder_blocked_cells[held.levels_mm > -17.0] == 0)
    assert np.all(held.holder_blocked_cells[held.levels_mm < -17.0] > 0)
    assert held.n_holder_blocked_cells == held.holder_blocked_cells.sum() > 0
    assert held.min_clearance_mm >= ALLOW - 1e-6
    # where the holder did not matter the path is the same, level by level
    assert np.sum(_level_cuts(free)[:, 2] >= -16.0) == cuts.shape[0]


def test_no_holder_gives_todays_path():
    """``holder_pieces=None`` (and pieces that can never meet anything) give the path of the roughing
    before the holder was modelled (fingerprints recorded from that version)."""
    cloud = _pocket()
    a = roughing_paths(cloud, tool_radius_mm=3.0, cell_mm=0.5)
    b = roughing_paths(cloud, tool_radius_mm=3.0, cell_mm=0.5, holder_pieces=[(500.0, math.inf, 40.0)])
    c = roughing_paths(cloud, tool_radius_mm=3.0, cell_mm=0.5, holder_pieces=())
    for other in (b, c):
        assert other.toolpath.n_moves == a.toolpath.n_moves
        np.testing.assert_array_equal(other.toolpath.xyz_mm, a.toolpath.xyz_mm)
        np.testing.assert_array_equal(other.toolpath.use, a.toolpath.use)
    assert b.holder and not c.holder and b.n_holder_blocked_cells == 0
    fa = _fingerprint(a)
    assert fa[:3] == (4029, 21, 75)
    np.testing.assert_allclose(fa[3:], (7110.568827596173, 5371.95954423178, -88759.0380254712,
                                        155809.55467169924), rtol=1e-9)
    wcloud, stock, win, sp = _wall_case()
    kw = {"tool_radius_mm": 3.0, "cell_mm": 0.375, "stock_points_mm": stock, "stock_spacing_mm": sp,
          "window_xy_mm": win, "window_reach_mm": 1.0}
    d = roughing_paths(wcloud, **kw)
    e = roughing_paths(wcloud, holder_pieces=[(500.0, math.inf, 40.0)], **kw)
    np.testing.assert_array_equal(e.toolpath.xyz_mm, d.toolpath.xyz_mm)
    fd = _fingerprint(d)
    assert fd[:3] == (1950, 15, 15)
    np.testing.assert_allclose(fd[3:], (5372.775856113734, 119.65136583406796, -62843.11887088915,
                                        94266.11243745469), rtol=1e-9)


def test_holder_clear_of_cloud_and_material_brute_force():
    # a pocket around an island: links and lifts between the sides, the holder near walls on both
    cloud = _pocket(half=25.0, ph=20.0, depth=24.0, island=3.0)
    pieces = [(12.0, 40.0, 4.5), (40.0, math.inf, 9.0)]
    kw = {"tool_radius_mm": 3.0, "cell_mm": 0.5}
    held = roughing_paths(cloud, holder_pieces=pieces, **kw)
    lo, hi = held.stock_box_mm

    def box_top(x, y):          # the stock box
        return np.where((x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1]), hi[2], -np.inf)

    bad_cloud, bad_mat = _holder_violations(held, cloud, pieces, box_top, lo - 4.0, hi + 4.0, 3.0)
    assert bad_cloud == [] and bad_mat == []
    assert held.n_holder_blocked_cells > 0 and held.min_clearance_mm >= ALLOW - 1e-6
    assert held.deepest_cut_mm < -12.0          # it still goes on where the holder fits
    # the check has teeth: without the holder model the same holder runs into the material
    free = roughing_paths(cloud, **kw)
    bad_cloud, bad_mat = _holder_violations(free, cloud, pieces, box_top, lo - 4.0, hi + 4.0, 3.0, stop=True)
    assert bad_cloud or bad_mat


def test_tall_wall_beside_the_window_blocks_the_cells_within_the_holder_radius():
    cloud, stock, win, sp = _wall_case()
    z0, r = 15.0, 10.0
    kw = {"tool_radius_mm": 3.0, "cell_mm": 0.375, "stock_points_mm": stock, "stock_spacing_mm": sp,
          "window_xy_mm": win, "window_reach_mm": 1.0}
    free = roughing_paths(cloud, **kw)
    held = roughing_paths(cloud, holder_pieces=[(z0, math.inf, r)], **kw)
    np.testing.assert_array_equal(held.levels_mm, free.levels_mm)
    cuts = _level_cuts(held)
    deep = cuts[:, 2] < WALL_TOP - z0               # the holder's bottom below the wall's top
    assert deep.any() and not deep.all()
    assert cuts[deep, 0].max() <= WALL_X - r        # ... so the holder stays a radius off the wall
    # above that depth the tool still comes up to the window's edge (x = 0)
    assert cuts[~deep, 0].max() > -0.5
    assert cuts[deep, 2].min() < -10.0 and held.deepest_cut_mm < -10.0
    lv = held.levels_mm
    assert np.all(held.holder_blocked_cells[lv > WALL_TOP - z0 + 0.5] == 0)
    assert np.all(held.holder_blocked_cells[lv < WALL_TOP - z0] > 0)
    # without the holder model the tool cuts beside the wall at every level
    fc = _level_cuts(free)
    assert fc[fc[:, 2] < WALL_TOP - z0, 0].max() > -0.5
    lo = np.array([-24.0, -24.0])
    hi = np.array([24.0, 24.0])
    bad_cloud, bad_mat = _holder_violations(held, cloud, [(z0, math.inf, r)], _wall_top, lo, hi, 3.0)
    assert bad_cloud == [] and bad_mat == []
    assert held.min_clearance_mm >= ALLOW - 1e-6


def test_holder_map_blocks_every_cell_whose_holder_meets_something_and_lifts_clear_it():
    """The level's blocked cells against a brute force on a material map with a few towers and a
    random cloud: every cell whose centre has a piece meeting the material (a coarse cell's part
    closer than r, above the piece's bottom - HOLDER_GAP_MM) or the cloud (closer than r + a, above
    the bottom - a) is blocked, and none is blocked without something within r + the raster's
    slack; the lifts between free cells keep every piece above the material and the cloud along
    the way, which the cutter's own lift height does not."""
    rng = np.random.default_rng(7)
    Rt, h, a, z = 2.0, 0.25, 0.5, -20.0
    lo, hi = np.array([0.0, 0.0]), np.array([40.0, 30.0])
    cloud = np.column_stack([rng.uniform(lo, hi, (40, 2)), rng.uniform(-30.0, -10.0, 40)])
    grid = _raster(cloud, lo, hi, Rt, h)
    mat = _MaterialMap(grid, lo, hi, 0.0, Rt)
    inside = np.isfinite(mat.top)
    mat.top[inside] = -40.0
    ti, tj = np.nonzero(inside)
    k = rng.choice(ti.size, 6, replace=False)
    mat.top[ti[k], tj[k]] = rng.uniform(-5.0, 0.0, 6)                    # six towers
    pieces = _holder_pieces([(6.0, 9.0, 3.0), (9.0, math.inf, 5.0)])
    hold = _HolderMap(pieces, grid, mat, a, Rt, 40.0)
    nx, ny = grid.nx, grid.ny
    G = np.full((nx, ny), -np.inf)
    n = hold.level(np.ones((nx, ny), bool), G, 0.0, z, mat, None, True)
    free = hold.limit
    assert n == nx * ny - free.sum() > 0 and free.sum() > 0.2 * nx * ny
    cx = grid.x0 + (np.arange(nx) + 0.5) * h
    cy = grid.y0 + (np.arange(ny) + 0.5) * h
    CX, CY = np.meshgrid(cx, cy, indexing="ij")

    def hits(px, py, tip, r=0.0, gap=HOLDER_GAP_MM, allow=a):
        """Per point: a piece at tip height ``tip`` (grown by r) meets the material (above its
        bottom - gap) or the cloud (within its radius + allow, above its bottom - allow)."""
        out = np.zeros(np.shape(px), bool)
        for z0, rr in pieces:
            mi, mj = np.nonzero(mat.top > tip + z0 - gap)
            dx = np.maximum(np.abs(px[..., None] - mat.cx[mi]) - mat.hx[mi], 0.0)
            dy = np.maximum(np.abs(py[..., None] - mat.cy[mj]) - mat.hy[mj], 0.0)
            out |= np.any(np.hypot(dx, dy) < rr + r, axis=-1)
            c = cloud[cloud[:, 2] > tip + z0 - allow]
            out |= np.any(np.hypot(px[..., None] - c[:, 0], py[..., None] - c[:, 1]) < rr + allow + r, axis=-1)
        return out

    must = hits(CX, CY, z)
    assert must.any() and not np.any(free & must)
    may = hits(CX, CY, z, r=3.2 * h + 2 * mat.H)          # the reach's margins (blocks of up to 2 cells)
    assert np.all(free | may)
    # lifts between free cells: the holder clears everything (no gap, no allowance) along the way
    fi, fj = np.nonzero(free)
    pairs = rng.choice(fi.size, (60, 2))
    t = np.linspace(0.0, 1.0, 400)[:, None]
    low = 0
    for hold_map in (hold.HT, None):
        lv = _Level(free.copy(), grid.x0, grid.y0, h, nx, ny, z, mat.dilated(), mat.H, Rt, _Scratch(nx * ny),
                    hold=hold_map)
        for p, q in pairs:
            A, B = np.array([cx[fi[p]], cy[fj[p]]]), np.array([cx[fi[q]], cy[fj[q]]])
            zl = _link_height(lv, A, B, z, z, math.inf)
            P = A + (B - A) * t
            hit = hits(P[:, 0], P[:, 1], zl, gap=0.0, allow=0.0).any()
            if hold_map is not None:
                assert not hit and zl >= z + GAP_MM
            else:
                low += bool(hit)
    assert low > 0              # the cutter's own lift height would run the holder into a tower
