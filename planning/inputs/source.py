"""Stage 1, the cloud: the input bytes and the size limits every reader checks.

:class:`_Source` holds a cloud given as bytes or as a path: the first MiB (``head``, where every
header must end) is read at once, the whole body only when a reader asks for it, so a header that
claims billions of points fails before the body is read. :func:`_check_bytes` (``max_bytes``,
``file_too_large``), :func:`_check_count` (``max_points``, ``too_many_points``) and
:func:`_check_faces` (``max_faces``, ``too_many_faces``) raise :class:`~planning.errors.InputTooLarge`
(HTTP 413) with the limit and what to do about it.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from planning.errors import InputError, InputTooLarge, ParameterError

_HEAD_BYTES = 1 << 20          # headers must end within the first MiB


class _Source:
    """The input bytes: the first MiB (``head``) for headers, ``data()`` for the whole body."""

    def __init__(self, name: str | None, size: int, head: bytes, path: Path | None,
                 data: bytes | None):
        self.name, self.size, self.head, self._path, self._data = name, size, head, path, data

    @classmethod
    def open(cls, source, max_bytes: int | None) -> _Source:
        if isinstance(source, (bytes, bytearray, memoryview)):
            data = bytes(source)
            _check_bytes(len(data), max_bytes)
            return cls(None, len(data), data[:_HEAD_BYTES], None, data)
        if not isinstance(source, (str, os.PathLike)):
            raise ParameterError("source must be a file path or bytes, got "
                                 f"{type(source).__name__}.",
                                 parameter="source")
        path = Path(source)
        try:
            size = path.stat().st_size
            _check_bytes(size, max_bytes)
            with open(path, "rb") as fh:
                head = fh.read(_HEAD_BYTES)
        except OSError as exc:
            raise InputError(f"Cannot open the cloud file {path.name!r}: {exc.strerror or exc}.",
                             code="unreadable_file") from exc
        return cls(path.name, size, head, path, head if size <= len(head) else None)

    def data(self) -> bytes:
        if self._data is None:
            try:
                self._data = self._path.read_bytes()
            except OSError as exc:
                raise InputError(f"Cannot read the cloud file {self.name!r}: {exc}.",
                                 code="unreadable_file") from exc
        return self._data

    @contextlib.contextmanager
    def file(self) -> Iterator[BinaryIO]:
        """A binary file object of the whole input (the file itself, or the bytes in memory)."""
        if self._data is not None or self._path is None:
            yield io.BytesIO(self.data())
            return
        try:
            fh = open(self._path, "rb")
        except OSError as exc:
            raise InputError(f"Cannot read the cloud file {self.name!r}: {exc}.",
                             code="unreadable_file") from exc
        with fh:
            yield fh

    @contextlib.contextmanager
    def local_path(self, suffix: str = "") -> Iterator[Path]:
        """A path on disk holding the input (for libraries that open files by name): the file
        itself, or the bytes written to a temporary file that is removed afterwards."""
        if self._path is not None:
            yield self._path
            return
        with tempfile.TemporaryDirectory(prefix="scanmill-input-") as folder:
            path = Path(folder) / f"input{suffix}"
            path.write_bytes(self.data())
            yield path

    @property
    def quoted(self) -> str:
        """The file name quoted for messages, after a space (`` 'scan.e57'``); '' for bytes."""
        return f" {self.name!r}" if self.name else ""

    @property
    def suffix(self) -> str:
        return Path(self.name).suffix.lower() if self.name else ""


def _check_bytes(size: int, max_bytes: int | None) -> None:
    if max_bytes is not None and size > max_bytes:
        raise InputTooLarge(
            f"The cloud file is {size:,} bytes; the limit is {max_bytes:,} bytes. Decimate the "
            "scan (or save it as binary PLY, which is smaller) and submit it again.",
            code="file_too_large", size_bytes=int(size), max_bytes=int(max_bytes))


def _check_count(n: int, max_points: int) -> None:
    if n > max_points:
        raise InputTooLarge(
            f"The cloud has {n:,} points; the limit is {max_points:,}. Decimate the scan "
            "(e.g. a voxel grid of 0.2-0.5 mm) and submit it again.",
            code="too_many_points", n_points=int(n), max_points=int(max_points))


def _check_faces(n: int, max_faces: int, what: str = "The mesh has") -> None:
    """Refuse a mesh of more than ``max_faces`` triangles (``what`` starts the message, e.g. "The PLY
    header declares at least")."""
    if n > max_faces:
        raise InputTooLarge(
            f"{what} {n:,} triangles; the limit input.max_faces is {max_faces:,}. Decimate the mesh "
            "(or raise input.max_faces) and submit it again.",
            code="too_many_faces", n_faces=int(n), max_faces=int(max_faces), parameter="input.max_faces")


@contextlib.contextmanager
def quiet_native_stderr():
    """Send what native code writes to stderr (file descriptor 2) while reading to a scratch file: a
    Rust panic in lazrs prints its message and a backtrace there, libtiff its complaints about a damaged
    strip, before the reader raises (and the failure is answered as a typed error, one line). The
    descriptor is the process's: the CLI reads in its one thread, the service in child processes."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):        # no usable stderr: nothing to keep quiet
        yield
        return
    try:
        with tempfile.TemporaryFile() as scratch:
            os.dup2(scratch.fileno(), 2)
            try:
                yield
            finally:
                os.dup2(saved, 2)
    finally:
        os.close(saved)
