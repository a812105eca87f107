"""Benchmark: set-up selection when no k <= max_setups reaches the coverage (issue 17), against a
feasible selection on the same visibility matrix.  Prints figures only.

Instances (docs/design.md, Performance, "Set-ups": infeasibility proven in under 3 s on the femur-like
case and under 1 s on 10k points):

* ``femur``: the femur-like sample (``planning.inputs.samples.femur_like``, 1M points) through the
  pipeline's normals, orientations and visibility stages with the default parameters (cone [10, 80],
  travel and collisions on, fixture height 50 mm, tool 6 mm): about 100k sampled points x 145 axes.
  The best 5 axes cover 94.1 %, so coverage 0.95 with 5 set-ups is infeasible.  Building it takes
  30-60 s, so the boolean matrix is cached (``--cache``, an .npz under /tmp by default; never commit it).
* ``10k``: 10,000 rows of that matrix drawn with a fixed seed.

Each instance is solved at the infeasible coverage (``--coverage``, 0.95) and at feasible ones
(``--feasible``, default 0.90 and 0.94: the second lies just below the best coverage, the hardest
feasible case), with max 5 set-ups, in the same run; the ratio infeasible / feasible is printed.
``--before REV`` also runs the planning/setups package of git revision REV (e.g. the commit before
issue 17) on the same matrices, in a subprocess, so that both figures come from the same machine
state.  Every solver runs in its own subprocess, one after the other (one heavy process at a time),
after a tiny warm-up call (imports, e.g. SciPy's HiGHS, are not timed).

    .venv/bin/python bench/bench_infeasible.py                        # after only
    .venv/bin/python bench/bench_infeasible.py --before 43c11a9       # before and after
    .venv/bin/python bench/bench_infeasible.py --cache /tmp/femur_vis.npz --repeat 3
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def femur_visibility(cache: str) -> np.ndarray:
    """The femur-like default visibility matrix (points x feasible axes, bool), cached in ``cache``."""
    if os.path.exists(cache):
        return np.load(cache)["visible"]
    from planning import pipeline as pl
    from planning.inputs import Cloud
    from planning.inputs.samples import femur_like
    from planning.orientations import load_profile
    from schemas.params import PlanConfig

    t = time.perf_counter()
    s = femur_like()
    cloud = Cloud(points=s.points, normals=None, source_format="generated")
    cfg = PlanConfig()
    profile = load_profile(cfg.machine.profile)
    nrm = pl._normals(cloud, cfg, None)
    ori = pl._orientations(cfg, profile)
    _, gv = pl._visibility(cloud.points, nrm, ori, cfg, cfg.tool.assembly(), profile, None, None)
    np.savez_compressed(cache, visible=gv.visible)
    print(f"(built the femur-like visibility {gv.visible.shape} in {time.perf_counter() - t:.1f} s, "
          f"cached in {cache})", flush=True)
    return gv.visible


def instances(V: np.ndarray, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"femur": V, "10k": V[np.sort(rng.choice(V.shape[0], 10_000, replace=False))]}


# ------------------------------------------------------------------------------------------------
# worker: one solver version, every case, timings as JSON on stdout
# ------------------------------------------------------------------------------------------------


def select_setups_of(setups_dir: str | None):
    """``select_setups`` of the working tree, or of the package exported under ``setups_dir``
    (:func:`export_revision`, put in front of the working tree's), after a warm-up call (imports)."""
    if setups_dir:  # the package of another revision in front of the working tree's
        import planning

        planning.__path__.insert(0, setups_dir)
    from planning.setups import select_setups

    select_setups(np.eye(4, dtype=bool), coverage=0.95, max_setups=2)  # warm-up: imports
    return select_setups


def worker(npz: str, cases: list[tuple[str, float]], max_setups: int, repeat: int, setups_dir: str | None):
    select_setups = select_setups_of(setups_dir)
    data = np.load(npz)
    out = []
    for name, cov in cases:
        V = data[name]
        best = None
        for _ in range(repeat):
            t = time.perf_counter()
            r = select_setups(V, coverage=cov, max_setups=max_setups)
            dt = time.perf_counter() - t
            best = dt if best is None else min(best, dt)
        out.append({"name": name, "coverage": cov, "seconds": best, "status": r.status, "k": r.k,
                    "covered": r.covered, "overlap": r.overlap, "selected": r.selected.tolist(),
                    "n": r.n_points, "classes": r.n_classes, "axes": r.n_axes_kept, "message": r.message})
    print("JSON " + json.dumps(out), flush=True)


def run_json_worker(script: str, args: list[str], setups_dir: str | None = None):
    """``script`` run with ``args`` (and ``--setups-dir``) in a fresh process: the figures it prints on
    its ``JSON`` line."""
    cmd = [sys.executable, os.path.abspath(script), *args]
    if setups_dir:
        cmd += ["--setups-dir", setups_dir]
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=False)
    for line in p.stdout.splitlines():
        if line.startswith("JSON "):
            return json.loads(line[5:])
    raise RuntimeError(f"worker failed:\n{p.stdout}\n{p.stderr}")


def run_worker(npz, cases, max_setups, repeat, setups_dir=None):
    return run_json_worker(__file__, ["--worker", npz, "--max-setups", str(max_setups), "--repeat", str(repeat),
                                      "--cases", json.dumps(cases)], setups_dir)


def solver_runs(before: str | None, tmp: str) -> list[tuple[str, str | None]]:
    """(label, exported package dir or None) of the solvers to run: revision ``before`` (exported
    under ``tmp``) when given, then the working tree."""
    runs = []
    if before:
        runs.append((f"before ({before})", export_revision(before, os.path.join(tmp, "before"))))
    runs.append(("after (working tree)", None))
    return runs


def export_revision(rev: str, dest: str) -> str:
    """planning/setups of git revision ``rev`` under ``dest``/setups (a package path for planning)."""
    files = subprocess.run(["git", "ls-tree", "--name-only", rev, "planning/setups/"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    os.makedirs(os.path.join(dest, "setups"), exist_ok=True)
    for f in files:
        if f.endswith(".py"):
            src = subprocess.run(["git", "show", f"{rev}:{f}"], cwd=ROOT, capture_output=True,
                                 text=True, check=True).stdout
            with open(os.path.join(dest, "setups", os.path.basename(f)), "w") as fh:
                fh.write(src)
    return dest


def report(label, res):
    print(f"\n== {label}")
    by = {}
    for r in res:
        by.setdefault(r["name"], []).append(r)
        print(f"  {r['name']:>5} coverage {r['coverage']:.2f}: {r['status']:>10} k {r['k']} covered "
              f"{r['covered']}/{r['n']} ({r['covered'] / r['n'] * 100:.2f} %) overlap {r['overlap']} "
              f"selected {r['selected']}  {r['seconds']:.2f} s")
    for name, rs in by.items():
        inf = [r for r in rs if r["status"] == "infeasible"]
        fea = [r for r in rs if r["status"] == "optimal"]
        for a in inf:
            ratios = ", ".join(f"{a['seconds'] / f['seconds']:.2f}x the feasible {f['coverage']:.2f} "
                               f"({f['seconds']:.2f} s)" for f in fea)
            print(f"  {name}: infeasible {a['coverage']:.2f} in {a['seconds']:.2f} s = {ratios}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default=os.path.join(tempfile.gettempdir(), "scanmill_femur_visibility.npz"))
    ap.add_argument("--coverage", type=float, default=0.95, help="the infeasible coverage")
    ap.add_argument("--feasible", type=float, nargs="*", default=[0.90, 0.94])
    ap.add_argument("--max-setups", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=1, help="runs per case; the fastest is shown")
    ap.add_argument("--seed", type=int, default=0, help="rows of the 10k subsample")
    ap.add_argument("--case", choices=["all", "femur", "10k"], default="all")
    ap.add_argument("--before", metavar="REV", help="also run planning/setups of this git revision")
    ap.add_argument("--worker", metavar="NPZ", help=argparse.SUPPRESS)
    ap.add_argument("--cases", help=argparse.SUPPRESS)
    ap.add_argument("--setups-dir", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        worker(a.worker, [tuple(c) for c in json.loads(a.cases)], a.max_setups, a.repeat, a.setups_dir)
        return

    inst = instances(femur_visibility(a.cache), a.seed)
    names = ["femur", "10k"] if a.case == "all" else [a.case]
    cases = [(nm, c) for nm in names for c in [a.coverage, *a.feasible]]
    with tempfile.TemporaryDirectory() as tmp:
        npz = os.path.join(tmp, "instances.npz")
        np.savez(npz, **{k: inst[k] for k in names})
        for nm in names:
            print(f"{nm}: {inst[nm].shape[0]} points x {inst[nm].shape[1]} axes, max {a.max_setups} set-ups")
        runs = solver_runs(a.before, tmp)
        results = {}
        for label, d in runs:
            results[label] = run_worker(npz, cases, a.max_setups, a.repeat, d)
            report(label, results[label])
    if a.before:
        b, f = (results[label] for label, _ in runs)
        print("\n== speed-up (before / after)")
        for rb, ra in zip(b, f, strict=True):
            same = (rb["status"], rb["k"], rb["covered"], rb["overlap"], rb["selected"]) == (
                ra["status"], ra["k"], ra["covered"], ra["overlap"], ra["selected"])
            print(f"  {rb['name']:>5} coverage {rb['coverage']:.2f}: {rb['seconds']:.2f} s -> "
                  f"{ra['seconds']:.2f} s ({rb['seconds'] / ra['seconds']:.1f}x), same answer: {same}")


if __name__ == "__main__":
    main()
