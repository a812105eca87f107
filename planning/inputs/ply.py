"""Stage 1, the cloud: the PLY reader (ascii, binary little and big endian), vertices and faces.

The header is parsed from the first MiB; the vertex element must hold ``x y z`` (any PLY scalar
type) and may hold ``nx ny nz`` (read as file normals). A ``face`` element with a list property
``vertex_indices`` (or ``vertex_index``) gives the faces: triangles as they are, polygons fan
triangulated (:func:`planning.inputs.mesh._fan_triangles`); without one, ``faces`` is None.
Binary elements are ``numpy.frombuffer`` views at offsets summed from the elements before them; an
element with list properties is a view too when its lists are all of one length (checked on every
record), else its records are walked by a compiled loop (:mod:`planning.inputs.ply_lists`). Ascii
vertices are parsed in one ``numpy.fromstring`` call (:mod:`planning.inputs.rows`), ascii faces
likewise with a cursor moved over the properties of every row at once. ``plyfile`` is used only
when the vertex element itself holds a list property.

Every count is checked before anything is allocated for it: the vertex count against ``max_points``
and the face count against ``max_faces`` (every face record is at least one triangle), then every
element the reader reaches against the bytes left (binary: the smallest possible record, its scalars
and list counts with empty lists, times the count; ascii: one line per record); a list whose count
makes its record longer than the rest of the file ends the file early. Float face indices (ascii,
or a float list type) that are not whole numbers, or too large to be an index, are refused before
they are converted to integers.
Errors: ``unreadable_file`` (header or body damaged), ``truncated_file`` (body cut off, or
declared counts the file cannot hold), ``empty_cloud`` (0 vertices), ``too_many_points`` (declared
count over ``max_points``) and ``too_many_faces`` (declared faces, or the triangles of the polygons,
over ``max_faces``), both checked before the body is read.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass

import numpy as np

from planning.errors import InputError
from planning.inputs.mesh import _check_polygon_sizes, _fan_triangles
from planning.inputs.rows import (
    _fast_numbers,
    _line_block,
    _normals_from,
    _parse_numbers,
    _tokens_per_line,
    _xyz,
)
from planning.inputs.source import _check_count, _check_faces, _Source

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_FACE_LISTS = ("vertex_indices", "vertex_index")


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


def _read_ply(src: _Source, max_points: int, max_faces: int = 10_000_000):
    fmt, elements, body_start = _parse_ply_header(src.head)
    vertex = _find_vertex(elements)
    _check_count(vertex.count, max_points)
    if vertex.count == 0:
        raise InputError("The PLY file declares 0 vertices; the cloud is empty.",
                         code="empty_cloud")
    label = f"ply-{fmt}"
    face, face_list = _find_faces(elements)
    if face is not None:
        _check_faces(face.count, max_faces, f"The PLY header declares {face.count:,} faces, at least")
    data = src.data()
    # what is read: every element with plyfile, else those up to the vertices and the faces
    last = len(elements) - 1 if vertex.has_lists else \
        max(elements.index(vertex), elements.index(face) if face is not None else -1)
    _check_declared_sizes(data, body_start, elements[: last + 1], fmt)
    if vertex.has_lists:
        table, faces = _ply_plyfile(data, face_list, max_faces)
    elif fmt == "ascii":
        table = _ply_ascii_vertices(data, body_start, vertex, _lines_before(elements, vertex))
        faces = None if face is None else _ply_ascii_faces(data, body_start, face, face_list,
                                                           _lines_before(elements, face), max_faces,
                                                           vertex.count)
    else:
        table, faces = _ply_binary(data, body_start, elements, vertex, face, face_list,
                                   _PLY_FORMATS[fmt], max_faces)
    return _xyz(table), _normals_from(table, ("nx", "ny", "nz")), faces, label


def _min_record_bytes(e: _PlyElement) -> int:
    """The fewest bytes a binary record of ``e`` takes: its scalars and list counts, every list empty."""
    return sum(np.dtype(p[1]).itemsize for p in e.props)


def _check_declared_sizes(data: bytes, body_start: int, elements, fmt: str) -> None:
    """Refuse, before anything is allocated for them, element counts the file cannot hold.

    Binary: the elements' smallest possible records (:func:`_min_record_bytes`) times their counts must
    fit, one after the other, in the bytes after the header. Ascii: one line per record.
    """
    if fmt == "ascii":
        lines = data.count(b"\n", body_start) + (0 if data.endswith(b"\n") or len(data) <= body_start
                                                  else 1)
        needed = 0
        for e in elements:
            needed += e.count
            if needed > lines:
                raise _ply_error(f"the header declares {e.count:,} {e.name!r} records (one line each) but the "
                                 f"file has only {lines:,} lines after the header, fewer than the "
                                 f"{needed:,} records declared up to there need; the file was cut off during "
                                 "transfer or export, or its header is damaged. Send the complete file.",
                                 code="truncated_file")
        return
    offset = body_start
    for e in elements:
        size = _min_record_bytes(e)
        left = max(len(data) - offset, 0)
        if size * e.count > left:
            least = "" if not e.has_lists else " at least"
            raise _ply_error(f"the header declares {e.count:,} {e.name!r} records of{least} {size:,} "
                             f"byte{'s' if size != 1 else ''} "
                             f"each ({size * e.count:,} bytes) but only {left:,} bytes are left in the file "
                             f"for them; the file was cut off during transfer or export, or its header is "
                             "damaged. Send the complete file.", code="truncated_file")
        offset += size * e.count


def _lines_before(elements, element) -> int:
    return sum(e.count for e in elements[: elements.index(element)])


def _find_faces(elements):
    """The ``face`` element and the name of its vertex index list, or (None, None)."""
    for e in elements:
        if e.name != "face":
            continue
        for p in e.props:
            if len(p) == 3 and p[0] in _FACE_LISTS:
                return e, p[0]
    return None, None


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


def _ply_binary(data: bytes, body_start: int, elements, vertex: _PlyElement, face, face_list,
                endian: str, max_faces: int = 10_000_000):
    """Vertex table and faces of a binary PLY: each element located after the ones before it."""
    last = max(elements.index(vertex), elements.index(face) if face is not None else -1)
    offset, table, faces = body_start, None, None
    for e in elements[: last + 1]:
        if e is vertex:
            table = _ply_binary_vertices(data, offset, vertex, endian)
            offset += vertex.count * vertex.dtype(endian).itemsize
            continue
        dtype = e.dtype(endian) if not e.has_lists else _uniform_list_dtype(data, offset, e, endian)
        if dtype is not None:
            if e is face:
                faces = _uniform_polygons(np.frombuffer(data, dtype=dtype, count=e.count,
                                                        offset=offset)[face_list], max_faces,
                                          vertex.count)
            offset += e.count * dtype.itemsize
            continue
        from planning.inputs.ply_lists import walk_list_element

        end, done, items, sizes = walk_list_element(data, offset, e.count, e.props, endian,
                                                    face_list if e is face else None)
        if end < 0:
            raise _ply_error(f"the header declares {e.count:,} {e.name!r} records but the file ends "
                             f"inside record {done + 1:,}; the file was cut off during transfer or "
                             "export. Send the complete file.", code="truncated_file")
        if e is face:
            faces = _polygons(items, sizes, max_faces, vertex.count)
        offset = end
    return table, faces


def _uniform_list_dtype(data: bytes, offset: int, e: _PlyElement, endian: str) -> np.dtype | None:
    """The record dtype of an element whose lists have, on every record, the first record's length.

    None when some record differs (or the element does not fit in the file): the records must then
    be walked one by one. A first record whose list count makes it longer than the rest of the file
    is a file cut off (``truncated_file``).
    """
    fields, pos, lists = [], offset, []
    for p in e.props:
        if len(p) == 2:
            fields.append((p[0], endian + p[1]))
            pos += np.dtype(p[1]).itemsize
            continue
        count_type = np.dtype(endian + p[1])
        if e.count == 0 or pos + count_type.itemsize > len(data):
            return None
        n = int(np.frombuffer(data, dtype=count_type, count=1, offset=pos)[0])
        if n < 0:
            return None
        pos += count_type.itemsize + n * np.dtype(p[2]).itemsize
        if pos > len(data):
            raise _ply_error(f"the first {e.name!r} record's list {p[0]!r} declares {n:,} items, which "
                             f"reach byte {pos:,} of a file of {len(data):,} bytes; the file was cut off "
                             "or the record is damaged. Send the complete file.", code="truncated_file")
        fields += [("__count " + p[0], count_type), (p[0], endian + p[2], (n,))]
        lists.append((p[0], n))
    if pos - offset >= 2 ** 31:                      # numpy's record size limit: walk such records
        return None
    dtype = np.dtype(fields)
    if offset + e.count * dtype.itemsize > len(data):
        return None
    table = np.frombuffer(data, dtype=dtype, count=e.count, offset=offset)
    if all(bool(np.all(table["__count " + name] == n)) for name, n in lists):
        return dtype
    return None


def _polygons(indices: np.ndarray, sizes: np.ndarray, max_faces: int = 10_000_000,
              n_vertices: int | None = None) -> np.ndarray:
    """Faces from concatenated vertex indices and sizes: triangles, polygons fan triangulated.

    Float indices (an ascii file, or a float list type) must be whole numbers, and those too large to
    convert to integers are refused as out of range before they are converted; the others are checked by
    :func:`planning.inputs.validate.validate_faces`. More than ``max_faces`` triangles are refused before
    they are built."""
    sizes = np.asarray(sizes, dtype=np.int64)
    _check_polygon_sizes(sizes, "PLY faces")
    values = np.asarray(indices)
    if values.dtype.kind == "f":
        with np.errstate(invalid="ignore"):
            whole = np.isfinite(values) & (values == np.round(values))
        if not whole.all():
            k = int(np.argmax(~whole))
            raise _ply_error(f"a face refers to vertex index {float(values[k])!r}, which is not a whole "
                             "number.")
        huge = np.abs(values) >= 2.0 ** 62
        if huge.any():
            k = int(np.argmax(huge))
            face = int(np.searchsorted(np.cumsum(sizes), k, side="right"))
            vertices = "" if n_vertices is None else f", but the file has {n_vertices:,} vertices"
            raise _ply_error(f"face {face + 1:,} (counting from 1) refers to vertex {float(values[k]):.15g} "
                             f"(counting from 0){vertices}. The file is damaged; export the mesh again.")
    return _fan_triangles(values.astype(np.int64), sizes, max_faces,
                          "The PLY faces split into")


def _uniform_polygons(lists: np.ndarray, max_faces: int = 10_000_000,
                      n_vertices: int | None = None) -> np.ndarray:
    """Faces from an ``(F, n)`` array of vertex index lists all of one length ``n``."""
    return _polygons(lists.reshape(-1), np.full(lists.shape[0], lists.shape[1] if lists.ndim == 2 else 0),
                     max_faces, n_vertices)


def _ply_ascii_faces(data: bytes, body_start: int, face: _PlyElement, face_list: str,
                     skip_lines: int, max_faces: int = 10_000_000,
                     n_vertices: int | None = None) -> np.ndarray:
    """Faces of an ascii PLY: one record per line, the properties walked for every line at once."""
    if face.count == 0:
        return np.zeros((0, 3), dtype=np.int64)
    block, n_rows = _line_block(data, body_start, skip_lines, face.count)
    if n_rows < face.count:
        raise _ply_error(f"the header declares {face.count:,} faces but the file has only "
                         f"{n_rows:,} face lines; the file is incomplete. Send the complete file.",
                         code="truncated_file")
    values = _fast_numbers(block)
    counts = _tokens_per_line(block)
    if values is None:
        raise _ply_error("the face lines contain text that is not a number.")
    if counts.size != face.count:
        raise _ply_error(f"the header declares {face.count:,} faces but {counts.size:,} face lines "
                         "hold values; a face line is empty.")
    line_end = np.cumsum(counts)
    cursor = line_end - counts
    item_start = sizes = None
    for p in face.props:
        if len(p) == 2:
            cursor = cursor + 1
            continue
        short = cursor >= line_end
        if short.any():
            row = int(np.argmax(short))
            raise _ply_error(f"face line {row + 1} holds {int(counts[row])} values, fewer than its "
                             "properties need.")
        n = values[cursor]
        room = line_end - cursor - 1                       # values left on the line after the count
        with np.errstate(invalid="ignore"):
            bad = ~((n >= 0) & (n == np.floor(n)) & (n <= room))
        if bad.any():
            row = int(np.argmax(bad))
            raise _ply_error(f"face line {row + 1} has the list count {float(n[row])!r}, which is not a "
                             f"whole number from 0 to the {int(room[row])} values left on its line.")
        if p[0] == face_list:
            item_start, sizes = cursor + 1, n.astype(np.int64)
        cursor = cursor + 1 + n.astype(np.int64)
    wrong = np.flatnonzero(cursor != line_end)
    if wrong.size:
        row = int(wrong[0])
        raise _ply_error(f"face line {row + 1} holds {int(counts[row])} values, but its list counts "
                         f"call for {int(cursor[row] - line_end[row] + counts[row])}.")
    _check_polygon_sizes(sizes, "PLY faces")
    _check_faces(int(sizes.sum()) - 2 * sizes.size, max_faces, "The PLY faces split into")
    first = np.cumsum(sizes) - sizes
    at = np.repeat(item_start, sizes) + (np.arange(int(sizes.sum())) - np.repeat(first, sizes))
    return _polygons(values[at], sizes, max_faces, n_vertices)


def _ply_plyfile(data: bytes, face_list: str | None, max_faces: int = 10_000_000):
    """Vertex table (and faces) via plyfile: for a vertex element that holds list properties."""
    import plyfile

    try:
        ply = plyfile.PlyData.read(io.BytesIO(data))
        table = ply["vertex"].data
        lists = ply["face"].data[face_list] if face_list is not None else None
    except Exception as exc:  # plyfile raises several exception types
        text = str(exc)
        code = "truncated_file" if re.search(r"end.of.file|early end|truncat", text, re.I) \
            else "unreadable_file"
        raise _ply_error(f"{text}. The file is damaged or incomplete.", code=code) from None
    dtype = table.dtype
    scalar = [n for n in dtype.names if dtype[n].shape == () and dtype[n] != object]
    faces = None
    if lists is not None:
        if lists.dtype == object:
            sizes = np.fromiter(map(len, lists), dtype=np.int64, count=len(lists))
            items = np.concatenate(lists) if len(lists) else np.zeros(0, dtype=np.int64)
            faces = _polygons(items, sizes, max_faces, len(table))
        else:
            faces = _uniform_polygons(lists, max_faces, len(table))
    return np.asarray(table[scalar]), faces
