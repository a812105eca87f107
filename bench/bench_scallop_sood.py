"""Issue 31 item 2: Sood's Bezier test surfaces (thesis ch. 5, tables 5.1 and 5.4) finished at the
thesis's scallop heights, side by side with its tables 5.2, 5.3 and 5.5, and the scallop measured after
the fact from the finishing moves.

Each surface is the biquadratic Bezier patch of the table's 3 x 3 control points (P_ij: i along x,
j along y), sampled on a uv grid (``--spacing``, mm, about the points' spacing) as a point cloud; the
ball (R = 3 mm, the radius of the thesis's ch. 4 examples; ch. 5 does not state it, and its pass counts
match the plane step-over of R = 3 mm) finishes the whole patch with
:func:`planning.toolpath.finishing.finishing_passes` (``scallop_mm`` = the thesis's epsilon,
``tol_mm`` = ``--tol-share`` times it: the chords along a pass keep half of that), passes along the patch's longer side (Sood's final feed direction, y, on the
first patch). Per epsilon:

* passes and tool locations (CL points on the passes, before CL reduction: the thesis counts the
  tool locations of its raster before its own reduction, §5.4.6; and after
  :func:`planning.toolpath.reduce.reduce_cl` at ``tol_mm``, the links, leads and retracts not counted);
* the scallop measured: the material left over the patch's points 2 mm or more inside its edges, from the
  finishing moves (:func:`planning.simulate.finish.finish_left_mm`, the exact distance to the swept
  ball), its largest value and 99th percentile, against epsilon, and its largest value from the reduced
  moves (which may run up to ``tol_mm`` from the dropped points);
* seconds to plan (this machine; the thesis's are its own machine's, for the record).

    .venv/bin/python bench/bench_scallop_sood.py [--spacing 0.1] [--tol-share 0.25]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(1, str(Path(__file__).resolve().parents[1] / "tests"))

import scallop_cases

from planning.simulate.finish import finish_left_mm
from planning.toolpath.finishing import finishing_passes
from planning.toolpath.reduce import reduce_cl
from planning.toolpath.verify import BinnedCloud

R = 3.0

#: Table 5.1 (rows x, y, z of P00 P01 P02 P10 P11 P12 P20 P21 P22), 50 x 100 x 25 mm
TABLE_5_1 = ((0.0, 0.0, 0.0, 25.0, 25.0, 25.0, 50.0, 50.0, 50.0),
             (0.0, 50.0, 100.0, 0.0, 48.0, 100.0, 0.0, 50.0, 100.0),
             (19.0, 24.0, 25.0, 24.0, 24.5, 25.0, 25.0, 25.0, 25.0))
#: Table 5.4, the convex patch, 50 x 50 x 25 mm
TABLE_5_4 = ((0.0, 0.0, 0.0, 25.0, 25.0, 25.0, 50.0, 50.0, 50.0),
             (0.0, 25.0, 50.0, 0.0, 25.0, 50.0, 0.0, 25.0, 50.0),
             (15.0, 21.0, 15.0, 21.0, 25.0, 21.0, 15.0, 21.0, 15.0))

#: The thesis's figures: epsilon mm -> (tool locations, passes, seconds) (None: "does not work")
SOOD = {
    "table 5.1 (tables 5.2 / 5.3)": {
        0.05: None, 0.06: (6795, 45, 53.8), 0.08: (3237, 39, 29.3), 0.1: (2485, 35, 24.6), 0.125: (1953, 31, 20.5)},
    "table 5.4 (table 5.5)": {
        0.07: None, 0.08: (7921, 89, 59.1), 0.1: (3025, 55, 27.9), 0.125: (1849, 43, 19.5), 0.15: (1295, 37, 14.8)},
}


def bezier_points(table, spacing_mm: float) -> np.ndarray:
    """(N,3) points of the biquadratic Bezier patch of a 3 x 3 control net on a uv grid fine enough for
    about ``spacing_mm`` between neighbours."""
    P = np.array(table, dtype=np.float64).T.reshape(3, 3, 3)        # P[i, j] = (x, y, z)
    size = np.ptp(P[..., 0]), np.ptp(P[..., 1])
    nu, nv = (int(np.ceil(s / spacing_mm)) + 1 for s in size)
    u, v = np.linspace(0, 1, nu), np.linspace(0, 1, nv)

    def bern(t):
        return np.stack([(1 - t) ** 2, 2 * t * (1 - t), t * t], 1)

    Bu, Bv = bern(u), bern(v)
    S = np.einsum("ai,bj,ijk->abk", Bu, Bv, P)
    return S.reshape(-1, 3)


def plan_and_measure(pts: np.ndarray, eps: float, tol: float) -> dict:
    """Finish the patch (passes along its longer side) and measure the scallop from the moves."""
    frame = pts.copy()
    if np.ptp(frame[:, 1]) > np.ptp(frame[:, 0]):                 # the longer side along X
        frame = frame[:, [1, 0, 2]]
    frame[:, 2] -= frame[:, 2].max()
    t0 = time.perf_counter()
    fin = finishing_passes(frame, np.ones(frame.shape[0], dtype=bool), radius_mm=R, scallop_mm=eps, tol_mm=tol,
                           margin_mm=0.0)
    sec = time.perf_counter() - t0
    reduced = reduce_cl(fin.toolpath, BinnedCloud(frame, R / 4.0), R, tol_mm=tol, pass_index=fin.pass_index)
    lo, hi = frame[:, :2].min(0) + 2.0, frame[:, :2].max(0) - 2.0
    inner = np.flatnonzero(np.all((frame[:, :2] >= lo) & (frame[:, :2] <= hi), axis=1))
    rng = np.random.default_rng(0)
    if inner.size > 60_000:
        inner = np.sort(rng.choice(inner, 60_000, replace=False))
    ball = scallop_cases.ball(R)
    left = finish_left_mm(frame[inner], [scallop_cases.ball_motion(fin.toolpath, R)], ball)
    fin_left = left[np.isfinite(left)]
    left_r = finish_left_mm(frame[inner], [scallop_cases.ball_motion(reduced, R)], ball)
    left_r = left_r[np.isfinite(left_r)]
    return {"passes": int(fin.n_passes), "cl": int((fin.pass_index >= 0).sum()),
            "cl_reduced": int(reduced.xyz_mm.shape[0] - (fin.toolpath.xyz_mm.shape[0] - (fin.pass_index >= 0).sum())), "seconds": round(sec, 2),
            "left_max": float(fin_left.max()), "left_max_reduced": float(left_r.max()), "left_p99": float(np.percentile(fin_left, 99)),
            "reached": float(np.isfinite(left).mean()), "n_measured": int(inner.size)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spacing", type=float, default=0.1, help="point spacing of the sampled patches, mm")
    ap.add_argument("--tol-share", type=float, default=0.25,
                    help="the finishing tolerance (gouge, chords; tol_mm) as a share of epsilon: the thesis's "
                         "epsilon bounds the forward direction too")
    args = ap.parse_args(argv)
    print(f"R = {R} mm, points every ~{args.spacing} mm, tol_mm = {args.tol_share} x epsilon")
    print("| surface | epsilon mm | Sood: tool locations / passes / s | here: tool locations (after CL reduction) / passes / s | "
          "scallop measured: max / p99 mm | max / epsilon | after CL reduction: max / epsilon |")
    print("|---|---|---|---|---|---|---|")
    for (name, sood), table in zip(SOOD.items(), (TABLE_5_1, TABLE_5_4)):
        pts = bezier_points(table, args.spacing)
        for eps, theirs in sood.items():
            r = plan_and_measure(pts, eps, args.tol_share * eps)
            t = "does not work" if theirs is None else f"{theirs[0]} / {theirs[1]} / {theirs[2]}"
            print(f"| {name} | {eps} | {t} | {r['cl']} ({r['cl_reduced']}) / {r['passes']} / {r['seconds']} | "
                  f"{r['left_max']:.4f} / {r['left_p99']:.4f} | {r['left_max'] / eps:.2f} | "
                  f"{r['left_max_reduced'] / eps:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
