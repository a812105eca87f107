"""Compile the numba kernels of a plan before the first job: ``scanmill warmup`` and the service's start.

The kernels are ``@njit(cache=True)``: compiled at their first call with given argument types, then
kept in numba's cache directory (:mod:`planning.kernel_cache`), from where later processes load them
in milliseconds. :func:`warm` plans a small reference scan in-process, through the same path as
``scanmill plan`` and the service (a binary PLY read by :func:`~planning.inputs.cloud.read_input`, the
default configuration: sphere-throwing normals, global visibility and travel, roughing, finishing,
both posts and the simulation), then a small simultaneous 5-axis plan of the deep slot (the kernels only
``paths.finishing.mode = 5axis`` calls), so the kernels are compiled for the argument types of a real
plan; the plans themselves are discarded. The exact gouge confirmation runs in a plan only where the deviation
suspects a gouge, which the warm-up plan may not: its kernels are compiled apart, on a tiny input
(:func:`planning.simulate.gouge.warm_kernels`; the kernels see arrays of fixed types whatever the
input). :class:`CompileCounter` counts the compilations (numba's
``numba:compile`` events fire only when a kernel is not found in the cache), which is how a second
warm-up or a test sees that nothing compiled again.

A successful warm-up leaves a marker file in the cache directory named after :func:`warm_stamp` (the
planning sources, numba, Python and the CPU): :func:`is_warm` tells the service at start whether the
cache already holds this code's kernels, so that it runs the warm-up only when they would compile.
"""

from __future__ import annotations

import hashlib
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Self

from planning import kernel_cache

#: The warm-up scan: the slot block (walls, a floor reached by few axes, material under the tool at
#: every level, so roughing entries and links run too) with few points, and coarse paths and simulation.
#: Only the values are coarser than the defaults, never the types (floats stay floats, nothing turns
#: None). The block keeps its full size: some kernels see a contiguous array or a strided view depending
#: on the size of the part (the roughing holder map's windows, ``maps._block_max``), which are two
#: compilations; a smaller block compiled only one of them. tests/test_warmup.py (slow) checks that a
#: default plan of the full slot scan compiles nothing after this warm-up.
WARMUP_SAMPLE = "slot"
WARMUP_POINTS = 1500
#: Other arguments of the sample generator.
WARMUP_SAMPLE_ARGS: dict = {}
#: Configuration overrides of the warm-up plan.
WARMUP_CONFIG: dict = {"simulate": {"resolution_mm": 2.0},
                       "paths": {"finishing": {"scallop_mm": 0.2}, "roughing": {"step_down_mm": 5.0}}}

#: The simultaneous 5-axis warm-up (issue 33 item 4): ``paths.finishing.mode = 5axis`` runs kernels no 3+2
#: plan calls (the axis search per position, the 5-axis holder and fixture checks, the 5-axis posts and
#: the verification of their programs), so the warm-up also plans the deep slot of issue 19 (the reference
#: 5-axis case, a scan of its top) that way, from one pass direction, with coarse values of the same types.
#: tests/test_warmup.py (slow) checks that a 5-axis plan of the slot compiles nothing after the warm-up.
WARMUP_FIVE_AXIS_SAMPLE = "draft_slot"
WARMUP_FIVE_AXIS_SAMPLE_ARGS: dict = {"density_per_mm2": 0.5, "seed": 1, "include_sides": False}
WARMUP_FIVE_AXIS_CONFIG: dict = {"normals": {"method": "input"}, "visibility": {"cone_deg": [10.0, 45.0]},
                                 "setups": {"max_setups": 1}, "simulate": {"resolution_mm": 2.0},
                                 "paths": {"finishing": {"scallop_mm": 0.3, "mode": "5axis"},
                                           "roughing": {"step_down_mm": 5.0}}}


class CompileCounter:
    """Context manager recording each kernel numba compiles meanwhile (not those loaded from the cache).

    ``compiled``: ``module.qualname`` of each compilation, one entry per compiled signature.
    """

    def __init__(self):
        self.compiled: list[str] = []

    def __enter__(self) -> Self:
        from numba.core import event

        counter = self

        class _Listener(event.Listener):
            def on_start(self, ev):
                f = ev.data["dispatcher"].py_func
                counter.compiled.append(f"{f.__module__}.{f.__qualname__}")

            def on_end(self, ev):
                pass

        self._listener = _Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc) -> None:
        from numba.core import event
        event.unregister("numba:compile", self._listener)


@dataclass
class WarmupReport:
    """What :func:`warm` did: seconds taken, kernels compiled (``module.qualname``), the cache directory."""

    seconds: float
    compiled: list[str] = field(default_factory=list)
    cache_dir: str | None = None
    threading_layer: str | None = None
    status: str = ""

    @property
    def n_compiled(self) -> int:
        return len(self.compiled)


def warm_plan(progress=None, five_axis: bool = False):
    """Plan the warm-up scan (:data:`WARMUP_SAMPLE` with :data:`WARMUP_CONFIG`; ``five_axis``:
    :data:`WARMUP_FIVE_AXIS_SAMPLE` with :data:`WARMUP_FIVE_AXIS_CONFIG`) and write its files into a
    temporary directory, as ``scanmill plan`` and a job do; return the plan outcome."""
    from planning.inputs.cloud import read_input
    from planning.inputs.samples import make_sample
    from planning.pipeline import run_plan
    from planning.report.files import write_ply
    from planning.report.plan_files import write_plan
    from schemas.params import parse_config

    if five_axis:
        name = WARMUP_FIVE_AXIS_SAMPLE
        config = parse_config(WARMUP_FIVE_AXIS_CONFIG)
        sample = make_sample(name, **WARMUP_FIVE_AXIS_SAMPLE_ARGS)
    else:
        name = WARMUP_SAMPLE
        config = parse_config(WARMUP_CONFIG)
        sample = make_sample(name, n_points=WARMUP_POINTS, **WARMUP_SAMPLE_ARGS)
    with tempfile.TemporaryDirectory(prefix="scanmill-warmup-") as tmp:
        path = Path(tmp) / f"{name}.ply"
        # written and read back as a user's file is: the same dtypes and layout reach the kernels
        write_ply(path, sample.points, normals=sample.normals, binary=True)
        cloud = read_input(path, config.input)
        outcome = run_plan(cloud, config, name=f"warmup-{name}", progress=progress)
        write_plan(outcome, Path(tmp) / "plan")      # the artifacts run kernels too (the stock mesh)
    return outcome


def warm_stamp() -> str:
    """A hash of what the cached kernels depend on: every planning source, numba, Python and the CPU."""
    import llvmlite.binding as llvm
    import numba

    h = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode() + b"\0")
        h.update(path.read_bytes() + b"\0")
    for part in (numba.__version__, sys.version, platform.machine(), llvm.get_host_cpu_name(),
                 llvm.get_host_cpu_features().flatten(), os.environ.get("NUMBA_CPU_NAME", ""),
                 os.environ.get("NUMBA_CPU_FEATURES", "")):
        h.update(str(part).encode() + b"\0")
    return h.hexdigest()[:20]


def _marker(stamp: str) -> Path | None:
    d = kernel_cache.state.get("cache_dir") or os.environ.get("NUMBA_CACHE_DIR")
    return Path(d) / f"scanmill-warm-{stamp}" if d else None


def is_warm() -> bool:
    """True if a warm-up of this very code on this CPU finished into the current cache directory."""
    try:
        m = _marker(warm_stamp())
        return m is not None and m.is_file()
    except OSError:
        return False


def warm(progress=None) -> WarmupReport:
    """Compile (or load from the cache) every kernel a default plan uses, by running a small plan.

    ``progress(stage, fraction, message)`` is passed to the pipeline. Returns a :class:`WarmupReport`.
    """
    t0 = time.perf_counter()
    with CompileCounter() as counter:
        outcome = warm_plan(progress)
        warm_plan(progress, five_axis=True)          # the simultaneous 5-axis kernels (issue 33 item 4)
        from planning.simulate.gouge import warm_kernels
        warm_kernels()                       # the gouge confirmation: the warm-up plan may suspect none
    seconds = time.perf_counter() - t0
    try:
        import numba
        layer = numba.threading_layer()
    except (ImportError, ValueError):     # no parallel kernel ran
        layer = None
    try:
        m = _marker(warm_stamp())
        if m is not None:
            for old in m.parent.glob("scanmill-warm-*"):     # one marker: the stamp of the code now
                old.unlink(missing_ok=True)
            m.write_text(f"{time.strftime('%Y-%m-%dT%H:%M:%S')} {len(counter.compiled)} compiled\n")
    except OSError:
        pass                                                   # a read-only cache: nothing to remember
    return WarmupReport(seconds=seconds, compiled=list(counter.compiled),
                        cache_dir=kernel_cache.state.get("cache_dir"), threading_layer=layer,
                        status=outcome.result.status)
