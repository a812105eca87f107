"""LAS/LAZ (laspy) and E57 (pye57) read by stage 1: coordinates, poses, structured-scan faces, and
damaged files answered with the file's name and what is wrong. The files are written by the libraries.

No library here ships a sample .las/.laz/.e57 file in site-packages (the wheels carry none), so every
file is written in the test."""

from __future__ import annotations

import numpy as np
import pytest
from mesh_files import las_bytes, write_e57

from planning.errors import InputError, InputTooLarge
from planning.inputs.cloud import read_cloud, read_input
from planning.inputs.e57 import JUMP_FACTOR, _rotation
from schemas.params import InputParams


def expect_code(code: str, fn, *args, **kwargs) -> InputError:
    with pytest.raises(InputError) as info:
        fn(*args, **kwargs)
    assert info.value.code == code, (info.value.code, info.value.message)
    return info.value


def part_points(n: int = 800, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform([0, 0, 0], [80, 60, 40], (n, 3))


def grid_scan(rows: int = 6, cols: int = 8, spacing: float = 0.002):
    r, c = np.divmod(np.arange(rows * cols), cols)
    pts = np.column_stack((c * spacing, r * spacing, 0.5 + 0.0001 * np.sin(c)))
    return pts, r, c


# ------------------------------------------------------------------------------------ LAS / LAZ

@pytest.mark.parametrize("compress, label", [(False, "las"), (True, "laz")])
def test_las_and_laz_scaled_coordinates(tmp_path, compress, label):
    pts = part_points()
    path = tmp_path / f"scan.{label}"
    path.write_bytes(las_bytes(pts, compress=compress, scale=0.001))
    cloud = read_cloud(path)
    assert cloud.source_format == label and cloud.normals is None and cloud.faces is None
    np.testing.assert_allclose(cloud.points, pts, atol=0.0005 + 1e-9)      # raw integers x 0.001 + offset
    assert read_cloud(path.read_bytes()).source_format == label            # detected from 'LASF'


def test_las_units_and_read_input(tmp_path):
    pts = part_points() / 1000.0                                            # metres
    path = tmp_path / "scan.las"
    path.write_bytes(las_bytes(pts, scale=1e-6))
    cloud = read_input(path, InputParams(units="m"))
    np.testing.assert_allclose(cloud.points, pts * 1000.0, atol=1e-3)


def test_las_point_count_is_checked_from_the_header(tmp_path):
    path = tmp_path / "scan.laz"
    path.write_bytes(las_bytes(part_points(), compress=True))
    with pytest.raises(InputTooLarge) as info:
        read_cloud(path, max_points=799)
    assert info.value.code == "too_many_points"
    with pytest.raises(InputTooLarge):
        read_input(path, InputParams(), max_points=500)


def test_damaged_las_and_laz(tmp_path):
    las = las_bytes(part_points())
    laz = las_bytes(part_points(), compress=True)
    path = tmp_path / "cut.las"
    path.write_bytes(las[: len(las) - 500])
    err = expect_code("truncated_file", read_cloud, path)
    assert "cut.las" in err.message and "800 points" in err.message
    path = tmp_path / "cut.laz"
    path.write_bytes(laz[: len(laz) // 2])
    assert "cut.laz" in expect_code("truncated_file", read_cloud, path).message
    path = tmp_path / "garbage.las"
    path.write_bytes(b"LASF" + bytes(range(256)) * 2)
    err = expect_code("unreadable_file", read_cloud, path)
    assert "garbage.las" in err.message and "header" in err.message
    expect_code("unreadable_file", read_cloud, b"LASF" + b"\0" * 100, fmt="las")


# ------------------------------------------------------------------------------------ E57

def test_e57_scan_without_pose(tmp_path):
    pts = part_points(300)
    path = write_e57(tmp_path / "scan.e57", [{"points": pts}])
    cloud = read_cloud(path)
    assert cloud.source_format == "e57" and cloud.faces is None and cloud.normals is None
    np.testing.assert_allclose(cloud.points, pts, rtol=1e-6, atol=1e-5)   # stored as float32 by pye57


def test_e57_every_scan_moved_by_its_pose(tmp_path):
    a, b = part_points(300, seed=1), part_points(200, seed=2)
    angle = np.radians(30.0)
    q = [np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]            # 30 deg about +Z
    t = [100.0, -20.0, 5.0]
    path = write_e57(tmp_path / "two.e57", [{"points": a}, {"points": b, "rotation": q, "translation": t}])
    cloud = read_cloud(path)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(cloud.points[:300], a, atol=1e-4)
    np.testing.assert_allclose(cloud.points[300:], b @ rot.T + t, atol=1e-4)
    np.testing.assert_allclose(_rotation([2.0, 0, 0, 0]), np.eye(3))    # normalised first


def test_e57_from_bytes_and_units(tmp_path):
    pts = part_points(300) / 1000.0
    path = write_e57(tmp_path / "m.e57", [{"points": pts}])
    cloud = read_input(path.read_bytes(), InputParams(units="m"))
    np.testing.assert_allclose(cloud.points, pts * 1000.0, rtol=1e-6, atol=1e-4)


def test_e57_structured_scan_gives_grid_faces(tmp_path):
    pts, r, c = grid_scan(6, 8)
    moved = [np.sqrt(0.5), 0.0, np.sqrt(0.5), 0.0]                   # 90 deg about +Y
    path = write_e57(tmp_path / "grid.e57", [{"points": pts, "row": r, "column": c, "rotation": moved,
                                              "translation": [1, 2, 3]}])
    cloud = read_input(path, InputParams(units="m"))
    assert cloud.n_faces == 2 * 5 * 7
    # every triangle joins grid neighbours: its sides are about one spacing (2 mm), or a diagonal
    p = cloud.points
    for i, j in ((0, 1), (1, 2), (0, 2)):
        side = np.linalg.norm(p[cloud.faces[:, i]] - p[cloud.faces[:, j]], axis=1)
        assert side.max() < 2.0 * np.sqrt(2) + 0.05
    rot = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    np.testing.assert_allclose(p, (pts @ rot.T + [1, 2, 3]) * 1000.0, atol=1e-3)


def test_e57_grid_skips_invalid_points_and_depth_jumps(tmp_path):
    pts, r, c = grid_scan(6, 8)
    pts = pts.copy()
    invalid = np.zeros(len(pts), dtype=np.int8)
    invalid[9] = 2                                                     # an interior point with no return
    pts[30, 2] += 10 * JUMP_FACTOR * 0.002                             # a depth jump at an interior point
    path = write_e57(tmp_path / "holes.e57", [{"points": pts, "row": r, "column": c, "invalid": invalid},
                                              {"points": part_points(50) / 1000.0}])
    cloud = read_input(path, InputParams(units="m"))
    assert cloud.n_points == len(pts) - 1 + 50
    assert cloud.n_faces == 2 * (5 * 7 - 4 - 4)                         # 4 cells around each
    assert cloud.faces.max() < len(pts) - 1                             # the unstructured scan has none


def test_e57_point_count_checked_before_reading(tmp_path):
    path = write_e57(tmp_path / "big.e57", [{"points": part_points(300)}, {"points": part_points(300)}])
    with pytest.raises(InputTooLarge) as info:
        read_cloud(path, max_points=599)
    assert info.value.code == "too_many_points" and info.value.details["n_points"] == 600


def test_damaged_e57(tmp_path):
    data = write_e57(tmp_path / "good.e57", [{"points": part_points(300)}]).read_bytes()
    path = tmp_path / "cut.e57"
    path.write_bytes(data[: len(data) // 2])
    err = expect_code("truncated_file", read_cloud, path)
    assert "cut.e57" in err.message
    path = tmp_path / "broken.e57"
    broken = bytearray(data)
    broken[100:4000] = b"\x55" * 3900                                    # pages of garbage, length kept
    path.write_bytes(bytes(broken))
    err = expect_code("unreadable_file", read_cloud, path)
    assert "broken.e57" in err.message
    path = tmp_path / "zeros.e57"
    path.write_bytes(b"ASTM-E57" + b"\0" * 300)
    assert "zeros.e57" in expect_code("unreadable_file", read_cloud, path).message


def test_las_header_counts_are_checked_before_laspy_reads_them(tmp_path):
    import struct

    las = bytearray(las_bytes(part_points()))
    struct.pack_into("<I", las, 100, 0xFFFF_FFFF)         # VLRs: laspy would read past the end for hours
    err = expect_code("unreadable_file", read_cloud, bytes(las), fmt="las")
    assert "variable length records" in err.message
    laz = bytearray(las_bytes(part_points(), compress=True))
    point_offset = struct.unpack_from("<I", laz, 96)[0]
    table = struct.unpack_from("<q", laz, point_offset)[0]
    struct.pack_into("<I", laz, table + 4, 0xFFFF_FFF0)    # chunks: lazrs would abort the process
    err = expect_code("unreadable_file", read_cloud, bytes(laz), fmt="laz")
    assert "chunk" in err.message
    struct.pack_into("<q", laz, point_offset, len(laz) + 100)
    expect_code("truncated_file", read_cloud, bytes(laz), fmt="laz")
