"""The pieces of clearing of one level of the Z-level roughing (:mod:`planning.toolpath.roughing`;
mm, area frame): the parallel lines clipped to the level's region and the offset contours
(Tchanchane & Bey). Stage: per level, after the region (:mod:`planning.toolpath.roughing.regions`)
and before their order (:mod:`planning.toolpath.roughing.ordering`) and the links
(:mod:`planning.toolpath.roughing.links`).

**Clearing.** Lines along X of the frame at fixed y (the same at every level), ``stepover_mm``
apart: default 60 % of the diameter, at most the diameter, so the discs of neighbouring lines
overlap and no island of stock is left between them (a bull-nose leaves a cusp of
``rc - sqrt(rc^2 - (s/2 - Rf)^2)`` where ``s > 2 Rf``); the outer lines ``max(Rf, Rt / 2) - h``
inside the stock's sides (the flat bottom reaches h past them). Each line is clipped to the
region (runs of region cells, to the cells' edges). Then (``contour``) the offset contour: the
region's boundary where it borders cells the part forbids (marching squares on the map through
the midpoints between an allowed and a forbidden cell centre, allowed cells 8-connected), run
with the material that stays on the right of the travel (climb milling with a clockwise, M3,
spindle); where the region ends at its limit around the stock the contour is not cut (air).
Every path point lies within ``h`` of an allowed cell centre (lines ``h / sqrt(2)``, contour
``0.8 h``, links below ``0.96 h``), hence is safe (but for the chords below, which the exact
clearance makes safe).

**Hugging the walls** (:func:`_hug`; on the stock view only, issue 30). The contour is a staircase
of raster cells; along a wall at an angle to the raster, each step away from the part moves the tool
into the room it has just cut and feeds through air (on the slot case most of the roughing's air was
such steps of 0.3-0.45 mm). A vertex where the chain turns right (towards the part) and that lies
within ``h`` of the chord of its two neighbours is dropped when the tool moved along that chord at the
level keeps the allowance from every cloud point (the exact clearance of
:mod:`planning.toolpath.roughing.clearance`, :class:`~planning.toolpath.roughing.clearance._MoveClearance`:
the cloud binned once per set-up, one kernel call per round for all the level's chords). The chord
lies between the staircase and the part, so it cuts at least what the steps cut; at most every other
vertex of a run of candidates goes per round, HUG_ROUNDS rounds. A chain's ends stay; the lines and
the contour on the box or the points alone are unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from planning.toolpath.roughing.regions import _comp_at, _edge_cells, _march


@dataclass
class _Piece:
    """A piece of clearing at one level: a line run or a contour chain. ``xy`` (m,2), ``cells``
    (m,) flat raster index of an allowed cell within h of each vertex; ``ends``: 'both' (either
    end may start: zig-zag lines), 'start' (one-way lines, open chains) or 'loop' (closed: any
    vertex, ``xy[0] == xy[-1]``)."""

    comp: int
    xy: np.ndarray
    cells: np.ndarray
    ends: str
    is_line: bool
    row: int = -1


def _line_ys(box_lo, box_hi, h, Rt, rc, s):
    """The y positions of the clearing lines (the same at every level), ``s`` apart at most, the
    outer ones ``max(Rt - rc, Rt / 2) - h`` inside the stock box's sides (module docstring)."""
    W = float(box_hi[1] - box_lo[1])
    span = W + 2 * h - 2 * max(Rt - rc, 0.5 * Rt)           # the flat bottom reaches past the sides
    if span <= 0:
        ys = np.array([0.5 * (box_lo[1] + box_hi[1])])
    else:
        n = int(math.ceil(span / s - 1e-9)) + 1
        ys = 0.5 * (box_lo[1] + box_hi[1]) + (np.arange(n) - (n - 1) / 2.0) * (span / (n - 1))
    return ys


@njit(cache=True, nogil=True)
def _line_runs(region, cols, rows, j0, j1, comp):
    """Runs of region cells along x in the raster columns ``cols`` (the clearing lines): arrays
    (line index, first cell, end cell (exclusive), component)."""
    nx = region.shape[0]
    cap = 256
    out = np.empty((cap, 4), np.int64)
    n = 0
    for r in range(cols.shape[0]):
        j = cols[r]
        start = -1
        for i in range(nx + 1):
            v = i < nx and region[i, j]
            if v and start < 0:
                start = i
            elif not v and start >= 0:
                if n == cap:
                    cap *= 2
                    o2 = np.empty((cap, 4), np.int64)
                    for q in range(n):
                        for c in range(4):
                            o2[q, c] = out[q, c]
                    out = o2
                out[n, 0] = r
                out[n, 1] = start
                out[n, 2] = i
                out[n, 3] = _comp_at(rows, j0, j1, comp, start, j)
                n += 1
                start = -1
    return out[:n]



def _line_pieces(region, runs, ys, x0, y0, h, ny, oneway) -> list[_Piece]:
    """The level's line pieces: each line at ``ys`` clipped to the region (``runs`` from
    :func:`planning.toolpath.roughing.regions._region_runs`), from cell edge to cell edge."""
    cols = np.array([int(math.floor((y - y0) / h)) for y in ys], np.int64)
    out = []
    for r, i0, i1, comp in _line_runs(region, cols, *runs).tolist():       # cells i0 .. i1 - 1
        y, j = float(ys[r]), int(cols[r])
        xy = np.array([[x0 + i0 * h, y], [x0 + i1 * h, y]])
        cells = np.array([i0 * ny + j, (i1 - 1) * ny + j])
        out.append(_Piece(comp, xy, cells, "start" if oneway else "both", True, r))
    return out


def _contour_pieces(region, G, thr, runs, x0, y0, h) -> list[_Piece]:
    """The level's offset-contour pieces: the region's boundary loops
    (:func:`~planning.toolpath.roughing.regions._march`) where they border forbidden cells
    (``G > thr``): a whole loop stays closed, else its runs of such edges are open chains;
    collinear vertices dropped."""
    ny = region.shape[1]
    edges, starts = _march(region, *runs[:3])
    if edges.size == 0:
        return []
    cell, keep, gx, gy = _edge_cells(edges, region, G, thr)
    out = []
    for k in range(starts.size - 1):
        s0, s1 = starts[k], starts[k + 1]
        kf = keep[s0:s1]
        if not kf.any():
            continue
        idx = np.arange(s0, s1)
        if kf.all():
            pieces = [(np.concatenate([idx, idx[:1]]), True)]
        else:
            r = int(np.flatnonzero(~kf)[0])
            idx = np.roll(idx, -r)
            kr = np.roll(kf, -r)
            e = np.flatnonzero(np.diff(np.concatenate([[0], kr.astype(np.int8), [0]])))
            pieces = [(idx[a:b], False) for a, b in zip(e[::2], e[1::2]) if b - a >= 2]
        for run, closed in pieces:
            g = np.stack([gx[run], gy[run]], 1)
            if g.shape[0] > 2:          # drop the middle of collinear vertices (exact, integer coordinates)
                d = np.diff(g, axis=0)
                sel = np.concatenate([[True], np.any(d[1:] != d[:-1], axis=1), [True]])
                run, g = run[sel], g[sel]
            xy = np.stack([x0 + 0.5 * h * g[:, 0], y0 + 0.5 * h * g[:, 1]], 1)
            c0 = int(cell[run[0]])
            comp = int(_comp_at(*runs, c0 // ny, c0 % ny))
            out.append(_Piece(comp, xy, cell[run], "loop" if closed else "start", False))
    return out



#: Rounds of :func:`_hug` (each drops at most every other vertex of a run of candidates)
HUG_ROUNDS = 2


def _hug(pieces: list[_Piece], keeps, z: float, need_mm: float, h: float) -> list[_Piece]:
    """The contour pieces with their staircase's steps away from the part taken out where the exact
    clearance allows (module docstring, "Hugging the walls"): a vertex where the chain turns right (the
    part side) and that lies within ``h`` of the chord of its two neighbours is dropped when the tool
    moved along that chord at height ``z`` keeps ``need_mm`` (the allowance) from the cloud
    (``keeps(a (k,2), b (k,2), z, need) -> (k,) bool``:
    :meth:`planning.toolpath.roughing.clearance._MoveClearance.keeps`). A chain's first and last vertex
    stay; lines are returned as they are."""
    out = list(pieces)
    idx = [k for k, p in enumerate(out) if not p.is_line and p.xy.shape[0] >= 3]
    for _ in range(HUG_ROUNDS):
        cand, owner = [], []
        for k in idx:
            xy = out[k].xy
            p, v, n = xy[:-2], xy[1:-1], xy[2:]
            d1, d2, ch = v - p, n - v, n - p
            cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
            L = np.hypot(ch[:, 0], ch[:, 1])
            # the vertex's distance from the chord: |cross| / |chord|
            ok = (cross < -1e-12) & (-cross <= h * L + 1e-12)
            j = np.flatnonzero(ok) + 1                      # vertex index in xy
            if j.size == 0:
                continue
            # at most every other vertex of a run of consecutive candidates (the chords must not overlap)
            run_start = np.concatenate([[True], np.diff(j) != 1])
            pos = np.arange(j.size) - np.maximum.accumulate(np.where(run_start, np.arange(j.size), 0))
            j = j[pos % 2 == 0]
            cand.append(j)
            owner.append(k)
        if not cand:
            break
        a = np.concatenate([out[k].xy[j - 1] for k, j in zip(owner, cand)])
        b = np.concatenate([out[k].xy[j + 1] for k, j in zip(owner, cand)])
        good = keeps(a, b, z, need_mm)
        if not good.any():
            break
        s = 0
        for k, j in zip(owner, cand):
            g = good[s:s + j.size]
            s += j.size
            if g.any():
                keep = np.ones(out[k].xy.shape[0], dtype=bool)
                keep[j[g]] = False
                pc = out[k]
                out[k] = _Piece(pc.comp, pc.xy[keep], pc.cells[keep], pc.ends, pc.is_line, pc.row)
    return out
