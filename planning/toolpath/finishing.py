"""Ball-end finishing passes of one area by ball drop on the cloud (issue 5 item 2; Sood's
point-based ball drop, Makki 2010 §4: 3-axis paths at the area's fixed orientation).

All in the area frame (:mod:`planning.toolpath.frames`: tool axis +Z, X along the footprint's longer side,
every cloud point at z <= 0). Parallel planes y = const (passes along X), zig-zag or one-way:

* step-over from the target scallop height ``h`` on a plane: ``s = 2 sqrt(2 R h - h^2)``; with
  ``adaptive`` (default) each side step is shortened so that neighbouring ball centres, at every
  x, stay at most ``s`` apart in the cross-section, which keeps the scallop at ``h`` on slopes
  across the passes too (Sood ch. 5 adapts the side step per line);
* the band: the area's points in (x, y) on a square raster of ``s / 2`` cells, grown by
  ``margin_mm`` into the neighbours (the overlap band); a pass keeps the stretches where the dropped
  ball's contact point lies in the band (on a slope the contact is up to R from the centre);
* along a pass, CL points every ``step_mm``; the CL height is the exact ball drop on the WHOLE
  cloud (all areas are obstacles, :func:`planning.toolpath.balldrop.ball_drop`);
* gouge safety of the straight moves between CL points:
  :func:`planning.toolpath.verify.move_clearance` measures the smallest distance from any cloud
  point to each move of the ball-centre polyline (capped at R); a move closer than
  ``R - tol_mm`` is split at its midpoint with a fresh ball drop until it clears (bounded), and
  the final clearance is reported;
* links: in zig-zag, the end of a stretch and the start of the next one less than ``link_max_mm``
  apart (neighbouring passes) are joined on the surface by a ball-drop link made safe like a pass;
  otherwise a lead-out ramp, a retract to ``safe_z_mm`` (the caller puts it above the cloud and the
  fixtures; default R + 5 mm above the cloud's top, the frame's z = 0), a rapid, and a lead-in
  ramp. Ramps are 45 degrees in the pass direction, or vertical where a ramp would come closer
  than R - tol to the cloud. Vertical moves above a ball-drop height never touch the cloud with
  the ball (the drop height is the lowest free one on that line).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from planning.errors import ParameterError
from planning.progress import Throttled
from planning.toolpath import scallop
from planning.toolpath.balldrop import DropSurface
from planning.toolpath.moves import (
    FEED,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    BisectedLines,
    Toolpath,
    lines,
)
from planning.toolpath.verify import BinnedCloud, move_clearance

_ADAPT_ROUNDS = 8   # fixed-point rounds of an adaptive side step

#: :func:`finishing_passes` calls its ``progress`` at most this often (seconds), the last call aside.
PROGRESS_EVERY_S = 0.1
#: A straight move along a pass is bisected (with a fresh ball drop) while its midpoint lies more than
#: this share of ``tol_mm`` above the ball-drop height there (:func:`planning.toolpath.scallop.refine_chords`):
#: CL reduction may add up to ``tol_mm`` more, so a finishing move runs at most 1.5 ``tol_mm`` above
#: the ball-drop surface
CHORD_SHARE = 0.5
#: The share of ``progress``'s fraction that the passes take; making them safe and joining them the rest.
PASSES_SHARE = 0.7


class _Progress:
    """Throttled progress of one :func:`finishing_passes` call (see its ``progress``)."""

    def __init__(self, fn, y0: float, y1: float, s: float):
        self.fn, self.y0, self.span, self.s = fn, y0, max(y1 - y0, 0.0), s
        self._call = Throttled(fn, PROGRESS_EVERY_S)

    def passed(self, k: int, y: float, total: int | None = None) -> None:
        """Pass ``k`` (1-based) made at ``y``; ``total`` when known, else estimated from the step-over."""
        if self.fn is None:
            return
        share = min((y - self.y0) / self.span, 1.0) if self.span > 0 else 1.0
        if total is None:
            total = k + max(math.ceil((self.y0 + self.span - y) / self.s - 1e-9), 0)
        self._call(PASSES_SHARE * share, f"pass {k}/~{total}")

    def joining(self, n: int, share: float = 0.0, what: str = "making safe and linking") -> None:
        """The ``n`` passes made; ``share`` in [0, 1] of making them safe and joining them done."""
        if self.fn is not None:
            self._call(PASSES_SHARE + (1.0 - PASSES_SHARE) * share, f"pass {n}/{n}: {what}")

    def done(self, n: int) -> None:
        if self.fn is not None:
            self._call(1.0, f"pass {n}/{n}: done", force=True)


@dataclass(frozen=True)
class FinishingPath:
    """``toolpath``: the moves (:class:`planning.toolpath.moves.Toolpath`, ball centres, tip offset
    R), ``n_passes``, ``step_over_mm``, ``min_clearance_mm`` (smallest distance from a cloud point
    to the feed moves; >= R - tol when gouge free), ``length_mm`` (feed length), ``n_retracts``
    (retracts to the safe height between stretches), ``pass_index`` (P,) the pass each point of a
    stretch lies on (-1 for links, leads, retracts and rapids), ``n_regions``: how many connected
    regions of the area the path finishes one after another
    (:func:`planning.toolpath.area_paths.area_toolpaths` joins one path per region; 1 for a path
    of :func:`finishing_passes`)."""

    toolpath: Toolpath
    n_passes: int
    step_over_mm: float
    min_clearance_mm: float
    length_mm: float
    n_retracts: int
    pass_index: np.ndarray
    n_regions: int = 1

    @property
    def cl_mm(self) -> np.ndarray:
        """(P,3) ball-centre positions in the area frame."""
        return self.toolpath.xyz_mm

    @property
    def move(self) -> np.ndarray:
        """(P,) RAPID 0 or FEED 1: the move that reaches each point."""
        return self.toolpath.kind


def step_over_mm(radius_mm: float, scallop_mm: float) -> float:
    """Step-over that leaves a scallop of height ``scallop_mm`` between passes on a plane:
    ``2 sqrt(2 R h - h^2)`` (mm)."""
    R, h = float(radius_mm), float(scallop_mm)
    if not (R > 0 and 0 < h <= R):
        raise ParameterError(f"scallop height {scallop_mm} mm must be in (0, R = {radius_mm}]")
    return 2.0 * math.sqrt(2 * R * h - h * h)


def finishing_passes(cloud_frame: np.ndarray, area_mask: np.ndarray, *, radius_mm: float,
                     scallop_mm: float = 0.01, step_mm: float | None = None, margin_mm: float = 1.0,
                     zigzag: bool = True, tol_mm: float = 1e-3, safe_z_mm: float | None = None,
                     lead_mm: float = 1.0, link_max_mm: float | None = None, adaptive: bool = True,
                     max_slope_deg: float = 87.0, max_splits: int = 12,
                     binned: BinnedCloud | None = None, surface: DropSurface | None = None,
                     progress: Callable[[float, str], None] | None = None) -> FinishingPath:
    """Ball-end finishing of one area (mm, area frame; see the module docstring).

    ``cloud_frame`` (N,3): every cloud point (and forbidden point); ``area_mask`` (N,) bool: the
    points of this area. A CL point is kept where the ball dropped there rests on a point of the
    area or of the band ``margin_mm`` around it in (x, y) (its contact point, not its centre, decides:
    on a slope the two are up to R apart); ``radius_mm``: ball radius R; ``scallop_mm``: target scallop on a plane;
    ``step_mm``: forward step (default R / 4); ``margin_mm``: overlap band into the neighbours;
    ``zigzag``: alternate pass directions (else one-way, rapid back); ``tol_mm``: gouge tolerance;
    ``safe_z_mm``: ball-centre height of retracts and rapids (default R + 5 above the cloud top);
    ``lead_mm``: length of the 45-degree lead-in / lead-out ramps in the pass direction (vertical
    when a ramp would come closer than R - tol to the cloud; 0 = plunge straight down);
    ``link_max_mm``: the longest xy gap between the end of a stretch and the start of the next that
    is joined by a ball-drop link on the surface instead of a retract (default 2.5 step-overs,
    zig-zag only); ``adaptive``: choose each side step so that neighbouring ball centres stay at
    most the plane step-over apart in the cross-section (the scallop on a slope across the passes
    stays at the target), never shorter than ``s cos(max_slope_deg)`` (the steepest surface the
    area has: the tool cone's upper angle; this also keeps a sparse cloud's ball-drop noise from
    crowding the passes), else a constant step-over (the target holds on a plane only);
    ``binned``: ``cloud_frame`` already binned for the clearance queries (built here if None);
    ``surface``: ``cloud_frame`` already binned for ball drops of radius ``radius_mm``
    (:class:`planning.toolpath.balldrop.DropSurface`, built here if None; a caller finishing
    several regions of one cloud shares one);
    ``progress``: called as ``progress(fraction, message)`` while the passes are made (``fraction``
    in [0, 1] rises with the passes done: up to :data:`PASSES_SHARE` over the passes, by the
    share of the y range they cover, the rest while they are made safe and joined; ``message``
    like ``"pass 12/~80"``, the total estimated from the step-over), at most every
    :data:`PROGRESS_EVERY_S` seconds, and once with 1.0 at the end (None: not called).
    """
    pts = np.asarray(cloud_frame, dtype=np.float64)
    mask = np.asarray(area_mask, dtype=bool).reshape(-1)
    if pts.ndim != 2 or pts.shape[1] != 3 or mask.shape[0] != pts.shape[0]:
        raise ParameterError("cloud_frame must be (N,3) and area_mask (N,) bool")
    area = pts[mask]
    R = float(radius_mm)
    s = step_over_mm(R, scallop_mm)
    step = R / 4.0 if step_mm is None else float(step_mm)
    if not step > 0 or margin_mm < 0 or tol_mm <= 0 or lead_mm < 0:
        raise ParameterError("step_mm and tol_mm must be > 0, margin_mm and lead_mm >= 0")
    if area.shape[0] == 0:
        raise ParameterError("the area has no points")
    safe = (R + 5.0) if safe_z_mm is None else float(safe_z_mm)
    link_max = 2.5 * s if link_max_mm is None else float(link_max_mm)
    on_band, near_band, lo, hi = _band(pts, mask, area, s, margin_mm, R)
    # ball centres touching the band lie within R of it in (x, y)
    y0, y1 = area[:, 1].min() - margin_mm - R, area[:, 1].max() + margin_mm + R
    xs = np.arange(lo[0] - R, hi[0] + R + step, step)
    if surface is None:
        surface = DropSurface(pts, R)
    elif surface.R != R or surface.n != pts.shape[0]:
        raise ParameterError("surface must bin cloud_frame for a ball of radius radius_mm")
    # the clearance queries' raster (verify.move_clearance); the caller may share one
    tree = BinnedCloud(pts, R / 4.0) if binned is None else binned

    def drop_pass(y):
        """Which samples of the pass at y rest on the band, and their ball-drop heights (NaN elsewhere)."""
        # only samples with a band point within R can rest on one: the others are not dropped
        near = np.flatnonzero(near_band(xs, y))
        res = surface.drop(np.stack([xs[near], np.full(near.size, y)], 1))
        ok = res.contact >= 0
        ok[ok] = on_band(res.contact[ok])
        inside = np.zeros(xs.size, dtype=bool)
        inside[near] = ok
        z = np.full(xs.size, np.nan)
        z[near] = np.where(ok, res.z_mm, np.nan)
        return inside, z

    if not 0.0 <= max_slope_deg < 90.0:
        raise ParameterError(f"max_slope_deg = {max_slope_deg}: must be in [0, 90)")
    dy_min = s * math.cos(math.radians(max_slope_deg))
    tell = _Progress(progress, y0, y1, s)
    noise = []                  # the drop heights' jitter, per step taken (scallop.curvature_across)
    passes = _adaptive_passes(drop_pass, y0, y1, s, dy_min, R, float(scallop_mm), tell, noise) if adaptive else \
        _even_passes(drop_pass, y0, y1, s, tell)
    stretches, n_done = _stretches(passes, xs, zigzag)
    # the forward step: a move over a concave stretch is bisected until its chord keeps within
    # CHORD_SHARE of the tolerance of the ball-drop height between its ends (plus what the drop heights'
    # jitter, seen across the passes, explains)
    refined = scallop.refine_chords(lambda q: surface.drop(q).z_mm, [ln for _, ln in stretches],
                                    CHORD_SHARE * float(tol_mm), noise_mm=float(np.median(noise)) if noise else 0.0)
    stretches = [(p, ln) for (p, _), ln in zip(stretches, refined)]
    tell.joining(len(passes))
    if not stretches:
        raise ParameterError("no finishing pass lies on the area")
    cl, u, clear, pass_index, n_retracts = _join_stretches(
        surface, tree, stretches, R, step, tol_mm, max_splits, lead_mm, safe, link_max if zigzag else -1.0,
        lambda share, what: tell.joining(len(passes), share, what))
    tp = lines(cl, u, tip_offset_mm=R)
    # moves not measured while being made safe (leads, plunges, retracts): measure them now
    feed = tp.kind == FEED
    todo = feed & np.isnan(clear)
    todo[0] = False
    if todo.any():
        clear[todo] = _clr(cl, todo, tree, R)[todo]
    seg = np.linalg.norm(np.diff(cl, axis=0), axis=1)
    worst = float(np.nanmin(clear)) if np.isfinite(clear).any() else float("inf")
    tell.done(len(passes))
    return FinishingPath(toolpath=tp, n_passes=n_done, step_over_mm=s, min_clearance_mm=worst,
                         length_mm=float(seg[feed[1:]].sum()), n_retracts=n_retracts, pass_index=pass_index)


def _band(pts: np.ndarray, mask: np.ndarray, area: np.ndarray, s: float, margin_mm: float, R: float):
    """The points a pass may rest on: the area's footprint on a square raster of ``s / 2`` cells
    (closed once), grown by ``margin_mm`` into the neighbours. Returns ``on_band``, a function of
    point indices into ``pts`` (k,) -> (k,) bool (whether each of those points is in the band);
    ``near_band``, a function of ``(xs (k,), y)`` -> (k,) bool, False only where no band point
    lies within ``R`` of ``(x, y)`` in (x, y) (a ball of radius R dropped there cannot rest on
    the band: it is not dropped); and the raster's lower and upper (x, y) corners ``lo``, ``hi``
    (mm). Only the points a ball rests on are ever asked about, so the band is not evaluated over
    the whole cloud (a region's passes ask about a few thousand points of a cloud of a million)."""
    # footprint raster (cells of s/2), grown by the margin: the band of points the ball may touch
    c = s / 2.0
    lo = area[:, :2].min(axis=0) - margin_mm - c
    hi = area[:, :2].max(axis=0) + margin_mm + c
    nx = int(np.ceil((hi[0] - lo[0]) / c)) + 1
    ny = int(np.ceil((hi[1] - lo[1]) / c)) + 1
    occ = np.zeros((nx, ny), dtype=bool)
    ij = np.floor((area[:, :2] - lo) / c).astype(np.int64)
    occ[ij[:, 0], ij[:, 1]] = True
    foot = occ                                  # the cells of the area's own points (in the band whatever closing does)
    occ = ndimage.binary_closing(occ, iterations=1)
    if margin_mm > 0:
        r = int(np.ceil(margin_mm / c))
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        occ = ndimage.binary_dilation(occ, structure=(xx * xx + yy * yy) * c * c <= margin_mm ** 2)
    # cells within R of a band cell, on the raster padded by more than R: a band point p and a
    # line (x, y) with |p - (x, y)| <= R lie in cells whose indices differ by less than R / c + 1
    # per axis, so by less than R / c + sqrt(2) (< R / c + 1.5) between the cells' centres
    pad = int(np.ceil(R / c)) + 2
    grid = np.zeros((nx + 2 * pad, ny + 2 * pad), dtype=bool)
    grid[pad:pad + nx, pad:pad + ny] = occ | foot
    near = ndimage.distance_transform_edt(~grid) <= R / c + 1.5 if grid.any() else grid

    def near_band(xs: np.ndarray, y: float) -> np.ndarray:
        j = int(np.floor((y - lo[1]) / c)) + pad
        if not 0 <= j < ny + 2 * pad:
            return np.zeros(xs.size, dtype=bool)
        i = np.floor((xs - lo[0]) / c).astype(np.int64) + pad
        ok = (i >= 0) & (i < nx + 2 * pad)
        ok[ok] = near[i[ok], j]
        return ok

    def on_band(idx: np.ndarray) -> np.ndarray:
        ij = np.floor((pts[idx, :2] - lo) / c).astype(np.int64)
        inr = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        band = mask[idx]
        band[inr] |= occ[ij[inr, 0], ij[inr, 1]]
        return band

    return on_band, near_band, lo, hi


def _adaptive_passes(drop_pass, y0: float, y1: float, s: float, dy_min: float, R: float, h: float,
                     tell=None, noise: list | None = None) -> list:
    """Passes ``(y, inside, z)`` from ``y0`` to ``y1``, each side step the largest found (within
    [``dy_min``, SIDE_STEP_MAX ``s``]) whose scallop across the passes, at every x, stays within the
    target ``h``: :func:`planning.toolpath.scallop.scallop_across_mm` on the ball centres of this pass and
    the next, with the curvature across the passes from the previous pass, this one and the next (where
    the previous pass has no height, from this one and the next two); Sood ch. 5 sets the side step per line from the scallop measured between
    the passes. The step is found by a few rounds of ``dy <- dy sqrt(h / scallop)`` (the scallop grows as
    dy^2), started from the last pass's step, and the widest step tried whose scallop is within the target
    is taken; where the two passes share no x on the band, the step is at most ``s`` (``tell``: a
    :class:`_Progress`, told of each pass; ``noise``: a list the drop heights' jitter estimates of the
    steps taken are appended to, :func:`planning.toolpath.scallop.curvature_across`)."""
    passes = []                                 # (y, inside, z)
    y, cur = y0, drop_pass(y0)
    prev = None                                 # (y, z) of the pass before
    cap = scallop.SIDE_STEP_MAX * s
    dy_last = s
    while True:
        passes.append((y, *cur))
        if tell is not None:
            tell.passed(len(passes), y)
        if y >= y1 - 1e-9:
            break
        dy = max(min(dy_last * 1.25, cap, y1 - y), min(dy_min, y1 - y))
        best = None                             # (dy, pass) the widest within the target
        last = None
        for _ in range(_ADAPT_ROUNDS):
            nxt = drop_pass(y + dy)
            if not (np.isfinite(cur[1]) & np.isfinite(nxt[1])).any():
                # no x where both passes rest on the band (before it, past it): the plane's step-over,
                # so that no edge of the band is stepped over
                if dy > s:
                    dy = max(min(s, y1 - y), min(dy_min, y1 - y))
                    nxt = drop_pass(y + dy)
                best = (dy, nxt, [])
                break
            said = []
            c = np.full(nxt[1].shape, np.nan) if prev is None else \
                scallop.curvature_across(prev[0], prev[1], y, cur[1], y + dy, nxt[1], noise=said)
            if (np.isnan(c) & np.isfinite(cur[1]) & np.isfinite(nxt[1])).any():
                # the first pass, or x the pass before did not reach: the curvature from the next two
                far = drop_pass(y + 2.0 * dy)
                c = np.where(np.isnan(c), scallop.curvature_across(y, cur[1], y + dy, nxt[1], y + 2.0 * dy, far[1],
                                                                   noise=said), c)
            hw = scallop.worst(scallop.scallop_across_mm(R, y, cur[1], y + dy, nxt[1], c))
            last = (dy, nxt, said)
            if hw <= h * (1 + 1e-9):
                if best is None or dy > best[0]:
                    best = (dy, nxt, said)
                if hw >= scallop.ACCEPT_LOW * h or dy >= min(cap, y1 - y) - 1e-12:
                    break
                grow = min(cap, y1 - y, dy * math.sqrt(h / hw) * 0.99) if hw > 0 else min(cap, y1 - y)
                if grow <= dy * 1.01:
                    break
                dy = grow
            else:
                if dy <= dy_min * (1 + 1e-9):
                    break
                dy = max(dy_min, min(dy * math.sqrt(h / hw) * 0.99 if np.isfinite(hw) else 0.5 * dy, 0.95 * dy))
                if best is not None and dy <= best[0]:
                    break
        dy, nxt, said = best if best is not None else last
        if noise is not None:
            noise.extend(said)
        prev = (y, cur[1])
        dy_last = dy
        y, cur = y + dy, nxt
    return passes


def _even_passes(drop_pass, y0: float, y1: float, s: float, tell=None) -> list:
    """Passes ``(y, inside, z)`` a constant ``s`` apart, centred on ``[y0, y1]`` (``tell``: a
    :class:`_Progress`, told of each pass)."""
    passes = []                                 # (y, inside, z)
    n_pass = max(1, int(np.ceil((y1 - y0) / s)) + 1)
    for y in 0.5 * (y0 + y1) + (np.arange(n_pass) - (n_pass - 1) / 2.0) * s:   # centred on the area
        passes.append((y, *drop_pass(y)))
        if tell is not None:
            tell.passed(len(passes), y, n_pass)
    return passes


def _stretches(passes: list, xs: np.ndarray, zigzag: bool):
    """The runs of consecutive samples on the band, as CL lines in cutting order (every other pass
    reversed in zig-zag): ``([(pass number, (L,3) CL line)], number of passes with a run)``."""
    stretches = []                      # (pass number, (L,3) CL line)
    n_done = 0
    for y, inside, z_all in passes:
        if not inside.any():
            continue
        # stretches of consecutive inside samples, reversed on every other pass (zig-zag)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
        runs = list(zip(edges[::2], edges[1::2]))
        back = zigzag and n_done % 2 == 1
        for a, b in (runs[::-1] if back else runs):
            sl = slice(a, b)
            xr, z = (xs[sl][::-1], z_all[sl][::-1]) if back else (xs[sl], z_all[sl])
            ok = np.isfinite(z)                 # no point under the ball: nothing to cut there
            if not ok.any():
                continue
            stretches.append((n_done, np.column_stack([xr[ok], np.full(int(ok.sum()), y), z[ok]])))
        n_done += 1
    return stretches, n_done


def _join_stretches(surface, tree, stretches, R, step, tol_mm, max_splits, lead_mm, safe, link_max, tick=None):
    """Make the stretches gouge safe (:func:`_make_safe_many`) and join them in order: a surface
    link where :func:`_links` finds one (``link_max`` < 0: never), else lead-out, retract, rapid
    and lead-in. Returns the CL points (P,3), the use of the move reaching each (P,), its
    clearance (NaN where not measured), the pass of each point (-1 off the passes) and the
    number of retracts. ``tick(share done, what next)``, if given, is told of the steps."""
    tick = tick or (lambda share, what: None)
    safe_lines = _make_safe_many(surface, tree, [ln for _, ln in stretches], R, tol_mm, max_splits)
    stretches = [(p, ln, cl) for (p, _), (ln, cl) in zip(stretches, safe_lines)]
    tick(0.6, "ramps")
    ramp_in, ramp_out = _ramps(surface, tree, [ln for _, ln, _ in stretches], R, tol_mm, lead_mm, safe)
    tick(0.7, "links")
    xyz, use, clr, pid = [], [], [], []
    n_retracts = 0

    def add(p, u, cl=np.nan, pass_no=-1):
        xyz.append(np.asarray(p, dtype=np.float64).reshape(-1, 3))
        n = xyz[-1].shape[0]
        use.append(np.full(n, u, dtype=np.int8))
        clr.append(np.broadcast_to(np.asarray(cl, dtype=np.float64), (n,)).copy())
        pid.append(np.full(n, pass_no, dtype=np.int32))

    links = _links(surface, tree, [ln for _, ln, _ in stretches], R, step, tol_mm, max_splits, link_max)
    prev = None
    for k, (pass_no, line, clear) in enumerate(stretches):
        if prev is not None:
            link = links[k]
            if link is not None:
                add(link[0], USE_CUT, link[1])
            else:
                _lead_out(add, prev, ramp_out[k - 1], lead_mm, safe)
                n_retracts += 1
                _lead_in(add, line, ramp_in[k], lead_mm, safe)
        else:
            _lead_in(add, line, ramp_in[k], lead_mm, safe)
        pid[-1][-1] = pass_no                      # the stretch's first point ends the plunge or link
        add(line[1:], USE_CUT, clear[1:], pass_no)
        prev = line
    _lead_out(add, prev, ramp_out[len(stretches) - 1], lead_mm, safe)
    return np.concatenate(xyz), np.concatenate(use), np.concatenate(clr), np.concatenate(pid), n_retracts


def _clr(cl: np.ndarray, mask: np.ndarray, binned: BinnedCloud, R: float) -> np.ndarray:
    """Per straight move of the polyline ``cl`` selected by ``mask``: the exact distance to the
    nearest cloud point, capped at R (:func:`planning.toolpath.verify.move_clearance`); NaN elsewhere."""
    mask = np.asarray(mask, dtype=bool).copy()
    mask[0] = False
    out = np.full(cl.shape[0], np.nan)
    if mask.any():
        tp = lines(cl, np.full(cl.shape[0], USE_CUT, dtype=np.int8))
        out = move_clearance(tp, binned, R, moves=mask)
    return out


def _direction(line: np.ndarray, at_end: bool) -> np.ndarray:
    """Unit xy direction of a stretch at its start (or end)."""
    if line.shape[0] < 2:
        return np.array([1.0, 0.0])
    d = (line[-1] - line[-2])[:2] if at_end else (line[1] - line[0])[:2]
    return d / max(float(np.hypot(*d)), 1e-12)


def _ramps(surface, tree, stretch_lines, R, tol, lead, safe):
    """Lead-in and lead-out ramp ends of every stretch: the 45-degree ramp's far end where the ramp
    keeps R - tol from the cloud and its far end lies above the ball-drop height there (so the
    vertical rapid onto it is clear), else None (vertical). All checked in two kernel calls."""
    n = len(stretch_lines)
    if lead <= 0 or n == 0:
        return [None] * n, [None] * n
    ends, starts = [], []
    for ln in stretch_lines:
        d0, d1 = _direction(ln, False), _direction(ln, True)
        starts.append(ln[0] + np.array([-d0[0] * lead, -d0[1] * lead, lead]))
        ends.append(ln[-1] + np.array([d1[0] * lead, d1[1] * lead, lead]))
    far = np.array(starts + ends)
    near = np.array([ln[0] for ln in stretch_lines] + [ln[-1] for ln in stretch_lines])
    za = surface.drop(far[:, :2]).z_mm
    ok = (far[:, 2] < safe) & ~(np.isfinite(za) & (far[:, 2] < za))
    pairs = np.empty((2 * far.shape[0], 3))
    pairs[0::2], pairs[1::2] = far, near
    mask = np.zeros(pairs.shape[0], dtype=bool)
    mask[1::2] = True
    c = _clr(pairs, mask, tree, R)[1::2]
    ok &= c >= R - tol
    return ([far[i] if ok[i] else None for i in range(n)], [far[n + i] if ok[n + i] else None for i in range(n)])


def _lead_in(add, line, ramp, lead, safe):
    """Rapid above the stretch's start at the safe height, rapid down to the lead-in start, then a
    45-degree ramp (``ramp``: its checked far end) or a vertical plunge at plunge feed onto the
    first CL point."""
    p0 = line[0]
    start = None
    if lead > 0:
        start = ramp if ramp is not None else p0 + np.array([0.0, 0.0, lead])
    if start is not None and start[2] < safe:
        add([start[0], start[1], safe], USE_RAPID)
        add(start, USE_RAPID)
    else:
        add([p0[0], p0[1], safe], USE_RAPID)
    add(p0, USE_PLUNGE)


def _lead_out(add, line, ramp, lead, safe):
    """A 45-degree ramp (``ramp``: its checked far end) or a vertical move up from the stretch's last
    CL point at feed, then a rapid retract to the safe height."""
    p1 = line[-1]
    if lead > 0:
        end = ramp if ramp is not None else p1 + np.array([0.0, 0.0, min(lead, max(safe - p1[2], 0.0))])
        add(end, USE_RETRACT)
        add([end[0], end[1], safe], USE_RAPID)
    else:
        add([p1[0], p1[1], safe], USE_RETRACT)


def _links(surface, tree, stretch_lines, R, step, tol, max_splits, link_max):
    """Surface links between consecutive stretches whose ends are at most ``link_max`` apart in
    (x, y): the ball dropped along the straight xy line every ``step`` mm and made safe like a pass
    (all links together). ``links[k]`` joins stretch k-1 to k: ``(points after the start, their
    clearances)``, or None where the ball finds nothing under it or the link would not clear."""
    n = len(stretch_lines)
    out = [None] * n
    todo, raw = [], []
    for k in range(1, n):
        a, b = stretch_lines[k - 1][-1], stretch_lines[k][0]
        L = float(np.hypot(*(b[:2] - a[:2])))
        if L > link_max:
            continue
        m = max(1, int(np.ceil(L / step)))
        t = np.linspace(0.0, 1.0, m + 1)[1:-1]
        todo.append(k)
        raw.append((a, b, a[None, :2] + t[:, None] * (b[:2] - a[:2])[None, :]))
    if not todo:
        return out
    xy = np.concatenate([r[2] for r in raw])
    z = surface.drop(xy).z_mm if xy.size else np.zeros(0)
    cut = np.cumsum([r[2].shape[0] for r in raw])[:-1]
    keep, lines_ = [], []
    for k, (a, b, _), pxy, pz in zip(todo, raw, np.split(xy, cut), np.split(z, cut)):
        if not np.all(np.isfinite(pz)):
            continue
        keep.append(k)
        lines_.append(np.concatenate([a[None], np.column_stack([pxy, pz]), b[None]]))
    for k, (line, clear) in zip(keep, _make_safe_many(surface, tree, lines_, R, tol, max_splits)):
        if line.shape[0] < 2 or np.nanmin(clear) >= R - tol:
            out[k] = (line[1:], clear[1:])
    return out


def _make_safe_many(surface, tree, stretch_lines, R, tol, max_splits):
    """Split the moves of the stretches whose clearance is below R - tol at their midpoints (with a
    fresh ball drop) until every move clears or ``max_splits`` rounds have run; only the new moves
    are measured again, all stretches together (one clearance call per round). Returns
    ``[(line, clearance of the move reaching each point (NaN for its first))]`` in order."""
    if not stretch_lines:
        return []
    pl = BisectedLines(stretch_lines)
    clear = _clr(pl.xyz, pl.inner(), tree, R)          # NaN at each line's first point
    for _ in range(max_splits):
        bad = np.flatnonzero(clear < R - tol)           # never a first point (NaN there)
        if bad.size == 0:
            break
        mids = 0.5 * (pl.xyz[bad - 1] + pl.xyz[bad])
        mids[:, 2] = np.maximum(surface.drop(mids[:, :2]).z_mm, mids[:, 2])
        new = pl.insert(bad, mids)
        clear = np.insert(clear, bad, np.nan)
        redo = np.zeros(pl.lid.size, dtype=bool)
        redo[new] = True
        redo[new + 1] = True
        clear[redo] = _clr(pl.xyz, redo, tree, R)[redo]
    cut = np.flatnonzero(np.diff(pl.lid)) + 1
    return list(zip(pl.split(), np.split(clear, cut)))
