"""Hostile and damaged input files for the reader tests (tests/test_reader_limits.py,
tests/test_reader_fuzz.py), and :func:`read_in_child`, which reads files in a separate Python process
under an address-space limit and reports, per file, what the reader answered.

- small files whose headers claim far more than they hold (:func:`ply_claiming_faces`,
  :func:`ply_list_count`, :func:`laz_claiming_points`, :func:`obj_copies_of_one_triangle`);
- :func:`corpus`: a deterministic (seeded) corpus of mutated small valid files of every format read:
  truncations, bit flips, header counts inflated (x1000, 2**31, 2**63-1), list counts inflated,
  negative and huge numbers.

The files are written here with struct / plain text / plyfile / laspy / pye57, independently of the
readers.
"""

from __future__ import annotations

import io
import json
import os
import re
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from mesh_files import las_bytes  # one LAS writer for every test (tests/ is on sys.path)

ROOT = Path(__file__).resolve().parents[1]

#: the address space a child may grow by over its size once the readers are imported
AS_HEADROOM = 1536 << 20
#: the most resident memory a child may reach
RSS_LIMIT = 1536 << 20

HUGE_COUNTS = (1000, 2 ** 31, 2 ** 63 - 1)      # x1000 (a factor), then absolute values


# --------------------------------------------------------------------------------------------- PLY

TRIANGLE = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], dtype=np.float64)


def ply_binary_faces(vertices: np.ndarray, face_records: bytes, *, declared_faces: int,
                     count_type: str = "uchar", pad_to: int | None = None) -> bytes:
    """A binary little-endian PLY: ``vertices`` (float x y z) and the face records as given, its header
    declaring ``declared_faces`` faces (``count_type`` the list count type); a comment pads the file to
    ``pad_to`` bytes."""
    def header(comment: str) -> bytes:
        return ("ply\nformat binary_little_endian 1.0\n" + comment +
                f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
                f"element face {declared_faces}\nproperty list {count_type} int vertex_indices\n"
                "end_header\n").encode()

    body = np.asarray(vertices, dtype="<f4").tobytes() + face_records
    out = header("") + body
    if pad_to is not None and len(out) < pad_to:
        out = header("comment " + "x" * max(pad_to - len(out) - 9, 0) + "\n") + body
    return out


def ply_claiming_faces(declared: int, pad_to: int | None = None) -> bytes:
    """Three vertices and one triangle, the header claiming ``declared`` faces."""
    return ply_binary_faces(TRIANGLE, struct.pack("<B3i", 3, 0, 1, 2), declared_faces=declared, pad_to=pad_to)


def ply_list_count(count: int = 0xFFFFFFFF) -> bytes:
    """Three vertices and one face whose uint list count is ``count`` (the file holds three indices)."""
    return ply_binary_faces(TRIANGLE, struct.pack("<I3i", count, 0, 1, 2), declared_faces=1, count_type="uint")


def ply_mesh_ascii(vertices, faces) -> bytes:
    v, f = np.asarray(vertices), np.asarray(faces)
    lines = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y",
             "property float z", f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    lines += [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in v]
    lines += [f"{len(t)} " + " ".join(str(int(i)) for i in t) for t in f]
    return ("\n".join(lines) + "\n").encode()


def ply_mesh_binary(vertices, polygons) -> bytes:
    """Binary PLY of polygons of any sizes (uchar counts, int indices: records walked when they differ)."""
    body = np.asarray(vertices, dtype="<f4").tobytes()
    body += b"".join(struct.pack(f"<B{len(p)}i", len(p), *map(int, p)) for p in polygons)
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\nproperty float x\n"
              f"property float y\nproperty float z\nelement face {len(polygons)}\n"
              "property list uchar int vertex_indices\nend_header\n").encode()
    return header + body


# --------------------------------------------------------------------------------------------- LAS



def las_with_count(data: bytes, count: int) -> bytes:
    """The LAS/LAZ bytes with the header's (legacy 32-bit) point count replaced."""
    out = bytearray(data)
    struct.pack_into("<I", out, 107, count & 0xFFFFFFFF)
    return bytes(out)


def laz_claiming_points(count: int = 19_000_000) -> bytes:
    """A real small LAZ of 400 points with 158-byte records (point format 3 and 124 extra bytes), its
    header then claiming ``count`` points (count x record length: 3 GB for 19 M)."""
    pts = np.random.default_rng(7).uniform([0, 0, 0], [80, 60, 40], (400, 3))
    return las_with_count(las_bytes(pts, compress=True, extra_bytes=124), count)


# --------------------------------------------------------------------------------------------- OBJ

def obj_copies_of_one_triangle(copies: int) -> bytes:
    """Three vertices and ``copies`` identical ``f 1 2 3`` lines."""
    return b"v 0 0 0\nv 10 0 0\nv 0 10 0\n" + b"f 1 2 3\n" * copies


# --------------------------------------------------------------------------------------------- E57

_CRC32C = []
for _n in range(256):
    _c = _n
    for _ in range(8):
        _c = (_c >> 1) ^ (0x82F63B78 if _c & 1 else 0)
    _CRC32C.append(_c)


def _crc32c(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for b in data:
        crc = (crc >> 8) ^ _CRC32C[(crc ^ b) & 0xFF]
    return crc ^ 0xFFFFFFFF


def e57_resign(data: bytes) -> bytes:
    """The E57 bytes with the CRC-32C of every 1024-byte page written again (big-endian, last 4 bytes)."""
    out = bytearray(data)
    for start in range(0, len(out) - 1023, 1024):
        struct.pack_into(">I", out, start + 1020, _crc32c(bytes(out[start:start + 1020])))
    return bytes(out)


def e57_edit_xml(data: bytes, old: bytes, new: bytes) -> bytes | None:
    """Replace the first ``old`` of the E57 file's XML by ``new``, keeping the XML's length (indentation
    blanks taken out or put in), the pages re-signed; None if ``old`` is not there."""
    xml_offset, xml_length = struct.unpack_from("<QQ", data, 24)
    spans, pos, left = [], xml_offset, xml_length          # (physical start, length) of the XML's pieces
    while left > 0:
        take = min(1020 - pos % 1024, left)
        spans.append((pos, take))
        left -= take
        pos = (pos // 1024 + 1) * 1024
    xml = b"".join(data[p:p + n] for p, n in spans)
    if old not in xml:
        return None
    xml = xml.replace(old, new, 1)
    grow = len(xml) - xml_length
    if grow > 0:                                           # take blanks out of the indentation
        xml = re.sub(rb"\n {2,}", lambda m: b"\n" + m.group(0)[1:][:-1], xml, count=grow)
    elif grow < 0:
        xml = xml.replace(b"\n  ", b"\n" + b" " * (2 - grow), 1)
    if len(xml) != xml_length:
        return None
    out, at = bytearray(data), 0
    for p, n in spans:
        out[p:p + n] = xml[at:at + n]
        at += n
    return e57_resign(bytes(out))


def e57_grid_bytes() -> bytes:
    """A structured E57 scan (6 x 8 grid) written by pye57."""
    import pye57

    r, c = np.divmod(np.arange(48), 8)
    pts = np.column_stack((c * 2.0, r * 2.0, 1.0 + np.sin(c)))
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "scan.e57")
        with pye57.E57(path, mode="w") as e57:
            e57.write_scan_raw({"cartesianX": pts[:, 0].copy(), "cartesianY": pts[:, 1].copy(),
                                "cartesianZ": pts[:, 2].copy(), "rowIndex": r.astype(np.uint16),
                                "columnIndex": c.astype(np.uint16)},
                               rotation=np.array([1.0, 0, 0, 0]), translation=np.zeros(3))
        return Path(path).read_bytes()


# ------------------------------------------------------------------------------------ the corpus

def _sphere(n_lat: int = 5, n_lon: int = 8, radius: float = 20.0):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from mesh_files import sphere_mesh

    return sphere_mesh(n_lat, n_lon, radius)


def base_files() -> dict[str, bytes]:
    """Small valid files of every format read, by file name (the extension selects the reader)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from mesh_files import obj_text, stl_ascii, stl_binary

    rng = np.random.default_rng(2024)
    pts = rng.uniform([0, 0, 0], [40, 30, 20], (120, 3))
    v, f = _sphere()
    polygons = [list(t) for t in f[:-2]] + [[int(f[-2][0]), int(f[-2][1]), int(f[-2][2]), int(f[-1][2])]]
    n = len(pts)
    pcd_head = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
                f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ")
    cloud_ply = ("ply\nformat binary_little_endian 1.0\n"
                 f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
                 "property float nx\nproperty float ny\nproperty float nz\nend_header\n").encode()
    normals = pts - pts.mean(axis=0)
    return {
        "mesh_ascii.ply": ply_mesh_ascii(v, f),
        "mesh_binary.ply": ply_mesh_binary(v, polygons),
        "cloud_binary.ply": cloud_ply + np.hstack((pts, normals)).astype("<f4").tobytes(),
        "cloud_ascii.pcd": (pcd_head + "ascii\n").encode() + "".join(
            f"{x:.5f} {y:.5f} {z:.5f}\n" for x, y, z in pts).encode(),
        "cloud_binary.pcd": (pcd_head + "binary\n").encode() + pts.astype("<f4").tobytes(),
        "cloud.xyz": ("# x y z\n" + "".join(f"{x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in pts)).encode(),
        "mesh_ascii.stl": stl_ascii(v, f),
        "mesh_binary.stl": stl_binary(v, f),
        "mesh.obj": obj_text(v, f, style="vtvn"),
        "cloud.las": las_bytes(pts),
        "cloud.laz": las_bytes(pts, compress=True),
        "grid.e57": e57_grid_bytes(),
    }


def _replace_number(data: bytes, pattern: bytes, values, group: int = 1) -> list[tuple[str, bytes]]:
    """Copies of ``data`` with the number matched by group ``group`` of ``pattern`` (first match) set to
    each of ``values`` (ints; 1000 multiplies)."""
    m = re.search(pattern, data, re.MULTILINE)
    if m is None:
        return []
    out = []
    for v in values:
        number = int(m.group(group)) * 1000 if v == 1000 else v
        out.append((f"{number}", data[:m.start(group)] + str(number).encode() + data[m.end(group):]))
    return out


def _packed(data: bytes, offset: int, fmt: str, values) -> list[tuple[str, bytes]]:
    out = []
    (old,) = struct.unpack_from(fmt, data, offset)
    limit = 256 ** struct.calcsize(fmt) - 1
    for v in values:
        number = min(old * 1000 if v == 1000 else v, limit)
        b = bytearray(data)
        struct.pack_into(fmt, b, offset, number)
        out.append((f"{number}", bytes(b)))
    return out


def _specific(name: str, data: bytes) -> list[tuple[str, bytes]]:
    """Mutations that know the format: counts inflated, list counts inflated, negative and huge numbers."""
    out: list[tuple[str, bytes]] = []
    counts = (*HUGE_COUNTS, -1)

    def add(label, items):
        out.extend((f"{label}-{k}", b) for k, b in items)

    if name.endswith(".ply"):
        add("vertex_count", _replace_number(data, rb"^element vertex (-?\d+)", counts))
        add("face_count", _replace_number(data, rb"^element face (-?\d+)", counts))
        if name == "mesh_binary.ply":
            start = data.index(b"end_header\n") + 11 + 12 * int(re.search(rb"element vertex (\d+)", data).group(1))
            add("list_count", _packed(data, start, "<B", (255,)))
            add("index", _packed(data, start + 1, "<i", (2 ** 31 - 1,)))
        if name == "mesh_ascii.ply":
            add("list_count", _replace_number(data, rb"^(\d+) \d+ \d+ \d+$", (2 ** 32 - 1, 2 ** 63 - 1, -1)))
            for bad in (b"1e30", b"nan", b"-99999999999999999999"):
                out.append((f"list_count-{bad.decode()}", re.sub(rb"(?m)^3 (?=\d+ \d+ \d+$)", bad + b" ", data,
                                                                  count=1)))
            add("index", _replace_number(data, rb"^3 \d+ (\d+) \d+$", (2 ** 63 - 1, 10 ** 30)))
        if name == "cloud_binary.ply":
            add("coordinate", [("inf", data[:-4] + struct.pack("<f", float("inf")))])
    elif name.endswith(".pcd"):
        add("points", _replace_number(data, rb"^POINTS (-?\d+)", counts))
        add("width", _replace_number(data, rb"^WIDTH (-?\d+)", counts))
        add("count", _replace_number(data, rb"^COUNT (\d+)", (2 ** 31, 2 ** 63 - 1)))
        add("size", _replace_number(data, rb"^SIZE (\d+)", (2 ** 31,)))
        if b"DATA ascii" in data:
            for bad in (b"1e400", b"-99999999999999999999"):
                out.append((f"number-{bad.decode()}", re.sub(rb"(?m)^[-\d.]+ ", bad + b" ", data, count=1)))
        if b"HEIGHT 1\n" in data:
            no_points = re.sub(rb"(?m)^POINTS.*\n", b"", data)
            out.append(("width_height_negative", no_points.replace(b"WIDTH ", b"WIDTH -").replace(b"HEIGHT 1",
                                                                                                  b"HEIGHT -4")))
    elif name.endswith(".xyz"):
        for bad in (b"1e400", b"-99999999999999999999", b"nan", b"0x10"):
            out.append((f"number-{bad.decode()}", re.sub(rb"(?m)^[-\d.]+ ", bad + b" ", data, count=1)))
    elif name.endswith(".stl"):
        if data[:5] != b"solid":
            add("triangle_count", _packed(data, 80, "<I", (1000, 2 ** 31, 2 ** 32 - 1)))
        else:
            for bad in (b"1e400", b"-1e308"):
                out.append((f"number-{bad.decode()}", re.sub(rb"vertex [-\d.e+]+", b"vertex " + bad, data, count=1)))
            out.append(("endsolid-missing", data.replace(b"endsolid", b"", 1)))
    elif name.endswith(".obj"):
        for bad in (b"99999999999999999999", b"-2147483649", b"0", b"9223372036854775807", b"1.5", b"1e30"):
            out.append((f"face_ref-{bad.decode()}", re.sub(rb"(?m)^f (\d+)", b"f " + bad, data, count=1)))
        out.append(("coordinate-1e400", re.sub(rb"(?m)^v [-\d.e+]+", b"v 1e400", data, count=1)))
        out.append(("polygon-100000", data + b"f " + b" ".join(b"1 2 3" for _ in range(33334)) + b"\n"))
    elif name.endswith((".las", ".laz")):
        add("point_count", _packed(data, 107, "<I", (1000, 2 ** 31, 2 ** 32 - 1)))
        add("record_length", _packed(data, 105, "<H", (2 ** 16 - 1,)))
        add("point_offset", _packed(data, 96, "<I", (2 ** 31,)))
        add("vlr_count", _packed(data, 100, "<I", (2 ** 32 - 1,)))
        add("scale", [("1e300", data[:131] + struct.pack("<d", 1e300) + data[139:])])
        if name.endswith(".laz"):                   # the LASzip items disagree with the record: lazrs panics
            items = data.index(b"laszip encoded") - 2 + 54 + 34
            add("laszip_item_size", _packed(data, items + 6 + 2, "<H", (0,)))
            add("record_length_with_items", _packed(data, 105, "<H", (34 + 256,)))
    elif name.endswith(".e57"):
        m = re.search(rb'recordCount="(\d+)"', data)
        n = int(m.group(1)) if m else 48
        for v in HUGE_COUNTS:
            number = n * 1000 if v == 1000 else v
            edited = e57_edit_xml(data, f'recordCount="{n}"'.encode(), f'recordCount="{number}"'.encode())
            if edited is not None:
                out.append((f"record_count-{number}", edited))
        edited = e57_edit_xml(data, b'<rowIndex type="Integer" minimum="0" maximum="5"/>',
                              b'<rowIndex type="Integer" minimum="0" maximum="9223372036854775807"/>')
        if edited is not None:
            out.append(("row_maximum-huge", edited))
        add("physical_length", _packed(data, 16, "<Q", (2 ** 63 - 1,)))
    return out


def _generic(data: bytes, rng: np.random.Generator, n_flips: int) -> list[tuple[str, bytes]]:
    """Truncations (half, 90 %, the last byte, at a random point) and ``n_flips`` files of random bit flips."""
    out = [("cut-half", data[: len(data) // 2]), ("cut-90", data[: len(data) * 9 // 10]), ("cut-last", data[:-1]),
           (f"cut-{(k := int(rng.integers(1, len(data))))}", data[:k])]
    for i in range(n_flips):
        b = np.frombuffer(data, dtype=np.uint8).copy()
        k = int(rng.choice((1, 4, 32)))
        at = rng.integers(0, b.size, k)
        b[at] ^= (1 << rng.integers(0, 8, k)).astype(np.uint8)
        out.append((f"flip{i}-{k}", b.tobytes()))
    return out


def corpus(seed: int = 0, n_flips: int = 2) -> list[tuple[str, bytes]]:
    """The mutated files, ``(file name, bytes)``: every base file, its format-specific mutations, the
    truncations and ``n_flips`` bit-flipped copies (seeded: the same corpus every run)."""
    out = []
    for index, (name, data) in enumerate(base_files().items()):
        rng = np.random.default_rng([seed, index])
        stem, ext = name.rsplit(".", 1)
        items = [("valid", data), *_specific(name, data), *_generic(data, rng, n_flips)]
        out += [(f"{stem}__{re.sub(r'[^A-Za-z0-9_.-]', '_', label)}.{ext}", blob) for label, blob in items]
    return out


# ---------------------------------------------------------------------------------- the child reader

_CHILD = r"""
import contextlib, io, json, os, resource, sys, tempfile, warnings
sys.path.insert(0, os.environ["SCANMILL_ROOT"])
job = json.loads(sys.stdin.read())
from planning.errors import PlanningError
from planning.inputs.cloud import read_cloud
import planning.inputs.e57, planning.inputs.las, planning.inputs.ply_lists, laspy, pye57, plyfile  # noqa
if job.get("plan"):
    from scanmill.cli import main
    import planning.pipeline  # noqa

def vm_size():
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0

limit = vm_size() + int(job["headroom"])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
try:                                        # the limit holds: more than the headroom cannot be had
    probe = bytearray(int(job["headroom"]) + (256 << 20))
    limit_enforced = False
    del probe
except MemoryError:
    limit_enforced = True
results = []
for item in job["files"]:
    caught = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            cloud = read_cloud(item["path"], **item["kwargs"])
        result = {"ok": True, "n_points": cloud.n_points, "n_faces": cloud.n_faces,
                  "format": cloud.source_format, "warnings": list(cloud.warnings)}
    except PlanningError as exc:
        result = {"ok": False, "error": type(exc).__name__, "code": exc.code, "status": exc.status,
                  "message": exc.message, "details": {k: v for k, v in exc.details.items()
                                                      if isinstance(v, (int, float, str))}}
    except BaseException as exc:
        result = {"ok": False, "error": type(exc).__name__, "code": None, "message": str(exc)[:300]}
    result["python_warnings"] = [str(w.message)[:200] for w in caught]
    result["path"] = item["path"]
    results.append(result)
    if job.get("plan"):
        out_dir = os.path.join(tempfile.mkdtemp(prefix="scanmill-fuzz-"), "plan")
        err = io.StringIO()
        try:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err), \
                    warnings.catch_warnings(record=True) as plan_warnings:
                warnings.simplefilter("always")
                status = main(["plan", item["path"], "--out", out_dir, "--quiet", *job["plan"]])
            result["cli"] = {"status": status, "stderr": err.getvalue(), "out_exists": os.path.exists(out_dir),
                             "python_warnings": [str(w.message)[:200] for w in plan_warnings]}
        except BaseException as exc:
            result["cli"] = {"status": None, "exception": type(exc).__name__, "message": str(exc)[:300],
                             "stderr": err.getvalue()}
    result["max_rss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"results": results, "limit": limit, "limit_enforced": limit_enforced,
                  "max_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}))
"""


def read_in_child(files, *, headroom: int = AS_HEADROOM, plan_args: list[str] | None = None) -> dict:
    """Read ``files`` (paths, or ``(path, read_cloud keyword arguments)`` pairs) with ``read_cloud`` in one
    child Python process whose address space (RLIMIT_AS) is its size once the readers are imported plus
    ``headroom``; with ``plan_args``, also plan each through the CLI's own ``scanmill.cli.main(["plan",
    FILE, "--out", DIR, "--quiet", *plan_args])`` in that process.

    Returns the child's report: ``results`` (per file: ``ok`` and the counts and ``warnings``, or ``error``
    (the exception class), ``code``, ``status`` and ``message``; ``python_warnings`` raised while reading;
    ``cli`` (``status``, ``stderr``, ``out_exists``) when planned; ``max_rss``, the child's peak resident
    bytes so far), ``limit``, ``limit_enforced`` (a buffer of the headroom and 256 MiB more failed there),
    ``max_rss``, and the child's ``returncode`` and ``stderr``.
    """
    items = []
    for f in files:
        path, kw = (f if isinstance(f, tuple) else (f, {}))
        items.append({"path": str(path), "kwargs": kw})
    env = {**os.environ, "SCANMILL_ROOT": str(ROOT), "MALLOC_ARENA_MAX": "2", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "PYTHONWARNINGS": "default"}
    proc = subprocess.run([sys.executable, "-c", _CHILD], input=json.dumps(
        {"files": items, "headroom": headroom, "plan": plan_args}), capture_output=True, text=True,
        env=env, cwd=str(ROOT), check=False)
    report = {"returncode": proc.returncode, "stderr": proc.stderr, "results": []}
    if proc.returncode == 0 and proc.stdout.strip():
        report.update(json.loads(proc.stdout.strip().splitlines()[-1]))
    return report
