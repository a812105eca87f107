"""The plan keeps to its thread budget (numba's threads: ``NUMBA_NUM_THREADS``, a service job's
``SCANMILL_WORKER_THREADS``): the per-axis collision test and the per-direction sphere throwing start no
pool of threads when the budget is one, and give the same answers as with two."""

from __future__ import annotations

import concurrent.futures

import numba
import numpy as np
import pytest

import planning.normals.throwing as throwing
from planning.geometry.collision import centres_collision_free
from planning.geometry.tool import ball_tool
from planning.inputs.samples import half_sphere


@pytest.fixture
def pools(monkeypatch):
    """Counts the thread pools started (the collision test imports the class when it runs, the
    throwing at import)."""
    started = []
    real = concurrent.futures.ThreadPoolExecutor

    class Counted(real):
        def __init__(self, *a, **k):
            started.append(k.get("max_workers", a[0] if a else None))
            super().__init__(*a, **k)
    monkeypatch.setattr(concurrent.futures, "ThreadPoolExecutor", Counted)
    monkeypatch.setattr(throwing, "ThreadPoolExecutor", Counted)
    return started


def _with_threads(n, fn):
    before = numba.get_num_threads()
    numba.set_num_threads(n)
    try:
        return fn()
    finally:
        numba.set_num_threads(before)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs numba to have two threads to compare")
def test_the_collision_test_and_the_throwing_keep_to_one_thread_when_that_is_the_budget(pools):
    s = half_sphere()
    pts = s.points[::7]
    tool = ball_tool(3.0, flute_length_mm=10.0, stickout_mm=20.0, holder=[(8.0, None, None)])
    axes = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.6, 0.8], [-0.6, 0.0, 0.8]])

    def collide():
        return centres_collision_free(pts, pts + 3.0 * s.normals[::7], axes, tool)

    def throw():
        return throwing.sphere_throwing(s.points, sphere_diameter_mm=7.0)

    one = _with_threads(1, collide), _with_threads(1, throw)
    assert pools == []                                  # one thread: no pool anywhere
    two = _with_threads(2, collide), _with_threads(2, throw)
    assert len(pools) == 2 and all(w == 2 for w in pools)
    np.testing.assert_array_equal(one[0], two[0])
    np.testing.assert_array_equal(one[1].normals, two[1].normals)
