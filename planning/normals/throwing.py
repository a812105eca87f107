"""Outward normals by sphere throwing (Makki et al. 2010 §2.1, eq. 2.1), vectorised.

The method
----------
For each throwing direction ``d`` (normalised; the sphere comes from ``+d`` towards the part, i.e.
it is dropped along ``-d``) a square grid of lines parallel to ``d``, ``grid_spacing_mm`` = ``g``
apart, is laid in the plane normal to ``d``. A ball of radius ``r = D/2`` is lowered along each
line until it touches the cloud. With ``h`` the height of a point along ``d`` and ``rho`` its
distance from the line, the ball centre stops at

    H = max over points with rho < r of  h + sqrt(r^2 - rho^2)

and the maximising point is the touched point ``C_c``; its normal is ``(C_l - C_c) / r`` with
``C_l`` the ball centre: a unit vector pointing from the material towards the ball, i.e. outward
(Makki's Remark 1). Lines that touch nothing give nothing. A point touched several times (by
several lines and/or directions) gets the normalised mean of its normals; ``touches`` says how
many were averaged. Only touched points get a normal (the paper's femur: ~10 % of the points).

What is exact and what is not
-----------------------------
The lines are split into *candidate cells*: squares of side ``2 g`` in the plane normal to ``d``,
each holding 2 x 2 grid lines. In each cell only the point that is highest along ``d`` can be
touched (the "top" point, ties to the lowest input index). Given that subsample the drop is exact:
for every line the ball height is the maximum of ``h + sqrt(r^2 - rho^2)`` over *every* top point
within ``r`` of the line, each evaluated at its exact position (nothing is snapped to the grid).
The search runs in float32 in a frame centred on the cloud, so heights that differ by less than
about 1e-5 mm (times the cloud extent / 100 mm) may be ordered either way; the reported normals
are then recomputed in float64 from the original coordinates, and are unit length to 1e-12.

The approximation is the discarding of non-top points. A non-top point sits below the top point
of its cell, so the ball can sink below the exact drop height into the full cloud, by at most the
rise of the ball surface across one cell. Measured against an exact drop on all points (noisy wave
patch, 45 points/mm^2, sigma 0.02 mm, D 7, g 0.25): seen face-on, 40 % of the lines touch the same
point, the ball sinks by a median 0.008 mm (90th percentile 0.09 mm) and the per-line normals differ
by a median 2.9 deg; about 1 % of the exact lines (at the rim of the cloud) get no contact. After
averaging per point the effect is small where the cloud is dense: on the analytic surfaces of
``tests/surfaces.py`` at the default grid the error against the exact surface normals is within
0.11 deg (median) and 0.2 deg (95th percentile) of the exact method's (e.g. tilted plane 1.59 / 3.90
deg against 1.59 / 3.82), but about 40 % fewer points receive a normal (7.5 % against 12 %). On
steep walls seen from the side (the shaft of ``planning.inputs.samples.femur_like``, 19 points/mm^2, sigma
0.03 mm) the top point of a cell is a poor stand-in for the touched one and the tail grows: per-point
median 2.58 deg against 2.44, 95th percentile 13.1 deg against 7.4 (whole femur: 2.41 / 7.8 deg).
``tests/test_normals.py`` checks the search against a brute-force drop on the candidate subset
(identical contacts) and against one on all points (the tolerances above).

Speed
-----
Per direction: one pass over the points to bin them (``ufunc.at`` maxima, no sort), then the heights
of all lines are computed on a dense raster of candidate cells by a loop over the few hundred cell
offsets within ``r`` (each step is a handful of whole-array float32 operations over all lines), keeping
the running maximum and the offset that gave it. The directions run in parallel threads (numpy
releases the GIL in these loops). There is no Python loop over points or lines. Cost grows like
(number of lines) x (r / 2g)^2, i.e. like 1 / g^4 for a given cloud.

On sparse scans the contact error dominates (it grows like ``asin(2 g / r)``): on simulated range scans
(0.3 x 0.6 mm pitches, ``g`` about 0.45 mm) 3-4 deg median and 12-17 deg p95, against about 1 / 2-3 deg
for a local plane fit. ``refine=True`` keeps the sampled points and the orientation and refits each
direction by a plane through the cloud's points within ``2 g`` (:mod:`planning.normals.refine`).

Default grid spacing (:func:`default_grid_spacing_mm`)
-----------------------------------------------------
``g = 1.5 s`` where ``s`` is the typical point spacing on the surface, clipped to
``[r / 32, r / 4]`` and rounded to 3 significant digits. ``s = 1 / sqrt(surface density)`` is
estimated on a fixed pseudo-random subsample of at most 20,000 points: the median distance to the
8th nearest neighbour in the subsample gives its density (``(k - 1/3) / (pi d^2)``, the median of a
planar Poisson process), scaled by the subsampling fraction. At 45 points/mm^2 (the paper's femur)
``s`` is 0.149 mm and ``g`` 0.22 mm (candidate cells 0.45 mm); on ``planning.inputs.samples.femur_like``
(19 points/mm^2) ``g`` is about 0.34 mm.

Layout: one module of a little over 600 lines, a tenth of it this docstring: the checks, the default
spacing and the per-direction search (:func:`_throw_direction` and its four steps) serve one method
and share its constants; :func:`sphere_throwing` and :func:`throw_lines` are the entries.
"""

from __future__ import annotations

import contextlib
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, NamedTuple, Sequence

import numba
import numpy as np

from planning.errors import InputError, ParameterError

__all__ = [
    "DEFAULT_DIRECTIONS",
    "NormalsResult",
    "LineContacts",
    "default_grid_spacing_mm",
    "point_spacing_mm",
    "sphere_throwing",
    "throw_lines",
    "direction_frame",
    "MAX_CELLS_PER_DIRECTION",
    "MAX_RADIUS_OVER_SPACING",
]

#: The paper's five throwing directions: +Z, +X, -X, +Y, -Y (the sphere comes from +direction).
DEFAULT_DIRECTIONS = ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, -1.0, 0.0))

#: Largest raster of candidate cells (each ``2 g`` square) per direction: guards memory (~16 bytes
#: per cell plus ~8 per line) against a grid far too fine for the cloud's extent.
MAX_CELLS_PER_DIRECTION = 1 << 25

#: Largest ratio sphere radius / grid spacing: the per-line search visits ~pi (r / 2g)^2 cells.
MAX_RADIUS_OVER_SPACING = 128.0

# Default-spacing rule (see module docstring).
_SPACING_FACTOR = 1.5
_SPACING_MIN_FRAC_R = 1.0 / 32.0
_SPACING_MAX_FRAC_R = 1.0 / 4.0
_DENSITY_SAMPLE = 20_000
_DENSITY_K = 8
_DENSITY_SEED = 20100605   # fixed: the same cloud always gives the same spacing

# Lines per candidate cell along each axis (cells are CELL_LINES * g wide).
CELL_LINES = 2

Progress = Callable[[float, str], None]


@dataclass(frozen=True)
class NormalsResult:
    """Outcome of :func:`sphere_throwing`.

    ``sample_index`` (n,) int64, sorted ascending: indices into the input points that got a normal.
    ``normals`` (n,3) float64 unit vectors, outward (from the material towards the thrown sphere).
    ``touches`` (n,) int32: how many (direction, grid line) contacts were averaged into each normal.
    ``grid_spacing_mm``: the line spacing actually used; ``sphere_diameter_mm``: the sphere's.
    ``n_refined``: how many normals a plane fit replaced (``refine=True``; 0 otherwise).
    """

    sample_index: np.ndarray
    normals: np.ndarray
    touches: np.ndarray
    grid_spacing_mm: float
    sphere_diameter_mm: float
    n_refined: int = 0


@dataclass(frozen=True)
class LineContacts:
    """Every grid line of one throwing direction that touched the cloud (see :func:`throw_lines`).

    ``direction``, ``e_u``, ``e_v``: the orthonormal frame (the lines are parallel to ``direction``;
    line ``(i, j)`` passes through ``origin + i g e_u + j g e_v``). ``line_ij`` (m,2) int64 grid
    indices; ``contact_index`` (m,) int64 the touched input point; ``centres`` (m,3) the ball centre
    ``C_l`` in the input frame; ``normals`` (m,3) ``(C_l - C_c) / r``. Rows are ordered by ``(i, j)``.
    ``candidate_index`` (k,) int64 sorted: the points that could be touched (the top point of each
    candidate cell); the drop is exact on this subset.
    """

    direction: np.ndarray
    e_u: np.ndarray
    e_v: np.ndarray
    origin: np.ndarray
    grid_spacing_mm: float
    sphere_diameter_mm: float
    line_ij: np.ndarray
    contact_index: np.ndarray
    centres: np.ndarray
    normals: np.ndarray
    candidate_index: np.ndarray


# ----------------------------------------------------------------------------------------------
# validation

def _as_points(points) -> np.ndarray:
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"points must be an (N, 3) array of numbers: {exc}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must be an (N, 3) array, got shape {p.shape}")
    if p.shape[0] == 0:
        raise InputError("the cloud is empty: sphere throwing needs at least one point")
    if p.shape[0] >= np.iinfo(np.int32).max:
        raise InputError(f"the cloud has {p.shape[0]} points; at most {np.iinfo(np.int32).max - 1} "
                         "are supported")
    if not np.isfinite(p).all():
        bad = int(np.count_nonzero(~np.isfinite(p).all(axis=1)))
        raise InputError(f"the cloud has {bad} point(s) with NaN or infinite coordinates")
    return p


def _check_diameter(sphere_diameter_mm) -> float:
    try:
        dval = float(sphere_diameter_mm)
    except (TypeError, ValueError):
        raise ParameterError(f"sphere_diameter_mm = {sphere_diameter_mm!r}: must be a number of mm > 0",
                             parameter="sphere_diameter_mm", value=repr(sphere_diameter_mm)) from None
    if not (math.isfinite(dval) and dval > 0.0):
        raise ParameterError(f"sphere_diameter_mm = {dval:g}: must be a finite number of mm > 0",
                             parameter="sphere_diameter_mm", value=dval)
    return dval


def _check_spacing(grid_spacing_mm, diameter: float) -> float:
    try:
        g = float(grid_spacing_mm)
    except (TypeError, ValueError):
        raise ParameterError(f"grid_spacing_mm = {grid_spacing_mm!r}: must be a number of mm > 0 "
                             "(or None for the density-derived default)",
                             parameter="grid_spacing_mm", value=repr(grid_spacing_mm)) from None
    if not (math.isfinite(g) and g > 0.0):
        raise ParameterError(f"grid_spacing_mm = {g:g}: must be a finite number of mm > 0 "
                             "(or None for the density-derived default)",
                             parameter="grid_spacing_mm", value=g)
    gmin = diameter / 2.0 / MAX_RADIUS_OVER_SPACING
    if g < gmin:
        raise ParameterError(
            f"grid_spacing_mm = {g:g} is too fine for sphere_diameter_mm = {diameter:g}: it must be at "
            f"least sphere_diameter_mm / {2 * MAX_RADIUS_OVER_SPACING:g} = {gmin:.4g} mm",
            parameter="grid_spacing_mm", value=g, minimum=gmin)
    return g


def _check_directions(directions) -> np.ndarray:
    try:
        d = np.asarray(directions, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"directions = {directions!r}: must be a list of 3-vectors",
                             parameter="directions", value=repr(directions)) from None
    if d.size == 0:
        raise ParameterError("directions is empty: give at least one throwing direction",
                             parameter="directions", value=[])
    if d.ndim == 1 and d.shape == (3,):
        d = d[None, :]
    if d.ndim != 2 or d.shape[1] != 3:
        raise ParameterError(f"directions must be a list of 3-vectors (k, 3), got shape {d.shape}",
                             parameter="directions", value=repr(directions))
    if not np.isfinite(d).all():
        raise ParameterError("directions must be finite 3-vectors", parameter="directions",
                             value=d.tolist())
    norm = np.linalg.norm(d, axis=1)
    bad = np.flatnonzero(~(norm > 1e-12))
    if bad.size:
        raise ParameterError(f"directions[{int(bad[0])}] = {d[bad[0]].tolist()} is the zero vector: every "
                             "throwing direction must be a non-zero 3-vector",
                             parameter="directions", value=d.tolist())
    return d / norm[:, None]


# ----------------------------------------------------------------------------------------------
# default grid spacing

def point_spacing_mm(points) -> float:
    """Typical distance between neighbouring points on the scanned surface, ``1 / sqrt(density)``.

    Estimated on a fixed pseudo-random subsample of at most 20,000 points: ``d`` = median distance
    to the 8th nearest neighbour inside the subsample, surface density of the subsample
    ``(8 - 1/3) / (pi d^2)`` (median for a planar Poisson process), times ``N / n_sample`` for the
    whole cloud. Deterministic. Returns ``nan`` for fewer than 9 distinct points.
    """
    from scipy.spatial import cKDTree

    p = _as_points(points)
    n = p.shape[0]
    k = _DENSITY_K
    if n <= k:
        return float("nan")
    if n > _DENSITY_SAMPLE:
        rng = np.random.default_rng(_DENSITY_SEED)
        idx = np.sort(rng.choice(n, size=_DENSITY_SAMPLE, replace=False))
        sub = p[idx]
    else:
        sub = p
    m = sub.shape[0]
    dist, _ = cKDTree(sub).query(sub, k=k + 1)
    dk = float(np.median(dist[:, k]))
    if not dk > 0.0:
        return float("nan")
    spacing_sub = dk * math.sqrt(math.pi / (k - 1.0 / 3.0))
    return spacing_sub * math.sqrt(m / n)


def default_grid_spacing_mm(points, sphere_diameter_mm) -> float:
    """The line spacing used when ``grid_spacing_mm`` is None.

    Rule: ``1.5 x`` :func:`point_spacing_mm` (so each ``2 g`` candidate cell holds about 9 surface
    points seen face-on), clipped to ``[r / 32, r / 4]`` with ``r`` the sphere radius (the upper bound
    keeps several lines per contact on sparse clouds, the lower one bounds the work on very dense
    ones), rounded to 3 significant digits. 45 points/mm^2 and D 7 mm give 0.224 mm.
    """
    dval = _check_diameter(sphere_diameter_mm)
    r = dval / 2.0
    s = point_spacing_mm(points)
    lo, hi = r * _SPACING_MIN_FRAC_R, r * _SPACING_MAX_FRAC_R
    g = hi if not math.isfinite(s) else min(max(_SPACING_FACTOR * s, lo), hi)
    return float(f"{g:.3g}")


# ----------------------------------------------------------------------------------------------
# one direction

def direction_frame(direction) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal frame ``(d, e_u, e_v)`` used for a throwing direction (deterministic).

    Axis-aligned directions use the other two axes in increasing order (+-Z: X, Y; +-X: Y, Z;
    +-Y: X, Z); others take ``e_u`` from the axis least aligned with ``d``, and ``e_v = d x e_u``.
    """
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    d = d / np.linalg.norm(d)
    nz = np.flatnonzero(d != 0.0)
    if nz.size == 1:
        others = [k for k in range(3) if k != nz[0]]
        eu = np.zeros(3)
        ev = np.zeros(3)
        eu[others[0]] = 1.0
        ev[others[1]] = 1.0
        d = np.sign(d)
        return d, eu, ev
    a = np.zeros(3)
    a[int(np.argmin(np.abs(d)))] = 1.0
    eu = a - (a @ d) * d
    eu /= np.linalg.norm(eu)
    ev = np.cross(d, eu)
    ev /= np.linalg.norm(ev)
    return d, eu, ev


def _project32(cols32, vec) -> np.ndarray:
    """``cols32 @ vec`` in float32 for three contiguous coordinate columns (exact for axis vectors)."""
    nz = np.flatnonzero(vec != 0.0)
    if nz.size == 1 and abs(vec[nz[0]]) == 1.0:
        c = cols32[nz[0]]
        return c if vec[nz[0]] > 0 else np.negative(c)
    out = cols32[0] * np.float32(vec[0])
    out += cols32[1] * np.float32(vec[1])
    out += cols32[2] * np.float32(vec[2])
    return out


def _top_per_cell(cell: np.ndarray, h: np.ndarray, ncell: int):
    """Highest ``h`` per cell and the lowest point index attaining it (``len(h)`` where empty)."""
    cm = np.full(ncell, -np.inf, dtype=np.float32)
    np.maximum.at(cm, cell, h)
    cand = np.flatnonzero(h == cm[cell]).astype(np.int32)
    top = np.full(ncell, h.shape[0], dtype=np.int32)
    np.minimum.at(top, cell[cand], cand)
    return cm, top


def _offsets(r: float, g: float, pad: int):
    """Cell offsets (A, B) that can hold a point within r of a line of sub-lattice (a, b).

    Returns per offset: A, B and for each of the CELL_LINES^2 sub-lattices the cell's lower-left
    corner relative to the line (cx, cy) and whether any part of the cell is closer than r; sorted
    by the distance from the cell centre to the cell's line group centre (deterministic ties).
    """
    m = CELL_LINES
    G = m * g
    rows = []
    for A in range(-pad, pad + 1):
        for B in range(-pad, pad + 1):
            subs = []
            for a in range(m):
                for b in range(m):
                    cx = (m * A - a - 0.5) * g
                    cy = (m * B - b - 0.5) * g
                    dx = max(cx, 0.0, -(cx + G))
                    dy = max(cy, 0.0, -(cy + G))
                    subs.append((cx, cy, dx * dx + dy * dy < r * r))
            if any(s[2] for s in subs):
                rows.append((A * A + B * B, A, B, subs))
    rows.sort(key=lambda t: (t[0], t[1], t[2]))
    return [(A, B, subs) for _, A, B, subs in rows]


class _Grid(NamedTuple):
    """The flat raster of candidate cells of one direction (cells ``2 g`` wide, ``CELL_LINES``
    lines per cell along each axis): cell ``(I, J)`` is at flat index
    ``margin + (I - i0 + 2 pad) ny + (J - j0 + 2 pad)``, with ``2 pad`` empty cells around the
    occupied ones and ``margin`` guard cells before and after. ``swap``: the raster's rows run
    along ``e_v`` (the longer side is put along the contiguous axis)."""

    swap: bool
    i0: int
    j0: int
    nx: int
    ny: int
    pad: int
    margin: int

    @property
    def base(self) -> int:
        """Flat index of the first line's cell (raster row ``pad``)."""
        return self.margin + self.pad * self.ny

    @property
    def length(self) -> int:
        """Number of lines: raster rows ``pad .. nx - pad - 1``, every column."""
        return (self.nx - 2 * self.pad) * self.ny


def _throw_direction(cols32, p64, origin, direction, r: float, g: float):
    """All line contacts for one direction: (line_i, line_j, contact index) int64 arrays + frame.

    In four steps: the candidate cells and their top points (:func:`_candidate_cells`), the ball's
    stop on every line over the top points within ``r`` (:func:`_drop_heights`), the top point
    that stopped it (:func:`_line_contacts`), and each contact's normal and ball centre in float64
    (:func:`_contact_normals`)."""
    d, eu, ev = direction_frame(direction)
    grid, cm, top, tdx, tdy, tp = _candidate_cells(cols32, d, eu, ev, r, g)
    best, arg, shifts = _drop_heights(grid, cm, tdx, tdy, r, g)
    del cm, tdx, tdy
    li, lj, lp = _line_contacts(grid, best, arg, shifts, top)
    if grid.swap:   # report (i, j) along the frame's (e_u, e_v) as returned by direction_frame
        li, lj = lj, li
    order = np.lexsort((lj, li))
    li, lj, lp = li[order], lj[order], lp[order]
    centres, nrm = _contact_normals(p64, origin, d, eu, ev, li, lj, lp, r, g)
    return d, eu, ev, li, lj, lp, centres, nrm, np.sort(tp).astype(np.int64)


def _candidate_cells(cols32, d, eu, ev, r: float, g: float):
    """Bin the points (float32 columns ``cols32``) into the candidate cells of direction ``d``
    (frame ``d, eu, ev``). Returns the raster (:class:`_Grid`); per flat cell the highest height
    ``cm`` (float32, -inf where empty), the top point ``top`` (the point count where empty) and
    the top point's position ``tdx, tdy`` from the cell's lower-left corner (float32, in
    ``[0, 2 g)``); and ``tp``, the top points of the occupied cells."""
    n_pts = cols32[0].shape[0]
    m = CELL_LINES
    G = m * g
    h = _project32(cols32, d)
    u = _project32(cols32, eu)
    v = _project32(cols32, ev)
    # candidate cell of each point: lines i = m*I + a (a in 0..m-1) at u = i g; cell I spans
    # u in [(m I - 0.5) g, (m I + m - 0.5) g)
    inv = np.float32(1.0 / G)
    sh = np.float32(0.5 / m)
    ci = np.floor(u * inv + sh).astype(np.int64)
    cj = np.floor(v * inv + sh).astype(np.int64)
    i0, i1 = int(ci.min()), int(ci.max())
    j0, j1 = int(cj.min()), int(cj.max())
    pad = int(math.ceil(r / G)) + 1
    nx = (i1 - i0 + 1) + 4 * pad
    ny = (j1 - j0 + 1) + 4 * pad
    swap = nx > ny           # put the longer side along the contiguous (column) axis
    if swap:
        eu, ev, u, v, ci, cj = ev, eu, v, u, cj, ci
        i0, i1, j0, j1, nx, ny = j0, j1, i0, i1, ny, nx
    if nx * ny > MAX_CELLS_PER_DIRECTION:
        gmin = g * math.sqrt(nx * ny / MAX_CELLS_PER_DIRECTION)
        raise ParameterError(
            f"grid_spacing_mm = {g:g} is too fine for this cloud: direction {d.tolist()} would need "
            f"{nx * ny} candidate cells (at most {MAX_CELLS_PER_DIRECTION}); use at least {gmin:.3g} mm",
            parameter="grid_spacing_mm", value=g, minimum=gmin)
    margin = pad + 1                     # guard elements before/after the flat raster
    ncell = nx * ny + 2 * margin
    # flat cell index: row (ci - i0 + 2 pad), column (cj - j0 + 2 pad)
    ci -= i0 - 2 * pad
    cj -= j0 - 2 * pad
    flat = ci
    flat *= ny
    flat += cj
    flat += margin
    cell = flat.astype(np.int32) if ncell < np.iinfo(np.int32).max else flat
    del ci, cj, flat
    cm, top = _top_per_cell(cell, h, ncell)
    del cell
    occ = np.flatnonzero(top < n_pts)
    tp = top[occ]
    row = (occ - margin) // ny - 2 * pad + i0
    col = (occ - margin) % ny - 2 * pad + j0
    tdx = np.zeros(ncell, dtype=np.float32)
    tdy = np.zeros(ncell, dtype=np.float32)
    # position of the top point inside its cell (from the cell's lower-left corner), in [0, G)
    tdx[occ] = (u[tp].astype(np.float64) - (m * row - 0.5) * g).astype(np.float32)
    tdy[occ] = (v[tp].astype(np.float64) - (m * col - 0.5) * g).astype(np.float32)
    return _Grid(swap, i0, j0, nx, ny, pad, margin), cm, top, tdx, tdy, tp


def _drop_heights(grid: _Grid, cm, tdx, tdy, r: float, g: float):
    """The ball's stop on every line of each of the ``CELL_LINES^2`` sub-lattices: ``best[q]``
    (float32 per line, -inf where nothing is within ``r``), the max over the top points within
    ``r`` of ``h + sqrt(r^2 - rho^2)``; ``arg[q]``, the offset that gave it; ``shifts``, the flat
    index shift of each offset (:func:`_offsets`). One loop over the offsets, each step a few
    whole-array float32 operations over all lines."""
    m = CELL_LINES
    base, length, ny = grid.base, grid.length, grid.ny
    offsets = _offsets(r, g, grid.pad)
    nsub = m * m
    best = [np.full(length, -np.inf, dtype=np.float32) for _ in range(nsub)]
    arg = [np.zeros(length, dtype=np.int32) for _ in range(nsub)]
    b1 = np.empty(length, dtype=np.float32)
    b2 = np.empty(length, dtype=np.float32)
    mask = np.empty(length, dtype=bool)
    r2 = np.float32(r * r)
    shifts = np.empty(len(offsets), dtype=np.int64)
    with np.errstate(invalid="ignore"):
        for k, (A, B, subs) in enumerate(offsets):
            s = base + A * ny + B
            shifts[k] = A * ny + B
            cms = cm[s:s + length]
            txs = tdx[s:s + length]
            tys = tdy[s:s + length]
            for q, (cx, cy, inside) in enumerate(subs):
                if not inside:
                    continue
                np.add(txs, np.float32(cx), out=b1)
                np.multiply(b1, b1, out=b1)
                np.add(tys, np.float32(cy), out=b2)
                np.multiply(b2, b2, out=b2)
                np.add(b1, b2, out=b1)
                np.subtract(r2, b1, out=b1)
                np.sqrt(b1, out=b1)           # NaN outside the cylinder: never > best
                np.add(b1, cms, out=b1)       # -inf for empty cells
                np.greater(b1, best[q], out=mask)
                np.copyto(best[q], b1, where=mask)
                np.copyto(arg[q], k, where=mask)
    return best, arg, shifts


def _line_contacts(grid: _Grid, best, arg, shifts, top):
    """The lines that touched a point: raster line indices ``li, lj`` (along the raster's rows
    and columns) and the touched point ``lp`` (int64), sub-lattice by sub-lattice."""
    m = CELL_LINES
    base, pad, ny = grid.base, grid.pad, grid.ny
    li, lj, lp = [], [], []
    for q in range(m * m):
        a, b = divmod(q, m)
        k = np.flatnonzero(best[q] > -np.inf)
        pos = k + base - grid.margin
        rr, cc = np.divmod(pos, ny)
        ok = (cc >= pad) & (cc < ny - pad)   # columns whose offsets never wrap into another row
        k, rr, cc = k[ok], rr[ok], cc[ok]
        src = k + base + shifts[arg[q][k]]
        li.append(m * (rr - 2 * pad + grid.i0) + a)
        lj.append(m * (cc - 2 * pad + grid.j0) + b)
        lp.append(top[src].astype(np.int64))
    return np.concatenate(li), np.concatenate(lj), np.concatenate(lp)


def _contact_normals(p64, origin, d, eu, ev, li, lj, lp, r: float, g: float):
    """Ball centres ``C_l`` (input frame) and unit normals ``(C_l - C_c) / r`` of the contacts of
    lines ``(li, lj)`` with points ``lp``, in float64 from the original coordinates ``p64``."""
    # float64 geometry of each contact: n = ((X - p_u) e_u + (Y - p_v) e_v + s d) / r
    q = p64[lp] - origin
    du = li * g - q @ eu
    dv = lj * g - q @ ev
    s = np.sqrt(np.maximum(r * r - du * du - dv * dv, 0.0))
    nrm = (du[:, None] * eu + dv[:, None] * ev + s[:, None] * d) / r
    centres = p64[lp] + r * nrm
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    return centres, nrm


def _prepare(points):
    p = _as_points(points)
    origin = 0.5 * (p.min(axis=0) + p.max(axis=0))
    cols32 = tuple(np.ascontiguousarray(p[:, k] - origin[k], dtype=np.float32) for k in range(3))
    return p, origin, cols32


def throw_lines(points, direction, *, sphere_diameter_mm: float = 7.0,
                grid_spacing_mm: float | None = None) -> LineContacts:
    """Sphere throwing along one direction, reported per grid line (for inspection and tests).

    Same method and parameters as :func:`sphere_throwing`; the grid origin is the centre of the
    cloud's bounding box (``LineContacts.origin``).
    """
    dval = _check_diameter(sphere_diameter_mm)
    p, origin, cols32 = _prepare(points)
    g = default_grid_spacing_mm(p, dval) if grid_spacing_mm is None else _check_spacing(grid_spacing_mm, dval)
    dirs = _check_directions([direction])
    d, eu, ev, li, lj, lp, centres, nrm, cand = _throw_direction(cols32, p, origin, dirs[0], dval / 2.0, g)
    return LineContacts(direction=d, e_u=eu, e_v=ev, origin=origin, grid_spacing_mm=g,
                        sphere_diameter_mm=dval, line_ij=np.column_stack((li, lj)),
                        contact_index=lp, centres=centres, normals=nrm, candidate_index=cand)


def _workers(k: int) -> int:
    try:
        ncpu = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        ncpu = os.cpu_count() or 1
    # never more than the plan's own thread budget (numba's threads: a service job's SCANMILL_WORKER_THREADS)
    return max(1, min(k, ncpu, 4, numba.get_num_threads()))


def sphere_throwing(points, *, sphere_diameter_mm: float = 7.0, grid_spacing_mm: float | None = None,
                    directions: Sequence[Sequence[float]] = DEFAULT_DIRECTIONS,
                    progress: Progress | None = None, refine: bool = False) -> NormalsResult:
    """Outward normals of the touched points by sphere throwing (Makki 2010 §2.1, eq. 2.1).

    ``points`` (N,3) mm. ``sphere_diameter_mm`` D > 0. ``grid_spacing_mm`` g > 0 (at least
    D / 256), or None for :func:`default_grid_spacing_mm`. ``directions``: non-zero 3-vectors, the
    sphere coming from +direction (default: the paper's five, +Z +X -X +Y -Y). ``progress``, if
    given, is called as ``progress(fraction_done, message)`` once per finished direction.
    The same input always gives the same arrays. See the module docstring for the method and for
    what is exact. ``refine`` (default False, the paper's method): replace each normal's direction by
    a least-squares plane fit over the cloud's points within the candidate cell (``CELL_LINES * g``),
    turned to the thrown normal's side, where the fit is well posed
    (:func:`planning.normals.refine.refine_normals`; ``NormalsResult.n_refined`` counts them): same
    sampled points and orientation, several times smaller error on sparse scans (range scans).
    """
    dval = _check_diameter(sphere_diameter_mm)
    if grid_spacing_mm is not None:
        g = _check_spacing(grid_spacing_mm, dval)
    dirs = _check_directions(directions)
    p, origin, cols32 = _prepare(points)
    if grid_spacing_mm is None:
        g = default_grid_spacing_mm(p, dval)
    r = dval / 2.0
    n_pts = p.shape[0]
    k = dirs.shape[0]

    def one(i):
        _, _, _, _, _, lp, _, nrm, _ = _throw_direction(cols32, p, origin, dirs[i], r, g)
        return lp, nrm

    results = []
    workers = _workers(k)
    with ThreadPoolExecutor(max_workers=workers) if workers > 1 else contextlib.nullcontext() as pool:
        # in direction order either way: deterministic progress messages
        ordered = map(one, range(k)) if pool is None else pool.map(one, range(k))
        for i, res in enumerate(ordered):
            results.append(res)
            if progress is not None:
                progress((i + 1) / k, _progress_message(i, k, dirs[i], res[0].size))

    lp = np.concatenate([res[0] for res in results])
    nrm = np.concatenate([res[1] for res in results])
    counts = np.bincount(lp, minlength=n_pts)
    sums = np.stack([np.bincount(lp, weights=nrm[:, c], minlength=n_pts) for c in range(3)], axis=1)
    idx = np.flatnonzero(counts)
    sums = sums[idx]
    length = np.linalg.norm(sums, axis=1)
    keep = length > 1e-9 * counts[idx]     # opposite normals that cancel exactly: no normal
    idx, sums, length = idx[keep], sums[keep], length[keep]
    normals = sums / length[:, None]
    n_refined = 0
    if refine:
        from planning.normals.refine import refine_normals

        normals, fitted = refine_normals(p, idx, normals, CELL_LINES * g)
        n_refined = int(np.count_nonzero(fitted))
    return NormalsResult(sample_index=idx.astype(np.int64), normals=normals,
                         touches=counts[idx].astype(np.int32), grid_spacing_mm=float(g),
                         sphere_diameter_mm=dval, n_refined=n_refined)


def _progress_message(i: int, k: int, d: np.ndarray, n_lines: int) -> str:
    dtxt = ", ".join(f"{c:g}" for c in np.round(d, 4))
    return f"sphere throwing: direction {i + 1}/{k} ({dtxt}) done, {n_lines} lines touched"
