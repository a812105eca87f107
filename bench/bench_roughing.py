"""Z-level roughing benchmark (planning.toolpath.roughing): seconds per set-up axis of
``roughing_paths`` on the femur-like cloud, with the pipeline's arguments (as in
planning/toolpath/area_paths.py and the default ``paths.roughing`` parameters: flat end mill
Ø10, step down 2 mm, allowance 0.5 mm, margin 2 mm, zig-zag, contour pass).

The cloud is ``planning.inputs.samples.femur_like(--points)`` (1,000,000 by default, about 3 s to
generate); for each ``--axis`` the whole cloud is put in the area frame
(:func:`planning.toolpath.frames.area_frame`), the area being the points whose exact normal lies
within 60 deg of the axis (the tool cone's upper angle; a stand-in for the pipeline's labels). The
floor is the area's lowest point + the allowance, the safe height the cloud's top + margin + 5 mm.
Prints per axis: seconds, levels, moves, feed / air length, retracts and the reported minimal
clearance (which must be >= the allowance).

``--baseline PATH`` also times another version in the same run, alternating the two per axis, and
prints the ratio and whether the paths are identical. PATH is either one file, a roughing.py from
before the module became the package ``planning/toolpath/roughing/`` (for example
``git show <rev>:planning/toolpath/roughing.py > /tmp/roughing_orig.py``), imported as
``roughing_baseline``, or a copy of the package folder (for example
``git archive <rev> planning/toolpath/roughing | tar -x -C /tmp/base``, then
``--baseline /tmp/base/planning/toolpath/roughing``), imported from that folder as the package
``roughing_baseline``. numba caches the baseline's kernels beside its files, under those names (a
file once run under another module name needs its ``__pycache__`` cleared). The kernels of both
are compiled before timing. The default axes are two tilted set-ups and the femur plan's area-1
axis.

    .venv/bin/python bench/bench_roughing.py [--points 1000000] [--repeat 1]
        [--axis 0.433 -0.75 -0.5] [--axis 0.433 0.25 0.866] [--baseline /tmp/roughing_orig.py] [--profile]

Measured on the 2-core development machine (shared, noisy), ``--baseline`` = the module before the
speed-up, ``--repeat 2``: 1.14-1.50 s per axis against 6.8-9.3 s, 4.16 s against 23.07 s for the three
axes (5.5x); same levels and minimal clearance, feed within 1.3 %.
"""

from __future__ import annotations

import argparse
import cProfile
import importlib.abc
import importlib.util
import os
import pstats
import re
import shlex
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from planning.inputs.samples import femur_like
from planning.toolpath import roughing
from planning.toolpath.frames import area_frame

DEFAULT_AXES = [(0.433, -0.75, -0.5), (0.433, 0.25, 0.866), (-0.8138, -0.4698, 0.342)]


class _Renamed(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports a copy of the package folder as ``roughing_baseline``: its modules import each other
    as ``planning.toolpath.roughing.*``, names rewritten on import so that the copy (and the numba
    caches of its kernels, which record their module's name) stays apart from the current package."""

    def __init__(self, folder):
        self.folder = folder

    def find_spec(self, name, path=None, target=None):
        if name == "roughing_baseline":
            return importlib.util.spec_from_file_location(name, os.path.join(self.folder, "__init__.py"), loader=self,
                                                          submodule_search_locations=[self.folder])
        file = os.path.join(self.folder, *name.split(".")[1:]) + ".py"
        if name.startswith("roughing_baseline.") and os.path.isfile(file):
            return importlib.util.spec_from_file_location(name, file, loader=self)
        return None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        with open(module.__spec__.origin, encoding="utf-8") as fh:
            src = re.sub(r"\bplanning\.toolpath\.roughing\b", "roughing_baseline", fh.read())
        exec(compile(src, module.__spec__.origin, "exec"), module.__dict__)  # noqa: S102 (the copy's own source)


def _load(path):
    """The baseline module ``roughing_baseline``: one file, or a copy of the package folder (see the
    module docstring)."""
    if os.path.isdir(path):
        sys.meta_path.insert(0, _Renamed(os.path.abspath(path)))
        return importlib.import_module("roughing_baseline")
    spec = importlib.util.spec_from_file_location("roughing_baseline", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod             # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def _run(mod, cloud_f, floor, safe, args):
    t0 = time.perf_counter()
    rp = mod.roughing_paths(cloud_f, tool_radius_mm=args.diameter / 2.0, corner_radius_mm=args.corner,
                            step_down_mm=args.step_down, stock_allowance_mm=args.allowance,
                            stock_margin_mm=args.margin, stepover_mm=None, pattern=args.pattern,
                            floor_z_mm=floor, safe_z_mm=safe)
    return time.perf_counter() - t0, rp


def _line(tag, sec, rp):
    return (f"  {tag:<9} {sec:8.2f} s  levels {rp.n_levels:4d}  moves {rp.toolpath.n_moves:7d}  "
            f"feed {rp.length_mm / 1000:8.2f} m  air {rp.air_mm / 1000:7.2f} m  retracts {rp.n_retracts:5d}  "
            f"min clearance {rp.min_clearance_mm:.4f} mm  cell {rp.cell_mm:.4f} mm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--axis", type=float, nargs=3, action="append", help="set-up tool axis (part frame)")
    ap.add_argument("--diameter", type=float, default=10.0)
    ap.add_argument("--corner", type=float, default=0.0)
    ap.add_argument("--step-down", type=float, default=2.0)
    ap.add_argument("--allowance", type=float, default=0.5)
    ap.add_argument("--margin", type=float, default=2.0)
    ap.add_argument("--pattern", default="zigzag", choices=["zigzag", "oneway"])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--baseline", help="another roughing.py, or a copy of the package folder, to time in the "
                    "same run")
    ap.add_argument("--profile", action="store_true", help="cProfile the (first) run of the current module")
    args = ap.parse_args()
    axes = [tuple(a) for a in args.axis] if args.axis else DEFAULT_AXES

    print("command:", shlex.join([".venv/bin/python", "bench/bench_roughing.py"] + sys.argv[1:]))
    t0 = time.perf_counter()
    s = femur_like(args.points)
    print(f"cores {os.cpu_count()}; femur_like {s.points.shape[0]} points in {time.perf_counter() - t0:.1f} s; "
          f"tool Ø{args.diameter} rc {args.corner}, step down {args.step_down}, allowance {args.allowance}, "
          f"margin {args.margin}, {args.pattern}")
    base = _load(args.baseline) if args.baseline else None
    # compile / load the cached kernels on a small cloud
    small = femur_like(20_000).points
    for mod in ([roughing] + ([base] if base else [])):
        mod.roughing_paths(small - [0, 0, small[:, 2].max()], tool_radius_mm=args.diameter / 2.0)
    totals = {"current": 0.0, "baseline": 0.0}
    for axis in axes:
        t = np.asarray(axis, dtype=np.float64)
        t /= np.linalg.norm(t)
        area = s.points[s.normals @ t >= 0.5]
        frame = area_frame(t, s.points, area)
        cloud_f = frame.to_frame(s.points)
        area_f = frame.to_frame(area)
        floor = float(area_f[:, 2].min()) + args.allowance
        safe = float(cloud_f[:, 2].max()) + args.margin + 5.0
        print(f"axis ({t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}): {area.shape[0]} area points, floor {floor:.2f} mm")
        for rep in range(args.repeat):
            runs = [("current", roughing)] + ([("baseline", base)] if base else [])
            if rep % 2:
                runs = runs[::-1]
            res = {}
            for tag, mod in runs:
                if args.profile and tag == "current" and rep == 0:
                    pr = cProfile.Profile()
                    pr.enable()
                    res[tag] = _run(mod, cloud_f, floor, safe, args)
                    pr.disable()
                    pstats.Stats(pr).sort_stats("tottime").print_stats(25)
                else:
                    res[tag] = _run(mod, cloud_f, floor, safe, args)
                totals[tag] += res[tag][0]
            for tag, (sec, rp) in res.items():
                print(_line(tag, sec, rp))
            if base:
                a, b = res["current"][1], res["baseline"][1]
                same = (a.toolpath.n_moves == b.toolpath.n_moves
                        and np.array_equal(a.toolpath.xyz_mm, b.toolpath.xyz_mm))
                print(f"  speed-up {res['baseline'][0] / res['current'][0]:.2f}x; identical paths: {same}; "
                      f"feed length ratio {a.length_mm / b.length_mm:.4f}")
            assert res["current"][1].min_clearance_mm >= args.allowance - 1e-6
    print(f"total current {totals['current'] / args.repeat:.2f} s per repeat"
          + (f", baseline {totals['baseline'] / args.repeat:.2f} s, speed-up "
             f"{totals['baseline'] / totals['current']:.2f}x" if base else ""))


if __name__ == "__main__":
    main()
