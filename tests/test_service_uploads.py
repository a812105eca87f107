"""Bad uploads over real HTTP: each answers a 4xx problem document that says what is wrong (naming the
limit or parameter), no job is created, and no file is left behind in the data directory."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from planning.inputs.samples import half_sphere
from service_fixtures import HALF_SPHERE_PARAMS, ServerProcess, ascii_ply, stray_files, write_half_sphere

PROBLEM = "application/problem+json"
MAX_UPLOAD = 400_000          # bytes: the half sphere (~122 kB) fits, 'oversize' does not
MAX_INLINE = 1_000


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("uploads")
    srv = ServerProcess(root / "data", workers=1, max_upload_bytes=MAX_UPLOAD, max_json_bytes=200_000,
                        max_inline_points=MAX_INLINE, max_points=1_000_000, job_time_limit_s=600).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def c(server):
    with server.client() as client:          # anonymous: no keys configured, and we are on loopback
        yield client


@pytest.fixture(scope="module")
def good_ply(tmp_path_factory):
    return write_half_sphere(tmp_path_factory.mktemp("in") / "half_sphere.ply").read_bytes()


def post_file(c, content: bytes, filename="scan.ply", params=None, content_type="application/octet-stream",
              **fields):
    data = {"parameters": json.dumps(HALF_SPHERE_PARAMS if params is None else params)}
    data.update(fields)
    return c.post("/jobs", files={"cloud": (filename, content, content_type)}, data=data)


def assert_problem(r, status: int, code: str | None = None, *words: str) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    p = r.json()
    assert p["status"] == status and p["title"] and p["detail"] and p["type"].startswith("https://")
    if code:
        assert p["code"] == code, p
    for w in words:
        assert w.lower() in p["detail"].lower(), (w, p["detail"])
    return p


@pytest.fixture(autouse=True)
def no_stray_files(server, c):
    yield
    jobs = [j["id"] for j in c.get("/jobs", params={"limit": 100}).json()["items"]]
    assert stray_files(server.data_dir, jobs) == []


def _binary_ply_header(n: int) -> bytes:
    return (f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty double x\nproperty double y\n"
            f"property double z\nend_header\n").encode()


def test_truncated_ply(c, good_ply):
    assert_problem(post_file(c, good_ply[: len(good_ply) // 2]), 422, "truncated_file")


def test_binary_garbage(c):
    rng = np.random.default_rng(1)
    r = post_file(c, rng.integers(0, 256, 50_000, dtype=np.uint8).tobytes(), filename="scan.bin")
    p = assert_problem(r, 422)
    assert p["code"] in ("unreadable_file", "unsupported_format", "non_finite", "too_few_points")


def test_nan_coordinates(c):
    pts = half_sphere(n_points=200).points.copy()
    pts[7, 1] = np.nan
    assert_problem(post_file(c, ascii_ply(pts), params={}), 422, "non_finite")


def test_empty_file(c):
    assert_problem(post_file(c, b""), 422, "empty_cloud", "empty")


def test_header_claiming_billions_of_points(c):
    body = _binary_ply_header(3_000_000_000) + struct.pack("<3d", 1.0, 2.0, 3.0) * 10
    p = assert_problem(post_file(c, body), 413, "too_many_points", "1,000,000")
    assert p["limit_value"] == 1_000_000 and "max_points" in p["limit"]


def test_parameter_max_points_is_a_limit_too(c, good_ply):
    params = dict(HALF_SPHERE_PARAMS, input={"max_points": 1000})
    p = assert_problem(post_file(c, good_ply, params=params), 413, "too_many_points", "1,000")
    assert p["limit_value"] == 1000


def test_oversize_upload_with_content_length(c):
    p = assert_problem(post_file(c, b"0 0 0\n" * (MAX_UPLOAD // 6 + 1000), filename="big.xyz"), 413,
                       "request_too_large", f"{MAX_UPLOAD:,}")
    assert p["limit"] == "SCANMILL_MAX_UPLOAD_BYTES" and p["limit_value"] == MAX_UPLOAD


def test_oversize_upload_streamed_without_length(c):
    boundary = "scanmillboundary"
    head = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"cloud\"; filename=\"big.xyz\"\r\n"
            "Content-Type: application/octet-stream\r\n\r\n").encode()

    def chunks():                              # chunked transfer: the server cannot know the size up front
        yield head
        for _ in range(10):
            yield b"1 2 3\n" * 10_000           # 60 kB each, 600 kB in all
        yield f"\r\n--{boundary}--\r\n".encode()

    r = c.post("/jobs", content=chunks(), headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert_problem(r, 413, "request_too_large", "SCANMILL_MAX_UPLOAD_BYTES")


def test_wrong_request_content_type(c, good_ply):
    r = c.post("/jobs", content=good_ply, headers={"Content-Type": "application/x-ply"})
    assert_problem(r, 415, "unsupported_media_type", "multipart/form-data")
    r = c.post("/jobs", content=good_ply)
    assert_problem(r, 415, "unsupported_media_type")


def test_wrong_part_content_type(c, good_ply):
    # PNG, JPEG, BMP and TIFF parts are scans (read as reliefs); other images are not
    assert_problem(post_file(c, good_ply, filename="scan.gif", content_type="image/gif"), 415,
                   "unsupported_media_type", "image/gif")


def test_missing_cloud_part(c):
    r = c.post("/jobs", files={"other": ("x.ply", b"ply\n", "application/octet-stream")},
               data={"parameters": "{}"})
    assert_problem(r, 422, None, "other")
    r = c.post("/jobs", data={"parameters": "{}"}, files={"fixtures": ("f.ply", b"x", "application/octet-stream")})
    assert_problem(r, 422, "missing_cloud", "cloud")


def test_parameters_not_json(c, good_ply):
    r = c.post("/jobs", files={"cloud": ("scan.ply", good_ply, "application/octet-stream")},
               data={"parameters": "{setups: coverage=0.9"})
    assert_problem(r, 422, "invalid_parameter", "not valid JSON")


@pytest.mark.parametrize("params, name", [
    ({"setups": {"coverage": 2}}, "setups.coverage"),
    ({"setups": {"max_setups": 0}}, "setups.max_setups"),
    ({"visibility": {"cone_deg": [70, 20]}}, "visibility.cone_deg"),
    ({"tool": {"diameter_mm": -1}}, "tool.diameter_mm"),
    ({"setups": {"coverrage": 0.9}}, "setups.coverrage"),
])
def test_parameter_out_of_range_names_the_parameter(c, good_ply, params, name):
    p = assert_problem(post_file(c, good_ply, params=params), 422, "invalid_parameter", name)
    assert any(name in e for e in p["errors"])


def test_input_normals_without_normals_in_file(c):
    pts = half_sphere(n_points=300).points
    assert_problem(post_file(c, ascii_ply(pts)), 422, "missing_normals", "normals.method")


def test_time_limit_above_service_limit(c, good_ply):
    p = assert_problem(post_file(c, good_ply, time_limit_s="100000"), 422, None, "SCANMILL_JOB_TIME_LIMIT_S")
    assert p["limit_value"] == 600


def test_inline_cloud_over_its_point_limit(c):
    pts = np.random.default_rng(0).uniform(0, 10, (MAX_INLINE + 1, 3)).round(2).tolist()
    p = assert_problem(c.post("/jobs", json={"cloud": {"points": pts}}), 413, "too_many_points",
                       "SCANMILL_MAX_INLINE_POINTS")
    assert p["limit_value"] == MAX_INLINE


def test_inline_json_body_over_its_byte_limit(c):
    pts = [[1.123456789, 2.123456789, 3.123456789]] * 9000         # ~ 300 kB of JSON
    assert_problem(c.post("/jobs", json={"cloud": {"points": pts}}), 413, "request_too_large",
                   "SCANMILL_MAX_JSON_BYTES")


def test_inline_cloud_with_nan_and_bad_shapes(c):
    text = '{"cloud": {"points": [[0, 0, NaN], [1, 0, 0], [0, 1, 0]]}}'
    r = c.post("/jobs", content=text, headers={"Content-Type": "application/json"})
    assert_problem(r, 422)
    assert_problem(c.post("/jobs", json={"cloud": {"points": [[0, 0]]}}), 422, "invalid_request", "cloud.points")
    assert_problem(c.post("/jobs", json={"cloud": {"points": []}}), 422, "invalid_request")
    assert_problem(c.post("/jobs", json=[1, 2, 3]), 422, "invalid_request")
    r = c.post("/jobs", content=b"{not json", headers={"Content-Type": "application/json"})
    assert_problem(r, 422, "invalid_request", "JSON")
    pts = half_sphere(n_points=50).points.tolist()
    assert_problem(c.post("/jobs", json={"cloud": {"points": pts, "normals": pts[:10]}}), 422,
                   "invalid_request", "normals")


def test_degenerate_cloud(c):
    line = np.column_stack([np.linspace(0, 100, 500), np.zeros(500), np.zeros(500)])
    assert_problem(post_file(c, ascii_ply(line), params={}), 422, "degenerate_cloud")


def test_bad_fixture_is_refused_and_good_ones_are_kept(c, good_ply):
    r = c.post("/jobs", files=[("cloud", ("scan.ply", good_ply, "application/octet-stream")),
                               ("fixtures", ("clamp.ply", b"ply\nbroken", "application/octet-stream"))],
               data={"parameters": json.dumps(HALF_SPHERE_PARAMS)})
    assert_problem(r, 422, None, "fixture 0")
    clamp = ascii_ply(np.random.default_rng(2).uniform(-60, -50, (50, 3)))
    r = c.post("/jobs", files=[("cloud", ("scan.ply", good_ply, "application/octet-stream")),
                               ("fixtures", ("clamp.ply", clamp, "application/octet-stream"))],
               data={"parameters": json.dumps(HALF_SPHERE_PARAMS)})
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["input"]["fixtures"] == ["clamp.ply"]
    assert any("fixture" in w for w in job["warnings"])
    assert c.delete(f"/jobs/{job['id']}").status_code in (200, 204)


def test_invalid_idempotency_key(c, good_ply):
    r = c.post("/jobs", files={"cloud": ("scan.ply", good_ply, "application/octet-stream")},
               headers={"Idempotency-Key": "x" * 300})
    assert_problem(r, 422)


def test_nothing_was_accepted(c, server):
    # every bad request above left no job behind (the fixture job was deleted)
    assert [j for j in c.get("/jobs", params={"limit": 100}).json()["items"] if j["status"] != "cancelled"] == []
    assert list((server.data_dir / "tmp").iterdir()) == []


def test_deeply_nested_json_is_refused_not_crashed(c, good_ply):
    deep = "[" * 50_000 + "]" * 50_000
    r = c.post("/jobs", files={"cloud": ("scan.ply", good_ply, "application/octet-stream")}, data={"parameters": deep})
    assert_problem(r, 422, "invalid_parameter")
    r = c.post("/jobs", content=('{"cloud": ' + deep + "}").encode(), headers={"Content-Type": "application/json"})
    assert_problem(r, 422, "invalid_request")
