"""The admission estimate (planning.budget.estimate_job_memory): its cost, and its calibration.

    .venv/bin/python bench/bench_admission.py                 # microseconds per estimate
    .venv/bin/python bench/bench_admission.py --calibrate     # estimate vs measured, real jobs (minutes)

The first prints the time of one estimate for the half sphere and femur-like parameter sets (many
repeats, best of several rounds). The second runs each calibration case as the embedded worker runs a
job - in a fresh process that has imported what the worker's fork server preloads, under
``service.memlimit.apply_job_memory_limit`` (a limit far above the need, so that the process is set up
as a job process is) and through ``service.workers.plan_attempt`` - and prints the address space the
job added (VmPeak minus VmSize before the job, what the limit counts) and its peak resident growth
next to the estimate.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HALF_EXTENT = (100.0, 100.0, 50.0)
FEMUR_EXTENT = (396.1, 104.9, 67.5)

CASES = [  # (name, sample, points, parameters)
    *[(f"half sphere, phi_step {s:g}", "half_sphere", 2537, {"orientations": {"phi_step_deg": s}})
      for s in (10, 2, 1, 0.5, 0.2)],
    ("half sphere, phi_step 0.5, 5 set-ups searched", "half_sphere", 2537,
     {"orientations": {"phi_step_deg": 0.5}, "visibility": {"cone_deg": [10, 45]},
      "setups": {"coverage": 0.99, "time_limit_s": 20}}),
    ("femur-like 100k", "femur_like", 100_000, {}),
    ("femur-like 100k, normals input", "femur_like", 100_000, {"normals": {"method": "input"}}),
    ("femur-like 1M", "femur_like", 1_000_000, {}),
]
SLOW_CASES = [("half sphere, phi_step 0.1", "half_sphere", 2537, {"orientations": {"phi_step_deg": 0.1}})]


def _status(key: str) -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    return 0


def run_one(ply: str, params: dict) -> dict:
    """One job, as the embedded worker runs it; returns the measured growth (bytes) and what was planned."""
    import numpy  # noqa: F401 - the fork server's preload (service.workers.PRELOAD)

    import planning.inputs.cloud  # noqa: F401
    import planning.pipeline  # noqa: F401
    import planning.report.plan_files  # noqa: F401
    import schemas.params  # noqa: F401
    from service.memlimit import apply_job_memory_limit
    from service.workers import plan_attempt

    vm0, rss0 = _status("VmSize"), _status("VmRSS")
    apply_job_memory_limit(8 * 1024 * 1024)          # 8 TiB: set up like a job process, never reached
    stages = []

    def report(stage, fraction, message=""):
        if fraction >= 1.0:
            stages.append((stage, (_status("VmPeak") - vm0) // (1 << 20)))

    with tempfile.TemporaryDirectory() as tmp:
        spec = {"parameters": params, "input_path": ply, "fmt": None, "max_points": 20_000_000,
                "work_dir": str(Path(tmp) / "work"), "name": "calibration"}
        t0 = time.perf_counter()
        summary, _ = plan_attempt(spec, report)
        seconds = time.perf_counter() - t0
        artifacts = sum(p.stat().st_size for p in Path(tmp, "work").iterdir())
    return {"vm_growth": _status("VmPeak") - vm0, "rss_growth": _status("VmHWM") - rss0, "stages": stages,
            "seconds": round(seconds, 1), "artifact_bytes": artifacts, "summary": summary}


def calibrate(slow: bool, verbose: bool = False) -> None:
    import numpy as np

    from planning.budget import estimate_artifact_bytes, estimate_job_memory
    from planning.inputs.samples import make_sample
    from planning.report.files import write_ply
    from schemas.params import parse_config

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        plys = {}
        for name, sample, npts, params in CASES + (SLOW_CASES if slow else []):
            key = (sample, npts)
            if key not in plys:
                s = make_sample(sample, **({} if sample == "half_sphere" else {"n_points": npts}))
                path = Path(tmp) / f"{sample}-{npts}.ply"
                write_ply(path, s.points, normals=s.normals, binary=True)
                plys[key] = (str(path), tuple(float(v) for v in np.ptp(s.points, axis=0)), s.points.shape[0])
            path, extent, n = plys[key]
            out = subprocess.run([sys.executable, __file__, "--one", path, json.dumps(params)], cwd=ROOT,
                                 capture_output=True, text=True, env={**os.environ, "PYTHONHASHSEED": "0"}, check=False)
            if out.returncode != 0:
                print(f"{name}: failed\n{out.stderr[-3000:]}")
                continue
            got = json.loads(out.stdout.strip().splitlines()[-1])
            config = parse_config(params)
            est = estimate_job_memory(n, config, extent_mm=extent)
            art = estimate_artifact_bytes(n, config, extent_mm=extent)
            rows.append((name, est, got, art))
            mib = 1 << 20
            print(f"| {name} | {n:,} | {est.n_sampled:,} | {est.n_feasible:,} | {est.total_bytes / mib:,.0f} "
                  f"({est.peak_stage}: {est.largest.what}) | {got['vm_growth'] / mib:,.0f} | "
                  f"{got['rss_growth'] / mib:,.0f} | {est.total_bytes / got['vm_growth']:.2f} | "
                  f"{got['artifact_bytes'] / mib:,.0f} / {art / mib:,.0f} | {got['seconds']} |", flush=True)
            if verbose:
                print(f"    stages (address space MiB at the end of each): {got['stages']}; terms: "
                      + ", ".join(f"{t.what} {t.mib:,.0f}" for t in est.terms), flush=True)
    print("\ncolumns: case | points | sampled (estimated) | feasible axes | estimate MiB (peak stage: largest term)"
          " | measured address space MiB | measured resident MiB | estimate / measured | artifacts MiB "
          "measured / estimated | seconds")


def bench(repeats: int, rounds: int) -> None:
    from planning.budget import estimate_job_memory
    from schemas.params import parse_config

    cases = [
        ("half sphere (2,537 points, normals from the file)", 2537, HALF_EXTENT,
         {"normals": {"method": "input"}, "tool": {"diameter_mm": 10}, "setups": {"max_setups": 2}}),
        ("half sphere, phi_step 0.01", 2537, HALF_EXTENT, {"orientations": {"phi_step_deg": 0.01}}),
        ("femur-like (1,000,000 points, defaults)", 1_000_000, FEMUR_EXTENT, {}),
        ("femur-like, no extent given", 1_000_000, None, {}),
    ]
    for name, n, extent, params in cases:
        config = parse_config(params)
        est = estimate_job_memory(n, config, extent_mm=extent)
        best = float("inf")
        for _ in range(rounds):
            t0 = time.perf_counter()
            for _ in range(repeats):
                estimate_job_memory(n, config, extent_mm=extent)
            best = min(best, (time.perf_counter() - t0) / repeats)
        print(f"{name}: {best * 1e6:.1f} us per estimate ({est.total_mib:,.0f} MiB, largest: {est.largest.what})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calibrate", action="store_true", help="run the calibration jobs (minutes)")
    ap.add_argument("--slow", action="store_true", help="with --calibrate: also phi_step 0.1 (5 GiB, a minute)")
    ap.add_argument("--verbose", action="store_true", help="with --calibrate: per-stage figures and the terms")
    ap.add_argument("--repeat", type=int, default=2000, help="estimates per round (default 2000)")
    ap.add_argument("--rounds", type=int, default=5, help="rounds, the best is reported (default 5)")
    ap.add_argument("--one", nargs=2, metavar=("PLY", "PARAMS"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(run_one(args.one[0], json.loads(args.one[1]))))
    elif args.calibrate:
        calibrate(args.slow, args.verbose)
    else:
        bench(args.repeat, args.rounds)


if __name__ == "__main__":
    main()
