"""Job execution backends: the interface the API talks to, and the factory that picks one.

``SCANMILL_BACKEND`` selects:

* ``embedded`` (default, :class:`service.workers.JobRunner`): worker processes of the API server
  itself, claiming jobs from the store (SQLite by default); one machine, no other service.
* ``celery`` (:class:`service.celery_backend.CeleryBackend`): jobs are published to a Redis broker
  and run by ``scanmill worker`` processes on any number of machines, which share the job store
  (PostgreSQL) and the artifact directory with the API.
"""

from __future__ import annotations

from typing import Protocol

from service.settings import Settings
from service.storage import Storage
from service.store import JobRecord, JobStore


class ExecutionBackend(Protocol):
    """What the API needs from whatever runs the jobs."""

    name: str

    def recover(self) -> dict[str, list[str]]:
        """At start, before :meth:`start`: settle what a previous run left behind; job ids per outcome."""

    def start(self) -> None:
        """Begin running (or dispatching) queued jobs."""

    def stop(self) -> None:
        """Stop at shutdown; jobs this process was running go back to the queue."""

    def submitted(self, job: JobRecord) -> None:
        """A job was accepted into the store: get it run."""

    def cancel(self, job_id: str) -> bool:
        """The store marked the job cancelled: stop its work; True if a running attempt was stopped."""

    def health(self) -> dict[str, int]:
        """``workers`` (job slots) and ``busy_workers`` for ``GET /healthz``."""


def make_backend(settings: Settings, store: JobStore, storage: Storage) -> ExecutionBackend:
    """The backend named by ``settings.backend``."""
    if settings.backend == "celery":
        from service.celery_backend import CeleryBackend
        return CeleryBackend(settings, store, storage)
    from service.workers import JobRunner
    return JobRunner(settings, store, storage)
