"""A full disk, the job side (issue 13, finding 3): "jobs compute for ~40 s and then fail OSError 28;
one job stayed `running` forever (marking it failed also failed) until a restart".

The embedded runner (``service.workers.JobRunner``) runs here in the test process, with its real
fork server and worker processes, over a real data directory and SQLite store. The disk is made
"full" in three ways: ``SCANMILL_MIN_FREE_DISK_MB`` larger than any disk (the free-space check before
a job starts trips), a worker whose artifact write fails with ENOSPC (fault injection in the worker
process: the runner starts :func:`run_job_disk_full` instead of ``run_job``), and a publication (the
rename of ``work-N`` to ``result``) that fails with ENOSPC. The job store write that marks the job
failed is then made to fail as well, for a while or for good.
Every wait is a loop bounded in count.
"""

from __future__ import annotations

import errno
import json
import time
from pathlib import Path

import pytest
import sqlalchemy as sa

import service.workers
from planning.inputs.samples import half_sphere
from planning.report.files import write_ply
from service.settings import Settings
from service.storage import Storage, new_job_id
from service.store import JobStore
from service.workers import JobRunner, run_job

from service_fixtures import HALF_SPHERE_PARAMS

HUGE_MB = 1024 * 1024 * 1024          # a reserve of 1 PiB: no disk has that much free


def write_plan_disk_full(outcome, out_dir, progress=None):
    """``write_plan`` on a disk that fills up: the first file is half written, then ENOSPC."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "plan.npz.tmp").write_bytes(b"\0" * 4096)
    raise OSError(errno.ENOSPC, "No space left on device", str(out / "plan.npz.tmp"))


def run_job_disk_full(spec, conn):
    """The worker entry point with the artifact write failing as on a full disk (runs in the worker process)."""
    import planning.report.plan_files
    planning.report.plan_files.write_plan = write_plan_disk_full
    run_job(spec, conn)


class Env:
    """A data directory, its store and storage, and queued half-sphere jobs."""

    def __init__(self, root: Path, **settings):
        self.settings = Settings(data_dir=root, workers=1, job_time_limit_s=600, **settings)
        self.storage = Storage(root)
        self.storage.open()
        self.store = JobStore(self.storage.db_path)

    def add_job(self) -> str:
        job_id = new_job_id()
        inp = self.storage.input_dir(job_id)
        inp.mkdir(parents=True)
        s = half_sphere()
        write_ply(inp / "cloud.ply", s.points, normals=s.normals, binary=True)
        self.store.create(job_id=job_id, owner="o", parameters=HALF_SPHERE_PARAMS, time_limit_s=600,
                          input={"path": "input/cloud.ply", "fmt": None, "n_points": 2537, "name": "half",
                                 "extent_mm": [100.0, 100.0, 50.0]})
        return job_id

    def runner(self) -> JobRunner:
        r = JobRunner(self.settings, self.store, self.storage)
        r.recover()
        r.start()
        return r

    def close(self) -> None:
        self.store.close()
        self.storage.close()


@pytest.fixture
def env(tmp_path):
    made = []

    def make(**settings) -> Env:
        e = Env(tmp_path / "data", **settings)
        made.append(e)
        return e

    yield make
    for e in made:
        e.close()


def wait_final(store: JobStore, job_id: str, max_polls: int = 1200):
    for _ in range(max_polls):
        job = store.get(job_id)
        if job.status in ("succeeded", "failed", "cancelled"):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} never ended: {store.get(job_id)}")


def wait_until(predicate, max_polls: int = 600):
    for _ in range(max_polls):
        v = predicate()
        if v:
            return v
        time.sleep(0.1)
    raise AssertionError("condition never became true")


def no_attempt_files(e: Env, job_id: str) -> bool:
    d = e.storage.job_dir(job_id)
    return not any(d.glob("work-*")) and not e.storage.result_dir(job_id).exists()


def run_to_the_end(e, jid):
    """Start a job runner, wait until the job is final, stop the runner; the job and what the runner still
    had to record in the store then (``unsettled``)."""
    runner = e.runner()
    try:
        return wait_final(e.store, jid), runner.unsettled
    finally:
        runner.stop()


def recover_at_next_start(e, jid):
    """What a new server's start does with the job: ``JobRunner.recover()`` on a fresh store; (outcome, job)."""
    store2 = JobStore(e.storage.db_path)
    try:
        return JobRunner(e.settings, store2, e.storage).recover(), store2.get(jid)
    finally:
        store2.close()


def test_a_job_does_not_start_when_the_disk_is_short_of_its_reserve(env):
    e = env(min_free_disk_mb=HUGE_MB)
    jid = e.add_job()
    job, _ = run_to_the_end(e, jid)
    assert job.status == "failed" and job.error_code == "insufficient_storage", (job.status, job.error_code)
    msg = job.error_message
    assert "SCANMILL_MIN_FREE_DISK_MB" in msg and "MiB are free" in msg and "not started" in msg
    assert job.stage == "read" and job.progress == 0.0 and job.attempts == 1   # no worker ever reported
    assert no_attempt_files(e, jid)


def test_an_artifact_write_that_hits_a_full_disk_fails_the_job_naming_the_free_space(env, monkeypatch):
    e = env()
    jid = e.add_job()
    monkeypatch.setattr(service.workers, "run_job", run_job_disk_full)
    job, _ = run_to_the_end(e, jid)
    assert job.status == "failed" and job.error_code == "disk_full", (job.error_code, job.error_message)
    assert "No space left on device" in job.error_message and "MiB free" in job.error_message
    assert "SCANMILL_DATA_DIR" in job.error_message
    assert no_attempt_files(e, jid)                       # nothing half-written stays


def test_a_publication_that_hits_a_full_disk_fails_the_job(env, monkeypatch):
    e = env()
    jid = e.add_job()

    def publish_disk_full(self, job_id, attempt):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Storage, "publish_result", publish_disk_full)
    job, _ = run_to_the_end(e, jid)
    assert job.status == "failed" and job.error_code == "disk_full", (job.error_code, job.error_message)
    assert "MiB free" in job.error_message
    assert no_attempt_files(e, jid)


def failing_store_writes(store: JobStore, failures: int | None, method: str = "fail") -> dict:
    """Make ``store.<method>`` raise as SQLite does on a full disk, the first ``failures`` times (None: always)."""
    real = getattr(store, method)
    calls = {"n": 0}

    def write(*args, **kw):
        calls["n"] += 1
        if failures is None or calls["n"] <= failures:
            raise sa.exc.OperationalError("UPDATE jobs SET ...", {}, Exception("database or disk is full"))
        return real(*args, **kw)

    setattr(store, method, write)
    return calls


def test_a_failure_the_store_cannot_record_is_settled_at_the_next_start(env, monkeypatch):
    e = env()
    jid = e.add_job()
    monkeypatch.setattr(service.workers, "run_job", run_job_disk_full)
    calls = failing_store_writes(e.store, None)
    runner = e.runner()
    try:
        wait_until(lambda: getattr(runner, "unsettled", None) == [jid])   # the retries are spent: kept for later
        assert calls["n"] >= 5
        record = e.storage.job_dir(jid) / "outcome-1.json"
        assert json.loads(record.read_text())["code"] == "disk_full"
        other = JobStore(e.storage.db_path)                  # what clients see meanwhile
        assert other.get(jid).status == "running"
        other.close()
    finally:
        runner.stop()
    # the service stops with the job still 'running' in the store; the next start settles it, no re-run
    out, job = recover_at_next_start(e, jid)
    assert out["failed"] == [jid] and out["requeued"] == [], out
    assert job.status == "failed" and job.error_code == "disk_full" and job.attempts == 1
    assert "MiB free" in job.error_message
    assert not record.exists() and no_attempt_files(e, jid)


def test_a_store_that_refuses_writes_for_a_while_gets_the_failure_later(env, monkeypatch):
    e = env()
    jid = e.add_job()
    monkeypatch.setattr(service.workers, "run_job", run_job_disk_full)
    calls = failing_store_writes(e.store, 6)     # more than one supervisor's tries: the dispatcher lands it
    job, unsettled = run_to_the_end(e, jid)
    assert job.status == "failed" and job.error_code == "disk_full" and calls["n"] == 7
    assert unsettled == [] and not (e.storage.job_dir(jid) / "outcome-1.json").exists()


def test_a_success_the_store_refuses_for_a_while_is_recorded_later(env):
    e = env()
    jid = e.add_job()
    calls = failing_store_writes(e.store, 6, "succeed")   # the files are published first, the row follows
    job, unsettled = run_to_the_end(e, jid)
    assert job.status == "succeeded" and calls["n"] == 7 and unsettled == []
    assert (e.storage.result_dir(jid) / "plan.json").is_file() and not any(e.storage.job_dir(jid).glob("work-*"))


def test_a_published_plan_the_store_never_recorded_succeeds_at_the_next_start(env):
    e = env()
    jid = e.add_job()
    failing_store_writes(e.store, None, "succeed")
    runner = e.runner()
    try:
        wait_until(lambda: runner.unsettled == [jid])
        assert (e.storage.result_dir(jid) / "plan.json").is_file()   # published; the store still says running
    finally:
        runner.stop()
    out, job = recover_at_next_start(e, jid)
    assert out["succeeded"] == [jid], out
    assert job.status == "succeeded" and job.attempts == 1 and job.result["n_setups"] >= 1
