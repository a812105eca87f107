"""The finishing passes of a set-up computed in a second process while the main one roughs it (issue 30
item 3, "every core"; ``docs/design.md`` "Stock-first planning").

A set-up's finishing passes (:func:`planning.toolpath.area_paths._region_finishing`: ball drop on the
cloud, the passes made gouge safe and joined) depend on the cloud in the set-up's frame, the area's
regions, the points handed on by the set-ups before and the safe height, all known when the set-up
starts; they do not depend on the stock. The roughing of the same set-up (and its guard) depends on
the stock, is mostly Python, and takes as long as the passes or longer. Threads would share one
interpreter lock between the two; a process does not. So :class:`FinishingWorker` hands the passes
of each set-up to one worker process when the set-up starts and the main process collects them when
its roughing is done: on two cores the passes cost no wall time where they fit beside the roughing.
The result is the same function on the same inputs, so the plan does not change (the tests compare).

The worker is a fresh interpreter (``python -m planning.toolpath.finishing_worker``, one numba
thread) fed pickled jobs on its standard input and answering on its standard output; it never
imports the caller's main module (as a ``multiprocessing`` spawn would, running an unguarded script
again) and exits when its input closes, so it does not outlive the plan.

It is used only where it can pay and is allowed: at least two threads for this plan
(``numba.get_num_threads()``), a cloud of at least :data:`MIN_POINTS` points, not turned off
(``SCANMILL_FINISHING_WORKER=0`` in the environment: the service pins it in its job processes with
their thread counts, :func:`service.workers.pin_thread_env`, so that a job keeps to its thread
budget and to the memory admitted for one process), and not in a daemonic process. Any failure to start or run the worker falls back to computing the
passes in this process; the worker's own errors (a region without a pass) are raised here as they
would be.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import pickle
import select
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence

import numba
import numpy as np

_log = logging.getLogger(__name__)

#: Fewer cloud points than this: the passes are computed in this process (the worker's start and the
#: cloud's transfer would cost more than they save).
MIN_POINTS = 100_000

_HEADER = struct.Struct("<Q")


def _threads() -> int:
    """The threads this plan may use (numba's)."""
    return numba.get_num_threads()


class WorkerFailed(RuntimeError):
    """The worker process died or answered nonsense: the caller computes the passes itself."""


class IndexMasks(Sequence):
    """Boolean masks over ``n`` points kept as the indices of their True entries (``indices``: one int32
    array per mask, int64 from 2**31 points on); each mask is made when it is read. The regions of a
    set-up (:func:`planning.toolpath.area_paths._region_masks`) are held and sent to the worker so,
    instead of one byte per cloud point per region."""

    def __init__(self, indices: list, n: int):
        self.n = int(n)
        dtype = np.int32 if self.n < 2**31 else np.int64
        self.indices = [np.asarray(i, dtype=dtype) for i in indices]

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, k: int) -> np.ndarray:
        out = np.zeros(self.n, dtype=bool)
        out[self.indices[k]] = True
        return out


def binned_cloud(cloud_f: np.ndarray, faces, R: float):
    """The set-up's cloud (frame, mm) binned at R/4 for the finishing's clearance queries, with the
    triangles through it the ball rests on when ``faces`` are given (``binned.triangles``)."""
    from planning.geometry.triangles import TriangleDropSurface
    from planning.toolpath.verify import BinnedCloud

    binned = BinnedCloud(cloud_f, R / 4.0)
    if faces is not None and len(faces):
        binned.triangles = TriangleDropSurface(cloud_f, faces, R)
    return binned


def cloud_check(fin, safe: float, R: float, check) -> tuple[float, np.ndarray] | None:
    """The stock-free part of the check of the passes' positions (step 1 of
    :func:`planning.toolpath.safety.guard_finishing` at its default sample spacing, R / 4): the
    cloud reason of :func:`planning.toolpath.safety.cloud_blocked` for
    :func:`planning.toolpath.safety.check_positions`, as ``guard_finishing``'s ``cloud_known``.
    ``check``: ``(frame, axis (part frame), tool assembly, obstacles (part frame))`` or None."""
    from planning.toolpath.safety import check_positions, cloud_blocked

    if check is None:
        return None
    frame, axis, tool, obstacles = check
    if obstacles is None or len(obstacles) == 0:
        return None
    spacing = 0.25 * float(R)
    positions, _ = check_positions(fin.toolpath, safe, spacing)
    return spacing, cloud_blocked(positions, frame, axis, tool, obstacles)


def region_passes(cloud_f: np.ndarray, region_masks: list, faces, fp, R: float, tol: float, safe: float,
                  max_slope_deg: float, progress=None):
    """The finishing passes of one set-up's regions (the step of
    :func:`planning.toolpath.area_paths._add_finishing` that needs no stock): :func:`binned_cloud`,
    then :func:`planning.toolpath.area_paths._region_finishing`. Returns ``(FinishingPath, binned)``."""
    from planning.toolpath.area_paths import _region_finishing

    binned = binned_cloud(cloud_f, faces, R)
    fin = _region_finishing(cloud_f, region_masks, binned, fp, R, tol, safe, max_slope_deg, progress=progress,
                            triangles=binned.triangles)
    return fin, binned


# ------------------------------------------------------------------------------------------ framing

def _write_frame(stream, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)))
    stream.write(data)
    stream.flush()


def _read_exact(stream, n: int) -> bytes:
    chunks, got = [], 0
    while got < n:
        b = stream.read(n - got)
        if not b:
            raise EOFError
        chunks.append(b)
        got += len(b)
    return b"".join(chunks)


def _read_frame(stream):
    (n,) = _HEADER.unpack(_read_exact(stream, _HEADER.size))
    return pickle.loads(_read_exact(stream, n))


def _serve() -> int:
    """The worker's loop: a job per frame on stdin, ``("ok", FinishingPath)`` or ``("error", exc)``
    per frame on stdout, until stdin closes. A job with a semi-finishing part answers it first, in a frame
    of its own (its passes: the same function with the semi-finishing's radius and parameters)."""
    numba.set_num_threads(1)
    src, dst = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr                  # nothing else may write on the answers' stream
    while True:
        try:
            job = _read_frame(src)
        except EOFError:
            return 0
        passes, check = job[0], job[1]
        semi = job[2] if len(job) > 2 else None
        if semi is not None:
            try:
                answer = ("ok", region_passes(*semi)[0])
            except Exception as e:            # noqa: BLE001 - the caller raises it as its own
                answer = ("error", e)
            _write_frame(dst, answer)
        try:
            fin, _ = region_passes(*passes)
            answer = ("ok", (fin, cloud_check(fin, passes[6], passes[4], check)))
        except Exception as e:                # noqa: BLE001 - the caller raises it as its own
            answer = ("error", e)
        _write_frame(dst, answer)


# ------------------------------------------------------------------------------------------ caller

class FinishingWorker:
    """One worker process for the finishing passes of a plan's set-ups (module docstring). Use
    :meth:`open` (None when the worker would not pay or is not allowed), :meth:`submit` when a set-up
    starts, :meth:`passes` when its finishing is due, :meth:`close` at the end."""

    def __init__(self, proc: subprocess.Popen):
        self._proc: subprocess.Popen | None = proc
        self._writer: threading.Thread | None = None
        self._write_error: BaseException | None = None
        self._semi_pending = False             # the job's semi-finishing answer not read yet

    @classmethod
    def open(cls, n_points: int) -> FinishingWorker | None:
        """A worker for a cloud of ``n_points``, or None (fewer than :data:`MIN_POINTS` points, one
        thread, a daemonic process, the environment variable ``SCANMILL_FINISHING_WORKER=0``, or the
        process could not be started)."""
        if os.environ.get("SCANMILL_FINISHING_WORKER", "1").strip() == "0":
            return None
        if n_points < MIN_POINTS or _threads() < 2 or multiprocessing.current_process().daemon:
            return None
        env = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1",
                   PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        try:
            proc = subprocess.Popen([sys.executable, "-m", "planning.toolpath.finishing_worker"],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        except OSError as e:
            _log.info("finishing worker not started (%s): passes computed in this process", e)
            return None
        return cls(proc)

    @property
    def usable(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def submit(self, cloud_f, region_masks, faces, fp, R: float, tol: float, safe: float,
               max_slope_deg: float, check=None, semi=None) -> bool:
        """Start one set-up's passes in the worker (the job is written by a thread: the worker may still
        be starting), and with ``check`` (:func:`cloud_check`'s) the cloud reason of their check;
        ``semi``: ``(region_masks, fp, R, tol, safe)`` of the set-up's semi-finishing passes
        (:mod:`planning.toolpath.semi_finishing`, on the same cloud), computed first and read by
        :meth:`semi_passes`, or None. False when the worker is not usable (compute the passes here)."""
        if not self.usable or self._writer is not None:
            return False
        # region_masks as given: the planner's are IndexMasks, a few MB where the masks themselves would
        # be one byte per cloud point each (the femur-like plan's first set-up: 103 regions, 103 MB)
        cloud = np.ascontiguousarray(cloud_f)
        tri = None if faces is None else np.asarray(faces)
        semi_job = None if semi is None else (cloud, semi[0], tri, semi[1], float(semi[2]), float(semi[3]),
                                              float(semi[4]), float(max_slope_deg))
        job = ((cloud, region_masks, tri, fp, float(R), float(tol), float(safe), float(max_slope_deg)), check,
               semi_job)
        self._semi_pending = semi is not None

        def write():
            try:
                _write_frame(self._proc.stdin, job)
            except BaseException as e:        # noqa: BLE001 - reported by passes()
                self._write_error = e
        self._write_error = None
        self._writer = threading.Thread(target=write, name="finishing-worker-writer", daemon=True)
        self._writer.start()
        return True

    def semi_passes(self, progress: Callable[[float, str], None] | None = None):
        """The semi-finishing passes of the job submitted last (its ``semi`` part; waiting as :meth:`passes`).
        The worker's errors are raised here; :class:`WorkerFailed` when there is no such part or the worker
        died (it is closed; the caller computes the passes itself)."""
        if self._writer is None or not self._semi_pending:
            raise WorkerFailed("no semi-finishing job submitted")
        self._semi_pending = False
        try:
            kind, value = self._answer(progress)
        except WorkerFailed:
            self._writer = None
            raise
        if kind == "error":
            raise value
        return value

    def passes(self, progress: Callable[[float, str], None] | None = None):
        """``(the passes, the cloud reason of their check or None)`` of the job submitted last
        (:func:`region_passes`, :func:`cloud_check`; waiting for them, ``progress(0, ...)`` about
        every second meanwhile). The worker's errors are raised here; :class:`WorkerFailed` when the worker
        died (it is closed; the caller computes the passes itself)."""
        if self._writer is None:
            raise WorkerFailed("no job submitted")
        try:
            if self._semi_pending:             # a semi-finishing answer nobody asked for: read and dropped
                self._semi_pending = False
                self._answer(None)
            kind, value = self._answer(progress)
        finally:
            self._writer = None
        if kind == "error":
            raise value
        return value

    def _answer(self, progress):
        """The next answer frame ``(kind, value)``, waiting for it (``progress(0, ...)`` about every second);
        :class:`WorkerFailed` (the worker closed) when it died or answered nonsense."""
        t0 = time.perf_counter()
        try:
            out = self._proc.stdout
            while not select.select([out], [], [], 1.0)[0]:
                if self._proc.poll() is not None:
                    raise WorkerFailed(f"the worker exited with status {self._proc.returncode}")
                if progress is not None:
                    progress(0.0, f"passes from the worker process ({time.perf_counter() - t0:.0f} s)")
            self._writer.join()
            if self._write_error is not None:
                raise WorkerFailed(f"the job could not be sent: {self._write_error}")
            return _read_frame(out)
        except (EOFError, OSError, pickle.UnpicklingError, struct.error) as e:
            self.close()
            raise WorkerFailed(f"the worker failed: {e!r}") from e
        except WorkerFailed:
            self.close()
            raise

    def close(self) -> None:
        """Close the worker's input (it exits) and wait for it a little; then kill it."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        try:
            proc.stdin.close()
        except OSError:
            pass
        try:
            proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stdout.close()


if __name__ == "__main__":
    raise SystemExit(_serve())
