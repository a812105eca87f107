"""The move list every tool path stage produces and every post-processor reads (issue 5 item 6).

A :class:`Toolpath` is a 3-axis program for one operation of one area, in that area's frame
(:mod:`planning.toolpath.frames`: tool axis +Z, mm). Move ``i`` goes from ``xyz_mm[i-1]`` to
``xyz_mm[i]``; move 0 is a rapid to the start, from wherever the machine is (the post comes down
from its safe height).

* ``kind``: :data:`RAPID` (G0), :data:`FEED` (G1 straight line), :data:`ARC_CW` (G2) or
  :data:`ARC_CCW` (G3). Arcs are circular, with centre ``centre_mm[i]``, in the plane ``plane[i]``
  (:data:`PLANE_XY` G17, :data:`PLANE_ZX` G18, :data:`PLANE_YZ` G19: the plane through the start
  point normal to Z, Y or X). Clockwise / counter-clockwise as seen from the positive end of that
  normal axis looking towards the origin (ISO 6983), so :data:`ARC_CCW` is a right-hand turn about
  +Z, +Y or +X respectively. Arcs turn by less than 360 degrees; start and end are equidistant
  from the centre (within the fitting tolerance).
* ``use``: what the move is for, which sets its feed rate in the post: :data:`USE_RAPID`,
  :data:`USE_CUT`, :data:`USE_PLUNGE` (plunges, ramps and lead moves into the material),
  :data:`USE_RETRACT`.
* ``tip_offset_mm``: the path's points are the tool's reference point; the tool tip (the point
  a control's length offset G43 drives) is ``xyz - (0, 0, tip_offset_mm)``. Ball-end finishing
  records ball centres (offset R); roughing with a flat or bull-nose mill records the tip (offset 0).
* ``axis`` (simultaneous 5-axis finishing only, issue 19; None for a 3+2 path): the unit tool axis
  at every end point, in the area frame; the tip is then ``xyz - tip_offset_mm * axis``, moves are
  straight (no arcs), and the axis turns along each move (:mod:`planning.toolpath.fiveaxis`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

RAPID, FEED, ARC_CW, ARC_CCW = 0, 1, 2, 3
PLANE_NONE, PLANE_XY, PLANE_ZX, PLANE_YZ = 0, 17, 18, 19
USE_RAPID, USE_CUT, USE_PLUNGE, USE_RETRACT = 0, 1, 2, 3

#: For each arc plane: the indices of its two in-plane axes (first, second) and of its normal, such
#: that (first, second, normal) is right-handed (G17: X, Y, Z; G18: Z, X, Y; G19: Y, Z, X).
PLANE_AXES = {PLANE_XY: (0, 1, 2), PLANE_ZX: (2, 0, 1), PLANE_YZ: (1, 2, 0)}


@dataclass(frozen=True)
class Toolpath:
    """Moves of one operation in an area frame (mm; see the module docstring).

    ``xyz_mm`` (P,3) float64 end points; ``kind`` (P,) int8; ``centre_mm`` (P,3) arc centres (NaN
    on straight moves); ``plane`` (P,) int8 (0 on straight moves); ``use`` (P,) int8;
    ``tip_offset_mm``: reference point to tool tip along -Z (along ``-axis`` when given);
    ``axis`` (P,3) or None: the tool axis per end point of a simultaneous 5-axis path (area frame).
    """

    xyz_mm: np.ndarray
    kind: np.ndarray
    centre_mm: np.ndarray
    plane: np.ndarray
    use: np.ndarray
    tip_offset_mm: float = 0.0
    axis: np.ndarray | None = None

    def __post_init__(self):
        p = self.xyz_mm.shape[0]
        if self.xyz_mm.shape != (p, 3) or self.centre_mm.shape != (p, 3):
            raise ValueError("xyz_mm and centre_mm must be (P,3)")
        if self.axis is not None and self.axis.shape != (p, 3):
            raise ValueError("axis must be (P,3)")
        for name in ("kind", "plane", "use"):
            if getattr(self, name).shape != (p,):
                raise ValueError(f"{name} must be (P,)")

    @property
    def n_moves(self) -> int:
        return int(self.xyz_mm.shape[0])

    def tip_mm(self) -> np.ndarray:
        """(P,3) tool-tip end points (what the post's X Y Z drive)."""
        if self.axis is not None:
            return self.xyz_mm - self.tip_offset_mm * self.axis
        return self.xyz_mm - np.array([0.0, 0.0, self.tip_offset_mm])


def lines(xyz_mm, use, *, tip_offset_mm: float = 0.0, kind=None) -> Toolpath:
    """A toolpath of straight moves: ``kind`` FEED except where ``use`` is USE_RAPID (RAPID), unless
    given."""
    xyz = np.ascontiguousarray(xyz_mm, dtype=np.float64).reshape(-1, 3)
    use = np.asarray(use, dtype=np.int8).reshape(-1)
    if use.shape[0] != xyz.shape[0]:
        raise ValueError("use must have one entry per point")
    k = np.where(use == USE_RAPID, RAPID, FEED).astype(np.int8) if kind is None else np.asarray(kind, np.int8)
    p = xyz.shape[0]
    return Toolpath(xyz_mm=xyz, kind=k, centre_mm=np.full((p, 3), np.nan), plane=np.zeros(p, np.int8),
                    use=use, tip_offset_mm=float(tip_offset_mm))


def concatenate(paths: list[Toolpath]) -> Toolpath:
    """Paths one after another (same tip offset required)."""
    if not paths:
        raise ValueError("nothing to concatenate")
    off = {p.tip_offset_mm for p in paths}
    if len(off) != 1:
        raise ValueError("paths with different tip offsets cannot be joined")
    with_axis = {p.axis is not None for p in paths}
    if len(with_axis) != 1:
        raise ValueError("5-axis and 3-axis paths cannot be joined")
    return Toolpath(xyz_mm=np.concatenate([p.xyz_mm for p in paths]),
                    kind=np.concatenate([p.kind for p in paths]),
                    centre_mm=np.concatenate([p.centre_mm for p in paths]),
                    plane=np.concatenate([p.plane for p in paths]),
                    use=np.concatenate([p.use for p in paths]), tip_offset_mm=off.pop(),
                    axis=np.concatenate([p.axis for p in paths]) if with_axis.pop() else None)


def arc_sweep_rad(start, end, centre, plane: int, ccw: bool) -> tuple[float, float, float]:
    """(start angle, signed sweep, radius) of one arc in its plane's (first, second) coordinates;
    the sweep is positive for counter-clockwise (right-hand about the normal) and in (-2pi, 2pi)."""
    a, b, _ = PLANE_AXES[int(plane)]
    u0, v0 = start[a] - centre[a], start[b] - centre[b]
    u1, v1 = end[a] - centre[a], end[b] - centre[b]
    t0, t1 = math.atan2(v0, u0), math.atan2(v1, u1)
    sweep = (t1 - t0) % (2 * math.pi) if ccw else -((t0 - t1) % (2 * math.pi))
    if sweep == 0.0:
        sweep = 2 * math.pi if ccw else -2 * math.pi
    return t0, sweep, math.hypot(u0, v0)


#: PLANE_AXES as a table by plane code (rows of unused codes are never read).
_PLANE_TABLE = np.zeros((PLANE_YZ + 1, 3), dtype=np.int64)
for _code, _axes in PLANE_AXES.items():
    _PLANE_TABLE[_code] = _axes


def densify(tp: Toolpath, max_step_mm: float = 0.05, *, start_index: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Points along the path from move ``start_index`` on, arcs sampled every ``max_step_mm`` of arc
    length (at least 2 points per arc; the helix component along the normal interpolated linearly).
    Returns ``(points (Q,3), move (Q,))``: each point with the index of the move it lies on (end points
    included, the first point is ``xyz_mm[start_index - 1]`` with move ``start_index - 1``).
    Vectorised over the arcs (the sweep of :func:`arc_sweep_rad`, per arc at once)."""
    xyz = tp.xyz_mm
    moves = np.arange(start_index, tp.n_moves)
    kind = tp.kind[start_index:]
    is_arc = (kind == ARC_CW) | (kind == ARC_CCW)
    counts = np.ones(moves.size, dtype=np.int64)
    arcs = moves[is_arc]
    if arcs.size:
        s, e, c = xyz[arcs - 1], xyz[arcs], tp.centre_mm[arcs]
        a, b, n = _PLANE_TABLE[tp.plane[arcs].astype(np.int64)].T
        rows = np.arange(arcs.size)
        u0, v0 = s[rows, a] - c[rows, a], s[rows, b] - c[rows, b]
        u1, v1 = e[rows, a] - c[rows, a], e[rows, b] - c[rows, b]
        t0, t1 = np.arctan2(v0, u0), np.arctan2(v1, u1)
        ccw = tp.kind[arcs] == ARC_CCW
        sweep = np.where(ccw, np.mod(t1 - t0, 2 * math.pi), -np.mod(t0 - t1, 2 * math.pi))
        sweep = np.where(sweep == 0.0, np.where(ccw, 2 * math.pi, -2 * math.pi), sweep)
        r0, r1 = np.hypot(u0, v0), np.hypot(u1, v1)
        m = np.maximum(2, np.ceil(np.abs(sweep) * np.maximum(r0, 1e-9) / max_step_mm)).astype(np.int64)
        counts[is_arc] = m
    out = np.repeat(xyz[start_index:], counts, axis=0)      # straight moves: their end point
    mv = np.repeat(moves, counts)
    if arcs.size:
        owner = np.repeat(rows, m)                          # arc of each arc point
        k = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m) + 1
        t = k * np.repeat(1.0 / m, m)                       # k / m as np.linspace gives it
        last = k == np.repeat(m, m)
        t[last] = 1.0
        rr = r0[owner] + (r1 - r0)[owner] * t
        ang = t0[owner] + sweep[owner] * t
        pts = np.arange(owner.size)
        aa, bb, nn = a[owner], b[owner], n[owner]
        q = np.empty((owner.size, 3))
        q[pts, aa] = c[owner, aa] + rr * np.cos(ang)
        q[pts, bb] = c[owner, bb] + rr * np.sin(ang)
        q[pts, nn] = s[owner, nn] + (e[owner, nn] - s[owner, nn]) * t
        q[last] = e
        first = (np.cumsum(counts) - counts)[is_arc]        # first output row of each arc
        out[np.repeat(first, m) + k - 1] = q
    return (np.concatenate([xyz[start_index - 1:start_index], out]),
            np.concatenate([[start_index - 1], mv]).astype(np.int64))


def move_lengths_mm(tp: Toolpath) -> np.ndarray:
    """(P,) length of every move, mm: straight moves by their chord, arcs by their true length
    ``hypot(|sweep| r, rise along the plane normal)`` (as :func:`densify` draws them); move 0 is 0.
    Vectorised over the moves."""
    xyz = tp.xyz_mm
    out = np.zeros(tp.n_moves)
    if tp.n_moves < 2:
        return out
    out[1:] = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    arcs = np.flatnonzero((tp.kind == ARC_CW) | (tp.kind == ARC_CCW))
    arcs = arcs[arcs > 0]
    if arcs.size:
        axes = np.array([PLANE_AXES[int(p)] for p in tp.plane[arcs]]).T      # (3, n): first, second, normal
        rows = np.arange(arcs.size)
        s, e, c = xyz[arcs - 1], xyz[arcs], tp.centre_mm[arcs]
        u0, v0 = s[rows, axes[0]] - c[rows, axes[0]], s[rows, axes[1]] - c[rows, axes[1]]
        u1, v1 = e[rows, axes[0]] - c[rows, axes[0]], e[rows, axes[1]] - c[rows, axes[1]]
        t0, t1 = np.arctan2(v0, u0), np.arctan2(v1, u1)
        ccw = tp.kind[arcs] == ARC_CCW
        sweep = np.where(ccw, np.mod(t1 - t0, 2 * math.pi), np.mod(t0 - t1, 2 * math.pi))
        sweep[sweep == 0.0] = 2 * math.pi                    # start = end: a full turn (arc_sweep_rad)
        out[arcs] = np.hypot(sweep * np.hypot(u0, v0), e[rows, axes[2]] - s[rows, axes[2]])
    return out


def path_length_mm(tp: Toolpath, *, kinds=(FEED, ARC_CW, ARC_CCW)) -> float:
    """Length of the moves of the given kinds (arcs by their true arc length), mm."""
    return float(move_lengths_mm(tp)[np.isin(tp.kind, kinds)].sum())


def machining_time_s(tp: Toolpath, *, feed_mm_min: float, plunge_mm_min: float,
                     rapid_mm_min: float) -> float:
    """Time to run the path at the given rates (no acceleration limits), seconds."""
    rate = np.where(tp.use == USE_RAPID, rapid_mm_min,
                    np.where(tp.use == USE_CUT, feed_mm_min, plunge_mm_min)).astype(np.float64)
    return float((move_lengths_mm(tp) / rate).sum() * 60.0)


class BisectedLines:
    """Several polylines (CL lines, (L_k,3) each) held as one array so that their moves can be bisected
    together, vectorised: ``xyz`` (P,3) the points, ``lid`` (P,) the line of each point. Move ``i`` (for
    ``i`` with :meth:`inner` True) runs from ``xyz[i-1]`` to ``xyz[i]`` within one line. Used where moves
    are split at their midpoints with a fresh ball drop until a test holds (finishing's gouge safety,
    :func:`planning.toolpath.finishing._make_safe_many`; the forward step,
    :func:`planning.toolpath.scallop.refine_chords`)."""

    def __init__(self, lines: list[np.ndarray]):
        sizes = np.array([ln.shape[0] for ln in lines], dtype=np.int64)
        self.xyz = np.concatenate(lines) if lines else np.zeros((0, 3))
        self.lid = np.repeat(np.arange(sizes.size), sizes)

    def inner(self) -> np.ndarray:
        """(P,) bool: the points a move of their own line reaches (every point but each line's first)."""
        out = np.zeros(self.lid.size, dtype=bool)
        out[1:] = self.lid[1:] == self.lid[:-1]
        return out

    def insert(self, at: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Put ``points`` (k,3) before the points ``at`` (k,) (ascending indices of inner points: each new
        point splits the move reaching ``xyz[at]``); returns the new points' indices (k,)."""
        at = np.asarray(at, dtype=np.int64)
        self.xyz = np.insert(self.xyz, at, points, axis=0)
        self.lid = np.insert(self.lid, at, self.lid[at])
        return at + np.arange(at.size)

    def split(self) -> list[np.ndarray]:
        """The polylines again, in order."""
        return np.split(self.xyz, np.flatnonzero(np.diff(self.lid)) + 1)
