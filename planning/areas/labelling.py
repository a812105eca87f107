"""The labelling energy of the areas and its minimisation by alpha-expansion (issue 14).

Over the neighbourhood graph (:mod:`planning.areas.graph`), a labelling ``l`` (a chosen set-up per
sampled point) costs

    E(l) = sum_p a_p c_p(l_p)  +  lambda * sum_{edges pq, l_p != l_q} s_pq w_pq

* data term: ``a_p`` the point's area (mm^2) times its discomfort ``c_p(l)`` in [0, 1], the
  distance of the angle between the normal and the set-up's axis from the middle of the tool
  cone, over the cone's half width (0: the most comfortable cut, 1: at the cone's edge). A set-up
  that cannot see the point (visibility after every global filter) is forbidden (infinite cost). A
  point no chosen set-up sees (a leftover, flagged ``integrated``) costs nothing in any area: the
  seams alone place it.
* smoothness term (copies of one position are bonded by a cost of twice the largest point area):
  ``s_pq`` the seam length the edge stands for (mm), ``w_pq`` 1, or
  ``areas.sharp_edge_weight`` across a sharp edge of the part (normals more than
  ``areas.sharp_edge_deg`` apart), where a seam is least visible; ``lambda`` =
  ``areas.smoothness_mm``: a seam 1 mm long costs as much as lambda mm^2 of surface cut at the edge
  of the cone rather than in its middle.

The energy is a Potts model with a metric pairwise term, minimised by alpha-expansion (Boykov,
Veksler & Zabih 2001; the GCO library of Veksler and Delong through ``gco-wrapper``), which
reaches a local minimum within a factor 2 of the global one. It starts from the per-point
labelling (each point the most comfortable set-up that sees it), so it never ends above it; no
expansion move takes a forbidden label because its cost exceeds all the seam a point can save
(checked after the solve).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planning.areas.graph import SurfaceGraph
from planning.visibility.cone import axis_normal_angles_deg

#: Integer units of the data term of a node of median area at the cone's edge (GCO works in int32).
_UNIT = 1000.0
#: GCO_MAX_ENERGYTERM: the largest data or smoothness term GCO accepts (it aborts the process beyond).
_MAX_TERM = 10_000_000


@dataclass(frozen=True)
class LabellingEnergy:
    """``data`` (n,k) float: data cost per point and set-up (``inf`` where forbidden);
    ``weights`` (E,) float: the cost of cutting each graph edge; both in mm^2 (see the module
    docstring); ``seen`` (n,) bool: points some chosen set-up sees (the others are leftovers)."""

    data: np.ndarray
    weights: np.ndarray
    seen: np.ndarray

    def value(self, edges: np.ndarray, labels: np.ndarray) -> float:
        """E(labels): data plus smoothness, ``inf`` when a forbidden label is used."""
        labels = np.asarray(labels, dtype=np.int64)
        d = float(self.data[np.arange(labels.shape[0]), labels].sum()) if labels.size else 0.0
        cut = labels[edges[:, 0]] != labels[edges[:, 1]] if edges.size else np.zeros(0, bool)
        return d + float(self.weights[cut].sum())


def labelling_energy(graph: SurfaceGraph, normals: np.ndarray, visible: np.ndarray, axes: np.ndarray,
                     cone_deg=(10.0, 80.0), smoothness_mm: float = 5.0, sharp_edge_deg: float = 30.0,
                     sharp_edge_weight: float = 0.25) -> LabellingEnergy:
    """The energy of the module docstring. ``normals`` (n,3) unit; ``visible`` (n,k) bool: which
    chosen set-up sees which point; ``axes`` (k,3) unit tool axes; ``cone_deg`` (lower, upper)
    degrees; ``smoothness_mm`` lambda (mm); ``sharp_edge_deg`` degrees; ``sharp_edge_weight`` the
    factor on seams across sharp edges."""
    visible = np.asarray(visible, dtype=bool)
    lo, hi = float(cone_deg[0]), float(cone_deg[1])
    half = max(0.5 * (hi - lo), 1e-9)
    ang = axis_normal_angles_deg(np.nan_to_num(normals), axes)
    discomfort = np.clip(np.abs(ang - 0.5 * (lo + hi)) / half, 0.0, 1.0)
    data = graph.area_mm2[:, None] * discomfort
    seen = visible.any(axis=1)
    data = np.where(visible, data, np.inf)
    data[~seen] = 0.0
    w = smoothness_mm * graph.seam_mm * np.where(graph.normal_angle_deg > sharp_edge_deg, sharp_edge_weight, 1.0)
    if graph.bond is not None and graph.bond.any():
        # copies of one position stay together wherever they may: as strong as a whole point's comfort
        w = np.where(graph.bond, 2.0 * float(np.max(graph.area_mm2)), w)
    return LabellingEnergy(data=data, weights=w, seen=seen)


def per_point_labels(energy: LabellingEnergy) -> np.ndarray:
    """Each point's cheapest allowed label alone, without seams (ties: the lowest set-up id):
    the most comfortable set-up that sees it; -1 for a leftover no set-up sees."""
    data = energy.data
    if data.shape[1] == 0:
        return np.full(data.shape[0], -1, np.int64)
    lab = np.argmin(np.round(data, 9), axis=1).astype(np.int64)
    lab[~energy.seen] = -1
    return lab


def alpha_expansion(energy: LabellingEnergy, edges: np.ndarray, init: np.ndarray) -> np.ndarray:
    """Minimise ``energy`` over labellings of the graph ``edges`` by alpha-expansion from the
    feasible labelling ``init`` (n,) (every point's label allowed). Returns (n,) int64 labels with
    energy <= that of ``init``, every label allowed.

    Only the points with a choice (two or more allowed labels) enter the graph cut; a point with
    one allowed label is fixed, and its edges to free points become part of their data cost (the
    cost of differing from it), which leaves the energy to minimise unchanged."""
    init = np.asarray(init, dtype=np.int64)
    n, k = energy.data.shape
    finite = np.isfinite(energy.data)
    free = finite.sum(axis=1) > 1
    if k <= 1 or not free.any() or edges.shape[0] == 0:
        return init.copy()
    fa, fb = free[edges[:, 0]], free[edges[:, 1]]
    data = np.where(finite, energy.data, np.inf)
    for a, b, keep in ((0, 1, fa & ~fb), (1, 0, fb & ~fa)):    # free end a, fixed end b
        e = edges[keep]
        cost = np.repeat(energy.weights[keep][:, None], k, axis=1)
        cost[np.arange(e.shape[0]), init[e[:, b]]] = 0.0
        np.add.at(data, e[:, a], cost)
    idx = np.flatnonzero(free)
    local = np.full(n, -1, np.int64)
    local[idx] = np.arange(idx.size)
    both = fa & fb
    sub_edges = local[edges[both]]
    labels = init.copy()
    labels[idx] = _gco_expansion(data[idx], sub_edges, energy.weights[both], init[idx])
    bad = ~finite[np.arange(n), labels]
    labels[bad] = init[bad]                            # never happens with the forbidding cost; a guard
    return labels


def _gco_expansion(data: np.ndarray, edges: np.ndarray, weights: np.ndarray, init: np.ndarray) -> np.ndarray:
    """GCO's alpha-expansion (Potts smoothness, int32 costs) of the data (n,k) (``inf`` =
    forbidden) and edge ``weights`` (E,), from ``init``; costs are scaled to integers so that the
    median point's largest allowed data cost is :data:`_UNIT`, and a forbidden label costs more
    than any point can save."""
    import gco  # the GCO library (Veksler & Delong), imported here: only this stage needs it

    n, k = data.shape
    finite = np.isfinite(data)
    big = np.where(finite, data, 0.0)
    scale = _UNIT / max(float(np.median(big.max(axis=1))), 1e-12)
    big *= scale
    w = np.maximum(np.rint(weights * scale), 0.0)
    incident = np.bincount(edges.reshape(-1), weights=np.repeat(w, 2), minlength=n) if edges.size else np.zeros(n)
    forbid = 2.0 * (float(big.max(initial=0.0)) + float(incident.max(initial=0.0))) + 1.0
    if forbid > _MAX_TERM:                             # GCO refuses (aborts on) larger terms
        shrink = _MAX_TERM / forbid
        big, w, forbid = big * shrink, np.rint(w * shrink), _MAX_TERM
    unary = np.where(finite, np.rint(big), forbid).astype(np.intc)
    if edges.shape[0] == 0:
        return np.argmin(unary, axis=1).astype(np.int64)
    g = gco.GCO()
    g.create_general_graph(n, k, energy_is_float=False)
    try:
        g.set_data_cost(unary)
        g.set_all_neighbors(edges[:, 0].astype(np.intc), edges[:, 1].astype(np.intc), w.astype(np.intc))
        g.set_smooth_cost((1 - np.eye(k)).astype(np.intc))
        for site in range(n):                         # the wrapper has no vectorised initialisation
            g.init_label_at_site(site, int(init[site]))
        g.expansion(-1)
        return np.asarray(g.get_labels(), dtype=np.int64)
    finally:
        g.destroy_graph()
