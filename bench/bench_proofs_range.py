"""Benchmark: set-up proofs (feasible optimum and infeasibility) on simulated range scans (issue 32).
Prints figures only.

Each sample is :func:`planning.inputs.samples.range_scan` (``--shape``, default ``femur_like``) at
``--points`` recorded points (default 10k, 20k and 40k; seed ``--seed``; the other scan parameters
at their defaults unless ``--scan`` overrides them, e.g. ``--scan outlier_share=0.01 n_views=12``),
taken through the pipeline's normals, orientations and visibility stages with the default
parameters (as ``bench/bench_infeasible.py`` does for the femur-like sample; no placement), then
:func:`planning.pipeline.selection_matrix`: the matrix the set-up stage receives.  The matrices are
cached under ``--cache-dir`` (.npz, /tmp by default; never commit them).

Per sample, in one worker process (after tiny warm-up calls, the first of which solves an LP; that
import and start of SciPy's HiGHS is printed apart: a plan run pays it once) and in this
order: the feasible case (``--feasible``, coverage 0.80 with ``--max-setups`` 5) and the infeasible
targets (``--infeasible``, default ``0.95:5 0.99:5 0.95:3``: coverage:max_setups).  Printed per
sample: n points, n sampled, classes and axes, then per case the set-up seconds
(``SetupSelection.seconds``), status, k, coverage and overlap.  ``--before REV`` also runs the
planning/setups package of git revision REV on the same matrices (same run, its own worker first),
and prints whether the answers are the same.  ``--json PATH`` writes every figure.

    .venv/bin/python bench/bench_proofs_range.py
    .venv/bin/python bench/bench_proofs_range.py --before e66e245 --json /tmp/proofs_range.json   # e66e245: the commit before the change
    .venv/bin/python bench/bench_proofs_range.py --points 40000 --scan outlier_share=0.01
    .venv/bin/python bench/bench_proofs_range.py --scales 1 --scan along_mm=1.0 across_mm=2.0   # a full-size bone
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def _scan_kwargs(items):
    out = {}
    for it in items or []:
        k, v = it.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
        if isinstance(out[k], list):
            out[k] = tuple(out[k])
    return out


def range_visibility(shape: str, n_points: int, seed: int, scan: dict, cache_dir: str):
    """(selection matrix (n sampled x feasible axes, bool), n recorded points), cached."""
    tag = hashlib.sha1(json.dumps([shape, n_points, seed, sorted(scan.items())], default=str).encode()).hexdigest()[:10]
    path = os.path.join(cache_dir, f"scanmill_range_vis_{shape}_{n_points}_{tag}.npz")
    if os.path.exists(path):
        d = np.load(path)
        return d["visible"], int(d["n_points"])
    from planning import pipeline as pl
    from planning.inputs import Cloud
    from planning.inputs.samples import range_scan
    from planning.orientations import load_profile
    from schemas.params import PlanConfig

    t = time.perf_counter()
    if n_points < 0:  # a scale instead of a point count: -n_points / 1000
        s = range_scan(shape, scale=-n_points / 1000.0, seed=seed, **scan)
    else:
        s = range_scan(shape, n_points=n_points, seed=seed, **scan)
    cloud = Cloud(points=s.points, normals=None, source_format="generated")
    cfg = PlanConfig()
    profile = load_profile(cfg.machine.profile)
    nrm = pl._normals(cloud, cfg, None)
    ori = pl._orientations(cfg, profile)
    _, gv = pl._visibility(cloud.points, nrm, ori, cfg, cfg.tool.assembly(), profile, None, None)
    V = np.ascontiguousarray(pl.selection_matrix(gv.visible, ori.axes, nrm.normals, cfg), dtype=bool)
    np.savez_compressed(path, visible=V, n_points=s.points.shape[0])
    print(f"(built {shape} {n_points}: {s.points.shape[0]} points -> {V.shape} in "
          f"{time.perf_counter() - t:.1f} s, cached in {path})", flush=True)
    return V, int(s.points.shape[0])


# ------------------------------------------------------------------------------------------------
# worker: one solver version, every case, figures as JSON on stdout


def worker(npz: str, cases: list, setups_dir: str | None, time_limit: float):
    from bench_infeasible import select_setups_of

    select_setups = select_setups_of(setups_dir)
    t = time.perf_counter()  # the first LP of the process: SciPy's optimize import and HiGHS
    select_setups(np.eye(6, dtype=bool), coverage=0.95, max_setups=3)
    cold = time.perf_counter() - t
    data = np.load(npz)
    out = [{"name": "_cold", "seconds": cold}]
    for name, cov, K in cases:
        V = data[name]
        r = select_setups(V, coverage=cov, max_setups=K, time_limit_s=time_limit)
        out.append({"name": name, "coverage": cov, "max_setups": K, "seconds": r.seconds, "status": r.status,
                    "k": r.k, "covered": r.covered, "overlap": r.overlap, "selected": r.selected.tolist(),
                    "n": r.n_points, "classes": r.n_classes, "axes": r.n_axes_kept, "message": r.message})
    print("JSON " + json.dumps(out), flush=True)


def run_worker(npz, cases, setups_dir, time_limit):
    from bench_infeasible import run_json_worker

    return run_json_worker(__file__, ["--worker", npz, "--cases", json.dumps(cases), "--time-limit",
                                      str(time_limit)], setups_dir)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shape", default="femur_like")
    ap.add_argument("--points", type=int, nargs="+", default=[10_000, 20_000, 40_000])
    ap.add_argument("--scales", type=float, nargs="*", default=[],
                    help="scan the part at these scales instead of --points (the count follows from the pitches)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scan", nargs="*", default=[], help="range_scan keyword=value overrides (JSON values)")
    ap.add_argument("--feasible", default="0.80:5", help="coverage:max_setups of the feasible case")
    ap.add_argument("--infeasible", nargs="*", default=["0.95:5", "0.99:5", "0.95:3"])
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--cache-dir", default=tempfile.gettempdir())
    ap.add_argument("--before", metavar="REV", help="also run planning/setups of this git revision")
    ap.add_argument("--json", metavar="PATH", help="write every figure here")
    ap.add_argument("--worker", metavar="NPZ", help=argparse.SUPPRESS)
    ap.add_argument("--cases", help=argparse.SUPPRESS)
    ap.add_argument("--setups-dir", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        worker(a.worker, [tuple(c) for c in json.loads(a.cases)], a.setups_dir, a.time_limit)
        return

    scan = _scan_kwargs(a.scan)
    specs = [a.feasible, *a.infeasible]
    targets = [(float(s.split(":")[0]), int(s.split(":")[1])) for s in specs]
    samples = {}
    sizes = [-round(sc * 1000) for sc in a.scales] if a.scales else a.points
    for n in sizes:
        V, npts = range_visibility(a.shape, n, a.seed, scan, a.cache_dir)
        samples[f"{a.shape}_{n}" if n > 0 else f"{a.shape}_scale{-n / 1000:g}"] = (V, npts)
    cases = [(name, c, K) for name in samples for c, K in targets]
    load = os.getloadavg()[0]
    print(f"shape {a.shape}, scan overrides {scan or '-'}, load average {load:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        npz = os.path.join(tmp, "instances.npz")
        np.savez(npz, **{k: v[0] for k, v in samples.items()})
        from bench_infeasible import solver_runs

        runs = solver_runs(a.before, tmp)
        results = {}
        for label, d in runs:
            results[label] = run_worker(npz, cases, d, a.time_limit)
    for label, res in results.items():
        print(f"\n== {label}")
        print(f"  first LP of the process (SciPy optimize import + HiGHS start; not in the figures below): "
              f"{res[0]['seconds']:.2f} s")
        res = res[1:]
        for name, (V, npts) in samples.items():
            rs = [r for r in res if r["name"] == name]
            print(f"  {name}: {npts} points, {V.shape[0]} sampled, {rs[0]['classes']} classes x {rs[0]['axes']} axes")
            for r in rs:
                kind = "feasible case" if (r["coverage"], r["max_setups"]) == targets[0] else "target       "
                print(f"    {kind} coverage {r['coverage']:<6g} max {r['max_setups']}: {r['seconds']:6.2f} s  "
                      f"{r['status']:>10} k {r['k']} covered {r['covered'] / r['n'] * 100:.2f} % "
                      f"overlap {r['overlap']}")
    if a.before:
        b, f = (results[label][1:] for label, _ in runs)
        print("\n== before -> after")
        for rb, ra in zip(b, f, strict=True):
            same = all(rb[x] == ra[x] for x in ("status", "k", "covered", "overlap", "selected"))
            print(f"  {rb['name']} coverage {rb['coverage']:<6g} max {rb['max_setups']}: {rb['seconds']:.2f} s -> "
                  f"{ra['seconds']:.2f} s, same answer: {same}")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"shape": a.shape, "scan": scan, "seed": a.seed,
                       "samples": {k: {"n_points": v[1], "n_sampled": int(v[0].shape[0]), "axes": int(v[0].shape[1])}
                                   for k, v in samples.items()},
                       "results": results}, fh, indent=1)


if __name__ == "__main__":
    main()
