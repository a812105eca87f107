"""Areas as contiguous regions (issue 14): how speckled the assignment of points to set-ups is, and
what it costs, before and after.

For each reference case (``--cases``, default the femur-like scan and the half sphere, planned with
the configurations of scripts/demo_service.py's ``CONFIGS`` as ``--set`` flags, tool paths on) it
runs ``PYTHON -m scanmill.cli plan CLOUD --out DIR --set ...`` in ``--cwd`` (with ``PYTHONPATH``
= ``--cwd`` first, so an older checkout's packages are the ones imported; checked before planning),
times it, and measures:

* on the INPUT points, with THIS checkout's ``planning.areas.graph.neighbour_graph(points, None, 8)``
  (so plans of every version are measured on one graph): the share of edges whose two ends carry
  different ``input_labels`` (plan.npz), per area the connected pieces (components over same-label
  edges), the pieces of >= 50 points, the largest piece's share of the area's points, and the seam
  length (sum of ``seam_mm`` over the cut edges; bond edges weigh 0);
* the same share and seam on the SAMPLED points (``labels``, ``sample_index``) for comparison with
  plan.json ``areas`` (which the plan computes on its own graph, with normals);
* from plan.json: selection k / overlap / status / coverage, the ``areas`` stage and the sum of all
  stage timings, and per area the finishing CL moves (``n_cl``), retracts, passes, regions (when
  reported) and the roughing levels, length and time;
* from each ``area_*.moves.json.gz`` (planning/post/neutral.py; ``.moves.json`` of older plans), in the ``finishing`` operation:
  ``rapids`` = moves of type ``rapid``, ``plunges`` / ``retracts`` = feed moves with that ``use``,
  ``links`` = maximal runs of consecutive rapid moves with a feed move before and after (an air
  move from one cut to the next, through the safe height; the approach and the departure are not
  links), and the operation's ``rapid_length_mm``.

The wall seconds are the whole ``scanmill plan`` subprocess (start, reading, planning, writing).
Sample clouds are written once into ``OUT/clouds`` by this checkout
(``python -m scanmill.cli sample NAME --out FILE``) and shared by every run.

    .venv/bin/python bench/bench_areas.py --label after --json bench/out/areas/after.json
    git worktree add /tmp/wt_before 98e870c
    .venv/bin/python bench/bench_areas.py --cwd /tmp/wt_before --label before --json bench/out/areas/before.json
    .venv/bin/python bench/bench_areas.py --compare bench/out/areas/before.json bench/out/areas/after.json

``--set KEY=VALUE`` adds overrides (for example ``--set areas.method=per_point``); ``--repeat N``
plans each case N times and keeps the fastest wall time (figures from the last run).
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: Pieces of an area with at least this many input points count as "large".
LARGE_PIECE_POINTS = 50


def reference_configs() -> dict:
    """``CONFIGS`` of scripts/demo_service.py, read without importing it (it imports httpx)."""
    tree = ast.parse((ROOT / "scripts" / "demo_service.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "CONFIGS" for t in node.targets):
            return ast.literal_eval(node.value)
    raise SystemExit("CONFIGS not found in scripts/demo_service.py")


def set_flags(config: dict, prefix: str = "") -> list[str]:
    """A nested configuration as ``KEY=VALUE`` strings (values as JSON) for ``scanmill plan --set``."""
    out = []
    for key, value in config.items():
        if isinstance(value, dict):
            out += set_flags(value, f"{prefix}{key}.")
        else:
            out.append(f"{prefix}{key}={json.dumps(value)}")
    return out


def run_env(cwd: Path) -> dict:
    """The environment of the planning subprocess: ``cwd`` first on PYTHONPATH."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(cwd)] + [p for p in [env.get("PYTHONPATH")] if p])
    return env


def check_imports(python: str, cwd: Path) -> str:
    """The folder ``planning`` and ``scanmill`` are imported from in the subprocess; exits when it
    is not ``cwd`` (an editable install shadowing the checkout)."""
    code = "import planning, scanmill; print(planning.__file__); print(scanmill.__file__)"
    res = subprocess.run([python, "-c", code], cwd=cwd, env=run_env(cwd), capture_output=True, text=True, check=True)
    files = res.stdout.split()
    for f in files:
        if not Path(f).resolve().is_relative_to(cwd.resolve()):
            raise SystemExit(f"{python} in {cwd} imports {f}, not the checkout in {cwd}")
    return files[0]


def sample_cloud(name: str, clouds: Path) -> Path:
    """The sample cloud ``name`` as binary PLY in ``clouds`` (written by this checkout if missing)."""
    path = clouds / f"{name}.ply"
    if not path.exists():
        clouds.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "scanmill.cli", "sample", name, "--out", str(path)], cwd=ROOT,
                       check=True)
    return path


def run_plan(python: str, cwd: Path, cloud: Path, out: Path, flags: list[str], retries: int) -> float:
    """Run ``scanmill plan`` (log in ``out``.log); wall seconds. Exit 0 (planned) or 3 (infeasible or
    incomplete) are results; anything else is retried after a minute (files being edited), then fatal."""
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [python, "-m", "scanmill.cli", "plan", str(cloud), "--out", str(out), "--quiet"]
    for f in flags:
        cmd += ["--set", f]
    for attempt in range(retries + 1):
        t0 = time.perf_counter()
        with open(f"{out}.log", "w") as log:
            rc = subprocess.run(cmd, cwd=cwd, env=run_env(cwd), stdout=log, stderr=subprocess.STDOUT,
                                check=False).returncode
        wall = time.perf_counter() - t0
        if rc in (0, 3):
            return wall
        print(f"  plan exited {rc} (see {out}.log); attempt {attempt + 1} of {retries + 1}", flush=True)
        if attempt < retries:
            time.sleep(60)
    raise SystemExit(f"plan failed: {' '.join(cmd)}")


def graph_figures(points: np.ndarray, labels: np.ndarray) -> dict:
    """Label-change share, seam length and per-area pieces of ``labels`` on the kNN graph (k 8, no
    normals) of ``points``, with this checkout's ``neighbour_graph``."""
    from planning.areas.graph import neighbour_graph
    from planning.areas.regions import label_regions

    t0 = time.perf_counter()
    g = neighbour_graph(points, None, 8)
    e = g.edges
    cut = labels[e[:, 0]] != labels[e[:, 1]]
    real = ~g.bond
    comp, nc = label_regions(g, labels)
    areas = []
    for lab in np.unique(labels[labels >= 0]):
        sizes = np.bincount(comp[labels == lab], minlength=nc)
        sizes = sizes[sizes > 0]
        areas.append({"label": int(lab), "n_points": int(sizes.sum()), "pieces": int(sizes.size),
                      "pieces_large": int((sizes >= LARGE_PIECE_POINTS).sum()),
                      "largest_share": float(sizes.max() / sizes.sum())})
    return {"n_points": int(points.shape[0]), "n_edges": int(real.sum()),
            "label_change_share": float(cut[real].mean()), "seam_mm": float(g.seam_mm[cut & real].sum()),
            "pieces": int(sum(a["pieces"] for a in areas)), "areas": areas,
            "seconds": round(time.perf_counter() - t0, 2)}


def moves_figures(path: Path) -> dict | None:
    """Rapids, plunges, retracts, links (runs of rapids) and rapid length of the finishing operation
    of one neutral move file, ``.moves.json.gz`` or an older plan's ``.moves.json`` (None without a
    finishing operation)."""
    from planning.report.moves_files import read_moves_text

    doc = json.loads(read_moves_text(path))
    ops = [op for op in doc["operations"] if op["name"] == "finishing"]
    if not ops:
        return None
    op = ops[0]
    kind = np.array(op["moves"]["type"])
    use = np.array(op["moves"]["use"])
    rapid = kind == "rapid"
    edge = np.diff(np.r_[0, rapid.astype(np.int8), 0])
    first, last = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1) - 1      # runs of rapids
    between = (first > 0) & (last < rapid.size - 1)
    return {"moves": int(kind.size), "rapids": int(rapid.sum()), "plunges": int((use == "plunge").sum()),
            "retracts": int((use == "retract").sum()), "links": int(between.sum()),
            "rapid_length_mm": float(op.get("rapid_length_mm") or 0.0)}


def plan_figures(plan_dir: Path) -> dict:
    """Selection, timings and per-area paths from plan.json and the move files."""
    plan = json.loads((plan_dir / "plan.json").read_text())
    sel = plan.get("selection") or {}
    stages = {t["stage"]: t["seconds"] for t in plan.get("timings") or []}
    out = {"status": plan.get("status"), "k": sel.get("k"), "overlap": sel.get("overlap"),
           "selection_status": sel.get("status"), "coverage": plan.get("coverage"),
           "areas_s": stages.get("areas"), "stages_s": round(sum(stages.values()), 2), "stages": stages,
           "plan_areas": plan.get("areas"), "setups": []}
    for s in plan.get("setups") or []:
        path = s.get("path") or {}
        fin, rough = path.get("finishing") or {}, path.get("roughing") or {}
        row = {"id": s.get("id"), "n_points": s.get("n_points"), "regions": s.get("regions"),
               "finishing": {k: fin.get(k) for k in ("n_cl", "n_retracts", "n_passes", "n_regions", "length_mm",
                                                     "machining_time_s")},
               "roughing": {k: rough.get(k) for k in ("n_levels", "length_mm", "machining_time_s")},
               "links": None}
        if path.get("moves") and (plan_dir / path["moves"]).exists():
            row["links"] = moves_figures(plan_dir / path["moves"])
        out["setups"].append(row)
    return out


def case_figures(name: str, cloud: Path, plan_dir: Path) -> dict:
    """Everything measured for one planned case (see the module docstring)."""
    from planning.inputs.cloud import read_cloud

    fig = plan_figures(plan_dir)
    npz = np.load(plan_dir / "plan.npz")
    points = read_cloud(str(cloud)).points
    fig["input_graph"] = graph_figures(points, np.asarray(npz["input_labels"], np.int64))
    if "labels" in npz.files and "sample_index" in npz.files:
        sampled = graph_figures(points[npz["sample_index"]], np.asarray(npz["labels"], np.int64))
        fig["sampled_graph"] = {k: sampled[k] for k in ("n_points", "label_change_share", "seam_mm", "pieces")}
    fig["case"] = name
    return fig


def _fmt(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1000 else f"{value:.0f}"
    return str(value)


def _area_rows(fig: dict) -> list[tuple[str, object]]:
    """Per area: input-graph pieces and the finishing / roughing figures."""
    rows = []
    pieces = {a["label"]: a for a in fig["input_graph"]["areas"]}
    for i, s in enumerate(fig["setups"]):
        a, f, r, ln = pieces.get(i), s["finishing"], s["roughing"], s["links"]
        reg = s.get("regions")
        regions = f"{reg['n_regions']} ({reg['min_regions']}, {reg['n_visible_regions']})" if reg else None
        links = f"{ln['links']} / {ln['rapids']} / {ln['plunges']}" if ln else None
        rapid_m = ln["rapid_length_mm"] / 1000 if ln else 0.0
        rows += [(f"area {i}: input points", a and a["n_points"]),
                 (f"area {i}: pieces (>= {LARGE_PIECE_POINTS} points)",
                  f"{a['pieces']} ({a['pieces_large']})" if a else None),
                 (f"area {i}: largest piece share", round(a["largest_share"], 4) if a else None),
                 (f"area {i}: plan regions (min, visible)", regions),
                 (f"area {i}: finishing moves / retracts / passes",
                  f"{f['n_cl']} / {f['n_retracts']} / {f['n_passes']}"),
                 (f"area {i}: finishing regions", f.get("n_regions")),
                 (f"area {i}: finishing links / rapids / plunges", links),
                 (f"area {i}: finishing rapid m / cut m", f"{rapid_m:.1f} / {(f['length_mm'] or 0) / 1000:.1f}"),
                 (f"area {i}: roughing levels / m / min",
                  f"{r['n_levels']} / {(r['length_mm'] or 0) / 1000:.1f} / {(r['machining_time_s'] or 0) / 60:.0f}")]
    return rows


def summary_rows(fig: dict) -> list[tuple[str, object]]:
    """The figures of one case as (name, value) rows, in print order."""
    g, sg, pa = fig["input_graph"], fig.get("sampled_graph"), fig.get("plan_areas")
    links = [s["links"] for s in fig["setups"] if s["links"]]
    plan_areas = (f"{pa['method']} / {pa['n_regions']} / {pa['seam_mm']:.0f} / {pa['label_change_share']:.2%}"
                  if pa else None)
    rows = [("status", fig["status"]),
            ("k / overlap / selection", f"{fig['k']} / {fig['overlap']} / {fig['selection_status']}"),
            ("coverage", round(fig["coverage"], 4)),
            ("input points / graph edges", f"{g['n_points']} / {g['n_edges']}"),
            ("label-change share, input graph", f"{g['label_change_share']:.2%}"),
            ("seam mm, input graph", round(g["seam_mm"])),
            ("pieces, input graph (all areas)", g["pieces"]),
            ("label-change share, sampled graph", f"{sg['label_change_share']:.2%}" if sg else None),
            ("seam mm, sampled graph", round(sg["seam_mm"]) if sg else None),
            ("plan.json areas: method / regions / seam mm / change", plan_areas)]
    rows += _area_rows(fig)
    rows += [("finishing moves, all areas", sum(s["finishing"]["n_cl"] or 0 for s in fig["setups"])),
             ("finishing retracts, all areas", sum(s["finishing"]["n_retracts"] or 0 for s in fig["setups"])),
             ("finishing links, all areas", sum(ln["links"] for ln in links) if links else None),
             ("areas stage s", fig["areas_s"]), ("all stages s", fig["stages_s"]),
             ("wall s (scanmill plan)", round(fig["wall_s"], 1))]
    return rows


def markdown(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def print_case(fig: dict) -> None:
    print(f"\n### {fig['case']} ({fig['label']})\n")
    print(markdown(["figure", "value"], [[k, _fmt(v)] for k, v in summary_rows(fig)]))


def compare(before_path: str, after_path: str) -> None:
    """Before -> after table per case present in both files."""
    before, after = (json.loads(Path(p).read_text()) for p in (before_path, after_path))
    for name in [c for c in before["cases"] if c in after["cases"]]:
        b, a = before["cases"][name], after["cases"][name]
        rb, ra = dict(summary_rows(b)), dict(summary_rows(a))
        names = list(rb) + [k for k in ra if k not in rb]
        print(f"\n### {name}\n")
        print(markdown(["figure", before.get("label", "before"), after.get("label", "after")],
                       [[k, _fmt(rb.get(k)), _fmt(ra.get(k))] for k in names]))


def parse_args(argv=None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=["femur_like", "half_sphere"])
    ap.add_argument("--out", default=str(ROOT / "bench" / "out" / "areas"), help="plans, logs and clouds")
    ap.add_argument("--python", default=sys.executable, help="interpreter that runs -m scanmill.cli")
    ap.add_argument("--cwd", default=str(ROOT), help="checkout to plan with (put first on PYTHONPATH)")
    ap.add_argument("--label", default=None, help="name of this run (default: the checkout's folder name)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="extra scanmill plan --set")
    ap.add_argument("--json", help="write the figures to this JSON file")
    ap.add_argument("--repeat", type=int, default=1, help="plans per case; the fastest wall time is kept")
    ap.add_argument("--retries", type=int, default=2, help="retries of a failed plan, a minute apart")
    ap.add_argument("--compare", nargs=2, metavar=("A.json", "B.json"), help="print A -> B; plan nothing")
    return ap.parse_args(argv)


def run_case(name: str, config: dict, args: argparse.Namespace, out: Path) -> dict:
    """Plan one case ``--repeat`` times and measure the last plan."""
    cwd = Path(args.cwd)
    cloud = sample_cloud(name, out / "clouds")
    flags = set_flags(config) + list(args.set)
    plan_dir = out / args.label / name
    walls = [run_plan(args.python, cwd, cloud, plan_dir, flags, args.retries) for _ in range(max(1, args.repeat))]
    fig = case_figures(name, cloud, plan_dir)
    fig.update(label=args.label, wall_s=min(walls), walls_s=[round(w, 2) for w in walls], flags=flags)
    return fig


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.compare:
        compare(*args.compare)
        return 0
    cwd = Path(args.cwd).resolve()
    args.label = args.label or cwd.name
    configs = reference_configs()
    out = Path(args.out)
    imported = check_imports(args.python, cwd)
    head = subprocess.run(["git", "-C", str(cwd), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True, check=False).stdout.strip()
    print(f"{args.label}: {args.python} in {cwd} (HEAD {head}, imports {imported})", flush=True)
    result = {"label": args.label, "cwd": str(cwd), "head": head, "python": args.python, "cases": {}}
    for name in args.cases:
        fig = run_case(name, configs[name], args, out)
        result["cases"][name] = fig
        print_case(fig)
        if args.json:                       # after every case: a later failure keeps the earlier ones
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
