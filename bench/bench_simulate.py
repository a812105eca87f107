"""Benchmark of the verification stage (issue 15): a plan's posted programs run on the simulated
machine and stock (:func:`planning.simulate.verify.verify_plan`), timed and measured in a process
of its own.

What it measures, per case (default: the femur-like plan as ``make run`` plans it: the
configuration of ``scripts/demo_service.py`` ``CONFIGS["femur_like"]``, tool paths and posts on,
the cloud written by ``python -m scanmill.cli sample femur_like`` and read back WITHOUT its normals,
as the demo sends a raw scan):

1. the cloud is planned ONCE in this process by :func:`planning.pipeline.run_plan`, with
   ``verify_plan`` replaced by a stub that only records the arguments the pipeline passes it
   (programs, set-up count, configuration, machine profile, placement, tool, the global
   visibility's fixtures, points, normals, input labels): the plan's stage timings and its whole
   time (the stub's "simulate" stage, ~0 s, is left out);
2. those arguments go to a temporary pickle + npz, and for every resolution of ``--res`` a FRESH
   child process (``--child``) loads them, warms the numba kernels with one first call on the same
   programs at a coarse resolution (``--warm-res``) and every 100th point (reported as
   "compile/first call"), then runs ``verify_plan`` ``--repeat`` times at the resolution (best time
   reported, each on a fresh stock; the last call's time at the end of each area's program; the
   time to read all programs back, measured apart). Memory, from the child's /proc/self/status:
   its RSS once the inputs are loaded and the kernels warm, the peak RSS of the timed calls (VmHWM,
   reset through /proc/self/clear_refs just before them) and the peak of its whole life (VmHWM;
   not ru_maxrss, which a child started from a large parent reports as the parent's). The
   parent's peak RSS (the planner holding the plan) is reported beside them: in the pipeline the
   simulation runs in the planning process, on top of what the plan holds;
3. the share of the simulation in the whole plan: simulation s / (plan s + simulation s);
4. the verification figures, overall and per area: status, travel excursions (worst: line, axis,
   excess), rapids into material (count, deepest), holder and fixture collisions, straight plunges
   of the roughing end mill into material, removed volume,
   deviation percentiles of the material left, deepest cut, finished share, gouges, simulated
   machining time.

``--whole`` also runs, in one more fresh process, the whole ``run_plan`` with the simulation on at
the first resolution, as the pipeline does: its "simulate" stage time (numba kernels loaded from
their on-disk cache on first use, as in a fresh worker), its share of the whole plan, and the
process's peak RSS (VmHWM) with the plan and the simulation together.

``--cases`` adds the other reference cases, at the default ``simulate.resolution_mm`` only: ``half_sphere``
(``normals.method=input``, ``setups.max_setups=2``, ``tool.diameter_mm=10``), ``slot`` and
``post_wall`` (defaults); their clouds keep the sample's exact normals.

    .venv/bin/python bench/bench_simulate.py [--res 1.0 0.5] [--repeat 1] [--json PATH]
        [--whole] [--cases femur_like half_sphere slot post_wall] [--timeout 1200]
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import pickle
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: ``--set`` overrides of each case besides the femur (whose configuration is the demo's).
OVERRIDES = {"half_sphere": ["normals.method=input", "setups.max_setups=2", "tool.diameter_mm=10"],
             "slot": [], "post_wall": []}
ARRAYS = ("points", "normals", "input_labels", "placement_mm")


def case_config(name: str) -> dict:
    """The configuration document of a case (``simulate.enabled`` is left on: the stub takes its place)."""
    from schemas.params import apply_overrides

    if name == "femur_like":
        spec = importlib.util.spec_from_file_location("demo_service", ROOT / "scripts" / "demo_service.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return json.loads(json.dumps(mod.CONFIGS["femur_like"]))
    return apply_overrides({}, OVERRIDES[name])


def write_cloud(name: str, path: Path) -> None:
    """``python -m scanmill.cli sample NAME --out PATH``."""
    subprocess.run([sys.executable, "-m", "scanmill.cli", "sample", name, "--out", str(path)], cwd=ROOT,
                   check=True, capture_output=True, timeout=600)


def read_case_cloud(name: str, ply: Path):
    """The sample's cloud as the case plans it (the femur without normals: the demo sends a raw scan)."""
    from planning.inputs.cloud import read_cloud

    cloud = read_cloud(ply)
    return dataclasses.replace(cloud, normals=None) if name == "femur_like" else cloud


def plan_once(name: str, ply: Path) -> tuple[dict, dict]:
    """Plan ``ply`` with the case's configuration; return (plan figures, verify_plan's arguments)."""
    from planning.pipeline import run_plan
    from planning.simulate import verify
    from schemas.params import parse_config

    config = parse_config(case_config(name))
    cloud = read_case_cloud(name, ply)
    captured: dict = {}
    real = verify.verify_plan

    def stub(**kwargs):
        captured.update(kwargs)
        return verify.skipped("captured by bench_simulate")

    verify.verify_plan = stub
    try:
        t0 = time.perf_counter()
        out = run_plan(cloud, config, name=ply.name)
        wall = time.perf_counter() - t0
    finally:
        verify.verify_plan = real
    stages = {t.stage: round(t.seconds, 2) for t in out.result.timings if t.stage != "simulate"}
    stub_s = sum(t.seconds for t in out.result.timings if t.stage == "simulate")
    plan = {"case": name, "n_points": int(cloud.points.shape[0]), "status": out.result.status,
            "k": len(captured.get("order", [])), "n_programs": len(captured.get("programs", {})),
            "stages_s": stages, "plan_s": round(wall - stub_s, 2), "config": case_config(name)}
    return plan, captured


def dump_inputs(kwargs: dict, folder: Path) -> Path:
    """verify_plan's arguments as ``inputs.npz`` (arrays) + ``inputs.pkl`` (the rest); returns the stem."""
    kw = {k: v for k, v in kwargs.items() if k != "progress"}
    np.savez(folder / "inputs.npz", **{k: np.asarray(kw.pop(k)) for k in ARRAYS})
    with open(folder / "inputs.pkl", "wb") as fh:
        pickle.dump(kw, fh)
    return folder / "inputs"


def load_inputs(stem: Path) -> dict:
    with open(f"{stem}.pkl", "rb") as fh:
        kw = pickle.load(fh)
    with np.load(f"{stem}.npz") as z:
        kw.update({k: z[k] for k in ARRAYS})
    return kw


def _with_res(config, res: float):
    return config.model_copy(update={"simulate": config.simulate.model_copy(update={"resolution_mm": res})})


def _status_kib(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return float(line.split()[1])
    return float("nan")


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _read_all_s(kw: dict) -> float:
    """Seconds to read every area's program text back into moves (part of each verify_plan call)."""
    from planning.simulate.program import read_program
    from planning.simulate.verify import choose_dialect, tool_shapes as _tools

    cfg = kw["config"]
    dialect = choose_dialect(kw["programs"], cfg.simulate.dialect)
    tools = _tools(cfg, kw["tool"])
    t0 = time.perf_counter()
    for name, text in kw["programs"].items():
        if name.endswith(f".{dialect}.nc"):
            read_program(text, dialect=dialect, program=name, area=int(name.split("_")[1].split(".")[0]),
                         profile=kw["profile"], placement_mm=kw["placement_mm"], tools=tools)
    return time.perf_counter() - t0


def _timed(kw: dict, res: float, repeat: int) -> tuple[list[float], list[float], object]:
    """``repeat`` calls at ``res``: their seconds, the last call's progress times (s since its
    start, one per area) and its outcome."""
    from planning.simulate.verify import verify_plan

    times, marks, outcome = [], [], None
    for _ in range(repeat):
        t0, marks = time.perf_counter(), []
        outcome = verify_plan(**dict(kw, config=_with_res(kw["config"], res),
                                     progress=lambda f, m, mk=marks, t=t0: mk.append(round(time.perf_counter() - t, 2))))
        times.append(time.perf_counter() - t0)
    return times, marks, outcome


def child_main(stem: Path, res: float, repeat: int, warm_res: float, out: Path) -> None:
    """In the child: load, warm, time ``verify_plan`` at ``res``; write the figures to ``out``."""
    import numba

    from planning.simulate.verify import verify_plan

    t0 = time.perf_counter()
    kw = load_inputs(stem)
    load_s, rss_loaded = time.perf_counter() - t0, _status_kib("VmRSS") / 1024
    warm = dict(kw, config=_with_res(kw["config"], warm_res), points=kw["points"][::100],
                normals=kw["normals"][::100], input_labels=kw["input_labels"][::100])
    t0 = time.perf_counter()
    verify_plan(**warm)
    first_s = time.perf_counter() - t0
    rss_warm, hwm_warm = _status_kib("VmRSS") / 1024, _status_kib("VmHWM") / 1024
    load_before = os.getloadavg()
    reset = _reset_peak()
    times, marks, outcome = _timed(kw, res, repeat)
    peak_timed = _status_kib("VmHWM") / 1024 if reset else float("nan")
    rec = {"resolution_mm": res, "threads": numba.get_num_threads(), "loadavg_1min_before": round(load_before[0], 2),
           "load_s": round(load_s, 2), "first_call_s": round(first_s, 2), "warm_res_mm": warm_res,
           "seconds": [round(t, 2) for t in times], "best_s": round(min(times), 2), "area_marks_s": marks,
           "read_programs_s": round(_read_all_s(kw), 2),
           "rss_loaded_mib": round(rss_loaded), "rss_warm_mib": round(rss_warm), "peak_timed_mib": round(peak_timed),
           "peak_child_mib": round(max(hwm_warm, peak_timed if reset else _status_kib("VmHWM") / 1024)),
           "model_mib": round(outcome.stock.nbytes / 2**20, 1) if hasattr(outcome.stock, "nbytes") else None,
           "verification": outcome.verification.model_dump(mode="json")}
    out.write_text(json.dumps(rec))


def _spawn(extra: list[str], out: Path, timeout: float) -> dict:
    """Run this script as a fresh child with ``extra`` arguments; its JSON record (or the error)."""
    cmd = [sys.executable, str(Path(__file__).resolve()), *extra, "--child-out", str(out)]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout} s"}
    if p.returncode != 0:
        return {"error": p.stderr[-3000:]}
    rec = json.loads(out.read_text())
    rec["child_wall_s"] = round(time.perf_counter() - t0, 1)
    return rec


def run_child(stem: Path, res: float, args) -> dict:
    """One fresh child process for one resolution (bounded by ``--timeout``)."""
    rec = _spawn(["--child", str(stem), "--res", str(res), "--repeat", str(args.repeat),
                  "--warm-res", str(args.warm_res)], Path(f"{stem}.res{res}.json"), args.timeout)
    rec.setdefault("resolution_mm", res)
    return rec


def whole_child(case: str, ply: Path, res: float, out: Path) -> None:
    """In the child (``--whole``): the whole plan with the simulation on, as the pipeline runs it."""
    from planning.pipeline import run_plan
    from schemas.params import parse_config

    data = case_config(case)
    data.setdefault("simulate", {})["resolution_mm"] = res
    cloud = read_case_cloud(case, ply)
    t0 = time.perf_counter()
    o = run_plan(cloud, parse_config(data), name=ply.name)
    wall = time.perf_counter() - t0
    stages = {t.stage: round(t.seconds, 2) for t in o.result.timings}
    out.write_text(json.dumps({"resolution_mm": res, "whole_s": round(wall, 2), "stages_s": stages,
                               "simulate_s": stages.get("simulate"), "peak_mib": round(_status_kib("VmHWM") / 1024),
                               "loadavg_1min_after": round(os.getloadavg()[0], 2),
                               "status": o.result.verification.status}))


def print_whole(case: str, r: dict) -> None:
    if "error" in r:
        print(f"[{case}] whole plan failed: {r['error']}", file=sys.stderr)
        return
    print(f"\n{case}, whole plan with the simulation at {r['resolution_mm']} mm in one fresh process: "
          f"{r['whole_s']} s, of which simulate {r['simulate_s']} s ({r['simulate_s'] / r['whole_s']:.0%}); "
          f"peak RSS {r['peak_mib']} MiB; stages {r['stages_s']}; verification {r['status']}")


def _worst(v: dict, program: str, kind: str) -> dict | None:
    rows = [o for o in v["worst"] if o["program"] == program and o["kind"] == kind]
    return max(rows, key=lambda o: o["amount"]) if rows else None


def area_rows(v: dict) -> list[dict]:
    """Per area: the figures the acceptance asks for (module docstring, 4)."""
    rows = []
    for a in v["areas"]:
        d = a.get("deviation") or {}
        tr, rp = _worst(v, a["program"], "travel"), _worst(v, a["program"], "rapid_into_material")
        rows.append({
            "area": a["area"], "program": a["program"], "moves": a["n_moves"],
            "travel": a["travel_excursions"],
            "travel_worst": f"line {tr['line']}: {tr['detail']} (+{tr['amount']:.3f})" if tr else "",
            "rapids": a["rapids_into_material"], "rapid_deepest_mm": rp["amount"] if rp else 0.0,
            "holder": a["holder_collisions"], "fixture": a["fixture_collisions"],
            "plunges": a.get("plunges_into_material", 0),
            "removed_cm3": round(a["removed_mm3"] / 1000, 1),
            "left_p50": d.get("left_p50_mm"), "left_p95": d.get("left_p95_mm"), "left_max": d.get("left_max_mm"),
            "deepest_cut": d.get("gouge_max_mm"), "gouged": d.get("n_gouged"), "finished": d.get("finished_share"),
            "points": d.get("n_points"), "time_min": round(a["machining_time_s"] / 60, 1)})
    return rows


def print_areas(case: str, rec: dict) -> None:
    v = rec["verification"]
    print(f"\n{case} at {rec['resolution_mm']} mm: {v['status'].upper()} - {v['message']}")
    print("| area | program | moves | travel exc. (worst) | rapids into material (deepest mm) | holder | fixture "
          "| plunges | removed cm3 | left p50 / p95 / max mm | deepest cut mm | gouged pts | finished | machining min |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in area_rows(v):
        tw = f" ({r['travel_worst']})" if r["travel_worst"] else ""
        print(f"| {r['area']} | {r['program']} | {r['moves']} | {r['travel']}{tw} | {r['rapids']} "
              f"({r['rapid_deepest_mm']:.3f}) | {r['holder']} | {r['fixture']} | {r['plunges']} | {r['removed_cm3']} | "
              f"{r['left_p50']:.3f} / {r['left_p95']:.3f} / {r['left_max']:.3f} | {r['deepest_cut']:.3f} | "
              f"{r['gouged']} | {r['finished']:.1%} | {r['time_min']} |")
    d = v["deviation"]
    print(f"| all | | {sum(a['n_moves'] for a in v['areas'])} | {v['travel_excursions']} | "
          f"{v['rapids_into_material']} | {v['holder_collisions']} | {v['fixture_collisions']} | "
          f"{v.get('plunges_into_material', 0)} | "
          f"{round(sum(a['removed_mm3'] for a in v['areas']) / 1000, 1)} | {d['left_p50_mm']:.3f} / "
          f"{d['left_p95_mm']:.3f} / {d['left_max_mm']:.3f} | {d['gouge_max_mm']:.3f} | {d['n_gouged']} | "
          f"{d['finished_share']:.1%} | {round(v['machining_time_s'] / 60, 1)} |")


def print_timing(case: str, plan: dict, recs: list[dict], parent_mib: float) -> None:
    print(f"\n{case}: plan {plan['plan_s']} s without the simulation; stages {plan['stages_s']}; "
          f"parent peak RSS {parent_mib:.0f} MiB (holding the plan)")
    print("| resolution mm | verify_plan s (best of n) | compile/first call s | share of plan + simulation "
          "| child RSS loaded+warm MiB | peak RSS of the timed call MiB | child peak RSS MiB | reading the programs s "
          "| load (1 min) | status |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in recs:
        if "error" in r:
            print(f"| {r['resolution_mm']} | error: {r['error'].splitlines()[-1] if r['error'] else ''} |")
            continue
        share = r["best_s"] / (plan["plan_s"] + r["best_s"])
        print(f"| {r['resolution_mm']} | {r['best_s']} ({len(r['seconds'])}) | {r['first_call_s']} "
              f"(at {r['warm_res_mm']} mm) | {share:.0%} | {r['rss_warm_mib']} | {r['peak_timed_mib']} | "
              f"{r['peak_child_mib']} | {r['read_programs_s']} | {r['loadavg_1min_before']} | "
              f"{r['verification']['status']} |")
        print(f"|   | time at the end of each area's program, s: {r['area_marks_s']} | | | | | | | | |")


def bench_case(case: str, resolutions: list[float], args, tmp: Path) -> dict:
    """Sample, plan once, simulate each resolution in a fresh child; print and return the figures."""
    ply = tmp / f"{case}.ply"
    write_cloud(case, ply)
    print(f"[{case}] planning ...", flush=True)
    plan, kwargs = plan_once(case, ply)
    parent_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    if not kwargs:
        print(f"[{case}] nothing was posted: no simulation")
        return {"plan": plan, "runs": []}
    (tmp / case).mkdir()
    stem = dump_inputs(kwargs, tmp / case)
    del kwargs
    recs = []
    for res in resolutions:
        print(f"[{case}] simulating at {res} mm in a fresh process ...", flush=True)
        recs.append(run_child(stem, res, args))
    whole = None
    if args.whole:
        print(f"[{case}] whole plan with the simulation at {resolutions[0]} mm in a fresh process ...", flush=True)
        whole = _spawn(["--whole-child", case, "--whole-ply", str(ply), "--res", str(resolutions[0])],
                       tmp / case / "whole.json", args.timeout)
    for r in recs:
        if "error" in r:
            print(f"[{case}] {r['resolution_mm']} mm failed: {r['error']}", file=sys.stderr)
    print_timing(case, plan, recs, parent_mib)
    for r in recs:
        if "error" not in r:
            print_areas(case, r)
    if whole is not None:
        print_whole(case, whole)
    return {"plan": plan, "parent_peak_rss_mib": round(parent_mib), "runs": recs, "whole": whole}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=float, nargs="+", default=[1.0, 0.5], help="ray spacings, mm")
    ap.add_argument("--repeat", type=int, default=1, help="timed calls per resolution (best reported)")
    ap.add_argument("--cases", nargs="+", default=["femur_like"],
                    choices=["femur_like", "half_sphere", "slot", "post_wall"])
    ap.add_argument("--warm-res", type=float, default=5.0, help="resolution of the warm-up call, mm")
    ap.add_argument("--timeout", type=float, default=1200.0, help="bound on each child, s")
    ap.add_argument("--json", help="write every figure here")
    ap.add_argument("--whole", action="store_true",
                    help="also run the whole plan with the simulation on (first resolution) in a fresh process")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--whole-child", help=argparse.SUPPRESS)
    ap.add_argument("--whole-ply", help=argparse.SUPPRESS)
    ap.add_argument("--child-out", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child_main(Path(args.child), args.res[0], args.repeat, args.warm_res, Path(args.child_out))
        return
    if args.whole_child:
        whole_child(args.whole_child, Path(args.whole_ply), args.res[0], Path(args.child_out))
        return
    from schemas.params import PlanConfig

    default = PlanConfig().simulate.resolution_mm
    print(f"default simulate.resolution_mm = {default}")
    out = {"argv": sys.argv[1:], "cases": {}}
    with tempfile.TemporaryDirectory(prefix="bench_simulate_") as tmp:
        for case in args.cases:
            res = args.res if case == "femur_like" else [default]
            out["cases"][case] = bench_case(case, res, args, Path(tmp))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
