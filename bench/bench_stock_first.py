"""Issue 30: what the roughing does on the reference cases, read from the programs as the machine runs them.

Per case the whole plan (``run_plan``: paths, posts, verification on), then per area in machining order:

* the roughing end mill's feed length, the share of it in air (moves that removed no material on the
  simulated stock: ``verification.areas[].operations``), straight plunges into material (the verification's
  count: a roughing feed within 10 degrees of straight down its axis that removed material), simulated
  roughing time;
* the roughing feed length with the tool tip below the stock block's bottom (part frame z under the
  stock box's lowest z), all of it and the part in air (moves that removed nothing), from the posted
  LinuxCNC programs read back and run on a fresh stock in machining order (:func:`below_stock`; a tilted
  cutter may still cut the block's lower edge with its tip below it);
* what the guard had to repair in the roughing (rapids into material replaced by a way over, CL points
  cut out for travel, rounds) and the pieces the roughing left for lack of an entry (``n_pieces_left``);
* the area's LinuxCNC program read by LinuxCNC's own interpreter (``rs274``, :func:`rs274_check`): the
  moves it reads and how many leave the machine's travel (none when ``rs274`` is not installed);

and per case the verdict, the offence counts, the simulated machining time, the plan's seconds.

``--root`` plans with another checkout's ``planning`` package (e.g. a ``git worktree`` of the commit
before), so that before and after come from the same script:

    .venv/bin/python bench/bench_stock_first.py --json bench/out/stock_first/after.json
    git worktree add /tmp/base30 8399415
    .venv/bin/python bench/bench_stock_first.py --root /tmp/base30 --json bench/out/stock_first/before.json

Cases: ``half_sphere`` (the README's plan: normals from the file, 2 set-ups, Ø10 ball), ``slot``, ``post_wall``,
``filleted_box`` (Ø4), ``dome_mesh`` (tests/test_safe_programs.py's: a UV sphere's upper half as triangles,
facet normals, 3 set-ups) and
``femur_like`` (the ``make run`` configuration of scripts/demo_service.py, the cloud without normals).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
CASES = ("half_sphere", "slot", "post_wall", "filleted_box", "dome_mesh", "femur_like")


def _setup_path(root: Path) -> None:
    sys.path.insert(0, str(root))


def case_input(name: str, root: Path):
    """(points, normals or None, faces or None, the configuration document) of a case."""
    from planning.inputs import samples

    if name == "femur_like":
        sys.path.insert(0, str(root / "scripts"))
        from demo_service import CONFIGS

        s = samples.femur_like()
        return s.points, None, None, json.loads(json.dumps(CONFIGS["femur_like"])), []
    if name == "dome_mesh":                  # the test suite's reference mesh and its settings
        sys.path.insert(0, str(root / "tests"))
        from test_safe_programs import CASES as TEST_CASES
        from test_safe_programs import _dome_mesh

        s = _dome_mesh()
        return s.points, None, s.faces, {}, list(TEST_CASES["dome_mesh"][1])
    make, sets = {"half_sphere": (samples.half_sphere, ["normals.method=input", "setups.max_setups=2",
                                                        "tool.diameter_mm=10"]),
                  "slot": (samples.slot, []), "post_wall": (samples.post_wall, []),
                  "filleted_box": (samples.filleted_box, ["tool.diameter_mm=4"])}[name]
    s = make()
    return s.points, s.normals, None, {}, sets


def linuxcnc_motions(programs: dict, result):
    """``(area, ProgramMotion)`` of each area's posted LinuxCNC program (``programs``: name -> text), in
    machining order, read back as the verification reads it (:func:`planning.simulate.program.read_program`)."""
    from planning.orientations.kinematics import load_profile
    from planning.simulate.program import read_program
    from planning.simulate.verify import tool_shapes

    p = result.parameters
    tools = tool_shapes(p, p.tool.assembly())
    profile = load_profile(p.machine.profile)
    for area in result.machining_order:
        name = f"area_{area}.linuxcnc.nc"
        if name in programs:
            yield area, read_program(programs[name], dialect="linuxcnc", program=name, area=area, profile=profile,
                                     placement_mm=np.asarray(result.visibility.placement_mm, float), tools=tools)


def below_stock(programs: dict, result, points, faces=None) -> dict:
    """Per area: the roughing feed length (mm) with the tool tip under the stock box's bottom, all of it
    and the part that removed no material (in air), from the posted LinuxCNC programs read back
    (:func:`planning.simulate.program.read_program`) and run in machining order on a fresh stock
    (:func:`planning.simulate.run.run_moves`), as the verification runs them."""
    from planning.simulate import models as stock_models
    from planning.simulate.motion import FEED
    from planning.simulate.run import run_moves
    from planning.simulate.verify import stock_extent, tool_shapes

    p = result.parameters
    tools = tool_shapes(p, p.tool.assembly())
    lo, hi = stock_extent(points, p.stock)
    models = stock_models.build_models(lo, hi, p, [], tools, resolution_mm=p.simulate.resolution_mm)
    out = {}
    for area, m in linuxcnc_motions(programs, result):
        run = run_moves(models.stock, None, m, tools)
        rough = (m.tool == p.post.roughing_tool_number) & (m.kind == FEED)
        za, zb = m.start_mm[:, 2] - lo[2], m.end_mm[:, 2] - lo[2]
        L = np.linalg.norm(m.end_mm - m.start_mm, axis=1)
        # the part of each straight move below z = 0 (linear in the move's parameter)
        frac = np.where((za < 0) & (zb < 0), 1.0,
                        np.where((za >= 0) & (zb >= 0), 0.0,
                                 np.abs(np.minimum(za, zb)) / np.maximum(np.abs(za - zb), 1e-12)))
        below = np.where(rough, frac * L, 0.0)
        out[area] = (float(below.sum()), float(below[run.removed_mm3 < 1e-6].sum()))
    return out


def rs274_check(programs: dict, result) -> dict:
    """Per area: (moves ``rs274`` reads in its LinuxCNC program, moves beyond the profile's travel:
    :func:`planning.simulate.program.check_travel`); empty when ``rs274`` is not installed."""
    from planning.orientations.kinematics import load_profile
    from planning.simulate.program import check_travel
    from planning.simulate.rs274 import rs274_available, run_rs274
    from planning.simulate.verify import tool_shapes

    if not rs274_available():
        return {}
    p = result.parameters
    profile = load_profile(p.machine.profile)
    tools = tool_shapes(p, p.tool.assembly())
    place = np.asarray(result.visibility.placement_mm, float)
    out = {}
    for area in result.machining_order:
        name = f"area_{area}.linuxcnc.nc"
        if name in programs:
            m = run_rs274(programs[name], program=name, area=area, profile=profile, placement_mm=place, tools=tools)
            out[area] = (int(m.n_moves), len(check_travel(m, profile)))
    return out


def plan_case(name: str, root: Path) -> dict:
    from planning.inputs import Cloud
    from planning.pipeline import run_plan
    from schemas.params import apply_overrides, parse_config

    pts, nrm, faces, doc, sets = case_input(name, root)
    cfg = parse_config(apply_overrides(doc, sets))
    cloud = Cloud(points=pts, normals=nrm, source_format="generated", faces=faces)
    t0 = time.perf_counter()
    out = run_plan(cloud, cfg, name=name)
    seconds = time.perf_counter() - t0
    r = out.result
    v = r.verification
    setups = {st.id: st for st in r.setups}
    below = below_stock(out.extra["programs"], r, cloud.points)
    rs274 = rs274_check(out.extra["programs"], r)
    rows = []
    for a in (v.areas if v is not None else []):
        ops = {o.operation: o for o in a.operations}
        ro = ops.get("roughing")
        rs = setups[a.area].path.roughing if setups[a.area].path is not None else None
        g = rs.guard if rs is not None else None
        rows.append({
            "area": a.area,
            "roughing_feed_m": round(ro.feed_mm / 1000, 2) if ro else 0.0,
            "air_share": ro.air_share if ro else 0.0,
            "plunges": ro.plunges_into_material if ro else 0,
            "below_stock_mm": round(below.get(a.area, (0.0, 0.0))[0], 1),
            "below_stock_air_mm": round(below.get(a.area, (0.0, 0.0))[1], 1),
            "roughing_min": round(ro.machining_time_s / 60, 1) if ro else 0.0,
            "removed_cm3": round(ro.removed_mm3 / 1000, 1) if ro else 0.0,
            "guard_rapids": None if g is None else g.rapids_to_feed,
            "guard_dropped": None if g is None else g.dropped,
            "guard_rounds": None if g is None else g.rounds,
            "pieces_left": int(getattr(rs, "n_pieces_left", 0) or 0) if rs is not None else 0})
    return {"case": name, "seconds": round(seconds, 1), "status": v.status if v else None,
            "message": v.message if v else None,
            "offences": None if v is None else {k: getattr(v, k) for k in (
                "travel_excursions", "rapids_into_material", "holder_collisions", "fixture_collisions",
                "plunges_into_material")},
            "gouged": None if v is None or v.deviation is None else v.deviation.n_gouged,
            "finished_share": None if v is None or v.deviation is None else v.deviation.finished_share,
            "machining_h": None if v is None else round(v.machining_time_s / 3600, 2),
            "paths_s": {t.stage: t.seconds for t in r.timings}.get("paths"),
            "rs274": {str(a): list(v) for a, v in rs274.items()},
            "areas": rows}


def table(results: list[dict]) -> str:
    lines = ["| case | area | roughing feed m | in air | plunges into material | feed below stock mm (in air) | roughing min | "
             "removed cm^3 | guard: rapids over / CL cut / rounds | pieces left |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        for x in res["areas"]:
            lines.append(f"| {res['case']} | {x['area']} | {x['roughing_feed_m']} | {x['air_share']:.1%} | "
                         f"{x['plunges']} | {x['below_stock_mm']} ({x['below_stock_air_mm']}) | {x['roughing_min']} | {x['removed_cm3']} | "
                         f"{x['guard_rapids']} / {x['guard_dropped']} / {x['guard_rounds']} | {x['pieces_left']} |")
    lines += ["", "| case | verdict | offences (travel, rapids, holder, fixture) | gouged | finished | "
              "simulated machining h | paths s | plan s | rs274: moves read / beyond travel, per area |",
              "|---|---|---|---|---|---|---|---|---|"]
    for res in results:
        o = res["offences"] or {}
        lines.append(f"| {res['case']} | {res['status']} | {o.get('travel_excursions')}, {o.get('rapids_into_material')}, "
                     f"{o.get('holder_collisions')}, {o.get('fixture_collisions')} | {res['gouged']} | "
                     f"{res['finished_share']} | {res['machining_h']} | {res['paths_s']} | {res['seconds']} | "
                     + (", ".join(f"{a}: {n} / {x}" for a, (n, x) in res["rs274"].items()) or "rs274 not installed")
                     + " |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--root", default=str(HERE), help="the checkout whose planning package plans (default: this one)")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    root = Path(args.root).resolve()
    _setup_path(root)
    print(f"planning with {root} (load average {os.getloadavg()[0]:.1f}, {os.cpu_count()} cores)", flush=True)
    results = []
    for name in args.cases:
        print(f"planning {name} ...", flush=True)
        results.append(plan_case(name, root))
        print(f"  {results[-1]['status']} in {results[-1]['seconds']} s: {results[-1]['message']}", flush=True)
    print(table(results))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
