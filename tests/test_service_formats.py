"""Every input format over real HTTP: STL, OBJ, PLY with faces, LAS, LAZ, E57 and PNG uploads are accepted
(the job's input says what was read), and damaged ones are answered with a 4xx problem naming what is wrong,
no job created and no file left behind."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mesh_files import (image_bytes, las_bytes, obj_text, ply_mesh, sphere_mesh, stl_ascii, stl_binary,
                        write_e57)
from service_fixtures import ServerProcess, stray_files

from planning.inputs.cloud import EXTENSIONS, FORMATS
from service.intake import FORMATS as SERVICE_FORMATS
from service.storage import CLOUD_SUFFIXES

PROBLEM = "application/problem+json"
#: light parameters: the jobs are cancelled as soon as they are accepted
PARAMS = {"tool": {"diameter_mm": 6}, "setups": {"max_setups": 2}}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("formats")
    srv = ServerProcess(root / "data", workers=1, max_upload_bytes=2_000_000, max_points=1_000_000,
                        job_time_limit_s=600).start()
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def c(server):
    with server.client() as client:
        yield client


@pytest.fixture(autouse=True)
def no_stray_files(server, c):
    yield
    jobs = [j["id"] for j in c.get("/jobs", params={"limit": 100}).json()["items"]]
    assert stray_files(server.data_dir, jobs) == []


def post(c, content: bytes, filename: str, content_type="application/octet-stream", params=None, **fields):
    data = {"parameters": json.dumps(PARAMS if params is None else params), **fields}
    return c.post("/jobs", files={"cloud": (filename, content, content_type)}, data=data)


def accepted(c, r) -> dict:
    assert r.status_code == 202, r.text
    job = r.json()
    assert c.delete(f"/jobs/{job['id']}").status_code in (200, 204)
    return job


def assert_problem(r, status: int, code: str, *words: str) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    p = r.json()
    assert p["code"] == code, p
    for w in words:
        assert w.lower() in p["detail"].lower(), (w, p["detail"])
    return p


def part_points(n: int = 2000) -> np.ndarray:
    d = np.random.default_rng(0).normal(size=(n, 3))
    return 30.0 * d / np.linalg.norm(d, axis=1, keepdims=True) + [0, 0, 40]   # a 60 mm sphere


def sphere_e57(tmp_path, name="scan.e57") -> bytes:
    rows, cols = np.divmod(np.arange(40 * 40), 40)
    t, p = rows / 39 * np.pi / 2, cols / 39 * np.pi
    grid = 0.03 * np.column_stack((np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)))  # metres
    return write_e57(tmp_path / name, [{"points": grid, "row": rows, "column": cols},
                                       {"points": part_points(500) / 1000.0, "rotation": [0, 0, 0, 1],
                                        "translation": [0, 0, 0.01]}]).read_bytes()


def test_the_service_takes_every_format_the_readers_take():
    assert tuple(SERVICE_FORMATS) == tuple(FORMATS)
    assert set(CLOUD_SUFFIXES) == set(EXTENSIONS)


@pytest.mark.parametrize("kind", ["stl-binary", "stl-ascii", "obj", "ply-faces"])
def test_meshes_are_accepted(c, kind):
    v, f = sphere_mesh(radius=30.0)
    content, name, label = {
        "stl-binary": (stl_binary(v, f), "part.stl", "stl-binary"),
        "stl-ascii": (stl_ascii(v, f), "part.stl", "stl-ascii"),
        "obj": (obj_text(v, f, style="vtvn"), "part.obj", "obj"),
        "ply-faces": (ply_mesh(v, f), "part.ply", "ply-binary_little_endian"),
    }[kind]
    job = accepted(c, post(c, content, name))
    assert job["input"]["format"] == label and job["input"]["n_points"] == len(v)


@pytest.mark.parametrize("compress, label", [(False, "las"), (True, "laz")])
def test_las_and_laz_are_accepted(c, compress, label):
    job = accepted(c, post(c, las_bytes(part_points(), compress=compress), f"scan.{label}"))
    assert job["input"]["format"] == label and job["input"]["n_points"] == 2000


def test_e57_is_accepted_in_metres(c, tmp_path):
    job = accepted(c, post(c, sphere_e57(tmp_path), "scan.e57", params=dict(PARAMS, input={"units": "m"})))
    assert job["input"]["format"] == "e57" and job["input"]["n_points"] == 40 * 40 + 500


def test_png_relief_is_accepted_as_image_png(c):
    img = (np.add.outer(np.arange(48), np.arange(64)) * 2).astype(np.uint8)
    params = dict(PARAMS, input={"relief": {"size_mm": 80, "z_max_mm": 15, "blur": 3}})
    job = accepted(c, post(c, image_bytes(img), "relief.png", content_type="image/png", params=params))
    assert job["input"]["format"] == "image-png" and job["input"]["n_points"] == 48 * 64


def test_format_field_names_the_new_formats(c):
    v, f = sphere_mesh(radius=30.0)
    job = accepted(c, post(c, stl_binary(v, f), "upload.bin", format="stl"))
    assert job["input"]["format"] == "stl-binary"
    r = post(c, stl_binary(v, f), "upload.bin", format="gif")
    assert r.status_code == 422 and "stl" in r.json()["detail"]


def test_broken_stl(c):
    v, f = sphere_mesh(radius=30.0)
    data = stl_binary(v, f)
    assert_problem(post(c, data[:-100], "part.stl"), 422, "truncated_file", "part.stl", "triangles")
    text = stl_ascii(v, f)
    assert_problem(post(c, text[: len(text) // 2], "part.stl"), 422, "truncated_file", "endsolid")


def test_obj_face_out_of_range(c):
    v, f = sphere_mesh(radius=30.0)
    f = f.copy()
    f[10, 2] = 5000
    assert_problem(post(c, obj_text(v, f), "part.obj"), 422, "unreadable_file", "part.obj", "5001", "line")


def test_ply_face_out_of_range(c):
    v, f = sphere_mesh(radius=30.0)
    f = f.copy()
    f[3, 0] = len(v) + 1
    assert_problem(post(c, ply_mesh(v, f), "part.ply"), 422, "unreadable_file", "face")


def test_corrupt_las_and_laz(c):
    las = las_bytes(part_points())
    assert_problem(post(c, las[: len(las) - 1000], "scan.las"), 422, "truncated_file", "scan.las")
    assert_problem(post(c, b"LASF" + b"\x07" * 400, "scan.las"), 422, "unreadable_file", "scan.las")
    laz = las_bytes(part_points(), compress=True)
    assert_problem(post(c, laz[: len(laz) // 2], "scan.laz"), 422, "truncated_file", "scan.laz")


def test_corrupt_e57(c, tmp_path):
    data = sphere_e57(tmp_path)
    assert_problem(post(c, data[: len(data) // 2], "scan.e57"), 422, "truncated_file", "scan.e57")
    broken = bytearray(data)
    broken[2000:6000] = b"\x33" * 4000
    assert_problem(post(c, bytes(broken), "scan.e57"), 422, "unreadable_file", "scan.e57")


def test_broken_images(c):
    img = image_bytes(np.random.default_rng(1).integers(0, 256, (40, 50), dtype=np.uint8))
    assert_problem(post(c, img[: len(img) // 2], "relief.png", content_type="image/png"), 422, "truncated_file",
                   "relief.png")
    r = post(c, b"\x89PNG\r\n\x1a\n" + b"junk" * 50, "relief.png", content_type="image/png")
    assert r.status_code == 422 and r.json()["code"] in ("unreadable_file", "truncated_file"), r.text
    assert_problem(post(c, b"not a jpeg", "photo.jpg", content_type="image/jpeg"), 422, "unreadable_file",
                   "photo.jpg")


def test_relief_parameters_are_checked(c):
    img = image_bytes(np.random.default_rng(2).integers(0, 256, (20, 20), dtype=np.uint8))
    r = post(c, img, "relief.png", params={"input": {"relief": {"z_min_mm": 4, "z_max_mm": 1}}})
    assert r.status_code == 422 and "input.relief" in r.json()["detail"]


def test_nothing_broken_was_accepted(c, server):
    assert [j for j in c.get("/jobs", params={"limit": 100}).json()["items"] if j["status"] != "cancelled"] == []
    assert list((server.data_dir / "tmp").iterdir()) == []
