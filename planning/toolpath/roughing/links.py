"""Links between the pieces of one level of the Z-level roughing (:mod:`planning.toolpath.roughing`;
mm, area frame): feed moves at the level, straight or along a shortest path on the region's cells
(Popescu et al. 2014: shortest paths on a graph), or lifts over the remaining material. Stage: per
level, while the ordered pieces (:mod:`planning.toolpath.roughing.ordering`) are cut
(:func:`planning.toolpath.roughing.levels._cut_level`); reads the region
(:mod:`planning.toolpath.roughing.regions`) and the remaining-material map
(:mod:`planning.toolpath.roughing.maps`).

**Linking.** Two consecutive pieces of a component are joined at the level by a feed move when the
straight link stays in the region (sampled every h / 4), else along a shortest path on the
8-connected graph of the region's cells (A* with steps counted as 5 and 7 units, 7 / 5 <= sqrt 2,
so no path truly within the limit is missed and the path found is within 1 % of the shortest; the
octile bound; a bucket queue; within the box that can hold a short enough path), shortened by line
of sight, provided that link is no longer than twice the diameter or than lifting (up and down
counted as feed, the rapid across as 1 / RAPID_RATIO of its length), and, on the stock view, unless it
meets no material there, nor does the cutter at its end, and is longer than ``LINK_LIFT_MM`` plus
LIFT_SLOWER times the lift's feeds up and down
(:mod:`planning.toolpath.roughing.air`: a lift then feeds less through air). Otherwise (another
component, a one-way return, a new level, a long link) the tool lifts: retract GAP_MM (1 mm) at
feed (``USE_RETRACT``), rapid up to the link height (straight up from a safe position is safe),
rapid across, rapid down to GAP_MM above the remaining material under the tool disc, and plunge
(feed, ``USE_PLUNGE``) to the level, where that is in air; into material the way down is chosen by
:mod:`planning.toolpath.roughing.entries` (side entry, helix, ramp), which uses these moves. The
link height is GAP_MM above the highest remaining material under the disc along the way
(:class:`planning.toolpath.roughing.maps._MaterialMap`), at most ``safe_z_mm`` (default stock top +
5 mm; the first approach comes down from it, the last move returns to it). Feed links at a level
may cut uncut stock (full width, at most one step down). Fixtures are not obstacles here; the
holder (pieces given) is: its blocked cells are not in the region, so feed links avoid them, and
the link height is also GAP_MM above the holder's height map along the way
(:meth:`_Level.corridor_top`; a position clear at the level is clear above it, so the way up and
down is clear). Cost: the grid searches run in a window, their
scratch arrays reused.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from planning.toolpath.moves import USE_PLUNGE, USE_RAPID, USE_RETRACT

GAP_MM = 1.0            #: rapids stop this far above the remaining material, mm
RAPID_RATIO = 5.0       #: a rapid counts as 1 / RAPID_RATIO of its length of feed when links are compared
STEP_UNITS = 5          #: grid searches count a side step as 5 units and a diagonal one as 7 (7 / 5 <= sqrt 2)
DIAG_UNITS = 7


# ----------------------------------------------------------------------------------------------
# Straight links and grid searches at a level (numba)
# ----------------------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def _cell_at(x, y, x0, y0, h, nx, ny, e):
    ix = min(max(int(math.floor((x - x0) / h + e)), 0), nx - 1)
    iy = min(max(int(math.floor((y - y0) / h + e)), 0), ny - 1)
    return ix, iy


@njit(cache=True, nogil=True)
def _n_samples(ax, ay, bx, by, h):
    return max(1, int(math.ceil(math.hypot(bx - ax, by - ay) / (0.25 * h))))


@njit(cache=True, nogil=True)
def _seg_in(flat, x0, y0, h, nx, ny, ax, ay, bx, by):
    """Every sample of a -> b (h / 4 apart, ends included) lies in a cell where ``flat`` is True
    (a sample within 1e-9 h of a cell edge may count for the cell on either side)."""
    n = _n_samples(ax, ay, bx, by, h)
    for k in range(n + 1):
        t = k / n
        x = ax + (bx - ax) * t
        y = ay + (by - ay) * t
        ok = False
        for eu in (-1e-9, 1e-9):
            ix, _ = _cell_at(x, y, x0, y0, h, nx, ny, eu)
            for ev in (-1e-9, 1e-9):
                _, iy = _cell_at(x, y, x0, y0, h, nx, ny, ev)
                if flat[ix * ny + iy]:
                    ok = True
        if not ok:
            return False
    return True


@njit(cache=True, nogil=True)
def _seg_max(vals, x0, y0, h, nx, ny, ax, ay, bx, by):
    """Largest ``vals`` over the cells of the samples of a -> b (h / 4 apart)."""
    n = _n_samples(ax, ay, bx, by, h)
    best = -np.inf
    for k in range(n + 1):
        t = k / n
        ix, iy = _cell_at(ax + (bx - ax) * t, ay + (by - ay) * t, x0, y0, h, nx, ny, 0.0)
        v = vals[ix * ny + iy]
        best = max(best, v)
    return best


@njit(cache=True, nogil=True)
def _line_of_sight(flat, x0, y0, h, nx, ny, pts):
    """Indices of the points kept when shortening the polyline ``pts`` by line of sight: from each
    kept point jump to the farthest later point seen straight (:func:`_seg_in`), found by
    bisection when the last is not seen (the first and last points are kept)."""
    last = pts.shape[0] - 1
    out = np.empty(last + 1, np.int64)
    out[0] = 0
    m = 1
    i = 0
    while i < last:
        if _seg_in(flat, x0, y0, h, nx, ny, pts[i, 0], pts[i, 1], pts[last, 0], pts[last, 1]):
            j = last
        else:
            lo = i + 1
            hi = last - 1
            while lo < hi:
                mid = (lo + hi + 1) // 2
                if _seg_in(flat, x0, y0, h, nx, ny, pts[i, 0], pts[i, 1], pts[mid, 0], pts[mid, 1]):
                    lo = mid
                else:
                    hi = mid - 1
            j = lo
        out[m] = j
        m += 1
        i = j
    return out[:m]


@njit(cache=True, nogil=True)
def _link_path(flat, x0, y0, h, nx, ny, ax, ay, bx, by, ca, cb, limit, dist, pred, stamp, call):
    """:meth:`_Level.grid_path` in one call: the search window (the box of a and b grown by half the
    slack ``limit - |ab|`` and 2 h), :func:`_grid_path_cells`, the cell centres between a and b,
    :func:`_line_of_sight`, and the length check. Returns the path (k, 2), or (0, 2) when there is
    none within the limit."""
    none = np.zeros((0, 2))
    if not (flat[ca] and flat[cb]):
        return none
    grow = 0.5 * max(limit - math.hypot(bx - ax, by - ay), 0.0) + 2 * h
    i0 = max(int(math.floor((min(ax, bx) - grow - x0) / h)), 0)
    i1 = min(int(math.floor((max(ax, bx) + grow - x0) / h)) + 1, nx)
    j0 = max(int(math.floor((min(ay, by) - grow - y0) / h)), 0)
    j1 = min(int(math.floor((max(ay, by) + grow - y0) / h)) + 1, ny)
    c = _grid_path_cells(flat, nx, ny, h, ca, cb, limit, i0, i1, j0, j1, dist, pred, stamp, call)
    if c.shape[0] == 0:
        return none
    pts = np.empty((c.shape[0] + 2, 2))
    pts[0, 0] = ax
    pts[0, 1] = ay
    for k in range(c.shape[0]):
        pts[k + 1, 0] = x0 + (c[k] // ny + 0.5) * h
        pts[k + 1, 1] = y0 + (c[k] % ny + 0.5) * h
    pts[-1, 0] = bx
    pts[-1, 1] = by
    keep = _line_of_sight(flat, x0, y0, h, nx, ny, pts)
    path = np.empty((keep.shape[0], 2))
    length = 0.0
    for k in range(keep.shape[0]):
        path[k, 0] = pts[keep[k], 0]
        path[k, 1] = pts[keep[k], 1]
        if k > 0:
            length += math.hypot(path[k, 0] - path[k - 1, 0], path[k, 1] - path[k - 1, 1])
    if not length <= limit:
        return none
    return path


@njit(cache=True, nogil=True)
def _grid_path_cells(flat, nx, ny, h, src, dst, limit, i0, i1, j0, j1, dist, pred, stamp, call):
    """A short path from cell ``src`` to cell ``dst`` (flat indices) over the 8-connected cells
    where ``flat`` is True inside the window [i0, i1) x [j0, j1): A* in integer units (a side step
    STEP_UNITS, a diagonal one DIAG_UNITS, so a length in units / STEP_UNITS * h never exceeds the
    true length) with the octile distance as the (consistent) bound of the rest and a bucket queue
    on the integer priority (f never decreases: one pass over the buckets; last in, first out
    within one). Cells whose length so far plus the bound exceeds ``limit`` (in units, so no path
    truly within the limit is cut) are not searched. ``dist``, ``pred``, ``stamp`` (nx * ny):
    scratch reused between calls, a cell's entries being valid only where ``stamp == call`` (a
    number never used before). Returns the flat cell indices from src to dst (empty when there is
    none within the limit). A numba kernel of about 90 lines: the search loop stays in one body,
    the growth of its entry arrays included (a call there made the searches about 4 % slower)."""
    ti = dst // ny
    tj = dst % ny
    lim = int(math.floor(limit / h * STEP_UNITS + 1e-9))
    f0 = _octile(src // ny, src % ny, ti, tj)
    if f0 > lim:
        return np.zeros(0, np.int64)
    nb = lim - f0 + 1
    head = np.full(nb, -1, np.int64)
    cap = 4096
    ev = np.empty(cap, np.int64)          # entries: cell, length so far, next entry in the bucket
    eg = np.empty(cap, np.int64)
    en = np.empty(cap, np.int64)
    stamp[src] = call
    dist[src] = 0
    pred[src] = -1
    ev[0] = src
    eg[0] = 0
    en[0] = -1
    head[0] = 0
    ne = 1
    b = 0
    found = False
    while b < nb:
        e = head[b]
        if e < 0:
            b += 1
            continue
        head[b] = en[e]
        u = ev[e]
        d = eg[e]
        if d > dist[u]:
            continue
        if u == dst:
            found = True
            break
        ui = u // ny
        uj = u % ny
        for di in range(-1, 2):
            vi = ui + di
            if vi < i0 or vi >= i1:
                continue
            for dj in range(-1, 2):
                if di == 0 and dj == 0:
                    continue
                vj = uj + dj
                if vj < j0 or vj >= j1:
                    continue
                v = vi * ny + vj
                if not flat[v]:
                    continue
                nd = d + (DIAG_UNITS if di != 0 and dj != 0 else STEP_UNITS)
                if stamp[v] == call and nd >= dist[v]:
                    continue
                f = nd + _octile(vi, vj, ti, tj)
                if f > lim:
                    continue
                stamp[v] = call
                dist[v] = nd
                pred[v] = u
                if ne == cap:
                    cap *= 2
                    v2 = np.empty(cap, np.int64)
                    g2 = np.empty(cap, np.int64)
                    n2 = np.empty(cap, np.int64)
                    for q in range(ne):
                        v2[q] = ev[q]
                        g2[q] = eg[q]
                        n2[q] = en[q]
                    ev, eg, en = v2, g2, n2
                k = f - f0
                ev[ne] = v
                eg[ne] = nd
                en[ne] = head[k]
                head[k] = ne
                ne += 1
    if not found:
        return np.zeros(0, np.int64)
    return _trace_back(pred, src, dst)


@njit(cache=True, nogil=True)
def _octile(i, j, ti, tj):
    """The octile distance, in STEP_UNITS / DIAG_UNITS units, from cell (i, j) to cell (ti, tj)."""
    ai = abs(i - ti)
    aj = abs(j - tj)
    return STEP_UNITS * max(ai, aj) + (DIAG_UNITS - STEP_UNITS) * min(ai, aj)


@njit(cache=True, nogil=True)
def _trace_back(pred, src, dst):
    """The flat cell indices from ``src`` to ``dst`` following ``pred`` back from dst."""
    m = 1
    u = dst
    while u != src:
        u = pred[u]
        m += 1
    out = np.empty(m, np.int64)
    u = dst
    for k in range(m - 1, -1, -1):
        out[k] = u
        u = pred[u]
    return out


# ----------------------------------------------------------------------------------------------
# A level's raster state, and the moves of links and lifts
# ----------------------------------------------------------------------------------------------

class _Scratch:
    """Arrays of the grid searches, allocated at the first search and kept for the whole roughing
    (see :func:`_grid_path_cells`)."""

    def __init__(self, n):
        self.n = n
        self.dist = self.pred = self.stamp = None
        self.calls = 0

    def next_call(self):
        if self.stamp is None:
            self.dist = np.empty(self.n, np.int32)
            self.pred = np.empty(self.n, np.int32)
            self.stamp = np.zeros(self.n, np.int32)
        self.calls += 1
        return self.calls


class _Level:
    """Per-level raster state used while ordering and linking. ``hold`` (the material map's shape)
    or None: the height the tool tip must stay above for the holder to clear the material
    (:class:`planning.toolpath.roughing.maps._HolderMap`: ``HT``, already grown by the holder's
    reach), read along the rapids of lifts. ``reach`` (nx, ny) bool or None (everywhere): the cells
    whose centre, as a tool tip at the level, is within the machine's travel (the region's travel
    limit without its other limits), where a step off a wall may go outside the region."""

    def __init__(self, region, x0, y0, h, nx, ny, z, top_dil, H, Rt, scratch, hold=None, reach=None):
        self.Rt = Rt
        self.scratch = scratch
        self.region = region
        self.flat = region.ravel()
        self.x0, self.y0, self.h, self.nx, self.ny = x0, y0, h, nx, ny
        self.z = z
        self.H = H                                   # the material map's coarse cells, same origin
        self.ncx, self.ncy = top_dil.shape
        self.top_flat = np.ascontiguousarray(top_dil).ravel()
        self.hold_flat = None if hold is None else np.ascontiguousarray(hold).ravel()
        self.reach_flat = None if reach is None else np.ascontiguousarray(reach).ravel()

    def top_at(self, xy) -> float:
        """Highest remaining material under the tool disc about xy (from the dilated map)."""
        ix = min(max(int(math.floor((xy[0] - self.x0) / self.H)), 0), self.ncx - 1)
        iy = min(max(int(math.floor((xy[1] - self.y0) / self.H)), 0), self.ncy - 1)
        return float(self.top_flat[ix * self.ncy + iy])

    def cell_of(self, xy):
        """Flat index of the cell containing each point (clipped into the raster)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ix = np.clip(np.floor((xy[:, 0] - self.x0) / self.h).astype(np.int64), 0, self.nx - 1)
        iy = np.clip(np.floor((xy[:, 1] - self.y0) / self.h).astype(np.int64), 0, self.ny - 1)
        return ix * self.ny + iy

    def visible(self, a, b) -> bool:
        """The straight move a -> b at the level stays in the region: every sample (h / 4 apart) lies
        in a region cell, so every point of the move is within 0.96 h of an allowed centre."""
        return self._along(self.flat, a, b)

    def reachable(self, a, b) -> bool:
        """The straight move a -> b at the level stays within the machine's travel (every sample in a
        ``reach`` cell, as :meth:`visible` reads the region); True without a travel limit."""
        return self.reach_flat is None or self._along(self.reach_flat, a, b)

    def _along(self, flat, a, b) -> bool:
        """Every sample of a -> b (h / 4 apart) in a cell where the raster ``flat`` is True."""
        return bool(_seg_in(flat, self.x0, self.y0, self.h, self.nx, self.ny,
                            float(a[0]), float(a[1]), float(b[0]), float(b[1])))

    def corridor_top(self, a, b) -> float:
        """Highest remaining material under the tool disc along a -> b (from the dilated map), and
        with the holder at least the holder's height along it (samples H / 4 apart)."""
        t = float(_seg_max(self.top_flat, self.x0, self.y0, self.H, self.ncx, self.ncy,
                           float(a[0]), float(a[1]), float(b[0]), float(b[1])))
        if self.hold_flat is not None:
            t = max(t, float(_seg_max(self.hold_flat, self.x0, self.y0, self.H, self.ncx, self.ncy,
                                      float(a[0]), float(a[1]), float(b[0]), float(b[1]))))
        return t

    def grid_path(self, a, ca, b, cb, limit):
        """Shortest path at the level from a (in region cell ca) to b (cell cb) on the 8-connected
        graph of region cells (Popescu's graph; :func:`_grid_path_cells`), shortened by line of
        sight (:func:`_line_of_sight`); None when longer than ``limit`` (the search stays in the box
        holding every such path)."""
        sc = self.scratch
        call = sc.next_call()
        path = _link_path(self.flat, self.x0, self.y0, self.h, self.nx, self.ny, float(a[0]), float(a[1]),
                          float(b[0]), float(b[1]), int(ca), int(cb), float(limit), sc.dist, sc.pred, sc.stamp,
                          call)
        return path if path.shape[0] else None

class _Writer:
    """Collects the moves (tip points and uses) and the counts."""

    def __init__(self):
        self.pts: list[np.ndarray] = []
        self.codes: list[int] = []
        self.counts: list[int] = []
        self.n_retracts = 0
        #: ``column_clear(x, y, z, top)`` -> the lowest height at or above z from which a rapid straight
        #: up to ``top`` is clear of the material by the rapid clearance, read on the stock itself
        #: (None: no clearance asked)
        self.column_clear = None
        #: ``rapid_clear(a, b, z, top)`` -> the lowest height >= z (at most ``top``) at which a rapid
        #: from a to b (x, y) is clear of the material by the rapid clearance, on the stock itself
        self.rapid_clear = None
        #: how far a retract feeds up out of the cut and a lift's rapid stops above the material under
        #: it (mm): GAP_MM, or less where the stock itself is read (``column_clear``: the rapids are
        #: checked on it, so the gap is only what the feed needs, not a guard against the maps' error)
        self.gap = GAP_MM
        #: ``column_clear_many(points (n,3), top)`` -> (n,) ``column_clear`` of each point at once (None:
        #: no clearance asked); where a retract or a lift's descent beside a wall may step off it
        self.column_clear_many = None

    def add(self, xyz, use):
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        self.pts.append(xyz)
        self.codes.append(use)
        self.counts.append(xyz.shape[0])

    def use(self) -> np.ndarray:
        return np.repeat(np.array(self.codes, np.int8), self.counts)


def _link_height(lv: _Level, a, b, z_from, z_to, safe):
    zt = lv.corridor_top(a, b) + GAP_MM
    return min(safe, max(zt, z_from + GAP_MM, z_to + GAP_MM))


def _lift_cost(lv: _Level, a, b, z, safe) -> float:
    """What lifting from a to b at level z costs, as a length of feed: up and down at feed, the rapid
    across at 1 / RAPID_RATIO of its length."""
    zl = _link_height(lv, a, b, z, z, safe)
    return 2.0 * (zl - z) + float(np.hypot(*(b - a))) / RAPID_RATIO


#: A retract (or a lift's descent) steps off a wall beside it when that saves at least this much of
#: its feed straight up (mm)
STEP_OFF_GAIN_MM = 1.0


def _step_off(w: _Writer, lv: _Level | None, xyz, zl):
    """Where a feed straight up from the tip ``xyz`` beside a wall would run up the wall (the tool grown
    by the rapid clearance touches the allowance the level left on it): the point p ``w.gap`` away at
    the level (8 directions) from which the rapid up is clear lowest, and that height
    (:attr:`_Writer.column_clear_many` from ``w.gap`` above the tip, at most ``zl``); None when there is
    none or nothing to ask. A direction qualifies when the move to p stays in ``lv``'s region (at the
    level or below ``xyz``: allowed there, so allowed at ``xyz``'s height), or, outside the region (in
    the air beside the stock, where a level at the block's edge leaves the tool), when it stays within
    the machine's travel (:meth:`_Level.reachable`) and the tool grown by the rapid clearance is clear
    of the material and the obstacles all the way up from ``w.gap`` above the tip at p: the stock
    holds the part and its allowance, so a tool clear of the stock there is clear of the part, and
    the move up and out to p sweeps nothing the tool at its two ends does not (on a retract from a
    level cut along the block's lower edge with a tilted axis, the feed up the wall ran with the tip
    under the block)."""
    if lv is None or w.column_clear_many is None or lv.z > float(xyz[2]) + 1e-9:
        return None
    a = np.asarray(xyz[:2], dtype=np.float64)
    t = np.arange(8) * (math.pi / 4.0)
    cand = a + w.gap * np.column_stack([np.cos(t), np.sin(t)])
    inside = np.array([lv.visible(a, cand[k]) for k in range(8)])
    ok = [k for k in range(8) if inside[k] or lv.reachable(a, cand[k])]
    if not ok:
        return None
    z1 = float(xyz[2]) + w.gap
    zc = np.asarray(w.column_clear_many(np.column_stack([cand[ok], np.full(len(ok), z1)]), zl), dtype=np.float64)
    zc = np.where(inside[ok] | (zc <= z1 + 1e-9), zc, np.inf)
    k = int(np.argmin(zc))
    if not np.isfinite(zc[k]):
        return None
    return cand[ok[k]], float(zc[k])


def _retract(w: _Writer, cur, zl, lv: _Level | None = None):
    """Out of the cut by ``w.gap`` (GAP_MM without a stock view) at feed (``USE_RETRACT``), then up to ``zl`` by rapid (straight up
    from a position that is safe at its level is safe at any height above). With a rapid clearance
    (``w.column_clear``) the feed goes on up until the tool grown by it clears the material beside
    (the wall the tool has just cut along, the part's allowance), so that the rapid does not brush
    it; with ``lv`` (the level moved to) where that feed would run STEP_OFF_GAIN_MM or more up the
    wall, the retract steps ``w.gap`` off it instead (:func:`_step_off`, up and out at 45 degrees) and
    the rapid rises from there. Returns the x, y where the tool is at ``zl``."""
    zr = cur[2] + w.gap
    if w.column_clear is not None:             # the stock itself, as the moves so far left it
        zr = max(zr, w.column_clear(cur[0], cur[1], cur[2], zl))
    zr = min(zr, zl)
    if zr > cur[2] + w.gap + STEP_OFF_GAIN_MM:
        off = _step_off(w, lv, cur, zl)
        z1 = cur[2] + w.gap
        if off is not None and off[1] + STEP_OFF_GAIN_MM < zr and z1 < zl:
            p, zc = off
            w.add([p[0], p[1], z1], USE_RETRACT)
            if min(zc, zl) > z1:
                w.add([p[0], p[1], min(zc, zl)], USE_RETRACT)
            w.n_retracts += 1
            if zl > max(zc, z1):
                w.add([p[0], p[1], zl], USE_RAPID)
            return np.asarray(p, dtype=np.float64)
    w.add([cur[0], cur[1], zr], USE_RETRACT)
    w.n_retracts += 1
    if zl > zr:
        w.add([cur[0], cur[1], zl], USE_RAPID)
    return np.array(cur[:2], dtype=np.float64)


def _lift(w: _Writer, lv: _Level, cur, q, z, safe, top_q=None):
    """Lift from ``cur`` (or from nowhere: first approach at the safe height), rapid over, rapid down to
    ``w.gap`` (GAP_MM without a stock view) above the remaining material under the disc at q (``top_q``: that height, mm, when the
    caller knows it more closely than the dilated map's :meth:`_Level.top_at`; never below the
    material), plunge to z. Where that rapid down would stop STEP_OFF_GAIN_MM or more higher (the grown
    tool beside a wall), it comes down instead at a point ``w.gap`` off (:func:`_step_off`) whose column
    the grown tool clears down to ``w.gap`` above the level, and feeds in to q at 45 degrees."""
    if cur is None:
        zl = safe
        w.add([q[0], q[1], safe], USE_RAPID)
    else:
        a = np.array(cur[:2])
        zl = _link_height(lv, a, q, cur[2], z, safe)
        if w.rapid_clear is not None:          # the grown tool clear of the material beside the way
            zl = w.rapid_clear(a, q, zl, safe)
        a2 = _retract(w, cur, zl, lv)
        zl = _rapid_from(w, a, a2, q, zl, safe)
    zd = min(zl, max(lv.top_at(q) if top_q is None else top_q, z) + w.gap)
    if w.column_clear is not None:             # the grown tool keeps clear of the material beside
        zd = min(zl, w.column_clear(q[0], q[1], zd, zl))
    if cur is not None:
        if _down_off_wall(w, lv, q, z, zd, zl, safe):
            return
        w.add([q[0], q[1], zl], USE_RAPID)
    if zd < zl:
        w.add([q[0], q[1], zd], USE_RAPID)
    w.add([q[0], q[1], z], USE_PLUNGE)


def _down_off_wall(w: _Writer, lv: _Level, q, z, zd, zl, safe) -> bool:
    """Where the rapid down to (q, z) would stop at ``zd``, STEP_OFF_GAIN_MM or more above ``w.gap`` over
    z (the tool grown by the rapid clearance meets the stock beside: the rest would be fed straight
    down, by a wall or in the air under a tilted block's lower edge): come down instead at a point
    ``w.gap`` off (:func:`_step_off`) whose column the grown tool clears all the way down to ``w.gap``
    above z, and feed in to (q, z) at 45 degrees. The tool is at the last point written, at ``zl`` (the
    rapid across to q not yet written). Used by a lift's descent (:func:`_lift`) and by the approach to
    a helix or ramp (:func:`planning.toolpath.roughing.entries._approach`). Writes the moves and returns
    True, or writes nothing and returns False."""
    z1 = z + w.gap
    if not zd > z1 + STEP_OFF_GAIN_MM:
        return False
    off = _step_off(w, lv, (q[0], q[1], z), zl)
    # only where the rapid comes down at p all the way to z1: a feed straight down there could meet
    # material (nothing says that p's column is air below where the grown tool clears it)
    if off is None or off[1] > z1 + 1e-9 or not off[1] + STEP_OFF_GAIN_MM < zd:
        return False
    p = off[0]
    up = w.pts[-1][-1]
    zl2 = _rapid_from(w, up[:2], up[:2], p, zl, safe, at=False)
    if zl2 > zl:
        w.add([up[0], up[1], zl2], USE_RAPID)
    w.add([p[0], p[1], zl2], USE_RAPID)
    if z1 < zl2:
        w.add([p[0], p[1], z1], USE_RAPID)
    w.add([q[0], q[1], z], USE_PLUNGE)
    return True


def _rapid_from(w: _Writer, a, a2, q, zl, safe, at: bool = True) -> float:
    """The height of the rapid across to q: ``zl`` (checked from ``a``), or, where the retract ended at
    another x, y ``a2`` (stepped off a wall), the rapid clearance's own height from there, no lower
    (``at``: the tool is raised to it at ``a2`` here). Returns that height."""
    if w.rapid_clear is None or (np.allclose(a, a2) and at):
        return zl
    z2 = max(zl, w.rapid_clear(np.asarray(a2, dtype=np.float64), np.asarray(q, dtype=np.float64), zl, safe))
    if at and z2 > zl:
        w.add([a2[0], a2[1], z2], USE_RAPID)
    return z2
