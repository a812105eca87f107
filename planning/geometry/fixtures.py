"""Global visibility against fixtures (Makki 2010 §2.2.4): the tool and holder versus the clamps,
vises and machine table that hold the part.

Makki et al. 2010 (§2.2.4) call a tool axis globally visible at a point when the cutter and its
holder, placed along that axis, hit neither the part nor the fixtures. :mod:`planning.geometry.collision`
handles the part (the point cloud); this module handles the fixtures, given as solids in the
**part frame**, all lengths in mm:

* :class:`BoxFixture` - a box, axis-aligned or rotated about its centre (vise, clamp, riser);
* :class:`CylinderFixture` - a solid cylinder (chuck, round riser, clamp bolt);
* :class:`MeshFixture` - a triangle mesh (any holder from CAD, :func:`load_mesh`);
* :class:`TableFixture` - the machine table, the half-space ``z < z_mm`` below its top.

The tool is a :class:`planning.geometry.tool.ToolAssembly`: for ball centre ``c`` and unit axis ``t`` it
is the **whole solid ball** (radius ``R`` about ``c``: the cutter must never touch a fixture, so
unlike the cloud test its lower half counts too) and every segment, the solid cylinder
``{c + a t + w : lo <= a <= hi, w . t = 0, |w| <= r}``. Shapes are taken closed, as FCL does:
**touching counts as a collision** (distance 0 is "blocked"). An unbounded segment (``hi=None``)
is cut, for the finite fixtures, at ``a = reach``, the diagonal of the bounding box of all
centres and finite fixtures plus 1 mm: no tool point beyond it can lie in a finite fixture. The
table is treated analytically, so there the segment really is unbounded (a tool pointing down
always hits the table).

Meshes: FCL collides the triangles only, so a :class:`MeshFixture` is its **surface**; a tool
wholly inside a closed mesh touches no triangle. With ``solid=True`` (closed meshes; the default
of :func:`load_mesh` when the file is watertight) the interior counts as well: a pair also
collides when a point of the tool lies inside the mesh (the ball centre, plus one point of each
part of the tool not connected to the ball), found by ray casting (Open3D
``RaycastingScene.compute_occupancy``). A tool that touches no triangle lies wholly inside or
wholly outside, so one point per connected part decides.

Method of :func:`fixture_collision_free`. The answer is FCL's, pair for pair, as computed by
:func:`brute_force_fixture_collision_free`; numpy decides every pair it can prove either way with
a margin, and only the rest goes to FCL:

1. **Ball, per centre** (independent of the axis): exact point-to-box and point-to-cylinder
   distances ``d`` prove "hit" when ``d < R - MARGIN_MM`` and "free" when ``d > R + MARGIN_MM``;
   a mesh's bounding box can only prove "free"; else FCL (sphere). Table: hit when
   ``c_z - R <= z_table``. A centre whose ball hits is blocked for every axis.
2. **Table, per axis, exact**: the lowest point of a cylinder segment is
   ``c_z + min(lo t_z, hi t_z) - r sqrt(1 - t_z^2)`` (an unbounded segment with ``t_z < 0``
   always hits); the pair collides when it is ``<= z_table``.
3. **Finite fixtures**, in the frame of the fixture's oriented bounding box (the box itself for
   a box fixture), with support functions (a cylinder of half-height ``h``, radius ``r``,
   axis ``t`` has half-width ``h |u.t| + r sqrt(1 - (u.t)^2)`` along unit ``u``): a direction
   along which the two projections are more than ``MARGIN_MM`` apart proves "free".

   a. once per fixture: centres that no axis of the set can bring near it (26 fixed directions,
      the tool's extent along each maximised over all axes) are dropped;
   b. per axis, the cylinder bounding the whole stack, then every segment: 7 fixed directions
      ``e_k``, ``t``, ``t x e_k`` (separating-axis test);
   c. segments left: "hit" when one of 8 lines of the segment (axis, generators facing the
      fixture or extreme along ``-+e_k``, all at ``r - MARGIN_MM``, ``lo + MARGIN_MM .. hi -
      MARGIN_MM``) runs through the fixture shrunk by ``MARGIN_MM``, or a box edge runs through
      the segment shrunk by ``MARGIN_MM`` (exact clipping: slabs and quadratics);
   d. still left: a few alternating projections between segment and fixture (both shrunk by
      ``MARGIN_MM``): a common point proves "hit", else the direction between the two points
      is one more separating test, tight for vertex, edge and rim contacts;
   e. the rest: ``fcl.collide`` of the segment's ``fcl.Cylinder`` with the fixture's
      ``fcl.Box``/``fcl.Cylinder``/``fcl.BVHModel``; a pair stops at its first hit.

On the bench scene (a 200 mm part on a vise, two clamps, the table, 216 axes) FCL is left with
less than 0.1 % of the pairs. ``MARGIN_MM`` (1 um) keeps the numpy decisions clear of FCL's
own tolerance (libccd GJK, ~1e-6 mm): pairs that close to touching always go to FCL, so the
fast and brute-force answers agree, and a colliding pair is never called free.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import fcl
import numpy as np

from planning.errors import InputError, ParameterError
from planning.geometry.basis import complete_basis
from planning.geometry.tool import ToolAssembly

#: Numpy decides "free"/"hit" only with at least this clearance/penetration, mm; closer pairs go to FCL.
MARGIN_MM = 1e-3
_MESH_EXTENSIONS = (".stl", ".obj", ".ply")
_REQUEST = fcl.CollisionRequest()


# ----------------------------------------------------------------------------------------------
# fixture geometry (part frame, mm)

def _vec3(v, what: str) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ParameterError(f"{what} must be 3 finite numbers (mm), got {v!r}")
    return (float(a[0]), float(a[1]), float(a[2]))


def _positive(x, what: str) -> float:
    try:
        x = float(x)
    except (TypeError, ValueError):
        raise ParameterError(f"{what} must be a number, got {x!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise ParameterError(f"{what} must be finite and > 0, got {x}")
    return x


@dataclass(frozen=True)
class BoxFixture:
    """Solid box ``min_mm <= x <= max_mm`` (part frame, mm), optionally turned by ``rotation``
    (3x3 proper rotation) about its centre: the box is ``centre + rotation @ (x - centre)``."""

    min_mm: tuple[float, float, float]
    max_mm: tuple[float, float, float]
    rotation: tuple | None = None
    name: str = "box"
    kind: ClassVar[str] = "box"

    def __post_init__(self):
        lo, hi = _vec3(self.min_mm, "box min_mm"), _vec3(self.max_mm, "box max_mm")
        if not all(h > l for l, h in zip(lo, hi)):
            raise ParameterError(f"box {self.name!r}: max_mm {hi} must exceed min_mm {lo} on every axis")
        object.__setattr__(self, "min_mm", lo)
        object.__setattr__(self, "max_mm", hi)
        if self.rotation is not None:
            rot = np.asarray(self.rotation, dtype=float)
            if rot.shape != (3, 3) or not np.all(np.isfinite(rot)) \
                    or np.abs(rot.T @ rot - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) < 0:
                raise ParameterError(f"box {self.name!r}: rotation must be a 3x3 proper rotation matrix")
            object.__setattr__(self, "rotation", tuple(tuple(float(x) for x in row) for row in rot))

    @property
    def centre(self) -> np.ndarray:
        return (np.asarray(self.min_mm) + np.asarray(self.max_mm)) / 2

    @property
    def half_mm(self) -> np.ndarray:
        return (np.asarray(self.max_mm) - np.asarray(self.min_mm)) / 2

    @property
    def rotation_matrix(self) -> np.ndarray:
        return np.eye(3) if self.rotation is None else np.asarray(self.rotation, dtype=float)


@dataclass(frozen=True)
class CylinderFixture:
    """Solid cylinder: base disc centred at ``base_mm``, ``height_mm`` along ``axis`` (normalised
    here), radius ``radius_mm`` (part frame, mm)."""

    base_mm: tuple[float, float, float]
    axis: tuple[float, float, float]
    radius_mm: float
    height_mm: float
    name: str = "cylinder"
    kind: ClassVar[str] = "cylinder"

    def __post_init__(self):
        base = _vec3(self.base_mm, "cylinder base_mm")
        ax = np.asarray(_vec3(self.axis, "cylinder axis"))
        nrm = float(np.linalg.norm(ax))
        if not nrm > 1e-12:
            raise ParameterError(f"cylinder {self.name!r}: axis must be non-zero")
        object.__setattr__(self, "base_mm", base)
        object.__setattr__(self, "axis", tuple(float(x) for x in ax / nrm))
        object.__setattr__(self, "radius_mm", _positive(self.radius_mm, "cylinder radius_mm"))
        object.__setattr__(self, "height_mm", _positive(self.height_mm, "cylinder height_mm"))


def _closed(triangles: np.ndarray) -> bool:
    """True when every edge of the mesh is shared by exactly two triangles (no boundary)."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    e.sort(axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool(counts.size) and bool(np.all(counts == 2))


@dataclass(frozen=True, eq=False)
class MeshFixture:
    """Triangle mesh (part frame, mm): ``vertices`` (V,3), ``triangles`` (T,3) vertex indices.

    The triangles are the obstacle (FCL collides surfaces). With ``solid=True`` the mesh must be
    closed (every edge shared by two triangles) and its interior is an obstacle as well: a tool
    wholly inside it collides too (ray-casting test of one point per connected part of the tool).
    With ``solid=False`` a tool wholly inside a closed mesh is NOT detected."""

    vertices: np.ndarray
    triangles: np.ndarray
    name: str = "mesh"
    solid: bool = False
    kind: ClassVar[str] = "mesh"

    def __post_init__(self):
        v = np.array(self.vertices, dtype=float)
        tr = np.asarray(self.triangles)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 3:
            raise ParameterError(f"mesh {self.name!r}: vertices must be (V,3) with V >= 3, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ParameterError(f"mesh {self.name!r}: vertices must be finite")
        if tr.ndim != 2 or tr.shape[1] != 3 or tr.shape[0] == 0:
            raise ParameterError(f"mesh {self.name!r}: triangles must be (T,3) with T >= 1, got {tr.shape}")
        integral = np.issubdtype(tr.dtype, np.integer) or (
            np.issubdtype(tr.dtype, np.floating) and np.all(tr == np.round(tr)))
        if not integral:
            raise ParameterError(f"mesh {self.name!r}: triangles must be integer vertex indices")
        tr = np.array(tr, dtype=np.int64)
        if tr.min() < 0 or tr.max() >= v.shape[0]:
            raise ParameterError(f"mesh {self.name!r}: triangle index out of range")
        if self.solid and not _closed(tr):
            raise ParameterError(f"mesh {self.name!r}: solid=True needs a closed mesh (every edge in two triangles)")
        v.setflags(write=False)
        tr.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "triangles", tr)
        object.__setattr__(self, "solid", bool(self.solid))


@dataclass(frozen=True)
class TableFixture:
    """The machine table: the half-space ``z < z_mm`` of the part frame (everything below the
    table top). A tool touching the table top collides."""

    z_mm: float
    name: str = "table"
    kind: ClassVar[str] = "table"

    def __post_init__(self):
        try:
            z = float(self.z_mm)
        except (TypeError, ValueError):
            raise ParameterError(f"table z_mm must be a number, got {self.z_mm!r}") from None
        if not math.isfinite(z):
            raise ParameterError("table z_mm must be finite")
        object.__setattr__(self, "z_mm", z)


Fixture = BoxFixture | CylinderFixture | MeshFixture | TableFixture
_FIXTURE_TYPES = (BoxFixture, CylinderFixture, MeshFixture, TableFixture)


def load_mesh(path, *, units: float = 1.0, name: str | None = None,
              solid: bool | None = None) -> MeshFixture:
    """Read an STL, OBJ or PLY triangle mesh (Open3D) as a :class:`MeshFixture` in the part frame.

    ``units``: mm per file unit (1 for mm, 25.4 for inches, 1000 for metres). Duplicated
    vertices are merged. ``solid``: whether the interior is an obstacle; default: when the mesh
    is closed. Raises :class:`InputError` (code ``bad_fixture``) for a missing or unreadable
    file, an unknown extension, a mesh without triangles, non-finite vertices, or ``solid=True``
    with an open mesh; :class:`ParameterError` for a bad ``units``.
    """
    p = Path(path)
    scale = _positive(units, "units (mm per file unit)")
    if p.suffix.lower() not in _MESH_EXTENSIONS:
        raise InputError(f"fixture mesh {p.name}: unknown format {p.suffix or '(none)'!r}; "
                         f"use STL, OBJ or PLY", code="bad_fixture", path=str(p))
    if not p.is_file():
        raise InputError(f"fixture mesh {p} does not exist", code="bad_fixture", path=str(p))
    import open3d as o3d
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.io.read_triangle_mesh(str(p))
        mesh.remove_duplicated_vertices()
    v = np.asarray(mesh.vertices, dtype=float) * scale
    tr = np.asarray(mesh.triangles, dtype=np.int64)
    if tr.shape[0] == 0 or v.shape[0] < 3:
        raise InputError(f"fixture mesh {p.name}: no triangles could be read", code="bad_fixture",
                         path=str(p))
    if not np.all(np.isfinite(v)):
        raise InputError(f"fixture mesh {p.name}: non-finite vertex coordinates", code="bad_fixture",
                         path=str(p))
    if tr.min() < 0 or tr.max() >= v.shape[0]:
        raise InputError(f"fixture mesh {p.name}: triangle index out of range", code="bad_fixture",
                         path=str(p))
    closed = _closed(tr)
    if solid and not closed:
        raise InputError(f"fixture mesh {p.name} is not closed: it cannot be used as a solid",
                         code="bad_fixture", path=str(p))
    return MeshFixture(v, tr, name=name or p.stem, solid=closed if solid is None else bool(solid))


# ----------------------------------------------------------------------------------------------
# shared geometry

def _frame(t: np.ndarray) -> np.ndarray:
    """Proper rotation whose third column is the unit vector ``t`` (FCL's cylinder axis is local z)."""
    u, v = complete_basis(t)
    return np.column_stack([u, v, t])


def _collide(obj, tf, other) -> bool:
    obj.setTransform(tf)
    return fcl.collide(obj, other, _REQUEST, fcl.CollisionResult()) > 0


def _clip_slab(lo, hi, x, d, a0: float, a1: float):
    """Narrow the intervals ``[lo, hi]`` to the ``s`` with ``a0 <= x + s d <= a1`` (broadcasting)."""
    if np.ndim(d) == 0:
        if abs(d) <= 1e-12:
            return lo, np.where((x < a0) | (x > a1), -np.inf, hi)
        p, q = (a0 - x) / d, (a1 - x) / d
        if d < 0:
            p, q = q, p
        return np.maximum(lo, p), np.minimum(hi, q)
    flat = np.abs(d) <= 1e-12
    dd = np.where(flat, 1.0, d)
    p, q = (a0 - x) / dd, (a1 - x) / dd
    lo = np.where(flat, lo, np.maximum(lo, np.minimum(p, q)))
    hi = np.where(flat, np.where((x < a0) | (x > a1), -np.inf, hi), np.minimum(hi, np.maximum(p, q)))
    return lo, hi


def _clip_quad(lo, hi, A, B, Cq):
    """Narrow the intervals ``[lo, hi]`` to the ``s`` with ``A s^2 + 2 B s + Cq <= 0`` (A >= 0,
    broadcasting). Where ``A`` is ~0 the value at ``lo`` decides (a witness point)."""
    flat = A <= 1e-24
    AA = np.where(flat, 1.0, A)
    disc = B * B - AA * Cq
    sq = np.sqrt(np.maximum(disc, 0.0))
    lo2 = np.where(flat, lo, np.maximum(lo, (-B - sq) / AA))
    hi2 = np.where(flat, np.where(Cq + 2 * B * lo > 0, -np.inf, hi),
                   np.where(disc >= 0, np.minimum(hi, (-B + sq) / AA), -np.inf))
    return lo2, hi2


class _Finite:
    """A finite fixture prepared for the tests: its oriented bounding box ``b + Q y``,
    ``|y_k| <= e_k`` (exact for a box), the centres in that frame, the FCL object."""

    def __init__(self, f, centres: np.ndarray):
        self.fixture = f
        self.kind = f.kind
        self.solid = False
        if isinstance(f, BoxFixture):
            self.b, self.Q, self.e = f.centre, f.rotation_matrix, f.half_mm
            self.obj = fcl.CollisionObject(fcl.Box(*(2 * self.e)), fcl.Transform(self.Q, self.b))
        elif isinstance(f, CylinderFixture):
            ax = np.asarray(f.axis)
            self.Q = _frame(ax)
            self.b = np.asarray(f.base_mm) + ax * (f.height_mm / 2)
            self.e = np.array([f.radius_mm, f.radius_mm, f.height_mm / 2])
            self.obj = fcl.CollisionObject(fcl.Cylinder(f.radius_mm, f.height_mm),
                                           fcl.Transform(self.Q, self.b))
        else:
            lo, hi = f.vertices.min(axis=0), f.vertices.max(axis=0)
            self.b, self.Q, self.e = (lo + hi) / 2, np.eye(3), (hi - lo) / 2
            bvh = fcl.BVHModel()
            bvh.beginModel(f.vertices.shape[0], f.triangles.shape[0])
            bvh.addSubModel(f.vertices, f.triangles)
            bvh.endModel()
            self.obj = fcl.CollisionObject(bvh, fcl.Transform())
            self.solid = f.solid
            self._scene = None
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        pts = self.b + (corners * self.e) @ self.Q.T
        self.aabb = (pts.min(axis=0), pts.max(axis=0))
        # the 12 box edges: start vertex (box frame), direction index k, length 2 e_k
        starts, dirs = [], []
        for k in range(3):
            i, j = (k + 1) % 3, (k + 2) % 3
            for si in (-1.0, 1.0):
                for sj in (-1.0, 1.0):
                    v = np.zeros(3)
                    v[k], v[i], v[j] = -self.e[k], si * self.e[i], sj * self.e[j]
                    starts.append(v)
                    dirs.append(k)
        self.edge_start, self.edge_dir = np.array(starts), np.array(dirs)
        # centres in the box frame, one row per coordinate (3, n): column-wise numpy is fastest
        self.P = np.ascontiguousarray(((centres - self.b) @ self.Q).T)

    def far_for_all_axes(self, A: np.ndarray, segs, R: float) -> np.ndarray:
        """Bool per centre: the whole tool (ball and ``segs``) stays more than MARGIN_MM away from
        the bounding box for every axis of ``A``, proven along one of 26 fixed directions ``u``
        (faces, edges, corners of the box): the tool's extent along ``u`` from its ball centre,
        maximised over the axes, is below the gap between the centre and the box along ``u``."""
        U = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -1, 0], [1, 0, 1], [1, 0, -1],
                      [0, 1, 1], [0, 1, -1], [1, 1, 1], [1, 1, -1], [1, -1, 1], [-1, 1, 1]], float)
        U /= np.linalg.norm(U, axis=1, keepdims=True)
        U = np.concatenate([U, -U])                        # (26,3), box frame
        x = A @ (self.Q @ U.T)                             # (m,26): t . u
        reach = np.full(x.shape, R)
        side = np.sqrt(np.maximum(1.0 - x * x, 0.0))
        for lo, hi, r in segs:
            reach = np.maximum(reach, np.maximum(lo * x, hi * x) + r * side)
        S = reach.max(axis=0) if x.shape[0] else np.full(U.shape[0], -np.inf)
        half = np.abs(U) @ self.e                          # box half-width along u
        return ((-(U @ self.P)).T - half - S > MARGIN_MM).any(axis=1)

    def closest(self, X: np.ndarray, shrink: float = 0.0) -> np.ndarray:
        """Closest points (3,k), box frame, to ``X`` (3,k) of the solid (bounding box for a mesh)
        shrunk by ``shrink``."""
        e = self.e - shrink
        if self.kind == "cylinder":
            rho = np.hypot(X[0], X[1])
            s = np.minimum(1.0, e[0] / np.maximum(rho, 1e-300))
            return np.stack([X[0] * s, X[1] * s, np.clip(X[2], -e[2], e[2])])
        return np.clip(X, -e[:, None], e[:, None])

    def support(self, D: np.ndarray) -> np.ndarray:
        """Half-width (k,) of the solid (bounding box for a mesh) along unit directions ``D`` (3,k)."""
        e = self.e
        if self.kind == "cylinder":
            return e[2] * np.abs(D[2]) + e[0] * np.hypot(D[0], D[1])
        return e[0] * np.abs(D[0]) + e[1] * np.abs(D[1]) + e[2] * np.abs(D[2])

    def point_distance(self, P: np.ndarray) -> np.ndarray:
        """Distance from points (3,k), box frame, to the solid (to the bounding box for a mesh)."""
        if self.kind == "cylinder":
            radial = np.maximum(np.hypot(P[0], P[1]) - self.e[0], 0.0)
            return np.hypot(radial, np.maximum(np.abs(P[2]) - self.e[2], 0.0))
        g = np.maximum(np.abs(P) - self.e[:, None], 0.0)
        return np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])

    def inside(self, X: np.ndarray) -> np.ndarray:
        """Bool per point of ``X`` (k,3, part frame): inside a solid (closed) mesh, by ray casting."""
        out = np.zeros(X.shape[0], dtype=bool)
        sel = np.flatnonzero(np.all((X >= self.aabb[0]) & (X <= self.aabb[1]), axis=1))
        if sel.size == 0:
            return out
        import open3d as o3d
        if self._scene is None:
            self._scene = o3d.t.geometry.RaycastingScene()
            self._scene.add_triangles(o3d.core.Tensor(self.fixture.vertices.astype(np.float32)),
                                      o3d.core.Tensor(self.fixture.triangles.astype(np.uint32)))
        occ = self._scene.compute_occupancy(o3d.core.Tensor(X[sel].astype(np.float32)), nsamples=3)
        out[sel] = occ.numpy() > 0.5
        return out

    def line_inside(self, X0: np.ndarray, tau: np.ndarray, a0, a1) -> np.ndarray:
        """Bool per row: the line ``X0 + a tau`` (X0 (3,k), box frame), ``a0 <= a <= a1`` (scalars
        or (k,)), has a point in the box or cylinder shrunk by MARGIN_MM (exact clipping)."""
        lo = np.zeros(X0.shape[1]) + a0
        hi = np.zeros(X0.shape[1]) + a1
        e = self.e - MARGIN_MM
        for d in ((0, 1, 2) if self.kind == "box" else (2,)):
            lo, hi = _clip_slab(lo, hi, X0[d], tau[d], -e[d], e[d])
        if self.kind == "cylinder":           # |X0_xy + a tau_xy| <= radius - margin
            lo, hi = _clip_quad(lo, hi, tau[0] ** 2 + tau[1] ** 2, X0[0] * tau[0] + X0[1] * tau[1],
                                X0[0] ** 2 + X0[1] ** 2 - e[0] ** 2)
        return lo <= hi


class _AxisView:
    """One finite fixture seen along one tool axis ``t`` for a set of centres (box frame,
    ``tau = Q^T t``): the separating-axis quantities that do not depend on the segment."""

    def __init__(self, f: _Finite, t: np.ndarray, P: np.ndarray):
        self.f, self.P = f, P
        self.tau = tau = f.Q.T @ t
        self.abs_tau = np.abs(tau)
        self.sin = np.sqrt(np.maximum(1.0 - tau * tau, 0.0))    # |tau x e_k|
        p0, p1, p2 = P
        self.pt = p0 * tau[0] + p1 * tau[1] + p2 * tau[2]
        self.box_t = float(self.abs_tau @ f.e)                   # box half-width along t
        # axes tau x e_k: the projection of P is (P x tau)_k; box half-width sum_l e_l |(tau x e_k)_l|
        e, at = f.e, self.abs_tau
        cross = ((p1 * tau[2] - p2 * tau[1]), (p2 * tau[0] - p0 * tau[2]), (p0 * tau[1] - p1 * tau[0]))
        half = (e[1] * at[2] + e[2] * at[1], e[0] * at[2] + e[2] * at[0], e[0] * at[1] + e[1] * at[0])
        gx = None
        for k in range(3):
            if self.sin[k] > 1e-9:
                g = np.abs(cross[k]) * (1.0 / self.sin[k]) - half[k] / self.sin[k]
                gx = g if gx is None else np.maximum(gx, g)
        self.gx = np.full(P.shape[1], -np.inf) if gx is None else gx

    def subset(self, k: np.ndarray) -> _AxisView:
        v = object.__new__(_AxisView)
        v.__dict__.update(self.__dict__)
        v.P, v.pt, v.gx = self.P[:, k], self.pt[k], self.gx[k]
        return v

    # The segment tests below take lo, hi, r as scalars or as (k,) arrays, one per row.

    def free(self, lo, hi, r) -> np.ndarray:
        """Bool per row: cylinder ``lo..hi``, radius ``r`` is separated from the box by > MARGIN_MM
        along one of the axes e_k, t, t x e_k (exact support functions)."""
        mu, h = (lo + hi) / 2, (hi - lo) / 2
        tau, e = self.tau, self.f.e
        g = self.gx - r
        for k in range(3):
            g = np.maximum(g, np.abs(self.P[k] + mu * tau[k]) - (e[k] + h * self.abs_tau[k] + r * self.sin[k]))
        g = np.maximum(g, np.abs(self.pt + mu) - (self.box_t + h))
        return g > MARGIN_MM

    def closest_pair(self, lo, hi, r, iters: int = 5):
        """(free, hit) bools per row from alternating projections between the solid cylinder and
        the fixture, both shrunk by MARGIN_MM (closest points of each are cheap).

        If the shrunk solids overlap the iteration tends to a common point: a point of the
        shrunk cylinder found inside the shrunk fixture proves a hit. Otherwise it tends to the
        closest pair ``p``, ``y``; the direction ``y - p`` is tested with the exact support
        functions of both solids and proves "free" when the gap along it exceeds MARGIN_MM. Any
        direction is a valid separating test; a fitted one makes it tight for the vertex, edge
        and rim contacts the fixed axes miss."""
        f, P, tau = self.f, self.P, self.tau
        tc = tau[:, None]
        m = MARGIN_MM
        shrunk = (hi - lo > 2 * m) & (r > m)
        lo_s, hi_s, r_s = np.where(shrunk, lo + m, lo), np.where(shrunk, hi - m, hi), np.where(shrunk, r - m, r)

        def on_cylinder(X):
            v = X - P
            a = v[0] * tau[0] + v[1] * tau[1] + v[2] * tau[2]
            w = v - a * tc
            rho = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
            return P + np.clip(a, lo_s, hi_s) * tc + w * (np.minimum(rho, r_s) / np.maximum(rho, 1e-300))

        p = P + np.clip(-self.pt, lo_s, hi_s) * tc        # axis point nearest the fixture centre
        for _ in range(iters):
            p = on_cylinder(f.closest(p, m))
        d = f.closest(p, m) - p
        e = f.e - m
        if f.kind == "box":                                # p (in the shrunk cylinder) inside?
            hit = shrunk & np.all(np.abs(p) <= e[:, None], axis=0)
        elif f.kind == "cylinder":
            hit = shrunk & (np.abs(p[2]) <= e[2]) & (p[0] * p[0] + p[1] * p[1] <= e[0] * e[0])
        else:
            hit = np.zeros(P.shape[1], dtype=bool)
        nd = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        ok = nd > 1e-9
        d = d / np.where(ok, nd, 1.0)
        dt = d[0] * tau[0] + d[1] * tau[1] + d[2] * tau[2]
        mu, h = (lo + hi) / 2, (hi - lo) / 2
        M = P + mu * tc                                    # cylinder centre, fixture at the origin
        gap = (np.abs(d[0] * M[0] + d[1] * M[1] + d[2] * M[2]) - f.support(d)
               - h * np.abs(dt) - r * np.sqrt(np.maximum(1.0 - dt * dt, 0.0)))
        return ok & (gap > m) & ~hit, hit

    def hit(self, lo, hi, r) -> np.ndarray:
        """Bool per row: the cylinder surely overlaps the (box or cylinder) fixture by MARGIN_MM:
        one of 8 lines of the cylinder shrunk by MARGIN_MM (its axis, the generator facing the
        fixture centre, the 6 generators extreme along -+e_k) runs through the fixture shrunk by
        MARGIN_MM, or (box) a box edge runs through the shrunk cylinder. Exact line clipping."""
        P, tau = self.P, self.tau
        k = P.shape[1]
        if self.f.kind == "mesh" or k == 0:
            return np.zeros(k, dtype=bool)
        a0, a1 = lo + MARGIN_MM, hi - MARGIN_MM           # a0 > a1: empty, never a hit
        rad = np.maximum(r - MARGIN_MM, 0.0) + np.zeros(k)
        d = self.pt * tau[:, None] - P                      # from the axis towards the fixture centre
        nd = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        offsets = [np.zeros((3, k)), d * (rad / np.maximum(nd, 1e-300))]
        for j in range(3):                                  # generators reaching furthest along -+e_j
            g = -tau[j] * tau
            g[j] += 1.0
            ng = np.linalg.norm(g)
            if ng > 1e-9:
                g = g[:, None] * (rad / ng)
                offsets += [g, -g]
        L = len(offsets)
        X0 = (np.stack(offsets) + P[None]).transpose(1, 0, 2).reshape(3, -1)
        out = self.f.line_inside(X0, tau, np.tile(a0 + np.zeros(k), L),
                                 np.tile(a1 + np.zeros(k), L)).reshape(L, k).any(axis=0)
        if self.f.kind != "box":
            return out
        rest = np.flatnonzero(~out)
        if rest.size:                                       # a box edge through the cylinder
            f = self.f
            a0r, a1r, radr = (a0 + np.zeros(k))[rest], (a1 + np.zeros(k))[rest], rad[rest]
            X0 = f.edge_start[:, :, None] - P[None, :, rest]          # (12,3,k), from the centre
            xt = np.einsum("eck,c->ek", X0, tau)
            tk = tau[f.edge_dir][:, None]
            lo_s = np.zeros((12, rest.size))
            hi_s = np.broadcast_to((2 * f.e[f.edge_dir])[:, None], lo_s.shape)
            lo_s, hi_s = _clip_slab(lo_s, hi_s, xt, tk, a0r, a1r)
            xk = np.take_along_axis(X0, f.edge_dir[:, None, None], axis=1)[:, 0]
            lo_s, hi_s = _clip_quad(lo_s, hi_s, 1.0 - tk * tk, xk - xt * tk,
                                    np.einsum("eck,eck->ek", X0, X0) - xt * xt - radr * radr)
            out[rest] = (lo_s <= hi_s).any(axis=0)
        return out


class _Context:
    """Validated inputs, prepared fixtures and FCL tool objects shared by both methods."""

    def __init__(self, centres, axes, tool, fixtures, candidates):
        C = np.asarray(centres, dtype=np.float64)
        A = np.asarray(axes, dtype=np.float64)
        if C.ndim != 2 or C.shape[1] != 3:
            raise ParameterError(f"centres must be an (n,3) array, got shape {C.shape}")
        if A.ndim != 2 or A.shape[1] != 3:
            raise ParameterError(f"axes must be an (m,3) array, got shape {A.shape}")
        if not (np.all(np.isfinite(C)) and np.all(np.isfinite(A))):
            raise ParameterError("centres and axes must be finite")
        norms = np.linalg.norm(A, axis=1)
        if norms.size and np.abs(norms - 1.0).max() > 1e-6:
            raise ParameterError("axes must be unit vectors")
        self.C = np.ascontiguousarray(C)
        self.A = A / norms[:, None] if norms.size else A
        n, m = C.shape[0], A.shape[0]
        self.candidates = None
        if candidates is not None:
            cand = np.asarray(candidates)
            if cand.shape != (n, m):
                raise ParameterError(f"candidates must be ({n},{m}), got {cand.shape}")
            self.candidates = cand.astype(bool)

        if not isinstance(tool, ToolAssembly):
            raise ParameterError("tool must be a planning.geometry.tool.ToolAssembly")
        self.R = _positive(tool.radius_mm, "tool radius_mm")
        segs = []
        for s in tool.segments:
            lo, hi, r = float(s.lo_mm), None if s.hi_mm is None else float(s.hi_mm), float(s.radius_mm)
            if not (math.isfinite(lo) and math.isfinite(r) and (hi is None or math.isfinite(hi))):
                raise ParameterError("tool segments must be finite")
            if r > 0 and (hi is None or hi > lo):
                segs.append((lo, hi, r))         # an empty cylinder collides with nothing
        self.segs = segs

        if isinstance(fixtures, _FIXTURE_TYPES):
            fixtures = (fixtures,)
        fixtures = tuple(fixtures)
        for f in fixtures:
            if not isinstance(f, _FIXTURE_TYPES):
                raise ParameterError(f"unknown fixture {f!r}: use BoxFixture, CylinderFixture, "
                                     f"MeshFixture or TableFixture")
        self.tables = [f.z_mm for f in fixtures if isinstance(f, TableFixture)]
        self.finite = [_Finite(f, self.C) for f in fixtures if not isinstance(f, TableFixture)]

        # reach: beyond it along the axis no tool point can be in a finite fixture
        self.reach = 0.0
        if self.finite and n:
            lo = np.minimum.reduce([C.min(axis=0)] + [f.aabb[0] for f in self.finite])
            hi = np.maximum.reduce([C.max(axis=0)] + [f.aabb[1] for f in self.finite])
            self.reach = float(np.linalg.norm(hi - lo)) + 1.0
        self.fsegs = []                       # (lo, hi, r) capped at reach, for finite fixtures
        for lo, hi, r in segs:
            if hi is None:
                if lo >= self.reach:
                    continue
                hi = self.reach
            self.fsegs.append((lo, hi, r))
        # widest first: the holder is the likeliest to hit, a sure hit ends a pair's tests
        self.seg_order = sorted(range(len(self.fsegs)), key=lambda k: -self.fsegs[k][2])
        self.seg_arrays = tuple(np.array([s[i] for s in self.fsegs], dtype=float) for i in range(3))
        self.bounding_segment = (min(s[0] for s in self.fsegs), max(s[1] for s in self.fsegs),
                                 max(s[2] for s in self.fsegs)) if self.fsegs else None
        self._oriented = None
        self.sphere = fcl.CollisionObject(fcl.Sphere(self.R), fcl.Transform())
        self.fobjs = [fcl.CollisionObject(fcl.Cylinder(r, hi - lo), fcl.Transform())
                      for lo, hi, r in self.fsegs]
        # parts of the tool not connected to the ball: one axis point each (solid meshes)
        self.detached = []
        reach = self.R
        for lo, hi, r in sorted(self.fsegs):
            if lo > reach:
                self.detached.append((lo + hi) / 2)
            reach = max(reach, hi)

    def wanted(self, j: int | None = None) -> np.ndarray:
        n = self.C.shape[0]
        if self.candidates is None:
            return np.ones(n, dtype=bool)
        return self.candidates.any(axis=1) if j is None else self.candidates[:, j]

    def orient(self, j: int) -> None:
        """Turn every segment's FCL cylinder to axis ``j`` (does nothing when already there)."""
        if self._oriented != j:
            F = _frame(self.A[j])
            for o in self.fobjs:
                o.setRotation(F)
            self._oriented = j

    def seg_collides(self, k: int, centre: np.ndarray, t: np.ndarray, fobj) -> bool:
        """FCL: segment ``k`` (oriented by :meth:`orient`) at ball centre ``centre`` touches ``fobj``."""
        lo, hi, _ = self.fsegs[k]
        self.fobjs[k].setTranslation(centre + ((lo + hi) / 2) * t)
        return fcl.collide(self.fobjs[k], fobj, _REQUEST, fcl.CollisionResult()) > 0

    def detached_inside(self, f: _Finite, rows: np.ndarray, t: np.ndarray) -> np.ndarray:
        hit = np.zeros(rows.size, dtype=bool)
        for a in self.detached:
            hit |= f.inside(self.C[rows] + a * t)
        return hit


def _table_hits(zs, segs, R, cz: np.ndarray, t: np.ndarray, ball: bool) -> np.ndarray:
    """Exact: the ball (when ``ball``) or a segment reaches down to a table top, ``<=`` counts."""
    hit = np.zeros(cz.shape[0], dtype=bool)
    tz = float(t[2])
    sxy = math.sqrt(max(0.0, 1.0 - tz * tz))
    for z in zs:
        if ball:
            hit |= cz - R <= z
        for lo, hi, r in segs:
            if hi is None:
                if tz < 0:
                    hit[:] = True
                    return hit
                low = lo * tz
            else:
                low = min(lo * tz, hi * tz)
            hit |= cz + low - r * sxy <= z
    return hit


def _fixture_axis(ctx: _Context, f: _Finite, j: int, alive: np.ndarray, near: np.ndarray,
                  used_fcl: np.ndarray, st: dict) -> None:
    """Clear ``alive[i]`` for the centres whose tool along axis ``j`` collides with fixture ``f``
    (steps 3b-3e of the module docstring); ``near``: centres not ruled out by step 3a."""
    n, t = alive.size, ctx.A[j]
    cand = alive & near
    rows = np.flatnonzero(cand)
    if rows.size == 0:
        return
    lo_all, hi_all, r_all = ctx.bounding_segment
    if 4 * rows.size > n:                           # most rows: no gather for the first test
        view = _AxisView(f, t, f.P)
        und = np.flatnonzero(cand & ~view.free(lo_all, hi_all, r_all))
        view = view.subset(und)
    else:
        view = _AxisView(f, t, f.P[:, rows])
        k = np.flatnonzero(~view.free(lo_all, hi_all, r_all))
        und, view = rows[k], view.subset(k)
    if und.size == 0:
        return
    # (row, segment) pairs: proven free, surely hit (the row is done), or left to FCL. The widest
    # segments first (most hits end there), then the others for the rows not yet hit; each
    # group in one go (few numpy calls on long arrays).
    row_hit = np.zeros(und.size, dtype=bool)
    RR_all = ctx.seg_arrays[2]
    wide = np.flatnonzero(RR_all == RR_all.max())
    left_r, left_s = [], []
    for group in (wide, np.flatnonzero(RR_all != RR_all.max())):
        rows_g = np.flatnonzero(~row_hit)
        if group.size == 0 or rows_g.size == 0:
            continue
        ridx, sidx = np.repeat(rows_g, group.size), np.tile(group, rows_g.size)
        LO, HI, RR = (v[sidx] for v in ctx.seg_arrays)
        o = np.flatnonzero(~view.subset(ridx).free(LO, HI, RR))
        h = view.subset(ridx[o]).hit(LO[o], HI[o], RR[o])
        row_hit[ridx[o[h]]] = True
        left_r.append(ridx[o[~h]])
        left_s.append(sidx[o[~h]])
    ridx, sidx = (np.concatenate(v) if v else np.zeros(0, np.int64) for v in (left_r, left_s))
    keep = ~row_hit[ridx]
    ridx, sidx = ridx[keep], sidx[keep]
    if ridx.size:
        LO, HI, RR = (v[sidx] for v in ctx.seg_arrays)
        fr, h = view.subset(ridx).closest_pair(LO, HI, RR)
        row_hit[ridx[h]] = True
        keep = ~fr & ~h
        ridx, sidx = ridx[keep], sidx[keep]
    if ridx.size:                                   # FCL; a row stops at its first hit
        ctx.orient(j)
        used_fcl[und[ridx[~row_hit[ridx]]]] = True
        for k in ctx.seg_order:
            for row in ridx[sidx == k].tolist():
                if not row_hit[row]:
                    st["fcl_calls"] += 1
                    row_hit[row] = ctx.seg_collides(k, ctx.C[und[row]], t, f.obj)
    alive[und[row_hit]] = False


# ----------------------------------------------------------------------------------------------
# public API

def fixture_collision_free(centres, axes, tool: ToolAssembly, fixtures: Sequence[Fixture], *,
                           candidates=None, progress: Callable[[int, int], None] | None = None,
                           stats: dict | None = None) -> np.ndarray:
    """Bool (n, m): True where the tool assembly with ball centre ``centres[i]`` and axis
    ``axes[j]`` touches no fixture (Makki 2010 §2.2.4, tool and holder against the fixtures).

    ``centres`` (n,3) mm, part frame: ball centres (``c = p + R n`` for surface point ``p`` with
    unit normal ``n``). ``axes`` (m,3): unit tool axes, part frame, from the part towards the
    spindle. ``tool``: the ball (the whole solid ball counts) and the cutter, shank and holder
    cylinders of :class:`planning.geometry.tool.ToolAssembly`. ``fixtures``: :class:`BoxFixture`,
    :class:`CylinderFixture`, :class:`MeshFixture`, :class:`TableFixture` in the part frame.
    Touching counts as a collision. ``candidates`` (n,m) bool, optional: only these pairs are
    evaluated (the others are False). ``progress(done_axes, m)`` is called after each axis.
    ``stats``, optional dict, receives counters: ``pairs`` evaluated, ``pairs_fcl`` (pairs that
    needed at least one FCL call), ``fcl_calls`` and ``ball_fcl_calls`` (per centre).

    Same answer as :func:`brute_force_fixture_collision_free` (FCL on every pair), with numpy
    deciding every pair it can decide for sure (see the module docstring).
    """
    ctx = _Context(centres, axes, tool, fixtures, candidates)
    C, R = ctx.C, ctx.R
    n, m = C.shape[0], ctx.A.shape[0]
    st = {"pairs": 0, "pairs_fcl": 0, "fcl_calls": 0, "ball_fcl_calls": 0}
    out = np.zeros((n, m), dtype=bool)

    # 1. the ball, per centre
    ball = np.zeros(n, dtype=bool)
    rows = np.flatnonzero(ctx.wanted())
    if rows.size:
        ball[rows] = _table_hits(ctx.tables, (), R, C[rows, 2], np.array([0, 0, 1.0]), True)
    for f in ctx.finite:
        rows = rows[~ball[rows]]
        if rows.size == 0:
            break
        d = f.point_distance(f.P[:, rows])
        sure_hit = d < R - MARGIN_MM if f.kind != "mesh" else np.zeros(rows.size, dtype=bool)
        ball[rows[sure_hit]] = True
        for i in rows[~sure_hit & (d <= R + MARGIN_MM)]:
            st["ball_fcl_calls"] += 1
            ball[i] = _collide(ctx.sphere, fcl.Transform(C[i]), f.obj)
        if f.solid:
            rest = rows[~ball[rows]]
            ball[rest] = f.inside(C[rest])

    # 2-4. per axis: table (exact), then each finite fixture
    near = [~f.far_for_all_axes(ctx.A, ctx.fsegs, R) for f in ctx.finite] if ctx.fsegs else []
    for j in range(m):
        t = ctx.A[j]
        want = ctx.wanted(j)
        st["pairs"] += int(want.sum())
        alive = want & ~ball                        # bool (n,): not yet known to collide
        if ctx.tables and alive.any():
            alive &= ~_table_hits(ctx.tables, ctx.segs, R, C[:, 2], t, False)
        used_fcl = np.zeros(n, dtype=bool)
        for f, nf in zip(ctx.finite, near):
            _fixture_axis(ctx, f, j, alive, nf, used_fcl, st)
            if f.solid and ctx.detached:
                rows = np.flatnonzero(alive)
                alive[rows] = ~ctx.detached_inside(f, rows, t)
        st["pairs_fcl"] += int(used_fcl.sum())
        out[:, j] = alive
        if progress is not None:
            progress(j + 1, m)
    if stats is not None:
        stats.update(st)
    return out


def brute_force_fixture_collision_free(centres, axes, tool: ToolAssembly, fixtures: Sequence[Fixture], *,
                                       candidates=None,
                                       progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Reference for :func:`fixture_collision_free`: FCL on every pair, ball and every segment
    against every fixture (the table as ``fcl.Halfspace``, an unbounded segment cut per pair
    below the table when the axis points down). Same arguments and result; for small inputs."""
    ctx = _Context(centres, axes, tool, fixtures, candidates)
    C = ctx.C
    n, m = C.shape[0], ctx.A.shape[0]
    out = np.zeros((n, m), dtype=bool)
    tables = [fcl.CollisionObject(fcl.Halfspace(np.array([0.0, 0.0, 1.0]), z), fcl.Transform())
              for z in ctx.tables]
    inside = [f.inside(C) if f.solid else np.zeros(n, dtype=bool) for f in ctx.finite]
    for j in range(m):
        t = ctx.A[j]
        F = _frame(t)
        ctx.orient(j)
        want = ctx.wanted(j)
        det = [ctx.detached_inside(f, np.arange(n), t) if f.solid and ctx.detached
               else np.zeros(n, dtype=bool) for f in ctx.finite]
        for i in np.flatnonzero(want):
            c = C[i]
            hit = False
            for z, h in zip(ctx.tables, tables):
                hit = _collide(ctx.sphere, fcl.Transform(c), h)
                for lo, hi, r in ctx.segs:
                    if hit:
                        break
                    if hi is None:           # long enough to reach below the table top
                        down = (abs(c[2] - z) + r + 1.0) / max(-t[2], 1e-12) if t[2] < 0 else 0.0
                        hi = lo + max(1.0, ctx.reach, down)
                    obj = fcl.CollisionObject(fcl.Cylinder(r, hi - lo), fcl.Transform(F, c + ((lo + hi) / 2) * t))
                    hit = fcl.collide(obj, h, _REQUEST, fcl.CollisionResult()) > 0
                if hit:
                    break
            for q, f in enumerate(ctx.finite):
                if hit:
                    break
                hit = inside[q][i] or det[q][i] or _collide(ctx.sphere, fcl.Transform(c), f.obj)
                for k in range(len(ctx.fsegs)):
                    if hit:
                        break
                    hit = ctx.seg_collides(k, c, t, f.obj)
            out[i, j] = not hit
        if progress is not None:
            progress(j + 1, m)
    return out
