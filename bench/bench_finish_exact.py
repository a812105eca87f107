"""Benchmark: the finish measured exactly from the finishing moves (issue 31 item 1). Prints figures only.

Per case the plan is made with ``simulate.exact_finish = false`` (its own seconds: the plan without the
measure), then, in the same process, its LinuxCNC programs are read back as the verification reads
them and :func:`planning.simulate.finish.finish_left_mm` measures the scan points the verification
measures (all, or ``simulate.exact_finish_points`` drawn at random), timed with numba's threads set to
1 and then to 2 (``--threads``), each ``--repeat`` times (the least is printed); ``--all-points``: then
every point of a larger scan once, to compare the sample's share with the whole scan's. The
figures: the finished share by the stock model's rays (``verification.deviation``, what the plan
reported until now) and by the exact measure (``verification.finish``, as the verification now
computes it), the share reached, the material left over the reached points, the scallop over the
finished ones, the deepest cut.

Cases (``--cases``): ``femur_like`` (the ``make run`` plan of 1M points, bench/bench_scaling.py's
configuration), ``range_femur`` (the README's own-scan example: the simulated 40k-point range scan on
a 100 mm riser), ``half_sphere`` (the reference sample, defaults with input normals and 2 set-ups).

    .venv/bin/python bench/bench_finish_exact.py --all-points
    .venv/bin/python bench/bench_finish_exact.py --cases range_femur half_sphere --threads 1 2
    .venv/bin/python bench/bench_finish_exact.py --cases femur_like range_femur --noise-mm 0 --threads 2 --repeat 1
    .venv/bin/python bench/bench_finish_exact.py --cases femur_like --noise-mm 0 --threads 2 --repeat 1 --where
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))


def _case(name: str, noise_mm: float | None = None):
    """(cloud, PlanConfig) of a case; ``noise_mm``: the scan noise of the femur-like and range samples
    (None: their defaults, 0.03 and 0.02 mm)."""
    from planning.inputs import Cloud
    from planning.inputs.samples import make_sample
    from schemas.params import apply_overrides, parse_config

    off = ["simulate.exact_finish=false"]
    kw = {} if noise_mm is None else {"noise_mm": float(noise_mm)}
    if name == "femur_like":
        from bench_scaling import _config

        s = make_sample("femur_like", n_points=1_000_000, **kw)
        return Cloud(points=s.points, normals=None, source_format="generated"), \
            parse_config(apply_overrides(_config(), off))
    if name == "range_femur":
        s = make_sample("range_femur", **kw)
        return Cloud(points=s.points, normals=None, source_format="generated"), \
            parse_config(apply_overrides({}, ["fixtures.fixture_height_mm=100", *off]))
    if name == "half_sphere":
        s = make_sample("half_sphere")
        return Cloud(points=s.points, normals=s.normals, source_format="generated"), \
            parse_config(apply_overrides({}, ["normals.method=input", "setups.max_setups=2", *off]))
    raise SystemExit(f"unknown case {name!r}")


def _where(out, motions, fin, limit: float, below: float, n: int = 20_000) -> list[dict]:
    """The exact finish of ``n`` points drawn at random (each against every program): over the points
    the chosen set-ups see (covered) and per class the plan gives a point on the rays
    (:mod:`planning.report.figures`); then per area (its own points) by the angle between the point's
    normal (PCA of its 20 nearest scan points) and the area's tool axis, and by the distance to the
    nearest point of another area (the seams)."""
    from scipy.spatial import cKDTree

    from planning.simulate.finish import finish_left_mm

    pts, lab = out.points, out.input_labels
    idx = np.random.default_rng(0).choice(pts.shape[0], min(n, pts.shape[0]), replace=False)
    P, L = pts[idx], lab[idx]
    left = finish_left_mm(P, motions, fin)
    _, nb = cKDTree(pts).query(P, k=20)
    Q = pts[nb] - pts[nb].mean(axis=1, keepdims=True)
    normal = np.linalg.eigh(np.einsum("nki,nkj->nij", Q, Q))[1][:, :, 0]
    rows = []
    from planning.report.figures import FINISHED, LEFT, NOT_COVERED, UNREACHED

    cls = np.asarray(out.extra["point_classes"])[idx]
    done_all = (left <= limit) & (left >= -below)
    for name, m in (("covered (seen by a chosen set-up)", cls != NOT_COVERED), ("rays: finished", cls == FINISHED),
                    ("rays: left", cls == LEFT), ("rays: unreached", cls == UNREACHED),
                    ("rays: not covered", cls == NOT_COVERED)):
        if m.any():
            rows.append({"area": "all", "by": name, "range": (0, 0), "n": int(m.sum()),
                         "finished": float(done_all[m].mean()),
                         "left_p50_mm": float(np.percentile(np.maximum(left[m], 0.0), 50))})
    for st in out.result.setups:
        m = L == st.id
        if not m.any():
            continue
        slope = np.degrees(np.arccos(np.clip(np.abs(normal[m] @ np.asarray(st.tool_axis, float)), 0.0, 1.0)))
        seam = cKDTree(pts[lab != st.id]).query(P[m], k=1)[0] if (lab != st.id).any() else np.full(m.sum(), np.inf)
        lm = left[m]
        done = (lm <= limit) & (lm >= -below)
        for kind, val, edges in (("slope deg", slope, (0, 30, 45, 60, 90.1)), ("seam mm", seam, (0, 1, 3, np.inf))):
            for lo, hi in zip(edges[:-1], edges[1:]):
                k = (val >= lo) & (val < hi)
                if k.sum():
                    rows.append({"area": st.id, "by": kind, "range": (lo, hi), "n": int(k.sum()),
                                 "finished": float(done[k].mean()),
                                 "left_p50_mm": float(np.percentile(np.maximum(lm[k], 0.0), 50))})
    return rows


def run_case(name: str, threads: list[int], repeat: int, all_points: bool, noise_mm: float | None = None,
             where: bool = False) -> dict:
    import numba

    from planning.orientations.kinematics import load_profile
    from planning.pipeline import run_plan
    from planning.simulate.finish import finish_left_mm
    from planning.simulate.program import read_program
    from planning.simulate.verify import finish_figures, finish_sample, gouge_allowance_mm, tool_shapes

    cloud, cfg = _case(name, noise_mm)
    t = time.perf_counter()
    out = run_plan(cloud, cfg, name=name)
    plan_s = time.perf_counter() - t
    r = out.result
    v = r.verification
    profile = load_profile(cfg.machine.profile)
    tools = tool_shapes(cfg, cfg.tool.assembly())
    fin = tools[cfg.post.finishing_tool_number]
    place = np.asarray(r.visibility.placement_mm, dtype=float)
    motions = [read_program(out.extra["programs"][f"area_{a}.linuxcnc.nc"], dialect="linuxcnc",
                            program=f"area_{a}.linuxcnc.nc", area=a, profile=profile, placement_mm=place,
                            tools=tools) for a in r.machining_order if f"area_{a}.linuxcnc.nc" in out.extra["programs"]]
    n_fin = sum(int(((m.kind == 1) & (m.tool == fin.number)).sum()) for m in motions)
    idx = finish_sample(out.points.shape[0], cfg.simulate.exact_finish_points)   # as the verification draws them
    secs = {}
    left = None
    for th in threads:
        numba.set_num_threads(min(th, numba.config.NUMBA_NUM_THREADS))
        best = np.inf
        for _ in range(repeat):
            t = time.perf_counter()
            left = finish_left_mm(out.points[idx], motions, fin)
            best = min(best, time.perf_counter() - t)
        secs[th] = best
    fp = cfg.paths.finishing
    below = gouge_allowance_mm(cfg)
    f = finish_figures(left, fp.scallop_mm, fp.tolerance_mm, below)
    every = None
    if all_points and idx.size < out.points.shape[0]:   # the sample against every point, on all threads
        t = time.perf_counter()
        fa = finish_figures(finish_left_mm(out.points, motions, fin), fp.scallop_mm, fp.tolerance_mm, below)
        every = {"seconds": time.perf_counter() - t, "finished_share": fa.finished_share,
                 "left_p95_mm": fa.left_p95_mm, "threads": numba.get_num_threads()}
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    return {"case": name, "n_points": int(out.points.shape[0]), "finishing_feed_moves": n_fin,
            "plan_s": plan_s, "verification_s": float(v.seconds), "verdict": v.status,
            "finish_s": secs, "stock_model_finished_share": v.deviation.finished_share,
            "stock_model_left_p50_mm": v.deviation.left_p50_mm, "stock_model_left_p95_mm": v.deviation.left_p95_mm,
            "plan_figures_finished_share": r.figures.finished_share if r.figures is not None else None,
            "n_measured": int(idx.size), "exact": f.model_dump(), "every_point": every,
            "where": _where(out, motions, fin, f.limit_mm, below) if where else None}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["femur_like", "range_femur", "half_sphere"])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--all-points", action="store_true",
                    help="also measure every point of a scan larger than simulate.exact_finish_points (last threads)")
    ap.add_argument("--noise-mm", type=float, default=None,
                    help="scan noise of the femur-like and range femur samples (default: theirs, 0.03 / 0.02 mm)")
    ap.add_argument("--where", action="store_true",
                    help="per area, the exact finish by the slope to the tool axis and by the distance to a seam")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f}", flush=True)
    rows = []
    for name in a.cases:
        row = run_case(name, a.threads, a.repeat, a.all_points, a.noise_mm, a.where)
        rows.append(row)
        e = row["exact"]
        print(f"{name}: {row['n_points']:,} points, {row['finishing_feed_moves']:,} finishing feed moves; plan "
              f"{row['plan_s']:.1f} s (verification {row['verification_s']:.1f} s), {row['verdict']}", flush=True)
        print(f"  exact measure on {row['n_measured']:,} points: " + ", ".join(
            f"{th} thread{'s' if th > 1 else ''} {s:.2f} s" for th, s in row["finish_s"].items()))
        if row["every_point"]:
            ev = row["every_point"]
            print(f"  every point ({ev['threads']} threads): {ev['seconds']:.1f} s, finished {ev['finished_share']:.2%} "
                  f"(the sample: {e['finished_share']:.2%}), left p95 {ev['left_p95_mm']:.3f} mm")
        print(f"  finished: stock model {row['stock_model_finished_share']:.1%} (left p50 "
              f"{row['stock_model_left_p50_mm']:.3f}, p95 {row['stock_model_left_p95_mm']:.3f} mm); exact "
              f"{e['finished_share']:.1%} within {e['limit_mm']:g} mm, reached {e['reached_share']:.1%}, left p50 "
              f"{e['left_p50_mm']:.4f}, p95 {e['left_p95_mm']:.3f}, max {e['left_max_mm']:.2f} mm, scallop p95 "
              f"{e['scallop_p95_mm']:.4f} mm, deepest below {e['below_max_mm']:.4f} mm "
              f"({e['n_below_tolerance']} points beyond the tolerance)", flush=True)
        for w in row["where"] or []:
            rng = "" if w["area"] == "all" else f" {w['range'][0]:g}-{w['range'][1]:g}"
            print(f"    area {w['area']} {w['by']}{rng}: {w['n']:6,} points, finished "
                  f"{w['finished']:.1%}, left p50 {w['left_p50_mm']:.4f} mm")
    print(f"load average after {os.getloadavg()[0]:.2f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
