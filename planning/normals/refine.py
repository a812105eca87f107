"""Plane-fit refinement of sphere-throwing normals (opt-in: ``sphere_throwing(..., refine=True)``).

Why
---
Sphere throwing's normal at a touched point is the mean of the directions ``(C_l - C_c) / r`` from the
point to the centres of the balls that stopped on it. A ball resting on a discrete cloud touches the
candidate point nearest to the true tangent point, so each contact's direction is off by up to
``asin(a / r)`` with ``a`` the distance between candidates (``2 g``, the candidate cell), and the per-point
mean cancels that only where the lines a point captured lie symmetrically around it. On dense clouds
(45 points/mm^2, ``g`` 0.22 mm, ``r`` 3.5 mm) that leaves about 2 deg median. On a range scan at the
usual pitches (0.3 mm along, 0.6 mm across the lines) the density-derived ``g`` is 0.45-0.48 mm, the
candidates are ~1 mm apart and the error grows to 3-4 deg median and 12-17 deg at the 95th
percentile (``bench/bench_normals_range.py``), against 1 deg / 2-3 deg for a local plane fit
(Open3D's KNN 20) on the same clouds; the scan's open boundaries (its holes at grazing incidence and
the rim at the table) add contacts from balls hanging past the edge, 13 deg median there. Noise
(0-0.1 mm along the ray) and the anisotropy of the pitches matter little; the candidate spacing
relative to ``r`` does.

What
----
For every touched point ``p`` the points of the whole cloud within ``radius`` (default the candidate
cell, ``CELL_LINES * g``, i.e. 3 point spacings at the default grid) are fitted with a least-squares
plane (the eigenvector of the smallest eigenvalue of their covariance, Hoppe et al. 1992); its normal,
turned to the side of the sphere-throwing normal, replaces the latter. Which points are sampled, and
the orientation (outward by construction), stay sphere throwing's; only the direction is refitted.
The sphere-throwing normal is kept where the fit is not trustworthy: fewer than ``min_points``
neighbours, a neighbourhood that is not a patch (the middle eigenvalue below ``min_spread`` times the
largest: points along one scan line, the lines too far apart for the radius; or the smallest above
``max_flatness`` times the middle one: a thick blob), or a fitted
plane more than ``max_turn_deg`` from the throwing normal (a neighbourhood reaching across a thin wall or
an edge); a point whose fit fails is tried once more at twice the radius (lines farther apart than the
candidate cell on anisotropic scans, 0.3 x 1.2 mm). Vectorised: one KD-tree query, segment sums of the coordinates and their products, and a
batched 3 x 3 symmetric eigen-solve; the covariance is formed about each neighbourhood's first point
(shifted sums), so it stays accurate far from the origin.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["refine_normals"]

_MIN_POINTS = 6
_MAX_FLATNESS = 0.25
_MIN_SPREAD = 0.05
_MAX_TURN_DEG = 60.0


def refine_normals(points: np.ndarray, sample_index: np.ndarray, normals: np.ndarray, radius_mm: float, *,
                   min_points: int = _MIN_POINTS, max_flatness: float = _MAX_FLATNESS,
                   min_spread: float = _MIN_SPREAD, max_turn_deg: float = _MAX_TURN_DEG,
                   retries: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Refit the normals of ``points[sample_index]`` by local plane fits over the whole cloud.

    ``points`` (N, 3) float64; ``sample_index`` (n,) int; ``normals`` (n, 3) unit, oriented (sphere
    throwing's); ``radius_mm`` > 0 the neighbourhood radius. Returns ``(refined, fitted)``: the (n, 3)
    unit normals, each on the side of its input normal, and the (n,) bool mask of those replaced by a
    fit (the others are the input normals unchanged). Points whose fit fails the checks are tried
    again ``retries`` times at twice the radius each time (scan lines farther apart than the radius).
    See the module docstring for the checks."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    idx = np.asarray(sample_index, dtype=np.int64)
    out = np.asarray(normals, dtype=np.float64).copy()
    fitted = np.zeros(idx.size, dtype=bool)
    if idx.size == 0 or not (radius_mm > 0.0):
        return out, fitted
    tree = cKDTree(p)
    todo = np.arange(idx.size)
    r = float(radius_mm)
    for _ in range(max(0, int(retries)) + 1):
        n_fit, ok = _fit(tree, p, idx[todo], out[todo], r, min_points, max_flatness, min_spread, max_turn_deg)
        out[todo[ok]] = n_fit[ok]
        fitted[todo[ok]] = True
        todo = todo[~ok]
        r *= 2.0
        if todo.size == 0:
            break
    return out, fitted


def _fit(tree, p, idx, nin, radius_mm, min_points, max_flatness, min_spread, max_turn_deg):
    """One pass of plane fits at one radius: (fitted unit normals, bool mask of the well-posed fits)."""
    n = idx.size
    centre = p[idx]
    nb = tree.query_ball_point(centre, float(radius_mm), return_sorted=False)
    counts = np.fromiter(map(len, nb), dtype=np.int64, count=n)
    flat = np.concatenate(nb).astype(np.int64) if counts.sum() else np.zeros(0, np.int64)
    del nb
    owner = np.repeat(np.arange(n), counts)
    q = p[flat] - centre[owner]                     # about the sampled point: small numbers, no cancellation
    del flat
    starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
    nonempty = counts > 0
    s1 = np.zeros((n, 3))
    s1[nonempty] = np.add.reduceat(q, starts[nonempty], axis=0)
    s2 = np.zeros((n, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            col = np.zeros(n)
            col[nonempty] = np.add.reduceat(q[:, a] * q[:, b], starts[nonempty])
            s2[:, a, b] = s2[:, b, a] = col
    del q, owner
    cnt = np.maximum(counts, 1).astype(np.float64)
    mean = s1 / cnt[:, None]
    cov = s2 / cnt[:, None, None] - mean[:, :, None] * mean[:, None, :]
    w, v = np.linalg.eigh(cov)                      # ascending eigenvalues
    fit = v[:, :, 0]
    dots = np.einsum("ij,ij->i", fit, nin)
    fit[dots < 0.0] *= -1.0
    ok = (counts >= min_points) & (w[:, 1] > 0.0) & (w[:, 0] <= max_flatness * w[:, 1]) \
        & (w[:, 1] >= min_spread * w[:, 2]) & (np.abs(dots) >= math.cos(math.radians(max_turn_deg)))
    fit /= np.linalg.norm(fit, axis=1)[:, None]
    return fit, ok
