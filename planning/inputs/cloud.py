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

This module checks the parameters, detects the format (magic bytes, then the file name extension,
else text) and dispatches to the readers: :mod:`planning.inputs.ply`, :mod:`planning.inputs.pcd`
and :mod:`planning.inputs.text` (the bytes and size limits in :mod:`planning.inputs.source`,
shared row parsing in :mod:`planning.inputs.rows`); :mod:`planning.inputs.validate` checks the
points. Writing a PLY file is :func:`planning.report.files.write_ply`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from planning.errors import InputError, ParameterError
from planning.inputs.pcd import _read_pcd
from planning.inputs.ply import _read_ply
from planning.inputs.source import _check_count, _Source
from planning.inputs.text import _read_text
from planning.inputs.validate import _unit_normals, validate_points

__all__ = [
    "Cloud",
    "UNIT_SCALE",
    "FORMATS",
    "read_cloud",
    "validate_points",
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
# public entry point
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


# --------------------------------------------------------------------------------------------
# parameters and format detection
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
