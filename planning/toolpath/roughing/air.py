"""Keeping the clearing lines of one level out of the air (Z-level roughing on the stock itself, issue
30; mm, area frame, raster cells of :mod:`planning.toolpath.roughing.maps`). Stage: per level, while
:func:`planning.toolpath.roughing.levels._cut_level` writes the level's pieces.

At the start of a level the stock view says which cells hold material between the level and the one
above (``has``). As the level is cut, :class:`_LevelAir` marks the cells the tool's flat bottom has
surely swept (every point of the cell within ``Rf`` of a cut: the cell's centre within
``Rf - h / sqrt 2``), and before a clearing line is cut its ends are trimmed to the first and the last
of its cells whose tool disc (radius ``Rt`` about the cell's centre) still meets a cell that has
material and is not swept. A line that meets none is not cut. A contour chain (the offset contour
along the part) is trimmed the same way at its ends, and a closed one is opened at its longest run
of such vertices (:meth:`_LevelAir.trim_chain`). So a line that only runs along the band
its neighbour already cleared, or past the stock's edge, is not fed through the air; the gaps inside a
line are kept (it stays one piece). Conservative: a cell counts as swept only when wholly inside a
cut, so a line is never trimmed where material may be left.

**The stock decides the ends** (:func:`_exact_ends`, EXACT_ENDS). The cells leave a rim of a cell at
every cut's edge and count the allowance beside a wall as material to cut, so pieces still start and
end in air. After the cells' trim, the piece's moves (a line's in parts of about LINE_PART_RT cutter
radii) are asked at once whether the cutter, without its shank and holder, swept along them meets the
stock view's material deeper than MEET_DEPTH_MM, on the view as the level's cuts so far left it
(``_LevelAir.meets``: :meth:`planning.toolpath.roughing.levels._LiveStock.meets`, the simulation's own
collision kernel); the leading and trailing moves that meet none are not cut (a loop is opened at its
longest run of them) and a piece none of whose moves meets any is skipped. A move that meets nothing
before the piece is cut meets nothing when it is cut, so no material is lost. The same question decides
the feed links at the level (:func:`planning.toolpath.roughing.levels._cut_level`): a link longer than
LINK_LIFT_MM plus LIFT_SLOWER times the lift's feeds (the retract's rise there, more beside a wall, and
the feed down) that meets no material, to a
piece whose start the cutter meets none at either, is not fed: the tool lifts and the entry
(:mod:`planning.toolpath.roughing.entries`) comes straight down there, in the air the level has cut
(where the next piece starts in material, the link is kept: it brings the tool in from the side, where a
lift would need a helix or ramp, longer to run).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _mark_swept(swept, x0, y0, h, xy, r):
    """Mark the cells whose centre lies within ``r`` of the polyline ``xy`` (m,2)."""
    nx, ny = swept.shape
    if r <= 0.0:
        return
    for k in range(xy.shape[0]):
        ax, ay = xy[k, 0], xy[k, 1]
        if k + 1 < xy.shape[0]:
            bx, by = xy[k + 1, 0], xy[k + 1, 1]
        else:
            bx, by = ax, ay
        dx, dy = bx - ax, by - ay
        L2 = dx * dx + dy * dy
        i0 = max(0, int(math.floor((min(ax, bx) - r - x0) / h)))
        i1 = min(nx - 1, int(math.floor((max(ax, bx) + r - x0) / h)))
        j0 = max(0, int(math.floor((min(ay, by) - r - y0) / h)))
        j1 = min(ny - 1, int(math.floor((max(ay, by) + r - y0) / h)))
        for i in range(i0, i1 + 1):
            cx = x0 + (i + 0.5) * h
            for j in range(j0, j1 + 1):
                if swept[i, j]:
                    continue
                cy = y0 + (j + 0.5) * h
                t = 0.0
                if L2 > 0.0:
                    t = min(1.0, max(0.0, ((cx - ax) * dx + (cy - ay) * dy) / L2))
                ex, ey = cx - (ax + t * dx), cy - (ay + t * dy)
                if ex * ex + ey * ey <= r * r:
                    swept[i, j] = True


@njit(cache=True, nogil=True)
def _useful_cells(has, swept, cells, ny, reach_cells):
    """(k,) bool: whether the disc of ``reach_cells`` cells about each flat raster cell of ``cells``
    meets a cell with ``has`` and not ``swept``."""
    nx = has.shape[0]
    K = int(math.ceil(reach_cells))
    r2 = reach_cells * reach_cells
    out = np.zeros(cells.shape[0], np.bool_)
    for k in range(cells.shape[0]):
        i, j = cells[k] // ny, cells[k] % ny
        for di in range(max(-K, -i), min(K, nx - 1 - i) + 1):
            for dj in range(max(-K, -j), min(K, ny - 1 - j) + 1):
                if di * di + dj * dj <= r2 and has[i + di, j + dj] and not swept[i + di, j + dj]:
                    out[k] = True
                    break
            if out[k]:
                break
    return out


class _LevelAir:
    """One level's material (``has`` (nx, ny) bool: material between the level and the one above) and
    the cells its cuts have swept so far (module docstring). ``Rf``: the flat bottom's radius, ``Rt``
    the cutter's."""

    def __init__(self, has, x0, y0, h, Rt, Rf):
        self.has = np.ascontiguousarray(has, dtype=np.bool_)
        self.swept = np.zeros(self.has.shape, dtype=np.bool_)
        self.x0, self.y0, self.h = float(x0), float(y0), float(h)
        self.Rt = float(Rt)
        self.r_swept = float(Rf) - math.sqrt(0.5) * float(h)
        self.n_marked = 0
        self.meets = None      # ``meets(a, b, z)``: whether moves meet material on the stock view, or None

    def mark(self, polylines: list) -> None:
        """Mark what the polylines ``polylines[n_marked:]`` (the level's cuts, (m,2) each) swept."""
        for xy in polylines[self.n_marked:]:
            _mark_swept(self.swept, self.x0, self.y0, self.h, np.ascontiguousarray(xy, dtype=np.float64),
                        self.r_swept)
        self.n_marked = len(polylines)

    def trim(self, xy: np.ndarray, cells: np.ndarray, ny: int):
        """A clearing line (``xy`` (2,2) along X, ``cells`` its first and last raster cell) trimmed to
        its useful span: (xy, cells), or None when it would cut only air."""
        ca, cb = int(cells[0]), int(cells[-1])
        j = ca % ny
        ia, ib = ca // ny, cb // ny
        lo_i, hi_i = min(ia, ib), max(ia, ib)
        span = np.arange(lo_i, hi_i + 1, dtype=np.int64) * ny + j
        use = np.flatnonzero(_useful_cells(self.has, self.swept, span, ny, self.Rt / self.h))
        if use.size == 0:
            return None
        first, last = lo_i + int(use[0]), lo_i + int(use[-1])
        if first == lo_i and last == hi_i:
            return xy, cells
        h = self.h
        xa = max(self.x0 + first * h, float(min(xy[0, 0], xy[-1, 0])))
        xb = min(self.x0 + (last + 1) * h, float(max(xy[0, 0], xy[-1, 0])))
        y = float(xy[0, 1])
        if ib >= ia:
            return np.array([[xa, y], [xb, y]]), np.array([first * ny + j, last * ny + j])
        return np.array([[xb, y], [xa, y]]), np.array([last * ny + j, first * ny + j])

    def trim_chain(self, xy: np.ndarray, cells: np.ndarray, ny: int, loop: bool):
        """A contour chain (``xy`` (m,2), ``cells`` (m,) its vertices' raster cells; ``loop``: closed,
        ``xy[0] == xy[-1]``) without its ends (an open chain) or its longest run (a loop, which becomes
        an open chain) of vertices whose disc meets no material left at the level: (xy, cells), or
        None when none does. A vertex kept keeps the segments to its neighbours."""
        use = _useful_cells(self.has, self.swept, np.ascontiguousarray(cells, dtype=np.int64), ny, self.Rt / self.h)
        if not use.any():
            return None
        if use.all():
            return xy, cells
        if not loop:
            k = np.flatnonzero(use)
            a, b = max(int(k[0]) - 1, 0), min(int(k[-1]) + 1, len(use) - 1)
            return xy[a:b + 1], cells[a:b + 1]
        m = len(use) - 1                                  # the loop's vertices (the last repeats the first)
        # the longest cyclic run of vertices not used: the chain starts after it and ends before it
        best_start, best_len = _longest_cyclic_run(~use[:m])
        first = (best_start + best_len) % m               # the first vertex used after the run
        order = [(first - 1 + t) % m for t in range(m - best_len + 2)]
        return xy[order], cells[order]



#: A piece's move meets material on the stock view when the cutter swept along it is deeper in the
#: material than this (mm): below it a move removes next to nothing (a re-pass along a cut it made)
MEET_DEPTH_MM = 1e-4
#: Leading moves in air a piece keeps before its first move that meets material (:func:`_exact_ends`;
#: 1: its start is then in air, that move bringing the cutter in from the side). 0 (all go): on the
#: reference cases keeping one changed little and was not measured on its own for the machining time
KEEP_LEAD = 0
#: Whether the pieces' ends are asked of the stock view (:func:`_exact_ends`)
EXACT_ENDS = True
#: On the stock view a feed link at the level longer than this (mm) that meets no material, to a piece
#: that starts in air, is not fed: the tool lifts over it (a retract and a feed down of about the rapid
#: clearance each)
LINK_LIFT_MM = 2.0
#: How many times slower than the roughing feed a lift's feeds run (the default plunge feed, 500 mm/min,
#: against the roughing feed, 2000): a link is lifted over only where it is longer than LINK_LIFT_MM plus
#: this many times the lift's feed up and down, so that the lift is no slower than the link
LIFT_SLOWER = 4.0
#: A clearing line is asked of the stock view in parts about this many cutter radii long
LINE_PART_RT = 0.5


def _longest_cyclic_run(flag: np.ndarray) -> tuple[int, int]:
    """(start, length) of the longest cyclic run of True in ``flag`` (1-D bool, not all True); the first
    such run on a tie."""
    m = flag.size
    r = int(np.argmax(~flag))                           # a False: no run wraps past it
    f = np.roll(flag, -r).astype(np.int8)
    e = np.flatnonzero(np.diff(np.concatenate([[0], f, [0]])))
    if e.size == 0:
        return 0, 0
    starts, ends = e[::2], e[1::2]
    k = int(np.argmax(ends - starts))
    return (int(starts[k]) + r) % m, int(ends[k] - starts[k])


def _ends_meet(meets, pts: np.ndarray, z: float) -> bool:
    """Whether the first and the last move of the polyline ``pts`` (k,2), k >= 2, both meet material
    (``meets`` of :func:`_exact_ends`, both asked at once)."""
    k = pts.shape[0] - 1
    if k < 1:
        return False
    idx = np.array([0, k - 1]) if k > 1 else np.array([0])
    return bool(np.asarray(meets(pts[idx], pts[idx + 1], z), dtype=bool).all())


def _exact_ends(air: _LevelAir, xy: np.ndarray, cells: np.ndarray, ny: int, meets, z: float, loop: bool,
                line: bool):
    """A piece (after :meth:`_LevelAir.trim` / :meth:`_LevelAir.trim_chain`) without its leading and
    trailing moves that meet no material on the stock view (``meets(a (k,2), b (k,2), z) -> (k,) bool``),
    a closed chain opened at its longest run of such moves, a line cut to whole parts of about
    LINE_PART_RT x Rt: (xy, cells), or None when no move meets material. The moves are asked all at once
    of the stock as the level's cuts so far left it: a move that meets nothing there meets nothing when
    it is cut, so no material a piece would cut is lost. A line or an open chain whose first and last
    moves both meet material is kept whole after asking only those two (what the others meet cannot
    change its ends); the other moves are asked only when an end meets nothing."""
    if line:
        a, b = xy[0], xy[-1]
        L = float(np.hypot(*(b - a)))
        n = max(1, int(math.ceil(L / (LINE_PART_RT * air.Rt))))
        t = np.linspace(0.0, 1.0, n + 1)
        pts = a[None, :] + t[:, None] * (b - a)[None, :]
        if _ends_meet(meets, pts, z):
            return xy, cells
        hit = np.asarray(meets(pts[:-1], pts[1:], z), dtype=bool)
        if not hit.any():
            return None
        k0, k1 = max(int(np.argmax(hit)) - KEEP_LEAD, 0), n - 1 - int(np.argmax(hit[::-1]))
        if k0 == 0 and k1 == n - 1:
            return xy, cells
        # the new ends' cells: on the line's row, within its run of cells
        j = int(cells[0]) % ny
        ia, ib = int(cells[0]) // ny, int(cells[-1]) // ny
        lo_i, hi_i = min(ia, ib), max(ia, ib)
        ends = np.array([pts[k0], pts[k1 + 1]])
        ii = np.clip(np.floor((ends[:, 0] - air.x0) / air.h).astype(np.int64), lo_i, hi_i)
        return ends, ii * ny + j
    if not loop and _ends_meet(meets, xy, z):
        return xy, cells
    hit = np.asarray(meets(xy[:-1], xy[1:], z), dtype=bool)
    if not hit.any():
        return None
    if hit.all():
        return xy, cells
    m = hit.size
    if not loop:
        k0, k1 = max(int(np.argmax(hit)) - KEEP_LEAD, 0), m - 1 - int(np.argmax(hit[::-1]))
        return xy[k0:k1 + 2], cells[k0:k1 + 2]
    # a loop (xy[0] == xy[-1], move k from vertex k to k + 1): its longest cyclic run of moves that meet
    # nothing goes; the chain starts at the vertex after that run and ends at the vertex where it began
    start, length = _longest_cyclic_run(~hit)
    length -= min(KEEP_LEAD, length)                   # KEEP_LEAD moves into the material stay
    order = (start + length + np.arange(m - length + 1)) % m
    return xy[order], cells[order]
