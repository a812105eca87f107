"""Machine kinematics and machine visibility (Makki 2010 §2.2.2).

For each candidate tool axis (unit vector in the PART frame, from the part towards the spindle)
we find the machine's rotary positions (tilt, rotary) that present the part to the spindle along
that axis, and keep the axes whose positions lie within the rotary travel of the configured
:class:`~schemas.machine.MachineProfile` ("machine visibility", Makki Fig. 4b).

Angle conventions (all public angles in degrees)
------------------------------------------------
* Machine frame: right-handed X, Y, Z; the spindle (tool) axis points along machine +Z at zero
  head angles. With every rotary axis at 0, the part frame coincides with the machine frame and the
  tool axis is part +Z.
* ``R_x(a)``, ``R_y(a)``, ``R_z(a)`` are ACTIVE rotations by ``a`` about the positive machine X, Y,
  Z axes, right-hand rule (counter-clockwise looking down the axis towards the origin)::

      R_x(a) = [[1, 0, 0], [0, c, -s], [0, s, c]]
      R_y(a) = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
      R_z(a) = [[c, -s, 0], [s, c, 0], [0, 0, 1]]      (c = cos a, s = sin a)

* ``tilt`` is A (about X) for the ``*_ac`` kinematics, B (about Y) for ``*_bc``; ``rotary`` is C
  (about Z). Angle pairs are always ordered ``(tilt_deg, rotary_deg)``.
* **Table-table** (``table_table_ac`` / ``table_table_bc``): the part sits on the C table, which is
  carried by the tilting A/B trunnion. A part-frame vector v is, in the machine frame,
  ``R(tilt, rotary) @ v`` with ``R = R_tilt(tilt) @ R_z(rotary)`` (:func:`part_to_machine_rotation`).
  The spindle stays along machine +Z, so axis t is machinable when ``R @ t = +Z``, i.e.
  ``t = R_z(-rotary) @ R_tilt(-tilt) @ +Z``. Positive angles turn the TABLE (the part) by the
  right-hand rule.
* **Head-head** (``head_head_ac`` / ``head_head_bc``): the part is fixed (part frame = machine
  frame, :func:`part_to_machine_rotation` is the identity); C turns about machine Z and carries the
  A (head X) or B (head Y) swivel: ``t = R_z(rotary) @ R_tilt(tilt) @ +Z``. Positive angles turn
  the HEAD (the tool) by the right-hand rule.
* In every layout ``t_z = cos(tilt)``: the tilt angle is +-phi, the polar angle of the axis.
  Explicitly (s = sin tilt)::

      table_table_ac: t = ( s sin C,  s cos C, cos A)
      table_table_bc: t = (-s cos C,  s sin C, cos B)
      head_head_ac:   t = ( s sin C, -s cos C, cos A)
      head_head_bc:   t = ( s cos C,  s sin C, cos B)

These are the planner's mathematical signs. A given control may count an axis the other way
(ISO 841 counts rotary directions for the tool relative to the part); the post-processor maps them.

Each axis has up to two solutions, ``(+tau, C1)`` and ``(-tau, C1 +- 180)`` with
``tau = phi in [0, 180]``. At the poles (t = +-Z) the rotary angle is free: it is set to 0 (or
the travel limit nearest 0), and at t = +Z the two solutions coincide, so only one is counted.
A continuous rotary angle is reported in [-180, 180); a limited one is the 360-degree wrap within
travel nearest 0. Angles within :data:`ANGLE_TOL_DEG` of a travel limit (inside or outside) count
as within travel and are set exactly onto the limit.

Only rotary travel is checked here (Makki Fig. 4b). The translational travel (Fig. 4c) needs the
part placement and the tool length: :mod:`planning.visibility.travel` checks it per (point, axis) pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planning.errors import ParameterError
from schemas.machine import MachineProfile, available_profiles, load_profile

__all__ = [
    "ANGLE_TOL_DEG",
    "as_profile",
    "MachineProfile",
    "MachineVisibility",
    "RotarySolutions",
    "available_profiles",
    "choose_rotary",
    "load_profile",
    "machine_visibility",
    "part_to_machine_rotation",
    "part_to_tool_rotation",
    "solve_rotary",
    "tool_axis_from_angles",
]

#: Angles within this many degrees of a travel limit are accepted and set exactly onto the limit,
#: so that grid axes lying exactly on a limit (phi = 120 on a B -35..+120 trunnion) are feasible.
ANGLE_TOL_DEG = 1e-9

# Horizontal component below which an axis is taken as a pole (rotary angle free). The forward
# kinematics of the returned angles then differs from the axis by at most this much.
_POLE_TOL = 1e-12

# Accepted deviation of the norm of a supplied axis from 1 (the axis is then normalised).
_UNIT_TOL = 1e-6

# 360-degree wraps tried for a limited rotary axis (travel limits lie within [-720, 720]).
_WRAPS = np.arange(-3, 4, dtype=np.float64) * 360.0



@dataclass(frozen=True)
class RotarySolutions:
    """Inverse-kinematics solutions for m tool axes (Makki §2.2.2).

    ``angles_deg`` (m, 2, 2) float64: for axis i and solution j, ``(tilt_deg, rotary_deg)``.
    Solution 0 has tilt >= 0, solution 1 the mirrored tilt <= 0 with the rotary angle 180 degrees
    away. Always finite; where a solution is out of travel, its angles are the ones that would be
    needed. ``valid`` (m, 2) bool: the solution exists (not a duplicate at the +Z pole) and lies
    within the tilt and rotary travel.
    """

    angles_deg: np.ndarray
    valid: np.ndarray

    @property
    def n_solutions(self) -> np.ndarray:
        """(m,) int: number of valid solutions per axis (0, 1 or 2)."""
        return self.valid.sum(axis=1)


@dataclass(frozen=True)
class MachineVisibility:
    """Machine visibility of m candidate axes (Makki §2.2.2, Fig. 4b).

    ``feasible`` (m,) bool: some rotary position within travel presents the axis to the spindle.
    ``angles_deg`` (m, 2): the chosen ``(tilt_deg, rotary_deg)`` (:func:`choose_rotary`), NaN where
    infeasible. ``n_solutions`` (m,) int: valid solutions (0, 1, 2). ``solutions``: all of them.
    ``axis_names``: machine names of (tilt, rotary), e.g. ``('B', 'C')``.
    """

    feasible: np.ndarray
    angles_deg: np.ndarray
    n_solutions: np.ndarray
    solutions: RotarySolutions
    axis_names: tuple[str, str]


# ----------------------------------------------------------------------------------------------
# helpers


def as_profile(profile) -> MachineProfile:
    if profile is None:
        raise ParameterError("a machine profile is required", parameter="machine.profile")
    return load_profile(profile)


def _as_axes(axes) -> np.ndarray:
    a = np.asarray(axes, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3:
        raise ParameterError(f"tool axes must be an (m, 3) array of unit vectors, got shape {np.shape(axes)}",
                             parameter="axes")
    if not np.all(np.isfinite(a)):
        raise ParameterError("tool axes contain NaN or infinite values", parameter="axes")
    norms = np.linalg.norm(a, axis=1)
    bad = np.abs(norms - 1.0) > _UNIT_TOL
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ParameterError(f"tool axis {i} has norm {norms[i]:.9g}; tool axes must be unit vectors",
                             parameter="axes")
    return a / norms[:, None]


def _as_angles(angles_deg) -> np.ndarray:
    a = np.asarray(angles_deg, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 2:
        raise ParameterError(f"rotary angles must be an (m, 2) array of (tilt_deg, rotary_deg), got shape "
                             f"{np.shape(angles_deg)}", parameter="angles_deg")
    if not np.all(np.isfinite(a)):
        raise ParameterError("rotary angles contain NaN or infinite values", parameter="angles_deg")
    return a


def _rot(axis: str, a_rad: np.ndarray) -> np.ndarray:
    """(m,3,3) active right-hand rotations by ``a_rad`` about machine ``axis`` ('x', 'y' or 'z')."""
    c, s = np.cos(a_rad), np.sin(a_rad)
    out = np.zeros(np.shape(c) + (3, 3))
    i, j = {"x": (1, 2), "y": (2, 0)}.get(axis, (0, 1))     # the plane turned: i to j
    k = 3 - i - j
    out[..., k, k] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def _tilt_axis(profile: MachineProfile) -> str:
    return "x" if profile.kinematics.endswith("_ac") else "y"


def _snap(a_deg: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Angles within ANGLE_TOL_DEG of a travel limit (either side) set exactly onto it."""
    a = np.where(np.abs(a_deg - lo) <= ANGLE_TOL_DEG, lo, a_deg)
    return np.where(np.abs(a - hi) <= ANGLE_TOL_DEG, hi, a)


def _wrap180(a_deg: np.ndarray) -> np.ndarray:
    """Angles wrapped into [-180, 180) degrees."""
    w = np.mod(a_deg + 180.0, 360.0) - 180.0
    return np.where(w >= 180.0, w - 360.0, w) + 0.0


# ----------------------------------------------------------------------------------------------
# forward kinematics


def part_to_machine_rotation(angles_deg, profile) -> np.ndarray:
    """(m,3,3) rotations mapping PART-frame vectors to the MACHINE frame (Makki §2.2.2 machine model).

    ``angles_deg`` (m,2) or (2,): ``(tilt_deg, rotary_deg)`` in degrees. Table-table:
    ``R_tilt(tilt) @ R_z(rotary)`` (the part turns with the C table on the A/B trunnion); head-head:
    the identity (the part is fixed). Travel limits are not checked.
    """
    p = as_profile(profile)
    a = _as_angles(angles_deg)
    if not p.is_table_table:
        return np.broadcast_to(np.eye(3), (a.shape[0], 3, 3)).copy()
    Rt = _rot(_tilt_axis(p), np.radians(a[:, 0]))
    r = np.radians(a[:, 1])
    cr, sr = np.cos(r)[:, None], np.sin(r)[:, None]
    # R_tilt @ R_z(rotary), its columns written out (R_z mixes only the first two): the same numbers as
    # the matrix product, without a stack of 3x3 products (the 5-axis posts ask it for every posted point)
    M = np.empty_like(Rt)
    M[:, :, 0] = Rt[:, :, 0] * cr + Rt[:, :, 1] * sr
    M[:, :, 1] = Rt[:, :, 1] * cr - Rt[:, :, 0] * sr
    M[:, :, 2] = Rt[:, :, 2]
    return M + 0.0


def part_to_tool_rotation(angles_deg, profile) -> np.ndarray:
    """(m,3,3) rotations mapping PART-frame vectors to a frame whose +Z is the tool axis (set-up frame).

    ``angles_deg`` (m,2) or (2,), degrees. Table-table: the part-to-machine rotation (the spindle is
    machine +Z). Head-head: ``(R_z(rotary) @ R_tilt(tilt))^T``. In both, the tool axis
    :func:`tool_axis_from_angles` maps to +Z, as the 3-axis paths of a set-up need (docs/design.md stage 7;
    Makki §2.2.2). Travel limits are not checked.
    """
    p = as_profile(profile)
    if p.is_table_table:
        return part_to_machine_rotation(angles_deg, p)
    a = _as_angles(angles_deg)
    tilt_rad, rotary_rad = np.radians(a[:, 0]), np.radians(a[:, 1])
    head = _rot("z", rotary_rad) @ _rot(_tilt_axis(p), tilt_rad)
    return np.swapaxes(head, -1, -2)


def tool_axis_from_angles(angles_deg, profile) -> np.ndarray:
    """Forward kinematics: (m,3) unit tool axes in the PART frame for rotary positions (Makki §2.2.2).

    ``angles_deg`` (m,2) or (2,): ``(tilt_deg, rotary_deg)`` in degrees. Table-table:
    ``t = R_z(-rotary) @ R_tilt(-tilt) @ +Z`` (so that ``R @ t = +Z``); head-head:
    ``t = R_z(rotary) @ R_tilt(tilt) @ +Z``. Travel limits are not checked.
    """
    p = as_profile(profile)
    a = _as_angles(angles_deg)
    tilt_rad, rotary_rad = np.radians(a[:, 0]), np.radians(a[:, 1])
    if p.is_table_table:
        m = _rot("z", -rotary_rad) @ _rot(_tilt_axis(p), -tilt_rad)
    else:
        m = _rot("z", rotary_rad) @ _rot(_tilt_axis(p), tilt_rad)
    return m[:, :, 2].copy()


# ----------------------------------------------------------------------------------------------
# inverse kinematics and machine visibility


def solve_rotary(axes, profile) -> RotarySolutions:
    """All rotary positions presenting each tool axis to the spindle (inverse kinematics, Makki §2.2.2).

    ``axes`` (m,3) or (3,): unit tool axes in the part frame. Returns :class:`RotarySolutions` with
    ``angles_deg`` (m,2,2) in degrees: solution 0 = ``(tau, C1)``, solution 1 = ``(-tau, C1 +- 180)``
    where tau = phi in [0, 180] is the polar angle of the axis. A continuous rotary angle lies in
    [-180, 180); a limited one is the 360-degree wrap (up to +-1080) inside the travel that is
    nearest to 0 (the travel limit nearest 0 when 0 is outside). At the poles the rotary angle is
    free and set to 0 (or that nearest limit); at +Z solution 1 duplicates solution 0 and is marked
    invalid. ``valid`` is True where the solution lies within tilt and rotary travel (tolerance
    :data:`ANGLE_TOL_DEG`, snapped onto the limit). Vectorised over m.
    """
    p = as_profile(profile)
    t = _as_axes(axes)
    m = t.shape[0]
    tx, ty, tz = t[:, 0], t[:, 1], t[:, 2]
    h = np.hypot(tx, ty)
    pole = h <= _POLE_TOL
    tau = np.degrees(np.arctan2(h, tz))                       # [0, 180]
    tau = np.where(pole, np.where(tz > 0, 0.0, 180.0), tau)
    theta = np.degrees(np.arctan2(ty, tx))                    # azimuth of the axis

    # C for the positive tilt: C = sigma * (theta - alpha), see the module docstring table.
    table = p.is_table_table
    sigma = -1.0 if table else 1.0
    if _tilt_axis(p) == "x":
        alpha = -90.0 * sigma
    else:
        alpha = 0.0 if sigma > 0 else 180.0
    c_pos = sigma * (theta - alpha)
    c_neg = c_pos - 180.0 * sigma

    tilt = np.stack([tau, -tau], axis=1)                      # (m,2)
    rot = _wrap180(np.stack([c_pos, c_neg], axis=1))          # (m,2)

    if p.rotary_continuous:
        target = 0.0
        rot = np.where(pole[:, None], target, rot)
        rot_ok = np.ones((m, 2), dtype=bool)
    else:
        rmin, rmax = float(p.rotary_min_deg), float(p.rotary_max_deg)
        target = min(max(0.0, rmin), rmax)
        rot = np.where(pole[:, None], target, rot)
        cand = rot[:, :, None] + _WRAPS                       # (m,2,7)
        inside = (cand >= rmin - ANGLE_TOL_DEG) & (cand <= rmax + ANGLE_TOL_DEG)
        dist = np.abs(cand - target)
        # nearest to target among the wraps inside the travel; if none, nearest overall
        key = np.where(inside, dist, np.inf)
        best_in = np.argmin(key, axis=2)
        best_any = np.argmin(dist, axis=2)
        rot_ok = inside.any(axis=2)
        pick = np.where(rot_ok, best_in, best_any)
        rot = np.take_along_axis(cand, pick[:, :, None], axis=2)[:, :, 0]
        rot = np.where(rot_ok, _snap(np.clip(rot, rmin, rmax), rmin, rmax), rot)

    tmin, tmax = float(p.tilt_min_deg), float(p.tilt_max_deg)
    tilt_ok = (tilt >= tmin - ANGLE_TOL_DEG) & (tilt <= tmax + ANGLE_TOL_DEG)
    tilt = np.where(tilt_ok, _snap(np.clip(tilt, tmin, tmax), tmin, tmax), tilt)

    valid = tilt_ok & rot_ok
    north = pole & (tz > 0)
    valid[:, 1] &= ~north                                      # duplicate of solution 0 at +Z
    tilt = tilt + 0.0
    angles = np.stack([tilt, rot + 0.0], axis=2)               # (m,2,2)
    return RotarySolutions(angles_deg=angles, valid=valid)


def choose_rotary(solutions: RotarySolutions, profile=None) -> tuple[np.ndarray, np.ndarray]:
    """Pick one rotary position per axis among the valid solutions (Makki §2.2.2).

    Rule, lexicographic: smallest ``|tilt|`` (within :data:`ANGLE_TOL_DEG`), then ``tilt >= 0``, then
    ``|rotary|`` closest to 0, then solution 0. As both solutions of an axis have the same ``|tilt|``,
    in practice: the positive-tilt solution when it is within travel, else the negative one.
    Returns ``(angles_deg (m,2), feasible (m,))``: ``(tilt_deg, rotary_deg)`` in degrees, NaN where
    no solution is valid. ``profile`` is accepted for symmetry and validated when given.
    """
    if profile is not None:
        as_profile(profile)
    ang = np.asarray(solutions.angles_deg, dtype=np.float64)
    valid = np.asarray(solutions.valid, dtype=bool)
    t0, t1 = np.abs(ang[:, 0, 0]), np.abs(ang[:, 1, 0])
    r0, r1 = np.abs(ang[:, 0, 1]), np.abs(ang[:, 1, 1])
    n0, n1 = ang[:, 0, 0] < 0, ang[:, 1, 0] < 0
    tie_t = np.abs(t1 - t0) <= ANGLE_TOL_DEG
    one_better = np.where(
        ~tie_t, t1 < t0,
        np.where(n0 != n1, n0 & ~n1, r1 < r0 - ANGLE_TOL_DEG))
    take1 = valid[:, 1] & (~valid[:, 0] | one_better)
    chosen = np.where(take1[:, None], ang[:, 1, :], ang[:, 0, :])
    feasible = valid.any(axis=1)
    chosen = np.where(feasible[:, None], chosen, np.nan)
    return chosen, feasible


def machine_visibility(axes, profile) -> MachineVisibility:
    """Machine visibility of candidate axes (Makki 2010 §2.2.2, Fig. 4b): which lie within rotary travel.

    ``axes`` (m,3) unit tool axes in the part frame; ``profile`` a :class:`MachineProfile`, a bundled
    profile name or a profile JSON path. Returns :class:`MachineVisibility`: ``feasible`` (m,),
    chosen ``angles_deg`` (m,2) ``(tilt_deg, rotary_deg)`` in degrees (NaN where infeasible, rule of
    :func:`choose_rotary`), ``n_solutions`` (m,). Translational travel (Fig. 4c) is not checked here.
    """
    p = as_profile(profile)
    sols = solve_rotary(axes, p)
    chosen, feasible = choose_rotary(sols, p)
    return MachineVisibility(feasible=feasible, angles_deg=chosen, n_solutions=sols.n_solutions,
                             solutions=sols, axis_names=p.axis_names)
