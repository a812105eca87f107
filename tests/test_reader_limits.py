"""The readers check declared counts against the file and the limits before they allocate (issue 29).

Each finding of the issue has its test: the hostile files are read in one child process under an
address-space limit (tests/hostile_files.py: 1.5 GB over the child's size once the readers are imported),
which reports per file what the reader answered and the child's peak resident memory so far; a reader
that trusted a count would fail there with a MemoryError (or blow the limit) instead of a typed refusal.
Then the CLI's exit status and stderr on two of them, duplicate and degenerate faces, ``max_faces``, and
the one guard of ``read_cloud`` that turns any other failure inside a reader into a typed error.
"""

from __future__ import annotations

import re
import struct
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hostile_files import (
    RSS_LIMIT,
    las_bytes,
    las_with_count,
    laz_claiming_points,
    obj_copies_of_one_triangle,
    ply_claiming_faces,
    ply_list_count,
    ply_mesh_ascii,
    ply_mesh_binary,
    read_in_child,
)
from mesh_files import cube_mesh, sphere_mesh, stl_ascii, stl_binary

from planning.errors import InputError, InputTooLarge
from planning.inputs import cloud as cloud_module
from planning.inputs.cloud import read_cloud, read_input
from planning.inputs.facet_points import planned_point_count, points_on_facets
from schemas.params import InputParams

ONE_MILLION = 1_000_000


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    """The hostile files of issue 29, read in one child under RLIMIT_AS: {name: the child's result}."""
    root = tmp_path_factory.mktemp("hostile")
    files = {
        "ply316.ply": ply_claiming_faces(250_000_000, pad_to=316),
        "ply1e12.ply": ply_claiming_faces(10 ** 12),
        "plylist.ply": ply_list_count(0xFFFFFFFF),
        "laz19m.laz": laz_claiming_points(19_000_000),
        "las19m.las": las_with_count(las_bytes(np.random.default_rng(3).uniform(0, 50, (400, 3))), 19_000_000),
        "obj1m.obj": obj_copies_of_one_triangle(ONE_MILLION),
    }
    for name, data in files.items():
        (root / name).write_bytes(data)
    jobs = [
        ("ply316", root / "ply316.ply", {}),
        ("ply316_raised", root / "ply316.ply", {"max_faces": 10 ** 13}),
        ("ply1e12", root / "ply1e12.ply", {}),
        ("ply1e12_raised", root / "ply1e12.ply", {"max_faces": 10 ** 13}),
        ("plylist", root / "plylist.ply", {}),
        ("laz19m", root / "laz19m.laz", {}),
        ("las19m", root / "las19m.las", {}),
        ("obj1m", root / "obj1m.obj", {}),
    ]
    report = read_in_child([(path, kw) for _, path, kw in jobs])
    assert report["returncode"] == 0, report["stderr"][-3000:]
    assert report["stderr"] == ""
    results = dict(zip((name for name, _, _ in jobs), report["results"]))
    return {"results": results, "files": {name: root / name for name in files},
            "limit_enforced": report["limit_enforced"]}


def refused(hostile, name: str, code: str) -> dict:
    """The child's result for ``name``: a typed refusal with ``code``, no Python warning, peak RSS bounded."""
    r = hostile["results"][name]
    assert not r["ok"] and r["code"] == code, r
    assert r["error"] in ("InputError", "InputTooLarge"), r
    assert r["python_warnings"] == [], r
    assert r["max_rss"] < RSS_LIMIT, r["max_rss"]
    return r


def test_ply_316_bytes_claiming_250m_faces_allocates_nothing(hostile):
    """Before: 16 bytes per declared record allocated (3.96 GiB) before the first record was walked."""
    assert hostile["files"]["ply316.ply"].stat().st_size == 316
    r = refused(hostile, "ply316", "too_many_faces")
    assert r["status"] == 413
    assert r["details"] == {"n_faces": 250_000_000, "max_faces": 10_000_000, "parameter": "input.max_faces"}
    assert "input.max_faces" in r["message"] and "250,000,000" in r["message"]
    # under a limit that lets the faces through, the file cannot hold them: cut off, nothing allocated
    r = refused(hostile, "ply316_raised", "truncated_file")
    assert "250,000,000 'face' records" in r["message"]


def test_ply_claiming_1e12_faces_is_refused_not_a_memory_error(hostile):
    """Before: MemoryError (a traceback and exit 1 from the CLI)."""
    r = refused(hostile, "ply1e12", "too_many_faces")
    assert "1,000,000,000,000" in r["message"]
    refused(hostile, "ply1e12_raised", "truncated_file")


def test_ply_list_count_0xffffffff_is_a_truncated_file(hostile):
    """Before: ValueError from numpy (a record dtype of 4e9 items); the record cannot fit in the file."""
    r = refused(hostile, "plylist", "truncated_file")
    assert "4,294,967,295 items" in r["message"]


def test_laz_claiming_19m_points_decodes_in_chunks(hostile):
    """Before: laspy allocated count x record length (19 M x 158 B = 3.05 GiB) up front; under the limit
    that was a MemoryError reported as an unreadable file. The points are now decoded in chunks and the
    data runs out at the first."""
    assert hostile["files"]["laz19m.laz"].stat().st_size < 40_000
    r = refused(hostile, "laz19m", "truncated_file")
    assert "MemoryError" not in r["message"]
    r = refused(hostile, "las19m", "truncated_file")              # uncompressed: count x length vs the size
    assert "19,000,000 points" in r["message"]


def test_obj_of_1m_copies_of_one_triangle_is_one_triangle(hostile):
    """Before: every copy kept (8 M copies: 79.5 s and 2.6 GiB in the issue); now the duplicates are
    dropped and said in the warnings, reading vectorised (integer parsing of the face block)."""
    r = hostile["results"]["obj1m"]
    assert r["ok"], r
    assert (r["n_points"], r["n_faces"]) == (3, 1)
    assert r["warnings"] == ["999,999 duplicate triangles dropped (the same three vertices as an earlier triangle)"]
    assert r["python_warnings"] == [] and r["max_rss"] < RSS_LIMIT


def test_faces_over_max_faces_are_refused_before_reading(tmp_path):
    obj = obj_copies_of_one_triangle(ONE_MILLION)
    with pytest.raises(InputTooLarge) as info:
        read_cloud(obj, fmt="obj", max_faces=1000)
    e = info.value
    assert e.code == "too_many_faces" and e.status == 413
    assert e.details == {"n_faces": ONE_MILLION, "max_faces": 1000, "parameter": "input.max_faces"}
    assert "input.max_faces" in e.message and "1,000,000" in e.message and "1,000" in e.message
    path = tmp_path / "many.obj"
    path.write_bytes(obj)
    with pytest.raises(InputTooLarge) as info:                       # the plan's parameter reaches the reader
        read_input(path, InputParams(max_faces=999_999))
    assert info.value.code == "too_many_faces"
    v, f = sphere_mesh()                                              # 264 triangles
    for data, fmt in ((stl_binary(v, f), "stl"), (stl_ascii(v, f), "stl"), (ply_mesh_ascii(v, f), "ply"),
                      (ply_mesh_binary(v, [list(t) for t in f]), "ply")):
        with pytest.raises(InputTooLarge) as info:
            read_cloud(data, fmt=fmt, max_faces=len(f) - 1)
        assert info.value.code == "too_many_faces", fmt
        assert read_cloud(data, fmt=fmt, max_faces=len(f)).n_faces == len(f)
    quads = ply_mesh_binary(v, [list(t) + [t[0]] for t in f[:100]])  # 100 records, 200 triangles
    with pytest.raises(InputTooLarge) as info:
        read_cloud(quads, fmt="ply", max_faces=150)
    assert info.value.details["n_faces"] == 200


def test_all_degenerate_mesh_is_a_plain_cloud_held_to_min_points():
    """Before: the point minimum was lowered to 3 because the file had faces, and a 6-point, 0-face
    'part' was planned."""
    pts = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10], [10, 10, 0], [5, 5, 5]], dtype=float)
    faces = [[0, 0, 1], [1, 2, 2], [3, 4, 3], [0, 1, 0]]          # every one repeats a vertex
    obj = "".join(f"v {x} {y} {z}\n" for x, y, z in pts) + "".join(
        "f " + " ".join(str(i + 1) for i in t) + "\n" for t in faces)
    with pytest.raises(InputError) as info:
        read_cloud(obj.encode(), fmt="obj")
    e = info.value
    assert e.code == "too_few_points" and e.details["min_points"] == 10 and e.details["n_points"] == 6
    assert "4 triangles" in e.message and "degenerate" in e.message
    cloud = read_cloud(obj.encode(), fmt="obj", min_points=6)        # enough points: a plain cloud
    assert cloud.faces is None and cloud.n_points == 6
    assert cloud.warnings == (("Every one of the mesh's 4 triangles was dropped (4 degenerate triangles dropped "
                               "(a repeated vertex or zero area)); its 6 vertices are planned as a point cloud."),)


def test_duplicate_and_degenerate_faces_are_dropped_and_said():
    v, f = cube_mesh()
    extra = np.array([f[0][[1, 2, 0]], f[0][[2, 1, 0]], f[3], [0, 1, 1]])   # rotated, reversed, repeated, degenerate
    faces = np.vstack((f, extra))
    for data, fmt in ((ply_mesh_ascii(v, faces), "ply"), (ply_mesh_binary(v, faces), "ply"),
                      (("".join(f"v {x} {y} {z}\n" for x, y, z in v) +
                        "".join("f " + " ".join(str(i + 1) for i in t) + "\n" for t in faces)).encode(), "obj")):
        cloud = read_cloud(data, fmt=fmt)
        assert cloud.n_faces == 12, fmt
        np.testing.assert_array_equal(cloud.faces, f)                # the first of each kept, in file order
        assert cloud.warnings == ("1 degenerate triangle dropped (a repeated vertex or zero area)",
                                  ("3 duplicate triangles dropped (the same three vertices as an earlier "
                                   "triangle)")), fmt
    stl = read_cloud(stl_binary(v, np.vstack((f, f[:5]))), fmt="stl")   # STL corners merged, then compared
    assert stl.n_faces == 12
    assert stl.warnings == ("5 duplicate triangles dropped (the same three vertices as an earlier triangle)",)
    assert read_cloud(stl_binary(v, f), fmt="stl").warnings == ()


def _scanmill_command() -> list[str]:
    script = Path(sys.executable).with_name("scanmill")
    return [str(script)] if script.exists() else [sys.executable, "-m", "scanmill.cli"]


def test_cli_exits_2_with_one_error_line_on_hostile_ply(tmp_path):
    """Before: exit 1 and a traceback (MemoryError for 1e12 faces, ValueError for the list count)."""
    cases = {"ply1e12.ply": (ply_claiming_faces(10 ** 12), "too_many_faces"),
             "plylist.ply": (ply_list_count(0xFFFFFFFF), "truncated_file")}
    running = {}
    for name, (data, _) in cases.items():
        (tmp_path / name).write_bytes(data)
        out = tmp_path / f"out-{name}"
        running[name] = (out, subprocess.Popen([*_scanmill_command(), "plan", str(tmp_path / name), "--out", str(out),
                                                "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                               text=True, cwd=tmp_path))
    for name, (out, proc) in running.items():
        stdout, stderr = proc.communicate()
        lines = stderr.splitlines()
        assert proc.returncode == 2, (name, proc.returncode, stderr[-2000:])
        assert len(lines) == 1 and re.fullmatch(rf"error \[{cases[name][1]}\]: \S.*", lines[0]), stderr
        assert stdout == "" and not out.exists()


def _pcd(n: int = 30) -> bytes:
    pts = np.random.default_rng(1).uniform(0, 40, (n, 3))
    head = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {n}\nHEIGHT 1\nPOINTS {n}\nDATA binary\n").encode()
    return head + pts.astype("<f4").tobytes()


@pytest.mark.parametrize("exc, code, cls", [
    (MemoryError("Unable to allocate 3.96 GiB"), "too_large_for_memory", InputTooLarge),
    (ValueError("negative dimensions are not allowed"), "unreadable_file", InputError),
    (OverflowError("cannot fit 'int' into an index-sized integer"), "unreadable_file", InputError),
    (struct.error("unpack requires a buffer of 8 bytes"), "unreadable_file", InputError),
    (IndexError("index 7 is out of bounds"), "unreadable_file", InputError),
])
def test_any_failure_inside_a_reader_becomes_a_typed_error(monkeypatch, exc, code, cls):
    def broken(src, max_points):
        raise exc

    monkeypatch.setattr(cloud_module, "_read_pcd", broken)
    with pytest.raises(InputError) as info:
        read_cloud(_pcd(), fmt="pcd")
    e = info.value
    assert type(e) is cls and e.code == code
    assert type(exc).__name__ in e.message and e.__cause__ is None and e.__suppress_context__


def test_typed_errors_pass_through_and_no_warning_escapes(monkeypatch):
    typed = InputError("cut off", code="truncated_file")

    def raising(src, max_points):
        raise typed

    monkeypatch.setattr(cloud_module, "_read_pcd", raising)
    with pytest.raises(InputError) as info:
        read_cloud(_pcd(), fmt="pcd")
    assert info.value is typed

    def noisy(src, max_points):
        warnings.warn("a library's warning", UserWarning)
        np.array([np.nan, 1e300]).astype(np.int64)                  # numpy: invalid value in cast
        np.log(np.zeros(2))                                          # numpy: divide by zero
        pts = np.random.default_rng(0).uniform(0, 40, (30, 3))
        return pts, None, "pcd-binary"

    monkeypatch.setattr(cloud_module, "_read_pcd", noisy)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert read_cloud(_pcd(), fmt="pcd").n_points == 30
    assert caught == []


def _grid_mesh(n: int, m: int):
    r, c = np.divmod(np.arange(n * m), m)
    v = np.column_stack((c * 0.7, r * 0.7, np.sin(c * 0.3) * np.cos(r * 0.2)))
    a = (r * m + c)[(r < n - 1) & (c < m - 1)]
    return v, np.concatenate([np.column_stack((a, a + 1, a + m + 1)), np.column_stack((a, a + m + 1, a + m))])


def test_facet_edges_by_int64_keys_equal_numpy_unique_rows():
    """The 1-D keys a V + b give the edges numpy.unique(axis=0) gave, in its order, with the same facets."""
    from planning.inputs.facet_points import _edges, _unique_edges
    rng = np.random.default_rng(5)
    tangled = rng.integers(0, 60, (300, 3))                         # edges shared by 1, 2 or more facets
    tangled = tangled[(tangled[:, 0] != tangled[:, 1]) & (tangled[:, 1] != tangled[:, 2])
                      & (tangled[:, 0] != tangled[:, 2])]
    meshes = [cube_mesh(), sphere_mesh(), _grid_mesh(30, 41), (rng.uniform(0, 30, (60, 3)), tangled)]
    for v, f in meshes:
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(e, axis=0, return_inverse=True)
        edges, facets = _edges(f)
        np.testing.assert_array_equal(edges, uniq)
        np.testing.assert_array_equal(_unique_edges(f), uniq)
        owner = np.tile(np.arange(len(f)), 3)
        for k in rng.choice(len(uniq), min(20, len(uniq)), replace=False):
            expected = sorted(owner[inv.ravel() == k][:2])
            assert sorted(x for x in facets[k] if x >= 0) == expected
        for s, cap in ((0.4, 2_000_000), (2.0, 2_000_000), (0.4, 300)):
            fp = points_on_facets(v, f, s, cap)
            assert planned_point_count(v, f, s, cap) == (fp.points.shape[0] if fp.spacing_mm == s else
                                                        max(cap, len(v)))


def test_hostile_child_really_runs_under_the_limit(hostile):
    """The address-space limit is in force in the child (else the other tests prove nothing): there, a
    buffer of the headroom and 256 MiB more cannot be had."""
    assert hostile["limit_enforced"] is True
