"""The jobs API end to end over real HTTP (uvicorn on 127.0.0.1): submit, poll, result, artifacts,
list, delete, idempotency, failures, and isolation between two API keys."""

from __future__ import annotations

import gzip
import http.client
import io
import json

import jsonschema
import numpy as np
import pytest

from planning.inputs.cloud import read_cloud
from planning.inputs.samples import half_sphere
from schemas.plan import plan_json_schema
from service_fixtures import (HALF_SPHERE_PARAMS, KEY_A, KEY_B, NO_PATHS_PARAMS, ServerProcess, submit, wait_status,
                              write_half_sphere)

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("svc")
    srv = ServerProcess(root / "data", api_keys=[KEY_A, KEY_B], workers=1).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def cloud(tmp_path_factory):
    return write_half_sphere(tmp_path_factory.mktemp("in") / "half_sphere.ply")


@pytest.fixture(scope="module")
def a(server):
    with server.client(KEY_A) as c:
        yield c


@pytest.fixture(scope="module")
def b(server):
    with server.client(KEY_B) as c:
        yield c


@pytest.fixture(scope="module")
def done_job(a, cloud):
    r = submit(a, cloud)
    assert r.status_code == 202, r.text
    return wait_status(a, r.json()["id"])


def test_submit_answers_202_with_location_and_the_job(a, cloud):
    r = submit(a, cloud, NO_PATHS_PARAMS, name="my part")
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/jobs/{job['id']}"
    assert job["status"] in ("queued", "running")
    assert job["input"]["n_points"] == 2537 and job["input"]["has_normals"] is True
    assert job["input"]["name"] == "my part"
    assert job["parameters"]["setups"]["max_setups"] == 2          # the validated configuration, defaults filled
    assert job["parameters"]["visibility"]["global"] is True
    assert job["links"]["self"] == f"/jobs/{job['id']}" and job["links"]["result"] is None
    final = wait_status(a, job["id"])
    assert final["status"] == "succeeded", final


def test_finished_job_reports_times_progress_and_summary(done_job):
    j = done_job
    assert j["status"] == "succeeded" and j["progress"] == 1.0 and j["stage"] == "write"
    assert j["created_at"] <= j["started_at"] <= j["finished_at"]
    assert j["attempts"] == 1 and j["error"] is None
    assert j["result"]["status"] in ("planned", "unfinished") and j["result"]["n_setups"] == 2
    assert j["result"]["coverage"] >= 0.95
    # the programs ran on the simulated machine: the verdict is part of the result, not an error
    assert j["result"]["verification"] in ("passed", "failed") and j["result"]["verification_message"]
    assert j["links"]["result"].endswith("/result") and j["links"]["artifacts"].endswith("/artifacts")


def test_result_is_a_valid_plan(a, done_job):
    r = a.get(done_job["links"]["result"])
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/json")
    doc = r.json()
    jsonschema.validate(doc, plan_json_schema())
    assert doc["input"]["n_points"] == 2537
    assert len(doc["setups"]) == 2 and doc["coverage"] == pytest.approx(done_job["result"]["coverage"])
    assert doc["parameters"]["normals"]["method"] == "input"


def test_artifacts_list_and_download(a, done_job):
    r = a.get(done_job["links"]["artifacts"])
    assert r.status_code == 200
    items = {it["name"]: it for it in r.json()["items"]}
    assert {"plan.json", "plan.npz", "segmentation.ply", "preview.png", "deviation.png", "deviation.ply",
            "stock.ply"} <= set(items)
    png = a.get(items["preview.png"]["href"])
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    assert png.content[:8] == b"\x89PNG\r\n\x1a\n" and len(png.content) == items["preview.png"]["size_bytes"]
    npz = np.load(io.BytesIO(a.get(items["plan.npz"]["href"]).content))
    assert npz["labels"].max() < 2 and npz["visibility"].dtype == bool
    seg = read_cloud(a.get(items["segmentation.ply"]["href"]).content)
    assert seg.points.shape == (2537, 3)
    # the NC programs and moves of every area, named in plan.json, served as text / JSON
    plan = a.get(done_job["links"]["result"]).json()
    for st in plan["setups"]:
        names = list(st["path"]["programs"].values()) + [st["path"]["moves"]]
        assert len(names) == 3 and set(names) <= set(items)
        nc = a.get(items[st["path"]["programs"]["iso"]]["href"])
        assert nc.status_code == 200 and nc.headers["content-type"].startswith("text/plain")
        assert "G68.2" in nc.text and nc.text.rstrip().endswith("%")
        moves = json.loads(gzip.decompress(a.get(items[st["path"]["moves"]]["href"]).content))   # .moves.json.gz
        assert moves["area_id"] == st["id"] and moves["setup"]["tool_axis_part"] == pytest.approx(st["tool_axis"])
        assert nc.text.count("\n") > 20
        assert npz[f"cl_{st['id']}"].shape[0] == st["path"]["finishing"]["n_cl"]


def test_summary_plan_json_service_result_and_viewer_tell_one_story(a, done_job):
    """Issue 34: the CLI's summary (scanmill.summary on plan.json, the lines `scanmill plan` prints), plan.json,
    the service's result headline and the viewer's data carry the same figures."""
    from scanmill.summary import figures_line, summary_lines

    plan = a.get(done_job["links"]["result"]).json()
    f = plan["figures"]
    head = done_job["result"]
    assert head["status"] == plan["status"] and head["message"] == plan["message"]
    assert head["finished_share"] == f["finished_share"] and head["machining_time_s"] == f["machining_time_s"]
    assert head["time_source"] == f["time_source"] == "simulated"
    assert plan["message"].startswith(f"{f['finished_share']:.1%} of the scan finished within tolerance") or \
        plan["message"].startswith(f"only {f['finished_share']:.1%} of the scan finished within tolerance")
    assert plan["status"] == ("unfinished" if f["finished_share"] < plan["parameters"]["setups"]["coverage"]
                              else "planned")
    items = {it["name"]: it for it in a.get(done_job["links"]["artifacts"]).json()["items"]}
    viewer = a.get(items["viewer.json"]["href"]).json()
    assert viewer["figures"] == f and viewer["machining_order"] == plan["machining_order"]
    lines = summary_lines(plan)
    assert figures_line(f) in lines
    assert f"({f['machining_time_s'] / 60:.1f} min, simulated)" in "\n".join(lines)
    assert f["finished"] + f["left"] + f["unreached"] + f["not_covered"] == f["n_points"] == 2537
    assert f["finished_share"] == pytest.approx(plan["verification"]["deviation"]["finished_share"], abs=1e-6)
    assert f["machining_time_s"] == pytest.approx(plan["verification"]["machining_time_s"], abs=0.05)


@pytest.mark.parametrize("name", ["../plan.json", "..", ".plan.json.tmp", "plan.json/", "nope.txt",
                                  "%2e%2e%2fplan.json", "..%2F..%2Fscanmill.sqlite3", "input"])
def test_artifact_names_cannot_escape_the_job(server, done_job, name):
    # http.client sends the path as given (httpx would fold the '..' segments on the client side)
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    try:
        conn.request("GET", f"{done_job['links']['self']}/artifacts/{name}",
                     headers={"Authorization": f"Bearer {KEY_A}"})
        resp = conn.getresponse()
        body = resp.read()
    finally:
        conn.close()
    assert resp.status == 404, body[:200]
    assert resp.getheader("content-type") == PROBLEM
    assert json.loads(body)["code"] in ("not_found", "artifact_not_found")


def test_inline_json_submission(a):
    s = half_sphere(n_points=400)
    body = {"name": "inline half sphere", "parameters": HALF_SPHERE_PARAMS,
            "cloud": {"points": s.points.tolist(), "normals": s.normals.tolist()}}
    r = a.post("/jobs", json=body)
    assert r.status_code == 202, r.text
    job = wait_status(a, r.json()["id"])
    assert job["status"] == "succeeded", job
    assert job["input"]["n_points"] == 400 and job["input"]["name"] == "inline half sphere"


def test_idempotency_key(a, cloud):
    key = {"Idempotency-Key": "retry-me-7f9c"}
    first = submit(a, cloud, NO_PATHS_PARAMS, headers=key)
    second = submit(a, cloud, NO_PATHS_PARAMS, headers=key)
    assert first.status_code == second.status_code == 202
    assert first.json()["id"] == second.json()["id"]
    assert second.headers.get("idempotent-replayed") == "true" and "idempotent-replayed" not in first.headers
    other = dict(NO_PATHS_PARAMS, setups={"coverage": 0.9, "max_setups": 2})
    conflict = submit(a, cloud, other, headers=key)
    assert conflict.status_code == 422 and conflict.headers["content-type"] == PROBLEM
    assert conflict.json()["code"] == "idempotency_key_reused"
    ids = [j["id"] for j in a.get("/jobs", params={"limit": 100}).json()["items"]]
    assert ids.count(first.json()["id"]) == 1
    wait_status(a, first.json()["id"])          # let it finish before the next test queues more


def test_idempotency_keys_are_per_caller(a, b, cloud):
    key = {"Idempotency-Key": "shared-key-123"}
    ja = submit(a, cloud, NO_PATHS_PARAMS, headers=key).json()["id"]
    jb = submit(b, cloud, NO_PATHS_PARAMS, headers=key).json()["id"]
    assert ja != jb
    wait_status(a, ja)
    wait_status(b, jb)


def test_list_newest_first_paginated_and_filtered(a, cloud):
    ids = []
    for _ in range(3):
        r = submit(a, cloud, NO_PATHS_PARAMS)
        assert r.status_code == 202
        ids.append(r.json()["id"])
    for i in ids:
        wait_status(a, i)
    page = a.get("/jobs", params={"limit": 2}).json()
    assert [j["id"] for j in page["items"]] == ids[::-1][:2]
    assert page["next_cursor"] and page["links"]["next"]
    page2 = a.get("/jobs", params={"limit": 2, "cursor": page["next_cursor"]}).json()
    assert page2["items"][0]["id"] == ids[0]
    seen = [j["id"] for j in page["items"] + page2["items"]]
    assert len(seen) == len(set(seen))
    ok = a.get("/jobs", params={"status": "succeeded", "limit": 100}).json()["items"]
    assert ok and all(j["status"] == "succeeded" for j in ok)
    assert a.get("/jobs", params={"status": "running-ish"}).status_code == 422
    assert a.get("/jobs", params={"cursor": "garbage!"}).status_code == 422


def test_delete_finished_job_removes_it_and_its_files(server, a, cloud):
    job = wait_status(a, submit(a, cloud, NO_PATHS_PARAMS).json()["id"])
    folder = server.data_dir / "jobs" / job["id"]
    assert (folder / "result" / "plan.json").is_file()
    r = a.delete(f"/jobs/{job['id']}")
    assert r.status_code == 204
    assert not folder.exists()
    assert a.get(f"/jobs/{job['id']}").status_code == 404
    assert a.delete(f"/jobs/{job['id']}").status_code == 404


def test_planning_failure_is_a_failed_job_with_a_reason(a, cloud):
    # an index zone beyond the cloud is only found when the plan runs (the cloud size is known then)
    params = dict(HALF_SPHERE_PARAMS, setups={"max_setups": 2, "functional_zones": [
        {"type": "indices", "indices": [999_999]}]})
    r = submit(a, cloud, params)
    assert r.status_code == 202, r.text
    job = wait_status(a, r.json()["id"])
    assert job["status"] == "failed" and job["result"] is None and job["finished_at"]
    assert job["error"]["code"] == "invalid_parameter"
    assert "functional_zones" in job["error"]["message"] and "999999" in job["error"]["message"]
    res = a.get(f"/jobs/{job['id']}/result")
    assert res.status_code == 409 and res.json()["job_status"] == "failed"
    assert "functional_zones" in res.json()["detail"]
    assert a.get(f"/jobs/{job['id']}/artifacts").status_code == 409


def test_machine_profile_must_be_a_bundled_name(a, cloud):
    for profile in ("no_such_machine", "/etc/passwd", "../planning/orientations/profiles/fork_head_ac.json"):
        r = submit(a, cloud, dict(HALF_SPHERE_PARAMS, machine={"profile": profile}))
        assert r.status_code == 422 and r.json()["code"] == "invalid_parameter"
        assert "machine.profile" in r.json()["detail"] and "compact_trunnion_bc" in r.json()["detail"]
    r = submit(a, cloud, dict(HALF_SPHERE_PARAMS, machine={"profile": "fork_head_ac"}))
    assert r.status_code == 202
    wait_status(a, r.json()["id"])


def test_mesh_fixtures_are_cli_only_and_primitives_are_planned(a, cloud):
    mesh = {"items": [{"type": "mesh", "path": "/etc/passwd"}]}
    r = submit(a, cloud, dict(HALF_SPHERE_PARAMS, fixtures=mesh))
    assert r.status_code == 422 and r.json()["code"] == "invalid_parameter"
    assert "fixtures.items[0]" in r.json()["detail"] and "CLI" in r.json()["detail"]
    # a clamp box beside the half sphere's rim: accepted, planned, and its removals reported
    box = {"items": [{"type": "box", "name": "clamp", "min_mm": [52, -10, 0], "max_mm": [70, 10, 25]}]}
    r = submit(a, cloud, dict(HALF_SPHERE_PARAMS, fixtures=box))
    assert r.status_code == 202
    job = wait_status(a, r.json()["id"])
    assert job["status"] == "succeeded"
    plan = a.get(f"/jobs/{job['id']}/result").json()
    assert plan["parameters"]["fixtures"]["items"][0]["name"] == "clamp"
    assert plan["visibility"]["removed_total"]["fixture_collision"] > 0


def test_isolation_between_keys(server, a, b, done_job):
    jid = done_job["id"]
    for path in (f"/jobs/{jid}", f"/jobs/{jid}/result", f"/jobs/{jid}/artifacts", f"/jobs/{jid}/artifacts/plan.json"):
        r = b.get(path)
        assert r.status_code == 404, path
        assert r.headers["content-type"] == PROBLEM and r.json()["code"] == "job_not_found"
    assert b.delete(f"/jobs/{jid}").status_code == 404
    assert jid not in [j["id"] for j in b.get("/jobs", params={"limit": 100}).json()["items"]]
    assert a.get(f"/jobs/{jid}").status_code == 200          # still there for its owner


def test_authentication_is_required(server, done_job):
    with server.client() as anon:
        r = anon.get("/jobs")
        assert r.status_code == 401 and r.headers["content-type"] == PROBLEM
        assert r.headers["www-authenticate"].startswith("Bearer")
        assert anon.get(f"/jobs/{done_job['id']}").status_code == 401
    with server.client("not-a-valid-key") as bad:
        r = bad.get("/jobs")
        assert r.status_code == 401 and r.json()["code"] == "invalid_api_key"
    with server.client() as anon:          # health, version and the OpenAPI document are public
        assert anon.get("/healthz").json()["status"] == "ok"
        assert anon.get("/version").json()["name"] == "scanmill"


def test_openapi_document_names_operations_tags_and_examples(server):
    with server.client() as c:
        doc = c.get("/openapi.json").json()
    ops = {op["operationId"]: op for path in doc["paths"].values() for op in path.values()}
    assert {"create_job", "get_job", "get_job_result", "list_artifacts", "get_artifact", "delete_job",
            "list_jobs"} <= set(ops)
    assert all(op.get("tags") for op in ops.values())
    body = ops["create_job"]["requestBody"]["content"]
    assert {"multipart/form-data", "application/json"} <= set(body)
    assert body["application/json"]["examples"]
    assert "example" in ops["get_job"]["responses"]["200"]["content"]["application/json"]
    for op in ops.values():
        for code, resp in op["responses"].items():
            if code.startswith("4"):
                assert list(resp["content"]) == ["application/problem+json"], (op["operationId"], code)


def test_unknown_route_and_method_are_problems(a):
    r = a.get("/nope")
    assert r.status_code == 404 and r.headers["content-type"] == PROBLEM
    r = a.put("/jobs")
    assert r.status_code == 405 and r.headers["content-type"] == PROBLEM and "allow" in r.headers
    assert json.loads(r.text)["status"] == 405
