"""The neutral moves of an area on disk (issue 20): ``area_<i>.moves.json.gz`` and ``area_<i>.moves.npz``.

``area_<i>.moves.json.gz``
    The neutral moves JSON (:mod:`planning.post.neutral`, format ``scanmill-neutral-moves``), gzip
    compressed: ``gzip -dc`` (or :func:`read_moves_text`) gives the JSON text. The gzip stream is
    deterministic: the same text gives the same bytes (header mtime 0, no file name), zlib level
    :data:`JSON_GZ_LEVEL`.

``area_<i>.moves.npz``
    The same document as arrays (:func:`numpy.load` reads it without pickles), format
    :data:`MOVES_NPZ_FORMAT` version :data:`MOVES_NPZ_FORMAT_VERSION`. Every number is the one the JSON
    prints (the same rounded float64 values: lossless, :func:`moves_document` rebuilds the JSON
    document from it and ``json.dumps(..., separators=(",", ":"))`` gives the JSON text byte for byte).
    Every array is little endian; one ``<name>.npy`` member per array, deflated (zlib level
    :data:`NPZ_LEVEL`), zip timestamps fixed (the same moves give the same bytes).

    ========================= =========== ==================================================================
    member                    dtype       meaning
    ========================= =========== ==================================================================
    ``meta``                  ``<U`` 0-d  JSON text: ``npz_format``, ``npz_format_version``, ``codes`` (the
                                          code tables below) and ``document``: the JSON document with every
                                          long list left out (set-up, machine, frame, per operation its name,
                                          tool, feeds, lengths, ``moves.count``, ``arcs.count``, and
                                          ``controlled_machine_mm: true`` where the operation has that list;
                                          per simultaneous operation ``name``, ``tool_number``,
                                          ``radius_mm``, ``count``)
    ``op_start``              (n+1,) i8   moves of operation ``k`` are rows ``op_start[k]:op_start[k+1]``
    ``type``                  (P,) u1     0 rapid, 1 feed, 2 arc (``codes.type``)
    ``use``                   (P,) u1     0 rapid, 1 cut, 2 plunge, 3 retract (``codes.use``)
    ``feed_mm_min``           (P,) f8     the move's feed, NaN for rapids (JSON null)
    ``tip_part_mm``           (P,3) f8    tool-tip end points, part frame
    ``tip_machine_mm``        (P,3) f8    the same, machine frame
    ``controlled_machine_mm`` (P,3) f8    only when some operation has it: the machine's controlled point;
                                          NaN rows for the operations without it
    ``arc_start``             (n+1,) i8   arcs of operation ``k`` are rows ``arc_start[k]:arc_start[k+1]``
    ``arc_move``              (A,) i8     the arc's move index within its operation
    ``arc_direction``         (A,) u1     0 cw, 1 ccw (``codes.direction``)
    ``arc_plane``             (A,) u1     17, 18, 19 (area frame)
    ``arc_normal_part``,      (A,3) f8    the plane's unit normal, part / machine frame
    ``arc_normal_machine``
    ``arc_centre_part_mm``,   (A,3) f8    the arc's centre, part / machine frame
    ``arc_centre_machine_mm``
    ``five_start``            (m+1,) i8   with simultaneous 5-axis operations (the JSON's
                                          ``five_axis_operations``): rows of operation ``j``
    ``five_centre_mm``,       (Q,3) f8    per move the ball centre, the tool tip and the unit tool axis, part
    ``five_tip_mm``,                      frame
    ``five_axis``
    ``five_kind``, ``five_use`` (Q,) u1   the move's kind (0 rapid, 1 feed) and use (as ``use``), the JSON's
                                          integers
    ========================= =========== ==================================================================

    Reading it (numpy only)::

        z = np.load("area_0.moves.npz")
        meta = json.loads(str(z["meta"]))
        for k, op in enumerate(meta["document"].get("operations", [])):
            rows = slice(z["op_start"][k], z["op_start"][k + 1])
            tips = z["tip_part_mm"][rows]

Plan sizes (femur-like reference plan, BENCHMARKS): ``bench/bench_artifacts.py PLAN_DIR`` prints every
artifact's size and, for the moves, the sizes and write times of the JSON, JSON.gz and NPZ.
"""

from __future__ import annotations

import gzip
import io
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from planning.report.files import NPZ_LEVEL, savez_compressed

__all__ = [
    "DIRECTION_CODES",
    "JSON_GZ_LEVEL",
    "MOVES_NPZ_FORMAT",
    "MOVES_NPZ_FORMAT_VERSION",
    "NPZ_LEVEL",
    "TYPE_CODES",
    "USE_CODES",
    "gzip_bytes",
    "moves_document",
    "moves_npz_arrays",
    "moves_npz_bytes",
    "npz_of_json",
    "read_moves_text",
]

MOVES_NPZ_FORMAT = "scanmill-neutral-moves-npz"
MOVES_NPZ_FORMAT_VERSION = 1
TYPE_CODES = ("rapid", "feed", "arc")
USE_CODES = ("rapid", "cut", "plunge", "retract")
DIRECTION_CODES = ("cw", "ccw")

#: zlib level of the moves JSON's gzip. On the femur-like plan's largest area (7.71 MB of JSON,
#: 73.5k moves; gzip_bytes alone, best of 3): level 1 takes 0.05 s for 2.22 MB, level 6 0.35 s for
#: 1.90 MB: six times the time for 14 % fewer bytes, on every plan, in the planning process
#: (the whole plan, bench/bench_artifacts.py: 0.22 s against 1.32 s, BENCHMARKS). Level 1; a
#: client wanting the fewest bytes reads the npz or recompresses.
JSON_GZ_LEVEL = 1
_MOVE_FLOATS = ("tip_part_mm", "tip_machine_mm")
_ARC_FLOATS = ("normal_part", "normal_machine", "centre_part_mm", "centre_machine_mm")
_FIVE_FLOATS = ("centre_mm", "tip_mm", "axis")


def gzip_bytes(data: bytes | str, level: int = JSON_GZ_LEVEL) -> bytes:
    """``data`` (text is UTF-8 encoded) as a gzip stream, deterministic: header mtime 0, no file name."""
    if isinstance(data, str):
        data = data.encode()
    return gzip.compress(data, compresslevel=level, mtime=0)


def read_moves_text(path: str | Path) -> str:
    """The neutral moves JSON text of ``path``: ``area_<i>.moves.json.gz`` (or an old plain ``.moves.json``)."""
    path = Path(path)
    data = path.read_bytes()
    if data[:2] == b"\x1f\x8b":
        data = gzip.decompress(data)
    return data.decode()


# ------------------------------------------------------------------------------------------------
# writing


def _picked(value) -> tuple[tuple, np.ndarray]:
    """``(table, index)`` of a :class:`planning.post.neutral.Picked` or of a plain list of names."""
    if hasattr(value, "table"):
        return tuple(value.table), np.asarray(value.index, dtype=np.int64)
    if not len(value):
        return (), np.zeros(0, dtype=np.int64)
    table, index = np.unique(np.asarray(value, dtype=str), return_inverse=True)
    return tuple(table.tolist()), index.reshape(-1)


def _codes(value, names: Sequence[str]) -> np.ndarray:
    """uint8 codes into ``names`` of a list of names (:class:`planning.post.neutral.Picked` or a list)."""
    table, index = _picked(value)
    unknown = sorted(set(table) - set(names))
    if unknown:
        raise ValueError(f"neutral moves: unknown names {unknown}; known: {list(names)}")
    lut = np.array([names.index(v) for v in table], dtype=np.uint8)
    return lut[index] if index.size else np.zeros(0, dtype=np.uint8)


def _numbers(value) -> np.ndarray:
    """float64 of a list of numbers (:class:`planning.post.neutral.Picked` or a list), NaN for None."""
    if not hasattr(value, "table"):
        return np.array(value, dtype="<f8").reshape(-1)     # None -> NaN
    lut = np.array([np.nan if v is None else float(v) for v in value.table], dtype="<f8")
    return lut[value.index] if value.index.size else np.zeros(0, dtype="<f8")


def _rows(parts: list, dtype: str, width: int | None = None) -> np.ndarray:
    shape = (0,) if width is None else (0, width)
    return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype=dtype)


def _starts(counts: list[int]) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype("<i8")


def moves_npz_arrays(doc: dict | None, five: Sequence[dict] = ()) -> dict[str, np.ndarray]:
    """The npz members (module docstring) of ``doc``, the second value of
    :func:`planning.post.neutral.neutral_json_arrays` (None: no 3+2 operations), and ``five``, the
    simultaneous operations as :func:`planning.post.programs` lists them (``name``, ``tool_number``,
    ``radius_mm``, ``centre_mm``, ``tip_mm``, ``axis`` (Q,3) float64 already rounded, ``kind``,
    ``use`` (Q,) int). A parsed moves JSON document does as well (lists in place of the arrays; its
    ``five_axis_operations`` passed as ``five``: :func:`npz_of_json`)."""
    skeleton = {} if doc is None else {k: v for k, v in doc.items() if k not in ("operations", "five_axis_operations")}
    ops = [] if doc is None else doc["operations"]
    cols: dict[str, list] = {k: [] for k in ("type", "use", "feed_mm_min", *_MOVE_FLOATS, "controlled_machine_mm",
                                             "arc_move", "arc_direction", "arc_plane",
                                             *("arc_" + f for f in _ARC_FLOATS))}
    n_moves, n_arcs, meta_ops = [], [], []
    any_controlled = any("controlled_machine_mm" in op for op in ops)
    for op in ops:
        mv, arcs = op["moves"], op["arcs"]
        n_moves.append(int(mv["count"]))
        n_arcs.append(int(arcs["count"]))
        cols["type"].append(_codes(mv["type"], TYPE_CODES))
        cols["use"].append(_codes(mv["use"], USE_CODES))
        cols["feed_mm_min"].append(_numbers(mv["feed_mm_min"]))
        for f in _MOVE_FLOATS:
            cols[f].append(np.asarray(mv[f], dtype=np.float64).reshape(-1, 3))
        if any_controlled:
            c = op.get("controlled_machine_mm")
            cols["controlled_machine_mm"].append(np.full((n_moves[-1], 3), np.nan) if c is None
                                                 else np.asarray(c, dtype=np.float64).reshape(-1, 3))
        cols["arc_move"].append(np.asarray(arcs["move"], dtype=np.int64))
        cols["arc_direction"].append(_codes(arcs["direction"], DIRECTION_CODES))
        cols["arc_plane"].append(np.asarray(arcs["plane"], dtype=np.int64))
        for f in _ARC_FLOATS:
            cols["arc_" + f].append(np.asarray(arcs[f], dtype=np.float64).reshape(-1, 3))
        entry = {}
        for k, v in op.items():
            if k == "moves" or k == "arcs":
                entry[k] = {"count": int(v["count"])}
            elif k == "controlled_machine_mm":
                entry[k] = True
            else:
                entry[k] = v
        meta_ops.append(entry)
    if doc is not None:
        skeleton["operations"] = meta_ops
    if five:
        skeleton["five_axis_operations"] = [
            {"name": f["name"], "tool_number": int(f["tool_number"]), "radius_mm": float(f["radius_mm"]),
             "count": len(f["kind"])} for f in five]
    meta = {"npz_format": MOVES_NPZ_FORMAT, "npz_format_version": MOVES_NPZ_FORMAT_VERSION,
            "codes": {"type": list(TYPE_CODES), "use": list(USE_CODES), "direction": list(DIRECTION_CODES)},
            "document": skeleton}
    out = {"meta": np.array(json.dumps(meta, separators=(",", ":")))}
    out["op_start"] = _starts(n_moves)
    out["type"] = _rows(cols["type"], "u1")
    out["use"] = _rows(cols["use"], "u1")
    out["feed_mm_min"] = _rows(cols["feed_mm_min"], "<f8")
    for f in _MOVE_FLOATS:
        out[f] = _rows(cols[f], "<f8", 3)
    if any_controlled:
        out["controlled_machine_mm"] = _rows(cols["controlled_machine_mm"], "<f8", 3)
    out["arc_start"] = _starts(n_arcs)
    out["arc_move"] = _rows(cols["arc_move"], "<i8")
    out["arc_direction"] = _rows(cols["arc_direction"], "u1")
    out["arc_plane"] = _rows(cols["arc_plane"], "u1")
    for f in _ARC_FLOATS:
        out["arc_" + f] = _rows(cols["arc_" + f], "<f8", 3)
    if five:
        out["five_start"] = _starts([len(f["kind"]) for f in five])
        for f in _FIVE_FLOATS:
            out["five_" + f] = _rows([np.asarray(x[f], dtype=np.float64).reshape(-1, 3) for x in five], "<f8", 3)
        out["five_kind"] = _rows([np.asarray(x["kind"]) for x in five], "u1")
        out["five_use"] = _rows([np.asarray(x["use"]) for x in five], "u1")
    return out


def moves_npz_bytes(doc: dict | None, five: Sequence[dict] = (), level: int = NPZ_LEVEL) -> bytes:
    """The ``area_<i>.moves.npz`` file of :func:`moves_npz_arrays` (the same arguments), deterministic
    (:func:`planning.report.files.savez_compressed`: fixed member times, no pickles)."""
    buf = io.BytesIO()
    savez_compressed(buf, moves_npz_arrays(doc, five), level)
    return buf.getvalue()


def npz_of_json(text: str, level: int = NPZ_LEVEL) -> bytes:
    """The ``.moves.npz`` of a neutral moves JSON text (e.g. an older plan's ``area_<i>.moves.json``);
    ``moves_document`` of the result is ``json.loads(text)``."""
    doc = json.loads(text)
    five = doc.pop("five_axis_operations", [])
    return moves_npz_bytes(doc if doc else None, five, level=level)


# ------------------------------------------------------------------------------------------------
# reading


def moves_document(npz) -> dict:
    """The neutral moves JSON document (as ``json.loads`` of the ``.moves.json.gz`` text gives it) from
    an ``area_<i>.moves.npz``: a path, a file object or the mapping :func:`numpy.load` returns."""
    z = np.load(npz, allow_pickle=False) if isinstance(npz, (str, Path)) or hasattr(npz, "read") else npz
    meta = json.loads(str(z["meta"]))
    if meta.get("npz_format") != MOVES_NPZ_FORMAT or meta.get("npz_format_version") != MOVES_NPZ_FORMAT_VERSION:
        raise ValueError(f"not a {MOVES_NPZ_FORMAT} version {MOVES_NPZ_FORMAT_VERSION} file: "
                         f"{meta.get('npz_format')!r} {meta.get('npz_format_version')!r}")
    codes = meta["codes"]
    doc = meta["document"]
    op_start, arc_start = z["op_start"], z["arc_start"]
    type_names = np.array(codes["type"], dtype=object)
    use_names = np.array(codes["use"], dtype=object)
    dir_names = np.array(codes["direction"], dtype=object)
    cols = {k: z[k] for k in ("type", "use", "feed_mm_min", *_MOVE_FLOATS, "arc_move", "arc_direction",
                              "arc_plane", *("arc_" + f for f in _ARC_FLOATS))}
    controlled = z.get("controlled_machine_mm")
    for k, op in enumerate(doc.get("operations", [])):
        s, e = int(op_start[k]), int(op_start[k + 1])
        a, b = int(arc_start[k]), int(arc_start[k + 1])
        feed = cols["feed_mm_min"][s:e]
        feeds = np.where(np.isnan(feed), None, feed.astype(object)).tolist() if feed.size else []
        op["moves"] = {"count": op["moves"]["count"],
                       "type": type_names[cols["type"][s:e]].tolist(),
                       "use": use_names[cols["use"][s:e]].tolist(),
                       "feed_mm_min": feeds,
                       **{f: cols[f][s:e].tolist() for f in _MOVE_FLOATS}}
        op["arcs"] = {"count": op["arcs"]["count"],
                      "move": cols["arc_move"][a:b].tolist(),
                      "direction": dir_names[cols["arc_direction"][a:b]].tolist(),
                      "plane": cols["arc_plane"][a:b].tolist(),
                      **{f: cols["arc_" + f][a:b].tolist() for f in _ARC_FLOATS}}
        if "controlled_machine_mm" in op:
            op["controlled_machine_mm"] = controlled[s:e].tolist()
    if "five_axis_operations" in doc:
        five_start = z["five_start"]
        ops = []
        for j, f in enumerate(doc["five_axis_operations"]):
            s, e = int(five_start[j]), int(five_start[j + 1])
            ops.append({"name": f["name"], "tool_number": f["tool_number"], "radius_mm": f["radius_mm"],
                        **{k: z["five_" + k][s:e].tolist() for k in _FIVE_FLOATS},
                        "kind": z["five_kind"][s:e].tolist(), "use": z["five_use"][s:e].tolist()})
        doc["five_axis_operations"] = ops
    return doc
