"""Simultaneous 5-axis finishing against 3+2 on the same scan (issue 19): set-ups, finished share,
seams, machining and path time, offences, seconds.

    .venv/bin/python bench/bench_fiveaxis.py                      # femur-like, 1,000,000 points
    .venv/bin/python bench/bench_fiveaxis.py --points 200000 --five-setups 1 2
    .venv/bin/python bench/bench_fiveaxis.py --sample draft_slot --three-setups 3 --five-setups 1
    .venv/bin/python bench/bench_fiveaxis.py --sample range_femur --five-setups 2

``--sample draft_slot``: the draft-walled slot of tests/test_fiveaxis_plan.py (top only, exact
normals, cone [10, 45], light paths) instead. ``--sample range_femur``: the simulated 40,000-point
range scan of issue 24 (``samples.make_sample("range_femur")``; ``--points`` sets its size), planned with the
README's own-scan settings (bench/bench_range_scan.py OVERRIDES: the defaults, coverage 0.9, 5 set-ups).

Each plan runs the whole pipeline (paths, posts, the verification on the simulated machine) with the
femur-like reference parameters (scripts/demo_service.py CONFIGS["femur_like"]: sphere 7 mm, tool
6 mm, fixture 150 mm, cone [10, 60], coverage 0.85, max 5 set-ups), once in 3+2 and once per
``--five-setups`` value in 5axis (``setups.max_setups`` = that many pass directions, one clamping).
Printed per plan:

* ``setups``: the set-ups (3+2: fixed axes; 5axis: pass directions), the selection's status;
* ``finished``: the share of the scan within tolerance of the simulated stock (verification);
* ``unmachined``: scan points no kept finishing move reaches (plan.json unmachined);
* ``seam_pts``: scan points with a neighbour (8 nearest) in another area: where re-positioning
  errors show (Makki); ``seam_mm``: the areas stage's seam length;
* ``offences``: rapids into material, holder, fixture, travel, rotary feed, gouged points (all 0 to
  pass); the C words' range of the LinuxCNC programs (the register, issue 33 item 3);
* ``machine_s``: the verification's machining time of every program (feeds, rapids, no
  acceleration); ``finish_s``: the finishing paths' time alone (plan.json setups[].path.finishing);
* ``plan_s``: wall time of the plan, and the paths stage's seconds.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from planning.inputs import Cloud, samples
from planning.pipeline import run_plan
from schemas.params import parse_config

FEMUR = {"normals": {"method": "sphere_throwing", "sphere_diameter_mm": 7.0},
         "tool": {"diameter_mm": 6.0}, "fixtures": {"fixture_height_mm": 150.0},
         "visibility": {"cone_deg": [10, 60], "global": True, "travel": True},
         "setups": {"coverage": 0.85, "max_setups": 5}}


def seam_points(points: np.ndarray, labels: np.ndarray, k: int = 8) -> int:
    """Scan points with one of their ``k`` nearest neighbours in another area."""
    _, j = cKDTree(points).query(points, k=k + 1)
    return int((labels[j[:, 1:]] != labels[:, None]).any(axis=1).sum())


SLOT = {"normals": {"method": "input"}, "visibility": {"cone_deg": [10, 45]},
        "paths": {"finishing": {"scallop_mm": 0.2}, "roughing": {"step_down_mm": 5}}, "simulate": {"resolution_mm": 1.0}}


#: The README's own-scan settings (bench/bench_range_scan.py OVERRIDES), the defaults otherwise.
RANGE = {"setups": {"coverage": 0.9, "max_setups": 5}}


def rotary_word_range(programs: dict, letter: str = "C") -> tuple[float, float]:
    """``(min, max)`` of the ``letter`` words over the LinuxCNC programs (the C register, issue 33)."""
    vals = [float(m) for name, text in programs.items() if name.endswith(".linuxcnc.nc")
            for m in re.findall(rf"\b{letter}(-?\d+(?:\.\d*)?)", text)]
    return (min(vals), max(vals)) if vals else (float("nan"), float("nan"))


def one(cloud: Cloud, mode: str, max_setups: int, base: dict = FEMUR) -> dict:
    cfg = {**base, "setups": {**base.get("setups", {}), "max_setups": max_setups},
           "paths": {**base.get("paths", {}), "finishing": {**base.get("paths", {}).get("finishing", {}), "mode": mode}}}
    t0 = time.perf_counter()
    out = run_plan(cloud, parse_config(cfg), name=f"femur {mode}")
    wall = time.perf_counter() - t0
    r, v = out.result, out.result.verification
    fin = [s.path.finishing for s in r.setups if s.path is not None and s.path.finishing is not None]
    paths_s = next((t.seconds for t in r.timings if t.stage == "paths"), float("nan"))
    return {
        "mode": mode, "max_setups": max_setups, "status": r.status, "k": r.selection.k,
        "coverage": r.coverage, "finished": v.deviation.finished_share if v and v.deviation else float("nan"),
        "unmachined": r.unmachined.n_points if r.unmachined else 0,
        "seam_pts": seam_points(out.points, out.input_labels), "seam_mm": r.areas.seam_mm,
        "offences": (v.rapids_into_material, v.holder_collisions, v.fixture_collisions, v.travel_excursions,
                     getattr(v, "rotary_feed_excesses", -1), v.deviation.n_gouged if v.deviation else -1) if v else None,
        "c_range": rotary_word_range(out.extra.get("programs", {})),
        "verification": v.status if v else None, "machine_s": v.machining_time_s if v else float("nan"),
        "finish_s": sum(f.machining_time_s for f in fin), "plan_s": wall, "paths_s": paths_s,
        "five": [f.five_axis for f in fin if f.five_axis is not None],
        "guards": [(s.id, s.path.finishing.guard.found, s.path.finishing.guard.dropped, s.path.finishing.guard.truncated)
                   for s in r.setups if s.path is not None and s.path.finishing is not None
                   and s.path.finishing.guard is not None],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sample", choices=["femur_like", "draft_slot", "range_femur"], default="femur_like")
    ap.add_argument("--points", type=int, default=None,
                    help="points of the femur-like (default 1,000,000) or range femur (default 40,000) sample")
    ap.add_argument("--three-setups", type=int, default=5, help="setups.max_setups of the 3+2 plan (default 5)")
    ap.add_argument("--five-setups", type=int, nargs="+", default=[1, 2],
                    help="setups.max_setups of the 5axis plans (default 1 2)")
    args = ap.parse_args(argv)
    if args.sample == "draft_slot":
        s = samples.draft_slot(density_per_mm2=1.0, seed=1, include_sides=False)
        cloud, base = Cloud(points=s.points, normals=s.normals, source_format="generated"), SLOT
    elif args.sample == "range_femur":
        s = samples.make_sample("range_femur", n_points=args.points or 40_000)
        cloud, base = Cloud(points=s.points, normals=None, source_format="generated"), RANGE
    else:
        s = samples.femur_like(n_points=args.points or 1_000_000, seed=0)
        cloud, base = Cloud(points=s.points, normals=None, source_format="generated"), FEMUR
    rows = [one(cloud, "3+2", args.three_setups, base)] + [one(cloud, "5axis", k, base) for k in args.five_setups]
    print(f"{args.sample}, {cloud.points.shape[0]:,} points")
    print(f"{'mode':6} {'max':>3} {'k':>2} {'status':10} {'cover':>6} {'finished':>8} {'unmach':>7} {'seam_pts':>8} "
          f"{'seam_mm':>8} {'verdict':8} {'offences':18} {'machine_s':>9} {'finish_s':>8} {'plan_s':>7} {'paths_s':>7}")
    for r in rows:
        print(f"{r['mode']:6} {r['max_setups']:>3} {r['k']:>2} {r['status']:10} {r['coverage']:6.3f} "
              f"{r['finished']:8.3f} {r['unmachined']:7d} {r['seam_pts']:8d} {r['seam_mm']:8.0f} "
              f"{r['verification']!s:8} {r['offences']!s:18} {r['machine_s']:9.1f} {r['finish_s']:8.1f} "
              f"{r['plan_s']:7.1f} {r['paths_s']:7.1f}")
    base = rows[0]
    for r in rows[1:]:
        if base["finish_s"] > 0:
            print(f"5axis max_setups {r['max_setups']}: finishing path time {r['finish_s'] / base['finish_s']:.2f}x "
                  f"the 3+2 plan's, machining time {r['machine_s'] / max(base['machine_s'], 1e-9):.2f}x")
        print(f"  finishing guard per set-up (found, dropped, truncated): {r['guards']}")
        print(f"  C words of the LinuxCNC programs: {r['c_range'][0]:.3f} .. {r['c_range'][1]:.3f} deg")
        for f in r["five"]:
            print(f"  positions {f.n_positions}, alternatives {f.n_alternatives}, blocked {f.blocked}, cone "
                  f"{f.cone_deg}, swing {f.swing_deg}, rate {f.max_rate_deg_per_mm} deg/mm, biarcs {f.n_biarcs} "
                  f"({f.n_arcs} arcs for {f.n_moves_before_biarcs} moves, error {f.biarc_max_error_mm} mm, "
                  f"clearance {f.biarc_min_clearance_mm} mm)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
