"""Z-level roughing of one set-up with a flat or bull-nose end mill, straight from the cloud
(Popescu et al. 2014: slices, a binary occupancy map per slice, linking by shortest paths on a
graph; Tchanchane & Bey: the part's contours offset by R + stock allowance, parallel lines One-Way
or Zig-Zag clipped by them, then a pass along the offset contour). Everything is in the area frame
(:mod:`planning.toolpath.frames`: tool axis +Z; in a set-up frame every cloud point has z <= 0),
in mm; the path records the tool TIP (``Toolpath.tip_offset_mm = 0``).

**Tool.** A flat end mill of radius ``Rt`` or a bull-nose with corner radius ``rc`` (flat-bottom
radius ``Rf = Rt - rc``): the points within ``rc`` of the core, the half-infinite cylinder
``rho <= Rf, z >= tip + rc`` (``rc = 0``: the flat cylinder ``rho <= Rt, z >= tip``). Flutes,
shank and holder are this cylinder continued upwards without end (conservative for a shank no
wider than the cutter; the holder is not modelled). A cloud point's *clearance* is its distance
to that solid (0 or below: inside the tool).

**Stock.** The cloud's bounding box grown by ``stock_margin_mm`` on the four sides and on the top:
the stock top is the highest cloud z + ``stock_margin_mm`` (so ``stock_margin_mm`` in a set-up
frame). Each set-up starts from this full box: material removed by earlier set-ups is NOT
modelled, so some lines may cut air.

**Levels.** Tip heights from the stock top down every ``step_down_mm``, the last exactly at the
floor (``floor_z_mm``, default the lowest cloud z + allowance; the caller passes the area's
lowest point + allowance); a level within 1e-6 mm above the floor is dropped.

**Binary map per level (Popescu's map, made conservative).** A square XY raster (cell ``h`` =
``cell_mm``, default ``Rt / 16``). Seen along +Z nothing under a point can be reached, so the
material that stays at tip height z is every cloud point above ``z - a`` (``a`` the allowance)
and everything under it (Popescu's "point recovery" projects those points onto the slice). The
tip may stand at (x, y) only if every such point q keeps a clearance >= ``a``, i.e. its XY
distance is at least ``r(q) = Rf + sqrt(A^2 - t^2)``, ``A = rc + a``, ``t = clip(z + rc - q_z, 0,
A)``: ``Rt + a`` for points above the corner (Tchanchane & Bey's offset by R + allowance), less
for points in the band ``z - a < q_z < z + rc`` under the corner or the flat bottom. The band is
split into at most MAX_BANDS sub-bands of radius, each point taking its sub-band's largest. A
cell is *allowed* when every point within ``h`` of its centre is safe: the distance between its
centre and the centre of every cell holding such points must be at least ``r + h + h / sqrt(2)``
(a point lies within ``h / sqrt(2)`` of its cell's centre). This is decided exactly (the same map
as an exact Euclidean distance transform of those cells), once for all levels: the sub-band
thresholds are the level's z plus constants, so per sub-band each cell keeps the highest point
of the cells whose centre is closer than the band's reach (:func:`_disc_max`), and a level's map
is one comparison per cell (with several sub-bands, one map of the largest "highest point minus
the band's offset", made larger by 1e-12 relative to cover rounding: conservative). The map can
forbid more than needed (by about ``2.5 h`` at most, plus the sub-band width ``A / K`` for K
sub-bands), never less. Points at most Z_TOL_MM (1e-6 mm) above ``z - a`` are not obstacles (a
floor level exactly at the allowance).
The clearing region of a level: the allowed cells whose centre lies within ``g = Rt - h`` of the
stock box (the disc still reaches h into the stock; skins beside the part are reachable).

**Clearing.** Lines along X of the frame at fixed y (the same at every level), ``stepover_mm``
apart: default 60 % of the diameter, at most the diameter, so the discs of neighbouring lines
overlap and no island of stock is left between them (a bull-nose leaves a cusp of
``rc - sqrt(rc^2 - (s/2 - Rf)^2)`` where ``s > 2 Rf``); the outer lines ``max(Rf, Rt / 2) - h``
inside the stock's sides (the flat bottom reaches h past them). Each line is clipped to the
region (runs of region cells, to the cells' edges). Then (``contour``) the offset contour: the
region's boundary where it borders cells the part forbids (marching squares on the map through
the midpoints between an allowed and a forbidden cell centre, allowed cells 8-connected), run
with the material that stays on the right of the travel (climb milling with a clockwise, M3,
spindle); where the region ends at its limit around the stock the contour is not cut (air).
Every path point lies within ``h`` of an allowed cell centre (lines ``h / sqrt(2)``, contour
``0.8 h``, links below ``0.96 h``), hence is safe.

**Linking (Popescu: shortest paths on a graph).** Per level the connected components of the
region (8-connected; union-find over the region's runs of cells along y, numbered as
:func:`scipy.ndimage.label` numbers them) are cut one after another (the nearest next), each its
lines first, then
its contours. The lines of a component are grouped in boustrophedon zones (a run and the run of
the next line are in one zone when each is the other's only overlap in x), each cut as one
zig-zag (one-way: every run from its -X end); zones are taken greedily on the distance to their
entry plus the distance from their exit to the next remaining entry (one step of look-ahead);
contours greedily from the nearest vertex (any vertex of a closed one). Two consecutive pieces of
a component are joined at the level by a feed move when the straight link stays in the region
(sampled every h / 4), else along a shortest path on the 8-connected graph of the region's
cells (A* with steps counted as 5 and 7 units, 7 / 5 <= sqrt 2, so no path truly within the limit
is missed and the path found is within 1 % of the shortest; the octile bound; a bucket queue;
within the box that can hold a short enough path), shortened by line of sight, provided that
link is no longer than twice the diameter or than lifting (up and
down counted as feed, the rapid across as 1 / RAPID_RATIO of its length). Otherwise (another
component, a one-way return, a new level, a long link) the tool lifts: retract GAP_MM (1 mm) at
feed (``USE_RETRACT``), rapid up to the link height (straight up from a safe position is safe),
rapid across, rapid down to GAP_MM above the remaining material under the tool disc, and plunge
(feed, ``USE_PLUNGE``) to the level. The link height is GAP_MM above the highest remaining
material under the disc along the way, at most ``safe_z_mm`` (default stock top + 5 mm; the
first approach comes down from it, the last move returns to it). The remaining material is a
height map on a coarser raster (cells of TOP_CELLS x TOP_CELLS raster cells, each clipped to the
stock box): the stock top, lowered after each level where the flat bottom surely swept a whole
cell, i.e. the distance from the centre of its part in the stock to a move plus that part's half
diagonal is at most Rf (consecutive short moves merged into chords that stay within h / 4 of
them, the radius shrunk by as much), to z + rc where only the corner did (Rt); it is never below
a cloud point, so rapids run in free air. The highest remaining material under the disc about a
point is read from the map's maximum over the square of ``ceil((Rt + H / 4) / H)`` cells about
the point's cell (H the coarse cell; links are sampled every H / 4). Feed links at a level may
cut uncut stock (full width, at most one step down). Fixtures and the holder are not obstacles
here.

**Verification.** :func:`min_tool_clearance` measures, independently of the raster, the smallest
clearance between every cloud point and the tool swept along every move (exact for the
horizontal and vertical moves made here, a lower bound for others); the result reports it as
``min_clearance_mm`` (>= the allowance - 1e-6 mm by construction). Points more than Rt below the
lowest tip are left out (farther than Rt from the tool).

**Cost.** Per set-up: one pass over the cloud for the cells' highest points and one disc maximum
per sub-band; per level: one pass over the raster (the region and its runs), the boundary from
the runs (only the 2 x 2 blocks that can be mixed), the links' grid searches (in a window, scratch
arrays reused), the coarse material map; then one counting sort of the cloud for the
verification. The default raster of the femur-like case is about 1300 x 650 cells.

Simplified: no trochoidal or adaptive clearing, no ramped entries (plunges are straight down), no
holder or fixture collisions, no material model of earlier set-ups, no rest machining of the
corners a cutter of radius Rt cannot enter.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numba import get_num_threads, njit, prange

from planning.errors import ParameterError
from planning.toolpath.moves import (
    FEED,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
    lines,
    path_length_mm,
)

GAP_MM = 1.0            #: rapids stop this far above the remaining material, mm
Z_TOL_MM = 1e-6         #: points at most this far above (level - allowance) are not obstacles, mm
MAX_BANDS = 8           #: most sub-bands of radius under the tool corner / bottom
MAX_CELLS = 16_000_000  #: the raster's cell grows beyond cell_mm to stay under this many cells
MAX_LEVELS = 10_000     #: most Z levels
CLEARANCE_BLOCK = 8     #: min_tool_clearance skips blocks of this many cells each way by their highest point
TOP_CELLS = 2           #: a cell of the remaining-material map spans this many raster cells each way
ORDER_DENSE_MAX = 2048  #: up to this many zone variants in a component, all exit-entry distances are kept
RAPID_RATIO = 5.0       #: a rapid counts as 1 / RAPID_RATIO of its length of feed when links are compared
_SQ2 = math.sqrt(2.0)

REMOVED_NOTE = ("Each set-up is roughed from the full stock box (the cloud's box in the set-up frame grown by the "
                "stock margin): material removed by earlier set-ups is not modelled, so lines may cut air.")


@dataclass(frozen=True)
class RoughingPath:
    """Z-level roughing of one set-up (mm, area frame; see the module docstring).

    ``toolpath``: the moves (tool tip, ``tip_offset_mm`` 0); ``levels_mm`` (n_levels,) tip heights
    from the top down (the last is the floor); ``n_levels``; ``length_mm``: length of the feed
    moves (cuts, links at a level, plunges, retracts); ``air_mm``: length of the rapids;
    ``n_retracts``: lifts off a level (within levels, between levels and the final one);
    ``level_retracts`` (n_levels,): lifts between two pieces of the same level;
    ``min_clearance_mm``: smallest distance between the tool solid along every move and any cloud
    point (:func:`min_tool_clearance`; ``inf`` when no point comes within the tool radius);
    ``removed_mm3`` (n_levels,): the drop of the raster's remaining-material map at each level,
    mm^3 (cells wholly swept; the sum over the levels is a lower bound of the material
    removed); ``stock_box_mm`` (2,3): the stock box's lower and upper corners (the lower z is the
    lowest cloud point); ``cell_mm``: the raster cell used; ``stepover_mm``: the line spacing used;
    ``removed_note``: what the stock model leaves out."""

    toolpath: Toolpath
    levels_mm: np.ndarray
    n_levels: int
    length_mm: float
    air_mm: float
    n_retracts: int
    min_clearance_mm: float
    removed_note: str
    level_retracts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    removed_mm3: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stock_box_mm: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))
    cell_mm: float = 0.0
    stepover_mm: float = 0.0


@dataclass(frozen=True)
class ToolClearance:
    """``min_mm``: the smallest clearance (``inf`` when no point is within ``reach_mm``);
    ``move``: the move where it occurs; ``point``: the cloud point (-1 when none)."""

    min_mm: float
    move: int
    point: int


# ----------------------------------------------------------------------------------------------
# Exact clearance of a flat / bull-nose tool along moves (independent of the planning raster)
# ----------------------------------------------------------------------------------------------

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


@njit(cache=True, nogil=True)
def _cell_max(pts, x0, y0, h, nx, ny):
    """Highest z of the points (N,3) in each square cell of side h (-inf when empty), (nx, ny)."""
    cmax = np.full((nx, ny), -np.inf)
    for i in range(pts.shape[0]):
        ix = min(max(int(math.floor((pts[i, 0] - x0) / h)), 0), nx - 1)
        iy = min(max(int(math.floor((pts[i, 1] - y0) / h)), 0), ny - 1)
        cmax[ix, iy] = max(cmax[ix, iy], pts[i, 2])
    return cmax


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


# ----------------------------------------------------------------------------------------------
# Marching squares on the clearing region: oriented boundary loops
# ----------------------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def _march(region, rows, j0, j1):
    """Boundary loops of the True cells of ``region`` (nx, ny), the cells outside the raster
    counting as False, the True cells on the left of the travel, 8-connected (marching squares).
    In the raster padded by one cell (NX = nx + 2, NY = ny + 2), edges of the dual grid:
    horizontal H(i, j) between cells (i, j), (i+1, j): id ``i * NY + j``; vertical V(i, j) between
    (i, j), (i, j+1): id ``NH + i * (NY - 1) + j``, NH = (NX - 1) NY. Loops start at their smallest
    edge id, in increasing order of it. Only the 2 x 2 blocks that can be mixed are visited, found
    from the region's runs (``rows``, ``j0``, ``j1`` from :func:`_region_runs`): the blocks at a
    run's ends and those over the columns where the two rows differ. Returns (edge ids in loop
    order, loop start offsets)."""
    nx, ny = region.shape
    NX = nx + 2
    NY = ny + 2
    NH = (NX - 1) * NY
    cap = 4096
    src = np.empty(cap, np.int64)
    dst = np.empty(cap, np.int64)
    n = 0
    b = np.zeros(4, np.int64)
    e = np.empty(4, np.int64)
    mark = np.full(NY, -1, np.int64)
    cand = np.empty(NY, np.int64)
    bnd = np.empty(2 * NY + 2, np.int64)
    for i in range(NX - 1):
        # padded rows i and i + 1 are region rows i - 1 (A) and i (B)
        a0 = rows[i - 1] if i >= 1 else 0
        a1 = rows[i] if i >= 1 else 0
        b0 = rows[i] if i < nx else 0
        b1 = rows[i + 1] if i < nx else 0
        if a0 == a1 and b0 == b1:
            continue
        nc = 0
        nbd = 0                                   # run ends of A and of B, merged in order
        pa = 2 * a0
        pb = 2 * b0
        while pa < 2 * a1 or pb < 2 * b1:
            va = (j0[pa // 2] if pa % 2 == 0 else j1[pa // 2]) if pa < 2 * a1 else NY
            vb = (j0[pb // 2] if pb % 2 == 0 else j1[pb // 2]) if pb < 2 * b1 else NY
            if va <= vb:
                bnd[nbd] = va
                pa += 1
            else:
                bnd[nbd] = vb
                pb += 1
            nbd += 1
        for q in range(nbd):                      # the blocks at the ends of the runs
            jj = bnd[q]
            if mark[jj] != i:
                mark[jj] = i
                cand[nc] = jj
                nc += 1
        # columns where A and B differ: between consecutive boundaries both rows are constant
        bs = bnd
        ra = a0
        rb = b0
        for q in range(nbd - 1):
            p0 = bs[q]
            p1 = bs[q + 1]
            if p1 == p0:
                continue
            while ra < a1 and j1[ra] <= p0:
                ra += 1
            while rb < b1 and j1[rb] <= p0:
                rb += 1
            ina = ra < a1 and j0[ra] <= p0
            inb = rb < b1 and j0[rb] <= p0
            if ina != inb:                        # region columns p0 .. p1 - 1: blocks p0 .. p1
                for jj in range(p0, p1 + 1):
                    if mark[jj] != i:
                        mark[jj] = i
                        cand[nc] = jj
                        nc += 1
        for q in range(nc):
            j = cand[q]
            b[0] = 1 if (i >= 1 and j >= 1 and region[i - 1, j - 1]) else 0
            b[1] = 1 if (i < nx and j >= 1 and region[i, j - 1]) else 0
            b[2] = 1 if (i < nx and j < ny and region[i, j]) else 0
            b[3] = 1 if (i >= 1 and j < ny and region[i - 1, j]) else 0
            sm = b[0] + b[1] + b[2] + b[3]
            if sm == 0 or sm == 4:
                continue
            e[0] = i * NY + j                       # c0 -> c1 (bottom)
            e[1] = NH + (i + 1) * (NY - 1) + j      # c1 -> c2 (right)
            e[2] = i * NY + j + 1                   # c2 -> c3 (top)
            e[3] = NH + i * (NY - 1) + j            # c3 -> c0 (left)
            for k in range(4):
                if b[k] == 1 and b[(k + 1) % 4] == 0:
                    for d in range(1, 4):
                        m = (k + d) % 4
                        if b[m] == 0 and b[(m + 1) % 4] == 1:
                            if n == cap:
                                cap *= 2
                                s2 = np.empty(cap, np.int64)
                                d2 = np.empty(cap, np.int64)
                                for q in range(n):
                                    s2[q] = src[q]
                                    d2[q] = dst[q]
                                src, dst = s2, d2
                            src[n] = e[k]
                            dst[n] = e[m]
                            n += 1
                            break
    order = _argsort_stable(src[:n].astype(np.float64))
    ks = src[:n][order]
    kd = dst[:n][order]
    out = np.empty(n, np.int64)
    starts = np.empty(n + 1, np.int64)
    seen = np.zeros(n, np.bool_)
    m = 0
    nl = 0
    for p0 in range(n):
        if seen[p0]:
            continue
        starts[nl] = m
        nl += 1
        p = p0
        while not seen[p]:
            seen[p] = True
            out[m] = ks[p]
            m += 1
            lo = 0                              # the pair leaving from edge kd[p] (ids are unique)
            hi = n
            while lo < hi:
                mid = (lo + hi) // 2
                if ks[mid] < kd[p]:
                    lo = mid + 1
                else:
                    hi = mid
            p = lo
    starts[nl] = m
    return out[:m], starts[:nl + 1]


@njit(cache=True, nogil=True)
def _edge_cells(edges, region, G, thr):
    """For boundary edges from :func:`_march`: the region cell's flat index, whether the other cell is
    forbidden (``G > thr``; a cell outside the raster is not), and the crossing's doubled integer coordinates
    (x = x0 + gx h / 2, y = y0 + gy h / 2)."""
    nx, ny = region.shape
    NY = ny + 2
    NH = (nx + 1) * NY
    n = edges.shape[0]
    cell = np.empty(n, np.int64)
    keep = np.empty(n, np.bool_)
    gx = np.empty(n, np.int64)
    gy = np.empty(n, np.int64)
    for k in range(n):
        ed = edges[k]
        if ed < NH:
            i, j = ed // NY, ed % NY
            i2, j2 = i + 1, j
            gx[k], gy[k] = 2 * i, 2 * j - 1
        else:
            i, j = (ed - NH) // (NY - 1), (ed - NH) % (NY - 1)
            i2, j2 = i, j + 1
            gx[k], gy[k] = 2 * i - 1, 2 * j
        first_in = 1 <= i <= nx and 1 <= j <= ny and region[i - 1, j - 1]
        ri, rj, oi, oj = (i, j, i2, j2) if first_in else (i2, j2, i, j)
        cell[k] = (ri - 1) * ny + (rj - 1)
        keep[k] = 1 <= oi <= nx and 1 <= oj <= ny and G[oi - 1, oj - 1] > thr
    return cell, keep, gx, gy


# ----------------------------------------------------------------------------------------------
# Roughing
# ----------------------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def _cell_at(x, y, x0, y0, h, nx, ny, e):
    ix = min(max(int(math.floor((x - x0) / h + e)), 0), nx - 1)
    iy = min(max(int(math.floor((y - y0) / h + e)), 0), ny - 1)
    return ix, iy


@njit(cache=True, nogil=True)
def _n_samples(ax, ay, bx, by, h):
    return max(1, int(math.ceil(math.hypot(bx - ax, by - ay) / (0.25 * h))))


@njit(cache=True, nogil=True)
def _seg_in(flat, x0, y0, h, nx, ny, ax, ay, bx, by):
    """Every sample of a -> b (h / 4 apart, ends included) lies in a cell where ``flat`` is True
    (a sample within 1e-9 h of a cell edge may count for the cell on either side)."""
    n = _n_samples(ax, ay, bx, by, h)
    for k in range(n + 1):
        t = k / n
        x = ax + (bx - ax) * t
        y = ay + (by - ay) * t
        ok = False
        for eu in (-1e-9, 1e-9):
            ix, _ = _cell_at(x, y, x0, y0, h, nx, ny, eu)
            for ev in (-1e-9, 1e-9):
                _, iy = _cell_at(x, y, x0, y0, h, nx, ny, ev)
                if flat[ix * ny + iy]:
                    ok = True
        if not ok:
            return False
    return True


@njit(cache=True, nogil=True)
def _seg_max(vals, x0, y0, h, nx, ny, ax, ay, bx, by):
    """Largest ``vals`` over the cells of the samples of a -> b (h / 4 apart)."""
    n = _n_samples(ax, ay, bx, by, h)
    best = -np.inf
    for k in range(n + 1):
        t = k / n
        ix, iy = _cell_at(ax + (bx - ax) * t, ay + (by - ay) * t, x0, y0, h, nx, ny, 0.0)
        v = vals[ix * ny + iy]
        best = max(best, v)
    return best


@njit(cache=True, nogil=True)
def _line_of_sight(flat, x0, y0, h, nx, ny, pts):
    """Indices of the points kept when shortening the polyline ``pts`` by line of sight: from each
    kept point jump to the farthest later point seen straight (:func:`_seg_in`), found by
    bisection when the last is not seen (the first and last points are kept)."""
    last = pts.shape[0] - 1
    out = np.empty(last + 1, np.int64)
    out[0] = 0
    m = 1
    i = 0
    while i < last:
        if _seg_in(flat, x0, y0, h, nx, ny, pts[i, 0], pts[i, 1], pts[last, 0], pts[last, 1]):
            j = last
        else:
            lo = i + 1
            hi = last - 1
            while lo < hi:
                mid = (lo + hi + 1) // 2
                if _seg_in(flat, x0, y0, h, nx, ny, pts[i, 0], pts[i, 1], pts[mid, 0], pts[mid, 1]):
                    lo = mid
                else:
                    hi = mid - 1
            j = lo
        out[m] = j
        m += 1
        i = j
    return out[:m]


@njit(cache=True, nogil=True)
def _link_path(flat, x0, y0, h, nx, ny, ax, ay, bx, by, ca, cb, limit, dist, pred, stamp, call):
    """:meth:`_Level.grid_path` in one call: the search window (the box of a and b grown by half the
    slack ``limit - |ab|`` and 2 h), :func:`_grid_path_cells`, the cell centres between a and b,
    :func:`_line_of_sight`, and the length check. Returns the path (k, 2), or (0, 2) when there is
    none within the limit."""
    none = np.zeros((0, 2))
    if not (flat[ca] and flat[cb]):
        return none
    grow = 0.5 * max(limit - math.hypot(bx - ax, by - ay), 0.0) + 2 * h
    i0 = max(int(math.floor((min(ax, bx) - grow - x0) / h)), 0)
    i1 = min(int(math.floor((max(ax, bx) + grow - x0) / h)) + 1, nx)
    j0 = max(int(math.floor((min(ay, by) - grow - y0) / h)), 0)
    j1 = min(int(math.floor((max(ay, by) + grow - y0) / h)) + 1, ny)
    c = _grid_path_cells(flat, nx, ny, h, ca, cb, limit, i0, i1, j0, j1, dist, pred, stamp, call)
    if c.shape[0] == 0:
        return none
    pts = np.empty((c.shape[0] + 2, 2))
    pts[0, 0] = ax
    pts[0, 1] = ay
    for k in range(c.shape[0]):
        pts[k + 1, 0] = x0 + (c[k] // ny + 0.5) * h
        pts[k + 1, 1] = y0 + (c[k] % ny + 0.5) * h
    pts[-1, 0] = bx
    pts[-1, 1] = by
    keep = _line_of_sight(flat, x0, y0, h, nx, ny, pts)
    path = np.empty((keep.shape[0], 2))
    length = 0.0
    for k in range(keep.shape[0]):
        path[k, 0] = pts[keep[k], 0]
        path[k, 1] = pts[keep[k], 1]
        if k > 0:
            length += math.hypot(path[k, 0] - path[k - 1, 0], path[k, 1] - path[k - 1, 1])
    if not length <= limit:
        return none
    return path


STEP_UNITS = 5          #: grid searches count a side step as 5 units and a diagonal one as 7 (7 / 5 <= sqrt 2)
DIAG_UNITS = 7


@njit(cache=True, nogil=True)
def _grid_path_cells(flat, nx, ny, h, src, dst, limit, i0, i1, j0, j1, dist, pred, stamp, call):
    """A short path from cell ``src`` to cell ``dst`` (flat indices) over the 8-connected cells
    where ``flat`` is True inside the window [i0, i1) x [j0, j1): A* in integer units (a side step
    STEP_UNITS, a diagonal one DIAG_UNITS, so a length in units / STEP_UNITS * h never exceeds the
    true length) with the octile distance as the (consistent) bound of the rest and a bucket queue
    on the integer priority (f never decreases: one pass over the buckets; last in, first out
    within one). Cells whose length so far plus the bound exceeds ``limit`` (in units, so no path
    truly within the limit is cut) are not searched. ``dist``, ``pred``, ``stamp`` (nx * ny):
    scratch reused between calls, a cell's entries being valid only where ``stamp == call`` (a
    number never used before). Returns the flat cell indices from src to dst (empty when there is
    none within the limit)."""
    ti = dst // ny
    tj = dst % ny
    lim = int(math.floor(limit / h * STEP_UNITS + 1e-9))
    ai = abs(src // ny - ti)
    aj = abs(src % ny - tj)
    f0 = STEP_UNITS * max(ai, aj) + (DIAG_UNITS - STEP_UNITS) * min(ai, aj)
    if f0 > lim:
        return np.zeros(0, np.int64)
    nb = lim - f0 + 1
    head = np.full(nb, -1, np.int64)
    cap = 4096
    ev = np.empty(cap, np.int64)          # entries: cell, length so far, next entry in the bucket
    eg = np.empty(cap, np.int64)
    en = np.empty(cap, np.int64)
    stamp[src] = call
    dist[src] = 0
    pred[src] = -1
    ev[0] = src
    eg[0] = 0
    en[0] = -1
    head[0] = 0
    ne = 1
    b = 0
    found = False
    while b < nb:
        e = head[b]
        if e < 0:
            b += 1
            continue
        head[b] = en[e]
        u = ev[e]
        d = eg[e]
        if d > dist[u]:
            continue
        if u == dst:
            found = True
            break
        ui = u // ny
        uj = u % ny
        for di in range(-1, 2):
            vi = ui + di
            if vi < i0 or vi >= i1:
                continue
            for dj in range(-1, 2):
                if di == 0 and dj == 0:
                    continue
                vj = uj + dj
                if vj < j0 or vj >= j1:
                    continue
                v = vi * ny + vj
                if not flat[v]:
                    continue
                nd = d + (DIAG_UNITS if di != 0 and dj != 0 else STEP_UNITS)
                if stamp[v] == call and nd >= dist[v]:
                    continue
                ai = abs(vi - ti)
                aj = abs(vj - tj)
                f = nd + STEP_UNITS * max(ai, aj) + (DIAG_UNITS - STEP_UNITS) * min(ai, aj)
                if f > lim:
                    continue
                stamp[v] = call
                dist[v] = nd
                pred[v] = u
                if ne == cap:
                    cap *= 2
                    v2 = np.empty(cap, np.int64)
                    g2 = np.empty(cap, np.int64)
                    n2 = np.empty(cap, np.int64)
                    for q in range(ne):
                        v2[q] = ev[q]
                        g2[q] = eg[q]
                        n2[q] = en[q]
                    ev, eg, en = v2, g2, n2
                k = f - f0
                ev[ne] = v
                eg[ne] = nd
                en[ne] = head[k]
                head[k] = ne
                ne += 1
    if not found:
        return np.zeros(0, np.int64)
    m = 1
    u = dst
    while u != src:
        u = pred[u]
        m += 1
    out = np.empty(m, np.int64)
    u = dst
    for k in range(m - 1, -1, -1):
        out[k] = u
        u = pred[u]
    return out


@njit(cache=True, nogil=True)
def _max_rows(a, k, out):
    """``out[i, j] = max(a[i, j - k : j + k + 1])`` (the window clipped to the row), van Herk /
    Gil-Werman: blocks of 2k + 1 on the row padded by k with -inf, prefix and suffix maxima."""
    n, m = a.shape
    w = 2 * k + 1
    L = m + 2 * k
    buf = np.full(L, -np.inf)
    G = np.empty(L)
    H = np.empty(L)
    for i in range(n):
        for j in range(m):
            buf[k + j] = a[i, j]
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
            out[i, j] = max(H[j], G[j + 2 * k])


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
def _disc_max(v, h, reach):
    """``out[c] = max v[c']`` over the cells c' whose centre is closer than ``reach`` to c's
    (``sqrt(di^2 + dj^2) h < reach``; -inf when none): with ``v`` the cells' highest point, a cell
    is within ``reach`` of a cell holding a point above t exactly when ``out > t`` (the same test
    as an exact distance transform of the cells above t). The disc is cut in rows of offsets
    ``di``, each a 1-D window of half width ``w(di)``: one row filter per distinct width."""
    nx, ny = v.shape
    K = int(math.ceil(reach / h)) + 1
    wd = np.full(K + 1, -1, np.int64)
    for di in range(K + 1):
        for dj in range(K + 1):
            if math.sqrt(float(di * di + dj * dj)) * h < reach:
                wd[di] = dj
    out = np.full((nx, ny), -np.inf)
    tmp = np.empty((nx, ny))
    done = np.zeros(K + 1, np.bool_)
    for d0 in range(K + 1):
        if wd[d0] < 0 or done[d0]:
            continue
        _max_rows(v, wd[d0], tmp)
        for di in range(d0, K + 1):
            if wd[di] != wd[d0]:
                continue
            done[di] = True
            for sgn in (-1, 1):
                if di == 0 and sgn == 1:
                    continue
                dd = sgn * di
                for i in range(max(0, -dd), min(nx, nx - dd)):
                    for j in range(ny):
                        out[i, j] = max(out[i, j], tmp[i + dd, j])
    return out


@njit(cache=True, nogil=True)
def _find(parent, a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@njit(cache=True, nogil=True)
def _region_runs(G, thr, inbox, region):
    """A level's region and its components: ``region = inbox & (G <= thr)`` (the forbidden cells
    are those with ``G > thr``). The region's runs along y per row
    (``rows[i]:rows[i + 1]`` index the runs of row i, cells ``j0[r] .. j1[r] - 1``) and their
    8-connected components (union-find on the runs of neighbouring rows), numbered from 1 in the
    raster order of their first cell (as ``scipy.ndimage.label``). Returns (rows, j0, j1, comp)."""
    nx, ny = region.shape
    rows = np.empty(nx + 1, np.int64)
    nr = 0
    for i in range(nx):
        rows[i] = nr
        rr = region[i]
        ib = inbox[i]
        gi = G[i]
        prev = False
        for j in range(ny):
            v = ib[j] and not gi[j] > thr
            rr[j] = v
            nr += v and not prev
            prev = v
    rows[nx] = nr
    j0 = np.empty(nr, np.int64)
    j1 = np.empty(nr, np.int64)
    for i in range(nx):
        rr = region[i]
        k = rows[i]
        prev = False
        for j in range(ny):
            v = rr[j]
            if v and not prev:
                j0[k] = j
            elif prev and not v:
                j1[k] = j
                k += 1
            prev = v
        if prev:
            j1[k] = ny
    parent = np.arange(nr)
    for i in range(1, nx):
        a, ae = rows[i - 1], rows[i]
        b, be = rows[i], rows[i + 1]
        while a < ae and b < be:
            if j0[a] <= j1[b] and j0[b] <= j1[a]:         # touching, diagonals included
                ra = _find(parent, a)
                rb = _find(parent, b)
                if ra != rb:
                    if ra < rb:
                        parent[rb] = ra
                    else:
                        parent[ra] = rb
            if j1[a] < j1[b]:
                a += 1
            else:
                b += 1
    comp = np.zeros(nr, np.int64)
    lab = np.zeros(nr, np.int64)
    nxt = 1
    for r in range(nr):
        root = _find(parent, r)
        if lab[root] == 0:
            lab[root] = nxt
            nxt += 1
        comp[r] = lab[root]
    return rows, j0, j1, comp


@njit(cache=True, nogil=True)
def _comp_at(rows, j0, j1, comp, i, j):
    """Component of cell (i, j) (0 when not in the region), from :func:`_region_runs`."""
    lo = rows[i]
    hi = rows[i + 1]
    while lo < hi:                      # first run of the row ending after j
        mid = (lo + hi) // 2
        if j1[mid] <= j:
            lo = mid + 1
        else:
            hi = mid
    if lo < rows[i + 1] and j0[lo] <= j:
        return comp[lo]
    return 0


@njit(cache=True, nogil=True)
def _line_runs(region, cols, rows, j0, j1, comp):
    """Runs of region cells along x in the raster columns ``cols`` (the clearing lines): arrays
    (line index, first cell, end cell (exclusive), component)."""
    nx = region.shape[0]
    cap = 256
    out = np.empty((cap, 4), np.int64)
    n = 0
    for r in range(cols.shape[0]):
        j = cols[r]
        start = -1
        for i in range(nx + 1):
            v = i < nx and region[i, j]
            if v and start < 0:
                start = i
            elif not v and start >= 0:
                if n == cap:
                    cap *= 2
                    o2 = np.empty((cap, 4), np.int64)
                    for q in range(n):
                        for c in range(4):
                            o2[q, c] = out[q, c]
                    out = o2
                out[n, 0] = r
                out[n, 1] = start
                out[n, 2] = i
                out[n, 3] = _comp_at(rows, j0, j1, comp, start, j)
                n += 1
                start = -1
    return out[:n]


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


@dataclass
class _Piece:
    """A piece of clearing at one level: a line run or a contour chain. ``xy`` (m,2), ``cells``
    (m,) flat raster index of an allowed cell within h of each vertex; ``ends``: 'both' (either
    end may start: zig-zag lines), 'start' (one-way lines, open chains) or 'loop' (closed: any
    vertex, ``xy[0] == xy[-1]``)."""

    comp: int
    xy: np.ndarray
    cells: np.ndarray
    ends: str
    is_line: bool
    row: int = -1


class _Scratch:
    """Arrays of the grid searches, allocated at the first search and kept for the whole roughing
    (see :func:`_grid_path_cells`)."""

    def __init__(self, n):
        self.n = n
        self.dist = self.pred = self.stamp = None
        self.calls = 0

    def next_call(self):
        if self.stamp is None:
            self.dist = np.empty(self.n, np.int32)
            self.pred = np.empty(self.n, np.int32)
            self.stamp = np.zeros(self.n, np.int32)
        self.calls += 1
        return self.calls


class _Level:
    """Per-level raster state used while ordering and linking."""

    def __init__(self, region, x0, y0, h, nx, ny, z, top_dil, H, Rt, scratch):
        self.Rt = Rt
        self.scratch = scratch
        self.region = region
        self.flat = region.ravel()
        self.x0, self.y0, self.h, self.nx, self.ny = x0, y0, h, nx, ny
        self.z = z
        self.H = H                                   # the material map's coarse cells, same origin
        self.ncx, self.ncy = top_dil.shape
        self.top_flat = np.ascontiguousarray(top_dil).ravel()

    def top_at(self, xy) -> float:
        """Highest remaining material under the tool disc about xy (from the dilated map)."""
        ix = min(max(int(math.floor((xy[0] - self.x0) / self.H)), 0), self.ncx - 1)
        iy = min(max(int(math.floor((xy[1] - self.y0) / self.H)), 0), self.ncy - 1)
        return float(self.top_flat[ix * self.ncy + iy])

    def cell_of(self, xy):
        """Flat index of the cell containing each point (clipped into the raster)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ix = np.clip(np.floor((xy[:, 0] - self.x0) / self.h).astype(np.int64), 0, self.nx - 1)
        iy = np.clip(np.floor((xy[:, 1] - self.y0) / self.h).astype(np.int64), 0, self.ny - 1)
        return ix * self.ny + iy

    def visible(self, a, b) -> bool:
        """The straight move a -> b at the level stays in the region: every sample (h / 4 apart) lies
        in a region cell, so every point of the move is within 0.96 h of an allowed centre."""
        return bool(_seg_in(self.flat, self.x0, self.y0, self.h, self.nx, self.ny,
                            float(a[0]), float(a[1]), float(b[0]), float(b[1])))

    def corridor_top(self, a, b) -> float:
        """Highest remaining material under the tool disc along a -> b (from the dilated map)."""
        return float(_seg_max(self.top_flat, self.x0, self.y0, self.H, self.ncx, self.ncy,
                              float(a[0]), float(a[1]), float(b[0]), float(b[1])))

    def grid_path(self, a, ca, b, cb, limit):
        """Shortest path at the level from a (in region cell ca) to b (cell cb) on the 8-connected
        graph of region cells (Popescu's graph; :func:`_grid_path_cells`), shortened by line of
        sight (:func:`_line_of_sight`); None when longer than ``limit`` (the search stays in the box
        holding every such path)."""
        sc = self.scratch
        call = sc.next_call()
        path = _link_path(self.flat, self.x0, self.y0, self.h, self.nx, self.ny, float(a[0]), float(a[1]),
                          float(b[0]), float(b[1]), int(ca), int(cb), float(limit), sc.dist, sc.pred, sc.stamp,
                          call)
        return path if path.shape[0] else None


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


def _line_pieces(region, runs, ys, x0, y0, h, ny, oneway) -> list[_Piece]:
    cols = np.array([int(math.floor((y - y0) / h)) for y in ys], np.int64)
    out = []
    for r, i0, i1, comp in _line_runs(region, cols, *runs).tolist():       # cells i0 .. i1 - 1
        y, j = float(ys[r]), int(cols[r])
        xy = np.array([[x0 + i0 * h, y], [x0 + i1 * h, y]])
        cells = np.array([i0 * ny + j, (i1 - 1) * ny + j])
        out.append(_Piece(comp, xy, cells, "start" if oneway else "both", True, r))
    return out


def _contour_pieces(region, G, thr, runs, x0, y0, h) -> list[_Piece]:
    ny = region.shape[1]
    edges, starts = _march(region, *runs[:3])
    if edges.size == 0:
        return []
    cell, keep, gx, gy = _edge_cells(edges, region, G, thr)
    out = []
    for k in range(starts.size - 1):
        s0, s1 = starts[k], starts[k + 1]
        kf = keep[s0:s1]
        if not kf.any():
            continue
        idx = np.arange(s0, s1)
        if kf.all():
            pieces = [(np.concatenate([idx, idx[:1]]), True)]
        else:
            r = int(np.flatnonzero(~kf)[0])
            idx = np.roll(idx, -r)
            kr = np.roll(kf, -r)
            e = np.flatnonzero(np.diff(np.concatenate([[0], kr.astype(np.int8), [0]])))
            pieces = [(idx[a:b], False) for a, b in zip(e[::2], e[1::2]) if b - a >= 2]
        for run, closed in pieces:
            g = np.stack([gx[run], gy[run]], 1)
            if g.shape[0] > 2:          # drop the middle of collinear vertices (exact, integer coordinates)
                d = np.diff(g, axis=0)
                sel = np.concatenate([[True], np.any(d[1:] != d[:-1], axis=1), [True]])
                run, g = run[sel], g[sel]
            xy = np.stack([x0 + 0.5 * h * g[:, 0], y0 + 0.5 * h * g[:, 1]], 1)
            c0 = int(cell[run[0]])
            comp = int(_comp_at(*runs, c0 // ny, c0 % ny))
            out.append(_Piece(comp, xy, cell[run], "loop" if closed else "start", False))
    return out


class _Writer:
    """Collects the moves (tip points and uses) and the counts."""

    def __init__(self):
        self.pts: list[np.ndarray] = []
        self.codes: list[int] = []
        self.counts: list[int] = []
        self.n_retracts = 0

    def add(self, xyz, use):
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        self.pts.append(xyz)
        self.codes.append(use)
        self.counts.append(xyz.shape[0])

    def use(self) -> np.ndarray:
        return np.repeat(np.array(self.codes, np.int8), self.counts)


def roughing_paths(cloud_frame, *, tool_radius_mm: float, corner_radius_mm: float = 0.0, step_down_mm: float = 2.0,
                   stock_allowance_mm: float = 0.5, stock_margin_mm: float = 2.0,
                   stepover_mm: float | None = None, pattern: str = "zigzag", contour: bool = True,
                   floor_z_mm: float | None = None, cell_mm: float | None = None,
                   safe_z_mm: float | None = None,
                   progress: Callable[[int, int], None] | None = None) -> RoughingPath:
    """Z-level roughing of one set-up from a stock box (mm, area frame; see the module docstring).

    ``cloud_frame`` (N,3): the whole cloud in the area frame (every point is an obstacle);
    ``tool_radius_mm`` Rt; ``corner_radius_mm`` rc (0: flat end mill, 0 < rc <= Rt: bull-nose);
    ``step_down_mm``: depth between levels; ``stock_allowance_mm``: least distance left between
    the tool and every cloud point; ``stock_margin_mm``: the stock box is the cloud's box grown by
    this on the sides and on the top; ``stepover_mm``: distance between clearing lines (default
    0.6 x diameter, at most the diameter); ``pattern``: ``"zigzag"`` or ``"oneway"`` (lines along
    +X only, rapid back); ``contour``: add the offset-contour pass; ``floor_z_mm``: lowest tip
    height (default lowest cloud z + allowance); ``cell_mm``: raster cell (default Rt / 16, at
    most Rt / 2); ``safe_z_mm``: retract height cap and first approach (default stock top + 5 mm);
    ``progress(levels_done, n_levels)``.
    """
    pts = _check_points(cloud_frame)
    Rt, rc = _check_tool(tool_radius_mm, corner_radius_mm)
    step = _finite("step_down_mm", step_down_mm)
    a = _finite("stock_allowance_mm", stock_allowance_mm)
    margin = _finite("stock_margin_mm", stock_margin_mm)
    if not step > 0:
        raise ParameterError(f"step_down_mm = {step_down_mm}: the depth of cut must be > 0 mm")
    if not a >= 0:
        raise ParameterError(f"stock_allowance_mm = {stock_allowance_mm}: must be >= 0 mm")
    if not margin >= 0:
        raise ParameterError(f"stock_margin_mm = {stock_margin_mm}: must be >= 0 mm")
    s = 1.2 * Rt if stepover_mm is None else _finite("stepover_mm", stepover_mm)
    if not 0 < s <= 2 * Rt:
        raise ParameterError(f"stepover_mm = {stepover_mm}: must be in (0, {2 * Rt}] mm (at most the tool "
                             f"diameter, or stock is left between the lines)")
    if pattern not in ("zigzag", "oneway"):
        raise ParameterError(f"pattern = {pattern!r}: must be 'zigzag' or 'oneway'")
    h = Rt / 16.0 if cell_mm is None else _finite("cell_mm", cell_mm)
    if not 0 < h <= Rt / 2:
        raise ParameterError(f"cell_mm = {cell_mm}: must be in (0, {Rt / 2}] mm (half the tool radius)")

    lo, hi, big = _bounds(pts)
    z_top = float(hi[2]) + margin
    floor = float(lo[2]) + a if floor_z_mm is None else _finite("floor_z_mm", floor_z_mm)
    if not floor < z_top:
        raise ParameterError(f"floor_z_mm = {floor}: must be below the stock top {z_top} mm")
    safe = z_top + 5.0 if safe_z_mm is None else _finite("safe_z_mm", safe_z_mm)
    if not safe > z_top:
        raise ParameterError(f"safe_z_mm = {safe}: must be above the stock top {z_top} mm (the highest cloud "
                             f"point + stock_margin_mm)")
    box_lo = lo[:2] - margin
    box_hi = hi[:2] + margin

    # levels: every step from the top, the last at the floor
    if (z_top - floor) / step > MAX_LEVELS:
        raise ParameterError(f"step_down_mm = {step_down_mm}: {(z_top - floor) / step:.0f} levels from the stock top "
                             f"{z_top} to the floor {floor} mm; at most {MAX_LEVELS}")
    levels = []
    k = 1
    while z_top - k * step > floor + Z_TOL_MM:
        levels.append(z_top - k * step)
        k += 1
    levels.append(floor)
    levels = np.array(levels)

    # raster over the stock box grown by g = Rt - h (tool centres) and a border
    g = Rt - h
    ext = float(max(box_hi[0] - box_lo[0], box_hi[1] - box_lo[1])) + 2 * (g + 3 * h)
    h = max(h, ext / math.sqrt(MAX_CELLS))
    if h > Rt / 2:
        raise ParameterError(f"the stock ({ext:.0f} mm across) is too large for a {2 * Rt} mm cutter: the map would "
                             f"need more than {MAX_CELLS} cells; use a larger tool or rough a smaller area")
    g = Rt - h
    x0 = float(box_lo[0]) - g - 3 * h
    y0 = float(box_lo[1]) - g - 3 * h
    nx = int(math.ceil((box_hi[0] + g + 3 * h - x0) / h))
    ny = int(math.ceil((box_hi[1] + g + 3 * h - y0) / h))
    cmax = _cell_max(pts, x0, y0, h, nx, ny)
    cx = x0 + (np.arange(nx) + 0.5) * h
    cy = y0 + (np.arange(ny) + 0.5) * h
    ox = np.maximum(np.maximum(box_lo[0] - cx, cx - box_hi[0]), 0.0)     # distance to the box along x
    oy = np.maximum(np.maximum(box_lo[1] - cy, cy - box_hi[1]), 0.0)
    inbox = np.hypot(ox[:, None], oy[None, :]) <= g                         # centre within g of the box
    # remaining material: a height map on coarse cells (TOP_CELLS x TOP_CELLS raster cells, same
    # origin), each cell clipped to the stock box (centre, half sides); -inf outside the stock
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
    top = np.where(inx[:, None] & iny[None, :], z_top, -np.inf)
    kdil = int(math.ceil((Rt + 0.25 * H) / H))              # square >= the disc about any point within H / 8 of a cell

    # clearing lines: y positions fixed for all levels
    W = float(box_hi[1] - box_lo[1])
    span = W + 2 * h - 2 * max(Rt - rc, 0.5 * Rt)           # the flat bottom reaches past the sides
    if span <= 0:
        ys = np.array([0.5 * (box_lo[1] + box_hi[1])])
    else:
        n = int(math.ceil(span / s - 1e-9)) + 1
        ys = 0.5 * (box_lo[1] + box_hi[1]) + (np.arange(n) - (n - 1) / 2.0) * (span / (n - 1))

    K = int(min(MAX_BANDS, max(1, math.ceil((rc + a) / (2 * h)))))
    fmargin = h * (1.0 + 1.0 / _SQ2) + 1e-9 * max(1.0, float(big))
    Rf = Rt - rc

    w = _Writer()
    cur = None                    # current tip (x, y, z)
    level_retracts = np.zeros(levels.size, np.int64)
    removed = np.zeros(levels.size)

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
    region = np.empty((nx, ny), dtype=bool)
    top_dil = None
    scratch = _Scratch(nx * ny)
    for li, z in enumerate(levels):
        thr = _bands(float(z), Rt, rc, a, K)[0][0] if K == 1 else float(z)
        runs = _region_runs(G, thr, inbox, region)
        if top_dil is None:
            top_dil = _square_max(top, kdil)
        if runs[1].size:
            lv = _Level(region, x0, y0, h, nx, ny, float(z), top_dil, H, Rt, scratch)
            pieces = _line_pieces(region, runs, ys, x0, y0, h, ny, pattern == "oneway")
            if contour:
                pieces += _contour_pieces(region, G, thr, runs, x0, y0, h)
            cur, swept = _cut_level(w, lv, pieces, cur, safe, pattern == "oneway", level_retracts, li)
            # remaining material: cells the flat bottom (or the corner) surely swept
            if swept:
                starts = np.zeros(len(swept) + 1, np.int64)
                np.cumsum([p.shape[0] for p in swept], out=starts[1:])
                removed[li] = _sweep_top(top, tcx, tcy, thd, tarea, tfx, tfy, np.concatenate(swept).astype(np.float64),
                                         starts, x0, y0, H, float(z), Rf, Rt, rc, 0.25 * h)
                top_dil = None
        if progress is not None:
            progress(li + 1, int(levels.size))

    if cur is not None:
        _retract(w, cur, safe)
        xyz = np.concatenate(w.pts)
        use = w.use()
    else:
        xyz = np.zeros((0, 3))
        use = np.zeros(0, np.int8)
    tp = lines(xyz, use, tip_offset_mm=0.0)
    clear = math.inf
    if xyz.shape[0]:
        # a point more than Rt below the lowest tip is farther than Rt from the tool solid: leave it out
        near = pts[pts[:, 2] >= float(xyz[:, 2].min()) - Rt]
        if near.shape[0]:
            clear = min_tool_clearance(xyz, near, tool_radius_mm=Rt, corner_radius_mm=rc, reach_mm=Rt).min_mm
    return RoughingPath(
        toolpath=tp, levels_mm=levels, n_levels=int(levels.size),
        length_mm=path_length_mm(tp, kinds=(FEED,)), air_mm=path_length_mm(tp, kinds=(RAPID,)),
        n_retracts=int(w.n_retracts), min_clearance_mm=float(clear), removed_note=REMOVED_NOTE,
        level_retracts=level_retracts, removed_mm3=removed,
        stock_box_mm=np.array([[box_lo[0], box_lo[1], float(lo[2])], [box_hi[0], box_hi[1], z_top]]),
        cell_mm=float(h), stepover_mm=float(s))


def _entry(piece: _Piece, p):
    """Where to enter a piece from point p: (distance, oriented xy, oriented cells)."""
    if piece.ends == "loop":
        d = np.hypot(piece.xy[:-1, 0] - p[0], piece.xy[:-1, 1] - p[1])
        k = int(np.argmin(d))
        xy = np.concatenate([piece.xy[k:-1], piece.xy[:k + 1]])
        cells = np.concatenate([piece.cells[k:-1], piece.cells[:k + 1]])
        return float(d[k]), xy, cells
    d0 = float(np.hypot(*(piece.xy[0] - p)))
    if piece.ends == "both":
        d1 = float(np.hypot(*(piece.xy[-1] - p)))
        if d1 < d0:
            return d1, piece.xy[::-1], piece.cells[::-1]
    return d0, piece.xy, piece.cells


def _zones(lines_: list[_Piece]) -> list[list[_Piece]]:
    """Boustrophedon zones of one component's line runs: a run and the run of the next row are in
    the same zone when each is the other's only overlapping run (in x) in that row."""
    by_row: dict[int, list[_Piece]] = {}
    for pc in lines_:
        by_row.setdefault(pc.row, []).append(pc)
    up: dict[int, list[_Piece]] = {}
    down: dict[int, list[_Piece]] = {}
    ext = {id(pc): (min(float(pc.xy[0, 0]), float(pc.xy[-1, 0])), max(float(pc.xy[0, 0]), float(pc.xy[-1, 0])))
           for pc in lines_}                 # a line run is a straight segment along x
    for r, runs in by_row.items():
        for a in runs:
            for b in by_row.get(r + 1, []):
                if min(ext[id(a)][1], ext[id(b)][1]) > max(ext[id(a)][0], ext[id(b)][0]):
                    up.setdefault(id(a), []).append(b)
                    down.setdefault(id(b), []).append(a)
    zones, seen = [], set()
    for r in sorted(by_row):
        for a in sorted(by_row[r], key=lambda pc: ext[id(pc)][0]):
            if id(a) in seen:
                continue
            zone = [a]
            seen.add(id(a))
            while True:
                nxt = up.get(id(zone[-1]), [])
                if len(nxt) != 1 or len(down.get(id(nxt[0]), [])) != 1 or id(nxt[0]) in seen:
                    break
                zone.append(nxt[0])
                seen.add(id(nxt[0]))
            zones.append(zone)
    return zones


def _zone_variants(zone: list[_Piece], oneway):
    """The ways to cut a zone: from its first or last run, entered at either end (one-way: the -X
    end), zig-zag alternating; each as a list of (piece, oriented xy, oriented cells)."""
    out = []
    ends = {id(pc): (pc.xy[0].tolist(), pc.xy[-1].tolist()) for pc in zone}
    for runs in ((zone, zone[::-1]) if len(zone) > 1 else (zone,)):
        for flip in ((False,) if oneway else (False, True)):
            seq = []
            end = None
            for k, pc in enumerate(runs):
                first, last = ends[id(pc)]
                if oneway:
                    f = False
                elif k == 0:
                    f = flip
                else:                   # enter each run at the end nearer the last exit
                    f = math.hypot(last[0] - end[0], last[1] - end[1]) < math.hypot(first[0] - end[0],
                                                                                    first[1] - end[1])
                seq.append((pc, pc.xy[::-1], pc.cells[::-1]) if f else (pc, pc.xy, pc.cells))
                end = first if f else last
            out.append(seq)
    return out


def _near(p, variants_lists, contours):
    """Distance from p to the nearest entry of the remaining zones (or else contours; 0 if none)."""
    d = [float(np.hypot(*(v[0][1][0] - p))) for vs in variants_lists for v in vs]
    if not d:
        d = [_entry(pc, p)[0] for pc in contours]
    return min(d) if d else 0.0


def _exit_entry(ext, ent, zone_ext, zone_ent=None):
    """Distances from the exits ``ext`` (m,2) to the entries ``ent`` (n,2), inf between variants of
    the same zone."""
    zone_ent = zone_ext if zone_ent is None else zone_ent
    D = np.hypot(ent[None, :, 0] - ext[:, None, 0], ent[None, :, 1] - ext[:, None, 1])
    D[zone_ext[:, None] == zone_ent[None, :]] = np.inf
    return D


def _order(pieces: list[_Piece], p, oneway):
    """The order of a level's pieces from point p (None: anywhere): components one after another
    (the nearest next), in each the line zones then the contours. Zones: greedy on the distance to
    the zone's entry plus the distance from its exit to the next remaining entry (one step of
    look-ahead; the distances from every exit to every entry computed at once); contours: greedy
    nearest vertex."""
    comps: dict[int, tuple[list, list]] = {}
    for pc in pieces:
        comps.setdefault(pc.comp, ([], []))[0 if pc.is_line else 1].append(pc)
    todo = {}
    for c, (ls, cs) in comps.items():
        zs = [_zone_variants(z, oneway) for z in _zones(ls)]
        flat = [v for vs in zs for v in vs]
        zone = np.array([i for i, vs in enumerate(zs) for _ in vs], np.int64)
        ent = np.array([v[0][1][0] for v in flat]).reshape(-1, 2)
        ext = np.array([v[-1][1][-1] for v in flat]).reshape(-1, 2)
        todo[c] = (flat, zone, ent, ext, len(zs), list(cs))
    seq = []
    while todo:
        def entry_dist(c, p=p):
            flat, _, ent, _, _, cs = todo[c]
            if p is None:
                return 0.0
            if flat:
                return float(np.hypot(ent[:, 0] - p[0], ent[:, 1] - p[1]).min())
            return _near(p, [], cs)
        c = min(todo, key=entry_dist)
        flat, zone, ent, ext, nz, cs = todo.pop(c)
        if flat:
            # D[v, w]: from the exit of variant v to the entry of variant w of another zone
            D = _exit_entry(ext, ent, zone) if len(flat) <= ORDER_DENSE_MAX else None
            alive = np.ones(len(flat), dtype=bool)
            for _ in range(nz):
                live = np.flatnonzero(alive)
                if np.unique(zone[live]).size > 1:
                    if D is not None:
                        near = D[np.ix_(live, live)].min(axis=1)
                    else:
                        near = np.concatenate([_exit_entry(ext[live[k:k + 256]], ent[live], zone[live[k:k + 256]],
                                                           zone[live]).min(axis=1) for k in range(0, live.size, 256)])
                else:                       # the last zone: look ahead to the contours
                    near = np.array([_near(ext[v], [], cs) for v in live])
                d = np.zeros(live.size) if p is None else np.hypot(ent[live, 0] - p[0], ent[live, 1] - p[1])
                v = int(live[int(np.argmin(d + near))])
                alive[zone == zone[v]] = False
                seq += flat[v]
                p = flat[v][-1][1][-1]
        while cs:
            if p is None:
                p = cs[0].xy[0]
            k = min(range(len(cs)), key=lambda i: _entry(cs[i], p)[0])
            pc = cs.pop(k)
            _, xy, cells = _entry(pc, p)
            seq.append((pc, xy, cells))
            p = xy[-1]
    return seq


def _cut_level(w: _Writer, lv: _Level, pieces: list[_Piece], cur, safe, oneway, level_retracts, li):
    """Cut the pieces of one level in :func:`_order`'s order, linked at the level or by lifts;
    returns the new current tip and the polylines cut at the level."""
    z = lv.z
    here = None                  # (xy, cell, component) where the tool is at this level
    swept = []
    prev_line = False
    for piece, xy, cells in _order(pieces, None if cur is None else np.asarray(cur[:2]), oneway):
        q = xy[0]
        linked = False
        if here is not None and here[2] == piece.comp and not (oneway and piece.is_line and prev_line):
            worth = max(4.0 * lv.Rt, _lift_cost(lv, here[0], q, z, safe))     # longest link kept at the level
            dist = float(np.hypot(*(q - here[0])))
            if dist <= worth and lv.visible(here[0], q):
                w.add([q[0], q[1], z], USE_CUT)
                swept.append(np.array([here[0], q]))
                linked = True
            elif dist <= worth:
                path = lv.grid_path(here[0], here[1], q, cells[0], worth)
                if path is not None:
                    w.add(np.column_stack([path[1:], np.full(path.shape[0] - 1, z)]), USE_CUT)
                    swept.append(path)
                    linked = True
        if not linked:
            if here is not None:
                level_retracts[li] += 1
            _lift(w, lv, cur, q, z, safe)
        w.add(np.column_stack([xy[1:], np.full(xy.shape[0] - 1, z)]), USE_CUT)
        prev_line = piece.is_line
        swept.append(xy)
        cur = (float(xy[-1, 0]), float(xy[-1, 1]), z)
        here = (xy[-1].copy(), cells[-1], piece.comp)
    return cur, swept


def _link_height(lv: _Level, a, b, z_from, z_to, safe):
    zt = lv.corridor_top(a, b) + GAP_MM
    return min(safe, max(zt, z_from + GAP_MM, z_to + GAP_MM))


def _lift_cost(lv: _Level, a, b, z, safe) -> float:
    """What lifting from a to b at level z costs, as a length of feed: up and down at feed, the rapid
    across at 1 / RAPID_RATIO of its length."""
    zl = _link_height(lv, a, b, z, z, safe)
    return 2.0 * (zl - z) + float(np.hypot(*(b - a))) / RAPID_RATIO


def _retract(w: _Writer, cur, zl):
    """Out of the cut by GAP_MM at feed (``USE_RETRACT``), then up to ``zl`` by rapid (straight up
    from a position that is safe at its level is safe at any height above)."""
    zr = min(cur[2] + GAP_MM, zl)
    w.add([cur[0], cur[1], zr], USE_RETRACT)
    w.n_retracts += 1
    if zl > zr:
        w.add([cur[0], cur[1], zl], USE_RAPID)


def _lift(w: _Writer, lv: _Level, cur, q, z, safe):
    """Lift from ``cur`` (or from nowhere: first approach at the safe height), rapid over, rapid down to
    GAP_MM above the remaining material under the disc at q, plunge to z."""
    if cur is None:
        zl = safe
        w.add([q[0], q[1], safe], USE_RAPID)
    else:
        a = np.array(cur[:2])
        zl = _link_height(lv, a, q, cur[2], z, safe)
        _retract(w, cur, zl)
        w.add([q[0], q[1], zl], USE_RAPID)
    zd = min(zl, max(lv.top_at(q), z) + GAP_MM)
    if zd < zl:
        w.add([q[0], q[1], zd], USE_RAPID)
    w.add([q[0], q[1], z], USE_PLUNGE)
