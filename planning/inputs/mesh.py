"""Stage 1, the cloud: what the mesh readers share (STL, OBJ, PLY faces, E57 grids, image reliefs).

:func:`_merge_vertices` merges exactly equal vertex rows (``-0.0`` equals ``0.0``) by a lexicographic
sort of their bit patterns, so an STL's facets index shared vertices; :func:`_fan_triangles` turns
polygons given as one concatenated index array and a size per polygon into triangles
``(first, j, j + 1)``; :func:`_grid_triangles` triangulates a grid of points (two triangles per cell
whose four corners exist). All vectorised: no Python loop per vertex or per face.
"""

from __future__ import annotations

import numpy as np

from planning.errors import InputError


def _merge_vertices(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique rows of ``raw`` ``(M, 3)`` (float32 or float64) -> (``(V, 3)`` float64, ``(M,)`` int64).

    Rows are equal when their coordinates are equal as numbers (``-0.0`` and ``0.0`` merge; NaN rows
    merge only with identical bit patterns and are rejected later by the validation). ``unique[inverse]``
    equals ``raw``; the unique rows come in lexicographic order of their bit patterns.
    """
    raw = np.ascontiguousarray(raw)
    if raw.shape[0] == 0:
        return np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    zero = raw.dtype.type(0)
    clean = np.ascontiguousarray(raw + zero)            # -0.0 + 0.0 = +0.0: one bit pattern for zero
    if clean.dtype == np.float32:
        bits = clean.view(np.uint32).astype(np.uint64)
        keys = (bits[:, 2], (bits[:, 0] << np.uint64(32)) | bits[:, 1])
    else:
        clean = clean.astype(np.float64, copy=False)
        bits = clean.view(np.uint64)
        keys = (bits[:, 2], bits[:, 1], bits[:, 0])
    order = np.lexsort(keys)
    same = np.ones(order.size - 1, dtype=bool)          # row equal to the one before it in sorted order
    for key in keys:
        k = key[order]
        same &= k[1:] == k[:-1]
    first = np.concatenate(([True], ~same))
    inverse = np.empty(order.size, dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    return clean[order[first]].astype(np.float64), inverse


def _fan_triangles(indices: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons: ``indices`` concatenated, ``sizes`` (P,) each >= 3 -> ``(T, 3)`` int64.

    Polygon ``v0 v1 ... vn-1`` gives ``(v0, vj, vj+1)`` for ``j = 1 .. n-2`` (exact for convex
    polygons, which is what scanners and exporters write).
    """
    indices = np.asarray(indices, dtype=np.int64).reshape(-1)
    sizes = np.asarray(sizes, dtype=np.int64).reshape(-1)
    if sizes.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if np.all(sizes == 3):
        return indices.reshape(-1, 3).copy()
    starts = np.cumsum(sizes) - sizes
    n_tri = sizes - 2
    poly = np.repeat(np.arange(sizes.size), n_tri)
    first_tri = np.cumsum(n_tri) - n_tri
    j = np.arange(poly.size) - first_tri[poly] + 1
    base = starts[poly]
    return np.column_stack((indices[base], indices[base + j], indices[base + j + 1]))


def _check_polygon_sizes(sizes: np.ndarray, what: str) -> None:
    small = np.flatnonzero(np.asarray(sizes) < 3)
    if small.size:
        raise InputError(f"Cannot read the {what}: face {int(small[0]) + 1} has "
                         f"{int(sizes[small[0]])} vertex index(es); a face needs at least 3.",
                         code="unreadable_file")


def _grid_triangles(row: np.ndarray, col: np.ndarray, points: np.ndarray,
                    jump_factor: float) -> np.ndarray:
    """Triangles of a structured scan: point ``i`` sits at grid cell ``(row[i], col[i])``.

    Every 2x2 block of grid positions whose four points exist gives two triangles (split along the
    diagonal from ``(r, c)`` to ``(r+1, c+1)``), unless one of its four sides is longer than
    ``jump_factor`` times the median length of all grid edges (a depth jump: the points belong to
    different surfaces). Positions held twice keep their first point. Returns ``(T, 3)`` int64.
    """
    row = np.asarray(row, dtype=np.int64)
    col = np.asarray(col, dtype=np.int64)
    if row.size < 4:
        return np.zeros((0, 3), dtype=np.int64)
    r0, c0 = row.min(), col.min()
    width = int(col.max() - c0) + 2
    key = (row - r0) * width + (col - c0)
    keys, first = np.unique(key, return_index=True)       # sorted keys, first point at each

    def at(k: np.ndarray) -> np.ndarray:
        pos = np.clip(np.searchsorted(keys, k), 0, keys.size - 1)
        return np.where(keys[pos] == k, first[pos], -1)

    a = first
    b, c, d = at(keys + 1), at(keys + width), at(keys + width + 1)     # right, below, diagonal

    def length(i, j):
        ok = (i >= 0) & (j >= 0)
        out = np.full(i.size, np.nan)
        out[ok] = np.linalg.norm(points[i[ok]] - points[j[ok]], axis=1)
        return out

    ab, ac, bd, cd = length(a, b), length(a, c), length(b, d), length(c, d)
    edges = np.concatenate((ab, ac))
    edges = edges[np.isfinite(edges)]
    if edges.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    limit = jump_factor * float(np.median(edges))
    full = (b >= 0) & (c >= 0) & (d >= 0)
    with np.errstate(invalid="ignore"):
        longest = np.fmax(np.fmax(ab, ac), np.fmax(bd, cd))
        keep = full & (longest <= limit)
    a, b, c, d = a[keep], b[keep], c[keep], d[keep]
    tri = np.empty((2 * a.size, 3), dtype=np.int64)
    tri[0::2] = np.column_stack((a, b, d))
    tri[1::2] = np.column_stack((a, d, c))
    return tri
