"""Stage 1 of the pipeline: read a scanned point cloud and validate it.

``read_cloud`` turns file bytes (PLY ascii/binary, PCD ascii/binary/binary_compressed, XYZ/CSV/TXT)
into a :class:`Cloud` whose points are ``(N, 3)`` float64 millimetres. Every failure is a typed
:class:`~planning.errors.InputError` (or :class:`~planning.errors.InputTooLarge`) with a stable
``code`` and a message that says what the machinist has to fix:

``unreadable_file``, ``truncated_file``, ``unsupported_format``, ``empty_cloud``, ``non_finite``,
``too_few_points``, ``degenerate_cloud``, ``extent_too_large``, ``missing_normals``,
``too_many_points`` (413) and ``file_too_large`` (413).

Size limits are checked against the header (PLY element counts, PCD ``POINTS``, text row counts)
before the body is decoded, so a header that claims billions of points fails at once.
Decoding is vectorised (``numpy.frombuffer`` for binary bodies, ``numpy.fromstring`` for the
fixed-width rows of ascii PLY/PCD, numpy's C ``loadtxt`` for XYZ/CSV); no Python loop per point.

``write_ply`` writes a binary or ascii PLY atomically (temporary file + ``os.replace``).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import secrets
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from planning.errors import InputError, InputTooLarge, ParameterError

__all__ = [
    "Cloud",
    "UNIT_SCALE",
    "FORMATS",
    "read_cloud",
    "validate_points",
    "write_ply",
    "atomic_path",
]

#: Scale factor from each accepted input unit to millimetres.
UNIT_SCALE: dict[str, float] = {"mm": 1.0, "m": 1000.0, "in": 25.4}

#: Values accepted for ``read_cloud(fmt=...)`` (``None`` detects the format).
FORMATS = ("ply", "pcd", "xyz", "csv", "txt")

_TEXT_FORMATS = ("xyz", "csv", "txt")
_EXTENSION_FORMATS = {
    ".ply": "ply", ".pcd": "pcd", ".xyz": "xyz", ".csv": "csv", ".txt": "txt",
    ".pts": "xyz", ".asc": "xyz", ".xyzn": "xyz", ".xyzrgb": "xyz",
}
_UNSUPPORTED_EXTENSIONS = {
    ".las": "LAS", ".laz": "LAZ", ".e57": "E57", ".stl": "STL mesh", ".obj": "OBJ mesh",
    ".off": "OFF mesh", ".3mf": "3MF", ".step": "STEP CAD", ".stp": "STEP CAD",
    ".iges": "IGES CAD", ".igs": "IGES CAD", ".ptx": "PTX",
}
_UNSUPPORTED_MAGIC = {b"LASF": "LAS/LAZ", b"ASTM-E57": "E57"}
_HEAD_BYTES = 1 << 20          # headers must end within the first MiB
_TEXT_HEADER_LINES = 1000      # at most this many non-numeric lines before the data
_COV_CHUNK = 1 << 20           # rows per chunk when accumulating the covariance
_COINCIDENT_RTOL = 1e-9        # extent below this x coordinate magnitude: all points coincide
_LINE_RTOL = 1e-5              # 2nd singular value below this x the 1st: all points on a line
_LINE_ABS_RTOL = 1e-6          # ... or below this x coordinate magnitude (float32 rounding)


@dataclass(frozen=True)
class Cloud:
    """A validated point cloud.

    ``points``: ``(N, 3)`` float64 coordinates in millimetres (already scaled from ``units``).
    ``normals``: ``(N, 3)`` float64 unit normals read from the file (PLY ``nx ny nz``, PCD
    ``normal_x normal_y normal_z``, XYZ columns 4-6 when ``xyz_normals=True``), or ``None``.
    Rows whose stored normal is zero or not finite cannot be normalised and are NaN;
    :attr:`normals_valid` flags the usable rows.
    ``source_format``: ``ply-ascii``, ``ply-binary_little_endian``, ``ply-binary_big_endian``,
    ``pcd-ascii``, ``pcd-binary``, ``pcd-binary_compressed``, ``xyz`` (whitespace separated text)
    or ``csv`` (comma/semicolon separated text).
    """

    points: np.ndarray
    normals: np.ndarray | None
    source_format: str

    @property
    def n_points(self) -> int:
        """Number of points."""
        return int(self.points.shape[0])

    @property
    def normals_valid(self) -> np.ndarray | None:
        """``(N,)`` bool: rows of :attr:`normals` that are unit vectors (None without normals)."""
        if self.normals is None:
            return None
        return np.isfinite(self.normals).all(axis=1)


# --------------------------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------------------------

def read_cloud(
    source: str | os.PathLike | bytes,
    *,
    fmt: str | None = None,
    units: str = "mm",
    max_points: int = 20_000_000,
    max_extent_mm: float = 5_000.0,
    min_points: int = 10,
    max_bytes: int | None = None,
    xyz_normals: bool = False,
) -> Cloud:
    """Read a point cloud file (path or bytes) and return validated points in millimetres.

    ``fmt`` is one of :data:`FORMATS` or ``None`` to detect it from magic bytes (``ply``,
    ``# .PCD``/``VERSION``) and the file name extension, falling back to text.
    ``units`` is the unit of the file's coordinates (``mm``, ``m`` or ``in``); points are
    scaled by :data:`UNIT_SCALE`. ``max_points`` and ``max_bytes`` are checked before the body
    is decoded (:class:`InputTooLarge`); ``max_extent_mm`` bounds the largest side of the
    bounding box in mm; ``min_points`` is the fewest points accepted. ``xyz_normals`` reads
    columns 4-6 of a text file as normals. Raises :class:`InputError` / :class:`ParameterError`.
    """
    scale = _unit_scale(units)
    fmt = _check_read_parameters(fmt, max_points, max_extent_mm, min_points, max_bytes)
    src = _Source.open(source, max_bytes)
    if src.size == 0:
        raise InputError("The cloud file is empty (0 bytes).", code="empty_cloud")
    kind = _detect_format(src, fmt)
    if kind == "ply":
        points, normals, label = _read_ply(src, max_points)
    elif kind == "pcd":
        points, normals, label = _read_pcd(src, max_points)
    else:
        points, normals, label = _read_text(src, max_points, xyz_normals)
    _check_count(points.shape[0], max_points)
    if scale != 1.0:
        points = points * scale
    points = validate_points(points, max_extent_mm=max_extent_mm, min_points=min_points,
                             units=units)
    return Cloud(points=points, normals=_unit_normals(normals), source_format=label)


def validate_points(points, *, max_extent_mm: float = 5_000.0, min_points: int = 10,
                    units: str | None = None) -> np.ndarray:
    """Check a cloud and return it as a C-contiguous ``(N, 3)`` float64 array in mm.

    Raises :class:`InputError` with code ``empty_cloud``, ``non_finite``, ``too_few_points``,
    ``extent_too_large`` (largest bounding-box side above ``max_extent_mm``) or
    ``degenerate_cloud`` (all points coincident or on one straight line, judged from the
    singular values of the centred points relative to the extent; a flat plane is accepted).
    ``units`` only improves the hint of the extent message.
    """
    pts = _as_point_array(points)
    if pts.shape[0] == 0:
        raise InputError("The point cloud contains no points; check that the scan was exported "
                         "with its vertices.", code="empty_cloud")
    _check_finite(pts)
    if pts.shape[0] < min_points:
        raise InputError(
            f"The point cloud has only {pts.shape[0]} point(s); at least {min_points} are needed "
            "to plan machining. Export the full scan.", code="too_few_points",
            n_points=int(pts.shape[0]), min_points=int(min_points))
    lo, hi = _bounds(pts)
    _check_extent(lo, hi, max_extent_mm, units)
    _check_not_degenerate(pts, lo, hi)
    return pts


def write_ply(path, points, *, colors=None, normals=None, labels=None, binary: bool = True) -> None:
    """Write points (mm, stored as double ``x y z``) to a PLY file, atomically.

    Optional per-point ``colors`` ``(N, 3)`` 0-255 (uchar ``red green blue``), ``normals``
    ``(N, 3)`` (double ``nx ny nz``) and ``labels`` ``(N,)`` integers (int ``label``).
    ``binary=True`` writes binary little endian, otherwise ascii (round-trip exact ``%.17g``).
    The file appears complete or not at all (temporary file in the same folder + ``os.replace``).
    """
    vertex = _vertex_table(points, colors, normals, labels)
    header = _ply_header(vertex, binary)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            if binary:
                vertex.tofile(fh)
            else:
                _write_ascii_rows(fh, vertex)


@contextlib.contextmanager
def atomic_path(path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success move it onto ``path`` atomically.

    The temporary file already exists (created with the usual umask permissions, unlike
    ``mkstemp``'s 0600) and may be overwritten by the caller. On any exception it is removed
    and ``path`` is left untouched.
    """
    target = Path(path)
    tmp = _reserve_temp(target)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _reserve_temp(target: Path) -> Path:
    for _ in range(100):
        tmp = target.with_name(f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
        try:
            open(tmp, "xb").close()
            return tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"cannot create a temporary file next to {target}")


# --------------------------------------------------------------------------------------------
# parameters and source
# --------------------------------------------------------------------------------------------

def _unit_scale(units) -> float:
    if units not in UNIT_SCALE:
        allowed = ", ".join(repr(u) for u in UNIT_SCALE)
        raise ParameterError(f"input.units is {units!r}; allowed values are {allowed}.",
                             parameter="input.units", value=units, allowed=list(UNIT_SCALE))
    return UNIT_SCALE[units]


def _check_read_parameters(fmt, max_points, max_extent_mm, min_points, max_bytes) -> str | None:
    if fmt is not None:
        fmt = str(fmt).lower().lstrip(".")
        if fmt not in FORMATS:
            raise ParameterError(f"fmt is {fmt!r}; allowed values are {', '.join(FORMATS)} "
                                 "or None to detect it.", parameter="fmt", value=fmt)
    if not (isinstance(max_points, (int, np.integer)) and max_points >= 1):
        raise ParameterError(f"max_points must be a positive integer, got {max_points!r}.",
                             parameter="max_points", value=max_points)
    if not (np.isfinite(max_extent_mm) and max_extent_mm > 0):
        raise ParameterError(f"max_extent_mm must be a positive number, got {max_extent_mm!r}.",
                             parameter="max_extent_mm", value=max_extent_mm)
    if not (isinstance(min_points, (int, np.integer)) and min_points >= 1):
        raise ParameterError(f"min_points must be a positive integer, got {min_points!r}.",
                             parameter="min_points", value=min_points)
    if max_bytes is not None and not (isinstance(max_bytes, (int, np.integer)) and max_bytes >= 1):
        raise ParameterError(f"max_bytes must be a positive integer or None, got {max_bytes!r}.",
                             parameter="max_bytes", value=max_bytes)
    return fmt


class _Source:
    """The input bytes: the first MiB (``head``) for headers, ``data()`` for the whole body."""

    def __init__(self, name: str | None, size: int, head: bytes, path: Path | None,
                 data: bytes | None):
        self.name, self.size, self.head, self._path, self._data = name, size, head, path, data

    @classmethod
    def open(cls, source, max_bytes: int | None) -> "_Source":
        if isinstance(source, (bytes, bytearray, memoryview)):
            data = bytes(source)
            _check_bytes(len(data), max_bytes)
            return cls(None, len(data), data[:_HEAD_BYTES], None, data)
        if not isinstance(source, (str, os.PathLike)):
            raise ParameterError("source must be a file path or bytes, got "
                                 f"{type(source).__name__}.",
                                 parameter="source")
        path = Path(source)
        try:
            size = path.stat().st_size
            _check_bytes(size, max_bytes)
            with open(path, "rb") as fh:
                head = fh.read(_HEAD_BYTES)
        except OSError as exc:
            raise InputError(f"Cannot open the cloud file {path.name!r}: {exc.strerror or exc}.",
                             code="unreadable_file") from exc
        return cls(path.name, size, head, path, head if size <= len(head) else None)

    def data(self) -> bytes:
        if self._data is None:
            try:
                self._data = self._path.read_bytes()
            except OSError as exc:
                raise InputError(f"Cannot read the cloud file {self.name!r}: {exc}.",
                                 code="unreadable_file") from exc
        return self._data

    @property
    def suffix(self) -> str:
        return Path(self.name).suffix.lower() if self.name else ""


def _check_bytes(size: int, max_bytes: int | None) -> None:
    if max_bytes is not None and size > max_bytes:
        raise InputTooLarge(
            f"The cloud file is {size:,} bytes; the limit is {max_bytes:,} bytes. Decimate the "
            "scan (or save it as binary PLY, which is smaller) and submit it again.",
            code="file_too_large", size_bytes=int(size), max_bytes=int(max_bytes))


def _check_count(n: int, max_points: int) -> None:
    if n > max_points:
        raise InputTooLarge(
            f"The cloud has {n:,} points; the limit is {max_points:,}. Decimate the scan "
            "(e.g. a voxel grid of 0.2-0.5 mm) and submit it again.",
            code="too_many_points", n_points=int(n), max_points=int(max_points))


def _detect_format(src: _Source, fmt: str | None) -> str:
    """Return ``ply``, ``pcd`` or ``text``."""
    if fmt is not None:
        return "text" if fmt in _TEXT_FORMATS else fmt
    head = src.head
    if re.match(rb"ply\r?\n", head):
        return "ply"
    if _looks_like_pcd(head):
        return "pcd"
    for magic, what in _UNSUPPORTED_MAGIC.items():
        if head.startswith(magic):
            raise InputError(f"{what} files are not supported yet; export the scan as PLY, PCD "
                             "or XYZ/CSV text.", code="unsupported_format", format=what)
    ext = src.suffix
    if ext in _UNSUPPORTED_EXTENSIONS:
        what = _UNSUPPORTED_EXTENSIONS[ext]
        raise InputError(f"{what} files ({ext}) are not supported; export the scan as a point "
                         "cloud in PLY, PCD or XYZ/CSV text.", code="unsupported_format",
                         format=what)
    kind = _EXTENSION_FORMATS.get(ext, "text")
    return "text" if kind in _TEXT_FORMATS else kind


def _looks_like_pcd(head: bytes) -> bool:
    for line in head[:4096].splitlines()[:20]:
        text = line.strip()
        if not text:
            continue
        if text.startswith(b"#"):
            if text.upper().startswith(b"# .PCD"):
                return True
            continue
        return text.upper().startswith(b"VERSION")
    return False


# --------------------------------------------------------------------------------------------
# PLY
# --------------------------------------------------------------------------------------------

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass
class _PlyElement:
    name: str
    count: int
    props: list            # (name, numpy type) for scalars, (name, count type, item type) for lists

    @property
    def has_lists(self) -> bool:
        return any(len(p) == 3 for p in self.props)

    def dtype(self, endian: str) -> np.dtype:
        return np.dtype([(p[0], endian + p[1]) for p in self.props])


def _ply_error(msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Invalid PLY file: {msg}", code=code)


def _read_ply(src: _Source, max_points: int):
    fmt, elements, body_start = _parse_ply_header(src.head)
    vertex = _find_vertex(elements)
    _check_count(vertex.count, max_points)
    if vertex.count == 0:
        raise InputError("The PLY file declares 0 vertices; the cloud is empty.",
                         code="empty_cloud")
    label = f"ply-{fmt}"
    data = src.data()
    preceding = elements[: elements.index(vertex)]
    if vertex.has_lists or (fmt != "ascii" and any(e.has_lists for e in preceding)):
        table = _ply_vertices_plyfile(data)
    elif fmt == "ascii":
        table = _ply_ascii_vertices(data, body_start, vertex, sum(e.count for e in preceding))
    else:
        endian = _PLY_FORMATS[fmt]
        offset = body_start + sum(e.count * e.dtype(endian).itemsize for e in preceding)
        table = _ply_binary_vertices(data, offset, vertex, endian)
    return _xyz(table), _normals_from(table, ("nx", "ny", "nz")), label


def _parse_ply_header(head: bytes):
    """Parse a PLY header: (format, elements, byte offset of the body)."""
    if not re.match(rb"ply\r?\n", head):
        raise _ply_error("it does not start with the 'ply' magic line.")
    end = re.search(rb"(?m)^end_header[ \t]*(\r?\n|$)", head)
    if end is None:
        raise _ply_error("no 'end_header' line in the first MiB; the header is damaged.")
    try:
        lines = head[: end.start()].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise _ply_error("the header contains non-ASCII bytes; the file is damaged.") from None
    fmt = None
    elements: list[_PlyElement] = []
    for number, line in enumerate(lines[1:], start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = _ply_format_line(words, number)
        elif words[0] == "element":
            elements.append(_ply_element_line(words, number))
        elif words[0] == "property":
            if not elements:
                raise _ply_error(f"header line {number}: property before any element.")
            elements[-1].props.append(_ply_property_line(words, number))
        else:
            raise _ply_error(f"header line {number}: unknown keyword {words[0]!r}.")
    if fmt is None:
        raise _ply_error("the header has no 'format' line.")
    return fmt, elements, end.end()


def _ply_format_line(words, number) -> str:
    if len(words) < 2 or words[1] not in _PLY_FORMATS:
        raise _ply_error(f"header line {number}: unknown format {' '.join(words[1:])!r} "
                         "(expected ascii, binary_little_endian or binary_big_endian).")
    return words[1]


def _ply_element_line(words, number) -> _PlyElement:
    if len(words) != 3 or not re.fullmatch(r"\d+", words[2]):
        raise _ply_error(f"header line {number}: expected 'element NAME COUNT', got "
                         f"{' '.join(words)!r}.")
    return _PlyElement(words[1], int(words[2]), [])


def _ply_property_line(words, number):
    def np_type(name):
        if name not in _PLY_TYPES:
            raise _ply_error(f"header line {number}: unknown property type {name!r}.")
        return _PLY_TYPES[name]

    if len(words) == 5 and words[1] == "list":
        return (words[4], np_type(words[2]), np_type(words[3]))
    if len(words) == 3:
        return (words[2], np_type(words[1]))
    raise _ply_error(f"header line {number}: malformed property line {' '.join(words)!r}.")


def _find_vertex(elements) -> _PlyElement:
    vertex = next((e for e in elements if e.name == "vertex"), None)
    if vertex is None:
        raise _ply_error("the header declares no 'vertex' element.")
    names = [p[0] for p in vertex.props]
    if len(set(names)) != len(names):
        raise _ply_error("the vertex element declares a property twice.")
    missing = [c for c in ("x", "y", "z") if c not in names]
    if missing:
        raise _ply_error(f"the vertex element has no {' '.join(missing)} property.")
    for e in elements:
        if len({p[0] for p in e.props}) != len(e.props):
            raise _ply_error(f"element {e.name!r} declares a property twice.")
    return vertex


def _ply_binary_vertices(data: bytes, offset: int, vertex: _PlyElement, endian: str) -> np.ndarray:
    dtype = vertex.dtype(endian)
    needed = vertex.count * dtype.itemsize
    available = max(len(data) - offset, 0)
    if available < needed:
        raise _ply_error(
            f"the header declares {vertex.count:,} vertices ({needed:,} bytes) but the file holds "
            f"only {available // dtype.itemsize:,} complete ones; the file was cut off during "
            "transfer or export. Send the complete file.", code="truncated_file")
    return np.frombuffer(data, dtype=dtype, count=vertex.count, offset=offset)


def _ply_ascii_vertices(data: bytes, body_start: int, vertex: _PlyElement,
                        skip_lines: int) -> np.ndarray:
    block, n_rows = _line_block(data, body_start, skip_lines, vertex.count)
    if n_rows < vertex.count:
        raise _ply_error(f"the header declares {vertex.count:,} vertices but the file has only "
                         f"{n_rows:,} vertex lines; the file is incomplete. Send the complete "
                         "file.", code="truncated_file")
    values = _parse_numbers(block, len(vertex.props), vertex.count, what="PLY vertex data")
    dtype = np.dtype([(p[0], "f8") for p in vertex.props])
    return np.ascontiguousarray(values).view(dtype).reshape(-1)


def _line_block(data: bytes, start: int, skip: int, count: int) -> tuple[bytes, int]:
    """Bytes of ``count`` lines after skipping ``skip`` lines from ``start``; and lines found."""
    body = memoryview(data)[start:]
    newlines = np.flatnonzero(np.frombuffer(body, dtype=np.uint8) == 10)
    n_lines = newlines.size + (1 if body.nbytes and (newlines.size == 0
                                                      or newlines[-1] != body.nbytes - 1) else 0)
    begin = 0 if skip == 0 else (int(newlines[skip - 1]) + 1 if skip <= newlines.size
                                 else body.nbytes)
    last = skip + count - 1
    end = int(newlines[last]) if last < newlines.size else body.nbytes
    return bytes(body[begin:end]), max(min(n_lines - skip, count), 0)


def _ply_vertices_plyfile(data: bytes) -> np.ndarray:
    """Vertex table via plyfile (list properties in or before the vertex element)."""
    import plyfile

    try:
        ply = plyfile.PlyData.read(io.BytesIO(data))
        table = ply["vertex"].data
    except Exception as exc:  # plyfile raises several exception types
        text = str(exc)
        code = "truncated_file" if re.search(r"end.of.file|early end|truncat", text, re.I) \
            else "unreadable_file"
        raise _ply_error(f"{text}. The file is damaged or incomplete.", code=code) from None
    dtype = table.dtype
    scalar = [n for n in dtype.names if dtype[n].shape == () and dtype[n] != object]
    return np.asarray(table[scalar])


def _columns(table: np.ndarray, names) -> np.ndarray:
    """The fields ``names`` of a structured table as an ``(N, len(names))`` float64 array."""
    out = np.empty((table.shape[0], len(names)), dtype=np.float64)
    for j, c in enumerate(names):
        out[:, j] = table[c]
    return out


def _xyz(table: np.ndarray) -> np.ndarray:
    return _columns(table, ("x", "y", "z"))


def _normals_from(table: np.ndarray, names) -> np.ndarray | None:
    if not all(n in table.dtype.names for n in names):
        return None
    return _columns(table, names)


# --------------------------------------------------------------------------------------------
# PCD
# --------------------------------------------------------------------------------------------

_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4",
              ("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}
_PCD_NORMALS = ("normal_x", "normal_y", "normal_z")


def _pcd_error(msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Invalid PCD file: {msg}", code=code)


def _read_pcd(src: _Source, max_points: int):
    header, body_start = _parse_pcd_header(src.head)
    dtype, n_points, data_kind = _pcd_layout(header)
    _check_count(n_points, max_points)
    if n_points == 0:
        raise InputError("The PCD file declares 0 points; the cloud is empty.", code="empty_cloud")
    data = src.data()
    if data_kind == "binary":
        table = _pcd_binary(data, body_start, dtype, n_points)
    elif data_kind == "ascii":
        table = _pcd_ascii(data, body_start, dtype, n_points)
    else:
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


def _pcd_layout(header):
    """Structured dtype of one point, the point count and the DATA kind."""
    fields = header.get("FIELDS")
    sizes, types = header.get("SIZE"), header.get("TYPE")
    if not fields or not sizes or not types:
        raise _pcd_error("the header needs FIELDS, SIZE and TYPE lines.")
    counts = header.get("COUNT", ["1"] * len(fields))
    if not len(fields) == len(sizes) == len(types) == len(counts):
        raise _pcd_error("FIELDS, SIZE, TYPE and COUNT list different numbers of entries.")
    try:
        spec = [(_pcd_field_name(f, i), _PCD_TYPES[(t.upper(), int(s))], int(c))
                for i, (f, s, t, c) in enumerate(zip(fields, sizes, types, counts))]
    except (KeyError, ValueError):
        raise _pcd_error(f"unknown SIZE/TYPE/COUNT combination {sizes} {types} {counts}.") from None
    names = [s[0] for s in spec]
    if not {"x", "y", "z"} <= set(names) or len(set(names)) != len(names):
        raise _pcd_error("FIELDS must contain x, y and z exactly once.")
    dtype = np.dtype([(n, "<" + t, (c,)) if c != 1 else (n, "<" + t) for n, t, c in spec])
    kind = (header.get("DATA") or [""])[0].lower()
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
            n = int(header["WIDTH"][0]) * int(header.get("HEIGHT", ["1"])[0])
    except (KeyError, IndexError, ValueError):
        raise _pcd_error("the header needs a valid POINTS (or WIDTH and HEIGHT) line.") from None
    if n < 0:
        raise _pcd_error(f"negative point count {n}.")
    return n


def _pcd_binary(data: bytes, offset: int, dtype: np.dtype, n: int) -> np.ndarray:
    needed = n * dtype.itemsize
    available = max(len(data) - offset, 0)
    if available < needed:
        raise _pcd_error(f"the header declares {n:,} points ({needed:,} bytes) but the file holds "
                         f"only {available // dtype.itemsize:,} complete ones; the file was cut "
                         "off. Send the complete file.", code="truncated_file")
    return np.frombuffer(data, dtype=dtype, count=n, offset=offset)


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
        pcd = o3d.io.read_point_cloud(tmp, format="pcd", remove_nan_points=False,
                                      remove_infinite_points=False)
    pts = np.asarray(pcd.points, dtype=np.float64)
    if pts.shape[0] != n_points:
        raise _pcd_error(f"the header declares {n_points:,} points but only {pts.shape[0]:,} "
                         "could be decompressed; the file is damaged or cut off.",
                         code="truncated_file")
    normals = np.asarray(pcd.normals, dtype=np.float64) if pcd.has_normals() else None
    return pts, normals


# --------------------------------------------------------------------------------------------
# text (XYZ / CSV / TXT)
# --------------------------------------------------------------------------------------------

_NUMBER = r"[+-]?(?:\d+\.?\d*(?:[eE][+-]?\d+)?|\.\d+(?:[eE][+-]?\d+)?|nan|inf|infinity)"
_DATA_FIRST_BYTES = np.zeros(256, dtype=bool)
_DATA_FIRST_BYTES[np.frombuffer(b"0123456789+-.", dtype=np.uint8)] = True


def _text_error(msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Cannot read the text cloud: {msg}", code=code)


def _read_text(src: _Source, max_points: int, want_normals: bool):
    data = src.data()
    _reject_binary(data)
    start, n_header, delimiter, decimal_comma, n_cols = _text_layout(data)
    if start is None:
        raise InputError("The text file contains no rows of numbers (x y z); the cloud is empty.",
                         code="empty_cloud")
    body = data[start:]
    _check_count(_count_data_rows(body), max_points)
    body = _normalise_delimiters(body, delimiter, decimal_comma)
    need = 6 if want_normals else 3
    if n_cols < need:
        raise InputError(f"Normals were requested from columns 4-6 but the rows have only "
                         f"{n_cols} columns. Export the normals or use computed normals.",
                         code="missing_normals")
    values = _parse_text_rows(body, need, n_header)
    normals = values[:, 3:6] if want_normals else None
    label = "csv" if delimiter in (",", ";") else "xyz"
    return np.ascontiguousarray(values[:, :3]), normals, label


def _reject_binary(data: bytes) -> None:
    sample = np.frombuffer(data[:65536], dtype=np.uint8)
    control = (sample < 32) & ~np.isin(sample, (9, 10, 11, 12, 13))
    if control.any():
        raise InputError("The file is neither PLY, PCD nor text (it contains binary bytes); it "
                         "is damaged or in an unsupported format. Export the scan as PLY, PCD or "
                         "XYZ/CSV text.", code="unreadable_file")


def _text_layout(data: bytes):
    """Find the first data row: (byte offset, header lines, delimiter, decimal comma, columns)."""
    pos = 3 if data.startswith(b"\xef\xbb\xbf") else 0      # UTF-8 byte order mark
    for n_header in range(_TEXT_HEADER_LINES + 1):
        if pos >= len(data):
            break
        nl = data.find(b"\n", pos)
        nl = len(data) if nl < 0 else nl
        line = data[pos:nl].decode("latin-1").strip()
        parsed = _split_data_line(line)
        if parsed is not None:
            return (pos, n_header, *parsed)
        pos = nl + 1
    if pos < len(data):
        raise _text_error(f"no row of numbers in the first {_TEXT_HEADER_LINES} lines.")
    return None, 0, None, False, 0


def _split_data_line(line: str):
    """(delimiter, decimal comma, column count) if ``line`` is a row of >= 3 numbers, else None."""
    if not line or line.startswith(("#", "//")):
        return None
    decimal_comma = ";" in line and "," in line
    delimiter = ";" if ";" in line else ("," if "," in line else None)
    text = line.replace(",", ".") if decimal_comma else line
    fields = [f.strip() for f in (text.split(delimiter) if delimiter else text.split())]
    if delimiter and fields and fields[-1] == "":
        fields = fields[:-1]                       # trailing delimiter
    if len(fields) < 3 or not all(re.fullmatch(_NUMBER, f, re.I) for f in fields):
        return None
    return delimiter, decimal_comma, len(fields)


def _count_data_rows(body: bytes) -> int:
    """Lower bound of the number of data rows (lines starting with a digit, sign or dot)."""
    arr = np.frombuffer(body, dtype=np.uint8)
    starts = np.flatnonzero(arr[:-1] == 10) + 1
    firsts = np.concatenate((arr[:1], arr[starts]))
    return int(_DATA_FIRST_BYTES[firsts].sum())


def _normalise_delimiters(body: bytes, delimiter, decimal_comma: bool) -> bytes:
    if decimal_comma:
        body = body.replace(b",", b".")
    if delimiter:
        body = body.replace(delimiter.encode(), b" ")
    return body


def _parse_text_rows(body: bytes, need: int, n_header: int) -> np.ndarray:
    """The first ``need`` numbers of every data row as (rows, need) float64.

    numpy's C ``loadtxt`` (numpy >= 1.23) reads ~1M rows/s here, as fast as ``fromstring``,
    and handles extra columns, blank lines and ``#`` comments; a two-character ``//`` comment
    marker drops it to a slower path, so it is only passed when present.
    """
    comments = ("#", "//") if b"//" in body else "#"
    try:
        return np.loadtxt(io.BytesIO(body), usecols=range(need), comments=comments, ndmin=2,
                          dtype=np.float64, encoding="latin-1")
    except ValueError as exc:
        raise _text_error(_describe_loadtxt_error(str(exc), body, n_header)) from None


def _describe_loadtxt_error(text: str, body: bytes, n_header: int) -> str:
    """Turn numpy.loadtxt's message into one that names the file line (error path only)."""
    bad_value = re.search(r"could not convert string (.*) to \w+ at row (\d+), column (\d+)", text)
    few_columns = re.search(r"at row (\d+) with (\d+) columns", text)
    if bad_value:
        line = _file_line(body, int(bad_value.group(2)), n_header)
        return (f"line {line} holds {bad_value.group(1)} in column {bad_value.group(3)}, which is "
                "not a number. Every row must hold x y z numbers.")
    if few_columns:
        line = _file_line(body, int(few_columns.group(1)) - 1, n_header)
        return (f"line {line} holds {few_columns.group(2)} value(s); every row needs at least "
                "x y z (and nx ny nz when normals are read from the file).")
    return f"{text}. Every row must hold x y z numbers."


def _file_line(body: bytes, data_row: int, n_header: int) -> int:
    """1-based file line of the 0-based ``data_row`` (blank and comment lines skipped)."""
    seen = -1
    for index, raw in enumerate(body.splitlines()):
        stripped = raw.strip()
        if stripped and not stripped.startswith((b"#", b"//")):
            seen += 1
            if seen == data_row:
                return n_header + index + 1
    return n_header + 1


def _fast_numbers(text: bytes) -> np.ndarray | None:
    """All whitespace-separated numbers of ``text``, or None if some token is not a number."""
    try:
        return np.fromstring(text.decode("latin-1"), dtype=np.float64, sep=" ")
    except ValueError:
        return None


_WHITESPACE = np.zeros(256, dtype=bool)
_WHITESPACE[[9, 10, 11, 12, 13, 32]] = True


def _tokens_per_line(text: bytes) -> np.ndarray:
    """Number of whitespace-separated tokens on each non-blank line of ``text``."""
    arr = np.frombuffer(text, dtype=np.uint8)
    if arr.size == 0:
        return np.zeros(0, dtype=np.int64)
    space = _WHITESPACE[arr]
    starts = np.flatnonzero(~space & np.concatenate(([True], space[:-1])))
    line_ends = np.append(np.flatnonzero(arr == 10), arr.size)
    counts = np.diff(np.searchsorted(starts, line_ends), prepend=0)
    return counts[counts > 0]


def _rows_are_uniform(text: bytes, n_cols: int, n_values: int) -> bool:
    """True if every non-blank line holds exactly ``n_cols`` tokens (``n_values`` in all)."""
    if n_values % n_cols:
        return False
    counts = _tokens_per_line(text)
    return counts.size * n_cols == n_values and bool(np.all(counts == n_cols))


def _parse_numbers(block: bytes, n_cols: int, n_rows: int, *, what: str) -> np.ndarray:
    """Exactly ``n_rows`` x ``n_cols`` numbers from a block of text lines (one row per line)."""
    values = _fast_numbers(block)
    if values is not None and values.size == n_rows * n_cols \
            and _rows_are_uniform(block, n_cols, values.size):
        return values.reshape(n_rows, n_cols)
    counts = _tokens_per_line(block)
    wrong = np.flatnonzero(counts != n_cols)
    if wrong.size == 1 and wrong[0] == counts.size - 1 and counts[-1] < n_cols:
        raise InputError(f"Cannot read the {what}: the last row is incomplete; the file was cut "
                         "off. Send the complete file.", code="truncated_file")
    if wrong.size:
        raise InputError(f"Cannot read the {what}: row {int(wrong[0]) + 1} holds "
                         f"{int(counts[wrong[0]])} values, the header declares {n_cols}.",
                         code="unreadable_file")
    raise InputError(f"Cannot read the {what}: it contains text that is not a number.",
                     code="unreadable_file")


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------

def _as_point_array(points) -> np.ndarray:
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"Points must be numbers: {exc}.", code="unreadable_file") from None
    if pts.size == 0:
        return pts.reshape(0, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"Points must be an (N, 3) array of x y z; got shape {pts.shape}.",
                         code="unreadable_file")
    return np.ascontiguousarray(pts)


def _check_finite(pts: np.ndarray) -> None:
    if np.isfinite(pts).all():
        return
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        n_bad = int(bad.sum())
        first = int(np.argmax(bad))
        raise InputError(
            f"{n_bad:,} point(s) have NaN or infinite coordinates (first at point index {first}, "
            "counting from 0). Remove invalid points in the scanner software and export again.",
            code="non_finite", n_bad=n_bad, first_index=first)


def _bounds(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box corners (per-column reductions: ~10x faster than ``min(axis=0)``)."""
    lo = np.array([pts[:, j].min() for j in range(3)])
    hi = np.array([pts[:, j].max() for j in range(3)])
    return lo, hi


def _check_extent(lo: np.ndarray, hi: np.ndarray, max_extent_mm: float, units: str | None) -> None:
    size = hi - lo
    largest = float(size.max())
    if largest > max_extent_mm:
        dims = " x ".join(f"{s:,.1f}" for s in size)
        unit_hint = f" (read with units={units!r})" if units else ""
        raise InputError(
            f"The cloud measures {dims} mm{unit_hint}; its largest side {largest:,.1f} mm exceeds "
            f"the limit of {max_extent_mm:,.1f} mm. Check the input units (mm, m or in): a file "
            "in millimetres read as metres is 1000 times too large.",
            code="extent_too_large", extent_mm=largest, max_extent_mm=float(max_extent_mm))


def _check_not_degenerate(pts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> None:
    magnitude = max(float(np.abs(lo).max()), float(np.abs(hi).max()), 1.0)
    if float((hi - lo).max()) <= _COINCIDENT_RTOL * magnitude:
        raise InputError("All points of the cloud are at the same position; this is not a scan "
                         "of a part.", code="degenerate_cloud")
    sv = _singular_values(pts)
    if sv[1] <= max(_LINE_RTOL * sv[0], _LINE_ABS_RTOL * magnitude):
        raise InputError("All points of the cloud lie on one straight line; a part cannot be "
                         "planned from it. Check the export (a single scan line?).",
                         code="degenerate_cloud")


def _singular_values(pts: np.ndarray) -> np.ndarray:
    """Singular values of the centred points divided by sqrt(N) (RMS spread per principal axis)."""
    centre = pts.mean(axis=0)
    cov = np.zeros((3, 3))
    for i in range(0, pts.shape[0], _COV_CHUNK):
        d = pts[i:i + _COV_CHUNK] - centre
        cov += d.T @ d
    eig = np.linalg.eigvalsh(cov / pts.shape[0])[::-1]
    return np.sqrt(np.clip(eig, 0.0, None))


def _unit_normals(normals: np.ndarray | None) -> np.ndarray | None:
    """Normalise file normals to unit length; rows that cannot be normalised become NaN."""
    if normals is None:
        return None
    nrm = np.asarray(normals, dtype=np.float64)
    length = np.sqrt(np.einsum("ij,ij->i", nrm, nrm))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = nrm / length[:, None]
    bad = ~(np.isfinite(length) & (length > 1e-12))
    if bad.any():
        out[bad] = np.nan
    return out


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------

def _per_point(name: str, values, n: int, width: int | None) -> np.ndarray:
    arr = np.asarray(values)
    shape = (n, width) if width else (n,)
    if arr.shape != shape:
        raise ParameterError(f"{name} must have shape {shape}, got {arr.shape}.", parameter=name)
    return arr


def _vertex_table(points, colors, normals, labels) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ParameterError(f"points must have shape (N, 3), got {pts.shape}.", parameter="points")
    n = pts.shape[0]
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    cols = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]}
    if normals is not None:
        nrm = _per_point("normals", normals, n, 3).astype(np.float64)
        fields += [("nx", "<f8"), ("ny", "<f8"), ("nz", "<f8")]
        cols.update(nx=nrm[:, 0], ny=nrm[:, 1], nz=nrm[:, 2])
    if colors is not None:
        rgb = _per_point("colors", colors, n, 3)
        if rgb.size and (np.any(rgb < 0) or np.any(rgb > 255)):
            raise ParameterError("colors must be in 0..255.", parameter="colors")
        rgb = np.rint(rgb).astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        cols.update(red=rgb[:, 0], green=rgb[:, 1], blue=rgb[:, 2])
    if labels is not None:
        lab = _per_point("labels", labels, n, None)
        if not (np.issubdtype(lab.dtype, np.integer) or lab.dtype == bool):
            raise ParameterError(f"labels must be integers, got {lab.dtype}.", parameter="labels")
        if lab.size and (lab.min() < np.iinfo(np.int32).min or lab.max() > np.iinfo(np.int32).max):
            raise ParameterError("labels must fit a 32-bit integer.", parameter="labels")
        fields.append(("label", "<i4"))
        cols["label"] = lab.astype(np.int32)
    table = np.empty(n, dtype=fields)
    for name, col in cols.items():
        table[name] = col
    return table


_PLY_NAMES = {"f8": "double", "f4": "float", "u1": "uchar", "i4": "int"}


def _ply_header(table: np.ndarray, binary: bool) -> bytes:
    fmt = "binary_little_endian" if binary else "ascii"
    lines = ["ply", f"format {fmt} 1.0", "comment scanmill point cloud, units mm",
             f"element vertex {table.shape[0]}"]
    for name in table.dtype.names:
        lines.append(f"property {_PLY_NAMES[table.dtype[name].str[1:]]} {name}")
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def _write_ascii_rows(fh, table: np.ndarray) -> None:
    if table.shape[0]:
        fmts = ["%.17g" if table.dtype[n].kind == "f" else "%d" for n in table.dtype.names]
        np.savetxt(fh, table, fmt=fmts)
