"""Tool paths per connected region of an area (planning.toolpath.area_paths, ``input_regions``) and
roughing restricted to a window over the area (planning.toolpath.roughing, ``window_xy_mm``).

The scenes: a flat (or wavy) plate 100 x 40 mm at z = 0 whose area 0 is two 20 x 20 mm squares
40 mm apart along x (regions 0 and 1 of that area) and whose area 1 is the rest; both set-ups look
down +Z. The references are independent of the modules: KD-tree distances, the patches' rectangles.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from scipy.spatial import cKDTree

from planning.geometry.tool import ball_tool
from planning.toolpath.area_paths import (
    area_toolpaths,
    join_region_paths,
    roughing_window_reach_mm,
)
from planning.toolpath.finishing import finishing_passes
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    RAPID,
    USE_CUT,
    densify,
    path_length_mm,
)
from planning.toolpath.roughing import roughing_paths
from planning.toolpath.roughing.levels import _window_cells
from planning.toolpath.roughing.maps import _raster
from schemas.params import PathsParams

R = 3.0
TOL = 0.01
SCALLOP = 0.1
AXES = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
PATCH_X = (-30.0, 30.0)       # centres of the two 20 x 20 mm squares (y centre 0)
CUT = (FEED, ARC_CW, ARC_CCW)


def _tool():
    return ball_tool(R, flute_length_mm=15.0, stickout_mm=25.0, holder=[(4.0, None, None)])


def _params(roughing: bool = False) -> PathsParams:
    return PathsParams(finishing={"scallop_mm": SCALLOP, "tolerance_mm": TOL}, roughing={"enabled": roughing})


def _plate(wavy: bool = False, sp: float = 0.5):
    """Plate points (N,3), the area of each (0: the two squares, 1: the rest) and the region of each
    within its area (square at x = +30: region 1 of area 0; everything else region 0)."""
    X, Y = np.meshgrid(np.arange(-50, 50 + 1e-9, sp), np.arange(-20, 20 + 1e-9, sp), indexing="ij")
    x, y = X.ravel(), Y.ravel()
    z = 1.5 * np.sin(x / 4.0) * np.cos(y / 5.0) if wavy else np.zeros(x.size)
    pts = np.stack([x, y, z], 1)
    a = (np.abs(x - PATCH_X[0]) <= 10) & (np.abs(y) <= 10)
    b = (np.abs(x - PATCH_X[1]) <= 10) & (np.abs(y) <= 10)
    return pts, np.where(a | b, 0, 1), np.where(b, 1, 0).astype(np.int64)


def _patch_distance(xy: np.ndarray, k: int) -> np.ndarray:
    """Distance (mm) in (x, y) from each point to the 20 x 20 mm square k."""
    dx = np.maximum(np.abs(xy[:, 0] - PATCH_X[k]) - 10.0, 0.0)
    dy = np.maximum(np.abs(xy[:, 1]) - 10.0, 0.0)
    return np.hypot(dx, dy)


def _blocks(tp, safe):
    """The runs of moves between two visits of the safe height: lists of move indices whose end
    points lie below it (each a lead-in, the cut and the lead-out of one stretch or more)."""
    low = tp.xyz_mm[:, 2] < safe - 1e-9
    edges = np.flatnonzero(np.diff(np.concatenate([[0], low.astype(np.int8), [0]])))
    return [np.arange(a, b) for a, b in zip(edges[::2], edges[1::2])]


@pytest.fixture(scope="module")
def plate_paths():
    """Area 0 of the flat plate finished per region and as one region."""
    pts, labels, regions = _plate()
    per = area_toolpaths(pts, labels, AXES, tool=_tool(), paths_params=_params(), input_regions=regions)[0]
    whole = area_toolpaths(pts, labels, AXES, tool=_tool(), paths_params=_params())[0]
    return pts, per, whole


# ------------------------------------------------------------------------------------------------
# backward compatibility
# ------------------------------------------------------------------------------------------------

def _assert_same_toolpath(a, b):
    for name in ("xyz_mm", "kind", "centre_mm", "plane", "use"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.tip_offset_mm == b.tip_offset_mm


def test_no_regions_is_the_same_as_one_region_per_area():
    """Area 0 = one square (one region): input_regions None and all zero give the same finishing and
    roughing moves and figures; the roughing window keeps every tip within its reach (plus a cell)
    of the area's points, on a plate that reaches well beyond it."""
    pts, labels, _ = _plate()
    labels = np.where((np.abs(pts[:, 0] - PATCH_X[0]) <= 10) & (np.abs(pts[:, 1]) <= 10), 0, 1)
    kw = {"tool": _tool(), "paths_params": _params(roughing=True)}
    none = area_toolpaths(pts, labels, AXES, **kw)
    zero = area_toolpaths(pts, labels, AXES, input_regions=np.zeros(pts.shape[0], np.int64), **kw)
    assert len(none) == len(zero) == 2
    for a, b in zip(none, zero):
        _assert_same_toolpath(a.finishing, b.finishing)
        _assert_same_toolpath(a.finishing_info.toolpath, b.finishing_info.toolpath)
        _assert_same_toolpath(a.roughing, b.roughing)
        np.testing.assert_array_equal(a.finishing_info.pass_index, b.finishing_info.pass_index)
        assert a.finishing_info.n_regions == b.finishing_info.n_regions == 1
        assert (a.finishing_info.n_retracts, a.min_clearance_mm) == (b.finishing_info.n_retracts, b.min_clearance_mm)
    ap = none[0]
    reach = roughing_window_reach_mm(_params(roughing=True), _tool())
    feed = ap.roughing.kind == FEED
    assert feed.sum() > 0
    area_xy = ap.frame.to_frame(pts[labels == 0])[:, :2]
    d, _ = cKDTree(area_xy).query(ap.roughing.tip_mm()[feed, :2])
    assert d.max() <= reach + ap.roughing_info.cell_mm + 1e-9
    # the plate reaches 80 mm beyond the square: the window is what keeps the tool near it
    assert cKDTree(area_xy).query(ap.frame.to_frame(pts)[:, :2])[0].max() > reach + 20.0


# ------------------------------------------------------------------------------------------------
# finishing per region
# ------------------------------------------------------------------------------------------------

def test_each_region_gets_its_passes_and_the_cut_stays_on_it(plate_paths):
    _, ap, _ = plate_paths
    fin = ap.finishing_info
    assert fin.n_regions == 2
    tp = ap.finishing
    cut = np.flatnonzero(np.isin(tp.kind, CUT))
    xy_end, xy_start = tp.xyz_mm[cut, :2], tp.xyz_mm[cut - 1, :2]
    near = 1.0 + 1.0 + R        # margin + lead ramp + the contact cell's slack (well below R)
    for xy in (xy_end, xy_start):
        own = np.minimum(_patch_distance(xy, 0), _patch_distance(xy, 1))
        assert own.max() <= near
    # every cutting move starts and ends by the same square
    side_end, side_start = xy_end[:, 0] > 0, xy_start[:, 0] > 0
    assert np.array_equal(side_end, side_start)
    # each square is covered by passes at most a step-over apart (the CL points before reduction)
    s = fin.step_over_mm
    raw = fin.toolpath
    for k in (0, 1):
        on = (raw.use == USE_CUT) & (_patch_distance(raw.xyz_mm[:, :2], k) == 0.0)
        ys = np.unique(np.round(raw.xyz_mm[on, 1], 9))
        assert ys.min() <= -10.0 + s and ys.max() >= 10.0 - s and np.diff(ys).max() <= s + 1e-6
    # the regions one after another: the blocks below the safe height visit one square, then the other
    sides = [bool(tp.xyz_mm[b, 0].mean() > 0) for b in _blocks(tp, ap.safe_z_mm)]
    assert sum(a != b for a, b in pairwise(sides)) == 1


def test_the_move_between_regions_is_a_rapid_at_the_safe_height(plate_paths):
    _, ap, _ = plate_paths
    for tp in (ap.finishing, ap.finishing_info.toolpath):
        x = tp.xyz_mm[:, 0]
        cross = np.flatnonzero(np.sign(x[1:]) != np.sign(x[:-1])) + 1
        assert cross.size == 1
        i = int(cross[0])
        assert tp.kind[i] == RAPID
        assert tp.xyz_mm[i - 1, 2] == pytest.approx(ap.safe_z_mm) and tp.xyz_mm[i, 2] == pytest.approx(ap.safe_z_mm)


def test_per_region_is_not_worse_than_one_zigzag_over_both(plate_paths):
    """Passes along x cross both squares: as one region every pass has two stretches 40 mm apart
    and retracts between them; per region the passes of a square are linked on the surface."""
    _, per, whole = plate_paths
    fp, fw = per.finishing_info, whole.finishing_info
    assert whole.finishing_info.n_regions == 1
    assert fp.n_retracts < fw.n_retracts
    assert fp.n_retracts == 1                    # the one between the two squares
    assert fp.toolpath.n_moves <= fw.toolpath.n_moves
    assert per.finishing.n_moves <= whole.finishing.n_moves
    rapid = lambda tp: path_length_mm(tp, kinds=(RAPID,))
    assert rapid(per.finishing) < rapid(whole.finishing)
    n_rapids = lambda tp: int((tp.kind == RAPID).sum())
    assert n_rapids(per.finishing) < n_rapids(whole.finishing)


def test_joined_info_adds_up_over_the_regions():
    """The joined FinishingPath against the regions finished one by one."""
    pts, labels, regions = _plate()
    cloud = pts.copy()
    parts = [finishing_passes(cloud, (labels == 0) & (regions == r), radius_mm=R, scallop_mm=SCALLOP, tol_mm=TOL,
                              safe_z_mm=8.0) for r in (1, 0)]
    j = join_region_paths(parts)
    assert j.n_regions == 2 and j.n_passes == parts[0].n_passes + parts[1].n_passes
    assert j.length_mm == pytest.approx(parts[0].length_mm + parts[1].length_mm)
    assert j.n_retracts == parts[0].n_retracts + parts[1].n_retracts + 1
    assert j.min_clearance_mm == min(p.min_clearance_mm for p in parts)
    assert j.toolpath.n_moves == j.pass_index.shape[0] == sum(p.toolpath.n_moves for p in parts)
    # the first path comes first; the pass numbers of the second are offset past the first's
    n0 = parts[0].toolpath.n_moves
    np.testing.assert_array_equal(j.toolpath.xyz_mm[:n0], parts[0].toolpath.xyz_mm)
    pi0, pi1 = j.pass_index[:n0], j.pass_index[n0:]
    assert pi0.max() < parts[0].n_passes <= pi1[pi1 >= 0].min()
    assert np.array_equal(pi1 < 0, parts[1].pass_index < 0)


def test_nearest_region_comes_next():
    """Three regions: after the first, the one whose start is nearest the end of the first."""
    pts = _plate()[0]
    x, y = pts[:, 0], pts[:, 1]
    masks = [(np.abs(x - cx) <= 5) & (np.abs(y) <= 5) for cx in (-35.0, 35.0, 0.0)]
    parts = [finishing_passes(pts, m, radius_mm=R, scallop_mm=SCALLOP, tol_mm=TOL, safe_z_mm=8.0) for m in masks]
    j = join_region_paths(parts)
    n0 = parts[0].toolpath.n_moves
    # the next path starts with the start of the middle square's path, not the far one's
    np.testing.assert_array_equal(j.toolpath.xyz_mm[n0], parts[2].toolpath.xyz_mm[0])
    assert j.n_regions == 3 and j.n_retracts == sum(p.n_retracts for p in parts) + 2


def test_a_region_without_a_pass_adds_nothing(monkeypatch):
    """A region on which finishing_passes finds no pass (its ParameterError) is left out of the
    joined path; when no region gets a pass the error is raised as for a one-region area."""
    from planning.errors import ParameterError
    from planning.toolpath import area_paths

    pts, labels, regions = _plate()
    real = area_paths.finishing_passes

    def no_pass_on(min_x):
        def fake(cloud, mask, **kw):
            if cloud[mask, 0].mean() > min_x:       # the regions whose points lie right of min_x
                raise ParameterError("no finishing pass lies on the area")
            return real(cloud, mask, **kw)
        return fake

    monkeypatch.setattr(area_paths, "finishing_passes", no_pass_on(0.0))
    ap = area_toolpaths(pts, labels, AXES, tool=_tool(), paths_params=_params(), input_regions=regions)[0]
    assert ap.finishing_info.n_regions == 1 and ap.finishing_info.n_retracts == 0
    assert ap.finishing.xyz_mm[:, 0].max() < 0                  # only the square at x = -30
    assert ap.gouge_free
    monkeypatch.setattr(area_paths, "finishing_passes", no_pass_on(-np.inf))
    with pytest.raises(ParameterError, match="no finishing pass"):
        area_toolpaths(pts, labels, AXES, tool=_tool(), paths_params=_params(), input_regions=regions)


# ------------------------------------------------------------------------------------------------
# gouge checks on the joined path
# ------------------------------------------------------------------------------------------------

def test_joined_path_on_a_wavy_plate_is_gouge_free():
    pts, labels, regions = _plate(wavy=True)
    ap = area_toolpaths(pts, labels, AXES, tool=_tool(), paths_params=_params(), input_regions=regions)[0]
    assert ap.finishing_info.n_regions == 2
    assert ap.gouge_free and ap.min_clearance_mm >= R - TOL
    assert ap.finishing_info.min_clearance_mm >= R - TOL
    # independently: the final moves (arcs included) sampled every 0.02 mm against every point
    tp = ap.finishing
    q, mv = densify(tp, 0.02)
    keep = np.isin(tp.kind, CUT)[mv] & (mv > 0)
    d, _ = cKDTree(ap.frame.to_frame(pts)).query(q[keep])
    assert d.min() >= R - TOL - 1e-9
    # nothing below the safe height between the squares' blocks
    x = tp.xyz_mm[:, 0]
    i = int((np.flatnonzero(np.sign(x[1:]) != np.sign(x[:-1])) + 1)[0])
    assert min(tp.xyz_mm[i - 1, 2], tp.xyz_mm[i, 2]) >= ap.safe_z_mm - 1e-9


def test_adaptive_passes_cut_at_the_heights_of_their_own_y(monkeypatch):
    """When the side-step rounds run out (one round here), the pass taken is dropped at its own y:
    every CL point of a pass lies at or above the ball-drop height under it (a point below it is a
    gouge; the half sphere of tests/test_paths_pipeline.py hit this with the contiguous areas)."""
    from planning.toolpath import finishing
    from planning.toolpath.balldrop import ball_drop

    monkeypatch.setattr(finishing, "_ADAPT_ROUNDS", 1)
    pts = _dome()
    fin = finishing_passes(pts, np.ones(pts.shape[0], dtype=bool), radius_mm=R, scallop_mm=SCALLOP, tol_mm=TOL)
    on = fin.pass_index >= 0
    cl = fin.toolpath.xyz_mm[on]
    z = ball_drop(pts, cl[:, :2], R).z_mm
    assert np.all(cl[:, 2] >= z - 1e-9)
    assert fin.min_clearance_mm >= R - TOL


# ------------------------------------------------------------------------------------------------
# roughing window
# ------------------------------------------------------------------------------------------------

RT = 3.0
ALLOW = 0.5


def _dome():
    """A hemisphere of radius 8 on a plane (z = -8), 30 x 30 mm (area frame, top at z = 0)."""
    X, Y = np.meshgrid(np.arange(-15, 15 + 1e-9, 0.75), np.arange(-15, 15 + 1e-9, 0.75), indexing="ij")
    x, y = X.ravel(), Y.ravel()
    r = np.hypot(x, y)
    return np.stack([x, y, np.where(r < 8, np.sqrt(np.maximum(64 - r * r, 0.0)), 0.0) - 8.0], 1)


def test_window_cells_are_the_cells_within_reach():
    """The window mask against brute force: every cell centre against every window point."""
    rng = np.random.default_rng(3)
    pts = _dome()
    grid = _raster(pts, pts[:, :2].min(axis=0) - 2.0, pts[:, :2].max(axis=0) + 2.0, RT, RT / 16)
    xy = rng.uniform(-12, 4, (60, 2))
    for reach in (0.0, 0.7, 4.3):
        got = _window_cells(grid, xy, reach)
        cx = grid.x0 + (np.arange(grid.nx) + 0.5) * grid.h
        cy = grid.y0 + (np.arange(grid.ny) + 0.5) * grid.h
        C = np.stack(np.meshgrid(cx, cy, indexing="ij"), -1).reshape(-1, 2)
        d, _ = cKDTree(xy).query(C)
        want = (d <= reach * (1 + 1e-12) + 1e-12).reshape(grid.nx, grid.ny)
        assert np.array_equal(got, want)
        assert reach == 0.0 or got.sum() > 0


def test_roughing_stays_in_its_window():
    pts = _dome()
    win = pts[pts[:, 0] <= -8.0, :2]                  # a strip along one side
    reach = 3.0
    kw = {"tool_radius_mm": RT, "stock_allowance_mm": ALLOW, "step_down_mm": 3.0}
    full = roughing_paths(pts, **kw)
    rp = roughing_paths(pts, window_xy_mm=win, window_reach_mm=reach, **kw)
    tree = cKDTree(win)
    feed = rp.toolpath.kind == FEED
    assert feed.sum() > 10
    d, _ = tree.query(rp.toolpath.tip_mm()[feed, :2])
    assert d.max() <= reach + rp.cell_mm + 1e-9
    # the whole-box path goes well beyond the window, and the windowed one is shorter
    d_full, _ = tree.query(full.toolpath.tip_mm()[full.toolpath.kind == FEED, :2])
    assert d_full.max() > reach + 10.0
    assert rp.length_mm < full.length_mm
    assert rp.min_clearance_mm >= ALLOW - 1e-6


def test_window_over_everything_is_the_whole_box():
    pts = _dome()
    kw = {"tool_radius_mm": RT, "stock_allowance_mm": ALLOW, "step_down_mm": 3.0}
    full = roughing_paths(pts, **kw)
    rp = roughing_paths(pts, window_xy_mm=pts[:, :2], window_reach_mm=100.0, **kw)
    _assert_same_toolpath(full.toolpath, rp.toolpath)
    assert rp.n_retracts == full.n_retracts and rp.length_mm == full.length_mm


@pytest.mark.parametrize("xy, reach", [(np.zeros((3, 3)), 1.0), (np.array([[0.0, np.nan]]), 1.0),
                                       (np.zeros((2, 2)), -1.0)])
def test_bad_window_raises(xy, reach):
    from planning.errors import ParameterError
    with pytest.raises(ParameterError):
        roughing_paths(_dome(), tool_radius_mm=RT, window_xy_mm=xy, window_reach_mm=reach)
