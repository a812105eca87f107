"""Stage 1, the cloud: the LAS / LAZ reader (ASPRS lidar point files) via laspy.

The header (``LASF`` signature) gives the point count, checked against ``max_points`` before any
point is decoded; ``x y z`` are the scaled coordinates (raw integers x scale + offset) as float64, in
the unit of the file (``input.units``). LAZ (compressed) is decompressed by laspy's ``lazrs`` backend;
the label says which (``las`` or ``laz``). No normals are read (``normals`` None), no faces.
Errors: ``truncated_file`` (an uncompressed body shorter than the header's count needs, or a LAZ
stream that ends early), ``unreadable_file`` (laspy cannot parse the header or the points; its
message is passed on), ``unsupported_format`` (LAZ without a decompression backend),
``empty_cloud`` (0 points), ``too_many_points``.
"""

from __future__ import annotations

import re

import numpy as np

from planning.errors import InputError, PlanningError
from planning.inputs.source import _check_count, _Source

_TRUNCATED = re.compile(r"fill whole buffer|end of file|eof|unexpected end|truncat|not enough|"
                        r"multiple of element size", re.I)


def _las_error(src: _Source, msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Invalid LAS/LAZ file{src.quoted}: {msg}", code=code)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__).rstrip(".")


def _read_las(src: _Source, max_points: int):
    import laspy

    if not src.head.startswith(b"LASF"):
        raise _las_error(src, "it does not start with the 'LASF' signature; it is not a LAS file.")
    with src.file() as fh:
        try:
            reader = laspy.open(fh, closefd=False)
        except Exception as exc:  # noqa: BLE001 - laspy raises LaspyException, ValueError, struct errors
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
                record = reader.read_points(n)
                points = np.column_stack((np.asarray(record.x, dtype=np.float64),
                                          np.asarray(record.y, dtype=np.float64),
                                          np.asarray(record.z, dtype=np.float64)))
            except PlanningError:
                raise
            except Exception as exc:  # noqa: BLE001 - lazrs errors, ValueError from short buffers ...
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
