"""The Celery execution backend, API side: publish jobs to the broker, revoke cancelled ones, reap.

Publishing follows the outbox pattern: a job is committed to the store first; to publish it an API
takes it (``dispatched_at``, so that one replica sends it), sends the message, and records the
broker's acceptance (``published_at``). A job whose publication failed (broker down) is given back
(``dispatched_at`` unset) and the reaper thread publishes it when the broker is back. A job taken
but never confirmed for ``SCANMILL_PUBLISH_GRACE_S`` (the API died, or lost the store, between the
two marks) is given back by the reaper and published again. So an accepted job is never lost between
the store and the broker; in that one window it may be sent twice, and the second delivery finds the
job taken (:mod:`service.celery_tasks`: running with a fresh heartbeat, or ended) and leaves it.

The reaper (every ``SCANMILL_REAPER_INTERVAL_S``) also settles running jobs whose heartbeat is
older than ``SCANMILL_LEASE_S``: past their time limit they fail ``time_limit_exceeded`` (the hard
limit killed them); started ``SCANMILL_MAX_ATTEMPTS`` times they fail ``worker_lost``; otherwise
they are queued and published again. The broker's own redelivery (acks_late) usually gets there
first; the reaper covers messages that were acknowledged without the job ending (hard time limit)
or are only redelivered after the long visibility timeout. Every transition is fenced in the store,
so several API replicas may each run a reaper.

``GET /healthz`` reports the job slots of the workers that answer: a census thread asks every worker
for its statistics through the broker (``inspect().stats()``, answers awaited ``CENSUS_TIMEOUT_S``)
every ``CENSUS_INTERVAL_S`` and keeps the sum of their pool sizes; ``/healthz`` only reads that
number, so it never waits on the broker. A census older than ``CENSUS_MAX_AGE_S`` (the broker has
been unreachable that long) counts no workers.
"""

from __future__ import annotations

import logging
import threading
import time
from datetime import datetime, timezone

from service.celery_app import TASK_NAME, configure
from service.settings import Settings
from service.storage import Storage
from service.store import JobRecord, JobStore
from service.workers import time_limit_message

log = logging.getLogger("scanmill.service")

CENSUS_INTERVAL_S = 5.0    # how often the API asks the workers for their pool sizes
CENSUS_TIMEOUT_S = 1.0     # how long it waits for their answers
CENSUS_MAX_AGE_S = 30.0    # a census older than this (the broker is down) counts no workers


class WorkerCensus:
    """The live Celery workers and their job slots, as last counted through the broker (see the module)."""

    def __init__(self, app, interval_s: float = CENSUS_INTERVAL_S, timeout_s: float = CENSUS_TIMEOUT_S,
                 max_age_s: float = CENSUS_MAX_AGE_S):
        self.app, self.interval_s, self.timeout_s, self.max_age_s = app, interval_s, timeout_s, max_age_s
        self._lock = threading.Lock()
        self._slots: dict[str, int] = {}
        self._at: float | None = None          # time.monotonic() of the last census that reached the broker
        self._failing = False

    def take(self) -> dict[str, int] | None:
        """Ask the workers now (bounded by the timeout and one connection attempt); their slots, or None."""
        try:
            with self.app.connection_for_write() as conn:
                conn.ensure_connection(max_retries=1, interval_start=0, timeout=max(1.0, self.timeout_s))
                stats = self.app.control.inspect(timeout=self.timeout_s, connection=conn).stats() or {}
        except Exception as exc:  # noqa: BLE001 - the broker is down: keep the last census until it ages out
            if not self._failing:
                log.warning("worker census: the broker does not answer (%s); /healthz keeps the last count for "
                            "%g s", exc, self.max_age_s)
            self._failing = True
            return None
        slots = {}
        for node, info in stats.items():
            pool = (info or {}).get("pool") or {}
            slots[node] = int(pool.get("max-concurrency") or 1) if isinstance(pool, dict) else 1
        with self._lock:
            self._slots, self._at, self._failing = slots, time.monotonic(), False
        return slots

    def workers(self) -> dict[str, int]:
        """Job slots per live worker node, from the last census (empty if it is too old or never happened)."""
        with self._lock:
            if self._at is None or time.monotonic() - self._at > self.max_age_s:
                return {}
            return dict(self._slots)

    def run(self, stop: threading.Event) -> None:
        while True:
            self.take()
            if stop.wait(self.interval_s):
                return


class CeleryBackend:
    """Jobs run on ``scanmill worker`` machines through the Redis broker (see the module docstring)."""

    name = "celery"

    def __init__(self, settings: Settings, store: JobStore, storage: Storage):
        self.settings, self.store, self.storage = settings, store, storage
        self.app = configure(settings)
        self._stop = threading.Event()
        self._reaper: threading.Thread | None = None
        self._publish_lock = threading.Lock()
        self.census = WorkerCensus(self.app)
        self._census: threading.Thread | None = None

    # -- lifecycle -------------------------------------------------------------------------------
    def recover(self) -> dict[str, list[str]]:
        """Nothing runs in this process: only sweep this host's staging (workers elsewhere own the rest)."""
        self.storage.sweep(self.store.ids())
        return {}

    def start(self) -> None:
        if self.settings.reaper_interval_s > 0:
            self._reaper = threading.Thread(target=self._reap_loop, name="job-reaper", daemon=True)
            self._reaper.start()
        self._census = threading.Thread(target=self.census.run, args=(self._stop,), name="worker-census",
                                        daemon=True)
        self._census.start()

    def stop(self) -> None:
        self._stop.set()
        if self._reaper is not None:
            self._reaper.join(10)
        if self._census is not None:
            self._census.join(5)
        try:
            self.app.pool.force_close_all()
        except Exception:  # noqa: BLE001 - closing at shutdown is best effort
            pass

    # -- jobs ------------------------------------------------------------------------------------
    def submitted(self, job: JobRecord) -> None:
        """Publish the job's task now (if the broker is down, the reaper publishes it later)."""
        self.publish(job.id, job.time_limit_s)

    def publish(self, job_id: str, time_limit_s: float) -> bool:
        """Publish ``scanmill.plan_job(job_id)`` once per queued period of the job; True if published."""
        stamp = self.store.mark_dispatched(job_id)
        if stamp is None:
            return False                         # not queued any more, or another replica published it
        soft = float(time_limit_s)
        try:
            with self._publish_lock:
                self.app.send_task(TASK_NAME, args=[job_id], task_id=job_id, queue=self.settings.celery_queue,
                                   soft_time_limit=soft, time_limit=soft + self.settings.hard_time_limit_grace_s,
                                   retry=True, retry_policy={"max_retries": 2, "interval_start": 0.2,
                                                             "interval_step": 0.5, "interval_max": 1.0})
        except Exception as exc:  # noqa: BLE001 - the broker is down: the outbox keeps the job
            self.store.release_dispatched(job_id, stamp)
            log.warning("job %s: could not publish it to the broker (%s); it stays queued and is published "
                        "when the broker answers", job_id, exc)
            return False
        try:
            self.store.mark_published(job_id, stamp)
        except Exception:  # noqa: BLE001 - sent; unconfirmed, the reaper sends it again after the grace
            log.warning("job %s: published, but the store did not take the confirmation; the reaper may publish "
                        "it again (a second delivery leaves a taken job alone)", job_id, exc_info=True)
        return True

    def cancel(self, job_id: str) -> bool:
        """Revoke the job's task (a worker running it kills its child process); nothing for a job that ended."""
        st = self.store.status_of(job_id)
        if st is not None and st[0] in ("succeeded", "failed"):
            return False
        try:
            self.app.control.revoke(job_id, terminate=True, signal="SIGKILL")
        except Exception as exc:  # noqa: BLE001 - the worker's heartbeat stops the job anyway
            log.warning("job %s: revoke not sent (%s); its worker stops at its next heartbeat", job_id, exc)
            return False
        return True

    def health(self) -> dict[str, int]:
        """``workers``: the job slots of the live workers (last census); ``busy_workers``: the running jobs."""
        running = self.store.counts().get("running", 0)
        return {"workers": sum(self.census.workers().values()), "busy_workers": running}

    # -- reaper ----------------------------------------------------------------------------------
    def reap_once(self) -> dict[str, list[str]]:
        """Give back the jobs whose publication was never confirmed, publish unsent queued jobs and settle
        running jobs whose worker is gone; ids per action."""
        out: dict[str, list[str]] = {"published": [], "requeued": [], "failed": [], "unconfirmed": []}
        s = self.settings
        # taken for publication by an API that died before the broker's answer was recorded: give them back
        for job_id, stamp in self.store.unpublished(s.publish_grace_s):
            if self.store.release_dispatched(job_id, stamp):
                out["unconfirmed"].append(job_id)
        for job_id in self.store.undispatched():
            job = self.store.get(job_id)
            if job is not None and self.publish(job.id, job.time_limit_s):
                out["published"].append(job.id)
        now = datetime.now(timezone.utc)
        for job in self.store.abandoned(s.lease_s):
            started = datetime.fromisoformat(job.started_at) if job.started_at else now
            if (now - started).total_seconds() > job.time_limit_s:
                if self.store.fail(job.id, job.attempts, "time_limit_exceeded", time_limit_message(job.time_limit_s)):
                    out["failed"].append(job.id)
            elif job.attempts >= s.max_attempts:
                if self.store.fail(job.id, job.attempts, "worker_lost", self.store.lost_message(s.max_attempts)):
                    out["failed"].append(job.id)
            elif self.store.requeue(job.id, job.attempts, f"queued again: its worker {job.worker} stopped "
                                                          "answering"):
                out["requeued"].append(job.id)
                if self.publish(job.id, job.time_limit_s):
                    out["published"].append(job.id)
        if any(out.values()):
            log.warning("reaper: %s", {k: v for k, v in out.items() if v})
        return out

    def _reap_loop(self) -> None:
        while not self._stop.wait(self.settings.reaper_interval_s):
            try:
                self.reap_once()
            except Exception:  # noqa: BLE001 - the store or broker may be back on the next round
                log.exception("reaper round failed")
