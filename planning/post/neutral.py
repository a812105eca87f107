"""Neutral, controller-independent move list of one area, JSON-ready (DESIGN step 8).

:func:`neutral_moves` returns a dict that ``json.dumps`` accepts as is: the set-up (tool axis,
rotary angles with the machine's axis names), the area frame, and per operation its tool, feeds and
moves, with every tool-tip end point and arc centre in the PART frame and in the MACHINE frame.

Frames (mm; angles in degrees, signs of :mod:`planning.machine`)
----------------------------------------------------------------
* Part frame: the point cloud's frame. A toolpath point ``a`` (area frame) has the tip
  ``a - (0, 0, tip_offset_mm)`` and the part-frame tip ``frame.to_part(tip)``.
* Machine frame (:mod:`planning.travel`): origin at the table-top centre on the C axis with every
  rotary axis at 0, Z up. The part sits at ``placement_mm`` on the table.

  - table-table: the tip once the rotary axes are positioned,
    ``M (p + placement) + (I - R_tilt) P`` with ``M = part_to_machine_rotation((tilt, rotary))``,
    ``R_tilt = part_to_machine_rotation((tilt, 0))``, ``P = profile.pivot_mm``; the tool axis is
    machine +Z there (``M t = Z``);
  - head-head: the part does not move: ``p + placement``; the tool axis is ``t`` (the head turns).

  Vectors (arc normals, the tool axis) map by ``M`` (table-table) or unchanged (head-head).

Layout (columns, not one object per move)
-----------------------------------------
``operations[k]["moves"]`` holds parallel lists, one entry per move ``i`` (move 0 is the rapid to
the start, from wherever the machine is):

* ``type``: ``"rapid"`` | ``"feed"`` | ``"arc"``; ``use``: ``"rapid"`` | ``"cut"`` | ``"plunge"`` |
  ``"retract"``; ``feed_mm_min``: the feed of the move (null for rapids; ``plunge_mm_min`` for
  plunges, ``feed_mm_min`` otherwise);
* ``tip_part_mm``, ``tip_machine_mm``: ``[x, y, z]`` end points of the tool tip.

``operations[k]["arcs"]`` holds parallel lists, one entry per arc: ``move`` (its index ``i``; it
starts at move ``i - 1``'s end point), ``direction`` ``"cw"`` | ``"ccw"`` (as seen from the tip of
the plane's normal, ``"ccw"`` = right-hand turn about it), ``plane`` (17/18/19 in the AREA frame:
normal along the area z, y or x), ``normal_part`` / ``normal_machine`` (that normal, unit),
``centre_part_mm`` / ``centre_machine_mm`` (tip-path centre, in the plane of the start point).

With a gauge length (the operation's or the ``gauge_length_mm`` argument), ``controlled_machine_mm`` gives per move the machine's
controlled point (:func:`planning.travel.machine_position_affine`: spindle gauge point for
table-table, head rotation centre for head-head). Lengths are rounded to ``10^-decimals`` mm
(default 1e-4), unit vectors and the frame rotation to 1e-10.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from planning.errors import ParameterError
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
    path_length_mm,
)

from .common import (
    Operation,
    check_frame,
    check_gauge,
    check_operations,
    check_placement,
    check_rotary,
    feed_for,
    gauge_of,
    scanmill_version,
)

__all__ = ["NEUTRAL_FORMAT", "NEUTRAL_FORMAT_VERSION", "neutral_moves"]

NEUTRAL_FORMAT = "scanmill-neutral-moves"
NEUTRAL_FORMAT_VERSION = 1

_TYPE = {RAPID: "rapid", FEED: "feed", ARC_CW: "arc", ARC_CCW: "arc"}
_USE = {USE_RAPID: "rapid", USE_CUT: "cut", USE_PLUNGE: "plunge", USE_RETRACT: "retract"}
_UNIT_DECIMALS = 10


def _r(a, decimals: int):
    """Rounded nested lists of plain floats (no -0.0)."""
    return (np.round(np.asarray(a, dtype=np.float64), decimals) + 0.0).tolist()


def neutral_moves(operations: Sequence[Operation], frame: AreaFrame, *, tool_axis, rotary_deg, profile,
                  placement_mm, setup_id=None, area_id=None, gauge_length_mm=None, decimals: int = 4) -> dict:
    """The neutral move list of one area (dict, JSON-ready; layout in the module docstring).

    ``operations``: :class:`~planning.post.common.Operation` list; ``frame``: their area frame;
    ``tool_axis`` (3,): the set-up's tool axis in the part frame (must be the frame's +Z);
    ``rotary_deg``: ``(tilt_deg, rotary_deg)`` presenting it on ``profile`` (MachineProfile, name or
    path; checked by the forward kinematics); ``placement_mm`` (3,): the part origin in the table
    frame, mm. ``setup_id``, ``area_id``: copied into the result. ``gauge_length_mm``: tool gauge
    length (mm) for operations without their own, for ``controlled_machine_mm``. ``decimals``: places of every
    length (0..6, default 4). Angles are not rounded.
    """
    from planning.machine import _profile, part_to_machine_rotation
    from planning.travel import machine_position_affine

    if isinstance(decimals, bool) or not isinstance(decimals, (int, np.integer)) or not 0 <= decimals <= 6:
        raise ParameterError(f"decimals = {decimals!r}: must be an integer in [0, 6]", parameter="decimals")
    d = int(decimals)
    ops = check_operations(operations)
    t = check_frame(frame, tool_axis)
    p = _profile(profile)
    rot = check_rotary(rotary_deg, t, p)
    place = check_placement(placement_mm)
    gauge = check_gauge(gauge_length_mm)
    Rrows = np.asarray(frame.rotation, dtype=np.float64)
    origin = np.asarray(frame.origin_mm, dtype=np.float64)
    M = part_to_machine_rotation(rot, p)[0]                 # identity for head-head
    if p.is_table_table:
        # the controlled point with a zero gauge length is the tip itself
        A_tip, b_tip = machine_position_affine(rot, p, placement_mm=place, tool_radius_mm=0.0, gauge_length_mm=0.0)
        A_tip, b_tip = A_tip[0], b_tip[0]
    else:
        A_tip, b_tip = np.eye(3), place.copy()
    tilt_name, rot_name = p.axis_names

    out_ops = []
    for op in ops:
        tp = op.toolpath
        off = np.array([0.0, 0.0, tp.tip_offset_mm])
        tip_part = frame.to_part(tp.xyz_mm - off)
        tip_mach = tip_part @ A_tip.T + b_tip
        feeds = [None if int(k) == RAPID else feed_for(op, u) for k, u in zip(tp.kind, tp.use)]
        moves = {
            "count": int(tp.n_moves),
            "type": [_TYPE[int(k)] for k in tp.kind],
            "use": [_USE[int(u)] for u in tp.use],
            "feed_mm_min": feeds,
            "tip_part_mm": _r(tip_part, d),
            "tip_machine_mm": _r(tip_mach, d),
        }
        arc_idx = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)))
        cen_part = frame.to_part(tp.centre_mm[arc_idx] - off) if arc_idx.size else np.zeros((0, 3))
        normals = np.array([Rrows[PLANE_AXES[int(tp.plane[i])][2]] for i in arc_idx]).reshape(-1, 3)
        arcs = {
            "count": int(arc_idx.size),
            "move": [int(i) for i in arc_idx],
            "direction": ["ccw" if int(tp.kind[i]) == ARC_CCW else "cw" for i in arc_idx],
            "plane": [int(tp.plane[i]) for i in arc_idx],
            "normal_part": _r(normals, _UNIT_DECIMALS),
            "normal_machine": _r(normals @ M.T, _UNIT_DECIMALS),
            "centre_part_mm": _r(cen_part, d),
            "centre_machine_mm": _r(cen_part @ A_tip.T + b_tip, d),
        }
        entry = {
            "name": str(op.name),
            "tool": {"number": int(op.tool_number), "diameter_mm": float(op.tool_diameter_mm),
                     "type": str(op.tool_type),
                     "gauge_length_mm": None if op.gauge_length_mm is None else float(op.gauge_length_mm)},
            "spindle_rpm": float(op.spindle_rpm),
            "feed_mm_min": float(op.feed_mm_min),
            "plunge_mm_min": float(op.plunge_mm_min),
            "tip_offset_mm": float(tp.tip_offset_mm),
            "cut_length_mm": round(path_length_mm(tp), d),
            "rapid_length_mm": round(path_length_mm(tp, kinds=(RAPID,)), d),
            "moves": moves,
            "arcs": arcs,
        }
        G = gauge_of(op, gauge)
        entry["tool"]["gauge_length_mm"] = G
        if G is not None:
            A_c, b_c = machine_position_affine(rot, p, placement_mm=place, tool_radius_mm=0.0, gauge_length_mm=G)
            entry["controlled_machine_mm"] = _r(tip_part @ A_c[0].T + b_c[0], d)
        out_ops.append(entry)

    return {
        "format": NEUTRAL_FORMAT,
        "format_version": NEUTRAL_FORMAT_VERSION,
        "scanmill_version": scanmill_version(),
        "units": {"length": "mm", "angle": "deg", "feed": "mm/min", "spindle": "rev/min"},
        "area_id": area_id,
        "setup": {
            "id": setup_id,
            "tool_axis_part": _r(t, _UNIT_DECIMALS),
            "tool_axis_machine": _r(M @ t, _UNIT_DECIMALS),
            "rotary_deg": {tilt_name: float(rot[0]) + 0.0, rot_name: float(rot[1]) + 0.0},
            "axis_names": [tilt_name, rot_name],
            "angle_signs": "planning.machine: right-hand rule about the positive machine axis; "
                           + ("the table (part) turns" if p.is_table_table else "the head (tool) turns"),
        },
        "machine": {
            "profile": p.name,
            "kinematics": p.kinematics,
            "placement_mm": _r(place, d),
            "table_pivot_mm": _r(p.pivot_mm, d) if p.is_table_table else None,
            "head_pivot_length_mm": None if p.is_table_table else p.pivot_length_mm,
            "machine_frame": "origin at the table-top centre on the C axis with every rotary axis at 0, Z up; "
                             + ("tip_machine_mm = M (p + placement) + (I - R_tilt) P, the table turned"
                                if p.is_table_table else "tip_machine_mm = p + placement, the part fixed"),
        },
        "frame": {
            "origin_part_mm": _r(origin, d),
            "axes_part": _r(Rrows, _UNIT_DECIMALS),
            "axes_note": "rows: the area frame's x, y, z (= tool axis) in the part frame",
        },
        "operations": out_ops,
    }
