"""Stage 1, the cloud: decoding helpers shared by the PLY and PCD readers.

Ascii bodies of PLY and PCD files hold one point per line with a fixed number of values:
:func:`_line_block` cuts the lines of an element out of the body, :func:`_parse_numbers` parses
them at once with ``numpy.fromstring`` (vectorised, no Python loop per point) and, only when that
fails, finds the row to blame (``truncated_file`` for a cut-off last row, else
``unreadable_file``). :func:`_fast_integers` parses a block of whole numbers (OBJ face references)
with an integer ``numpy.fromstring``, several times faster than parsing them as floats, a few MiB at
a time into one preallocated array. :func:`_xyz` and :func:`_normals_from` take ``(N, 3)`` float64 columns out
of a structured vertex table (coordinates as stored in the file, before unit scaling).
"""

from __future__ import annotations

import itertools

import numpy as np

from planning.errors import InputError


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


_INT_CHUNK = 4 << 20            # bytes of text parsed per numpy.fromstring call by _fast_integers


def _fast_integers(arr: np.ndarray, line_starts: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """All whitespace-separated integers of the text ``arr`` (uint8) and how many each of its lines
    holds (``line_starts``: the offset of each line's first byte, increasing from 0); None if some token
    is not an integer (a lone ``+`` or ``-`` included, which ``numpy.fromstring`` would read as 0).

    The tokens are counted per line first (one ``add.reduceat`` over the token starts), the int64 result
    allocated once, and the text parsed a few MiB of whole lines at a time by ``numpy.fromstring`` with
    an integer dtype (5-6 times faster than parsing floats; a value beyond int64 saturates, which the
    caller's range check refuses): about 8 bytes per token plus 3 per byte of text at the peak.
    """
    arr = np.asarray(arr, dtype=np.uint8).reshape(-1)
    line_starts = np.asarray(line_starts, dtype=np.intp).reshape(-1)
    if arr.size == 0 or line_starts.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    word = _WHITESPACE[arr]
    np.logical_not(word, out=word)
    first = np.empty_like(word)
    first[0] = word[0]
    np.greater(word[1:], word[:-1], out=first[1:])      # the first byte of each token
    alone = first.copy()                                # one-byte tokens: a lone sign would parse as 0
    alone[:-1] &= ~word[1:]
    del word
    if alone.any() and bool(np.isin(arr[alone], (43, 45)).any()):
        return None
    del alone
    counts = np.add.reduceat(first, line_starts, dtype=np.int64)
    del first
    before = np.cumsum(counts)
    values = np.empty(int(before[-1]), dtype=np.int64)
    before -= counts                                      # tokens before each line
    cuts = np.unique(np.searchsorted(line_starts, np.arange(0, arr.size, _INT_CHUNK)))
    cuts = np.append(cuts[cuts < line_starts.size], line_starts.size)     # whole lines per chunk
    for a, b in itertools.pairwise(cuts):
        end = int(line_starts[b]) if b < line_starts.size else arr.size
        first_token = int(before[a])
        last_token = int(before[b]) if b < line_starts.size else values.size
        if last_token == first_token:                      # blank lines only
            continue
        try:
            part = np.fromstring(arr[int(line_starts[a]):end].tobytes().decode("latin-1"), dtype=np.int64,
                                 sep=" ")
        except ValueError:
            return None
        if part.size != last_token - first_token:
            return None
        values[first_token:last_token] = part
    return values, counts


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
