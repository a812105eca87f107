"""Exact confirmation of the gouges the tri-dexel deviation suspects (issue 16).

The deviation read on the dexel model (:func:`planning.simulate.dexel.deviation_pair`) is bounded by
``3/4 r^2 / rho`` only where the machined surface is smooth at the ray spacing ``r``; the cusps
between two finishing passes and the seams between two set-ups are not, and a point there can read
a few tenths of a millimetre low at 1 mm (the half sphere's seam: -0.29 mm read where the ball
came no closer than 0.0104 mm to the point). A point that reads as a gouge is therefore measured
again, exactly: how deep it lies inside any tool of any move that ran (:func:`penetration_mm`).
That depth, not the dexel reading, decides whether it is a gouge.

Tools (:class:`planning.simulate.motion.ToolShape`, tip ``q``, unit axis ``a``, a point ``p``):

* ball of radius R: the ball's centre runs along the segment ``q + R a``; depth ``R - dist(p,
  centre segment)`` (exact for the swept ball). A 5-axis move comes as the reader's steps, each with
  the axis at its end: a step that continues the one before starts where that step left the ball,
  its tip plus R along that step's axis (:func:`_ball_starts`; the control keeps the centre on the
  line between within the post's tolerance). With the step's own axis at both ends the centre at
  its start lay R times the step's turn off (0.05 mm at 1 degree; on the CLI slot it read cuts of
  up to 0.034 mm below the scan that the programs do not make);
* flat or bull-nose end mill of radius Rt, cutting up to the flute length L: the cylinder
  ``0 <= (p - q).a <= L``, radial distance <= Rt, swept along the segment; on the part of the move
  where the point is within Rt of the axis, sampled at 65 equal steps; depth at a sample = the distance from p to the
  cylinder's bottom face or side, whichever is nearer. A bull-nose is taken as the flat cylinder
  that contains it (its depth can only read deeper). The ball-end cutter's fluted cylinder above
  the ball (up to the flute length) counts with the depth to its side. On a 5-axis step that turns
  the axis (it continues the step before, whose axis ``a0`` it starts with) the flutes turn about the
  ball's centre with it: sampled at 65 steps with the axis ``a0 + t (a - a0)`` normalised and the
  centre on its line, on the part of the step where the point is within ``R + w`` of the line along
  ``a`` (``w = hypot(L - R, R) |a0 - a|``: no point of the turned flutes lies farther than that from
  the cylinder along ``a``; the searches reach as much farther). Held at the step's end axis, the
  flutes 5.5 mm above the centre of a step turning 0.7 degrees stood 0.07 mm off where they run: on
  the range femur in 5axis they read a cut of 0.037 mm below a scan point where the tool, run as the
  control runs it, goes no deeper than the planned chords' 0.010 mm.

Which moves count for a point (as the k-d tree of issue 16 chose them): every move is cut into
:data:`PIECE_MM` pieces (``ceil(length / PIECE_MM)`` equal parts, at least one), and a move counts
when the mid point of one of its pieces lies within ``rq = PIECE_MM / 2 + reach`` of the point
(``reach``: the farthest cutting point of the tool from its tip, ``max(hypot(R, L), 2 R)``), which
every move that can cut the point passes. The result is the deepest depth over those moves
(negative: not cut; a ball's depth is finite for every move that counts), ``-inf`` where no move
counts, in mm.

The work runs in numba kernels (:mod:`planning.simulate.gouge_kernels`; the pieces built and binned
there too): per tool one or two *layers* of pieces in a uniform grid (the ball: the mid points, with
the radius ``rq``; the cylinders: a bounding sphere per piece), the points in parallel (``prange``
over chunks of points, ``numba.get_num_threads()`` threads), each visiting the grid cells around it
and measuring each move once. Bounds that cannot be beaten by more than rounding skip what cannot
raise a point's deepest depth (the kernels' docstring says which), so the result is the maximum over
the same (point, move) pairs with the same formulas (to the last few ulps: ~1e-14 mm against the
numpy code in the tests), whatever the thread count.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from planning.progress import Progress
from planning.simulate import gouge_kernels as _k
from planning.simulate.motion import FEED, ProgramMotion, ToolShape

#: Moves are cut into pieces of at most this length (mm) to find the moves near a point.
PIECE_MM = 4.0
#: Samples along the part of a move where a point is within the cylinder's radius of the axis.
SAMPLES = 65
#: The side of a grid cell, as a fraction of the layer's search radius: the balls' layers (whose
#: bound searches much less than their radius) and the cylinders' layers.
CELL_FRACTION_BALL = 0.25
CELL_FRACTION_CYLINDER = 0.5
#: A layer's grid has at most this many cells per piece (plus :data:`MIN_CELLS`); larger cells beyond.
CELLS_PER_PIECE = 8
MIN_CELLS = 1 << 16
#: Points are sorted along cells of this side (mm) before they are dealt in blocks.
POINT_CELL_MM = 8.0
#: Chunks of points per thread (each chunk keeps two int32 stamps per move while it runs).
CHUNKS_PER_THREAD = 4
#: Points per kernel call (the stamps number the points twice in an int32).
MAX_POINTS = 1 << 29
#: With a ``progress`` callback the points go to the kernels in batches (the grid order cut in
#: consecutive runs; a point's depth does not depend on its batch), a report after each: at least this
#: many batches where there are enough points for them (each at least a block per chunk) ...
PROGRESS_BATCHES = 16
#: ... and each sized from the rate of the one before to take about this long (s), so that a long
#: confirmation speaks several times a second whatever the scan and the machine.
PROGRESS_BATCH_S = 0.25


class _Layer(NamedTuple):
    """A layer of the kernels (:mod:`planning.simulate.gouge_kernels`): ``mode``; the cylinder's or ball's
    ``radius`` and the cylinder's ``length``; each piece's point and second point (the ball's centre)
    ``shift`` / ``shift2`` along the axis from its mid point; the grid's search radius ``search``; a
    piece's radius ``rho`` (the ball: the candidates' radius rq; a cylinder: its bounding sphere less
    the piece's half length); the ``floor``; its moves ``base .. base + count`` of the tools' array."""

    mode: int
    radius: float
    length: float
    shift: float
    shift2: float
    search: float
    rho: float
    floor: float
    base: int
    count: int

    @property
    def moves(self) -> slice:
        return slice(self.base, self.base + self.count)


def _reach(shape: ToolShape) -> float:
    """Every cutting point of the tool lies within this of its tip (mm; the ball: 2 R)."""
    return max(float(np.hypot(shape.radius_mm, shape.flute_length_mm)), 2.0 * shape.radius_mm) + 1e-6


def _grid(lo: np.ndarray, hi: np.ndarray, cell: float, n_pieces: int) -> tuple[np.ndarray, float, np.ndarray]:
    """(lo, cell, dims) of a uniform grid over the box ``lo..hi`` with cells of side ``cell``, doubled
    while there would be more than ``CELLS_PER_PIECE * n_pieces + MIN_CELLS`` cells."""
    ext = np.maximum(hi - lo, 0.0)
    limit = CELLS_PER_PIECE * n_pieces + MIN_CELLS
    while True:
        dims = np.floor(ext / cell).astype(np.int64) + 1
        if float(dims[0]) * float(dims[1]) * float(dims[2]) <= limit:
            return lo, cell, dims
        cell *= 2.0


def penetration_mm(points: np.ndarray, motions: list[ProgramMotion], tools: dict[int, ToolShape],
                   progress: Progress | None = None, beyond_mm: float = 0.0) -> np.ndarray:
    """(n,) how deep each of ``points`` (n,3, part frame, mm) lies inside the cutting part of a tool
    on any FEED move of ``motions`` (module docstring; ``tools`` by T number); ``-inf`` where no
    move's tool reaches it (<= 0: not cut) and at points with a non-finite coordinate.

    ``progress(fraction of the points measured, message)``: called once the moves are binned and then
    after every batch of points (:data:`PROGRESS_BATCHES`, :data:`PROGRESS_BATCH_S`), the fraction
    rising to 1.0; the result is the same with or without it.

    ``beyond_mm`` (>= 0): the moves are searched this much farther from each point, so that a ball's
    depth down to ``-beyond_mm`` is settled by the bounded search alone (the ball layers' floor, below
    which a point is measured again without the bounds, drops from 0 to ``-beyond_mm``): for points
    that lie mostly outside the tools (:func:`planning.simulate.finish.finish_left_mm`). The depths are
    those of the moves within the search, as without it; a larger search only finds more of them."""
    import numba

    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    if pts.shape[0] > MAX_POINTS:                        # the kernels' stamps are int32, 2 per point
        n_all = pts.shape[0]

        def part(a):
            if progress is None:
                return None
            b = min(n_all, a + MAX_POINTS)
            return lambda f, msg: progress((a + f * (b - a)) / n_all, msg)

        return np.concatenate([penetration_mm(pts[a:a + MAX_POINTS], motions, tools, part(a), beyond_mm)
                               for a in range(0, n_all, MAX_POINTS)])
    out = np.full(pts.shape[0], -np.inf)
    finite = np.flatnonzero(np.isfinite(pts).all(axis=1))
    if finite.size == 0:
        if progress is not None:
            progress(1.0, "no finite point to measure")
        return out
    # the feed moves of each tool (T number), all tools in one array
    S, E, A, A0, groups = [], [], [], [], []
    n_moves = 0
    for number, shape in tools.items():
        ball = float(shape.radius_mm) if shape.kind == "ball" else 0.0
        sel = [(*_ball_starts(m, k, ball, with_axes=True), m.end_mm[k], m.axis[k]) for m in motions
               for k in [np.flatnonzero((m.kind == FEED) & (m.tool == number))] if k.size]
        if not sel:
            continue
        s, a0, e, a = (np.concatenate([x[i] for x in sel]).astype(np.float64) for i in range(4))
        if not (np.isfinite(s).all() and np.isfinite(e).all() and np.isfinite(a).all() and np.isfinite(a0).all()):
            ok = (np.isfinite(s).all(axis=1) & np.isfinite(e).all(axis=1) & np.isfinite(a).all(axis=1)
                  & np.isfinite(a0).all(axis=1))
            s, e, a, a0 = s[ok], e[ok], a[ok], a0[ok]
        if s.shape[0] == 0:
            continue
        S.append(s), E.append(e), A.append(a), A0.append(a0)
        groups.append((shape, n_moves, s.shape[0]))
        n_moves += s.shape[0]
    if not groups:
        if progress is not None:
            progress(1.0, "no feed move to measure against")
        return out
    S, E, A, A0 = (np.ascontiguousarray(np.concatenate(x)) for x in (S, E, A, A0))
    # the layers (module docstring): per tool the ball and the side of its flutes, or the cylinder
    layers = []
    for shape, base, count in groups:
        R, L = float(shape.radius_mm), float(shape.flute_length_mm)
        rq = 0.5 * PIECE_MM + _reach(shape) + max(0.0, float(beyond_mm))
        if shape.kind == "ball":
            # a piece beyond the search radius holds no ball depth above 2 R + PIECE_MM / 2 - rq
            layers.append(_Layer(_k.NEAR, R, R, 0.0, R, rq, rq, 2.0 * R + 0.5 * PIECE_MM - rq, base, count))
            if L > R:                                     # the fluted cylinder above the ball: its side
                rho = float(np.hypot(R, 0.5 * (L - R))) + _k.SPHERE_SLACK_MM
                # a step that turns the axis: its flutes stray up to hypot(L - R, R) |a0 - a| from the cylinder
                # along its end axis, and the search reaches that much farther (module docstring)
                mv = slice(base, base + count)
                turn = float(np.sqrt(((A0[mv] - A[mv]) ** 2).sum(axis=1)).max(initial=0.0))
                tw = float(np.hypot(L - R, R)) * turn + _k.SPHERE_SLACK_MM if turn > 0.0 else 0.0
                layers.append(_Layer(_k.SIDE, R, L - R, R + 0.5 * (L - R), 0.0, rho + 0.5 * PIECE_MM + tw, rho,
                                     -np.inf, base, count))
        else:
            rho = float(np.hypot(R, 0.5 * L)) + _k.SPHERE_SLACK_MM
            layers.append(_Layer(_k.FLAT, R, L, 0.5 * L, 0.0, rho + 0.5 * PIECE_MM, rho, -np.inf, base, count))
    layers.sort(key=lambda ly: ly.mode != _k.NEAR)       # the balls first: their depths bound the cylinders
    # every move's pieces, as the search over them has always cut them (PIECE_MM, equal parts)
    length = np.linalg.norm(E - S, axis=1)
    n = np.maximum(1, np.ceil(length / PIECE_MM).astype(np.int64))
    off = np.cumsum(n) - n
    half = 0.5 * length / n
    sizes = [int(n[ly.base:ly.base + ly.count].sum()) for ly in layers]
    total = sum(sizes)
    pcen, phalf, powner = np.empty((total, 3)), np.empty(total), np.empty(total, np.int64)
    pball = np.empty((sum(sz for ly, sz in zip(layers, sizes) if ly.mode == _k.NEAR), 3))
    grids = []
    for ly, size in zip(layers, sizes):
        lo, hi = _k.box(S[ly.moves], E[ly.moves], A[ly.moves], ly.shift)
        grids.append(_grid(lo - 1e-9, hi + 1e-9, (CELL_FRACTION_BALL if ly.mode == _k.NEAR else CELL_FRACTION_CYLINDER)
                           * ly.search, size))
    ncells = [int(np.prod(dims)) for _, _, dims in grids]
    cstart = np.empty(sum(nc + 1 for nc in ncells), np.int64)
    at = cat = 0
    lcoff = []
    for ly, size, (lo, cell, dims), nc in zip(layers, sizes, grids, ncells):
        key, cen, cen2 = np.empty(size, np.int64), np.empty((size, 3)), np.empty((size if ly.mode == _k.NEAR else 0, 3))
        hs, owner = np.empty(size), np.empty(size, np.int64)
        mv = ly.moves
        _k.fill_pieces(S[mv], E[mv], A[mv], length[mv], n[mv], off[mv] - off[ly.base], ly.base, ly.shift, ly.shift2,
                       lo, float(cell), dims, key, cen, cen2, hs, owner)
        _k.sort_pieces(key, nc, cen, cen2, hs, owner, at, cstart, cat, pcen, pball, phalf, powner)
        lcoff.append(cat)
        at += size
        cat += nc + 1
    # the points sorted along a grid (neighbours share candidates), dealt in blocks to the chunks; the
    # grid spans the moves (a point farther out reads -inf whatever its place in the order)
    plo = np.minimum(S.min(axis=0), E.min(axis=0))
    ext = np.maximum(S.max(axis=0), E.max(axis=0)) - plo
    pcell = max(POINT_CELL_MM, float(ext.max()) / (1 << 20))
    pdims = np.floor(ext / pcell).astype(np.int64) + 1
    ijk = np.clip(np.floor((np.clip(pts[finite], plo, plo + ext) - plo) / pcell), 0, pdims - 1).astype(np.int64)
    order = finite[np.argsort((ijk[:, 0] * pdims[1] + ijk[:, 1]) * pdims[2] + ijk[:, 2], kind="stable")]
    order = order.astype(np.int64)
    max_chunks = CHUNKS_PER_THREAD * numba.get_num_threads()

    def per_layer(values, dtype=np.float64):
        return np.ascontiguousarray(values, dtype=dtype)

    args = (S, E, A, A0,
            per_layer([ly.mode for ly in layers], np.int64), per_layer([ly.radius for ly in layers]),
            per_layer([ly.length for ly in layers]), per_layer([ly.search for ly in layers]),
            per_layer([ly.rho for ly in layers]),
            per_layer([n_moves if ly.mode == _k.SIDE else 0 for ly in layers], np.int64),     # stamp offsets
            per_layer([half[ly.moves].max() for ly in layers]), per_layer([ly.floor for ly in layers]),
            per_layer([g[0] for g in grids]), per_layer([g[1] for g in grids]),
            per_layer([g[2] for g in grids], np.int64), per_layer(lcoff, np.int64), cstart, pcen, pball, phalf,
            powner, np.linspace(0.0, 1.0, SAMPLES), out)

    def run(batch: np.ndarray) -> None:
        nchunk = max(1, min(-(-batch.size // _k.BLOCK), max_chunks))
        _k.penetration(pts, batch, int(nchunk), *args)

    total = order.size
    if progress is None:
        run(order)
        return out
    progress(0.0, f"exact gouge depth: {total:,} points against {n_moves:,} feed moves ({sum(sizes):,} pieces binned)")
    least = max_chunks * _k.BLOCK                        # every chunk a block
    most = max(least, -(-total // PROGRESS_BATCHES))
    size, done = least, 0
    while done < total:
        batch = order[done:done + size]
        t = time.perf_counter()
        run(batch)
        dt = time.perf_counter() - t
        done += batch.size
        progress(done / total, f"exact gouge depth: points {done:,} of {total:,} measured")
        size = int(min(most, max(least, batch.size * PROGRESS_BATCH_S / max(dt, 1e-6))))
    return out


def _ball_starts(motion: ProgramMotion, k: np.ndarray, R: float, with_axes: bool = False):
    """The start tips of ``motion``'s moves ``k`` for a ball of radius ``R`` (module docstring): a move
    that continues the one before (its start is that move's end) and turns the axis starts at its tip
    plus ``R (a0 - a)`` (``a0`` the axis of the move before, ``a`` its own), so that the kernels' ball
    centre ``start + R a`` is the centre it really starts from. ``R`` 0: the tips as they are (and no
    move turns). ``with_axes``: ``(starts, a0)``, the axis each move starts with (``a0`` where it
    turns, else its own), the flutes' turn."""
    start = motion.start_mm[k]
    a_start = motion.axis[k]
    j = k[k > 0]
    a, a0 = motion.axis[j], motion.axis[j - 1]
    cont = ((np.abs(motion.start_mm[j] - motion.end_mm[j - 1]).max(axis=1) <= 1e-9) & (np.abs(a - a0).max(axis=1) > 0.0)
            if R != 0.0 else np.zeros(j.size, dtype=bool))
    if cont.any():
        start = np.array(start, dtype=np.float64, copy=True)
        a_start = np.array(a_start, dtype=np.float64, copy=True)
        at = np.flatnonzero(k > 0)[cont]
        start[at] += R * (a0[cont] - a[cont])
        a_start[at] = a0[cont]
    return (start, a_start) if with_axes else start


def warm_kernels() -> None:
    """Compile (or load from numba's cache) the kernels of :func:`penetration_mm`: a plan calls it only
    when the deviation suspects a gouge, which the warm-up plan may not (:mod:`planning.warmup`). Every
    array the kernels see is built here with fixed dtypes and layouts, so this tiny call compiles the
    signatures of any real one."""
    from planning.simulate.motion import RAPID

    s = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    e = np.array([[5.0, 0.0, 0.0], [5.0, 5.0, -1.0], [0.0, 0.0, 0.0]])
    motion = ProgramMotion(program="warmup", area=0, line=np.arange(1, 4), kind=np.array([FEED, FEED, RAPID], np.int8),
                           tool=np.array([1, 2, 1]), start_mm=s, end_mm=e, axis=np.tile([0.0, 0.0, 1.0], (3, 1)),
                           machine_mm=np.zeros((3, 3)), rotary_deg=np.zeros((3, 2)))
    tools = {1: ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=3.0, flute_length_mm=12.0),
             2: ToolShape(number=2, kind="flat", radius_mm=4.0, corner_radius_mm=0.0, flute_length_mm=20.0)}
    penetration_mm(np.array([[1.0, 0.5, 1.0], [5.0, 2.0, 0.0]]), [motion], tools)
