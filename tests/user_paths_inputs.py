"""Tiny parts of every input kind, and the light parameters, for tests/test_user_paths.py (issue 29):
the planner driven as a user drives it (``scanmill plan`` in a subprocess, ``POST /jobs``), with its
progress listener on, in every finishing mode, roughing on and off.

Each part is small enough that a whole plan (paths, posts, simulation) takes seconds, and each
plans as it is (no ``accept_small_part``): a half sphere of radius 20 mm as a point cloud with exact
normals (PLY) and without them (XYZ text), the upper half of a UV sphere as a mesh (STL, OBJ) and a
40 x 40 pixel relief image (PNG) of a round bump. Writers are the tests' own
(:mod:`service_fixtures`, :mod:`mesh_files`), not the readers under test.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
from mesh_files import image_bytes, obj_text, sphere_mesh, stl_binary

from planning.inputs.samples import half_sphere
from planning.report.files import write_ply

#: every finishing mode (schemas.params.FinishingParams.mode)
MODES = ("3+2", "5axis")
#: paths.roughing.enabled
ROUGHING = (True, False)
#: input kind -> file name of its part
KINDS = {"ply": "dome.ply", "stl": "dome.stl", "obj": "dome.obj", "png": "bump.png", "xyz": "dome.xyz"}

#: what keeps every plan tiny: coarse orientations, a coarse scallop and step-down, a coarse simulation
LIGHT = {
    "tool": {"diameter_mm": 6.0},
    "orientations": {"phi_step_deg": 30, "theta_step_deg": 60},
    "setups": {"max_setups": 1, "coverage": 0.7},
    "paths": {"finishing": {"scallop_mm": 0.5, "step_mm": 1.5, "tolerance_mm": 0.02},
              "roughing": {"step_down_mm": 6, "diameter_mm": 8}},
    "simulate": {"resolution_mm": 2.0},
}

#: per input kind, what it needs on top of LIGHT (how its normals are found, how it is read)
KIND_PARAMS = {
    "ply": {"normals": {"method": "input"}},
    "xyz": {},                                            # no normals in the file: sphere throwing
    "stl": {"normals": {"method": "facets"}, "input": {"mesh_sample_mm": 1.5}},
    "obj": {"normals": {"method": "facets"}, "input": {"mesh_sample_mm": 1.5}},
    "png": {"input": {"relief": {"size_mm": 40, "z_min_mm": 0, "z_max_mm": 8}, "mesh_sample_mm": 1.5},
            "normals": {"method": "facets"}},
}

RADIUS_MM = 20.0


def _merge(a: dict, b: dict) -> dict:
    out = copy.deepcopy(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else copy.deepcopy(v)
    return out


def parameters(kind: str, mode: str, roughing: bool) -> dict:
    """The plan configuration (docs/design.md names) of a case: LIGHT, the kind's own, the mode and
    the roughing setting."""
    p = _merge(LIGHT, KIND_PARAMS[kind])
    return _merge(p, {"paths": {"finishing": {"mode": mode}, "roughing": {"enabled": bool(roughing)}}})


def _dome_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The upper half (z >= 0) of a UV sphere of radius RADIUS_MM: vertices and outward triangles."""
    v, f = sphere_mesh(n_lat=12, n_lon=24, radius=RADIUS_MM)
    keep = (v[f][:, :, 2] >= -1e-9).all(axis=1)
    used = np.unique(f[keep])
    remap = np.full(v.shape[0], -1)
    remap[used] = np.arange(used.size)
    return v[used], remap[f[keep]]


def _bump(n_px: int = 40) -> np.ndarray:
    """(n, n) uint8: a round bump (a cosine cap) on a dark ground, brighter = higher."""
    yy, xx = np.mgrid[0:n_px, 0:n_px].astype(np.float64)
    r = np.hypot(xx - (n_px - 1) / 2, yy - (n_px - 1) / 2) / (0.4 * n_px)
    h = np.where(r < 1.0, 0.5 * (1.0 + np.cos(np.pi * np.minimum(r, 1.0))), 0.0)
    return np.round(40 + 200 * h).astype(np.uint8)


def write_part(kind: str, folder: Path) -> Path:
    """Write the part of input kind ``kind`` (KINDS) into ``folder``; return its path."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / KINDS[kind]
    if kind in ("ply", "xyz"):
        s = half_sphere(n_points=900, radius_mm=RADIUS_MM)
        if kind == "ply":
            write_ply(path, s.points, normals=s.normals, binary=True)
        else:
            path.write_text("# x y z, mm\n" + "\n".join(f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in s.points) + "\n")
    elif kind == "stl":
        path.write_bytes(stl_binary(*_dome_mesh()))
    elif kind == "obj":
        path.write_bytes(obj_text(*_dome_mesh()))
    elif kind == "png":
        path.write_bytes(image_bytes(_bump()))
    else:
        raise ValueError(kind)
    return path
