"""Benchmark: normals on simulated range scans, sphere throwing (the pipeline's ``normals`` stage) against
Open3D, by scan-line spacing and by noise, against the sample's exact normals.

    .venv/bin/python bench/bench_normals_range.py                                   # femur + half sphere
    .venv/bin/python bench/bench_normals_range.py --shapes half_sphere --sweep noise --json /tmp/nr.json
    .venv/bin/python bench/bench_normals_range.py --grid 0.3 --diameter 7           # other throwing parameters

Clouds: :func:`planning.inputs.samples.range_scan` (scan lines, holes at grazing incidence, noise along
the ray, 0.1 % outliers, registration errors; exact outward normals at each ray's hit, per point its view).
Each shape is scanned at one fixed size, the scale at which the default pitches (0.3 mm along, 0.6 mm
across the lines) give ``--points`` points (40,000), so that a sweep changes the spacing and not the
part: ``--sweep spacing`` varies the pitches (along x across, mm) at noise 0.02 mm, ``--sweep noise``
varies the noise (mm, along the ray) at the default pitches; ``both`` (the default) runs both.

Methods, on the same cloud:

* ``ours``: :func:`planning.normals.throwing.sphere_throwing` exactly as the pipeline's ``normals`` stage
  calls it with the default parameters (``normals.sphere_diameter_mm`` 7, ``normals.grid_spacing_mm``
  None: density-derived, the paper's five directions); scored on the points it samples (it gives a
  normal only to touched points). Its normals are oriented outward by construction: flipped = the
  normal makes more than 90 deg with the exact one.
* ``ours+fit``: the same with ``refine=True`` (the same sampled points; each direction refitted by a
  plane through the cloud's points within the candidate cell, :mod:`planning.normals.refine`);
  ``fit`` is the share of sampled points whose normal the fit replaced.
* ``o3d``: Open3D ``estimate_normals(KDTreeSearchParamKNN(20))`` (as ``bench/bench_normals.py``) on all
  points, then oriented as a range scan allows, towards the scanner of each point's view
  (``n . v_view > 0``; what a scanner's software does). Scored on all points and on ours' sampled
  points (``o3d@ours``, the same points as ``ours``). ``flip MST``: the share flipped when oriented
  instead by ``orient_normals_consistent_tangent_plane(10)`` (no view known) with the global sign
  that points away from the centroid on average; its seconds are not in ``s``.

The scan's outliers (``meta["outlier_index"]``, moved 2.5-7.5 mm along the ray) are left out of every
statistic (their exact normal is that of a surface they are not on); ``outl.`` is the share of ours'
sampled points that are outliers. Angles: ``unoriented`` = arccos |n . n_exact| (the shape of the
estimate, sign ignored), median and 95th percentile in degrees; ``flip`` = share with n . n_exact < 0
after the orientation above. Seconds are wall seconds of one call on this machine (printed load
average), normals only (Open3D: estimate + view orientation; building its cloud excluded).
No assertions.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planning.inputs.samples import range_scan
from planning.normals.throwing import DEFAULT_DIRECTIONS, sphere_throwing

SHAPES = ("femur_like", "half_sphere")
PITCHES = ((0.15, 0.3), (0.3, 0.3), (0.3, 0.6), (0.3, 1.2), (0.6, 1.2))   # (along, across) mm
NOISES = (0.0, 0.01, 0.02, 0.05, 0.1)                                    # mm, along the ray
DEFAULT_PITCH, DEFAULT_NOISE = (0.3, 0.6), 0.02


def unoriented_deg(est, exact):
    d = np.abs(np.einsum("ij,ij->i", est, exact))
    return np.degrees(np.arccos(np.clip(d, -1.0, 1.0)))


def flipped(est, exact):
    return np.einsum("ij,ij->i", est, exact) < 0.0


def stats(est, exact):
    if est.shape[0] == 0:
        return {"n": 0, "median_deg": None, "p95_deg": None, "flip": None}
    e = unoriented_deg(est, exact)
    return {"n": int(est.shape[0]), "median_deg": float(np.median(e)), "p95_deg": float(np.percentile(e, 95)),
            "flip": float(flipped(est, exact).mean())}


def run_ours(points, diameter, grid, refine=False):
    t0 = time.perf_counter()
    res = sphere_throwing(points, sphere_diameter_mm=diameter, grid_spacing_mm=grid, directions=DEFAULT_DIRECTIONS,
                          refine=refine)
    return res, time.perf_counter() - t0


def run_o3d(o3d, points, view_dir, knn, mst):
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    t0 = time.perf_counter()
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn))
    n = np.asarray(pc.normals).copy()
    n[np.einsum("ij,ij->i", n, view_dir) < 0.0] *= -1.0      # towards each point's scanner
    sec = time.perf_counter() - t0
    n_mst = None
    if mst:
        pc.orient_normals_consistent_tangent_plane(10)
        n_mst = np.asarray(pc.normals).copy()
        if np.einsum("ij,ij->i", n_mst, points - points.mean(axis=0)).sum() < 0.0:
            n_mst = -n_mst
    return n, n_mst, sec


def one_case(o3d, shape, scale, along, across, noise, args) -> dict:
    t0 = time.perf_counter()
    s = range_scan(shape, scale=scale, along_mm=along, across_mm=across, noise_mm=noise, seed=args.seed)
    t_gen = time.perf_counter() - t0
    pts, exact, m = s.points, s.normals, s.meta
    good = np.ones(pts.shape[0], bool)
    good[m["outlier_index"]] = False
    view_dir = np.asarray(m["view_directions"])[m["view"]]
    res, t_ours = run_ours(pts, args.diameter, args.grid)
    idx = res.sample_index
    keep = good[idx]
    res_f, t_fit = run_ours(pts, args.diameter, args.grid, refine=True)
    assert np.array_equal(res_f.sample_index, idx)
    row = {"shape": shape, "scale": float(scale), "along_mm": along, "across_mm": across, "noise_mm": noise,
           "n_points": int(pts.shape[0]), "generate_s": t_gen,
           "grid_spacing_mm": res.grid_spacing_mm, "sphere_diameter_mm": res.sphere_diameter_mm,
           "ours_sampled": int(idx.size), "ours_sampled_share": idx.size / pts.shape[0],
           "ours_outlier_share": float(1.0 - keep.mean()) if idx.size else 0.0,
           "ours": stats(res.normals[keep], exact[idx[keep]]), "ours_s": t_ours,
           "fit": stats(res_f.normals[keep], exact[idx[keep]]), "fit_s": t_fit,
           "fit_share": res_f.n_refined / max(idx.size, 1)}
    if o3d is not None:
        n3, n3m, t3 = run_o3d(o3d, pts, view_dir, args.knn, not args.no_mst)
        row["o3d"] = stats(n3[good], exact[good])
        row["o3d_at_ours"] = stats(n3[idx[keep]], exact[idx[keep]])
        row["o3d_s"] = t3
        row["o3d_flip_mst"] = None if n3m is None else float(flipped(n3m[good], exact[good]).mean())
    return row


def _f(x, fmt):
    return "-" if x is None else format(x, fmt)


def table(rows) -> str:
    head = ("| shape | along x across mm | noise mm | points | g mm | ours sampled (outl.) | ours med / p95 deg | "
            "ours flip | ours s | ours+fit med / p95 (fit) | ours+fit flip | ours+fit s | o3d@ours med / p95 | o3d all med / p95 | o3d flip (view / MST) | o3d s |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        o = r["ours"]
        cells = [r["shape"], f"{r['along_mm']:g} x {r['across_mm']:g}", f"{r['noise_mm']:g}", f"{r['n_points']:,}",
                 f"{r['grid_spacing_mm']:.3g}",
                 f"{r['ours_sampled']:,} {r['ours_sampled_share']:.1%} ({r['ours_outlier_share']:.1%})",
                 f"{_f(o['median_deg'], '.2f')} / {_f(o['p95_deg'], '.2f')}", f"{_f(o['flip'], '.2%')}",
                 f"{r['ours_s']:.2f}"]
        fo = r["fit"]
        cells += [f"{_f(fo['median_deg'], '.2f')} / {_f(fo['p95_deg'], '.2f')} ({r['fit_share']:.0%})",
                  f"{_f(fo['flip'], '.2%')}", f"{r['fit_s']:.2f}"]
        if "o3d" in r:
            a, b = r["o3d_at_ours"], r["o3d"]
            cells += [f"{_f(a['median_deg'], '.2f')} / {_f(a['p95_deg'], '.2f')}",
                      f"{_f(b['median_deg'], '.2f')} / {_f(b['p95_deg'], '.2f')}",
                      f"{b['flip']:.2%} / {_f(r['o3d_flip_mst'], '.2%')}", f"{r['o3d_s']:.2f}"]
        else:
            cells += ["-"] * 4
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shapes", nargs="+", default=list(SHAPES),
                    choices=("femur_like", "half_sphere", "slot", "filleted_box"))
    ap.add_argument("--sweep", choices=("spacing", "noise", "both"), default="both")
    ap.add_argument("--points", type=int, default=40_000, help="points at the default pitches (fixes the scale)")
    ap.add_argument("--pitches", nargs="+", default=None, metavar="ALONGxACROSS",
                    help="pitches of the spacing sweep, e.g. 0.3x0.6 (default: 0.15x0.3 0.3x0.3 0.3x0.6 0.3x1.2 0.6x1.2)")
    ap.add_argument("--noises", type=float, nargs="+", default=list(NOISES), help="noise levels of the noise sweep, mm")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--diameter", type=float, default=7.0, help="sphere diameter, mm (pipeline default 7)")
    ap.add_argument("--grid", type=float, default=None, help="grid spacing, mm (pipeline default: density-derived)")
    ap.add_argument("--knn", type=int, default=20, help="Open3D neighbours")
    ap.add_argument("--no-open3d", action="store_true")
    ap.add_argument("--no-mst", action="store_true", help="skip Open3D's tangent-plane orientation")
    ap.add_argument("--json", default=None, help="write the raw figures (JSON) here")
    args = ap.parse_args(argv)
    pitches = PITCHES if args.pitches is None else tuple(tuple(float(x) for x in p.lower().split("x"))
                                                        for p in args.pitches)
    o3d = None
    if not args.no_open3d:
        import open3d as o3d
    print(f"cores {os.cpu_count()}; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} (1/5/15 min); "
          f"ours: sphere throwing D {args.diameter:g} mm, grid {args.grid or 'density-derived'}, "
          f"{len(DEFAULT_DIRECTIONS)} directions; Open3D KNN {args.knn}", flush=True)
    cases = []
    for shape in args.shapes:
        scale = range_scan(shape, n_points=args.points, along_mm=DEFAULT_PITCH[0], across_mm=DEFAULT_PITCH[1],
                           seed=args.seed).meta["scale"]
        if args.sweep in ("spacing", "both"):
            cases += [(shape, scale, a, c, DEFAULT_NOISE) for a, c in pitches]
        if args.sweep in ("noise", "both"):
            cases += [(shape, scale, *DEFAULT_PITCH, z) for z in args.noises
                      if not (args.sweep == "both" and z == DEFAULT_NOISE and DEFAULT_PITCH in pitches)]
    rows = []
    for shape, scale, a, c, z in cases:
        r = one_case(o3d, shape, scale, a, c, z, args)
        r["load_1min"] = os.getloadavg()[0]
        rows.append(r)
        o = r["ours"]
        line = (f"{shape} (scale {scale:.3g}) {a:g} x {c:g} mm, noise {z:g}: {r['n_points']:,} points, ours "
                f"{_f(o['median_deg'], '.2f')} / {_f(o['p95_deg'], '.2f')} deg, flip {_f(o['flip'], '.2%')} "
                f"({r['ours_s']:.2f} s); ours+fit {_f(r['fit']['median_deg'], '.2f')} / "
                f"{_f(r['fit']['p95_deg'], '.2f')} deg, flip {_f(r['fit']['flip'], '.2%')} ({r['fit_s']:.2f} s)")
        if "o3d" in r:
            line += (f"; o3d {r['o3d']['median_deg']:.2f} / {r['o3d']['p95_deg']:.2f} deg, flip "
                     f"{r['o3d']['flip']:.2%} ({r['o3d_s']:.2f} s)")
        print(line, flush=True)
    print()
    print(table(rows))
    print(f"\nload average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())} (1/5/15 min)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"args": vars(args), "rows": rows}, fh, indent=1)
        print(f"json: {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
