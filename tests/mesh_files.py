"""Writers of the input formats the readers take, for the tests: meshes (STL ascii/binary, OBJ, PLY with
faces), LAS/LAZ (laspy), E57 (pye57) and images (Pillow), plus small reference meshes.

Written independently of the readers (struct / plain text / the libraries), so a round trip compares
two implementations rather than one with itself.
"""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np


def cube_mesh(size: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned cube (8 vertices, 12 outward counter-clockwise triangles), corner at the origin."""
    v = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=np.float64) * size
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], dtype=np.int64)
    return v, f


def sphere_mesh(n_lat: int = 12, n_lon: int = 24, radius: float = 25.0) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere: poles and rings, triangles fanning to the poles and two per quad between rings."""
    theta = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring = np.column_stack((np.sin(t).ravel() * np.cos(p).ravel(), np.sin(t).ravel() * np.sin(p).ravel(),
                            np.cos(t).ravel()))
    v = np.vstack(([0, 0, 1], ring, [0, 0, -1])) * radius
    south = v.shape[0] - 1
    faces = []
    for j in range(n_lon):
        faces.append([0, 1 + j, 1 + (j + 1) % n_lon])
        last = 1 + (n_lat - 2) * n_lon
        faces.append([south, last + (j + 1) % n_lon, last + j])
    for i in range(n_lat - 2):
        for j in range(n_lon):
            a, b = 1 + i * n_lon + j, 1 + i * n_lon + (j + 1) % n_lon
            c, d = a + n_lon, b + n_lon
            faces += [[a, c, b], [b, c, d]]
    return v, np.array(faces, dtype=np.int64)


def stl_binary(vertices, faces, header: bytes = b"binary stl written by the tests") -> bytes:
    v = np.asarray(vertices, dtype=np.float32)
    f = np.asarray(faces)
    out = io.BytesIO()
    out.write(header[:80].ljust(80, b" "))
    out.write(struct.pack("<I", len(f)))
    for tri in f:
        a, b, c = v[tri]
        n = np.cross(b - a, c - a)
        n = n / (np.linalg.norm(n) or 1.0)
        out.write(struct.pack("<12fH", *n, *a, *b, *c, 0))
    return out.getvalue()


def stl_ascii(vertices, faces, name: str = "part", fmt: str = "{:.9g}") -> bytes:
    v = np.asarray(vertices, dtype=np.float64)
    lines = [f"solid {name}"]
    for tri in np.asarray(faces):
        a, b, c = v[tri]
        n = np.cross(b - a, c - a)
        n = n / (np.linalg.norm(n) or 1.0)
        lines.append("  facet normal " + " ".join(fmt.format(float(x)) for x in n))
        lines.append("    outer loop")
        for p in (a, b, c):
            lines.append("      vertex " + " ".join(fmt.format(float(x)) for x in p))
        lines.append("    endloop")
        lines.append("  endfacet")
    lines.append(f"endsolid {name}")
    return ("\n".join(lines) + "\n").encode()


def obj_text(vertices, polygons, *, style: str = "plain", negative: bool = False) -> bytes:
    """OBJ text; ``style`` 'plain' (f 1 2 3), 'vt' (f 1/1 ...), 'vn' (f 1//1 ...) or 'vtvn' (f 1/1/1)."""
    v = np.asarray(vertices, dtype=np.float64)
    lines = ["# written by the tests", "o part"]
    lines += [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in v]
    lines += ["vt 0 0", "vn 0 0 1"]
    n = len(v)
    for poly in polygons:
        refs = []
        for i in poly:
            k = (int(i) - n) if negative else int(i) + 1
            refs.append({"plain": f"{k}", "vt": f"{k}/1", "vn": f"{k}//1", "vtvn": f"{k}/1/1"}[style])
        lines.append("f " + " ".join(refs))
    return ("\n".join(lines) + "\n").encode()


def ply_mesh(vertices, polygons, *, binary: bool = True, byte_order: str = "<", index_type: str = "i4",
             count_type: str = "u1", list_name: str = "vertex_indices", face_extra: bool = False) -> bytes:
    """A PLY with a vertex element (double x y z) and a face element of polygons (plyfile writes it)."""
    import plyfile

    v = np.asarray(vertices, dtype=np.float64)
    vt = np.empty(len(v), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    vt["x"], vt["y"], vt["z"] = v.T
    dtype = [(list_name, "O")] + ([("flags", "u1")] if face_extra else [])
    ft = np.empty(len(polygons), dtype=dtype)
    ft[list_name] = [np.asarray(p, dtype=index_type) for p in polygons] if len(polygons) else []
    if face_extra:
        ft["flags"] = 7
    face = plyfile.PlyElement.describe(ft, "face", len_types={list_name: count_type},
                                       val_types={list_name: index_type})
    data = plyfile.PlyData([plyfile.PlyElement.describe(vt, "vertex"), face], text=not binary,
                           byte_order=byte_order)
    buf = io.BytesIO()
    data.write(buf)
    return buf.getvalue()


def las_bytes(points, *, compress: bool = False, extra_bytes: int = 0, scale: float = 0.001) -> bytes:
    """A LAS 1.2 point format 3 file (34-byte records, plus ``extra_bytes`` zero extra bytes each)."""
    import laspy

    pts = np.asarray(points, dtype=np.float64)
    header = laspy.LasHeader(point_format=3, version="1.2")
    if extra_bytes:
        n8, rest = divmod(extra_bytes, 8)
        dims = [laspy.ExtraBytesParams(name=f"pad{i}", type="f8") for i in range(n8)]
        dims += [laspy.ExtraBytesParams(name=f"rest{i}", type="u1") for i in range(rest)]
        header.add_extra_dims(dims)
    header.scales = np.array([scale] * 3)
    header.offsets = np.floor(pts.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    buf = io.BytesIO()
    las.write(buf, do_compress=compress)
    return buf.getvalue()


def write_e57(path: Path, scans) -> Path:
    """Write scans, each a dict: ``points`` (N,3), optional ``rotation`` (w x y z), ``translation``,
    ``row`` / ``column`` (grid indices) and ``invalid`` (cartesianInvalidState)."""
    import pye57

    with pye57.E57(str(path), mode="w") as e57:
        for scan in scans:
            p = np.asarray(scan["points"], dtype=np.float64)
            data = {"cartesianX": p[:, 0].copy(), "cartesianY": p[:, 1].copy(), "cartesianZ": p[:, 2].copy()}
            if "row" in scan:
                data["rowIndex"] = np.asarray(scan["row"], dtype=np.uint16)
                data["columnIndex"] = np.asarray(scan["column"], dtype=np.uint16)
            if "invalid" in scan:
                data["cartesianInvalidState"] = np.asarray(scan["invalid"], dtype=np.int8)
            e57.write_scan_raw(data, rotation=np.asarray(scan.get("rotation", [1.0, 0, 0, 0]), dtype=float),
                               translation=np.asarray(scan.get("translation", [0.0, 0, 0]), dtype=float))
    return Path(path)


def image_bytes(array, fmt: str = "PNG", mode: str | None = None) -> bytes:
    """Encode an ``(H, W)`` or ``(H, W, 3)`` uint8/uint16 array with Pillow."""
    from PIL import Image

    img = Image.fromarray(np.asarray(array), mode=mode) if mode else Image.fromarray(np.asarray(array))
    buf = io.BytesIO()
    img.save(buf, format=fmt)
    return buf.getvalue()


def canonical_triangles(points, faces) -> set:
    """Triangles as sets of vertex coordinates (rotation of a triangle's corners ignored, winding kept):
    a mesh compared with another up to the order of its vertices and faces."""
    p = np.asarray(points)
    out = set()
    for tri in np.asarray(faces):
        corners = [tuple(float(x) for x in p[i]) for i in tri]
        k = corners.index(min(corners))
        out.add(tuple(corners[k:] + corners[:k]))
    return out
