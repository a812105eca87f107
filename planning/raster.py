"""Square-cell raster of projected points, shared by the collision test and the ball drop.

:func:`bin_cells` is a counting sort (O(N)) of points by the cell ``(floor((x - x0) / h),
floor((y - y0) / h))`` of an ``nx`` x ``ny`` grid (indices clipped into the grid), cell index
``ix * ny + iy``. It returns the point order, every cell's run ``start[c]:start[c + 1]`` in that
order, and every cell's highest and lowest ``z`` (-inf / +inf when empty). :func:`take_rows`
gathers rows in that order into a contiguous array (contiguous reads in the scanning kernels).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def bin_cells(x, y, z, x0, y0, h, nx, ny):
    """Counting sort of points (x, y, z) into square cells of side ``h``: (order, start, cmax, cmin)."""
    n = x.shape[0]
    ncell = nx * ny
    cell = np.empty(n, np.int64)
    start = np.zeros(ncell + 1, np.int64)
    cmax = np.full(ncell, -np.inf)
    cmin = np.full(ncell, np.inf)
    for i in range(n):
        ix = min(max(int(math.floor((x[i] - x0) / h)), 0), nx - 1)
        iy = min(max(int(math.floor((y[i] - y0) / h)), 0), ny - 1)
        c = ix * ny + iy
        cell[i] = c
        start[c + 1] += 1
        if z[i] > cmax[c]:
            cmax[c] = z[i]
        if z[i] < cmin[c]:
            cmin[c] = z[i]
    for c in range(ncell):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        c = cell[i]
        order[fill[c]] = i
        fill[c] += 1
    return order, start, cmax, cmin


@njit(cache=True, nogil=True)
def take_rows(a, order):
    """``a[order]`` for a 2-D array, as a new C-contiguous array."""
    out = np.empty((order.shape[0], a.shape[1]))
    for s in range(order.shape[0]):
        q = order[s]
        for j in range(a.shape[1]):
            out[s, j] = a[q, j]
    return out
