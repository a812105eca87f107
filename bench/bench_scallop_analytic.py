"""Issue 31 item 2: the scallop finishing leaves on analytic surfaces, measured after the fact from the
finishing moves, against the target.

Per surface of tests/scallop_cases.py (the ones tests/test_scallop.py asserts on: a plane, a 40-degree
slope across the passes, a convex cylinder rho 10 mm, a concave one rho 6 mm = 2 R across and along the
passes, a sphere rho 15, a bowl rho 10, a saddle z = (x^2 - y^2) / 24): a 0.05 mm grid of its points, the middle (10 x 10 mm, 6 x 6 on the concave ones)
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
import sys
import time
from pathlib import Path

import numpy as np

H, TOL = 0.01, 0.001


def measure(kind: str) -> dict:
    """Passes, CL points, the largest scallop measured and the seconds of one surface
    (tests/scallop_cases.py, as the test finishes and measures it)."""
    import scallop_cases

    t0 = time.perf_counter()
    left, fin = scallop_cases.finish_and_measure(kind, H, TOL)
    return {"passes": int(fin.n_passes), "cl": int((fin.pass_index >= 0).sum()), "max": float(left.max()),
            "seconds": round(time.perf_counter() - t0, 2)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                    help="the checkout whose planning package plans (default: this one)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(args.root.resolve()))
    sys.path.insert(1, str(Path(__file__).resolve().parents[1] / "tests"))   # scallop_cases, this checkout's
    import scallop_cases
    R = scallop_cases.R
    print(f"planning from {args.root}; R {R} mm, scallop {H} mm, tolerance {TOL} mm")
    print("| surface | passes | CL points | scallop measured, largest mm | / target |")
    print("|---|---|---|---|---|")
    for kind in scallop_cases.SURFACES:
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
