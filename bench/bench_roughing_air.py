"""Benchmark: where a roughing feeds through air (issue 30). Prints figures only.

The case (``bench/bench_stock_first.py``'s cases) is planned without finishing and verification; the
roughing of the set-up ``--setup`` (its place in the machining order, default the second) is planned
again on the same stock view with every point the roughing writes tagged by the planner line that wrote
it, and its moves are run on the stock it met (``simulate_moves``, the verification's kernels). Printed:
the feed length and the part of it that removed under 1e-6 mm^3 (in air) per writing line, then the
level pieces' air split into leading, trailing and inner runs and the inner runs by length:

    .venv/bin/python bench/bench_roughing_air.py --case slot --setup 1
"""

from __future__ import annotations

import argparse
import collections
import linecache
import os
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "bench"))


def capture_all(case: str, extra_sets=()):
    """Every roughing call of the case's plan (without verification, plus ``extra_sets`` overrides), in
    machining order: [(cloud in frame, keyword arguments, (stock, frame, shape, obstacles))], and the
    parsed configuration and the cloud's points."""
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
        cfg = parse_config(apply_overrides(doc, sets + ["simulate.enabled=false", *extra_sets]))
        run_plan(Cloud(points=pts, normals=nrm, source_format="generated", faces=faces), cfg, name=case)
    finally:
        AP.roughing_paths = orig
    return calls, cfg, pts


def tagged_run(call, tag_of):
    """One captured roughing call planned again on its stock view with every point tagged by the planner
    call that wrote it (``tag_of(frame, its source line)``), and its moves run on the stock it met
    (``simulate_moves``, rapid clearance 0.5 mm). Returns a namespace: ``result`` (the roughing), ``pm``
    (its part moves), ``run``, ``axis``, per part move ``L`` (length), ``feed``, ``air`` (removed under
    ``AIR_MM3``), ``tag`` and ``block`` (the writer call), and the call's ``stock`` and ``shape``; None
    when the roughing wrote no move."""
    from types import SimpleNamespace

    import planning.toolpath.roughing.links as LK
    from planning.simulate.dexel import simulate_moves
    from planning.simulate.motion import FEED
    from planning.simulate.verify import AIR_MM3
    from planning.toolpath.guard import part_moves
    from planning.toolpath.roughing import roughing_paths
    from planning.toolpath.stock_view import StockView

    cloud_f, kw, (stock, frame, shape, obstacles) = call
    tags, blocks, n_blocks = [], [], [0]
    add = LK._Writer.add

    def tagged(self, xyz, use):
        f = sys._getframe(1)
        n = np.asarray(xyz, dtype=np.float64).reshape(-1, 3).shape[0]
        tags.extend([tag_of(f, linecache.getline(f.f_code.co_filename, f.f_lineno).strip())] * n)
        blocks.extend([n_blocks[0]] * n)
        n_blocks[0] += 1
        return add(self, xyz, use)

    LK._Writer.add = tagged
    try:
        r = roughing_paths(cloud_f, stock_view=StockView(stock.copy(), frame, shape, obstacles=obstacles), **kw)
    finally:
        LK._Writer.add = add
    tp = r.toolpath
    if tp.n_moves == 0:
        return None
    tags = np.array(tags + ["(final retract)"] * (tp.n_moves - len(tags)))
    blocks = np.array(blocks + [-1] * (tp.n_moves - len(blocks)))
    pm = part_moves(tp, frame)
    axis = np.broadcast_to(pm.axis, pm.start.shape)
    run = simulate_moves(stock.copy(), pm.start, pm.end, axis, shape, pm.kind, rapid_clearance_mm=0.5)
    feed = pm.kind == FEED
    return SimpleNamespace(result=r, pm=pm, run=run, axis=axis, L=np.linalg.norm(pm.end - pm.start, axis=1),
                           feed=feed, air=feed & (run.removed_mm3 < AIR_MM3), tag=tags[pm.source],
                           block=blocks[pm.source], stock=stock, shape=shape)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="slot")
    ap.add_argument("--setup", type=int, default=1, help="the set-up's place in the machining order")
    a = ap.parse_args()
    calls, _, _ = capture_all(a.case, ["paths.finishing.enabled=false"])
    got = tagged_run(calls[a.setup], lambda f, line: f"{f.f_code.co_name}: {line}")
    L, feed, air, t, b = got.L, got.feed, got.air, got.tag, got.block
    print(f"{a.case}, set-up {a.setup} in the machining order: feed {L[feed].sum():.0f} mm, in air {L[air].sum():.0f} mm "
          f"({L[air].sum() / max(L[feed].sum(), 1e-9):.1%}); load average {os.getloadavg()[0]:.2f}")
    agg = collections.defaultdict(lambda: [0.0, 0.0, 0])
    for i in np.flatnonzero(feed):
        g = agg[t[i]]
        g[0] += L[i]
        g[1] += L[i] if air[i] else 0.0
        g[2] += 1
    for tag, (tot, ai, cnt) in sorted(agg.items(), key=lambda kv: -kv[1][1]):
        print(f"  air {ai:7.0f} mm of {tot:7.0f} mm in {cnt:6d} moves  {tag}")
    # the level pieces (the writer's line that writes a piece's own points): air at their ends and inside
    piece = np.array(["xy[1:]" in x and "_cut_level" in x for x in t])
    lead = trail = 0.0
    runs = []
    for blk in np.unique(b[piece & feed]):
        idx = np.flatnonzero((b == blk) & feed)
        ai, li = air[idx], L[idx]
        if ai.all():
            lead += li.sum()
            continue
        k0, k1 = int(np.argmax(~ai)), len(ai) - 1 - int(np.argmax(~ai[::-1]))
        lead, trail = lead + li[:k0].sum(), trail + li[k1 + 1:].sum()
        cur = 0.0
        for k in range(k0, k1 + 1):
            if ai[k]:
                cur += li[k]
            elif cur > 0:
                runs.append(cur)
                cur = 0.0
    runs = np.array(runs)
    print(f"  level pieces: air leading (or all) {lead:.0f} mm, trailing {trail:.0f} mm, inner {runs.sum():.0f} mm")
    for lo, hi in ((0, 1), (1, 2.5), (2.5, 5), (5, 10), (10, np.inf)):
        m = (runs >= lo) & (runs < hi)
        print(f"    inner runs of [{lo}, {hi}) mm: {m.sum()} runs, {runs[m].sum():.0f} mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
