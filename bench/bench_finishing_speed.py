"""Finishing-side speed (issue 17): the ball-end finishing passes of many regions of one area on a
large cloud (:func:`planning.toolpath.finishing.finishing_passes` with a shared
:class:`~planning.toolpath.balldrop.DropSurface` and :class:`~planning.toolpath.verify.BinnedCloud`,
as :func:`planning.toolpath.area_paths.area_toolpaths` calls it), then
:func:`planning.toolpath.safety.unmachined_points` of the paths' cutting positions and a run of small
:func:`planning.toolpath.verify.move_clearance` calls (the serial kernels).

The cloud: a bumpy surface ``z = 4 sin(x/9) cos(y/13) - 20`` on ``[-half, half]^2`` sampled at
``--spacing`` with a little noise; the "area" is a band of ``--regions`` stripes across it (the
femur's areas have tens of regions each, many small). Or ``--capture FILE``: a pickle with
``cloud_f`` (N,3), ``masks`` (list of index arrays), ``fp`` (PathsParams.finishing), ``R``, ``tol``,
``safe``, ``max_slope_deg`` (the arguments of area_paths._region_finishing, captured from a plan).

Run twice: the first run compiles the kernels into the cache. Compare revisions in one command,
alternating, on the same machine:

    .venv/bin/python bench/bench_finishing_speed.py [--spacing 0.1] [--half 40] [--regions 12] [--repeat 2]
"""

from __future__ import annotations

import argparse
import pickle
import time
from types import SimpleNamespace

import numpy as np

from planning.errors import ParameterError
from planning.toolpath.balldrop import DropSurface
from planning.toolpath.finishing import finishing_passes
from planning.toolpath.moves import USE_CUT, lines
from planning.toolpath.safety import (
    cutting_positions,
    finished_reach_mm,
    unmachined_points,
)
from planning.toolpath.verify import BinnedCloud, move_clearance


def _synthetic(half: float, spacing: float, regions: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    g = np.arange(-half, half + 1e-9, spacing)
    X, Y = np.meshgrid(g, g, indexing="ij")
    x, y = X.ravel() + rng.normal(0, spacing / 10, X.size), Y.ravel() + rng.normal(0, spacing / 10, X.size)
    pts = np.stack([x, y, 4 * np.sin(x / 9) * np.cos(y / 13) - 20 + rng.normal(0, 0.002, x.size)], 1)
    # regions: stripes across the middle, of shrinking widths (a few large, many small)
    width = np.geomspace(0.3 * half, 0.03 * half, regions)
    edges = -0.6 * half + np.concatenate([[0], np.cumsum(width * 1.2)])
    masks = []
    for r in range(regions):
        sel = (y >= edges[r]) & (y < edges[r] + width[r]) & (np.abs(x) < 0.6 * half)
        if sel.any():
            masks.append(np.flatnonzero(sel))
    fp = SimpleNamespace(scallop_mm=0.01, step_mm=None, margin_mm=1.0, pattern="zigzag", lead_mm=1.0)
    return {"cloud_f": pts, "masks": masks, "fp": fp, "R": 3.0, "tol": 1e-3, "safe": 10.0, "max_slope_deg": 87.0}


def _finishing(d: dict, progress=None) -> list:
    pts, fp, R = d["cloud_f"], d["fp"], d["R"]
    binned = BinnedCloud(pts, R / 4.0)
    surface = DropSurface(pts, R)
    out = []
    for idx in d["masks"]:
        mask = np.zeros(pts.shape[0], dtype=bool)
        mask[idx] = True
        try:
            out.append(finishing_passes(pts, mask, radius_mm=R, scallop_mm=fp.scallop_mm, step_mm=fp.step_mm,
                                        margin_mm=fp.margin_mm, zigzag=fp.pattern == "zigzag", tol_mm=d["tol"],
                                        safe_z_mm=d["safe"], lead_mm=fp.lead_mm, max_slope_deg=d["max_slope_deg"],
                                        binned=binned, surface=surface, progress=progress))
        except ParameterError:
            pass
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--half", type=float, default=40.0)
    ap.add_argument("--spacing", type=float, default=0.1)
    ap.add_argument("--regions", type=int, default=12)
    ap.add_argument("--capture", default=None, help="pickle of _region_finishing's arguments (see the docstring)")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    if args.capture:
        with open(args.capture, "rb") as f:
            d = pickle.load(f)
    else:
        d = _synthetic(args.half, args.spacing, args.regions)
    pts, R = d["cloud_f"], d["R"]
    print(f"cloud {pts.shape[0]} points, {len(d['masks'])} regions, R = {R} mm")
    area = pts[np.concatenate(d["masks"])]
    binned = BinnedCloud(pts, R / 4.0)
    for rep in range(args.repeat):
        calls: list[float] = []
        t0 = time.perf_counter()
        fins = _finishing(d, progress=lambda f, m, calls=calls: calls.append(f))
        t1 = time.perf_counter()
        kept = np.concatenate([cutting_positions(f.toolpath, R / 4.0) for f in fins])
        reach = finished_reach_mm(R, tol_mm=d["tol"], scallop_mm=d["fp"].scallop_mm, spacing_mm=R / 4.0)
        left = unmachined_points(area, kept, R, reach)
        t2 = time.perf_counter()
        # small clearance calls, as making a path safe does (a few moves each: the serial kernels)
        cl = fins[0].cl_mm
        n_small = 0
        for a in range(1, min(cl.shape[0] - 20, 4000), 20):
            m = np.zeros(cl.shape[0], dtype=bool)
            m[a:a + 20] = True
            move_clearance(lines(cl, np.full(cl.shape[0], USE_CUT, dtype=np.int8)), binned, R, moves=m)
            n_small += 1
        t3 = time.perf_counter()
        print(f"run {rep + 1}: finishing_passes {t1 - t0:.2f} s ({sum(f.n_passes for f in fins)} passes, "
              f"{sum(f.toolpath.n_moves for f in fins)} moves, {len(calls)} progress calls); "
              f"unmachined_points {t2 - t1:.2f} s ({int(left.sum())} of {area.shape[0]} left); "
              f"{n_small} small move_clearance calls {t3 - t2:.2f} s")


if __name__ == "__main__":
    main()
