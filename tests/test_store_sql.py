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


def _age(store, job_id, column: str, seconds_ago: float) -> str:
    """Set the job's timestamp ``column`` to ``seconds_ago`` seconds ago; returns the value written."""
    from service.db import jobs
    from service.store import iso_ago
    value = iso_ago(seconds_ago)
    with store.engine.begin() as c:
        c.execute(jobs.update().where(jobs.c.id == job_id).values({column: value}))
    return value


def _age_heartbeat(store, job_id, seconds_ago: float):
    _age(store, job_id, "heartbeat_at", seconds_ago)


def test_fresh_database_is_migrated_to_head(db_url):
    store = JobStore(db_url)
    try:
        assert current_revision(store.engine) == head_revision() == "0004"
        cols = {c["name"] for c in sa.inspect(store.engine).get_columns("jobs")}
        assert {"worker", "heartbeat_at", "dispatched_at", "attempts", "request_hash", "stored_bytes",
                "published_at"} <= cols
        assert upgrade(store.engine) == "0004"            # running it again changes nothing
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
        assert current_revision(store.engine) == head_revision()
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
    stamp = store.mark_dispatched(jid)
    assert stamp and not store.mark_dispatched(jid)                               # one publisher wins
    assert store.undispatched() == []
    assert store.release_dispatched(jid, stamp)                                   # the broker refused it
    assert store.undispatched() == [jid]
    assert store.mark_dispatched(jid)
    _, job = store.claim(jid, "w", lease_s=30, max_attempts=3)
    assert store.requeue(jid, job.attempts, "worker gone")                       # the reaper: needs publishing again
    assert store.undispatched() == [jid] and store.get(jid).heartbeat_at is None
    store.close()


def test_a_job_taken_for_publication_and_never_confirmed_is_given_back_after_the_grace(db_url):
    """The outbox's window: an API takes a job (``dispatched_at``), then dies before the broker's answer is
    recorded. Past the grace the job is found, given back once, and published by the next round; a job whose
    sending was confirmed, one taken a moment ago, and one that has started are never touched."""
    store = JobStore(db_url)
    try:
        lost, sent, fresh, started = "1" * 32, "2" * 32, "3" * 32, "4" * 32
        for j in (lost, sent, fresh, started):
            _new(store, j)
            assert store.mark_dispatched(j)
        assert store.mark_published(sent, store.get(sent).dispatched_at)
        assert not store.mark_published(sent, store.get(sent).dispatched_at)      # once
        stamp = _age(store, lost, "dispatched_at", 120)
        _age(store, sent, "dispatched_at", 120)
        _age(store, started, "dispatched_at", 120)
        fresh_stamp = _age(store, fresh, "dispatched_at", 1)
        assert store.claim(started, "w", lease_s=30, max_attempts=3)[0] == "claimed"
        assert store.unpublished(60.0) == [(lost, stamp)]
        assert store.unpublished(600.0) == []                                         # within its grace
        # a confirmation under a mark that is no longer the job's changes nothing
        assert not store.mark_published(lost, "1999-01-01T00:00:00.000+00:00")
        assert store.release_dispatched(lost, stamp)
        assert not store.release_dispatched(lost, stamp)                              # one reaper gives it back
        assert store.undispatched() == [lost]
        again = store.mark_dispatched(lost)
        assert again and store.mark_published(lost, again)
        assert store.unpublished(0.5) == [(fresh, fresh_stamp)]                      # its turn comes
        assert store.get(lost).published_at is not None
        # a requeued job (its worker lost) must be published again: both marks cleared
        _, job = store.claim(lost, "w", lease_s=30, max_attempts=3)
        assert store.requeue(lost, job.attempts, "worker gone")
        j = store.get(lost)
        assert j.dispatched_at is None and j.published_at is None and lost in store.undispatched()
    finally:
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
    head = head_revision()
    assert f"revision (empty) -> {head}" in capsys.readouterr().out
    assert main(["db", "upgrade"]) == 0
    assert f"revision {head} -> {head}" in capsys.readouterr().out
    assert current_revision(make_engine(db_url)) == head
    monkeypatch.setenv("SCANMILL_DATABASE_URL", "postgresql://nobody@127.0.0.1:1/none")
    assert main(["db", "upgrade"]) == 2
    assert "cannot reach the job database" in capsys.readouterr().err


# -- issue 13: list cursors, per-key quotas, stored bytes, retention ------------------------------------------

_OVERFLOW_CURSOR = "czkyMjMzNzIwMzY4NTQ3NzU4MDg"          # base64 of 's9223372036854775808' (2**63)


def _service(store, tmp_path, **settings):
    """A JobService over ``store`` and a storage in tmp_path (no backend: nothing runs)."""
    from service.jobs import JobService
    from service.settings import load_settings
    from service.storage import Storage

    storage = Storage(tmp_path / "data")
    storage.open()
    return JobService(load_settings(env={}, data_dir=str(tmp_path / "data"), **settings), store, storage,
                      _NoBackend(), None)


_INPUT = {"path": "input/cloud.ply", "fmt": "ply", "name": "c.ply", "format": "ply-ascii", "size_bytes": 10,
          "n_points": 10, "has_normals": False, "sha256": "0" * 64}


def _job(store, job_id, owner="o", **kw):
    return store.create(job_id=job_id, owner=owner, parameters={}, input=_INPUT, time_limit_s=60, **kw)


class _NoBackend:
    name = "none"

    def cancel(self, job_id):
        return False

    def submitted(self, job):
        pass


@pytest.mark.parametrize("seq", [2 ** 63, 2 ** 63 - 1, 10 ** 40, 0, -1, -(2 ** 63) - 1])
def test_list_cursor_out_of_range_is_422_and_the_store_never_overflows(db_url, tmp_path, seq):
    """Finding 5: an integer past 64 bits in a cursor reached the database (500 on SQLite and PostgreSQL)."""
    from service.auth import Principal
    from service.jobs import encode_cursor
    from service.problems import ApiError

    store = JobStore(db_url)
    try:
        _job(store, "a" * 32)
        svc = _service(store, tmp_path)
        who = Principal(owner="o", anonymous=False)
        cursor = _OVERFLOW_CURSOR if seq == 2 ** 63 else encode_cursor(seq)
        if 1 <= seq < 2 ** 63:
            assert [j.id for j in svc.list(who, None, 20, cursor).items] == ["a" * 32]
        else:
            with pytest.raises(ApiError) as e:
                svc.list(who, None, 20, cursor)
            assert e.value.status == 422 and e.value.code == "invalid_cursor"
        # the store itself clamps whatever it is given (defence in depth)
        assert [j.id for j in store.list("o", before_seq=seq)[0]] == (["a" * 32] if seq >= 2 else [])
    finally:
        store.close()


def test_revision_0003_adds_stored_bytes_and_goes_back(db_url):
    store = JobStore(db_url)
    _job(store, "a" * 32, stored_bytes=123)
    assert store.get("a" * 32).stored_bytes == 123
    assert downgrade(store.engine, "0002") == "0002"
    assert "stored_bytes" not in {c["name"] for c in sa.inspect(store.engine).get_columns("jobs")}
    assert upgrade(store.engine) == "0004"
    job = store.get("a" * 32)
    assert job.status == "queued" and job.stored_bytes is None      # not measured again yet
    store.close()


def test_revision_0004_counts_jobs_taken_before_it_as_published_and_goes_back(db_url):
    store = JobStore(db_url)
    _new(store, "a" * 32)
    _new(store, "b" * 32)
    assert store.mark_dispatched("a" * 32)
    assert downgrade(store.engine, "0003") == "0003"
    assert "published_at" not in {c["name"] for c in sa.inspect(store.engine).get_columns("jobs")}
    assert upgrade(store.engine) == "0004"
    a, b = store.get("a" * 32), store.get("b" * 32)
    # taken before the revision: taken as sent (nothing recorded a crash), so never sent again
    assert a.published_at == a.dispatched_at is not None
    assert b.published_at is None and b.dispatched_at is None
    assert store.unpublished(0.0) == []
    store.close()


def test_usage_counts_active_jobs_and_sums_stored_bytes_per_owner(db_url):
    store = JobStore(db_url)
    try:
        assert store.usage("o") == (0, 0)
        _job(store, "1" * 32, stored_bytes=100)
        _job(store, "2" * 32, stored_bytes=2 ** 40)                 # past 32 bits: the column is 64-bit
        _job(store, "3" * 32)                                       # unmeasured: counts 0 bytes
        _job(store, "4" * 32, owner="other", stored_bytes=7)
        assert store.usage("o") == (3, 100 + 2 ** 40)
        store.claim_next()                                          # running still counts
        assert store.usage("o") == (3, 100 + 2 ** 40)
        store.cancel("2" * 32, "o")
        store.set_stored_bytes("2" * 32, 0)
        assert store.usage("o") == (2, 100)
        assert store.usage("other") == (1, 7)
    finally:
        store.close()


def test_create_enforces_the_quotas_and_replays_are_not_counted(db_url):
    from service.store import IdempotencyConflict, QuotaExceeded

    store = JobStore(db_url)
    try:
        lim = {"max_active": 2, "max_stored_bytes": 1000}
        _job(store, "1" * 32, stored_bytes=400, idempotency_key="k1", **lim)
        _job(store, "2" * 32, stored_bytes=400, **lim)
        with pytest.raises(QuotaExceeded) as e:
            _job(store, "3" * 32, stored_bytes=1, **lim)
        assert (e.value.kind, e.value.used, e.value.limit) == ("jobs", 2, 2)
        with pytest.raises(IdempotencyConflict) as r:                # at the limit, a replay still finds its job
            _job(store, "3" * 32, stored_bytes=400, idempotency_key="k1", **lim)
        assert r.value.existing.id == "1" * 32
        store.cancel("2" * 32, "o")
        store.set_stored_bytes("2" * 32, 0)
        with pytest.raises(QuotaExceeded) as e:
            _job(store, "3" * 32, stored_bytes=601, **lim)
        assert (e.value.kind, e.value.used, e.value.adding, e.value.limit) == ("bytes", 400, 601, 1000)
        _job(store, "3" * 32, stored_bytes=600, **lim)              # exactly at the limit is allowed
        assert store.usage("o") == (2, 1000)
        _job(store, "4" * 32, owner="other", stored_bytes=1000, **lim)   # per owner
        assert store.get("5" * 32) is None and store.list("o")[0][0].id == "3" * 32
    finally:
        store.close()


def test_parallel_submissions_of_one_owner_cannot_overshoot(db_url):
    """Eight threads insert 40 jobs for one owner with a limit of 5 at once: exactly 5 are stored."""
    from service.store import QuotaExceeded

    store = JobStore(db_url)
    ids = iter([f"{i:032x}" for i in range(40)])
    lock = threading.Lock()
    outcomes: list[str] = []

    def submitter() -> None:
        for _ in range(5):
            with lock:
                jid = next(ids)
            try:
                _job(store, jid, stored_bytes=1, max_active=5, max_stored_bytes=10 ** 9)
                res = "ok"
            except QuotaExceeded:
                res = "refused"
            with lock:
                outcomes.append(res)

    threads = [threading.Thread(target=submitter) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    try:
        assert len(outcomes) == 40 and outcomes.count("ok") == 5
        assert store.usage("o") == (5, 5)
    finally:
        store.close()


def _finish_at(store, job_id, seconds_ago: float, status="succeeded"):
    from service.db import jobs
    from service.store import iso_ago
    with store.engine.begin() as c:
        c.execute(jobs.update().where(jobs.c.id == job_id).values(status=status, finished_at=iso_ago(seconds_ago)))


def _files(storage, job_id, n=100):
    d = storage.input_dir(job_id)
    d.mkdir(parents=True)
    (d / "cloud.ply").write_bytes(b"x" * n)
    return storage.job_dir(job_id)


def test_retention_sweep_deletes_old_finished_jobs_with_their_files(db_url, tmp_path):
    """Finding 4 (no retention): finished jobs older than SCANMILL_RETENTION_DAYS go, with their files."""
    from service.retention import sweep
    from service.settings import load_settings
    from service.storage import Storage

    store = JobStore(db_url)
    storage = Storage(tmp_path / "data")
    storage.open()
    day = 86400.0
    try:
        old = {}
        for i, status in enumerate(("succeeded", "failed", "cancelled")):
            jid = f"{i + 1:032x}"
            _job(store, jid, stored_bytes=100)
            old[jid] = _files(storage, jid)
            _finish_at(store, jid, 3 * day, status)
        young, queued = "a" * 32, "b" * 32
        for jid in (young, queued):
            _job(store, jid, stored_bytes=100)
            _files(storage, jid)
        _finish_at(store, young, 1 * day)
        keep = load_settings(env={}, retention_days=0)
        assert sweep(keep, store, storage).deleted == 0 and len(store.list("o")[0]) == 5   # 0 keeps forever
        s = load_settings(env={}, retention_days=2)
        # bounded: one batch of two per pass
        first = sweep(s, store, storage, limit=2, max_batches=1)
        assert first.deleted == 2 and first.more
        second = sweep(s, store, storage, limit=2, max_batches=1)
        assert second.deleted == 1 and not second.more
        assert sorted(j.id for j in store.list("o")[0]) == [young, queued]
        assert not any(p.exists() for p in old.values())
        assert storage.job_dir(young).is_dir() and storage.job_dir(queued).is_dir()
        assert sweep(s, store, storage).deleted == 0
    finally:
        storage.close()
        store.close()


def test_retention_sweep_measures_jobs_from_before_0003_and_frees_cancelled_ones(db_url, tmp_path):
    from service.db import jobs
    from service.retention import sweep
    from service.settings import load_settings
    from service.storage import Storage

    store = JobStore(db_url)
    storage = Storage(tmp_path / "data")
    storage.open()
    try:
        done, waiting, cancelled = "1" * 32, "2" * 32, "3" * 32
        for jid in (done, waiting, cancelled):
            _job(store, jid)                               # stored_bytes NULL, as after the migration
            _files(storage, jid, 100)
        (storage.result_dir(done)).mkdir()
        (storage.result_dir(done) / "plan.json").write_bytes(b"y" * 50)
        with store.engine.begin() as c:
            c.execute(jobs.update().where(jobs.c.id == done).values(status="succeeded"))
        store.cancel(cancelled, "o")
        assert store.usage("o") == (1, 0)
        out = sweep(load_settings(env={}, retention_days=30), store, storage, limit=2)
        assert (out.measured, out.freed, out.deleted) == (3, 1, 0)
        assert [store.get(j).stored_bytes for j in (done, waiting, cancelled)] == [150, 100, 0]
        assert not storage.job_dir(cancelled).exists() and store.get(cancelled).status == "cancelled"
        assert store.usage("o") == (1, 250)
        # a figure recorded meanwhile is not overwritten by a measurement
        assert not store.set_stored_bytes(done, 1, only_if_unmeasured=True) and store.get(done).stored_bytes == 150
    finally:
        storage.close()
        store.close()


def test_cancel_through_the_service_frees_the_files_and_keeps_the_row(db_url, tmp_path):
    from service.auth import Principal

    store = JobStore(db_url)
    try:
        svc = _service(store, tmp_path)
        who = Principal(owner="o", anonymous=False)
        _job(store, "a" * 32, stored_bytes=100)
        folder = _files(svc.storage, "a" * 32)
        assert svc.delete("a" * 32, who).status == "cancelled"
        assert not folder.exists()
        assert store.get("a" * 32).status == "cancelled" and store.usage("o") == (0, 0)
        assert svc.get("a" * 32, who).status == "cancelled"
        assert svc.delete("a" * 32, who) is None and store.get("a" * 32) is None
    finally:
        store.close()
