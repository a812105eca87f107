"""LinuxCNC-style 3+2 post with explicit rotary positioning (docs/design.md stage 8).

The program turns the rotary axes to the set-up's angles, then runs plain 3-axis ``X Y Z`` moves in
the MACHINE frame of :mod:`planning.visibility.travel`. It needs no tilted-plane or TCP function in the control
(trivial kinematics).

Frames and what X Y Z are (mm)
------------------------------
* Work offset ``G54`` = the machine frame of :mod:`planning.visibility.travel`: origin at the table-top centre
  on the C axis with every rotary axis at 0, axes along the machine's X, Y, Z (Z up, along the
  spindle at zero head angles). The part sits on the table at ``placement_mm`` (part point ``p`` is
  at ``p + placement_mm`` in the table frame).
* **Table-table** (``table_table_ac`` / ``table_table_bc``): ``X Y Z`` = the tool TIP in the machine
  frame once the table has turned, with ``G43 H<tool>`` (the spindle stays vertical, so length
  compensation along Z is exact)::

      X = M (p + placement) + (I - R_tilt) P
      M = part_to_machine_rotation((tilt, rotary)) = R_tilt(tilt) R_z(rotary),
      R_tilt = part_to_machine_rotation((tilt, 0)), P = profile.pivot_mm (a point of the tilt axis)

* **Head-head** (``head_head_ac`` / ``head_head_bc``): the part stays put; the head tilts, so a Z
  length offset would be wrong. ``X Y Z`` = the HEAD ROTATION CENTRE (the point where C and A/B
  meet, the controlled point of :func:`planning.orientations.positions.machine_position_affine`), with ``G49`` (no
  length compensation)::

      X = p + placement + (G + L) t

  with ``G`` = the tool's gauge length (tip to spindle gauge line: ``Operation.gauge_length_mm`` or
  the post's ``gauge_length_mm`` argument, required), ``L =
  profile.head_pivot_length_mm`` and ``t`` the tool axis of the printed angles. This is what a
  head-head machine with trivial kinematics positions when its XYZ are referenced to the head's
  rotation centre; the tool table's lengths must then not be applied.

Rotary axes and signs
---------------------
``G0 A.. C..`` (A/C kinematics) or ``G0 B.. C..`` (B/C) with the angles of the plan in the signs of
:mod:`planning.orientations.kinematics`: right-hand rule about the positive machine axis, turning the TABLE (the
part) for table-table, the HEAD (the tool) for head-head; the tilt (A about X, B about Y) and C
about Z. ``PostOptions.rotary_sign = (tilt_sign, rotary_sign)`` (each +1 or -1) multiplies the
printed words, for a control that counts an axis the other way (ISO 841 counts rotations of the table reversed). The rotary
axes turn with Z at machine home (``G53 G0 Z0``) and the spindle off.

Angles are printed with ``angle_decimals`` places (default ``decimals + 4``) and every position is
computed from the PRINTED angles, so their rounding moves no tool tip.

Arcs
----
The rotary positioning maps an area-frame arc plane into the machine frame. An arc is printed as
``G2``/``G3`` when its plane's normal maps onto a machine principal axis within
:data:`~planning.post.arcs.ARC_PLANE_TOL` (1e-9): ``G17``/``G18``/``G19`` for +-Z/+-Y/+-X, the
direction reversed when it maps onto the negative axis. For table-table, area ``G17`` arcs always
stay ``G17`` arcs (the tool axis maps onto +Z). Every other arc is linearised: ``G1`` chords at
equal angle steps with every point on the arc and no chord farther than
``PostOptions.chord_tol_mm`` from it (:func:`~planning.post.arcs.arc_chord_points`). ``G64 P``
with that tolerance keeps LinuxCNC's path blending within it too.

Program layout: header comments (program number, scanmill version, area, set-up, tool axis,
angles, the home the program ends at), the safe block ``G21 G90 G94 G17 G40 G49 G80``, ``G64 P``,
``G54``; per operation: ``G53 G0 Z0``, ``T M6``, ``G0 A/B C``, ``S M3``, ``M8`` (coolant option),
``G43 H`` or ``G49``, ``G0 X Y Z`` straight to the point above the first one at the safe height, the
moves, ``G0`` back to the safe height along the tool axis, ``M9``, ``G53 G0 Z0``, ``G49``, ``M5``;
then the rotary axes home, ``G53 G0 A0 C0`` (``B0 C0`` for B/C; Z already at machine Z0, the
spindle stopped: the program ends at machine zero with the rotary axes at 0), and ``M30``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from planning.errors import ParameterError
from planning.toolpath.frames import AreaFrame

from .arcs import safe_height_mm
from .blocks import BlockWriter, comment, fmt, header_lines, operation_comment, rounded, spindle_word
from .motion import emit_motion
from .options import (
    Operation,
    PostOptions,
    check_frame,
    check_gauge,
    check_operations,
    check_options,
    check_placement,
    check_rotary,
    gauge_of,
)

__all__ = ["SUPPORTED_KINEMATICS", "linuxcnc_program", "printed_rotary_deg"]

SUPPORTED_KINEMATICS = ("table_table_ac", "table_table_bc", "head_head_ac", "head_head_bc")


def printed_rotary_deg(rotary_deg, options: PostOptions | None = None) -> tuple[float, float]:
    """The ``(tilt, rotary)`` angles in planning.orientations.kinematics signs that the printed words command
    (rounded to the post's angle decimals; ``rotary_sign`` undone), degrees."""
    o = check_options(options)
    ad = int(o.decimals) + 4 if o.angle_decimals is None else int(o.angle_decimals)
    st, sr = (float(v) for v in o.rotary_sign)
    a = np.asarray(rotary_deg, dtype=np.float64).reshape(2)
    return (st * rounded(st * a[0], ad), sr * rounded(sr * a[1], ad))


def linuxcnc_program(operations: Sequence[Operation], frame: AreaFrame, *, tool_axis, rotary_deg, profile,
                     placement_mm, setup_id=None, area_id=None, gauge_length_mm=None,
                     options: PostOptions | None = None, five_axis=()) -> str:
    """LinuxCNC G-code (str) machining one area with the rotary axes positioned once (module docstring).

    ``operations``: :class:`~planning.post.options.Operation` list, run in order. ``frame``: the area
    frame of their toolpaths; ``tool_axis`` (3,): the set-up's tool axis (part frame), which must be
    the frame's +Z; ``rotary_deg``: ``(tilt_deg, rotary_deg)`` presenting it on ``profile`` (checked
    by the forward kinematics); ``profile``: MachineProfile, bundled name or JSON path;
    ``placement_mm`` (3,): part origin in the table frame (:func:`planning.orientations.positions.default_placement`).
    Head-head machines need the tool's gauge length (tip to spindle gauge line, mm): an operation's
    own ``gauge_length_mm``, else the ``gauge_length_mm`` argument (unused for table-table). X Y Z in the machine frame, mm;
    feeds mm/min; angles degrees. ``five_axis``: :class:`planning.post.simultaneous.FiveAxisOperation` list
    run after ``operations`` (simultaneous motion, G93 inverse-time feeds; ``operations`` may then be
    empty).
    """
    from planning.orientations.kinematics import as_profile

    o = check_options(options)
    five = list(five_axis)
    ops = check_operations(operations, allow_empty=bool(five))
    t = check_frame(frame, tool_axis)
    p = as_profile(profile)
    if p.kinematics not in SUPPORTED_KINEMATICS:          # pragma: no cover - schema allows no other
        raise ParameterError(f"the LinuxCNC post supports {', '.join(SUPPORTED_KINEMATICS)}, not {p.kinematics!r}",
                             parameter="machine.profile")
    rot = check_rotary(rotary_deg, t, p)
    place = check_placement(placement_mm)
    gauge = check_gauge(gauge_length_mm)
    if not p.is_table_table:
        _require_gauges(ops, gauge, p.kinematics)
    ang = _rotary_words(rot, o, p)

    w = BlockWriter(o)
    _program_start(w, o, p, t, rot, place, ang, setup_id=setup_id, area_id=area_id)
    for k, op in enumerate(ops):
        _operation_blocks(w, o, k, op, frame, p, place, gauge, ang)
    for k, op in enumerate(five):
        # simultaneous 5-axis operations (issue 19): every block positions X Y Z and the rotary axes
        from planning.post.simultaneous import linuxcnc_5axis_blocks

        linuxcnc_5axis_blocks(w, o, op, p, place, index=len(ops) + k)
    # the rotary axes home, Z at machine Z0 and the spindle stopped since the last operation's end
    w.block("G53", "G0", f"{p.axis_names[0]}0", f"{p.axis_names[1]}0")
    w.block("M30")
    return w.text()


def _require_gauges(ops: Sequence[Operation], gauge: float | None, kinematics: str) -> None:
    """ParameterError naming the first operation without a gauge length (its own or ``gauge``): a
    head-head program outputs the head rotation centre."""
    for k, op in enumerate(ops):
        if gauge_of(op, gauge) is None:
            raise ParameterError(
                f"operation {k} ({op.name!r}): the LinuxCNC post outputs the head rotation centre on a head-head "
                f"machine ({kinematics}) and needs the tool's gauge_length_mm (tip to spindle gauge line)",
                parameter="gauge_length_mm")


class _RotaryWords(NamedTuple):
    """The rotary positioning of the program (module docstring, Rotary axes and signs)."""

    words: tuple[float, float]  #: the printed tilt and C values (rotary_sign applied, rounded), deg
    decimals: int               #: their places (``angle_decimals``)
    printed: np.ndarray         #: (2,) the (tilt, rotary) they command, planning.orientations.kinematics signs, deg
    tool_axis: np.ndarray       #: (3,) the tool axis of the printed angles, part frame


def _rotary_words(rot: np.ndarray, o: PostOptions, p) -> _RotaryWords:
    """The rotary words of the planned angles ``rot`` on profile ``p``."""
    from planning.orientations.kinematics import tool_axis_from_angles

    d = int(o.decimals)
    ad = d + 4 if o.angle_decimals is None else int(o.angle_decimals)
    st, sr = (float(v) for v in o.rotary_sign)
    words_angle = (rounded(st * rot[0], ad), rounded(sr * rot[1], ad))
    printed = np.array(printed_rotary_deg(rot, o))                        # planning.orientations.kinematics signs
    t_printed = tool_axis_from_angles(printed, p)[0]
    return _RotaryWords(words_angle, ad, printed, t_printed)


def _program_start(w: BlockWriter, o: PostOptions, p, t: np.ndarray, rot: np.ndarray, place: np.ndarray,
                   ang: _RotaryWords, *, setup_id, area_id) -> None:
    """The header comments and the blocks before the first operation."""
    d, ad = int(o.decimals), ang.decimals
    st, sr = (float(v) for v in o.rotary_sign)
    table = p.is_table_table
    tilt_name, rot_name = p.axis_names
    w.raw(comment(f"program {int(o.program_number)}"))
    if table:
        what = "X Y Z = tool tip in the machine frame, G43 tool length to the tip"
    else:
        what = "X Y Z = head rotation centre in the machine frame, G49: no tool length compensation"
    for line in header_lines(
            post=f"LinuxCNC 3+2 post, explicit rotary positioning, {p.kinematics}", area_id=area_id,
            setup_id=setup_id, tool_axis=t, rotary_deg=rot, axis_names=p.axis_names, upper=False,
            extra=["units mm, mm/min, deg, G54 = machine frame: table-top centre on the C axis, rotary axes at 0",
                   f"part placement on the table X{fmt(place[0], d)} Y{fmt(place[1], d)} Z{fmt(place[2], d)}",
                   what,
                   (f"rotary words {tilt_name}{fmt(ang.words[0], ad)} {rot_name}{fmt(ang.words[1], ad)}"
                    f", signs: {tilt_name} {'flipped' if st < 0 else 'as planned'}, "
                    f"{rot_name} {'flipped' if sr < 0 else 'as planned'}, planned = planning.orientations.kinematics: "
                    f"right-hand rule, the {'table' if table else 'head'} turns"),
                   (f"the program ends at home: G53 Z0, then G53 {tilt_name}0 {rot_name}0, machine zero with the "
                    f"rotary axes at 0")]):
        w.raw(line)
    w.block("G21", "G90", "G94", "G17", "G40", "G49", "G80")
    w.block("G64", "P" + fmt(o.chord_tol_mm, max(d, 3)))
    w.block("G54")


def _operation_blocks(w: BlockWriter, o: PostOptions, k: int, op: Operation, frame: AreaFrame, p,
                      place: np.ndarray, gauge: float | None, ang: _RotaryWords) -> None:
    """Operation ``k``: Z home, tool change, the rotary axes, spindle, coolant, length offset, the
    motion in the machine frame, and back to Z home."""
    from planning.orientations.positions import machine_position_affine

    d = int(o.decimals)
    table = p.is_table_table
    tilt_name, rot_name = p.axis_names
    Rf = np.asarray(frame.rotation, dtype=np.float64).T                  # area -> part: R a + origin
    origin = np.asarray(frame.origin_mm, dtype=np.float64)
    w.raw(operation_comment(k, op, upper=False))
    tool = int(op.tool_number)
    G = 0.0 if table else gauge_of(op, gauge)
    A_m, b_m = machine_position_affine(ang.printed, p, placement_mm=place, tool_radius_mm=0.0, gauge_length_mm=G)
    A = A_m[0] @ Rf
    b = A_m[0] @ origin + b_m[0]
    operation_start(w, o, tool, op.spindle_rpm, table,
                    (f"{tilt_name}{fmt(ang.words[0], ang.decimals)}", f"{rot_name}{fmt(ang.words[1], ang.decimals)}"),
                    f"head rotation centre = tip + {fmt(G + p.pivot_length_mm, d)} mm along the tool axis "
                    + " ".join(f"{n}{fmt(v, 6)}" for n, v in zip("XYZ", ang.tool_axis)))
    emit_motion(w, o, A, b, "principal", op, safe_height_mm(op, o))
    operation_end(w, o)


def operation_start(w: BlockWriter, o: PostOptions, tool: int, spindle_rpm: float, table: bool, rotary_words,
                    head_note: str) -> None:
    """The blocks that begin an operation (this post's and :mod:`planning.post.simultaneous`'s): Z to
    machine Z0, the tool change, the rotary axes to ``rotary_words`` (the printed tilt and C words),
    the spindle, the coolant option, and the length offset: ``G43 H`` on a table-table machine, else
    ``G49`` and the comment ``head_note`` (what X Y Z are on a head-head machine)."""
    w.block("G53", "G0", "Z0")
    w.block(f"T{tool}", "M6")
    w.block("G0", *rotary_words)
    w.block(spindle_word(spindle_rpm), "M3")
    if o.coolant:
        w.block("M8")
    if table:
        w.block("G43", f"H{tool}")
    else:
        w.block("G49")
        w.raw(comment(head_note))


def operation_end(w: BlockWriter, o: PostOptions) -> None:
    """The blocks that end an operation: coolant off (option), Z to machine Z0, no length offset,
    spindle stop."""
    if o.coolant:
        w.block("M9")
    w.block("G53", "G0", "Z0")
    w.block("G49")
    w.block("M5")
