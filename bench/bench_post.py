"""Post-processor benchmark (docs/design.md stage 8): moves per second of the ISO (G68.2), LinuxCNC and
neutral posts on a synthetic finishing-like tool path.

The path (area frame, ball centres, tip offset = ball radius 3 mm): zig-zag passes along X in
planes y = const over z = f(x, y), each pass alternating G1 lines and G18 (ZX-plane) arcs (about
half the moves are arcs), passes linked by a feed step-over, every tenth pass by a retract, a rapid
and a plunge instead. The area frame is tilted (tool axis ``--axis``) and the machine is a
table-table profile (``--profile``, default ``compact_trunnion_bc``), so that the LinuxCNC post
linearises the G18 arcs (their plane is off the machine's principal planes) while the ISO post
keeps them. ``neutral`` is ``json.dumps(neutral_moves(...))`` as ``planning.post.programs`` writes
the moves file, ``neutral_moves`` the dict alone, ``neutral_json`` the same text written directly
(where the module has it). The best of ``--repeat`` runs is reported.

    .venv/bin/python bench/bench_post.py [--moves 150000] [--repeat 3] [--axis 0.3 0.4 0.866]
                                         [--profile compact_trunnion_bc]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from planning.orientations.kinematics import machine_visibility
from planning.post import (
    Operation,
    PostOptions,
    iso_program,
    linuxcnc_program,
    neutral_moves,
)
from planning.toolpath.frames import area_frame
from planning.toolpath.moves import (
    ARC_CCW,
    ARC_CW,
    FEED,
    PLANE_ZX,
    RAPID,
    USE_CUT,
    USE_PLUNGE,
    USE_RAPID,
    USE_RETRACT,
    Toolpath,
)

try:
    from planning.post.neutral import neutral_json
except ImportError:                                 # the posts before neutral_json existed
    neutral_json = None


def finishing_like(n_moves: int, *, seed: int = 0, radius_mm: float = 3.0) -> Toolpath:
    """About ``n_moves`` moves of zig-zag finishing (see the module docstring), area frame, mm."""
    rng = np.random.default_rng(seed)
    step_x, step_y, half = 0.8, 0.6, 60.0
    per_pass = int(2 * half / step_x)
    n_pass = max(1, n_moves // (per_pass + 2))

    def surf(x, y):
        return -12.0 + 6.0 * np.sin(x / 17.0) * np.cos(y / 23.0) - 0.002 * x * x

    xyz, kind, cen, plane, use = [], [], [], [], []
    x = np.linspace(-half, half, per_pass + 1)
    for k in range(n_pass):
        y = -half + k * step_y
        xs = x if k % 2 == 0 else x[::-1]
        z = surf(xs, y) + rng.normal(scale=1e-3, size=xs.size)
        pts = np.c_[xs, np.full(xs.size, y), z]
        # link: retract / rapid / plunge every tenth pass, else a feed step-over
        if k == 0 or k % 10 == 0:
            if k:
                xyz.append(xyz[-1] + [0.0, 0.0, 5.0])
                kind.append(FEED), use.append(USE_RETRACT), plane.append(0), cen.append([np.nan] * 3)
            xyz.append(np.array([pts[0, 0], y, 2.0]))
            kind.append(RAPID), use.append(USE_RAPID), plane.append(0), cen.append([np.nan] * 3)
            xyz.append(pts[0])
            kind.append(FEED), use.append(USE_PLUNGE), plane.append(0), cen.append([np.nan] * 3)
        else:
            xyz.append(pts[0])
            kind.append(FEED), use.append(USE_CUT), plane.append(0), cen.append([np.nan] * 3)
        # the pass: odd segments are G18 arcs through the segment's end points
        for j in range(1, xs.size):
            s, e = pts[j - 1], pts[j]
            if j % 2:
                xyz.append(e)
                kind.append(FEED), use.append(USE_CUT), plane.append(0), cen.append([np.nan] * 3)
                continue
            r = rng.uniform(4.0, 40.0)
            mid = 0.5 * (s + e)
            dz, dx = e[2] - s[2], e[0] - s[0]
            half_chord = 0.5 * math.hypot(dz, dx)
            h = math.sqrt(max(r * r - half_chord * half_chord, 0.0))
            # unit normal of the chord in the (z, x) plane, pointing down (centre below the path)
            nz, nx = -dx / (2 * half_chord), dz / (2 * half_chord)
            if nz > 0:
                nz, nx = -nz, -nx
            c = mid.copy()
            c[2] += h * nz
            c[0] += h * nx
            u = (s[2] - c[2], s[0] - c[0])
            v = (e[2] - c[2], e[0] - c[0])
            ccw = u[0] * v[1] - u[1] * v[0] > 0
            xyz.append(e)
            kind.append(ARC_CCW if ccw else ARC_CW), use.append(USE_CUT), plane.append(PLANE_ZX), cen.append(c)
    return Toolpath(np.array(xyz, dtype=np.float64), np.array(kind, np.int8), np.array(cen, dtype=np.float64),
                    np.array(plane, np.int8), np.array(use, np.int8), float(radius_mm))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moves", type=int, default=150_000, help="moves of the synthetic path (about)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each post; the best is reported")
    ap.add_argument("--axis", type=float, nargs=3, default=(0.3, 0.4, 0.866), help="tool axis (part frame)")
    ap.add_argument("--profile", default="compact_trunnion_bc", help="machine profile (table-table or head-head)")
    args = ap.parse_args()
    root = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
    exe = os.path.relpath(sys.executable, root) if sys.executable.startswith(root + os.sep) else sys.executable
    print("command:", " ".join(shlex.quote(a) for a in [exe, *sys.argv]), f"(in {root})")

    tp = finishing_like(args.moves)
    axis = np.asarray(args.axis, dtype=np.float64)
    axis /= np.linalg.norm(axis)
    rng = np.random.default_rng(1)
    cloud = rng.normal(size=(2000, 3)) * [40.0, 40.0, 10.0]
    frame = area_frame(axis, cloud)
    mv = machine_visibility(axis, args.profile)
    if not mv.feasible[0]:
        raise SystemExit(f"tool axis {axis.tolist()} is out of reach on {args.profile}")
    angles = mv.angles_deg[0]
    op = Operation("finishing", tp, 2, 6.0, "ball", 12000, 1500.0, 400.0, gauge_length_mm=110.0)
    kw = {"tool_axis": axis, "rotary_deg": angles, "profile": args.profile, "placement_mm": [0.0, 0.0, 60.0],
          "setup_id": 0, "area_id": 0}
    n_arcs = int(np.isin(tp.kind, (ARC_CW, ARC_CCW)).sum())
    print(f"path: {tp.n_moves} moves, {n_arcs} G18 arcs ({100 * n_arcs / tp.n_moves:.0f} %), "
          f"{int((tp.kind == RAPID).sum())} rapids; tool axis {np.round(axis, 4).tolist()}, {args.profile} "
          f"angles {np.round(angles, 4).tolist()}; cores {os.cpu_count()}")

    posts = {
        "iso": lambda: iso_program([op], frame, options=PostOptions(), **kw),
        "linuxcnc": lambda: linuxcnc_program([op], frame, options=PostOptions(), **kw),
        "neutral": lambda: json.dumps(neutral_moves([op], frame, **kw), separators=(",", ":")),
        "neutral_moves": lambda: neutral_moves([op], frame, **kw),
    }
    if neutral_json is not None:
        posts["neutral_json"] = lambda: neutral_json([op], frame, **kw)
    print(f"{'post':<16} {'best s':>8} {'moves/s':>12} {'output':>10}")
    best = {}
    for name, fn in posts.items():
        best[name] = math.inf
        for _ in range(max(1, args.repeat)):
            out = None                                  # free the previous result outside the timing
            t0 = time.perf_counter()
            out = fn()
            best[name] = min(best[name], time.perf_counter() - t0)
        size = f"{len(out) / 1e6:.1f} MB" if isinstance(out, str) else "dict"
        print(f"{name:<16} {best[name]:8.3f} {tp.n_moves / best[name]:12,.0f} {size:>10}")
    for neutral in ("neutral", "neutral_json"):
        if neutral in best:
            total = best["iso"] + best["linuxcnc"] + best[neutral]
            print(f"{'iso+linuxcnc+' + neutral:<29} {total:8.3f} s")


if __name__ == "__main__":
    main()
