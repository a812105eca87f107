"""The durable job store: one SQLite database in WAL mode, one row per job.

Every state change is one short transaction with ``synchronous=FULL``, so an accepted job survives
a crash of the process (and of the machine). Transitions are conditional updates, so a late worker
cannot overwrite a job that was cancelled or re-run meanwhile::

    queued  --claim-->  running  --finish-->  succeeded | failed
    queued | running  --cancel-->  cancelled
    running  --recover (at start)-->  queued (again, attempts < max) | failed 'interrupted' | succeeded

Each thread gets its own connection; reads never block on the writer (WAL).
"""

from __future__ import annotations

import json
import sqlite3
import threading
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterator

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    seq             INTEGER PRIMARY KEY AUTOINCREMENT,
    id              TEXT NOT NULL UNIQUE,
    owner           TEXT NOT NULL,
    status          TEXT NOT NULL CHECK (status IN ('queued','running','succeeded','failed','cancelled')),
    stage           TEXT,
    progress        REAL NOT NULL DEFAULT 0,
    message         TEXT,
    created_at      TEXT NOT NULL,
    started_at      TEXT,
    finished_at     TEXT,
    updated_at      TEXT NOT NULL,
    attempts        INTEGER NOT NULL DEFAULT 0,
    time_limit_s    REAL NOT NULL,
    parameters      TEXT NOT NULL,
    input           TEXT NOT NULL,
    error_code      TEXT,
    error_message   TEXT,
    result          TEXT,
    warnings        TEXT NOT NULL DEFAULT '[]',
    idempotency_key TEXT,
    request_hash    TEXT,
    UNIQUE (owner, idempotency_key)
);
CREATE INDEX IF NOT EXISTS jobs_owner_seq ON jobs (owner, seq);
CREATE INDEX IF NOT EXISTS jobs_status_seq ON jobs (status, seq);
"""

_COLUMNS = ("seq, id, owner, status, stage, progress, message, created_at, started_at, finished_at, updated_at, "
            "attempts, time_limit_s, parameters, input, error_code, error_message, result, warnings, "
            "idempotency_key, request_hash")


def now_iso() -> str:
    """The current UTC time, RFC 3339 with milliseconds."""
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


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

    @classmethod
    def from_row(cls, row: sqlite3.Row) -> "JobRecord":
        d = dict(row)
        d["parameters"] = json.loads(d["parameters"])
        d["input"] = json.loads(d["input"])
        d["result"] = json.loads(d["result"]) if d["result"] else None
        d["warnings"] = json.loads(d["warnings"] or "[]")
        return cls(**d)


class JobStore:
    """Jobs in SQLite (WAL). Safe to use from many threads; one connection per thread."""

    def __init__(self, path: str | Path):
        self.path = str(path)
        self._local = threading.local()
        self._conns: list[sqlite3.Connection] = []
        self._conns_lock = threading.Lock()
        c = self._conn()
        c.executescript(_SCHEMA)          # idempotent; executescript commits by itself
        version = c.execute("PRAGMA user_version").fetchone()[0]
        if version == 0:
            c.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
        elif version > SCHEMA_VERSION:
            raise RuntimeError(f"the job database {self.path} was written by a newer scanmill "
                               f"(schema {version} > {SCHEMA_VERSION})")

    # -- connections -------------------------------------------------------------------------
    def _conn(self) -> sqlite3.Connection:
        c = getattr(self._local, "conn", None)
        if c is None:
            c = sqlite3.connect(self.path, timeout=30.0, isolation_level=None, check_same_thread=False)
            c.row_factory = sqlite3.Row
            c.execute("PRAGMA journal_mode=WAL")
            c.execute("PRAGMA synchronous=FULL")
            c.execute("PRAGMA busy_timeout=30000")
            c.execute("PRAGMA foreign_keys=ON")
            self._local.conn = c
            with self._conns_lock:
                self._conns.append(c)
        return c

    class _Tx:
        def __init__(self, conn: sqlite3.Connection):
            self.conn = conn

        def __enter__(self) -> sqlite3.Connection:
            self.conn.execute("BEGIN IMMEDIATE")
            return self.conn

        def __exit__(self, exc_type, exc, tb) -> None:
            self.conn.execute("COMMIT" if exc_type is None else "ROLLBACK")

    def _tx(self) -> "_Tx":
        return self._Tx(self._conn())

    def close(self) -> None:
        """Close every connection (at shutdown)."""
        with self._conns_lock:
            for c in self._conns:
                try:
                    c.close()
                except sqlite3.Error:  # pragma: no cover
                    pass
            self._conns.clear()
        self._local = threading.local()

    # -- create and read -----------------------------------------------------------------------
    def create(self, *, job_id: str, owner: str, parameters: dict[str, Any], input: dict[str, Any],
               time_limit_s: float, warnings: list[str] | None = None, idempotency_key: str | None = None,
               request_hash: str | None = None) -> JobRecord:
        """Insert a queued job. Raises :class:`IdempotencyConflict` if the owner already used the key."""
        t = now_iso()
        try:
            with self._tx() as c:
                row = c.execute(
                    "INSERT INTO jobs (id, owner, status, progress, created_at, updated_at, time_limit_s, parameters, "
                    "input, warnings, idempotency_key, request_hash, message) "
                    "VALUES (?, ?, 'queued', 0, ?, ?, ?, ?, ?, ?, ?, ?, 'waiting for a worker') "
                    f"RETURNING {_COLUMNS}",
                    (job_id, owner, t, t, float(time_limit_s), json.dumps(parameters), json.dumps(input),
                     json.dumps(warnings or []), idempotency_key, request_hash)).fetchone()
        except sqlite3.IntegrityError:
            existing = self.find_by_idempotency_key(owner, idempotency_key) if idempotency_key else None
            if existing is None:
                raise
            raise IdempotencyConflict(existing) from None
        return JobRecord.from_row(row)

    def get(self, job_id: str, owner: str | None = None) -> JobRecord | None:
        """The job, or None (also when ``owner`` is given and is not the job's owner)."""
        if owner is None:
            row = self._conn().execute(f"SELECT {_COLUMNS} FROM jobs WHERE id = ?", (job_id,)).fetchone()
        else:
            row = self._conn().execute(f"SELECT {_COLUMNS} FROM jobs WHERE id = ? AND owner = ?",
                                       (job_id, owner)).fetchone()
        return JobRecord.from_row(row) if row else None

    def find_by_idempotency_key(self, owner: str, key: str) -> JobRecord | None:
        row = self._conn().execute(f"SELECT {_COLUMNS} FROM jobs WHERE owner = ? AND idempotency_key = ?",
                                   (owner, key)).fetchone()
        return JobRecord.from_row(row) if row else None

    def list(self, owner: str, *, status: str | None = None, before_seq: int | None = None,
             limit: int = 20) -> tuple[list[JobRecord], bool]:
        """The owner's jobs newest first (by acceptance order), after ``before_seq``; and whether more follow."""
        sql = f"SELECT {_COLUMNS} FROM jobs WHERE owner = ?"
        args: list[Any] = [owner]
        if status is not None:
            sql += " AND status = ?"
            args.append(status)
        if before_seq is not None:
            sql += " AND seq < ?"
            args.append(int(before_seq))
        sql += " ORDER BY seq DESC LIMIT ?"
        args.append(int(limit) + 1)
        rows = self._conn().execute(sql, args).fetchall()
        return [JobRecord.from_row(r) for r in rows[:limit]], len(rows) > limit

    def counts(self) -> dict[str, int]:
        """Number of jobs per status."""
        rows = self._conn().execute("SELECT status, COUNT(*) FROM jobs GROUP BY status").fetchall()
        return {r[0]: int(r[1]) for r in rows}

    def ids(self) -> Iterator[str]:
        for (i,) in self._conn().execute("SELECT id FROM jobs"):
            yield i

    # -- transitions ---------------------------------------------------------------------------
    def claim_next(self) -> JobRecord | None:
        """Move the oldest queued job to running (attempts + 1) and return it, or None."""
        t = now_iso()
        with self._tx() as c:
            row = c.execute(
                "UPDATE jobs SET status = 'running', attempts = attempts + 1, started_at = ?, updated_at = ?, "
                "stage = 'read', progress = 0, message = 'starting' "
                "WHERE seq = (SELECT seq FROM jobs WHERE status = 'queued' ORDER BY seq LIMIT 1) "
                "AND status = 'queued' "
                f"RETURNING {_COLUMNS}", (t, t)).fetchone()
        return JobRecord.from_row(row) if row else None

    def update_progress(self, job_id: str, attempt: int, stage: str, progress: float, message: str) -> bool:
        """Record the progress of a running attempt; False if the job is no longer that attempt."""
        with self._tx() as c:
            cur = c.execute(
                "UPDATE jobs SET stage = ?, progress = ?, message = ?, updated_at = ? "
                "WHERE id = ? AND status = 'running' AND attempts = ?",
                (stage, max(0.0, min(1.0, float(progress))), message[:500], now_iso(), job_id, attempt))
        return cur.rowcount == 1

    def succeed(self, job_id: str, attempt: int, result: dict[str, Any], warnings: list[str]) -> bool:
        """running -> succeeded, for that attempt only."""
        t = now_iso()
        with self._tx() as c:
            cur = c.execute(
                "UPDATE jobs SET status = 'succeeded', stage = 'write', progress = 1, message = 'done', "
                "finished_at = ?, updated_at = ?, result = ?, warnings = ?, error_code = NULL, error_message = NULL "
                "WHERE id = ? AND status = 'running' AND attempts = ?",
                (t, t, json.dumps(result), json.dumps(warnings), job_id, attempt))
        return cur.rowcount == 1

    def fail(self, job_id: str, attempt: int | None, code: str, message: str) -> bool:
        """running (that attempt, or any if None) -> failed with a code and message."""
        t = now_iso()
        sql = ("UPDATE jobs SET status = 'failed', finished_at = ?, updated_at = ?, error_code = ?, "
               "error_message = ?, message = ? WHERE id = ? AND status = 'running'")
        args: list[Any] = [t, t, code, message[:2000], f"failed: {code}", job_id]
        if attempt is not None:
            sql += " AND attempts = ?"
            args.append(attempt)
        with self._tx() as c:
            cur = c.execute(sql, args)
        return cur.rowcount == 1

    def requeue(self, job_id: str, attempt: int, message: str, *, count_attempt: bool = True) -> bool:
        """running (that attempt) -> queued; ``count_attempt=False`` gives the attempt back (clean shutdown)."""
        with self._tx() as c:
            cur = c.execute(
                "UPDATE jobs SET status = 'queued', stage = NULL, progress = 0, message = ?, updated_at = ?, "
                "attempts = attempts - ? WHERE id = ? AND status = 'running' AND attempts = ?",
                (message, now_iso(), 0 if count_attempt else 1, job_id, attempt))
        return cur.rowcount == 1

    def cancel(self, job_id: str, owner: str) -> JobRecord | None:
        """queued | running -> cancelled. Returns the job after the change, or None if it was not active."""
        t = now_iso()
        with self._tx() as c:
            row = c.execute(
                "UPDATE jobs SET status = 'cancelled', finished_at = ?, updated_at = ?, error_code = 'cancelled', "
                "error_message = 'cancelled by the client (DELETE /jobs/{id})', message = 'cancelled' "
                f"WHERE id = ? AND owner = ? AND status IN ('queued', 'running') RETURNING {_COLUMNS}",
                (t, t, job_id, owner)).fetchone()
        return JobRecord.from_row(row) if row else None

    def delete(self, job_id: str, owner: str) -> bool:
        """Remove a finished job's row (its files are removed by the caller)."""
        with self._tx() as c:
            cur = c.execute("DELETE FROM jobs WHERE id = ? AND owner = ? "
                            "AND status IN ('succeeded', 'failed', 'cancelled')", (job_id, owner))
        return cur.rowcount == 1

    def running(self) -> list[JobRecord]:
        rows = self._conn().execute(f"SELECT {_COLUMNS} FROM jobs WHERE status = 'running' ORDER BY seq").fetchall()
        return [JobRecord.from_row(r) for r in rows]

    def status_of(self, job_id: str) -> tuple[str, int] | None:
        """(status, attempts) of a job, or None if it is gone."""
        row = self._conn().execute("SELECT status, attempts FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return (row[0], int(row[1])) if row else None
