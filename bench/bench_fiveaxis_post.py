"""The 5-axis posts on a real operation: the seconds of the guard's reading of the program as numbers
(``linuxcnc_5axis_motion``), of the LinuxCNC and of the ISO program, and a hash of each output (so that
a speed change can show it wrote the same programs). Prints figures only.

The operation is the first finishing operation of the range femur planned in 5axis from two pass
directions (``bench/bench_fiveaxis.py``'s settings), captured as the finishing guard first reads it
(then the plan stops), and pickled to ``--op`` (default ``/tmp/scanmill_fiveaxis_op.pkl``); with
``--root`` another checkout's posts are timed on the same pickle (capture with this checkout first):

    NUMBA_NUM_THREADS=2 .venv/bin/python bench/bench_fiveaxis_post.py
    .venv/bin/python bench/bench_fiveaxis_post.py --root /tmp/before        # the pickle from the line above
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


class _Stop(Exception):
    pass


def capture(path: Path) -> None:
    sys.path.insert(0, str(HERE / "bench"))
    from bench_fiveaxis import RANGE

    import planning.post.simultaneous as pm
    from planning.inputs import Cloud
    from planning.inputs.samples import make_sample
    from planning.pipeline import run_plan
    from schemas.params import parse_config

    motion = pm.linuxcnc_5axis_motion

    def spy(op, profile, placement, options=None, *a, **k):
        with open(path, "wb") as fh:
            pickle.dump((op, profile, placement, options), fh)
        raise _Stop

    pm.linuxcnc_5axis_motion = spy
    s = make_sample("range_femur", n_points=40_000)
    cfg = {**RANGE, "setups": {**RANGE["setups"], "max_setups": 2}, "paths": {"finishing": {"mode": "5axis"}}}
    try:
        run_plan(Cloud(points=s.points, normals=None, source_format="generated"), parse_config(cfg), name="post")
    except _Stop:
        pass
    finally:
        pm.linuxcnc_5axis_motion = motion


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--op", default="/tmp/scanmill_fiveaxis_op.pkl", help="the captured operation (pickle)")
    ap.add_argument("--root", default=None, help="time another checkout's posts on the captured operation")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each post; the fastest is printed (default 3)")
    args = ap.parse_args(argv)
    op_path = Path(args.op)
    sys.path.insert(0, str(Path(args.root).resolve() if args.root else HERE))
    if args.root is None and not op_path.exists():
        capture(op_path)
    import numpy as np

    import planning.post.simultaneous as post

    with open(op_path, "rb") as fh:
        op, profile, placement, options = pickle.load(fh)
    print(f"posts of {post.__file__}; operation: {op.centre_mm.shape[0]:,} planned moves")

    def best(fn):
        times, out = [], None
        for _ in range(max(1, args.repeat)):
            t = time.perf_counter()
            out = fn()
            times.append(time.perf_counter() - t)
        return min(times), out

    t, m = best(lambda: post.linuxcnc_5axis_motion(op, profile, placement, options))
    h = hashlib.sha256()
    for k in sorted(m):
        h.update(np.ascontiguousarray(m[k]).tobytes())
    print(f"linuxcnc_5axis_motion {t:6.2f} s  {h.hexdigest()[:16]}  ({m['pos_mm'].shape[0]:,} posted points)")
    for name, fn in (("linuxcnc program", post.linuxcnc_5axis_program), ("iso program", post.iso_5axis_program)):
        t, text = best(lambda fn=fn: fn(op, profile=profile, placement_mm=placement, options=options))
        print(f"{name:21} {t:6.2f} s  {hashlib.sha256(text.encode()).hexdigest()[:16]}  ({text.count(chr(10)):,} lines)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
