"""Retention: finished jobs older than ``SCANMILL_RETENTION_DAYS`` are deleted with their files.

:func:`sweep` is one bounded pass; :class:`RetentionSweeper` runs it in a daemon thread at start
and then every :data:`SWEEP_INTERVAL_S` (the API server wires it into its lifespan). A pass

1. deletes jobs that succeeded, failed or were cancelled more than ``SCANMILL_RETENTION_DAYS``
   ago (by ``finished_at``), the row first, then the files (a crash in between leaves only a
   folder without a job, which the storage's start sweep removes); 0 keeps jobs forever;
2. measures the stored bytes of jobs accepted before the store recorded them (revision 0003), so
   that they count against their key's quota, and frees the files of cancelled jobs among them.

Each step handles at most ``limit`` jobs per batch and ``max_batches`` batches per pass, so a pass
is bounded however many jobs are due; what is left is handled by the next pass. Every deletion is
conditional in the store, so several API replicas may each run a sweeper.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

from service.settings import Settings
from service.storage import Storage, tree_bytes
from service.store import JobStore, iso_ago

log = logging.getLogger("scanmill.service")

#: Seconds between two passes of :class:`RetentionSweeper`.
SWEEP_INTERVAL_S = 600.0
#: Jobs handled per batch, and batches per pass (at most 1000 deletions per pass by default).
BATCH = 100
MAX_BATCHES = 10


@dataclass
class SweepResult:
    deleted: int = 0           # finished jobs deleted with their files
    measured: int = 0          # jobs whose stored bytes were measured
    freed: int = 0             # cancelled jobs whose leftover files were removed
    more: bool = False         # the pass stopped at its bound with jobs still due


def sweep(settings: Settings, store: JobStore, storage: Storage, *, limit: int = BATCH,
          max_batches: int = MAX_BATCHES) -> SweepResult:
    """One bounded retention pass (see the module text); returns what it did."""
    out = SweepResult()
    if settings.retention_days > 0:
        cutoff = iso_ago(settings.retention_days * 86400.0)
        for _ in range(max_batches):
            due = store.expired(cutoff, limit)
            for job in due:
                if store.purge(job.id, cutoff):
                    storage.remove_job(job.id)
                    out.deleted += 1
            if len(due) < limit:
                break
        else:
            out.more = True
    for _ in range(max_batches):
        todo = store.unmeasured(limit)
        for job in todo:
            if job.status == "cancelled":          # a cancelled job keeps no files
                storage.remove_job(job.id)
                store.set_stored_bytes(job.id, 0)
                out.freed += 1
            else:       # the upload, with the artifacts once succeeded; only if nothing recorded a figure meanwhile
                size = (storage.job_bytes(job.id) if job.status == "succeeded"
                        else tree_bytes(storage.input_dir(job.id)))
                store.set_stored_bytes(job.id, size, only_if_unmeasured=True)
            out.measured += 1
        if len(todo) < limit:
            break
    else:
        out.more = True
    if out.deleted or out.measured:
        log.info("retention: deleted %d finished job(s) older than %g day(s) (SCANMILL_RETENTION_DAYS); measured "
                 "the stored bytes of %d older job(s)%s", out.deleted, settings.retention_days, out.measured,
                 "; more are due at the next pass" if out.more else "")
    return out


class RetentionSweeper:
    """Runs :func:`sweep` in a daemon thread: once at :meth:`start`, then every ``interval_s`` until :meth:`stop`.

    A pass that fails (the job store down, a file system error) is logged and tried again at the next
    interval; it never stops the server.
    """

    def __init__(self, settings: Settings, store: JobStore, storage: Storage, *,
                 interval_s: float = SWEEP_INTERVAL_S):
        self.settings, self.store, self.storage, self.interval_s = settings, store, storage, float(interval_s)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.passes = 0

    def start(self) -> RetentionSweeper:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="retention", daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                sweep(self.settings, self.store, self.storage)
            except Exception:                  # logged; the next pass tries again
                log.exception("retention: the sweep failed; it runs again in %g s", self.interval_s)
            self.passes += 1
            self._stop.wait(self.interval_s)

    def stop(self, timeout_s: float = 30.0) -> None:
        """Ask the thread to end and wait for a pass in progress (at most ``timeout_s``)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None
