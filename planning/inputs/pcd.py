"""Stage 1, the cloud: the PCD reader (Point Cloud Library format: ascii, binary, binary_compressed).

The header (``FIELDS``, ``SIZE``, ``TYPE``, ``COUNT``, ``POINTS`` or ``WIDTH`` x ``HEIGHT``,
``DATA``) gives a structured dtype per point; ``x y z`` are required, ``normal_x normal_y normal_z``
are read as file normals. Binary bodies are a ``numpy.frombuffer`` view; ascii bodies are parsed in
one ``numpy.fromstring`` call (:mod:`planning.inputs.rows`); ``binary_compressed`` (LZF) is decoded
by Open3D. The declared sizes are checked before anything is allocated for them: ``POINTS`` (or
``WIDTH x HEIGHT``, both non-negative) against ``max_points``, the point size (the sum of ``SIZE x
COUNT``; ascii: two characters a value) against the body, ``POINTS x`` point size against the body
of a binary file, and the compressed and uncompressed sizes at the start of a ``binary_compressed``
body (the compressed data must fit in the file, the uncompressed size must be ``POINTS x`` point
size) before Open3D reads it, its console warnings silenced. Errors: ``unreadable_file``,
``truncated_file`` (also a declared size the file cannot hold), ``empty_cloud``, ``unsupported_format``
(unknown ``DATA`` kind) and ``too_many_points`` (declared count, checked before the body is read).
"""

from __future__ import annotations

import os
import struct
import tempfile

import numpy as np

from planning.errors import InputError
from planning.inputs.rows import _line_block, _normals_from, _parse_numbers, _xyz
from planning.inputs.source import _check_count, _Source

_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4",
              ("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}
_PCD_NORMALS = ("normal_x", "normal_y", "normal_z")


def _pcd_error(msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Invalid PCD file: {msg}", code=code)


def _read_pcd(src: _Source, max_points: int):
    header, body_start = _parse_pcd_header(src.head)
    dtype, n_points, data_kind = _pcd_layout(header, max(src.size - body_start, 0))
    _check_count(n_points, max_points)
    if n_points == 0:
        raise InputError("The PCD file declares 0 points; the cloud is empty.", code="empty_cloud")
    data = src.data()
    if data_kind == "binary":
        table = _pcd_binary(data, body_start, dtype, n_points)
    elif data_kind == "ascii":
        table = _pcd_ascii(data, body_start, dtype, n_points)
    else:
        _check_compressed_sizes(data, body_start, dtype.itemsize, n_points)
        return (*_pcd_compressed_open3d(data, n_points), "pcd-binary_compressed")
    return _xyz(table), _normals_from(table, _PCD_NORMALS), f"pcd-{data_kind}"


def _parse_pcd_header(head: bytes):
    """Parse a PCD header into {KEY: [words]} and the byte offset of the body."""
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        nl = head.find(b"\n", pos)
        if nl < 0:
            raise _pcd_error("no DATA line in the first MiB; the header is damaged.")
        raw, pos = head[pos:nl], nl + 1
        try:
            words = raw.decode("ascii").split()
        except UnicodeDecodeError:
            raise _pcd_error("the header contains non-ASCII bytes; the file is damaged.") from None
        if not words or words[0].startswith("#"):
            continue
        header[words[0].upper()] = words[1:]
        if words[0].upper() == "DATA":
            return header, pos


def _pcd_layout(header, body_bytes: int):
    """Structured dtype of one point, the point count and the DATA kind (``body_bytes``: the bytes after
    the header, which one point must fit in)."""
    fields = header.get("FIELDS")
    sizes, types = header.get("SIZE"), header.get("TYPE")
    if not fields or not sizes or not types:
        raise _pcd_error("the header needs FIELDS, SIZE and TYPE lines.")
    counts = header.get("COUNT", ["1"] * len(fields))
    if not len(fields) == len(sizes) == len(types) == len(counts):
        raise _pcd_error("FIELDS, SIZE, TYPE and COUNT list different numbers of entries.")
    for f, c in zip(fields, counts):
        if not c.isdigit():
            raise _pcd_error(f"COUNT {c} for field {f!r} is not a whole number; COUNT gives how many values each "
                             "field holds per point (1 for x, y, z and most fields). Fix the COUNT line.")
        if int(c) < 1 or (f in ("x", "y", "z", *_PCD_NORMALS) and int(c) != 1):
            raise _pcd_error(f"COUNT {int(c)} for field {f!r}: {f} holds one value per point, so its COUNT must "
                             "be 1 (COUNT gives how many values each field holds per point). Fix the COUNT line.")
    try:
        spec = [(_pcd_field_name(f, i), _PCD_TYPES[(t.upper(), int(s))], int(c))
                for i, (f, s, t, c) in enumerate(zip(fields, sizes, types, counts))]
    except (KeyError, ValueError):
        raise _pcd_error(f"unknown SIZE/TYPE combination {sizes} {types} (SIZE 1, 2, 4 or 8 bytes; TYPE F, I "
                         "or U; F needs SIZE 4 or 8).") from None
    point_bytes = sum(int(np.dtype(t).itemsize) * c for _, t, c in spec)
    n_values = sum(c for _, _, c in spec)
    kind = (header.get("DATA") or [""])[0].lower()
    # one point must fit in the body (ascii: a value takes a character and a separator), checked before
    # numpy sizes a record from COUNT
    if (point_bytes > body_bytes if kind == "binary" else
            2 * n_values - 1 > body_bytes if kind == "ascii" else point_bytes >= 2 ** 31):
        what = (f"each point takes {point_bytes:,} bytes" if kind != "ascii" else
                f"each point holds {n_values:,} values")
        raise _pcd_error(f"by its FIELDS, SIZE and COUNT lines {what} (COUNT {' '.join(counts)}), more than the "
                         f"whole body of the file ({body_bytes:,} bytes) can hold: the COUNT or SIZE line is "
                         "wrong (COUNT gives how many values each field holds per point, usually 1), or the file "
                         "was cut off. Fix the header or send the complete file.", code="truncated_file")
    names = [s[0] for s in spec]
    if not {"x", "y", "z"} <= set(names) or len(set(names)) != len(names):
        raise _pcd_error("FIELDS must contain x, y and z exactly once.")
    dtype = np.dtype([(n, "<" + t, (c,)) if c != 1 else (n, "<" + t) for n, t, c in spec])
    if kind not in ("ascii", "binary", "binary_compressed"):
        raise _pcd_error(f"unknown DATA kind {kind!r} (expected ascii, binary or "
                         "binary_compressed).", code="unsupported_format")
    return dtype, _pcd_point_count(header), kind


def _pcd_field_name(name: str, index: int) -> str:
    return f"_pad{index}" if name == "_" else name


def _pcd_point_count(header) -> int:
    try:
        if "POINTS" in header:
            n = int(header["POINTS"][0])
        else:
            width, height = int(header["WIDTH"][0]), int(header.get("HEIGHT", ["1"])[0])
            if width < 0 or height < 0:
                raise _pcd_error(f"negative WIDTH or HEIGHT ({width} x {height}).")
            n = width * height
    except (KeyError, IndexError, ValueError):
        raise _pcd_error("the header needs a valid POINTS (or WIDTH and HEIGHT) line.") from None
    if n < 0:
        raise _pcd_error(f"negative point count {n}.")
    return n


def _check_compressed_sizes(data: bytes, offset: int, point_bytes: int, n: int) -> None:
    """A binary_compressed body starts with its compressed and uncompressed sizes (uint32): the
    compressed data must fit in the file and decompress to ``n`` points, before Open3D sizes its
    buffers from them."""
    if len(data) < offset + 8:
        raise _pcd_error("the binary_compressed body is missing its sizes; the file was cut off.",
                         code="truncated_file")
    compressed, uncompressed = struct.unpack_from("<II", data, offset)
    if uncompressed != n * point_bytes:
        raise _pcd_error(f"the compressed body says it holds {uncompressed:,} bytes, but {n:,} points of "
                         f"{point_bytes:,} bytes take {n * point_bytes:,}; the file is damaged.")
    if compressed > len(data) - offset - 8:
        raise _pcd_error(f"the compressed body declares {compressed:,} bytes but the file holds "
                         f"{len(data) - offset - 8:,} after the header; the file was cut off. Send the "
                         "complete file.", code="truncated_file")


def _pcd_binary(data: bytes, offset: int, dtype: np.dtype, n: int) -> np.ndarray:
    needed = n * dtype.itemsize
    available = max(len(data) - offset, 0)
    if available < needed:
        if dtype.itemsize > available:         # not even one point: the header, not the body, is wrong
            raise _pcd_error(f"by its FIELDS, SIZE and COUNT lines each point takes {dtype.itemsize:,} bytes "
                             f"(COUNT {' '.join(str(_count(dtype, k)) for k in dtype.names)}), more than the whole "
                             f"body of the file ({available:,} bytes) for {n:,} points: the COUNT or SIZE line is "
                             "wrong (COUNT gives how many values each field holds per point, usually 1), or the "
                             "file was cut off. Fix the header or send the complete file.", code="truncated_file")
        raise _pcd_error(f"the header declares {n:,} points of {dtype.itemsize:,} bytes each ({needed:,} bytes) "
                         f"but the file holds only {available // dtype.itemsize:,} complete ones; the file was cut "
                         "off. Send the complete file.", code="truncated_file")
    return np.frombuffer(data, dtype=dtype, count=n, offset=offset)


def _count(dtype: np.dtype, name: str) -> int:
    return int(np.prod(dtype[name].shape, dtype=np.int64)) if dtype[name].shape else 1


def _pcd_ascii(data: bytes, offset: int, dtype: np.dtype, n: int) -> np.ndarray:
    n_cols = sum(int(np.prod(dtype[name].shape, dtype=int)) for name in dtype.names)
    block, n_rows = _line_block(data, offset, 0, n)
    if n_rows < n:
        raise _pcd_error(f"the header declares {n:,} points but the file has only {n_rows:,} "
                         "data lines; the file is incomplete.", code="truncated_file")
    values = _parse_numbers(block, n_cols, n, what="PCD point data")
    columns, col = {}, 0
    for name in dtype.names:
        width = int(np.prod(dtype[name].shape, dtype=int))
        columns[name] = values[:, col]
        col += width
    table = np.empty(n, dtype=[(k, "f8") for k in columns])
    for k, v in columns.items():
        table[k] = v
    return table


def _pcd_compressed_open3d(data: bytes, n_points: int):
    """Decode a binary_compressed PCD with Open3D (LZF); returns (points, normals or None)."""
    try:
        import open3d as o3d
    except ImportError:  # pragma: no cover - open3d is a dependency
        raise _pcd_error("binary_compressed PCD needs Open3D; save the cloud as binary PCD.",
                         code="unsupported_format") from None
    with tempfile.TemporaryDirectory() as folder:
        tmp = os.path.join(folder, "cloud.pcd")
        with open(tmp, "wb") as fh:
            fh.write(data)
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):   # no console warnings
            pcd = o3d.io.read_point_cloud(tmp, format="pcd", remove_nan_points=False,
                                          remove_infinite_points=False)
    pts = np.asarray(pcd.points, dtype=np.float64)
    if pts.shape[0] != n_points:
        raise _pcd_error(f"the header declares {n_points:,} points but only {pts.shape[0]:,} "
                         "could be decompressed; the file is damaged or cut off.",
                         code="truncated_file")
    normals = np.asarray(pcd.normals, dtype=np.float64) if pcd.has_normals() else None
    return pts, normals
