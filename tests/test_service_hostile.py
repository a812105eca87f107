"""Untrusted uploads cannot take the service (issue 29): the files are read in child processes under the
job's memory limit, side by side up to SCANMILL_VALIDATION_WORKERS, the API process stays small and answers
/healthz meanwhile, a client that leaves before its 202 leaves no job, and `scanmill view` serves no link.

Every wait is a loop bounded in count; nothing asserts on elapsed time. Memory is read from /proc (VmHWM,
the process's peak resident set)."""

from __future__ import annotations

import io
import json
import os
import socket
import threading
import uuid
from pathlib import Path

import anyio
import httpx
import numpy as np
import pytest

from planning.report.files import write_ply
from service.problems import ApiError
from service.settings import load_settings
from service.validation import ClientGone, SubmissionChecker
from service_fixtures import HALF_SPHERE_PARAMS, ServerProcess, stray_files, wait_until, write_half_sphere

MIB = 1 << 20


# --------------------------------------------------------------------------------------------------
# hostile files (small to send, expensive if trusted)
# --------------------------------------------------------------------------------------------------

def png_bomb(side: int = 4472) -> bytes:
    """A grey PNG of side x side pixels: ~28 kB for 20 M pixels."""
    from PIL import Image
    buf = io.BytesIO()
    Image.new("L", (side, side), 128).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def jpeg_header_bomb(side: int = 13000) -> bytes:
    """A small valid JPEG whose SOF0 header is patched to claim side x side pixels (a few hundred bytes)."""
    from PIL import Image
    buf = io.BytesIO()
    Image.new("L", (8, 8), 100).save(buf, format="JPEG", quality=50)
    data = bytearray(buf.getvalue())
    at = data.find(b"\xff\xc0")
    assert at > 0
    data[at + 5:at + 7] = side.to_bytes(2, "big")       # height
    data[at + 7:at + 9] = side.to_bytes(2, "big")       # width
    return bytes(data)


def ply_claiming_faces(n_faces: int, count_type: str = "uchar", list_count: int | None = None) -> bytes:
    """A binary PLY with 3 vertices and a face element that claims ``n_faces`` records (one given)."""
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {n_faces}\nproperty list {count_type} int vertex_indices\n"
            "end_header\n").encode()
    verts = np.array([[0, 0, 0], [50, 0, 0], [0, 50, 0]], "<f4").tobytes()
    size = {"uchar": 1, "ushort": 2, "uint": 4}[count_type]
    count = 3 if list_count is None else list_count
    face = count.to_bytes(size, "little") + np.array([0, 1, 2], "<i4").tobytes()
    return head + verts + face


def degenerate_stl() -> bytes:
    """An ascii STL whose two triangles are both degenerate (a repeated corner, three points on a line)."""
    tris = [[(0, 0, 0), (0, 0, 0), (40, 0, 0)], [(0, 10, 0), (20, 10, 0), (40, 10, 0)]]
    lines = ["solid d"]
    for t in tris:
        lines += ["facet normal 0 0 1", "outer loop"] + [f"vertex {x} {y} {z}" for x, y, z in t] + \
                 ["endloop", "endfacet"]
    return ("\n".join(lines + ["endsolid d"]) + "\n").encode()


def float_tiff_with_nan() -> bytes:
    from PIL import Image
    yy, xx = np.mgrid[0:40, 0:40]
    img = np.exp(-((xx - 20.0) ** 2 + (yy - 20.0) ** 2) / 150.0).astype(np.float32)
    img[7, 11] = np.nan
    buf = io.BytesIO()
    Image.fromarray(img, mode="F").save(buf, format="TIFF")
    return buf.getvalue()


HOSTILE = {
    # name: (file name, bytes factory, statuses an honest answer may have)
    "png_bomb": ("bomb.png", png_bomb, (202, 413)),
    "jpeg_header_bomb": ("bomb.jpg", jpeg_header_bomb, (413, 422)),
    "ply_2.5e8_faces": ("faces.ply", lambda: ply_claiming_faces(250_000_000), (413, 422)),
    "ply_1e12_faces": ("huge.ply", lambda: ply_claiming_faces(10 ** 12), (413, 422)),
    "ply_list_count_ffffffff": ("list.ply", lambda: ply_claiming_faces(1, "uint", 0xFFFFFFFF), (422,)),
    "degenerate_mesh": ("flat.stl", degenerate_stl, (422,)),
    "nan_tiff": ("nan.tif", float_tiff_with_nan, (422,)),
}


# --------------------------------------------------------------------------------------------------
# the checker itself (child processes)
# --------------------------------------------------------------------------------------------------

def _settings(tmp_path: Path, **kw):
    return load_settings(env={}, data_dir=str(tmp_path / "data"), **kw)


def _spec(path: Path, params: dict | None = None) -> dict:
    return {"path": str(path), "fmt": None, "parameters": params or {}, "fixtures": []}


def test_checker_answers_the_readers_error_as_the_reader_raised_it(tmp_path):
    from planning.errors import InputError
    bad = tmp_path / "garbage.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nend_header\n1\n2\n")
    checker = SubmissionChecker(_settings(tmp_path))
    with pytest.raises(InputError) as info:
        anyio.run(lambda: checker.check(_spec(bad)))
    assert info.value.code in ("truncated_file", "unreadable_file", "too_few_points"), info.value.code
    assert 400 <= info.value.status < 500


def test_checker_runs_the_admission_estimate_and_keeps_its_problem_members(tmp_path):
    cloud = write_half_sphere(tmp_path / "hs.ply")
    checker = SubmissionChecker(_settings(tmp_path, job_memory_mb=64))
    fine_axes = {**HALF_SPHERE_PARAMS, "orientations": {"phi_step_deg": 0.2, "theta_step_deg": 0.2}}
    with pytest.raises(ApiError) as info:
        anyio.run(lambda: checker.check(_spec(cloud, fine_axes)))
    assert info.value.status == 422 and info.value.code == "job_too_large"
    assert info.value.extra["limit"] == "SCANMILL_JOB_MEMORY_MB" and info.value.extra["parameter"]


def test_a_read_past_the_memory_limit_fails_in_the_child_with_413(tmp_path):
    """The child runs under SCANMILL_JOB_MEMORY_MB of address space: a cloud that needs more to read is
    refused there (the API process never holds it)."""
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 100, (3_000_000, 3))
    big = tmp_path / "big.ply"
    write_ply(big, pts, binary=True)
    checker = SubmissionChecker(_settings(tmp_path, job_memory_mb=64))
    with pytest.raises(ApiError) as info:
        anyio.run(lambda: checker.check(_spec(big)))
    assert info.value.status == 413 and info.value.code == "too_large_for_memory"
    assert "SCANMILL_JOB_MEMORY_MB" in info.value.detail


def test_checks_run_side_by_side_up_to_the_setting(tmp_path):
    cloud = write_half_sphere(tmp_path / "hs.ply")
    checker = SubmissionChecker(_settings(tmp_path, validation_workers=2, validation_start_delay_s=1.0))
    peak, answers = [0], []

    async def one():
        answers.append(await checker.check(_spec(cloud, HALF_SPHERE_PARAMS)))

    async def watch():
        for _ in range(400):                       # bounded: until the three checks are done
            peak[0] = max(peak[0], checker.running)
            if len(answers) == 3:
                return
            await anyio.sleep(0.01)

    async def main():
        async with anyio.create_task_group() as tg:
            for _ in range(3):
                tg.start_soon(one)
            tg.start_soon(watch)

    anyio.run(main)
    assert [a["n_points"] for a in answers] == [2537] * 3
    assert peak[0] == 2                            # two at once, the third waited for a place


def test_a_client_that_leaves_stops_its_check(tmp_path):
    import psutil
    cloud = write_half_sphere(tmp_path / "hs.ply")
    checker = SubmissionChecker(_settings(tmp_path, validation_start_delay_s=30.0))
    asked = [0]

    async def gone() -> bool:
        asked[0] += 1
        return asked[0] > 3                        # the client goes away while the child waits

    # the fork server (and the resource tracker it starts with) up first: run alone, the test would
    # otherwise count the tracker as a process the check left behind
    assert checker.warm()
    before = {p.pid for p in psutil.Process().children(recursive=True)}
    with pytest.raises(ClientGone):
        anyio.run(lambda: checker.check(_spec(cloud), disconnected=gone))
    left = [p for p in psutil.Process().children(recursive=True)
            if p.pid not in before and p.status() != psutil.STATUS_ZOMBIE and "forkserver" not in " ".join(p.cmdline())]
    assert not left, left                          # the check's process was killed and reaped


# --------------------------------------------------------------------------------------------------
# a real service on 127.0.0.1
# --------------------------------------------------------------------------------------------------

def _vm(pid: int, field: str) -> int:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    raise AssertionError(field)


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("hostile")
    srv = ServerProcess(root / "data", workers=1, validation_workers=2, job_time_limit_s=600).start()
    yield srv
    srv.stop()


def test_hostile_files_are_refused_or_bounded_while_the_service_answers(server, tmp_path):
    """Each hostile file: a clean answer (4xx, or 202 for the image bomb scaled down to
    input.relief.max_pixels), the API process's peak resident memory grows by less than 300 MB over all of
    them, and /healthz, polled throughout from another thread, answers 200 every time."""
    pid = server.proc.pid
    with server.client() as c:
        warm = write_half_sphere(tmp_path / "hs.ply")                 # the first upload imports what it needs
        with open(warm, "rb") as fh:
            r = c.post("/jobs", files={"cloud": ("hs.ply", fh)}, data={"parameters": json.dumps(HALF_SPHERE_PARAMS)})
        assert r.status_code == 202, r.text
        c.delete(f"/jobs/{r.json()['id']}")
        hwm0 = _vm(pid, "VmHWM")
        health: list[int] = []
        done = threading.Event()

        def poll():
            with httpx.Client(base_url=server.url, timeout=30) as h:
                for _ in range(3000):                                 # bounded; stops when the uploads are done
                    if done.is_set():
                        return
                    health.append(h.get("/healthz").status_code)

        t = threading.Thread(target=poll)
        t.start()
        answers = {}
        try:
            for name, (fname, make, ok) in HOSTILE.items():
                r = c.post("/jobs", files={"cloud": (fname, make(), "application/octet-stream")},
                           data={"parameters": "{}"})
                answers[name] = (r.status_code, r.json().get("code"))
                assert r.status_code in ok, (name, r.status_code, r.text)
                if r.status_code == 202:                              # accepted, scaled down: not planned here
                    job = r.json()
                    assert any("max_pixels" in w for w in job["warnings"]), job["warnings"]
                    c.delete(f"/jobs/{job['id']}")
                else:
                    assert r.headers["content-type"] == "application/problem+json"
        finally:
            done.set()
            t.join()
        growth = _vm(pid, "VmHWM") - hwm0
    assert health and set(health) == {200}, health
    assert growth < 300 * MIB, f"the API process grew by {growth / MIB:.0f} MiB: {answers}"
    assert answers["nan_tiff"][1] == "non_finite"
    assert answers["degenerate_mesh"][1] == "too_few_points"


def test_healthz_answers_while_a_submission_is_checked(tmp_path_factory):
    root = tmp_path_factory.mktemp("slowcheck")
    cloud = write_half_sphere(root / "hs.ply")
    with ServerProcess(root / "data", workers=1, validation_start_delay_s=4.0) as srv:
        result = {}

        def post():
            with srv.client() as c, open(cloud, "rb") as fh:
                result["r"] = c.post("/jobs", files={"cloud": ("hs.ply", fh)},
                                     data={"parameters": json.dumps(HALF_SPHERE_PARAMS)})

        t = threading.Thread(target=post)
        t.start()
        answered_meanwhile = 0
        with srv.client() as c:
            for _ in range(200):                       # bounded
                if not t.is_alive():
                    break
                if c.get("/healthz").status_code == 200 and t.is_alive():
                    answered_meanwhile += 1
                if answered_meanwhile >= 3:
                    break
        t.join()
        assert answered_meanwhile >= 3                  # /healthz answered three times while the check ran
        assert result["r"].status_code == 202, result["r"].text
        with srv.client() as c:
            c.delete(f"/jobs/{result['r'].json()['id']}")


def test_healthz_answers_once_uploads_can_be_checked_without_waiting_for_the_planning_imports(tmp_path_factory):
    """The first upload after a start is checked at once: by the time /healthz first answers, the server's
    fork server (the parent of every check and job process) runs and has imported the planning code (its
    compiled kernels' library, llvmlite, is mapped). Before, it was started beside the first requests, and
    the first upload waited for those imports (17 s once on a loaded CI machine)."""
    import psutil

    root = tmp_path_factory.mktemp("readiness")
    with ServerProcess(root / "data", workers=1) as srv:
        forkservers = [p for p in psutil.Process(srv.proc.pid).children()
                       if "forkserver" in " ".join(p.cmdline())]
        assert len(forkservers) == 1, [p.cmdline() for p in psutil.Process(srv.proc.pid).children()]
        mapped = {m.path for m in forkservers[0].memory_maps()}
        assert any("libllvmlite" in path for path in mapped), sorted(mapped)[:40]
        assert "submission checks ready in" in srv.log_text()


def _raw_post(url: str, body: bytes, boundary: str, headers: dict[str, str]) -> socket.socket:
    host, port = url.removeprefix("http://").split(":")
    s = socket.create_connection((host, int(port)))
    head = (f"POST /jobs HTTP/1.1\r\nHost: {host}\r\nContent-Type: multipart/form-data; boundary={boundary}\r\n"
            f"Content-Length: {len(body)}\r\n" + "".join(f"{k}: {v}\r\n" for k, v in headers.items()) + "\r\n")
    s.sendall(head.encode() + body)
    return s


def _multipart(cloud: bytes, params: dict, boundary: str) -> bytes:
    parts = [f'--{boundary}\r\nContent-Disposition: form-data; name="parameters"\r\n\r\n{json.dumps(params)}\r\n'.encode(),
             f'--{boundary}\r\nContent-Disposition: form-data; name="cloud"; filename="hs.ply"\r\n'
             f'Content-Type: application/octet-stream\r\n\r\n'.encode() + cloud + b"\r\n",
             f"--{boundary}--\r\n".encode()]
    return b"".join(parts)


def test_a_client_that_gives_up_before_the_202_leaves_no_job_and_a_retry_creates_one(tmp_path_factory):
    root = tmp_path_factory.mktemp("gone")
    cloud = write_half_sphere(root / "hs.ply").read_bytes()
    key = str(uuid.uuid4())
    with ServerProcess(root / "data", workers=1, validation_start_delay_s=3.0) as srv:
        boundary = "b" + uuid.uuid4().hex
        s = _raw_post(srv.url, _multipart(cloud, HALF_SPHERE_PARAMS, boundary), boundary,
                      {"Idempotency-Key": key})
        s.close()                                       # gives up before any answer
        wait_until(lambda: "no job was created" in srv.log_text(), max_polls=300)
        with srv.client() as c:
            assert c.get("/jobs").json()["items"] == []
            assert stray_files(srv.data_dir, []) == []
            # the retry with the same key creates the job, once
            first = c.post("/jobs", files={"cloud": ("hs.ply", cloud)}, headers={"Idempotency-Key": key},
                           data={"parameters": json.dumps(HALF_SPHERE_PARAMS)})
            again = c.post("/jobs", files={"cloud": ("hs.ply", cloud)}, headers={"Idempotency-Key": key},
                           data={"parameters": json.dumps(HALF_SPHERE_PARAMS)})
            assert first.status_code == 202 and again.status_code == 202
            assert again.headers.get("Idempotent-Replayed") == "true"
            assert first.json()["id"] == again.json()["id"]
            assert [j["id"] for j in c.get("/jobs").json()["items"]] == [first.json()["id"]]
            c.delete(f"/jobs/{first.json()['id']}")


# --------------------------------------------------------------------------------------------------
# scanmill view: only the plan's own regular files
# --------------------------------------------------------------------------------------------------

def test_scanmill_view_serves_no_symbolic_link_and_nothing_outside_the_plan(tmp_path):
    from fastapi.testclient import TestClient

    from scanmill.viewer.local import create_local_app
    plan = tmp_path / "plan"
    plan.mkdir()
    secret = tmp_path / "secret.txt"
    secret.write_text("not for the viewer")
    (plan / "viewer.json").write_text("{}")
    (plan / "plan.json").symlink_to(secret)                 # a link to a file outside the plan
    (plan / "preview.png").symlink_to("/etc/passwd")
    (plan / "viewer.points.bin").write_bytes(b"\x00" * 8)
    os.symlink(plan / "viewer.points.bin", plan / "deviation.png")   # a link even inside the folder
    auth = {"Authorization": "Bearer k" * 1}
    with TestClient(create_local_app(plan, "k")) as c:
        assert c.get("/artifacts/viewer.json", headers=auth).status_code == 200
        assert c.get("/artifacts/viewer.points.bin", headers=auth).status_code == 200
        for name in ("plan.json", "preview.png", "deviation.png", "..%2Fsecret.txt", "unmachined.png"):
            r = c.get(f"/artifacts/{name}", headers=auth)
            assert r.status_code == 404, (name, r.status_code)
            assert "not for the viewer" not in r.text and "root:" not in r.text
