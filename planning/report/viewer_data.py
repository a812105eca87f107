"""The data of the browser viewer (issue 20): a small JSON index and two little-endian binary files.

:func:`write_viewer_data` writes, next to ``plan.json``:

* ``viewer.json``: the index. Format ``scanmill-viewer`` version 1: the plan's name, status and
  message; the verification verdict, its worst offences (kind, program, line, tool tip in the part
  frame, amount) and the deviation limit of its colour bar; per set-up its
  colour, tool axis, polar/azimuth angles, machine rotary positions, point counts and finishing
  mode; and a table of the binary arrays, each as ``{"file", "offset", "length", "dtype", "shape"}``
  (byte offsets, dtype a numpy little-endian code such as ``<u2``).
* ``viewer.points.bin``: the scan, every input point up to ``max_points`` (a fixed-seed random
  subset above it, reported as ``points.n_shown`` of ``points.n_total``):

  - ``position`` (n, 3) ``<u2``: coordinates quantised on the points' bounding box,
    ``p = box_min + q / 65535 * (box_max - box_min)`` (mm; a 400 mm part has 0.006 mm steps);
  - ``label`` (n,) ``u1``: the area (set-up id), 255 where no set-up machines the point;
  - ``flags`` (n,) ``u1``: bit 0 integrated (attached to an area without a guaranteed axis),
    bit 1 unmachined (no kept finishing move reaches it);
  - ``normal`` (n, 3) ``i1``: the unit normal times 127 (the nearest sampled point's), for shading;
  - ``deviation`` (n,) ``<i2`` when the programs were simulated: the point's deviation from the
    simulated final stock in micrometres, positive where material is left, clipped to +-32.767 mm;
    -32768 (:data:`DEV_UNMEASURED`) where it was not measured;
  - the deviation colours (``deviation.lut``, (m, 3) ``u1``): :func:`planning.report.deviation.deviation_colors`
    of every micrometre from ``deviation.lut_first_um`` to ``-lut_first_um`` (the saturation, beyond which
    the colour no longer changes), so that the page paints each point with the colour the PLY and the PNG
    give it (issue 34: one convention, ``deviation.colors`` and ``deviation.saturation`` by name).

* ``viewer.paths.bin``: per area and operation (``finishing``, ``roughing``) the tool-tip path in
  the part frame, ``vertices`` (m, 3) ``<u2`` quantised on the paths' own box (safe heights
  included) and ``use`` (m,) ``u1``, the use of the move ending at each vertex (0 rapid, 1 cut,
  2 plunge, 3 retract, :mod:`planning.toolpath.moves`). Arcs are drawn as chords of at most
  ``arc_step_mm`` (display only: the NC programs keep the arcs).

``viewer.json`` also carries plan.json's ``figures`` (issue 34: finished, left, unreached and not covered
input points and the machining times, per area in machining order and in total) as they are, null
for a plan without them, and ``machining_order``.

The points come first in their own file so the page can draw the scan before the paths arrive.
Quantised positions halve the bytes of float32 and the page hands them to the GPU as normalised
attributes, with no decoding loop in JavaScript.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from planning.report.deviation import (
    DEVIATION_COLORS,
    DEVIATION_SATURATION,
    deviation_colors,
)
from planning.report.files import atomic_path
from planning.report.preview import UNCOVERED_COLOR, area_colors
from planning.toolpath.moves import densify

__all__ = [
    "DEV_UNMEASURED",
    "VIEWER_FILES",
    "VIEWER_FORMAT",
    "VIEWER_FORMAT_VERSION",
    "deviation_lut",
    "input_integrated",
    "viewer_index",
    "write_viewer_data",
]

VIEWER_FORMAT = "scanmill-viewer"
VIEWER_FORMAT_VERSION = 1
#: The files :func:`write_viewer_data` writes (index first, binaries after).
VIEWER_FILES = ("viewer.json", "viewer.points.bin", "viewer.paths.bin")
#: Default budget of points sent to the browser: 2 million points draw smoothly in WebGL.
MAX_POINTS = 2_000_000
UNLABELLED = 255
FLAG_INTEGRATED, FLAG_UNMACHINED = 1, 2
#: ``deviation`` of a point the simulation did not measure (NaN), micrometres.
DEV_UNMEASURED = -32768
_DEV_MAX_UM = 32767
_Q = 65535.0
_SEED = 0


class _Buffers:
    """Arrays appended to one binary file, with their index entries."""

    def __init__(self, name: str):
        self.name, self.parts, self.offset = name, [], 0

    def add(self, array: np.ndarray) -> dict:
        a = np.ascontiguousarray(array)
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        entry = {"file": self.name, "offset": self.offset, "length": int(a.nbytes),
                 "dtype": a.dtype.str, "shape": list(a.shape)}
        self.parts.append(a.tobytes())
        pad = (-a.nbytes) % 8                 # 8-byte alignment: typed arrays need their element size
        if pad:
            self.parts.append(b"\0" * pad)
        self.offset += a.nbytes + pad
        return entry

    def write(self, path: Path) -> None:
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            fh.writelines(self.parts)


def quantise(points: np.ndarray) -> tuple[np.ndarray, list[float], list[float]]:
    """``(q (n,3) uint16, box_min, box_max)`` with ``p ~ box_min + q / 65535 * (box_max - box_min)``
    (mm). A flat side gets a 1e-6 mm extent so the scale stays finite."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] == 0:
        return np.zeros((0, 3), np.uint16), [0.0] * 3, [1e-6] * 3
    lo, hi = p.min(axis=0), p.max(axis=0)
    hi = np.maximum(hi, lo + 1e-6)
    q = np.rint((p - lo) / (hi - lo) * _Q)
    return np.clip(q, 0, _Q).astype(np.uint16), lo.tolist(), hi.tolist()


def dequantise(q: np.ndarray, box_min, box_max) -> np.ndarray:
    """Inverse of :func:`quantise` (mm)."""
    lo, hi = np.asarray(box_min, float), np.asarray(box_max, float)
    return lo + np.asarray(q, float) / _Q * (hi - lo)


def chords(tp, frame, arc_step_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Tool-tip vertices (m,3) in the part frame, mm, and the use of the move ending at each, with every
    arc replaced by chords of at most ``arc_step_mm`` (:func:`planning.toolpath.moves.densify`)."""
    if tp.n_moves == 0:
        return np.zeros((0, 3)), np.zeros(0, np.uint8)
    points, move = densify(tp, arc_step_mm)
    # a 3+2 path's tip is its reference point shifted along the area's -Z; a 5-axis path has no arcs, so
    # its points are its end points, each with its own axis
    tip = points - (0.0, 0.0, tp.tip_offset_mm) if tp.axis is None else tp.tip_mm()[move]
    return frame.to_part(tip), tp.use[move].astype(np.uint8)


def input_integrated(outcome) -> np.ndarray | None:
    """(N,) bool: input points whose nearest sampled point is integrated (attached to an area by
    distance; every input point takes its nearest sample's area), or None when the plan has no areas."""
    areas = outcome.extra.get("areas")
    if areas is None or getattr(areas, "nearest_sample", None) is None:
        return None
    return np.asarray(outcome.arrays["integrated"], bool)[areas.nearest_sample]


def input_normals(outcome) -> np.ndarray | None:
    """(N,3) unit normals of the input points: the nearest sampled point's (the ones the plan used), or
    None when the plan has none. Only shading uses them, so the nearest sample's is close enough."""
    areas = outcome.extra.get("areas")
    nrm = outcome.arrays.get("normals")
    if areas is None or getattr(areas, "nearest_sample", None) is None or nrm is None:
        return None
    n = np.asarray(nrm, dtype=np.float64)[areas.nearest_sample]
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)


def _input_flags(outcome) -> np.ndarray:
    flags = np.zeros(outcome.points.shape[0], dtype=np.uint8)
    integrated = input_integrated(outcome)
    if integrated is not None:
        flags[integrated] |= FLAG_INTEGRATED
    for ap in outcome.extra.get("area_paths", []) or []:
        idx = getattr(ap, "unmachined", None)
        if idx is not None and idx.size:
            flags[idx] |= FLAG_UNMACHINED
    return flags


def _setup_rows(result, colors: np.ndarray) -> list[dict]:
    rows = []
    for s in result.setups:
        fin = s.path.finishing if s.path is not None else None
        rows.append({"id": s.id, "color": colors[s.id].tolist(), "tool_axis": list(s.tool_axis),
                     "phi_deg": s.phi_deg, "theta_deg": s.theta_deg, "rotary_deg": dict(s.rotary_deg),
                     "n_points": s.n_points, "n_input_points": s.n_input_points, "n_integrated": s.n_integrated,
                     "finishing_mode": fin.mode if fin is not None else None,
                     "order": (result.machining_order.index(s.id) if s.id in (result.machining_order or [])
                               else None)})
    return rows


def _finite_or_none(x) -> float | None:
    return float(x) if x is not None and np.isfinite(x) else None


def deviation_lut(limit_mm: float, buffers: _Buffers) -> dict:
    """The deviation colour convention for the page: ``colors`` and ``saturation`` by name
    (:data:`planning.report.deviation.DEVIATION_COLORS`, :data:`DEVIATION_SATURATION`) and ``lut``, an
    (m, 3) ``u1`` array in ``buffers``: :func:`deviation_colors` of each whole micrometre from
    ``lut_first_um`` (minus the saturation, ``DEVIATION_SATURATION * limit_mm``, rounded up and at most
    32.767 mm) to ``-lut_first_um``. The page reads a point's colour at ``clamp(d_um) - lut_first_um``:
    the very colour the PLY and the PNG give the point's (micrometre-rounded) deviation."""
    span = int(min(_DEV_MAX_UM, max(1, np.ceil(DEVIATION_SATURATION * limit_mm * 1000.0 - 1e-6))))
    um = np.arange(-span, span + 1)
    return {"saturation": float(DEVIATION_SATURATION),
            "colors": {k: [int(c) for c in v] for k, v in DEVIATION_COLORS.items()},
            "lut_first_um": int(-span), "lut": buffers.add(deviation_colors(um / 1000.0, limit_mm)),
            "unmeasured_um": DEV_UNMEASURED}


def _figures(result) -> dict | None:
    """plan.json's ``figures`` (:class:`schemas.plan.PlanFigures`) as JSON, None when the plan has none."""
    fig = getattr(result, "figures", None)
    if fig is None:
        return None
    return fig.model_dump(mode="json") if hasattr(fig, "model_dump") else dict(fig)


def viewer_index(outcome, *, max_points: int = MAX_POINTS, arc_step_mm: float = 0.5
                 ) -> tuple[dict, _Buffers, _Buffers]:
    """The index document and the two buffers of a plan (see the module docstring)."""
    result = outcome.result
    k = len(result.setups)
    colors = area_colors(k)
    pts = np.asarray(outcome.points, dtype=np.float64)
    n_total = pts.shape[0]
    keep = (np.arange(n_total) if n_total <= max_points else
            np.sort(np.random.default_rng(_SEED).choice(n_total, size=max_points, replace=False)))
    points_buf, paths_buf = _Buffers(VIEWER_FILES[1]), _Buffers(VIEWER_FILES[2])

    q, lo, hi = quantise(pts[keep])
    labels = np.asarray(outcome.input_labels)[keep]
    label_u8 = np.where(labels < 0, UNLABELLED, labels).astype(np.uint8)
    flags = _input_flags(outcome)
    arrays = {"position": points_buf.add(q), "label": points_buf.add(label_u8),
              "flags": points_buf.add(flags[keep])}
    normals = input_normals(outcome)
    if normals is not None:
        arrays["normal"] = points_buf.add(np.clip(np.rint(normals[keep] * 127.0), -127, 127).astype(np.int8))
    sim = outcome.extra.get("simulation")
    deviation = None
    if sim is not None and getattr(sim, "deviation_mm", None) is not None:
        dev_mm = np.asarray(sim.deviation_mm, float)
        dev_um = np.clip(np.rint(np.nan_to_num(dev_mm[keep]) * 1000.0), -_DEV_MAX_UM, _DEV_MAX_UM)
        arrays["deviation"] = points_buf.add(np.where(np.isfinite(dev_mm[keep]), dev_um, DEV_UNMEASURED
                                                      ).astype(np.int16))
        fp = result.parameters.paths.finishing
        v = result.verification
        limit = fp.tolerance_mm + fp.scallop_mm + ((v.measuring_bound_mm or 0.0) if v else 0.0)
        deviation = {"limit_mm": limit,
                     "min_mm": _finite_or_none(np.nanmin(dev_mm) if np.isfinite(dev_mm).any() else None),
                     "max_mm": _finite_or_none(np.nanmax(dev_mm) if np.isfinite(dev_mm).any() else None),
                     **deviation_lut(limit, points_buf)}

    paths = []
    verts, uses, owners = [], [], []
    for ap in outcome.extra.get("area_paths", []) or []:
        for op in ("finishing", "semi_finishing", "roughing"):
            tp = getattr(ap, op, None)
            if tp is None or tp.n_moves == 0:
                continue
            v, u = chords(tp, ap.frame, arc_step_mm)
            verts.append(v), uses.append(u), owners.append((int(ap.area), op, v.shape[0]))
    if verts:
        qp, plo, phi = quantise(np.concatenate(verts))
        start = 0
        for (area, op, m), u in zip(owners, uses):
            paths.append({"area": area, "operation": op, "n_vertices": m,
                          "vertices": paths_buf.add(qp[start:start + m]), "use": paths_buf.add(u)})
            start += m
        paths_box = {"min_mm": plo, "max_mm": phi}
    else:
        paths_box = None

    v = result.verification
    index = {
        "format": VIEWER_FORMAT, "version": VIEWER_FORMAT_VERSION,
        "name": result.input.name, "message": result.message,
        "selection_status": result.selection.status,
        "verification": ({"status": v.status, "message": v.message} if v is not None else None),
        # the worst offences of each class (plan.json verification.worst): where the programs would harm
        # the machine, the tool or the part, drawn as markers at the tool tip (part frame, mm)
        "offences": ([{"kind": o.kind, "program": o.program, "line": o.line, "position_mm": list(o.position_mm),
                       "amount": o.amount, "detail": o.detail} for o in v.worst] if v is not None else []),
        "deviation": deviation,
        # plan.json's figures as they are (issue 34): the page's time and point table reads only these
        "figures": _figures(result),
        "machining_order": list(result.machining_order or []),
        "rotary_axes": list(result.orientations.rotary_axes) if getattr(result, "orientations", None) else None,
        "colors": {"areas": colors.tolist(), "uncovered": UNCOVERED_COLOR.tolist()},
        "setups": _setup_rows(result, colors),
        "points": {"n_total": int(n_total), "n_shown": int(keep.size), "box_min_mm": lo, "box_max_mm": hi,
                   "arrays": arrays,
                   "n_integrated": int(np.count_nonzero(flags & FLAG_INTEGRATED)),
                   "n_unmachined": int(result.unmachined.n_points) if result.unmachined is not None else 0},
        "paths": {"box": paths_box, "arc_step_mm": arc_step_mm, "items": paths},
    }
    return index, points_buf, paths_buf


def write_viewer_data(outcome, out_dir, *, max_points: int = MAX_POINTS) -> dict[str, Path]:
    """Write ``viewer.json``, ``viewer.points.bin`` and ``viewer.paths.bin`` into ``out_dir`` (atomically,
    the index last); return their paths by kind."""
    out = Path(out_dir)
    index, points_buf, paths_buf = viewer_index(outcome, max_points=max_points)
    paths = {"viewer_points": out / VIEWER_FILES[1], "viewer_paths": out / VIEWER_FILES[2],
             "viewer_json": out / VIEWER_FILES[0]}
    points_buf.write(paths["viewer_points"])
    paths_buf.write(paths["viewer_paths"])
    with atomic_path(paths["viewer_json"]) as tmp:
        tmp.write_text(json.dumps(index, separators=(",", ":")) + "\n")
    return paths
