"""Issue 31 item 2: the scallop finishing leaves on analytic surfaces, measured after the fact from the
finishing moves, against the target.

Per surface (a plane, a 40-degree slope across the passes, a convex cylinder rho 10 mm, a concave one
rho 6 mm = 2 R across and along the passes, a sphere rho 15, a bowl rho 10, a saddle
z = (x^2 - y^2) / 24): a 0.05 mm grid of its points, the middle (10 x 10 mm, 6 x 6 on the concave ones)
finished by :func:`planning.toolpath.finishing.finishing_passes` (R 3 mm, scallop 0.01 mm, tolerance
0.001 mm), and the material left over the points 1 mm or more inside the finished square measured from
the moves (:func:`planning.simulate.finish.finish_left_mm`, the exact distance to the swept ball): its
largest value over the target, the passes and the CL points. Then a plane sampled as a scan is (random
points, 0.3 mm apart on average, 0.03 mm of noise): its passes against the plane step-over's count (the
noise must not read as curvature; the scallop is not measured there, the noise would dominate it).
``--root`` plans with another checkout's
``planning`` package (a ``git worktree`` of the commit before), so that before and after come from one
script:

    .venv/bin/python bench/bench_scallop_analytic.py
    git worktree add /tmp/before c76fb85
    .venv/bin/python bench/bench_scallop_analytic.py --root /tmp/before
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

R, H, TOL = 3.0, 0.01, 0.001
SURFACES = ("plane", "slope_40", "convex_cylinder", "concave_cylinder_across", "concave_cylinder_along",
            "sphere", "bowl", "saddle")


def surface_z(kind: str, x, y):
    """Height of the analytic surface ``kind`` at (x, y), mm."""
    return {
        "plane": lambda: 0.0 * x,
        "slope_40": lambda: math.tan(math.radians(40.0)) * y,
        "convex_cylinder": lambda: np.sqrt(100.0 - y * y) - 10.0,
        "concave_cylinder_across": lambda: 6.0 - np.sqrt(36.0 - y * y),
        "concave_cylinder_along": lambda: 6.0 - np.sqrt(36.0 - x * x),
        "sphere": lambda: np.sqrt(225.0 - x * x - y * y) - 15.0,
        "bowl": lambda: 10.0 - np.sqrt(100.0 - x * x - y * y),
        "saddle": lambda: (x * x - y * y) / 24.0,
    }[kind]()


def measure(kind: str) -> dict:
    from planning.simulate.finish import finish_left_mm
    from planning.simulate.motion import FEED, ProgramMotion, ToolShape
    from planning.toolpath.finishing import finishing_passes

    half = 3.0 if kind.startswith("concave") or kind == "bowl" else 5.0
    g = np.arange(-half - 2.0, half + 2.0 + 1e-9, 0.05)
    X, Y = np.meshgrid(g, g, indexing="ij")
    x, y = X.ravel(), Y.ravel()
    pts = np.column_stack([x, y, surface_z(kind, x, y)])
    pts[:, 2] -= pts[:, 2].max()
    area = (np.abs(x) <= half) & (np.abs(y) <= half)
    t0 = time.perf_counter()
    fin = finishing_passes(pts, area, radius_mm=R, scallop_mm=H, tol_mm=TOL, margin_mm=1.0)
    sec = time.perf_counter() - t0
    cl, kind_ = fin.toolpath.xyz_mm, fin.toolpath.kind
    f = kind_[1:] == FEED
    n = int(f.sum())
    tip = np.array([0.0, 0.0, R])
    m = ProgramMotion(program="t", area=0, line=np.arange(1, n + 1), kind=np.full(n, FEED, np.int8),
                      tool=np.ones(n, np.int64), start_mm=cl[:-1][f] - tip, end_mm=cl[1:][f] - tip,
                      axis=np.tile([0.0, 0.0, 1.0], (n, 1)), machine_mm=np.zeros((n, 3)),
                      rotary_deg=np.zeros((n, 2)))
    ball = ToolShape(number=1, kind="ball", radius_mm=R, corner_radius_mm=R, flute_length_mm=20.0,
                     pieces=((20.0, 60.0, 4.0),))
    inner = np.flatnonzero((np.abs(x) <= half - 1.0) & (np.abs(y) <= half - 1.0))
    left = finish_left_mm(pts[inner], [m], ball)
    return {"passes": int(fin.n_passes), "cl": int((fin.pass_index >= 0).sum()), "max": float(left.max()),
            "seconds": round(sec, 2)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                    help="the checkout whose planning package plans (default: this one)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(args.root.resolve()))
    print(f"planning from {args.root}; R {R} mm, scallop {H} mm, tolerance {TOL} mm")
    print("| surface | passes | CL points | scallop measured, largest mm | / target |")
    print("|---|---|---|---|---|")
    for kind in SURFACES:
        r = measure(kind)
        print(f"| {kind} | {r['passes']} | {r['cl']} | {r['max']:.4f} | {r['max'] / H:.2f} |", flush=True)
    from planning.toolpath.finishing import finishing_passes, step_over_mm

    rng = np.random.default_rng(2)
    n = int(40 * 20 / 0.3 ** 2)
    pts = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(-10, 10, n), rng.normal(0.0, 0.03, n)])
    pts[:, 2] -= pts[:, 2].max()
    area = (np.abs(pts[:, 0]) < 15) & (np.abs(pts[:, 1]) < 7)
    fin = finishing_passes(pts, area, radius_mm=R, scallop_mm=H, tol_mm=0.01)
    ys = np.unique(np.round(fin.toolpath.xyz_mm[fin.pass_index >= 0, 1], 9))
    plane_rule = int(np.ceil((ys.max() - ys.min()) / step_over_mm(R, H))) + 1
    print(f"scan-like plane (0.3 mm, 0.03 mm noise, tolerance 0.01 mm): {fin.n_passes} passes over "
          f"{ys.max() - ys.min():.2f} mm, the plane step-over's count {plane_rule}; "
          f"{int((fin.pass_index >= 0).sum())} CL points")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
