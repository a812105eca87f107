"""The entry of the Z-level roughing of one set-up (:mod:`planning.toolpath.roughing`; mm, area
frame, tool tip): :func:`roughing_paths` checks the arguments, builds the stock box, the levels and
the maps, cuts the levels from the top down and verifies the clearance; :class:`RoughingPath` is
its result. Stage: called per area by :mod:`planning.toolpath.area_paths`, after the area frame
(:mod:`planning.toolpath.frames`) and before the post-processor; the tool tip, stock, levels and
the whole method (Popescu et al. 2014; Tchanchane & Bey) are described in the package docstring.
With ``window_xy_mm`` the clearing region of every level is also limited to the raster cells within
``window_reach_mm`` of the window's points (:func:`_window_cells`: the caller's area footprint).

**Rest roughing** (``stock_points_mm``, ``stock_spacing_mm``): the stock is the material that is
there now, given by points sampling its boundary (the caller's tri-dexel stock carried through the
set-ups). Its top per raster cell (:func:`~planning.toolpath.roughing.maps._stock_tops`: the highest
point per cell, then the largest over a disc of ``spacing + h``, hole-free and never too low; at
least the cloud's highest point per cell) gives: the first level, one step below the highest top
that a tool centre of the window can reach (the largest over the disc of ``Rt + h``); each level's
clearing region, limited to the tool-centre cells within ``Rt + h`` of a cell whose top is above
the level (no air is cut where there is no stock; the forbidden map, hence the allowance, is
unchanged); the remaining-material map's start (its coarse maxima instead of the box top, over a
raster grown by ``2 Rt + 3 h`` so that it holds the material under every tool disc, side entries
included), so lifts, links and rapids stay clear of the real material. The safe height is still
the cap of every move, but is raised to GAP_MM above the highest material of the map where the
stock rises above it (reported in ``RoughingPath.safe_z_mm``). Stock-free windows give an empty
path with no level.

**Entries** (``entry``, :mod:`planning.toolpath.roughing.entries`): where a piece starts after a
lift, the tool comes straight down only into air or a hole already cut; into material it enters
from the side, by a helix or by a ramp, and plunges (counted) only when none fits.

**Holder** (``holder_pieces``): a :class:`~planning.toolpath.roughing.maps._HolderMap` is built
once (the cloud part of the test) and asked at every level, before its region, which candidate
cells the holder blocks (the material part, from the remaining-material map as the level above
left it: the level's own cut only lowers it, so it is an upper bound for the whole level); the
region is the candidates less the blocked cells, side entries keep to the unblocked cells, and the
level's :class:`~planning.toolpath.roughing.links._Level` carries the holder's heights for the
lifts. Levels are unchanged: where everything is blocked a level simply cuts nothing there. The
offset contour follows only the forbidden map's edges, not the holder's (as with the window's).

A level is cut (:func:`_cut_level`) by taking its pieces (:mod:`planning.toolpath.roughing.clearing`)
in their order (:mod:`planning.toolpath.roughing.ordering`), each joined to the one before by a
feed link at the level or a lift (:mod:`planning.toolpath.roughing.links`); the remaining-material
map (:mod:`planning.toolpath.roughing.maps`) is then lowered along the cut.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit
from scipy import ndimage
from scipy.spatial import cKDTree

from planning.errors import ParameterError
from planning.toolpath.moves import (
    FEED,
    RAPID,
    USE_CUT,
    USE_RAPID,
    Toolpath,
    lines,
    path_length_mm,
)
import planning.toolpath.roughing.air as air_mod
from planning.toolpath.roughing.air import _exact_ends, _LevelAir
from planning.toolpath.roughing.clearance import _MoveClearance, min_tool_clearance
from planning.toolpath.roughing.clearing import (
    _contour_pieces,
    _hug,
    _line_pieces,
    _line_ys,
    _Piece,
)
from planning.toolpath.roughing.common import (
    _bounds,
    _check_points,
    _check_tool,
    _finite,
)
from planning.toolpath.roughing.entries import FEED_CLEAR_MM, _Entries, _entry_cfg
from planning.toolpath.roughing.links import (
    GAP_MM,
    _Level,
    _lift_cost,
    _retract,
    _Scratch,
    _Writer,
)
from planning.toolpath.roughing.maps import (
    HOLDER_GAP_MM,
    TOP_CELLS,
    Z_TOL_MM,
    _air_length,
    _coarse_max,
    _disc_any,
    _disc_max,
    _ForbiddenMap,
    _holder_pieces,
    _HolderMap,
    _MaterialMap,
    _Raster,
    _raster,
    _stamp_max,
    _stock_tops,
)
from planning.toolpath.roughing.ordering import _order
from planning.toolpath.roughing.regions import _region_runs

MAX_LEVELS = 10_000     #: most Z levels
#: With the contour pass, the clearing lines stop this many flat radii (at least half the cutter
#: radius) short of the part's walls, so that the contour cuts a band along them everywhere rather than
#: retracing the lines' ends (issue 30: most of the contour's feed in air was such retracing); with
#: the lines ``stepover_mm`` <= 1.2 Rt apart the band and the lines' discs still overlap
LINE_BACK_RT = 0.5

REMOVED_NOTE = ("Each set-up is roughed from the full stock box (the cloud's box in the set-up frame grown by the "
                "stock margin): material removed by earlier set-ups is not modelled, so lines may cut air.")
REST_NOTE = ("Rest roughing: the stock is the material left by the earlier set-ups (the caller's points on its "
             "boundary, its top per cell made hole-free by a disc of their spacing + one cell); lines are cut "
             "only within the tool radius + one cell of stock above each level.")


@dataclass(frozen=True)
class RoughingPath:
    """Z-level roughing of one set-up (mm, area frame; see :mod:`planning.toolpath.roughing`).

    ``toolpath``: the moves (tool tip, ``tip_offset_mm`` 0); ``levels_mm`` (n_levels,) tip heights
    from the top down (the last is the floor); ``n_levels``; ``length_mm``: length of the feed
    moves (cuts, links at a level, plunges, retracts); ``air_mm``: length of the rapids;
    ``n_retracts``: lifts off a level (within levels, between levels and the final one);
    ``level_retracts`` (n_levels,): lifts between two pieces of the same level;
    ``min_clearance_mm``: smallest distance between the tool solid along every move and any cloud
    point (:func:`~planning.toolpath.roughing.clearance.min_tool_clearance`; ``inf`` when no point
    comes within the tool radius); ``removed_mm3`` (n_levels,): the drop of the raster's
    remaining-material map at each level, mm^3 (cells wholly swept; the sum over the levels is a
    lower bound of the material removed); ``stock_box_mm`` (2,3): the stock box's lower and upper
    corners (the lower z is the lowest cloud point); ``cell_mm``: the raster cell used;
    ``stepover_mm``: the line spacing used; ``removed_note``: what the stock model leaves out.

    Rest roughing and entries: ``rest``: the stock was given (``stock_points_mm``) rather than the
    box; ``air_cut_mm``: length of the feed moves at a level (clearing, contours, feed links) along
    which the tool disc (radius Rt) meets no stock above the level, the stock as it was given (box or
    points; what this roughing cut before is not subtracted), mm; a lower bound: the disc must clear
    the stock by about 1.5 raster cells to count;
    ``stock_before_mm3`` / ``stock_after_mm3``: the volume of the remaining-material map above the
    floor over the coarse cells of the window's tool-centre cells, at the start and at the end (the
    map is an upper bound of the material, lowered only where a cell was wholly swept), mm^3;
    ``safe_z_mm``: the retract height cap used; ``entry``: the entry setting; ``n_helix``,
    ``n_ramps``, ``n_side_entries``: pieces entered by a helix, a ramp, or from the side (a plunge
    beside the material, then a feed in at the level); ``n_plunges_into_material``: straight
    plunges with remaining material above the level under the tool disc
    (:mod:`planning.toolpath.roughing.entries`; only with ``entry="plunge"``);
    ``n_pieces_left`` / ``left_length_mm``: pieces not cut because no side entry, helix or ramp
    fits (with a ``stock_view``, helix and ramp modes never plunge straight into material), and
    their length, mm. With a ``stock_view``: ``n_entered_in_air``: pieces whose start the maps
    put under material but the stock itself shows in air (entered by a feed straight down, no
    helix or ramp); ``n_fed_down``: helices and ramps begun by a straight feed down through the air
    to just above the material (ENTRY_FEED_GAP_MM) instead of descending from the rapid clearance;
    ``n_started_late``: helices and ramps begun at a later vertex of their way, where the column
    above it is air (:meth:`~planning.toolpath.roughing.entries._Entries._late_start`).

    Holder (``holder_pieces``): ``holder``: pieces were given; ``holder_blocked_cells``
    (n_levels,): per level, the raster cells the tool centre could have cut (in the window's reach,
    allowed by the forbidden map, rest roughing: near stock) but the holder blocks
    (:class:`~planning.toolpath.roughing.maps._HolderMap`); ``n_holder_blocked_cells``: their sum
    over the levels (cell-levels); ``deepest_cut_mm``: the lowest level at which anything was cut
    (NaN when nothing was), with or without the holder."""

    toolpath: Toolpath
    levels_mm: np.ndarray
    n_levels: int
    length_mm: float
    air_mm: float
    n_retracts: int
    min_clearance_mm: float
    removed_note: str
    level_retracts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    removed_mm3: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stock_box_mm: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))
    cell_mm: float = 0.0
    stepover_mm: float = 0.0
    rest: bool = False
    air_cut_mm: float = 0.0
    stock_before_mm3: float = 0.0
    stock_after_mm3: float = 0.0
    safe_z_mm: float = 0.0
    entry: str = "plunge"
    n_helix: int = 0
    n_ramps: int = 0
    n_side_entries: int = 0
    n_plunges_into_material: int = 0
    n_pieces_left: int = 0
    left_length_mm: float = 0.0
    n_entered_in_air: int = 0
    n_fed_down: int = 0
    n_started_late: int = 0
    holder: bool = False
    holder_blocked_cells: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    n_holder_blocked_cells: int = 0
    deepest_cut_mm: float = math.nan


def roughing_paths(cloud_frame, *, tool_radius_mm: float, corner_radius_mm: float = 0.0, step_down_mm: float = 2.0,
                   stock_allowance_mm: float = 0.5, stock_margin_mm: float = 2.0,
                   stepover_mm: float | None = None, pattern: str = "zigzag", contour: bool = True,
                   floor_z_mm: float | None = None, cell_mm: float | None = None,
                   safe_z_mm: float | None = None, window_xy_mm=None, window_reach_mm: float = 0.0,
                   stock_points_mm=None, stock_spacing_mm: float | None = None, entry: str = "helix",
                   entry_angle_deg: float = 3.0, entry_diameter_mm: float | None = None,
                   ramp_length_mm: float | None = None, holder_pieces=None, stock_view=None,
                   travel_cells=None, rapid_clearance_mm: float = 0.0,
                   progress: Callable[[int, int], None] | None = None) -> RoughingPath:
    """Z-level roughing of one set-up from a stock box or the stock left (mm, area frame; see
    :mod:`planning.toolpath.roughing`).

    ``cloud_frame`` (N,3): the whole cloud in the area frame (every point is an obstacle);
    ``tool_radius_mm`` Rt; ``corner_radius_mm`` rc (0: flat end mill, 0 < rc <= Rt: bull-nose);
    ``step_down_mm``: depth between levels; ``stock_allowance_mm``: least distance left between
    the tool and every cloud point; ``stock_margin_mm``: the stock box is the cloud's box grown by
    this on the sides and on the top; ``stepover_mm``: distance between clearing lines (default
    0.6 x diameter, at most the diameter); ``pattern``: ``"zigzag"`` or ``"oneway"`` (lines along
    +X only, rapid back); ``contour``: add the offset-contour pass; ``floor_z_mm``: lowest tip
    height (default lowest cloud z + allowance); ``cell_mm``: raster cell (default Rt / 16, at
    most Rt / 2); ``safe_z_mm``: retract height cap and first approach (default stock top + 5 mm);
    ``window_xy_mm`` (M,2): frame (x, y) positions, mm, that restrict the cut to a window: the
    tool centre (tip x, y) cuts only in raster cells whose centre lies within ``window_reach_mm``
    (mm, >= 0) of one of them (:func:`_window_cells`; the stock box, levels and retract heights
    are unchanged; the material outside is left for other set-ups); None (default): the whole
    stock box; ``progress(levels_done, n_levels)``.

    Rest roughing (module docstring): ``stock_points_mm`` (M,3): points in the area frame (mm)
    sampling the boundary of the material that is there now (e.g. the end points of a tri-dexel
    stock's material intervals), ``stock_spacing_mm`` (> 0, required with them): their sampling
    spacing, mm; None (default): the stock box, as before. Entries
    (:mod:`planning.toolpath.roughing.entries`): ``entry`` ``"helix"`` (default), ``"ramp"`` or
    ``"plunge"`` (straight plunges everywhere, the former behaviour); ``entry_angle_deg``: descent
    angle of helices and ramps from the horizontal, in (0, 45] degrees; ``entry_diameter_mm``: the
    diameter of the circle the tool centre runs on in a helix, in (0, 2 x cutter diameter) mm (None:
    70 % of the cutter diameter); ``ramp_length_mm``: the longest ramp leg, >= Rt, mm (None: twice
    the cutter diameter).

    ``stock_view`` (rest roughing only; issue 30 item 1): a
    :class:`planning.toolpath.stock_view.StockView` of the stock in this frame (its own copy). Given,
    the roughing reads the material from the stock model itself and cuts the view with every level's
    moves before it plans the next: a level cuts only the cells within Rt + h of material between
    it and the level above (the cloud's points count as material), and the first level comes from
    the stock's tops; at the start of every level the remaining-material map and the entries' tops
    are lowered to what the view says is left (grown by half a ray spacing's diagonal + one cell, so
    they stay upper bounds of the view's material). So no feed runs in the air beside steep stock
    faces, under the stock's overhangs (the underside of a block tilted with the set-up), in the
    holes earlier set-ups cut or below the stock, and entries and lifts meet the material that is
    there, not the bound of it. None (default): the points' conservative top for all of it, down to
    the floor, lowered only where the map saw a cell wholly swept.

    ``travel_cells`` (issue 30: planned where the machine goes, not cut out afterwards):
    ``travel_cells(x0, y0, h, nx, ny, z)`` -> (nx, ny) bool, the raster cells whose centre, as a tool
    tip at frame height ``z``, the machine reaches within its travel (and with the lift to the
    retract height); a level cuts only those. None (default): travel not known.
    The stock view's obstacles (fixtures, the riser, the table: what is never cut), when it has them:
    their top per cell from their boundary points (as the stock's, never too low) counts as material
    that never goes: no tool centre comes within ``Rt`` + HOLDER_GAP_MM of one above its tip less that
    gap, the holder keeps HOLDER_GAP_MM above them (they are in the remaining-material map, which the
    holder map reads), and lifts, links and entries go over them. Without them the guard alone keeps
    the tool off the obstacles.
    ``rapid_clearance_mm`` (>= 0, default 0): how far every rapid keeps its tool from the material (the
    guard's and the verification's rapid clearance; with a ``stock_view`` only): the retracts feed up,
    the rapids down stop and the rapids across rise where the tool grown by it clears the view
    brought up to date with the moves so far and the obstacles (the guard's own tests,
    :meth:`planning.toolpath.stock_view.StockView.column_clear_z` and ``rapid_clear_z``).

    Holder: ``holder_pieces``: the non-cutting solids above the tip, a sequence of ``(z0_mm,
    z1_mm, radius_mm)`` cylinders from z0 to z1 (may be inf) above the tip, as
    :attr:`planning.simulate.motion.ToolShape.pieces` (e.g. ``roughing_shape(...).pieces``: the
    holder from the stick-out up); None (default) or empty: the tool is the cutter's cylinder
    continued upwards, as before. Given, at every level the tool centre keeps out of the cells where
    a piece would meet the cloud (within its radius + the allowance, above its bottom - the
    allowance) or the remaining material (within its radius, above its bottom - HOLDER_GAP_MM),
    and the lifts rise so that the pieces clear the material
    (:class:`~planning.toolpath.roughing.maps._HolderMap`): where the holder cannot follow, the
    roughing stops going deeper and the material is left.
    """
    pts, Rt, rc, step, a, margin, s, h = _check_args(cloud_frame, tool_radius_mm, corner_radius_mm, step_down_mm,
                                                      stock_allowance_mm, stock_margin_mm, stepover_mm, pattern,
                                                      cell_mm)
    cfg = _entry_cfg(entry, entry_angle_deg, entry_diameter_mm, ramp_length_mm, Rt)
    pieces = _holder_pieces(()) if holder_pieces is None else _holder_pieces(holder_pieces)
    rest = stock_points_mm is not None
    if rest:
        spts, spacing = _check_stock(stock_points_mm, stock_spacing_mm)
    elif stock_spacing_mm is not None:
        raise ParameterError("stock_spacing_mm is given without stock_points_mm")
    stock = _stock(pts, a, margin, floor_z_mm, safe_z_mm, rest)
    grid = _raster(pts, stock.box_lo, stock.box_hi, Rt, h, extra_mm=2 * Rt + 3 * h if rest else 0.0)
    h = grid.h
    win = None
    if window_xy_mm is not None:
        win = _window_cells(grid, window_xy_mm, window_reach_mm)
        grid = replace(grid, inbox=grid.inbox & win)
    obs = None
    if rest and stock_view is not None and stock_view.obstacles is not None:
        opts = stock_view.obstacle_points()
        opts = opts[opts[:, 2] > float(stock.floor) - Rt - HOLDER_GAP_MM - h]      # those a tool can meet
        if opts.shape[0]:
            obs = _stock_tops(opts, grid, spacing)
    if rest:
        fine = _stock_tops(spts, grid, spacing, floor_map=grid.cmax)
        if obs is not None:            # never cut: material for the map, the holder, lifts and entries
            fine = np.maximum(fine, obs)
        read, slab, live = fine, None, None
        if stock_view is not None:                     # the stock's own top: where there is material to cut
            read = stock_view.tops(grid.x0, grid.y0, h, grid.nx, grid.ny, fine + h, stock.floor - Rt)
            read = np.maximum(np.where(fine > -np.inf, read, -np.inf), grid.cmax)
            slab = _slab_reader(stock_view, grid, fine, Rt)
            live = _LiveStock(stock_view, grid, read, Rt, rapid_clearance_mm, obs)
        near = _disc_max(read, h, Rt + h)              # material above z within Rt + h of a tool centre
        reach = near[grid.inbox]
        z_top = float(reach.max()) if reach.size else -math.inf
        lo_r = np.array([grid.x0, grid.y0])
        hi_r = lo_r + h * np.array([grid.nx, grid.ny])
        mat = _MaterialMap(grid, lo_r, hi_r, None, Rt, top0=_coarse_max(fine))
        stock = _rest_stock(stock, z_top, mat, safe_z_mm)
        levels = _levels(stock.z_top, stock.floor, step, step_down_mm) if stock.z_top > stock.floor + Z_TOL_MM \
            else np.zeros(0)
    else:
        fine = near = slab = live = None
        mat = _MaterialMap(grid, stock.box_lo, stock.box_hi, stock.z_top, Rt)
        levels = _levels(stock.z_top, stock.floor, step, step_down_mm)
    ys = _line_ys(stock.box_lo, stock.box_hi, grid.h, Rt, rc, s)
    hug = None
    if slab is not None and contour:   # on the stock view: the contour's steps away from the walls taken out
        chords = _MoveClearance(pts, Rt, rc)

        def hug(pieces_, z_):
            return _hug(pieces_, chords.keeps, z_, a, h)
    forb = _ForbiddenMap(grid.cmax, grid.h, Rt, rc, a, stock.big)
    ent = _Entries(cfg, mat, fine, forb.G, Rt, rc, edge=(Rt + h) if rest else h, win=win)
    # on the stock view, the map is read on one ray family; the other two may keep slivers of up to
    # a ray spacing that the simulation's holder check sees: the holder keeps that much more gap
    gap = HOLDER_GAP_MM + (float(stock_view.resolution_mm) if stock_view is not None else 0.0)
    hold = _HolderMap(pieces, grid, mat, a, Rt, stock.big, win, gap_mm=gap) if pieces.shape[0] else None
    wmask = _coarse_max(grid.inbox.astype(np.float64)) > 0      # coarse cells of the window's tool centres
    before = mat.volume_above(stock.floor, wmask)
    w, cur, level_retracts, removed, blocked, deepest = _cut_levels(levels, grid, forb, mat, ys, pattern == "oneway",
                                                                    contour, stock.safe, Rt, rc, progress, ent, near,
                                                                    stock.z_top, hold, slab, travel_cells,
                                                                    live,
                                                                    None if obs is None else
                                                                    _disc_max(obs, h, Rt + HOLDER_GAP_MM + h), hug)
    air_top = fine if rest else _box_tops(grid, stock)
    return _result(pts, w, cur, levels, level_retracts, removed, stock, Rt, rc, grid.h, s,
                   rest=rest, ent=ent, air_top=air_top, before=before, after=mat.volume_above(stock.floor, wmask),
                   holder=hold is not None, blocked=blocked, deepest=deepest)


def _check_args(cloud_frame, tool_radius_mm, corner_radius_mm, step_down_mm, stock_allowance_mm, stock_margin_mm,
                stepover_mm, pattern, cell_mm):
    """The checked arguments of :func:`roughing_paths` (the first wrong one raises
    :class:`~planning.errors.ParameterError`): (points, Rt, rc, step down, allowance, margin,
    stepover, cell)."""
    pts = _check_points(cloud_frame)
    Rt, rc = _check_tool(tool_radius_mm, corner_radius_mm)
    step = _finite("step_down_mm", step_down_mm)
    a = _finite("stock_allowance_mm", stock_allowance_mm)
    margin = _finite("stock_margin_mm", stock_margin_mm)
    if not step > 0:
        raise ParameterError(f"step_down_mm = {step_down_mm}: the depth of cut must be > 0 mm")
    if not a >= 0:
        raise ParameterError(f"stock_allowance_mm = {stock_allowance_mm}: must be >= 0 mm")
    if not margin >= 0:
        raise ParameterError(f"stock_margin_mm = {stock_margin_mm}: must be >= 0 mm")
    s = 1.2 * Rt if stepover_mm is None else _finite("stepover_mm", stepover_mm)
    if not 0 < s <= 2 * Rt:
        raise ParameterError(f"stepover_mm = {stepover_mm}: must be in (0, {2 * Rt}] mm (at most the tool "
                             f"diameter, or stock is left between the lines)")
    if pattern not in ("zigzag", "oneway"):
        raise ParameterError(f"pattern = {pattern!r}: must be 'zigzag' or 'oneway'")
    h = Rt / 16.0 if cell_mm is None else _finite("cell_mm", cell_mm)
    if not 0 < h <= Rt / 2:
        raise ParameterError(f"cell_mm = {cell_mm}: must be in (0, {Rt / 2}] mm (half the tool radius)")
    return pts, Rt, rc, step, a, margin, s, h


def _window_cells(grid: _Raster, window_xy_mm, window_reach_mm: float) -> np.ndarray:
    """(nx, ny) bool: the raster cells whose centre lies within ``window_reach_mm`` (mm) of a point
    of ``window_xy_mm`` (M,2, frame x, y, mm), exactly (points off the raster are ignored; the
    caller's points are cloud points, which the raster covers). The cells of the points are
    marked and their Euclidean distance transform taken: a cell centre is within h / sqrt(2) of
    the points of its cell, so cells whose distance to a marked cell centre is at most
    ``reach - h / sqrt(2)`` are in, those farther than ``reach + h / sqrt(2)`` out, and the thin
    ring in between is decided by a k-d tree of the points."""
    xy = np.asarray(window_xy_mm, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise ParameterError("window_xy_mm must be a finite (M,2) array of frame x, y positions, mm")
    reach = _finite("window_reach_mm", window_reach_mm)
    if not reach >= 0:
        raise ParameterError(f"window_reach_mm = {window_reach_mm}: must be >= 0 mm")
    h, nx, ny = grid.h, grid.nx, grid.ny
    ij = np.floor((xy - np.array([grid.x0, grid.y0])) / h).astype(np.int64)
    on = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
    marked = np.zeros((nx, ny), dtype=bool)
    marked[ij[on, 0], ij[on, 1]] = True
    if not marked.any():
        return marked
    d = ndimage.distance_transform_edt(~marked, sampling=h)
    slack = h / math.sqrt(2.0)
    inside = d <= reach - slack
    ring = np.argwhere((d <= reach + slack) & ~inside)
    if ring.shape[0]:
        centres = np.column_stack([grid.x0 + (ring[:, 0] + 0.5) * h, grid.y0 + (ring[:, 1] + 0.5) * h])
        dist, _ = cKDTree(xy[on]).query(centres, k=1, distance_upper_bound=reach * (1 + 1e-12) + 1e-12)
        ok = np.isfinite(dist)
        inside[ring[ok, 0], ring[ok, 1]] = True
    return inside


def _check_stock(stock_points_mm, stock_spacing_mm):
    """The checked rest-roughing stock: (points (M,3) mm, spacing mm)."""
    p = np.asarray(stock_points_mm, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ParameterError(f"stock_points_mm must be an (M,3) array of points in mm (got shape {p.shape})")
    if not np.all(np.isfinite(p)):
        raise ParameterError("stock_points_mm holds NaN or infinite coordinates")
    if stock_spacing_mm is None:
        raise ParameterError("stock_spacing_mm (the spacing of stock_points_mm, mm) is required with stock_points_mm")
    sp = _finite("stock_spacing_mm", stock_spacing_mm)
    if not sp > 0:
        raise ParameterError(f"stock_spacing_mm = {stock_spacing_mm}: must be > 0 mm")
    return np.ascontiguousarray(p), sp


@dataclass(frozen=True)
class _Stock:
    """The stock of one set-up (mm): ``lo`` (3,) the cloud's lowest coordinates, ``big`` its
    largest |coordinate|; ``z_top`` the stock top (rest roughing: the highest the window's tool
    centres reach, where the levels start), ``floor`` the lowest tip height, ``safe`` the retract
    height cap; ``box_lo``, ``box_hi`` (2,) the stock box's XY corners."""

    lo: np.ndarray
    big: float
    z_top: float
    floor: float
    safe: float
    box_lo: np.ndarray
    box_hi: np.ndarray


def _stock(pts, a, margin, floor_z_mm, safe_z_mm, rest=False) -> _Stock:
    """The stock box (the cloud's box grown by ``margin`` on the sides and the top), the floor and
    the safe height, checked (rest roughing: the top and the safe height are set by
    :func:`_rest_stock`)."""
    lo, hi, big = _bounds(pts)
    z_top = float(hi[2]) + margin
    floor = float(lo[2]) + a if floor_z_mm is None else _finite("floor_z_mm", floor_z_mm)
    if rest:
        safe = math.inf if safe_z_mm is None else _finite("safe_z_mm", safe_z_mm)
        return _Stock(lo, big, z_top, floor, safe, lo[:2] - margin, hi[:2] + margin)
    if not floor < z_top:
        raise ParameterError(f"floor_z_mm = {floor}: must be below the stock top {z_top} mm")
    safe = z_top + 5.0 if safe_z_mm is None else _finite("safe_z_mm", safe_z_mm)
    if not safe > z_top:
        raise ParameterError(f"safe_z_mm = {safe}: must be above the stock top {z_top} mm (the highest cloud "
                             f"point + stock_margin_mm)")
    box_lo = lo[:2] - margin
    box_hi = hi[:2] + margin
    return _Stock(lo, big, z_top, floor, safe, box_lo, box_hi)


def _rest_stock(stock: _Stock, z_top, mat: _MaterialMap, safe_z_mm) -> _Stock:
    """Rest roughing: the stock with ``z_top`` (where the levels start: the highest stock top the
    window's tool centres reach) and the safe height: the given one (default the highest material
    of the map + 5 mm), raised to GAP_MM above the highest material of the map where that is
    higher (so that every rapid at it is clear)."""
    fin = mat.top[np.isfinite(mat.top)]
    top_all = float(fin.max()) if fin.size else z_top
    if not math.isfinite(top_all):
        top_all = stock.floor
    safe = top_all + 5.0 if safe_z_mm is None else stock.safe
    if not safe > stock.floor:
        raise ParameterError(f"safe_z_mm = {safe_z_mm}: must be above the floor {stock.floor} mm")
    safe = max(safe, top_all + GAP_MM)
    z_top = float(z_top) if math.isfinite(z_top) else stock.floor     # no stock: no level
    return replace(stock, z_top=z_top, safe=float(safe))


def _box_tops(grid: _Raster, stock: _Stock) -> np.ndarray:
    """The stock box's top per raster cell (``z_top`` where the cell overlaps the box's XY, -inf
    elsewhere), for the air measure."""
    ex = grid.x0 + np.arange(grid.nx + 1) * grid.h                 # cell edges
    ey = grid.y0 + np.arange(grid.ny + 1) * grid.h
    inx = (ex[1:] > stock.box_lo[0]) & (ex[:-1] < stock.box_hi[0])
    iny = (ey[1:] > stock.box_lo[1]) & (ey[:-1] < stock.box_hi[1])
    return np.where(inx[:, None] & iny[None, :], stock.z_top, -np.inf)


def _levels(z_top, floor, step, step_down_mm) -> np.ndarray:
    """The tip heights: every ``step`` from the stock top down, the last at the floor (a level
    within Z_TOL_MM above the floor is dropped); at most MAX_LEVELS."""
    if (z_top - floor) / step > MAX_LEVELS:
        raise ParameterError(f"step_down_mm = {step_down_mm}: {(z_top - floor) / step:.0f} levels from the stock top "
                             f"{z_top} to the floor {floor} mm; at most {MAX_LEVELS}")
    levels = []
    k = 1
    while z_top - k * step > floor + Z_TOL_MM:
        levels.append(z_top - k * step)
        k += 1
    levels.append(floor)
    return np.array(levels)


def _crop(grid: _Raster, margin_mm: float, align: int = 1) -> tuple[slice, slice]:
    """The raster's cells within ``margin_mm`` (+ one cell) of the bounding box of its tool-centre
    cells (``grid.inbox``: the window, the box), the box's corners on multiples of ``align`` cells:
    what a level's reading of the stock needs to cover."""
    ii = np.flatnonzero(grid.inbox.any(axis=1))
    jj = np.flatnonzero(grid.inbox.any(axis=0))
    if ii.size == 0:
        return slice(0, 0), slice(0, 0)
    m = int(math.ceil(margin_mm / grid.h)) + 1
    i0, i1 = max(0, int(ii[0]) - m), min(grid.nx, int(ii[-1]) + 1 + m)
    j0, j1 = max(0, int(jj[0]) - m), min(grid.ny, int(jj[-1]) + 1 + m)
    i0, j0 = i0 - i0 % align, j0 - j0 % align
    i1 = min(grid.nx, -(-i1 // align) * align)
    j1 = min(grid.ny, -(-j1 // align) * align)
    return slice(i0, i1), slice(j0, j1)


class _LiveStock:
    """The stock view (:class:`planning.toolpath.stock_view.StockView`) kept level with the roughing:
    :meth:`advance` runs the moves written since the last call on the view, reads the material left
    above the next level and lowers the remaining-material map (to the reading grown by about a ray
    spacing across: an upper bound of the material on the ray family read, which the lifts and the
    holder map need; the other two families may keep slivers up to a ray spacing above it, which the
    holder map's gap covers) and the entries' tops (to the
    reading itself: where a helix or ramp starts; the rapid down to it is checked on the view) to it."""

    def __init__(self, view, grid: _Raster, read, Rt: float, clearance_mm: float = 0.0, obstacles=None):
        self.view, self.grid, self.Rt = view, grid, float(Rt)
        self.obstacles = obstacles            # the obstacles' top per cell (never cut), or None
        self.clearance_mm = float(clearance_mm)
        self.top = np.array(read, dtype=np.float64)        # the view's top per cell, as last read
        self.k = 0                                         # blocks of the writer already run on the view
        self.last = None
        self.grow = float(view.resolution_mm) + grid.h   # the walk reads a ray within ~0.9 spacing
        self.inner = self.outer = None

    def sync(self, w) -> None:
        """Run the moves ``w`` has written since the last call on the view (its blocks of points from
        the first one not run yet)."""
        if len(w.pts) <= self.k:
            return
        new = np.concatenate(w.pts[self.k:])
        rapid = np.repeat(np.array(w.codes[self.k:], np.int8), w.counts[self.k:]) == USE_RAPID
        start = np.concatenate([new[:1] if self.last is None else self.last[None, :], new[:-1]])
        self.view.cut(start, new, rapid)
        self.k, self.last = len(w.pts), new[-1].copy()

    def column_clear(self, w, clearance_mm: float):
        """The writer's ``column_clear(x, y, z, top)`` (:class:`~planning.toolpath.roughing.links._Writer`):
        the lowest height at or above z from which a rapid straight up to ``top`` keeps the tool
        ``clearance_mm`` from the material, on the view brought up to date with ``w``'s moves."""
        def clear(x, y, z, top):
            self.sync(w)
            return float(self.view.column_clear_z(np.array([[x, y, z]]), top, clearance_mm)[0])
        return clear

    def material_rise(self, w, shrink_mm: float):
        """``rise(xy, z, top)`` -> the highest frame height at which the cutter (its flutes, without the
        shank and holder pieces) narrowed by ``shrink_mm`` and moved straight up from (x, y, z) to
        ``top`` for every x, y of ``xy`` (k,2), meets the view's material or the obstacles (the view
        brought up to date with ``w``'s moves; :func:`planning.simulate.dexel.column_rise`, at most
        its tolerance above the exact height); -inf where it meets none. Where a helix or ramp above
        those points begins to cut more than a ring of ``shrink_mm`` at its rim (the allowance the
        levels above left on a wall beside the tool, which the whole descent rubs)."""
        from planning.simulate.dexel import column_rise

        sh = self.view.shape
        r = max(sh.radius_mm - shrink_mm, 0.5 * sh.radius_mm)
        cutter = replace(sh, pieces=(), radius_mm=r, corner_radius_mm=min(sh.corner_radius_mm, r))
        axis = self.view.frame.rotation[2]

        def rise(xy, z, top):
            self.sync(w)
            xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
            if xy.shape[0] == 0 or not top > z:
                return -math.inf
            tips = self.view.frame.to_part(np.column_stack([xy, np.full(xy.shape[0], float(z))]))
            out = -math.inf
            for model in (self.view.stock, self.view.obstacles):
                if model is not None:
                    s = column_rise(model, tips, axis, float(top) - float(z), cutter)
                    out = max(out, float(s.max()))
            return float(z) + out if math.isfinite(out) else -math.inf
        return rise

    def meets(self, w):
        """``meets(a (k,2), b (k,2), z) -> (k,) bool``: whether the cutter (its flutes, without the shank
        and holder pieces), its tip at height z, moved from a to b meets the view's material deeper than
        :data:`~planning.toolpath.roughing.air.MEET_DEPTH_MM` (the view brought up to date with ``w``'s
        moves; :func:`planning.simulate.dexel.collide`, the simulation's own kernel)."""
        from planning.simulate.dexel import collide

        sh = self.view.shape
        cutter = replace(sh, pieces=())
        axis = self.view.frame.rotation[2]

        def meets(a, b, z):
            self.sync(w)
            a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
            b = np.asarray(b, dtype=np.float64).reshape(-1, 2)
            zz = np.full((a.shape[0], 1), float(z))
            s = self.view.frame.to_part(np.hstack([a, zz]))
            e = self.view.frame.to_part(np.hstack([b, zz]))
            ax = np.broadcast_to(axis, s.shape)
            return collide(self.view.stock, s, e, ax, cutter, which="tool") > air_mod.MEET_DEPTH_MM
        return meets

    def column_clear_many(self, w, clearance_mm: float):
        """The writer's ``column_clear_many(points (n,3), top)``: :meth:`column_clear` of n tips at once."""
        def clear(points, top):
            self.sync(w)
            return self.view.column_clear_z(np.asarray(points, dtype=np.float64).reshape(-1, 3), top, clearance_mm)
        return clear

    def column_is_clear(self, w, clearance_mm: float):
        """``clear(x, y, z, top)`` -> bool: whether the tool at (x, y, z), moved straight up to ``top``,
        keeps ``clearance_mm`` from the material (the view brought up to date with ``w``'s moves; one
        swept test, :meth:`planning.toolpath.stock_view.StockView.column_is_clear`)."""
        def clear(x, y, z, top):
            self.sync(w)
            return self.view.column_is_clear((x, y, z), top, clearance_mm)
        return clear

    def rapid_clear(self, w, clearance_mm: float):
        """The writer's ``rapid_clear(a, b, z, top)``: the lowest height at or above z at which a rapid
        across from a to b keeps the tool ``clearance_mm`` from the material (the view, up to date)."""
        def clear(a, b, z, top):
            if not z < top:
                return float(top)
            self.sync(w)
            return self.view.rapid_clear_z(a, b, z, top, clearance_mm)
        return clear

    def _boundary_tops(self, oi: slice, oj: slice, stop: float) -> np.ndarray:
        """(cells of ``oi`` x ``oj``) the highest boundary point of the view's stock above ``stop`` per
        cell, every ray family (:func:`planning.simulate.heightfield.boundary_tops_in_frame`); -inf
        where none."""
        from planning.simulate.heightfield import boundary_tops_in_frame

        g, v = self.grid, self.view
        return boundary_tops_in_frame(v.stock, v.frame.rotation, v.frame.origin_mm, g.x0 + oi.start * g.h,
                                      g.y0 + oj.start * g.h, g.h, oi.stop - oi.start, oj.stop - oj.start, stop)

    def advance(self, w, z: float, mat: _MaterialMap, ent: _Entries) -> None:
        """Run the moves so far on the view and lower the map and the entries' tops for level ``z``,
        over the cells about the window (:func:`_crop`: the tool centres' box grown by ``3 Rt``, what
        lifts, side entries and helices reach; the cells beyond keep their older, higher tops)."""
        g = self.grid
        self.sync(w)
        if self.inner is None:
            self.inner = _crop(g, 3.0 * self.Rt, TOP_CELLS)
            self.outer = _crop(g, 3.0 * self.Rt + self.grow + g.h, TOP_CELLS)
        (oi, oj), (ii, ij) = self.outer, self.inner
        if oi.stop <= oi.start or oj.stop <= oj.start:
            return
        # the material left above this level (it only ever goes down: read from the last top down;
        # where nothing is above the stop, the stop bounds what may be left below it)
        stop = z - g.h
        # (the kernels take whole arrays and the crop's corner: a view of a crop is contiguous or not
        # with the crop's width, and each layout would be a compilation of its own)
        top = self.view.tops(g.x0 + oi.start * g.h, g.y0 + oj.start * g.h, g.h, oi.stop - oi.start,
                             oj.stop - oj.start, _read_start(self.top, oi.start, oj.start, oi.stop - oi.start,
                                                             oj.stop - oj.start), stop)
        _lower_tops(self.top, oi.start, oj.start, top, stop, _c(g.cmax))
        # an upper bound of the view's material, kept over the inner cells (their discs lie in the outer)
        bound_o = _disc_max(self.top[oi, oj], g.h, self.grow)
        # the line along the frame's Z is read on one ray family and misses slivers thinner than a ray
        # spacing that only the other two hold (a skin the levels above left on a wall, 0.25 mm thick on
        # the range femur, 30 mm above the level, which the holder met): the stock's boundary points,
        # every family, grown as the first reading was (:func:`_stock_tops`), keep the bound above them
        _stamp_max(bound_o, self._boundary_tops(oi, oj, stop), self.top[oi, oj], g.h, self.grow)
        ci = slice(ii.start // TOP_CELLS, -(-ii.stop // TOP_CELLS))
        cj = slice(ij.start // TOP_CELLS, -(-ij.stop // TOP_CELLS))
        if ent.use_fine and ent.fine_start is None:     # the entries' own arrays (``fine`` is the caller's), once
            ent.fine = np.array(ent.fine)
            ent.fine_start = ent.fine.copy()
        # over the inner cells (their discs lie in the outer): the bound and the reading raised to the
        # obstacles; the material map lowered to the bound's maximum per coarse cell; with the entries'
        # fine maps, whether there is material under the tool: the bound; where a helix or ramp starts:
        # the material as read (not grown: beside a wall the growth reaches the part's top), the rapid
        # down to it being checked on the view
        empty = np.zeros((0, 0))
        for a in (self.top, mat.top) + ((ent.fine, ent.fine_start) if ent.use_fine else ()):
            if not (a.flags.c_contiguous and a.dtype == np.float64):
                raise AssertionError("the live stock's maps are changed in place: C-contiguous float arrays")
        if mat.top[ci, cj].shape != (-(-(ii.stop - ii.start) // TOP_CELLS), -(-(ij.stop - ij.start) // TOP_CELLS)):
            raise AssertionError("the material map's coarse cells do not cover the inner cells")
        _lower_maps(bound_o, ii.start - oi.start, ij.start - oj.start, self.top, ii.start, ij.start,
                    ii.stop - ii.start, ij.stop - ij.start, empty if self.obstacles is None else _c(self.obstacles),
                    mat.top, ci.start, cj.start, TOP_CELLS, ent.fine if ent.use_fine else empty,
                    ent.fine_start if ent.use_fine else empty)


def _c(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-contiguous float array (itself when it is one): the layout the kernels below are
    compiled for."""
    return np.ascontiguousarray(a, dtype=np.float64)


@njit(cache=True, nogil=True)
def _read_start(top, i0, j0, ni, nj):
    """Where :meth:`_LiveStock.advance` starts reading each cell of the crop (``ni`` x ``nj`` cells of
    ``top`` from (i0, j0)): just above its last top (-inf: none)."""
    out = np.empty((ni, nj))
    for i in range(ni):
        for j in range(nj):
            v = top[i0 + i, j0 + j]
            out[i, j] = v + 1e-9 if v > -np.inf else -np.inf
    return out


@njit(cache=True, nogil=True)
def _lower_tops(top, i0, j0, read, stop, cmax):
    """``top`` over the crop of ``read``'s shape from (i0, j0), in place, lowered to the new reading
    (where the reading met nothing above ``stop``, to the stop: what is left lies below it), never below
    ``cmax`` (the part itself)."""
    for i in range(read.shape[0]):
        for j in range(read.shape[1]):
            r = read[i, j]
            t = top[i0 + i, j0 + j]
            if not np.isfinite(r):
                r = min(t, stop) if t > -np.inf else -np.inf
            top[i0 + i, j0 + j] = max(r, cmax[i0 + i, j0 + j])


@njit(cache=True, nogil=True)
def _lower_maps(bound_o, di, dj, top, i0, j0, ni, nj, obstacles, mat_top, c0, d0, k, fine, fine_start):
    """:meth:`_LiveStock.advance`'s last step over the inner cells (``ni`` x ``nj`` cells from (i0, j0)
    of the raster's arrays ``top``, ``obstacles``, ``fine`` and ``fine_start``; the bound at
    ``bound_o[di + i, dj + j]``): the bound and the reading ``top`` raised to ``obstacles`` (when not
    empty); ``mat_top`` (coarse cells of k x k, the inner box's corner at coarse cell (c0, d0); in
    place) lowered to the bound's maximum per coarse cell; ``fine`` lowered to the bound and
    ``fine_start`` to the lowered ``fine`` and the reading (both in place, when not empty)."""
    obs = obstacles.shape[0] > 0
    use_fine = fine.shape[0] > 0
    nci, ncj = -(-ni // k), -(-nj // k)
    coarse = np.full((nci, ncj), -np.inf)
    for i in range(ni):
        for j in range(nj):
            b = bound_o[di + i, dj + j]
            r = top[i0 + i, j0 + j]
            if obs:
                b = max(b, obstacles[i0 + i, j0 + j])
                r = max(r, obstacles[i0 + i, j0 + j])
            if b > coarse[i // k, j // k]:
                coarse[i // k, j // k] = b
            if use_fine:
                f = min(fine[i0 + i, j0 + j], b)
                fine[i0 + i, j0 + j] = f
                fine_start[i0 + i, j0 + j] = min(f, r)
    for i in range(nci):
        for j in range(ncj):
            mat_top[c0 + i, d0 + j] = min(mat_top[c0 + i, d0 + j], coarse[i, j])


def _slab_reader(view, grid: _Raster, fine, Rt: float):
    """``slab(z, z_above)`` -> ((nx, ny) bool, (nx, ny) bool): the raster cells within ``Rt + h`` (the
    level's region: where a tool centre may meet material) of a cell that has material, and the cells
    that have material: whose line along the frame's Z meets the stock (the stock view's
    :meth:`tops`) or the cloud between the heights z and ``z_above`` (inf: anywhere above z)."""
    h, nx, ny = grid.h, grid.nx, grid.ny

    ci, cj = _crop(grid, Rt + 2.0 * h)          # the tool centres' cells and the material their discs reach

    def slab(z, z_above):
        near, has = np.zeros((nx, ny), dtype=bool), np.zeros((nx, ny), dtype=bool)
        if ci.stop <= ci.start or cj.stop <= cj.start:
            return near, has
        f = fine[ci, cj]
        start = f + h if not math.isfinite(z_above) else np.minimum(f + h, z_above)
        tops = view.tops(grid.x0 + ci.start * h, grid.y0 + cj.start * h, h, ci.stop - ci.start, cj.stop - cj.start,
                         start, z)
        cm = grid.cmax[ci, cj]
        has[ci, cj] = np.isfinite(tops) | ((cm > z) & (cm < z_above))
        near[ci, cj] = _disc_any(has[ci, cj], h, Rt + h)
        return near, has
    return slab


#: With the stock read exactly, a helix or ramp starts this far above the rapid clearance over the
#: material under it (mm).
ENTRY_GAP_EXTRA_MM = 0.15


def _cut_levels(levels, grid: _Raster, forb: _ForbiddenMap, mat: _MaterialMap, ys, oneway, contour, safe, Rt, rc,
                progress, ent: _Entries, near=None, z_top=math.inf, hold: _HolderMap | None = None, slab=None,
                travel=None, live=None, obstacle_near=None, hug=None):
    """Cut every level from the top down: its region (rest roughing, ``near`` not None: only the
    cells whose ``near`` is above the level; ``hold`` not None: without the cells the holder
    blocks, and lifts that keep the holder clear; ``slab`` not None: only the cells ``slab(z, z_above)``
    gives, within reach of material between the level and the one above, so that no level cuts
    under an overhang of the stock or in a hole cut by an earlier set-up; ``obstacle_near`` not
    None: without the cells where it (the obstacles' top within Rt + HOLDER_GAP_MM) is above the
    level less that gap; ``live`` not None: the
    moves of every level run on the stock view before the next level is planned
    (:class:`_LiveStock`); ``travel`` not None: only the cells within the machine's travel at the level;
    ``hug`` not None: ``hug(pieces, z)`` gives the level's pieces with the contours' steps away from the
    walls taken out, :func:`~planning.toolpath.roughing.clearing._hug`), pieces,
    order, links and entries, lowering the
    remaining material along the cut. Returns (the moves, the last tip (None when nothing was
    cut), lifts within each level, the volume removed at each level, the cells the holder blocked
    at each level, the lowest level cut (NaN when none))."""
    x0, y0, h, nx, ny = grid.x0, grid.y0, grid.h, grid.nx, grid.ny
    w = _Writer()
    ent.exact = live is not None
    if live is not None:
        ent.gap = min(GAP_MM, live.clearance_mm + ENTRY_GAP_EXTRA_MM)
        ent.clear = live.column_is_clear(w, FEED_CLEAR_MM)
        ent.rise = live.material_rise(w, grid.h)
    if live is not None and live.clearance_mm > 0:
        w.gap = ent.gap
        w.column_clear = live.column_clear(w, live.clearance_mm)
        w.column_clear_many = live.column_clear_many(w, live.clearance_mm)
        w.rapid_clear = live.rapid_clear(w, live.clearance_mm)
    cur = None                    # current tip (x, y, z)
    level_retracts = np.zeros(levels.size, np.int64)
    removed = np.zeros(levels.size)
    blocked = np.zeros(levels.size, np.int64)
    deepest = math.nan
    region = np.empty((nx, ny), dtype=bool)
    top_dil = None
    scratch = _Scratch(nx * ny)
    for li, z in enumerate(levels):
        if live is not None and li:    # the levels above cut on the view; the maps lowered to what is left
            live.advance(w, float(z), mat, ent)
            top_dil = None
        thr = forb.threshold(z)
        limit = grid.inbox if near is None else grid.inbox & (near > z + Z_TOL_MM)
        air = None
        if slab is not None:
            near_z, has = slab(float(z), float(levels[li - 1]) if li else math.inf)
            limit = limit & near_z
            air = _LevelAir(has, x0, y0, h, Rt, Rt - rc)
            if live is not None and air_mod.EXACT_ENDS:
                air.meets = live.meets(w)
        reach = None
        if travel is not None:
            reach = travel(x0, y0, h, nx, ny, float(z))
            limit = limit & reach
        if obstacle_near is not None:  # no cutter within Rt + the gap of a fixture, the riser or the table
            limit = limit & ~(obstacle_near > z - HOLDER_GAP_MM)
        if hold is not None:         # the map at the start of the level: an upper bound of the material during it
            blocked[li] = hold.level(limit, forb.G, thr, z, mat, cur, top_dil is None)
            limit = hold.limit
            ent.win, ent.use_win = hold.ok, True
        runs = _region_runs(forb.G, thr, limit, region)
        if top_dil is None:
            top_dil = mat.dilated()
        if runs[1].size:
            lv = _Level(region, x0, y0, h, nx, ny, float(z), top_dil, mat.H, Rt, scratch,
                        hold=None if hold is None else hold.HT, reach=reach)
            # on the stock view, with the contour pass, the lines keep LINE_BACK_RT x the flat radius off the
            # part's walls: the contour then cuts that band all along (not the thin scallops between the
            # lines' ends); on the box or the points alone the lines run up to the walls as before
            lines_at = region
            if contour and slab is not None:
                lines_at = _off_walls(region, forb.G, thr, h, LINE_BACK_RT * max(Rt - rc, 0.5 * Rt))
            pieces = _line_pieces(lines_at, runs, ys, x0, y0, h, ny, oneway)
            if contour:
                pieces += _contour_pieces(region, forb.G, thr, runs, x0, y0, h)
                if hug is not None:
                    pieces = hug(pieces, float(z))
            if pieces:
                deepest = float(z)
            ent.thr = thr
            ent.z_prev = float(levels[li - 1]) if li else float(z_top)
            cur, removed[li], any_swept = _cut_level(w, lv, pieces, cur, safe, oneway, level_retracts, li, ent, mat,
                                                     Rt, rc, air)
            if any_swept:             # the dilated map is redone at the next level
                top_dil = None
        if progress is not None:
            progress(li + 1, int(levels.size))
    return w, cur, level_retracts, removed, blocked, deepest


def _off_walls(region, G, thr, h: float, back_mm: float) -> np.ndarray:
    """The region less, along every run of its cells in x (the clearing lines' direction) that ends at a
    forbidden cell (``G > thr``: the part's walls offset by the tool radius and the allowance; not the
    region's other limits), the run's last ``back_mm`` at that end (cells whose centre is closer than
    ``back_mm`` to the run's edge): where the clearing lines run when the offset contour follows the
    walls (:func:`_cut_levels`)."""
    if not back_mm > 0 or not region.any():
        return region
    return _pull_back(region, G, float(thr), int(math.ceil(back_mm / h - 0.5)))


@njit(cache=True, nogil=True)
def _pull_back(region, G, thr, k):
    """:func:`_off_walls`' kernel: ``k`` cells off each run end that borders a forbidden cell in x."""
    nx, ny = region.shape
    out = region.copy()
    if k <= 0:
        return out
    for j in range(ny):
        i = 0
        while i < nx:
            if not region[i, j]:
                i += 1
                continue
            i0 = i
            while i < nx and region[i, j]:
                i += 1
            i1 = i                                     # the run is i0 .. i1 - 1
            if i0 > 0 and G[i0 - 1, j] > thr:
                for q in range(i0, min(i0 + k, i1)):
                    out[q, j] = False
            if i1 < nx and G[i1, j] > thr:
                for q in range(max(i1 - k, i0), i1):
                    out[q, j] = False
    return out


def _result(pts, w: _Writer, cur, levels, level_retracts, removed, stock: _Stock, Rt, rc, h, s, *, rest, ent,
            air_top, before, after, holder=False, blocked=None, deepest=math.nan) -> RoughingPath:
    """The last retract to the safe height, the toolpath, its verified clearance
    (:func:`~planning.toolpath.roughing.clearance.min_tool_clearance`), the air cut (feed moves
    at a level whose disc meets no stock of ``air_top`` above it, :func:`_air_length` on the map's
    maximum over the cells whose centre is closer than Rt + 1.5 h: a stock cell within Rt of a
    point of the move is that close to the centre of the point's cell, so no move that touches
    stock counts) and the :class:`RoughingPath`."""
    box_lo, box_hi, lo, z_top = stock.box_lo, stock.box_hi, stock.lo, stock.z_top
    if cur is not None:
        _retract(w, cur, stock.safe)
        xyz = np.concatenate(w.pts)
        use = w.use()
    else:
        xyz = np.zeros((0, 3))
        use = np.zeros(0, np.int8)
    tp = lines(xyz, use, tip_offset_mm=0.0)
    clear = math.inf
    if xyz.shape[0]:
        # a point more than Rt below the lowest tip is farther than Rt from the tool solid: leave it out
        near = pts[pts[:, 2] >= float(xyz[:, 2].min()) - Rt]
        if near.shape[0]:
            clear = min_tool_clearance(xyz, near, tool_radius_mm=Rt, corner_radius_mm=rc, reach_mm=Rt).min_mm
    air_cut = 0.0
    if xyz.shape[0] > 1:
        air_cut = float(_air_length(xyz, use, _disc_max(air_top, h, Rt + 1.5 * h), ent.mat.x0, ent.mat.y0, h, USE_CUT))
    return RoughingPath(
        toolpath=tp, levels_mm=levels, n_levels=int(levels.size),
        length_mm=path_length_mm(tp, kinds=(FEED,)), air_mm=path_length_mm(tp, kinds=(RAPID,)),
        n_retracts=int(w.n_retracts), min_clearance_mm=float(clear), removed_note=REST_NOTE if rest else REMOVED_NOTE,
        level_retracts=level_retracts, removed_mm3=removed,
        stock_box_mm=np.array([[box_lo[0], box_lo[1], float(lo[2])], [box_hi[0], box_hi[1], z_top]]),
        cell_mm=float(h), stepover_mm=float(s), rest=bool(rest), air_cut_mm=air_cut,
        stock_before_mm3=float(before), stock_after_mm3=float(after), safe_z_mm=float(stock.safe),
        entry=ent.cfg.kind, n_helix=int(ent.n_helix), n_ramps=int(ent.n_ramps), n_side_entries=int(ent.n_side),
        n_plunges_into_material=int(ent.n_plunges), n_pieces_left=int(ent.n_left),
        left_length_mm=round(float(ent.left_mm), 1), n_entered_in_air=int(ent.n_in_air),
        n_fed_down=int(ent.n_fed_down), n_started_late=int(ent.n_started_late), holder=bool(holder),
        holder_blocked_cells=np.zeros(levels.size, np.int64) if blocked is None else blocked,
        n_holder_blocked_cells=0 if blocked is None else int(blocked.sum()), deepest_cut_mm=float(deepest))


def _retract_rise(w: _Writer, xy, z: float, safe: float) -> float:
    """How far a retract from the tip (``xy``, ``z``) feeds up (:func:`~planning.toolpath.roughing.links._retract`
    without its step off a wall): ``w.gap``, or up to where the tool grown by the rapid clearance clears
    the material on the stock view."""
    zr = z + w.gap
    if w.column_clear is not None:
        zr = max(zr, float(w.column_clear(float(xy[0]), float(xy[1]), z, safe)))
    return min(zr, safe) - z


def _cut_level(w: _Writer, lv: _Level, pieces: list[_Piece], cur, safe, oneway, level_retracts, li, ent: _Entries,
               mat: _MaterialMap, Rt, rc, air: _LevelAir | None = None):
    """Cut the pieces of one level in the order of
    :func:`~planning.toolpath.roughing.ordering._order`, linked at the level or by lifts and
    entries (:class:`~planning.toolpath.roughing.entries._Entries`); the remaining-material map is
    lowered along what was cut (cells the flat bottom, or the corner, surely swept) before each
    entry and at the end. With ``air`` (:class:`~planning.toolpath.roughing.air._LevelAir`) a clearing
    line is trimmed, just before it is cut, to the span where its disc still meets material of the
    level that the level's cuts so far have not swept, and skipped when there is none, and on the stock view
    any piece loses the ends whose moves meet no material there (``air.meets``:
    :func:`~planning.toolpath.roughing.air._exact_ends`), and a link at the level longer than
    LINK_LIFT_MM (plus LIFT_SLOWER times the retract's rise, :func:`_retract_rise`, and the feed down)
    that meets none, to a piece that
    starts in air, is lifted over instead of fed; a piece that no
    entry fits (a straight plunge only) is tried again after the level's other pieces, which may have
    swept its material (it is then trimmed away as air) or cut beside it (a side entry or a link at the
    level), and is left (``n_pieces_left``) only when it still cannot be entered. Returns the
    new current tip, the volume removed (mm^3) and whether anything was cut at the level."""
    z = lv.z
    here = None                  # (xy, cell, component) where the tool is at this level
    swept = []
    vol = 0.0
    any_swept = False
    prev_line = False
    cut_all = []                 # every polyline cut at this level, for ``air``
    later = []                   # pieces no entry fitted yet: tried again after the others

    def _all():
        for piece_, xy_, cells_ in _order(pieces, None if cur is None else np.asarray(cur[:2]), oneway):
            yield piece_, xy_, cells_, False
        for piece_, xy_, cells_ in later:
            yield piece_, xy_, cells_, True

    for piece, xy, cells, retry in _all():
        if air is not None:
            air.mark(cut_all)
            trimmed = air.trim(xy, cells, lv.ny) if piece.is_line else \
                air.trim_chain(xy, cells, lv.ny, loop=piece.ends == "loop")
            if trimmed is None:      # only air left along it
                continue
            xy, cells = trimmed
            if air.meets is not None:   # its ends as the stock itself shows them
                loop = piece.ends == "loop" and xy.shape[0] > 2 and bool(np.all(xy[0] == xy[-1]))
                trimmed = _exact_ends(air, xy, cells, lv.ny, air.meets, z, loop, piece.is_line)
                if trimmed is None:
                    continue
                xy, cells = trimmed
        q = xy[0]
        linked = False
        if here is not None and here[2] == piece.comp and not (oneway and piece.is_line and prev_line):
            worth = max(4.0 * lv.Rt, _lift_cost(lv, here[0], q, z, safe))     # longest link kept at the level
            dist = float(np.hypot(*(q - here[0])))
            if dist <= worth and air is not None and air.meets is not None and dist > air_mod.LINK_LIFT_MM \
                    and not air.meets(np.array([here[0], q]), np.array([q, q]), z).any() \
                    and dist > air_mod.LINK_LIFT_MM + air_mod.LIFT_SLOWER * (_retract_rise(w, here[0], z, safe) + w.gap):
                pass      # through air all the way: lifted over (the entry finds a way in beside q)
            elif dist <= worth and lv.visible(here[0], q):
                w.add([q[0], q[1], z], USE_CUT)
                swept.append(np.array([here[0], q]))
                cut_all.append(swept[-1])
                linked = True
            elif dist <= worth:
                path = lv.grid_path(here[0], here[1], q, cells[0], worth)
                if path is not None and air is not None and air.meets is not None:
                    long_ = float(np.hypot(*np.diff(path, axis=0).T).sum())
                    if long_ > air_mod.LINK_LIFT_MM and not air.meets(np.vstack([path[:-1], q]), np.vstack([path[1:], q]),
                                                                      z).any() \
                            and long_ > air_mod.LINK_LIFT_MM + air_mod.LIFT_SLOWER * (_retract_rise(w, here[0], z, safe)
                                                                                     + w.gap):
                        path = None   # through air all the way: lifted over
                if path is not None:
                    w.add(np.column_stack([path[1:], np.full(path.shape[0] - 1, z)]), USE_CUT)
                    swept.append(path)
                    cut_all.append(path)
                    linked = True
        if not linked:
            if swept:
                vol += mat.sweep(swept, z, Rt - rc, Rt, rc, 0.25 * lv.h)
                any_swept = True
                swept = []
            entered = ent.enter(w, lv, cur, xy, cells[0], z, safe)
            if entered is None:       # no entry but a straight plunge: the piece is left, the tool stays
                if air is not None and not retry:
                    # the level's other pieces may yet clear its material or open a way in from the side
                    later.append((piece, xy, cells))
                    ent.n_left -= 1
                    continue
                ent.left_mm += float(np.hypot(*np.diff(xy, axis=0).T).sum()) if xy.shape[0] > 1 else 0.0
                continue
            if here is not None:
                level_retracts[li] += 1
            swept += entered
            cut_all += entered
        w.add(np.column_stack([xy[1:], np.full(xy.shape[0] - 1, z)]), USE_CUT)
        prev_line = piece.is_line
        swept.append(xy)
        cut_all.append(xy)
        cur = (float(xy[-1, 0]), float(xy[-1, 1]), z)
        here = (xy[-1].copy(), cells[-1], piece.comp)
    if swept:
        vol += mat.sweep(swept, z, Rt - rc, Rt, rc, 0.25 * lv.h)
        any_swept = True
    return cur, vol, any_swept
