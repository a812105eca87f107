"""What the post-processors share: the operation record, the options, validation, number formatting,
the block writer, the motion emitter and arc linearisation (DESIGN step 8).

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
``feed_mm_min`` otherwise (cuts, retracts, and feed moves marked as rapids), mm/min, ``G94``.

Approach and retract (safe height)
----------------------------------
Each operation starts with one rapid to the point straight above the path's first point at the
safe height ``z_safe = max(safe_z_mm, highest tip z of the operation)`` (area frame, mm; the frame's
origin lies at the top of the whole cloud along the tool axis, so ``safe_z_mm > 0`` clears the
part), then follows the path (its move 0 comes down from there). It ends with a rapid straight up
along the tool axis to ``z_safe``. Before the first plunge no rapid is therefore below the path's
own first point.

Numbers
-------
Coordinates are printed with ``decimals`` places (default 4, i.e. 0.1 micrometre), always with a
decimal point (``X10.`` — on a Fanuc without decimal-point programming ``X10`` would mean 10
micrometres), without trailing zeros and never as ``-0.``. A coordinate word is printed only when
its rounded value changes (modal); the first move of every operation prints X, Y and Z. Arc centre
offsets ``I J K`` are measured from the ROUNDED start point as printed, so the centre the control
computes is the planned one to within the rounding of the offsets.

Speed
-----
:func:`emit_motion` prints an operation's motion blocks with whole-array numpy work: program
coordinates of every move, rounding to the printed digits (exact: rounding ties go to Python's own
formatting), modal words by array comparisons of the rounded values, arcs that degenerate after
rounding, chords of linearised arcs, and the text itself (a character matrix per batch of blocks).
The text is byte for byte what the per-move :class:`MotionEmitter` prints; MotionEmitter stays as
the reference the tests compare with, and prints the rare operation with coordinates beyond the
whole-array formatter's range (2^51 output steps, about 2e11 mm at 4 decimals). Where numpy's
functions may differ from the math module's in the last bit (np.hypot, np.arctan2) and that could
change a printed digit or a decision, the scalar code decides.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from planning.errors import ParameterError
from planning.toolpath.frames import AreaFrame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    PLANE_XY,
    PLANE_YZ,
    PLANE_ZX,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
    arc_sweep_rad,
)

__all__ = [
    "ARC_PLANE_TOL",
    "AXIS_TOL",
    "Operation",
    "PostOptions",
    "scanmill_version",
]

#: A supplied tool axis must match the frame's +Z (and, where checked, the forward kinematics of the
#: rotary angles) within this distance between unit vectors.
AXIS_TOL = 1e-6

#: An arc is emitted as G2/G3 only when its plane's normal, mapped into the program frame, lies
#: within this distance (per component, unit vector) of a principal axis.
ARC_PLANE_TOL = 1e-9

#: Letters of the arc-centre offsets by program axis (X, Y, Z).
_OFFSET_LETTERS = ("I", "J", "K")

_KIND_OK = (RAPID, FEED, ARC_CW, ARC_CCW)
_USE_OK = (USE_RAPID, USE_CUT, USE_PLUNGE, USE_RETRACT)

#: In-plane axes (first, second) and normal axis of each arc plane code, as arrays indexed by the
#: code (PLANE_AXES as lookup tables for whole arrays of planes).
_AX_A, _AX_B, _AX_N = (np.zeros(PLANE_YZ + 1, dtype=np.int64) for _ in range(3))
for _p, (_a, _b, _n) in PLANE_AXES.items():
    _AX_A[_p], _AX_B[_p], _AX_N[_p] = _a, _b, _n
del _p, _a, _b, _n


def scanmill_version() -> str:
    """The installed scanmill version (``scanmill.__version__``)."""
    import scanmill

    return str(scanmill.__version__)


# ----------------------------------------------------------------------------------------------
# inputs


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
      principal plane to :data:`ARC_PLANE_TOL`).
    * ``coolant``: True prints M8 after the spindle start and M9 before it stops.
    * ``line_numbers``: prefix every block (not the comment lines, nor ``%``) with ``N``, starting at
      ``line_number_step`` and going up by it (wrapping after 99999).
    * ``safe_z_mm``: approach / retract height above the area frame's origin along the tool axis, mm
      (> 0; raised to the highest tip of the operation when that is higher).
    * ``chord_tol_mm``: largest distance between a chord and the true arc where an arc is linearised,
      mm (default 0.002): LinuxCNC arcs off the machine's principal planes, and in both posts an arc
      longer than 90 degrees whose start and end coincide after rounding (a G2/G3 would be a full
      circle); LinuxCNC also gets ``G64 P`` with it.
    * ``rotary_sign``: LinuxCNC only: ``(tilt_sign, rotary_sign)``, each +1 or -1: the printed A/B
      and C words are these times the planned angles (planning.orientations.kinematics signs); -1 for a control
      that counts that axis the other way.
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
    for name in ("safe_z_mm", "chord_tol_mm"):
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


def check_operations(operations: Sequence[Operation]) -> list[Operation]:
    """The operations as a list, each checked (ParameterError naming the operation and the field)."""
    if isinstance(operations, Operation):
        operations = [operations]
    ops = list(operations) if operations is not None else []
    if not ops:
        raise ParameterError("a post needs at least one operation", parameter="operations")
    for k, op in enumerate(ops):
        where = f"operation {k}"
        if not isinstance(op, Operation):
            raise ParameterError(f"{where}: expected an Operation, got {type(op).__name__}", parameter="operations")
        where = f"operation {k} ({op.name!r})"
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


# ----------------------------------------------------------------------------------------------
# formatting


def fmt(value: float, decimals: int) -> str:
    """``value`` rounded to ``decimals`` places with a decimal point and no trailing zeros:
    ``10.``, ``-0.5``, ``0.`` (never ``-0.``)."""
    s = f"{float(value):.{decimals}f}"
    if "." not in s:
        s += "."
    s = s.rstrip("0")
    if s.startswith("-") and float(s) == 0.0:
        s = s[1:]
    if s.startswith("."):
        s = "0" + s
    elif s.startswith("-."):
        s = "-0" + s[1:]
    return s


def rounded(value: float, decimals: int) -> float:
    """The value a control reads from ``fmt(value, decimals)``."""
    return float(fmt(value, decimals))


_COMMENT_BAD = re.compile(r"[^A-Za-z0-9 .,:=+\-_/*#<>\[\]]")


def comment(text: str, *, upper: bool = False) -> str:
    """``(text)`` with parentheses and unusual characters replaced by spaces (no nesting)."""
    s = _COMMENT_BAD.sub(" ", str(text))
    s = re.sub(r"\s+", " ", s).strip()
    return f"({s.upper() if upper else s})"


class BlockWriter:
    """Collects program lines; numbers the blocks (not comments, not ``%``) when asked."""

    def __init__(self, options: PostOptions):
        self.lines: list[str] = []
        self.numbered = options.line_numbers
        self.step = int(options.line_number_step)
        self.n = 0

    def raw(self, text: str) -> None:
        self.lines.append(text)

    def block(self, *words: str) -> None:
        words = [w for w in words if w]
        if not words:
            return
        if self.numbered:
            self.n += self.step
            if self.n > 99999:
                self.n = self.step
            words = [f"N{self.n}"] + words
        self.lines.append(" ".join(words))

    def take_numbers(self, count: int) -> np.ndarray:
        """The ``N`` numbers (int64, (count,)) of the next ``count`` blocks, as :meth:`block` would give
        them one by one (the writer moves on past them)."""
        period = 99999 // self.step                      # blocks before the numbers wrap
        k = self.n // self.step + np.arange(count, dtype=np.int64)
        out = (k % period + 1) * self.step
        if count:
            self.n = int(out[-1])
        return out

    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


# ----------------------------------------------------------------------------------------------
# geometry


def feed_for(op: Operation, use: int) -> float:
    """Feed of a non-rapid move, mm/min (see the module docstring)."""
    return float(op.plunge_mm_min if int(use) == USE_PLUNGE else op.feed_mm_min)


def safe_height_mm(op: Operation, options: PostOptions) -> float:
    """Approach / retract height in the area frame, mm: ``max(safe_z_mm, highest tip z)``, where an
    arc in G18 / G19 counts the top of its circle (it may bulge above its end points)."""
    tp = op.toolpath
    top = float(tp.tip_mm()[:, 2].max())
    arcs = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)) & (tp.plane != PLANE_XY))
    if arcs.size:
        # circle top = centre z + the larger of the start and end radii; np.hypot may differ from
        # math.hypot in the last bit, so the candidates for the highest are settled with math.hypot
        a, b = _AX_A[tp.plane[arcs]], _AX_B[tp.plane[arcs]]
        c = tp.centre_mm[arcs]
        rows = np.arange(arcs.size)
        d = [(tp.xyz_mm[j, a] - c[rows, a], tp.xyz_mm[j, b] - c[rows, b]) for j in (arcs - 1, arcs)]
        val = (c[:, 2] - tp.tip_offset_mm) + np.maximum(np.hypot(*d[0]), np.hypot(*d[1]))
        best = float(val.max())
        for k in np.flatnonzero(val >= best - 1e-9 * (abs(best) + 1.0)):
            r = max(math.hypot(du[k], dv[k]) for du, dv in d)
            top = max(top, float(c[k, 2] - tp.tip_offset_mm + r))
    return max(float(options.safe_z_mm), top)


def _reference_safe_height_mm(op: Operation, options: PostOptions) -> float:
    """:func:`safe_height_mm` one arc at a time (the tests' reference)."""
    tp = op.toolpath
    top = float(tp.tip_mm()[:, 2].max())
    for i in np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)) & (tp.plane != PLANE_XY)):
        a, b, _ = PLANE_AXES[int(tp.plane[i])]
        c = tp.centre_mm[i]
        r = max(math.hypot(*(tp.xyz_mm[j, [a, b]] - c[[a, b]])) for j in (i - 1, i))
        top = max(top, float(c[2] - tp.tip_offset_mm + r))
    return max(float(options.safe_z_mm), top)


def arc_chord_points(start, end, centre, plane: int, ccw: bool, chord_tol_mm: float) -> np.ndarray:
    """Points (n,3) after ``start`` along an arc (area frame, mm), the last one ``end``, such that no
    chord between consecutive points strays more than ``chord_tol_mm`` from the arc.

    Points are at equal angle steps ``|sweep| / n`` with ``n = ceil(|sweep| / dmax)``,
    ``dmax = 2 acos(1 - chord_tol / r)`` (the angle whose chord has the sagitta ``chord_tol``), capped
    at 90 degrees; the radius and the coordinate along the plane's normal vary linearly with the
    angle from start to end (helices; start and end radii that differ by the fitting tolerance),
    the same parametrisation as :func:`planning.toolpath.moves.densify`. Every point lies on the
    arc; for a helix the in-plane sagitta bounds the chord error as well."""
    s, e, c = (np.asarray(v, dtype=np.float64) for v in (start, end, centre))
    a, b, n = PLANE_AXES[int(plane)]
    t0, sw, r0, r1, m = _chord_params(s, e, c, plane, ccw, chord_tol_mm)
    t = np.arange(1, m + 1) / m
    q = np.empty((m, 3))
    rr = r0 + (r1 - r0) * t
    q[:, a] = c[a] + rr * np.cos(t0 + sw * t)
    q[:, b] = c[b] + rr * np.sin(t0 + sw * t)
    q[:, n] = s[n] + (e[n] - s[n]) * t
    q[-1] = e
    return q


def _chord_params(s: np.ndarray, e: np.ndarray, c: np.ndarray, plane: int, ccw: bool,
                  chord_tol_mm: float) -> tuple[float, float, float, float, int]:
    """``(start angle, signed sweep, start radius, end radius, number of chords)`` of
    :func:`arc_chord_points` for one arc (start, end, centre (3,) float64)."""
    a, b, _ = PLANE_AXES[int(plane)]
    t0, sw, r0 = arc_sweep_rad(s, e, c, plane, ccw)
    r1 = math.hypot(e[a] - c[a], e[b] - c[b])
    r = max(r0, r1)
    if r <= chord_tol_mm:
        dmax = math.pi / 2
    else:
        dmax = min(2.0 * math.acos(1.0 - chord_tol_mm / r), math.pi / 2)
    m = max(1, math.ceil(abs(sw) / dmax - 1e-12))
    return t0, sw, r0, r1, m


def principal_plane(normal: np.ndarray, tol: float = ARC_PLANE_TOL) -> tuple[int, int] | None:
    """``(plane code, sign)`` when the unit vector ``normal`` is ``sign`` times a principal axis
    (Z -> 17, Y -> 18, X -> 19) within ``tol`` per component, else None."""
    for idx, plane in ((2, PLANE_XY), (1, PLANE_ZX), (0, PLANE_YZ)):
        for sign in (1, -1):
            target = np.zeros(3)
            target[idx] = sign
            if np.abs(normal - target).max() <= tol:
                return plane, sign
    return None


@dataclass
class MotionState:
    """Modal state of one operation's motion blocks (reset at each operation)."""

    motion: str | None = None
    plane: int = PLANE_XY
    feed: str | None = None
    pos: list = field(default_factory=lambda: [None, None, None])     # printed X Y Z strings


class MotionEmitter:
    """Prints one operation's moves in a program frame ``X = A a + b`` (``a``: tip point in the area
    frame, mm; ``A`` a rotation, ``b`` mm).

    ``arc_mode``: ``"frame"`` keeps each arc in its area-frame plane (ISO tilted plane, where the
    program frame is the area frame up to the rounding of the G68.2 words); ``"principal"`` maps the
    plane's normal by ``A`` and prints G2/G3 only when it lies on a principal axis within
    :data:`ARC_PLANE_TOL` (the direction flips when it maps onto a negative axis), linearising the
    arc within ``chord_tol_mm`` otherwise (LinuxCNC).

    One move at a time: the posts print through :func:`emit_motion`, which gives this class's text
    with whole arrays; this class is its reference and its fallback for huge coordinates.
    """

    def __init__(self, writer: BlockWriter, options: PostOptions, A: np.ndarray, b: np.ndarray, arc_mode: str):
        self.w = writer
        self.o = options
        self.d = int(options.decimals)
        self.A = np.asarray(A, dtype=np.float64)
        self.b = np.asarray(b, dtype=np.float64)
        self.arc_mode = arc_mode
        self.state = MotionState()
        self.n_linearised = 0
        self.n_arcs = 0

    def to_prog(self, a) -> np.ndarray:
        return np.asarray(a, dtype=np.float64) @ self.A.T + self.b

    def _printed_pos(self) -> np.ndarray:
        return np.array([float(v) if v is not None else np.nan for v in self.state.pos])

    def _words_xyz(self, X: np.ndarray, force: bool = False) -> list[str]:
        out = []
        for k, letter in enumerate("XYZ"):
            s = fmt(X[k], self.d)
            if force or self.state.pos[k] != s:
                out.append(letter + s)
                self.state.pos[k] = s
        return out

    def _motion(self, g: str) -> str:
        if self.state.motion == g:
            return ""
        self.state.motion = g
        return g

    def _feed(self, f: float) -> str:
        s = fmt(f, min(self.d, 3))
        if self.state.feed == s:
            return ""
        self.state.feed = s
        return "F" + s

    def _plane(self, plane: int) -> str:
        if self.state.plane == plane:
            return ""
        self.state.plane = plane
        return f"G{plane}"

    def rapid(self, a, *, prefix: Sequence[str] = (), force: bool = False) -> None:
        X = self.to_prog(a)
        words = self._words_xyz(X, force)
        if words or prefix:
            self.w.block(self._motion("G0"), *prefix, *words)

    def line(self, a, feed: float) -> None:
        X = self.to_prog(a)
        words = self._words_xyz(X)
        if words:
            self.w.block(self._motion("G1"), *words, self._feed(feed))

    def arc(self, start_a, end_a, centre_a, plane: int, ccw: bool, feed: float) -> None:
        self.n_arcs += 1
        if self.arc_mode == "frame":
            pp = (int(plane), 1)
        else:
            n_area = np.zeros(3)
            n_area[PLANE_AXES[int(plane)][2]] = 1.0
            pp = principal_plane(self.A @ n_area)
        if pp is None:
            self._linearise(start_a, end_a, centre_a, plane, ccw, feed)
            return
        out_plane, sign = pp
        out_ccw = ccw if sign > 0 else not ccw
        S = self._printed_pos()
        E = self.to_prog(end_a)
        C = self.to_prog(centre_a)
        ia, ib, _ = PLANE_AXES[out_plane]
        Er = np.array([rounded(v, self.d) for v in E])
        chord = math.hypot(Er[ia] - S[ia], Er[ib] - S[ib])
        radius = math.hypot(C[ia] - S[ia], C[ib] - S[ib])
        res = 10.0 ** (-self.d)
        if chord < 2 * res or radius < 2 * res:
            # start and end coincide in the plane after rounding (a G2/G3 would be a full circle), or
            # a radius at the output resolution: short arcs become chords, long ones are linearised
            _, sw, _ = arc_sweep_rad(np.asarray(start_a), np.asarray(end_a), np.asarray(centre_a), plane, ccw)
            if abs(sw) > math.pi / 2 and radius >= 2 * res:
                self._linearise(start_a, end_a, centre_a, plane, ccw, feed)
            else:
                self.line(end_a, feed)
            return
        words = self._words_xyz(E)
        offs = []
        for k in (ia, ib):
            offs.append(_OFFSET_LETTERS[k] + fmt(C[k] - S[k], self.d))
        offs.sort(key=lambda w: "IJK".index(w[0]))
        g = "G3" if out_ccw else "G2"
        self.w.block(self._plane(out_plane), self._motion(g), *words, *offs, self._feed(feed))

    def _linearise(self, start_a, end_a, centre_a, plane, ccw, feed) -> None:
        self.n_linearised += 1
        for q in arc_chord_points(start_a, end_a, centre_a, plane, ccw, float(self.o.chord_tol_mm)):
            self.line(q, feed)

    def run(self, op: Operation, z_safe: float, *, approach_prefix: Sequence[str] = ()) -> None:
        """Approach at the safe height, every move of the operation, retract to the safe height."""
        tp = op.toolpath
        tip = tp.tip_mm()
        centre = tp.centre_mm - np.array([0.0, 0.0, tp.tip_offset_mm])
        first = tip[0]
        self.rapid([first[0], first[1], z_safe], prefix=approach_prefix, force=True)
        for i in range(tp.n_moves):
            k = int(tp.kind[i])
            if k == RAPID:
                self.rapid(tip[i])
            elif k == FEED:
                self.line(tip[i], feed_for(op, tp.use[i]))
            else:
                self.arc(tip[i - 1], tip[i], centre[i], int(tp.plane[i]), k == ARC_CCW, feed_for(op, tp.use[i]))
        last = tip[-1]
        self.rapid([last[0], last[1], z_safe])
        if self.state.plane != PLANE_XY:
            self.w.block(self._plane(PLANE_XY))


# ----------------------------------------------------------------------------------------------
# the motion blocks of a whole operation at once

#: True: :func:`emit_motion` prints every operation with the per-move :class:`MotionEmitter`, the
#: reference that its whole-array path reproduces byte for byte (the tests switch it on to compare).
_REFERENCE_MOTION = False

#: Largest ``|value| * 10^decimals`` the whole-array formatter takes (integers far inside what
#: float64 and int64 hold exactly); an operation with a larger coordinate goes through MotionEmitter.
_Q_MAX = 2.0 ** 51

#: Blocks whose text is built at once (bounds the temporary character matrices).
_CHUNK_ROWS = 1 << 16

_MOTION_WORDS = ("G0", "G1", "G2", "G3")
_PLANE_WORDS = ("G17", "G18", "G19")


def emit_motion(writer: BlockWriter, options: PostOptions, A: np.ndarray, b: np.ndarray, arc_mode: str,
                op: Operation, z_safe: float, *, approach_prefix: Sequence[str] = ()) -> None:
    """One operation's motion blocks, byte for byte what ``MotionEmitter(writer, options, A, b,
    arc_mode).run(op, z_safe, approach_prefix=approach_prefix)`` prints (see :class:`MotionEmitter`),
    computed for all moves at once: program coordinates, rounding, modal words, degenerate arcs,
    chords of linearised arcs and the text. Operations with coordinates beyond ``2^51`` output
    steps (about 2e11 mm at 4 decimals) go through MotionEmitter itself."""
    if _REFERENCE_MOTION or not _bulk_motion(writer, options, A, b, arc_mode, op, z_safe, tuple(approach_prefix)):
        MotionEmitter(writer, options, A, b, arc_mode).run(op, z_safe, approach_prefix=approach_prefix)


def _quantise(values, decimals: int) -> np.ndarray | None:
    """The integers ``q`` (int64, the shape of ``values``) whose digits :func:`fmt` prints:
    ``v * 10^decimals`` rounded half to even on the exact binary value of ``v``, as Python's
    ``f"{v:.{decimals}f}"`` (``float(fmt(v, d)) == q / 10^d`` exactly). None when some
    ``|v| * 10^decimals >= _Q_MAX``.

    The float product is off the exact one by at most ``|p| 2^-53``; where that could move it across
    a half-way point (exact ties included), Python's formatting decides."""
    v = np.asarray(values, dtype=np.float64)
    p = v * float(10 ** decimals)
    a = np.abs(p)
    if a.size and not a.max() < _Q_MAX:
        return None
    q = np.rint(p).astype(np.int64)
    for i in np.flatnonzero(np.abs(a - np.floor(a) - 0.5) <= a * 2.0 ** -52):
        q.flat[i] = int(f"{float(v.flat[i]):.{decimals}f}".replace(".", ""))
    return q


def _digits(q: np.ndarray, decimals: int, point: bool = True, repr_style: bool = False) -> list[tuple]:
    """The characters of ``fmt(q[i] / 10^decimals, decimals)`` for every i (``point=False``: the
    digits of the integers ``q >= 0``; ``repr_style``: Python's ``repr`` of the float
    ``q[i] / 10^decimals`` where that is positional: one digit after the point at least, ``10.0``,
    ``0.5``) as columns, left to right: ``(chars, keep)`` pairs, ``chars`` a (n,) uint8 array or one
    character code for all rows, ``keep`` (n,) bool (the row has it)."""
    n = q.shape[0]
    a = np.abs(q)
    top = int(a.max()) if n else 0
    nd = len(str(top // 10 ** decimals))                  # digits before the point
    rest = a.astype(np.uint32) if top < 2 ** 32 else a    # (uint32 divides several times faster)
    digit = {}
    frac_keep = {}
    nonzero = np.zeros(n, dtype=bool)
    for j in range(nd + decimals - 1, -1, -1):            # digit by digit from the right
        if j == nd - 1:
            ip = rest                                     # the integer part
        higher = rest // 10
        digit[j] = (rest - higher * 10).astype(np.uint8) + np.uint8(ord("0"))
        if j >= nd:                                       # no trailing zeros after the point
            nonzero = nonzero | (digit[j] != ord("0"))
            frac_keep[j] = nonzero
        rest = higher
    everyone = np.ones(n, dtype=bool)
    cols = [(ord("-"), q < 0)]
    cols += [(digit[j], ip >= 10 ** (nd - 1 - j)) for j in range(nd - 1)]      # no leading zeros
    cols.append((digit[nd - 1], everyone))
    if point:
        cols.append((ord("."), everyone))
    if repr_style:
        if decimals:
            frac_keep[nd] = everyone
        else:
            cols.append((ord("0"), everyone))
    cols += [(digit[j], frac_keep[j]) for j in range(nd, nd + decimals)]
    return cols


class _Rows:
    """The text of many rows at once (blocks of a program, items of a JSON list): words added left
    to right, each present or not in each row, joined by ``sep`` (where ``glue``), each row ended by
    ``end``. Every character position is a column (characters (n,) or one for all, kept (n,)
    bool); :meth:`text` lays them out row by row."""

    def __init__(self, n: int, sep: str = " ", end: str = "\n"):
        self.n = n
        self.sep, self.end = ord(sep), ord(end)
        self.cols: list[tuple] = []
        self.seen = np.zeros(n, dtype=bool)

    def _word(self, cols: list[tuple], present: np.ndarray, glue: bool = True) -> None:
        if glue:
            self.cols.append((self.sep, present & self.seen))
        self.cols += [(c, k & present) for c, k in cols]
        self.seen = self.seen | present

    def const(self, text: str, present: np.ndarray, glue: bool = True) -> None:
        """Word ``text`` in the rows where ``present``."""
        self._word([(ord(ch), present) for ch in text], present, glue)

    def table(self, idx: np.ndarray, words: Sequence[str], present: np.ndarray, glue: bool = True) -> None:
        """Word ``words[idx[i]]`` in row i where ``present[i]``."""
        if not present.any():
            return
        width = max(len(w) for w in words)
        tab = np.array([w.encode("ascii") for w in words], dtype=f"S{width}").view(np.uint8).reshape(-1, width)
        cols = []
        for j in range(width):
            c = tab[:, j]
            if np.all(c == c[0]):
                cols.append((int(c[0]), present))
            else:
                cols.append((c[idx], c[idx] != 0))
        self._word(cols, present, glue)

    def number(self, letter: str, q: np.ndarray, decimals: int, present: np.ndarray, point: bool = True,
               repr_style: bool = False, glue: bool = True) -> None:
        """Word ``letter + fmt(q[i] / 10^decimals, decimals)`` (see :func:`_digits` for ``point`` and
        ``repr_style``) in row i where ``present[i]``."""
        if not present.any():
            return
        lead = [(ord(letter), present)] if letter else []
        self._word(lead + _digits(q, decimals, point, repr_style), present, glue)

    def raw(self, rows: np.ndarray, texts: Sequence[str], glue: bool = True) -> None:
        """Word ``texts[j]`` in row ``rows[j]`` (ASCII)."""
        if not len(rows):
            return
        present = np.zeros(self.n, dtype=bool)
        present[rows] = True
        width = max(len(t) for t in texts)
        tab = np.zeros((self.n, width), dtype=np.uint8)
        tab[rows] = np.array([t.encode("ascii") for t in texts], dtype=f"S{width}").view(np.uint8).reshape(-1, width)
        self._word([(tab[:, j], tab[:, j] != 0) for j in range(width)], present, glue)

    def text(self) -> str:
        """The rows with a word, each ended by ``end``."""
        cols = self.cols + [(self.end, self.seen)]
        chars = np.empty((self.n, len(cols)), dtype=np.uint8)
        keep = np.empty((self.n, len(cols)), dtype=bool)
        for j, (c, k) in enumerate(cols):
            chars[:, j] = c
            keep[:, j] = k
        return chars[keep].tobytes().decode("ascii")


def _hypot_settled(u: np.ndarray, v: np.ndarray, ref: float) -> np.ndarray:
    """``hypot(u, v)`` per element, with ``math.hypot`` (whose last bit np.hypot may not match)
    wherever the value lies near ``ref``, so that comparisons with ``ref`` come out as
    MotionEmitter's."""
    h = np.hypot(u, v)
    for j in np.flatnonzero(np.abs(h - ref) <= 1e-9 * ref):
        h[j] = math.hypot(u[j], v[j])
    return h


def _chord_points(s: np.ndarray, e: np.ndarray, c: np.ndarray, plane: np.ndarray, ccw: np.ndarray,
                  chord_tol_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`arc_chord_points` of k arcs at once (start, end, centre (k,3), plane codes, ccw flags):
    ``(points (sum m, 3), m (k,), slack (k,))``, the points of arc j after those of arc j - 1.

    The counts ``m`` are exactly the scalar code's (arcs whose sweep lies near 0 or 360 degrees,
    whose radius is near the tolerance or whose count lies near a step of the ceiling take
    :func:`_chord_params`); the points may differ from :func:`arc_chord_points` by the last bits of
    np.arctan2 / np.hypot against math's, at most ``slack`` mm (a generous bound)."""
    k = s.shape[0]
    rows = np.arange(k)
    a, b, nn = _AX_A[plane], _AX_B[plane], _AX_N[plane]
    ca, cb = c[rows, a], c[rows, b]
    u0, v0 = s[rows, a] - ca, s[rows, b] - cb
    u1, v1 = e[rows, a] - ca, e[rows, b] - cb
    t0 = np.arctan2(v0, u0)
    t1 = np.arctan2(v1, u1)
    two_pi = 2 * math.pi
    sw = np.where(ccw, np.mod(t1 - t0, two_pi), -np.mod(t0 - t1, two_pi))
    zero = sw == 0.0
    sw[zero] = np.where(ccw[zero], two_pi, -two_pi)
    r0 = np.hypot(u0, v0)
    r1 = np.hypot(u1, v1)
    r = np.maximum(r0, r1)
    dmax = np.full(k, math.pi / 2)
    big = r > chord_tol_mm
    dmax[big] = np.minimum(2.0 * np.arccos(1.0 - chord_tol_mm / r[big]), math.pi / 2)
    x = np.abs(sw) / dmax - 1e-12
    m = np.maximum(1, np.ceil(x)).astype(np.int64)
    risky = ((np.minimum(np.abs(sw), two_pi - np.abs(sw)) < 1e-9) | (np.abs(r - chord_tol_mm) <= 1e-9 * chord_tol_mm)
             | ((x > 0.5) & (np.abs(x - np.rint(x)) < 1e-9)))
    for j in np.flatnonzero(risky):
        t0[j], sw[j], r0[j], r1[j], m[j] = _chord_params(s[j], e[j], c[j], int(plane[j]), bool(ccw[j]), chord_tol_mm)
    total = int(m.sum())
    arc_of = np.repeat(rows, m)
    first = np.cumsum(m) - m
    t = (np.arange(total, dtype=np.int64) - first[arc_of] + 1) / m[arc_of]
    rr = r0[arc_of] + (r1 - r0)[arc_of] * t
    ang = t0[arc_of] + sw[arc_of] * t
    q = np.empty((total, 3))
    pts = np.arange(total)
    q[pts, a[arc_of]] = ca[arc_of] + rr * np.cos(ang)
    q[pts, b[arc_of]] = cb[arc_of] + rr * np.sin(ang)
    sn, en = s[rows, nn], e[rows, nn]
    q[pts, nn[arc_of]] = sn[arc_of] + (en - sn)[arc_of] * t
    q[first + m - 1] = e
    slack = 1e-11 * (np.abs(ca) + np.abs(cb) + np.abs(sn) + np.abs(en) + r0 + r1 + 1.0)
    return q, m, slack


def _bulk_motion(w: BlockWriter, o: PostOptions, A, b, arc_mode: str, op: Operation, z_safe: float,
                 prefix: tuple[str, ...]) -> bool:
    """:func:`emit_motion` with whole arrays; False (and nothing written) when some coordinate is too
    large for :func:`_quantise`.

    MotionEmitter's state after a block is a function of the blocks so far: the printed X Y Z are
    those of the latest move (after rounding), so a word is printed where its rounded value differs
    from the previous move's; G0/G1/G2/G3 where it differs from the previous printed block's; F where
    it differs from the previous printed G1/G2/G3 block's; G17/18/19 where it differs from the
    previous arc's (G17 at the start). An arc starts from the rounded end of the previous move (the
    last chord of a linearised arc ends on it exactly)."""
    d = int(o.decimals)
    scale = float(10 ** d)
    two_res = 2 * 10.0 ** (-d)
    tol = float(o.chord_tol_mm)
    A = np.asarray(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    At = A.T

    def prog(pts: np.ndarray) -> np.ndarray:
        # MotionEmitter.to_prog row by row: a stack of (1,3) @ (3,3) products makes numpy call the
        # same BLAS kernel for every row as it does for one point, hence the same bits
        return (pts[:, None, :] @ At)[:, 0, :] + b

    tp = op.toolpath
    n = tp.n_moves
    kind, plane = tp.kind, tp.plane
    tip = tp.tip_mm()
    centre = tp.centre_mm - np.array([0.0, 0.0, tp.tip_offset_mm])
    first, last = tip[0], tip[-1]
    x_app = np.asarray([first[0], first[1], z_safe], dtype=np.float64) @ At + b
    x_ret = np.asarray([last[0], last[1], z_safe], dtype=np.float64) @ At + b
    q_app, q_ret, q_mv = _quantise(x_app, d), _quantise(x_ret, d), _quantise(prog(tip), d)
    if q_app is None or q_ret is None or q_mv is None:
        return False

    # what each move prints: 0 a G0 point, 1 a G1 point, 2 a G2/G3 block, 3 G1 chords
    mode = np.where(kind == RAPID, 0, 1).astype(np.int8)
    arcs = np.flatnonzero((kind == ARC_CW) | (kind == ARC_CCW))
    ccw = kind[arcs] == ARC_CCW
    if arc_mode == "frame":
        kept = np.ones(arcs.size, dtype=bool)
        out_plane = plane[arcs].astype(np.int64)
        flip = np.zeros(arcs.size, dtype=bool)
    else:
        kept = np.zeros(arcs.size, dtype=bool)
        out_plane = np.full(arcs.size, PLANE_XY, dtype=np.int64)
        flip = np.zeros(arcs.size, dtype=bool)
        for p in (PLANE_XY, PLANE_ZX, PLANE_YZ):
            n_area = np.zeros(3)
            n_area[PLANE_AXES[p][2]] = 1.0
            pp = principal_plane(A @ n_area)
            if pp is not None:
                sel = plane[arcs] == p
                kept[sel] = True
                out_plane[sel] = pp[0]
                flip[sel] = pp[1] < 0
    out_ccw = ccw ^ flip
    # kept arcs whose start and end coincide after rounding, or with a radius at the resolution
    ki = np.flatnonzero(kept)
    ka = arcs[ki]
    rows = np.arange(ka.size)
    ia, ib = _AX_A[out_plane[ki]], _AX_B[out_plane[ki]]
    S = q_mv[ka - 1] / scale                   # the printed start (float(fmt(.)) == q / 10^d exactly)
    E = q_mv[ka] / scale
    C = prog(centre[ka])
    chord = _hypot_settled(E[rows, ia] - S[rows, ia], E[rows, ib] - S[rows, ib], two_res)
    radius = _hypot_settled(C[rows, ia] - S[rows, ia], C[rows, ib] - S[rows, ib], two_res)
    lin = ~kept
    block = kept.copy()
    for j in np.flatnonzero((chord < two_res) | (radius < two_res)):
        i = ka[j]
        block[ki[j]] = False
        _, sw, _ = arc_sweep_rad(tip[i - 1], tip[i], centre[i], int(plane[i]), bool(kind[i] == ARC_CCW))
        lin[ki[j]] = abs(sw) > math.pi / 2 and radius[j] >= two_res     # else one G1 to the end
    mode[arcs[block]] = 2
    mode[arcs[lin]] = 3
    blk = arcs[block]
    in_blk = block[ki]
    q_off = _quantise(C[in_blk] - S[in_blk], d)            # I J K: centre - printed start
    if q_off is None:
        return False

    # chords of the linearised arcs
    lin_mv = arcs[lin]
    count = np.ones(n, dtype=np.int64)
    if lin_mv.size:
        pts, m, slack = _chord_points(tip[lin_mv - 1], tip[lin_mv], centre[lin_mv], plane[lin_mv].astype(np.int64),
                                      kind[lin_mv] == ARC_CCW, tol)
        P = prog(pts)
        arc_of = np.repeat(np.arange(lin_mv.size), m)
        first_pt = np.cumsum(m) - m
        p = np.abs(P) * scale
        near = np.abs(p - np.floor(p) - 0.5) <= (slack * scale)[arc_of, None] + p * 2.0 ** -52
        for j in np.unique(arc_of[near.any(axis=1)]):          # within reach of a rounding tie: exact points
            i = lin_mv[j]
            ex = arc_chord_points(tip[i - 1], tip[i], centre[i], int(plane[i]), bool(kind[i] == ARC_CCW), tol)
            P[first_pt[j]:first_pt[j] + m[j]] = prog(ex)
        q_lin = _quantise(P, d)
        if q_lin is None:
            return False
        count[lin_mv] = m

    # the points in order: approach, every move's (a linearised arc's chords), retract
    ev_move = np.concatenate([[0], np.repeat(np.arange(n), count), [n - 1]])
    ev_type = np.concatenate([[0], mode[ev_move[1:-1]], [0]])
    q = np.concatenate([q_app[None], q_mv[ev_move[1:-1]], q_ret[None]])
    if lin_mv.size:
        q[np.flatnonzero(ev_type == 3)] = q_lin
        ev_type[ev_type == 3] = 1
    changed = np.ones(q.shape, dtype=bool)
    changed[1:] = q[1:] != q[:-1]
    is_arc = ev_type == 2
    printed = changed.any(axis=1) | is_arc
    em = np.flatnonzero(printed)                           # em[0] == 0, the approach
    mv = ev_move[em]
    t_em = ev_type[em]
    arc_em = t_em == 2
    # modal G0/G1/G2/G3, feed and plane words
    out_ccw_mv = np.zeros(n, dtype=bool)
    out_ccw_mv[arcs] = out_ccw
    motion = np.where(arc_em, 2 + out_ccw_mv[mv], t_em)
    new_motion = np.ones(em.size, dtype=bool)
    new_motion[1:] = motion[1:] != motion[:-1]
    fmt_feed = fmt(float(op.feed_mm_min), min(d, 3))
    fmt_plunge = fmt(float(op.plunge_mm_min), min(d, 3))
    feed_id = ((tp.use == USE_PLUNGE) & (fmt_plunge != fmt_feed)).astype(np.int64)
    fed = np.flatnonzero(t_em != 0)
    f_code = feed_id[mv[fed]]
    new_feed = np.zeros(em.size, dtype=bool)
    new_feed[fed] = np.concatenate([[True], f_code[1:] != f_code[:-1]])
    plane_mv = np.full(n, PLANE_XY, dtype=np.int64)
    plane_mv[arcs] = out_plane
    arc_planes = plane_mv[mv[arc_em]]
    new_plane = np.zeros(em.size, dtype=bool)
    new_plane[arc_em] = arc_planes != np.concatenate([[PLANE_XY], arc_planes[:-1]])
    blk_pos = np.zeros(n, dtype=np.int64)
    blk_pos[blk] = np.arange(blk.size)
    if not blk.size:
        q_off = np.zeros((1, 3), dtype=np.int64)

    w.block("G0", *prefix, *(letter + fmt(x_app[k], d) for k, letter in enumerate("XYZ")))
    numbers = w.take_numbers(em.size - 1) if w.numbered else None
    text = []
    for lo in range(1, em.size, _CHUNK_ROWS):
        sl = slice(lo, min(lo + _CHUNK_ROWS, em.size))
        ev, mvs, arc_rows = em[sl], mv[sl], arc_em[sl]
        rows = _Rows(ev.size)
        if numbers is not None:
            rows.number("N", numbers[lo - 1:sl.stop - 1], 0, np.ones(ev.size, dtype=bool), point=False)
        pl = plane_mv[mvs]
        rows.table(pl - PLANE_XY, _PLANE_WORDS, new_plane[sl])
        rows.table(motion[sl], _MOTION_WORDS, new_motion[sl])
        for k, letter in enumerate("XYZ"):
            rows.number(letter, q[ev, k], d, changed[ev, k])
        qo = q_off[blk_pos[mvs]]
        for k, (letter, skip) in enumerate(zip("IJK", (PLANE_YZ, PLANE_ZX, PLANE_XY))):
            rows.number(letter, qo[:, k], d, arc_rows & (pl != skip))
        rows.table(feed_id[mvs], ("F" + fmt_feed, "F" + fmt_plunge), new_feed[sl])
        text.append(rows.text())
    if text:
        w.raw("".join(text)[:-1])
    if arc_planes.size and arc_planes[-1] != PLANE_XY:
        w.block(_PLANE_WORDS[0])
    return True


def header_lines(*, post: str, area_id, setup_id, tool_axis: np.ndarray, rotary_deg, axis_names,
                 extra: Sequence[str], upper: bool) -> list[str]:
    """The header comment lines common to the posts."""
    lines = [comment(f"scanmill {scanmill_version()} - {post}", upper=upper)]
    lines.append(comment(f"area {area_id if area_id is not None else '-'} setup "
                         f"{setup_id if setup_id is not None else '-'}", upper=upper))
    lines.append(comment("tool axis in the part frame " + " ".join(
        f"{n}{fmt(v, 6)}" for n, v in zip("XYZ", tool_axis)), upper=upper))
    if rotary_deg is not None:
        names = axis_names or ("tilt", "rotary")
        lines.append(comment(f"rotary angles of the plan (planning.orientations.kinematics signs, deg) {names[0]}"
                             f"{fmt(rotary_deg[0], 6)} {names[1]}{fmt(rotary_deg[1], 6)}", upper=upper))
    lines.extend(comment(e, upper=upper) for e in extra)
    return lines


def operation_comment(k: int, op: Operation, upper: bool) -> str:
    return comment(f"operation {k + 1}: {op.name} - T{int(op.tool_number)} D{fmt(op.tool_diameter_mm, 3)} "
                   f"{op.tool_type} - S{fmt(op.spindle_rpm, 0)[:-1]} F{fmt(op.feed_mm_min, 3)} "
                   f"plunge F{fmt(op.plunge_mm_min, 3)} mm/min - tip offset {fmt(op.toolpath.tip_offset_mm, 4)}",
                   upper=upper)


def spindle_word(rpm: float) -> str:
    return f"S{round(float(rpm))}"


