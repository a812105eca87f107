"""Issue 31 item 3: what a semi-finishing pass does to the stock the finishing meets, and what it costs.

Per case, the whole plan (``run_plan``: paths, posts, verification) twice in this process, without and with
``paths.semi_finishing.enabled`` (its other parameters at their defaults unless ``--set`` says), and per set-up
in machining order:

* the stock over the set-up's scan points along their normals when its finishing starts, read on the carried
  stock (``setups[].path.roughing.allowance_left_mm``: p50 / p95 / max, mm), without and with the pass; with
  it, also over the points the pass reaches (``semi_finishing.allowance_reached_mm``, ``reached_share``:
  issue 31's "within 2x the allowance where the tool reaches");
* the simulated machining minutes of its roughing, semi-finishing and finishing (``verification.areas[].
  operations``, the programs as the machine runs them) and the volume each removed (cm^3);

and per case the verdict and offences, the finished shares (the stock model's rays and the exact measure
from the finishing moves), the simulated machining time, the plan's and the paths stage's seconds.

    .venv/bin/python bench/bench_semi_finishing.py --cases half_sphere femur_like range_femur

Cases: ``half_sphere`` (the README's plan: normals from the file, 2 set-ups, Ø10 ball), ``femur_like``
(``make run``'s configuration, 1,000,000 points) and ``range_femur`` (the README's own-scan example, a
40,000-point range scan, its overrides from bench/bench_range_scan.py).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "bench"))
sys.path.insert(0, str(HERE / "scripts"))

CASES = ("half_sphere", "femur_like", "range_femur")


def case_input(name: str):
    """(points, normals or None, configuration document, overrides) of a case."""
    from planning.inputs import samples

    if name == "femur_like":
        from demo_service import CONFIGS

        return samples.femur_like().points, None, json.loads(json.dumps(CONFIGS["femur_like"])), []
    if name == "range_femur":
        from bench_range_scan import OVERRIDES

        return samples.make_sample("range_femur", n_points=40_000).points, None, {}, list(OVERRIDES)
    s = samples.half_sphere()
    return s.points, s.normals, {}, ["normals.method=input", "setups.max_setups=2", "tool.diameter_mm=10"]


def plan(name: str, semi: bool, extra: list[str]) -> dict:
    from planning.inputs import Cloud
    from planning.pipeline import run_plan
    from schemas.params import apply_overrides, parse_config

    pts, nrm, doc, sets = case_input(name)
    cfg = parse_config(apply_overrides(doc, sets + [f"paths.semi_finishing.enabled={'true' if semi else 'false'}"]
                                       + extra))
    t0 = time.perf_counter()
    out = run_plan(Cloud(points=pts, normals=nrm, source_format="generated"), cfg, name=name)
    seconds = time.perf_counter() - t0
    r = out.result
    v = r.verification
    setups = {st.id: st for st in r.setups}
    rows = []
    for a in (v.areas if v is not None else []):
        p = setups[a.area].path
        ops = {o.operation: o for o in a.operations}
        semi_s = p.semi_finishing if p is not None else None

        def q(d):
            return None if not d else {k: d[k] for k in ("p50", "p95", "max") if k in d}
        rows.append({
            "area": a.area,
            "finishing_meets": q(p.roughing.allowance_left_mm) if p is not None and p.roughing is not None else None,
            "before_semi": q(semi_s.allowance_before_mm) if semi_s is not None else None,
            "semi_reached": q(semi_s.allowance_reached_mm) if semi_s is not None else None,
            "reached_share": semi_s.reached_share if semi_s is not None else None,
            "min": {k: round(o.machining_time_s / 60.0, 1) for k, o in ops.items()},
            "removed_cm3": {k: round(o.removed_mm3 / 1000.0, 2) for k, o in ops.items()}})
    return {"case": name, "semi": semi, "seconds": round(seconds, 1),
            "paths_s": {t.stage: t.seconds for t in r.timings}.get("paths"),
            "status": v.status if v else None,
            "offences": None if v is None else sum(getattr(v, k) for k in (
                "travel_excursions", "rapids_into_material", "holder_collisions", "fixture_collisions",
                "plunges_into_material")),
            "gouged": None if v is None or v.deviation is None else v.deviation.n_gouged,
            "finished_rays": None if v is None or v.deviation is None else v.deviation.finished_share,
            "finished_exact": None if v is None or v.finish is None else v.finish.finished_share,
            "machining_h": None if v is None else round(v.machining_time_s / 3600, 2),
            "areas": rows}


def _stock(d) -> str:
    return "-" if not d else f"{d['p50']:.2f} / {d['p95']:.2f} / {d['max']:.1f}"


def table(off: dict, on: dict) -> str:
    lines = [f"### {off['case']}", "",
             "| set-up | stock the finishing meets, p50 / p95 / max mm: without | with | with, where the pass reaches "
             "(share of the set-up's points) | roughing / semi / finishing min (with) | finishing removed cm^3: "
             "without -> with |", "|---|---|---|---|---|---|"]
    for a, b in zip(off["areas"], on["areas"]):
        share = "-" if b["reached_share"] is None else f"{b['reached_share']:.1%}"
        lines.append(f"| {a['area']} | {_stock(a['finishing_meets'])} | {_stock(b['finishing_meets'])} | "
                     f"{_stock(b['semi_reached'])} ({share}) | "
                     f"{b['min'].get('roughing', 0)} / {b['min'].get('semi_finishing', 0)} / "
                     f"{b['min'].get('finishing', 0)} | {a['removed_cm3'].get('finishing', 0)} -> "
                     f"{b['removed_cm3'].get('finishing', 0)} |")
    lines += ["", "| | without | with |", "|---|---|---|"]
    for key, label in (("status", "verdict"), ("offences", "offences"), ("gouged", "gouged points"),
                       ("finished_rays", "finished, rays"), ("finished_exact", "finished, exact"),
                       ("machining_h", "simulated machining h"), ("seconds", "plan s"), ("paths_s", "paths s")):
        lines.append(f"| {label} | {off[key]} | {on[key]} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="more overrides for both plans (e.g. paths.semi_finishing.diameter_mm=6)")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    results = []
    for name in args.cases:
        off = plan(name, False, args.set)
        on = plan(name, True, args.set)
        results += [off, on]
        print(table(off, on), flush=True)
        print(flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
