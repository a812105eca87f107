"""Per-area tool paths: the stage between the areas and the posts (docs/design.md stage 7; Makki 2010 §4:
each area is machined by 3-axis paths at its set-up's fixed orientation).

For area ``i`` with tool axis ``t_i``:

1. the frame (:func:`planning.toolpath.frames.area_frame`, turned about +Z by
   ``paths.finishing.direction_deg`` when given); the WHOLE cloud and the forbidden points are
   transformed into it (every area is an obstacle of every other);
2. the safe height: the ball-centre height of retracts and rapids, ``R + safe_clearance_mm`` above
   the highest of the cloud (frame z = 0) and of the fixtures whose frame footprint comes within the
   holder's reach of the path window (:func:`obstacle_top_mm`);
3. roughing (when enabled; :mod:`planning.toolpath.roughing`) from a stock box, down to the area's
   lowest point, in a window over the area's footprint (:func:`roughing_window_reach_mm`): the
   tool centre cuts only within that reach of the area's points, the material elsewhere is left to
   the set-ups of the other areas;
4. finishing by ball drop (:func:`planning.toolpath.finishing.finishing_passes`) once per connected
   region of the area (``input_regions``; one region when not given), the regions' paths joined
   in a nearest-next order at the safe height (:func:`join_region_paths`), then CL reduction and
   arc fitting (:mod:`planning.toolpath.reduce`) of the joined path, each gouge-checked;
5. verification (:mod:`planning.toolpath.verify`): the minimal clearance between the final
   finishing moves (lines and arcs) and every cloud point, which must be >= R - tolerance; the
   cutter, shank and holder above the ball at every finishing CL point against the cloud
   (:func:`planning.geometry.collision.cloud_collision_free`) and the fixtures and table
   (:func:`planning.geometry.fixtures.fixture_collision_free`): positions that collide are counted and
   reported (the paths are not changed: an area the holder cannot reach shows up as a warning).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from planning.errors import ParameterError
from planning.geometry.collision import centres_collision_free
from planning.geometry.fixtures import (
    BoxFixture,
    CylinderFixture,
    MeshFixture,
    TableFixture,
    fixture_collision_free,
)
from planning.geometry.tool import ToolAssembly
from planning.geometry.triangles import TriangleDropSurface
from planning.progress import Throttled
from planning.toolpath.balldrop import DropSurface
from planning.toolpath.carried import stock_figures
from planning.toolpath.finishing import FinishingPath, finishing_passes
from planning.toolpath.finishing_worker import (
    FinishingWorker,
    IndexMasks,
    WorkerFailed,
    binned_cloud,
    region_passes,
)
from planning.toolpath.frames import AreaFrame, area_frame
from planning.toolpath.guard import guard_toolpath
from planning.toolpath.moves import ARC_CCW, ARC_CW, FEED, Toolpath, concatenate
from planning.toolpath.reduce import fit_arcs, reduce_cl
from planning.toolpath.roughing import roughing_paths
from planning.toolpath.safety import (
    cutting_positions,
    finished_reach_mm,
    guard_finishing,
    unmachined_points,
)
from planning.toolpath.stock_view import StockView
from planning.toolpath.verify import BinnedCloud, move_clearance

Progress = Callable[[float, str], None]
_log = logging.getLogger(__name__)


@dataclass
class AreaPaths:
    """Everything computed for one area: ``frame``, ``safe_z_mm`` (ball centre, frame), the final
    ``finishing`` toolpath and its ``finishing_info``, ``roughing`` (toolpath or None) and its
    ``roughing_info``, the verification figures and the seconds spent."""

    area: int
    frame: AreaFrame
    safe_z_mm: float
    finishing: Toolpath | None
    finishing_info: FinishingPath | None
    roughing: Toolpath | None = None
    roughing_info: object = None
    radius_mm: float = 0.0
    tolerance_mm: float = 0.0
    min_clearance_mm: float = math.inf
    n_arcs: int = 0
    holder_collisions: int = 0
    fixture_collisions: int = 0
    seconds: dict = field(default_factory=dict)
    roughing_guard: object = None
    finishing_guard: object = None
    blocked: dict = field(default_factory=dict)
    allowance_left: dict | None = None
    handed_in: int = 0                         # points other set-ups left that this one finished
    unmachined: np.ndarray | None = None       # input point indices of the area no kept finishing move reaches
    five_axis: object = None                   # FiveAxisFigures of a simultaneous 5-axis finishing
    five_axis_input: Toolpath | None = None    # the 3-axis passes it was planned from
    five_axis_links: object = None             # its StockLinks (the guard plans the links of its cuts with it)
    five_axis_pass_index: np.ndarray | None = None  # (P,) its pass per point, -1 on links (the C register's routes)
    semi: object = None                        # SemiFinishing between the roughing and the finishing, or None

    @property
    def semi_finishing(self) -> Toolpath | None:
        """The semi-finishing toolpath (None: none), named like ``roughing`` and ``finishing``."""
        return None if self.semi is None else self.semi.toolpath

    @property
    def semi_finishing_guard(self):
        """The guard's outcome of the semi-finishing (None: none or not guarded)."""
        return None if self.semi is None else self.semi.guard

    @property
    def gouge_free(self) -> bool:
        """The final finishing moves keep at least R - tolerance from every cloud point."""
        return self.min_clearance_mm >= self.radius_mm - self.tolerance_mm - 1e-12


def rotate_frame(frame: AreaFrame, angle_deg: float) -> AreaFrame:
    """The frame turned by ``angle_deg`` about its +Z axis (passes along the new X)."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    x, y, z = frame.rotation
    return AreaFrame(rotation=np.stack([c * x + s * y, -s * x + c * y, z]), origin_mm=frame.origin_mm.copy())


def _fixture_points(f) -> np.ndarray:
    """Points whose convex hull bounds a finite fixture (part frame, mm)."""
    if isinstance(f, BoxFixture):
        lo, hi = np.asarray(f.min_mm), np.asarray(f.max_mm)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        c = f.centre
        return c + (corners - c) @ f.rotation_matrix.T
    if isinstance(f, CylinderFixture):
        ax = np.asarray(f.axis)
        ref = np.array([1.0, 0.0, 0.0]) if abs(ax[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(ax, ref)
        u /= np.linalg.norm(u)
        v = np.cross(ax, u)
        # a polygon circumscribing the rim circle (radius r / cos(pi / 32)) contains the cylinder
        t = np.linspace(0, 2 * np.pi, 32, endpoint=False)
        r = f.radius_mm / math.cos(math.pi / 32)
        rim = r * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)
        base = np.asarray(f.base_mm)
        return np.concatenate([base + rim, base + f.height_mm * ax + rim])
    if isinstance(f, MeshFixture):
        return np.asarray(f.vertices)
    raise TypeError(f"no bounding points for {type(f).__name__}")


def obstacle_top_mm(frame: AreaFrame, fixtures: Sequence, xy_lo, xy_hi, reach_mm: float) -> float:
    """The highest frame z (mm) of the fixtures and the table over the window
    ``[xy_lo, xy_hi]`` (frame x, y) grown by ``reach_mm`` (the holder's largest radius): the tool
    moving at a height above it, over that window, cannot touch them. Finite fixtures are bounded by
    their corners / circumscribed rims / vertices; the table (a plane) by its height at the window's
    corners. ``-inf`` when nothing is there."""
    lo = np.asarray(xy_lo, dtype=np.float64) - reach_mm
    hi = np.asarray(xy_hi, dtype=np.float64) + reach_mm
    top = -math.inf
    for f in fixtures:
        if isinstance(f, TableFixture):
            corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
            # table plane in the frame: points q with (R^T q + o)_z = z_table
            n = frame.rotation[:, 2]                     # part z expressed in frame coordinates
            d = f.z_mm - frame.origin_mm[2]
            if abs(n[2]) < 1e-12:
                continue                                 # a vertical table plane: no height to speak of
            z = (d - corners @ n[:2]) / n[2]
            if n[2] > 0:                                 # frame +z points away from the table: material below
                top = max(top, float(z.max()))
            continue
        qq = frame.to_frame(_fixture_points(f))
        # a solid whose frame bounding box meets the window counts with its highest point
        if np.all(qq[:, :2].max(axis=0) >= lo) and np.all(qq[:, :2].min(axis=0) <= hi):
            top = max(top, float(qq[:, 2].max()))
    return top


class _PathsProgress:
    """Progress of the paths stage (issue 17 item 3): the area being done (``n_done`` of ``k``) and,
    inside it, its steps by a fixed share of the area (:data:`STEPS`), each step's own fraction
    (levels, passes, chunks, repair rounds) mapped into its share. Reports never go back, and
    calls within ``min_interval_s`` of the last are dropped unless a step starts."""

    #: share of an area's time each step starts at and ends at (rough, from the femur-like plan), in
    #: the order the steps run. ``cut_blocked`` (3+2: the blocked CL points cut out) and ``five_axis``
    #: (simultaneous 5-axis: the axes set on the dense CL points, which does its own cutting out) are
    #: the two kinds of the same step and share its place: an area runs one of them. Every
    #: ``step("...")`` name of :mod:`planning.toolpath` must be here (tests/test_user_paths.py); a
    #: name that is not is still reported, with no share of its own (:meth:`step`), never an error.
    STEPS: ClassVar[dict[str, tuple[float, float]]] = {
        "frame": (0.0, 0.02), "roughing": (0.02, 0.2), "guard_roughing": (0.2, 0.3),
        "semi_finishing": (0.3, 0.3), "finishing": (0.3, 0.55), "cut_blocked": (0.55, 0.75), "five_axis": (0.55, 0.75),
        "reduce_arcs": (0.75, 0.85), "verify": (0.85, 0.87), "collisions": (0.87, 0.89),
        "guard_finishing": (0.89, 1.0)}

    def __init__(self, progress: Progress | None, k: int, min_interval_s: float = 0.1):
        self.progress, self.k = progress, max(int(k), 1)
        self.n_done, self.area = 0, -1
        self._emit = Throttled(progress, min_interval_s)
        self._reached = 0.0                    # the share of the current area its latest step started at
        self._unknown: set[str] = set()

    @property
    def min_interval_s(self) -> float:
        return self._emit.min_interval_s

    @min_interval_s.setter
    def min_interval_s(self, seconds: float) -> None:
        self._emit.min_interval_s = float(seconds)

    def start_area(self, n_done: int, area: int) -> None:
        self.n_done, self.area = int(n_done), int(area)
        self._reached = 0.0

    def _share(self, name: str) -> tuple[float, float]:
        """The (start, end) share of the area of step ``name``, never before where the area's steps
        so far reached (so its fractions never go back within the area, whatever the order). A name
        not in :data:`STEPS` gets no span of its own (start = end = where the area is), logged once."""
        span = self.STEPS.get(name)
        if span is None:
            if name not in self._unknown:
                self._unknown.add(name)
                _log.warning("paths progress: step %r has no share in _PathsProgress.STEPS; "
                             "reported without one", name)
            span = (self._reached, self._reached)
        lo = max(span[0], self._reached)
        hi = max(span[1], lo)
        self._reached = lo
        return lo, hi

    def step(self, name: str) -> Callable[[float, str], None] | None:
        """Announce step ``name`` of the current area; return the callback of its own progress
        (fraction of the step in [0, 1], message), or None when nobody listens. A step name missing
        from :data:`STEPS` never stops a plan (:meth:`_share`)."""
        if self.progress is None:
            return None
        lo, hi = self._share(name)
        head = f"area {self.area} ({self.n_done + 1}/{self.k}): {name.replace('_', ' ')}"
        self._emit((self.n_done + lo) / self.k, head, force=True)

        def report(fraction: float, message: str = "") -> None:
            f = max(0.0, min(1.0, float(fraction)))
            self._emit((self.n_done + lo + (hi - lo) * f) / self.k, f"{head}, {message}" if message else head,
                       force=False)
        return report

    def area_done(self) -> None:
        if self.progress is not None:
            self._emit((self.n_done + 1) / self.k, f"area {self.area}: paths done", force=True)


def _count_arcs(tp: Toolpath) -> int:
    return int(np.isin(tp.kind, [ARC_CW, ARC_CCW]).sum())


def area_toolpaths(points: np.ndarray, input_labels: np.ndarray, axes: np.ndarray, *, tool: ToolAssembly,
                   paths_params, fixtures: Sequence = (), forbidden: np.ndarray | None = None,
                   max_slope_deg: float = 87.0, input_regions: np.ndarray | None = None,
                   progress: Progress | None = None, carried=None,
                   faces: np.ndarray | None = None, cone_deg=(10.0, 80.0),
                   semi_tool: ToolAssembly | None = None) -> list[AreaPaths]:
    """Tool paths for every area (see the module docstring).

    ``points`` (N,3) mm: the whole cloud (part frame); ``input_labels`` (N,): the area of every
    point; ``axes`` (k,3): the areas' unit tool axes; ``tool``: the finishing ball cutter and its
    holder; ``paths_params``: :class:`schemas.params.PathsParams`; ``fixtures``: fixture solids and
    the table (part frame); ``forbidden`` (K,3): forbidden points (obstacles like the cloud);
    ``max_slope_deg``: the steepest surface an area holds (the tool cone's upper angle), which
    bounds how short the adaptive side step gets; ``input_regions`` (N,) int: the connected region
    of every point within its area (0 the largest, 1 the next, ...; any value where the label is
    -1), each finished on its own; None: every area is one region. ``carried``: a
    :class:`planning.toolpath.carried.CarriedStock` (issue 16): the areas are done in its order on
    its stock (rest roughing from what the set-ups before left; every operation guarded by
    :func:`planning.toolpath.guard.guard_toolpath`; finishing CL points where the assembly would
    touch the cloud, the stock, a fixture, go below the part's underside or leave the travel cut
    out); None: every area on its own from a stock box, nothing guarded (the collisions only counted).
    ``faces`` (T,3) int: triangles through ``points`` (indices into them) the finishing ball rests on
    and its gouge clearance is measured to, besides the points (:mod:`planning.toolpath.surface`);
    None: the points only. ``cone_deg``: the tool cone (``visibility.cone_deg``) the axes of
    simultaneous 5-axis finishing keep to (``paths.finishing.mode`` / ``area_modes`` "5axis":
    :mod:`planning.toolpath.fiveaxis.finishing` on the reduced path, no arcs). ``semi_tool``: the
    semi-finishing cutter (:func:`planning.toolpath.semi_finishing.semi_tool`) when
    ``paths.semi_finishing`` is enabled: each 3+2 set-up gets a semi-finishing pass after its roughing
    (:mod:`planning.toolpath.semi_finishing`; with ``carried``, cut and guarded on the stock like the
    finishing, with ``carried.semi_shape``). The result lists the areas in the order they were done.
    """
    fp = paths_params.finishing
    forbidden = np.zeros((0, 3)) if forbidden is None else np.asarray(forbidden, dtype=np.float64).reshape(-1, 3)
    obstacles = np.concatenate([points, forbidden]) if forbidden.size else points
    regions = _check_regions(input_regions, input_labels)
    k = axes.shape[0]
    order = list(range(k)) if carried is None else list(carried.order)
    prog = _PathsProgress(progress, len(order))
    # the finishing passes of each set-up in a second process while this one roughs it (finishing_worker)
    worker = FinishingWorker.open(obstacles.shape[0]) if fp.enabled else None
    try:
        return _areas_in_order(points, input_labels, axes, tool, paths_params, fixtures, obstacles, max_slope_deg,
                               regions, carried, faces, cone_deg, order, prog, worker, semi_tool)
    finally:
        if worker is not None:
            worker.close()


def _areas_in_order(points, input_labels, axes, tool, paths_params, fixtures, obstacles, max_slope_deg, regions,
                    carried, faces, cone_deg, order, prog, worker, semi_tool=None):
    """The loop of :func:`area_toolpaths` over the areas in ``order`` (its arguments, the progress
    ``prog`` and the finishing ``worker`` or None)."""
    fp = paths_params.finishing
    R = float(tool.radius_mm)
    tol = float(fp.tolerance_mm)
    reach = max([s.radius_mm for s in tool.segments] + [R])
    out: list[AreaPaths] = []
    pool = np.zeros(points.shape[0], dtype=bool)       # unmachined by a set-up before: handed on
    for n_done, i in enumerate(order):
        sec: dict[str, float] = {}
        t0 = time.perf_counter()
        mine = input_labels == i
        if not mine.any():
            continue
        prog.start_area(n_done, i)
        prog.step("frame")
        extra = np.zeros_like(mine)
        if carried is not None and carried.visible is not None and pool.any():
            extra = pool & carried.visible[:, i] & ~mine
        frame, cloud_f, area_f, top = _frame_and_top(points, mine, axes[i], obstacles, fixtures, fp, R, reach)
        stock_f = None
        if carried is not None:
            # the stock left by the set-ups before, in this frame: its top raises the safe height
            stock_f = frame.to_frame(carried.stock.boundary_points())
            if stock_f.shape[0]:
                top = max(top, float(stock_f[:, 2].max()))
        safe = top + paths_params.safe_clearance_mm + R
        sec["frame"] = time.perf_counter() - t0
        ap = AreaPaths(area=i, frame=frame, safe_z_mm=safe, finishing=None, finishing_info=None, radius_mm=R,
                       tolerance_mm=tol)
        masks, job = None, None
        five = fp.area_modes.get(i, fp.mode) == "5axis"
        semi = _SemiJob.of(semi_tool, paths_params, mine, regions, cloud_f.shape[0], safe - R) \
            if (semi_tool is not None and fp.enabled and not five) else None
        if fp.enabled:
            # and the points set-ups before left that this one sees, as one more region
            masks = _region_masks(mine, regions, cloud_f.shape[0], extra=extra)
            # computed there while this process roughs (with the cloud's part of their check; the
            # semi-finishing's passes first)
            check = None if (carried is None or five) else (frame, axes[i], tool, obstacles)
            if worker is not None and worker.submit(cloud_f, masks, faces, fp, R, tol, safe, max_slope_deg, check,
                                                    semi=None if semi is None else semi.worker_args()):
                job = worker
        _add_roughing(ap, cloud_f, area_f, top, paths_params, sec, roughing_window_reach_mm(paths_params, tool),
                      stock_f=stock_f, carried=carried, progress=prog.step("roughing"))
        if ap.roughing is not None and ap.roughing.n_moves == 0:
            ap.roughing = None                 # rest roughing: nothing left above this area
        if carried is not None and ap.roughing is not None:
            t0 = time.perf_counter()
            _guard_roughing(ap, carried, top + paths_params.roughing.stock_margin_mm + paths_params.safe_clearance_mm,
                            progress=prog.step("guard_roughing"))
            sec["guard_roughing"] = time.perf_counter() - t0
        if semi is not None:
            _add_semi(ap, cloud_f, mine, semi, faces, paths_params, semi_tool, max_slope_deg, carried, obstacles,
                      axes[i], fixtures, area_f, points, sec, prog, job)
        if carried is not None and carried.normals is not None:
            # issue 16 item 1: the stock the finishing meets over this area (roughing allowance
            # where roughing reached; more where the roughing tool or its holder could not go)
            left = carried.stock_over(points[mine], carried.normals[mine])
            ap.allowance_left = stock_figures(left)
            if ap.semi is not None:
                # what the semi-finishing left: over the area, and over the points it reaches
                ap.semi.allowance_after_mm = ap.allowance_left
                if ap.semi.reached is not None and ap.semi.reached.any():
                    ap.semi.allowance_reached_mm = stock_figures(left[ap.semi.reached])
        if fp.enabled:
            _add_finishing(ap, cloud_f, masks, fp, max_slope_deg, sec, faces=faces, job=job,
                           blocked=None if (carried is None or five) else
                           (lambda fin, prg, known: _cut_blocked(ap, fin, carried, obstacles, axes[i], tool, fixtures,
                                                                      area_f, fp, progress=prg, cloud_known=known)),
                           progress=prog, five_axis=None if not five else
                           _FiveAxisArea(obstacles, tool, cone_deg, carried, fp))
            # cutter, shank and holder above the ball at every CL point of the cut
            t0 = time.perf_counter()
            prog.step("collisions")
            _count_collisions(ap, obstacles, axes[i], tool, fixtures)
            sec["collisions"] = time.perf_counter() - t0
            if carried is not None and ap.finishing is not None:
                t0 = time.perf_counter()
                _guard_finishing(ap, carried, area_f, fp, progress=prog.step("guard_finishing"))
                sec["guard_finishing"] = time.perf_counter() - t0
            if five and carried is not None:
                # what the 3+2 ball-drop passes finish and no kept 5-axis move does (after the guard), as
                # a mask over the area's points (inner corners no ball reaches are not the cut's doing)
                fa = ap.five_axis_input
                before = (_still_unmachined(ap, area_f, fp, fa) if fa is not None
                          else np.ones(area_f.shape[0], dtype=bool))
                ap.unmachined = _still_unmachined(ap, area_f, fp) & ~before
            if carried is not None and ap.unmachined is not None:
                ap.unmachined = np.flatnonzero(mine)[ap.unmachined]       # input point indices
            if carried is not None:
                pool[ap.unmachined if ap.unmachined is not None else np.zeros(0, np.int64)] = True
                if extra.any():
                    left = _still_unmachined(ap, cloud_f[:points.shape[0]][extra], fp)
                    ap.handed_in = int(extra.sum() - left.sum())
                    pool[np.flatnonzero(extra)[~left]] = False
        ap.seconds = {k2: round(v, 4) for k2, v in sec.items()}
        out.append(ap)
        prog.area_done()
    if carried is not None:
        # what no set-up finished, by the area it belongs to
        for ap in out:
            ap.unmachined = np.flatnonzero(pool & (input_labels == ap.area))
    return out


def _still_unmachined(ap: AreaPaths, pts_f: np.ndarray, fp, toolpath: Toolpath | None = None) -> np.ndarray:
    """(n,) bool: the points ``pts_f`` (area frame, n,3) that no kept cutting move of ``ap``'s finishing
    (or of ``toolpath``) reaches (:func:`planning.toolpath.safety.unmachined_points` on the moves
    sampled every R / 4)."""
    tp = ap.finishing if toolpath is None else toolpath
    if tp is None or pts_f.shape[0] == 0:
        return np.ones(pts_f.shape[0], dtype=bool)
    spacing = ap.radius_mm / 4.0
    kept = cutting_positions(tp, spacing)
    reach = finished_reach_mm(ap.radius_mm, tol_mm=fp.tolerance_mm, scallop_mm=fp.scallop_mm, spacing_mm=spacing)
    return unmachined_points(pts_f, kept, ap.radius_mm, reach)


def roughing_window_reach_mm(paths_params, tool: ToolAssembly) -> float:
    """How far (mm, frame x, y) from the area's points the roughing tool centre may cut (step 3):
    the finishing ball's contact lies in the band ``margin_mm`` around the area, its centre within
    R of the contact, and the cutter, shank and holder within their largest radius of that centre;
    a roughing tool centre clears the material within its radius Rt. So
    ``margin + R + max segment radius + Rt``: everywhere the finishing tool can be, the material
    above the area has been roughed (or lies where a centre cannot go, beside the part)."""
    fp, rp = paths_params.finishing, paths_params.roughing
    R = float(tool.radius_mm)
    widest = max([s.radius_mm for s in tool.segments] + [R])
    return float(fp.margin_mm) + R + float(widest) + rp.diameter_mm / 2.0


def _check_regions(input_regions, input_labels) -> np.ndarray | None:
    """``input_regions`` as an (N,) int64 array (None stays None); every labelled point needs a
    region id >= 0."""
    if input_regions is None:
        return None
    regions = np.asarray(input_regions).reshape(-1)
    labels = np.asarray(input_labels).reshape(-1)
    if regions.shape != labels.shape or not np.issubdtype(regions.dtype, np.integer):
        raise ParameterError(f"input_regions must be ({labels.size},) integers like input_labels")
    if np.any(regions[labels >= 0] < 0):
        raise ParameterError("input_regions: every point of an area needs a region id >= 0")
    return regions.astype(np.int64, copy=False)


def _region_masks(mine: np.ndarray, regions: np.ndarray | None, n_obstacles: int,
                  extra: np.ndarray | None = None) -> IndexMasks:
    """(n_obstacles,) bool masks over the obstacles (cloud first, then the forbidden points) of the
    area's points ``mine`` (N,), one per region id present, by increasing id (the area's largest
    region first); one mask of the whole area when ``regions`` is None; then, where ``extra`` (N,)
    has any point, one mask of those. Kept as point indices (:class:`IndexMasks`)."""
    idx = np.flatnonzero(mine)
    if regions is None:
        parts = [idx]
    else:
        lab = regions[idx]
        order = np.argsort(lab, kind="stable")            # by region id, each region's points in cloud order
        _, first = np.unique(lab[order], return_index=True)
        parts = np.split(idx[order], first[1:])
    if extra is not None and extra.any():
        parts.append(np.flatnonzero(extra))
    return IndexMasks(parts, n_obstacles)


def _frame_and_top(points, mine, axis, obstacles, fixtures, fp, R: float, reach: float):
    """Step 1 and the height of step 2 for the area of the points ``mine``: its frame, the
    obstacles (cloud, then forbidden points) and the area's points in that frame, and the highest
    frame z (mm) of the cloud (at least 0) and of the fixtures near the path window."""
    frame = area_frame(axis, points, points[mine])
    if fp.direction_deg is not None:
        frame = rotate_frame(frame, fp.direction_deg)
    cloud_f = frame.to_frame(obstacles)
    area_f = cloud_f[:points.shape[0]][mine]
    lo = area_f[:, :2].min(axis=0) - fp.margin_mm - R
    hi = area_f[:, :2].max(axis=0) + fp.margin_mm + R
    fix_top = obstacle_top_mm(frame, fixtures, lo, hi, reach)
    top = max(0.0, float(cloud_f[:, 2].max()), fix_top)
    return frame, cloud_f, area_f, top


def _add_roughing(ap: AreaPaths, cloud_f, area_f, top: float, paths_params, sec: dict, window_reach: float,
                  stock_f=None, carried=None, progress=None) -> None:
    """Step 3: roughing (when enabled and there is stock above the area's floor) into ``ap``, the
    tool centre within ``window_reach`` mm of the area's points (:func:`roughing_window_reach_mm`).
    With ``carried``, rest roughing: only the material of the carried stock (its boundary points
    ``stock_f`` in the area frame) is cut."""
    rp = paths_params.roughing
    safe_tip_z = top + rp.stock_margin_mm + paths_params.safe_clearance_mm
    floor = float(area_f[:, 2].min()) + rp.stock_allowance_mm
    stock_top = float(cloud_f[:, 2].max()) + rp.stock_margin_mm
    if stock_f is not None:
        stock_top = float(stock_f[:, 2].max()) if stock_f.shape[0] else -math.inf
    if rp.enabled and floor < stock_top:
        t0 = time.perf_counter()
        # with the carried stock: rest roughing, and the end mill's holder kept out of the stock and the part
        view = None if carried is None else StockView(carried.stock, ap.frame, carried.roughing_shape,
                                                      obstacles=carried.obstacles)
        rest = {} if carried is None else {"stock_points_mm": stock_f, "stock_spacing_mm": carried.resolution_mm,
                                           "holder_pieces": carried.roughing_shape.pieces,
                                           "stock_view": view,
                                           "travel_cells": None if carried.machines is None else
                                           _travel_cells(carried.machines[ap.area], ap.frame,
                                                         carried.roughing_shape.gauge_length_mm, safe_tip_z),
                                           "rapid_clearance_mm": carried.rapid_clearance_mm}
        rr = roughing_paths(cloud_f, tool_radius_mm=rp.diameter_mm / 2.0,
                            corner_radius_mm=rp.corner_radius_mm, step_down_mm=rp.step_down_mm,
                            stock_allowance_mm=rp.stock_allowance_mm, stock_margin_mm=rp.stock_margin_mm,
                            stepover_mm=rp.stepover_mm, pattern=rp.pattern, floor_z_mm=floor,
                            safe_z_mm=safe_tip_z,
                            window_xy_mm=area_f[:, :2] if rp.window else None, window_reach_mm=window_reach, **rest,
                            **_entry_args(rp), progress=None if progress is None else
                            (lambda done, n: progress(done / max(n, 1), f"level {done}/{n}")))
        ap.roughing, ap.roughing_info = rr.toolpath, rr
        sec["roughing"] = time.perf_counter() - t0


def _travel_cells(machine, frame: AreaFrame, gauge_mm: float, lift_z: float):
    """The ``travel_cells`` of :func:`planning.toolpath.roughing.roughing_paths`: per raster cell,
    whether the roughing tool's tip at the cell's centre (frame, at height z) and straight above it
    at ``lift_z`` (the retract height) is within ``machine``'s travel
    (:meth:`planning.toolpath.guard.SetupMachine.travel_ok`). The set-up's rotary position is fixed,
    so the controlled point is an affine function of the tip: it is evaluated at four points and
    extended over the raster."""
    from planning.toolpath.guard import TRAVEL_SLACK_MM

    base = frame.to_part(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]))
    m = machine.model.machine_from_tip(base, machine.angles_deg, gauge_mm)
    m0, dx, dy, dz = m[0], m[1] - m[0], m[2] - m[0], m[3] - m[0]
    limits = machine.model.profile.linear_limits_mm

    def ok(x0, y0, h, nx, ny, z):
        x = x0 + (np.arange(nx) + 0.5) * h
        y = y0 + (np.arange(ny) + 0.5) * h
        out = np.ones((nx, ny), dtype=bool)
        if nx == 0 or ny == 0:
            return out
        # affine in the cell centre: within the limits at the raster's four corner cells (both heights),
        # within them over the whole raster (the usual case: nothing to compute per cell)
        cx = np.array([x[0], x[-1], x[0], x[-1]])
        cy = np.array([y[0], y[0], y[-1], y[-1]])
        inside = True
        for i, (lo, hi) in enumerate(limits):
            for zz in (z, max(z, lift_z)):
                v = cx * dx[i] + cy * dy[i] + m0[i] + zz * dz[i]
                inside = inside and bool(np.all((v >= lo - TRAVEL_SLACK_MM) & (v <= hi + TRAVEL_SLACK_MM)))
        if inside:
            return out
        for i, (lo, hi) in enumerate(limits):
            base_i = x[:, None] * dx[i] + y[None, :] * dy[i] + m0[i]
            for zz in (z, max(z, lift_z)):
                v = base_i + zz * dz[i]
                out &= (v >= lo - TRAVEL_SLACK_MM) & (v <= hi + TRAVEL_SLACK_MM)
        return out
    return ok


def _entry_args(rp) -> dict:
    """The roughing entry parameters (helix / ramp; issue 16 item 2) as :func:`roughing_paths` takes them."""
    return {"entry": rp.entry, "entry_angle_deg": rp.entry_angle_deg, "entry_diameter_mm": rp.entry_diameter_mm,
            "ramp_length_mm": rp.ramp_length_mm}


def _guard_roughing(ap: AreaPaths, carried, safe_tip_z: float, progress: Progress | None = None) -> None:
    """The roughing of ``ap`` run on the carried stock (:func:`planning.toolpath.guard.guard_toolpath`);
    the stock it leaves is carried on."""
    g = guard_toolpath(ap.roughing, ap.frame, carried.roughing_shape, carried.stock, carried.obstacles,
                       None if carried.machines is None else carried.machines[ap.area], safe_z_mm=safe_tip_z,
                       rapid_clearance_mm=carried.rapid_clearance_mm, progress=progress)
    ap.roughing, ap.roughing_guard = (g.toolpath if g.toolpath.n_moves else None), g
    carried.stock = g.stock


@dataclass
class _SemiJob:
    """What a set-up's semi-finishing passes are planned from (known when the set-up starts, so the
    finishing worker can compute them while this process roughs): the area's region masks, the passes'
    parameters (:func:`planning.toolpath.semi_finishing.pass_params`), the radius ``R'`` they are planned
    with, their tolerance and the tool tip's safe height (frame z, mm)."""

    masks: IndexMasks
    fp: object
    radius_mm: float
    tol_mm: float
    safe_tip_z_mm: float

    @classmethod
    def of(cls, tool: ToolAssembly, paths_params, mine, regions, n_obstacles: int, safe_tip_z_mm: float) -> _SemiJob:
        from planning.toolpath.semi_finishing import pass_params

        sp = paths_params.semi_finishing
        return cls(masks=_region_masks(mine, regions, n_obstacles), fp=pass_params(paths_params.finishing, sp),
                   radius_mm=float(tool.radius_mm) + float(sp.allowance_mm), tol_mm=float(sp.tolerance_mm),
                   safe_tip_z_mm=float(safe_tip_z_mm))

    def worker_args(self) -> tuple:
        """``FinishingWorker.submit``'s ``semi``: (masks, fp, R', tol, the ball-centre safe height)."""
        return (self.masks, self.fp, self.radius_mm, self.tol_mm, self.safe_tip_z_mm + self.radius_mm)


def _add_semi(ap: AreaPaths, cloud_f, mine, job_semi: _SemiJob, faces, paths_params, tool: ToolAssembly,
              max_slope_deg: float, carried, obstacles, axis, fixtures, area_f, points, sec: dict,
              prog: _PathsProgress, job=None) -> None:
    """The semi-finishing of ``ap``'s set-up into ``ap.semi`` (:mod:`planning.toolpath.semi_finishing`):
    planned on the area's regions (its passes from the finishing ``job`` when it computed them), the
    positions its shank, holder, depth of cut or travel forbid cut out on the carried stock, then guarded
    on it (the stock it leaves is carried on to the finishing)."""
    from planning.toolpath.semi_finishing import DepthLimit, plan_semi_finishing

    sp, fp = paths_params.semi_finishing, paths_params.finishing
    t0 = time.perf_counter()
    report = prog.step("semi_finishing")
    safe_tip = job_semi.safe_tip_z_mm
    R_off = job_semi.radius_mm
    passes = None
    if job is not None:
        try:
            passes = job.semi_passes(report)
        except WorkerFailed as e:
            _log.warning("finishing worker failed on the semi-finishing passes (%s): computed in this process", e)
        except ParameterError:
            pass                               # no pass lies on the area: found again here, and none planned
    before = blocked = machine = None
    if carried is not None:
        if carried.normals is not None:
            before = stock_figures(carried.stock_over(points[mine], carried.normals[mine]))
        shape = carried.semi_shape
        machine = None if carried.machines is None else carried.machines[ap.area]
        travel = None if machine is None else (lambda tips: machine.travel_ok(tips, shape.gauge_length_mm))
        rp = paths_params.roughing
        max_depth = sp.max_depth_mm if sp.max_depth_mm is not None else (
            rp.step_down_mm + rp.stock_allowance_mm + carried.resolution_mm if rp.enabled else None)
        depth = None
        if max_depth is not None:
            grow = float(fp.margin_mm if sp.margin_mm is None else sp.margin_mm) + R_off + float(tool.radius_mm) + 1.0
            depth = DepthLimit(carried.stock, ap.frame, area_f[:, :2].min(axis=0) - grow,
                               area_f[:, :2].max(axis=0) + grow, float(tool.radius_mm), float(max_depth),
                               float(area_f[:, 2].min()) - 1.0)

        def blocked(fin):
            out, figs = guard_finishing(fin, ap.frame, axis, tool=tool, obstacles_part=obstacles, area_points_frame=area_f,
                                safe_z_mm=safe_tip + R_off, fixtures=fixtures, stock=carried.stock, stock_shape=shape,
                                travel_ok=travel, floor_z_part_mm=carried.footprint, tol_mm=sp.tolerance_mm,
                                scallop_mm=sp.scallop_mm, step_mm=sp.step_mm, depth=depth)
            return out, dict(figs.blocked)
    semi = plan_semi_finishing(cloud_f, job_semi.masks, faces, sp=sp, fp=fp, tool=tool, safe_tip_z_mm=safe_tip,
                               max_slope_deg=max_slope_deg, blocked=blocked, progress=report, passes=passes)
    semi.allowance_before_mm = before
    if carried is not None and semi.toolpath is not None and semi.toolpath.n_moves:
        g = guard_toolpath(semi.toolpath, ap.frame, carried.semi_shape, carried.stock, carried.obstacles, machine,
                           safe_z_mm=safe_tip + R_off, rapid_clearance_mm=carried.rapid_clearance_mm)
        semi.toolpath, semi.guard = (g.toolpath if g.toolpath.n_moves else None), g
        carried.stock = g.stock
    if semi.toolpath is not None:
        # the area's points its kept moves reach (the ball of radius R' within the scallop, the tolerance and
        # the sampling's slack): the stock it leaves over them is issue 31 item 3's measure (read with the
        # area's, after this step)
        spacing = float(tool.radius_mm) / 4.0
        reach = finished_reach_mm(R_off, tol_mm=sp.tolerance_mm, scallop_mm=sp.scallop_mm, spacing_mm=spacing)
        semi.reached = ~unmachined_points(area_f, cutting_positions(semi.toolpath, spacing), R_off, reach)
    ap.semi = semi
    sec["semi_finishing"] = time.perf_counter() - t0


def _guard_finishing(ap: AreaPaths, carried, area_f, fp, progress: Progress | None = None) -> None:
    """The final finishing moves of ``ap`` run on the carried stock (the safety net after the CL
    cut of :func:`_cut_blocked`); the stock they leave is carried on, and the area's points that no
    kept finishing move reaches are the unmachined ones. A 5-axis path's travel was checked per
    position with its own rotary solution (:class:`planning.toolpath.fiveaxis.finishing.Admissible`),
    not at the set-up's fixed angles."""
    five = ap.finishing.axis is not None
    links = getattr(ap, "five_axis_links", None) if five else None
    relink = None if links is None else links.relink
    # the passes of a 5-axis path: the relinking after a cut routes the links where C must turn back
    # through the safe height again (without them it could not tell a link from a pass, and the routes
    # it replanned lower were lost: the slot from two set-ups wound C to -5,878 degrees)
    pi = ap.five_axis_pass_index if five else None
    if pi is not None and pi.shape[0] != ap.finishing.n_moves:
        raise AssertionError(f"area {ap.area}: the 5-axis pass index has {pi.shape[0]} points, "
                             f"the finishing {ap.finishing.n_moves}")
    g = guard_toolpath(ap.finishing, ap.frame, carried.finishing_shape, carried.stock, carried.obstacles,
                       None if (carried.machines is None or five) else carried.machines[ap.area], safe_z_mm=ap.safe_z_mm,
                       pass_index=pi, rapid_clearance_mm=carried.rapid_clearance_mm, progress=progress, relink=relink,
                       moves=_program_moves(ap, carried) if five else None)
    ap.finishing, ap.finishing_guard = (g.toolpath if g.toolpath.n_moves else None), g
    if five:
        ap.five_axis_pass_index = g.pass_index if g.toolpath.n_moves else None
    if links is not None and ap.five_axis is not None:
        ap.five_axis.links = links.figures.as_dict()          # with the links of the guard's cuts
    carried.stock = g.stock


def _program_moves(ap: AreaPaths, carried):
    """``(toolpath, frame) -> PartMoves``: a 5-axis finishing path's moves as the area's LinuxCNC
    program runs them (:func:`planning.toolpath.fiveaxis.program_moves.program_part_moves`), so that
    the guard runs on the stock what the verification will; None without the machine or the plan's
    parameters, or when the verification reads the ISO programs (TCP: the tip straight between the
    points, not mirrored yet): the guard then runs the planned moves (:func:`planning.toolpath.guard.part_moves`)."""
    cfg = getattr(carried, "config", None)
    if cfg is None or carried.machines is None:
        return None
    from planning.simulate.verify import choose_dialect

    if choose_dialect({f"area.{d}.nc": "" for d in cfg.post.dialects}, cfg.simulate.dialect) != "linuxcnc":
        return None
    from planning.post.programs import area_post_options, five_axis_operation
    from planning.toolpath.fiveaxis.program_moves import program_part_moves

    model = carried.machines[ap.area].model
    options = area_post_options(cfg, ap.area, ap.safe_z_mm)
    gauge = carried.finishing_shape.gauge_length_mm
    return lambda tp, frame: program_part_moves(five_axis_operation(tp, frame, cfg, gauge, ap.safe_z_mm),
                                                profile=model.profile, placement_mm=model.placement, options=options)


def _cut_blocked(ap: AreaPaths, fin: FinishingPath, carried, obstacles, axis, tool: ToolAssembly, fixtures,
                 area_f, fp, progress: Progress | None = None, cloud_known=None) -> FinishingPath:
    """Issue 16 item 3 on the dense finishing CL points, before reduction
    (:func:`planning.toolpath.safety.guard_finishing`): the points (and the insides of the moves)
    where the cutter, shank or holder would meet the cloud, the carried stock, a fixture or the
    table, where the ball would cut below the part's underside inside its footprint, or that the
    machine cannot reach are cut out of the passes, which are linked again through the safe height;
    the area's points only they finished are the unmachined ones."""
    machine = None if carried.machines is None else carried.machines[ap.area]
    travel = None
    if machine is not None:
        gauge = carried.finishing_shape.gauge_length_mm
        travel = lambda tips: machine.travel_ok(tips, gauge)
    out, figs = guard_finishing(fin, ap.frame, axis, tool=tool, obstacles_part=obstacles, area_points_frame=area_f,
                                safe_z_mm=ap.safe_z_mm, fixtures=fixtures, stock=carried.stock,
                                stock_shape=carried.finishing_shape, travel_ok=travel,
                                floor_z_part_mm=carried.footprint, tol_mm=fp.tolerance_mm, scallop_mm=fp.scallop_mm,
                                step_mm=fp.step_mm, progress=progress, cloud_known=cloud_known)
    ap.blocked = dict(figs.blocked)
    ap.unmachined = figs.unmachined
    if out is None:                            # the set-up cannot finish any of its area
        ap.unmachined = np.ones(area_f.shape[0], dtype=bool)
    return out


@dataclass
class _FiveAxisArea:
    """What the 5-axis step of :func:`_add_finishing` needs beyond the 3+2 finishing: the obstacles
    (part frame), the tool assembly, the tool cone, the carried stock (its set-up machines and the
    part's footprint; None: travel and floor unchecked) and the finishing parameters."""

    obstacles: np.ndarray
    tool: ToolAssembly
    cone_deg: tuple
    carried: object
    fp: object
    figures: object = None

    def run(self, ap: AreaPaths, tp: Toolpath, pass_index, cloud_f) -> Toolpath:
        from planning.toolpath.fiveaxis.finishing import Admissible, five_axis_path

        machine = gauge = floor = stock_f = None
        if self.carried is not None:
            floor = self.carried.footprint
            stock_f = ap.frame.to_frame(self.carried.stock.boundary_points())
            if self.carried.machines is not None:
                machine = self.carried.machines[ap.area].model
                gauge = self.carried.finishing_shape.gauge_length_mm
        ok = Admissible(ap.frame, ap.frame.to_frame(self.obstacles), self.tool, max_swing_deg=self.fp.max_swing_deg,
                        machine=machine, gauge_mm=gauge, stock_f=stock_f,
                        pole_clearance_deg=self.fp.pole_clearance_deg)
        links = None
        if self.carried is not None:
            from planning.toolpath.fiveaxis.links import LINK_MARGIN_MM, StockLinks

            c = self.carried
            links = StockLinks(ap.frame, c.finishing_shape, c.stock, c.obstacles, ok, safe_z_mm=ap.safe_z_mm,
                               clearance_mm=c.rapid_clearance_mm + LINK_MARGIN_MM)
        out, pi, figs = five_axis_path(tp, pass_index, cloud_f=cloud_f, admissible=ok, fp=self.fp,
                                       cone_deg=self.cone_deg, safe_z_mm=ap.safe_z_mm, floor=floor, links=links)
        self.figures = figs
        ap.five_axis, ap.five_axis_input, ap.five_axis_links = figs, tp, links
        ap.five_axis_pass_index = pi
        return out


def _add_finishing(ap: AreaPaths, cloud_f, region_masks: list[np.ndarray], fp, max_slope_deg: float,
                   sec: dict, blocked=None, progress: _PathsProgress | None = None,
                   faces: np.ndarray | None = None, five_axis: _FiveAxisArea | None = None, job=None) -> None:
    """Step 4 and the gouge check of step 5 into ``ap``: finishing passes per region
    (:func:`_region_finishing`; ``job``: the finishing worker computing the same passes,
    :class:`planning.toolpath.finishing_worker.FinishingWorker`, or None), the blocked CL points cut
    out (``blocked``: (FinishingPath, progress, the cloud reason of its check if the worker found it,
    or None) -> FinishingPath, or None), arc fitting or CL reduction of the joined
    path, and the minimal clearance of the final moves (capped at R)."""
    R, tol = ap.radius_mm, ap.tolerance_mm
    t0 = time.perf_counter()
    step = (lambda name: None) if progress is None else progress.step
    finishing_progress = step("finishing")
    fin = cloud_known = None
    if job is not None:
        try:
            fin, cloud_known = job.passes(finishing_progress)
        except WorkerFailed as e:
            _log.warning("finishing worker failed (%s): passes computed in this process", e)
    if fin is None:
        # the ball rests on the triangles too, and every gouge check measures to them (surface.py)
        fin, binned = region_passes(cloud_f, region_masks, faces, fp, R, tol, ap.safe_z_mm, max_slope_deg,
                                    progress=finishing_progress)
    else:
        binned = binned_cloud(cloud_f, faces, R)
    sec["finishing"] = time.perf_counter() - t0
    if blocked is not None:
        t0 = time.perf_counter()
        fin = blocked(fin, step("cut_blocked"), cloud_known)
        sec["cut_blocked"] = time.perf_counter() - t0
        if fin is None:                        # nothing of the area can be finished from this set-up
            return
    tp = fin.toolpath
    if five_axis is not None:
        # 5-axis: the axes on the dense CL points (a position cut out costs one forward step), then the
        # reduction only where the axis stands still (moves are straight: no arcs)
        t0 = time.perf_counter()
        step("five_axis")
        tp = five_axis.run(ap, tp, fin.pass_index, cloud_f)
        sec["five_axis"] = time.perf_counter() - t0
        if tp.n_moves == 0:
            return
    t0 = time.perf_counter()
    step("reduce_arcs")
    # arc fitting also reduces the straight stretches it leaves, against the ORIGINAL CL
    # points (reducing first would let the arcs drift 2 tol from them)
    if five_axis is not None:
        from planning.toolpath.fiveaxis.finishing import axis_runs, biarc_figures

        if fp.reduce:
            tp, kept = reduce_cl(tp, binned, R, tol_mm=tol, pass_index=axis_runs(tp), with_kept=True)
            if ap.five_axis_pass_index is not None:
                ap.five_axis_pass_index = ap.five_axis_pass_index[kept]
        biarc_figures(tp, ap.five_axis, binned=binned, radius_mm=R, tol_mm=tol)
    elif fp.arcs:
        tp = fit_arcs(tp, binned, R, tol_mm=tol, reduce_lines=fp.reduce, pass_index=fin.pass_index)
    elif fp.reduce:
        tp = reduce_cl(tp, binned, R, tol_mm=tol, pass_index=fin.pass_index)
    sec["reduce_arcs"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    step("verify")
    clear = move_clearance(tp, binned, R)
    ap.min_clearance_mm = float(np.nanmin(clear)) if np.isfinite(clear).any() else float(R)
    ap.min_clearance_mm = min(ap.min_clearance_mm, float(R))
    sec["verify"] = time.perf_counter() - t0
    ap.finishing, ap.finishing_info = tp, fin
    ap.n_arcs = _count_arcs(tp)


def _region_finishing(cloud_f, region_masks, binned: BinnedCloud, fp, R: float, tol: float, safe: float,
                      max_slope_deg: float, progress: Progress | None = None,
                      triangles: TriangleDropSurface | None = None) -> FinishingPath:
    """The finishing passes (:func:`planning.toolpath.finishing.finishing_passes`, ``safe`` the
    ball-centre height of retracts and rapids, mm) of each region in ``region_masks`` (bool masks
    over ``cloud_f``), joined by :func:`join_region_paths`. A region on which no pass lies adds
    nothing; when none gets a pass, the first region's error is raised (as for a one-region area)."""
    surface = DropSurface(cloud_f, R, triangles=triangles)
    fins, first_error = [], None
    sizes = np.array([np.count_nonzero(m) for m in region_masks], dtype=np.float64)
    done_before = np.concatenate([[0.0], np.cumsum(sizes)]) / max(sizes.sum(), 1.0)
    for r, mask in enumerate(region_masks):
        inner = None
        if progress is not None:         # regions by their share of the area's points, passes inside
            head = f"region {r + 1}/{len(region_masks)}"
            progress(done_before[r], head)
            inner = (lambda f, m, r=r, head=head:
                     progress(done_before[r] + f * (done_before[r + 1] - done_before[r]), f"{head}, {m}"))
        try:
            fins.append(finishing_passes(cloud_f, mask, radius_mm=R, scallop_mm=fp.scallop_mm, step_mm=fp.step_mm,
                                         margin_mm=fp.margin_mm, zigzag=fp.pattern == "zigzag", tol_mm=tol,
                                         safe_z_mm=safe, lead_mm=fp.lead_mm, max_slope_deg=max_slope_deg,
                                         binned=binned, surface=surface, progress=inner))
        except ParameterError as e:
            if len(region_masks) == 1:
                raise
            first_error = first_error or e
    if not fins:
        raise first_error
    return join_region_paths(fins) if len(fins) > 1 else fins[0]


def join_region_paths(paths: Sequence[FinishingPath]) -> FinishingPath:
    """One :class:`FinishingPath` for the finishing paths of several regions of one area, mm.

    Order: the first of ``paths`` (the area's largest region), then always the unvisited one whose
    first point is nearest in (x, y) to the last point of the one before (short rapids). Every
    path of :func:`planning.toolpath.finishing.finishing_passes` starts with a rapid at the safe
    height and ends at the safe height after its lead-out, so consecutive paths are joined by that
    rapid at the safe height: the joined path never goes from one region to the next below it.
    ``pass_index`` of each path is offset by the passes before it (the passes of two regions are
    never merged by the reducer); ``n_passes``, ``length_mm`` summed, ``min_clearance_mm`` the
    smallest, ``n_retracts`` summed plus one retract per join (the lead-out and retract that ends
    a region is not counted in its own path), ``n_regions`` the number of paths."""
    if not paths:
        raise ParameterError("no finishing path to join")
    order = [0]
    left = list(range(1, len(paths)))
    while left:
        end = paths[order[-1]].toolpath.xyz_mm[-1, :2]
        d = [float(np.hypot(*(paths[j].toolpath.xyz_mm[0, :2] - end))) for j in left]
        order.append(left.pop(int(np.argmin(d))))
    ps = [paths[j] for j in order]
    offsets = np.cumsum([0] + [p.n_passes for p in ps[:-1]])
    pass_index = np.concatenate([np.where(p.pass_index >= 0, p.pass_index + o, -1).astype(np.int32)
                                 for p, o in zip(ps, offsets)])
    return FinishingPath(toolpath=concatenate([p.toolpath for p in ps]), n_passes=sum(p.n_passes for p in ps),
                         step_over_mm=ps[0].step_over_mm, min_clearance_mm=min(p.min_clearance_mm for p in ps),
                         length_mm=float(sum(p.length_mm for p in ps)),
                         n_retracts=sum(p.n_retracts for p in ps) + len(ps) - 1, pass_index=pass_index,
                         n_regions=sum(p.n_regions for p in ps))


def _count_collisions(ap: AreaPaths, obstacles, axis, tool: ToolAssembly, fixtures: Sequence) -> None:
    """The rest of step 5 into ``ap``: the finishing CL points (feed and arc moves) at which the
    cutter, shank or holder meets an obstacle point, and at which the tool meets a fixture."""
    tp = ap.finishing
    if tp is None:
        return
    cut = np.flatnonzero(np.isin(tp.kind, [FEED, ARC_CW, ARC_CCW]))
    centres = ap.frame.to_part(tp.xyz_mm[cut])
    if tp.axis is not None:
        # 5-axis: every position with its own axis (the fixtures, the riser and the table are run by
        # the guard on the carried stock, in 1-degree steps of every move)
        from planning.geometry.axis_collision import pointwise_collision_free

        ok = pointwise_collision_free(obstacles, centres, tp.axis[cut] @ ap.frame.rotation, tool)
        ap.holder_collisions = int((~ok).sum())
        return
    ap.holder_collisions = _holder_collisions(obstacles, centres, axis, tool)
    if fixtures:
        ok = fixture_collision_free(centres, axis[None, :], tool, list(fixtures))
        ap.fixture_collisions = int((~ok[:, 0]).sum())


def _holder_collisions(obstacles: np.ndarray, centres: np.ndarray, axis: np.ndarray, tool: ToolAssembly) -> int:
    """Ball centres (part frame) at which the cutter, shank or holder above the ball's centre meets
    an obstacle point (:func:`planning.geometry.collision.centres_collision_free`, exact)."""
    if centres.shape[0] == 0:
        return 0
    t = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    ok = centres_collision_free(obstacles, centres, t[None, :], tool)
    return int((~ok[:, 0]).sum())
