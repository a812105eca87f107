"""Issue 31 item 5: the roughing end mill's radial engagement on the reference plans, as the verification
measures it (planning/simulate/engagement.py), and what measuring it costs.

Per case the whole plan (``run_plan``, the cases and settings of ``bench/bench_stock_first.py``, plus the
README's range samples ``range_femur`` and ``range_half_sphere`` with its own-scan settings), then per area
in machining order, from the verification's per-move measure of the roughing's level moves:

* the level feed length (m) and how it splits by engagement angle, as shares of that length: under 60
  degrees (a quarter of the diameter or less), 60-90, 90-120 (a 60 % step-over is 101.5), 120-175, and
  175 or more (slotting);
* the largest and the length-weighted 95th percentile, and the moves over ``paths.roughing.max_engagement_deg``;
* the seconds the measure took for that program, beside the verification's and the plan's seconds.

    .venv/bin/python bench/bench_engagement.py
    .venv/bin/python bench/bench_engagement.py --cases half_sphere femur_like range_femur
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "bench"))

from bench_stock_first import CASES as STOCK_CASES  # noqa: E402
from bench_stock_first import case_input  # noqa: E402

RANGE = ("range_femur", "range_half_sphere")
CASES = tuple(STOCK_CASES) + RANGE
BANDS = (0.0, 60.0, 90.0, 120.0, 175.0, 180.1)


def _input(name: str):
    if name in RANGE:
        from bench_range_scan import OVERRIDES
        from planning.inputs import samples

        s = samples.SAMPLES[name]()
        return s.points, getattr(s, "normals", None), None, {}, list(OVERRIDES)
    return case_input(name, HERE)


def plan_case(name: str) -> dict:
    from planning.inputs import Cloud
    from planning.pipeline import run_plan
    from planning.simulate import verify as V
    from schemas.params import apply_overrides, parse_config

    calls: dict[str, tuple] = {}
    original = V.measure_engagement

    def timed(motion, stock, tools, config):
        t = time.perf_counter()
        e = original(motion, stock, tools, config)
        calls[motion.program] = (motion, e, time.perf_counter() - t)
        return e

    V.measure_engagement = timed
    try:
        pts, nrm, faces, doc, sets = _input(name)
        cfg = parse_config(apply_overrides(doc, sets))
        t0 = time.perf_counter()
        out = run_plan(Cloud(points=pts, normals=nrm, source_format="generated", faces=faces), cfg, name=name)
        seconds = time.perf_counter() - t0
    finally:
        V.measure_engagement = original
    v = out.result.verification
    rows = []
    for a in (v.areas if v is not None else []):
        motion, e, s = calls.get(a.program, (None, None, 0.0))
        ro = next((o for o in a.operations if o.operation == "roughing"), None)
        row = {"area": a.area, "seconds": round(s, 2)}
        if e is not None and e.level.any():
            L = np.linalg.norm(motion.end_mm - motion.start_mm, axis=1)[e.level]
            hist, _ = np.histogram(e.deg[e.level], BANDS, weights=L)
            row.update(level_feed_m=round(float(L.sum()) / 1000, 2),
                       bands=[round(float(x), 3) for x in hist / L.sum()],
                       max_deg=ro.engagement_max_deg, p95_deg=ro.engagement_p95_deg,
                       over_moves=ro.over_engagement_moves, over_m=round(ro.over_engagement_mm / 1000, 2))
        rows.append(row)
    return {"case": name, "plan_s": round(seconds, 1), "verify_s": None if v is None else v.seconds,
            "status": None if v is None else v.status, "mode": None if v is None else v.mode,
            "bound_deg": cfg.paths.roughing.max_engagement_deg, "over_moves": None if v is None else v.over_engagement_moves,
            "areas": rows}


def table(results: list[dict]) -> str:
    head = ("| case / area | level feed m | < 60 | 60-90 | 90-120 | 120-175 | slot (>= 175) | max deg | p95 deg "
            "| moves over the bound (m) | measure s | verification s / plan s |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in results:
        for i, a in enumerate(r["areas"]):
            tail = f"{r['verify_s']:.1f} / {r['plan_s']:.1f}" if i == 0 else ""
            if "bands" not in a:
                lines.append(f"| {r['case']} {a['area']} | - | | | | | | | | | {a['seconds']:.2f} | {tail} |")
                continue
            b = " | ".join(f"{x:.1%}" for x in a["bands"])
            lines.append(f"| {r['case']} {a['area']} | {a['level_feed_m']:.1f} | {b} | {a['max_deg']:.0f} | "
                         f"{a['p95_deg']:.0f} | {a['over_moves']} ({a['over_m']:.1f}) | {a['seconds']:.2f} | {tail} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--json", default=None, help="also write the figures here")
    args = ap.parse_args()
    results = []
    for name in args.cases:
        r = plan_case(name)
        results.append(r)
        print(f"{name}: {r['status']} ({r['mode']}), plan {r['plan_s']} s, verification {r['verify_s']} s, "
              f"{r['over_moves']} moves over {r['bound_deg']:g} deg, measured in "
              f"{sum(a['seconds'] for a in r['areas']):.2f} s", flush=True)
    print(table(results))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
