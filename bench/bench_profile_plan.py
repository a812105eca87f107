"""Benchmark: where the femur-like ``make run`` plan spends its time (issue 30's serial share). Prints
figures only.

The plan (scripts/demo_service.py's femur-like configuration, 1M points) under ``cProfile``: the stage
seconds, the functions with the most own time, and the calls into the tri-dexel kernels
(``planning.simulate.dexel._run``, which every cut, simulation and collision test goes through) grouped
by their five callers, with their count, moves and seconds:

    NUMBA_NUM_THREADS=2 .venv/bin/python bench/bench_profile_plan.py

``--wall``: no profiler (it charges the kernels' many small calls far more than they cost); the stage
seconds, and the wall seconds and calls of the paths stage's steps and checks (:data:`STEPS`, each timed
where it is called, nested ones included in their callers):

    NUMBA_NUM_THREADS=2 .venv/bin/python bench/bench_profile_plan.py --wall
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


#: (module, attribute path) of the functions ``--wall`` times.
STEPS = (
    ("planning.toolpath.area_paths", "_add_roughing"), ("planning.toolpath.area_paths", "_guard_roughing"),
    ("planning.toolpath.area_paths", "_add_finishing"), ("planning.toolpath.area_paths", "_cut_blocked"),
    ("planning.toolpath.area_paths", "_guard_finishing"), ("planning.toolpath.safety", "blocked_cl"),
    ("planning.toolpath.guard", "_FixtureMemo.check"), ("planning.toolpath.guard", "simulate_moves"),
    ("planning.toolpath.guard", "column_clear_z"), ("planning.toolpath.stock_view", "StockView.column_is_clear"),
    ("planning.toolpath.stock_view", "StockView.rapid_clear_z"),
    ("planning.toolpath.roughing.levels", "_LiveStock.advance"),
    ("planning.toolpath.roughing.levels", "_LiveStock._boundary_tops"),
    # inside the roughing: its level loop, one level, the entries (and the descents they write), the
    # steps off a wall, and the stock view brought up to date with the moves written (a function another
    # module imported by name is not seen there: the retracts are not listed for that reason)
    ("planning.toolpath.roughing.levels", "_cut_levels"), ("planning.toolpath.roughing.levels", "_cut_level"),
    ("planning.toolpath.roughing.entries", "_Entries.enter"), ("planning.toolpath.roughing.entries", "_Entries._write"),
    ("planning.toolpath.roughing.entries", "_Entries._sweep_top"),
    ("planning.toolpath.roughing.links", "_step_off"),
    ("planning.toolpath.roughing.levels", "_LiveStock.sync"),
)


def _time_steps(acc: dict) -> None:
    """Wrap every function of :data:`STEPS` where it is looked up, adding (seconds, calls) to ``acc``."""
    import importlib

    for mod_name, path in STEPS:
        owner = importlib.import_module(mod_name)
        *outer, name = path.split(".")
        for part in outer:
            owner = getattr(owner, part)
        fn = getattr(owner, name)

        def timed(*a, _fn=fn, _key=path, **k):
            t = time.perf_counter()
            try:
                return _fn(*a, **k)
            finally:
                got = acc.setdefault(_key, [0.0, 0])
                got[0] += time.perf_counter() - t
                got[1] += 1
        setattr(owner, name, timed)


def main() -> int:
    import argparse

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

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--wall", action="store_true", help="no profiler: wall seconds of the paths stage's steps")
    wall = ap.parse_args().wall
    s = make_sample("femur_like", n_points=1_000_000)
    cfg = parse_config(json.loads(json.dumps(CONFIGS["femur_like"])))
    print(f"load average {os.getloadavg()[0]:.2f}", flush=True)
    if wall:
        acc: dict = {}
        _time_steps(acc)
        out = run_plan(Cloud(points=s.points, normals=None, source_format="generated"), cfg, name="femur_like")
        print(", ".join(f"{t.stage} {t.seconds:.1f} s" for t in out.result.timings))
        for _, path in STEPS:
            sec, n = acc.get(path, (0.0, 0))
            print(f"  {sec:7.2f} s {n:6d} calls  {path}")
        return 0
    D._run = timed
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
