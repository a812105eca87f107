"""Gouge verification of ball-end paths on a triangle mesh: :func:`mesh_move_clearance`, the mesh
twin of :func:`planning.toolpath.verify.move_clearance` (which measures against cloud points).

The path's points are ball centres in the area frame (tool axis +Z, mm; ``Toolpath.tip_offset_mm
= R``), the mesh a :class:`planning.geometry.triangles.TriangleDropSurface` binned once (the same
object that drops the ball). A ball of radius R following a centre curve cuts into a triangle
exactly when the curve comes closer than R to it, so a move is gouge free when its value is
>= R - tol.

* RAPID / FEED: the straight segment from ``xyz_mm[i-1]`` to ``xyz_mm[i]``; exact
  segment-triangle distance (:meth:`~planning.geometry.triangles.TriangleDropSurface.clearance`).
* ARC_CW / ARC_CCW: measured by their chord, then lowered by how far the arc can stray from it,
  so the value is a lower bound of the arc's true clearance (never an over-report):
  ``w = r (1 - cos(sweep / 2)) + |dn| + |r_end - r_start|`` with ``r`` the start radius, ``sweep``
  the signed sweep (:func:`planning.toolpath.moves.arc_sweep_rad`), ``dn`` the helix rise along the
  plane's normal and the last term the radius mismatch the control tolerates. Every point of a
  planar arc lies within ``r (1 - cos(sweep / 2))`` of the chord's midpoint or its nearest chord
  point (the sagitta for sweeps up to 180 degrees; beyond, ``r + |OM|`` with ``|OM| = -r cos(sweep
  / 2)`` the centre-to-midpoint distance, the same expression); the helix and the spiral add at
  most ``|dn|`` and ``|r_end - r_start|``. Value: ``clip(chord clearance - w, 0, cutoff)``.
"""

from __future__ import annotations

import numpy as np

from planning.errors import ParameterError
from planning.geometry.triangles import TriangleDropSurface
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    PLANE_AXES,
    PLANE_XY,
    PLANE_YZ,
    PLANE_ZX,
    Toolpath,
)
from planning.toolpath.verify import _selected


def arc_widening_mm(tp: Toolpath, sel: np.ndarray) -> np.ndarray:
    """(len(sel),) how far (mm) the arc moves ``sel`` of ``tp`` can stray from their chords (module
    docstring); 0 for straight moves."""
    w = np.zeros(sel.size)
    k = tp.kind[sel]
    arcs = (k == ARC_CW) | (k == ARC_CCW)
    if not arcs.any():
        return w
    m = sel[arcs]
    pl = tp.plane[m]
    if not np.all((pl == PLANE_XY) | (pl == PLANE_ZX) | (pl == PLANE_YZ)):
        raise ParameterError(f"move {int(m[~np.isin(pl, (PLANE_XY, PLANE_ZX, PLANE_YZ))][0])}: "
                             "an arc needs plane 17, 18 or 19")
    cen = tp.centre_mm[m]
    if not np.all(np.isfinite(cen)):
        raise ParameterError("arc moves need finite centres (centre_mm)")
    ax = np.array([PLANE_AXES[int(p)] for p in pl])           # (n, 3): first, second, normal
    r_ = np.arange(m.size)
    s, e = tp.xyz_mm[m - 1], tp.xyz_mm[m]
    u0, v0 = s[r_, ax[:, 0]] - cen[r_, ax[:, 0]], s[r_, ax[:, 1]] - cen[r_, ax[:, 1]]
    u1, v1 = e[r_, ax[:, 0]] - cen[r_, ax[:, 0]], e[r_, ax[:, 1]] - cen[r_, ax[:, 1]]
    t0, t1 = np.arctan2(v0, u0), np.arctan2(v1, u1)
    ccw = tp.kind[m] == ARC_CCW
    two_pi = 2 * np.pi
    sweep = np.where(ccw, (t1 - t0) % two_pi, -((t0 - t1) % two_pi))
    sweep = np.where(sweep == 0.0, np.where(ccw, two_pi, -two_pi), sweep)   # as arc_sweep_rad
    r0, r1 = np.hypot(u0, v0), np.hypot(u1, v1)
    dn = e[r_, ax[:, 2]] - s[r_, ax[:, 2]]
    w[arcs] = r0 * (1.0 - np.cos(sweep / 2.0)) + np.abs(dn) + np.abs(r1 - r0)
    return w


def mesh_move_clearance(tp: Toolpath, surface: TriangleDropSurface, *, moves=None,
                        cutoff_mm: float | None = None) -> np.ndarray:
    """Per move of ``tp`` (ball centres, area frame, mm): the smallest distance (mm) from the
    move's ball-centre curve to the triangles of ``surface``, ``min(distance, cutoff_mm)`` (default
    the surface's R). Straight moves exactly; arcs by their chord widened as the module docstring
    says (a lower bound). Returns (P,) float64, NaN for the moves not measured: ``moves`` (a bool
    mask or indices; default every FEED and arc move) chooses them, and move 0 has no start; as
    :func:`planning.toolpath.verify.move_clearance`. A move is gouge free when its value is >= R - tol."""
    cut = surface.R if cutoff_mm is None else float(cutoff_mm)
    if not cut > 0:
        raise ParameterError(f"cutoff_mm = {cutoff_mm}: must be > 0 (inf for no cut-off)")
    sel = _selected(tp, moves)
    out = np.full(tp.n_moves, np.nan)
    if sel.size == 0:
        return out
    xyz = np.asarray(tp.xyz_mm, dtype=np.float64)
    if not np.all(np.isfinite(xyz[np.concatenate([sel - 1, sel])])):
        raise ParameterError("the measured moves must have finite end points")
    w = arc_widening_mm(tp, sel)
    arc = w > 0
    got = np.empty(sel.size)
    if (~arc).any():
        s = sel[~arc]
        got[~arc] = surface.clearance(xyz[s - 1], xyz[s], cut)
    if arc.any():
        s = sel[arc]
        d = surface.clearance(xyz[s - 1], xyz[s], cut + float(w[arc].max()))
        got[arc] = np.clip(d - w[arc], 0.0, cut)
    out[sel] = got
    return out


__all__ = ["arc_widening_mm", "mesh_move_clearance"]
