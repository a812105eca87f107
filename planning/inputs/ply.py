"""Stage 1, the cloud: the PLY reader (ascii, binary little and big endian).

The header is parsed from the first MiB; the vertex element must hold ``x y z`` (any PLY scalar
type) and may hold ``nx ny nz`` (read as file normals). Binary vertices are a
``numpy.frombuffer`` view after the elements that precede them; ascii vertices are parsed in one
``numpy.fromstring`` call (:mod:`planning.inputs.rows`). ``plyfile`` is used only when the vertex
element holds a list property, or when a list property (faces) comes before it in a binary file.
Errors: ``unreadable_file`` (header or body damaged), ``truncated_file`` (body cut off),
``empty_cloud`` (0 vertices), ``too_many_points`` (declared count over ``max_points``, checked
before the body is read).
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass

import numpy as np

from planning.errors import InputError
from planning.inputs.rows import _line_block, _normals_from, _parse_numbers, _xyz
from planning.inputs.source import _check_count, _Source

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
