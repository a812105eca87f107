"""Stage 1 of the pipeline: read a scanned point cloud, mesh or relief image and validate it.

``read_cloud`` turns file bytes into a :class:`Cloud` whose points are ``(N, 3)`` float64
millimetres, with the file's normals and triangles where it has them:

- point clouds: PLY ascii/binary (and its faces), PCD ascii/binary/binary_compressed, XYZ/CSV/TXT,
  LAS/LAZ (:mod:`planning.inputs.las`), E57 (:mod:`planning.inputs.e57`: every scan by its pose,
  grid faces of structured scans);
- meshes: STL ascii/binary (:mod:`planning.inputs.stl`), OBJ (:mod:`planning.inputs.obj`);
- images as reliefs: PNG, JPEG, BMP, TIFF (:mod:`planning.inputs.relief`, Sood 2015 ch. 3).

:func:`read_input` is the entry every caller uses (the CLI, the service's submission check and
worker, the warm-up): it reads with an :class:`~schemas.params.InputParams` (units, limits, relief).
Every failure is a typed :class:`~planning.errors.InputError` (or
:class:`~planning.errors.InputTooLarge`) with a stable ``code`` and a message that says what the
machinist has to fix:

``unreadable_file``, ``truncated_file``, ``unsupported_format``, ``empty_cloud``, ``non_finite``,
``too_few_points``, ``degenerate_cloud``, ``extent_too_large``, ``missing_normals``,
``too_many_points`` (413), ``too_many_faces`` (413, ``input.max_faces``), ``too_many_pixels``
(413, ``input.relief.max_pixels``), ``file_too_large`` (413) and ``too_large_for_memory`` (413).

Size limits are checked against the header (PLY element counts, PCD ``POINTS``, text row counts,
STL triangle counts, OBJ ``v`` and ``f`` lines, LAS and E57 point counts) before the body is decoded,
so a header that claims billions of points or faces fails at once; an image larger than
``max_points`` pixels is scaled down instead. Declared counts are also checked against the size of
the file before anything is allocated for them (PLY elements and list counts, binary STL, PCD, LAS,
E57 scans), and LAZ and E57 points are decoded in chunks, so a small file whose header lies costs
little memory: a count the file cannot hold is ``truncated_file``. Whatever still fails inside a
reader is turned into a typed error here: a ``MemoryError`` into ``too_large_for_memory``, any other
exception (a reader bug or a damage no check foresaw) into ``unreadable_file`` naming the exception
type; typed planning errors pass through as they are. Python warnings and numpy floating-point
warnings raised while reading are silenced (what matters is in the error or in
:attr:`Cloud.warnings`).

Faces are checked by :func:`validate_faces` (indices in range, degenerate triangles dropped), then
triangles that repeat an earlier one's three vertices (any order or winding) are dropped; both drops
are said in :attr:`Cloud.warnings`. ``min_points`` counts the points of a plain cloud; a mesh needs
3 vertices, unless every one of its faces is dropped: it is then a plain cloud (``faces`` None) and
``min_points`` applies, the message naming what was dropped.

Decoding is vectorised (``numpy.frombuffer`` for binary bodies, ``numpy.fromstring`` for ascii rows,
numpy's C ``loadtxt`` for XYZ/CSV); no Python loop per point or per face.

This module checks the parameters, detects the format (magic bytes, then the file name extension,
then the content: STL ``solid``/binary size, OBJ statements, else text) and dispatches to the
readers: :mod:`planning.inputs.ply`, :mod:`planning.inputs.pcd`, :mod:`planning.inputs.text`,
:mod:`planning.inputs.stl`, :mod:`planning.inputs.obj`, :mod:`planning.inputs.las`,
:mod:`planning.inputs.e57` and :mod:`planning.inputs.relief` (the bytes and size limits in
:mod:`planning.inputs.source`, shared row parsing in :mod:`planning.inputs.rows`, mesh helpers in
:mod:`planning.inputs.mesh`); :mod:`planning.inputs.validate` checks the points and the faces.
Writing a PLY file is :func:`planning.report.files.write_ply`.
"""

from __future__ import annotations

import functools
import inspect
import os
import re
import warnings as _warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from planning.errors import InputError, InputTooLarge, ParameterError, PlanningError
from planning.inputs.mesh import _duplicate_faces
from planning.inputs.obj import _looks_like_obj, _read_obj
from planning.inputs.pcd import _read_pcd
from planning.inputs.ply import _read_ply
from planning.inputs.relief import IMAGE_FORMATS, _looks_like_image
from planning.inputs.source import _check_count, _Source
from planning.inputs.stl import _looks_like_stl, _read_stl
from planning.inputs.text import _read_text
from planning.inputs.validate import (
    _unit_normals,
    _valid_faces,
    validate_faces,
    validate_points,
)

if TYPE_CHECKING:
    from schemas.params import InputParams, ReliefParams

__all__ = [
    "EXTENSIONS",
    "FORMATS",
    "SUPPORTED",
    "UNIT_SCALE",
    "Cloud",
    "read_cloud",
    "read_input",
    "validate_faces",
    "validate_points",
]


#: Scale factor from each accepted input unit to millimetres.
UNIT_SCALE: dict[str, float] = {"mm": 1.0, "m": 1000.0, "in": 25.4}

#: Values accepted for ``read_cloud(fmt=...)`` (``None`` detects the format).
FORMATS = ("ply", "pcd", "xyz", "csv", "txt", "stl", "obj", "las", "laz", "e57",
           "png", "jpg", "jpeg", "bmp", "tif", "tiff")

_TEXT_FORMATS = ("xyz", "csv", "txt")
_IMAGE_FORMATS = tuple(ext.lstrip(".") for ext in IMAGE_FORMATS)
_READER_OF_FORMAT = {"laz": "las", **{f: "image" for f in _IMAGE_FORMATS},
                     **{f: "text" for f in _TEXT_FORMATS}}
_EXTENSION_FORMATS = {
    ".ply": "ply", ".pcd": "pcd", ".xyz": "xyz", ".csv": "csv", ".txt": "txt",
    ".pts": "xyz", ".asc": "xyz", ".xyzn": "xyz", ".xyzrgb": "xyz",
    ".stl": "stl", ".obj": "obj", ".las": "las", ".laz": "laz", ".e57": "e57",
    **{ext: ext.lstrip(".") for ext in IMAGE_FORMATS},
}
#: File name extensions that select a reader (the service keeps them on stored uploads).
EXTENSIONS = tuple(_EXTENSION_FORMATS)
_UNSUPPORTED_EXTENSIONS = {
    ".off": "OFF mesh", ".3mf": "3MF", ".step": "STEP CAD", ".stp": "STEP CAD",
    ".iges": "IGES CAD", ".igs": "IGES CAD", ".ptx": "PTX", ".gif": "GIF image",
    ".webp": "WebP image",
}
#: The formats read, as messages name them.
SUPPORTED = "PLY, PCD, XYZ/CSV text, STL, OBJ, LAS/LAZ, E57 or a PNG/JPEG/BMP/TIFF relief image"


@dataclass(frozen=True)
class Cloud:
    """A validated point cloud, with the triangles of a mesh where the file has them.

    ``points``: ``(N, 3)`` float64 coordinates in millimetres (already scaled from ``units``).
    ``normals``: ``(N, 3)`` float64 unit normals read from the file (PLY ``nx ny nz``, PCD
    ``normal_x normal_y normal_z``, XYZ columns 4-6 when ``xyz_normals=True``), or ``None``.
    Rows whose stored normal is zero or not finite cannot be normalised and are NaN;
    :attr:`normals_valid` flags the usable rows.
    ``source_format``: ``ply-ascii``, ``ply-binary_little_endian``, ``ply-binary_big_endian``,
    ``pcd-ascii``, ``pcd-binary``, ``pcd-binary_compressed``, ``xyz`` (whitespace separated text),
    ``csv`` (comma/semicolon separated text), ``stl-ascii``, ``stl-binary``, ``obj``, ``las``,
    ``laz``, ``e57``, ``image-png``, ``image-jpeg``, ``image-bmp`` or ``image-tiff``.
    ``faces``: ``(T, 3)`` int64 indices into ``points``, one row per triangle (polygons fan
    triangulated; STL corners merged into shared vertices; E57 structured-scan grids and image
    pixel grids triangulated), every index in ``[0, N)`` and no degenerate triangle (a repeated index
    or zero area); ``None`` for a plain cloud (a file that declares no faces). Winding is the file's
    (image reliefs: counter-clockwise seen from +Z).
    """

    points: np.ndarray
    normals: np.ndarray | None
    source_format: str
    faces: np.ndarray | None = None
    #: what reading changed in the file's content (an image scaled down, pixels filled, faces dropped),
    #: in words for the plan's warnings
    warnings: tuple[str, ...] = ()

    @property
    def n_points(self) -> int:
        """Number of points."""
        return int(self.points.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of triangles (0 for a plain cloud)."""
        return 0 if self.faces is None else int(self.faces.shape[0])

    @property
    def normals_valid(self) -> np.ndarray | None:
        """``(N,)`` bool: rows of :attr:`normals` that are unit vectors (None without normals)."""
        if self.normals is None:
            return None
        return np.isfinite(self.normals).all(axis=1)


# --------------------------------------------------------------------------------------------
# public entry point
# --------------------------------------------------------------------------------------------

def _typed_failures(read):
    """Run ``read`` with Python and numpy floating-point warnings silenced, and turn whatever a reader
    raises other than a :class:`~planning.errors.PlanningError` into one: a ``MemoryError`` (numpy's
    ``_ArrayMemoryError`` too) into :class:`InputTooLarge` ``too_large_for_memory``, any other exception (a
    reader bug, a damage no check foresaw: ``ValueError``, ``OverflowError``, ``struct.error``, ...)
    into :class:`InputError` ``unreadable_file`` naming its type. Typed errors pass through as they
    are; so do ``KeyboardInterrupt`` and ``SystemExit``. (``warnings.catch_warnings`` changes the
    process's filters while it reads: not thread-safe, and the service reads uploads in processes.)"""

    signature = inspect.signature(read)

    @functools.wraps(read)
    def guarded(source, **kwargs):
        signature.bind(source, **kwargs)           # a wrong argument is the caller's TypeError, not the file's
        try:
            with _warnings.catch_warnings(), np.errstate(all="ignore"):
                _warnings.simplefilter("ignore")
                return read(source, **kwargs)
        except PlanningError:
            raise
        except MemoryError as exc:
            raise InputTooLarge(
                f"The cloud file{_quoted(source)} needs more memory to read than is free ({type(exc).__name__}: "
                f"{_first_line(exc)}). Decimate the scan and submit it again; if the file is small, its header "
                "is probably damaged: export it again.", code="too_large_for_memory") from None
        except Exception as exc:  # noqa: BLE001 - never a traceback for a damaged file
            raise InputError(
                f"The cloud file{_quoted(source)} cannot be read: its reader failed with {type(exc).__name__} "
                f"({_first_line(exc)}). The file is probably damaged: export it again.",
                code="unreadable_file", exception=type(exc).__name__) from None

    return guarded


def _quoted(source) -> str:
    return f" {os.path.basename(os.fspath(source))!r}" if isinstance(source, (str, os.PathLike)) else ""


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return (lines[0][:200] if lines else "no message").rstrip(".")


@_typed_failures
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
    relief: ReliefParams | None = None,
    max_faces: int = 10_000_000,
) -> Cloud:
    """Read a point cloud, mesh or relief image (path or bytes) and return it validated, in mm.

    ``fmt`` is one of :data:`FORMATS` or ``None`` to detect it from magic bytes (``ply``,
    ``# .PCD``/``VERSION``, ``LASF``, ``ASTM-E57``, PNG/JPEG/BMP/TIFF signatures), then the file
    name extension, then the content (an STL ``solid``/binary size, OBJ statements), falling back to
    text. ``units`` is the unit of the file's coordinates (``mm``, ``m`` or ``in``); points are
    scaled by :data:`UNIT_SCALE` (not for images, whose relief is sized in mm). ``max_points`` and
    ``max_bytes`` are checked before the body is decoded (:class:`InputTooLarge`); an image with
    more pixels than ``max_points`` is scaled down instead. ``max_extent_mm`` bounds the largest side
    of the bounding box in mm; ``min_points`` is the fewest points accepted. ``xyz_normals`` reads
    columns 4-6 of a text file as normals. ``relief`` (:class:`~schemas.params.ReliefParams` or a
    dict of its fields; None: its defaults) maps an image to heights. ``max_faces`` is the most
    triangles a mesh may have (``input.max_faces``; PLY, STL, OBJ, E57 grids), checked from the header
    or the line count before the faces are read. Faces are checked by :func:`validate_faces`, then
    duplicates dropped (module docstring).
    Raises :class:`InputError` (:class:`InputTooLarge`) / :class:`ParameterError`, never another
    exception for a damaged file.
    """
    scale = _unit_scale(units)
    fmt = _check_read_parameters(fmt, max_points, max_extent_mm, min_points, max_bytes)
    if not (isinstance(max_faces, (int, np.integer)) and max_faces >= 1):
        raise ParameterError(f"max_faces must be a positive integer, got {max_faces!r}.",
                             parameter="max_faces", value=max_faces)
    src = _Source.open(source, max_bytes)
    if src.size == 0:
        raise InputError("The cloud file is empty (0 bytes).", code="empty_cloud")
    kind = _detect_format(src, fmt)
    notes: list[str] = []                       # what reading changed, for Cloud.warnings
    if kind == "ply":
        points, normals, faces, label = _read_ply(src, max_points, max_faces)
    elif kind == "pcd":
        points, normals, label = _read_pcd(src, max_points)
        faces = None
    elif kind == "stl":
        points, normals, faces, label = _read_stl(src, max_points, max_faces)
    elif kind == "obj":
        points, normals, faces, label = _read_obj(src, max_points, max_faces)
    elif kind == "las":
        from planning.inputs.las import _read_las
        points, normals, faces, label = _read_las(src, max_points)
    elif kind == "e57":
        from planning.inputs.e57 import _read_e57
        points, normals, faces, label = _read_e57(src, max_points, max_faces)
    elif kind == "image":
        from planning.inputs.relief import _read_image
        points, normals, faces, label = _read_image(src, max_points, _relief(relief), notes)
        scale = 1.0                                 # the relief parameters are millimetres
    else:
        points, normals, label = _read_text(src, max_points, xyz_normals)
        faces = None
    _check_count(points.shape[0], max_points)
    if scale != 1.0:
        points = points * scale
    # a mesh is a surface from one triangle on (a CAD cube has 8 vertices): min_points counts the
    # points of a plain cloud; the plan lays points on a mesh's facets (planning/inputs/facet_points.py)
    has_faces = faces is not None and len(faces) > 0
    points = validate_points(points, max_extent_mm=max_extent_mm, min_points=min(min_points, 3) if has_faces
                             else min_points, units=units)
    faces = _checked_faces(faces, points, kind, notes, min_points)
    return Cloud(points=points, normals=_unit_normals(normals), source_format=label,
                 faces=faces, warnings=tuple(notes))


def _checked_faces(faces, points: np.ndarray, kind: str, notes: list[str], min_points: int):
    """The faces validated (:func:`validate_faces`), duplicates dropped; what was dropped said in
    ``notes``. A mesh left without faces is a plain cloud (None), held to ``min_points``."""
    if faces is None:
        return None
    n_given = len(faces)
    tri, n_degenerate = _valid_faces(faces, points)
    n_duplicate = 0
    if kind != "image" and tri.shape[0] > 1:     # image grids hold each cell once
        repeated = _duplicate_faces(tri, points.shape[0])
        n_duplicate = int(repeated.sum())
        if n_duplicate:
            tri = np.ascontiguousarray(tri[~repeated])
    dropped = []
    if n_degenerate:
        dropped.append(f"{n_degenerate:,} degenerate triangle{'s' if n_degenerate != 1 else ''} dropped (a "
                       "repeated vertex or zero area)")
    if n_duplicate:
        dropped.append(f"{n_duplicate:,} duplicate triangle{'s' if n_duplicate != 1 else ''} dropped (the same "
                       "three vertices as an earlier triangle)")
    if n_given and tri.shape[0] == 0:            # nothing of the mesh is left but its vertices
        n = points.shape[0]
        what = " and ".join(dropped)
        if n < min_points:
            raise InputError(
                f"Every one of the mesh's {n_given:,} triangles was dropped ({what}), which leaves a point "
                f"cloud of {n} point(s); at least {min_points} are needed to plan machining. Export the "
                "mesh again (check its units and that it holds the part's surface).",
                code="too_few_points", n_points=int(n), min_points=int(min_points),
                n_faces_dropped=int(n_given))
        notes.append(f"Every one of the mesh's {n_given:,} triangles was dropped ({what}); its {n:,} "
                     "vertices are planned as a point cloud.")
        return None
    notes.extend(dropped)
    return tri


def read_input(
    source: str | os.PathLike | bytes,
    params: InputParams,
    *,
    fmt: str | None = None,
    max_points: int | None = None,
) -> Cloud:
    """Read a submitted file with the plan configuration's ``input`` parameters.

    The one entry of the CLI, the service (submission check and worker) and the warm-up:
    :func:`read_cloud` with ``params.units``, ``params.max_points`` (capped by ``max_points``,
    e.g. a service limit), ``params.max_extent_mm``, ``params.min_points`` and ``params.relief``.
    """
    limit = int(params.max_points) if max_points is None else min(int(params.max_points),
                                                                   int(max_points))
    return read_cloud(source, fmt=fmt, units=params.units, max_points=limit,
                      max_extent_mm=params.max_extent_mm, min_points=params.min_points,
                      relief=params.relief, max_faces=params.max_faces)


def _relief(relief):
    """The relief parameters: a ReliefParams as given, a mapping validated into one, None the defaults."""
    from schemas.params import ReliefParams, parse_config

    if relief is None:
        return ReliefParams()
    if isinstance(relief, dict):                     # checked and described as the configuration is
        return parse_config({"input": {"relief": relief}}).input.relief
    return relief


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
    """Return ``ply``, ``pcd``, ``stl``, ``obj``, ``las``, ``e57``, ``image`` or ``text``."""
    if fmt is not None:
        return _READER_OF_FORMAT.get(fmt, fmt)
    head = src.head
    if re.match(rb"ply\r?\n", head):
        return "ply"
    if _looks_like_pcd(head):
        return "pcd"
    if head.startswith(b"LASF"):
        return "las"
    if head.startswith(b"ASTM-E57"):
        return "e57"
    if _looks_like_image(head, src.size):
        return "image"
    ext = src.suffix
    if ext in _UNSUPPORTED_EXTENSIONS:
        what = _UNSUPPORTED_EXTENSIONS[ext]
        raise InputError(f"{what} files ({ext}) are not supported; export the scan as {SUPPORTED}.",
                         code="unsupported_format", format=what)
    if ext in _EXTENSION_FORMATS:
        kind = _EXTENSION_FORMATS[ext]
        return _READER_OF_FORMAT.get(kind, kind)
    if _looks_like_stl(src):
        return "stl"
    if _looks_like_obj(head):
        return "obj"
    return "text"


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
