"""Collision test of the tool assembly with its own tool axis per ball-centre position.

:mod:`planning.geometry.collision` checks many ball centres against one tool axis at a time (a raster
per axis). Simultaneous 5-axis finishing gives every ball-centre position ``centres[i]`` (part frame,
mm) its own unit tool axis ``axes[i]`` (part frame, pointing from the part towards the spindle).
:func:`pointwise_collision_free` answers, per position, whether the cutter, shank and holder above
the ball centre leave every obstacle point (the cloud, mm) outside, with exactly the rule of
:mod:`planning.geometry.collision`: for an obstacle point ``q``, ``d = q - c``, ``a = d . t`` (height
above the ball centre along the axis) and ``rho = |d - a t|`` (distance from the axis), and with
``EPS_MM = 1e-6``

    q collides with position i  when, for some segment (lo, hi, r) of the tool,
                                lo < a <= hi  (hi None: unbounded)  and  rho < r - EPS_MM.

The ball itself (``a <= 0``) is not tested: the local gouge test belongs to the tool paths. ``parts``
restricts the test to segments of those parts (``"cutter"``, ``"shank"``, ``"holder"``).
:func:`brute_force_pointwise` is the reference (every position against every point, numpy, with
:mod:`~planning.geometry.collision`'s own ``_inside`` and ``_segments``); the fast method gives the
same answer position for position, the floating-point expressions of ``a`` and ``rho`` being the
reference's, in the same order.

Axes are scaled to unit length (an axis already unit to within ``1e-12`` is used exactly as given, as
:mod:`~planning.geometry.collision` does, so a unit axis gives its answer bit for bit); zero,
near-zero (``< 1e-9``) and non-finite axes raise :class:`planning.errors.ParameterError`.

**Method.** :class:`ObstacleGrid` bins the obstacles into a uniform 3-D grid of cubic cells of side
``cell_mm`` over their bounding box (by default half the smallest segment radius of the tool,
:func:`default_cell_mm`) and sorts them by the Morton code of their cell, so the points of one cell,
and of every aligned block of 2^l x 2^l x 2^l cells, are contiguous. Only occupied cells are kept:
the leaves of an octree whose level-l nodes are the occupied blocks, each node holding the tight
bounding box of its points (memory O(points), whatever the box's extent: no dense array of cells).
The grid is built once (``O(K log K)``) and serves any number of batches of positions, tools and
axes (:meth:`ObstacleGrid.free`).

For one position the tool is the union of its segments, written as a piecewise radius over ``a``
(breakpoints: every ``lo`` and ``hi``; on each piece the largest ``r - EPS_MM`` of the segments
covering it, which decides ``rho < r - EPS_MM`` for some segment exactly, subtraction being
monotone). A numba kernel (parallel over positions, ``prange``; positions visited in Morton order for
locality) walks the octree depth first from the root and descends only into nodes whose box can meet
the tool: the box's range of ``a`` (its centre's ``a`` plus or minus ``sum |t_k| half_k``) must
overlap a piece of the tool, and its centre's distance from the axis less the box's half diagonal must
be below that piece's largest radius (both widened by a rounding margin of ``1e-8`` times the
coordinates' scale). Unbounded segments need no clipping: only occupied boxes exist. The points of a
leaf (one cell) are tested exactly, ``rho < r - EPS_MM`` decided on ``rho^2`` where a relative margin
of ``1e-12`` makes it clear-cut and on ``sqrt`` (the reference's expression) otherwise, and the walk
stops at the first colliding point. The hierarchy keeps the cost of large, far cylinders (a holder of
radius 25 mm spans tens of thousands of 1.5 mm cells, nearly all empty or far from the tool) to a few
coarse boxes, while points are read only in the cells next to the tool.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Iterable, Optional

import numpy as np
from numba import njit, prange

from planning.errors import ParameterError
from planning.geometry.collision import EPS_MM, _inside, _segments
from planning.geometry.tool import ToolAssembly

#: Default cell side as a fraction of the smallest segment radius tested (speed only, never the answer).
CELL_FRACTION = 0.5
#: Largest number of cells along one side of the grid (Morton codes: 21 bits per coordinate).
_MAX_SIDE_CELLS = 1 << 20
#: Positions per kernel call (between two progress reports).
_BATCH = 1 << 16
#: Depth-first stack per thread: at most 8 children pushed per level, 21 levels and the root.
_STACK = 8 * 24 + 8
_KNOWN_PARTS = ("cutter", "shank", "holder")


# ----------------------------------------------------------------------------------------------
# validation

def _points(x, name: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ParameterError(f"{name} must be an (n,3) array, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ParameterError(f"{name} must be finite")
    return np.ascontiguousarray(x)


def _unit_axes(axes, n: int) -> np.ndarray:
    """Axes (n,3) scaled to unit length; rows unit to within 1e-12 kept bit for bit."""
    t = _points(axes, "axes")
    if t.shape[0] != n:
        raise ParameterError(f"axes must have one row per centre ({n}), got {t.shape[0]}")
    norm = np.sqrt(np.einsum("ij,ij->i", t, t))
    if norm.size and not norm.min() >= 1e-9:
        raise ParameterError(f"axis {int(np.argmin(norm))} has (near) zero length: tool axes must be "
                             "non-zero vectors")
    fix = np.abs(norm - 1.0) > 1e-12
    if fix.any():
        t = t.copy()
        t[fix] /= norm[fix, None]
    return t


def _tool_segments(tool, parts) -> list[tuple[float, Optional[float], float]]:
    """``collision._segments`` of the tool, restricted to ``parts`` (None: all)."""
    if not isinstance(tool, ToolAssembly):
        raise ParameterError("tool must be a planning.geometry.tool.ToolAssembly")
    if parts is not None:
        if isinstance(parts, str):
            parts = (parts,)
        try:
            names = {str(p) for p in parts}
        except TypeError:
            raise ParameterError("parts must be a sequence of part names") from None
        known = set(_KNOWN_PARTS) | {s.part for s in tool.segments}
        unknown = sorted(names - known)
        if unknown:
            raise ParameterError(f"unknown tool part(s) {unknown}: known parts are {sorted(known)}")
        tool = dataclasses.replace(tool, segments=tuple(s for s in tool.segments if s.part in names))
    return _segments(tool)


def default_cell_mm(tool: ToolAssembly, parts: Optional[Iterable[str]] = None) -> float:
    """The grid cell side (mm) :func:`pointwise_collision_free` uses for ``tool``: ``CELL_FRACTION``
    times the smallest radius of the segments tested (1 mm when none is)."""
    segs = _tool_segments(tool, parts)
    return CELL_FRACTION * min(r for _, _, r in segs) if segs else 1.0


def _pieces(segs):
    """The union of the segments as pieces ``(B[k], B[k+1]]`` of ``a`` with threshold ``thr[k]`` =
    the largest ``r - EPS_MM`` of the segments covering the piece (0: none), neighbours of equal
    threshold merged; ``B[-1] = inf`` when a segment is unbounded. Also ``thr^2`` with relative
    margins -/+ 1e-12 (the kernel's clear-cut tests)."""
    bps = sorted({lo for lo, _, _ in segs} | {hi for _, hi, _ in segs if hi is not None})
    if any(hi is None for _, hi, _ in segs):
        bps.append(math.inf)
    B = [bps[0]]
    thr: list[float] = []
    for b0, b1 in zip(bps[:-1], bps[1:]):
        th = 0.0
        for lo, hi, r in segs:
            if lo <= b0 and (hi is None or hi >= b1):
                th = max(th, r - EPS_MM)        # the reference's threshold, the same float
        if thr and thr[-1] == th:
            B[-1] = b1                          # (B[k-1], b0] and (b0, b1] share a threshold
        else:
            thr.append(th)
            B.append(b1)
    thr_a = np.asarray(thr, dtype=np.float64)
    return (np.asarray(B, dtype=np.float64), thr_a, thr_a * thr_a * (1.0 - 1e-12),
            thr_a * thr_a * (1.0 + 1e-12))


# ----------------------------------------------------------------------------------------------
# the grid (Morton-ordered octree of occupied cells)

@njit(cache=True, nogil=True, inline="always")
def _spread(v):
    """The 21 low bits of ``v`` spread to every third bit."""
    v &= 0x1FFFFF
    v = (v | (v << 32)) & 0x1F00000000FFFF
    v = (v | (v << 16)) & 0x1F0000FF0000FF
    v = (v | (v << 8)) & 0x100F00F00F00F00F
    v = (v | (v << 4)) & 0x10C30C30C30C30C3
    v = (v | (v << 2)) & 0x1249249249249249
    return v


@njit(cache=True, nogil=True)
def _morton(x, o0, o1, o2, h, n0, n1, n2):
    """Morton code of the cell of each row of ``x`` (k,3) in the grid of origin ``o``, side ``h``,
    ``n0 x n1 x n2`` cells (indices clipped into the grid)."""
    out = np.empty(x.shape[0], np.int64)
    for i in range(x.shape[0]):
        i0 = min(max(int(math.floor((x[i, 0] - o0) / h)), 0), n0 - 1)
        i1 = min(max(int(math.floor((x[i, 1] - o1) / h)), 0), n1 - 1)
        i2 = min(max(int(math.floor((x[i, 2] - o2) / h)), 0), n2 - 1)
        out[i] = _spread(np.int64(i0)) | (_spread(np.int64(i1)) << 1) | (_spread(np.int64(i2)) << 2)
    return out


@njit(cache=True, nogil=True)
def _leaves(pts, codes):
    """Runs of equal codes of the sorted ``codes``: per leaf (point range, tight box lo/hi, code)."""
    n = codes.shape[0]
    cnt = 0
    for i in range(n):
        if i == 0 or codes[i] != codes[i - 1]:
            cnt += 1
    rng = np.empty((cnt, 2), np.int64)
    lo = np.empty((cnt, 3))
    hi = np.empty((cnt, 3))
    lcode = np.empty(cnt, np.int64)
    k = -1
    for i in range(n):
        if i == 0 or codes[i] != codes[i - 1]:
            k += 1
            rng[k, 0] = i
            lcode[k] = codes[i]
            for j in range(3):
                lo[k, j] = pts[i, j]
                hi[k, j] = pts[i, j]
        rng[k, 1] = i + 1
        for j in range(3):
            lo[k, j] = min(lo[k, j], pts[i, j])
            hi[k, j] = max(hi[k, j], pts[i, j])
    return rng, lo, hi, lcode


@njit(cache=True, nogil=True)
def _parents(lo, hi, codes, offset):
    """The level above nodes ``offset + k`` (their codes >> 3, sorted): per parent (child index
    range, box lo/hi, code)."""
    n = codes.shape[0]
    cnt = 0
    for i in range(n):
        if i == 0 or (codes[i] >> 3) != (codes[i - 1] >> 3):
            cnt += 1
    rng = np.empty((cnt, 2), np.int64)
    plo = np.empty((cnt, 3))
    phi = np.empty((cnt, 3))
    pcode = np.empty(cnt, np.int64)
    k = -1
    for i in range(n):
        if i == 0 or (codes[i] >> 3) != (codes[i - 1] >> 3):
            k += 1
            rng[k, 0] = offset + i
            pcode[k] = codes[i] >> 3
            for j in range(3):
                plo[k, j] = lo[i, j]
                phi[k, j] = hi[i, j]
        rng[k, 1] = offset + i + 1
        for j in range(3):
            plo[k, j] = min(plo[k, j], lo[i, j])
            phi[k, j] = max(phi[k, j], hi[i, j])
    return rng, plo, phi, pcode


class ObstacleGrid:
    """The obstacle points (K,3) mm binned once into cells of side ``cell_mm`` (an octree of the
    occupied cells, module docstring), for :meth:`free` on any number of batches of positions.

    ``cell_mm`` affects the speed only, never the answer; :func:`default_cell_mm` gives the default for
    a tool (half its smallest segment radius). It is raised where the bounding box would need more
    than 2^20 cells along a side.
    """

    def __init__(self, obstacles, cell_mm: float):
        obst = _points(obstacles, "obstacles")
        h = float(cell_mm)
        if not (math.isfinite(h) and h > 0):
            raise ParameterError(f"cell_mm must be a positive number of mm, got {cell_mm!r}")
        self.n_points = int(obst.shape[0])
        if self.n_points == 0:
            self.cell_mm = h
            self.scale = 1.0
            self.n_leaves = 0
            self.depth = 0
            return
        bmin = obst.min(axis=0)
        bmax = obst.max(axis=0)
        h = max(h, float((bmax - bmin).max()) / (_MAX_SIDE_CELLS - 1) * (1 + 1e-9))
        self.cell_mm = h
        self._origin = bmin
        self._dims = tuple(int(min(math.floor((bmax[k] - bmin[k]) / h) + 1, _MAX_SIDE_CELLS)) for k in range(3))
        codes = _morton(obst, bmin[0], bmin[1], bmin[2], h, *self._dims)
        order = np.argsort(codes, kind="stable")
        self._pts = np.ascontiguousarray(obst[order])
        codes = codes[order]
        rng, lo, hi, code = _leaves(self._pts, codes)
        levels = [(rng, lo, hi)]
        offset = 0
        while code.shape[0] > 1:
            prng, lo, hi, code = _parents(lo, hi, code, offset)
            offset += rng.shape[0]
            rng = prng
            levels.append((rng, lo, hi))
        self.n_leaves = int(levels[0][0].shape[0])
        self.depth = len(levels)
        self._rng = np.ascontiguousarray(np.concatenate([lv[0] for lv in levels]))
        lo = np.concatenate([lv[1] for lv in levels])
        hi = np.concatenate([lv[2] for lv in levels])
        half = 0.5 * (hi - lo)
        # per node: box centre (3), half extents (3), half diagonal; the root is the last node
        self._box = np.ascontiguousarray(np.concatenate(
            [0.5 * (lo + hi), half, np.sqrt((half * half).sum(axis=1))[:, None]], axis=1))
        self.scale = float(max(np.abs(obst).max(), 1.0))

    def free(self, centres, axes, tool: ToolAssembly, *, parts: Optional[Iterable[str]] = None,
             progress: Optional[Callable[[int, int], None]] = None) -> np.ndarray:
        """Bool (n,): True where the tool with its ball centre at ``centres[i]`` (n,3 mm) and axis
        ``axes[i]`` (n,3; scaled to unit length) leaves every obstacle point outside the segments of
        ``parts`` (None: all); the rule and method of the module docstring. ``progress(done, n)`` is
        called after each batch of positions."""
        c = _points(centres, "centres")
        n = c.shape[0]
        t = _unit_axes(axes, n)
        segs = _tool_segments(tool, parts)
        out = np.ones(n, dtype=bool)
        if n == 0 or not segs or self.n_points == 0:
            if progress is not None:
                progress(n, n)
            return out
        B, thr, thr2lo, thr2hi = _pieces(segs)
        scale = max(self.scale, float(np.abs(c).max()))
        slack = 1e-8 * scale            # rounding of the node tests, mm (the point test is exact)
        # positions in Morton order of their cells: neighbours walk the same nodes
        order = np.argsort(_morton(c, *self._origin, self.cell_mm, *self._dims), kind="stable")
        root = self._box.shape[0] - 1
        for b0 in range(0, n, _BATCH):
            sel = order[b0:b0 + _BATCH]
            hit = np.zeros(sel.size, dtype=np.bool_)
            _hits(self._pts, self._box, self._rng, self.n_leaves, root, c, t, sel, B, thr, thr2lo,
                  thr2hi, float(thr.max()), slack, hit)
            out[sel] = ~hit
            if progress is not None:
                progress(min(b0 + _BATCH, n), n)
        return out


# ----------------------------------------------------------------------------------------------
# the kernel

@njit(cache=True, nogil=True, inline="always")
def _piece(B, a):
    """k with ``B[k] < a <= B[k + 1]`` for ``B[0] < a <= B[-1]``."""
    lo = 0
    hi = B.shape[0] - 2
    while lo < hi:
        mid = (lo + hi) >> 1
        if B[mid + 1] < a:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def _centre_hits(c0, c1, c2, t0, t1, t2, pts, box, rng, n_leaves, root, B, thr, thr2lo, thr2hi,
                 thr_max, slack, stack):
    """True when an obstacle point lies in the tool at centre c, axis t (the module's rule)."""
    at0 = abs(t0)
    at1 = abs(t1)
    at2 = abs(t2)
    bmin = B[0]
    bmax = B[B.shape[0] - 1]
    npiece = B.shape[0] - 1
    stack[0] = root
    top = 1
    while top > 0:
        top -= 1
        nd = stack[top]
        x0 = box[nd, 0] - c0
        x1 = box[nd, 1] - c1
        x2 = box[nd, 2] - c2
        ac = x0 * t0 + x1 * t1 + x2 * t2
        ext = at0 * box[nd, 3] + at1 * box[nd, 4] + at2 * box[nd, 5] + slack
        amax = ac + ext
        if amax <= bmin:
            continue
        amin = ac - ext
        if amin > bmax:
            continue
        w0 = x0 - ac * t0
        w1 = x1 - ac * t1
        w2 = x2 - ac * t2
        rin = math.sqrt(w0 * w0 + w1 * w1 + w2 * w2) - box[nd, 6] - slack
        if rin >= thr_max:
            continue
        # the largest threshold of the pieces the box's range of a overlaps
        k = 0 if amin <= bmin else _piece(B, amin)
        rm = 0.0
        while k < npiece and B[k] < amax:
            if thr[k] > rm:
                rm = thr[k]
            k += 1
        if rin >= rm:
            continue
        if nd < n_leaves:
            for s in range(rng[nd, 0], rng[nd, 1]):
                d0 = pts[s, 0] - c0
                d1 = pts[s, 1] - c1
                d2 = pts[s, 2] - c2
                a = d0 * t0 + d1 * t1 + d2 * t2
                if a <= bmin or a > bmax:
                    continue
                q0 = d0 - a * t0
                q1 = d1 - a * t1
                q2 = d2 - a * t2
                w = q0 * q0 + q1 * q1 + q2 * q2
                k = _piece(B, a)
                if w < thr2lo[k]:
                    return True
                if w <= thr2hi[k] and math.sqrt(w) < thr[k]:
                    return True
        else:
            for ch in range(rng[nd, 0], rng[nd, 1]):
                stack[top] = ch
                top += 1
    return False


@njit(cache=True, parallel=True)
def _hits(pts, box, rng, n_leaves, root, centres, axes, sel, B, thr, thr2lo, thr2hi, thr_max, slack, hit):
    """``hit[k]`` for the position ``sel[k]``: :func:`_centre_hits`, parallel over chunks of positions."""
    n = sel.shape[0]
    nchunk = min(n, 64)
    for ch in prange(nchunk):
        stack = np.empty(_STACK, np.int64)
        for k in range(ch * n // nchunk, (ch + 1) * n // nchunk):
            i = sel[k]
            hit[k] = _centre_hits(centres[i, 0], centres[i, 1], centres[i, 2], axes[i, 0], axes[i, 1],
                                  axes[i, 2], pts, box, rng, n_leaves, root, B, thr, thr2lo, thr2hi,
                                  thr_max, slack, stack)


# ----------------------------------------------------------------------------------------------
# public functions

def pointwise_collision_free(obstacles, centres, axes, tool: ToolAssembly, *,
                             parts: Optional[Iterable[str]] = None,
                             progress: Optional[Callable[[int, int], None]] = None) -> np.ndarray:
    """Bool (n,): True where no point of ``obstacles`` (K,3 mm) lies inside a segment (of ``parts``,
    None: all) of ``tool`` with its ball centre at ``centres[i]`` (n,3 mm) and axis ``axes[i]`` (n,3,
    part frame, from the part towards the spindle; scaled to unit length). The rule and the method
    are in the module docstring; the grid is built for this call (:class:`ObstacleGrid` to reuse it
    across batches). ``progress(done, n)`` is called after each batch of positions."""
    c = _points(centres, "centres")
    _unit_axes(axes, c.shape[0])
    return ObstacleGrid(obstacles, default_cell_mm(tool, parts)).free(c, axes, tool, parts=parts,
                                                                      progress=progress)


def brute_force_pointwise(obstacles, centres, axes, tool: ToolAssembly, parts: Optional[Iterable[str]] = None,
                          *, chunk: int = 1 << 18) -> np.ndarray:
    """Reference for :func:`pointwise_collision_free`: every position against every obstacle point
    with :mod:`planning.geometry.collision`'s ``_inside`` (obstacles in chunks of ``chunk`` rows).
    O(n K), for tests only."""
    obst = _points(obstacles, "obstacles")
    c = _points(centres, "centres")
    t = _unit_axes(axes, c.shape[0])
    segs = _tool_segments(tool, parts)
    out = np.ones(c.shape[0], dtype=bool)
    for i in range(c.shape[0]):
        for s0 in range(0, obst.shape[0], chunk):
            d = obst[s0:s0 + chunk] - c[i]
            if any(_inside(d, t[i], lo, hi, r).any() for lo, hi, r in segs):
                out[i] = False
                break
    return out
