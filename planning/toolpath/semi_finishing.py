"""Semi-finishing of one set-up (issue 31 item 3; docs/design.md "Semi-finishing"): a ball-end cutter of
its own, run over the area between its roughing and its finishing, so that the finishing ball meets a
thin, even layer of material instead of the roughing's steps.

Z-level roughing leaves the allowance plus up to a step on every slope (on a gentle slope, nearly the
whole 2 mm step; BENCHMARKS.md, issue 16). The pass here removes that stair:

* **The allowance surface.** The cutter of radius ``r`` (``paths.semi_finishing.diameter_mm / 2``)
  runs its ball centre on the surface a ball of radius ``R' = r + a`` (``a`` =
  ``allowance_mm``) dropped on the scan rests on: every such centre is at least ``R'`` from every
  scan point, so the cutter's ball stays ``a`` off the scan. The passes are the finishing's own
  (:func:`planning.toolpath.finishing_worker.region_passes`: ball drop, side step from the scallop
  on every curvature, forward step from the chords, gouge-checked links and leads) planned with the
  radius ``R'``, ``scallop_mm``, ``step_mm`` and ``tolerance_mm`` of ``paths.semi_finishing``; CL
  reduction and arcs are fitted against ``R'`` the same way. The result's ``tip_offset_mm`` is ``r``:
  the posts and the simulation drive the real cutter's tip, ``r`` under the centre.
* **On the stock.** With a carried stock, the positions where the cutter's shank or holder would
  meet the stock the roughing left (or the scan, a fixture, the table, the part's underside, the
  machine's travel) are cut out exactly as the finishing's are
  (:func:`planning.toolpath.safety.guard_finishing` with this cutter), and the pass is then run on the
  carried stock by the guard (:func:`planning.toolpath.guard.guard_toolpath`) like every operation:
  the finishing after it is planned and checked on the stock it leaves.

What the pass is for is measured on the stock (:meth:`planning.toolpath.carried.CarriedStock.allowance_left`):
the material over the area's scan points along their normals before it and after it
(``plan.json`` ``setups[].path.semi_finishing.allowance_before_mm`` / ``allowance_after_mm``).
Units: mm; frame: the set-up's area frame (tool axis +Z).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from planning.geometry.tool import ToolAssembly
from planning.toolpath.finishing import FinishingPath
from planning.toolpath.moves import ARC_CCW, ARC_CW, Toolpath
from planning.toolpath.reduce import fit_arcs, reduce_cl
from planning.toolpath.verify import move_clearance


@njit(cache=True, nogil=True, parallel=True)
def _depth_kernel(top, x0, y0, h, centres, r, out):
    nx, ny = top.shape
    r2 = r * r
    for k in prange(centres.shape[0]):
        cx, cy, cz = centres[k, 0], centres[k, 1], centres[k, 2]
        i0 = max(int(math.floor((cx - r - x0) / h)), 0)
        i1 = min(int(math.floor((cx + r - x0) / h)), nx - 1)
        j0 = max(int(math.floor((cy - r - y0) / h)), 0)
        j1 = min(int(math.floor((cy + r - y0) / h)), ny - 1)
        best = -math.inf
        for i in range(i0, i1 + 1):
            dx = x0 + (i + 0.5) * h - cx
            for j in range(j0, j1 + 1):
                dy = y0 + (j + 0.5) * h - cy
                d2 = dx * dx + dy * dy
                t = top[i, j]
                if d2 >= r2 or not t > cz - math.sqrt(r2 - d2):
                    continue                     # no material of this line inside the ball
                # the material on this line inside the ball lies from the ball's lower surface up to the top
                # (or the ball's upper surface); its point nearest the centre is at min(t, cz)
                dz = min(t, cz) - cz
                e = r - math.sqrt(d2 + dz * dz)
                if e > best:
                    best = e
        out[k] = best


class DepthLimit:
    """The semi-finishing's deepest cut as a test of ball centres (the ``depth`` of
    :func:`planning.toolpath.safety.blocked_cl`): a centre ``c`` (area frame) cuts too deep where stock
    lies more than ``max_depth_mm`` inside the cutter's ball of radius ``r``, measured radially (``r``
    less the distance from ``c`` to the stock's nearest point inside the ball): the chip thickness a
    ball cuts, normal to the surface it leaves, on a slope as on a flat. The stock is read once along
    the frame's Z on a raster of ``cell_mm`` cells over ``lo``..``hi`` (frame x, y;
    :func:`planning.simulate.heightfield.stock_tops_in_frame`, the stock as the pass finds it; the
    positions beyond the raster see none of it) and taken as solid below its top on every cell's line
    within ``r`` of the centre's (x, y). Units mm."""

    def __init__(self, stock, frame, lo, hi, r: float, max_depth_mm: float, stop_z_mm: float, cell_mm: float = 0.5):
        self.stock, self.frame, self.r, self.max_depth = stock, frame, float(r), float(max_depth_mm)
        self.h = float(cell_mm)
        self.x0, self.y0 = float(lo[0]), float(lo[1])
        self.nx = max(1, int(math.ceil((float(hi[0]) - self.x0) / self.h)))
        self.ny = max(1, int(math.ceil((float(hi[1]) - self.y0) / self.h)))
        self.stop = float(stop_z_mm)
        self._top = None

    def top(self) -> np.ndarray:
        """(nx, ny) the stock's top per cell (frame z, -inf where there is none), read at the first call."""
        if self._top is None:
            from planning.simulate.heightfield import stock_tops_in_frame

            self._top = stock_tops_in_frame(self.stock, self.frame.rotation, self.frame.origin_mm, self.x0, self.y0,
                                            self.h, self.nx, self.ny, math.inf, self.stop)
        return self._top

    def depth_mm(self, centres_frame) -> np.ndarray:
        """(n,) how deep the stock lies inside the cutter's ball at each centre, radially (-inf: none)."""
        c = np.ascontiguousarray(np.asarray(centres_frame, dtype=np.float64).reshape(-1, 3))
        out = np.empty(c.shape[0])
        if c.shape[0]:
            _depth_kernel(self.top(), self.x0, self.y0, self.h, c, self.r, out)
        return out

    def __call__(self, centres_frame) -> np.ndarray:
        return self.depth_mm(centres_frame) > self.max_depth


def semi_flute_mm(config) -> float:
    """The semi-finishing cutter's flute length, mm (``paths.semi_finishing.flute_length_mm``; null: the
    finishing tool's, at least the cutter's radius)."""
    sp = config.paths.semi_finishing
    r = sp.diameter_mm / 2.0
    fl = config.tool.flute_length_mm if sp.flute_length_mm is None else sp.flute_length_mm
    return float(max(fl, r))


def semi_tool(config) -> ToolAssembly:
    """The semi-finishing ball-end cutter held like the finishing one (``tool.*``: the same stick-out,
    holder and gauge length; its shank as wide as its cut), as a :class:`ToolAssembly`."""
    sp = config.paths.semi_finishing
    return config.tool.model_copy(update={"diameter_mm": float(sp.diameter_mm), "flute_length_mm": semi_flute_mm(config),
                                          "shank_diameter_mm": None}).assembly()


def pass_params(fp, sp):
    """The :class:`schemas.params.FinishingParams` the passes are planned with: the finishing's, with the
    scallop, forward step, tolerance, margin and pattern of ``sp`` (:class:`schemas.params.SemiFinishingParams`);
    always 3+2."""
    return fp.model_copy(update={"scallop_mm": float(sp.scallop_mm), "step_mm": sp.step_mm,
                                 "tolerance_mm": float(sp.tolerance_mm),
                                 "margin_mm": fp.margin_mm if sp.margin_mm is None else float(sp.margin_mm),
                                 "pattern": sp.pattern, "mode": "3+2", "area_modes": {}})


@dataclass
class SemiFinishing:
    """One set-up's semi-finishing: ``toolpath`` (ball centres, tip offset the cutter radius; None when
    nothing of the area is left to it), ``passes`` (the passes before the cut and the reduction),
    ``radius_mm`` (the cutter's), ``offset_radius_mm`` (``R'``, the radius the passes were planned
    with), ``min_clearance_mm`` (smallest distance from a scan point to the final moves' ball
    centres: at least ``R' - tolerance_mm``), ``blocked`` (positions cut out, by reason), ``n_arcs``,
    ``guard`` (the guard's outcome on the carried stock, or None), ``allowance_before_mm`` /
    ``allowance_after_mm`` (the stock over the area's points before and after it),
    ``allowance_reached_mm`` (after it, over the points its kept moves reach: ``reached``, (n,) bool over
    the area's points), ``seconds``."""

    toolpath: Toolpath | None
    passes: FinishingPath | None
    radius_mm: float
    offset_radius_mm: float
    tolerance_mm: float
    min_clearance_mm: float = math.inf
    blocked: dict = field(default_factory=dict)
    n_arcs: int = 0
    guard: object = None
    allowance_before_mm: dict | None = None
    allowance_after_mm: dict | None = None
    allowance_reached_mm: dict | None = None
    reached: np.ndarray | None = None
    seconds: dict = field(default_factory=dict)

    @property
    def reached_share(self) -> float:
        """Share of the area's points its kept moves reach (0 when it has none)."""
        return 0.0 if self.reached is None or self.reached.size == 0 else float(self.reached.mean())

    @property
    def gouge_free(self) -> bool:
        """Every final move keeps the cutter at least ``allowance - tolerance`` off the scan."""
        return self.min_clearance_mm >= self.offset_radius_mm - self.tolerance_mm - 1e-12


def plan_semi_finishing(cloud_f: np.ndarray, region_masks, faces, *, sp, fp, tool: ToolAssembly,
                        safe_tip_z_mm: float, max_slope_deg: float, blocked=None, progress=None,
                        passes: FinishingPath | None = None) -> SemiFinishing:
    """The semi-finishing passes of one set-up (module docstring), before the guard.

    ``cloud_f`` (N,3): the scan and the forbidden points in the area frame; ``region_masks``: the
    area's regions (:func:`planning.toolpath.area_paths._region_masks`); ``faces``: the triangles the
    finishing ball rests on, or None; ``sp``: :class:`schemas.params.SemiFinishingParams`; ``fp``: the
    finishing's :class:`schemas.params.FinishingParams` (the leads, links and arcs settings);
    ``tool``: the semi-finishing cutter (:func:`semi_tool`); ``safe_tip_z_mm``: the tool tip's height of
    the finishing's retracts and rapids in the frame (the pass's centres retract to ``safe_tip_z_mm + R'``,
    its tip ``allowance_mm`` above the finishing's, never lower); ``max_slope_deg``: as for the finishing;
    ``blocked``: ``(FinishingPath) -> FinishingPath | None`` the positions the tool may not take cut out
    (:func:`planning.toolpath.safety.guard_finishing` with this tool), or None: not checked;
    ``progress(fraction, message)``; ``passes``: the passes already computed with these arguments (the
    finishing worker's, :class:`planning.toolpath.finishing_worker.FinishingWorker`), or None: computed
    here. An area on which no pass lies gets none (``toolpath`` None), not an error: the finishing
    still runs."""
    from planning.errors import ParameterError
    from planning.toolpath.finishing_worker import binned_cloud, region_passes

    r = float(tool.radius_mm)
    R = r + float(sp.allowance_mm)
    tol = float(sp.tolerance_mm)
    sec = {}
    t0 = time.perf_counter()
    pfp = pass_params(fp, sp)
    if passes is not None:
        fin, binned = passes, binned_cloud(cloud_f, faces, R)
    else:
        try:
            fin, binned = region_passes(cloud_f, region_masks, faces, pfp, R, tol, float(safe_tip_z_mm) + R,
                                        max_slope_deg, progress=None if progress is None else
                                        (lambda f, m="": progress(0.6 * f, f"passes, {m}" if m else "passes")))
        except ParameterError:
            return SemiFinishing(toolpath=None, passes=None, radius_mm=r, offset_radius_mm=R, tolerance_mm=tol)
    # the real cutter's tip is r under the centre (the posts, the guard and the simulation read it there)
    tip = dataclasses.replace(fin.toolpath, tip_offset_mm=r)
    fin = dataclasses.replace(fin, toolpath=tip)
    out = SemiFinishing(toolpath=None, passes=fin, radius_mm=r, offset_radius_mm=R, tolerance_mm=tol)
    sec["passes"] = time.perf_counter() - t0
    if blocked is not None:
        t0 = time.perf_counter()
        if progress is not None:
            progress(0.6, "positions the tool may not take")
        fin, out.blocked = blocked(fin)
        sec["cut_blocked"] = time.perf_counter() - t0
        if fin is None:
            out.seconds = sec
            return out
    t0 = time.perf_counter()
    if progress is not None:
        progress(0.85, "reduction and arcs")
    tp = fin.toolpath
    if fp.arcs:
        tp = fit_arcs(tp, binned, R, tol_mm=tol, reduce_lines=fp.reduce, pass_index=fin.pass_index)
    elif fp.reduce:
        tp = reduce_cl(tp, binned, R, tol_mm=tol, pass_index=fin.pass_index)
    clear = move_clearance(tp, binned, R)
    out.min_clearance_mm = min(float(np.nanmin(clear)) if np.isfinite(clear).any() else R, R)
    out.toolpath, out.passes = tp, fin
    out.n_arcs = int(np.isin(tp.kind, [ARC_CW, ARC_CCW]).sum())
    sec["reduce_arcs"] = time.perf_counter() - t0
    out.seconds = sec
    return out

