"""Posts for SIMULTANEOUS 5-axis finishing: every block moves X Y Z and both rotary axes together.

The 3+2 posts (:mod:`planning.post.linuxcnc`, :mod:`planning.post.iso`) turn the rotary axes once
per operation; here the tool axis changes from point to point. An operation is given as ball-centre
positions with a tool axis per point (:class:`FiveAxisOperation`, part frame, mm); the post
chooses the rotary angles along the path (:func:`rotary_path`), inserts points where the control's
interpolation would take the ball off the planned straight segments (linearisation, below), and
prints one of two programs:

* **LinuxCNC, trivial kinematics** (:func:`linuxcnc_5axis_program`): X Y Z are machine positions
  the post computes, as in :mod:`planning.post.linuxcnc` (table-table: the tool tip in the machine
  frame with ``G43 H``; head-head: the head rotation centre with ``G49``), plus the rotary words on
  every block. Between two blocks all axes move together LINEARLY IN JOINT SPACE.
* **ISO / Fanuc with tool centre point control** (:func:`iso_5axis_program`): ``G43.4 H`` (TCP on);
  X Y Z are the tool TIP in ``G54`` = the part frame, plus the rotary words. Between two blocks the
  control moves the tip straight in the part frame while the rotary axes move linearly.

Angles, frames and signs are those of :mod:`planning.orientations.kinematics` and
:mod:`planning.simulate.kinematics` (:class:`~planning.simulate.kinematics.MachineModel`).

Rotary angles along a path (:func:`rotary_path`)
------------------------------------------------
Every tool axis has up to two rotary solutions (:func:`~planning.orientations.kinematics.solve_rotary`:
``(tau, C1)`` and ``(-tau, C1 + 180)``). Point by point the solution WITHIN TRAVEL CLOSEST TO THE
PREVIOUS POINT'S ANGLES is taken (distance: the larger of the two joint turns, then their sum). A
continuous rotary axis is unwrapped by multiples of 360 degrees towards the previous angle, so
neighbours never differ by 180 degrees or more on it and the table never spins round between two
points (the printed C may leave [-180, 180)); a limited rotary axis only takes the 360-degree wraps
within its travel. The first point takes the solution :func:`~planning.orientations.kinematics.choose_rotary`
takes (smallest tilt, tilt >= 0), or the one closest to ``start_deg`` when given.

**The pole.** Where the tool axis is within ``pole_deg`` (default :data:`POLE_DEG` = 0.5 degree)
of the rotary axis' pole (tilt about 0, the axis along machine Z), the rotary angle is ill-defined:
the solver returns C = 0 there, and just beside the pole a small change of the tool axis needs a
large C turn (at 0.1 degree from the pole, a 0.1 degree step across it turns C by 90 degrees) - the
classic 5-axis singularity. Inside that cone the post KEEPS the previous rotary angle (the next
point's outside the cone, for a path that starts in it) and sets the tilt to the one that brings
the tool axis closest to the planned one with that C (``tilt = atan2(t . u(C), t_z)``, ``u(C)`` the
horizontal axis of tilt 90 at that C): for a path through the pole this interpolates the signed
tilt through 0 with C standing still. The tool axis then differs from the planned one by at most
about ``pole_deg``; the BALL CENTRE is still put exactly on the planned centre (positions below),
so a ball-end mill cuts the planned surface, only the tip moves by up to ``R * pole_deg`` (rad).

Points with no solution within travel are reported (``feasible`` False, with the out-of-travel
angles closest to the previous point), never clamped; the posts refuse such a path
(:class:`~planning.errors.ParameterError` naming the point).

Positions
---------
For every posted point the post rounds the angles as printed (rotary words, ``rotary_sign``
applied), takes the tool axis ``t'`` of the PRINTED angles, and puts the tool tip at ``tip = centre
- R t'`` (``R`` = ``radius_mm``), so that the ball centre is the planned one whatever the rounding of
the angles. X Y Z are computed from that tip and the printed angles (LinuxCNC:
:meth:`~planning.simulate.kinematics.MachineModel.machine_from_tip`; ISO: the tip itself). Where
the angles are exact (everywhere but the pole cone, to the rounding of the angles) the tip is the
planned ``centre - R t``.

Linearisation
-------------
Between two posted points the control interpolates its own way (LinuxCNC: joint space; ISO TCP: the
tip straight, the angles linear), and the ball centre leaves the straight planned centre segment
(on a table-table machine a C turn of 2 degrees with the part point 25 mm from the C axis takes it
about 0.004 mm off). The post inserts points on every move ``k`` (from planned point ``k - 1`` to
``k``, moves ``1..P-1``; move 0 comes from outside the path) by bisection in the move's parameter
``u``: the inserted centre is interpolated linearly, the inserted axis by slerp (great-circle
interpolation), its angles are the solution closest to the linear interpolation of the move's end
angles (pole rule as above; on a move with an end in the pole cone the inserted points take the
interpolated rotary angle and the closest tilt, so that the angles change continuously along the
move where C swings from the held to the solved value). A sub-move is split until the ball centre of the control's
interpolated motion at its quarter, mid and three-quarter points lies within ``linearise_tol_mm``
(default ``PostOptions.chord_tol_mm``) of the planned straight centre segment of its move. The
bisection runs on all moves at once, one depth at a time (at most :data:`MAX_DEPTH` halvings: a
move that still deviates raises). ``linearise=False`` posts the planned points only (the deviation
is still measured and reported).

Feeds
-----
Every feed move lasts ``time = max(L / feed, tilt turn / tilt limit, rotary turn / rotary limit,
MIN_MOVE_TIME_MIN)`` minutes: ``L`` the length of the straight TIP segment of the move in the part
frame (mm), ``feed`` the operation's ``feed_mm_min`` (``plunge_mm_min`` for
:data:`~planning.toolpath.moves.USE_PLUNGE` moves), the turns those of the printed angles (deg), the
limits the profile's ``tilt_feed_max_deg_min`` and ``rotary_feed_max_deg_min`` (default
:data:`~schemas.machine.DEFAULT_ROTARY_FEED_DEG_MIN` = 7200 deg/min, 20 rev/min; ``rotary_feed_deg_min`` given to the
LinuxCNC post overrides both). So no feed move turns an axis faster than the machine allows (the tip
then moves slower than ``feed``), a move that only turns takes its turn over the limit, and one that
neither travels nor turns :data:`MIN_MOVE_TIME_MIN`. F words are rounded DOWN to ``decimals`` (at
least one unit of the last), so the printed feed never makes a move faster than this. The
verification reads the programs back and counts a feed move that still turns an axis faster than
the profile's limit (:func:`planning.simulate.rotary_speed.rotary_feed_excesses`).

* LinuxCNC: feed moves (``G1``) in INVERSE-TIME mode ``G93``: ``F`` = 1 / time. ``G93``
  is printed on the first feed block of a run of feed moves, ``G94`` on the first rapid after it and
  at the end of the operation (``G93`` needs an ``F`` on every feed block: every one has it).
* ISO: ``G94`` ``F`` in mm/min of the TIP (TCP feed): ``L / time``, i.e. ``feed`` (``plunge_mm_min``
  on plunges) unless an axis limit makes the move slower; printed where it changes. A move that turns
  without moving the tip keeps ``feed`` (TCP has no way to time it; the control's own axis limits
  apply).

The C register
--------------
A continuous C is unwrapped along a path (above), so passes that keep turning the same way
accumulate whole turns (the deep slot's program reached C-4,600 and the 200k-point femur-like plan's C+4,433, which
the end of the program then turns back). The posts keep it in a register range: on a move in the air between
passes (the operation's ``unwind`` moves: in a plan, the rapids with both ends at the safe height;
without them, a rapid between two rapids) whose start has C more than :func:`unwind_deg` (the
register less two turns, at least one turn) from 0, C is turned back
to the twin in that range (:func:`rotary_path` ``unwind``). That move is posted as an operation's
start positions the rotary axes: up to machine Z0 (LinuxCNC ``G53 G0 Z0``; ISO ``G91 G28 Z0.``
and ``G49``, TCP off), the rotary axes turned there (``G0`` / ``G53 G0`` with the tilt and C
words), then down to the move's end (ISO ``G0 G43.4 H``, TCP on again): the table never swings
with the tool near the part. Within a pass C runs on continuously. The programs' C must stay
within +-``rotary_register_deg`` of the profile (default
:data:`~schemas.machine.DEFAULT_ROTARY_REGISTER_DEG`, ten turns): the verification's travel check
(:func:`planning.simulate.program.check_travel`) counts a C beyond it as a travel excursion.
The same is done for every rapid that changes rotary solution (the tilt's sign, outside the pole
cone): such a rapid cannot follow its segment and swings the table through the pole (the 50k-point
femur-like plan had one, C turning 180 degrees, whose tool went 3.6 mm into the stock), so it goes
up to machine Z0 first. A rapid that turns C a long way on the same solution is linearised like any
other (the ball centre on its segment; the verification runs it): a trip to machine Z0 for each of
those costs machining time (BENCHMARKS.md, "Simultaneous 5-axis: the C register").
Figures: ``rotary_range_deg``, ``n_unwound``, ``n_home`` (the rapids written through machine Z0).
* Rapids are ``G0``, also linearised (the control moves every axis together on them too; Fanuc:
  linear-interpolation-type positioning assumed, below).

LinuxCNC program (trivial kinematics)
-------------------------------------
``G54`` = the machine frame of :mod:`planning.post.linuxcnc`. Table-table: ``X Y Z`` = the tool tip
in the machine frame with ``G43 H<tool>`` (the spindle stays along machine Z); head-head: the head
rotation centre (``tip + (G + L) t``) with ``G49``, ``G`` = ``gauge_length_mm``. Rotary words: the
profile's letters, planner angles times ``rotary_sign``, ``decimals + 4`` places by default
(``angle_decimals``), on EVERY block with X Y Z. Layout: header comments (with ``signs: B as
planned, C as planned``, which the readers parse), ``G21 G90 G94 G17 G40 G49 G80``, ``G64 P<chord
tolerance>``, ``G54``; per operation ``G53 G0 Z0``, ``T M6``, ``G0 <tilt> <C>`` (the first point's
angles, at machine Z0, spindle off), ``S M3``, ``M8`` (coolant option), ``G43 H`` or ``G49``, ``G0``
to the approach point (the first tip ``safe_z_mm`` along the first tool axis), the moves, ``G94``,
``M9``, ``G53 G0 Z0``, ``G49``, ``M5``; at the end ``G53 G0 <tilt>0 C0`` and ``M30``. A continuous C
is not wrapped by the control (LinuxCNC's default for a rotary axis without ``WRAPPED_ROTARY``).

ISO / Fanuc program (``G43.4`` tool centre point control)
---------------------------------------------------------
Assumptions about the control (check them on yours):

* ``G43.4 H<t>`` is TCP "type 1": the rotary axes are programmed by their angle words (not a tool
  vector, ``G43.5``); the programmed point is the tool TIP (``H`` = the tool length to the tip).
* The program coordinate system ``G54`` is the PART frame as in :mod:`planning.post.iso` (origin at
  the part origin, axes parallel to the machine's with the rotary axes at 0) and, on a table-table
  machine, it TURNS WITH THE TABLE (the control's table-rotation TCP setting "program coordinate
  system fixed on the table").
* Between two blocks the tip moves straight in that frame and every rotary axis moves linearly in
  its angle from the start to the end value; ``G0`` in TCP mode is linear-interpolation-type
  positioning (not each axis at its own rapid rate).
* A continuous C is not rolled over (no shortest-way / modulo-360 positioning of the rotary axis).
* ``G91 G28 Z0.`` is accepted with TCP on (as the 3+2 post returns Z home with ``G43`` on); ``G49``
  cancels TCP once Z is home.

Rotary words: the profile's letters with the planner's angles (no sign change; the 3+2 ISO post
prints none either), ``angle_decimals`` places (default ``decimals``). Layout: ``%``, ``O``,
header comments, ``G21 G90 G94 G17 G40 G49 G80``, ``G69``, ``G91 G28 Z0.`` / ``G90``, ``G54``; per
operation ``T M6``, ``G53 G0 <tilt> <C>`` (the first point's angles in machine coordinates - the
rotary axes' machine zero is the planner's 0, as the ``G28`` return assumes - with Z home and TCP
off), ``S M3``,
``M8``, ``G0 G43.4 H<t> X Y Z <tilt> <C>`` (TCP on, straight to the approach point), the moves,
``M9``, ``G91 G28 Z0.``, ``G90 G49``, ``M5``; at the end ``G91 G28 <tilt>0. C0.`` / ``G90``,
``M30``, ``%``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from planning.errors import ParameterError
from planning.toolpath.fiveaxis.axes import slerp
from planning.toolpath.moves import (
    FEED,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
)

from .blocks import BlockWriter, comment, fmt, fmt_many, scanmill_version, spindle_word
from .options import PostOptions, check_options, check_placement

__all__ = [
    "MAX_DEPTH",
    "MIN_MOVE_TIME_MIN",
    "POLE_DEG",
    "UNWIND_ROOM_DEG",
    "FiveAxisOperation",
    "iso_5axis_blocks",
    "iso_5axis_program",
    "linuxcnc_5axis_blocks",
    "linuxcnc_5axis_motion",
    "linuxcnc_5axis_program",
    "rotary_path",
    "unwind_deg",
]

#: Half-angle of the cone about the rotary axis' pole inside which the rotary angle is held, deg.
POLE_DEG = 0.5
#: Largest number of halvings of one move by the linearisation.
MAX_DEPTH = 16
#: The room (deg) a continuous C keeps below its register when it is turned back: a pass's own turn.
UNWIND_ROOM_DEG = 720.0


def unwind_deg(profile) -> float:
    """How far from 0 (deg) a continuous C may be before it is turned back to its twin in
    [-180, 180] on a move in the air: the register (``rotary_limits_deg``) less
    :data:`UNWIND_ROOM_DEG`, at least one turn. Each turn back is a trip to machine Z0, which costs
    machining time (BENCHMARKS.md, "Simultaneous 5-axis: the C register"), so C is turned back only
    where the register needs it."""
    p = _profile(profile)
    return max(360.0, float(p.rotary_limits_deg[1]) - UNWIND_ROOM_DEG)

#: Shortest time of a LinuxCNC inverse-time move that neither travels nor turns, min.
MIN_MOVE_TIME_MIN = 1e-5

_UNIT_TOL = 1e-6
_ANGLE_TOL = 1e-9
_WRAPS = np.arange(-3, 4, dtype=np.float64) * 360.0
_SUPPORTED = ("table_table_ac", "table_table_bc", "head_head_ac", "head_head_bc")


@dataclass(frozen=True)
class FiveAxisOperation:
    """One simultaneous 5-axis operation (ball-end tool), PART frame, mm.

    ``centre_mm`` (P,3): ball-centre end points of the moves; ``axis`` (P,3): unit tool axis at each
    end point (from the part towards the spindle); ``kind`` (P,) int8:
    :data:`~planning.toolpath.moves.RAPID` or :data:`~planning.toolpath.moves.FEED` (no arcs);
    ``use`` (P,) int8: ``USE_RAPID`` / ``USE_CUT`` / ``USE_PLUNGE`` / ``USE_RETRACT``. Move ``k``
    goes from point ``k - 1`` to point ``k``; move 0 is a rapid to the first point from a safe
    position, and the path starts and ends with retract moves along the axis. ``radius_mm``: ball
    radius R (tip = centre - R axis); ``spindle_rpm`` (M3); ``feed_mm_min`` / ``plunge_mm_min``
    (mm/min of the tip); ``gauge_length_mm``: tool tip to spindle gauge line, mm. ``unwind`` (P,) bool
    or None: the moves (into point k) on which a continuous C may be turned back by whole turns
    (in the air: the planner gives the rapids at its safe height); None: every rapid between two
    rapids (module docstring, "The C register").
    """

    name: str
    centre_mm: np.ndarray
    axis: np.ndarray
    kind: np.ndarray
    use: np.ndarray
    tool_number: int
    radius_mm: float
    spindle_rpm: float
    feed_mm_min: float
    plunge_mm_min: float
    gauge_length_mm: float
    unwind: np.ndarray | None = None


# ------------------------------------------------------------------------------------------------
# checks


def _positive(v, what: str, parameter: str, *, zero_ok: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v) \
            or not (v >= 0 if zero_ok else v > 0):
        raise ParameterError(f"{what} = {v!r}: must be a finite number {'>= 0' if zero_ok else '> 0'}",
                             parameter=parameter, value=v)
    return float(v)


def _check_operation(op: FiveAxisOperation, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(centre (P,3), axis (P,3) unit, kind (P,), use (P,))`` of operation ``k``, checked."""
    if not isinstance(op, FiveAxisOperation):
        raise ParameterError(f"operation {k}: expected a FiveAxisOperation, got {type(op).__name__}",
                             parameter="operations")
    where = f"operation {k} ({op.name!r})"
    c = np.asarray(op.centre_mm, dtype=np.float64)
    a = np.asarray(op.axis, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or c.shape[0] == 0 or a.shape != c.shape:
        raise ParameterError(f"{where}: centre_mm and axis must be (P,3) with P >= 1, got {c.shape} and {a.shape}",
                             parameter="centre_mm")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(a))):
        raise ParameterError(f"{where}: NaN or infinite centres or axes", parameter="centre_mm")
    n = np.linalg.norm(a, axis=1)
    bad = np.abs(n - 1.0) > _UNIT_TOL
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ParameterError(f"{where}: axis {i} has norm {n[i]:.9g}; tool axes must be unit vectors",
                             parameter="axis")
    a = a / n[:, None]
    kind = np.asarray(op.kind).reshape(-1)
    use = np.asarray(op.use).reshape(-1)
    if kind.shape != (c.shape[0],) or use.shape != (c.shape[0],):
        raise ParameterError(f"{where}: kind and use must have one entry per point ({c.shape[0]})", parameter="kind")
    if not np.all(np.isin(kind, (RAPID, FEED))):
        i = int(np.flatnonzero(~np.isin(kind, (RAPID, FEED)))[0])
        raise ParameterError(f"{where}: move {i} has kind {int(kind[i])}; a 5-axis path has RAPID and FEED moves "
                             f"only (no arcs)", parameter="kind")
    if not np.all(np.isin(use, (USE_RAPID, USE_CUT, USE_PLUNGE, USE_RETRACT))):
        i = int(np.flatnonzero(~np.isin(use, (USE_RAPID, USE_CUT, USE_PLUNGE, USE_RETRACT)))[0])
        raise ParameterError(f"{where}: move {i} has an unknown use {int(use[i])}", parameter="use")
    t = op.tool_number
    if isinstance(t, bool) or not isinstance(t, (int, np.integer)) or not 1 <= int(t) <= 9999:
        raise ParameterError(f"{where}: tool_number = {t!r}: must be an integer in [1, 9999]", parameter="tool_number")
    _positive(op.radius_mm, f"{where}: radius_mm", "radius_mm", zero_ok=True)
    for name in ("spindle_rpm", "feed_mm_min", "plunge_mm_min", "gauge_length_mm"):
        _positive(getattr(op, name), f"{where}: {name}", name)
    if c.shape[0] > 1:
        dots = np.einsum("ij,ij->i", a[:-1], a[1:])
        if np.any(dots < -1.0 + 1e-9):
            i = int(np.flatnonzero(dots < -1.0 + 1e-9)[0]) + 1
            raise ParameterError(f"{where}: move {i} reverses the tool axis (no unique interpolation)",
                                 parameter="axis")
    return c, a, kind.astype(np.int8), use.astype(np.int8)


def _ops_list(operations) -> list:
    if isinstance(operations, FiveAxisOperation):
        operations = [operations]
    ops = list(operations) if operations is not None else []
    if not ops:
        raise ParameterError("a post needs at least one operation", parameter="operations")
    return ops


def _profile(profile):
    from planning.orientations.kinematics import as_profile

    p = as_profile(profile)
    if p.kinematics not in _SUPPORTED:            # pragma: no cover - the schema allows no other
        raise ParameterError(f"the 5-axis posts support {', '.join(_SUPPORTED)}, not {p.kinematics!r}",
                             parameter="machine.profile")
    return p


# ------------------------------------------------------------------------------------------------
# inverse kinematics along a path


class _Kin:
    """The profile's rotary travel and the pole rule (module docstring)."""

    def __init__(self, p, pole_deg: float):
        from planning.orientations.kinematics import tool_axis_from_angles

        self.p = p
        pole = _positive(pole_deg, "pole_deg", "pole_deg", zero_ok=True)
        if pole >= 90.0:
            raise ParameterError(f"pole_deg = {pole_deg!r}: must be below 90 degrees", parameter="pole_deg")
        self.pole_deg = pole
        self.sin_pole = math.sin(math.radians(pole))
        self.tmin, self.tmax = float(p.tilt_min_deg), float(p.tilt_max_deg)
        self.cont = bool(p.rotary_continuous)
        self.rmin = -math.inf if self.cont else float(p.rotary_min_deg)
        self.rmax = math.inf if self.cont else float(p.rotary_max_deg)
        u = tool_axis_from_angles(np.array([[90.0, 0.0], [90.0, 90.0]]), p)
        self.u0, self.u90 = u[0], u[1]          # u(C) = cos C u0 + sin C u90: the axis at tilt 90

    def is_pole(self, axes: np.ndarray) -> np.ndarray:
        return np.hypot(axes[:, 0], axes[:, 1]) < self.sin_pole

    def pole_tilt(self, axes: np.ndarray, c_deg: np.ndarray, ref_tilt: np.ndarray) -> np.ndarray:
        """(m,) the tilt that brings the axis of ``(tilt, c_deg)`` closest to ``axes`` (m,3), the
        360-degree twin nearest ``ref_tilt`` where it is at +-180."""
        cr = np.radians(c_deg)
        u = np.cos(cr)[:, None] * self.u0 + np.sin(cr)[:, None] * self.u90
        t = np.degrees(np.arctan2(np.einsum("ij,ij->i", axes, u), axes[:, 2]))
        twin = t - 360.0 * np.sign(t)
        return np.where(np.abs(twin - ref_tilt) < np.abs(t - ref_tilt), twin, t) + 0.0

    def tilt_ok(self, t):
        return (t >= self.tmin - _ANGLE_TOL) & (t <= self.tmax + _ANGLE_TOL)

    def rot_ok(self, c):
        return (c >= self.rmin - _ANGLE_TOL) & (c <= self.rmax + _ANGLE_TOL)

    def near(self, axes: np.ndarray, ref: np.ndarray, held=None, branch=None) -> tuple[np.ndarray, np.ndarray]:
        """``(angles (m,2), ok (m,))``: per axis the solution within travel closest to ``ref`` (m,2)
        (the closest out of travel, ok False, where none is within), pole rule applied (also where
        ``held`` (m,) bool: the rotary angle of ``ref`` kept, the tilt the closest). ``branch`` (m,)
        of -1, 0, 1: where not 0, a solution whose tilt has that sign is taken whenever one is within
        travel, however far from ``ref`` (the branch both ends of a move are on: a reference
        interpolated between the ends can lie nearer the other branch where the rotary angle turns
        fast beside the pole). Vectorised."""
        from planning.orientations.kinematics import solve_rotary

        m = axes.shape[0]
        if m == 0:
            return np.zeros((0, 2)), np.zeros(0, dtype=bool)
        sols = solve_rotary(axes, self.p).angles_deg
        T, Cw = sols[:, :, 0], sols[:, :, 1]
        rt, rc = ref[:, 0:1], ref[:, 1:2]
        if self.cont:
            C = Cw + 360.0 * np.round((rc - Cw) / 360.0)
            cok = np.ones(C.shape, dtype=bool)
        else:
            cand = Cw[:, :, None] + _WRAPS
            inside = self.rot_ok(cand)
            d = np.abs(cand - rc[:, :, None])
            pick = np.where(inside.any(axis=2), np.argmin(np.where(inside, d, np.inf), axis=2), np.argmin(d, axis=2))
            C = np.take_along_axis(cand, pick[:, :, None], axis=2)[:, :, 0]
            cok = inside.any(axis=2)
        ok = self.tilt_ok(T) & cok
        dt, dc = np.abs(T - rt), np.abs(C - rc)
        key = np.maximum(dt, dc) + 1e-9 * (dt + dc)
        if branch is not None:
            b = np.asarray(branch, dtype=np.float64).reshape(-1, 1)
            on = ok & ((b == 0) | (np.sign(T) == b))
            ok_pick = np.where(on.any(axis=1, keepdims=True), on, ok)
        else:
            ok_pick = ok
        any_ok = ok.any(axis=1)
        j = np.where(any_ok, np.argmin(np.where(ok_pick, key, np.inf), axis=1), np.argmin(key, axis=1))
        r = np.arange(m)
        ang = np.stack([T[r, j], C[r, j]], axis=1)
        good = ok[r, j]
        pole = self.is_pole(axes)
        if held is not None:
            pole = pole | held
        if pole.any():
            c_hold = ref[pole, 1]
            t_pole = self.pole_tilt(axes[pole], c_hold, ref[pole, 0])
            ang[pole] = np.stack([t_pole, c_hold], axis=1)
            good[pole] = self.tilt_ok(t_pole) & self.rot_ok(c_hold)
        return ang, good


def _unit_axes(axes) -> np.ndarray:
    a = np.asarray(axes, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise ParameterError(f"tool axes must be a finite (n,3) array, got shape {np.shape(axes)}", parameter="axes")
    n = np.linalg.norm(a, axis=1)
    if np.any(np.abs(n - 1.0) > _UNIT_TOL):
        i = int(np.flatnonzero(np.abs(n - 1.0) > _UNIT_TOL)[0])
        raise ParameterError(f"tool axis {i} has norm {n[i]:.9g}; tool axes must be unit vectors", parameter="axes")
    return a / n[:, None]


def rotary_path(axes, profile, *, start_deg=None, pole_deg: float = POLE_DEG,
                unwind=None) -> tuple[np.ndarray, np.ndarray]:
    """Rotary angles along a path of tool axes: inverse kinematics with continuity (module docstring).

    ``axes`` (n,3): unit tool axes in the part frame, in path order; ``profile``: MachineProfile,
    bundled name or JSON path; ``start_deg`` ``(tilt, rotary)`` (deg, planner signs) or None: the
    first point takes the solution closest to it, else the one
    :func:`~planning.orientations.kinematics.choose_rotary` takes; ``pole_deg``: half-angle of the
    cone about the pole inside which the rotary angle is held (deg); ``unwind`` (n,) bool or None:
    the points where a continuous C may be turned back (module docstring, "The C register"): at such
    a point whose predecessor's C lies more than :func:`unwind_deg` from 0 the solution is chosen as if the
    predecessor's C were its twin in that range, so the move into it unwinds whole turns.

    Returns ``(angles_deg (n,2), feasible (n,))``: ``(tilt, rotary)`` per point in the signs of
    :mod:`planning.orientations.kinematics` (continuous rotary axis unwrapped: consecutive values
    differ by less than 180 degrees), and whether the point is within the rotary travel. An
    infeasible point gets the out-of-travel solution closest to the previous point (not clamped).
    """
    from planning.orientations.kinematics import choose_rotary, solve_rotary

    p = _profile(profile)
    a = _unit_axes(axes)
    n = a.shape[0]
    kin = _Kin(p, pole_deg)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, dtype=bool)
    sols = solve_rotary(a, p)
    pole = kin.is_pole(a)
    if start_deg is not None:
        ref = np.asarray(start_deg, dtype=np.float64).reshape(-1)
        if ref.shape != (2,) or not np.all(np.isfinite(ref)):
            raise ParameterError(f"start_deg = {start_deg!r}: must be (tilt_deg, rotary_deg)", parameter="start_deg")
        ref = ref.copy()
    else:
        free = np.flatnonzero(~pole)
        if free.size:
            f = int(free[0])
            chosen, ok = choose_rotary(solve_rotary(a[f], p))
            ref = chosen[0] if bool(ok[0]) else sols.angles_deg[f, 0].copy()
        else:
            ref = sols.angles_deg[0, 0].copy()
    if unwind is None:
        uw = np.zeros(n, dtype=np.bool_)
    else:
        uw = np.asarray(unwind, dtype=np.bool_).reshape(-1)
        if uw.shape != (n,):
            raise ParameterError(f"unwind must have one entry per axis ({n}), got {uw.shape}", parameter="unwind")
    return _rotary_walk(sols.angles_deg[:, :, 0], sols.angles_deg[:, :, 1], a, pole, kin.u0, kin.u90,
                        kin.tmin - _ANGLE_TOL, kin.tmax + _ANGLE_TOL, kin.rmin - _ANGLE_TOL, kin.rmax + _ANGLE_TOL,
                        kin.cont, _WRAPS, kin.pole_deg, float(ref[0]), float(ref[1]), uw, unwind_deg(p))


@njit(cache=True, nogil=True)
def _rotary_walk(T, Cw, axes, pole, u0, u90, tmin, tmax, rmin, rmax, cont, wraps, pole_deg, pt, pc, unwind,
                 unwind_deg):
    """The point-by-point choice of :func:`rotary_path` (compiled: each point depends on the last).
    ``T``/``Cw`` (n,2): the solver's tilts and unwrapped rotary angles; ``pole`` (n,): in the pole
    cone; ``tmin``..``rmax``: the travel with its tolerance; ``(pt, pc)``: the reference angles;
    ``unwind`` (n,): where a continuous C beyond ``unwind_deg`` is referred to its twin in [-180, 180]."""
    n = axes.shape[0]
    out = np.empty((n, 2))
    feas = np.empty(n, dtype=np.bool_)
    for i in range(n):
        if cont and unwind[i] and not pole[i] and abs(pc) > unwind_deg:
            pc = pc - 360.0 * np.rint(pc / 360.0)
        if pole[i]:
            cr = math.radians(pc)
            cc, sc = math.cos(cr), math.sin(cr)
            x, y, z = axes[i, 0], axes[i, 1], axes[i, 2]
            ux = cc * u0[0] + sc * u90[0]
            uy = cc * u0[1] + sc * u90[1]
            uz = cc * u0[2] + sc * u90[2]
            t = math.degrees(math.atan2(x * ux + y * uy + z * uz, z))
            twin = t - 360.0 if t > 0 else t + 360.0
            if abs(twin - pt) < abs(t - pt):
                t = twin
            ok = tmin <= t <= tmax and rmin <= pc <= rmax
            pt = t + 0.0
        else:
            # the key of a candidate: (it flips the tilt's sign, the larger joint turn, their sum),
            # compared in that order; the first of equal keys is kept
            have, have_any = False, False
            bf, bm, bs, bt, bc = False, 0.0, 0.0, 0.0, 0.0
            af, am, as_, at, ac = False, 0.0, 0.0, 0.0, 0.0
            nc = 1 if cont else wraps.shape[0]
            for s in range(2):
                t = T[i, s]
                t_ok = tmin <= t <= tmax
                cw = Cw[i, s]
                for w in range(nc):
                    c = cw + 360.0 * np.rint((pc - cw) / 360.0) if cont else cw + wraps[w]
                    dt, dc = abs(t - pt), abs(c - pc)
                    # the other solution has the tilt of the other sign: going there the tilt passes
                    # through 0, the pole, where the rotary axis swings; taken only when it must be
                    # (from a point in the pole cone the tilt does change sign: the path went through it)
                    f = t * pt < 0.0 and abs(pt) > pole_deg
                    m, sm = max(dt, dc), dt + dc
                    if not have_any or _key_less(f, m, sm, af, am, as_):
                        have_any, af, am, as_, at, ac = True, f, m, sm, t, c
                    if t_ok and rmin <= c <= rmax and (not have or _key_less(f, m, sm, bf, bm, bs)):
                        have, bf, bm, bs, bt, bc = True, f, m, sm, t, c
            ok = have
            if ok:
                pt, pc = bt + 0.0, bc + 0.0
            else:
                pt, pc = at + 0.0, ac + 0.0
        out[i, 0], out[i, 1] = pt, pc
        feas[i] = ok
    return out, feas


@njit(cache=True, nogil=True, inline="always")
def _key_less(f, m, s, f0, m0, s0) -> bool:
    """``(f, m, s) < (f0, m0, s0)`` as tuples compare."""
    if f != f0:
        return f0
    if m != m0:
        return m < m0
    return s < s0


# ------------------------------------------------------------------------------------------------
# the posted points and the linearisation


def _seg_dist(q: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """(m,) distance of points ``q`` from the segments ``p0``-``p1`` (all (m,3))."""
    d = p1 - p0
    dd = np.einsum("ij,ij->i", d, d)
    s = np.clip(np.einsum("ij,ij->i", q - p0, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(q - (p0 + s[:, None] * d), axis=1)


_CHECK_AT = (0.25, 0.5, 0.75)


class _Path:
    """One operation's path on one machine for one dialect: the posted points and how the control
    moves between them (module docstring)."""

    def __init__(self, op: FiveAxisOperation, k: int, p, placement: np.ndarray, dialect: str, o: PostOptions,
                 rotary_sign, pole_deg: float, start_deg):
        from planning.orientations.kinematics import tool_axis_from_angles
        from planning.simulate.kinematics import MachineModel

        self.op, self.k, self.p, self.dialect, self.o = op, k, p, dialect, o
        self.c, self.a, self.kind, self.use = _check_operation(op, k)
        self.R = float(op.radius_mm)
        self.model = MachineModel(p, placement)
        self.kin = _Kin(p, pole_deg)
        self.fk = lambda ang: tool_axis_from_angles(ang, p)
        self.iso = dialect == "iso"
        # LinuxCNC: the controlled point the program's X Y Z are (tip with G43 / head centre with G49)
        self.g_post = 0.0 if (self.iso or p.is_table_table) else float(op.gauge_length_mm)
        d = int(o.decimals)
        if o.angle_decimals is not None:
            self.ad = int(o.angle_decimals)
        else:
            self.ad = d if self.iso else d + 4
        if self.iso:
            self.sign = (1.0, 1.0)
        else:
            rs = o.rotary_sign if rotary_sign is None else rotary_sign
            if not (isinstance(rs, (tuple, list)) and len(rs) == 2 and all(v in (1, -1) for v in rs)):
                raise ParameterError(f"rotary_sign = {rs!r}: must be two signs (tilt, rotary), each 1 or -1",
                                     parameter="rotary_sign", value=rs)
            self.sign = (float(rs[0]), float(rs[1]))
        cand = self._unwind_candidates()
        self.ang, feas = rotary_path(self.a, p, start_deg=start_deg, pole_deg=pole_deg, unwind=cand)
        #: (P,) the moves INTO each point that turn C back (module docstring, "The C register")
        self.unwinding = cand
        self.unwinding[1:] &= np.abs(np.diff(self.ang[:, 1])) >= 180.0
        #: (P,) the rapids INTO each point written through machine Z0: the turns back, and every rapid
        #: that changes rotary solution (the tilt's sign, outside the pole cone): the table is not
        #: swung through the pole with the tool near the part
        self.home = self.unwinding.copy()
        if self.c.shape[0] > 1:
            t = self.ang[:, 0]
            flip = (t[1:] * t[:-1] < 0) & (np.abs(t[1:]) > self.kin.pole_deg) & (np.abs(t[:-1]) > self.kin.pole_deg)
            self.home[1:] |= (self.kind[1:] == RAPID) & flip
        if not feas.all():
            i = int(np.flatnonzero(~feas)[0])
            raise ParameterError(
                f"operation {k} ({op.name!r}): point {i} (tool axis {np.round(self.a[i], 6).tolist()}) has no rotary "
                f"position within the travel of {p.name} (needs {p.axis_names[0]}{self.ang[i, 0]:.4f} "
                f"{p.axis_names[1]}{self.ang[i, 1]:.4f}; tilt {p.tilt_min_deg:g}..{p.tilt_max_deg:g})",
                parameter="axis")
        self.n_pole = int(self.kin.is_pole(self.a).sum())

    def _unwind_candidates(self) -> np.ndarray:
        """(P,) bool: the moves into each point on which C may be turned back (``op.unwind``, else a
        rapid between two rapids); none on a limited C."""
        P = self.c.shape[0]
        cand = np.zeros(P, dtype=bool)
        if not self.p.rotary_continuous or P < 2:
            return cand
        if self.op.unwind is not None:
            u = np.asarray(self.op.unwind, dtype=bool).reshape(-1)
            if u.shape != (P,):
                raise ParameterError(f"operation {self.k} ({self.op.name!r}): unwind must have one entry per point "
                                     f"({P}), got {u.shape}", parameter="unwind")
            cand[1:] = u[1:] & (self.kind[1:] == RAPID)
            return cand
        cand[1:] = (self.kind[1:] == RAPID) & (self.kind[:-1] == RAPID)
        return cand

    # ---- posted points

    def words(self, ang: np.ndarray) -> list:
        """``[(tilt, rot)]``: the rotary words (strings) of planner angles ``ang`` (m,2)."""
        st, sr = self.sign
        a = np.asarray(ang, dtype=np.float64).reshape(-1, 2)
        return list(zip(fmt_many(st * a[:, 0], self.ad), fmt_many(sr * a[:, 1], self.ad)))

    def printed(self, ang: np.ndarray) -> np.ndarray:
        """(m,2) the planner angles that the words of ``ang`` (m,2) command: what a control reads
        from :meth:`words`, to the bit (:func:`_as_printed`), without writing them."""
        sg = np.array(self.sign)
        return _as_printed(np.asarray(ang, dtype=np.float64).reshape(-1, 2) * sg, self.ad) * sg + 0.0

    def points(self, j: np.ndarray, u: np.ndarray) -> dict:
        """The posted point at parameter ``u`` (m,) of planned move ``j`` (m,) (``u = 1``: the
        planned point ``j``; ``u = 0``: point ``j - 1``)."""
        j = np.asarray(j, dtype=np.int64)
        u = np.asarray(u, dtype=np.float64)
        jm = np.maximum(j - 1, 0)
        c, a, ang = self.c, self.a, self.ang
        inner = (u > 0.0) & (u < 1.0)
        centre = np.where((u >= 1.0)[:, None], c[j], c[jm])
        axis = np.where((u >= 1.0)[:, None], a[j], a[jm])
        angles = np.where((u >= 1.0)[:, None], ang[j], ang[jm])
        if inner.any():
            ji, ui = j[inner], u[inner]
            centre[inner] = c[ji - 1] + ui[:, None] * (c[ji] - c[ji - 1])
            axis[inner] = slerp(a[ji - 1], a[ji], ui)
            ref = ang[ji - 1] + ui[:, None] * (ang[ji] - ang[ji - 1])
            # on a move into or out of the pole cone C changes from the held to the solved value:
            # the inserted points take C linearly (pole rule) so that the angles stay continuous in u
            held = self.kin.is_pole(a[ji - 1]) | self.kin.is_pole(a[ji])
            # both ends on one branch (the tilt's sign, outside the pole cone): the points between keep it
            t0, t1 = ang[ji - 1, 0], ang[ji, 0]
            pole_t = self.kin.pole_deg
            branch = np.where((t0 * t1 > 0) & (np.abs(t0) > pole_t) & (np.abs(t1) > pole_t), np.sign(t1), 0.0)
            got, ok = self.kin.near(axis[inner], ref, held, branch)
            if not ok.all():
                b = int(np.flatnonzero(~ok)[0])
                raise ParameterError(
                    f"operation {self.k} ({self.op.name!r}): the interpolated tool axis on move {int(ji[b])} "
                    f"{np.round(axis[inner][b], 6).tolist()} has no rotary position within travel", parameter="axis")
            angles[inner] = got
        printed = self.printed(angles)
        axis_p = self.fk(printed)
        tip = centre - self.R * axis_p
        pos = tip if self.iso else self.model.machine_from_tip(tip, printed, self.g_post)
        # ``angles``: the planner's, whose words (:meth:`words`) the writers print; ``printed`` what they command
        return {"j": j, "u": u, "centre": centre, "axis": axis, "angles": angles, "printed": printed,
                "axis_p": axis_p, "tip": tip, "pos": pos}

    def centres(self, pos: np.ndarray, ang: np.ndarray) -> np.ndarray:
        """(m,3) ball centres (part frame) where the control is at program point ``pos`` and angles ``ang``."""
        if self.iso:
            return pos + self.R * self.fk(ang)
        tip, axis = self.model.tip_from_machine(pos, ang, self.g_post)
        return tip + self.R * axis

    def deviation(self, A: dict, B: dict, j: np.ndarray) -> np.ndarray:
        """(m,) largest distance of the ball centre from the planned centre segment of move ``j``
        at the checked fractions of the sub-moves from ``A`` to ``B``."""
        dev = np.zeros(len(j))
        p0, p1 = self.c[j - 1], self.c[j]
        for s in _CHECK_AT:
            q = self.centres(A["pos"] + s * (B["pos"] - A["pos"]), A["printed"] + s * (B["printed"] - A["printed"]))
            dev = np.maximum(dev, _seg_dist(q, p0, p1))
        return dev

    def linearise(self, tol: float, enabled: bool) -> tuple[dict, dict]:
        """``(posted, figures)``: every posted point in order (dict of arrays, as :meth:`points`) and
        the figures of the linearisation (module docstring)."""
        P = self.c.shape[0]
        first = self.points(np.arange(P), np.ones(P))
        if P == 1:
            return first, {"max_deviation_mm": 0.0, "max_deviation_unlinearised_mm": 0.0, "depth": 0}
        j = np.arange(1, P)
        U0 = np.zeros(P - 1)
        A, B = _take(first, j - 1), _take(first, j)
        done = []
        dev_before, dev_after, depth = 0.0, 0.0, 0
        for depth in range(MAX_DEPTH + 1):
            dev = self.deviation(A, B, j)
            dev[self.home[j]] = 0.0               # posted through machine Z0 (module docstring)
            if depth == 0:
                dev_before = float(dev.max())
            bad = dev > tol if enabled else np.zeros(len(j), dtype=bool)
            good = ~bad
            if good.any():
                done.append(_take(B, good))
                dev_after = max(dev_after, float(dev[good].max()))
            if not bad.any():
                break
            if depth == MAX_DEPTH:
                # a rapid (in the air, at the safe height or along the axis) that turns the table to
                # another rotary solution cannot follow its segment: it is posted as it is (the
                # simulation runs it as the control does); a feed move must follow
                air = self.kind[j] == RAPID
                if not (bad & ~air).any():
                    done.append(_take(B, bad))
                    break
                i = int(np.flatnonzero(bad & ~air)[0])
                jj = int(j[i])
                turn = np.abs(self.ang[jj] - self.ang[jj - 1])
                tn, rn = self.p.axis_names
                raise ParameterError(
                    f"operation {self.k} ({self.op.name!r}): move {jj} still takes the ball centre {dev[i]:.4g} mm "
                    f"off its segment after {MAX_DEPTH} halvings (tolerance {tol:g} mm); its end points are "
                    f"{tn}{turn[0]:.4g} {rn}{turn[1]:.4g} deg apart (a change of rotary solution at a travel limit "
                    f"cannot be made on the surface: retract, turn, re-enter)", parameter="linearise_tol_mm")
            jb, u0, Ab, Bb = j[bad], U0[bad], _take(A, bad), _take(B, bad)
            um = 0.5 * (u0 + Bb["u"])
            M = self.points(jb, um)
            j, U0 = np.concatenate([jb, jb]), np.concatenate([u0, um])
            A, B = _cat(Ab, M), _cat(M, Bb)
        posted = _cat(_take(first, np.array([0])), *done)
        order = np.lexsort((posted["u"], posted["j"]))
        posted = _take(posted, order)
        return posted, {"max_deviation_mm": dev_after, "max_deviation_unlinearised_mm": dev_before, "depth": depth}


def _take(d: dict, idx) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, list):
            ix = np.arange(len(v))[idx]
            out[k] = [v[i] for i in ix.tolist()]
        else:
            out[k] = v[idx]
    return out


def _cat(*ds: dict) -> dict:
    keys = ds[0].keys()
    out = {}
    for k in keys:
        if isinstance(ds[0][k], list):
            out[k] = [x for d in ds for x in d[k]]
        else:
            out[k] = np.concatenate([d[k] for d in ds])
    return out


# ------------------------------------------------------------------------------------------------
# the programs


def _rate_limits(p, rotary_feed_deg_min) -> tuple[float, float]:
    """``(tilt, rotary)`` fastest turns in a feed move, deg/min: the profile's
    (``feed_limits_deg_min``), or ``rotary_feed_deg_min`` for both where given."""
    if rotary_feed_deg_min is None:
        return p.feed_limits_deg_min
    v = _positive(rotary_feed_deg_min, "rotary_feed_deg_min", "rotary_feed_deg_min")
    return v, v


def _floor_dec(v: np.ndarray, d: int) -> np.ndarray:
    """``v`` rounded DOWN to ``d`` decimals, at least one unit of the last (a feed word printed this
    way never makes a move faster than computed)."""
    s = 10.0 ** int(d)
    return np.maximum(np.floor(v * s) / s, 1.0 / s)


def _feeds(path: _Path, posted: dict, approach_tip: np.ndarray, limits: tuple[float, float],
           decimals: int, printed_tips: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(tip length (n,), inverse-time F (n,), tip feed F (n,))`` of the moves ending at the posted
    points (from the approach point for the first), mm, 1/min and mm/min: each feed move lasts
    ``max(L / feed, tilt turn / tilt limit, rotary turn / rotary limit, MIN_MOVE_TIME_MIN)``
    (printed angles); both F words rounded down to ``decimals`` (:func:`_floor_dec`). The tip feed
    of a move that turns without moving the tip is the operation's feed. ``printed_tips``: the tips
    are the program's X Y Z (ISO): the lengths are taken between the printed (rounded) tips, as the
    control measures them."""
    tip = posted["tip"]
    if printed_tips:
        tip, approach_tip = np.round(tip, int(decimals)), np.round(approach_tip, int(decimals))
    prev_tip = np.vstack([approach_tip[None, :], tip[:-1]])
    L = np.linalg.norm(tip - prev_tip, axis=1)
    ang = posted["printed"]
    turn = np.vstack([np.zeros((1, 2)), np.abs(np.diff(ang, axis=0))]) if len(ang) else np.zeros((0, 2))
    use = path.use[posted["j"]]
    feed = np.where(use == USE_PLUNGE, float(path.op.plunge_mm_min), float(path.op.feed_mm_min))
    time = np.maximum.reduce([L / feed, turn[:, 0] / limits[0], turn[:, 1] / limits[1],
                              np.full(L.shape, MIN_MOVE_TIME_MIN)]) if len(L) else np.zeros(0)
    tip_feed = np.where(L > 1e-9, np.minimum(feed, L / np.maximum(time, 1e-300)), feed)
    return L, _floor_dec(1.0 / np.maximum(time, 1e-300), decimals), _floor_dec(tip_feed, decimals)


def _prepare(op, k, p, place, dialect, o, rotary_sign, pole_deg, start_deg, linearise_tol_mm, linearise):
    path = _Path(op, k, p, place, dialect, o, rotary_sign, pole_deg, start_deg)
    tol = o.chord_tol_mm if linearise_tol_mm is None else _positive(linearise_tol_mm, "linearise_tol_mm",
                                                                     "linearise_tol_mm")
    posted, fig = path.linearise(float(tol), bool(linearise))
    return path, posted, fig, float(tol)


def _home_points(path: _Path, posted: dict) -> np.ndarray:
    """(n,) bool: the posted points a rapid reaches through machine Z0 (the planned points whose move
    turns C back or changes rotary solution, ``_Path.home``; never an inserted point)."""
    return path.home[posted["j"]] & (posted["u"] >= 1.0)


def _approach(path: _Path, posted: dict, o: PostOptions) -> tuple[np.ndarray, np.ndarray]:
    """``(tip (3,), program position (3,))`` of the approach point: the first tip ``safe_z_mm``
    along the first tool axis (printed angles)."""
    tip = posted["tip"][0] + float(o.safe_z_mm) * posted["axis_p"][0]
    if path.iso:
        return tip, tip
    return tip, path.model.machine_from_tip(tip[None, :], posted["printed"][:1], path.g_post)[0]


def _op_comment(k: int, op: FiveAxisOperation, n_inserted: int, tol: float, upper: bool) -> str:
    return comment(f"operation {k + 1}: {op.name} - T{int(op.tool_number)} ball R{fmt(op.radius_mm, 4)} - "
                   f"S{round(float(op.spindle_rpm))} F{fmt(op.feed_mm_min, 3)} plunge F{fmt(op.plunge_mm_min, 3)} "
                   f"mm/min - gauge {fmt(op.gauge_length_mm, 4)} - {n_inserted} points inserted, ball centre within "
                   f"{fmt(tol, 4)} mm of the planned segments", upper=upper)


def _figures(path: _Path, posted: dict, fig: dict, lines: list, L: np.ndarray, tol: float,
             limits: tuple[float, float]) -> dict:
    P = path.c.shape[0]
    ang = posted["printed"]
    turn = np.abs(np.diff(ang, axis=0)).max(axis=1) if len(ang) > 1 else np.zeros(0)
    return {
        "name": path.op.name,
        "n_moves": int(P),
        "n_points": len(posted["j"]),
        "n_inserted": int(len(posted["j"]) - P),
        "n_pole": path.n_pole,
        "linearise_tol_mm": tol,
        "max_deviation_mm": fig["max_deviation_mm"],
        "max_deviation_unlinearised_mm": fig["max_deviation_unlinearised_mm"],
        "max_depth": int(fig["depth"]),
        "max_turn_deg": float(turn.max()) if turn.size else 0.0,
        "tilt_range_deg": (float(ang[:, 0].min()), float(ang[:, 0].max())),
        "rotary_range_deg": (float(ang[:, 1].min()), float(ang[:, 1].max())),
        "n_unwound": int(path.unwinding.sum()),
        "n_home": int(path.home.sum()),
        "feed_limits_deg_min": (float(limits[0]), float(limits[1])),
        "tip_path_mm": float(L[1:].sum()),
        "line": np.asarray(lines, dtype=np.int64),
        "move": posted["j"].copy(),
        "u": posted["u"].copy(),
        "angles_deg": ang.copy(),
        "tip_mm": posted["tip"].copy(),
        "centre_mm": posted["centre"].copy(),
    }


def linuxcnc_5axis_blocks(w: BlockWriter, options: PostOptions | None, op: FiveAxisOperation, profile, placement_mm,
                          rotary_sign=None, *, index: int = 0, start_deg=None, linearise_tol_mm: float | None = None,
                          linearise: bool = True, pole_deg: float = POLE_DEG,
                          rotary_feed_deg_min: float | None = None) -> dict:
    """Write one simultaneous operation for LinuxCNC (trivial kinematics) to ``w``; return its figures.

    ``options``: :class:`~planning.post.options.PostOptions` (None: defaults); ``op``:
    :class:`FiveAxisOperation`; ``profile``: MachineProfile, bundled name or path; ``placement_mm``
    (3,): part origin in the table frame; ``rotary_sign``: ``(tilt_sign, rotary_sign)`` of the
    printed words (None: ``options.rotary_sign``); ``index``: the operation's number - 1 (comment);
    ``start_deg``: see :func:`rotary_path`; ``linearise_tol_mm`` (None: ``options.chord_tol_mm``),
    ``linearise`` (False: the planned points only), ``pole_deg``, ``rotary_feed_deg_min``: module
    docstring. The program around it (header, safe block, end) is :func:`linuxcnc_5axis_program`'s.

    Figures (dict): ``n_moves`` (planned points), ``n_points`` (posted motion blocks of the path),
    ``n_inserted``, ``n_pole`` (planned points in the pole cone), ``max_deviation_mm`` /
    ``max_deviation_unlinearised_mm`` (ball centre from the planned segments at the checked
    fractions, with / without the inserted points), ``max_depth``, ``max_turn_deg`` (largest rotary
    turn between posted points), ``tilt_range_deg`` / ``rotary_range_deg``, ``tip_path_mm``, and per
    posted point ``line`` (1-based line in ``w``), ``move`` (the planned move it lies on), ``u``,
    ``angles_deg`` (printed, planner signs), ``tip_mm`` and ``centre_mm`` (part frame).
    """
    o = check_options(options)
    p = _profile(profile)
    place = check_placement(placement_mm)
    limits = _rate_limits(p, rotary_feed_deg_min)
    path, posted, fig, tol = _prepare(op, index, p, place, "linuxcnc", o, rotary_sign, pole_deg, start_deg,
                                      linearise_tol_mm, linearise)
    d = int(o.decimals)
    table = p.is_table_table
    tn, rn = p.axis_names
    tool = int(op.tool_number)
    tip_a, pos_a = _approach(path, posted, o)
    L, F, _ = _feeds(path, posted, tip_a, limits, d)
    words = path.words(posted["angles"])
    n_ins = len(posted["j"]) - path.c.shape[0]

    w.raw(_op_comment(index, op, n_ins, tol, upper=False))
    from planning.post.linuxcnc import operation_end, operation_start

    operation_start(w, o, tool, op.spindle_rpm, table, (f"{tn}{words[0][0]}", f"{rn}{words[0][1]}"),
                    f"X Y Z = head rotation centre = tip + {fmt(op.gauge_length_mm + p.pivot_length_mm, d)} mm "
                    f"along the tool axis")
    w.block("G0", f"X{fmt(pos_a[0], d)}", f"Y{fmt(pos_a[1], d)}", f"Z{fmt(pos_a[2], d)}", f"{tn}{words[0][0]}",
            f"{rn}{words[0][1]}")
    X, Y, Z = (fmt_many(posted["pos"][:, k], d) for k in range(3))
    kinds = path.kind[posted["j"]].tolist()
    Fl = fmt_many(F, d)
    lines = []
    mode = 94
    home = _home_points(path, posted).tolist()
    for i in range(len(X)):
        head = []
        if kinds[i] == RAPID:
            if mode == 93:
                head.append("G94")
                mode = 94
            if home[i]:
                # C turned back by whole turns: up to machine Z0, turn, down to the point (as an
                # operation's start positions the rotary axes)
                w.block(*head, "G53", "G0", "Z0")
                w.block("G0", f"{tn}{words[i][0]}", f"{rn}{words[i][1]}")
                head = []
            head.append("G0")
            tail = ()
        else:
            if mode != 93:
                head.append("G93")
                mode = 93
            head.append("G1")
            tail = (f"F{Fl[i]}",)
        w.block(*head, f"X{X[i]}", f"Y{Y[i]}", f"Z{Z[i]}", f"{tn}{words[i][0]}", f"{rn}{words[i][1]}", *tail)
        lines.append(len(w.lines))
    if mode == 93:
        w.block("G94")
    operation_end(w, o)
    return _figures(path, posted, fig, lines, L, tol, limits)


def _as_printed(values: np.ndarray, decimals: int) -> np.ndarray:
    """``values`` as a control reads them back from :func:`~planning.post.blocks.fmt` (the same
    decimal rounding, to the bit): numpy's rounding, and the string's for the values within a hair
    of a half unit of the last place, where the two may round differently."""
    v = np.asarray(values, dtype=np.float64)
    s = 10.0 ** int(decimals)
    out = np.round(v, int(decimals))
    frac = np.abs(v * s - np.floor(v * s) - 0.5)
    near = np.flatnonzero((frac < 1e-6).ravel())
    if near.size:
        text = f"{{:.{int(decimals)}f}}".format
        flat = out.reshape(-1)
        flat[near] = [float(text(x)) for x in v.reshape(-1)[near].tolist()]
    return out


def linuxcnc_5axis_motion(op: FiveAxisOperation, profile, placement_mm, options: PostOptions | None = None,
                          pole_deg: float = POLE_DEG) -> dict:
    """The motion blocks :func:`linuxcnc_5axis_blocks` writes for ``op`` (same arguments, its defaults),
    as numbers instead of text: what a control reads from them, for the 5-axis guard
    (:mod:`planning.toolpath.fiveaxis.program_moves`). Keys: ``approach_mm`` (3,) and
    ``approach_deg`` (2,): the approach block (``G0`` to the first tip ``safe_z_mm`` up its axis);
    then per posted point ``pos_mm`` (n,3) the printed X Y Z (rounded to ``decimals``: tip in the machine
    frame on a table-table machine, the head's rotation centre on a head-head one), ``angles_deg`` (n,2) the
    printed rotary words in planner signs (:func:`rotary_path` signs, the words times ``rotary_sign``),
    ``kind`` (n,) RAPID / FEED, ``move`` (n,) the planned move it ends, ``home`` (n,) bool: the block
    is preceded by ``G53 G0 Z0`` and the rotary words alone (C turned back at machine Z0)."""
    o = check_options(options)
    p = _profile(profile)
    place = check_placement(placement_mm)
    path, posted, _, _ = _prepare(op, 0, p, place, "linuxcnc", o, None, pole_deg, None, None, True)
    d = int(o.decimals)
    _, pos_a = _approach(path, posted, o)
    return {"approach_mm": _as_printed(pos_a, d), "approach_deg": posted["printed"][0].copy(),
            "pos_mm": _as_printed(posted["pos"], d), "angles_deg": posted["printed"].copy(),
            "kind": path.kind[posted["j"]].copy(), "move": posted["j"].astype(np.int64),
            "home": _home_points(path, posted) & (path.kind[posted["j"]] == RAPID)}


def _check_program_args(operations, profile, placement_mm, options):
    o = check_options(options)
    ops = _ops_list(operations)
    p = _profile(profile)
    place = check_placement(placement_mm)
    return o, ops, p, place


def linuxcnc_5axis_program(operations, *, profile, placement_mm, options: PostOptions | None = None,
                           linearise_tol_mm: float | None = None, linearise: bool = True,
                           pole_deg: float = POLE_DEG, rotary_feed_deg_min: float | None = None,
                           return_figures: bool = False):
    """A whole LinuxCNC program (str) of simultaneous 5-axis operations (module docstring).

    ``operations``: a :class:`FiveAxisOperation` or a list of them, run in order; ``profile``,
    ``placement_mm``, ``options`` and the keywords as :func:`linuxcnc_5axis_blocks` (each operation's
    first point takes the :func:`~planning.orientations.kinematics.choose_rotary` solution).
    ``return_figures``: return ``(text, [figures of each operation])`` instead of the text.
    """
    o, ops, p, place = _check_program_args(operations, profile, placement_mm, options)
    d = int(o.decimals)
    st, sr = (float(v) for v in o.rotary_sign)
    tn, rn = p.axis_names
    table = p.is_table_table
    w = BlockWriter(o)
    w.raw(comment(f"program {int(o.program_number)}"))
    w.raw(comment(f"scanmill {scanmill_version()} - LinuxCNC simultaneous 5-axis post, {p.kinematics}, trivial "
                  f"kinematics: all axes interpolated linearly in joint space"))
    w.raw(comment("units mm, deg, G54 = machine frame: table-top centre on the C axis, rotary axes at 0"))
    w.raw(comment(f"part placement on the table X{fmt(place[0], d)} Y{fmt(place[1], d)} Z{fmt(place[2], d)}"))
    if table:
        w.raw(comment("X Y Z = tool tip in the machine frame, G43 tool length to the tip"))
    else:
        w.raw(comment("X Y Z = head rotation centre in the machine frame, G49: no tool length compensation"))
    w.raw(comment(f"rotary words {tn} {rn} on every block, signs: {tn} {'flipped' if st < 0 else 'as planned'}, "
                  f"{rn} {'flipped' if sr < 0 else 'as planned'}, planned = planning.orientations.kinematics: "
                  f"right-hand rule, the {'table' if table else 'head'} turns, {rn} unwrapped: not wrapped by the "
                  f"control"))
    lim_t, lim_r = _rate_limits(p, rotary_feed_deg_min)
    w.raw(comment(f"feed moves G93 inverse time: F = 1 / move time in min, time = tip path length / feed, at least "
                  f"the {tn} turn / {fmt(lim_t, 1)} deg/min and the {rn} turn / {fmt(lim_r, 1)} deg/min, F rounded "
                  f"down"))
    w.raw(comment(f"the program ends at home: G53 Z0, then G53 {tn}0 {rn}0, machine zero with the rotary axes at 0"))
    w.block("G21", "G90", "G94", "G17", "G40", "G49", "G80")
    w.block("G64", "P" + fmt(o.chord_tol_mm, max(d, 3)))
    w.block("G54")
    figs = []
    for k, op in enumerate(ops):
        figs.append(linuxcnc_5axis_blocks(w, o, op, p, place, None, index=k, linearise_tol_mm=linearise_tol_mm,
                                          linearise=linearise, pole_deg=pole_deg,
                                          rotary_feed_deg_min=rotary_feed_deg_min))
    w.block("G53", "G0", f"{tn}0", f"{rn}0")
    w.block("M30")
    return (w.text(), figs) if return_figures else w.text()


def iso_5axis_blocks(w: BlockWriter, options: PostOptions | None, op: FiveAxisOperation, profile, placement_mm, *,
                     index: int = 0, start_deg=None, linearise_tol_mm: float | None = None, linearise: bool = True,
                     pole_deg: float = POLE_DEG) -> dict:
    """Write one simultaneous operation for an ISO / Fanuc control with ``G43.4`` TCP to ``w``;
    return its figures (as :func:`linuxcnc_5axis_blocks`; ``tip_path_mm`` the programmed tip path).

    X Y Z are tool tips in G54 = the part frame, the rotary words the planner's angles with the
    profile's letters; ``placement_mm`` places the part for the simulated machine (the program does
    not depend on it). Feeds ``G94`` mm/min of the tip. Assumptions: module docstring.
    """
    o = check_options(options)
    p = _profile(profile)
    place = check_placement(placement_mm)
    path, posted, fig, tol = _prepare(op, index, p, place, "iso", o, None, pole_deg, start_deg,
                                      linearise_tol_mm, linearise)
    d = int(o.decimals)
    tn, rn = p.axis_names
    tool = int(op.tool_number)
    tip_a, _ = _approach(path, posted, o)
    limits = _rate_limits(p, None)
    L, _, tip_feed = _feeds(path, posted, tip_a, limits, d, printed_tips=True)
    words = path.words(posted["angles"])
    n_ins = len(posted["j"]) - path.c.shape[0]

    w.raw(_op_comment(index, op, n_ins, tol, upper=True))
    w.block(f"T{tool}", "M6")
    w.block("G53", "G0", f"{tn}{words[0][0]}", f"{rn}{words[0][1]}")
    w.block(spindle_word(op.spindle_rpm), "M3")
    if o.coolant:
        w.block("M8")
    w.block("G0", "G43.4", f"H{tool}", f"X{fmt(tip_a[0], d)}", f"Y{fmt(tip_a[1], d)}", f"Z{fmt(tip_a[2], d)}",
            f"{tn}{words[0][0]}", f"{rn}{words[0][1]}")
    X, Y, Z = (fmt_many(posted["pos"][:, k], d) for k in range(3))
    kinds = path.kind[posted["j"]].tolist()
    feeds = fmt_many(tip_feed, d)
    lines = []
    f_now = None
    home = _home_points(path, posted).tolist()
    for i in range(len(X)):
        if kinds[i] == RAPID and home[i]:
            # C turned back by whole turns: TCP off at Z home, turn, TCP on to the point (as an
            # operation's start)
            w.block("G91", "G28", "Z0.")
            w.block("G90", "G49")
            w.block("G53", "G0", f"{tn}{words[i][0]}", f"{rn}{words[i][1]}")
            head, tail = ("G0", "G43.4", f"H{tool}"), ()
            f_now = None
        elif kinds[i] == RAPID:
            head, tail = ("G0",), ()
        else:
            fw = f"F{feeds[i]}"
            head, tail = ("G1",), (() if fw == f_now else (fw,))
            f_now = fw
        w.block(*head, f"X{X[i]}", f"Y{Y[i]}", f"Z{Z[i]}", f"{tn}{words[i][0]}", f"{rn}{words[i][1]}", *tail)
        lines.append(len(w.lines))
    if o.coolant:
        w.block("M9")
    w.block("G91", "G28", "Z0.")
    w.block("G90", "G49")
    w.block("M5")
    return _figures(path, posted, fig, lines, L, tol, limits)


def iso_5axis_program(operations, *, profile, placement_mm, options: PostOptions | None = None,
                      linearise_tol_mm: float | None = None, linearise: bool = True, pole_deg: float = POLE_DEG,
                      return_figures: bool = False):
    """A whole ISO / Fanuc program (str) of simultaneous 5-axis operations with ``G43.4`` TCP
    (module docstring). Arguments as :func:`linuxcnc_5axis_program` (``rotary_sign`` does not apply)."""
    o, ops, p, place = _check_program_args(operations, profile, placement_mm, options)
    tn, rn = p.axis_names
    w = BlockWriter(o)
    w.raw("%")
    w.raw(f"O{int(o.program_number):04d} " + comment("scanmill simultaneous 5-axis", upper=True))
    head = [f"scanmill {scanmill_version()} - ISO/Fanuc simultaneous 5-axis post, G43.4 tool centre point control, "
            + p.kinematics,
            "units mm, mm/min, G54 = part frame origin" + (", turning with the table" if p.is_table_table else "")]
    head.append(f"X Y Z = tool tip in G54, {tn} {rn} = rotary axes as planned: planning.orientations.kinematics signs, "
                f"the {'table' if p.is_table_table else 'head'} turns")
    head.append("TCP type 1: tip straight, rotary axes linear between blocks, G0 linear interpolation type, no rotary "
                "roll over")
    head.append(f"the program ends at home: Z, then {tn} and {rn} to their reference position [G28], machine zero "
                f"with the rotary axes at 0")
    for line in head:
        w.raw(comment(line, upper=True))
    w.block("G21", "G90", "G94", "G17", "G40", "G49", "G80")
    w.block("G69")
    w.block("G91", "G28", "Z0.")
    w.block("G90")
    w.block("G54")
    figs = []
    for k, op in enumerate(ops):
        figs.append(iso_5axis_blocks(w, o, op, p, place, index=k, linearise_tol_mm=linearise_tol_mm,
                                     linearise=linearise, pole_deg=pole_deg))
    w.block("G91", "G28", f"{tn}0.", f"{rn}0.")
    w.block("G90")
    w.block("M30")
    w.raw("%")
    return (w.text(), figs) if return_figures else w.text()
