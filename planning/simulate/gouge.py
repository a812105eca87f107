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
  centre segment)`` (exact for the swept ball);
* flat or bull-nose end mill of radius Rt, cutting up to the flute length L: the cylinder
  ``0 <= (p - q).a <= L``, radial distance <= Rt, swept along the segment; on the part of the move
  where the point is within Rt of the axis, sampled at 65 equal steps; depth at a sample = the distance from p to the
  cylinder's bottom face or side, whichever is nearer. A bull-nose is taken as the flat cylinder
  that contains it (its depth can only read deeper). The ball-end cutter's fluted cylinder above
  the ball (up to the flute length) counts with the depth to its side.

Only the moves that pass within reach of a point are measured (a k-d tree over the moves'
bounding spheres).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from planning.simulate.motion import FEED, ProgramMotion, ToolShape

#: Moves are cut into pieces of at most this length (mm) to find the moves near a point.
PIECE_MM = 4.0


def _ball_depth(p: np.ndarray, s: np.ndarray, e: np.ndarray, R: float) -> np.ndarray:
    v = e - s
    L2 = np.einsum("ij,ij->i", v, v)
    t = np.clip(np.einsum("ij,ij->i", p - s, v) / np.maximum(L2, 1e-300), 0.0, 1.0)
    q = s + t[:, None] * v
    return R - np.linalg.norm(p - q, axis=1)


def _flat_depth(p: np.ndarray, s: np.ndarray, e: np.ndarray, a: np.ndarray, Rt: float, L: float,
                samples: int = 65, side_only: bool = False) -> np.ndarray:
    """Depth of each point ``p`` (k,3) inside the cylinder (radius ``Rt``, from the tip ``q`` up to
    ``L`` along the unit axis ``a``) swept from tip ``s`` to ``e``: on the part of the move where the
    point is within ``Rt`` of the axis (the roots of a quadratic in the move's parameter), at
    ``samples`` equal steps; ``-inf`` where the point is never inside."""
    v = e - s
    w0 = p - s
    vv = v - np.einsum("ij,ij->i", v, a)[:, None] * a          # the move across the axis
    ww = w0 - np.einsum("ij,ij->i", w0, a)[:, None] * a
    A = np.einsum("ij,ij->i", vv, vv)
    B = -2.0 * np.einsum("ij,ij->i", ww, vv)
    C = np.einsum("ij,ij->i", ww, ww) - Rt * Rt
    disc = B * B - 4.0 * A * C
    moving = A > 1e-18
    root = np.sqrt(np.maximum(disc, 0.0))
    t0 = np.where(moving, (-B - root) / (2.0 * np.maximum(A, 1e-300)), 0.0)
    t1 = np.where(moving, (-B + root) / (2.0 * np.maximum(A, 1e-300)), 1.0)
    t0, t1 = np.clip(t0, 0.0, 1.0), np.clip(t1, 0.0, 1.0)
    hit = np.where(moving, disc >= 0.0, C <= 0.0) & (t1 >= t0)
    out = np.full(p.shape[0], -np.inf)
    f = np.linspace(0.0, 1.0, samples)
    hits = np.flatnonzero(hit)
    for c0 in range(0, hits.size, 20_000):                 # bounded memory: (20k, samples, 3)
        idx = hits[c0:c0 + 20_000]
        t = t0[idx, None] + (t1 - t0)[idx, None] * f[None, :]                       # (m, S)
        w = w0[idx, None, :] - t[:, :, None] * v[idx, None, :]                      # p - q(t)
        h = np.einsum("msk,mk->ms", w, a[idx])
        r = np.linalg.norm(w - h[:, :, None] * a[idx, None, :], axis=2)
        inside = (h >= 0.0) & (h <= L) & (r <= Rt + 1e-12)
        d = np.where(inside, (Rt - r) if side_only else np.minimum(h, Rt - r), -np.inf)
        out[idx] = d.max(axis=1)
    return out


def penetration_mm(points: np.ndarray, motions: list[ProgramMotion], tools: dict[int, ToolShape]) -> np.ndarray:
    """(n,) how deep each of ``points`` (n,3, part frame, mm) lies inside the cutting part of a tool
    on any FEED move of ``motions`` (module docstring; ``tools`` by T number); ``-inf`` where no
    move's tool reaches it (<= 0: not cut)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.full(pts.shape[0], -np.inf)
    if pts.shape[0] == 0:
        return out
    for m in motions:
        for number, shape in tools.items():
            sel = np.flatnonzero((m.kind == FEED) & (m.tool == number))
            if sel.size == 0:
                continue
            s, e, a = m.start_mm[sel], m.end_mm[sel], m.axis[sel]
            # every cutting point of the tool lies within this of its tip (the ball: 2 R)
            reach = max(float(np.hypot(shape.radius_mm, shape.flute_length_mm)), 2.0 * shape.radius_mm) + 1e-6
            # candidate (point, move) pairs: the moves cut into pieces of at most PIECE_MM, a k-d
            # tree over the pieces' mid points, every point's pieces within PIECE_MM / 2 + reach
            length = np.linalg.norm(e - s, axis=1)
            n = np.maximum(1, np.ceil(length / PIECE_MM).astype(np.int64))
            owner = np.repeat(np.arange(sel.size), n)
            k = np.arange(owner.size) - np.repeat(np.cumsum(n) - n, n)
            f = ((k + 0.5) / n[owner])[:, None]
            mids = s[owner] + f * (e - s)[owner]
            near = cKDTree(mids).query_ball_point(pts, 0.5 * PIECE_MM + reach)
            cnt = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(near))
            if cnt.sum() == 0:
                continue
            pair = np.unique(np.c_[np.repeat(np.arange(pts.shape[0]), cnt),
                                   owner[np.concatenate([np.asarray(x, dtype=np.int64) for x in near if x])]], axis=0)
            pi, mv = pair[:, 0], pair[:, 1]
            if shape.kind == "ball":
                R = shape.radius_mm
                d = _ball_depth(pts[pi], s[mv] + R * a[mv], e[mv] + R * a[mv], R)
                if shape.flute_length_mm > R:        # the fluted cylinder above the ball: its side
                    side = _flat_depth(pts[pi], s[mv] + R * a[mv], e[mv] + R * a[mv], a[mv], R,
                                       shape.flute_length_mm - R, side_only=True)
                    d = np.maximum(d, side)
            else:
                d = _flat_depth(pts[pi], s[mv], e[mv], a[mv], shape.radius_mm, shape.flute_length_mm)
            np.maximum.at(out, pi, d)
    return out
