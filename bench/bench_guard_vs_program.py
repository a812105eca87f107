"""Does the 5-axis finishing guard's stock match what the posted program cuts? (issue 33, the holder
contacts the verification finds and the guard does not)

    .venv/bin/python bench/bench_guard_vs_program.py --points 20000

Plans the femur-like sample in ``paths.finishing.mode=5axis`` (the parameters of
bench/bench_fiveaxis.py, two pass directions), keeping for every 5-axis area the stock its finishing
guard started from and the one it carried on. Then, per area, the posted LinuxCNC program's
finishing moves (read back as the verification reads them) are run on the stock the guard started
from, and the material left compared with the guard's, ray by ray: how many rays differ by more than
0.05 mm, the largest difference each way (mm along a ray) and the volume (mm^3; positive: the
program leaves more than the guard's model has). The guard's own moves are run again with smaller
axis steps (``--steps``) to show how much of the difference its sampling makes (the guard runs each
step of at most ``planning.toolpath.guard.AXIS_STEP_DEG`` with the step's end axis).
``--axis-step DEG``: the guard's step for the plan itself.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _lengths(stock, family: int) -> np.ndarray:
    ptr, iv = stock.csr(family)
    return np.add.reduceat(np.r_[iv[:, 1] - iv[:, 0], 0.0], ptr[:-1]) * (np.diff(ptr) > 0)


def _compare(model, program) -> str:
    """Program minus model, per ray family (X, Y, Z rays; each family sees the same volume up to the
    rays' spacing)."""
    out = []
    for f in range(3):
        d = _lengths(program, f) - _lengths(model, f)
        out.append(f"{'XYZ'[f]}: {int((np.abs(d) > 0.05).sum())} rays, +{d.max():.3f} / {d.min():.3f} mm, "
                   f"{d.sum() * program.res ** 2:+.1f} mm3")
    return "; ".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=20_000, help="femur-like points (default 20,000)")
    ap.add_argument("--axis-step", type=float, default=None, help="the guard's axis step for the plan, deg")
    ap.add_argument("--steps", type=float, nargs="*", default=[1.0, 0.25], help="guard steps replayed, deg")
    args = ap.parse_args(argv)

    from bench.bench_fiveaxis import FEMUR
    from planning.inputs import Cloud, samples
    from planning.orientations.kinematics import as_profile
    from planning.pipeline import run_plan
    from planning.simulate.dexel import simulate_moves
    from planning.simulate.program import read_program
    from planning.simulate.verify import tool_shapes
    from planning.toolpath import area_paths, guard
    from schemas.params import parse_config

    if args.axis_step is not None:
        d = list(guard.part_moves.__defaults__)
        d[-1] = float(args.axis_step)
        guard.part_moves.__defaults__ = tuple(d)
    kept = {}
    orig = area_paths._guard_finishing

    def watched(ap_, carried, area_f, fp, progress=None):
        before = carried.stock.copy()
        out = orig(ap_, carried, area_f, fp, progress)
        if ap_.finishing is not None and ap_.finishing.axis is not None:
            kept[ap_.area] = (ap_.frame, ap_.finishing, before, carried.stock, carried.finishing_shape,
                              carried.rapid_clearance_mm)
        return out

    area_paths._guard_finishing = watched
    s = samples.femur_like(n_points=args.points, seed=0)
    cfg = parse_config({**FEMUR, "setups": {**FEMUR["setups"], "max_setups": 2},
                        "paths": {"finishing": {"mode": "5axis"}}})
    t0 = time.perf_counter()
    out = run_plan(Cloud(points=s.points, normals=None, source_format="generated"), cfg, name="femur 5axis")
    v = out.result.verification
    print(f"{args.points:,} points, guard step {guard.part_moves.__defaults__[-1]} deg, "
          f"{time.perf_counter() - t0:.0f} s: {v.status}: {v.message}")
    for a in v.areas:
        print(f"  {a.program}: holder {a.holder_collisions}, rapids into material {a.rapids_into_material}, "
              f"travel {a.travel_excursions}")
    tools = tool_shapes(cfg, cfg.tool.assembly())
    profile = as_profile(cfg.machine.profile)
    progs = out.extra["programs"]
    for area, (frame, tp, before, after, shape, clearance) in sorted(kept.items()):
        text = progs[f"area_{area}.linuxcnc.nc"]
        text = text if isinstance(text, str) else text.decode()
        place = [float(x) for x in re.search(r"part placement on the table X(\S+) Y(\S+) Z(\S+)\)", text).groups()]
        m = read_program(text, dialect="linuxcnc", program=f"area_{area}", area=area, profile=profile,
                         placement_mm=place, tools=tools)
        fin = m.tool == cfg.post.finishing_tool_number
        first = int(np.flatnonzero(fin)[0])
        sl = slice(first, m.n_moves)
        prog = before.copy()
        run = simulate_moves(prog, m.start_mm[sl], m.end_mm[sl], m.axis[sl], shape, m.kind[sl],
                             rapid_clearance_mm=clearance)
        print(f"area {area}: the program's finishing ({sl.stop - sl.start:,} moves) on the guard's starting "
              f"stock: holder {int((run.holder_depth_mm > 0).sum())}")
        print(f"  program minus the guard's carried stock: {_compare(after, prog)}")
        for step in args.steps:
            pm = guard.part_moves(tp, frame, axis_step_deg=step)
            mine = before.copy()
            simulate_moves(mine, pm.start, pm.end, np.broadcast_to(pm.axis, pm.start.shape), shape, pm.kind,
                           rapid_clearance_mm=clearance)
            print(f"  program minus the guard's moves at {step:g} deg steps ({pm.start.shape[0]:,} steps): "
                  f"{_compare(mine, prog)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
