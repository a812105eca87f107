"""Finishing CL points the tool assembly cannot take, cut out of the passes (issue 16 items 3 and 4).

All tool paths here are :class:`planning.toolpath.moves.Toolpath` in an area frame
(:mod:`planning.toolpath.frames`: tool axis +Z, mm); the obstacles, fixtures, stock and travel are
in the part frame (``frame.to_part``). Four steps, each usable alone:

1. :func:`blocked_cl`: per ball-centre position, whether the tool may be there, and why not:

   * ``cloud``: the cutter above the ball, the shank or the holder contains a cloud (or forbidden)
     point (:func:`planning.geometry.collision.centres_collision_free`, exact; the ball's lower
     half is the ball drop's business);
   * ``fixture``: the whole tool (solid ball included; touching counts) meets a fixture or the
     table (:func:`planning.geometry.fixtures.fixture_collision_free`);
   * ``stock``: the shank or the holder, not the cutting part, is in the current stock
     (:func:`planning.simulate.dexel.collide` with ``which="holder"`` on zero-length moves at the
     tip ``c - R t``; depth > 0, at the stock model's ray resolution);
   * ``travel``: the caller's ``travel_ok(tips_part) -> bool`` says the tip is beyond the travel;
   * ``underside``: the ball's lowest point is below the part's underside:
     ``c_z - R < floor_z - tol`` (part frame).

   Every reason is evaluated on every point (the counts are per reason, a point may have several).

2. :func:`cut_moves`: a path without the dropped points. The path is split into pieces, the runs
   of consecutive kept points (a move survives only when both its ends do, arcs included); a
   piece without a cutting move (FEED or arc of use USE_CUT) goes. A piece starts at the end of
   its last rapid before its first cutting move (so a lead-in that survives whole is kept as it
   was: the safe-height rapid over its start is written again, then the rapid down onto it) or,
   when there is none, at its first point, which is then approached the way
   :mod:`planning.toolpath.finishing` plunges (rapid over it at ``safe_z_mm``, rapid down to
   ``approach_mm`` above it, feed down at USE_PLUNGE). A piece ends before its first rapid after
   its last cutting move (a surviving lead-out stays), then leaves straight up along +Z, the tool
   axis: a feed retract (USE_RETRACT) of ``approach_mm`` where it ends on the surface (a cut or a
   plunge reaches its last point) and a rapid to ``safe_z_mm``, else a rapid straight up. Links
   are therefore: up along the tool axis over the last kept point, a rapid at the safe height,
   down along the tool axis over the next piece's first point. For a ball-drop CL point the
   column of radius R above the ball centre holds no cloud point (the drop height is the lowest
   free one), so the ball and the cutter cylinder clear the cloud on the way up and down; the
   wider shank and holder pieces are not covered by that argument: :func:`guard_finishing`
   checks those columns too.

3. :func:`unmachined_points`: the scan points that no kept ball position comes near enough to
   finish.

4. :func:`guard_finishing`: 1 to 3 for one area's :class:`planning.toolpath.finishing.FinishingPath`
   in one call, with the moves between CL points and the new link columns checked as well.

Lengths in mm.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit, prange
from scipy.spatial import cKDTree

from planning.errors import ParameterError
from planning.geometry.collision import centres_collision_free
from planning.geometry.fixtures import fixture_collision_free
from planning.geometry.kernels import serial_twin
from planning.geometry.tool import ToolAssembly
from planning.simulate.dexel import collides
from planning.toolpath.finishing import FinishingPath
from planning.toolpath.frames import AreaFrame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
    densify,
    path_length_mm,
)

#: The reasons :func:`blocked_cl` reports, in this order.
REASONS = ("cloud", "fixture", "stock", "travel", "underside")

#: A point this close below the safe height counts as at it (mm).
_AT_SAFE_MM = 1e-6

_ARCS = (ARC_CW, ARC_CCW)
_CUT_KINDS = (FEED, ARC_CW, ARC_CCW)


# ------------------------------------------------------------------------------------------------
# 1. blocked positions

@dataclass(frozen=True)
class BlockedCL:
    """What :func:`blocked_cl` found: ``mask`` (n,) bool, True where the tool may not be (any
    reason); ``reasons``: reason name -> (n,) bool for every reason that was checked (those
    skipped are absent)."""

    mask: np.ndarray
    reasons: dict = field(default_factory=dict)

    @property
    def counts(self) -> dict:
        """Points blocked per reason: every name of :data:`REASONS` (0 where not checked), then any other
        reason checked (``depth``, the semi-finishing's). A point blocked for several reasons counts under
        each."""
        out = {r: 0 for r in REASONS}
        out.update({r: int(m.sum()) for r, m in self.reasons.items()})
        return out

    @property
    def n_blocked(self) -> int:
        return int(self.mask.sum())


def flute_length_mm(tool: ToolAssembly) -> float:
    """The cutting length from the tip of ``tool`` (top of its cutter segments; R without one)."""
    R = float(tool.radius_mm)
    tops = [s.hi_mm for s in tool.cutter_segments if s.part == "cutter" and s.hi_mm is not None]
    return R + max(tops, default=0.0)


def _unit_axis(axis, frame: AreaFrame) -> np.ndarray:
    t = np.asarray(frame.rotation[2] if axis is None else axis, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(t))
    if not (np.isfinite(n) and n > 1e-12):
        raise ParameterError("axis must be a finite non-zero vector")
    return t / n


def cloud_blocked(centres_frame, frame: AreaFrame, axis, tool: ToolAssembly, obstacles_part) -> np.ndarray:
    """(n,) bool: the ``cloud`` reason of :func:`blocked_cl` alone (the cutter above the ball, the shank
    or the holder meets the cloud or the forbidden points ``obstacles_part``), for the ball centres
    ``centres_frame`` (n,3, area frame). It needs no stock: the finishing worker computes it for
    step 1 of :func:`guard_finishing` beside the passes (:mod:`planning.toolpath.finishing_worker`)."""
    c_f = np.asarray(centres_frame, dtype=np.float64).reshape(-1, 3)
    if c_f.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    t = _unit_axis(axis, frame)
    return ~centres_collision_free(np.asarray(obstacles_part, dtype=np.float64).reshape(-1, 3), frame.to_part(c_f),
                                   t[None, :], tool)[:, 0]


def blocked_cl(centres_frame, frame: AreaFrame, axis=None, *, tool: ToolAssembly, obstacles_part,
               fixtures: Sequence = (), stock=None, stock_shape=None,
               travel_ok: Callable[[np.ndarray], np.ndarray] | None = None,
               floor_z_part_mm: float | None = None, tol_mm: float = 1e-3,
               progress: Callable[[float, str], None] | None = None,
               cloud_known: np.ndarray | None = None,
               depth: Callable[[np.ndarray], np.ndarray] | None = None) -> BlockedCL:
    """Which ball-centre positions the tool may not take (module docstring, step 1).

    ``centres_frame`` (n,3): ball centres in the area frame ``frame``; ``axis`` (3,): the tool axis
    in the part frame (None: the frame's +Z, ``frame.rotation[2]``); ``tool``: the ball and the
    cylinders above its centre; ``obstacles_part`` (K,3): the cloud and the forbidden points (part
    frame; None or empty: not checked); ``fixtures``: fixture solids and the table (part frame;
    empty: not checked); ``stock``: the current stock (:class:`planning.simulate.dexel.TriDexel`,
    part frame; None: not checked) and ``stock_shape`` the tool as the simulation sees it
    (:class:`planning.simulate.motion.ToolShape`; None: :func:`planning.simulate.tools.finishing_shape`
    of ``tool`` with its flute length); ``travel_ok``: tool tips (n,3) part frame -> (n,) bool
    within the machine's travel (None: not checked); ``floor_z_part_mm``: the part's underside
    (part frame z; None: not checked), or a :class:`planning.toolpath.carried.Footprint` (only a ball
    reaching below the underside INSIDE the part's footprint counts); ``tol_mm``: how far below the
    underside the ball may reach. ``progress(fraction, message)``: each check as it starts (the
    stock's inside it). ``cloud_known`` (n,) bool: the cloud reason already found for these points
    (:func:`cloud_blocked`), not computed again. ``depth``: ball centres (n,3, area frame) -> (n,)
    bool, the positions that would cut deeper than allowed (reason ``depth``; None: not checked).
    Vectorised: one call of each check for all points."""
    say = progress or (lambda fraction, message="": None)
    c_f = np.asarray(centres_frame, dtype=np.float64).reshape(-1, 3)
    n = c_f.shape[0]
    if not np.all(np.isfinite(c_f)):
        raise ParameterError("centres_frame must be finite")
    t = _unit_axis(axis, frame)
    R = float(tool.radius_mm)
    reasons: dict[str, np.ndarray] = {}
    if n == 0:
        return BlockedCL(mask=np.zeros(0, dtype=bool), reasons={})
    c_p = frame.to_part(c_f)
    tips = c_p - R * t
    obst = None if obstacles_part is None else np.asarray(obstacles_part, dtype=np.float64).reshape(-1, 3)
    if obst is not None and obst.shape[0]:
        if cloud_known is not None and np.shape(cloud_known) == (n,):
            reasons["cloud"] = np.asarray(cloud_known, dtype=bool)
        else:
            say(0.0, f"{n} positions: cloud")
            reasons["cloud"] = cloud_blocked(c_f, frame, t, tool, obst)
    if fixtures:
        say(0.3, f"{n} positions: fixtures")
        reasons["fixture"] = ~fixture_collision_free(c_p, t[None, :], tool, list(fixtures))[:, 0]
    if stock is not None:
        shape = stock_shape
        if shape is None:
            from planning.simulate.tools import finishing_shape

            shape = finishing_shape(tool, 0, flute_length_mm(tool))
        say(0.4, f"{n} positions: stock")
        # the same answer as collide on every position, by runs along the path (most are clear)
        reasons["stock"] = collides(stock, tips, tips, np.broadcast_to(t, (n, 3)), shape, which="holder",
                                    progress=None if progress is None else
                                    (lambda f, m: say(0.4 + 0.55 * f, f"{n} positions: stock, {m}")))
    if travel_ok is not None:
        say(0.95, f"{n} positions: travel")
        ok = np.asarray(travel_ok(tips), dtype=bool).reshape(-1)
        if ok.shape[0] != n:
            raise ParameterError(f"travel_ok must return one bool per tip ({n}), got {ok.shape[0]}")
        reasons["travel"] = ~ok
    if floor_z_part_mm is not None:
        if hasattr(floor_z_part_mm, "below_floor"):      # a footprint: only below the part counts
            reasons["underside"] = floor_z_part_mm.below_floor(c_p, R, float(tol_mm))
        else:
            reasons["underside"] = c_p[:, 2] - R < float(floor_z_part_mm) - float(tol_mm)
    if depth is not None:
        reasons["depth"] = np.asarray(depth(c_f), dtype=bool).reshape(n)
    mask = np.zeros(n, dtype=bool)
    for m in reasons.values():
        mask |= m
    return BlockedCL(mask=mask, reasons=reasons)


# ------------------------------------------------------------------------------------------------
# 2. cutting the path

@dataclass(frozen=True)
class CutResult:
    """What :func:`cut_moves` made.

    ``toolpath``: the path without the dropped points (empty, 0 moves, when no piece is left);
    ``pass_index`` (P',) int32: the input's for every point kept, -1 for the link points (None
    when none was given); ``n_dropped_points``: points the mask dropped; ``n_cut_points_lost``:
    ends of cutting moves of the input that are not in the result (the dropped ones and those of
    pieces too short to keep); ``n_pieces``: pieces kept; ``n_links``: links made between two
    pieces; ``n_new_retracts``: retracts to the safe height between cutting moves in the result
    minus those in the input (:func:`count_retracts`; what to add to
    :attr:`planning.toolpath.finishing.FinishingPath.n_retracts`; it can be negative when a
    whole stretch between two retracts goes); ``source`` (P',) int64: the input index of every
    point (-1 for a new link point); ``anchor`` (P',) int64: for a new move straight along the
    tool axis (a retract or an approach of a link), the index in the RESULT of the kept point it
    stands over, else -1; ``pieces`` (n_pieces, 2) int64: first and last input index of every
    piece kept."""

    toolpath: Toolpath
    pass_index: np.ndarray | None
    n_dropped_points: int
    n_cut_points_lost: int
    n_pieces: int
    n_links: int
    n_new_retracts: int
    source: np.ndarray
    anchor: np.ndarray
    pieces: np.ndarray


def _carried_axes(axes: np.ndarray, src: np.ndarray, anchor: np.ndarray) -> np.ndarray:
    """The tool axis of every point of a cut 5-axis path (issue 19): a kept point keeps its own; a new
    point along the axis over a kept point (retract, approach) takes that point's; any other new
    point (a rapid at the safe height) the next kept point's, so the axis turns on the way to the
    piece it enters (the last kept point's after the last piece)."""
    out = np.empty((src.shape[0], 3))
    kept = src >= 0
    out[kept] = axes[src[kept]]
    over = ~kept & (anchor >= 0)
    out[over] = out[anchor[over]]
    rest = np.flatnonzero(~kept & (anchor < 0))
    if rest.size:
        k_idx = np.flatnonzero(kept)
        nxt = np.searchsorted(k_idx, rest)
        has_next = nxt < k_idx.size
        out[rest[has_next]] = out[k_idx[nxt[has_next]]]
        prv = np.searchsorted(k_idx, rest[~has_next]) - 1
        out[rest[~has_next]] = out[k_idx[np.maximum(prv, 0)]] if k_idx.size else [0.0, 0.0, 1.0]
    return out


def _cut_moves_mask(tp: Toolpath) -> np.ndarray:
    """(P,) bool: move i is a cutting move (FEED or arc, use USE_CUT); move 0 never."""
    m = np.isin(tp.kind, _CUT_KINDS) & (tp.use == USE_CUT)
    if m.size:
        m[0] = False
    return m


def count_retracts(tp: Toolpath, safe_z_mm: float) -> int:
    """Visits of the safe height between the first and the last cutting move of ``tp``: runs of
    consecutive points at ``z >= safe_z_mm`` (within 1e-6 mm) after the start of the first cutting
    move and before the end of the last (what :class:`FinishingPath` counts as ``n_retracts``)."""
    cut = np.flatnonzero(_cut_moves_mask(tp))
    if cut.size < 2:
        return 0
    lo, hi = int(cut[0]) - 1, int(cut[-1])
    high = tp.xyz_mm[lo + 1:hi, 2] >= float(safe_z_mm) - _AT_SAFE_MM
    if not high.any():
        return 0
    return int(np.count_nonzero(np.diff(np.concatenate([[0], high.astype(np.int8)])) == 1))


def _identity(tp: Toolpath, pass_index, n_pieces: int) -> CutResult:
    P = tp.n_moves
    return CutResult(toolpath=tp, pass_index=None if pass_index is None else pass_index.copy(),
                     n_dropped_points=0, n_cut_points_lost=0, n_pieces=n_pieces, n_links=0, n_new_retracts=0,
                     source=np.arange(P, dtype=np.int64), anchor=np.full(P, -1, dtype=np.int64),
                     pieces=np.array([[0, P - 1]] if n_pieces else np.zeros((0, 2)), dtype=np.int64).reshape(-1, 2))


def _pieces(tp: Toolpath, keep: np.ndarray):
    """The pieces of the kept points (module docstring, step 2): (first, last, reached by a rapid,
    ends on the surface) per piece, input indices."""
    P = tp.n_moves
    cut = _cut_moves_mask(tp)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], keep.astype(np.int8), [0]])))
    s, e = edges[::2], edges[1::2] - 1                       # runs of kept points, inclusive
    ncut = np.concatenate([[0], np.cumsum(cut)])             # ncut[i + 1]: cutting moves <= i
    has = ncut[e + 1] - ncut[s + 1] > 0                      # a cutting move in (s, e]
    s, e = s[has], e[has]
    cuts = np.flatnonzero(cut)
    j0 = cuts[np.searchsorted(cuts, s, side="right")]        # first cutting move after s
    j1 = cuts[np.searchsorted(cuts, e, side="right") - 1]    # last cutting move <= e
    rap = np.flatnonzero(tp.kind == RAPID)                  # moves that are rapids (move 0 included)
    # start: the end of the last rapid before the first cutting move, not before s (move s itself
    # only at the path's start: for s > 0 it comes from a dropped point)
    k = np.searchsorted(rap, j0, side="left") - 1
    r = rap[np.maximum(k, 0)] if rap.size else np.full(s.size, -1)
    by_rapid = (k >= 0) & (r >= np.where(s == 0, 0, s + 1))
    first = np.where(by_rapid, r, s)
    # end: the point before the first rapid after the last cutting move, within the run
    k = np.searchsorted(rap, j1 + 1, side="left")
    f = rap[np.minimum(k, rap.size - 1)] if rap.size else np.full(s.size, P)
    last = np.where((k < rap.size) & (f <= e), f - 1, e)
    on_surface = np.isin(tp.kind[last], _CUT_KINDS) & np.isin(tp.use[last], (USE_CUT, USE_PLUNGE))
    return first, last, by_rapid, on_surface


def cut_moves(tp: Toolpath, drop, *, safe_z_mm: float, pass_index=None, approach_mm: float = 1.0) -> CutResult:
    """``tp`` (area frame, reference points: ball centres for finishing) without the points where
    ``drop`` (P,) is True, the pieces left linked along the tool axis through ``safe_z_mm`` (the
    reference point's height of retracts and rapids; module docstring, step 2). No dropped point
    remains and no move starts or ends at one (arcs included: an arc with a dropped end goes);
    a piece without a cutting move goes. ``pass_index`` (P,): kept aligned (-1 on link points)
    so :func:`planning.toolpath.reduce.reduce_cl` / ``fit_arcs`` can run on the result;
    ``approach_mm``: length of the feed retract off the surface and of the plunge onto it (0:
    retract and plunge from the safe height at feed). Python loops only over the pieces. See
    :class:`CutResult`."""
    P = tp.n_moves
    drop = np.asarray(drop, dtype=bool).reshape(-1)
    if drop.shape[0] != P:
        raise ParameterError(f"drop must have one entry per point ({P}), not {drop.shape[0]}")
    pi = None
    if pass_index is not None:
        pi = np.asarray(pass_index).reshape(-1)
        if pi.shape[0] != P:
            raise ParameterError(f"pass_index must have one entry per point ({P}), not {pi.shape[0]}")
    safe = float(safe_z_mm)
    app = max(float(approach_mm), 0.0)
    cut = _cut_moves_mask(tp)
    if not drop.any():
        return _identity(tp, pi, int(cut.any()))
    first, last, by_rapid, on_surface = _pieces(tp, ~drop)
    xyz = tp.xyz_mm

    # the output in blocks: new link points, or input points a..b as they are
    out_xyz, out_kind, out_cen, out_plane, out_use, out_src, out_anchor_rel = [], [], [], [], [], [], []
    n_out = 0

    def add_new(points, uses, anchored):
        """New points; ``anchored[k]``: the move reaching point k runs along the axis over
        the kept point at output index ``anchored[k]`` (or -1)."""
        nonlocal n_out
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        m = pts.shape[0]
        if m == 0:
            return
        u = np.asarray(uses, dtype=np.int8)
        out_xyz.append(pts)
        out_kind.append(np.where(u == USE_RAPID, RAPID, FEED).astype(np.int8))
        out_cen.append(np.full((m, 3), np.nan))
        out_plane.append(np.zeros(m, np.int8))
        out_use.append(u)
        out_src.append(np.full(m, -1, np.int64))
        out_anchor_rel.append(np.asarray(anchored, np.int64))
        n_out += m

    def add_old(a, b, first_kind=None, first_use=None, first_anchor=-1):
        nonlocal n_out
        sl = slice(a, b + 1)
        m = b - a + 1
        kind = tp.kind[sl].copy()
        cen = tp.centre_mm[sl].copy()
        plane = tp.plane[sl].copy()
        use = tp.use[sl].copy()
        anc = np.full(m, -1, np.int64)
        if first_kind is not None:
            kind[0], use[0] = first_kind, first_use
            cen[0], plane[0] = np.nan, 0
            anc[0] = first_anchor
        out_xyz.append(xyz[sl])
        out_kind.append(kind)
        out_cen.append(cen)
        out_plane.append(plane)
        out_use.append(use)
        out_src.append(np.arange(a, b + 1, dtype=np.int64))
        out_anchor_rel.append(anc)
        n_out += m

    n_pieces = int(first.size)
    for k in range(n_pieces):
        a, b = int(first[k]), int(last[k])
        p = xyz[a]
        below = p[2] < safe - _AT_SAFE_MM
        # entry: over the first point at the safe height, then down along the axis
        if by_rapid[k] or not below:
            if below:
                add_new([[p[0], p[1], safe]], [USE_RAPID], [-1])
            at = n_out
            add_old(a, b, RAPID, USE_RAPID, at if below else -1)
        else:
            at = n_out + 1 + int(app > 0 and p[2] + app < safe - _AT_SAFE_MM)
            pts, uses, anc = [[p[0], p[1], safe]], [USE_RAPID], [-1]
            if app > 0 and p[2] + app < safe - _AT_SAFE_MM:
                pts.append([p[0], p[1], p[2] + app])
                uses.append(USE_RAPID)
                anc.append(at)
            add_new(pts, uses, anc)
            add_old(a, b, FEED, USE_PLUNGE, at)
        # exit: straight up along the axis to the safe height
        q = xyz[b]
        if q[2] < safe - _AT_SAFE_MM:
            at = n_out - 1
            if on_surface[k]:
                if app > 0 and q[2] + app < safe - _AT_SAFE_MM:
                    add_new([[q[0], q[1], q[2] + app], [q[0], q[1], safe]], [USE_RETRACT, USE_RAPID], [at, at])
                else:
                    add_new([[q[0], q[1], safe]], [USE_RETRACT], [at])
            else:
                add_new([[q[0], q[1], safe]], [USE_RAPID], [at])

    if n_out == 0:
        out = Toolpath(xyz_mm=np.zeros((0, 3)), kind=np.zeros(0, np.int8), centre_mm=np.zeros((0, 3)),
                       plane=np.zeros(0, np.int8), use=np.zeros(0, np.int8), tip_offset_mm=tp.tip_offset_mm,
                       axis=None if tp.axis is None else np.zeros((0, 3)))
        src = np.zeros(0, np.int64)
        anchor = np.zeros(0, np.int64)
    else:
        out = Toolpath(xyz_mm=np.concatenate(out_xyz), kind=np.concatenate(out_kind).astype(np.int8),
                       centre_mm=np.concatenate(out_cen), plane=np.concatenate(out_plane).astype(np.int8),
                       use=np.concatenate(out_use).astype(np.int8), tip_offset_mm=tp.tip_offset_mm)
        src = np.concatenate(out_src)
        anchor = np.concatenate(out_anchor_rel)
        if tp.axis is not None:
            out = replace(out, axis=_carried_axes(tp.axis, src, anchor))
    new_pi = None
    if pi is not None:
        new_pi = np.where(src >= 0, pi[np.maximum(src, 0)] if P else -1, -1).astype(np.int32)
    lost = int(np.count_nonzero(~np.isin(np.flatnonzero(cut), src)))
    return CutResult(toolpath=out, pass_index=new_pi, n_dropped_points=int(drop.sum()), n_cut_points_lost=lost,
                     n_pieces=n_pieces, n_links=max(n_pieces - 1, 0),
                     n_new_retracts=count_retracts(out, safe) - count_retracts(tp, safe),
                     source=src, anchor=anchor, pieces=np.stack([first, last], 1).astype(np.int64).reshape(-1, 2))


# ------------------------------------------------------------------------------------------------
# 3. unmachined points

def unmachined_points(area_points_frame, kept_centres_frame, radius_mm: float, reach_mm: float) -> np.ndarray:
    """(n,) bool: the points of ``area_points_frame`` (n,3) that no ball centre of
    ``kept_centres_frame`` (m,3) finishes, both in the area frame. A point ``p`` counts as
    finished when some centre ``c`` has ``|p - c| <= R + reach_mm``: ``|p - c| - R`` is how far
    ``p`` lies outside the ball at ``c``, i.e. the material the ball leaves at ``p`` at most.
    ``reach_mm`` therefore is the material allowed to remain plus the slack of sampling the
    moves at their CL points only (see :func:`finished_reach_mm`). The centres are binned on a
    cubic grid of cells a little over half ``R + reach_mm`` wide; each point looks at the centres
    of the cells near enough and stops at the first centre near enough (numba, parallel over the
    points; the same ``sqrt(dx^2 + dy^2 + dz^2) <= R + reach_mm`` as a KD-tree query)."""
    pts = np.ascontiguousarray(np.asarray(area_points_frame, dtype=np.float64).reshape(-1, 3))
    cen = np.asarray(kept_centres_frame, dtype=np.float64).reshape(-1, 3)
    if pts.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    if cen.shape[0] == 0:
        return np.ones(pts.shape[0], dtype=bool)
    lim = float(radius_mm) + float(reach_mm)
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(cen)) and math.isfinite(lim) and lim > 0):
        # the KD-tree's answer where the grid cannot be built
        d, _ = cKDTree(cen).query(pts, k=1, distance_upper_bound=lim * (1 + 1e-12) + 1e-12)
        return ~(d <= lim)
    lo = cen.min(axis=0)
    ext = cen.max(axis=0) - lo
    # cells at least lim / _SUB wide (a centre within lim is at most _SUB cells off per axis), at most ~8M
    h = max(lim * (1.0 + 1e-9) / _SUB, float(ext.max()) / 200.0, 1e-12)
    n = (ext / h).astype(np.int64) + 1
    key = ((np.floor((cen[:, 0] - lo[0]) / h).astype(np.int64) * n[1]
            + np.floor((cen[:, 1] - lo[1]) / h).astype(np.int64)) * n[2]
           + np.floor((cen[:, 2] - lo[2]) / h).astype(np.int64))
    order = np.argsort(key, kind="stable")
    start = np.searchsorted(key[order], np.arange(int(n.prod()) + 1))
    out = np.empty(pts.shape[0], dtype=np.bool_)
    kernel = _finished if pts.shape[0] >= _PARALLEL_MIN else _finished_serial
    kernel(pts, np.ascontiguousarray(cen[order]), start, lo[0], lo[1], lo[2], h, n[0], n[1], n[2], lim, out)
    return ~out


@njit(parallel=True, cache=True)
def _finished(pts, cen, start, x0, y0, z0, h, nx, ny, nz, lim, out):
    """out[k]: some centre of ``cen`` (sorted by cell, ``start`` per cell) lies within ``lim`` of
    pts[k]. Cells are at least lim / _SUB wide: the cells within _SUB of the point's own per axis
    are looked at, those whose box is farther than lim from the point skipped."""
    lim2 = lim * lim
    lo2 = lim2 * (1.0 - 1e-9)                   # surely within lim (the sqrt only between lo2 and hi2)
    hi2 = lim2 * (1.0 + 1e-9)
    for k in prange(pts.shape[0]):
        px, py, pz = pts[k, 0], pts[k, 1], pts[k, 2]
        fx, fy, fz = math.floor((px - x0) / h), math.floor((py - y0) / h), math.floor((pz - z0) / h)
        found = False
        if -_SUB - 1.0 < fx < nx + _SUB and -_SUB - 1.0 < fy < ny + _SUB and -_SUB - 1.0 < fz < nz + _SUB:
            ix, iy, iz = int(fx), int(fy), int(fz)
            for ax in range(max(ix - _SUB, 0), min(ix + _SUB, nx - 1) + 1):
                gx = _gap1(px, x0 + ax * h, h)
                if gx * gx > hi2:
                    continue
                for ay in range(max(iy - _SUB, 0), min(iy + _SUB, ny - 1) + 1):
                    gy = _gap1(py, y0 + ay * h, h)
                    gxy = gx * gx + gy * gy
                    if gxy > hi2:
                        continue
                    base = (ax * ny + ay) * nz
                    for az in range(max(iz - _SUB, 0), min(iz + _SUB, nz - 1) + 1):
                        gz = _gap1(pz, z0 + az * h, h)
                        if gxy + gz * gz > hi2:
                            continue
                        c = base + az
                        for s in range(start[c], start[c + 1]):
                            dx = px - cen[s, 0]
                            dy = py - cen[s, 1]
                            dz = pz - cen[s, 2]
                            d2 = dx * dx + dy * dy + dz * dz
                            if d2 <= lo2 or (d2 <= hi2 and math.sqrt(d2) <= lim):
                                found = True
                                break
                        if found:
                            break
                    if found:
                        break
                if found:
                    break
        out[k] = found


@njit(cache=True, nogil=True)
def _gap1(v, a, w):
    """Distance from v to [a, a + w], a little short (the cell bounds' rounding): 0 inside."""
    if v < a:
        return max(a - v - 1e-9 * w, 0.0)
    if v > a + w:
        return max(v - (a + w) - 1e-9 * w, 0.0)
    return 0.0


#: Cells per lim of :func:`_finished`'s grid.
_SUB = 2


#: Fewer points than this are checked on one thread.
_PARALLEL_MIN = 20000
_finished_serial = serial_twin(_finished, "_finished_serial")


def finished_reach_mm(radius_mm: float, *, tol_mm: float, scallop_mm: float, spacing_mm: float) -> float:
    """The ``reach_mm`` of :func:`unmachined_points` used by :func:`guard_finishing`: the gouge
    tolerance (the scan's own spread about the ball-drop surface), plus the scallop the passes are
    allowed to leave between them (a point between two passes lies about R + h from both), plus the
    largest gap between the sampled ball positions and the real moves: a point at distance R from a
    move whose samples are ``spacing_mm`` apart is at most ``sqrt(R^2 + (spacing/2)^2) - R`` further
    from the nearest sample."""
    R, d = float(radius_mm), 0.5 * float(spacing_mm)
    return float(tol_mm) + float(scallop_mm) + (math.sqrt(R * R + d * d) - R)


def check_positions(tp: Toolpath, safe_z_mm: float, spacing_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Step 1 of :func:`guard_finishing`'s positions: every point of ``tp``, then points inside its
    moves at most ``spacing_mm`` apart, the moves along the safe height left out. Returns
    ``(positions (P + Q, 3), the move of each inside point (Q,))``."""
    xyz = tp.xyz_mm
    P = tp.n_moves
    low = xyz[:, 2] < float(safe_z_mm) - _AT_SAFE_MM
    moves = np.arange(1, P)
    moves = moves[low[moves] | low[moves - 1]]
    inner, owner = _move_samples(tp, moves, spacing_mm)
    return np.concatenate([xyz, inner]), owner


def _move_samples(tp: Toolpath, moves: np.ndarray, spacing_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Points inside the moves ``moves`` (indices >= 1) at most ``spacing_mm`` apart (end points
    excluded): straight moves vectorised, arcs by :func:`planning.toolpath.moves.densify`. Returns
    ``(points (Q,3), move (Q,))``."""
    moves = np.asarray(moves, dtype=np.int64)
    moves = moves[moves >= 1]
    xyz = tp.xyz_mm
    is_arc = np.isin(tp.kind[moves], _ARCS)
    lin = moves[~is_arc]
    out_p, out_m = [np.zeros((0, 3))], [np.zeros(0, np.int64)]
    if lin.size:
        a, b = xyz[lin - 1], xyz[lin]
        L = np.linalg.norm(b - a, axis=1)
        m = np.maximum(np.ceil(L / spacing_mm).astype(np.int64), 1)
        inner = m - 1
        if inner.sum():
            owner = np.repeat(np.arange(lin.size), inner)
            start = np.concatenate([[0], np.cumsum(inner)[:-1]])
            kk = np.arange(owner.size) - start[owner] + 1
            t = (kk / m[owner])[:, None]
            out_p.append(a[owner] + t * (b[owner] - a[owner]))
            out_m.append(lin[owner])
    arcs = moves[is_arc]
    if arcs.size:
        q, mv = densify(tp, spacing_mm)
        sel = np.isin(mv, arcs) & np.any(q != xyz[mv], axis=1)
        out_p.append(q[sel])
        out_m.append(mv[sel])
    return np.concatenate(out_p), np.concatenate(out_m)


def cutting_positions(tp: Toolpath, spacing_mm: float) -> np.ndarray:
    """(Q,3) ball positions along the feed and arc moves of ``tp`` (every kind of use): their end
    points and points inside them at most ``spacing_mm`` apart (what :func:`unmachined_points`
    takes as the kept centres)."""
    feed = np.flatnonzero(np.isin(tp.kind, _CUT_KINDS))
    feed = feed[feed >= 1]
    if feed.size == 0:
        return np.zeros((0, 3))
    ends = np.unique(np.concatenate([feed - 1, feed]))
    inner, _ = _move_samples(tp, feed, spacing_mm)
    return np.concatenate([tp.xyz_mm[ends], inner])


# ------------------------------------------------------------------------------------------------
# 4. one area's finishing

@dataclass(frozen=True)
class FinishingSafety:
    """The figures of :func:`guard_finishing`.

    ``blocked``: points of the input path blocked, per reason (:attr:`BlockedCL.counts`);
    ``n_blocked_points``: points of the input path blocked (any reason); ``n_blocked_moves``:
    moves of the input with a blocked position inside and an end not blocked itself (both ends
    are dropped); ``n_column_dropped``: points dropped further because a link column (straight
    up to the safe height) was blocked; ``n_dropped_points``: points of the input dropped in
    all; ``n_cut_points_lost``, ``n_pieces``, ``n_links``, ``n_new_retracts``: of the final cut
    (:class:`CutResult`); ``rounds``: cuts made; ``unmachined`` (n_area,) bool: the area's points
    the input path finishes and the result does not; ``n_unmachined``; ``reach_mm``: the reach
    that decided it (:func:`unmachined_points`)."""

    blocked: dict
    n_blocked_points: int
    n_blocked_moves: int
    n_column_dropped: int
    n_dropped_points: int
    n_cut_points_lost: int
    n_pieces: int
    n_links: int
    n_new_retracts: int
    rounds: int
    unmachined: np.ndarray
    n_unmachined: int
    reach_mm: float


def _columns(points: np.ndarray, safe: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Samples of the vertical segments from each of ``points`` (k,3) up to ``safe``, both ends
    included, at most ``spacing`` apart: ``(samples (Q,3), owner (Q,) into points)``."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    L = np.maximum(safe - p[:, 2], 0.0)
    m = np.maximum(np.ceil(L / spacing).astype(np.int64), 1) + 1
    owner = np.repeat(np.arange(p.shape[0]), m)
    start = np.concatenate([[0], np.cumsum(m)[:-1]]).astype(np.int64)
    kk = np.arange(owner.size) - start[owner]
    z = p[owner, 2] + L[owner] * kk / (m[owner] - 1)
    return np.column_stack([p[owner, :2], z]), owner


def guard_finishing(fin: FinishingPath, frame: AreaFrame, axis=None, *, tool: ToolAssembly, obstacles_part,
                    area_points_frame, safe_z_mm: float, fixtures: Sequence = (), stock=None, stock_shape=None,
                    travel_ok: Callable[[np.ndarray], np.ndarray] | None = None,
                    floor_z_part_mm: float | None = None, tol_mm: float = 1e-3, scallop_mm: float = 0.01,
                    step_mm: float | None = None, reach_mm: float | None = None, approach_mm: float = 1.0,
                    sample_mm: float | None = None, max_rounds: int = 8,
                    progress: Callable[[float, str], None] | None = None,
                    cloud_known: tuple[float, np.ndarray] | None = None,
                    depth: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[FinishingPath | None, FinishingSafety]:
    """Steps 1 to 3 of the module docstring for one area's finishing ``fin``, best on the dense CL
    points before CL reduction and arc fitting (arcs are handled too).

    1. Every point of ``fin.toolpath`` and points inside its moves at most ``sample_mm`` apart
       (default R / 4; the moves along the safe height are left out) are checked by
       :func:`blocked_cl` (same arguments). A blocked point is dropped; a move with a blocked
       position inside has both its ends dropped.
    2. :func:`cut_moves` (``approach_mm``). The new link columns (the vertical segment from the
       first or last point of a piece up to ``safe_z_mm``) are sampled the same way and checked.
       Where one is blocked, the columns of every point of that piece are checked (those of all
       such pieces in one call) and the piece is shortened from that end to its nearest point
       whose column is free (the whole piece goes when none is); then the path is cut again.
       Every column is checked once, so this ends after a round or two (``max_rounds`` bounds
       it: past it, a piece with a blocked link column goes whole).
    3. ``unmachined``: the points of ``area_points_frame`` (n,3: the area's scan points, area
       frame) that the input path finishes and the result does not (:func:`unmachined_points` on
       :func:`cutting_positions` of both paths at ``step_mm``, default R / 4, the finishing's
       default forward step); ``reach_mm`` default :func:`finished_reach_mm` of ``tol_mm``,
       ``scallop_mm`` and that spacing. Points the input itself leaves (inner corners no ball
       reaches) are not the cut's doing and are not counted.

    Returns ``(finishing, figures)``: the :class:`FinishingPath` with the new ``toolpath``,
    ``pass_index``, ``n_passes`` (passes with a point left), ``length_mm`` (feed and arc length)
    and ``n_retracts`` (plus :attr:`CutResult.n_new_retracts`): ``fin`` itself when nothing is
    blocked, None when no piece is left; ``min_clearance_mm`` stays the input's (a lower bound:
    the kept moves are the input's, the new ones run straight up over ball-drop points); and
    :class:`FinishingSafety`. ``progress(fraction, message)``: the check of step 1 takes the first
    70 %, the rounds of step 2 the next 20 %, step 3 the rest. ``cloud_known``: ``(spacing, mask)``,
    the cloud reason of step 1's positions (:func:`check_positions` at that spacing,
    :func:`cloud_blocked`) found beforehand; used when the spacing is this call's and the count
    matches. ``depth``: as :func:`blocked_cl`'s (the semi-finishing's deepest cut)."""
    say = progress or (lambda fraction, message="": None)
    tp = fin.toolpath
    R = float(tool.radius_mm)
    P = tp.n_moves
    safe = float(safe_z_mm)
    spacing = 0.25 * R if sample_mm is None else float(sample_mm)
    step = 0.25 * R if step_mm is None else float(step_mm)
    if not (spacing > 0 and step > 0):
        raise ParameterError("sample_mm and step_mm must be > 0")
    reach = finished_reach_mm(R, tol_mm=tol_mm, scallop_mm=scallop_mm, spacing_mm=step) if reach_mm is None \
        else float(reach_mm)
    kw = {"tool": tool, "obstacles_part": obstacles_part, "fixtures": fixtures, "stock": stock,
          "stock_shape": stock_shape, "travel_ok": travel_ok, "floor_z_part_mm": floor_z_part_mm, "tol_mm": tol_mm,
          "depth": depth}

    def check(points, message):
        return blocked_cl(points, frame, axis, **kw,
                          progress=None if progress is None else (lambda f, m: say(round_at[0], f"{message}: {m}"))).mask

    # 1. the points and the insides of the moves (not those along the safe height); the cloud reason
    # of these very positions may be known (cloud_known: (the sample spacing, the mask))
    xyz = tp.xyz_mm
    positions, owner = check_positions(tp, safe, spacing)
    known = None
    if cloud_known is not None and float(cloud_known[0]) == spacing and len(cloud_known[1]) == positions.shape[0]:
        known = cloud_known[1]
    b = blocked_cl(positions, frame, axis, **kw, cloud_known=known,
                   progress=None if progress is None else (lambda f, m: say(0.7 * f, f"check of {m}")))
    on_pts = BlockedCL(mask=b.mask[:P], reasons={k: v[:P] for k, v in b.reasons.items()})
    drop = on_pts.mask.copy()
    bad_moves = np.unique(owner[b.mask[P:]])
    n_bad_moves = int(np.count_nonzero(~(drop[bad_moves] & drop[bad_moves - 1])))
    drop[bad_moves] = True
    drop[bad_moves - 1] = True
    n_first = int(drop.sum())

    # 2. cut; the new link columns checked (state per input point: 0 unknown, 1 free, 2 blocked)
    col = np.zeros(P, dtype=np.int8)

    def columns(idx):
        idx = idx[col[idx] == 0]
        if idx.size:
            samples, own = _columns(xyz[idx], safe, spacing)
            hit = np.zeros(idx.size, dtype=bool)
            hit[np.unique(own[check(samples, f"link columns of {idx.size} points")])] = True
            col[idx] = np.where(hit, 2, 1)

    rounds = 0
    round_at = [0.7]                # the progress of the round under way (its column checks report there)
    while True:
        round_at[0] = min(0.7 + 0.05 * rounds, 0.9)
        say(round_at[0], f"cut, round {rounds + 1}")
        c = cut_moves(tp, drop, safe_z_mm=safe, pass_index=fin.pass_index, approach_mm=approach_mm)
        rounds += 1
        ends = np.unique(c.source[c.anchor[c.anchor >= 0]])
        columns(ends)
        bad = ends[col[ends] == 2]
        if bad.size == 0:
            break
        hit = [(a, e, bad[(bad >= a) & (bad <= e)]) for a, e in c.pieces]
        hit = [(a, e, ends_here) for a, e, ends_here in hit if ends_here.size]
        if rounds > max_rounds:
            for a, e, _ in hit:
                drop[a:e + 1] = True
            continue
        # the columns of every point of those pieces, in one check (its cost is mostly per call)
        if hit:
            columns(np.unique(np.concatenate([np.arange(a, e + 1) for a, e, _ in hit])))
        for a, e, ends_here in hit:
            idx = np.arange(a, e + 1)
            free = np.flatnonzero(col[idx] == 1)
            if free.size == 0:
                drop[a:e + 1] = True
                continue
            if a in ends_here:
                drop[a:a + free[0]] = True
            if e in ends_here:
                drop[a + free[-1] + 1:e + 1] = True

    # 3. what the cut leaves unfinished
    say(0.9, "unmachined points")
    pts = np.asarray(area_points_frame, dtype=np.float64).reshape(-1, 3)
    # what the result leaves, and of that what the input left too (asked only about those points)
    unm = unmachined_points(pts, cutting_positions(c.toolpath, step), R, reach)
    if unm.any():
        unm[unm] = ~unmachined_points(pts[unm], cutting_positions(tp, step), R, reach)
    figures = FinishingSafety(blocked=on_pts.counts, n_blocked_points=on_pts.n_blocked,
                              n_blocked_moves=n_bad_moves, n_column_dropped=int(drop.sum()) - n_first,
                              n_dropped_points=int(drop.sum()), n_cut_points_lost=c.n_cut_points_lost,
                              n_pieces=c.n_pieces, n_links=c.n_links, n_new_retracts=c.n_new_retracts,
                              rounds=rounds, unmachined=unm, n_unmachined=int(unm.sum()), reach_mm=reach)
    if not drop.any():
        return fin, figures
    if c.toolpath.n_moves == 0:
        return None, figures
    pi = c.pass_index if c.pass_index is not None else np.full(c.toolpath.n_moves, -1, np.int32)
    out = replace(fin, toolpath=c.toolpath, pass_index=pi, n_passes=int(np.unique(pi[pi >= 0]).size),
                  length_mm=path_length_mm(c.toolpath), n_retracts=fin.n_retracts + c.n_new_retracts)
    return out, figures


__all__ = ["REASONS", "BlockedCL", "CutResult", "FinishingSafety", "blocked_cl", "count_retracts", "cut_moves",
           "cutting_positions", "finished_reach_mm", "flute_length_mm", "guard_finishing", "unmachined_points"]
