"""Stage 1, reference samples: simulated range scans of the reference shapes (scan lines, holes, registration).

The other samples draw points uniformly from the surface. A real scanner writes range images: per
view a grid of rays, finely spaced along the scan lines and more coarsely across them; a ray
records the first surface it meets, grazing rays return nothing, the range is noisy along the ray,
a few returns are wild, and the views are registered to each other with small errors.
:func:`range_scan` simulates that on the exact surfaces of :func:`~planning.inputs.samples.femur_like`
(its implicit function, ray-marched), :func:`~planning.inputs.samples.half_sphere`,
:func:`~planning.inputs.samples.slot` (a union of boxes) and
:func:`~planning.inputs.samples.filleted_box` (a distance function), all intersected exactly
(to 1e-9 mm), vectorised over the rays. :func:`shape_distance` gives the signed distance to and
the outward normal of each shape, so a test can check how far a point lies from it.
"""

from __future__ import annotations

import math

import numpy as np

from planning.errors import ParameterError
from planning.inputs.samples.common import Sample, _check_float, _check_int, _check_seed
from planning.inputs.samples.femur import (
    _FEMUR_AREA_MM2,
    _FEMUR_OFFSET,
    _FEMUR_PARTS,
    FEMUR_DIMENSIONS_MM,
    _femur_union,
    femur_implicit,
)
from planning.inputs.samples.filleted import _LABELS as _BOX_LABELS
from planning.inputs.samples.filleted import filleted_box_inner_box
from planning.inputs.samples.scanner import _basis, _scanner_directions

__all__ = ["RANGE_SHAPES", "range_femur", "range_filleted_box", "range_half_sphere", "range_scan", "range_slot",
           "shape_distance"]

#: The shapes :func:`range_scan` scans, and the name of the sample it returns for each.
RANGE_SHAPES = {"femur_like": "range_femur", "half_sphere": "range_half_sphere", "slot": "range_slot",
                "filleted_box": "range_filleted_box"}
_DEFAULT_VIEWS = {"femur_like": 8, "half_sphere": 5, "slot": 5, "filleted_box": 5}
_TURNTABLE_ELEVATION_DEG = 40.0     # the views around a part on the table look down at this angle
_MAX_RAYS = 40_000_000              # rays cast in all, at most (cast in chunks; the hits are kept)
_CHUNK = 1 << 17                    # rays cast at once
_EST_RAYS = 60_000                  # rays of the coarse grid that estimates the count (scale None)
_HIT_TOL_MM = 1e-9                  # |value| at an accepted intersection (mm)

# The reference dimensions at scale 1 (the defaults of the uniform generators).
_SPHERE_R = 50.0
_SLOT_SIZE, _SLOT_W, _SLOT_H = (80.0, 60.0, 30.0), 12.0, 15.0
_BOX_SIZE, _BOX_R = (60.0, 40.0, 20.0), 10.0
_SLOT_LABELS = ("top", "slot_floor", "slot_wall", "pocket_end_wall", "side", "bottom")


# ---------------------------------------------------------------------------------------------
# the shapes, at a scale: first intersection of rays, distance and normal, known answers


def _slab(o, d, lo, hi):
    """Entry and exit parameters of the rays o + t d (d one unit vector) through the box [lo, hi],
    and the axis each enters by (-1 where a ray starts inside or misses); t_in > t_out: a miss."""
    m = o.shape[0]
    t_in, t_out = np.full(m, -np.inf), np.full(m, np.inf)
    axis = np.full(m, -1, np.int64)
    for k in range(3):
        if d[k] == 0.0:
            outside = (o[:, k] < lo[k]) | (o[:, k] > hi[k])
            t_in[outside], t_out[outside] = np.inf, -np.inf
            continue
        a, b = (lo[k] - o[:, k]) / d[k], (hi[k] - o[:, k]) / d[k]
        near, far = np.minimum(a, b), np.maximum(a, b)
        later = near > t_in
        axis[later] = k
        t_in = np.where(later, near, t_in)
        t_out = np.minimum(t_out, far)
    return t_in, t_out, axis


def _box_sdf(p, lo, hi):
    """Exact signed distance to the box [lo, hi] and its gradient (unit)."""
    c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
    rel = p - c
    q = np.abs(rel) - h
    qp = np.maximum(q, 0.0)
    out = np.sqrt(np.einsum("ij,ij->i", qp, qp))
    inside = np.minimum(q.max(axis=1), 0.0)
    sgn = np.where(rel < 0.0, -1.0, 1.0)
    g = np.where(out[:, None] > 0.0, sgn * qp / np.maximum(out, 1e-300)[:, None], 0.0)
    k = np.argmax(q, axis=1)
    gin = np.zeros_like(p)
    gin[np.arange(p.shape[0]), k] = sgn[np.arange(p.shape[0]), k]
    g = np.where((out > 0.0)[:, None], g, gin)
    return out + inside, g


class _Shape:
    """One reference surface at ``scale``: ``lo``/``hi`` its bounding box (mm), ``table`` whether it
    stands on the table (z = 0 is not scanned: a ray meeting z < 0 first is lost on the table)."""

    table = True
    label_names: tuple | None = None

    def __init__(self, scale):
        self.s = float(scale)

    def labels(self, p, n):          # pragma: no cover - overridden where there are labels
        return None


class _HalfSphere(_Shape):
    name = "half_sphere"

    def __init__(self, scale):
        super().__init__(scale)
        self.r = _SPHERE_R * self.s
        self.lo, self.hi = np.array([-self.r, -self.r, 0.0]), np.array([self.r, self.r, self.r])

    def cast(self, o, d):
        b = o @ d
        c = np.einsum("ij,ij->i", o, o) - self.r * self.r
        disc = b * b - c
        ok = disc >= 0.0
        t = -b - np.sqrt(np.maximum(disc, 0.0))
        p = o + t[:, None] * d
        ok &= p[:, 2] >= 0.0
        return t, ok, p / self.r

    def distance(self, p):
        rho = np.sqrt(np.einsum("ij,ij->i", p, p))
        return rho - self.r, p / np.maximum(rho, 1e-300)[:, None]

    def known(self):
        return {"radius_mm": self.r, "centre_mm": (0.0, 0.0, 0.0),
                "surface_area_mm2": 2.0 * math.pi * self.r ** 2}


class _Slot(_Shape):
    """The through slot of :func:`~planning.inputs.samples.slot` (default dimensions, scaled): the
    union of the two blocks beside the slot and the one under its floor."""

    name = "slot"
    label_names = _SLOT_LABELS

    def __init__(self, scale):
        super().__init__(scale)
        X, Y, Z = (v * self.s for v in _SLOT_SIZE)
        w, h = _SLOT_W * self.s, _SLOT_H * self.s
        self.X, self.Y, self.Z, self.w, self.h, self.zf = X, Y, Z, w, h, Z - h
        self.boxes = [(np.array([-X / 2, -Y / 2, 0.0]), np.array([-w / 2, Y / 2, Z])),
                      (np.array([w / 2, -Y / 2, 0.0]), np.array([X / 2, Y / 2, Z])),
                      (np.array([-w / 2, -Y / 2, 0.0]), np.array([w / 2, Y / 2, Z - h]))]
        self.lo, self.hi = np.array([-X / 2, -Y / 2, 0.0]), np.array([X / 2, Y / 2, Z])

    def cast(self, o, d):
        best = np.full(o.shape[0], np.inf)
        axis = np.full(o.shape[0], -1, np.int64)
        for lo, hi in self.boxes:
            t_in, t_out, ax = _slab(o, d, lo, hi)
            hit = (t_in <= t_out) & (t_in > 0.0) & (t_in < best)
            best[hit], axis[hit] = t_in[hit], ax[hit]
        ok = np.isfinite(best)
        n = np.zeros(o.shape)
        rows = np.flatnonzero(ok)
        n[rows, axis[rows]] = -np.sign(d[axis[rows]])        # the face entered faces the ray
        t = np.where(ok, best, 0.0)
        return t, ok, n

    def distance(self, p):
        best, g = _box_sdf(p, *self.boxes[0])
        for lo, hi in self.boxes[1:]:
            f, gb = _box_sdf(p, lo, hi)
            closer = f < best
            best, g = np.where(closer, f, best), np.where(closer[:, None], gb, g)
        return best, g

    def labels(self, p, n):
        lab = np.full(p.shape[0], _SLOT_LABELS.index("side"), np.int8)
        up = n[:, 2] > 0.5
        tol = 1e-6 * max(self.s, 1.0)
        lab[up & (np.abs(p[:, 2] - self.Z) < tol)] = _SLOT_LABELS.index("top")
        lab[up & (np.abs(p[:, 2] - self.zf) < tol)] = _SLOT_LABELS.index("slot_floor")
        wall = (np.abs(n[:, 0]) > 0.5) & (np.abs(np.abs(p[:, 0]) - 0.5 * self.w) < tol)
        lab[wall] = _SLOT_LABELS.index("slot_wall")
        lab[n[:, 2] < -0.5] = _SLOT_LABELS.index("bottom")
        return lab

    def known(self):
        return {"kind": "through_slot", "size_mm": (self.X, self.Y, self.Z), "top_z_mm": self.Z,
                "slot_width_mm": self.w, "slot_depth_mm": self.h, "floor_z_mm": self.zf,
                "slot_length_mm": self.Y, "slot_axis": (0.0, 1.0, 0.0), "slot_centre_x_mm": 0.0}


class _Marched(_Shape):
    """A surface given by a value close to a signed distance: sphere tracing from the ray's entry
    into the bounding box (steps of ``safety`` times the value) to within ``_MARCH_TOL`` mm, then
    Newton along the ray to |value| < 1e-9 mm."""

    _SAFETY = 0.8
    _MARCH_TOL = 1e-3
    _MAX_STEPS = 400

    def cast(self, o, d):
        m = o.shape[0]
        t = np.zeros(m)
        ok = np.zeros(m, bool)
        n = np.zeros((m, 3))
        grow = 1.0 + 1e-3 * self.s
        t_in, t_out, _ = _slab(o, d, self.lo - grow, self.hi + grow)
        act = np.flatnonzero(t_in <= t_out)
        if act.size == 0:
            return t, ok, n
        t[act] = np.maximum(t_in[act], 0.0)
        t_end = t_out
        near = np.zeros(m, bool)
        for _ in range(self._MAX_STEPS):
            f = self._value(o[act] + t[act, None] * d)
            close = f < self._MARCH_TOL
            near[act[close]] = True
            step = self._SAFETY * np.maximum(f, 0.5 * self._MARCH_TOL)
            t[act] += np.where(close, 0.0, step)
            keep = ~close & (t[act] <= t_end[act])
            act = act[keep]
            if act.size == 0:
                break
        idx = np.flatnonzero(near)
        if idx.size == 0:
            return t, ok, n
        t0 = t[idx].copy()
        ti = t0.copy()
        for _ in range(12):
            f, g = self._eval(o[idx] + ti[:, None] * d)
            gd = g @ d
            step = np.where(gd < -1e-6, f / np.minimum(gd, -1e-6), 0.0)
            ti -= np.clip(step, -self._MARCH_TOL * 50, self._MARCH_TOL * 50)
            if np.all(np.abs(f) < _HIT_TOL_MM):
                break
        f, g = self._eval(o[idx] + ti[:, None] * d)
        gn = np.sqrt(np.einsum("ij,ij->i", g, g))
        nn = g / np.maximum(gn, 1e-300)[:, None]
        good = (np.abs(f) < _HIT_TOL_MM * max(1.0, self.s)) & (nn @ d < 0.0) \
            & (np.abs(ti - t0) < 0.1 * max(self.s, 1e-3))
        t[idx], ok[idx], n[idx] = ti, good, nn
        return t, ok, n

    def distance(self, p):
        f, g = self._eval(p)
        gn = np.sqrt(np.einsum("ij,ij->i", g, g))
        return f / np.maximum(gn, 1e-300), g / np.maximum(gn, 1e-300)[:, None]


class _Femur(_Marched):
    """:func:`~planning.inputs.samples.femur_like`'s surface scaled about the part frame's origin
    (the bounding box stays centred in x and y, lowest point at z = 0). Scanned all round."""

    name = "femur_like"
    table = False

    def __init__(self, scale):
        super().__init__(scale)
        lo = np.min([p.lo for p, _ in _FEMUR_PARTS], axis=0) + _FEMUR_OFFSET
        hi = np.max([p.hi for p, _ in _FEMUR_PARTS], axis=0) + _FEMUR_OFFSET
        self.lo, self.hi = lo * self.s, hi * self.s

    def _value(self, p):
        f, _, _ = _femur_union(p / self.s - _FEMUR_OFFSET, grad=False, cull=False)
        return f * self.s

    def _eval(self, p):
        f, g = femur_implicit(p / self.s)
        return f * self.s, g

    def known(self):
        return {"dimensions_mm": tuple(v * self.s for v in FEMUR_DIMENSIONS_MM), "long_axis": (1.0, 0.0, 0.0),
                "surface_area_mm2": _FEMUR_AREA_MM2 * self.s ** 2,
                "primitives": tuple(p.name for p, _ in _FEMUR_PARTS)}


class _FilletedBox(_Marched):
    """:func:`~planning.inputs.samples.filleted_box` (default dimensions, scaled): the points at the
    fillet radius from the inner box, z >= 0; exact distance, so the march can step the whole value."""

    name = "filleted_box"
    label_names = _BOX_LABELS
    _SAFETY = 1.0

    def __init__(self, scale):
        super().__init__(scale)
        size = tuple(v * self.s for v in _BOX_SIZE)
        self.size, self.r = size, _BOX_R * self.s
        lo, hi = filleted_box_inner_box(size, self.r)
        self.ilo, self.ihi = np.array(lo), np.array(hi)
        self.lo = np.array([-size[0] / 2, -size[1] / 2, 0.0])
        self.hi = np.array([size[0] / 2, size[1] / 2, size[2]])

    def _eval(self, p):
        f, g = _box_sdf(p, self.ilo, self.ihi)
        return f - self.r, g

    def _value(self, p):
        return self._eval(p)[0]

    def labels(self, p, n):
        out = (p < self.ilo - 1e-9 * max(1.0, self.s)) | (p > self.ihi + 1e-9 * max(1.0, self.s))
        ox, oy, oz = out[:, 0], out[:, 1], out[:, 2]
        lab = np.full(p.shape[0], _BOX_LABELS.index("side"), np.int8)
        lab[oz & ~ox & ~oy] = _BOX_LABELS.index("top")
        lab[~oz & ox & oy] = _BOX_LABELS.index("vertical_fillet")
        lab[oz & (ox ^ oy)] = _BOX_LABELS.index("top_fillet")
        lab[oz & ox & oy] = _BOX_LABELS.index("corner")
        lab[n[:, 2] < -0.5] = _BOX_LABELS.index("bottom")
        return lab

    def known(self):
        return {"size_mm": self.size, "fillet_radius_mm": self.r, "top_z_mm": self.size[2],
                "inner_box_mm": (tuple(self.ilo), tuple(self.ihi))}


_SHAPE_CLASSES = {"femur_like": _Femur, "half_sphere": _HalfSphere, "slot": _Slot, "filleted_box": _FilletedBox}


def _check_shape(shape):
    if not isinstance(shape, str) or shape not in _SHAPE_CLASSES:
        raise ParameterError(f"shape = {shape!r}: must be one of {', '.join(_SHAPE_CLASSES)}",
                             parameter="shape", value=repr(shape), allowed=list(_SHAPE_CLASSES))
    return shape


def shape_distance(shape: str, points: np.ndarray, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (mm, negative inside) from ``points`` (N, 3) to the surface of ``shape`` at
    ``scale`` as :func:`range_scan` scans it (``sample.meta["shape"]``, ``sample.meta["scale"]``),
    and the unit outward normal of the nearest surface (the gradient of the distance).

    Exact for the half sphere (its whole sphere) and the filleted box (its inner box dilated by the
    radius); for the slot block exact outside the part and a lower bound on the depth inside (the
    least of the distances to its three boxes); for the femur the first-order distance of
    :func:`~planning.inputs.samples.femur_implicit` (within 2 um of the true one up to 0.1 mm
    from the surface). The table (z = 0) is not part of any surface."""
    shp = _SHAPE_CLASSES[_check_shape(shape)](_check_float("scale", scale, 0.0, 10.0, unit=""))
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return shp.distance(p)


# ---------------------------------------------------------------------------------------------
# the scan


def _turntable_directions(n_views):
    """Unit vectors from a part on the table towards each view: the first from above (+Z), the
    others around it at :data:`_TURNTABLE_ELEVATION_DEG` above the table, evenly in azimuth from
    45 deg (diagonal to a box's faces)."""
    dirs = [[0.0, 0.0, 1.0]]
    m = n_views - 1
    el = math.radians(_TURNTABLE_ELEVATION_DEG)
    for k in range(m):
        az = math.radians(45.0) + 2.0 * math.pi * k / m
        dirs.append([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    d = np.array(dirs)
    d[np.abs(d) < 1e-15] = 0.0
    return d


def _keep_probability(theta_deg, start, end):
    """Share of rays kept at incidence ``theta_deg``: 1 up to ``start``, 0 from ``end`` on, a
    half cosine between them."""
    if end <= start:
        return (theta_deg < start).astype(np.float64)
    u = np.clip((theta_deg - start) / (end - start), 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(math.pi * u))


def _grid(shape, v, ea, ec, along, across, phase):
    """The ray grid of one view: rows (scan lines) along ``ea``, ``across`` apart along ``ec``,
    samples ``along`` apart, covering the projection of the shape's bounding box; the origins lie
    beyond the box towards the scanner. Returns (n_rows, n_cols, origin of row 0 col 0 in the
    image plane as (a0, c0), depth)."""
    lo, hi = shape.lo, shape.hi
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    pa, pc, pv = corners @ ea, corners @ ec, corners @ v
    pad = 1e-3 * max(shape.s, 1.0)
    a0, c0 = pa.min() - pad + phase[0] * along, pc.min() - pad + phase[1] * across
    n_cols = math.floor((pa.max() + pad - a0) / along) + 1
    n_rows = math.floor((pc.max() + pad - c0) / across) + 1
    return n_rows, n_cols, a0, c0, pv.max() + 1.0 + pad


def _cast_view(shape, v, ea, ec, along, across, phase):
    """Cast one view's grid. Returns (row, col, hit point, unit normal) of the rays that hit, in
    row-major order (scan line by scan line), and the number of rays cast."""
    n_rows, n_cols, a0, c0, depth = _grid(shape, v, ea, ec, along, across, phase)
    total = n_rows * n_cols
    d = -v
    rows, cols, pts, nrm = [], [], [], []
    for s in range(0, total, _CHUNK):
        k = np.arange(s, min(total, s + _CHUNK))
        r, c = np.divmod(k, n_cols)
        o = (a0 + c * along)[:, None] * ea + (c0 + r * across)[:, None] * ec + depth * v
        t, ok, n = shape.cast(o, d)
        p = o + t[:, None] * d
        if shape.table:
            ok &= p[:, 2] >= 0.0
        ok &= n @ v > 0.0
        rows.append(r[ok])
        cols.append(c[ok])
        pts.append(p[ok])
        nrm.append(n[ok])
    return (np.concatenate(rows), np.concatenate(cols), np.vstack(pts), np.vstack(nrm), n_rows, total)


def _rays_per_view(shape, dirs, frames, along, across):
    total = 0
    for v, (ea, ec) in zip(dirs, frames):
        n_rows, n_cols, *_ = _grid(shape, v, ea, ec, along, across, (0.5, 0.5))
        total += n_rows * n_cols
    return total


def _rotation(axis, angle_rad):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1.0 - math.cos(angle_rad)) * (k @ k)


def _unit_vector(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def range_scan(shape: str = "femur_like", n_points: int | None = None, along_mm: float = 0.3,
               across_mm: float = 0.6, n_views: int | None = None, noise_mm: float = 0.02,
               dropout_deg: tuple = (60.0, 80.0), outlier_share: float = 0.001, outlier_mm: float = 5.0,
               registration_mm: float = 0.05, registration_deg: float = 0.02, scale: float | None = None,
               seed: int = 0) -> Sample:
    """A simulated multi-view range scan of a reference shape: scan lines, holes, noise along the
    rays, outliers and registration errors.

    ``shape``: ``"femur_like"`` (the bone of :func:`~planning.inputs.samples.femur_like`, scanned
    all round, views of :func:`~planning.inputs.samples.scanner._scanner_directions`: default 8,
    six around the long axis X and one from each end), ``"half_sphere"`` (R 50 mm, z >= 0),
    ``"slot"`` (the 80 x 60 x 30 mm block with the 12 mm wide, 15 mm deep through slot along Y)
    or ``"filleted_box"`` (60 x 40 x 20 mm, 10 mm fillets); the last three stand on the table
    (z = 0, never scanned) and are seen by a turntable: default 5 views, one from above and the
    others around it 40 deg above the table, from azimuth 45 deg. Every dimension is multiplied by
    the scale (below); frames as in the uniform samples.

    Per view (unit vector v from the part towards the scanner): an orthographic grid of rays along
    -v, in rows (scan lines) ``across_mm`` apart, each row sampled every ``along_mm`` (0.3 x 0.6
    mm by default) over the projection of the part's bounding box; the scan lines run along a
    direction of the image plane turned by an angle drawn per view, and the grid's phase is drawn
    per view too. Each ray records the first intersection with the exact surface (what the part
    hides from the view is not recorded). A ray meeting the surface at incidence theta (between
    the ray and the normal) is kept with probability 1 up to ``dropout_deg[0]`` (60), a half
    cosine down to 0 at ``dropout_deg[1]`` (80) and 0 beyond: holes where the surface turns away.
    The recorded point moves along the ray by Gaussian noise of std ``noise_mm`` (0.02);
    ``round(outlier_share * N)`` points (0.1 %) instead move by +-(0.5 to 1.5) x ``outlier_mm`` (5)
    along the ray (either sign). Then every view's points move by its registration error: a rotation
    of exactly ``registration_deg`` (0.02) about a random axis through the centre of the bounding
    box and a translation of exactly ``registration_mm`` (0.05) in a random direction.

    Size: at the default pitches a full-size part gives far more points than a typical scan of 30-
    50 thousand (about 500,000 for the 396 mm femur over 8 views, 170,000 for the half sphere,
    145,000 for the slot block, 58,000 for the filleted box over 5 views), so the pitches are kept
    and the part is scaled about the origin of its frame: ``scale`` None (the default) picks the
    scale at which about ``n_points`` (40,000 when None) points are recorded (the count grows as
    scale^2; casting a coarse grid at scale 1 measures the constant, so the count lands within a
    few per cent), at 40,000: 0.28 for the femur (a 113 mm bone), 0.49 for the half sphere
    (R 24 mm), 0.53 for the slot block (42 x 32 x 16 mm), 0.83 for the filleted box (50 x 33 x 17
    mm). A given ``scale`` scans the part at that size instead, whatever the count (``n_points``
    must then be None). Every scan line is kept whole; nothing is subsampled.

    Deterministic for a ``seed``; the grid frames, the dropout, the noise, the outliers and the
    registration draw from separate streams of it, so changing one of them (``noise_mm``, say)
    leaves the others (the holes, the registration) as they were. Not modelled: the shadows of a
    triangulation scanner's second line of sight, reflections, the table and the fixture (never
    recorded). About 2 s for the 40,000-point femur (ray marching), well under 1 s for the others.

    ``normals``: the exact outward unit normal of the surface at the ray's hit, before noise,
    outlier displacement and registration. Points are grouped by view, then by scan line, then
    along the line. ``meta``: ``shape``, ``scale``, ``along_mm``, ``across_mm``, ``n_views``,
    ``view_directions`` (k, 3), ``line_directions`` / ``across_directions`` (k, 3, the grid axes of
    each view), ``noise_mm``, ``dropout_deg``, ``dropout_law``, ``outlier_share``, ``outlier_mm``,
    ``outliers`` (count), ``outlier_index`` (indices), ``registration_deg``, ``registration_mm``,
    ``registration_rotvec_deg`` / ``registration_translation_mm`` (k, 3),
    ``registration_centre_mm``, ``view`` (N,) int16, ``line`` (N,) int32 (unique over the sample;
    consecutive ids of one view are neighbouring lines, ``across_mm`` apart), ``column`` (N,) int32
    (sample index along the line), ``incidence_deg`` (N,), ``points_per_view``, ``rays``, ``hits``
    (before the dropout), ``n_lines``, ``n_points_target``, ``seed``, plus the shape's known
    answers (``radius_mm``; ``dimensions_mm``, ``surface_area_mm2``; the slot's and the box's
    dimensions with ``labels`` / ``label_names`` as in the uniform samples).
    """
    shape = _check_shape(shape)
    along = _check_float("along_mm", along_mm, 0.0, 100.0)
    across = _check_float("across_mm", across_mm, 0.0, 100.0)
    nv = _DEFAULT_VIEWS[shape] if n_views is None else _check_int("n_views", n_views, 1, 64)
    sigma = _check_float("noise_mm", noise_mm, 0.0, 5.0, lo_open=False)
    try:
        d0, d1 = (float(v) for v in dropout_deg)
    except (TypeError, ValueError):
        raise ParameterError(f"dropout_deg = {dropout_deg!r}: must be two angles (start, end) in [0, 90] deg",
                             parameter="dropout_deg", value=repr(dropout_deg), allowed="0 <= start <= end <= 90")
    if not (0.0 <= d0 <= d1 <= 90.0):
        raise ParameterError(f"dropout_deg = {dropout_deg!r}: must be two angles 0 <= start <= end <= 90 deg",
                             parameter="dropout_deg", value=repr(dropout_deg), allowed="0 <= start <= end <= 90")
    share = _check_float("outlier_share", outlier_share, 0.0, 0.5, lo_open=False, unit="")
    out_mm = _check_float("outlier_mm", outlier_mm, 0.0, 1000.0, lo_open=False)
    reg_mm = _check_float("registration_mm", registration_mm, 0.0, 100.0, lo_open=False)
    reg_deg = _check_float("registration_deg", registration_deg, 0.0, 10.0, lo_open=False, unit="deg")
    seed = _check_seed(seed)
    if scale is not None and n_points is not None:
        raise ParameterError("range_scan: give n_points (the part is scaled to it) or scale (the count follows), "
                             "not both", parameter="scale", value=scale, allowed="None when n_points is given")
    target = None if scale is not None else (40_000 if n_points is None else
                                            _check_int("n_points", n_points, 1000, 5_000_000))
    # one stream per effect, so that changing one (the noise, say) leaves the others as they were
    rng, rng_drop, rng_noise, rng_out, rng_reg = (np.random.default_rng(q)
                                                  for q in np.random.SeedSequence(seed).spawn(5))

    dirs = _scanner_directions(nv) if shape == "femur_like" else _turntable_directions(nv)
    frames = []
    for v in dirs:
        e1, e2 = _basis(v)
        psi = rng.uniform(0.0, math.pi)
        ea = math.cos(psi) * e1 + math.sin(psi) * e2
        frames.append((ea, np.cross(v, ea)))
    phases = rng.random((nv, 2))

    if scale is None:
        unit = _SHAPE_CLASSES[shape](1.0)
        k = max(1.0, math.sqrt(_rays_per_view(unit, dirs, frames, along, across) / _EST_RAYS))
        expected = 0.0
        for v, (ea, ec) in zip(dirs, frames):
            _, _, _, n, _, _ = _cast_view(unit, v, ea, ec, k * along, k * across, (0.5, 0.5))
            theta = np.degrees(np.arccos(np.clip(n @ v, -1.0, 1.0)))
            expected += float(_keep_probability(theta, d0, d1).sum()) * k * k
        if expected <= 0.0:
            raise ParameterError(f"range_scan: no ray of the {nv} views meets the {shape} within the dropout "
                                 f"angle {d1:g} deg", parameter="dropout_deg", value=repr(dropout_deg))
        s = min(10.0, math.sqrt(target / expected))
    else:
        s = _check_float("scale", scale, 0.0, 10.0, unit="")
    shp = _SHAPE_CLASSES[shape](s)
    rays = _rays_per_view(shp, dirs, frames, along, across)
    if rays > _MAX_RAYS:
        raise ParameterError(f"range_scan: {rays:.3g} rays at scale {s:g} and pitches {along:g} x {across:g} mm, "
                             f"at most {_MAX_RAYS:.0e}; lower the scale or widen the pitches",
                             parameter="scale", value=s, allowed=f"<= {_MAX_RAYS:.0e} rays")

    centre = 0.5 * (shp.lo + shp.hi)
    pts, nrms, views, lines, cols, inc, labs = [], [], [], [], [], [], []
    rotvecs, shifts = np.zeros((nv, 3)), np.zeros((nv, 3))
    line0, hits, cast = 0, 0, 0
    for j, (v, (ea, ec)) in enumerate(zip(dirs, frames)):
        r, c, p, n, n_rows, n_rays = _cast_view(shp, v, ea, ec, along, across, phases[j])
        cast += n_rays
        hits += r.size
        theta = np.degrees(np.arccos(np.clip(n @ v, -1.0, 1.0)))
        keep = rng_drop.random(r.size) < _keep_probability(theta, d0, d1)
        r, c, p, n, theta = r[keep], c[keep], p[keep], n[keep], theta[keep]
        if shp.label_names is not None:
            labs.append(shp.labels(p, n))
        if sigma > 0.0:
            p = p + rng_noise.normal(0.0, sigma, r.size)[:, None] * v
        pts.append(p)
        nrms.append(n)
        views.append(np.full(r.size, j, np.int16))
        lines.append((line0 + r).astype(np.int32))
        cols.append(c.astype(np.int32))
        inc.append(theta)
        line0 += n_rows
    points, normals = np.vstack(pts), np.vstack(nrms)
    view = np.concatenate(views)
    n_total = points.shape[0]
    if n_total == 0:
        raise ParameterError(f"range_scan: the views recorded no point of the {shape} at scale {s:g}",
                             parameter="scale", value=s)
    n_out = round(share * n_total)
    out_idx = np.sort(rng_out.choice(n_total, n_out, replace=False)) if n_out else np.zeros(0, np.int64)
    if n_out:
        mag = out_mm * rng_out.uniform(0.5, 1.5, n_out) * rng_out.choice([-1.0, 1.0], n_out)
        points[out_idx] += mag[:, None] * dirs[view[out_idx]]
    for j in range(nv):
        axis, tdir = _unit_vector(rng_reg), _unit_vector(rng_reg)
        rotvecs[j], shifts[j] = reg_deg * axis, reg_mm * tdir
        rows = view == j
        if reg_deg > 0.0 or reg_mm > 0.0:
            rot = _rotation(axis, math.radians(reg_deg))
            points[rows] = (points[rows] - centre) @ rot.T + centre + shifts[j]

    meta = {"shape": shape, "scale": s, "along_mm": along, "across_mm": across, "n_views": nv,
            "view_directions": dirs, "line_directions": np.array([f[0] for f in frames]),
            "across_directions": np.array([f[1] for f in frames]), "noise_mm": sigma,
            "dropout_deg": (d0, d1),
            "dropout_law": (f"kept with probability 1 below {d0:g} deg incidence, 0.5 (1 + cos(pi (theta - "
                            f"{d0:g}) / {d1 - d0:g})) up to {d1:g} deg, 0 beyond"),
            "outlier_share": share, "outlier_mm": out_mm, "outliers": n_out, "outlier_index": out_idx,
            "registration_deg": reg_deg, "registration_mm": reg_mm, "registration_rotvec_deg": rotvecs,
            "registration_translation_mm": shifts, "registration_centre_mm": tuple(float(x) for x in centre),
            "view": view, "line": np.concatenate(lines), "column": np.concatenate(cols),
            "incidence_deg": np.concatenate(inc), "points_per_view": np.bincount(view, minlength=nv),
            "rays": cast, "hits": hits, "n_lines": line0, "n_points_target": target, "seed": seed}
    meta.update(shp.known())
    if shp.label_names is not None:                 # the face of each exact hit
        meta["labels"] = np.concatenate(labs)
        meta["label_names"] = shp.label_names
    dims = " x ".join(f"{x:.3g}" for x in shp.hi - shp.lo)
    return Sample(
        name=RANGE_SHAPES[shape], points=points, normals=normals,
        description=(f"range scan of the {shape} ({dims} mm, scale {s:.3g}): {n_total} points, {nv} views, lines "
                     f"{across:g} mm apart sampled every {along:g} mm, noise {sigma:g} mm along the rays, "
                     f"dropout {d0:g}-{d1:g} deg, {n_out} outliers, registration {reg_deg:g} deg / {reg_mm:g} mm, "
                     f"exact normals"),
        meta=meta,
    )


def _named(shape: str):
    """:func:`range_scan` of one ``shape``, with the same arguments less ``shape`` (the registry's
    ``range_femur``, ``range_half_sphere``, ``range_slot``, ``range_filleted_box``)."""
    import functools
    import inspect

    @functools.wraps(range_scan)
    def gen(**kwargs) -> Sample:
        return range_scan(shape, **kwargs)

    sig = inspect.signature(range_scan)
    gen.__signature__ = sig.replace(parameters=[p for p in sig.parameters.values() if p.name != "shape"])
    gen.__name__ = gen.__qualname__ = RANGE_SHAPES[shape]
    gen.__doc__ = f"""{RANGE_SHAPES[shape]}: :func:`range_scan` with ``shape="{shape}"`` (same arguments)."""
    del gen.__wrapped__
    return gen


range_femur = _named("femur_like")
range_half_sphere = _named("half_sphere")
range_slot = _named("slot")
range_filleted_box = _named("filleted_box")
