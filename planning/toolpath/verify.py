"""Gouge verification of ball-end paths on the cloud: the smallest distance from any cloud point to
the ball-centre curve of each move (issue 5: "after every transformation, no CL point and no
interpolated segment comes closer than R - tol to any cloud point; a verification step measures
the minimal clearance of the final paths"). Sood 2015 §4.4 reduces CL points without checking
gouging (docs/design.md "Papers"); this is the check every reduction here is held to.

Everything in the area frame (tool axis +Z, mm). The path's points are taken as ball centres
(ball-end finishing records ball centres, ``Toolpath.tip_offset_mm = R``); a path recorded at
another reference point must be shifted first. A ball of radius R following a centre curve
removes exactly the points closer than R to that curve, so a move is gouge free when its
clearance (that distance) is >= R - tol.

The centre curve of move i runs from ``xyz_mm[i-1]`` to ``xyz_mm[i]``:

* RAPID / FEED: the straight segment; exact point-to-segment distance.
* ARC_CW / ARC_CCW: the circle about ``centre_mm[i]`` in the plane ``plane[i]`` through the start
  (:data:`planning.toolpath.moves.PLANE_AXES`), of the START radius, swept as
  :func:`planning.toolpath.moves.arc_sweep_rad` says; when the end's normal coordinate differs from
  the start's the curve is the helix that rises linearly with the angle (as
  :func:`planning.toolpath.moves.densify` and a control interpolate). The distance is exact for
  circular arcs and helices (planar arcs in closed form; a helix by the at most two intervals on
  which the squared distance is convex, its stationary point there found by bisection to machine
  precision). Where the end is not equidistant from the centre (a fitting tolerance; controls
  accept a small mismatch), ``|r_end - r_start|`` is subtracted: a lower bound, never an
  over-report, of the distance to the spiral :func:`~planning.toolpath.moves.densify` draws.

Cut-off: only what can gouge matters, so a move's value is ``min(true distance, cutoff_mm)``
(default ``cutoff_mm = R``: a move reported at R has no point closer than R). ``cutoff_mm = inf``
gives the exact distance to the nearest point of the whole cloud (slow: every point is a candidate).

Candidates come from a square xy raster of the points (:func:`planning.geometry.raster.bin_cells`, cells
of ``cell_mm``, default R/4, with each cell's lowest and highest z): for each move, the cells its
xy bounding box grown by the cut-off touches; a cell is skipped when the distance between its box
(cell square x [z_min, z_max]) and the move's bounding box, or the distance from the box's centre
to the curve less the box's half diagonal, cannot beat the best distance found so far; the others
are scanned point by point. Compiled with numba, parallel over moves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from planning.errors import ParameterError
from planning.geometry.kernels import interval_gap as _gap
from planning.geometry.kernels import serial_twin
from planning.geometry.raster import bin_cells, rows_in_order
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    PLANE_XY,
    PLANE_YZ,
    PLANE_ZX,
    Toolpath,
)

_TWO_PI = 2.0 * math.pi

# A move is one row of a float table F and an int table I (built by _fill_line / _fill_arc):
# F: start xyz, end xyz, centre (u, v) in the arc plane, start's normal coordinate, start angle,
#    signed sweep (rad), start radius, rise along the normal, |r_end - r_start|, bbox lo xyz, hi xyz.
# I: code (0 straight, 1 arc), the plane's first, second and normal axis indices.
_S, _E, _CU, _CV, _SN, _T0, _SW, _RR, _DN, _DR, _LO, _HI = 0, 3, 6, 7, 8, 9, 10, 11, 12, 13, 14, 17
_NF = 20
_LINE, _ARC = 0, 1


# ------------------------------------------------------------------------------------ geometry

@njit(cache=True, nogil=True)
def _mod2pi(x):
    """x mod 2 pi in [0, 2 pi)."""
    r = x - _TWO_PI * math.floor(x / _TWO_PI)
    r = max(r, 0.0)
    if r >= _TWO_PI:
        r -= _TWO_PI
    return r


@njit(cache=True, nogil=True)
def _pick(x, y, z, k):
    if k == 0:
        return x
    if k == 1:
        return y
    return z


@njit(cache=True, nogil=True)
def _seg_d2(px, py, pz, sx, sy, sz, dx, dy, dz, L2):
    """Squared distance from p to the segment s + t d, t in [0, 1] (L2 = |d|^2)."""
    ex, ey, ez = px - sx, py - sy, pz - sz
    if L2 > 0.0:
        t = (ex * dx + ey * dy + ez * dz) / L2
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
        ex -= t * dx
        ey -= t * dy
        ez -= t * dz
    return ex * ex + ey * ey + ez * ez


@njit(cache=True, nogil=True)
def _helix_f(t, a0, sw, rho, r, e0, dn):
    """Squared distance at parameter t (see _arc_dist)."""
    s = math.sin(0.5 * (a0 + sw * t))
    w = e0 + dn * t
    return (rho - r) * (rho - r) + 4.0 * rho * r * s * s + w * w


@njit(cache=True, nogil=True)
def _helix_g(t, a0, sw, rho, r, e0, dn):
    """Half the derivative of _helix_f."""
    return rho * r * sw * math.sin(a0 + sw * t) + dn * (e0 + dn * t)


@njit(cache=True, nogil=True)
def _arc_dist(u, v, e0, t0, sw, r, dn):
    """Distance from a point to a circular arc or helix.

    The point is (u, v) in the arc plane relative to the centre and ``e0`` = start's normal
    coordinate minus the point's; the curve is ``r (cos th, sin th)`` for th = t0 + sw t, t in
    [0, 1], at normal coordinate start + dn t. Planar arcs (dn == 0) in closed form. Helices: the
    squared distance f(t) = (rho - r)^2 + 4 rho r sin^2(alpha / 2) + (e0 + dn t)^2 with
    alpha = th - phi has f''/2 = rho r sw^2 cos(alpha) + dn^2, which changes sign at most twice
    over a sweep below 2 pi: f is convex on at most two intervals, and its minimum is an end, a
    sign change of f'', or the single zero of the monotone f' on a convex interval (bisection).
    """
    rho = math.sqrt(u * u + v * v)
    phi = math.atan2(v, u) if rho > 0.0 else t0
    a0 = t0 - phi
    if dn == 0.0:
        if sw > 0.0:
            inside = _mod2pi(phi - t0) <= sw
        else:
            inside = _mod2pi(t0 - phi) <= -sw
        if inside or rho == 0.0:
            return math.sqrt((rho - r) * (rho - r) + e0 * e0)
        f0 = _helix_f(0.0, a0, sw, rho, r, e0, 0.0)
        f1 = _helix_f(1.0, a0, sw, rho, r, e0, 0.0)
        return math.sqrt(min(f0, f1))
    best = min(_helix_f(0.0, a0, sw, rho, r, e0, dn), _helix_f(1.0, a0, sw, rho, r, e0, dn))
    B = rho * r * sw * sw
    t1 = -1.0
    t2 = -1.0
    if B > dn * dn:
        acos_k = math.acos(-dn * dn / B)
        for j in range(2):
            beta = acos_k if j == 0 else -acos_k
            if sw > 0.0:
                k = math.floor((a0 - beta) / _TWO_PI) + 1.0
            else:
                k = math.ceil((a0 - beta) / _TWO_PI) - 1.0
            t = (beta + _TWO_PI * k - a0) / sw
            if 0.0 < t < 1.0:
                if t1 < 0.0:
                    t1 = t
                else:
                    t2 = t
    if t2 >= 0.0 and t2 < t1:
        t1, t2 = t2, t1
    # interval ends: 0, t1, t2, 1 (the breaks that exist)
    ends = (0.0, t1, t2, 1.0)
    lo = 0.0
    for q in range(1, 4):
        hi = ends[q]
        if hi < 0.0:
            continue
        if hi > lo:
            fm = B * math.cos(a0 + sw * 0.5 * (lo + hi)) + dn * dn      # f''/2 at the middle
            if fm > 0.0:
                glo = _helix_g(lo, a0, sw, rho, r, e0, dn)
                ghi = _helix_g(hi, a0, sw, rho, r, e0, dn)
                if glo < 0.0 < ghi:
                    a, b = lo, hi
                    for _ in range(200):
                        m = 0.5 * (a + b)
                        if m <= a or m >= b:
                            break
                        if _helix_g(m, a0, sw, rho, r, e0, dn) < 0.0:
                            a = m
                        else:
                            b = m
                    best = min(best, _helix_f(a, a0, sw, rho, r, e0, dn), _helix_f(b, a0, sw, rho, r, e0, dn))
            if hi < 1.0:
                best = min(best, _helix_f(hi, a0, sw, rho, r, e0, dn))
        lo = hi
    return math.sqrt(best)


@njit(cache=True, nogil=True)
def _fill_line(F, I, row, sx, sy, sz, ex, ey, ez):
    """Describe the straight move (s -> e) in row ``row`` of F, I."""
    F[row, 0], F[row, 1], F[row, 2] = sx, sy, sz
    F[row, 3], F[row, 4], F[row, 5] = ex, ey, ez
    for k in range(6, _LO):
        F[row, k] = 0.0
    F[row, _LO], F[row, _LO + 1], F[row, _LO + 2] = min(sx, ex), min(sy, ey), min(sz, ez)
    F[row, _HI], F[row, _HI + 1], F[row, _HI + 2] = max(sx, ex), max(sy, ey), max(sz, ez)
    I[row, 0] = _LINE
    I[row, 1], I[row, 2], I[row, 3] = 0, 1, 2


@njit(cache=True, nogil=True)
def _fill_arc(F, I, row, s, e, cu, cv, ia, ib, inn, ccw):
    """Describe the arc from ``s`` to ``e`` (xyz arrays) about the centre (cu, cv) in the plane with
    axes (ia, ib; normal inn), counter-clockwise when ``ccw`` (moves.arc_sweep_rad's convention)."""
    su, sv = s[ia] - cu, s[ib] - cv
    eu, ev = e[ia] - cu, e[ib] - cv
    t0, t1 = math.atan2(sv, su), math.atan2(ev, eu)
    if ccw:
        sw = _mod2pi(t1 - t0)
        if sw == 0.0:
            sw = _TWO_PI
    else:
        sw = -_mod2pi(t0 - t1)
        if sw == 0.0:
            sw = -_TWO_PI
    r0 = math.sqrt(su * su + sv * sv)
    r1 = math.sqrt(eu * eu + ev * ev)
    dr = abs(r1 - r0)
    for k in range(3):
        F[row, _S + k] = s[k]
        F[row, _E + k] = e[k]
    F[row, _CU], F[row, _CV], F[row, _SN] = cu, cv, s[inn]
    F[row, _T0], F[row, _SW], F[row, _RR] = t0, sw, r0
    F[row, _DN], F[row, _DR] = e[inn] - s[inn], dr
    # bounding box: ends and the quadrant points inside the sweep, grown by dr
    umin, umax = min(su, eu, r0 * math.cos(t1)), max(su, eu, r0 * math.cos(t1))
    vmin, vmax = min(sv, ev, r0 * math.sin(t1)), max(sv, ev, r0 * math.sin(t1))
    for q in range(4):
        ang = 0.5 * math.pi * q
        rel = _mod2pi(ang - t0) if sw > 0.0 else _mod2pi(t0 - ang)
        if rel <= abs(sw):
            if q == 0:
                umax = max(umax, r0)
            elif q == 1:
                vmax = max(vmax, r0)
            elif q == 2:
                umin = min(umin, -r0)
            else:
                vmin = min(vmin, -r0)
    F[row, _LO + ia], F[row, _HI + ia] = cu + umin - dr, cu + umax + dr
    F[row, _LO + ib], F[row, _HI + ib] = cv + vmin - dr, cv + vmax + dr
    F[row, _LO + inn], F[row, _HI + inn] = min(s[inn], e[inn]), max(s[inn], e[inn])
    I[row, 0] = _ARC
    I[row, 1], I[row, 2], I[row, 3] = ia, ib, inn


@njit(cache=True, nogil=True)
def _dist_row(F, I, row, px, py, pz):
    """Exact distance from p to the centre curve of move ``row`` (lower bound by dr for spirals)."""
    if I[row, 0] == _LINE:
        sx, sy, sz = F[row, 0], F[row, 1], F[row, 2]
        dx, dy, dz = F[row, 3] - sx, F[row, 4] - sy, F[row, 5] - sz
        return math.sqrt(_seg_d2(px, py, pz, sx, sy, sz, dx, dy, dz, dx * dx + dy * dy + dz * dz))
    ia, ib, inn = I[row, 1], I[row, 2], I[row, 3]
    u = _pick(px, py, pz, ia) - F[row, _CU]
    v = _pick(px, py, pz, ib) - F[row, _CV]
    e0 = F[row, _SN] - _pick(px, py, pz, inn)
    d = _arc_dist(u, v, e0, F[row, _T0], F[row, _SW], F[row, _RR], F[row, _DN])
    return max(d - F[row, _DR], 0.0)


@njit(cache=True, nogil=True)
def _move_min(F, I, row, pts, start, cmin, cmax, x0, y0, h, nx, ny, slack, limit, stop):
    """min(limit, smallest distance from a binned point to the curve of move ``row``); returns as
    soon as a distance below ``stop`` is found (then the value is that distance, < stop)."""
    best = limit
    if math.isinf(best):
        ix0, ix1, iy0, iy1 = 0, nx - 1, 0, ny - 1
    else:
        ix0 = max(int(math.floor((F[row, _LO] - best - x0) / h)), 0)
        ix1 = min(int(math.floor((F[row, _HI] + best - x0) / h)), nx - 1)
        iy0 = max(int(math.floor((F[row, _LO + 1] - best - y0) / h)), 0)
        iy1 = min(int(math.floor((F[row, _HI + 1] + best - y0) / h)), ny - 1)
    lox, loy, loz = F[row, _LO], F[row, _LO + 1], F[row, _LO + 2]
    hix, hiy, hiz = F[row, _HI], F[row, _HI + 1], F[row, _HI + 2]
    line = I[row, 0] == _LINE
    sx, sy, sz = F[row, 0], F[row, 1], F[row, 2]
    dx, dy, dz = F[row, 3] - sx, F[row, 4] - sy, F[row, 5] - sz
    L2 = dx * dx + dy * dy + dz * dz
    ia, ib, inn = I[row, 1], I[row, 2], I[row, 3]
    cu, cv, sn = F[row, _CU], F[row, _CV], F[row, _SN]
    t0, sw, rr, dn, dr = F[row, _T0], F[row, _SW], F[row, _RR], F[row, _DN], F[row, _DR]
    nlo, nhi = min(sn, sn + dn), max(sn, sn + dn)
    half_xy2 = 0.5 * h * h                      # (half diagonal of a cell square)^2
    for ix in range(ix0, ix1 + 1):
        cx0 = x0 + ix * h
        gx = _gap(cx0, cx0 + h, lox, hix)
        if gx - slack >= best:
            continue
        for iy in range(iy0, iy1 + 1):
            c = ix * ny + iy
            s0, s1 = start[c], start[c + 1]
            if s0 == s1:
                continue
            cy0 = y0 + iy * h
            gy = _gap(cy0, cy0 + h, loy, hiy)
            gz = _gap(cmin[c], cmax[c], loz, hiz)
            lb2 = gx * gx + gy * gy + gz * gz
            bs = best + slack
            if lb2 >= bs * bs:
                continue
            # the box lies within its half diagonal of its centre
            hz = 0.5 * (cmax[c] - cmin[c])
            dc = _dist_row(F, I, row, cx0 + 0.5 * h, cy0 + 0.5 * h, cmin[c] + hz)
            if dc - math.sqrt(half_xy2 + hz * hz) - slack >= best:
                continue
            if line:
                b2 = best * best
                for s in range(s0, s1):
                    d2 = _seg_d2(pts[s, 0], pts[s, 1], pts[s, 2], sx, sy, sz, dx, dy, dz, L2)
                    if d2 < b2:
                        b2 = d2
                        best = math.sqrt(d2)
                        if best < stop:
                            return best
            else:
                for s in range(s0, s1):
                    pu = pts[s, ia] - cu
                    pv = pts[s, ib] - cv
                    pn = pts[s, inn]
                    # cheap bound: distance to the whole circle / helix cylinder
                    g = _gap(pn, pn, nlo, nhi)
                    rho = math.sqrt(pu * pu + pv * pv)
                    if math.sqrt((rho - rr) * (rho - rr) + g * g) - dr >= best:
                        continue
                    d = _arc_dist(pu, pv, sn - pn, t0, sw, rr, dn) - dr
                    if d < best:
                        best = max(d, 0.0)
                        if best < stop:
                            return best
    return best


@njit(parallel=True, cache=True)
def _prep(sel, xyz, kind, centre, plane_a, plane_b, plane_n, F, I):
    for k in prange(sel.shape[0]):
        m = sel[k]
        if kind[m] == ARC_CW or kind[m] == ARC_CCW:
            ia, ib, inn = plane_a[m], plane_b[m], plane_n[m]
            _fill_arc(F, I, k, xyz[m - 1], xyz[m], centre[m, ia], centre[m, ib], ia, ib, inn, kind[m] == ARC_CCW)
        else:
            # scalars, not row views: a view per move costs reference counting (atomic in the
            # threads) many times the fill itself
            _fill_line(F, I, k, xyz[m - 1, 0], xyz[m - 1, 1], xyz[m - 1, 2], xyz[m, 0], xyz[m, 1], xyz[m, 2])


@njit(parallel=True, cache=True)
def _clearance(F, I, pts, start, cmin, cmax, x0, y0, h, nx, ny, slack, limit, out):
    for k in prange(F.shape[0]):
        out[k] = _move_min(F, I, k, pts, start, cmin, cmax, x0, y0, h, nx, ny, slack, limit, -1.0)


# ------------------------------------------------------------------------------------ public API

#: Fewer measured moves than this run on one thread.
_PARALLEL_MIN = 4096


_prep_serial = serial_twin(_prep, "_prep_serial")
_clearance_serial = serial_twin(_clearance, "_clearance_serial")


class BinnedCloud:
    """The cloud ``points`` (N,3, mm, area frame) binned once on a square xy raster of
    ``cell_mm`` cells (each cell's lowest and highest z kept) for clearance queries; pass it as
    ``points`` to :func:`move_clearance` to measure several paths on one cloud. The cell size
    changes speed only (R/4 is a good choice; at most ~16M cells)."""

    def __init__(self, points, cell_mm: float):
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ParameterError("points must be an (N,3) array")
        if not np.all(np.isfinite(pts)):
            raise ParameterError("points must be finite")
        h = float(cell_mm)
        if not (h > 0 and math.isfinite(h)):
            raise ParameterError(f"cell_mm = {cell_mm}: must be > 0")
        self.n = pts.shape[0]
        #: triangles through the points (a planning.geometry.triangles.TriangleDropSurface), or None:
        #: move_clearance then measures to them too (issue 18, planning/toolpath/surface.py)
        self.triangles = None
        if self.n == 0:
            self.arrays = (np.zeros((0, 3)), np.zeros(2, np.int64), np.full(1, np.inf), np.full(1, -np.inf),
                           0.0, 0.0, h, 1, 1, 1e-9)
            return
        lo = pts[:, :2].min(axis=0)
        hi = pts[:, :2].max(axis=0)
        h = max(h, float((hi - lo).max()) / 4000.0, 1e-9)
        nx = int((hi[0] - lo[0]) / h) + 1
        ny = int((hi[1] - lo[1]) / h) + 1
        _, rank, start, cmax, cmin = bin_cells(pts[:, 0], pts[:, 1], pts[:, 2], lo[0], lo[1], h, nx, ny)
        slack = 1e-9 * max(float(np.abs(pts).max()), 1.0)      # rounding of cell bounds, mm
        self.cell_mm = h
        self.arrays = (rows_in_order(pts, rank), start, cmin, cmax, float(lo[0]), float(lo[1]), h, nx, ny, slack)


def _binned(points, radius_mm, cell_mm) -> BinnedCloud:
    if isinstance(points, BinnedCloud):
        return points
    return BinnedCloud(points, radius_mm / 4.0 if cell_mm is None else cell_mm)


def _check_radius(radius_mm) -> float:
    R = float(radius_mm)
    if not (R > 0 and math.isfinite(R)):
        raise ParameterError(f"radius_mm = {radius_mm}: must be > 0")
    return R


def _selected(tp: Toolpath, moves) -> np.ndarray:
    P = tp.n_moves
    if moves is None:
        k = tp.kind
        sel = np.flatnonzero((k == FEED) | (k == ARC_CW) | (k == ARC_CCW))
    else:
        m = np.asarray(moves)
        if m.dtype == bool:
            if m.shape != (P,):
                raise ParameterError(f"moves: a bool mask must have one entry per move ({P})")
            sel = np.flatnonzero(m)
        else:
            sel = np.unique(m.astype(np.int64).reshape(-1))
            if sel.size and (sel[0] < 0 or sel[-1] >= P):
                raise ParameterError(f"moves: indices must be in [0, {P})")
    return sel[sel > 0]


def move_clearance(tp: Toolpath, points: np.ndarray | BinnedCloud, radius_mm: float, *,
                   moves=None, cutoff_mm: float | None = None,
                   cell_mm: float | None = None) -> np.ndarray:
    """Per move of ``tp`` (ball centres, area frame, mm): the smallest distance (mm) from any point
    of ``points`` (N,3, or a :class:`BinnedCloud`) to the ball-centre curve of the move (straight
    segment, circular arc or helix; exact, see the module docstring), capped at ``cutoff_mm``
    (default ``radius_mm``: the value is ``min(true distance, cutoff)``). Returns (P,) float64,
    NaN for the moves not measured: ``moves`` (a bool mask or indices; default every FEED and
    arc move) chooses them, and move 0 has no start. A move is gouge free when its value is
    >= R - tol. ``cell_mm`` (default R/4) sets the raster and changes speed only."""
    R = _check_radius(radius_mm)
    cut = R if cutoff_mm is None else float(cutoff_mm)
    if not cut > 0:
        raise ParameterError(f"cutoff_mm = {cutoff_mm}: must be > 0 (inf for no cut-off)")
    sel = _selected(tp, moves)
    out = np.full(tp.n_moves, np.nan)
    if sel.size == 0:
        return out
    ks = tp.kind[sel]
    arcs = (ks == ARC_CW) | (ks == ARC_CCW)
    pl = tp.plane[sel]
    bad = arcs & ~((pl == PLANE_XY) | (pl == PLANE_ZX) | (pl == PLANE_YZ))
    if bad.any():
        raise ParameterError(f"move {int(sel[bad][0])}: an arc needs plane 17, 18 or 19")
    xyz = np.ascontiguousarray(tp.xyz_mm, dtype=np.float64)
    if not np.all(np.isfinite(xyz[np.concatenate([sel - 1, sel])])):
        raise ParameterError("the measured moves must have finite end points")
    if not np.all(np.isfinite(tp.centre_mm[sel[arcs]])):
        raise ParameterError("arc moves need finite centres (centre_mm)")
    cen = np.zeros((tp.n_moves, 3))
    if arcs.any():
        cen[sel[arcs]] = tp.centre_mm[sel[arcs]]
    ax = np.zeros((3, tp.n_moves), np.int64)
    for pl, axes in PLANE_AXES.items():
        ax[:, tp.plane == pl] = np.array(axes)[:, None]
    F = np.empty((sel.size, _NF))
    I = np.empty((sel.size, 4), np.int64)
    # a few moves: the serial kernels (starting the thread pool costs more than the work)
    prep, clearance = (_prep, _clearance) if sel.size >= _PARALLEL_MIN else (_prep_serial, _clearance_serial)
    prep(sel, xyz, tp.kind.astype(np.int64), cen, ax[0], ax[1], ax[2], F, I)
    cloud = _binned(points, R, cell_mm)
    got = np.empty(sel.size)
    clearance(F, I, *cloud.arrays, cut, got)
    if cloud.triangles is not None:
        np.minimum(got, _triangle_clearance(F, I, cloud.triangles, cut), out=got)
    out[sel] = got
    return out


#: Arcs are measured against triangles by chords whose distance from the arc is at most this, mm.
ARC_CHORD_MM = 1e-3


def _triangle_clearance(F: np.ndarray, I: np.ndarray, triangles, cut: float) -> np.ndarray:
    """Per move row of ``F``/``I`` (see :func:`_fill_line`, :func:`_fill_arc`): the distance from its
    ball-centre curve to the ``triangles`` (a :class:`planning.geometry.triangles.TriangleDropSurface`),
    capped at ``cut``. Straight moves exactly; an arc or helix by chords of ``n`` equal angular pieces,
    ``n`` such that each piece's curve stays within ``e = r dtheta^2 / 8 <= ARC_CHORD_MM`` of its chord
    (linear interpolation error of the circle, and of the helix, whose rise is linear in the angle,
    so its chord interpolates the rise exactly), less ``e`` and the spiral's ``|r_end - r_start|``:
    a lower bound of the exact distance, never an over-report."""
    m = F.shape[0]
    arc = I[:, 0] == _ARC
    starts = [F[~arc, _S:_S + 3]]
    ends = [F[~arc, _E:_E + 3]]
    owner = [np.flatnonzero(~arc)]
    less = [np.zeros(int((~arc).sum()))]
    rows = np.flatnonzero(arc)
    if rows.size:
        r = np.maximum(F[rows, _RR], 1e-12)
        sw = F[rows, _SW]
        n = np.maximum(np.ceil(np.abs(sw) / np.sqrt(8.0 * ARC_CHORD_MM / r)).astype(np.int64), 1)
        piece = np.repeat(np.arange(rows.size), n)
        j = np.arange(piece.size) - np.repeat(np.cumsum(n) - n, n)
        ends_of = []
        for frac in (j / n[piece], (j + 1) / n[piece]):
            k = rows[piece]
            ang = F[k, _T0] + sw[piece] * frac
            p = np.empty((piece.size, 3))
            ia, ib, inn = I[k, 1], I[k, 2], I[k, 3]
            ar = np.arange(piece.size)
            p[ar, ia] = F[k, _CU] + r[piece] * np.cos(ang)
            p[ar, ib] = F[k, _CV] + r[piece] * np.sin(ang)
            p[ar, inn] = F[k, _SN] + F[k, _DN] * frac
            ends_of.append(p)
        starts.append(ends_of[0])
        ends.append(ends_of[1])
        owner.append(rows[piece])
        dth = np.abs(sw[piece]) / n[piece]
        less.append(r[piece] * dth * dth / 8.0 + F[rows[piece], _DR])
    S, E = np.concatenate(starts), np.concatenate(ends)
    d = triangles.clearance(S, E, cut) - np.concatenate(less)
    out = np.full(m, cut)
    np.minimum.at(out, np.concatenate(owner), np.maximum(d, 0.0))
    return out


@dataclass(frozen=True)
class ClearanceReport:
    """Gouge check of a path: ``min_clearance_mm`` the smallest move clearance (mm; capped at the
    cut-off, so R means nothing within R; NaN when no move was measured), ``worst_move`` its move
    index (-1 when none), ``n_below`` the number of moves closer than ``threshold_mm`` = R - tol
    to the cloud, ``n_measured`` the number of moves measured. ``ok``: nothing below."""

    min_clearance_mm: float
    worst_move: int
    n_below: int
    n_measured: int
    threshold_mm: float

    @property
    def ok(self) -> bool:
        return self.n_below == 0


def clearance_report(tp: Toolpath, points, radius_mm: float, tol_mm: float, *, moves=None,
                     cutoff_mm: float | None = None, cell_mm: float | None = None) -> ClearanceReport:
    """Measure the path's move clearances (:func:`move_clearance`) and sum them up against the
    gouge threshold R - ``tol_mm`` (mm)."""
    R = _check_radius(radius_mm)
    tol = float(tol_mm)
    if not (0 <= tol < R):
        raise ParameterError(f"tol_mm = {tol_mm}: must be in [0, R = {R})")
    c = move_clearance(tp, points, R, moves=moves, cutoff_mm=cutoff_mm, cell_mm=cell_mm)
    measured = np.isfinite(c)
    if not measured.any():
        return ClearanceReport(float("nan"), -1, 0, 0, R - tol)
    worst = int(np.nanargmin(c))
    return ClearanceReport(min_clearance_mm=float(c[worst]), worst_move=worst,
                           n_below=int(np.count_nonzero(c[measured] < R - tol)),
                           n_measured=int(measured.sum()), threshold_mm=R - tol)


__all__ = ["BinnedCloud", "ClearanceReport", "clearance_report", "move_clearance"]
