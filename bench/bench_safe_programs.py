"""Issue 16: the programs of the reference cases with and without the carried stock and the guard
(`paths.carry_stock`), planned in the same process, verified on the simulated machine.

Per case and per set-up (in machining order): roughing time (s, at the post's feeds), the volume the
roughing removes from the stock it meets (mm^3; the simulation's figure per program, roughing and
finishing together, in the verification table), finishing time; per case: the verification's offence
counts, finished share, unmachined share, and the whole plan's seconds.

    .venv/bin/python bench/bench_safe_programs.py --cases half_sphere slot post_wall filleted_box \
        --json bench/out/safe_programs/cases.json
    .venv/bin/python bench/bench_safe_programs.py --cases femur_like --json bench/out/safe_programs/femur.json

The femur-like case uses the `make run` configuration (scripts/demo_service.py CONFIGS). Figures are
printed as Markdown tables for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planning.inputs import Cloud, samples  # noqa: E402
from planning.pipeline import run_plan  # noqa: E402
from schemas.params import apply_overrides, parse_config  # noqa: E402

CASES = {
    "half_sphere": (samples.half_sphere, ["normals.method=input", "setups.max_setups=2", "tool.diameter_mm=10"]),
    "slot": (samples.slot, []),
    "post_wall": (samples.post_wall, []),
    "filleted_box": (samples.filleted_box, ["tool.diameter_mm=4"]),
}


def _femur_config() -> dict:
    sys.path.insert(0, str(ROOT / "scripts"))
    from demo_service import CONFIGS

    return json.loads(json.dumps(CONFIGS["femur_like"]))


def plan_case(name: str, carry: bool) -> dict:
    if name == "femur_like":
        s = samples.femur_like()
        cfg = apply_overrides(_femur_config(), [f"paths.carry_stock={str(carry).lower()}"])
        cloud = Cloud(points=s.points, normals=None, source_format="generated")
    else:
        make, sets = CASES[name]
        s = make()
        cfg = apply_overrides({}, sets + [f"paths.carry_stock={str(carry).lower()}"])
        cloud = Cloud(points=s.points, normals=s.normals, source_format="generated")
    t0 = time.perf_counter()
    out = run_plan(cloud, parse_config(cfg), name=name)
    seconds = time.perf_counter() - t0
    r = out.result
    v = r.verification
    by_area = {a.area: a for a in v.areas} if v is not None else {}
    rows = []
    order = r.machining_order or [st.id for st in r.setups]
    setups = {st.id: st for st in r.setups}
    for i in order:
        st = setups[i]
        path = st.path
        rough = path.roughing if path is not None else None
        fin = path.finishing if path is not None else None
        a = by_area.get(i)
        rows.append({"area": i,
                     "roughing_s": rough.machining_time_s if rough is not None else 0.0,
                     "roughing_levels": rough.n_levels if rough is not None else 0,
                     "roughing_removed_mm3": rough.guard.removed_mm3 if rough is not None and rough.guard else None,
                     "finishing_s": fin.machining_time_s if fin is not None else 0.0,
                     "program_removed_mm3": a.removed_mm3 if a is not None else None,
                     "offences": None if a is None else {k: getattr(a, k) for k in (
                         "travel_excursions", "rapids_into_material", "holder_collisions", "fixture_collisions",
                         "plunges_into_material")},
                     "gouged": None if a is None or a.deviation is None else a.deviation.n_gouged})
    return {"case": name, "carry_stock": carry, "seconds": round(seconds, 1), "status": v.status if v else None,
            "message": v.message if v else None,
            "finished_share": v.deviation.finished_share if v and v.deviation else None,
            "unmachined_share": r.unmachined.share if r.unmachined is not None else None,
            "roughing_total_s": round(sum(x["roughing_s"] for x in rows), 1),
            "finishing_total_s": round(sum(x["finishing_s"] for x in rows), 1),
            "timings": {t.stage: t.seconds for t in r.timings}, "setups": rows}


def table(results: list[dict]) -> str:
    lines = ["| case | carry_stock | set-up | roughing min | levels | program removed cm^3 | finishing min | "
             "travel | rapids | holder | fixture | plunges | gouged |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        for x in res["setups"]:
            o = x["offences"] or {}
            rem = x["program_removed_mm3"]
            lines.append(f"| {res['case']} | {res['carry_stock']} | {x['area']} | {x['roughing_s'] / 60:.1f} | "
                         f"{x['roughing_levels']} | {'' if rem is None else f'{rem / 1000:.1f}'} | "
                         f"{x['finishing_s'] / 60:.1f} | {o.get('travel_excursions', '')} | "
                         f"{o.get('rapids_into_material', '')} | {o.get('holder_collisions', '')} | "
                         f"{o.get('fixture_collisions', '')} | {o.get('plunges_into_material', '')} | {x['gouged']} |")
    lines += ["", "| case | carry_stock | verdict | roughing total h | finishing total h | finished share | "
              "unmachined share | plan s |", "|---|---|---|---|---|---|---|---|"]
    for res in results:
        fs = res["finished_share"]
        us = res["unmachined_share"]
        lines.append(f"| {res['case']} | {res['carry_stock']} | {res['status']} | {res['roughing_total_s'] / 3600:.2f} | "
                     f"{res['finishing_total_s'] / 3600:.2f} | {'' if fs is None else f'{fs:.3f}'} | "
                     f"{'' if us is None else f'{us:.3f}'} | {res['seconds']} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=sorted(CASES), choices=sorted(CASES) + ["femur_like"])
    ap.add_argument("--only", choices=["true", "false"], help="run only carry_stock=true or false")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    results = []
    for name in args.cases:
        for carry in (False, True):
            if args.only is not None and str(carry).lower() != args.only:
                continue
            print(f"planning {name} carry_stock={carry} ...", flush=True)
            results.append(plan_case(name, carry))
            print(f"  {results[-1]['status']}: {results[-1]['message']}", flush=True)
    print(table(results))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
