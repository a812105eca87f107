"""What the finishing surface costs (issue 18): a plan on triangles against the same plan on points, in one
process, and what the density guard adds to every plan.

Cases (each planned twice after a warm-up plan that compiles the kernels; the paths stage is timed):

* ``sphere.stl``: a UV sphere of radius 25 mm (960 triangles) read as binary STL, facet normals, points
  laid on its facets 0.5 mm apart; ``paths.surface = points`` against ``auto`` (its triangles);
* ``sparse``: the 1.5 mm jittered grid on z = 2 sin(x/20) cos(y/20) of tests/test_density_guard.py
  (1,681 points), tool R 3; ``points`` against ``auto`` (Delaunay triangles through the points), and how
  deep each plan's finishing moves come into the true analytic surface (the test's Newton projection);

and the guard's own cost on the femur-like 1M cloud: the spacing estimate (``point_spacing_mm``).

    .venv/bin/python bench/bench_surface.py [--repeat 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from mesh_files import sphere_mesh, stl_binary  # noqa: E402
from test_density_guard import R, _every, distance_to_true_surface, sparse_surface  # noqa: E402

from planning.inputs import Cloud  # noqa: E402
from planning.inputs.cloud import read_input  # noqa: E402
from planning.pipeline import run_plan  # noqa: E402
from planning.toolpath.moves import densify  # noqa: E402
from planning.toolpath.surface import point_spacing_mm, reconstruct  # noqa: E402
from schemas.params import parse_config  # noqa: E402


def _cases():
    V, F = sphere_mesh(n_lat=16, n_lon=32, radius=25.0)
    sphere_cfg = {"tool": {"diameter_mm": 6.0}, "visibility": {"cone_deg": [10, 80]}, "normals": {"method": "facets"},
                  "setups": {"coverage": 0.85, "max_setups": 5}, "paths": {"roughing": {"enabled": False}},
                  "simulate": {"enabled": False}}
    sphere = read_input(stl_binary(V, F), parse_config(sphere_cfg).input, fmt="stl")
    pts, nrm = sparse_surface()
    sparse_cfg = {"tool": {"diameter_mm": 6.0}, "normals": {"method": "input"}, "visibility": {"cone_deg": [0, 60]},
                  "setups": {"coverage": 0.9, "max_setups": 1},
                  "paths": {"roughing": {"enabled": False}, "carry_stock": False,
                            "finishing": {"scallop_mm": 0.05}}, "simulate": {"enabled": False}}
    sparse = Cloud(points=pts, normals=nrm, source_format="bench")
    return [("sphere.stl", sphere, sphere_cfg), ("sparse", sparse, sparse_cfg)]


def _paths_seconds(cloud, cfg, surface):
    config = parse_config({**cfg, "paths": {**cfg["paths"], "surface": surface}})
    out = run_plan(cloud, config)
    t = {x.stage: x.seconds for x in out.result.timings}
    return t.get("paths", float("nan")), out.result.paths_surface, out


def _depth_into_true_surface(out) -> float:
    """How far the sparse case's finishing moves come into z = f(x, y) beyond R, mm (inside the patch)."""
    c = []
    for ap in out.extra["area_paths"]:
        xyz, _ = densify(ap.finishing, 0.05)
        c.append(ap.frame.to_part(_every(xyz, 0.05)))
    c = np.concatenate(c)
    c = c[(np.abs(c[:, 0]) < 30 - R) & (np.abs(c[:, 1]) < 30 - R)]
    return float(R - distance_to_true_surface(c).min())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    print(f"load {os.getloadavg()[0]:.1f}; paths stage seconds, min of {args.repeat} runs after a warm-up")
    print(f"{'case':12s} {'points':>7s} {'surface':14s} {'triangles':>9s} {'spacing mm':>10s} {'paths s':>8s} "
          f"{'ratio':>6s} {'into true surface mm':>21s}")
    for name, cloud, cfg in _cases():
        base = None
        for surface in ("points", "auto"):
            _paths_seconds(cloud, cfg, surface)                           # compile
            runs = [_paths_seconds(cloud, cfg, surface) for _ in range(args.repeat)]
            sec = min(r[0] for r in runs)
            ps, out = runs[0][1], runs[0][2]
            base = sec if base is None else base
            depth = f"{_depth_into_true_surface(out):21.4f}" if name == "sparse" else f"{'':>21s}"
            print(f"{name:12s} {out.points.shape[0]:7d} {ps.kind:14s} {ps.n_triangles:9d} {ps.spacing_mm:10.3f} "
                  f"{sec:8.2f} {sec / base:6.2f} {depth}")
        if name == "sparse":
            t0 = time.perf_counter()
            reconstruct(cloud.points, point_spacing_mm(cloud.points))
            print(f"{'':12s} reconstruction alone (spacing estimate and Delaunay): {time.perf_counter() - t0:.3f} s")
    from planning.inputs.samples import make_sample
    femur = make_sample("femur_like", n_points=1_000_000).points
    point_spacing_mm(femur)
    t = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        s = point_spacing_mm(femur)
        t.append(time.perf_counter() - t0)
    print(f"femur-like 1M: spacing {s:.3f} mm (points: under 0.6 mm for R 3), estimate {min(t):.2f} s")


if __name__ == "__main__":
    main()
