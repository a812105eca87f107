"""Benchmark: a case's roughing alone, every set-up's call replayed on the stock it met (issue 30, speed).
Prints figures only.

The case (``bench/bench_stock_first.py``'s cases) is planned once without verification, every set-up's
roughing call captured (``bench_roughing_air.capture_all``); then the calls are planned again, in
machining order, each on a copy of the stock view it met, ``--rounds`` times (the first compiles nothing
the plan did not: the kernels come from the numba cache). Printed: per round each call's seconds and
moves, and the round's total:

    NUMBA_NUM_THREADS=2 .venv/bin/python bench/bench_roughing_replay.py femur_like

Where that time goes, by a sampling profiler (py-spy, not a dependency: ``pip install py-spy``), then
``--shares`` reads its raw output and prints, over the samples inside ``roughing_paths``, the functions'
inclusive shares and the deepest ``planning/`` line of each sample (a kernel shows as the line that
calls it):

    .venv/bin/py-spy record -r 100 -f raw -o /tmp/rough.raw -- .venv/bin/python bench/bench_roughing_replay.py femur_like
    .venv/bin/python bench/bench_roughing_replay.py --shares /tmp/rough.raw

``--within _paths`` counts the samples of a whole plan's paths stage instead (any plan's py-spy raw
file, e.g. of ``bench/bench_plan_once.py``).

``--questions``: over the last round, how many questions the roughing asked its stock view of each kind
and the seconds they took (:class:`planning.toolpath.roughing.levels._LiveStock`: the view brought up
to date with the moves written since the last question (``sync``, counted in the question that asked
it, and on its own), the questions themselves, and the per-level reading ``advance``), timed where
they are asked: what a rewrite asking a level's questions together would have to take over:

    NUMBA_NUM_THREADS=2 .venv/bin/python bench/bench_roughing_replay.py femur_like --questions
"""

from __future__ import annotations

import argparse
import collections
import re
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "bench"))

_FRAME = re.compile(r"(.*) \((.*):(\d+)\)")


def shares(raw: Path, top: int = 25, within: str = "roughing_paths") -> None:
    """The inclusive share of each function and the share of each deepest planning line, over the
    py-spy raw samples (``stack count`` lines) whose stack holds the function ``within`` (default
    ``roughing_paths``; ``_paths``: the whole paths stage of a plan)."""
    incl: collections.Counter = collections.Counter()
    deepest: collections.Counter = collections.Counter()
    total = 0
    for line in raw.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        frames = stack.split(";")
        if not any(f.startswith(within + " (") for f in frames):
            continue
        total += int(n)
        parsed = [m.groups() for m in map(_FRAME.match, frames) if m]
        for key in {(name, path.split("/")[-1]) for name, path, _ in parsed}:
            incl[key] += int(n)
        inner = [(name, path.split("planning/")[-1], ln) for name, path, ln in parsed if "planning/" in path]
        if inner:
            deepest[inner[-1]] += int(n)
    if not total:
        raise SystemExit(f"{raw}: no sample inside {within}")
    print(f"{total} samples inside {within}")
    print("inclusive share, function, file")
    for (name, path), n in incl.most_common(top):
        print(f"{100 * n / total:5.1f} %  {name}  {path}")
    print("share of samples by the deepest planning line")
    for (name, path, ln), n in deepest.most_common(top):
        print(f"{100 * n / total:5.1f} %  {name}  {path}:{ln}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", nargs="?", default="femur_like", help="a bench_stock_first case")
    ap.add_argument("--rounds", type=int, default=2, help="replays of all the calls")
    ap.add_argument("--shares", type=Path, help="read a py-spy raw file instead (module docstring)")
    ap.add_argument("--within", default="roughing_paths",
                    help="with --shares: the function whose samples are counted (default roughing_paths)")
    ap.add_argument("--top", type=int, default=25, help="with --shares: lines of each list (default 25)")
    ap.add_argument("--questions", action="store_true",
                    help="count and time the questions to the stock view over the last round (docstring)")
    args = ap.parse_args()
    if args.shares is not None:
        shares(args.shares, top=args.top, within=args.within)
        return 0
    from bench_roughing_air import capture_all

    asked = _count_questions() if args.questions else None

    from planning.toolpath.roughing import roughing_paths
    from planning.toolpath.stock_view import StockView

    calls, _, _ = capture_all(args.case)
    for r in range(args.rounds):
        total = 0.0
        if asked is not None:
            asked.clear()
        for cloud_f, kw, (stock, frame, shape, obstacles) in calls:
            t = time.perf_counter()
            out = roughing_paths(cloud_f, stock_view=StockView(stock.copy(), frame, shape, obstacles=obstacles), **kw)
            dt = time.perf_counter() - t
            total += dt
            print(f"round {r + 1}: {dt:7.2f} s, {out.toolpath.n_moves} moves", flush=True)
        print(f"round {r + 1}: {len(calls)} roughing calls, {total:.2f} s", flush=True)
    if asked is not None:
        print(f"questions to the stock view in round {args.rounds} (of its {total:.2f} s):")
        for kind, (n, sec) in sorted(asked.items(), key=lambda kv: -kv[1][1]):
            print(f"  {kind:20s} {n:7d} calls {sec:7.2f} s  {1000 * sec / max(n, 1):6.2f} ms each")
    return 0


#: :class:`planning.toolpath.roughing.levels._LiveStock`'s questions: methods that return the closure a
#: level's writer calls (each call one question), and the methods timed as they are.
_QUESTIONS = ("column_clear", "material_rise", "meets", "column_clear_many", "column_is_clear", "rapid_clear")
_STEPS = ("sync", "advance")


def _count_questions() -> dict:
    """Wrap the live stock's questions (module docstring) to count them and sum their seconds into the
    returned dict, ``kind -> [calls, seconds]``, for the rest of the process."""
    import collections

    from planning.toolpath.roughing import levels

    asked: dict = collections.defaultdict(lambda: [0, 0.0])

    def timed(kind, fn):
        def run(*a, **k):
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                asked[kind][0] += 1
                asked[kind][1] += time.perf_counter() - t
        return run

    def question(kind, make):                  # the method returns the closure the writer calls
        return lambda self, *a, **k: timed(kind, make(self, *a, **k))

    for name in _QUESTIONS:
        setattr(levels._LiveStock, name, question(name, getattr(levels._LiveStock, name)))
    for name in _STEPS:
        setattr(levels._LiveStock, name, timed(name, getattr(levels._LiveStock, name)))
    return asked

if __name__ == "__main__":
    raise SystemExit(main())
