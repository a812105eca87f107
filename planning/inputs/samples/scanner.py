"""Stage 1, reference samples: simulated scanner views of a sampled surface (part frame, mm).

Used by :func:`planning.inputs.samples.femur.femur_like` (the stand-in for the 8 sensor
orientations of Makki et al. 2010 §4.1). :func:`_scanner_directions` gives the unit vectors from
the part towards each scanner. :func:`_assign_views` gives each surface draw to at most one of the
views that face it (n . v > :data:`_MIN_FACING`, incidence under 78 deg), each with probability
1 / m, so every view samples what faces it uniformly. :func:`_recorded_by_views` keeps the draws
that their view sees: a z-buffer of a random subset of the draws per view (:func:`_unoccluded`).
"""

from __future__ import annotations

import functools
import math

import numpy as np


def _scanner_directions(n_dirs: int) -> np.ndarray:
    """Unit vectors from the part towards each scanner (part frame, long axis X).

    n <= 4: n views evenly spaced around the long axis, the first from above (+Z).
    n >= 5: n - 2 views around the long axis (the first from above) and one from each end (+-X).
    """
    n_around = n_dirs if n_dirs <= 4 else n_dirs - 2
    ang = 2.0 * math.pi * np.arange(n_around) / n_around
    dirs = np.column_stack((np.zeros(n_around), np.sin(ang), np.cos(ang)))
    if n_dirs >= 5:
        dirs = np.vstack((dirs, [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]]))
    dirs[np.abs(dirs) < 1e-15] = 0.0
    return dirs


_MIN_FACING = 0.2          # a view records a surface point when n . v > this (78 deg incidence)
_OCCLUDER_BUDGET = 400_000  # surface draws splatted into each view's z-buffer, at most


@functools.lru_cache(maxsize=8)
def _max_facing(n_dirs):
    """Most of the views of :func:`_scanner_directions` that any unit normal faces
    (n . v > _MIN_FACING), over a dense Fibonacci sphere."""
    dirs = _scanner_directions(n_dirs)
    m = 200_000
    i = np.arange(m) + 0.5
    z = 1.0 - 2.0 * i / m
    r = np.sqrt(1.0 - z * z)
    ph = math.pi * (3.0 - math.sqrt(5.0)) * i
    u = np.column_stack((r * np.cos(ph), r * np.sin(ph), z))
    return int(max(1, (u @ dirs.T > _MIN_FACING).sum(axis=1).max()))


def _basis(v):
    e1 = np.cross(v, [0.0, 0.0, 1.0] if abs(v[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(v, e1)


def _unoccluded(occ_x, occ_n, xc, nc, v, cell):
    """Mask over candidate rows ``xc`` (normals ``nc``): not hidden from direction ``v``.

    z-buffer: occluder points (``occ_x``, a dense sample of the whole surface) facing ``v``
    are splatted into a grid of ``cell`` mm in the plane normal to ``v``, each cell keeping the
    largest depth x . v. A candidate is unoccluded when its depth is within
    ``cell * (sqrt(2) tan(incidence) + 1)`` of its cell's maximum: the most a surface of its own
    slope rises across one cell, so that no point is hidden by its own neighbours; an occluder
    closer than that in depth is missed.
    """
    e1, e2 = _basis(v)
    occ = occ_x[occ_n @ v > 0.0]
    inv = 1.0 / cell
    a, b, ac, bc = occ @ e1, occ @ e2, xc @ e1, xc @ e2
    a0, b0 = min(a.min(), ac.min()), min(b.min(), bc.min())
    ia = ((a - a0) * inv).astype(np.int64)
    ib = ((b - b0) * inv).astype(np.int64)
    ca = ((ac - a0) * inv).astype(np.int64)
    cb = ((bc - b0) * inv).astype(np.int64)
    nb = int(max(ib.max(), cb.max())) + 1
    zbuf = np.full((int(max(ia.max(), ca.max())) + 1) * nb, -np.inf)
    np.maximum.at(zbuf, ia * nb + ib, occ @ v)
    dot = nc @ v
    tan = np.sqrt(np.maximum(1.0 - dot * dot, 0.0)) / np.maximum(dot, 1e-12)
    return xc @ v >= zbuf[ca * nb + cb] - cell * (math.sqrt(2.0) * tan + 1.0)


def _assign_views(rng, nrm, dirs, m_max):
    """The view (index into ``dirs``, int8) of each draw with unit normal ``nrm``, or -1 for none.

    Each draw goes to at most one view: the pick-th of the views it faces, pick uniform in
    [0, m_max), so every facing view gets it with probability 1 / m_max and each view records the
    surface facing it uniformly, independently of the others.
    """
    pick = rng.integers(0, m_max, nrm.shape[0]).astype(np.int8)
    count = np.zeros(nrm.shape[0], np.int8)
    view = np.full(nrm.shape[0], -1, np.int8)
    for s in range(dirs.shape[0]):
        fs = nrm @ dirs[s] > _MIN_FACING
        view[fs & (count == pick)] = s
        count += fs
    return view


def _recorded_by_views(rng, x, nrm, view, dirs, area_mm2):
    """Indices of the draws (points ``x``, unit normals ``nrm``) that their ``view`` records,
    grouped by view: those the part does not hide (:func:`_unoccluded`). The occluders are a
    random subset of all draws, about :data:`_OCCLUDER_BUDGET` of them, the same for every view;
    the z-buffer cell (mm) follows from their density over the surface area ``area_mm2``."""
    occ = np.flatnonzero(rng.random(x.shape[0]) < _OCCLUDER_BUDGET / x.shape[0])
    occ_x, occ_n = x[occ], nrm[occ]
    cell = 2.0 / math.sqrt(occ.size / area_mm2)
    kept = []
    for s in range(dirs.shape[0]):
        t = np.flatnonzero(view == s)
        if t.size:
            kept.append(t[_unoccluded(occ_x, occ_n, x[t], nrm[t], dirs[s], cell)])
    return np.concatenate(kept) if kept else np.zeros(0, np.int64)
