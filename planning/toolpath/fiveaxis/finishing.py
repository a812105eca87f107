"""Simultaneous 5-axis finishing of one area (issue 19; Chui, Chiu and Yu 2008): the ball-drop
passes of the 3+2 finishing (:mod:`planning.toolpath.finishing`: the ball centres are gouge-free
whatever the axis, since a ball is the same from every side) with a tool axis per position.

:func:`five_axis_path` takes the area's finishing toolpath (area frame, ball centres, after CL
reduction) and:

1. finds the positions that touch the part (feed moves that cut, plunge or link on the surface) and
   their contact normals (:func:`planning.toolpath.fiveaxis.axes.contact_normals`);
2. gives each one its axis (:func:`planning.toolpath.fiveaxis.axes.plan_axes`: Chui eq. 12 lead and
   tilt, the tool cone, the turn rate), where an axis is admissible when (:class:`Admissible`) it
   leans at most ``max_swing_deg`` from the set-up axis (the area frame's +Z, along which the
   retracts run), the cutter, shank and holder above the ball leave every cloud point outside
   (:class:`planning.geometry.axis_collision.ObstacleGrid`, exact, per position), and the machine
   reaches it: a rotary solution within the rotary travel whose tool tip lies within the linear
   travel (:mod:`planning.simulate.kinematics`); with a carried stock, the shank and holder also
   clear the points of the stock's boundary;
3. checks the motion between neighbouring positions too: points along every move (centre on the
   segment, axis along the great circle; the midpoint, and on a long or fast-turning move one every
   :data:`BETWEEN_STEP_MM` of the centre's path and :data:`BETWEEN_TURN_DEG` of the axis's turn,
   :func:`_between_fractions`) must be admissible, and the axis's whole great-circle arc must keep off
   the rotary pole (a pass across a hole in the scan or down a wall has moves of several mm whose axis
   turns tens of degrees: their flutes above the ball can meet the scan between the ends);
4. cuts out (:func:`planning.toolpath.safety.cut_moves`, linked through the safe height) the
   positions with no admissible axis, the ends of moves whose midpoint is not admissible and the
   positions where the turn rate could not be met (a pass broken there), and gives every other
   point of the path an axis (retracts keep the axis of the point they leave, rapids take the next
   one's: the axis turns at the safe height);
5. with the carried stock, plans the links between passes on it
   (:mod:`planning.toolpath.fiveaxis.links`, issue 33 item 1): up each cutting position's own axis to a
   clearance over the stock, across, down, checked on the stock, the fixtures, the travel and the
   rotary pole when planned;
6. routes the short links where a continuous C must be turned back through the safe height
   (:mod:`planning.toolpath.fiveaxis.register`: the C register, issue 33 item 3).

The guard still runs every move on the carried stock afterwards (:mod:`planning.toolpath.guard`,
which runs 5-axis moves in 1-degree steps), as for 3+2: it is the check of the whole operation; the
links of step 5 were planned so that it finds nothing on them.
Lengths in mm, angles in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from planning.geometry.axis_collision import ObstacleGrid, default_cell_mm
from planning.geometry.tool import ToolAssembly
from planning.toolpath.fiveaxis.axes import contact_normals, plan_axes, slerp, turn_deg
from planning.toolpath.fiveaxis.register import route_unwinding_links
from planning.toolpath.frames import AreaFrame
from planning.toolpath.moves import FEED, USE_CUT, USE_PLUNGE, USE_RETRACT, Toolpath
from planning.toolpath.safety import cut_moves

__all__ = ["Admissible", "FiveAxisFigures", "axis_runs", "biarc_figures", "five_axis_path"]

#: Chord tolerance (mm) with which the fitted biarcs are sampled for their clearance from the cloud.
BIARC_CHORD_MM = 0.002

#: How far (frame z) above a touching point the way in and out runs along the tool axis, mm; above
#: it the column to the safe height stays vertical (along the set-up axis), so a leaning tool does
#: not travel sideways by (safe height - z) tan(swing) to reach it (beyond the machine's travel on a
#: long part).
AXIS_COLUMN_MM = 5.0

#: A 5-axis path is reduced (straight moves replacing CL points) only where its axis turns less than
#: this along the replaced stretch, degrees: the axes of the points kept stand for the dropped ones.
REDUCE_AXIS_DEG = 0.5


@dataclass
class FiveAxisFigures:
    """What :func:`five_axis_path` did: ``n_positions`` positions given an axis, ``n_alternatives``
    whose ideal axis was not admissible and that took another, ``blocked`` positions cut out by
    reason (``no_axis``: no admissible axis in the cone; ``between``: the move into it is not
    admissible halfway; ``rate``: the turn rate could not be met; ``floor``: the ball below the part's
    underside; ``flip``: the rotary solution changes there), ``max_rate_deg_per_mm`` the
    fastest turn between linked positions kept, ``cone_deg`` the range of angles between the axes
    and the normals, ``swing_deg`` the largest angle from the set-up axis; the biarcs of
    :func:`biarc_figures`; ``n_unwinding_links`` the short links routed through the safe height so
    that the post can turn a continuous C back (:mod:`planning.toolpath.fiveaxis.register`); ``links``
    the figures of the links planned on the stock
    (:meth:`planning.toolpath.fiveaxis.links.LinkFigures.as_dict`; empty without a stock)."""

    n_positions: int = 0
    n_alternatives: int = 0
    blocked: dict = field(default_factory=dict)
    max_rate_deg_per_mm: float = 0.0
    cone_deg: tuple[float, float] = (0.0, 0.0)
    swing_deg: float = 0.0
    n_moves_before_biarcs: int = 0
    n_biarcs: int = 0
    n_arcs: int = 0
    biarc_max_error_mm: float = 0.0
    biarc_min_clearance_mm: float = math.inf
    n_unwinding_links: int = 0
    links: dict = field(default_factory=dict)


#: Along a move between two cutting positions, the points checked (:func:`_between_fractions`) are at
#: most this far apart on the ball centre's path (mm) ...
BETWEEN_STEP_MM = 0.25
#: ... and the axis turns at most this much between them (degrees).
BETWEEN_TURN_DEG = 1.0


def _between_fractions(c0: np.ndarray, c1: np.ndarray, a0: np.ndarray, a1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(owner (k,), u (k,))``: the points checked along the moves from centres ``c0`` to ``c1``
    (m,3) with axes ``a0`` to ``a1`` (m,3, unit): per move its ``n - 1`` inner fractions ``i / n``,
    ``n = max(2, ceil(length / BETWEEN_STEP_MM), ceil(turn / BETWEEN_TURN_DEG))`` (a short, slowly
    turning move: its midpoint alone); ``owner`` the move of each."""
    length = np.linalg.norm(c1 - c0, axis=1)
    turn = turn_deg(a0, a1)
    n = np.maximum(2, np.maximum(np.ceil(length / BETWEEN_STEP_MM), np.ceil(turn / BETWEEN_TURN_DEG))).astype(np.int64)
    owner = np.repeat(np.arange(c0.shape[0]), n - 1)
    first = np.cumsum(n - 1) - (n - 1)
    i = np.arange(owner.size) - first[owner] + 1
    return owner, i / n[owner]


def between_ok(admissible, c0: np.ndarray, c1: np.ndarray, a0: np.ndarray, a1: np.ndarray) -> np.ndarray:
    """(m,) bool: the moves from centres ``c0`` to ``c1`` (m,3, area frame) with axes ``a0`` to ``a1``
    (m,3, unit) are admissible between their ends (module docstring, step 3): ``admissible`` (an
    :class:`Admissible`) at every point :func:`_between_fractions` gives (the centre on the segment,
    the axis along the great circle), and the axis's arc clear of the rotary pole."""
    owner, u = _between_fractions(c0, c1, a0, a1)
    c = c0[owner] + u[:, None] * (c1[owner] - c0[owner])
    a = slerp(a0[owner], a1[owner], u)
    fails = np.zeros(c0.shape[0], dtype=bool)
    np.logical_or.at(fails, owner, ~admissible(c, a))
    return ~fails & admissible.arc_clear_of_pole(a0, a1)


class Admissible:
    """``ok(centres, axes) -> bool (n,)`` for positions in the AREA frame (module docstring, step 2):
    within ``max_swing_deg`` of the frame's +Z, the tool assembly clear of ``obstacles_f`` (area
    frame), the shank and holder clear of ``stock_f`` (points on the boundary of the stock left
    before this finishing, area frame: the flutes may cut it, the shank and holder may not; the
    points are ``simulate.resolution_mm`` apart, so this is a screen and the guard on the stock
    model decides), and, with ``machine`` (a :class:`planning.simulate.kinematics.MachineModel`) and
    ``gauge_mm``, reachable: a rotary solution within travel putting the tip within the linear
    travel, and at least ``pole_clearance_deg`` from the machine's rotary pole (the tool axis at zero
    tilt: near it the rotary axis turns fast for a small change of the tool axis)."""

    def __init__(self, frame: AreaFrame, obstacles_f: np.ndarray, tool: ToolAssembly, *, max_swing_deg: float,
                 machine=None, gauge_mm: float | None = None, stock_f: np.ndarray | None = None,
                 pole_clearance_deg: float = 0.0):
        self.frame = frame
        self.tool = tool
        self.grid = ObstacleGrid(obstacles_f, default_cell_mm(tool))
        self.stock_grid = None
        if stock_f is not None and len(stock_f):
            self.stock_grid = ObstacleGrid(stock_f, default_cell_mm(tool, ("shank", "holder")))
        self.cos_swing = math.cos(math.radians(float(max_swing_deg)))
        self.machine = machine
        self.gauge = gauge_mm
        self.calls = 0
        self.pole_f = None
        self.cos_pole = math.cos(math.radians(float(pole_clearance_deg)))
        if machine is not None and pole_clearance_deg > 0:
            from planning.orientations.kinematics import tool_axis_from_angles

            self.pole_f = frame.rotation @ tool_axis_from_angles(np.zeros((1, 2)), machine.profile)[0]

    def arc_clear_of_pole(self, a0: np.ndarray, a1: np.ndarray) -> np.ndarray:
        """(n,) bool: the great-circle arc from ``a0`` to ``a1`` (n,3 unit, area frame), along which the
        axis turns between two positions, stays ``pole_clearance_deg`` from the rotary pole (True
        without a machine)."""
        n = a0.shape[0]
        if self.pole_f is None or n == 0:
            return np.ones(n, dtype=bool)
        p = self.pole_f
        nrm = np.cross(a0, a1)
        ln = np.linalg.norm(nrm, axis=1)
        near_ends = np.maximum(a0 @ p, a1 @ p)                     # cos of the smaller end angle
        # the pole's foot on the arc's great circle, and whether it lies between a0 and a1
        u = nrm / np.where(ln > 1e-12, ln, 1.0)[:, None]
        foot = p[None, :] - (u @ p)[:, None] * u
        fl = np.linalg.norm(foot, axis=1)
        foot = foot / np.where(fl > 1e-12, fl, 1.0)[:, None]
        inside = (ln > 1e-12) & (fl > 1e-12) & (np.einsum("ij,ij->i", np.cross(a0, foot), u) >= 0) \
            & (np.einsum("ij,ij->i", np.cross(foot, a1), u) >= 0)
        cos_min = np.where(inside, np.einsum("ij,ij->i", foot, np.broadcast_to(p, foot.shape)), near_ends)
        return cos_min < self.cos_pole

    def solution_flips(self, axes_f: np.ndarray, runs: np.ndarray) -> np.ndarray:
        """(n,) bool: position i is the first after a change of rotary solution along its run (the tilt
        changes sign outside the pole cone, as :func:`planning.post.simultaneous.rotary_path` picks
        the angles: it keeps the branch while the travel allows): between i-1 and i the machine would
        swing the table through the pole on the surface, which no control can follow; the pass is
        broken there."""
        n = axes_f.shape[0]
        out = np.zeros(n, dtype=bool)
        if self.machine is None or n < 2:
            return out
        from planning.post.simultaneous import POLE_DEG, rotary_path

        ang, _ = rotary_path(axes_f @ self.frame.rotation, self.machine.profile)
        t = ang[:, 0]
        linked = (runs[1:] == runs[:-1]) & (runs[1:] >= 0)
        out[1:] = linked & (t[1:] * t[:-1] < 0) & (np.abs(t[1:]) > POLE_DEG) & (np.abs(t[:-1]) > POLE_DEG)
        return out

    def reachable(self, centres_f: np.ndarray, axes_f: np.ndarray) -> np.ndarray:
        """(n,) bool: some rotary solution within the rotary travel puts the tool tip within the linear
        travel (both solutions of :func:`planning.orientations.kinematics.solve_rotary` tried)."""
        from planning.orientations.kinematics import solve_rotary

        m = self.machine
        n = centres_f.shape[0]
        if m is None or n == 0:
            return np.ones(n, dtype=bool)
        axes_p = axes_f @ self.frame.rotation
        tips_p = self.frame.to_part(centres_f) - self.tool.radius_mm * axes_p
        sols = solve_rotary(axes_p, m.profile)
        out = np.zeros(n, dtype=bool)
        (x0, x1), (y0, y1), (z0, z1) = m.profile.linear_limits_mm
        lo, hi = np.array([x0, y0, z0]) - 1e-6, np.array([x1, y1, z1]) + 1e-6
        for j in range(2):
            valid = np.asarray(sols.valid[:, j], dtype=bool)
            if not valid.any():
                continue
            mpos = m.machine_from_tip(tips_p[valid], sols.angles_deg[valid, j], self.gauge)
            inside = np.all((mpos >= lo) & (mpos <= hi), axis=1)
            out[np.flatnonzero(valid)[inside]] = True
        return out

    def __call__(self, centres_f: np.ndarray, axes_f: np.ndarray) -> np.ndarray:
        self.calls += 1
        c = np.asarray(centres_f, dtype=np.float64).reshape(-1, 3)
        a = np.asarray(axes_f, dtype=np.float64).reshape(-1, 3)
        ok = a[:, 2] >= self.cos_swing - 1e-12
        if self.pole_f is not None:
            ok &= (a @ self.pole_f) < self.cos_pole
        idx = np.flatnonzero(ok)
        if idx.size:
            ok[idx] = self.reachable(c[idx], a[idx])
        idx = np.flatnonzero(ok)
        if idx.size:
            ok[idx] = self.grid.free(c[idx], a[idx], self.tool)
        if self.stock_grid is not None:
            idx = np.flatnonzero(ok)
            if idx.size:
                ok[idx] = self.stock_grid.free(c[idx], a[idx], self.tool, parts=("shank", "holder"))
        return ok


def _touching(tp: Toolpath) -> np.ndarray:
    """(P,) bool: the points reached by a feed move that cuts or plunges (on the part)."""
    return (tp.kind == FEED) & np.isin(tp.use, (USE_CUT, USE_PLUNGE))


def _runs(touch: np.ndarray) -> np.ndarray:
    """(P,) run id of consecutive touching points (-1 elsewhere): the stretches smoothed together."""
    start = touch & ~np.concatenate([[False], touch[:-1]])
    rid = np.cumsum(start) - 1
    return np.where(touch, rid, -1)


def _fill_axes(tp: Toolpath, touch: np.ndarray, axes_touch: np.ndarray) -> np.ndarray:
    """(P,3) an axis for every point: the touching points their own; the points that leave one (its
    retracts, straight or as a lead-out ramp, then the column straight up, frame z, to the safe
    height) the axis of that point; any other point (the rapid across at the safe height, the way
    down to the next touching point) the next one's (the last one's after the last): the axis turns
    during the rapid across."""
    P = tp.n_moves
    out = np.empty((P, 3))
    idx = np.flatnonzero(touch)
    if idx.size == 0:
        out[:] = [0.0, 0.0, 1.0]
        return out
    out[idx] = axes_touch
    rest = np.flatnonzero(~touch)
    prv = np.searchsorted(idx, rest) - 1
    nxt = prv + 1
    # leaving: the retracts after a touching point and the column straight up over the last of them
    # (frame z; the rapid up to the safe height) keep its axis, as one chain
    xyz = tp.xyz_mm
    up = np.zeros(P, dtype=bool)
    up[1:] = (np.hypot(*(xyz[1:, :2] - xyz[:-1, :2]).T) <= 1e-6) & (xyz[1:, 2] >= xyz[:-1, 2])
    cond = (tp.use == USE_RETRACT) | up
    fail = (~touch & ~cond).astype(np.int64)
    run_start = ~touch & np.r_[True, touch[:-1]]
    cum = np.cumsum(fail)
    base = np.maximum.accumulate(np.where(run_start, np.arange(P), 0))
    before = np.where(base > 0, cum[np.maximum(base - 1, 0)], 0)
    chain = ~touch & (cum - before == 0)
    chain[0] = False
    use_prev = (chain[rest] & (prv >= 0)) | (nxt >= idx.size)
    out[rest[use_prev]] = out[idx[np.maximum(prv[use_prev], 0)]]
    out[rest[~use_prev]] = out[idx[nxt[~use_prev]]]
    return out


def axis_runs(tp: Toolpath, max_turn_deg: float = REDUCE_AXIS_DEG) -> np.ndarray:
    """(P,) int32 run ids for :func:`planning.toolpath.reduce.reduce_cl` on a 5-axis path: consecutive
    touching points whose axis has turned less than ``max_turn_deg`` in all since the run began
    share an id (the reducer drops points only inside a run); -1 elsewhere."""
    touch = _touching(tp)
    P = tp.n_moves
    turn = np.zeros(P)
    if P > 1:
        turn[1:] = turn_deg(tp.axis[1:], tp.axis[:-1])
    start = touch & ~np.concatenate([[False], touch[:-1]])
    run = np.cumsum(start)
    # cumulative turn within each run of touching points, then a new id every max_turn_deg
    cum = np.cumsum(np.where(touch & ~start, turn, 0.0))
    # the cumulative turn where the current run began (forward fill of the run starts)
    at = np.maximum.accumulate(np.where(start, np.arange(P), 0)) if P else np.zeros(0, np.int64)
    base = cum[at] if P else cum
    step = np.where(touch, np.floor((cum - base) / float(max_turn_deg)), 0).astype(np.int64)
    key = run * (P + 1) + step
    ids = np.concatenate([[0], np.cumsum(key[1:] != key[:-1])]) if P else np.zeros(0, np.int64)
    return np.where(touch, ids, -1).astype(np.int32)


def axis_columns(tp: Toolpath) -> Toolpath:
    """``tp`` (with ``axis``) with the foot of its vertical columns turned onto the tool axis: a point off
    the part (a retract, an approach) at most :data:`AXIS_COLUMN_MM` straight above (frame z) the
    touching point
    next to it in the same run of such points, the last one before it for the points after a
    touching point, the next one after for the points before it, is moved along that touching
    point's axis to the same frame height: the tool leaves and enters the surface along its own axis,
    as 5-axis programs do, instead of sliding with its shank leaning; the rest of the column, to the
    safe height, stays straight up. Heights (frame z) are kept."""
    if tp.axis is None or tp.n_moves == 0:
        return tp
    touch = _touching(tp)
    idx = np.flatnonzero(touch)
    if idx.size == 0:
        return tp
    xyz = tp.xyz_mm.copy()
    rest = np.flatnonzero(~touch)
    prv = np.searchsorted(idx, rest) - 1
    nxt = prv + 1
    for anchor_sel, anchor in (((prv >= 0), idx[np.maximum(prv, 0)]), ((nxt < idx.size), idx[np.minimum(nxt, idx.size - 1)])):
        p = tp.xyz_mm[anchor]
        q = xyz[rest]
        col = anchor_sel & (np.hypot(q[:, 0] - p[:, 0], q[:, 1] - p[:, 1]) <= 1e-6) & (q[:, 2] >= p[:, 2])
        col &= q[:, 2] - p[:, 2] <= AXIS_COLUMN_MM + 1e-9       # the way off the surface, not to the safe height
        col &= np.all(np.abs(q - tp.xyz_mm[rest]) <= 0, axis=1)     # each point moved once
        a = tp.axis[anchor]
        dz = (q[:, 2] - p[:, 2]) / np.maximum(a[:, 2], 1e-9)
        moved = p + a * dz[:, None]
        xyz[rest[col]] = moved[col]
    return Toolpath(xyz_mm=xyz, kind=tp.kind, centre_mm=tp.centre_mm, plane=tp.plane, use=tp.use,
                    tip_offset_mm=tp.tip_offset_mm, axis=tp.axis)


def five_axis_path(tp: Toolpath, pass_index: np.ndarray | None, *, cloud_f: np.ndarray, admissible: Admissible,
                   fp, cone_deg, safe_z_mm: float, tree: cKDTree | None = None,
                   floor=None, links=None) -> tuple[Toolpath, np.ndarray, FiveAxisFigures]:
    """The 5-axis version of the finishing toolpath ``tp`` (module docstring): ``(toolpath with
    axis, pass_index, figures)``. ``cloud_f`` (N,3): the scan in the area frame (contact normals);
    ``admissible``: the test of step 2; ``fp``: :class:`schemas.params.FinishingParams` (lead, tilt,
    frame, rate); ``cone_deg``: ``visibility.cone_deg``; ``safe_z_mm``: the ball-centre height of
    retracts (area frame); ``floor``: the part's :class:`planning.toolpath.carried.Footprint` (positions
    whose ball reaches below the part's underside inside it are cut out first, as in 3+2); ``links``: a
    :class:`planning.toolpath.fiveaxis.links.StockLinks` (None: the links stay as the cut made them)."""
    figs = FiveAxisFigures()
    blocked = {"no_axis": 0, "between": 0, "rate": 0, "floor": 0, "flip": 0}
    pi = None if pass_index is None else np.asarray(pass_index)
    tree = cKDTree(cloud_f) if tree is None else tree
    if floor is not None and tp.n_moves:
        touch = _touching(tp)
        low = np.zeros(tp.n_moves, dtype=bool)
        low[touch] = floor.below_floor(admissible.frame.to_part(tp.xyz_mm[touch]), admissible.tool.radius_mm,
                                       float(fp.tolerance_mm))
        if low.any():
            blocked["floor"] = int(low.sum())
            cut = cut_moves(tp, low, safe_z_mm=safe_z_mm, pass_index=pi)
            tp, pi = cut.toolpath, cut.pass_index
    memo: dict = {}               # the ring search's answers by position, across the attempts
    for attempt in range(3):
        if tp.n_moves == 0:
            break
        touch = _touching(tp)
        idx = np.flatnonzero(touch)
        c = tp.xyz_mm[idx]
        nrm = contact_normals(c, cloud_f, tree)
        runs = _runs(touch)
        plan = plan_axes(c, runs[idx], nrm, lead_deg=fp.lead_deg, tilt_deg=fp.tilt_deg, cone_deg=cone_deg,
                         max_rate_deg_per_mm=fp.max_axis_rate_deg_per_mm, frame=fp.axis_frame, ok=admissible,
                         memo=memo)
        if attempt == 0:
            figs.n_positions = int(idx.size)
            figs.n_alternatives = int(plan.n_alternatives)
        drop = np.zeros(tp.n_moves, dtype=bool)
        drop[idx[plan.blocked]] = True
        blocked["no_axis"] += int(plan.blocked.sum())
        drop[idx[plan.breaks]] = True
        blocked["rate"] += int((plan.breaks & ~plan.blocked).sum())
        # along every move between two kept touching positions
        pair = np.flatnonzero(touch[1:] & touch[:-1]) + 1
        ok_pos = np.zeros(tp.n_moves, dtype=bool)
        ok_pos[idx[~plan.blocked]] = True
        pair = pair[ok_pos[pair] & ok_pos[pair - 1]]
        if pair.size:
            ax = np.empty((tp.n_moves, 3))
            ax[idx] = plan.axes
            bad = ~between_ok(admissible, tp.xyz_mm[pair - 1], tp.xyz_mm[pair], ax[pair - 1], ax[pair])
            drop[pair[bad]] = True
            blocked["between"] += int((bad & ~drop[pair - 1]).sum())
        with_axes = Toolpath(xyz_mm=tp.xyz_mm, kind=tp.kind, centre_mm=tp.centre_mm, plane=tp.plane, use=tp.use,
                             tip_offset_mm=tp.tip_offset_mm, axis=_fill_axes(tp, touch, plan.axes))
        # the rotary solutions along the whole path as the post picks them: a change between two
        # cutting positions breaks the pass there
        flips = admissible.solution_flips(with_axes.axis, runs) & ~drop
        drop |= flips
        blocked["flip"] += int(flips.sum())
        if not drop.any():
            tp = with_axes
            break
        cut = cut_moves(with_axes, drop, safe_z_mm=safe_z_mm, pass_index=pi)
        tp, pi = cut.toolpath, cut.pass_index
        if tp.n_moves == 0:
            break
    figs.blocked = blocked
    tp = axis_columns(tp)
    if links is not None and tp.n_moves:
        tp, pi = links(tp, pi)
        figs.links = links.figures.as_dict()
    if admissible.machine is not None and tp.n_moves:
        tp, pi, figs.n_unwinding_links = route_unwinding_links(
            tp, pi, profile=admissible.machine.profile, rotation=admissible.frame.rotation, safe_z_mm=safe_z_mm)
    if tp.n_moves and tp.axis is not None:
        touch = _touching(tp)
        idx = np.flatnonzero(touch)
        if idx.size:
            a = tp.axis[idx]
            nrm = contact_normals(tp.xyz_mm[idx], cloud_f, tree)
            ang = turn_deg(a, nrm)
            figs.cone_deg = (round(float(ang.min()), 3), round(float(ang.max()), 3))
            figs.swing_deg = round(float(np.degrees(np.arccos(np.clip(a[:, 2].min(), -1, 1)))), 3)
            lk = np.flatnonzero(touch[1:] & touch[:-1]) + 1
            if lk.size:
                d = np.linalg.norm(tp.xyz_mm[lk] - tp.xyz_mm[lk - 1], axis=1)
                rate = turn_deg(tp.axis[lk], tp.axis[lk - 1]) / np.maximum(d, 1e-9)
                figs.max_rate_deg_per_mm = round(float(rate[d > 1e-6].max()) if (d > 1e-6).any() else 0.0, 4)
    return tp, pi, figs


def biarc_figures(tp: Toolpath, figs: FiveAxisFigures, *, binned, radius_mm: float, tol_mm: float) -> None:
    """3D biarcs through the ball centres of the touching runs of ``tp`` (Chui 2008 App. A,
    :func:`planning.toolpath.fiveaxis.biarc.fit_biarcs`, every centre within ``tol_mm``), their move
    count against the path's, their largest error and the clearance of the fitted curve from the cloud
    (``binned``: :class:`planning.toolpath.verify.BinnedCloud` of the area frame; chords within
    :data:`BIARC_CHORD_MM`) into ``figs``."""
    from planning.toolpath.fiveaxis.biarc import biarc_chords, fit_biarcs
    from planning.toolpath.moves import lines
    from planning.toolpath.verify import move_clearance

    touch = _touching(tp)
    idx = np.flatnonzero(touch)
    if idx.size < 2:
        return
    # a new piece wherever the run of touching points is interrupted
    breaks = np.flatnonzero(np.diff(idx) > 1) + 1
    pts = tp.xyz_mm[idx]
    corners: set[int] = set()
    R = float(radius_mm)
    memo: dict = {}                    # a refit fits again only the pieces the new corners split
    for _ in range(8):
        fit = fit_biarcs(pts, float(tol_mm), breaks=breaks, corners=sorted(corners), memo=memo)
        if fit.n_biarcs == 0:
            break
        owner, chords = biarc_chords(fit.biarcs, BIARC_CHORD_MM)
        # one polyline per piece: a new piece starts where the previous biarc does not end
        piece = np.asarray(fit.path_piece)[owner]
        use = np.where(np.r_[True, piece[1:] != piece[:-1]], 0, 1).astype(np.int8)
        clear = move_clearance(lines(chords, use), binned, R)
        bad = np.isfinite(clear) & (clear < R - float(tol_mm))
        if not bad.any():
            break
        # gouge-checked: a biarc that comes too close to the cloud is split at its middle point and refitted
        spans = np.unique(owner[bad])
        s0, s1 = np.asarray(fit.span_start)[spans], np.asarray(fit.span_end)[spans]
        mid = (s0 + s1) // 2
        new = {int(m) for m, a, b in zip(mid, s0, s1) if a < m < b}
        # a biarc between two neighbouring points that still comes too close: both become corners, so
        # the piece between them is the straight move itself (which the path's gouge check passed)
        new |= {int(v) for a, b in zip(s0, s1) if b == a + 1 for v in (a, b)}
        if not new - corners:
            break
        corners |= new
    figs.n_moves_before_biarcs = int(idx.size - 1 - breaks.size)
    figs.n_biarcs, figs.n_arcs = int(fit.n_biarcs), int(fit.n_arcs_out)
    figs.biarc_max_error_mm = round(float(fit.max_error_mm), 6)
    if fit.n_biarcs:
        ok = np.isfinite(clear)
        figs.biarc_min_clearance_mm = round(float(min(np.min(clear[ok]) if ok.any() else R, R)), 6)
