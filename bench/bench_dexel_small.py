"""Benchmark: the cost of one small tri-dexel call (a planner's single check). Prints figures only.

The roughing and the guards ask the stock thousands of questions of one to a few moves each (a
column, a rapid, a piece's ends: issue 30's profile of the femur-like plan). This times ``collide`` and
``cut`` of 1, 4 and 16 moves and ``column_rise`` of one tip on a femur-sized block (230 x 90 x 80 mm,
1 mm rays, 20 pockets cut into it), per call (median of 5 rounds of 200 calls, after one round to
warm up), with the tool of the femur-like plan's roughing (Ø10 flat, shank and holder pieces).

``--root DIR`` times another checkout's ``planning`` (e.g. a ``git worktree`` of the commit before):

    .venv/bin/python bench/bench_dexel_small.py
    .venv/bin/python bench/bench_dexel_small.py --root /tmp/before
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]), help="checkout whose planning to time")
    ap.add_argument("--calls", type=int, default=200, help="calls per round")
    args = ap.parse_args()
    sys.path.insert(0, args.root)
    import numba
    import numpy as np

    from planning.simulate.dexel import TriDexel, collide, column_rise, cut
    from planning.simulate.motion import ToolShape

    rng = np.random.default_rng(1)
    stock = TriDexel.box(np.array([0, 0, 0.0]), np.array([230, 90, 80.0]), resolution_mm=1.0)
    cutter = ToolShape(number=1, kind="flat", radius_mm=5, corner_radius_mm=0, flute_length_mm=25)
    tool = ToolShape(number=1, kind="flat", radius_mm=5, corner_radius_mm=0, flute_length_mm=25,
                     pieces=((25, 60, 6), (60, 120, 20)))
    for _ in range(20):
        a = rng.uniform([10, 10, 40], [220, 80, 78], (30, 3))
        cut(stock, a, a + rng.uniform(-10, 10, (30, 3)) * [1, 1, 0], np.tile([0, 0, 1.0], (30, 1)), cutter)
    axis = np.array([0.3, 0.1, 0.95]) / np.linalg.norm([0.3, 0.1, 0.95])
    n = args.calls

    def per_call(fn) -> float:
        rounds = []
        for r in range(6):
            t = time.perf_counter()
            for i in range(n):
                fn(i)
            if r:
                rounds.append((time.perf_counter() - t) / n)
        return statistics.median(rounds) * 1e6

    print(f"root {args.root}, {numba.get_num_threads()} numba threads")
    for k in (1, 4, 16):
        s = rng.uniform([10, 10, 40], [220, 80, 78], (n, k, 3))
        e = s + rng.uniform(-5, 5, s.shape)
        ax = np.broadcast_to(axis, (k, 3))
        c = per_call(lambda i: collide(stock, s[i], e[i], ax, tool, which="tool"))
        work = stock.copy()
        u = per_call(lambda i: cut(work, s[i], e[i], ax, cutter))
        print(f"{k:3d} moves: collide {c:8.1f} us/call   cut {u:8.1f} us/call")
    tips = rng.uniform([10, 10, 40], [220, 80, 78], (n, 1, 3))
    print(f"column_rise, one tip: {per_call(lambda i: column_rise(stock, tips[i], axis, 40.0, tool)):8.1f} us/call")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
