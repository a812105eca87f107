"""Issue 30 item 2: the verification in one pass against running every program again, on the same programs.

Per case (bench/bench_stock_first.py's six reference cases) the whole plan once (its verification in the
default ``simulate.mode = "single_pass"``: the programs proven to be the moves the guard ran, that run
taken), then the same programs verified again in ``"independent"`` mode (every program run on a fresh
stock) in the same process, so both seconds come from one machine state. Printed per case: each mode's
verification seconds (``verification.seconds``), what the single pass proved (or why it ran the programs
again), the verdict and offence counts of both, the finished share, the removed volume and the air share of
the roughing and finishing feed length in both; and the first set-up's finishing moves as the guard ran
them, run again on the stock they met, exact and with their coordinates rounded to the post's decimals: the
feed length "in air" (under 1e-6 mm^3 removed) of each, how much of that figure the rounding alone moves.

    .venv/bin/python bench/bench_single_pass.py
    .venv/bin/python bench/bench_single_pass.py --cases half_sphere femur_like --json /tmp/single_pass.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "bench"))

from bench_stock_first import CASES, case_input


def _figures(v) -> dict:
    ops: dict[str, list[float]] = {}
    for a in v.areas:
        for o in a.operations:
            f = ops.setdefault(o.operation, [0.0, 0.0, 0.0])
            f[0] += o.feed_mm
            f[1] += o.air_feed_mm
            f[2] += o.removed_mm3
    return {"mode": v.mode, "seconds": v.seconds, "status": v.status,
            "counts": [v.travel_excursions, v.rapids_into_material, v.holder_collisions, v.fixture_collisions,
                       v.plunges_into_material, v.deviation.n_gouged if v.deviation else None],
            "finished_share": v.deviation.finished_share if v.deviation else None,
            "air_share": {k: round(f[1] / f[0], 4) if f[0] else 0.0 for k, f in ops.items()},
            "removed_cm3": {k: round(f[2] / 1000, 2) for k, f in ops.items()}}


def run_case(name: str) -> dict:
    from planning.inputs import Cloud
    from planning.pipeline import run_plan
    from schemas.params import apply_overrides, parse_config

    pts, nrm, faces, doc, sets = case_input(name, HERE)
    cfg = parse_config(apply_overrides(doc, sets))
    t0 = time.perf_counter()
    out = run_plan(Cloud(points=pts, normals=nrm, source_format="generated", faces=faces), cfg, name=name)
    plan_s = time.perf_counter() - t0
    single = out.result.verification
    independent = out.extra["verify_again"]("independent").verification
    return {"case": name, "plan_s": round(plan_s, 1), "note": single.mode_note,
            "single": _figures(single), "independent": _figures(independent),
            "rounding": _rounding(out, cfg)}


def _rounding(out, cfg) -> dict | None:
    """How much of the finishing's "in air" figure is rounding: the first set-up's finishing moves as the
    guard ran them, run again on the stock they met, exact and with every coordinate rounded to the
    post's decimals (part frame); feed length that removed under 1e-6 mm^3 in each, mm."""
    import numpy as np

    from planning.simulate.dexel import simulate_moves
    from planning.simulate.motion import FEED
    from planning.simulate.verify import AIR_MM3, tool_shapes

    g = getattr(out.extra["area_paths"][0], "finishing_guard", None)
    op = None if g is None else g.moves
    if op is None or op.stock_before is None:
        return None
    shape = tool_shapes(cfg, cfg.tool.assembly())[op.tool]
    length = np.linalg.norm(op.end_mm - op.start_mm, axis=1)
    feed = op.kind == FEED
    air = {}
    for key, d in (("exact", None), ("rounded", int(cfg.post.decimals))):
        s, e = (op.start_mm, op.end_mm) if d is None else (np.round(op.start_mm, d), np.round(op.end_mm, d))
        run = simulate_moves(op.stock_before.copy(), s, e, op.axis, shape, op.kind)
        air[key] = round(float(length[feed & (run.removed_mm3 < AIR_MM3)].sum()), 1)
    air["feed"] = round(float(length[feed].sum()), 1)
    return air


def table(rows: list[dict]) -> str:
    lines = [("| case | verification s: single pass / independent | verdict (travel, rapids, holder, fixture, "
              "plunges, gouged) single / independent | finished share | air share roughing, finishing: single / "
              "independent | removed cm^3 roughing, finishing: single / independent |"),
             "|---|---|---|---|---|---|"]
    for r in rows:
        s, i = r["single"], r["independent"]
        def air(f):
            return ", ".join(f"{f['air_share'].get(k, 0):.1%}" for k in ("roughing", "finishing"))

        def rem(f):
            return ", ".join(f"{f['removed_cm3'].get(k, 0):g}" for k in ("roughing", "finishing"))
        lines.append(f"| {r['case']} | {s['seconds']:.2f} ({s['mode']}) / {i['seconds']:.2f} | "
                     f"{s['status']} {tuple(s['counts'])} / {i['status']} {tuple(i['counts'])} | "
                     f"{s['finished_share']} / {i['finished_share']} | {air(s)} / {air(i)} | {rem(s)} / {rem(i)} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} cores", flush=True)
    rows = []
    for name in args.cases:
        rows.append(run_case(name))
        r = rows[-1]
        print(f"{name}: plan {r['plan_s']} s; verification {r['single']['seconds']:.2f} s "
              f"({r['single']['mode']}) against {r['independent']['seconds']:.2f} s independent; {r['note']}",
              flush=True)
        if r["rounding"]:
            q = r["rounding"]
            print(f"  first set-up's finishing in air: {q['exact']} mm exact, {q['rounded']} mm with the coordinates "
                  f"rounded to the post's decimals, of {q['feed']} mm fed", flush=True)
    print(table(rows))
    print(f"load average after {os.getloadavg()[0]:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
