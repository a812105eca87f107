"""One stock carried through the set-ups (issue 16 item 1): the order the set-ups are machined in and
the simulated stock, obstacles, tools and machine positions that the tool paths of each set-up are
planned and guarded on (:mod:`planning.toolpath.area_paths`, :mod:`planning.toolpath.guard`).

**Order** (:func:`machining_order`): the area with the most scan points first, then the next
largest (ties: the lower set-up number). The largest area is usually the most open side of the
part: roughing it first takes the bulk of the stock off with the shortest tool reach, and every
later set-up only roughs what is left over its own area (rest roughing). The order is written to
``plan.json`` (``machining_order``) and the programs are run (simulated, and on the machine) in it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planning.simulate.dexel import TriDexel
from planning.simulate.motion import ToolShape
from planning.toolpath.guard import SetupMachine


def machining_order(input_labels: np.ndarray, k: int) -> list[int]:
    """The set-ups' machining order (module docstring): area ids 0..k-1, most points first."""
    counts = np.bincount(np.asarray(input_labels)[np.asarray(input_labels) >= 0], minlength=k)[:k]
    return [int(i) for i in sorted(range(k), key=lambda i: (-int(counts[i]), i))]


@dataclass
class CarriedStock:
    """What every set-up's paths are planned and guarded on: ``stock`` (the tri-dexel stock, cut by
    each guarded operation in turn), ``obstacles`` (fixtures, riser and table, never cut; or None),
    ``finishing_shape`` / ``roughing_shape`` (the tools as the simulation sees them), ``machines``
    (per set-up :class:`SetupMachine`, or None: travel not checked), ``order`` (area ids),
    ``rapid_clearance_mm`` (the guard's), ``resolution_mm`` (the stock model's ray spacing),
    ``footprint`` (:func:`footprint` of the scan: no finishing ball cuts below the part's underside
    inside it), ``normals`` (N,3) unit normals of the
    scan's points (for the allowance left before finishing), ``visible`` (N,k) bool: which set-up
    sees each scan point (the visibility of its nearest sample): points a set-up leaves unmachined
    are handed to a later one that sees them; ``semi_shape``: the semi-finishing cutter
    (``paths.semi_finishing``) as the simulation sees it, or None when there is none; ``config``: the
    plan's parameters (the 5-axis guard posts its path as the programs will, with their options), or
    None."""

    stock: TriDexel
    obstacles: TriDexel | None
    finishing_shape: ToolShape
    roughing_shape: ToolShape
    machines: list[SetupMachine] | None
    order: list[int]
    rapid_clearance_mm: float
    resolution_mm: float
    footprint: Footprint | None = None
    normals: np.ndarray | None = None
    visible: np.ndarray | None = None
    semi_shape: ToolShape | None = None
    config: object = None

    def stock_over(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(k,) the stock left over the scan ``points`` (k,3, part frame) along their unit ``normals`` on
        the carried stock as it is now (:func:`planning.simulate.dexel.signed_deviation`, clipped at 20 mm;
        mm; NaN where not read)."""
        from planning.simulate.dexel import signed_deviation

        return signed_deviation(self.stock, points, normals, max_mm=20.0)


def stock_figures(d: np.ndarray) -> dict:
    """``p05``, ``p50``, ``p95``, ``max`` (mm) of the finite readings ``d`` of :meth:`CarriedStock.stock_over`,
    and ``n`` read."""
    d = np.asarray(d, dtype=np.float64)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return {"n": 0}
    q = np.percentile(d, [5, 50, 95])
    return {"n": int(d.size), "p05": round(float(q[0]), 3), "p50": round(float(q[1]), 3),
            "p95": round(float(q[2]), 3), "max": round(float(d.max()), 3)}


@dataclass
class Footprint:
    """The part's footprint on its underside (issue 16 item 4: no cut below the part's underside inside
    its footprint): the cells of a raster (``cell_mm``, part frame x, y) that the scan's points cover,
    holes filled, and the distance of every cell to the footprint (mm, 0 inside); ``floor_z_mm`` the
    part's underside (lowest scan point z). Built by :func:`footprint`."""

    lo: np.ndarray
    cell_mm: float
    distance_mm: np.ndarray
    floor_z_mm: float

    def below_floor(self, centres_part: np.ndarray, radius_mm: float, tol_mm: float) -> np.ndarray:
        """(n,) bool: the ball of radius ``radius_mm`` at part-frame ``centres_part`` (n,3) reaches more than
        ``tol_mm`` below the underside at a point inside the footprint: with ``h`` the centre's height
        above ``floor - tol`` and ``d`` its horizontal distance to the footprint, ``h < R`` and
        ``d < sqrt(R^2 - max(h, 0)^2)``. The distance is read at the centre's cell, less half a
        cell's diagonal (conservative)."""
        c = np.asarray(centres_part, dtype=np.float64).reshape(-1, 3)
        R = float(radius_mm)
        h = c[:, 2] - (self.floor_z_mm - float(tol_mm))
        ij = np.floor((c[:, :2] - self.lo) / self.cell_mm).astype(np.int64)
        nx, ny = self.distance_mm.shape
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        d = np.full(c.shape[0], np.inf)
        d[inside] = self.distance_mm[ij[inside, 0], ij[inside, 1]]
        d = np.maximum(d - self.cell_mm * 0.7072, 0.0)
        reach = np.sqrt(np.maximum(R * R - np.maximum(h, 0.0) ** 2, 0.0))
        return (h < R) & (d < reach)


def footprint(points: np.ndarray, cell_mm: float = 0.5, reach_mm: float = 50.0) -> Footprint:
    """The :class:`Footprint` of the scan ``points`` (N,3, part frame, mm): the cells holding a point's
    (x, y), closed over 2 cells and with their holes filled, on a raster reaching ``reach_mm`` beyond
    the points (farther cells are taken as far from the footprint)."""
    from scipy import ndimage

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo = p[:, :2].min(axis=0) - reach_mm
    n = np.ceil((p[:, :2].max(axis=0) + reach_mm - lo) / cell_mm).astype(np.int64) + 1
    occ = np.zeros((int(n[0]), int(n[1])), dtype=bool)
    ij = np.floor((p[:, :2] - lo) / cell_mm).astype(np.int64)
    occ[ij[:, 0], ij[:, 1]] = True
    occ = ndimage.binary_closing(occ, iterations=2)
    occ = ndimage.binary_fill_holes(occ)
    dist = ndimage.distance_transform_edt(~occ) * cell_mm
    return Footprint(lo=lo, cell_mm=float(cell_mm), distance_mm=dist, floor_z_mm=float(p[:, 2].min()))
