"""Arc geometry of the posts (docs/design.md stage 8, post-processing), area or program frame, mm and
radians: the principal plane an arc's normal lands on in a program frame (:func:`principal_plane`),
the chord points of a linearised arc (:func:`arc_chord_points`, and :func:`_chord_points` for many
arcs at once in the whole-array motion blocks), the radius that ``PostOptions.max_arc_radius_mm``
bounds (:func:`arc_radius_mm`), and the safe height of an operation (:func:`safe_height_mm`: its
highest tip, an arc that passes over the top of its circle counted there).

Approach and retract (safe height)
----------------------------------
Each operation starts with one rapid to the point straight above the path's first point at the
safe height ``z_safe = max(safe_z_mm, highest tip z of the operation)`` (area frame, mm; the frame's
origin lies at the top of the whole cloud along the tool axis, so ``safe_z_mm > 0`` clears the
part), then follows the path (its move 0 comes down from there). It ends with a rapid straight up
along the tool axis to ``z_safe``. Before the first plunge no rapid is therefore below the path's
own first point.
"""

from __future__ import annotations

import math

import numpy as np

from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    PLANE_AXES,
    PLANE_XY,
    PLANE_YZ,
    PLANE_ZX,
    arc_sweep_rad,
)

from .options import Operation, PostOptions

__all__ = ["ARC_PLANE_TOL", "arc_chord_points", "arc_radius_mm", "principal_plane", "safe_height_mm"]

#: An arc is emitted as G2/G3 only when its plane's normal, mapped into the program frame, lies
#: within this distance (per component, unit vector) of a principal axis.
ARC_PLANE_TOL = 1e-9

#: In-plane axes (first, second) and normal axis of each arc plane code, as arrays indexed by the
#: code (PLANE_AXES as lookup tables for whole arrays of planes).
_AX_A, _AX_B, _AX_N = (np.zeros(PLANE_YZ + 1, dtype=np.int64) for _ in range(3))
for _p, (_a, _b, _n) in PLANE_AXES.items():
    _AX_A[_p], _AX_B[_p], _AX_N[_p] = _a, _b, _n
del _p, _a, _b, _n


def safe_height_mm(op: Operation, options: PostOptions) -> float:
    """Approach / retract height in the area frame, mm: ``max(safe_z_mm, highest tip z)``, where a
    ``G18`` / ``G19`` arc counts the top of its circle (centre z + the larger of its start and end
    radii) only when its swept angle contains that top (:func:`_arc_top_mm`); otherwise its end
    points are its highest points and are counted with the other tips.

    Whole arrays: a bound from above of every arc's top (numpy's arctan2 / hypot, with margins for
    their last bits) picks the arcs that may raise the height; those are settled, highest bound first,
    by the scalar :func:`_arc_top_mm`, so the result is exactly :func:`_reference_safe_height_mm`'s."""
    tp = op.toolpath
    top = float(tp.tip_mm()[:, 2].max())
    arcs = np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)) & (tp.plane != PLANE_XY))
    if arcs.size:
        a, b = _AX_A[tp.plane[arcs]], _AX_B[tp.plane[arcs]]
        c = tp.centre_mm[arcs]
        rows = np.arange(arcs.size)
        d = [(tp.xyz_mm[j, a] - c[rows, a], tp.xyz_mm[j, b] - c[rows, b]) for j in (arcs - 1, arcs)]
        ccw = tp.kind[arcs] == ARC_CCW
        two_pi = 2 * math.pi
        t0 = np.arctan2(d[0][1], d[0][0])
        t1 = np.arctan2(d[1][1], d[1][0])
        sw = np.abs(np.where(ccw, np.mod(t1 - t0, two_pi), np.mod(t0 - t1, two_pi)))
        sw[sw == 0.0] = two_pi
        t_top = np.where(a == 2, 0.0, math.pi / 2)            # G18: (Z, X), z = r cos t; G19: (Y, Z), z = r sin t
        ang = np.where(ccw, np.mod(t_top - t0, two_pi), np.mod(t0 - t_top, two_pi))
        # the top may be swept (a superset of the scalar decision: angles within 1e-9 of a wrap or an end)
        maybe = (ang <= sw + 1e-9) | (ang >= two_pi - 1e-9) | (np.minimum(sw, two_pi - sw) < 1e-9)
        k = np.flatnonzero(maybe)
        bound = (c[k, 2] - tp.tip_offset_mm) + np.maximum(np.hypot(d[0][0][k], d[0][1][k]),
                                                          np.hypot(d[1][0][k], d[1][1][k]))
        bound += 1e-9 * (np.abs(bound) + 1.0)
        for j in np.argsort(-bound, kind="stable"):
            if not bound[j] > top:
                break
            i = int(arcs[k[j]])
            v = _arc_top_mm(tp.xyz_mm[i - 1], tp.xyz_mm[i], tp.centre_mm[i], int(tp.plane[i]),
                            bool(tp.kind[i] == ARC_CCW), tp.tip_offset_mm)
            if v is not None:
                top = max(top, v)
    return max(float(options.safe_z_mm), top)


def _reference_safe_height_mm(op: Operation, options: PostOptions) -> float:
    """:func:`safe_height_mm` one arc at a time (the tests' reference)."""
    tp = op.toolpath
    top = float(tp.tip_mm()[:, 2].max())
    for i in np.flatnonzero(np.isin(tp.kind, (ARC_CW, ARC_CCW)) & (tp.plane != PLANE_XY)):
        v = _arc_top_mm(tp.xyz_mm[i - 1], tp.xyz_mm[i], tp.centre_mm[i], int(tp.plane[i]),
                        bool(tp.kind[i] == ARC_CCW), tp.tip_offset_mm)
        if v is not None:
            top = max(top, v)
    return max(float(options.safe_z_mm), top)


def _arc_top_mm(start, end, centre, plane: int, ccw: bool, tip_offset_mm: float = 0.0) -> float | None:
    """The tip height of the highest point of one ``G18`` / ``G19`` arc's circle, ``centre z -
    tip_offset_mm + max(start radius, end radius)`` (mm, area frame), when the arc's swept angle
    (:func:`~planning.toolpath.moves.arc_sweep_rad`, in the direction of travel from the start)
    contains the circle's highest point; None otherwise (and for ``G17``, whose z varies linearly):
    the arc then rises nowhere above its end points. (A spiral, whose start and end radii differ by
    the fitting tolerance, may rise above its end points by at most that difference.)"""
    a, b, _ = PLANE_AXES[int(plane)]
    if a != 2 and b != 2:
        return None
    s, e, c = (np.asarray(v, dtype=np.float64) for v in (start, end, centre))
    t0, sw, r0 = arc_sweep_rad(s, e, c, plane, ccw)
    t_top = 0.0 if a == 2 else math.pi / 2
    ang = (t_top - t0) % (2 * math.pi) if ccw else (t0 - t_top) % (2 * math.pi)
    if ang > abs(sw):
        return None
    r1 = math.hypot(e[a] - c[a], e[b] - c[b])
    return float(c[2] - tip_offset_mm + max(r0, r1))


def arc_radius_mm(start, end, centre, plane: int) -> float:
    """The larger of an arc's start and end radii in its plane (area frame, mm): what
    ``PostOptions.max_arc_radius_mm`` bounds."""
    a, b, _ = PLANE_AXES[int(plane)]
    return max(math.hypot(start[a] - centre[a], start[b] - centre[b]),
               math.hypot(end[a] - centre[a], end[b] - centre[b]))


def _large_arcs(s: np.ndarray, e: np.ndarray, c: np.ndarray, plane: np.ndarray, limit_mm: float) -> np.ndarray:
    """:func:`arc_radius_mm` ``> limit_mm`` for k arcs at once (start, end, centre (k,3), plane codes):
    bool (k,), exactly the scalar decision (np.hypot may differ from math.hypot in the last bit,
    so the radii near the limit are settled with :func:`arc_radius_mm`)."""
    rows = np.arange(s.shape[0])
    a, b = _AX_A[plane], _AX_B[plane]
    r = np.maximum(np.hypot(s[rows, a] - c[rows, a], s[rows, b] - c[rows, b]),
                   np.hypot(e[rows, a] - c[rows, a], e[rows, b] - c[rows, b]))
    big = r > limit_mm
    for j in np.flatnonzero(np.abs(r - limit_mm) <= 1e-9 * limit_mm):
        big[j] = arc_radius_mm(s[j], e[j], c[j], int(plane[j])) > limit_mm
    return big


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
