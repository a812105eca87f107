"""Global visibility (Makki 2010 §2.2.4): collisions of the cutter and its holder with the cloud.

For a sampled point ``p = points[sample_index[i]]`` with unit normal ``n = normals[i]`` and a
candidate tool axis ``t = axes[j]`` (unit, part frame, pointing from the part to the spindle) a
ball-end cutter of radius ``R`` touches ``p`` with its ball centre at ``c = p + R n``. The tool
assembly above the ball centre is a stack of coaxial cylinders (:class:`planning.geometry.tool.Segment`,
``lo < a <= hi``, radius ``r``). For every obstacle point ``q`` (the cloud, plus optional extra
obstacle points such as forbidden regions given as point clouds) let ``d = q - c``,
``a = d . t`` (height above the ball centre along the axis) and ``rho = |d - a t|`` (distance
from the axis). With ``EPS_MM = 1e-6``:

    q collides with pair (i, j)  when, for some segment,  lo < a <= hi  and  rho < r - EPS_MM.

The pair is collision free when no obstacle point collides. Points below the ball centre
(``a <= 0``) are left to the ball itself: the local gouge test belongs to the tool paths. The
contact point and its surface neighbours lie at or below the centre for any admissible axis, and
``EPS_MM`` keeps points exactly on the cylinder wall (a flat floor met by a tilted axis) free.

``brute_force_collision_free`` is the reference: every pair against every point, in numpy.

``cloud_collision_free`` is the fast method and gives the same answer pair for pair. Per axis
the obstacles are projected onto the plane normal to the axis and binned into square cells of
``cell_fraction`` times the smallest segment radius (:func:`_sorted_projection`: the counting sort of
:mod:`planning.geometry.raster` fused with the projection; radii more than 10x that get a raster of
their own), keeping
each cell's highest and lowest height along the axis. Two disk max filters over the cells (docs/design.md
"Global visibility"), read at each centre's cell, settle most pairs: "free" when no cell that may
come within ``r`` of a centre anywhere in that cell rises above ``lo``, "hit" (unbounded segments)
when a cell wholly within ``r`` does. The pairs left are scanned by a numba kernel: for the exact
centre, the cells of its disk row by row (widened by a rounding slack), skipping cells wholly
below ``lo`` or above ``hi``, the other cells' points tested with the same floating-point
expressions as the reference, stopping at the first colliding point. Axes run on two threads.
"""

from __future__ import annotations

import math
import os
from typing import Callable, Optional

import numba
import numpy as np
from numba import njit
from scipy import ndimage

from planning.errors import ParameterError
from planning.geometry.basis import complete_basis
from planning.geometry.raster import cell_of, new_cells, tally
from planning.geometry.tool import ToolAssembly

EPS_MM = 1e-6
_MAX_GRID_CELLS = 8_000_000
_THREADS = max(1, min(2, os.cpu_count() or 1))
_RADII_PER_RASTER = 10.0  # segment radii up to this multiple of the smallest share one raster (a finer
#                            raster costs the exact scan a few more empty cells; a second raster costs a
#                            whole sort of the obstacles per axis: 10 measured 1.5x faster than 4 on the femur)



# ----------------------------------------------------------------------------------------------
# shared arithmetic (the reference and the fast kernel use exactly the same expressions)

def _inside(d: np.ndarray, t: np.ndarray, lo: float, hi: Optional[float], r: float) -> np.ndarray:
    """Bool per row of ``d`` (k,3): ``lo < a <= hi`` and ``rho < r - EPS_MM``."""
    a = d[:, 0] * t[0] + d[:, 1] * t[1] + d[:, 2] * t[2]
    w0 = d[:, 0] - a * t[0]
    w1 = d[:, 1] - a * t[1]
    w2 = d[:, 2] - a * t[2]
    rho = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    m = (a > lo) & (rho < r - EPS_MM)
    if hi is not None:
        m &= a <= hi
    return m


def _segments(tool) -> list[tuple[float, Optional[float], float]]:
    if not isinstance(tool, ToolAssembly):
        raise ParameterError("tool must be a planning.geometry.tool.ToolAssembly")
    out = []
    for s in tool.segments:
        lo = float(s.lo_mm)
        hi = None if s.hi_mm is None else float(s.hi_mm)
        r = float(s.radius_mm)
        if not (math.isfinite(lo) and (hi is None or math.isfinite(hi)) and math.isfinite(r)):
            raise ParameterError("tool segments must be finite")
        if lo < 0:
            raise ParameterError(f"tool segment starts below the ball centre (lo_mm = {lo})")
        if r - EPS_MM <= 0 or (hi is not None and hi <= lo):
            continue            # an empty cylinder collides with nothing
        out.append((lo, hi, r))
    return out


def _as_queries(segs):
    """The same union of cylinders, with a segment made unbounded where the stack above it is
    contiguous, unbounded and nowhere narrower (its points above ``hi`` collide anyway): an
    unbounded query can be settled by the under-reporting filter alone."""
    segs = sorted(segs, key=lambda s: s[0])
    merged = []
    for lo, hi, r in segs:          # join touching segments of one radius (cutter and shank)
        if merged and merged[-1][2] == r and merged[-1][1] is not None and merged[-1][1] == lo:
            merged[-1] = (merged[-1][0], hi, r)
        else:
            merged.append((lo, hi, r))
    segs = merged
    out = []
    for k, (lo, hi, r) in enumerate(segs):
        above = segs[k:]
        ok = above[-1][1] is None and all(
            a[1] is not None and a[1] == b[0] for a, b in zip(above[:-1], above[1:])) \
            and all(s[2] >= r for s in above)
        out.append((lo, None if ok else hi, r))
    return out


def _validate(points, sample_index, normals, axes, tool, candidates, obstacles):
    points = np.asarray(points, dtype=np.float64)
    sample_index = np.asarray(sample_index, dtype=np.int64).reshape(-1)
    normals = np.asarray(normals, dtype=np.float64)
    axes = np.asarray(axes, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ParameterError("points must be an (N,3) array")
    if normals.ndim != 2 or normals.shape[1] != 3 or normals.shape[0] != sample_index.shape[0]:
        raise ParameterError("normals must be (n,3) with one row per sample_index entry")
    if axes.ndim != 2 or axes.shape[1] != 3:
        raise ParameterError("axes must be an (m,3) array")
    if sample_index.size and (sample_index.min() < 0 or sample_index.max() >= points.shape[0]):
        raise ParameterError("sample_index out of range")
    if not np.all(np.isfinite(points)) or not np.all(np.isfinite(normals)) \
            or not np.all(np.isfinite(axes)):
        raise ParameterError("points, normals and axes must be finite")
    segs = _segments(tool)
    n, m = normals.shape[0], axes.shape[0]
    if candidates is not None:
        candidates = np.asarray(candidates, dtype=bool)
        if candidates.shape != (n, m):
            raise ParameterError(f"candidates must be ({n},{m}), got {candidates.shape}")
    obst = points
    if obstacles is not None:
        extra = np.asarray(obstacles, dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(extra)):
            raise ParameterError("obstacle points must be finite")
        obst = np.concatenate([points, extra]) if extra.size else points
    return points, obst, sample_index, normals, axes, float(tool.radius_mm), segs, candidates


def brute_force_collision_free(points, sample_index, normals, axes, tool: ToolAssembly, *,
                               candidates=None, obstacles=None,
                               progress: Optional[Callable] = None) -> np.ndarray:
    """Reference for :func:`cloud_collision_free`: every pair against every obstacle point.

    Same arguments, definitions and result; O(n * m * N), for small clouds and tests only.
    """
    points, obst, sample_index, normals, axes, R, segs, candidates = _validate(
        points, sample_index, normals, axes, tool, candidates, obstacles)
    n, m = normals.shape[0], axes.shape[0]
    centres = points[sample_index] + R * normals
    out = np.zeros((n, m), dtype=bool)
    for j in range(m):
        t = axes[j]
        for i in range(n):
            if candidates is not None and not candidates[i, j]:
                continue
            d = obst - centres[i]
            hit = np.zeros(obst.shape[0], dtype=bool)
            for lo, hi, r in segs:
                hit |= _inside(d, t, lo, hi, r)
            out[i, j] = not hit.any()
        if progress is not None:
            progress(j + 1, m)
    return out


# ----------------------------------------------------------------------------------------------
# fast method (numba kernels)

def _offsets(r_eff: float, h: float, slack: float):
    """Cell offsets of the over-reporting disk, the under-reporting disk, and the ring between."""
    k = int(np.ceil((r_eff + slack) / h)) + 2
    di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1), indexing="ij")
    adi, adj = np.abs(di), np.abs(dj)
    near = h * np.hypot(np.maximum(adi - 1, 0), np.maximum(adj - 1, 0))
    far = h * np.hypot(adi + 1, adj + 1)
    over = near < r_eff + slack
    under = far < r_eff - slack
    return k, di, dj, over, under


def _disk_max(mz: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``ndimage.maximum_filter(mz, footprint=fp, mode="constant", cval=-inf)`` for a footprint
    whose rows are intervals centred on the middle column (a disk): one 1-D running max per
    distinct row width, then a max over the shifted rows. Exactly the same values (max is exact)."""
    kk = fp.shape[0] // 2
    widths = fp.sum(axis=1)
    for a in range(fp.shape[0]):
        w = int(widths[a])
        if w and (w % 2 == 0 or not fp[a, kk - w // 2:kk + w // 2 + 1].all()):
            return ndimage.maximum_filter(mz, footprint=fp, mode="constant", cval=-np.inf)
    nx = mz.shape[0]
    out = np.full(mz.shape, -np.inf)
    cache = {}
    for a in range(fp.shape[0]):
        w = int(widths[a])
        if w == 0:
            continue
        f = cache.get(w)
        if f is None:
            f = cache[w] = ndimage.maximum_filter1d(mz, w, axis=1, mode="constant", cval=-np.inf)
        di = a - kk
        if abs(di) >= nx:
            continue
        if di >= 0:
            np.maximum(out[:nx - di], f[di:], out=out[:nx - di])
        else:
            np.maximum(out[-di:], f[:nx + di], out=out[-di:])
    return out



@njit(cache=True, nogil=True)
def _project(x, u, v, t):
    """Rows of ``x`` (k,3) with their projections: (k,6) = (x, y, z, x.u, x.v, x.t), the last in the
    reference's operation order. One row per point keeps the scan's reads in one place."""
    out = np.empty((x.shape[0], 6))
    for i in range(x.shape[0]):
        _put_row(out, i, x[i, 0], x[i, 1], x[i, 2], u, v, t)
    return out


@njit(cache=True, nogil=True, inline="always")
def _put_row(out, r, a, b, c, u, v, t):
    """Row ``r`` of ``out``: the point (a, b, c) and its projections on u, v, t (:func:`_project`)."""
    out[r, 0] = a
    out[r, 1] = b
    out[r, 2] = c
    out[r, 3] = a * u[0] + b * u[1] + c * u[2]
    out[r, 4] = a * v[0] + b * v[1] + c * v[2]
    out[r, 5] = a * t[0] + b * t[1] + c * t[2]


@njit(cache=True, nogil=True)
def _query(spts, centres, rows, t, cx, cy, cz, lo, hi, bounded, r, start, cmax, cmin,
           x0, y0, h, nx, ny, slack, tol, hit):
    """Set ``hit[k]`` when an obstacle point lies in segment (lo, hi, r) of centre rows[k]."""
    rr = r - 1e-6 + slack
    r_eff = r - 1e-6
    rr2 = rr * rr
    r2_in = r_eff * r_eff * (1.0 - 1e-12)
    r2_out = r_eff * r_eff * (1.0 + 1e-12)
    t0, t1, t2 = t[0], t[1], t[2]
    for k in range(rows.shape[0]):
        if hit[k]:
            continue
        i = rows[k]
        c0, c1, c2 = centres[i, 0], centres[i, 1], centres[i, 2]
        px, py = cx[k], cy[k]
        thr_lo = cz[k] + lo - tol
        thr_hi = cz[k] + hi + tol
        ix0 = max(int(math.floor((px - rr - x0) / h)), 0)
        ix1 = min(int(math.floor((px + rr - x0) / h)), nx - 1)
        found = False
        for ix in range(ix0, ix1 + 1):
            if found:
                break
            xa = x0 + ix * h
            gx = 0.0
            if px < xa:
                gx = xa - px
            elif px > xa + h:
                gx = px - (xa + h)
            if gx >= rr:
                continue
            half = math.sqrt(rr * rr - gx * gx)
            iy0 = max(int(math.floor((py - half - y0) / h)), 0)
            iy1 = min(int(math.floor((py + half - y0) / h)), ny - 1)
            base = ix * ny
            for iy in range(iy0, iy1 + 1):
                cc = base + iy
                if cmax[cc] <= thr_lo:
                    continue
                if bounded and cmin[cc] > thr_hi:
                    continue
                for s in range(start[cc], start[cc + 1]):
                    # projected prefilter, conservative by the rounding margins
                    if spts[s, 5] <= thr_lo:
                        continue
                    if bounded and spts[s, 5] > thr_hi:
                        continue
                    e0 = spts[s, 3] - px
                    e1 = spts[s, 4] - py
                    if e0 * e0 + e1 * e1 >= rr2:
                        continue
                    d0 = spts[s, 0] - c0
                    d1 = spts[s, 1] - c1
                    d2 = spts[s, 2] - c2
                    a = d0 * t0 + d1 * t1 + d2 * t2
                    if a > lo and ((not bounded) or a <= hi):
                        w0 = d0 - a * t0
                        w1 = d1 - a * t1
                        w2 = d2 - a * t2
                        w = w0 * w0 + w1 * w1 + w2 * w2
                        # rho < r_eff decided on the square where it is clear-cut (the
                        # relative margin dwarfs rounding); sqrt, as the reference, otherwise
                        if w < r2_in:
                            found = True
                            break
                        if w <= r2_out and math.sqrt(w) < r_eff:
                            found = True
                            break
                if found:
                    break
        if found:
            hit[k] = True


def cloud_collision_free(points, sample_index, normals, axes, tool: ToolAssembly, *,
                         candidates=None, obstacles=None, progress: Optional[Callable] = None,
                         cell_fraction: float = 0.35) -> np.ndarray:
    """Bool (n, m): True where sample i machined along axis j leaves every obstacle point outside
    the tool assembly (Makki 2010 §2.2.4, cloud part of the global visibility).

    ``points`` (N,3) mm is the whole cloud; ``sample_index`` (n,) picks the sampled points and
    ``normals`` (n,3) their unit outward normals; ``axes`` (m,3) are unit tool axes in the part
    frame pointing from the part to the spindle; ``tool`` gives the ball radius ``R`` (ball centre
    ``c = p + R n``) and the cutter, shank and holder cylinders above the centre. ``obstacles``
    (K,3) mm: extra obstacle points (forbidden regions given as point clouds) checked like the
    cloud. The collision rule is in the module docstring; the ball's lower half is not tested
    (local gouging belongs to the tool paths).

    ``candidates`` (n,m) bool, optional: only these pairs are evaluated, the others are False.
    ``progress(done_axes, m)`` is called after each axis. ``cell_fraction`` sets the raster cell
    to that fraction of the smallest segment radius of each raster (speed only, never the answer). Agrees with
    :func:`brute_force_collision_free` pair for pair: it never calls a colliding pair free.
    """
    points, obst, sample_index, normals, axes, R, segs, candidates = _validate(
        points, sample_index, normals, axes, tool, candidates, obstacles)
    if not 0 < float(cell_fraction) <= 2:
        raise ParameterError("cell_fraction must be in (0, 2]")
    return _collision_free(obst, np.ascontiguousarray(points[sample_index] + R * normals), axes, segs, candidates,
                           progress, cell_fraction)


def centres_collision_free(obstacles, centres, axes, tool: ToolAssembly, *, candidates=None,
                           progress: Optional[Callable] = None, cell_fraction: float = 0.35) -> np.ndarray:
    """Bool (n, m): True where the tool assembly with its ball centre at ``centres[i]`` (part frame,
    mm) and axis ``axes[j]`` leaves every point of ``obstacles`` (K,3) outside the cutter, shank and
    holder segments above the ball centre (the rule of the module docstring; the ball itself is not
    tested). Used on tool path CL points (the ball drop keeps the ball itself clear); same method
    and same exactness as :func:`cloud_collision_free`."""
    centres = np.ascontiguousarray(centres, dtype=np.float64).reshape(-1, 3)
    obst, _, _, _, axes, _, segs, candidates = _validate(
        obstacles, np.zeros(0, np.int64), np.zeros((0, 3)), axes, tool, None, None)
    if not np.all(np.isfinite(centres)):
        raise ParameterError("centres must be finite")
    if not 0 < float(cell_fraction) <= 2:
        raise ParameterError("cell_fraction must be in (0, 2]")
    if candidates is not None:
        candidates = np.asarray(candidates, dtype=bool)
        if candidates.shape != (centres.shape[0], axes.shape[0]):
            raise ParameterError(f"candidates must be ({centres.shape[0]},{axes.shape[0]}), got {candidates.shape}")
    return _collision_free(np.ascontiguousarray(obst), centres, axes, segs, candidates, progress, cell_fraction)


def _collision_free(obst, centres, axes, segs, candidates, progress, cell_fraction):
    """Bool (n, m) of :func:`cloud_collision_free` and :func:`centres_collision_free` from validated
    inputs: the rounding margins of the whole problem, then :func:`_axis_hits` per axis."""
    n, m = centres.shape[0], axes.shape[0]
    out = np.zeros((n, m), dtype=bool)
    if n == 0 or m == 0:
        return out
    obst = np.ascontiguousarray(obst)
    scale = float(max(np.abs(obst).max(), np.abs(centres).max(), 1.0))
    slack = 1e-9 * scale     # rounding of projections and of the cell assignment, mm
    tol = 1e-9 * scale       # height margin of the cell skips, mm
    ext = float(max(np.ptp(obst, axis=0).max(), np.ptp(centres, axis=0).max())) + 1.0
    segs = _as_queries(segs)
    groups = _radius_groups(segs)
    cand_t = None if candidates is None else np.ascontiguousarray(candidates.T)

    def one_axis(j):
        rows = np.arange(n) if cand_t is None else np.flatnonzero(cand_t[j])
        if rows.size and segs:
            return rows, _axis_hits(obst, centres[rows], axes[j], segs, groups, cell_fraction, slack, tol, ext)
        return rows, np.zeros(rows.size, dtype=np.bool_)

    _each_axis(one_axis, out, progress)
    return out


def _radius_groups(segs) -> list[list[float]]:
    """The segments' distinct radii, ascending, in groups that share a raster: at most
    ``_RADII_PER_RASTER`` times the group's smallest."""
    radii = sorted({r for _, _, r in segs})
    groups: list[list[float]] = []          # radii sharing a raster: at most 10x the smallest
    for r in radii:
        if groups and r <= _RADII_PER_RASTER * groups[-1][0]:
            groups[-1].append(r)
        else:
            groups.append([r])
    return groups


def _axis_hits(obst, cs, axis, segs, groups, cell_fraction, slack, tol, ext) -> np.ndarray:
    """Bool per centre of ``cs`` (k,3): an obstacle point lies in a segment of the tool along
    ``axis`` (the two disk filters, then the :func:`_query` kernel for the pairs they leave)."""
    t_ref = np.ascontiguousarray(axis)     # the exact test uses the axis as given
    t = t_ref / np.linalg.norm(t_ref)
    u, v = complete_basis(t)
    cproj = _project(cs, u, v, t_ref)
    cx, cy, cz = cproj[:, 3], cproj[:, 4], cproj[:, 5]
    o_lo0, o_lo1, o_hi0, o_hi1 = _projected_bounds(obst, u, v)
    bounds = (min(o_lo0, float(cx.min())), min(o_lo1, float(cy.min())), max(o_hi0, float(cx.max())),
              max(o_hi1, float(cy.max())))
    hit = np.zeros(cs.shape[0], dtype=np.bool_)
    for group in groups:
        # one raster per group of radii, its cell set by the group's smallest radius
        # (sorting the obstacles is the dominant cost on a large cloud)
        x0, y0, h, nx, ny, spts, start, cmax, cmin = _raster(obst, u, v, t_ref, bounds, group, cell_fraction,
                                                             slack, ext)
        mz = cmax.reshape(nx, ny)
        ccell = np.floor((cx - x0) / h).astype(np.int64) * ny + np.floor((cy - y0) / h).astype(np.int64)
        for r in group:
            # per centre cell: the highest point of every cell that may come within r of a
            # centre anywhere in the cell (over-reports) and of the cells wholly within r of
            # every such centre (under-reports)
            _, _, _, over, under = _offsets(r - EPS_MM, h, slack)
            m_over = _disk_max(mz, over).ravel()[ccell]
            m_under = _disk_max(mz, under).ravel()[ccell] if under.any() else None
            for lo, hi, rs in segs:
                if rs != r:
                    continue
                thr = cz + lo
                todo = ~hit & (m_over > thr - tol)          # the others are surely free
                if hi is None and m_under is not None:
                    sure = todo & (m_under > thr + tol)     # a point surely inside
                    hit |= sure
                    todo &= ~sure
                sel = np.flatnonzero(todo)
                if sel.size == 0:
                    continue
                sub = np.zeros(sel.size, dtype=np.bool_)
                _query(spts, cs, sel, t_ref, cx[sel], cy[sel], cz[sel], lo,
                       0.0 if hi is None else hi, hi is not None, r, start, cmax, cmin,
                       x0, y0, h, nx, ny, slack, tol, sub)
                hit[sel] |= sub
    return hit


@njit(cache=True, nogil=True)
def _sorted_projection(x, u, v, t, x0, y0, h, nx, ny):
    """:func:`_project`, :func:`planning.geometry.raster.bin_cells` on its columns 3-5 and
    :func:`planning.geometry.raster.rows_in_order` in one kernel, without the unsorted (k,6) array:
    the projections are computed twice with the same expressions (so the same values), once to count
    the cells and once to write each row at its place. Returns (spts, start, cmax, cmin) exactly as
    the three calls would. On a million obstacles this reads the cloud twice instead of writing,
    sorting and gathering 48 MB per raster: the rasters were most of the collision test's time."""
    n = x.shape[0]
    ncell = nx * ny
    cell, start, cmax, cmin = new_cells(n, ncell)
    for i in range(n):
        a, b, c = x[i, 0], x[i, 1], x[i, 2]
        pu = a * u[0] + b * u[1] + c * u[2]
        pv = a * v[0] + b * v[1] + c * v[2]
        pt = a * t[0] + b * t[1] + c * t[2]
        cc = cell_of(pu, pv, x0, y0, h, nx, ny)
        cell[i] = cc
        tally(cc, pt, start, cmax, cmin)
    for cc in range(ncell):
        start[cc + 1] += start[cc]
    fill = start[:-1].copy()
    out = np.empty((n, 6))
    for i in range(n):
        cc = cell[i]
        r = fill[cc]
        fill[cc] = r + 1
        _put_row(out, r, x[i, 0], x[i, 1], x[i, 2], u, v, t)
    return out, start, cmax, cmin


@njit(cache=True, nogil=True)
def _projected_bounds(x, u, v):
    """Smallest and largest ``x.u`` and ``x.v`` over the rows of ``x`` (k,3), in :func:`_project`'s
    operation order (the same values), without storing the projections."""
    lo0 = lo1 = np.inf
    hi0 = hi1 = -np.inf
    for i in range(x.shape[0]):
        a, b, c = x[i, 0], x[i, 1], x[i, 2]
        pu = a * u[0] + b * u[1] + c * u[2]
        pv = a * v[0] + b * v[1] + c * v[2]
        lo0 = min(lo0, pu)
        hi0 = max(hi0, pu)
        lo1 = min(lo1, pv)
        hi1 = max(hi1, pv)
    return lo0, lo1, hi0, hi1


def _raster(obst, u, v, t_ref, bounds, group, cell_fraction, slack, ext):
    """The raster of one group of radii over the obstacles ``obst`` (k,3) projected on the basis
    ``u, v, t_ref`` (``bounds``: the projections' (u min, v min, u max, v max) with the centres'):
    cell side ``h`` (mm) from the group's smallest radius, origin ``x0, y0``, ``nx`` x ``ny`` cells
    padded by the largest radius, and the projected obstacles (rows of :func:`_project`) sorted by
    cell (:func:`_sorted_projection`): ``spts``, ``start``, per-cell ``cmax``, ``cmin``."""
    bx0, by0, bx1, by1 = bounds
    h = max(cell_fraction * group[0], ext / math.sqrt(_MAX_GRID_CELLS))
    k_pad = int(math.ceil((group[-1] + slack) / h)) + 3
    x0 = bx0 - k_pad * h
    y0 = by0 - k_pad * h
    nx = int((bx1 - x0) / h) + k_pad + 2
    ny = int((by1 - y0) / h) + k_pad + 2
    spts, start, cmax, cmin = _sorted_projection(obst, u, v, t_ref, x0, y0, h, nx, ny)
    return x0, y0, h, nx, ny, spts, start, cmax, cmin


def _each_axis(one_axis, out: np.ndarray, progress) -> None:
    """``out[rows, j] = ~hit`` for ``rows, hit = one_axis(j)``, every axis j of ``out``, in order."""
    m = out.shape[1]
    # axes are independent and the kernels release the GIL: up to two threads (the cores here), never
    # more than the plan's own thread budget (numba's threads: a service job's SCANMILL_WORKER_THREADS)
    workers = min(_THREADS, max(1, numba.get_num_threads()), m)
    if workers > 1:
        from concurrent.futures import ThreadPoolExecutor
        with ThreadPoolExecutor(max_workers=workers) as ex:
            for j, (rows, hit) in enumerate(ex.map(one_axis, range(m))):
                out[rows, j] = ~hit
                if progress is not None:
                    progress(j + 1, m)
    else:
        for j in range(m):
            rows, hit = one_axis(j)
            out[rows, j] = ~hit
            if progress is not None:
                progress(j + 1, m)
