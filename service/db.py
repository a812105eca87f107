"""The job database behind SQLAlchemy: the ``jobs`` table, engines for SQLite and PostgreSQL, migrations.

``SCANMILL_DATABASE_URL`` picks the database: unset, the embedded default is SQLite in the data
directory (``DATA_DIR/scanmill.sqlite3``); ``postgresql+psycopg://USER:PASSWORD@HOST:PORT/DB``
uses PostgreSQL through psycopg 3 (``postgresql://`` and ``postgres://`` are read as psycopg 3 too).

SQLite runs in WAL mode with ``synchronous=FULL`` and in autocommit mode: every transition of the
store is one conditional statement, so each is its own durable transaction. PostgreSQL runs
each transition in its own READ COMMITTED transaction; the queue claim skips rows locked by
another claimer (``FOR UPDATE SKIP LOCKED``).

The schema is created and upgraded by the Alembic migrations in ``service/migrations`` (run by
:func:`upgrade` whenever a store opens, under a lock so that several processes starting at once
migrate once). A SQLite database written by scanmill before the migrations existed (``PRAGMA
user_version = 1``, no ``alembic_version`` table) has exactly the first revision's schema and is
stamped with it before upgrading.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path
from typing import Iterator

import sqlalchemy as sa
from sqlalchemy.engine import URL, Connection, Engine, make_url

metadata = sa.MetaData()

#: The jobs table at the head revision (the migrations are the authority; this mirrors them).
jobs = sa.Table(
    "jobs", metadata,
    sa.Column("seq", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("id", sa.Text, nullable=False, unique=True),
    sa.Column("owner", sa.Text, nullable=False),
    sa.Column("status", sa.Text, nullable=False),
    sa.Column("stage", sa.Text),
    sa.Column("progress", sa.Float, nullable=False, server_default="0"),
    sa.Column("message", sa.Text),
    sa.Column("created_at", sa.Text, nullable=False),
    sa.Column("started_at", sa.Text),
    sa.Column("finished_at", sa.Text),
    sa.Column("updated_at", sa.Text, nullable=False),
    sa.Column("attempts", sa.Integer, nullable=False, server_default="0"),
    sa.Column("time_limit_s", sa.Float, nullable=False),
    sa.Column("parameters", sa.Text, nullable=False),
    sa.Column("input", sa.Text, nullable=False),
    sa.Column("error_code", sa.Text),
    sa.Column("error_message", sa.Text),
    sa.Column("result", sa.Text),
    sa.Column("warnings", sa.Text, nullable=False, server_default="[]"),
    sa.Column("idempotency_key", sa.Text),
    sa.Column("request_hash", sa.Text),
    # revision 0002: distributed execution
    sa.Column("worker", sa.Text),             # host/process of the attempt that runs or ran the job
    sa.Column("heartbeat_at", sa.Text),       # last sign of life of the running attempt (UTC, RFC 3339)
    sa.Column("dispatched_at", sa.Text),      # when the job was handed to the broker (Celery backend)
    # revision 0003: quotas and retention
    sa.Column("stored_bytes", sa.BigInteger),  # bytes of the job's files (upload; + artifacts once succeeded)
    # revision 0004: the outbox's second mark
    sa.Column("published_at", sa.Text),       # when the broker accepted the job's message (Celery backend)
    sa.CheckConstraint("status IN ('queued','running','succeeded','failed','cancelled')", name="jobs_status"),
    sa.UniqueConstraint("owner", "idempotency_key"),
    sqlite_autoincrement=True,
)
sa.Index("jobs_owner_seq", jobs.c.owner, jobs.c.seq)
sa.Index("jobs_status_seq", jobs.c.status, jobs.c.seq)
sa.Index("jobs_status_heartbeat", jobs.c.status, jobs.c.heartbeat_at)
sa.Index("jobs_owner_status", jobs.c.owner, jobs.c.status, jobs.c.stored_bytes)
sa.Index("jobs_finished_at", jobs.c.finished_at)

MIGRATIONS = Path(__file__).resolve().parent / "migrations"
_PG_MIGRATION_LOCK = 0x5CA4_A111   # pg_advisory_lock key held while migrating


class DatabaseError(RuntimeError):
    """The database URL is unusable or the database cannot be reached or migrated; the message says why."""


def database_url(url: str | None, data_dir: str | os.PathLike) -> URL:
    """The SQLAlchemy URL of ``SCANMILL_DATABASE_URL``, or of the SQLite file in ``data_dir`` when unset.

    ``postgresql://`` and ``postgres://`` are taken as ``postgresql+psycopg://`` (psycopg 3).
    """
    if not url:
        return make_url(f"sqlite:///{(Path(data_dir).resolve() / 'scanmill.sqlite3')}")
    if url.startswith("postgres://"):
        url = "postgresql://" + url[len("postgres://"):]
    try:
        u = make_url(url)
    except Exception as exc:  # noqa: BLE001 - sqlalchemy raises ArgumentError with a terse text
        raise DatabaseError(f"SCANMILL_DATABASE_URL is not a database URL ({exc})") from None
    if u.drivername == "postgresql":
        u = u.set(drivername="postgresql+psycopg")
    if u.drivername not in ("sqlite", "sqlite+pysqlite", "postgresql+psycopg"):
        raise DatabaseError(f"SCANMILL_DATABASE_URL uses {u.drivername!r}; supported: sqlite:///PATH and "
                            "postgresql+psycopg://USER:PASSWORD@HOST:PORT/DB")
    return u


def _sqlite_pragmas(dbapi_conn, _record) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA synchronous=FULL")
    cur.execute("PRAGMA busy_timeout=30000")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.close()


def make_engine(url: URL | str) -> Engine:
    """An engine for the job store: SQLite in WAL/autocommit mode, or PostgreSQL via psycopg 3."""
    u = make_url(url) if isinstance(url, str) else url
    if u.get_backend_name() == "sqlite":
        if u.database and u.database != ":memory:":
            Path(u.database).parent.mkdir(parents=True, exist_ok=True)
        # autocommit: every statement commits itself, so a returned connection has nothing to roll back
        engine = sa.create_engine(u, isolation_level="AUTOCOMMIT", connect_args={"timeout": 30.0},
                                  pool_reset_on_return=None)
        sa.event.listen(engine, "connect", _sqlite_pragmas)
        return engine
    return sa.create_engine(u, pool_pre_ping=True, pool_size=10, max_overflow=20,
                            connect_args={"connect_timeout": 10})


@contextlib.contextmanager
def _migration_lock(engine: Engine) -> Iterator[Connection]:
    """A connection holding the migration lock: a file lock beside a SQLite file, an advisory lock on PostgreSQL."""
    if engine.dialect.name == "sqlite":
        db = engine.url.database
        fd = None
        if db and db != ":memory:":
            fd = os.open(f"{db}.migrate.lock", os.O_RDWR | os.O_CREAT, 0o644)
            fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            with engine.connect() as conn:
                yield conn
        finally:
            if fd is not None:
                fcntl.flock(fd, fcntl.LOCK_UN)
                os.close(fd)
        return
    with engine.connect() as conn:
        conn.execute(sa.text("SELECT pg_advisory_lock(:k)"), {"k": _PG_MIGRATION_LOCK})
        conn.commit()
        try:
            yield conn
        finally:
            conn.execute(sa.text("SELECT pg_advisory_unlock(:k)"), {"k": _PG_MIGRATION_LOCK})
            conn.commit()


def _alembic_config(conn: Connection | None = None):
    from alembic.config import Config
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    if conn is not None:
        cfg.attributes["connection"] = conn
    return cfg


def _revision_known(rev: str) -> bool:
    from alembic.script import ScriptDirectory
    try:
        return ScriptDirectory.from_config(_alembic_config()).get_revision(rev) is not None
    except Exception:  # noqa: BLE001 - alembic raises for an unknown id
        return False


def head_revision() -> str:
    """The newest migration's revision id."""
    from alembic.script import ScriptDirectory
    return ScriptDirectory.from_config(_alembic_config()).get_current_head()


def _unreachable(engine: Engine, exc: sa.exc.OperationalError) -> DatabaseError:
    first = str(exc.orig).strip().splitlines()[0] if exc.orig else str(exc)
    return DatabaseError(f"cannot reach the job database {engine.url.render_as_string(hide_password=True)}: {first}")


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at (None: not migrated yet)."""
    from alembic.runtime.migration import MigrationContext
    try:
        with engine.connect() as conn:
            return MigrationContext.configure(conn).get_current_revision()
    except sa.exc.OperationalError as exc:
        raise _unreachable(engine, exc) from None


def upgrade(engine: Engine, revision: str = "head") -> str:
    """Create or upgrade the schema to ``revision`` (Alembic), once even if many processes call it at once.

    Returns the revision the database is at afterwards.
    """
    import logging

    from alembic import command
    from alembic.runtime.migration import MigrationContext
    logging.getLogger("alembic").setLevel(logging.WARNING)
    try:
        with _migration_lock(engine) as conn:
            insp = sa.inspect(conn)
            current = MigrationContext.configure(conn).get_current_revision()
            if current is None and insp.has_table("jobs"):
                # written by the store before migrations existed: exactly revision 0001's schema
                version = conn.exec_driver_sql("PRAGMA user_version").scalar() if engine.dialect.name == "sqlite" \
                    else None
                if version not in (1, None):
                    raise DatabaseError(f"the job database {engine.url!r} has an unknown schema (user_version "
                                        f"{version})")
                command.stamp(_alembic_config(conn), "0001")
                conn.commit()
            current = MigrationContext.configure(conn).get_current_revision()
            if current is not None and not _revision_known(current):
                raise DatabaseError(f"the job database is at revision {current}, which this scanmill does not "
                                    "know: it was migrated by a newer scanmill")
            command.upgrade(_alembic_config(conn), revision)
            conn.commit()
            return MigrationContext.configure(conn).get_current_revision()
    except sa.exc.OperationalError as exc:
        raise _unreachable(engine, exc) from None


def downgrade(engine: Engine, revision: str) -> str | None:
    """Take the schema back to ``revision`` (to run an older scanmill on this database)."""
    from alembic import command
    with _migration_lock(engine) as conn:
        command.downgrade(_alembic_config(conn), revision)
        conn.commit()
    return current_revision(engine)
