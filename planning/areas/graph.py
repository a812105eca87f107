"""The neighbourhood graph of the sampled points on which areas are labelled (issue 14).

Nodes are the sampled points; an edge joins two points when either is among the other's
``k`` nearest neighbours (symmetrised kNN, Euclidean, mm). Two points whose normals differ by
more than :data:`OPPOSITE_SIDES_DEG` are not joined: they lie on the two sides of a thin wall,
not next to each other on the surface.

Per point, the surface area it stands for (mm^2), unbiased for uniformly random samples:
``a_p = 2 pi mean_j(r_j^2) / (k + 1)`` over the distances ``r_j`` to its ``k`` nearest neighbours
(for a Poisson sample of density rho, ``E[r_j^2] = j / (pi rho)``; on a square grid it reads
4.7 % high).

Per edge, the length of seam it stands for when its two ends carry different labels (mm), from
Buffon's needle / Crofton's formula: a curve of length ``L`` on a surface covered by isotropic
segments of total length ``lambda`` per mm^2 crosses ``2 lambda L / pi`` of them on average, so
each crossed edge stands for ``pi / (2 lambda)`` mm of seam, with ``lambda`` the mean of its two
ends' ``(sum of incident edge lengths / 2) / a_p``. The seam length of a labelling is the sum over
its cut edges (checked against straight seams on random and grid samples in tests/test_areas_graph.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

#: Normals further apart than this (degrees) mark the two sides of a thin wall: no edge.
OPPOSITE_SIDES_DEG = 120.0
#: Points closer than this (mm) are one position of the surface (copies).
SAME_POINT_MM = 1e-6
#: Neighbours searched for an edge that joins two pieces of a kNN graph that fell apart.
BRIDGE_NEIGHBOURS = 32


@dataclass(frozen=True)
class SurfaceGraph:
    """``edges`` (E,2) int64 node pairs with ``edges[:,0] < edges[:,1]``; ``length_mm`` (E,);
    ``seam_mm`` (E,): seam length an edge stands for when cut; ``normal_angle_deg`` (E,): angle
    between the two ends' normals (0 where a normal is unknown); ``area_mm2`` (n,): surface area
    per node; ``bond`` (E,) bool: the edge joins two copies of one position."""

    edges: np.ndarray
    length_mm: np.ndarray
    seam_mm: np.ndarray
    normal_angle_deg: np.ndarray
    area_mm2: np.ndarray
    bond: np.ndarray = None  # type: ignore[assignment]

    @property
    def n_nodes(self) -> int:
        return int(self.area_mm2.shape[0])


def neighbour_graph(points: np.ndarray, normals: np.ndarray | None = None, k: int = 8) -> SurfaceGraph:
    """The symmetrised ``k``-nearest-neighbour graph of ``points`` (n,3) mm with per-node area
    (mm^2) and per-edge seam length (mm), as in the module docstring. ``normals`` (n,3) unit or
    None; edges between points whose normals differ by more than :data:`OPPOSITE_SIDES_DEG` are
    dropped. Coincident points (within :data:`SAME_POINT_MM`) would fill each other's neighbour
    lists and cut themselves off: the graph is built on distinct positions, and every copy is
    bonded to its position's first point (a ``bond`` edge: seam 0, share of that point's area).
    Vectorised (one kd-tree query)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = pts.shape[0]
    first, inverse, count = _positions(pts)
    nu = first.shape[0]
    kk = int(min(max(1, k), nu - 1)) if nu > 1 else 0
    area = np.ones(n)
    edges = np.zeros((0, 2), np.int64)
    if kk > 0:
        dist, idx = cKDTree(pts[first]).query(pts[first], k=kk + 1, workers=-1)
        dist, idx = dist[:, 1:], idx[:, 1:]
        a_u = 2.0 * math.pi * np.mean(dist ** 2, axis=1) / (kk + 1)
        med = float(np.median(a_u[a_u > 0])) if (a_u > 0).any() else 1.0
        a_u = np.clip(a_u, 0.01 * med, 10.0 * med)      # isolated outliers
        area = (a_u / count)[inverse]
        a = first[np.repeat(np.arange(nu, dtype=np.int64), kk)]
        b = first[idx.reshape(-1)]
        edges = _bridge(pts, first, _unique_edges(a, b, n))
    copies = np.flatnonzero(first[inverse] != np.arange(n))
    bonds = np.stack([first[inverse[copies]], copies], axis=1)
    bonds = np.stack([bonds.min(axis=1), bonds.max(axis=1)], axis=1)
    angle = _normal_angles(normals, edges)
    same_side = angle <= OPPOSITE_SIDES_DEG
    edges, angle = edges[same_side], angle[same_side]
    length = np.linalg.norm(pts[edges[:, 0]] - pts[edges[:, 1]], axis=1)
    incident = np.bincount(edges.reshape(-1), weights=np.repeat(length, 2), minlength=n)
    rep_area = (area * count[inverse])            # the area of the whole position, for its first point
    density = 0.5 * incident / rep_area
    lam = 0.5 * (density[edges[:, 0]] + density[edges[:, 1]])
    seam = np.where(lam > 0, math.pi / (2.0 * np.maximum(lam, 1e-300)), 0.0)
    return SurfaceGraph(edges=np.concatenate([edges, bonds]), length_mm=np.concatenate([length, np.zeros(len(bonds))]),
                        seam_mm=np.concatenate([seam, np.zeros(len(bonds))]),
                        normal_angle_deg=np.concatenate([angle, np.zeros(len(bonds))]), area_mm2=area,
                        bond=np.concatenate([np.zeros(len(edges), bool), np.ones(len(bonds), bool)]))


def _positions(pts: np.ndarray):
    """The distinct positions of ``pts`` (n,3) (within :data:`SAME_POINT_MM`): (the first point of
    each position (u,), each point's position (n,), points per position (u,))."""
    n = pts.shape[0]
    key = np.round(pts / SAME_POINT_MM).astype(np.int64)
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    ks = key[order]
    start = np.r_[True, np.any(ks[1:] != ks[:-1], axis=1)] if n else np.zeros(0, bool)
    group = np.cumsum(start) - 1
    inverse = np.empty(n, np.int64)
    inverse[order] = group
    first = np.full(int(start.sum()), n, np.int64)
    np.minimum.at(first, group, order)
    return first, inverse, np.bincount(inverse, minlength=first.shape[0])


def _unique_edges(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """The distinct undirected edges (lo, hi), lo < hi, of the pairs (a, b) (self-pairs dropped)."""
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    code = np.unique((lo * n + hi)[lo != hi])
    return np.stack([code // n, code % n], axis=1)


def _bridge(pts: np.ndarray, first: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """``edges`` plus, while the graph falls apart, each piece's shortest edge to another piece
    among its points' :data:`BRIDGE_NEIGHBOURS` nearest (Boruvka rounds): a kNN graph of an
    anisotropic sample (rings of a parametric scan, scan lines) splits into strips that lie side by
    side on the surface. Pieces farther apart than that stay apart (separate bodies)."""
    from planning.areas.regions import components

    n = pts.shape[0]
    q = min(BRIDGE_NEIGHBOURS, first.shape[0] - 1)
    tree = None
    for _ in range(32):
        comp, nc = components(n, edges)
        if nc <= 1 or q < 1:
            break
        if tree is None:
            tree = cKDTree(pts[first])
        # every piece but the largest looks for its shortest edge out (the largest is found by them)
        cu = comp[first]
        outside = first[cu != np.argmax(np.bincount(cu))]
        dist, idx = tree.query(pts[outside], k=q + 1, workers=-1)
        idx = first[idx]
        cs = comp[outside]
        d = np.where(comp[idx] != cs[:, None], dist, np.inf)
        j = np.argmin(d, axis=1)
        dbest = d[np.arange(outside.shape[0]), j]
        ok = np.isfinite(dbest)
        if not ok.any():
            break
        order = np.lexsort((dbest[ok], cs[ok]))
        src, dst, cc = outside[ok][order], idx[ok, j[ok]][order], cs[ok][order]
        head = np.r_[True, cc[1:] != cc[:-1]]          # each piece's shortest outgoing edge
        edges = _unique_edges(np.r_[edges[:, 0], src[head]], np.r_[edges[:, 1], dst[head]], n)
    return edges


def _normal_angles(normals, edges) -> np.ndarray:
    """Angle (degrees) between the normals at the two ends of each edge (0 where one is unknown)."""
    if normals is None or edges.shape[0] == 0:
        return np.zeros(edges.shape[0])
    nn = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    dot = np.einsum("ij,ij->i", nn[edges[:, 0]], nn[edges[:, 1]])
    return np.degrees(np.arccos(np.clip(np.nan_to_num(dot, nan=1.0), -1.0, 1.0)))
