"""The Celery application of the distributed backend, configured for long CPU-heavy numpy jobs.

One task, ``scanmill.plan_job(job_id)`` (:mod:`service.celery_tasks`), whose message carries only
the job id: the job store (PostgreSQL) holds the job and receives its progress, the shared
storage holds its files. Configuration (:func:`configure`), and why:

* ``task_acks_late`` + ``task_reject_on_worker_lost``: a message is acknowledged only when its job
  has ended, so a worker that dies (kill -9, OOM killer, lost machine) leaves it to be delivered
  again: at once when only the child process died, after the broker's visibility timeout
  (``SCANMILL_BROKER_VISIBILITY_TIMEOUT_S``) when the whole worker did.
* ``worker_prefetch_multiplier = 1``: a busy worker does not hold jobs that an idle one could run.
* ``worker_max_tasks_per_child``: child processes are replaced after ``SCANMILL_MAX_TASKS_PER_CHILD``
  jobs, returning the memory that numpy/open3d keep.
* BLAS/OpenMP threads are pinned to ``SCANMILL_WORKER_THREADS`` per job (environment set before
  numpy loads, and threadpoolctl in each child), so ``concurrency`` jobs never oversubscribe cores.
* soft and hard time limits per job: the soft limit (the job's ``time_limit_s``) fails it with
  ``time_limit_exceeded``; the hard limit (+ ``SCANMILL_HARD_TIME_LIMIT_GRACE_S``) kills the child.
* cancel = revoke with terminate (SIGKILL), sent by the API when the job store marks the job
  cancelled; the task's heartbeat also notices and stops.
* no result backend: results, progress and errors go to the job store.
"""

from __future__ import annotations

from celery import Celery

from service.settings import Settings

TASK_NAME = "scanmill.plan_job"

app = Celery("scanmill", include=["service.celery_tasks"])
app.conf.update(
    task_acks_late=True,
    task_reject_on_worker_lost=True,
    task_acks_on_failure_or_timeout=True,
    worker_prefetch_multiplier=1,
    worker_cancel_long_running_tasks_on_connection_loss=True,
    task_ignore_result=True,
    result_backend=None,
    task_serializer="json",
    accept_content=["json"],
    task_track_started=False,
    worker_send_task_events=False,
    broker_connection_retry_on_startup=True,
    worker_hijack_root_logger=False,
    worker_redirect_stdouts=False,
)


def configure(settings: Settings) -> Celery:
    """Point :data:`app` at the broker and queue of ``settings`` and apply the per-deployment limits."""
    app.conf.update(
        broker_url=settings.broker_url,
        task_default_queue=settings.celery_queue,
        worker_max_tasks_per_child=settings.max_tasks_per_child,
        worker_concurrency=settings.workers,
        broker_transport_options={
            "visibility_timeout": settings.visibility_timeout_s,
            # look for abandoned messages often enough for the timeout (at most every 10 s)
            "unacked_restore_interval": max(1, min(10, int(settings.visibility_timeout_s // 4) or 1)),
            "unacked_restore_throttle": 1,
            "socket_timeout": 30, "socket_connect_timeout": 10,
        },
    )
    app.conf.scanmill_settings = settings
    return app
