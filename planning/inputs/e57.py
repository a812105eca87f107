"""Stage 1, the cloud: the E57 reader (ASTM E2807 3D imaging files) via pye57 (libE57Format).

Every scan of the file (``data3D``) is read and moved into the file's frame by its pose (the unit
quaternion ``w x y z`` of ``pose.rotation`` and ``pose.translation``; identity where a scan has no
pose), and the scans are joined into one cloud. Cartesian coordinates are read as they are,
spherical ones (range, azimuth, elevation) converted; points whose ``cartesianInvalidState`` /
``sphericalInvalidState`` is not 0 are dropped. A structured scan (``rowIndex`` and ``columnIndex``
present) also gives faces: two triangles per 2x2 block of grid positions whose four points exist,
unless one of its sides is longer than :data:`JUMP_FACTOR` times the median grid edge of that scan
(a depth jump between two surfaces). The coordinates are taken in ``input.units``: the E57 standard
stores metres, so a standard file is read with ``input.units = "m"``.

The file header (``ASTM-E57`` signature, physical length) is checked first, then the point counts of
all scans against ``max_points`` and each scan's count against the file size (its record prototype
gives the fewest bits a point takes: 32 or 64 per float field, the bits of the range of an integer
field) before any point is decoded. The points are then decoded in chunks of at most
:data:`CHUNK_POINTS`, so a count that the data does not hold allocates only one chunk before the scan
ends early; the grid faces are checked against ``max_faces``. Errors: ``truncated_file`` (the file is
shorter than its header says, a scan's declared points cannot fit in it or end early),
``unreadable_file`` (libE57Format's own message, first line, with the file name), ``empty_cloud`` (no
scan or no valid point), ``too_many_points``, ``too_many_faces``.
"""

from __future__ import annotations

import struct

import numpy as np

from planning.errors import InputError, PlanningError
from planning.inputs.mesh import _grid_triangles
from planning.inputs.source import _check_count, _check_faces, _Source

#: A grid cell with a side longer than this x the median grid edge spans a depth jump: no faces.
JUMP_FACTOR = 4.0
#: Most points decoded at once (the buffers of one chunk: about 35 bytes a point).
CHUNK_POINTS = 1 << 20

_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
_GRID = ("rowIndex", "columnIndex")


def _e57_error(src: _Source, msg: str, code: str = "unreadable_file") -> InputError:
    return InputError(f"Invalid E57 file{src.quoted}: {msg}", code=code)


def _first_line(exc: BaseException) -> str:
    for line in str(exc).strip().splitlines():
        if line.strip() and not line.startswith("*"):
            return line.strip().rstrip(".")
    return type(exc).__name__


def _check_file_header(src: _Source) -> None:
    head = src.head
    if not head.startswith(b"ASTM-E57"):
        raise _e57_error(src, "it does not start with the 'ASTM-E57' signature; it is not an E57 file.")
    if len(head) < 48:
        raise _e57_error(src, f"the file is {src.size} bytes, shorter than the 48-byte E57 header; it "
                              "was cut off.", code="truncated_file")
    physical = struct.unpack_from("<Q", head, 16)[0]
    if src.size < physical:
        raise _e57_error(src, f"the header says the file is {physical:,} bytes but it holds "
                              f"{src.size:,}; it was cut off during transfer or export. Send the "
                              "complete file.", code="truncated_file")
    if src.size > physical:
        raise _e57_error(src, f"the header says the file is {physical:,} bytes but it holds "
                              f"{src.size:,}; the file is damaged.")


def _rotation(q) -> np.ndarray:
    """Rotation matrix of the quaternion ``(w, x, y, z)`` (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _read_e57(src: _Source, max_points: int, max_faces: int = 10_000_000):
    _check_file_header(src)
    import pye57

    with src.local_path(".e57") as path:
        try:
            e57 = pye57.E57(str(path))
        except Exception as exc:  # noqa: BLE001 - libE57Format's E57Exception and others
            raise _e57_error(src, f"{_first_line(exc)}; the file is damaged. Export it again.") from None
        try:
            return _read_scans(src, e57, max_points, max_faces)
        except PlanningError:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged file must not become a crash
            raise _e57_error(src, f"{_first_line(exc)}; the file is damaged. Export it again.") from None
        finally:
            e57.close()


def _read_scans(src: _Source, e57, max_points: int, max_faces: int):
    headers = [e57.get_header(i) for i in range(e57.scan_count)]         # a few scans, not points
    total = sum(int(h.point_count) for h in headers)
    _check_count(total, max_points)
    if total == 0:
        raise InputError(f"The E57 file{src.quoted} holds no scanned points; the cloud is empty.",
                         code="empty_cloud")
    for index, header in enumerate(headers):
        n, bits = int(header.point_count), _min_record_bits(header)
        if n * bits > 8 * src.size:
            raise _e57_error(src, f"scan {index} declares {n:,} points of at least {bits} bits each "
                                  f"({n * bits // 8:,} bytes), more than the {src.size:,} bytes of the file; "
                                  "the file was cut off or its header is damaged. Send the complete file.",
                             code="truncated_file")
    parts, faces, offset = [], [], 0
    for index, header in enumerate(headers):
        if int(header.point_count) == 0:
            continue
        points, grid = _read_scan(src, e57, header, index)
        points = points @ _rotation(header.rotation).T + np.asarray(header.translation, dtype=np.float64)
        if grid is not None:
            tri = _grid_triangles(grid[0], grid[1], points, JUMP_FACTOR)
            faces.append(tri + offset)
        parts.append(points)
        offset += points.shape[0]
    if offset == 0:
        raise InputError(f"The E57 file{src.quoted} holds no valid point (every point is flagged "
                         "invalid); the cloud is empty.", code="empty_cloud")
    points = np.concatenate(parts) if len(parts) > 1 else parts[0]
    _check_faces(sum(len(f) for f in faces), max_faces, "The scan grids of the E57 file make")
    tri = (np.concatenate(faces) if len(faces) > 1 else faces[0]) if faces else None
    return points, None, tri, "e57"


def _min_record_bits(header) -> int:
    """The fewest bits one point of the scan takes in the file, from its record prototype (0 if unknown):
    32 or 64 per float field, the bit length of ``maximum - minimum`` per (scaled) integer field."""
    from pye57 import libe57
    from pye57.utils import get_node

    try:
        proto = libe57.StructureNode(header.points.prototype())
        bits = 0
        for i in range(proto.childCount()):
            node = get_node(proto, proto.get(i).elementName())
            if isinstance(node, libe57.FloatNode):
                bits += 32 if "SINGLE" in str(node.precision()).upper() else 64
            elif isinstance(node, (libe57.IntegerNode, libe57.ScaledIntegerNode)):
                bits += max(int(node.maximum()) - int(node.minimum()), 0).bit_length()
        return bits
    except Exception:  # noqa: BLE001 - an odd prototype: no bound from it (the chunks bound the memory)
        return 0


def _read_scan(src: _Source, e57, header, index: int):
    """The valid points of one scan in its own frame, and its (row, column) grid or None."""
    fields = set(header.point_fields)
    if all(f in fields for f in _CARTESIAN):
        coords, state = _CARTESIAN, "cartesianInvalidState"
    elif all(f in fields for f in _SPHERICAL):
        coords, state = _SPHERICAL, "sphericalInvalidState"
    else:
        raise _e57_error(src, f"scan {index} has neither cartesianX/Y/Z nor sphericalRange/Azimuth/"
                              f"Elevation fields (it has {', '.join(sorted(fields))}).")
    wanted = list(coords) + [state] * (state in fields) + \
        (list(_GRID) if all(f in fields for f in _GRID) else [])
    n = int(header.point_count)
    data = _read_chunks(src, e57, header, wanted, n, index)
    valid = np.ones(n, dtype=bool) if state not in data else data[state] == 0
    if coords is _CARTESIAN:
        pts = np.column_stack([np.asarray(data[f], dtype=np.float64)[valid] for f in coords])
    else:
        rng, az, el = (np.asarray(data[f], dtype=np.float64)[valid] for f in coords)
        pts = np.column_stack((rng * np.cos(el) * np.cos(az), rng * np.cos(el) * np.sin(az),
                               rng * np.sin(el)))
    grid = None
    if "rowIndex" in data:
        grid = (data["rowIndex"][valid].astype(np.int64), data["columnIndex"][valid].astype(np.int64))
    return pts, grid


def _read_chunks(src: _Source, e57, header, wanted, n: int, index: int) -> dict:
    """The ``wanted`` fields of the scan's ``n`` points, decoded :data:`CHUNK_POINTS` at a time."""
    chunk = max(min(n, CHUNK_POINTS), 1)
    buffer, buffers = e57.make_buffers(wanted, chunk)
    parts: dict[str, list] = {f: [] for f in wanted}
    got = 0
    reader = header.points.reader(buffers)
    try:
        while got < n:
            k = int(reader.read())
            if k <= 0:
                break
            k = min(k, n - got)
            for f in wanted:
                parts[f].append(buffer[f][:k].copy())
            got += k
    finally:
        reader.close()
    if got < n:
        raise _e57_error(src, f"scan {index} declares {n:,} points but only {got:,} could be read; the "
                              "file was cut off or is damaged.", code="truncated_file")
    return {f: (np.concatenate(v) if len(v) > 1 else v[0]) for f, v in parts.items()}
