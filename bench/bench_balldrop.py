"""Ball-drop benchmark (issue 5): CL points per second of scanmill's point-based ball drop against
OpenCAMLib's BatchDropCutter on the same surface, in the same run.

The surface z = 5 sin(x/10) cos(y/15) on [-half, half]^2 as a triangle mesh (grid ``--spacing``);
OpenCAMLib drops a ball cutter on the triangles, scanmill on points sampled on the same triangles
(barycentric grid, ``--k`` subdivisions). Both get the same random CL lines. OpenCAMLib uses its
OpenMP threads (``ocl.max_threads()``), scanmill its numba threads.

    .venv/bin/python bench/bench_balldrop.py [--lines 20000] [--spacing 1.0] [--k 10] [--repeat 2]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import opencamlib as ocl

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from test_balldrop import _mesh, _sample_triangles  # noqa: E402

from planning.toolpath.balldrop import ball_drop  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=20_000)
    ap.add_argument("--spacing", type=float, default=1.0)
    ap.add_argument("--k", type=int, default=10)
    ap.add_argument("--radius", type=float, default=3.0)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    V, T = _mesh(spacing=args.spacing)
    pts = _sample_triangles(V, T, args.k)
    R = args.radius
    surf = ocl.STLSurf()
    for t in T:
        surf.addTriangle(ocl.Triangle(*(ocl.Point(*map(float, V[q])) for q in t)))
    rng = np.random.default_rng(0)
    xy = rng.uniform(-15, 15, size=(args.lines, 2))
    ball_drop(pts[:10], xy[:10], R)      # compile / load the cached kernels
    print(f"cores {os.cpu_count()}, OpenCAMLib {ocl.version()} threads {ocl.max_threads()}; "
          f"{T.shape[0]} triangles, {pts.shape[0]} points, {args.lines} CL lines, R {R} mm")
    print(f"{'run':>4} {'scanmill s':>11} {'CL/s':>12} {'OCL s':>9} {'CL/s':>10} {'ratio':>7} {'max |dz| mm':>12}")
    for rep in range(args.repeat):
        t0 = time.perf_counter()
        z = ball_drop(pts, xy, R).z_mm
        t_us = time.perf_counter() - t0
        cutter = ocl.BallCutter(2 * R, 30.0)    # keep a reference: OCL holds a bare pointer to it
        bdc = ocl.BatchDropCutter()
        bdc.setSTL(surf)
        bdc.setCutter(cutter)
        for x, y in xy:
            bdc.appendPoint(ocl.CLPoint(float(x), float(y), -100.0))
        t0 = time.perf_counter()
        bdc.run()
        t_ocl = time.perf_counter() - t0
        z_ocl = np.array([p.z for p in bdc.getCLPoints()]) + R
        print(f"{rep:>4} {t_us:>11.3f} {args.lines / t_us:>12.0f} {t_ocl:>9.3f} {args.lines / t_ocl:>10.0f} "
              f"{t_ocl / t_us:>7.1f} {np.abs(z_ocl - z).max():>12.5f}")


if __name__ == "__main__":
    main()
