"""What the 5-axis ring candidates fail on (issue 33: why a pass direction leaves positions with no
admissible axis). Prints figures only.

The sample is planned in 5axis from two pass directions (``bench/bench_fiveaxis.py``'s settings for
it) up to the first set-up's finishing guard; the first ring search of that set-up
(:func:`planning.toolpath.fiveaxis.axes._search`: every position whose wanted axis fails, 4 rings x 16
azimuths about its normal) is taken, and every (position, candidate) pair is sorted by the plan's own
:class:`planning.toolpath.fiveaxis.finishing.Admissible`: within the swing, off the rotary pole, a
rotary solution within the tilt's travel, the tip within the linear travel (which limit, and at what
tilt), then clear of the cloud:

    NUMBA_NUM_THREADS=2 .venv/bin/python bench/bench_fiveaxis_reach.py --sample range_femur
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "bench"))


class _Stop(Exception):
    pass


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sample", choices=["range_femur", "femur_like"], default="range_femur")
    ap.add_argument("--points", type=int, default=None, help="sample size (default 40,000 / 200,000)")
    ap.add_argument("--setup", type=int, default=0,
                    help="which 5-axis finishing set-up (0: the first planned) to take the first ring search of")
    ap.add_argument("--dense", type=int, default=0,
                    help="also try this many directions spread evenly over the sphere (those inside the cone "
                         "about the normal) on every position the rings leave with no admissible axis: how "
                         "many of them a finer search would finish")
    args = ap.parse_args(argv)
    from bench_fiveaxis import FEMUR, RANGE

    import planning.toolpath.fiveaxis.axes as axes_mod
    from planning.inputs import Cloud
    from planning.inputs.samples import make_sample
    from planning.orientations.kinematics import solve_rotary
    from planning.pipeline import run_plan
    from planning.toolpath import area_paths
    from schemas.params import parse_config

    seen = {}
    search = axes_mod._search

    oks = []

    def spy(centres, normals, want, cone_deg, ok, idx, n_rings, n_azimuths, memo=None):
        if not any(o is ok for o in oks):
            oks.append(ok)
        if not seen and len(oks) == args.setup + 1:
            seen.update(centres=centres, normals=normals, cone=cone_deg, ok=ok, idx=idx.copy(), rings=n_rings,
                        az=n_azimuths)
        return search(centres, normals, want, cone_deg, ok, idx, n_rings, n_azimuths, memo)

    guard = area_paths._guard_finishing

    def stop(*a, **k):
        if seen:
            raise _Stop
        return guard(*a, **k)

    axes_mod._search = spy
    area_paths._guard_finishing = stop
    n = args.points or (40_000 if args.sample == "range_femur" else 200_000)
    s = make_sample(args.sample, n_points=n)
    base = RANGE if args.sample == "range_femur" else FEMUR
    cfg = {**base, "setups": {**base.get("setups", {}), "max_setups": 2}, "paths": {"finishing": {"mode": "5axis"}}}
    try:
        run_plan(Cloud(points=s.points, normals=None, source_format="generated"), parse_config(cfg), name="reach")
    except _Stop:
        pass
    if not seen:
        print(f"no ring search of set-up {args.setup} ran")
        return 1
    ok, idx = seen["ok"], seen["idx"]
    cand = axes_mod.ring_candidates(seen["normals"][idx], seen["cone"], n_rings=seen["rings"], n_azimuths=seen["az"])
    k = cand.shape[1]
    c = np.repeat(seen["centres"][idx], k, axis=0)
    a = cand.reshape(-1, 3)
    swing = a[:, 2] >= ok.cos_swing - 1e-12
    pole = (a @ ok.pole_f) < ok.cos_pole if ok.pole_f is not None else np.ones(len(a), dtype=bool)
    m = ok.machine
    axes_p = a @ ok.frame.rotation
    sols = solve_rotary(axes_p, m.profile)
    rot = sols.valid.any(axis=1)
    reach = ok.reachable(c, a)
    inner = swing & pole
    print(f"{args.sample}, {n:,} points: 5-axis set-up {args.setup}'s first ring search, {idx.size:,} positions x {k} candidates "
          f"= {len(a):,} pairs")
    print(f"  within the swing and off the pole: {int(inner.sum()):,}")
    print(f"  of those, no rotary solution within the tilt's travel: {int((inner & ~rot).sum()):,}")
    lin = np.flatnonzero(inner & rot & ~reach)
    print(f"  of those, a rotary solution but the tip outside the linear travel: {lin.size:,}")
    if lin.size:
        j = np.where(sols.valid[lin, 0], 0, 1)
        tips = ok.frame.to_part(c[lin]) - ok.tool.radius_mm * axes_p[lin]
        mpos = m.machine_from_tip(tips, sols.angles_deg[lin, j], ok.gauge)
        (x0, x1), (y0, y1), (z0, z1) = m.profile.linear_limits_mm
        lo, hi = np.array([x0, y0, z0]), np.array([x1, y1, z1])
        names = ("X-", "Y-", "Z-", "X+", "Y+", "Z+")
        over = np.c_[mpos < lo, mpos > hi].sum(axis=0)
        print("    limits exceeded (first solution within the rotary travel): "
              + ", ".join(f"{nm} {int(v):,}" for nm, v in zip(names, over) if v))
        t = np.abs(sols.angles_deg[lin, j, 0])
        print(f"    their tilt, 5/50/95 %: {np.percentile(t, 5):.1f} / {np.percentile(t, 50):.1f} / "
              f"{np.percentile(t, 95):.1f} deg")
    free = np.flatnonzero(inner & reach)
    clear = ok.grid.free(c[free], a[free], ok.tool)
    print(f"  reachable: {free.size:,}; of those, the tool assembly meets the cloud: {int((~clear).sum()):,}")
    if args.dense:
        _dense(seen, ok, cand, args.dense)
    return 0


def _fibonacci(n: int) -> np.ndarray:
    """(n,3) unit directions spread evenly over the sphere (the golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


def _dense(seen, ok, cand, n_dirs: int) -> None:
    """The positions of the first ring search whose 64 candidates all fail ``ok``: how many have an
    admissible axis among ``n_dirs`` evenly spread directions inside the cone about their normal."""
    idx = seen["idx"]
    cen, nrm = seen["centres"][idx], seen["normals"][idx]
    k = cand.shape[1]
    good = ok(np.repeat(cen, k, axis=0), cand.reshape(-1, 3)).reshape(-1, k)
    none = np.flatnonzero(~good.any(axis=1))
    d = _fibonacci(n_dirs)
    lo, hi = (np.cos(np.radians(float(v))) for v in seen["cone"])
    cosang = nrm[none] @ d.T                                     # (p, n_dirs)
    inside = (cosang <= lo) & (cosang >= hi) & (d[:, 2][None, :] >= ok.cos_swing - 1e-12)
    rows, cols = np.nonzero(inside)
    rescued = np.zeros(none.size, dtype=bool)
    step = 200_000
    for s0 in range(0, rows.size, step):
        r, c = rows[s0:s0 + step], cols[s0:s0 + step]
        g = ok(cen[none[r]], d[c])
        rescued[r[g]] = True
    print(f"  positions with no admissible ring candidate: {none.size:,} of {idx.size:,}; "
          f"{int(inside.any(axis=1).sum()):,} have some of {n_dirs:,} even directions inside the cone and the "
          f"swing ({int(inside.sum(axis=1).mean()) if none.size else 0} each on average); an admissible one "
          f"among them: {int(rescued.sum()):,}")


if __name__ == "__main__":
    sys.exit(main())
