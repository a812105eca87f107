"""The roughing end mill's radial engagement, move by move (issue 31 item 5: "the simulation checks the
engagement of every move").

**What is measured.** A side-milling cutter of radius ``R`` that advances by ``ds`` along its level
removes, at each height of its flutes, a strip of material of area ``ae * ds``: ``ae`` is the radial
depth of cut (the width of the strip across the motion). On a straight cut whose material starts at
one side of the cutter, ``ae`` and the angle of the cutter's circumference in contact with the
material (the engagement angle) are tied by ``theta = acos(1 - ae / R)``: a slot (``ae = 2R``) is
180 degrees, a 60 % step-over 101.5 degrees, a 25 % one 60 degrees. Here ``ae`` is measured from the
area the tool really removes per length of path, at each height, and turned into that angle: the
*equivalent* engagement. On a curved path or in a corner it rises with the area removed, as the load
on the cutter does (an inside corner reads higher than the straight cut beside it). This is the
quantity adaptive clearing bounds (it keeps the area cut per step, i.e. the chip load, under a limit).

**How.** One program's moves of the roughing tool, at one fixed tool axis (a 3+2 set-up), on the
stock as it was before they ran (the tri-dexel model of :mod:`planning.simulate.dexel`):

* the material at a point is the stock before the program, read on the nearest ray of the family most
  parallel to the tool axis (exact along it), and not yet removed by these moves;
* what these moves removed is kept as a height field in the set-up frame, on square columns along the
  tool axis (side ``cell_mm``, default R / 14: 0.36 mm for a 10 mm end mill), started at the stock's top
  read on the rays (:func:`planning.simulate.heightfield.stock_tops_in_frame`, plus two ray spacings: no
  material lies above it). A column within ``R`` of a move, across the axis, is cleared down to the
  cutter's bottom over it: the tip's lowest height while the column is under the cutter plus the
  cutter's profile at the nearest approach (flat: 0; bull-nose: the torus). That is exact for a tool at
  a fixed axis (everything above the cutting edge is inside the tool, the shank and the holder), for a
  level move or a flat cutter; for a bull-nose on a descending move it clears a little too low;
* on the level moves (horizontal in the set-up frame) the material each newly cleared column held is
  counted at slices of the flute height above the tip (at most :data:`MAX_SLICES`), in the step of
  ``cell_mm`` along the move in which the column first comes under the cutter's edge;
* per slice, the areas over the last ``window_mm`` (default R / 2) of a run of level moves (consecutive
  moves that join) are divided by the length advanced: ``ae``; the engagement of a step is the largest
  over its slices, and a move's the largest over its steps. A window that starts in the move before
  counts there too: a move's figure includes the turn into it.

Moves that are not level (helix and ramp entries, lifts, descents) clear the columns but are not
measured: a helix or ramp enters material by design, and its own rule (the entry angle) bounds its
load. Rapids are neither run nor measured (a rapid that cuts is an offence of its own).

**Accuracy.** The strip area is counted in whole columns; the columns along the two arcs that bound it
are half in, half out, and their errors mostly cancel over a window. With the defaults a straight cut
reads within about 4 degrees of ``acos(1 - ae / R)`` and a slot as 180 (``tests/test_engagement.py``
holds straight cuts in any direction, flat and bull-nose, to their closed forms, and the same cut written
as one move or as a thousand chords to the same figure). The largest over a long cut is the upper edge
of that noise, so it reads a little high rather than low. The stock before the program is read at the
tri-dexel's resolution (``simulate.resolution_mm``): where an earlier set-up's cut bounds the material,
the boundary is that coarse.

**Cost.** The columns under each move are visited once (a move that continues a level move skips those
its start already cleared): about ``2 R / cell^2`` visits per mm of level feed, 60-100 ns each; the
femur-like make-run plan's five programs take about 2.6 s of CPU, run on the simulation's threads
(BENCHMARKS.md, "The roughing's engagement").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from planning.simulate.motion import FEED, ToolShape

#: Side of the height field's columns, as a share of the cutter radius (0.36 mm for a 10 mm end mill).
CELL_PER_RADIUS = 1.0 / 14.0
#: The length of a level run over which the area cut per length is averaged, as a share of the cutter
#: radius (2.5 mm for a 10 mm end mill).
WINDOW_PER_RADIUS = 0.5
#: At most this many slices of the flute height are measured.
MAX_SLICES = 16
#: A move is level when its rise along the tool axis is at most this share of its length (or 1e-6 mm).
LEVEL_SLOPE = 1e-3


@dataclass
class Engagement:
    """Per move of the program (P,): ``deg`` the equivalent engagement angle (degrees, module docstring;
    NaN where not measured: other tools, rapids, moves that are not level); ``level`` (P,) bool: the moves
    measured. ``note``: why nothing was measured ('' when something was)."""

    deg: np.ndarray
    level: np.ndarray
    note: str = ""


@njit(cache=True, nogil=True, inline="always")
def _in_ray(pool, off, cnt, r, x):
    """Whether coordinate ``x`` along ray ``r`` is inside one of its intervals (binary search)."""
    o = off[r]
    lo = 0
    hi = cnt[r]
    while lo < hi:                      # first interval whose upper end is >= x
        mid = (lo + hi) // 2
        if pool[o + mid, 1] < x:
            lo = mid + 1
        else:
            hi = mid
    return lo < cnt[r] and pool[o + lo, 0] <= x


@njit(cache=True, nogil=True, inline="always")
def _on_ray(lo, res, n, base, off, cnt, pool, f, px, py, pz):
    """Material at part-frame point (px, py, pz) on the nearest ray of family ``f`` (False off the grid)."""
    if f == 0:
        x, u, v = px, py, pz
    elif f == 1:
        x, u, v = py, pz, px
    else:
        x, u, v = pz, px, py
    ua = (f + 1) % 3
    va = (f + 2) % 3
    iu = int(math.floor((u - lo[ua]) / res))
    iv = int(math.floor((v - lo[va]) / res))
    if iu < 0 or iv < 0 or iu >= n[ua] or iv >= n[va]:
        return False
    return _in_ray(pool, off, cnt, base[f] + iv * n[ua] + iu, x)


@njit(cache=True, nogil=True, inline="always")
def _bottom(d, R, rc):
    """Height of the cutter's lower edge over the tip at distance ``d`` from its axis (d <= R)."""
    if rc <= 0.0 or d <= R - rc:
        return 0.0
    u = d - (R - rc)
    return rc - math.sqrt(max(0.0, rc * rc - u * u))


@njit(cache=True, nogil=True, inline="always")
def _count(k, xc, yc, zt, hold, bz, slice_mm, J, E1, E2, AX, fam, lo, res, n, base, off, cnt, pool, cell2, area):
    """Add to ``area[k]`` the material a column at (xc, yc) held at the flute slices between its new floor
    ``zt`` and its old one ``hold`` (slices measured up from the tip height ``bz``)."""
    qa = max(0, int(math.ceil((zt - bz) / slice_mm - 0.5)))
    for q in range(qa, J):
        zq = bz + (q + 0.5) * slice_mm
        if zq >= hold:
            break
        px = xc * E1[0] + yc * E2[0] + zq * AX[0]
        py = xc * E1[1] + yc * E2[1] + zq * AX[1]
        pz = xc * E1[2] + yc * E2[2] + zq * AX[2]
        if _on_ray(lo, res, n, base, off, cnt, pool, fam, px, py, pz):
            area[k, q] += cell2


@njit(cache=True, nogil=True)
def _stamp(h, bx, by, bz, R, rc, gx0, gy0, cell, nx, ny):
    """Clear the columns under the cutter with its tip at (bx, by, bz) (a move straight along the axis)."""
    j0 = max(0, int(math.floor((by - R - gy0) / cell)))
    j1 = min(ny - 1, int(math.floor((by + R - gy0) / cell)))
    for j in range(j0, j1 + 1):
        ry = gy0 + (j + 0.5) * cell - by
        w2 = R * R - ry * ry
        if w2 < 0.0:
            continue
        w = math.sqrt(w2)
        i0 = max(0, int(math.floor((bx - w - gx0) / cell)))
        i1 = min(nx - 1, int(math.floor((bx + w - gx0) / cell)))
        for i in range(i0, i1 + 1):
            rx = gx0 + (i + 0.5) * cell - bx
            d2 = rx * rx + ry * ry
            if d2 > R * R:
                continue
            zt = bz + _bottom(math.sqrt(d2), R, rc)
            if zt < h[j, i]:
                h[j, i] = zt


@njit(cache=True, nogil=True)
def _sweep(h, k0, ns, sx, sy, ex, ey, sz, ez, level, R, rc, gx0, gy0, cell, nx, ny, slice_mm, J, E1, E2, AX, fam,
           lo, res, n, base, off, cnt, pool, area, cont):
    """A move from (sx, sy, sz) to (ex, ey, ez) (frame; not straight along the axis), in ``ns`` steps from
    step ``k0``: every column within ``R`` of it across the axis is cleared to the cutter's bottom over it
    (the tip's lowest height while the column is under the cutter, plus the cutter's profile at the nearest
    approach: exact for a level move or a flat cutter, a little low for a bull-nose on a slope), and on a
    ``level`` move what it held is counted at the step in which the column first comes under the cutter. ``cont``: the move before
    was a level move at this height that ended here, so the columns under the cutter at the start are done
    (a flat cutter's all of them, a bull-nose's those behind the start, which come no nearer)."""
    dx = ex - sx
    dy = ey - sy
    L = math.sqrt(dx * dx + dy * dy)
    ux = dx / L
    uy = dy / L
    cell2 = cell * cell
    j0 = max(0, int(math.floor((min(sy, ey) - R - gy0) / cell)))
    j1 = min(ny - 1, int(math.floor((max(sy, ey) + R - gy0) / cell)))
    for j in range(j0, j1 + 1):
        yc = gy0 + (j + 0.5) * cell
        # the row's span of the capsule (convex): the union of the end discs' spans and the band's
        xa = np.inf
        xb = -np.inf
        for cx, cy in ((sx, sy), (ex, ey)):
            w2 = R * R - (yc - cy) * (yc - cy)
            if w2 >= 0.0:
                w = math.sqrt(w2)
                xa = min(xa, cx - w)
                xb = max(xb, cx + w)
        # band: |lat| <= R and 0 <= proj <= L with proj = (x-sx) ux + (yc-sy) uy, lat = -(x-sx) uy + (yc-sy) ux
        if abs(uy) > 1e-12:
            t1 = ((yc - sy) * ux - R) / uy
            t2 = ((yc - sy) * ux + R) / uy
            lo1, hi1 = min(t1, t2), max(t1, t2)
        elif abs(yc - sy) <= R:
            lo1, hi1 = -np.inf, np.inf
        else:
            lo1, hi1 = np.inf, -np.inf
        if abs(ux) > 1e-12:
            t3 = (0.0 - (yc - sy) * uy) / ux
            t4 = (L - (yc - sy) * uy) / ux
            lo2, hi2 = min(t3, t4), max(t3, t4)
        elif 0.0 <= (yc - sy) * uy <= L:
            lo2, hi2 = -np.inf, np.inf
        else:
            lo2, hi2 = np.inf, -np.inf
        ba = max(lo1, lo2)
        bb = min(hi1, hi2)
        if ba <= bb:
            xa = min(xa, sx + ba)
            xb = max(xb, sx + bb)
        if xa > xb:
            continue
        i0 = max(0, int(math.floor((xa - gx0) / cell)))
        i1 = min(nx - 1, int(math.floor((xb - gx0) / cell)))
        # the columns surely under the cutter at the start (centres inside its disc by a margin)
        ia, ib = 1, 0
        if cont:
            w2 = (R - 1e-6) ** 2 - (yc - sy) * (yc - sy)
            if w2 > 0.0:
                w = math.sqrt(w2)
                ia = int(math.ceil((sx - w - gx0) / cell - 0.5))
                ib = int(math.floor((sx + w - gx0) / cell - 0.5))
        flat_skip = cont and rc <= 0.0 and ia <= ib
        bull_skip = cont and rc > 0.0 and ia <= ib
        for part in range(2 if flat_skip else 1):
            if not flat_skip:
                ra, rb = i0, i1
            elif part == 0:
                ra, rb = i0, min(i1, ia - 1)
            else:
                ra, rb = max(i0, ib + 1), i1
            _sweep_row(h, j, ra, rb, yc, sx, sy, ex, ey, sz, ez, level, ux, uy, L, R, rc, gx0, cell, ns, k0,
                       bull_skip, ia, ib, slice_mm, J, E1, E2, AX, fam,
                       lo, res, n, base, off, cnt, pool, cell2, area)


@njit(cache=True, nogil=True)
def _sweep_row(h, j, ra, rb, yc, sx, sy, ex, ey, sz, ez, level, ux, uy, L, R, rc, gx0, cell, ns, k0, skip_behind,
               ia, ib,
               slice_mm, J, E1, E2, AX, fam, lo, res, n, base, off, cnt, pool, cell2, area):
    """Columns ``ra``..``rb`` of row ``j`` of :func:`_sweep`."""
    for i in range(ra, rb + 1):
        xc = gx0 + (i + 0.5) * cell
        px_ = xc - sx
        py_ = yc - sy
        proj = px_ * ux + py_ * uy
        lat = -px_ * uy + py_ * ux
        if skip_behind and ia <= i <= ib and proj <= 0.0:
            continue
        if proj < 0.0:
            d = math.sqrt(px_ * px_ + py_ * py_)
        elif proj > L:
            qx = xc - ex
            qy = yc - ey
            d = math.sqrt(qx * qx + qy * qy)
        else:
            d = abs(lat)
        if d > R:
            continue
        # the stretch of the move over which the column is under the cutter, and the tip's lowest height on it
        half = math.sqrt(max(0.0, R * R - lat * lat))
        t_in = min(L, max(0.0, proj - half))
        t_out = min(L, max(0.0, proj + half))
        bz = min(sz + (ez - sz) * t_in / L, sz + (ez - sz) * t_out / L)
        zt = bz + _bottom(d, R, rc)
        hold = h[j, i]
        if zt >= hold:
            continue
        h[j, i] = zt
        if not level:
            continue
        # the step in which the column comes under the cutter's edge
        step = min(ns - 1, max(0, int(t_in / L * ns)))
        _count(k0 + step, xc, yc, zt, hold, bz, slice_mm, J, E1, E2, AX, fam, lo, res, n, base, off, cnt, pool,
               cell2, area)


@njit(cache=True, nogil=True)
def _walk(h, S, E, feed, E1, E2, AX, fam, lo, res, n, base, off, cnt, pool, gx0, gy0, cell, nx, ny, R, rc,
          slice_mm, J, step_mm, level_slope):
    """Walk the moves (frame coordinates ``S``, ``E`` (P,3): x, y along ``E1``, ``E2``, z along ``AX``).
    Returns per step: move index, the length advanced across the axis, whether the move is level, and the
    area (mm^2) newly removed at each of ``J`` slices above the tip. ``h`` (ny, nx): per column the height
    above which there is no material (changed in place)."""
    P = S.shape[0]
    nsteps = 0
    for m in range(P):
        if feed[m]:
            dx = E[m, 0] - S[m, 0]
            dy = E[m, 1] - S[m, 1]
            dz = E[m, 2] - S[m, 2]
            L = max(math.sqrt(dx * dx + dy * dy), abs(dz))
            nsteps += max(1, int(math.ceil(L / step_mm)))
    mv = np.empty(nsteps, np.int64)
    ds = np.empty(nsteps)
    lev = np.empty(nsteps, np.bool_)
    area = np.zeros((nsteps, J), np.float32)
    k = 0
    prev = -1                      # the last feed move walked, and whether it was level
    prev_level = False
    for m in range(P):
        if not feed[m]:
            prev = -1
            continue
        sx, sy, sz = S[m, 0], S[m, 1], S[m, 2]
        dx = E[m, 0] - sx
        dy = E[m, 1] - sy
        dz = E[m, 2] - sz
        dxy = math.sqrt(dx * dx + dy * dy)
        L = max(dxy, abs(dz))
        ns = max(1, int(math.ceil(L / step_mm)))
        level = abs(dz) <= max(1e-6, level_slope * dxy) and dxy > 0.0
        for s in range(ns):
            mv[k + s] = m
            ds[k + s] = dxy / ns
            lev[k + s] = level
        if dxy > 1e-9:
            cont = (level and prev >= 0 and prev_level and abs(E[prev, 0] - sx) <= 1e-9
                    and abs(E[prev, 1] - sy) <= 1e-9 and abs(E[prev, 2] - sz) <= 1e-6)
            if level:             # one height: the move's mean (within LEVEL_SLOPE of its ends)
                zs = ze = 0.5 * (sz + E[m, 2])
            else:
                zs, ze = sz, E[m, 2]
            _sweep(h, k, ns, sx, sy, E[m, 0], E[m, 1], zs, ze, level, R, rc, gx0, gy0, cell, nx, ny,
                   slice_mm, J, E1, E2, AX, fam, lo, res, n, base, off, cnt, pool, area, cont)
        else:                     # straight along the axis: the lowest of its ends
            _stamp(h, sx, sy, min(sz, E[m, 2]), R, rc, gx0, gy0, cell, nx, ny)
        prev = m
        prev_level = level
        k += ns
    return mv, ds, lev, area


def _runs(motion_start: np.ndarray, motion_end: np.ndarray, mv: np.ndarray, lev: np.ndarray) -> np.ndarray:
    """Per step, the id of its run of level moves (consecutive level moves, each starting where the one
    before it ended; -1 for other steps)."""
    run = np.full(mv.shape[0], -1, np.int64)
    if mv.size == 0:
        return run
    prev_mv = np.r_[-1, mv[:-1]]
    prev_lev = np.r_[False, lev[:-1]]
    same = mv == prev_mv
    joins = np.zeros(mv.shape[0], bool)
    nxt = np.flatnonzero(~same & (prev_mv >= 0) & (mv == prev_mv + 1))
    joins[nxt] = np.abs(motion_start[mv[nxt]] - motion_end[prev_mv[nxt]]).max(axis=1) <= 1e-6
    starts = lev & ~(prev_lev & (same | joins))
    rid = np.cumsum(starts) - 1
    run[lev] = rid[lev]
    return run


def _windowed(ds: np.ndarray, area: np.ndarray, run: np.ndarray, window_mm: float) -> np.ndarray:
    """Per level step, the largest over the slices of (area removed)/(length advanced) over the window of
    ``window_mm`` that ends at it (at its run's first full window where the run has not yet covered one;
    the whole run where it is shorter): ``ae`` (mm). NaN for other steps."""
    out = np.full(ds.shape[0], np.nan)
    keep = np.flatnonzero(run >= 0)
    if keep.size == 0:
        return out
    r = run[keep]
    L = np.cumsum(ds[keep])
    used = np.flatnonzero(area.any(axis=0))          # the slices some step cut in (a few of them)
    if used.size == 0:
        out[keep] = 0.0
        return out
    A = np.cumsum(area[np.ix_(keep, used)].astype(np.float64), axis=0)
    first = np.r_[True, r[1:] != r[:-1]]
    rs = np.flatnonzero(first)                       # each run's first step (in keep)
    re = np.r_[rs[1:], keep.size] - 1                # and its last
    run_of = np.cumsum(first) - 1
    L0 = np.where(rs > 0, L[np.maximum(rs - 1, 0)], 0.0)[run_of]          # length before the run
    A0 = np.where((rs > 0)[:, None], A[np.maximum(rs - 1, 0)], 0.0)[run_of]
    # the window's end: this step, or the run's first step that completes a window (or its last)
    full = np.searchsorted(L, L0 + window_mm - 1e-9, side="left")
    end = np.maximum(np.arange(keep.size), np.minimum(full, re[run_of]))
    # the window's start: the last step whose end lies a window before the end's (within the run)
    s = np.searchsorted(L, L[end] - window_mm + 1e-9, side="left")
    s = np.maximum(s, rs[run_of])
    Ls = np.where(s > rs[run_of], L[np.maximum(s - 1, 0)], L0)
    As = np.where((s > rs[run_of])[:, None], A[np.maximum(s - 1, 0)], A0)
    length = L[end] - Ls
    with np.errstate(invalid="ignore", divide="ignore"):
        ae = ((A[end] - As).max(axis=1)) / length
    out[keep] = np.where(length > 0, ae, np.nan)
    return out


def engagement_angle_deg(ae_mm: np.ndarray, radius_mm: float) -> np.ndarray:
    """The engagement angle of a straight cut of radial depth ``ae_mm`` with a cutter of radius
    ``radius_mm``: ``acos(1 - ae / R)`` in degrees, 180 for a slot (``ae >= 2 R``)."""
    return np.degrees(np.arccos(np.clip(1.0 - np.asarray(ae_mm, float) / float(radius_mm), -1.0, 1.0)))


def measure(stock, start_mm, end_mm, axis, kind, tool, shape: ToolShape, *, cell_mm: float | None = None,
            window_mm: float | None = None) -> Engagement:
    """The equivalent engagement (degrees, module docstring) of every level feed move of the tool
    ``shape.number`` among one program's moves (``start_mm``, ``end_mm`` (P,3) tool tip, part frame;
    ``axis`` (P,3) unit tool axis; ``kind`` (P,) :data:`~planning.simulate.motion.FEED` or RAPID;
    ``tool`` (P,) T numbers), on ``stock`` (:class:`~planning.simulate.dexel.TriDexel`) as it was before
    those moves ran; ``stock`` is not changed. The tool must keep one axis over its feed moves (a 3+2
    set-up); otherwise nothing is measured and the note says so. ``cell_mm``: the columns' side (default
    :data:`CELL_PER_RADIUS` of the cutter radius); ``window_mm``: the averaging length (default
    :data:`WINDOW_PER_RADIUS` of it). Lengths mm."""
    from planning.geometry.basis import complete_basis

    S = np.asarray(start_mm, float).reshape(-1, 3)
    E = np.asarray(end_mm, float).reshape(-1, 3)
    A = np.asarray(axis, float).reshape(-1, 3)
    P = S.shape[0]
    deg = np.full(P, np.nan)
    level = np.zeros(P, bool)
    mine = np.asarray(tool).reshape(-1) == int(shape.number)
    feed = mine & (np.asarray(kind).reshape(-1) == FEED)
    if not feed.any():
        return Engagement(deg, level, f"no feed move of T{shape.number}")
    ax = A[feed]
    a = ax[0] / np.linalg.norm(ax[0])
    if np.abs(ax / np.linalg.norm(ax, axis=1, keepdims=True) - a).max() > 1e-6:
        return Engagement(deg, level, f"T{shape.number} changes its axis while it feeds (5-axis): "
                                      "its engagement is not measured")
    e1, e2 = complete_basis(a)
    Rm = np.stack([e1, e2, a])                        # rows: frame axes in the part frame
    fS = S @ Rm.T
    fE = E @ Rm.T
    R = float(shape.radius_mm)
    rc = float(shape.corner_radius_mm) if shape.kind != "flat" else 0.0
    cell = float(cell_mm) if cell_mm is not None else R * CELL_PER_RADIUS
    window = float(window_mm) if window_mm is not None else R * WINDOW_PER_RADIUS
    pts = np.concatenate([fS[feed], fE[feed]])
    gx0, gy0 = pts[:, 0].min() - R - cell, pts[:, 1].min() - R - cell
    nx = int(math.ceil((pts[:, 0].max() + R + cell - gx0) / cell)) + 1
    ny = int(math.ceil((pts[:, 1].max() + R + cell - gy0) / cell)) + 1
    flute = float(shape.flute_length_mm)
    slice_mm = max(2.0 * cell, flute / MAX_SLICES)
    J = max(1, min(MAX_SLICES, int(math.ceil(flute / slice_mm))))
    # no material above the stock's top along the axis (read on the rays, within about a ray spacing: two
    # spacings more): the slices above it are not read
    from planning.simulate.heightfield import stock_tops_in_frame

    tops = stock_tops_in_frame(stock, Rm, np.zeros(3), float(gx0), float(gy0), cell, nx, ny, np.inf, -np.inf)
    h = np.ascontiguousarray((tops + 2.0 * stock.res + cell).T)
    mv, ds, lev, area = _walk(h, np.ascontiguousarray(fS), np.ascontiguousarray(fE), feed, np.ascontiguousarray(e1),
                              np.ascontiguousarray(e2), np.ascontiguousarray(a), int(np.argmax(np.abs(a))), stock.lo, stock.res, stock.n,
                              stock.base, stock.off, stock.cnt, stock.pool, float(gx0), float(gy0), cell, nx, ny,
                              R, rc, slice_mm, J, cell, LEVEL_SLOPE)
    run = _runs(S, E, mv, lev)
    ae = _windowed(ds, area, run, window)
    ok = np.isfinite(ae)
    if ok.any():
        step_deg = engagement_angle_deg(ae[ok], R)
        best = np.full(P, -np.inf)
        np.maximum.at(best, mv[ok], step_deg)
        level[np.unique(mv[ok])] = True
        deg[level] = best[level]
    return Engagement(deg, level, "")
