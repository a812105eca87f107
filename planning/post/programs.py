"""NC programs and path summaries of every area (docs/design.md stage 8): the glue between the per-area
tool paths (:mod:`planning.toolpath.area_paths`) and the posts (:mod:`planning.post.iso`,
:mod:`planning.post.linuxcnc`, :mod:`planning.post.neutral`).

Artifacts per area ``i``: ``area_<i>.<dialect>.nc`` for each dialect in ``post.dialects``
(``area_0.iso.nc``, ``area_0.linuxcnc.nc``), ``area_<i>.moves.json.gz`` (the neutral moves JSON, part and
machine frames, gzip compressed) and ``area_<i>.moves.npz`` (the same moves as arrays); both files
are made here as bytes (:mod:`planning.report.moves_files`). Operations in each program: roughing (when
computed) then finishing.
"""

from __future__ import annotations

import numpy as np

from planning.post.iso import iso_program
from planning.post.linuxcnc import linuxcnc_program
from planning.post.neutral import neutral_json_arrays
from planning.post.options import Operation, PostOptions
from planning.report.moves_files import gzip_bytes, moves_npz_bytes
from planning.toolpath.moves import machining_time_s
from schemas.plan import (
    AreaPathSummary,
    FinishingSummary,
    FiveAxisLinksSummary,
    FiveAxisSummary,
    FrameSummary,
    GuardSummary,
    RoughingSummary,
    SemiFinishingSummary,
)

_POSTS = {"iso": iso_program, "linuxcnc": linuxcnc_program}


def _five_axis_operations(ap, config, gauge_length_mm) -> list:
    """The area's simultaneous 5-axis finishing (a toolpath with an axis per move) as a
    :class:`planning.post.simultaneous.FiveAxisOperation` in the part frame; [] otherwise."""
    tp = ap.finishing
    if tp is None or tp.axis is None:
        return []
    return [five_axis_operation(tp, ap.frame, config, gauge_length_mm, ap.safe_z_mm)]


def five_axis_operation(tp, frame, config, gauge_length_mm: float, safe_z_mm: float):
    """A 5-axis finishing path ``tp`` (ball centres in the area ``frame``, with ``axis``) as the
    :class:`planning.post.simultaneous.FiveAxisOperation` the area's programs post (part frame; the
    plan's finishing tool, feeds and speed; ``gauge_length_mm``; C may be turned back on the rapids at
    the safe height ``safe_z_mm``, :func:`planning.toolpath.fiveaxis.register.air_moves`). The 5-axis
    guard posts the same (:mod:`planning.toolpath.fiveaxis.program_moves`)."""
    from planning.post.simultaneous import FiveAxisOperation
    from planning.toolpath.fiveaxis.register import air_moves

    post = config.post
    return FiveAxisOperation(name="finishing 5-axis", centre_mm=frame.to_part(tp.xyz_mm),
                             axis=tp.axis @ frame.rotation, kind=tp.kind.copy(), use=tp.use.copy(),
                             tool_number=post.finishing_tool_number, radius_mm=config.tool.diameter_mm / 2.0,
                             spindle_rpm=post.spindle_rpm, feed_mm_min=post.feed_mm_min,
                             plunge_mm_min=post.plunge_mm_min, gauge_length_mm=float(gauge_length_mm),
                             unwind=air_moves(tp, safe_z_mm))


def area_post_options(config, area: int, safe_z_mm: float) -> PostOptions:
    """The post options of area ``area``'s programs: the plan's ``post`` parameters, and retracts and
    rapids with the tip at the area's safe height ``safe_z_mm`` (ball centre, area frame; the posts
    never go lower). The 5-axis guard posts its path with the same (:mod:`planning.toolpath.fiveaxis.program_moves`)."""
    post = config.post
    R = config.tool.diameter_mm / 2.0
    return PostOptions(program_number=post.program_number + int(area), coolant=post.coolant,
                       decimals=post.decimals, rotary_sign=tuple(post.rotary_sign),
                       safe_z_mm=float(safe_z_mm - R), max_arc_radius_mm=float(post.max_arc_radius_mm))


def _five_axis_lists(five: list, decimals: int) -> list[dict]:
    """The simultaneous operations' entries of ``five_axis_operations``: per move the ball centre, the
    tool tip and the tool axis in the part frame (rounded float64 arrays), the kind and the use."""
    return [{"name": op.name, "tool_number": int(op.tool_number), "radius_mm": float(op.radius_mm),
             "centre_mm": np.round(op.centre_mm, decimals),
             "tip_mm": np.round(op.centre_mm - op.radius_mm * op.axis, decimals),
             "axis": np.round(op.axis, 9), "kind": op.kind.astype(np.int64), "use": op.use.astype(np.int64)}
            for op in five]


def _five_axis_moves(text: str, five: list[dict]) -> str:
    """The neutral moves JSON ``text`` ("" for none) with ``five`` (:func:`_five_axis_lists`) added under
    ``five_axis_operations``: ``json.dumps`` of the parsed text with that key added, without parsing it."""
    import json

    entries = json.dumps([{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in f.items()} for f in five],
                         separators=(",", ":"))
    head = text[:-1] + "," if text else "{"
    return head + '"five_axis_operations":' + entries + "}"


def _operations(ap, config) -> list[Operation]:
    post, rp = config.post, config.paths.roughing
    ops = []
    if ap.roughing is not None:
        ops.append(Operation(name="roughing", toolpath=ap.roughing, tool_number=post.roughing_tool_number,
                             tool_diameter_mm=rp.diameter_mm, tool_type=rp.tool_type,
                             spindle_rpm=post.roughing_spindle_rpm, feed_mm_min=post.roughing_feed_mm_min,
                             plunge_mm_min=post.plunge_mm_min))
    if getattr(ap, "semi_finishing", None) is not None:
        sp = config.paths.semi_finishing
        ops.append(Operation(name="semi_finishing", toolpath=ap.semi_finishing, tool_number=post.semi_finishing_tool_number,
                             tool_diameter_mm=sp.diameter_mm, tool_type="ball",
                             spindle_rpm=post.semi_finishing_spindle_rpm, feed_mm_min=post.semi_finishing_feed_mm_min,
                             plunge_mm_min=post.plunge_mm_min))
    if ap.finishing is not None and ap.finishing.axis is None:
        ops.append(Operation(name="finishing", toolpath=ap.finishing, tool_number=post.finishing_tool_number,
                             tool_diameter_mm=config.tool.diameter_mm, tool_type="ball",
                             spindle_rpm=post.spindle_rpm, feed_mm_min=post.feed_mm_min,
                             plunge_mm_min=post.plunge_mm_min))
    return ops


def post_areas(area_paths, *, setups_axes, rotary_deg, profile, placement_mm, gauge_length_mm, config,
               progress=None):
    """Programs ``{artifact name: text}`` (the NC programs as str, the moves files as bytes) and path
    summaries ``{area: AreaPathSummary}`` for every
    area in ``area_paths``; ``rotary_deg`` (k,2) (tilt, rotary) of each set-up; ``gauge_length_mm``:
    tool tip to spindle gauge line of the finishing tool. ``progress(fraction, message)``, when given,
    before each area's program in each dialect and its moves files."""
    post = config.post
    fp = config.paths.finishing
    files: dict[str, str | bytes] = {}
    summaries: dict[int, AreaPathSummary] = {}
    for k_area, ap in enumerate(area_paths):
        i = ap.area
        ops = _operations(ap, config)
        five = _five_axis_operations(ap, config, gauge_length_mm)
        names = {}
        if ops or five:
            # retracts and rapids: the tip at the area's safe height (the posts never go lower)
            options = area_post_options(config, i, ap.safe_z_mm)
            n_steps = len(post.dialects) + 1
            for d_i, dialect in enumerate(post.dialects):
                name = f"area_{i}.{dialect}.nc"
                if progress is not None:
                    progress((k_area + d_i / n_steps) / len(area_paths), f"area {i}: {name}")
                files[name] = _POSTS[dialect](ops, ap.frame, setup_id=i, area_id=i, tool_axis=setups_axes[i],
                                              rotary_deg=rotary_deg[i], profile=profile, placement_mm=placement_mm,
                                              gauge_length_mm=gauge_length_mm, options=options, five_axis=five)
                names[dialect] = name
            if progress is not None:
                progress((k_area + (n_steps - 1) / n_steps) / len(area_paths), f"area {i}: moves files")
            text, doc = neutral_json_arrays(
                ops, ap.frame, setup_id=i, area_id=i, tool_axis=setups_axes[i], rotary_deg=rotary_deg[i], profile=profile,
                placement_mm=placement_mm, decimals=post.decimals) if ops else ("", None)
            five_lists = _five_axis_lists(five, post.decimals)
            if five:
                text = _five_axis_moves(text, five_lists)
            # the same numbers twice: the JSON text gzip compressed, and as arrays (planning/report/moves_files.py)
            files[f"area_{i}.moves.json.gz"] = gzip_bytes(text + "\n")
            del text
            files[f"area_{i}.moves.npz"] = moves_npz_bytes(doc, five_lists)
        fin = rough = None
        if ap.finishing is not None:
            info = ap.finishing_info
            fin = FinishingSummary(
                n_passes=int(info.n_passes), n_regions=int(getattr(info, "n_regions", 1)), step_over_mm=float(info.step_over_mm), n_cl=int(ap.finishing.n_moves),
                n_cl_before_reduction=int(info.toolpath.n_moves), n_arcs=int(ap.n_arcs),
                n_retracts=int(info.n_retracts), length_mm=round(float(_cut_length(ap.finishing)), 3),
                tolerance_mm=float(fp.tolerance_mm), min_clearance_mm=round(float(ap.min_clearance_mm), 6),
                gouge_free=ap.gouge_free,
                holder_collisions=int(ap.holder_collisions), fixture_collisions=int(ap.fixture_collisions),
                blocked_cl=dict(getattr(ap, "blocked", {}) or {}),
                unmachined_points=int(0 if getattr(ap, "unmachined", None) is None else ap.unmachined.size),
                handed_in_points=int(getattr(ap, "handed_in", 0)),
                guard=_guard_summary(getattr(ap, "finishing_guard", None)),
                mode="5axis" if ap.finishing.axis is not None else "3+2",
                five_axis=_five_axis_summary(getattr(ap, "five_axis", None)),
                machining_time_s=round(machining_time_s(ap.finishing, feed_mm_min=post.feed_mm_min,
                                                        plunge_mm_min=post.plunge_mm_min,
                                                        rapid_mm_min=post.rapid_mm_min), 1))
        if ap.roughing is not None:
            info = ap.roughing_info
            rough = RoughingSummary(
                n_levels=int(info.n_levels), length_mm=round(float(info.length_mm), 3),
                air_mm=round(float(info.air_mm), 3), n_retracts=int(info.n_retracts),
                min_clearance_mm=round(float(info.min_clearance_mm), 6) if np.isfinite(info.min_clearance_mm)
                else None,
                stock_box_mm=tuple(tuple(float(v) for v in c) for c in np.asarray(info.stock_box_mm).reshape(2, 3)),
                rest=bool(getattr(info, "rest", False)), n_helix=int(getattr(info, "n_helix", 0)),
                n_ramps=int(getattr(info, "n_ramps", 0)),
                n_plunges_into_material=int(getattr(info, "n_plunges_into_material", 0)),
                n_pieces_left=int(getattr(info, "n_pieces_left", 0)),
                left_length_mm=float(getattr(info, "left_length_mm", 0.0)),
                guard=_guard_summary(getattr(ap, "roughing_guard", None)),
                allowance_left_mm=getattr(ap, "allowance_left", None),
                machining_time_s=round(machining_time_s(ap.roughing, feed_mm_min=post.roughing_feed_mm_min,
                                                        plunge_mm_min=post.plunge_mm_min,
                                                        rapid_mm_min=post.rapid_mm_min), 1))
        semi = _semi_summary(getattr(ap, "semi", None), config)
        rot = ap.frame.rotation
        summaries[i] = AreaPathSummary(
            frame=FrameSummary(origin_mm=tuple(map(float, ap.frame.origin_mm)), x_axis=tuple(map(float, rot[0])),
                               y_axis=tuple(map(float, rot[1])), z_axis=tuple(map(float, rot[2]))),
            safe_z_mm=round(float(ap.safe_z_mm), 4), finishing=fin, roughing=rough, semi_finishing=semi,
            programs=names,
            moves=f"area_{i}.moves.json.gz" if ops or five else None,
            moves_npz=f"area_{i}.moves.npz" if ops or five else None, seconds=ap.seconds)
    return files, summaries


def _semi_summary(semi, config):
    """plan.json's figures of a :class:`planning.toolpath.semi_finishing.SemiFinishing` (None: no pass)."""
    if semi is None:
        return None
    post, sp = config.post, config.paths.semi_finishing
    tp, passes = semi.toolpath, semi.passes
    return SemiFinishingSummary(
        diameter_mm=float(sp.diameter_mm), allowance_mm=float(sp.allowance_mm),
        n_passes=int(passes.n_passes) if passes is not None else 0,
        step_over_mm=float(passes.step_over_mm) if passes is not None else 0.0,
        n_cl=int(tp.n_moves) if tp is not None else 0, n_arcs=int(semi.n_arcs),
        length_mm=round(float(_cut_length(tp)), 3) if tp is not None else 0.0,
        min_clearance_mm=round(float(min(semi.min_clearance_mm, semi.offset_radius_mm)) - float(semi.radius_mm), 6),
        blocked_cl=dict(semi.blocked), allowance_before_mm=semi.allowance_before_mm,
        allowance_after_mm=semi.allowance_after_mm, allowance_reached_mm=semi.allowance_reached_mm,
        reached_share=round(semi.reached_share, 4),
        machining_time_s=round(machining_time_s(tp, feed_mm_min=post.semi_finishing_feed_mm_min,
                                                plunge_mm_min=post.plunge_mm_min, rapid_mm_min=post.rapid_mm_min), 1)
        if tp is not None else 0.0,
        guard=_guard_summary(semi.guard))


def _five_axis_summary(f):
    """plan.json's figures of a :class:`planning.toolpath.fiveaxis.finishing.FiveAxisFigures` (None: 3+2)."""
    if f is None:
        return None
    return FiveAxisSummary(
        n_positions=f.n_positions, n_alternatives=f.n_alternatives, blocked=dict(f.blocked), cone_deg=f.cone_deg,
        swing_deg=f.swing_deg, max_rate_deg_per_mm=f.max_rate_deg_per_mm, n_moves_before_biarcs=f.n_moves_before_biarcs,
        n_biarcs=f.n_biarcs, n_arcs=f.n_arcs, biarc_max_error_mm=f.biarc_max_error_mm,
        n_unwinding_links=int(f.n_unwinding_links),
        links=FiveAxisLinksSummary(**f.links) if f.links else None,
        biarc_min_clearance_mm=float(f.biarc_min_clearance_mm) if np.isfinite(f.biarc_min_clearance_mm) else 0.0)


def _guard_summary(g):
    """plan.json's figures of a :class:`planning.toolpath.guard.GuardOutcome` (None: not guarded)."""
    if g is None:
        return None
    return GuardSummary(found=dict(g.found), rapids_to_feed=int(g.rapids_to_feed), dropped=int(g.dropped),
                        truncated=int(g.truncated), rounds=int(g.rounds), removed_mm3=round(float(g.removed_mm3), 1))


def _cut_length(tp) -> float:
    from planning.toolpath.moves import ARC_CCW, ARC_CW, FEED, path_length_mm
    return path_length_mm(tp, kinds=(FEED, ARC_CW, ARC_CCW))

