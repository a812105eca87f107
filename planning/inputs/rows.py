"""Stage 1, the cloud: decoding helpers shared by the PLY and PCD readers.

Ascii bodies of PLY and PCD files hold one point per line with a fixed number of values:
:func:`_line_block` cuts the lines of an element out of the body, :func:`_parse_numbers` parses
them at once with ``numpy.fromstring`` (vectorised, no Python loop per point) and, only when that
fails, finds the row to blame (``truncated_file`` for a cut-off last row, else
``unreadable_file``). :func:`_xyz` and :func:`_normals_from` take ``(N, 3)`` float64 columns out
of a structured vertex table (coordinates as stored in the file, before unit scaling).
"""

from __future__ import annotations

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
