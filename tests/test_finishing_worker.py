"""The finishing passes computed by a worker process while the main one roughs (issue 30 item 3,
planning.toolpath.finishing_worker): the same paths as computed in the planning process, on a plate
of two areas with rest roughing on the carried stock; a worker that dies is replaced by the passes
computed here; the worker is not used where it cannot pay or is not allowed."""

from __future__ import annotations

import numpy as np
import pytest

import planning.toolpath.finishing_worker as W
from planning.geometry.tool import ball_tool
from planning.toolpath.area_paths import area_toolpaths
from planning.toolpath.frames import AreaFrame
from planning.toolpath.safety import check_positions, cloud_blocked
from schemas.params import PathsParams

R = 3.0


def _scene():
    X, Y = np.meshgrid(np.arange(-50, 50 + 1e-9, 0.5), np.arange(-20, 20 + 1e-9, 0.5), indexing="ij")
    x, y = X.ravel(), Y.ravel()
    z = 1.5 * np.sin(x / 4.0) * np.cos(y / 5.0)
    pts = np.stack([x, y, z], 1)
    labels = np.where(x < 0, 0, 1)
    axes = np.array([[0.0, 0.0, 1.0], [0.2, 0.0, 0.98]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    tool = ball_tool(R, flute_length_mm=15.0, stickout_mm=25.0, holder=[(4.0, None, None)])
    pp = PathsParams(finishing={"scallop_mm": 0.1, "tolerance_mm": 0.01})
    return pts, labels, axes, tool, pp


def _paths(**kw):
    pts, labels, axes, tool, pp = _scene()
    return area_toolpaths(pts, labels, axes, tool=tool, paths_params=pp, **kw)


def _same(a, b):
    assert [x.area for x in a] == [x.area for x in b]
    for pa, pb in zip(a, b, strict=True):
        for f in ("xyz_mm", "kind", "use"):
            np.testing.assert_array_equal(getattr(pa.finishing, f), getattr(pb.finishing, f))
        assert pa.finishing_info.n_passes == pb.finishing_info.n_passes
        assert pa.min_clearance_mm == pb.min_clearance_mm


@pytest.fixture
def worker_on(monkeypatch):
    """Whether the worker is used for this small cloud (on any machine) is ``MIN_POINTS``'s: 0 on,
    10**12 off; the workers opened (None: not opened) are listed."""
    monkeypatch.delenv("SCANMILL_FINISHING_WORKER", raising=False)
    monkeypatch.setattr(W, "MIN_POINTS", 10 ** 12)
    monkeypatch.setattr(W, "_threads", lambda: 2)
    opened = []
    real_open = W.FinishingWorker.open.__func__

    def spy(cls, n):
        w = real_open(cls, n)
        opened.append(w)
        return w
    monkeypatch.setattr(W.FinishingWorker, "open", classmethod(spy))
    return opened


def test_the_worker_computes_the_same_passes_as_the_planning_process(worker_on, monkeypatch):
    here = _paths()
    assert worker_on == [None]                              # off: the passes computed here
    monkeypatch.setattr(W, "MIN_POINTS", 0)
    calls = []
    real = W.FinishingWorker.passes

    def counted(self, progress=None):
        calls.append(1)
        return real(self, progress)
    monkeypatch.setattr(W.FinishingWorker, "passes", counted)
    there = _paths()
    assert worker_on and worker_on[-1] is not None            # the worker ran ...
    assert len(calls) == 2                                   # ... the passes of both areas
    assert not worker_on[-1].usable                           # and is gone at the end
    _same(here, there)


def test_a_worker_that_dies_is_replaced_by_the_passes_computed_here(worker_on, monkeypatch, caplog):
    here = _paths()
    monkeypatch.setattr(W, "MIN_POINTS", 0)
    real = W.FinishingWorker.submit

    def submit_then_die(self, *a, **kw):
        ok = real(self, *a, **kw)
        if ok:
            self._proc.kill()
        return ok
    monkeypatch.setattr(W.FinishingWorker, "submit", submit_then_die)
    with caplog.at_level("WARNING"):
        there = _paths()
    assert worker_on[-1] is not None and not worker_on[-1].usable
    assert "finishing worker failed" in caplog.text
    _same(here, there)


def test_no_worker_where_it_would_not_pay_or_is_not_allowed(monkeypatch):
    monkeypatch.delenv("SCANMILL_FINISHING_WORKER", raising=False)
    monkeypatch.setattr(W, "_threads", lambda: 2)
    assert W.FinishingWorker.open(W.MIN_POINTS - 1) is None
    monkeypatch.setattr(W, "_threads", lambda: 1)
    assert W.FinishingWorker.open(10 * W.MIN_POINTS) is None
    monkeypatch.setattr(W, "_threads", lambda: 2)
    monkeypatch.setenv("SCANMILL_FINISHING_WORKER", "0")
    assert W.FinishingWorker.open(10 * W.MIN_POINTS) is None
    monkeypatch.delenv("SCANMILL_FINISHING_WORKER")
    # a service job's process: pinned off (service.workers.pin_thread_env)
    from service.workers import pin_thread_env
    env: dict = {}
    pin_thread_env(2, env)
    assert env["SCANMILL_FINISHING_WORKER"] == "0"
    w = W.FinishingWorker.open(10 * W.MIN_POINTS)
    assert w is not None and w.usable
    w.close()
    assert not w.usable


def test_the_workers_own_errors_are_raised_here_and_it_goes_on(monkeypatch):
    """A region without a pass raises ParameterError in the worker; the planning process gets it as
    its own, and the worker takes the next job."""
    from planning.errors import ParameterError

    monkeypatch.delenv("SCANMILL_FINISHING_WORKER", raising=False)
    monkeypatch.setattr(W, "_threads", lambda: 2)
    pts, labels, axes, tool, pp = _scene()
    w = W.FinishingWorker.open(10 * W.MIN_POINTS)
    try:
        fp = pp.finishing
        assert w.submit(pts, [np.zeros(len(pts), dtype=bool)], None, fp, R, 0.01, 20.0, 80.0)
        with pytest.raises(ParameterError):
            w.passes()
        assert w.usable
        assert w.submit(pts, [labels == 0], None, fp, R, 0.01, 20.0, 80.0)
        fin, known = w.passes()
        assert known is None                                  # no check asked for
        here, _ = W.region_passes(pts, [labels == 0], None, fp, R, 0.01, 20.0, 80.0)
        np.testing.assert_array_equal(fin.toolpath.xyz_mm, here.toolpath.xyz_mm)
        # with the cloud's part of the check of the positions: the planning process's own answer
        frame = AreaFrame(rotation=np.eye(3), origin_mm=np.zeros(3))
        assert w.submit(pts, [labels == 0], None, fp, R, 0.01, 20.0, 80.0, (frame, axes[0], tool, pts))
        fin, (spacing, mask) = w.passes()
        positions, _ = check_positions(here.toolpath, 20.0, 0.25 * R)
        assert spacing == 0.25 * R
        np.testing.assert_array_equal(mask, cloud_blocked(positions, frame, axes[0], tool, pts))
    finally:
        w.close()


def test_a_plan_on_the_carried_stock_is_the_same_with_the_worker(monkeypatch):
    """The whole plan of a reference case (rest roughing on the carried stock, the finishing's CL points
    cut where the holder meets the stock, the guard): the same programs with the worker (passes and
    the cloud's part of their check computed there) as without."""
    from planning.inputs import Cloud
    from planning.inputs.samples import filleted_box
    from planning.pipeline import run_plan
    from schemas.params import apply_overrides, parse_config

    monkeypatch.delenv("SCANMILL_FINISHING_WORKER", raising=False)
    monkeypatch.setattr(W, "_threads", lambda: 2)
    s = filleted_box(density_per_mm2=0.5, seed=3)
    cfg = parse_config(apply_overrides({}, ["tool.diameter_mm=4", "paths.finishing.scallop_mm=0.2",
                                            "paths.roughing.step_down_mm=5", "simulate.resolution_mm=1.0"]))

    def plan():
        return run_plan(Cloud(points=s.points, normals=s.normals, source_format="generated"), cfg, name="box")

    monkeypatch.setattr(W, "MIN_POINTS", 10 ** 12)
    here = plan()
    used = []
    real = W.FinishingWorker.passes

    def counted(self, progress=None):
        out = real(self, progress)
        used.append(out[1] is not None)
        return out
    monkeypatch.setattr(W.FinishingWorker, "passes", counted)
    monkeypatch.setattr(W, "MIN_POINTS", 0)
    there = plan()
    assert used and all(used)                           # every set-up's passes and cloud check came from it
    assert here.extra["programs"] == there.extra["programs"]
    assert here.result.verification.status == there.result.verification.status == "passed"


def test_the_regions_travel_as_indices_and_read_back_as_the_same_masks():
    """A set-up's regions are held and sent to the worker as point indices (:class:`IndexMasks`, made by
    ``area_paths._region_masks``): each read back is the mask the region ids give, written out here point by
    point, in order (by increasing id, then the points handed on), and the pickle holds 4 bytes per indexed
    point, a fraction of the masks' bytes."""
    import pickle

    from planning.toolpath.area_paths import _region_masks

    rng = np.random.default_rng(3)
    n, pad = 200_000, 500
    regions = rng.integers(0, 45, n) ** 2 % 50                 # 23 of 50 ids present, uneven sizes
    mine = rng.random(n) < 0.7
    extra = ~mine & (rng.random(n) < 0.01)
    im = _region_masks(mine, regions, n + pad, extra=extra)
    ids = sorted({int(regions[i]) for i in range(n) if mine[i]})
    masks = [np.concatenate([mine & (regions == r), np.zeros(pad, bool)]) for r in ids]
    masks.append(np.concatenate([extra, np.zeros(pad, bool)]))
    assert len(im) == len(masks)
    for m, back in zip(masks, im):
        assert back.dtype == bool and back.shape == (n + pad,) and np.array_equal(back, m)
    assert [np.count_nonzero(im[k]) for k in (1, 2)] == [np.count_nonzero(m) for m in masks[1:3]]
    with pytest.raises(IndexError):
        im[len(masks)]
    # 4 bytes per point of the area (int32 indices) against one byte per point per region: 24 regions here
    size = len(pickle.dumps(im))
    assert size < 4 * (mine.sum() + extra.sum()) + 10_000
    assert size < len(pickle.dumps(masks)) / 5
    whole = _region_masks(mine, None, n + pad)
    assert len(whole) == 1 and np.array_equal(whole[0], np.concatenate([mine, np.zeros(pad, bool)]))


def test_a_plan_with_semi_finishing_is_the_same_with_the_worker(monkeypatch):
    """With paths.semi_finishing the worker computes each set-up's semi-finishing passes first (answered on
    their own) and then its finishing passes: the same programs as without the worker, and both answers
    of every set-up came from it."""
    from planning.inputs import Cloud
    from planning.inputs.samples import filleted_box
    from planning.pipeline import run_plan
    from schemas.params import apply_overrides, parse_config

    monkeypatch.delenv("SCANMILL_FINISHING_WORKER", raising=False)
    monkeypatch.setattr(W, "_threads", lambda: 2)
    s = filleted_box(density_per_mm2=0.5, seed=3)
    cfg = parse_config(apply_overrides({}, ["tool.diameter_mm=4", "paths.finishing.scallop_mm=0.2",
                                            "paths.roughing.step_down_mm=5", "simulate.resolution_mm=1.0",
                                            "paths.semi_finishing.enabled=true", "paths.semi_finishing.diameter_mm=6",
                                            "paths.semi_finishing.scallop_mm=0.2"]))

    def plan():
        return run_plan(Cloud(points=s.points, normals=s.normals, source_format="generated"), cfg, name="box")

    monkeypatch.setattr(W, "MIN_POINTS", 10 ** 12)
    here = plan()
    asked = []
    real_semi, real = W.FinishingWorker.semi_passes, W.FinishingWorker.passes

    def semi_counted(self, progress=None):
        asked.append("semi")
        return real_semi(self, progress)

    def counted(self, progress=None):
        asked.append("finishing")
        return real(self, progress)
    monkeypatch.setattr(W.FinishingWorker, "semi_passes", semi_counted)
    monkeypatch.setattr(W.FinishingWorker, "passes", counted)
    monkeypatch.setattr(W, "MIN_POINTS", 0)
    there = plan()
    k = len(there.result.setups)
    assert asked == ["semi", "finishing"] * k
    assert any(op.operation == "semi_finishing" for a in there.result.verification.areas for op in a.operations)
    assert here.extra["programs"] == there.extra["programs"]
    assert here.result.verification.status == there.result.verification.status == "passed"
