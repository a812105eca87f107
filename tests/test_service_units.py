"""The service's parts without HTTP: settings, the job store's transitions (SQLite and PostgreSQL), file storage."""

from __future__ import annotations

import hashlib
import io
import os

import pytest

from service.settings import SettingsError, load_settings
from service.storage import (Storage, StorageLocked, UploadTooLarge, atomic_write_bytes, copy_stream,
                             safe_artifact_name)
from service.store import IdempotencyConflict, JobStore
from service.workers import JOB_STAGES, overall_progress

from servers import postgres_server, postgres_url  # noqa: F401  (fixtures: a real PostgreSQL on 127.0.0.1)


# -- settings ----------------------------------------------------------------------------------

def test_settings_from_env_file_and_flags(tmp_path):
    cfg = tmp_path / "scanmill.toml"
    cfg.write_text('workers = 3\nport = 9000\napi_keys = ["file-key-12345"]\n')
    s = load_settings(cfg, env={"SCANMILL_PORT": "9100", "SCANMILL_API_KEYS": "aaaaaaaa1, bbbbbbbb2",
                                "SCANMILL_JOB_TIME_LIMIT_S": "12.5"})
    assert s.workers == 3                      # from the file
    assert s.port == 9100                      # the environment wins over the file
    assert s.api_keys == ["aaaaaaaa1", "bbbbbbbb2"] and s.job_time_limit_s == 12.5
    assert load_settings(cfg, env={"SCANMILL_PORT": "9100"}, port=9200).port == 9200   # flags win
    assert load_settings(env={}).anonymous and load_settings(env={}).data_dir.name == "scanmill-data"


@pytest.mark.parametrize("env, words", [
    ({"SCANMILL_WORKERS": "0"}, ["SCANMILL_WORKERS", "greater than or equal to 1"]),
    ({"SCANMILL_API_KEYS": "short"}, ["SCANMILL_API_KEYS", "8 characters"]),
    ({"SCANMILL_START_METHOD": "fork"}, ["SCANMILL_START_METHOD"]),
])
def test_bad_settings_name_the_variable(env, words):
    with pytest.raises(SettingsError) as e:
        load_settings(env=env)
    for w in words:
        assert w in str(e.value)


def test_unknown_setting_in_file(tmp_path):
    cfg = tmp_path / "s.json"
    cfg.write_text('{"wokers": 2}')
    with pytest.raises(SettingsError, match="unknown setting 'wokers'"):
        load_settings(cfg, env={})


# -- store -------------------------------------------------------------------------------------

@pytest.fixture(params=["sqlite", "postgresql"])
def store(request, tmp_path):
    """The same transitions on both databases the store supports."""
    s = JobStore(tmp_path / "db.sqlite3" if request.param == "sqlite" else request.getfixturevalue("postgres_url"))
    assert s.dialect == request.param
    yield s
    s.close()


def _new(store, job_id, owner="o", key=None, h="h"):
    return store.create(job_id=job_id, owner=owner, parameters={"setups": {}}, input={"path": "input/cloud.ply"},
                        time_limit_s=10, idempotency_key=key, request_hash=h)


def test_store_lifecycle_and_fencing(store):
    _new(store, "a" * 32)
    job = store.claim_next()
    assert job.status == "running" and job.attempts == 1 and store.claim_next() is None
    assert store.update_progress(job.id, 1, "normals", 0.3, "x")
    assert not store.update_progress(job.id, 2, "normals", 0.4, "x")      # another attempt: refused
    assert store.requeue(job.id, 1, "restart")
    again = store.claim_next()
    assert again.attempts == 2
    assert not store.succeed(job.id, 1, {}, [])                            # the old attempt cannot finish it
    assert store.cancel(job.id, "someone-else") is None                    # not the owner
    assert store.cancel(job.id, "o").status == "cancelled"
    assert not store.succeed(job.id, 2, {}, [])                            # cancelled stays cancelled
    assert not store.fail(job.id, 2, "x", "y")
    assert store.get(job.id).status == "cancelled"
    assert store.delete(job.id, "o") and store.get(job.id) is None


def test_store_clean_requeue_gives_the_attempt_back(store):
    _new(store, "b" * 32)
    j = store.claim_next()
    assert store.requeue(j.id, 1, "stopped", count_attempt=False)
    assert store.get(j.id).attempts == 0 and store.get(j.id).status == "queued"


def test_store_idempotency_and_listing(store):
    _new(store, "1" * 32, key="k1", h="h1")
    with pytest.raises(IdempotencyConflict) as e:
        _new(store, "2" * 32, key="k1", h="h2")
    assert e.value.existing.id == "1" * 32 and e.value.existing.request_hash == "h1"
    _new(store, "2" * 32, key="k1", owner="other")                        # keys are per owner
    for c in "345":
        _new(store, c * 32)
    page, more = store.list("o", limit=2)
    assert [j.id for j in page] == ["5" * 32, "4" * 32] and more
    page2, more2 = store.list("o", limit=2, before_seq=page[-1].seq)
    assert [j.id for j in page2] == ["3" * 32, "1" * 32] and not more2
    assert store.list("o", status="running")[0] == []


def test_store_survives_reopening(tmp_path):
    s = JobStore(tmp_path / "db.sqlite3")
    _new(s, "c" * 32)
    s.close()
    s2 = JobStore(tmp_path / "db.sqlite3")
    assert s2.get("c" * 32).status == "queued"
    with s2.engine.connect() as c:
        assert c.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
    s2.close()


# -- storage -----------------------------------------------------------------------------------

@pytest.mark.parametrize("name, ok", [
    ("plan.json", True), ("area_0.nc", True), ("segmentation.ply", True), ("../plan.json", False),
    ("..", False), (".hidden", False), ("a/b", False), ("plan.json.tmp", False), ("", False), ("a" * 200, False),
    ("x\x00y", False), ("x..y", False),
])
def test_artifact_names(name, ok):
    assert safe_artifact_name(name) is ok


def test_artifact_path_stays_inside_the_result(tmp_path):
    st = Storage(tmp_path / "data")
    st.open()
    try:
        jid = "d" * 32
        res = st.result_dir(jid)
        res.mkdir(parents=True)
        (res / "plan.json").write_text("{}")
        (tmp_path / "secret.txt").write_text("s")
        os.symlink(tmp_path / "secret.txt", res / "link.txt")
        assert st.artifact_path(jid, "plan.json") == (res / "plan.json").resolve()
        assert st.artifact_path(jid, "link.txt") is None
        assert st.artifact_path(jid, "../result/plan.json") is None
        assert [p.name for p in st.artifacts(jid)] == ["plan.json"]
    finally:
        st.close()


def test_one_server_per_data_dir_and_sweep(tmp_path):
    a = Storage(tmp_path / "data")
    a.open()
    b = Storage(tmp_path / "data")
    with pytest.raises(StorageLocked):
        b.open()
    (a.tmp_dir / "upload-x").mkdir()
    (a.jobs_dir / ("e" * 32)).mkdir()                 # a folder no job owns
    keep = a.jobs_dir / ("f" * 32)
    (keep / "work-1").mkdir(parents=True)
    (keep / "input").mkdir()
    removed = a.sweep(["f" * 32])
    assert len(removed) == 3
    assert list(a.tmp_dir.iterdir()) == [] and [p.name for p in a.jobs_dir.iterdir()] == ["f" * 32]
    assert [p.name for p in keep.iterdir()] == ["input"]
    a.close()
    b.open()                                          # released: another server may take it now
    b.close()


def test_atomic_and_bounded_writes(tmp_path):
    atomic_write_bytes(tmp_path / "x.bin", b"abc")
    assert (tmp_path / "x.bin").read_bytes() == b"abc" and [p.name for p in tmp_path.iterdir()] == ["x.bin"]
    size, sha = copy_stream(io.BytesIO(b"12345"), tmp_path / "ok", max_bytes=5)
    assert size == 5 and sha == hashlib.sha256(b"12345").hexdigest()
    with pytest.raises(UploadTooLarge):
        copy_stream(io.BytesIO(b"123456"), tmp_path / "big", max_bytes=5)
    assert not (tmp_path / "big").exists()


def test_overall_progress_is_monotonic():
    values = [overall_progress(s, f) for s in JOB_STAGES for f in (0.0, 0.5, 1.0)]
    assert values == sorted(values) and values[0] == 0.0 and values[-1] == 1.0


def test_every_pipeline_stage_moves_the_progress():
    """The tool paths and posts take most of a job's time: their progress must show, in pipeline order."""
    from planning.pipeline import STAGES

    assert list(STAGES) == [s for s in JOB_STAGES if s in STAGES]
    for s in STAGES:
        assert overall_progress(s, 0.0) < overall_progress(s, 1.0), s


# -- auth --------------------------------------------------------------------------------------

def _request(host: str, settings):
    from starlette.requests import Request

    class _App:
        class state:
            pass
    _App.state.settings = settings
    return Request({"type": "http", "method": "GET", "path": "/jobs", "headers": [], "client": (host, 5000),
                    "app": _App})


@pytest.mark.parametrize("host, allowed", [("127.0.0.1", True), ("127.8.9.10", True), ("::1", True),
                                           ("10.0.0.5", False), ("192.168.1.2", False), ("8.8.8.8", False)])
def test_anonymous_access_is_for_loopback_only(host, allowed):
    import asyncio

    from service.auth import get_principal
    from service.problems import ApiError
    settings = load_settings(env={})
    req = _request(host, settings)
    if allowed:
        assert asyncio.run(get_principal(req, None, settings)).anonymous
    else:
        with pytest.raises(ApiError) as e:
            asyncio.run(get_principal(req, None, settings))
        assert e.value.status == 403 and "local machine" in e.value.detail and "SCANMILL_API_KEYS" in e.value.detail


def test_keys_are_required_when_configured_and_owners_differ():
    import asyncio

    from fastapi.security import HTTPAuthorizationCredentials

    from service.auth import get_principal, owner_of_key
    from service.problems import ApiError
    settings = load_settings(env={"SCANMILL_API_KEYS": "first-key-1,second-key-2"})
    req = _request("127.0.0.1", settings)
    with pytest.raises(ApiError) as e:                       # even on loopback
        asyncio.run(get_principal(req, None, settings))
    assert e.value.status == 401 and "Bearer" in e.value.headers["WWW-Authenticate"]
    a = asyncio.run(get_principal(req, HTTPAuthorizationCredentials(scheme="Bearer", credentials="first-key-1"),
                                  settings))
    b = asyncio.run(get_principal(req, HTTPAuthorizationCredentials(scheme="Bearer", credentials="second-key-2"),
                                  settings))
    assert a.owner == owner_of_key("first-key-1") != b.owner and "first-key-1" not in a.owner


def test_serve_refuses_bad_settings_with_a_message(capsys, monkeypatch):
    from scanmill.cli import main
    monkeypatch.setenv("SCANMILL_JOB_TIME_LIMIT_S", "-5")
    assert main(["serve", "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert "--workers" in err and "SCANMILL_JOB_TIME_LIMIT_S" in err


def test_shared_storage_has_no_lock_stages_per_host_and_spares_young_folders(tmp_path):
    from service.storage import SharedStorage, open_storage
    a = SharedStorage(tmp_path / "data", host="api-1")
    b = SharedStorage(tmp_path / "data", host="api-2")
    assert isinstance(open_storage(tmp_path / "data", "shared"), SharedStorage)
    assert type(open_storage(tmp_path / "data", "local")) is Storage
    a.open()
    b.open()                                            # several machines at once: no lock
    st_a, st_b = a.new_staging(), b.new_staging()
    assert st_a.parent.name == "api-1" and st_b.parent.name == "api-2"
    young = a.jobs_dir / ("1" * 32)                     # a folder whose job row is about to be committed
    young.mkdir()
    old = a.jobs_dir / ("2" * 32)
    old.mkdir()
    os.utime(old, (0, 0))
    work = a.jobs_dir / ("3" * 32) / "work-1"           # an attempt running on some worker
    work.mkdir(parents=True)
    removed = a.sweep(["3" * 32])
    assert sorted(removed) == sorted([str(st_a), str(old)])
    assert st_b.exists() and young.exists() and work.exists()
    with pytest.raises(ValueError, match="unknown storage kind"):
        open_storage(tmp_path, "s3")
