"""ISO / Fanuc-style 3+2 post with a tilted work plane (``G68.2`` + ``G53.1``), docs/design.md stage 8.

What the program means
----------------------
* ``G54`` is the PART frame: the operator sets work offset G54 at the origin of the part frame
  (the point cloud's coordinates), its axes parallel to the machine's with every rotary axis at 0.
* ``G68.2 X Y Z I J K`` defines the tilted work plane (feature coordinate system) of the area:
  ``X Y Z`` = the area frame's origin in G54 (part frame), mm; ``I J K`` = Euler angles, degrees, in
  Fanuc's convention for G68.2: rotate about Z by I, then about the NEW X by J, then about the NEW
  Z by K (intrinsic, "rotating" Z-X'-Z''). The matrix whose columns are the feature axes in G54 is::

      R = Rz(I) @ Rx(J) @ Rz(K)       (Rz, Rx active right-hand rotations, planning.orientations.kinematics)

  and a feature point ``q`` is at ``R q + (X, Y, Z)`` in G54. That is SciPy's
  ``Rotation.from_euler('ZXZ', [I, J, K], degrees=True)`` (upper case = intrinsic); the extrinsic
  ``'zxz'`` is the reverse product ``Rz(K) Rx(J) Rz(I)`` and is NOT the Fanuc convention. The area
  frame's ``rotation`` has the frame axes as ROWS, so ``R = frame.rotation.T``. Angles: ``J`` in
  [0, 180]; ``I`` and ``K`` in (-180, 180]; when J is 0 or 180 (tool axis along +-Z) only I +- K
  matters and I is set to 0.
* ``G53.1`` turns the rotary axes so that the tool lies along the feature +Z (the set-up's tool
  axis); the control's own kinematics chooses the rotary solution. The plan's rotary angles
  (planning.orientations.kinematics signs) are printed in the header for the operator to compare.
* ``G43 H<tool>``: tool length compensation to the TIP. All ``X Y Z`` after it are tool-tip
  positions in the tilted plane = the area frame, mm. Arcs: ``G2``/``G3`` in the area-frame plane
  ``G17``/``G18``/``G19`` (CW/CCW seen from the positive end of the plane's normal, ISO 6983),
  centre as incremental offsets from the start point, ``I`` along X, ``J`` along Y, ``K`` along Z,
  only the two of the active plane.

Rounding: the program's ``X Y Z`` are computed in the frame that the PRINTED G68.2 words build
(rounded origin and angles), so the rounding of the angles moves no tool tip; it only turns the
tool axis by at most about ``0.5 * 10^-angle_decimals`` degrees per angle.

Program layout: ``%``, ``O<program>``, header comments (scanmill version, area, set-up, tool axis,
rotary angles, the home the program ends at), the safe block ``G21 G90 G94 G17 G40 G49 G80``,
``G69``, Z home (``G91 G28 Z0.`` / ``G90``), ``G54``; per operation: ``T M6``, ``G68.2``,
``G53.1`` (the table or head tilts with Z home and the spindle stopped), ``S M3``, ``M8`` (coolant
option), ``G0 G43 H X Y Z`` straight to the point above the first one at the safe height, the
moves, ``G0 Z`` back to the safe height, ``M9``, ``G69``, ``G91 G28 Z0.`` / ``G90 G49`` (the
length offset is cancelled only once Z is home: a control that executes G49 as a move would drive
the tip down by the tool length at the safe height), ``M5``; then the rotary axes home
(``G91 G28 B0. C0.`` / ``G90`` with the profile's axis names: the program ends at machine zero
with the rotary axes at 0, the reference position of every axis; without a profile the names are
unknown and a comment says so), ``M30`` and ``%``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

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
)

__all__ = ["euler_zxz_deg", "euler_zxz_matrix", "iso_program"]

# sin(J) below this: the tool axis is along +-Z and only I +- K is defined (gimbal lock).
_GIMBAL = 1e-12


def _rz(a_rad: float) -> np.ndarray:
    c, s = math.cos(a_rad), math.sin(a_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(a_rad: float) -> np.ndarray:
    c, s = math.cos(a_rad), math.sin(a_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def euler_zxz_matrix(i_deg: float, j_deg: float, k_deg: float) -> np.ndarray:
    """``Rz(I) @ Rx(J) @ Rz(K)`` (3,3): the columns are the G68.2 feature axes in the work frame."""
    return _rz(math.radians(i_deg)) @ _rx(math.radians(j_deg)) @ _rz(math.radians(k_deg))


def euler_zxz_deg(R) -> tuple[float, float, float]:
    """Fanuc G68.2 Euler angles ``(I, J, K)`` in degrees of a rotation ``R`` (3,3) whose COLUMNS are
    the feature axes in the work frame: ``R = Rz(I) Rx(J) Rz(K)`` with J in [0, 180], I and K in
    (-180, 180]; I = 0 when J is 0 or 180 (see the module docstring)."""
    R = np.asarray(R, dtype=np.float64)
    sj = math.hypot(R[0, 2], R[1, 2])
    j = math.atan2(sj, R[2, 2])
    if sj > _GIMBAL:
        i = math.atan2(R[0, 2], -R[1, 2])
        k = math.atan2(R[2, 0], R[2, 1])
    elif R[2, 2] > 0:            # Rz(I + K)
        i, k = 0.0, math.atan2(R[1, 0], R[0, 0])
    else:                        # Rx(180) Rz(K): R00 = cos K, R10 = -sin K
        i, k = 0.0, math.atan2(-R[1, 0], R[0, 0])

    def deg(a):
        d = math.degrees(a)
        return 180.0 if d <= -180.0 else d + 0.0

    return deg(i), math.degrees(j) + 0.0, deg(k)


def iso_program(operations: Sequence[Operation], frame: AreaFrame, *, tool_axis, setup_id=None, area_id=None,
                rotary_deg=None, profile=None, placement_mm=None, gauge_length_mm=None,
                options: PostOptions | None = None, five_axis=()) -> str:
    """ISO / Fanuc G-code (str) machining one area in its tilted work plane (see the module docstring).

    ``operations``: :class:`~planning.post.options.Operation` list, run in order (one tool change
    each). ``frame``: the area frame of their toolpaths; ``tool_axis`` (3,): the set-up's tool axis
    in the part frame, which must be the frame's +Z. ``setup_id`` / ``area_id``: for the header.
    ``rotary_deg`` ``(tilt_deg, rotary_deg)`` and ``profile`` (name, path or MachineProfile),
    optional: the plan's rotary angles, printed in the header with the profile's axis names and
    checked against the tool axis when both are given (the control's G53.1 picks its own); the
    profile's axis names also name the rotary axes returned to 0 at the end.
    ``placement_mm`` and ``gauge_length_mm`` are accepted so that every post takes the same
    arguments, and are not used: G54 is the part frame and G43 takes the tool length from the
    control's tool table. ``options``: :class:`~planning.post.options.PostOptions`
    (``rotary_sign`` does not apply; ``chord_tol_mm`` only to the arcs printed as chords). X Y Z
    are tool-tip positions in the area frame, mm; feeds mm/min. ``five_axis``:
    :class:`planning.post.simultaneous.FiveAxisOperation` list run after ``operations`` with ``G43.4``
    tool centre point control (they need ``profile`` and ``placement_mm``; ``operations`` may then be
    empty).
    """
    o = check_options(options)
    five = list(five_axis)
    ops = check_operations(operations, allow_empty=bool(five))
    t = check_frame(frame, tool_axis)
    if placement_mm is not None:
        check_placement(placement_mm)
    check_gauge(gauge_length_mm)
    if five:
        from planning.post.simultaneous import iso_5axis_blocks

        if profile is None or placement_mm is None:
            raise ParameterError("a simultaneous 5-axis operation needs the machine profile and the placement",
                                 parameter="profile")
    d = int(o.decimals)
    ad = d if o.angle_decimals is None else int(o.angle_decimals)
    axis_names, rot = _plan_angles(rotary_deg, profile, t)
    g682, A, b = _tilted_plane(frame, d, ad)

    w = BlockWriter(o)
    _program_start(w, o, t, rot, axis_names, setup_id=setup_id, area_id=area_id)
    for k, op in enumerate(ops):
        _operation_blocks(w, o, k, op, g682, A, b)
    for k, op in enumerate(five):
        # simultaneous 5-axis operations (issue 19): G43.4 tool centre point control
        iso_5axis_blocks(w, o, op, profile, placement_mm, index=len(ops) + k)
    _program_end(w, axis_names)
    return w.text()


def _plan_angles(rotary_deg, profile, t: np.ndarray) -> tuple[tuple[str, str] | None, np.ndarray | None]:
    """``(axis_names, rot)`` for the header: the profile's rotary axis names (None without a profile)
    and the plan's ``(tilt_deg, rotary_deg)`` (None without them), checked against the tool axis
    ``t`` when the profile is given."""
    axis_names = None
    rot = None
    if profile is not None:
        from planning.orientations.kinematics import as_profile

        p = as_profile(profile)
        axis_names = p.axis_names
        if rotary_deg is not None:
            rot = check_rotary(rotary_deg, t, p)
    elif rotary_deg is not None:
        rot = np.asarray(rotary_deg, dtype=np.float64).reshape(-1)
        if rot.shape != (2,) or not np.all(np.isfinite(rot)):
            raise ParameterError(f"rotary_deg = {rotary_deg!r}: must be (tilt_deg, rotary_deg)", parameter="rotary_deg")
    return axis_names, rot


def _tilted_plane(frame: AreaFrame, d: int, ad: int) -> tuple[list[str], np.ndarray, np.ndarray]:
    """``(g682, A, b)``: the words of the area's ``G68.2`` block (origin with ``d`` places, Euler
    angles with ``ad``) and the program frame ``X = A a + b`` of a tip ``a`` (area frame) in the
    feature frame those PRINTED words build (module docstring, Rounding)."""
    R = np.asarray(frame.rotation, dtype=np.float64).T            # columns: frame axes in the part frame
    origin = np.asarray(frame.origin_mm, dtype=np.float64)
    ijk = [rounded(v, ad) for v in euler_zxz_deg(R)]
    ijk = [180.0 if v <= -180.0 else v for v in ijk]
    origin_r = np.array([rounded(v, d) for v in origin])
    R_r = euler_zxz_matrix(*ijk)
    # tip in the area frame a -> part R a + origin -> printed feature frame R_r^T (part - origin_r)
    A = R_r.T @ R
    b = R_r.T @ (origin - origin_r)
    g682 = ["G68.2"] + [f"{n}{fmt(v, d)}" for n, v in zip("XYZ", origin_r)] + \
           [f"{n}{fmt(v, ad)}" for n, v in zip("IJK", ijk)]
    return g682, A, b


def _program_start(w: BlockWriter, o: PostOptions, t: np.ndarray, rot, axis_names, *, setup_id, area_id) -> None:
    """``%``, the ``O`` line, the header comments and the blocks before the first operation."""
    w.raw("%")
    w.raw(f"O{int(o.program_number):04d} " + comment(f"scanmill area {area_id if area_id is not None else '-'}",
                                                      upper=True))
    for line in header_lines(
            post="ISO/Fanuc 3+2 post, G68.2 tilted work plane", area_id=area_id, setup_id=setup_id, tool_axis=t,
            rotary_deg=rot, axis_names=axis_names, upper=True,
            extra=["units mm, mm/min, G54 = part frame origin",
                   "X Y Z = tool tip in the tilted plane = area frame",
                   "G68.2 Euler angles, rotating Z-X-Z: R = Rz[I] * Rx[J] * Rz[K], columns = plane axes in G54",
                   "G53.1 orients the tool along the plane +Z, the control picks the rotary solution",
                   _home_line(axis_names)]):
        w.raw(line)
    w.block("G21", "G90", "G94", "G17", "G40", "G49", "G80")
    w.block("G69")
    w.block("G91", "G28", "Z0.")
    w.block("G90")
    w.block("G54")


def _home_line(axis_names) -> str:
    """The header comment on the home the program ends at."""
    if axis_names is None:
        return ("the program ends with Z at its reference position, the rotary axes where the last G53.1 turned "
                "them: no machine profile, so their names are unknown")
    return (f"the program ends at home: Z, then {axis_names[0]} and {axis_names[1]} to their reference position "
            f"[G28], machine zero with the rotary axes at 0")


def _operation_blocks(w: BlockWriter, o: PostOptions, k: int, op: Operation, g682: list[str], A: np.ndarray,
                      b: np.ndarray) -> None:
    """Operation ``k``: tool change, tilted plane (the rotary axes turn with Z home and the spindle
    stopped), spindle, coolant, the motion (program frame ``X = A a + b``), and back to Z home with
    the plane and the length offset cancelled."""
    w.raw(operation_comment(k, op, upper=True))
    tool = int(op.tool_number)
    w.block(f"T{tool}", "M6")
    w.block(*g682)
    w.block("G53.1")
    w.block(spindle_word(op.spindle_rpm), "M3")
    if o.coolant:
        w.block("M8")
    emit_motion(w, o, A, b, "frame", op, safe_height_mm(op, o), approach_prefix=("G43", f"H{tool}"))
    if o.coolant:
        w.block("M9")
    w.block("G69")
    w.block("G91", "G28", "Z0.")
    w.block("G90", "G49")
    w.block("M5")


def _program_end(w: BlockWriter, axis_names) -> None:
    """After the last operation (Z home, G69, G49, M5): the rotary axes to their reference position,
    0 (``G91 G28 <tilt>0. C0.`` / ``G90``; a comment instead without the profile's axis names), then
    ``M30`` and ``%``."""
    if axis_names is not None:
        w.block("G91", "G28", f"{axis_names[0]}0.", f"{axis_names[1]}0.")
        w.block("G90")
    else:
        w.raw(comment("no machine profile: return the rotary axes to 0 before the next program", upper=True))
    w.block("M30")
    w.raw("%")
