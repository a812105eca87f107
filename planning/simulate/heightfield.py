"""The stock read along a set-up's tool axis as a height field (issue 30 item 1, ``docs/design.md``
"Stock-first planning"): for every cell of a raster in a set-up frame, the highest point of the
tri-dexel material (:class:`planning.simulate.dexel.TriDexel`) on the line through the cell's
centre along the frame's +Z, in mm (frame z). The operations of a set-up plan on it: roughing clears
only where this top is above the level.

**How the line is read.** The line is walked from a given start height downwards on the ray family
most parallel to it (``|d_f| >= 1/sqrt 3``): in steps over which its projection across that family
moves at most half a ray spacing, each step is read on the ray nearest the step's middle, whose
material intervals are exact along it; the first interval that overlaps the step's span along the
ray gives the highest material point of the step, exactly on that ray. So the result is the top of
the material as the simulation itself sees it (the tri-dexel knows nothing between its rays):
within ``r / 2`` of the line across the rays, i.e. within ``r / 2 * tan(slope)`` in height of the
true top of a face of that slope, higher or lower. It is not a conservative bound: the planners use
it to decide where there is material to cut (air or not), never to clear a rapid (they keep the
bound from the boundary points for that, :func:`planning.toolpath.roughing.maps._stock_tops`).

Cost: one walk per cell, from ``start`` (the conservative top, a few mm above the true one) down
to the first material or ``stop``, within the model's domain only (so an infinite or far start costs
nothing more); the cells run in parallel (numba ``prange``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from planning.simulate.dexel import TriDexel


@njit(cache=True, nogil=True, parallel=True)
def _frame_tops(lo, res, n, base, off, cnt, pool, rot, origin, x0, y0, h, start, stop, out):
    nx, ny = start.shape
    d = rot[2]
    f = 0
    for k in range(1, 3):
        if abs(d[k]) > abs(d[f]):
            f = k
    ua, va = (f + 1) % 3, (f + 2) % 3
    across = max(abs(d[ua]), abs(d[va]))
    dt_max = 0.5 * res / across if across > 1e-12 else math.inf
    nu = n[ua]
    for cx in prange(nx):
        x = x0 + (cx + 0.5) * h
        for cy in range(ny):
            t = start[cx, cy]
            out[cx, cy] = -math.inf
            if not (t > stop):
                continue
            y = y0 + (cy + 0.5) * h
            px = origin[0] + x * rot[0, 0] + y * rot[1, 0]
            py = origin[1] + x * rot[0, 1] + y * rot[1, 1]
            pz = origin[2] + x * rot[0, 2] + y * rot[1, 2]
            p = (px, py, pz)
            # only the part of the line inside the model's domain can meet material
            t_lo, t_hi = -math.inf, math.inf
            for k in range(3):
                a_k, b_k = lo[k], lo[k] + n[k] * res
                if abs(d[k]) < 1e-15:
                    if p[k] < a_k or p[k] > b_k:
                        t_lo, t_hi = math.inf, -math.inf
                    continue
                u0, u1 = (a_k - p[k]) / d[k], (b_k - p[k]) / d[k]
                t_lo, t_hi = max(t_lo, min(u0, u1)), min(t_hi, max(u0, u1))
            t = min(t, t_hi)
            low = max(stop, t_lo)
            while t > low:
                t1 = max(t - dt_max, low)
                tm = 0.5 * (t + t1)
                mu = p[ua] + tm * d[ua]
                mv = p[va] + tm * d[va]
                i = int(math.floor((mu - lo[ua]) / res))
                j = int(math.floor((mv - lo[va]) / res))
                if 0 <= i < nu and 0 <= j < n[va]:
                    s_t, s_t1 = p[f] + t * d[f], p[f] + t1 * d[f]
                    slo, shi = min(s_t, s_t1), max(s_t, s_t1)
                    r = base[f] + j * nu + i
                    o, c = off[r], cnt[r]
                    best = -math.inf
                    for q in range(o, o + c):
                        a, b = pool[q, 0], pool[q, 1]
                        if b < slo or a > shi:
                            continue
                        # the highest t of [a, b] within the step: along +d_f t grows with s
                        if d[f] > 0:
                            th = t1 + (min(b, shi) - s_t1) / d[f]
                        else:
                            th = t1 + (max(a, slo) - s_t1) / d[f]
                        best = max(best, th)
                    if best > -math.inf:
                        out[cx, cy] = min(best, t)
                        break
                t = t1


def stock_tops_in_frame(stock: TriDexel, rotation, origin_mm, x0: float, y0: float, h: float, nx: int, ny: int,
                        start_mm, stop_mm: float) -> np.ndarray:
    """(nx, ny) frame z (mm) of the highest material of ``stock`` on the line along the frame's +Z
    through the centre of every cell of the raster (cells of side ``h`` from (``x0``, ``y0``), frame
    x, y; module docstring). ``rotation`` (3,3): rows the frame's x, y, z axes in part coordinates;
    ``origin_mm`` (3,) the frame's origin (:class:`planning.toolpath.frames.AreaFrame`). The walk
    starts at ``start_mm`` (a scalar or (nx, ny) frame z: a height known to be at or above the
    material, e.g. the conservative top; -inf: no material, skipped) and stops at ``stop_mm``;
    -inf where it meets no material."""
    R = np.ascontiguousarray(rotation, dtype=np.float64).reshape(3, 3)
    o = np.ascontiguousarray(origin_mm, dtype=np.float64).reshape(3)
    s = np.broadcast_to(np.asarray(start_mm, dtype=np.float64), (int(nx), int(ny)))
    # no material lies above the domain's highest corner along the frame's Z
    lo, hi = stock.lo, stock.hi
    corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
    t_max = float(((corners - o) @ R[2]).max())
    s = np.ascontiguousarray(np.where(np.isnan(s), -np.inf, np.minimum(s, t_max)))
    out = np.empty((int(nx), int(ny)))
    _frame_tops(stock.lo, stock.res, stock.n, stock.base, stock.off, stock.cnt, stock.pool, R, o, float(x0), float(y0),
                float(h), s, float(stop_mm), out)
    return out


@njit(cache=True, nogil=True)
def _boundary_tops(lo, res, n, base, off, cnt, pool, rot, origin, x0, y0, h, above, out):
    nx, ny = out.shape
    p = np.empty(3)
    for f in range(3):
        ua = (f + 1) % 3
        va = (f + 2) % 3
        nu = n[ua]
        for r in range(base[f + 1] - base[f]):
            g = base[f] + r
            c = cnt[g]
            if c == 0:
                continue
            p[ua] = lo[ua] + (r % nu + 0.5) * res
            p[va] = lo[va] + (r // nu + 0.5) * res
            o = off[g]
            for k in range(c):
                for e in range(2):
                    p[f] = pool[o + k, e]
                    dx = p[0] - origin[0]
                    dy = p[1] - origin[1]
                    dz = p[2] - origin[2]
                    fz = rot[2, 0] * dx + rot[2, 1] * dy + rot[2, 2] * dz
                    if not fz > above:
                        continue
                    i = int(math.floor((rot[0, 0] * dx + rot[0, 1] * dy + rot[0, 2] * dz - x0) / h))
                    j = int(math.floor((rot[1, 0] * dx + rot[1, 1] * dy + rot[1, 2] * dz - y0) / h))
                    if 0 <= i < nx and 0 <= j < ny and fz > out[i, j]:
                        out[i, j] = fz


def boundary_tops_in_frame(stock: TriDexel, rotation, origin_mm, x0: float, y0: float, h: float, nx: int, ny: int,
                           above_mm: float = -math.inf) -> np.ndarray:
    """(nx, ny) frame z (mm) of the highest boundary point of ``stock`` in every cell of the raster (cells
    of side ``h`` from (``x0``, ``y0``), frame x, y), among those above ``above_mm``; -inf where none. The
    boundary points are both ends of every material interval of all three ray families
    (:meth:`planning.simulate.dexel.TriDexel.boundary_points`, without building them): unlike
    :func:`stock_tops_in_frame`, which reads one family, it sees a sliver thinner than a ray spacing
    that only one family holds (a plate between two families' rays). Sampled, not a bound: a cell
    between samples reads -inf; grown over the sampling's spacing (as
    :func:`planning.toolpath.roughing.maps._stock_tops` grows it) it bounds the material. Cost: one
    pass over the model's intervals."""
    R = np.ascontiguousarray(rotation, dtype=np.float64).reshape(3, 3)
    o = np.ascontiguousarray(origin_mm, dtype=np.float64).reshape(3)
    out = np.full((int(nx), int(ny)), -np.inf)
    _boundary_tops(stock.lo, stock.res, stock.n, stock.base, stock.off, stock.cnt, stock.pool, R, o, float(x0),
                   float(y0), float(h), float(above_mm), out)
    return out
