"""The job store behind SQLAlchemy: Alembic migrations, the distributed claim, heartbeats, the outbox.

Every test runs on SQLite and on a real PostgreSQL server started on 127.0.0.1 (tests/servers.py).
"""

from __future__ import annotations

import sqlite3
import threading
import time

import pytest
import sqlalchemy as sa

from service.db import (DatabaseError, current_revision, database_url, downgrade, head_revision, make_engine,
                        upgrade)
from service.store import JobStore

from servers import postgres_server, postgres_url  # noqa: F401  (fixtures)


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request, tmp_path):
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'jobs.sqlite3'}"
    return request.getfixturevalue("postgres_url")


def _new(store, job_id, owner="o"):
    return store.create(job_id=job_id, owner=owner, parameters={}, input={"path": "input/cloud.ply"}, time_limit_s=60)


def _age_heartbeat(store, job_id, seconds_ago: float):
    from service.db import jobs
    from service.store import iso_ago
    with store.engine.begin() as c:
        c.execute(jobs.update().where(jobs.c.id == job_id).values(heartbeat_at=iso_ago(seconds_ago)))


def test_fresh_database_is_migrated_to_head(db_url):
    store = JobStore(db_url)
    try:
        assert current_revision(store.engine) == head_revision() == "0002"
        cols = {c["name"] for c in sa.inspect(store.engine).get_columns("jobs")}
        assert {"worker", "heartbeat_at", "dispatched_at", "attempts", "request_hash"} <= cols
        assert upgrade(store.engine) == "0002"            # running it again changes nothing
    finally:
        store.close()


def test_downgrade_and_upgrade_keep_rows(db_url):
    store = JobStore(db_url)
    _new(store, "a" * 32)
    assert downgrade(store.engine, "0001") == "0001"
    assert "heartbeat_at" not in {c["name"] for c in sa.inspect(store.engine).get_columns("jobs")}
    upgrade(store.engine)
    assert store.get("a" * 32).status == "queued"
    store.close()


# the schema the store wrote before it was moved to SQLAlchemy and Alembic (scanmill 0.1, PRAGMA user_version 1)
_OLD_SQLITE_SCHEMA = """
CREATE TABLE jobs (
    seq INTEGER PRIMARY KEY AUTOINCREMENT, id TEXT NOT NULL UNIQUE, owner TEXT NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('queued','running','succeeded','failed','cancelled')),
    stage TEXT, progress REAL NOT NULL DEFAULT 0, message TEXT, created_at TEXT NOT NULL, started_at TEXT,
    finished_at TEXT, updated_at TEXT NOT NULL, attempts INTEGER NOT NULL DEFAULT 0, time_limit_s REAL NOT NULL,
    parameters TEXT NOT NULL, input TEXT NOT NULL, error_code TEXT, error_message TEXT, result TEXT,
    warnings TEXT NOT NULL DEFAULT '[]', idempotency_key TEXT, request_hash TEXT, UNIQUE (owner, idempotency_key));
CREATE INDEX jobs_owner_seq ON jobs (owner, seq);
CREATE INDEX jobs_status_seq ON jobs (status, seq);
PRAGMA user_version = 1;
INSERT INTO jobs (id, owner, status, created_at, updated_at, time_limit_s, parameters, input, result)
VALUES ('cccccccccccccccccccccccccccccccc', 'o', 'succeeded', '2026-01-01T00:00:00.000+00:00',
        '2026-01-01T00:00:00.000+00:00', 60, '{}', '{"path": "input/cloud.ply"}', '{"n_setups": 2}');
"""


def test_a_database_from_before_migrations_is_adopted(tmp_path):
    path = tmp_path / "scanmill.sqlite3"
    con = sqlite3.connect(path)
    con.executescript(_OLD_SQLITE_SCHEMA)
    con.close()
    store = JobStore(path)
    try:
        assert current_revision(store.engine) == "0002"
        old = store.get("c" * 32)
        assert old.status == "succeeded" and old.result == {"n_setups": 2} and old.heartbeat_at is None
        _new(store, "d" * 32)                              # and it keeps working
        assert [j.id for j in store.list("o")[0]] == ["d" * 32, "c" * 32]
    finally:
        store.close()


def test_unknown_revision_is_refused(tmp_path):
    url = f"sqlite:///{tmp_path / 'x.sqlite3'}"
    JobStore(url).close()
    eng = make_engine(url)
    with eng.begin() as c:
        c.exec_driver_sql("UPDATE alembic_version SET version_num = '9999'")
    with pytest.raises(DatabaseError, match="newer scanmill"):
        upgrade(eng)


def test_unreachable_database_says_so():
    eng = make_engine(database_url("postgresql://nobody@127.0.0.1:1/none", "."))
    with pytest.raises(DatabaseError, match="cannot reach the job database"):
        upgrade(eng)


@pytest.mark.parametrize("url, words", [
    ("mysql://u@h/db", "supported: sqlite"),
    ("not a url", "not a database URL"),
])
def test_bad_database_urls(url, words):
    with pytest.raises(DatabaseError, match=words):
        database_url(url, ".")


def test_postgres_scheme_means_psycopg3():
    assert database_url("postgres://u:p@h:5/db", ".").drivername == "postgresql+psycopg"
    assert database_url(None, "/x").database == "/x/scanmill.sqlite3"


def test_claim_takeover_and_exhaustion(db_url):
    store = JobStore(db_url)
    jid = "e" * 32
    _new(store, jid)
    outcome, job = store.claim(jid, "w1", lease_s=30, max_attempts=2)
    assert outcome == "claimed" and job.attempts == 1 and job.worker == "w1" and job.heartbeat_at
    # a second delivery while w1 beats: left alone
    assert store.claim(jid, "w2", lease_s=30, max_attempts=2)[0] == "busy"
    assert store.heartbeat(jid, 1)
    # w1 goes silent past the lease: the next delivery takes the job over as attempt 2
    _age_heartbeat(store, jid, 60)
    assert [j.id for j in store.abandoned(30)] == [jid]
    outcome, job = store.claim(jid, "w2", lease_s=30, max_attempts=2)
    assert outcome == "taken_over" and job.attempts == 2 and job.worker == "w2"
    assert not store.heartbeat(jid, 1) and not store.succeed(jid, 1, {}, [])    # w1 is fenced off
    # w2 dies too, and the job has had its attempts: it fails instead of starting a third time
    _age_heartbeat(store, jid, 60)
    outcome, job = store.claim(jid, "w3", lease_s=30, max_attempts=2)
    assert outcome == "exhausted" and job.status == "failed" and job.error_code == "worker_lost"
    assert store.claim(jid, "w4", lease_s=30, max_attempts=2)[0] == "finished"
    assert store.claim("f" * 32, "w4", lease_s=30, max_attempts=2) == ("finished", None)
    store.close()


def test_outbox_marks_each_queued_period_once(db_url):
    store = JobStore(db_url)
    jid = "1" * 32
    _new(store, jid)
    assert store.undispatched() == [jid]
    assert store.mark_dispatched(jid) and not store.mark_dispatched(jid)        # one publisher wins
    assert store.undispatched() == []
    store.undo_dispatched(jid)                                                    # the broker refused it
    assert store.undispatched() == [jid]
    assert store.mark_dispatched(jid)
    _, job = store.claim(jid, "w", lease_s=30, max_attempts=3)
    assert store.requeue(jid, job.attempts, "worker gone")                       # the reaper: needs publishing again
    assert store.undispatched() == [jid] and store.get(jid).heartbeat_at is None
    store.close()


def test_concurrent_claims_never_share_a_job(db_url):
    """Eight threads claim 40 jobs (claim_next and claim by id mixed): each job is started exactly once."""
    store = JobStore(db_url)
    ids = [f"{i:032x}" for i in range(40)]
    for i in ids:
        _new(store, i)
    got: list[str] = []
    lock = threading.Lock()

    def claimer(k: int) -> None:
        for _ in range(200):                       # bounded
            if k % 2:
                job = store.claim_next(worker=f"w{k}")
            else:
                job = next((j for i in ids if (j := store.claim(i, f"w{k}", lease_s=30, max_attempts=3))[0]
                            == "claimed"), (None, None))[1]
            if job is None:
                if not store.counts().get("queued"):
                    return
                time.sleep(0.001)
                continue
            with lock:
                got.append(job.id)

    threads = [threading.Thread(target=claimer, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert sorted(got) == sorted(ids)                   # every job once, none twice
    assert all(j.attempts == 1 for j in store.running()) and len(store.running()) == 40
    store.close()


def test_scanmill_db_upgrade_migrates_the_configured_database(db_url, monkeypatch, capsys, tmp_path):
    from scanmill.cli import main
    for k in [k for k in __import__("os").environ if k.startswith("SCANMILL_")]:
        monkeypatch.delenv(k)
    monkeypatch.setenv("SCANMILL_DATABASE_URL", db_url)
    monkeypatch.setenv("SCANMILL_DATA_DIR", str(tmp_path / "data"))
    assert main(["db", "upgrade"]) == 0
    assert "revision (empty) -> 0002" in capsys.readouterr().out
    assert main(["db", "upgrade"]) == 0
    assert "revision 0002 -> 0002" in capsys.readouterr().out
    assert current_revision(make_engine(db_url)) == "0002"
    monkeypatch.setenv("SCANMILL_DATABASE_URL", "postgresql://nobody@127.0.0.1:1/none")
    assert main(["db", "upgrade"]) == 2
    assert "cannot reach the job database" in capsys.readouterr().err
