"""Stage 1, reference samples: prismatic parts with known answers (not cases of the paper), in mm.

:func:`slot`: a block with a straight slot (or a closed pocket) cut in its top, whose floor is
reachable only by tool axes near the slot's vertical plane (:func:`slot_floor_max_tilt_deg`, deg).
:func:`post_wall`: a plate with a cylindrical post standing a known gap away from a wall. Both
stand on the table (z = 0), centred in x and y. Their planar faces, cylinder sides and disks
(:class:`_Face`) are sampled on jittered grids (one uniform random point per cell of
1/sqrt(density) mm), with exact normals and optional Gaussian noise along the normal; the face of
each point is in ``meta["labels"]``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planning.errors import ParameterError
from planning.inputs.samples.common import (
    Sample,
    _check_float,
    _check_int,
    _check_seed,
    _check_size,
)

__all__ = ["draft_slot", "post_wall", "slot", "slot_floor_max_tilt_deg"]


@dataclass(frozen=True)
class _Face:
    """A planar rectangle origin + u du + v dv (u in [0, lu], v in [0, lv]) with outward normal,
    less the points for which ``hole(points)`` is true; or a cylinder side / disk (``kind``)."""

    label: str
    kind: str                       # "rect", "cylinder" (side, normal radial) or "disk"
    origin: tuple
    du: tuple = (1.0, 0.0, 0.0)
    dv: tuple = (0.0, 1.0, 0.0)
    lu: float = 0.0                 # rect: lengths; cylinder: radius, height; disk: radius
    lv: float = 0.0
    normal: tuple = (0.0, 0.0, 1.0)
    hole: Callable | None = None
    hole_area: float = 0.0

    @property
    def area(self) -> float:
        if self.kind == "cylinder":
            return 2.0 * math.pi * self.lu * self.lv
        if self.kind == "disk":
            return math.pi * self.lu**2
        return self.lu * self.lv - self.hole_area


def _jitter_grid(rng, lu, lv, spacing):
    """One uniform random point per cell of a grid of about ``spacing`` over [0, lu] x [0, lv]."""
    nu, nv = max(1, round(lu / spacing)), max(1, round(lv / spacing))
    i, j = np.divmod(np.arange(nu * nv), nv)
    return (i + rng.random(i.size)) * (lu / nu), (j + rng.random(j.size)) * (lv / nv)


def _sample_faces(faces, rng, spacing):
    pts, nrm, lab = [], [], []
    for li, f in enumerate(faces):
        if f.kind == "rect":
            u, v = _jitter_grid(rng, f.lu, f.lv, spacing)
            p = np.asarray(f.origin) + u[:, None] * np.asarray(f.du) + v[:, None] * np.asarray(f.dv)
            n = np.broadcast_to(np.asarray(f.normal, float), p.shape)
        elif f.kind == "cylinder":        # axis +Z through origin (the bottom centre)
            ph, z = _jitter_grid(rng, 2.0 * math.pi * f.lu, f.lv, spacing)
            ph = ph / f.lu
            n = np.column_stack((np.cos(ph), np.sin(ph), np.zeros_like(ph)))
            p = np.asarray(f.origin) + f.lu * n + z[:, None] * np.array([0.0, 0.0, 1.0])
        else:                             # disk of radius lu about origin, normal +-Z
            u, v = _jitter_grid(rng, 2.0 * f.lu, 2.0 * f.lu, spacing)
            u, v = u - f.lu, v - f.lu
            inside = u * u + v * v < f.lu**2
            p = np.asarray(f.origin) + np.column_stack((u[inside], v[inside], np.zeros(inside.sum())))
            n = np.broadcast_to(np.asarray(f.normal, float), p.shape)
        if f.hole is not None:
            keep = ~f.hole(p)
            p, n = p[keep], n[keep]
        pts.append(p)
        nrm.append(np.array(n, dtype=np.float64))
        lab.append(np.full(p.shape[0], li))
    return np.vstack(pts), np.vstack(nrm), np.concatenate(lab)


def _finish_prismatic(name, faces, label_names, *, density, n_points, noise_mm, seed, description,
                      meta):
    """Sample ``faces`` at ``density`` (or about ``n_points`` in all), add normal noise, pack."""
    area = float(sum(f.area for f in faces))
    if n_points is not None:
        n_req = _check_int("n_points", n_points, 10, 20_000_000)
        density = n_req / area
    else:
        density = _check_float("density_per_mm2", density, 0.0, 1000.0, unit="points/mm^2")
    sigma = _check_float("noise_mm", noise_mm, 0.0, 5.0, lo_open=False)
    seed = _check_seed(seed)
    if area * density > 20_000_000:
        raise ParameterError(f"{name}: {area * density:.3g} points requested, at most 2e7",
                             parameter="density_per_mm2", value=density, allowed="<= 2e7 points")
    rng = np.random.default_rng(seed)
    points, normals, face = _sample_faces(faces, rng, 1.0 / math.sqrt(density))
    if sigma > 0:
        points = points + rng.normal(0.0, sigma, points.shape[0])[:, None] * normals
    names = tuple(label_names)
    labels = np.array([names.index(f.label) for f in faces], dtype=np.int8)[face]
    meta = dict(meta)
    meta.update({"density_per_mm2": density, "area_mm2": area, "noise_mm": sigma, "seed": seed,
                 "labels": labels, "label_names": names})
    return Sample(name=name, points=points, normals=normals, description=description, meta=meta)


def _box_faces(x0, x1, y0, y1, z0, z1, *, label, bottom, skip=(), holes=None):
    """The side faces (and the bottom if asked) of an axis-aligned box, outward normals.
    ``skip``: face keys among "-x", "+x", "-y", "+y", "+z" left out. ``holes``: key -> (fn, area)."""
    holes = holes or {}
    spec = {
        "-x": ((x0, y0, z0), (0, 1, 0), (0, 0, 1), y1 - y0, z1 - z0, (-1, 0, 0)),
        "+x": ((x1, y0, z0), (0, 1, 0), (0, 0, 1), y1 - y0, z1 - z0, (1, 0, 0)),
        "-y": ((x0, y0, z0), (1, 0, 0), (0, 0, 1), x1 - x0, z1 - z0, (0, -1, 0)),
        "+y": ((x0, y1, z0), (1, 0, 0), (0, 0, 1), x1 - x0, z1 - z0, (0, 1, 0)),
        "+z": ((x0, y0, z1), (1, 0, 0), (0, 1, 0), x1 - x0, y1 - y0, (0, 0, 1)),
        "-z": ((x0, y0, z0), (1, 0, 0), (0, 1, 0), x1 - x0, y1 - y0, (0, 0, -1)),
    }
    keys = ["-x", "+x", "-y", "+y", "+z"] + (["-z"] if bottom else [])
    faces = []
    for k in keys:
        if k in skip:
            continue
        o, du, dv, lu, lv, nn = spec[k]
        hole, hole_area = holes.get(k, (None, 0.0))
        faces.append(_Face("bottom" if k == "-z" else label[k] if isinstance(label, dict) else label,
                           "rect", tuple(map(float, o)), tuple(map(float, du)), tuple(map(float, dv)),
                           float(lu), float(lv), tuple(map(float, nn)), hole, hole_area))
    return faces


def slot(size_mm: tuple = (80.0, 60.0, 30.0), slot_width_mm: float = 12.0, slot_depth_mm: float = 15.0,
         slot_length_mm: float | None = None, density_per_mm2: float = 1.0, n_points: int | None = None,
         noise_mm: float = 0.0, seed: int = 0, include_bottom: bool = False) -> Sample:
    """A rectangular block with a straight slot (or a closed pocket) cut in its top.

    Frame (mm): block x in [-X/2, X/2], y in [-Y/2, Y/2], z in [0, Z] with ``size_mm = (X, Y, Z)``
    (default 80 x 60 x 30, top at z = 30), standing on the table (z = 0). The slot runs along +Y,
    centred on x = 0: x in [-w/2, w/2] with w = ``slot_width_mm`` (12), from the top down to the
    floor at z = Z - h, h = ``slot_depth_mm`` (15). ``slot_length_mm`` None: a through slot open at
    both ends (y = +-Y/2); a length L < Y: a closed pocket y in [-L/2, L/2] with two end walls.

    Sampled faces (``meta["labels"]`` indexes ``meta["label_names"]``): ``top`` (+Z), ``slot_floor``
    (+Z), ``slot_wall`` (the wall at x = -w/2 faces +X, the one at +w/2 faces -X), ``pocket_end_wall``
    (pocket only), ``side`` (the four outer walls, notched by a through slot), and ``bottom`` (-Z,
    only with ``include_bottom``: a part on the table is not scanned there). A jittered grid gives
    one point per cell of 1/sqrt(density) mm: uniform ``density_per_mm2`` (1 by default), or about
    ``n_points`` in all when given. Normals are exact; ``noise_mm`` > 0 adds Gaussian noise along
    the normal (none by default).

    Known answer (not a case in the paper): the floor is reachable only by tool axes near the
    slot's vertical plane. For a ball-end mill of radius R (cylindrical shank, no holder) touching
    the floor on the slot's centre line, the shank clears the slot's top edges while the axis tilts
    about Y by at most :func:`slot_floor_max_tilt_deg` = atan2(w/2, h - R) - asin(R / sqrt((w/2)^2
    + (h - R)^2)) (13.6 deg for w 12, h 15, R 3), and the floor cannot be reached at all if 2R > w;
    tilting along the slot (about X) is unlimited for a through slot.
    ``meta``: ``kind``, ``size_mm``, ``top_z_mm``, ``slot_width_mm``, ``slot_depth_mm``,
    ``floor_z_mm``, ``slot_length_mm``, ``slot_axis``, ``slot_centre_x_mm``, ``density_per_mm2``,
    ``area_mm2``, ``labels``, ``label_names``, ``noise_mm``, ``seed``.
    """
    X, Y, Z = _check_size("size_mm", size_mm, 3)
    w = _check_float("slot_width_mm", slot_width_mm, 0.0, X - 1e-6)
    h = _check_float("slot_depth_mm", slot_depth_mm, 0.0, Z - 1e-6)
    through = slot_length_mm is None
    L = Y if through else _check_float("slot_length_mm", slot_length_mm, 0.0, Y - 1e-6)
    zf = Z - h
    names = ["top", "slot_floor", "slot_wall", "pocket_end_wall", "side", "bottom"]
    if through:
        def notch(p):
            return (np.abs(p[:, 0]) < 0.5 * w) & (p[:, 2] > zf)
        faces = _box_faces(-X / 2, X / 2, -Y / 2, Y / 2, 0.0, Z, label="side", bottom=include_bottom,
                           skip=("+z",), holes={"-y": (notch, w * h), "+y": (notch, w * h)})
        faces += [
            _Face("top", "rect", (-X / 2, -Y / 2, Z), lu=X / 2 - w / 2, lv=Y),
            _Face("top", "rect", (w / 2, -Y / 2, Z), lu=X / 2 - w / 2, lv=Y),
        ]
    else:
        def opening(p):
            return (np.abs(p[:, 0]) < 0.5 * w) & (np.abs(p[:, 1]) < 0.5 * L)
        faces = _box_faces(-X / 2, X / 2, -Y / 2, Y / 2, 0.0, Z, label="side", bottom=include_bottom,
                           skip=("+z",))
        faces += [
            _Face("top", "rect", (-X / 2, -Y / 2, Z), lu=X, lv=Y, hole=opening, hole_area=w * L),
            _Face("pocket_end_wall", "rect", (-w / 2, -L / 2, zf), (1, 0, 0), (0, 0, 1), w, h, (0, 1, 0)),
            _Face("pocket_end_wall", "rect", (-w / 2, L / 2, zf), (1, 0, 0), (0, 0, 1), w, h, (0, -1, 0)),
        ]
    faces += [
        _Face("slot_floor", "rect", (-w / 2, -L / 2, zf), lu=w, lv=L),
        _Face("slot_wall", "rect", (-w / 2, -L / 2, zf), (0, 1, 0), (0, 0, 1), L, h, (1, 0, 0)),
        _Face("slot_wall", "rect", (w / 2, -L / 2, zf), (0, 1, 0), (0, 0, 1), L, h, (-1, 0, 0)),
    ]
    kind = "through_slot" if through else "pocket"
    return _finish_prismatic(
        "slot", faces, names, density=density_per_mm2, n_points=n_points, noise_mm=noise_mm, seed=seed,
        description=(f"block {X:g} x {Y:g} x {Z:g} mm with a {'through slot' if through else 'pocket'} "
                     f"{w:g} mm wide, {h:g} mm deep along Y (floor at z = {zf:g}), exact normals"),
        meta={"kind": kind, "size_mm": (X, Y, Z), "top_z_mm": Z, "slot_width_mm": w,
              "slot_depth_mm": h, "floor_z_mm": zf, "slot_length_mm": L, "slot_axis": (0.0, 1.0, 0.0),
              "slot_centre_x_mm": 0.0},
    )


def slot_floor_max_tilt_deg(slot_width_mm: float, slot_depth_mm: float, tool_radius_mm: float) -> float:
    """Largest tilt (deg, about the slot axis) of a ball-end mill touching the floor of a slot on
    its centre line, before its cylindrical shank (radius R, no holder) meets a top edge:
    atan2(w/2, h - R) - asin(R / sqrt((w/2)^2 + (h - R)^2)), at most 90. NaN when the ball does
    not fit in the slot (2R > w); 0 when it just fits (2R = w). See :func:`slot`."""
    w2 = 0.5 * float(slot_width_mm)
    h, r = float(slot_depth_mm), float(tool_radius_mm)
    if r > w2:
        return float("nan")
    rho = math.hypot(w2, h - r)
    return min(90.0, math.degrees(math.atan2(w2, h - r) - math.asin(r / rho)))


def draft_slot(size_mm: tuple = (60.0, 40.0, 30.0), floor_width_mm: float = 8.0, slot_depth_mm: float = 15.0,
               wall_deg: float = 70.0, density_per_mm2: float = 1.0, n_points: int | None = None,
               noise_mm: float = 0.0, seed: int = 0, include_sides: bool = True) -> Sample:
    """A block with a deep, narrow through slot whose walls lean outwards (a draft), for simultaneous
    5-axis finishing (issue 19).

    Frame (mm): block x in [-X/2, X/2], y in [-Y/2, Y/2], z in [0, Z] (default 60 x 40 x 30). The slot
    runs along +Y; its floor (normal +Z) is ``floor_width_mm`` wide (8) at depth ``slot_depth_mm``
    (15) below the top; its two walls rise from the floor's edges at ``wall_deg`` (70) from the
    horizontal to the top, so the wall at -x faces (sin a, 0, cos a) and the one at +x faces
    (-sin a, 0, cos a), a = ``wall_deg``. Faces (``meta["labels"]``): ``top``, ``slot_floor``,
    ``slot_wall``, ``side`` (no bottom: it stands on the table; no sides either with ``include_sides``
    False: a scan of the top only). Sampling as :func:`slot`.

    Known answer: the floor's normal and the two walls' normals are 2a apart around the slot's
    cross-section, so with a tool cone [v1, v2] about the normal no single fixed tool axis lies in
    the cone of the floor and of both walls once v2 < a (the walls need the axis at least a - v2
    from vertical towards each of them); the ball dropping straight down the slot touches all three
    (the walls lean out), so one pass direction can finish the slot if the axis may change per
    position.
    """
    X, Y, Z = _check_size("size_mm", size_mm, 3)
    wf = _check_float("floor_width_mm", floor_width_mm, 0.0, X - 1e-6)
    h = _check_float("slot_depth_mm", slot_depth_mm, 0.0, Z - 1e-6)
    a = math.radians(_check_float("wall_deg", wall_deg, 10.0, 90.0, unit="deg"))
    run = h / math.tan(a)
    wt = wf + 2.0 * run
    if wt >= X:
        raise ParameterError(f"draft_slot: the slot is {wt:.3g} mm wide at the top, wider than the block",
                             parameter="wall_deg", value=wall_deg, allowed="a steeper wall or a wider block")
    zf = Z - h

    def notch(p):
        return (p[:, 2] > zf) & (np.abs(p[:, 0]) < 0.5 * wf + (p[:, 2] - zf) / math.tan(a))

    names = ["top", "slot_floor", "slot_wall", "side"]
    faces = _box_faces(-X / 2, X / 2, -Y / 2, Y / 2, 0.0, Z, label="side", bottom=False, skip=("+z",),
                       holes={"-y": (notch, 0.5 * h * (wf + wt)), "+y": (notch, 0.5 * h * (wf + wt))}) \
        if include_sides else []
    lw = h / math.sin(a)
    ca, sa = math.cos(a), math.sin(a)
    faces += [
        _Face("top", "rect", (-X / 2, -Y / 2, Z), lu=X / 2 - wt / 2, lv=Y),
        _Face("top", "rect", (wt / 2, -Y / 2, Z), lu=X / 2 - wt / 2, lv=Y),
        _Face("slot_floor", "rect", (-wf / 2, -Y / 2, zf), lu=wf, lv=Y),
        _Face("slot_wall", "rect", (-wf / 2, -Y / 2, zf), (0.0, 1.0, 0.0), (-ca, 0.0, sa), Y, lw, (sa, 0.0, ca)),
        _Face("slot_wall", "rect", (wf / 2, -Y / 2, zf), (0.0, 1.0, 0.0), (ca, 0.0, sa), Y, lw, (-sa, 0.0, ca)),
    ]
    return _finish_prismatic(
        "draft_slot", faces, names, density=density_per_mm2, n_points=n_points, noise_mm=noise_mm, seed=seed,
        description=(f"block {X:g} x {Y:g} x {Z:g} mm with a through slot {wf:g} mm wide at its floor, {h:g} mm "
                     f"deep, walls at {math.degrees(a):g} deg (top width {wt:.3g} mm), exact normals"),
        meta={"kind": "draft_slot", "size_mm": (X, Y, Z), "top_z_mm": Z, "floor_width_mm": wf,
              "slot_depth_mm": h, "wall_deg": math.degrees(a), "top_width_mm": wt, "floor_z_mm": zf,
              "slot_axis": (0.0, 1.0, 0.0)},
    )


def post_wall(post_radius_mm: float = 5.0, post_height_mm: float = 30.0, gap_mm: float = 8.0,
              wall_height_mm: float = 40.0, wall_thickness_mm: float = 10.0,
              plate_size_mm: tuple = (100.0, 60.0, 10.0), density_per_mm2: float = 1.0,
              n_points: int | None = None, noise_mm: float = 0.0, seed: int = 0,
              include_bottom: bool = False) -> Sample:
    """A base plate with a cylindrical post standing a known gap away from a wall.

    Frame (mm): plate x in [-PX/2, PX/2], y in [-PY/2, PY/2], z in [0, T] with ``plate_size_mm =
    (PX, PY, T)`` (default 100 x 60 x 10), standing on the table (z = 0). The post (radius R =
    ``post_radius_mm``, 5) stands on the plate with its axis the line x = y = 0, from z = T up to
    T + ``post_height_mm`` (40 by default). The wall runs along Y over the whole plate width, from
    x = R + gap (``gap_mm``, 8: the face at x = 13 faces the post) to R + gap + ``wall_thickness_mm``
    (23), from z = T up to T + ``wall_height_mm`` (50). The gap between the post and the wall
    (x in [R, R + gap]) is reachable only by tools thinner than the gap, with axes near vertical.

    Sampled faces (``meta["labels"]`` indexes ``meta["label_names"]``): ``plate_top`` (+Z, less the
    post and wall footprints), ``plate_side``, ``post_side`` (radial normals), ``post_top``,
    ``wall_front`` (-X, facing the post), ``wall_back`` (+X), ``wall_top``, ``wall_end`` (+-Y),
    ``bottom`` (only with ``include_bottom``). Jittered grid at ``density_per_mm2`` (1) or about
    ``n_points`` in all; exact normals; optional Gaussian ``noise_mm`` along the normal.
    ``meta``: the dimensions above as ``plate_size_mm``, ``plate_top_z_mm``, ``post_centre_xy_mm``,
    ``post_radius_mm``, ``post_height_mm``, ``post_top_z_mm``, ``gap_mm``, ``wall_face_x_mm``,
    ``wall_thickness_mm``, ``wall_height_mm``, ``wall_top_z_mm``, plus ``labels``, ``label_names``,
    ``density_per_mm2``, ``area_mm2``, ``noise_mm``, ``seed``.
    """
    PX, PY, T = _check_size("plate_size_mm", plate_size_mm, 3)
    R = _check_float("post_radius_mm", post_radius_mm, 0.0, 0.5 * min(PX, PY) - 1e-6)
    Hp = _check_float("post_height_mm", post_height_mm, 0.0, 1e4)
    gap = _check_float("gap_mm", gap_mm, 0.0, 1e4)
    Hw = _check_float("wall_height_mm", wall_height_mm, 0.0, 1e4)
    Tw = _check_float("wall_thickness_mm", wall_thickness_mm, 0.0, 1e4)
    wx0, wx1 = R + gap, R + gap + Tw
    if wx1 > PX / 2 + 1e-9:
        raise ParameterError(
            f"post_wall: the wall (x from {wx0:g} to {wx1:g} mm) overhangs the plate (x <= {PX / 2:g} mm); "
            f"make plate_size_mm[0] at least {2 * wx1:g} or reduce gap_mm / wall_thickness_mm",
            parameter="plate_size_mm", value=PX, allowed=f">= {2 * wx1:g}")
    names = ["plate_top", "plate_side", "post_side", "post_top", "wall_front", "wall_back", "wall_top",
             "wall_end", "bottom"]

    def footprints(p):
        return (p[:, 0] ** 2 + p[:, 1] ** 2 < R * R) | ((p[:, 0] > wx0) & (p[:, 0] < wx1))

    faces = _box_faces(-PX / 2, PX / 2, -PY / 2, PY / 2, 0.0, T, bottom=include_bottom,
                       label={"-x": "plate_side", "+x": "plate_side", "-y": "plate_side",
                              "+y": "plate_side", "+z": "plate_top"},
                       holes={"+z": (footprints, math.pi * R * R + Tw * PY)})
    faces += _box_faces(wx0, wx1, -PY / 2, PY / 2, T, T + Hw, bottom=False,
                        label={"-x": "wall_front", "+x": "wall_back", "-y": "wall_end",
                               "+y": "wall_end", "+z": "wall_top"})
    faces += [
        _Face("post_side", "cylinder", (0.0, 0.0, T), lu=R, lv=Hp),
        _Face("post_top", "disk", (0.0, 0.0, T + Hp), lu=R, normal=(0.0, 0.0, 1.0)),
    ]
    return _finish_prismatic(
        "post_wall", faces, names, density=density_per_mm2, n_points=n_points, noise_mm=noise_mm,
        seed=seed,
        description=(f"plate {PX:g} x {PY:g} x {T:g} mm, post R {R:g} x {Hp:g} mm high {gap:g} mm from "
                     f"a wall {Hw:g} mm high, {Tw:g} mm thick, exact normals"),
        meta={"plate_size_mm": (PX, PY, T), "plate_top_z_mm": T, "post_centre_xy_mm": (0.0, 0.0),
              "post_radius_mm": R, "post_height_mm": Hp, "post_top_z_mm": T + Hp, "gap_mm": gap,
              "wall_face_x_mm": wx0, "wall_thickness_mm": Tw, "wall_height_mm": Hw,
              "wall_top_z_mm": T + Hw},
    )
