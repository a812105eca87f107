"""Workers over real HTTP: cancelling stops the worker process, the per-job time limit stops it too,
results are refused until a job has succeeded, and workers run with pinned BLAS threads.

The server runs with ``SCANMILL_WORKER_START_DELAY_S`` so that a small job stays running long enough to
be cancelled (the worker waits before reading its cloud); the kill itself does not care what the
worker is doing.
"""

from __future__ import annotations

from pathlib import Path

import psutil
import pytest

from service_fixtures import ServerProcess, submit, wait_status, wait_until, write_half_sphere

DELAY_S = 120


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("workers")
    srv = ServerProcess(root / "data", workers=1, worker_start_delay_s=DELAY_S, worker_threads=3,
                        job_time_limit_s=900).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def c(server):
    with server.client() as client:
        yield client


@pytest.fixture(scope="module")
def cloud(tmp_path_factory):
    return write_half_sphere(tmp_path_factory.mktemp("in") / "half_sphere.ply")


def _running(c, server, job_id):
    job = wait_status(c, job_id, statuses=("running",))
    pids = wait_until(server.worker_pids)
    return job, pids


def _gone(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def test_cancel_running_job_stops_its_worker(server, c, cloud):
    jid = submit(c, cloud).json()["id"]
    job, pids = _running(c, server, jid)
    assert len(pids) == 1 and job["stage"] == "read"
    r = c.delete(f"/jobs/{jid}")
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["status"] == "cancelled" and body["error"]["code"] == "cancelled" and body["finished_at"]
    assert _gone(pids[0]), "the worker process still runs after DELETE answered"
    assert server.worker_pids() == []
    assert c.get(f"/jobs/{jid}").json()["status"] == "cancelled"
    assert c.get(f"/jobs/{jid}/result").status_code == 409
    # a cancelled job is finished: DELETE now removes it with its files
    assert c.delete(f"/jobs/{jid}").status_code == 204
    assert not (server.data_dir / "jobs" / jid).exists()


def test_cancel_queued_job_and_results_wait_for_success(server, c, cloud):
    first = submit(c, cloud).json()["id"]
    _running(c, server, first)
    queued = submit(c, cloud).json()["id"]              # one worker: this one waits behind the first
    j = c.get(f"/jobs/{queued}").json()
    assert j["status"] == "queued" and j["started_at"] is None
    for path in (f"/jobs/{first}/result", f"/jobs/{first}/artifacts", f"/jobs/{first}/artifacts/plan.json"):
        r = c.get(path)
        assert r.status_code == 409 and r.json()["job_status"] == "running", path
    assert c.get(f"/jobs/{queued}/result").json()["job_status"] == "queued"
    r = c.delete(f"/jobs/{queued}")
    assert r.status_code == 200 and r.json()["status"] == "cancelled" and r.json()["attempts"] == 0
    assert c.delete(f"/jobs/{first}").json()["status"] == "cancelled"
    assert wait_until(lambda: server.worker_pids() == [])
    # neither comes back to life
    for jid in (first, queued):
        assert c.get(f"/jobs/{jid}").json()["status"] == "cancelled"


def test_time_limit_stops_the_worker(server, c, cloud):
    jid = submit(c, cloud, time_limit_s=1.5).json()["id"]
    assert c.get(f"/jobs/{jid}").json()["time_limit_s"] == 1.5
    job = wait_status(c, jid)
    assert job["status"] == "failed"
    assert job["error"]["code"] == "time_limit_exceeded" and "1.5 s" in job["error"]["message"]
    assert wait_until(lambda: server.worker_pids() == [])
    assert not any(Path(server.data_dir, "jobs", jid).glob("work-*"))


def test_workers_pin_blas_threads(server, c, cloud):
    jid = submit(c, cloud).json()["id"]
    _, pids = _running(c, server, jid)
    env = psutil.Process(pids[0]).environ()
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        assert env.get(var) == "3", var      # SCANMILL_WORKER_THREADS, a value nobody sets by chance
    assert c.delete(f"/jobs/{jid}").status_code == 200


def test_health_reports_the_pool(server, c):
    h = c.get("/healthz").json()
    assert h["workers"] == 1 and h["busy_workers"] in (0, 1) and h["queued_jobs"] >= 0
