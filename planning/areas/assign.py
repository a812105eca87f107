"""Areas (Makki 2010 §3.1): one chosen set-up per sampled point, as contiguous regions; the whole
scan labelled (issue 14).

1. the neighbourhood graph of the sampled points (:mod:`planning.areas.graph`);
2. a start: each point the most comfortable set-up that sees it (the angle between normal and
   axis nearest the middle of the tool cone; ties: the lowest set-up id); a point no chosen set-up
   sees (a leftover) the label of its nearest labelled point, which realises the paper's attachment
   to the nearest area by point-to-set distance, flagged ``integrated`` (accessibility not
   guaranteed);
3. with ``areas.method = graphcut`` (default): the labelling energy (comfort plus seam length,
   :mod:`planning.areas.labelling`) minimised by alpha-expansion from that start, then regions
   smaller than ``areas.min_region_mm2`` merged into a larger neighbour that sees them
   (:mod:`planning.areas.regions`). A point never takes a set-up that cannot see it, unless no
   chosen set-up does;
4. every input point takes the label and the region of its nearest sampled point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from planning.areas.graph import neighbour_graph
from planning.areas.labelling import alpha_expansion, labelling_energy, per_point_labels
from planning.areas.regions import (
    AreaFigures,
    area_figures,
    merge_small_regions,
    region_index,
    seam_totals,
)
from schemas.params import AreasParams


@dataclass(frozen=True)
class Areas:
    """``labels`` (n,) int64 in [0, k): set-up of each sampled point (-1 when no set-up is chosen);
    ``integrated`` (n,) bool: seen by no chosen set-up; ``overlap`` (n,) bool: seen by two or more;
    ``input_labels`` (N,): set-up of every input point; ``regions`` (n,) / ``input_regions`` (N,):
    region number within the area (0 = its largest); ``figures``: per set-up
    :class:`~planning.areas.regions.AreaFigures`; ``label_change_share``: share of graph edges
    whose ends differ; ``seam_mm``: total seam length (mm); ``method``: the rule used."""

    labels: np.ndarray
    integrated: np.ndarray
    overlap: np.ndarray
    input_labels: np.ndarray
    regions: np.ndarray | None = None
    input_regions: np.ndarray | None = None
    figures: tuple[AreaFigures, ...] = ()
    label_change_share: float = 0.0
    seam_mm: float = 0.0
    method: str = "per_point"
    nearest_sample: np.ndarray | None = None


def assign_areas(points: np.ndarray, sample_index: np.ndarray, normals: np.ndarray,
                 visibility: np.ndarray, selected: np.ndarray, selected_axes: np.ndarray,
                 cone_deg=(10.0, 80.0), params: AreasParams | None = None, progress=None) -> Areas:
    """Label sampled and input points with set-ups (see the module docstring).

    ``points`` (N,3) mm is the whole cloud, ``sample_index`` (n,) the sampled points with unit
    ``normals`` (n,3); ``visibility`` (n,m) bool after every global filter; ``selected`` (k,)
    column indices with unit ``selected_axes`` (k,3); ``cone_deg`` the tool cone (degrees);
    ``params`` :class:`schemas.params.AreasParams` (default values when None); ``progress(fraction,
    message)`` is told each step (graph, alpha-expansion, merging, propagation).
    """
    params = params or AreasParams()
    say = progress or (lambda fraction, message="": None)
    points = np.asarray(points, dtype=np.float64)
    sample_index = np.asarray(sample_index, dtype=np.int64)
    n, k = sample_index.shape[0], len(selected)
    sub = np.asarray(visibility, dtype=bool)[:, np.asarray(selected, dtype=np.int64)]  # (n,k)
    seen = sub.any(axis=1)
    sp = points[sample_index]
    say(0.0, "neighbour graph")
    graph = neighbour_graph(sp, normals, params.neighbours)
    labels = np.full(n, -1, dtype=np.int64)
    method = params.method if params.smoothness_mm > 0 else "per_point"
    if seen.any() and k > 0:
        energy = labelling_energy(graph, normals, sub, selected_axes, cone_deg, params.smoothness_mm,
                                  params.sharp_edge_deg, params.sharp_edge_weight)
        labels = _attach_leftovers(sp, per_point_labels(energy), seen)
        if method == "graphcut":
            say(0.35, "alpha-expansion")
            labels = alpha_expansion(energy, graph.edges, labels)
            say(0.6, "merging small regions")
            labels = merge_small_regions(graph, labels, sub | ~seen[:, None], params.min_region_mm2)
    say(0.7, "regions and the input points' areas")
    regions = region_index(graph, labels)
    nearest = _nearest_sample(points, sample_index)
    input_labels, input_regions = _propagate(nearest, sample_index, labels, regions, k)
    share, seam = seam_totals(graph, labels)
    return Areas(labels=labels, integrated=~seen, overlap=sub.sum(axis=1) >= 2, input_labels=input_labels,
                 regions=regions, input_regions=input_regions,
                 figures=tuple(area_figures(graph, labels, sub, params.min_region_mm2)),
                 label_change_share=share, seam_mm=seam, method=method, nearest_sample=nearest)


def _attach_leftovers(sp: np.ndarray, labels: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Step 2 for the leftovers: the label of the nearest seen sampled point (Euclidean, mm)."""
    labels = labels.copy()
    if (~seen).any():
        _, j = cKDTree(sp[seen]).query(sp[~seen], k=1, workers=-1)
        labels[~seen] = labels[seen][j]
    return labels


def _nearest_sample(points, sample_index) -> np.ndarray:
    """(N,) the nearest sampled point of every input point (a sampled point is its own)."""
    if sample_index.shape[0] == 0:
        return np.zeros(points.shape[0], np.int64)
    _, j = cKDTree(points[sample_index]).query(points, k=1, workers=-1)
    j = np.asarray(j, dtype=np.int64)
    j[sample_index] = np.arange(sample_index.shape[0])
    return j


def _propagate(nearest, sample_index, labels, regions, k):
    """Step 4: the label and region of every input point from its nearest sampled point."""
    N = nearest.shape[0]
    if sample_index.shape[0] == 0 or k == 0:
        return np.full(N, -1, np.int64), np.full(N, -1, np.int64)
    return labels[nearest], regions[nearest]
