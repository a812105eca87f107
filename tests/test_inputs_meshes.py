"""Meshes read by stage 1: STL (ascii, binary), OBJ and PLY with faces, into Cloud.points + Cloud.faces.

The files are written by tests/mesh_files.py (struct, plain text, plyfile), independently of the readers."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from mesh_files import (canonical_triangles, cube_mesh, obj_text, ply_mesh, sphere_mesh, stl_ascii,
                        stl_binary)

from planning.errors import InputError, InputTooLarge
from planning.inputs.cloud import read_cloud
from planning.inputs.mesh import _fan_triangles, _grid_triangles, _merge_vertices
from planning.inputs.validate import validate_faces


def expect_code(code: str, fn, *args, **kwargs) -> InputError:
    with pytest.raises(InputError) as info:
        fn(*args, **kwargs)
    assert info.value.code == code, (info.value.code, info.value.message)
    return info.value


def same_mesh(cloud, vertices, faces) -> None:
    """Same vertex set and the same triangles (corners as coordinates, winding kept) up to order."""
    got = {tuple(p) for p in cloud.points.tolist()}
    assert got == {tuple(p) for p in np.asarray(vertices, dtype=np.float64).tolist()}
    assert cloud.points.shape[0] == len(got)
    assert canonical_triangles(cloud.points, cloud.faces) == canonical_triangles(vertices, faces)
    assert cloud.faces.dtype == np.int64 and cloud.faces.shape == (len(faces), 3)


# ------------------------------------------------------------------------------------ STL

def test_binary_stl_merges_corners_into_shared_vertices(tmp_path):
    v, f = cube_mesh()
    path = tmp_path / "cube.stl"
    path.write_bytes(stl_binary(v, f))
    cloud = read_cloud(path, min_points=4)
    assert cloud.source_format == "stl-binary" and cloud.normals is None
    assert cloud.n_points == 8 and cloud.n_faces == 12        # 36 corners -> 8 vertices
    same_mesh(cloud, v, f)


def test_binary_stl_whose_header_says_solid_is_read_as_binary():
    v, f = sphere_mesh()
    data = stl_binary(v.astype(np.float32), f, header=b"solid exported by a CAD system")
    cloud = read_cloud(data)
    assert cloud.source_format == "stl-binary"
    same_mesh(cloud, v.astype(np.float32), f)


def test_binary_stl_detected_without_a_name():
    v, f = sphere_mesh()
    assert read_cloud(stl_binary(v, f)).source_format == "stl-binary"


def test_ascii_stl(tmp_path):
    v, f = sphere_mesh()
    path = tmp_path / "sphere.stl"
    path.write_bytes(stl_ascii(v, f, fmt="{!r}"))
    cloud = read_cloud(path)
    assert cloud.source_format == "stl-ascii"
    same_mesh(cloud, v, f)


def test_ascii_stl_upper_case_crlf_several_solids_and_signed_zero():
    v, f = cube_mesh()
    v = v - 10.0                                        # coordinates -10 and 10
    one = stl_ascii(v, f[:6], name="first part 1").upper().replace(b"\n", b"\r\n")
    two = stl_ascii(v, f[6:], name="second").replace(b" -10 ", b" -10.0e0 ")
    cloud = read_cloud(one + two, min_points=4)
    assert cloud.source_format == "stl-ascii" and cloud.n_points == 8
    same_mesh(cloud, v, f)
    zero = stl_ascii(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), [[0, 1, 2], [0, 2, 3]])
    cloud = read_cloud(zero.replace(b"vertex 0 0 0", b"vertex -0 0 -0", 1), min_points=4)
    assert cloud.n_points == 4                          # -0 and 0 are one vertex


def test_truncated_binary_stl():
    v, f = sphere_mesh()
    data = stl_binary(v, f)
    err = expect_code("truncated_file", read_cloud, data[:-30], fmt="stl")
    assert f"{len(f):,} triangles" in err.message
    expect_code("truncated_file", read_cloud, data[:50], fmt="stl")
    expect_code("unreadable_file", read_cloud, data + b"\0" * 7, fmt="stl")


def test_truncated_binary_stl_by_name(tmp_path):
    v, f = cube_mesh()
    path = tmp_path / "part.stl"
    path.write_bytes(stl_binary(v, f)[:300])
    err = expect_code("truncated_file", read_cloud, path)
    assert "part.stl" in err.message


def test_broken_ascii_stl():
    v, f = cube_mesh()
    data = stl_ascii(v, f)
    expect_code("truncated_file", read_cloud, data[: len(data) // 2], fmt="stl")
    err = expect_code("unreadable_file", read_cloud, data.replace(b"vertex 20 0 0", b"vertex 20 zero 0", 1),
                      fmt="stl")
    assert "zero" in err.message
    expect_code("unreadable_file", read_cloud, data.replace(b"vertex 0 0 20\n", b"", 1), fmt="stl")
    expect_code("unreadable_file", read_cloud, data.replace(b"vertex 0 0 20", b"vertex 0 0", 1), fmt="stl")


def test_stl_triangle_count_is_checked_before_decoding():
    header = b" " * 80 + struct.pack("<I", 3_000_000_000)
    with pytest.raises(InputTooLarge) as info:
        read_cloud(header + b"\0" * 500, fmt="stl", max_points=1_000_000)
    assert info.value.code == "too_many_points"
    expect_code("empty_cloud", read_cloud, b" " * 80 + struct.pack("<I", 0), fmt="stl")


def test_stl_degenerate_facets_are_dropped():
    v, f = cube_mesh()
    v = np.vstack((v, [[5.0, 0, 0]]))                  # on the edge 0-1
    faces = np.vstack((f, [[0, 8, 1], [2, 2, 3]]))     # zero area, and a repeated corner
    cloud = read_cloud(stl_binary(v, faces), min_points=4)
    assert cloud.n_faces == 12
    assert canonical_triangles(cloud.points, cloud.faces) == canonical_triangles(v, f)


# ------------------------------------------------------------------------------------ OBJ

@pytest.mark.parametrize("style", ["plain", "vt", "vn", "vtvn"])
@pytest.mark.parametrize("negative", [False, True])
def test_obj_face_syntaxes_and_negative_indices(style, negative):
    v, f = sphere_mesh()
    cloud = read_cloud(obj_text(v, f, style=style, negative=negative), fmt="obj")
    assert cloud.source_format == "obj"
    np.testing.assert_array_equal(cloud.points, v)     # OBJ vertices keep their order
    np.testing.assert_array_equal(cloud.faces, f)


def test_obj_polygons_are_fan_triangulated(tmp_path):
    v = np.array([[0.0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0], [-5, 5, 0], [0, 0, 10]])
    path = tmp_path / "poly.obj"
    path.write_bytes(obj_text(v, [[0, 1, 2, 3, 4], [0, 1, 5]], style="vt"))
    cloud = read_cloud(path, min_points=4)
    assert cloud.faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 1, 5]]


def test_obj_comments_crlf_colours_groups_and_detection_without_name():
    text = ("# exported\r\nmtllib part.mtl\r\no part\r\n"
            "v 0 0 0 1 0 0\r\nv 10 0 0 0 1 0   # a coloured vertex\r\nv 0 10 0\r\nv 0 0 10 1.0\r\n"
            "vn 0 0 1\r\ng side\r\nusemtl steel\r\ns 1\r\n  f 1//1 2//1 3//1\r\nf 1 3 4\r\nl 1 2\r\n")
    cloud = read_cloud(text.encode(), min_points=4)
    assert cloud.source_format == "obj"
    np.testing.assert_array_equal(cloud.points, [[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]])
    assert cloud.faces.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_obj_without_faces_is_a_plain_cloud():
    v, _ = sphere_mesh()
    cloud = read_cloud(obj_text(v, []), fmt="obj")
    assert cloud.faces is None and cloud.n_faces == 0 and cloud.n_points == len(v)


def test_obj_negative_index_counts_back_from_the_line():
    text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nf -4 -2 -1\n"
    cloud = read_cloud(text, fmt="obj", min_points=4)
    assert cloud.faces.tolist() == [[0, 1, 2], [0, 2, 3]]


@pytest.mark.parametrize("face, words", [
    ("f 1 2 9", ["line 5", "vertex 9", "4 vertices"]),
    ("f 0 1 2", ["line 5", "vertex 0"]),
    ("f -1 -2 -7", ["line 5", "-7"]),
    ("f 1 2", ["line 5", "at least 3"]),
    ("f 1 2 x", ["line 5"]),
])
def test_obj_bad_faces_name_the_line(face, words):
    text = f"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n{face}\n".encode()
    err = expect_code("unreadable_file", read_cloud, text, fmt="obj", min_points=4)
    for w in words:
        assert w in err.message, (w, err.message)


def test_obj_bad_vertices_and_empty(tmp_path):
    err = expect_code("unreadable_file", read_cloud, b"v 0 0 0\nv 1 0\nv 0 1 0\nv 0 0 1\n", fmt="obj")
    assert "line 2" in err.message
    err = expect_code("unreadable_file", read_cloud, b"v 0 0 0\nv 1 0 nan0\nv 0 1 0\n", fmt="obj")
    assert "line 2" in err.message
    expect_code("empty_cloud", read_cloud, b"# nothing\no empty\n", fmt="obj")
    path = tmp_path / "bin.obj"
    path.write_bytes(b"v 0 0 0\n\x00\x01\x02\x03")
    assert "bin.obj" in expect_code("unreadable_file", read_cloud, path).message


def test_obj_vertex_count_is_checked_before_parsing():
    text = b"v 1 2 3\n" * 50
    with pytest.raises(InputTooLarge):
        read_cloud(text, fmt="obj", max_points=49)


# ------------------------------------------------------------------------------------ PLY faces

@pytest.mark.parametrize("binary, order", [(True, "<"), (True, ">"), (False, "<")])
def test_ply_triangles(binary, order):
    v, f = sphere_mesh()
    cloud = read_cloud(ply_mesh(v, f, binary=binary, byte_order=order))
    np.testing.assert_array_equal(cloud.points, v)
    np.testing.assert_array_equal(cloud.faces, f)


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("extra", [False, True])
def test_ply_mixed_polygons_are_fan_triangulated(binary, extra):
    v = np.random.default_rng(3).uniform(0, 50, (12, 3))
    polys = [[0, 1, 2], [3, 4, 5, 6], [7, 8, 9, 10, 11], [0, 5, 9]]
    cloud = read_cloud(ply_mesh(v, polys, binary=binary, face_extra=extra, count_type="u1", index_type="u4"))
    assert cloud.faces.tolist() == [[0, 1, 2], [3, 4, 5], [3, 5, 6], [7, 8, 9], [7, 9, 10], [7, 10, 11],
                                    [0, 5, 9]]


@pytest.mark.parametrize("binary", [True, False])
def test_ply_quads_vertex_index_name_and_int_counts(binary):
    v = np.random.default_rng(4).uniform(0, 50, (8, 3))
    cloud = read_cloud(ply_mesh(v, [[0, 1, 2, 3], [4, 5, 6, 7]], binary=binary, list_name="vertex_index",
                                count_type="i4", index_type="i2"), min_points=4)
    assert cloud.faces.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]


def test_ply_faces_before_vertices_and_elements_after():
    import io

    import plyfile

    v = np.random.default_rng(5).uniform(0, 50, (30, 3))
    vt = np.array([tuple(p) for p in v], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    ft = np.empty(3, dtype=[("vertex_indices", "O")])
    ft["vertex_indices"] = [np.array(p, dtype="i4") for p in ([0, 1, 2], [3, 4, 5, 6], [7, 8, 9])]
    et = np.array([(0, 1), (1, 2)], dtype=[("vertex1", "i4"), ("vertex2", "i4")])
    for text in (True, False):
        buf = io.BytesIO()
        plyfile.PlyData([plyfile.PlyElement.describe(ft, "face"), plyfile.PlyElement.describe(vt, "vertex"),
                         plyfile.PlyElement.describe(et, "edge")], text=text).write(buf)
        cloud = read_cloud(buf.getvalue())
        np.testing.assert_array_equal(cloud.points, v.astype(np.float32))
        assert cloud.faces.tolist() == [[0, 1, 2], [3, 4, 5], [3, 5, 6], [7, 8, 9]]


def test_ply_without_face_element_has_no_faces(tmp_path):
    from planning.report.files import write_ply

    v, _ = sphere_mesh()
    path = tmp_path / "cloud.ply"
    write_ply(path, v)
    assert read_cloud(path).faces is None


@pytest.mark.parametrize("binary", [True, False])
def test_ply_face_index_out_of_range(binary):
    v, f = sphere_mesh()
    f = f.copy()
    f[5, 1] = len(v) + 3
    err = expect_code("unreadable_file", read_cloud, ply_mesh(v, f, binary=binary))
    assert "Face 6" in err.message and str(len(v) + 3) in err.message


def test_ply_truncated_faces():
    v, f = sphere_mesh()
    data = ply_mesh(v, f, binary=True)
    expect_code("truncated_file", read_cloud, data[:-20])
    mixed = ply_mesh(v, [[0, 1, 2, 3]] + f.tolist(), binary=True)          # lists of two lengths
    expect_code("truncated_file", read_cloud, mixed[:-20])
    text = ply_mesh(v, f, binary=False)
    expect_code("truncated_file", read_cloud, text[: text.rindex(b"\n3 ")])


# ------------------------------------------------------------------------------------ round trip

def test_mesh_written_as_stl_and_as_ply_reads_back_equal(tmp_path):
    v, f = sphere_mesh(n_lat=16, n_lon=32, radius=40.0)
    v = v.astype(np.float32).astype(np.float64)         # what binary STL can hold exactly
    (tmp_path / "m.stl").write_bytes(stl_binary(v, f))
    (tmp_path / "a.stl").write_bytes(stl_ascii(v, f, fmt="{!r}"))
    (tmp_path / "m.ply").write_bytes(ply_mesh(v, f, binary=True))
    (tmp_path / "m.obj").write_bytes(obj_text(v, f))
    clouds = [read_cloud(tmp_path / n) for n in ("m.stl", "a.stl", "m.ply", "m.obj")]
    ref = canonical_triangles(clouds[2].points, clouds[2].faces)
    for cloud in clouds:
        same_mesh(cloud, v, f)
        assert canonical_triangles(cloud.points, cloud.faces) == ref


# ------------------------------------------------------------------------------------ helpers

def test_merge_vertices_is_exact():
    raw = np.array([[1.0, 2, 3], [1.0, 2, 3 + 1e-12], [-0.0, 0, 0], [0.0, 0, 0], [1.0, 2, 3]])
    unique, inverse = _merge_vertices(raw)
    assert unique.shape == (3, 3)
    np.testing.assert_array_equal(unique[inverse], raw + 0.0)
    assert inverse[0] == inverse[4] and inverse[2] == inverse[3] and inverse[0] != inverse[1]
    u32, _ = _merge_vertices(raw.astype(np.float32))
    assert u32.shape == (2, 3) and u32.dtype == np.float64                # 3 + 1e-12 rounds to 3 in float32


def test_fan_triangles():
    out = _fan_triangles(np.array([7, 8, 9, 1, 2, 3, 4, 5]), np.array([3, 5]))
    assert out.tolist() == [[7, 8, 9], [1, 2, 3], [1, 3, 4], [1, 4, 5]]
    assert _fan_triangles(np.zeros(0), np.zeros(0)).shape == (0, 3)


def test_validate_faces_drops_degenerate_and_refuses_out_of_range():
    pts = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [5, 0, 0], [20, 0, 0]])
    faces = np.array([[0, 1, 2], [0, 1, 1], [0, 3, 1], [0, 1, 4], [1, 2, 0]])
    out = validate_faces(faces, pts)
    assert out.tolist() == [[0, 1, 2], [1, 2, 0]] and out.dtype == np.int64
    assert validate_faces(None, pts) is None
    with pytest.raises(InputError) as info:
        validate_faces(np.array([[0, 1, 5]]), pts)
    assert info.value.code == "unreadable_file" and "vertex 5" in info.value.message
    with pytest.raises(InputError):
        validate_faces(np.array([[0, -1, 2]]), pts)


def test_grid_triangles_skip_missing_points_and_depth_jumps():
    rows, cols = np.divmod(np.arange(20), 5)                    # a 4 x 5 grid, 1 mm apart
    pts = np.column_stack((cols * 1.0, rows * 1.0, np.zeros(20)))
    tri = _grid_triangles(rows, cols, pts, 4.0)
    assert tri.shape == (2 * 3 * 4, 3)
    keep = np.arange(20) != 7                                   # a missing point: its 4 cells go
    tri = _grid_triangles(rows[keep], cols[keep], pts[keep], 4.0)
    assert tri.shape == (2 * (12 - 4), 3)
    jump = pts.copy()
    jump[12, 2] = 30.0                                          # a depth jump: its 4 cells go
    assert _grid_triangles(rows, cols, jump, 4.0).shape == (2 * (12 - 4), 3)
