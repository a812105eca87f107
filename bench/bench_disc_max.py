"""Benchmark: the disc maximum of the roughing's maps (``planning.toolpath.roughing.maps._disc_max``), the
kernel the roughing calls once or twice per level (the femur-like plan: 851 calls). Prints figures only.

A random map (``--shape``, default 600 x 500 cells, 70 % of the cells holding a height) at a reach of
``--reach-cells`` cells (default 17: the slab's ``Rt + h`` with ``h = Rt / 16``), the milliseconds per
call (best of ``--repeat`` after a warm-up call) at ``NUMBA_NUM_THREADS`` as set; with ``--before REV``
the same for the module of git revision REV (its ``maps.py`` loaded apart), and whether both give the
same map bit for bit:

    for T in 1 2; do NUMBA_NUM_THREADS=$T .venv/bin/python bench/bench_disc_max.py --before 3e7a356; done
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def _maps_of(rev: str):
    """``planning/toolpath/roughing/maps.py`` of git revision ``rev``, loaded as a module of its own."""
    src = subprocess.run(["git", "show", f"{rev}:planning/toolpath/roughing/maps.py"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    path = os.path.join(tempfile.mkdtemp(), f"maps_{rev}.py")
    with open(path, "w") as fh:
        fh.write(src)
    spec = importlib.util.spec_from_file_location(f"maps_{rev}", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod                   # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def time_ms(fn, v, h, reach, repeat):
    fn(v, h, reach)
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn(v, h, reach)
        best = min(best, time.perf_counter() - t)
    return 1000.0 * best


def main() -> int:
    import numba

    from planning.toolpath.roughing.maps import _disc_max

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shape", type=int, nargs=2, default=[600, 500])
    ap.add_argument("--reach-cells", type=float, default=17.0)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--before", metavar="REV")
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    v = np.where(rng.random(a.shape) < 0.7, rng.normal(size=a.shape), -np.inf)
    h = 0.3125
    reach = a.reach_cells * h
    print(f"{a.shape[0]} x {a.shape[1]} cells, reach {a.reach_cells:g} cells, {numba.get_num_threads()} numba "
          f"thread(s), load average {os.getloadavg()[0]:.2f}")
    now = time_ms(_disc_max, v, h, reach, a.repeat)
    print(f"  this checkout: {now:.2f} ms per call")
    if a.before:
        old = _maps_of(a.before)._disc_max
        then = time_ms(old, v, h, reach, a.repeat)
        same = np.array_equal(old(v, h, reach), _disc_max(v, h, reach))
        print(f"  {a.before}: {then:.2f} ms per call; the same map: {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
