"""A set-up's finishing beside the next set-up's roughing (issue 30 item 3, planning.toolpath.overlap):
the same programs with it as without, the roughing planned on the stock the set-ups before left after
their roughing (a copy the finishing beside it cannot change), an error beside the roughing raised in
the plan with nothing left running, and the small runner itself."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import planning.toolpath.area_paths as AP
import planning.toolpath.finishing_worker as W
import planning.toolpath.overlap as O


def _box_plan():
    """A function planning the filleted box (two set-ups, rest roughing on the carried stock, the guard)."""
    from planning.inputs import Cloud
    from planning.inputs.samples import filleted_box
    from planning.pipeline import run_plan
    from schemas.params import apply_overrides, parse_config

    s = filleted_box(density_per_mm2=0.5, seed=3)
    cfg = parse_config(apply_overrides({}, ["tool.diameter_mm=4", "paths.finishing.scallop_mm=0.2",
                                            "paths.roughing.step_down_mm=5", "simulate.resolution_mm=1.0"]))
    return lambda: run_plan(Cloud(points=s.points, normals=s.normals, source_format="generated"), cfg, name="box")


@pytest.fixture
def two_threads(monkeypatch):
    """The finishing worker and the overlap used for this small cloud, whatever the machine's cores
    (running the finishing beside the roughing is the same work on one core, only slower)."""
    monkeypatch.delenv("SCANMILL_FINISHING_WORKER", raising=False)
    monkeypatch.delenv(O.ENV_VAR, raising=False)
    monkeypatch.setattr(W, "_threads", lambda: 2)
    monkeypatch.setattr(W, "MIN_POINTS", 0)
    monkeypatch.setattr(O, "_threads", lambda: 2)


def test_a_plan_is_the_same_with_the_finishing_beside_the_roughing(two_threads, monkeypatch):
    plan = _box_plan()
    monkeypatch.setenv(O.ENV_VAR, "0")
    started = []
    real_start = O.Overlap.start

    def start(self, fn):
        def spied():
            started.append(threading.current_thread().name)
            return fn()
        real_start(self, spied)
    monkeypatch.setattr(O.Overlap, "start", start)
    alone = plan()
    assert started == []
    monkeypatch.delenv(O.ENV_VAR)
    beside = plan()
    k = len(beside.result.setups)
    assert k >= 2
    # every set-up's finishing but the last ran on the thread beside the roughing
    assert len(started) == k - 1 and all(name.startswith("paths-beside") for name in started)
    assert alone.extra["programs"] == beside.extra["programs"]
    assert alone.result.verification.status == beside.result.verification.status == "passed"


def test_the_roughing_is_planned_on_the_stock_before_the_previous_finishing(two_threads, monkeypatch):
    """The second set-up's roughing reads a copy of the stock taken before the first set-up's finishing ran:
    it holds more material than the carried stock its guard then runs on (the finishing took some off),
    and the same as the carried stock held right after the first set-up's roughing was guarded."""
    plan = _box_plan()
    after_guard, seen, guarded = [], [], []
    real_guard, real_rough = AP._guard_roughing, AP._add_roughing

    def guard(ap, carried, *a, **k):
        guarded.append(carried.stock.volume_mm3())      # before this roughing runs on it
        real_guard(ap, carried, *a, **k)
        after_guard.append(carried.stock.volume_mm3())

    def rough(*a, view=None, **k):
        seen.append(None if view is None else view.stock.volume_mm3())
        real_rough(*a, view=view, **k)
    monkeypatch.setattr(AP, "_guard_roughing", guard)
    monkeypatch.setattr(AP, "_add_roughing", rough)
    out = plan()
    assert out.result.verification.status == "passed"
    assert len(seen) >= 2 and len(guarded) >= 2 and None not in seen
    # set-up 2's view: the stock after set-up 1's roughing, not after its finishing
    assert seen[1] == pytest.approx(after_guard[0], abs=1e-6)
    assert seen[1] > guarded[1] + 1.0


def test_an_error_beside_the_roughing_is_raised_in_the_plan_and_nothing_is_left_running(two_threads, monkeypatch):
    plan = _box_plan()
    real = AP._guard_finishing
    calls = []

    def failing(ap, *a, **k):
        calls.append(threading.current_thread().name)
        if len(calls) == 1:
            raise RuntimeError("guard failed on purpose")
        return real(ap, *a, **k)
    monkeypatch.setattr(AP, "_guard_finishing", failing)
    with pytest.raises(RuntimeError, match="on purpose"):
        plan()
    assert calls[0].startswith("paths-beside")
    assert not [t for t in threading.enumerate() if t.name.startswith("paths-beside")]


def test_the_overlap_runs_one_job_beside_and_raises_its_error_at_the_join():
    with O.Overlap(True) as ov:
        got = []
        ov.start(lambda: got.append(threading.current_thread().name))
        with pytest.raises(RuntimeError, match="not joined"):
            ov.start(lambda: None)
        ov.join()
        assert got and got[0].startswith("paths-beside")
        ov.start(lambda: 1 / 0)
        with pytest.raises(ZeroDivisionError):
            ov.join()
        ov.join()                                   # nothing running: nothing to do
    with O.Overlap(False) as off, pytest.raises(RuntimeError, match="not on"):
        off.start(lambda: None)


def test_leaving_the_overlap_waits_for_its_job():
    release, finished = threading.Event(), threading.Event()

    def job():
        release.wait(30)
        finished.set()
    with pytest.raises(KeyError):
        with O.Overlap(True) as ov:
            ov.start(job)
            threading.Timer(0.2, release.set).start()
            raise KeyError("the caller fails while the job runs")
    assert finished.is_set()
    assert not [t for t in threading.enumerate() if t.name.startswith("paths-beside")]


def test_the_overlap_is_allowed_only_with_two_threads_a_safe_threading_layer_and_not_switched_off(monkeypatch):
    import numba

    from planning.simulate.dexel import TriDexel

    TriDexel.box(np.zeros(3), np.ones(3), 0.5)              # a parallel kernel has run: a layer is chosen
    monkeypatch.delenv(O.ENV_VAR, raising=False)
    monkeypatch.setattr(O, "_threads", lambda: 2)
    assert O.allowed() is (numba.threading_layer() in O.THREADSAFE_LAYERS)
    monkeypatch.setattr(numba, "threading_layer", lambda: "workqueue")
    assert O.allowed() is False
    monkeypatch.undo()
    monkeypatch.setattr(O, "_threads", lambda: 1)
    assert O.allowed() is False
    monkeypatch.setattr(O, "_threads", lambda: 2)
    monkeypatch.setenv(O.ENV_VAR, "0")
    assert O.allowed() is False
    assert O.Overlap.open(True).on is False
