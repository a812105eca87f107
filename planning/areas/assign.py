"""Areas (Makki 2010 §3.1): one set-up per sampled point, leftovers integrated, the whole scan labelled.

Rules (documented in the README):
- a point seen by exactly one chosen axis takes it;
- an overlap point (seen by several) takes the axis whose angle to its normal is nearest the
  middle of the tool cone, (v1 + v2) / 2 (ties: the lowest set-up id) - the most comfortable cut;
- a point no chosen axis sees (a leftover) takes the label of its nearest labelled point, which
  realises the paper's attachment to the nearest area by point-to-set (Hausdorff) distance, and is
  flagged ``integrated``: its accessibility is not guaranteed;
- every input point takes the label of its nearest sampled point (so the whole scan is segmented).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from planning.visibility.cone import axis_normal_angles_deg


@dataclass(frozen=True)
class Areas:
    labels: np.ndarray        # (n,) int64 in [0, k): set-up of each sampled point
    integrated: np.ndarray    # (n,) bool: leftover attached by distance
    overlap: np.ndarray       # (n,) bool: seen by two or more chosen axes
    input_labels: np.ndarray  # (N,) int64: set-up of every input point (via its nearest sampled point)


def assign_areas(points: np.ndarray, sample_index: np.ndarray, normals: np.ndarray,
                 visibility: np.ndarray, selected: np.ndarray, selected_axes: np.ndarray,
                 cone_deg=(10.0, 80.0)) -> Areas:
    """Label sampled and input points with set-ups (Makki §3.1: areas, overlap, nearest-area leftovers).

    ``points`` (N,3) mm is the whole cloud, ``sample_index`` (n,) the sampled points with
    ``normals`` (n,3); ``visibility`` (n,m) bool; ``selected`` (k,) column indices with unit
    ``selected_axes`` (k,3). Distances are Euclidean in mm.
    """
    points = np.asarray(points, dtype=np.float64)
    sample_index = np.asarray(sample_index, dtype=np.int64)
    n = sample_index.shape[0]
    k = len(selected)
    sub = np.asarray(visibility)[:, np.asarray(selected, dtype=np.int64)]  # (n,k)
    n_seen = sub.sum(axis=1)
    seen = n_seen > 0
    integrated = ~seen
    labels = np.full(n, -1, dtype=np.int64)   # no set-up (k == 0) or no point seen: all -1
    if seen.any():
        middle = 0.5 * (float(cone_deg[0]) + float(cone_deg[1]))
        # rounded so that equal angles up to float noise tie, and the tie goes to the lowest set-up id
        score = np.round(np.abs(axis_normal_angles_deg(normals, selected_axes) - middle), 6)
        score = np.where(sub, score, np.inf)
        labels = np.argmin(score, axis=1).astype(np.int64)  # the first (lowest id) on ties
        if integrated.any():
            sp = points[sample_index]
            tree = cKDTree(sp[seen])
            _, j = tree.query(sp[integrated], k=1, workers=-1)
            labels[integrated] = labels[seen][j]
    if n > 0 and k > 0:
        tree = cKDTree(points[sample_index])
        _, j = tree.query(points, k=1, workers=-1)
        input_labels = labels[j]
        # A sampled point keeps its own label even when a duplicate coordinate exists.
        input_labels[sample_index] = labels
    else:
        input_labels = np.full(points.shape[0], -1, dtype=np.int64)
    return Areas(labels=labels, integrated=integrated, overlap=n_seen >= 2, input_labels=input_labels)
