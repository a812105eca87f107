"""Links between the passes of a 5-axis finishing path planned on the stock (issue 33 item 1).

The passes of a 5-axis path come from the 3+2 finishing (:mod:`planning.toolpath.finishing`), whose
links were planned on the scan alone: a short link retracts a few mm, crosses in one rapid and
plunges; a link made by :func:`planning.toolpath.safety.cut_moves` goes up a vertical column (frame
z) to the safe height, across and down. With a tool axis that turns from one pass to the next,
neither knows the stock the roughing left: the short rapid turns the leaning tool a few mm over
material, and the long way to the safe height moves a tilted tool sideways along the set-up axis,
out of the machine's travel (the 50k-point femur-like plan had 434 such travel excursions), after
which the guard repaired what it found, round after round.

:class:`StockLinks` plans every link between two cutting positions ``a`` and ``b`` (a run of points
off the surface that contains a rapid) again, on the stock the finishing starts from (more material
than there will be when the link runs, so what is clear there is clear then):

1. **Up the local axis.** From ``a`` along ``a``'s own tool axis ``u_a``: a feed to ``h_a``, the
   lowest height on that column from which the whole tool, grown by the link clearance, is clear of
   the stock all the way up (:func:`planning.simulate.dexel.column_rise`, exact on the stock's rays,
   at least ``approach_mm``); likewise ``h_b`` over ``b`` along ``u_b``.
2. **Across.** A rapid from ``a + H u_a`` to ``b + H u_b`` at the lift ``H = max(h_a, h_b) + l``, the
   axis turning from ``u_a`` to ``u_b`` along the great circle (as the posts linearise it and the
   guard runs it: steps of at most :data:`planning.toolpath.guard.AXIS_STEP_DEG`), written as four
   rapids (:data:`VIAS` points between). Where that arc passes the machine's rotary pole closer than an
   admissible position may (the rotary axis would swing half a turn within a degree of the axis:
   no control follows that, and the table swings with the tool over the part), the axis turns
   round the pole instead: halfway it is beside the pole at the larger tilt of the two ends
   (:meth:`StockLinks._vias`), so the tilt holds and the rotary axis turns.
3. **Down** ``b``'s axis: a rapid to ``b + h_b u_b``, a plunge feed to ``b``.
4. **Checked when planned**, every link of one lift at once: the rapids with the whole tool grown by
   the clearance, the feeds' shank and holder, on the stock; the whole tool (grown by
   ``clearance_mm``) against the fixtures, riser and table; every step's position within the
   machine's travel on the rotary solution the posts' walk keeps along the link (the tilt's sign at
   ``a``: :meth:`StockLinks._travel_ok`) and both arcs of the axis clear of the rotary pole. A link
   that fails is tried at the next lift ``l`` of :data:`LIFTS_MM`, then with both ends up their own
   axes to the safe height (the across then runs over all the stock; axes leaning less than 75
   degrees from the set-up axis); one that fails every level keeps the link it had (the guard, still
   run on every operation, decides on it; the verification's travel check finds what it would
   leave out of travel).

Lengths in mm (area frame, ball-centre reference points), angles in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planning.simulate.dexel import TriDexel, collide, column_rise
from planning.simulate.motion import RAPID as SIM_RAPID
from planning.simulate.motion import ToolShape
from planning.toolpath.fiveaxis.axes import _unit, slerp
from planning.toolpath.fiveaxis.finishing import _touching
from planning.toolpath.fiveaxis.register import route_unwinding_links
from planning.toolpath.frames import AreaFrame
from planning.toolpath.guard import part_moves
from planning.toolpath.moves import (
    FEED,
    RAPID,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
)

__all__ = ["LIFTS_MM", "LINK_MARGIN_MM", "LinkFigures", "StockLinks", "air_links", "branch_angles"]

#: The lifts tried, mm over the higher of the two clear heights (step 2), lowest first.
LIFTS_MM = (1.0, 3.0, 8.0, 20.0, 50.0, 100.0)

#: The longest column read along a tool axis (mm): a link whose column is not clear below this is kept.
COLUMN_MM = 120.0

#: How much further than the guard's rapid clearance the links keep from the stock (mm), so that the
#: posts' rounding and linearisation do not bring a planned rapid within the guard's clearance.
LINK_MARGIN_MM = 0.5

#: The last level tried takes both ends up their own axes to the safe height (frame z), where the
#: stock is below the ball whatever the axis; only for axes leaning less than this from the set-up
#: axis (cosine; 75 degrees), so the columns stay of reasonable length.
SAFE_LEAN_COS = math.cos(math.radians(75.0))

#: Points across a link between its two tops (the axis turning in VIAS + 1 arcs).
VIAS = 3

#: Round the pole, the held tilt grows by this (degrees) where an arc of the turn would still come
#: within the pole clearance, at most ROUND_TILT_STEPS times.
ROUND_TILT_STEP_DEG = 3.0
ROUND_TILT_STEPS = 4

#: The fractions of the way (and of the axis's turn) at which the VIAS points across lie.
_EVEN = np.arange(1, VIAS + 1) / (VIAS + 1.0)

#: Extra growth of the shank and holder on a link's feed moves (mm): a margin over the guard's test.
FEED_MARGIN_MM = 0.2


@dataclass
class LinkFigures:
    """What :class:`StockLinks` did: ``n_links`` links between two cutting positions with a rapid in
    them; ``n_planned`` replaced by a link over the stock, ``by_lift`` how many at each lift (mm, or
    ``safe``: up the axes to the safe height); ``n_round_pole`` planned links whose axis turns round
    the rotary pole; ``n_holder`` planned links whose feed off or onto the surface meets the stock
    with the shank or holder (left to the guard, which cuts the cutting position beside it out);
    ``n_kept`` kept as they were (no lift cleared; ``kept_by`` the first failing check at the highest
    lift: ``column`` (a column not clear within :data:`COLUMN_MM`), ``stock``, ``obstacles``,
    ``travel``, ``pole``); ``length_before_mm`` / ``length_after_mm`` the reference point's way over
    the replaced links before and after."""

    n_links: int = 0
    n_planned: int = 0
    n_kept: int = 0
    n_round_pole: int = 0
    n_holder: int = 0
    by_lift: dict = field(default_factory=dict)
    kept_by: dict = field(default_factory=dict)
    length_before_mm: float = 0.0
    length_after_mm: float = 0.0

    def add(self, other: LinkFigures) -> None:
        """Add ``other``'s counts to these (the guard's relinking after a cut)."""
        for name in ("n_links", "n_planned", "n_kept", "n_round_pole", "n_holder", "length_before_mm",
                     "length_after_mm"):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        for mine, theirs in ((self.by_lift, other.by_lift), (self.kept_by, other.kept_by)):
            for key, v in theirs.items():
                mine[key] = mine.get(key, 0) + v

    def as_dict(self) -> dict:
        return {"n_links": self.n_links, "n_planned": self.n_planned, "n_kept": self.n_kept,
                "n_round_pole": self.n_round_pole, "n_holder": self.n_holder,
                "by_lift": {str(k): v for k, v in self.by_lift.items()}, "kept_by": dict(self.kept_by),
                "length_before_mm": round(self.length_before_mm, 1), "length_after_mm": round(self.length_after_mm, 1)}


def air_links(tp: Toolpath) -> tuple[np.ndarray, np.ndarray]:
    """``(a, b)``: for every link of ``tp`` (a run of points that are not cutting positions between
    two that are, with at least one rapid among the moves into its points), the cutting position
    before it and the one after it."""
    touch = _touching(tp)
    idx = np.flatnonzero(touch)
    if idx.size < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    gap = np.flatnonzero(np.diff(idx) > 1)
    a, b = idx[gap], idx[gap + 1]
    rap = np.concatenate([[0], np.cumsum(tp.kind == RAPID)])       # rap[k]: rapids among moves 0..k-1
    air = rap[b] - rap[a + 1] > 0                                   # a rapid among moves a+1 .. b-1
    return a[air].astype(np.int64), b[air].astype(np.int64)


def branch_angles(axes_p: np.ndarray, profile, tilt_sign) -> tuple[np.ndarray, np.ndarray]:
    """``(angles_deg (n,2), valid (n,))``: the rotary position (tilt, rotary; planner signs) of each
    tool axis (part frame) on the branch whose tilt has the sign ``tilt_sign`` (scalar or (n,); the
    solution of :func:`planning.orientations.kinematics.solve_rotary` with tilt >= 0 for a positive
    sign, the mirrored one for a negative), as :func:`planning.post.simultaneous.rotary_path` keeps
    it along a path while the travel allows (the rotary angle up to whole turns); at the pole the
    valid one. ``valid``: that solution lies within the rotary travel."""
    from planning.orientations.kinematics import solve_rotary

    a = np.asarray(axes_p, dtype=np.float64).reshape(-1, 3)
    n = a.shape[0]
    sols = solve_rotary(a, profile)
    rows = np.arange(n)
    sign = np.broadcast_to(np.asarray(tilt_sign, dtype=np.float64), (n,))
    j = np.where(sign >= 0, 0, 1)
    at_pole = np.abs(sols.angles_deg[:, 0, 0]) < 1e-9
    j = np.where(at_pole, np.where(sols.valid[:, 0], 0, 1), j)
    return sols.angles_deg[rows, j], np.asarray(sols.valid[rows, j], dtype=bool)


class StockLinks:
    """The link planner of the module docstring for one operation: ``frame`` the area frame;
    ``shape`` the finishing tool as the simulation sees it; ``stock`` the stock the finishing starts
    from (read, never changed); ``obstacles`` fixtures, riser and table (or None); ``admissible`` a
    :class:`planning.toolpath.fiveaxis.finishing.Admissible` (its machine for the travel and the pole;
    without one neither is checked); ``clearance_mm`` the distance the rapids keep from the stock
    (the guard's rapid clearance plus a margin); ``approach_mm`` the shortest feed off and onto the
    surface; ``lifts_mm`` the lifts tried (step 2)."""

    def __init__(self, frame: AreaFrame, shape: ToolShape, stock: TriDexel, obstacles: TriDexel | None, admissible, *,
                 safe_z_mm: float, clearance_mm: float, approach_mm: float = 1.0, lifts_mm=LIFTS_MM):
        self.frame, self.shape, self.stock, self.obstacles = frame, shape, stock, obstacles
        self.safe_z = float(safe_z_mm)
        self.admissible = admissible
        self.clearance = float(clearance_mm)
        self.approach = max(float(approach_mm), 1e-3)
        self.lifts = tuple(float(v) for v in lifts_mm)
        self.figures = LinkFigures()

    # -- step 1 ------------------------------------------------------------------------------------
    def clear_heights(self, ref_f: np.ndarray, axes_f: np.ndarray, tip_offset_mm: float,
                      length_mm: np.ndarray) -> np.ndarray:
        """(n,) the lowest lift (mm along each point's own axis from its reference point) from which
        the whole tool, grown by the clearance, is clear of the stock up to ``length_mm`` (n,) along
        that axis (at least ``approach_mm``); inf where the column is not clear below that."""
        n = ref_f.shape[0]
        out = np.full(n, self.approach)
        tips = self.frame.to_part(ref_f - tip_offset_mm * axes_f)
        axes_p = axes_f @ self.frame.rotation
        for i in range(n):                 # column_rise reads one axis per call
            L = float(length_mm[i])
            s = column_rise(self.stock, tips[i:i + 1], axes_p[i], L, self.shape, grow_mm=self.clearance)[0]
            if np.isfinite(s) and s >= L - 1e-6:
                out[i] = math.inf
            elif np.isfinite(s):
                out[i] = max(self.approach, float(s) + 0.05)
        return out

    # -- steps 2-4 -----------------------------------------------------------------------------------
    @staticmethod
    def _candidate(xyz_a, xyz_b, ua, ub, ha, hb, Ha, Hb, vias):
        """The reference points (k, 6 + V, 3) of each link: a, up (its clear height), top a, the V points
        across (evenly between the tops), top b, down (b's clear height), b; and their axes: ``vias``
        (k, V, 3) across, ``a``'s before, ``b``'s after."""
        top_a, top_b = xyz_a + Ha[:, None] * ua, xyz_b + Hb[:, None] * ub
        f = _EVEN[None, :, None]
        across = top_a[:, None, :] + f * (top_b - top_a)[:, None, :]
        pts = np.concatenate([np.stack([xyz_a, xyz_a + ha[:, None] * ua, top_a], 1), across,
                              np.stack([top_b, xyz_b + hb[:, None] * ub, xyz_b], 1)], axis=1)
        ax = np.concatenate([np.stack([ua, ua, ua], 1), vias, np.stack([ub, ub, ub], 1)], axis=1)
        return pts, ax

    def _vias(self, ua: np.ndarray, ub: np.ndarray, tilt_sign=None, c_walk=None) -> tuple[np.ndarray, np.ndarray]:
        """``(vias (k, VIAS, 3), round_pole (k,))``: the axes across each link, at even steps: on the
        great circle from ``ua`` to ``ub``, or, where that arc passes the rotary pole closer than an
        admissible position may (``round_pole``), round the pole: at a fixed angle from it (the larger
        of the two ends' plus 2 degrees, at least the pole clearance plus 2), the azimuth about it
        turning from ``ua``'s to ``ub``'s the way of the arc's midpoint, in even steps, the tilt held
        and the rotary axis turning; where an arc between neighbours would still pass within the
        clearance (an end just off the pole, a long step of azimuth), the held tilt grows by
        :data:`ROUND_TILT_STEP_DEG` until every arc clears.

        Either way round turns the rotary axis about half a turn; with ``c_walk`` (the posts' walk on
        the path as it was: the rotary angle at each link's start and its change over the link, deg)
        the links are taken in path order and each goes round the way that brings a continuous C
        nearer 0, so that the turns round the pole do not wind C up (the C register)."""
        k = ua.shape[0]
        f = _EVEN
        vias = np.stack([slerp(ua, ub, np.full(k, t)) for t in f], axis=1)
        adm = self.admissible
        if adm is None or adm.pole_f is None:
            return vias, np.zeros(k, dtype=bool)
        p = adm.pole_f
        rnd = ~adm.arc_clear_of_pole(ua, ub)
        if rnd.any():
            a, b = ua[rnd], ub[rnd]
            e1 = np.cross(p, [1.0, 0.0, 0.0] if abs(p[0]) < 0.9 else [0.0, 1.0, 0.0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(p, e1)
            # the side the arc passes the pole on: its midpoint's azimuth (or across the arc's plane)
            m = a + b
            d = m - np.outer(m @ p, p)
            dn = np.linalg.norm(d, axis=1)
            alt = np.cross(np.broadcast_to(p, a.shape), a - b)
            d = np.where((dn > 1e-6)[:, None], d, alt)
            az_a, az_b, az_d = (np.arctan2(v @ e2, v @ e1) for v in (a, b, d))
            ccw = np.mod(az_b - az_a, 2 * np.pi)                    # turning counter-clockwise to b
            via_ccw = np.mod(az_d - az_a, 2 * np.pi) <= ccw
            span = np.where(via_ccw, ccw, ccw - 2 * np.pi)
            clr = math.degrees(math.acos(min(1.0, adm.cos_pole))) + 2.0
            th = np.radians(np.maximum(np.maximum(np.degrees(np.arccos(np.clip(a @ p, -1, 1))),
                                                  np.degrees(np.arccos(np.clip(b @ p, -1, 1)))) + 2.0, clr))

            def round_vias(sp, tilt):
                az = az_a[:, None] + f[None, :] * sp[:, None]
                ring = np.cos(az)[..., None] * e1 + np.sin(az)[..., None] * e2
                return np.cos(tilt)[:, None, None] * p + np.sin(tilt)[:, None, None] * ring

            span_used = span
            near = round_vias(span, th)
            if c_walk is not None and adm.machine is not None and adm.machine.profile.rotary_continuous:
                span_other = np.where(via_ccw, ccw - 2 * np.pi, ccw)
                other = round_vias(span_other, th)
                dc_near = self._c_turn(a, near, b, tilt_sign[rnd])
                dc_other = self._c_turn(a, other, b, tilt_sign[rnd])
                c0, dc_old = c_walk[0][rnd], c_walk[1][rnd]
                offset = 0.0
                take_other = np.zeros(a.shape[0], dtype=bool)
                for i in range(a.shape[0]):            # in path order: each choice moves the C after it
                    c = c0[i] + offset
                    take_other[i] = abs(c + dc_other[i]) < abs(c + dc_near[i])
                    offset += (dc_other[i] if take_other[i] else dc_near[i]) - dc_old[i]
                near[take_other] = other[take_other]
                span_used = np.where(take_other, span_other, span)
            # an end just off the pole and a long step of azimuth (the longer way round) can bring the
            # first or last arc within the clearance: the held tilt grows until every arc clears
            for _ in range(ROUND_TILT_STEPS):
                clear = self._arcs_clear(np.concatenate([a[:, None], near, b[:, None]], axis=1))
                if clear.all():
                    break
                th = np.where(clear, th, th + np.radians(ROUND_TILT_STEP_DEG))
                near[~clear] = round_vias(span_used, th)[~clear]
            vias[rnd] = near
        return vias, rnd

    def _arcs_clear(self, seq: np.ndarray) -> np.ndarray:
        """(k,) bool: every arc between neighbouring axes of ``seq`` (k, m, 3) keeps the pole clearance."""
        clear = np.ones(seq.shape[0], dtype=bool)
        for i in range(seq.shape[1] - 1):
            clear &= self.admissible.arc_clear_of_pole(seq[:, i], seq[:, i + 1])
        return clear

    def _c_turn(self, a: np.ndarray, vias: np.ndarray, b: np.ndarray, tilt_sign: np.ndarray) -> np.ndarray:
        """(k,) how far (deg) the rotary axis turns from axis ``a`` through ``vias`` (k, V, 3) to ``b``
        (area frame) on the branch of ``tilt_sign``, unwrapped as the posts' walk unwraps it."""
        seq = np.concatenate([a[:, None, :], vias, b[:, None, :]], axis=1)
        k, m = seq.shape[:2]
        ang, _ = branch_angles((seq @ self.frame.rotation).reshape(-1, 3), self.admissible.machine.profile,
                               np.repeat(tilt_sign, m))
        c = np.unwrap(np.radians(ang[:, 1].reshape(k, m)), axis=1)
        return np.degrees(c[:, -1] - c[:, 0])

    def _moves(self, pts: np.ndarray, ax: np.ndarray, tip_offset_mm: float):
        """The moves of every candidate link as the guard runs them (:func:`planning.toolpath.guard.part_moves`
        on the links joined into one path, the joining moves left out): ``(link, start tip, end tip,
        axis, rapid)`` per step, tips and axes in the part frame."""
        k, m = pts.shape[:2]
        kind = np.tile(np.array([FEED, FEED] + [RAPID] * (m - 3) + [FEED], np.int8), k)
        P = k * m
        joined = Toolpath(xyz_mm=pts.reshape(-1, 3), kind=kind, centre_mm=np.full((P, 3), np.nan),
                          plane=np.zeros(P, np.int8), use=np.zeros(P, np.int8), tip_offset_mm=tip_offset_mm,
                          axis=ax.reshape(-1, 3))
        pm = part_moves(joined, self.frame)
        own = pm.source % m != 0                       # not the move into a link's first point
        return pm.source[own] // m, pm.start[own], pm.end[own], pm.axis[own], pm.kind[own] == SIM_RAPID

    def _travel_ok(self, tips_p: np.ndarray, axes_p: np.ndarray, tilt_sign: np.ndarray) -> np.ndarray:
        """(n,) bool: the machine reaches each tool tip (part frame) with its axis on the rotary
        solution the posts' walk keeps along the link (:func:`branch_angles`, ``tilt_sign`` that of
        the walk at the link's start), within the rotary travel, with the controlled point within the
        linear travel. A sample whose solution on that side is out of travel fails (the walk would
        change solution there, swinging the table)."""
        adm = self.admissible
        m = adm.machine
        ang, ok = branch_angles(axes_p, m.profile, tilt_sign)
        mpos = m.machine_from_tip(tips_p, ang, adm.gauge)
        (x0, x1), (y0, y1), (z0, z1) = m.profile.linear_limits_mm
        lo, hi = np.array([x0, y0, z0]) - 1e-6, np.array([x1, y1, z1]) + 1e-6
        return ok & np.all((mpos >= lo) & (mpos <= hi), axis=1)

    def _check(self, pts: np.ndarray, ax: np.ndarray, tip_offset_mm: float, tilt_sign: np.ndarray) -> np.ndarray:
        """``(why, holder)``: (k,) the first failing check of each candidate link (module docstring,
        step 4): '' when it passes, else 'stock', 'obstacles', 'travel' or 'pole'; and (k,) bool
        whether the feed off or onto the surface meets the stock with the shank or holder. That feed is
        the same at every lift and is the way off and on the surface of any link there (the
        guard cuts the cutting position beside it out and the cut is linked again), so it does not
        make a link fail. ``tilt_sign`` (k,): the sign of the tilt the posts' walk has at each link's
        start (:meth:`_travel_ok`)."""
        k = pts.shape[0]
        why = np.full(k, "", dtype=object)
        link, ts, te, ap, rapid = self._moves(pts, ax, tip_offset_mm)
        grow = np.where(rapid, self.clearance, FEED_MARGIN_MM)
        dep = collide(self.stock, ts, te, ap, self.shape, which=rapid, grow_mm=grow)
        holder = np.zeros(k, dtype=bool)
        np.logical_or.at(holder, link, (dep > 0) & ~rapid)
        bad = np.zeros(k, dtype=bool)
        np.logical_or.at(bad, link, (dep > 0) & rapid)
        why[bad & (why == "")] = "stock"
        if self.obstacles is not None:
            dep = collide(self.obstacles, ts, te, ap, self.shape, which="tool", grow_mm=self.clearance)
            b2 = np.zeros(k, dtype=bool)
            np.logical_or.at(b2, link, dep > 0)
            why[b2 & (why == "")] = "obstacles"
            bad |= b2
        adm = self.admissible
        if adm is not None and adm.machine is not None:
            ok = self._travel_ok(te, ap, tilt_sign[link])
            b3 = np.zeros(k, dtype=bool)
            np.logical_or.at(b3, link, ~ok)
            why[b3 & (why == "")] = "travel"
        if adm is not None and adm.pole_f is not None:
            clear = self._arcs_clear(ax[:, 2:ax.shape[1] - 2])   # the arcs across, top a to top b
            why[~clear & (why == "")] = "pole"
        return why, holder

    def __call__(self, tp: Toolpath, pass_index, *, only_high: bool = False) -> tuple[Toolpath, np.ndarray | None]:
        """``(toolpath, pass_index)`` with the links planned on the stock (module docstring); the new
        points have pass index -1. ``tp``: the 5-axis path (area frame, with ``axis``); ``only_high``:
        only the links that reach the safe height (those a cut made; the guard's relinking), and the
        figures are added to the last call's instead of replacing them."""
        figs = LinkFigures()
        if not only_high:
            self.figures = figs
        if tp.axis is None or tp.n_moves < 3:
            return tp, pass_index
        a_idx, b_idx = air_links(tp)
        if only_high and a_idx.size:
            z = tp.xyz_mm[:, 2]
            hi = np.concatenate([[0], np.cumsum(z >= self.safe_z - 1e-6)])
            keep = hi[b_idx] - hi[a_idx + 1] > 0
            a_idx, b_idx = a_idx[keep], b_idx[keep]
        out = self._plan(tp, pass_index, a_idx, b_idx, figs)
        if only_high:
            self.figures.add(figs)
        return out

    def relink(self, tp: Toolpath, pass_index) -> tuple[Toolpath, np.ndarray | None]:
        """The guard's relinking after a cut (:func:`planning.toolpath.guard.guard_toolpath` ``relink``):
        the links through the safe height the cut made planned on the stock (``only_high``), then, on
        a machine with a continuous C, the links where C must turn back routed through the safe height
        again (:func:`planning.toolpath.fiveaxis.register.route_unwinding_links`; the relinking may
        have replaced such a link), as :func:`planning.toolpath.fiveaxis.finishing.five_axis_path`
        does after its links."""
        tp, pass_index = self(tp, pass_index, only_high=True)
        adm = self.admissible
        if adm is not None and adm.machine is not None:
            tp, pass_index, _ = route_unwinding_links(tp, pass_index, profile=adm.machine.profile,
                                                      rotation=self.frame.rotation, safe_z_mm=self.safe_z)
        return tp, pass_index

    def _plan(self, tp: Toolpath, pass_index, a_idx: np.ndarray, b_idx: np.ndarray, figs: LinkFigures):
        """The links between ``a_idx`` and ``b_idx`` planned (:meth:`__call__`), figures into ``figs``."""
        figs.n_links = int(a_idx.size)
        if a_idx.size == 0:
            return tp, pass_index
        xyz, axes = tp.xyz_mm, _unit(tp.axis)
        off = float(tp.tip_offset_mm)
        ua, ub = axes[a_idx], axes[b_idx]
        tilt_sign = np.ones(a_idx.size)
        walk = None
        if self.admissible is not None and self.admissible.machine is not None:
            from planning.post.simultaneous import rotary_path

            walk, _ = rotary_path(axes @ self.frame.rotation, self.admissible.machine.profile)
            tilt_sign = np.where(walk[a_idx, 0] < 0, -1.0, 1.0)
        # the lifts along each axis that reach the safe height (the last level tried), when they lean
        # less than SAFE_LEAN
        za, zb = np.maximum(ua[:, 2], 1e-9), np.maximum(ub[:, 2], 1e-9)
        up_a = (self.safe_z - xyz[a_idx, 2]) / za
        up_b = (self.safe_z - xyz[b_idx, 2]) / zb
        safe_ok = (ua[:, 2] >= SAFE_LEAN_COS) & (ub[:, 2] >= SAFE_LEAN_COS)
        La = np.maximum(COLUMN_MM, np.where(safe_ok, up_a + 1.0, 0.0))
        Lb = np.maximum(COLUMN_MM, np.where(safe_ok, up_b + 1.0, 0.0))
        ha = self.clear_heights(xyz[a_idx], ua, off, La)
        hb = self.clear_heights(xyz[b_idx], ub, off, Lb)
        c_walk = None if walk is None else (walk[a_idx, 1], walk[b_idx, 1] - walk[a_idx, 1])
        vias, rnd = self._vias(ua, ub, tilt_sign, c_walk)
        k = a_idx.size
        pts_k = np.full((k, 6 + VIAS, 3), np.nan)
        ax_k = np.full((k, 6 + VIAS, 3), np.nan)
        done = np.zeros(k, dtype=bool)
        why_last = np.full(k, "column", dtype=object)
        pending = np.flatnonzero(np.isfinite(ha) & np.isfinite(hb))
        levels = [(f"{v:g}", v) for v in self.lifts] + [("safe", None)]
        for name, lift in levels:
            if lift is None:
                pending = pending[safe_ok[pending]]
            if pending.size == 0:
                break
            P = pending
            if lift is None:
                Ha = np.maximum(up_a[P], ha[P] + self.lifts[0])
                Hb = np.maximum(up_b[P], hb[P] + self.lifts[0])
            else:
                Ha = Hb = np.maximum(ha[P], hb[P]) + lift
            pts, ax = self._candidate(xyz[a_idx[P]], xyz[b_idx[P]], ua[P], ub[P], ha[P], hb[P], Ha, Hb, vias[P])
            why, holder = self._check(pts, ax, off, tilt_sign[P])
            good = why == ""
            figs.n_holder += int((good & holder).sum())
            pts_k[P[good]], ax_k[P[good]] = pts[good], ax[good]
            done[P[good]] = True
            why_last[P[~good]] = why[~good]
            if good.any():
                figs.by_lift[name] = int(good.sum())
            pending = P[~good]
        take = np.flatnonzero(done)
        figs.n_planned = int(take.size)
        figs.n_kept = int(k - take.size)
        figs.n_round_pole = int((rnd & done).sum())
        for w in why_last[~done]:
            figs.kept_by[w] = figs.kept_by.get(w, 0) + 1
        if take.size == 0:
            return tp, pass_index
        step = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
        cs = np.concatenate([[0.0], np.cumsum(step)])
        figs.length_before_mm = float((cs[b_idx[take]] - cs[a_idx[take]]).sum())
        figs.length_after_mm = float(np.linalg.norm(np.diff(pts_k[take], axis=1), axis=2).sum())
        return _splice(tp, pass_index, a_idx[take], b_idx[take], pts_k[take, 1:-1], ax_k[take, 1:-1])


def _splice(tp: Toolpath, pass_index, a_idx, b_idx, new_pts, new_ax):
    """``tp`` with the points strictly between ``a_idx[j]`` and ``b_idx[j]`` replaced by ``new_pts[j]``
    (q points: up (a feed), then rapids) and the move into ``b_idx[j]`` a plunge feed."""
    P = tp.n_moves
    keep = np.ones(P, dtype=bool)
    edge = np.zeros(P + 1, np.int64)
    np.add.at(edge, a_idx + 1, 1)
    np.add.at(edge, b_idx, -1)
    keep &= np.cumsum(edge)[:P] == 0
    # the new points go just before each b: order by (position, rank)
    old = np.flatnonzero(keep)
    k = a_idx.size
    pos_old = old.astype(np.float64)
    q = new_pts.shape[1]
    pos_new = (b_idx[:, None] - 1.0 + (np.arange(1, q + 1)[None, :] / (q + 1.0))).reshape(-1)
    order = np.argsort(np.concatenate([pos_old, pos_new]), kind="stable")
    n_old = old.size
    xyz = np.concatenate([tp.xyz_mm[old], new_pts.reshape(-1, 3)])[order]
    axis = np.concatenate([tp.axis[old], new_ax.reshape(-1, 3)])[order]
    kind_new = np.tile(np.array([FEED] + [RAPID] * (q - 1), np.int8), k)
    use_new = np.tile(np.array([USE_RETRACT] + [USE_RAPID] * (q - 1), np.int8), k)
    kind = np.concatenate([tp.kind[old], kind_new])[order]
    use = np.concatenate([tp.use[old], use_new])[order]
    centre = np.concatenate([tp.centre_mm[old], np.full((q * k, 3), np.nan)])[order]
    plane = np.concatenate([tp.plane[old], np.zeros(q * k, np.int8)])[order]
    src = np.concatenate([old, np.full(q * k, -1)])[order]
    # the move into b: a plunge feed along b's axis
    at_b = np.isin(src, b_idx)
    kind[at_b], use[at_b] = FEED, USE_PLUNGE
    centre[at_b], plane[at_b] = np.nan, 0
    out = Toolpath(xyz_mm=xyz, kind=kind.astype(np.int8), centre_mm=centre, plane=plane.astype(np.int8),
                   use=use.astype(np.int8), tip_offset_mm=tp.tip_offset_mm, axis=axis)
    pi = None
    if pass_index is not None:
        p = np.asarray(pass_index)
        pi = np.where(src >= 0, p[np.maximum(src, 0)], -1).astype(p.dtype)
    assert n_old + q * k == xyz.shape[0]
    return out, pi
