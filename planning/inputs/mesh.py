"""Stage 1, the cloud: what the mesh readers share (STL, OBJ, PLY faces, E57 grids, image reliefs).

:func:`_merge_vertices` merges exactly equal vertex rows (``-0.0`` equals ``0.0``) by a lexicographic
sort of their bit patterns, so an STL's facets index shared vertices; :func:`_fan_triangles` turns
polygons given as one concatenated index array and a size per polygon into triangles
``(first, j, j + 1)`` (the triangle count checked against ``max_faces`` before they are built);
:func:`_grid_triangles` triangulates a grid of points (two triangles per cell whose four corners
exist); :func:`_duplicate_faces` finds the triangles that repeat an earlier one's three vertices. All
vectorised: no Python loop per vertex or per face.
"""

from __future__ import annotations

import numpy as np

from planning.errors import InputError
from planning.inputs.source import _check_faces


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


def _fan_triangles(indices: np.ndarray, sizes: np.ndarray, max_faces: int | None = None,
                   what: str = "The mesh has", owned: bool = False) -> np.ndarray:
    """Fan-triangulate polygons: ``indices`` concatenated, ``sizes`` (P,) each >= 3 -> ``(T, 3)`` int64.

    Polygon ``v0 v1 ... vn-1`` gives ``(v0, vj, vj+1)`` for ``j = 1 .. n-2`` (exact for convex
    polygons, which is what scanners and exporters write). With ``max_faces``, more triangles than that
    raise :class:`~planning.errors.InputTooLarge` ``too_many_faces`` before any is built (``what``
    starts its message). ``owned``: the caller gives ``indices`` away (triangles may be a view of it).
    """
    given = None if owned else indices
    indices = np.asarray(indices, dtype=np.int64).reshape(-1)
    sizes = np.asarray(sizes, dtype=np.int64).reshape(-1)
    if sizes.size == 0:
        return np.zeros((0, 3), dtype=np.int64)
    if max_faces is not None:
        _check_faces(int(sizes.sum()) - 2 * sizes.size, max_faces, what)
    if np.all(sizes == 3):
        tri = indices.reshape(-1, 3)
        return tri.copy() if given is not None and np.shares_memory(tri, given) else tri
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
    if width * (int(row.max() - r0) + 2) >= 2 ** 62:    # damaged indices: the keys would overflow
        return np.zeros((0, 3), dtype=np.int64)
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


def _duplicate_faces(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """``(T,)`` bool: the triangles of ``faces`` ``(T, 3)`` (indices in ``[0, n_vertices)``) whose three
    vertices, in any order or winding, are those of an earlier triangle.

    Each triangle's indices sorted give a key (one int64 ``(a V + b) V + c`` while ``V^3`` fits, else
    the pair ``a V + b``, ``c``); a stable sort of the keys puts every triangle after the earlier ones
    equal to it. About 50 bytes per triangle at the peak.
    """
    tri = np.asarray(faces, dtype=np.int64)
    out = np.zeros(tri.shape[0], dtype=bool)
    if tri.shape[0] < 2:
        return out
    v = max(int(n_vertices), 1)
    a = np.minimum(np.minimum(tri[:, 0], tri[:, 1]), tri[:, 2])
    c = np.maximum(np.maximum(tri[:, 0], tri[:, 1]), tri[:, 2])
    b = tri.sum(axis=1)
    b -= a
    b -= c
    if v <= 2_000_000:                                   # V^3 < 2^63
        key = a
        key *= v
        key += b
        key *= v
        key += c
        del b, c
        order = np.argsort(key, kind="stable")
        k = key[order]
        same = k[1:] == k[:-1]
    else:
        high = a
        high *= v
        high += b
        del b
        order = np.lexsort((np.arange(tri.shape[0]), c, high))
        h, low = high[order], c[order]
        same = (h[1:] == h[:-1]) & (low[1:] == low[:-1])
    out[order[1:][same]] = True
    return out
