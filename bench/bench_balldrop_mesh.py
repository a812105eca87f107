"""Ball drop on triangle meshes (issue 18): CL points per second of scanmill's exact triangle drop
(planning.geometry.triangles.TriangleDropSurface) against OpenCAMLib's BatchDropCutter on the same
triangles and the same random CL lines, in the same run, with the largest height difference.

Two meshes: the surface of bench/bench_balldrop.py, z = 5 sin(x/10) cos(y/15) on [-20, 20]^2 as a
grid mesh (``--spacing``), and a scan-like mesh: ``--scan-points`` random points on a bumpy part
(two bumps, a ridge and a step) with 0.02 mm noise, Delaunay-triangulated in xy. Build times (our
raster, OCL's kd-tree in ``setSTL``) are printed apart from the drops. OpenCAMLib uses its OpenMP
threads (``ocl.max_threads()``), scanmill its numba threads.

    .venv/bin/python bench/bench_balldrop_mesh.py [--lines 20000] [--scan-lines 5000] [--spacing 1.0]
        [--scan-points 100000] [--radius 3.0] [--repeat 2]

The scan-like mesh gets the first ``--scan-lines`` of the same random lines (OpenCAMLib needs
minutes for 20,000 lines on it).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import opencamlib as ocl
from scipy.spatial import Delaunay

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from test_balldrop import _mesh  # noqa: E402

from planning.geometry.triangles import TriangleDropSurface  # noqa: E402


def scan_mesh(n, seed=0, half=20.0):
    """A scan-like height field: ``n`` random xy points, z a bumpy part with noise, Delaunay."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-half, half, (n, 2))
    x, y = xy[:, 0], xy[:, 1]
    z = (6.0 * np.exp(-((x - 6) ** 2 + (y - 4) ** 2) / 40.0) + 4.0 * np.exp(-((x + 8) ** 2 + (y + 6) ** 2) / 15.0)
         + 2.0 * np.maximum(0.0, 1.0 - np.abs(x + y) / 3.0) + np.where(y > 12.0, 3.0, 0.0)
         + rng.normal(0.0, 0.02, n))
    V = np.column_stack([xy, z])
    F = Delaunay(xy).simplices.astype(np.int64)
    return V, F


def run(name, V, F, xy, R, repeat):
    t0 = time.perf_counter()
    surf = TriangleDropSurface(V, F, R)
    t_build = time.perf_counter() - t0
    tri = ocl.STLSurf()
    for t in F:
        tri.addTriangle(ocl.Triangle(*(ocl.Point(*map(float, V[q])) for q in t)))
    low = float(V[:, 2].min()) - 100.0
    K = xy.shape[0]
    print(f"{name}: {F.shape[0]} triangles, {K} CL lines, R {R} mm; scanmill raster built in {t_build:.3f} s "
          f"(cell {surf.cell_mm:.3f} mm, {surf.n_entries} entries)")
    print(f"{'run':>4} {'scanmill s':>11} {'CL/s':>12} {'OCL s':>9} {'CL/s':>10} {'ratio':>7} {'max |dz| mm':>12}"
          f" {'OCL setSTL s':>13}")
    ratios, diffs = [], []
    for rep in range(repeat):
        t0 = time.perf_counter()
        z = surf.drop(xy).z_mm
        t_us = time.perf_counter() - t0
        cutter = ocl.BallCutter(2 * R, 100.0)    # keep a reference: OCL holds a bare pointer to it
        bdc = ocl.BatchDropCutter()
        t0 = time.perf_counter()
        bdc.setSTL(tri)
        t_kd = time.perf_counter() - t0
        bdc.setCutter(cutter)
        for x, y in xy:
            bdc.appendPoint(ocl.CLPoint(float(x), float(y), low))
        t0 = time.perf_counter()
        bdc.run()
        t_ocl = time.perf_counter() - t0
        zo = np.array([p.z for p in bdc.getCLPoints()])
        zo = np.where(zo <= low, -np.inf, zo + R)     # OCL gives the tip: centre = tip + R
        fin = np.isfinite(z)
        assert np.array_equal(fin, np.isfinite(zo)), "touched lines differ"
        dz = float(np.abs(z[fin] - zo[fin]).max()) if fin.any() else 0.0
        ratios.append(t_ocl / t_us)
        diffs.append(dz)
        print(f"{rep:>4} {t_us:>11.4f} {K / t_us:>12.0f} {t_ocl:>9.3f} {K / t_ocl:>10.0f} {t_ocl / t_us:>7.1f} "
              f"{dz:>12.2e} {t_kd:>13.3f}")
    return min(ratios), max(ratios), max(diffs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=20_000)
    ap.add_argument("--scan-lines", type=int, default=5_000)
    ap.add_argument("--spacing", type=float, default=1.0)
    ap.add_argument("--scan-points", type=int, default=100_000)
    ap.add_argument("--radius", type=float, default=3.0)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    R = args.radius
    rng = np.random.default_rng(0)
    xy = rng.uniform(-15, 15, size=(args.lines, 2))
    V0, F0 = _mesh(spacing=args.spacing)
    TriangleDropSurface(V0, F0, R).drop(xy[:10])      # compile / load the cached kernels
    TriangleDropSurface(V0, F0, R).drop(xy)
    print(f"cores {os.cpu_count()}, load {os.getloadavg()[0]:.2f}, OpenCAMLib {ocl.version()} threads "
          f"{ocl.max_threads()}")
    r1a, r1b, d1 = run("sine surface", V0, F0, xy, R, args.repeat)
    V1, F1 = scan_mesh(args.scan_points)
    r2a, r2b, d2 = run("scan-like mesh", V1, F1, xy[:args.scan_lines], R, args.repeat)
    cmd = "bench/bench_balldrop_mesh.py " + " ".join(sys.argv[1:])
    print(f"summary: triangle drop vs OpenCAMLib BatchDropCutter, CL/s ratio over {args.repeat} runs: sine "
          f"{F0.shape[0]} triangles {r1a:.0f}-{r1b:.0f}x (max |dz| {d1:.1e} mm), scan-like {F1.shape[0]} triangles "
          f"{r2a:.0f}-{r2b:.0f}x "
          f"(max |dz| {d2:.1e} mm), {args.lines} / {min(args.lines, args.scan_lines)} lines, R {R} mm; "
          f"command: .venv/bin/python {cmd.strip()}")


if __name__ == "__main__":
    main()
