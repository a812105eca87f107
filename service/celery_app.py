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
* broker outages (a Redis restart) are ridden out, not turned into failed jobs: workers reconnect by
  themselves, forever (``broker_connection_retry``, ``broker_connection_max_retries = None``), and
  ``worker_cancel_long_running_tasks_on_connection_loss`` is off, so a running job keeps running
  while the broker is away (its progress and heartbeat go to the job store, not to Redis). Its
  message could not be acknowledged on the lost connection: it is acknowledged on the new one when
  the job ends, or, if the broker hands it out again first, the receiving worker finds the job
  running with a live heartbeat and leaves it alone (:mod:`service.celery_tasks`), so no attempt is
  started or counted. The Redis transport is :class:`RedisTransport`, which fixes kombu's channel
  teardown while the broker is unreachable (see there).
"""

from __future__ import annotations

import logging
import ssl
import warnings
from typing import Any
from urllib.parse import parse_qs, urlsplit

from celery import Celery
from celery.exceptions import CPendingDeprecationWarning
from celery.signals import celeryd_after_setup
from kombu.transport import redis as kombu_redis

from service.settings import Settings

TASK_NAME = "scanmill.plan_job"

log = logging.getLogger("scanmill.worker")


class RedisChannel(kombu_redis.Channel):
    """kombu's Redis channel, able to finish closing (and to acknowledge late) after its broker went away.

    When the broker connection drops, the worker closes the connection twice: once while the broker is
    unreachable (the pending BRPOP read fails, leaving the channel half closed) and once more after
    kombu has detached the connection from the transport. The second close tries to put the
    unacknowledged messages back on the queue, and kombu 5.7 then fails with ``AttributeError`` when
    it rebuilds its Redis pool from the detached connection; that error is not a connection error,
    so it ends the whole worker (``Unrecoverable error``: it finishes its running jobs and exits,
    taking no more). Acknowledging, after the reconnection, a message received before the loss
    would fail the same way.

    This channel keeps the parameters it connected with, so both work as they should: restoring
    fails like any command to a broker that is down (a connection error, which the worker handles:
    the messages stay in the broker's unacknowledged set, which hands them out again after the
    visibility timeout), and a late acknowledgement reaches the broker once it is back (Redis
    delivery tags are not tied to a connection), so the message is not delivered again.
    """

    _scanmill_connparams: dict[bool, dict[str, Any]]

    def _connparams(self, asynchronous: bool = False) -> dict[str, Any]:
        known = self.__dict__.setdefault("_scanmill_connparams", {})
        if self.connection is not None and self.connection.client is not None:
            known[asynchronous] = super()._connparams(asynchronous=asynchronous)
        elif asynchronous not in known:   # detached before it ever connected: nothing to talk to
            raise kombu_redis.redis.exceptions.ConnectionError("the broker connection was closed")
        return dict(known[asynchronous])

    def basic_ack(self, delivery_tag: Any, multiple: bool = False) -> None:
        if not self.closed:
            return super().basic_ack(delivery_tag, multiple)
        try:                             # a message received before the connection was lost and renewed
            super().basic_ack(delivery_tag, multiple)
        finally:
            self._disconnect_pools()     # the pool made for this one command
        log.info("acknowledged message %s after the broker connection was renewed", delivery_tag)


class RedisTransport(kombu_redis.Transport):
    """kombu's Redis transport with :class:`RedisChannel` (``broker_transport`` of ``redis://`` brokers)."""

    Channel = RedisChannel


def _quiet_connection_loss_notice(**_: Any) -> None:
    """Drop the pending-deprecation notice Celery 5 logs at every broker connection loss about
    ``worker_cancel_long_running_tasks_on_connection_loss``: we set that option on purpose. Celery's
    logging setup turns all its deprecation warnings on, so this runs after it (``celeryd_after_setup``)."""
    warnings.filterwarnings("ignore", category=CPendingDeprecationWarning,
                            message=r"(?s).*worker_cancel_long_running_tasks_on_connection_loss")


celeryd_after_setup.connect(_quiet_connection_loss_notice, weak=False)

app = Celery("scanmill", include=["service.celery_tasks"])
app.conf.update(
    task_acks_late=True,
    task_reject_on_worker_lost=True,
    task_acks_on_failure_or_timeout=True,
    worker_prefetch_multiplier=1,
    # a broker outage must not stop running jobs: they neither need the broker nor lose their message
    worker_cancel_long_running_tasks_on_connection_loss=False,
    task_ignore_result=True,
    result_backend=None,
    task_serializer="json",
    accept_content=["json"],
    task_track_started=False,
    worker_send_task_events=False,
    # reconnect, at start and after a loss, for as long as it takes (a worker without a broker is idle,
    # not broken; its running jobs carry on meanwhile)
    broker_connection_retry=True,
    broker_connection_retry_on_startup=True,
    broker_connection_max_retries=None,
    worker_hijack_root_logger=False,
    worker_redirect_stdouts=False,
)


def broker_options(settings: Settings) -> dict[str, Any]:
    """The broker settings of ``settings``: URL, transport (with its options) and TLS."""
    url = settings.broker_url
    scheme = urlsplit(url or "").scheme
    out: dict[str, Any] = {
        "broker_url": url,
        "broker_transport_options": {
            "visibility_timeout": settings.visibility_timeout_s,
            # look for abandoned messages often enough for the timeout (at most every 10 s)
            "unacked_restore_interval": max(1, min(10, int(settings.visibility_timeout_s // 4) or 1)),
            "unacked_restore_throttle": 1,
            # a dead or restarted broker is noticed (keepalive, bounded reads and connects) and every
            # command is retried once on a timeout (a duplicate job message is harmless: claims are fenced)
            "socket_timeout": 30, "socket_connect_timeout": 10, "socket_keepalive": True,
            "retry_on_timeout": True, "health_check_interval": 10,
        },
        "broker_transport": None,
        "broker_use_ssl": None,
    }
    if scheme in ("redis", "rediss"):
        out["broker_transport"] = f"{__name__}:RedisTransport"
        # kombu picks TLS from the URL scheme only when it chooses the transport itself: say it here.
        # Without ssl_* options in the URL the server certificate is verified against the system CAs.
        if scheme == "rediss" and not any(k.startswith("ssl_") for k in parse_qs(urlsplit(url).query)):
            out["broker_use_ssl"] = {"ssl_cert_reqs": ssl.CERT_REQUIRED}
    return out


def configure(settings: Settings) -> Celery:
    """Point :data:`app` at the broker and queue of ``settings`` and apply the per-deployment limits."""
    app.conf.update(
        task_default_queue=settings.celery_queue,
        worker_max_tasks_per_child=settings.max_tasks_per_child,
        worker_concurrency=settings.workers,
        **broker_options(settings),
    )
    app.conf.scanmill_settings = settings
    return app
