"""Candidate placements of the part on the table: how the scanned part may be clamped instead.

Makki 2010 (§3.1, §4) ends where no ``n_pmax`` set-ups reach the coverage with "change the set-up of
the part". This module lists the part orientations worth trying; :mod:`planning.placement.search`
evaluates them with the plan's own stages. A :class:`Pose` is a rigid motion of the scanned cloud,
``placed = scanned @ rotation.T + translation_mm``, after which the plan's usual placement applies
(``fixtures.fixture_height_mm`` under the lowest point, the part centred on the table's C axis).

The candidates, in this order (:func:`candidate_poses`):

1. ``as_scanned``: the identity, today's plan (rotation I, translation 0).
2. ``hull_face``: the stable resting poses of the convex hull (:func:`stable_poses`). The part put
   down on a flat table touches it with a face of its convex hull; it stays there when the foot of
   its centre of mass (here the centroid of the hull's volume: a scan has no inside, and the hull's
   centroid does not depend on the scanner's point density) falls inside that face, and tips
   otherwise. Hull facets are merged into faces when their outward normals lie within
   :data:`MERGE_DEG` of the face's largest facet (a scanned flat face is a fan of near-coplanar
   triangles; on a convex hull facets of close normals are neighbours, so the normal alone merges
   them). A face's stability is its tipping angle, ``atan(margin / height)``: ``margin`` the distance
   from the foot of the centroid to the nearest edge of the face polygon (the convex hull of the
   face's vertices in its plane), ``height`` the centroid's height above the face. Faces that tip
   at less than :data:`MIN_STABILITY_DEG` are balanced, not stable (on a curved hull every small
   patch under the centroid qualifies otherwise); the stable faces are ranked by it, most stable
   first, and the first :data:`MAX_HULL_POSES` kept.
3. ``principal_axis``: each principal axis of the points (eigenvectors of their covariance, largest
   variance first) pointing up, then down: six poses whatever the shape.

Yaw (the turn about the vertical). Every pose but the identity turns its points about the vertical
so that the longest horizontal principal direction of the placed points lies along the table's X
axis (the longer travel on the bundled machines), its sign fixed so that the result does not depend
on eigenvector signs. Where the machine's rotary (C) axis turns a full 360 degrees (a continuous C
table, or a C range of 360 degrees or more) that is the only yaw tried: the C axis presents the part
at any yaw anyway, and yaw then changes only where the azimuth grid of the candidate axes
(``orientations.theta_step_deg``) and the X/Y travel fall on the part, which matters little. Where
the C axis turns less, each pose is also tried turned by 90, 180 and 270 degrees (:data:`YAWS_DEG`).

Duplicates: a pose whose up direction (the scanned-frame direction the pose turns to +Z) lies within
:data:`SAME_UP_DEG` of an earlier candidate's, with the same yaw rule, is dropped (a principal axis
usually repeats a hull face). 5 degrees is half the default polar step of the candidate axes: two such
poses present the part to nearly the same axes, while a face 9 degrees off the scanned bottom (the
femur-like sample's most stable face) is still tried.

Translation: every pose but the identity puts the placed cloud's bounding box centred on x = y = 0
with its lowest point at z = 0 (the frame of the reference samples, which stand on the table); the
identity keeps the scanned coordinates, so an ``as_scanned`` winner plans exactly as
``fixtures.placement = "as_scanned"`` does.

Everything here is whole-array numpy on the hull's vertices and facets (a loop runs per merged face,
never per point); the same points give the same poses in the same order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planning.errors import ParameterError

__all__ = [
    "MAX_HULL_POSES",
    "MERGE_DEG",
    "MIN_STABILITY_DEG",
    "SAME_UP_DEG",
    "YAWS_DEG",
    "HullFace",
    "Pose",
    "apply_pose",
    "candidate_poses",
    "hull_centroid",
    "max_candidates",
    "principal_poses",
    "stable_faces",
    "stable_poses",
    "turn",
]

#: Hull facets whose outward normals lie within this of a face's largest facet form one face, deg.
MERGE_DEG = 3.0
#: A face on which the part tips over by less than this is balanced rather than stable, deg.
MIN_STABILITY_DEG = 1.0
#: At most this many stable hull faces are tried (the most stable ones).
MAX_HULL_POSES = 8
#: A pose whose up direction lies within this of an earlier candidate's is a duplicate, deg.
SAME_UP_DEG = 5.0
#: Extra turns about the vertical tried where the machine's C axis turns less than 360 degrees.
YAWS_DEG = (0.0, 90.0, 180.0, 270.0)

_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class Pose:
    """One candidate placement: ``placed = scanned @ rotation.T + translation_mm``.

    ``kind``: ``"as_scanned"``, ``"hull_face"`` or ``"principal_axis"``; ``label``: what a machinist
    reads ("resting on hull face 2", "principal axis 1 up"); ``up``: the scanned-frame unit vector
    that points up once placed (``rotation.T @ [0, 0, 1]``); ``stability_deg``: the tipping angle of
    a hull face (None for the others); ``yaw_deg``: the extra turn about the vertical (0 unless the
    C axis is limited); ``part_height_mm``: the placed cloud's height (z extent)."""

    kind: str
    label: str
    rotation: np.ndarray          # (3,3) proper rotation
    translation_mm: np.ndarray    # (3,)
    up: np.ndarray                # (3,) scanned frame
    stability_deg: float | None
    yaw_deg: float
    part_height_mm: float

    def describe(self) -> str:
        """The label and which scanned-frame direction points down once placed, for the operator."""
        if self.kind == "as_scanned" and self.yaw_deg == 0:
            return self.label
        d = -self.up
        return f"{self.label}, scan direction ({d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f}) down"


@dataclass(frozen=True)
class HullFace:
    """A merged face of the convex hull on which the part rests stably: ``normal`` (3,) outward,
    unit, scanned frame; ``area_mm2``; ``stability_deg`` its tipping angle; ``n_facets`` merged."""

    normal: np.ndarray
    area_mm2: float
    stability_deg: float
    n_facets: int


def _as_points(points) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 4 or not np.all(np.isfinite(p)):
        raise ParameterError("placement needs an (N,3) array of at least 4 finite points, mm", parameter="points")
    return p


def _hull(points: np.ndarray):
    """scipy's ConvexHull of the points, or None for a flat or degenerate cloud."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return ConvexHull(points)
    except (QhullError, ValueError):
        return None


def _hull_parts(hull):
    """(facet triangles (F,3,3), unit outward normals (F,3), areas (F,))."""
    tri = hull.points[hull.simplices]                                   # (F,3,3)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normals = hull.equations[:, :3] / np.linalg.norm(hull.equations[:, :3], axis=1)[:, None]
    return tri, normals, area


def hull_centroid(points) -> np.ndarray:
    """Centroid of the volume of the points' convex hull (3,), mm; the points' mean for a flat cloud.
    The part's centre of mass where it is convex and solid, and independent of the point density."""
    p = _as_points(points)
    hull = _hull(p)
    if hull is None:
        return p.mean(axis=0)
    return _volume_centroid(hull, p)


def _volume_centroid(hull, p: np.ndarray) -> np.ndarray:
    tri = hull.points[hull.simplices]
    o = hull.points[hull.vertices].mean(axis=0)
    a, b, c = tri[:, 0] - o, tri[:, 1] - o, tri[:, 2] - o
    vol = np.abs(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6.0
    if vol.sum() <= 0:
        return p.mean(axis=0)
    cen = o + (a + b + c) / 4.0
    return (vol[:, None] * cen).sum(axis=0) / vol.sum()


def _merge_facets(normals: np.ndarray, area: np.ndarray, merge_deg: float) -> np.ndarray:
    """Face id (F,) of every facet: leader clustering by normal, largest facet first (ties by index)."""
    F = normals.shape[0]
    face = np.full(F, -1, dtype=np.int64)
    order = np.lexsort((np.arange(F), -area))
    cos_m = math.cos(math.radians(merge_deg))
    nf = 0
    for s in order:
        if face[s] >= 0:
            continue
        near = (face < 0) & (normals @ normals[s] >= cos_m)
        face[near] = nf
        nf += 1
    return face


def _polygon_margin(xy: np.ndarray, q: np.ndarray) -> float:
    """Signed distance (mm) from 2-D point q to the boundary of the convex hull of ``xy`` (k,2):
    positive inside, negative or zero outside or on it; -inf for a degenerate polygon."""
    from scipy.spatial import ConvexHull, QhullError

    if xy.shape[0] < 3:
        return -math.inf
    try:
        h = ConvexHull(xy)
    except (QhullError, ValueError):
        return -math.inf
    # equations: n . x + d <= 0 inside, n unit
    return float(-(h.equations[:, :2] @ q + h.equations[:, 2]).max())


def stable_faces(points, *, merge_deg: float = MERGE_DEG, min_stability_deg: float = MIN_STABILITY_DEG,
                 hull=None) -> list[HullFace]:
    """The faces of the points' convex hull on which the part rests stably, most stable first.

    Facets are merged by normal (:data:`MERGE_DEG`); a face is stable when the foot of the hull's
    volume centroid on its plane falls inside the face polygon with a tipping angle
    ``atan(margin / height)`` (``stability_deg``) of at least ``min_stability_deg``. Ties (a symmetric part) keep the order of the largest
    facets, so the result is deterministic. Empty for a flat or degenerate cloud. ``hull``: the
    points' scipy ConvexHull when the caller has it."""
    p = _as_points(points)
    hull = _hull(p) if hull is None else hull
    if hull is None:
        return []
    g = _volume_centroid(hull, p)
    tri, normals, area = _hull_parts(hull)
    face = _merge_facets(normals, area, merge_deg)
    nface = int(face.max()) + 1
    # area-weighted mean normal of every face, in one pass
    fn = np.zeros((nface, 3))
    np.add.at(fn, face, normals * area[:, None])
    farea = np.bincount(face, weights=area, minlength=nface)
    fn /= np.maximum(np.linalg.norm(fn, axis=1), 1e-300)[:, None]
    hv = hull.points[hull.vertices]
    support = (hv @ fn.T).max(axis=0)                                   # (nface,) plane offset
    height = support - fn @ g                                           # centroid height above it
    order = np.argsort(face, kind="stable")
    starts = np.searchsorted(face[order], np.arange(nface + 1))
    # a necessary condition, for every face at once: the foot of the centroid lies within the sphere
    # about the face's area centroid that holds its vertices (most faces of a curved hull fail it)
    fc = np.zeros((nface, 3))
    np.add.at(fc, face, tri.mean(axis=1) * area[:, None])
    fc /= np.maximum(farea, 1e-300)[:, None]
    reach = np.zeros(nface)
    np.maximum.at(reach, face, np.linalg.norm(tri - fc[face][:, None, :], axis=2).max(axis=1))
    foot3 = g + height[:, None] * fn
    near = (height > 0) & (np.linalg.norm(foot3 - fc, axis=1) < reach)
    out: list[tuple[float, int, HullFace]] = []
    for f in np.flatnonzero(near):
        members = order[starts[f]:starts[f + 1]]
        verts = tri[members].reshape(-1, 3)
        n = fn[f]
        e = np.zeros(3)
        e[int(np.argmin(np.abs(n)))] = 1.0
        u = np.cross(n, e)
        u /= np.linalg.norm(u)
        w = np.cross(n, u)
        foot = np.array([g @ u, g @ w])
        xy = np.column_stack((verts @ u, verts @ w))
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        if np.any(foot <= lo) or np.any(foot >= hi):
            continue                                                    # cheap reject: outside the box
        margin = _polygon_margin(xy, foot)
        if margin <= 0:
            continue
        tip = math.degrees(math.atan2(margin, float(height[f])))
        if tip < min_stability_deg:
            continue
        out.append((tip, f, HullFace(normal=n.copy(), area_mm2=float(farea[f]), stability_deg=tip,
                                     n_facets=int(members.size))))
    out.sort(key=lambda t: (-round(t[0], 9), t[1]))
    return [h for _, _, h in out]


def _sign_fixed(v: np.ndarray) -> np.ndarray:
    """``v`` or ``-v``: the one whose largest-magnitude component (first on ties) is positive."""
    i = int(np.argmax(np.abs(v) - 1e-12 * np.arange(v.size)))
    return v if v[i] >= 0 else -v


def _covariance(points: np.ndarray) -> np.ndarray:
    """The points' covariance (3,3), mm^2: computed once per search, every pose's yaw reads it."""
    c = points - points.mean(axis=0)
    return c.T @ c / max(points.shape[0], 1)


def _principal_axes(cov: np.ndarray) -> np.ndarray:
    """Rows: the principal directions of covariance ``cov``, largest variance first, signs fixed."""
    w, v = np.linalg.eigh(cov)
    idx = np.argsort(-w, kind="stable")
    return np.array([_sign_fixed(v[:, i]) for i in idx])


def _rz(yaw_deg: float) -> np.ndarray:
    """The turn by ``yaw_deg`` about +Z (3,3)."""
    a = math.radians(yaw_deg)
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _rotation_up(up: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The rotation that turns ``up`` (scanned frame) to +Z and the longest horizontal principal
    direction of the turned points (covariance ``cov``) to +X."""
    up = up / np.linalg.norm(up)
    P = np.eye(3) - np.outer(up, up)
    w, v = np.linalg.eigh(P @ cov @ P)
    x = v[:, int(np.argmax(w))]
    x = x - (x @ up) * up
    if np.linalg.norm(x) < 1e-9:                                        # isotropic: any horizontal
        e = np.zeros(3)
        e[int(np.argmin(np.abs(up)))] = 1.0
        x = np.cross(up, e)
    x = _sign_fixed(x / np.linalg.norm(x))
    y = np.cross(up, x)
    return np.array([x, y, up])


def _standing_translation(points: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, float]:
    """Translation putting the turned points' box centred on x = y = 0 with its lowest point at z = 0,
    and the placed height (mm)."""
    q = points @ R.T
    lo, hi = q.min(axis=0), q.max(axis=0)
    return np.array([-0.5 * (lo[0] + hi[0]), -0.5 * (lo[1] + hi[1]), -lo[2]]), float(hi[2] - lo[2])


def turn(vectors, rotation: np.ndarray) -> np.ndarray:
    """``vectors @ rotation.T`` (N,3): einsum, 3-4x faster than BLAS's matmul on an (N,3) by (3,3) product
    (measured on 1M points), and no thread pool to wake."""
    return np.einsum("ij,kj->ik", np.asarray(vectors, dtype=np.float64), rotation)


def apply_pose(points, pose: Pose) -> np.ndarray:
    """The placed points ``points @ rotation.T + translation_mm`` (N,3), mm."""
    out = turn(points, pose.rotation)
    out += pose.translation_mm
    return out


def _pose(kind, label, up, cov, extent_pts, stability) -> Pose:
    R = _rotation_up(up, cov)
    t, h = _standing_translation(extent_pts, R)
    return Pose(kind=kind, label=label, rotation=R, translation_mm=t, up=R[2].copy(), stability_deg=stability,
                yaw_deg=0.0, part_height_mm=h)


def _extent_points(p: np.ndarray, hull) -> np.ndarray:
    """The points that decide a placed box: the hull's vertices (all points for a flat cloud)."""
    return p if hull is None else hull.points[hull.vertices]


def stable_poses(points, *, max_poses: int = MAX_HULL_POSES, merge_deg: float = MERGE_DEG, hull=None,
                 cov=None) -> list[Pose]:
    """The part resting on each of its most stable hull faces (:func:`stable_faces`), face down."""
    p = _as_points(points)
    hull = _hull(p) if hull is None else hull
    ext = _extent_points(p, hull)
    cov = _covariance(p) if cov is None else cov
    return [_pose("hull_face", f"resting on hull face {i} (tipping angle {f.stability_deg:.1f} deg)", -f.normal, cov,
                  ext, f.stability_deg)
            for i, f in enumerate(stable_faces(p, merge_deg=merge_deg, hull=hull)[:max_poses])]


def principal_poses(points, *, hull=None, cov=None) -> list[Pose]:
    """Six poses: principal axis 1, 2, 3 (largest variance first) pointing up, then down."""
    p = _as_points(points)
    ext = _extent_points(p, _hull(p) if hull is None else hull)
    cov = _covariance(p) if cov is None else cov
    out = []
    for i, a in enumerate(_principal_axes(cov)):
        for s, word in ((1.0, "up"), (-1.0, "down")):
            out.append(_pose("principal_axis", f"principal axis {i + 1} {word}", s * a, cov, ext, None))
    return out


def _identity(points: np.ndarray) -> Pose:
    z = points[:, 2]
    return Pose(kind="as_scanned", label="as scanned", rotation=np.eye(3), translation_mm=np.zeros(3), up=_Z.copy(),
                stability_deg=None, yaw_deg=0.0, part_height_mm=float(z.max() - z.min()))


def _yawed(pose: Pose, yaw: float, points: np.ndarray) -> Pose:
    R = _rz(yaw) @ pose.rotation
    t, h = _standing_translation(points, R)
    return Pose(kind=pose.kind, label=f"{pose.label}, turned {yaw:g} deg about the vertical", rotation=R,
                translation_mm=t, up=pose.up, stability_deg=pose.stability_deg, yaw_deg=float(yaw), part_height_mm=h)


def max_candidates(full_yaw: bool) -> int:
    """The most poses :func:`candidate_poses` lists after the as-scanned one: :data:`MAX_HULL_POSES` hull
    faces and the six principal-axis poses, times :data:`YAWS_DEG` where the C axis is limited (a bound
    known before any hull is computed)."""
    return (MAX_HULL_POSES + 6) * (1 if full_yaw else len(YAWS_DEG))


def candidate_poses(points, *, full_yaw: bool = True, max_hull_poses: int = MAX_HULL_POSES,
                    same_up_deg: float = SAME_UP_DEG) -> list[Pose]:
    """Every candidate placement, in the order of the module docstring: the identity, the stable
    hull faces (most stable first), the six principal-axis poses; duplicates of an earlier up
    direction (within ``same_up_deg``) dropped. ``full_yaw``: the machine's C axis turns 360 degrees
    (one yaw per pose); otherwise each pose is also turned by 90, 180 and 270 degrees."""
    p = _as_points(points)
    hull = _hull(p)
    cov = _covariance(p)
    poses = ([_identity(p)] + stable_poses(p, max_poses=max_hull_poses, hull=hull, cov=cov)
             + principal_poses(p, hull=hull, cov=cov))
    cos_s = math.cos(math.radians(same_up_deg))
    kept: list[Pose] = []
    for q in poses:
        if any(float(q.up @ k.up) >= cos_s for k in kept):
            continue
        kept.append(q)
    if full_yaw:
        return kept
    ext = _extent_points(p, hull)
    return [q if y == 0.0 else _yawed(q, y, ext) for q in kept for y in YAWS_DEG]
