"""The finishing passes of a set-up, and the roughing of the next one, computed in a second process
(issue 30 item 3, "every core"; ``docs/design.md`` "Stock-first planning").

A set-up's finishing passes (:func:`planning.toolpath.area_paths._region_finishing`: ball drop on the
cloud, the passes made gouge safe and joined) depend on the cloud in the set-up's frame, the area's
regions, the points handed on by the set-ups before and the safe height, all known when the set-up
starts; they do not depend on the stock. A set-up's roughing depends on the stock as the roughing of
the set-up before left it (:func:`planning.toolpath.area_paths.plan_roughing`; not on that set-up's
finishing, which only takes material off within the part's allowance band), so it can be planned while
the main process finishes the set-up before (cuts the blocked CL points out and runs the finishing on
the stock). Both are mostly Python; threads would share one interpreter lock, a process does not. So
:class:`FinishingWorker` takes the first set-up's passes while the main process roughs it, and each
next set-up's roughing as soon as the set-up before is roughed and guarded; a set-up's passes go to the
worker only when it is idle (else the main process computes them while the worker roughs). The
results are the same functions of the same inputs, so the plan does not change (the tests compare).
Jobs run one at a time in the order they were sent; the answers come back in that order.

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
import queue
import select
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable

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


class _FdReader:
    """Reads a pipe's file descriptor with no buffer of its own: a buffered reader may take the next
    answer's bytes in with the current one, where ``select`` on the descriptor no longer sees them."""

    def __init__(self, fd: int):
        self.fd = fd

    def read(self, n: int) -> bytes:
        return os.read(self.fd, min(n, 1 << 24))


def _serve() -> int:
    """The worker's loop: a job per frame on stdin (``("passes", (passes, check))`` or
    ``("roughing", keyword arguments of plan_roughing)``), ``("ok", answer)`` or ``("error", exc)``
    per frame on stdout in the same order, until stdin closes."""
    numba.set_num_threads(1)
    src, dst = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr                  # nothing else may write on the answers' stream
    while True:
        try:
            kind, job = _read_frame(src)
        except EOFError:
            return 0
        try:
            if kind == "roughing":
                from planning.toolpath.area_paths import plan_roughing

                answer = ("ok", plan_roughing(**job))
            else:
                passes, check = job
                fin, _ = region_passes(*passes)
                answer = ("ok", (fin, cloud_check(fin, passes[6], passes[4], check)))
        except Exception as e:                # noqa: BLE001 - the caller raises it as its own
            answer = ("error", e)
        _write_frame(dst, answer)


# ------------------------------------------------------------------------------------------ caller

class FinishingWorker:
    """One worker process for the finishing passes of a plan's set-ups and the roughing of the next
    set-up (module docstring). Use :meth:`open` (None when the worker would not pay or is not
    allowed), :meth:`submit` when a set-up starts and :meth:`passes` when its finishing is due,
    :meth:`submit_roughing` when a set-up's roughing is guarded and :meth:`roughing` when the next
    set-up starts, :meth:`close` at the end. Jobs run one at a time in the order they were
    submitted."""

    def __init__(self, proc: subprocess.Popen):
        self._proc: subprocess.Popen | None = proc
        self._queue: queue.Queue = queue.Queue()
        self._writer: threading.Thread | None = None
        self._write_error: BaseException | None = None
        self._sent = 0                     # jobs handed to the writer
        self._read = 0                     # answers read
        self._answers: dict[int, tuple] = {}
        self._passes_ticket: int | None = None

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

    def _send(self, kind: str, job) -> int | None:
        """Queue one job for the writer thread (the worker may still be starting, or busy: the pipe
        fills); its ticket, or None when the worker is not usable."""
        if not self.usable or self._write_error is not None:
            return None
        if self._writer is None:
            proc, q = self._proc, self._queue

            def write():
                while True:
                    frame = q.get()
                    if frame is None:
                        return
                    try:
                        _write_frame(proc.stdin, frame)
                    except BaseException as e:        # noqa: BLE001 - reported by _wait()
                        self._write_error = e
                        return
            self._writer = threading.Thread(target=write, name="finishing-worker-writer", daemon=True)
            self._writer.start()
        self._queue.put((kind, job))
        self._sent += 1
        return self._sent - 1

    def submit(self, cloud_f, region_masks, faces, fp, R: float, tol: float, safe: float,
               max_slope_deg: float, check=None) -> bool:
        """Start one set-up's passes in the worker, and with ``check`` (:func:`cloud_check`'s) the cloud
        reason of their check; False when the worker is not usable or a set-up's passes are still
        due (compute the passes here)."""
        if self._passes_ticket is not None:
            return False
        job = ((np.ascontiguousarray(cloud_f), list(region_masks), None if faces is None else np.asarray(faces),
                fp, float(R), float(tol), float(safe), float(max_slope_deg)), check)
        self._passes_ticket = self._send("passes", job)
        return self._passes_ticket is not None

    def submit_roughing(self, **job) -> int | None:
        """Start a set-up's roughing in the worker (:func:`planning.toolpath.area_paths.plan_roughing`'s
        keyword arguments); its ticket for :meth:`roughing`, or None when the worker is not usable."""
        return self._send("roughing", job)

    def passes(self, progress: Callable[[float, str], None] | None = None):
        """``(the passes, the cloud reason of their check or None)`` of the passes submitted last
        (:func:`region_passes`, :func:`cloud_check`; waiting for them, ``progress(0, ...)`` about
        every second meanwhile). The worker's errors are raised here; :class:`WorkerFailed` when the worker
        died (it is closed; the caller computes the passes itself)."""
        if self._passes_ticket is None:
            raise WorkerFailed("no job submitted")
        ticket, self._passes_ticket = self._passes_ticket, None
        return self._wait(ticket, progress, "passes")

    def roughing(self, ticket: int, progress: Callable[[float, str], None] | None = None):
        """The answer of the roughing job ``ticket`` (:meth:`submit_roughing`; waiting for it as
        :meth:`passes` does, errors likewise)."""
        return self._wait(ticket, progress, "roughing")

    def busy(self) -> bool:
        """Whether a job submitted is not answered yet (the answers already written are read in, so the
        test does not wait): the caller then computes a set-up's passes itself rather than queue them
        behind the next set-up's roughing. False when the worker is not usable."""
        if not self.usable:
            return False
        out = self._proc.stdout
        try:
            while self._read < self._sent and select.select([out], [], [], 0.0)[0]:
                self._answers[self._read] = _read_frame(_FdReader(out.fileno()))
                self._read += 1
        except (EOFError, OSError, pickle.UnpicklingError, struct.error):
            self.close()
            return False
        return self._read < self._sent

    def _wait(self, ticket: int, progress, what: str):
        t0 = time.perf_counter()
        try:
            out = self._proc.stdout if self._proc is not None else None
            while ticket not in self._answers:
                if out is None:
                    raise WorkerFailed("the worker was closed")
                if self._write_error is not None:
                    raise WorkerFailed(f"a job could not be sent: {self._write_error}")
                if not select.select([out], [], [], 1.0)[0]:
                    if self._proc.poll() is not None:
                        raise WorkerFailed(f"the worker exited with status {self._proc.returncode}")
                    if progress is not None:
                        progress(0.0, f"{what} from the worker process ({time.perf_counter() - t0:.0f} s)")
                    continue
                self._answers[self._read] = _read_frame(_FdReader(out.fileno()))
                self._read += 1
        except (EOFError, OSError, pickle.UnpicklingError, struct.error) as e:
            self.close()
            raise WorkerFailed(f"the worker failed: {e!r}") from e
        except WorkerFailed:
            self.close()
            raise
        kind, value = self._answers.pop(ticket)
        if kind == "error":
            raise value
        return value

    def close(self) -> None:
        """Close the worker's input (it exits) and wait for it a little; then kill it."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        if self._writer is not None:
            self._queue.put(None)
            self._writer.join(timeout=5.0)
            if self._writer.is_alive():
                # still writing a job the worker does not read (it waits to write an answer nobody reads
                # any more): closing its input would wait for the writer's lock; end the worker first
                proc.kill()
                self._writer.join()
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
