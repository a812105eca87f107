"""Stage 1, the cloud: points on a mesh's facets, for the stages that work on points (issue 18).

Normals by sphere throwing, visibility, set-ups and areas all work on points; a mesh from CAD or a
decimated scan has few vertices on large triangles (a 100 mm cube exported as STL has 8). So a mesh's
points are its vertices followed by points laid on its edges and inside its facets no farther apart
than ``spacing_mm`` (Sood 2015 ch. 3 samples the facets the same way for point-based ball drop). The
triangles stay: the finishing ball rests on them (:mod:`planning.toolpath.surface`).

* each unique edge of length L gets ``ceil(L / s) - 1`` evenly spaced interior points;
* each facet whose longest edge is L gets the interior points of the barycentric lattice of
  ``n = ceil(L / s)`` subdivisions, ``(i/n, j/n, 1 - (i+j)/n)`` with ``i, j >= 1``, ``i + j <= n - 1``
  (so no point of the lattice is farther than s from another along either edge direction).

When that makes more than ``max_points`` points, ``s`` is widened by ``sqrt(count / max_points)``
(and again if still over) so the cap holds; the spacing used is returned. Vectorised: one numpy
pass per distinct subdivision count, none per facet or point. The unique edges are found from one
int64 key per edge, ``a V + b`` with ``a < b`` (a 1-D sort, in the order ``numpy.unique(axis=0)`` would
give), and the facets' longest sides are measured a million facets at a time, so counting the points
of a mesh (:func:`planned_point_count`) costs about 80 bytes per triangle at the peak (a 2048 x 2048
relief grid, 8.4 M triangles: 0.64 GB and 4-5 s on two cores, against 2.5 GB and 30-60 s with
``numpy.unique(axis=0)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FacetPoints:
    """``points`` (P,3) mm: the V vertices first, then edge points, then facet points. ``parents`` (P,2)
    int64: the facets a point lies on (edge points: the two facets of the edge, -1 where the edge has
    one; facet points: the facet and -1; vertices: -1, -1). ``spacing_mm`` the spacing used."""

    points: np.ndarray
    parents: np.ndarray
    spacing_mm: float
    n_vertices: int


_CHUNK = 1 << 20               # facets per chunk when measuring their sides


def _edge_keys(faces: np.ndarray) -> tuple[np.ndarray, int]:
    """One int64 key ``a * V + b`` (``a < b``) per edge of every facet, edges ``01``, ``12``, ``20`` of all
    the facets in turn (3T,), and the ``V`` used (one more than the largest index)."""
    v = int(faces.max()) + 1 if faces.size else 1
    keys = np.empty(3 * faces.shape[0], dtype=np.int64)
    for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        a, b = faces[:, i], faces[:, j]
        out = keys[k * faces.shape[0]:(k + 1) * faces.shape[0]]
        np.minimum(a, b, out=out)
        out *= v
        out += np.maximum(a, b)
    return keys, v


def _sorted_unique(keys: np.ndarray) -> np.ndarray:
    """``numpy.unique`` of 1-D int64 keys by one sort (numpy 2's ``unique`` took 20 times longer than
    ``sort`` on these keys)."""
    keys = np.sort(keys)
    first = np.empty(keys.size, dtype=bool)
    first[:1] = True
    np.not_equal(keys[1:], keys[:-1], out=first[1:])
    return keys[first]


def _unique_edges(faces: np.ndarray) -> np.ndarray:
    """The unique undirected edges (E,2), ``a < b``, in lexicographic order (no facets: for counting)."""
    keys, v = _edge_keys(faces)
    keys = _sorted_unique(keys)
    return np.stack(np.divmod(keys, v), axis=1)


def _edges(faces: np.ndarray):
    """Unique undirected edges (E,2) and their (up to two) facets (E,2), -1 where only one."""
    t = faces.shape[0]
    keys, v = _edge_keys(faces)
    owner = np.tile(np.arange(t, dtype=np.int64), 3)
    order = np.argsort(keys, kind="stable")
    ordered = keys[order]
    first = np.empty(keys.size, dtype=bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    inv = np.empty(keys.size, dtype=np.int64)
    inv[order] = np.cumsum(first) - 1                       # numpy.unique's return_inverse
    uniq = np.stack(np.divmod(ordered[first], v), axis=1)
    order = np.argsort(inv, kind="stable")
    first = np.full(uniq.shape[0], -1, dtype=np.int64)
    second = np.full(uniq.shape[0], -1, dtype=np.int64)
    s_inv, s_own = inv[order], owner[order]
    start = np.r_[True, s_inv[1:] != s_inv[:-1]]
    first[s_inv[start]] = s_own[start]
    nxt = np.r_[~start[1:], False] & start          # an edge with a second facet right after its first
    second[s_inv[nxt]] = s_own[np.flatnonzero(nxt) + 1]
    return uniq, np.stack([first, second], axis=1)


def _edge_lengths(vertices, edges) -> np.ndarray:
    out = np.empty(edges.shape[0])
    for i in range(0, edges.shape[0], _CHUNK):
        e = edges[i:i + _CHUNK]
        out[i:i + _CHUNK] = np.linalg.norm(vertices[e[:, 0]] - vertices[e[:, 1]], axis=1)
    return out


def _longest_sides(vertices, faces) -> np.ndarray:
    """The longest side of every facet: ``sqrt(dx^2 + dy^2 + dz^2)`` summed in that order, as
    ``numpy.linalg.norm`` does, so the same numbers to the last bit."""
    out = np.empty(faces.shape[0])
    for i in range(0, faces.shape[0], _CHUNK):
        f = faces[i:i + _CHUNK]
        p = [vertices[f[:, k]] for k in range(3)]
        longest = None
        for a, b in ((0, 2), (1, 0), (2, 1)):
            d = p[a] - p[b]
            d *= d
            sq = d[:, 0] + d[:, 1]
            sq += d[:, 2]
            longest = sq if longest is None else np.maximum(longest, sq, out=longest)
        out[i:i + _CHUNK] = np.sqrt(longest)
    return out


def _count(vertices, faces, edges, s, lengths=None):
    """Subdivisions per edge and per facet at spacing ``s`` and the points they add; ``lengths``: the
    edge lengths and the facets' longest sides, when already measured."""
    el, longest = lengths if lengths is not None else (_edge_lengths(vertices, edges),
                                                       _longest_sides(vertices, faces))
    ne = np.maximum(np.ceil(el / s - 1e-9).astype(np.int64), 1)
    nt = np.maximum(np.ceil(longest / s - 1e-9).astype(np.int64), 1)
    return ne, nt, int((ne - 1).sum() + ((nt - 1) * (nt - 2) // 2).sum())


def points_on_facets(vertices: np.ndarray, faces: np.ndarray, spacing_mm: float,
                     max_points: int = 2_000_000) -> FacetPoints:
    """The vertices (V,3) mm of the mesh ``faces`` (T,3) followed by points on its edges and facets no
    farther apart than ``spacing_mm`` (module docstring), at most ``max_points`` in all (the spacing is
    widened to fit, never the cap broken except by the vertices themselves)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    s = float(spacing_mm)
    if not s > 0:
        raise ValueError("spacing_mm must be > 0")
    nv = v.shape[0]
    if f.shape[0] == 0:
        return FacetPoints(v.copy(), np.full((nv, 2), -1, dtype=np.int64), s, nv)
    edges, edge_facets = _edges(f)
    budget = max(int(max_points) - nv, 0)
    lengths = (_edge_lengths(v, edges), _longest_sides(v, f))
    ne, nt, extra = _count(v, f, edges, s, lengths)
    for _ in range(4):
        if extra <= budget:
            break
        s *= math.sqrt(extra / max(budget, 1)) * 1.01
        ne, nt, extra = _count(v, f, edges, s, lengths)
    if extra > budget:          # a budget below one point per edge: the vertices only
        ne[:] = 1
        nt[:] = 1
    # edge points
    k = ne - 1
    rep = np.repeat(np.arange(edges.shape[0]), k)
    j = np.arange(rep.size) - np.repeat(np.cumsum(k) - k, k) + 1
    t = (j / ne[rep])[:, None]
    pe = v[edges[rep, 0]] * (1.0 - t) + v[edges[rep, 1]] * t
    parents_e = edge_facets[rep]
    # facet points, one lattice per distinct subdivision count
    pf, parents_f = [], []
    for n in np.unique(nt[nt >= 3]):
        ids = np.flatnonzero(nt == n)
        ii, jj = np.meshgrid(np.arange(1, n), np.arange(1, n), indexing="ij")
        keep = ii + jj <= n - 1
        a = ii[keep] / n
        b = jj[keep] / n
        c = 1.0 - a - b
        tri = v[f[ids]]                                     # (m,3,3)
        pts = (a[None, :, None] * tri[:, None, 0] + b[None, :, None] * tri[:, None, 1]
               + c[None, :, None] * tri[:, None, 2]).reshape(-1, 3)
        pf.append(pts)
        parents_f.append(np.stack([np.repeat(ids, a.size), np.full(ids.size * a.size, -1)], axis=1))
    points = np.concatenate([v, pe] + pf) if pf else np.concatenate([v, pe])
    parents = np.concatenate([np.full((nv, 2), -1, dtype=np.int64), parents_e.astype(np.int64)]
                             + [p.astype(np.int64) for p in parents_f])
    return FacetPoints(points, parents, s, nv)


def planned_point_count(vertices: np.ndarray, faces: np.ndarray | None, spacing_mm: float,
                        max_points: int = 2_000_000) -> int:
    """How many points :func:`points_on_facets` gives for this mesh at ``spacing_mm``, capped at
    ``max_points`` (but never below the vertex count; the vertices alone without faces), counted without
    building them: what a plan of the mesh will hold (the service's memory estimate). About 80 bytes
    per triangle at the peak (the edge keys, their sort and the unique edges)."""
    nv = int(np.asarray(vertices).shape[0])
    if faces is None or len(faces) == 0:
        return nv
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    extra = _count(v, f, _unique_edges(f), float(spacing_mm))[2]
    return int(min(nv + extra, max(int(max_points), nv)))
