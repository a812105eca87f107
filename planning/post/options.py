"""The inputs of the posts and their checks (docs/design.md stage 8, post-processing): the operation record,
the G-code options, and the validation of toolpaths, frames, rotary angles, placement and gauge
lengths (every check raises :class:`~planning.errors.ParameterError` naming the field).

Every post takes the same inputs for one area:

* ``operations``: a list of :class:`Operation` (one :class:`~planning.toolpath.moves.Toolpath` each,
  with its tool, spindle speed and feeds), machined one after the other;
* ``frame``: the area's :class:`~planning.toolpath.frames.AreaFrame` (the toolpaths' frame, +Z = the
  tool axis; part-frame point ``p = frame.to_part(a)``);
* ``tool_axis``: the set-up's tool axis (unit, PART frame, part towards spindle), which must equal
  the frame's +Z (checked to :data:`AXIS_TOL`).

Tool tip
--------
All posts drive the TOOL TIP: for a toolpath point ``xyz`` (area frame) the tip is
``xyz - (0, 0, tip_offset_mm)`` (:meth:`Toolpath.tip_mm`), and an arc's centre is moved the same way.

Feeds
-----
``G0`` for :data:`~planning.toolpath.moves.RAPID` moves; every other move is cut at
``plunge_mm_min`` when its ``use`` is :data:`~planning.toolpath.moves.USE_PLUNGE` and at
``feed_mm_min`` otherwise (cuts, retracts, and feed moves marked as rapids), mm/min, ``G94``
(:func:`feed_for`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from planning.errors import ParameterError
from planning.toolpath.frames import AreaFrame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_XY,
    PLANE_YZ,
    PLANE_ZX,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
)

__all__ = [
    "AXIS_TOL",
    "Operation",
    "PostOptions",
    "check_frame",
    "check_gauge",
    "check_operations",
    "check_options",
    "check_placement",
    "check_rotary",
    "check_toolpath",
    "feed_for",
    "gauge_of",
]

#: A supplied tool axis must match the frame's +Z (and, where checked, the forward kinematics of the
#: rotary angles) within this distance between unit vectors.
AXIS_TOL = 1e-6

_KIND_OK = (RAPID, FEED, ARC_CW, ARC_CCW)
_USE_OK = (USE_RAPID, USE_CUT, USE_PLUNGE, USE_RETRACT)


@dataclass(frozen=True)
class Operation:
    """One operation of an area: a toolpath and how to run it.

    ``name``: e.g. ``"roughing"`` or ``"finishing"`` (printed in comments). ``toolpath``: the moves
    in the area frame (mm). ``tool_number``: T and H number (1..9999). ``tool_diameter_mm``,
    ``tool_type`` (e.g. ``"ball"``, ``"flat"``, ``"bull"``): for the comments and the neutral file.
    ``spindle_rpm``: S, rev/min, clockwise (M3). ``feed_mm_min``: cutting feed, mm/min;
    ``plunge_mm_min``: feed of plunges, ramps and lead-ins (``USE_PLUNGE``), mm/min.
    ``gauge_length_mm``: tool tip to spindle gauge line, mm; needed only where the post outputs the
    head rotation centre (LinuxCNC post, head-head kinematics) and used by the neutral file for the
    controlled point. None: the ``gauge_length_mm`` argument of the post, if any.
    """

    name: str
    toolpath: Toolpath
    tool_number: int
    tool_diameter_mm: float
    tool_type: str
    spindle_rpm: float
    feed_mm_min: float
    plunge_mm_min: float
    gauge_length_mm: float | None = None


@dataclass(frozen=True)
class PostOptions:
    """Options shared by the G-code posts (each post documents the ones it ignores).

    * ``program_number``: ISO ``O`` number (1..99999999); LinuxCNC: printed in a comment only.
    * ``decimals``: places of the coordinates and feeds (0..6, default 4).
    * ``angle_decimals``: places of the angles; None = the post's default (ISO: ``decimals``, since
      the positions are computed in the frame the printed G68.2 angles build; LinuxCNC:
      ``decimals + 4``, so that the printed rotary angles keep an arc's plane on a machine
      principal plane to :data:`~planning.post.arcs.ARC_PLANE_TOL`).
    * ``coolant``: True prints M8 after the spindle start and M9 before it stops.
    * ``line_numbers``: prefix every block (not the comment lines, nor ``%``) with ``N``, starting at
      ``line_number_step`` and going up by it (wrapping after 99999).
    * ``safe_z_mm``: approach / retract height above the area frame's origin along the tool axis, mm
      (> 0; raised to the highest tip of the operation when that is higher).
    * ``chord_tol_mm``: largest distance between a chord and the true arc where an arc is linearised,
      mm (default 0.002): LinuxCNC arcs off the machine's principal planes, and in both posts an arc
      longer than 90 degrees whose start and end coincide after rounding (a G2/G3 would be a full
      circle) and every arc of a radius beyond ``max_arc_radius_mm``; LinuxCNC also gets ``G64 P``
      with it.
    * ``rotary_sign``: LinuxCNC only: ``(tilt_sign, rotary_sign)``, each +1 or -1: the printed A/B
      and C words are these times the planned angles (planning.orientations.kinematics signs); -1 for a control
      that counts that axis the other way.
    * ``max_arc_radius_mm``: largest radius of an arc printed as G2/G3, mm (> 0, default 500): an
      arc whose start or end radius (in its plane) is larger is printed as ``G1`` chords within
      ``chord_tol_mm`` (one ``G1`` to its end where its sagitta is within the tolerance), in both
      posts (a near-straight arc of metres' radius is a straight stretch for the control, and its
      centre and circle lie far off the part).
    """

    program_number: int = 1000
    decimals: int = 4
    angle_decimals: int | None = None
    coolant: bool = True
    line_numbers: bool = False
    line_number_step: int = 10
    safe_z_mm: float = 10.0
    chord_tol_mm: float = 0.002
    rotary_sign: tuple[int, int] = (1, 1)
    max_arc_radius_mm: float = 500.0


def check_options(options: PostOptions | None) -> PostOptions:
    """Validated options (defaults when None); ParameterError naming the field otherwise."""
    o = PostOptions() if options is None else options
    if not isinstance(o, PostOptions):
        raise ParameterError(f"options must be a PostOptions, got {type(o).__name__}", parameter="options")

    def _int(name, lo, hi):
        v = getattr(o, name)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= int(v) <= hi:
            raise ParameterError(f"post option {name} = {v!r}: must be an integer in [{lo}, {hi}]",
                                 parameter=f"post.{name}", value=v, allowed=[lo, hi])

    _int("program_number", 1, 99_999_999)
    _int("decimals", 0, 6)
    if o.angle_decimals is not None:
        _int("angle_decimals", 0, 12)
    _int("line_number_step", 1, 1000)
    for name in ("safe_z_mm", "chord_tol_mm", "max_arc_radius_mm"):
        v = getattr(o, name)
        if not isinstance(v, (int, float, np.floating, np.integer)) or not (math.isfinite(v) and v > 0):
            raise ParameterError(f"post option {name} = {v!r} mm: must be a finite number > 0",
                                 parameter=f"post.{name}", value=v)
    rs = o.rotary_sign
    if not (isinstance(rs, (tuple, list)) and len(rs) == 2 and all(
            not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating)) and v in (1, -1)
            for v in rs)):
        raise ParameterError(f"post option rotary_sign = {rs!r}: must be two signs (tilt, rotary), each 1 or -1",
                             parameter="post.rotary_sign", value=rs, allowed=[1, -1])
    if o.chord_tol_mm < 0.5 * 10.0 ** (-o.decimals):
        raise ParameterError(f"post option chord_tol_mm = {o.chord_tol_mm!r} mm is below the output resolution "
                             f"({10.0 ** (-o.decimals):g} mm at decimals = {o.decimals}); raise it or the decimals",
                             parameter="post.chord_tol_mm", value=o.chord_tol_mm)
    return o


def check_operations(operations: Sequence[Operation], *, allow_empty: bool = False) -> list[Operation]:
    """The operations as a list, each checked (ParameterError naming the operation and the field);
    ``allow_empty``: none is accepted (a program whose only operation is a simultaneous 5-axis one,
    :mod:`planning.post.simultaneous`)."""
    if isinstance(operations, Operation):
        operations = [operations]
    ops = list(operations) if operations is not None else []
    if not ops and not allow_empty:
        raise ParameterError("a post needs at least one operation", parameter="operations")
    for k, op in enumerate(ops):
        where = f"operation {k}"
        if not isinstance(op, Operation):
            raise ParameterError(f"{where}: expected an Operation, got {type(op).__name__}", parameter="operations")
        where = f"operation {k} ({op.name!r})"
        if op.toolpath.axis is not None:
            raise ParameterError(f"{where}: a toolpath with a tool axis per move is simultaneous 5-axis: post it as a "
                                 "planning.post.simultaneous.FiveAxisOperation", parameter="operations")
        if isinstance(op.tool_number, bool) or not isinstance(op.tool_number, (int, np.integer)) \
                or not 1 <= int(op.tool_number) <= 9999:
            raise ParameterError(f"{where}: tool_number = {op.tool_number!r}: must be an integer in [1, 9999]",
                                 parameter="tool_number", value=op.tool_number)
        for name in ("tool_diameter_mm", "spindle_rpm", "feed_mm_min", "plunge_mm_min"):
            v = getattr(op, name)
            if not isinstance(v, (int, float, np.integer, np.floating)) or isinstance(v, bool) \
                    or not (math.isfinite(v) and v > 0):
                raise ParameterError(f"{where}: {name} = {v!r}: must be a finite number > 0", parameter=name, value=v)
        if op.gauge_length_mm is not None:
            g = op.gauge_length_mm
            if not isinstance(g, (int, float, np.integer, np.floating)) or not (math.isfinite(g) and g > 0):
                raise ParameterError(f"{where}: gauge_length_mm = {g!r}: must be a finite number > 0 mm",
                                     parameter="gauge_length_mm", value=g)
        check_toolpath(op.toolpath, where)
    return ops


def check_gauge(gauge_length_mm) -> float | None:
    """A program-level tool gauge length (mm, > 0) or None."""
    if gauge_length_mm is None:
        return None
    g = gauge_length_mm
    if isinstance(g, bool) or not isinstance(g, (int, float, np.integer, np.floating)) or not (math.isfinite(g) and g > 0):
        raise ParameterError(f"gauge_length_mm = {g!r}: must be a finite number > 0 mm", parameter="gauge_length_mm",
                             value=g)
    return float(g)


def gauge_of(op: Operation, default: float | None) -> float | None:
    """The operation's own gauge length, else the program-level one (mm), else None."""
    return float(op.gauge_length_mm) if op.gauge_length_mm is not None else default


def check_toolpath(tp: Toolpath, where: str = "toolpath") -> None:
    """A toolpath the posts can print: at least one move, finite points, known kinds, uses and arc
    planes, finite centres on arcs, no arc as move 0 (it has no start point)."""
    if not isinstance(tp, Toolpath):
        raise ParameterError(f"{where}: toolpath must be a Toolpath, got {type(tp).__name__}", parameter="toolpath")
    if tp.n_moves == 0:
        raise ParameterError(f"{where}: the toolpath has no moves", parameter="toolpath")
    if not np.all(np.isfinite(tp.xyz_mm)) or not math.isfinite(tp.tip_offset_mm):
        raise ParameterError(f"{where}: the toolpath has NaN or infinite points", parameter="toolpath")
    bad = ~np.isin(tp.kind, _KIND_OK)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ParameterError(f"{where}: move {i} has an unknown kind {int(tp.kind[i])}", parameter="toolpath")
    bad = ~np.isin(tp.use, _USE_OK)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ParameterError(f"{where}: move {i} has an unknown use {int(tp.use[i])}", parameter="toolpath")
    arc = np.isin(tp.kind, (ARC_CW, ARC_CCW))
    if arc[0]:
        raise ParameterError(f"{where}: move 0 is an arc; the first move must be a straight move to the start",
                             parameter="toolpath")
    if arc.any():
        if not np.all(np.isin(tp.plane[arc], (PLANE_XY, PLANE_ZX, PLANE_YZ))):
            i = int(np.flatnonzero(arc & ~np.isin(tp.plane, (PLANE_XY, PLANE_ZX, PLANE_YZ)))[0])
            raise ParameterError(f"{where}: arc move {i} has plane {int(tp.plane[i])}; expected 17, 18 or 19",
                                 parameter="toolpath")
        if not np.all(np.isfinite(tp.centre_mm[arc])):
            i = int(np.flatnonzero(arc & ~np.all(np.isfinite(tp.centre_mm), axis=1))[0])
            raise ParameterError(f"{where}: arc move {i} has no finite centre", parameter="toolpath")


def check_frame(frame: AreaFrame, tool_axis) -> np.ndarray:
    """The unit tool axis, after checking that ``frame`` is a proper rotation whose +Z is it."""
    if not isinstance(frame, AreaFrame):
        raise ParameterError(f"frame must be an AreaFrame, got {type(frame).__name__}", parameter="frame")
    R = np.asarray(frame.rotation, dtype=np.float64)
    o = np.asarray(frame.origin_mm, dtype=np.float64)
    if R.shape != (3, 3) or o.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(o))):
        raise ParameterError("frame: rotation must be finite (3,3) and origin_mm finite (3,)", parameter="frame")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-9 or np.linalg.det(R) < 0:
        raise ParameterError("frame.rotation is not a proper rotation (orthonormal rows, right-handed)",
                             parameter="frame")
    t = np.asarray(tool_axis, dtype=np.float64).reshape(-1)
    if t.shape != (3,) or not np.all(np.isfinite(t)) or np.linalg.norm(t) < 1e-12:
        raise ParameterError(f"tool_axis = {tool_axis!r}: must be 3 finite numbers, not all zero",
                             parameter="tool_axis")
    t = t / np.linalg.norm(t)
    dev = float(np.linalg.norm(R[2] - t))
    if dev > AXIS_TOL:
        raise ParameterError(f"the area frame's +Z {np.round(R[2], 6).tolist()} is not the tool axis "
                             f"{np.round(t, 6).tolist()} (deviation {dev:.3g}); the toolpaths must be in the "
                             f"frame of this set-up", parameter="tool_axis")
    return t


def check_rotary(rotary_deg, tool_axis: np.ndarray, profile) -> np.ndarray:
    """(tilt_deg, rotary_deg) as (2,) float, checked against the tool axis by the profile's forward
    kinematics (:func:`planning.orientations.kinematics.tool_axis_from_angles`)."""
    from planning.orientations.kinematics import tool_axis_from_angles

    a = np.asarray(rotary_deg, dtype=np.float64).reshape(-1)
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ParameterError(f"rotary_deg = {rotary_deg!r}: must be (tilt_deg, rotary_deg), two finite numbers",
                             parameter="rotary_deg")
    t = tool_axis_from_angles(a, profile)[0]
    dev = float(np.linalg.norm(t - tool_axis))
    if dev > AXIS_TOL:
        raise ParameterError(f"rotary_deg = {a.tolist()} gives the tool axis {np.round(t, 6).tolist()} on this "
                             f"machine, not {np.round(tool_axis, 6).tolist()} (deviation {dev:.3g}); pass the "
                             f"angles machine_visibility chose for this axis", parameter="rotary_deg")
    return a


def check_placement(placement_mm) -> np.ndarray:
    p = np.asarray(placement_mm, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ParameterError(f"placement_mm = {placement_mm!r}: must be 3 finite numbers (mm)",
                             parameter="placement_mm")
    return p


def feed_for(op: Operation, use: int) -> float:
    """Feed of a non-rapid move, mm/min (see the module docstring)."""
    return float(op.plunge_mm_min if int(use) == USE_PLUNGE else op.feed_mm_min)
