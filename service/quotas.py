"""Per-key quotas: jobs queued or running at once, and bytes of uploads and artifacts kept stored.

Each API key (and the anonymous user, as one key) may have at most
``SCANMILL_MAX_QUEUED_JOBS_PER_KEY`` jobs queued or running; one more is refused with ``429
too_many_jobs`` and ``Retry-After``. Its jobs' files (uploads, and the artifacts of succeeded jobs)
may take at most ``SCANMILL_MAX_STORED_BYTES_PER_KEY`` bytes; a submission whose upload would pass
that is refused with ``507 storage_quota_exceeded`` naming the limit, what is used and how to
free space. The figures come from the job store in one query (``stored_bytes`` per job), and
:meth:`service.store.JobStore.create` checks them again atomically with the insert, so parallel
submissions cannot overshoot. An idempotent replay answers the existing job and is not counted.
"""

from __future__ import annotations

from service.problems import ApiError
from service.settings import Settings
from service.store import JobStore, QuotaExceeded

#: Seconds a client refused for too many jobs is asked to wait (jobs take seconds to hours).
RETRY_AFTER_S = 30
MIB = 1 << 20


def _size(n: int) -> str:
    return f"{n / MIB:,.1f} MiB" if n >= MIB else f"{n:,} bytes"


class TooManyJobs(ApiError):
    """429 ``too_many_jobs``: the key already has its limit of jobs queued or running."""

    def __init__(self, active: int, limit: int):
        super().__init__(
            429, "too_many_jobs",
            f"This API key already has {active} job(s) queued or running; the limit is "
            f"SCANMILL_MAX_QUEUED_JOBS_PER_KEY = {limit}. Wait until some have finished (GET /jobs?status=queued, "
            "GET /jobs?status=running) or cancel some (DELETE /jobs/{id}), then submit again.",
            title="Too many requests", headers={"Retry-After": str(RETRY_AFTER_S)},
            limit="SCANMILL_MAX_QUEUED_JOBS_PER_KEY", limit_value=int(limit), active_jobs=int(active))


class StorageQuotaExceeded(ApiError):
    """507 ``storage_quota_exceeded``: the key's stored files plus this upload would pass its limit."""

    def __init__(self, used: int, adding: int, limit: int):
        super().__init__(
            507, "storage_quota_exceeded",
            f"This submission needs {_size(adding)}, and the jobs of this API key already keep "
            f"{_size(used)} of uploads and artifacts; the limit is SCANMILL_MAX_STORED_BYTES_PER_KEY = "
            f"{int(limit):,} bytes ({_size(limit)}). Free space by deleting finished jobs you no longer need "
            "(DELETE /jobs/{id}; GET /jobs?status=succeeded and ?status=failed list them; cancelling a job frees "
            "its files at once), then submit again.",
            title="Insufficient storage", limit="SCANMILL_MAX_STORED_BYTES_PER_KEY", limit_value=int(limit),
            used_bytes=int(used), needed_bytes=int(adding))


def limits(settings: Settings) -> dict[str, int]:
    """The keyword arguments of :meth:`JobStore.create` that enforce the quotas."""
    return {"max_active": int(settings.max_queued_jobs_per_key),
            "max_stored_bytes": int(settings.max_stored_bytes_per_key)}


def refusal(exc: QuotaExceeded) -> ApiError:
    """The problem a store's :class:`QuotaExceeded` is answered with."""
    if exc.kind == "jobs":
        return TooManyJobs(exc.used, exc.limit)
    return StorageQuotaExceeded(exc.used, exc.adding, exc.limit)


def check(settings: Settings, store: JobStore, owner: str, adding_bytes: int) -> None:
    """Refuse early (before the cloud is read) a submission that would pass a quota of ``owner``.

    Raises :class:`TooManyJobs` or :class:`StorageQuotaExceeded`. The insert checks again atomically.
    """
    try:
        store.check_quota(owner, int(adding_bytes), **limits(settings))
    except QuotaExceeded as exc:
        raise refusal(exc) from None
