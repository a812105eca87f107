"""The durable job store: one row per job in SQLite (embedded default) or PostgreSQL, through SQLAlchemy.

Every state change is one short conditional statement in its own transaction (SQLite: WAL with
``synchronous=FULL``), so an accepted job survives a crash of the process (and of the machine),
and a late worker cannot overwrite a job that was cancelled or re-run meanwhile (fencing by
``status`` and ``attempts``)::

    queued  --claim-->  running  --finish-->  succeeded | failed
    queued | running  --cancel-->  cancelled
    running  --recover (embedded, at start)-->  queued (attempts < max) | failed 'interrupted' | succeeded
    running, heartbeat older than the lease  --take over (Celery redelivery)-->  running (attempts + 1)
                                             --requeue (reaper)-->  queued | failed 'worker_lost'

Per-key quotas: :meth:`JobStore.create` counts the owner's queued and running jobs and sums the
bytes its jobs keep stored (``stored_bytes``), and inserts the job only if both stay within the
limits, all under a per-owner lock (SQLite: one ``BEGIN IMMEDIATE`` transaction; PostgreSQL: a
transaction-scoped advisory lock), so parallel submissions cannot overshoot.

The schema comes from the Alembic migrations (:mod:`service.db`), applied when a store opens.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Iterator

import sqlalchemy as sa
from sqlalchemy.engine import URL

from service.db import database_url, jobs, make_engine, upgrade

# the statements of the hot paths (polling, progress), built once: building a statement costs more than running it
_GET = sa.select(jobs).where(jobs.c.id == sa.bindparam("id"))
_GET_OWNED = sa.select(jobs).where((jobs.c.id == sa.bindparam("id")) & (jobs.c.owner == sa.bindparam("owner")))
_STATUS = sa.select(jobs.c.status, jobs.c.attempts).where(jobs.c.id == sa.bindparam("id"))
_RUNNING_ATTEMPT = ((jobs.c.id == sa.bindparam("b_id")) & (jobs.c.status == "running")
                    & (jobs.c.attempts == sa.bindparam("b_attempt")))
_PROGRESS = jobs.update().where(_RUNNING_ATTEMPT).values(
    stage=sa.bindparam("b_stage"), progress=sa.bindparam("b_progress"), message=sa.bindparam("b_message"),
    updated_at=sa.bindparam("t"), heartbeat_at=sa.bindparam("t"))
_HEARTBEAT = jobs.update().where(_RUNNING_ATTEMPT).values(heartbeat_at=sa.bindparam("t"))
_COUNTS = sa.select(jobs.c.status, sa.func.count()).group_by(jobs.c.status)

ACTIVE_STATUSES = ("queued", "running")
FINISHED_STATUSES = ("succeeded", "failed", "cancelled")
#: The largest ``seq`` each database can hold (PostgreSQL: SERIAL, int4; SQLite: INTEGER, int64).
MAX_SEQ = {"postgresql": 2 ** 31 - 1, "sqlite": 2 ** 63 - 1}
_OWNER_LOCK_CLASS = 0x5CA4            # first key of the PostgreSQL advisory lock that serializes one owner's inserts


def now_iso() -> str:
    """The current UTC time, RFC 3339 with milliseconds."""
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def iso_ago(seconds: float) -> str:
    """The UTC time ``seconds`` ago, formatted like :func:`now_iso` (so that text comparison orders times)."""
    return (datetime.now(timezone.utc) - timedelta(seconds=float(seconds))).isoformat(timespec="milliseconds")


class QuotaExceeded(Exception):
    """A new job would pass a per-owner limit. ``kind``: 'jobs' (queued + running) or 'bytes' (stored);
    ``used``: the owner's figure now; ``adding``: what the job would add; ``limit``: the limit."""

    def __init__(self, kind: str, used: int, adding: int, limit: int):
        super().__init__(f"{kind}: {used} + {adding} > {limit}")
        self.kind, self.used, self.adding, self.limit = kind, int(used), int(adding), int(limit)


def _check_quota(active: int, used: int, adding: int, max_active: int | None, max_stored_bytes: int | None) -> None:
    """The per-owner limits: ``max_active`` jobs queued or running, ``max_stored_bytes`` bytes stored."""
    if max_active is not None and active >= max_active:
        raise QuotaExceeded("jobs", active, 1, max_active)
    if max_stored_bytes is not None and used + adding > max_stored_bytes:
        raise QuotaExceeded("bytes", used, adding, max_stored_bytes)


class IdempotencyConflict(Exception):
    """The owner already used this Idempotency-Key; ``existing`` is that job."""

    def __init__(self, existing: "JobRecord"):
        super().__init__(existing.id)
        self.existing = existing


@dataclass
class JobRecord:
    """A job row. ``parameters`` is the plan configuration (public names); ``input`` describes the upload
    (public fields plus the internal ``path``, ``fmt`` and ``fixture_paths`` relative to the job folder)."""

    seq: int
    id: str
    owner: str
    status: str
    stage: str | None
    progress: float
    message: str | None
    created_at: str
    started_at: str | None
    finished_at: str | None
    updated_at: str
    attempts: int
    time_limit_s: float
    parameters: dict[str, Any]
    input: dict[str, Any]
    error_code: str | None = None
    error_message: str | None = None
    result: dict[str, Any] | None = None
    warnings: list[str] = field(default_factory=list)
    idempotency_key: str | None = None
    request_hash: str | None = None
    worker: str | None = None
    heartbeat_at: str | None = None
    dispatched_at: str | None = None       # taken for publication (Celery backend)
    published_at: str | None = None        # the broker accepted its message (revision 0004)
    stored_bytes: int | None = None        # bytes of the job's files; None: not measured yet (before revision 0003)

    @classmethod
    def from_row(cls, row: Any) -> "JobRecord":
        d = row._asdict()
        d["parameters"] = json.loads(d["parameters"])
        d["input"] = json.loads(d["input"])
        d["result"] = json.loads(d["result"]) if d["result"] else None
        d["warnings"] = json.loads(d["warnings"] or "[]")
        return cls(**d)


class JobStore:
    """Jobs in SQLite or PostgreSQL. Safe to use from many threads and many processes.

    ``database``: a SQLAlchemy URL (``sqlite:///PATH``, ``postgresql+psycopg://...``) or the path of
    a SQLite file. The schema is migrated to the newest revision when the store opens.
    """

    def __init__(self, database: str | Path | URL, *, migrate: bool = True):
        if isinstance(database, URL):
            url = database
        elif isinstance(database, Path) or "://" not in database:
            url = sa.engine.make_url(f"sqlite:///{Path(database).resolve()}")
        else:
            url = database_url(database, ".")
        self.url = url
        self.engine = make_engine(url)
        self.dialect = self.engine.dialect.name
        if migrate:
            upgrade(self.engine)

    @property
    def max_seq(self) -> int:
        """The largest sequence number (``seq``) this database can hold."""
        return MAX_SEQ.get(self.dialect, 2 ** 31 - 1)

    @property
    def display_url(self) -> str:
        """The database URL without its password (for logs)."""
        return self.url.render_as_string(hide_password=True)

    def close(self) -> None:
        """Close every pooled connection (at shutdown)."""
        self.engine.dispose()

    # -- helpers -------------------------------------------------------------------------------
    def _one(self, stmt) -> JobRecord | None:
        with self.engine.begin() as c:
            row = c.execute(stmt).fetchone()
        return JobRecord.from_row(row) if row else None

    def _count(self, stmt) -> int:
        with self.engine.begin() as c:
            return c.execute(stmt).rowcount

    @staticmethod
    def _is(job_id: str, attempt: int | None = None):
        cond = (jobs.c.id == job_id) & (jobs.c.status == "running")
        return cond if attempt is None else cond & (jobs.c.attempts == int(attempt))

    # -- create and read -----------------------------------------------------------------------
    def create(self, *, job_id: str, owner: str, parameters: dict[str, Any], input: dict[str, Any],
               time_limit_s: float, warnings: list[str] | None = None, idempotency_key: str | None = None,
               request_hash: str | None = None, stored_bytes: int | None = None, max_active: int | None = None,
               max_stored_bytes: int | None = None) -> JobRecord:
        """Insert a queued job.

        Raises :class:`IdempotencyConflict` if the owner already used the key (checked first: a replay is
        never refused by a quota), then :class:`QuotaExceeded` if the owner already has ``max_active``
        jobs queued or running, or if its stored bytes plus ``stored_bytes`` would pass ``max_stored_bytes``.
        The checks and the insert are atomic per owner.
        """
        t = now_iso()
        stmt = jobs.insert().values(
            id=job_id, owner=owner, status="queued", progress=0.0, created_at=t, updated_at=t,
            time_limit_s=float(time_limit_s), parameters=json.dumps(parameters), input=json.dumps(input),
            warnings=json.dumps(warnings or []), idempotency_key=idempotency_key, request_hash=request_hash,
            stored_bytes=None if stored_bytes is None else int(stored_bytes),
            message="waiting for a worker").returning(jobs)
        try:
            with self._owner_transaction(owner) as c:
                if idempotency_key is not None:
                    row = c.execute(sa.select(jobs).where((jobs.c.owner == owner)
                                                          & (jobs.c.idempotency_key == idempotency_key))).fetchone()
                    if row is not None:
                        raise IdempotencyConflict(JobRecord.from_row(row))
                if max_active is not None or max_stored_bytes is not None:
                    _check_quota(*self._usage(c, owner), int(stored_bytes or 0), max_active, max_stored_bytes)
                return JobRecord.from_row(c.execute(stmt).fetchone())
        except sa.exc.IntegrityError:
            existing = self.find_by_idempotency_key(owner, idempotency_key) if idempotency_key else None
            if existing is None:
                raise
            raise IdempotencyConflict(existing) from None

    @contextlib.contextmanager
    def _owner_transaction(self, owner: str) -> Iterator[sa.Connection]:
        """A transaction in which no other writer (SQLite) or no other insert of ``owner`` (PostgreSQL) runs."""
        if self.dialect == "sqlite":
            # the engine is in autocommit mode: open the transaction by hand, taking the write lock at once
            with self.engine.connect() as c:
                c.exec_driver_sql("BEGIN IMMEDIATE")
                done = False
                try:
                    yield c
                    c.exec_driver_sql("COMMIT")
                    done = True
                finally:
                    if not done:
                        with contextlib.suppress(Exception):
                            c.exec_driver_sql("ROLLBACK")
            return
        key = int.from_bytes(hashlib.sha256(owner.encode()).digest()[:4], "big", signed=True)
        with self.engine.begin() as c:
            c.execute(sa.text("SELECT pg_advisory_xact_lock(CAST(:a AS integer), CAST(:b AS integer))"),
                      {"a": _OWNER_LOCK_CLASS, "b": key})
            yield c

    @staticmethod
    def _usage(c: sa.Connection, owner: str) -> tuple[int, int]:
        active = sa.func.coalesce(sa.func.sum(sa.case((jobs.c.status.in_(ACTIVE_STATUSES), 1), else_=0)), 0)
        stored = sa.func.coalesce(sa.func.sum(jobs.c.stored_bytes), 0)
        row = c.execute(sa.select(active, stored).where(jobs.c.owner == owner)).one()
        return int(row[0]), int(row[1])

    def usage(self, owner: str) -> tuple[int, int]:
        """(jobs queued or running, bytes stored) of ``owner``, in one query (unmeasured jobs count 0 bytes)."""
        with self.engine.connect() as c:
            return self._usage(c, owner)

    def check_quota(self, owner: str, adding_bytes: int, max_active: int | None,
                    max_stored_bytes: int | None) -> None:
        """Raise :class:`QuotaExceeded` if one more job of ``owner`` adding ``adding_bytes`` would pass a limit
        (the same test :meth:`create` makes atomically with its insert; this one takes no lock)."""
        with self.engine.connect() as c:
            _check_quota(*self._usage(c, owner), int(adding_bytes), max_active, max_stored_bytes)

    def get(self, job_id: str, owner: str | None = None) -> JobRecord | None:
        """The job, or None (also when ``owner`` is given and is not the job's owner)."""
        with self.engine.connect() as c:
            row = (c.execute(_GET, {"id": job_id}) if owner is None else
                   c.execute(_GET_OWNED, {"id": job_id, "owner": owner})).fetchone()
        return JobRecord.from_row(row) if row else None

    def find_by_idempotency_key(self, owner: str, key: str) -> JobRecord | None:
        with self.engine.connect() as c:
            row = c.execute(sa.select(jobs).where((jobs.c.owner == owner) & (jobs.c.idempotency_key == key))
                            ).fetchone()
        return JobRecord.from_row(row) if row else None

    def list(self, owner: str, *, status: str | None = None, before_seq: int | None = None,
             limit: int = 20) -> tuple[list[JobRecord], bool]:
        """The owner's jobs newest first (by acceptance order), after ``before_seq``; and whether more follow."""
        q = sa.select(jobs).where(jobs.c.owner == owner)
        if status is not None:
            q = q.where(jobs.c.status == status)
        if before_seq is not None:
            before_seq = int(before_seq)
            if before_seq <= 1:                            # no job has a sequence number below 1
                return [], False
            if before_seq <= self.max_seq:                 # past the column's range: every job is before it
                q = q.where(jobs.c.seq < before_seq)
        q = q.order_by(jobs.c.seq.desc()).limit(int(limit) + 1)
        with self.engine.connect() as c:
            rows = c.execute(q).fetchall()
        return [JobRecord.from_row(r) for r in rows[:limit]], len(rows) > limit

    def counts(self) -> dict[str, int]:
        """Number of jobs per status."""
        with self.engine.connect() as c:
            rows = c.execute(_COUNTS).fetchall()
        return {r[0]: int(r[1]) for r in rows}

    def ids(self) -> Iterator[str]:
        with self.engine.connect() as c:
            return iter([r[0] for r in c.execute(sa.select(jobs.c.id))])

    # -- transitions ---------------------------------------------------------------------------
    def claim_next(self, worker: str | None = None) -> JobRecord | None:
        """Move the oldest queued job to running (attempts + 1) and return it, or None (embedded runner)."""
        t = now_iso()
        oldest = (sa.select(jobs.c.seq).where(jobs.c.status == "queued").order_by(jobs.c.seq).limit(1)
                  .with_for_update(skip_locked=True).scalar_subquery())
        return self._one(jobs.update().where((jobs.c.seq == oldest) & (jobs.c.status == "queued")).values(
            status="running", attempts=jobs.c.attempts + 1, started_at=t, updated_at=t, heartbeat_at=t,
            worker=worker, stage="read", progress=0.0, message="starting").returning(jobs))

    def claim(self, job_id: str, worker: str, *, lease_s: float, max_attempts: int) -> tuple[str, JobRecord | None]:
        """Start an attempt of ``job_id`` for a delivered task message (Celery backend).

        Returns ``(outcome, job)``:
        ``claimed`` the job was queued and now runs here (attempts + 1);
        ``taken_over`` it was running but its heartbeat is older than ``lease_s`` (its worker died):
        it now runs here (attempts + 1);
        ``exhausted`` as ``taken_over`` but it had started ``max_attempts`` times: it is now failed
        with code ``worker_lost``;
        ``busy`` it runs elsewhere with a fresh heartbeat; ``finished`` it has ended or is gone.
        """
        t = now_iso()
        start = dict(status="running", attempts=jobs.c.attempts + 1, started_at=t, updated_at=t, heartbeat_at=t,
                     worker=worker, stage="read", progress=0.0, message=f"starting on {worker}"[:500])
        job = self._one(jobs.update().where((jobs.c.id == job_id) & (jobs.c.status == "queued"))
                        .values(**start).returning(jobs))
        if job is not None:
            return "claimed", job
        stale = iso_ago(lease_s)
        abandoned = self._is(job_id) & (jobs.c.heartbeat_at < stale)
        job = self._one(jobs.update().where(abandoned & (jobs.c.attempts < int(max_attempts)))
                        .values(**start).returning(jobs))
        if job is not None:
            return "taken_over", job
        job = self._one(jobs.update().where(abandoned & (jobs.c.attempts >= int(max_attempts))).values(
            status="failed", finished_at=t, updated_at=t, error_code="worker_lost",
            error_message=self.lost_message(max_attempts), message="failed: worker_lost").returning(jobs))
        if job is not None:
            return "exhausted", job
        current = self.get(job_id)
        return ("busy" if current is not None and current.status == "running" else "finished"), current

    @staticmethod
    def lost_message(max_attempts: int) -> str:
        return (f"the worker running this job stopped answering (crashed, killed or cut off), and the job had "
                f"already been started {max_attempts} time(s) (SCANMILL_MAX_ATTEMPTS); it was not started "
                "again. Submit it again, possibly with a smaller cloud.")

    def heartbeat(self, job_id: str, attempt: int) -> bool:
        """Record that the attempt is alive; False if the job is no longer that attempt (stop working on it)."""
        with self.engine.begin() as c:
            return c.execute(_HEARTBEAT, {"b_id": job_id, "b_attempt": int(attempt), "t": now_iso()}).rowcount == 1

    def update_progress(self, job_id: str, attempt: int, stage: str, progress: float, message: str) -> bool:
        """Record the progress of a running attempt; False if the job is no longer that attempt."""
        with self.engine.begin() as c:
            return c.execute(_PROGRESS, {"b_id": job_id, "b_attempt": int(attempt), "b_stage": stage,
                                         "b_progress": max(0.0, min(1.0, float(progress))),
                                         "b_message": message[:500], "t": now_iso()}).rowcount == 1

    def succeed(self, job_id: str, attempt: int, result: dict[str, Any], warnings: list[str], *,
                stored_bytes: int | None = None) -> bool:
        """running -> succeeded, for that attempt only; ``stored_bytes``: the job's files with its artifacts."""
        t = now_iso()
        values: dict[str, Any] = {
            "status": "succeeded", "stage": "write", "progress": 1.0, "message": "done", "finished_at": t,
            "updated_at": t, "result": json.dumps(result), "warnings": json.dumps(warnings), "error_code": None,
            "error_message": None}
        if stored_bytes is not None:
            values["stored_bytes"] = int(stored_bytes)
        return self._count(jobs.update().where(self._is(job_id, attempt)).values(**values)) == 1

    def fail(self, job_id: str, attempt: int | None, code: str, message: str) -> bool:
        """running (that attempt, or any if None) -> failed with a code and message."""
        t = now_iso()
        return self._count(jobs.update().where(self._is(job_id, attempt)).values(
            status="failed", finished_at=t, updated_at=t, error_code=code, error_message=message[:2000],
            message=f"failed: {code}")) == 1

    def requeue(self, job_id: str, attempt: int, message: str, *, count_attempt: bool = True) -> bool:
        """running (that attempt) -> queued; ``count_attempt=False`` gives the attempt back (clean shutdown)."""
        return self._count(jobs.update().where(self._is(job_id, attempt)).values(
            status="queued", stage=None, progress=0.0, message=message, updated_at=now_iso(), worker=None,
            heartbeat_at=None, dispatched_at=None, published_at=None,
            attempts=jobs.c.attempts - (0 if count_attempt else 1))) == 1

    def cancel(self, job_id: str, owner: str) -> JobRecord | None:
        """queued | running -> cancelled. Returns the job after the change, or None if it was not active."""
        t = now_iso()
        return self._one(jobs.update().where(
            (jobs.c.id == job_id) & (jobs.c.owner == owner) & jobs.c.status.in_(("queued", "running"))).values(
            status="cancelled", finished_at=t, updated_at=t, error_code="cancelled",
            error_message="cancelled by the client (DELETE /jobs/{id})", message="cancelled").returning(jobs))

    def delete(self, job_id: str, owner: str) -> bool:
        """Remove a finished job's row (its files are removed by the caller)."""
        return self._count(jobs.delete().where(
            (jobs.c.id == job_id) & (jobs.c.owner == owner) & jobs.c.status.in_(FINISHED_STATUSES))) == 1

    # -- stored bytes and retention ----------------------------------------------------------------
    def set_stored_bytes(self, job_id: str, stored_bytes: int, *, only_if_unmeasured: bool = False) -> bool:
        """Record the bytes a job's files take; ``only_if_unmeasured``: only where none is recorded yet
        (a measurement that raced with a change that recorded its own figure loses)."""
        cond = jobs.c.id == job_id
        if only_if_unmeasured:
            cond = cond & jobs.c.stored_bytes.is_(None)
        return self._count(jobs.update().where(cond).values(stored_bytes=int(stored_bytes))) == 1

    def expired(self, finished_before: str, limit: int = 100) -> list[JobRecord]:
        """Finished jobs (succeeded, failed, cancelled) that finished before ``finished_before`` (RFC 3339),
        oldest first, at most ``limit``."""
        q = (sa.select(jobs).where(jobs.c.status.in_(FINISHED_STATUSES) & (jobs.c.finished_at < finished_before))
             .order_by(jobs.c.finished_at).limit(int(limit)))
        with self.engine.connect() as c:
            return [JobRecord.from_row(r) for r in c.execute(q).fetchall()]

    def purge(self, job_id: str, finished_before: str) -> bool:
        """Remove a finished job's row if it finished before ``finished_before`` (retention; any owner)."""
        return self._count(jobs.delete().where(
            (jobs.c.id == job_id) & jobs.c.status.in_(FINISHED_STATUSES)
            & (jobs.c.finished_at < finished_before))) == 1

    def unmeasured(self, limit: int = 100) -> list[JobRecord]:
        """Jobs whose stored bytes are unknown (accepted before revision 0003), oldest first, at most ``limit``."""
        q = sa.select(jobs).where(jobs.c.stored_bytes.is_(None)).order_by(jobs.c.seq).limit(int(limit))
        with self.engine.connect() as c:
            return [JobRecord.from_row(r) for r in c.execute(q).fetchall()]

    def running(self) -> list[JobRecord]:
        with self.engine.connect() as c:
            rows = c.execute(sa.select(jobs).where(jobs.c.status == "running").order_by(jobs.c.seq)).fetchall()
        return [JobRecord.from_row(r) for r in rows]

    def abandoned(self, lease_s: float) -> list[JobRecord]:
        """Running jobs whose last heartbeat is older than ``lease_s`` seconds (their worker is presumably gone)."""
        stale = iso_ago(lease_s)
        last_sign = sa.func.coalesce(jobs.c.heartbeat_at, jobs.c.updated_at)
        q = sa.select(jobs).where((jobs.c.status == "running") & (last_sign < stale)).order_by(jobs.c.seq)
        with self.engine.connect() as c:
            return [JobRecord.from_row(r) for r in c.execute(q).fetchall()]

    def undispatched(self, limit: int = 100) -> list[str]:
        """Ids of queued jobs not yet handed to the broker, oldest first (Celery backend)."""
        q = (sa.select(jobs.c.id).where((jobs.c.status == "queued") & jobs.c.dispatched_at.is_(None))
             .order_by(jobs.c.seq).limit(int(limit)))
        with self.engine.connect() as c:
            return [r[0] for r in c.execute(q)]

    def mark_dispatched(self, job_id: str) -> str | None:
        """Take the right to publish a queued job's task message (once per queued period): the mark
        (``dispatched_at``, to give to :meth:`mark_published` or :meth:`release_dispatched`), or None if
        it is taken or the job is not queued."""
        stamp = now_iso()
        taken = self._count(jobs.update().where((jobs.c.id == job_id) & (jobs.c.status == "queued")
                                                & jobs.c.dispatched_at.is_(None)).values(dispatched_at=stamp)) == 1
        return stamp if taken else None

    def mark_published(self, job_id: str, stamp: str) -> bool:
        """The broker accepted the message sent under the mark ``stamp`` (:meth:`mark_dispatched`)."""
        return self._count(jobs.update().where((jobs.c.id == job_id) & (jobs.c.dispatched_at == stamp)
                                               & jobs.c.published_at.is_(None)).values(published_at=now_iso())) == 1

    def release_dispatched(self, job_id: str, stamp: str) -> bool:
        """Give back the mark ``stamp`` of a queued job whose message was not (or not knowingly) sent, so
        that the next publication round sends it: its publisher's send failed (broker down), or
        :meth:`unpublished` found it unconfirmed. Only that mark, and only while unconfirmed: a mark
        another replica has taken since, or a confirmed one, stays."""
        return self._count(jobs.update().where((jobs.c.id == job_id) & (jobs.c.status == "queued")
                                               & (jobs.c.dispatched_at == stamp) & jobs.c.published_at.is_(None))
                           .values(dispatched_at=None)) == 1

    def unpublished(self, grace_s: float, limit: int = 100) -> list[tuple[str, str]]:
        """(id, mark) of queued jobs taken for publication more than ``grace_s`` seconds ago whose
        publication was never confirmed (the API that took them died, or lost the store, between the
        mark and the broker's answer), oldest first (Celery backend)."""
        q = (sa.select(jobs.c.id, jobs.c.dispatched_at)
             .where((jobs.c.status == "queued") & jobs.c.dispatched_at.is_not(None) & jobs.c.published_at.is_(None)
                    & (jobs.c.dispatched_at < iso_ago(grace_s)))
             .order_by(jobs.c.seq).limit(int(limit)))
        with self.engine.connect() as c:
            return [(r[0], r[1]) for r in c.execute(q)]

    def status_of(self, job_id: str) -> tuple[str, int] | None:
        """(status, attempts) of a job, or None if it is gone."""
        with self.engine.connect() as c:
            row = c.execute(_STATUS, {"id": job_id}).fetchone()
        return (row[0], int(row[1])) if row else None
