"""The Celery task that runs one planning job on a worker machine (``scanmill worker``).

A delivery of ``scanmill.plan_job(job_id)`` first claims the job in the job store
(:meth:`service.store.JobStore.claim`): a queued job starts here; a running job whose heartbeat is
older than ``SCANMILL_LEASE_S`` lost its worker and is taken over (this is how a message the broker
delivers again after a worker died finishes the job); a job that runs elsewhere with a fresh
heartbeat, or has ended, is left alone and the message is acknowledged. So however often a message
is delivered, a job is completed at most once: every write of an attempt is fenced by its attempt
number.

While it runs, a heartbeat thread writes to the job store every ``SCANMILL_HEARTBEAT_S``; when the
store says the job is no longer this attempt (cancelled, deleted, or taken over after a network
partition) the child process ends itself at once. Progress is written back to the job store; the
artifacts are written into the attempt's ``work-N`` folder of the shared storage and published
(renamed to ``result``) before the job is marked succeeded.

Memory: an attempt runs under the job memory limit (:func:`service.memlimit.apply_job_memory_limit`,
``SCANMILL_JOB_MEMORY_MB``), set in the pool child when the attempt starts, so that each job of a
child (``SCANMILL_MAX_TASKS_PER_CHILD``) gets its whole budget on top of what the child maps then;
an allocation past it fails the job ``memory_limit_exceeded``, not the machine.

Broker outages: the job needs the broker only to receive its message. A job whose worker lost
the broker keeps running and writing its heartbeat; if the broker hands its message out again
meanwhile, the delivery finds the job ``running`` with a heartbeat that keeps moving and leaves it
alone (``busy``): no attempt is started or counted. Only a holder whose heartbeat stops for
``SCANMILL_LEASE_S`` is taken over.
"""

from __future__ import annotations

import logging
import os
import resource
import shutil
import signal
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any

from celery.exceptions import SoftTimeLimitExceeded
from celery.signals import worker_process_init

from service.celery_app import TASK_NAME, app
from service.memlimit import apply_job_memory_limit, is_memory_exhaustion, memory_limit_message
from service.settings import Settings, load_settings
from service.storage import Storage
from service.store import JobRecord, JobStore
from service.workers import (
    ArtifactWriteError,
    complete_attempt,
    error_of,
    job_spec,
    overall_progress,
    pin_thread_env,
    plan_attempt,
    time_limit_message,
)

log = logging.getLogger("scanmill.worker")


@dataclass
class _Context:
    settings: Settings
    store: JobStore
    storage: Storage
    pid: int


_CTX: _Context | None = None


def context() -> _Context:
    """This process's settings, job store and storage (made anew in each child process)."""
    global _CTX
    if _CTX is None or _CTX.pid != os.getpid():
        settings = getattr(app.conf, "scanmill_settings", None) or load_settings()
        from service.db import database_url
        store = JobStore(database_url(settings.database_url, settings.data_dir), migrate=False)
        # paths only: the worker never locks or sweeps the directory the API serves
        storage = Storage(settings.data_dir)
        _CTX = _Context(settings, store, storage, os.getpid())
    return _CTX


@worker_process_init.connect
def _child_init(**_: Any) -> None:
    """In each pool child: die with the worker's main process, pin BLAS threads, no inherited connections."""
    global _CTX
    _CTX = None
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL, 0, 0, 0)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # pragma: no cover - not Linux/glibc
        pass
    settings = getattr(app.conf, "scanmill_settings", None)
    threads = settings.threads_per_job if settings else 1
    pin_thread_env(threads)
    effective: dict[str, int] = {}
    try:
        from threadpoolctl import threadpool_info, threadpool_limits
        threadpool_limits(threads)
        effective = {i.get("internal_api", "?"): int(i.get("num_threads", 0)) for i in threadpool_info()}
    except Exception:  # noqa: BLE001 - pinning is best effort; the environment is already set
        pass
    try:
        import numba
        effective["numba"] = int(numba.config.NUMBA_NUM_THREADS)
    except Exception:  # noqa: BLE001 - numba not loaded in this process
        pass
    log.info("pool child %d: %d thread(s) per job; effective: %s", os.getpid(), threads,
             ", ".join(f"{k}={v}" for k, v in sorted(effective.items())) or "-")


class _Progress:
    """The pipeline's progress callback: writes (throttled) overall progress to the job store."""

    def __init__(self, store: JobStore, job: JobRecord, min_interval_s: float = 0.5):
        self.store, self.job, self.min_interval_s = store, job, min_interval_s
        self.stage: str | None = None
        self.last = 0.0
        self.progress = 0.0

    def __call__(self, stage: str, fraction: float, message: str = "") -> None:
        now = time.monotonic()
        if stage == self.stage and 0.0 < fraction < 1.0 and now - self.last < self.min_interval_s:
            return
        self.stage, self.last = stage, now
        p = overall_progress(stage, fraction)
        self.progress = self.progress if p is None else max(self.progress, p)
        try:
            self.store.update_progress(self.job.id, self.job.attempts, stage, self.progress, str(message)[:300])
        except Exception:  # noqa: BLE001 - progress is advisory; the heartbeat decides about the attempt
            log.warning("job %s: could not write progress", self.job.id, exc_info=True)


def _heartbeat(store: JobStore, job: JobRecord, every_s: float, stop: threading.Event) -> None:
    """Beat until ``stop``; end this process at once if the job is no longer this attempt."""
    while not stop.wait(every_s):
        try:
            alive = store.heartbeat(job.id, job.attempts)
        except Exception:  # noqa: BLE001 - the database may be back on the next beat
            log.warning("job %s: heartbeat not written", job.id, exc_info=True)
            continue
        if not alive and not stop.is_set():
            log.warning("job %s: no longer attempt %d here (cancelled, deleted or taken over); stopping",
                        job.id, job.attempts)
            os.kill(os.getpid(), signal.SIGKILL)


def _wait_for_holder(ctx: _Context, job: JobRecord, worker: str) -> tuple[str, JobRecord | None]:
    """The job runs elsewhere with a fresh heartbeat: see whether that holder is alive or gone.

    A redelivered message can reach us a moment after its previous holder died (its last heartbeat
    still fresh). Watch the heartbeat for up to a lease: if it moves, the holder is alive ('busy');
    if it goes stale, take the job over.
    """
    s = ctx.settings
    first = job.heartbeat_at
    for _ in range(int((s.lease_s + 2 * s.heartbeat_s) / 0.5) + 2):
        time.sleep(0.5)
        outcome, current = ctx.store.claim(job.id, worker, lease_s=s.lease_s, max_attempts=s.max_attempts)
        if outcome != "busy":
            return outcome, current
        if current is not None and current.heartbeat_at != first:
            return "busy", current
    return "busy", job


@app.task(name=TASK_NAME, bind=True)
def plan_job(self, job_id: str) -> str:
    """Run job ``job_id`` (see the module docstring); returns what this delivery did."""
    ctx = context()
    s = ctx.settings
    worker = f"{self.request.hostname or socket.gethostname()}/{os.getpid()}"
    outcome, job = ctx.store.claim(job_id, worker, lease_s=s.lease_s, max_attempts=s.max_attempts)
    if outcome == "busy" and job is not None:
        outcome, job = _wait_for_holder(ctx, job, worker)
    if outcome == "exhausted":
        log.warning("job %s: its worker was lost and it had been started %d time(s): failed (worker_lost)",
                    job_id, job.attempts if job else -1)
        return outcome
    if outcome not in ("claimed", "taken_over") or job is None:
        log.info("job %s: delivery %s: nothing to do (%s)", job_id,
                 "redelivered" if (self.request.delivery_info or {}).get("redelivered") else "new", outcome)
        return outcome
    log.info("job %s: attempt %d %s on %s", job.id, job.attempts,
             "started" if outcome == "claimed" else "took over from a lost worker", worker)
    return _run_attempt(ctx, job)


def _limit_memory(job: JobRecord, limit_mb: int) -> tuple[int, int] | None:
    """Put this pool child under the job memory limit (at each attempt: the budget is per job).

    Returns the address-space limit the child had before, for :func:`_lift_memory_limit`.
    """
    before = resource.getrlimit(resource.RLIMIT_AS) if hasattr(resource, "RLIMIT_AS") else None
    try:
        cap = apply_job_memory_limit(limit_mb)
    except (OSError, ValueError) as exc:          # e.g. a hard limit below what the child already maps
        log.warning("job %s: the job memory limit (%d MiB) could not be applied: %s", job.id, limit_mb, exc)
        return None
    if cap is None:
        log.warning("job %s: no job memory limit on this platform (SCANMILL_JOB_MEMORY_MB = %d MiB not applied)",
                    job.id, limit_mb)
        return None
    log.info("job %s: memory limit %d MiB (address space capped at %d MiB)", job.id, limit_mb, cap >> 20)
    return before


def _lift_memory_limit(before: tuple[int, int] | None) -> None:
    """The attempt is over: give the child back its own limit (writing the outcome must not hit the job's)."""
    if before is not None:
        try:
            resource.setrlimit(resource.RLIMIT_AS, before)
        except (OSError, ValueError):  # pragma: no cover - raising a soft limit up to the hard one is allowed
            log.warning("could not lift the job memory limit", exc_info=True)


def _run_attempt(ctx: _Context, job: JobRecord) -> str:
    store, storage, s = ctx.store, ctx.storage, ctx.settings
    spec = job_spec(job, s, storage)
    storage.remove_work(job.id, job.attempts)
    limit_mb = s.job_memory_limit_mb
    before = _limit_memory(job, limit_mb)
    stop = threading.Event()
    beat = threading.Thread(target=_heartbeat, args=(store, job, s.heartbeat_s, stop), daemon=True,
                            name=f"heartbeat-{job.id[:8]}")
    beat.start()
    try:
        try:
            summary, warnings = plan_attempt(spec, _Progress(store, job))
        finally:
            _lift_memory_limit(before)
    except SoftTimeLimitExceeded:
        stop.set()
        storage.remove_work(job.id, job.attempts)
        store.fail(job.id, job.attempts, "time_limit_exceeded", time_limit_message(job.time_limit_s))
        log.info("job %s: stopped at its time limit", job.id)
        return "time_limit_exceeded"
    except Exception as exc:  # noqa: BLE001 - every failure becomes a job error with a reason
        stop.set()
        storage.remove_work(job.id, job.attempts)
        if is_memory_exhaustion(exc):
            store.fail(job.id, job.attempts, "memory_limit_exceeded", memory_limit_message(limit_mb))
            log.warning("job %s: failed [memory_limit_exceeded]: it needed more than its %d MiB (%s)", job.id,
                        limit_mb, type(exc).__name__)
            return "memory_limit_exceeded"
        code, message = error_of(exc)
        store.fail(job.id, job.attempts, code, message)
        log.info("job %s: failed [%s] %s", job.id, code, message)
        return "failed"
    finally:
        stop.set()
    try:
        completed = complete_attempt(store, storage, job, summary, warnings)
    except ArtifactWriteError as exc:          # a full disk while publishing: the job says so
        store.fail(job.id, job.attempts, exc.code, exc.message)
        log.warning("job %s: failed [%s] %s", job.id, exc.code, exc.message)
        return "failed"
    if not completed:
        log.info("job %s: attempt %d finished but the job changed meanwhile; its artifacts were dropped",
                 job.id, job.attempts)
        return "discarded"
    for stale in storage.job_dir(job.id).glob("work-*"):       # earlier attempts' leftovers (dead workers)
        shutil.rmtree(stale, ignore_errors=True)
    log.info("job %s: succeeded on attempt %d (%s)", job.id, job.attempts, summary.get("message"))
    return "succeeded"
