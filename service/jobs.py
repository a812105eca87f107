"""The jobs use cases behind the routes: submit, read, list, cancel, delete, results and artifacts.

:class:`JobService` glues the store (SQL), the storage (files) and the execution backend; the
routers only parse HTTP and call it. :func:`job_view` turns a stored row into the public
:class:`schemas.api.Job` resource.
"""

from __future__ import annotations

import base64
import binascii
import logging
import re
from datetime import datetime
from pathlib import Path

import anyio
from starlette.requests import Request

from schemas.api import (
    FINISHED_STATUSES,
    Artifact,
    ArtifactList,
    Job,
    JobError,
    JobInput,
    JobLinks,
    JobPage,
    JobResultSummary,
)
from service import quotas
from service.auth import Principal
from service.backends import ExecutionBackend
from service.intake import (
    Submission,
    check_idempotency_key,
    receive_submission,
    validate_submission,
)
from service.problems import ApiError
from service.settings import Settings
from service.validation import ClientGone, SubmissionChecker
from service.storage import (
    Storage,
    gzip_alias,
    is_job_id,
    media_type,
    new_job_id,
    tree_bytes,
)
from service.store import IdempotencyConflict, JobRecord, JobStore, QuotaExceeded

log = logging.getLogger("scanmill.service")


def job_view(job: JobRecord) -> Job:
    """The public resource of a stored job."""
    base = f"/jobs/{job.id}"
    done = job.status == "succeeded"
    error = None
    if job.status in ("failed", "cancelled") and job.error_code:
        error = JobError(code=job.error_code, message=job.error_message or job.error_code)
    return Job(
        id=job.id, status=job.status, stage=job.stage, progress=job.progress, message=job.message,
        created_at=datetime.fromisoformat(job.created_at),
        started_at=datetime.fromisoformat(job.started_at) if job.started_at else None,
        finished_at=datetime.fromisoformat(job.finished_at) if job.finished_at else None,
        updated_at=datetime.fromisoformat(job.updated_at), attempts=job.attempts, time_limit_s=job.time_limit_s,
        input=JobInput(**{k: job.input[k] for k in JobInput.model_fields if k in job.input}),  # not the internal keys
        parameters=job.parameters, error=error,
        result=JobResultSummary(**job.result) if (done and job.result) else None,
        warnings=job.warnings,
        links=JobLinks(self=base, result=f"{base}/result" if done else None,
                       artifacts=f"{base}/artifacts" if done else None))


#: A list cursor is ``s`` and a job's sequence number (1 .. 2**63 - 1, no sign, no leading zero), base64url.
_CURSOR_TEXT = re.compile(r"s[1-9][0-9]{0,18}")
MAX_CURSOR_SEQ = 2 ** 63 - 1


def encode_cursor(seq: int) -> str:
    return base64.urlsafe_b64encode(f"s{seq}".encode()).decode().rstrip("=")


def decode_cursor(cursor: str) -> int:
    """The sequence number in a cursor this service gave out; 422 ``invalid_cursor`` for anything else
    (not base64url, not ``s`` + digits, not in 1 .. 2**63 - 1, or not in the form :func:`encode_cursor` writes)."""
    seq = None
    try:
        raw = base64.b64decode(cursor + "=" * (-len(cursor) % 4), altchars=b"-_", validate=True).decode("ascii")
        if _CURSOR_TEXT.fullmatch(raw) and int(raw[1:]) <= MAX_CURSOR_SEQ and encode_cursor(int(raw[1:])) == cursor:
            seq = int(raw[1:])
    except (ValueError, binascii.Error, UnicodeDecodeError):
        pass
    if seq is None:
        raise ApiError(422, "invalid_cursor", "The cursor is not one this service gave out; start from the first "
                                              "page (no cursor) and follow next_cursor.",
                       errors=["query cursor: invalid"])
    return seq


class JobService:
    """What the routes do, independent of HTTP details."""

    def __init__(self, settings: Settings, store: JobStore, storage: Storage, backend: ExecutionBackend,
                 limiter: anyio.CapacityLimiter, checker: SubmissionChecker | None = None):
        self.settings, self.store, self.storage, self.backend, self.limiter = (settings, store, storage, backend,
                                                                              limiter)
        self.checker = checker or SubmissionChecker(settings)   # reads the submitted files in child processes

    # -- submit ----------------------------------------------------------------------------------
    async def submit(self, request: Request, who: Principal, idempotency_key: str | None) -> tuple[Job, bool]:
        """Accept a job; returns (job, replayed). ``replayed``: the Idempotency-Key named an identical request."""
        key = check_idempotency_key(idempotency_key)
        sub = await receive_submission(request, self.settings, self.storage, self.limiter)
        try:
            if key is not None:
                existing = await anyio.to_thread.run_sync(self.store.find_by_idempotency_key, who.owner, key)
                if existing is not None:
                    return self._replay(existing, sub), True
            # the quotas, before the cloud is read (cheap); the insert checks them again atomically
            size = await anyio.to_thread.run_sync(tree_bytes, sub.staging)
            await anyio.to_thread.run_sync(quotas.check, self.settings, self.store, who.owner, size)
            try:
                await validate_submission(sub, self.checker, disconnected=request.is_disconnected)
            except ClientGone:
                log.info("submission dropped: the client closed the connection while its file was checked; "
                         "no job was created")
                raise ApiError(400, "client_disconnected", "The client closed the connection before the "
                                                          "submission was accepted; no job was created.") from None
            try:
                job = await anyio.to_thread.run_sync(self._store_job, sub, who, key, size)
            except IdempotencyConflict as exc:     # the same key raced in from a parallel request
                return self._replay(exc.existing, sub), True
            except QuotaExceeded as exc:           # parallel submissions of this key got there first
                raise quotas.refusal(exc) from None
        finally:
            self.storage.discard(sub.staging)      # a no-op once it was moved into the job's folder
        if await request.is_disconnected():
            # the client gave up between the check and now: it would never learn the job's id
            await anyio.to_thread.run_sync(self._drop_unanswered, job)
            raise ApiError(400, "client_disconnected", "The client closed the connection before the submission "
                                                      "was accepted; the job was cancelled.")
        await anyio.to_thread.run_sync(self.backend.submitted, job)
        log.info("job %s: accepted (%s, %s points)", job.id, job.input.get("name"), job.input.get("n_points"))
        return job_view(job), False

    def _drop_unanswered(self, job: JobRecord) -> None:
        """Remove a job stored for a client that closed its connection before the 202: cancelled (its worker
        stopped, should one have claimed it already), its files and its row removed, its id logged."""
        self.store.cancel(job.id, job.owner)
        self.backend.cancel(job.id)
        self.storage.remove_job(job.id)
        self.store.delete(job.id, job.owner)
        log.warning("job %s: removed before it started: its client closed the connection before the answer",
                    job.id)

    def _replay(self, existing: JobRecord, sub: Submission) -> Job:
        if existing.request_hash != sub.request_hash:
            raise ApiError(422, "idempotency_key_reused",
                           "This Idempotency-Key was already used for a different request (other cloud or "
                           f"parameters), job {existing.id}; use a new key for a new job.",
                           errors=["header Idempotency-Key: already used with another body"])
        return job_view(existing)

    def _store_job(self, sub: Submission, who: Principal, key: str | None, size: int) -> JobRecord:
        job_id = new_job_id()
        self.storage.accept_staging(sub.staging, job_id)
        try:
            return self.store.create(job_id=job_id, owner=who.owner, parameters=sub.config.to_json_dict(),
                                     input=sub.input, time_limit_s=sub.time_limit_s, warnings=sub.warnings,
                                     idempotency_key=key, request_hash=sub.request_hash, stored_bytes=size,
                                     **quotas.limits(self.settings))
        except BaseException:
            self.storage.remove_job(job_id)
            raise

    # -- read ------------------------------------------------------------------------------------
    def _get(self, job_id: str, who: Principal) -> JobRecord:
        job = self.store.get(job_id, owner=who.owner) if is_job_id(job_id) else None
        if job is None:
            raise ApiError(404, "job_not_found", f"There is no job {job_id[:64]!r} for this API key.")
        return job

    def get(self, job_id: str, who: Principal) -> Job:
        return job_view(self._get(job_id, who))

    def list(self, who: Principal, status: str | None, limit: int, cursor: str | None) -> JobPage:
        before = decode_cursor(cursor) if cursor else None
        rows, more = self.store.list(who.owner, status=status, before_seq=before, limit=limit)
        next_cursor = encode_cursor(rows[-1].seq) if (more and rows) else None
        q = f"limit={limit}" + (f"&status={status}" if status else "")
        links = {"self": f"/jobs?{q}" + (f"&cursor={cursor}" if cursor else "")}
        if next_cursor:
            links["next"] = f"/jobs?{q}&cursor={next_cursor}"
        return JobPage(items=[job_view(r) for r in rows], next_cursor=next_cursor, links=links)

    # -- cancel / delete ---------------------------------------------------------------------------
    def delete(self, job_id: str, who: Principal) -> Job | None:
        """Cancel an active job (returns it) or delete a finished one with its files (returns None).

        A cancelled job's files (upload, work, artifacts) are removed at once; its row stays (GET answers
        ``cancelled``) until it is deleted or the retention sweep removes it.
        """
        job = self._get(job_id, who)
        if job.status not in FINISHED_STATUSES:
            cancelled = self.store.cancel(job.id, who.owner)
            if cancelled is not None:
                stopped = self.backend.cancel(job.id)
                self.storage.remove_job(job.id)      # the worker is stopped: nothing writes there any more
                self.store.set_stored_bytes(job.id, 0)
                log.info("job %s: cancelled %s; its files were removed", job.id,
                         "and its worker stopped" if stopped else "before it started")
                return job_view(self.store.get(job.id) or cancelled)
            job = self._get(job_id, who)           # it finished meanwhile: delete it below
        self.backend.cancel(job.id)                # a cancelled job's worker may still be stopping
        if self.store.delete(job.id, who.owner):
            self.storage.remove_job(job.id)
            log.info("job %s: deleted with its files", job.id)
            return None
        raise ApiError(409, "job_busy", "The job changed while it was being deleted; try again.",
                       job_status=self._get(job_id, who).status)

    # -- results -----------------------------------------------------------------------------------
    def _finished(self, job_id: str, who: Principal) -> JobRecord:
        job = self._get(job_id, who)
        if job.status != "succeeded":
            what = {"queued": "is still queued", "running": "is still running",
                    "failed": f"failed ({job.error_code}: {job.error_message})",
                    "cancelled": "was cancelled"}[job.status]
            raise ApiError(409, "job_not_succeeded", f"Job {job.id} {what}; its results exist once it has "
                                                    "succeeded.", job_status=job.status)
        return job

    def result_path(self, job_id: str, who: Principal) -> Path:
        job = self._finished(job_id, who)
        path = self.storage.artifact_path(job.id, "plan.json")
        if path is None:
            raise ApiError(404, "artifact_not_found", f"Job {job.id} has no plan.json.")
        return path

    def artifacts(self, job_id: str, who: Principal) -> ArtifactList:
        job = self._finished(job_id, who)
        items = [Artifact(name=p.name, media_type=media_type(p.name), size_bytes=p.stat().st_size,
                          href=f"/jobs/{job.id}/artifacts/{p.name}") for p in self.storage.artifacts(job.id)]
        return ArtifactList(job_id=job.id, items=items)

    def artifact_path(self, job_id: str, name: str, who: Principal) -> Path:
        """The stored file of artifact ``name``. A name with no file of its own but a stored gzip form
        (``area_0.moves.json`` -> ``area_0.moves.json.gz``, :func:`service.storage.gzip_alias`) gives that
        file: the caller tells by ``path.name != name`` and serves it decoded or with Content-Encoding."""
        job = self._finished(job_id, who)
        path = self.storage.artifact_path(job.id, name)
        if path is None and (alias := gzip_alias(name)) is not None:
            path = self.storage.artifact_path(job.id, alias)
        if path is None:
            raise ApiError(404, "artifact_not_found",
                           f"Job {job.id} has no artifact named {name[:100]!r}; GET /jobs/{job.id}/artifacts "
                           "lists them.")
        return path
