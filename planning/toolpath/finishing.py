"""Ball-end finishing passes of one area by ball drop on the cloud (issue 5 item 2; Sood's
point-based ball drop, Makki 2010 §4: 3-axis paths at the area's fixed orientation).

All in the area frame (:mod:`planning.toolpath.frames`: tool axis +Z, X along the footprint's longer side,
every cloud point at z <= 0). Parallel planes y = const (passes along X), zig-zag or one-way:

* step-over from the target scallop height ``h`` on a plane: ``s = 2 sqrt(2 R h - h^2)``;
* the footprint: the area's points in (x, y) on a square raster of ``s / 2`` cells, grown by
  ``margin_mm`` into the neighbours (the overlap band); passes keep the stretches inside it;
* along a pass, CL points every ``step_mm``; the CL height is the exact ball drop on the WHOLE
  cloud (all areas are obstacles, :func:`planning.toolpath.balldrop.ball_drop`);
* gouge safety of the straight moves between CL points: :func:`min_clearance` measures the
  smallest distance from any cloud point to the ball-centre polyline; a move closer than
  ``R - tol_mm`` is split at its midpoint with a fresh ball drop until it clears (bounded), and
  the final clearance is reported;
* links: retract to ``safe_z_mm`` (default R + 5 mm above the cloud's top: the frame's z = 0)
  between stretches. Fixtures are not yet obstacles of the links: see the issue notes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from planning.toolpath.balldrop import DropSurface
from planning.errors import ParameterError

RAPID, FEED = 0, 1
_CHUNK = 256        # moves per KD-tree query in min_clearance (bounds the gathered points)


@dataclass(frozen=True)
class FinishingPath:
    """``cl_mm`` (P,3) ball-centre positions in the area frame, ``move`` (P,) the move that reaches
    each (RAPID 0 or FEED 1), ``n_passes``, ``step_over_mm``, ``min_clearance_mm`` (smallest
    distance from a cloud point to the feed moves; >= R - tol when gouge free), ``length_mm``
    (feed length)."""

    cl_mm: np.ndarray
    move: np.ndarray
    n_passes: int
    step_over_mm: float
    min_clearance_mm: float
    length_mm: float


def step_over_mm(radius_mm: float, scallop_mm: float) -> float:
    """Step-over that leaves a scallop of height ``scallop_mm`` between passes on a plane:
    ``2 sqrt(2 R h - h^2)`` (mm)."""
    R, h = float(radius_mm), float(scallop_mm)
    if not (R > 0 and 0 < h <= R):
        raise ParameterError(f"scallop height {scallop_mm} mm must be in (0, R = {radius_mm}]")
    return 2.0 * math.sqrt(2 * R * h - h * h)


def min_clearance(cl_mm: np.ndarray, feed: np.ndarray, points: np.ndarray, radius_mm: float, *,
                  tree: cKDTree | None = None) -> np.ndarray:
    """Per feed move i (from ``cl_mm[i-1]`` to ``cl_mm[i]`` where ``feed[i]``): the smallest distance
    from a cloud point to that segment (``inf`` where no point is within ``2 R``; NaN for non-feed
    entries). Exact point-to-segment distances over the points a KD-tree (``tree``, built on
    ``points`` when not given) finds near each move, in chunks of moves."""
    cl = np.asarray(cl_mm, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64)
    out = np.full(cl.shape[0], np.nan)
    idx = np.flatnonzero(np.asarray(feed, dtype=bool))
    idx = idx[idx > 0]
    if idx.size == 0:
        return out
    out[idx] = np.inf
    tree = cKDTree(points) if tree is None else tree
    a, b = cl[idx - 1], cl[idx]
    mid = 0.5 * (a + b)
    reach = 0.5 * np.linalg.norm(b - a, axis=1) + 2 * float(radius_mm)
    for c0 in range(0, idx.size, _CHUNK):
        c1 = min(c0 + _CHUNK, idx.size)
        near = tree.query_ball_point(mid[c0:c1], reach[c0:c1])
        counts = np.fromiter((len(x) for x in near), dtype=np.int64, count=c1 - c0)
        if counts.sum() == 0:
            continue
        own = np.repeat(np.arange(c0, c1), counts)
        q = points[np.concatenate([np.asarray(x, dtype=np.int64) for x in near])]
        d = b[own] - a[own]
        L2 = (d * d).sum(axis=1)
        u = np.clip(np.where(L2 > 0, ((q - a[own]) * d).sum(axis=1) / np.where(L2 > 0, L2, 1.0), 0.0), 0.0, 1.0)
        dist = np.sqrt(((q - (a[own] + u[:, None] * d)) ** 2).sum(axis=1))
        has = np.flatnonzero(counts)
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])[has]
        out[idx[c0 + has]] = np.minimum.reduceat(dist, first)
    return out


def finishing_passes(cloud_frame: np.ndarray, area_frame_points: np.ndarray, *, radius_mm: float,
                     scallop_mm: float = 0.01, step_mm: float | None = None, margin_mm: float = 1.0,
                     zigzag: bool = True, tol_mm: float = 1e-3, safe_z_mm: float | None = None,
                     max_splits: int = 12) -> FinishingPath:
    """Ball-end finishing of one area (mm, area frame; see the module docstring).

    ``cloud_frame`` (N,3): every cloud point; ``area_frame_points`` (k,3): this area's points;
    ``radius_mm``: ball radius R; ``scallop_mm``: target scallop on a plane; ``step_mm``: forward
    step (default R / 4); ``margin_mm``: overlap band into the neighbours; ``zigzag``: alternate
    pass directions (else one-way, rapid back); ``tol_mm``: gouge tolerance.
    """
    pts = np.asarray(cloud_frame, dtype=np.float64)
    area = np.asarray(area_frame_points, dtype=np.float64)
    R = float(radius_mm)
    s = step_over_mm(R, scallop_mm)
    step = R / 4.0 if step_mm is None else float(step_mm)
    if not step > 0 or margin_mm < 0 or tol_mm <= 0:
        raise ParameterError("step_mm and tol_mm must be > 0 and margin_mm >= 0")
    if area.shape[0] == 0:
        raise ParameterError("the area has no points")
    safe = (R + 5.0) if safe_z_mm is None else float(safe_z_mm)
    # footprint raster (cells of s/2), grown by the margin
    c = s / 2.0
    lo = area[:, :2].min(axis=0) - margin_mm - c
    hi = area[:, :2].max(axis=0) + margin_mm + c
    nx = int(np.ceil((hi[0] - lo[0]) / c)) + 1
    ny = int(np.ceil((hi[1] - lo[1]) / c)) + 1
    occ = np.zeros((nx, ny), dtype=bool)
    ij = np.floor((area[:, :2] - lo) / c).astype(np.int64)
    occ[ij[:, 0], ij[:, 1]] = True
    occ = ndimage.binary_closing(occ, iterations=1)
    if margin_mm > 0:
        r = int(np.ceil(margin_mm / c))
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        occ = ndimage.binary_dilation(occ, structure=(xx * xx + yy * yy) * c * c <= margin_mm ** 2)
    y0, y1 = area[:, 1].min(), area[:, 1].max()
    n_pass = max(1, int(np.ceil((y1 - y0) / s)) + 1)
    ys = 0.5 * (y0 + y1) + (np.arange(n_pass) - (n_pass - 1) / 2.0) * s     # centred on the area
    xs = np.arange(lo[0], hi[0] + step, step)
    surface = DropSurface(pts, R)
    tree = cKDTree(pts)
    cls, moves, clears = [], [], []
    n_done = 0
    for y in ys:
        ix = np.floor((xs - lo[0]) / c).astype(np.int64)
        iy = int(np.floor((y - lo[1]) / c))
        inside = (ix >= 0) & (ix < nx) & (0 <= iy < ny)
        if inside.any():
            inside[inside] = occ[ix[inside], iy]
        if not inside.any():
            continue
        # stretches of consecutive inside samples, reversed on every other pass (zig-zag)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
        runs = list(zip(edges[::2], edges[1::2]))
        back = zigzag and n_done % 2 == 1
        for a, b in (runs[::-1] if back else runs):
            xr = xs[a:b][::-1] if back else xs[a:b]
            xy = np.stack([xr, np.full(xr.size, y)], 1)
            z = surface.drop(xy).z_mm
            ok = np.isfinite(z)                 # no point under the ball: nothing to cut there
            if not ok.any():
                continue
            line, clear = _make_safe(surface, tree, pts, np.column_stack([xy[ok], z[ok]]), R, tol_mm, max_splits)
            # rapid above the start, plunge, the pass, retract straight up (plunge and retract
            # are feed moves above ball-drop heights; their clearance is measured below)
            cls += [[[line[0, 0], line[0, 1], safe]], line, [[line[-1, 0], line[-1, 1], safe]]]
            moves += [[RAPID], [FEED] * line.shape[0], [FEED]]
            clears += [[np.nan], clear, [np.nan]]
        n_done += 1
    if not cls:
        raise ParameterError("no finishing pass lies on the area")
    cl = np.concatenate([np.asarray(x, dtype=np.float64).reshape(-1, 3) for x in cls])
    mv = np.concatenate([np.asarray(m, dtype=np.int8) for m in moves])
    clear = np.concatenate([np.asarray(x, dtype=np.float64) for x in clears])
    # the passes' moves were measured while making them safe; measure the plunges and retracts
    feed = mv == FEED
    links = feed & np.isnan(clear)
    clear[links] = min_clearance(cl, links, pts, R, tree=tree)[links]
    seg = np.linalg.norm(np.diff(cl, axis=0), axis=1)
    worst = np.nanmin(clear)
    return FinishingPath(cl_mm=cl, move=mv, n_passes=n_done, step_over_mm=s,
                         min_clearance_mm=float(worst), length_mm=float(seg[feed[1:]].sum()))

def _make_safe(surface, tree, pts, line, R, tol, max_splits):
    """Split the moves of a pass whose clearance is below R - tol at their midpoints (with a fresh
    ball drop) until every move clears or ``max_splits`` rounds have run; only the new moves are
    measured again. Returns the pass and each point's move clearance (NaN for its first point)."""
    feed = np.ones(line.shape[0], dtype=bool)
    feed[0] = False
    clear = min_clearance(line, feed, pts, R, tree=tree)
    for _ in range(max_splits):
        bad = np.flatnonzero(clear < R - tol)
        if bad.size == 0:
            break
        mids = 0.5 * (line[bad - 1] + line[bad])
        mids[:, 2] = np.maximum(surface.drop(mids[:, :2]).z_mm, mids[:, 2])
        line = np.insert(line, bad, mids, axis=0)
        clear = np.insert(clear, bad, np.nan)
        at = bad + np.arange(bad.size)          # where the midpoints landed
        redo = np.zeros(line.shape[0], dtype=bool)
        redo[at] = True
        redo[at + 1] = True
        clear[redo] = min_clearance(line, redo, pts, R, tree=tree)[redo]
    return line, clear
