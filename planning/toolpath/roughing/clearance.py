"""Verification of a roughing path (:mod:`planning.toolpath.roughing`; the last stage of
:func:`planning.toolpath.roughing.levels.roughing_paths`): the exact clearance, in mm, of a flat
or bull-nose end mill moved along straight moves against every cloud point, independent of the
planning raster.

:func:`min_tool_clearance` measures the smallest clearance between every cloud point and the tool
swept along every move (exact for the horizontal and vertical moves made here, a lower bound for
others); :class:`~planning.toolpath.roughing.levels.RoughingPath` reports it as
``min_clearance_mm`` (>= the allowance - 1e-6 mm by construction). Points more than Rt below the
lowest tip are left out (farther than Rt from the tool). Cost: one counting sort of the cloud
(:func:`_bin_highest_first`), then a scan of the cells near each move (numba, parallel over chunks
of moves). :class:`_MoveClearance` asks the same kernel of many separate moves against one binning
(the contour's chords on the stock view, :func:`planning.toolpath.roughing.clearing._hug`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import get_num_threads, njit, prange

from planning.errors import ParameterError
from planning.toolpath.roughing.common import (
    _argsort_stable,
    _bounds,
    _check_points,
    _check_tool,
    _finite,
    _seg_d2,
)

CLEARANCE_BLOCK = 8     #: min_tool_clearance skips blocks of this many cells each way by their highest point


@dataclass(frozen=True)
class ToolClearance:
    """``min_mm``: the smallest clearance (``inf`` when no point is within ``reach_mm``);
    ``move``: the move where it occurs; ``point``: the cloud point (-1 when none)."""

    min_mm: float
    move: int
    point: int



@njit(parallel=True, cache=True)
def _clearance(pts, order, start, cmax, bmax, B, x0, y0, c, nx, ny, xyz, Rf, rc, reach, nchunk, best_out, move_out,
               point_out):
    P = xyz.shape[0]
    half_diag = 0.5 * c * 1.4142135623730951 * (1.0 + 1e-12)
    block_half_diag = 0.5 * B * c * 1.4142135623730951 * (1.0 + 1e-12)
    for t in prange(nchunk):
        best = reach
        bm = -1
        bp = -1
        m0 = (t * P) // nchunk
        m1 = ((t + 1) * P) // nchunk
        for m in range(m0, m1):
            a = m - 1 if m > 0 else 0
            ax, ay, az = xyz[a, 0], xyz[a, 1], xyz[a, 2]
            bx, by, bz = xyz[m, 0], xyz[m, 1], xyz[m, 2]
            zl = min(az, bz)
            span = Rf + rc + best + c
            ix0 = max(int(math.floor((min(ax, bx) - span - x0) / c)), 0)
            ix1 = min(int(math.floor((max(ax, bx) + span - x0) / c)), nx - 1)
            iy0 = max(int(math.floor((min(ay, by) - span - y0) / c)), 0)
            iy1 = min(int(math.floor((max(ay, by) + span - y0) / c)), ny - 1)
            for bi in range(ix0 // B, ix1 // B + 1):
                for bj in range(iy0 // B, iy1 // B + 1):
                    # lower bound of the clearance of any point of the block (B x B cells)
                    vv = zl + rc - bmax[bi, bj]
                    vv = max(vv, 0.0)
                    if vv - rc >= best:
                        continue
                    bcx = x0 + (bi + 0.5) * B * c
                    bcy = y0 + (bj + 0.5) * B * c
                    uu = math.sqrt(_seg_d2(bcx, bcy, ax, ay, bx, by)) - block_half_diag - Rf
                    uu = max(uu, 0.0)
                    if math.sqrt(uu * uu + vv * vv) - rc >= best:
                        continue
                    for ix in range(max(ix0, bi * B), min(ix1, bi * B + B - 1) + 1):
                        cx = x0 + (ix + 0.5) * c
                        for iy in range(max(iy0, bj * B), min(iy1, bj * B + B - 1) + 1):
                            cc = ix * ny + iy
                            if start[cc] == start[cc + 1]:
                                continue
                            # lower bound of the clearance of any point of the cell
                            vv = zl + rc - cmax[cc]
                            vv = max(vv, 0.0)
                            if vv - rc >= best:
                                continue
                            cy = y0 + (iy + 0.5) * c
                            uu = math.sqrt(_seg_d2(cx, cy, ax, ay, bx, by)) - half_diag - Rf
                            uu = max(uu, 0.0)
                            if math.sqrt(uu * uu + vv * vv) - rc >= best:
                                continue
                            for s in range(start[cc], start[cc + 1]):     # highest first
                                v = zl + rc - pts[s, 2]
                                v = max(v, 0.0)
                                if v - rc >= best:
                                    break
                                u = math.sqrt(_seg_d2(pts[s, 0], pts[s, 1], ax, ay, bx, by)) - Rf
                                u = max(u, 0.0)
                                cl = math.sqrt(u * u + v * v) - rc
                                if cl < best:
                                    best = cl
                                    bm = m
                                    bp = order[s]
        best_out[t] = best
        move_out[t] = bm
        point_out[t] = bp


@njit(cache=True, nogil=True)
def _bin_highest_first(pts, x0, y0, c, nx, ny, B):
    """Counting sort of the points (N,3) into square cells of side c (cell ``ix * ny + iy``), each
    cell's run by decreasing z (equal z: input order), as :func:`planning.geometry.raster.bin_cells` after a
    stable sort by decreasing z. Returns (points in that order (N,3), their input indices, run
    starts (ncell + 1), highest z per cell (-inf when empty), highest z per block of B x B cells)."""
    n = pts.shape[0]
    ncell = nx * ny
    cell = np.empty(n, np.int64)
    start = np.zeros(ncell + 1, np.int64)
    cmax = np.full(ncell, -np.inf)
    for i in range(n):
        ix = min(max(int(math.floor((pts[i, 0] - x0) / c)), 0), nx - 1)
        iy = min(max(int(math.floor((pts[i, 1] - y0) / c)), 0), ny - 1)
        cc = ix * ny + iy
        cell[i] = cc
        start[cc + 1] += 1
        cmax[cc] = max(cmax[cc], pts[i, 2])
    for cc in range(ncell):
        start[cc + 1] += start[cc]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        cc = cell[i]
        order[fill[cc]] = i
        fill[cc] += 1
    zk = np.empty(n)
    for k in range(n):
        zk[k] = pts[order[k], 2]
    for cc in range(ncell):
        s0 = start[cc]
        s1 = start[cc + 1]
        if s1 - s0 <= 32:                   # insertion sort (stable)
            for k in range(s0 + 1, s1):
                o = order[k]
                z = zk[k]
                q = k - 1
                while q >= s0 and zk[q] < z:
                    order[q + 1] = order[q]
                    zk[q + 1] = zk[q]
                    q -= 1
                order[q + 1] = o
                zk[q + 1] = z
        else:
            seg = order[s0:s1].copy()
            perm = _argsort_stable(-zk[s0:s1])
            for k in range(s1 - s0):
                order[s0 + k] = seg[perm[k]]
    sp = np.empty((n, 3))
    for k in range(n):
        o = order[k]
        sp[k, 0] = pts[o, 0]
        sp[k, 1] = pts[o, 1]
        sp[k, 2] = pts[o, 2]
    nbx = (nx + B - 1) // B
    nby = (ny + B - 1) // B
    bmax = np.full((nbx, nby), -np.inf)
    for ix in range(nx):
        for iy in range(ny):
            v = cmax[ix * ny + iy]
            bmax[ix // B, iy // B] = max(bmax[ix // B, iy // B], v)
    return sp, order, start, cmax, bmax



def min_tool_clearance(xyz_mm, points, *, tool_radius_mm: float, corner_radius_mm: float = 0.0,
                       reach_mm: float | None = None, cell_mm: float | None = None) -> ToolClearance:
    """Smallest clearance (mm) between a flat / bull-nose end mill (tip at the path points, axis +Z,
    radius ``tool_radius_mm``, corner ``corner_radius_mm``, body continued upwards without end) moved
    along the straight moves ``xyz_mm[i-1] -> xyz_mm[i]`` (the first point as a move of its own)
    and the cloud ``points`` (N,3).

    Per move and point: ``sqrt(max(d - Rf, 0)^2 + max(z_low + rc - q_z, 0)^2) - rc`` with ``d`` the
    XY distance from the point to the move's XY segment and ``z_low`` the move's lowest tip
    height: exact for horizontal and vertical moves (the swept core is then a slab of the
    half-infinite cylinder), a lower bound (never an over-report) for oblique ones. Only values
    below ``reach_mm`` (default the tool radius) are searched: ``inf`` when none. Candidates come
    from a square XY raster of the points (cells of ``cell_mm``, default ``Rt / 8`` within [0.25, 2])
    with each cell's highest z; cells whose bound cannot beat the best value found so far are
    skipped, the others scanned point by point from the highest down, until the height alone
    rules the rest out (numba, parallel over chunks of moves)."""
    Rt, rc = _check_tool(tool_radius_mm, corner_radius_mm)
    pts = _check_points(points, "points")
    xyz = np.ascontiguousarray(np.asarray(xyz_mm, dtype=np.float64).reshape(-1, 3))
    if xyz.shape[0] == 0:
        return ToolClearance(math.inf, -1, -1)
    if not np.all(np.isfinite(xyz)):
        raise ParameterError("the path holds NaN or infinite coordinates")
    reach = Rt if reach_mm is None else _finite("reach_mm", reach_mm)
    if not reach > 0:
        raise ParameterError(f"reach_mm = {reach_mm}: must be > 0")
    lo, hi, _ = _bounds(pts)
    lo, hi = lo[:2], hi[:2]
    c = min(max(Rt / 8.0, 0.25), 2.0) if cell_mm is None else _finite("cell_mm", cell_mm)
    if not c > 0:
        raise ParameterError(f"cell_mm = {cell_mm}: must be > 0")
    c = max(c, float((hi - lo).max()) / 4000.0, 1e-9)
    nx = int((hi[0] - lo[0]) / c) + 1
    ny = int((hi[1] - lo[1]) / c) + 1
    sp, order, start, cmax, bmax = _bin_highest_first(pts, lo[0], lo[1], c, nx, ny, CLEARANCE_BLOCK)
    nchunk = max(1, min(xyz.shape[0], 8 * get_num_threads()))
    best = np.empty(nchunk)
    mv = np.empty(nchunk, np.int64)
    pi = np.empty(nchunk, np.int64)
    _clearance(sp, order, start, cmax, bmax, CLEARANCE_BLOCK, lo[0], lo[1], c, nx, ny, xyz, Rt - rc, rc, reach,
               nchunk, best, mv, pi)
    k = int(np.argmin(best))
    if not best[k] < reach:
        return ToolClearance(math.inf, -1, -1)
    return ToolClearance(float(best[k]), int(mv[k]), int(pi[k]))


class _MoveClearance:
    """The exact clearance test of :func:`min_tool_clearance` asked of many single moves: the cloud
    ``points`` (N,3) binned once (the same raster and counting sort), then :meth:`keeps` says of each
    horizontal move at a tip height whether the tool swept along it keeps at least a clearance (the
    roughing's wall-hugging contour chords, :func:`planning.toolpath.roughing.clearing._hug`)."""

    def __init__(self, points, tool_radius_mm: float, corner_radius_mm: float = 0.0):
        Rt, rc = _check_tool(tool_radius_mm, corner_radius_mm)
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        self.Rf, self.rc, self.n = Rt - rc, rc, pts.shape[0]
        if self.n == 0:
            return
        lo, hi, _ = _bounds(pts)
        c = min(max(Rt / 8.0, 0.25), 2.0)
        c = max(c, float((hi[:2] - lo[:2]).max()) / 4000.0, 1e-9)
        self.x0, self.y0, self.c = float(lo[0]), float(lo[1]), c
        self.nx = int((hi[0] - lo[0]) / c) + 1
        self.ny = int((hi[1] - lo[1]) / c) + 1
        self.binned = _bin_highest_first(pts, self.x0, self.y0, c, self.nx, self.ny, CLEARANCE_BLOCK)

    def keeps(self, a_xy, b_xy, z: float, need_mm: float) -> np.ndarray:
        """(k,) bool: whether the tool, its tip at height ``z``, moved from ``a_xy[i]`` to ``b_xy[i]``
        ((k,2) each) keeps a clearance of at least ``need_mm`` from every point (exact: a horizontal
        move)."""
        a_xy = np.asarray(a_xy, dtype=np.float64).reshape(-1, 2)
        b_xy = np.asarray(b_xy, dtype=np.float64).reshape(-1, 2)
        k = a_xy.shape[0]
        if k == 0 or self.n == 0:
            return np.ones(k, dtype=bool)
        # the moves a_i -> b_i are the odd moves of the path a_0, b_0, a_1, b_1, ...; one chunk per move
        xyz = np.empty((2 * k, 3))
        xyz[0::2, :2], xyz[1::2, :2], xyz[:, 2] = a_xy, b_xy, float(z)
        reach = max(float(need_mm), 0.0) + 1e-3
        best = np.empty(2 * k)
        mv = np.empty(2 * k, np.int64)
        pi = np.empty(2 * k, np.int64)
        sp, order, start, cmax, bmax = self.binned
        _clearance(sp, order, start, cmax, bmax, CLEARANCE_BLOCK, self.x0, self.y0, self.c, self.nx, self.ny, xyz,
                   self.Rf, self.rc, reach, 2 * k, best, mv, pi)
        return best[1::2] >= float(need_mm) - 1e-9
