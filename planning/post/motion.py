"""The motion blocks of one operation (docs/design.md stage 8, post-processing): ``G0``/``G1``/``G2``/``G3``
with modal words, ``X Y Z`` tool tips in a program frame ``X = A a + b`` (mm), arcs kept as
``G2``/``G3`` or linearised (off a principal plane, degenerate after rounding, or of a radius beyond
``PostOptions.max_arc_radius_mm``), feeds in mm/min (:func:`~planning.post.options.feed_for`). The posts
(:mod:`planning.post.iso`, :mod:`planning.post.linuxcnc`) print every operation through
:func:`emit_motion`.

Approach and retract
--------------------
Each operation starts with one rapid to the point straight above the path's first point at the safe
height (:func:`~planning.post.arcs.safe_height_mm`, area frame, mm), then follows the path (its move
0 comes down from there), and ends with a rapid straight up along the tool axis to the safe height.
Numbers print as :mod:`planning.post.blocks` describes: modal X Y Z words, I J K from the rounded
start point as printed.

Speed
-----
:func:`emit_motion` prints an operation's motion blocks with whole-array numpy work: program
coordinates of every move, rounding to the printed digits (exact: rounding ties go to Python's own
formatting), modal words by array comparisons of the rounded values, arcs that degenerate after
rounding, chords of linearised arcs, and the text itself (a character matrix per batch of blocks,
:mod:`planning.post.bulk_text`). The text is byte for byte what the per-move :class:`MotionEmitter`
prints; MotionEmitter stays as the reference the tests compare with, and prints the rare operation
with coordinates beyond the whole-array formatter's range (2^51 output steps, about 2e11 mm at 4
decimals). Where numpy's functions may differ from the math module's in the last bit (np.hypot,
np.arctan2) and that could change a printed digit or a decision, the scalar code decides.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_AXES,
    PLANE_XY,
    PLANE_YZ,
    PLANE_ZX,
    RAPID,
    USE_PLUNGE,
    Toolpath,
    arc_sweep_rad,
)

from .arcs import (
    _AX_A,
    _AX_B,
    _chord_points,
    _large_arcs,
    arc_chord_points,
    arc_radius_mm,
    principal_plane,
)
from .blocks import BlockWriter, fmt, rounded
from .bulk_text import _quantise, _Rows
from .options import Operation, PostOptions, feed_for

__all__ = ["MotionEmitter", "MotionState", "emit_motion"]

#: Letters of the arc-centre offsets by program axis (X, Y, Z).
_OFFSET_LETTERS = ("I", "J", "K")


@dataclass
class MotionState:
    """Modal state of one operation's motion blocks (reset at each operation)."""

    motion: str | None = None
    plane: int = PLANE_XY
    feed: str | None = None
    pos: list = field(default_factory=lambda: [None, None, None])     # printed X Y Z strings


class MotionEmitter:
    """Prints one operation's moves in a program frame ``X = A a + b`` (``a``: tip point in the area
    frame, mm; ``A`` a rotation, ``b`` mm).

    ``arc_mode``: ``"frame"`` keeps each arc in its area-frame plane (ISO tilted plane, where the
    program frame is the area frame up to the rounding of the G68.2 words); ``"principal"`` maps the
    plane's normal by ``A`` and prints G2/G3 only when it lies on a principal axis within
    :data:`~planning.post.arcs.ARC_PLANE_TOL` (the direction flips when it maps onto a negative
    axis), linearising the arc within ``chord_tol_mm`` otherwise (LinuxCNC). In both modes an arc
    whose radius (:func:`~planning.post.arcs.arc_radius_mm`) exceeds ``max_arc_radius_mm`` is
    linearised within ``chord_tol_mm`` (one G1 where its sagitta is within the tolerance).

    One move at a time: the posts print through :func:`emit_motion`, which gives this class's text
    with whole arrays; this class is its reference and its fallback for huge coordinates.
    """

    def __init__(self, writer: BlockWriter, options: PostOptions, A: np.ndarray, b: np.ndarray, arc_mode: str):
        self.w = writer
        self.o = options
        self.d = int(options.decimals)
        self.A = np.asarray(A, dtype=np.float64)
        self.b = np.asarray(b, dtype=np.float64)
        self.arc_mode = arc_mode
        self.state = MotionState()
        self.n_linearised = 0
        self.n_arcs = 0

    def to_prog(self, a) -> np.ndarray:
        return np.asarray(a, dtype=np.float64) @ self.A.T + self.b

    def _printed_pos(self) -> np.ndarray:
        return np.array([float(v) if v is not None else np.nan for v in self.state.pos])

    def _words_xyz(self, X: np.ndarray, force: bool = False) -> list[str]:
        out = []
        for k, letter in enumerate("XYZ"):
            s = fmt(X[k], self.d)
            if force or self.state.pos[k] != s:
                out.append(letter + s)
                self.state.pos[k] = s
        return out

    def _motion(self, g: str) -> str:
        if self.state.motion == g:
            return ""
        self.state.motion = g
        return g

    def _feed(self, f: float) -> str:
        s = fmt(f, min(self.d, 3))
        if self.state.feed == s:
            return ""
        self.state.feed = s
        return "F" + s

    def _plane(self, plane: int) -> str:
        if self.state.plane == plane:
            return ""
        self.state.plane = plane
        return f"G{plane}"

    def rapid(self, a, *, prefix: Sequence[str] = (), force: bool = False) -> None:
        X = self.to_prog(a)
        words = self._words_xyz(X, force)
        if words or prefix:
            self.w.block(self._motion("G0"), *prefix, *words)

    def line(self, a, feed: float) -> None:
        X = self.to_prog(a)
        words = self._words_xyz(X)
        if words:
            self.w.block(self._motion("G1"), *words, self._feed(feed))

    def arc(self, start_a, end_a, centre_a, plane: int, ccw: bool, feed: float) -> None:
        self.n_arcs += 1
        if arc_radius_mm(start_a, end_a, centre_a, plane) > float(self.o.max_arc_radius_mm):
            self._linearise(start_a, end_a, centre_a, plane, ccw, feed)
            return
        if self.arc_mode == "frame":
            pp = (int(plane), 1)
        else:
            n_area = np.zeros(3)
            n_area[PLANE_AXES[int(plane)][2]] = 1.0
            pp = principal_plane(self.A @ n_area)
        if pp is None:
            self._linearise(start_a, end_a, centre_a, plane, ccw, feed)
            return
        out_plane, sign = pp
        out_ccw = ccw if sign > 0 else not ccw
        S = self._printed_pos()
        E = self.to_prog(end_a)
        C = self.to_prog(centre_a)
        ia, ib, _ = PLANE_AXES[out_plane]
        Er = np.array([rounded(v, self.d) for v in E])
        chord = math.hypot(Er[ia] - S[ia], Er[ib] - S[ib])
        radius = math.hypot(C[ia] - S[ia], C[ib] - S[ib])
        res = 10.0 ** (-self.d)
        if chord < 2 * res or radius < 2 * res:
            # start and end coincide in the plane after rounding (a G2/G3 would be a full circle), or
            # a radius at the output resolution: short arcs become chords, long ones are linearised
            _, sw, _ = arc_sweep_rad(np.asarray(start_a), np.asarray(end_a), np.asarray(centre_a), plane, ccw)
            if abs(sw) > math.pi / 2 and radius >= 2 * res:
                self._linearise(start_a, end_a, centre_a, plane, ccw, feed)
            else:
                self.line(end_a, feed)
            return
        words = self._words_xyz(E)
        offs = []
        for k in (ia, ib):
            offs.append(_OFFSET_LETTERS[k] + fmt(C[k] - S[k], self.d))
        offs.sort(key=lambda w: "IJK".index(w[0]))
        g = "G3" if out_ccw else "G2"
        self.w.block(self._plane(out_plane), self._motion(g), *words, *offs, self._feed(feed))

    def _linearise(self, start_a, end_a, centre_a, plane, ccw, feed) -> None:
        self.n_linearised += 1
        for q in arc_chord_points(start_a, end_a, centre_a, plane, ccw, float(self.o.chord_tol_mm)):
            self.line(q, feed)

    def run(self, op: Operation, z_safe: float, *, approach_prefix: Sequence[str] = ()) -> None:
        """Approach at the safe height, every move of the operation, retract to the safe height."""
        tp = op.toolpath
        tip = tp.tip_mm()
        centre = tp.centre_mm - np.array([0.0, 0.0, tp.tip_offset_mm])
        first = tip[0]
        self.rapid([first[0], first[1], z_safe], prefix=approach_prefix, force=True)
        for i in range(tp.n_moves):
            k = int(tp.kind[i])
            if k == RAPID:
                self.rapid(tip[i])
            elif k == FEED:
                self.line(tip[i], feed_for(op, tp.use[i]))
            else:
                self.arc(tip[i - 1], tip[i], centre[i], int(tp.plane[i]), k == ARC_CCW, feed_for(op, tp.use[i]))
        last = tip[-1]
        self.rapid([last[0], last[1], z_safe])
        if self.state.plane != PLANE_XY:
            self.w.block(self._plane(PLANE_XY))


# ----------------------------------------------------------------------------------------------
# the motion blocks of a whole operation at once

#: True: :func:`emit_motion` prints every operation with the per-move :class:`MotionEmitter`, the
#: reference that its whole-array path reproduces byte for byte (the tests switch it on to compare).
_REFERENCE_MOTION = False

#: Blocks whose text is built at once (bounds the temporary character matrices).
_CHUNK_ROWS = 1 << 16

_MOTION_WORDS = ("G0", "G1", "G2", "G3")
_PLANE_WORDS = ("G17", "G18", "G19")


def emit_motion(writer: BlockWriter, options: PostOptions, A: np.ndarray, b: np.ndarray, arc_mode: str,
                op: Operation, z_safe: float, *, approach_prefix: Sequence[str] = ()) -> None:
    """One operation's motion blocks, byte for byte what ``MotionEmitter(writer, options, A, b,
    arc_mode).run(op, z_safe, approach_prefix=approach_prefix)`` prints (see :class:`MotionEmitter`),
    computed for all moves at once: program coordinates, rounding, modal words, degenerate arcs,
    chords of linearised arcs and the text. Operations with coordinates beyond ``2^51`` output
    steps (about 2e11 mm at 4 decimals) go through MotionEmitter itself."""
    if _REFERENCE_MOTION or not _bulk_motion(writer, options, A, b, arc_mode, op, z_safe, tuple(approach_prefix)):
        MotionEmitter(writer, options, A, b, arc_mode).run(op, z_safe, approach_prefix=approach_prefix)


def _hypot_settled(u: np.ndarray, v: np.ndarray, ref: float) -> np.ndarray:
    """``hypot(u, v)`` per element, with ``math.hypot`` (whose last bit np.hypot may not match)
    wherever the value lies near ``ref``, so that comparisons with ``ref`` come out as
    MotionEmitter's."""
    h = np.hypot(u, v)
    for j in np.flatnonzero(np.abs(h - ref) <= 1e-9 * ref):
        h[j] = math.hypot(u[j], v[j])
    return h


def _bulk_motion(w: BlockWriter, o: PostOptions, A, b, arc_mode: str, op: Operation, z_safe: float,
                 prefix: tuple[str, ...]) -> bool:
    """:func:`emit_motion` with whole arrays; False (and nothing written) when some coordinate is too
    large for :func:`~planning.post.bulk_text._quantise`.

    MotionEmitter's state after a block is a function of the blocks so far: the printed X Y Z are
    those of the latest move (after rounding), so a word is printed where its rounded value differs
    from the previous move's; G0/G1/G2/G3 where it differs from the previous printed block's; F where
    it differs from the previous printed G1/G2/G3 block's; G17/18/19 where it differs from the
    previous arc's (G17 at the start). An arc starts from the rounded end of the previous move (the
    last chord of a linearised arc ends on it exactly).

    The steps: the rounded program coordinates of the approach, the moves and the retract; the arcs'
    planes in the program frame (:func:`_arc_planes`), less the arcs beyond ``max_arc_radius_mm``
    (:func:`~planning.post.arcs._large_arcs`: linearised); the arcs that degenerate after rounding
    (:func:`_degenerate_arcs`); the chords of the linearised arcs (:func:`_chords`); the printed
    points in order (:func:`_events`); their modal words (:func:`_modal_words`); the text
    (:func:`_write_blocks`)."""
    d = int(o.decimals)
    f = _ProgramFrame(A, b)
    tp = op.toolpath
    n = tp.n_moves
    kind = tp.kind
    tip = tp.tip_mm()
    centre = tp.centre_mm - np.array([0.0, 0.0, tp.tip_offset_mm])
    first, last = tip[0], tip[-1]
    x_app = f.point([first[0], first[1], z_safe])
    x_ret = f.point([last[0], last[1], z_safe])
    q_app, q_ret, q_mv = _quantise(x_app, d), _quantise(x_ret, d), _quantise(f.points(tip), d)
    if q_app is None or q_ret is None or q_mv is None:
        return False

    arcs = np.flatnonzero((kind == ARC_CW) | (kind == ARC_CCW))
    kept, out_plane, flip = _arc_planes(f.A, tp.plane[arcs], arc_mode)
    if arcs.size:
        kept &= ~_large_arcs(tip[arcs - 1], tip[arcs], centre[arcs], tp.plane[arcs].astype(np.int64),
                             float(o.max_arc_radius_mm))
    out_ccw = (kind[arcs] == ARC_CCW) ^ flip
    block, lin, q_off = _degenerate_arcs(f, d, tp, tip, centre, arcs, kept, out_plane, q_mv)
    if q_off is None:
        return False
    # what each move prints: 0 a G0 point, 1 a G1 point, 2 a G2/G3 block, 3 G1 chords
    mode = np.where(kind == RAPID, 0, 1).astype(np.int8)
    mode[arcs[block]] = 2
    mode[arcs[lin]] = 3

    lin_mv = arcs[lin]
    count = np.ones(n, dtype=np.int64)
    q_lin = None
    if lin_mv.size:
        q_lin, m = _chords(f, d, float(o.chord_tol_mm), tp, tip, centre, lin_mv)
        if q_lin is None:
            return False
        count[lin_mv] = m

    ev = _events(q_app, q_mv, q_ret, mode, count, q_lin)
    words = _modal_words(ev, op, d, arcs, out_ccw, out_plane, arcs[block], q_off)
    _write_blocks(w, prefix, x_app, d, ev, words)
    return True


class _ProgramFrame:
    """The program frame ``X = A a + b`` of :meth:`MotionEmitter.to_prog`, for whole arrays."""

    def __init__(self, A, b):
        self.A = np.asarray(A, dtype=np.float64)
        self.b = np.asarray(b, dtype=np.float64)
        self.At = self.A.T

    def point(self, a) -> np.ndarray:
        """One point (3,), as MotionEmitter.to_prog maps it."""
        return np.asarray(a, dtype=np.float64) @ self.At + self.b

    def points(self, pts: np.ndarray) -> np.ndarray:
        """Points (k,3): MotionEmitter.to_prog row by row (a stack of (1,3) @ (3,3) products makes
        numpy call the same BLAS kernel for every row as it does for one point, hence the same bits)."""
        return (pts[:, None, :] @ self.At)[:, 0, :] + self.b


def _arc_planes(A: np.ndarray, arc_plane: np.ndarray, arc_mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The arcs' planes in the program frame, ``(kept, out_plane, flip)`` per arc (``arc_plane``: the
    area-frame plane codes): ``"frame"`` keeps every arc in its plane; ``"principal"`` keeps the arcs
    whose plane's normal ``A`` maps onto a principal axis (:func:`~planning.post.arcs.principal_plane`),
    ``flip`` where it maps onto the negative one (the direction reverses)."""
    k = arc_plane.size
    if arc_mode == "frame":
        return np.ones(k, dtype=bool), arc_plane.astype(np.int64), np.zeros(k, dtype=bool)
    kept = np.zeros(k, dtype=bool)
    out_plane = np.full(k, PLANE_XY, dtype=np.int64)
    flip = np.zeros(k, dtype=bool)
    for p in (PLANE_XY, PLANE_ZX, PLANE_YZ):
        n_area = np.zeros(3)
        n_area[PLANE_AXES[p][2]] = 1.0
        pp = principal_plane(A @ n_area)
        if pp is not None:
            sel = arc_plane == p
            kept[sel] = True
            out_plane[sel] = pp[0]
            flip[sel] = pp[1] < 0
    return kept, out_plane, flip


def _degenerate_arcs(f: _ProgramFrame, d: int, tp: Toolpath, tip: np.ndarray, centre: np.ndarray, arcs: np.ndarray,
                     kept: np.ndarray, out_plane: np.ndarray, q_mv: np.ndarray):
    """``(block, lin, q_off)``: the arcs (moves ``arcs``) printed as G2/G3 and those printed as G1
    chords (bool per arc), and the rounded I J K of the G2/G3 blocks (int64 (k,3); None when too
    large). A kept arc whose start and end coincide after rounding, or whose radius lies at the
    resolution, is no block: as in :meth:`MotionEmitter.arc` it is linearised when it sweeps more
    than 90 degrees (and its radius is not at the resolution), else it is one G1 to its end."""
    kind, plane = tp.kind, tp.plane
    scale = float(10 ** d)
    two_res = 2 * 10.0 ** (-d)
    ki = np.flatnonzero(kept)
    ka = arcs[ki]
    rows = np.arange(ka.size)
    ia, ib = _AX_A[out_plane[ki]], _AX_B[out_plane[ki]]
    S = q_mv[ka - 1] / scale                   # the printed start (float(fmt(.)) == q / 10^d exactly)
    E = q_mv[ka] / scale
    C = f.points(centre[ka])
    chord = _hypot_settled(E[rows, ia] - S[rows, ia], E[rows, ib] - S[rows, ib], two_res)
    radius = _hypot_settled(C[rows, ia] - S[rows, ia], C[rows, ib] - S[rows, ib], two_res)
    lin = ~kept
    block = kept.copy()
    for j in np.flatnonzero((chord < two_res) | (radius < two_res)):
        i = ka[j]
        block[ki[j]] = False
        _, sw, _ = arc_sweep_rad(tip[i - 1], tip[i], centre[i], int(plane[i]), bool(kind[i] == ARC_CCW))
        lin[ki[j]] = abs(sw) > math.pi / 2 and radius[j] >= two_res     # else one G1 to the end
    in_blk = block[ki]
    q_off = _quantise(C[in_blk] - S[in_blk], d)            # I J K: centre - printed start
    return block, lin, q_off


def _chords(f: _ProgramFrame, d: int, tol: float, tp: Toolpath, tip: np.ndarray, centre: np.ndarray,
            lin_mv: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """``(q_lin, m)``: the rounded program coordinates (int64, None when too large) of the chord
    points of the linearised arcs (moves ``lin_mv``), arc after arc, and their counts ``m`` (k,).
    An arc with a point within reach of a rounding tie takes its points from
    :func:`~planning.post.arcs.arc_chord_points` (MotionEmitter's)."""
    kind, plane = tp.kind, tp.plane
    scale = float(10 ** d)
    pts, m, slack = _chord_points(tip[lin_mv - 1], tip[lin_mv], centre[lin_mv], plane[lin_mv].astype(np.int64),
                                  kind[lin_mv] == ARC_CCW, tol)
    P = f.points(pts)
    arc_of = np.repeat(np.arange(lin_mv.size), m)
    first_pt = np.cumsum(m) - m
    p = np.abs(P) * scale
    near = np.abs(p - np.floor(p) - 0.5) <= (slack * scale)[arc_of, None] + p * 2.0 ** -52
    for j in np.unique(arc_of[near.any(axis=1)]):          # within reach of a rounding tie: exact points
        i = lin_mv[j]
        ex = arc_chord_points(tip[i - 1], tip[i], centre[i], int(plane[i]), bool(kind[i] == ARC_CCW), tol)
        P[first_pt[j]:first_pt[j] + m[j]] = f.points(ex)
    return _quantise(P, d), m


class _Events(NamedTuple):
    """The points of an operation in order (approach, every move's point or a linearised arc's
    chords, retract) and the ones that print a block."""

    q: np.ndarray        #: (k,3) int64: rounded program X Y Z of every point (see _quantise)
    changed: np.ndarray  #: (k,3) bool: the word differs from the previous point's
    em: np.ndarray       #: the points that print a block; em[0] == 0, the approach
    mv: np.ndarray       #: the move of each printed block
    t_em: np.ndarray     #: what each printed block is: 0 G0, 1 G1, 2 G2/G3
    arc_em: np.ndarray   #: t_em == 2


def _events(q_app: np.ndarray, q_mv: np.ndarray, q_ret: np.ndarray, mode: np.ndarray, count: np.ndarray,
            q_lin: np.ndarray | None) -> _Events:
    """The points in order, from the rounded approach, moves and retract and each move's ``mode``
    (0 G0, 1 G1, 2 G2/G3, 3 G1 chords: ``count`` of them, ``q_lin`` their points)."""
    n = mode.size
    ev_move = np.concatenate([[0], np.repeat(np.arange(n), count), [n - 1]])
    ev_type = np.concatenate([[0], mode[ev_move[1:-1]], [0]])
    q = np.concatenate([q_app[None], q_mv[ev_move[1:-1]], q_ret[None]])
    if q_lin is not None:
        q[np.flatnonzero(ev_type == 3)] = q_lin
        ev_type[ev_type == 3] = 1
    changed = np.ones(q.shape, dtype=bool)
    changed[1:] = q[1:] != q[:-1]
    is_arc = ev_type == 2
    printed = changed.any(axis=1) | is_arc
    em = np.flatnonzero(printed)                           # em[0] == 0, the approach
    t_em = ev_type[em]
    return _Events(q, changed, em, ev_move[em], t_em, t_em == 2)


class _Words(NamedTuple):
    """The modal words of the printed blocks (arrays over _Events.em, or over the moves: ``_mv``)."""

    motion: np.ndarray      #: 0..3: G0..G3
    new_motion: np.ndarray  #: printed (differs from the previous block's)
    feeds: tuple            #: the F words (feed, plunge)
    feed_id: np.ndarray     #: per move: 1 for the plunge feed's F word where it prints differently
    new_feed: np.ndarray    #: printed (differs from the previous G1/G2/G3 block's)
    plane_mv: np.ndarray    #: per move: the arc's program plane code (G17 for other moves)
    new_plane: np.ndarray   #: printed (differs from the previous arc's)
    arc_planes: np.ndarray  #: program plane of each printed arc block, in order
    q_off: np.ndarray       #: (k,3) rounded I J K of the G2/G3 blocks (one row of zeros where none)
    blk_pos: np.ndarray     #: per move: its row in q_off


def _modal_words(ev: _Events, op: Operation, d: int, arcs: np.ndarray, out_ccw: np.ndarray, out_plane: np.ndarray,
                 blk: np.ndarray, q_off: np.ndarray) -> _Words:
    """The modal words of the printed blocks ``ev`` (``blk``: the moves printed as G2/G3 blocks,
    ``q_off`` their I J K)."""
    n = op.toolpath.n_moves
    out_ccw_mv = np.zeros(n, dtype=bool)
    out_ccw_mv[arcs] = out_ccw
    motion = np.where(ev.arc_em, 2 + out_ccw_mv[ev.mv], ev.t_em)
    new_motion = np.ones(ev.em.size, dtype=bool)
    new_motion[1:] = motion[1:] != motion[:-1]
    fmt_feed = fmt(float(op.feed_mm_min), min(d, 3))
    fmt_plunge = fmt(float(op.plunge_mm_min), min(d, 3))
    feed_id = ((op.toolpath.use == USE_PLUNGE) & (fmt_plunge != fmt_feed)).astype(np.int64)
    fed = np.flatnonzero(ev.t_em != 0)
    f_code = feed_id[ev.mv[fed]]
    new_feed = np.zeros(ev.em.size, dtype=bool)
    new_feed[fed] = np.concatenate([[True], f_code[1:] != f_code[:-1]])
    plane_mv = np.full(n, PLANE_XY, dtype=np.int64)
    plane_mv[arcs] = out_plane
    arc_planes = plane_mv[ev.mv[ev.arc_em]]
    new_plane = np.zeros(ev.em.size, dtype=bool)
    new_plane[ev.arc_em] = arc_planes != np.concatenate([[PLANE_XY], arc_planes[:-1]])
    blk_pos = np.zeros(n, dtype=np.int64)
    blk_pos[blk] = np.arange(blk.size)
    if not blk.size:
        q_off = np.zeros((1, 3), dtype=np.int64)
    return _Words(motion, new_motion, ("F" + fmt_feed, "F" + fmt_plunge), feed_id, new_feed, plane_mv, new_plane,
                  arc_planes, q_off, blk_pos)


def _write_blocks(w: BlockWriter, prefix: tuple[str, ...], x_app: np.ndarray, d: int, ev: _Events,
                  words: _Words) -> None:
    """The approach block, the text of the other printed blocks (batches of ``_CHUNK_ROWS``), and G17
    at the end where the last arc was in another plane."""
    w.block("G0", *prefix, *(letter + fmt(x_app[k], d) for k, letter in enumerate("XYZ")))
    numbers = w.take_numbers(ev.em.size - 1) if w.numbered else None
    text = []
    for lo in range(1, ev.em.size, _CHUNK_ROWS):
        text.append(_blocks_text(slice(lo, min(lo + _CHUNK_ROWS, ev.em.size)), ev, words, numbers, d))
    if text:
        w.raw("".join(text)[:-1])
    if words.arc_planes.size and words.arc_planes[-1] != PLANE_XY:
        w.block(_PLANE_WORDS[0])


def _blocks_text(sl: slice, ev: _Events, words: _Words, numbers: np.ndarray | None, d: int) -> str:
    """The printed blocks ``ev.em[sl]`` as text, each ended by a newline (``numbers``: the N words of
    all printed blocks after the approach, or None)."""
    em, mvs, arc_rows = ev.em[sl], ev.mv[sl], ev.arc_em[sl]
    rows = _Rows(em.size)
    if numbers is not None:
        rows.number("N", numbers[sl.start - 1:sl.stop - 1], 0, np.ones(em.size, dtype=bool), point=False)
    pl = words.plane_mv[mvs]
    rows.table(pl - PLANE_XY, _PLANE_WORDS, words.new_plane[sl])
    rows.table(words.motion[sl], _MOTION_WORDS, words.new_motion[sl])
    for k, letter in enumerate("XYZ"):
        rows.number(letter, ev.q[em, k], d, ev.changed[em, k])
    qo = words.q_off[words.blk_pos[mvs]]
    for k, (letter, skip) in enumerate(zip("IJK", (PLANE_YZ, PLANE_ZX, PLANE_XY))):
        rows.number(letter, qo[:, k], d, arc_rows & (pl != skip))
    rows.table(words.feed_id[mvs], words.feeds, words.new_feed[sl])
    return rows.text()
