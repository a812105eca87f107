"""What the verification of a 5-axis femur-like plan still finds, with the program lines (issue 33).

    .venv/bin/python bench/bench_fiveaxis_offences.py --points 50000

Plans the femur-like sample (the reference parameters of bench/bench_fiveaxis.py) in
``paths.finishing.mode=5axis`` from ``--setups`` pass directions and prints the verdict, the
finishing guard's figures per set-up, the offences per program, and the worst offences with the
program line before and at each (the move that offends and where it comes from).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_fiveaxis import FEMUR
from planning.inputs import Cloud, samples
from planning.pipeline import run_plan
from schemas.params import parse_config


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=50_000, help="femur-like points (default 50,000)")
    ap.add_argument("--setups", type=int, default=2, help="setups.max_setups: pass directions (default 2)")
    ap.add_argument("--worst", type=int, default=12, help="worst offences printed (default 12)")
    args = ap.parse_args(argv)
    s = samples.femur_like(n_points=args.points, seed=0)
    cfg = {**FEMUR, "setups": {**FEMUR["setups"], "max_setups": args.setups},
           "paths": {"finishing": {"mode": "5axis"}}}
    t0 = time.perf_counter()
    out = run_plan(Cloud(points=s.points, normals=None, source_format="generated"), parse_config(cfg), name="femur 5axis")
    r, v = out.result, out.result.verification
    print(f"{args.points:,} points, {time.perf_counter() - t0:.0f} s: {v.status} ({v.mode}): {v.message}")
    for st in r.setups:
        f = st.path.finishing if st.path else None
        if f is not None and f.guard is not None:
            g = f.guard
            print(f"set-up {st.id}: guard found {g.found}, rapids fed {g.rapids_to_feed}, dropped {g.dropped}, "
                  f"truncated {g.truncated}, rounds {g.rounds}; links routed for C "
                  f"{f.five_axis.n_unwinding_links if f.five_axis else '-'}")
    for a in v.areas:
        print(f"{a.program}: rapids into material {a.rapids_into_material}, holder {a.holder_collisions}, "
              f"travel {a.travel_excursions}, rotary feed {a.rotary_feed_excesses}")
    progs = out.extra["programs"]
    for w in v.worst[:args.worst]:
        lines = progs[w.program].splitlines()
        print(f"{w.kind} {w.program}:{w.line} {w.amount} {w.detail} | {lines[w.line - 2][:80]} -> "
              f"{lines[w.line - 1][:80]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
