"""Workers: each job runs ``planning.pipeline`` in its own process, never on the event loop.

:class:`JobRunner` lives in the server process. A dispatcher thread claims queued jobs from the
store while fewer than ``SCANMILL_WORKERS`` run, and starts one worker process per job from a
``forkserver`` (the planning modules are imported once in the fork server, so a job starts in
milliseconds; ``spawn`` is the fallback). A supervisor thread per running job relays the worker's
progress into the store, enforces the job's time limit, and publishes the artifacts when the
worker reports success. Cancelling a job kills its process (SIGKILL) and waits until it is gone.
At start, unless the numba cache already holds this code's kernels (:func:`planning.warmup.is_warm`,
e.g. after ``scanmill warmup``), a first worker process compiles them with a small plan and the queued
jobs wait for it, so that no job pays the compilation (``/healthz`` answers meanwhile).

Worker processes pin their BLAS/OpenMP pools (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
``MKL_NUM_THREADS``, ... = ``SCANMILL_WORKER_THREADS``; set before numpy is imported in the fork
server) and die with the server: a watchdog thread sees the progress pipe close when the server
exits or is killed (plus a parent-death signal and a parent-pid check), so a killed server leaves
no job running; at the next start the store's
recovery re-queues or fails what was running (see :meth:`JobRunner.recover`).

The worker function only calls ``planning.inputs.cloud.read_input``, ``planning.pipeline.run_plan`` and
``planning.report.plan_files.write_plan``: the service holds no geometry.

Holding under pressure (issue 13):

* **Memory.** Each job process runs under an address-space limit of ``SCANMILL_JOB_MEMORY_MB``
  (:mod:`service.memlimit`); a job that needs more fails alone with ``memory_limit_exceeded`` and
  the limit named, and the host never runs out of memory because of it.
* **Disk.** Before a job starts, the free space of the data directory is checked against the
  artifacts it will write plus ``SCANMILL_MIN_FREE_DISK_MB`` (:func:`service.diskspace.check_free_space`);
  short of it the job fails at once with ``insufficient_storage``. A write of the artifacts that
  fails ends the job ``disk_full`` (ENOSPC, EDQUOT; the free space named) or
  ``artifact_write_failed``, its partial files removed.
* **Store.** A job store write that ends an attempt is retried with backoff
  (:data:`STORE_RETRY_DELAYS_S`); if it still fails, the outcome is kept in memory and retried by
  the dispatcher until the store takes it, and written next to the job's files
  (``jobs/ID/outcome-N.json``), where :meth:`JobRunner.recover` finds it at the next start and
  settles the job with that outcome instead of running it again. No job stays ``running`` without
  a worker once the store answers again, or after a restart.
"""

from __future__ import annotations

import contextlib
import errno
import gc
import json
import logging
import multiprocessing
import multiprocessing.connection
import os
import select
import shutil
import signal
import sys
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy.exc import SQLAlchemyError

from planning.errors import PlanningError
from schemas.api import JOB_STAGES
from schemas.plan import PlanResult
from service.diskspace import InsufficientStorage, check_free_space, free_bytes
from service.memlimit import applied_limit_mb, apply_job_memory_limit, is_memory_exhaustion, memory_limit_message
from service.settings import Settings
from service.storage import Storage, atomic_write_bytes
from service.store import JobRecord, JobStore

if TYPE_CHECKING:
    from planning.inputs.cloud import Cloud
    from schemas.params import PlanConfig

log = logging.getLogger("scanmill.service")

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "BLIS_NUM_THREADS", "NUMBA_NUM_THREADS")
#: Modules the fork server imports once, so that every worker starts with them loaded.
PRELOAD = ["numpy", "planning.inputs.cloud", "planning.pipeline", "planning.report.plan_files", "schemas.params"]
#: What :func:`pin_thread_env` sets: the thread counts, and the finishing worker turned off.
PINNED_VARS = (*THREAD_VARS, "SCANMILL_FINISHING_WORKER")

#: Share of the whole job each stage stands for (for ``progress`` 0..1); rough, from the benchmarks.
# Share of a job's time per stage, from the femur-like plan of `make run` (2026-11-25, plan.json timings:
# visibility 25 s, setups 3, areas 2, paths 58, post 1.5, simulate 43 s on a first run whose kernels
# compiled, about 12 s warm; BENCHMARKS.md): the tool paths take about 45 %, the simulation 15-30 %.
STAGE_WEIGHTS = {"read": 0.02, "normals": 0.02, "placement": 0.04, "orientations": 0.01, "visibility": 0.18,
                 "setups": 0.03, "areas": 0.02, "paths": 0.40, "post": 0.02, "simulate": 0.18, "write": 0.08}
_STAGE_START = {s: sum(STAGE_WEIGHTS[t] for t in JOB_STAGES[:i]) for i, s in enumerate(JOB_STAGES)}


def overall_progress(stage: str, fraction: float) -> float | None:
    """Fraction of the whole job done when ``stage`` is ``fraction`` done (None for a stage not listed)."""
    if stage not in STAGE_WEIGHTS:
        return None
    f = max(0.0, min(1.0, float(fraction)))
    return round(min(1.0, _STAGE_START[stage] + STAGE_WEIGHTS[stage] * f), 4)


def plan_summary(r: PlanResult) -> dict[str, Any]:
    """The job's ``result`` headline (:class:`schemas.api.JobResultSummary` fields) of a finished plan."""
    v = r.verification
    return {"status": r.status, "message": r.message, "n_setups": len(r.setups),
            "coverage": float(r.coverage), "overlap_points": int(r.overlap_points),
            "verification": v.status if v is not None else None,
            "verification_message": v.message if v is not None else None,
            "finished_share": r.figures.finished_share if r.figures is not None else None,
            "machining_time_s": r.figures.machining_time_s if r.figures is not None else None,
            "time_source": r.figures.time_source if r.figures is not None else None}


def read_job_cloud(path: str | os.PathLike, fmt: str | None, config: PlanConfig, max_points: int) -> Cloud:
    """Read a job's cloud with its configuration's input limits, ``max_points`` capped by the service's.

    Submission validates the cloud with this very call, so the worker reads it the same way.
    """
    from planning.inputs.cloud import read_input
    return read_input(path, config.input, fmt=fmt, max_points=max_points)


def pin_thread_env(threads: int, env: dict[str, str] | None = None) -> None:
    """Set the BLAS/OpenMP thread-count variables (in ``os.environ`` by default), and keep a job's
    finishing passes in its own process (``SCANMILL_FINISHING_WORKER=0``,
    :mod:`planning.toolpath.finishing_worker`): a job keeps to its thread budget and to the memory
    the admission estimated for one process."""
    target = os.environ if env is None else env
    for var in THREAD_VARS:
        target[var] = str(int(threads))
    target["SCANMILL_FINISHING_WORKER"] = "0"


# ---------------------------------------------------------------------------------------------
# the worker process
# ---------------------------------------------------------------------------------------------

def _die_with_parent(conn) -> None:
    """End this worker as soon as the server is gone, whatever the process tree looks like.

    A watchdog thread waits for the far end of the progress pipe to close (POLLERR on our write end:
    the server exited or was killed) and checks the parent pid once a second; on Linux the process
    also asks for SIGKILL when its parent dies (PR_SET_PDEATHSIG).
    """
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)   # PR_SET_PDEATHSIG
        except (OSError, AttributeError):  # pragma: no cover - not Linux/glibc
            pass
    fd = conn.fileno()

    def watchdog() -> None:
        poller = select.poll()
        poller.register(fd, select.POLLERR | select.POLLHUP)
        while True:
            if poller.poll(1000) or os.getppid() != parent:
                os._exit(70)

    threading.Thread(target=watchdog, name="server-watchdog", daemon=True).start()


class _Reporter:
    """The pipeline's ``progress`` callback in the worker: sends (throttled) progress to the server."""

    def __init__(self, conn):
        self.conn = conn
        self.stage: str | None = None
        self.last = 0.0

    def __call__(self, stage: str, fraction: float, message: str = "") -> None:
        now = time.monotonic()
        if stage == self.stage and 0.0 < fraction < 1.0 and now - self.last < 0.1:
            return
        self.stage, self.last = stage, now
        self.conn.send(("progress", str(stage), float(fraction), str(message)[:300]))


def plan_attempt(spec: dict[str, Any], report) -> tuple[dict[str, Any], list[str]]:
    """One attempt of a job, in whatever process runs it: read the stored cloud, plan, write the artifacts.

    ``spec`` holds ``parameters``, ``input_path``, ``fmt``, ``max_points``, ``work_dir`` (where the
    artifacts go), ``name`` and ``start_delay_s``; ``report(stage, fraction, message)`` receives the
    progress. Returns the result summary and the plan's warnings; raises what the planning raises
    (see :func:`error_of`).
    """
    from planning.pipeline import run_plan
    from planning.report.plan_files import write_plan
    from schemas.params import parse_config

    report("read", 0.0, "reading the cloud")
    if spec.get("start_delay_s"):
        time.sleep(float(spec["start_delay_s"]))
    config = parse_config(spec["parameters"])
    cloud = read_job_cloud(spec["input_path"], spec.get("fmt"), config, spec["max_points"])
    report("read", 1.0, f"{cloud.points.shape[0]} points ({cloud.source_format})")
    outcome = run_plan(cloud, config, name=spec.get("name"), progress=report)
    report("write", 0.0, "writing the artifacts")
    work = Path(spec["work_dir"])
    try:
        work.mkdir(parents=True, exist_ok=True)
        write_plan(outcome, work, progress=lambda f, m: report("write", f, m))
    except OSError as exc:
        raise ArtifactWriteError.of(exc, work) from exc
    report("write", 1.0, "artifacts written")
    r = outcome.result
    return plan_summary(r), list(r.warnings)


class ArtifactWriteError(Exception):
    """Writing or publishing a job's artifacts failed: ``code`` ``disk_full`` (no space, quota) or
    ``artifact_write_failed`` (any other file system error), and a ``message`` for the client."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code, self.message = code, message

    @classmethod
    def of(cls, exc: OSError, where: str | os.PathLike) -> ArtifactWriteError:
        """The job error of ``exc``, raised while writing under ``where`` (the free space there is named)."""
        try:
            free = f"{free_bytes(where) / (1 << 20):,.0f} MiB"
        except OSError:
            free = "an unknown amount"
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return cls("disk_full",
                       f"the artifacts could not be written: the data directory's disk is full "
                       f"({os.strerror(exc.errno)}; {free} free). Nothing of this attempt was kept. Free space "
                       "under SCANMILL_DATA_DIR (delete finished jobs) and submit the job again.")
        reason = exc.strerror or type(exc).__name__
        return cls("artifact_write_failed",
                   f"the artifacts could not be written ({reason}; {free} free in the data directory). Nothing "
                   "of this attempt was kept; submit the job again, and tell the operator if it keeps failing.")


def error_of(exc: BaseException) -> tuple[str, str]:
    """The job error (code, message) of an exception an attempt raised (unexpected ones are logged).

    Running out of memory is ``memory_limit_exceeded`` (with the limit) where this process runs under
    :func:`service.memlimit.apply_job_memory_limit`, ``out_of_memory`` otherwise; a failed write of
    the artifacts is ``disk_full`` or ``artifact_write_failed`` (:class:`ArtifactWriteError`).
    """
    if isinstance(exc, PlanningError):
        return exc.code, exc.message
    if isinstance(exc, ArtifactWriteError):
        return exc.code, exc.message
    limit = applied_limit_mb()
    if limit is not None and is_memory_exhaustion(exc):
        return "memory_limit_exceeded", memory_limit_message(limit)
    if isinstance(exc, MemoryError):
        return "out_of_memory", ("the plan needed more memory than the service has; decimate the cloud and "
                                 "submit it again")
    traceback.print_exception(exc, file=sys.stderr)
    return "internal_error", f"the planning failed unexpectedly: {type(exc).__name__}: {exc}"


def run_job(spec: dict[str, Any], conn) -> None:
    """Embedded worker entry point: :func:`plan_attempt` with progress sent over ``conn`` to the server.

    The process first caps its address space at ``spec["memory_limit_mb"]`` MiB more than it maps
    (:func:`service.memlimit.apply_job_memory_limit`). Sends ``("progress", stage, fraction,
    message)`` while it runs and ends with one ``("done", summary, warnings)`` or ``("error", code,
    message)``.
    """
    _die_with_parent(conn)
    pin_thread_env(spec["threads"])
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # Ctrl-C in the terminal goes to the server, which stops us
    if spec.get("memory_limit_mb"):
        apply_job_memory_limit(int(spec["memory_limit_mb"]))
    try:
        try:
            summary, warnings = plan_attempt(spec, _Reporter(conn))
            outcome: tuple = ("done", summary, warnings)
        except Exception as exc:  # noqa: BLE001 - every failure becomes a job error with a reason
            outcome = ("error", *error_of(exc))
        # the exception and its frames (the job's arrays) are gone here: memory to send the outcome
        gc.collect()
        conn.send(outcome)
    finally:
        conn.close()


def time_limit_message(limit_s: float) -> str:
    """The error message of a job stopped at its time limit (code ``time_limit_exceeded``)."""
    return (f"the job ran longer than its time limit of {limit_s:g} s and was stopped (time_limit_s, at most "
            "SCANMILL_JOB_TIME_LIMIT_S); decimate the cloud or coarsen the orientations and submit it again")


def complete_attempt(store: JobStore, storage: Storage, job: JobRecord, summary: dict[str, Any],
                     warnings: list[str]) -> bool:
    """Publish an attempt's artifacts and mark the job succeeded, for that attempt only.

    If the job is no longer that attempt (cancelled, deleted, taken over) the artifacts are dropped
    instead. The job's own warnings (from submission) come first. True if the job succeeded.
    Raises :class:`ArtifactWriteError` when the artifacts cannot be published (the attempt's files
    are removed), and the store's errors when it cannot be written.
    """
    warnings = list(job.warnings) + [w for w in warnings if w not in job.warnings]
    if store.status_of(job.id) != ("running", job.attempts):
        storage.remove_work(job.id, job.attempts)
        return False
    try:
        storage.publish_result(job.id, job.attempts)
    except OSError as exc:
        storage.remove_work(job.id, job.attempts)
        raise ArtifactWriteError.of(exc, storage.job_dir(job.id)) from exc
    if not store.succeed(job.id, job.attempts, summary, warnings, stored_bytes=storage.job_bytes(job.id)):
        # cancelled between the check and now: its files go with it
        shutil.rmtree(storage.result_dir(job.id), ignore_errors=True)
        return False
    return True


def job_spec(job: JobRecord, settings: Settings, storage: Storage) -> dict[str, Any]:
    """What :func:`plan_attempt` needs to run the current attempt of ``job``."""
    return {
        "job_id": job.id, "attempt": job.attempts, "parameters": job.parameters,
        "input_path": str(storage.job_dir(job.id) / job.input["path"]), "fmt": job.input.get("fmt"),
        "name": job.input.get("name"), "work_dir": str(storage.work_dir(job.id, job.attempts)),
        "max_points": settings.max_points, "threads": settings.threads_per_job,
        "start_delay_s": settings.worker_start_delay_s, "memory_limit_mb": settings.job_memory_limit_mb,
    }


def job_artifact_bytes(job: JobRecord) -> int:
    """About how many bytes the artifacts of ``job`` will take (:func:`planning.budget.estimate_artifact_bytes`)."""
    from planning.budget import estimate_artifact_bytes
    from schemas.params import parse_config
    try:
        config = parse_config(job.parameters)
    except Exception:  # noqa: BLE001 - the parameters were validated at submission; the worker reports it
        return 0
    n = int(job.input.get("n_points") or 0)
    extent = job.input.get("extent_mm")
    return estimate_artifact_bytes(n, config, extent_mm=extent)


def check_job_disk(settings: Settings, storage: Storage, job: JobRecord) -> tuple[str, str] | None:
    """Before an attempt starts: ``("insufficient_storage", message)`` when its artifacts would not fit
    above ``SCANMILL_MIN_FREE_DISK_MB`` on the data directory's file system, else None."""
    try:
        check_free_space(settings, job_artifact_bytes(job), f"the artifacts of job {job.id}",
                         path=storage.job_dir(job.id))
    except InsufficientStorage as exc:
        return exc.code, (f"the job was not started: {exc.detail[0].lower()}{exc.detail[1:]} "
                          "Submit it again once there is room.")
    except OSError as exc:       # the file system cannot even be asked: let the attempt find out
        log.warning("job %s: could not check the free disk space: %s", job.id, exc)
    return None


def outcome_path(storage: Storage, job_id: str, attempt: int) -> Path:
    """Where an attempt's outcome is kept when the job store could not record it (``jobs/ID/outcome-N.json``)."""
    return storage.job_dir(job_id) / f"outcome-{int(attempt)}.json"


def read_outcome(storage: Storage, job: JobRecord) -> dict[str, Any] | None:
    """The outcome recorded for the job's current attempt by :meth:`JobRunner._fail`, or None."""
    try:
        doc = json.loads(outcome_path(storage, job.id, job.attempts).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("attempt") != job.attempts or doc.get("op") != "fail":
        return None
    if not isinstance(doc.get("code"), str) or not isinstance(doc.get("message"), str):
        return None
    return doc


def _noop() -> None:
    """Started once at startup so the fork server is up (and has imported the planning code) early."""


def _warm_kernels() -> None:
    """Started once at startup, in place of :func:`_noop`, when the numba cache does not hold this code's
    kernels: compile them (:func:`planning.warmup.warm`, a small plan) before the first job, which then
    loads them. A process of its own: the fork server never runs a kernel (GNU OpenMP is not fork-safe)."""
    from planning.warmup import warm
    rep = warm()
    print(f"scanmill serve: kernels warm in {rep.seconds:.1f} s ({rep.n_compiled} compiled; cache {rep.cache_dir})",
          file=sys.stderr, flush=True)


# ---------------------------------------------------------------------------------------------
# the runner in the server
# ---------------------------------------------------------------------------------------------

@dataclass
class _Active:
    job: JobRecord
    process: Any
    conn: Any
    done: threading.Event = field(default_factory=threading.Event)
    killed_for: str | None = None       # 'cancel', 'shutdown' or 'time_limit' once killed by us


@dataclass
class _Unsettled:
    """An attempt's end the job store has not taken yet: ``write()`` records it (idempotent)."""

    job_id: str
    attempt: int
    what: str                           # 'failed [code]' or 'succeeded', for the log
    write: Any
    next_try: float
    delay: float


@dataclass
class _AttemptRef:
    """The job id and attempt of a job (what :meth:`JobRunner._fail` needs of a :class:`JobRecord`)."""

    id: str
    attempts: int


#: Longest the dispatcher holds the queue at start while the kernels compile (a cold cache: 1-3 min).
WARMUP_TIMEOUT_S = 900.0
#: Waits (seconds) between the tries of a job store write that ends an attempt (then kept for later).
STORE_RETRY_DELAYS_S = (0.2, 0.5, 1.0, 2.0)
#: Longest wait between two later tries of an unsettled outcome (the dispatcher retries it).
UNSETTLED_MAX_DELAY_S = 30.0


class JobRunner:
    """The embedded execution backend: runs queued jobs in worker processes of this server, at most
    ``settings.workers`` at once (see :class:`service.backends.ExecutionBackend`)."""

    name = "embedded"

    def __init__(self, settings: Settings, store: JobStore, storage: Storage):
        self.settings, self.store, self.storage = settings, store, storage
        self._active: dict[str, _Active] = {}
        self._unsettled: dict[str, _Unsettled] = {}
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._dispatcher: threading.Thread | None = None
        self._ctx = None

    # -- lifecycle -------------------------------------------------------------------------------
    def start(self) -> None:
        """Pin worker threads, start the fork server (in the background) and the dispatcher."""
        pin_thread_env(self.settings.threads_per_job)
        method = self.settings.start_method
        if method == "forkserver" and "forkserver" not in multiprocessing.get_all_start_methods():
            method = "spawn"  # pragma: no cover - not on Linux
        self._ctx = multiprocessing.get_context(method)
        if method == "forkserver":
            self._ctx.set_forkserver_preload(PRELOAD)
        self._dispatcher = threading.Thread(target=self._dispatch_loop, name="job-dispatcher", daemon=True)
        self._dispatcher.start()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop taking jobs, kill running workers and put their jobs back in the queue (attempt not counted)."""
        self._stopping.set()
        self._wake.set()
        with self._lock:
            active = list(self._active.values())
        for a in active:
            a.killed_for = a.killed_for or "shutdown"
            self._kill(a)
        for a in active:
            a.done.wait(timeout)
        if self._dispatcher is not None:
            self._dispatcher.join(timeout)
        self._retry_unsettled(force=True)     # a last try; what is left is settled by recover() at the next start

    def wake(self) -> None:
        """A job was queued: let the dispatcher look now."""
        self._wake.set()

    def submitted(self, job: JobRecord) -> None:
        """A job was accepted: the dispatcher claims it from the store."""
        self.wake()

    def cancel(self, job_id: str) -> bool:
        """The job was cancelled in the store: stop its worker if it runs here."""
        return self.kill(job_id, "cancel")

    def health(self) -> dict[str, int]:
        """Worker slots and how many are busy."""
        return {"workers": self.settings.workers, "busy_workers": self.busy}

    @property
    def busy(self) -> int:
        with self._lock:
            return len(self._active)

    @property
    def unsettled(self) -> list[str]:
        """Ids of jobs whose end the job store has not recorded yet (retried by the dispatcher)."""
        with self._lock:
            return sorted(self._unsettled)

    def recover(self) -> dict[str, list[str]]:
        """At start, before any worker runs: settle jobs a previous server left 'running'.

        A job whose attempt ended in an error the store could not record (``jobs/ID/outcome-N.json``)
        fails with that error; one whose attempt had written a complete plan (or published it) succeeds;
        one that has been started ``max_attempts`` times fails with code ``interrupted``; any other is
        queued again. Then folders no job owns are swept. Returns the job ids per outcome (for the log).
        """
        out: dict[str, list[str]] = {"succeeded": [], "requeued": [], "failed": []}
        for job in self.store.running():
            recorded = read_outcome(self.storage, job)
            if recorded is not None:
                self.store.fail(job.id, job.attempts, recorded["code"], recorded["message"])
                outcome_path(self.storage, job.id, job.attempts).unlink(missing_ok=True)
                log.info("job %s: failed [%s] (the outcome its attempt recorded)", job.id, recorded["code"])
                out["failed"].append(job.id)
                continue
            if self._recover_plan(job):
                out["succeeded"].append(job.id)
                continue
            if job.attempts >= self.settings.max_attempts:
                self.store.fail(job.id, job.attempts, "interrupted",
                                f"the service stopped while this job was running, {job.attempts} time(s) "
                                f"(limit SCANMILL_MAX_ATTEMPTS = {self.settings.max_attempts}); it was not "
                                "started again. Submit it again, possibly with a smaller cloud.")
                out["failed"].append(job.id)
            else:
                self.store.requeue(job.id, job.attempts, "queued again after the service restarted")
                out["requeued"].append(job.id)
        self.storage.sweep(self.store.ids())
        return out

    def _recover_plan(self, job: JobRecord) -> bool:
        """Succeed ``job`` from the complete plan its attempt left (in ``work-N``, or already published)."""
        work = self.storage.work_dir(job.id, job.attempts)
        published = self.storage.result_dir(job.id) / "plan.json"
        for path in (work / "plan.json", published):
            if not path.is_file():
                continue
            try:
                r = PlanResult.model_validate(json.loads(path.read_text()))
                summary, warnings = plan_summary(r), list(r.warnings)
                if path == published:     # renamed into place, the store write was lost
                    merged = list(job.warnings) + [w for w in warnings if w not in job.warnings]
                    return self.store.succeed(job.id, job.attempts, summary, merged,
                                      stored_bytes=self.storage.job_bytes(job.id))
                return complete_attempt(self.store, self.storage, job, summary, warnings)
            except Exception:  # noqa: BLE001 - an unreadable plan is simply run again
                log.warning("job %s: the plan left by the interrupted attempt is unreadable; running again",
                            job.id)
                return False
        return False

    # -- store writes that end an attempt --------------------------------------------------------
    def _store_write(self, what: str, fn, *args, **kw):
        """``fn(*args, **kw)`` (a store transition), tried again after each of :data:`STORE_RETRY_DELAYS_S`
        while the store fails (a database error); returns its value, or raises the last error (any other
        error at once)."""
        for i, delay in enumerate((0.0, *STORE_RETRY_DELAYS_S)):
            if delay:
                time.sleep(delay)
            try:
                return fn(*args, **kw)
            except SQLAlchemyError as exc:   # the database or its disk failed: try again
                if i == len(STORE_RETRY_DELAYS_S):
                    raise
                log.warning("%s: the job store write failed (%s); trying again in %g s", what,
                            str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__,
                            STORE_RETRY_DELAYS_S[i])
        raise AssertionError("unreachable")  # pragma: no cover

    def _fail(self, job: JobRecord | _AttemptRef, code: str, message: str) -> None:
        """End the attempt of ``job`` as failed (``code``, ``message``), whatever the store does.

        The write is retried (:meth:`_store_write`); if it still fails, the outcome is written next to
        the job's files (``outcome-N.json``, for :meth:`recover`) and kept for the dispatcher to retry.
        """
        try:
            self._store_write(f"job {job.id}", self.store.fail, job.id, job.attempts, code, message)
            return
        except Exception:  # noqa: BLE001
            log.exception("job %s: could not record its end [%s] in the job store; retrying later", job.id, code)
        try:
            atomic_write_bytes(outcome_path(self.storage, job.id, job.attempts), json.dumps(
                {"op": "fail", "attempt": job.attempts, "code": code, "message": message}).encode())
        except OSError as exc:
            log.error("job %s: could not write its outcome file either (%s); unless the store takes it first, "
                      "the next start runs the job again", job.id, exc)
        self._settle_later(job, f"failed [{code}]",
                           lambda: self.store.fail(job.id, job.attempts, code, message))

    def _complete(self, job: JobRecord, summary: dict[str, Any], warnings: list[str]) -> bool:
        """:func:`complete_attempt`, or only its store write when an earlier try already published the files."""
        published = (not self.storage.work_dir(job.id, job.attempts).exists()
                     and (self.storage.result_dir(job.id) / "plan.json").is_file())
        if not published:
            return complete_attempt(self.store, self.storage, job, summary, warnings)
        merged = list(job.warnings) + [w for w in warnings if w not in job.warnings]
        return self.store.succeed(job.id, job.attempts, summary, merged,
                                      stored_bytes=self.storage.job_bytes(job.id))

    def _settle_later(self, job: JobRecord | _AttemptRef, what: str, write) -> None:
        """Keep an attempt's end for the dispatcher to record once the store takes writes again."""
        with self._lock:
            self._unsettled[job.id] = _Unsettled(job.id, job.attempts, what, write, time.monotonic() + 1.0, 1.0)
        self._wake.set()

    def _retry_unsettled(self, force: bool = False) -> None:
        """Try again to record the ends the store refused (each with its own backoff; all if ``force``)."""
        now = time.monotonic()
        with self._lock:
            due = [u for u in self._unsettled.values() if force or u.next_try <= now]
        for u in due:
            try:
                u.write()
            except ArtifactWriteError as exc:           # publishing its files failed after all
                with self._lock:
                    self._unsettled.pop(u.job_id, None)
                self._fail(_AttemptRef(u.job_id, u.attempt), exc.code, exc.message)
                continue
            except Exception as exc:  # noqa: BLE001 - still failing: later
                u.delay = min(UNSETTLED_MAX_DELAY_S, u.delay * 2)
                u.next_try = time.monotonic() + u.delay
                log.warning("job %s: the job store still refuses its end, %s (%s); next try in %g s",
                            u.job_id, u.what, type(exc).__name__, u.delay)
                continue
            with self._lock:
                self._unsettled.pop(u.job_id, None)
            with contextlib.suppress(OSError, ValueError):
                outcome_path(self.storage, u.job_id, u.attempt).unlink(missing_ok=True)
            log.info("job %s: its end is recorded now: %s", u.job_id, u.what)

    # -- cancellation ----------------------------------------------------------------------------
    def kill(self, job_id: str, reason: str = "cancel", timeout: float = 30.0) -> bool:
        """Kill the worker of ``job_id`` if it runs here and wait until its supervisor has finished.

        Returns True if a worker was running. Called after the store marked the job cancelled.
        """
        with self._lock:
            a = self._active.get(job_id)
        if a is None:
            return False
        a.killed_for = a.killed_for or reason
        self._kill(a)
        a.done.wait(timeout)
        return True

    @staticmethod
    def _kill(a: _Active) -> None:
        try:
            if a.process.is_alive():
                a.process.kill()
        except (OSError, ValueError, AssertionError):  # already gone or closed
            pass

    # -- dispatching -----------------------------------------------------------------------------
    def _dispatch_loop(self) -> None:
        try:   # bring the fork server up now, so that the first job starts without the import delay; and
            # unless the numba cache holds this code's kernels, compile them first: jobs wait (queued) meanwhile
            from planning.warmup import is_warm
            warm = is_warm()
            if not warm:
                log.info("compiling the planning kernels into the numba cache before the first job (scanmill warmup)")
            p = self._ctx.Process(target=_noop if warm else _warm_kernels, name="scanmill-warmup", daemon=True)
            p.start()
            deadline = time.monotonic() + (120 if warm else WARMUP_TIMEOUT_S)
            while p.is_alive() and not self._stopping.is_set() and time.monotonic() < deadline:
                p.join(0.5)
            if p.is_alive():       # stopping, or a warm-up past its time: jobs compile what is missing
                p.kill()
            elif not warm and p.exitcode != 0:
                log.warning("the kernel warm-up failed (exit code %s); jobs compile what they need", p.exitcode)
        except Exception:  # noqa: BLE001 - the first job will try again and report a failure
            log.exception("could not start the worker fork server")
        while not self._stopping.is_set():
            self._wake.wait(timeout=1.0)
            self._wake.clear()
            if self._unsettled:
                self._retry_unsettled()
            while not self._stopping.is_set() and self.busy < self.settings.workers:
                try:
                    job = self.store.claim_next()
                except Exception:  # noqa: BLE001 - e.g. database busy; try again on the next tick
                    log.exception("claiming a job failed")
                    break
                if job is None:
                    break
                self._launch(job)

    def _launch(self, job: JobRecord) -> None:
        refused = check_job_disk(self.settings, self.storage, job)
        if refused is not None:
            log.warning("job %s: not started, the disk is short of space", job.id)
            self._fail(job, *refused)
            return
        spec = job_spec(job, self.settings, self.storage)
        self.storage.remove_work(job.id, job.attempts)
        parent_conn, child_conn = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(target=run_job, args=(spec, child_conn),
                                 name=f"scanmill-job-{job.id[:8]}", daemon=True)
        try:
            proc.start()
        except Exception as exc:  # noqa: BLE001
            log.exception("could not start a worker for job %s", job.id)
            self._fail(job, "worker_start_failed", f"the service could not start a worker process: {exc}")
            return
        finally:
            child_conn.close()
        a = _Active(job=job, process=proc, conn=parent_conn)
        with self._lock:
            self._active[job.id] = a
        if self._status(job) not in (("running", job.attempts), None):   # cancelled while it was being started
            a.killed_for = "cancel"
            self._kill(a)
        log.info("job %s: attempt %d started in process %s", job.id, job.attempts, proc.pid)
        threading.Thread(target=self._supervise, args=(a,), name=f"supervise-{job.id[:8]}", daemon=True).start()

    def _status(self, job: JobRecord) -> tuple[str, int] | None:
        """``(status, attempts)`` of the job in the store; ``None`` when the store cannot be read now."""
        try:
            return self.store.status_of(job.id) or ("gone", -1)
        except Exception as exc:  # noqa: BLE001 - a store that cannot be read is asked again later
            log.warning("job %s: could not read its status (%s)", job.id, type(exc).__name__)
            return None

    # -- supervising one job -----------------------------------------------------------------------
    def _supervise(self, a: _Active) -> None:
        job, proc, conn = a.job, a.process, a.conn
        deadline = time.monotonic() + float(job.time_limit_s)
        outcome: tuple | None = None
        last_write, last_stage, progress = 0.0, None, 0.0
        next_check = time.monotonic() + 1.0
        eof = False
        try:
            while True:
                waitables = [proc.sentinel] if eof else [conn, proc.sentinel]
                ready = multiprocessing.connection.wait(waitables, timeout=0.2)
                while not eof:                       # drain every message that is there
                    try:
                        if not conn.poll():
                            break
                        msg = conn.recv()
                    except (EOFError, OSError):      # the worker closed its end (it ends, or was killed)
                        eof = True
                        break
                    if msg[0] == "progress":
                        _, stage, fraction, message = msg
                        now = time.monotonic()
                        if stage != last_stage or fraction >= 1.0 or now - last_write >= 0.25:
                            p = overall_progress(stage, fraction)
                            progress = progress if p is None else max(progress, p)
                            try:
                                self.store.update_progress(job.id, job.attempts, stage, progress, message)
                            except Exception as exc:  # noqa: BLE001 - progress is best effort; the end is not
                                log.warning("job %s: could not record its progress (%s)", job.id,
                                            type(exc).__name__)
                            last_write, last_stage = now, stage
                    else:
                        outcome = msg
                if proc.sentinel in ready:
                    break
                now = time.monotonic()
                if now > deadline and a.killed_for is None:
                    a.killed_for = "time_limit"
                    self._kill(a)
                if now >= next_check:      # fencing: the job was cancelled or deleted elsewhere
                    next_check = now + 1.0
                    st = self._status(job)
                    if st is not None and st != ("running", job.attempts) and a.killed_for is None:
                        a.killed_for = "cancel"
                        self._kill(a)
            proc.join(10)
            self._finish(a, outcome)
        except Exception:  # noqa: BLE001 - never leave a job running because the supervisor broke
            log.exception("supervising job %s failed", job.id)
            self._kill(a)
            self._fail(job, "internal_error", "the service lost track of this job's worker")
        finally:
            try:
                conn.close()
            except OSError:  # pragma: no cover
                pass
            with self._lock:
                self._active.pop(job.id, None)
            a.done.set()
            self._wake.set()

    def _finish(self, a: _Active, outcome: tuple | None) -> None:
        job = a.job
        if a.killed_for is None and outcome is not None and outcome[0] == "done":
            _, summary, warnings = outcome
            try:
                ok = self._store_write(f"job {job.id}", self._complete, job, summary, warnings)
            except ArtifactWriteError as exc:
                self._fail(job, exc.code, exc.message)
                log.warning("job %s: failed [%s] %s", job.id, exc.code, exc.message)
                return
            except SQLAlchemyError:          # the plan is in work-N or published: later, or recover() at start
                log.exception("job %s: could not record its success in the job store; retrying later", job.id)
                self._settle_later(job, "succeeded", lambda: self._complete(job, summary, warnings))
                return
            except Exception:  # noqa: BLE001 - never leave the job running
                log.exception("job %s: publishing its artifacts failed unexpectedly", job.id)
                self.storage.remove_work(job.id, job.attempts)
                self._fail(job, "internal_error", "the service failed while publishing the job's artifacts; "
                                                  "submit it again, and tell the operator if it keeps failing")
                return
            if ok:
                log.info("job %s: succeeded (%s)", job.id, summary.get("message"))
            return
        self.storage.remove_work(job.id, job.attempts)          # killed or failed: nothing to publish
        if a.killed_for == "shutdown":
            try:
                self._store_write(f"job {job.id}", self.store.requeue, job.id, job.attempts,
                                  "queued again: the service was stopped while it ran", count_attempt=False)
            except Exception:  # noqa: BLE001 - still 'running': recover() at the next start queues it again
                log.exception("job %s: could not put it back in the queue; the next start will", job.id)
            return
        if a.killed_for == "cancel":
            return
        if a.killed_for == "time_limit":
            self._fail(job, "time_limit_exceeded", time_limit_message(job.time_limit_s))
            log.info("job %s: stopped at its time limit", job.id)
            return
        if outcome is not None and outcome[0] == "error":
            _, code, message = outcome
            self._fail(job, code, message)
            log.info("job %s: failed [%s] %s", job.id, code, message)
            return
        code = a.process.exitcode
        how = (f"killed by signal {-code} ({signal.Signals(-code).name})" if code is not None and code < 0
               else f"exit code {code}")
        limit = self.settings.job_memory_limit_mb
        self._fail(job, "worker_crashed",
                   f"the worker process stopped unexpectedly ({how}); it may have run out of memory (each job "
                   f"may use SCANMILL_JOB_MEMORY_MB = {limit:,} MiB): decimate the cloud or coarsen "
                   "orientations.phi_step_deg / theta_step_deg and submit it again")
        log.warning("job %s: worker crashed (%s)", job.id, how)
