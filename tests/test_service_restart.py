"""Durability: ``kill -9`` the server while a job runs, start it again on the same data directory.

The interrupted job runs again and finishes; a job interrupted ``SCANMILL_MAX_ATTEMPTS`` times fails
with code ``interrupted`` and a reason; a job that was queued runs after the restart; no accepted
job is lost, none stays 'running' forever, and the killed server leaves no worker behind.
"""

from __future__ import annotations

import psutil
import pytest

from service_fixtures import KEY_A, ServerProcess, submit, wait_status, wait_until, write_half_sphere


@pytest.fixture
def cloud(tmp_path):
    return write_half_sphere(tmp_path / "in" / "half_sphere.ply")


def _alive(pids) -> list[int]:
    out = []
    for p in pids:
        try:
            if psutil.Process(p).status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


def test_kill9_while_running_then_restart(tmp_path, cloud):
    data = tmp_path / "data"
    slow = dict(api_keys=[KEY_A], workers=1, max_attempts=2, worker_start_delay_s=300)
    with ServerProcess(data, **slow) as srv, srv.client(KEY_A) as c:
        running = submit(c, cloud).json()["id"]
        queued = submit(c, cloud).json()["id"]
        wait_status(c, running, statuses=("running",))
        workers = wait_until(srv.worker_pids)
        assert c.get(f"/jobs/{queued}").json()["status"] == "queued"
        srv.kill9()
    # the worker dies with the server (parent-death signal / watchdog), it does not run on unsupervised
    assert wait_until(lambda: _alive(workers) == [], max_polls=100)

    # second life, still slow: the interrupted job is started again (attempt 2), then we crash once more
    with ServerProcess(data, **slow) as srv2, srv2.client(KEY_A) as c:
        j = wait_status(c, running, statuses=("running",))
        assert j["attempts"] == 2
        assert c.get(f"/jobs/{queued}").json()["status"] == "queued"
        wait_until(srv2.worker_pids)
        srv2.kill9()

    # third life, fast: the twice-interrupted job fails with a reason, the queued one runs and succeeds
    with ServerProcess(data, api_keys=[KEY_A], workers=1, max_attempts=2) as srv3, srv3.client(KEY_A) as c:
        failed = wait_status(c, running)
        assert failed["status"] == "failed" and failed["error"]["code"] == "interrupted"
        assert "2 time" in failed["error"]["message"] and "SCANMILL_MAX_ATTEMPTS" in failed["error"]["message"]
        done = wait_status(c, queued)
        assert done["status"] == "succeeded", done
        assert c.get(f"/jobs/{queued}/result").json()["input"]["n_points"] == 2537
        listed = {j["id"]: j["status"] for j in c.get("/jobs", params={"limit": 100}).json()["items"]}
        assert listed == {running: "failed", queued: "succeeded"}          # nothing lost, nothing stuck
        assert list((data / "tmp").iterdir()) == []
        assert not list((data / "jobs").glob("*/work-*"))


def test_interrupted_job_runs_again_and_finishes(tmp_path, cloud):
    data = tmp_path / "data"
    with ServerProcess(data, api_keys=[KEY_A], workers=1, max_attempts=3, worker_start_delay_s=300) as srv, \
            srv.client(KEY_A) as c:
        jid = submit(c, cloud).json()["id"]
        wait_status(c, jid, statuses=("running",))
        srv.kill9()
    with ServerProcess(data, api_keys=[KEY_A], workers=1, max_attempts=3) as srv2, srv2.client(KEY_A) as c:
        job = wait_status(c, jid)
        assert job["status"] == "succeeded" and job["attempts"] == 2, job
        arts = {a["name"] for a in c.get(f"/jobs/{jid}/artifacts").json()["items"]}
        assert {"plan.json", "plan.npz", "segmentation.ply", "preview.png"} <= arts


def test_clean_stop_requeues_without_counting_an_attempt(tmp_path, cloud):
    data = tmp_path / "data"
    with ServerProcess(data, workers=1, max_attempts=1, worker_start_delay_s=300) as srv, srv.client() as c:
        jid = submit(c, cloud).json()["id"]
        wait_status(c, jid, statuses=("running",))
    # leaving the block stopped it with SIGTERM: a deliberate stop, not a crash
    with ServerProcess(data, workers=1, max_attempts=1) as srv2, srv2.client() as c:
        job = wait_status(c, jid)
        assert job["status"] == "succeeded" and job["attempts"] == 1, job


def test_second_server_on_the_same_data_dir_is_refused(tmp_path):
    data = tmp_path / "data"
    with ServerProcess(data, workers=1):
        other = ServerProcess(data, workers=1)
        with pytest.raises(RuntimeError, match="another scanmill server"):
            other.start(max_polls=50)
