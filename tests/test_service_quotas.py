"""Hold under abuse: per-key quotas (jobs queued or running, bytes stored), freeing files on cancel,
retention of finished jobs, and list cursors that cannot reach the database as out-of-range integers.

The HTTP tests run a real ``scanmill serve`` on 127.0.0.1 whose workers wait before reading the
cloud (``SCANMILL_WORKER_START_DELAY_S``), so that submitted jobs stay queued or running.
"""

from __future__ import annotations

import base64

import numpy as np
import pytest
from service_fixtures import (
    KEY_A,
    KEY_B,
    ServerProcess,
    submit,
    wait_until,
    write_half_sphere,
)

from planning.report.files import write_ply

PROBLEM = "application/problem+json"
MAX_JOBS = 3


@pytest.fixture(scope="module")
def cloud(tmp_path_factory):
    return write_half_sphere(tmp_path_factory.mktemp("in") / "half_sphere.ply")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("quota")
    srv = ServerProcess(root / "data", api_keys=[KEY_A, KEY_B], workers=1, worker_start_delay_s=600,
                        max_queued_jobs_per_key=MAX_JOBS).start()
    yield srv
    srv.stop()


def _cancel_all(client) -> None:
    for job in client.get("/jobs", params={"limit": 100}).json()["items"]:
        if job["status"] in ("queued", "running"):
            assert client.delete(f"/jobs/{job['id']}").status_code == 200


def test_jobs_queued_or_running_per_key_are_limited(server, cloud):
    """Finding 4: one key could queue any number of jobs. Past SCANMILL_MAX_QUEUED_JOBS_PER_KEY: 429."""
    with server.client(KEY_A) as a, server.client(KEY_B) as b:
        accepted = [submit(a, cloud) for _ in range(MAX_JOBS)]
        assert [r.status_code for r in accepted] == [202] * MAX_JOBS
        r = submit(a, cloud)
        assert r.status_code == 429, r.text
        assert r.headers["content-type"].startswith(PROBLEM)
        assert int(r.headers["retry-after"]) > 0
        p = r.json()
        assert p["code"] == "too_many_jobs"
        assert p["limit"] == "SCANMILL_MAX_QUEUED_JOBS_PER_KEY" and p["limit_value"] == MAX_JOBS
        assert "SCANMILL_MAX_QUEUED_JOBS_PER_KEY" in p["detail"] and str(MAX_JOBS) in p["detail"]
        # the limit is per key: another key is not affected
        rb = submit(b, cloud)
        assert rb.status_code == 202, rb.text
        # an idempotent replay of an accepted job is answered, not counted again
        key = {"Idempotency-Key": "replay-0001"}
        assert a.delete(f"/jobs/{accepted[0].json()['id']}").status_code == 200    # room for one
        first = submit(a, cloud, headers=key)
        assert first.status_code == 202, first.text
        again = submit(a, cloud, headers=key)
        assert again.status_code == 202 and again.headers["idempotent-replayed"] == "true"
        assert again.json()["id"] == first.json()["id"]
        # a cancelled job frees its place
        assert submit(a, cloud).status_code == 429
        assert a.delete(f"/jobs/{accepted[1].json()['id']}").status_code == 200
        assert submit(a, cloud).status_code == 202
        _cancel_all(a)
        _cancel_all(b)


def test_cancel_frees_the_files_at_once_and_keeps_the_job(server, cloud):
    """Finding 4: a cancelled job kept its upload until a second DELETE."""
    with server.client(KEY_A) as a:
        r = submit(a, cloud)
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        job_dir = server.data_dir / "jobs" / job_id
        assert (job_dir / "input").is_dir()
        c = a.delete(f"/jobs/{job_id}")
        assert c.status_code == 200 and c.json()["status"] == "cancelled"
        assert not job_dir.exists(), sorted(str(p) for p in job_dir.rglob("*"))
        got = a.get(f"/jobs/{job_id}")
        assert got.status_code == 200 and got.json()["status"] == "cancelled"
        assert a.delete(f"/jobs/{job_id}").status_code == 204
        assert a.get(f"/jobs/{job_id}").status_code == 404


def _cursor(text: str) -> str:
    return base64.urlsafe_b64encode(text.encode()).decode().rstrip("=")


@pytest.mark.parametrize("cursor", [
    "czkyMjMzNzIwMzY4NTQ3NzU4MDg",             # base64 of s9223372036854775808 (2**63): the reported 500
    _cursor("s" + "9" * 40), _cursor("s-1"), _cursor("s0"), _cursor("s-9223372036854775809"), _cursor("s 5"),
    _cursor("s+5"), _cursor("s٣"), _cursor("s1_000"), "!!!", _cursor("x5"),
])
def test_out_of_range_cursors_are_422(server, cursor):
    """Finding 5: a cursor holding an integer past 64 bits answered 500."""
    with server.client(KEY_A) as a:
        r = a.get("/jobs", params={"cursor": cursor})
        assert r.status_code == 422, r.text
        assert r.json()["code"] == "invalid_cursor"


# -- the anonymous user, the stored-bytes quota, retention -------------------------------------------------

MIB = 1 << 20


@pytest.fixture(scope="module")
def big_cloud(tmp_path_factory):
    """A valid cloud of a bit over half a MiB: two of them pass a 1 MiB quota."""
    rng = np.random.default_rng(7)
    p = rng.normal(size=(12_000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    path = tmp_path_factory.mktemp("big") / "sphere.ply"
    write_ply(path, p * 40.0, normals=p, binary=True)
    assert MIB / 2 < path.stat().st_size < MIB
    return path


@pytest.fixture(scope="module")
def anon_server(tmp_path_factory):
    root = tmp_path_factory.mktemp("anon")
    srv = ServerProcess(root / "data", workers=1, worker_start_delay_s=600, max_queued_jobs_per_key=2,
                        max_stored_bytes_per_key=MIB, retention_days=1).start()
    yield srv
    srv.stop()


def test_the_anonymous_user_is_one_key(anon_server, cloud):
    with anon_server.client() as c1, anon_server.client() as c2:
        first, second = submit(c1, cloud), submit(c2, cloud)
        assert (first.status_code, second.status_code) == (202, 202), (first.text, second.text)
        r = submit(c1, cloud)
        assert r.status_code == 429 and r.json()["code"] == "too_many_jobs", r.text
        assert r.json()["limit_value"] == 2 and r.json()["active_jobs"] == 2
        _cancel_all(c1)


def test_stored_bytes_per_key_are_limited(anon_server, big_cloud):
    """Finding 4 (no disk quota): past SCANMILL_MAX_STORED_BYTES_PER_KEY a submission is refused with 507."""
    size = big_cloud.stat().st_size
    with anon_server.client() as c:
        first = submit(c, big_cloud)
        assert first.status_code == 202, first.text
        r = submit(c, big_cloud)
        assert r.status_code == 507, r.text
        assert r.headers["content-type"].startswith(PROBLEM)
        p = r.json()
        assert p["code"] == "storage_quota_exceeded"
        assert p["limit"] == "SCANMILL_MAX_STORED_BYTES_PER_KEY" and p["limit_value"] == MIB
        assert p["used_bytes"] == size and p["needed_bytes"] == size
        assert "SCANMILL_MAX_STORED_BYTES_PER_KEY" in p["detail"] and "DELETE /jobs/" in p["detail"]
        assert list((anon_server.data_dir / "tmp").iterdir()) == []          # the refused upload is not kept
        # cancelling the first job frees its upload: the same submission now fits
        assert c.delete(f"/jobs/{first.json()['id']}").status_code == 200
        again = submit(c, big_cloud)
        assert again.status_code == 202, again.text
        _cancel_all(c)


def test_retention_deletes_old_finished_jobs_at_start(anon_server, cloud):
    """Finding 4 (no retention): a job finished longer ago than SCANMILL_RETENTION_DAYS is deleted by the
    sweep the server runs at start (and then periodically)."""
    from service.db import jobs
    from service.store import JobStore, iso_ago

    with anon_server.client() as c:
        old, recent = submit(c, cloud).json()["id"], submit(c, cloud).json()["id"]
        for jid in (old, recent):
            assert c.delete(f"/jobs/{jid}").status_code == 200
    anon_server.stop()
    store = JobStore(anon_server.data_dir / "scanmill.sqlite3")
    try:
        with store.engine.begin() as conn:
            conn.execute(jobs.update().where(jobs.c.id == old).values(finished_at=iso_ago(2 * 86400)))
    finally:
        store.close()
    (anon_server.data_dir / "jobs" / old / "input").mkdir(parents=True)     # as if it still had files
    anon_server.start()
    with anon_server.client() as c:
        wait_until(lambda: c.get(f"/jobs/{old}").status_code == 404)
        assert not (anon_server.data_dir / "jobs" / old).exists()
        assert c.get(f"/jobs/{recent}").json()["status"] == "cancelled"      # younger than a day: kept


def test_a_succeeded_job_counts_its_artifacts(tmp_path):
    """The stored bytes of a succeeded job are its upload and its artifacts (set when they are published)."""
    from service.storage import Storage
    from service.store import JobStore
    from service.workers import complete_attempt

    storage = Storage(tmp_path / "data")
    storage.open()
    store = JobStore(tmp_path / "data" / "scanmill.sqlite3")
    try:
        jid = "c" * 32
        (storage.input_dir(jid)).mkdir(parents=True)
        (storage.input_dir(jid) / "cloud.ply").write_bytes(b"x" * 1000)
        job = store.create(job_id=jid, owner="o", parameters={}, input={"path": "input/cloud.ply"},
                           time_limit_s=60, stored_bytes=1000)
        job = store.claim_next()
        work = storage.work_dir(jid, job.attempts)
        work.mkdir()
        (work / "plan.json").write_bytes(b"y" * 300)
        (work / "plan.npz").write_bytes(b"z" * 200)
        assert complete_attempt(store, storage, job, {"status": "planned"}, [])
        assert store.get(jid).stored_bytes == 1500 and store.usage("o") == (0, 1500)
    finally:
        store.close()
        storage.close()


def test_the_sweeper_runs_at_start_survives_a_failing_pass_and_stops(tmp_path):
    from service.retention import RetentionSweeper
    from service.settings import load_settings
    from service.storage import Storage
    from service.store import JobStore

    class Flaky:
        """A store whose first query fails, as a database that is down for a moment."""

        def __init__(self, store):
            self.store, self.calls = store, 0

        def __getattr__(self, name):
            attr = getattr(self.store, name)
            if name == "expired":
                self.calls += 1
                if self.calls == 1:
                    raise RuntimeError("the job store does not answer")
            return attr

    storage = Storage(tmp_path / "data")
    storage.open()
    store = JobStore(tmp_path / "data" / "scanmill.sqlite3")
    flaky = Flaky(store)
    sweeper = RetentionSweeper(load_settings(env={}), flaky, storage, interval_s=0.05).start()
    try:
        wait_until(lambda: sweeper.passes >= 3)           # the first pass failed; the next ones ran
        assert flaky.calls >= 3
    finally:
        sweeper.stop()
        store.close()
        storage.close()
    assert sweeper._thread is None
