"""A job's memory budget over the real HTTP service (issue 13, finding 1): "One parameter takes the host:
orientations.phi_step_deg=0.01 on the 2,537-point half sphere grew one worker to 23.5 GB and triggered the
kernel's OOM killer for the whole machine".

* Admission: a job whose estimate (planning/budget.py) exceeds ``SCANMILL_JOB_MEMORY_MB`` is answered
  ``422 job_too_large`` at submission, naming the parameter that drives it, the estimate and the limit.
* Enforcement: a job that gets to run anyway (here: accepted by a server with a larger budget, then
  started by a server restarted with a small one) runs under an address-space limit; it fails
  ``memory_limit_exceeded`` naming the limit, while the server's process tree stays within its
  baseline plus the limit, and the next job runs normally.
"""

from __future__ import annotations

import json
import time

import psutil
import pytest

from planning.inputs.samples import half_sphere
from schemas.params import parse_config
from service.admission import check_job_budget
from service.problems import ApiError
from service.settings import Settings

from service_fixtures import HALF_SPHERE_PARAMS, ServerProcess, submit, wait_status, wait_until, write_half_sphere

LIMIT_MB = 512
MIB = 1 << 20
#: The finding's parameters: the half sphere at a 0.01-degree polar step (216,000 candidate axes).
FINDING = {**HALF_SPHERE_PARAMS, "orientations": {"phi_step_deg": 0.01}}
#: A job the estimate lets through under a large budget but that needs far more than LIMIT_MB at once:
#: 0.1-degree steps (14,401 axes within travel), the collision checks off so that it gets there in seconds.
HUNGRY = {**HALF_SPHERE_PARAMS, "orientations": {"phi_step_deg": 0.1},
          "visibility": {"cone_deg": [10, 80], "global": False, "travel": False}}


@pytest.fixture(scope="module")
def cloud(tmp_path_factory):
    return write_half_sphere(tmp_path_factory.mktemp("in") / "half_sphere.ply")


def tree_rss(pid: int) -> int:
    """Resident bytes of a process and all its descendants (the server, its fork server, the workers)."""
    try:
        root = psutil.Process(pid)
        procs = [root] + root.children(recursive=True)
    except psutil.Error:
        return 0
    total = 0
    for p in procs:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass
    return total


def test_check_job_budget_names_the_parameter_the_estimate_and_the_limit(tmp_path):
    settings = Settings(data_dir=tmp_path, job_memory_mb=2048)
    n = half_sphere().points.shape[0]
    with pytest.raises(ApiError) as e:
        check_job_budget(parse_config(FINDING), n, settings, extent_mm=(100, 100, 50))
    err = e.value
    assert err.status == 422 and err.code == "job_too_large"
    assert err.extra["limit"] == "SCANMILL_JOB_MEMORY_MB" and err.extra["limit_value"] == 2048
    assert err.extra["estimate_mb"] > 100 * 2048 and err.extra["parameter"] == "orientations.phi_step_deg"
    assert "orientations.phi_step_deg" in err.detail and "2,048 MiB" in err.detail
    assert f"{err.extra['estimate_mb']:,} MiB" in err.detail and "144,001 candidate axes" in err.detail
    # the same cloud with the service tests' parameters fits easily, also without its extent
    assert check_job_budget(parse_config(HALF_SPHERE_PARAMS), n, settings).total_bytes < 2048 * MIB
    assert check_job_budget(parse_config(HALF_SPHERE_PARAMS), n, settings,
                            extent_mm=(100, 100, 50)).total_bytes < LIMIT_MB * MIB


def test_the_finding_is_refused_at_submission(tmp_path, cloud):
    with ServerProcess(tmp_path / "data", workers=1, job_memory_mb=LIMIT_MB) as srv, srv.client() as c:
        r = submit(c, cloud, FINDING)
        assert r.status_code == 422, r.text
        assert r.headers["content-type"].startswith("application/problem+json")
        body = r.json()
        assert body["code"] == "job_too_large" and body["status"] == 422
        assert body["limit"] == "SCANMILL_JOB_MEMORY_MB" and body["limit_value"] == LIMIT_MB
        assert body["estimate_mb"] > LIMIT_MB and "orientations.phi_step_deg" in body["detail"]
        assert f"{LIMIT_MB:,} MiB" in body["detail"]
        assert c.get("/jobs").json()["items"] == []                    # nothing was kept
        assert not any((srv.data_dir / "jobs").iterdir())
        assert not any((srv.data_dir / "tmp").iterdir())
        # the same cloud with ordinary parameters is accepted and planned under the same budget
        ok = submit(c, cloud)
        assert ok.status_code == 202, ok.text
        assert wait_status(c, ok.json()["id"])["status"] == "succeeded"


def test_a_job_over_its_memory_limit_fails_alone(tmp_path, cloud):
    data = tmp_path / "data"
    # accepted under a large budget; the worker waits before reading, and the server is killed meanwhile
    with ServerProcess(data, workers=1, max_attempts=3, job_memory_mb=64 * 1024, worker_start_delay_s=300) as srv:
        with srv.client() as c:
            r = submit(c, cloud, HUNGRY)
            assert r.status_code == 202, r.text
            jid = r.json()["id"]
            wait_status(c, jid, statuses=("running",))
            wait_until(srv.worker_pids)
            baseline = tree_rss(srv.proc.pid)                  # server, fork server and a started worker
        srv.kill9()
    # the service comes back with a small budget and starts the job again under it
    with ServerProcess(data, workers=1, max_attempts=3, job_memory_mb=LIMIT_MB) as srv2, srv2.client() as c:
        peak = 0
        job = None
        for _ in range(3000):                                  # bounded: at most ~5 min of 0.1 s polls
            peak = max(peak, tree_rss(srv2.proc.pid))
            job = c.get(f"/jobs/{jid}").json()
            if job["status"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.1)
        assert job is not None and job["status"] == "failed", json.dumps(job)[:2000]
        assert job["error"]["code"] == "memory_limit_exceeded", job["error"]
        msg = job["error"]["message"]
        assert "SCANMILL_JOB_MEMORY_MB" in msg and f"{LIMIT_MB:,} MiB" in msg and "phi_step_deg" in msg
        assert job["attempts"] == 2
        # the job stayed inside its budget: the whole tree never grew past the baseline plus the limit
        assert peak <= baseline + LIMIT_MB * MIB, (peak / MIB, baseline / MIB)
        assert wait_until(lambda: srv2.worker_pids() == [])
        assert not any((data / "jobs" / jid).glob("work-*"))
        # the service is unharmed: the next job runs to the end under the same limit
        nxt = submit(c, cloud)
        assert nxt.status_code == 202, nxt.text
        assert wait_status(c, nxt.json()["id"])["status"] == "succeeded"
