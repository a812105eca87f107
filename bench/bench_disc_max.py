"""Benchmark: the disc maximum of the roughing's maps (``planning.toolpath.roughing.maps._disc_max``), the
kernel the roughing calls once or twice per level (the femur-like plan: 851 calls). Prints figures only.

A random map (``--shape``, default 600 x 500 cells, 70 % of the cells holding a height) at a reach of
``--reach-cells`` cells (default 17: the slab's ``Rt + h`` with ``h = Rt / 16``), the milliseconds per
call (best of ``--repeat`` after a warm-up call) at ``NUMBA_NUM_THREADS`` as set; with ``--before REV``
the same for the module of git revision REV (its ``maps.py`` loaded apart), and whether both give the
same map bit for bit:

    for T in 1 2; do NUMBA_NUM_THREADS=$T .venv/bin/python bench/bench_disc_max.py --before 3e7a356; done

Then the two kernels that replaced numpy or float work on the same raster (issue 30, speed): the slab's cells
within reach of material (a boolean map of blobs covering ``--mask-share`` of the cells), by ``_disc_any``
against the disc maximum of +-inf it replaced, and the material map's coarse cells (``_coarse_max``, 2 x 2
cells) against the padded reshape's maximum it replaced; milliseconds per call and whether each gives the
same map:

    .venv/bin/python bench/bench_disc_max.py --shape 1300 650
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
    ap.add_argument("--mask-share", type=float, default=0.3)
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
    _replaced(rng, a, h, reach)
    return 0


def _replaced(rng, a, h, reach) -> None:
    """The slab's mask dilation and the coarse maximum, each against the expression it replaced."""
    from scipy import ndimage

    from planning.toolpath.roughing.maps import _coarse_max, _disc_any, _disc_max

    f = ndimage.gaussian_filter(rng.normal(size=a.shape), 4.0)
    mask = f > np.quantile(f, 1.0 - a.mask_share)

    def old_any(m, h_, r_):
        return _disc_max(np.where(m, 1.0, -np.inf), h_, r_) > 0.0

    t_old, t_new = time_ms(old_any, mask, h, reach, a.repeat), time_ms(_disc_any, mask, h, reach, a.repeat)
    same = np.array_equal(old_any(mask, h, reach), _disc_any(mask, h, reach))
    print(f"  cells within reach of a mask ({a.mask_share:.0%} of the cells): disc maximum of +-inf {t_old:.2f} ms, "
          f"_disc_any {t_new:.2f} ms; the same map: {same}")
    v = np.where(rng.random(a.shape) < 0.7, rng.normal(size=a.shape), -np.inf)

    def old_coarse(x, k=2):
        nx, ny = x.shape
        ncx, ncy = -(-nx // k), -(-ny // k)
        pad = np.full((ncx * k, ncy * k), -np.inf)
        pad[:nx, :ny] = x
        return pad.reshape(ncx, k, ncy, k).max(axis=(1, 3))

    t_old = time_ms(lambda x, *_: old_coarse(x), v, h, reach, a.repeat)
    t_new = time_ms(lambda x, *_: _coarse_max(x), v, h, reach, a.repeat)
    print(f"  coarse maximum over 2 x 2 cells: padded reshape {t_old:.2f} ms, _coarse_max {t_new:.2f} ms; the same "
          f"map: {np.array_equal(old_coarse(v), _coarse_max(v))}")


if __name__ == "__main__":
    raise SystemExit(main())
