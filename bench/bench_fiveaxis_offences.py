"""What the verification of a 5-axis femur-like plan still finds, with the program lines (issue 33).

    .venv/bin/python bench/bench_fiveaxis_offences.py --points 50000

Plans the femur-like sample (the reference parameters of bench/bench_fiveaxis.py) in
``paths.finishing.mode=5axis`` from ``--setups`` pass directions and prints the verdict, the
finishing guard's figures per set-up, the offences per program, and the worst offences with the
program line before and at each (the move that offends and where it comes from).

``--why``: the first run of each 5-axis finishing guard is also broken down by what the offending
moves are (their ``use`` in the path, and whether they lie in a link between passes); this runs the
guard's first simulation once more per set-up. ``--save DIR``: the programs written to DIR.
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
    ap.add_argument("--why", action="store_true", help="break the finishing guards' first findings down")
    ap.add_argument("--save", type=Path, default=None, help="write the programs to this folder")
    args = ap.parse_args(argv)
    if args.why:
        _watch_guard()
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
            if f.five_axis is not None and f.five_axis.links is not None:
                print(f"  links over the stock: {f.five_axis.links.model_dump()}")
    for a in v.areas:
        print(f"{a.program}: rapids into material {a.rapids_into_material}, holder {a.holder_collisions}, "
              f"travel {a.travel_excursions}, rotary feed {a.rotary_feed_excesses}")
    progs = out.extra["programs"]
    for w in v.worst[:args.worst]:
        lines = progs[w.program].splitlines()
        print(f"{w.kind} {w.program}:{w.line} {w.amount} {w.detail} | {lines[w.line - 2][:80]} -> "
              f"{lines[w.line - 1][:80]}")
    if args.save is not None:
        args.save.mkdir(parents=True, exist_ok=True)
        for name, text in progs.items():
            (args.save / name).write_bytes(text if isinstance(text, bytes) else text.encode())
    return 0


def _watch_guard() -> None:
    """Wrap the paths stage's guard: before a 5-axis path is guarded, its moves are run on the stock
    once (as the guard's first round does) and the offending moves printed by kind of move."""
    import numpy as np

    from planning.toolpath import area_paths
    from planning.toolpath.guard import run_on_stock
    from planning.toolpath.moves import USE_CUT, USE_PLUNGE, USE_RAPID, USE_RETRACT

    names = {USE_RAPID: "rapid", USE_CUT: "cut", USE_PLUNGE: "plunge", USE_RETRACT: "retract"}
    real = area_paths.guard_toolpath

    def watched(tp, frame, shape, stock, obstacles, machine, **kw):
        if tp.axis is not None and tp.n_moves:
            off, _, _ = run_on_stock(tp, frame, shape, stock, obstacles, machine,
                                     rapid_clearance_mm=kw.get("rapid_clearance_mm", 0.5))
            safe = kw["safe_z_mm"]
            z = tp.xyz_mm[:, 2]
            high = np.r_[False, (z[1:] >= safe - 1e-6) | (z[:-1] >= safe - 1e-6)]
            top = float(frame.to_frame(stock.boundary_points())[:, 2].max())
            touch = (tp.kind == 1) & np.isin(tp.use, (USE_CUT, USE_PLUNGE))
            t_idx = np.flatnonzero(touch)
            where = np.where(np.arange(tp.n_moves) <= t_idx[0], "start",
                             np.where(np.arange(tp.n_moves) > t_idx[-1], "end", "link"))
            print(f"  set-up frame: safe height {safe:.1f} mm, stock top {top:.1f} mm (frame z)")
            for what in ("rapid", "holder", "fixture", "travel"):
                m = getattr(off, what)
                if m.any():
                    by = {}
                    for i in np.flatnonzero(m):
                        key = f"{names.get(int(tp.use[i]), tp.use[i])}{' at safe' if high[i] else ''} ({where[i]})"
                        by[key] = by.get(key, 0) + 1
                    print(f"  guard's first run, {what}: {int(m.sum())} moves: {by}")
        return real(tp, frame, shape, stock, obstacles, machine, **kw)

    area_paths.guard_toolpath = watched


if __name__ == "__main__":
    sys.exit(main())
