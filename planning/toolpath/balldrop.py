"""Point-based ball drop (Sood et al., point-based tool paths; Makki 2010 §4 machines each area with
3-axis paths at its fixed orientation): the height of a ball-end cutter dropped onto a point cloud.

Everything is in a frame whose +Z is the tool axis (the per-area frame). A ball of radius ``R``
whose centre is on the vertical line through ``(x, y)`` rests on the cloud at centre height

    z_c(x, y) = max over points q with rho^2 = (q_x - x)^2 + (q_y - y)^2 <= R^2 of  q_z + sqrt(R^2 - rho^2)

(the lowest centre at which no point lies strictly inside the ball). ``-inf`` where no point lies
within ``R`` of the line: nothing is under the ball there.

:func:`ball_drop` computes it exactly (the same expression as :func:`brute_force_ball_drop`, the
O(K N) reference): the points are binned on a square raster with each cell's highest z; for each
query line the cells within R are visited, a cell is skipped when its highest point plus R cannot
beat the best height found so far (its highest z plus the ball's height at the cell's nearest
edge; first for blocks of 4 x 4 cells, then per cell), and the others are scanned point by point. Compiled with numba,
parallel over the query lines.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from planning.errors import ParameterError
from planning.geometry.kernels import BallDrop, serial_twin
from planning.geometry.raster import bin_cells, rows_in_order

_BLOCK = 4      # raster cells per side of the blocks pruned as a whole


def _check(points, xy, radius_mm):
    points = np.ascontiguousarray(points, dtype=np.float64)
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ParameterError("points must be an (N,3) array")
    if xy.ndim != 2 or xy.shape[1] != 2:
        raise ParameterError("xy must be a (K,2) array")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(xy))):
        raise ParameterError("points and xy must be finite")
    R = float(radius_mm)
    if not R > 0:
        raise ParameterError(f"radius_mm = {radius_mm}: must be > 0")
    return points, xy, R


def brute_force_ball_drop(points, xy, radius_mm) -> BallDrop:
    """Reference for :func:`ball_drop`: every line against every point (small inputs only)."""
    points, xy, R = _check(points, xy, radius_mm)
    z = np.full(xy.shape[0], -np.inf)
    idx = np.full(xy.shape[0], -1, dtype=np.int64)
    R2 = R * R
    for k in range(xy.shape[0]):
        ex = points[:, 0] - xy[k, 0]
        ey = points[:, 1] - xy[k, 1]
        rho2 = ex * ex + ey * ey
        ok = rho2 <= R2
        if ok.any():
            h = np.where(ok, points[:, 2] + np.sqrt(np.maximum(R2 - rho2, 0.0)), -np.inf)
            j = int(np.argmax(h))
            z[k], idx[k] = h[j], j
    return BallDrop(z, idx)


@njit(cache=True)
def _gap(v, a, w):
    """Distance from v to the interval [a, a + w] (0 inside)."""
    if v < a:
        return a - v
    if v > a + w:
        return v - (a + w)
    return 0.0


@njit(parallel=True, cache=True)
def _drop(pts, order, start, cmax, bmax, nby, xy, R, x0, y0, h, nx, ny, slack, z_out, idx_out):
    R2 = R * R
    rr = R * (1.0 + 1e-12) + 1e-12          # reach, a hair wide: the point test decides
    hb = _BLOCK * h
    nbx = (nx + _BLOCK - 1) // _BLOCK
    for k in prange(xy.shape[0]):
        x, y = xy[k, 0], xy[k, 1]
        best = -np.inf
        bi = -1
        bxc = int(math.floor((x - x0) / hb))
        bx0 = max(int(math.floor((x - rr - x0) / hb)), 0)
        bx1 = min(int(math.floor((x + rr - x0) / hb)), nbx - 1)
        span = max(bxc - bx0, bx1 - bxc)
        # block rows from the line's own outwards: a high point nearby prunes more early
        for off in range(span + 1):
            for sgn in (1, -1):
                if off == 0 and sgn == -1:
                    continue
                bx = bxc + sgn * off
                if bx < bx0 or bx > bx1:
                    continue
                gbx = _gap(x, x0 + bx * hb, hb)
                if gbx > rr:
                    continue
                bhalf = math.sqrt(rr * rr - gbx * gbx)
                by0 = max(int(math.floor((y - bhalf - y0) / hb)), 0)
                by1 = min(int(math.floor((y + bhalf - y0) / hb)), nby - 1)
                for by in range(by0, by1 + 1):
                    # no point of a block is nearer the line than the block's edge, so none
                    # rises above its highest z + sqrt(R^2 - g^2) (g shrunk and the sum widened
                    # by rounding margins; ties are still scanned). The same for each cell.
                    zb = bmax[bx * nby + by]
                    if zb + R < best:
                        continue
                    gx_ = max(gbx - slack, 0.0)
                    gy_ = max(_gap(y, y0 + by * hb, hb) - slack, 0.0)
                    g2 = gx_ * gx_ + gy_ * gy_
                    if g2 < R2 and zb + math.sqrt(R2 - g2) + 1e-9 * R < best:
                        continue
                    for ix in range(bx * _BLOCK, min((bx + 1) * _BLOCK, nx)):
                        gx = _gap(x, x0 + ix * h, h)
                        if gx > rr:
                            continue
                        half = math.sqrt(rr * rr - gx * gx)
                        iy0 = max(int(math.floor((y - half - y0) / h)), by * _BLOCK)
                        iy1 = min(int(math.floor((y + half - y0) / h)), (by + 1) * _BLOCK - 1, ny - 1)
                        base = ix * ny
                        for iy in range(iy0, iy1 + 1):
                            cc = base + iy
                            if cmax[cc] + R < best:
                                continue
                            ex_ = max(gx - slack, 0.0)
                            ey_ = max(_gap(y, y0 + iy * h, h) - slack, 0.0)
                            g2 = ex_ * ex_ + ey_ * ey_
                            if g2 < R2 and cmax[cc] + math.sqrt(R2 - g2) + 1e-9 * R < best:
                                continue
                            for s in range(start[cc], start[cc + 1]):
                                ex = pts[s, 0] - x
                                ey = pts[s, 1] - y
                                rho2 = ex * ex + ey * ey
                                if rho2 <= R2:
                                    zc = pts[s, 2] + math.sqrt(max(R2 - rho2, 0.0))
                                    if zc > best or (zc == best and order[s] < bi):
                                        best = zc
                                        bi = order[s]
        z_out[k] = best
        idx_out[k] = bi


#: Fewer query lines than this run on one thread (starting the thread pool costs more).
_PARALLEL_MIN = 2048
_drop_serial = serial_twin(_drop, "_drop_serial")   # its own cache entry (see serial_twin)


class DropSurface:
    """The cloud ``points`` (N,3, mm, tool axis +Z) binned once for ball drops of radius
    ``radius_mm``: call :meth:`drop` as often as needed (the raster is built here only).
    ``cell_mm`` (default R/10) sets the raster cell and changes speed only. With ``triangles`` (a
    :class:`planning.geometry.triangles.TriangleDropSurface` whose ``faces`` index ``points``) the
    ball rests on the points and the triangles through them: the higher of the two drops
    (:mod:`planning.toolpath.surface`)."""

    def __init__(self, points, radius_mm, *, cell_mm: float | None = None, triangles=None):
        points, _, R = _check(points, np.zeros((0, 2)), radius_mm)
        self.triangles = triangles
        self._xy = None if triangles is None else points[:, :2].copy()
        h = R / 10.0 if cell_mm is None else float(cell_mm)
        if not h > 0:
            raise ParameterError("cell_mm must be > 0")
        self.R = R
        self.n = points.shape[0]
        if self.n == 0:
            return
        lo = points[:, :2].min(axis=0) - R
        hi = points[:, :2].max(axis=0) + R
        h = max(h, float((hi - lo).max()) / 4000.0)           # at most ~16M cells
        nx = int((hi[0] - lo[0]) / h) + 2
        ny = int((hi[1] - lo[1]) / h) + 2
        order, rank, start, cmax, _ = bin_cells(points[:, 0], points[:, 1], points[:, 2], lo[0], lo[1], h, nx, ny)
        # highest point of each block of _BLOCK x _BLOCK cells (padded with empty cells)
        nbx, nby = -(-nx // _BLOCK), -(-ny // _BLOCK)
        grid = np.full((nbx * _BLOCK, nby * _BLOCK), -np.inf)
        grid[:nx, :ny] = cmax.reshape(nx, ny)
        self._raster = (rows_in_order(points, rank), order, start, cmax,
                        grid.reshape(nbx, _BLOCK, nby, _BLOCK).max(axis=(1, 3)).ravel(), nby)
        self._grid = (lo[0], lo[1], h, nx, ny)
        self._scale = float(np.abs(points).max())

    def drop(self, xy) -> BallDrop:
        """Ball-centre heights on the vertical lines through ``xy`` (K,2) mm (module docstring)."""
        _, xy, _ = _check(np.zeros((0, 3)), xy, self.R)
        z = np.full(xy.shape[0], -np.inf)
        idx = np.full(xy.shape[0], -1, dtype=np.int64)
        if xy.shape[0] == 0 or self.n == 0:
            return BallDrop(z, idx)
        # rounding of the cell bounds, mm
        slack = 1e-9 * max(self._scale, float(np.abs(xy).max()), 1.0)
        kernel = _drop if xy.shape[0] >= _PARALLEL_MIN else _drop_serial
        kernel(*self._raster, xy, self.R, *self._grid, slack, z, idx)
        if self.triangles is not None:
            self._on_triangles(xy, z, idx)
        return BallDrop(z, idx)

    def _on_triangles(self, xy, z, idx) -> None:
        """Raise ``z`` to the drop on the triangles where that is higher (their vertices are points, so it
        never is lower); the contact there is the triangle's vertex nearest the line (a point index, as
        every contact of this class)."""
        t = self.triangles.drop(xy)
        up = np.flatnonzero(t.z_mm > z)
        if up.size == 0:
            return
        f = self.triangles.faces[t.contact[up]]                          # (u,3) point indices
        d2 = ((self._xy[f] - xy[up, None, :]) ** 2).sum(axis=2)
        z[up] = t.z_mm[up]
        idx[up] = f[np.arange(up.size), np.argmin(d2, axis=1)]


def ball_drop(points, xy, radius_mm, *, cell_mm: float | None = None) -> BallDrop:
    """Drop a ball-end cutter of radius ``radius_mm`` onto ``points`` (N,3), mm, frame with the tool
    axis along +Z, along the vertical lines through ``xy`` (K,2): the ball-centre height of each
    (Sood's point-based ball drop; exact, see the module docstring). ``cell_mm`` (default R/10)
    sets the raster cell and changes speed only. Ties go to the lowest point index. To drop many
    times on one cloud, build a :class:`DropSurface` once.
    """
    return DropSurface(points, radius_mm, cell_mm=cell_mm).drop(xy)
