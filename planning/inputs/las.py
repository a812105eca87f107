"""Stage 1, the cloud: the LAS / LAZ reader (ASPRS lidar point files) via laspy.

The header (``LASF`` signature, version 1.0 to 1.4, sizes and record counts checked first: laspy
trusts them) gives the point count, checked against ``max_points`` before any point is decoded, and
for an uncompressed file ``count x record length`` against the file size. laspy allocates ``count x
record length`` bytes for every read, so the points are read in chunks of at most
:data:`CHUNK_BYTES` of records (:meth:`laspy.LasReader.read_points` called per chunk): a LAZ whose
header claims millions of points its compressed data does not hold fails at the first chunk that
runs dry, having allocated one chunk. ``x y z`` are the scaled coordinates (raw integers x scale +
offset) as float64, in the unit of the file (``input.units``). LAZ (compressed) is decompressed by
laspy's sequential ``lazrs`` backend (the parallel one sizes its buffers from the chunk table
unchecked: a damaged table made it abort the whole process); the LAZ chunk count is checked first
for the same reason. The label says which (``las`` or ``laz``). No normals are read (``normals``
None), no faces. What laspy logs while reading (e.g. "Could only read ... points") and what lazrs
prints to stderr when it panics are kept off the console: the error says it. The LASzip record's
items are checked first (their types' sizes, adding up to the point record length): lazrs panics
when they disagree with the data.
Errors: ``truncated_file`` (an uncompressed body shorter than the header's count needs, or a LAZ
stream that ends early), ``unreadable_file`` (laspy cannot parse the header or the points; its
message is passed on), ``unsupported_format`` (LAZ without a decompression backend),
``empty_cloud`` (0 points), ``too_many_points``.
"""

from __future__ import annotations

import contextlib
import logging
import re
import struct

import numpy as np

from planning.errors import InputError, PlanningError
from planning.inputs.source import _check_count, _Source, quiet_native_stderr

#: Most bytes of point records decoded at once.
CHUNK_BYTES = 64 << 20
_VLR_HEADER = 54                # bytes of a variable length record's header
_EVLR_HEADER = 60               # ... and of an extended one's
_TRUNCATED = re.compile(r"fill whole buffer|end of file|eof|unexpected end|truncat|not enough|"
                        r"multiple of element size", re.I)


def _las_error(src: _Source, msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Invalid LAS/LAZ file{src.quoted}: {msg}", code=code)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__).rstrip(".")


def _check_header(src: _Source) -> None:
    """Check the public header block's sizes and counts before laspy reads it.

    laspy trusts them: a damaged header that claims billions of VLRs would keep it reading past the
    end of the file for hours. So the VLRs (54 bytes each at least) must fit between the header and
    the point data, the EVLRs (60 bytes each) between their start and the end of the file.
    """
    head = src.head
    if not head.startswith(b"LASF"):
        raise _las_error(src, "it does not start with the 'LASF' signature; it is not a LAS file.")
    if len(head) < 26 or head[24] != 1 or head[25] > 4:
        version = f"{head[24]}.{head[25]}" if len(head) >= 26 else "unknown"
        raise _las_error(src, f"its header says LAS version {version}; versions 1.0 to 1.4 are read. "
                              "The file is damaged or not a LAS file.")
    minor = head[25]
    minimum = 375 if minor >= 4 else (235 if minor == 3 else 227)
    if src.size < minimum:
        raise _las_error(src, f"the file is {src.size} bytes, shorter than the {minimum}-byte LAS "
                              f"1.{minor} header; it was cut off.", code="truncated_file")
    header_size, point_offset, n_vlrs = struct.unpack_from("<HII", head, 94)
    point_format = head[104] & 0x3F
    if header_size < minimum or point_offset < header_size:
        raise _las_error(src, f"its header size ({header_size}) or point data offset ({point_offset}) "
                              "is impossible; the header is damaged.")
    if point_offset > src.size:
        raise _las_error(src, f"the point data should start at byte {point_offset:,} but the file holds "
                              f"{src.size:,} bytes; it was cut off.", code="truncated_file")
    if n_vlrs * _VLR_HEADER > point_offset - header_size:
        raise _las_error(src, f"the header declares {n_vlrs:,} variable length records, which cannot fit "
                              f"in the {point_offset - header_size:,} bytes before the point data; the "
                              "header is damaged.")
    if point_format > 10:
        raise _las_error(src, f"point data format {point_format} does not exist (0 to 10); the header is "
                              "damaged.")
    n_points = struct.unpack_from("<I", head, 107)[0]
    if minor >= 4:
        evlr_start, n_evlrs, n_points_14 = struct.unpack_from("<QIQ", head, 235)
        n_points = n_points_14 or n_points
        if n_evlrs and (evlr_start > src.size or n_evlrs * _EVLR_HEADER > src.size - evlr_start):
            raise _las_error(src, f"the header declares {n_evlrs:,} extended records from byte "
                                  f"{evlr_start:,}, beyond the {src.size:,} bytes of the file; it is cut "
                                  "off or damaged.", code="truncated_file")
    if head[104] & 0x80:
        _check_laszip_items(src, header_size, n_vlrs, struct.unpack_from("<H", head, 105)[0])
        _check_chunk_table(src, point_offset, n_points)


#: bytes of the LASzip item types of a fixed size (0 and 14, extra bytes, take any size)
_LAZ_ITEM_SIZES = {6: 20, 7: 8, 8: 6, 9: 29, 10: 30, 11: 6, 12: 8, 13: 29}


def _check_laszip_items(src: _Source, header_size: int, n_vlrs: int, record_length: int) -> None:
    """LAZ: the LASzip VLR's items must have their types' sizes and add up to the point record length
    (lazrs splits every record by the declared sizes and panics when they disagree with the data)."""
    head, pos = src.head, header_size
    for _ in range(n_vlrs):
        if pos + _VLR_HEADER > len(head):
            return                                       # beyond the first MiB: laspy reads and checks it
        user_id, record_id, length = struct.unpack_from("<16sHH", head, pos + 2)
        body = pos + _VLR_HEADER
        if user_id.rstrip(b"\0") == b"laszip encoded" and record_id == 22204:
            if length < 34 or body + length > len(head):
                raise _las_error(src, "its LASzip record is cut short; the header is damaged.")
            n_items = struct.unpack_from("<H", head, body + 32)[0]
            if 34 + 6 * n_items > length:
                raise _las_error(src, f"its LASzip record declares {n_items:,} items in {length} bytes; the "
                                      "header is damaged.")
            items = [struct.unpack_from("<HHH", head, body + 34 + 6 * i) for i in range(n_items)]
            wrong = [(t, n) for t, n, _ in items if t in _LAZ_ITEM_SIZES and n != _LAZ_ITEM_SIZES[t]]
            total = sum(n for _, n, _ in items)
            if wrong or total != record_length or any(t not in _LAZ_ITEM_SIZES and t not in (0, 14)
                                                       for t, _, _ in items):
                raise _las_error(src, f"its LASzip items (type, bytes: {', '.join(f'{t}, {n}' for t, n, _ in items)}) "
                                      f"do not make its {record_length}-byte point records; the header is "
                                      "damaged.")
            return
        pos = body + length


def _check_chunk_table(src: _Source, point_offset: int, n_points: int) -> None:
    """LAZ: the chunk table's chunk count must be possible (lazrs allocates it unchecked and aborts the
    whole process when the allocation fails). Every chunk holds a point and at least a byte."""
    with src.file() as fh:
        fh.seek(point_offset)
        raw = fh.read(8)
        if len(raw) < 8:
            raise _las_error(src, "the compressed point data is missing; the file was cut off.",
                             code="truncated_file")
        table = struct.unpack("<q", raw)[0]
        if table == -1:                                 # written last: its offset ends the file
            fh.seek(max(src.size - 8, 0))
            table = struct.unpack("<q", fh.read(8).rjust(8, b"\0"))[0]
        if not point_offset + 8 <= table <= src.size - 8:
            raise _las_error(src, f"the LAZ chunk table should be at byte {table:,}, outside the "
                                  f"{src.size:,} bytes of the file; the file is cut off or damaged.",
                             code="truncated_file" if table > src.size else "unreadable_file")
        fh.seek(table)
        _, n_chunks = struct.unpack("<II", fh.read(8))
    if n_chunks > max(1, min(n_points, src.size)):
        raise _las_error(src, f"the LAZ chunk table declares {n_chunks:,} chunks for {n_points:,} points "
                              f"in {src.size:,} bytes; the file is damaged.")


@contextlib.contextmanager
def _quiet_laspy():
    """Keep laspy's log records off the console while reading (they would reach stderr through the
    logging module's last-resort handler when nothing else handles them)."""
    log = logging.getLogger("laspy")
    sink = logging.NullHandler()
    propagate = log.propagate
    log.addHandler(sink)
    log.propagate = False
    try:
        yield
    finally:
        log.removeHandler(sink)
        log.propagate = propagate


def _read_las(src: _Source, max_points: int):
    _check_header(src)
    with _quiet_laspy(), quiet_native_stderr():
        return _read_points(src, max_points)


def _read_points(src: _Source, max_points: int):
    import laspy

    with src.file() as fh:
        try:
            reader = laspy.open(fh, closefd=False, laz_backend=laspy.LazBackend.Lazrs)
        except (KeyboardInterrupt, SystemExit):
            raise
        except BaseException as exc:  # noqa: BLE001 - LaspyException, ValueError, lazrs' Rust panics
            raise _las_error(src, f"the header cannot be read ({_first_line(exc)}); the file is "
                                  "damaged. Export it again.") from None
        with reader:
            header = reader.header
            n = int(header.point_count)
            compressed = bool(header.are_points_compressed)
            _check_count(n, max_points)
            if n == 0:
                raise InputError("The LAS file declares 0 points; the cloud is empty.",
                                 code="empty_cloud")
            if not compressed:
                needed = int(header.offset_to_point_data) + n * int(header.point_format.size)
                if src.size < needed:
                    raise _las_error(src, f"the header declares {n:,} points ({needed:,} bytes) but "
                                          f"the file holds {src.size:,} bytes; it was cut off during "
                                          "transfer or export. Send the complete file.",
                                     code="truncated_file")
            try:
                points = _read_chunks(reader, n, int(header.point_format.size))
            except (PlanningError, KeyboardInterrupt, SystemExit):
                raise
            except BaseException as exc:  # noqa: BLE001 - lazrs errors and Rust panics (BaseException)
                text = _first_line(exc)
                if "backend" in text.lower() and compressed:
                    raise InputError("LAZ (compressed LAS) needs the lazrs package to be decompressed; "
                                     "install it (pip install lazrs) or send an uncompressed LAS file.",
                                     code="unsupported_format", format="LAZ") from None
                code = "truncated_file" if _TRUNCATED.search(text) else "unreadable_file"
                raise _las_error(src, f"the points cannot be decoded ({text}); the file is "
                                      f"{'cut off' if code == 'truncated_file' else 'damaged'}. "
                                      "Send the complete file.", code=code) from None
    if points.shape[0] < n:
        raise _las_error(src, f"the header declares {n:,} points but only {points.shape[0]:,} could be "
                              "decoded; the file was cut off. Send the complete file.",
                         code="truncated_file")
    return points, None, None, "laz" if compressed else "las"


def _read_chunks(reader, n: int, record_size: int) -> np.ndarray:
    """``(m, 3)`` float64 coordinates of the first ``m <= n`` points, read :data:`CHUNK_BYTES` of
    records at a time; ``m < n`` when the data runs out first."""
    out = np.empty((0, 3))
    parts, got = [], 0
    step = max(1, CHUNK_BYTES // max(record_size, 1))
    while got < n:
        want = min(step, n - got)
        record = reader.read_points(want)
        k = len(record)
        if k:
            with np.errstate(over="ignore", invalid="ignore"):   # damaged scales: non_finite later
                parts.append(np.column_stack((np.asarray(record.x, dtype=np.float64),
                                              np.asarray(record.y, dtype=np.float64),
                                              np.asarray(record.z, dtype=np.float64))))
        got += k
        if k < want:
            break
    if parts:
        out = np.concatenate(parts) if len(parts) > 1 else parts[0]
    return out
