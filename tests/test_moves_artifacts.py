"""The neutral moves of each area as ``area_<i>.moves.json.gz`` and ``area_<i>.moves.npz`` (issue 20).

Checked: the npz holds the numbers the JSON prints (the JSON document rebuilt from the npz is the
gzipped JSON text byte for byte) for posted test operations on every profile (with and without a
gauge length, several decimals), for simultaneous 5-axis operations, and for a small plan written
to disk; both files are deterministic (gzip mtime 0 and no name; fixed zip times); plan.json names
them; the service serves the ``.json.gz`` as is and the old name ``.moves.json`` as JSON, gzip
encoded when the client accepts it and decompressed when it does not, with the same bytes either
way; unknown names are still 404."""

from __future__ import annotations

import dataclasses
import gzip
import http.client
import io
import json
import zipfile

import numpy as np
import pytest
from service_fixtures import (
    KEY_A,
)
from test_post import PROFILES, cloud, random_ops, unit

from planning.inputs import samples
from planning.inputs.cloud import Cloud
from planning.orientations.kinematics import machine_visibility
from planning.pipeline import run_plan
from planning.post import programs
from planning.post.neutral import NEUTRAL_FORMAT, neutral_json, neutral_json_arrays
from planning.report.moves_files import (
    DIRECTION_CODES,
    MOVES_NPZ_FORMAT,
    MOVES_NPZ_FORMAT_VERSION,
    TYPE_CODES,
    USE_CODES,
    gzip_bytes,
    moves_document,
    moves_npz_bytes,
    npz_of_json,
    read_moves_text,
)
from planning.report.plan_files import write_plan
from planning.toolpath.frames import area_frame
from schemas.params import parse_config
from service.storage import accepts_gzip, media_type

TILTED = (0.3, 0.4, 0.866)


def dumps(doc) -> str:
    return json.dumps(doc, separators=(",", ":"))


def npz_text(data: bytes) -> str:
    """The JSON text the npz ``data`` encodes (as the post writes it, with its final newline)."""
    return dumps(moves_document(io.BytesIO(data))) + "\n"


@pytest.mark.parametrize("k", range(len(PROFILES)))
def test_npz_holds_the_numbers_of_the_json_on_every_profile(k):
    """neutral_json_arrays gives neutral_json's text and the arrays it prints: the npz made of them
    rebuilds the text byte for byte (gauge lengths give controlled_machine_mm; 0, 2 and 4 decimals)."""
    name = PROFILES[k]
    axis = unit(TILTED)
    mv = machine_visibility(axis, name)
    frame = area_frame(axis, cloud(k))
    for seed, gauge, d, mixed in ((10, None, 4, False), (11, 120.0, 2, False), (12, None, 0, True)):
        ops = random_ops(200 + seed + k, 300)
        if gauge is None:                      # no gauge length: no controlled_machine_mm (mixed: the first has its own)
            ops = [op if mixed and j == 0 else dataclasses.replace(op, gauge_length_mm=None)
                   for j, op in enumerate(ops)]
        kw = {"tool_axis": axis, "rotary_deg": mv.angles_deg[0], "profile": name, "placement_mm": [1.0, -2.0, 60.0],
              "setup_id": 1, "area_id": 2, "gauge_length_mm": gauge, "decimals": d}
        text, doc = neutral_json_arrays(ops, frame, **kw)
        assert text == neutral_json(ops, frame, **kw)
        data = moves_npz_bytes(doc)
        assert npz_text(data) == text + "\n"
        z = np.load(io.BytesIO(data), allow_pickle=False)
        meta = json.loads(str(z["meta"]))
        assert (meta["npz_format"], meta["npz_format_version"]) == (MOVES_NPZ_FORMAT, MOVES_NPZ_FORMAT_VERSION)
        assert meta["codes"] == {"type": list(TYPE_CODES), "use": list(USE_CODES), "direction": list(DIRECTION_CODES)}
        assert meta["document"]["format"] == NEUTRAL_FORMAT
        assert list(z["op_start"]) == [0, 300, 600] and z["tip_part_mm"].shape == (600, 3)
        has = ["controlled_machine_mm" in op for op in json.loads(text)["operations"]]
        assert has == ([True, False] if mixed else [gauge is not None] * 2)
        assert ("controlled_machine_mm" in z.files) == any(has)
        if mixed:                              # NaN rows for the operation without it
            assert np.isnan(z["controlled_machine_mm"][300:]).all() and not np.isnan(z["controlled_machine_mm"][:300]).any()
        for key in z.files:                    # little endian (or single bytes) throughout
            assert z[key].dtype.byteorder in ("<", "|", "=") and (z[key].dtype.byteorder != "=" or
                                                                  np.little_endian), key
        # a parsed JSON document makes the same npz (older plans' files, bench/bench_artifacts.py)
        assert npz_of_json(text) == data


def five_axis_ops(n: int = 400):
    from planning.post.simultaneous import FiveAxisOperation

    rng = np.random.default_rng(5)
    axis = rng.normal(size=(n, 3)) + [0, 0, 4]
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    return [FiveAxisOperation(name="finishing 5-axis", centre_mm=rng.uniform(-40, 40, (n, 3)), axis=axis,
                              kind=(rng.uniform(size=n) < 0.9).astype(np.int8), use=rng.integers(0, 4, n).astype(np.int8),
                              tool_number=3, radius_mm=3.0, spindle_rpm=12000.0, feed_mm_min=1500.0,
                              plunge_mm_min=300.0, gauge_length_mm=100.0)]


def _old_five_axis_moves(text: str, five: list, decimals: int) -> str:
    """How planning/post/programs.py added the simultaneous operations before issue 20 (parse, add, dump)."""
    doc = json.loads(text) if text else {}
    doc["five_axis_operations"] = [
        {"name": op.name, "tool_number": int(op.tool_number), "radius_mm": float(op.radius_mm),
         "centre_mm": np.round(op.centre_mm, decimals).tolist(),
         "tip_mm": np.round(op.centre_mm - op.radius_mm * op.axis, decimals).tolist(),
         "axis": np.round(op.axis, 9).tolist(), "kind": op.kind.astype(int).tolist(), "use": op.use.astype(int).tolist()}
        for op in five]
    return dumps(doc)


@pytest.mark.parametrize("with_ops", [True, False])
def test_simultaneous_operations_in_json_and_npz(with_ops):
    """five_axis_operations: the JSON text as before issue 20, and the npz gives it back (alone, or
    after 3+2 operations)."""
    five = five_axis_ops()
    name = PROFILES[0]
    axis = unit(TILTED)
    text, doc = ("", None)
    if with_ops:
        text, doc = neutral_json_arrays(random_ops(7, 100), area_frame(axis, cloud(0)), tool_axis=axis,
                                        rotary_deg=machine_visibility(axis, name).angles_deg[0], profile=name,
                                        placement_mm=[0, 0, 60.0], decimals=4)
    lists = programs._five_axis_lists(five, 4)
    full = programs._five_axis_moves(text, lists)
    assert full == _old_five_axis_moves(text, five, 4)
    data = moves_npz_bytes(doc, lists)
    assert npz_text(data) == full + "\n"
    z = np.load(io.BytesIO(data))
    assert list(z["five_start"]) == [0, 400] and z["five_axis"].dtype == np.dtype("<f8")
    assert z["five_kind"].dtype == np.uint8 and ("operations" in json.loads(str(z["meta"]))["document"]) == with_ops


def test_gzip_and_npz_are_deterministic():
    text = dumps({"a": list(range(1000)), "b": "x" * 5000}) + "\n"
    one, two = gzip_bytes(text), gzip_bytes(text.encode())
    assert one == two and gzip.decompress(one).decode() == text
    # RFC 1952 header: magic, deflate, no flags (no FNAME, no FCOMMENT), MTIME 0
    assert one[:4] == b"\x1f\x8b\x08\x00" and one[4:8] == b"\x00\x00\x00\x00"
    axis = unit(TILTED)
    kw = {"tool_axis": axis, "rotary_deg": machine_visibility(axis, PROFILES[0]).angles_deg[0],
          "profile": PROFILES[0], "placement_mm": [0, 0, 60.0]}
    frame = area_frame(axis, cloud(0))
    a = moves_npz_bytes(neutral_json_arrays(random_ops(3, 50), frame, **kw)[1])
    b = moves_npz_bytes(neutral_json_arrays(random_ops(3, 50), frame, **kw)[1])
    assert a == b
    with zipfile.ZipFile(io.BytesIO(a)) as zf:
        assert {i.date_time for i in zf.infolist()} == {(1980, 1, 1, 0, 0, 0)}
        assert all(i.compress_type == zipfile.ZIP_DEFLATED for i in zf.infolist())


# ----------------------------------------------------------------------------------------------
# a small plan


@pytest.fixture(scope="module")
def half_sphere_plan(tmp_path_factory):
    s = samples.half_sphere()
    cfg = {"paths": {"finishing": {"scallop_mm": 0.2}}, "simulate": {"enabled": False}, "normals": {"method": "input"},
           "setups": {"max_setups": 2}, "tool": {"diameter_mm": 10}}
    out = run_plan(Cloud(points=s.points, normals=s.normals, source_format="generated"), parse_config(cfg),
                   name="half_sphere")
    d = tmp_path_factory.mktemp("plan")
    write_plan(out, d)
    return out, d


def test_plan_writes_json_gz_and_npz_with_the_same_moves(half_sphere_plan):
    out, d = half_sphere_plan
    plan = json.loads((d / "plan.json").read_text())
    assert not list(d.glob("*.moves.json"))
    assert len(plan["setups"]) == 2
    for st in plan["setups"]:
        i, p = st["id"], st["path"]
        assert p["moves"] == f"area_{i}.moves.json.gz" and p["moves_npz"] == f"area_{i}.moves.npz"
        raw = (d / p["moves"]).read_bytes()
        assert raw == out.extra["programs"][p["moves"]] and raw[:2] == b"\x1f\x8b"
        text = read_moves_text(d / p["moves"])
        doc = json.loads(text)
        assert doc["area_id"] == i and "finishing" in [op["name"] for op in doc["operations"]]
        assert npz_text((d / p["moves_npz"]).read_bytes()) == text
        # the arrays as a client reads them: the finishing tips are plan.npz's cl_i less the ball radius
        z = np.load(d / p["moves_npz"])
        k = [op["name"] for op in json.loads(str(z["meta"]))["document"]["operations"]].index("finishing")
        rows = slice(z["op_start"][k], z["op_start"][k + 1])
        fin = doc["operations"][k]["moves"]
        assert np.array_equal(z["tip_part_mm"][rows], np.array(fin["tip_part_mm"]))
        assert [TYPE_CODES[c] for c in z["type"][rows]] == fin["type"]
        assert np.array_equal(np.isnan(z["feed_mm_min"][rows]), np.array([f is None for f in fin["feed_mm_min"]]))
        cl = np.load(d / "plan.npz")[f"cl_{i}"]
        assert z["tip_part_mm"][rows].shape == cl.shape


# ----------------------------------------------------------------------------------------------
# HTTP


@pytest.mark.parametrize("header, gz", [
    (None, False), ("", False), ("identity", False), ("gzip", True), ("gzip, deflate, br", True),
    ("br;q=1.0, gzip;q=0.5", True), ("gzip;q=0", False), ("*", True), ("*;q=0", False),
    ("identity, *;q=0", False), ("gzip;q=0, *", False), ("GZIP;Q=0.001", True), ("x-gzip", True),
    ("gzip;q=nan", False), ("gzip;q=abc", False), (";;,", False),
])
def test_accept_encoding(header, gz):
    assert accepts_gzip(header) is gz


def test_media_types():
    assert media_type("area_0.moves.json.gz") == "application/gzip"
    assert media_type("area_0.moves.npz") == "application/octet-stream"


@pytest.fixture(scope="module")
def server(half_sphere_service):
    return half_sphere_service[0]


@pytest.fixture(scope="module")
def done_job(half_sphere_service):
    return half_sphere_service[1]


def raw_get(server, path: str, accept_encoding: str | None):
    """GET with exactly these headers (http.client neither adds Accept-Encoding nor decodes)."""
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=60)
    headers = {"Authorization": f"Bearer {KEY_A}"}
    if accept_encoding is not None:
        headers["Accept-Encoding"] = accept_encoding
    try:
        conn.request("GET", path, headers=headers)
        resp = conn.getresponse()
        return resp, resp.read()
    finally:
        conn.close()


def test_service_serves_the_moves_gzipped_or_plain(server, done_job):
    base = done_job["links"]["self"]
    with server.client(KEY_A) as c:
        items = {it["name"]: it for it in c.get(f"{base}/artifacts").json()["items"]}
        plan = c.get(f"{base}/result").json()
    stored = server.data_dir / "jobs" / done_job["id"] / "result"
    for st in plan["setups"]:
        gz_name, npz_name = st["path"]["moves"], st["path"]["moves_npz"]
        old_name = gz_name[:-3]
        # the list names the real files only
        assert {gz_name, npz_name} <= set(items) and old_name not in items
        assert items[gz_name]["media_type"] == "application/gzip"
        stored_gz = (stored / gz_name).read_bytes()
        text = gzip.decompress(stored_gz)
        # the stored file as is: application/gzip, no Content-Encoding
        resp, body = raw_get(server, f"{base}/artifacts/{gz_name}", "gzip")
        assert resp.status == 200 and resp.getheader("content-type") == "application/gzip"
        assert resp.getheader("content-encoding") is None and body == stored_gz
        # the old name, gzip accepted: the stored bytes with Content-Encoding gzip
        resp, body = raw_get(server, f"{base}/artifacts/{old_name}", "gzip, deflate")
        assert resp.status == 200, body[:200]
        assert resp.getheader("content-type").startswith("application/json")
        assert resp.getheader("content-encoding") == "gzip" and "Accept-Encoding" in resp.getheader("vary")
        assert body == stored_gz and gzip.decompress(body) == text
        # the old name, gzip refused or not mentioned: the JSON decompressed on the way
        for accept in ("identity", None, "gzip;q=0"):
            resp, body = raw_get(server, f"{base}/artifacts/{old_name}", accept)
            assert resp.status == 200 and resp.getheader("content-type").startswith("application/json")
            assert resp.getheader("content-encoding") in (None, "identity"), accept
            assert body == text
        assert json.loads(text)["area_id"] == st["id"]
        # the npz: the same moves
        resp, body = raw_get(server, f"{base}/artifacts/{npz_name}", "gzip")
        assert resp.status == 200 and body == (stored / npz_name).read_bytes()
        assert npz_text(body).encode() == text


@pytest.mark.parametrize("name", ["area_9.moves.json", "area_9.moves.json.gz", "nope.json", "plan.npz.gz",
                                  "area_0.moves.npz.gz", "area_0.moves", "area_0.moves.json.gz.gz", "plan.json.gz"])
def test_unknown_artifact_names_are_404(server, done_job, name):
    resp, body = raw_get(server, f"{done_job['links']['self']}/artifacts/{name}", "gzip")
    assert resp.status == 404, body[:200]
    assert json.loads(body)["code"] == "artifact_not_found"
