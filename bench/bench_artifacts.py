"""Artifact sizes of a plan directory, and the neutral moves as JSON, JSON.gz and NPZ (issue 20).

    .venv/bin/python bench/bench_artifacts.py PLAN_DIR [--levels 1,6] [--repeat 3] [--json OUT.json]

Prints every file of ``PLAN_DIR`` with its size, then for each area's moves
(``area_<i>.moves.json.gz``, or ``area_<i>.moves.json`` of a plan written before issue 20) the moves
re-encoded from the plan's own file, so that a plan of any version is measured the same way:

* ``json``: the raw JSON text (what older plans stored);
* ``json.gz Ln``: that text gzip compressed at zlib level ``n`` (``--levels``; the plan writes
  :data:`planning.report.moves_files.JSON_GZ_LEVEL`), deterministic (mtime 0, no name);
* ``npz``: :func:`planning.report.moves_files.moves_npz_bytes` of the same document, the lists first
  turned into the arrays the post hands over (untimed), as :mod:`planning.post.programs` does;

with per form: bytes, the seconds to encode and write it (into a temporary folder beside ``PLAN_DIR``'s
parent: written atomically and fsynced as plan files are, best of ``--repeat``), the seconds to read
it back into numbers (``json.loads`` of the text / of the gunzipped text; ``np.load`` of every npz
member), and whether the npz gives back the JSON text byte for byte
(:func:`planning.report.moves_files.moves_document`).
"""

from __future__ import annotations

import argparse
import gzip
import io
import json
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from planning.post.neutral import Picked
from planning.report.files import atomic_path
from planning.report.moves_files import (
    DIRECTION_CODES,
    JSON_GZ_LEVEL,
    TYPE_CODES,
    USE_CODES,
    gzip_bytes,
    moves_document,
    moves_npz_bytes,
    read_moves_text,
)


def _picked(names: list, table: tuple) -> Picked:
    pos = {v: i for i, v in enumerate(table)}
    return Picked(table, np.fromiter((pos[v] for v in names), dtype=np.int64, count=len(names)))


def _arrays_doc(doc: dict) -> tuple[dict | None, list]:
    """The document as :func:`planning.post.neutral.neutral_json_arrays` gives it, and the
    simultaneous operations as planning.post.programs lists them (arrays)."""
    doc = dict(doc)
    five = [{k: (np.asarray(v) if isinstance(v, list) else v) for k, v in f.items()}
            for f in doc.pop("five_axis_operations", [])]
    if not doc:
        return None, five
    ops = []
    for op in doc["operations"]:
        op = dict(op)
        mv, arcs = dict(op["moves"]), dict(op["arcs"])
        mv["type"] = _picked(mv["type"], TYPE_CODES)
        mv["use"] = _picked(mv["use"], USE_CODES)
        feeds = tuple(dict.fromkeys(mv["feed_mm_min"]))
        mv["feed_mm_min"] = _picked(mv["feed_mm_min"], feeds)
        for k in ("tip_part_mm", "tip_machine_mm"):
            mv[k] = np.array(mv[k], dtype=np.float64).reshape(-1, 3)
        arcs["direction"] = _picked(arcs["direction"], DIRECTION_CODES)
        for k in ("move", "plane"):
            arcs[k] = np.array(arcs[k], dtype=np.int64)
        for k in ("normal_part", "normal_machine", "centre_part_mm", "centre_machine_mm"):
            arcs[k] = np.array(arcs[k], dtype=np.float64).reshape(-1, 3)
        op["moves"], op["arcs"] = mv, arcs
        if "controlled_machine_mm" in op:
            op["controlled_machine_mm"] = np.array(op["controlled_machine_mm"], dtype=np.float64).reshape(-1, 3)
        ops.append(op)
    doc["operations"] = ops
    return doc, five


def _best(fn, repeat: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def _gzip_fixed(data: bytes) -> bool:
    """Whether a gzip stream's header holds nothing that changes from run to run (RFC 1952: no flags,
    so no file name or comment, and MTIME 0); encoding the same bytes again in this process would
    give the same stream whatever the header holds."""
    return data[3] == 0 and data[4:8] == b"\0\0\0\0"


def _zip_fixed(data: bytes) -> bool:
    """Whether every member of a zip has the fixed timestamp (no wall clock in the file)."""
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        return all(i.date_time == (1980, 1, 1, 0, 0, 0) for i in zf.infolist())


def _write(path: Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def moves_forms(path: Path, levels: list[int], repeat: int, scratch: Path) -> dict:
    """Sizes and times of one area's moves in every form (module docstring)."""
    text = read_moves_text(path)
    raw = text.encode()
    doc, five = _arrays_doc(json.loads(text))
    forms = {}
    t, _ = _best(lambda: _write(scratch / "m.json", raw), repeat)
    r, _ = _best(lambda: json.loads((scratch / "m.json").read_bytes()), repeat)
    forms["json"] = {"bytes": len(raw), "write_s": t, "read_s": r}
    for lv in levels:
        def enc(lv=lv):
            data = gzip_bytes(raw, level=lv)
            _write(scratch / "m.json.gz", data)
            return data
        t, data = _best(enc, repeat)
        r, _ = _best(lambda: json.loads(gzip.decompress((scratch / "m.json.gz").read_bytes())), repeat)
        forms[f"json.gz L{lv}"] = {"bytes": len(data), "write_s": t, "read_s": r,
                                   "deterministic": _gzip_fixed(data)}

    def enc_npz():
        data = moves_npz_bytes(doc, five)
        _write(scratch / "m.npz", data)
        return data
    t, data = _best(enc_npz, repeat)

    def load_npz():
        with np.load(scratch / "m.npz", allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    r, _ = _best(load_npz, repeat)
    same = json.dumps(moves_document(io.BytesIO(data)), separators=(",", ":")) + "\n" == text
    forms["npz"] = {"bytes": len(data), "write_s": t, "read_s": r, "lossless": same,
                    "deterministic": _zip_fixed(data)}
    n_moves = sum(op["moves"]["count"] for op in (doc or {}).get("operations", []))
    return {"file": path.name, "moves": n_moves, "five_axis_moves": sum(len(f["kind"]) for f in five),
            "forms": forms}


def _mb(n: int) -> str:
    return f"{n / 1e6:9.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("plan_dir", type=Path)
    ap.add_argument("--levels", default="1,6", help="gzip levels to measure (comma separated; default 1,6; "
                                                     f"the plan writes {JSON_GZ_LEVEL})")
    ap.add_argument("--repeat", type=int, default=3, help="best of N for every time (default 3)")
    ap.add_argument("--json", type=Path, help="also write the figures here")
    args = ap.parse_args(argv)
    d = args.plan_dir
    files = sorted(p for p in d.iterdir() if p.is_file() and not p.name.startswith("."))
    print(f"artifacts of {d}")
    print(f"{'file':<28}{'bytes':>12}{'MB':>10}")
    for p in files:
        print(f"{p.name:<28}{p.stat().st_size:>12}{_mb(p.stat().st_size)}")
    total = sum(p.stat().st_size for p in files)
    print(f"{'total':<28}{total:>12}{_mb(total)}")

    moves = sorted(p for p in files if p.name.endswith((".moves.json", ".moves.json.gz")))
    levels = [int(v) for v in args.levels.split(",") if v.strip()]
    out = {"plan_dir": str(d), "files": {p.name: p.stat().st_size for p in files}, "total_bytes": total, "moves": []}
    with tempfile.TemporaryDirectory(prefix=".bench_artifacts_", dir=d.parent) as tmp:
        for p in moves:
            out["moves"].append(moves_forms(p, levels, args.repeat, Path(tmp)))
    if moves:
        print(f"\nmoves re-encoded from the plan's files (best of {args.repeat}; write = encode + atomic write + fsync, "
              "read = parse / load into numbers)")
        print(f"{'file':<24}{'moves':>9}{'form':>13}{'bytes':>12}{'MB':>10}{'ratio':>8}{'write s':>9}{'read s':>8}")
        sums: dict[str, list[float]] = {}
        for m in out["moves"]:
            base = m["forms"]["json"]["bytes"]
            for form, f in m["forms"].items():
                note = "" if f.get("lossless", True) and f.get("deterministic", True) else "  NOT lossless/deterministic"
                print(f"{m['file']:<24}{m['moves']:>9}{form:>13}{f['bytes']:>12}{_mb(f['bytes'])}"
                      f"{f['bytes'] / base:>8.3f}{f['write_s']:>9.3f}{f['read_s']:>8.3f}{note}")
                s = sums.setdefault(form, [0, 0.0, 0.0])
                s[0] += f["bytes"]
                s[1] += f["write_s"]
                s[2] += f["read_s"]
        base = sums["json"][0]
        for form, (b, w, r) in sums.items():
            print(f"{'all areas':<24}{'':>9}{form:>13}{b:>12}{_mb(b)}{b / base:>8.3f}{w:>9.3f}{r:>8.3f}")
        out["moves_total"] = {form: {"bytes": b, "write_s": w, "read_s": r} for form, (b, w, r) in sums.items()}
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
