"""Neutral, controller-independent move list of one area, JSON-ready (docs/design.md stage 8).

:func:`neutral_moves` returns a dict that ``json.dumps`` accepts as is: the set-up (tool axis,
rotary angles with the machine's axis names), the area frame, and per operation its tool, feeds and
moves, with every tool-tip end point and arc centre in the PART frame and in the MACHINE frame.

Frames (mm; angles in degrees, signs of :mod:`planning.orientations.kinematics`)
----------------------------------------------------------------
* Part frame: the point cloud's frame. A toolpath point ``a`` (area frame) has the tip
  ``a - (0, 0, tip_offset_mm)`` and the part-frame tip ``frame.to_part(tip)``.
* Machine frame (:mod:`planning.visibility.travel`): origin at the table-top centre on the C axis with every
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
controlled point (:func:`planning.orientations.positions.machine_position_affine`: spindle gauge point for
table-table, head rotation centre for head-head). Lengths are rounded to ``10^-decimals`` mm
(default 1e-4), unit vectors and the frame rotation to 1e-10.

:func:`neutral_json` returns ``json.dumps(neutral_moves(...), separators=(",", ":"))`` byte for byte,
with the long lists written as text at once (on large tool paths ``json`` encoding the floats one by
one costs several times more than building the dict). :func:`neutral_json_arrays` gives that text and
the same document with every long list as the numpy values the text prints (:class:`Picked` for the
lists of names and feeds), from which :mod:`planning.report.moves_files` writes the binary
``area_<i>.moves.npz``.
"""

from __future__ import annotations

import gc
import json
import re
import secrets
from collections.abc import Sequence
from contextlib import contextmanager
from typing import NamedTuple

import numpy as np

from planning.errors import ParameterError
from planning.toolpath.frames import AreaFrame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    PLANE_YZ,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    path_length_mm,
)

from .blocks import scanmill_version
from .bulk_text import _Rows
from .options import (
    Operation,
    check_frame,
    check_gauge,
    check_operations,
    check_placement,
    check_rotary,
    gauge_of,
)

__all__ = ["NEUTRAL_FORMAT", "NEUTRAL_FORMAT_VERSION", "Picked", "neutral_json", "neutral_json_arrays",
           "neutral_moves"]

NEUTRAL_FORMAT = "scanmill-neutral-moves"
NEUTRAL_FORMAT_VERSION = 1

_TYPE = {RAPID: "rapid", FEED: "feed", ARC_CW: "arc", ARC_CCW: "arc"}
_USE = {USE_RAPID: "rapid", USE_CUT: "cut", USE_PLUNGE: "plunge", USE_RETRACT: "retract"}
_UNIT_DECIMALS = 10
_TYPE_NAMES = tuple(_TYPE[k] for k in range(4))
_USE_NAMES = tuple(_USE[k] for k in range(4))
#: Normal axis by arc plane code (PLANE_AXES as a lookup table).
_NORMAL_AXIS = np.array([PLANE_AXES.get(p, (0, 0, 0))[2] for p in range(PLANE_YZ + 1)])


@contextmanager
def _gc_paused():
    """The cyclic garbage collector off inside the block (back on afterwards if it was on)."""
    was_on = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()


def _r(a, decimals: int):
    """Rounded nested lists of plain floats (no -0.0)."""
    return (np.round(np.asarray(a, dtype=np.float64), decimals) + 0.0).tolist()


def neutral_moves(operations: Sequence[Operation], frame: AreaFrame, *, tool_axis, rotary_deg, profile,
                  placement_mm, setup_id=None, area_id=None, gauge_length_mm=None, decimals: int = 4) -> dict:
    """The neutral move list of one area (dict, JSON-ready; layout in the module docstring).

    ``operations``: :class:`~planning.post.options.Operation` list; ``frame``: their area frame;
    ``tool_axis`` (3,): the set-up's tool axis in the part frame (must be the frame's +Z);
    ``rotary_deg``: ``(tilt_deg, rotary_deg)`` presenting it on ``profile`` (MachineProfile, name or
    path; checked by the forward kinematics); ``placement_mm`` (3,): the part origin in the table
    frame, mm. ``setup_id``, ``area_id``: copied into the result. ``gauge_length_mm``: tool gauge
    length (mm) for operations without their own, for ``controlled_machine_mm``. ``decimals``: places of every
    length (0..6, default 4). Angles are not rounded.
    """
    with _gc_paused():
        return _document(operations, frame, tool_axis=tool_axis, rotary_deg=rotary_deg, profile=profile,
                         placement_mm=placement_mm, setup_id=setup_id, area_id=area_id,
                         gauge_length_mm=gauge_length_mm, decimals=decimals, lists=_Lists())


def neutral_json(operations: Sequence[Operation], frame: AreaFrame, *, tool_axis, rotary_deg, profile,
                 placement_mm, setup_id=None, area_id=None, gauge_length_mm=None, decimals: int = 4) -> str:
    """``json.dumps(neutral_moves(...), separators=(",", ":"))``, byte for byte (the same arguments),
    with the long per-move and per-arc lists written as text at once instead of as Python objects
    that ``json`` then encodes one by one (several times faster on large tool paths).

    Numbers print as ``json`` prints them (``repr`` of the float): where a rounded coordinate's
    shortest repr is not its rounded decimal digits for certain (15 significant digits or more,
    below 1e-4, or a float that is not the nearest one to those digits), Python's ``repr`` writes it.
    """
    return _json_text(operations, frame, tool_axis=tool_axis, rotary_deg=rotary_deg, profile=profile,
                      placement_mm=placement_mm, setup_id=setup_id, area_id=area_id, gauge_length_mm=gauge_length_mm,
                      decimals=decimals, keep=False)[0]


class Picked(NamedTuple):
    """A long list of :func:`neutral_json_arrays`' document given by a table and indices:
    the list is ``[table[i] for i in index]`` (names such as ``"rapid"``, or feeds with None for rapids)."""

    table: tuple
    index: np.ndarray


def neutral_json_arrays(operations: Sequence[Operation], frame: AreaFrame, *, tool_axis, rotary_deg, profile,
                        placement_mm, setup_id=None, area_id=None, gauge_length_mm=None,
                        decimals: int = 4) -> tuple[str, dict]:
    """``(text, doc)``: :func:`neutral_json`'s text (the same arguments) and the document it encodes
    with every long list (the per-move, per-arc and ``controlled_machine_mm`` lists) as the numpy
    values the text prints: float rows as (k,3) float64 (already rounded: ``v.tolist()`` is the
    list of the text), integer lists as int64, lists of names and feeds as :class:`Picked`."""
    return _json_text(operations, frame, tool_axis=tool_axis, rotary_deg=rotary_deg, profile=profile,
                      placement_mm=placement_mm, setup_id=setup_id, area_id=area_id, gauge_length_mm=gauge_length_mm,
                      decimals=decimals, keep=True)


def _json_text(operations, frame, *, keep: bool, **kw) -> tuple[str, dict | None]:
    lists = _JsonLists(keep=keep)
    doc = _document(operations, frame, lists=lists, **kw)
    text = lists.splice(json.dumps(doc, separators=(",", ":")))
    return text, (lists.materialise(doc) if keep else None)


class _Lists:
    """The long lists of the document as Python lists (:func:`neutral_moves`)."""

    def floats(self, a, decimals: int, groups=None) -> list:
        """Rows of ``a`` (k,3) rounded (:func:`_r`); ``groups``: see :func:`_json_float_rows`."""
        return _r(a, decimals)

    def pick(self, table: Sequence, idx: np.ndarray) -> list:
        """``[table[i] for i in idx]`` (strings, floats, None)."""
        return _object_array(table)[idx].tolist()

    def ints(self, a: np.ndarray) -> list:
        return a.tolist()


class _JsonLists:
    """The long lists of the document as placeholders, their JSON text kept aside (:func:`neutral_json`)."""

    def __init__(self, keep: bool = False):
        self.tag = secrets.token_hex(8)
        self.texts: list[str] = []
        self.keep = keep
        self.values: list = []          #: with ``keep``: each list's values (:func:`neutral_json_arrays`)

    def _put(self, text: str, value=None) -> str:
        self.texts.append(text)
        if self.keep:
            self.values.append(value)
        return f"\x00{self.tag}:{len(self.texts) - 1}"

    def floats(self, a, decimals: int, groups=None) -> str:
        v = np.round(np.asarray(a, dtype=np.float64), decimals) + 0.0
        return self._put(_json_float_rows(v, decimals, groups), v.reshape(-1, 3))

    def pick(self, table: Sequence, idx: np.ndarray) -> str:
        idx = np.asarray(idx, dtype=np.int64)
        value = Picked(tuple(table), idx)
        if not len(idx):
            return self._put("[]", value)
        rows = _Rows(len(idx), sep=",", end=",")
        rows.table(idx, [json.dumps(v) for v in table], np.ones(len(idx), dtype=bool))
        return self._put("[" + rows.text()[:-1] + "]", value)

    def ints(self, a: np.ndarray) -> str:
        a = np.asarray(a, dtype=np.int64)
        if not a.size:
            return self._put("[]", a)
        rows = _Rows(a.size, sep=",", end=",")
        rows.number("", a, 0, np.ones(a.size, dtype=bool), point=False)
        return self._put("[" + rows.text()[:-1] + "]", a)

    def materialise(self, doc):
        """``doc`` (the skeleton :func:`_document` built with this object) with every placeholder
        replaced by its list's values (``keep``); ``doc`` itself is left as it is."""
        if isinstance(doc, dict):
            return {k: self.materialise(v) for k, v in doc.items()}
        if isinstance(doc, list):
            return [self.materialise(v) for v in doc]
        if isinstance(doc, str) and doc.startswith(f"\x00{self.tag}:"):
            return self.values[int(doc.rsplit(":", 1)[1])]
        return doc

    def splice(self, skeleton: str) -> str:
        """The document's JSON text with every placeholder replaced by its list's text."""
        parts = re.split(re.escape(json.dumps(f"\x00{self.tag}:")[:-1]) + r'(\d+)"', skeleton)
        ids = [int(k) for k in parts[1::2]]
        if sorted(ids) != list(range(len(self.texts))):       # pragma: no cover - a tag in the user's strings
            raise RuntimeError("neutral_json: placeholder mismatch")
        parts[1::2] = [self.texts[k] for k in ids]
        return "".join(parts)


def _object_array(values: Sequence) -> np.ndarray:
    out = np.empty(len(values), dtype=object)
    out[:] = list(values)
    return out


def _json_float_rows(v: np.ndarray, decimals: int, groups: np.ndarray | None = None) -> str:
    """``json.dumps(v.tolist(), separators=(",", ":"))`` for ``v`` (k,3) float64 already rounded
    (``np.round(a, decimals) + 0.0``, as ``_r(a, decimals)``), the numbers written from their
    rounded digits at once. A float ``v`` with ``v == K / 10^decimals`` (the nearest
    float to the decimal ``K 10^-decimals``), ``|K| < 10^15`` and ``|v| >= 1e-4`` (or 0) has that
    decimal as its shortest repr (at most 15 significant digits name one float each), printed
    positionally; the rows with any other number go through ``repr``. ``groups`` (k,) int: rows
    that are likely equal where their groups are (checked)."""
    k = v.shape[0]
    if k == 0:
        return "[]"
    if groups is not None:
        # rows equal within each group (the arcs' plane normals): each group's text once
        _, first, code = np.unique(groups, return_index=True, return_inverse=True)
        if np.array_equal(v, v[first][code]):
            texts = ["[" + ",".join(map(repr, row)) + "]" for row in v[first].tolist()]
            rows = _Rows(k, sep=",", end=",")
            rows.table(code.reshape(-1), texts, np.ones(k, dtype=bool))
            return "[" + rows.text()[:-1] + "]"
    scale = 10.0 ** decimals
    K = np.rint(v * scale)
    fast = ((np.abs(K) < 1e15) & (K / scale == v) & ((K == 0) | (np.abs(v) >= 1e-4))).all(axis=1)
    q = np.where(fast[:, None], K, 0.0).astype(np.int64)
    rows = _Rows(k, sep=",", end=",")
    rows.const("[", fast)
    for j in range(v.shape[1]):
        rows.number("", q[:, j], decimals, fast, repr_style=True, glue=j > 0)
    rows.const("]", fast, glue=False)
    slow = np.flatnonzero(~fast)
    rows.raw(slow, ["[" + ",".join(map(repr, v[i].tolist())) + "]" for i in slow])
    return "[" + rows.text()[:-1] + "]"


def _document(operations, frame, *, tool_axis, rotary_deg, profile, placement_mm, setup_id, area_id,
              gauge_length_mm, decimals, lists) -> dict:
    """The neutral document, its long lists made by ``lists`` (:class:`_Lists` or :class:`_JsonLists`)."""
    from planning.orientations.kinematics import as_profile

    if isinstance(decimals, bool) or not isinstance(decimals, (int, np.integer)) or not 0 <= decimals <= 6:
        raise ParameterError(f"decimals = {decimals!r}: must be an integer in [0, 6]", parameter="decimals")
    d = int(decimals)
    ops = check_operations(operations)
    t = check_frame(frame, tool_axis)
    p = as_profile(profile)
    rot = check_rotary(rotary_deg, t, p)
    place = check_placement(placement_mm)
    gauge = check_gauge(gauge_length_mm)
    m = _on_machine(frame, rot, p, place)
    tilt_name, rot_name = p.axis_names
    out_ops = [_operation_entry(op, m, gauge, d, lists) for op in ops]

    return {
        "format": NEUTRAL_FORMAT,
        "format_version": NEUTRAL_FORMAT_VERSION,
        "scanmill_version": scanmill_version(),
        "units": {"length": "mm", "angle": "deg", "feed": "mm/min", "spindle": "rev/min"},
        "area_id": area_id,
        "setup": {
            "id": setup_id,
            "tool_axis_part": _r(t, _UNIT_DECIMALS),
            "tool_axis_machine": _r(m.M @ t, _UNIT_DECIMALS),
            "rotary_deg": {tilt_name: float(rot[0]) + 0.0, rot_name: float(rot[1]) + 0.0},
            "axis_names": [tilt_name, rot_name],
            "angle_signs": "planning.orientations.kinematics: right-hand rule about the positive machine axis; "
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
            "origin_part_mm": _r(m.origin, d),
            "axes_part": _r(m.Rrows, _UNIT_DECIMALS),
            "axes_note": "rows: the area frame's x, y, z (= tool axis) in the part frame",
        },
        "operations": out_ops,
    }


class _OnMachine(NamedTuple):
    """The area frame and the set-up on the machine (module docstring, Frames)."""

    frame: AreaFrame
    Rrows: np.ndarray     #: (3,3) the frame's axes as rows, part frame
    origin: np.ndarray    #: (3,) the frame's origin, part frame, mm
    M: np.ndarray         #: (3,3) part -> machine rotation of the rotary angles (identity for head-head)
    A_tip: np.ndarray     #: (3,3) and
    b_tip: np.ndarray     #: (3,) mm: machine tip = A_tip p + b_tip for a part-frame tip p
    rot: np.ndarray       #: (tilt_deg, rotary_deg)
    profile: object       #: the MachineProfile
    place: np.ndarray     #: (3,) placement of the part on the table, mm


def _on_machine(frame: AreaFrame, rot: np.ndarray, p, place: np.ndarray) -> _OnMachine:
    """The frame and the machine mapping of the tips of a checked set-up."""
    from planning.orientations.kinematics import part_to_machine_rotation
    from planning.orientations.positions import machine_position_affine

    M = part_to_machine_rotation(rot, p)[0]                 # identity for head-head
    if p.is_table_table:
        # the controlled point with a zero gauge length is the tip itself
        A_tip, b_tip = machine_position_affine(rot, p, placement_mm=place, tool_radius_mm=0.0, gauge_length_mm=0.0)
        A_tip, b_tip = A_tip[0], b_tip[0]
    else:
        A_tip, b_tip = np.eye(3), place.copy()
    Rrows = np.asarray(frame.rotation, dtype=np.float64)
    origin = np.asarray(frame.origin_mm, dtype=np.float64)
    return _OnMachine(frame, Rrows, origin, M, A_tip, b_tip, rot, p, place)


def _operation_entry(op: Operation, m: _OnMachine, gauge: float | None, d: int, lists) -> dict:
    """``operations[k]`` of the document: the tool, feeds, lengths, the moves and the arcs of ``op``
    (lengths rounded to ``d`` places, long lists by ``lists``)."""
    from planning.orientations.positions import machine_position_affine

    tp = op.toolpath
    off = np.array([0.0, 0.0, tp.tip_offset_mm])
    tip_part = m.frame.to_part(tp.xyz_mm - off)
    tip_mach = tip_part @ m.A_tip.T + m.b_tip
    feed_code = np.where(tp.kind == RAPID, 0, np.where(tp.use == USE_PLUNGE, 2, 1))
    moves = {
        "count": int(tp.n_moves),
        "type": lists.pick(_TYPE_NAMES, tp.kind),
        "use": lists.pick(_USE_NAMES, tp.use),
        "feed_mm_min": lists.pick((None, float(op.feed_mm_min), float(op.plunge_mm_min)), feed_code),
        "tip_part_mm": lists.floats(tip_part, d),
        "tip_machine_mm": lists.floats(tip_mach, d),
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
        "arcs": _arc_lists(tp, off, m, d, lists),
    }
    G = gauge_of(op, gauge)
    entry["tool"]["gauge_length_mm"] = G
    if G is not None:
        A_c, b_c = machine_position_affine(m.rot, m.profile, placement_mm=m.place, tool_radius_mm=0.0,
                                           gauge_length_mm=G)
        entry["controlled_machine_mm"] = lists.floats(tip_part @ A_c[0].T + b_c[0], d)
    return entry


def _arc_lists(tp, off: np.ndarray, m: _OnMachine, d: int, lists) -> dict:
    """``operations[k]["arcs"]``: one entry per arc of ``tp`` (``off``: the tip offset (0, 0, tip_offset_mm))."""
    arc_idx = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)))
    cen_part = m.frame.to_part(tp.centre_mm[arc_idx] - off) if arc_idx.size else np.zeros((0, 3))
    normals = m.Rrows[_NORMAL_AXIS[tp.plane[arc_idx]]].reshape(-1, 3)
    return {
        "count": int(arc_idx.size),
        "move": lists.ints(arc_idx),
        "direction": lists.pick(("cw", "ccw"), (tp.kind[arc_idx] == ARC_CCW).astype(np.int64)),
        "plane": lists.ints(tp.plane[arc_idx]),
        "normal_part": lists.floats(normals, _UNIT_DECIMALS, tp.plane[arc_idx]),
        "normal_machine": lists.floats(normals @ m.M.T, _UNIT_DECIMALS, tp.plane[arc_idx]),
        "centre_part_mm": lists.floats(cen_part, d),
        "centre_machine_mm": lists.floats(cen_part @ m.A_tip.T + m.b_tip, d),
    }
