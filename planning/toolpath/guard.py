"""The last check of a set-up's tool paths before they are posted (issue 16): every move run on the
stock the set-ups before it left, against the fixtures, the riser and the table, and against the
machine's travel, with the same tri-dexel kernels and the same machine model as the verification
(:mod:`planning.simulate`); what would crash is taken out, not written.

One operation (roughing or finishing of one area, a :class:`~planning.toolpath.moves.Toolpath` in
the area frame) is guarded by :func:`guard_toolpath`:

1. its moves as the control runs them: tool-tip segments in the part frame, arcs split into chords
   (:func:`part_moves`); a simultaneous 5-axis path as its LinuxCNC program moves the machine (the
   caller's ``moves``, :mod:`planning.toolpath.fiveaxis.program_moves`: the post's inserted points,
   joint-space steps), since the planned straight moves leave the tool elsewhere between points;
2. on a copy of the current stock, in program order (:func:`planning.simulate.dexel.simulate_moves`):
   a rapid whose tool (grown by the rapid clearance) meets material, a feed move whose shank or
   holder meets material; against the obstacles (:func:`planning.simulate.dexel.collide`): any
   part of the tool in a fixture, the riser or the table; the controlled point of every move end
   beyond the profile's linear travel (:class:`SetupMachine`, the posts' kinematics);
3. repairs, then again from step 2 (at most ``max_rounds`` times): a rapid into material goes over
   it instead: up along the tool axis to the safe height (fed until the column is clear of the
   stock), across, rapid down to where the column meets stock and fed from there (the columns above
   the path's points are clear of the part, so only stock is cut; a rapid straight across could cut
   the part); the end point of any other offending move is cut out of the path
   (:func:`planning.toolpath.safety.cut_moves`: the path retracts along the tool axis to the safe
   height before it and comes down after it; a 5-axis path's new links are then planned on the
   stock by the caller's ``relink``, :mod:`planning.toolpath.fiveaxis.links`);
4. what still offends after the last round: the path is cut off before its first offending move
   and ends with a retract (``truncated``), so no program carries a known collision.

The stock that the accepted moves leave is handed to the next operation (the carried stock of
:mod:`planning.toolpath.area_paths`). Lengths in mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planning.progress import Progress, Throttled
from planning.simulate.dexel import TriDexel, collides, column_rise, simulate_moves
from planning.simulate.kinematics import MachineModel, arc_chords
from planning.simulate.motion import FEED as SIM_FEED
from planning.simulate.motion import RAPID as SIM_RAPID
from planning.simulate.motion import SimulatedMoves, ToolShape
from planning.toolpath.fiveaxis.axes import slerp
from planning.toolpath.frames import AreaFrame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
)

#: Chord tolerance of arcs when the guard runs them (mm); the reader of the programs uses its own.
CHORD_TOL_MM = 0.005

#: Largest axis turn of one simulated step of a 5-axis move (degrees; the program reader steps 1 degree).
AXIS_STEP_DEG = 1.0

#: How far above the exact height (mm, on the stock's rays) :func:`column_clear_z` may answer.
COLUMN_TOL_MM = 0.02

#: Slack on the travel limits (mm): a position this close to a limit counts as within it.
TRAVEL_SLACK_MM = 1e-6


@dataclass
class SetupMachine:
    """The machine at one set-up: ``model`` (:class:`MachineModel`, the part placed on the table),
    ``angles_deg`` (2,) the set-up's (tilt, rotary) position. :meth:`travel_ok` says which tool tips
    the controlled point reaches within the profile's linear travel."""

    model: MachineModel
    angles_deg: np.ndarray

    def travel_ok(self, tips_part: np.ndarray, gauge_mm: float) -> np.ndarray:
        """(n,) bool: the controlled point (table-table: the spindle gauge point; head-head: the
        head's pivot) that puts the tool tip at ``tips_part`` (n,3, part frame, mm) with a tool of
        gauge length ``gauge_mm`` lies within ``x/y/z_limits_mm`` (the same test as
        :func:`planning.simulate.program.check_travel`)."""
        tips = np.asarray(tips_part, dtype=np.float64).reshape(-1, 3)
        if tips.shape[0] == 0:
            return np.zeros(0, dtype=bool)
        m = self.model.machine_from_tip(tips, self.angles_deg, gauge_mm)
        ok = np.ones(tips.shape[0], dtype=bool)
        for i, (lo, hi) in enumerate(self.model.profile.linear_limits_mm):
            ok &= (m[:, i] >= lo - TRAVEL_SLACK_MM) & (m[:, i] <= hi + TRAVEL_SLACK_MM)
        return ok


@dataclass
class PartMoves:
    """One toolpath as straight tool-tip segments in the part frame: ``start``/``end`` (P,3),
    ``kind`` (P,) :data:`planning.simulate.motion.RAPID` / ``FEED``, ``source`` (P,) the toolpath
    move each segment belongs to, ``axis`` (3,) the tool axis (part frame)."""

    start: np.ndarray
    end: np.ndarray
    kind: np.ndarray
    source: np.ndarray
    axis: np.ndarray


def part_moves(tp: Toolpath, frame: AreaFrame, start_tip_frame=None, chord_tol_mm: float = CHORD_TOL_MM,
               axis_step_deg: float = AXIS_STEP_DEG) -> PartMoves:
    """The moves of ``tp`` (area frame) as tool-tip segments in the part frame, arcs as chords within
    ``chord_tol_mm``. Move 0 starts at ``start_tip_frame`` (the tip, area frame), default: straight
    above its end point at the same position (a zero-length first move). A 5-axis path (``tp.axis``)
    is split where its axis turns, in steps of at most ``axis_step_deg`` (the reference point moved
    linearly, the axis along the great circle; each step runs with its end's axis, as the program
    reader runs the rotary axes); ``axis`` is then (P', 3)."""
    if tp.axis is not None:
        return _part_moves_5axis(tp, frame, start_tip_frame, axis_step_deg)
    tip = tp.tip_mm()
    P = tp.n_moves
    off = np.array([0.0, 0.0, tp.tip_offset_mm])
    arcs = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)))
    pts = [tip]
    src = [np.arange(P)]
    if arcs.size:
        prev = np.where(arcs > 0, arcs - 1, arcs)
        axes = np.array([PLANE_AXES[int(p)] for p in tp.plane[arcs]], dtype=np.int64)
        turns = np.where(tp.kind[arcs] == ARC_CCW, 1, -1)
        owner, chords = arc_chords(tip[prev], tip[arcs], tp.centre_mm[arcs] - off, axes, turns, chord_tol_mm)
        # replace each arc's single end point by its chord points (the last one is the end)
        keep = np.ones(P, dtype=bool)
        keep[arcs] = False
        pts = [tip[keep], chords]
        src = [np.flatnonzero(keep), arcs[owner]]
    order = np.argsort(np.concatenate(src), kind="stable")
    end_f = np.concatenate(pts)[order]
    source = np.concatenate(src)[order]
    first = tip[0] if start_tip_frame is None else np.asarray(start_tip_frame, dtype=np.float64)
    start_f = np.concatenate([first[None, :], end_f[:-1]])
    kind = np.where(tp.kind[source] == RAPID, SIM_RAPID, SIM_FEED).astype(np.int8)
    axis = frame.rotation[2].copy()
    return PartMoves(start=frame.to_part(start_f), end=frame.to_part(end_f), kind=kind, source=source, axis=axis)


def _part_moves_5axis(tp: Toolpath, frame: AreaFrame, start_tip_frame, step_deg: float) -> PartMoves:
    """:func:`part_moves` of a 5-axis path (straight moves, an axis per end point)."""
    P = tp.n_moves
    ref = tp.xyz_mm
    ax = tp.axis / np.linalg.norm(tp.axis, axis=1, keepdims=True)
    a0 = np.vstack([ax[:1], ax[:-1]])
    r0 = np.vstack([ref[:1], ref[:-1]])
    cos = np.clip(np.einsum("ij,ij->i", a0, ax), -1.0, 1.0)
    ang = np.degrees(np.arccos(cos))
    n = np.maximum(1, np.ceil(ang / float(step_deg) - 1e-12)).astype(np.int64)
    source = np.repeat(np.arange(P), n)
    k = np.arange(source.size) - (np.cumsum(n) - n)[source]
    f1 = ((k + 1) / n[source])[:, None]
    a_end = slerp(a0[source], ax[source], f1[:, 0])
    r_end = r0[source] + f1 * (ref - r0)[source]
    tip_end = r_end - tp.tip_offset_mm * a_end
    first = tp.tip_mm()[0] if start_tip_frame is None else np.asarray(start_tip_frame, dtype=np.float64)
    tip_start = np.concatenate([first[None, :], tip_end[:-1]])
    kind = np.where(tp.kind[source] == RAPID, SIM_RAPID, SIM_FEED).astype(np.int8)
    return PartMoves(start=frame.to_part(tip_start), end=frame.to_part(tip_end), kind=kind, source=source,
                     axis=a_end @ frame.rotation)


@dataclass
class Offences:
    """Per toolpath move (P,) bool: ``rapid`` a rapid whose tool meets material; ``holder`` a feed
    move whose shank or holder meets material; ``fixture`` the tool in a fixture, the riser or the
    table; ``travel`` a move end beyond the travel."""

    rapid: np.ndarray
    holder: np.ndarray
    fixture: np.ndarray
    travel: np.ndarray

    @property
    def any(self) -> np.ndarray:
        return self.rapid | self.holder | self.fixture | self.travel

    def counts(self) -> dict:
        return {k: int(getattr(self, k).sum()) for k in ("rapid", "holder", "fixture", "travel")}


class _FixtureMemo:
    """The obstacle check of :func:`run_on_stock` per part move, kept across the repair rounds of one
    operation: it depends on the move alone (the obstacles do not change, the tool and its axis are
    the operation's), so a round checks only the moves the previous rounds did not."""

    def __init__(self):
        self.keys = np.zeros((0, 6))
        self.hit = np.zeros(0, dtype=bool)

    def check(self, obstacles: TriDexel, pm: PartMoves, ax: np.ndarray, shape: ToolShape, progress=None):
        key = np.ascontiguousarray(np.concatenate([pm.start, pm.end], axis=1))
        n = key.shape[0]
        out = np.zeros(n, dtype=bool)
        known = np.zeros(n, dtype=bool)
        if self.keys.shape[0]:
            row = np.dtype((np.void, key.dtype.itemsize * 6))
            old = self.keys.view(row).ravel()
            new = key.view(row).ravel()
            order = np.argsort(old, kind="stable")
            pos = np.searchsorted(old[order], new)
            pos = np.minimum(pos, old.shape[0] - 1)
            known = old[order][pos] == new
            out[known] = self.hit[order[pos[known]]]
        todo = np.flatnonzero(~known)
        if todo.size:
            # the same answer as collide move by move, by runs along the path (the obstacles are far
            # from most moves)
            out[todo] = collides(obstacles, pm.start[todo], pm.end[todo], ax[todo], shape, which="tool",
                                 progress=progress)
        self.keys, self.hit = key, out
        return out


def run_on_stock(tp: Toolpath, frame: AreaFrame, shape: ToolShape, stock: TriDexel, obstacles: TriDexel | None,
                 machine: SetupMachine | None, *, rapid_clearance_mm: float, progress: Progress | None = None,
                 _fixtures: _FixtureMemo | None = None, keep: dict | None = None, moves=None
                 ) -> tuple[Offences, TriDexel, np.ndarray]:
    """Steps 1-2 of the module docstring: ``(offences per toolpath move, the stock after the moves
    (a copy; ``stock`` is unchanged), removed volume per toolpath move mm^3)``. ``progress``:
    ``progress(fraction, message)`` (unthrottled: the caller's). ``keep``: a dict that receives the
    run's part moves and figures as ``keep["moves"]`` (:class:`~planning.simulate.motion.SimulatedMoves`).
    ``moves``: ``(toolpath, frame) -> PartMoves``, the moves the machine makes (None: :func:`part_moves`;
    a 5-axis path: :func:`planning.toolpath.fiveaxis.program_moves.program_part_moves`)."""
    pm = part_moves(tp, frame) if moves is None else moves(tp, frame)
    P = tp.n_moves
    n = pm.start.shape[0]
    ax = np.broadcast_to(pm.axis, (n, 3))
    after = stock.copy()
    sim_part = fix_part = None
    if progress is not None:
        sim_part = lambda f, msg: progress(0.8 * f, f"stock: {msg}")            # noqa: E731
        fix_part = lambda f, msg: progress(0.8 + 0.2 * f, f"fixtures: {msg}")   # noqa: E731
    run = simulate_moves(after, pm.start, pm.end, ax, shape, pm.kind, rapid_clearance_mm=rapid_clearance_mm,
                         progress=sim_part)

    def per_move(flag: np.ndarray) -> np.ndarray:
        out = np.zeros(P, dtype=bool)
        out[pm.source[flag]] = True
        return out

    fixture = np.zeros(n, dtype=bool)
    if obstacles is not None:
        fixture = (_FixtureMemo() if _fixtures is None else _fixtures).check(obstacles, pm, ax, shape, fix_part)
    travel = np.zeros(n, dtype=bool)
    if machine is not None:
        travel = ~machine.travel_ok(pm.end, shape.gauge_length_mm)
    removed = np.zeros(P)
    np.add.at(removed, pm.source, run.removed_mm3)
    if keep is not None:
        keep["moves"] = SimulatedMoves(
            tool=int(shape.number), source=pm.source, start_mm=pm.start, end_mm=pm.end, axis=np.ascontiguousarray(ax), kind=pm.kind,
            removed_mm3=run.removed_mm3, rapid_depth_mm=run.rapid_depth_mm, holder_depth_mm=run.holder_depth_mm,
            fixture=fixture, travel=travel, rapid_clearance_mm=float(rapid_clearance_mm),
            stock_before=stock, stock_after=after)
    return (Offences(rapid=per_move(run.rapid_depth_mm > 0), holder=per_move(run.holder_depth_mm > 0),
                     fixture=per_move(fixture), travel=per_move(travel)), after, removed)


@dataclass
class GuardOutcome:
    """The guarded operation: ``toolpath`` and its ``pass_index`` (None when none was given);
    ``stock`` the stock after it; ``found`` the offences of the first run (per class, moves);
    ``rapids_to_feed`` rapids replaced by a way over the stock (up, across, down); ``dropped`` CL points cut out; ``truncated`` moves
    cut off at the end (step 4); ``rounds`` the runs made; ``removed_mm3`` the volume it removes; ``moves`` the
    accepted run's moves and figures (None when nothing ran), which the verification takes when it
    proves the posted program runs them (:mod:`planning.simulate.single_pass`)."""

    toolpath: Toolpath
    pass_index: np.ndarray | None
    stock: TriDexel
    found: dict = field(default_factory=dict)
    rapids_to_feed: int = 0
    dropped: int = 0
    truncated: int = 0
    rounds: int = 0
    removed_mm3: float = 0.0
    moves: SimulatedMoves | None = None

    @property
    def clean(self) -> bool:
        return self.truncated == 0


def column_clear_z(frame: AreaFrame, shape: ToolShape, stock: TriDexel, points_frame: np.ndarray, top_z: float,
                   tip_offset_mm: float, clearance_mm: float, step_mm: float | None = None) -> np.ndarray:
    """(n,) for each reference point (area frame, n,3) the lowest height (reference point, frame z) at
    or above it from which the tool, moved straight up the tool axis to ``top_z``, never comes
    within ``clearance_mm`` of the stock, to ``step_mm`` (default :data:`COLUMN_TOL_MM`) above the
    exact one on the stock's rays: :func:`planning.simulate.dexel.column_rise`, the highest position
    on the column at which the whole tool grown by the clearance meets material, in one pass over
    the column's rays (the swept test of :func:`planning.simulate.dexel.collide` from the height
    found up to ``top_z`` meets nothing). ``top_z`` where the tool meets material at the top."""
    p = np.asarray(points_frame, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] == 0:
        return np.zeros(0)
    tol = COLUMN_TOL_MM if step_mm is None else float(step_mm)
    z = p[:, 2].copy()
    hi = np.maximum(float(top_z), z)
    tips = frame.to_part(p - np.array([0.0, 0.0, tip_offset_mm]))
    s = column_rise(stock, tips, frame.rotation[2], hi - z, shape, grow_mm=clearance_mm, tol_mm=tol)
    met = np.isfinite(s) & (s >= 0.0)
    # just above the highest contact (the kernels' own rounding), never above the top
    return np.where(met, np.minimum(z + s + 1e-6, hi), z)


def _rapids_over(tp: Toolpath, which: np.ndarray, safe_z_mm: float, pass_index, clear_above=None):
    """Each rapid ``which`` (P,) from point a to point b replaced by a way over the stock: up from a
    along +Z (a feed until the column above a is clear of stock, then a rapid) to the safe height, a
    rapid at the safe height over b, a rapid down to where the column above b meets stock, and a
    plunge feed to b. The columns above the path's points are clear of the part (ball drop; roughing
    levels), so the feed moves cut only stock; a rapid along the safe height meets nothing.
    ``clear_above``: (points (k,3) -> (k,) lowest clear heights, :func:`column_clear_z`); None:
    the whole way up and down is fed. Returns the new toolpath and pass_index (-1 on the new points)."""
    idx = np.flatnonzero(which)
    idx = idx[idx > 0]
    if idx.size == 0:
        return tp, pass_index
    a_pts, b_pts = tp.xyz_mm[idx - 1], tp.xyz_mm[idx]
    top = np.maximum(safe_z_mm, np.maximum(a_pts[:, 2], b_pts[:, 2]))
    if clear_above is None:
        za, zb = top.copy(), top.copy()
    else:
        za = np.minimum(clear_above(a_pts), top)
        zb = np.minimum(clear_above(b_pts), top)
    xyz, kind, use, centre, plane = [], [], [], [], []
    pi = [] if pass_index is not None else None
    prev = 0
    nan3 = np.full((1, 3), np.nan)
    for n, i in enumerate(idx):
        xyz.append(tp.xyz_mm[prev:i])
        kind.append(tp.kind[prev:i])
        use.append(tp.use[prev:i])
        centre.append(tp.centre_mm[prev:i])
        plane.append(tp.plane[prev:i])
        if pi is not None:
            pi.append(pass_index[prev:i])
        a, b, z = a_pts[n], b_pts[n], top[n]
        xyz.append(np.array([[a[0], a[1], za[n]], [a[0], a[1], z], [b[0], b[1], z], [b[0], b[1], zb[n]], b]))
        kind.append(np.array([FEED, RAPID, RAPID, RAPID, FEED], np.int8))
        use.append(np.array([USE_RETRACT, USE_RAPID, USE_RAPID, USE_RAPID, USE_PLUNGE], np.int8))
        centre.append(np.repeat(nan3, 5, axis=0))
        plane.append(np.zeros(5, np.int8))
        if pi is not None:
            pi.append(np.array([-1, -1, -1, -1, pass_index[i]], dtype=pass_index.dtype))
        prev = i + 1
    xyz.append(tp.xyz_mm[prev:])
    kind.append(tp.kind[prev:])
    use.append(tp.use[prev:])
    centre.append(tp.centre_mm[prev:])
    plane.append(tp.plane[prev:])
    if pi is not None:
        pi.append(pass_index[prev:])
    out = Toolpath(xyz_mm=np.concatenate(xyz), kind=np.concatenate(kind).astype(np.int8),
                   centre_mm=np.concatenate(centre), plane=np.concatenate(plane).astype(np.int8),
                   use=np.concatenate(use).astype(np.int8), tip_offset_mm=tp.tip_offset_mm)
    return out, (None if pi is None else np.concatenate(pi))


def _cut_points_to_drop(tp: Toolpath, bad: np.ndarray) -> np.ndarray:
    """(P,) bool: the path points to cut out for the offending moves ``bad``: the end of an offending
    cutting move; for an offending link, lead, entry or retract move, the cutting points on either
    side of it (the last before and the first after), so that the link is rebuilt from points
    further along the pieces (dropping the link's own point would rebuild the same link)."""
    cutting = np.isin(tp.kind, (FEED, ARC_CW, ARC_CCW)) & (tp.use == USE_CUT)
    drop = bad & cutting
    other = np.flatnonzero(bad & ~cutting)
    if other.size:
        idx = np.flatnonzero(cutting)
        if idx.size:
            before = np.searchsorted(idx, other, side="right") - 1
            after = np.searchsorted(idx, other, side="left")
            drop[idx[before[before >= 0]]] = True
            drop[idx[after[after < idx.size]]] = True
    return drop


def _without_null_moves(tp: Toolpath, pass_index):
    """``tp`` without its straight moves of zero length (after move 0): a post writes none for them,
    so the move list and the programs stay one to one."""
    if tp.n_moves < 2:
        return tp, pass_index
    step = np.linalg.norm(np.diff(tp.xyz_mm, axis=0), axis=1)
    if tp.axis is not None:                    # a move that only turns the axis is a real move
        step = step + np.linalg.norm(np.diff(tp.axis, axis=0), axis=1)
    null = np.r_[False, (step <= 1e-9) & np.isin(tp.kind[1:], (RAPID, FEED))]
    if not null.any():
        return tp, pass_index
    k = ~null
    out = Toolpath(xyz_mm=tp.xyz_mm[k], kind=tp.kind[k], centre_mm=tp.centre_mm[k], plane=tp.plane[k], use=tp.use[k],
                   tip_offset_mm=tp.tip_offset_mm, axis=None if tp.axis is None else tp.axis[k])
    return out, (None if pass_index is None else pass_index[k])


def _truncate(tp: Toolpath, pass_index, first_bad: int, safe_z_mm: float):
    """Moves before ``first_bad`` and a retract along +Z to ``safe_z_mm`` (reference point)."""
    keep = max(first_bad, 1)
    xyz = tp.xyz_mm[:keep]
    last = xyz[-1].copy()
    up = np.array([[last[0], last[1], max(safe_z_mm, last[2])]])
    out = Toolpath(xyz_mm=np.concatenate([xyz, up]), kind=np.concatenate([tp.kind[:keep], [FEED]]).astype(np.int8),
                   centre_mm=np.concatenate([tp.centre_mm[:keep], np.full((1, 3), np.nan)]),
                   plane=np.concatenate([tp.plane[:keep], [0]]).astype(np.int8),
                   use=np.concatenate([tp.use[:keep], [USE_RETRACT]]).astype(np.int8), tip_offset_mm=tp.tip_offset_mm,
                   axis=None if tp.axis is None else np.concatenate([tp.axis[:keep], tp.axis[keep - 1:keep]]))
    pi = None if pass_index is None else np.concatenate([pass_index[:keep], [-1]]).astype(pass_index.dtype)
    return out, pi


def guard_toolpath(tp: Toolpath, frame: AreaFrame, shape: ToolShape, stock: TriDexel, obstacles: TriDexel | None,
                   machine: SetupMachine | None, *, safe_z_mm: float, pass_index=None, rapid_clearance_mm: float = 0.5,
                   max_rounds: int = 4, progress: Progress | None = None, relink=None,
                   moves=None) -> GuardOutcome:
    """Guard one operation (module docstring). ``tp``: the toolpath in ``frame``; ``shape``: the
    tool that runs it (simulation shape, its gauge length for the travel); ``stock``: the stock
    before it (unchanged: the outcome carries the stock after); ``obstacles``: fixtures, riser and
    table (or None); ``machine``: the set-up on the machine (None: travel not checked);
    ``safe_z_mm``: the retract height of the toolpath's reference point (area frame);
    ``pass_index``: (P,) kept aligned through the cuts; ``rapid_clearance_mm``: a rapid must stay
    this far from material (mm; a margin over the verification's own clearance, so the posted
    programs' rounding does not turn a grazing rapid into an offence); ``progress``:
    ``progress(fraction in [0, 1], message)`` while the rounds run (the first round takes the
    first 70 %, each further one half of what is left; 1.0 at the end), at most ~10 calls a
    second. ``relink``: ``(toolpath, pass_index) -> (toolpath, pass_index)`` run on the path after
    every cut of step 3 (a 5-axis path: the links the cut made through the safe height planned
    again on the stock, :class:`planning.toolpath.fiveaxis.links.StockLinks` with ``only_high``).
    ``moves``: the machine's moves of a path, as :func:`run_on_stock` takes it (None: :func:`part_moves`)."""
    from planning.toolpath.safety import cut_moves

    prog = Throttled(progress)
    fixtures = _FixtureMemo()
    lo, span = 0.0, 0.7

    def round_progress(rnd: int):
        if progress is None:
            return None
        part = prog.part(lo, lo + span)
        return lambda f, msg: part(f, f"guard round {rnd + 1}, {msg}")

    def finish(out: GuardOutcome) -> GuardOutcome:
        prog(1.0, f"guard done in {out.rounds} round(s)")
        return out

    out = GuardOutcome(toolpath=tp, pass_index=pass_index, stock=stock)
    for rnd in range(max_rounds + 1):
        if tp.n_moves == 0:                    # nothing (left) to run
            out.toolpath, out.pass_index, out.rounds = tp, pass_index, rnd
            return finish(out)
        kept: dict = {}
        off, after, removed = run_on_stock(tp, frame, shape, stock, obstacles, machine,
                                           rapid_clearance_mm=rapid_clearance_mm, progress=round_progress(rnd),
                                           _fixtures=fixtures, keep=kept, moves=moves)
        lo, span = lo + span, 0.5 * (1.0 - lo - span)
        out.rounds = rnd + 1
        if rnd == 0:
            out.found = off.counts()
        bad = off.any
        if not bad.any():
            # the repairs and the CL cut may leave null moves: the post writes none
            tp, pass_index = _without_null_moves(tp, pass_index)
            out.toolpath, out.pass_index, out.stock, out.moves = tp, pass_index, after, kept["moves"]
            out.removed_mm3 = float(removed.sum())
            return finish(out)
        if rnd == max_rounds:
            break
        rapid_only = off.rapid & ~(off.holder | off.fixture | off.travel)
        if tp.axis is not None:
            # 5-axis: a rapid off the safe height that meets stock (the approach or the retract along
            # the leaning axis brushing the allowance) is fed instead; the next round checks the shank
            # and holder on it as on any feed move
            low = rapid_only.copy()
            low[1:] &= np.minimum(tp.xyz_mm[1:, 2], tp.xyz_mm[:-1, 2]) < safe_z_mm - 1e-9
            low[0] = False
            if low.any():
                up = np.r_[False, tp.xyz_mm[1:, 2] > tp.xyz_mm[:-1, 2]]
                kind, use = tp.kind.copy(), tp.use.copy()
                kind[low] = FEED
                use[low] = np.where(up[low], USE_RETRACT, USE_PLUNGE)
                tp = Toolpath(xyz_mm=tp.xyz_mm, kind=kind, centre_mm=tp.centre_mm, plane=tp.plane, use=use,
                              tip_offset_mm=tp.tip_offset_mm, axis=tp.axis)
                out.rapids_to_feed += int(low.sum())
            rapid_only = np.zeros_like(rapid_only)
            bad = bad & ~low
            if not bad.any():
                continue
        drop = _cut_points_to_drop(tp, bad & ~rapid_only)
        # a rapid that is already a rapid over the safe height and still meets stock cannot be
        # lifted further: its neighbours go instead
        lifted = np.zeros_like(rapid_only)
        lifted[1:] = rapid_only[1:] & (np.minimum(tp.xyz_mm[1:, 2], tp.xyz_mm[:-1, 2]) >= safe_z_mm - 1e-9)
        drop |= _cut_points_to_drop(tp, lifted)
        rapid_only &= ~lifted
        if rapid_only.any() and not drop.any():
            # the columns are read on the stock before the operation: more material than when the
            # rapid runs, so the heights found are safe ones
            top = max(safe_z_mm, float(tp.xyz_mm[:, 2].max()))
            clear = (lambda pts, tp=tp, top=top: column_clear_z(frame, shape, stock, pts, top, tp.tip_offset_mm,
                                                                rapid_clearance_mm + 0.5))
            tp, pass_index = _rapids_over(tp, rapid_only, safe_z_mm, pass_index, clear_above=clear)
            out.rapids_to_feed += int(rapid_only.sum())
            continue
        if drop.any():
            cut = cut_moves(tp, drop, safe_z_mm=safe_z_mm, pass_index=pass_index)
            tp, pass_index = cut.toolpath, cut.pass_index
            out.dropped += int(drop.sum())
            if relink is not None and tp.n_moves:
                tp, pass_index = relink(tp, pass_index)
    first = int(np.flatnonzero(off.any)[0])
    out.truncated = tp.n_moves - first
    tp, pass_index = _truncate(tp, pass_index, first, safe_z_mm)
    tp, pass_index = _without_null_moves(tp, pass_index)
    kept = {}
    off, after, removed = run_on_stock(tp, frame, shape, stock, obstacles, machine,
                                       rapid_clearance_mm=rapid_clearance_mm,
                                       progress=round_progress(max_rounds + 1), _fixtures=fixtures, keep=kept,
                                       moves=moves)
    out.toolpath, out.pass_index, out.stock, out.moves = tp, pass_index, after, kept["moves"]
    out.removed_mm3 = float(removed.sum())
    return finish(out)
