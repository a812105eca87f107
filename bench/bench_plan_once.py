"""One whole plan of one reference sample, for timing from outside (``farm-bench``). Prints one line.

Plans the sample ``CASE`` of ``--points`` points with ``run_plan`` (``femur_like`` with the ``make run``
configuration of ``scripts/demo_service.py``; any other sample with the README's own-scan settings,
``setups.coverage=0.9`` and ``setups.max_setups=5``, plus ``--set`` overrides), writes the plan into a
temporary folder and prints::

    RESULT <case> plan_s=<run_plan seconds> paths_s=<paths stage> status=<...> verdict=<...> nc=<hash>
           cpu_s=<this process's CPU seconds in run_plan> worker_cpu_s=<its child processes' (the finishing worker)>
           main_cpu_s=<the CPU seconds of the thread that called run_plan, in it>

``cpu_s`` and ``worker_cpu_s`` (user + system, the operating system's accounting) say how much work
the plan was: on two cores it cannot take less wall time than their sum over two, nor less than
``main_cpu_s``, what its own thread computed. ``nc`` is the first 16
hex digits of the SHA-256 of every posted program (``*.nc``, by name): two code trees that plan the
same programs print the same hash, so a speed change can be timed and shown not to change the plan in
the same runs. ``--threads-cpu`` adds each live thread's CPU seconds since the process started.
``--root DIR`` plans with the code of another checkout (e.g. a ``git
worktree`` of the commit before), so a before/after pair runs from one command line. A fresh worktree
compiles every numba kernel of the planner in its first plan (about two minutes: numba's cache knows a
source file by its path), so plan once with it before timing it:

    git worktree add /tmp/before HEAD~1
    .venv/bin/python bench/bench_plan_once.py range_femur --root /tmp/before    # compiles its kernels
    farm-bench -n 4 --timeout 900 \\
      --vs "sh -c 'exec .venv/bin/python bench/bench_plan_once.py range_femur --root /tmp/before >>/tmp/B.txt'" \\
      -- sh -c 'exec .venv/bin/python bench/bench_plan_once.py range_femur >>/tmp/A.txt'

and one core against two (the child processes inherit the cores ``taskset`` gives):

    farm-bench -n 5 --timeout 1200 \\
      --vs "sh -c 'NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 exec taskset -c 0 .venv/bin/python bench/bench_plan_once.py range_femur'" \\
      -- sh -c 'NUMBA_NUM_THREADS=2 OMP_NUM_THREADS=2 exec taskset -c 0,1 .venv/bin/python bench/bench_plan_once.py range_femur'
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(HERE, "bench"))

from bench_range_scan import OVERRIDES  # noqa: E402  (the README's own-scan settings)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", help="sample name (planning.inputs.samples.SAMPLES)")
    ap.add_argument("--points", type=int, default=None,
                    help="points asked of the sample (default: 1,000,000 for femur_like, else 40,000)")
    ap.add_argument("--root", default=HERE, help="the checkout whose code plans (default: this one)")
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="more overrides (as scanmill plan --set)")
    ap.add_argument("--threads-cpu", action="store_true",
                    help="after the RESULT line, the CPU seconds of each thread of this process still alive "
                         "(Linux /proc; the plan's own thread, the kernels' pool threads, OpenMP's)")
    args = ap.parse_args()
    root = os.path.abspath(args.root)
    sys.path.insert(0, os.path.join(root, "scripts"))
    sys.path.insert(0, root)
    from planning.inputs import Cloud
    from planning.inputs.samples import make_sample
    from planning.pipeline import run_plan
    from planning.report.plan_files import write_plan
    from schemas.params import apply_overrides, parse_config

    if args.case == "femur_like":
        from demo_service import CONFIGS

        cfg = parse_config(apply_overrides(json.loads(json.dumps(CONFIGS["femur_like"])), args.set))
        n = args.points or 1_000_000
    else:
        cfg = parse_config(apply_overrides({}, [*OVERRIDES, *args.set]))
        n = args.points or 40_000
    sample = make_sample(args.case, n_points=n)
    c0 = resource.getrusage(resource.RUSAGE_SELF)
    k0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    m0 = time.thread_time()
    t0 = time.perf_counter()
    out = run_plan(Cloud(points=sample.points, normals=None, source_format="generated"), cfg, name=args.case)
    plan_s = time.perf_counter() - t0
    main_cpu_s = time.thread_time() - m0
    c1 = resource.getrusage(resource.RUSAGE_SELF)
    k1 = resource.getrusage(resource.RUSAGE_CHILDREN)       # the worker is waited for when the paths end
    cpu_s = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    worker_cpu_s = (k1.ru_utime - k0.ru_utime) + (k1.ru_stime - k0.ru_stime)
    digest = hashlib.sha256()
    with tempfile.TemporaryDirectory() as d:
        write_plan(out, d)
        for name in sorted(os.listdir(d)):
            if name.endswith(".nc"):
                with open(os.path.join(d, name), "rb") as fh:
                    digest.update(name.encode() + b"\0" + fh.read())
    r = out.result
    paths = [t.seconds for t in r.timings if t.stage == "paths"]
    verdict = r.verification.status if r.verification is not None else None
    print(f"RESULT {args.case} plan_s={plan_s:.2f} paths_s={paths[0] if paths else 0.0:.2f} status={r.status} "
          f"verdict={verdict} nc={digest.hexdigest()[:16]} cpu_s={cpu_s:.1f} worker_cpu_s={worker_cpu_s:.1f} "
          f"main_cpu_s={main_cpu_s:.1f}", flush=True)
    if args.threads_cpu:
        print_thread_cpu()
    return 0


def print_thread_cpu() -> None:
    """One line per live thread of this process: its CPU seconds since it started (user + system,
    /proc/self/task; the plan's own thread's include the imports and the sample before the plan), its
    Python name where Python started it ("-": a thread of a native library, e.g. OpenMP's); then the
    live threads' sum against the whole process's (the rest: threads that have ended)."""
    import threading

    tick = os.sysconf("SC_CLK_TCK")
    names = {t.native_id: t.name for t in threading.enumerate()}
    rows = []
    for tid in os.listdir("/proc/self/task"):
        with open(f"/proc/self/task/{tid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        rows.append(((int(fields[11]) + int(fields[12])) / tick, names.get(int(tid), "-")))
    rows.sort(reverse=True)
    for sec, name in rows:
        if sec >= 0.05:
            print(f"THREAD cpu_s={sec:.1f} name={name}")
    u = resource.getrusage(resource.RUSAGE_SELF)
    print(f"THREADS live_cpu_s={sum(r[0] for r in rows):.1f} process_cpu_s={u.ru_utime + u.ru_stime:.1f}",
          flush=True)


if __name__ == "__main__":
    sys.exit(main())
