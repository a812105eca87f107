"""Issue 34: one machining time. Per reference case and area, three figures for the same posted programs:

* ``estimate``: the tool paths' own figure (``setups[].path.{roughing,finishing}.machining_time_s``: feeds,
  plunges and rapids at the post's rates, before posting; no tool changes or moves to the machine's Z0);
* ``nominal``: the posted LinuxCNC program read back with every feed move at its tool's nominal feed
  (``post.feed_mm_min`` / ``post.roughing_feed_mm_min``): the verification's "simulated" time before this
  change;
* ``control``: the same program with each feed move at the F word in force on its line, G93 lines at 1/F
  minutes, rapids at ``post.rapid_mm_min`` (:func:`planning.simulate.verify.move_minutes`): the one time
  plan.json ``figures`` now reports.

    .venv/bin/python bench/bench_machining_time.py --cases half_sphere femur_like
    .venv/bin/python bench/bench_machining_time.py --plan-dir f/ rf/     # plans written by `scanmill plan`

Cases as ``bench/bench_stock_first.py`` (the femur-like one is the ``make run`` configuration).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "bench"))

def rows_of(name: str, result, programs: dict) -> list[tuple]:
    """``(name, area, estimate s, nominal-feed s, as-the-control s, plan.json figures s)`` per area of a plan
    (``programs``: its LinuxCNC programs by name), in machining order."""
    from bench_stock_first import linuxcnc_motions

    from planning.simulate.verify import move_minutes

    p = result.parameters
    rows = []
    for area, m in linuxcnc_motions(programs, result):
        control = 60.0 * float(move_minutes(m, p).sum())
        nominal = 60.0 * float(move_minutes(replace(m, line_feed=None, line_inverse_time=None), p).sum())
        path = next(s.path for s in result.setups if s.id == area)
        est = sum(op.machining_time_s for op in (path.roughing, path.finishing) if op is not None)
        fig = next(a for a in result.figures.areas if a.area == area)
        rows.append((name, area, est, nominal, control, fig.machining_time_s))
    return rows

def plan_dir_times(folder: Path) -> list[tuple]:
    """The rows of a plan already written (``scanmill plan ... --out folder``)."""
    from schemas.plan import PlanResult

    r = PlanResult.model_validate_json((folder / "plan.json").read_text())
    programs = {f.name: f.read_text() for f in folder.glob("area_*.linuxcnc.nc")}
    return rows_of(folder.name, r, programs)

def times(name: str) -> list[tuple]:
    """The rows of a reference case, planned here."""
    from bench_stock_first import case_input

    from planning.inputs import Cloud
    from planning.pipeline import run_plan
    from schemas.params import apply_overrides, parse_config

    pts, nrm, faces, doc, sets = case_input(name, HERE)
    out = run_plan(Cloud(points=pts, normals=nrm, source_format="generated", faces=faces),
                   parse_config(apply_overrides(doc, sets)), name=name)
    return rows_of(name, out.result, out.extra["programs"])

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", nargs="+", default=["half_sphere", "femur_like"])
    ap.add_argument("--plan-dir", nargs="+", type=Path, default=[],
                    help="read plans already written instead of planning the cases")
    args = ap.parse_args()
    print("| case | area | estimate min | nominal feeds min | as the control runs it min | plan.json figures min |")
    print("|---|---|---|---|---|---|")
    for name in (args.plan_dir or args.cases):
        rows = plan_dir_times(name) if args.plan_dir else times(name)
        for _, area, est, nom, ctl, fig in rows:
            print(f"| {name} | {area} | {est / 60:.1f} | {nom / 60:.1f} | {ctl / 60:.1f} | {fig / 60:.1f} |", flush=True)
        tot = [sum(r[i] for r in rows) / 60 for i in (2, 3, 4, 5)]
        print(f"| {name} | all | {tot[0]:.1f} | {tot[1]:.1f} | {tot[2]:.1f} | {tot[3]:.1f} |", flush=True)
    return 0

if __name__ == "__main__":
    sys.exit(main())
