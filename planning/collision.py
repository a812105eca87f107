"""Global visibility (Makki 2010 §2.2.4): cloud collisions of a ball-end cutter and its holder.

For a sampled point ``p = points[sample_index[i]]`` with unit normal ``n = normals[i]`` and a
candidate tool axis ``t = axes[j]`` (unit, part frame, pointing from the part to the spindle) the
ball of radius ``R`` touches ``p`` with its centre at ``c = p + R n``. For every cloud point ``q``
let ``d = q - c``, ``a = d . t`` (height above the ball centre along the axis) and
``rho = |d - a t|`` (radial distance from the axis). With ``eps = 1e-6`` mm:

* the cutter collides with ``q`` when ``0 < a <= L`` and ``rho < R - eps``
  (``L = flute_length_mm``: the cylinder from the ball centre to the top of the flutes);
* the holder collides with ``q`` when ``L < a <= L + H`` and ``rho < R_h - eps``
  (``R_h = holder_radius_mm``, ``H = holder_length_mm``; ``H = None`` means an infinitely long
  holder, ``R_h = None`` means no holder at all).

The pair (i, j) is collision free when no cloud point collides. Points below the ball centre
(``a <= 0``) are left to the ball itself: the local gouge test belongs to the tool paths. The
contact point and its surface neighbours lie at or below the centre for any admissible axis, and
the ``eps`` keeps points exactly on the cylinder wall (a flat floor met by a tilted axis) free.

``brute_force_collision_free`` is the reference (every pair against every point).
``cloud_collision_free`` is the fast method (DESIGN.md, Performance, "Global visibility"): per
axis the cloud is projected onto the plane normal to the axis and rastered into square cells
keeping the highest point of each cell. The question "is there a point within radius r of the
axis and higher than the centre" is answered by two disk max filters evaluated at the centre's
cell: one over every cell that *may* hold a point within r of a centre anywhere in its cell (it can
only over-report) and one over the cells that lie *wholly* within r (it can only under-report).
Pairs the two disagree on, and pairs of height-bounded questions (a finite flute length without a
holder above it, a finite holder), get the exact test above on the points of the relevant cells,
gathered through a CSR cell -> points index. Filter decisions keep a float margin, so a pair is
only called free by a filter when every point is below the centre by more than rounding; the
exact test uses the same arithmetic as the reference, so both agree pair for pair.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np
from scipy import ndimage

from planning.errors import ParameterError

EPS_MM = 1e-6
_MAX_GRID_CELLS = 4_000_000
_MAX_PAIR_CELLS = 2_000_000
_MAX_GATHER = 4_000_000


# ----------------------------------------------------------------------------------------------
# shared arithmetic (the reference and the fast exact step use exactly the same expressions)

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


def _validate(points, sample_index, normals, axes, tool_radius_mm, flute_length_mm,
              holder_radius_mm, holder_length_mm, candidates):
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
    R = float(tool_radius_mm)
    L = float(flute_length_mm)
    if not R > 0:
        raise ParameterError(f"tool_radius_mm = {tool_radius_mm}: must be > 0")
    if not L >= 0:
        raise ParameterError(f"flute_length_mm = {flute_length_mm}: must be >= 0")
    Rh = None if holder_radius_mm is None else float(holder_radius_mm)
    H = None if holder_length_mm is None or Rh is None else float(holder_length_mm)
    if Rh is not None and not Rh > 0:
        raise ParameterError(f"holder_radius_mm = {holder_radius_mm}: must be > 0")
    if H is not None and not H > 0:
        raise ParameterError(f"holder_length_mm = {holder_length_mm}: must be > 0")
    n, m = normals.shape[0], axes.shape[0]
    if candidates is not None:
        candidates = np.asarray(candidates, dtype=bool)
        if candidates.shape != (n, m):
            raise ParameterError(f"candidates must be ({n},{m}), got {candidates.shape}")
    return points, sample_index, normals, axes, R, L, Rh, H, candidates


def _queries(R, L, Rh, H):
    """The collision region as a union of (lo, hi, r): lo < a <= hi (hi None: unbounded), rho < r-eps."""
    if Rh is None:
        return [(0.0, L, R)]
    if H is None:
        if Rh >= R:
            # {0<a<=L, rho<R} u {a>L, rho<Rh} == {a>0, rho<R} u {a>L, rho<Rh}
            return [(0.0, None, R), (L, None, Rh)]
        # == {a>0, rho<Rh} u {0<a<=L, rho<R}
        return [(0.0, None, Rh), (0.0, L, R)]
    return [(0.0, L, R), (L, L + H, Rh)]


def brute_force_collision_free(points, sample_index, normals, axes, *, tool_radius_mm,
                               flute_length_mm, holder_radius_mm=None, holder_length_mm=None,
                               candidates=None, progress: Optional[Callable] = None) -> np.ndarray:
    """Reference for :func:`cloud_collision_free`: every pair against every cloud point.

    Same arguments, definitions and result; O(n * m * N), for small clouds and tests only.
    """
    points, sample_index, normals, axes, R, L, Rh, H, candidates = _validate(
        points, sample_index, normals, axes, tool_radius_mm, flute_length_mm,
        holder_radius_mm, holder_length_mm, candidates)
    n, m = normals.shape[0], axes.shape[0]
    centres = points[sample_index] + R * normals
    out = np.zeros((n, m), dtype=bool)
    for j in range(m):
        t = axes[j]
        for i in range(n):
            if candidates is not None and not candidates[i, j]:
                continue
            d = points - centres[i]
            hit = _inside(d, t, 0.0, L, R)
            if Rh is not None:
                hit |= _inside(d, t, L, None if H is None else L + H, Rh)
            out[i, j] = not hit.any()
        if progress is not None:
            progress(j + 1, m)
    return out


# ----------------------------------------------------------------------------------------------
# fast method

def _basis(t: np.ndarray):
    """Two unit vectors completing ``t`` to an orthonormal frame."""
    k = int(np.argmin(np.abs(t)))
    e = np.zeros(3)
    e[k] = 1.0
    u = np.cross(t, e)
    u /= np.linalg.norm(u)
    v = np.cross(t, u)
    return u, v


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


class _AxisRaster:
    """Points and centres projected along one axis, binned on a square grid (CSR cell -> points)."""

    def __init__(self, px, py, pz, cx, cy, h, pad):
        x0 = min(px.min(), cx.min()) - pad * h
        y0 = min(py.min(), cy.min()) - pad * h
        nx = int(np.floor((max(px.max(), cx.max()) - x0) / h)) + pad + 2
        ny = int(np.floor((max(py.max(), cy.max()) - y0) / h)) + pad + 2
        self.nx, self.ny = nx, ny
        self.x0, self.y0, self.h = x0, y0, h
        self.cx, self.cy = cx, cy
        pix = np.floor((px - x0) / h).astype(np.int64)
        piy = np.floor((py - y0) / h).astype(np.int64)
        self.cix = np.floor((cx - x0) / h).astype(np.int64)
        self.ciy = np.floor((cy - y0) / h).astype(np.int64)
        cell = pix * ny + piy
        order = np.lexsort((-pz, cell))      # by cell, highest point first within a cell
        sc = cell[order]
        self.sz = pz[order]
        self.sx = px[order]
        self.sy = py[order]
        self.order = order
        ncell = nx * ny
        self.start = np.searchsorted(sc, np.arange(ncell + 1))
        self.count = np.diff(self.start)
        mz = np.full(ncell, -np.inf)
        nz = self.count > 0
        firsts = self.start[:-1][nz]
        mz[nz] = np.maximum.reduceat(pz[order], firsts)
        self.mz_flat = mz
        self.mz = mz.reshape(nx, ny)


def _exact(raster: _AxisRaster, points, centres_sel, t, thr, lo, hi, r, pair_rows, dis, djs, tol,
           slack):
    """Exact test of pairs ``pair_rows`` (rows into centres_sel/thr) over the given cell offsets.

    Returns bool per pair row: some point collides."""
    hit = np.zeros(pair_rows.size, dtype=bool)
    k = dis.size
    if k == 0 or pair_rows.size == 0:
        return hit
    step = max(1, _MAX_PAIR_CELLS // k)
    ny = raster.ny
    for s in range(0, pair_rows.size, step):
        rows = pair_rows[s:s + step]
        cells = (raster.cix[rows][:, None] + dis[None, :]) * ny + (raster.ciy[rows][:, None] + djs[None, :])
        keep = raster.mz_flat[cells] > (thr[rows] - tol)[:, None]
        loc, col = np.nonzero(keep)
        if loc.size == 0:
            continue
        # keep only the cells that may hold a point within r of this very centre (not just of
        # some centre in its cell)
        rl = rows[loc]
        hx = raster.h
        ix = (raster.cix[rl] + dis[col]) * hx + raster.x0
        iy = (raster.ciy[rl] + djs[col]) * hx + raster.y0
        pcx, pcy = raster.cx[rl], raster.cy[rl]
        gx = np.maximum(np.maximum(ix - pcx, pcx - (ix + hx)), 0.0)
        gy = np.maximum(np.maximum(iy - pcy, pcy - (iy + hx)), 0.0)
        lim = r - EPS_MM + slack
        near = gx * gx + gy * gy < lim * lim
        loc, col = loc[near], col[near]
        if loc.size == 0:
            continue
        cc = cells[loc, col]
        # only the points of a cell higher than the threshold matter: binary search in the
        # cell's run, sorted by decreasing height
        th = (thr[rows] - tol)[loc]
        lo_i = raster.start[cc].copy()
        hi_i = lo_i + raster.count[cc]
        act = np.flatnonzero(lo_i < hi_i)
        while act.size:
            mid = (lo_i[act] + hi_i[act]) // 2
            above = raster.sz[mid] > th[act]
            lo_i[act[above]] = mid[above] + 1
            hi_i[act[~above]] = mid[~above]
            act = act[lo_i[act] < hi_i[act]]
        cnt = lo_i - raster.start[cc]
        # split so the gathered points stay bounded
        csum = np.cumsum(cnt)
        bounds = [0]
        base = 0
        while bounds[-1] < cc.size:
            nxt = int(np.searchsorted(csum, base + _MAX_GATHER, side="right"))
            nxt = max(nxt, bounds[-1] + 1)
            bounds.append(min(nxt, cc.size))
            base = int(csum[bounds[-1] - 1])
        for b0, b1 in zip(bounds[:-1], bounds[1:]):
            c_cnt = cnt[b0:b1]
            tot = int(c_cnt.sum())
            if tot == 0:
                continue
            owner = np.repeat(loc[b0:b1], c_cnt)
            first = np.repeat(raster.start[cc[b0:b1]] - (np.cumsum(c_cnt) - c_cnt), c_cnt)
            sidx = first + np.arange(tot)
            # 2-D prefilter on the projected distance (conservative by slack), then the exact test
            ro = rows[owner]
            ex = raster.sx[sidx] - raster.cx[ro]
            ey = raster.sy[sidx] - raster.cy[ro]
            cand = np.flatnonzero(ex * ex + ey * ey < lim * lim)
            if cand.size == 0:
                continue
            own = owner[cand]
            d = points[raster.order[sidx[cand]]] - centres_sel[rows[own]]
            ins = _inside(d, t, lo, hi, r)
            if ins.any():
                hit[s + np.unique(own[ins])] = True
    return hit


def cloud_collision_free(points, sample_index, normals, axes, *, tool_radius_mm, flute_length_mm,
                         holder_radius_mm=None, holder_length_mm=None, candidates=None,
                         progress: Optional[Callable] = None,
                         cell_fraction: float = 0.2) -> np.ndarray:
    """Bool (n, m): True where sample i machined along axis j touches no cloud point.

    ``points`` (N,3) is the whole cloud; ``sample_index`` (n,) picks the sampled points and
    ``normals`` (n,3) their unit outward normals; ``axes`` (m,3) are unit tool axes in the part
    frame pointing from the part to the spindle. A cloud point ``q`` collides with pair (i, j) when,
    with ``c = points[sample_index[i]] + R normals[i]``, ``d = q - c``, ``a = d . t`` and
    ``rho = |d - a t|``: ``0 < a <= flute_length_mm`` and ``rho < R - 1e-6`` (cutter), or
    ``flute_length_mm < a <= flute_length_mm + holder_length_mm`` and
    ``rho < holder_radius_mm - 1e-6`` (holder; ``holder_length_mm=None``: unbounded;
    ``holder_radius_mm=None``: no holder). Points below the ball centre (``a <= 0``) are ignored:
    the local gouge test belongs to the tool paths. See the module docstring for the method.

    ``candidates`` (n,m) bool, optional: only these pairs are evaluated, the others are False.
    ``progress(done_axes, m)`` is called after each axis. ``cell_fraction`` sets the raster cell to
    that fraction of the smallest query radius (at least 1/8 of each query radius; it changes
    speed only, never the answer). Agrees with
    :func:`brute_force_collision_free` pair for pair; never calls a colliding pair free.
    """
    points, sample_index, normals, axes, R, L, Rh, H, candidates = _validate(
        points, sample_index, normals, axes, tool_radius_mm, flute_length_mm,
        holder_radius_mm, holder_length_mm, candidates)
    if not 0 < float(cell_fraction) <= 1:
        raise ParameterError("cell_fraction must be in (0, 1]")
    n, m = normals.shape[0], axes.shape[0]
    out = np.zeros((n, m), dtype=bool)
    if n == 0 or m == 0:
        return out
    centres = points[sample_index] + R * normals
    scale = float(max(np.abs(points).max(), np.abs(centres).max(), 1.0))
    slack = 1e-9 * scale      # covers rounding of projections and cell assignment
    tol = 1e-9 * scale        # height margin of the filter decisions
    queries = [q for q in _queries(R, L, Rh, H) if q[2] - EPS_MM > 0 and (q[1] is None or q[1] > q[0])]
    ext = float(np.ptp(points, axis=0).max() + 2 * R) if points.shape[0] else 1.0
    r_min = min(q[2] for q in queries) if queries else R
    def one_axis(j):
        t = axes[j] / np.linalg.norm(axes[j])
        t_ref = axes[j]   # the exact test uses the axis as given, like the reference
        rows_all = np.arange(n) if candidates is None else np.flatnonzero(candidates[:, j])
        if rows_all.size == 0:
            return rows_all, np.zeros(0, dtype=bool)
        u, v = _basis(t)
        px = points @ u
        py = points @ v
        pz = points[:, 0] * t_ref[0] + points[:, 1] * t_ref[1] + points[:, 2] * t_ref[2]
        cs = centres[rows_all]
        cx = cs @ u
        cy = cs @ v
        cz = cs[:, 0] * t_ref[0] + cs[:, 1] * t_ref[1] + cs[:, 2] * t_ref[2]
        hit = np.zeros(rows_all.size, dtype=bool)
        for lo, hi, r in queries:
            todo = np.flatnonzero(~hit)
            if todo.size == 0:
                break
            r_eff = r - EPS_MM
            # one cell size for all queries, set by the smallest radius (a wide holder disk
            # with fine cells has a thin undecided ring: far fewer pairs and points to check)
            h = cell_fraction * max(r_min, r / 8.0)
            while (ext / h + 10) ** 2 > _MAX_GRID_CELLS:
                h *= 1.5
            k, di, dj, over, under = _offsets(r_eff, h, slack)
            raster = _AxisRaster(px, py, pz, cx, cy, h, k + 1)
            thr = cz + lo
            ci, cj = raster.cix[todo], raster.ciy[todo]
            mo = _disk_max(raster.mz, over)[ci, cj]
            sure_free = mo <= thr[todo] - tol
            if hi is None:
                mu = _disk_max(raster.mz, under)[ci, cj]
                sure_hit = mu > thr[todo] + tol
                hit[todo[sure_hit & ~sure_free]] = True
                amb = ~sure_free & ~sure_hit
                ring = over & ~under
                amb_ring = amb & (mu <= thr[todo] - tol)    # wholly-inside cells all below centre
                amb_full = amb & ~amb_ring
                for sel, fp in ((amb_ring, ring), (amb_full, over)):
                    rows = todo[sel]
                    if rows.size:
                        hit[rows] |= _exact(raster, points, cs, t_ref, thr, lo, hi, r, rows,
                                            di[fp], dj[fp], tol, slack)
            else:
                rows = todo[~sure_free]
                if rows.size:
                    hit[rows] |= _exact(raster, points, cs, t_ref, thr, lo, hi, r, rows,
                                        di[over], dj[over], tol, slack)
        return rows_all, hit

    # axes are independent; numpy releases the GIL in the heavy array work, so two threads
    # overlap well (results and progress stay in axis order)
    workers = min(2, m)
    if workers > 1:
        from concurrent.futures import ThreadPoolExecutor
        with ThreadPoolExecutor(max_workers=workers) as ex:
            for j, (rows_all, hit) in enumerate(ex.map(one_axis, range(m))):
                out[rows_all, j] = ~hit
                if progress is not None:
                    progress(j + 1, m)
    else:
        for j in range(m):
            rows_all, hit = one_axis(j)
            out[rows_all, j] = ~hit
            if progress is not None:
                progress(j + 1, m)
    return out
