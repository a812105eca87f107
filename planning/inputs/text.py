"""Stage 1, the cloud: the text reader (XYZ, CSV, TXT: one point per row).

The first row of at least three numbers (after at most 1000 header lines, ``#`` and ``//``
comments skipped, a UTF-8 byte order mark dropped) fixes the layout: whitespace, comma or
semicolon separated, decimal commas when a row holds both ``;`` and ``,``. The rows are counted
against ``max_points`` before they are parsed, then parsed by numpy's C ``loadtxt`` (columns 1-3
are x y z, 4-6 the normals when asked for; extra columns are ignored). Errors name the file line:
``unreadable_file`` (binary bytes, a word among the numbers, a short row), ``empty_cloud`` (no
row of numbers), ``missing_normals`` (normals asked for, fewer than six columns).
"""

from __future__ import annotations

import io
import re

import numpy as np

from planning.errors import InputError
from planning.inputs.source import _check_count, _Source

_TEXT_HEADER_LINES = 1000      # at most this many non-numeric lines before the data


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


def _has_binary_bytes(data: bytes) -> bool:
    """True if the first 64 KiB hold a control byte other than tab, line feed, VT, FF or CR."""
    sample = np.frombuffer(data[:65536], dtype=np.uint8)
    return bool(((sample < 32) & ~np.isin(sample, (9, 10, 11, 12, 13))).any())


def _reject_binary(data: bytes) -> None:
    if _has_binary_bytes(data):
        raise InputError("The file is in no format that is read here (it is not text and has no "
                         "known signature); it is damaged or in an unsupported format. Export the "
                         "scan as PLY, PCD, XYZ/CSV text, STL, OBJ, LAS/LAZ or E57.",
                         code="unreadable_file")


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
