"""Benchmark of the tri-dexel material removal (issue 15, :mod:`planning.simulate.dexel`).

Synthetic (default), on a femur-sized stock box (406 x 115 x 78 mm: the femur-like sample's
396.1 x 104.9 x 67.5 mm plus 5 mm around), each case at 0.25, 0.5 and 1.0 mm ray spacing on a
fresh stock, run as feed moves by ``simulate_moves`` (cut + shank/holder check):

* roughing-like: a flat end mill R 5 mm (flutes 30 mm, then a shank and an unbounded R 16 mm
  holder), tool axis along Z, zig-zag levels 2 mm apart from the stock's top down over its whole
  extent, stepover 6 mm, passes cut into moves of ``--rough-step`` mm (default 5 mm);
* finishing-like: a ball end mill R 3 mm, tool axis tilted 20 deg from Z, dense short moves (``--fin-step`` mm,
  default 0.3 mm) rastering a wavy surface 0.3 mm apart, on the stock roughing leaves (the
  surface + 0.7 mm, built from a closed mesh).

``--femur``: the real thing. Plans the femur-like reference scan (1M points, max 5 set-ups, tool
6 mm, roughing on; ``simulate.enabled`` off, about 80 s), takes every area's roughing and finishing
tool path to the part frame (tool tip, arcs as 0.5 mm chords, rapids kept) and runs them all in
set-up order on the box stock (part box + 2 mm) with the plan's tools (ball R 3, flutes 12, shank
to 30, holder R 12.5 to 75 then R 25; roughing flat R 5 fluted to 30, same holder): rapids check
the whole tool, feeds cut and check shank and holder.

Reported: moves/s, rays evaluated/s (rays whose exact interval was computed), mm of cut per s,
the model's memory and the process's peak RSS; deviation of 1M points. Kernels compiled (and
cached) before timing.

    .venv/bin/python bench/bench_dexel.py [--res 0.25 0.5 1.0] [--rough-m 30] [--fin-m 3] [--femur]
"""

from __future__ import annotations

import argparse
import math
import resource
import time

import numba
import numpy as np

from planning.simulate.dexel import TriDexel, cut, signed_deviation, simulate_moves
from planning.simulate.motion import FEED, RAPID, ToolShape

LO = np.array([-203.0, -57.5, -5.0])
HI = np.array([203.0, 57.5, 73.0])


def _tilt(deg: float) -> np.ndarray:
    """Rotation about Y by deg: the program frame's Z to the part frame."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _polyline_moves(pts: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """A polyline cut into moves of at most ``step`` mm: (start (P,3), end (P,3))."""
    out = [pts[:1]]
    for a, b in zip(pts[:-1], pts[1:]):
        k = max(1, int(math.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + (b - a) * (np.arange(1, k + 1) / k)[:, None])
    p = np.concatenate(out)
    return p[:-1].copy(), p[1:].copy()


def _program_box(rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stock box's extent in the program frame (rotated about the box centre)."""
    corners = np.array([[x, y, z] for x in (LO[0], HI[0]) for y in (LO[1], HI[1]) for z in (LO[2], HI[2])])
    q = (corners - (LO + HI) / 2) @ rot
    return q.min(0), q.max(0)


def roughing_program(length_m: float, step: float, tilt_deg: float = 0.0):
    """Zig-zag levels 2 mm apart from the stock's top down (program frame, tilted into the part
    frame) over the stock's extent in the program frame until ``length_m`` of cut."""
    rot = _tilt(tilt_deg)
    centre = (LO + HI) / 2
    qlo, qhi = _program_box(rot)
    pts = []
    total = 0.0
    z = qhi[2] - 2.0
    while total < length_m * 1000 and z > qlo[2]:
        ys = np.arange(qlo[1] + 3.0, qhi[1] - 3.0, 6.0)
        for k, y in enumerate(ys):
            xs = (qlo[0] + 4.0, qhi[0] - 4.0) if k % 2 == 0 else (qhi[0] - 4.0, qlo[0] + 4.0)
            pts += [(xs[0], y, z), (xs[1], y, z)]
            total += abs(xs[1] - xs[0]) + 6.0
            if total >= length_m * 1000:
                break
        z -= 2.0
    p = np.array(pts) @ rot.T + centre
    s, e = _polyline_moves(p, step)
    return s, e, np.tile(rot[:, 2], (s.shape[0], 1))


def _surface(x, y):
    return 3.0 * np.sin(x / 17.0) * np.cos(y / 11.0)


def heightfield_solid(xs, ys, top, bottom: float):
    """A closed triangle mesh: the height field ``top`` (nx, ny) over the grid xs x ys above the
    plane z = ``bottom``, closed by its four walls."""
    nx, ny = len(xs), len(ys)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    vt = np.stack([X, Y, top], -1).reshape(-1, 3)
    vb = np.stack([X, Y, np.full_like(top, bottom)], -1).reshape(-1, 3)
    V = np.concatenate([vt, vb])
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    top_f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    bot_f = top_f[:, ::-1] + nx * ny
    ring = np.concatenate([idx[:, 0], idx[-1, 1:], idx[-2::-1, -1], idx[0, -2:0:-1]])
    r2 = np.roll(ring, -1)
    walls = np.concatenate([np.stack([ring, ring + nx * ny, r2], 1), np.stack([r2, ring + nx * ny, r2 + nx * ny], 1)])
    F = np.concatenate([top_f, bot_f, walls])
    return V, F


def finishing_stock(res: float, tilt_deg: float = 20.0, allowance: float = 0.7) -> TriDexel:
    """The stock left by roughing for :func:`finishing_program`: the wavy surface + ``allowance``
    over the finishing region (program frame, tilted into the part frame) down to 30 mm below."""
    rot = _tilt(tilt_deg)
    xs = np.arange(-160.0, 160.01, 0.5)
    ys = np.arange(-50.0, 50.01, 0.5)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    V, F = heightfield_solid(xs, ys, 25.0 + _surface(X, Y) + allowance, -5.0)
    V = V @ rot.T + (LO + HI) / 2
    return TriDexel.from_mesh(V, F, res, domain_lo=LO - res, domain_hi=HI + res)


def finishing_program(length_m: float, step: float, tilt_deg: float = 20.0):
    """Raster of a wavy surface 0.3 mm apart in short moves until ``length_m`` of cut."""
    rot = _tilt(tilt_deg)
    centre = (LO + HI) / 2
    rows = []
    total = 0.0
    y = -40.0
    x = np.arange(-150.0, 150.0, step)
    while total < length_m * 1000:
        xx = x if len(rows) % 2 == 0 else x[::-1]
        z = 25.0 + _surface(xx, y)
        rows.append(np.stack([xx, np.full_like(xx, y), z], 1))
        total += 300.0
        y += 0.3
    p = np.concatenate(rows) @ rot.T + centre
    s, e = p[:-1], p[1:]
    return s, e, np.tile(rot[:, 2], (s.shape[0], 1))


FLAT = ToolShape(number=2, kind="flat", radius_mm=5.0, corner_radius_mm=0.0, flute_length_mm=30.0,
                 pieces=((30.0, 45.0, 5.0), (45.0, math.inf, 16.0)))
BALL = ToolShape(number=1, kind="ball", radius_mm=3.0, corner_radius_mm=3.0, flute_length_mm=15.0,
                 pieces=((15.0, 40.0, 3.0), (40.0, math.inf, 16.0)))


def run_case(name, shape, prog, res):
    s, e, a = prog
    if name == "finishing":
        stock = finishing_stock(res)
    else:
        stock = TriDexel.box(LO, HI, res, domain_lo=LO - res, domain_hi=HI + res)
    t0 = time.perf_counter()
    run = simulate_moves(stock, s, e, a, shape, np.full(s.shape[0], FEED))
    dt = time.perf_counter() - t0
    length = float(np.linalg.norm(e - s, axis=1).sum())
    return dict(case=name, res=res, moves=s.shape[0], length_mm=length, seconds=dt,
                visits=run.ray_visits, removed=float(run.removed_mm3.sum()), model_mb=stock.nbytes / 2**20,
                stock=stock)


def _femur_moves():
    """The femur-like plan's tool paths as part-frame moves: {name: (start, end, axis, kind)}."""
    from planning.inputs import Cloud
    from planning.inputs.samples import femur_like
    from planning.pipeline import run_plan
    from planning.toolpath.moves import RAPID as TP_RAPID
    from planning.toolpath.moves import densify
    from schemas.params import parse_config

    sample = femur_like()
    cfg = parse_config({"setups": {"max_setups": 5, "coverage": 0.95}, "tool": {"diameter_mm": 6.0},
                        "simulate": {"enabled": False}})
    t0 = time.perf_counter()
    out = run_plan(Cloud(points=sample.points, normals=None, source_format="generated"), cfg, name="femur_like")
    print(f"femur plan: {time.perf_counter() - t0:.0f} s, {len(out.extra['area_paths'])} areas")
    progs = {}
    for ap in out.extra["area_paths"]:
        for op in ("roughing", "finishing"):
            tp = getattr(ap, op)
            if tp is None:
                continue
            pts, mv = densify(tp, 0.5)
            part = ap.frame.to_part(pts - np.array([0.0, 0.0, tp.tip_offset_mm]))
            kind = np.where(tp.kind[mv][1:] == TP_RAPID, RAPID, FEED)
            progs[f"area {ap.area} {op}"] = (part[:-1], part[1:], np.tile(ap.frame.rotation[2], (len(part) - 1, 1)),
                                             kind)
    return progs, sample.points.min(0) - 2.0, sample.points.max(0) + 2.0


def femur(resolutions) -> None:
    progs, lo, hi = _femur_moves()
    holder = ((30.0, 75.0, 12.5), (75.0, math.inf, 25.0))
    ball = ToolShape(1, "ball", 3.0, 3.0, 12.0, ((12.0, 30.0, 3.0),) + holder)
    flat = ToolShape(2, "flat", 5.0, 0.0, 30.0, holder)
    n = sum(len(p[0]) for p in progs.values())
    feed = sum(float(np.linalg.norm(p[1] - p[0], axis=1)[p[3] == FEED].sum()) for p in progs.values())
    rapid = sum(float(np.linalg.norm(p[1] - p[0], axis=1)[p[3] == RAPID].sum()) for p in progs.values())
    print(f"{n} moves, {feed / 1000:.0f} m feed, {rapid / 1000:.0f} m rapid")
    print("| res mm | program | moves | s | moves/s | rays/s | holder hits | rapid hits |")
    print("|---|---|---|---|---|---|---|---|")
    for res in resolutions:
        stock = TriDexel.box(lo, hi, res)
        total = 0.0
        for name, (s, e, a, k) in progs.items():
            t0 = time.perf_counter()
            run = simulate_moves(stock, s, e, a, flat if "roughing" in name else ball, k)
            dt = time.perf_counter() - t0
            total += dt
            print(f"| {res} | {name} | {len(s)} | {dt:.2f} | {len(s) / dt:,.0f} | {run.ray_visits / dt:,.0f} | "
                  f"{int((run.holder_depth_mm > 0).sum())} | {int((run.rapid_depth_mm > 0).sum())} |")
        print(f"| {res} | **all** | {n} | **{total:.1f}** | {n / total:,.0f} | | | |")
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"model {stock.nbytes / 2**20:.0f} MiB, peak RSS {rss:.0f} MiB (with the plan)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=float, nargs="+", default=[0.25, 0.5, 1.0])
    ap.add_argument("--rough-m", type=float, default=30.0, help="metres of roughing cut")
    ap.add_argument("--fin-m", type=float, default=3.0, help="metres of finishing cut")
    ap.add_argument("--rough-step", type=float, default=5.0)
    ap.add_argument("--fin-step", type=float, default=0.3)
    ap.add_argument("--femur", action="store_true", help="plan the femur-like scan and simulate its programs")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    if args.threads:
        numba.set_num_threads(args.threads)
    print(f"threads {numba.get_num_threads()}")
    # compile once on a tiny case
    tiny = TriDexel.box([0, 0, 0], [10, 10, 10], 1.0)
    simulate_moves(tiny, [[0, 5, 9]], [[10, 5, 9]], [[0, 0, 1]], BALL, [FEED])
    cut(tiny, [[0, 5, 9]], [[10, 5, 9]], [[0, 0, 1]], FLAT)
    signed_deviation(tiny, np.zeros((1, 3)), np.array([[0, 0, 1.0]]))
    if args.femur:
        femur(args.res)
        return
    progs = {"roughing": (FLAT, roughing_program(args.rough_m, args.rough_step)),
             "finishing": (BALL, finishing_program(args.fin_m, args.fin_step))}
    print("| case | res mm | moves | cut m | s | moves/s | rays/s | cut mm/s | model MiB |")
    print("|---|---|---|---|---|---|---|---|---|")
    for res in args.res:
        for name, (shape, prog) in progs.items():
            r = run_case(name, shape, prog, res)
            print(f"| {name} | {res} | {r['moves']} | {r['length_mm'] / 1000:.1f} | {r['seconds']:.2f} | "
                  f"{r['moves'] / r['seconds']:,.0f} | {r['visits'] / r['seconds']:,.0f} | "
                  f"{r['length_mm'] / r['seconds']:,.0f} | {r['model_mb']:.1f} |")
        stock = r["stock"]
        rng = np.random.default_rng(0)
        pts = rng.uniform(LO, HI, (1_000_000, 3))
        nrm = rng.normal(size=(1_000_000, 3))
        t0 = time.perf_counter()
        signed_deviation(stock, pts, nrm, max_mm=5.0)
        print(f"| deviation, 1M points | {res} | | | {time.perf_counter() - t0:.2f} | | | | |")
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
