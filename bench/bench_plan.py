"""Whole-plan benchmark on the femur-like reference scan (docs/design.md "Performance").

Prints, for a femur-like cloud (default 1,000,000 points, sphere 7 mm, five throwing directions,
cone [10, 60] deg, max_setups 5, coverage 95 %): seconds and peak RSS after each pipeline stage,
and, in the same run on the same cloud, Open3D ``estimate_normals`` (KNN 20) seconds beside
sphere throwing, so the ratio is between peers measured together. Figures only, no assertions.

    .venv/bin/python bench/bench_plan.py [--points 1000000] [--repeat 2]
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

import numpy as np


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _args() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=2, help="repeats of the normals comparison")
    ap.add_argument("--cone", type=float, nargs=2, default=(10.0, 60.0))
    ap.add_argument("--max-setups", type=int, default=5)
    ap.add_argument("--no-write", action="store_true", help="skip writing the artifacts")
    ap.add_argument("--no-global", action="store_true", help="skip the collision checks (visibility.global false)")
    ap.add_argument("--fixture-height", type=float, default=150.0,
                    help="part's lowest point above the table, mm (150: a riser; at 50 the table blocks the "
                         "underside and the plan is infeasible)")
    ap.add_argument("--obstacles", choices=("all", "sampled"), default="all",
                    help="cloud points the collision test checks (visibility.obstacles)")
    ap.add_argument("--no-paths", action="store_true", help="skip the tool paths (paths.*.enabled false)")
    ap.add_argument("--no-roughing", action="store_true", help="finishing paths only")
    ap.add_argument("--travel", action="store_true",
                    help="check X/Y/Z travel on the default profile (the 400 mm femur does not fit it at 60 deg)")
    return ap.parse_args()


def _normals_side_by_side(s, repeat: int) -> None:
    """Sphere throwing and Open3D KNN-20 normals on the same cloud, alternately, and the error of ours."""
    import open3d as o3d

    from planning.normals import sphere_throwing

    pts = s.points
    print("\nnormals, same cloud, same run (seconds):")
    print(f"{'run':>4} {'sphere_throwing(5 dirs)':>24} {'open3d KNN20':>14} {'ratio':>7}")
    for i in range(repeat):
        t = time.perf_counter()
        res = sphere_throwing(pts, sphere_diameter_mm=7.0)
        t_st = time.perf_counter() - t
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        t = time.perf_counter()
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(20))
        t_o3d = time.perf_counter() - t
        print(f"{i:>4} {t_st:>24.2f} {t_o3d:>14.2f} {t_st / t_o3d:>7.2f}")
        del pcd
    if s.normals is not None:
        ang = np.degrees(np.arccos(np.clip(np.sum(res.normals * s.normals[res.sample_index], axis=1), -1, 1)))
        print(f"sphere throwing: {res.sample_index.size} points with normals ({res.sample_index.size / len(pts):.1%}), "
              f"grid {res.grid_spacing_mm:.3f} mm; error vs exact normals: median {np.median(ang):.2f} deg, "
              f"p95 {np.percentile(ang, 95):.2f} deg")


def _config(args):
    from schemas.params import parse_config

    return parse_config({"visibility": {"cone_deg": list(args.cone), "global": not args.no_global,
                                       "travel": args.travel, "obstacles": args.obstacles},
                        "fixtures": {"fixture_height_mm": args.fixture_height},
                        "setups": {"max_setups": args.max_setups, "coverage": 0.95},
                        "tool": {"diameter_mm": 6.0},
                        "paths": {"finishing": {"enabled": not args.no_paths},
                                  "roughing": {"enabled": not (args.no_paths or args.no_roughing)}}})


def _whole_plan(pts, cfg, args):
    """Run and time the plan (and its writing), printing seconds and peak RSS per stage."""
    from planning.inputs import Cloud
    from planning.pipeline import run_plan
    from planning.report.plan_files import write_plan

    marks: dict[str, float] = {}

    def progress(stage, fraction, message):
        if fraction >= 1.0:
            marks[stage] = peak_rss_mb()

    t = time.perf_counter()
    out = run_plan(Cloud(points=pts, normals=None, source_format="generated"), cfg, name="femur_like",
                   progress=progress)
    total = time.perf_counter() - t
    r = out.result
    print(f"\nwhole plan (cone {list(args.cone)}, max_setups {args.max_setups}):")
    print(f"{'stage':<14}{'seconds':>9}{'peak RSS MB':>13}")
    for tm in r.timings:
        print(f"{tm.stage:<14}{tm.seconds:>9.2f}{marks.get(tm.stage, float('nan')):>13.0f}")
    if not args.no_write:
        with tempfile.TemporaryDirectory() as d:
            t = time.perf_counter()
            write_plan(out, d)
            tw = time.perf_counter() - t
        print(f"{'write':<14}{tw:>9.2f}{peak_rss_mb():>13.0f}")
        total += tw
    print(f"{'total':<14}{total:>9.2f}{peak_rss_mb():>13.0f}")
    return r


def _print_selection(r) -> None:
    sel = r.selection
    v = r.visibility
    print(f"\nvisibility: global {v.global_checked}, travel {v.travel_checked}, {v.n_obstacle_points} obstacle points; "
          f"{v.pairs_cone} pairs in the cone, removed {v.removed_total}, {v.pairs_visible} visible")
    print(f"\nsampled {r.normals.n_sampled} points x {r.orientations.n_machine_feasible} axes "
          f"({sel.n_classes} classes): k {sel.k}, coverage {sel.coverage:.2%}, overlap {sel.overlap}, "
          f"status {sel.status}, solver {sel.solver}, {sel.seconds:.2f} s")
    print("axes: " + "; ".join("({:.3f} {:.3f} {:.3f})".format(*s.tool_axis) for s in r.setups))


def _print_paths(r, cfg) -> None:
    paths = [(st.id, st.path) for st in r.setups if st.path is not None]
    if paths:
        print("\ntool paths per area (finishing: ball R 3, scallop "
              f"{cfg.paths.finishing.scallop_mm} mm, tolerance {cfg.paths.finishing.tolerance_mm} mm):")
        print(f"{'area':>4} {'passes':>7} {'CL raw':>9} {'CL final':>9} {'arcs':>7} {'cut m':>7} "
              f"{'min clear':>10} {'holder hits':>11} {'finish min':>10} {'rough lvls':>10} {'rough min':>9} "
              f"{'s':>6}")
        t_fin = t_rough = 0.0
        for i, p in paths:
            f, ro = p.finishing, p.roughing
            t_fin += f.machining_time_s if f else 0.0
            t_rough += ro.machining_time_s if ro else 0.0
            print(f"{i:>4} {f.n_passes:>7} {f.n_cl_before_reduction:>9} {f.n_cl:>9} {f.n_arcs:>7} "
                  f"{f.length_mm / 1000:>7.1f} {f.min_clearance_mm:>10.4f} {f.holder_collisions:>11} "
                  f"{f.machining_time_s / 60:>10.1f} {ro.n_levels if ro else 0:>10} "
                  f"{(ro.machining_time_s / 60) if ro else 0:>9.1f} {sum(p.seconds.values()):>6.1f}")
        print(f"machining time at the post's feeds: finishing {t_fin / 3600:.2f} h, roughing {t_rough / 3600:.2f} h")


def main() -> None:
    args = _args()
    import open3d as o3d

    from planning.inputs.samples import femur_like

    print(f"cores: {os.cpu_count()}  numpy {np.__version__}  open3d {o3d.__version__}")
    t0 = time.perf_counter()
    s = femur_like(n_points=args.points, seed=0)
    print(f"femur_like: {s.points.shape[0]} points generated in {time.perf_counter() - t0:.2f} s, "
          f"peak RSS {peak_rss_mb():.0f} MB")
    _normals_side_by_side(s, args.repeat)
    cfg = _config(args)
    r = _whole_plan(s.points, cfg, args)
    _print_selection(r)
    _print_paths(r, cfg)


if __name__ == "__main__":
    main()
