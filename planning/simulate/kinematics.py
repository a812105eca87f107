"""The simulated machine shared by the program readers (issue 15): where the tool tip is in the part
frame for a machine position, the G53 / G28 home, rotary repositioning steps and arc chords.

Both readers (:mod:`planning.simulate.program` from the program text, :mod:`planning.simulate.rs274`
from LinuxCNC's interpreter) describe the machine by its linear axes and its rotary axes:

* ``mpos`` (mm, machine frame of :mod:`planning.orientations.positions`: origin at the table-top
  centre on the C axis with every rotary axis at 0, Z up): the profile's CONTROLLED point. Table-table:
  the spindle gauge point (the spindle stays along machine +Z); head-head: the head's rotation
  centre (pivot), ``head_pivot_length_mm`` above the gauge line along the tool axis.
* ``angles`` ``(tilt_deg, rotary_deg)`` in the signs of :mod:`planning.orientations.kinematics`
  (right-hand rule about the positive machine axis; the table turns for table-table, the head for
  head-head).
* ``gauge``: tip to spindle gauge line of the tool in the spindle (mm; 0 with no tool).

The part sits on the table at ``placement_mm`` (part point ``p`` at ``p + placement`` in the table
frame). With ``M = part_to_machine_rotation(angles)``, ``R_tilt`` the tilt alone and ``P`` the
tilt-axis point ``profile.pivot_mm``, the tool TIP ``p`` (part frame) and the tool axis ``t``
(part frame, from the tip towards the spindle) are::

    table-table:  mpos = M (p + placement) + (I - R_tilt) P + G Z          t = M^T Z
    head-head:    mpos = p + placement + (G + L) t,  t = R_z(C) R_tilt +Z   (L = head_pivot_length_mm)

Home (an assumption, the control's machine zero is not in the program; :data:`HOME_NOTE`): G53
(machine coordinates) ``X0 Y0 Z0`` and the G28 reference point are the controlled point at
``(centre of x_limits_mm, centre of y_limits_mm, z_limits_mm[1])``: the top of the Z travel over
the table centre. ``G53 X x Y y Z z`` is the controlled point at ``home + (x, y, z)``. A program
starts at home with the rotary axes at 0.
"""

from __future__ import annotations

import math

import numpy as np

from planning.orientations.kinematics import (
    _rot,
    _tilt_axis,
    as_profile,
    choose_rotary,
    part_to_machine_rotation,
    solve_rotary,
    tool_axis_from_angles,
)

__all__ = ["HOME_NOTE", "MachineModel", "arc_chords", "interpolate_moves", "machine_home_mm"]

HOME_NOTE = ("G53 / G28 home assumed: machine zero (G53 X0 Y0 Z0, the G28 reference point) is the controlled "
             "point at the centre of the X and Y limits and the TOP of the Z travel (z_limits_mm[1]); G53 X Y Z "
             "are offsets from it; the program starts there with the rotary axes at 0")

_EZ = np.array([0.0, 0.0, 1.0])


def machine_home_mm(profile) -> np.ndarray:
    """(3,) the controlled point at machine zero (module docstring, Home), machine frame, mm."""
    (x0, x1), (y0, y1), (_, z1) = as_profile(profile).linear_limits_mm
    return np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), z1])


def _rows(a, n: int) -> np.ndarray:
    """``a`` as (n, k): a single row is repeated."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    return np.broadcast_to(a, (n, a.shape[1])) if a.shape[0] == 1 else a


class MachineModel:
    """A machine profile with the part placed on it (module docstring), vectorised over moves.

    ``profile``: MachineProfile (or a bundled name / path); ``placement_mm`` (3,): part origin in the
    table frame, mm. Angles are ``(n, 2)`` or one ``(2,)`` row for all; gauges a scalar or ``(n,)``.
    """

    def __init__(self, profile, placement_mm):
        self.profile = as_profile(profile)
        self.placement = np.asarray(placement_mm, dtype=np.float64).reshape(3)
        self.table = self.profile.is_table_table
        self.pivot = np.asarray(self.profile.pivot_mm, dtype=np.float64)
        self.pivot_length = float(self.profile.pivot_length_mm)
        self.home = machine_home_mm(self.profile)

    def _rotation(self, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(M (k,3,3), shift (k,3))``: table-table ``M`` (:func:`part_to_machine_rotation`),
        ``(I - R_tilt) P`` of each row."""
        M = part_to_machine_rotation(angles, self.profile)
        Rt = _rot(_tilt_axis(self.profile), np.radians(np.asarray(angles, dtype=np.float64)[:, 0]))
        P = self.pivot
        return M, P - (Rt[:, :, 0] * P[0] + Rt[:, :, 1] * P[1] + Rt[:, :, 2] * P[2])

    def axis(self, angles) -> np.ndarray:
        """(k,3) unit tool axis in the part frame (tip towards spindle) for ``angles`` (k,2), degrees."""
        a = np.atleast_2d(np.asarray(angles, dtype=np.float64))
        return tool_axis_from_angles(a, self.profile)

    def tip_from_machine(self, mpos, angles, gauge) -> tuple[np.ndarray, np.ndarray]:
        """``(tip (n,3), axis (n,3))`` in the part frame, mm, of controlled points ``mpos`` (n,3)
        (machine frame, mm) at rotary ``angles`` (n,2 or 2,; degrees) with tool gauge length ``gauge``
        (mm, scalar or (n,))."""
        m = np.atleast_2d(np.asarray(mpos, dtype=np.float64))
        a = np.atleast_2d(np.asarray(angles, dtype=np.float64))
        g = np.broadcast_to(np.asarray(gauge, dtype=np.float64), (m.shape[0],))[:, None]
        if self.table:
            M, shift = self._rotation(a)
            Mt = np.swapaxes(M, 1, 2)
            v = (m - g * _EZ - shift)[:, :, None]
            tip = (Mt @ v)[:, :, 0] - self.placement
            t = M[:, 2, :]
        else:
            t = self.axis(a)
            tip = m - (g + self.pivot_length) * t - self.placement
        return tip, _rows(t, m.shape[0]).copy()

    def machine_from_tip(self, tip, angles, gauge) -> np.ndarray:
        """(n,3) controlled points (machine frame, mm) that put the tool tip at part points ``tip``
        (n,3) at rotary ``angles`` with gauge length ``gauge`` (the inverse of
        :meth:`tip_from_machine`)."""
        p = np.atleast_2d(np.asarray(tip, dtype=np.float64))
        a = np.atleast_2d(np.asarray(angles, dtype=np.float64))
        g = np.broadcast_to(np.asarray(gauge, dtype=np.float64), (p.shape[0],))[:, None]
        if self.table:
            M, shift = self._rotation(a)
            return (M @ (p + self.placement)[:, :, None])[:, :, 0] + shift + g * _EZ
        return p + self.placement + (g + self.pivot_length) * self.axis(a)

    def orient(self, axis) -> tuple[np.ndarray, bool]:
        """``(angles (2,), feasible)``: the rotary position presenting the part-frame tool ``axis``
        (3,) to the spindle, chosen as the planner chooses (:func:`choose_rotary`: smallest tilt, then
        tilt >= 0); ``feasible`` False when no solution is within travel (solution 0 is returned)."""
        sols = solve_rotary(np.asarray(axis, dtype=np.float64)[None, :], self.profile)
        chosen, feasible = choose_rotary(sols)
        if bool(feasible[0]):
            return chosen[0], True
        return sols.angles_deg[0, 0].copy(), False


def interpolate_moves(p0, p1, a0, a1, step_deg: float):
    """Split moves whose rotary axes turn into steps of at most ``step_deg`` degrees on every rotary axis.

    ``p0``/``p1`` (m,3): controlled point at the start / end (machine frame, mm); ``a0``/``a1`` (m,2):
    rotary angles at the start / end (degrees). All axes move together, linearly in machine
    coordinates (a coordinated G0/G1 of the linear and rotary axes). Returns ``(owner (N,), q0, q1,
    b0, b1)``: for each step, the move it belongs to, its start and end controlled points (N,3) and
    its start and end angles (N,2); a move whose angles do not change is one step.
    """
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    a0, a1 = np.asarray(a0, float), np.asarray(a1, float)
    turn = np.abs(a1 - a0).max(axis=1) if len(a0) else np.zeros(0)
    n = np.maximum(1, np.ceil(turn / float(step_deg) - 1e-12)).astype(np.int64)
    owner = np.repeat(np.arange(len(n)), n)
    first = np.cumsum(n) - n
    k = np.arange(owner.size) - first[owner]
    f0 = (k / n[owner])[:, None]
    f1 = ((k + 1) / n[owner])[:, None]
    f1[np.cumsum(n) - 1] = 1.0
    dp, da = p1 - p0, a1 - a0
    q0 = p0[owner] + f0 * dp[owner]
    q1 = np.where(f1 == 1.0, p1[owner], p0[owner] + f1 * dp[owner])
    b0 = a0[owner] + f0 * da[owner]
    b1 = np.where(f1 == 1.0, a1[owner], a0[owner] + f1 * da[owner])
    return owner, q0, q1, b0, b1


def arc_chords(start, end, centre, axes, turns, tol_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Chord end points of circular (or spiral, helical) arcs, no chord farther than ``tol_mm`` from its arc.

    ``start``/``end``/``centre`` (m,3) in any right-handed Cartesian frame (mm); the centre's
    normal coordinate is ignored. ``axes`` (m,3) int: the in-plane axes ``(first, second)`` and the
    normal of each arc's plane, right-handed (G17 ``(0,1,2)``, G18 ``(2,0,1)``, G19 ``(1,2,0)``).
    ``turns`` (m,) int: +n counter-clockwise about the normal (G3), -n clockwise (G2); ``|n| > 1``
    adds full turns (LinuxCNC ``P``). The sweep is the angle from the start to the end in that
    direction, in (0, 360] degrees (an end on the start is a full circle), plus the extra turns.
    Where the start and end radii differ the radius changes linearly with the angle (a spiral, as
    LinuxCNC moves), and the normal coordinate linearly (helix). Returns ``(owner (N,), points
    (N,3))``: the arc each chord belongs to and the chord's end point, in order; an arc's last point
    is its end exactly.
    """
    s, e, c = (np.asarray(v, dtype=np.float64) for v in (start, end, centre))
    ax = np.asarray(axes, dtype=np.int64)
    tn = np.asarray(turns, dtype=np.int64)
    r = np.arange(len(s))
    ia, ib, inn = ax[:, 0], ax[:, 1], ax[:, 2]
    sa, sb = s[r, ia] - c[r, ia], s[r, ib] - c[r, ib]
    ea, eb = e[r, ia] - c[r, ia], e[r, ib] - c[r, ib]
    r0, r1 = np.hypot(sa, sb), np.hypot(ea, eb)
    th0 = np.arctan2(sb, sa)
    d = np.arctan2(eb, ea) - th0
    sign = np.where(tn > 0, 1.0, -1.0)
    sweep = np.mod(sign * d, 2 * math.pi)
    sweep = np.where(sweep == 0.0, 2 * math.pi, sweep) + 2 * math.pi * (np.abs(tn) - 1)
    rmax = np.maximum(r0, r1)
    step = np.where(rmax > tol_mm, 2 * np.arccos(np.clip(1 - tol_mm / np.maximum(rmax, 1e-300), -1, 1)), 2 * math.pi)
    n = np.maximum(1, np.ceil(sweep / np.minimum(step, math.pi / 2) - 1e-9)).astype(np.int64)
    owner = np.repeat(r, n)
    k = np.arange(owner.size) - (np.cumsum(n) - n)[owner] + 1
    f = k / n[owner]
    th = th0[owner] + sign[owner] * sweep[owner] * f
    rad = r0[owner] + (r1 - r0)[owner] * f
    pts = np.empty((owner.size, 3))
    rows = np.arange(owner.size)
    pts[rows, ia[owner]] = c[owner, ia[owner]] + rad * np.cos(th)
    pts[rows, ib[owner]] = c[owner, ib[owner]] + rad * np.sin(th)
    pts[rows, inn[owner]] = s[owner, inn[owner]] + (e - s)[owner, inn[owner]] * f
    last = np.cumsum(n) - 1
    pts[last] = e
    return owner, pts
