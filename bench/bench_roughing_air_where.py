"""Benchmark: where and for what the roughing end mill feeds through air (issue 30). Figures only.

The case (``bench/bench_stock_first.py``'s cases) is planned without verification, every
set-up's roughing call captured (``bench_roughing_air.capture_all``), then each set-up's roughing is
planned again on its stock view with every point tagged by the planner function that wrote it, and its
moves run on the stock it met (``bench_roughing_air.tagged_run``: ``simulate_moves``, the
verification's kernels, rapid clearance 0.5 mm). A feed move is *in air* when it removed under ``AIR_MM3``. Per set-up (machining
order) the air feed length is broken down:

* by the move's ``use`` (cut, plunge/entry, retract; :mod:`planning.toolpath.moves`);
* by where the tool tip is (the move's midpoint, part frame, against the stock box of
  ``verify.stock_extent``): above the box's top, below its bottom, beside it (in its z range, outside
  its x, y), inside it;
* by why there is no material: the air moves are run again, alone, on the stock as it was before this
  set-up's roughing: ``this roughing`` when they remove material there (a level above or an earlier
  pass of the same roughing took it), ``before`` when they do not (an earlier set-up took it, or there
  never was stock: outside the box);
* by the writing function (``_cut_level`` pieces and links, ``enter``/``_lift`` entries, ``_retract``);
* by where x why and where x writer (e.g. what feeds below the stock's bottom, and which function wrote it);
* how much of it a rapid could run: the air moves run again as rapids among the others as they were (they
  removed nothing, so every move meets the same stock), the whole tool grown by the rapid clearance clear
  of the stock as it then is and of the obstacles (fixtures, riser, table): all of the air, and the part
  below the stock's bottom.

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

#: The rapid clearance the moves are run with (mm; ``bench_roughing_air.tagged_run``'s).
RAPID_CLEARANCE_MM = 0.5


def _writer(f, line: str) -> str:
    """The tag of a point: the planner function that wrote it; in ``_cut_level``, a line's or a
    contour's own points or a link."""
    what = f.f_code.co_name
    if what == "_cut_level":
        what += (": line" if f.f_locals["piece"].is_line else ": contour") if "xy[1:]" in line else ": link"
    return what


def breakdown(call, box_lo, box_hi):
    """The air breakdown of one captured roughing call (module docstring): a dict of figures."""
    from bench_roughing_air import tagged_run

    from planning.simulate.dexel import simulate_moves
    from planning.simulate.verify import AIR_MM3

    got = tagged_run(call, _writer)
    if got is None:
        return None
    r, pm, run, axis, L, feed, air = got.result, got.pm, got.run, got.axis, got.L, got.feed, got.air
    tp, stock, shape = r.toolpath, got.stock, got.shape
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
    tag = got.tag
    # could a rapid run them? The air moves as rapids, every other move as it was (the air moves removed
    # nothing, so the stock each move meets is the same): the whole tool grown by the rapid clearance clear of
    # the stock as it then is, and of the obstacles
    from planning.simulate.dexel import collide
    from planning.simulate.motion import RAPID

    as_rapid = np.zeros(len(L), bool)
    if ia.size:
        kind = pm.kind.copy()
        kind[ia] = RAPID
        rr = simulate_moves(stock.copy(), pm.start, pm.end, axis, shape, kind, rapid_clearance_mm=RAPID_CLEARANCE_MM)
        as_rapid[ia] = rr.rapid_depth_mm[ia] <= 0.0
        obstacles = call[2][3]
        if obstacles is not None and as_rapid.any():
            ir = np.flatnonzero(as_rapid)
            as_rapid[ir] = collide(obstacles, pm.start[ir], pm.end[ir], axis[ir], shape, which="tool",
                                   grow_mm=RAPID_CLEARANCE_MM) <= 0.0
    out = {"feed": float(L[feed].sum()), "air": float(L[air].sum()), "n_levels": int(r.n_levels),
           "as_rapid": float(L[as_rapid].sum()), "as_rapid_below": float(L[as_rapid & (where == "below bottom")].sum()),
           "air_below": float(L[air & (where == "below bottom")].sum()),
           "removed_cm3": float(run.removed_mm3.sum()) / 1000.0, "left": (int(r.n_pieces_left), float(r.left_length_mm)),
           "levels": (float(r.levels_mm[0]), float(r.levels_mm[-1])) if r.n_levels else None}
    for name, key in (("use", use), ("where", where), ("why", why), ("writer", tag),
                      ("where x why", np.char.add(np.char.add(where, " / "), why)),
                      ("where x writer", np.char.add(np.char.add(where, " / "), tag)),
                      ("writer x why", np.char.add(np.char.add(tag, " / "), why))):
        agg = collections.defaultdict(lambda: [0.0, 0.0])
        for i in np.flatnonzero(feed):
            agg[key[i]][0] += L[i]
            if air[i]:
                agg[key[i]][1] += L[i]
        out[name] = dict(sorted(agg.items(), key=lambda kv: -kv[1][1]))
    # the level pieces' air: at their ends (or all of the piece) and inside, by the piece's kind
    blk = got.block
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
    from bench_roughing_air import capture_all
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
            print(f"  a rapid could run (whole tool {RAPID_CLEARANCE_MM} mm clear of the stock as it then is and of "
                  f"the obstacles): {b['as_rapid']:.0f} mm of the {b['air']:.0f} mm in air; below the stock's bottom "
                  f"{b['as_rapid_below']:.0f} mm of {b['air_below']:.0f} mm")
            for name in ("use", "where", "why", "where x why", "where x writer", "writer", "writer x why"):
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
