"""Benchmark: the placement search (``fixtures.placement = "auto"``, issue 18) on the femur-like scan with the
default set-up parameters.  Prints figures only.

The case of ``bench/bench_infeasible.py``: the femur-like sample (``planning.inputs.samples.femur_like``, 1M
points) with the default configuration (cone [10, 80], travel and collisions on with every input point an
obstacle, fixture height 50 mm, tool 6 mm, coverage 0.95, max 5 set-ups, machine ``compact_trunnion_bc``).  As
scanned the best 5 set-ups cover 94.1 %: infeasible.  The normals stage runs once (timed apart: the plan needs
it anyway), then the placement stage's own call, :func:`planning.placement.search_placement`, tries every
candidate pose (as scanned, the stable hull faces, the principal axes up and down) and either finds one that
reaches the coverage or proves that none of them does.  Per candidate it prints how far it was evaluated
(``bound``: ruled out by the price bound before any collision test; ``screened``: the collision test with the
sampled points as obstacles and the set-up search; ``confirmed``: the plan's own stages), its best coverage or
bound, and its time; then the total.  ``uptime``'s load is printed before and after (the machine is shared).

    .venv/bin/python bench/bench_placement.py
    .venv/bin/python bench/bench_placement.py --coverage 0.94      # a coverage some placement reaches
    .venv/bin/python bench/bench_placement.py --plan               # also run_plan with auto (no paths)
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def load() -> str:
    try:
        return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover
        return "load unknown"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--coverage", type=float, default=0.95)
    ap.add_argument("--max-setups", type=int, default=5)
    ap.add_argument("--points", type=int, default=None, help="points of the femur-like sample (default: 1M)")
    ap.add_argument("--plan", action="store_true", help="also run run_plan with placement auto, paths off")
    a = ap.parse_args(argv)

    from planning import pipeline as pl
    from planning.inputs import Cloud
    from planning.inputs.samples import femur_like
    from planning.orientations import load_profile
    from planning.placement import candidate_poses, full_yaw, search_placement
    from schemas.params import parse_config

    print(f"before: {load()} on {os.cpu_count()} cores", flush=True)
    t = time.perf_counter()
    s = femur_like(**({"n_points": a.points} if a.points else {}))
    cloud = Cloud(points=s.points, normals=None, source_format="generated")
    print(f"femur-like sample: {s.points.shape[0]:,} points ({time.perf_counter() - t:.1f} s to generate, not timed)")
    cfg = parse_config({"setups": {"coverage": a.coverage, "max_setups": a.max_setups},
                        "fixtures": {"placement": "auto"}})
    profile = load_profile(cfg.machine.profile)
    tool = cfg.tool.assembly()

    t0 = time.perf_counter()
    nrm = pl._normals(cloud, cfg, None)
    t_normals = time.perf_counter() - t0
    print(f"normals: {nrm.sample_index.size:,} sampled points in {t_normals:.2f} s", flush=True)

    t1 = time.perf_counter()

    def progress(fraction, message=""):
        print(f"  [{time.perf_counter() - t1:6.1f} s] {fraction:4.2f} {message}", flush=True)

    poses = candidate_poses(cloud.points, full_yaw=full_yaw(profile))      # what search_placement lists itself
    print(f"poses: {len(poses)} candidates (hull, covariance) in {time.perf_counter() - t1:.2f} s", flush=True)
    res = search_placement(cloud.points, nrm.sample_index, nrm.normals, cfg, profile, tool, poses=poses,
                           progress=progress)
    t_search = time.perf_counter() - t1                                     # the poses included

    print(f"\n{len(res.tried)} candidates, coverage {a.coverage:g} with at most {a.max_setups} set-ups "
          f"({res.required:,} of {res.n_sampled:,} sampled points):")
    print(f"  {'#':>2} {'candidate':<48} {'stage':<9} {'k':>2} {'coverage':>9} {'bound':>8} {'height mm':>9} {'s':>6}")
    for c in res.tried:
        cov = "" if c.coverage is None else f"{c.coverage * 100:.2f} %"
        bnd = "" if c.coverage_bound is None else f"{c.coverage_bound * 100:.2f} %"
        verdict = {True: "feasible", False: "no", None: "?"}[c.feasible]
        print(f"  {c.index:>2} {c.pose.label[:48]:<48} {c.stage:<9} {'' if c.k is None else c.k:>2} {cov:>9} "
              f"{bnd:>8} {c.pose.part_height_mm:9.1f} {c.seconds:6.2f}  {verdict}")
    print(f"\n{res.message}")
    print(f"placement search {t_search:.1f} s; with the normals {t_normals + t_search:.1f} s")
    print(f"after: {load()}", flush=True)

    if a.plan:
        cfg2 = parse_config({"setups": {"coverage": a.coverage, "max_setups": a.max_setups},
                             "fixtures": {"placement": "auto"}, "simulate": {"enabled": False},
                             "paths": {"finishing": {"enabled": False}, "roughing": {"enabled": False}}})
        t2 = time.perf_counter()
        out = pl.run_plan(cloud, cfg2, name="femur_like")
        r = out.result
        print(f"\nrun_plan (placement auto, no paths): {time.perf_counter() - t2:.1f} s, {r.status}: {r.message}")
        print("  " + ", ".join(f"{x.stage} {x.seconds:.2f} s" for x in r.timings))
        print(f"  placement: {r.placement.label}, R {np.round(np.array(r.placement.rotation), 4).tolist()}, "
              f"t {np.round(r.placement.translation_mm, 3).tolist()} mm")
        print(f"after: {load()}", flush=True)


if __name__ == "__main__":
    main()
