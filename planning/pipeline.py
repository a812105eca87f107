"""The planning pipeline: cloud -> normals -> orientations -> visibility -> set-ups -> areas.

One function, :func:`run_plan`, calls each stage in turn (DESIGN.md "The pipeline", Makki 2010
§2-3), times it, and gathers the ``plan.json`` document and the ``plan.npz`` arrays. No global
state: the same cloud and parameters give the same plan.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

import scanmill
from planning.areas import Areas, assign_areas
from planning.cloud import Cloud
from planning.errors import InputError, ParameterError
from planning.gaussmap import candidate_axes
from planning.globalvis import global_visibility
from planning.machine import load_profile, machine_visibility
from planning.normals import sphere_throwing
from planning.post.programs import post_areas
from planning.setups import SetupSelection, select_setups
from planning.toolpath.area_paths import area_toolpaths
from planning.visibility import cone_visibility
from schemas.params import BoxZone, IndexZone, PlanConfig, SphereZone
from schemas.plan import (
    AxisFilters,
    InputSummary,
    NormalsSummary,
    OrientationsSummary,
    PlanResult,
    Selection,
    Setup,
    Timing,
    VisibilitySummary,
)

# progress(stage, fraction of that stage done in [0, 1], message)
Progress = Callable[[str, float, str], None]

STAGES = ("normals", "orientations", "visibility", "setups", "areas", "paths", "post")

_ROTARY_NAMES = {
    "table_table_ac": ("A", "C"), "table_table_bc": ("B", "C"),
    "head_head_ac": ("A", "C"), "head_head_bc": ("B", "C"),
}


@dataclass
class PlanOutcome:
    """A finished plan: the ``plan.json`` model, the ``plan.npz`` arrays, and what the writers need."""

    result: PlanResult
    arrays: dict[str, np.ndarray]
    points: np.ndarray                      # (N,3) mm, the whole input cloud
    input_labels: np.ndarray                # (N,) set-up of every input point
    selected_axes: np.ndarray               # (k,3)
    extra: dict = field(default_factory=dict)


def _stage_progress(progress: Progress | None, stage: str):
    if progress is None:
        return None
    return lambda fraction, message="": progress(stage, float(fraction), str(message))


def zone_mask(points: np.ndarray, sample_index: np.ndarray, zones) -> tuple[np.ndarray, list[str]]:
    """Bool mask (n,) of sampled points inside any functional zone, and warnings for empty zones.

    Index zones refer to the submitted cloud (0-based); boxes and spheres are in part coordinates, mm.
    """
    n_input = points.shape[0]
    sp = points[sample_index]
    mask = np.zeros(sample_index.shape[0], dtype=bool)
    warnings: list[str] = []
    for i, z in enumerate(zones):
        if isinstance(z, IndexZone):
            idx = np.asarray(z.indices, dtype=np.int64)
            if idx.max(initial=-1) >= n_input:
                raise ParameterError(
                    f"setups.functional_zones[{i}]: index {int(idx.max())} is out of range for a cloud of "
                    f"{n_input} points (indices are 0-based)")
            inside = np.isin(sample_index, idx)
        elif isinstance(z, BoxZone):
            lo, hi = np.asarray(z.min_mm), np.asarray(z.max_mm)
            inside = np.all((sp >= lo) & (sp <= hi), axis=1)
        elif isinstance(z, SphereZone):
            inside = np.sum((sp - np.asarray(z.center_mm)) ** 2, axis=1) <= z.radius_mm ** 2
        else:  # pragma: no cover - the schema admits no other kind
            raise ParameterError(f"setups.functional_zones[{i}]: unknown zone type")
        if not inside.any():
            warnings.append(f"functional zone {i} ({z.type}) contains no sampled point and constrains nothing")
        mask |= inside
    return mask, warnings


def _normals_stage(cloud: Cloud, config: PlanConfig, progress) -> tuple[np.ndarray, np.ndarray, NormalsSummary]:
    p = config.normals
    n_input = cloud.points.shape[0]
    if p.method == "input":
        if cloud.normals is None:
            raise InputError("normals.method is 'input' but the file carries no normals (PLY nx ny nz, "
                             "PCD normal_x normal_y normal_z); use normals.method = sphere_throwing",
                             code="missing_normals")
        nrm = np.asarray(cloud.normals, dtype=np.float64)
        length = np.linalg.norm(nrm, axis=1)
        good = np.isfinite(length) & (length > 1e-12)
        if not good.any():
            raise InputError("the normals in the file are all zero or invalid", code="invalid_normals")
        sample_index = np.flatnonzero(good).astype(np.int64)
        normals = nrm[good] / length[good, None]
        summary = NormalsSummary(method="input", n_sampled=int(sample_index.size),
                                 sampled_fraction=sample_index.size / n_input)
        return sample_index, normals, summary
    res = sphere_throwing(cloud.points, sphere_diameter_mm=p.sphere_diameter_mm,
                          grid_spacing_mm=p.grid_spacing_mm, directions=p.directions, progress=progress)
    if res.sample_index.size == 0:
        raise InputError("sphere throwing touched no point: check normals.sphere_diameter_mm and "
                         "normals.grid_spacing_mm against the part size", code="no_normals")
    summary = NormalsSummary(method="sphere_throwing", n_sampled=int(res.sample_index.size),
                             sampled_fraction=res.sample_index.size / n_input,
                             sphere_diameter_mm=float(res.sphere_diameter_mm),
                             grid_spacing_mm=float(res.grid_spacing_mm))
    return np.asarray(res.sample_index, dtype=np.int64), np.asarray(res.normals, dtype=np.float64), summary


def run_plan(cloud: Cloud, config: PlanConfig, *, name: str | None = None,
             progress: Progress | None = None, base_dir=None) -> PlanOutcome:
    """Plan the 3+2 machining of ``cloud`` (points in mm) with ``config`` (Makki 2010 §2-3).

    Returns the ``plan.json`` model and the ``plan.npz`` arrays: ``sample_index`` (n,),
    ``normals`` (n,3), ``candidate_axes`` (m,3) (machine-feasible axes), ``visibility`` (n,m),
    ``selected`` (k,), ``labels`` (n,), ``integrated`` (n,), plus ``input_labels`` (N,).
    ``base_dir``: where relative fixture mesh paths are looked up (the configuration's folder).
    """
    timings: list[Timing] = []
    warnings: list[str] = []
    points = cloud.points

    def timed(stage, fn):
        t0 = time.perf_counter()
        if progress:
            progress(stage, 0.0, "start")
        out = fn()
        timings.append(Timing(stage=stage, seconds=round(time.perf_counter() - t0, 4)))
        if progress:
            progress(stage, 1.0, f"done in {timings[-1].seconds:.2f} s")
        return out

    # 1. normals (Makki §2.1)
    sample_index, normals, nsum = timed(
        "normals", lambda: _normals_stage(cloud, config, _stage_progress(progress, "normals")))
    if nsum.method == "sphere_throwing" and nsum.sampled_fraction < 0.01:
        warnings.append(f"only {nsum.sampled_fraction:.1%} of the points got a normal: the cloud may be sparse "
                        "for the sphere diameter, or the grid spacing coarse")

    # 2. orientations + machine visibility (§2.2.1-2.2.2)
    profile = load_profile(config.machine.profile)

    def orientations():
        o = config.orientations
        cand = candidate_axes(o.sampling, phi_step_deg=o.phi_step_deg, theta_step_deg=o.theta_step_deg,
                              resolution_deg=o.resolution_deg)
        mv = machine_visibility(cand.axes, profile)
        return cand, mv

    cand, mv = timed("orientations", orientations)
    feasible = np.asarray(mv.feasible, dtype=bool)
    if not feasible.any():
        raise ParameterError(f"no candidate orientation lies within the rotary travel of machine profile "
                             f"'{profile.name}'")
    axes = cand.axes[feasible]
    angles = np.asarray(mv.angles_deg)[feasible]

    # 3. tool visibility (§2.2.3), then travel (Fig. 4c) and global visibility (§2.2.4)
    vp = config.visibility
    tool = config.tool.assembly()          # cutter, shank and holder: visibility, paths and posts

    def visibility():
        cone = cone_visibility(normals, axes, vp.cone_deg)
        gv = global_visibility(points, sample_index, normals, axes, angles, cone, tool=tool,
                               profile=profile, fixtures_params=config.fixtures, check_global=vp.global_,
                               check_travel=vp.travel, obstacles=vp.obstacles, base_dir=base_dir,
                               progress=_stage_progress(progress, "visibility"))
        return cone, gv

    cone, gv = timed("visibility", visibility)
    vis = gv.visible
    n_s = int(sample_index.size)
    feas_idx = np.flatnonzero(feasible)
    cone_counts = cone.sum(axis=0)
    col = {int(c): k for k, c in enumerate(feas_idx)}
    per_axis = []
    for c in range(cand.axes.shape[0]):
        k = col.get(c)
        if k is None:
            per_axis.append(AxisFilters(candidate=c, phi_deg=float(cand.phi_deg[c]), theta_deg=float(cand.theta_deg[c]),
                                        machine=n_s, cone=0, travel=0, fixture_collision=0, cloud_collision=0,
                                        visible=0))
        else:
            per_axis.append(AxisFilters(
                candidate=c, phi_deg=float(cand.phi_deg[c]), theta_deg=float(cand.theta_deg[c]), machine=0,
                cone=int(n_s - cone_counts[k]), travel=int(gv.removed["travel"][k]),
                fixture_collision=int(gv.removed["fixture_collision"][k]),
                cloud_collision=int(gv.removed["cloud_collision"][k]), visible=int(vis[:, k].sum())))
    vsum = VisibilitySummary(
        global_checked=vp.global_, travel_checked=vp.travel, obstacles=vp.obstacles,
        n_obstacle_points=gv.n_obstacles, placement_mm=tuple(float(x) for x in gv.placement_mm),
        table_z_mm=gv.table_z_mm, pairs_cone=int(cone.sum()), pairs_visible=int(vis.sum()),
        removed_total={k: int(v.sum()) for k, v in gv.removed.items()}, per_axis=per_axis)
    if not vis.any():
        warnings.append("no sampled point is visible along any feasible axis after the travel and collision "
                        "checks: check the tool length, holder, placement and fixtures")

    # 4. set-ups (§3.1)
    zmask, zwarn = zone_mask(points, sample_index, config.setups.functional_zones)
    warnings.extend(zwarn)
    s = config.setups
    sel: SetupSelection = timed("setups", lambda: select_setups(
        vis, coverage=s.coverage, max_setups=s.max_setups, min_points=s.min_points,
        zone_mask=zmask if zmask.any() else None, solver=s.solver, time_limit_s=s.time_limit_s,
        progress=_stage_progress(progress, "setups")))
    selected = np.asarray(sel.selected, dtype=np.int64)
    sel_axes = axes[selected]
    if sel.status in ("infeasible", "unknown"):
        warnings.append(sel.message)
        removed = {k: v for k, v in vsum.removed_total.items() if v}
        if removed:
            warnings.append(
                "of the " + f"{vsum.pairs_cone:,} (point, axis) pairs in the tool cone, "
                + ", ".join(f"{k.replace('_', ' ')} removed {v:,}" for k, v in removed.items())
                + " (per axis in plan.json 'visibility'): check fixtures.fixture_height_mm, the tool and holder "
                  "lengths and the machine profile's travel")
    elif sel.status == "feasible":
        warnings.append(f"the set-up search hit setups.time_limit_s = {s.time_limit_s} s before proving "
                        f"optimality (gap {sel.gap:.1%}); the best plan found is returned")

    # 5. areas (§3.1)
    areas: Areas = timed("areas", lambda: assign_areas(
        points, sample_index, normals, vis, selected, sel_axes, config.visibility.cone_deg))
    n_integrated = int(areas.integrated.sum())
    if n_integrated:
        warnings.append(f"{n_integrated} sampled points ({n_integrated / max(len(sample_index), 1):.1%}) are seen "
                        "by no chosen orientation and were attached to the nearest area: their accessibility "
                        "is not guaranteed")

    # 6. tool paths per area (Makki §4; Sood; Popescu; Tchanchane & Bey) and 7. the NC programs
    area_paths = []
    pp = config.paths
    if (pp.finishing.enabled or pp.roughing.enabled) and selected.size:
        area_paths = timed("paths", lambda: area_toolpaths(
            points, areas.input_labels, sel_axes, tool=tool, paths_params=pp, fixtures=gv.fixtures,
            forbidden=gv.forbidden_mm, max_slope_deg=min(float(config.visibility.cone_deg[1]), 87.0),
            progress=_stage_progress(progress, "paths")))
        for ap in area_paths:
            if ap.finishing is not None and not ap.gouge_free:
                warnings.append(f"area {ap.area}: the finishing path comes {ap.min_clearance_mm:.4f} mm from a cloud "
                                f"point, closer than R - tolerance: it would gouge")
            if ap.holder_collisions or ap.fixture_collisions:
                warnings.append(f"area {ap.area}: at {ap.holder_collisions} finishing CL points the shank or holder "
                                f"meets the cloud and at {ap.fixture_collisions} the tool meets a fixture or the "
                                "table (plan.json setups[].path): check the stick-out and the holder")
    programs, path_summaries = ({}, {})
    if area_paths:
        programs, path_summaries = timed("post", lambda: post_areas(
            area_paths, setups_axes=sel_axes, rotary_deg=angles[selected], profile=profile,
            placement_mm=gv.placement_mm, gauge_length_mm=tool.gauge_length_mm, config=config))

    names = _ROTARY_NAMES[profile.kinematics]
    setups = []
    for i, j in enumerate(selected):
        lab = areas.labels == i
        setups.append(Setup(
            id=i, candidate_index=int(j), tool_axis=tuple(float(c) for c in axes[j]),
            phi_deg=float(cand.phi_deg[feasible][j]), theta_deg=float(cand.theta_deg[feasible][j]),
            rotary_deg={names[0]: float(angles[j, 0]), names[1]: float(angles[j, 1])},
            n_visible=int(vis[:, j].sum()), n_points=int(lab.sum()),
            n_integrated=int((lab & areas.integrated).sum()),
            n_input_points=int((areas.input_labels == i).sum()), path=path_summaries.get(i)))

    lo, hi = points.min(axis=0), points.max(axis=0)
    result = PlanResult(
        scanmill_version=scanmill.__version__,
        status={"infeasible": "infeasible", "unknown": "incomplete"}.get(sel.status, "planned"),
        message=sel.message,
        input=InputSummary(name=name, format=cloud.source_format, n_points=int(points.shape[0]),
                           units=config.input.units, bbox_min_mm=tuple(map(float, lo)),
                           bbox_max_mm=tuple(map(float, hi)), has_normals=cloud.normals is not None),
        parameters=config,
        normals=nsum,
        orientations=OrientationsSummary(
            sampling=config.orientations.sampling, n_candidates=int(cand.axes.shape[0]),
            n_machine_feasible=int(feasible.sum()), n_kept=int(sel.n_axes_kept),
            machine_profile=profile.name, kinematics=profile.kinematics, rotary_axes=names),
        visibility=vsum,
        selection=Selection(status=sel.status, solver=sel.solver, k=int(sel.k), covered=int(sel.covered),
                            required_covered=int(sel.required_covered), coverage=float(sel.coverage),
                            overlap=int(sel.overlap), lower_bound=sel.lower_bound, gap=sel.gap,
                            best_coverage_at_max=sel.best_coverage_at_max, n_classes=int(sel.n_classes),
                            seconds=float(sel.seconds), message=sel.message),
        setups=setups, coverage=float(sel.coverage), overlap_points=int(sel.overlap),
        n_integrated=n_integrated, timings=timings, warnings=warnings)
    arrays = {
        "sample_index": sample_index, "normals": normals, "candidate_axes": axes,
        "candidate_rotary_deg": angles, "visibility": vis, "selected": selected,
        "labels": areas.labels, "integrated": areas.integrated, "overlap": areas.overlap,
        "input_labels": areas.input_labels,
    }
    for ap in area_paths:
        if ap.finishing is not None:
            # ball centres in the part frame, every move of the final path; cl_kind_i: 0 rapid,
            # 1 feed, 2 arc cw, 3 arc ccw (arc end points; centres in the neutral JSON)
            arrays[f"cl_{ap.area}"] = ap.frame.to_part(ap.finishing.xyz_mm)
            arrays[f"cl_kind_{ap.area}"] = ap.finishing.kind
    return PlanOutcome(result=result, arrays=arrays, points=points, input_labels=areas.input_labels,
                       selected_axes=sel_axes, extra={"programs": programs, "area_paths": area_paths})
