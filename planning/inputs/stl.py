"""Stage 1, the cloud: the STL reader (ascii and binary triangle meshes).

Binary STL: an 80-byte header, a uint32 triangle count, then 50 bytes per triangle (normal, three
float32 vertices, a uint16 attribute); the file size must be ``84 + 50 x count``. A binary file whose
header happens to start with ``solid`` (many CAD exporters write that) is recognised by its size.
Ascii STL (``solid`` ... ``facet normal`` / ``outer loop`` / three ``vertex x y z`` / ``endloop`` /
``endfacet`` ... ``endsolid``, several solids allowed, keywords in any case) is decoded by removing
the keywords and parsing the numbers left in one ``numpy.fromstring`` call (12 per facet).

The three corners of each facet are merged with every exactly equal vertex
(:func:`planning.inputs.mesh._merge_vertices`), so the faces index shared vertices; the facet normals
are not kept (``normals`` is None). The triangle count (the binary header's, or the ascii ``endfacet``
count) is checked before the body is decoded: more than ``2 x max_points`` triangles is refused (a
closed mesh has about half as many vertices as triangles), and more than ``max_faces``; a binary
count must also match the file size exactly. The merged vertex count is then checked against
``max_points`` exactly.
Errors: ``truncated_file`` (fewer bytes than the count needs, a last facet or ``endsolid``
missing), ``unreadable_file`` (trailing bytes, words among the numbers, a facet without three
vertices), ``empty_cloud`` (0 triangles), ``too_many_points``, ``too_many_faces``.
"""

from __future__ import annotations

import re

import numpy as np

from planning.errors import InputError
from planning.inputs.mesh import _merge_vertices
from planning.inputs.source import _check_count, _check_faces, _Source

_HEADER = 84
_RECORD = np.dtype([("normal", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])
_SOLID_LINE = re.compile(rb"(?m)^[ \t]*(?:end)?solid\b[^\n]*")
_KEYWORDS = (b"endfacet", b"endloop", b"facet", b"normal", b"outer", b"loop", b"vertex")


def _stl_error(src: _Source, msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Invalid STL file{src.quoted}: {msg}", code=code)


def _binary_count(src: _Source) -> int | None:
    """The triangle count of the binary header, or None when the file is shorter than the header."""
    if src.size < _HEADER:
        return None
    return int(np.frombuffer(src.head, dtype="<u4", count=1, offset=80)[0])


def _is_binary_stl(src: _Source) -> bool:
    """True if the size matches the binary header's count (whatever the first 80 bytes say)."""
    count = _binary_count(src)
    return count is not None and src.size == _HEADER + _RECORD.itemsize * count


def _looks_like_ascii_stl(head: bytes) -> bool:
    """``solid`` first, then a facet, and no NUL byte after the 80-byte header area."""
    text = head.lstrip()
    if text[:5].lower() != b"solid":
        return False
    sample = head[:65536]
    return b"\0" not in sample and re.search(rb"(?i)\bfacet\b|\bendsolid\b", sample) is not None


def _looks_like_stl(src: _Source) -> bool:
    """Detection without a file name: an exact binary size match, or an ascii ``solid ... facet``."""
    return _looks_like_ascii_stl(src.head) or (src.size > _HEADER and _is_binary_stl(src))


def _read_stl(src: _Source, max_points: int, max_faces: int = 10_000_000):
    if _is_binary_stl(src) or not _looks_like_ascii_stl(src.head):
        raw, label = _binary_vertices(src, max_points, max_faces), "stl-binary"
    else:
        raw, label = _ascii_vertices(src, max_points, max_faces), "stl-ascii"
    points, inverse = _merge_vertices(raw)
    _check_count(points.shape[0], max_points)
    return points, None, inverse.reshape(-1, 3), label


def _check_triangles(src: _Source, count: int, max_points: int, max_faces: int, what: str) -> None:
    if count == 0:
        raise InputError("The STL file holds 0 triangles; the mesh is empty.", code="empty_cloud")
    if count > 2 * max_points:
        _check_count(count // 2, max_points)
    _check_faces(count, max_faces, what)


def _binary_vertices(src: _Source, max_points: int, max_faces: int) -> np.ndarray:
    count = _binary_count(src)
    if count is None:
        raise _stl_error(src, f"the file is {src.size} bytes, shorter than the 84-byte binary header "
                              "(80 bytes of text and the triangle count); it was cut off or is not "
                              "an STL file.", code="truncated_file")
    _check_triangles(src, count, max_points, max_faces, "The binary STL header declares")
    needed = _HEADER + _RECORD.itemsize * count
    if src.size < needed:
        raise _stl_error(src, f"the header declares {count:,} triangles ({needed:,} bytes) but the file "
                              f"holds {src.size:,} bytes, {(src.size - _HEADER) // _RECORD.itemsize:,} "
                              "complete triangles; the file was cut off during transfer or export. "
                              "Send the complete file.", code="truncated_file")
    if src.size > needed:
        raise _stl_error(src, f"the header declares {count:,} triangles ({needed:,} bytes) but the file "
                              f"holds {src.size:,} bytes; the triangle count or the file is damaged. "
                              "Export the mesh again.")
    table = np.frombuffer(src.data(), dtype=_RECORD, count=count, offset=_HEADER)
    return table["v"].reshape(-1, 3)


def _ascii_vertices(src: _Source, max_points: int, max_faces: int) -> np.ndarray:
    text = _SOLID_LINE.sub(b" ", src.data().lower())
    n_facets = text.count(b"endfacet")
    n_open = text.count(b"facet") - n_facets
    n_vertices = text.count(b"vertex")
    ends = src.data().rstrip().lower()
    if n_open > n_facets or not re.search(rb"(?m)^[ \t]*endsolid\b[^\n]*\Z", ends):
        raise _stl_error(src, f"the last facet or the closing 'endsolid' line is missing after "
                              f"{n_facets:,} complete facets; the file was cut off. Send the complete "
                              "file.", code="truncated_file")
    _check_triangles(src, n_facets, max_points, max_faces, "The STL file holds")
    if n_vertices != 3 * n_facets:
        raise _stl_error(src, f"{n_facets:,} facets hold {n_vertices:,} 'vertex' lines; every facet "
                              "needs exactly three.")
    for word in _KEYWORDS:
        text = text.replace(word, b" ")
    try:
        values = np.fromstring(text.decode("latin-1"), dtype=np.float64, sep=" ")
    except ValueError:
        words = re.findall(rb"[a-z_][a-z_0-9]*", text)
        what = f" ({words[0].decode('latin-1')!r})" if words else ""
        raise _stl_error(src, f"it contains a word{what} that is not an STL keyword or a number.") \
            from None
    if values.size != 12 * n_facets:
        raise _stl_error(src, f"{n_facets:,} facets should hold {12 * n_facets:,} numbers (a normal and "
                              f"three vertices of x y z each) but hold {values.size:,}; a value is "
                              "missing or extra.")
    return values.reshape(n_facets, 12)[:, 3:].reshape(-1, 3)
