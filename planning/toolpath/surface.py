"""Which surface the finishing ball rests on: the points, or triangles through them (issue 18, density guard).

Sood (2015, ch. 4) drops the ball on the points and warns that it dips between them when they lie far
apart against the tool: between points ``s`` apart on a square grid the ball sinks
``R - sqrt(R^2 - s^2 / 2)`` below the surface they sample (0.03 mm for s = 0.6 mm, R = 3 mm; 0.19 mm for
s = 1.5 mm), a gouge the point-based clearance check cannot see. The thesis switches to the facets
when the spacing exceeds 20 % of R (:data:`SPARSE_SHARE_OF_RADIUS`). So does scanmill:

* :func:`point_spacing_mm` estimates the spacing: the mean spacing ``s = sqrt(area per point)`` from
  the distance ``r_k`` to each point's k-th neighbour, ``s = median(r_k) sqrt(pi / k)`` (k = 6; exact
  for a uniform random sampling, 1.02 s on a square grid), or the spacing across the sampling's main
  direction where that is larger (scan lines far apart), on a seeded subsample of the points;
* :func:`path_surface` decides with ``paths.surface``:

  - ``auto`` (default): the file's own triangles when it has them (a mesh, or a scanner's grid:
    structured E57 scans, relief images: the surface itself, not a sampling of it); else the points
    when ``s <= 0.2 R``; else triangles through the points (:func:`reconstruct`: the faces of their
    Delaunay tetrahedra with a circumradius of at most 1.6 s, an alpha shape's triangles) whose
    vertices ARE the points; when that leaves more than :data:`MAX_UNMESHED_SHARE` of the points on
    no triangle (e.g. scan lines far apart), the plan is refused (``cloud_too_sparse``) with the
    spacing, the tool and the choices;
  - ``mesh``: triangles whatever the spacing (the same sources);
  - ``points``: the points whatever the spacing; when sparse, a warning gives the dip depth.

Triangles only ever raise the ball (their vertices are points, and the drop is the max over points
and triangles), so triangles a reconstruction adds across a concave gap leave material, never gouge.
The gouge clearance is then measured to the triangles too. The answer is a :class:`PathSurface`
whose :meth:`PathSurface.summary` goes into plan.json (``paths_surface``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from planning.errors import InputError, ParameterError

#: Sood's criterion: the points carry the ball while their spacing is at most this share of R.
SPARSE_SHARE_OF_RADIUS = 0.2
#: A reconstruction leaving more than this share of the points on no triangle is not used.
MAX_UNMESHED_SHARE = 0.02
#: Neighbour rank of the spacing estimate.
_K = 6
#: Neighbours searched for the spacing across the sampling's main direction.
_ACROSS_K = 16
#: Points whose neighbours are measured (a seeded subsample of larger clouds).
_SAMPLE = 20_000
#: Triangles of the reconstruction have a circumradius of at most this many spacings.
ALPHA_SPACINGS = 1.6

SURFACE_MODES = ("auto", "points", "mesh")


def point_spacing_mm(points: np.ndarray, *, k: int = _K, sample: int = _SAMPLE, seed: int = 0) -> float:
    """Point spacing of ``points`` (N,3) mm, on a seeded subsample of ``sample`` points: the larger of

    * the mean spacing ``median(r_k) sqrt(pi / k)``, ``r_k`` the distance to the k-th nearest other
      point (exact for a uniform random sampling, 1.02 s on a square grid), and
    * the spacing ACROSS the sampling's main direction: the median over the points of the distance to
      the nearest of their :data:`_ACROSS_K` neighbours that lies more than 45 degrees off the main axis
      of those neighbours (their covariance's first eigenvector), or the farthest of them where none
      does. A scan of dense lines far apart has a small mean spacing but a large one across the lines,
      which is where the ball sinks; on an even sampling this is about the nearest-neighbour distance,
      below the mean spacing.

    0 for fewer than ``k + 1`` points."""
    p = np.asarray(points, dtype=np.float64)
    n = p.shape[0]
    if n <= k:
        return 0.0
    rng = np.random.default_rng(seed)
    sub = p if n <= sample else p[np.sort(rng.choice(n, sample, replace=False))]
    kk = min(_ACROSS_K, n - 1)
    d, idx = cKDTree(p).query(sub, k=kk + 1)
    mean = float(np.median(d[:, min(k, kk)]) * math.sqrt(math.pi / k))
    rel = p[idx[:, 1:]] - sub[:, None, :]                       # (m, kk, 3) the neighbours
    cov = np.einsum("mki,mkj->mij", rel, rel)
    axis = np.linalg.eigh(cov)[1][:, :, 2]                     # main direction of each neighbourhood
    dist = d[:, 1:]
    along = np.einsum("mki,mi->mk", rel, axis)
    off = along * along < 0.5 * np.maximum(dist * dist, 1e-300)   # more than 45 degrees off the axis
    across = np.where(off, dist, np.inf).min(axis=1)
    across = np.where(np.isfinite(across), across, dist[:, -1])
    return max(mean, float(np.median(across)))


def dip_mm(spacing_mm: float, radius_mm: float) -> float:
    """How far a ball of ``radius_mm`` sinks between points ``spacing_mm`` apart on a square grid, mm:
    ``R - sqrt(R^2 - s^2 / 2)`` (R when the gap is wider than the ball)."""
    h2 = spacing_mm * spacing_mm / 2.0
    r2 = radius_mm * radius_mm
    return float(radius_mm - math.sqrt(r2 - h2)) if h2 < r2 else float(radius_mm)


@dataclass(frozen=True)
class PathSurface:
    """The surface the finishing paths use.

    ``kind``: ``points``, ``input_mesh`` (the file's faces), ``scanner_grid`` (faces from a structured
    scan or a relief image's pixel grid) or ``reconstructed`` (:func:`reconstruct`). ``faces`` (T,3) int64
    indices into the plan's points (None for ``points``). ``spacing_mm`` the estimated spacing,
    ``threshold_mm`` = 0.2 R, ``dip_mm`` the dip of a ball on points that far apart, ``reason`` one
    sentence for plan.json, ``unmeshed_share`` the share of points on no triangle."""

    kind: str
    faces: np.ndarray | None
    spacing_mm: float
    threshold_mm: float
    dip_mm: float
    reason: str
    unmeshed_share: float = 0.0
    warning: str | None = None

    def summary(self) -> dict:
        """The plan.json ``paths_surface`` block."""
        return {"kind": self.kind, "n_triangles": 0 if self.faces is None else int(self.faces.shape[0]),
                "spacing_mm": round(self.spacing_mm, 4), "threshold_mm": round(self.threshold_mm, 4),
                "dip_on_points_mm": round(self.dip_mm, 4), "unmeshed_share": round(self.unmeshed_share, 6),
                "reason": self.reason}


def _grid_kind(source_format: str) -> bool:
    return source_format.startswith(("e57", "image"))


def reconstruct(points: np.ndarray, spacing_mm: float) -> np.ndarray:
    """Triangles (T,3) int64 through ``points`` (N,3) mm: the faces of their 3D Delaunay tetrahedra
    (scipy's Qhull, joggled so flat or cospherical samplings triangulate) whose circumradius is at
    most :data:`ALPHA_SPACINGS` x ``spacing_mm`` (the triangles of an alpha shape, without its
    emptiness test: a superset, each triangle within that radius of its own vertices, so one a ball
    rests on lies inside the sampled band of the surface). Vertices are the points themselves."""
    from scipy.spatial import Delaunay, QhullError

    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.shape[0] < 4:
        return np.zeros((0, 3), dtype=np.int64)
    try:
        tets = Delaunay(p, qhull_options="Qbb Qc Q12 QJ").simplices
    except QhullError:
        return np.zeros((0, 3), dtype=np.int64)
    f = np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]])
    f = np.unique(np.sort(f, axis=1), axis=0).astype(np.int64)
    t = p[f]
    a = np.linalg.norm(t[:, 1] - t[:, 2], axis=1)
    b = np.linalg.norm(t[:, 2] - t[:, 0], axis=1)
    c = np.linalg.norm(t[:, 0] - t[:, 1], axis=1)
    area2 = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)     # twice the area
    keep = a * b * c <= 2.0 * ALPHA_SPACINGS * spacing_mm * area2                     # abc / (4 A) <= alpha
    return f[keep]


def path_surface(points: np.ndarray, *, radius_mm: float, mode: str = "auto", faces: np.ndarray | None = None,
                 source_format: str = "") -> PathSurface:
    """Choose the surface the finishing ball rests on (module docstring). ``points`` (N,3) mm, the
    plan's points; ``faces`` the file's triangles into them (or None). Raises :class:`InputError` ``cloud_too_sparse`` when ``auto`` needs triangles and
    none can be built."""
    if mode not in SURFACE_MODES:
        raise ParameterError(f"paths.surface is {mode!r}; allowed: {', '.join(SURFACE_MODES)}",
                             parameter="paths.surface", value=mode, allowed=list(SURFACE_MODES))
    R = float(radius_mm)
    s = point_spacing_mm(points)
    limit = SPARSE_SHARE_OF_RADIUS * R
    dip = dip_mm(s, R)
    sparse = s > limit
    what = (f"point spacing {s:.3f} mm {'exceeds' if sparse else 'is within'} 20 % of the tool radius "
            f"({limit:.3f} mm for R {R:g} mm)")
    has_faces = faces is not None and len(faces) > 0
    if mode == "points" or (mode == "auto" and not sparse and not has_faces):
        warning = None
        if sparse:
            warning = (f"paths.surface = points on a sparse cloud: {what}; the ball can sink up to {dip:.3f} mm "
                       "between the points (a gouge no check against the points sees); paths.surface = auto "
                       "drops it on triangles")
        return PathSurface("points", None, s, limit, dip, f"{what}: the ball rests on the points"
                           + (" (paths.surface = points)" if mode == "points" else ""), warning=warning)
    if has_faces:
        kind = "scanner_grid" if _grid_kind(source_format) else "input_mesh"
        faces = np.asarray(faces, dtype=np.int64)
        used = np.zeros(int(faces.max()) + 1, dtype=bool)      # the vertices (a mesh's facet points come after)
        used[faces.ravel()] = True
        return PathSurface(kind, np.asarray(faces, dtype=np.int64), s, limit, dip,
                           f"{what}: the ball rests on the {'file' if kind == 'input_mesh' else 'scan grid'}'s "
                           f"{len(faces):,} triangles", unmeshed_share=float(1.0 - used.mean()))
    tri = reconstruct(points, max(s, 1e-6))
    used = np.zeros(points.shape[0], dtype=bool)
    if tri.size:
        used[tri.ravel()] = True
    unmeshed = float(1.0 - used.mean())
    if unmeshed > MAX_UNMESHED_SHARE:
        raise InputError(
            f"No surface can be built through the points for the finishing ball: the triangles through them "
            f"(circumradius <= {ALPHA_SPACINGS:g} x the {s:.3f} mm point spacing) leave {unmeshed:.1%} of the points "
            f"on no triangle (scan lines or patches far apart?), and on the points alone a ball of R {R:g} mm sinks "
            f"{dip:.3f} mm or more between them. Choices: a denser scan (spacing <= {limit:.3f} mm everywhere), a "
            f"larger tool (tool.diameter_mm >= {2 * s / SPARSE_SHARE_OF_RADIUS:.1f} mm), the scan as a mesh (STL, "
            "OBJ, PLY with faces), or paths.surface = points to accept the dip.",
            code="cloud_too_sparse", spacing_mm=s, threshold_mm=limit, unmeshed_share=unmeshed)
    return PathSurface("reconstructed", tri, s, limit, dip,
                       f"{what}: the ball rests on {len(tri):,} triangles through the points (Delaunay faces of "
                       f"circumradius <= {ALPHA_SPACINGS:g} spacings)",
                       unmeshed_share=unmeshed)
