"""Benchmark: where and for what the roughing end mill feeds through air (issue 30). Figures only.

The case (``bench/bench_stock_first.py``'s cases) is planned without verification, every
set-up's roughing call captured (``bench_roughing_air.capture``'s spy, all set-ups at once), then each
set-up's roughing is planned again on its stock view with every point tagged by the planner function
that wrote it, and its moves run on the stock it met (``simulate_moves``, the verification's kernels,
rapid clearance 0.5 mm). A feed move is *in air* when it removed under ``AIR_MM3``. Per set-up (machining
order) the air feed length is broken down:

* by the move's ``use`` (cut, plunge/entry, retract; :mod:`planning.toolpath.moves`);
* by where the tool tip is (the move's midpoint, part frame, against the stock box of
  ``verify.stock_extent``): above the box's top, below its bottom, beside it (in its z range, outside
  its x, y), inside it;
* by why there is no material: the air moves are run again, alone, on the stock as it was before this
  set-up's roughing: ``this roughing`` when they remove material there (a level above or an earlier
  pass of the same roughing took it), ``before`` when they do not (an earlier set-up took it, or there
  never was stock: outside the box);
* by the writing function (``_cut_level`` pieces and links, ``enter``/``_lift`` entries, ``_retract``).

    .venv/bin/python bench/bench_roughing_air_where.py --cases slot post_wall filleted_box
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "bench"))

USE_NAMES = {0: "rapid", 1: "cut", 2: "plunge/entry", 3: "retract"}


def capture_all(case: str):
    """Every roughing call of the case's plan, in machining order: [(cloud in frame, keyword arguments,
    (stock, frame, shape, obstacles))], and the parsed configuration and cloud points."""
    from bench_stock_first import case_input

    import planning.toolpath.area_paths as AP
    from planning.inputs import Cloud
    from planning.pipeline import run_plan
    from schemas.params import apply_overrides, parse_config

    calls = []
    orig = AP.roughing_paths

    def spy(cloud_f, **kw):
        v = kw["stock_view"]
        calls.append((cloud_f.copy(), {k: x for k, x in kw.items() if k not in ("progress", "stock_view")},
                      (v.stock.copy(), v.frame, v.shape, v.obstacles)))
        return orig(cloud_f, **kw)

    AP.roughing_paths = spy
    try:
        pts, nrm, faces, doc, sets = case_input(case, HERE)
        cfg = parse_config(apply_overrides(doc, sets + ["simulate.enabled=false"]))
        run_plan(Cloud(points=pts, normals=nrm, source_format="generated", faces=faces), cfg, name=case)
    finally:
        AP.roughing_paths = orig
    return calls, cfg, pts


def breakdown(call, box_lo, box_hi):
    """The air breakdown of one captured roughing call (module docstring): a dict of figures."""
    import linecache

    import planning.toolpath.roughing.links as LK
    from planning.simulate.dexel import simulate_moves
    from planning.simulate.motion import FEED
    from planning.simulate.verify import AIR_MM3
    from planning.toolpath.guard import part_moves
    from planning.toolpath.roughing import roughing_paths
    from planning.toolpath.stock_view import StockView

    cloud_f, kw, (stock, frame, shape, obstacles) = call
    tags, blocks, blocks_n = [], [], []
    add = LK._Writer.add

    def tagged(self, xyz, use):
        f = sys._getframe(1)
        n = np.asarray(xyz, dtype=np.float64).reshape(-1, 3).shape[0]
        line = linecache.getline(f.f_code.co_filename, f.f_lineno).strip()
        what = f.f_code.co_name
        if what == "_cut_level":
            what += (": line" if f.f_locals["piece"].is_line else ": contour") if "xy[1:]" in line else ": link"
        blocks.extend([len(blocks_n)] * n)
        blocks_n.append(n)
        tags.extend([what] * n)
        return add(self, xyz, use)

    LK._Writer.add = tagged
    try:
        r = roughing_paths(cloud_f, stock_view=StockView(stock.copy(), frame, shape, obstacles=obstacles), **kw)
    finally:
        LK._Writer.add = add
    tp = r.toolpath
    if tp.n_moves == 0:
        return None
    tags = np.array(tags + ["_result: final retract"] * (tp.n_moves - len(tags)))
    blocks = np.array(blocks + [-1] * (tp.n_moves - len(blocks)))
    pm = part_moves(tp, frame)
    axis = np.broadcast_to(pm.axis, pm.start.shape)
    run = simulate_moves(stock.copy(), pm.start, pm.end, axis, shape, pm.kind, rapid_clearance_mm=0.5)
    L = np.linalg.norm(pm.end - pm.start, axis=1)
    feed = pm.kind == FEED
    air = feed & (run.removed_mm3 < AIR_MM3)
    # the air moves alone on the stock before this roughing: did it have material there?
    ia = np.flatnonzero(air)
    before = np.zeros(len(L), bool)
    if ia.size:
        rerun = simulate_moves(stock.copy(), pm.start[ia], pm.end[ia], axis[ia], shape, pm.kind[ia],
                               rapid_clearance_mm=0.5)
        before[ia] = rerun.removed_mm3 >= AIR_MM3
    mid = 0.5 * (pm.start + pm.end)
    inxy = np.all((mid[:, :2] >= box_lo[:2]) & (mid[:, :2] <= box_hi[:2]), axis=1)
    where = np.where(mid[:, 2] > box_hi[2], "above top",
                     np.where(mid[:, 2] < box_lo[2], "below bottom", np.where(inxy, "inside box", "beside box")))
    why = np.where(before, "this roughing", "before")
    use = np.array([USE_NAMES.get(int(u), str(u)) for u in tp.use[pm.source]])
    tag = tags[pm.source]
    out = {"feed": float(L[feed].sum()), "air": float(L[air].sum()), "n_levels": int(r.n_levels),
           "removed_cm3": float(run.removed_mm3.sum()) / 1000.0, "left": (int(r.n_pieces_left), float(r.left_length_mm)),
           "levels": (float(r.levels_mm[0]), float(r.levels_mm[-1])) if r.n_levels else None}
    for name, key in (("use", use), ("where", where), ("why", why), ("writer", tag),
                      ("where x why", np.char.add(np.char.add(where, " / "), why)),
                      ("writer x why", np.char.add(np.char.add(tag, " / "), why))):
        agg = collections.defaultdict(lambda: [0.0, 0.0])
        for i in np.flatnonzero(feed):
            agg[key[i]][0] += L[i]
            if air[i]:
                agg[key[i]][1] += L[i]
        out[name] = dict(sorted(agg.items(), key=lambda kv: -kv[1][1]))
    # the level pieces' air: at their ends (or all of the piece) and inside, by the piece's kind
    blk = blocks[pm.source]
    for kind in ("_cut_level: line", "_cut_level: contour"):
        lead = inner = 0.0
        for b_ in np.unique(blk[(tag == kind) & feed]):
            idx = np.flatnonzero((blk == b_) & feed)
            ai, li = air[idx], L[idx]
            if ai.all():
                lead += li.sum()
                continue
            k0, k1 = int(np.argmax(~ai)), len(ai) - 1 - int(np.argmax(~ai[::-1]))
            lead += li[:k0].sum() + li[k1 + 1:].sum()
            inner += li[k0:k1 + 1][ai[k0:k1 + 1]].sum()
        out["pieces " + kind.split(": ")[1]] = (lead, inner)
    return out


def main() -> int:
    from bench_stock_first import CASES

    from planning.simulate.verify import stock_extent

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["slot", "post_wall", "filleted_box"], choices=list(CASES))
    a = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    for case in a.cases:
        calls, cfg, pts = capture_all(case)
        lo, hi = stock_extent(np.asarray(pts, float), cfg.stock)
        for k, call in enumerate(calls):
            b = breakdown(call, lo, hi)
            if b is None:
                print(f"\n{case}, set-up {k}: no roughing")
                continue
            print(f"\n{case}, set-up {k} (machining order): feed {b['feed']:.0f} mm, in air {b['air']:.0f} mm "
                  f"({b['air'] / max(b['feed'], 1e-9):.1%}); removed {b['removed_cm3']:.2f} cm^3; pieces left {b['left']}; "
                  f"{b['n_levels']} levels {b['levels']}")
            for name in ("use", "where", "why", "where x why", "writer", "writer x why"):
                print(f"  by {name}:")
                for key, (tot, ai) in b[name].items():
                    if ai > 0.5 or tot > 0.5:
                        print(f"    {key:45s} air {ai:7.0f} mm of {tot:7.0f} mm ({ai / max(b['air'], 1e-9):5.1%} of the air)")
            for kind in ("line", "contour"):
                lead, inner = b["pieces " + kind]
                print(f"  {kind} pieces: air at their ends or all of the piece {lead:.0f} mm, inside {inner:.0f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
