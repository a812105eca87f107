"""Benchmark: sphere throwing (planning.normals.throwing) against Open3D normals on the same ~1M-point cloud.

    .venv/bin/python bench/bench_normals.py                      # femur-like, 1,000,000 points
    .venv/bin/python bench/bench_normals.py --cloud synthetic    # closed bar, 45 points/mm^2
    .venv/bin/python bench/bench_normals.py --repeats 3 --points 1000000 --threads 0

Clouds: ``femur`` = ``planning.inputs.samples.femur_like`` (8 simulated views, noise 0.03 mm, ~19 points/mm^2);
``synthetic`` = ``tests/surfaces.cylinder``: a closed bar R 15 mm, capped, length chosen for ``--points``
at 45 points/mm^2 (the paper's density), noise 0.02 mm along the recording view. Both carry exact
normals, so the angular error of each method is printed too (Open3D's normals are unoriented: its
error is taken up to sign).

Timed, in the same process and interleaved, ``--repeats`` times each: ``sphere_throwing`` with the
paper's five directions, D 7 mm and the density-derived grid spacing (its estimation included), and
Open3D ``estimate_normals(KDTreeSearchParamKNN(20))`` (building the Open3D cloud excluded). Prints
seconds (best and median), CPU seconds, the ratio, the points with normals, the grid spacing, and
memory: the process peak RSS (ru_maxrss, includes generating the cloud) and the peak of numpy
allocations inside one sphere_throwing call (tracemalloc, untimed run). No assertions.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from planning.normals.throwing import DEFAULT_DIRECTIONS, sphere_throwing  # noqa: E402


def make_cloud(kind: str, n_points: int, seed: int):
    if kind == "femur":
        from planning.inputs.samples import femur_like
        s = femur_like(n_points=n_points, seed=seed)
        return s.points, s.normals, s.description
    import surfaces
    density, radius = 45.0, 15.0
    caps = 2.0 * math.pi * radius * radius
    length = (n_points / density - caps) / (2.0 * math.pi * radius)
    s = surfaces.cylinder(radius, length, density=density, sigma_mm=0.02, seed=seed)
    return (s.points, s.normals,
            f"closed bar R {radius:g} mm x {length:.0f} mm, {s.points.shape[0]} points, 45 points/mm^2, "
            f"noise 0.02 mm along the recording view")


def angular_error(est, exact, unoriented=False):
    d = np.einsum("ij,ij->i", est, exact)
    if unoriented:
        d = np.abs(d)
    return np.degrees(np.arccos(np.clip(d, -1.0, 1.0)))


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0   # KiB on Linux


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cloud", choices=("femur", "synthetic"), default="femur")
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--diameter", type=float, default=7.0, help="sphere diameter, mm")
    ap.add_argument("--grid", type=float, default=None, help="grid spacing, mm (default: density-derived)")
    ap.add_argument("--no-open3d", action="store_true")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    points, exact, desc = make_cloud(args.cloud, args.points, args.seed)
    print(f"cloud: {desc}")
    print(f"  generated in {time.perf_counter() - t0:.1f} s; peak RSS so far {rss_mb():.0f} MB")
    try:
        ncpu = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        ncpu = os.cpu_count()
    print(f"machine: {ncpu} CPUs available, load average {os.getloadavg()[0]:.2f}")

    o3d = None
    if not args.no_open3d:
        import open3d as o3d

    st_wall, st_cpu, o3_wall, o3_cpu = [], [], [], []
    res = None
    o3_normals = None
    for rep in range(args.repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        res = sphere_throwing(points, sphere_diameter_mm=args.diameter, grid_spacing_mm=args.grid,
                              directions=DEFAULT_DIRECTIONS)
        st_wall.append(time.perf_counter() - w0)
        st_cpu.append(time.process_time() - c0)
        if o3d is not None:
            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
            c0, w0 = time.process_time(), time.perf_counter()
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
            o3_wall.append(time.perf_counter() - w0)
            o3_cpu.append(time.process_time() - c0)
            o3_normals = np.asarray(pc.normals)
        line = f"  repeat {rep + 1}: sphere throwing {st_wall[-1]:.3f} s (cpu {st_cpu[-1]:.2f} s)"
        if o3_wall:
            line += f", Open3D KNN 20 {o3_wall[-1]:.3f} s (cpu {o3_cpu[-1]:.2f} s)"
        print(line, flush=True)

    n = res.sample_index.size
    err = angular_error(res.normals, exact[res.sample_index])
    print(f"sphere throwing: D {res.sphere_diameter_mm:g} mm, grid spacing {res.grid_spacing_mm:g} mm, "
          f"{len(DEFAULT_DIRECTIONS)} directions")
    print(f"  wall best {min(st_wall):.3f} s, median {statistics.median(st_wall):.3f} s; "
          f"cpu median {statistics.median(st_cpu):.2f} s")
    print(f"  points with normals {n} ({n / points.shape[0]:.1%}), mean touches {res.touches.mean():.2f}")
    print(f"  error vs exact normals: median {np.median(err):.2f} deg, p95 {np.percentile(err, 95):.2f} deg, "
          f"max {err.max():.1f} deg; outward (dot > 0) {np.mean(np.einsum('ij,ij->i', res.normals, exact[res.sample_index]) > 0):.4%}")
    if o3_wall:
        e3 = angular_error(o3_normals, exact, unoriented=True)
        print(f"Open3D estimate_normals KNN 20: wall best {min(o3_wall):.3f} s, median "
              f"{statistics.median(o3_wall):.3f} s; cpu median {statistics.median(o3_cpu):.2f} s")
        print(f"  error vs exact normals (unoriented, all points): median {np.median(e3):.2f} deg, "
              f"p95 {np.percentile(e3, 95):.2f} deg")
        print(f"ratio sphere throwing / Open3D (wall): best {min(st_wall) / min(o3_wall):.3f}, "
              f"median {statistics.median(st_wall) / statistics.median(o3_wall):.3f}")
    print(f"peak RSS (whole process) {rss_mb():.0f} MB")
    tracemalloc.start()
    sphere_throwing(points, sphere_diameter_mm=args.diameter, grid_spacing_mm=args.grid)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"peak numpy/Python allocations inside sphere_throwing (tracemalloc): {peak / 2**20:.0f} MB")


if __name__ == "__main__":
    main()
