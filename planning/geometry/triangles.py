"""A ball-end cutter against a triangle mesh: the exact drop (OpenCAMLib's drop-cutter for a
``BallCutter``, Sood 2015's vertex, edge and face contacts) and the exact distance from straight
ball-centre moves to the triangles (the gouge check of a path on a mesh).

Everything in a frame whose +Z is the tool axis, mm. The mesh is ``vertices`` (V,3) float64 and
``faces`` (T,3) int64 indices into them. Triangles are two-sided: the winding does not matter
(a facet's normal is taken pointing up), so facets whose stored normal points down count like any
other; a vertical facet (normal z exactly 0) can only be touched at its edges and vertices, which
is where the highest contact with it lies. Degenerate triangles (zero area) count through their
edges and vertices.

**Drop.** A ball of radius ``R`` whose centre is on the vertical line through ``(x, y)`` rests on
the mesh at the lowest centre height at which it touches no triangle's interior:

    z_c(x, y) = max over triangles of the highest centre height at which the ball touches it,

and per triangle that is the highest of its contacts (each kept only where its contact point lies
on the triangle):

* vertex ``p`` within R of the line: ``p_z + sqrt(R^2 - rho^2)`` (the point drop);
* edge ``p q``: the ball against the cylinder of radius R about the edge's line. In the vertical
  plane of the edge the ball's section is a circle of radius ``r' = sqrt(R^2 - d^2)`` (``d`` the
  horizontal distance from the line to that plane); it rests on the line at parameter
  ``t = u / L_h + r' dz / (L L_h)`` (``u`` the line's projection along the edge, ``L`` and ``L_h``
  the edge's length and horizontal length), kept for ``0 <= t <= 1``, centre height
  ``p_z + t dz + r' L_h / L``. Vertical edges (``L_h = 0``) touch the ball first at their top
  vertex.
* facet: the centre is ``R`` above the plane along the upward unit normal ``n``: contact point
  ``(x - R n_x, y - R n_y)`` on the plane, kept when its barycentric coordinates in the triangle's
  xy projection are all >= 0; centre height = the plane's height there (that convex combination
  of the vertex heights, so a steep facet's rounding stays within its own height range) ``+ R n_z``.

The maximum over the candidates that are kept is the exact answer (the set of centre heights at
which the ball meets a convex triangle is an interval, and its top has its nearest point on a
vertex, in an edge or in the facet). ``-inf`` where no triangle comes within R of the line. A
facet contact, when kept, is the triangle's answer (the ball resting on the whole plane bounds
every contact with the triangle), and a vertex is tried only where neither of its two edges keeps
a contact (it lies on both edges' lines).

:class:`TriangleDropSurface` bins the triangles once on a square xy raster: each triangle is listed
in every cell its xy bounding box overlaps, each cell's list sorted by the triangles' highest
vertex (descending), with a copy of each triangle's box beside its entry (read in cell order) and
each cell's (and each 4 x 4 block's) highest vertex. A drop reads the cell under its line first,
then the blocks and cells within R from the line's own outwards, as the point drop does
(:mod:`planning.toolpath.balldrop`): a triangle's highest contact has its contact point in a cell
where the triangle is listed, no nearer the line than that cell and no higher than the cell's
highest vertex, so a cell (block) is skipped when its highest vertex + the ball's height at the
cell's nearest edge cannot beat the best height so far; within a cell the scan stops at the first
triangle whose highest vertex + R cannot, and skips a triangle when its highest vertex + the
ball's height at its xy box cannot, or when the ball resting on the triangle's whole plane cannot
(for facets with n_z >= 0.1). Compiled with numba, parallel over the lines (a serial twin for
short batches). :func:`brute_force_triangle_drop` is the numpy reference (every line against
every triangle, every candidate). Contact: the index of the triangle (row of ``faces``) the ball
rests on, -1 where none; among triangles giving the same height (as computed) the lowest index.

**Clearance.** :func:`triangle_clearance` measures, per straight move ``starts[k] -> ends[k]`` of a
ball-centre path, the smallest distance to any triangle, capped: ``min(true distance, cap_mm)``.
Segment to triangle: 0 when the segment crosses the triangle, else the least of the distances from
its two end points to the triangle (Ericson's closest point on a triangle) and from the segment to
the triangle's three edges (segment-segment, Ericson); exact in exact arithmetic (a closest pair
with both points interior makes the segment parallel to the plane, and sliding along it reaches a
boundary at the same distance). The same raster serves: the triangles within the cap of a move
are listed in the cells its xy bounding box grown by the cap overlaps; a cell is skipped when the
box holding its triangles (its square grown by how far they reach beyond it, between their lowest
and highest z) is no nearer the move's bounding box than the best distance so far; each triangle
is measured once per move (only in the first cell of the overlap of its cells with the move's),
and skipped when its 3D bounding box is no nearer. A ball of radius R following the move gouges
no triangle when the clearance is >= R (minus a tolerance).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from planning.errors import ParameterError
from planning.geometry.kernels import BallDrop, serial_twin
from planning.geometry.kernels import interval_gap as _gap

# Columns of the per-triangle table: the vertices in increasing vertex-index order (so an edge
# shared by two triangles is computed from the same end, giving the same value in both), the
# upward unit normal, the xy projection's doubled signed area, the z range and the xy box.
_A, _B, _C, _N, _AR, _ZLO, _ZHI, _XLO, _XHI, _YLO, _YHI = 0, 3, 6, 9, 12, 13, 14, 15, 16, 17, 18
# the plane's slopes dz/dx, dz/dy and 1/n_z where n_z >= _BOUND_NZ (else 0, 0, inf): the ball resting
# on the whole plane is an upper bound of its rest on the triangle
_PA, _PB, _INZ = 19, 20, 21
_NF = 22
# columns of each raster entry's copy of its triangle's box (read in cell order, not per triangle)
_EZHI, _EZLO, _EXLO, _EXHI, _EYLO, _EYHI = 0, 1, 2, 3, 4, 5
_BOUND_NZ = 0.1
_BLOCK = 4      # raster cells per side of the blocks pruned as a whole (as in the point drop)


def _as_mesh(vertices, faces):
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ParameterError("vertices must be a (V,3) array")
    if F.ndim != 2 or F.shape[1] != 3:
        raise ParameterError("faces must be a (T,3) array of vertex indices")
    if F.size and not np.issubdtype(F.dtype, np.integer):
        raise ParameterError("faces must hold integer vertex indices")
    F = np.ascontiguousarray(F, dtype=np.int64)
    if F.size and (F.min() < 0 or F.max() >= V.shape[0]):
        raise ParameterError(f"faces: vertex indices must be in [0, {V.shape[0]})")
    used = np.zeros(V.shape[0], dtype=bool)
    used[F.ravel()] = True
    if not np.all(np.isfinite(V[used])):
        raise ParameterError("the vertices of the faces must be finite")
    return V, F


def _check_radius(radius_mm) -> float:
    R = float(radius_mm)
    if not (R > 0 and math.isfinite(R)):
        raise ParameterError(f"radius_mm = {radius_mm}: must be > 0")
    return R


def _check_xy(xy) -> np.ndarray:
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ParameterError("xy must be a (K,2) array")
    if not np.all(np.isfinite(xy)):
        raise ParameterError("xy must be finite")
    return xy


@njit(cache=True, nogil=True)
def _fill_table(V, F, tab):
    for t in range(F.shape[0]):
        i0, i1, i2 = F[t, 0], F[t, 1], F[t, 2]
        # vertices in increasing index order
        if i0 > i1:
            i0, i1 = i1, i0
        if i1 > i2:
            i1, i2 = i2, i1
        if i0 > i1:
            i0, i1 = i1, i0
        ax, ay, az = V[i0, 0], V[i0, 1], V[i0, 2]
        bx, by, bz = V[i1, 0], V[i1, 1], V[i1, 2]
        cx, cy, cz = V[i2, 0], V[i2, 1], V[i2, 2]
        tab[t, 0], tab[t, 1], tab[t, 2] = ax, ay, az
        tab[t, 3], tab[t, 4], tab[t, 5] = bx, by, bz
        tab[t, 6], tab[t, 7], tab[t, 8] = cx, cy, cz
        ux, uy, uz = bx - ax, by - ay, bz - az
        vx, vy, vz = cx - ax, cy - ay, cz - az
        nx = uy * vz - uz * vy
        ny = uz * vx - ux * vz
        nz = ux * vy - uy * vx
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        if ln > 0.0:
            nx, ny, nz = nx / ln, ny / ln, nz / ln
        else:
            nx, ny, nz = 0.0, 0.0, 0.0
        if nz < 0.0:
            nx, ny, nz = -nx, -ny, -nz
        nz = abs(nz)                                    # no -0.0
        tab[t, _N], tab[t, _N + 1], tab[t, _N + 2] = nx, ny, nz
        tab[t, _AR] = ux * vy - uy * vx
        tab[t, _ZLO] = min(az, bz, cz)
        tab[t, _ZHI] = max(az, bz, cz)
        tab[t, _XLO] = min(ax, bx, cx)
        tab[t, _XHI] = max(ax, bx, cx)
        tab[t, _YLO] = min(ay, by, cy)
        tab[t, _YHI] = max(ay, by, cy)
        if nz >= _BOUND_NZ:
            tab[t, _PA], tab[t, _PB], tab[t, _INZ] = -nx / nz, -ny / nz, 1.0 / nz
        else:
            tab[t, _PA], tab[t, _PB], tab[t, _INZ] = 0.0, 0.0, np.inf


def triangle_table(vertices, faces) -> np.ndarray:
    """(T, 22) float64 per triangle: vertices in increasing index order (9), upward unit normal (3,
    zeros for a degenerate triangle), doubled signed area of the xy projection, z min, z max,
    x min, x max, y min, y max, and for facets not steeper than n_z = 0.1 the plane's slopes
    dz/dx, dz/dy and 1/n_z (else 0, 0, inf)."""
    V, F = _as_mesh(vertices, faces)
    tab = np.empty((F.shape[0], _NF))
    _fill_table(V, F, tab)
    return tab


# ------------------------------------------------------------------------------------ drop

@njit(cache=True, nogil=True, inline="always")
def _vertex_z(px, py, pz, x, y, R2):
    ex = px - x
    ey = py - y
    rho2 = ex * ex + ey * ey
    if rho2 <= R2:
        return pz + math.sqrt(max(R2 - rho2, 0.0))
    return -np.inf


@njit(cache=True, nogil=True)
def _edge_z(px, py, pz, qx, qy, qz, x, y, R2):
    """Centre height of the ball on the vertical line (x, y) resting on the segment p q (-inf when
    the contact is off the segment or the line is farther than R from it)."""
    dx = qx - px
    dy = qy - py
    dz = qz - pz
    Lh2 = dx * dx + dy * dy
    if Lh2 == 0.0:
        return -np.inf                   # vertical: its top vertex is touched first
    wx = x - px
    wy = y - py
    cr = wx * dy - wy * dx               # L_h times the horizontal distance to the edge's plane
    d2 = cr * cr / Lh2
    if d2 > R2:
        return -np.inf
    rp = math.sqrt(R2 - d2)
    Lh = math.sqrt(Lh2)
    L = math.sqrt(Lh2 + dz * dz)
    t = (wx * dx + wy * dy) / Lh2 + rp * dz / (L * Lh)
    if t < 0.0 or t > 1.0:
        return -np.inf
    return pz + t * dz + rp * (Lh / L)


@njit(cache=True, nogil=True)
def _tri_z(tab, t, x, y, R, R2):
    """Highest ball-centre height on the line (x, y) touching triangle ``t`` (-inf if none). The
    ball on the facet rests as high as on the whole plane, which bounds every other contact, so a
    facet contact is returned at once; a vertex lies on the lines of its two edges, so it is
    needed only where neither edge's contact falls on the segment."""
    ax, ay, az = tab[t, 0], tab[t, 1], tab[t, 2]
    bx, by, bz = tab[t, 3], tab[t, 4], tab[t, 5]
    cx, cy, cz = tab[t, 6], tab[t, 7], tab[t, 8]
    nz = tab[t, _N + 2]
    ar = tab[t, _AR]
    if nz > 0.0 and ar != 0.0:
        # contact point's xy, then its barycentric coordinates in the xy projection
        px = x - R * tab[t, _N]
        py = y - R * tab[t, _N + 1]
        la = ((bx - px) * (cy - py) - (by - py) * (cx - px)) / ar
        lb = ((cx - px) * (ay - py) - (cy - py) * (ax - px)) / ar
        lc = ((ax - px) * (by - py) - (ay - py) * (bx - px)) / ar
        if la >= 0.0 and lb >= 0.0 and lc >= 0.0:
            return (la * az + lb * bz + lc * cz) / (la + lb + lc) + R * nz
    eab = _edge_z(ax, ay, az, bx, by, bz, x, y, R2)
    eac = _edge_z(ax, ay, az, cx, cy, cz, x, y, R2)
    ebc = _edge_z(bx, by, bz, cx, cy, cz, x, y, R2)
    best = max(eab, eac, ebc)
    if eab == -np.inf and eac == -np.inf:
        best = max(best, _vertex_z(ax, ay, az, x, y, R2))
    if eab == -np.inf and ebc == -np.inf:
        best = max(best, _vertex_z(bx, by, bz, x, y, R2))
    if eac == -np.inf and ebc == -np.inf:
        best = max(best, _vertex_z(cx, cy, cz, x, y, R2))
    return best


@njit(cache=True, nogil=True, inline="always")
def _gap1(v, lo, hi):
    """Distance from v to the interval [lo, hi] (0 inside)."""
    if v < lo:
        return lo - v
    if v > hi:
        return v - hi
    return 0.0


@njit(cache=True, nogil=True)
def _cell_scan(tab, orig, ent, ebox, s0, s1, x, y, R, R2, slack, best, bi):
    """The triangles of one cell (highest first) against the line (x, y): (best, its face index)."""
    margin = 1e-9 * R + 64.0 * slack        # rounding of the plane bound (slopes at most 10)
    for e in range(s0, s1):
        zt = ebox[e, _EZHI]
        if zt + R < best:
            break                           # sorted: no later triangle reaches higher
        # no point of the triangle is nearer the line than its xy box (shrunk by the rounding
        # margin), so none rises above its top + the ball's height there
        gx = max(_gap1(x, ebox[e, _EXLO], ebox[e, _EXHI]) - slack, 0.0)
        gy = max(_gap1(y, ebox[e, _EYLO], ebox[e, _EYHI]) - slack, 0.0)
        g2 = gx * gx + gy * gy
        if g2 > R2:
            continue
        if zt + math.sqrt(R2 - g2) + 1e-9 * R < best:
            continue
        t = ent[e]
        # the ball on the triangle's whole plane rests no lower (inf for steep facets)
        ax, ay = tab[t, 0], tab[t, 1]
        if tab[t, 2] + tab[t, _PA] * (x - ax) + tab[t, _PB] * (y - ay) + R * tab[t, _INZ] + margin < best:
            continue
        z = _tri_z(tab, t, x, y, R, R2)
        if z > best or (z == best and orig[t] < bi):
            best = z
            bi = orig[t]
    return best, bi


@njit(parallel=True, cache=True)
def _drop(tab, orig, ent, ebox, start, cmax, bmax, nby, x0, y0, h, nx, ny, xy, R, slack, z_out, idx_out):
    R2 = R * R
    rr = R * (1.0 + 1e-12) + 1e-12          # reach, a hair wide: the exact tests decide
    hb = _BLOCK * h
    nbx = nx // _BLOCK
    for k in prange(xy.shape[0]):
        x, y = xy[k, 0], xy[k, 1]
        best = -np.inf
        bi = -1
        # the cell under the line first: its triangles give a high bound at once
        ixc = int(math.floor((x - x0) / h))
        iyc = int(math.floor((y - y0) / h))
        own = -1
        if 0 <= ixc < nx and 0 <= iyc < ny:
            own = ixc * ny + iyc
            best, bi = _cell_scan(tab, orig, ent, ebox, start[own], start[own + 1], x, y, R, R2, slack, best, bi)
        bxc = int(math.floor((x - x0) / hb))
        byc = int(math.floor((y - y0) / hb))
        bx0 = max(int(math.floor((x - rr - x0) / hb)), 0)
        bx1 = min(int(math.floor((x + rr - x0) / hb)), nbx - 1)
        # blocks from the line's own outwards, columns then rows
        for bo in range(max(bxc - bx0, bx1 - bxc) + 1):
            for bsx in (1, -1):
                if bo == 0 and bsx == -1:
                    continue
                bx = bxc + bsx * bo
                if bx < bx0 or bx > bx1:
                    continue
                gbx = _gap1(x, x0 + bx * hb, x0 + (bx + 1) * hb)
                if gbx > rr:
                    continue
                bhalf = math.sqrt(rr * rr - gbx * gbx)
                by0 = max(int(math.floor((y - bhalf - y0) / hb)), 0)
                by1 = min(int(math.floor((y + bhalf - y0) / hb)), nby - 1)
                for ro in range(max(byc - by0, by1 - byc) + 1):
                    for bsy in (1, -1):
                        if ro == 0 and bsy == -1:
                            continue
                        by = byc + bsy * ro
                        if by < by0 or by > by1:
                            continue
                        # a triangle's contact point lies in a cell its xy box overlaps, where it
                        # is listed: it is no nearer the line than that cell (or block), and no
                        # higher than the cell's highest triangle top (margins as in the point drop)
                        zb = bmax[bx * nby + by]
                        if zb + R < best:
                            continue
                        gx_ = max(gbx - slack, 0.0)
                        gy_ = max(_gap1(y, y0 + by * hb, y0 + (by + 1) * hb) - slack, 0.0)
                        g2 = gx_ * gx_ + gy_ * gy_
                        if g2 > R2 or zb + math.sqrt(R2 - g2) + 1e-9 * R < best:
                            continue
                        for ix in range(bx * _BLOCK, (bx + 1) * _BLOCK):
                            gx = _gap1(x, x0 + ix * h, x0 + (ix + 1) * h)
                            if gx > rr:
                                continue
                            half = math.sqrt(rr * rr - gx * gx)
                            iy0 = max(int(math.floor((y - half - y0) / h)), by * _BLOCK)
                            iy1 = min(int(math.floor((y + half - y0) / h)), (by + 1) * _BLOCK - 1)
                            for iy in range(iy0, iy1 + 1):
                                cc = ix * ny + iy
                                if cc == own or cmax[cc] + R < best:
                                    continue
                                ex_ = max(gx - slack, 0.0)
                                ey_ = max(_gap1(y, y0 + iy * h, y0 + (iy + 1) * h) - slack, 0.0)
                                g2 = ex_ * ex_ + ey_ * ey_
                                if g2 > R2 or cmax[cc] + math.sqrt(R2 - g2) + 1e-9 * R < best:
                                    continue
                                best, bi = _cell_scan(tab, orig, ent, ebox, start[cc], start[cc + 1], x, y, R, R2,
                                                      slack, best, bi)
        z_out[k] = best
        idx_out[k] = bi


@njit(cache=True, nogil=True)
def _raster_order(tab, x0, y0, h, nx, ny):
    """The rows of ``tab`` ordered by the cell of their xy box's low corner (a counting sort):
    (that table, the original row of each)."""
    T = tab.shape[0]
    ncell = nx * ny
    cell = np.empty(T, np.int64)
    start = np.zeros(ncell + 1, np.int64)
    for t in range(T):
        ix = min(max(int(math.floor((tab[t, _XLO] - x0) / h)), 0), nx - 1)
        iy = min(max(int(math.floor((tab[t, _YLO] - y0) / h)), 0), ny - 1)
        cell[t] = ix * ny + iy
        start[cell[t] + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    out = np.empty_like(tab)
    perm = np.empty(T, np.int64)
    for t in range(T):
        r = start[cell[t]]
        start[cell[t]] = r + 1
        out[r, :] = tab[t, :]
        perm[r] = t
    return out, perm


@njit(cache=True, nogil=True)
def _bin(tab, order, x0, y0, h, nx, ny):
    """Triangles (visited in ``order``) into every cell their xy box overlaps: (entries, each
    entry's triangle box (top, bottom, x, y ranges) and first cell column and row, cell starts,
    each cell's highest top, each cell's lowest bottom, how far the cell's triangles reach beyond
    its square)."""
    T = order.shape[0]
    ncell = nx * ny
    start = np.zeros(ncell + 1, np.int64)
    cx0 = np.empty(T, np.int64)
    cx1 = np.empty(T, np.int64)
    cy0 = np.empty(T, np.int64)
    cy1 = np.empty(T, np.int64)
    for t in range(T):
        cx0[t] = min(max(int(math.floor((tab[t, _XLO] - x0) / h)), 0), nx - 1)
        cx1[t] = min(max(int(math.floor((tab[t, _XHI] - x0) / h)), 0), nx - 1)
        cy0[t] = min(max(int(math.floor((tab[t, _YLO] - y0) / h)), 0), ny - 1)
        cy1[t] = min(max(int(math.floor((tab[t, _YHI] - y0) / h)), 0), ny - 1)
        for ix in range(cx0[t], cx1[t] + 1):
            for iy in range(cy0[t], cy1[t] + 1):
                start[ix * ny + iy + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    ent = np.empty(start[ncell], np.int32)
    ebox = np.empty((start[ncell], 6))
    ecell = np.empty((start[ncell], 2), np.int32)
    cmax = np.full(ncell, -np.inf)
    cmin = np.full(ncell, np.inf)
    reach = np.zeros(ncell)
    for r in range(T):
        t = order[r]
        for ix in range(cx0[t], cx1[t] + 1):
            for iy in range(cy0[t], cy1[t] + 1):
                c = ix * ny + iy
                f = fill[c]
                ent[f] = t
                ebox[f, _EZHI] = tab[t, _ZHI]
                ebox[f, _EZLO] = tab[t, _ZLO]
                ebox[f, _EXLO] = tab[t, _XLO]
                ebox[f, _EXHI] = tab[t, _XHI]
                ebox[f, _EYLO] = tab[t, _YLO]
                ebox[f, _EYHI] = tab[t, _YHI]
                ecell[f, 0] = cx0[t]
                ecell[f, 1] = cy0[t]
                fill[c] = f + 1
                cmax[c] = max(cmax[c], tab[t, _ZHI])
                cmin[c] = min(cmin[c], tab[t, _ZLO])
                ox = max(x0 + ix * h - tab[t, _XLO], tab[t, _XHI] - (x0 + (ix + 1) * h))
                oy = max(y0 + iy * h - tab[t, _YLO], tab[t, _YHI] - (y0 + (iy + 1) * h))
                reach[c] = max(reach[c], ox, oy)
    return ent, ebox, ecell, start, cmax, cmin, reach


# ------------------------------------------------------------------------------------ clearance

@njit(cache=True, nogil=True, inline="always")
def _clamp01(v):
    return min(max(v, 0.0), 1.0)


@njit(cache=True, nogil=True)
def _pt_tri_d2(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Squared distance from p to the triangle abc (Ericson, Real-Time Collision Detection 5.1.5;
    degenerate triangles fall to their edges)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        qx, qy, qz = apx - v * abx, apy - v * aby, apz - v * abz
        return qx * qx + qy * qy + qz * qz
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cpx * cpx + cpy * cpy + cpz * cpz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        qx, qy, qz = apx - w * acx, apy - w * acy, apz - w * acz
        return qx * qx + qy * qy + qz * qz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        qx, qy, qz = bpx - w * (cx - bx), bpy - w * (cy - by), bpz - w * (cz - bz)
        return qx * qx + qy * qy + qz * qz
    den = va + vb + vc
    if den == 0.0:                      # degenerate triangle: its edges
        return min(_seg_seg_d2(px, py, pz, px, py, pz, ax, ay, az, bx, by, bz),
                   _seg_seg_d2(px, py, pz, px, py, pz, ax, ay, az, cx, cy, cz),
                   _seg_seg_d2(px, py, pz, px, py, pz, bx, by, bz, cx, cy, cz))
    v = vb / den
    w = vc / den
    qx = apx - abx * v - acx * w
    qy = apy - aby * v - acy * w
    qz = apz - abz * v - acz * w
    return qx * qx + qy * qy + qz * qz


@njit(cache=True, nogil=True)
def _seg_seg_d2(p1x, p1y, p1z, q1x, q1y, q1z, p2x, p2y, p2z, q2x, q2y, q2z):
    """Squared distance between the segments p1 q1 and p2 q2 (Ericson 5.1.9, degenerate segments
    included)."""
    d1x, d1y, d1z = q1x - p1x, q1y - p1y, q1z - p1z
    d2x, d2y, d2z = q2x - p2x, q2y - p2y, q2z - p2z
    rx, ry, rz = p1x - p2x, p1y - p2y, p1z - p2z
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    if a == 0.0 and e == 0.0:
        return rx * rx + ry * ry + rz * rz
    if a == 0.0:
        s = 0.0
        t = _clamp01(f / e)
    else:
        c = d1x * rx + d1y * ry + d1z * rz
        if e == 0.0:
            t = 0.0
            s = _clamp01(-c / a)
        else:
            b = d1x * d2x + d1y * d2y + d1z * d2z
            den = a * e - b * b
            s = _clamp01((b * f - c * e) / den) if den > 0.0 else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = _clamp01(-c / a)
            elif t > 1.0:
                t = 1.0
                s = _clamp01((b - c) / a)
    ux = p1x + d1x * s - (p2x + d2x * t)
    uy = p1y + d1y * s - (p2y + d2y * t)
    uz = p1z + d1z * s - (p2z + d2z * t)
    return ux * ux + uy * uy + uz * uz


@njit(cache=True, nogil=True)
def _crosses(sx, sy, sz, ex, ey, ez, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Whether the segment s e meets the triangle abc away from its plane-parallel cases (a
    segment lying in the plane is caught by the edge and end-point distances)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    nx = aby * acz - abz * acy
    ny = abz * acx - abx * acz
    nz = abx * acy - aby * acx
    da = nx * (sx - ax) + ny * (sy - ay) + nz * (sz - az)
    db = nx * (ex - ax) + ny * (ey - ay) + nz * (ez - az)
    if (da > 0.0 and db > 0.0) or (da < 0.0 and db < 0.0) or da == db:
        return False
    u = da / (da - db)
    px = sx + u * (ex - sx)
    py = sy + u * (ey - sy)
    pz = sz + u * (ez - sz)
    # p on the same side of each edge as the triangle (n . (edge x (p - edge start)) >= 0)
    w0 = nx * (aby * (pz - az) - abz * (py - ay)) + ny * (abz * (px - ax) - abx * (pz - az)) \
        + nz * (abx * (py - ay) - aby * (px - ax))
    bcx, bcy, bcz = cx - bx, cy - by, cz - bz
    w1 = nx * (bcy * (pz - bz) - bcz * (py - by)) + ny * (bcz * (px - bx) - bcx * (pz - bz)) \
        + nz * (bcx * (py - by) - bcy * (px - bx))
    cax, cay, caz = ax - cx, ay - cy, az - cz
    w2 = nx * (cay * (pz - cz) - caz * (py - cy)) + ny * (caz * (px - cx) - cax * (pz - cz)) \
        + nz * (cax * (py - cy) - cay * (px - cx))
    return w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0


@njit(cache=True, nogil=True)
def _seg_tri_d2(sx, sy, sz, ex, ey, ez, tab, t):
    """Squared distance from the segment s e to triangle ``t`` of the table."""
    ax, ay, az = tab[t, 0], tab[t, 1], tab[t, 2]
    bx, by, bz = tab[t, 3], tab[t, 4], tab[t, 5]
    cx, cy, cz = tab[t, 6], tab[t, 7], tab[t, 8]
    if _crosses(sx, sy, sz, ex, ey, ez, ax, ay, az, bx, by, bz, cx, cy, cz):
        return 0.0
    d = _pt_tri_d2(sx, sy, sz, ax, ay, az, bx, by, bz, cx, cy, cz)
    d = min(d, _pt_tri_d2(ex, ey, ez, ax, ay, az, bx, by, bz, cx, cy, cz))
    d = min(d, _seg_seg_d2(sx, sy, sz, ex, ey, ez, ax, ay, az, bx, by, bz))
    d = min(d, _seg_seg_d2(sx, sy, sz, ex, ey, ez, ax, ay, az, cx, cy, cz))
    d = min(d, _seg_seg_d2(sx, sy, sz, ex, ey, ez, bx, by, bz, cx, cy, cz))
    return d


@njit(cache=True, nogil=True)
def _move_min(sx, sy, sz, ex, ey, ez, tab, ent, ebox, ecell, start, cmin, cmax, reach, x0, y0, h, nx, ny,
              widen, slack, cap):
    """min(cap, distance from the segment s e to the nearest triangle); the cells read are those
    the segment's xy box grown by ``widen`` (>= cap, or the whole grid) overlaps."""
    best = cap
    lox, hix = min(sx, ex), max(sx, ex)
    loy, hiy = min(sy, ey), max(sy, ey)
    loz, hiz = min(sz, ez), max(sz, ez)
    if math.isinf(widen):
        qx0, qx1, qy0, qy1 = 0, nx - 1, 0, ny - 1
    else:
        qx0 = min(max(int(math.floor((lox - widen - x0) / h)), 0), nx - 1)
        qx1 = min(max(int(math.floor((hix + widen - x0) / h)), 0), nx - 1)
        qy0 = min(max(int(math.floor((loy - widen - y0) / h)), 0), ny - 1)
        qy1 = min(max(int(math.floor((hiy + widen - y0) / h)), 0), ny - 1)
    b2 = best * best
    for ix in range(qx0, qx1 + 1):
        for iy in range(qy0, qy1 + 1):
            c = ix * ny + iy
            if start[c] == start[c + 1]:
                continue
            # the cell's triangles lie in its square grown by its reach, between its z bounds
            gx = _gap(x0 + ix * h - reach[c], x0 + (ix + 1) * h + reach[c], lox, hix)
            gy = _gap(y0 + iy * h - reach[c], y0 + (iy + 1) * h + reach[c], loy, hiy)
            gz = _gap(cmin[c], cmax[c], loz, hiz)
            bs = best + slack
            if gx * gx + gy * gy + gz * gz >= bs * bs:
                continue
            for e in range(start[c], start[c + 1]):
                # each triangle once: in the first cell its cells share with the move's
                if ix != max(ecell[e, 0], qx0) or iy != max(ecell[e, 1], qy0):
                    continue
                gx = _gap(ebox[e, _EXLO], ebox[e, _EXHI], lox, hix)
                gy = _gap(ebox[e, _EYLO], ebox[e, _EYHI], loy, hiy)
                gz = _gap(ebox[e, _EZLO], ebox[e, _EZHI], loz, hiz)
                bs = best + slack
                if gx * gx + gy * gy + gz * gz >= bs * bs:
                    continue
                d2 = _seg_tri_d2(sx, sy, sz, ex, ey, ez, tab, ent[e])
                if d2 < b2:
                    b2 = d2
                    best = math.sqrt(d2)
                    if d2 == 0.0:
                        return 0.0
    return best


@njit(parallel=True, cache=True)
def _clearance(S, E, tab, ent, ebox, ecell, start, cmin, cmax, reach, x0, y0, h, nx, ny, widen, slack, cap, out):
    for k in prange(S.shape[0]):
        out[k] = _move_min(S[k, 0], S[k, 1], S[k, 2], E[k, 0], E[k, 1], E[k, 2], tab, ent, ebox, ecell, start,
                           cmin, cmax, reach, x0, y0, h, nx, ny, widen, slack, cap)


#: Fewer lines (moves) than this run on one thread (starting the thread pool costs more).
_PARALLEL_MIN = 2048
_drop_serial = serial_twin(_drop, "_drop_serial")
_clearance_serial = serial_twin(_clearance, "_clearance_serial")


# ------------------------------------------------------------------------------------ public API

class TriangleDropSurface:
    """The mesh ``vertices`` (V,3, mm) / ``faces`` (T,3) in a frame with the tool axis +Z, binned
    once for a ball-end cutter of radius ``radius_mm``: :meth:`drop` (ball-centre heights on
    vertical lines, the interface of :class:`planning.toolpath.balldrop.DropSurface`) and
    :meth:`clearance` (distance from straight ball-centre moves to the triangles) as often as
    needed. ``cell_mm`` sets the raster cell and changes speed and memory only (each triangle is
    listed in every cell its xy box overlaps); the default is R/3, or the median triangle's xy
    extent where that is larger (at most R), coarser where the raster would pass ~4M cells or ~16
    entries per triangle. The contact indices refer to the rows of ``faces``."""

    def __init__(self, vertices, faces, radius_mm, *, cell_mm: float | None = None):
        R = _check_radius(radius_mm)
        tab = triangle_table(vertices, faces)
        #: (T,3) int64, the faces as given: ``contact`` indexes its rows
        self.faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if cell_mm is not None and not (float(cell_mm) > 0 and math.isfinite(float(cell_mm))):
            raise ParameterError(f"cell_mm = {cell_mm}: must be > 0")
        self.R = R
        self.n = tab.shape[0]
        if self.n == 0:
            return
        if self.n >= 2 ** 31:
            raise ParameterError(f"{self.n} triangles: at most 2**31 - 1")
        w = np.maximum(tab[:, _XHI] - tab[:, _XLO], tab[:, _YHI] - tab[:, _YLO])
        h = min(max(R / 3.0, float(np.median(w))), R) if cell_mm is None else float(cell_mm)
        lo = np.array([tab[:, _XLO].min(), tab[:, _YLO].min()])
        hi = np.array([tab[:, _XHI].max(), tab[:, _YHI].max()])
        h = max(h, float((hi - lo).max()) / 2000.0, 1e-9)     # at most ~4M cells
        while float(np.sum((w / h + 1.0) ** 2)) > 16.0 * self.n + 1e6:
            h *= 1.25                                          # big triangles against a small cell
        nx = -(-int((hi[0] - lo[0]) / h + 1) // _BLOCK) * _BLOCK
        ny = -(-int((hi[1] - lo[1]) / h + 1) // _BLOCK) * _BLOCK
        # the table in raster order (neighbours near in memory), then each cell's list highest first
        tab_r, perm = _raster_order(tab, lo[0], lo[1], h, nx, ny)
        order = np.argsort(-tab_r[:, _ZHI], kind="stable")
        ent, ebox, ecell, start, cmax, cmin, reach = _bin(tab_r, order, lo[0], lo[1], h, nx, ny)
        nbx, nby = nx // _BLOCK, ny // _BLOCK
        bmax = cmax.reshape(nbx, _BLOCK, nby, _BLOCK).max(axis=(1, 3)).ravel()
        self.cell_mm = h
        self._grid = (float(lo[0]), float(lo[1]), h, nx, ny)
        self._tables = (tab_r, perm)
        self._drop_arrays = (ent, ebox, start, cmax, bmax, nby)
        self._clear_arrays = (ent, ebox, ecell, start, cmin, cmax, reach)
        self.n_entries = int(ent.size)
        self._scale = float(np.abs(tab[:, :9]).max())

    def drop(self, xy) -> BallDrop:
        """Ball-centre heights (mm) on the vertical lines through ``xy`` (K,2) mm: ``z_mm`` (K,)
        (``-inf`` where no triangle is within R of the line) and ``contact`` (K,) the index of the
        face the ball rests on (-1 where none; equal heights: the lowest index). Module docstring."""
        xy = _check_xy(xy)
        z = np.full(xy.shape[0], -np.inf)
        idx = np.full(xy.shape[0], -1, dtype=np.int64)
        if xy.shape[0] == 0 or self.n == 0:
            return BallDrop(z, idx)
        slack = 1e-9 * max(self._scale, float(np.abs(xy).max()), 1.0)     # rounding of cell bounds, mm
        kernel = _drop if xy.shape[0] >= _PARALLEL_MIN else _drop_serial
        kernel(*self._tables, *self._drop_arrays, *self._grid, xy, self.R, slack, z, idx)
        return BallDrop(z, idx)

    def clearance(self, starts, ends, cap_mm: float | None = None) -> np.ndarray:
        """Per straight move ``starts[k] -> ends[k]`` ((K,3) each, mm): ``min(distance to the
        nearest triangle, cap_mm)`` (default cap R; ``inf`` for no cap, then every triangle may be
        measured). Exact segment-triangle distance (module docstring)."""
        S = np.ascontiguousarray(starts, dtype=np.float64)
        E = np.ascontiguousarray(ends, dtype=np.float64)
        if S.ndim != 2 or S.shape[1] != 3 or E.shape != S.shape:
            raise ParameterError("starts and ends must be (K,3) arrays of the same shape")
        if not (np.all(np.isfinite(S)) and np.all(np.isfinite(E))):
            raise ParameterError("starts and ends must be finite")
        cap = self.R if cap_mm is None else float(cap_mm)
        if not cap > 0:
            raise ParameterError(f"cap_mm = {cap_mm}: must be > 0 (inf for no cap)")
        out = np.full(S.shape[0], cap)
        if S.shape[0] == 0 or self.n == 0:
            return out
        x0, y0, h, nx, ny = self._grid
        slack = 1e-9 * max(self._scale, float(np.abs(S).max()), float(np.abs(E).max()), 1.0)
        widen = cap + slack                     # inf: every cell
        kernel = _clearance if S.shape[0] >= _PARALLEL_MIN else _clearance_serial
        kernel(S, E, self._tables[0], *self._clear_arrays, x0, y0, h, nx, ny, widen, slack, cap, out)
        return out


def triangle_drop(vertices, faces, xy, radius_mm, *, cell_mm: float | None = None) -> BallDrop:
    """Drop a ball-end cutter of radius ``radius_mm`` onto the mesh along the vertical lines through
    ``xy`` (K,2), mm, tool axis +Z (exact; module docstring). To drop many times on one mesh, build
    a :class:`TriangleDropSurface` once."""
    return TriangleDropSurface(vertices, faces, radius_mm, cell_mm=cell_mm).drop(xy)


def triangle_clearance(starts, ends, surface: TriangleDropSurface, cap_mm: float | None = None) -> np.ndarray:
    """(K,) ``min(distance from the segment starts[k] -> ends[k] to the nearest triangle of
    surface, cap_mm)``, mm (default cap: the surface's R). See :meth:`TriangleDropSurface.clearance`."""
    return surface.clearance(starts, ends, cap_mm)


# ------------------------------------------------------------------------------------ references

def _edge_z_np(p, q, x, y, R2):
    d = q - p
    Lh2 = d[:, 0] ** 2 + d[:, 1] ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        wx, wy = x - p[:, 0], y - p[:, 1]
        cr = wx * d[:, 1] - wy * d[:, 0]
        d2 = cr * cr / Lh2
        rp = np.sqrt(np.maximum(R2 - d2, 0.0))
        Lh = np.sqrt(Lh2)
        L = np.sqrt(Lh2 + d[:, 2] ** 2)
        t = (wx * d[:, 0] + wy * d[:, 1]) / Lh2 + rp * d[:, 2] / (L * Lh)
        z = p[:, 2] + t * d[:, 2] + rp * (Lh / L)
    ok = (Lh2 > 0) & (d2 <= R2) & (t >= 0) & (t <= 1)
    return np.where(ok, z, -np.inf)


def brute_force_triangle_drop(vertices, faces, xy, radius_mm) -> BallDrop:
    """Reference for :meth:`TriangleDropSurface.drop`: every line against every triangle, numpy
    (small inputs only)."""
    R = _check_radius(radius_mm)
    tab = triangle_table(vertices, faces)
    xy = _check_xy(xy)
    R2 = R * R
    A, B, C = tab[:, 0:3], tab[:, 3:6], tab[:, 6:9]
    n = tab[:, _N:_N + 3]
    ar = tab[:, _AR]
    z = np.full(xy.shape[0], -np.inf)
    idx = np.full(xy.shape[0], -1, dtype=np.int64)
    if tab.shape[0] == 0:
        return BallDrop(z, idx)
    for k in range(xy.shape[0]):
        x, y = xy[k]
        cand = [np.where((P[:, 0] - x) ** 2 + (P[:, 1] - y) ** 2 <= R2,
                         P[:, 2] + np.sqrt(np.maximum(R2 - (P[:, 0] - x) ** 2 - (P[:, 1] - y) ** 2, 0.0)), -np.inf)
                for P in (A, B, C)]
        cand += [_edge_z_np(A, B, x, y, R2), _edge_z_np(A, C, x, y, R2), _edge_z_np(B, C, x, y, R2)]
        px, py = x - R * n[:, 0], y - R * n[:, 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            la = ((B[:, 0] - px) * (C[:, 1] - py) - (B[:, 1] - py) * (C[:, 0] - px)) / ar
            lb = ((C[:, 0] - px) * (A[:, 1] - py) - (C[:, 1] - py) * (A[:, 0] - px)) / ar
            lc = ((A[:, 0] - px) * (B[:, 1] - py) - (A[:, 1] - py) * (B[:, 0] - px)) / ar
            zf = (la * A[:, 2] + lb * B[:, 2] + lc * C[:, 2]) / (la + lb + lc) + R * n[:, 2]
        ok = (n[:, 2] > 0) & (ar != 0) & (la >= 0) & (lb >= 0) & (lc >= 0)
        cand.append(np.where(ok, zf, -np.inf))
        h = np.max(np.stack(cand), axis=0)
        j = int(np.argmax(h))
        if h[j] > -np.inf:
            z[k], idx[k] = h[j], j
    return BallDrop(z, idx)


__all__ = ["TriangleDropSurface", "brute_force_triangle_drop", "triangle_clearance", "triangle_drop",
           "triangle_table"]
