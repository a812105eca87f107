"""The whole plan on the simulated range scans (issue 30's acceptance figure).  Prints figures only.

Each case is a scanner-like reference sample, :func:`planning.inputs.samples.range_scan` (scan lines
0.3 mm along and 0.6 mm across, holes at grazing incidence, noise, outliers, registration errors;
default ``range_femur`` and ``range_half_sphere`` at 40,000 points, seed 0), planned as a real scan
would be: the default parameters with ``--set setups.coverage=0.9 --set setups.max_setups=5`` (the
same ``path=value`` overrides as ``scanmill plan --set``, applied by
:func:`schemas.params.apply_overrides` before :func:`schemas.params.parse_config`), no normals from
the file, paths and verification on (the defaults), then written to a temporary folder.

Every case runs once per thread count (``--threads``, default 1 and 2), each in a fresh process
(``--one``) whose environment sets ``NUMBA_NUM_THREADS`` and ``OMP_NUM_THREADS`` to that count,
so each peak memory is that run's own and both counts come from the same run of this script.  Those
two variables limit the numba kernels and OpenMP/BLAS; the Python thread pools of the normals
(up to 4 workers, by CPU affinity) and of the axis collision scan (2 workers) are not limited by them:
``--pin`` also restricts each child to its first N cores (``os.sched_setaffinity``), so that a
1-thread run uses one core for everything.  The kernels come from the numba cache: run
``.venv/bin/scanmill warmup`` (or any plan) first, or the first run's figures include compiling.

Per case and thread count it prints: the wall seconds of the plan (``run_plan``) and of plan + write,
the seconds per stage (``plan.json`` ``timings``, the pipeline's own clock; ``write`` is
:func:`planning.report.plan_files.write_plan`) with the peak RSS while each ran, the peak RSS of the
process (MB; sampled every 20 ms by a thread, the generated sample included), the plan status and
the exit code ``scanmill plan`` would give (``scanmill.cli.exit_status``: 0 planned, 3 infeasible or
incomplete, 4 verification failed, 5 unfinished), the verification status and mode (``single_pass`` or
``independent`` where the plan reports it), the coverage reached, the simulated machining time
(``verification.machining_time_s``, h:mm), the roughing air share (``air_feed_mm / feed_mm``
summed over the roughing operations of every area) and the roughing plunges into material, and the
share of scan points finished within tolerance.  Then, per case, t(1 thread) / t(2 threads) of the
plan and of each stage.  An infeasible plan (coverage 0.9 not reachable with 5 set-ups) is printed
with its status like any other; nothing in the planner is changed for it.

    .venv/bin/scanmill warmup
    .venv/bin/python bench/bench_range_scan.py                                  # femur + half sphere, 1 and 2 threads
    .venv/bin/python bench/bench_range_scan.py --cases range_slot range_filleted_box --threads 2
    .venv/bin/python bench/bench_range_scan.py --points 30000 50000 --json /tmp/range_scan.json
    .venv/bin/python bench/bench_range_scan.py --pin --set simulate.mode=independent

Issue 30's targets (printed as ``ok``/``NO`` under the table): plan + write under 30 s and peak RSS
under 1 GB (1024 MB) on 2 cores, and verification ``passed``.  The load average (1 min) is printed
before each run and after all of them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

CASES = ("range_femur", "range_half_sphere")
POINTS = (40_000,)
THREADS = (1, 2)
#: issue 30: "a real scan": 90 % coverage with up to 5 set-ups; everything else at its default
OVERRIDES = ("setups.coverage=0.9", "setups.max_setups=5")
TARGET_S, TARGET_MB = 30.0, 1024.0
STAGE_ORDER = ("normals", "orientations", "placement", "visibility", "setups", "areas", "paths", "post",
               "simulate", "write")


def _exit_code(result) -> int:
    """What ``scanmill plan`` returns for this plan: the CLI's own rule (scanmill/cli.py exit_status)."""
    from scanmill.cli import exit_status

    return exit_status(result)


def _hmm(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    m = round(seconds / 60.0)
    return f"{m // 60}:{m % 60:02d}"


def run_one(case: str, n_points: int, overrides: list[str]) -> dict:
    """Plan the sample ``case`` of ``n_points`` points in this process; return its figures."""
    t_start = time.perf_counter()
    import numba
    from bench_scaling import _RssSampler, plan_and_write

    from planning.inputs import Cloud
    from planning.inputs.samples import make_sample
    from schemas.params import apply_overrides, parse_config

    cfg = parse_config(apply_overrides({}, overrides))
    t0 = time.perf_counter()
    s = make_sample(case, n_points=n_points)
    t_sample = time.perf_counter() - t0
    sampler = _RssSampler()
    sampler.stage = "start"
    base = sampler.rss_mb()
    sampler.start()

    def progress(stage, fraction, message):
        if stage != sampler.stage:
            sampler.mark()
            sampler.stage = stage

    out, seconds, t_plan, t_write = plan_and_write(Cloud(points=s.points, normals=None, source_format="generated"),
                                                   cfg, case, sampler, progress)
    r = out.result
    v = r.verification
    rough_feed = rough_air = 0.0
    rough_plunges = 0
    rough_time = 0.0
    if v is not None:
        for a in v.areas:
            for op in getattr(a, "operations", []) or []:
                if op.operation == "roughing":
                    rough_feed += float(op.feed_mm)
                    rough_air += float(op.air_feed_mm)
                    rough_plunges += int(op.plunges_into_material)
                    rough_time += float(op.machining_time_s)
    dev = None if v is None else v.deviation
    verdict = None if v is None else v.status
    try:
        layer = numba.threading_layer()
    except Exception:  # noqa: BLE001 - no parallel kernel ran in this process
        layer = None
    return {
        "case": case, "n_points_target": n_points, "n_points": int(s.points.shape[0]),
        "scale": s.meta.get("scale"), "overrides": list(overrides),
        "numba_threads": int(numba.config.NUMBA_NUM_THREADS), "threading_layer": layer,
        "omp_threads": os.environ.get("OMP_NUM_THREADS"),
        "cpus": sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "n_sampled": int(r.normals.n_sampled), "k": int(r.selection.k) if r.selection is not None else None,
        "status": r.status, "exit_code": _exit_code(r), "message": r.message,
        "coverage": float(r.coverage),
        "verdict": verdict, "verification_mode": getattr(v, "mode", None) if v is not None else None,
        "verification_message": None if v is None else v.message,
        "machining_time_s": None if v is None else float(v.machining_time_s),
        "roughing_feed_mm": rough_feed, "roughing_air_feed_mm": rough_air,
        "roughing_air_share": (rough_air / rough_feed) if rough_feed > 0 else None,
        "roughing_time_s": rough_time, "roughing_plunges": rough_plunges,
        "plunges_into_material": None if v is None else int(v.plunges_into_material),
        "finished_share": None if dev is None else float(dev.finished_share),
        "gouge_max_mm": None if dev is None else float(dev.gouge_max_mm),
        "seconds": seconds, "sample_s": t_sample, "plan_s": t_plan, "total_s": t_plan + t_write,
        "process_s": time.perf_counter() - t_start,
        "peak_rss_mb": sampler.peak, "base_rss_mb": base, "overall_peak_mb": max(sampler.peak.values()),
    }


def _label(r: dict) -> str:
    return f"{r['case']} {r['n_points_target'] / 1000:g}k, {r['threads']} thr"


def _table(rows: list[dict]) -> str:
    ok = [r for r in rows if "error" not in r]
    seen = [s for s in STAGE_ORDER if any(s in r["seconds"] for r in ok)]
    seen += [s for r in ok for s in r["seconds"] if s not in seen and s not in STAGE_ORDER]
    seen = list(dict.fromkeys(seen))
    lines = ["| | " + " | ".join(_label(r) for r in rows) + " |", "|" + "---|" * (len(rows) + 1)]

    def row(name, fn):
        cells = []
        for r in rows:
            if "error" in r:
                cells.append(f"failed (exit {r['error']})" if name == "plan status (exit code)" else "-")
            else:
                cells.append(fn(r))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")

    row("points (sampled)", lambda r: f"{r['n_points']:,} ({r['n_sampled']:,})")
    for st in seen:
        def cell(r, st=st):
            sec, mb = r["seconds"].get(st), r["peak_rss_mb"].get(st)
            return "-" if sec is None else f"{sec:.2f} ({mb:.0f} MB)" if mb else f"{sec:.2f}"
        row(f"{st}, s (peak RSS)", cell)
    row("**plan, s**", lambda r: f"**{r['plan_s']:.2f}**")
    row("plan + write, s", lambda r: f"{r['total_s']:.2f}")
    row("peak RSS, MB", lambda r: f"{r['overall_peak_mb']:.0f}")
    row("plan status (exit code)", lambda r: f"{r['status']} ({r['exit_code']})")
    row("set-ups", lambda r: "-" if r["k"] is None else str(r["k"]))
    row("coverage reached", lambda r: f"{r['coverage']:.1%}")
    row("verification (mode)", lambda r: f"{r['verdict']} ({r['verification_mode'] or '-'})")
    row("simulated machining, h:mm", lambda r: _hmm(r["machining_time_s"]))
    row("roughing air share (air / feed m)",
        lambda r: "-" if r["roughing_air_share"] is None else
        f"{r['roughing_air_share']:.1%} ({r['roughing_air_feed_mm'] / 1000:.1f} / {r['roughing_feed_mm'] / 1000:.1f})")
    row("roughing plunges into material", lambda r: str(r["roughing_plunges"]))
    row("finished within tolerance", lambda r: "-" if r["finished_share"] is None else f"{r['finished_share']:.1%}")
    row(f"under {TARGET_S:g} s / {TARGET_MB / 1024:g} GB / clean",
        lambda r: " / ".join("ok" if c else "NO" for c in (r["total_s"] < TARGET_S, r["overall_peak_mb"] < TARGET_MB,
                                                          r["verdict"] == "passed")))
    row("load before (1 min)", lambda r: f"{r['load_before']:.2f}")
    return "\n".join(lines)


def _ratios(rows: list[dict], threads: list[int]) -> str:
    """Per case: t(first thread count) / t(each other) of the plan and of every stage."""
    if len(threads) < 2:
        return ""
    base_t = threads[0]
    out = []
    groups: dict[tuple, dict[int, dict]] = {}
    for r in rows:
        if "error" not in r:
            groups.setdefault((r["case"], r["n_points_target"]), {})[r["threads"]] = r
    for (case, n), by in groups.items():
        if base_t not in by:
            continue
        a = by[base_t]
        for t in threads[1:]:
            if t not in by:
                continue
            b = by[t]
            parts = [f"plan {a['plan_s']:.2f} / {b['plan_s']:.2f} s = {a['plan_s'] / b['plan_s']:.2f}"]
            for st, sa in a["seconds"].items():
                sb = b["seconds"].get(st)
                if sb and sa > 0.05:
                    parts.append(f"{st} {sa / sb:.2f}")
            out.append(f"t({base_t} thread{'s' if base_t > 1 else ''}) / t({t} threads), {case} {n / 1000:g}k: "
                       + "; ".join(parts))
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), help="sample names (planning.inputs.samples.SAMPLES)")
    ap.add_argument("--points", type=int, nargs="+", default=list(POINTS), help="point counts asked of the scan")
    ap.add_argument("--threads", type=int, nargs="+", default=list(THREADS),
                    help="NUMBA_NUM_THREADS / OMP_NUM_THREADS of each run (the first is the ratios' numerator)")
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="more overrides after setups.coverage=0.9 and setups.max_setups=5 (as scanmill plan --set)")
    ap.add_argument("--pin", action="store_true", help="also restrict each child to its first N cores")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds one child may run")
    ap.add_argument("--json", default=None, help="write the raw figures (JSON) here")
    ap.add_argument("--one", nargs=2, default=None, help=argparse.SUPPRESS)          # the child: CASE N
    ap.add_argument("--cpus", type=int, default=None, help=argparse.SUPPRESS)        # the child, with --pin
    args = ap.parse_args()
    overrides = list(OVERRIDES) + list(args.set)
    if args.one is not None:
        if args.cpus:
            os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:args.cpus])
        print("RESULT " + json.dumps(run_one(args.one[0], int(args.one[1]), overrides)), flush=True)
        return 0

    print(f"cores {os.cpu_count()}; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} (1/5/15 min); "
          f"overrides {' '.join(overrides)}; threads {args.threads}{' (pinned)' if args.pin else ''}", flush=True)
    rows = []
    failed = False
    for case in args.cases:
        for n in args.points:
            for th in args.threads:
                env = dict(os.environ, NUMBA_NUM_THREADS=str(th), OMP_NUM_THREADS=str(th))
                cmd = [sys.executable, os.path.abspath(__file__), "--one", case, str(n)]
                for s in args.set:
                    cmd += ["--set", s]
                if args.pin:
                    cmd += ["--cpus", str(th)]
                load = os.getloadavg()[0]
                t = time.perf_counter()
                try:
                    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, cwd=ROOT, env=env,
                                          timeout=args.timeout)
                    rc, stdout, stderr = proc.returncode, proc.stdout, proc.stderr
                except subprocess.TimeoutExpired as exc:
                    rc, stdout, stderr = "timeout", exc.stdout or "", exc.stderr or ""
                    stdout = stdout.decode() if isinstance(stdout, bytes) else stdout
                    stderr = stderr.decode() if isinstance(stderr, bytes) else stderr
                line = [x for x in stdout.splitlines() if x.startswith("RESULT ")]
                if rc != 0 or not line:
                    print(f"{case} {n:,} points, {th} threads: the child failed (exit {rc})\n{stderr[-3000:]}",
                          file=sys.stderr, flush=True)
                    rows.append({"case": case, "n_points_target": n, "threads": th, "error": rc, "load_before": load})
                    failed = True
                    continue
                row = json.loads(line[0][len("RESULT "):])
                row.update(threads=th, load_before=load, child_s=time.perf_counter() - t)
                rows.append(row)
                print(f"{case} {row['n_points']:,} points (scale {row['scale']}), {th} thread(s) "
                      f"[numba {row['numba_threads']}, {row['threading_layer']}, cpus {row['cpus']}]: "
                      f"plan {row['plan_s']:.1f} s, write {row['seconds']['write']:.1f} s, "
                      f"peak {row['overall_peak_mb']:.0f} MB, {row['status']}, verification {row['verdict']}"
                      f"{' (' + row['verification_mode'] + ')' if row['verification_mode'] else ''}; "
                      f"load before {load:.2f}", flush=True)
                if row["status"] != "planned":
                    print(f"  not planned: {row['message']}", flush=True)
                if row["verdict"] not in ("passed", None):
                    print(f"  verification: {row['verification_message']}", flush=True)
    print()
    print(_table(rows))
    ratios = _ratios(rows, args.threads)
    if ratios:
        print()
        print(ratios)
    print(f"\nload average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())} (1/5/15 min); "
          f"cores: {os.cpu_count()}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
        print(f"json: {args.json}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
