"""Scaling of the whole plan with the number of points (issue 17 item 5).  Prints figures only.

The femur-like reference shape is sampled at several sizes (default 0.25, 0.5, 1, 2 and 4 million
points) and planned with the ``make run`` configuration (``scripts/demo_service.py`` CONFIGS
"femur_like": sphere 7 mm, tool 6 mm, cone [10, 60] deg, travel and collisions checked, the part on
a 150 mm riser, 85 % coverage, up to 5 set-ups), paths and verification on, then written to a
temporary folder.  Each size runs in a fresh process (``--one N``), so each peak memory is that
size's own; the kernels come from the numba cache (run ``scanmill warmup`` or any plan first).

Per size and stage it prints the seconds and the peak resident memory while the stage ran (RSS of
the process and its children, the finishing worker included, sampled every 20 ms by a thread);
then, between consecutive sizes, each stage's growth exponent ``log(t2/t1) / log(n2/n1)`` (1.0 is
linear; n log n reads about 1.05-1.1 over a doubling at these
sizes). A stage whose exponent exceeds ``--flag-exponent`` (default 1.25) is marked ``*``. It also
prints, per size, the longest wait between two progress reports of the same stage (issue 17 item 3:
every stage reports at least every 2 s of work).

    .venv/bin/python bench/bench_scaling.py                              # 0.25 .. 4 M points
    .venv/bin/python bench/bench_scaling.py --sizes 250000 500000 --plot /tmp/scaling.png
    .venv/bin/python bench/bench_scaling.py --plot docs/images/scaling.png --json /tmp/scaling.json

Stage seconds come from ``plan.json`` ``timings`` (the pipeline's own clock); ``write`` is
:func:`planning.report.plan_files.write_plan`.  The load average is printed with the figures.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

SIZES = (250_000, 500_000, 1_000_000, 2_000_000, 4_000_000)


def _config() -> dict:
    """The ``make run`` femur configuration (one source: scripts/demo_service.py)."""
    sys.path.insert(0, os.path.join(ROOT, "scripts"))
    from demo_service import CONFIGS  # noqa: E402

    return json.loads(json.dumps(CONFIGS["femur_like"]))


class _RssSampler:
    """Peak RSS (MB) per stage: a thread samples /proc/self/statm, and that of this process's
    children (the finishing worker, planning/toolpath/finishing_worker.py), every ``interval_s``:
    the sum, the memory the plan holds on the machine."""

    def __init__(self, interval_s: float = 0.02):
        self.stage = "read"
        self.peak: dict[str, float] = {}
        self._stop = threading.Event()
        self._page = os.sysconf("SC_PAGE_SIZE")
        self._t = threading.Thread(target=self._loop, args=(interval_s,), daemon=True)

    def rss_mb(self) -> float:
        pids = ["self"]
        try:
            for task in os.listdir("/proc/self/task"):
                with open(f"/proc/self/task/{task}/children") as fh:
                    pids += fh.read().split()
        except OSError:
            pass
        pages = 0
        for pid in pids:
            try:
                with open(f"/proc/{pid}/statm") as fh:
                    pages += int(fh.read().split()[1])
            except (OSError, ValueError, IndexError):
                pass             # a child that has just gone
        return pages * self._page / 2**20

    def _loop(self, interval_s):
        while not self._stop.is_set():
            self.mark()
            time.sleep(interval_s)

    def mark(self):
        r = self.rss_mb()
        if r > self.peak.get(self.stage, 0.0):
            self.peak[self.stage] = r

    def start(self):
        self._t.start()
        return self

    def stop(self):
        self._stop.set()
        self._t.join()


def plan_and_write(cloud, cfg, name: str, sampler: _RssSampler, progress):
    """``run_plan`` with ``progress`` (which marks the sampler's stages), then ``write_plan`` into a
    temporary folder as the stage ``write``; the sampler stopped. Returns ``(outcome, seconds per stage
    from plan.json timings plus "write", plan s, write s)``."""
    from planning.pipeline import run_plan
    from planning.report.plan_files import write_plan

    t0 = time.perf_counter()
    out = run_plan(cloud, cfg, name=name, progress=progress)
    t_plan = time.perf_counter() - t0
    sampler.mark()
    sampler.stage = "write"
    with tempfile.TemporaryDirectory() as d:
        t1 = time.perf_counter()
        write_plan(out, d)
        t_write = time.perf_counter() - t1
    sampler.stop()
    seconds = {t.stage: float(t.seconds) for t in out.result.timings}
    seconds["write"] = t_write
    return out, seconds, t_plan, t_write


def run_one(n_points: int) -> dict:
    """Plan the femur-like shape sampled at ``n_points`` in this process; return its figures."""
    from planning.inputs import Cloud
    from planning.inputs.samples import make_sample
    from schemas.params import parse_config

    s = make_sample("femur_like", n_points=n_points)
    cfg = parse_config(_config())
    sampler = _RssSampler()
    base = sampler.rss_mb()
    sampler.start()

    last = {"t": None, "stage": None}
    silence: dict[str, tuple[float, str]] = {}     # per stage: the longest wait between two reports

    def progress(stage, fraction, message):
        now = time.perf_counter()
        if last["t"] is not None and last["stage"] == stage:
            gap = now - last["t"]
            if gap > silence.get(stage, (0.0, ""))[0]:
                silence[stage] = (gap, str(message)[:120])
        last["t"], last["stage"] = now, stage
        if stage != sampler.stage:
            sampler.mark()
            sampler.stage = stage

    out, seconds, t_plan, t_write = plan_and_write(Cloud(points=s.points, normals=None, source_format="generated"),
                                                   cfg, "femur_like", sampler, progress)
    r = out.result
    return {"n_points": n_points, "n_sampled": int(r.normals.n_sampled), "k": int(r.selection.k),
            "status": r.status, "verdict": None if r.verification is None else r.verification.status,
            "seconds": seconds, "plan_s": t_plan, "total_s": t_plan + t_write,
            "peak_rss_mb": sampler.peak, "base_rss_mb": base, "overall_peak_mb": max(sampler.peak.values()),
            "longest_silence_s": {k: [round(v[0], 3), v[1]] for k, v in silence.items()}}


def _table(rows: list[dict], flag: float) -> str:
    stages = [s for s in ("normals", "orientations", "visibility", "setups", "areas", "paths", "post",
                          "simulate", "write") if any(s in r["seconds"] for r in rows)]
    head = "| stage | " + " | ".join(f"{r['n_points'] / 1e6:g} M s (MB)" for r in rows) + " | exponents |"
    lines = [head, "|" + "---|" * (len(rows) + 2)]
    for st in stages:
        cells = []
        for r in rows:
            sec = r["seconds"].get(st)
            mb = r["peak_rss_mb"].get(st)
            cells.append("-" if sec is None else f"{sec:.2f} ({mb:.0f})" if mb else f"{sec:.2f}")
        exps = []
        for a, b in zip(rows[:-1], rows[1:]):
            ta, tb = a["seconds"].get(st), b["seconds"].get(st)
            if ta and tb and ta > 0.05:
                e = math.log(tb / ta) / math.log(b["n_points"] / a["n_points"])
                exps.append(f"{e:.2f}{'*' if e > flag else ''}")
            else:
                exps.append("-")
        lines.append(f"| {st} | " + " | ".join(cells) + " | " + " ".join(exps) + " |")
    lines.append("| total | " + " | ".join(f"{r['total_s']:.2f} ({r['overall_peak_mb']:.0f})" for r in rows)
                 + " | |")
    lines.append("| longest wait between two progress reports, s (stage) | "
                 + " | ".join("{:.2f} ({})".format(*max(((v[0], k) for k, v in r["longest_silence_s"].items()),
                                                        default=(0.0, "-"))) for r in rows) + " | |")
    lines.append("| sampled points / set-ups / verdict | "
                 + " | ".join(f"{r['n_sampled']:,} / {r['k']} / {r['verdict']}" for r in rows) + " | |")
    return "\n".join(lines)


def _plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stages = [s for s in ("normals", "visibility", "setups", "areas", "paths", "post", "simulate", "write")
              if any(r["seconds"].get(s, 0) > 0 for r in rows)]
    n = [r["n_points"] / 1e6 for r in rows]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 4.5), gridspec_kw={"width_ratios": [1.6, 1.0]})
    for st in stages:
        ax.plot(n, [max(r["seconds"].get(st, 0.0), 1e-3) for r in rows], marker="o", label=st)
    ax.plot(n, [r["total_s"] for r in rows], marker="s", color="k", lw=2, label="total")
    ref = rows[0]["total_s"]
    ax.plot(n, [ref * x / n[0] for x in n], ls=":", color="grey", label="linear (from the first total)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    for a in (ax, ax2):
        a.set_xscale("log")
        a.set_xticks(n, [f"{x:g}" for x in n])
        a.minorticks_off()
    ax.set_xlabel("points (millions)")
    ax.set_ylabel("seconds")
    ax.set_title("femur-like plan: seconds per stage")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(True, which="both", alpha=0.3)
    ax2.plot(n, [r["overall_peak_mb"] for r in rows], marker="o", color="C3")
    ax2.set_xlabel("points (millions)")
    ax2.set_ylabel("peak RSS (MB)")
    ax2.set_title("peak memory of the whole plan")
    ax2.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), help="point counts")
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)   # the child process
    ap.add_argument("--plot", default=None, help="write the plot (PNG) here")
    ap.add_argument("--json", default=None, help="write the raw figures (JSON) here")
    ap.add_argument("--flag-exponent", type=float, default=1.25)
    ap.add_argument("--replot", default=None, help="print the table and plot from a --json file; plan nothing")
    args = ap.parse_args()
    if args.one is not None:
        print("RESULT " + json.dumps(run_one(args.one)), flush=True)
        return 0
    rows = []
    if args.replot:
        with open(args.replot) as fh:
            rows = json.load(fh)
        args.sizes = []
    for n in args.sizes:
        load = os.getloadavg()[0]
        t = time.perf_counter()
        proc = subprocess.run([sys.executable, os.path.abspath(__file__), "--one", str(n)],
                              capture_output=True, text=True, cwd=ROOT)
        line = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
        if proc.returncode != 0 or not line:
            print(f"{n} points: the child failed (exit {proc.returncode})\n{proc.stderr[-3000:]}", file=sys.stderr)
            return 1
        row = json.loads(line[0][len("RESULT "):])
        row["load_before"] = load
        rows.append(row)
        print(f"{n:>9,} points: plan {row['plan_s']:.1f} s, write {row['seconds']['write']:.1f} s, "
              f"peak {row['overall_peak_mb']:.0f} MB, process {time.perf_counter() - t:.1f} s, "
              f"load before {load:.2f}", flush=True)
    print()
    print(_table(rows, args.flag_exponent))
    print(f"\nload average after: {os.getloadavg()[0]:.2f} (1 min); cores: {os.cpu_count()}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    if args.plot:
        _plot(rows, args.plot)
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
