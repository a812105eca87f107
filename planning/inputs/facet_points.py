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
pass per distinct subdivision count, none per facet or point.
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


def _edges(faces: np.ndarray):
    """Unique undirected edges (E,2) and their (up to two) facets (E,2), -1 where only one."""
    t = faces.shape[0]
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    owner = np.tile(np.arange(t, dtype=np.int64), 3)
    uniq, inv = np.unique(e, axis=0, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    first = np.full(uniq.shape[0], -1, dtype=np.int64)
    second = np.full(uniq.shape[0], -1, dtype=np.int64)
    s_inv, s_own = inv[order], owner[order]
    start = np.r_[True, s_inv[1:] != s_inv[:-1]]
    first[s_inv[start]] = s_own[start]
    nxt = np.r_[~start[1:], False] & start          # an edge with a second facet right after its first
    second[s_inv[nxt]] = s_own[np.flatnonzero(nxt) + 1]
    return uniq, np.stack([first, second], axis=1)


def _count(vertices, faces, edges, s):
    el = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    ne = np.maximum(np.ceil(el / s - 1e-9).astype(np.int64), 1)
    tri = vertices[faces]
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
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
    ne, nt, extra = _count(v, f, edges, s)
    for _ in range(4):
        if extra <= budget:
            break
        s *= math.sqrt(extra / max(budget, 1)) * 1.01
        ne, nt, extra = _count(v, f, edges, s)
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
    """How many points :func:`points_on_facets` gives for this mesh (the vertices alone without faces),
    counted without building them: what a plan of the mesh will hold (the service's memory estimate)."""
    nv = int(np.asarray(vertices).shape[0])
    if faces is None or len(faces) == 0:
        return nv
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    extra = _count(v, f, _edges(f)[0], float(spacing_mm))[2]
    return int(min(nv + extra, max(int(max_points), nv)))
