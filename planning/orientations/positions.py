"""Machine positions: where the linear axes must put the controlled point (Makki 2010 §2.2.2, Fig. 4c).

Part of the kinematics (:mod:`planning.orientations.kinematics` gives the rotations): the part's
placement on the table and the affine map from a ball centre to the machine X/Y/Z of the
controlled point. Travel (:mod:`planning.visibility.travel`) and the posts call these; they call
neither.

Why it matters (Makki Fig. 4c): once the part is placed on the table and the tool length is
known, a (point, orientation) pair is feasible only if the X/Y/Z axes can bring the tool to it; a
long tool or a large part makes otherwise visible orientations unreachable.

Frames and conventions (all lengths in mm, angles in degrees; rotations as in
:mod:`planning.orientations.kinematics`)
--------------------------------------------------------------------------------------------------
* **Part frame**: the frame of the point cloud; ball centres ``c`` and tool axes ``t`` (unit, from
  the part towards the spindle) are given in it.
* **Table frame**: origin at the table-top centre, on the C axis, with every rotary axis at 0; Z
  up. The part is fixed to the table without rotation: part point ``p`` is at
  ``p + placement_mm`` (see :func:`default_placement`).
* **Machine frame**: fixed to the machine's rotary pivot, equal to the table frame when every
  rotary axis is at 0. The profile's ``x/y/z_limits_mm`` (:attr:`MachineProfile.linear_limits_mm`)
  bound the controlled point in this frame.
* Tool: ball radius ``R = tool_radius_mm``; ``G = gauge_length_mm`` is the distance from the tool
  tip to the spindle gauge line (:class:`planning.geometry.tool.ToolAssembly`). The tip is ``c - R t``.

Table-table (``table_table_ac`` / ``table_table_bc``): the C table turns the part about the table
frame's Z axis, then the trunnion tilts it about the tilt axis through ``P = profile.pivot_mm``
(``table_pivot_mm``); the spindle stays along machine +Z. A table point ``q`` is at::

    q_m = R_tilt (R_z q - P) + P          R_tilt R_z = part_to_machine_rotation(angles)

and the controlled point is the spindle gauge point, ``G`` above the tip along machine +Z. The
tool axis of these angles maps to +Z (``M t = Z``), so the tip ``c - R t`` lands ``R`` below the
ball centre and, with ``M = part_to_machine_rotation(angles)`` and
``R_tilt = part_to_machine_rotation((tilt, 0))``::

    gauge = M (c + placement) + (I - R_tilt) P + (G - R) Z

When the tilt axis meets the C axis (``P`` on it, e.g. ``[0, 0, z]``), ``R_z P = P`` and this is
``M (c + placement - P) + P + (G - R) Z``.

Head-head (``head_head_ac`` / ``head_head_bc``): the part stays put (machine frame = table frame);
the controlled point is the head's rotation centre, ``L = profile.pivot_length_mm``
(``head_pivot_length_mm``) beyond the gauge line along the tool axis
``t = tool_axis_from_angles(angles)``::

    pivot = c + placement + (G + L - R) t

Both are affine in ``c``: ``position = A_j c + b_j`` for rotary position ``j``
(:func:`machine_position_affine`), which keeps the travel check vectorised and memory-bounded.
"""

from __future__ import annotations

import numpy as np

from planning.errors import ParameterError
from planning.orientations.kinematics import as_profile, part_to_machine_rotation, tool_axis_from_angles

__all__ = [
    "DEFAULT_FIXTURE_HEIGHT_MM",
    "as_angles_deg",
    "as_points_mm",
    "default_placement",
    "machine_position_affine",
    "machine_positions",
]

#: Default height of the part's lowest point above the table top (fixture / vice), mm.
DEFAULT_FIXTURE_HEIGHT_MM = 50.0


# ----------------------------------------------------------------------------------------------
# input checks (shared with planning.visibility.travel)


def as_points_mm(a, name: str) -> np.ndarray:
    """``a`` as an (n, 3) float64 array of finite coordinates, mm (one point may be given as (3,))."""
    x = np.asarray(a, dtype=np.float64)
    if x.ndim == 1 and x.shape[0] == 3:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != 3:
        raise ParameterError(f"{name} must be an (n, 3) array, got shape {np.shape(a)}", parameter=name)
    if not np.all(np.isfinite(x)):
        raise ParameterError(f"{name} contain NaN or infinite values", parameter=name)
    return x


def as_angles_deg(a) -> np.ndarray:
    """``a`` as an (m, 2) float64 array of ``(tilt_deg, rotary_deg)``; NaN rows (infeasible axes) are kept."""
    x = np.asarray(a, dtype=np.float64)
    if x.ndim == 1 and x.shape[0] == 2:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != 2:
        raise ParameterError(f"rotary angles must be an (m, 2) array of (tilt_deg, rotary_deg), got shape "
                             f"{np.shape(a)}", parameter="angles_deg")
    if np.any(np.isinf(x)):
        raise ParameterError("rotary angles contain infinite values", parameter="angles_deg")
    return x


def _vec3(a, name: str) -> np.ndarray:
    x = np.asarray(a, dtype=np.float64)
    if x.shape != (3,) or not np.all(np.isfinite(x)):
        raise ParameterError(f"{name} must be 3 finite numbers (mm), got {a!r}", parameter=name)
    return x


def _tool(tool_radius_mm, gauge_length_mm) -> tuple[float, float]:
    R, G = float(tool_radius_mm), float(gauge_length_mm)
    if not (np.isfinite(R) and R >= 0):
        raise ParameterError(f"tool radius {tool_radius_mm!r} mm: must be >= 0", parameter="tool_radius_mm")
    if not (np.isfinite(G) and G >= R):
        raise ParameterError(f"gauge length {gauge_length_mm!r} mm: must be finite and at least the tool radius "
                             f"{R:g} mm", parameter="gauge_length_mm")
    return R, G



# ----------------------------------------------------------------------------------------------
# machine positions


def default_placement(points, *, fixture_height_mm: float = DEFAULT_FIXTURE_HEIGHT_MM) -> np.ndarray:
    """Default part placement on the table (Makki 2010 §2.2.2, Fig. 4c set-up): (3,) mm.

    The part is centred over the table centre in X and Y (the centre of its axis-aligned bounding
    box lies on the C axis) and its lowest point sits ``fixture_height_mm`` (default
    :data:`DEFAULT_FIXTURE_HEIGHT_MM` = 50 mm, a fixture or vice) above the table top. Returns
    ``placement_mm``: part point ``p`` is at ``p + placement_mm`` in the table frame.
    """
    p = as_points_mm(points, "points")
    if p.shape[0] == 0:
        raise ParameterError("cannot place an empty point set", parameter="points")
    h = float(fixture_height_mm)
    if not (np.isfinite(h) and h >= 0):
        raise ParameterError(f"fixture height {fixture_height_mm!r} mm: must be >= 0", parameter="fixture_height_mm")
    lo, hi = p.min(axis=0), p.max(axis=0)
    return np.array([-0.5 * (lo[0] + hi[0]), -0.5 * (lo[1] + hi[1]), h - lo[2]])


def machine_position_affine(angles_deg, profile, *, placement_mm, tool_radius_mm: float,
                            gauge_length_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Affine maps from ball centre to controlled-point position (Makki 2010 §2.2.2, Fig. 4c).

    ``angles_deg`` (m,2) or (2,): rotary positions ``(tilt_deg, rotary_deg)`` as
    ``machine_visibility(...).angles_deg`` gives them (rows with NaN, for infeasible axes, give NaN
    maps). Returns ``(A (m,3,3), b (m,3))`` such that the machine-frame X/Y/Z (mm) of the controlled
    point that puts the ball centre at part point ``c`` with the tool axis of rotary position ``j``
    is ``A[j] @ c + b[j]``. Table-table: ``A = M``, ``b = M placement + (I - R_tilt) P + (G - R) Z``
    (gauge point); head-head: ``A = I``, ``b = placement + (G + L - R) t`` (head rotation centre).
    See the module docstring for the frames.
    """
    p = as_profile(profile)
    ang = as_angles_deg(angles_deg)
    place = _vec3(placement_mm, "placement_mm")
    R, G = _tool(tool_radius_mm, gauge_length_mm)
    m = ang.shape[0]
    A = np.full((m, 3, 3), np.nan)
    b = np.full((m, 3), np.nan)
    fin = np.all(np.isfinite(ang), axis=1)
    if not fin.any():
        return A, b
    a = ang[fin]
    if p.is_table_table:
        M = part_to_machine_rotation(a, p)                                   # R_tilt R_z
        tilt_only = np.c_[a[:, 0], np.zeros(len(a))]
        R_tilt = part_to_machine_rotation(tilt_only, p)
        P = np.asarray(p.pivot_mm, dtype=np.float64)
        A[fin] = M
        b[fin] = M @ place + (P - R_tilt @ P)
        b[fin, 2] += G - R
    else:
        t = tool_axis_from_angles(a, p)
        A[fin] = np.eye(3)
        b[fin] = place + (G + p.pivot_length_mm - R) * t
    return A, b


def machine_positions(centres, angles_deg, profile, *, placement_mm, tool_radius_mm: float,
                      gauge_length_mm: float) -> np.ndarray:
    """Machine X/Y/Z of the controlled point for every ball centre and rotary position (Makki §2.2.2, Fig. 4c).

    ``centres`` (n,3): ball centres in the part frame, mm. ``angles_deg`` (m,2): ``(tilt_deg,
    rotary_deg)`` (NaN rows give NaN). ``placement_mm`` (3,): part origin in the table frame.
    ``tool_radius_mm``: ball radius R; ``gauge_length_mm``: tool tip to spindle gauge line G.
    Returns (n, m, 3) float64, mm, in the machine frame: the spindle gauge point (table-table) or
    the head rotation centre (head-head). Holds n*m*3 floats: for large inputs use
    :func:`planning.visibility.travel.travel_feasible` (chunked) or :func:`machine_position_affine`.
    """
    c = as_points_mm(centres, "centres")
    A, b = machine_position_affine(angles_deg, profile, placement_mm=placement_mm,
                                   tool_radius_mm=tool_radius_mm, gauge_length_mm=gauge_length_mm)
    return np.einsum("mij,nj->nmi", A, c) + b[None, :, :]

