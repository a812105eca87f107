"""Areas on range scans (issue 32 item 2): are the areas striped along the scan lines?  Prints figures.

A real scanner writes scan lines (0.3 mm along, 0.6 mm across in
:func:`planning.inputs.samples.range_scan`). A neighbourhood graph that links points along a line and
barely across lines leaves the seam term of the labelling nothing to act on across lines, and the
areas come out striped. This bench plans each case with the tool paths, roughing and simulation off
(only the stages up to the areas run) and prints, per case:

* the plan's own figures (plan.json ``areas`` and ``setups[i].regions``, on the plan's own graph of
  the sampled points): label-change share, seam length, regions, and per area its points, regions,
  largest region's share of its points, ``min_regions`` (the regions the visibility alone forces) and
  the visible pieces;
* the seconds of the ``areas`` stage (the pipeline's own clock) and the graph's edges per point;
* the label-change share on one fixed reference neighbourhood, the same for every version of the
  code: every pair of sampled points closer than ``REF_RADIUS_FACTOR`` times the median distance
  to the 4th nearest sampled point (``cKDTree.query_pairs``; isotropic, so it sees changes across
  scan lines as well as along them), and the share of those pairs between two scan lines of one
  view that change label next to the share within a line (``across / along``, range scans only: a
  striped labelling changes mostly across lines).

Cases (``--cases``): ``range_femur`` and ``range_half_sphere`` (40,000 points, seed 0, no normals from
the file) planned like the README's own scan: every parameter at its default but
``fixtures.fixture_height_mm=100``; ``femur_like`` (the uniform sample,
``--uniform-points``, default 300,000) with scripts/demo_service.py's femur configuration (sphere
throwing 7 mm, tool 6 mm, riser 150 mm, cone [10, 60], global visibility and travel, coverage 0.85,
max 5 set-ups). ``--set`` adds overrides to every case.

``--png-dir DIR --tag NAME`` also writes ``DIR/areas_<shape>_<NAME>.png`` per case (``<shape>`` =
``range_femur``, ``range_half_sphere``, ``femur_like``): the input points coloured by area, seen
orthographically from two opposite sides (left and right half), nearest point on top, shaded by
the normal; with ``--bound`` also ``DIR/areas_<shape>_<NAME>_least.png``, an allowed labelling with
the fewest label changes on the plan graph (the LP's).

``--bound`` (issue 32 item 2) adds, per case: the least label-change share any labelling can reach
when every point keeps a set-up that sees it (:func:`planning.areas.bound.least_label_changes`, an
LP lower bound, exact when its solution is integral) on the plan graph and on the reference pairs;
the same with the forced specks under ``areas.min_region_mm2`` freed (what the visibility's speckle
costs); and per area the share of its points outside the largest of its regions within their piece
of the area's visible set (regions in different pieces are forced apart by the visibility; within
a piece the labelling chose the split), with what joining those regions by corridors would cost
(:func:`corridor_join`). ``--old-settings``: the range cases with cone [10, 60] and 4 set-ups (the
own-scan example before 47143a2, the settings of the first issue 32 figures). ``--cache DIR`` keeps the inputs of the areas stage per case (``DIR/<case>.npz``) and, when
they are there, runs only :func:`planning.areas.assign.assign_areas` on them (same visibility and
set-ups, for trying the areas code quickly; the seconds are then that call's).

    .venv/bin/python bench/bench_areas_range.py --json /tmp/areas_range_before.json \
        --png-dir docs/images --tag before
    (change the code)
    .venv/bin/python bench/bench_areas_range.py --json /tmp/areas_range_after.json --png-dir docs/images --tag after
    .venv/bin/python bench/bench_areas_range.py --compare /tmp/areas_range_before.json /tmp/areas_range_after.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

CASES = ("range_femur", "range_half_sphere", "femur_like")
#: the README's own-scan example ("Planning your own scan"): defaults on a 100 mm riser
RANGE_OVERRIDES = ("fixtures.fixture_height_mm=100",)
#: that example before commit 47143a2 (``--old-settings``; the issue 32 figures measured before it)
OLD_RANGE_OVERRIDES = ("visibility.cone_deg=[10,60]", "setups.max_setups=4")
#: scripts/demo_service.py CONFIGS["femur_like"]
UNIFORM_OVERRIDES = ('normals.method="sphere_throwing"', "normals.sphere_diameter_mm=7.0", "tool.diameter_mm=6.0",
                     "fixtures.fixture_height_mm=150.0", "visibility.cone_deg=[10,60]", "visibility.global=true",
                     "visibility.travel=true", "setups.coverage=0.85", "setups.max_setups=5")
#: only the stages up to the areas
OFF = ("paths.finishing.enabled=false", "paths.roughing.enabled=false", "simulate.enabled=false")
#: the reference neighbourhood: pairs closer than this times the median 8th-neighbour distance
REF_RADIUS_FACTOR = 1.5
#: a colour per area (RGB), then grey for unlabelled points
PALETTE = ((230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180), (70, 240, 240),
           (240, 50, 230), (210, 245, 60), (128, 128, 0), (0, 0, 128), (170, 110, 40), (255, 215, 180))


def reference_figures(sp: np.ndarray, labels: np.ndarray, line: np.ndarray | None, view: np.ndarray | None) -> dict:
    """Label-change share over all pairs of sampled points ``sp`` closer than the reference radius
    (module docstring); with the scan ``line`` / ``view`` of each sampled point, the shares within a
    line and between two lines of one view."""
    from scipy.spatial import cKDTree

    tree = cKDTree(sp)
    d8, _ = tree.query(sp, k=9, workers=-1)
    radius = REF_RADIUS_FACTOR * float(np.median(d8[:, 8]))
    pairs = tree.query_pairs(radius, output_type="ndarray")
    cut = labels[pairs[:, 0]] != labels[pairs[:, 1]]
    out = {"radius_mm": round(radius, 4), "pairs_per_point": round(2 * pairs.shape[0] / max(sp.shape[0], 1), 2),
           "share": float(cut.mean()) if cut.size else 0.0}
    if line is not None:
        same_view = view[pairs[:, 0]] == view[pairs[:, 1]]
        along = same_view & (line[pairs[:, 0]] == line[pairs[:, 1]])
        across = same_view & (line[pairs[:, 0]] != line[pairs[:, 1]])
        out["along_share"] = float(cut[along].mean()) if along.any() else 0.0
        out["across_share"] = float(cut[across].mean()) if across.any() else 0.0
    return out


def reference_pairs(sp: np.ndarray) -> np.ndarray:
    """The reference neighbourhood's pairs (module docstring)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(sp)
    d8, _ = tree.query(sp, k=9, workers=-1)
    return tree.query_pairs(REF_RADIUS_FACTOR * float(np.median(d8[:, 8])), output_type="ndarray")


def freed_allowed(graph, allowed: np.ndarray, min_region_mm2: float) -> np.ndarray:
    """``allowed`` (n,k) with every forced piece (connected points that only one chosen set-up
    sees, all the same one) smaller than ``min_region_mm2`` free to take any set-up: what the
    labelling could reach if those specks of visibility were noise (not an allowed labelling)."""
    from planning.areas.regions import components

    n, k = allowed.shape
    e = graph.edges
    out = allowed.copy()
    forced = allowed.sum(axis=1) == 1
    for j in range(k):
        fj = forced & allowed[:, j]
        comp, nc = components(n, e, fj[e[:, 0]] & fj[e[:, 1]])
        size = np.bincount(comp[fj], weights=graph.area_mm2[fj], minlength=nc)
        out[fj & (size[comp] < min_region_mm2)] = True
    return out


def corridor_join(graph, labels: np.ndarray, allowed: np.ndarray, j: int, rounds: int = 200):
    """``labels`` with area ``j``'s regions that share a piece of its visible set (``allowed[:, j]``)
    joined to that piece's largest region, each by the corridor of fewest points to relabel
    (Dijkstra over the points ``j`` may take, nearest region first): (labels, points relabelled).
    A figure of what one region per visible piece would cost, not a rule of the plan (a corridor
    one point wide is no better to machine than the seam it saves)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    from planning.areas.regions import components, label_regions

    lab = np.asarray(labels, np.int64).copy()
    n = lab.shape[0]
    e = graph.edges
    ok = allowed[e[:, 0], j] & allowed[e[:, 1], j]
    ee = e[ok]
    mcomp, mn = components(n, e, ok)
    added = 0
    for _ in range(rounds):
        comp, nc = label_regions(graph, lab)
        mine = lab == j
        size = np.bincount(comp[mine], minlength=nc)
        piece = np.full(nc, -1, np.int64)
        piece[comp[mine]] = mcomp[mine]
        regs = np.flatnonzero(size > 0)
        multi = np.flatnonzero(np.bincount(piece[regs], minlength=mn) > 1)
        if multi.size == 0:
            break
        rr = regs[piece[regs] == multi[0]]
        big = rr[np.argmax(size[rr])]
        enter = (lab != j).astype(np.float64) + 1e-6             # cost of a corridor's point
        m = coo_matrix((np.r_[enter[ee[:, 1]], enter[ee[:, 0]]], (np.r_[ee[:, 0], ee[:, 1]], np.r_[ee[:, 1], ee[:, 0]])),
                       shape=(n, n)).tocsr()
        d, pred, _ = dijkstra(m, indices=np.flatnonzero(comp == big), min_only=True, return_predecessors=True)
        targets = np.flatnonzero(np.isin(comp, rr) & (comp != big))
        v = int(targets[np.argmin(d[targets])])
        while v >= 0 and comp[v] != big:
            if lab[v] != j:
                lab[v] = j
                added += 1
            v = int(pred[v])
    return lab, added


def bound_figures(graph, pairs: np.ndarray, labels: np.ndarray, sub: np.ndarray, min_region_mm2: float) -> dict:
    """``--bound``: the least label-change share any labelling the visibility allows can reach
    (:func:`planning.areas.bound.least_label_changes`, on the plan graph and on the reference
    pairs), the same with the forced specks under ``min_region_mm2`` freed (:func:`freed_allowed`),
    and per area the points outside the largest of its regions within their piece of the set the
    area may cover (its set-up sees them, or none does): a split there is the labelling's, a split
    between pieces is forced by the visibility."""
    from planning.areas.bound import least_label_changes
    from planning.areas.regions import components, label_regions

    n, k = sub.shape
    allowed = sub | ~sub.any(axis=1)[:, None]
    out = {}
    for name, e, allow in (("plan", graph.edges, allowed), ("reference", pairs, allowed),
                           ("plan_freed", graph.edges, freed_allowed(graph, allowed, min_region_mm2))):
        t = time.perf_counter()
        b = least_label_changes(e, allow)
        if name == "plan":
            out["least_labels"] = b.labels                  # for the picture; not written to the JSON
        m = max(e.shape[0], 1)
        out[name] = {"bound_share": b.bound / m, "cut_share": b.cut / m, "fractional_points": b.fractional_points,
                     "freed_points": int((allow.sum(axis=1) > allowed.sum(axis=1)).sum()),
                     "lp_s": round(time.perf_counter() - t, 2)}
    comp, nc = label_regions(graph, labels)
    e = graph.edges
    unforced = []
    for j in range(k):
        mine = labels == j
        mcomp, mn = components(n, e, allowed[e[:, 0], j] & allowed[e[:, 1], j])
        best = np.zeros(mn, np.int64)                     # per piece, the size of its largest region
        rsize = np.bincount(comp[mine], minlength=nc)
        piece_of = np.full(nc, -1, np.int64)
        piece_of[comp[mine]] = mcomp[mine]
        has = rsize > 0
        np.maximum.at(best, piece_of[has], rsize[has])
        kept = int(best.sum())
        unforced.append((int(mine.sum()) - kept) / max(int(mine.sum()), 1))
    out["unforced_split_share"] = unforced
    joins = []
    for j in range(k):
        if unforced[j] == 0:
            joins.append(None)
            continue
        lab, added = corridor_join(graph, labels, allowed, j)
        c2, n2 = label_regions(graph, lab)
        sizes = np.bincount(c2[lab == j])
        sizes = sizes[sizes > 0]
        joins.append({"corridor_points": added, "share": float((lab[e[:, 0]] != lab[e[:, 1]]).mean()),
                      "regions_all": int(n2), "regions": int(sizes.size),
                      "largest_region_share": float(sizes.max() / sizes.sum())})
    out["corridors"] = joins
    return out


def picture(path: str, points: np.ndarray, normals: np.ndarray | None, labels: np.ndarray, width: int = 900) -> int:
    """The points coloured by area, orthographic along the least-extent axis of the bounding box from
    both sides (side by side, or one above the other for a long part; the second mirrored), nearest
    on top, shaded by the normal; returns the file's bytes."""
    from PIL import Image

    lo, hi = points.min(axis=0), points.max(axis=0)
    ext = hi - lo
    order = np.argsort(ext)                       # view along the smallest extent
    depth_ax, v_ax, u_ax = order[0], order[1], order[2]
    stacked = ext[u_ax] > 2.0 * ext[v_ax]
    pad = 6
    panel_w = width if stacked else width // 2
    scale = (panel_w - 2 * pad) / max(ext[u_ax], 1e-9)
    panel_h = int(ext[v_ax] * scale) + 2 * pad
    height = 2 * panel_h if stacked else panel_h
    canvas = np.full((height, width, 3), 255, np.uint8)
    lut = np.array([(160, 160, 160)] + [PALETTE[i % len(PALETTE)] for i in range(int(labels.max(initial=0)) + 1)],
                   np.float64)
    base = lut[labels + 1]                                     # grey: no area
    for side, sign in enumerate((1.0, -1.0)):
        u = ((points[:, u_ax] - lo[u_ax]) if sign > 0 else (hi[u_ax] - points[:, u_ax])) * scale
        v = (hi[v_ax] - points[:, v_ax]) * scale
        ox, oy = (0, side * panel_h) if stacked else (side * panel_w, 0)
        px = np.clip((u + pad + ox).astype(np.int64), 0, width - 2)
        py = np.clip((v + pad + oy).astype(np.int64), 0, height - 2)
        col = base
        if normals is not None:
            light = np.zeros(3)
            light[depth_ax], light[v_ax], light[u_ax] = sign * 1.0, 0.4, 0.3 * sign
            light /= np.linalg.norm(light)
            col = base * (0.4 + 0.6 * np.clip(np.nan_to_num(normals) @ light, 0, 1))[:, None]
        rgb = np.clip(col, 0, 255).astype(np.uint8)
        idx = np.argsort(sign * points[:, depth_ax])           # far first, near last (on top)
        for dx in (0, 1):
            for dy in (0, 1):
                canvas[py[idx] + dy, px[idx] + dx] = rgb[idx]
    img = Image.fromarray(canvas).quantize(colors=64, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    img.save(path, optimize=True)
    return os.path.getsize(path)


def _graph():
    """The ``neighbour_graph`` in use (``--graph``, else this checkout's)."""
    if "_GRAPH" in globals():
        return globals()["_GRAPH"]
    from planning.areas.graph import neighbour_graph

    return neighbour_graph


def _config(case: str, extra: list[str]):
    from schemas.params import apply_overrides, parse_config

    base = UNIFORM_OVERRIDES if case == "femur_like" else RANGE_OVERRIDES
    return parse_config(apply_overrides({}, list(base) + list(OFF) + list(extra))), list(base) + list(extra)


def run_case(case: str, n_points: int, extra: list[str], cache: str | None, png_dir: str | None,
             tag: str | None, file_normals: bool = False, bound: bool = False) -> dict:
    """Plan ``case`` (areas and what they need only); its figures."""
    from planning import pipeline
    from planning.areas.assign import assign_areas
    from planning.inputs import Cloud
    from planning.inputs.samples import make_sample

    t0 = time.perf_counter()
    s = make_sample(case, n_points=n_points)
    t_sample = time.perf_counter() - t0
    cfg, overrides = _config(case, extra)
    stash = os.path.join(cache, f"{case}.npz") if cache else None
    fig = {"case": case, "n_points": int(s.points.shape[0]), "overrides": overrides, "sample_s": round(t_sample, 2)}
    if stash and os.path.exists(stash):
        z = np.load(stash)
        args = (z["points"], z["sample_index"], z["normals"], z["visibility"], z["selected"], z["axes"],
                tuple(z["cone"]))
        t1 = time.perf_counter()
        areas = assign_areas(*args, cfg.areas)
        fig.update(areas_s=round(time.perf_counter() - t1, 3), from_cache=True, k=len(z["selected"]),
                   status=None, coverage=None)
        points, sample_index, normals = z["points"], z["sample_index"], z["normals"]
        visibility, selected = z["visibility"], z["selected"]
    else:
        captured = {}
        real = pipeline.assign_areas

        def spy(points, sample_index, normals, visibility, selected, axes, cone, params, progress=None):
            captured.update(points=points, sample_index=sample_index, normals=normals, visibility=visibility,
                            selected=selected, axes=axes, cone=np.asarray(cone, float))
            return real(points, sample_index, normals, visibility, selected, axes, cone, params, progress=progress)

        pipeline.assign_areas = spy
        try:
            t1 = time.perf_counter()
            cloud = Cloud(points=s.points, normals=s.normals if file_normals else None, source_format="generated")
            out = pipeline.run_plan(cloud, cfg, name=case)
            t_plan = time.perf_counter() - t1
        finally:
            pipeline.assign_areas = real
        r = out.result
        areas = out.extra["areas"]
        stages = {t.stage: float(t.seconds) for t in r.timings}
        fig.update(areas_s=round(stages.get("areas", float("nan")), 3), plan_s=round(t_plan, 2), stages=stages,
                   from_cache=False, k=int(r.selection.k) if r.selection is not None else 0, status=r.status,
                   coverage=float(r.coverage))
        if stash and captured:
            os.makedirs(cache, exist_ok=True)
            np.savez_compressed(stash, **captured)
        points, sample_index, normals = captured["points"], captured["sample_index"], captured["normals"]
        visibility, selected = captured["visibility"], captured["selected"]
    sp = points[sample_index]
    g = _graph()(sp, normals, cfg.areas.neighbours)
    real_edges = ~g.bond
    fig.update(n_sampled=int(sample_index.shape[0]), method=areas.method,
               label_change_share=round(float(areas.label_change_share), 6), seam_mm=round(float(areas.seam_mm), 1),
               n_regions=int(sum(f.n_regions for f in areas.figures)),
               edges_per_point=round(2 * float(real_edges.sum()) / max(sample_index.shape[0], 1), 2),
               area_sum_mm2=round(float(g.area_mm2.sum()), 1),
               areas=[{"n_points": f.n_points, "n_regions": f.n_regions,
                       "largest_region_share": round(f.largest_region_share, 4), "min_regions": f.min_regions,
                       "n_visible_regions": f.n_visible_regions, "n_small_regions": f.n_small_regions,
                       "seam_mm": round(f.seam_mm, 1)} for f in areas.figures])
    if "surface_area_mm2" in s.meta:
        fig["true_area_mm2"] = round(float(s.meta["surface_area_mm2"]), 1)
    line = s.meta.get("line")
    if line is not None and points.shape[0] == s.points.shape[0]:
        fig["reference"] = reference_figures(sp, areas.labels, np.asarray(line)[sample_index],
                                             np.asarray(s.meta["view"])[sample_index])
    else:
        fig["reference"] = reference_figures(sp, areas.labels, None, None)
    if bound:
        z_sel = np.asarray(selected, dtype=np.int64)
        fig["bound"] = bound_figures(g, reference_pairs(sp), areas.labels, np.asarray(visibility, bool)[:, z_sel],
                                     cfg.areas.min_region_mm2)
    if png_dir and tag:
        os.makedirs(png_dir, exist_ok=True)
        name = {"range_femur": "range_femur", "range_half_sphere": "range_half_sphere"}.get(case, case)
        path = os.path.join(png_dir, f"areas_{name}_{tag}.png")
        nrm = normals[areas.nearest_sample] if areas.nearest_sample is not None else None
        fig["png"] = path
        fig["png_bytes"] = picture(path, points, nrm, areas.input_labels)
        if bound and areas.nearest_sample is not None:
            least = os.path.join(png_dir, f"areas_{name}_{tag}_least.png")
            picture(least, points, nrm, fig["bound"]["least_labels"][areas.nearest_sample])
            fig["png_least"] = least
    if bound:
        fig["bound"].pop("least_labels")
    return fig


def _lines(fig: dict) -> list[str]:
    ref = fig["reference"]
    cov = fig["coverage"] if fig["coverage"] is None else round(fig["coverage"], 4)
    surface = f" (surface {fig['true_area_mm2']:.0f})" if "true_area_mm2" in fig else ""
    lines = (f"; along a line {ref['along_share']:.2%}, across lines {ref['across_share']:.2%}"
             if "along_share" in ref else "")
    out = [(f"== {fig['case']}: {fig['n_points']:,} points, {fig['n_sampled']:,} sampled, k {fig['k']}, "
            f"status {fig['status']}, coverage {cov}"),
           (f"   areas stage {fig['areas_s']:.3f} s{' (cached inputs)' if fig['from_cache'] else ''}; graph edges per "
            f"point {fig['edges_per_point']}; point areas sum {fig['area_sum_mm2']:.0f} mm^2{surface}"),
           (f"   plan graph: label-change share {fig['label_change_share']:.2%}, seam {fig['seam_mm']:.0f} mm, "
            f"regions {fig['n_regions']}"),
           (f"   reference graph (r {ref['radius_mm']} mm, {ref['pairs_per_point']} pairs/point): label-change share "
            f"{ref['share']:.2%}{lines}")]
    bd = fig.get("bound")
    if bd:
        for name, label in (("plan", "plan graph"), ("reference", "reference graph"),
                            ("plan_freed", f"plan graph, {bd['plan_freed']['freed_points']} points of forced specks freed")):
            b = bd[name]
            gap = "exact" if b["fractional_points"] == 0 else f"LP, {b['fractional_points']} fractional points"
            out.append(f"   least share any allowed labelling reaches, {label}: {b['bound_share']:.2%} ({gap}; "
                       f"a labelling at {b['cut_share']:.2%}; {b['lp_s']:.1f} s)")
    for i, a in enumerate(fig["areas"]):
        ok = a["largest_region_share"] >= 0.9 or a["n_regions"] <= a["min_regions"]
        split, flag = "", "  <- under 90 % and above min_regions"
        if bd:
            u = bd["unforced_split_share"][i]
            split = f", split within a visible piece {u:.1%}"
            flag = flag if u < 0.1 else flag + ", 10 % or more split within a visible piece"
            c = bd["corridors"][i]
            if c:
                split += (f" (joined by corridors of {c['corridor_points']} points: {c['regions']} regions, largest "
                          f"{c['largest_region_share']:.1%}, share {c['share']:.2%}, all regions {c['regions_all']})")
        out.append(f"   area {i}: {a['n_points']:6d} points, {a['n_regions']:4d} regions (min {a['min_regions']}, "
                   f"visible {a['n_visible_regions']}, small {a['n_small_regions']}), largest {a['largest_region_share']:.1%}"
                   f"{split}{'' if ok else flag}")
    if "png" in fig:
        out.append(f"   picture {fig['png']} ({fig['png_bytes'] / 1024:.0f} KB)")
    if "png_least" in fig:
        out.append(f"   picture of a labelling with the least label changes on the plan graph: {fig['png_least']}")
    return out


def compare(before: str, after: str) -> None:
    docs = []
    for path in (before, after):
        with open(path) as fh:
            docs.append(json.load(fh))
    a, b = docs
    rows = {f["case"]: f for f in a["cases"]}
    for fb in b["cases"]:
        fa = rows.get(fb["case"])
        if fa is None:
            continue
        print(f"== {fb['case']}          before -> after")
        for key, fmt in (("label_change_share", "{:.2%}"), ("seam_mm", "{:.0f}"), ("n_regions", "{}"),
                         ("areas_s", "{:.3f}"), ("edges_per_point", "{}")):
            print(f"   {key:<22} {fmt.format(fa[key])} -> {fmt.format(fb[key])}")
        for key in ("share", "along_share", "across_share"):
            if key in fb["reference"]:
                print(f"   reference {key:<12} {fa['reference'][key]:.2%} -> {fb['reference'][key]:.2%}")
        for i in range(max(len(fa["areas"]), len(fb["areas"]))):
            x = fa["areas"][i] if i < len(fa["areas"]) else None
            y = fb["areas"][i] if i < len(fb["areas"]) else None
            cell = (lambda r: "-" if r is None else
                    f"{r['n_regions']} regions (min {r['min_regions']}), largest {r['largest_region_share']:.1%}")
            print(f"   area {i}: {cell(x)} -> {cell(y)}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES))
    ap.add_argument("--points", type=int, default=40_000, help="points of the range scans")
    ap.add_argument("--uniform-points", type=int, default=300_000, help="points of the uniform femur_like sample")
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE", help="more overrides (every case)")
    ap.add_argument("--file-normals", action="store_true",
                    help="hand the sample's exact normals to the plan (with --set normals.method=input: every point "
                         "a sampled point, the graph on the scan lines themselves)")
    ap.add_argument("--graph", default=None, metavar="FILE",
                    help="take neighbour_graph from this file instead (the code before a change: "
                         "git show HEAD:planning/areas/graph.py > /tmp/graph_before.py)")
    ap.add_argument("--cache", default=None, help="keep / reuse the areas stage's inputs here")
    ap.add_argument("--bound", action="store_true",
                    help="also the least label-change share the visibility allows (an LP per graph, seconds each; "
                         "planning/areas/bound.py) and per area the split within one visible piece")
    ap.add_argument("--old-settings", action="store_true",
                    help="the range cases with the own-scan settings before 47143a2 (cone [10,60], 4 set-ups)")
    ap.add_argument("--png-dir", default=None)
    ap.add_argument("--tag", default=None, help="picture name suffix (before, after)")
    ap.add_argument("--json", default=None, help="write the figures (JSON) here")
    ap.add_argument("--compare", nargs=2, default=None, metavar=("BEFORE", "AFTER"))
    args = ap.parse_args()
    if args.compare:
        compare(*args.compare)
        return 0
    if args.old_settings:
        global RANGE_OVERRIDES
        RANGE_OVERRIDES = OLD_RANGE_OVERRIDES
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} (1/5/15 min)", flush=True)
    if args.graph:
        import importlib.util

        from planning.areas import assign

        spec = importlib.util.spec_from_file_location("graph_alternative", args.graph)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        assign.neighbour_graph = mod.neighbour_graph           # what assign_areas calls
        globals()["_GRAPH"] = mod.neighbour_graph
        print(f"neighbour_graph from {args.graph}")
    figs = []
    for case in args.cases:
        n = args.uniform_points if case == "femur_like" else args.points
        fig = run_case(case, n, args.set, args.cache, args.png_dir, args.tag, args.file_normals, args.bound)
        figs.append(fig)
        print("\n".join(_lines(fig)), flush=True)
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as fh:
            json.dump({"tag": args.tag, "cases": figs}, fh, indent=1, default=float)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
