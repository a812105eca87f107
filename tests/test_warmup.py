"""No cold start: the numba kernels are cached outside the source tree, and a second process compiles nothing.

Every plan here runs in a subprocess with a fresh, empty cache (``SCANMILL_CACHE_DIR`` in ``tmp_path``),
which reports numba's ``numba:compile`` events (:class:`planning.warmup.CompileCounter`: they fire only
when a kernel is not in the cache) and each planning dispatcher's cache directory and cache hits. The
first process of a test compiles (that is the cost of these tests); the second must compile nothing.
The subprocesses import a copy of the packages taken when the module starts (numba keys its cache by
the source file's content, so an edit of the working tree between the two runs would compile again),
and that copy, their source tree, must end without a cache file in it.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Runs in the child: a small plan of the half sphere (normals from the file; finishing on, roughing and
#: the simulation off, to keep the compilation of the first run short), then a report on stdout.
CHILD = r"""
import json, sys, time
from numba.core.dispatcher import Dispatcher
from planning import kernel_cache
from planning.warmup import CompileCounter
mode = sys.argv[1]
with CompileCounter() as counter:
    if mode == "warmup":
        from planning.warmup import warm
        status = warm().status
    else:
        import tempfile
        from planning.inputs.cloud import read_cloud
        from planning.pipeline import run_plan
        from planning.report.plan_files import write_plan
        from schemas.params import parse_config
        config = parse_config(json.loads(sys.argv[3]))
        outcome = run_plan(read_cloud(sys.argv[2]), config)
        with tempfile.TemporaryDirectory() as out:
            write_plan(outcome, out)                 # as scanmill plan and a job do
        status = outcome.result.status
paths, hits = set(), 0
for name, mod in list(sys.modules.items()):
    if name.startswith("planning") and mod is not None:
        for obj in list(vars(mod).values()):
            if isinstance(obj, Dispatcher) and obj._cache.__class__.__name__ != "NullCache":
                paths.add(obj.stats.cache_path)
                hits += sum(obj.stats.cache_hits.values())
print(json.dumps({"status": status, "compiled": counter.compiled, "cache_dir": kernel_cache.state["cache_dir"],
                  "cache_paths": sorted(paths), "cache_hits": hits}))
"""

SMALL_PLAN = {"normals": {"method": "input"}, "tool": {"diameter_mm": 10}, "setups": {"max_setups": 2},
              "paths": {"finishing": {"scallop_mm": 0.2}, "roughing": {"enabled": False}},
              "simulate": {"enabled": False}}


@pytest.fixture(scope="module")
def src(tmp_path_factory) -> Path:
    """A copy of the packages the subprocesses import (ahead of the editable install on their path)."""
    root = tmp_path_factory.mktemp("src")
    for pkg in ("planning", "schemas", "scanmill"):
        shutil.copytree(ROOT / pkg, root / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return root


def _env(src: Path, cache: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "SCANMILL_"))}
    env["SCANMILL_CACHE_DIR"] = str(cache)
    env["PYTHONPATH"] = str(src)
    return env


def _child(src: Path, cache: Path, *args: str) -> dict:
    p = subprocess.run([sys.executable, "-c", CHILD, *args], check=False, cwd=src, env=_env(src, cache),
                       capture_output=True, text=True, timeout=1800)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "TBB" not in p.stderr, p.stderr[-3000:]          # the threading layer is chosen without probing TBB
    return json.loads(p.stdout.strip().splitlines()[-1])


def _source_tree_caches(src: Path) -> list[Path]:
    return [p for pat in ("*.nbi", "*.nbc") for p in src.rglob(pat)]


@pytest.fixture(scope="module")
def half_sphere_ply(tmp_path_factory) -> Path:
    from planning.inputs.samples import half_sphere
    from planning.report.files import write_ply
    s = half_sphere()
    path = tmp_path_factory.mktemp("in") / "half_sphere.ply"
    write_ply(path, s.points, normals=s.normals, binary=True)
    return path


@pytest.mark.slow           # compiles every kernel into an empty cache: 2 min on 2 cores
def test_a_second_process_loads_every_kernel_from_the_cache(src, tmp_path, half_sphere_ply):
    cache = tmp_path / "kernels"
    first = _child(src, cache, "plan", str(half_sphere_ply), json.dumps(SMALL_PLAN))
    second = _child(src, cache, "plan", str(half_sphere_ply), json.dumps(SMALL_PLAN))
    assert first["status"] == second["status"] == "planned"
    assert first["cache_dir"] == str(cache)
    planning_kernels = [f for f in first["compiled"] if f.startswith("planning.")]
    assert planning_kernels, "the first run should have compiled the kernels into the empty cache"
    assert second["compiled"] == [], f"the second process compiled {second['compiled']}"
    assert second["cache_hits"] > 0      # the kernels called from Python were loaded (callees come with them)
    # every cached kernel lives under the chosen directory, none in the source tree
    assert first["cache_paths"] and all(Path(p).is_relative_to(cache) for p in first["cache_paths"])
    assert list(cache.rglob("*.nbi")) and list(cache.rglob("*.nbc"))
    assert not _source_tree_caches(src), "cache files were written into the source tree"


@pytest.mark.slow
def test_warmup_compiles_what_a_default_plan_needs(src, tmp_path):
    """``scanmill warmup`` into an empty cache, then: a second warm-up, a default plan of the full-size
    slot and a simultaneous 5-axis plan of the deep slot compile nothing (the warm-up plans pass the
    kernels the argument types of real plans)."""
    from planning.inputs.samples import slot
    from planning.report.files import write_ply
    cache = tmp_path / "kernels"
    s = slot()
    ply = tmp_path / "slot.ply"
    write_ply(ply, s.points, normals=s.normals, binary=True)
    cli = subprocess.run([sys.executable, "-m", "scanmill.cli", "warmup"], check=False, cwd=src, env=_env(src, cache),
                         capture_output=True, text=True, timeout=1800)
    assert cli.returncode == 0, cli.stderr[-3000:]
    assert f"numba cache: {cache}" in cli.stdout, cli.stdout
    assert "that were not in the numba cache (cached now)" in cli.stdout, cli.stdout
    assert list(cache.glob("scanmill-warm-*")), "a finished warm-up leaves its marker"
    cli2 = subprocess.run([sys.executable, "-m", "scanmill.cli", "warmup"], check=False, cwd=src, env=_env(src, cache),
                          capture_output=True, text=True, timeout=1800)
    assert cli2.returncode == 0 and "every kernel came from the numba cache (nothing compiled)" in cli2.stdout, \
        cli2.stdout
    again = _child(src, cache, "warmup")
    assert again["compiled"] == [], f"a second warm-up compiled {again['compiled']}"
    plan = _child(src, cache, "plan", str(ply), "{}")
    assert plan["compiled"] == [], f"a default plan after the warm-up compiled {plan['compiled']}"
    # issue 33 item 4: the simultaneous 5-axis plan of the reference deep slot (tests/test_fiveaxis_plan.py's)
    from planning.inputs.samples import draft_slot
    d = draft_slot(density_per_mm2=1.0, seed=1, include_sides=False)
    ply5 = tmp_path / "draft_slot.ply"
    write_ply(ply5, d.points, normals=d.normals, binary=True)
    five = {"normals": {"method": "input"}, "visibility": {"cone_deg": [10.0, 45.0]}, "setups": {"max_setups": 1},
            "paths": {"finishing": {"mode": "5axis", "scallop_mm": 0.2}, "roughing": {"step_down_mm": 5.0}},
            "simulate": {"resolution_mm": 1.0}}
    plan5 = _child(src, cache, "plan", str(ply5), json.dumps(five))
    assert plan5["status"] in ("planned", "unfinished")          # it ran to the end (the share is not the point)
    assert plan5["compiled"] == [], f"a 5-axis plan after the warm-up compiled {plan5['compiled']}"
    assert not _source_tree_caches(src)


def test_cache_directory_choice(src, tmp_path):
    """NUMBA_CACHE_DIR set by the user wins; else SCANMILL_CACHE_DIR, else XDG; an unwritable one falls back
    to a private temporary directory. The threading layer is left alone when the user chose one."""
    code = ("import json, os, numba, planning; print(json.dumps([planning._kernel_cache.state, numba.config.CACHE_DIR, "
            "numba.config.THREADING_LAYER_PRIORITY, numba.config.THREADING_LAYER]))")

    def run(**env):
        e = _env(src, tmp_path / "unused")
        del e["SCANMILL_CACHE_DIR"]
        e.update(env)
        p = subprocess.run([sys.executable, "-c", code], cwd=src, env=e, capture_output=True, text=True,
                           timeout=300, check=True)
        return json.loads(p.stdout)

    state, cache_dir, priority, layer = run(SCANMILL_CACHE_DIR=str(tmp_path / "a"))
    assert cache_dir == str(tmp_path / "a") and state["source"] == "SCANMILL_CACHE_DIR"
    assert priority == ["omp", "workqueue", "tbb"] and layer == "default"
    state, cache_dir, _, _ = run(XDG_CACHE_HOME=str(tmp_path / "xdg"))
    assert cache_dir == str(tmp_path / "xdg" / "scanmill" / "numba") and state["source"] == "XDG"
    state, cache_dir, priority, layer = run(NUMBA_CACHE_DIR=str(tmp_path / "mine"), SCANMILL_CACHE_DIR=str(tmp_path / "a"),
                                            NUMBA_THREADING_LAYER="workqueue")
    assert cache_dir == str(tmp_path / "mine") and state["source"] == "NUMBA_CACHE_DIR"
    assert priority == ["tbb", "omp", "workqueue"] and layer == "workqueue"     # numba's own defaults kept
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    state, cache_dir, _, _ = run(SCANMILL_CACHE_DIR=str(blocker / "sub"))
    assert state["source"] == "temp" and state["skipped"] and not Path(cache_dir).is_relative_to(blocker)
    assert Path(cache_dir).is_dir() and os.access(cache_dir, os.W_OK)


#: A child that imports ``planning`` then Open3D (as the service does), with any warning an error, runs a
#: prange kernel and prints numba's threading layer and thread count.
_PARALLEL_CHILD = r"""
import warnings
warnings.simplefilter("error")
import planning, open3d, numba, numpy as np
@numba.njit(parallel=True, cache=False)
def total(a):
    s = 0.0
    for i in numba.prange(a.size):
        s += a[i]
    return s
assert total(np.ones(1000)) == 1000.0
print(numba.threading_layer(), numba.get_num_threads())
"""


def _parallel_child(src, tmp_path, env: dict, drop=()) -> subprocess.CompletedProcess:
    """:data:`_PARALLEL_CHILD` run with two numba threads, ``env`` added and the variables ``drop`` removed;
    it must exit 0."""
    e = _env(src, tmp_path / "kernels")
    e["NUMBA_NUM_THREADS"] = "2"
    for k in drop:
        e.pop(k, None)
    e.update(env)
    p = subprocess.run([sys.executable, "-c", _PARALLEL_CHILD], check=False, cwd=src, env=e, capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    return p


def test_parallel_kernels_run_on_openmp_after_open3d_without_a_tbb_warning(src, tmp_path):
    """Open3D loads its own old TBB; numba must not probe it (no warning) and still run prange in parallel."""
    p = _parallel_child(src, tmp_path, {})
    assert "TBB" not in p.stderr
    layer, threads = p.stdout.split()
    assert layer in ("omp", "workqueue") and int(threads) == 2


def test_idle_openmp_threads_sleep_unless_the_user_chose_a_wait_policy(src, tmp_path):
    """``planning`` sets OMP_WAIT_POLICY=PASSIVE before libgomp is loaded (also with Open3D imported after
    it): libgomp itself reports a spin count of 0 instead of its default 300,000. A policy or spin count
    the user set is kept."""

    def spin(**env):
        p = _parallel_child(src, tmp_path, dict(OMP_DISPLAY_ENV="VERBOSE", **env),
                            drop=("OMP_WAIT_POLICY", "GOMP_SPINCOUNT"))
        assert p.stdout.split()[0] == "omp", p.stdout     # the layer kernel_cache puts first
        got = re.findall(r"GOMP_SPINCOUNT = '(\d+)'", p.stderr)
        policy = re.findall(r"OMP_WAIT_POLICY = '(\w+)'", p.stderr)
        assert got and policy, p.stderr[-2000:]
        return int(got[-1]), policy[-1]

    assert spin() == (0, "PASSIVE")
    assert spin(OMP_WAIT_POLICY="ACTIVE")[1] == "ACTIVE"
    assert spin(GOMP_SPINCOUNT="1000")[0] == 1000
