"""Benchmark of the collision test with one tool axis per ball-centre position
(planning.geometry.axis_collision; simultaneous 5-axis finishing).

A synthetic bumpy surface of ``--points`` points (a jittered grid over 150 x 150 mm, heights
``8 sin(x/15) cos(y/12) + 1.5 sin(x/3 + y/4)`` mm, every point an obstacle); ``--centres`` ball centres
``p + R n`` at random surface points ``p`` with their exact normals ``n``; one random axis per centre,
uniform on the cap within ``--tilt`` degrees of +Z. Tool: radius 3, flute 12, stickout 30, holder
[(12.5, 45), (25, 40)] mm. Printed: the grid's build time, the query time (and the total of
``pointwise_collision_free``), and as a peer in the same run ``collision.centres_collision_free`` for
the same centres with ONE axis (+Z), with the ratio. ``--check N`` compares N random positions with
the brute-force reference.

    .venv/bin/python bench/bench_axis_collision.py [--points 1000000] [--centres 200000] [--repeat 2]
        [--tilt 60] [--cell 1.5 ...] [--threads 1 2] [--check 200] [--no-peer]
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np

from planning.geometry import axis_collision as axc
from planning.geometry.collision import centres_collision_free
from planning.geometry.tool import ball_tool


def bumpy_surface(n_points: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """(points, unit normals) of the benchmark surface, about ``n_points`` of them."""
    k = int(round(np.sqrt(n_points)))
    step = 150.0 / k
    x, y = np.meshgrid(np.arange(k) * step - 75.0, np.arange(k) * step - 75.0)
    x = x.ravel() + rng.uniform(-0.3, 0.3, x.size) * step
    y = y.ravel() + rng.uniform(-0.3, 0.3, y.size) * step
    z = 8 * np.sin(x / 15) * np.cos(y / 12) + 1.5 * np.sin(x / 3 + y / 4)
    fx = 8 / 15 * np.cos(x / 15) * np.cos(y / 12) + 1.5 / 3 * np.cos(x / 3 + y / 4)
    fy = -8 / 12 * np.sin(x / 15) * np.sin(y / 12) + 1.5 / 4 * np.cos(x / 3 + y / 4)
    nrm = np.stack([-fx, -fy, np.ones_like(x)], 1)
    return np.stack([x, y, z], 1), nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def cap_axes(m: int, max_deg: float, rng) -> np.ndarray:
    """m random unit axes, uniform on the cap within max_deg of +Z."""
    ct = rng.uniform(np.cos(np.radians(max_deg)), 1.0, m)
    ph = rng.uniform(0, 2 * np.pi, m)
    st = np.sqrt(1 - ct * ct)
    return np.stack([st * np.cos(ph), st * np.sin(ph), ct], 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--centres", type=int, default=200_000)
    ap.add_argument("--tilt", type=float, default=60.0, help="largest angle of the axes from +Z, degrees")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--cell", type=float, nargs="*", default=None,
                    help="grid cell sides to time (mm; default: the tool's default_cell_mm)")
    ap.add_argument("--threads", type=int, nargs="+", default=None,
                    help="numba threads for the query (default: numba's, the cores)")
    ap.add_argument("--check", type=int, default=0, help="positions compared with the brute force")
    ap.add_argument("--no-peer", action="store_true", help="skip the one-axis centres_collision_free run")
    args = ap.parse_args()

    rng = np.random.default_rng(1)
    P, N = bumpy_surface(args.points, rng)
    tool = ball_tool(3.0, flute_length_mm=12.0, stickout_mm=30.0, holder=[(12.5, 45.0, None), (25.0, 40.0, None)])
    R = tool.radius_mm
    pick = rng.choice(P.shape[0], args.centres, replace=False)
    C = P[pick] + R * N[pick]
    A = cap_axes(args.centres, args.tilt, rng)
    z = np.array([[0.0, 0.0, 1.0]])
    cells = args.cell or [axc.default_cell_mm(tool)]
    threads = args.threads or [numba.get_num_threads()]
    print(f"cores {os.cpu_count()}, numba threads {numba.get_num_threads()}, load {os.getloadavg()[0]:.2f}; "
          f"{P.shape[0]} obstacle points, {C.shape[0]} centres, axes within {args.tilt:g} deg of +Z")
    t0 = time.perf_counter()                     # compile or load the cached kernels, untimed
    axc.pointwise_collision_free(P[:2000], C[:50], A[:50], tool)
    if not args.no_peer:
        centres_collision_free(P[:2000], C[:50], z, tool)
    print(f"first calls (compile or load cached kernels): {time.perf_counter() - t0:.2f} s")
    for rep in range(args.repeat):
        for cell in cells:
            for th in threads:
                numba.set_num_threads(th)
                t0 = time.perf_counter()
                grid = axc.ObstacleGrid(P, cell)
                t_build = time.perf_counter() - t0
                t0 = time.perf_counter()
                free = grid.free(C, A, tool)
                t_query = time.perf_counter() - t0
                print(f"run {rep} cell {grid.cell_mm:.3g} mm ({grid.n_leaves} cells, depth {grid.depth}), "
                      f"{th} threads: grid {t_build:.2f} s + query {t_query:.2f} s = {t_build + t_query:.2f} s, "
                      f"free {100 * free.mean():.1f} %", flush=True)
        if not args.no_peer:
            t0 = time.perf_counter()
            one = centres_collision_free(P, C, z, tool)[:, 0]
            t_one = time.perf_counter() - t0
            print(f"run {rep} peer centres_collision_free, one axis (+Z): {t_one:.2f} s, "
                  f"free {100 * one.mean():.1f} %; per-position axes / one axis = {(t_build + t_query) / t_one:.2f}", flush=True)
    if args.check:
        sub = rng.choice(C.shape[0], args.check, replace=False)
        t0 = time.perf_counter()
        ref = axc.brute_force_pointwise(P, C[sub], A[sub], tool)
        print(f"check vs brute force, {args.check} positions ({time.perf_counter() - t0:.1f} s): "
              f"{int((ref != free[sub]).sum())} disagreements")


if __name__ == "__main__":
    main()
