"""Synthetic clouds and stocks shared by the roughing tests (area frame: tool axis +Z, mm)."""

from __future__ import annotations

import numpy as np

SP = 1.0          # stock sampling spacing (rest roughing), mm


def _grid(x0, x1, y0, y1, sp):
    X, Y = np.meshgrid(np.arange(x0, x1 + 1e-9, sp), np.arange(y0, y1 + 1e-9, sp), indexing="ij")
    return X.ravel(), Y.ravel()


def _dome():
    """A hemisphere of radius 8 standing on a plane (z = -8), 30 x 30 mm."""
    x, y = _grid(-15, 15, -15, 15, 0.75)
    r = np.hypot(x, y)
    z = np.where(r < 8, np.sqrt(np.maximum(64 - r * r, 0.0)), 0.0) - 8.0
    return np.stack([x, y, z], 1)


def _post():
    """A plane at z = -8 with a 6 x 6 mm square post rising to z = 0, its walls sampled."""
    x, y = _grid(-15, 15, -12, 12, 0.75)
    on = (np.abs(x - 3) <= 3) & (np.abs(y) <= 3)
    top = np.stack([x, y, np.where(on, 0.0, -8.0)], 1)
    s = np.arange(-3, 3 + 1e-9, 0.5)
    zs = np.arange(-8, 0 + 1e-9, 0.5)
    rim = np.concatenate([np.stack([3 + s, np.full_like(s, -3)], 1), np.stack([3 + s, np.full_like(s, 3)], 1),
                          np.stack([np.full_like(s, 0.0), s], 1), np.stack([np.full_like(s, 6.0), s], 1)])
    walls = np.array([[p[0], p[1], z] for p in rim for z in zs])
    return np.concatenate([top, walls])


def _pockets(centres, half_x, half_y=10.0, radius=7.0, depth=6.0):
    """A block with its top at z = 0 and round pockets (walls and floor at z = -depth sampled)."""
    x, y = _grid(-half_x, half_x, -half_y, half_y, 0.6)
    pts = []
    inside = np.zeros(x.size, dtype=bool)
    for cx, cy in centres:
        inside |= np.hypot(x - cx, y - cy) < radius
    pts.append(np.stack([x, y, np.where(inside, -depth, 0.0)], 1))
    ang = np.linspace(0, 2 * np.pi, int(2 * np.pi * radius / 0.5), endpoint=False)
    zs = np.arange(-depth, 0 + 1e-9, 0.5)
    for cx, cy in centres:
        ring = np.stack([cx + radius * np.cos(ang), cy + radius * np.sin(ang)], 1)
        pts.append(np.array([[p[0], p[1], z] for p in ring for z in zs]))
    return np.concatenate(pts)


def _dexel_points(top, lo, hi, s=SP, fine=8):
    """End points of the material intervals of the height-field stock ``top`` (material from lo[2]
    up to top(x, y); -inf: none) inside the box lo..hi, along rays parallel to X, Y, Z spaced s
    apart (interval ends along X and Y found every s / fine)."""
    xs = np.arange(lo[0] + s / 2, hi[0], s)
    ys = np.arange(lo[1] + s / 2, hi[1], s)
    zs = np.arange(lo[2] + s / 2, hi[2], s)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    T = np.minimum(top(X, Y), hi[2])
    m = T > lo[2]
    out = [np.stack([X[m], Y[m], T[m]], 1), np.stack([X[m], Y[m], np.full(m.sum(), lo[2])], 1)]
    for axis, other in ((0, ys), (1, xs)):
        a = np.arange(lo[axis], hi[axis] + 1e-9, s / fine)
        A, O, Z = np.meshgrid(a, other, zs, indexing="ij")
        inside = (top(A, O) if axis == 0 else top(O, A)) > Z
        pad = np.zeros((1,) + inside.shape[1:], bool)
        start = inside & ~np.concatenate([pad, inside[:-1]])
        end = inside & ~np.concatenate([inside[1:], pad])
        e = start | end
        p = np.stack([A[e], O[e], Z[e]], 1)
        out.append(p if axis == 0 else p[:, [1, 0, 2]])
    return np.concatenate(out)
