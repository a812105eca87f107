"""Stage 1, the cloud: the Wavefront OBJ reader (``v`` vertices and ``f`` faces).

``v x y z [w]`` lines give the points (extra values such as a weight or a vertex colour are
ignored); ``f`` lines give polygons of vertex references ``i``, ``i/t``, ``i//n`` or ``i/t/n``
(1-based; negative references count back from the last vertex defined before the line), fan
triangulated. Other statements (``vt``, ``vn``, ``o``, ``g``, ``s``, ``usemtl``, ``l``, ...) and ``#``
comments are skipped; a ``\\`` at the end of a line continues it. An OBJ without ``f`` lines is a plain
cloud (``faces`` None); ``normals`` is None (``vn`` normals belong to face corners, not to vertices).

Decoding is vectorised: the lines are classified from their first bytes with numpy, the ``v`` and
``f`` lines cut out as two byte blocks, the ``v`` block parsed by one ``numpy.fromstring`` call and
the ``f`` block (its ``/t/n`` parts dropped by a mask over the bytes) by
:func:`planning.inputs.rows._fast_integers`, an integer ``numpy.fromstring`` a few MiB at a time
into one preallocated array (the float parse again if it holds something else, for the error
message): 8 million ``f 1 2 3`` lines (64 MB) read in 2.5-4 s on two cores at a peak of 0.85 GB, the
duplicates then dropped by :mod:`planning.inputs.cloud`. The vertex count is checked against
``max_points`` and the ``f`` line count against ``max_faces`` (each is at least one triangle) before
the numbers are parsed, the triangle count of the polygons before they are split. Errors name the
file line: ``unreadable_file`` (a word among the numbers, a vertex with fewer than three
coordinates, a face with fewer than three vertices, an index 0 or out of range), ``empty_cloud`` (no
``v`` line), ``too_many_points``, ``too_many_faces``.
"""

from __future__ import annotations

import re

import numpy as np

from planning.errors import InputError
from planning.inputs.mesh import _fan_triangles
from planning.inputs.rows import _fast_integers, _fast_numbers, _tokens_per_line
from planning.inputs.source import _check_count, _check_faces, _Source
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


def _read_obj(src: _Source, max_points: int, max_faces: int = 10_000_000):
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
    del first, second, blank_after
    n_vertices = int(is_v.sum())
    _check_count(n_vertices, max_points)
    if n_vertices == 0:
        raise InputError("The OBJ file holds no vertex ('v') lines; the mesh is empty.",
                         code="empty_cloud")
    n_face_lines = int(is_f.sum())
    _check_faces(n_face_lines, max_faces, f"The OBJ file holds {n_face_lines:,} face ('f') lines, at least")
    points = _vertices(src, arr, starts, lengths, is_v)
    if not n_face_lines:
        return points, None, None, "obj"
    block, line_starts = _statement_block(arr, starts, lengths, is_f, with_starts=True)
    del starts, lengths, arr, text, data                   # the face block is all that is left to read
    block, line_starts = _first_of_each_reference(block, line_starts)
    return points, None, _faces(src, block, line_starts, is_v, is_f, max_faces), "obj"


def _lines(text: bytes):
    """The bytes as uint8 and the offset of each line's first byte."""
    arr = np.frombuffer(text, dtype=np.uint8)
    starts = np.flatnonzero(arr == 10) + 1
    return arr, np.concatenate(([0], starts[starts < arr.size]))


def _statement_block(arr, starts, lengths, which, with_starts: bool = False):
    """The bytes of the lines flagged ``which`` with their one-letter keyword blanked (and, with
    ``with_starts``, the offset of each of those lines in the block)."""
    body = arr[np.repeat(which, lengths)]
    at = np.cumsum(lengths[which])
    at -= lengths[which]                                         # line starts inside the block
    body[at] = 32
    block = np.append(body, np.uint8(10))
    return (block, at) if with_starts else block


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


def _first_of_each_reference(block: np.ndarray, line_starts: np.ndarray):
    """Drop everything from a ``/`` to the end of its word: ``i/t/n`` -> ``i`` (vectorised); the block
    and its line starts moved to match. About 11 bytes per byte of the block at the peak."""
    slash = block == ord("/")
    if not slash.any():
        return block, line_starts
    blank = _SPACE[block]
    seen = np.cumsum(slash, dtype=np.int32 if block.size < 2 ** 31 else np.int64)
    del slash
    at_word_start = np.where(blank, seen, 0)
    np.maximum.accumulate(at_word_start, out=at_word_start)       # slashes before the word
    keep = seen == at_word_start
    del seen, at_word_start
    keep |= blank
    del blank
    dropped = np.add.reduceat(~keep, np.asarray(line_starts, dtype=np.intp), dtype=np.int64)
    shift = np.cumsum(dropped)
    shift -= dropped                                              # bytes dropped before each line
    return block[keep], line_starts - shift


def _face_references(src, block: np.ndarray, line_starts: np.ndarray, line_numbers):
    """The vertex references of the face block as int64 and the count per line (at least 3 each)."""
    parsed = _fast_integers(block, line_starts)
    if parsed is not None:
        refs, sizes = parsed
        short = np.flatnonzero(sizes < 3)
        if short.size:
            raise _obj_error(src, f"line {int(line_numbers()[short[0]])} is a face with "
                                  f"{int(sizes[short[0]])} vertex reference(s); a face needs at least 3.")
        return refs, sizes
    del parsed
    values, sizes = _row_values(src, block.tobytes(), line_numbers(), "face ('f')", "face",
                                "vertex reference(s)", "a face needs at least 3")
    with np.errstate(invalid="ignore"):
        whole = np.isfinite(values) & (values == np.round(values)) & (np.abs(values) < 2.0 ** 62)
    if not whole.all():
        k = int(np.argmax(~whole))
        poly = int(np.searchsorted(np.cumsum(sizes), k, side="right"))
        raise _obj_error(src, f"line {int(line_numbers()[poly])} refers to vertex {float(values[k]):.15g}, "
                              "which is not a whole number.")
    return values.astype(np.int64), sizes


def _faces(src, block: np.ndarray, line_starts: np.ndarray, is_v, is_f, max_faces: int) -> np.ndarray:
    def line_numbers():
        return np.flatnonzero(is_f) + 1

    refs, sizes = _face_references(src, block, line_starts, line_numbers)
    del block
    _check_faces(int(sizes.sum()) - 2 * sizes.size, max_faces, "The OBJ faces split into")
    n_vertices = int(is_v.sum())
    index = refs                                        # turned into 0-based indices in place
    negative = np.flatnonzero(refs < 0)
    before = None
    if negative.size:                                   # relative to the 'v' lines before the face line
        defined_before = (np.cumsum(is_v) - is_v)[is_f]
        poly = np.searchsorted(np.cumsum(sizes), negative, side="right")
        before = defined_before[poly]
        index[negative] += before + 1
    index -= 1                                          # OBJ counts from 1
    bad = (index < 0) | (index >= n_vertices)          # a 0 reference is -1 here
    if bad.any():
        k = int(np.argmax(bad))
        poly = int(np.searchsorted(np.cumsum(sizes), k, side="right"))
        line = int(line_numbers()[poly])
        ref = _original_reference(src, index, k, negative, before)
        if ref == 0:
            why = "vertex 0 (OBJ counts vertices from 1)"
        elif ref < 0:
            n_before = int(before[np.searchsorted(negative, k)])
            why = (f"vertex {ref}, {-ref} back from the last of the {n_before:,} vertices defined "
                   "before it")
        else:
            why = f"vertex {ref}, but the file defines only {n_vertices:,} vertices"
        raise _obj_error(src, f"the face on line {line} refers to {why}; {int(bad.sum()):,} vertex "
                              "reference(s) are out of range. The file is damaged or incomplete.")
    return _fan_triangles(index, sizes, max_faces, "The OBJ faces split into", owned=True)


def _original_reference(src, index, k: int, negative, before) -> int:
    """The reference as the file wrote it, from its 0-based index (error path only)."""
    at = np.searchsorted(negative, k)
    if at < negative.size and negative[at] == k:
        return int(index[k]) - int(before[at])
    return int(index[k]) + 1
