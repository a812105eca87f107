"""Stage 1, reference samples: a box with rounded top and vertical edges, the part a new user brings (mm).

:func:`filleted_box`: a solid box (60 x 40 x 20 mm by default) whose four vertical edges and four top
edges are rounded with fillets of one radius (10 mm), the four top corners being sphere octants:
the standard rounded box. Its surface is every point at ``fillet_radius_mm`` from the inner box
shrunk by that radius on the sides and the top (:func:`filleted_box_inner_box`), cut at z = 0,
so the distance to the inner box and its gradient give the exact surface and outward normals.

Sampling follows :mod:`planning.inputs.samples.prismatic`: the planar faces and the quarter
cylinders (developable: arc length x length) on jittered grids, one uniform random point per cell
of 1/sqrt(density) mm; each sphere octant in latitude bands one cell high, split into cells of
about the same area, with one point drawn uniformly per unit area in each cell; exact normals;
optional Gaussian noise along the normal; ``meta["labels"]`` names the patch of each point.
"""

from __future__ import annotations

import math

import numpy as np

from planning.errors import ParameterError
from planning.inputs.samples.common import (
    Sample,
    _check_float,
    _check_int,
    _check_seed,
    _check_size,
)
from planning.inputs.samples.prismatic import _jitter_grid

__all__ = ["filleted_box", "filleted_box_inner_box"]

_LABELS = ("top", "side", "vertical_fillet", "top_fillet", "corner", "bottom")


def filleted_box_inner_box(size_mm: tuple = (60.0, 40.0, 20.0), fillet_radius_mm: float = 10.0):
    """The box (lo, hi corners, mm) whose points at ``fillet_radius_mm`` with z >= 0 form the surface
    of :func:`filleted_box`: the part shrunk by the radius on the four sides and the top (not the
    bottom). Default (-20, -10, 0), (20, 10, 10)."""
    X, Y, Z = (float(v) for v in size_mm)
    r = float(fillet_radius_mm)
    return (-X / 2 + r, -Y / 2 + r, 0.0), (X / 2 - r, Y / 2 - r, Z - r)


def _quarter_cylinder(rng, spacing, centre, axis, length, e1, e2, r):
    """Points c + s axis + r (cos a e1 + sin a e2), s in [0, length], a in [0, pi/2]; normals radial."""
    arc, s = _jitter_grid(rng, 0.5 * math.pi * r, length, spacing)
    a = arc / r
    n = np.cos(a)[:, None] * np.asarray(e1, float) + np.sin(a)[:, None] * np.asarray(e2, float)
    p = np.asarray(centre, float) + s[:, None] * np.asarray(axis, float) + r * n
    return p, n


def _sphere_octant(rng, spacing, centre, sx, sy, r):
    """The octant of the sphere (centre, r) in the direction (sx, sy, +1): latitude bands about +Z
    one cell high, each split into cells of about spacing^2 of area; in a cell the azimuth and
    h = cos(polar angle) are uniform, which is uniform per unit area (Archimedes)."""
    nb = max(1, round(0.5 * math.pi * r / spacing))
    edges = np.cos(np.linspace(0.0, 0.5 * math.pi, nb + 1))       # h from 1 (pole) down to 0
    phis, hs = [], []
    for k in range(nb):
        h_hi, h_lo = edges[k], edges[k + 1]
        m = max(1, round(0.5 * math.pi * r * r * (h_hi - h_lo) / spacing**2))
        j = np.arange(m)
        phis.append((j + rng.random(m)) * (0.5 * math.pi / m))
        hs.append(h_lo + rng.random(m) * (h_hi - h_lo))
    phi, h = np.concatenate(phis), np.concatenate(hs)
    rho = np.sqrt(np.maximum(0.0, 1.0 - h * h))
    n = np.column_stack((sx * rho * np.cos(phi), sy * rho * np.sin(phi), h))
    return np.asarray(centre, float) + r * n, n


def _rect(rng, spacing, origin, du, dv, lu, lv, normal):
    u, v = _jitter_grid(rng, lu, lv, spacing)
    p = np.asarray(origin, float) + u[:, None] * np.asarray(du, float) + v[:, None] * np.asarray(dv, float)
    return p, np.array(np.broadcast_to(np.asarray(normal, float), p.shape))


def _bottom(rng, spacing, X, Y, r):
    """The footprint at z = 0 (normal -Z): the X x Y rectangle with its corners rounded by r."""
    u, v = _jitter_grid(rng, X, Y, spacing)
    x, y = u - X / 2, v - Y / 2
    dx = np.maximum(np.abs(x) - (X / 2 - r), 0.0)
    dy = np.maximum(np.abs(y) - (Y / 2 - r), 0.0)
    keep = dx * dx + dy * dy < r * r
    p = np.column_stack((x[keep], y[keep], np.zeros(int(keep.sum()))))
    return p, np.array(np.broadcast_to(np.array([0.0, 0.0, -1.0]), p.shape))


def filleted_box(size_mm: tuple = (60.0, 40.0, 20.0), fillet_radius_mm: float = 10.0,
                 density_per_mm2: float = 1.0, n_points: int | None = None, noise_mm: float = 0.0,
                 seed: int = 0, include_bottom: bool = False) -> Sample:
    """A solid box with its four vertical edges and its four top edges rounded: the standard rounded box.

    Frame (mm): the box x in [-X/2, X/2], y in [-Y/2, Y/2], z in [0, Z] with ``size_mm = (X, Y, Z)``
    (default 60 x 40 x 20), standing on the table (z = 0), centred in x and y. Every vertical edge
    is a quarter cylinder of radius r = ``fillet_radius_mm`` (10) from z = 0 to Z - r, every top
    edge a quarter cylinder of radius r along X or Y, every top corner a sphere octant of radius r;
    the flat top is (X - 2r) x (Y - 2r) at z = Z, the flat sides are Z - r high. Equivalently the
    surface is the set of points with z >= 0 at distance r from the inner box
    :func:`filleted_box_inner_box` (x in [-X/2 + r, X/2 - r], y likewise, z in [0, Z - r]); the
    outward normal is the gradient of that distance.

    Sampled patches (``meta["labels"]`` indexes ``meta["label_names"]``): ``top`` (+Z), ``side``
    (the four flat walls, +-X, +-Y), ``vertical_fillet``, ``top_fillet``, ``corner``, and ``bottom``
    (-Z, the rounded footprint, only with ``include_bottom``: a part on the table is not scanned
    there). Points about 1/sqrt(density) mm apart: ``density_per_mm2`` (1 by default, about 5,100
    points) or about ``n_points`` in all when given; exact normals; ``noise_mm`` > 0 adds Gaussian
    noise along the normal (none by default). Deterministic for a given ``seed``.

    ``meta``: ``size_mm``, ``fillet_radius_mm``, ``top_z_mm``, ``inner_box_mm`` (lo, hi corners),
    ``density_per_mm2``, ``area_mm2``, ``labels``, ``label_names``, ``noise_mm``, ``seed``.
    """
    X, Y, Z = _check_size("size_mm", size_mm, 3)
    r = _check_float("fillet_radius_mm", fillet_radius_mm, 0.0, min(X / 2, Y / 2, Z))
    lx, ly, lz = X - 2 * r, Y - 2 * r, Z - r                 # flat top lengths, flat side height
    q = 0.5 * math.pi * r                                     # quarter arc length
    area = (lx * ly + 2 * (ly + lx) * lz + 4 * q * lz + 2 * q * (lx + ly) + 2 * math.pi * r * r
            + (X * Y - (4 - math.pi) * r * r if include_bottom else 0.0))
    if n_points is not None:
        density = _check_int("n_points", n_points, 10, 20_000_000) / area
    else:
        density = _check_float("density_per_mm2", density_per_mm2, 0.0, 1000.0, unit="points/mm^2")
    sigma = _check_float("noise_mm", noise_mm, 0.0, 5.0, lo_open=False)
    seed = _check_seed(seed)
    if area * density > 20_000_000:
        raise ParameterError(f"filleted_box: {area * density:.3g} points requested, at most 2e7",
                             parameter="density_per_mm2", value=density, allowed="<= 2e7 points")
    rng = np.random.default_rng(seed)
    spacing = 1.0 / math.sqrt(density)
    (x0, y0, _), (x1, y1, z1) = filleted_box_inner_box((X, Y, Z), r)
    ex, ey, ez = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)

    patches = []                                   # (label, generator) in a fixed order
    if lx > 0 and ly > 0:
        patches.append(("top", lambda: _rect(rng, spacing, (x0, y0, Z), ex, ey, lx, ly, ez)))
    if lz > 0:
        if ly > 0:
            for sx in (-1.0, 1.0):
                patches.append(("side", lambda sx=sx: _rect(rng, spacing, (sx * X / 2, y0, 0.0), ey, ez, ly, lz,
                                                             (sx, 0.0, 0.0))))
        if lx > 0:
            for sy in (-1.0, 1.0):
                patches.append(("side", lambda sy=sy: _rect(rng, spacing, (x0, sy * Y / 2, 0.0), ex, ez, lx, lz,
                                                             (0.0, sy, 0.0))))
        for sx in (-1.0, 1.0):
            for sy in (-1.0, 1.0):
                patches.append(("vertical_fillet", lambda sx=sx, sy=sy: _quarter_cylinder(
                    rng, spacing, (sx * x1, sy * y1, 0.0), ez, lz, (sx, 0.0, 0.0), (0.0, sy, 0.0), r)))
    if lx > 0:
        for sy in (-1.0, 1.0):
            patches.append(("top_fillet", lambda sy=sy: _quarter_cylinder(
                rng, spacing, (x0, sy * y1, z1), ex, lx, (0.0, sy, 0.0), ez, r)))
    if ly > 0:
        for sx in (-1.0, 1.0):
            patches.append(("top_fillet", lambda sx=sx: _quarter_cylinder(
                rng, spacing, (sx * x1, y0, z1), ey, ly, (sx, 0.0, 0.0), ez, r)))
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            patches.append(("corner", lambda sx=sx, sy=sy: _sphere_octant(
                rng, spacing, (sx * x1, sy * y1, z1), sx, sy, r)))
    if include_bottom:
        patches.append(("bottom", lambda: _bottom(rng, spacing, X, Y, r)))

    pts, nrm, lab = [], [], []
    for label, gen in patches:
        p, n = gen()
        pts.append(p)
        nrm.append(n)
        lab.append(np.full(p.shape[0], _LABELS.index(label), dtype=np.int8))
    points, normals, labels = np.vstack(pts), np.vstack(nrm), np.concatenate(lab)
    if sigma > 0:
        points = points + rng.normal(0.0, sigma, points.shape[0])[:, None] * normals
    return Sample(
        name="filleted_box", points=points, normals=normals,
        description=(f"box {X:g} x {Y:g} x {Z:g} mm with its top and vertical edges rounded, fillet radius "
                     f"{r:g} mm, exact normals"),
        meta={"size_mm": (X, Y, Z), "fillet_radius_mm": r, "top_z_mm": Z,
              "inner_box_mm": filleted_box_inner_box((X, Y, Z), r), "density_per_mm2": density,
              "area_mm2": float(area), "noise_mm": sigma, "seed": seed, "labels": labels,
              "label_names": _LABELS},
    )
