"""Small pieces every stage of the Z-level roughing shares (:mod:`planning.toolpath.roughing`):
the argument checks (mm values must be finite numbers, the cloud a non-empty (N,3) array), the
bounds of a cloud (mm), the squared XY distance from a point to a segment (mm^2) and a stable
argsort written for numba. No stage of its own: used by the clearance verification, the maps, the
regions and the level loop.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planning.errors import ParameterError


@njit(cache=True, nogil=True)
def _seg_d2(px, py, ax, ay, bx, by):
    """Squared distance from (px, py) to the segment a-b."""
    dx = bx - ax
    dy = by - ay
    L2 = dx * dx + dy * dy
    u = 0.0
    if L2 > 0.0:
        u = ((px - ax) * dx + (py - ay) * dy) / L2
        if u < 0.0:
            u = 0.0
        elif u > 1.0:
            u = 1.0
    ex = ax + u * dx - px
    ey = ay + u * dy - py
    return ex * ex + ey * ey


@njit(cache=True, nogil=True)
def _bounds(pts):
    """Per coordinate lowest and highest value of the points (N,3), and the largest |coordinate|."""
    lo = pts[0].copy()
    hi = pts[0].copy()
    for i in range(pts.shape[0]):
        for k in range(3):
            v = pts[i, k]
            lo[k] = min(lo[k], v)
            hi[k] = max(hi[k], v)
    big = 0.0
    for k in range(3):
        big = max(big, abs(lo[k]), abs(hi[k]))
    return lo, hi, big


@njit(cache=True, nogil=True)
def _argsort_stable(keys):
    """Indices that sort ``keys`` (float64) ascending, equal keys in input order: insertion sort of
    runs of 16, then bottom-up merges (numba's own sorts cost seconds of compilation)."""
    n = keys.shape[0]
    idx = np.arange(n)
    tmp = np.empty(n, np.int64)
    for s0 in range(0, n, 16):
        s1 = min(s0 + 16, n)
        for k in range(s0 + 1, s1):
            v = idx[k]
            kv = keys[v]
            q = k - 1
            while q >= s0 and keys[idx[q]] > kv:
                idx[q + 1] = idx[q]
                q -= 1
            idx[q + 1] = v
    width = 16
    while width < n:
        for s0 in range(0, n, 2 * width):
            m = min(s0 + width, n)
            e = min(s0 + 2 * width, n)
            i = s0
            j = m
            k = s0
            while i < m and j < e:
                if keys[idx[j]] < keys[idx[i]]:
                    tmp[k] = idx[j]
                    j += 1
                else:
                    tmp[k] = idx[i]
                    i += 1
                k += 1
            while i < m:
                tmp[k] = idx[i]
                i += 1
                k += 1
            while j < e:
                tmp[k] = idx[j]
                j += 1
                k += 1
        idx, tmp = tmp, idx
        width *= 2
    return idx


def _check_tool(tool_radius_mm, corner_radius_mm) -> tuple[float, float]:
    Rt = _finite("tool_radius_mm", tool_radius_mm)
    rc = _finite("corner_radius_mm", corner_radius_mm)
    if not Rt > 0:
        raise ParameterError(f"tool_radius_mm = {tool_radius_mm}: the cutter radius must be > 0 mm")
    if not 0 <= rc <= Rt:
        raise ParameterError(f"corner_radius_mm = {corner_radius_mm}: the corner radius must be between 0 and the "
                             f"cutter radius {Rt} mm")
    return Rt, rc


def _finite(name, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: must be a number") from None
    if not math.isfinite(v):
        raise ParameterError(f"{name} = {value}: must be a finite number")
    return v


def _check_points(points, name="cloud_frame") -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise ParameterError(f"{name} must be a non-empty (N,3) array of points in mm (got shape {p.shape})")
    if not np.all(np.isfinite(p)):
        raise ParameterError(f"{name} holds {int((~np.isfinite(p)).any(axis=1).sum())} points with NaN or "
                             f"infinite coordinates")
    return np.ascontiguousarray(p)
