"""The rasters of the Z-level roughing (:mod:`planning.toolpath.roughing`), in mm in the area
frame: the forbidden map (where the tool tip may stand at a level) and the remaining-material map
(how high the stock still stands, for the lifts). Stage: built once per set-up by
:func:`planning.toolpath.roughing.levels.roughing_paths`, read per level by
:mod:`planning.toolpath.roughing.regions` (the forbidden map) and
:mod:`planning.toolpath.roughing.links` (the material map), lowered after each level.

**Binary map per level (Popescu et al. 2014's map, made conservative).** A square XY raster (cell
``h`` = ``cell_mm``, default ``Rt / 16``). Seen along +Z nothing under a point can be reached, so
the material that stays at tip height z is every cloud point above ``z - a`` (``a`` the
allowance) and everything under it (Popescu's "point recovery" projects those points onto the
slice). The tip may stand at (x, y) only if every such point q keeps a clearance >= ``a``, i.e.
its XY distance is at least ``r(q) = Rf + sqrt(A^2 - t^2)``, ``A = rc + a``, ``t = clip(z + rc -
q_z, 0, A)``: ``Rt + a`` for points above the corner (Tchanchane & Bey's offset by R +
allowance), less for points in the band ``z - a < q_z < z + rc`` under the corner or the flat
bottom. The band is split into at most MAX_BANDS sub-bands of radius, each point taking its
sub-band's largest. A cell is *allowed* when every point within ``h`` of its centre is safe: the
distance between its centre and the centre of every cell holding such points must be at least
``r + h + h / sqrt(2)`` (a point lies within ``h / sqrt(2)`` of its cell's centre). This is
decided exactly (the same map as an exact Euclidean distance transform of those cells), once for
all levels: the sub-band thresholds are the level's z plus constants, so per sub-band each cell
keeps the highest point of the cells whose centre is closer than the band's reach
(:func:`_disc_max`), and a level's map is one comparison per cell (with several sub-bands, one
map of the largest "highest point minus the band's offset", made larger by 1e-12 relative to
cover rounding: conservative). The map can forbid more than needed (by about ``2.5 h`` at most,
plus the sub-band width ``A / K`` for K sub-bands), never less. Points at most Z_TOL_MM (1e-6 mm)
above ``z - a`` are not obstacles (a floor level exactly at the allowance). The raster covers the
stock box grown by ``g = Rt - h`` and a border of 3 cells; the cells whose centre lies within g
of the stock box are ``inbox`` (the clearing region's limit,
:mod:`planning.toolpath.roughing.regions`).

**Remaining material.** A height map on a coarser raster (cells of TOP_CELLS x TOP_CELLS raster
cells, each clipped to the stock box): the stock top, lowered after each level where the flat
bottom surely swept a whole cell, i.e. the distance from the centre of its part in the stock to a
move plus that part's half diagonal is at most Rf (consecutive short moves merged into chords
that stay within h / 4 of them, the radius shrunk by as much), to z + rc where only the corner
did (Rt); it is never below a cloud point, so rapids run in free air. The highest remaining
material under the disc about a point is read from the map's maximum over the square of
``ceil((Rt + H / 4) / H)`` cells about the point's cell (H the coarse cell; links are sampled
every H / 4).

**Rest roughing.** With the stock given as points on its boundary (:func:`_stock_tops`), the
raster grows by ``extra_mm`` (whole coarse cells) so that it holds the material under every tool
disc; the stock top per raster cell is the highest point per cell made hole-free by a disc maximum
(radius the sampling spacing + one cell), at least the cloud's highest point; the material map
starts from its maxima over the coarse cells (:func:`_coarse_max`) instead of the box top. Reading
the map under a disc exactly (:meth:`_MaterialMap.disc_top`, :func:`_disc_top`,
:func:`_fine_disc_top`: cells whose square comes closer than the radius) serves the entries;
:func:`_air_length` measures the feed at a level that meets no stock.

**Holder** (:class:`_HolderMap`, pieces given): which tool-centre cells a holder piece (z0, r)
would put into the cloud (once, from the cells' highest points) or into the remaining material
(per level, from this map), each a disc maximum over the piece's radius grown by the raster's
slack, on blocks of cells that grow with the radius (:func:`_block_max`, HOLDER_BLOCKS);
:func:`_holder_pieces` checks and reduces the pieces.

Cost per set-up: one pass over the cloud for the cells' highest points and one disc maximum per
sub-band (rest roughing: one pass over the stock points and two disc maxima more; holder: one disc
maximum per piece); per level: the coarse material map's square maximum and its lowering along the
moves (holder: the candidates' box, the mask, and where the map changed a disc maximum per piece).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange

from planning.errors import ParameterError
from planning.toolpath.roughing.common import _seg_d2

Z_TOL_MM = 1e-6         #: points at most this far above (level - allowance) are not obstacles, mm
MAX_BANDS = 8           #: most sub-bands of radius under the tool corner / bottom
MAX_CELLS = 16_000_000  #: the raster's cell grows beyond cell_mm to stay under this many cells
TOP_CELLS = 2           #: a cell of the remaining-material map spans this many raster cells each way
HOLDER_GAP_MM = 0.5     #: the holder's bottom stays this far above the remaining material, mm
HOLDER_PIECES = 4       #: most holder pieces kept (more are merged into larger ones, conservative)
HOLDER_BLOCKS = 16      #: a holder piece's disc spans about this many blocks (cells grouped as its radius grows)
_SQ2 = math.sqrt(2.0)


# ----------------------------------------------------------------------------------------------
# The planning raster and the forbidden map
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Raster:
    """The planning raster: cells of side ``h`` (mm) from (``x0``, ``y0``), ``nx`` x ``ny``;
    ``cmax`` (nx, ny): the highest cloud z per cell (-inf when empty); ``inbox`` (nx, ny): the
    cell's centre lies within ``Rt - h`` of the stock box."""

    x0: float
    y0: float
    h: float
    nx: int
    ny: int
    cmax: np.ndarray
    inbox: np.ndarray


def _raster(pts, box_lo, box_hi, Rt, h, extra_mm: float = 0.0) -> _Raster:
    """The raster over the stock box (XY corners ``box_lo``, ``box_hi``) grown by g = Rt - h (tool
    centres) and a border of 3 cells; the cell grows beyond ``h`` to stay under MAX_CELLS cells.
    ``extra_mm`` > 0 (rest roughing: the material beside the box under the tool disc) grows it by
    that much more on every side, in whole multiples of TOP_CELLS cells, so that the cells (and
    the material map's coarse cells) of the box and its border keep their place."""
    g = Rt - h
    ext = float(max(box_hi[0] - box_lo[0], box_hi[1] - box_lo[1])) + 2 * (g + 3 * h)
    h = max(h, ext / math.sqrt(MAX_CELLS))
    if h > Rt / 2:
        raise ParameterError(f"the stock ({ext:.0f} mm across) is too large for a {2 * Rt} mm cutter: the map would "
                             f"need more than {MAX_CELLS} cells; use a larger tool or rough a smaller area")
    g = Rt - h
    k = TOP_CELLS * int(math.ceil(extra_mm / (TOP_CELLS * h))) if extra_mm > 0 else 0
    x0 = float(box_lo[0]) - g - 3 * h - k * h
    y0 = float(box_lo[1]) - g - 3 * h - k * h
    nx = int(math.ceil((box_hi[0] + g + 3 * h - (x0 + k * h)) / h)) + 2 * k
    ny = int(math.ceil((box_hi[1] + g + 3 * h - (y0 + k * h)) / h)) + 2 * k
    cmax = _cell_max(pts, x0, y0, h, nx, ny)
    cx = x0 + (np.arange(nx) + 0.5) * h
    cy = y0 + (np.arange(ny) + 0.5) * h
    ox = np.maximum(np.maximum(box_lo[0] - cx, cx - box_hi[0]), 0.0)     # distance to the box along x
    oy = np.maximum(np.maximum(box_lo[1] - cy, cy - box_hi[1]), 0.0)
    inbox = np.hypot(ox[:, None], oy[None, :]) <= g                         # centre within g of the box
    return _Raster(x0, y0, h, nx, ny, cmax, inbox)


@njit(cache=True, nogil=True)
def _cell_max(pts, x0, y0, h, nx, ny):
    """Highest z of the points (N,3) in each square cell of side h (-inf when empty), (nx, ny)."""
    cmax = np.full((nx, ny), -np.inf)
    for i in range(pts.shape[0]):
        ix = min(max(int(math.floor((pts[i, 0] - x0) / h)), 0), nx - 1)
        iy = min(max(int(math.floor((pts[i, 1] - y0) / h)), 0), ny - 1)
        cmax[ix, iy] = max(cmax[ix, iy], pts[i, 2])
    return cmax



def _bands(z, Rt, rc, a, K):
    """(height threshold, radius) pairs: cells whose highest point is above the threshold keep the
    tool centre at least the radius away (module docstring)."""
    Rf, A = Rt - rc, rc + a
    out = []
    for j in range(1, K + 1):
        e_prev = Rf + A * (j - 1) / K
        e_j = Rf + A * j / K
        t = math.sqrt(max(A * A - (e_prev - Rf) ** 2, 0.0))
        thr = z + rc - t
        if j == 1:
            thr = z - a + Z_TOL_MM
        out.append((thr, e_j))
    return out



class _ForbiddenMap:
    """Where the tool tip may not stand, all levels at once (module docstring): at level z the
    cells with ``G > threshold(z)`` are forbidden. ``K``: the number of sub-bands of radius."""

    def __init__(self, cmax, h, Rt, rc, a, big):
        nx, ny = cmax.shape
        self.Rt, self.rc, self.a = Rt, rc, a
        K = int(min(MAX_BANDS, max(1, math.ceil((rc + a) / (2 * h)))))
        self.K = K
        fmargin = h * (1.0 + 1.0 / _SQ2) + 1e-9 * max(1.0, float(big))
        # per band, the highest point among the cells within its reach of each cell: a level's map is
        # then one comparison per cell (the same map as a distance transform of the cells above the
        # band's threshold)
        bands0 = _bands(0.0, Rt, rc, a, K)
        if K == 1:          # forb = G > the band's threshold, exactly
            G = _disc_max(cmax, h, bands0[0][1] + fmargin)
        else:               # forb = G > z: the bands' thresholds are z + off_j (off_j from z = 0), so G is the
            # largest (highest point within the band's reach - off_j), made larger by far more than the
            # rounding of either form of the comparison (conservative)
            eps = 1e-12 * (big + Rt + a + 1.0)
            G = np.full((nx, ny), -np.inf)
            for off, e in bands0:
                np.maximum(G, _disc_max(cmax, h, e + fmargin) - off + eps, out=G)
        self.G = G

    def threshold(self, z) -> float:
        """The level's threshold: cells with ``G`` above it are forbidden at tip height z."""
        return _bands(float(z), self.Rt, self.rc, self.a, self.K)[0][0] if self.K == 1 else float(z)


@njit(cache=True, nogil=True)
def _row_window_max(v, i, k, buf, G, H, out_row):
    """``out_row[j] = max(v[i, j - k : j + k + 1])`` (the window clipped to the row), van Herk /
    Gil-Werman: blocks of 2k + 1 on the row padded by k with -inf, prefix and suffix maxima, in the
    caller's buffers (each at least ``ny + 2k`` long)."""
    m = v.shape[1]
    w = 2 * k + 1
    L = m + 2 * k
    for p in range(k):
        buf[p] = -np.inf
        buf[k + m + p] = -np.inf
    for j in range(m):
        buf[k + j] = v[i, j]
    for b0 in range(0, L, w):
        b1 = min(b0 + w, L)
        g = buf[b0]
        G[b0] = g
        for p in range(b0 + 1, b1):
            g = max(g, buf[p])
            G[p] = g
        g = buf[b1 - 1]
        H[b1 - 1] = g
        for p in range(b1 - 2, b0 - 1, -1):
            g = max(g, buf[p])
            H[p] = g
    for j in range(m):
        out_row[j] = max(H[j], G[j + 2 * k])


@njit(cache=True, nogil=True)
def _max_rows(a, k, out):
    """``out[i, j] = max(a[i, j - k : j + k + 1])`` (the window clipped to the row), every row by
    :func:`_row_window_max`."""
    n, m = a.shape
    L = m + 2 * k
    buf, G, H = np.empty(L), np.empty(L), np.empty(L)
    for i in range(n):
        _row_window_max(a, i, k, buf, G, H, out[i])


@njit(cache=True, nogil=True)
def _max_cols(a, k, out):
    """``out[i, j] = max(a[i - k : i + k + 1, j])`` (clipped), as :func:`_max_rows` along the first
    axis, whole rows at a time (contiguous)."""
    n, m = a.shape
    w = 2 * k + 1
    L = n + 2 * k
    G = np.empty((L, m))
    H = np.empty((L, m))
    for p in range(L):
        q = p - k
        inside = 0 <= q < n
        start = p % w == 0
        for j in range(m):
            v = a[q, j] if inside else -np.inf
            if start or v > G[p - 1, j]:
                G[p, j] = v
            else:
                G[p, j] = G[p - 1, j]
    for p in range(L - 1, -1, -1):
        q = p - k
        inside = 0 <= q < n
        end = p % w == w - 1 or p == L - 1
        for j in range(m):
            v = a[q, j] if inside else -np.inf
            if end or v > H[p + 1, j]:
                H[p, j] = v
            else:
                H[p, j] = H[p + 1, j]
    for i in range(n):
        for j in range(m):
            out[i, j] = max(H[i, j], G[i + 2 * k, j])


def _square_max(a, k):
    """The maximum over the (2k + 1)^2 square about each cell (-inf outside the raster), as
    ``scipy.ndimage.maximum_filter(a, 2k + 1, mode="constant", cval=-inf)``."""
    tmp = np.empty_like(a)
    out = np.empty_like(a)
    _max_rows(a, k, tmp)
    _max_cols(tmp, k, out)
    return out


@njit(cache=True, nogil=True)
def _disc_widths(h, reach):
    """Per row offset ``di`` (0..K) the half width of the disc's row (-1 past the disc) and K."""
    K = int(math.ceil(reach / h)) + 1
    wd = np.full(K + 1, -1, np.int64)
    for di in range(K + 1):
        for dj in range(K + 1):
            if math.sqrt(float(di * di + dj * dj)) * h < reach:
                wd[di] = dj
    return wd, K


@njit(cache=True, nogil=True)
def _stamp_max(out, src, raw, h, reach):
    """``out[c] = max(out[c], src[c'])`` for every cell c' where ``src`` is above ``raw`` and every c whose
    centre is closer than ``reach`` to c''s (the disc of :func:`_disc_max`): with ``out`` =
    ``_disc_max(raw, h, reach)`` it becomes ``_disc_max(max(raw, src), h, reach)`` at the cost of the few
    cells where ``src`` adds something."""
    nx, ny = out.shape
    wd, K = _disc_widths(h, reach)
    for i in range(nx):
        for j in range(ny):
            v = src[i, j]
            if not v > raw[i, j]:
                continue
            for di in range(-K, K + 1):
                w = wd[abs(di)]
                ii = i + di
                if w < 0 or ii < 0 or ii >= nx:
                    continue
                for jj in range(max(0, j - w), min(ny, j + w + 1)):
                    if v > out[ii, jj]:
                        out[ii, jj] = v


@njit(cache=True, nogil=True, inline="always")
def _max_into(out, o, row):
    """``out[o] = max(out[o], row)`` element-wise."""
    for j in range(row.shape[0]):
        if row[j] > out[o, j]:
            out[o, j] = row[j]


def _disc_max(v, h, reach):
    """``out[c] = max v[c']`` over the cells c' whose centre is closer than ``reach`` to c's
    (``sqrt(di^2 + dj^2) h < reach``; -inf when none): with ``v`` the cells' highest point, a cell
    is within ``reach`` of a cell holding a point above t exactly when ``out > t`` (the same test
    as an exact distance transform of the cells above t). The disc is cut in rows of offsets
    ``di``, each a 1-D window of half width ``w(di)`` (van Herk / Gil-Werman): per block of output
    rows, each input row within reach is filtered once per width it is needed at. One block of rows
    per thread (``NUMBA_NUM_THREADS``; the rows within reach of a block's edges are filtered by both
    blocks), one parallel region a call."""
    v = np.ascontiguousarray(v, dtype=np.float64)
    return _disc_max_blocks(v, float(h), float(reach), max(1, min(v.shape[0], numba.get_num_threads())))


@njit(cache=True, nogil=True, parallel=True)
def _disc_max_blocks(v, h, reach, nb):
    """:func:`_disc_max` in ``nb`` blocks of rows, one per ``prange`` iteration."""
    nx, ny = v.shape
    wd, K = _disc_widths(h, reach)
    out = np.full((nx, ny), -np.inf)
    if wd[0] < 0 or nx == 0 or ny == 0:
        return out
    for b in prange(nb):
        i0 = b * nx // nb
        i1 = (b + 1) * nx // nb
        L = ny + 2 * (K + 1)
        buf = np.empty(L)
        G = np.empty(L)
        H = np.empty(L)
        row = np.empty(ny)
        # every input row r within reach of the block, filtered at every width its offsets need
        for r in range(max(0, i0 - K), min(nx, i1 + K)):
            last_w = -2
            for di in range(K + 1):
                w = wd[di]
                if w < 0:
                    break
                # the output rows r - di and r + di inside the block take this row at width w(di)
                lo_ok = i0 <= r + di < i1
                hi_ok = di > 0 and i0 <= r - di < i1
                if not lo_ok and not hi_ok:
                    continue
                if w != last_w:
                    _row_window_max(v, r, w, buf, G, H, row)
                    last_w = w
                if lo_ok:
                    _max_into(out, r + di, row)
                if hi_ok:
                    _max_into(out, r - di, row)
    return out


def _disc_any(mask, h, reach):
    """``out[c]``: whether a cell c' with ``mask[c']`` has its centre closer than ``reach`` to c's
    (the disc of :func:`_disc_max`): ``_disc_max(where(mask, 1, -inf), h, reach) > 0``, exactly, in
    two passes over the raster instead of one per row of the disc. Since the disc's half width
    ``w(di)`` does not grow with ``|di|``, c is reached exactly when some column j' holds, at the
    smallest row distance ``g`` from c's row, a masked cell with ``|j - j'| <= w(g)``: the first pass
    finds ``g`` per cell (two sweeps along the rows), the second marks each row's intervals
    (a difference array). One block of rows per thread, as :func:`_disc_max`."""
    m = np.ascontiguousarray(mask, dtype=np.bool_)
    return _disc_any_kernel(m, float(h), float(reach), max(1, min(m.shape[1], numba.get_num_threads())))


@njit(cache=True, nogil=True, parallel=True)
def _disc_any_kernel(mask, h, reach, nb):
    """:func:`_disc_any`: the row distances in ``nb`` blocks of columns, the intervals in ``nb``
    blocks of rows."""
    nx, ny = mask.shape
    wd, K = _disc_widths(h, reach)
    out = np.zeros((nx, ny), dtype=np.bool_)
    if wd[0] < 0 or nx == 0 or ny == 0:
        return out
    far = K + 1                                  # a row distance no disc row reaches
    g = np.empty((nx, ny), dtype=np.int64)
    for b in prange(nb):
        j0 = b * ny // nb
        j1 = (b + 1) * ny // nb
        for j in range(j0, j1):
            g[0, j] = 0 if mask[0, j] else far
        for i in range(1, nx):
            for j in range(j0, j1):
                g[i, j] = 0 if mask[i, j] else min(g[i - 1, j] + 1, far)
        for i in range(nx - 2, -1, -1):
            for j in range(j0, j1):
                if g[i + 1, j] + 1 < g[i, j]:
                    g[i, j] = g[i + 1, j] + 1
    for b in prange(nb):
        i0 = b * nx // nb
        i1 = (b + 1) * nx // nb
        diff = np.empty(ny + 1, dtype=np.int64)
        for i in range(i0, i1):
            diff[:] = 0
            for j in range(ny):
                d = g[i, j]
                if d > K:
                    continue
                w = wd[d]
                if w < 0:
                    continue
                diff[max(0, j - w)] += 1
                diff[min(ny, j + w + 1)] -= 1
            run = 0
            for j in range(ny):
                run += diff[j]
                out[i, j] = run > 0
    return out


# ----------------------------------------------------------------------------------------------
# The remaining-material map
# ----------------------------------------------------------------------------------------------

class _MaterialMap:
    """The remaining material (module docstring): ``top`` (ncx, ncy), the stock's height on coarse
    cells of side ``H`` = TOP_CELLS raster cells from the raster's origin (-inf outside the stock);
    the part of cell (i, j) in the stock box has centre (``cx[i]``, ``cy[j]``), half diagonal
    ``hd[i, j]`` and area ``area[i, j]``; ``full_x[i]``, ``full_y[j]``: the column / row lies wholly
    in the stock. ``kdil``: the half width, in cells, of the square read about a point."""

    def __init__(self, grid: _Raster, box_lo, box_hi, z_top, Rt, top0=None):
        """``top0`` (ncx, ncy) or None: the initial heights per coarse cell (rest roughing:
        :func:`_stock_tops`, with ``box_lo``, ``box_hi`` the raster's own corners so that no cell
        is clipped); None: ``z_top`` over the stock box."""
        x0, y0, h, nx, ny = grid.x0, grid.y0, grid.h, grid.nx, grid.ny
        self.x0, self.y0 = x0, y0
        H = TOP_CELLS * h
        ncx = -(-nx // TOP_CELLS)
        ncy = -(-ny // TOP_CELLS)
        tlx = np.maximum(x0 + np.arange(ncx) * H, box_lo[0])
        thx = np.minimum(x0 + (np.arange(ncx) + 1) * H, box_hi[0])
        tly = np.maximum(y0 + np.arange(ncy) * H, box_lo[1])
        thy = np.minimum(y0 + (np.arange(ncy) + 1) * H, box_hi[1])
        tcx, tcy = 0.5 * (tlx + thx), 0.5 * (tly + thy)
        inx, iny = thx > tlx, thy > tly
        thx, thy = np.where(inx, 0.5 * (thx - tlx), 0.0), np.where(iny, 0.5 * (thy - tly), 0.0)
        tfx = (x0 + np.arange(ncx) * H >= box_lo[0]) & (x0 + (np.arange(ncx) + 1) * H <= box_hi[0])
        tfy = (y0 + np.arange(ncy) * H >= box_lo[1]) & (y0 + (np.arange(ncy) + 1) * H <= box_hi[1])   # not clipped
        thd = np.hypot(thx[:, None], thy[None, :])            # half diagonal of the part in the stock
        tarea = 4.0 * thx[:, None] * thy[None, :]
        inside = inx[:, None] & iny[None, :]
        if top0 is None:
            top = np.where(inside, z_top, -np.inf)
        else:
            top = np.where(inside, np.asarray(top0, dtype=np.float64), -np.inf)
        # a square >= the disc about any point within H / 8 of a cell
        kdil = int(math.ceil((Rt + 0.25 * H) / H))
        self.H, self.kdil, self.top = H, kdil, top
        self.cx, self.cy, self.hd, self.area, self.full_x, self.full_y = tcx, tcy, thd, tarea, tfx, tfy
        self.hx, self.hy = thx, thy                             # half sizes of the parts in the stock

    def disc_top(self, x, y, r) -> float:
        """Highest remaining material (``top``) over the coarse cells whose part in the stock comes
        closer than ``r`` (mm) to (x, y) (exact square-to-point distance; -inf when none): the
        material under a tool disc of radius r about (x, y), never below it."""
        return float(_disc_top(self.top, self.cx, self.cy, self.hx, self.hy, self.x0, self.y0, self.H,
                               float(x), float(y), float(r)))

    def volume_above(self, z, mask=None) -> float:
        """The volume of the map above height z (mm^3), over the coarse cells where ``mask``
        (ncx, ncy) is True (all when None)."""
        v = np.maximum(self.top - z, 0.0) * self.area
        v[~np.isfinite(self.top)] = 0.0
        return float(v.sum() if mask is None else v[mask].sum())

    def dilated(self):
        """The maximum of ``top`` over the square of ``kdil`` cells each way about each cell."""
        return _square_max(self.top, self.kdil)

    def sweep(self, swept, z, Rf, Rt, rc, tol) -> float:
        """Lower ``top`` after a level cut along the polylines ``swept`` at tip height z
        (:func:`_sweep_top`); returns the volume removed, mm^3."""
        starts = np.zeros(len(swept) + 1, np.int64)
        np.cumsum([p.shape[0] for p in swept], out=starts[1:])
        return _sweep_top(self.top, self.cx, self.cy, self.hd, self.area, self.full_x, self.full_y,
                          np.concatenate(swept).astype(np.float64), starts, self.x0, self.y0, self.H, float(z),
                          Rf, Rt, rc, tol)


@njit(cache=True, nogil=True)
def _lower_cell(top, area, i, j, d2, hd, z, r1, r2, rc):
    """Lower cell (i, j) of ``top`` whose centre is sqrt(d2) from a move (see
    :func:`_sweep_segment`); returns the volume removed."""
    t = top[i, j]
    if not (t > z):                     # outside the stock (-inf) or already at this level
        return 0.0
    new = t
    q = r1 - hd
    if q >= 0.0 and d2 <= q * q:
        new = z
    elif rc > 0:
        q = r2 - hd
        if q >= 0.0 and d2 <= q * q:
            new = min(t, z + rc)
    if new < t:
        top[i, j] = new
        return (t - new) * area[i, j]
    return 0.0


@njit(cache=True, nogil=True)
def _sweep_segment(top, cx, cy, hd, area, full_x, full_y, ax, ay, bx, by, x0, y0, H, z, r1, r2, rc):
    """Lower ``top`` (see :func:`_sweep_top`) for one straight move a -> b: cells whose centre is
    within ``r1 - hd`` of it drop to z, else (rc > 0) within ``r2 - hd`` to z + rc. ``full_x[i]``,
    ``full_y[j]``: the column / row lies wholly in the stock (its cells are not clipped). A move
    along x (all clearing lines) takes, in each full column, the rows whose centre is within
    ``r - H / sqrt(2)`` of it in closed form (at most as far as a cell's own test allows, since no
    cell is larger), the clipped cells one by one. Returns the volume removed."""
    ncx, ncy = top.shape
    R = r2 if rc > 0 else r1
    removed = 0.0
    if R <= 0.0:
        return removed
    i0 = max(int(math.floor((min(ax, bx) - R - x0) / H)), 0)
    i1 = min(int(math.floor((max(ax, bx) + R - x0) / H)), ncx - 1)
    dx = bx - ax
    along_x = ay == by
    hfull = 0.5 * H * 1.4142135623730951
    ex_last = -1.0
    k0, k1, m0, m1 = 1, 0, 1, 0
    for i in range(i0, i1 + 1):
        # the move's y range over |x - cx| <= R, grown by R: the only cells of the column within R
        if along_x:
            ya = ay
            yb = ay
        elif abs(dx) > 1e-12:
            t0 = (cx[i] - R - ax) / dx
            t1 = (cx[i] + R - ax) / dx
            if t0 > t1:
                t0, t1 = t1, t0
            t0 = max(t0, 0.0)
            t1 = min(t1, 1.0)
            if t0 > t1:
                continue
            ya = ay + (by - ay) * t0
            yb = ay + (by - ay) * t1
        else:
            ya = ay
            yb = by
        j0 = max(int(math.floor((min(ya, yb) - R - y0) / H)), 0)
        j1 = min(int(math.floor((max(ya, yb) + R - y0) / H)), ncy - 1)
        if along_x and full_x[i]:
            ex = max(min(ax, bx) - cx[i], cx[i] - max(ax, bx), 0.0)
            if ex != ex_last:
                # rows [k0, k1]: to z; [m0, m1] (contains it): to z + rc (rc > 0); empty when k0 > k1
                ex_last = ex
                k0, k1, m0, m1 = 1, 0, 1, 0
                q = r1 - hfull
                if q >= 0.0 and ex <= q:
                    half = math.sqrt(q * q - ex * ex) * (1.0 - 1e-12)
                    k0 = max(int(math.ceil((ay - half - y0) / H - 0.5)), 0)
                    k1 = min(int(math.floor((ay + half - y0) / H - 0.5)), ncy - 1)
                if rc > 0:
                    q = r2 - hfull
                    if q >= 0.0 and ex <= q:
                        half = math.sqrt(q * q - ex * ex) * (1.0 - 1e-12)
                        m0 = max(int(math.ceil((ay - half - y0) / H - 0.5)), 0)
                        m1 = min(int(math.floor((ay + half - y0) / H - 0.5)), ncy - 1)
            for j in range(j0, j1 + 1):
                t = top[i, j]
                if not (t > z):
                    continue
                if not full_y[j]:
                    removed += _lower_cell(top, area, i, j, _seg_d2(cx[i], cy[j], ax, ay, bx, by), hd[i, j], z,
                                           r1, r2, rc)
                elif k0 <= j <= k1:
                    removed += (t - z) * area[i, j]
                    top[i, j] = z
                elif m0 <= j <= m1 and t > z + rc:
                    removed += (t - z - rc) * area[i, j]
                    top[i, j] = z + rc
            continue
        for j in range(j0, j1 + 1):
            if top[i, j] > z:
                removed += _lower_cell(top, area, i, j, _seg_d2(cx[i], cy[j], ax, ay, bx, by), hd[i, j], z,
                                       r1, r2, rc)
    return removed


@njit(cache=True, nogil=True)
def _sweep_top(top, cx, cy, hd, area, full_x, full_y, xy, starts, x0, y0, H, z, Rf, Rt, rc, tol):
    """Lower the remaining-material map ``top`` (coarse cells of side H from (x0, y0); the part of
    cell (i, j) in the stock box has centre (cx[i], cy[j]), half diagonal hd[i, j] and area
    area[i, j]; -inf outside the stock) after a level cut along the polylines
    ``xy[starts[k]:starts[k + 1]]`` at tip height z: a cell wholly within Rf of a move (the distance
    from its centre plus its half diagonal) was swept by the flat bottom and drops to z; else
    (rc > 0) within Rt, swept by the corner, to z + rc. Consecutive moves are merged into one chord
    while their inner vertices stay within ``tol`` of it (at most 64 moves): every point of the
    chord is then within ``tol`` of the polyline (it crosses the chord's normal there between two
    vertices within tol of the chord's line), so the radii shrink by ``tol``. Returns the volume
    removed (drop x cell area in the stock)."""
    removed = 0.0
    tol2 = tol * tol
    for k in range(starts.shape[0] - 1):
        p0 = starts[k]
        p1 = starts[k + 1]
        if p1 - p0 == 1:
            removed += _sweep_segment(top, cx, cy, hd, area, full_x, full_y, xy[p0, 0], xy[p0, 1], xy[p0, 0], xy[p0, 1],
                                      x0, y0, H, z, Rf, Rt, rc)
            continue
        s = p0
        while s < p1 - 1:
            e = s + 1
            while e + 1 < p1 and e + 1 - s <= 64:
                ok = True
                for q in range(s + 1, e + 1):
                    if _seg_d2(xy[q, 0], xy[q, 1], xy[s, 0], xy[s, 1], xy[e + 1, 0], xy[e + 1, 1]) > tol2:
                        ok = False
                        break
                if not ok:
                    break
                e += 1
            sh = tol if e > s + 1 else 0.0
            removed += _sweep_segment(top, cx, cy, hd, area, full_x, full_y, xy[s, 0], xy[s, 1], xy[e, 0], xy[e, 1],
                                      x0, y0, H, z, Rf - sh, Rt - sh, rc)
            s = e
    return removed



@njit(cache=True, nogil=True)
def _disc_top(top, cx, cy, hx, hy, x0, y0, H, px, py, r):
    """Largest ``top[i, j]`` over the coarse cells (side H from (x0, y0); the part of cell (i, j) in
    the stock: centre (cx[i], cy[j]), half sizes hx[i], hy[j]) whose part is closer than r to
    (px, py); -inf when none."""
    ncx, ncy = top.shape
    best = -np.inf
    i0 = max(int(math.floor((px - r - x0) / H)) - 1, 0)
    i1 = min(int(math.floor((px + r - x0) / H)) + 1, ncx - 1)
    j0 = max(int(math.floor((py - r - y0) / H)) - 1, 0)
    j1 = min(int(math.floor((py + r - y0) / H)) + 1, ncy - 1)
    r2 = r * r
    for i in range(i0, i1 + 1):
        dx = max(abs(px - cx[i]) - hx[i], 0.0)
        for j in range(j0, j1 + 1):
            t = top[i, j]
            if not (t > best):
                continue
            dy = max(abs(py - cy[j]) - hy[j], 0.0)
            if dx * dx + dy * dy < r2:
                best = t
    return best


@njit(cache=True, nogil=True)
def _fine_disc_top(v, x0, y0, h, px, py, r):
    """Largest ``v[i, j]`` over the raster cells (side h from (x0, y0)) whose square is closer than
    r to (px, py); -inf when none."""
    nx, ny = v.shape
    best = -np.inf
    i0 = max(int(math.floor((px - r - x0) / h)) - 1, 0)
    i1 = min(int(math.floor((px + r - x0) / h)) + 1, nx - 1)
    j0 = max(int(math.floor((py - r - y0) / h)) - 1, 0)
    j1 = min(int(math.floor((py + r - y0) / h)) + 1, ny - 1)
    r2 = r * r
    for i in range(i0, i1 + 1):
        dx = max(abs(px - (x0 + (i + 0.5) * h)) - 0.5 * h, 0.0)
        for j in range(j0, j1 + 1):
            t = v[i, j]
            if not (t > best):
                continue
            dy = max(abs(py - (y0 + (j + 0.5) * h)) - 0.5 * h, 0.0)
            if dx * dx + dy * dy < r2:
                best = t
    return best


# ----------------------------------------------------------------------------------------------
# The stock of rest roughing
# ----------------------------------------------------------------------------------------------

def _stock_tops(stock_pts, grid: _Raster, spacing, floor_map=None):
    """The stock top per raster cell from points sampling the boundary of the material that is
    there now (rest roughing; mm, area frame): the highest point per cell (points off the raster
    are left out: nothing beyond it is under a tool disc), then the largest of these over the cells
    whose centre is closer than ``spacing + h`` (:func:`_disc_max`), so the sampling leaves no hole
    (the boundary's samples, projected on the frame's XY, lie within ``spacing / sqrt 2`` of every
    point of a top the rays along Z sample, within about ``spacing`` where rays oblique to the
    frame's Z do, and a cell's centre within ``h / sqrt 2`` of its points; a top too high costs air
    only, one too low would let the tool rapid into material). ``floor_map``
    (nx, ny) or None: raised to at least this (the cloud's highest point per cell: the part is
    material whatever the stock model says). Returns (nx, ny), -inf where no stock is near."""
    p = np.asarray(stock_pts, dtype=np.float64)
    h, nx, ny = grid.h, grid.nx, grid.ny
    on = ((p[:, 0] >= grid.x0) & (p[:, 0] < grid.x0 + nx * h) & (p[:, 1] >= grid.y0) & (p[:, 1] < grid.y0 + ny * h))
    fine = _cell_max(np.ascontiguousarray(p[on]), grid.x0, grid.y0, h, nx, ny)
    top = _disc_max(fine, h, spacing + h)
    if floor_map is not None:
        np.maximum(top, floor_map, out=top)
    return top


def _coarse_max(fine, k=TOP_CELLS):
    """The maximum over blocks of k x k cells (the last blocks clipped): the material map's coarse
    cells from raster cells, (ceil(nx / k), ceil(ny / k))."""
    return _coarse_max_kernel(np.ascontiguousarray(fine, dtype=np.float64), int(k))


@njit(cache=True, nogil=True)
def _coarse_max_kernel(fine, k):
    """:func:`_coarse_max` in one pass over ``fine`` (NaN-free: the planners' heights are finite or
    -inf)."""
    nx, ny = fine.shape
    ncx, ncy = -(-nx // k), -(-ny // k)
    out = np.full((ncx, ncy), -np.inf)
    for i in range(nx):
        ci = i // k
        for cj in range(ncy):
            m = out[ci, cj]
            for j in range(cj * k, min(cj * k + k, ny)):
                if fine[i, j] > m:
                    m = fine[i, j]
            out[ci, cj] = m
    return out


@njit(cache=True, nogil=True)
def _air_length(xyz, use, D, x0, y0, h, use_cut):
    """Length (mm) of the moves ``i`` with ``use[i] == use_cut`` at one height (both ends at the
    same z) along which ``D`` (the stock top's maximum over the disc of the tool radius about each
    raster cell) is not above that height: no stock under the tool disc (to within one cell);
    pieces of h / 2 at most, each judged at its middle (off the raster: air)."""
    nx, ny = D.shape
    total = 0.0
    for i in range(1, xyz.shape[0]):
        if use[i] != use_cut:
            continue
        z = xyz[i, 2]
        if xyz[i - 1, 2] != z:
            continue
        ax, ay = xyz[i - 1, 0], xyz[i - 1, 1]
        bx, by = xyz[i, 0], xyz[i, 1]
        L = math.hypot(bx - ax, by - ay)
        if L <= 0.0:
            continue
        m = max(1, int(math.ceil(L / (0.5 * h))))
        for k in range(m):
            t = (k + 0.5) / m
            ix = int(math.floor((ax + (bx - ax) * t - x0) / h))
            iy = int(math.floor((ay + (by - ay) * t - y0) / h))
            if ix < 0 or iy < 0 or ix >= nx or iy >= ny or not D[ix, iy] > z + Z_TOL_MM:
                total += L / m
    return total


# ----------------------------------------------------------------------------------------------
# The holder (non-cutting pieces above the tip)
# ----------------------------------------------------------------------------------------------

def _holder_pieces(pieces) -> np.ndarray:
    """The checked holder pieces, (k, 2) rows (z0, r) in mm: ``pieces`` is a sequence of
    ``(z0_mm, z1_mm, radius_mm)`` (:attr:`planning.simulate.motion.ToolShape.pieces`: a cylinder
    from z0 to z1 above the tip, z1 may be inf), z0 >= 0, z1 > z0, radius > 0 (the first wrong one
    raises :class:`~planning.errors.ParameterError`). The tops are dropped (every height map here
    is solid down to the floor, so a piece meets the material exactly when its bottom does), the
    pieces that another one contains as seen from below (no higher, no narrower) are left out, and
    while more than HOLDER_PIECES remain (a cone sliced into cylinders), the two neighbours (by z0)
    of the closest radii become one (the lower's z0, the larger radius: conservative). Rows by z0
    ascending, radii ascending; (0, 2) when there is none."""
    try:
        rows = [tuple(float(v) for v in p) for p in pieces]
    except (TypeError, ValueError):
        raise ParameterError("holder_pieces must be a sequence of (z0_mm, z1_mm, radius_mm) triples") from None
    for k, p in enumerate(rows):
        if len(p) != 3:
            raise ParameterError(f"holder_pieces[{k}] = {p}: must be (z0_mm, z1_mm, radius_mm)")
        z0, z1, r = p
        if not (math.isfinite(z0) and z0 >= 0):
            raise ParameterError(f"holder_pieces[{k}]: z0 = {z0} must be a finite height >= 0 mm above the tip")
        if not z1 > z0:               # inf allowed, NaN not
            raise ParameterError(f"holder_pieces[{k}]: z1 = {z1} must be above z0 = {z0} mm (may be inf)")
        if not (math.isfinite(r) and r > 0):
            raise ParameterError(f"holder_pieces[{k}]: radius = {r} must be a finite radius > 0 mm")
    front: list[list[float]] = []
    for z0, _, r in sorted(rows, key=lambda p: (p[0], -p[2])):
        if not front or r > front[-1][1]:
            front.append([z0, r])
    while len(front) > HOLDER_PIECES:
        k = min(range(len(front) - 1), key=lambda i: front[i + 1][1] - front[i][1])
        front[k][1] = front[k + 1][1]
        del front[k + 1]
    return np.array(front, dtype=np.float64).reshape(-1, 2)


@njit(cache=True, nogil=True)
def _block_max(v, b):
    """The maximum over blocks of b x b cells of ``v`` (the last blocks clipped; -inf for none), as
    :func:`_coarse_max` (any layout of ``v``)."""
    n, m = v.shape
    out = np.full((-(-n // b), -(-m // b)), -np.inf)
    for i in range(n):
        bi = i // b
        for j in range(m):
            out[bi, j // b] = max(out[bi, j // b], v[i, j])
    return out


def _expand(D, b, n, m):
    """Blocks of b x b cells back to cells: (n, m) with each block's value."""
    if b == 1:
        return D[:n, :m]
    return np.repeat(np.repeat(D, b, axis=0), b, axis=1)[:n, :m]


class _HolderMap:
    """Where the holder stops the tool centre (:mod:`planning.toolpath.roughing.levels`, holder
    pieces given): at tip height z a raster cell is *blocked* when a piece (z0, r) would meet

    (a) the cloud: a point within ``r + a`` of the tool centre (XY) above ``z + z0 - a`` (``a``
        the allowance; a point stands for everything under it, as in the forbidden map, so the
        piece's top does not matter). Once per set-up: ``GC`` (nx, ny), the largest over the
        pieces of (the highest point among the cells within reach) - z0, + a; blocked where
        ``GC > z``. The reach covers every centre within h of the cell's centre and every point of
        the source cells (``r + a + h + (2b - 1) h / sqrt 2`` between blocks of b x b cells, b
        growing with r so that a disc spans about HOLDER_BLOCKS blocks).
    (b) the remaining material: the material map (:class:`_MaterialMap`, the box or the given stock
        as lowered by the levels cut so far) above ``z + z0 - gap`` on a coarse cell
        closer than r. Per level (:meth:`level`), from the map at the start of the level: ``HT``
        (ncx, ncy, the map's coarse cells), the largest over the pieces of (the highest material
        within reach) - z0; blocked where ``HT > z - gap`` (``gap_mm``, default HOLDER_GAP_MM). The level's own cut only
        lowers the map (to z, or z + rc under the corner), so the map at its start is an upper
        bound of the material during the level: safe; it is also not too strict while z0 >
        step + HOLDER_GAP_MM + rc (what the level removes, between z and the level above, is
        below every piece; a holder whose lowest piece starts within a step of the tip would be
        in the layer being cut, and blocks everything beside uncut material). The reach covers
        every centre within h of a raster cell of the coarse cell and every point within H / 8 of
        it (the links' samples), ``r + h (1 + 1 / sqrt 2) + (2b - 1) H / sqrt 2`` between blocks.
        ``HT`` is computed only over the window of the level's candidate cells, the tool's last
        position and side entries (+inf outside), and only again when the map has changed, the
        window has grown, or a piece skipped (all its material below the level's threshold) might
        now matter.

    Blocked cells are neither cut, linked through, entered (helices and ramps lie in the region;
    side entries keep to :attr:`ok`), nor used for lifts: a position clear at z is clear above it
    (the material does not depend on the tip height). The rapids of lifts keep the holder clear
    by rising at least GAP above ``HT`` along the way
    (:meth:`planning.toolpath.roughing.links._Level.corridor_top`).
    """

    def __init__(self, pieces, grid: _Raster, mat: _MaterialMap, a, Rt, big, win=None, gap_mm: float = HOLDER_GAP_MM):
        h, nx, ny = grid.h, grid.nx, grid.ny
        self.gap = float(gap_mm)
        H = mat.H
        self.h, self.H, self.nx, self.ny = h, H, nx, ny
        self.x0, self.y0 = grid.x0, grid.y0
        self.z0 = pieces[:, 0].copy()
        tiny = 1e-9 * max(1.0, float(big))
        GC = np.full((nx, ny), -np.inf)
        for z0, r in pieces:
            b = max(1, int(math.ceil(r / (HOLDER_BLOCKS * h))))
            reach = (r + a + h + (2 * b - 1) * h / _SQ2) * (1.0 + 1e-12) + tiny
            D = _disc_max(_block_max(grid.cmax, b), b * h, reach)
            np.maximum(GC, _expand(D, b, nx, ny) - z0, out=GC)
        self.GC = np.ascontiguousarray(GC + a + 1e-12 * (abs(big) + a + 1.0))
        self.mb = [max(1, int(math.ceil(r / (HOLDER_BLOCKS * H)))) for r in pieces[:, 1]]
        self.mreach = [(r + h * (1.0 + 1.0 / _SQ2) + (2 * b - 1) * H / _SQ2) * (1.0 + 1e-12) + tiny
                       for r, b in zip(pieces[:, 1], self.mb)]
        self.HT = np.full(mat.top.shape, np.inf)
        self.win_c = None                 # the coarse window (i0, i1, j0, j1) where HT holds
        self.valid_zm = math.inf          # ... for thresholds at least this (skipped pieces)
        self.limit = np.zeros((nx, ny), dtype=bool)
        self.ok = np.zeros(nx * ny, dtype=bool)
        self.use_win = win is not None
        self.win = np.ascontiguousarray(win if win is not None else np.ones((1, 1), bool))
        self.pad = int(math.ceil((Rt + 4.0 * h) / h)) + 3         # side entries, in cells

    def level(self, limit, G, thr, z, mat: _MaterialMap, cur, changed) -> int:
        """The level's limit without the blocked cells: :attr:`limit` (nx, ny) = ``limit`` and not
        forbidden (``G > thr``) and not blocked at tip height z; :attr:`ok` (nx * ny): the cells
        not blocked (and in the window) around them, where side entries may pass; ``cur``: the
        tool's position (x, y, z) or None; ``changed``: the material map was lowered since the last
        call. Returns the number of candidate cells (``limit`` and allowed) blocked."""
        nx, ny, T = self.nx, self.ny, TOP_CELLS
        self.limit.fill(False)
        self.ok.fill(False)
        i0, i1, j0, j1 = _cand_box(limit, G, float(thr))
        if i1 < 0:
            return 0
        if cur is not None:
            ic = min(max(int(math.floor((cur[0] - self.x0) / self.h)), 0), nx - 1)
            jc = min(max(int(math.floor((cur[1] - self.y0) / self.h)), 0), ny - 1)
            i0, i1, j0, j1 = min(i0, ic), max(i1, ic), min(j0, jc), max(j1, jc)
        p = self.pad
        ci0, ci1 = max(i0 - p, 0) // T, -(-min(i1 + 1 + p, nx) // T)
        cj0, cj1 = max(j0 - p, 0) // T, -(-min(j1 + 1 + p, ny) // T)
        zm = float(z) - self.gap
        w = self.win_c
        if changed or w is None or zm < self.valid_zm or not (w[0] <= ci0 and ci1 <= w[1] and w[2] <= cj0
                                                               and cj1 <= w[3]):
            self._material(mat, (ci0, ci1, cj0, cj1), zm)
        return int(_holder_mask(limit, G, float(thr), self.GC, float(z), self.HT, zm, ci0 * T, min(ci1 * T, nx),
                                cj0 * T, min(cj1 * T, ny), self.limit, self.ok, self.win, self.use_win))

    def _material(self, mat: _MaterialMap, cw, zm):
        """``HT`` over the coarse window ``cw`` from the map as it is now (class docstring); pieces
        whose material in reach is nowhere above ``zm`` + z0 are skipped while the threshold stays
        at least that high."""
        ci0, ci1, cj0, cj1 = cw
        top, H = mat.top, self.H
        ncx, ncy = top.shape
        acc = np.full((ci1 - ci0, cj1 - cj0), -np.inf)
        valid = -math.inf
        for z0, b, reach in zip(self.z0, self.mb, self.mreach):
            g = int(math.ceil(reach / H)) + b
            s0, s1 = max(ci0 - g, 0), min(ci1 + g, ncx)
            t0, t1 = max(cj0 - g, 0), min(cj1 + g, ncy)
            src = top[s0:s1, t0:t1]
            m = float(src.max())
            if not m - z0 > zm:
                valid = max(valid, m - z0)
                continue
            D = _disc_max(_block_max(src, b), b * H, reach)
            E = _expand(D, b, s1 - s0, t1 - t0)[ci0 - s0:ci1 - s0, cj0 - t0:cj1 - t0]
            np.maximum(acc, E - z0, out=acc)
        self.HT.fill(np.inf)
        self.HT[ci0:ci1, cj0:cj1] = acc
        self.win_c = cw
        self.valid_zm = valid


@njit(cache=True, nogil=True)
def _cand_box(limit, G, thr):
    """The bounding box (i0, i1, j0, j1), inclusive, of the cells where ``limit`` holds and ``G``
    is not above ``thr``; i1 = -1 when there is none."""
    nx, ny = limit.shape
    i0, i1, j0, j1 = nx, -1, ny, -1
    for i in range(nx):
        for j in range(ny):
            if limit[i, j] and not G[i, j] > thr:
                i0 = min(i0, i)
                i1 = i
                j0 = min(j0, j)
                j1 = max(j1, j)
    return i0, i1, j0, j1


@njit(cache=True, nogil=True)
def _holder_mask(limit, G, thr, GC, z, HT, zm, i0, i1, j0, j1, out, ok, win, use_win):
    """Over the cells [i0, i1) x [j0, j1): ``out`` = ``limit`` and not ``G > thr`` and not blocked
    (``GC > z`` or ``HT`` of the coarse cell ``> zm``); ``ok`` (flat) = not blocked (and, with
    ``use_win``, in ``win``). Returns the number of cells ``limit`` and allowed but blocked."""
    ny = out.shape[1]
    n = 0
    for i in range(i0, i1):
        ci = i // TOP_CELLS
        for j in range(j0, j1):
            hold = GC[i, j] > z or HT[ci, j // TOP_CELLS] > zm
            cand = limit[i, j] and not G[i, j] > thr
            out[i, j] = cand and not hold
            if cand and hold:
                n += 1
            ok[i * ny + j] = not hold and (not use_win or win[i, j])
    return n
