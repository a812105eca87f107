"""Workers: each job runs ``planning.pipeline`` in its own process, never on the event loop.

:class:`JobRunner` lives in the server process. A dispatcher thread claims queued jobs from the
store while fewer than ``SCANMILL_WORKERS`` run, and starts one worker process per job from a
``forkserver`` (the planning modules are imported once in the fork server, so a job starts in
milliseconds; ``spawn`` is the fallback). A supervisor thread per running job relays the worker's
progress into the store, enforces the job's time limit, and publishes the artifacts when the
worker reports success. Cancelling a job kills its process (SIGKILL) and waits until it is gone.

Worker processes pin their BLAS/OpenMP pools (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
``MKL_NUM_THREADS``, ... = ``SCANMILL_WORKER_THREADS``; set before numpy is imported in the fork
server) and die with the server: a watchdog thread sees the progress pipe close when the server
exits or is killed (plus a parent-death signal and a parent-pid check), so a killed server leaves
no job running; at the next start the store's
recovery re-queues or fails what was running (see :meth:`JobRunner.recover`).

The worker function only calls ``planning.inputs.cloud.read_cloud``, ``planning.pipeline.run_plan`` and
``planning.report.plan_files.write_plan``: the service holds no geometry.
"""

from __future__ import annotations

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

from planning.errors import PlanningError
from schemas.api import JOB_STAGES
from schemas.plan import PlanResult
from service.settings import Settings
from service.storage import Storage
from service.store import JobRecord, JobStore

if TYPE_CHECKING:
    from planning.inputs.cloud import Cloud
    from schemas.params import PlanConfig

log = logging.getLogger("scanmill.service")

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "BLIS_NUM_THREADS", "NUMBA_NUM_THREADS")
#: Modules the fork server imports once, so that every worker starts with them loaded.
PRELOAD = ["numpy", "planning.inputs.cloud", "planning.pipeline", "planning.report.plan_files", "schemas.params"]

#: Share of the whole job each stage stands for (for ``progress`` 0..1); rough, from the benchmarks.
STAGE_WEIGHTS = {"read": 0.05, "normals": 0.35, "orientations": 0.05, "visibility": 0.2, "setups": 0.2,
                 "areas": 0.05, "write": 0.1}
_STAGE_START = {s: sum(STAGE_WEIGHTS[t] for t in JOB_STAGES[:i]) for i, s in enumerate(JOB_STAGES)}


def overall_progress(stage: str, fraction: float) -> float | None:
    """Fraction of the whole job done when ``stage`` is ``fraction`` done (None for a stage not listed)."""
    if stage not in STAGE_WEIGHTS:
        return None
    f = max(0.0, min(1.0, float(fraction)))
    return round(min(1.0, _STAGE_START[stage] + STAGE_WEIGHTS[stage] * f), 4)


def plan_summary(r: PlanResult) -> dict[str, Any]:
    """The job's ``result`` headline (:class:`schemas.api.JobResultSummary` fields) of a finished plan."""
    return {"status": r.status, "message": r.message, "n_setups": len(r.setups),
            "coverage": float(r.coverage), "overlap_points": int(r.overlap_points)}


def read_job_cloud(path: str | os.PathLike, fmt: str | None, config: PlanConfig, max_points: int) -> Cloud:
    """Read a job's cloud with its configuration's input limits, ``max_points`` capped by the service's.

    Submission validates the cloud with this very call, so the worker reads it the same way.
    """
    from planning.inputs.cloud import read_cloud
    return read_cloud(path, fmt=fmt, units=config.input.units, max_points=min(config.input.max_points, max_points),
                      max_extent_mm=config.input.max_extent_mm, min_points=config.input.min_points)


def pin_thread_env(threads: int, env: dict[str, str] | None = None) -> None:
    """Set the BLAS/OpenMP thread-count variables (in ``os.environ`` by default)."""
    target = os.environ if env is None else env
    for var in THREAD_VARS:
        target[var] = str(int(threads))


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
    work.mkdir(parents=True, exist_ok=True)
    write_plan(outcome, work)
    report("write", 1.0, "artifacts written")
    r = outcome.result
    return plan_summary(r), list(r.warnings)


def error_of(exc: BaseException) -> tuple[str, str]:
    """The job error (code, message) of an exception an attempt raised (unexpected ones are logged)."""
    if isinstance(exc, PlanningError):
        return exc.code, exc.message
    if isinstance(exc, MemoryError):
        return "out_of_memory", ("the plan needed more memory than the service has; decimate the cloud and "
                                 "submit it again")
    traceback.print_exception(exc, file=sys.stderr)
    return "internal_error", f"the planning failed unexpectedly: {type(exc).__name__}: {exc}"


def run_job(spec: dict[str, Any], conn) -> None:
    """Embedded worker entry point: :func:`plan_attempt` with progress sent over ``conn`` to the server.

    Sends ``("progress", stage, fraction, message)`` while it runs and ends with one
    ``("done", summary, warnings)`` or ``("error", code, message)``.
    """
    _die_with_parent(conn)
    pin_thread_env(spec["threads"])
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # Ctrl-C in the terminal goes to the server, which stops us
    try:
        summary, warnings = plan_attempt(spec, _Reporter(conn))
        conn.send(("done", summary, warnings))
    except Exception as exc:  # noqa: BLE001 - every failure becomes a job error with a reason
        conn.send(("error", *error_of(exc)))
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
    """
    warnings = list(job.warnings) + [w for w in warnings if w not in job.warnings]
    if store.status_of(job.id) != ("running", job.attempts):
        storage.remove_work(job.id, job.attempts)
        return False
    storage.publish_result(job.id, job.attempts)
    if not store.succeed(job.id, job.attempts, summary, warnings):
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
        "start_delay_s": settings.worker_start_delay_s,
    }


def _noop() -> None:
    """Started once at startup so the fork server is up (and has imported the planning code) early."""


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


class JobRunner:
    """The embedded execution backend: runs queued jobs in worker processes of this server, at most
    ``settings.workers`` at once (see :class:`service.backends.ExecutionBackend`)."""

    name = "embedded"

    def __init__(self, settings: Settings, store: JobStore, storage: Storage):
        self.settings, self.store, self.storage = settings, store, storage
        self._active: dict[str, _Active] = {}
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

    def recover(self) -> dict[str, list[str]]:
        """At start, before any worker runs: settle jobs a previous server left 'running'.

        A job whose attempt had written a complete plan is published and succeeds; one that has been
        started ``max_attempts`` times fails with code ``interrupted``; any other is queued again.
        Then folders no job owns are swept. Returns the job ids per outcome (for the log).
        """
        out: dict[str, list[str]] = {"succeeded": [], "requeued": [], "failed": []}
        for job in self.store.running():
            work = self.storage.work_dir(job.id, job.attempts)
            if (work / "plan.json").is_file():
                try:
                    r = PlanResult.model_validate(json.loads((work / "plan.json").read_text()))
                    if complete_attempt(self.store, self.storage, job, plan_summary(r), list(r.warnings)):
                        out["succeeded"].append(job.id)
                        continue
                except Exception:  # noqa: BLE001 - an unreadable plan is simply run again
                    log.warning("job %s: the plan left by the interrupted attempt is unreadable; running again",
                                job.id)
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
        try:   # bring the fork server up now, so that the first job starts without the import delay
            p = self._ctx.Process(target=_noop, name="scanmill-warmup", daemon=True)
            p.start()
            p.join(120)
        except Exception:  # noqa: BLE001 - the first job will try again and report a failure
            log.exception("could not start the worker fork server")
        while not self._stopping.is_set():
            self._wake.wait(timeout=1.0)
            self._wake.clear()
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
        spec = job_spec(job, self.settings, self.storage)
        self.storage.remove_work(job.id, job.attempts)
        parent_conn, child_conn = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(target=run_job, args=(spec, child_conn), name=f"scanmill-job-{job.id[:8]}",
                                 daemon=True)
        try:
            proc.start()
        except Exception as exc:  # noqa: BLE001
            log.exception("could not start a worker for job %s", job.id)
            self.store.fail(job.id, job.attempts, "worker_start_failed",
                            f"the service could not start a worker process: {exc}")
            return
        finally:
            child_conn.close()
        a = _Active(job=job, process=proc, conn=parent_conn)
        with self._lock:
            self._active[job.id] = a
        if self.store.status_of(job.id) != ("running", job.attempts):   # cancelled while it was being started
            a.killed_for = "cancel"
            self._kill(a)
        log.info("job %s: attempt %d started in process %s", job.id, job.attempts, proc.pid)
        threading.Thread(target=self._supervise, args=(a,), name=f"supervise-{job.id[:8]}", daemon=True).start()

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
                            self.store.update_progress(job.id, job.attempts, stage, progress, message)
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
                    st = self.store.status_of(job.id)
                    if st != ("running", job.attempts) and a.killed_for is None:
                        a.killed_for = "cancel"
                        self._kill(a)
            proc.join(10)
            self._finish(a, outcome)
        except Exception:  # noqa: BLE001 - never leave a job running because the supervisor broke
            log.exception("supervising job %s failed", job.id)
            self._kill(a)
            try:
                self.store.fail(job.id, job.attempts, "internal_error", "the service lost track of this job's worker")
            except Exception:  # noqa: BLE001
                log.exception("could not mark job %s failed", job.id)
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
            if complete_attempt(self.store, self.storage, job, summary, warnings):
                log.info("job %s: succeeded (%s)", job.id, summary.get("message"))
            return
        self.storage.remove_work(job.id, job.attempts)          # killed or failed: nothing to publish
        if a.killed_for == "shutdown":
            self.store.requeue(job.id, job.attempts, "queued again: the service was stopped while it ran",
                               count_attempt=False)
            return
        if a.killed_for == "cancel":
            return
        if a.killed_for == "time_limit":
            self.store.fail(job.id, job.attempts, "time_limit_exceeded", time_limit_message(job.time_limit_s))
            log.info("job %s: stopped at its time limit", job.id)
            return
        if outcome is not None and outcome[0] == "error":
            _, code, message = outcome
            self.store.fail(job.id, job.attempts, code, message)
            log.info("job %s: failed [%s] %s", job.id, code, message)
            return
        code = a.process.exitcode
        how = (f"killed by signal {-code} ({signal.Signals(-code).name})" if code is not None and code < 0
               else f"exit code {code}")
        self.store.fail(job.id, job.attempts, "worker_crashed",
                        f"the worker process stopped unexpectedly ({how}); if the cloud is very large the "
                        "service may have run out of memory: decimate it and submit it again")
        log.warning("job %s: worker crashed (%s)", job.id, how)
