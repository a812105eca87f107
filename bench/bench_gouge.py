"""Benchmark of the exact gouge confirmation (issue 30): :func:`planning.simulate.gouge.penetration_mm`,
numba kernels, against the numpy implementation they replaced (k-d tree over the move pieces,
np.unique over the (point, move) pairs, the depths vectorised over the pairs; kept with the same
operations as ``reference_penetration_mm`` in tests/test_simulate_gouge.py, imported from there).

Per case, in this one process:

1. the sample is planned once by :func:`planning.pipeline.run_plan` with ``verify_plan`` replaced by a
   stub that records its arguments (as bench/bench_simulate.py does); the posted programs are read
   back into moves as the verification reads them (:func:`planning.simulate.program.read_program`,
   :func:`planning.simulate.verify.tool_shapes`): ``motions`` and ``tools`` exactly as
   ``verify_plan`` passes them to ``penetration_mm``;
2. the points measured: every point of the planned scan (as if the deviation suspected them all;
   the verification passes only the suspects, so this is the worst case of a scan of that size),
   and a random subset of ``--ref-points`` of them for the slow reference;
3. timings, medians of ``--repeat`` runs, the thread counts alternating run by run (the machine is
   shared: peers measured in the same process, interleaved): the reference on the subset; the
   kernels on the subset and on all points with ``numba.set_num_threads(1)`` and ``(2)``, each
   followed by a trivial compute-bound ``prange`` loop on the same threads (the calibration: what the
   shared machine gave a second thread at the time); the first call (compilation or cache load)
   apart. Printed: the seconds, reference / kernel, and
   1 thread / 2 threads; the largest difference from the reference on the subset (mm) and the
   count of points cut.

Cases: ``half_sphere`` (the sample's 2537 points with its normals, ``normals.method=input``,
``setups.max_setups=2``, ``tool.diameter_mm=10``, as bench_simulate plans it) and ``femur_like``
(``--femur-points`` points, default 100k, planned with the demo's configuration, read without its
normals as a raw scan).

    .venv/bin/python bench/bench_gouge.py [--cases half_sphere femur_like] [--femur-points 100000]
        [--ref-points 600] [--repeat 3] [--ref-repeat 2] [--json PATH]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _module(path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def plan_case(name: str, n_points: int | None) -> tuple[dict, list, dict, np.ndarray]:
    """Plan the sample; return (figures, motions, tools, points) as verify_plan would see them."""
    from planning.inputs.samples import make_sample
    from planning.report.files import write_ply
    from planning.simulate import verify
    from planning.simulate.program import read_program

    bench_simulate = _module(ROOT / "bench" / "bench_simulate.py", "bench_simulate")
    sample = make_sample(name, **({"n_points": n_points} if n_points else {}))
    with tempfile.TemporaryDirectory() as tmp:          # the plan with verify_plan captured, as bench_simulate does
        ply = Path(tmp) / f"{name}.ply"
        write_ply(ply, sample.points, normals=sample.normals, binary=True)
        plan, captured = bench_simulate.plan_once(name, ply)
    if not captured:
        raise SystemExit(f"{name}: the plan posted no programs ({plan['status']})")
    cfg = captured["config"]
    dialect = verify.choose_dialect(captured["programs"], cfg.simulate.dialect)
    tools = verify.tool_shapes(cfg, captured["tool"])
    order = captured["order"]
    order = list(range(order)) if isinstance(order, (int, np.integer)) else [int(i) for i in order]
    motions = []
    for i in order:
        prog = f"area_{i}.{dialect}.nc"
        if prog in captured["programs"]:
            motions.append(read_program(captured["programs"][prog], dialect=dialect, program=prog, area=i,
                                        profile=captured["profile"], placement_mm=captured["placement_mm"],
                                        tools=tools))
    from planning.simulate.motion import FEED
    feed = {int(t): int(sum(((m.kind == FEED) & (m.tool == t)).sum() for m in motions)) for t in tools}
    figures = {"case": name, "n_points": int(captured["points"].shape[0]), "status": plan["status"],
               "plan_s": plan["plan_s"], "n_programs": len(motions),
               "n_moves": int(sum(m.n_moves for m in motions)), "feed_moves_by_tool": feed,
               "tools": {int(t): f"{s.kind} R{s.radius_mm:g} L{s.flute_length_mm:g}" for t, s in tools.items()}}
    return figures, motions, tools, np.asarray(captured["points"], dtype=np.float64)


def make_spin():
    """A trivial compute-bound ``prange`` loop, timed beside the kernels on the same thread counts: how
    much of a second core the shared machine gives at the time, to read the kernels' ratio against."""
    import numba

    @numba.njit(parallel=True, cache=False)
    def spin(n):
        out = np.empty(n)
        for i in numba.prange(n):
            s = 0.0
            for k in range(4000):
                s += np.sqrt(i + k + 0.5)
            out[i] = s
        return out

    spin(64)
    return spin


def _time(fn, *args) -> tuple[float, np.ndarray]:
    t0 = time.perf_counter()
    r = fn(*args)
    return time.perf_counter() - t0, r


def bench_case(name: str, args, reference) -> dict:
    import numba

    from planning.simulate.gouge import penetration_mm

    figures, motions, tools, points = plan_case(name, args.femur_points if name == "femur_like" else None)
    rng = np.random.default_rng(0)
    sub = points[np.sort(rng.choice(points.shape[0], min(args.ref_points, points.shape[0]), replace=False))]
    threads = [t for t in (1, 2) if t <= numba.config.NUMBA_NUM_THREADS]
    first_s, _ = _time(penetration_mm, sub[:10], motions, tools)          # compilation or cache load
    times: dict[str, list[float]] = {"reference_subset": []}
    spin = make_spin()
    for t in threads:
        times[f"kernel_subset_{t}t"], times[f"kernel_all_{t}t"], times[f"calibration_{t}t"] = [], [], []
    diff, n_cut_sub, n_cut_all, all_by_threads = 0.0, 0, 0, {}
    before = numba.get_num_threads()
    try:
        for rep in range(args.repeat):
            if rep < args.ref_repeat:
                s, ref = _time(reference, sub, motions, tools)
                times["reference_subset"].append(s)
            for t in (threads if rep % 2 == 0 else threads[::-1]):
                numba.set_num_threads(t)
                s, got = _time(penetration_mm, sub, motions, tools)
                times[f"kernel_subset_{t}t"].append(s)
                s, all_ = _time(penetration_mm, points, motions, tools)
                times[f"kernel_all_{t}t"].append(s)
                times[f"calibration_{t}t"].append(_time(spin, 20_000)[0])
                all_by_threads[t] = all_
            fin = np.isfinite(ref)
            if not np.array_equal(fin, np.isfinite(got)):
                raise SystemExit(f"{name}: the kernels reach other points than the reference")
            diff = max(diff, float(np.abs(ref[fin] - got[fin]).max(initial=0.0)))
            n_cut_sub, n_cut_all = int((got > 0).sum()), int((all_ > 0).sum())
    finally:
        numba.set_num_threads(before)
    med = {k: statistics.median(v) for k, v in times.items() if v}
    same_threads = all(np.array_equal(all_by_threads[threads[0]], a) for a in all_by_threads.values())
    rec = dict(figures, n_subset=int(sub.shape[0]), first_call_s=round(first_s, 3),
               median_s={k: round(v, 4) for k, v in med.items()}, runs_s={k: [round(x, 4) for x in v]
                                                                          for k, v in times.items()},
               max_abs_diff_mm=diff, n_cut_subset=n_cut_sub, n_cut_all=n_cut_all,
               thread_counts_agree=same_threads, loadavg_1min=round(os.getloadavg()[0], 2))
    return rec


def print_case(r: dict) -> None:
    m = r["median_s"]
    print(f"\n== {r['case']}: {r['n_points']} points, {r['n_programs']} programs, {r['n_moves']} moves "
          f"(feed by tool {r['feed_moves_by_tool']}; {r['tools']}), planned in {r['plan_s']} s")
    print(f"   first kernel call (compile or cache load): {r['first_call_s']} s;  load {r['loadavg_1min']}")
    ref = m["reference_subset"]
    for t in (1, 2):
        if f"kernel_subset_{t}t" in m:
            k = m[f"kernel_subset_{t}t"]
            print(f"   subset {r['n_subset']} pts: reference {ref:8.3f} s | kernel {t} thread(s) {k:8.4f} s "
                  f"| before/after {ref / k:7.1f}x")
    if "kernel_subset_2t" in m:
        print(f"   subset 1 thread / 2 threads: {m['kernel_subset_1t'] / m['kernel_subset_2t']:.2f}x")
    for t in (1, 2):
        if f"kernel_all_{t}t" in m:
            print(f"   all {r['n_points']} pts: kernel {t} thread(s) {m[f'kernel_all_{t}t']:8.4f} s")
    if "kernel_all_2t" in m:
        print(f"   all 1 thread / 2 threads: {m['kernel_all_1t'] / m['kernel_all_2t']:.2f}x")
    if "calibration_2t" in m:
        print(f"   calibration, a trivial prange loop timed beside them: 1 thread {m['calibration_1t']:.3f} s, "
              f"2 threads {m['calibration_2t']:.3f} s: {m['calibration_1t'] / m['calibration_2t']:.2f}x "
              f"(what the shared machine gave a second thread meanwhile)")
    print(f"   largest |kernel - reference| on the subset: {r['max_abs_diff_mm']:.3g} mm; points cut: "
          f"{r['n_cut_subset']} of the subset, {r['n_cut_all']} of all; 1 and 2 threads identical: "
          f"{r['thread_counts_agree']}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["half_sphere", "femur_like"], choices=["half_sphere", "femur_like"])
    ap.add_argument("--femur-points", type=int, default=100_000)
    ap.add_argument("--ref-points", type=int, default=600, help="points of the subset the reference measures")
    ap.add_argument("--repeat", type=int, default=3, help="runs of the kernels (medians)")
    ap.add_argument("--ref-repeat", type=int, default=2, help="runs of the reference (at most --repeat)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    import numba

    reference = _module(ROOT / "tests" / "test_simulate_gouge.py", "test_simulate_gouge").reference_penetration_mm
    print(f"cores {os.cpu_count()}, NUMBA_NUM_THREADS {numba.config.NUMBA_NUM_THREADS}, "
          f"load {os.getloadavg()[0]:.2f}")
    recs = []
    for name in args.cases:
        rec = bench_case(name, args, reference)
        recs.append(rec)
        print_case(rec)
        sys.stdout.flush()
    if args.json:
        args.json.write_text(json.dumps(recs, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
