"""Benchmark of the cloud collision test (global visibility, Makki 2010 §2.2.4; docs/design.md target:
100k points x 216 orientations with cutter and holder within 5 s on 2 cores).

A 100k-point femur-like part with its exact normals; 216 near-uniform (Fibonacci) axes over the
whole sphere; every point is both a sample and an obstacle. Tools: the docs/design.md yardstick
(R 3 mm cutter to 9 mm above the ball centre, then an unbounded R 10 mm holder) and scanmill's
default assembly. Pairs: all n x m, and the pairs inside the tool cone [10, 80] deg (what the
pipeline asks). One and two threads in the same run; ``--check`` compares a random subset of
pairs with the brute-force reference.

    .venv/bin/python bench/bench_collision.py [--points 100000] [--axes 216] [--repeat 2] [--check]
    .venv/bin/python bench/bench_collision.py --before 43c11a9 --obstacles 1000000 --threads 2

``--before REV`` runs ``planning/geometry/collision.py`` as it was at git revision REV beside
today's, alternately in the same process on the same pairs, and says whether the answers are equal
(issue 17: the fused raster). ``--obstacles N``: the part sampled at N points, all of them
obstacles, the first ``--points`` of them the samples (the femur plan checks ~100k samples against
its 1M scan points).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import planning.geometry.collision as col
from planning.inputs.samples import femur_like
from planning.geometry.tool import Segment, ToolAssembly
from schemas.params import ToolParams


def fibonacci_axes(m: int) -> np.ndarray:
    k = np.arange(m) + 0.5
    z = 1 - 2 * k / m
    r = np.sqrt(1 - z * z)
    ph = np.pi * (1 + 5 ** 0.5) * k
    return np.stack([r * np.cos(ph), r * np.sin(ph), z], 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--axes", type=int, default=216)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--check", action="store_true", help="brute-force check of 40 samples x all axes")
    ap.add_argument("--before", default=None, help="also time collision.py of this git revision (same pairs)")
    ap.add_argument("--obstacles", type=int, default=None, help="obstacle points (default: --points)")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = ap.parse_args()

    if args.before:
        return _before_after(args)
    s = femur_like(n_points=args.points)
    P, N = s.points, s.normals
    A = fibonacci_axes(args.axes)
    cosang = N @ A.T
    cone = (cosang <= np.cos(np.radians(10))) & (cosang >= np.cos(np.radians(80)))
    tools = {
        "yardstick R3 + holder R10": ToolAssembly(3.0, (Segment(0, 9, 3.0, "cutter"), Segment(9, None, 10.0)), 100.0),
        "default assembly": ToolParams().assembly(),
    }
    idx = np.arange(P.shape[0])
    print(f"cores: {os.cpu_count()}  points {P.shape[0]}  axes {A.shape[0]}  cone pairs {int(cone.sum())}")
    # compile the kernels (numba caches them on disk afterwards)
    t0 = time.perf_counter()
    col.cloud_collision_free(P[:200], idx[:200], N[:200], A[:3], tools["default assembly"])
    print(f"first call (compile or load cached kernels): {time.perf_counter() - t0:.2f} s")
    print(f"{'tool':28s} {'pairs':6s} {'threads':>7s} {'seconds':>8s} {'Mpairs/s':>9s} {'free %':>7s}")
    for name, tool in tools.items():
        for label, cand in (("cone", cone), ("all", None)):
            for rep in range(args.repeat):
                for th in args.threads:
                    col._THREADS = th
                    t0 = time.perf_counter()
                    free = col.cloud_collision_free(P, idx, N, A, tool, candidates=cand)
                    dt = time.perf_counter() - t0
                    npairs = int(cone.sum()) if cand is not None else P.shape[0] * A.shape[0]
                    print(f"{name:28s} {label:6s} {th:7d} {dt:8.2f} {npairs / dt / 1e6:9.2f} "
                          f"{100 * free.sum() / npairs:7.2f}", flush=True)
            if args.check:
                rng = np.random.default_rng(0)
                sub = rng.choice(P.shape[0], 40, replace=False)
                c = None if cand is None else cand[sub]
                ref = col.brute_force_collision_free(P, sub, N[sub], A, tool, candidates=c)
                fast = col.cloud_collision_free(P, sub, N[sub], A, tool, candidates=c)
                print(f"  check vs brute force, 40 samples x {A.shape[0]} axes: "
                      f"{int((fast != ref).sum())} disagreements, {int((fast & ~ref).sum())} unsafe")


def _before_after(args) -> None:
    """Today's collision test against revision ``args.before``'s, alternately, on the femur-like part:
    ``--points`` samples in the tool cone [10, 80] deg of the axes, ``--obstacles`` obstacle points."""
    import importlib.util
    import subprocess
    import tempfile

    src = subprocess.run(["git", "show", f"{args.before}:planning/geometry/collision.py"], capture_output=True,
                         text=True, check=True, cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__)))).stdout
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "collision_before.py")
        with open(path, "w") as fh:
            fh.write(src)
        spec = importlib.util.spec_from_file_location("collision_before", path)
        old = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(old)
        n_obst = args.obstacles or args.points
        s = femur_like(n_points=n_obst)
        P, N = s.points, s.normals
        idx = np.arange(min(args.points, n_obst))
        A = fibonacci_axes(args.axes)
        cosang = N[idx] @ A.T
        cone = (cosang <= np.cos(np.radians(10))) & (cosang >= np.cos(np.radians(80)))
        tool = ToolParams().assembly()
        for mod in (old, col):                                   # kernels compiled or loaded, untimed
            mod._THREADS = args.threads[-1]
            mod.cloud_collision_free(P, idx[:200], N[:200], A[:3], tool, candidates=cone[:200, :3])
        print(f"{idx.size} samples x {A.shape[0]} axes ({int(cone.sum())} cone pairs), {n_obst} obstacles, "
              f"default assembly, {args.threads[-1]} threads, load {os.getloadavg()[0]:.2f}")
        for rep in range(args.repeat):
            got = {}
            for name, mod in ((args.before, old), ("now", col)):
                t0 = time.perf_counter()
                got[name] = mod.cloud_collision_free(P, idx, N[idx], A, tool, candidates=cone)
                print(f"  run {rep}: {name:>10s} {time.perf_counter() - t0:7.2f} s", flush=True)
            print(f"  same answer pair for pair: {np.array_equal(got[args.before], got['now'])}")


if __name__ == "__main__":
    main()
