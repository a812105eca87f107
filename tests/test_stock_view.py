"""Issue 30 item 1: the stock read along a set-up's axis (planning.simulate.heightfield), the stock view an
operation plans and cuts on (planning.toolpath.stock_view), and the roughing planned on it: regions where
the material is, entries that never plunge straight into material, retracts and rapids that keep the rapid
clearance, tool tips within the machine's travel. Every check runs the roughing's moves on the tri-dexel
stock (the simulation's own kernels), not on the roughing's maps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planning.simulate.dexel import TriDexel, cut, simulate_moves
from planning.simulate.heightfield import stock_tops_in_frame
from planning.simulate.motion import FEED, RAPID, ToolShape
from planning.toolpath.frames import AreaFrame, area_frame
from planning.toolpath.guard import COLUMN_TOL_MM, part_moves
from planning.toolpath.roughing import roughing_paths
from planning.toolpath.stock_view import StockView

RES = 1.0
SHAPE = ToolShape(number=2, kind="flat", radius_mm=4.0, corner_radius_mm=0.0, flute_length_mm=25.0,
                  pieces=((25.0, math.inf, 4.0),))


def _box(lo, hi, res=RES, pad=12.0):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return TriDexel.box(lo, hi, resolution_mm=res, domain_lo=lo - pad, domain_hi=hi + pad)


def _tilted_frame(points, axis=(0.47, 0.814, 0.342)):
    a = np.asarray(axis, float)
    return area_frame(a / np.linalg.norm(a), points)


def _slab(frame, lo, hi, X, Y):
    """The analytic [t_in, t_out] of the frame's Z lines through (X, Y) in the box [lo, hi] (slab method)."""
    P = frame.origin_mm + X[..., None] * frame.rotation[0] + Y[..., None] * frame.rotation[1]
    d = frame.rotation[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - P) / d, (hi - P) / d
    return np.minimum(ta, tb).max(-1), np.maximum(ta, tb).min(-1)


def test_tops_of_a_tilted_box_match_the_analytic_top_within_half_a_ray_spacing_times_the_slope():
    lo, hi = np.array([-30.0, -20.0, -5.0]), np.array([30.0, 20.0, 25.0])
    stock = _box(lo, hi)
    rng = np.random.default_rng(0)
    frame = _tilted_frame(rng.uniform(lo, hi, (500, 3)))
    h, x0, y0, n = 0.5, -70.0, -70.0, 280
    tops = stock_tops_in_frame(stock, frame.rotation, frame.origin_mm, x0, y0, h, n, n, np.inf, -200.0)
    X, Y = np.meshgrid(x0 + (np.arange(n) + 0.5) * h, y0 + (np.arange(n) + 0.5) * h, indexing="ij")
    t_in, t_out = _slab(frame, lo, hi, X, Y)
    inside = t_out > t_in + 1e-9
    both = inside & np.isfinite(tops)
    # every line through the box reads it, but for a sliver along its silhouette (half a ray spacing)
    assert both.sum() > 0.98 * inside.sum()
    assert not np.any(np.isfinite(tops) & ~inside & (np.abs(t_out - t_in) > 2 * RES))
    # on the faces the reading is the top as the simulation's rays see it: within r / 2 across them,
    # i.e. r / 2 * tan(face slope to the line); this frame's steepest face leans 70 degrees
    d = frame.rotation[2]
    bound = 0.5 * RES * max(math.sqrt(1 - c * c) / c for c in np.abs(d) if c > 0.1) + 1e-6
    err = tops[both] - t_out[both]
    assert np.abs(err).max() <= bound
    assert np.median(np.abs(err)) < 0.1
    # the walk between two heights: only material between them, the highest
    mid = float(np.median(t_out[inside]))
    part = stock_tops_in_frame(stock, frame.rotation, frame.origin_mm, x0, y0, h, n, n, mid, mid - 3.0)
    has = np.isfinite(part)
    assert np.all(part[has] <= mid + 1e-9) and np.all(part[has] >= mid - 3.0 - 1e-9)
    expect = inside & (t_out > mid - 3.0 + bound) & (t_in < mid - bound)
    assert has[expect].mean() > 0.99


def test_the_view_cuts_a_copy_as_the_simulation_does_and_clears_a_column_as_the_guard_does():
    lo, hi = np.array([-20.0, -20.0, -10.0]), np.array([20.0, 20.0, 10.0])
    stock = _box(lo, hi)
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    view = StockView(stock, frame, SHAPE)
    # a slot 12 mm wide (two passes 4 mm apart), 5 mm deep, then a rapid up out of it
    a = np.array([[-25.0, -2.0, 5.0], [0.0, -2.0, 5.0], [0.0, 2.0, 5.0], [-25.0, 2.0, 5.0]])
    b = np.array([[0.0, -2.0, 5.0], [0.0, 2.0, 5.0], [-25.0, 2.0, 5.0], [-25.0, 2.0, 30.0]])
    kinds = np.array([FEED, FEED, FEED, RAPID])
    removed = view.cut(a, b, rapid=kinds == RAPID)
    ref = stock.copy()
    ref_removed = cut(ref, a, b, np.tile([0.0, 0.0, 1.0], (4, 1)), SHAPE, kinds)
    np.testing.assert_allclose(removed, ref_removed)
    assert removed[3] == 0.0 and removed[0] > 0.0
    assert stock.volume_mm3() == pytest.approx(_box(lo, hi).volume_mm3())          # the carried stock untouched
    assert view.stock.volume_mm3() == pytest.approx(ref.volume_mm3())
    # a rapid up from the slot's floor: on its axis the tool grown by 0.5 mm clears the walls (6 mm away)
    # once its grown tip clears the floor; 1.6 mm off the axis it brushes the wall until above the block
    z_axis = view.column_clear_z(np.array([[-10.0, 0.0, 5.0]]), 40.0, 0.5)[0]
    z_wall = view.column_clear_z(np.array([[-10.0, 1.6, 5.0]]), 40.0, 0.5)[0]
    assert 5.5 - 1e-9 <= z_axis <= 5.5 + 0.5 * RES + 1e-9
    # the wall's edge is seen on the stock's rays (RES apart, the top one half a spacing under the
    # block's top): the swept test may clear it up to half a spacing lower than the exact 10.5
    assert 10.0 + 0.5 - 0.5 * RES - 1e-9 <= z_wall <= 10.0 + 0.5 + 0.5 * RES + 1e-9
    for x, y, z in ((-10.0, 0.0, z_axis), (-10.0, 1.6, z_wall)):
        up = simulate_moves(view.stock.copy(), np.array([[x, y, z]]), np.array([[x, y, 40.0]]),
                            np.array([[0.0, 0.0, 1.0]]), SHAPE, np.array([RAPID]), rapid_clearance_mm=0.5)
        assert up.rapid_depth_mm[0] == 0.0
        low = simulate_moves(view.stock.copy(), np.array([[x, y, z - 0.6]]), np.array([[x, y, 40.0]]),
                             np.array([[0.0, 0.0, 1.0]]), SHAPE, np.array([RAPID]), rapid_clearance_mm=0.5)
        assert low.rapid_depth_mm[0] > 0.0


def test_a_column_is_clear_exactly_where_the_height_search_finds_it_clear():
    """StockView.column_is_clear (one swept test per model) against column_clear_z (the height found):
    on a tilted frame over a cut box with an obstacle beside it, for columns from inside the material,
    beside the walls and in the air, clear is the same as a clear height at the start."""
    lo, hi = np.array([-20.0, -20.0, -10.0]), np.array([20.0, 20.0, 10.0])
    stock = _box(lo, hi)
    rng = np.random.default_rng(3)
    frame = _tilted_frame(rng.uniform(lo, hi, (200, 3)), axis=(0.2, 0.3, 0.93))
    obstacles = _box([25.0, -5.0, -10.0], [30.0, 5.0, 15.0])
    view = StockView(stock, frame, SHAPE, obstacles=obstacles)
    a = frame.to_frame(np.array([[-25.0, -2.0, 5.0], [0.0, -2.0, 5.0], [0.0, 2.0, 5.0]]))
    view.cut(a[:-1], a[1:], rapid=np.zeros(2, bool))
    pts = frame.to_frame(rng.uniform(lo - 8.0, hi + 8.0, (300, 3)))
    top = float(frame.to_frame(np.array([lo, hi]))[:, 2].max()) + 40.0
    heights = view.column_clear_z(pts, top, 0.5)
    clear = np.array([view.column_is_clear(p, top, 0.5) for p in pts])
    assert 30 < clear.sum() < 270                     # both answers occur
    # a column the swept test finds blocked has its clear height above the start; one it finds clear
    # has it at the start, or within the height search's tolerance above it (the tool's hull)
    assert np.all(heights[~clear] > pts[~clear, 2])
    assert np.all(heights[clear] <= pts[clear, 2] + COLUMN_TOL_MM + 1e-6)
    assert np.mean(heights[clear] <= pts[clear, 2] + 1e-9) > 0.95


def _dome(n=5000, radius=22.0, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u[:, 2] = np.abs(u[:, 2])
    u /= np.linalg.norm(u, axis=1)[:, None]
    return radius * u


def _run(tp, frame, stock, clearance):
    pm = part_moves(tp, frame)
    run = simulate_moves(stock.copy(), pm.start, pm.end, np.broadcast_to(pm.axis, pm.start.shape), SHAPE, pm.kind,
                         rapid_clearance_mm=clearance)
    d = pm.end - pm.start
    L = np.linalg.norm(d, axis=1)
    feed = pm.kind == FEED
    down = feed & (L > 0) & (-(d @ pm.axis) > math.cos(math.radians(10.0)) * L)
    return pm, run, L, feed, down


def _dome_case():
    """The tilted dome's inputs: (cloud in the frame, the block's stock, the frame, the block's lower corner,
    the roughing's keyword arguments on the block's boundary points)."""
    cloud = _dome()
    lo, hi = np.array([-26.0, -26.0, -0.5]), np.array([26.0, 26.0, 24.0])
    stock = _box(lo, hi)
    frame = _tilted_frame(cloud)
    cloud_f = frame.to_frame(cloud)
    kw = {"tool_radius_mm": SHAPE.radius_mm, "step_down_mm": 3.0, "stock_allowance_mm": 0.5,
          "floor_z_mm": float(cloud_f[:, 2].min()) + 0.5, "stock_points_mm": frame.to_frame(stock.boundary_points()),
          "stock_spacing_mm": RES, "holder_pieces": SHAPE.pieces, "safe_z_mm": float(cloud_f[:, 2].max()) + 30.0}
    return cloud_f, stock, frame, lo, kw


@pytest.fixture(scope="module")
def tilted_dome():
    """A dome on a block, roughed from a set-up tilted 70 degrees (the half sphere's), from the points of
    the block's boundary only and from a stock view of it."""
    cloud_f, stock, frame, lo, kw = _dome_case()
    points = roughing_paths(cloud_f, **kw)
    viewed = roughing_paths(cloud_f, stock_view=StockView(stock, frame, SHAPE), rapid_clearance_mm=0.5, **kw)
    return frame, stock, lo, points, viewed


def test_roughing_on_the_stock_view_cuts_less_air_never_plunges_and_keeps_its_rapids_clear(tilted_dome):
    frame, stock, lo, points, viewed = tilted_dome
    res = {}
    for name, rr in (("points", points), ("view", viewed)):
        pm, run, L, feed, down = _run(rr.toolpath, frame, stock, 0.5)
        air = feed & (run.removed_mm3 < 1e-6)
        below = feed & (np.maximum(pm.start[:, 2], pm.end[:, 2]) < lo[2]) & air
        res[name] = {"air": L[air].sum() / L[feed].sum(), "removed": run.removed_mm3.sum(),
                         "plunges": int((down & (run.removed_mm3 > 1e-6)).sum()),
                         "rapids": int((run.rapid_depth_mm > 0).sum()), "holder": int((run.holder_depth_mm > 0).sum()),
                         "below": L[below].sum()}
    v, p = res["view"], res["points"]
    assert v["plunges"] == 0 and viewed.n_plunges_into_material == 0
    assert v["rapids"] == 0 and v["holder"] == 0
    # far less feed in the air, and under the block (a tilted cutter still runs along the block's lower
    # edge with its tip under it, and its retracts feed up there until the grown tool clears the edge)
    assert v["below"] < 0.25 * p["below"]
    assert v["air"] < 0.75 * p["air"]
    # the same material comes off (within the few pieces left for want of an entry)
    assert v["removed"] > 0.97 * p["removed"]
    # what no entry fits and is left is a sliver of the roughing, and is counted
    assert viewed.left_length_mm < 0.05 * viewed.length_mm
    assert (viewed.n_pieces_left == 0) == (viewed.left_length_mm == 0.0)
    # the view was cut with the moves as they were planned: what it removed is what the moves remove
    assert viewed.toolpath.n_moves > 100


def test_entries_feed_down_through_air_the_stock_shows_and_never_into_it(tilted_dome, monkeypatch):
    """Where the stock itself shows air, a helix or ramp is begun by a straight feed down to just above
    the material, and a piece whose start the maps put under material but the stock shows in air is
    entered straight down; no straight feed down removes anything, and the entries feed less in air
    than the same roughing with the feed down turned off (its gap set above every start)."""
    import planning.toolpath.roughing.entries as E
    from planning.toolpath.moves import USE_PLUNGE

    frame, stock, lo, points, viewed = tilted_dome

    def entry_air(rr):
        pm, run, L, feed, down = _run(rr.toolpath, frame, stock, 0.5)
        entry = feed & (rr.toolpath.use[pm.source] == USE_PLUNGE)
        return L[entry & (run.removed_mm3 < 1e-6)].sum(), run, down, L, feed

    air, run, down, L, feed = entry_air(viewed)
    assert viewed.n_fed_down > 0
    # a straight feed down is in air, to the stock's own rays: the helices' tops, the side entries and
    # the lifts alike
    assert down.sum() > 10
    assert np.all(run.removed_mm3[down] < 1e-6)
    monkeypatch.setattr(E, "ENTRY_FEED_GAP_MM", 1e3)
    cloud_f, _, _, _, kw = _dome_case()
    slow = roughing_paths(cloud_f, stock_view=StockView(stock, frame, SHAPE), rapid_clearance_mm=0.5, **kw)
    assert slow.n_fed_down == 0
    air_slow, run_slow, *_ = entry_air(slow)
    # every helix or ramp fed down saves at least (gap - ENTRY_FEED_GAP_MM) / tan(entry angle) of
    # descent less the straight feed: most of the entries' air
    assert air < air_slow - viewed.n_fed_down * 2.0
    assert run.removed_mm3.sum() == pytest.approx(run_slow.removed_mm3.sum(), rel=0.01)


def test_a_helix_or_ramp_begins_where_the_column_above_its_way_is_air(tilted_dome, monkeypatch):
    """A helix or ramp whose start the material put high (a sliver at the top of its way) begins at the
    last vertex of its way over which the grown tool is clear of the stock up to the safe height: the
    entries feed less through the air than with every descent begun at its first vertex, they remove
    the same material, and no straight feed down removes anything."""
    import planning.toolpath.roughing.entries as E
    from planning.toolpath.moves import USE_PLUNGE

    frame, stock, lo, points, viewed = tilted_dome

    def entry_air(rr):
        pm, run, L, feed, down = _run(rr.toolpath, frame, stock, 0.5)
        entry = feed & (rr.toolpath.use[pm.source] == USE_PLUNGE)
        return L[entry & (run.removed_mm3 < 1e-6)].sum(), run, down

    air, run, down = entry_air(viewed)
    assert viewed.n_started_late > 0
    assert np.all(run.removed_mm3[down] < 1e-6)
    monkeypatch.setattr(E._Entries, "_late_start", lambda self, w, xyz, zs, safe: (xyz, zs))
    cloud_f, _, _, _, kw = _dome_case()
    first = roughing_paths(cloud_f, stock_view=StockView(stock, frame, SHAPE), rapid_clearance_mm=0.5, **kw)
    assert first.n_started_late == 0
    air_first, run_first, _ = entry_air(first)
    assert air < air_first - 1.0
    assert run.removed_mm3.sum() == pytest.approx(run_first.removed_mm3.sum(), rel=0.01)


def test_travel_cells_are_the_machines_own_travel_test():
    """The affine extension of the set-up's kinematics over the raster agrees with
    SetupMachine.travel_ok at the cells' centres (and the lift above them)."""
    from planning.orientations.kinematics import load_profile
    from planning.simulate.kinematics import MachineModel
    from planning.toolpath.area_paths import _travel_cells
    from planning.toolpath.guard import SetupMachine

    profile = load_profile("compact_trunnion_ac")
    model = MachineModel(profile, placement_mm=np.array([0.0, 0.0, 0.0]))
    cloud = _dome()
    frame = _tilted_frame(cloud)
    machine = SetupMachine(model=model, angles_deg=np.array([70.0, 120.0]))
    gauge = 80.0
    ok = _travel_cells(machine, frame, gauge, lift_z=60.0)
    x0, y0, h, nx, ny = -400.0, -300.0, 4.0, 200, 150
    for z in (-40.0, 0.0, 30.0):
        cells = ok(x0, y0, h, nx, ny, z)
        X, Y = np.meshgrid(x0 + (np.arange(nx) + 0.5) * h, y0 + (np.arange(ny) + 0.5) * h, indexing="ij")
        pts = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], axis=1)
        lift = pts.copy()
        lift[:, 2] = max(z, 60.0)
        ref = machine.travel_ok(frame.to_part(pts), gauge) & machine.travel_ok(frame.to_part(lift), gauge)
        assert np.array_equal(cells.ravel(), ref)
        assert 0 < cells.sum() < cells.size
    # a raster inside the travel (the shortcut of the four corners): all cells, as the machine says
    from scipy.ndimage import binary_erosion

    deep = binary_erosion(ok(x0, y0, h, nx, ny, 0.0), np.ones((11, 11), dtype=bool))
    assert deep.any()
    i, j = np.argwhere(deep)[0]
    # between the centres of the cells 4 to either side (the travel is convex in the cell centre)
    sx, sy = x0 + (i - 3.5) * h, y0 + (j - 3.5) * h
    inner = ok(sx, sy, h / 4, 32, 32, 0.0)
    X, Y = np.meshgrid(sx + (np.arange(32) + 0.5) * h / 4, sy + (np.arange(32) + 0.5) * h / 4, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    lift = pts.copy()
    lift[:, 2] = 60.0
    ref = machine.travel_ok(frame.to_part(pts), gauge) & machine.travel_ok(frame.to_part(lift), gauge)
    assert ref.all() and inner.all()


def test_level_air_trims_a_line_to_where_its_disc_meets_material_not_yet_swept():
    """planning.toolpath.roughing.air against a brute force over the cells."""
    from planning.toolpath.roughing.air import _LevelAir

    h, nx, ny, Rt = 0.5, 120, 80, 3.0
    has = np.zeros((nx, ny), dtype=bool)
    has[40:70, 30:50] = True                               # material: x in [20, 35), y in [15, 25) mm
    air = _LevelAir(has, 0.0, 0.0, h, Rt, Rt)

    def brute(j, swept):
        ii, jj = np.nonzero(has & ~swept)
        ok = [i for i in range(nx) if np.any((ii - i) ** 2 + (jj - j) ** 2 <= (Rt / h) ** 2)]
        return (ok[0], ok[-1]) if ok else None

    def line(j):
        y = (j + 0.5) * h
        return np.array([[0.0, y], [nx * h, y]]), np.array([0 * ny + j, (nx - 1) * ny + j])

    for j in (20, 24, 25, 40, 55, 56, 60):
        xy, cells = line(j)
        got = air.trim(xy, cells, ny)
        ref = brute(j, air.swept)
        if ref is None:
            assert got is None, j
        else:
            assert got is not None, j
            txy, tcells = got
            assert (tcells[0] // ny, tcells[-1] // ny) == ref
            assert txy[0, 0] == pytest.approx(ref[0] * h) and txy[1, 0] == pytest.approx((ref[1] + 1) * h)
    # a cut along y = 20 mm with a flat bottom of 3 mm sweeps the band y in (17, 23) (cells wholly inside):
    # a line at y = 21 mm then meets only what is left beyond the band, within its disc
    air.mark([np.array([[0.0, 20.0], [60.0, 20.0]])])
    assert air.swept[50, 40] and not air.swept[50, 30]
    for j in (36, 42, 44, 48):
        xy, cells = line(j)
        got = air.trim(xy, cells, ny)
        ref = brute(j, air.swept)
        assert (got is None) == (ref is None)
        if ref is not None:
            assert (got[1][0] // ny, got[1][-1] // ny) == ref
    # a reversed line keeps its direction
    xy, cells = line(40)
    got = air.trim(xy[::-1].copy(), cells[::-1].copy(), ny)
    ref = brute(40, air.swept)
    assert got is not None and got[0][0, 0] > got[0][1, 0]             # still from +x to -x
    assert (got[1][-1] // ny, got[1][0] // ny) == ref                # the same span as the forward line


def test_roughing_keeps_the_tool_off_the_obstacles_it_is_given_and_its_rapids_clear():
    """A clamp beside the block, reaching above the block's floor: the roughing on a stock view that holds
    the obstacles keeps the whole tool off it (the guard's own collision test), without them it
    runs into it."""
    from planning.simulate.dexel import collide

    cloud = _dome()
    lo, hi = np.array([-26.0, -26.0, -0.5]), np.array([26.0, 26.0, 24.0])
    stock = _box(lo, hi)
    clamp = TriDexel.box(np.array([26.5, -8.0, -0.5]), np.array([34.0, 8.0, 6.0]), resolution_mm=RES,
                         domain_lo=lo - 12.0, domain_hi=hi + 12.0)
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.array([0.0, 0.0, 0.0]))
    kw = dict(tool_radius_mm=SHAPE.radius_mm, step_down_mm=3.0, stock_allowance_mm=0.5, floor_z_mm=0.0,
              stock_points_mm=stock.boundary_points(), stock_spacing_mm=RES, holder_pieces=SHAPE.pieces,
              safe_z_mm=40.0, rapid_clearance_mm=0.5)
    with_obs = roughing_paths(cloud, stock_view=StockView(stock, frame, SHAPE, obstacles=clamp), **kw)
    without = roughing_paths(cloud, stock_view=StockView(stock, frame, SHAPE), **kw)
    hits = {}
    for name, rr in (("with", with_obs), ("without", without)):
        pm, run, L, feed, down = _run(rr.toolpath, frame, stock, 0.5)
        ax = np.broadcast_to(pm.axis, pm.start.shape)
        hits[name] = int((collide(clamp, pm.start, pm.end, ax, SHAPE, which="tool") > 0).sum())
        if name == "with":
            assert int((run.rapid_depth_mm > 0).sum()) == 0 and not np.any(down & (run.removed_mm3 > 1e-6))
            # the rapids keep the clearance from the clamp too
            rap = pm.kind == RAPID
            assert int((collide(clamp, pm.start[rap], pm.end[rap], ax[rap], SHAPE, which="tool", grow_mm=0.5) > 0).sum()) == 0
    assert hits["with"] == 0 and hits["without"] > 0


def _channel(r_in=10.0, r_out=21.0, depth=10.0, half=27.0, step=0.5):
    """A ring channel, ``depth`` deep, between a post (radius ``r_in``) and a block (hole ``r_out``): the
    cloud on the post's wall and top, the channel's floor, the hole's wall and the block's top."""
    pts = []
    for r in (r_in, r_out):
        n = int(2 * math.pi * r / step)
        t = np.linspace(0, 2 * math.pi, n, endpoint=False)
        for z in np.arange(0.0, depth + 1e-9, step):
            pts.append(np.column_stack([r * np.cos(t), r * np.sin(t), np.full(n, z)]))
    g = np.arange(-half, half + 1e-9, step)
    X, Y = np.meshgrid(g, g, indexing="ij")
    R = np.hypot(X, Y)
    top = (R <= r_in) | (R >= r_out)
    pts.append(np.column_stack([X[top], Y[top], np.full(top.sum(), depth)]))
    floor = (R > r_in) & (R < r_out)
    pts.append(np.column_stack([X[floor], Y[floor], np.zeros(floor.sum())]))
    return np.concatenate(pts)


def test_a_narrow_ring_channel_no_helix_fits_is_ramped_along_its_own_path_not_plunged():
    """The tool centre has a ring 2 mm wide: no helix fits, its clearing lines are short chords; the
    roughing on the stock view enters by ramps along the pieces' own paths, at the entry angle, and
    leaves next to nothing uncut."""
    rr, frame, stock, shape = _channel_roughing()
    assert rr.n_plunges_into_material == 0 and rr.n_helix == 0 and rr.n_ramps > 0
    pm = part_moves(rr.toolpath, frame)
    run = simulate_moves(stock.copy(), pm.start, pm.end, np.broadcast_to(pm.axis, pm.start.shape), shape, pm.kind,
                         rapid_clearance_mm=0.5)
    d = pm.end - pm.start
    L = np.linalg.norm(d, axis=1)
    feed = pm.kind == FEED
    straight_down = feed & (L > 0) & (-d[:, 2] > math.cos(math.radians(10.0)) * L)
    assert not np.any(straight_down & (run.removed_mm3 > 1e-6))
    assert int((run.rapid_depth_mm > 0).sum()) == 0
    # every descent that cuts is a ramp at the entry angle (3 degrees) or a feed at a level
    cutting_down = feed & (d[:, 2] < -1e-9) & (run.removed_mm3 > 1e-6)
    slope = np.degrees(np.arctan2(-d[cutting_down, 2], np.hypot(d[cutting_down, 0], d[cutting_down, 1])))
    np.testing.assert_allclose(slope, 3.0, atol=1e-6)
    # the channel is roughed to its floor: the pieces left are slivers
    assert rr.deepest_cut_mm == pytest.approx(0.5)
    assert rr.left_length_mm < 0.05 * rr.length_mm


def test_level_air_trims_a_contour_chain_and_opens_a_loop_at_its_longest_useless_run():
    from planning.toolpath.roughing.air import _LevelAir

    h, nx, ny, Rt = 0.5, 100, 100, 2.0
    has = np.zeros((nx, ny), dtype=bool)
    has[60:70, 40:60] = True                               # material beside the loop's right side only
    air = _LevelAir(has, 0.0, 0.0, h, Rt, Rt)
    # a square loop of side 20 mm about (25, 25) mm, vertices every 0.5 mm (last = first)
    t = np.arange(0.0, 80.0, 0.5)
    side = np.minimum(t // 20, 3)
    u = t - side * 20
    x = np.select([side == 0, side == 1, side == 2, side == 3], [15 + u, 35 + 0 * u, 35 - u, 15 + 0 * u])
    y = np.select([side == 0, side == 1, side == 2, side == 3], [15 + 0 * u, 15 + u, 35 + 0 * u, 35 - u])
    xy = np.column_stack([x, y])
    xy = np.vstack([xy, xy[:1]])
    cells = (np.floor(xy[:, 0] / h).astype(np.int64) * ny + np.floor(xy[:, 1] / h).astype(np.int64))
    got = air.trim_chain(xy, cells, ny, loop=True)
    assert got is not None
    txy, tcells = got
    # brute force: the vertices whose disc (Rt) meets material
    ii, jj = np.nonzero(has)
    useful = np.array([np.any((ii - c // ny) ** 2 + (jj - c % ny) ** 2 <= (Rt / h) ** 2) for c in cells[:-1]])
    assert useful.any() and not useful.all()
    kept = {tuple(p) for p in np.round(txy, 6)}
    for p, ok in zip(np.round(xy[:-1], 6), useful):
        if ok:
            assert tuple(p) in kept                  # every vertex that cuts is kept
    assert len(txy) == useful.sum() + 2              # one useful run here: it and the segment either side
    assert not np.allclose(txy[0], txy[-1])          # an open chain now
    # an open chain keeps its ends only to the first and last vertex that cut
    got2 = air.trim_chain(xy[:-1], cells[:-1], ny, loop=False)
    assert got2 is not None and len(got2[0]) == useful.sum() + 2
    # a chain that meets nothing is dropped
    far = xy[:-1] - np.array([10.0, 10.0])
    fcells = np.floor(far[:, 0] / h).astype(np.int64) * ny + np.floor(far[:, 1] / h).astype(np.int64)
    assert air.trim_chain(far, fcells, ny, loop=False) is None


def _channel_roughing():
    """A ring channel (the tool centre has a ring 2 mm wide) roughed on its stock view: the stock left to
    rough is the channel, 10 mm deep, over a floor 0.5 mm thick (the allowance). Returns
    (roughing, frame, stock, tool shape)."""
    Rt = 4.0
    shape = ToolShape(number=2, kind="flat", radius_mm=Rt, corner_radius_mm=0.0, flute_length_mm=25.0,
                      pieces=((25.0, math.inf, 4.0),))
    cloud = _channel(r_out=10.0 + 2 * Rt + 1.0 + 2.0)
    lo, hi = np.array([-27.0, -27.0, 0.0]), np.array([27.0, 27.0, 10.0])
    stock = _box(lo, hi)
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    rr = roughing_paths(cloud, tool_radius_mm=Rt, step_down_mm=2.5, stock_allowance_mm=0.5, floor_z_mm=0.5,
                        stock_points_mm=stock.boundary_points(), stock_spacing_mm=RES, holder_pieces=shape.pieces,
                        safe_z_mm=25.0, rapid_clearance_mm=0.5, stock_view=StockView(stock, frame, shape))
    return rr, frame, stock, shape


def test_entries_beside_walls_descend_at_the_entry_angle_only_from_the_material_the_stock_shows(monkeypatch):
    """In the ring channel every ramp runs beside the channel's walls, where the maps' material under it
    is the part's own height: the stock itself (the cutter, less a cell at its rim, moved up over the
    ramp's way) shows where the descent meets material, and the ramp is fed (straight, or at STEEP_DEG
    where a straight feed would shave the wall) through the air above that; the entries feed far less
    in air than when the maps alone decide, take off the same material and never plunge into it."""
    import planning.toolpath.roughing.entries as E
    from planning.toolpath.moves import USE_PLUNGE

    def entry_air(rr, frame, stock, shape):
        pm = part_moves(rr.toolpath, frame)
        run = simulate_moves(stock.copy(), pm.start, pm.end, np.broadcast_to(pm.axis, pm.start.shape), shape,
                             pm.kind, rapid_clearance_mm=0.5)
        d = pm.end - pm.start
        L = np.linalg.norm(d, axis=1)
        feed = pm.kind == FEED
        down = feed & (L > 0) & (-d[:, 2] > math.cos(math.radians(10.0)) * L)
        entry = feed & (rr.toolpath.use[pm.source] == USE_PLUNGE)
        return L[entry & (run.removed_mm3 < 1e-6)].sum(), run, down

    rr, frame, stock, shape = _channel_roughing()
    air, run, down = entry_air(rr, frame, stock, shape)
    assert rr.n_ramps > 0 and rr.n_plunges_into_material == 0
    assert np.all(run.removed_mm3[down] < 1e-6)
    monkeypatch.setattr(E._Entries, "_sweep_top", lambda self, xyz, z, top: math.inf)
    old, *_ = _channel_roughing()
    air_old, run_old, _ = entry_air(old, frame, stock, shape)
    assert air < 0.5 * air_old
    assert old.length_mm - rr.length_mm > 0.5 * (air_old - air)
    assert run.removed_mm3.sum() == pytest.approx(run_old.removed_mm3.sum(), rel=0.01)


def test_a_piece_no_entry_fits_is_tried_again_after_the_levels_other_pieces():
    """The ring channel's clearing lines are short chords no entry fits when they come first; the
    contours along the walls then sweep them, so tried again after the level's other pieces they are
    air (not cut) or entered from the cut beside them: none is left, and the channel is roughed down
    to its floor all round (the stock's top over the tool's reach is the floor, 0.5 mm)."""
    rr, frame, stock, shape = _channel_roughing()
    assert rr.n_pieces_left == 0 and rr.left_length_mm == 0.0
    pm = part_moves(rr.toolpath, frame)
    s = stock.copy()
    simulate_moves(s, pm.start, pm.end, np.broadcast_to(pm.axis, pm.start.shape), shape, pm.kind,
                   rapid_clearance_mm=0.5)
    h, x0, n = 0.5, -27.0, 108
    tops = stock_tops_in_frame(s, frame.rotation, frame.origin_mm, x0, x0, h, n, n, np.inf, -5.0)
    c = x0 + (np.arange(n) + 0.5) * h
    R = np.hypot(*np.meshgrid(c, c, indexing="ij"))
    ring = (R > 10.5 + RES) & (R < 21.0 - 0.5 - RES)            # within the tool's reach, off the walls' allowance
    assert np.all(tops[ring] <= 0.5 + 1e-6)


def test_lines_keep_off_the_walls_so_the_contour_cuts_a_band_not_the_lines_ends(monkeypatch):
    """On the stock view, with the contour pass, the clearing lines stop LINE_BACK_RT x the flat radius
    short of the part's walls where they run into them (:func:`~planning.toolpath.roughing.levels._off_walls`): the contour then
    cuts that band all along instead of retracing the thin scallops between the lines' ends. Against the
    lines run up to the walls (LINE_BACK_RT = 0): less feed, less of it in air, the same material off
    and no straight plunge."""
    import planning.toolpath.roughing.levels as LV
    from planning.toolpath.roughing.levels import _off_walls

    # the helper: a run along x loses back_mm at an end where a forbidden cell stops it, not elsewhere
    h = 0.5
    G = np.zeros((30, 40))
    G[:5, :20] = 1.0                                  # a wall across the first 20 rows' runs, at x < 2.5 mm
    region = G <= 0.5
    off = _off_walls(region, G, 0.5, h, 2.0)
    i = np.arange(30)
    assert np.all(off[:, 20:] == region[:, 20:])                     # runs from the raster's edge: whole
    assert np.all(off[i >= 9, :20]) and not off[i < 9, :20].any()    # 4 cells (2 mm) off the wall
    assert np.array_equal(_off_walls(region, G, 0.5, h, 0.0), region)

    cloud = _dome()
    lo, hi = np.array([-26.0, -26.0, -0.5]), np.array([26.0, 26.0, 24.0])
    stock = _box(lo, hi)
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    kw = {"tool_radius_mm": SHAPE.radius_mm, "step_down_mm": 3.0, "stock_allowance_mm": 0.5, "floor_z_mm": 0.0,
          "stock_points_mm": stock.boundary_points(), "stock_spacing_mm": RES, "holder_pieces": SHAPE.pieces,
          "safe_z_mm": 40.0, "rapid_clearance_mm": 0.5}
    res = {}
    for back in (LV.LINE_BACK_RT, 0.0):
        monkeypatch.setattr(LV, "LINE_BACK_RT", back)
        rr = roughing_paths(cloud, stock_view=StockView(stock, frame, SHAPE), **kw)
        pm, run, L, feed, down = _run(rr.toolpath, frame, stock, 0.5)
        res[back] = (L[feed].sum(), L[feed & (run.removed_mm3 < 1e-6)].sum(), run.removed_mm3.sum(),
                     int((down & (run.removed_mm3 > 1e-6)).sum()))
    (feed1, air1, rem1, pl1), (feed0, air0, rem0, _) = res[0.5], res[0.0]
    assert pl1 == 0
    assert feed1 < feed0 and air1 < air0
    assert rem1 == pytest.approx(rem0, rel=0.005)


def _plate(x0=0.55, thick=0.25):
    """A plate of stock ``thick`` mm across x between two rays of the families along y and z (1 mm apart at
    whole millimetres): only the x family's rays hold it."""
    lo, hi = np.array([x0, -20.0, -5.0]), np.array([x0 + thick, 20.0, 25.0])
    return TriDexel.box(lo, hi, resolution_mm=RES, domain_lo=np.full(3, -30.0), domain_hi=np.full(3, 30.0))


def test_the_live_map_stays_above_a_sliver_that_the_line_reading_misses():
    """A 0.25 mm plate that two of the three ray families miss is invisible to the stock view's reading
    along a tilted set-up axis (the lines meet none of its rays); when a level advances the live stock,
    the remaining-material map (what the holder map and the lifts read) still covers every boundary
    point of it above the level (on the range femur the holder met such a sliver 30 mm above the level
    10 times, and the guard's repairs plunged through it)."""
    from planning.toolpath.roughing.entries import _entry_cfg, _Entries
    from planning.toolpath.roughing.levels import _LiveStock
    from planning.toolpath.roughing.links import _Writer
    from planning.toolpath.roughing.maps import _coarse_max, _MaterialMap, _raster, _stock_tops

    stock = _plate()
    frame = _tilted_frame(np.random.default_rng(0).uniform([-30, -20, -5], [30, 20, 25], (500, 3)))
    bp = frame.to_frame(stock.boundary_points())
    lo_f, hi_f = bp[:, :2].min(axis=0), bp[:, :2].max(axis=0)
    Rt = SHAPE.radius_mm
    cloud_f = np.array([[lo_f[0], lo_f[1], bp[:, 2].min() - 5.0]])
    grid = _raster(cloud_f, lo_f, hi_f, Rt, 0.3125, extra_mm=2 * Rt + 3 * 0.3125)
    view = StockView(stock.copy(), frame, SHAPE)
    # the line reading sees nothing of the plate
    assert not np.isfinite(view.tops(grid.x0, grid.y0, grid.h, grid.nx, grid.ny, np.inf, -1e3)).any()
    read = _stock_tops(bp, grid, RES, floor_map=grid.cmax)
    lo_r = np.array([grid.x0, grid.y0])
    mat = _MaterialMap(grid, lo_r, lo_r + grid.h * np.array([grid.nx, grid.ny]), None, Rt, top0=_coarse_max(read))
    ent = _Entries(_entry_cfg("helix", 3.0, None, None, Rt), mat, read, np.full((grid.nx, grid.ny), -np.inf), Rt,
                   0.0, Rt + grid.h)
    live = _LiveStock(view, grid, read, Rt, 0.5)
    z = float(np.percentile(bp[:, 2], 30))
    live.advance(_Writer(), z, mat, ent)
    above = bp[bp[:, 2] > z]
    ci = np.floor((above[:, 0] - grid.x0) / mat.H).astype(int)
    cj = np.floor((above[:, 1] - grid.y0) / mat.H).astype(int)
    assert above.shape[0] > 100
    assert np.all(mat.top[ci, cj] >= above[:, 2] - 1e-9)


def test_a_helix_whose_start_has_material_above_it_begins_higher_by_a_ramp_along_its_own_way():
    """Where the stock stands in the column over a helix's start (the rapid down would stop above it and
    the feed on to it cut: a straight plunge), the descent is begun where the column over every point of
    its way is clear, by a ramp back and forth along that way at the entry angle, ending where the
    helix began; nothing changes where the column is clear."""
    from planning.toolpath.roughing.entries import _entry_cfg, _Entries, _helix_xyz
    from planning.toolpath.roughing.links import _Writer

    cfg = _entry_cfg("helix", 3.0, None, None, 4.0)
    ent = _Entries(cfg, None, None, np.zeros((2, 2)), 4.0, 0.0, 4.0)
    xyz = _helix_xyz(np.array([10.0, 5.0]), 2.8, 0.3, -2.0, -6.0, cfg.tan)
    w = _Writer()
    asked = []

    def column_clear_many(points, top):
        asked.append(np.array(points))
        return np.where(np.hypot(points[:, 0] - 12.0, points[:, 1] - 5.0) < 1.0, 3.5, points[:, 2])

    w.column_clear_many = column_clear_many
    out, zs = ent._raised(w, xyz, float(xyz[0, 2]), 20.0)
    assert zs == pytest.approx(3.5) and out[0, 2] == pytest.approx(3.5)
    assert ent.n_raised == 1
    # the new head ends where the helix began, then the helix as it was
    k = out.shape[0] - xyz.shape[0] + 1
    assert np.allclose(out[k - 1], xyz[0]) and np.allclose(out[k:], xyz[1:])
    # every segment of the head descends at the entry angle, along the helix's own way
    d = np.diff(out[:k], axis=0)
    run_xy = np.hypot(d[:, 0], d[:, 1])
    assert np.allclose(-d[:, 2], cfg.tan * run_xy, atol=1e-9)
    pts = asked[0][:, :2]
    near = np.min(np.hypot(out[:k, None, 0] - pts[None, :, 0], out[:k, None, 1] - pts[None, :, 1]), axis=1)
    assert near.max() < 0.26
    # a clear column: unchanged
    w.column_clear_many = lambda points, top: points[:, 2]
    same, zs2 = ent._raised(w, xyz, float(xyz[0, 2]), 20.0)
    assert same is xyz and zs2 == xyz[0, 2] and ent.n_raised == 1


def test_boundary_tops_in_frame_are_the_highest_boundary_point_per_cell():
    """The kernel against the boundary points themselves (numpy, per cell maximum), on a cut box and the
    thin plate in a tilted frame, with and without a lower bound."""
    from planning.simulate.heightfield import boundary_tops_in_frame

    stock = _box([-20.0, -15.0, -5.0], [20.0, 15.0, 20.0])
    frame = _tilted_frame(np.random.default_rng(1).uniform([-20, -15, -5], [20, 15, 20], (300, 3)))
    t = np.linspace(0.0, 1.0, 40)[:, None]
    path = frame.to_part(np.column_stack([(-25.0 + 50.0 * t)[:, 0], np.full(40, 2.0), np.full(40, 3.0)]))
    cut(stock, path[:-1], path[1:], np.broadcast_to(frame.rotation[2], (39, 3)), SHAPE)
    h, x0, y0, n = 0.5, -45.0, -45.0, 180
    for model in (stock, _plate()):
        p = frame.to_frame(model.boundary_points())
        for above in (-np.inf, float(np.median(p[:, 2]))):
            got = boundary_tops_in_frame(model, frame.rotation, frame.origin_mm, x0, y0, h, n, n, above)
            want = np.full((n, n), -np.inf)
            q = p[p[:, 2] > above]
            i = np.floor((q[:, 0] - x0) / h).astype(int)
            j = np.floor((q[:, 1] - y0) / h).astype(int)
            ok = (i >= 0) & (i < n) & (j >= 0) & (j < n)
            np.maximum.at(want, (i[ok], j[ok]), q[ok, 2])
            assert np.isfinite(want).sum() > 50
            assert np.allclose(got, want, equal_nan=False) and np.array_equal(np.isfinite(got), np.isfinite(want))


def test_the_contours_steps_away_from_a_wall_are_taken_out_where_the_exact_clearance_allows(monkeypatch):
    """The offset contour is a staircase of raster cells; along a sloping wall its steps away from the
    part cut nothing (the tool steps into the room it has just cut). On the stock view a vertex where the
    chain turns towards the part, within a cell of its neighbours' chord, is dropped when the tool along
    that chord keeps the allowance from the cloud (:func:`~planning.toolpath.roughing.clearing._hug`):
    against the same roughing without it (HUG_ROUNDS = 0), the contour feeds far less in air, no less
    material comes off, nothing plunges, and the path still keeps the allowance from every point."""
    import planning.toolpath.roughing.clearing as CL
    from planning.toolpath.roughing.clearance import _MoveClearance, min_tool_clearance
    from planning.toolpath.roughing.clearing import _hug, _Piece

    # the helper on a staircase beside a wall x = 0 sloping away (the part on the right of the travel,
    # +y): the steps right (towards the part) stay, a step left is dropped only where the chord keeps the
    # clearance
    h, Rt, a = 0.5, 2.0, 0.3
    ys = np.arange(-20.0, 20.01, 0.25)
    wall = np.column_stack([np.zeros_like(ys), ys, np.full_like(ys, 5.0)])    # points on x = 0, above the tip
    x = -(Rt + a) - np.array([0.0, 0.0, h, h, 2 * h, 2 * h])               # stepping away from the wall
    y = np.array([-10.0, -5.0, -4.5, 0.0, 0.5, 5.0])
    piece = _Piece(0, np.column_stack([x, y]), np.arange(6), "start", False)
    keeps = _MoveClearance(wall, Rt).keeps
    out = _hug([piece], keeps, 1.0, a, h)[0]
    # the vertices where the chain turns right (towards the wall at x = 0) after a step left are gone
    assert out.xy.shape[0] < piece.xy.shape[0]
    assert np.allclose(out.xy[0], piece.xy[0]) and np.allclose(out.xy[-1], piece.xy[-1])
    assert min_tool_clearance(np.column_stack([out.xy, np.ones(len(out.xy))]), wall, tool_radius_mm=Rt).min_mm \
        >= a - 1e-9
    # a wall that follows the staircase itself (points Rt + a to the right of every point of it): no chord
    # keeps the allowance, nothing changes
    t = np.linspace(0.0, 1.0, 200)[:, None]
    stair = np.concatenate([piece.xy[k] + t * (piece.xy[k + 1] - piece.xy[k]) for k in range(5)])
    tight = np.column_stack([stair[:, 0] + Rt + a, stair[:, 1], np.full(len(stair), 5.0)])
    same = _hug([piece], _MoveClearance(tight, Rt).keeps, 1.0, a, h)[0]
    assert same.xy.shape == piece.xy.shape

    # a cone (its wall at every angle to the raster, sloping: each level cuts a band along it)
    cloud = _cone()
    stock = _box([-26.0, -26.0, 0.0], [26.0, 26.0, 22.0])
    frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
    kw = {"tool_radius_mm": SHAPE.radius_mm, "step_down_mm": 3.0, "stock_allowance_mm": 0.5, "floor_z_mm": 0.5,
          "stock_points_mm": stock.boundary_points(), "stock_spacing_mm": RES, "holder_pieces": SHAPE.pieces,
          "safe_z_mm": 40.0, "rapid_clearance_mm": 0.5}
    import planning.toolpath.roughing.air as AM

    # the chords alone (the exact ends and the lifted links, tested below, change which pieces start where)
    monkeypatch.setattr(AM, "EXACT_ENDS", False)
    monkeypatch.setattr(AM, "LINK_LIFT_MM", 1e9)
    on = CL.HUG_ROUNDS
    assert on > 0
    res = {}
    for rounds in (on, 0):
        monkeypatch.setattr(CL, "HUG_ROUNDS", rounds)
        rr = roughing_paths(cloud, stock_view=StockView(stock, frame, SHAPE), **kw)
        pm, run, L, feed, down = _run(rr.toolpath, frame, stock, 0.5)
        air = feed & (run.removed_mm3 < 1e-6)
        d = pm.end - pm.start
        steps = feed & (np.abs(d[:, 2]) < 1e-9) & (L <= 2 * rr.cell_mm + 1e-9)     # a cell or two at a level
        res[rounds] = {"air": L[air].sum(), "steps_air": L[steps & air].sum(), "removed": run.removed_mm3.sum(),
                       "plunges": int((down & ~air).sum()), "rapids": int((run.rapid_depth_mm > 0).sum()),
                       "holder": int((run.holder_depth_mm > 0).sum()), "rr": rr}
    new, old = res[on], res[0]
    assert new["plunges"] == 0 and new["rapids"] == 0 and new["holder"] == 0
    assert new["rr"].n_plunges_into_material == 0
    assert old["steps_air"] > 10.0 and new["steps_air"] < 0.2 * old["steps_air"]
    assert new["air"] < old["air"]
    assert new["removed"] >= old["removed"]
    assert new["rr"].min_clearance_mm >= 0.5 - 1e-6


def _cone(r0=20.0, r1=10.0, height=20.0, step=0.5):
    """A cone's frustum standing on z = 0 (radius ``r0`` at the bottom, ``r1`` at the top), points ``step``
    apart on its wall and its top."""
    pts = []
    for z in np.arange(0.0, height + 1e-9, step):
        r = r0 + (r1 - r0) * z / height
        n = int(2 * math.pi * r / step)
        t = np.linspace(0, 2 * math.pi, n, endpoint=False)
        pts.append(np.column_stack([r * np.cos(t), r * np.sin(t), np.full(n, z)]))
    g = np.arange(-r1, r1 + 1e-9, step)
    X, Y = np.meshgrid(g, g, indexing="ij")
    m = np.hypot(X, Y) <= r1
    pts.append(np.column_stack([X[m], Y[m], np.full(m.sum(), height)]))
    return np.concatenate(pts)


def test_pieces_ends_and_links_that_meet_no_material_on_the_stock_are_not_fed():
    """On the stock view a piece's leading and trailing moves that meet no material as the level's cuts
    so far left it are not cut (a loop is opened at its longest such run, a line cut to the parts that
    meet material: :func:`~planning.toolpath.roughing.air._exact_ends`), and a feed link at the level
    longer than LINK_LIFT_MM (plus LIFT_SLOWER times the lift's feeds) through air only, to a piece that starts in
    air, is lifted over. On the
    tilted dome, each step feeds less in air than the one before, the same material comes off, and
    nothing plunges, brushes a rapid or meets the holder."""
    import planning.toolpath.roughing.air as AM
    from planning.toolpath.roughing.air import _exact_ends, _LevelAir

    # the helper, with a made-up stock: material only where x > 5
    air = _LevelAir(np.zeros((40, 40), bool), 0.0, 0.0, 0.5, 2.0, 2.0)

    def meets(a, b, z):
        return np.maximum(a[:, 0], b[:, 0]) > 5.0

    xs = np.arange(0.0, 10.01, 1.0)
    chain = np.column_stack([xs, np.full_like(xs, 3.0)])
    cells = np.arange(xs.size)
    k = AM.KEEP_LEAD                                   # leading moves in air kept (the way in from the side)
    got = _exact_ends(air, chain, cells, 40, meets, 0.0, False, False)
    assert got is not None and np.allclose(got[0], chain[5 - k:]) and np.array_equal(got[1], cells[5 - k:])
    assert _exact_ends(air, chain[:5], cells[:5], 40, meets, 0.0, False, False) is None
    # a loop about the square [0, 10] x [0, 10]: opened at its run of moves with x <= 5
    t = np.concatenate([np.arange(0, 10), np.full(10, 10.0), np.arange(10, 0, -1), np.zeros(10)])
    u = np.concatenate([np.zeros(10), np.arange(0, 10), np.full(10, 10.0), np.arange(10, 0, -1)])
    loop = np.vstack([np.column_stack([t, u]), [[0.0, 0.0]]])
    lcells = np.arange(loop.shape[0]) % (loop.shape[0] - 1)
    got = _exact_ends(air, loop, lcells, 40, meets, 0.0, True, False)
    assert got is not None
    hit = meets(got[0][:-1], got[0][1:], 0.0)
    assert hit[k:].all() and not hit[:k].any() and hit.size == int(meets(loop[:-1], loop[1:], 0.0).sum()) + k
    # a line from x = 0 to 10 (cells of the row j = 6): cut to the parts that meet material
    line = np.array([[0.0, 3.0], [10.0, 3.0]])
    lc = np.array([0 * 40 + 6, 19 * 40 + 6])
    got = _exact_ends(air, line, lc, 40, meets, 0.0, False, True)
    part = AM.LINE_PART_RT * 2.0
    assert got is not None and 4.0 - k * part <= got[0][0, 0] <= 5.0 - (k - 1) * part
    assert got[0][1, 0] == pytest.approx(10.0)
    assert got[1][0] // 40 == int(math.floor(got[0][0, 0] / 0.5)) and got[1][1] == lc[1] and got[1][0] % 40 == 6
    # a line or chain whose two end moves meet material stays whole, material or not between them, and
    # only those two moves are asked of the stock; the same pieces with an end in air are still trimmed
    asked = []

    def meets_ends(a, b, z):                          # material beyond x = 8 and before x = 2
        asked.append(a.shape[0])
        return (np.maximum(a[:, 0], b[:, 0]) > 8.0) | (np.minimum(a[:, 0], b[:, 0]) < 2.0)

    for piece, pc, is_line in ((chain, cells, False), (np.array([[0.0, 3.0], [10.0, 3.0]]), lc, True)):
        asked.clear()
        got = _exact_ends(air, piece, pc, 40, meets_ends, 0.0, False, is_line)
        assert got[0] is piece and got[1] is pc and asked == [2]
    asked.clear()                                      # from x = 3: its first move in air, every move asked
    got = _exact_ends(air, chain[3:], cells[3:], 40, meets_ends, 0.0, False, False)
    assert asked == [2, chain.shape[0] - 4] and np.allclose(got[0], chain[8 - k:])
    asked.clear()
    got = _exact_ends(air, np.array([[3.0, 3.0], [10.0, 3.0]]), lc, 40, meets_ends, 0.0, False, True)
    assert len(asked) == 2 and asked[0] == 2 and 7.0 - k * part <= got[0][0, 0] <= 8.0 - (k - 1) * part

    cloud_f, stock, frame, lo, kw = _dome_case()
    kw["rapid_clearance_mm"] = 0.5
    link = AM.LINK_LIFT_MM
    assert AM.EXACT_ENDS and link < 1e6
    res = []
    # the lifts' feeds counted at the roughing feed (LIFT_SLOWER = 1): the dome's links through air are then
    # long enough to lift over (at the default, 4 x, none is here)
    for ends, lift, slower in ((False, 1e9, AM.LIFT_SLOWER), (True, 1e9, AM.LIFT_SLOWER), (True, link, 1.0)):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(AM, "EXACT_ENDS", ends)
            mp.setattr(AM, "LINK_LIFT_MM", lift)
            mp.setattr(AM, "LIFT_SLOWER", slower)
            rr = roughing_paths(cloud_f, stock_view=StockView(stock, frame, SHAPE), **kw)
        pm, run, L, feed, down = _run(rr.toolpath, frame, stock, 0.5)
        air_ = feed & (run.removed_mm3 < 1e-6)
        res.append((L[air_].sum(), run.removed_mm3.sum(), int((down & ~air_).sum()),
                    int((run.rapid_depth_mm > 0).sum()), int((run.holder_depth_mm > 0).sum()),
                    rr.n_plunges_into_material))
    (a0, r0, *_), (a1, r1, *c1), (a2, r2, *c2) = res
    assert a1 < a0 and a2 < a1
    assert r1 == pytest.approx(r0, rel=1e-3) and r2 == pytest.approx(r0, rel=1e-3)
    assert c1 == [0, 0, 0, 0] and c2 == [0, 0, 0, 0]
