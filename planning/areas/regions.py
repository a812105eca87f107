"""Connected regions of the areas on the neighbourhood graph: small pieces merged, figures reported
(issue 14 items 2 and 3).

A region is a connected component of the graph restricted to the edges whose two ends carry the
same label. Every region is machined by its own finishing passes, entries and exits, and its
border is a seam, so the plan wants few regions and short seams.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from planning.areas.graph import SurfaceGraph

#: Most rounds of merging small pieces (each round merges every small piece that can merge).
MAX_MERGE_ROUNDS = 50


def components(n: int, edges: np.ndarray, keep: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """Connected components of the ``n`` nodes over ``edges`` (E,2) (only those with ``keep``):
    ((n,) component id, number of components)."""
    if keep is not None:
        edges = edges[keep]
    m = coo_matrix((np.ones(edges.shape[0], np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    nc, comp = connected_components(m, directed=False)
    return comp.astype(np.int64), int(nc)


def label_regions(graph: SurfaceGraph, labels: np.ndarray) -> tuple[np.ndarray, int]:
    """The regions of a labelling: ((n,) component id, count); edges join same-label nodes."""
    e = graph.edges
    same = labels[e[:, 0]] == labels[e[:, 1]] if e.size else np.zeros(0, bool)
    return components(graph.n_nodes, e, same)


def merge_small_regions(graph: SurfaceGraph, labels: np.ndarray, allowed: np.ndarray,
                        min_region_mm2: float) -> np.ndarray:
    """Relabel every region of less than ``min_region_mm2`` (mm^2) with the label of a larger
    neighbouring region allowed at all its points (``allowed`` (n,k): the set-up sees the point,
    or no chosen set-up does); among several, the one it shares the longest seam with. Repeated
    until nothing changes (at most :data:`MAX_MERGE_ROUNDS`); a piece no larger neighbour may
    take stays. Merging only into strictly larger regions keeps two pieces from swapping."""
    labels = np.asarray(labels, dtype=np.int64).copy()
    n, k = allowed.shape
    e = graph.edges
    if min_region_mm2 <= 0 or n == 0 or k <= 1 or e.shape[0] == 0:
        return labels
    for _ in range(MAX_MERGE_ROUNDS):
        comp, nc = label_regions(graph, labels)
        size = np.bincount(comp, weights=graph.area_mm2, minlength=nc)
        small = size < min_region_mm2
        if not small.any():
            break
        blocked = np.stack([np.bincount(comp, weights=~allowed[:, j], minlength=nc) for j in range(k)], axis=1)
        border = np.zeros((nc, k))
        for a, b in ((0, 1), (1, 0)):
            ca, cb = comp[e[:, a]], comp[e[:, b]]
            go = (ca != cb) & small[ca] & (size[cb] > size[ca])
            np.add.at(border, (ca[go], labels[e[go, b]]), graph.seam_mm[go])
        own = np.zeros(nc, np.int64)
        own[comp] = labels
        border[np.arange(nc), own] = 0.0
        border[blocked > 0] = 0.0
        target = np.argmax(border, axis=1)
        move = small & (border.max(axis=1) > 0)
        if not move.any():
            break
        change = move[comp]
        labels[change] = target[comp[change]]
    return labels


def region_index(graph: SurfaceGraph, labels: np.ndarray) -> np.ndarray:
    """(n,) each node's region number within its area: 0 for the area's largest region (by
    points), 1 for the next, ...; -1 where the label is -1."""
    comp, nc = label_regions(graph, labels)
    size = np.bincount(comp, minlength=nc)
    lab_of = np.full(nc, -1, np.int64)
    lab_of[comp] = labels
    order = np.lexsort((np.arange(nc), -size, lab_of))          # by label, then largest first
    rank = np.empty(nc, np.int64)
    sorted_lab = lab_of[order]
    first = np.searchsorted(sorted_lab, sorted_lab, side="left")
    rank[order] = np.arange(nc) - first
    out = rank[comp]
    out[labels < 0] = -1
    return out


@dataclass(frozen=True)
class AreaFigures:
    """One area's shape on the graph: ``n_points`` sampled points, ``n_regions`` connected
    regions, ``largest_region_share`` of its points in the largest one, ``area_mm2`` surface,
    ``seam_mm`` length of its border with other areas (mm, the Crofton estimate of
    :mod:`planning.areas.graph`), ``n_visible_regions``: the connected pieces of at least the
    minimum region size of the set of points its set-up sees; ``n_small_regions``: regions under
    the minimum size (each holds a point only this set-up sees: nothing else may take it);
    ``min_regions``: a lower bound on ``n_regions`` from the visibility alone, the connected pieces
    of the set where the area may be (the points its set-up sees and the leftovers) that hold a
    point no other chosen set-up sees (each needs a region of its own)."""

    n_points: int
    n_regions: int
    largest_region_share: float
    area_mm2: float
    seam_mm: float
    n_visible_regions: int
    n_small_regions: int = 0
    min_regions: int = 0


def area_figures(graph: SurfaceGraph, labels: np.ndarray, visible: np.ndarray,
                 min_region_mm2: float) -> list[AreaFigures]:
    """:class:`AreaFigures` of every set-up (a column of ``visible`` (n,k))."""
    n, k = visible.shape
    e = graph.edges
    comp, nc = label_regions(graph, labels)
    cut = labels[e[:, 0]] != labels[e[:, 1]] if e.size else np.zeros(0, bool)
    out = []
    region_area = np.bincount(comp, weights=graph.area_mm2, minlength=nc)
    only = visible & (visible.sum(axis=1) == 1)[:, None]
    leftover = ~visible.any(axis=1)
    for j in range(k):
        mine = labels == j
        counts = np.bincount(comp[mine], minlength=nc)
        sizes = counts[counts > 0]
        touching = cut & (mine[e[:, 0]] | mine[e[:, 1]])
        vcomp, vn = components(n, e, visible[e[:, 0], j] & visible[e[:, 1], j])
        varea = np.bincount(vcomp[visible[:, j]], weights=graph.area_mm2[visible[:, j]], minlength=vn)
        may = visible[:, j] | leftover            # where this area may be
        mcomp, _ = components(n, e, may[e[:, 0]] & may[e[:, 1]])
        out.append(AreaFigures(
            n_points=int(mine.sum()), n_regions=int(sizes.size),
            largest_region_share=float(sizes.max() / mine.sum()) if mine.any() else 0.0,
            area_mm2=float(graph.area_mm2[mine].sum()), seam_mm=float(graph.seam_mm[touching].sum()),
            n_visible_regions=int(((varea >= min_region_mm2) & (varea > 0)).sum()),
            n_small_regions=int(((counts > 0) & (region_area < min_region_mm2)).sum()),
            min_regions=int(np.unique(mcomp[only[:, j]]).size)))
    return out


def seam_totals(graph: SurfaceGraph, labels: np.ndarray) -> tuple[float, float]:
    """(share of graph edges whose ends carry different labels, total seam length in mm)."""
    e = graph.edges
    if e.shape[0] == 0:
        return 0.0, 0.0
    cut = labels[e[:, 0]] != labels[e[:, 1]]
    return float(cut.mean()), float(graph.seam_mm[cut].sum())
