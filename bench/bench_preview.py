"""Time of the PNG preview (planning/report/preview.py) on a large cloud, against another version of the
module in the same process (issue 20: every input point is drawn, by numpy rasterisation).

The cloud: ``--points`` random points on a sphere of radius 100 mm, 5 areas by longitude, 2 % integrated,
three tool axes. ``--against REV`` loads preview.py as it was at git revision REV (default b7a22ca, before
issue 20) into a temporary module and times it on the same cloud, with its own default sample cap (its
60,000 samples) and, with ``--all-points``, on every point as well.

    python bench/bench_preview.py --points 1000000 --repeat 3 --all-points
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planning.report import preview as current


def _module_at(rev: str):
    src = subprocess.run(["git", "show", f"{rev}:planning/report/preview.py"], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout
    path = Path(tempfile.mkdtemp(prefix="bench-preview-")) / f"preview_{rev}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(f"preview_{rev}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _cloud(n: int):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(n, 3))
    pts = 100.0 * v / np.linalg.norm(v, axis=1, keepdims=True)
    lon = np.arctan2(pts[:, 1], pts[:, 0])
    labels = np.minimum(((lon + np.pi) / (2 * np.pi) * 5).astype(np.int64), 4)
    labels[rng.random(n) < 0.01] = -1
    integrated = rng.random(n) < 0.02
    axes = np.array([[0, 0, 1.0], [1.0, 0, 0.2], [-0.5, 0.8, 0.3], [0, -1.0, 0.1], [0.3, 0.3, -1.0]])
    return pts, labels, axes, integrated


def _best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=3, help="best of N")
    ap.add_argument("--against", default="b7a22ca", help="git revision of the other preview.py")
    ap.add_argument("--all-points", action="store_true", help="also time the other version on every point (once)")
    args = ap.parse_args(argv)
    pts, labels, axes, integ = _cloud(args.points)
    out = Path(tempfile.mkdtemp(prefix="bench-preview-"))
    old = _module_at(args.against)
    angles = [{"B": 10.0 * i, "C": -30.0 * i} for i in range(axes.shape[0])]
    rows = []
    t = _best(lambda: old.render_preview(out / "old.png", pts, labels, axes, integrated=integ), args.repeat)
    rows.append((f"{args.against}, its default sample cap", t))
    if args.all_points:
        t = _best(lambda: old.render_preview(out / "old_all.png", pts, labels, axes, integrated=integ,
                                             max_points=args.points), 1)
        rows.append((f"{args.against}, every point (once)", t))
    t = _best(lambda: current.render_preview(out / "new.png", pts, labels, axes, integrated=integ, angles=angles),
              args.repeat)
    rows.append(("this tree, every point", t))
    print(f"render_preview on {args.points:,} sphere points, best of {args.repeat}:")
    for name, sec in rows:
        print(f"  {sec:8.2f} s  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
