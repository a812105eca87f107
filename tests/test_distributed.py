"""The distributed backend end to end: API -> Redis -> Celery workers -> PostgreSQL, on real servers.

Redis and PostgreSQL are started on 127.0.0.1 by tests/servers.py; the API (``scanmill serve``) and
the workers (``scanmill worker``) run as separate processes, as on separate machines: they share
only the broker, the database and the data directory, which the workers reach through another
path (a symlink standing for a network mount). Timings are shortened through the documented
settings (heartbeat 0.5 s, lease 3 s, broker visibility timeout 6 s). Every wait is bounded in
count; nothing asserts on elapsed time.
"""
# ruff: noqa: F811  (pytest fixtures imported from servers.py are redefined as test arguments)

from __future__ import annotations

import re

import pytest
import sqlalchemy as sa

from service_fixtures import ServerProcess, WorkerProcess, submit, wait_status, wait_until, write_half_sphere
from servers import postgres_server, postgres_url, redis_server, redis_url  # noqa: F401  (fixtures)


@pytest.fixture
def cluster(tmp_path, redis_url, postgres_url):
    """Settings shared by the API and the workers, and the worker's view of the shared directory."""
    shared = tmp_path / "shared"
    shared.mkdir()
    mount = tmp_path / "mnt-scanmill"
    mount.symlink_to(shared, target_is_directory=True)
    common = dict(backend="celery", broker_url=redis_url, database_url=postgres_url, heartbeat_s=0.5, lease_s=3,
                  broker_visibility_timeout_s=6, max_attempts=3)
    return {"api": dict(common, reaper_interval_s=1), "worker": dict(common, data_dir=mount),
            "shared": shared, "logs": tmp_path / "logs", "cloud": write_half_sphere(tmp_path / "half_sphere.ply"),
            "database_url": postgres_url}


def _api(cluster, **extra) -> ServerProcess:
    cluster["logs"].mkdir(exist_ok=True)
    return ServerProcess(cluster["shared"], log_dir=cluster["logs"], **dict(cluster["api"], **extra))


def _worker(cluster, name, **extra) -> WorkerProcess:
    return WorkerProcess(name, cluster["logs"], **dict(cluster["worker"], **extra))


def _row(cluster, job_id) -> dict:
    eng = sa.create_engine(cluster["database_url"])
    try:
        with eng.connect() as c:
            return dict(c.execute(sa.text("SELECT * FROM jobs WHERE id = :i"), {"i": job_id}).one()._mapping)
    finally:
        eng.dispose()


def test_a_job_runs_through_redis_a_worker_and_postgres(cluster):
    with _api(cluster) as api, _worker(cluster, "w1", worker_threads=3) as w, api.client() as c:
        # the pool child runs with its BLAS/OpenMP and numba thread pools at SCANMILL_WORKER_THREADS
        line = wait_until(lambda: re.search(r"pool child \d+: 3 thread\(s\) per job; effective: (.*)", w.log_text()))
        effective = dict(kv.split("=") for kv in line.group(1).split(", "))
        assert effective.get("numba") == "3" and effective.get("openblas") == "3", effective
        r = submit(c, cluster["cloud"])
        assert r.status_code == 202, r.text
        jid = r.json()["id"]
        seen = set()

        def progressed():
            j = c.get(f"/jobs/{jid}").json()
            seen.add((j["status"], j["stage"]))
            return j if j["status"] in ("succeeded", "failed", "cancelled") else None

        job = wait_until(progressed, max_polls=1200, interval=0.05)
        assert job["status"] == "succeeded", job
        assert job["attempts"] == 1 and job["result"]["n_setups"] >= 1
        assert any(s == "running" for s, _ in seen)            # progress came back through the job store
        names = {a["name"] for a in c.get(f"/jobs/{jid}/artifacts").json()["items"]}
        assert {"plan.json", "plan.npz"} <= names and any(n.endswith(".nc") for n in names)
        plan = c.get(f"/jobs/{jid}/result").json()
        assert plan["status"] == job["result"]["status"] and len(plan["setups"]) == job["result"]["n_setups"]
        row = _row(cluster, jid)                                 # the record lives in PostgreSQL
        assert row["status"] == "succeeded" and row["worker"].startswith("w1@test/") and row["dispatched_at"]
        # the worker wrote through its own mount path; the API serves the same files
        assert (cluster["shared"] / "jobs" / jid / "result" / "plan.json").is_file()
        assert not list((cluster["shared"] / "jobs" / jid).glob("work-*"))
        health = c.get("/healthz").json()
        assert health["queued_jobs"] == 0 and health["running_jobs"] == 0


def test_a_killed_worker_job_is_redelivered_and_finishes(cluster):
    """kill -9 a worker in the middle of a job: the broker delivers the message again and another worker
    takes the job over. The API's reaper is off, so the broker's redelivery is the only way back."""
    with _api(cluster, reaper_interval_s=0) as api, api.client() as c:
        a = _worker(cluster, "wa", worker_start_delay_s=60).start()     # wa's attempts stall after claiming
        try:
            jid = submit(c, cluster["cloud"]).json()["id"]
            wait_until(lambda: _row(cluster, jid)["status"] == "running", max_polls=600)
            assert _row(cluster, jid)["worker"].startswith("wa@test/")
            children = a.children()
            assert children
            a.kill9()
            import psutil                                      # the pool child dies with its worker
            wait_until(lambda: not any(psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE
                                       for p in children), max_polls=300)
        finally:
            a.stop()
        assert c.get(f"/jobs/{jid}").json()["status"] == "running"   # nobody has noticed yet
        with _worker(cluster, "wb") as b:
            job = wait_status(c, jid, max_polls=1200)
            assert job["status"] == "succeeded", job
            assert job["attempts"] == 2
            assert _row(cluster, jid)["worker"].startswith("wb@test/")
            assert f"job {jid}: attempt 2 took over from a lost worker" in b.log_text()
            assert f"job {jid}: succeeded on attempt 2" in b.log_text()


def test_the_reaper_requeues_a_job_whose_worker_died_before_the_broker_would(cluster):
    """With the production-like visibility timeout (an hour) the broker would wait; the API's reaper sees the
    heartbeat go silent for a lease, queues the job again and publishes it: another worker runs attempt 2."""
    with _api(cluster, broker_visibility_timeout_s=3600) as api, api.client() as c:
        a = _worker(cluster, "wa", worker_start_delay_s=60, broker_visibility_timeout_s=3600).start()
        try:
            jid = submit(c, cluster["cloud"]).json()["id"]
            wait_until(lambda: _row(cluster, jid)["status"] == "running", max_polls=600)
            a.kill9()
        finally:
            a.stop()
        with _worker(cluster, "wb", broker_visibility_timeout_s=3600) as b:
            job = wait_status(c, jid, max_polls=1200)
            assert job["status"] == "succeeded" and job["attempts"] == 2, job
            assert f"job {jid}: attempt 2 started on wb@test/" in b.log_text()       # claimed from the queue
        assert f"'requeued': ['{jid}']" in api.log_text()


@pytest.mark.slow           # 2 min on 2 cores: eight plans; the default run keeps one job through both servers
def test_two_workers_drain_a_queue_and_no_job_completes_twice(cluster):
    n = 8
    with _api(cluster) as api, _worker(cluster, "w1") as w1, _worker(cluster, "w2") as w2, api.client() as c:
        ids = [submit(c, cluster["cloud"]).json()["id"] for _ in range(n)]
        jobs = [wait_status(c, j, max_polls=3000) for j in ids]
        assert [j["status"] for j in jobs] == ["succeeded"] * n
        assert all(j["attempts"] == 1 for j in jobs)
        done = re.compile(r"job ([0-9a-f]{32}): succeeded on attempt (\d+)")
        by_worker = {w.name: [m.group(1) for m in done.finditer(w.log_text())] for w in (w1, w2)}
        completions = by_worker["w1"] + by_worker["w2"]
        assert sorted(completions) == sorted(ids)              # each job completed once, by one worker
        assert by_worker["w1"] and by_worker["w2"]             # and both workers took part
        workers = {_row(cluster, j)["worker"].split("@")[0] for j in ids}
        assert workers == {"w1", "w2"}


def test_cancel_revokes_the_running_task(cluster):
    with _api(cluster) as api, _worker(cluster, "wc", worker_start_delay_s=60) as w, api.client() as c:
        jid = submit(c, cluster["cloud"]).json()["id"]
        wait_until(lambda: c.get(f"/jobs/{jid}").json()["status"] == "running", max_polls=600)
        before = set(w.children())
        r = c.delete(f"/jobs/{jid}")
        assert r.status_code == 200 and r.json()["status"] == "cancelled", r.text
        wait_until(lambda: f"Terminating {jid}" in w.log_text(), max_polls=300)
        wait_until(lambda: set(w.children()) and not (set(w.children()) & before), max_polls=300)  # child replaced
        assert c.get(f"/jobs/{jid}").json()["status"] == "cancelled"
        assert _row(cluster, jid)["status"] == "cancelled"


def test_a_job_accepted_while_the_broker_is_down_is_published_later(cluster):
    """The outbox: the API keeps the job queued in PostgreSQL and its reaper publishes it once Redis answers."""
    dead = "redis://127.0.0.1:1/0"
    # the reaper off: its own attempt to publish (every second here) marks the row while it tries the dead
    # broker, so reading the row while it ran could see the job taken for publication
    with _api(cluster, broker_url=dead, reaper_interval_s=0) as api, api.client() as c:
        r = submit(c, cluster["cloud"])
        assert r.status_code == 202, r.text
        jid = r.json()["id"]
        assert _row(cluster, jid)["dispatched_at"] is None and r.json()["status"] == "queued"
    # the API comes back with a reachable broker: the reaper publishes the job and a worker runs it
    with _api(cluster) as api, _worker(cluster, "w1"), api.client() as c:
        job = wait_status(c, jid, max_polls=1200)
        assert job["status"] == "succeeded" and job["attempts"] == 1


def test_a_job_taken_for_publication_by_an_api_that_died_is_published_again(cluster):
    """The outbox's window: an API takes a queued job for publication (``dispatched_at``) and dies before it
    sends the message, or before the broker's acceptance is recorded. The row is then queued, taken, and not
    confirmed (``published_at`` NULL); the next API's reaper gives it back after ``publish_grace_s`` and
    publishes it, and a worker runs it once. (Before the second mark such a job stayed queued for ever.)"""
    dead = "redis://127.0.0.1:1/0"
    with _api(cluster, broker_url=dead, reaper_interval_s=0) as api, api.client() as c:
        r = submit(c, cluster["cloud"])
        assert r.status_code == 202, r.text
        jid = r.json()["id"]
    # what the API leaves when it dies between the mark and the broker's answer
    eng = sa.create_engine(cluster["database_url"])
    try:
        with eng.begin() as c:
            c.execute(sa.text("UPDATE jobs SET dispatched_at = '2026-01-01T00:00:00.000+00:00', published_at = NULL "
                              "WHERE id = :i"), {"i": jid})
    finally:
        eng.dispose()
    with _api(cluster, publish_grace_s=2) as api, _worker(cluster, "w1"), api.client() as c:
        job = wait_status(c, jid, max_polls=1200)
        assert job["status"] == "succeeded" and job["attempts"] == 1
        assert f"'unconfirmed': ['{jid}']" in api.log_text()
    row = _row(cluster, jid)
    assert row["published_at"] is not None and row["dispatched_at"] != "2026-01-01T00:00:00.000+00:00"


def test_worker_refuses_to_start_without_a_broker_or_database(cluster):
    import subprocess
    import sys

    from service_fixtures import ROOT
    w = _worker(cluster, "bad")
    env = w.env()
    env.pop("SCANMILL_BROKER_URL")
    env.pop("SCANMILL_BACKEND")
    out = subprocess.run([sys.executable, "-m", "scanmill.cli", "worker"], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2 and "SCANMILL_BROKER_URL" in out.stderr
    env = w.env()
    env["SCANMILL_DATABASE_URL"] = "postgresql+psycopg://nobody@127.0.0.1:1/none"
    out = subprocess.run([sys.executable, "-m", "scanmill.cli", "worker"], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2 and "cannot reach the job database" in out.stderr


def test_a_redelivery_watches_the_heartbeat_before_taking_a_job_over(tmp_path):
    """A message delivered again right after its holder died finds a fresh heartbeat: it must wait for it to
    go stale (then take over) rather than drop the job; a holder that keeps beating keeps the job."""
    import threading

    from service.celery_tasks import _Context, _wait_for_holder
    from service.settings import Settings
    from service.storage import Storage
    from service.store import JobStore

    store = JobStore(tmp_path / "jobs.sqlite3")
    ctx = _Context(Settings(heartbeat_s=0.2, lease_s=1.0, max_attempts=3), store, Storage(tmp_path), 0)
    for jid, holder_alive in (("a" * 32, False), ("b" * 32, True)):
        store.create(job_id=jid, owner="o", parameters={}, input={}, time_limit_s=60)
        outcome, job = store.claim(jid, "first", lease_s=1.0, max_attempts=3)
        stop = threading.Event()

        def beat(job=job, stop=stop):
            while not stop.wait(0.2):
                store.heartbeat(job.id, job.attempts)

        t = threading.Thread(target=beat)
        if holder_alive:
            t.start()
        try:
            outcome, after = _wait_for_holder(ctx, job, "second")
        finally:
            stop.set()
            if holder_alive:
                t.join()
        if holder_alive:
            assert outcome == "busy" and store.get(jid).worker == "first" and store.get(jid).attempts == 1
        else:
            assert outcome == "taken_over" and after.worker == "second" and after.attempts == 2
    store.close()


def test_the_soft_time_limit_fails_the_job_on_the_worker(cluster):
    with _api(cluster, hard_time_limit_grace_s=5) as api, \
            _worker(cluster, "wt", worker_start_delay_s=60, hard_time_limit_grace_s=5) as w, api.client() as c:
        r = submit(c, cluster["cloud"], time_limit_s=2)
        assert r.status_code == 202, r.text
        job = wait_status(c, r.json()["id"], max_polls=600)
        assert job["status"] == "failed" and job["error"]["code"] == "time_limit_exceeded", job
        assert f"job {job['id']}: stopped at its time limit" in w.log_text()


def test_embedded_backend_on_postgres_and_a_store_outage_answers_503(tmp_path):
    """The embedded backend runs on PostgreSQL too; when the database goes away the API answers 503 problems
    (Retry-After) instead of 500, and a submission during the outage leaves no files behind."""
    from servers import PostgresServer

    from service_fixtures import stray_files
    pg = PostgresServer().start()
    try:
        cloud = write_half_sphere(tmp_path / "half_sphere.ply")
        with ServerProcess(tmp_path / "data", database_url=pg.create_database(), workers=1) as api, \
                api.client() as c:
            jid = submit(c, cloud).json()["id"]
            assert wait_status(c, jid, max_polls=1200)["status"] == "succeeded"
            pg.stop()
            for r in (c.get(f"/jobs/{jid}"), submit(c, cloud), c.get("/jobs"), c.get("/healthz")):
                assert r.status_code == 503, r.text
                assert r.headers["content-type"].startswith("application/problem+json")
                assert r.json()["code"] == "store_unavailable"
            assert stray_files(tmp_path / "data", [jid]) == []
            doc = c.get("/openapi.json").json()
            assert "503" in doc["paths"]["/jobs/{job_id}"]["get"]["responses"]
    finally:
        pg.stop()


@pytest.fixture
def restartable_redis():
    """A Redis of this test's own, with its append-only file, that the test may restart (same port, same file)."""
    from servers import RedisServer

    with RedisServer(appendonly=True) as server:
        yield server


@pytest.mark.slow           # two ~6 s outages and two jobs; the killed worker and the reaper stay in the default run
def test_two_redis_restarts_during_a_job_neither_fail_it_nor_cost_an_attempt(cluster, restartable_redis):
    """Issue 13, finding 2: Redis restarts twice, ~6 s down each time, while a job runs (the worker reconnects in
    between). The running task is not terminated, the worker does not stop, the copy of the message the broker
    hands out again finds the job running with a live heartbeat and leaves it alone: the job succeeds on
    attempt 1, and the next job runs too."""
    redis_srv = restartable_redis
    settings = {"broker_url": redis_srv.url, "max_attempts": 2}
    with _api(cluster, **settings) as api, api.client() as c, \
            _worker(cluster, "wr", workers=2, worker_start_delay_s=20, **settings) as w:
        jid = submit(c, cluster["cloud"]).json()["id"]
        wait_until(lambda: _row(cluster, jid)["status"] == "running", max_polls=600)
        for outage in (1, 2):
            row = _row(cluster, jid)
            assert (row["status"], row["attempts"]) == ("running", 1), (outage, row)   # the outage hits the job
            connected = w.log_text().count("consumer.connection: Connected to ")
            redis_srv.restart(down_s=6)
            # the worker reconnects by itself (the second time, while the job finishes)
            wait_until(lambda n=connected: w.log_text().count("consumer.connection: Connected to ") > n, max_polls=600)
        job = wait_status(c, jid, max_polls=1200)
        assert job["status"] == "succeeded", job
        assert job["attempts"] == 1, job
        log = w.log_text()
        losses = [m.start() for m in re.finditer("Connection to broker lost", log)]
        assert len(losses) == 2 and losses[1] < log.index(f"job {jid}: succeeded on attempt 1"), log[-3000:]
        assert "cannot be acknowledged after a connection loss" not in log and "Unrecoverable error" not in log
        assert f"job {jid}: delivery redelivered: nothing to do (busy)" in log    # the copy left the job alone
        assert "took over from a lost worker" not in log
        # the worker is still there and the broker works again: a new job is published, delivered and claimed
        again = submit(c, cluster["cloud"]).json()["id"]
        wait_until(lambda: _row(cluster, again)["status"] == "running", max_polls=600)
        assert _row(cluster, again)["worker"].startswith("wr@test/") and w.proc.poll() is None
        assert c.delete(f"/jobs/{again}").status_code == 200          # (so that the worker stops at once)


def test_healthz_counts_the_job_slots_of_the_live_celery_workers(cluster):
    """Issue 13, finding 8 (Celery): /healthz reported ``workers: 0`` while workers ran. It now reports the job
    slots of the workers that answer the API's census through the broker, and follows them as they come and go."""
    with _api(cluster) as api, api.client() as c:
        assert c.get("/healthz").json()["workers"] == 0                       # no worker yet
        with _worker(cluster, "h1", workers=1), _worker(cluster, "h2", workers=2) as h2:
            health = wait_until(lambda: (h := c.get("/healthz").json())["workers"] == 3 and h, max_polls=300)
            assert health["status"] == "ok" and health["busy_workers"] == 0
            h2.stop()
            wait_until(lambda: c.get("/healthz").json()["workers"] == 1, max_polls=300)


def test_a_job_over_its_memory_limit_fails_alone_on_the_worker(cluster):
    """Each Celery pool child runs its job under SCANMILL_JOB_MEMORY_MB (an address-space limit set when the attempt
    starts). A job that needs far more (1-degree orientation steps: matrices of gigabytes) fails
    ``memory_limit_exceeded`` on its first attempt, with the message naming the limit; the same child then runs a
    job within the budget. (The API admits the job: its own budget is large, so only the worker's limit acts.)"""
    import copy

    from service_fixtures import HALF_SPHERE_PARAMS

    from service.memlimit import memory_limit_message

    greedy = copy.deepcopy(HALF_SPHERE_PARAMS)
    greedy["orientations"] = {"phi_step_deg": 1, "theta_step_deg": 1}
    with _api(cluster, job_memory_mb=1024 * 1024) as api, api.client() as c, \
            _worker(cluster, "wm", workers=1, worker_threads=1, job_memory_mb=400) as w:
        r = submit(c, cluster["cloud"], greedy)
        assert r.status_code == 202, r.text
        job = wait_status(c, r.json()["id"], max_polls=1200)
        assert job["status"] == "failed", job
        assert job["error"] == {"code": "memory_limit_exceeded", "message": memory_limit_message(400)}, job
        assert job["attempts"] == 1, job
        assert f"job {job['id']}: failed [memory_limit_exceeded]" in w.log_text()
        children = w.children()
        ok = wait_status(c, submit(c, cluster["cloud"]).json()["id"], max_polls=1200)
        assert ok["status"] == "succeeded" and ok["attempts"] == 1, ok
        assert w.children() == children                           # the same pool child, its limit set anew


def test_the_worker_census_answers_from_memory_and_forgets_a_silent_broker():
    """/healthz reads the census and never waits on the broker: a dead broker gives no count (at once), a census
    counts each answering worker's pool size, and a count older than the census's max age is dropped."""
    import time
    from types import SimpleNamespace

    from service.celery_app import configure
    from service.celery_backend import WorkerCensus
    from service.settings import Settings

    dead = WorkerCensus(configure(Settings(backend="celery", broker_url="redis://127.0.0.1:1/0")))
    assert dead.take() is None and dead.workers() == {}

    class Conn:
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def ensure_connection(self, **_):
            return self

    stats = {"w1@a": {"pool": {"max-concurrency": 2}}, "w2@b": {"pool": {"max-concurrency": 1}}}
    app = SimpleNamespace(connection_for_write=Conn,
                          control=SimpleNamespace(inspect=lambda **_: SimpleNamespace(stats=lambda: stats)))
    census = WorkerCensus(app, max_age_s=0.05)
    assert census.take() == {"w1@a": 2, "w2@b": 1} == census.workers()
    time.sleep(0.1)
    assert census.workers() == {}


def test_broker_settings_pick_the_fixed_redis_transport_and_keep_tls():
    import ssl

    from service.celery_app import broker_options
    from service.settings import Settings

    def opts(url):
        return broker_options(Settings(backend="celery", broker_url=url))

    plain = opts("redis://127.0.0.1:6379/0")
    assert plain["broker_transport"] == "service.celery_app:RedisTransport" and plain["broker_use_ssl"] is None
    assert plain["broker_transport_options"]["socket_keepalive"] is True
    assert opts("rediss://h:6380/0")["broker_use_ssl"] == {"ssl_cert_reqs": ssl.CERT_REQUIRED}
    assert opts("rediss://h:6380/0?ssl_cert_reqs=none")["broker_use_ssl"] is None      # the URL says it
    assert opts("memory://")["broker_transport"] is None
