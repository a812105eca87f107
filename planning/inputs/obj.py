"""Stage 1, the cloud: the Wavefront OBJ reader (``v`` vertices and ``f`` faces).

``v x y z [w]`` lines give the points (extra values such as a weight or a vertex colour are
ignored); ``f`` lines give polygons of vertex references ``i``, ``i/t``, ``i//n`` or ``i/t/n``
(1-based; negative references count back from the last vertex defined before the line), fan
triangulated. Other statements (``vt``, ``vn``, ``o``, ``g``, ``s``, ``usemtl``, ``l``, ...) and ``#``
comments are skipped; a ``\\`` at the end of a line continues it. An OBJ without ``f`` lines is a plain
cloud (``faces`` None); ``normals`` is None (``vn`` normals belong to face corners, not to vertices).

Decoding is vectorised: the lines are classified from their first bytes with numpy, the ``v`` and
``f`` lines cut out as two byte blocks and each parsed by one ``numpy.fromstring`` call (the
``/t/n`` parts removed first by one regular expression substitution). The vertex count is checked
against ``max_points`` before the numbers are parsed. Errors name the file line:
``unreadable_file`` (a word among the numbers, a vertex with fewer than three coordinates, a face
with fewer than three vertices, an index 0 or out of range), ``empty_cloud`` (no ``v`` line).
"""

from __future__ import annotations

import re

import numpy as np

from planning.errors import InputError
from planning.inputs.mesh import _fan_triangles
from planning.inputs.rows import _fast_numbers, _tokens_per_line
from planning.inputs.source import _check_count, _Source
from planning.inputs.text import _has_binary_bytes

_STATEMENTS = {b"v", b"vt", b"vn", b"vp", b"f", b"l", b"p", b"o", b"g", b"s", b"mtllib", b"usemtl",
               b"cstype", b"deg", b"curv", b"surf", b"mg", b"usemap", b"maplib", b"shadow_obj",
               b"trace_obj", b"lod", b"bevel", b"c_interp", b"d_interp", b"call", b"csh"}
_SPACE = np.zeros(256, dtype=bool)
_SPACE[[9, 10, 11, 12, 13, 32]] = True


def _obj_error(src: _Source, msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Invalid OBJ file{src.quoted}: {msg}", code=code)


def _looks_like_obj(head: bytes) -> bool:
    """The first statement is an OBJ keyword and a ``v x y z`` line follows within the first MiB."""
    for line in head[:65536].splitlines()[:200]:
        text = line.strip()
        if not text or text.startswith(b"#"):
            continue
        if text.split()[0] not in _STATEMENTS:
            return False
        return re.search(rb"(?m)^[ \t]*v[ \t]+[-+.\d]", head) is not None
    return False


def _read_obj(src: _Source, max_points: int):
    data = src.data()
    if _has_binary_bytes(data):
        raise _obj_error(src, "it contains binary bytes; an OBJ file is text. The file is damaged or "
                              "not an OBJ mesh.")
    text = data
    if b"\\" in text:
        text = re.sub(rb"\\[ \t]*\r?\n", b"  ", text)              # line continuations
    if b"#" in text:
        text = re.sub(rb"#[^\n]*", b"", text)                      # comments (line numbers kept)
    arr, starts = _lines(text)
    if np.isin(arr[starts], (9, 32)).any():
        arr, starts = _lines(re.sub(rb"(?m)^[ \t]+", b"", text))   # leading blanks
    lengths = np.diff(np.append(starts, arr.size))                 # bytes per line, newline included
    first = arr[starts]
    second = arr[np.minimum(starts + 1, arr.size - 1)]
    blank_after = (lengths > 1) & _SPACE[second] & (second != 10)
    is_v = (first == ord("v")) & blank_after
    is_f = (first == ord("f")) & blank_after
    n_vertices = int(is_v.sum())
    _check_count(n_vertices, max_points)
    if n_vertices == 0:
        raise InputError("The OBJ file holds no vertex ('v') lines; the mesh is empty.",
                         code="empty_cloud")
    points = _vertices(src, arr, starts, lengths, is_v)
    faces = _faces(src, arr, starts, lengths, is_v, is_f) if is_f.any() else None
    return points, None, faces, "obj"


def _lines(text: bytes):
    """The bytes as uint8 and the offset of each line's first byte."""
    arr = np.frombuffer(text, dtype=np.uint8)
    starts = np.flatnonzero(arr == 10) + 1
    return arr, np.concatenate(([0], starts[starts < arr.size]))


def _statement_block(arr, starts, lengths, which) -> np.ndarray:
    """The bytes of the lines flagged ``which`` with their one-letter keyword blanked."""
    body = arr[np.repeat(which, lengths)]
    at = np.cumsum(lengths[which]) - lengths[which]              # line starts inside the block
    body[at] = 32
    return np.append(body, np.uint8(10))


def _row_values(src, block: bytes, line_numbers: np.ndarray, what: str, noun: str, items: str, need: str):
    """All numbers of a block and how many each of its lines holds (at least 3, else ``need`` is said)."""
    values = _fast_numbers(block)
    counts = _tokens_per_line(block)
    if values is None or counts.size != line_numbers.size:
        lines = block.split(b"\n")
        for k, line in enumerate(lines[: line_numbers.size]):           # error path only
            if _fast_numbers(line) is None or not line.split():
                raise _obj_error(src, f"line {int(line_numbers[k])} is a {what} line whose values are "
                                      f"not numbers: {line.strip()[:60].decode('latin-1')!r}.")
        raise _obj_error(src, f"a {what} line holds text that is not a number.")
    short = np.flatnonzero(counts < 3)
    if short.size:
        raise _obj_error(src, f"line {int(line_numbers[short[0]])} is a {noun} with "
                              f"{int(counts[short[0]])} {items}; {need}.")
    return values, counts


def _vertices(src, arr, starts, lengths, is_v) -> np.ndarray:
    block = _statement_block(arr, starts, lengths, is_v).tobytes()
    line_numbers = np.flatnonzero(is_v) + 1
    values, counts = _row_values(src, block, line_numbers, "vertex ('v')", "vertex", "coordinate(s)",
                                 "'v' needs x y z")
    first = np.cumsum(counts) - counts
    return values[first[:, None] + np.arange(3)]


def _first_of_each_reference(block: np.ndarray) -> bytes:
    """Drop everything from a ``/`` to the end of its word: ``i/t/n`` -> ``i`` (vectorised)."""
    slash = block == ord("/")
    if not slash.any():
        return block.tobytes()
    blank = _SPACE[block]
    seen = np.cumsum(slash)
    at_word_start = np.maximum.accumulate(np.where(blank, seen, 0))   # slashes before the word
    return block[blank | (seen == at_word_start)].tobytes()


def _faces(src, arr, starts, lengths, is_v, is_f) -> np.ndarray:
    block = _first_of_each_reference(_statement_block(arr, starts, lengths, is_f))
    line_numbers = np.flatnonzero(is_f) + 1
    values, sizes = _row_values(src, block, line_numbers, "face ('f')", "face", "vertex reference(s)",
                                "a face needs at least 3")
    refs = values.astype(np.int64)
    poly_of_ref = np.repeat(np.arange(sizes.size), sizes)
    if (refs != values).any():
        k = int(np.argmax(refs != values))
        raise _obj_error(src, f"line {int(line_numbers[poly_of_ref[k]])} refers to vertex "
                              f"{values[k]!r}, which is not a whole number.")
    n_vertices = int(is_v.sum())
    defined_before = (np.cumsum(is_v) - is_v)[is_f]            # 'v' lines before each face line
    before = defined_before[poly_of_ref]
    index = np.where(refs > 0, refs - 1, before + refs)
    bad = (refs == 0) | (index < 0) | (index >= n_vertices)
    if bad.any():
        k = int(np.argmax(bad))
        line = int(line_numbers[poly_of_ref[k]])
        if refs[k] == 0:
            why = "vertex 0 (OBJ counts vertices from 1)"
        elif refs[k] < 0:
            why = (f"vertex {int(refs[k])}, {-int(refs[k])} back from the last of the "
                   f"{int(before[k])} vertices defined before it")
        else:
            why = f"vertex {int(refs[k])}, but the file defines only {n_vertices:,} vertices"
        raise _obj_error(src, f"the face on line {line} refers to {why}; {int(bad.sum()):,} vertex "
                              "reference(s) are out of range. The file is damaged or incomplete.")
    return _fan_triangles(index, sizes)
