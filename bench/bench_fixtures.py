"""Benchmark: global visibility against fixtures (planning.geometry.fixtures, Makki 2010 §2.2.4).

    .venv/bin/python bench/bench_fixtures.py                       # 100k centres x 216 axes
    .venv/bin/python bench/bench_fixtures.py --centres 20000 --check 100

Scene (part frame, mm): a 200 x 120 x 50 mm block part (0 <= z <= 50) held in a vise box
(160 x 150 x 120 mm, under the part), two clamps (30 x 30 x 20 mm boxes on the top face at both
ends), the machine table at z = -120. Ball centres: ``--centres`` random points on the top and
side faces of the part, offset by R along the face normal. Axes: tilt 5..80 deg by 15 deg from +Z
x azimuth 0..350 by 10 deg (6 x 36 = 216), or ``--uniform`` random axes in the upper hemisphere.
Tool: ball R 3, cutter to 12 mm and shank (dia 6) to 30 mm above the ball centre (flute length 15,
stick-out 33 from the tip), holder dia 20 x 40 mm, then dia 40 x 60 mm (``planning.geometry.tool.ball_tool``).

Prints the seconds of ``fixture_collision_free`` (best of ``--repeats``), the pairs, how many the
numpy broad phase decided and how many needed FCL (and the FCL calls), the free fraction, and,
with ``--check N``, compares N centres against ``brute_force_fixture_collision_free``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planning.geometry.fixtures import (
    BoxFixture,
    TableFixture,
    brute_force_fixture_collision_free,
    fixture_collision_free,
)
from planning.geometry.tool import ball_tool


def scene():
    return [BoxFixture((-80, -75, -120), (80, 75, 0), name="vise"),
            BoxFixture((85, -15, 50), (115, 15, 70), name="clamp +x"),
            BoxFixture((-115, -15, 50), (-85, 15, 70), name="clamp -x"),
            TableFixture(-120.0)]


def centres_on_part(n: int, R: float, rng) -> np.ndarray:
    """Random points on the top and side faces of the block [-100,100]x[-60,60]x[0,50], + R n."""
    faces = [  # (area, sampler -> points, normal)
        (200 * 120, lambda k: np.c_[rng.uniform(-100, 100, k), rng.uniform(-60, 60, k), np.full(k, 50.0)], (0, 0, 1)),
        (120 * 50, lambda k: np.c_[np.full(k, 100.0), rng.uniform(-60, 60, k), rng.uniform(0, 50, k)], (1, 0, 0)),
        (120 * 50, lambda k: np.c_[np.full(k, -100.0), rng.uniform(-60, 60, k), rng.uniform(0, 50, k)], (-1, 0, 0)),
        (200 * 50, lambda k: np.c_[rng.uniform(-100, 100, k), np.full(k, 60.0), rng.uniform(0, 50, k)], (0, 1, 0)),
        (200 * 50, lambda k: np.c_[rng.uniform(-100, 100, k), np.full(k, -60.0), rng.uniform(0, 50, k)], (0, -1, 0)),
    ]
    area = np.array([f[0] for f in faces], float)
    counts = rng.multinomial(n, area / area.sum())
    out = [f[1](k) + R * np.asarray(f[2], float) for f, k in zip(faces, counts)]
    return rng.permutation(np.concatenate(out))


def axes_grid(uniform: int, rng) -> np.ndarray:
    if uniform:
        v = rng.normal(size=(uniform, 3))
        v[:, 2] = np.abs(v[:, 2])
        return v / np.linalg.norm(v, axis=1, keepdims=True)
    th, ph = np.meshgrid(np.radians(np.arange(5, 81, 15)), np.radians(np.arange(0, 360, 10)), indexing="ij")
    th, ph = th.ravel(), ph.ravel()
    return np.c_[np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--centres", type=int, default=100_000)
    ap.add_argument("--uniform", type=int, default=0, help="use this many random axes instead of the 216 grid")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--check", type=int, default=0, help="compare this many centres with the brute force")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    tool = ball_tool(3.0, flute_length_mm=15.0, stickout_mm=33.0, shank_radius_mm=3.0,
                     holder=[(10.0, 40.0, None), (20.0, 60.0, None)])
    fixtures = scene()
    C = centres_on_part(args.centres, tool.radius_mm, rng)
    A = axes_grid(args.uniform, rng)
    print(f"{C.shape[0]} centres x {A.shape[0]} axes = {C.shape[0] * A.shape[0]:,} pairs; "
          f"fixtures: {', '.join(f.name for f in fixtures)}")

    best, cpu, stats, free = None, None, None, None
    for _ in range(max(1, args.repeats)):
        st = {}
        t0, c0 = time.perf_counter(), time.process_time()
        free = fixture_collision_free(C, A, tool, fixtures, stats=st)
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        if best is None or dt < best:
            best, cpu, stats = dt, dc, st
    pairs = stats["pairs"]
    print(f"fixture_collision_free: {best:.2f} s wall, {cpu:.2f} s CPU  ({best / pairs * 1e9:.0f} ns/pair)")
    print(f"  decided by numpy: {pairs - stats['pairs_fcl']:,} pairs ({100 * (1 - stats['pairs_fcl'] / pairs):.3f} %); "
          f"needed FCL: {stats['pairs_fcl']:,} pairs, {stats['fcl_calls']:,} FCL calls "
          f"(+ {stats['ball_fcl_calls']} ball calls, per centre)")
    print(f"  free pairs: {100 * free.mean():.1f} %")

    if args.check:
        k = min(args.check, C.shape[0])
        t0 = time.perf_counter()
        ref = brute_force_fixture_collision_free(C[:k], A, tool, fixtures)
        dt = time.perf_counter() - t0
        diff = int((ref != free[:k]).sum())
        print(f"brute force on {k} centres: {dt:.2f} s ({dt / ref.size * 1e6:.0f} us/pair); "
              f"differences: {diff}")


if __name__ == "__main__":
    main()
