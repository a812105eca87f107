"""Writes a finished plan to a directory: plan.json, plan.npz, segmentation.ply, preview.png (every
input point), the viewer's data (viewer.json, viewer.points.bin, viewer.paths.bin), and per area the NC
programs ``area_<i>.<dialect>.nc`` and neutral moves ``area_<i>.moves.json.gz`` and ``area_<i>.moves.npz``.

Every file is written to a temporary name and renamed into place; ``plan.json`` is written last,
so a directory holding ``plan.json`` holds a complete plan.
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np

from planning.pipeline import PlanOutcome
from planning.report.files import NPZ_LEVEL, atomic_path, savez_compressed, write_ply  # noqa: F401 (NPZ_LEVEL: re-export)
from planning.report.preview import point_colors, render_preview
from planning.report.viewer_data import input_integrated, write_viewer_data


def _atomic_bytes(path: Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def plan_json_text(outcome: PlanOutcome) -> str:
    """The plan.json document (public parameter names, e.g. ``visibility.global``)."""
    return json.dumps(outcome.result.model_dump(mode="json", by_alias=True), indent=2) + "\n"


def npz_arrays(outcome: PlanOutcome) -> dict[str, np.ndarray]:
    """The plan.npz arrays (docs/design.md contract names), with per-area ``cl_i`` once paths exist."""
    return dict(outcome.arrays)


def write_plan(outcome: PlanOutcome, out_dir: str | os.PathLike, progress=None) -> dict[str, Path]:
    """Write the plan's artifacts into ``out_dir`` (created if needed); return their paths by kind.
    ``progress(fraction, message)`` is told each artifact before it is written."""
    say = progress or (lambda fraction, message="": None)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    names = outcome.result.artifacts
    paths = {"plan_npz": out / names.plan_npz, "segmentation_ply": out / names.segmentation_ply,
             "preview_png": out / names.preview_png, "plan_json": out / "plan.json"}

    say(0.0, names.plan_npz)
    buf = io.BytesIO()
    savez_compressed(buf, npz_arrays(outcome), allow_pickle=True)
    _atomic_bytes(paths["plan_npz"], buf.getvalue())

    say(0.15, names.segmentation_ply)
    labels = outcome.input_labels
    colors = point_colors(labels, len(outcome.result.setups))
    write_ply(paths["segmentation_ply"], outcome.points, colors=colors, labels=labels, binary=True,
              single=True)

    say(0.3, names.preview_png)
    integ = input_integrated(outcome)
    f = outcome.result.figures
    note = None
    if f is not None and integ is not None and f.measured:
        note = (f"seen by no chosen set-up, attached by distance (darker, larger): {int(np.sum(integ)):,} input pts, "
                f"{f.not_covered:,} of them not finished")
    render_preview(paths["preview_png"], outcome.points, labels, outcome.selected_axes,
                   integrated=integ, integrated_label=note,
                   angles=[dict(s.rotary_deg) for s in outcome.result.setups],
                   title=f"{outcome.result.input.name or 'cloud'}: {outcome.result.message}")

    if names.placed_ply:                 # fixtures.placement = auto: the cloud as the plan placed it
        say(0.35, names.placed_ply)
        paths["placed_ply"] = out / names.placed_ply
        write_ply(paths["placed_ply"], outcome.points, binary=True)

    say(0.4, "NC programs")
    for name, text in outcome.extra.get("programs", {}).items():
        # NC programs are text; the moves files (.moves.json.gz, .moves.npz) come encoded as bytes
        paths[name] = out / name
        _atomic_bytes(paths[name], text if isinstance(text, bytes) else text.encode())

    paths.update(_write_simulation(outcome, out, say))
    say(0.85, "viewer data")
    paths.update(write_viewer_data(outcome, out))
    say(0.9, "unmachined points")
    paths.update(_write_unmachined(outcome, out))
    say(0.95, "plan.json")
    _atomic_bytes(paths["plan_json"], plan_json_text(outcome).encode())
    return paths


def _write_unmachined(outcome: PlanOutcome, out: Path) -> dict[str, Path]:
    """``unmachined.png`` when the guard left scan points unmachined (issue 16)."""
    from planning.report.deviation import render_unmachined_png
    from planning.report.figures import UNREACHED, unreached_indices

    u = outcome.result.unmachined
    if u is None or u.n_points == 0 or not outcome.result.artifacts.unmachined_png:
        return {}
    f, classes = outcome.result.figures, outcome.extra.get("point_classes")
    path = out / outcome.result.artifacts.unmachined_png
    if f is not None and classes is not None:
        # the plan's own class (figures.unreached): not finished, seen by a chosen set-up, reached by no
        # kept finishing move; the points no move reaches that end finished or not covered are counted there
        idx = np.flatnonzero(classes == UNREACHED)
        title = (f"unreached (red): {f.unreached:,} input points ({f.unreached_share:.1%}) no kept finishing move "
                 f"reaches and not finished within tolerance; {u.n_points:,} no kept move reaches in all")
    else:
        idx = unreached_indices(outcome.extra.get("area_paths", []))
        title = f"input points no kept finishing move reaches (red): {u.n_points:,} ({u.share:.1%})"
    render_unmachined_png(path, outcome.points, idx, title=title)
    return {"unmachined_png": path}


def _write_simulation(outcome: PlanOutcome, out: Path, say=lambda fraction, message="": None) -> dict[str, Path]:
    """The verification's artifacts (deviation PLY and PNG, final stock mesh) when it ran."""
    from planning.report.deviation import (
        render_deviation_png,
        write_deviation_ply,
        write_mesh_ply,
    )

    sim = outcome.extra.get("simulation")
    names = outcome.result.artifacts
    paths: dict[str, Path] = {}
    if sim is None or sim.deviation_mm is None:
        return paths
    from planning.report.figures import finishing_limit_mm

    v = outcome.result.verification
    limit = finishing_limit_mm(outcome.result.parameters, v)     # the limit the figures count by
    say(0.5, names.deviation_ply)
    paths["deviation_ply"] = out / names.deviation_ply
    write_deviation_ply(paths["deviation_ply"], outcome.points, sim.deviation_mm, limit,
                        getattr(sim, "finish_left_mm", None))
    say(0.6, names.deviation_png)
    paths["deviation_png"] = out / names.deviation_png
    f = outcome.result.figures
    head = (f"{f.finished_share:.1%} of {f.n_points:,} input points finished within +-{limit:.3g} mm"
            if f is not None and f.finished_share is not None else "")
    render_deviation_png(paths["deviation_png"], outcome.points, sim.deviation_mm, limit,
                         title=f"verification {v.status}" + (f": {head}" if head else ""))
    if sim.stock is not None and names.stock_ply:
        say(0.75, names.stock_ply)
        from planning.simulate.mesh import stock_mesh
        vertices, faces = stock_mesh(sim.stock)
        paths["stock_ply"] = out / names.stock_ply
        write_mesh_ply(paths["stock_ply"], vertices, faces)
    return paths
