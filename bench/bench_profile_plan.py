"""Benchmark: where the femur-like ``make run`` plan spends its time (issue 30's serial share). Prints
figures only.

The plan (scripts/demo_service.py's femur-like configuration, 1M points) under ``cProfile``: the stage
seconds, the functions with the most own time, and the calls into the tri-dexel kernels
(``planning.simulate.dexel._run``, which every cut, simulation and collision test goes through) grouped
by their five callers, with their count, moves and seconds:

    NUMBA_NUM_THREADS=2 .venv/bin/python bench/bench_profile_plan.py
"""

from __future__ import annotations

import collections
import cProfile
import json
import os
import pstats
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "scripts"))


def main() -> int:
    from demo_service import CONFIGS

    import planning.simulate.dexel as D
    from planning.inputs import Cloud
    from planning.inputs.samples import make_sample
    from planning.pipeline import run_plan
    from schemas.params import parse_config

    stats = collections.defaultdict(lambda: [0, 0, 0.0])
    run = D._run

    def timed(model, start, end, *a, **k):
        t = time.perf_counter()
        r = run(model, start, end, *a, **k)
        key = " < ".join(f.name for f in reversed(traceback.extract_stack(limit=6)[:-1]))
        s = stats[key]
        s[0], s[1], s[2] = s[0] + 1, s[1] + len(start), s[2] + time.perf_counter() - t
        return r

    D._run = timed
    s = make_sample("femur_like", n_points=1_000_000)
    cfg = parse_config(json.loads(json.dumps(CONFIGS["femur_like"])))
    print(f"load average {os.getloadavg()[0]:.2f}", flush=True)
    pr = cProfile.Profile()
    pr.enable()
    out = run_plan(Cloud(points=s.points, normals=None, source_format="generated"), cfg, name="femur_like")
    pr.disable()
    print(", ".join(f"{t.stage} {t.seconds:.1f} s" for t in out.result.timings))
    pstats.Stats(pr).sort_stats("tottime").print_stats(15)
    print("tri-dexel kernel calls by caller:")
    for key, (n, m, sec) in sorted(stats.items(), key=lambda kv: -kv[1][2])[:15]:
        print(f"  {sec:7.2f} s {n:6d} calls {m:9d} moves  {key}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
