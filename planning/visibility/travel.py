"""Translational travel: can the linear axes put the tool there? (Makki 2010 §2.2.2, Fig. 4c).

Machine visibility (:mod:`planning.orientations.kinematics`, Fig. 4b) only asks whether the rotary axes can present
the part to the spindle along a tool axis. Once the part is placed on the table and the tool length
is known, a (point, orientation) pair is feasible only if the machine's X/Y/Z axes can also bring
the tool to it: the position of the machine's **controlled point** needed to put the ball centre at
``c`` with the tool axis ``t`` must lie within the X/Y/Z limits of the
:class:`~schemas.machine.MachineProfile` (Makki Fig. 4c, where a long tool or a large part makes
otherwise visible orientations unreachable).

The frames (part, table, machine), the controlled point of each kind of machine and the affine map
``position = A_j c + b_j`` from a ball centre ``c`` to it are described and computed in
:mod:`planning.orientations.positions` (:func:`~planning.orientations.positions.machine_position_affine`);
this module only holds those positions against the profile's X/Y/Z limits, vectorised and
memory-bounded.

A position is within travel when ``min - tol <= x <= max + tol`` on all three axes with
``tol = TRAVEL_TOL_MM`` (1e-6 mm, for floating-point rounding only; it is not a machining margin).
Only the cutting position itself is checked, not the approach / retract moves or the tool change.
"""

from __future__ import annotations

import numpy as np

from planning.errors import ParameterError
from planning.orientations.kinematics import as_profile, tool_axis_from_angles
from planning.orientations.positions import as_angles_deg, as_points_mm, machine_position_affine
from schemas.machine import MachineProfile

__all__ = ["TRAVEL_TOL_MM", "travel_feasible"]

#: Tolerance of the travel limits, mm: positions up to this far outside a limit count as inside.
TRAVEL_TOL_MM = 1e-6

# Supplied tool axes must match the forward kinematics of the supplied angles within this.
_AXIS_MATCH_TOL = 1e-6

# Largest number of (point, axis) values evaluated at once per coordinate (float64: 32 MB).
_CHUNK_ELEMS = 1 << 22


# ----------------------------------------------------------------------------------------------
# input checks


def _check_axes(axes, angles: np.ndarray, profile: MachineProfile) -> None:
    """Supplied (m,3) axes must be the forward kinematics of the finite (m,2) angles."""
    t = as_points_mm(axes, "axes")
    if t.shape[0] != angles.shape[0]:
        raise ParameterError(f"{t.shape[0]} tool axes but {angles.shape[0]} rotary positions", parameter="axes")
    fin = np.all(np.isfinite(angles), axis=1)
    if not fin.any():
        return
    t = t[fin] / np.linalg.norm(t[fin], axis=1)[:, None]
    err = np.linalg.norm(t - tool_axis_from_angles(angles[fin], profile), axis=1)
    if np.any(err > _AXIS_MATCH_TOL):
        i = int(np.flatnonzero(fin)[np.argmax(err)])
        raise ParameterError(f"tool axis {i} does not match its rotary angles {angles[i].tolist()} "
                             f"(deviation {err.max():.3g}); pass the angles machine_visibility chose for these axes",
                             parameter="angles_deg")



def travel_feasible(centres, axes, angles_deg, profile, *, placement_mm, tool_radius_mm: float,
                    gauge_length_mm: float, candidates=None, tol_mm: float = TRAVEL_TOL_MM) -> np.ndarray:
    """Translational travel check (Makki 2010 §2.2.2, Fig. 4c): (n, m) bool.

    True where the controlled point needed to put the ball centre ``centres[i]`` (part frame, mm)
    on the tool axis ``axes[j]`` at rotary position ``angles_deg[j]`` lies within the profile's
    X, Y and Z limits (:attr:`MachineProfile.linear_limits_mm`), each widened by ``tol_mm``
    (default :data:`TRAVEL_TOL_MM`). ``axes`` (m,3) must be the forward kinematics of
    ``angles_deg`` (checked to 1e-6; the positions are computed from the angles); columns whose
    angles are NaN (rotary-infeasible axes) are all False. ``candidates`` (n,m) bool, optional:
    only those pairs are evaluated, the others are False. Other arguments as in
    :func:`machine_positions`.

    Memory is bounded (chunks of about 4M values per coordinate); a column whose bounding-box image
    lies wholly inside (or outside) a limit is decided without evaluating its points.
    """
    p = as_profile(profile)
    c = as_points_mm(centres, "centres")
    ang = as_angles_deg(angles_deg)
    _check_axes(axes, ang, p)
    n, m = c.shape[0], ang.shape[0]
    tol = float(tol_mm)
    if not (np.isfinite(tol) and tol >= 0):
        raise ParameterError(f"tol_mm = {tol_mm!r}: must be >= 0", parameter="tol_mm")
    cand = None
    if candidates is not None:
        cand = np.asarray(candidates, dtype=bool)
        if cand.shape != (n, m):
            raise ParameterError(f"candidates must be ({n}, {m}) bool, got shape {cand.shape}",
                                 parameter="candidates")
    A, b = machine_position_affine(ang, p, placement_mm=placement_mm, tool_radius_mm=tool_radius_mm,
                                   gauge_length_mm=gauge_length_mm)
    out = np.zeros((n, m), dtype=bool)
    active = np.all(np.isfinite(ang), axis=1)
    if cand is not None:
        active &= cand.any(axis=0)
    if n == 0 or not active.any():
        return out
    lims = np.asarray(p.linear_limits_mm, dtype=np.float64)          # (3,2)

    # Range of each coordinate over the bounding box of the centres: decides whole columns.
    cmin, cmax = c.min(axis=0), c.max(axis=0)
    lo_box = np.einsum("mkd,d->mk", np.minimum(A * cmin, A * cmax), np.ones(3)) + b   # (m,3)
    hi_box = np.einsum("mkd,d->mk", np.maximum(A * cmin, A * cmax), np.ones(3)) + b
    half = 0.5 * tol
    inside_all = (lo_box >= lims[:, 0] - half) & (hi_box <= lims[:, 1] + half)       # (m,3)
    outside_all = (hi_box < lims[:, 0] - 1.5 * tol) | (lo_box > lims[:, 1] + 1.5 * tol)
    inside_all[~active] = False
    outside_all[~active] = True

    dead = outside_all.any(axis=1)                                     # every point out of travel
    whole = active & ~dead & inside_all.all(axis=1)                    # every point within travel
    out[:, whole] = True
    mixed = np.flatnonzero(active & ~dead & ~whole)
    step = max(1, _CHUNK_ELEMS // n)
    for s in range(0, len(mixed), step):
        cols = mixed[s:s + step]
        ok = np.ones((n, len(cols)), dtype=bool)
        for k in range(3):
            sel = ~inside_all[cols, k]
            if not sel.any():
                continue
            jj = cols[sel]
            v = c @ A[jj, k, :].T
            v += b[jj, k]
            ok[:, sel] &= (v >= lims[k, 0] - tol) & (v <= lims[k, 1] + tol)
        out[:, cols] = ok
    if cand is not None:
        out &= cand
    return out
