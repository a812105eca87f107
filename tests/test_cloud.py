"""Tests of planning.inputs.cloud: reading PLY/PCD/XYZ clouds, validation errors, and the atomic PLY writing of planning.report.files."""

from __future__ import annotations

import os
import time

import numpy as np
import plyfile
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from planning.errors import InputError, InputTooLarge, ParameterError
from planning.inputs.cloud import UNIT_SCALE, Cloud, read_cloud, validate_points
from planning.report.files import write_ply

# ------------------------------------------------------------------------------------ helpers

def box_cloud(n: int = 200, seed: int = 0, size_mm: float = 50.0) -> np.ndarray:
    """Points spread in a box (a valid, non-degenerate cloud), in mm."""
    return np.random.default_rng(seed).uniform(-size_mm / 2, size_mm / 2, size=(n, 3))


def unit_rows(n: int, seed: int = 1) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def expect_code(code: str, fn, *args, **kwargs) -> InputError:
    with pytest.raises(InputError) as info:
        fn(*args, **kwargs)
    assert info.value.code == code, (info.value.code, info.value.message)
    assert info.value.message
    return info.value


def ply_bytes(vertices: np.ndarray, *, text: bool, byte_order: str = "<", faces=None,
              faces_first: bool = False) -> bytes:
    """A PLY file written with plyfile (an independent writer)."""
    import io

    elements = [plyfile.PlyElement.describe(vertices, "vertex")]
    if faces is not None:
        face = np.empty(len(faces), dtype=[("vertex_indices", "i4", (3,))])
        face["vertex_indices"] = faces
        face_el = plyfile.PlyElement.describe(face, "face")
        elements = [face_el, *elements] if faces_first else [*elements, face_el]
    buf = io.BytesIO()
    plyfile.PlyData(elements, text=text, byte_order=byte_order).write(buf)
    return buf.getvalue()


def pcd_header(n: int, data: str, fields=("x", "y", "z"), sizes=None, types=None) -> bytes:
    sizes = sizes or ["4"] * len(fields)
    types = types or ["F"] * len(fields)
    return (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(fields)}\nSIZE {' '.join(sizes)}\nTYPE {' '.join(types)}\n"
        f"COUNT {' '.join('1' for _ in fields)}\nWIDTH {n}\nHEIGHT 1\n"
        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    ).encode()


# ------------------------------------------------------------------------------------ PLY

@pytest.mark.parametrize("binary", [True, False])
def test_write_read_ply_round_trip_is_exact(tmp_path, binary):
    pts, nrm = box_cloud(300), unit_rows(300)
    path = tmp_path / "cloud.ply"
    write_ply(path, pts, normals=nrm, colors=np.full((300, 3), 200), labels=np.arange(300) % 4,
              binary=binary)
    cloud = read_cloud(path)
    assert isinstance(cloud, Cloud)
    assert cloud.source_format == ("ply-binary_little_endian" if binary else "ply-ascii")
    assert cloud.points.dtype == np.float64 and cloud.points.shape == (300, 3)
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_allclose(cloud.normals, nrm, atol=1e-15)
    assert cloud.normals_valid.all()


def test_written_ply_is_standard(tmp_path):
    pts = box_cloud(50)
    path = tmp_path / "seg.ply"
    write_ply(path, pts, colors=np.tile([255, 0, 10], (50, 1)), labels=np.arange(50) - 1)
    data = plyfile.PlyData.read(str(path))
    vertex = data["vertex"].data
    assert data.byte_order == "<"
    assert vertex.dtype["x"] == np.dtype("<f8") and vertex.dtype["red"] == np.dtype("u1")
    np.testing.assert_array_equal(vertex["label"], np.arange(50) - 1)
    np.testing.assert_array_equal(vertex["green"], 0)


def test_ply_without_normals_has_none(tmp_path):
    path = tmp_path / "plain.ply"
    write_ply(path, box_cloud(20))
    assert read_cloud(path).normals is None


def test_big_endian_float32_ply_with_faces(tmp_path):
    pts = box_cloud(100).astype(np.float32)
    v = np.empty(100, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("quality", "u1"),
                             ("nx", "f4"), ("ny", "f4"), ("nz", "f4")])
    v["x"], v["y"], v["z"] = pts.T
    v["nx"], v["ny"], v["nz"] = (unit_rows(100) * 3).T.astype(np.float32)     # not unit length
    path = tmp_path / "be.ply"
    path.write_bytes(ply_bytes(v, text=False, byte_order=">", faces=[[0, 1, 2], [2, 3, 4]]))
    cloud = read_cloud(path)
    assert cloud.source_format == "ply-binary_big_endian"
    np.testing.assert_array_equal(cloud.points, pts.astype(np.float64))
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0)


@pytest.mark.parametrize("text", [True, False])
def test_ply_with_faces_before_vertices(text):
    v = np.zeros(30, dtype=[("x", "i2"), ("y", "i2"), ("z", "i2")])
    v["x"], v["y"], v["z"] = np.round(box_cloud(30)).astype(np.int16).T
    data = ply_bytes(v, text=text, faces=[[0, 1, 2]] * 5, faces_first=True)
    cloud = read_cloud(data)
    np.testing.assert_array_equal(cloud.points, np.c_[v["x"], v["y"], v["z"]])


def test_ascii_ply_with_faces_after_vertices():
    v = np.zeros(12, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    v["x"], v["y"], v["z"] = box_cloud(12).T
    cloud = read_cloud(ply_bytes(v, text=True, faces=[[0, 1, 2], [3, 4, 5]]), fmt="ply")
    assert cloud.points.shape == (12, 3)
    np.testing.assert_allclose(cloud.points[:, 0], v["x"])


def test_ply_zero_length_normals_become_nan(tmp_path):
    nrm = unit_rows(20)
    nrm[3] = 0.0
    path = tmp_path / "n.ply"
    write_ply(path, box_cloud(20), normals=nrm)
    cloud = read_cloud(path)
    assert np.isnan(cloud.normals[3]).all()
    assert cloud.normals_valid.sum() == 19


@settings(max_examples=25, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(10, 40), st.just(3)),
                  elements=st.floats(-1000, 1000, allow_nan=False)))
def test_round_trip_property(tmp_path_factory, pts):
    try:
        expected = validate_points(pts)
    except InputError:
        return                     # degenerate draws are rejected, nothing to round-trip
    path = tmp_path_factory.mktemp("rt") / "p.ply"
    write_ply(path, pts, binary=bool(pts.shape[0] % 2))
    np.testing.assert_array_equal(read_cloud(path).points, expected)


# ------------------------------------------------------------------------------------ PCD

def test_pcd_ascii_with_normals(tmp_path):
    pts, nrm = np.round(box_cloud(40), 4), unit_rows(40)
    rows = np.c_[pts, nrm, np.arange(40)]
    body = "\n".join(" ".join(f"{v:.9g}" for v in r) for r in rows) + "\n"
    fields = ("x", "y", "z", "normal_x", "normal_y", "normal_z", "intensity")
    path = tmp_path / "scan.pcd"
    path.write_bytes(pcd_header(40, "ascii", fields) + body.encode())
    cloud = read_cloud(path)
    assert cloud.source_format == "pcd-ascii"
    np.testing.assert_allclose(cloud.points, pts, atol=1e-9)
    np.testing.assert_allclose(cloud.normals, nrm, atol=1e-8)


def test_pcd_binary_mixed_types():
    pts = box_cloud(25)
    rec = np.zeros(25, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("rgb", "<u4"),
                              ("label", "<i2")])
    rec["x"], rec["y"], rec["z"] = pts.T
    header = pcd_header(25, "binary", ("x", "y", "z", "rgb", "label"),
                        sizes=["8", "8", "8", "4", "2"], types=["F", "F", "F", "U", "I"])
    cloud = read_cloud(header + rec.tobytes())          # format detected from magic bytes
    assert cloud.source_format == "pcd-binary"
    np.testing.assert_array_equal(cloud.points, pts)
    assert cloud.normals is None


def test_pcd_binary_compressed_via_open3d(tmp_path):
    o3d = pytest.importorskip("open3d")
    pts = box_cloud(60).astype(np.float32).astype(np.float64)
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(pts)
    path = tmp_path / "c.pcd"
    o3d.io.write_point_cloud(str(path), pcd, compressed=True)
    assert b"binary_compressed" in path.read_bytes()[:400]
    cloud = read_cloud(path)
    assert cloud.source_format == "pcd-binary_compressed"
    np.testing.assert_array_equal(cloud.points, pts)


def test_pcd_truncated_and_oversized():
    rec = np.zeros(10, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    expect_code("truncated_file", read_cloud, pcd_header(10, "binary") + rec.tobytes()[:-5])
    with pytest.raises(InputTooLarge) as info:
        read_cloud(pcd_header(3_000_000_000, "binary") + rec.tobytes())
    assert info.value.code == "too_many_points" and info.value.status == 413


# ------------------------------------------------------------------------------------ text

def test_xyz_whitespace_tabs_comments_and_extra_columns(tmp_path):
    pts = np.round(box_cloud(30), 3)
    lines = ["# exported by scanner", "X Y Z I"]
    lines += [f"{a}\t{b}  {c} 17 0.5" for a, b, c in pts]
    lines.insert(10, "# a comment in the middle")
    path = tmp_path / "scan.xyz"
    path.write_text("\n".join(lines) + "\n\n")
    cloud = read_cloud(path)
    assert cloud.source_format == "xyz"
    np.testing.assert_array_equal(cloud.points, pts)


def test_csv_with_header_and_extra_columns(tmp_path):
    pts = np.round(box_cloud(30), 4)
    text = "x,y,z,r,g,b\n" + "".join(f"{a},{b},{c},1,2,3\n" for a, b, c in pts)
    path = tmp_path / "scan.csv"
    path.write_text(text)
    cloud = read_cloud(path)
    assert cloud.source_format == "csv"
    np.testing.assert_array_equal(cloud.points, pts)


def test_text_from_bytes_with_bom_windows_newlines_and_normals():
    pts, nrm = np.round(box_cloud(20), 3), np.round(unit_rows(20), 6)
    text = "".join(" ".join(str(v) for v in (*p, *n)) + "\r\n" for p, n in zip(pts, nrm))
    cloud = read_cloud(b"\xef\xbb\xbf" + text.encode(), fmt="txt", xyz_normals=True)
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_allclose(cloud.normals, nrm / np.linalg.norm(nrm, axis=1, keepdims=True))
    assert read_cloud(text.encode()).normals is None            # columns 4-6 only when asked


def test_semicolon_csv_with_decimal_commas():
    pts = np.round(box_cloud(15), 2)
    text = "".join(";".join(f"{v:.2f}".replace(".", ",") for v in p) + "\n" for p in pts)
    np.testing.assert_allclose(read_cloud(text.encode()).points, pts)


def test_ragged_text_rows_and_slash_comments():
    pts = np.round(box_cloud(12), 3)
    lines = [f"{a} {b} {c}" + (" 9" if i % 2 else "") for i, (a, b, c) in enumerate(pts)]
    lines.insert(4, "// scanner pass 2")
    np.testing.assert_array_equal(read_cloud("\n".join(lines).encode()).points, pts)


def test_ascii_ply_row_with_missing_value_is_unreadable():
    data = ply_bytes(np.ones(20, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]), text=True)
    head, body = data.split(b"end_header\n")
    rows = body.split(b"\n")
    rows[4] = b"1 1"
    rows[7] = b"1 1 1 1"
    err = expect_code("unreadable_file", read_cloud, head + b"end_header\n" + b"\n".join(rows))
    assert "row 5" in err.message


def test_text_missing_normal_columns():
    text = "".join(f"{a} {b} {c}\n" for a, b, c in box_cloud(20))
    expect_code("missing_normals", read_cloud, text.encode(), xyz_normals=True)


def test_text_with_words_among_numbers_is_unreadable():
    lines = [f"{a} {b} {c}" for a, b, c in box_cloud(20)]
    lines[7] = "1.0 oops 2.0"
    err = expect_code("unreadable_file", read_cloud, ("x y z\n" + "\n".join(lines)).encode())
    assert "line 9" in err.message and "'oops'" in err.message


def test_text_row_with_two_values_is_unreadable():
    lines = [f"{a} {b} {c}" for a, b, c in box_cloud(20)]
    lines[5] = "1.0 2.0"
    err = expect_code("unreadable_file", read_cloud, "\n".join(lines).encode())
    assert "line 6" in err.message


# ------------------------------------------------------------------------------------ units

@pytest.mark.parametrize("units", ["m", "in"])
def test_units_scale_exactly(tmp_path, units):
    raw = box_cloud(50, size_mm=2.0)
    path = tmp_path / "u.ply"
    write_ply(path, raw)
    cloud = read_cloud(path, units=units)
    np.testing.assert_array_equal(cloud.points, raw * UNIT_SCALE[units])
    assert UNIT_SCALE == {"mm": 1.0, "m": 1000.0, "in": 25.4}


def test_unknown_units_name_allowed_values():
    with pytest.raises(ParameterError) as info:
        read_cloud(b"1 2 3\n", units="cm")
    assert "'mm'" in info.value.message and "'in'" in info.value.message
    with pytest.raises(ParameterError):
        read_cloud(b"1 2 3\n", fmt="step")


# ------------------------------------------------------------------------------------ errors

def test_truncated_binary_ply(tmp_path):
    path = tmp_path / "cut.ply"
    write_ply(path, box_cloud(100))
    path.write_bytes(path.read_bytes()[:-100])
    err = expect_code("truncated_file", read_cloud, path)
    assert "100" in err.message


def test_truncated_ascii_ply_rows():
    data = ply_bytes(np.zeros(20, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]), text=True)
    lines = data.split(b"\n")
    expect_code("truncated_file", read_cloud, b"\n".join(lines[:-6]) + b"\n")
    expect_code("truncated_file", read_cloud, b"\n".join(lines[:-2]) + b"\n0 0")   # half a row


def test_truncated_faces_before_vertices_via_plyfile():
    v = np.zeros(30, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    data = ply_bytes(v, text=False, faces=[[0, 1, 2]] * 5, faces_first=True)
    expect_code("truncated_file", read_cloud, data[:-40])


def test_binary_garbage_is_unreadable(tmp_path):
    garbage = np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8).tobytes()
    path = tmp_path / "scan.xyz"
    path.write_bytes(garbage)
    expect_code("unreadable_file", read_cloud, path)
    expect_code("unreadable_file", read_cloud, garbage)
    expect_code("unreadable_file", read_cloud, b"ply\nformat ascii 1.0\n" + garbage)
    expect_code("unreadable_file", read_cloud, garbage, fmt="ply")


@pytest.mark.parametrize("header", [
    b"ply\nformat binary_middle_endian 1.0\nelement vertex 3\nproperty float x\nend_header\n",
    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n2\n3\n",
    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty quad x\nend_header\n",
    b"ply\nformat ascii 1.0\nelement vertex lots\nend_header\n",
    b"ply\nformat ascii 1.0\nelement face 3\nproperty list uchar int vertex_indices\nend_header\n",
    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n",
])
def test_bad_ply_headers_are_unreadable(header):
    expect_code("unreadable_file", read_cloud, header)


def test_header_claiming_4e9_vertices_fails_fast():
    header = (b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n"
              b"property float x\nproperty float y\nproperty float z\nend_header\n")
    start = time.perf_counter()
    with pytest.raises(InputTooLarge) as info:
        read_cloud(header + b"\0" * 120)
    assert time.perf_counter() - start < 0.5
    assert info.value.code == "too_many_points" and info.value.status == 413
    assert "4,000,000,000" in info.value.message


def test_too_many_points_in_text_and_max_bytes(tmp_path):
    text = "".join(f"{a} {b} {c}\n" for a, b, c in box_cloud(50)).encode()
    with pytest.raises(InputTooLarge) as info:
        read_cloud(text, max_points=40)
    assert info.value.code == "too_many_points"
    path = tmp_path / "big.xyz"
    path.write_bytes(text)
    with pytest.raises(InputTooLarge) as info:
        read_cloud(path, max_bytes=100)
    assert info.value.code == "file_too_large" and info.value.status == 413
    assert read_cloud(path, max_points=50, max_bytes=len(text)).n_points == 50


def test_nan_row_reports_count_and_first_index():
    pts = box_cloud(40)
    pts[17, 1] = np.nan
    pts[30, 2] = np.inf
    text = "".join(f"{a} {b} {c}\n" for a, b, c in pts).encode()
    err = expect_code("non_finite", read_cloud, text)
    assert "2 point" in err.message and "17" in err.message
    assert err.details == {"n_bad": 2, "first_index": 17}


@pytest.mark.parametrize("data", [b"", b"x,y,z\n", b"# nothing here\n\n"])
def test_empty_files(data):
    expect_code("empty_cloud", read_cloud, data)


def test_empty_ply_and_empty_file_on_disk(tmp_path):
    path = tmp_path / "empty.ply"
    path.write_bytes(b"")
    expect_code("empty_cloud", read_cloud, path)
    write_ply(path, np.zeros((0, 3)))
    expect_code("empty_cloud", read_cloud, path)
    expect_code("empty_cloud", validate_points, np.zeros((0, 3)))


def test_missing_file_is_unreadable(tmp_path):
    expect_code("unreadable_file", read_cloud, tmp_path / "nope.ply")


def test_three_points_are_too_few():
    err = expect_code("too_few_points", read_cloud, b"0 0 0\n1 0 0\n0 1 0\n")
    assert "3 point" in err.message
    assert read_cloud(b"0 0 0\n1 0 0\n0 1 0\n", min_points=3).n_points == 3


def test_coincident_points_are_degenerate():
    expect_code("degenerate_cloud", validate_points, np.tile([5.0, -2.0, 100.0], (50, 1)))


def test_collinear_points_are_degenerate():
    t = np.linspace(-40, 60, 200)[:, None]
    line = np.array([10.0, 20.0, 30.0]) + t * np.array([0.3, -0.5, 0.8])
    expect_code("degenerate_cloud", validate_points, line)
    far_f32 = (line + 1000.0).astype(np.float32).astype(np.float64)     # float32 rounding noise
    expect_code("degenerate_cloud", validate_points, far_f32)


def test_flat_plane_and_thin_rod_are_accepted():
    rng = np.random.default_rng(5)
    plane = np.c_[rng.uniform(0, 100, (300, 2)), np.zeros(300)]
    np.testing.assert_array_equal(validate_points(plane), plane)
    rod = np.c_[rng.uniform(0, 1000, 300), rng.normal(0, 1.0, (300, 2))]   # 2 mm rod, 1 m long
    assert validate_points(rod).shape == (300, 3)


def test_extent_too_large_hints_at_units(tmp_path):
    path = tmp_path / "mm.ply"
    write_ply(path, box_cloud(50, size_mm=120.0))
    err = expect_code("extent_too_large", read_cloud, path, units="m")
    assert "5,000.0" in err.message and "units" in err.message
    assert err.details["extent_mm"] > 100_000
    expect_code("extent_too_large", validate_points, box_cloud(50, size_mm=60.0), max_extent_mm=50)


@pytest.mark.parametrize("name,data", [
    ("part.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
    ("part.step", b"ISO-10303-21;\nHEADER;\n"),
    ("scan.ptx", b"10\n10\n0 0 0\n"),
])
def test_unsupported_formats(tmp_path, name, data):
    path = tmp_path / name
    path.write_bytes(data)
    expect_code("unsupported_format", read_cloud, path)


@pytest.mark.parametrize("name,data,code", [
    ("scan.las", b"LASF" + b"\0" * 300, "unreadable_file"),
    ("scan.e57", b"ASTM-E57" + b"\0" * 300, "unreadable_file"),
    ("part.stl", b"solid part\nfacet normal 0 0 1\n", "truncated_file"),
])
def test_formats_read_elsewhere_name_what_is_broken(tmp_path, name, data, code):
    path = tmp_path / name
    path.write_bytes(data)
    err = expect_code(code, read_cloud, path)
    assert name in err.message


def test_validate_points_rejects_bad_shapes():
    expect_code("unreadable_file", validate_points, np.zeros((10, 2)))
    out = validate_points(box_cloud(20).astype(np.float32))
    assert out.dtype == np.float64 and out.flags.c_contiguous


# ------------------------------------------------------------------------------------ writing

def _leftovers(folder) -> list[str]:
    return [p for p in os.listdir(folder) if p.endswith(".tmp")]


def test_atomic_write_leaves_no_temp_file(tmp_path):
    write_ply(tmp_path / "a.ply", box_cloud(20), binary=False)
    assert sorted(os.listdir(tmp_path)) == ["a.ply"]


def test_failed_write_keeps_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "a.ply"
    write_ply(path, box_cloud(20))
    before = path.read_bytes()

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError):
        write_ply(path, box_cloud(30, seed=9))
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert _leftovers(tmp_path) == []


def test_write_ply_rejects_mismatched_arrays(tmp_path):
    with pytest.raises(ParameterError):
        write_ply(tmp_path / "x.ply", box_cloud(10), labels=np.zeros(9, dtype=int))
    with pytest.raises(ParameterError):
        write_ply(tmp_path / "x.ply", box_cloud(10), colors=np.full((10, 3), 300))
    assert os.listdir(tmp_path) == []
