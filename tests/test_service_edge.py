"""The edge of the service under abuse (issue 13): request bodies that lie about their size or stop
arriving, a full disk, the client address behind proxies, a database outage seen by /healthz, and
answers that name the limit they enforce.

The raw-socket tests talk HTTP/1.1 by hand to a real ``scanmill serve`` on 127.0.0.1, since an HTTP
client library would not send a Content-Length it does not honour. Every wait is bounded: sockets
carry a timeout (a server that never answers fails the test instead of hanging it) and loops are
bounded in count; nothing asserts on elapsed time. The in-process tests run the app under
Starlette's TestClient to inject faults (ENOSPC while writing, an unreachable database).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import socket
import struct
import warnings

import pytest

with warnings.catch_warnings():            # Starlette 1.x prefers httpx2 for its TestClient; httpx works the same
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

from service_fixtures import ServerProcess, free_port, stray_files, write_half_sphere

PROBLEM = "application/problem+json"
MAX_UPLOAD = 3_000_000          # bytes: over the 1 MiB text-field limit, so that limit is the one hit
MAX_JSON = 200_000
SOCKET_TIMEOUT_S = 30          # a bound, not a measurement: a server that never answers fails the test
KEY = "edge-key-0123456789"


# -- helpers ---------------------------------------------------------------------------------------

class RawResponse:
    def __init__(self, status: int, headers: dict[str, str], body: bytes, closed: bool):
        self.status, self.headers, self.body, self.closed = status, headers, body, closed

    def json(self) -> dict:
        return json.loads(self.body)


def connect(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=SOCKET_TIMEOUT_S)
    s.settimeout(SOCKET_TIMEOUT_S)
    return s


def request_head(method: str, path: str, headers: dict[str, str]) -> bytes:
    lines = [f"{method} {path} HTTP/1.1", "Host: 127.0.0.1"] + [f"{k}: {v}" for k, v in headers.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")


def read_response(s: socket.socket) -> RawResponse:
    """Read one response (Content-Length framed), then whether the server closed the connection."""
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = s.recv(65536)                  # socket.timeout fails the test: no answer came
        if not chunk:
            raise AssertionError(f"connection closed before a response; got {buf!r}")
        buf += chunk
    head, body = buf.split(b"\r\n\r\n", 1)
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:])}
    n = int(headers.get("content-length", "0"))
    while len(body) < n:
        chunk = s.recv(65536)
        if not chunk:
            break
        body += chunk
    try:
        closed = s.recv(1) == b""
    except ConnectionResetError:
        closed = True
    except TimeoutError:
        closed = False
    return RawResponse(status, headers, body[:n], closed)


def multipart_head(boundary: str) -> bytes:
    return (f"--{boundary}\r\nContent-Disposition: form-data; name=\"cloud\"; filename=\"scan.xyz\"\r\n"
            "Content-Type: application/octet-stream\r\n\r\n").encode()


def assert_problem(status: int, content_type: str, doc: dict, want_status: int, code: str, *words: str) -> dict:
    assert status == want_status, doc
    assert content_type.startswith(PROBLEM)
    assert doc["status"] == want_status and doc["code"] == code, doc
    for w in words:
        assert w.lower() in doc["detail"].lower(), (w, doc["detail"])
    return doc


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("edge")
    srv = ServerProcess(root / "data", workers=1, max_upload_bytes=MAX_UPLOAD, max_json_bytes=MAX_JSON,
                        body_read_timeout_s=1, job_time_limit_s=600).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def c(server):
    with server.client() as client:            # anonymous: no keys, and we are on loopback
        yield client


@pytest.fixture(scope="module")
def cloud_bytes(tmp_path_factory):
    return write_half_sphere(tmp_path_factory.mktemp("in") / "half_sphere.ply").read_bytes()


def small_ply() -> bytes:
    return (b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
            b"end_header\n0 0 0\n")


# -- finding 6: a declared size over the limit, and a body that stops arriving --------------------------

@pytest.mark.parametrize("content_type, limit_name", [
    ("multipart/form-data; boundary=b0undary", "SCANMILL_MAX_UPLOAD_BYTES"),
    ("application/json", "SCANMILL_MAX_JSON_BYTES"),
])
def test_declared_length_over_the_limit_is_answered_at_once_and_closed(server, c, content_type, limit_name):
    """Content-Length: 2,000,000,000 and no body at all, on 40 connections at once: each is answered 413
    naming the limit, without the server waiting for (or draining) the body, and then closed."""
    socks = []
    try:
        for _ in range(40):
            s = connect(server.port)
            s.sendall(request_head("POST", "/jobs", {"Content-Type": content_type,
                                                     "Content-Length": "2000000000"}))
            socks.append(s)
        for s in socks:
            r = read_response(s)
            p = assert_problem(r.status, r.headers.get("content-type", ""), r.json(), 413, "request_too_large",
                               limit_name)
            assert p["limit"] == limit_name
            assert r.headers.get("connection", "").lower() == "close"
            assert r.closed, "the server kept the connection open after refusing its body"
    finally:
        for s in socks:
            s.close()
    assert c.get("/healthz").status_code == 200           # and the server still answers
    assert stray_files(server.data_dir, []) == []


def test_chunked_body_over_the_limit_is_answered_and_closed(server):
    """A chunked body (no length up front) is refused once it passes the limit, and the connection closed;
    the client may keep sending: the server does not read on."""
    with connect(server.port) as s:
        s.sendall(request_head("POST", "/jobs", {"Content-Type": "multipart/form-data; boundary=b0undary",
                                                 "Transfer-Encoding": "chunked"}))
        block = b"1 2 3\n" * 10_000
        data = multipart_head("b0undary")
        s.sendall(b"%x\r\n%s\r\n" % (len(data), data))
        for _ in range(MAX_UPLOAD // len(block) + 2):   # just past the limit, then stop sending
            try:
                s.sendall(b"%x\r\n%s\r\n" % (len(block), block))
            except (BrokenPipeError, ConnectionResetError):
                break              # the server has answered and closed while the client was still sending
        r = read_response(s)
    assert_problem(r.status, r.headers["content-type"], r.json(), 413, "request_too_large",
                   "SCANMILL_MAX_UPLOAD_BYTES", f"{MAX_UPLOAD:,}")
    assert r.closed


@pytest.mark.parametrize("framing, sent", [
    ("length", b""),                          # headers only: the body never starts
    ("length", b"partial"),                   # a body that starts and stops
    ("chunked", b"partial"),                  # a chunked body that stops mid-way
    ("json", b'{"cloud": {"points": [[0, 0,'),  # an inline JSON body that stops mid-way
])
def test_a_body_that_stops_arriving_is_answered_408_and_dropped(server, c, framing, sent):
    boundary = "b0undary"
    head = multipart_head(boundary)
    ct = f"multipart/form-data; boundary={boundary}"
    with connect(server.port) as s:
        if framing == "json":
            s.sendall(request_head("POST", "/jobs", {"Content-Type": "application/json", "Content-Length": "5000"}))
            s.sendall(sent)
        elif framing == "length":
            s.sendall(request_head("POST", "/jobs", {"Content-Type": ct, "Content-Length": "100000"}))
            if sent:
                s.sendall(head + sent)
        else:
            s.sendall(request_head("POST", "/jobs", {"Content-Type": ct, "Transfer-Encoding": "chunked"}))
            data = head + sent
            s.sendall(b"%x\r\n%s\r\n" % (len(data), data))
        r = read_response(s)                  # the server's timeout (1 s here) answers, not ours (30 s)
    assert_problem(r.status, r.headers["content-type"], r.json(), 408, "body_timeout",
                   "SCANMILL_BODY_READ_TIMEOUT_S")
    assert r.json()["limit"] == "SCANMILL_BODY_READ_TIMEOUT_S" and r.json()["limit_value"] == 1
    assert r.closed
    assert stray_files(server.data_dir, []) == []
    assert c.get("/healthz").status_code == 200


def test_ordinary_upload_still_works_beside_the_limits(server, c, cloud_bytes):
    r = c.post("/jobs", files={"cloud": ("half_sphere.ply", cloud_bytes, "application/octet-stream")},
               data={"parameters": json.dumps({"normals": {"method": "input"}})})
    assert r.status_code == 202, r.text
    assert c.delete(f"/jobs/{r.json()['id']}").status_code == 200


# -- finding 9: answers that name the limit ------------------------------------------------------------

def test_too_many_fixture_files_names_scanmill_max_fixtures(c):
    ply = small_ply()
    files = [("cloud", ("scan.ply", ply, "application/octet-stream"))]
    files += [("fixtures", (f"f{i}.ply", ply, "application/octet-stream")) for i in range(9)]
    r = c.post("/jobs", files=files)
    p = assert_problem(r.status_code, r.headers["content-type"], r.json(), 422, "too_many_fixtures",
                       "SCANMILL_MAX_FIXTURES", "8")
    assert p["limit"] == "SCANMILL_MAX_FIXTURES" and p["limit_value"] == 8
    assert "files is 9" not in p["detail"]       # not starlette's 'Maximum number of files is 9'


@pytest.mark.parametrize("as_file", [False, True])
def test_parameters_part_over_one_mib_names_the_limit(c, as_file):
    big = json.dumps({"setups": {"coverage": 0.95}, "pad": "x" * (1 << 20)})
    part = ("parameters.json", big.encode(), "application/octet-stream") if as_file else (None, big)
    r = c.post("/jobs", files=[("cloud", ("scan.ply", small_ply(), "application/octet-stream")),
                               ("parameters", part)])
    p = assert_problem(r.status_code, r.headers["content-type"], r.json(), 413, "field_too_large",
                       "parameters", "1,048,576")
    assert p["limit_value"] == 1 << 20


def test_very_long_file_name_names_the_limit(c):
    r = c.post("/jobs", files={"cloud": ("a" * 5000 + ".ply", small_ply(), "application/octet-stream")})
    p = assert_problem(r.status_code, r.headers["content-type"], r.json(), 413, "part_header_too_large",
                       "file name", "4,224")
    assert p["limit_value"] == 4224


def test_too_many_form_fields_names_the_limit(c):
    r = c.post("/jobs", files=[("cloud", ("scan.ply", small_ply(), "application/octet-stream"))]
               + [("name", (None, "x"))] * 20)
    p = assert_problem(r.status_code, r.headers["content-type"], r.json(), 422, "too_many_fields", "16")
    assert p["limit_value"] == 16


def _pcd(count: str, n: int = 10, fields: str = "x y z", size: str = "4 4 4", types: str = "F F F") -> bytes:
    return (f"VERSION .7\nFIELDS {fields}\nSIZE {size}\nTYPE {types}\nCOUNT {count}\nWIDTH {n}\nHEIGHT 1\n"
            f"POINTS {n}\nDATA binary\n").encode() + struct.pack("<3f", 1, 2, 3) * n


@pytest.mark.parametrize("header, words", [
    (_pcd("100000000 1 1"), ["COUNT", "x", "must be 1"]),
    (_pcd("0 1 1"), ["COUNT", "must be 1"]),
    (_pcd("-1 1 1"), ["COUNT"]),
    (_pcd("1e8 1 1"), ["COUNT", "1e8", "whole number"]),
    (_pcd("1 1 1 100000000", fields="x y z rgb", size="4 4 4 4", types="F F F U"), ["COUNT", "400,000,012 bytes"]),
])
def test_pcd_with_an_absurd_count_says_what_is_wrong_with_the_header(c, header, words):
    from planning.errors import InputError
    from planning.inputs.cloud import read_cloud
    with pytest.raises(InputError) as e:
        read_cloud(header)
    for w in words:
        assert w in e.value.message, (w, e.value.message)
    r = c.post("/jobs", files={"cloud": ("scan.pcd", header, "application/octet-stream")})
    assert r.status_code == 422 and r.headers["content-type"] == PROBLEM
    assert r.json()["detail"] == e.value.message


# -- finding 7: one rule for the client address --------------------------------------------------------

REMOTE = "203.0.113.7"                         # a documentation address: only ever a header value here


@pytest.mark.parametrize("headers", [
    {"X-Forwarded-For": REMOTE},
    {"X-Forwarded-For": f"{REMOTE}, 127.0.0.1"},           # a second, local proxy hop is skipped
    {"Forwarded": f"for={REMOTE};proto=http"},
    {"Forwarded": 'for="[2001:db8::7]:4711"'},
    {"Forwarded": "for=unknown"},                          # an unknown client is not a local one
    {"X-Real-IP": REMOTE},
    {"Forwarded": "for=127.0.0.1", "X-Real-IP": REMOTE},   # one header claims loopback, another does not
])
def test_a_remote_client_behind_a_trusted_local_proxy_is_not_local(c, headers):
    """The test client is the same-host proxy (127.0.0.1, trusted by default) sending each header kind for
    a remote client: without API keys, that client is refused like any remote one."""
    r = c.get("/jobs", headers=headers)
    assert_problem(r.status_code, r.headers["content-type"], r.json(), 403, "anonymous_not_allowed")


@pytest.mark.parametrize("headers", [{}, {"X-Forwarded-For": "127.0.0.1"}, {"Forwarded": "for=127.0.0.1"},
                                     {"X-Real-IP": "::1"}])
def test_a_direct_or_local_client_is_local(c, headers):
    assert c.get("/jobs", headers=headers).status_code == 200


@pytest.fixture
def in_process(tmp_path, monkeypatch):
    """Build the app in this process (``TestClient`` runs its lifespan); returns a factory."""
    from service.app import create_app
    from service.settings import load_settings
    from service.workers import PINNED_VARS
    for var in PINNED_VARS:                    # the runner pins these in os.environ: restore them afterwards
        monkeypatch.setenv(var, os.environ.get(var, "1"))

    def make(client=("127.0.0.1", 50000), **settings):
        s = load_settings(env={}, data_dir=str(tmp_path / "data"), workers=1, **settings)
        return TestClient(create_app(s), client=client, raise_server_exceptions=False)
    return make


@pytest.mark.parametrize("headers", [{"X-Forwarded-For": "127.0.0.1"}, {"Forwarded": "for=127.0.0.1"},
                                     {"X-Real-IP": "127.0.0.1"}, {}])
def test_an_untrusted_peer_claiming_loopback_is_not_believed(in_process, headers):
    with in_process(client=(REMOTE, 50000)) as tc:
        r = tc.get("/jobs", headers=headers)
    assert r.status_code == 403 and r.json()["code"] == "anonymous_not_allowed"


def test_a_proxy_outside_the_allow_list_is_not_believed(in_process):
    # the peer is loopback but not in SCANMILL_FORWARDED_ALLOW_IPS: its headers are ignored, the socket decides
    with in_process(forwarded_allow_ips="10.0.0.0/8") as tc:
        assert tc.get("/jobs", headers={"X-Forwarded-For": REMOTE}).status_code == 200
    with in_process(client=("10.1.2.3", 50000), forwarded_allow_ips="10.0.0.0/8") as tc:
        assert tc.get("/jobs", headers={"X-Forwarded-For": "127.0.0.1"}).status_code == 200
        assert tc.get("/jobs", headers={"X-Forwarded-For": f"127.0.0.1, {REMOTE}"}).status_code == 403


def test_uvicorn_does_not_rewrite_the_client_itself():
    """``scanmill serve`` turns uvicorn's own proxy-header handling off: the rule lives in service.auth alone."""
    import inspect

    import scanmill.serve
    src = inspect.getsource(scanmill.serve.serve)
    assert "proxy_headers=False" in src


# -- findings 3 and 8: a full disk, and /healthz -------------------------------------------------------

def test_health_reports_disk_and_database(c):
    h = c.get("/healthz").json()
    assert h["status"] == "ok"
    assert h["database"] == "ok"
    assert h["disk"]["status"] == "ok" and h["disk"]["free_bytes"] > 0
    assert h["disk"]["min_free_bytes"] == 1024 * 1024 * 1024


def test_upload_refused_507_and_health_degraded_when_the_disk_is_below_its_reserve(tmp_path, cloud_bytes):
    """The data directory's file system has less free space than SCANMILL_MIN_FREE_DISK_MB (the reserve is
    set above what is free, as a full disk would be): uploads are refused 507 before anything is written,
    and /healthz says 'degraded' (HTTP 200: reads still work)."""
    free_mb = shutil.disk_usage(tmp_path).free // (1 << 20)
    reserve = free_mb + 10_000
    with ServerProcess(tmp_path / "data", workers=1, min_free_disk_mb=reserve) as srv, srv.client() as c:
        r = c.post("/jobs", files={"cloud": ("half_sphere.ply", cloud_bytes, "application/octet-stream")})
        p = assert_problem(r.status_code, r.headers["content-type"], r.json(), 507, "insufficient_storage",
                           "SCANMILL_MIN_FREE_DISK_MB", f"{reserve:,}")
        assert p["needed_bytes"] >= len(cloud_bytes) and p["free_bytes"] > 0
        inline = c.post("/jobs", json={"cloud": {"points": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]}})
        assert_problem(inline.status_code, inline.headers["content-type"], inline.json(), 507,
                       "insufficient_storage")
        h = c.get("/healthz")
        assert h.status_code == 200
        doc = h.json()
        assert doc["status"] == "degraded" and doc["disk"]["status"] == "low"
        assert doc["disk"]["min_free_bytes"] == reserve << 20 and doc["database"] == "ok"
        assert c.get("/jobs").json()["items"] == []
        assert stray_files(srv.data_dir, []) == []


@pytest.mark.parametrize("form", ["multipart", "json"])
def test_enospc_while_writing_an_upload_answers_507_and_keeps_nothing(in_process, monkeypatch, cloud_bytes, form):
    """The disk fills between the free-space check and the write: the write fails with ENOSPC (here: its
    fsync, as on a delayed-allocation file system). The answer is 507, never 500, and nothing stays."""
    import planning.report.files as files_mod
    import service.storage
    real_fsync = os.fsync

    def full_fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with in_process(min_free_disk_mb=0) as tc:
        data_dir = tc.app.state.settings.data_dir
        monkeypatch.setattr(service.storage.os, "fsync", full_fsync)
        if form == "json":                     # the inline cloud is written as PLY: make that write fail
            real_write_ply = files_mod.write_ply

            def full_write_ply(path, *a, **kw):
                real_write_ply(path, *a, **kw)
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
            monkeypatch.setattr(files_mod, "write_ply", full_write_ply)
            r = tc.post("/jobs", json={"cloud": {"points": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]}})
        else:
            r = tc.post("/jobs", files={"cloud": ("half_sphere.ply", cloud_bytes, "application/octet-stream")})
        monkeypatch.setattr(service.storage.os, "fsync", real_fsync)
        assert_problem(r.status_code, r.headers["content-type"], r.json(), 507, "insufficient_storage",
                       "SCANMILL_MIN_FREE_DISK_MB")
        assert tc.get("/jobs").json()["items"] == []
    assert stray_files(data_dir, []) == []


def test_health_during_a_database_outage_reveals_no_internals(in_process):
    """The job store's database stops answering (here: a PostgreSQL URL on a closed 127.0.0.1 port): /healthz,
    which needs no key, answers 503 store_unavailable without the driver's error, host or port."""
    import sqlalchemy as sa
    port = free_port()
    with in_process(api_keys=[KEY]) as tc:
        tc.app.state.store.engine = sa.create_engine(
            f"postgresql+psycopg://scanmill:secret@127.0.0.1:{port}/scanmill?connect_timeout=5")
        r = tc.get("/healthz")
        assert r.status_code == 503 and r.headers["content-type"] == PROBLEM
        text = r.text.lower()
        for leak in (str(port), "127.0.0.1", "psycopg", "connection refused", "secret", "traceback",
                     "operationalerror"):
            assert leak not in text, (leak, r.text)
        doc = r.json()
        assert doc["code"] == "store_unavailable" and doc["database"] == "unavailable"
        assert r.headers.get("retry-after")


def test_disk_full_is_recognised_through_the_database_driver():
    """SQLite's 'database or disk is full' (wrapped by SQLAlchemy) is a full disk (507), not an outage (503)."""
    import sqlite3

    from sqlalchemy import exc as sa_exc

    from service.problems import is_disk_full
    full = sa_exc.OperationalError("INSERT ...", {}, sqlite3.OperationalError("database or disk is full"))
    down = sa_exc.OperationalError("SELECT ...", {}, sqlite3.OperationalError("unable to open database file"))
    assert is_disk_full(full) and not is_disk_full(down)
    assert is_disk_full(OSError(errno.ENOSPC, "No space left on device"))
    assert not is_disk_full(OSError(errno.EACCES, "Permission denied"))
