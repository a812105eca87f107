"""The report, after the last stage: the plan's files on disk, atomic writes and the PLY writer (mm).

:func:`atomic_path` yields a temporary path next to the target and moves it into place with
``os.replace`` once the caller has written it, so a file appears complete or not at all; the
plan's files (:mod:`planning.report.plan_files`, :mod:`planning.report.preview`), the service's
stored uploads and ``scanmill sample`` go through it. :func:`write_ply` writes points (mm, double
``x y z``) with optional normals, colours and integer labels as binary little endian or ascii PLY
(round-trip exact ``%.17g``): the segmentation PLY of a plan, the samples written by
``scanmill sample`` and the clouds the service stores, all readable again by stage 1
(:func:`planning.inputs.cloud.read_cloud`).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import zipfile
from pathlib import Path
from typing import Iterator

import numpy as np

from planning.errors import ParameterError

__all__ = ["NPZ_LEVEL", "atomic_path", "savez_compressed", "write_ply"]


def write_ply(path, points, *, colors=None, normals=None, labels=None, binary: bool = True,
              single: bool = False) -> None:
    """Write points (mm, stored as double ``x y z``, or float with ``single``) to a PLY file, atomically.

    ``single`` halves the coordinates' bytes for files that are looked at, not planned from (the
    segmentation PLY): float keeps 24 bits, under 0.00005 mm on a part within +-400 mm, far below a
    scanner's noise; files read back for planning (samples, the service's stored clouds) keep double.

    Optional per-point ``colors`` ``(N, 3)`` 0-255 (uchar ``red green blue``), ``normals``
    ``(N, 3)`` (double ``nx ny nz``) and ``labels`` ``(N,)`` integers (int ``label``).
    ``binary=True`` writes binary little endian, otherwise ascii (round-trip exact ``%.17g``).
    The file appears complete or not at all (temporary file in the same folder + ``os.replace``).
    """
    vertex = _vertex_table(points, colors, normals, labels, "<f4" if single else "<f8")
    header = _ply_header(vertex, binary)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            if binary:
                vertex.tofile(fh)
            else:
                _write_ascii_rows(fh, vertex)


#: zlib level of the plan's npz files (plan.npz, the moves npz): 1 takes about a third of the time of
#: np.savez_compressed's default (6) for ~13 % more bytes (femur plan.npz: 0.67 s / 8.96 MB against
#: 1.83 s / 7.93 MB); the arrays are the same.
NPZ_LEVEL = 1
#: Every member's zip time: the same arrays give the same bytes (the zip format's earliest date).
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def savez_compressed(file, arrays: dict[str, np.ndarray], level: int = NPZ_LEVEL, *,
                     allow_pickle: bool = False) -> None:
    """:func:`numpy.savez_compressed` (one ``<name>.npy`` member per array, deflated, zip64) at zlib
    ``level``, each member streamed (no copy of a large array) and stamped with a fixed time, so the
    same arrays give the same bytes; :func:`numpy.load` reads it back the same."""
    with zipfile.ZipFile(file, mode="w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
        for name, val in arrays.items():
            info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info._compresslevel = level       # what ZipFile(compresslevel=) sets on the members it names
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(val), allow_pickle=allow_pickle)


@contextlib.contextmanager
def atomic_path(path) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success move it onto ``path`` atomically.

    The temporary file already exists (created with the usual umask permissions, unlike
    ``mkstemp``'s 0600) and may be overwritten by the caller. On any exception it is removed
    and ``path`` is left untouched.
    """
    target = Path(path)
    tmp = _reserve_temp(target)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _reserve_temp(target: Path) -> Path:
    for _ in range(100):
        tmp = target.with_name(f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
        try:
            open(tmp, "xb").close()
            return tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"cannot create a temporary file next to {target}")


def _per_point(name: str, values, n: int, width: int | None) -> np.ndarray:
    arr = np.asarray(values)
    shape = (n, width) if width else (n,)
    if arr.shape != shape:
        raise ParameterError(f"{name} must have shape {shape}, got {arr.shape}.", parameter=name)
    return arr


def _vertex_table(points, colors, normals, labels, coord: str = "<f8") -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ParameterError(f"points must have shape (N, 3), got {pts.shape}.", parameter="points")
    n = pts.shape[0]
    fields = [("x", coord), ("y", coord), ("z", coord)]
    cols = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2]}
    if normals is not None:
        nrm = _per_point("normals", normals, n, 3).astype(np.float64)
        fields += [("nx", "<f8"), ("ny", "<f8"), ("nz", "<f8")]
        cols.update(nx=nrm[:, 0], ny=nrm[:, 1], nz=nrm[:, 2])
    if colors is not None:
        rgb = _per_point("colors", colors, n, 3)
        if rgb.size and (np.any(rgb < 0) or np.any(rgb > 255)):
            raise ParameterError("colors must be in 0..255.", parameter="colors")
        rgb = np.rint(rgb).astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        cols.update(red=rgb[:, 0], green=rgb[:, 1], blue=rgb[:, 2])
    if labels is not None:
        lab = _per_point("labels", labels, n, None)
        if not (np.issubdtype(lab.dtype, np.integer) or lab.dtype == bool):
            raise ParameterError(f"labels must be integers, got {lab.dtype}.", parameter="labels")
        if lab.size and (lab.min() < np.iinfo(np.int32).min or lab.max() > np.iinfo(np.int32).max):
            raise ParameterError("labels must fit a 32-bit integer.", parameter="labels")
        fields.append(("label", "<i4"))
        cols["label"] = lab.astype(np.int32)
    table = np.empty(n, dtype=fields)
    for name, col in cols.items():
        table[name] = col
    return table


_PLY_NAMES = {"f8": "double", "f4": "float", "u1": "uchar", "i4": "int"}


def _ply_header(table: np.ndarray, binary: bool) -> bytes:
    fmt = "binary_little_endian" if binary else "ascii"
    lines = ["ply", f"format {fmt} 1.0", "comment scanmill point cloud, units mm",
             f"element vertex {table.shape[0]}"]
    for name in table.dtype.names:
        lines.append(f"property {_PLY_NAMES[table.dtype[name].str[1:]]} {name}")
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def _write_ascii_rows(fh, table: np.ndarray) -> None:
    if table.shape[0]:
        fmts = ["%.17g" if table.dtype[n].kind == "f" else "%d" for n in table.dtype.names]
        np.savetxt(fh, table, fmt=fmts)
