"""A set-up's finishing run beside the next set-up's roughing (issue 30 item 3, "every core";
``docs/design.md`` "Stock-first planning").

The paths stage does the set-ups one after the other on the carried stock. Each set-up's roughing is
planned on the stock as the set-ups before left it after their roughing and semi-finishing (a copy,
:class:`planning.toolpath.stock_view.StockView`), not after their finishing
(:func:`planning.toolpath.area_paths._areas_in_order` says why that is safe). So the previous set-up's
finishing (the cut-out of its blocked CL points, arc fitting, the guard's simulation on the carried
stock: mostly numba kernels, which release the interpreter lock) no longer has to be done before the
roughing (mostly Python) starts: :class:`Overlap` runs it on one more thread while the roughing runs,
and joins it before the roughing's own guard runs on the carried stock.

It is used where the plan may use two threads and the finishing worker process is in use
(:mod:`planning.toolpath.finishing_worker`; the two rest on the same thread budget: the service's job
processes turn both off), numba's threading layer lets parallel kernels start from two threads at
once (OpenMP and TBB do; the workqueue layer does not), and ``SCANMILL_PATHS_OVERLAP`` is not ``0``.
Elsewhere the same steps run in the same order of results on one thread: the plan does not depend on
it (tests/test_overlap.py compares the programs).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Self

import numba

_log = logging.getLogger(__name__)

#: environment switch: ``0`` keeps every set-up's finishing on the planning thread
ENV_VAR = "SCANMILL_PATHS_OVERLAP"
#: numba threading layers whose parallel kernels may be started from two threads at once
THREADSAFE_LAYERS = ("omp", "tbb")


def _threads() -> int:
    """The threads this plan may use (numba's)."""
    return numba.get_num_threads()


def allowed() -> bool:
    """Whether a plan may run a finishing beside a roughing here (module docstring): not switched off,
    two threads or more, and a threading layer that takes parallel kernels from two threads (once
    none has run yet, the layer is not chosen: not allowed)."""
    if os.environ.get(ENV_VAR, "").strip() == "0" or _threads() < 2:
        return False
    try:
        layer = numba.threading_layer()
    except ValueError:
        return False
    return layer in THREADSAFE_LAYERS


class Overlap:
    """At most one job beside the caller's thread: :meth:`start` it, :meth:`join` it (its exception
    raised there). ``on`` False: nothing runs beside (the caller does the job itself). Used as a context
    manager: on leaving, a job still running is waited for (its own error logged when the caller is
    already failing), so that nothing outlives the paths stage."""

    def __init__(self, on: bool):
        self.on = bool(on)
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="paths-beside") if self.on else None
        self._job: Future | None = None

    @classmethod
    def open(cls, wanted: bool) -> Overlap:
        """On where ``wanted`` (the caller's own condition) and :func:`allowed`."""
        return cls(bool(wanted) and allowed())

    def start(self, fn: Callable[[], object]) -> None:
        if self._pool is None:
            raise RuntimeError("Overlap.start: not on")
        if self._job is not None:
            raise RuntimeError("Overlap.start: the job before was not joined")
        self._job = self._pool.submit(fn)

    def join(self) -> None:
        job, self._job = self._job, None
        if job is not None:
            job.result()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if self._job is not None:
                if exc_type is None:
                    self.join()
                else:
                    job, self._job = self._job, None
                    err = job.exception()          # waits for it
                    if err is not None:
                        _log.warning("the finishing beside the roughing failed too: %s", err)
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
